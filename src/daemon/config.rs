//! Daemon configuration (`config/ianav.toml`; docs/DAEMON.md "Configuration keys"): the MAVLink
//! link, what to request from and publish to the autopilot, the camera (source, intrinsics or
//! calibration file, mounting), the INS configuration and logging. Unknown keys and out-of-range values are errors that name the key
//! (`output.rate_hz = 500: must be in [1, 200]`).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::ins::{InsConfig, InsConfigError};
use crate::vision::vns::{AidingConfig, VnsConfig};

mod camera;
mod navigation;

pub use camera::{CameraConfig, CameraSourceKind};
pub use navigation::{NavigationConfig, VisionThreadPolicy};

/// Why a configuration was rejected. Each message is complete on its own line: no variant
/// also returns its cause as `source()`, which printed the same text twice (once in the
/// message, once as the cause) at start-up.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{path}: {error}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: std::io::Error,
    },
    /// Not TOML, a wrong type, or an unknown key (the TOML error names it and its line).
    #[error("{0}")]
    Toml(toml::de::Error),
    /// A value outside its domain.
    #[error("{key} = {value}: {reason}")]
    Invalid {
        /// Dotted key.
        key: String,
        /// The rejected value, as written.
        value: String,
        /// What it must satisfy.
        reason: String,
    },
    /// The camera's intrinsics (`camera.calibration_file` or the nominal pinhole's keys);
    /// the message names the key, and the calibration file's own key.
    #[error("{0}")]
    Camera(crate::vision::camera::CameraConfigError),
    /// The INS configuration (inline `[ins]` or the file named by `navigation.ins_config`).
    #[error("{context}: {error}")]
    Ins {
        /// Where the INS configuration came from.
        context: String,
        /// The INS error (it names the INS key).
        error: InsConfigError,
    },
}

pub(crate) fn invalid(
    key: &str,
    value: impl std::fmt::Display,
    reason: impl Into<String>,
) -> ConfigError {
    ConfigError::Invalid {
        key: key.to_owned(),
        value: value.to_string(),
        reason: reason.into(),
    }
}

/// A number as written in a file: plain, or in exponent form when tiny or huge (`1e-300`
/// printed plain is 300 digits long).
fn number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e15).contains(&v.abs()) {
        v.to_string()
    } else {
        format!("{v:e}")
    }
}

fn in_range(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), ConfigError> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(invalid(key, number(v), format!("must be in [{lo}, {hi}]")))
    }
}

/// Which autopilot firmware the daemon talks to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutopilotKind {
    /// Learn it from the autopilot's HEARTBEAT (`autopilot` field).
    Auto,
    /// PX4 (MAV_AUTOPILOT_PX4).
    Px4,
    /// ArduPilot (MAV_AUTOPILOT_ARDUPILOTMEGA).
    Ardupilot,
}

/// What the daemon publishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputMode {
    /// Pick from the autopilot kind: `odometry` for PX4, `gps_input` for ArduPilot.
    Auto,
    /// ODOMETRY in the autopilot's local NED frame (PX4 external vision, 30–50 Hz), with
    /// SET_GPS_GLOBAL_ORIGIN.
    Odometry,
    /// GPS_INPUT as a MAVLink GPS instance (ArduPilot `GPSn_TYPE = 14`, 5–10 Hz).
    GpsInput,
    /// VISION_POSITION_ESTIMATE in the local NED frame (ArduPilot ExtNav, PX4 EV).
    VisionPositionEstimate,
}

/// The time base of the navigation core's `t_us`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockSource {
    /// The daemon's monotonic clock, autopilot stamps mapped with TIMESYNC (real vehicles).
    Daemon,
    /// The autopilot's own time (a simulated vehicle running faster than real time).
    Autopilot,
}

pub use crate::io::mavlink_in::TemperatureSource;

/// What the AOA_SSA message is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AoaSsaUse {
    /// Not used (default). ArduPilot computes AOA_SSA from its own EKF velocity minus its EKF
    /// wind, not from vanes: once the autopilot fuses our output, that is our own solution
    /// fed back, which made the sideslip and the position diverge beside ArduPlane.
    Ignore,
    /// AOA_SSA carries measurements of real angle-of-attack and sideslip vanes (e.g. the
    /// simulator's vehicle, or an autopilot build that forwards vanes there).
    Vanes,
}

/// Which message carries the magnetometer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MagnetometerSource {
    /// Follow the autopilot found (default): `scaled_imu` beside PX4 and any other autopilot
    /// that sends HIGHRES_IMU (falling back to HIGHRES_IMU's field while no SCALED_IMU comes),
    /// `imu` beside ArduPilot, whose IMU message is SCALED_IMU already.
    Auto,
    /// The IMU message's magnetometer fields: HIGHRES_IMU on PX4, SCALED_IMU on ArduPilot.
    Imu,
    /// SCALED_IMU, requested besides the IMU message: the sensor's field. PX4's HIGHRES_IMU
    /// subtracts EKF2's current magnetometer-bias estimate, which wanders by hundreds of nT
    /// (beside SIH 1,050–1,750 nT after take-off, 30–410 nT three minutes later; 375 nT is a
    /// degree of heading) and would be taken for the INS's own magnetometer error.
    ScaledImu,
}

/// `[mavlink]`: the link to the autopilot.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MavlinkConfig {
    /// `udpin:IP:PORT`, `udpout:IP:PORT`, `tcpin:IP:PORT`, `tcpout:IP:PORT` or
    /// `serial:DEVICE:BAUD`.
    pub connection: String,
    /// Our system id; 0 = adopt the autopilot's once its HEARTBEAT is seen.
    #[serde(default)]
    pub system_id: u8,
    /// Our component id (197 = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY).
    #[serde(default = "default_component_id")]
    pub component_id: u8,
    /// Autopilot firmware.
    #[serde(default = "default_autopilot")]
    pub autopilot: AutopilotKind,
    /// The autopilot's system id; 0 = the first flight controller heard (docs/DAEMON.md
    /// "Link ownership").
    #[serde(default)]
    pub autopilot_system_id: u8,
    /// The autopilot's component id; 0 = any.
    #[serde(default)]
    pub autopilot_component_id: u8,
    /// MAVLink 2 signing key: 64 hex digits or the base64 of 32 bytes. Empty = no signing.
    #[serde(default)]
    pub signing_key: String,
    /// Signing link id of our outgoing frames.
    #[serde(default)]
    pub signing_link_id: u8,
    /// With a signing key: refuse unsigned (and MAVLink 1) input.
    #[serde(default)]
    pub refuse_unsigned: bool,
    /// The link is declared lost after this long without any message from the autopilot, s.
    #[serde(default = "default_link_timeout_s")]
    pub link_timeout_s: f64,
    /// Time base: `daemon` (real vehicle) or `autopilot` (SITL faster than real time).
    #[serde(default = "default_clock")]
    pub clock: ClockSource,
    /// Rate of our own TIMESYNC requests, Hz.
    #[serde(default = "default_timesync_rate_hz")]
    pub timesync_rate_hz: f64,
    /// TIMESYNC round trips longer than this are not used, ms.
    #[serde(default = "default_timesync_max_rtt_ms")]
    pub timesync_max_rtt_ms: f64,
}

fn default_component_id() -> u8 {
    197
}
fn default_autopilot() -> AutopilotKind {
    AutopilotKind::Auto
}
fn default_clock() -> ClockSource {
    ClockSource::Daemon
}
fn default_link_timeout_s() -> f64 {
    3.0
}
fn default_timesync_rate_hz() -> f64 {
    5.0
}
fn default_timesync_max_rtt_ms() -> f64 {
    10.0
}

/// `[input]`: message rates requested with MAV_CMD_SET_MESSAGE_INTERVAL (0 = do not request).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputConfig {
    /// HIGHRES_IMU (PX4) or SCALED_IMU / RAW_IMU (ArduPilot), Hz. The INS runs on 25–200 Hz.
    #[serde(default = "default_imu_rate_hz")]
    pub imu_rate_hz: f64,
    /// SCALED_PRESSURE, AIRSPEED / VFR_HUD and AOA_SSA, Hz.
    #[serde(default = "default_air_rate_hz")]
    pub air_rate_hz: f64,
    /// GPS_RAW_INT and GLOBAL_POSITION_INT, Hz.
    #[serde(default = "default_gnss_rate_hz")]
    pub gnss_rate_hz: f64,
    /// ATTITUDE (for the INS initialisation), Hz.
    #[serde(default = "default_attitude_rate_hz")]
    pub attitude_rate_hz: f64,
    /// Outside air temperature source.
    #[serde(default = "default_temperature")]
    pub temperature: TemperatureSource,
    /// ISA temperature offset used with `temperature = "isa"`, K.
    #[serde(default)]
    pub isa_delta_t_k: f64,
    /// GNSS is declared lost after this long without a valid 3D fix, s.
    #[serde(default = "default_gnss_loss_timeout_s")]
    pub gnss_loss_timeout_s: f64,
    /// What AOA_SSA is: `ignore` (default: ArduPilot derives it from its EKF) or `vanes`.
    #[serde(default = "default_aoa_ssa")]
    pub aoa_ssa: AoaSsaUse,
    /// Age of a GNSS fix when the autopilot stamps it, s: GPS_RAW_INT `time_usec` is when the
    /// autopilot received the fix (receiver latency not included). The fix is dated this much
    /// earlier; the INS compares it with its own state at that time (ArduPilot SITL: 0.1 s of
    /// simulated receiver lag; a u-blox receiver: about 0.1–0.2 s).
    #[serde(default)]
    pub gnss_lag_s: f64,
    /// Started on the ground, the INS is started again once the true airspeed reaches this,
    /// m/s: its models are those of a flying aircraft (no sustained longitudinal acceleration,
    /// the air velocity along the body), and through a take-off roll it re-initialised five
    /// times. 0: never (a daemon started in flight starts its INS once, at the first fix).
    #[serde(default = "default_start_airspeed_mps")]
    pub start_airspeed_mps: f64,
    /// Which message the magnetometer is taken from.
    #[serde(default = "default_magnetometer")]
    pub magnetometer: MagnetometerSource,
}

fn default_magnetometer() -> MagnetometerSource {
    MagnetometerSource::Auto
}

impl MagnetometerSource {
    /// What the decoder does beside an autopilot of this kind (`Auto` before it is known).
    pub fn decoder_choice(self, kind: AutopilotKind) -> crate::io::mavlink_in::MagFrom {
        use crate::io::mavlink_in::MagFrom;
        match (self, kind) {
            (Self::Imu, _) | (Self::Auto, AutopilotKind::Ardupilot | AutopilotKind::Auto) => {
                MagFrom::ImuMessage
            }
            (Self::ScaledImu, _) => MagFrom::ScaledImu,
            (Self::Auto, AutopilotKind::Px4) => MagFrom::ScaledImuWhileItComes,
        }
    }
}

fn default_start_airspeed_mps() -> f64 {
    10.0
}

fn default_aoa_ssa() -> AoaSsaUse {
    AoaSsaUse::Ignore
}

fn default_imu_rate_hz() -> f64 {
    100.0
}
fn default_air_rate_hz() -> f64 {
    25.0
}
fn default_gnss_rate_hz() -> f64 {
    5.0
}
fn default_attitude_rate_hz() -> f64 {
    10.0
}
fn default_temperature() -> TemperatureSource {
    TemperatureSource::Sensor
}
fn default_gnss_loss_timeout_s() -> f64 {
    2.0
}

impl Default for InputConfig {
    fn default() -> Self {
        Self {
            imu_rate_hz: default_imu_rate_hz(),
            air_rate_hz: default_air_rate_hz(),
            gnss_rate_hz: default_gnss_rate_hz(),
            attitude_rate_hz: default_attitude_rate_hz(),
            temperature: default_temperature(),
            isa_delta_t_k: 0.0,
            gnss_loss_timeout_s: default_gnss_loss_timeout_s(),
            aoa_ssa: default_aoa_ssa(),
            gnss_lag_s: 0.0,
            start_airspeed_mps: default_start_airspeed_mps(),
            magnetometer: default_magnetometer(),
        }
    }
}

/// `[output]`: what is published, how often.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// Message kind.
    #[serde(default = "default_mode")]
    pub mode: OutputMode,
    /// Publication rate, Hz (PX4 ODOMETRY 30–50, ArduPilot GPS_INPUT 5–10).
    pub rate_hz: f64,
    /// GPS_INPUT `gps_id`: 0 = GPS1, 1 = GPS2 (keep the real receiver on GPS1).
    #[serde(default = "default_gps_id")]
    pub gps_id: u8,
    /// GPS_INPUT `satellites_visible` (ArduPilot wants ≥ 6 for a usable fix).
    #[serde(default = "default_satellites")]
    pub satellites_visible: u8,
    /// GPS − UTC leap seconds for GPS_INPUT's week and ms (18 since 2017).
    #[serde(default = "default_leap_seconds")]
    pub gps_leap_seconds: u8,
    /// Send SET_GPS_GLOBAL_ORIGIN (the first GNSS fix) with ODOMETRY / VISION output.
    #[serde(default = "default_true")]
    pub set_origin: bool,
}

fn default_mode() -> OutputMode {
    OutputMode::Auto
}
fn default_gps_id() -> u8 {
    1
}
fn default_satellites() -> u8 {
    10
}
fn default_leap_seconds() -> u8 {
    18
}
fn default_true() -> bool {
    true
}

/// `[logging]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoggingConfig {
    /// `tracing` filter (`error`, `warn`, `info`, `debug`, `trace`, or env-filter directives),
    /// parsed strictly; a `RUST_LOG` set in the environment replaces it (`daemon::preflight`).
    #[serde(default = "default_level")]
    pub level: String,
    /// Period of the counter summary in the log, s (0 = never).
    #[serde(default = "default_counters_period_s")]
    pub counters_period_s: f64,
}

fn default_level() -> String {
    "info".to_owned()
}
fn default_counters_period_s() -> f64 {
    10.0
}

impl Default for LoggingConfig {
    fn default() -> Self {
        Self {
            level: default_level(),
            counters_period_s: default_counters_period_s(),
        }
    }
}

/// The whole file as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    mavlink: MavlinkConfig,
    #[serde(default)]
    input: InputConfig,
    output: OutputConfig,
    #[serde(default)]
    camera: CameraConfig,
    #[serde(default)]
    navigation: NavigationConfig,
    #[serde(default)]
    ins: Option<toml::Table>,
    #[serde(default)]
    vision: Option<toml::Table>,
    #[serde(default)]
    logging: LoggingConfig,
}

/// A settings section given by a file (`file`, relative to `base_dir`), an inline table, or
/// both (the table's keys override the file's): the merged table and where it came from;
/// `None` when neither is given.
fn section(
    name: &str,
    file: &str,
    file_key: &str,
    inline: Option<&toml::Table>,
    base_dir: Option<&Path>,
) -> Result<Option<(toml::Table, String)>, ConfigError> {
    if file.is_empty() {
        return Ok(inline.map(|t| (t.clone(), format!("[{name}]"))));
    }
    let p = Path::new(file);
    let p = match base_dir {
        Some(dir) if p.is_relative() => dir.join(p),
        _ => p.to_owned(),
    };
    let text = std::fs::read_to_string(&p).map_err(|error| ConfigError::Read {
        path: p.clone(),
        error,
    })?;
    let mut context = format!("{file_key} ({})", p.display());
    let mut table: toml::Table =
        toml::from_str(&text).map_err(|e| invalid(&context, "[file]", e.to_string()))?;
    if let Some(over) = inline {
        merge_tables(&mut table, over);
        context.push_str(&format!(" with [{name}] overrides"));
    }
    Ok(Some((table, context)))
}

/// A table written back as TOML text (for the parsers that read text).
fn retoml(name: &str, table: &toml::Table) -> Result<String, ConfigError> {
    toml::to_string(table)
        .map_err(|e| invalid(name, "[table]", format!("cannot re-serialise: {e}")))
}

/// A validated daemon configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct DaemonConfig {
    /// `[mavlink]`.
    pub mavlink: MavlinkConfig,
    /// `[input]`.
    pub input: InputConfig,
    /// `[output]`.
    pub output: OutputConfig,
    /// `[camera]`.
    pub camera: CameraConfig,
    /// `[navigation]`.
    pub navigation: NavigationConfig,
    /// The INS configuration (from `navigation.ins_config`, `[ins]`, or the defaults).
    pub ins: InsConfig,
    /// The visual navigation's settings (from `navigation.vision_config`, `[vision]`, or the
    /// defaults for the paper's 768 × 1024 camera), the paper's IA-VNS unless they set
    /// `aiding`.
    pub vision: VnsConfig,
    /// `[logging]`.
    pub logging: LoggingConfig,
    /// The decoded signing key.
    pub signing_key: Option<[u8; 32]>,
    /// Sensor log to record every event the navigator is fed into (`ianav run --record`; not
    /// a configuration key).
    pub record: Option<std::path::PathBuf>,
}

/// Overwrite `base`'s keys with `over`'s, table by table.
fn merge_tables(base: &mut toml::Table, over: &toml::Table) {
    for (key, value) in over {
        match (base.get_mut(key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            _ => {
                base.insert(key.clone(), value.clone());
            }
        }
    }
}

impl DaemonConfig {
    /// Read and validate a file; `navigation.ins_config` and `camera.calibration_file` are
    /// resolved against its directory.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
            path: path.to_owned(),
            error,
        })?;
        Self::from_toml_str(&text, path.parent())
    }

    /// Parse and validate TOML text; `base_dir` resolves a relative `navigation.ins_config`
    /// and `camera.calibration_file` (without it they are taken from the working directory).
    pub fn from_toml_str(text: &str, base_dir: Option<&Path>) -> Result<Self, ConfigError> {
        let raw: RawConfig = toml::from_str(text).map_err(ConfigError::Toml)?;
        let ins = match section(
            "ins",
            &raw.navigation.ins_config,
            "navigation.ins_config",
            raw.ins.as_ref(),
            base_dir,
        )? {
            Some((table, context)) => {
                let text = retoml("ins", &table)?;
                InsConfig::from_toml_str(&text)
                    .map_err(|error| ConfigError::Ins { context, error })?
            }
            None => InsConfig::default(),
        };
        let vision = match section(
            "vision",
            &raw.navigation.vision_config,
            "navigation.vision_config",
            raw.vision.as_ref(),
            base_dir,
        )? {
            Some((table, context)) => {
                let mut vision: VnsConfig = toml::from_str(&retoml("vision", &table)?)
                    .map_err(|e| invalid(&context, "[table]", e.to_string()))?;
                // The daemon runs the paper's IA-VNS unless the settings say otherwise.
                if !table.contains_key("aiding") {
                    vision.aiding = AidingConfig::paper();
                }
                vision
                    .validate()
                    .map_err(|e| invalid(&context, "[table]", e.to_string()))?;
                vision
            }
            None => VnsConfig {
                aiding: AidingConfig::paper(),
                ..VnsConfig::default()
            },
        };
        let signing_key = if raw.mavlink.signing_key.is_empty() {
            None
        } else {
            Some(decode_key(&raw.mavlink.signing_key).ok_or_else(|| {
                invalid(
                    "mavlink.signing_key",
                    "<hidden>",
                    "must be 64 hex digits or the base64 of 32 bytes",
                )
            })?)
        };
        let mut camera = raw.camera;
        camera::resolve(&mut camera, base_dir)?;
        let cfg = Self {
            mavlink: raw.mavlink,
            input: raw.input,
            output: raw.output,
            camera,
            navigation: raw.navigation,
            ins,
            vision,
            logging: raw.logging,
            signing_key,
            record: None,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    fn validate(&self) -> Result<(), ConfigError> {
        let m = &self.mavlink;
        validate_connection(&m.connection)?;
        if m.component_id == 0 {
            return Err(invalid("mavlink.component_id", 0, "must be in [1, 255]"));
        }
        if m.refuse_unsigned && self.signing_key.is_none() {
            return Err(invalid(
                "mavlink.refuse_unsigned",
                true,
                "needs mavlink.signing_key",
            ));
        }
        in_range("mavlink.link_timeout_s", m.link_timeout_s, 0.5, 60.0)?;
        // 0 = off; below 0.1 Hz the request period (1 / rate) is useless and, near 0, beyond
        // what a `Duration` holds (1e-300 panicked the TIMESYNC task).
        let r = m.timesync_rate_hz;
        if r != 0.0 && !(r.is_finite() && (0.1..=50.0).contains(&r)) {
            return Err(invalid(
                "mavlink.timesync_rate_hz",
                number(r),
                "must be 0 (no requests) or in [0.1, 50]",
            ));
        }
        in_range(
            "mavlink.timesync_max_rtt_ms",
            m.timesync_max_rtt_ms,
            0.1,
            1000.0,
        )?;
        let i = &self.input;
        in_range("input.imu_rate_hz", i.imu_rate_hz, 0.0, 400.0)?;
        if i.imu_rate_hz > 0.0 && i.imu_rate_hz < 25.0 {
            return Err(invalid(
                "input.imu_rate_hz",
                i.imu_rate_hz,
                "must be 0 (do not request) or in [25, 400]: the INS needs ≥ 25 Hz",
            ));
        }
        in_range("input.air_rate_hz", i.air_rate_hz, 0.0, 200.0)?;
        in_range("input.gnss_rate_hz", i.gnss_rate_hz, 0.0, 50.0)?;
        in_range("input.attitude_rate_hz", i.attitude_rate_hz, 0.0, 200.0)?;
        in_range("input.isa_delta_t_k", i.isa_delta_t_k, -60.0, 60.0)?;
        in_range(
            "input.gnss_loss_timeout_s",
            i.gnss_loss_timeout_s,
            0.2,
            60.0,
        )?;
        // The INS refuses fixes older than `position.gnss_max_lag_s` at their IMU step; keep
        // room for the link's own delay.
        in_range(
            "input.gnss_lag_s",
            i.gnss_lag_s,
            0.0,
            0.8 * self.ins.position.gnss_max_lag_s,
        )?;
        in_range("input.start_airspeed_mps", i.start_airspeed_mps, 0.0, 100.0)?;
        let o = &self.output;
        in_range("output.rate_hz", o.rate_hz, 1.0, 200.0)?;
        if o.gps_id > 1 {
            return Err(invalid("output.gps_id", o.gps_id, "must be 0 or 1"));
        }
        if o.gps_leap_seconds > 60 {
            return Err(invalid(
                "output.gps_leap_seconds",
                o.gps_leap_seconds,
                "must be in [0, 60]",
            ));
        }
        camera::validate(&self.camera)?;
        let n = &self.navigation;
        if n.mag_decimal_year != 0.0 {
            in_range(
                "navigation.mag_decimal_year",
                n.mag_decimal_year,
                2025.0,
                2030.0,
            )?;
        }
        n.vision_error.validate().map_err(|e| {
            invalid(
                &format!("navigation.vision_error.{}", e.0),
                number(e.1),
                "must be finite and ≥ 0",
            )
        })?;
        let l = &self.logging;
        if l.level.trim().is_empty() {
            return Err(invalid("logging.level", "\"\"", "must not be empty"));
        }
        parse_log_filter(&l.level)
            .map_err(|reason| invalid("logging.level", format!("{:?}", l.level), reason))?;
        in_range(
            "logging.counters_period_s",
            l.counters_period_s,
            0.0,
            3600.0,
        )?;
        Ok(())
    }
}

/// Check a connection string's scheme and shape (the mavlink crate parses it again).
fn validate_connection(s: &str) -> Result<(), ConfigError> {
    let bad = |reason: &str| invalid("mavlink.connection", format!("{s:?}"), reason);
    let Some((scheme, rest)) = s.split_once(':') else {
        return Err(bad(
            "must be scheme:address (udpin, udpout, tcpin, tcpout, serial)",
        ));
    };
    match scheme {
        "udpin" | "udpout" | "tcpin" | "tcpout" => {
            let Some((host, port)) = rest.rsplit_once(':') else {
                return Err(bad("must be scheme:host:port"));
            };
            if host.is_empty() || port.parse::<u16>().is_err() {
                return Err(bad("must be scheme:host:port with a port in [0, 65535]"));
            }
            Ok(())
        }
        "serial" => {
            let Some((dev, baud)) = rest.rsplit_once(':') else {
                return Err(bad("must be serial:device:baud"));
            };
            if dev.is_empty() || !baud.parse::<u32>().is_ok_and(|b| b > 0) {
                return Err(bad("must be serial:device:baud with a positive baud rate"));
            }
            Ok(())
        }
        _ => Err(bad(
            "unknown scheme: use udpin, udpout, tcpin, tcpout or serial",
        )),
    }
}

/// Decode a 32-byte key from 64 hex digits or standard (padded) base64.
fn decode_key(s: &str) -> Option<[u8; 32]> {
    use base64::Engine as _;
    let s = s.trim();
    let bytes = if s.len() == 64 && s.bytes().all(|b| b.is_ascii_hexdigit()) {
        (0..32)
            .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok())
            .collect::<Option<Vec<u8>>>()?
    } else {
        base64::engine::general_purpose::STANDARD.decode(s).ok()?
    };
    bytes.try_into().ok()
}

/// Parse a `tracing` filter (`logging.level` or `RUST_LOG`) strictly, as `ianav run` does:
/// an unknown level or a malformed directive is an error, not silently dropped. A directive
/// without `=` must be a level: `tracing` would read `inf` as a module named "inf" and log
/// nothing of ours, so a typo of a level is refused; a whole module is `module=trace`.
pub fn parse_log_filter(s: &str) -> Result<tracing_subscriber::EnvFilter, String> {
    for directive in s.split(',').map(str::trim) {
        let bare = !directive.is_empty() && !directive.contains(['=', '[']);
        if bare
            && directive
                .parse::<tracing::level_filters::LevelFilter>()
                .is_err()
        {
            return Err(format!(
                "{directive:?} is not a level (trace, debug, info, warn, error, off); \
                 to set a module's level write module=level"
            ));
        }
    }
    // The parser's error repeats its cause in `source()`: keep the message only.
    tracing_subscriber::EnvFilter::builder()
        .parse(s)
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHIPPED: &str = include_str!("../../config/ianav.toml");

    fn parse(s: &str) -> Result<DaemonConfig, ConfigError> {
        DaemonConfig::from_toml_str(s, Some(Path::new("config")))
    }

    const MINIMAL: &str = "[mavlink]\nconnection = \"udpin:0.0.0.0:14540\"\n\
                           [output]\nrate_hz = 30\n";

    #[test]
    fn the_shipped_file_and_a_minimal_file_are_valid() {
        let cfg = parse(SHIPPED).unwrap();
        assert_eq!(cfg.mavlink.component_id, 197);
        // ins.toml with the drifting-gyro random walk of an autopilot's MEMS IMU.
        let mut ins = InsConfig::from_toml_str(include_str!("../../config/ins.toml")).unwrap();
        ins.attitude.q_e_gyr_rad2ps2 = 1.27e-10;
        assert_eq!(cfg.ins, ins);
        let min = parse(MINIMAL).unwrap();
        assert_eq!(
            (min.mavlink.component_id, min.output.mode, min.camera.source),
            (197, OutputMode::Auto, CameraSourceKind::None)
        );
        assert_eq!(min.input.imu_rate_hz, 100.0);
        assert_eq!(min.ins, InsConfig::default());
        assert!(min.signing_key.is_none());
    }

    fn error(s: &str) -> String {
        parse(s).unwrap_err().to_string()
    }

    #[test]
    fn bad_values_name_their_key() {
        let e = error(&MINIMAL.replace("rate_hz = 30", "rate_hz = 500"));
        assert_eq!(e, "output.rate_hz = 500: must be in [1, 200]");
        let e = error(&MINIMAL.replace("udpin:0.0.0.0:14540", "udp:1.2.3.4:5"));
        assert!(
            e.starts_with("mavlink.connection = \"udp:1.2.3.4:5\""),
            "{e}"
        );
        let e = error(&MINIMAL.replace("14540", "99999"));
        assert!(e.starts_with("mavlink.connection"), "{e}");
        assert!(parse(&MINIMAL.replace("udpin:0.0.0.0:14540", "serial:/dev/ttyS1:57600")).is_ok());
        let e = error(&format!("{MINIMAL}[input]\nimu_rate_hz = 10\n"));
        assert!(e.starts_with("input.imu_rate_hz = 10:"), "{e}");
        let e = error(&format!("{MINIMAL}[camera]\nsource = \"frame_stream\"\n"));
        assert!(e.starts_with("camera.address"), "{e}");
        let v4l2 = format!("{MINIMAL}[camera]\nsource = \"v4l2\"\ndevice = \"/dev/video0\"\n");
        if cfg!(feature = "opencv") {
            assert!(parse(&v4l2).is_ok());
            let e = error(&format!("{MINIMAL}[camera]\nsource = \"gstreamer\"\n"));
            assert!(e.starts_with("camera.pipeline"), "{e}");
        } else {
            assert!(error(&v4l2).contains("opencv"));
        }
        let e = error(&MINIMAL.replace("[output]", "refuse_unsigned = true\n[output]"));
        assert!(e.starts_with("mavlink.refuse_unsigned"), "{e}");
        let e = error(&MINIMAL.replace("[output]", "signing_key = \"abc\"\n[output]"));
        assert!(e.starts_with("mavlink.signing_key"), "{e}");
        // Accepted before, then panicked or misbehaved at run time.
        let e = error(&MINIMAL.replace("[output]", "timesync_rate_hz = 1e-300\n[output]"));
        assert_eq!(
            e,
            "mavlink.timesync_rate_hz = 1e-300: must be 0 (no requests) or in [0.1, 50]"
        );
        assert!(parse(&MINIMAL.replace("[output]", "timesync_rate_hz = 0.0\n[output]")).is_ok());
        let e = error(&format!(
            "{MINIMAL}[logging]\nlevel = \"info,ianav=loud\"\n"
        ));
        assert!(e.starts_with("logging.level = \"info,ianav=loud\":"), "{e}");
        // A typo of a level would be a module named "inf" to `tracing`: refused.
        for typo in ["inf", "warn,ianav::vision=debug,degub"] {
            let e = error(&format!("{MINIMAL}[logging]\nlevel = \"{typo}\"\n"));
            assert!(e.contains("is not a level"), "{typo}: {e}");
        }
        for good in [
            "INFO",
            "off",
            "ianav=trace",
            "warn,ianav::vision=debug",
            "ianav[nav]=debug",
        ] {
            let filter = format!("{MINIMAL}[logging]\nlevel = \"{good}\"\n");
            assert!(parse(&filter).is_ok(), "{good}");
        }
        assert!(
            parse(&format!(
                "{MINIMAL}[logging]\nlevel = \"warn,ianav=debug\"\n"
            ))
            .is_ok()
        );
        // The INS key is named too.
        let e = error(&format!("{MINIMAL}[ins]\nimu_gap_s = -1.0\n"));
        assert!(e.contains("imu_gap_s"), "{e}");
    }

    #[test]
    fn unknown_keys_and_broken_toml_are_errors() {
        let e = error(&MINIMAL.replace("rate_hz = 30", "rate_hz = 30\nrat_hz = 1"));
        assert!(e.contains("rat_hz"), "{e}");
        let e = error(&format!("{MINIMAL}[camra]\n"));
        assert!(e.contains("camra"), "{e}");
        let e = error(&format!("{MINIMAL}[ins.air]\nbogus = 1\n"));
        assert!(e.contains("bogus"), "{e}");
        assert!(parse("[mavlink\nconnection = 1").is_err());
        assert!(parse("").unwrap_err().to_string().contains("mavlink"));
    }

    #[test]
    fn signing_keys_decode_from_hex_and_base64() {
        let hex: String = (0..32).map(|i| format!("{i:02x}")).collect();
        let expect: Vec<u8> = (0..32).collect();
        assert_eq!(decode_key(&hex).unwrap().to_vec(), expect);
        // base64 of bytes 0..32, computed by hand from the 6-bit groups.
        let b64 = "AAECAwQFBgcICQoLDA0ODxAREhMUFRYXGBkaGxwdHh8=";
        assert_eq!(decode_key(b64).unwrap().to_vec(), expect);
        assert!(decode_key("AAEC").is_none(), "3 bytes is not a key");
        assert!(decode_key(&hex[..62]).is_none());
        let cfg = parse(&MINIMAL.replace(
            "[output]",
            &format!("signing_key = \"{hex}\"\nrefuse_unsigned = true\n[output]"),
        ))
        .unwrap();
        assert_eq!(cfg.signing_key.unwrap()[31], 31);
    }

    #[test]
    fn ins_from_a_file_inline_or_a_file_with_inline_overrides() {
        let cfg = parse(&format!(
            "{MINIMAL}[navigation]\nins_config = \"ins.toml\"\n"
        ))
        .unwrap();
        assert_eq!(cfg.ins.imu_gap_s, 0.1);
        let e = error(&format!(
            "{MINIMAL}[navigation]\nins_config = \"missing.toml\"\n"
        ));
        assert!(e.contains("missing.toml"), "{e}");
        let inline = parse(&format!("{MINIMAL}[ins]\nimu_gap_s = 0.2\n")).unwrap();
        assert_eq!(inline.ins.imu_gap_s, 0.2);
        let both = parse(&format!(
            "{MINIMAL}[navigation]\nins_config = \"ins.toml\"\n[ins]\nimu_gap_s = 0.2\n\
             [ins.attitude]\nq_e_gyr_rad2ps2 = 1.27e-10\n"
        ))
        .unwrap();
        let file = parse(&format!(
            "{MINIMAL}[navigation]\nins_config = \"ins.toml\"\n"
        ))
        .unwrap();
        assert_eq!(both.ins.imu_gap_s, 0.2);
        assert_eq!(both.ins.attitude.q_e_gyr_rad2ps2, 1.27e-10);
        // Everything else from the file.
        let mut expected = file.ins.clone();
        expected.imu_gap_s = 0.2;
        expected.attitude.q_e_gyr_rad2ps2 = 1.27e-10;
        assert_eq!(both.ins, expected);
        let e = error(&format!(
            "{MINIMAL}[navigation]\nins_config = \"ins.toml\"\n[ins.attitude]\nq_nonsense = 1.0\n"
        ));
        assert!(e.contains("with [ins] overrides"), "{e}");
    }

    /// The visual navigation's settings: the paper's IA-VNS on the defaults; an inline table
    /// (e.g. the pixel settings of a smaller camera) keeps the IA-VNS unless it sets `aiding`;
    /// a file is read relative to the configuration; unknown keys are refused by their source.
    #[test]
    fn vision_settings_from_the_defaults_inline_or_a_file() {
        let paper = VnsConfig {
            aiding: AidingConfig::paper(),
            ..VnsConfig::default()
        };
        assert_eq!(parse(MINIMAL).unwrap().vision, paper);
        let small = parse(&format!(
            "{MINIMAL}[vision]\ninit_cell_size_px = 8\n[vision.detector]\ncell_size_px = 16\n"
        ))
        .unwrap();
        assert_eq!(small.vision.detector.cell_size_px, 16);
        assert_eq!(small.vision.init_cell_size_px, 8);
        assert_eq!(small.vision.aiding, AidingConfig::paper());
        let file = parse(&format!(
            "{MINIMAL}[navigation]\nvision_config = \"vision.toml\"\n"
        ))
        .unwrap();
        let text = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/vision.toml"),
        )
        .unwrap();
        let shipped: VnsConfig = toml::from_str(&text).unwrap();
        assert_eq!(file.vision, shipped, "the file's own aiding settings");
        let e = error(&format!("{MINIMAL}[vision]\nnonsense = 1\n"));
        assert!(e.starts_with("[vision]"), "{e}");
        let e = error(&format!("{MINIMAL}[vision.detector]\ncell_size_px = 0\n"));
        assert!(e.contains("cell_size_px"), "{e}");
    }
}
