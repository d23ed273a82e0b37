//! The SITL vehicle without its network: a simulated [`Flight`] seen through an autopilot's MAVLink
//! interface (docs/REFERENCES.md M3 for what an autopilot sends, M3.3 SET_MESSAGE_INTERVAL, M3.4
//! TIMESYNC, M2.1–M2.3 what a companion sends back).
//!
//! Synchronous and transport-free so that it can be tested message by message: the async
//! link (`super::link`) feeds it incoming messages, advances it on the simulated clock and
//! ships what it queues. The vehicle's boot clock is the flight's sensor clock (`t_us` from
//! the start of the warm-up): `time_usec`, `time_boot_ms`, TIMESYNC `tc1` and the camera
//! frame stamps all count on it.
//!
//! What it reports as its own estimate (ATTITUDE, GLOBAL_POSITION_INT, VFR_HUD) is the estimate its
//! guidance flies on: the vehicle's own INS (the simulator's EKF, with its realistic errors), or,
//! after GNSS loss, the companion's horizontal position (`docs/SITL.md`, "Flying on the daemon's
//! position after GNSS loss").
//!
//! Message content follows the imitated autopilot (`docs/SITL.md` has the
//! side-by-side table): **ArduPilot** sends the latest IMU sample as `float × 1000` truncated
//! to int16, optionally with SITL's gyro drift triangle added; AOA_SSA computed as ArduPlane's AHRS does,
//! from the vehicle's own velocity, wind and attitude estimates (not a vane, so it feeds the
//! navigation solution back); GPS_RAW_INT stamped when the lagged fix was received, without
//! speed accuracy; a second barometer in SCALED_PRESSURE2; AIRSPEED `raw_press` in Pa.
//! **PX4** v1.16 sends HIGHRES_IMU box averages with its pressures in Pa and `fields_updated`
//! only for new data, and has no AIRSPEED or AOA_SSA. **Ideal** sends every simulated sample
//! as the MAVLink definitions say. Any stream can be delayed by a configured latency.

use std::collections::VecDeque;

use ianav::env::atmosphere;
use ianav::math::map_projection::MapProjection;
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav::sensors::{AirSample, Frame, GnssFix, ImuSample, MagSample, SensorEvent};
use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MavHeader, MessageData};

use nalgebra::Vector3;

use super::convert::{self, ExternalFix, ExternalFixError};
use super::streams::{Autopilot, ImuAverager, IntervalOutcome, STREAMABLE, Streams, stream_index};
use super::timesync::ClockMap;
use crate::flight::{Flight, FlightError, FlightObserver, FlightSetup, PositionAid};
use crate::rng;

/// Satellites the simulated receiver reports with a fix (it has no constellation model).
pub const SATELLITES_WITH_FIX: u8 = 12;
/// How far back truth is kept to compare estimates at their time of validity, µs.
pub const TRUTH_HISTORY_US: u64 = 10_000_000;
/// Window of the estimate-rate measurement, µs of vehicle time.
pub const RATE_WINDOW_US: u64 = 1_000_000;

/// ArduPilot SITL's gyro drift rate of change, rad/s per minute (`SIM_DRIFT_SPEED` 0.05°/s).
pub const GYRO_DRIFT_RPS_PER_MIN: f64 = 0.05 * std::f64::consts::PI / 180.0;
/// ArduPilot SITL's gyro drift half-period, minutes (`SIM_DRIFT_TIME`).
pub const GYRO_DRIFT_HALF_PERIOD_MIN: f64 = 5.0;
/// ArduPilot SITL's GNSS receiver lag, µs (`SIM_GPS1_LAG_MS` 100).
pub const ARDUPILOT_GNSS_LAG_US: u64 = 100_000;
/// Satellites ArduPilot SITL's first receiver reports once disabled (it "starts sending back
/// 3 satellites", `SIM_GPS.cpp`).
pub const ARDUPILOT_SATELLITES_WITHOUT_LOCK: u8 = 3;
/// ArduPilot computes AOA_SSA at most every 50 ms (`AP_AHRS::update_AOA_SSA`).
pub const ARDUPILOT_AOA_SSA_PERIOD_MS: u64 = 50;
/// Constant offset of the second barometer, 1-σ over seeds, Pa (our assumption: a different
/// physical sensor; ArduPilot SITL gives its second barometer independent noise only).
pub const BARO2_OFFSET_SIGMA_PA: f64 = 30.0;
/// Second barometer's noise: uniform within ± this height, m (ArduPilot SITL `SIM_BAR2_RND`).
pub const BARO2_NOISE_M: f64 = 0.2;

/// Vehicle settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleConfig {
    /// Autopilot imitated.
    pub autopilot: Autopilot,
    /// MAVLink system id of the vehicle.
    pub system_id: u8,
    /// MAVLink component id of the autopilot (1 = MAV_COMP_ID_AUTOPILOT1).
    pub component_id: u8,
    /// After GNSS loss, fly on the companion's horizontal position (`docs/SITL.md`).
    pub fly_on_estimates: bool,
    /// Age beyond which a companion position is no longer flown on, µs of vehicle time.
    pub estimate_timeout_us: u64,
    /// Add ArduPilot SITL's gyro drift (a triangle on all three axes, 0.05°/s per minute up
    /// to 0.25°/s over 5 min and back) to the gyro rates sent. The vehicle's own INS does not
    /// see it (an autopilot's EKF estimates it away). Off by default: today's daemon diverges
    /// on it (docs/E2E.md), so the end-to-end CI flight would only show that.
    pub gyro_drift: bool,
    /// GNSS receiver lag, µs: a fix of the truth at `t` reaches the autopilot, and its
    /// GPS_RAW_INT, at `t + lag` and is stamped with that reception time.
    pub gnss_lag_us: u64,
    /// ArduPilot: from this boot time on (µs) the airspeed sensor is flagged unhealthy, as
    /// ArduPlane does when it stops trusting it: AIRSPEED carries the UNHEALTHY flag (not
    /// USING) and VFR_HUD's airspeed becomes the AHRS estimate (`airspeed_estimate`, the
    /// equivalent airspeed of the vehicle's own navigation estimate). `None`: always healthy.
    pub airspeed_unhealthy_from_us: Option<u64>,
    /// Transport and processing latency of each stream (indexed like
    /// [`super::streams::STREAMABLE`]), µs of vehicle time: a message built at `t` leaves at
    /// `t + latency` (on the 10 ms sensor grid), with its content and stamps of `t`.
    pub latency_us: [u64; STREAMABLE.len()],
}

impl VehicleConfig {
    /// The defaults of `autopilot`: ArduPilot with its SITL's 100 ms GNSS lag; no gyro drift,
    /// no added latency.
    pub fn for_autopilot(autopilot: Autopilot) -> Self {
        let ardupilot = autopilot == Autopilot::ArduPilot;
        Self {
            autopilot,
            system_id: 1,
            component_id: 1,
            fly_on_estimates: true,
            estimate_timeout_us: 1_000_000,
            gyro_drift: false,
            gnss_lag_us: if ardupilot { ARDUPILOT_GNSS_LAG_US } else { 0 },
            airspeed_unhealthy_from_us: None,
            latency_us: [0; STREAMABLE.len()],
        }
    }

    /// The same latency for every stream.
    pub fn with_latency_us(mut self, latency_us: u64) -> Self {
        self.latency_us = [latency_us; STREAMABLE.len()];
        self
    }
}

impl Default for VehicleConfig {
    fn default() -> Self {
        Self::for_autopilot(Autopilot::Px4)
    }
}

/// ArduPilot SITL's gyro drift at boot time `t_us`, rad/s (the same on every axis): rises at
/// [`GYRO_DRIFT_RPS_PER_MIN`] for [`GYRO_DRIFT_HALF_PERIOD_MIN`] minutes, then falls back.
pub fn ardupilot_gyro_drift_rps(t_us: u64) -> f64 {
    let period_min = 2.0 * GYRO_DRIFT_HALF_PERIOD_MIN;
    let minutes = (t_us as f64 / 60e6).rem_euclid(period_min);
    let ramp_min = if minutes < GYRO_DRIFT_HALF_PERIOD_MIN {
        minutes
    } else {
        period_min - minutes
    };
    ramp_min * GYRO_DRIFT_RPS_PER_MIN
}

/// What the simulated receiver last reported.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GnssReport {
    /// A 3D fix (of the truth at `fix.t_us`), received by the autopilot at `rx_us`.
    Fix {
        /// The fix.
        fix: GnssFix,
        /// Reception by the autopilot, µs (`fix.t_us` + receiver lag).
        rx_us: u64,
    },
    /// The receiver runs but has no fix (after the scenario's GNSS loss).
    NoFix {
        /// Report time, µs.
        t_us: u64,
    },
    /// ArduPilot after its receiver lost lock: no fix, the last fix's time kept.
    NoGps {
        /// Reception of the last fix, µs.
        last_fix_rx_us: u64,
    },
}

/// How the time of validity of a companion estimate was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeBasis {
    /// Its timestamp is on the vehicle's boot clock (within the last 10 s, not ahead).
    Stamp,
    /// Its timestamp is on the companion's clock, mapped through the TIMESYNC exchanges.
    Timesync,
    /// Its timestamp is on another clock: the arrival time is used.
    Arrival,
}

/// Which companion message carried an estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EstimateKind {
    /// ODOMETRY (331).
    Odometry,
    /// VISION_POSITION_ESTIMATE (102).
    VisionPosition,
    /// GPS_INPUT (232).
    GpsInput,
}

impl EstimateKind {
    /// MAVLink message name.
    pub fn name(self) -> &'static str {
        match self {
            EstimateKind::Odometry => "ODOMETRY",
            EstimateKind::VisionPosition => "VISION_POSITION_ESTIMATE",
            EstimateKind::GpsInput => "GPS_INPUT",
        }
    }
}

/// One companion estimate compared with the truth (a row of `sitl.csv`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimateRow {
    /// Arrival, µs of vehicle time.
    pub t_rx_us: u64,
    /// Time of validity used, µs of vehicle time.
    pub t_valid_us: u64,
    /// How `t_valid_us` was obtained.
    pub basis: TimeBasis,
    /// Message.
    pub kind: EstimateKind,
    /// Sender.
    pub system_id: u32,
    /// Sender component.
    pub component_id: u8,
    /// Truth at `t_valid_us`.
    pub truth: Geodetic,
    /// The estimate.
    pub estimate: Geodetic,
    /// Horizontal error, m.
    pub hor_err_m: f64,
    /// Vertical error (estimate − truth), m.
    pub ver_err_m: f64,
    /// Estimates received in the last second of vehicle time, Hz.
    pub rate_hz: f64,
    /// Whether guidance was flying on the companion's position when it arrived.
    pub aided: bool,
}

/// Counters of the vehicle.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VehicleStats {
    /// Messages queued for sending.
    pub queued: u64,
    /// Messages received (all kinds).
    pub received: u64,
    /// TIMESYNC requests answered.
    pub timesync_answered: u64,
    /// Answers to the vehicle's TIMESYNC requests used for the companion clock map.
    pub timesync_pairs: u64,
    /// COMMAND_LONG handled (acknowledged).
    pub commands: u64,
    /// Usable companion estimates.
    pub estimates: u64,
    /// Companion estimates refused (no origin, unsupported frame, invalid values, no fix).
    pub estimates_refused: u64,
    /// Vehicle time of the first and last usable estimate, µs.
    pub estimate_span_us: Option<(u64, u64)>,
    /// Camera frames produced.
    pub frames: u64,
    /// Sensor instants at which guidance flew on the companion's position.
    pub aided_ticks: u64,
    /// Sensor instants after GNSS loss.
    pub ticks_after_loss: u64,
}

/// Collects a step's sensor events.
#[derive(Default)]
struct Collector {
    events: Vec<SensorEvent>,
}

impl FlightObserver for Collector {
    fn sensor_event(&mut self, event: &SensorEvent) {
        self.events.push(event.clone());
    }
}

/// The SITL vehicle.
pub struct Vehicle {
    flight: Flight,
    collector: Collector,
    cfg: VehicleConfig,
    streams: Streams,
    highres_avg: ImuAverager,
    scaled_avg: ImuAverager,
    raw_avg: ImuAverager,
    last_imu: Option<ImuSample>,
    last_air: Option<AirSample>,
    last_mag: Option<MagSample>,
    gnss: Option<GnssReport>,
    gnss_fresh: bool,
    gnss_period_us: u64,
    /// Fixes taken but not yet received by the autopilot (receiver lag).
    pending_fixes: VecDeque<GnssFix>,
    /// Messages built but held back by their stream's latency: (release time µs, message),
    /// in release order.
    delayed: VecDeque<(u64, apm::MavMessage)>,
    /// ArduPilot's AOA_SSA state: angles (deg) and the time of their last update (ms).
    aoa_ssa_deg: Option<(f64, f64)>,
    aoa_ssa_ms: Option<u64>,
    /// Second barometer: constant offset (Pa) and its noise generator.
    baro2_offset_pa: f64,
    baro2_rng: rng::Stream,
    /// Times of the magnetometer and air samples last reported in HIGHRES_IMU (PX4 sets
    /// `fields_updated` only for new data).
    highres_mag_t_us: Option<u64>,
    highres_air_t_us: Option<u64>,
    /// Id of the last chunked STATUSTEXT.
    statustext_id: u16,
    origin: Option<MapProjection>,
    home_h_m: f64,
    boot_unix_us: u64,
    unix_time_valid: bool,
    truth_history: VecDeque<(u64, Geodetic)>,
    estimate_arrivals: VecDeque<u64>,
    aided: bool,
    clock_map: ClockMap,
    /// Components whose HEARTBEAT has been seen (a few; for the log).
    peers: Vec<(u32, u8)>,
    outbox: Vec<apm::MavMessage>,
    frames: Vec<Frame>,
    rows: Vec<EstimateRow>,
    notices: Vec<String>,
    stats: VehicleStats,
}

/// UNIX time of a decimal year, µs (proleptic Gregorian calendar, no leap seconds).
pub fn unix_us_of_decimal_year(year: f64) -> u64 {
    let y = year.floor() as i64;
    let days_to = |y: i64| -> i64 {
        // Days from 1970-01-01 to y-01-01.
        let y1 = y - 1;
        365 * (y - 1970) + (y1 / 4 - 1969 / 4) - (y1 / 100 - 1969 / 100) + (y1 / 400 - 1969 / 400)
    };
    let start_s = days_to(y) as f64 * 86_400.0;
    let year_s = (days_to(y + 1) - days_to(y)) as f64 * 86_400.0;
    ((start_s + (year - y as f64) * year_s) * 1e6).max(0.0) as u64
}

impl Vehicle {
    /// The vehicle flying `setup` with `seed`.
    pub fn new(setup: &FlightSetup, seed: u64, cfg: VehicleConfig) -> Result<Self, FlightError> {
        // The vehicle's frames are the daemon's to navigate on: its own navigator (what
        // guidance flies on) runs the INS only.
        let mut setup = setup.clone();
        if let Some(camera) = setup.camera.as_mut() {
            camera.vision_navigation = false;
        }
        let setup = &setup;
        let flight = Flight::new(setup, seed)?;
        let gnss_period_us = (setup.sensors.gnss.period_s * 1e6).round().max(1.0) as u64;
        Ok(Self {
            flight,
            collector: Collector::default(),
            cfg,
            streams: Streams::new(cfg.autopilot),
            highres_avg: ImuAverager::default(),
            scaled_avg: ImuAverager::default(),
            raw_avg: ImuAverager::default(),
            last_imu: None,
            last_air: None,
            last_mag: None,
            gnss: None,
            gnss_fresh: false,
            gnss_period_us,
            pending_fixes: VecDeque::new(),
            delayed: VecDeque::new(),
            aoa_ssa_deg: None,
            aoa_ssa_ms: None,
            baro2_offset_pa: BARO2_OFFSET_SIGMA_PA
                * rng::normal(&mut rng::stream(seed, "sitl.baro2.offset")),
            baro2_rng: rng::stream(seed, "sitl.baro2.noise"),
            highres_mag_t_us: None,
            highres_air_t_us: None,
            statustext_id: 0,
            origin: None,
            home_h_m: 0.0,
            boot_unix_us: unix_us_of_decimal_year(setup.scenario.magnetic_decimal_year),
            unix_time_valid: false,
            truth_history: VecDeque::with_capacity(1100),
            estimate_arrivals: VecDeque::with_capacity(256),
            aided: false,
            clock_map: ClockMap::default(),
            peers: Vec::new(),
            outbox: Vec::with_capacity(64),
            frames: Vec::new(),
            rows: Vec::new(),
            notices: Vec::new(),
            stats: VehicleStats::default(),
        })
    }

    /// Vehicle (boot) time, µs.
    pub fn t_us(&self) -> u64 {
        self.flight.t_us()
    }

    /// The flight.
    pub fn flight(&self) -> &Flight {
        &self.flight
    }

    /// Settings.
    pub fn config(&self) -> &VehicleConfig {
        &self.cfg
    }

    /// The stream table.
    pub fn streams(&self) -> &Streams {
        &self.streams
    }

    /// Counters.
    pub fn stats(&self) -> &VehicleStats {
        &self.stats
    }

    /// Whether the mission is over.
    pub fn finished(&self) -> bool {
        self.flight.finished()
    }

    /// The local-frame origin used for ODOMETRY and VISION_POSITION_ESTIMATE.
    pub fn origin(&self) -> Option<Geodetic> {
        self.origin.as_ref().map(MapProjection::origin)
    }

    /// Messages queued since the last call.
    pub fn take_outbox(&mut self) -> Vec<apm::MavMessage> {
        std::mem::take(&mut self.outbox)
    }

    /// Camera frames produced since the last call.
    pub fn take_frames(&mut self) -> Vec<Frame> {
        std::mem::take(&mut self.frames)
    }

    /// Estimate rows since the last call.
    pub fn take_rows(&mut self) -> Vec<EstimateRow> {
        std::mem::take(&mut self.rows)
    }

    /// State changes worth a log line since the last call.
    pub fn take_notices(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notices)
    }

    /// Whether guidance flies on the companion's position now.
    pub fn aided(&self) -> bool {
        self.aided
    }

    /// Estimates received in the last second of vehicle time, Hz.
    pub fn estimate_rate_hz(&self) -> f64 {
        self.estimate_arrivals.len() as f64 * 1e6 / RATE_WINDOW_US as f64
    }

    /// Fly until the vehicle clock reaches `t_us` (or the mission ends).
    pub fn advance_to(&mut self, t_us: u64) -> Result<(), FlightError> {
        while self.flight.t_us() < t_us && !self.flight.finished() {
            self.flight.step(&mut self.collector)?;
            if !self.collector.events.is_empty() {
                let events = std::mem::take(&mut self.collector.events);
                self.on_events(events);
            }
        }
        Ok(())
    }

    fn on_events(&mut self, mut events: Vec<SensorEvent>) {
        let mut imu_t_us = None;
        for event in events.drain(..) {
            match event {
                SensorEvent::Imu(s) => {
                    self.highres_avg.add(&s);
                    self.scaled_avg.add(&s);
                    self.raw_avg.add(&s);
                    imu_t_us = Some(s.t_us);
                    self.last_imu = Some(s);
                }
                SensorEvent::Air(s) => self.last_air = Some(s),
                SensorEvent::Mag(s) => self.last_mag = Some(s),
                SensorEvent::Gnss(fix) => self.pending_fixes.push_back(fix),
                SensorEvent::Frame(f) => {
                    self.stats.frames += 1;
                    self.frames.push(f);
                }
                // The flight's sensors make none; the vehicle reports its own estimate.
                SensorEvent::RefAttitude(_)
                | SensorEvent::Alignment(_)
                | SensorEvent::HeightAboveTerrain(_)
                | SensorEvent::VisionApplied(_) => {}
            }
        }
        self.collector.events = events;
        if let Some(t_us) = imu_t_us {
            self.tick(t_us);
        }
    }

    fn on_fix(&mut self, fix: GnssFix, rx_us: u64) {
        if self.origin.is_none() {
            // The EKF origin and home: the first fix, as both autopilots set them.
            self.origin = Some(MapProjection::new(&fix.pos));
            self.home_h_m = fix.pos.h_m;
            self.queue_origin();
        }
        self.unix_time_valid = true;
        self.gnss = Some(GnssReport::Fix { fix, rx_us });
        self.gnss_fresh = true;
    }

    /// One sensor instant of the vehicle's loop.
    fn tick(&mut self, t_us: u64) {
        let loss_us = self.flight.gnss_loss_t_us();
        // Fixes reach the autopilot after the receiver lag (on the 10 ms grid).
        while let Some(fix) = self
            .pending_fixes
            .front()
            .copied()
            .filter(|f| f.t_us + self.cfg.gnss_lag_us <= t_us)
        {
            self.pending_fixes.pop_front();
            self.on_fix(fix, t_us);
        }
        if self.cfg.autopilot == Autopilot::ArduPilot {
            // ArduPilot SITL with GPS 1 disabled keeps sending, without lock and with 3
            // satellites; the driver reports NO_FIX and GPS_RAW_INT keeps the time of the last
            // fix (`last_fix_time_ms` only moves with a fix).
            let rx_us = match self.gnss {
                Some(GnssReport::Fix { rx_us, .. }) => Some(rx_us),
                Some(GnssReport::NoGps { last_fix_rx_us }) => Some(last_fix_rx_us),
                _ => None,
            };
            // The receiver's reports after the loss, received after its lag.
            let lag_us = self.cfg.gnss_lag_us;
            if let Some(rx_us) = rx_us
                && t_us > loss_us + lag_us
                && (t_us - lag_us).is_multiple_of(self.gnss_period_us)
            {
                self.gnss = Some(GnssReport::NoGps {
                    last_fix_rx_us: rx_us,
                });
                self.gnss_fresh = true;
            }
        } else if t_us > loss_us && t_us.is_multiple_of(self.gnss_period_us) {
            // The receiver keeps reporting, without a fix.
            self.gnss = Some(GnssReport::NoFix { t_us });
            self.gnss_fresh = true;
        }
        self.truth_history
            .push_back((t_us, self.flight.truth().pos));
        while self
            .truth_history
            .front()
            .is_some_and(|&(t, _)| t + TRUTH_HISTORY_US < t_us)
        {
            self.truth_history.pop_front();
        }
        while self
            .estimate_arrivals
            .front()
            .is_some_and(|&t| t + RATE_WINDOW_US <= t_us)
        {
            self.estimate_arrivals.pop_front();
        }
        if t_us > loss_us {
            self.stats.ticks_after_loss += 1;
        }
        let aided = self.flight.position_aid_used();
        if aided {
            self.stats.aided_ticks += 1;
        }
        if aided != self.aided {
            let t_s = self.flight.mission_time_s();
            self.notices.push(if aided {
                format!("t = {t_s:.2} s: flying on the companion's position")
            } else {
                format!(
                    "t = {t_s:.2} s: companion position older than {:.1} s, flying on the vehicle's INS",
                    self.cfg.estimate_timeout_us as f64 * 1e-6
                )
            });
            self.aided = aided;
        }
        let fresh_gnss = self.gnss_fresh;
        let due = self
            .streams
            .due(t_us, |id| id == apm::GPS_RAW_INT_DATA::ID && fresh_gnss);
        if self.streams.is_loop_tick(t_us) {
            self.gnss_fresh = false;
        }
        if self.cfg.autopilot == Autopilot::ArduPilot && self.streams.is_loop_tick(t_us) {
            self.update_aoa_ssa(t_us);
        }
        for id in due {
            if let Some(msg) = self.build(id, t_us) {
                let latency_us = stream_index(id).map_or(0, |i| self.cfg.latency_us[i]);
                if latency_us == 0 {
                    self.queue(msg);
                } else {
                    let release_us = t_us + latency_us;
                    let at = self.delayed.partition_point(|(r, _)| *r <= release_us);
                    self.delayed.insert(at, (release_us, msg));
                }
            }
        }
        while self.delayed.front().is_some_and(|(r, _)| *r <= t_us) {
            if let Some((_, msg)) = self.delayed.pop_front() {
                self.queue(msg);
            }
        }
        // Averages of streams that are off must not pile up.
        for (id, avg) in [
            (apm::HIGHRES_IMU_DATA::ID, &mut self.highres_avg),
            (apm::SCALED_IMU_DATA::ID, &mut self.scaled_avg),
            (apm::RAW_IMU_DATA::ID, &mut self.raw_avg),
        ] {
            if self.streams.interval_us(id).is_none() {
                avg.clear();
            }
        }
    }

    fn queue(&mut self, msg: apm::MavMessage) {
        self.stats.queued += 1;
        self.outbox.push(msg);
    }

    fn queue_origin(&mut self) {
        if let Some(o) = self.origin() {
            let t_us = self.t_us();
            self.queue(apm::MavMessage::GPS_GLOBAL_ORIGIN(
                apm::GPS_GLOBAL_ORIGIN_DATA {
                    latitude: convert::deg_e7(o.lat_rad),
                    longitude: convert::deg_e7(o.lon_rad),
                    altitude: convert::mm(o.h_m),
                    time_usec: t_us,
                },
            ));
        }
    }

    /// The IMU sample an int16 IMU stream reports at `t_us`: ArduPilot's latest sample, else
    /// the box average since the stream's previous message; with the gyro drift added when
    /// configured.
    fn imu_for_stream(&mut self, stream: ImuStream, t_us: u64) -> Option<ImuSample> {
        let avg = match stream {
            ImuStream::Scaled => &mut self.scaled_avg,
            ImuStream::Raw => &mut self.raw_avg,
        };
        let mut imu = if self.cfg.autopilot == Autopilot::ArduPilot {
            avg.clear();
            let mut s = self.last_imu?;
            s.t_us = t_us;
            s
        } else {
            avg.take(t_us)?
        };
        if self.cfg.gyro_drift {
            imu.gyro_rps += Vector3::repeat(ardupilot_gyro_drift_rps(t_us));
        }
        Some(imu)
    }

    /// The int16 triplets of an IMU message: ArduPilot converts its floats with a C cast
    /// (truncation toward zero), the others round to nearest.
    fn int16_triplets(&self, imu: &ImuSample, mag: &MagSample) -> ([i16; 3], [i16; 3], [i16; 3]) {
        if self.cfg.autopilot == Autopilot::ArduPilot {
            let a = imu
                .accel_mps2
                .map(|v| convert::trunc_i16(v / ianav::env::atmosphere::G0_MPS2 * 1e3));
            let g = imu.gyro_rps.map(|v| convert::trunc_i16(v * 1e3));
            let m = mag
                .mag_b_nt
                .map(|v| convert::trunc_i16(v / convert::NT_PER_GAUSS * 1e3));
            ([a.x, a.y, a.z], [g.x, g.y, g.z], [m.x, m.y, m.z])
        } else {
            scaled_triplets(imu, mag)
        }
    }

    /// ArduPilot's AOA_SSA (`AP_AHRS::update_AOA_SSA`, at most every 50 ms): the vehicle's
    /// navigation velocity minus its wind estimate, in body axes of its attitude estimate.
    /// Below 2 m/s both are 0; the angle of attack is 0 when flying backwards.
    fn update_aoa_ssa(&mut self, t_us: u64) {
        let now_ms = t_us / 1000;
        if self
            .aoa_ssa_ms
            .is_some_and(|last| now_ms - last < ARDUPILOT_AOA_SSA_PERIOD_MS)
        {
            return;
        }
        self.aoa_ssa_ms = Some(now_ms);
        self.aoa_ssa_deg = Some(aoa_ssa_from_estimate_deg(
            self.flight.estimate(),
            &self.nav_wind_ned_mps(),
        ));
    }

    /// Whether ArduPilot's airspeed sensor is flagged unhealthy at `t_us`.
    fn airspeed_unhealthy(&self, t_us: u64) -> bool {
        self.cfg.autopilot == Autopilot::ArduPilot
            && self
                .cfg
                .airspeed_unhealthy_from_us
                .is_some_and(|t0| t_us >= t0)
    }

    /// ArduPlane's AHRS airspeed estimate (equivalent airspeed) from the vehicle's navigation
    /// estimate: its true airspeed × √(ρ/ρ₀), at its pressure altitude and its INS's outside
    /// air temperature (the ISA temperature under truth navigation).
    pub fn ahrs_eas_mps(&self) -> f64 {
        use ianav::env::atmosphere as atm;
        let est = self.flight.estimate();
        let temp_k = self
            .flight
            .nav_solution()
            .map_or_else(|| atm::isa_temperature_k(est.hp_m), |s| s.ins.temp_k);
        let rho = atm::density_kgpm3(atm::pressure_pa(est.hp_m), temp_k);
        let rho0 = atm::density_kgpm3(atm::P0_PA, atm::T0_K);
        est.tas_mps * (rho / rho0).sqrt()
    }

    /// The wind the vehicle's navigation estimates (its INS), or the truth's under truth
    /// navigation.
    pub fn nav_wind_ned_mps(&self) -> Vector3<f64> {
        match self.flight.nav_solution() {
            Some(sol) => sol.ins.wind_ned_mps,
            None => self.flight.truth_sample().wind_ned_mps,
        }
    }

    /// Static pressure of the second barometer, Pa: the true static pressure plus its own
    /// constant offset and uniform noise of ± [`BARO2_NOISE_M`] (converted at the local
    /// pressure gradient `−p·g/(R·T)`).
    fn baro2_pa(&mut self, temp_k: f64) -> f64 {
        use ianav::env::atmosphere as atm;
        let p_true_pa = atm::pressure_pa(self.flight.truth_sample().hp_m);
        let pa_per_m = p_true_pa * atm::G0_MPS2 / (atm::R_JPKGK * temp_k);
        let u: f64 = rand::RngExt::random_range(&mut self.baro2_rng, -1.0..=1.0);
        p_true_pa + self.baro2_offset_pa + u * BARO2_NOISE_M * pa_per_m
    }

    /// Queue a STATUSTEXT as ArduPilot sends long texts: 50-byte chunks sharing an id.
    fn statustext(&mut self, severity: apm::MavSeverity, text: &str) {
        let bytes = text.as_bytes();
        let chunked = bytes.len() > 50;
        if chunked {
            self.statustext_id = self.statustext_id.wrapping_add(1).max(1);
        }
        for (seq, chunk) in bytes.chunks(50).enumerate() {
            let mut buf = [0_u8; 50];
            buf[..chunk.len()].copy_from_slice(chunk);
            self.queue(apm::MavMessage::STATUSTEXT(apm::STATUSTEXT_DATA {
                severity,
                text: buf.into(),
                id: if chunked { self.statustext_id } else { 0 },
                chunk_seq: u8::try_from(seq).unwrap_or(u8::MAX),
            }));
        }
    }

    /// Message `id` now (`None` when its data does not exist yet, e.g. no vanes fitted).
    pub fn build(&mut self, id: u32, t_us: u64) -> Option<apm::MavMessage> {
        let boot_ms = (t_us / 1000) as u32;
        let air = self.last_air;
        let mag = self.last_mag;
        let msg = match id {
            apm::HEARTBEAT_DATA::ID => apm::MavMessage::HEARTBEAT(self.heartbeat()),
            // A TIMESYNC request (broadcast), as PX4 sends them.
            apm::TIMESYNC_DATA::ID => apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                tc1: 0,
                ts1: i64::try_from(t_us.saturating_mul(1000)).unwrap_or(i64::MAX),
                target_system: 0,
                target_component: 0,
            }),
            apm::SYSTEM_TIME_DATA::ID => apm::MavMessage::SYSTEM_TIME(apm::SYSTEM_TIME_DATA {
                time_unix_usec: if self.unix_time_valid {
                    self.boot_unix_us + t_us
                } else {
                    0
                },
                time_boot_ms: boot_ms,
            }),
            apm::HIGHRES_IMU_DATA::ID => {
                let imu = self.highres_avg.take(t_us)?;
                let (air, mag) = (air.as_ref()?, mag.as_ref()?);
                let mut m = highres_imu(&imu, air, mag);
                if self.cfg.autopilot == Autopilot::Px4 {
                    // PX4 v1.16.0 fills the pressures in Pa (the MAVLink definition says
                    // hPa) and flags only the fields that hold new data.
                    m.abs_pressure = air.p_pa as f32;
                    m.diff_pressure =
                        convert::impact_pressure_pa(air.tas_mps, air.p_pa, air.temp_k) as f32;
                    let mut bits = 0x3F_u16;
                    if self.highres_mag_t_us != Some(mag.t_us) {
                        bits |= 0x1C0;
                    }
                    if self.highres_air_t_us != Some(air.t_us) {
                        bits |= 0x1E00;
                    }
                    m.fields_updated = apm::HighresImuUpdatedFlags::from_bits_truncate(bits);
                }
                self.highres_mag_t_us = Some(mag.t_us);
                self.highres_air_t_us = Some(air.t_us);
                apm::MavMessage::HIGHRES_IMU(m)
            }
            apm::SCALED_IMU_DATA::ID => {
                let imu = self.imu_for_stream(ImuStream::Scaled, t_us)?;
                let (a, g, m) = self.int16_triplets(&imu, mag.as_ref()?);
                apm::MavMessage::SCALED_IMU(apm::SCALED_IMU_DATA {
                    time_boot_ms: boot_ms,
                    xacc: a[0],
                    yacc: a[1],
                    zacc: a[2],
                    xgyro: g[0],
                    ygyro: g[1],
                    zgyro: g[2],
                    xmag: m[0],
                    ymag: m[1],
                    zmag: m[2],
                    // 0: the IMU reports no temperature.
                    temperature: 0,
                })
            }
            apm::RAW_IMU_DATA::ID => {
                // ArduPilot fills RAW_IMU with scaled values (mG, mrad/s, mgauss).
                let imu = self.imu_for_stream(ImuStream::Raw, t_us)?;
                let (a, g, m) = self.int16_triplets(&imu, mag.as_ref()?);
                apm::MavMessage::RAW_IMU(apm::RAW_IMU_DATA {
                    time_usec: t_us,
                    xacc: a[0],
                    yacc: a[1],
                    zacc: a[2],
                    xgyro: g[0],
                    ygyro: g[1],
                    zgyro: g[2],
                    xmag: m[0],
                    ymag: m[1],
                    zmag: m[2],
                    id: 0,
                    temperature: 0,
                })
            }
            apm::SCALED_PRESSURE_DATA::ID => {
                let air = air?;
                let qc_pa = convert::impact_pressure_pa(air.tas_mps, air.p_pa, air.temp_k);
                let ardupilot = self.cfg.autopilot == Autopilot::ArduPilot;
                apm::MavMessage::SCALED_PRESSURE(apm::SCALED_PRESSURE_DATA {
                    // ArduPilot stamps the send time (its latest baro sample), PX4 the sample.
                    time_boot_ms: if ardupilot {
                        boot_ms
                    } else {
                        (air.t_us / 1000) as u32
                    },
                    press_abs: (air.p_pa * convert::HPA_PER_PA) as f32,
                    press_diff: (qc_pa * convert::HPA_PER_PA) as f32,
                    temperature: if ardupilot {
                        convert::trunc_i16((air.temp_k - convert::CELSIUS_ZERO_K) * 100.0)
                    } else {
                        convert::cdeg_c(air.temp_k)
                    },
                    temperature_press_diff: 0,
                })
            }
            apm::SCALED_PRESSURE2_DATA::ID => {
                // ArduPilot's second barometer; PX4 SIH simulates one.
                if self.cfg.autopilot != Autopilot::ArduPilot {
                    return None;
                }
                let air = air?;
                let p_pa = self.baro2_pa(air.temp_k);
                apm::MavMessage::SCALED_PRESSURE2(apm::SCALED_PRESSURE2_DATA {
                    time_boot_ms: boot_ms,
                    press_abs: (p_pa * convert::HPA_PER_PA) as f32,
                    // No second airspeed sensor: ArduPilot sends 0.
                    press_diff: 0.0,
                    temperature: convert::trunc_i16((air.temp_k - convert::CELSIUS_ZERO_K) * 100.0),
                    temperature_press_diff: 0,
                })
            }
            apm::AIRSPEED_DATA::ID => {
                let air = air?;
                let mut m = airspeed(&air);
                if self.cfg.autopilot == Autopilot::ArduPilot {
                    // ArduPilot sends the differential pressure in Pa (the MAVLink definition
                    // says hPa) and truncates the temperature.
                    m.raw_press =
                        convert::impact_pressure_pa(air.tas_mps, air.p_pa, air.temp_k) as f32;
                    m.temperature =
                        convert::trunc_i16((air.temp_k - convert::CELSIUS_ZERO_K) * 100.0);
                    if self.airspeed_unhealthy(t_us) {
                        m.flags = apm::AirspeedSensorFlags::AIRSPEED_SENSOR_UNHEALTHY;
                    }
                }
                apm::MavMessage::AIRSPEED(m)
            }
            apm::AOA_SSA_DATA::ID => match self.cfg.autopilot {
                // ArduPlane's AOA_SSA is its AHRS estimate, not a vane.
                Autopilot::ArduPilot => {
                    let (aoa_deg, ssa_deg) = self.aoa_ssa_deg?;
                    apm::MavMessage::AOA_SSA(apm::AOA_SSA_DATA {
                        time_usec: t_us,
                        AOA: aoa_deg as f32,
                        SSA: ssa_deg as f32,
                    })
                }
                Autopilot::Ideal => {
                    let air = air?;
                    apm::MavMessage::AOA_SSA(apm::AOA_SSA_DATA {
                        time_usec: air.t_us,
                        AOA: air.aoa_rad?.to_degrees() as f32,
                        SSA: air.aos_rad?.to_degrees() as f32,
                    })
                }
                Autopilot::Px4 => return None,
            },
            apm::GPS_RAW_INT_DATA::ID => {
                apm::MavMessage::GPS_RAW_INT(gps_raw_int(&self.gnss?, self.cfg.autopilot))
            }
            apm::ATTITUDE_DATA::ID => {
                let est = self.flight.estimate();
                let e = so3::euler_zyx(&est.q_nb);
                apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA {
                    time_boot_ms: boot_ms,
                    roll: e.z as f32,
                    pitch: e.y as f32,
                    yaw: e.x as f32,
                    rollspeed: est.w_nb_b_rps.x as f32,
                    pitchspeed: est.w_nb_b_rps.y as f32,
                    yawspeed: est.w_nb_b_rps.z as f32,
                })
            }
            apm::GLOBAL_POSITION_INT_DATA::ID => {
                self.origin.as_ref()?;
                let est = self.flight.estimate();
                let yaw = so3::euler_zyx(&est.q_nb).x;
                apm::MavMessage::GLOBAL_POSITION_INT(apm::GLOBAL_POSITION_INT_DATA {
                    time_boot_ms: boot_ms,
                    lat: convert::deg_e7(est.pos.lat_rad),
                    lon: convert::deg_e7(est.pos.lon_rad),
                    alt: convert::mm(est.pos.h_m),
                    relative_alt: convert::mm(est.pos.h_m - self.home_h_m),
                    vx: convert::sat_i16(est.v_ned_mps.x * 100.0),
                    vy: convert::sat_i16(est.v_ned_mps.y * 100.0),
                    vz: convert::sat_i16(est.v_ned_mps.z * 100.0),
                    hdg: convert::cdeg_0_36000(yaw),
                })
            }
            apm::VFR_HUD_DATA::ID => {
                let est = self.flight.estimate();
                let air = air?;
                let ias_mps = if self.airspeed_unhealthy(t_us) {
                    self.ahrs_eas_mps()
                } else {
                    convert::cas_mps(convert::impact_pressure_pa(
                        air.tas_mps,
                        air.p_pa,
                        air.temp_k,
                    ))
                };
                let yaw_deg = so3::euler_zyx(&est.q_nb).x.to_degrees().rem_euclid(360.0);
                let throttle = self.flight.truth_sample().controls.throttle;
                apm::MavMessage::VFR_HUD(apm::VFR_HUD_DATA {
                    airspeed: ias_mps as f32,
                    groundspeed: est.v_ned_mps.x.hypot(est.v_ned_mps.y) as f32,
                    alt: est.pos.h_m as f32,
                    climb: (-est.v_ned_mps.z) as f32,
                    heading: (yaw_deg.round() as i16).rem_euclid(360),
                    throttle: (throttle * 100.0).round().clamp(0.0, 100.0) as u16,
                })
            }
            _ => return None,
        };
        Some(msg)
    }

    fn heartbeat(&self) -> apm::HEARTBEAT_DATA {
        let (autopilot, custom_mode) = match self.cfg.autopilot {
            // PX4 AUTO.MISSION: main mode 4 in bits 16–23, sub mode 4 in bits 24–31.
            Autopilot::Px4 | Autopilot::Ideal => {
                (apm::MavAutopilot::MAV_AUTOPILOT_PX4, (4 << 16) | (4 << 24))
            }
            // ArduPlane AUTO = 10.
            Autopilot::ArduPilot => (apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, 10),
        };
        apm::HEARTBEAT_DATA {
            custom_mode,
            mavtype: apm::MavType::MAV_TYPE_FIXED_WING,
            autopilot,
            base_mode: apm::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                | apm::MavModeFlag::MAV_MODE_FLAG_AUTO_ENABLED
                | apm::MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED
                | apm::MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
                | apm::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
            system_status: apm::MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }
    }

    /// Handle one incoming message (never panics on any content).
    #[expect(
        deprecated,
        reason = "SET_GPS_GLOBAL_ORIGIN is superseded by MAV_CMD_DO_SET_GLOBAL_ORIGIN (2025-04) \
                  but is what PX4 and ArduPilot handle and companions send today"
    )]
    pub fn handle(&mut self, header: &MavHeader, msg: &apm::MavMessage) {
        if header.system_id == u32::from(self.cfg.system_id)
            && header.component_id == self.cfg.component_id
        {
            return; // our own echo (broadcast links)
        }
        self.stats.received += 1;
        let now_us = self.t_us();
        match msg {
            apm::MavMessage::HEARTBEAT(hb) => {
                let id = (header.system_id, header.component_id);
                if !self.peers.contains(&id) && self.peers.len() < 16 {
                    self.peers.push(id);
                    self.notices.push(format!(
                        "t = {:.2} s: HEARTBEAT from {}/{} ({:?}, {:?})",
                        self.flight.mission_time_s(),
                        id.0,
                        id.1,
                        hb.mavtype,
                        hb.system_status
                    ));
                }
            }
            apm::MavMessage::TIMESYNC(m) if m.tc1 == 0 => {
                self.stats.timesync_answered += 1;
                self.queue(apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                    tc1: i64::try_from(now_us.saturating_mul(1000)).unwrap_or(i64::MAX),
                    ts1: m.ts1,
                    target_system: u8::try_from(header.system_id).unwrap_or(0),
                    target_component: header.component_id,
                }));
            }
            apm::MavMessage::TIMESYNC(m)
                if m.target_system == 0 || m.target_system == self.cfg.system_id =>
            {
                // An answer to one of our requests.
                self.clock_map.add(m.ts1, m.tc1, now_us);
                self.stats.timesync_pairs = self.clock_map.used;
            }
            apm::MavMessage::COMMAND_LONG(c)
                if c.target_system == 0 || c.target_system == self.cfg.system_id =>
            {
                self.command(header, c, now_us);
            }
            apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(o)
                if o.target_system == 0 || o.target_system == self.cfg.system_id =>
            {
                self.set_origin(o);
            }
            apm::MavMessage::ODOMETRY(m) => {
                let fix = convert::odometry_fix(m, self.origin.as_ref());
                self.on_estimate(header, EstimateKind::Odometry, fix);
            }
            apm::MavMessage::VISION_POSITION_ESTIMATE(m) => {
                let fix = convert::vision_fix(m, self.origin.as_ref());
                self.on_estimate(header, EstimateKind::VisionPosition, fix);
            }
            apm::MavMessage::GPS_INPUT(m) => {
                let fix = convert::gps_input_fix(m);
                self.on_estimate(header, EstimateKind::GpsInput, fix);
            }
            _ => {}
        }
    }

    #[expect(
        deprecated,
        reason = "SET_GPS_GLOBAL_ORIGIN, deprecated but what companions send today (see `handle`)"
    )]
    fn set_origin(&mut self, o: &apm::SET_GPS_GLOBAL_ORIGIN_DATA) {
        let pos = Geodetic {
            lat_rad: convert::rad_from_deg_e7(o.latitude),
            lon_rad: convert::rad_from_deg_e7(o.longitude),
            h_m: f64::from(o.altitude) * 1e-3,
        };
        if pos.lat_rad.abs() > std::f64::consts::FRAC_PI_2
            || pos.lon_rad.abs() > std::f64::consts::PI
        {
            self.notices
                .push("SET_GPS_GLOBAL_ORIGIN out of range, ignored".to_owned());
            return;
        }
        // ArduPilot only takes an origin when it has none; PX4 resets its origin.
        if self.cfg.autopilot == Autopilot::ArduPilot && self.origin.is_some() {
            self.notices
                .push("SET_GPS_GLOBAL_ORIGIN ignored: the EKF origin is already set".to_owned());
            return;
        }
        self.origin = Some(MapProjection::new(&pos));
        self.notices.push(format!(
            "local origin set by the companion: {:.7}°, {:.7}°, {:.2} m",
            pos.lat_rad.to_degrees(),
            pos.lon_rad.to_degrees(),
            pos.h_m
        ));
        self.queue_origin();
    }

    fn ack(&mut self, header: &MavHeader, command: apm::MavCmd, result: apm::MavResult) {
        self.stats.commands += 1;
        self.queue(apm::MavMessage::COMMAND_ACK(apm::COMMAND_ACK_DATA {
            command,
            result,
            progress: 0,
            result_param2: 0,
            target_system: u8::try_from(header.system_id).unwrap_or(0),
            target_component: header.component_id,
        }));
    }

    fn command(&mut self, header: &MavHeader, c: &apm::COMMAND_LONG_DATA, now_us: u64) {
        use apm::{MavCmd, MavResult};
        match c.command {
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => {
                let outcome = self
                    .streams
                    .set_interval(c.param1, c.param2, c.param3, now_us);
                let result = match outcome {
                    IntervalOutcome::Accepted(_) => MavResult::MAV_RESULT_ACCEPTED,
                    IntervalOutcome::Denied | IntervalOutcome::TooFast => {
                        MavResult::MAV_RESULT_DENIED
                    }
                    IntervalOutcome::Failed => MavResult::MAV_RESULT_FAILED,
                };
                // The ACK leaves at once; ArduPilot's text follows from its STATUSTEXT queue.
                self.ack(header, c.command, result);
                let id = c.param1 as u32;
                match outcome {
                    IntervalOutcome::TooFast => {
                        self.notices.push(format!(
                            "SET_MESSAGE_INTERVAL {id} at {:.0} µs denied: too fast for the 50 Hz loop",
                            c.param2
                        ));
                        self.statustext(
                            apm::MavSeverity::MAV_SEVERITY_INFO,
                            &format!(
                                "Requested rate for message ID {id} too fast. Increase SCHED_LOOP_RATE"
                            ),
                        );
                    }
                    IntervalOutcome::Denied
                        if self.cfg.autopilot == Autopilot::ArduPilot
                            && !super::streams::has_stream(Autopilot::ArduPilot, id) =>
                    {
                        // Said by SITL builds only.
                        self.statustext(
                            apm::MavSeverity::MAV_SEVERITY_INFO,
                            &format!("No ap_message for mavlink id ({id})"),
                        );
                    }
                    _ => {}
                }
            }
            MavCmd::MAV_CMD_REQUEST_MESSAGE => {
                // The ACK first, then the message (mavlink.io "Requesting messages").
                let id = if c.param1.is_finite() && c.param1 >= 0.0 {
                    Some(c.param1.round() as u32)
                } else {
                    None
                };
                let imu_ids = [
                    apm::HIGHRES_IMU_DATA::ID,
                    apm::SCALED_IMU_DATA::ID,
                    apm::RAW_IMU_DATA::ID,
                ];
                match id {
                    Some(apm::GPS_GLOBAL_ORIGIN_DATA::ID) if self.origin.is_some() => {
                        self.ack(header, c.command, MavResult::MAV_RESULT_ACCEPTED);
                        self.queue_origin();
                    }
                    Some(apm::GPS_GLOBAL_ORIGIN_DATA::ID) => self.ack(
                        header,
                        c.command,
                        MavResult::MAV_RESULT_TEMPORARILY_REJECTED,
                    ),
                    // One-shot IMU samples would steal from the streams' averages.
                    Some(id) if !imu_ids.contains(&id) => match self.build(id, now_us) {
                        Some(msg) => {
                            self.ack(header, c.command, MavResult::MAV_RESULT_ACCEPTED);
                            self.queue(msg);
                        }
                        None => self.ack(header, c.command, MavResult::MAV_RESULT_UNSUPPORTED),
                    },
                    _ => self.ack(header, c.command, MavResult::MAV_RESULT_DENIED),
                }
            }
            _ => self.ack(header, c.command, MavResult::MAV_RESULT_UNSUPPORTED),
        }
    }

    fn truth_at(&self, t_us: u64) -> Geodetic {
        let h = &self.truth_history;
        let i = h.partition_point(|&(t, _)| t < t_us);
        match (i.checked_sub(1).and_then(|j| h.get(j)), h.get(i)) {
            (Some(&(t0, p0)), Some(&(t1, p1))) if t1 > t0 => {
                let w = (t_us - t0) as f64 / (t1 - t0) as f64;
                Geodetic {
                    lat_rad: p0.lat_rad + w * (p1.lat_rad - p0.lat_rad),
                    lon_rad: p0.lon_rad + w * (p1.lon_rad - p0.lon_rad),
                    h_m: p0.h_m + w * (p1.h_m - p0.h_m),
                }
            }
            (_, Some(&(_, p))) | (Some(&(_, p)), None) => p,
            (None, None) => self.flight.truth().pos,
        }
    }

    fn on_estimate(
        &mut self,
        header: &MavHeader,
        kind: EstimateKind,
        fix: Result<ExternalFix, ExternalFixError>,
    ) {
        let fix = match fix {
            Ok(f) => f,
            Err(e) => {
                self.stats.estimates_refused += 1;
                if self.stats.estimates_refused.is_power_of_two() {
                    self.notices.push(format!(
                        "{} refused ({e}); {} refused so far",
                        kind.name(),
                        self.stats.estimates_refused
                    ));
                }
                return;
            }
        };
        let now_us = self.t_us();
        // A stamp on the vehicle clock is within the truth history and not ahead of now
        // (one 10 ms sensor period of slack for rounding); else one on the companion's clock
        // maps there through TIMESYNC; else the arrival time is all there is.
        let plausible = |t: u64| t <= now_us + 10_000 && t + TRUTH_HISTORY_US >= now_us;
        let mapped = self
            .clock_map
            .to_vehicle_us(fix.stamp_us)
            .filter(|v| v.is_finite() && *v >= 0.0)
            .map(|v| v.round() as u64);
        let (t_valid_us, basis) = match mapped {
            _ if plausible(fix.stamp_us) => (fix.stamp_us.min(now_us), TimeBasis::Stamp),
            Some(v) if plausible(v) => (v.min(now_us), TimeBasis::Timesync),
            _ => (now_us, TimeBasis::Arrival),
        };
        let truth = self.truth_at(t_valid_us);
        let d = wgs84::ned_difference_m(&truth, &fix.pos);
        self.estimate_arrivals.push_back(now_us);
        self.stats.estimates += 1;
        self.stats.estimate_span_us = Some(match self.stats.estimate_span_us {
            None => (now_us, now_us),
            Some((first, _)) => (first, now_us),
        });
        if self.cfg.fly_on_estimates && now_us > self.flight.gnss_loss_t_us() {
            self.flight.set_position_aid(
                PositionAid {
                    t_us: t_valid_us,
                    lat_rad: fix.pos.lat_rad,
                    lon_rad: fix.pos.lon_rad,
                },
                self.cfg.estimate_timeout_us,
            );
        }
        self.rows.push(EstimateRow {
            t_rx_us: now_us,
            t_valid_us,
            basis,
            kind,
            system_id: header.system_id,
            component_id: header.component_id,
            truth,
            estimate: fix.pos,
            hor_err_m: d.x.hypot(d.y),
            ver_err_m: -d.z,
            rate_hz: self.estimate_rate_hz(),
            aided: self.aided,
        });
    }
}

/// HIGHRES_IMU of an (averaged) IMU sample with the latest air data and magnetometer.
pub fn highres_imu(imu: &ImuSample, air: &AirSample, mag: &MagSample) -> apm::HIGHRES_IMU_DATA {
    let qc_pa = convert::impact_pressure_pa(air.tas_mps, air.p_pa, air.temp_k);
    let b_g = mag.mag_b_nt / convert::NT_PER_GAUSS;
    apm::HIGHRES_IMU_DATA {
        time_usec: imu.t_us,
        xacc: imu.accel_mps2.x as f32,
        yacc: imu.accel_mps2.y as f32,
        zacc: imu.accel_mps2.z as f32,
        xgyro: imu.gyro_rps.x as f32,
        ygyro: imu.gyro_rps.y as f32,
        zgyro: imu.gyro_rps.z as f32,
        xmag: b_g.x as f32,
        ymag: b_g.y as f32,
        zmag: b_g.z as f32,
        abs_pressure: (air.p_pa * convert::HPA_PER_PA) as f32,
        diff_pressure: (qc_pa * convert::HPA_PER_PA) as f32,
        pressure_alt: atmosphere::pressure_altitude_m(air.p_pa) as f32,
        temperature: (air.temp_k - convert::CELSIUS_ZERO_K) as f32,
        // Bits 0–12: every field holds a new sample.
        fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x1FFF),
        id: 0,
    }
}

/// Which int16 IMU stream.
#[derive(Debug, Clone, Copy)]
enum ImuStream {
    Scaled,
    Raw,
}

/// ArduPilot's angle of attack and sideslip (degrees) from a navigation estimate and a wind
/// estimate (`AP_AHRS::update_AOA_SSA`).
pub fn aoa_ssa_from_estimate_deg(
    est: &crate::control::NavEstimate,
    wind_ned_mps: &Vector3<f64>,
) -> (f64, f64) {
    let v_b = est.q_nb.inverse() * (est.v_ned_mps - wind_ned_mps);
    let speed = v_b.norm();
    if speed < 2.0 {
        return (0.0, 0.0);
    }
    let aoa_deg = if v_b.x > 0.0 {
        (v_b.z / v_b.x).atan().to_degrees()
    } else {
        0.0
    };
    let ssa_deg = (v_b.y / speed).clamp(-1.0, 1.0).asin().to_degrees();
    (aoa_deg, ssa_deg)
}

/// Accelerations (mG), rates (mrad/s) and field (mgauss) of the int16 IMU messages.
fn scaled_triplets(imu: &ImuSample, mag: &MagSample) -> ([i16; 3], [i16; 3], [i16; 3]) {
    let a = imu.accel_mps2.map(convert::milli_g);
    let g = imu.gyro_rps.map(convert::mrad_s);
    let m = mag.mag_b_nt.map(convert::milli_gauss);
    ([a.x, a.y, a.z], [g.x, g.y, g.z], [m.x, m.y, m.z])
}

/// AIRSPEED: calibrated airspeed (= indicated, the simulated Pitot has no error), the Pitot
/// impact pressure and the outside air temperature.
pub fn airspeed(air: &AirSample) -> apm::AIRSPEED_DATA {
    let qc_pa = convert::impact_pressure_pa(air.tas_mps, air.p_pa, air.temp_k);
    apm::AIRSPEED_DATA {
        airspeed: convert::cas_mps(qc_pa) as f32,
        raw_press: (qc_pa * convert::HPA_PER_PA) as f32,
        temperature: convert::cdeg_c(air.temp_k),
        id: 0,
        flags: apm::AirspeedSensorFlags::AIRSPEED_SENSOR_USING,
    }
}

/// GPS_RAW_INT of a receiver report as `autopilot` sends it. Without a fix: fix type
/// NO_FIX, zero position, unknown (UINT16_MAX) DOP, speed and course, as a receiver that lost
/// lock reports. ArduPilot stamps the fix with
/// the millisecond the driver received it and reports no speed accuracy (`vel_acc` 0, as its
/// SITL receiver); PX4 and Ideal stamp the fix's time and give all three accuracies.
pub fn gps_raw_int(report: &GnssReport, autopilot: Autopilot) -> apm::GPS_RAW_INT_DATA {
    let ardupilot = autopilot == Autopilot::ArduPilot;
    match report {
        GnssReport::Fix { fix, rx_us } => {
            let v = fix.v_ned_mps;
            let speed_mps = v.x.hypot(v.y);
            apm::GPS_RAW_INT_DATA {
                time_usec: if ardupilot {
                    rx_us / 1000 * 1000
                } else {
                    fix.t_us
                },
                lat: convert::deg_e7(fix.pos.lat_rad),
                lon: convert::deg_e7(fix.pos.lon_rad),
                alt: convert::mm(fix.pos.h_m),
                // No DOP model: the accuracies are in h_acc / v_acc.
                eph: u16::MAX,
                epv: u16::MAX,
                vel: convert::sat_u16_known(speed_mps * 100.0),
                cog: convert::cdeg_0_36000(v.y.atan2(v.x)),
                fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
                satellites_visible: SATELLITES_WITH_FIX,
                alt_ellipsoid: convert::mm(fix.pos.h_m),
                h_acc: convert::sat_u32(fix.sigma_hor_m * 1e3),
                v_acc: convert::sat_u32(fix.sigma_ver_m * 1e3),
                vel_acc: if ardupilot {
                    0
                } else {
                    convert::sat_u32(fix.sigma_vel_mps * 1e3)
                },
                hdg_acc: 0,
                yaw: 0,
            }
        }
        // Position 0: what ArduPilot's driver keeps without lock was not measured.
        GnssReport::NoGps { last_fix_rx_us } => apm::GPS_RAW_INT_DATA {
            time_usec: last_fix_rx_us / 1000 * 1000,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_NO_FIX,
            satellites_visible: ARDUPILOT_SATELLITES_WITHOUT_LOCK,
            eph: u16::MAX,
            epv: u16::MAX,
            vel: u16::MAX,
            cog: u16::MAX,
            ..Default::default()
        },
        GnssReport::NoFix { t_us } => apm::GPS_RAW_INT_DATA {
            time_usec: *t_us,
            lat: 0,
            lon: 0,
            alt: 0,
            eph: u16::MAX,
            epv: u16::MAX,
            vel: u16::MAX,
            cog: u16::MAX,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_NO_FIX,
            satellites_visible: 0,
            alt_ellipsoid: 0,
            h_acc: 0,
            v_acc: 0,
            vel_acc: 0,
            hdg_acc: 0,
            yaw: 0,
        },
    }
}
