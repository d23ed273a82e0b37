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
//!
//! Here: [`run`] in named steps (set-up, the navigation thread, the workers, the shutdown).
//! `shared.rs`: what the tasks share (clock, counters, state, outbox); `supervisor.rs`: the
//! workers' supervision and the `IANAV_FAULT` test hook; `monitor.rs`: heartbeat, health
//! STATUSTEXTs, sd_notify and the counter line; the other modules: one worker or concern each.

pub mod camera;
#[cfg(feature = "opencv")]
pub mod camera_cv;
mod camera_stream;
pub mod config;
pub mod health;
pub mod intervals;
pub mod link;
mod monitor;
pub mod nav_thread;
pub mod preflight;
pub mod publish;
mod shared;
mod supervisor;
pub mod transport;

pub use monitor::log_counters;
pub use shared::{
    Clock, Counters, ECHO_MEMORY, Handle, LATENCY_RING, Latest, Outbox, Outgoing, Shared, State,
};
pub use supervisor::MAX_CAMERA_RESTARTS;
pub(crate) use supervisor::{Fault, FaultKind};

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, oneshot, watch};

use crate::daemon::config::{AutopilotKind, DaemonConfig, OutputMode};
use crate::io::mavlink_out;
use crate::nav::Navigator;
use mavlink::dialects::ardupilotmega as apm;
use nav_thread::{FrameQueue, NavInput, Recorder};
use shared::Context;
use supervisor::{
    CAMERA, Ending, INTERVALS, LAST_WORDS, MONITOR, NAV_ID, NavThread, OwnStop, READER, Supervisor,
    TIMESYNC, WRITER,
};

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

/// The navigation core's settings for this daemon: its INS, started by the core's rules with
/// the magnetic model of `mag_decimal_year`, and started again at the first fix at
/// `input.start_airspeed_mps` when first started below it (on the ground).
///
/// With a camera source, the visual navigation is the paper's IA-VNS (docs/IAVNS.md), run off
/// the IMU path (`vision_deferred`, docs/DAEMON.md "Vision off the IMU path") and started from
/// the INS's height over `camera.terrain_height_m`; its horizontal position is published after
/// the GNSS loss unless `navigation.vision_position` is off (docs/FUSION.md).
pub fn nav_config(cfg: &DaemonConfig, mag_decimal_year: f64) -> crate::nav::NavConfig {
    let mut nav = crate::nav::NavConfig::new(cfg.ins.clone(), mag_decimal_year);
    nav.start.restart_airspeed_mps = Some(cfg.input.start_airspeed_mps);
    if let Some(camera) = cfg.camera.nav_camera() {
        nav.camera = Some(camera);
        nav.vision = cfg.vision.clone();
        nav.vision_deferred = true;
        nav.flat_terrain = cfg
            .camera
            .terrain_height_m
            .map(|h_m| crate::nav::FlatTerrain {
                h_m,
                sigma_m: cfg.camera.terrain_height_sigma_m,
            });
        nav.fusion = cfg
            .navigation
            .vision_position
            .then_some(cfg.navigation.vision_error);
        nav.vision_restart = Some(cfg.navigation.vision_restart);
    }
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
    handle_tx: Option<oneshot::Sender<Handle>>,
) -> Result<(), DaemonError> {
    let fault = Fault::from_env();
    let clock = Clock::new();
    let (navigator, recorder) = navigation(&cfg, clock)?;
    let (stop_tx, stop) = watch::channel(false);
    let (out_tx, out_rx) = mpsc::channel(OUTBOX);
    let ctx = Context::new(cfg, clock, out_tx, stop);
    let (mut nav, channels) = start_navigation(&ctx, navigator, recorder, fault.on(NAV_ID))?;
    if let Some(h) = handle_tx {
        let _ = h.send(Handle {
            shared: ctx.shared.clone(),
            stop: stop_tx.clone(),
        });
    }
    let mut sup = Supervisor::new(fault);
    spawn_workers(&mut sup, &ctx, out_rx, channels);
    let ending = sup.supervise(&ctx, &mut nav.exit).await;
    shut_down(ctx, stop_tx, sup, nav, ending).await
}

/// Set-up: the navigation core, with the magnetic model of `navigation.mag_decimal_year` (of
/// today when 0), a warning if its body rate would lag in turns, and the `--record` log.
fn navigation(
    cfg: &DaemonConfig,
    clock: Clock,
) -> Result<(Navigator, Option<Recorder>), DaemonError> {
    let year = if cfg.navigation.mag_decimal_year != 0.0 {
        cfg.navigation.mag_decimal_year
    } else {
        clock.decimal_year()
    };
    let nav_cfg = nav_config(cfg, year);
    let nav = Navigator::new(&nav_cfg)?;
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
            Recorder::create(path, &nav_cfg)
                .map_err(|e| DaemonError::Record(format!("{}: {e}", path.display())))?,
        ),
        None => None,
    };
    Ok((nav, recorder))
}

/// The navigation thread's channels as the workers hold them.
struct NavChannels {
    /// Sensor events (the reader) and the frames' wake-up (the camera).
    events: mpsc::Sender<NavInput>,
    /// Camera frames.
    frames: Arc<FrameQueue>,
    /// The latest solution (the monitor).
    latest: watch::Receiver<Option<Latest>>,
}

/// Start the navigation thread on `navigator`, its solutions published on the outbox;
/// `fault`: the test fault armed for it.
fn start_navigation(
    ctx: &Context,
    navigator: Navigator,
    recorder: Option<Recorder>,
    fault: Option<FaultKind>,
) -> Result<(NavThread, NavChannels), DaemonError> {
    let (events, events_rx) = mpsc::channel(EVENT_CHANNEL);
    let (latest_tx, latest) = watch::channel(None);
    let frames = Arc::new(FrameQueue::new(ctx.cfg.camera.queue_frames));
    let publisher = publish::Publisher::new(
        ctx.cfg.clone(),
        ctx.clock,
        ctx.outbox.clone(),
        ctx.shared.clone(),
    );
    let (exit_tx, exit) = oneshot::channel();
    let join = nav_thread::spawn(
        navigator,
        recorder,
        events_rx,
        events.downgrade(),
        frames.clone(),
        latest_tx,
        publisher,
        ctx.shared.clone(),
        ctx.cfg.navigation.vision_thread,
        nav_thread::Exit::new(exit_tx, fault),
    )
    .map_err(|e| DaemonError::Thread(e.to_string()))?;
    let channels = NavChannels {
        events,
        frames,
        latest,
    };
    Ok((NavThread { exit, join }, channels))
}

/// Start every task under `sup`: the link writer and reader, the TIMESYNC and interval
/// requests, the monitor and the camera (restartable). `out_rx`: the outbox, for the writer.
fn spawn_workers(
    sup: &mut Supervisor,
    ctx: &Context,
    out_rx: mpsc::Receiver<Outgoing>,
    nav: NavChannels,
) {
    let NavChannels {
        events,
        frames,
        latest,
    } = nav;
    let (conn_tx, conn_rx) = watch::channel(None);
    // The reader and the camera own the only event senders: when both have stopped, the
    // navigation thread sees the channel close and ends.
    let cam_wake = events.clone();
    // Each worker takes what it needs of its own copy of the context.
    let c = ctx.clone();
    let writer = link::writer(c.cfg, out_rx, conn_rx, c.shared, c.stop);
    sup.spawn(WRITER, writer);
    let c = ctx.clone();
    let reader = link::reader(c.cfg, c.clock, conn_tx, events, c.outbox, c.shared, c.stop);
    sup.spawn(READER, reader);
    let c = ctx.clone();
    let timesync = link::timesync_requests(c.cfg, c.clock, c.outbox, c.shared, c.stop);
    sup.spawn(TIMESYNC, timesync);
    let c = ctx.clone();
    let intervals = link::interval_requests(c.cfg, c.outbox, c.shared, c.stop);
    sup.spawn(INTERVALS, intervals);
    sup.spawn(MONITOR, monitor::monitor(ctx.clone(), latest));
    // Each run of the camera stops on its own signal, so that its capture thread ends with it.
    let c = ctx.clone();
    sup.spawn_restartable(CAMERA, move || {
        let (own_stop, own) = OwnStop::new(&c.stop);
        let wake = cam_wake.clone();
        let camera = camera::run(
            c.cfg.clone(),
            c.clock,
            frames.clone(),
            wake,
            c.shared.clone(),
            own,
        );
        own_stop.around(camera)
    });
}

/// Announce a failure (with [`LAST_WORDS`] for the writer to send it), stop every task, then
/// the navigation thread, and say why the daemon stopped.
async fn shut_down(
    ctx: Context,
    stop_tx: watch::Sender<bool>,
    sup: Supervisor,
    mut nav: NavThread,
    ending: Ending,
) -> Result<(), DaemonError> {
    // The reader stops when the navigation thread is gone, maybe seen first: name the thread
    // then (its end is signalled before its event receiver is dropped).
    let nav_ended = matches!(ending, Ending::NavEnded) || nav.exit.try_recv().is_ok();
    if let Some(what) = ending.failed_worker(nav_ended) {
        // Not logged here: `ianav run` prints the error once when the daemon returns it.
        ctx.shared.count(|c| c.statustexts += 1);
        ctx.outbox
            .send(apm::MavMessage::STATUSTEXT(mavlink_out::statustext(
                apm::MavSeverity::MAV_SEVERITY_CRITICAL,
                &format!("ianav: {what} failed, exiting"),
            )));
        tokio::time::sleep(LAST_WORDS).await;
    }
    let _ = stop_tx.send(true);
    sup.stop().await;
    // Every event sender went with the supervisor (the camera's is in its restart closure):
    // the navigation thread sees the channel close and ends.
    drop(ctx);
    nav.finish(nav_ended, ending).await
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_camera_source_runs_the_ia_vns_deferred_from_the_configured_ground() {
        let toml = |camera: &str| {
            format!(
                "[mavlink]\nconnection = \"udpin:127.0.0.1:14540\"\n[output]\nrate_hz = 30\n\
                 [camera]\n{camera}\n"
            )
        };
        let parse = |camera: &str| DaemonConfig::from_toml_str(&toml(camera), None).unwrap();
        let none = nav_config(&parse("source = \"none\""), 2026.5);
        assert!(none.camera.is_none() && !none.vision_deferred && none.flat_terrain.is_none());
        assert_eq!(none.vision, crate::vision::vns::VnsConfig::default());
        let cfg = parse(
            "source = \"frame_stream\"\naddress = \"127.0.0.1:5600\"\n\
             terrain_height_m = 180.0\nterrain_height_sigma_m = 20.0",
        );
        let nav = nav_config(&cfg, 2026.5);
        assert_eq!(nav.camera, cfg.camera.nav_camera());
        assert!(nav.camera.is_some() && nav.vision_deferred);
        assert_eq!(nav.vision.aiding, crate::vision::vns::AidingConfig::paper());
        assert_eq!(
            nav.flat_terrain,
            Some(crate::nav::FlatTerrain {
                h_m: 180.0,
                sigma_m: 20.0
            })
        );
        assert!(crate::nav::Navigator::new(&nav).is_ok());
        let bad = DaemonConfig::from_toml_str(&toml("terrain_height_m = 1e9"), None);
        assert!(
            bad.unwrap_err()
                .to_string()
                .starts_with("camera.terrain_height_m"),
        );
    }

    /// With a camera the IA-VNS position is published after the loss, with the configured
    /// error model, unless switched off; an invalid model is refused by its key.
    #[test]
    fn a_camera_source_publishes_the_visual_position_unless_told_not_to() {
        let toml = |extra: &str| {
            format!(
                "[mavlink]\nconnection = \"udpin:127.0.0.1:14540\"\n[output]\nrate_hz = 30\n\
                 [camera]\nsource = \"frame_stream\"\naddress = \"127.0.0.1:5600\"\n\
                 terrain_height_m = 180.0\n[navigation]\n{extra}\n"
            )
        };
        let parse = |extra: &str| DaemonConfig::from_toml_str(&toml(extra), None);
        let on = nav_config(&parse("").unwrap(), 2026.5);
        assert_eq!(on.fusion, Some(crate::nav::fusion::FusionConfig::default()));
        assert_eq!(
            on.vision_restart,
            Some(crate::nav::VisionRestart::default())
        );
        let tuned = nav_config(
            &parse("[navigation.vision_error]\nk_per_m = 0.01").unwrap(),
            2026.5,
        );
        assert_eq!(tuned.fusion.map(|f| f.k_per_m), Some(0.01));
        let off = nav_config(&parse("vision_position = false").unwrap(), 2026.5);
        assert_eq!(off.fusion, None);
        assert!(off.camera.is_some());
        let bad = parse("[navigation.vision_error]\nsigma0_m = -3.0").unwrap_err();
        assert!(
            bad.to_string()
                .starts_with("navigation.vision_error.sigma0_m = -3"),
            "{bad}"
        );
        let none = DaemonConfig::from_toml_str(
            "[mavlink]\nconnection = \"udpin:127.0.0.1:14540\"\n[output]\nrate_hz = 30\n",
            None,
        )
        .unwrap();
        assert_eq!(
            nav_config(&none, 2026.5).fusion,
            None,
            "no camera, no fusion"
        );
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
