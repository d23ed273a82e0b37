//! Air-data sensors (docs/REFERENCES.md A2.4): Pitot true airspeed, AoA and AoS vanes, static
//! pressure and outside air temperature. Each is `ỹ = x + B₀ν₀ + σ·ν_k`: a constant per-run
//! bias and a per-sample white noise whose σ does **not** depend on the sample rate
//! (docs/REFERENCES.md A9.10, kept so the noise matches the published 100 Hz figures; at another
//! rate the noise density changes).
//!
//! The C++ applies the sideslip error to `−β`; the error is symmetric, so it is applied to
//! `β` directly (same distribution, opposite sign of each draw).

use ianav::sensors::AirSample;

use super::SensorTruth;
use super::config::AirDataConfig;
use crate::rng::{self, Stream};

/// Radians per degree.
const RAD_PER_DEG: f64 = std::f64::consts::PI / 180.0;

/// One scalar sensor `ỹ = x + b + σ·ν`.
#[derive(Debug, Clone)]
pub struct ScalarSensor {
    /// Constant per-run bias `B₀ν₀`.
    pub bias: f64,
    /// Per-sample noise σ.
    pub noise_sigma: f64,
    /// Run stream: the bias draw, then one noise draw per sample.
    run: Stream,
}

impl ScalarSensor {
    /// Draw the bias (first draw of `run`).
    pub fn new(bias_sigma: f64, noise_sigma: f64, mut run: Stream) -> Self {
        let bias = bias_sigma * rng::normal(&mut run);
        Self {
            bias,
            noise_sigma,
            run,
        }
    }

    /// Measure `x`.
    #[inline]
    pub fn measure(&mut self, x: f64) -> f64 {
        x + self.bias + self.noise_sigma * rng::normal(&mut self.run)
    }
}

/// The constant air-data biases of one run, in the units of [`AirSample`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AirDataBiases {
    /// True-airspeed bias, m/s.
    pub tas_mps: f64,
    /// Angle-of-attack bias, rad (`None` without vanes).
    pub aoa_rad: Option<f64>,
    /// Angle-of-sideslip bias, rad (`None` without vanes).
    pub aos_rad: Option<f64>,
    /// Static-pressure bias, Pa.
    pub p_pa: f64,
    /// Temperature bias, K.
    pub temp_k: f64,
}

/// The air-data suite. Every sensor has its own run stream, so removing the vanes changes
/// no other draw.
#[derive(Debug, Clone)]
pub struct AirData {
    tas: ScalarSensor,
    aoa: Option<ScalarSensor>,
    aos: Option<ScalarSensor>,
    p: ScalarSensor,
    temp: ScalarSensor,
}

impl AirData {
    /// Build from the configuration and one run-stream factory (`name → stream`).
    pub fn new(cfg: &AirDataConfig, mut stream: impl FnMut(&str) -> Stream) -> Self {
        let vane = |bias_deg: f64, noise_deg: f64, s: Stream| {
            ScalarSensor::new(bias_deg * RAD_PER_DEG, noise_deg * RAD_PER_DEG, s)
        };
        let (aoa, aos) = if cfg.vanes_enabled {
            (
                Some(vane(
                    cfg.aoa_bias_sigma_deg,
                    cfg.aoa_noise_sigma_deg,
                    stream("aoa"),
                )),
                Some(vane(
                    cfg.aos_bias_sigma_deg,
                    cfg.aos_noise_sigma_deg,
                    stream("aos"),
                )),
            )
        } else {
            (None, None)
        };
        Self {
            tas: ScalarSensor::new(
                cfg.tas_bias_sigma_mps,
                cfg.tas_noise_sigma_mps,
                stream("tas"),
            ),
            aoa,
            aos,
            p: ScalarSensor::new(cfg.p_bias_sigma_pa, cfg.p_noise_sigma_pa, stream("p")),
            temp: ScalarSensor::new(
                cfg.temp_bias_sigma_k,
                cfg.temp_noise_sigma_k,
                stream("temp"),
            ),
        }
    }

    /// Measure the truth.
    pub fn sample(&mut self, truth: &SensorTruth) -> AirSample {
        AirSample {
            t_us: truth.t_us,
            tas_mps: self.tas.measure(truth.tas_mps),
            aoa_rad: self.aoa.as_mut().map(|s| s.measure(truth.aoa_rad)),
            aos_rad: self.aos.as_mut().map(|s| s.measure(truth.aos_rad)),
            p_pa: self.p.measure(truth.p_pa),
            temp_k: self.temp.measure(truth.temp_k),
        }
    }

    /// The run's constant biases.
    pub fn biases(&self) -> AirDataBiases {
        AirDataBiases {
            tas_mps: self.tas.bias,
            aoa_rad: self.aoa.as_ref().map(|s| s.bias),
            aos_rad: self.aos.as_ref().map(|s| s.bias),
            p_pa: self.p.bias,
            temp_k: self.temp.bias,
        }
    }
}
