//! The INS's public data (docs/INS.md): its initial state [`InsInit`] with the cold-start
//! uncertainties, the solution [`InsSolution`] with its covariances, the counters
//! [`InsStats`], and its errors.

use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::config::InsConfigError;
use crate::env::magnetic::MagneticError;
use crate::math::wgs84::Geodetic;
use crate::sensors::SensorErrorPriors;

/// Cold-start σ of the gyro error per axis, rad/s (the "base" gyro bias offset, 0.2 °/s).
pub const COLD_E_GYR_SIGMA_RPS: f64 = 3.490_658_503_988_659e-3;
/// Cold-start σ of the accelerometer error per axis, m/s² (the "base" bias offset).
pub const COLD_E_ACC_SIGMA_MPS2: f64 = 0.157;
/// Cold-start σ of the magnetometer error per axis, nT (offset 500 nT ⊕ hard iron 175 nT).
pub const COLD_E_MAG_SIGMA_NT: f64 = 529.7;
/// Cold-start σ of the magnetic-model error `ΔB_n` (N, E, D), nT (WMM uncertainty,
/// docs/REFERENCES.md A3.6).
pub const COLD_DELTA_B_SIGMA_NT: [f64; 3] = [138.0, 89.0, 165.0];

/// Why the INS could not be built.
#[derive(Debug, thiserror::Error)]
pub enum InsError {
    /// Invalid configuration.
    #[error(transparent)]
    Config(#[from] InsConfigError),
    /// An initial estimate is not finite or out of its domain.
    #[error("INS initialisation: `{field}`: {reason}")]
    Init {
        /// The offending field of [`InsInit`].
        field: &'static str,
        /// What it must satisfy.
        reason: &'static str,
    },
    /// The magnetic model cannot be built for the requested epoch.
    #[error("INS magnetic model: {0}")]
    Magnetic(#[from] MagneticError),
}

/// Initial estimates (docs/REFERENCES.md A1.9: the simulator draws them around the truth) and their
/// one-sigma uncertainties, which set the filters' P₀.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InsInit {
    /// Initial attitude `q_nb` (P₀ from `attitude.p0_attitude_sigma_deg`).
    pub q_nb: UnitQuaternion<f64>,
    /// Initial position (normally the first GNSS fix; P₀ = the GNSS σ).
    pub pos: Geodetic,
    /// Initial NED ground velocity, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Initial sensor-error estimates and their σ.
    pub priors: SensorErrorPriors,
    /// Angle of attack assumed while no AoA vane reading exists, rad.
    pub aoa_rad: f64,
    /// Epoch of the World Magnetic Model, decimal year (within WMM2025's validity).
    pub mag_decimal_year: f64,
    /// Time of validity of `pos` and `v_ned_mps` (the fix's time), µs. The INS starts at its
    /// first IMU sample, which can be later (a slow stream, a lagged fix): it carries position
    /// and velocity there with that sample's acceleration. `None`: valid at that first sample.
    pub valid_at_us: Option<u64>,
}

/// Cold start: zero sensor-error estimates with the cold-start σ (`COLD_*`).
pub fn cold_priors() -> SensorErrorPriors {
    SensorErrorPriors {
        e_gyr_rps: Vector3::zeros(),
        e_gyr_sigma_rps: Vector3::repeat(COLD_E_GYR_SIGMA_RPS),
        e_acc_mps2: Vector3::zeros(),
        e_acc_sigma_mps2: Vector3::repeat(COLD_E_ACC_SIGMA_MPS2),
        e_mag_nt: Vector3::zeros(),
        e_mag_sigma_nt: Vector3::repeat(COLD_E_MAG_SIGMA_NT),
        delta_b_n_nt: Vector3::zeros(),
        delta_b_n_sigma_nt: Vector3::from(COLD_DELTA_B_SIGMA_NT),
    }
}

impl InsInit {
    /// Cold start: zero sensor-error estimates with the cold-start σ ([`cold_priors`]).
    pub fn new(
        q_nb: UnitQuaternion<f64>,
        pos: Geodetic,
        v_ned_mps: Vector3<f64>,
        mag_decimal_year: f64,
    ) -> Self {
        Self {
            q_nb,
            pos,
            v_ned_mps,
            priors: cold_priors(),
            aoa_rad: 0.0,
            mag_decimal_year,
            valid_at_us: None,
        }
    }

    pub(crate) fn validate(&self) -> Result<(), InsError> {
        let bad = |field, reason| Err(InsError::Init { field, reason });
        let finite3 = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
        let sigma3 = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite() && *x >= 0.0);
        if !self.q_nb.coords.iter().all(|x| x.is_finite()) {
            return bad("q_nb", "must be finite");
        }
        let p = &self.pos;
        let lat_ok = p.lat_rad.abs() < std::f64::consts::FRAC_PI_2 - 1e-6;
        if !lat_ok || !p.lon_rad.is_finite() || !p.h_m.is_finite() {
            return bad("pos", "must be finite with |lat| < 90°");
        }
        for (field, v) in [
            ("v_ned_mps", &self.v_ned_mps),
            ("e_gyr_rps", &self.priors.e_gyr_rps),
            ("e_acc_mps2", &self.priors.e_acc_mps2),
            ("e_mag_nt", &self.priors.e_mag_nt),
            ("delta_b_n_nt", &self.priors.delta_b_n_nt),
        ] {
            if !finite3(v) {
                return bad(field, "must be finite");
            }
        }
        for (field, v) in [
            ("e_gyr_sigma_rps", &self.priors.e_gyr_sigma_rps),
            ("e_acc_sigma_mps2", &self.priors.e_acc_sigma_mps2),
            ("e_mag_sigma_nt", &self.priors.e_mag_sigma_nt),
            ("delta_b_n_sigma_nt", &self.priors.delta_b_n_sigma_nt),
        ] {
            if !sigma3(v) {
                return bad(field, "must be finite and non-negative");
            }
        }
        if !self.aoa_rad.is_finite() {
            return bad("aoa_rad", "must be finite");
        }
        Ok(())
    }
}

/// Covariances reported with each solution (first-order, from the filters).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsCovariance {
    /// Attitude error `δθ` with `q_nb = q̂_nb ∘ Exp(δθ)` (body tangent), rad²: the attitude
    /// filter's covariance plus the tilt implied by the accelerometer-error uncertainty.
    pub attitude_rad2: Matrix3<f64>,
    /// Body rate `w_nb_b`, (rad/s)².
    pub w_nb_b_rad2ps2: Matrix3<f64>,
    /// Gyro error `E_gyr`, (rad/s)².
    pub e_gyr_rad2ps2: Matrix3<f64>,
    /// NED ground velocity, (m/s)².
    pub velocity_m2ps2: Matrix3<f64>,
    /// NED position, m² (in GNSS-denied mode: horizontal dead-reckoning block and barometric
    /// vertical variance, uncorrelated).
    pub position_m2: Matrix3<f64>,
    /// Low-frequency wind, NED, (m/s)².
    pub wind_m2ps2: Matrix3<f64>,
    /// Air-data filter `[v_TAS, α, β, T, Hp, ROC, v̇_TAS, α̇, β̇]` (SI units, rad).
    pub air_data: SMatrix<f64, 9, 9>,
    /// Temperature offset ΔT, K².
    pub delta_t_k2: f64,
    /// Pressure offset Δp, Pa².
    pub delta_p_pa2: f64,
}

/// The navigation solution after one IMU step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsSolution {
    /// Time of the IMU sample, µs.
    pub t_us: u64,
    /// Length of the step that produced this solution, s (0 for the initial solution).
    pub dt_s: f64,
    /// The step bridged an IMU gap longer than `imu_gap_s` (propagated in sub-steps).
    pub imu_gap: bool,
    /// Geodetic position (height above the ellipsoid; barometric when GNSS-denied).
    pub pos: Geodetic,
    /// NED ground velocity, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Attitude, body to NED.
    pub q_nb: UnitQuaternion<f64>,
    /// Body rate with respect to NED, body axes, rad/s.
    pub w_nb_b_rps: Vector3<f64>,
    /// Pressure altitude, m.
    pub hp_m: f64,
    /// Rate of climb (pressure-altitude rate), m/s.
    pub roc_mps: f64,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Angle of attack, rad.
    pub aoa_rad: f64,
    /// Angle of sideslip, rad.
    pub aos_rad: f64,
    /// Outside air temperature, K.
    pub temp_k: f64,
    /// Temperature offset ΔT, K.
    pub delta_t_k: f64,
    /// Pressure offset Δp, Pa (frozen when GNSS-denied).
    pub delta_p_pa: f64,
    /// Low-frequency wind, NED, m/s (frozen when GNSS-denied).
    pub wind_ned_mps: Vector3<f64>,
    /// Specific force estimate, body, m/s².
    pub f_ib_b_mps2: Vector3<f64>,
    /// Gyro error estimate `E_gyr`, rad/s.
    pub e_gyr_rps: Vector3<f64>,
    /// Accelerometer error estimate `E_acc`, m/s².
    pub e_acc_mps2: Vector3<f64>,
    /// Magnetometer error estimate `E_mag`, nT.
    pub e_mag_nt: Vector3<f64>,
    /// Magnetic-model error estimate `ΔB_n`, nT.
    pub delta_b_n_nt: Vector3<f64>,
    /// The reference attitude's slowly varying error estimate `ε̂` (transfer alignment,
    /// `q_ref = q_nb ∘ Exp(ε)`), body axes, rad; zero without references.
    pub ref_attitude_err_rad: Vector3<f64>,
    /// GNSS-denied mode (latched once entered).
    pub gnss_denied: bool,
    /// Normalised innovation squared of the GNSS fix processed at this step (fused or gated;
    /// 6 degrees of freedom), for consistency monitoring.
    pub gnss_nis: Option<f64>,
    /// Covariances.
    pub cov: InsCovariance,
}

/// Counters of one sensor kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct SensorCounters {
    /// Samples accepted (validated and in order).
    pub accepted: u64,
    /// Samples rejected as non-finite or physically impossible.
    pub rejected_invalid: u64,
    /// Samples rejected for a timestamp not after the previous accepted one of the same kind
    /// (duplicate or out of order).
    pub rejected_time: u64,
}

/// Counters of the INS, see [`super::Ins::stats`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct InsStats {
    /// IMU samples.
    pub imu: SensorCounters,
    /// Air-data samples.
    pub air: SensorCounters,
    /// Magnetometer samples.
    pub mag: SensorCounters,
    /// GNSS fixes.
    pub gnss: SensorCounters,
    /// IMU samples dropped because no air-data sample had arrived yet to initialise.
    pub imu_before_init: u64,
    /// IMU steps longer than `imu_gap_s` (propagated in sub-steps and flagged).
    pub imu_gaps: u64,
    /// IMU samples refused because they came more than [`super::MAX_PROPAGATED_INTERVAL_S`] after
    /// the last step (also counted in `imu.rejected_time`).
    pub imu_interval_too_long: u64,
    /// GNSS fixes fused.
    pub gnss_fused: u64,
    /// GNSS fixes refused by the innovation gate.
    pub gnss_gated: u64,
    /// GNSS fixes not fused because they were older than `gnss_max_lag_s` at their step, or
    /// superseded by a newer fix before a step.
    pub gnss_stale: u64,
    /// GNSS fixes received after the switch to GNSS-denied mode (not used).
    pub gnss_after_loss: u64,
    /// Reference attitudes (transfer alignment).
    pub ref_attitude: SensorCounters,
    /// Reference attitudes fused.
    pub ref_attitude_fused: u64,
    /// Reference attitudes refused by the innovation gate.
    pub ref_attitude_gated: u64,
    /// Attitude restarts at the reference after `alignment.max_consecutive_rejections`
    /// gated references in a row.
    pub ref_attitude_resets: u64,
    /// Reference attitudes not used: alignment disabled, GNSS-denied mode, within
    /// `alignment.min_interval_s` of the last fused one, superseded or too old.
    pub ref_attitude_unused: u64,
    /// Camera frames (ignored by the INS).
    pub frames_ignored: u64,
    /// Air or magnetometer samples superseded by a newer one before an IMU step.
    pub superseded: u64,
    /// Filter updates refused for numerical reasons (S not positive definite, non-finite).
    pub numerical_rejections: u64,
    /// Steps without a magnetometer update because the magnetic model failed.
    pub mag_model_errors: u64,
    /// IMU step at which GNSS-denied mode started (µs), if it has.
    pub gnss_denied_since_us: Option<u64>,
}
