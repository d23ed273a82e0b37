//! IMU noise check: the white noise of the incoming gyro and accelerometer samples, measured in
//! flight, against the noise the INS is configured for (docs/INS.md "IMU noise check"): the gyro
//! R of the attitude filter and the velocity random walk Q̃ of the position filter (the authors
//! take both from their sensors, docs/REFERENCES.md A1.5–A1.7).
//!
//! Why: an INS that believes its IMU far quieter than it is over-trusts its propagation. Beside
//! PX4 SIH (gyro σ 0.07 rad/s per sample against the paper's 7.5e-4) the GNSS velocity
//! innovations grew on straight legs until the gate rejected the fixes and the INS
//! re-initialised; nothing told the operator why. The check only measures and reports; the
//! configuration stays the operator's.
//!
//! Adoption (docs/INS.md "IMU noise adoption"): with `[ins.imu_noise] adopt`, a measured noise
//! above `adopt_ratio` × the model in use replaces it ([`ImuNoiseModel::adopted`]): gyro R (and
//! the body-rate Q̃ with it, so the rate state's lag stays the configured one), the velocity
//! random walk, and on the ground the accelerometer's white R. The model only ever rises, up to
//! ceilings, and in flight by a bounded factor over the model at take-off.
//!
//! The estimate: second differences `x[k] − 2 x[k−1] + x[k−2]` remove the motion (a turn's rate
//! changes by far less than the noise from one sample to the next) and have 6 σ² for white
//! noise; per-window variances over [`WINDOW_SAMPLES`], the median of the last
//! [`WINDOWS_KEPT`] windows (robust to manoeuvres and bumps).

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::{ImuNoiseAdoptionConfig, InsConfig};
use crate::sensors::ImuSample;

/// Samples per variance window (1 s at 100 Hz).
pub const WINDOW_SAMPLES: usize = 100;
/// Windows whose median is the estimate.
pub const WINDOWS_KEPT: usize = 31;
/// Windows needed before there is an estimate.
pub const MIN_WINDOWS: usize = 5;
/// Samples further apart than this are not differenced (a gap restarts the differences), µs.
pub const MAX_SAMPLE_GAP_US: u64 = 100_000;
/// Measured over configured above which the IMU is reported noisier than configured.
pub const NOISY_RATIO: f64 = 4.0;
/// ... and below which that report ends (hysteresis).
pub const QUIET_RATIO: f64 = 2.0;

/// The measured IMU noise and how it compares with the configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoise {
    /// Per-sample gyro white-noise variance, mean of the axes, (rad/s)².
    pub gyro_var_rad2ps2: f64,
    /// Per-sample accelerometer white-noise variance, mean of the axes, (m/s²)².
    pub accel_var_m2ps4: f64,
    /// Median sample interval, s.
    pub period_s: f64,
    /// The gyro variance over the per-sample R the attitude filter uses at this period
    /// (`attitude.r_gyro_rad2ps2 × reference_period / period`).
    pub gyro_ratio: f64,
    /// The velocity random walk the accelerometer noise causes per reference period
    /// (`var × period × reference_period`) over `position.q_velocity_m2ps2`.
    pub accel_ratio: f64,
}

impl ImuNoise {
    /// The gyro R (`[ins.attitude] r_gyro_rad2ps2`) that matches the measured noise.
    pub fn matching_r_gyro_rad2ps2(&self, cfg: &InsConfig) -> f64 {
        self.gyro_var_rad2ps2 * self.period_s / cfg.reference_period_s
    }

    /// The velocity Q̃ (`[ins.position] q_velocity_m2ps2`) that covers the measured noise.
    pub fn matching_q_velocity_m2ps2(&self, cfg: &InsConfig) -> f64 {
        self.accel_var_m2ps4 * self.period_s * cfg.reference_period_s
    }

    /// Whether either ratio exceeds `threshold`.
    pub fn exceeds(&self, threshold: f64) -> bool {
        self.gyro_ratio > threshold || self.accel_ratio > threshold
    }
}

/// The IMU noise the filters use: the configured values, or those adopted from the measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoiseModel {
    /// `[ins.attitude] r_gyro_rad2ps2`.
    pub r_gyro_rad2ps2: f64,
    /// `[ins.attitude] q_w_nb_rad2ps2`, scaled with the gyro R.
    pub q_w_nb_rad2ps2: f64,
    /// `[ins.attitude] r_accel_white_m2ps4`. The position filter's `r_accel_m2ps4` is left
    /// alone: raised, it smooths the specific force and the fixes lag the INS in turns
    /// (docs/PX4.md); the velocity random walk carries the accelerometer's noise there.
    pub r_accel_white_m2ps4: f64,
    /// `[ins.position] q_velocity_m2ps2`.
    pub q_velocity_m2ps2: f64,
}

/// What one adoption did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adoption {
    /// The model from now on.
    pub model: ImuNoiseModel,
    /// A measured value was above its ceiling and the ceiling was adopted instead.
    pub capped: bool,
}

impl ImuNoiseModel {
    /// The model `cfg` configures.
    pub fn from_config(cfg: &InsConfig) -> Self {
        Self {
            r_gyro_rad2ps2: cfg.attitude.r_gyro_rad2ps2,
            q_w_nb_rad2ps2: cfg.attitude.q_w_nb_rad2ps2,
            r_accel_white_m2ps4: cfg.attitude.r_accel_white_m2ps4,
            q_velocity_m2ps2: cfg.position.q_velocity_m2ps2,
        }
    }

    /// Write the model into `cfg`.
    pub fn apply_to(&self, cfg: &mut InsConfig) {
        cfg.attitude.r_gyro_rad2ps2 = self.r_gyro_rad2ps2;
        cfg.attitude.q_w_nb_rad2ps2 = self.q_w_nb_rad2ps2;
        cfg.attitude.r_accel_white_m2ps4 = self.r_accel_white_m2ps4;
        cfg.position.q_velocity_m2ps2 = self.q_velocity_m2ps2;
    }

    /// The model after measuring `n`, if it must change. `at_takeoff` is the model in use when
    /// the aircraft began to fly (`None` on the ground). Only rises: each quantity whose
    /// measurement exceeds `adopt_ratio` × its value takes the measurement, capped by the
    /// ceiling and, in flight, by `max_flight_growth` × its take-off value. In flight the
    /// accelerometer's white R is left alone: the gusts' accelerations dominate the second
    /// differences there (×15–19 the sensor's noise on the simulator in turbulence), and the
    /// attitude filter models them apart (`r_accel_turbulence_m2ps4`, 10⁵× larger).
    pub fn adopted(
        &self,
        n: &ImuNoise,
        reference_period_s: f64,
        at_takeoff: Option<&ImuNoiseModel>,
        cfg: &ImuNoiseAdoptionConfig,
    ) -> Option<Adoption> {
        let mut next = *self;
        let mut capped = false;
        // `measured` against `current`: the new value, if adopted.
        let mut raise = |measured: f64, current: f64, ceiling: f64| -> Option<f64> {
            // NaN measurements compare false: never adopted.
            if measured.partial_cmp(&(cfg.adopt_ratio * current))
                != Some(std::cmp::Ordering::Greater)
            {
                return None;
            }
            let v = measured.min(ceiling);
            if v <= current {
                return None;
            }
            capped |= measured > ceiling;
            Some(v)
        };
        let growth = |takeoff: fn(&ImuNoiseModel) -> f64| {
            at_takeoff.map_or(f64::INFINITY, |m| cfg.max_flight_growth * takeoff(m))
        };
        let r_gyro = n.gyro_var_rad2ps2 * n.period_s / reference_period_s;
        let gyro_ceiling = cfg.max_gyro_var_rad2ps2.min(growth(|m| m.r_gyro_rad2ps2));
        if let Some(r) = raise(r_gyro, self.r_gyro_rad2ps2, gyro_ceiling) {
            next.q_w_nb_rad2ps2 = self.q_w_nb_rad2ps2 * r / self.r_gyro_rad2ps2;
            next.r_gyro_rad2ps2 = r;
        }
        // The velocity random walk white accelerometer noise causes per reference period.
        let q_vel = n.accel_var_m2ps4 * n.period_s * reference_period_s;
        let q_ceiling = (cfg.max_accel_var_m2ps4 * reference_period_s * reference_period_s)
            .min(growth(|m| m.q_velocity_m2ps2));
        if let Some(q) = raise(q_vel, self.q_velocity_m2ps2, q_ceiling) {
            next.q_velocity_m2ps2 = q;
        }
        if at_takeoff.is_none() {
            let r_accel = n.accel_var_m2ps4 * n.period_s / reference_period_s;
            if let Some(r) = raise(r_accel, self.r_accel_white_m2ps4, cfg.max_accel_var_m2ps4) {
                next.r_accel_white_m2ps4 = r;
            }
        }
        (next != *self).then_some(Adoption {
            model: next,
            capped,
        })
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct Window {
    n: usize,
    gyro_d2: f64,
    accel_d2: f64,
    dt_us: u64,
}

/// Measures the IMU's white noise from the sample stream.
#[derive(Debug, Clone, Default)]
pub struct ImuNoiseMonitor {
    last: Option<ImuSample>,
    before_last: Option<ImuSample>,
    window: Window,
    /// Per window: (gyro variance, accel variance, mean interval s).
    windows: VecDeque<(f64, f64, f64)>,
}

impl ImuNoiseMonitor {
    /// Take one sample (non-finite samples and out-of-order times restart the differences);
    /// `true` when it closed a window (the estimate changed).
    pub fn push(&mut self, s: &ImuSample) -> bool {
        let finite = s
            .gyro_rps
            .iter()
            .chain(s.accel_mps2.iter())
            .all(|v| v.is_finite());
        let follows = self
            .last
            .is_some_and(|l| s.t_us > l.t_us && s.t_us - l.t_us <= MAX_SAMPLE_GAP_US);
        if !finite || !follows {
            self.before_last = None;
            self.last = finite.then_some(*s);
            return false;
        }
        let mut closed = false;
        if let (Some(b), Some(l)) = (self.before_last, self.last) {
            let d2 = |x: Vector3<f64>, y: Vector3<f64>, z: Vector3<f64>| {
                (x - 2.0 * y + z).norm_squared()
            };
            let w = &mut self.window;
            w.n += 1;
            w.gyro_d2 += d2(s.gyro_rps, l.gyro_rps, b.gyro_rps);
            w.accel_d2 += d2(s.accel_mps2, l.accel_mps2, b.accel_mps2);
            w.dt_us += s.t_us - l.t_us;
            if w.n == WINDOW_SAMPLES {
                // 3 axes, and 6 σ² per second difference of white noise.
                let k = 1.0 / (18.0 * w.n as f64);
                let period_s = w.dt_us as f64 * 1e-6 / w.n as f64;
                self.windows
                    .push_back((w.gyro_d2 * k, w.accel_d2 * k, period_s));
                if self.windows.len() > WINDOWS_KEPT {
                    self.windows.pop_front();
                }
                *w = Window::default();
                closed = true;
            }
        }
        self.before_last = self.last;
        self.last = Some(*s);
        closed
    }

    /// The measured noise against `cfg` (`None` before [`MIN_WINDOWS`] windows).
    pub fn noise(&self, cfg: &InsConfig) -> Option<ImuNoise> {
        if self.windows.len() < MIN_WINDOWS {
            return None;
        }
        let median = |f: fn(&(f64, f64, f64)) -> f64| {
            let mut v: Vec<f64> = self.windows.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let gyro_var_rad2ps2 = median(|w| w.0);
        let accel_var_m2ps4 = median(|w| w.1);
        let period_s = median(|w| w.2);
        let r_gyro = cfg.attitude.r_gyro_rad2ps2 * cfg.reference_period_s / period_s;
        let q_vel = cfg.position.q_velocity_m2ps2;
        Some(ImuNoise {
            gyro_var_rad2ps2,
            accel_var_m2ps4,
            period_s,
            gyro_ratio: gyro_var_rad2ps2 / r_gyro,
            accel_ratio: accel_var_m2ps4 * period_s * cfg.reference_period_s / q_vel,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Box–Muller.
    fn normal(rng: &mut ChaCha8Rng) -> f64 {
        let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
        let u2: f64 = rng.random();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// A coordinated-turn-like rate profile plus white noise of σ per axis, at `period_us`.
    fn stream(sigma_g: f64, sigma_a: f64, period_us: u64, n: usize, seed: u64) -> Vec<ImuSample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|k| {
                let t_s = k as f64 * period_us as f64 * 1e-6;
                // 0.3 rad/s turns every 20 s, 3 m/s² of centripetal acceleration.
                let turn = (t_s * std::f64::consts::TAU / 20.0).sin();
                let mut noise = |sigma: f64| {
                    Vector3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)) * sigma
                };
                let gyro_rps = Vector3::new(0.0, 0.0, 0.3 * turn) + noise(sigma_g);
                let accel_mps2 = Vector3::new(0.0, 3.0 * turn, -9.81) + noise(sigma_a);
                ImuSample {
                    t_us: k as u64 * period_us + rng.random_range(0..50),
                    gyro_rps,
                    accel_mps2,
                }
            })
            .collect()
    }

    #[test]
    fn measures_white_noise_under_turns_and_compares_with_the_configuration() {
        let cfg = InsConfig::default();
        // PX4 SIH-like: σ 0.05 rad/s and 0.6 m/s² at 100 Hz.
        let mut m = ImuNoiseMonitor::default();
        for s in stream(0.05, 0.6, 10_000, 6_000, 1) {
            m.push(&s);
        }
        let n = m.noise(&cfg).expect("an estimate after 60 s");
        // 31 windows of 297 differences (3 axes × 99): the median's relative spread is a few %.
        assert!((n.gyro_var_rad2ps2 / 0.0025 - 1.0).abs() < 0.1, "{n:?}");
        assert!((n.accel_var_m2ps4 / 0.36 - 1.0).abs() < 0.1, "{n:?}");
        assert!((n.period_s - 0.01).abs() < 1e-4);
        let expect_gyro = 0.0025 / cfg.attitude.r_gyro_rad2ps2;
        assert!((n.gyro_ratio / expect_gyro - 1.0).abs() < 0.1);
        assert!(n.exceeds(NOISY_RATIO));
        // What to configure: at the reference period the per-sample variance itself.
        assert!((n.matching_r_gyro_rad2ps2(&cfg) / 0.0025 - 1.0).abs() < 0.1);
        assert!((n.matching_q_velocity_m2ps2(&cfg) / (0.36 * 1e-4) - 1.0).abs() < 0.1);
    }

    #[test]
    fn the_configured_imu_is_not_reported() {
        let cfg = InsConfig::default();
        let sigma_g = cfg.attitude.r_gyro_rad2ps2.sqrt();
        // At 200 Hz the per-sample variance of the configured IMU doubles (R ∝ 1/Δt).
        let mut m = ImuNoiseMonitor::default();
        for s in stream(
            sigma_g * 2f64.sqrt(),
            cfg.position.r_accel_m2ps4.sqrt(),
            5_000,
            12_000,
            2,
        ) {
            m.push(&s);
        }
        let n = m.noise(&cfg).expect("an estimate");
        assert!((n.gyro_ratio - 1.0).abs() < 0.15, "{n:?}");
        assert!(!n.exceeds(QUIET_RATIO), "{n:?}");
    }

    fn measured(gyro_var: f64, accel_var: f64) -> ImuNoise {
        ImuNoise {
            gyro_var_rad2ps2: gyro_var,
            accel_var_m2ps4: accel_var,
            period_s: 0.004,
            gyro_ratio: f64::NAN,
            accel_ratio: f64::NAN,
        }
    }

    #[test]
    fn adoption_only_raises_above_the_ratio_and_keeps_the_lag() {
        let cfg = InsConfig::default();
        let policy = ImuNoiseAdoptionConfig::default();
        let m = ImuNoiseModel::from_config(&cfg);
        let per_sample = |r_ref: f64| r_ref * cfg.reference_period_s / 0.004;
        // Quieter than configured, or noisier by less than the ratio: nothing.
        for f in [0.01, 1.0, 3.9] {
            let n = measured(per_sample(f * m.r_gyro_rad2ps2), 0.0);
            assert_eq!(m.adopted(&n, cfg.reference_period_s, None, &policy), None);
        }
        // PX4 SIH on the ground: gyro ×84; the accelerometer σ 0.65 m/s² per 250 Hz sample.
        let n = measured(per_sample(84.0 * m.r_gyro_rad2ps2), 0.42);
        let a = m
            .adopted(&n, cfg.reference_period_s, None, &policy)
            .unwrap();
        assert!(!a.capped);
        assert!((a.model.r_gyro_rad2ps2 / m.r_gyro_rad2ps2 / 84.0 - 1.0).abs() < 1e-9);
        let lag = |x: &ImuNoiseModel| x.q_w_nb_rad2ps2 / x.r_gyro_rad2ps2;
        assert!((lag(&a.model) / lag(&m) - 1.0).abs() < 1e-12);
        // On the ground the accelerometer's white R is the measured one at the reference
        // period; its velocity random walk (1.7e-5) is under 4 × q_velocity (1e-5).
        assert!((a.model.r_accel_white_m2ps4 - 0.42 * 0.4).abs() < 1e-9);
        assert_eq!(a.model.q_velocity_m2ps2, m.q_velocity_m2ps2);
        // Adopting again what was adopted changes nothing.
        let again = a.model.adopted(&n, cfg.reference_period_s, None, &policy);
        assert_eq!(again, None);
    }

    #[test]
    fn in_flight_the_accelerometer_r_stays_and_growth_and_ceilings_bound_the_rest() {
        let cfg = InsConfig::default();
        let policy = ImuNoiseAdoptionConfig::default();
        let m = ImuNoiseModel::from_config(&cfg);
        let ref_s = cfg.reference_period_s;
        // Gusts: the accelerometer ×19 the white R (the simulator in turbulence), its velocity
        // random walk far under q_velocity: nothing, in flight.
        let n = measured(0.0, 19.0 * m.r_accel_white_m2ps4 * ref_s / 0.004);
        assert_eq!(m.adopted(&n, ref_s, Some(&m), &policy), None);
        // ... the same on the ground would be adopted.
        assert!(m.adopted(&n, ref_s, None, &policy).is_some());
        // In flight the gyro may grow ×100 over the take-off model.
        let n = measured(1e4 * m.r_gyro_rad2ps2 * ref_s / 0.004, 0.0);
        let a = m.adopted(&n, ref_s, Some(&m), &policy).unwrap();
        assert!(a.capped);
        assert!((a.model.r_gyro_rad2ps2 / m.r_gyro_rad2ps2 - 100.0).abs() < 1e-9);
        // On the ground only the absolute ceiling holds.
        let n = measured(1.0 * ref_s / 0.004, 100.0 * ref_s / 0.004);
        let a = m.adopted(&n, ref_s, None, &policy).unwrap();
        assert!(a.capped);
        assert_eq!(a.model.r_gyro_rad2ps2, policy.max_gyro_var_rad2ps2);
        assert_eq!(a.model.r_accel_white_m2ps4, policy.max_accel_var_m2ps4);
        assert_eq!(
            a.model.q_velocity_m2ps2,
            policy.max_accel_var_m2ps4 * ref_s * ref_s
        );
        // Written into a configuration and read back.
        let mut c = cfg.clone();
        a.model.apply_to(&mut c);
        assert_eq!(ImuNoiseModel::from_config(&c), a.model);
        assert!(c.validate().is_ok());
    }

    #[test]
    fn gaps_and_bad_samples_restart_the_differences_without_poisoning_the_estimate() {
        let cfg = InsConfig::default();
        let mut m = ImuNoiseMonitor::default();
        for (k, mut s) in stream(0.01, 0.1, 10_000, 3_000, 3).into_iter().enumerate() {
            if k % 500 == 7 {
                s.gyro_rps.x = f64::NAN;
            }
            if k % 700 == 0 {
                s.t_us += 1_000_000_000; // a lone jump forward
            }
            m.push(&s);
        }
        let n = m.noise(&cfg).expect("an estimate");
        assert!((n.gyro_var_rad2ps2 / 1e-4 - 1.0).abs() < 0.15, "{n:?}");
        assert!(ImuNoiseMonitor::default().noise(&cfg).is_none());
    }
}
