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
mod input;
mod position;
mod solution;
mod step;
#[cfg(test)]
mod tests;
mod types;

use nalgebra::{Matrix2, Matrix3, Vector3};

pub use config::{
    AirDataFilterConfig, AlignmentConfig, AttitudeFilterConfig, ImuNoiseAdoptionConfig,
    InputLimits, InsConfig, InsConfigError, MAX_BODY_RATE_LAG_S, PositionFilterConfig,
};

use crate::env::magnetic::{MagneticGrid, MagneticModel};
use crate::math::so3;
use crate::math::wgs84::{self, Geodetic};
use crate::sensors::{AirSample, GnssFix, ImuSample, MagSample, RefAttitude, SensorEvent};
use air_data::AirDataFilter;
use attitude::{AttitudeContext, AttitudeFilter, AttitudeInit, ReferenceErrorModel};
use input::{accept, valid_air, valid_gnss, valid_imu, valid_mag, valid_ref_attitude};
pub use position::DeniedBudget;
use position::{DeniedNav, GnssFilter, GnssPhaseEstimates, PositionInit};
use solution::assemble_solution;
use step::run_step;
pub use types::{
    COLD_DELTA_B_SIGMA_NT, COLD_E_ACC_SIGMA_MPS2, COLD_E_GYR_SIGMA_RPS, COLD_E_MAG_SIGMA_NT,
    InsCovariance, InsError, InsInit, InsSolution, InsStats, SensorCounters, cold_priors,
};

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

    /// Use `model` for the IMU's noise from the next step on (the filters read their R and Q̃
    /// each step; nothing else is touched).
    pub fn set_imu_noise(&mut self, model: &imu_noise::ImuNoiseModel) {
        model.apply_to(&mut self.cfg);
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
            // The visual navigation's scale and its results' markers, not INS inputs.
            SensorEvent::HeightAboveTerrain(_) | SensorEvent::VisionApplied(_) => None,
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
                let a_n = init.q_nb * (s.accel_mps2 - init.priors.e_acc_mps2)
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
                w_nb_b: s.gyro_rps - init.priors.e_gyr_rps - init.q_nb.inverse() * w_in_n,
                e_gyr: init.priors.e_gyr_rps,
                e_gyr_sigma: init.priors.e_gyr_sigma_rps,
                e_mag: init.priors.e_mag_nt,
                e_mag_sigma: init.priors.e_mag_sigma_nt,
                delta_b_n: init.priors.delta_b_n_nt,
                delta_b_n_sigma: init.priors.delta_b_n_sigma_nt,
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
                f_b: s.accel_mps2 - init.priors.e_acc_mps2,
                e_acc: init.priors.e_acc_mps2,
                e_acc_sigma: init.priors.e_acc_sigma_mps2,
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
        let est = match cfg.position.airspeed_bias_from_turns {
            true => est.with_airspeed_bias(cfg.position.lpf_window_s),
            false => est,
        };
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
        let sol = assemble_solution(cfg, &core, 0.0, false, None, s);
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
