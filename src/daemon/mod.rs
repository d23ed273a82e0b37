//! The onboard daemon (docs/DAEMON.md; docs/REFERENCES.md M1, M3, M6):
//! tokio tasks around a navigation OS thread.
//!
//! ```text
//!  link (reader) ─ HEARTBEAT: autopilot kind, ids ─► interval requests (again after reboot)
//!     │           TIMESYNC: answer / offset            │
//!     │ SensorEvents (t_us, our clock), bounded 2048,  ▼
//!     │ backpressure: never dropped               outbox (bounded 256) ─► writer ─► link
//!     ▼                                                ▲
//!  navigation thread (Navigator) ─ latest solution ─► publisher (rate_hz) ─┘
//!     ▲ frames: queue of camera.queue_frames, oldest dropped     heartbeat 1 Hz, monitor
//!  camera task (frame stream / directory)                        (STATUSTEXT, counters, sd_notify)
//! ```
//!
//! One clock: [`Clock`], monotonic µs since the daemon started; every `t_us` the navigation
//! core sees and every `time_usec` sent is on it.

pub mod camera;
#[cfg(feature = "opencv")]
pub mod camera_cv;
pub mod config;
pub mod health;
pub mod intervals;
pub mod link;
pub mod nav_thread;
pub mod preflight;
pub mod publish;
pub mod transport;

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant, SystemTime};

use tokio::sync::{mpsc, watch};

use crate::daemon::config::{AutopilotKind, DaemonConfig, OutputMode};
use crate::ins::InsStats;
use crate::io::mavlink_in::InputCounters;
use crate::io::mavlink_out::{self, Health};
use crate::io::timesync::TimeSyncCounters;
use crate::math::wgs84::Geodetic;
use crate::nav::{NavSolution, NavigatorStats};
use mavlink::dialects::ardupilotmega as apm;

/// Capacity of the sensor-event channel to the navigation thread: ≥ 2 s of a 200 Hz IMU plus
/// air, magnetometer and GNSS at their rates, so a 2 s stall of the thread loses nothing
/// (the reader waits instead).
pub const EVENT_CHANNEL: usize = 2_048;
/// Capacity of the outgoing-message queue; beyond it messages are dropped and counted.
pub const OUTBOX: usize = 256;
/// A solution whose IMU message was received longer ago than this is stale (the IMU has
/// stopped): the heartbeat leaves ACTIVE and the watchdog is not fed, µs.
pub const MAX_SOLUTION_AGE_US: u64 = 500_000;

/// Why the daemon stopped.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The navigation core could not be built.
    #[error("navigation: {0}")]
    Nav(#[from] crate::nav::NavError),
    /// The navigation thread could not be started or did not stop.
    #[error("navigation thread: {0}")]
    Thread(String),
    /// The sensor log to record into could not be created.
    #[error("record: {0}")]
    Record(String),
    /// A worker panicked: the daemon stops rather than run on without it.
    #[error("{worker} panicked: {message}")]
    WorkerPanicked {
        /// The worker.
        worker: &'static str,
        /// The panic message.
        message: String,
    },
    /// A worker ended while the daemon was running.
    #[error("{worker} stopped unexpectedly")]
    WorkerStopped {
        /// The worker.
        worker: &'static str,
    },
}

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
    /// Frames refused: time not mappable or out of order.
    pub frames_refused: u64,
    /// Camera connection / read errors.
    pub camera_errors: u64,
    /// Camera (re)connections.
    pub camera_connects: u64,
    /// STATUSTEXTs sent.
    pub statustexts: u64,
    /// Workers restarted after a panic (the camera task: [`MAX_CAMERA_RESTARTS`]).
    pub worker_restarts: u64,
    /// Published solutions whose latency was measured.
    pub latency_samples: u64,
    /// Largest latency from the reception of an IMU message to the socket write of the
    /// solution computed from it, µs.
    pub latency_max_us: u64,
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
        let n = {
            let mut c = lock(&self.counters);
            c.latency_max_us = c.latency_max_us.max(us);
            c.latency_samples += 1;
            c.latency_samples
        };
        let mut ring = lock(&self.latencies_us);
        let v = u32::try_from(us).unwrap_or(u32::MAX);
        if ring.len() < LATENCY_RING {
            ring.push(v);
        } else {
            let i = usize::try_from(n % LATENCY_RING as u64).unwrap_or(0);
            ring[i] = v;
        }
    }

    /// (p50, p99, max) of the recent latencies, µs (`None` without samples).
    pub fn latency_percentiles(&self) -> Option<(u32, u32, u32)> {
        let mut v = lock(&self.latencies_us).clone();
        if v.is_empty() {
            return None;
        }
        v.sort_unstable();
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Some((at(0.5), at(0.99), at(1.0)))
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
    tx: mpsc::Sender<Outgoing>,
    shared: Arc<Shared>,
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
    stop: watch::Sender<bool>,
}

impl Handle {
    /// Ask every task to stop.
    pub fn stop(&self) {
        let _ = self.stop.send(true);
    }
}

/// The camera task is restarted after a panic at most this many times, then the daemon stops:
/// the camera is an optional input with its own reconnection, so a failure there should not
/// cost the navigation state (a restarted daemon needs a GNSS fix to start its INS again), but
/// a camera that keeps failing is a fault, not a transient.
pub const MAX_CAMERA_RESTARTS: u64 = 3;

/// Time left to the writer to send the STATUSTEXT announcing a fatal error.
const LAST_WORDS: Duration = Duration::from_millis(300);

/// A supervised worker: its name in messages, and whether it may end on its own (the camera
/// with no source or at the end of its directory, TIMESYNC requests at rate 0).
#[derive(Debug, Clone, Copy)]
struct Worker {
    name: &'static str,
    may_end: bool,
}

const READER: Worker = Worker {
    name: "link reader",
    may_end: false,
};
const WRITER: Worker = Worker {
    name: "link writer",
    may_end: false,
};
const TIMESYNC: Worker = Worker {
    name: "TIMESYNC requests",
    may_end: true,
};
const INTERVALS: Worker = Worker {
    name: "interval requests",
    may_end: false,
};
const MONITOR: Worker = Worker {
    name: "monitor",
    may_end: false,
};
const CAMERA: Worker = Worker {
    name: "camera",
    may_end: true,
};
const NAV: &str = "navigation thread";

/// Test hook (docs/DAEMON.md "Worker failures"): `IANAV_FAULT=WORKER[:stop]` makes a worker
/// (`reader`, `writer`, `timesync`, `intervals`, `monitor`, `camera`, `nav`) panic, or with
/// `:stop` end, [`Fault::AFTER`] after the start. Only builds with debug assertions read it
/// (the `ci` test profile): a release build ignores the variable.
#[derive(Debug, Clone, Default)]
pub(crate) struct Fault {
    worker: Option<String>,
    stop: bool,
}

/// What an injected fault does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FaultKind {
    /// Panic.
    Panic,
    /// Return as if done.
    Stop,
}

impl Fault {
    /// Delay before an injected fault strikes (the daemon is running by then).
    pub(crate) const AFTER: Duration = Duration::from_secs(1);

    fn from_env() -> Self {
        if !cfg!(debug_assertions) {
            return Self::default();
        }
        let Ok(v) = std::env::var("IANAV_FAULT") else {
            return Self::default();
        };
        let (worker, stop) = match v.split_once(':') {
            Some((w, "stop")) => (w.to_owned(), true),
            _ => (v, false),
        };
        tracing::warn!(worker, stop, "IANAV_FAULT: test fault armed");
        Self {
            worker: Some(worker),
            stop,
        }
    }

    /// The fault armed for `worker`, if any.
    pub(crate) fn on(&self, worker: &str) -> Option<FaultKind> {
        (self.worker.as_deref() == Some(worker)).then_some(if self.stop {
            FaultKind::Stop
        } else {
            FaultKind::Panic
        })
    }

    /// Run `fut` as worker `id`, with its fault if one is armed.
    fn wrap(
        &self,
        id: &str,
        fut: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> impl std::future::Future<Output = ()> + Send + 'static {
        let fault = self.on(id);
        let id = id.to_owned();
        async move {
            let Some(kind) = fault else {
                return fut.await;
            };
            tokio::select! {
                () = fut => {}
                () = tokio::time::sleep(Fault::AFTER) => {
                    if kind == FaultKind::Panic {
                        panic!("IANAV_FAULT: injected panic in {id}");
                    }
                }
            }
        }
    }
}

/// The message of a panic payload.
fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".to_owned())
}

/// The worker tasks and their names.
struct Supervisor {
    tasks: tokio::task::JoinSet<()>,
    workers: std::collections::HashMap<tokio::task::Id, Worker>,
    fault: Fault,
}

/// A worker's future.
type WorkerFuture = std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>>;

impl Supervisor {
    fn spawn(&mut self, id: &str, w: Worker, fut: WorkerFuture) {
        let h = self.tasks.spawn(self.fault.wrap(id, fut));
        self.workers.insert(h.id(), w);
    }
}

/// How supervision ended.
enum Ending {
    /// `Handle::stop` (SIGINT / SIGTERM).
    Stopped,
    /// The navigation thread ended (its panic, if any, is taken from its join).
    NavEnded,
    /// A worker failed.
    Failed(DaemonError),
}

/// The navigation core's settings for this daemon: its INS, started by the core's rules with
/// the magnetic model of `mag_decimal_year`, and started again at the first fix at
/// `input.start_airspeed_mps` when first started below it (on the ground).
pub fn nav_config(cfg: &DaemonConfig, mag_decimal_year: f64) -> crate::nav::NavConfig {
    let mut nav = crate::nav::NavConfig::new(cfg.ins.clone(), mag_decimal_year);
    nav.start.restart_airspeed_mps = Some(cfg.input.start_airspeed_mps);
    nav
}

/// Run the daemon until `handle.stop()` or a fatal error. The caller provides the runtime.
///
/// Every worker is supervised: one that panics, or ends while it should run, stops the daemon
/// with [`DaemonError::WorkerPanicked`] / [`DaemonError::WorkerStopped`] after a STATUSTEXT
/// saying so (so `ianav run` exits non-zero and systemd restarts it), except the camera task,
/// restarted up to [`MAX_CAMERA_RESTARTS`] times. Never alive with a dead worker.
pub async fn run(
    cfg: DaemonConfig,
    handle_tx: Option<tokio::sync::oneshot::Sender<Handle>>,
) -> Result<(), DaemonError> {
    let fault = Fault::from_env();
    let shared = Arc::new(Shared::default());
    let (stop_tx, stop_rx) = watch::channel(false);
    let clock = Clock::new();
    let year = if cfg.navigation.mag_decimal_year != 0.0 {
        cfg.navigation.mag_decimal_year
    } else {
        clock.decimal_year()
    };
    let nav_cfg = nav_config(&cfg, year);
    let nav = crate::nav::Navigator::new(&nav_cfg)?;
    let att = &nav_cfg.ins.attitude;
    let lag_s = att.body_rate_lag_s(nav_cfg.ins.reference_period_s);
    if lag_s > crate::ins::MAX_BODY_RATE_LAG_S {
        tracing::warn!(
            lag_ms = lag_s * 1e3,
            "the INS body rate lags the gyro by {:.0} ms in turns ([ins.attitude] \
             q_w_nb_rad2ps2 small for r_gyro_rad2ps2): set q_w_nb_rad2ps2 ≥ {:.2e} \
             (docs/INS.md \"Body-rate lag\")",
            lag_s * 1e3,
            crate::ins::AttitudeFilterConfig::matching_q_w_nb_rad2ps2(att.r_gyro_rad2ps2)
        );
    }
    let recorder = match &cfg.record {
        Some(path) => Some(
            nav_thread::Recorder::create(path, &nav_cfg)
                .map_err(|e| DaemonError::Record(format!("{}: {e}", path.display())))?,
        ),
        None => None,
    };
    let (event_tx, event_rx) = mpsc::channel(EVENT_CHANNEL);
    let frames = Arc::new(nav_thread::FrameQueue::new(cfg.camera.queue_frames));
    let (latest_tx, latest_rx) = watch::channel(None::<Latest>);
    let (out_tx, out_rx) = mpsc::channel(OUTBOX);
    let outbox = Outbox {
        tx: out_tx,
        shared: shared.clone(),
    };
    let cfg = Arc::new(cfg);
    let publisher = publish::Publisher::new(cfg.clone(), clock, outbox.clone(), shared.clone());
    let (nav_exit_tx, nav_exit_rx) = tokio::sync::oneshot::channel();
    let nav_join = nav_thread::spawn(
        nav,
        recorder,
        event_rx,
        frames.clone(),
        latest_tx,
        publisher,
        shared.clone(),
        nav_thread::Exit::new(nav_exit_tx, fault.on("nav")),
    )
    .map_err(|e| DaemonError::Thread(e.to_string()))?;
    if let Some(h) = handle_tx {
        let _ = h.send(Handle {
            shared: shared.clone(),
            stop: stop_tx.clone(),
        });
    }
    let mut sup = Supervisor {
        tasks: tokio::task::JoinSet::new(),
        workers: std::collections::HashMap::new(),
        fault: fault.clone(),
    };
    let (conn_tx, conn_rx) = watch::channel(None);
    // The reader and the camera own the only senders: when both have stopped, the navigation
    // thread sees the channel close and ends.
    let cam_wake = event_tx.clone();
    sup.spawn(
        "writer",
        WRITER,
        Box::pin(link::writer(
            cfg.clone(),
            out_rx,
            conn_rx,
            shared.clone(),
            stop_rx.clone(),
        )),
    );
    sup.spawn(
        "reader",
        READER,
        Box::pin(link::reader(
            cfg.clone(),
            clock,
            conn_tx,
            event_tx,
            outbox.clone(),
            shared.clone(),
            stop_rx.clone(),
        )),
    );
    sup.spawn(
        "timesync",
        TIMESYNC,
        Box::pin(link::timesync_requests(
            cfg.clone(),
            clock,
            outbox.clone(),
            shared.clone(),
            stop_rx.clone(),
        )),
    );
    sup.spawn(
        "intervals",
        INTERVALS,
        Box::pin(link::interval_requests(
            cfg.clone(),
            outbox.clone(),
            shared.clone(),
            stop_rx.clone(),
        )),
    );
    sup.spawn(
        "monitor",
        MONITOR,
        Box::pin(monitor(
            cfg.clone(),
            clock,
            latest_rx,
            outbox.clone(),
            shared.clone(),
            stop_rx.clone(),
        )),
    );
    let camera = {
        let (cfg, shared, stop) = (cfg.clone(), shared.clone(), stop_rx.clone());
        move || -> WorkerFuture {
            Box::pin(camera::run(
                cfg.clone(),
                clock,
                frames.clone(),
                cam_wake.clone(),
                shared.clone(),
                stop.clone(),
            ))
        }
    };
    sup.spawn("camera", CAMERA, camera());
    // Supervise until the stop signal or a failure.
    let mut stop = stop_rx.clone();
    let mut nav_exit = nav_exit_rx;
    let ending = loop {
        tokio::select! {
            _ = stop.wait_for(|s| *s) => break Ending::Stopped,
            _ = &mut nav_exit => break Ending::NavEnded,
            Some(joined) = sup.tasks.join_next_with_id() => {
                let (id, panic) = match joined {
                    Ok((id, ())) => (id, None),
                    Err(e) => {
                        let id = e.id();
                        let msg = match e.try_into_panic() {
                            Ok(p) => panic_message(p.as_ref()),
                            Err(e) => e.to_string(),
                        };
                        (id, Some(msg))
                    }
                };
                let Some(w) = sup.workers.remove(&id) else { continue };
                match panic {
                    // Workers end by themselves on the stop signal.
                    None if w.may_end || *stop_rx.borrow() => {}
                    None => break Ending::Failed(DaemonError::WorkerStopped { worker: w.name }),
                    Some(msg) if w.name == CAMERA.name
                        && shared.counters().worker_restarts < MAX_CAMERA_RESTARTS =>
                    {
                        let n = shared.count(|c| {
                            c.worker_restarts += 1;
                            c.worker_restarts
                        });
                        tracing::error!("camera task panicked ({msg}): restarting");
                        outbox.status(
                            apm::MavSeverity::MAV_SEVERITY_WARNING,
                            &format!("ianav: camera failed, restart {n}/{MAX_CAMERA_RESTARTS}"),
                        );
                        sup.spawn("camera", CAMERA, camera());
                    }
                    Some(message) => {
                        break Ending::Failed(DaemonError::WorkerPanicked {
                            worker: w.name,
                            message,
                        });
                    }
                }
            }
        }
    };
    // The reader stops when the navigation thread is gone, maybe seen first: name the thread
    // then (its end is signalled before its event receiver is dropped).
    let nav_ended = matches!(ending, Ending::NavEnded) || nav_exit.try_recv().is_ok();
    let failed = match &ending {
        Ending::Stopped => None,
        Ending::NavEnded => Some(NAV),
        _ if nav_ended => Some(NAV),
        Ending::Failed(
            DaemonError::WorkerPanicked { worker, .. } | DaemonError::WorkerStopped { worker },
        ) => Some(*worker),
        Ending::Failed(_) => Some("worker"),
    };
    if let Some(what) = failed {
        // Not logged here: `ianav run` prints the error once when the daemon returns it.
        shared.count(|c| c.statustexts += 1);
        outbox.send(apm::MavMessage::STATUSTEXT(mavlink_out::statustext(
            apm::MavSeverity::MAV_SEVERITY_CRITICAL,
            &format!("ianav: {what} failed, exiting"),
        )));
        tokio::time::sleep(LAST_WORDS).await;
    }
    let _ = stop_tx.send(true);
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        while sup.tasks.join_next().await.is_some() {}
    })
    .await;
    sup.tasks.abort_all();
    // Drop every event sender (the camera's is in its restart closure): the navigation thread
    // sees the channel close and ends.
    drop((outbox, camera, sup));
    if !nav_ended
        && tokio::time::timeout(Duration::from_secs(5), &mut nav_exit)
            .await
            .is_err()
    {
        return Err(DaemonError::Thread("did not stop within 5 s".to_owned()));
    }
    let nav_result = tokio::task::spawn_blocking(move || nav_join.join())
        .await
        .map_err(|e| DaemonError::Thread(e.to_string()))?;
    // The navigation thread's end first: the reader then stops too, for that reason.
    match (nav_result, ending) {
        (Err(p), _) => Err(DaemonError::WorkerPanicked {
            worker: NAV,
            message: panic_message(p.as_ref()),
        }),
        (Ok(()), Ending::NavEnded) => Err(DaemonError::WorkerStopped { worker: NAV }),
        (Ok(()), _) if nav_ended => Err(DaemonError::WorkerStopped { worker: NAV }),
        (Ok(()), Ending::Failed(e)) => Err(e),
        (Ok(()), Ending::Stopped) => Ok(()),
    }
}

/// The output mode in force (auto resolved from the autopilot kind; `None` while unknown).
pub fn resolved_mode(cfg: &DaemonConfig, kind: Option<AutopilotKind>) -> Option<OutputMode> {
    match cfg.output.mode {
        OutputMode::Auto => match kind {
            Some(AutopilotKind::Px4) => Some(OutputMode::Odometry),
            Some(AutopilotKind::Ardupilot) => Some(OutputMode::GpsInput),
            _ => None,
        },
        m => Some(m),
    }
}

/// Sleep helper that returns `true` when stopped.
async fn stopped_after(stop: &mut watch::Receiver<bool>, d: Duration) -> bool {
    // Ok(Err(_)): every sender is gone, which also means stop.
    tokio::time::timeout(d, stop.wait_for(|s| *s)).await.is_ok()
}

/// Health flags watched by the monitor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Flags {
    link_up: bool,
    initialised: bool,
    /// `None` until the first fix (the first fix is not a "regained").
    gnss_ok: Option<bool>,
    camera_ok: bool,
    reset_counter: u8,
}

/// HEARTBEAT at 1 Hz, STATUSTEXT on state changes, counters in the log, sd_notify.
async fn monitor(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    latest: watch::Receiver<Option<Latest>>,
    outbox: Outbox,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    use apm::MavSeverity as S;
    // systemd (sd_notify(3); no-ops without $NOTIFY_SOCKET): STATUS while waiting; READY=1
    // when the estimator first runs, so the start timeout, not the watchdog, covers the wait
    // for the first fix; then WATCHDOG=1 each second only while solutions come from IMU
    // messages received less than MAX_SOLUTION_AGE_US ago (`running` below: the INS yields a
    // solution only on an IMU sample), i.e. only while the navigation processes IMU samples.
    use sd_notify::NotifyState as N;
    let notify = |states: &[N]| {
        if let Err(e) = sd_notify::notify(states) {
            tracing::warn!("sd_notify: {e}");
        }
    };
    notify(&[N::Status("waiting for the autopilot and a GNSS fix")]);
    let mut ready_sent = false;
    let mut flags = Flags::default();
    let mut link_lost_at: Option<u64> = None;
    let mut last_heartbeat_us: Option<u64> = None;
    let mut last_log_us = 0_u64;
    let camera_used = cfg.camera.source != crate::daemon::config::CameraSourceKind::None;
    loop {
        if stopped_after(&mut stop, Duration::from_millis(100)).await {
            return;
        }
        let now = clock.now_us();
        let st = shared.state(|s| s.clone());
        let l = *latest.borrow();
        // Link.
        let link_up = st
            .last_rx_us
            .is_some_and(|t| now.saturating_sub(t) < (cfg.mavlink.link_timeout_s * 1e6) as u64);
        if flags.link_up && !link_up {
            shared.count(|c| c.link_losses += 1);
            link_lost_at = Some(now);
            tracing::warn!("link to the autopilot lost");
        } else if !flags.link_up
            && link_up
            && let Some(t) = link_lost_at.take()
        {
            // From the last message before the silence to the first after it (measured by the
            // reader): the loss was only noticed a link timeout after it began.
            let s = st.last_outage_us.unwrap_or(now.saturating_sub(t)) as f64 / 1e6;
            outbox.status(
                S::MAV_SEVERITY_NOTICE,
                &format!("ianav: link restored ({s:.1} s)"),
            );
            // The autopilot may have restarted meanwhile: ask for the streams again.
            shared.state(|s| s.request_generation += 1);
        }
        flags.link_up = link_up;
        // Estimator.
        if let Some(l) = l {
            if !flags.initialised {
                flags.initialised = true;
                flags.reset_counter = l.sol.reset_counter;
                outbox.status(S::MAV_SEVERITY_INFO, "ianav: INS initialised");
            } else if l.sol.reset_counter != flags.reset_counter {
                flags.reset_counter = l.sol.reset_counter;
                outbox.status(S::MAV_SEVERITY_WARNING, "ianav: estimator reset");
            }
        }
        let timeout_us = (cfg.input.gnss_loss_timeout_s * 1e6) as u64;
        // In sensor time while solutions flow (with the autopilot clock a vehicle at 10× real
        // time would otherwise be announced 20 s of its time late), else in reception time.
        let gnss_ok = match (l, st.last_fix_sensor_us) {
            (Some(l), Some(fix_us)) => l.sol.ins.t_us.saturating_sub(fix_us) < timeout_us,
            _ => st
                .last_fix_us
                .is_some_and(|t| now.saturating_sub(t) < timeout_us),
        };
        if st.last_fix_us.is_some() && flags.gnss_ok.is_some_and(|was| was != gnss_ok) {
            if gnss_ok {
                outbox.status(S::MAV_SEVERITY_NOTICE, "ianav: GNSS regained");
            } else {
                outbox.status(
                    S::MAV_SEVERITY_WARNING,
                    "ianav: GNSS lost, INS dead reckoning",
                );
            }
        }
        if st.last_fix_us.is_some() {
            flags.gnss_ok = Some(gnss_ok);
        }
        if camera_used {
            let cam_ok = st
                .last_frame_us
                .is_some_and(|t| now.saturating_sub(t) < (cfg.camera.timeout_s * 1e6) as u64);
            if cam_ok != flags.camera_ok && (cam_ok || st.last_frame_us.is_some()) {
                if cam_ok {
                    outbox.status(S::MAV_SEVERITY_INFO, "ianav: camera frames received");
                } else {
                    outbox.status(S::MAV_SEVERITY_WARNING, "ianav: camera lost");
                }
            }
            flags.camera_ok = cam_ok;
        }
        // Fresh = computed from an IMU message received less than 0.5 s ago (real time, so
        // it also holds with the autopilot clock).
        let running =
            l.is_some_and(|l| l.imu_rx.elapsed() < Duration::from_micros(MAX_SOLUTION_AGE_US));
        if l.is_some() && !running {
            // Nothing is published from a stale solution (the publisher runs on new ones).
            shared.count(|c| c.publish_stale += 1);
        }
        // HEARTBEAT at 1 Hz (sent regardless of the link: UDP/routers learn us from it).
        if last_heartbeat_us.is_none_or(|t| now.saturating_sub(t) >= 1_000_000) {
            last_heartbeat_us = Some(now);
            let health = match (
                running,
                l.is_some_and(|l| l.sol.ins.gnss_denied) || !gnss_ok,
            ) {
                (false, _) => Health::Standby,
                (true, false) => Health::Active,
                (true, true) => Health::Critical,
            };
            outbox.send(apm::MavMessage::HEARTBEAT(mavlink_out::heartbeat(health)));
            // The watchdog is fed only while the estimator runs on fresh IMU samples.
            if running {
                if ready_sent {
                    notify(&[N::Watchdog]);
                } else {
                    ready_sent = true;
                    notify(&[N::Ready, N::Status("estimator running"), N::Watchdog]);
                }
            }
        }
        let period_us = (cfg.logging.counters_period_s * 1e6) as u64;
        if period_us > 0 && now.saturating_sub(last_log_us) >= period_us {
            last_log_us = now;
            log_counters(&shared.counters());
        }
    }
}

impl Counters {
    /// Every input refused, by kind, as `kind=n` for the non-zero ones ("none" otherwise).
    pub fn rejections(&self) -> String {
        let (i, t) = (&self.input, &self.timesync);
        let kinds = [
            ("parse", self.rx_parse_errors),
            ("non_finite", i.non_finite),
            ("out_of_range", i.out_of_range),
            ("no_fix", i.no_fix),
            ("unscaled_raw_imu", i.unscaled_raw_imu),
            ("time_unmapped", i.time),
            ("no_airspeed", i.no_airspeed),
            ("airspeed_unhealthy", i.airspeed_unhealthy),
            ("time_implausible", t.implausible),
            ("clock_outlier", t.clock_outliers),
            ("clock_held", t.clock_held),
            ("time_order", self.time_order_rejected),
            ("time_repeated", self.time_repeated),
            ("timesync_rtt", t.rtt_rejected),
            ("timesync_outlier", t.outliers),
            ("gnss_echo", self.gnss_echo),
            ("foreign", self.rx_foreign),
            ("before_heartbeat", self.rx_before_heartbeat),
        ];
        let v: Vec<String> = kinds
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(k, n)| format!("{k}={n}"))
            .collect();
        if v.is_empty() {
            "none".to_owned()
        } else {
            v.join(" ")
        }
    }
}

/// One log line with the counters that matter in operation (periodically and at exit).
pub fn log_counters(c: &Counters) {
    tracing::info!(
        rx = c.rx_frames,
        rx_v1 = c.rx_v1_frames,
        parse_err = c.rx_parse_errors,
        seq_lost = c.rx_seq_lost,
        seq_lost_v1 = c.rx_seq_lost_v1,
        foreign = c.rx_foreign,
        foreign_hb = c.rx_foreign_heartbeats,
        foreign_autopilot = c.rx_foreign_autopilots,
        foreign_input = c.rx_foreign_input,
        imu = c.input.imu,
        air = c.input.air,
        mag = c.input.mag,
        gnss = c.input.gnss,
        rejected = c.input.rejected(),
        time_order = c.time_order_rejected,
        repeated = c.time_repeated,
        ts_samples = c.timesync.samples,
        reboots = c.autopilot_reboots,
        time_jumps = c.autopilot_time_jumps,
        autopilot_changes = c.autopilot_changes,
        solutions = c.solutions,
        published = c.published,
        withheld = c.publish_withheld,
        gnss_echo = c.gnss_echo,
        interval_refused = c.interval_refused,
        airspeed_unhealthy = c.input.airspeed_unhealthy,
        stale = c.publish_stale,
        tx = c.tx_messages,
        tx_failed = c.tx_failed,
        tx_full = c.tx_queue_full,
        frames = c.frames_received,
        frames_dropped = c.frames_dropped,
        camera_err = c.camera_errors,
        restarts = c.worker_restarts,
        latency_samples = c.latency_samples,
        latency_max_us = c.latency_max_us,
        refused = %c.rejections(),
        "counters"
    );
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

    #[test]
    fn the_counter_line_names_every_refusal_by_kind() {
        let mut c = Counters::default();
        assert_eq!(c.rejections(), "none");
        c.input.out_of_range = 3;
        c.timesync.clock_outliers = 1;
        c.rx_foreign = 40;
        assert_eq!(c.rejections(), "out_of_range=3 clock_outlier=1 foreign=40");
    }

    /// The memory bound stated in docs/DAEMON.md: queue capacities × element sizes.
    #[test]
    fn queue_elements_are_small_enough_for_the_stated_memory_bound() {
        let nav = std::mem::size_of::<nav_thread::NavInput>();
        let out = std::mem::size_of::<Outgoing>();
        eprintln!("NavInput {nav} B, Outgoing {out} B");
        assert!(nav <= 128, "NavInput is {nav} B");
        assert!(out <= 320, "Outgoing is {out} B");
        // 2,048 × 128 B + 256 × 320 B < 350 kB.
        const { assert!(EVENT_CHANNEL * 128 + OUTBOX * 320 < 350_000) };
    }
}
