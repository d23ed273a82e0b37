//! GNSS-denied EKF inertial navigation (paper: the INS of Gallo & Barrientos; docs/REFERENCES.md A1):
//! a cascade of three filters stepped on every IMU sample — air data (A1.4), attitude (A1.5),
//! and position with GNSS (A1.6) or, after GNSS loss, the GNSS-denied propagation (A1.7).
//! Design, models, noise values and the deviations from the authors' code: `docs/INS.md`.
//!
//! ```text
//! push(event) ── Air / Mag / Gnss: validate, keep the latest (used at the next IMU step)
//!             └─ Imu: validate → Δt from the timestamps (gaps sub-stepped, flagged)
//!                 1. air-data filter: predict, update with the new air sample
//!                 2. attitude filter: predict, update with gyro, accel, new mag sample,
//!                    using the previous step's position, velocity, wind and E_acc
//!                 3. GNSS mode: position filter predict, accel update, GNSS update (gated);
//!                    Δp and wind low-pass filters.
//!                    Denied mode (no valid fix for > gnss_timeout_s): 6-state [f, E_acc]
//!                    EKF + dead reckoning with the frozen wind and Δp.
//!                 → InsSolution
//! ```

mod air_data;
mod attitude;
mod config;
mod ekf;
pub mod imu_noise;
mod position;
#[cfg(test)]
mod tests;

use nalgebra::{Matrix2, Matrix3, SMatrix, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

pub use config::{
    AirDataFilterConfig, AlignmentConfig, AttitudeFilterConfig, InputLimits, InsConfig,
    InsConfigError, PositionFilterConfig,
};

use crate::env::magnetic::{MagneticError, MagneticGrid, MagneticModel};
use crate::math::so3;
use crate::math::wgs84::{self, Geodetic};
use crate::sensors::{AirSample, GnssFix, ImuSample, MagSample, RefAttitude, SensorEvent};
use air_data::AirDataFilter;
use attitude::{AttitudeContext, AttitudeFilter, AttitudeInit, ReferenceErrorModel};
pub use position::DeniedBudget;
use position::{DeniedNav, GnssFilter, GnssPhaseEstimates, PositionInit};

/// Largest number of propagation sub-steps of one IMU interval (bounds the work of a very
/// long gap; beyond `MAX_SUBSTEPS · max_substep_s` the sub-steps get longer).
const MAX_SUBSTEPS: u32 = 10_000;
/// IMU intervals longer than this are refused, not propagated, s. Dead reckoning over a gap
/// means nothing beyond a few seconds; a stamp days ahead (a corrupt or misread time) stepped
/// the INS over the whole gap to latitudes past ±90° and NaN (found by the fuzzer,
/// docs/RELIABILITY.md). A driver whose time really jumped re-initialises the INS.
pub const MAX_PROPAGATED_INTERVAL_S: f64 = 30.0;
/// Microseconds per second.
const US_PER_S: f64 = 1e6;

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
    /// Initial gyro error estimate `E_gyr`, rad/s.
    pub e_gyr_rps: Vector3<f64>,
    /// σ of the gyro error estimate per axis, rad/s.
    pub e_gyr_sigma_rps: Vector3<f64>,
    /// Initial accelerometer error estimate `E_acc`, m/s².
    pub e_acc_mps2: Vector3<f64>,
    /// σ of the accelerometer error estimate per axis, m/s².
    pub e_acc_sigma_mps2: Vector3<f64>,
    /// Initial magnetometer error estimate `E_mag`, nT.
    pub e_mag_nt: Vector3<f64>,
    /// σ of the magnetometer error estimate per axis, nT.
    pub e_mag_sigma_nt: Vector3<f64>,
    /// Initial magnetic-model error estimate `ΔB_n = B_model − B_true`, NED, nT.
    pub delta_b_n_nt: Vector3<f64>,
    /// σ of the magnetic-model error estimate per axis, nT.
    pub delta_b_n_sigma_nt: Vector3<f64>,
    /// Angle of attack assumed while no AoA vane reading exists, rad.
    pub aoa_rad: f64,
    /// Epoch of the World Magnetic Model, decimal year (within WMM2025's validity).
    pub mag_decimal_year: f64,
    /// Time of validity of `pos` and `v_ned_mps` (the fix's time), µs. The INS starts at its
    /// first IMU sample, which can be later (a slow stream, a lagged fix): it carries position
    /// and velocity there with that sample's acceleration. `None`: valid at that first sample.
    pub valid_at_us: Option<u64>,
}

impl InsInit {
    /// Cold start: zero sensor-error estimates with the cold-start σ (`COLD_*`).
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
            e_gyr_rps: Vector3::zeros(),
            e_gyr_sigma_rps: Vector3::repeat(COLD_E_GYR_SIGMA_RPS),
            e_acc_mps2: Vector3::zeros(),
            e_acc_sigma_mps2: Vector3::repeat(COLD_E_ACC_SIGMA_MPS2),
            e_mag_nt: Vector3::zeros(),
            e_mag_sigma_nt: Vector3::repeat(COLD_E_MAG_SIGMA_NT),
            delta_b_n_nt: Vector3::zeros(),
            delta_b_n_sigma_nt: Vector3::from(COLD_DELTA_B_SIGMA_NT),
            aoa_rad: 0.0,
            mag_decimal_year,
            valid_at_us: None,
        }
    }

    fn validate(&self) -> Result<(), InsError> {
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
            ("e_gyr_rps", &self.e_gyr_rps),
            ("e_acc_mps2", &self.e_acc_mps2),
            ("e_mag_nt", &self.e_mag_nt),
            ("delta_b_n_nt", &self.delta_b_n_nt),
        ] {
            if !finite3(v) {
                return bad(field, "must be finite");
            }
        }
        for (field, v) in [
            ("e_gyr_sigma_rps", &self.e_gyr_sigma_rps),
            ("e_acc_sigma_mps2", &self.e_acc_sigma_mps2),
            ("e_mag_sigma_nt", &self.e_mag_sigma_nt),
            ("delta_b_n_sigma_nt", &self.delta_b_n_sigma_nt),
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

/// Counters of the INS, see [`Ins::stats`].
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
    /// IMU samples refused because they came more than [`MAX_PROPAGATED_INTERVAL_S`] after
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

/// Position part of the cascade.
#[derive(Debug, Clone)]
enum PositionMode {
    Gnss {
        filter: Box<GnssFilter>,
        est: Box<GnssPhaseEstimates>,
    },
    Denied(Box<DeniedNav>),
}

/// Outputs of the previous step used by the attitude filter (docs/REFERENCES.md A1.5).
#[derive(Debug, Clone, Copy)]
struct PrevOutputs {
    pos: Geodetic,
    v_n: Vector3<f64>,
    wind_n: Vector3<f64>,
    e_acc: Vector3<f64>,
}

/// The running filters.
#[derive(Debug, Clone)]
struct Core {
    t_us: u64,
    /// Estimated nominal IMU period (first non-gap Δt, then low-passed), s.
    imu_period_s: f64,
    /// IMU steps since the initialisation.
    imu_steps: u64,
    air: AirDataFilter,
    att: AttitudeFilter,
    position: PositionMode,
    prev: PrevOutputs,
    /// Time of the last valid GNSS fix (or of the initialisation), µs.
    last_fix_us: u64,
    consecutive_gated: u32,
    /// Time of validity of the last fused reference attitude, µs.
    last_ref_attitude_us: Option<u64>,
    consecutive_ref_gated: u32,
}

/// The INS. Feed time-ordered [`SensorEvent`]s to [`Ins::push`]; every accepted IMU sample
/// (after the first air-data sample) produces an [`InsSolution`].
#[derive(Debug, Clone)]
pub struct Ins {
    cfg: InsConfig,
    init: InsInit,
    mag: MagneticGrid,
    stats: InsStats,
    last_imu_us: Option<u64>,
    last_air_us: Option<u64>,
    last_mag_us: Option<u64>,
    last_gnss_us: Option<u64>,
    last_ref_attitude_us: Option<u64>,
    pending_air: Option<AirSample>,
    pending_mag: Option<MagSample>,
    pending_gnss: Option<GnssFix>,
    pending_ref_attitude: Option<RefAttitude>,
    core: Option<Box<Core>>,
}

/// Number of IMU periods over which the nominal period estimate is averaged.
const IMU_PERIOD_AVERAGING: f64 = 50.0;

impl Ins {
    /// Build the INS. Fails on an invalid configuration, initial estimate or magnetic epoch.
    pub fn new(config: &InsConfig, init: &InsInit) -> Result<Self, InsError> {
        config.validate()?;
        init.validate()?;
        let model = MagneticModel::new(init.mag_decimal_year)?;
        Ok(Self {
            cfg: config.clone(),
            init: *init,
            mag: MagneticGrid::new(model),
            stats: InsStats::default(),
            last_imu_us: None,
            last_air_us: None,
            last_mag_us: None,
            last_gnss_us: None,
            last_ref_attitude_us: None,
            pending_air: None,
            pending_mag: None,
            pending_gnss: None,
            pending_ref_attitude: None,
            core: None,
        })
    }

    /// Counters of accepted, rejected and gated inputs.
    pub fn stats(&self) -> &InsStats {
        &self.stats
    }

    /// The configuration in use.
    pub fn config(&self) -> &InsConfig {
        &self.cfg
    }

    /// Whether the INS has switched to GNSS-denied mode.
    pub fn gnss_denied(&self) -> bool {
        matches!(
            self.core.as_deref().map(|c| &c.position),
            Some(PositionMode::Denied(_))
        )
    }

    /// What the GNSS-denied covariance started from, once the INS is GNSS-denied.
    pub fn denied_budget(&self) -> Option<&DeniedBudget> {
        match self.core.as_deref().map(|c| &c.position) {
            Some(PositionMode::Denied(d)) => Some(d.budget()),
            _ => None,
        }
    }

    /// Feed one event. Air, magnetometer and GNSS samples are validated and kept for the next
    /// IMU step; an IMU sample steps the filters and returns the solution. Invalid or
    /// out-of-order samples are counted in [`Ins::stats`] and ignored.
    pub fn push(&mut self, event: &SensorEvent) -> Option<InsSolution> {
        match event {
            SensorEvent::Imu(s) => self.push_imu(s),
            SensorEvent::Air(s) => {
                if accept(
                    &mut self.stats.air,
                    &mut self.last_air_us,
                    s.t_us,
                    valid_air(&self.cfg.limits, s),
                ) && self.pending_air.replace(*s).is_some()
                {
                    self.stats.superseded += 1;
                }
                None
            }
            SensorEvent::Mag(s) => {
                if accept(
                    &mut self.stats.mag,
                    &mut self.last_mag_us,
                    s.t_us,
                    valid_mag(&self.cfg.limits, s),
                ) && self.pending_mag.replace(*s).is_some()
                {
                    self.stats.superseded += 1;
                }
                None
            }
            SensorEvent::Gnss(s) => {
                if accept(
                    &mut self.stats.gnss,
                    &mut self.last_gnss_us,
                    s.t_us,
                    valid_gnss(&self.cfg.limits, s),
                ) {
                    if self.gnss_denied() {
                        self.stats.gnss_after_loss += 1;
                    } else {
                        if let Some(core) = self.core.as_deref_mut() {
                            core.last_fix_us = core.last_fix_us.max(s.t_us);
                        }
                        if self.pending_gnss.replace(*s).is_some() {
                            self.stats.gnss_stale += 1;
                        }
                    }
                }
                None
            }
            SensorEvent::RefAttitude(s) => {
                if accept(
                    &mut self.stats.ref_attitude,
                    &mut self.last_ref_attitude_us,
                    s.t_us,
                    valid_ref_attitude(s),
                ) {
                    // Unused: alignment off, GNSS lost, or a newer one supersedes it.
                    let usable = self.cfg.alignment.enabled && !self.gnss_denied();
                    if !usable || self.pending_ref_attitude.replace(*s).is_some() {
                        self.stats.ref_attitude_unused += 1;
                    }
                }
                None
            }
            SensorEvent::Frame(_) => {
                self.stats.frames_ignored += 1;
                None
            }
            // Start alignments are the navigator's (`nav::policy`), not the running INS's.
            SensorEvent::Alignment(_) => None,
        }
    }

    fn push_imu(&mut self, s: &ImuSample) -> Option<InsSolution> {
        // Before the ordering gate, which would otherwise take the outlier's time as the
        // latest and refuse every good sample after it.
        // The first sample is measured from the initial state's time of validity (its carry
        // over a fix's age would otherwise run over the whole gap).
        let last_us = match (self.core.as_deref(), self.init.valid_at_us) {
            (Some(core), _) => Some(core.t_us),
            (None, valid_at_us) => valid_at_us,
        };
        if let Some(last_us) = last_us
            && s.t_us.abs_diff(last_us) as f64 / US_PER_S > MAX_PROPAGATED_INTERVAL_S
            && (self.core.is_none() || s.t_us > last_us)
        {
            self.stats.imu.rejected_time += 1;
            self.stats.imu_interval_too_long += 1;
            return None;
        }
        if !accept(
            &mut self.stats.imu,
            &mut self.last_imu_us,
            s.t_us,
            valid_imu(&self.cfg.limits, s),
        ) {
            return None;
        }
        let Some(core) = self.core.as_deref_mut() else {
            return self.initialise(s);
        };
        let dt_s = (s.t_us - core.t_us) as f64 / US_PER_S;
        let gap = dt_s > self.cfg.imu_gap_s;
        if gap {
            self.stats.imu_gaps += 1;
        } else if core.imu_steps == 0 {
            core.imu_period_s = dt_s;
        } else {
            core.imu_period_s += (dt_s - core.imu_period_s) / IMU_PERIOD_AVERAGING;
        }
        core.imu_steps += 1;
        let n_sub = ((dt_s / self.cfg.max_substep_s).ceil() as u32).clamp(1, MAX_SUBSTEPS);
        let step = Step {
            t_us: s.t_us,
            dt_s,
            dt_sub_s: dt_s / f64::from(n_sub),
            n_sub,
            q_scale_sub: dt_s / f64::from(n_sub) / self.cfg.reference_period_s,
            r_scale: self.cfg.reference_period_s / core.imu_period_s,
            gap,
        };
        let air = self.pending_air.take();
        let mag = self.pending_mag.take();
        let fix = self.pending_gnss.take();
        let ref_att = self.pending_ref_attitude.take();
        let sol = run_step(
            &self.cfg,
            core,
            &mut self.mag,
            &mut self.stats,
            &step,
            s,
            Aiding {
                air: air.as_ref(),
                mag: mag.as_ref(),
                fix: fix.as_ref(),
                ref_attitude: ref_att.as_ref(),
            },
        );
        Some(sol)
    }

    /// First IMU sample with an air-data sample available: build the filters.
    fn initialise(&mut self, s: &ImuSample) -> Option<InsSolution> {
        let Some(air_sample) = self.pending_air.take() else {
            self.stats.imu_before_init += 1;
            return None;
        };
        let cfg = &self.cfg;
        let init = &self.init;
        // Carried over the fix's age at the acceleration of this first sample (C_nb f + g:
        // a take-off roll at 8 m/s² gains 2.4 m/s over a 0.3 s old fix).
        let (init_pos, init_v) = match init.valid_at_us {
            Some(t0_us) => {
                let dt_s = (s.t_us as f64 - t0_us as f64) / US_PER_S;
                let a_n = init.q_nb * (s.accel_mps2 - init.e_acc_mps2)
                    + wgs84::gravity_ned_mps2(&init.pos);
                let v_mid = init.v_ned_mps + a_n * (dt_s / 2.0);
                let rates = wgs84::geodetic_rates(&init.pos, &v_mid);
                let pos = Geodetic {
                    lat_rad: init.pos.lat_rad + rates.x * dt_s,
                    lon_rad: init.pos.lon_rad + rates.y * dt_s,
                    h_m: init.pos.h_m + rates.z * dt_s,
                };
                (pos, init.v_ned_mps + a_n * dt_s)
            }
            None => (init.pos, init.v_ned_mps),
        };
        let air = AirDataFilter::new(&cfg.air, &air_sample, init.aoa_rad);
        let w_in_n = wgs84::omega_ie_n(init_pos.lat_rad) + wgs84::omega_en_n(&init_pos, &init_v);
        let att = AttitudeFilter::new(
            &cfg.attitude,
            &AttitudeInit {
                q_nb: init.q_nb,
                w_nb_b: s.gyro_rps - init.e_gyr_rps - init.q_nb.inverse() * w_in_n,
                e_gyr: init.e_gyr_rps,
                e_gyr_sigma: init.e_gyr_sigma_rps,
                e_mag: init.e_mag_nt,
                e_mag_sigma: init.e_mag_sigma_nt,
                delta_b_n: init.delta_b_n_nt,
                delta_b_n_sigma: init.delta_b_n_sigma_nt,
            },
            ReferenceErrorModel {
                var_rad2: Vector3::from(cfg.alignment.ref_error_sigma_deg.map(f64::to_radians))
                    .map(|s| s * s),
                time_s: cfg.alignment.ref_error_time_s,
            },
        );
        let gnss = GnssFilter::new(
            &cfg.position,
            &PositionInit {
                pos: init_pos,
                v_n: init_v,
                f_b: s.accel_mps2 - init.e_acc_mps2,
                e_acc: init.e_acc_mps2,
                e_acc_sigma: init.e_acc_sigma_mps2,
            },
        );
        let (v_air, v_air_cov) = position::air_velocity_n(
            &att.q_nb(),
            air.state(),
            &air.covariance_without_held_angles(),
        );
        let wind = gnss.v_n() - v_air;
        let est = GnssPhaseEstimates::new(
            cfg.position.lpf_window_s,
            cfg.position.turbulence_integral_scale_m,
            &att.q_nb(),
            air.state()[air_data::HP],
            air.covariance()[(air_data::HP, air_data::HP)],
            gnss.pos().h_m,
            gnss.position_cov_with_bias(&cfg.position)[(2, 2)],
            air.delta_t_k(),
            wind,
            gnss.velocity_cov() + v_air_cov,
            v_air,
        );
        let prev = PrevOutputs {
            pos: gnss.pos(),
            v_n: gnss.v_n(),
            wind_n: wind,
            e_acc: gnss.e_acc(),
        };
        // A fix that arrived before the first IMU sample is used at the next step.
        let last_fix_us = self.pending_gnss.map_or(s.t_us, |f| f.t_us.max(s.t_us));
        let core = Core {
            t_us: s.t_us,
            imu_period_s: cfg.reference_period_s,
            imu_steps: 0,
            air,
            att,
            position: PositionMode::Gnss {
                filter: Box::new(gnss),
                est: Box::new(est),
            },
            prev,
            last_fix_us,
            consecutive_gated: 0,
            last_ref_attitude_us: None,
            consecutive_ref_gated: 0,
        };
        let sol = solution(cfg, &core, 0.0, false, None, s);
        self.pending_mag = None;
        if self.pending_ref_attitude.take().is_some() {
            self.stats.ref_attitude_unused += 1;
        }
        self.core = Some(Box::new(core));
        Some(sol)
    }
}

/// Timing of one IMU step.
#[derive(Debug, Clone, Copy)]
struct Step {
    t_us: u64,
    dt_s: f64,
    dt_sub_s: f64,
    n_sub: u32,
    /// `dt_sub / reference_period`: scale of the per-step Q̃ for one sub-step.
    q_scale_sub: f64,
    /// `reference_period / nominal IMU period`: scale of the IMU white-noise R.
    r_scale: f64,
    gap: bool,
}

/// The aiding samples consumed by one IMU step.
#[derive(Debug, Clone, Copy)]
struct Aiding<'a> {
    air: Option<&'a AirSample>,
    mag: Option<&'a MagSample>,
    fix: Option<&'a GnssFix>,
    ref_attitude: Option<&'a RefAttitude>,
}

/// One cascade step (module doc).
fn run_step(
    cfg: &InsConfig,
    core: &mut Core,
    mag_model: &mut MagneticGrid,
    stats: &mut InsStats,
    step: &Step,
    imu: &ImuSample,
    aiding: Aiding<'_>,
) -> InsSolution {
    let Aiding {
        air,
        mag,
        fix,
        ref_attitude,
    } = aiding;
    // GNSS loss: no valid fix for longer than the timeout, or too many gated in a row.
    if let PositionMode::Gnss { filter, est } = &core.position {
        let since_fix_s = step.t_us.saturating_sub(core.last_fix_us) as f64 / US_PER_S;
        if since_fix_s > cfg.position.gnss_timeout_s
            || core.consecutive_gated >= cfg.position.gnss_max_consecutive_rejections
        {
            let c_nb = core.att.q_nb().to_rotation_matrix().into_inner();
            let att_cov_n = c_nb
                * core
                    .att
                    .covariance()
                    .fixed_view::<3, 3>(attitude::TH, attitude::TH)
                * c_nb.transpose();
            core.position = PositionMode::Denied(Box::new(DeniedNav::new(
                &cfg.position,
                &cfg.air,
                core.air.state(),
                core.air.held_angles(),
                &att_cov_n,
                filter,
                est,
            )));
            stats.gnss_denied_since_us = Some(step.t_us);
        }
    }

    // 1. Air data.
    let numerical_before = core.air.numerical_rejections;
    for _ in 0..step.n_sub {
        core.air.predict(&cfg.air, step.dt_sub_s, step.q_scale_sub);
    }
    if let Some(a) = air {
        core.air.update(&cfg.air, a);
    }
    stats.numerical_rejections += core.air.numerical_rejections - numerical_before;

    // 2. Attitude, with the previous step's outputs.
    let prev = core.prev;
    let w_ie = wgs84::omega_ie_n(prev.pos.lat_rad);
    let w_en = wgs84::omega_en_n(&prev.pos, &prev.v_n);
    let b_model_n = match mag_model.field_ned_nt(&prev.pos) {
        Ok(b) => Some(b),
        Err(_) => {
            stats.mag_model_errors += 1;
            None
        }
    };
    let ctx = AttitudeContext {
        w_in_n: w_ie + w_en,
        a_n: w_en.cross(&prev.v_n) + (w_ie * 2.0).cross(&prev.v_n)
            - wgs84::gravity_ned_mps2(&prev.pos),
        v_tashf_n: prev.v_n - prev.wind_n,
        e_acc_b: prev.e_acc,
        b_model_n,
    };
    for _ in 0..step.n_sub {
        core.att
            .predict(&cfg.attitude, step.dt_sub_s, step.q_scale_sub);
    }
    if core
        .att
        .update(
            &cfg.attitude,
            &ctx,
            &imu.gyro_rps,
            &imu.accel_mps2,
            mag.map(|m| &m.mag_b_nt),
            step.r_scale,
        )
        .is_err()
    {
        stats.numerical_rejections += 1;
    }
    if let Some(r) = ref_attitude {
        fuse_ref_attitude(cfg, core, stats, step.t_us, r);
    }
    let q_nb = core.att.q_nb();
    let (v_air, v_air_cov) = position::air_velocity_n(
        &q_nb,
        core.air.state(),
        &core.air.covariance_without_held_angles(),
    );
    let delta_t_k = core.air.delta_t_k();
    let hp_m = core.air.state()[air_data::HP];

    // 3. Position.
    let mut gnss_nis = None;
    match &mut core.position {
        PositionMode::Gnss { filter, est } => {
            for _ in 0..step.n_sub {
                filter.predict(&cfg.position, &q_nb, step.dt_sub_s, step.q_scale_sub);
            }
            if filter
                .update_accel(&cfg.position, &imu.accel_mps2, step.r_scale)
                .is_err()
            {
                stats.numerical_rejections += 1;
            }
            if let Some(fix) = fix {
                let lag_s = (step.t_us as f64 - fix.t_us as f64) / US_PER_S;
                if lag_s.abs() > cfg.position.gnss_max_lag_s {
                    stats.gnss_stale += 1;
                } else {
                    match filter.update_gnss(&cfg.position, fix, lag_s, &q_nb, &core.att.w_nb_b()) {
                        Ok(nis) => {
                            stats.gnss_fused += 1;
                            core.consecutive_gated = 0;
                            gnss_nis = Some(nis);
                        }
                        Err(ekf::UpdateRejection::Gated { nis }) => {
                            gnss_nis = Some(nis);
                            stats.gnss_gated += 1;
                            core.consecutive_gated += 1;
                        }
                        Err(ekf::UpdateRejection::Numerical) => {
                            stats.numerical_rejections += 1;
                        }
                    }
                }
            }
            filter.record(step.t_us, cfg.position.gnss_max_lag_s);
            let p_air = core.air.covariance();
            est.step(
                step.dt_s,
                &q_nb,
                core.air.state()[air_data::TAS],
                hp_m,
                p_air[(air_data::HP, air_data::HP)],
                filter.pos().h_m,
                filter.position_cov_with_bias(&cfg.position)[(2, 2)],
                delta_t_k,
                filter.v_n() - v_air,
                filter.velocity_cov() + v_air_cov,
                v_air,
            );
            core.prev = PrevOutputs {
                pos: filter.pos(),
                v_n: filter.v_n(),
                wind_n: est.wind().0,
                e_acc: filter.e_acc(),
            };
        }
        PositionMode::Denied(nav) => {
            let q_scale = step.dt_s / cfg.reference_period_s;
            if nav
                .filter_accel(&cfg.position, &imu.accel_mps2, q_scale, step.r_scale)
                .is_err()
            {
                stats.numerical_rejections += 1;
            }
            let p_air = core.air.covariance();
            let t_hp = Matrix2::new(
                p_air[(air_data::TEMP, air_data::TEMP)],
                p_air[(air_data::TEMP, air_data::HP)],
                p_air[(air_data::HP, air_data::TEMP)],
                p_air[(air_data::HP, air_data::HP)],
            );
            nav.propagate(
                &cfg.position,
                &q_nb,
                core.air.state()[air_data::TAS],
                &v_air,
                &v_air_cov,
                hp_m,
                delta_t_k,
                &t_hp,
                step.dt_sub_s,
                step.n_sub,
                step.q_scale_sub,
            );
            core.prev = PrevOutputs {
                pos: nav.pos(),
                v_n: nav.v_n(),
                wind_n: nav.wind().0,
                e_acc: nav.e_acc(),
            };
        }
    }
    core.t_us = step.t_us;
    solution(cfg, core, step.dt_s, step.gap, gnss_nis, imu)
}

/// Transfer alignment (`AlignmentConfig`): fuse the reference attitude if the INS is in its
/// GNSS phase, the last fused one is at least `min_interval_s` older and it is recent.
fn fuse_ref_attitude(
    cfg: &InsConfig,
    core: &mut Core,
    stats: &mut InsStats,
    t_us: u64,
    r: &RefAttitude,
) {
    let a = &cfg.alignment;
    let lag_s = (t_us as f64 - r.t_us as f64) / US_PER_S;
    let due = core
        .last_ref_attitude_us
        .is_none_or(|last| (r.t_us.saturating_sub(last) as f64) / US_PER_S >= a.min_interval_s);
    let gnss_phase = matches!(core.position, PositionMode::Gnss { .. });
    if !gnss_phase || !due || lag_s.abs() > a.max_lag_s {
        stats.ref_attitude_unused += 1;
        return;
    }
    let var = a.ref_attitude_sigma_deg.to_radians().powi(2);
    match core.att.update_reference(&r.q_nb, lag_s, var, a.gate_chi2) {
        Ok(_) => {
            stats.ref_attitude_fused += 1;
            core.consecutive_ref_gated = 0;
            core.last_ref_attitude_us = Some(r.t_us);
        }
        Err(ekf::UpdateRejection::Gated { .. }) => {
            stats.ref_attitude_gated += 1;
            core.consecutive_ref_gated += 1;
            // Decimated like the fused ones, so the restart takes that many intervals.
            core.last_ref_attitude_us = Some(r.t_us);
            if core.consecutive_ref_gated >= a.max_consecutive_rejections {
                let q_then = r.q_nb * so3::exp(&(core.att.w_nb_b() * lag_s));
                core.att.reset_attitude(&q_then, var);
                core.consecutive_ref_gated = 0;
                stats.ref_attitude_resets += 1;
            }
        }
        Err(ekf::UpdateRejection::Numerical) => stats.numerical_rejections += 1,
    }
}

/// Assemble the solution from the filters.
fn solution(
    cfg: &InsConfig,
    core: &Core,
    dt_s: f64,
    gap: bool,
    gnss_nis: Option<f64>,
    imu: &ImuSample,
) -> InsSolution {
    let ax = core.air.state();
    let pa = core.att.covariance();
    let (pos, v_n, f_b, e_acc, wind, dp, p_pos, p_vel, p_eacc, gnss_denied) = match &core.position {
        PositionMode::Gnss { filter, est } => (
            filter.pos(),
            filter.v_n(),
            filter.f_b(),
            filter.e_acc(),
            est.wind(),
            est.delta_p(),
            filter.position_cov_with_bias(&cfg.position),
            filter.velocity_cov(),
            filter.e_acc_cov(),
            false,
        ),
        PositionMode::Denied(nav) => (
            nav.pos(),
            nav.v_n(),
            nav.f_b(),
            nav.e_acc(),
            nav.wind(),
            nav.delta_p(),
            nav.position_cov(),
            nav.velocity_cov(),
            nav.e_acc_cov(),
            true,
        ),
    };
    let block = |i: usize| -> Matrix3<f64> { pa.fixed_view::<3, 3>(i, i).into_owned() };
    // The attitude filter takes E_acc as known; an error δE in it tilts the attitude by
    // δθ = −[f]× δE / |f|² (the rotation that explains δE as a turn of the specific force),
    // a persistent error its own covariance does not contain.
    let f_norm2 = f_b.norm_squared();
    let tilt_from_eacc = if f_norm2 > 1.0 {
        let j = -so3::skew(&f_b) / f_norm2;
        let c = j * p_eacc * j.transpose();
        (c + c.transpose()) * 0.5
    } else {
        Matrix3::zeros()
    };
    InsSolution {
        t_us: imu.t_us,
        dt_s,
        imu_gap: gap,
        pos,
        v_ned_mps: v_n,
        q_nb: core.att.q_nb(),
        w_nb_b_rps: core.att.w_nb_b(),
        hp_m: ax[air_data::HP],
        roc_mps: ax[air_data::ROC],
        tas_mps: ax[air_data::TAS],
        aoa_rad: ax[air_data::AOA],
        aos_rad: ax[air_data::AOS],
        temp_k: ax[air_data::TEMP],
        delta_t_k: core.air.delta_t_k(),
        delta_p_pa: dp.0,
        wind_ned_mps: wind.0,
        f_ib_b_mps2: f_b,
        e_gyr_rps: core.att.e_gyr(),
        e_acc_mps2: e_acc,
        e_mag_nt: core.att.e_mag(),
        delta_b_n_nt: core.att.delta_b_n(),
        ref_attitude_err_rad: core.att.ref_err(),
        gnss_denied,
        gnss_nis,
        cov: InsCovariance {
            attitude_rad2: block(attitude::TH) + tilt_from_eacc,
            w_nb_b_rad2ps2: block(attitude::W),
            e_gyr_rad2ps2: block(attitude::EG),
            velocity_m2ps2: p_vel,
            position_m2: p_pos,
            wind_m2ps2: wind.1,
            air_data: *core.air.covariance(),
            delta_t_k2: core.air.delta_t_var_k2(),
            delta_p_pa2: dp.1,
        },
    }
}

/// Count and filter a sample: valid and strictly after the previous accepted one of its kind.
fn accept(
    counters: &mut SensorCounters,
    last_us: &mut Option<u64>,
    t_us: u64,
    valid: bool,
) -> bool {
    if !valid {
        counters.rejected_invalid += 1;
        return false;
    }
    if last_us.is_some_and(|last| t_us <= last) {
        counters.rejected_time += 1;
        return false;
    }
    *last_us = Some(t_us);
    counters.accepted += 1;
    true
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn valid_imu(l: &InputLimits, s: &ImuSample) -> bool {
    finite3(&s.gyro_rps)
        && finite3(&s.accel_mps2)
        && s.accel_mps2.norm() <= l.max_specific_force_mps2
        && s.gyro_rps.norm() <= l.max_angular_rate_rps
}

fn valid_air(l: &InputLimits, s: &AirSample) -> bool {
    let vane_ok = |a: Option<f64>| {
        a.is_none_or(|a| a.is_finite() && a.abs() <= l.max_vane_angle_deg.to_radians())
    };
    s.tas_mps.is_finite()
        && s.tas_mps >= 0.0
        && s.tas_mps <= l.max_tas_mps
        && s.p_pa.is_finite()
        && s.p_pa > 0.0
        && s.p_pa <= l.max_pressure_pa
        && s.temp_k.is_finite()
        && s.temp_k >= l.min_temp_k
        && s.temp_k <= l.max_temp_k
        && vane_ok(s.aoa_rad)
        && vane_ok(s.aos_rad)
}

fn valid_ref_attitude(s: &RefAttitude) -> bool {
    let q = s.q_nb.quaternion();
    q.coords.iter().all(|x| x.is_finite()) && (q.norm() - 1.0).abs() < 1e-6
}

fn valid_mag(l: &InputLimits, s: &MagSample) -> bool {
    finite3(&s.mag_b_nt) && s.mag_b_nt.norm() <= l.max_mag_nt
}

fn valid_gnss(l: &InputLimits, s: &GnssFix) -> bool {
    let sigma_ok = |x: f64| x.is_finite() && x >= 0.0;
    s.pos.lat_rad.is_finite()
        && s.pos.lat_rad.abs() < std::f64::consts::FRAC_PI_2
        && s.pos.lon_rad.is_finite()
        && s.pos.h_m.is_finite()
        && s.pos.h_m >= l.min_gnss_h_m
        && s.pos.h_m <= l.max_gnss_h_m
        && finite3(&s.v_ned_mps)
        && s.v_ned_mps.norm() <= l.max_gnss_speed_mps
        && sigma_ok(s.sigma_hor_m)
        && sigma_ok(s.sigma_ver_m)
        && sigma_ok(s.sigma_vel_mps)
}
