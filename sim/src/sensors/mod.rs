//! Simulated sensors (author_impl §2): IMU (gyroscope, accelerometer) with bias offset, bias
//! random walk, white noise, scale and cross-coupling, mounting misalignment and lever arm;
//! magnetometer with hard and soft iron; Pitot, vanes, barometer, thermometer; GNSS with
//! white noise and a slowly varying ionospheric error.

use ianav::math::wgs84::Geodetic;
use nalgebra::{UnitQuaternion, Vector3};

/// Everything the sensors need to know about the true flight at one sample time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorTruth {
    /// Sample time, microseconds.
    pub t_us: u64,
    /// Position of the CG.
    pub pos: Geodetic,
    /// Ground velocity, NED, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Attitude `q_nb`.
    pub q_nb: UnitQuaternion<f64>,
    /// Inertial angular velocity, body, rad/s.
    pub w_ib_b_rps: Vector3<f64>,
    /// Inertial angular acceleration, body, rad/s².
    pub w_dot_ib_b_rps2: Vector3<f64>,
    /// Specific force at the CG, body, m/s².
    pub f_ib_b_mps2: Vector3<f64>,
    /// Position of the CG from the aircraft reference point, body axes, m (moves with fuel).
    pub cg_from_ref_b_m: Vector3<f64>,
    /// True magnetic field, NED, nT.
    pub mag_ned_nt: Vector3<f64>,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Angle of attack, rad.
    pub aoa_rad: f64,
    /// Angle of sideslip, rad.
    pub aos_rad: f64,
    /// Static pressure, Pa.
    pub p_pa: f64,
    /// Outside air temperature, K.
    pub temp_k: f64,
}
