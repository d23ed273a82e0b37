//! Magnetometer (docs/REFERENCES.md A2.3): `B̃ = B^b + B_hi + B_off + M_si·B^b + (σ_v/√Δt)·ν` with
//! `B^b = C_bn·B^n`. Hard iron `B_hi` and soft iron `M_si` (full 3×3) belong to the aircraft;
//! the offset `B_off` and the noise to the run. No platform misalignment, as in the C++.

use ianav::sensors::MagSample;
use nalgebra::{Matrix3, Vector3};

use super::SensorTruth;
use super::config::MagConfig;
use crate::rng::{self, Stream};

/// A three-axis magnetometer with its error state.
#[derive(Debug, Clone)]
pub struct Magnetometer {
    /// Soft-iron matrix `M_si`, dimensionless.
    soft_iron: Matrix3<f64>,
    /// `B_hi + B_off`, nT (both constant per run).
    offset_nt: Vector3<f64>,
    /// Hard iron alone, nT.
    hard_iron_nt: Vector3<f64>,
    /// Per-sample noise σ `σ_v/√Δt`, nT.
    noise_sigma_nt: f64,
    /// Run stream: 3 offset draws at construction, then 3 noise draws per sample.
    run: Stream,
    /// Error except white noise at the last sample, nT.
    e_mag_nt: Vector3<f64>,
}

impl Magnetometer {
    /// Draw the aircraft part (9 soft-iron entries row-major, then 3 hard-iron) and the run
    /// offset (3 draws).
    pub fn new(cfg: &MagConfig, aircraft: &mut Stream, mut run: Stream) -> Self {
        let soft_iron = Matrix3::from_fn(|r, c| {
            let sigma = if r == c {
                cfg.soft_iron_scale_sigma
            } else {
                cfg.soft_iron_cross_sigma
            };
            sigma * rng::normal(aircraft)
        });
        let hard_iron_nt = Vector3::from_fn(|_, _| cfg.hard_iron_sigma_nt * rng::normal(aircraft));
        let b_off = Vector3::from_fn(|_, _| cfg.offset_sigma_nt * rng::normal(&mut run));
        let offset_nt = hard_iron_nt + b_off;
        Self {
            soft_iron,
            offset_nt,
            hard_iron_nt,
            noise_sigma_nt: cfg.noise_density_nt_sqrt_s / cfg.period_s.sqrt(),
            run,
            e_mag_nt: offset_nt,
        }
    }

    /// Measure the true field `truth.mag_ned_nt` in the body axes of `truth.q_nb`.
    pub fn sample(&mut self, truth: &SensorTruth) -> MagSample {
        let b_b = truth.q_nb.inverse_transform_vector(&truth.mag_ned_nt);
        let s = self.noise_sigma_nt;
        let noise = Vector3::new(
            s * rng::normal(&mut self.run),
            s * rng::normal(&mut self.run),
            s * rng::normal(&mut self.run),
        );
        let e = self.offset_nt + self.soft_iron * b_b;
        self.e_mag_nt = e;
        MagSample {
            t_us: truth.t_us,
            mag_b_nt: b_b + e + noise,
        }
    }

    /// Error except white noise at the last sample ("E_mag"), body axes, nT.
    pub fn e_mag_nt(&self) -> Vector3<f64> {
        self.e_mag_nt
    }

    /// Hard iron `B_hi`, nT.
    pub fn hard_iron_nt(&self) -> Vector3<f64> {
        self.hard_iron_nt
    }

    /// Soft-iron matrix `M_si`.
    pub fn soft_iron(&self) -> &Matrix3<f64> {
        &self.soft_iron
    }
}
