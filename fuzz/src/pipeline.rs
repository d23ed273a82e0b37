//! The daemon's input path without its sockets, threads and clock, with the fuzz oracle.
//!
//! Bytes are read by the mavlink crate's frame reader exactly as the daemon's connection reads
//! them (`MavlinkReader` with the daemon's version filter and signing state), payloads parsed
//! with `MavMessage::parse`, messages handled as `daemon::link::handle_raw` does (autopilot
//! lock, TIMESYNC, reboot detection, the [`InputDecoder`] with the time mapping, the
//! [`MonotonicGate`]) and the events fed to the [`Navigator`] as the navigation thread does
//! (the INS start rules are the navigator's own). The reader task
//! of `link.rs` is async and private, so its steps are repeated here in order: keep them in
//! step with it. Left out: the outbox (replies are only counted), the GPS_INPUT echo check and
//! the sequence-gap counters, which touch no navigation state.
//!
//! Oracle, checked after every message: no panic (the caller catches it); every event the
//! decoder emits passes the decoder's own documented limits; the decoder's counters only grow
//! and count exactly the events emitted; the INS counters account for every event pushed; every
//! solution is finite, its latitude within ±90°, its variances non-negative, and it is
//! strictly later than the previous one.

use std::cell::Cell;
use std::io::Read;
use std::rc::Rc;
use std::sync::Arc;

use ianav::daemon::config::{
    AoaSsaUse, AutopilotKind, ClockSource, DaemonConfig, TemperatureSource,
};
use ianav::ins::SensorCounters;
use ianav::io::mavlink_in::{
    DecoderConfig, InputCounters, InputDecoder, MAX_ACCEL_MPS2, MAX_GYRO_RPS, MAX_MAG_NT,
    P_RANGE_PA, T_RANGE_K,
};
use ianav::io::timesync::{ClockStamp, Kind, MonotonicGate, TimeSync};
use ianav::nav::{NavSolution, Navigator, StartKind};
use ianav::sensors::SensorEvent;
use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MAVLinkMessageRaw, MavlinkReader, MavlinkVersion, Message, SigningConfig};

use crate::wire::SIGNING_KEY;

/// Magnetic epoch used instead of the system clock (determinism).
pub const MAG_DECIMAL_YEAR: f64 = 2026.5;

/// How the link reads bytes: the daemon's `[mavlink]` signing settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkMode {
    /// No key: MAVLink 1 and 2, signed or not, all accepted.
    Open,
    /// A key, `refuse_unsigned = false`: signatures checked, unsigned frames accepted.
    Signed,
    /// A key, `refuse_unsigned = true`: only MAVLink 2 frames with a valid signature.
    SignedOnly,
}

impl LinkMode {
    /// All modes, indexed by an input's link byte.
    pub const ALL: [LinkMode; 3] = [LinkMode::Open, LinkMode::Signed, LinkMode::SignedOnly];
}

/// The daemon configurations fuzzed: the shipped `config/ianav.toml` with these changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// PX4, the daemon's clock (TIMESYNC mapping), the sensor temperature.
    Px4,
    /// ArduPilot, the autopilot's clock, AOA_SSA as vanes, ISA temperature, a GNSS lag.
    Ardupilot,
}

/// The daemon configuration of a variant.
pub fn config(variant: Variant) -> anyhow::Result<DaemonConfig> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
    let mut cfg = DaemonConfig::from_file(&dir.join("ianav.toml"))?;
    cfg.navigation.mag_decimal_year = MAG_DECIMAL_YEAR;
    if variant == Variant::Ardupilot {
        cfg.mavlink.clock = ClockSource::Autopilot;
        cfg.input.aoa_ssa = AoaSsaUse::Vanes;
        cfg.input.temperature = TemperatureSource::Isa;
        cfg.input.isa_delta_t_k = 5.0;
        cfg.input.gnss_lag_s = 0.1;
    }
    Ok(cfg)
}

/// What one pipeline has seen (summed over a fuzz run).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Frames the mavlink reader returned.
    pub frames: u64,
    /// MAVLink 1 frames among them.
    pub v1_frames: u64,
    /// Signed frames among them.
    pub signed_frames: u64,
    /// Payloads the dialect refused.
    pub parse_errors: u64,
    /// Messages parsed.
    pub messages: u64,
    /// Frames from another system, a 32-bit system id or our own component.
    pub foreign: u64,
    /// Messages before any autopilot HEARTBEAT.
    pub before_heartbeat: u64,
    /// Autopilot HEARTBEATs.
    pub heartbeats: u64,
    /// Changes of the autopilot followed.
    pub autopilot_changes: u64,
    /// TIMESYNC replies the daemon would send.
    pub timesync_replies: u64,
    /// Reboots detected.
    pub reboots: u64,
    /// Events out of the decoder.
    pub events: u64,
    /// Events refused by the monotonic gate.
    pub gated: u64,
    /// Events pushed to the navigator.
    pub to_nav: u64,
    /// INS (re)starts requested.
    pub inits: u64,
    /// INS starts refused by `Ins::new`.
    pub inits_refused: u64,
    /// GNSS-return re-initialisations.
    pub reinits: u64,
    /// Solutions.
    pub solutions: u64,
    /// Solutions in GNSS-denied mode.
    pub denied_solutions: u64,
    /// Decoder rejections (all kinds).
    pub rejected: u64,
    /// Decoder rejections: non-finite values.
    pub rej_non_finite: u64,
    /// Decoder rejections: out of range.
    pub rej_out_of_range: u64,
    /// Decoder rejections: GNSS without a 3D fix.
    pub rej_no_fix: u64,
    /// Decoder rejections: unscaled RAW_IMU.
    pub rej_unscaled_raw_imu: u64,
    /// Decoder rejections: timestamp not mappable.
    pub rej_time: u64,
    /// Decoder rejections: pressure without a recent airspeed.
    pub rej_no_airspeed: u64,
    /// Decoder rejections: airspeed flagged unhealthy.
    pub rej_airspeed_unhealthy: u64,
    /// Samples the INS refused (invalid or out of time order).
    pub ins_rejected: u64,
    /// GNSS fixes and reference attitudes refused by the INS's innovation gates.
    pub ins_gated: u64,
    /// Filter updates the INS refused for numerical reasons.
    pub ins_numerical: u64,
    /// IMU gaps the INS bridged.
    pub ins_imu_gaps: u64,
}

impl Stats {
    /// Add `o` to `self`.
    pub fn add(&mut self, o: &Stats) {
        self.frames += o.frames;
        self.v1_frames += o.v1_frames;
        self.signed_frames += o.signed_frames;
        self.parse_errors += o.parse_errors;
        self.messages += o.messages;
        self.foreign += o.foreign;
        self.before_heartbeat += o.before_heartbeat;
        self.heartbeats += o.heartbeats;
        self.autopilot_changes += o.autopilot_changes;
        self.timesync_replies += o.timesync_replies;
        self.reboots += o.reboots;
        self.events += o.events;
        self.gated += o.gated;
        self.to_nav += o.to_nav;
        self.inits += o.inits;
        self.inits_refused += o.inits_refused;
        self.reinits += o.reinits;
        self.solutions += o.solutions;
        self.denied_solutions += o.denied_solutions;
        self.rejected += o.rejected;
        self.rej_non_finite += o.rej_non_finite;
        self.rej_out_of_range += o.rej_out_of_range;
        self.rej_no_fix += o.rej_no_fix;
        self.rej_unscaled_raw_imu += o.rej_unscaled_raw_imu;
        self.rej_time += o.rej_time;
        self.rej_no_airspeed += o.rej_no_airspeed;
        self.rej_airspeed_unhealthy += o.rej_airspeed_unhealthy;
        self.ins_rejected += o.ins_rejected;
        self.ins_gated += o.ins_gated;
        self.ins_numerical += o.ins_numerical;
        self.ins_imu_gaps += o.ins_imu_gaps;
    }

    /// (name, value) of every counter, for the "never reached" report.
    pub fn fields(&self) -> Vec<(&'static str, u64)> {
        vec![
            ("frames", self.frames),
            ("v1_frames", self.v1_frames),
            ("signed_frames", self.signed_frames),
            ("parse_errors", self.parse_errors),
            ("messages", self.messages),
            ("foreign", self.foreign),
            ("before_heartbeat", self.before_heartbeat),
            ("heartbeats", self.heartbeats),
            ("autopilot_changes", self.autopilot_changes),
            ("timesync_replies", self.timesync_replies),
            ("reboots", self.reboots),
            ("events", self.events),
            ("gated", self.gated),
            ("to_nav", self.to_nav),
            ("inits", self.inits),
            ("inits_refused", self.inits_refused),
            ("reinits", self.reinits),
            ("solutions", self.solutions),
            ("denied_solutions", self.denied_solutions),
            ("rejected", self.rejected),
            ("rej_non_finite", self.rej_non_finite),
            ("rej_out_of_range", self.rej_out_of_range),
            ("rej_no_fix", self.rej_no_fix),
            ("rej_unscaled_raw_imu", self.rej_unscaled_raw_imu),
            ("rej_time", self.rej_time),
            ("rej_no_airspeed", self.rej_no_airspeed),
            ("rej_airspeed_unhealthy", self.rej_airspeed_unhealthy),
            ("ins_rejected", self.ins_rejected),
            ("ins_gated", self.ins_gated),
            ("ins_numerical", self.ins_numerical),
            ("ins_imu_gaps", self.ins_imu_gaps),
        ]
    }
}

/// A broken property (the oracle's finding; a panic is the other kind): `kind: details`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Violation(pub String);

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

macro_rules! ensure {
    ($cond:expr, $($arg:tt)*) => {{
        let holds: bool = $cond;
        if !holds {
            return Err(Violation(format!($($arg)*)));
        }
    }};
}

/// Events pushed to the current INS, per kind, and solutions out of it.
#[derive(Debug, Clone, Copy, Default)]
struct InsLedger {
    imu: u64,
    air: u64,
    mag: u64,
    gnss: u64,
    ref_attitude: u64,
    solutions: u64,
    last_t_us: Option<u64>,
}

/// One datagram of input: its arrival time after the previous one and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Datagram {
    /// Time since the previous datagram (or since the pipeline's clock), µs.
    pub dt_us: u32,
    /// Bytes.
    pub bytes: Vec<u8>,
}

/// Reads datagrams one per `read` call (as the UDP transport does) and publishes the arrival
/// time of the last one read: the reception time of the frame completed by it.
struct Datagrams<'a> {
    list: &'a [Datagram],
    next: usize,
    offset: usize,
    now_us: Rc<Cell<u64>>,
}

impl Read for Datagrams<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        // Empty datagrams carry time only.
        while let Some(d) = self.list.get(self.next) {
            if self.offset == 0 {
                self.now_us
                    .set(self.now_us.get().saturating_add(u64::from(d.dt_us)));
            }
            let rest = &d.bytes[self.offset..];
            if rest.is_empty() {
                self.next += 1;
                self.offset = 0;
                continue;
            }
            // A datagram larger than the reader's free space is read in parts (stream
            // semantics: TCP and serial; a UDP socket would truncate it instead).
            let n = rest.len().min(buf.len());
            buf[..n].copy_from_slice(&rest[..n]);
            self.offset += n;
            if self.offset == d.bytes.len() {
                self.next += 1;
                self.offset = 0;
            }
            return Ok(n);
        }
        Ok(0)
    }
}

/// The input path's state between messages: what the daemon's reader task and navigation
/// thread keep. Cloning it snapshots a warmed-up daemon.
#[derive(Debug, Clone)]
pub struct Pipeline {
    cfg: Arc<DaemonConfig>,
    /// Daemon clock, µs (advanced by the datagrams' `dt_us`).
    now_us: u64,
    autopilot: Option<(u8, u8, AutopilotKind)>,
    ts: TimeSync,
    dec: InputDecoder,
    gate: MonotonicGate,
    nav: Navigator,
    /// Air, magnetometer and reference-attitude events since the last IMU sample.
    since_imu: [u64; 3],
    ledger: InsLedger,
    pushed_before_init: u64,
    /// Counters of this pipeline.
    pub stats: Stats,
}

impl Pipeline {
    /// A daemon that has just started with `cfg`, its clock at `now_us`.
    pub fn new(cfg: DaemonConfig, now_us: u64) -> anyhow::Result<Self> {
        let p = &cfg.ins.position;
        let ts = TimeSync::new((cfg.mavlink.timesync_max_rtt_ms * 1e6) as u64);
        let ts = if cfg.mavlink.clock == ClockSource::Autopilot {
            ts.with_autopilot_clock()
        } else {
            ts
        };
        let dec = InputDecoder::new(DecoderConfig {
            temperature: cfg.input.temperature,
            isa_delta_t_k: cfg.input.isa_delta_t_k,
            raw_imu_is_scaled: cfg.mavlink.autopilot == AutopilotKind::Ardupilot,
            default_sigma: (p.gnss_sigma_hor_m, p.gnss_sigma_ver_m, p.gnss_sigma_vel_mps),
            aoa_ssa_is_vanes: cfg.input.aoa_ssa == AoaSsaUse::Vanes,
            gnss_lag_us: (cfg.input.gnss_lag_s * 1e6).round() as u64,
            mag_from: cfg.input.magnetometer.decoder_choice(cfg.mavlink.autopilot),
        });
        let nav = Navigator::new(&ianav::daemon::nav_config(&cfg, MAG_DECIMAL_YEAR))?;
        Ok(Self {
            cfg: Arc::new(cfg),
            now_us,
            autopilot: None,
            ts,
            dec,
            gate: MonotonicGate::default(),
            nav,
            since_imu: [0; 3],
            ledger: InsLedger::default(),
            pushed_before_init: 0,
            stats: Stats::default(),
        })
    }

    /// The daemon clock, µs.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Whether the INS runs.
    pub fn nav_running(&self) -> bool {
        self.nav.is_initialised()
    }

    /// Whether the INS is in GNSS-denied mode.
    pub fn gnss_denied(&self) -> bool {
        self.nav.gnss_denied()
    }

    /// The decoder's counters.
    pub fn decoder_counters(&self) -> &InputCounters {
        self.dec.counters()
    }

    /// The INS counters (`None` before the INS starts).
    pub fn ins_stats(&self) -> Option<ianav::ins::InsStats> {
        self.nav.ins_stats().copied()
    }

    /// Read `datagrams` through a new connection (the daemon's reconnection: a fresh frame
    /// reader and signing state, the rest kept) in link mode `mode`.
    pub fn feed(&mut self, mode: LinkMode, datagrams: &[Datagram]) -> Result<(), Violation> {
        let now = Rc::new(Cell::new(self.now_us));
        let mut reader = MavlinkReader::new(Datagrams {
            list: datagrams,
            next: 0,
            offset: 0,
            now_us: now.clone(),
        });
        let signing = match mode {
            LinkMode::Open => None,
            LinkMode::Signed => Some(SigningConfig::new(SIGNING_KEY, 0, true, true)),
            LinkMode::SignedOnly => Some(SigningConfig::new(SIGNING_KEY, 0, true, false)),
        }
        .map(mavlink::SigningData::from_config);
        loop {
            let r = if mode == LinkMode::SignedOnly {
                reader.read_raw_message_signed::<apm::MavMessage>(
                    MavlinkVersion::V2,
                    signing.as_ref(),
                )
            } else {
                reader.read_any_raw_message_signed::<apm::MavMessage>(signing.as_ref())
            };
            match r {
                Ok(raw) => {
                    self.now_us = now.get();
                    self.handle_raw(&raw)?;
                }
                // The raw reader reports no parse errors; an I/O error is the end of input.
                Err(_) => break,
            }
        }
        self.now_us = now.get();
        Ok(())
    }

    /// `daemon::link::handle_raw`, step by step.
    fn handle_raw(&mut self, raw: &MAVLinkMessageRaw) -> Result<(), Violation> {
        use apm::MavMessage as M;
        let rx_us = self.now_us;
        let version = raw.version();
        self.stats.frames += 1;
        self.stats.v1_frames += u64::from(version == MavlinkVersion::V1);
        self.stats.signed_frames += u64::from(
            matches!(raw, MAVLinkMessageRaw::V2(r) if r.incompatibility_flags() & 0x01 != 0),
        );
        let msg = match M::parse(version, raw.message_id(), raw.payload()) {
            Ok(m) => m,
            Err(_) => {
                self.stats.parse_errors += 1;
                return Ok(());
            }
        };
        self.stats.messages += 1;
        let Ok(sys) = u8::try_from(raw.system_id()) else {
            self.stats.foreign += 1;
            return Ok(());
        };
        let comp = raw.component_id();
        if comp == self.cfg.mavlink.component_id {
            self.stats.foreign += 1;
            return Ok(());
        }
        if let M::HEARTBEAT(h) = &msg
            && h.autopilot != apm::MavAutopilot::MAV_AUTOPILOT_INVALID
        {
            let kind = match (self.cfg.mavlink.autopilot, h.autopilot) {
                (AutopilotKind::Auto, apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA) => {
                    AutopilotKind::Ardupilot
                }
                (AutopilotKind::Auto, _) => AutopilotKind::Px4,
                (k, _) => k,
            };
            if self.autopilot.is_none_or(|(a, _, _)| a != sys) {
                self.stats.autopilot_changes += 1;
                self.autopilot = Some((sys, comp, kind));
                self.dec
                    .set_raw_imu_is_scaled(kind == AutopilotKind::Ardupilot);
                self.dec
                    .set_mag_from(self.cfg.input.magnetometer.decoder_choice(kind));
            }
            self.stats.heartbeats += 1;
        }
        let now_ns = rx_us.saturating_mul(1_000);
        let Some((ap_sys, _, _)) = self.autopilot else {
            if let M::TIMESYNC(t) = &msg {
                self.stats.timesync_replies +=
                    u64::from(self.ts.handle(t, now_ns, sys, comp).is_some());
            } else {
                self.stats.before_heartbeat += 1;
            }
            return Ok(());
        };
        if sys != ap_sys {
            self.stats.foreign += 1;
            return Ok(());
        }
        // As link::handle_raw: a stamp that does not fit the clock (yet) holds the message;
        // a confirmed reboot or jump resets the decoder.
        let stamp = ianav::io::timesync::clock_stamp_us(&msg)
            .map(|ap_us| self.ts.observe_clock(ap_us, rx_us));
        match stamp {
            Some(ClockStamp::Held) => return Ok(()),
            Some(ClockStamp::Reboot | ClockStamp::Jump) => {
                self.dec.reset();
                self.stats.reboots += 1;
            }
            Some(ClockStamp::Fits) | None => {}
        }
        if let M::TIMESYNC(t) = &msg {
            self.stats.timesync_replies +=
                u64::from(self.ts.handle(t, now_ns, sys, comp).is_some());
        }
        let before = *self.dec.counters();
        let Self { ts, dec, .. } = self;
        let evs = dec.decode(&msg, &mut |t| ts.map(t, rx_us));
        self.check_decoder(&before, &evs, rx_us)
            .map_err(|v| Violation(format!("{} (in {})", v.0, msg.message_name())))?;
        self.stats.events += evs.len() as u64;
        let after = *self.dec.counters();
        let d = |f: fn(&InputCounters) -> u64| f(&after) - f(&before);
        self.stats.rejected += d(InputCounters::rejected);
        self.stats.rej_non_finite += d(|c| c.non_finite);
        self.stats.rej_out_of_range += d(|c| c.out_of_range);
        self.stats.rej_no_fix += d(|c| c.no_fix);
        self.stats.rej_unscaled_raw_imu += d(|c| c.unscaled_raw_imu);
        self.stats.rej_time += d(|c| c.time);
        self.stats.rej_no_airspeed += d(|c| c.no_airspeed);
        self.stats.rej_airspeed_unhealthy += d(|c| c.airspeed_unhealthy);
        for ev in evs {
            self.event(ev)?;
        }
        Ok(())
    }

    /// The per-event part of `handle_raw`: gate, INS start rules, then the navigation thread.
    fn event(&mut self, ev: SensorEvent) -> Result<(), Violation> {
        let kind = match &ev {
            SensorEvent::Imu(_) => Kind::Imu,
            SensorEvent::Air(_) => Kind::Air,
            SensorEvent::Mag(_) => Kind::Mag,
            SensorEvent::Gnss(_) => Kind::Gnss,
            SensorEvent::Frame(_) => Kind::Frame,
            SensorEvent::RefAttitude(_) => Kind::RefAttitude,
            SensorEvent::Alignment(_)
            | SensorEvent::HeightAboveTerrain(_)
            | SensorEvent::VisionApplied(_) => return Ok(()),
        };
        if !self.gate.accept(kind, ev.t_us()) {
            self.stats.gated += 1;
            return Ok(());
        }
        self.stats.to_nav += 1;
        self.nav_event(&ev)
    }

    /// `daemon::nav_thread`'s handling of one event: the navigator's push, with its start rules
    /// (`nav::policy`). A start hands the new INS the aiding samples since the last IMU sample,
    /// then the event: the ledger restarts from those.
    fn nav_event(&mut self, ev: &SensorEvent) -> Result<(), Violation> {
        let before = self.nav.ins_stats().map(ins_tally);
        let (inits_before, refused_before) = (
            self.nav.stats().initialisations,
            self.nav.stats().starts_refused,
        );
        let running_before = self.nav.is_initialised();
        let sol = self.nav.push(ev);
        let started = self.nav.stats().initialisations > inits_before;
        self.stats.inits_refused += self.nav.stats().starts_refused - refused_before;
        if started {
            match self.nav.last_start().map(|s| s.kind) {
                Some(StartKind::GnssBack) => self.stats.reinits += 1,
                _ => self.stats.inits += 1,
            }
            // One event starts the INS at most once.
            ensure!(
                self.nav.stats().initialisations == inits_before + 1,
                "navigator initialisations jumped from {inits_before} to {} on one event",
                self.nav.stats().initialisations
            );
            let [air, mag, ref_attitude] = self.since_imu;
            self.ledger = InsLedger {
                air,
                mag,
                ref_attitude,
                ..InsLedger::default()
            };
        }
        if started || running_before {
            let l = &mut self.ledger;
            match ev {
                SensorEvent::Imu(_) => l.imu += 1,
                SensorEvent::Air(_) => l.air += 1,
                SensorEvent::Mag(_) => l.mag += 1,
                SensorEvent::Gnss(_) => l.gnss += 1,
                SensorEvent::RefAttitude(_) => l.ref_attitude += 1,
                SensorEvent::Frame(_)
                | SensorEvent::Alignment(_)
                | SensorEvent::HeightAboveTerrain(_)
                | SensorEvent::VisionApplied(_) => {}
            }
        } else if !matches!(
            ev,
            SensorEvent::Alignment(_)
                | SensorEvent::HeightAboveTerrain(_)
                | SensorEvent::VisionApplied(_)
        ) {
            self.pushed_before_init += 1;
        }
        match ev {
            SensorEvent::Imu(_) => self.since_imu = [0; 3],
            SensorEvent::Air(_) => self.since_imu[0] += 1,
            SensorEvent::Mag(_) => self.since_imu[1] += 1,
            SensorEvent::RefAttitude(_) => self.since_imu[2] += 1,
            _ => {}
        }
        if let (Some(b), Some(a), false) = (before, self.nav.ins_stats().map(ins_tally), started) {
            self.stats.ins_rejected += a[0] - b[0];
            self.stats.ins_gated += a[1] - b[1];
            self.stats.ins_numerical += a[2] - b[2];
            self.stats.ins_imu_gaps += a[3] - b[3];
        }
        if let Some(sol) = sol {
            let SensorEvent::Imu(imu) = ev else {
                return Err(Violation("solution from a non-IMU event: -".into()));
            };
            check_solution(&sol, imu.t_us, self.ledger.last_t_us)?;
            self.ledger.solutions += 1;
            self.ledger.last_t_us = Some(sol.ins.t_us);
            self.stats.solutions += 1;
            self.stats.denied_solutions += u64::from(sol.ins.gnss_denied);
        }
        self.check_ins()
    }

    fn check_decoder(
        &self,
        before: &InputCounters,
        evs: &[SensorEvent],
        rx_us: u64,
    ) -> Result<(), Violation> {
        let after = self.dec.counters();
        let fields = |c: &InputCounters| {
            [
                c.imu,
                c.air,
                c.mag,
                c.gnss,
                c.attitude,
                c.non_finite,
                c.out_of_range,
                c.no_fix,
                c.unscaled_raw_imu,
                c.time,
                c.no_airspeed,
                c.airspeed_unhealthy,
                c.aoa_ssa_ignored,
                c.second_baro_ignored,
                c.gnss_msl_height,
                c.gnss_no_vd,
                c.imu_lower_priority,
                c.highres_mag_ignored,
            ]
        };
        let (b, a) = (fields(before), fields(after));
        ensure!(
            b.iter().zip(&a).all(|(b, a)| a >= b),
            "decoder counter went down: {before:?} → {after:?}"
        );
        let count = |f: fn(&SensorEvent) -> bool| evs.iter().filter(|e| f(e)).count() as u64;
        let emitted = [
            count(|e| matches!(e, SensorEvent::Imu(_))),
            count(|e| matches!(e, SensorEvent::Air(_))),
            count(|e| matches!(e, SensorEvent::Mag(_))),
            count(|e| matches!(e, SensorEvent::Gnss(_))),
            count(|e| matches!(e, SensorEvent::RefAttitude(_))),
        ];
        ensure!(
            (0..5).all(|i| a[i] - b[i] == emitted[i]),
            "decoder event counters wrong: {:?} → {:?} for events {emitted:?}",
            &b[..5],
            &a[..5]
        );
        ensure!(evs.len() <= 3, "{} events from one message", evs.len());
        let rejected = after.rejected() - before.rejected();
        ensure!(
            rejected <= 3,
            "more than 3 rejections for one message: {rejected}"
        );
        // The daemon's clock maps no sample after its reception (autopilot clock: its own time).
        let daemon_clock = self.cfg.mavlink.clock == ClockSource::Daemon;
        for e in evs {
            check_event(e)?;
            ensure!(
                !daemon_clock || e.t_us() <= rx_us,
                "event dated after its reception: {} µs > {rx_us} µs: {e:?}",
                e.t_us()
            );
        }
        Ok(())
    }

    fn check_ins(&self) -> Result<(), Violation> {
        let n = self.nav.stats();
        ensure!(
            n.events_before_init == self.pushed_before_init,
            "navigator events before init miscounted: {} counted, {} pushed",
            n.events_before_init,
            self.pushed_before_init
        );
        let Some(s) = self.nav.ins_stats() else {
            return Ok(());
        };
        let l = &self.ledger;
        let total = |c: &SensorCounters| c.accepted + c.rejected_invalid + c.rejected_time;
        for (name, c, pushed) in [
            ("imu", &s.imu, l.imu),
            ("air", &s.air, l.air),
            ("mag", &s.mag, l.mag),
            ("gnss", &s.gnss, l.gnss),
            ("ref_attitude", &s.ref_attitude, l.ref_attitude),
        ] {
            ensure!(
                total(c) == pushed,
                "INS sample counters miscounted: {name} {c:?} for {pushed} events pushed"
            );
        }
        ensure!(
            s.imu.accepted == l.solutions + s.imu_before_init,
            "INS solutions miscounted: {} IMU samples accepted ({} before its start), {} solutions",
            s.imu.accepted,
            s.imu_before_init,
            l.solutions
        );
        ensure!(s.frames_ignored == 0, "frames counted with none pushed");
        Ok(())
    }
}

/// (refused samples, gated, numerical rejections, IMU gaps) of the INS counters.
fn ins_tally(s: &ianav::ins::InsStats) -> [u64; 4] {
    let refused = |c: &SensorCounters| c.rejected_invalid + c.rejected_time;
    [
        refused(&s.imu)
            + refused(&s.air)
            + refused(&s.mag)
            + refused(&s.gnss)
            + refused(&s.ref_attitude),
        s.gnss_gated + s.ref_attitude_gated,
        s.numerical_rejections,
        s.imu_gaps,
    ]
}

/// The decoder's documented limits (`io::mavlink_in`), re-checked on its output.
fn check_event(e: &SensorEvent) -> Result<(), Violation> {
    let fin3 = |v: &nalgebra::Vector3<f64>| v.iter().all(|x| x.is_finite());
    match e {
        SensorEvent::Imu(s) => ensure!(
            fin3(&s.accel_mps2)
                && fin3(&s.gyro_rps)
                && s.accel_mps2.norm() <= MAX_ACCEL_MPS2
                && s.gyro_rps.norm() <= MAX_GYRO_RPS,
            "IMU event outside the decoder's limits: {s:?}"
        ),
        SensorEvent::Mag(s) => ensure!(
            fin3(&s.mag_b_nt) && s.mag_b_nt.norm() <= MAX_MAG_NT && s.mag_b_nt.norm() > 0.0,
            "magnetometer event outside the decoder's limits: {s:?}"
        ),
        SensorEvent::Air(s) => {
            let vane = |a: Option<f64>| a.is_none_or(|a| a.is_finite() && a.abs() <= 1.571);
            ensure!(
                (P_RANGE_PA.0..=P_RANGE_PA.1).contains(&s.p_pa)
                    && (T_RANGE_K.0..=T_RANGE_K.1).contains(&s.temp_k)
                    && s.tas_mps.is_finite()
                    && s.tas_mps >= 0.0
                    && vane(s.aoa_rad)
                    && vane(s.aos_rad),
                "air-data event outside the decoder's limits: {s:?}"
            )
        }
        SensorEvent::Gnss(s) => {
            let sigma = |x: f64| x.is_finite() && x > 0.0;
            ensure!(
                s.pos.lat_rad.abs() < std::f64::consts::FRAC_PI_2
                    && s.pos.lon_rad.abs() <= std::f64::consts::PI
                    && s.pos.h_m.is_finite()
                    && fin3(&s.v_ned_mps)
                    && sigma(s.sigma_hor_m)
                    && sigma(s.sigma_ver_m)
                    && sigma(s.sigma_vel_mps),
                "GNSS event outside the decoder's limits: {s:?}"
            )
        }
        SensorEvent::RefAttitude(s) => {
            let q = s.q_nb.quaternion();
            ensure!(
                q.coords.iter().all(|x| x.is_finite()) && (q.norm() - 1.0).abs() < 1e-9,
                "attitude event not a unit quaternion: {s:?}"
            )
        }
        SensorEvent::Frame(_)
        | SensorEvent::Alignment(_)
        | SensorEvent::HeightAboveTerrain(_)
        | SensorEvent::VisionApplied(_) => {
            return Err(Violation(
                "camera frame, start alignment or terrain height out of the MAVLink decoder: -"
                    .into(),
            ));
        }
    }
    Ok(())
}

/// A solution is finite, its variances are not negative, and it is later than the last one.
fn check_solution(sol: &NavSolution, imu_t_us: u64, last: Option<u64>) -> Result<(), Violation> {
    let s = &sol.ins;
    ensure!(
        s.t_us == imu_t_us,
        "solution time not its IMU sample's: {} µs for {imu_t_us} µs",
        s.t_us
    );
    ensure!(
        last.is_none_or(|l| s.t_us > l),
        "solution not after the previous one: {} µs after {last:?} µs",
        s.t_us
    );
    let c = &s.cov;
    let scalars = [
        s.dt_s,
        s.pos.lat_rad,
        s.pos.lon_rad,
        s.pos.h_m,
        s.hp_m,
        s.roc_mps,
        s.tas_mps,
        s.aoa_rad,
        s.aos_rad,
        s.temp_k,
        s.delta_t_k,
        s.delta_p_pa,
        s.gnss_nis.unwrap_or(0.0),
        c.delta_t_k2,
        c.delta_p_pa2,
    ];
    let vectors = [
        s.v_ned_mps,
        s.w_nb_b_rps,
        s.wind_ned_mps,
        s.f_ib_b_mps2,
        s.e_gyr_rps,
        s.e_acc_mps2,
        s.e_mag_nt,
        s.delta_b_n_nt,
    ];
    let q = s.q_nb.quaternion();
    let mats3 = [
        &c.attitude_rad2,
        &c.w_nb_b_rad2ps2,
        &c.e_gyr_rad2ps2,
        &c.velocity_m2ps2,
        &c.position_m2,
        &c.wind_m2ps2,
    ];
    let finite = scalars.iter().all(|x| x.is_finite())
        && vectors.iter().all(|v| v.iter().all(|x| x.is_finite()))
        && q.coords.iter().all(|x| x.is_finite())
        && mats3.iter().all(|m| m.iter().all(|x| x.is_finite()))
        && c.air_data.iter().all(|x| x.is_finite());
    ensure!(finite, "non-finite solution: {s:?}");
    // Geodetic latitude is ±90° by definition: beyond it the state is garbage however finite.
    ensure!(
        s.pos.lat_rad.abs() <= std::f64::consts::FRAC_PI_2,
        "latitude out of its domain: {} rad in {:?}",
        s.pos.lat_rad,
        s.pos
    );
    ensure!(
        (q.norm() - 1.0).abs() < 1e-6,
        "attitude quaternion not unit: norm {}",
        q.norm()
    );
    ensure!(
        mats3.iter().all(|m| m.diagonal().iter().all(|x| *x >= 0.0))
            && c.air_data.diagonal().iter().all(|x| *x >= 0.0)
            && c.delta_t_k2 >= 0.0
            && c.delta_p_pa2 >= 0.0
            && s.gnss_nis.is_none_or(|n| n >= 0.0),
        "negative variance in the solution: {c:?}"
    );
    Ok(())
}
