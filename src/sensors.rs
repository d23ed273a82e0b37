//! Sensor sample types and the [`SensorEvent`] stream fed to the navigation core
//! (paper, section "Testing: High Fidelity Simulation", sensed trajectory `x~`).
//!
//! All values are SI, in the frame named by the field. Inertial samples are expressed in the
//! IMU platform axes as the navigation believes them aligned with the body (`B`) axes.

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::math::wgs84::Geodetic;

/// Gyroscope and accelerometer sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    /// Sample time, microseconds on the run's monotonic clock.
    pub t_us: u64,
    /// Measured inertial angular velocity `w_ib_b`, rad/s.
    pub gyro_rps: Vector3<f64>,
    /// Measured specific force `f_ib_b`, m/s².
    pub accel_mps2: Vector3<f64>,
}

/// Air data: Pitot, vanes, barometer and thermometer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AirSample {
    /// Sample time, microseconds.
    pub t_us: u64,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Angle of attack from the vane, rad (`None` when no vane is fitted).
    pub aoa_rad: Option<f64>,
    /// Angle of sideslip from the vane, rad (`None` when no vane is fitted).
    pub aos_rad: Option<f64>,
    /// Static (outside) pressure, Pa.
    pub p_pa: f64,
    /// Outside air temperature, K.
    pub temp_k: f64,
}

/// Magnetometer sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MagSample {
    /// Sample time, microseconds.
    pub t_us: u64,
    /// Measured magnetic field in body axes, nT.
    pub mag_b_nt: Vector3<f64>,
}

/// GNSS position and velocity fix.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GnssFix {
    /// Fix time, microseconds.
    pub t_us: u64,
    /// Geodetic position (WGS84).
    pub pos: Geodetic,
    /// Ground velocity in NED, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// One-sigma horizontal position accuracy the receiver reports, m.
    pub sigma_hor_m: f64,
    /// One-sigma vertical position accuracy, m.
    pub sigma_ver_m: f64,
    /// One-sigma velocity accuracy per axis, m/s.
    pub sigma_vel_mps: f64,
}

/// Attitude estimated by another navigation system on board (the autopilot's GNSS-aided
/// estimator, MAVLink ATTITUDE): the reference of the INS's transfer alignment while GNSS is
/// available.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RefAttitude {
    /// Time of validity, microseconds.
    pub t_us: u64,
    /// Attitude body → NED.
    pub q_nb: UnitQuaternion<f64>,
}

/// Sensor-error estimates and their one-sigma uncertainty at a start (paper eqs. of the
/// sensor models: gyro `E_gyr`, accelerometer `E_acc`, magnetometer `E_mag`, magnetic-model
/// error `ΔB_n`), per axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorErrorPriors {
    /// Gyro error `E_gyr`, rad/s.
    pub e_gyr_rps: Vector3<f64>,
    /// σ of `E_gyr`, rad/s.
    pub e_gyr_sigma_rps: Vector3<f64>,
    /// Accelerometer error `E_acc`, m/s².
    pub e_acc_mps2: Vector3<f64>,
    /// σ of `E_acc`, m/s².
    pub e_acc_sigma_mps2: Vector3<f64>,
    /// Magnetometer error `E_mag`, nT.
    pub e_mag_nt: Vector3<f64>,
    /// σ of `E_mag`, nT.
    pub e_mag_sigma_nt: Vector3<f64>,
    /// Magnetic-model error `ΔB_n = B_model − B_true`, NED, nT.
    pub delta_b_n_nt: Vector3<f64>,
    /// σ of `ΔB_n`, nT.
    pub delta_b_n_sigma_nt: Vector3<f64>,
}

/// A start alignment offered by the vehicle: the attitude, angle of attack and sensor-error
/// estimates from which the navigator starts the INS at the next GNSS fix (`nav::policy`).
/// The simulator offers its truth with the drawn initial errors (docs/REFERENCES.md A1.9); a
/// daemon without one starts from the autopilot's [`RefAttitude`] with cold-start priors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Alignment {
    /// Time of validity, microseconds.
    pub t_us: u64,
    /// Attitude body → NED.
    pub q_nb: UnitQuaternion<f64>,
    /// Angle of attack, rad.
    pub aoa_rad: f64,
    /// Sensor-error estimates.
    pub priors: SensorErrorPriors,
}

/// Height of the vehicle over the terrain below it (a rangefinder, a terrain model, or the
/// simulator's truth with its drawn error): the scale of the visual navigation's two-view
/// initialisation (paper, section "SVO": "requiring the height over the terrain to provide the
/// scale").
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HeightAboveTerrain {
    /// Time of validity, microseconds.
    pub t_us: u64,
    /// Height of the body origin over the terrain, m.
    pub h_agl_m: f64,
    /// Its standard deviation, m.
    pub sigma_m: f64,
}

/// A grey-level camera frame (8 bits per pixel, row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Exposure time, microseconds.
    pub t_us: u64,
    /// Width in pixels (image columns).
    pub width: u32,
    /// Height in pixels (image rows).
    pub height: u32,
    /// `width * height` grey levels, row after row.
    pub pixels: std::sync::Arc<[u8]>,
}

/// Where a deferred frame's visual navigation was handed back to the navigator
/// (`nav::NavConfig::vision_deferred`): recorded with the events so that a replay applies
/// the result at the same point of the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct VisionApplied {
    /// The frame's exposure time, microseconds.
    pub t_us: u64,
}

/// One timestamped input of the navigation core.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEvent {
    /// Inertial measurement unit.
    Imu(ImuSample),
    /// Air data and atmosphere.
    Air(AirSample),
    /// Magnetometer.
    Mag(MagSample),
    /// GNSS receiver.
    Gnss(GnssFix),
    /// Another estimator's attitude (transfer alignment).
    RefAttitude(RefAttitude),
    /// Down-looking camera.
    Frame(Frame),
    /// A start alignment (boxed: it is rare and large).
    Alignment(Box<Alignment>),
    /// Height over the terrain.
    HeightAboveTerrain(HeightAboveTerrain),
    /// A deferred frame's visual navigation handed back (its time is the frame's).
    VisionApplied(VisionApplied),
}

impl SensorEvent {
    /// Time of the event, microseconds.
    pub fn t_us(&self) -> u64 {
        match self {
            SensorEvent::Imu(s) => s.t_us,
            SensorEvent::Air(s) => s.t_us,
            SensorEvent::Mag(s) => s.t_us,
            SensorEvent::Gnss(s) => s.t_us,
            SensorEvent::RefAttitude(s) => s.t_us,
            SensorEvent::Frame(s) => s.t_us,
            SensorEvent::Alignment(s) => s.t_us,
            SensorEvent::HeightAboveTerrain(s) => s.t_us,
            SensorEvent::VisionApplied(s) => s.t_us,
        }
    }
}
