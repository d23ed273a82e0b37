//! The navigation OS thread (ARCHITECTURE "The daemon"): owns the [`Navigator`], fed by a
//! bounded channel of sensor events (the sender waits when it is full: IMU, air, magnetometer
//! and GNSS are never dropped) and a small frame queue that drops its oldest frame when the
//! thread is late. No clock here: it only feeds the synchronous core and publishes the latest
//! solution. When to start and re-initialise the INS is the navigator's (`nav::policy`); the
//! thread logs each start, and the reset counter tells consumers (ODOMETRY `reset_counter`,
//! STATUSTEXT) of the jump.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use tokio::sync::{mpsc, watch};

use super::config::VisionThreadPolicy;
use super::{Latest, Shared};
use crate::io::sensor_log::SensorLogWriter;
use crate::nav::{NavConfig, Navigator, StartKind, VisionDone, VisionTask};
use crate::sensors::{Frame, SensorEvent};

/// `ianav run --record FILE`: every event fed to the navigator, in the order fed (frames
/// inline), into a sensor log headed by the navigation settings, so that `ianav replay`
/// reproduces the solutions; and every solution the navigator produced (what the publisher was
/// handed) into `FILE` with the extension `solutions.csv`, in `ianav replay`'s format. A write
/// error stops the recording (logged, `record_failed`), never the navigation.
#[derive(Debug)]
pub struct Recorder {
    log: Option<SensorLogWriter<std::io::BufWriter<std::fs::File>>>,
    solutions: Option<std::io::BufWriter<std::fs::File>>,
    line: String,
    path: std::path::PathBuf,
}

impl Recorder {
    /// Create (or truncate) `path` and its solutions file; write the header and `cfg`.
    pub fn create(path: &std::path::Path, cfg: &NavConfig) -> std::io::Result<Self> {
        use std::io::Write;
        let file = std::io::BufWriter::new(std::fs::File::create(path)?);
        let mut log = SensorLogWriter::new(file)?;
        log.write_nav_config(&crate::nav::replay::config_to_toml(cfg))?;
        let mut solutions =
            std::io::BufWriter::new(std::fs::File::create(Self::solutions_path(path))?);
        writeln!(solutions, "{}", crate::nav::replay::CSV_HEADER)?;
        Ok(Self {
            log: Some(log),
            solutions: Some(solutions),
            line: String::with_capacity(320),
            path: path.to_path_buf(),
        })
    }

    /// Where the solutions of the recording at `path` go.
    pub fn solutions_path(path: &std::path::Path) -> std::path::PathBuf {
        path.with_extension("solutions.csv")
    }

    fn record(&mut self, event: &SensorEvent, shared: &Shared) {
        let Some(log) = self.log.as_mut() else { return };
        match log.write(event) {
            Ok(()) => shared.count(|c| c.events_recorded += 1),
            Err(e) => self.fail(&e, shared),
        }
    }

    fn solution(&mut self, sol: &crate::nav::NavSolution, shared: &Shared) {
        use std::io::Write;
        let Some(out) = self.solutions.as_mut() else {
            return;
        };
        crate::nav::replay::csv_line(sol, &mut self.line);
        if let Err(e) = writeln!(out, "{}", self.line) {
            self.fail(&e, shared);
        }
    }

    fn finish(&mut self, shared: &Shared) {
        use std::io::Write;
        let log = self.log.take().map(SensorLogWriter::finish);
        let solutions = self.solutions.take().map(|mut s| s.flush());
        for result in [log.map(|r| r.map(drop)), solutions].into_iter().flatten() {
            if let Err(e) = result {
                self.fail(&e, shared);
            }
        }
    }

    fn fail(&mut self, e: &std::io::Error, shared: &Shared) {
        self.log = None;
        self.solutions = None;
        shared.count(|c| c.record_failed = true);
        tracing::error!(path = %self.path.display(), "recording stopped: {e}");
    }
}

/// Input of the navigation thread.
#[derive(Debug)]
pub enum NavInput {
    /// A sensor event and the reception time of its message.
    Event(SensorEvent, Instant),
    /// Frames are waiting in the [`FrameQueue`] (sent with `try_send`: when the channel is
    /// full, events are flowing and the frames are taken with them).
    FramesReady,
    /// The vision thread has finished a frame: take its result now rather than at the next
    /// event (sent like `FramesReady`).
    VisionDone,
}

/// Bounded frame queue, oldest dropped first.
#[derive(Debug)]
pub struct FrameQueue {
    cap: usize,
    /// Frames with the instant each was queued (for the frame → result latency).
    q: Mutex<VecDeque<(Frame, Instant)>>,
}

impl FrameQueue {
    /// A queue of at most `cap` frames.
    pub fn new(cap: usize) -> Self {
        Self {
            cap: cap.max(1),
            q: Mutex::new(VecDeque::with_capacity(cap.max(1))),
        }
    }

    /// Add a frame; returns how many old frames were dropped to make room.
    pub fn push(&self, f: Frame) -> u64 {
        let mut q = self
            .q
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut dropped = 0;
        while q.len() >= self.cap {
            q.pop_front();
            dropped += 1;
        }
        q.push_back((f, Instant::now()));
        dropped
    }

    /// Take every queued frame with the instant it was queued, oldest first.
    pub fn drain(&self) -> Vec<(Frame, Instant)> {
        let mut q = self
            .q
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        q.drain(..).collect()
    }
}

/// The time contract on the thread's side: once the INS runs, frames wait until the event
/// stream reaches their time, and go to the navigator just before the first event at or after
/// it, in time order (before, they go at once: there is no pose for their time to wait for).
/// A frame therefore never goes ahead of older IMU samples already queued; one that arrives
/// after newer IMU samples were applied goes at once, and the navigator navigates it with the
/// INS pose at its time or rejects it as late (`nav.frames_late`).
#[derive(Debug)]
pub struct FrameMerge {
    cap: usize,
    /// Waiting frames, oldest first.
    pending: VecDeque<Frame>,
}

impl FrameMerge {
    /// At most `cap` frames wait (the oldest are dropped: no events, e.g. the link is lost).
    pub fn new(cap: usize) -> Self {
        Self {
            cap: cap.max(1),
            pending: VecDeque::with_capacity(cap.max(1)),
        }
    }

    /// Add a frame; returns how many waiting frames were dropped to make room.
    pub fn add(&mut self, f: Frame) -> u64 {
        let at = self.pending.partition_point(|p| p.t_us <= f.t_us);
        self.pending.insert(at, f);
        let mut dropped = 0;
        while self.pending.len() > self.cap {
            self.pending.pop_front();
            dropped += 1;
        }
        dropped
    }

    /// The oldest waiting frame taken at or before `t_us`.
    pub fn pop_due(&mut self, t_us: u64) -> Option<Frame> {
        if self.pending.front()?.t_us <= t_us {
            self.pending.pop_front()
        } else {
            None
        }
    }

    /// The oldest waiting frame, whatever its time (at the end).
    pub fn pop(&mut self) -> Option<Frame> {
        self.pending.pop_front()
    }
}

/// The thread's end, reported to the supervisor (`daemon::run`) when it is dropped: on return
/// and while unwinding from a panic alike. Carries the test fault armed for the thread.
#[derive(Debug)]
pub struct Exit {
    notice: Option<tokio::sync::oneshot::Sender<()>>,
    fault: Option<super::FaultKind>,
}

impl Exit {
    /// Report the end on `notice`; `fault`: the test fault armed for the thread.
    pub(crate) fn new(
        notice: tokio::sync::oneshot::Sender<()>,
        fault: Option<super::FaultKind>,
    ) -> Self {
        Self {
            notice: Some(notice),
            fault,
        }
    }
}

impl Drop for Exit {
    fn drop(&mut self) {
        if let Some(n) = self.notice.take() {
            let _ = n.send(());
        }
    }
}

/// Start the thread. It ends when the event channel closes.
#[expect(
    clippy::too_many_arguments,
    reason = "the thread's inputs and outputs, each used once"
)]
pub fn spawn(
    mut nav: Navigator,
    mut recorder: Option<Recorder>,
    mut rx: mpsc::Receiver<NavInput>,
    wake: mpsc::WeakSender<NavInput>,
    frames: Arc<FrameQueue>,
    latest: watch::Sender<Option<Latest>>,
    mut publisher: super::publish::Publisher,
    shared: Arc<Shared>,
    vision_policy: VisionThreadPolicy,
    exit: Exit,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("ianav-nav".to_owned())
        .spawn(move || {
            let started = Instant::now();
            let fault = exit.fault;
            let _exit = exit;
            let mut since_sync = 0_u32;
            let mut noisy_reported = 0_u64;
            let mut adoptions_reported = 0_u64;
            let mut starts_logged = 0_u64;
            let mut merge = FrameMerge::new(frames.cap);
            // Each waiting or running frame: exposure time, when it was received, and when it
            // was due (fed to the navigator: the INS had reached its time).
            let mut arrivals: VecDeque<(u64, Instant, Option<Instant>)> = VecDeque::new();
            let mut vision = VisionWorker::start(&nav, wake, vision_policy);
            let feed_frame = |nav: &mut Navigator,
                              recorder: &mut Option<Recorder>,
                              vision: &mut Option<VisionWorker>,
                              arrivals: &mut VecDeque<(u64, Instant, Option<Instant>)>,
                              f: Frame| {
                if let Some(a) = arrivals.iter_mut().rev().find(|a| a.0 == f.t_us) {
                    a.2 = Some(Instant::now());
                }
                let frame = SensorEvent::Frame(f);
                if let Some(r) = recorder.as_mut() {
                    r.record(&frame, &shared);
                }
                nav.push(&frame);
                if let Some(w) = vision.as_mut() {
                    w.dispatch(nav);
                }
            };
            // The denied-mode covariance budget is logged once per loss.
            let mut budget_logged = false;
            while let Some(input) = rx.blocking_recv() {
                if let Some(kind) = fault
                    && started.elapsed() >= super::Fault::AFTER
                {
                    match kind {
                        super::FaultKind::Panic => panic!("IANAV_FAULT: injected panic in nav"),
                        super::FaultKind::Stop => return,
                    }
                }
                for (f, at) in frames.drain() {
                    if arrivals.len() >= 4 * frames.cap + 8 {
                        arrivals.pop_front();
                    }
                    arrivals.push_back((f.t_us, at, None));
                    let dropped = merge.add(f);
                    if dropped > 0 {
                        shared.count(|c| c.frames_dropped += dropped);
                    }
                }
                if let Some(w) = vision.as_mut()
                    && let Some(t_us) = w.collect(&mut nav, &mut recorder, &shared)
                {
                    // Frames up to this one are done with (applied, refused or dropped).
                    while let Some(&(t, at, due)) = arrivals.front()
                        && t <= t_us
                    {
                        arrivals.pop_front();
                        if t == t_us {
                            let us = |i: Instant| {
                                u64::try_from(i.elapsed().as_micros()).unwrap_or(u64::MAX)
                            };
                            shared.record_frame_latency(us(at), us(due.unwrap_or(at)));
                        }
                    }
                }
                // Before the INS runs there is no pose for a frame's time to wait for.
                if !nav.is_initialised() {
                    while let Some(f) = merge.pop() {
                        feed_frame(&mut nav, &mut recorder, &mut vision, &mut arrivals, f);
                    }
                }
                match input {
                    NavInput::FramesReady | NavInput::VisionDone => {}
                    NavInput::Event(ev, rx_at) => {
                        while let Some(f) = merge.pop_due(ev.t_us()) {
                            feed_frame(&mut nav, &mut recorder, &mut vision, &mut arrivals, f);
                        }
                        if let SensorEvent::Gnss(fix) = &ev {
                            publisher.on_fix(fix.t_us);
                        }
                        if let Some(r) = recorder.as_mut() {
                            r.record(&ev, &shared);
                        }
                        let sol = nav.push(&ev);
                        // A frame that waited for the INS to reach its time becomes a task
                        // at an IMU step, not at a frame.
                        if let Some(w) = vision.as_mut() {
                            w.dispatch(&mut nav);
                        }
                        if nav.stats().initialisations > starts_logged {
                            starts_logged = nav.stats().initialisations;
                            log_start(&nav, &shared);
                        }
                        if let Some(sol) = sol {
                            if let Some(r) = recorder.as_mut() {
                                r.solution(&sol, &shared);
                            }
                            if let Some(nis) = sol.ins.gnss_nis {
                                let w = sol.ins.wind_ned_mps;
                                tracing::debug!(
                                    t_us = sol.ins.t_us,
                                    nis,
                                    denied = sol.ins.gnss_denied,
                                    wind_n_mps = w.x,
                                    wind_e_mps = w.y,
                                    tas_mps = sol.ins.tas_mps,
                                    ref_att_err_roll_deg =
                                        sol.ins.ref_attitude_err_rad.x.to_degrees(),
                                    ref_att_err_pitch_deg =
                                        sol.ins.ref_attitude_err_rad.y.to_degrees(),
                                    ref_att_err_yaw_deg =
                                        sol.ins.ref_attitude_err_rad.z.to_degrees(),
                                    "GNSS fix processed"
                                );
                            }
                            if sol.ins.gnss_denied && !budget_logged {
                                budget_logged = true;
                                if let Some(b) = nav.denied_budget() {
                                    let g = b.gust_sigma_b_mps;
                                    tracing::info!(
                                        wind_sigma_mps = b.wind_sigma_mps,
                                        wind_avg_sigma_mps = b.wind_avg_sigma_mps,
                                        wind_gust_sigma_mps = b.wind_gust_sigma_mps,
                                        wind_air_bias_sigma_mps = b.wind_air_bias_sigma_mps,
                                        wind_attitude_sigma_mps = b.wind_attitude_sigma_mps,
                                        airspeed_correction_mps = b.airspeed_correction_mps,
                                        gust_sigma_x_mps = g.x,
                                        gust_sigma_y_mps = g.y,
                                        gust_sigma_z_mps = g.z,
                                        gust_tau_x_s = b.gust_tau_s.x,
                                        heading_sigma_deg = b.heading_sigma_rad.to_degrees(),
                                        "GNSS-denied covariance at the loss (docs/INS.md)"
                                    );
                                }
                            } else if !sol.ins.gnss_denied {
                                budget_logged = false;
                            }
                            publisher.on_solution(&sol, rx_at);
                            latest.send_replace(Some(Latest { sol, imu_rx: rx_at }));
                            shared.count(|c| c.solutions += 1);
                        }
                    }
                }
                since_sync += 1;
                if since_sync >= 50 || rx.is_empty() {
                    since_sync = 0;
                    let (n, i) = (*nav.stats(), nav.ins_stats().copied());
                    if n.imu_noise_adoptions > adoptions_reported {
                        adoptions_reported = n.imu_noise_adoptions;
                        log_imu_noise_adoption(&nav, n.imu_noise_capped);
                    }
                    if n.imu_noisier_than_configured > noisy_reported {
                        noisy_reported = n.imu_noisier_than_configured;
                        if let Some(m) = nav.imu_noise() {
                            let cfg = &nav.config().ins;
                            tracing::warn!(
                                gyro_ratio = m.gyro_ratio,
                                accel_ratio = m.accel_ratio,
                                period_s = m.period_s,
                                adopting = cfg.imu_noise.adopt,
                                "IMU noisier than the INS's model (beyond what \
                                 [ins.imu_noise] adopts, or adoption off): the INS \
                                 over-trusts its propagation; set [ins.attitude] \
                                 r_gyro_rad2ps2 ≥ {:.2e} with q_w_nb_rad2ps2 ≥ {:.2e}, and \
                                 [ins.position] q_velocity_m2ps2 ≥ {:.2e}, or find the \
                                 vibration (docs/INS.md)",
                                m.matching_r_gyro_rad2ps2(cfg),
                                crate::ins::AttitudeFilterConfig::matching_q_w_nb_rad2ps2(
                                    m.matching_r_gyro_rad2ps2(cfg)
                                ),
                                m.matching_q_velocity_m2ps2(cfg)
                            );
                        }
                    }
                    shared.count(|c| {
                        c.nav = n;
                        c.ins = i;
                    });
                }
            }
            while let Some(f) = merge.pop() {
                feed_frame(&mut nav, &mut recorder, &mut vision, &mut arrivals, f);
            }
            // A frame still out is given up: its result would come after the last event.
            drop(vision);
            let (n, i) = (*nav.stats(), nav.ins_stats().copied());
            shared.count(|c| {
                c.nav = n;
                c.ins = i;
            });
            if let Some(r) = recorder.as_mut() {
                r.finish(&shared);
            }
        })
}

/// The thread that runs the deferred visual navigation ([`NavConfig::vision_deferred`]) away
/// from the IMU path: one frame at a time, handed back to the navigator at the next event after
/// it is done (within one IMU period), where the recording gets its marker. A panic in it is
/// caught and logged; the navigator then keeps the frame out and counts the later frames busy
/// (`frames_vision_busy`): the INS navigates on, without vision.
struct VisionWorker {
    tasks: Option<std::sync::mpsc::SyncSender<VisionTask>>,
    done: std::sync::mpsc::Receiver<Result<VisionDone, String>>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// Set once the worker has failed (logged once).
    failed: bool,
}

impl VisionWorker {
    /// The worker, when the navigator defers its vision; `None` otherwise (or when the thread
    /// cannot be started: logged, and the frames are then counted busy).
    /// `wake`: the navigation thread's input, told when a frame is done (weak: the thread
    /// ends when the link and the camera have stopped, whatever the worker holds).
    fn start(
        nav: &Navigator,
        wake: mpsc::WeakSender<NavInput>,
        policy: VisionThreadPolicy,
    ) -> Option<Self> {
        let cfg = nav.config();
        if !(cfg.vision_deferred && cfg.camera.is_some()) {
            return None;
        }
        let (task_tx, task_rx) = std::sync::mpsc::sync_channel::<VisionTask>(1);
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("ianav-vision".to_owned())
            .spawn(move || {
                apply_policy(policy);
                while let Ok(task) = task_rx.recv() {
                    let result =
                        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| task.run()))
                            .map_err(|p| super::supervisor::panic_message(p.as_ref()));
                    let failed = result.is_err();
                    if done_tx.send(result).is_err() || failed {
                        return;
                    }
                    if let Some(tx) = wake.upgrade() {
                        let _ = tx.try_send(NavInput::VisionDone);
                    }
                }
            });
        match thread {
            Ok(thread) => Some(Self {
                tasks: Some(task_tx),
                done: done_rx,
                thread: Some(thread),
                failed: false,
            }),
            Err(e) => {
                tracing::error!("vision: cannot start its thread ({e}); navigating without it");
                None
            }
        }
    }

    /// Hand the navigator's waiting frame, if any, to the thread.
    fn dispatch(&mut self, nav: &mut Navigator) {
        let Some(task) = nav.take_vision_task() else {
            return;
        };
        // The channel holds one task and the navigator hands out one at a time: a send fails
        // only when the thread has ended (after a panic, reported by `collect`).
        if let Some(tx) = &self.tasks
            && tx.send(task).is_err()
        {
            self.tasks = None;
        }
    }

    /// Hand a finished frame back to the navigator and record its marker; the frame's exposure
    /// time when one was applied.
    fn collect(
        &mut self,
        nav: &mut Navigator,
        recorder: &mut Option<Recorder>,
        shared: &Shared,
    ) -> Option<u64> {
        match self.done.try_recv() {
            Ok(Ok(done)) => {
                let t_us = done.frame_t_us();
                if let Some(marker) = nav.apply_vision(done)
                    && let Some(r) = recorder.as_mut()
                {
                    r.record(&marker, shared);
                }
                return Some(t_us);
            }
            Ok(Err(panic)) => {
                self.tasks = None;
                self.failed = true;
                shared.count(|c| c.vision_failures += 1);
                tracing::error!(
                    "vision: its thread panicked ({panic}); navigating on the INS without vision"
                );
            }
            Err(std::sync::mpsc::TryRecvError::Empty) => {}
            Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                if !self.failed {
                    self.failed = true;
                    shared.count(|c| c.vision_failures += 1);
                    tracing::error!(
                        "vision: its thread ended; navigating on the INS without vision"
                    );
                }
            }
        }
        None
    }
}

impl Drop for VisionWorker {
    fn drop(&mut self) {
        // Closing the task channel ends the thread once its frame (if any) is done.
        self.tasks = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Log a start of the navigator's; the first fixes the local frame's origin.
/// Schedule the calling (vision) thread by `policy`; a refusal is logged and the thread runs
/// at the default policy.
fn apply_policy(policy: VisionThreadPolicy) {
    use thread_priority::unix::{
        NormalThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy,
        thread_native_id,
    };
    if policy == VisionThreadPolicy::Normal {
        return;
    }
    let idle = ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Idle);
    match set_thread_priority_and_policy(
        thread_native_id(),
        thread_priority::ThreadPriority::Min,
        idle,
    ) {
        Ok(()) => tracing::debug!("vision thread at SCHED_IDLE"),
        Err(e) => tracing::warn!("vision thread: SCHED_IDLE refused ({e:?}); default policy"),
    }
}

fn log_start(nav: &Navigator, shared: &Shared) {
    let Some(start) = nav.last_start() else {
        return;
    };
    let pos = start.pos;
    match start.kind {
        StartKind::First => {
            shared.state(|s| s.origin = Some(pos));
            tracing::info!(
                lat_deg = pos.lat_rad.to_degrees(),
                lon_deg = pos.lon_rad.to_degrees(),
                h_m = pos.h_m,
                "INS initialised"
            );
        }
        StartKind::Flying => tracing::info!("flying: INS started again for flight"),
        StartKind::GnssBack => tracing::warn!("GNSS back for 5 s: INS re-initialised at the fix"),
    }
}

/// The daemon's log line for an adoption of the IMU's measured noise (docs/INS.md "IMU noise
/// adoption"): the model now in use against the configured one.
fn log_imu_noise_adoption(nav: &Navigator, capped: u64) {
    let configured = crate::ins::imu_noise::ImuNoiseModel::from_config(&nav.config().ins);
    let m = nav.imu_noise_model();
    tracing::warn!(
        r_gyro_rad2ps2 = m.r_gyro_rad2ps2,
        gyro_factor = m.r_gyro_rad2ps2 / configured.r_gyro_rad2ps2,
        q_w_nb_rad2ps2 = m.q_w_nb_rad2ps2,
        q_velocity_m2ps2 = m.q_velocity_m2ps2,
        q_velocity_factor = m.q_velocity_m2ps2 / configured.q_velocity_m2ps2,
        r_accel_white_m2ps4 = m.r_accel_white_m2ps4,
        capped,
        "INS adopted the IMU's measured noise (pin the configured model with \
         [ins.imu_noise] adopt = false)"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t_us: u64) -> Frame {
        Frame {
            t_us,
            width: 1,
            height: 1,
            pixels: Arc::from(vec![0_u8]),
        }
    }

    #[test]
    fn the_merge_sorts_waiting_frames_and_releases_them_at_their_time() {
        let mut m = FrameMerge::new(3);
        for t in [50, 20, 40] {
            assert_eq!(m.add(frame(t)), 0);
        }
        assert!(m.pop_due(10).is_none());
        assert_eq!(m.pop_due(45).map(|f| f.t_us), Some(20));
        assert_eq!(m.pop_due(45).map(|f| f.t_us), Some(40));
        assert!(m.pop_due(45).is_none());
        // Full: the oldest waiting frame goes.
        let added = (m.add(frame(60)), m.add(frame(30)), m.add(frame(70)));
        assert_eq!(added, (0, 0, 1));
        let rest: Vec<u64> = std::iter::from_fn(|| m.pop()).map(|f| f.t_us).collect();
        assert_eq!(rest, vec![50, 60, 70]);
    }

    /// The navigation thread with frames and IMU samples arriving interleaved and out of
    /// order: its recording (the order it fed the navigator) has every frame just before the
    /// first event at or after its time, and a frame older than the reorder window is counted
    /// late by the navigator.
    #[test]
    fn frames_and_imu_arriving_out_of_order_are_applied_in_time_order() {
        use crate::ins::InsInit;
        use crate::io::sensor_log::SensorLogReader;
        use crate::math::wgs84::Geodetic;
        use crate::sensors::{AirSample, ImuSample};
        use nalgebra::{UnitQuaternion, Vector3};

        let dir = std::env::temp_dir().join(format!("ianav_nav_thread_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rec.bin");
        let cfg = Arc::new(
            crate::daemon::config::DaemonConfig::from_toml_str(
                "[mavlink]\nconnection = \"udpin:127.0.0.1:0\"\n[output]\nrate_hz = 30\n",
                None,
            )
            .unwrap(),
        );
        let nav_cfg = crate::daemon::nav_config(&cfg, 2026.5);
        let mut nav = Navigator::new(&nav_cfg).unwrap();
        nav.initialise(&InsInit::new(
            UnitQuaternion::identity(),
            Geodetic {
                lat_rad: 0.7,
                lon_rad: -1.5,
                h_m: 1_000.0,
            },
            Vector3::new(30.0, 0.0, 0.0),
            2026.5,
        ))
        .unwrap();
        let shared = Arc::new(Shared::default());
        let (out_tx, _out_rx) = mpsc::channel(1024);
        let outbox = super::super::Outbox {
            tx: out_tx,
            shared: shared.clone(),
        };
        let publisher = super::super::publish::Publisher::new(
            cfg,
            super::super::Clock::new(),
            outbox,
            shared.clone(),
        );
        let (tx, rx) = mpsc::channel(4096);
        let queue = Arc::new(FrameQueue::new(8));
        let (latest, _latest_rx) = watch::channel(None);
        let (exit_tx, _exit_rx) = tokio::sync::oneshot::channel();
        let recorder = Recorder::create(&path, &nav_cfg).unwrap();
        let join = spawn(
            nav,
            Some(recorder),
            rx,
            tx.downgrade(),
            queue.clone(),
            latest,
            publisher,
            shared.clone(),
            VisionThreadPolicy::Idle,
            Exit::new(exit_tx, None),
        )
        .unwrap();
        let send = |ev: SensorEvent| {
            tx.blocking_send(NavInput::Event(ev, Instant::now()))
                .unwrap()
        };
        let imu = |t_us| {
            SensorEvent::Imu(ImuSample {
                t_us,
                gyro_rps: Vector3::zeros(),
                accel_mps2: Vector3::new(0.0, 0.0, -9.81),
            })
        };
        // Two frames out of order, queued before the IMU samples that precede them.
        queue.push(frame(55_000));
        queue.push(frame(25_000));
        send(SensorEvent::Air(AirSample {
            t_us: 0,
            tas_mps: 30.0,
            aoa_rad: None,
            aos_rad: None,
            p_pa: 89_874.0,
            temp_k: 281.65,
        }));
        for k in 0..=200 {
            send(imu(k * 10_000));
        }
        // 2 s of IMU applied; a frame 1.5 s old (late) and one 0.5 s old (in the window).
        // Wait until the thread has taken every IMU sample so the frames come after them.
        let deadline = Instant::now() + std::time::Duration::from_secs(10);
        while shared.counters().solutions < 201 && Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        queue.push(frame(500_000));
        queue.push(frame(1_500_000));
        send(imu(2_010_000));
        drop(tx);
        join.join().unwrap();

        let log = std::fs::read(&path).unwrap();
        let order: Vec<(bool, u64)> = SensorLogReader::new(&log[..])
            .unwrap()
            .map(|e| e.unwrap())
            .map(|e| (matches!(e, SensorEvent::Frame(_)), e.t_us()))
            .collect();
        let at = |frame_t| order.iter().position(|&(f, t)| f && t == frame_t).unwrap();
        let next_t = |i: usize| order[i + 1].1;
        // Each early frame right before the first IMU sample after it, in time order.
        assert_eq!((next_t(at(25_000)), next_t(at(55_000))), (30_000, 60_000));
        assert!(at(25_000) < at(55_000));
        // The late pair: fed in time order before the next IMU sample.
        assert!(at(500_000) < at(1_500_000) && next_t(at(1_500_000)) == 2_010_000);
        let c = shared.counters();
        assert_eq!((c.nav.frames, c.nav.frames_late), (3, 1));
        assert_eq!(c.solutions, 202);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_frame_queue_drops_the_oldest() {
        let q = FrameQueue::new(2);
        assert_eq!(q.push(frame(1)), 0);
        assert_eq!(q.push(frame(2)), 0);
        assert_eq!(q.push(frame(3)), 1);
        let t: Vec<u64> = q.drain().iter().map(|(f, _)| f.t_us).collect();
        assert_eq!(t, vec![2, 3]);
        assert!(q.drain().is_empty());
    }
}
