//! The simulated aircraft (author_impl §4): a ~20 kg piston-engine fixed-wing UAV with a
//! stability-derivative aerodynamic model, engine and propeller, mass and inertia with fuel
//! burn, actuators, and the 6-DOF equations of motion on the rotating WGS84 Earth.

use ianav::math::wgs84::Geodetic;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Aircraft truth state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruthState {
    /// Position of the centre of gravity.
    pub pos: Geodetic,
    /// Ground velocity (relative to the Earth) viewed in body axes, m/s.
    pub v_b_mps: Vector3<f64>,
    /// Attitude: `v_n = q_nb * v_b`.
    pub q_nb: UnitQuaternion<f64>,
    /// Inertial angular velocity of the body viewed in body axes, rad/s.
    pub w_ib_b_rps: Vector3<f64>,
    /// Mass, kg (decreases as fuel burns).
    pub mass_kg: f64,
}

/// Control positions (or commands): throttle in [0, 1], surfaces in rad.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Controls {
    /// Throttle δ_T in [0, 1].
    pub throttle: f64,
    /// Elevator δ_E, rad (positive trailing edge down).
    pub elevator_rad: f64,
    /// Ailerons δ_A, rad (positive: right aileron trailing edge up, rolls right... see docs).
    pub aileron_rad: f64,
    /// Rudder δ_R, rad.
    pub rudder_rad: f64,
}

/// Atmosphere and wind around the aircraft, held constant over one integration step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AirInputs {
    /// Static pressure, Pa.
    pub p_pa: f64,
    /// Air temperature, K.
    pub temp_k: f64,
    /// Air density, kg/m³.
    pub rho_kgpm3: f64,
    /// Low-frequency wind, NED, m/s.
    pub wind_ned_mps: Vector3<f64>,
    /// High-frequency (turbulence) wind, body axes, m/s.
    pub turb_b_mps: Vector3<f64>,
}

/// Air-relative motion derived from the state and the wind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AirRelative {
    /// Air velocity in body axes `v_tas_b = v_b − C_bn·wind_n − turb_b`, m/s.
    pub v_tas_b_mps: Vector3<f64>,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Angle of attack α = atan2(w, u), rad.
    pub aoa_rad: f64,
    /// Angle of sideslip β = asin(v / V), rad.
    pub aos_rad: f64,
}

/// Forces, moments and by-products evaluated at one state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loads {
    /// Specific force at the CG `f_ib_b = (F_aero + F_prop)/m`, m/s².
    pub f_ib_b_mps2: Vector3<f64>,
    /// Total moment about the CG, body axes, N·m.
    pub moment_b_nm: Vector3<f64>,
    /// Inertial angular acceleration `dw_ib_b/dt`, rad/s².
    pub w_dot_ib_b_rps2: Vector3<f64>,
    /// Propeller thrust, N.
    pub thrust_n: f64,
    /// Shaft power, W.
    pub power_w: f64,
    /// Propeller shaft speed, rev/s.
    pub shaft_rps: f64,
    /// Fuel flow, kg/s (positive when burning).
    pub fuel_flow_kgps: f64,
    /// Air-relative motion.
    pub air: AirRelative,
}
