//! Simulated sensors (docs/REFERENCES.md A2): IMU (gyroscope, accelerometer) with bias offset, bias
//! random walk, white noise, scale and cross-coupling, mounting misalignment and lever arm;
//! magnetometer with hard and soft iron; Pitot, vanes, barometer, thermometer; GNSS with
//! white noise and a slowly varying ionospheric error.
//!
//! Randomness: every sensor draws from its own streams `rng::stream(seed, name)`, an
//! "aircraft" stream for what belongs to the airframe (scale and cross-coupling, soft and hard
//! iron, mounting) and a "run" stream for what changes every flight (offsets, drift, noise),
//! so adding or removing a sensor never changes another's draws. The names are the
//! `STREAM_*` constants below. See `docs/SENSORS.md` for the models and default values.

pub mod air_data;
pub mod allan;
pub mod camera;
pub mod config;
pub mod gnss;
pub mod inertial;
pub mod magnetometer;
pub mod platform;
pub mod random_walk;

use ianav::math::wgs84::Geodetic;
use ianav::sensors::{AirSample, GnssFix, ImuSample, MagSample};
use nalgebra::{UnitQuaternion, Vector3};

pub use air_data::{AirData, AirDataBiases};
pub use config::{
    AirDataConfig, CrossCoupling, GnssConfig, InertialConfig, MagConfig, PlatformConfig,
    SensorConfigError, SensorsConfig,
};
pub use gnss::Gnss;
pub use inertial::{Imu, InertialTriad};
pub use magnetometer::Magnetometer;
pub use platform::Platform;

use crate::rng;

/// Aircraft stream of the IMU mounting.
pub const STREAM_PLATFORM_AIRCRAFT: &str = "sensors.platform.aircraft";
/// Aircraft stream of the gyroscope (scale and cross-coupling).
pub const STREAM_GYRO_AIRCRAFT: &str = "sensors.gyro.aircraft";
/// Run stream of the gyroscope (offset, drift, noise).
pub const STREAM_GYRO_RUN: &str = "sensors.gyro.run";
/// Aircraft stream of the accelerometer.
pub const STREAM_ACCEL_AIRCRAFT: &str = "sensors.accel.aircraft";
/// Run stream of the accelerometer.
pub const STREAM_ACCEL_RUN: &str = "sensors.accel.run";
/// Aircraft stream of the magnetometer (soft and hard iron).
pub const STREAM_MAG_AIRCRAFT: &str = "sensors.mag.aircraft";
/// Run stream of the magnetometer (offset, noise).
pub const STREAM_MAG_RUN: &str = "sensors.mag.run";
/// Prefix of the air-data run streams: `sensors.air.{tas,aoa,aos,p,temp}.run`.
pub const STREAM_AIR_PREFIX: &str = "sensors.air";
/// Run stream of the GNSS white noise.
pub const STREAM_GNSS_RUN: &str = "sensors.gnss.run";
/// Run stream of the GNSS ionospheric walk.
pub const STREAM_GNSS_IONO: &str = "sensors.gnss.iono";

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

/// The true systematic sensor errors ("E" = everything except white noise, docs/REFERENCES.md A1.1)
/// and mounting, for the INS initialisation (docs/REFERENCES.md A1.9).
///
/// The `e_*` errors depend on the measured quantity (scale, cross-coupling, misalignment,
/// lever arm), so they are those of the **last** sample of each sensor; before the first
/// sample they are the bias offsets alone.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorErrors {
    /// Gyro error except white noise, estimated body axes, rad/s.
    pub e_gyr_rps: Vector3<f64>,
    /// Accelerometer error except its white noise (includes the lever-arm compensation error,
    /// which carries gyro noise), estimated body axes, m/s².
    pub e_acc_mps2: Vector3<f64>,
    /// Magnetometer error except white noise, body axes, nT.
    pub e_mag_nt: Vector3<f64>,
    /// Current gyro bias (offset + drift), rad/s.
    pub gyr_bias_rps: Vector3<f64>,
    /// Current accelerometer bias (offset + drift), m/s².
    pub acc_bias_mps2: Vector3<f64>,
    /// True IMU platform orientation `q_bp` (`v_b = q_bp * v_p`).
    pub q_bp_true: UnitQuaternion<f64>,
    /// The navigation's estimate of `q_bp`.
    pub q_bp_est: UnitQuaternion<f64>,
    /// True IMU position from the aircraft reference point, body axes, m.
    pub t_rp_b_true_m: Vector3<f64>,
    /// The navigation's estimate of that position, m.
    pub t_rp_b_est_m: Vector3<f64>,
    /// Ionospheric error of the last GNSS fix, NED, m.
    pub gnss_iono_ned_m: Vector3<f64>,
    /// Constant air-data biases.
    pub air: AirDataBiases,
}

/// All simulated sensors of one aircraft in one run.
#[derive(Debug, Clone)]
pub struct SensorSuite {
    imu: Imu,
    mag: Magnetometer,
    air: AirData,
    gnss: Gnss,
}

impl SensorSuite {
    /// The sensors of run `seed`; the airframe errors are drawn from the same seed. `cfg`
    /// should have passed [`SensorsConfig::validate`] (this never panics, but an invalid
    /// configuration gives meaningless samples); see [`SensorSuite::try_new`].
    pub fn new(cfg: &SensorsConfig, seed: u64) -> Self {
        Self::with_seeds(cfg, seed, seed)
    }

    /// Validate `cfg`, then build as [`SensorSuite::new`].
    pub fn try_new(cfg: &SensorsConfig, seed: u64) -> Result<Self, SensorConfigError> {
        cfg.validate()?;
        Ok(Self::new(cfg, seed))
    }

    /// The sensors with the airframe errors (mounting, scale and cross-coupling, hard and
    /// soft iron) from `aircraft_seed` and everything else from `run_seed`: several runs of
    /// one aircraft share `aircraft_seed`.
    pub fn with_seeds(cfg: &SensorsConfig, run_seed: u64, aircraft_seed: u64) -> Self {
        let dt = cfg.imu_period_s;
        let platform = Platform::draw(
            &cfg.platform,
            &mut rng::stream(aircraft_seed, STREAM_PLATFORM_AIRCRAFT),
        );
        let gyro = InertialTriad::new(
            &cfg.gyro,
            dt,
            &platform,
            &mut rng::stream(aircraft_seed, STREAM_GYRO_AIRCRAFT),
            rng::stream(run_seed, STREAM_GYRO_RUN),
        );
        let accel = InertialTriad::new(
            &cfg.accel,
            dt,
            &platform,
            &mut rng::stream(aircraft_seed, STREAM_ACCEL_AIRCRAFT),
            rng::stream(run_seed, STREAM_ACCEL_RUN),
        );
        let mag = Magnetometer::new(
            &cfg.mag,
            &mut rng::stream(aircraft_seed, STREAM_MAG_AIRCRAFT),
            rng::stream(run_seed, STREAM_MAG_RUN),
        );
        let air = AirData::new(&cfg.air, |name| {
            rng::stream(run_seed, &format!("{STREAM_AIR_PREFIX}.{name}.run"))
        });
        let gnss = Gnss::new(
            &cfg.gnss,
            rng::stream(run_seed, STREAM_GNSS_RUN),
            rng::stream(run_seed, STREAM_GNSS_IONO),
        );
        Self {
            imu: Imu::new(gyro, accel, platform, dt),
            mag,
            air,
            gnss,
        }
    }

    /// Gyroscope and accelerometer sample; call every `imu_period_s`.
    pub fn sample_imu(&mut self, truth: &SensorTruth) -> ImuSample {
        self.imu.sample(truth)
    }

    /// Air-data sample (any rate: the noise is per sample).
    pub fn sample_air(&mut self, truth: &SensorTruth) -> AirSample {
        self.air.sample(truth)
    }

    /// Magnetometer sample; call every `mag.period_s`.
    pub fn sample_mag(&mut self, truth: &SensorTruth) -> MagSample {
        self.mag.sample(truth)
    }

    /// GNSS fix; call every `gnss.period_s` (the ionospheric walk advances per fix).
    pub fn sample_gnss(&mut self, truth: &SensorTruth) -> GnssFix {
        self.gnss.sample(truth)
    }

    /// The true systematic errors now (see [`SensorErrors`]).
    pub fn true_errors(&self) -> SensorErrors {
        let platform = self.imu.platform();
        SensorErrors {
            e_gyr_rps: self.imu.e_gyr_rps(),
            e_acc_mps2: self.imu.e_acc_mps2(),
            e_mag_nt: self.mag.e_mag_nt(),
            gyr_bias_rps: self.imu.gyro_bias_rps(),
            acc_bias_mps2: self.imu.accel_bias_mps2(),
            q_bp_true: platform.q_bp_true,
            q_bp_est: platform.q_bp_est,
            t_rp_b_true_m: platform.t_rp_b_true_m,
            t_rp_b_est_m: platform.t_rp_b_est_m,
            gnss_iono_ned_m: self.gnss.iono_ned_m(),
            air: self.air.biases(),
        }
    }

    /// The IMU (mounting, triads).
    pub fn imu(&self) -> &Imu {
        &self.imu
    }

    /// The magnetometer.
    pub fn mag(&self) -> &Magnetometer {
        &self.mag
    }
}
