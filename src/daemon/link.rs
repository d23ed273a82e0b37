//! The MAVLink link tasks (docs/REFERENCES.md M1.3–M1.6, M3.3–M3.4): connection with
//! reconnection, the reader (autopilot identification, TIMESYNC, reboot detection, message →
//! sensor events, INS initialisation), the writer, and the periodic TIMESYNC and
//! SET_MESSAGE_INTERVAL requests.
//!
//! Link ownership ([`AutopilotLock`]): the reader listens to one autopilot, the configured
//! system/component or the first flight controller heard; every other sender is counted and
//! ignored, and another autopilot is taken only after this one has been silent for the link
//! timeout.
//!
//! The reader receives raw frames (`recv_raw`) and parses the payload itself, so that it can
//! count MAVLink 1 and signed frames and payload parse errors on every transport. Frames with
//! a bad CRC or an unknown message id, and (with `refuse_unsigned`) unsigned or MAVLink 1
//! frames, are discarded inside the mavlink crate's frame decoder before the reader sees
//! them: they are invisible to the counters (rust-mavlink #209), and the robustness tests
//! check instead that valid traffic after them still gets through.

use std::sync::Arc;
use std::time::{Duration, Instant};

use mavlink::{
    AsyncMavConnection, MAVLinkMessageRaw, MavHeader, MavlinkVersion, Message, MessageData,
};
use tokio::sync::{mpsc, watch};

use super::nav_thread::NavInput;
use super::{Clock, Outbox, Shared, stopped_after};
use crate::daemon::config::{AoaSsaUse, AutopilotKind, DaemonConfig, MagnetometerSource};
use crate::io::mavlink_in::{self, DecoderConfig, InputDecoder};
use crate::io::mavlink_out;
use crate::io::timesync::{self, ClockStamp, Kind, MonotonicGate, TimeSync};
use crate::sensors::SensorEvent;
use mavlink::dialects::ardupilotmega as apm;

/// The connection type.
pub type Conn = mavlink::AsyncConnection<apm::MavMessage>;

async fn connect(cfg: &DaemonConfig) -> std::io::Result<Conn> {
    let mut conn = super::transport::open(&cfg.mavlink.connection).await?;
    conn.set_allow_recv_any_version(!cfg.mavlink.refuse_unsigned);
    if let Some(key) = cfg.signing_key {
        conn.setup_signing(Some(mavlink::SigningConfig::new(
            key,
            cfg.mavlink.signing_link_id,
            true,
            !cfg.mavlink.refuse_unsigned,
        )));
    }
    Ok(conn)
}

/// Send queued messages on the current connection.
pub(super) async fn writer(
    cfg: Arc<DaemonConfig>,
    mut out: mpsc::Receiver<super::Outgoing>,
    conn: watch::Receiver<Option<Arc<Conn>>>,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    loop {
        let (msg, imu_rx) = tokio::select! {
            m = out.recv() => match m { Some(m) => m, None => return },
            _ = stop.wait_for(|s| *s) => return,
        };
        let current = conn.borrow().clone();
        let Some(c) = current else {
            shared.count(|c| c.tx_failed += 1);
            continue;
        };
        let system_id = if cfg.mavlink.system_id != 0 {
            cfg.mavlink.system_id
        } else {
            shared.state(|s| s.autopilot.map_or(1, |a| a.0))
        };
        let header = MavHeader {
            system_id: u32::from(system_id),
            component_id: cfg.mavlink.component_id,
            sequence: 0,
        };
        match c.send(&header, &msg).await {
            // udpin before the first datagram: no peer to send to.
            Ok(0) => shared.count(|c| c.tx_failed += 1),
            Ok(_) => {
                shared.count(|c| c.tx_messages += 1);
                if let Some(t) = imu_rx {
                    shared
                        .record_latency(u64::try_from(t.elapsed().as_micros()).unwrap_or(u64::MAX));
                }
            }
            Err(e) => {
                tracing::debug!("send {}: {e}", msg.message_name());
                shared.count(|c| c.tx_failed += 1);
            }
        }
    }
}

/// Whether a HEARTBEAT is a flight controller's: a MAVLink autopilot (not
/// MAV_AUTOPILOT_INVALID) on a vehicle, not a ground station, companion computer, camera,
/// gimbal, ADS-B receiver or other peripheral. MAV_TYPE_GENERIC is not a vehicle either: it is
/// what tools send when they fill nothing in (pymavlink's `heartbeat_send(0, 0, …)`).
pub fn is_flight_controller(h: &apm::HEARTBEAT_DATA) -> bool {
    use apm::MavType as T;
    if h.autopilot == apm::MavAutopilot::MAV_AUTOPILOT_INVALID {
        return false;
    }
    // Exhaustive on purpose: a MAV_TYPE added to the dialect must be classified here.
    match h.mavtype {
        T::MAV_TYPE_FIXED_WING
        | T::MAV_TYPE_QUADROTOR
        | T::MAV_TYPE_COAXIAL
        | T::MAV_TYPE_HELICOPTER
        | T::MAV_TYPE_AIRSHIP
        | T::MAV_TYPE_FREE_BALLOON
        | T::MAV_TYPE_ROCKET
        | T::MAV_TYPE_GROUND_ROVER
        | T::MAV_TYPE_SURFACE_BOAT
        | T::MAV_TYPE_SUBMARINE
        | T::MAV_TYPE_HEXAROTOR
        | T::MAV_TYPE_OCTOROTOR
        | T::MAV_TYPE_TRICOPTER
        | T::MAV_TYPE_FLAPPING_WING
        | T::MAV_TYPE_KITE
        | T::MAV_TYPE_VTOL_TAILSITTER_DUOROTOR
        | T::MAV_TYPE_VTOL_TAILSITTER_QUADROTOR
        | T::MAV_TYPE_VTOL_TILTROTOR
        | T::MAV_TYPE_VTOL_FIXEDROTOR
        | T::MAV_TYPE_VTOL_TAILSITTER
        | T::MAV_TYPE_VTOL_TILTWING
        | T::MAV_TYPE_VTOL_RESERVED5
        | T::MAV_TYPE_PARAFOIL
        | T::MAV_TYPE_DODECAROTOR
        | T::MAV_TYPE_DECAROTOR
        | T::MAV_TYPE_GENERIC_MULTIROTOR
        | T::MAV_TYPE_SPACECRAFT_ORBITER
        | T::MAV_TYPE_GROUND_QUADRUPED
        | T::MAV_TYPE_VTOL_GYRODYNE => true,
        T::MAV_TYPE_GENERIC
        | T::MAV_TYPE_ANTENNA_TRACKER
        | T::MAV_TYPE_GCS
        | T::MAV_TYPE_ONBOARD_CONTROLLER
        | T::MAV_TYPE_GIMBAL
        | T::MAV_TYPE_ADSB
        | T::MAV_TYPE_CAMERA
        | T::MAV_TYPE_CHARGING_STATION
        | T::MAV_TYPE_FLARM
        | T::MAV_TYPE_SERVO
        | T::MAV_TYPE_ODID
        | T::MAV_TYPE_BATTERY
        | T::MAV_TYPE_PARACHUTE
        | T::MAV_TYPE_LOG
        | T::MAV_TYPE_OSD
        | T::MAV_TYPE_IMU
        | T::MAV_TYPE_GPS
        | T::MAV_TYPE_WINCH
        | T::MAV_TYPE_ILLUMINATOR
        | T::MAV_TYPE_GRIPPER
        | T::MAV_TYPE_RADIO => false,
    }
}

/// Who sent a frame, for [`AutopilotLock::observe`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sender {
    /// The autopilot the daemon listens to.
    Autopilot,
    /// No autopilot yet, and this is not one.
    Unlocked,
    /// Another system or component.
    Foreign,
    /// Another flight controller's HEARTBEAT, refused while the autopilot is heard.
    OtherAutopilot,
}

/// A change of the autopilot listened to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LockChange {
    /// The first autopilot.
    Locked,
    /// Another autopilot, after the previous one (system, component) fell silent.
    Changed {
        /// The previous autopilot.
        from: (u8, u8),
    },
}

/// Link ownership (docs/DAEMON.md "Link ownership"). The daemon listens to one autopilot
/// (system, component): the configured one, or the first flight controller heard
/// ([`is_flight_controller`]). Another flight controller's HEARTBEAT takes over only when the
/// autopilot has sent nothing for `silence_us` (its reboot under a new id, or its
/// replacement); the same autopilot rebooting keeps its ids and is detected from its clock
/// (`io::timesync`). Pure: the caller passes the reception time.
#[derive(Debug, Clone)]
pub struct AutopilotLock {
    want_sys: Option<u8>,
    want_comp: Option<u8>,
    silence_us: u64,
    locked: Option<(u8, u8)>,
    last_heard_us: u64,
}

impl AutopilotLock {
    /// Listen to system `sys` and component `comp` (0: any), taking another autopilot after
    /// `silence_us` without a message from the current one.
    pub fn new(sys: u8, comp: u8, silence_us: u64) -> Self {
        Self {
            want_sys: (sys != 0).then_some(sys),
            want_comp: (comp != 0).then_some(comp),
            silence_us,
            locked: None,
            last_heard_us: 0,
        }
    }

    /// The autopilot listened to.
    pub fn locked(&self) -> Option<(u8, u8)> {
        self.locked
    }

    /// A frame from (`sys`, `comp`) received at `rx_us`, with its HEARTBEAT if it is one.
    pub fn observe(
        &mut self,
        sys: u8,
        comp: u8,
        heartbeat: Option<&apm::HEARTBEAT_DATA>,
        rx_us: u64,
    ) -> (Sender, Option<LockChange>) {
        if self.locked == Some((sys, comp)) {
            self.last_heard_us = rx_us;
            return (Sender::Autopilot, None);
        }
        let fc = heartbeat.is_some_and(is_flight_controller);
        let wanted =
            self.want_sys.is_none_or(|s| s == sys) && self.want_comp.is_none_or(|c| c == comp);
        match self.locked {
            None if fc && wanted => {
                self.locked = Some((sys, comp));
                self.last_heard_us = rx_us;
                (Sender::Autopilot, Some(LockChange::Locked))
            }
            Some(from)
                if fc && wanted && rx_us.saturating_sub(self.last_heard_us) >= self.silence_us =>
            {
                self.locked = Some((sys, comp));
                self.last_heard_us = rx_us;
                (Sender::Autopilot, Some(LockChange::Changed { from }))
            }
            None => (Sender::Unlocked, None),
            Some(_) if fc => (Sender::OtherAutopilot, None),
            Some(_) => (Sender::Foreign, None),
        }
    }
}

/// Frames missing from the autopilot's 8-bit sequence, per MAVLink version (a sender's
/// MAVLink 1 and MAVLink 2 frames may be numbered apart, e.g. a router's, and a MAVLink 1 frame
/// in a MAVLink 2 stream is no loss). The mavlink crate drops frames with a bad CRC, an unknown
/// message id or a refused signature without telling us (rust-mavlink #209); each of them,
/// like a lost datagram, leaves a gap.
#[derive(Debug, Clone, Default)]
pub(super) struct SequenceTracker {
    /// Last sequence number: MAVLink 1, MAVLink 2.
    last: [Option<u8>; 2],
    /// Frames missing (gaps of 1–127): MAVLink 1, MAVLink 2.
    pub lost: [u64; 2],
    /// Frames repeated or arriving late (gaps of 128–255, i.e. behind the previous one).
    pub reordered: [u64; 2],
}

impl SequenceTracker {
    /// Account for a frame of `version` with sequence `seq`.
    pub fn observe(&mut self, version: MavlinkVersion, seq: u8) {
        let v = usize::from(version == MavlinkVersion::V2);
        if let Some(last) = self.last[v] {
            let gap = seq.wrapping_sub(last).wrapping_sub(1);
            match gap {
                0 => {}
                1..=127 => self.lost[v] += u64::from(gap),
                _ => self.reordered[v] += 1,
            }
        }
        self.last[v] = Some(seq);
    }

    /// Forget the sequences (the autopilot rebooted and restarts at 0).
    pub fn reset(&mut self) {
        self.last = [None; 2];
    }
}

/// Per-connection-independent state of the reader.
struct ReaderState {
    lock: AutopilotLock,
    ts: TimeSync,
    dec: InputDecoder,
    gate: MonotonicGate,
    seq: SequenceTracker,
    /// The sequence counts before the first frame of a clock being confirmed: a confirmed
    /// reboot restarts the sequence, which is no loss.
    seq_before_candidate: Option<SequenceTracker>,
}

/// Connect (with back-off), read, reconnect on transport errors.
pub(super) async fn reader(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    conn_tx: watch::Sender<Option<Arc<Conn>>>,
    events: mpsc::Sender<NavInput>,
    outbox: Outbox,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    let p = &cfg.ins.position;
    let mut st = ReaderState {
        lock: AutopilotLock::new(
            cfg.mavlink.autopilot_system_id,
            cfg.mavlink.autopilot_component_id,
            (cfg.mavlink.link_timeout_s * 1e6) as u64,
        ),
        ts: {
            let ts = TimeSync::new((cfg.mavlink.timesync_max_rtt_ms * 1e6) as u64);
            if cfg.mavlink.clock == crate::daemon::config::ClockSource::Autopilot {
                ts.with_autopilot_clock()
            } else {
                ts
            }
        },
        dec: InputDecoder::new(DecoderConfig {
            temperature: cfg.input.temperature,
            isa_delta_t_k: cfg.input.isa_delta_t_k,
            raw_imu_is_scaled: cfg.mavlink.autopilot == AutopilotKind::Ardupilot,
            default_sigma: (p.gnss_sigma_hor_m, p.gnss_sigma_ver_m, p.gnss_sigma_vel_mps),
            aoa_ssa_is_vanes: cfg.input.aoa_ssa == AoaSsaUse::Vanes,
            gnss_lag_us: (cfg.input.gnss_lag_s * 1e6).round() as u64,
            mag_from: cfg.input.magnetometer.decoder_choice(cfg.mavlink.autopilot),
        }),
        gate: MonotonicGate::default(),
        seq: SequenceTracker::default(),
        seq_before_candidate: None,
    };
    let mut backoff = Duration::from_millis(100);
    loop {
        if *stop.borrow() {
            return;
        }
        let conn = tokio::select! {
            c = connect(&cfg) => c,
            _ = stop.wait_for(|s| *s) => return,
        };
        let conn = match conn {
            Ok(c) => Arc::new(c),
            Err(e) => {
                tracing::warn!("connect {}: {e}", cfg.mavlink.connection);
                shared.count(|c| c.link_errors += 1);
                if stopped_after(&mut stop, backoff).await {
                    return;
                }
                backoff = (backoff * 2).min(Duration::from_secs(5));
                continue;
            }
        };
        backoff = Duration::from_millis(100);
        shared.count(|c| c.connects += 1);
        tracing::info!("MAVLink link open: {}", cfg.mavlink.connection);
        conn_tx.send_replace(Some(conn.clone()));
        loop {
            let r = tokio::select! {
                r = conn.recv_raw() => r,
                _ = stop.wait_for(|s| *s) => return,
            };
            match r {
                Ok(raw) => {
                    if !handle_raw(&cfg, clock, &raw, &mut st, &events, &outbox, &shared).await {
                        return;
                    }
                }
                Err(mavlink::error::MessageReadError::Parse(e)) => {
                    tracing::debug!("parse error: {e}");
                    shared.count(|c| c.rx_parse_errors += 1);
                }
                Err(mavlink::error::MessageReadError::Io(e)) => {
                    tracing::warn!("link error, reconnecting: {e}");
                    shared.count(|c| c.link_errors += 1);
                    break;
                }
            }
        }
        conn_tx.send_replace(None);
        if stopped_after(&mut stop, backoff).await {
            return;
        }
    }
}

fn kind_of(cfg: &DaemonConfig, h: &apm::HEARTBEAT_DATA) -> AutopilotKind {
    match (cfg.mavlink.autopilot, h.autopilot) {
        (AutopilotKind::Auto, apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA) => {
            AutopilotKind::Ardupilot
        }
        // PX4 and any other MAVLink autopilot: the common-message behaviour.
        (AutopilotKind::Auto, _) => AutopilotKind::Px4,
        (k, _) => k,
    }
}

/// Handle one frame. Returns `false` when the navigation thread is gone.
async fn handle_raw(
    cfg: &DaemonConfig,
    clock: Clock,
    raw: &MAVLinkMessageRaw,
    st: &mut ReaderState,
    events: &mpsc::Sender<NavInput>,
    outbox: &Outbox,
    shared: &Shared,
) -> bool {
    use apm::MavMessage as M;
    let rx_at = Instant::now();
    let rx_us = clock.now_us();
    let version = raw.version();
    let signed = matches!(raw, MAVLinkMessageRaw::V2(r) if r.incompatibility_flags() & 0x01 != 0);
    shared.count(|c| {
        c.rx_frames += 1;
        c.rx_v1_frames += u64::from(version == mavlink::MavlinkVersion::V1);
        c.rx_signed_frames += u64::from(signed);
    });
    let msg = match M::parse(version, raw.message_id(), raw.payload()) {
        Ok(m) => m,
        Err(e) => {
            tracing::debug!("payload parse error: {e}");
            shared.count(|c| c.rx_parse_errors += 1);
            return true;
        }
    };
    let Ok(sys) = u8::try_from(raw.system_id()) else {
        shared.count(|c| c.rx_foreign += 1);
        return true;
    };
    let comp = raw.component_id();
    // Our own frames echoed back by a router or a broadcast link.
    if comp == cfg.mavlink.component_id {
        shared.count(|c| c.rx_foreign += 1);
        return true;
    }
    let heartbeat = match &msg {
        M::HEARTBEAT(h) => Some(h),
        _ => None,
    };
    let (sender, change) = st.lock.observe(sys, comp, heartbeat, rx_us);
    if let (Some(change), Some(h)) = (change, heartbeat) {
        let kind = kind_of(cfg, h);
        match change {
            LockChange::Locked => tracing::info!(sys, comp, ?kind, "autopilot found"),
            LockChange::Changed { from } => {
                // Another autopilot, another clock and stream: start over as after a reboot.
                st.ts.restart();
                st.dec.reset();
                st.seq = SequenceTracker::default();
                st.seq_before_candidate = None;
                shared.count(|c| c.autopilot_changes += 1);
                outbox.status(
                    apm::MavSeverity::MAV_SEVERITY_WARNING,
                    &format!(
                        "ianav: autopilot {}/{} silent, now {sys}/{comp}",
                        from.0, from.1
                    ),
                );
            }
        }
        shared.state(|s| {
            s.autopilot = Some((sys, comp, kind));
            s.request_generation += 1;
        });
        st.dec
            .set_raw_imu_is_scaled(kind == AutopilotKind::Ardupilot);
        st.dec
            .set_mag_from(cfg.input.magnetometer.decoder_choice(kind));
    }
    if sender != Sender::Autopilot {
        // TIMESYNC requests are answered from anyone; responses count only from the autopilot.
        if let M::TIMESYNC(t) = &msg
            && t.tc1 == 0
            && let Some(reply) = st.ts.handle(t, clock.now_ns(), sys, comp)
        {
            outbox.send(M::TIMESYNC(reply));
        }
        let input = mavlink_in::is_input(&msg);
        shared.count(|c| match sender {
            Sender::Unlocked => c.rx_before_heartbeat += 1,
            _ => {
                c.rx_foreign += 1;
                c.rx_foreign_heartbeats += u64::from(heartbeat.is_some());
                c.rx_foreign_autopilots += u64::from(sender == Sender::OtherAutopilot);
                c.rx_foreign_input += u64::from(input);
            }
        });
        return true;
    }
    if heartbeat.is_some() {
        shared.count(|c| c.autopilot_heartbeats += 1);
    }
    let outage_after_us = (cfg.mavlink.link_timeout_s * 1e6) as u64;
    shared.state(|s| {
        if let Some(last) = s.last_rx_us
            && rx_us.saturating_sub(last) >= outage_after_us
        {
            s.last_outage_us = Some(rx_us - last);
        }
        s.last_rx_us = Some(rx_us);
    });
    let stamp = timesync::clock_stamp_us(&msg).map(|ap_us| st.ts.observe_clock(ap_us, rx_us));
    match stamp {
        Some(ClockStamp::Held) => {
            st.seq_before_candidate
                .get_or_insert_with(|| st.seq.clone());
        }
        Some(ClockStamp::Reboot) => {
            // The new boot's sequence restarted: no loss since the first frame held.
            if let Some(before) = st.seq_before_candidate.take() {
                st.seq = before;
            }
            st.seq.reset();
            st.dec.reset();
            shared.state(|s| s.request_generation += 1);
            shared.count(|c| c.autopilot_reboots += 1);
            outbox.status(
                apm::MavSeverity::MAV_SEVERITY_WARNING,
                "ianav: autopilot reboot detected",
            );
        }
        Some(ClockStamp::Jump) => {
            st.seq_before_candidate = None;
            st.dec.reset();
            shared.state(|s| s.request_generation += 1);
            shared.count(|c| c.autopilot_time_jumps += 1);
            outbox.status(
                apm::MavSeverity::MAV_SEVERITY_WARNING,
                "ianav: autopilot clock jumped",
            );
        }
        Some(ClockStamp::Fits) => st.seq_before_candidate = None,
        None => {}
    }
    st.seq.observe(raw.version(), raw.sequence());
    let (seq, tc) = (st.seq.clone(), *st.ts.counters());
    shared.count(|c| {
        c.rx_seq_lost_v1 = seq.lost[0];
        c.rx_seq_lost = seq.lost[1];
        c.rx_seq_reordered_v1 = seq.reordered[0];
        c.rx_seq_reordered = seq.reordered[1];
        c.timesync = tc;
    });
    if stamp == Some(ClockStamp::Held) {
        // Not on the autopilot's clock (yet): its time would be wrong (io::timesync).
        return true;
    }
    match &msg {
        M::TIMESYNC(t) => {
            if let Some(reply) = st.ts.handle(t, clock.now_ns(), sys, comp) {
                outbox.send(M::TIMESYNC(reply));
            }
        }
        M::COMMAND_ACK(a) => {
            shared.count(|c| c.command_acks += 1);
            if a.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL {
                shared.state(|s| s.interval_acks.push(a.result));
            }
        }
        _ => {}
    }
    let ReaderState { ts, dec, .. } = st;
    let evs = dec.decode(&msg, &mut |t| ts.map(t, rx_us));
    let (dc, tc, offset) = (
        *st.dec.counters(),
        *st.ts.counters(),
        st.ts.vehicle_offset_us(),
    );
    shared.count(|c| {
        c.input = dc;
        c.timesync = tc;
    });
    shared.state(|s| s.offset_us = offset);
    for ev in evs {
        let kind = match &ev {
            SensorEvent::Imu(_) => Kind::Imu,
            SensorEvent::Air(_) => Kind::Air,
            SensorEvent::Mag(_) => Kind::Mag,
            SensorEvent::Gnss(_) => Kind::Gnss,
            SensorEvent::Frame(_) => Kind::Frame,
            SensorEvent::RefAttitude(_) => Kind::RefAttitude,
            // Not decoded from MAVLink.
            SensorEvent::Alignment(_)
            | SensorEvent::HeightAboveTerrain(_)
            | SensorEvent::VisionApplied(_) => continue,
        };
        if !st.gate.accept(kind, ev.t_us()) {
            let (n, r) = (st.gate.rejected, st.gate.repeated);
            shared.count(|c| {
                c.time_order_rejected = n;
                c.time_repeated = r;
            });
            continue;
        }
        if let SensorEvent::Gnss(fix) = &ev {
            let e7 = |rad: f64| (rad.to_degrees() * 1e7).round() as i64;
            let h_acc_mm = (fix.sigma_hor_m * 1e3).round() as i64;
            if shared.state(|s| s.is_echo(e7(fix.pos.lat_rad), e7(fix.pos.lon_rad), h_acc_mm)) {
                let first = shared.count(|c| {
                    c.gnss_echo += 1;
                    c.gnss_echo == 1
                });
                if first {
                    outbox.status(
                        apm::MavSeverity::MAV_SEVERITY_WARNING,
                        "ianav: autopilot reports our GPS_INPUT as GNSS; refused",
                    );
                }
                continue;
            }
            shared.state(|s| {
                s.last_fix_us = Some(rx_us);
                s.last_fix_sensor_us = Some(fix.t_us);
            });
            // The undulation at the start's fix gives the origin's MSL altitude (the start
            // itself is the navigator's: `nav::policy`).
            if let Some(und) = st.dec.undulation_m() {
                shared.state(|s| {
                    if s.origin.is_none() {
                        s.undulation_m = und;
                    }
                });
            }
        }
        if events.send(NavInput::Event(ev, rx_at)).await.is_err() {
            tracing::error!("navigation thread gone");
            return false;
        }
        shared.count(|c| c.events_to_nav += 1);
    }
    true
}

/// Our TIMESYNC requests at `mavlink.timesync_rate_hz`.
pub(super) async fn timesync_requests(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    outbox: Outbox,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    if cfg.mavlink.timesync_rate_hz <= 0.0 {
        return;
    }
    let period = Duration::from_secs_f64(1.0 / cfg.mavlink.timesync_rate_hz);
    loop {
        if stopped_after(&mut stop, period).await {
            return;
        }
        if let Some((sys, comp, _)) = shared.state(|s| s.autopilot) {
            outbox.send(apm::MavMessage::TIMESYNC(TimeSync::request(
                clock.now_ns(),
                sys,
                comp,
            )));
        }
    }
}

/// The messages and rates to request from an autopilot kind.
pub fn requested_streams(cfg: &DaemonConfig, kind: AutopilotKind) -> Vec<(u32, f64)> {
    let i = &cfg.input;
    let mut v = match kind {
        // ArduPlane DENIES intervals shorter than 80 % of its loop period: the negotiation
        // steps the rate down to the fastest it accepts (40 Hz at a 50 Hz loop).
        AutopilotKind::Ardupilot => vec![
            (apm::SCALED_IMU_DATA::ID, i.imu_rate_hz),
            // Its AIRSPEED (the sensor, with a health flag) defaults to 1 Hz.
            (apm::AIRSPEED_DATA::ID, i.air_rate_hz),
        ],
        _ => vec![
            (apm::HIGHRES_IMU_DATA::ID, i.imu_rate_hz),
            (apm::AIRSPEED_DATA::ID, i.air_rate_hz),
        ],
    };
    if i.aoa_ssa == AoaSsaUse::Vanes {
        v.push((apm::AOA_SSA_DATA::ID, i.air_rate_hz));
    }
    if i.magnetometer != MagnetometerSource::Imu && kind != AutopilotKind::Ardupilot {
        v.push((apm::SCALED_IMU_DATA::ID, i.air_rate_hz));
    }
    v.extend([
        (apm::SCALED_PRESSURE_DATA::ID, i.air_rate_hz),
        (apm::VFR_HUD_DATA::ID, i.air_rate_hz),
        (apm::ATTITUDE_DATA::ID, i.attitude_rate_hz),
        (apm::GPS_RAW_INT_DATA::ID, i.gnss_rate_hz),
        (apm::GLOBAL_POSITION_INT_DATA::ID, i.gnss_rate_hz),
    ]);
    v.retain(|(_, r)| *r > 0.0);
    v
}

/// Negotiate the SET_MESSAGE_INTERVAL set whenever the request generation changes (autopilot
/// found, reboot, link restored): one request in flight at a time, refused rates retried
/// slower ([`intervals`](super::intervals)), every refusal logged, counted and announced.
pub(super) async fn interval_requests(
    cfg: Arc<DaemonConfig>,
    outbox: Outbox,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    use super::intervals::{Negotiator, Outcome};
    let start = Instant::now();
    let mut done = 0_u64;
    let mut round: Option<(u8, u8, Negotiator)> = None;
    loop {
        if stopped_after(&mut stop, Duration::from_millis(20)).await {
            return;
        }
        let (generation, ap, acks) = shared.state(|s| {
            (
                s.request_generation,
                s.autopilot,
                std::mem::take(&mut s.interval_acks),
            )
        });
        let Some((sys, comp, kind)) = ap else {
            continue;
        };
        if generation != done {
            done = generation;
            round = Some((sys, comp, Negotiator::new(requested_streams(&cfg, kind))));
            shared.state(|s| s.granted_intervals.clear());
            shared.count(|c| c.interval_requests += 1);
            tracing::info!(?kind, "negotiating message intervals");
            continue;
        }
        let Some((sys, comp, neg)) = &mut round else {
            continue;
        };
        let now_us = u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX);
        let mut outcomes: Vec<Outcome> = acks.into_iter().filter_map(|r| neg.on_ack(r)).collect();
        let (send, timed_out) = neg.poll(now_us);
        outcomes.extend(timed_out);
        for o in outcomes {
            match o {
                Outcome::Accepted { msg_id, rate_hz } => {
                    tracing::info!(msg_id, rate_hz, "message interval accepted");
                    shared.state(|s| s.granted_intervals.push((msg_id, rate_hz)));
                }
                Outcome::Refused {
                    msg_id,
                    rate_hz,
                    result,
                    retry_hz,
                } => {
                    shared.count(|c| c.interval_refused += 1);
                    let text = match retry_hz {
                        Some(r) => {
                            format!("ianav: msg {msg_id} at {rate_hz} Hz refused, trying {r} Hz")
                        }
                        None => format!("ianav: msg {msg_id} refused at every rate"),
                    };
                    tracing::warn!(?result, "{text}");
                    outbox.status(apm::MavSeverity::MAV_SEVERITY_WARNING, &text);
                }
                Outcome::Unanswered { msg_id, rate_hz } => {
                    shared.count(|c| c.interval_unanswered += 1);
                    tracing::warn!(msg_id, rate_hz, "message interval request not acknowledged");
                }
            }
        }
        if let Some((id, rate)) = send {
            outbox.send(apm::MavMessage::COMMAND_LONG(
                mavlink_out::set_message_interval(*sys, *comp, id, rate),
            ));
        }
        if neg.done() {
            round = None;
            tracing::info!("message intervals negotiated");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use MavlinkVersion::{V1, V2};

    #[test]
    fn sequence_gaps_count_missing_frames_and_late_ones_apart_per_mavlink_version() {
        let mut t = SequenceTracker::default();
        for seq in [250, 251, 252] {
            t.observe(V2, seq);
        }
        assert_eq!((t.lost, t.reordered), ([0, 0], [0, 0]));
        // 253 and 254 dropped (say a bad CRC); wrap-around 255 → 0 is no gap.
        t.observe(V2, 255);
        t.observe(V2, 0);
        assert_eq!((t.lost, t.reordered), ([0, 2], [0, 0]));
        // A repeat and a late frame.
        t.observe(V2, 0);
        t.observe(V2, 1);
        t.observe(V2, 0);
        assert_eq!((t.lost, t.reordered), ([0, 2], [0, 2]));
        // MAVLink 1 frames keep their own numbers: interleaved, neither stream loses any.
        for k in 0..10_u8 {
            t.observe(V1, 100 + k);
            t.observe(V2, 1 + k);
        }
        assert_eq!((t.lost, t.reordered), ([0, 2], [0, 2]));
        t.observe(V1, 120);
        assert_eq!(t.lost, [10, 2]);
        // After a reboot the sequence restarts without a count.
        t.reset();
        t.observe(V2, 0);
        assert_eq!((t.lost, t.reordered), ([10, 2], [0, 2]));
    }

    fn hb(mavtype: apm::MavType, autopilot: apm::MavAutopilot) -> apm::HEARTBEAT_DATA {
        apm::HEARTBEAT_DATA {
            mavtype,
            autopilot,
            ..Default::default()
        }
    }

    const S: u64 = 1_000_000;

    #[test]
    fn the_first_flight_controller_is_kept_and_others_are_refused_while_it_is_heard() {
        use apm::MavAutopilot as A;
        use apm::MavType as T;
        let plane = hb(T::MAV_TYPE_FIXED_WING, A::MAV_AUTOPILOT_PX4);
        let mut lock = AutopilotLock::new(0, 0, 3 * S);
        // Before any autopilot: a ground station (also with a filled-in autopilot field, or
        // left at GENERIC/GENERIC as tools do), a companion, a camera: none is one.
        for h in [
            hb(T::MAV_TYPE_GCS, A::MAV_AUTOPILOT_INVALID),
            hb(T::MAV_TYPE_GCS, A::MAV_AUTOPILOT_ARDUPILOTMEGA),
            hb(T::MAV_TYPE_GENERIC, A::MAV_AUTOPILOT_GENERIC),
            hb(T::MAV_TYPE_ONBOARD_CONTROLLER, A::MAV_AUTOPILOT_PX4),
            hb(T::MAV_TYPE_CAMERA, A::MAV_AUTOPILOT_PX4),
            hb(T::MAV_TYPE_FIXED_WING, A::MAV_AUTOPILOT_INVALID),
        ] {
            assert_eq!(
                lock.observe(255, 190, Some(&h), 0),
                (Sender::Unlocked, None)
            );
        }
        assert_eq!(lock.observe(1, 1, None, 0), (Sender::Unlocked, None));
        assert_eq!(
            lock.observe(1, 1, Some(&plane), S),
            (Sender::Autopilot, Some(LockChange::Locked))
        );
        // A second flight controller (another system, or another component of this one)
        // every 0.5 s while the autopilot streams: refused each time.
        for k in 0..40 {
            let t = S + k * S / 2;
            assert_eq!(lock.observe(1, 1, None, t), (Sender::Autopilot, None));
            assert_eq!(
                lock.observe(2, 1, Some(&plane), t + 1),
                (Sender::OtherAutopilot, None)
            );
            assert_eq!(lock.observe(1, 191, None, t + 2), (Sender::Foreign, None));
            assert_eq!(
                lock.observe(
                    255,
                    190,
                    Some(&hb(T::MAV_TYPE_GCS, A::MAV_AUTOPILOT_INVALID)),
                    t
                ),
                (Sender::Foreign, None)
            );
        }
        assert_eq!(lock.locked(), Some((1, 1)));
        // The autopilot falls silent (last heard at 20.5 s): after 3 s, and not before, a
        // flight controller's HEARTBEAT takes over; others' messages never do.
        let last = S + 39 * S / 2;
        assert_eq!(
            lock.observe(2, 1, Some(&plane), last + 3 * S - 1),
            (Sender::OtherAutopilot, None)
        );
        assert_eq!(
            lock.observe(2, 1, None, last + 4 * S),
            (Sender::Foreign, None)
        );
        assert_eq!(
            lock.observe(2, 1, Some(&plane), last + 4 * S),
            (
                Sender::Autopilot,
                Some(LockChange::Changed { from: (1, 1) })
            )
        );
        assert_eq!(
            lock.observe(1, 1, Some(&plane), last + 4 * S + 1).0,
            Sender::OtherAutopilot
        );
    }

    #[test]
    fn a_configured_autopilot_is_the_only_one_taken() {
        use apm::MavAutopilot as A;
        use apm::MavType as T;
        let plane = hb(T::MAV_TYPE_FIXED_WING, A::MAV_AUTOPILOT_ARDUPILOTMEGA);
        let mut lock = AutopilotLock::new(7, 1, 3 * S);
        assert_eq!(
            lock.observe(1, 1, Some(&plane), 0),
            (Sender::Unlocked, None)
        );
        assert_eq!(
            lock.observe(7, 2, Some(&plane), 0),
            (Sender::Unlocked, None)
        );
        assert_eq!(
            lock.observe(7, 1, Some(&plane), 0),
            (Sender::Autopilot, Some(LockChange::Locked))
        );
        // Silent or not, no other autopilot is taken.
        assert_eq!(
            lock.observe(1, 1, Some(&plane), 100 * S),
            (Sender::OtherAutopilot, None)
        );
        // Any component of system 7 with component 0.
        let mut lock = AutopilotLock::new(7, 0, 3 * S);
        assert_eq!(
            lock.observe(7, 2, Some(&plane), 0).1,
            Some(LockChange::Locked)
        );
    }

    #[test]
    fn scaled_imu_is_requested_beside_px4_unless_the_imu_message_is_chosen() {
        let cfg = |mag: &str| {
            DaemonConfig::from_toml_str(
                &format!(
                    "[mavlink]\nconnection = \"udpin:127.0.0.1:14540\"\n\
                     [input]\nmagnetometer = \"{mag}\"\n[output]\nrate_hz = 10.0\n"
                ),
                None,
            )
            .unwrap()
        };
        let ids = |c: &DaemonConfig, k| -> Vec<u32> {
            requested_streams(c, k).iter().map(|(id, _)| *id).collect()
        };
        let scaled = apm::SCALED_IMU_DATA::ID;
        let px4_imu = ids(&cfg("imu"), AutopilotKind::Px4);
        assert!(px4_imu.contains(&apm::HIGHRES_IMU_DATA::ID));
        assert!(!px4_imu.contains(&scaled));
        // The default follows the autopilot: the raw field beside PX4.
        let px4_auto = ids(&cfg("auto"), AutopilotKind::Px4);
        assert!(px4_auto.contains(&apm::HIGHRES_IMU_DATA::ID) && px4_auto.contains(&scaled));
        let px4_raw = ids(&cfg("scaled_imu"), AutopilotKind::Px4);
        assert!(px4_raw.contains(&apm::HIGHRES_IMU_DATA::ID) && px4_raw.contains(&scaled));
        // ArduPilot's IMU message is SCALED_IMU already: requested once.
        let ap = ids(&cfg("scaled_imu"), AutopilotKind::Ardupilot);
        assert_eq!(ap.iter().filter(|&&id| id == scaled).count(), 1);
    }
}
