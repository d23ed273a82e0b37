//! Autopilot MAVLink messages → [`SensorEvent`]s in SI units (common.xml and ardupilotmega.xml
//! field units; docs/REFERENCES.md M3.1). Pure: no I/O, no clock; the caller maps the autopilot's
//! timestamps to the daemon's clock through [`ApTime`].
//!
//! Conversions (all checked in the tests with round numbers):
//! - IMU axes: PX4 and ArduPilot report the IMU in the vehicle's FRD body axes, which are our
//!   `B` (x forward, y right, z down), so vectors are taken as they are.
//! - HIGHRES_IMU: m/s², rad/s, gauss (1 G = 10⁵ nT), `abs_pressure` hPa (×100 Pa) — or Pa as
//!   PX4 v1.16 sends it, told apart by its magnitude ([`highres_pressure_pa`]), °C. Only
//!   the fields flagged in `fields_updated` are used (0 = legacy sender: all fields).
//! - SCALED_IMU (and ArduPilot's RAW_IMU, which carries the same scaled units): mG (×9.80665
//!   × 10⁻³ m/s²), mrad/s, mgauss (×100 nT). A PX4 RAW_IMU is in raw ADC counts with no scale
//!   on the wire and is refused.
//! - SCALED_PRESSURE / SCALED_PRESSURE2: hPa, cdegC.
//! - Airspeed: AIRSPEED reports calibrated airspeed, VFR_HUD indicated airspeed. Both are
//!   taken as equivalent airspeed (the compressibility correction CAS→EAS is < 0.4 % below
//!   Mach 0.3 and 3 km) and converted to true airspeed with the density from the static
//!   pressure and temperature: `tas = eas · √(ρ₀ / ρ)`, `ρ = p / (R T)`.
//!   The freshest of the two is used. AIRSPEED flagged unhealthy is refused, and VFR_HUD's
//!   airspeed is then refused too for [`AIRSPEED_UNHEALTHY_HOLD_US`]: ArduPilot's VFR_HUD
//!   airspeed is its AHRS estimate (ground speed minus its wind) when the sensor is unhealthy,
//!   i.e. derived from a solution that may be ours. (ArduPilot streams AIRSPEED at 1 Hz by
//!   default and VFR_HUD faster: preferring AIRSPEED for a second ran the air data on a 1 Hz
//!   airspeed.)
//! - AOA_SSA: degrees; used only when configured as real vanes ([`DecoderConfig`]): ArduPilot
//!   computes it from its EKF velocity minus its EKF wind — with our output fused, our own
//!   solution fed back as a measurement.
//! - SCALED_PRESSURE2 is a second barometer with its own bias: not mixed into the first one's
//!   stream (counted as ignored).
//! - One IMU source at a time: HIGHRES_IMU over SCALED_IMU over RAW_IMU. A lower-priority IMU
//!   message is ignored (counted) while a higher-priority one arrived within
//!   [`IMU_SOURCE_HOLD_US`]: ArduPilot streams RAW_IMU at 1 Hz by default next to the
//!   SCALED_IMU the daemon requests, and mixing them would interleave two copies of one IMU.
//! - GPS_RAW_INT: degE7, `alt_ellipsoid` mm (height above the ellipsoid, our `h`; when it is 0
//!   the MSL `alt` is used and counted, an error of the geoid undulation, ±100 m), `vel` cm/s
//!   along `cog` cdeg for the horizontal velocity. GPS_RAW_INT has no vertical velocity: the
//!   down velocity is the `vz` of GLOBAL_POSITION_INT (the autopilot's GNSS-aided estimate)
//!   at the fix's time (interpolated, or the nearest within [`VZ_MAX_AGE_US`]), else 0 with
//!   its σ raised to
//!   [`VD_UNKNOWN_SIGMA_MPS`]. σ: `h_acc`, `v_acc`, `vel_acc` when non-zero, else HDOP/VDOP ×
//!   [`UERE_M`] and the INS's configured defaults. The fix is dated the configured receiver
//!   lag before its stamp (`time_usec` is when the autopilot received it).

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};

use crate::env::atmosphere;
use crate::math::so3;
use crate::math::wgs84::Geodetic;
use crate::sensors::{AirSample, GnssFix, ImuSample, MagSample, RefAttitude, SensorEvent};
use mavlink::dialects::ardupilotmega as apm;

/// Where the outside air temperature for the air data comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TemperatureSource {
    /// The temperature the autopilot reports with the static pressure (SCALED_PRESSURE,
    /// HIGHRES_IMU): right for an outside-air probe, biased warm for a sensor in the fuselage.
    Sensor,
    /// ISA temperature at the measured pressure altitude plus `air.isa_delta_t_k`.
    Isa,
}

/// Standard gravity, m/s² (the "g" of mG).
pub const G_MPS2: f64 = 9.806_65;
/// nT per gauss.
pub const NT_PER_GAUSS: f64 = 1e5;
/// Sea-level ISA density, kg/m³.
pub const RHO0_KGPM3: f64 = 1.225;
/// Largest accepted specific force, m/s² (16 g, the usual accelerometer range).
pub const MAX_ACCEL_MPS2: f64 = 16.0 * G_MPS2;
/// Largest accepted angular rate, rad/s (2000 °/s, the usual gyro range).
pub const MAX_GYRO_RPS: f64 = 34.906_585;
/// Largest accepted field, nT (2 gauss).
pub const MAX_MAG_NT: f64 = 2e5;
/// Accepted static pressure, Pa.
pub const P_RANGE_PA: (f64, f64) = (1_000.0, 120_000.0);
/// Accepted air temperature, K (−90 °C to +70 °C).
pub const T_RANGE_K: (f64, f64) = (183.15, 343.15);
/// Largest accepted airspeed, m/s.
pub const MAX_AIRSPEED_MPS: f64 = 150.0;
/// Largest accepted GNSS ground speed, m/s: the largest airspeed plus a 150 m/s wind.
pub const MAX_GROUND_SPEED_MPS: f64 = 300.0;
/// Largest accepted vertical speed (GLOBAL_POSITION_INT `vz`), m/s: the largest airspeed.
pub const MAX_VERTICAL_SPEED_MPS: f64 = MAX_AIRSPEED_MPS;
/// Accepted height of a GNSS fix above the ellipsoid, m (below the Dead Sea shore to far above
/// any fixed wing's ceiling).
pub const H_RANGE_M: (f64, f64) = (-1_000.0, 50_000.0);
/// Largest accepted difference between the ellipsoidal and the MSL height of a fix, m (the
/// geoid lies between −107 m and +86 m).
pub const MAX_UNDULATION_M: f64 = 200.0;
/// Slack on the attitude angle ranges (f32 rounding of π), rad.
pub const ANGLE_SLACK_RAD: f64 = 1e-3;
/// Airspeed and vane samples older than this are not combined with a pressure sample, µs.
pub const AIR_MAX_AGE_US: u64 = 500_000;
/// GLOBAL_POSITION_INT `vz` kept to find the one at a lagged fix's time, µs.
pub const VZ_HISTORY_US: u64 = 3_000_000;
/// GLOBAL_POSITION_INT `vz` older than this is not used as the GNSS down velocity, µs.
pub const VZ_MAX_AGE_US: u64 = 1_000_000;
/// σ of the down velocity when none is known, m/s (a fixed wing rarely climbs faster).
pub const VD_UNKNOWN_SIGMA_MPS: f64 = 3.0;
/// After an AIRSPEED flagged unhealthy, VFR_HUD's airspeed is refused for this long, µs.
pub const AIRSPEED_UNHEALTHY_HOLD_US: u64 = 5_000_000;
/// A lower-priority IMU message is ignored while a higher-priority one is this recent, µs.
pub const IMU_SOURCE_HOLD_US: u64 = 1_000_000;
/// User-equivalent range error turning a DOP into a σ when no accuracy is reported, m.
pub const UERE_M: f64 = 3.0;

/// The autopilot's timestamp of a message, to be mapped to the daemon's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ApTime {
    /// Microseconds since the autopilot's boot (`time_usec`).
    BootUs(u64),
    /// Milliseconds since boot (`time_boot_ms`).
    BootMs(u32),
    /// No timestamp in the message: use the reception time.
    Receipt,
}

/// Why an input message was not turned into an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reject {
    /// A NaN or infinite value.
    NonFinite,
    /// A value outside the physical range of the sensor.
    OutOfRange,
    /// GNSS without a 3D fix (or an unknown fix type).
    NoFix,
    /// RAW_IMU from an autopilot that does not scale it (PX4).
    UnscaledRawImu,
    /// The timestamp could not be mapped to the daemon's clock.
    Time,
    /// A pressure sample with no recent airspeed (no air-data event).
    NoAirspeed,
    /// The airspeed sensor is flagged unhealthy.
    AirspeedUnhealthy,
}

/// Counters of the input conversion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct InputCounters {
    /// IMU events produced.
    pub imu: u64,
    /// Air-data events produced.
    pub air: u64,
    /// Magnetometer events produced.
    pub mag: u64,
    /// GNSS events produced.
    pub gnss: u64,
    /// Autopilot attitude events produced (transfer alignment).
    pub attitude: u64,
    /// Rejected: non-finite values.
    pub non_finite: u64,
    /// Rejected: out of range.
    pub out_of_range: u64,
    /// Rejected: GNSS without 3D fix.
    pub no_fix: u64,
    /// Rejected: unscaled RAW_IMU.
    pub unscaled_raw_imu: u64,
    /// Rejected: timestamp not mappable.
    pub time: u64,
    /// Pressure samples without a recent airspeed.
    pub no_airspeed: u64,
    /// AIRSPEED samples flagged unhealthy by the autopilot, and VFR_HUD airspeeds refused
    /// after one (the autopilot's synthetic airspeed).
    pub airspeed_unhealthy: u64,
    /// AOA_SSA messages ignored (not configured as vanes).
    pub aoa_ssa_ignored: u64,
    /// SCALED_PRESSURE2 messages ignored (a second barometer).
    pub second_baro_ignored: u64,
    /// GNSS fixes whose height is MSL (no `alt_ellipsoid`).
    pub gnss_msl_height: u64,
    /// GNSS fixes without a recent vertical velocity.
    pub gnss_no_vd: u64,
    /// IMU messages ignored because a higher-priority IMU message type is streaming.
    pub imu_lower_priority: u64,
    /// HIGHRES_IMU magnetometer samples ignored: the magnetometer is taken from SCALED_IMU.
    pub highres_mag_ignored: u64,
}

impl InputCounters {
    fn count(&mut self, r: Reject) {
        match r {
            Reject::NonFinite => self.non_finite += 1,
            Reject::OutOfRange => self.out_of_range += 1,
            Reject::NoFix => self.no_fix += 1,
            Reject::UnscaledRawImu => self.unscaled_raw_imu += 1,
            Reject::Time => self.time += 1,
            Reject::NoAirspeed => self.no_airspeed += 1,
            Reject::AirspeedUnhealthy => self.airspeed_unhealthy += 1,
        }
    }

    /// Sum of all rejections.
    pub fn rejected(&self) -> u64 {
        self.non_finite
            + self.out_of_range
            + self.no_fix
            + self.unscaled_raw_imu
            + self.time
            + self.no_airspeed
            + self.airspeed_unhealthy
    }
}

/// The autopilot's attitude (ATTITUDE), used to start the INS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApAttitude {
    /// Time, daemon clock, µs.
    pub t_us: u64,
    /// Attitude body → NED.
    pub q_nb: UnitQuaternion<f64>,
}

/// Configuration of the conversion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecoderConfig {
    /// Outside air temperature source.
    pub temperature: TemperatureSource,
    /// ISA offset for [`TemperatureSource::Isa`], K.
    pub isa_delta_t_k: f64,
    /// RAW_IMU carries scaled units (ArduPilot).
    pub raw_imu_is_scaled: bool,
    /// Default GNSS σ (the INS's), used when the receiver reports none: hor, ver m, vel m/s.
    pub default_sigma: (f64, f64, f64),
    /// AOA_SSA carries real vane measurements (else it is ignored).
    pub aoa_ssa_is_vanes: bool,
    /// Receiver lag: a fix is dated this long before its stamp, µs.
    pub gnss_lag_us: u64,
    /// Which message the magnetometer is taken from.
    pub mag_from: MagFrom,
}

/// Which message the magnetometer is taken from. PX4's HIGHRES_IMU subtracts its EKF's
/// current magnetometer-bias estimate, which wanders by hundreds of nT (degrees of heading);
/// SCALED_IMU carries the sensor's field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MagFrom {
    /// The IMU message's fields, whichever carries the IMU.
    ImuMessage,
    /// SCALED_IMU only.
    ScaledImu,
    /// SCALED_IMU while it comes (one within [`SCALED_MAG_HOLD_US`]), else the IMU message's:
    /// an autopilot that never sends SCALED_IMU still gives a field.
    ScaledImuWhileItComes,
}

/// How long a SCALED_IMU field keeps HIGHRES_IMU's out in [`MagFrom::ScaledImuWhileItComes`], µs.
pub const SCALED_MAG_HOLD_US: u64 = 1_000_000;

/// Stateful converter (keeps the latest airspeed, vanes, vertical speed and attitude).
#[derive(Debug, Clone)]
pub struct InputDecoder {
    cfg: DecoderConfig,
    counters: InputCounters,
    /// (t_us, equivalent airspeed m/s) from AIRSPEED (the sensor).
    eas_sensor: Option<(u64, f64)>,
    /// (t_us, equivalent airspeed m/s) from VFR_HUD.
    eas_hud: Option<(u64, f64)>,
    /// Last AIRSPEED flagged unhealthy, µs.
    airspeed_unhealthy_us: Option<u64>,
    /// (t_us, aoa rad, aos rad).
    vanes: Option<(u64, f64, f64)>,
    /// (t_us, down velocity m/s).
    /// GLOBAL_POSITION_INT `vz` of the last [`VZ_HISTORY_US`], oldest first: (µs, m/s).
    vz: VecDeque<(u64, f64)>,
    attitude: Option<ApAttitude>,
    /// Last geoid undulation seen (alt_ellipsoid − alt), m.
    undulation_m: Option<f64>,
    /// Whether the last decoded fix had a measured down velocity (a recent `vz`).
    last_fix_vd_known: bool,
    /// Last time of each IMU message type: HIGHRES_IMU, SCALED_IMU, RAW_IMU, µs.
    imu_seen_us: [Option<u64>; 3],
    /// Last SCALED_IMU whose field was taken, µs.
    scaled_mag_us: Option<u64>,
}

/// Events decoded from one message (at most IMU + magnetometer + air data).
pub type Events = Vec<SensorEvent>;

/// Whether the decoder reads this message (sensor data or the autopilot's clock): from any
/// system but the autopilot such a message is counted and ignored.
pub fn is_input(msg: &apm::MavMessage) -> bool {
    use apm::MavMessage as M;
    matches!(
        msg,
        M::HIGHRES_IMU(_)
            | M::SCALED_IMU(_)
            | M::RAW_IMU(_)
            | M::SCALED_PRESSURE(_)
            | M::SCALED_PRESSURE2(_)
            | M::AIRSPEED(_)
            | M::VFR_HUD(_)
            | M::AOA_SSA(_)
            | M::ATTITUDE(_)
            | M::GLOBAL_POSITION_INT(_)
            | M::GPS_RAW_INT(_)
            | M::SYSTEM_TIME(_)
    )
}

fn finite(v: &[f64]) -> Result<(), Reject> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(Reject::NonFinite)
    }
}

fn check_imu(accel: &Vector3<f64>, gyro: &Vector3<f64>) -> Result<(), Reject> {
    finite(accel.as_slice())?;
    finite(gyro.as_slice())?;
    if accel.norm() > MAX_ACCEL_MPS2 || gyro.norm() > MAX_GYRO_RPS {
        return Err(Reject::OutOfRange);
    }
    Ok(())
}

fn check_mag(mag_nt: &Vector3<f64>) -> Result<bool, Reject> {
    finite(mag_nt.as_slice())?;
    if mag_nt.norm() > MAX_MAG_NT {
        return Err(Reject::OutOfRange);
    }
    // All zeros: no magnetometer fitted.
    Ok(*mag_nt != Vector3::zeros())
}

impl InputDecoder {
    /// A converter with no history.
    pub fn new(cfg: DecoderConfig) -> Self {
        Self {
            cfg,
            counters: InputCounters::default(),
            eas_sensor: None,
            eas_hud: None,
            airspeed_unhealthy_us: None,
            vanes: None,
            vz: VecDeque::new(),
            attitude: None,
            undulation_m: None,
            last_fix_vd_known: false,
            imu_seen_us: [None; 3],
            scaled_mag_us: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &DecoderConfig {
        &self.cfg
    }

    /// Counters so far.
    pub fn counters(&self) -> &InputCounters {
        &self.counters
    }

    /// Whether RAW_IMU is in scaled units (set when the autopilot turns out to be ArduPilot).
    pub fn set_raw_imu_is_scaled(&mut self, scaled: bool) {
        self.cfg.raw_imu_is_scaled = scaled;
    }

    /// Which message the magnetometer is taken from (set when the autopilot is known).
    pub fn set_mag_from(&mut self, mag_from: MagFrom) {
        self.cfg.mag_from = mag_from;
    }

    /// The latest autopilot attitude.
    pub fn attitude(&self) -> Option<ApAttitude> {
        self.attitude
    }

    /// Geoid undulation N = h − MSL from the last fix that reported both, m.
    pub fn undulation_m(&self) -> Option<f64> {
        self.undulation_m
    }

    /// Whether the last decoded fix carried a measured down velocity. A fix without one says
    /// 0 m/s with a large σ: fine to fuse, wrong to start an INS from.
    pub fn last_fix_has_vertical_velocity(&self) -> bool {
        self.last_fix_vd_known
    }

    /// Forget the history (after an autopilot reboot).
    pub fn reset(&mut self) {
        self.eas_sensor = None;
        self.eas_hud = None;
        self.airspeed_unhealthy_us = None;
        self.vanes = None;
        self.vz.clear();
        self.attitude = None;
        self.imu_seen_us = [None; 3];
        self.scaled_mag_us = None;
    }

    /// Note an IMU message of `priority` (0 = best) at `t_us`; `false` if a better one is
    /// streaming.
    fn imu_preferred(&mut self, priority: usize, t_us: u64) -> bool {
        self.imu_seen_us[priority] = Some(t_us);
        let better = self.imu_seen_us[..priority]
            .iter()
            .flatten()
            .any(|t| t_us.abs_diff(*t) <= IMU_SOURCE_HOLD_US);
        if better {
            self.counters.imu_lower_priority += 1;
        }
        !better
    }

    /// Convert one message. `map` turns the message's timestamp into the daemon's `t_us`
    /// (`None`: not mappable). Messages that carry no sensor data give no event.
    pub fn decode(
        &mut self,
        msg: &apm::MavMessage,
        map: &mut impl FnMut(ApTime) -> Option<u64>,
    ) -> Events {
        let mut out = Events::new();
        if let Err(r) = self.decode_into(msg, map, &mut out) {
            self.counters.count(r);
        }
        // Aiding samples before the IMU sample of the same message: the INS fuses air,
        // magnetometer and GNSS samples at the next IMU step (docs/INS.md), so IMU first
        // would delay them by one IMU period. Stable: the rest keep their order.
        out.sort_by_key(|e| matches!(e, SensorEvent::Imu(_)));
        for e in &out {
            match e {
                SensorEvent::Imu(_) => self.counters.imu += 1,
                SensorEvent::Air(_) => self.counters.air += 1,
                SensorEvent::Mag(_) => self.counters.mag += 1,
                SensorEvent::Gnss(_) => self.counters.gnss += 1,
                SensorEvent::RefAttitude(_) => self.counters.attitude += 1,
                SensorEvent::Frame(_)
                | SensorEvent::Alignment(_)
                | SensorEvent::HeightAboveTerrain(_)
                | SensorEvent::VisionApplied(_) => {}
            }
        }
        out
    }

    fn decode_into(
        &mut self,
        msg: &apm::MavMessage,
        map: &mut impl FnMut(ApTime) -> Option<u64>,
        out: &mut Events,
    ) -> Result<(), Reject> {
        use apm::MavMessage as M;
        match msg {
            M::HIGHRES_IMU(m) => {
                let t_us = map(ApTime::BootUs(m.time_usec)).ok_or(Reject::Time)?;
                let bits = m.fields_updated.bits();
                let has = |mask: u16| bits == 0 || bits & mask == mask;
                if has(0x003f) && self.imu_preferred(0, t_us) {
                    let accel = Vector3::new(m.xacc, m.yacc, m.zacc).cast::<f64>();
                    let gyro = Vector3::new(m.xgyro, m.ygyro, m.zgyro).cast::<f64>();
                    check_imu(&accel, &gyro)?;
                    out.push(SensorEvent::Imu(ImuSample {
                        t_us,
                        gyro_rps: gyro,
                        accel_mps2: accel,
                    }));
                }
                let scaled_mag_comes = self
                    .scaled_mag_us
                    .is_some_and(|t| t.abs_diff(t_us) <= SCALED_MAG_HOLD_US);
                let skip_mag = match self.cfg.mag_from {
                    MagFrom::ImuMessage => false,
                    MagFrom::ScaledImu => true,
                    MagFrom::ScaledImuWhileItComes => scaled_mag_comes,
                };
                if has(0x01c0) && skip_mag {
                    self.counters.highres_mag_ignored += 1;
                } else if has(0x01c0) {
                    let mag = Vector3::new(m.xmag, m.ymag, m.zmag).cast::<f64>() * NT_PER_GAUSS;
                    match check_mag(&mag) {
                        Ok(true) => out.push(SensorEvent::Mag(MagSample {
                            t_us,
                            mag_b_nt: mag,
                        })),
                        Ok(false) => {}
                        Err(r) => self.counters.count(r),
                    }
                }
                if has(0x0200) {
                    let temp_c = has(0x1000).then_some(f64::from(m.temperature));
                    match self.air(t_us, highres_pressure_pa(m.abs_pressure), temp_c) {
                        Ok(a) => out.push(a),
                        Err(r) => self.counters.count(r),
                    }
                }
                Ok(())
            }
            M::SCALED_IMU(m) => {
                let t_us = map(ApTime::BootMs(m.time_boot_ms)).ok_or(Reject::Time)?;
                let imu = self.imu_preferred(1, t_us);
                if !imu && self.cfg.mag_from == MagFrom::ImuMessage {
                    return Ok(());
                }
                if self.cfg.mag_from != MagFrom::ImuMessage {
                    self.scaled_mag_us = Some(t_us);
                }
                self.scaled_imu(
                    t_us,
                    imu.then_some(([m.xacc, m.yacc, m.zacc], [m.xgyro, m.ygyro, m.zgyro])),
                    [m.xmag, m.ymag, m.zmag],
                    out,
                )
            }
            M::RAW_IMU(m) => {
                if !self.cfg.raw_imu_is_scaled {
                    return Err(Reject::UnscaledRawImu);
                }
                let t_us = map(ApTime::BootUs(m.time_usec)).ok_or(Reject::Time)?;
                if !self.imu_preferred(2, t_us) {
                    return Ok(());
                }
                self.scaled_imu(
                    t_us,
                    Some(([m.xacc, m.yacc, m.zacc], [m.xgyro, m.ygyro, m.zgyro])),
                    [m.xmag, m.ymag, m.zmag],
                    out,
                )
            }
            M::SCALED_PRESSURE(m) => {
                let t_us = map(ApTime::BootMs(m.time_boot_ms)).ok_or(Reject::Time)?;
                let temp_c = f64::from(m.temperature) / 100.0;
                out.push(self.air(t_us, f64::from(m.press_abs) * 100.0, Some(temp_c))?);
                Ok(())
            }
            M::SCALED_PRESSURE2(_) => {
                self.counters.second_baro_ignored += 1;
                Ok(())
            }
            M::AIRSPEED(m) => {
                let t_us = map(ApTime::Receipt).ok_or(Reject::Time)?;
                if m.flags
                    .contains(apm::AirspeedSensorFlags::AIRSPEED_SENSOR_UNHEALTHY)
                {
                    self.airspeed_unhealthy_us = Some(t_us);
                    self.eas_sensor = None;
                    return Err(Reject::AirspeedUnhealthy);
                }
                self.eas_sensor = Some((t_us, check_airspeed(f64::from(m.airspeed))?));
                Ok(())
            }
            M::VFR_HUD(m) => {
                let t_us = map(ApTime::Receipt).ok_or(Reject::Time)?;
                // With the sensor unhealthy this is the autopilot's own estimate.
                if self
                    .airspeed_unhealthy_us
                    .is_some_and(|t| t_us.abs_diff(t) <= AIRSPEED_UNHEALTHY_HOLD_US)
                {
                    self.eas_hud = None;
                    return Err(Reject::AirspeedUnhealthy);
                }
                self.eas_hud = Some((t_us, check_airspeed(f64::from(m.airspeed))?));
                Ok(())
            }
            M::AOA_SSA(m) => {
                if !self.cfg.aoa_ssa_is_vanes {
                    self.counters.aoa_ssa_ignored += 1;
                    return Ok(());
                }
                let t_us = map(ApTime::BootUs(m.time_usec)).ok_or(Reject::Time)?;
                let (aoa, ssa) = (f64::from(m.AOA), f64::from(m.SSA));
                finite(&[aoa, ssa])?;
                if aoa.abs() > 90.0 || ssa.abs() > 90.0 {
                    return Err(Reject::OutOfRange);
                }
                self.vanes = Some((t_us, aoa.to_radians(), ssa.to_radians()));
                Ok(())
            }
            M::ATTITUDE(m) => {
                let t_us = map(ApTime::BootMs(m.time_boot_ms)).ok_or(Reject::Time)?;
                let (r, p, y) = (f64::from(m.roll), f64::from(m.pitch), f64::from(m.yaw));
                finite(&[r, p, y])?;
                // Roll and yaw in [−π, π] (yaw also [0, 2π] from some senders), pitch in
                // [−π/2, π/2].
                use std::f64::consts::{FRAC_PI_2, PI};
                if r.abs() > PI + ANGLE_SLACK_RAD
                    || p.abs() > FRAC_PI_2 + ANGLE_SLACK_RAD
                    || !(-PI - ANGLE_SLACK_RAD..=2.0 * PI + ANGLE_SLACK_RAD).contains(&y)
                {
                    return Err(Reject::OutOfRange);
                }
                let q_nb = so3::from_euler_zyx(y, p, r);
                self.attitude = Some(ApAttitude { t_us, q_nb });
                out.push(SensorEvent::RefAttitude(RefAttitude { t_us, q_nb }));
                Ok(())
            }
            M::GLOBAL_POSITION_INT(m) => {
                let t_us = map(ApTime::BootMs(m.time_boot_ms)).ok_or(Reject::Time)?;
                let vz_mps = f64::from(m.vz) / 100.0;
                if vz_mps.abs() > MAX_VERTICAL_SPEED_MPS {
                    return Err(Reject::OutOfRange);
                }
                if self.vz.back().is_some_and(|(t, _)| *t >= t_us) {
                    self.vz.clear();
                }
                self.vz.push_back((t_us, vz_mps));
                while self
                    .vz
                    .front()
                    .is_some_and(|(t, _)| t_us.saturating_sub(*t) > VZ_HISTORY_US)
                {
                    self.vz.pop_front();
                }
                Ok(())
            }
            M::GPS_RAW_INT(m) => {
                // time_usec is 0 when the sender has no time: use the reception time.
                let at = if m.time_usec == 0 {
                    ApTime::Receipt
                } else {
                    ApTime::BootUs(m.time_usec)
                };
                let t_us = map(at)
                    .ok_or(Reject::Time)?
                    .saturating_sub(self.cfg.gnss_lag_us);
                out.push(SensorEvent::Gnss(self.gnss(t_us, m)?));
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// SCALED_IMU / RAW_IMU content: the IMU (`(acc mG, gyro mrad/s)`, absent when another
    /// message carries it) and the magnetometer.
    fn scaled_imu(
        &mut self,
        t_us: u64,
        imu: Option<([i16; 3], [i16; 3])>,
        mag_mgauss: [i16; 3],
        out: &mut Events,
    ) -> Result<(), Reject> {
        let v = |a: [i16; 3], k: f64| {
            Vector3::new(f64::from(a[0]), f64::from(a[1]), f64::from(a[2])) * k
        };
        if let Some((acc_mg, gyro_mradps)) = imu {
            let accel = v(acc_mg, G_MPS2 * 1e-3);
            let gyro = v(gyro_mradps, 1e-3);
            check_imu(&accel, &gyro)?;
            out.push(SensorEvent::Imu(ImuSample {
                t_us,
                gyro_rps: gyro,
                accel_mps2: accel,
            }));
        }
        let mag = v(mag_mgauss, 100.0);
        if check_mag(&mag)? {
            out.push(SensorEvent::Mag(MagSample {
                t_us,
                mag_b_nt: mag,
            }));
        }
        Ok(())
    }

    /// An air-data event from a static pressure, with the latest airspeed and vanes.
    fn air(&mut self, t_us: u64, p_pa: f64, temp_c: Option<f64>) -> Result<SensorEvent, Reject> {
        finite(&[p_pa])?;
        if !(P_RANGE_PA.0..=P_RANGE_PA.1).contains(&p_pa) {
            return Err(Reject::OutOfRange);
        }
        let temp_k = match (self.cfg.temperature, temp_c) {
            (TemperatureSource::Sensor, Some(c)) => c + 273.15,
            // No sensor temperature in this message, or ISA chosen.
            _ => atmosphere::temperature_k(
                atmosphere::pressure_altitude_m(p_pa),
                self.cfg.isa_delta_t_k,
            ),
        };
        finite(&[temp_k])?;
        if !(T_RANGE_K.0..=T_RANGE_K.1).contains(&temp_k) {
            return Err(Reject::OutOfRange);
        }
        let fresh = |t: u64| t_us.abs_diff(t) <= AIR_MAX_AGE_US;
        // The freshest airspeed; the sensor's on a tie.
        let eas = [self.eas_sensor, self.eas_hud]
            .into_iter()
            .flatten()
            .filter(|(t, _)| fresh(*t))
            .min_by_key(|(t, _)| t_us.abs_diff(*t))
            .map(|(_, v)| v);
        let Some(eas) = eas else {
            return Err(Reject::NoAirspeed);
        };
        let (aoa_rad, aos_rad) = match self.vanes.filter(|(t, _, _)| fresh(*t)) {
            Some((_, a, b)) => (Some(a), Some(b)),
            None => (None, None),
        };
        Ok(SensorEvent::Air(AirSample {
            t_us,
            tas_mps: tas_from_eas(eas, p_pa, temp_k),
            aoa_rad,
            aos_rad,
            p_pa,
            temp_k,
        }))
    }

    fn gnss(&mut self, t_us: u64, m: &apm::GPS_RAW_INT_DATA) -> Result<GnssFix, Reject> {
        use apm::GpsFixType as F;
        match m.fix_type {
            F::GPS_FIX_TYPE_3D_FIX
            | F::GPS_FIX_TYPE_DGPS
            | F::GPS_FIX_TYPE_RTK_FLOAT
            | F::GPS_FIX_TYPE_RTK_FIXED
            | F::GPS_FIX_TYPE_PPP => {}
            _ => return Err(Reject::NoFix),
        }
        if m.vel == u16::MAX || m.cog == u16::MAX {
            return Err(Reject::NoFix);
        }
        // Every field validated before anything is kept; i32 differences widened to f64
        // (alt_ellipsoid − alt overflows i32 for absurd values).
        let lat_deg = f64::from(m.lat) * 1e-7;
        let lon_deg = f64::from(m.lon) * 1e-7;
        let (alt_m, alt_ellipsoid_m) = (f64::from(m.alt) * 1e-3, f64::from(m.alt_ellipsoid) * 1e-3);
        let speed = f64::from(m.vel) / 100.0;
        let h_m = if m.alt_ellipsoid != 0 {
            alt_ellipsoid_m
        } else {
            alt_m
        };
        if lat_deg.abs() >= 90.0
            || lon_deg.abs() > 180.0
            || !(H_RANGE_M.0..=H_RANGE_M.1).contains(&h_m)
            || (m.alt_ellipsoid != 0 && (alt_ellipsoid_m - alt_m).abs() > MAX_UNDULATION_M)
            || speed > MAX_GROUND_SPEED_MPS
            || m.cog > 36_000
        {
            return Err(Reject::OutOfRange);
        }
        if m.alt_ellipsoid != 0 {
            self.undulation_m = Some(alt_ellipsoid_m - alt_m);
        } else {
            self.counters.gnss_msl_height += 1;
        }
        let cog = (f64::from(m.cog) / 100.0).to_radians();
        let (d_sigma_h, d_sigma_v, d_sigma_vel) = self.cfg.default_sigma;
        let dop_sigma = |dop: u16, default: f64| {
            if dop == u16::MAX || dop == 0 {
                default
            } else {
                f64::from(dop) / 100.0 * UERE_M
            }
        };
        let sigma_hor_m = if m.h_acc > 0 {
            f64::from(m.h_acc) * 1e-3
        } else {
            dop_sigma(m.eph, d_sigma_h)
        };
        let sigma_ver_m = if m.v_acc > 0 {
            f64::from(m.v_acc) * 1e-3
        } else {
            dop_sigma(m.epv, d_sigma_v)
        };
        let mut sigma_vel_mps = if m.vel_acc > 0 {
            f64::from(m.vel_acc) * 1e-3
        } else {
            d_sigma_vel
        };
        let vz = vz_at(&self.vz, t_us);
        self.last_fix_vd_known = vz.is_some();
        let vd = match vz {
            Some(vd) => vd,
            None => {
                self.counters.gnss_no_vd += 1;
                sigma_vel_mps = sigma_vel_mps.max(VD_UNKNOWN_SIGMA_MPS);
                0.0
            }
        };
        Ok(GnssFix {
            t_us,
            pos: Geodetic {
                lat_rad: lat_deg.to_radians(),
                lon_rad: lon_deg.to_radians(),
                h_m,
            },
            v_ned_mps: Vector3::new(speed * cog.cos(), speed * cog.sin(), vd),
            sigma_hor_m,
            sigma_ver_m,
            sigma_vel_mps,
        })
    }
}

/// The down velocity at the fix's time `t_us`: interpolated between the two `vz` around it,
/// else the nearest within [`VZ_MAX_AGE_US`]. `vz` is the autopilot's estimate at its own
/// time while the fix is a receiver lag older: in a pull-up from a 10 m/s climb the newest
/// `vz` is metres per second off the fix's.
fn vz_at(history: &VecDeque<(u64, f64)>, t_us: u64) -> Option<f64> {
    let i = history.partition_point(|(t, _)| *t < t_us);
    if let (Some(&(ta, va)), Some(&(tb, vb))) = (
        i.checked_sub(1).and_then(|j| history.get(j)),
        history.get(i),
    ) {
        let w = (t_us - ta) as f64 / (tb - ta) as f64;
        return Some(va + (vb - va) * w);
    }
    history
        .iter()
        .filter(|(t, _)| t.abs_diff(t_us) <= VZ_MAX_AGE_US)
        .min_by_key(|(t, _)| t.abs_diff(t_us))
        .map(|(_, v)| *v)
}

/// HIGHRES_IMU `abs_pressure` in Pa. The message defines hPa, but PX4 (v1.16) sends Pa. The two
/// ranges cannot overlap for a flying vehicle: hPa values lie below 1,200 and Pa values above
/// [`HIGHRES_PA_THRESHOLD`] (2.5 kPa is about 25 km up).
pub fn highres_pressure_pa(abs_pressure: f32) -> f64 {
    let v = f64::from(abs_pressure);
    if v > HIGHRES_PA_THRESHOLD {
        v
    } else {
        v * 100.0
    }
}

/// HIGHRES_IMU `abs_pressure` values above this are in Pa, below in hPa.
pub const HIGHRES_PA_THRESHOLD: f64 = 1_500.0;

fn check_airspeed(v: f64) -> Result<f64, Reject> {
    finite(&[v])?;
    if !(0.0..=MAX_AIRSPEED_MPS).contains(&v) {
        return Err(Reject::OutOfRange);
    }
    Ok(v)
}

/// True airspeed from equivalent airspeed, static pressure and temperature, m/s.
pub fn tas_from_eas(eas_mps: f64, p_pa: f64, temp_k: f64) -> f64 {
    eas_mps * (RHO0_KGPM3 / atmosphere::density_kgpm3(p_pa, temp_k)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decoder() -> InputDecoder {
        InputDecoder::new(DecoderConfig {
            temperature: TemperatureSource::Sensor,
            isa_delta_t_k: 0.0,
            raw_imu_is_scaled: false,
            default_sigma: (3.0, 5.0, 0.5),
            aoa_ssa_is_vanes: true,
            gnss_lag_us: 0,
            mag_from: MagFrom::ImuMessage,
        })
    }

    /// Identity mapping: boot µs = daemon µs, receipt time = 1 s.
    fn map(t: ApTime) -> Option<u64> {
        Some(match t {
            ApTime::BootUs(u) => u,
            ApTime::BootMs(m) => u64::from(m) * 1000,
            ApTime::Receipt => 1_000_000,
        })
    }

    fn highres(fields: u16) -> apm::HIGHRES_IMU_DATA {
        apm::HIGHRES_IMU_DATA {
            time_usec: 1_000_000,
            xacc: 1.0,
            yacc: -2.0,
            zacc: -9.80665,
            xgyro: 0.1,
            ygyro: 0.0,
            zgyro: -0.2,
            xmag: 0.2,
            ymag: -0.05,
            zmag: 0.45,
            abs_pressure: 1013.25,
            diff_pressure: 0.0,
            pressure_alt: 0.0,
            temperature: 15.0,
            fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(fields),
            id: 0,
        }
    }

    fn airspeed(cas_mps: f32, unhealthy: bool) -> apm::MavMessage {
        apm::MavMessage::AIRSPEED(apm::AIRSPEED_DATA {
            airspeed: cas_mps,
            flags: if unhealthy {
                apm::AirspeedSensorFlags::AIRSPEED_SENSOR_UNHEALTHY
            } else {
                apm::AirspeedSensorFlags::AIRSPEED_SENSOR_USING
            },
            ..Default::default()
        })
    }

    /// Static pressure at sea level, stamped `t_ms` after boot.
    fn pressure(t_ms: u32) -> apm::MavMessage {
        apm::MavMessage::SCALED_PRESSURE(apm::SCALED_PRESSURE_DATA {
            time_boot_ms: t_ms,
            press_abs: 1013.25,
            temperature: 1500,
            ..Default::default()
        })
    }

    /// The airspeed of the air-data event a pressure sample gives at receipt time `rx_us`.
    fn tas_at(d: &mut InputDecoder, rx_us: u64) -> Option<f64> {
        let mut at = |t: ApTime| {
            Some(match t {
                ApTime::BootUs(u) => u,
                ApTime::BootMs(m) => u64::from(m) * 1000,
                ApTime::Receipt => rx_us,
            })
        };
        let ms = u32::try_from(rx_us / 1000).unwrap();
        match d.decode(&pressure(ms), &mut at).first() {
            Some(SensorEvent::Air(a)) => Some(a.tas_mps),
            _ => None,
        }
    }

    /// Decode `msg` as received at `rx_us`.
    fn at(d: &mut InputDecoder, msg: &apm::MavMessage, rx_us: u64) -> Events {
        d.decode(msg, &mut |t| {
            Some(match t {
                ApTime::BootUs(u) => u,
                ApTime::BootMs(m) => u64::from(m) * 1000,
                ApTime::Receipt => rx_us,
            })
        })
    }

    #[test]
    fn the_freshest_airspeed_is_used_and_a_slow_airspeed_stream_does_not_hold_it() {
        // ArduPilot: AIRSPEED at 1 Hz, VFR_HUD at 25 Hz. Sea level ISA: TAS = EAS.
        let mut d = decoder();
        at(&mut d, &airspeed(20.0, false), 1_000_000);
        at(&mut d, &vfr(21.0), 1_040_000);
        let tas = tas_at(&mut d, 1_050_000).unwrap();
        assert!((tas - 21.0).abs() < 0.05, "{tas}");
        at(&mut d, &airspeed(22.0, false), 1_060_000);
        let tas = tas_at(&mut d, 1_070_000).unwrap();
        assert!((tas - 22.0).abs() < 0.05, "{tas}");
        // Nothing fresh (both older than AIR_MAX_AGE_US): no air-data event, counted.
        assert_eq!(tas_at(&mut d, 1_700_000), None);
        assert_eq!(d.counters().no_airspeed, 1);
    }

    #[test]
    fn an_unhealthy_airspeed_sensor_also_silences_the_autopilots_synthetic_airspeed() {
        let mut d = decoder();
        at(&mut d, &airspeed(20.0, true), 1_000_000);
        // VFR_HUD now carries the AHRS estimate (ground speed − wind): refused.
        at(&mut d, &vfr(21.0), 1_040_000);
        assert_eq!(tas_at(&mut d, 1_050_000), None);
        assert_eq!(d.counters().airspeed_unhealthy, 2);
        // Healthy again and the hold over: both are used again.
        at(&mut d, &airspeed(20.0, false), 7_000_000);
        at(&mut d, &vfr(21.0), 7_040_000);
        let tas = tas_at(&mut d, 7_050_000).unwrap();
        assert!((tas - 21.0).abs() < 0.05, "{tas}");
    }

    #[test]
    fn aoa_ssa_is_ignored_unless_configured_as_vanes_and_a_second_baro_is_not_mixed_in() {
        let mut d = InputDecoder::new(DecoderConfig {
            aoa_ssa_is_vanes: false,
            ..*decoder().config()
        });
        let aoa_ssa = apm::MavMessage::AOA_SSA(apm::AOA_SSA_DATA {
            time_usec: 1_000_000,
            AOA: 4.0,
            SSA: -1.0,
        });
        at(&mut d, &aoa_ssa, 1_000_000);
        at(&mut d, &airspeed(20.0, false), 1_000_000);
        let ev = at(&mut d, &pressure(1_000), 1_000_000);
        let SensorEvent::Air(air) = &ev[0] else {
            panic!("{ev:?}")
        };
        assert_eq!((air.aoa_rad, air.aos_rad), (None, None));
        assert_eq!(d.counters().aoa_ssa_ignored, 1);
        let baro2 = apm::MavMessage::SCALED_PRESSURE2(apm::SCALED_PRESSURE2_DATA {
            time_boot_ms: 1_010,
            press_abs: 900.0,
            temperature: 1500,
            ..Default::default()
        });
        assert!(at(&mut d, &baro2, 1_010_000).is_empty());
        assert_eq!(d.counters().second_baro_ignored, 1);
    }

    #[test]
    fn a_gnss_fix_is_dated_the_receiver_lag_before_its_stamp_and_extreme_heights_are_refused() {
        let mut d = InputDecoder::new(DecoderConfig {
            gnss_lag_us: 120_000,
            mag_from: MagFrom::ImuMessage,
            ..*decoder().config()
        });
        let mut m = apm::GPS_RAW_INT_DATA {
            time_usec: 2_000_000,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
            lat: 450_000_000,
            lon: 10_000_000,
            alt: i32::MIN,
            alt_ellipsoid: i32::MAX,
            vel: 2000,
            cog: 0,
            ..Default::default()
        };
        // alt_ellipsoid − alt = 2³² − 1 mm: computed without overflow, and refused.
        assert!(
            d.decode(&apm::MavMessage::GPS_RAW_INT(m.clone()), &mut map)
                .is_empty()
        );
        assert_eq!((d.counters().out_of_range, d.undulation_m()), (1, None));
        m.alt = 452_000;
        m.alt_ellipsoid = 500_000;
        let ev = d.decode(&apm::MavMessage::GPS_RAW_INT(m), &mut map);
        let SensorEvent::Gnss(fix) = &ev[0] else {
            panic!("{ev:?}")
        };
        assert_eq!(fix.t_us, 1_880_000);
        assert_eq!(d.undulation_m(), Some(48.0));
    }

    #[test]
    fn highres_pressure_in_hpa_per_the_definition_or_in_pa_as_px4_sends_it() {
        assert!((highres_pressure_pa(1013.25) - 101_325.0).abs() < 0.01);
        assert!((highres_pressure_pa(101_325.0) - 101_325.0).abs() < 0.01);
        // 25 km up: 25.5 hPa / 2,549 Pa; and the edges of the sea-level range.
        assert!((highres_pressure_pa(25.49) - 2_549.0).abs() < 0.01);
        assert!((highres_pressure_pa(2_549.0) - 2_549.0).abs() < 0.01);
        assert!((highres_pressure_pa(1_100.0) - 110_000.0).abs() < 0.01);
    }

    fn vfr(airspeed: f32) -> apm::MavMessage {
        apm::MavMessage::VFR_HUD(apm::VFR_HUD_DATA {
            airspeed,
            groundspeed: 0.0,
            heading: 0,
            throttle: 0,
            alt: 0.0,
            climb: 0.0,
        })
    }

    #[test]
    fn highres_imu_gives_imu_mag_and_air_in_si_units() {
        let mut d = decoder();
        d.decode(&vfr(30.0), &mut map);
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(highres(0x1fff)), &mut map);
        assert_eq!(ev.len(), 3);
        let SensorEvent::Imu(imu) = &ev[2] else {
            panic!()
        };
        assert_eq!(imu.t_us, 1_000_000);
        assert!((imu.accel_mps2 - Vector3::new(1.0, -2.0, -9.80665)).norm() < 1e-5);
        assert!((imu.gyro_rps.z + 0.2).abs() < 1e-7);
        let SensorEvent::Mag(mag) = &ev[0] else {
            panic!()
        };
        // 0.2 G = 20,000 nT.
        assert!((mag.mag_b_nt - Vector3::new(20_000.0, -5_000.0, 45_000.0)).norm() < 0.01);
        let SensorEvent::Air(air) = &ev[1] else {
            panic!()
        };
        // ISA sea level: 1013.25 hPa, 15 °C, ρ = ρ₀ → TAS = EAS.
        assert!((air.p_pa - 101_325.0).abs() < 0.01);
        assert!((air.temp_k - 288.15).abs() < 1e-9);
        assert!((air.tas_mps - 30.0).abs() < 0.01, "{}", air.tas_mps);
        assert_eq!((air.aoa_rad, air.aos_rad), (None, None));
        // Only accel+gyro flagged: just the IMU.
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(highres(0x003f)), &mut map);
        assert_eq!(ev.len(), 1);
        assert_eq!(d.counters().imu, 2);
    }

    #[test]
    fn true_airspeed_grows_as_density_falls() {
        // At p = ρ₀ R T / 4 the density is ρ₀/4, so TAS = 2 EAS.
        let t = 250.0;
        let p = RHO0_KGPM3 * atmosphere::R_JPKGK * t / 4.0;
        assert!((tas_from_eas(25.0, p, t) - 50.0).abs() < 1e-9);
        let mut d = decoder();
        let m = apm::SCALED_PRESSURE_DATA {
            time_boot_ms: 1000,
            press_abs: (p / 100.0) as f32,
            temperature: -2315, // 250 K − 273.15 → −23.15 °C
            ..Default::default()
        };
        d.decode(&airspeed(25.0, false), &mut map);
        d.decode(
            &apm::MavMessage::AOA_SSA(apm::AOA_SSA_DATA {
                time_usec: 1_000_000,
                AOA: 4.0,
                SSA: -1.0,
            }),
            &mut map,
        );
        // A VFR_HUD airspeed of the same age as AIRSPEED: the sensor's is used.
        d.decode(&vfr(99.0), &mut map);
        let ev = d.decode(&apm::MavMessage::SCALED_PRESSURE(m), &mut map);
        let SensorEvent::Air(air) = &ev[0] else {
            panic!("{ev:?}")
        };
        assert!((air.tas_mps - 50.0).abs() < 1e-3, "{}", air.tas_mps);
        assert!((air.aoa_rad.unwrap() - 4.0_f64.to_radians()).abs() < 1e-9);
        assert!((air.aos_rad.unwrap() + 1.0_f64.to_radians()).abs() < 1e-9);
    }

    #[test]
    fn scaled_imu_units_and_raw_imu_only_when_scaled() {
        let mut d = decoder();
        let m = apm::SCALED_IMU_DATA {
            time_boot_ms: 20,
            xacc: 1000,
            yacc: 0,
            zacc: -1000,
            xgyro: 100,
            ygyro: -50,
            zgyro: 0,
            xmag: 200,
            ymag: 0,
            zmag: 450,
            temperature: 0,
        };
        let ev = d.decode(&apm::MavMessage::SCALED_IMU(m.clone()), &mut map);
        let SensorEvent::Imu(imu) = &ev[1] else {
            panic!()
        };
        assert_eq!(imu.t_us, 20_000);
        // 1000 mG = g; 100 mrad/s = 0.1 rad/s; 200 mgauss = 20,000 nT.
        assert!((imu.accel_mps2 - Vector3::new(G_MPS2, 0.0, -G_MPS2)).norm() < 1e-12);
        assert!((imu.gyro_rps - Vector3::new(0.1, -0.05, 0.0)).norm() < 1e-12);
        let SensorEvent::Mag(mag) = &ev[0] else {
            panic!()
        };
        assert!((mag.mag_b_nt - Vector3::new(20_000.0, 0.0, 45_000.0)).norm() < 1e-9);
        let raw = apm::MavMessage::RAW_IMU(apm::RAW_IMU_DATA {
            time_usec: 30_000,
            xacc: 1000,
            zacc: -1000,
            ..Default::default()
        });
        assert!(d.decode(&raw, &mut map).is_empty());
        assert_eq!(d.counters().unscaled_raw_imu, 1);
        // SCALED_IMU streamed 10 ms before: the RAW_IMU copy of the same IMU is ignored.
        d.set_raw_imu_is_scaled(true);
        assert!(d.decode(&raw, &mut map).is_empty());
        assert_eq!(d.counters().imu_lower_priority, 1);
        // Alone (no SCALED_IMU for > 1 s), it is used.
        let mut d2 = decoder();
        d2.set_raw_imu_is_scaled(true);
        let ev = d2.decode(&raw, &mut map);
        assert_eq!(ev.len(), 1, "zero magnetometer = none fitted");
        // HIGHRES_IMU takes over from SCALED_IMU.
        d.decode(&apm::MavMessage::HIGHRES_IMU(highres(0x003f)), &mut map);
        let mut later = m;
        later.time_boot_ms = 1_010;
        assert!(
            d.decode(&apm::MavMessage::SCALED_IMU(later), &mut map)
                .is_empty()
        );
    }

    #[test]
    fn magnetometer_from_scaled_imu_beside_a_highres_imu() {
        let mut d = InputDecoder::new(DecoderConfig {
            mag_from: MagFrom::ScaledImu,
            ..*decoder().config()
        });
        // HIGHRES_IMU with every field: IMU and pressure, not its (bias-corrected) field.
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(highres(0x1fff)), &mut map);
        assert!(ev.iter().any(|e| matches!(e, SensorEvent::Imu(_))));
        assert!(!ev.iter().any(|e| matches!(e, SensorEvent::Mag(_))));
        assert_eq!(d.counters().highres_mag_ignored, 1);
        // SCALED_IMU 10 ms later: its field (mgauss × 100 nT), not its copy of the IMU.
        let ev = d.decode(
            &apm::MavMessage::SCALED_IMU(apm::SCALED_IMU_DATA {
                time_boot_ms: 1_010,
                xacc: 1000,
                xmag: 200,
                zmag: 450,
                ..Default::default()
            }),
            &mut map,
        );
        assert_eq!(ev.len(), 1);
        let SensorEvent::Mag(mag) = &ev[0] else {
            panic!("{ev:?}")
        };
        assert_eq!(mag.t_us, 1_010_000);
        assert!((mag.mag_b_nt - Vector3::new(20_000.0, 0.0, 45_000.0)).norm() < 1e-9);
        assert_eq!(d.counters().imu_lower_priority, 1);
    }

    #[test]
    fn magnetometer_from_scaled_imu_while_it_comes() {
        let mut d = InputDecoder::new(DecoderConfig {
            mag_from: MagFrom::ScaledImuWhileItComes,
            ..*decoder().config()
        });
        // x in nT, rounded: HIGHRES_IMU carries f32 gauss.
        let mags = |ev: &Events| -> Vec<f64> {
            ev.iter()
                .filter_map(|e| match e {
                    SensorEvent::Mag(m) => Some(m.mag_b_nt.x.round()),
                    _ => None,
                })
                .collect()
        };
        let at = |t_s: f64| apm::HIGHRES_IMU_DATA {
            time_usec: (t_s * 1e6) as u64,
            ..highres(0x1fff)
        };
        let scaled = |t_ms: u32| {
            apm::MavMessage::SCALED_IMU(apm::SCALED_IMU_DATA {
                time_boot_ms: t_ms,
                xmag: 300,
                ..Default::default()
            })
        };
        // No SCALED_IMU yet: HIGHRES_IMU's field (0.2 gauss).
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(at(1.0)), &mut map);
        assert_eq!(mags(&ev), [20_000.0]);
        // SCALED_IMU comes: its field, and HIGHRES_IMU's is left out within the hold.
        assert_eq!(mags(&d.decode(&scaled(1_010), &mut map)), [30_000.0]);
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(at(1.02)), &mut map);
        assert!(mags(&ev).is_empty() && ev.iter().any(|e| matches!(e, SensorEvent::Imu(_))));
        assert_eq!(d.counters().highres_mag_ignored, 1);
        // SCALED_IMU stops: past the hold, HIGHRES_IMU's field again.
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(at(2.02)), &mut map);
        assert_eq!(mags(&ev), [20_000.0]);
        // A decoder set to the IMU message ignores SCALED_IMU beside HIGHRES_IMU.
        d.set_mag_from(MagFrom::ImuMessage);
        assert!(mags(&d.decode(&scaled(2_030), &mut map)).is_empty());
    }

    #[test]
    fn gps_raw_int_units_velocity_and_sigmas() {
        let mut d = decoder();
        let mut m = apm::GPS_RAW_INT_DATA {
            time_usec: 2_000_000,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
            lat: 450_000_000,
            lon: -750_000_000,
            alt: 100_000,
            eph: 120,
            epv: 200,
            vel: 2000,
            cog: 9000,
            satellites_visible: 12,
            alt_ellipsoid: 66_000,
            h_acc: 1500,
            v_acc: 2500,
            vel_acc: 300,
            hdg_acc: 0,
            yaw: 0,
        };
        d.decode(
            &apm::MavMessage::GLOBAL_POSITION_INT(apm::GLOBAL_POSITION_INT_DATA {
                time_boot_ms: 1900,
                vz: -150,
                ..Default::default()
            }),
            &mut map,
        );
        let ev = d.decode(&apm::MavMessage::GPS_RAW_INT(m.clone()), &mut map);
        let SensorEvent::Gnss(fix) = &ev[0] else {
            panic!("{ev:?}")
        };
        assert!((fix.pos.lat_rad.to_degrees() - 45.0).abs() < 1e-12);
        assert!((fix.pos.lon_rad.to_degrees() + 75.0).abs() < 1e-12);
        assert!((fix.pos.h_m - 66.0).abs() < 1e-12);
        assert!((d.undulation_m().unwrap() + 34.0).abs() < 1e-12);
        // 20 m/s on course 090: due east; vz −150 cm/s = climbing at 1.5 m/s.
        assert!((fix.v_ned_mps - Vector3::new(0.0, 20.0, -1.5)).norm() < 1e-9);
        assert_eq!(
            (fix.sigma_hor_m, fix.sigma_ver_m, fix.sigma_vel_mps),
            (1.5, 2.5, 0.3)
        );
        // Without accuracies: DOP × UERE; without ellipsoid height: MSL, counted; without
        // a fresh vz: 0 and a 3 m/s σ.
        m.h_acc = 0;
        m.v_acc = 0;
        m.vel_acc = 0;
        m.alt_ellipsoid = 0;
        m.time_usec = 5_000_000;
        let ev = d.decode(&apm::MavMessage::GPS_RAW_INT(m.clone()), &mut map);
        let SensorEvent::Gnss(fix) = &ev[0] else {
            panic!()
        };
        assert!((fix.sigma_hor_m - 3.6).abs() < 1e-12);
        assert!((fix.sigma_ver_m - 6.0).abs() < 1e-12);
        assert_eq!(
            (fix.pos.h_m, fix.v_ned_mps.z, fix.sigma_vel_mps),
            (100.0, 0.0, 3.0)
        );
        assert_eq!(
            (d.counters().gnss_msl_height, d.counters().gnss_no_vd),
            (1, 1)
        );
        // 2D fix and unknown velocity are refused.
        m.fix_type = apm::GpsFixType::GPS_FIX_TYPE_2D_FIX;
        assert!(
            d.decode(&apm::MavMessage::GPS_RAW_INT(m.clone()), &mut map)
                .is_empty()
        );
        m.fix_type = apm::GpsFixType::GPS_FIX_TYPE_3D_FIX;
        m.vel = u16::MAX;
        assert!(
            d.decode(&apm::MavMessage::GPS_RAW_INT(m), &mut map)
                .is_empty()
        );
        assert_eq!(d.counters().no_fix, 2);
    }

    #[test]
    fn bad_values_are_rejected_and_counted_never_panic() {
        let mut d = decoder();
        d.decode(&vfr(30.0), &mut map);
        let mut m = highres(0x003f);
        m.xacc = f32::NAN;
        assert!(
            d.decode(&apm::MavMessage::HIGHRES_IMU(m), &mut map)
                .is_empty()
        );
        let mut m = highres(0x003f);
        m.zacc = -17.0 * 9.81; // 17 g
        assert!(
            d.decode(&apm::MavMessage::HIGHRES_IMU(m), &mut map)
                .is_empty()
        );
        let mut m = highres(0x0200 | 0x1000);
        m.abs_pressure = 5.0; // 500 Pa
        assert!(
            d.decode(&apm::MavMessage::HIGHRES_IMU(m), &mut map)
                .is_empty()
        );
        assert!(d.decode(&vfr(-3.0), &mut map).is_empty());
        assert!(d.decode(&vfr(f32::INFINITY), &mut map).is_empty());
        let c = *d.counters();
        assert_eq!((c.non_finite, c.out_of_range), (2, 3));
        // An unmappable time rejects the message.
        let ev = d.decode(&apm::MavMessage::HIGHRES_IMU(highres(0)), &mut |_| None);
        assert!(ev.is_empty());
        assert_eq!(d.counters().time, 1);
        // Pressure with no airspeed yet.
        let mut d = decoder();
        assert!(
            d.decode(&apm::MavMessage::HIGHRES_IMU(highres(0x1e00)), &mut map)
                .is_empty()
        );
        assert_eq!(d.counters().no_airspeed, 1);
    }

    #[test]
    fn attitude_is_kept_as_a_quaternion() {
        let mut d = decoder();
        d.decode(
            &apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA {
                time_boot_ms: 500,
                roll: 0.1,
                pitch: -0.05,
                yaw: 1.5,
                ..Default::default()
            }),
            &mut map,
        );
        let a = d.attitude().unwrap();
        assert_eq!(a.t_us, 500_000);
        let e = so3::euler_zyx(&a.q_nb);
        assert!((e - Vector3::new(1.5, -0.05, 0.1)).norm() < 1e-6);
    }

    /// A lagged fix takes the `vz` of its own time: 0.2 s behind the newest sample in a
    /// pull-up whose climb rate falls by 5 m/s per second, the newest would be 1 m/s off.
    #[test]
    fn the_down_velocity_is_taken_at_the_fix_time() {
        // vz at 5 Hz: −10 m/s (climbing) easing to 0 at 5 m/s².
        let history: VecDeque<(u64, f64)> = (0..=10)
            .map(|k| (k * 200_000, (-10.0 + 5.0 * 0.2 * k as f64).min(0.0)))
            .collect();
        let at = |t_us| vz_at(&history, t_us).unwrap();
        assert!((at(1_300_000) - (-3.5)).abs() < 1e-12);
        assert!((at(1_400_000) - (-3.0)).abs() < 1e-12);
        // Beyond the newest: the nearest within the age limit, then nothing.
        assert_eq!(vz_at(&history, 2_500_000), Some(0.0));
        assert_eq!(vz_at(&history, 2_000_000 + VZ_MAX_AGE_US + 1), None);
        assert_eq!(vz_at(&VecDeque::new(), 0), None);
    }
}
