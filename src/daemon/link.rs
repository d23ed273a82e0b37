//! The MAVLink link tasks (research/mavlink.md §1.3–1.6, §3.4, §7): connection with
//! reconnection, the reader (autopilot identification, TIMESYNC, reboot detection, message →
//! sensor events, INS initialisation), the writer, and the periodic TIMESYNC and
//! SET_MESSAGE_INTERVAL requests.
//!
//! The reader receives raw frames (`recv_raw`) and parses the payload itself, so that it can
//! count MAVLink 1 and signed frames and payload parse errors on every transport. Frames with
//! a bad CRC or an unknown message id, and (with `refuse_unsigned`) unsigned or MAVLink 1
//! frames, are discarded inside the mavlink crate's frame decoder before the reader sees
//! them: they are invisible to the counters (rust-mavlink #209), and the robustness tests
//! check instead that valid traffic after them still gets through.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mavlink::{AsyncMavConnection, MAVLinkMessageRaw, MavHeader, Message, MessageData};
use tokio::sync::{mpsc, watch};

use super::health::MIN_IMU_RATE_HZ;
use super::nav_thread::NavInput;
use super::{Clock, Outbox, Shared, stopped_after};
use crate::config::{AoaSsaUse, AutopilotKind, DaemonConfig};
use crate::ins::InsInit;
use crate::io::mavlink_in::{DecoderConfig, InputDecoder};
use crate::io::mavlink_out;
use crate::io::timesync::{Kind, MonotonicGate, TimeSync};
use crate::sensors::SensorEvent;
use mavlink::dialects::ardupilotmega as apm;

/// The connection type.
pub type Conn = mavlink::AsyncConnection<apm::MavMessage>;

/// Largest difference between the ATTITUDE and the GNSS fix used to start the INS, µs.
pub const INIT_ATTITUDE_MAX_AGE_US: u64 = 1_000_000;
/// The INS starts only once the IMU stream runs at the rate solutions are published at
/// ([`MIN_IMU_RATE_HZ`]) over this window: before the interval requests are granted an
/// autopilot streams its IMU at 1 Hz, and an INS started on that integrates seconds-long steps.
pub const INIT_IMU_WINDOW_US: u64 = 1_000_000;
/// Fixes without a down velocity after which the INS starts anyway (at 0 m/s down).
pub const INIT_FIXES_WITHOUT_VD: u64 = 10;

async fn connect(cfg: &DaemonConfig) -> std::io::Result<Conn> {
    let mut conn = mavlink::connect_async::<apm::MavMessage>(&cfg.mavlink.connection).await?;
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

/// Frames missing from a sender's 8-bit sequence. The mavlink crate drops frames with a bad
/// CRC, an unknown message id or a refused signature without telling us (rust-mavlink #209);
/// each of them, like a lost datagram, leaves a gap in the autopilot's sequence.
#[derive(Debug, Clone)]
pub(super) struct SequenceTracker {
    /// Last sequence number per component id.
    last: [Option<u8>; 256],
    /// Frames missing (gaps of 1–127).
    pub lost: u64,
    /// Frames repeated or arriving late (gaps of 128–255, i.e. behind the previous one).
    pub reordered: u64,
}

impl Default for SequenceTracker {
    fn default() -> Self {
        Self {
            last: [None; 256],
            lost: 0,
            reordered: 0,
        }
    }
}

impl SequenceTracker {
    /// Account for a frame of component `comp` with sequence `seq`.
    pub fn observe(&mut self, comp: u8, seq: u8) {
        if let Some(last) = self.last[usize::from(comp)] {
            let gap = seq.wrapping_sub(last).wrapping_sub(1);
            match gap {
                0 => {}
                1..=127 => self.lost += u64::from(gap),
                _ => self.reordered += 1,
            }
        }
        self.last[usize::from(comp)] = Some(seq);
    }

    /// Forget the sequences (the autopilot rebooted and restarts at 0).
    pub fn reset(&mut self) {
        self.last = [None; 256];
    }
}

/// Per-connection-independent state of the reader.
struct ReaderState {
    ts: TimeSync,
    dec: InputDecoder,
    gate: MonotonicGate,
    seq: SequenceTracker,
    init_sent: bool,
    /// Times of the IMU samples of the last [`INIT_IMU_WINDOW_US`], µs.
    recent_imu_us: VecDeque<u64>,
    /// True airspeed of the latest air-data sample, m/s.
    tas_mps: Option<f64>,
    /// The INS has been started at a flying airspeed.
    flight_init_sent: bool,
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
        ts: {
            let ts = TimeSync::new((cfg.mavlink.timesync_max_rtt_ms * 1e6) as u64);
            if cfg.mavlink.clock == crate::config::ClockSource::Autopilot {
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
        }),
        gate: MonotonicGate::default(),
        seq: SequenceTracker::default(),
        init_sent: false,
        recent_imu_us: VecDeque::new(),
        tas_mps: None,
        flight_init_sent: false,
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
    if let M::HEARTBEAT(h) = &msg
        && h.autopilot != apm::MavAutopilot::MAV_AUTOPILOT_INVALID
    {
        let kind = kind_of(cfg, h);
        let new = shared.state(|s| {
            let new = s.autopilot.is_none_or(|(a, _, _)| a != sys);
            if new {
                s.autopilot = Some((sys, comp, kind));
                s.request_generation += 1;
            }
            new
        });
        if new {
            tracing::info!(sys, comp, ?kind, "autopilot found");
            st.dec
                .set_raw_imu_is_scaled(kind == AutopilotKind::Ardupilot);
        }
        shared.count(|c| c.autopilot_heartbeats += 1);
    }
    let Some((ap_sys, _, _)) = shared.state(|s| s.autopilot) else {
        // Answer TIMESYNC from anyone; ignore the rest until the autopilot is known.
        if let M::TIMESYNC(t) = &msg {
            if let Some(reply) = st.ts.handle(t, clock.now_ns(), sys, comp) {
                outbox.send(M::TIMESYNC(reply));
            }
        } else {
            shared.count(|c| c.rx_before_heartbeat += 1);
        }
        return true;
    };
    if sys != ap_sys {
        shared.count(|c| c.rx_foreign += 1);
        return true;
    }
    shared.state(|s| s.last_rx_us = Some(rx_us));
    let clock_stamp_us = match &msg {
        M::HIGHRES_IMU(m) => Some(m.time_usec),
        M::RAW_IMU(m) => Some(m.time_usec),
        M::SCALED_IMU(m) => Some(u64::from(m.time_boot_ms) * 1_000),
        M::ATTITUDE(m) => Some(u64::from(m.time_boot_ms) * 1_000),
        M::SYSTEM_TIME(m) => Some(u64::from(m.time_boot_ms) * 1_000),
        _ => None,
    };
    if let Some(ap_us) = clock_stamp_us
        && st.ts.observe_clock(ap_us, rx_us)
    {
        st.dec.reset();
        st.seq.reset();
        st.recent_imu_us.clear();
        shared.state(|s| s.request_generation += 1);
        shared.count(|c| c.autopilot_reboots += 1);
        outbox.status(
            apm::MavSeverity::MAV_SEVERITY_WARNING,
            "ianav: autopilot reboot detected",
        );
    }
    // After the reboot check: a reboot restarts the sequence, which is not a loss.
    st.seq.observe(comp, raw.sequence());
    let (lost, reordered) = (st.seq.lost, st.seq.reordered);
    shared.count(|c| {
        c.rx_seq_lost = lost;
        c.rx_seq_reordered = reordered;
    });
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
        };
        if !st.gate.accept(kind, ev.t_us()) {
            let (n, r) = (st.gate.rejected, st.gate.repeated);
            shared.count(|c| {
                c.time_order_rejected = n;
                c.time_repeated = r;
            });
            continue;
        }
        if let SensorEvent::Air(air) = &ev {
            st.tas_mps = Some(air.tas_mps);
        }
        if let SensorEvent::Imu(imu) = &ev {
            st.recent_imu_us.push_back(imu.t_us);
            while st
                .recent_imu_us
                .front()
                .is_some_and(|t| imu.t_us.saturating_sub(*t) >= INIT_IMU_WINDOW_US)
            {
                st.recent_imu_us.pop_front();
            }
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
            let imu_ready =
                st.recent_imu_us.len() as f64 >= MIN_IMU_RATE_HZ * INIT_IMU_WINDOW_US as f64 * 1e-6;
            // GPS_RAW_INT has no down velocity: the INS starts from a fix that has
            // GLOBAL_POSITION_INT's (a descent taken for level flight throws the first seconds
            // off), unless the autopilot never sends it.
            let vd_ready = st.dec.last_fix_has_vertical_velocity()
                || st.dec.counters().gnss_no_vd >= INIT_FIXES_WITHOUT_VD;
            let flying = st
                .tas_mps
                .is_some_and(|v| v >= cfg.input.start_airspeed_mps);
            // Started on the ground (an autopilot with our GPS_INPUT as a receiver does not arm
            // without it), the INS is started again once flying: its models are those of a
            // flying aircraft, and through the take-off roll it went wrong.
            let start = !st.init_sent || (flying && !st.flight_init_sent);
            if start && imu_ready && vd_ready {
                match st.dec.attitude() {
                    Some(att) if att.t_us.abs_diff(fix.t_us) <= INIT_ATTITUDE_MAX_AGE_US => {
                        let year = if cfg.navigation.mag_decimal_year != 0.0 {
                            cfg.navigation.mag_decimal_year
                        } else {
                            clock.decimal_year()
                        };
                        let mut init = InsInit::new(att.q_nb, fix.pos, fix.v_ned_mps, year);
                        init.valid_at_us = Some(fix.t_us);
                        if !st.init_sent {
                            let und = st.dec.undulation_m().unwrap_or(0.0);
                            shared.state(|s| {
                                s.origin = Some(fix.pos);
                                s.undulation_m = und;
                            });
                        } else {
                            tracing::info!("flying: INS started again for flight");
                        }
                        if events.send(NavInput::Init(Box::new(init))).await.is_err() {
                            return false;
                        }
                        st.init_sent = true;
                        st.flight_init_sent = flying;
                    }
                    _ => tracing::debug!("GNSS fix without a recent ATTITUDE: INS not started"),
                }
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
    use super::SequenceTracker;

    #[test]
    fn sequence_gaps_count_missing_frames_and_late_ones_apart() {
        let mut t = SequenceTracker::default();
        for seq in [250, 251, 252] {
            t.observe(1, seq);
        }
        assert_eq!((t.lost, t.reordered), (0, 0));
        // 253 and 254 dropped (say a bad CRC); wrap-around 255 → 0 is no gap.
        t.observe(1, 255);
        t.observe(1, 0);
        assert_eq!((t.lost, t.reordered), (2, 0));
        // A repeat and a late frame.
        t.observe(1, 0);
        t.observe(1, 1);
        t.observe(1, 0);
        assert_eq!((t.lost, t.reordered), (2, 2));
        // Components are independent; the first frame of one sets no gap.
        t.observe(200, 77);
        t.observe(200, 80);
        assert_eq!((t.lost, t.reordered), (4, 2));
        // After a reboot the sequence restarts without a count.
        t.reset();
        t.observe(1, 0);
        assert_eq!((t.lost, t.reordered), (4, 2));
    }
}
