//! What the daemon's tasks and the navigation thread share: the one clock ([`Clock`]), every
//! counter ([`Counters`]), the link and estimator state ([`State`]) behind [`Shared`], the latest
//! solution ([`Latest`]), the outgoing-message queue ([`Outbox`]) and the caller's [`Handle`].

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Instant, SystemTime};

use tokio::sync::{mpsc, watch};

use crate::daemon::config::{AutopilotKind, DaemonConfig};
use crate::ins::InsStats;
use crate::io::mavlink_in::InputCounters;
use crate::io::mavlink_out;
use crate::io::timesync::TimeSyncCounters;
use crate::math::wgs84::Geodetic;
use crate::nav::{NavSolution, NavigatorStats};
use mavlink::dialects::ardupilotmega as apm;

/// The daemon's monotonic clock.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: Instant,
    unix_at_start_us: u64,
}

impl Clock {
    /// Start now.
    pub fn new() -> Self {
        let unix_at_start_us = SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX));
        Self {
            start: Instant::now(),
            unix_at_start_us,
        }
    }

    /// µs since start.
    pub fn now_us(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_micros()).unwrap_or(u64::MAX)
    }

    /// ns since start.
    pub fn now_ns(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    /// Unix time of a time on this clock, µs.
    pub fn unix_us(&self, t_us: u64) -> u64 {
        self.unix_at_start_us.saturating_add(t_us)
    }

    /// Decimal year now (for the magnetic model).
    pub fn decimal_year(&self) -> f64 {
        1970.0 + self.unix_at_start_us as f64 / 1e6 / 31_556_952.0
    }
}

impl Default for Clock {
    fn default() -> Self {
        Self::new()
    }
}

/// Every counter of the daemon (a snapshot is logged periodically; tests read it).
#[derive(Debug, Clone, Default)]
pub struct Counters {
    /// MAVLink frames received (CRC-valid, known message id).
    pub rx_frames: u64,
    /// … of which MAVLink 1.
    pub rx_v1_frames: u64,
    /// … of which signed.
    pub rx_signed_frames: u64,
    /// Frames whose payload did not parse (bad enum value, bad length).
    pub rx_parse_errors: u64,
    /// Frames missing from the autopilot's MAVLink 2 sequence numbers: bad CRC, unknown
    /// message id, refused signature (all dropped silently by the mavlink crate) or lost in
    /// transport.
    pub rx_seq_lost: u64,
    /// The same in the autopilot's MAVLink 1 frames, numbered apart.
    pub rx_seq_lost_v1: u64,
    /// Autopilot MAVLink 2 frames repeated or out of order by sequence number.
    pub rx_seq_reordered: u64,
    /// The same for MAVLink 1 frames.
    pub rx_seq_reordered_v1: u64,
    /// Messages from any system or component but the autopilot (or carrying our own component
    /// id), ignored.
    pub rx_foreign: u64,
    /// … of which HEARTBEATs.
    pub rx_foreign_heartbeats: u64,
    /// … of which another flight controller's HEARTBEATs, refused while the autopilot is
    /// heard (docs/DAEMON.md "Link ownership").
    pub rx_foreign_autopilots: u64,
    /// … of which sensor or clock messages (never decoded).
    pub rx_foreign_input: u64,
    /// Sensor messages received before the autopilot's HEARTBEAT, ignored.
    pub rx_before_heartbeat: u64,
    /// Link (re)connections.
    pub connects: u64,
    /// Transport errors that forced a reconnection.
    pub link_errors: u64,
    /// Link losses (no message for `link_timeout_s`).
    pub link_losses: u64,
    /// Messages sent.
    pub tx_messages: u64,
    /// Messages not sent (no peer yet, transport error).
    pub tx_failed: u64,
    /// Messages dropped because the outbox was full.
    pub tx_queue_full: u64,
    /// SET_MESSAGE_INTERVAL negotiation rounds started.
    pub interval_requests: u64,
    /// Interval requests refused by the autopilot (DENIED and others).
    pub interval_refused: u64,
    /// Interval requests never acknowledged.
    pub interval_unanswered: u64,
    /// COMMAND_ACKs received.
    pub command_acks: u64,
    /// Autopilot HEARTBEATs received.
    pub autopilot_heartbeats: u64,
    /// Autopilot reboots detected.
    pub autopilot_reboots: u64,
    /// Forward jumps of the autopilot's clock detected.
    pub autopilot_time_jumps: u64,
    /// Changes of the autopilot listened to (the previous one silent for the link timeout).
    pub autopilot_changes: u64,
    /// Message conversion counters.
    pub input: InputCounters,
    /// Time synchronisation counters.
    pub timesync: TimeSyncCounters,
    /// Samples refused as older than the previous one of their kind (reordering).
    pub time_order_rejected: u64,
    /// Samples refused as repeats of the previous one of their kind (same time).
    pub time_repeated: u64,
    /// Sensor events handed to the navigation thread.
    pub events_to_nav: u64,
    /// Events written to the `--record` log.
    pub events_recorded: u64,
    /// Recording stopped by a write error.
    pub record_failed: bool,
    /// Navigator counters.
    pub nav: NavigatorStats,
    /// INS counters.
    pub ins: Option<InsStats>,
    /// Solutions produced.
    pub solutions: u64,
    /// Messages published (ODOMETRY / GPS_INPUT / VISION_POSITION_ESTIMATE).
    pub published: u64,
    /// GNSS fixes that were our own GPS_INPUT reported back (refused).
    pub gnss_echo: u64,
    /// Solutions not published because a self-check failed (`daemon::health`).
    pub publish_withheld: u64,
    /// Times publication was stopped by a self-check.
    pub publish_withheld_episodes: u64,
    /// Monitor ticks (10 Hz) after the initialisation without a fresh solution (IMU
    /// stopped): nothing is published then.
    pub publish_stale: u64,
    /// SET_GPS_GLOBAL_ORIGIN sent.
    pub origins_sent: u64,
    /// Camera frames received.
    pub frames_received: u64,
    /// Frames dropped (oldest first) because the navigation thread was late.
    pub frames_dropped: u64,
    /// Times the deferred visual navigation's thread failed (a panic): the daemon then
    /// navigates on the INS alone.
    pub vision_failures: u64,
    /// Frames refused: time not mappable or out of order, or a size or pixel format that
    /// disagrees with the configured intrinsics.
    pub frames_refused: u64,
    /// Camera connection / read errors.
    pub camera_errors: u64,
    /// Camera (re)connections.
    pub camera_connects: u64,
    /// STATUSTEXTs sent.
    pub statustexts: u64,
    /// Workers restarted after a panic (the camera task:
    /// [`MAX_CAMERA_RESTARTS`](super::MAX_CAMERA_RESTARTS)).
    pub worker_restarts: u64,
    /// Published solutions whose latency was measured.
    pub latency_samples: u64,
    /// Largest latency from the reception of an IMU message to the socket write of the
    /// solution computed from it, µs.
    pub latency_max_us: u64,
    /// Visual results applied whose latency from the frame's reception was measured.
    pub frame_latency_samples: u64,
    /// Largest latency from a frame's reception to its visual result applied, µs.
    pub frame_latency_max_us: u64,
}

/// Latencies kept for percentiles (a ring of the most recent ones).
pub const LATENCY_RING: usize = 8_192;

/// Link and estimator state shared by the tasks.
#[derive(Debug, Clone, Default)]
pub struct State {
    /// Autopilot system and component id and kind, once its HEARTBEAT is seen.
    pub autopilot: Option<(u8, u8, AutopilotKind)>,
    /// Time of the last message from the autopilot, µs.
    pub last_rx_us: Option<u64>,
    /// The last silence of the autopilot longer than the link timeout, µs.
    pub last_outage_us: Option<u64>,
    /// Time of the last valid GNSS fix, µs.
    pub last_fix_us: Option<u64>,
    /// Time of validity of the last valid fix, sensor time (the navigation's `t_us`), µs.
    pub last_fix_sensor_us: Option<u64>,
    /// Time of the last camera frame, µs.
    pub last_frame_us: Option<u64>,
    /// Offset from the vehicle clock to `t_us`, µs (camera frame stamps).
    pub offset_us: Option<i64>,
    /// Origin of the local frame (first fix), and the geoid undulation there.
    pub origin: Option<Geodetic>,
    /// Geoid undulation (ellipsoid − MSL), m.
    pub undulation_m: f64,
    /// Incremented when the intervals must be requested again (reboot, link restored).
    pub request_generation: u64,
    /// Results of SET_MESSAGE_INTERVAL COMMAND_ACKs not yet taken by the negotiation.
    pub interval_acks: Vec<apm::MavResult>,
    /// Rates the autopilot accepted in the current negotiation (message id, Hz).
    pub granted_intervals: Vec<(u32, f64)>,
    /// Position (lat, lon, degE7) and horizontal accuracy (mm) of the last [`ECHO_MEMORY`]
    /// GPS_INPUTs sent: a GNSS fix carrying one of them is our own output reported back,
    /// never a measurement.
    pub sent_positions: std::collections::VecDeque<(i32, i32, u32)>,
}

/// GPS_INPUTs remembered for echo detection (10 s at 5 Hz, 2.5 s at 20 Hz).
pub const ECHO_MEMORY: usize = 50;

impl State {
    /// Remember a GPS_INPUT position and its horizontal accuracy.
    pub fn remember_sent(&mut self, lat_e7: i32, lon_e7: i32, h_acc_mm: u32) {
        if self.sent_positions.len() >= ECHO_MEMORY {
            self.sent_positions.pop_front();
        }
        self.sent_positions.push_back((lat_e7, lon_e7, h_acc_mm));
    }

    /// Whether a fix at (lat, lon) degE7 with horizontal accuracy `h_acc_mm` is one of our own
    /// GPS_INPUTs (an autopilot that made our GPS_INPUT instance its primary receiver reports
    /// it in GPS_RAW_INT, accuracy included). Position alone is not enough: at rest the INS
    /// converges onto the receiver's fix to the centimetre (seen beside ArduPlane SITL on the
    /// ground), but a receiver's accuracy does not equal our DRMS to the millimetre.
    pub fn is_echo(&self, lat_e7: i64, lon_e7: i64, h_acc_mm: i64) -> bool {
        self.sent_positions.iter().any(|(a, o, h)| {
            i64::from(*a) == lat_e7 && i64::from(*o) == lon_e7 && i64::from(*h) == h_acc_mm
        })
    }
}

/// State shared between tasks.
#[derive(Debug, Default)]
pub struct Shared {
    counters: Mutex<Counters>,
    state: Mutex<State>,
    latencies_us: Mutex<Vec<u32>>,
    frame_latencies_us: Mutex<Vec<u32>>,
    frame_due_latencies_us: Mutex<Vec<u32>>,
}

/// Keep `us` in a ring of the [`LATENCY_RING`] most recent latencies (`n`: samples so far).
fn keep_latency(ring: &Mutex<Vec<u32>>, n: u64, us: u64) {
    let mut ring = lock(ring);
    let v = u32::try_from(us).unwrap_or(u32::MAX);
    if ring.len() < LATENCY_RING {
        ring.push(v);
    } else {
        let i = usize::try_from(n % LATENCY_RING as u64).unwrap_or(0);
        ring[i] = v;
    }
}

/// (p50, p99, max) of a ring of latencies.
fn percentiles(ring: &Mutex<Vec<u32>>) -> Option<(u32, u32, u32)> {
    let mut v = lock(ring).clone();
    if v.is_empty() {
        return None;
    }
    v.sort_unstable();
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    Some((at(0.5), at(0.99), at(1.0)))
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panicking holder cannot leave these plain-data structs half-updated in a harmful way.
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Shared {
    /// Update the counters.
    pub fn count<R>(&self, f: impl FnOnce(&mut Counters) -> R) -> R {
        f(&mut lock(&self.counters))
    }

    /// A copy of the counters.
    pub fn counters(&self) -> Counters {
        lock(&self.counters).clone()
    }

    /// Record one IMU → socket latency.
    pub fn record_latency(&self, us: u64) {
        let n = self.count(|c| {
            c.latency_max_us = c.latency_max_us.max(us);
            c.latency_samples += 1;
            c.latency_samples
        });
        keep_latency(&self.latencies_us, n, us);
    }

    /// (p50, p99, max) of the recent latencies, µs (`None` without samples).
    pub fn latency_percentiles(&self) -> Option<(u32, u32, u32)> {
        percentiles(&self.latencies_us)
    }

    /// Record one frame's latencies to its visual result applied: from its reception
    /// (`received_us`) and from when it was due (`due_us`: the INS had reached its exposure
    /// time, so that the rest is the daemon's own work; a frame that arrives before the IMU
    /// samples of its instant waits for them first).
    pub fn record_frame_latency(&self, received_us: u64, due_us: u64) {
        let n = self.count(|c| {
            c.frame_latency_max_us = c.frame_latency_max_us.max(received_us);
            c.frame_latency_samples += 1;
            c.frame_latency_samples
        });
        keep_latency(&self.frame_latencies_us, n, received_us);
        keep_latency(&self.frame_due_latencies_us, n, due_us);
    }

    /// (p50, p99, max) of the recent frame received → visual result latencies, µs.
    pub fn frame_latency_percentiles(&self) -> Option<(u32, u32, u32)> {
        percentiles(&self.frame_latencies_us)
    }

    /// (p50, p99, max) of the recent frame due → visual result latencies, µs.
    pub fn frame_due_latency_percentiles(&self) -> Option<(u32, u32, u32)> {
        percentiles(&self.frame_due_latencies_us)
    }

    /// Read or update the state.
    pub fn state<R>(&self, f: impl FnOnce(&mut State) -> R) -> R {
        f(&mut lock(&self.state))
    }
}

/// The latest solution and the reception time of the IMU message that produced it.
#[derive(Debug, Clone, Copy)]
pub struct Latest {
    /// The solution.
    pub sol: NavSolution,
    /// When its IMU message was received.
    pub imu_rx: Instant,
}

/// Outgoing messages (bounded; full = dropped and counted).
#[derive(Debug, Clone)]
pub struct Outbox {
    pub(super) tx: mpsc::Sender<Outgoing>,
    pub(super) shared: Arc<Shared>,
}

/// A queued message and, for a published solution, when its IMU message was received.
pub type Outgoing = (apm::MavMessage, Option<Instant>);

impl Outbox {
    /// Queue a message.
    pub fn send(&self, msg: apm::MavMessage) {
        self.send_timed(msg, None);
    }

    /// Queue a message whose latency from `imu_rx` is measured when it has been written.
    pub fn send_timed(&self, msg: apm::MavMessage, imu_rx: Option<Instant>) {
        if self.tx.try_send((msg, imu_rx)).is_err() {
            self.shared.count(|c| c.tx_queue_full += 1);
        }
    }

    /// Log and send a STATUSTEXT.
    pub fn status(&self, severity: apm::MavSeverity, text: &str) {
        match severity {
            apm::MavSeverity::MAV_SEVERITY_EMERGENCY
            | apm::MavSeverity::MAV_SEVERITY_ALERT
            | apm::MavSeverity::MAV_SEVERITY_CRITICAL
            | apm::MavSeverity::MAV_SEVERITY_ERROR
            | apm::MavSeverity::MAV_SEVERITY_WARNING => tracing::warn!("{text}"),
            _ => tracing::info!("{text}"),
        }
        self.shared.count(|c| c.statustexts += 1);
        self.send(apm::MavMessage::STATUSTEXT(mavlink_out::statustext(
            severity, text,
        )));
    }
}

/// A running daemon: its shared state and a way to stop it.
#[derive(Debug)]
pub struct Handle {
    /// Counters and state.
    pub shared: Arc<Shared>,
    pub(super) stop: watch::Sender<bool>,
}

impl Handle {
    /// Ask every task to stop.
    pub fn stop(&self) {
        let _ = self.stop.send(true);
    }
}

/// What every task of the daemon is given: its settings, the clock, the outbox, the counters
/// and state, and the stop signal (one value for the argument list each spawn repeated).
#[derive(Debug, Clone)]
pub(super) struct Context {
    /// The configuration.
    pub(super) cfg: Arc<DaemonConfig>,
    /// The daemon's clock.
    pub(super) clock: Clock,
    /// Outgoing messages.
    pub(super) outbox: Outbox,
    /// Counters and state.
    pub(super) shared: Arc<Shared>,
    /// Set once to stop.
    pub(super) stop: watch::Receiver<bool>,
}

impl Context {
    /// The context of a daemon running `cfg` on `clock`, its messages queued on `out`.
    pub(super) fn new(
        cfg: DaemonConfig,
        clock: Clock,
        out: mpsc::Sender<Outgoing>,
        stop: watch::Receiver<bool>,
    ) -> Self {
        let shared = Arc::new(Shared::default());
        Self {
            cfg: Arc::new(cfg),
            clock,
            outbox: Outbox {
                tx: out,
                shared: shared.clone(),
            },
            shared,
            stop,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_echo_needs_our_position_and_our_accuracy() {
        let mut st = State::default();
        for k in 0..(ECHO_MEMORY as i32 + 5) {
            st.remember_sent(450_000_000 + k, 10_000_000, 2_500);
        }
        // Our output reported back, accuracy included.
        assert!(st.is_echo(450_000_010, 10_000_000, 2_500));
        // At rest the receiver's fix equals our position to the centimetre, not our accuracy.
        assert!(!st.is_echo(450_000_010, 10_000_000, 1_000));
        // Forgotten after ECHO_MEMORY newer ones.
        assert!(!st.is_echo(450_000_000, 10_000_000, 2_500));
    }
}
