//! Guidance and control (docs/REFERENCES.md A5), run at 50 Hz on the *navigation estimate*: a
//! mission is a list of operations, each fixing a target per channel and a trigger that ends
//! it; PID loops turn targets into throttle and surface commands.

pub mod config;
pub mod controller;
pub mod guidance;
pub mod pid;

pub use config::{ControlConfig, ControlConfigError, PidConfig};
pub use controller::Controller;
pub use guidance::{Guidance, GuidanceError};

use ianav::math::wgs84::Geodetic;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::aircraft::{AirRelative, TruthState};

/// What guidance and control know about the aircraft: the navigation estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavEstimate {
    /// Time of the estimate, microseconds.
    pub t_us: u64,
    /// Position.
    pub pos: Geodetic,
    /// Ground velocity, NED, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Attitude `q_nb`.
    pub q_nb: UnitQuaternion<f64>,
    /// Body angular velocity relative to NED, body axes, rad/s.
    pub w_nb_b_rps: Vector3<f64>,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Angle of attack, rad.
    pub aoa_rad: f64,
    /// Angle of sideslip, rad.
    pub aos_rad: f64,
    /// Pressure altitude, m.
    pub hp_m: f64,
}

/// Source of the estimate the guidance and control fly on.
pub trait Navigation {
    /// The latest estimate.
    fn estimate(&self) -> NavEstimate;
}

/// Navigation fed from the simulator's *truth* (a stand-in until the INS flies in the loop,
/// and for tests that must not depend on the INS).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthNavigation {
    /// Estimate built from truth.
    pub estimate: NavEstimate,
}

impl TruthNavigation {
    /// Build the estimate from the truth state, its air-relative motion, the transport and
    /// Earth rates and the true pressure altitude.
    pub fn from_truth(
        t_us: u64,
        x: &TruthState,
        air: &AirRelative,
        w_in_n_rps: &Vector3<f64>,
        hp_m: f64,
    ) -> Self {
        let v_ned_mps = x.q_nb * x.v_b_mps;
        let w_nb_b_rps = x.w_ib_b_rps - x.q_nb.inverse() * w_in_n_rps;
        Self {
            estimate: NavEstimate {
                t_us,
                pos: x.pos,
                v_ned_mps,
                q_nb: x.q_nb,
                w_nb_b_rps,
                tas_mps: air.tas_mps,
                aoa_rad: air.aoa_rad,
                aos_rad: air.aos_rad,
                hp_m,
            },
        }
    }
}

impl Navigation for TruthNavigation {
    fn estimate(&self) -> NavEstimate {
        self.estimate
    }
}

/// Elevator channel target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum ElevatorTarget {
    /// Hold pressure altitude, m.
    PressureAltitude {
        /// Target, m.
        hp_m: f64,
    },
    /// Hold the air path angle γ_TAS, rad (climb or descent).
    PathAngle {
        /// Target, rad.
        gamma_rad: f64,
    },
    /// Hold pitch θ, rad.
    Pitch {
        /// Target, rad.
        theta_rad: f64,
    },
}

/// Aileron channel target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum AileronTarget {
    /// Hold ground-track bearing χ = atan2(v_E, v_N), rad.
    Bearing {
        /// Target, rad.
        chi_rad: f64,
    },
    /// Hold bank ξ, rad (turns).
    Bank {
        /// Target, rad.
        xi_rad: f64,
    },
}

/// Condition that ends an operation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Trigger {
    /// Mission time reaches `t_s`.
    Time {
        /// Mission time, s.
        t_s: f64,
    },
    /// `dt_s` have elapsed since the operation started.
    Elapsed {
        /// Duration, s.
        dt_s: f64,
    },
    /// Pressure altitude crosses `hp_m`.
    PressureAltitude {
        /// Threshold, m.
        hp_m: f64,
    },
    /// Ground-track bearing crosses `chi_rad` (wrapped; inactive while more than 90° away).
    Bearing {
        /// Threshold, rad.
        chi_rad: f64,
    },
}

/// One guidance operation: a target per channel (the rudder always holds zero sideslip) and
/// the trigger that ends it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Operation {
    /// Airspeed target (throttle channel), m/s.
    pub tas_mps: f64,
    /// Elevator channel.
    pub elevator: ElevatorTarget,
    /// Aileron channel.
    pub aileron: AileronTarget,
    /// End condition.
    pub trigger: Trigger,
}
