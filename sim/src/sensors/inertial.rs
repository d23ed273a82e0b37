//! Gyroscope and accelerometer (docs/REFERENCES.md A2.1) on the IMU platform of A2.2.
//!
//! Each triad measures `ũ = A·u + B + (σ_v/√Δt)·ν` with
//! `A = R_bp,est·(I + M)·R_pb,true` (scale/cross-coupling `M` in platform axes, seen through
//! the true mounting and re-expressed in the body axes the navigation believes in) and bias
//! `B = B₀ν₀ + σ_u·√Δt·S_k` (`S` the band-limited walk of [`super::random_walk`]).
//!
//! The accelerometer also carries the lever arm: the IMU sits at `r = T_rp − T_rb` from the
//! CG, so it senses `f + ℓ_true`, and the output is moved back to the CG with the
//! navigation's lever-arm estimate:
//! `f̃ = A·(f + ℓ_true) − ℓ_est + B + noise`, `ℓ = ω×(ω×r) + ω̇×r`. `ℓ_true` uses the true
//! `ω, ω̇`; `ℓ_est` uses the measured gyro output and its finite difference over one sample
//! period, the estimated `T_rp` and the true CG (docs/REFERENCES.md A9.7, kept: the navigation has
//! no CG estimate of its own).
//!
//! Deviation from the C++ (docs/REFERENCES.md A9.7): the gyroscope gets the full mounting model
//! `ω̃ = A·ω + B + noise`, where the original applied the misalignment only through the scale
//! term; the difference is `(R_bp,est·R_pb,true − I)·ω`, ≈ 5e-4·|ω| for the default
//! 0.03° mounting-estimate error.

use ianav::sensors::ImuSample;
use nalgebra::{Matrix3, Vector3};

use super::SensorTruth;
use super::config::{CrossCoupling, InertialConfig};
use super::platform::Platform;
use super::random_walk::{BandedWalk3, SoftBand};
use crate::rng::{self, Stream};

/// One inertial triad (three axes of gyroscope or accelerometer) with its error state.
#[derive(Debug, Clone)]
pub struct InertialTriad {
    /// `A = R_bp,est·(I + M)·R_pb,true`, constant per aircraft.
    a: Matrix3<f64>,
    /// Per-run bias offset `B₀ν₀`.
    offset: Vector3<f64>,
    /// Bias drift walk, in steps.
    drift: BandedWalk3,
    /// Drift per walk step `σ_u·√Δt`.
    drift_per_step: f64,
    /// Per-sample white-noise σ, `σ_v/√Δt`.
    noise_sigma: f64,
    /// Run stream: offsets at construction, then per sample 3 drift and 3 noise draws.
    run: Stream,
}

impl InertialTriad {
    /// Build a triad. The aircraft stream gives the 9 entries of `M` (row-major; all nine are
    /// drawn even when `M` is lower-triangular, so the structure never shifts later draws);
    /// the run stream gives the 3 bias offsets, then the per-sample draws.
    pub fn new(
        cfg: &InertialConfig,
        dt_s: f64,
        platform: &Platform,
        aircraft: &mut Stream,
        mut run: Stream,
    ) -> Self {
        let mut m = Matrix3::zeros();
        for r in 0..3 {
            for c in 0..3 {
                let nu = rng::normal(aircraft);
                let kept = match cfg.cross_coupling {
                    CrossCoupling::Full => true,
                    CrossCoupling::LowerTriangular => c <= r,
                };
                if kept {
                    let sigma = if r == c {
                        cfg.scale_sigma
                    } else {
                        cfg.cross_coupling_sigma
                    };
                    m[(r, c)] = sigma * nu;
                }
            }
        }
        let r_bp_est = platform.q_bp_est.to_rotation_matrix().into_inner();
        let r_pb_true = platform
            .q_bp_true
            .to_rotation_matrix()
            .into_inner()
            .transpose();
        let a = r_bp_est * (Matrix3::identity() + m) * r_pb_true;
        let offset = Vector3::from_fn(|_, _| cfg.bias_offset_sigma * rng::normal(&mut run));
        let band = SoftBand {
            limit_steps: cfg.band_limit_steps,
            safety_steps: cfg.band_safety_steps,
        };
        Self {
            a,
            offset,
            drift: BandedWalk3::new([0.0; 3], band),
            drift_per_step: cfg.bias_rw_sigma * dt_s.sqrt(),
            noise_sigma: cfg.noise_density / dt_s.sqrt(),
            run,
        }
    }

    /// The combined mounting and scale matrix `A`.
    pub fn a(&self) -> &Matrix3<f64> {
        &self.a
    }

    /// Current bias `B = B₀ν₀ + σ_u√Δt·S`.
    #[inline]
    pub fn bias(&self) -> Vector3<f64> {
        self.offset + Vector3::from(self.drift.steps) * self.drift_per_step
    }

    /// Advance the drift one sample and return the new bias (3 draws).
    #[inline]
    fn advance_bias(&mut self) -> Vector3<f64> {
        self.drift.step(&mut self.run);
        self.bias()
    }

    /// One white-noise vector (3 draws).
    #[inline]
    fn noise(&mut self) -> Vector3<f64> {
        let s = self.noise_sigma;
        let run = &mut self.run;
        Vector3::new(
            s * rng::normal(run),
            s * rng::normal(run),
            s * rng::normal(run),
        )
    }
}

/// The IMU: gyroscope and accelerometer triads on one platform.
#[derive(Debug, Clone)]
pub struct Imu {
    gyro: InertialTriad,
    accel: InertialTriad,
    platform: Platform,
    dt_s: f64,
    /// Previous measured gyro output, for the navigation's angular-acceleration estimate.
    prev_gyro_rps: Option<Vector3<f64>>,
    /// Systematic gyro error at the last sample (everything but white noise).
    e_gyr_rps: Vector3<f64>,
    /// Systematic accelerometer error at the last sample.
    e_acc_mps2: Vector3<f64>,
}

impl Imu {
    /// An IMU sampled every `dt_s` seconds.
    pub fn new(gyro: InertialTriad, accel: InertialTriad, platform: Platform, dt_s: f64) -> Self {
        // Before the first sample the only systematic error is the bias offset.
        let (e_gyr_rps, e_acc_mps2) = (gyro.bias(), accel.bias());
        Self {
            gyro,
            accel,
            platform,
            dt_s,
            prev_gyro_rps: None,
            e_gyr_rps,
            e_acc_mps2,
        }
    }

    /// Measure the truth. Must be called once every `dt_s` (the noise, the drift step and the
    /// angular-acceleration estimate assume it); the first call estimates `ω̇ = 0`.
    pub fn sample(&mut self, truth: &SensorTruth) -> ImuSample {
        let w = truth.w_ib_b_rps;
        let w_dot = truth.w_dot_ib_b_rps2;
        let f = truth.f_ib_b_mps2;

        let b_gyr = self.gyro.advance_bias();
        let n_gyr = self.gyro.noise();
        let a_gyr_w = self.gyro.a * w;
        let gyro = a_gyr_w + b_gyr + n_gyr;

        let r_true = self.platform.t_rp_b_true_m - truth.cg_from_ref_b_m;
        let r_est = self.platform.t_rp_b_est_m - truth.cg_from_ref_b_m;
        let w_dot_est = match self.prev_gyro_rps {
            Some(prev) => (gyro - prev) / self.dt_s,
            None => Vector3::zeros(),
        };
        self.prev_gyro_rps = Some(gyro);
        let lever_true = w.cross(&w.cross(&r_true)) + w_dot.cross(&r_true);
        let lever_est = gyro.cross(&gyro.cross(&r_est)) + w_dot_est.cross(&r_est);
        // Grouped so that with A = I and equal lever arms the term is exactly zero.
        let lever_err = self.accel.a * lever_true - lever_est;

        let b_acc = self.accel.advance_bias();
        let n_acc = self.accel.noise();
        let a_acc_f = self.accel.a * f;
        let accel = a_acc_f + lever_err + b_acc + n_acc;

        self.e_gyr_rps = (a_gyr_w - w) + b_gyr;
        self.e_acc_mps2 = (a_acc_f - f) + lever_err + b_acc;
        ImuSample {
            t_us: truth.t_us,
            gyro_rps: gyro,
            accel_mps2: accel,
        }
    }

    /// Gyro error at the last sample except white noise ("E_gyr"), rad/s.
    pub fn e_gyr_rps(&self) -> Vector3<f64> {
        self.e_gyr_rps
    }

    /// Accelerometer error at the last sample except its own white noise ("E_acc"), m/s².
    /// It includes the lever-arm compensation error, which carries gyro noise through `ℓ_est`.
    pub fn e_acc_mps2(&self) -> Vector3<f64> {
        self.e_acc_mps2
    }

    /// Current gyro bias (offset + drift), rad/s.
    pub fn gyro_bias_rps(&self) -> Vector3<f64> {
        self.gyro.bias()
    }

    /// Current accelerometer bias (offset + drift), m/s².
    pub fn accel_bias_mps2(&self) -> Vector3<f64> {
        self.accel.bias()
    }

    /// The gyro triad (for its `A` matrix).
    pub fn gyro(&self) -> &InertialTriad {
        &self.gyro
    }

    /// The accelerometer triad.
    pub fn accel(&self) -> &InertialTriad {
        &self.accel
    }

    /// The platform mounting.
    pub fn platform(&self) -> &Platform {
        &self.platform
    }
}
