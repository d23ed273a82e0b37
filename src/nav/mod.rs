//! The navigation core seen by its drivers (ARCHITECTURE "The navigation core"; paper, "IA-VNS
//! flow diagram"): one synchronous object fed timestamped [`SensorEvent`]s that returns fused
//! [`NavSolution`]s. The simulator, the Monte Carlo, the SITL vehicle, the daemon and a replay
//! all drive this type and nothing else of the core: it owns the INS, decides when to start
//! and re-initialise it ([`policy`]), and runs the visual navigation system
//! ([`crate::vision::vns`]) on the camera's frames when a camera is fitted.
//!
//! The VNS is the paper's baseline: it starts from the INS pose and the height over the
//! terrain at its first image (`x̊₀`) and never reads the INS afterwards; the IA-VNS reads it at
//! every frame. The configured system's pose is reported beside the fused solution
//! ([`NavSolution::vision_fix`]); with [`NavConfig::fusion`] it is also the fused horizontal
//! position after the GNSS loss ([`fusion`]). Other systems can run beside it on the same
//! frames for comparison ([`vision`]).

pub mod fusion;
pub mod history;
pub mod policy;
pub mod replay;
pub mod solution;
pub mod vision;

pub use policy::{StartKind, StartPolicy, StartRecord};
pub use solution::{
    InsStatus, NavCovariance, NavSolution, PositionSource, VisionFix, VisionState, VisionStatus,
};
pub use vision::{
    ComparedVision, ComparedVisionError, VisionDone, VisionRestart, VisionTask, VisualSystemView,
};

use crate::ins::imu_noise::{ImuNoise, ImuNoiseModel, ImuNoiseMonitor, NOISY_RATIO, QUIET_RATIO};
use crate::ins::{Ins, InsConfig, InsError, InsInit, InsSolution};
use crate::sensors::{Frame, HeightAboveTerrain, SensorEvent, VisionApplied};
use crate::vision::camera::{CameraConfig, CameraConfigError, Mounting};
use crate::vision::vns::{VnsConfig, VnsCounters, VnsError};
use fusion::{Fusion, FusionConfig, FusionConfigError};
use history::{HistoryPose, PoseHistory};
use policy::{Running, StartState};
use vision::VisualSystems;

/// Span of the INS pose history, µs: longer than any frame's age that is accepted.
pub const POSE_HISTORY_US: u64 = 2_000_000;

/// A height over the terrain older than this at a frame is not used to start the VNS, µs.
pub const MAX_HEIGHT_AGE_US: u64 = 1_000_000;

/// Why a navigator could not be built.
#[derive(Debug, thiserror::Error)]
pub enum NavError {
    /// The INS settings are invalid.
    #[error(transparent)]
    Ins(#[from] InsError),
    /// The camera settings are invalid.
    #[error("camera: {0}")]
    Camera(#[from] CameraConfigError),
    /// The visual navigation's settings are invalid.
    #[error(transparent)]
    Vision(#[from] VnsError),
    /// The compared systems are invalid.
    #[error(transparent)]
    ComparedVision(#[from] ComparedVisionError),
    /// The fusion settings are invalid.
    #[error(transparent)]
    Fusion(#[from] FusionConfigError),
    /// The flat terrain's height or σ is not finite, or the σ is negative.
    #[error("flat_terrain: h_m = {0}, sigma_m = {1}: must be finite, sigma_m ≥ 0")]
    FlatTerrain(f64, f64),
}

/// The camera as the navigation knows it: intrinsics and the *estimated* mounting (the true
/// one is the vehicle's, or the simulator's).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavCamera {
    /// Intrinsics.
    pub intrinsics: CameraConfig,
    /// Estimated mounting body → camera.
    pub mounting: Mounting,
}

/// Settings of the navigation core (recorded in sensor logs as TOML, `io::sensor_log`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavConfig {
    /// The INS.
    pub ins: InsConfig,
    /// When to start and re-initialise the INS.
    pub start: StartPolicy,
    /// The down-looking camera, if one is fitted: the visual navigation runs on its frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<NavCamera>,
    /// The visual navigation's settings (used with a camera). Always written, so that a log
    /// records what its flight ran with; logs from before it take the defaults.
    #[serde(default)]
    pub vision: VnsConfig,
    /// Visual systems run beside `vision` on the same frames (with a camera), for comparison
    /// only: their poses are reported ([`Navigator::visual_systems`]), never fused.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub compared_vision: Vec<ComparedVision>,
    /// The time contract's reorder window, µs: a frame taken more than this before the newest
    /// IMU sample is rejected and counted (`frames_late`); one within it is navigated with the
    /// INS pose at its own time (the pose history spans [`POSE_HISTORY_US`]).
    #[serde(default = "default_reorder_window_us")]
    pub reorder_window_us: u64,
    /// Run the visual navigation away from the IMU path: a frame becomes a [`VisionTask`]
    /// that the driver runs (on a worker thread) and hands back with [`Navigator::apply_vision`],
    /// which returns the [`SensorEvent::VisionApplied`] marker the driver records; frames that
    /// come while a task is out are dropped and counted (`frames_vision_busy`). A replay applies
    /// each result where its marker stands, so it reproduces the solutions bit for bit. Off (the
    /// simulator, the Monte Carlo): each frame is navigated when it is pushed.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub vision_deferred: bool,
    /// Where no height over the terrain is measured (a daemon without a rangefinder or a
    /// terrain model): the ground taken as flat at this height, so that a frame's height over
    /// it is the INS's height at the frame less this. The visual navigation needs that height
    /// to start (`x̊₀`); a measured one, fresher than [`MAX_HEIGHT_AGE_US`], is preferred.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flat_terrain: Option<FlatTerrain>,
    /// Publish the visual horizontal position after the GNSS loss ([`fusion`]); without it
    /// (the paper's evaluation, the simulator) the fused position is the INS's and the visual
    /// fix is only reported beside it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fusion: Option<FusionConfig>,
    /// Start a visual system over after a long loss or a gap in the frames, from the fused
    /// pose (beyond the paper, whose VNS never restarts; docs/FUSION.md). Without it (the
    /// paper's evaluation, the simulator) a lost system relocalises for ever.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vision_restart: Option<VisionRestart>,
}

/// Flat ground at a known height ([`NavConfig::flat_terrain`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlatTerrain {
    /// Height of the ground above the WGS84 ellipsoid, m.
    pub h_m: f64,
    /// Its standard deviation, m (the visual navigation's scale error; the paper's 50 m).
    pub sigma_m: f64,
}

fn default_reorder_window_us() -> u64 {
    1_000_000
}

impl NavConfig {
    /// The INS `ins` started by the default rules with the magnetic model of
    /// `mag_decimal_year`, without a camera.
    pub fn new(ins: InsConfig, mag_decimal_year: f64) -> Self {
        Self {
            ins,
            start: StartPolicy::new(mag_decimal_year),
            camera: None,
            vision: VnsConfig::default(),
            compared_vision: Vec::new(),
            reorder_window_us: default_reorder_window_us(),
            vision_deferred: false,
            flat_terrain: None,
            fusion: None,
            vision_restart: None,
        }
    }
}

/// Counters of the navigator (the INS keeps its own, see [`Navigator::ins_stats`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NavigatorStats {
    /// Events dropped because the INS was not initialised yet.
    pub events_before_init: u64,
    /// Camera frames received within the reorder window.
    pub frames: u64,
    /// Camera frames older than the reorder window, rejected.
    pub frames_late: u64,
    /// Camera frames the visual navigation rejected (size, buffer, time order).
    pub frames_rejected: u64,
    /// Camera frames dropped because the previous one's deferred vision had not come back
    /// ([`NavConfig::vision_deferred`]).
    pub frames_vision_busy: u64,
    /// Deferred vision results that did not belong to the task out (ignored), or markers in a
    /// replayed stream without a result to apply.
    pub vision_results_unmatched: u64,
    /// Heights over the terrain rejected (non-finite, not positive).
    pub heights_rejected: u64,
    /// (Re)initialisations.
    pub initialisations: u64,
    /// Starts the INS refused (an invalid initial state).
    pub starts_refused: u64,
    /// Fixes that could have started the INS but came without an attitude at their time.
    pub start_fixes_without_attitude: u64,
    /// Times the IMU was found noisier than configured, or [`IMU_NOISE_ESCALATION`] times
    /// noisier than at the last report (see [`Navigator::imu_noise`]).
    pub imu_noisier_than_configured: u64,
    /// Times the INS adopted the IMU's measured noise (`[ins.imu_noise] adopt`).
    pub imu_noise_adoptions: u64,
    /// ... of which a measured value was above its ceiling (the ceiling was adopted).
    pub imu_noise_capped: u64,
    /// Visual fixes taken into the fused position ([`NavConfig::fusion`]).
    pub fused_vision_fixes: u64,
    /// Visual fixes without an INS pose at their exposure, not fused.
    pub vision_fixes_without_ins_pose: u64,
    /// Changes of the fused horizontal source (each moves the reset counter).
    pub horizontal_source_changes: u64,
    /// Restarts of the navigating visual system ([`NavConfig::vision_restart`]).
    pub vision_restarts: u64,
    /// Frames that waited for the INS to reach their exposure and were replaced by a newer
    /// one before it did (the IMU stalled), dropped.
    pub frames_replaced_waiting: u64,
}

/// The navigation core.
#[derive(Debug, Clone)]
pub struct Navigator {
    cfg: NavConfig,
    ins: Option<Ins>,
    /// The INS's latest solution (the GNSS-return re-initialisation starts from it).
    last: Option<InsSolution>,
    /// The INS poses of the last [`POSE_HISTORY_US`].
    history: PoseHistory,
    start: StartState,
    last_start: Option<StartRecord>,
    /// Aiding samples since the latest IMU sample: a new INS takes them, so that a start
    /// fuses what was measured at its first step.
    since_imu: Vec<SensorEvent>,
    stats: NavigatorStats,
    reset_counter: u8,
    imu_noise: ImuNoiseMonitor,
    imu_noisy: bool,
    /// The worst ratio when the IMU was last reported noisier than configured.
    imu_noisy_ratio: f64,
    /// The INS configuration in use: the configured one with the adopted IMU noise.
    ins_cfg: InsConfig,
    /// The IMU noise model in use when the aircraft began to fly (`None` on the ground).
    imu_model_at_takeoff: Option<ImuNoiseModel>,
    /// The visual navigation systems (with a camera; out with a [`VisionTask`] while their
    /// deferred frame runs).
    visual: Option<Box<VisualSystems>>,
    /// The deferred frame's task, until the driver takes it.
    vision_task: Option<VisionTask>,
    /// Exposure time of the deferred frame whose systems are out, µs.
    vision_out_t_us: Option<u64>,
    /// The navigating system's state and pose after its latest frame (kept while the systems
    /// are out).
    vision_status: VisionStatus,
    vision_fix: Option<VisionFix>,
    /// The latest height over the terrain.
    h_agl: Option<HeightAboveTerrain>,
    fusion: Fusion,
    /// A frame newer than the newest INS solution, until one reaches its exposure.
    waiting_frame: Option<Frame>,
}

/// The height over the terrain at a frame: the measured one if fresh, else the INS's height
/// over the flat terrain (when configured and the INS pose at the frame is known, and the
/// aircraft is above it).
fn height_at_frame(
    t_us: u64,
    measured: Option<HeightAboveTerrain>,
    flat: Option<FlatTerrain>,
    history: &PoseHistory,
) -> Option<HeightAboveTerrain> {
    let fresh = measured.filter(|h| t_us.abs_diff(h.t_us) <= MAX_HEIGHT_AGE_US);
    fresh.or_else(|| {
        let ground = flat?;
        let pose = history.at(t_us)?;
        Some(HeightAboveTerrain {
            t_us,
            h_agl_m: pose.pos.h_m - ground.h_m,
            sigma_m: ground.sigma_m,
        })
        .filter(|h| h.h_agl_m > 0.0)
    })
}

/// A noisy IMU is reported again when its worst ratio grows by this factor.
pub const IMU_NOISE_ESCALATION: f64 = 2.0;

impl Navigator {
    /// A navigator waiting for its first start. Fails on an invalid configuration.
    pub fn new(cfg: &NavConfig) -> Result<Self, NavError> {
        cfg.ins.validate().map_err(InsError::from)?;
        // Checked with or without a camera: the settings are recorded either way.
        cfg.vision.validate().map_err(VnsError::from)?;
        if let Some(g) = cfg.flat_terrain
            && !(g.h_m.is_finite() && g.sigma_m.is_finite() && g.sigma_m >= 0.0)
        {
            return Err(NavError::FlatTerrain(g.h_m, g.sigma_m));
        }
        vision::validate_compared(&cfg.compared_vision)?;
        if let Some(f) = &cfg.fusion {
            f.validate()?;
        }
        let visual = match &cfg.camera {
            Some(c) => Some(Box::new(VisualSystems::new(
                c,
                &cfg.vision,
                &cfg.compared_vision,
                cfg.vision_restart,
            )?)),
            None => None,
        };
        Ok(Self {
            cfg: cfg.clone(),
            ins: None,
            last: None,
            history: PoseHistory::new(POSE_HISTORY_US),
            start: StartState::default(),
            last_start: None,
            since_imu: Vec::with_capacity(4),
            stats: NavigatorStats::default(),
            reset_counter: 0,
            imu_noise: ImuNoiseMonitor::default(),
            imu_noisy: false,
            imu_noisy_ratio: 0.0,
            ins_cfg: cfg.ins.clone(),
            imu_model_at_takeoff: None,
            vision_status: visual
                .as_ref()
                .map_or(VisionStatus::INACTIVE, |v| *v.status()),
            vision_fix: None,
            visual,
            vision_task: None,
            vision_out_t_us: None,
            h_agl: None,
            fusion: Fusion::default(),
            waiting_frame: None,
        })
    }

    /// (Re)start the INS from `init` now, outside the start rules (tests and tools; drivers
    /// feed events and let [`policy`] decide). A failed initialisation leaves the previous
    /// state.
    pub fn initialise(&mut self, init: &InsInit) -> Result<(), InsError> {
        let ins = Ins::new(&self.ins_cfg, init)?;
        if self.ins.is_some() {
            self.reset_counter = self.reset_counter.wrapping_add(1);
        }
        self.ins = Some(ins);
        self.last = None;
        self.history.clear();
        self.fusion.ins_restarted();
        self.stats.initialisations += 1;
        Ok(())
    }

    /// Whether the INS has been started.
    pub fn is_initialised(&self) -> bool {
        self.ins.is_some()
    }

    /// The latest (re)start made by the rules.
    pub fn last_start(&self) -> Option<&StartRecord> {
        self.last_start.as_ref()
    }

    /// The INS pose at `t_us` (a frame's exposure), interpolated in the history of the last
    /// [`POSE_HISTORY_US`]; `None` outside it.
    pub fn ins_pose_at(&self, t_us: u64) -> Option<HistoryPose> {
        self.history.at(t_us)
    }

    /// Whether the INS is in GNSS-denied mode.
    pub fn gnss_denied(&self) -> bool {
        self.ins.as_ref().is_some_and(Ins::gnss_denied)
    }

    /// The GNSS-denied covariance budget at the loss ([`Ins::denied_budget`]).
    pub fn denied_budget(&self) -> Option<&crate::ins::DeniedBudget> {
        self.ins.as_ref().and_then(Ins::denied_budget)
    }

    /// Feed one event; an accepted IMU sample returns the solution at its time.
    pub fn push(&mut self, event: &SensorEvent) -> Option<NavSolution> {
        match event {
            SensorEvent::Frame(f) => {
                let newest = self.history.newest_t_us();
                if newest.is_some_and(|t| f.t_us.saturating_add(self.cfg.reorder_window_us) < t) {
                    self.stats.frames_late += 1;
                    return None;
                }
                self.stats.frames += 1;
                // The frame needs the INS pose at its exposure: until a solution at or after
                // it exists (a driver may push a frame just before the IMU sample of its own
                // instant), it waits.
                if self.history.newest_t_us().is_some_and(|t| t >= f.t_us) {
                    self.navigate_frame(f);
                } else if self.waiting_frame.replace(f.clone()).is_some() {
                    self.stats.frames_replaced_waiting += 1;
                }
            }
            SensorEvent::VisionApplied(_) => {
                // A marker reaches here only without its result (a replay driver hands results
                // back with `apply_vision`).
                self.stats.vision_results_unmatched += 1;
                return None;
            }
            SensorEvent::HeightAboveTerrain(h) => {
                if h.h_agl_m.is_finite() && h.h_agl_m > 0.0 && h.sigma_m.is_finite() {
                    self.h_agl = Some(*h);
                } else {
                    self.stats.heights_rejected += 1;
                }
                return None;
            }
            SensorEvent::Imu(s) => self.check_imu_noise(s),
            SensorEvent::Air(a)
                if self.imu_model_at_takeoff.is_none()
                    && a.tas_mps.is_finite()
                    && a.tas_mps > self.cfg.ins.imu_noise.flying_tas_mps =>
            {
                self.imu_model_at_takeoff = Some(ImuNoiseModel::from_config(&self.ins_cfg));
            }
            _ => {}
        }
        let running = self.ins.as_ref().map(|ins| Running {
            gnss_denied: ins.gnss_denied(),
            last: self.last.as_ref(),
        });
        let start = self.start.observe(&self.cfg.start, event, running);
        self.stats.start_fixes_without_attitude = self.start.fixes_without_attitude;
        if let Some((record, init)) = start {
            self.start_at(record, &init);
        }
        match event {
            SensorEvent::Alignment(_) => return None,
            SensorEvent::Air(_) | SensorEvent::Mag(_) | SensorEvent::RefAttitude(_) => {
                self.since_imu.push(event.clone());
            }
            SensorEvent::Imu(_) => self.since_imu.clear(),
            SensorEvent::Gnss(_)
            | SensorEvent::Frame(_)
            | SensorEvent::HeightAboveTerrain(_)
            | SensorEvent::VisionApplied(_) => {}
        }
        let Some(ins) = self.ins.as_mut() else {
            self.stats.events_before_init += 1;
            return None;
        };
        let sol = ins.push(event)?;
        self.last = Some(sol);
        self.history.push(HistoryPose {
            t_us: sol.t_us,
            pos: sol.pos,
            v_ned_mps: sol.v_ned_mps,
            q_nb: sol.q_nb,
        });
        if let Some(frame) = self.waiting_frame.take_if(|f| f.t_us <= sol.t_us) {
            self.navigate_frame(&frame);
        }
        let mut nav = NavSolution::from_ins(sol, self.reset_counter);
        nav.vision = *self.vision();
        nav.vision_fix = self.vision_fix().copied();
        if let Some(cfg) = &self.cfg.fusion {
            if self.fusion.fuse(cfg, &mut nav, &self.history) {
                self.reset_counter = self.reset_counter.wrapping_add(1);
                self.stats.horizontal_source_changes += 1;
                nav.reset_counter = self.reset_counter;
            }
            self.stats.fused_vision_fixes = self.fusion.fixes;
            self.stats.vision_fixes_without_ins_pose = self.fusion.fixes_without_ins;
        }
        Some(nav)
    }

    /// Run the visual systems on a frame, or (deferred) hand them out with it.
    fn navigate_frame(&mut self, frame: &Frame) {
        if self.cfg.camera.is_none() {
            return;
        }
        let Some(visual) = self.visual.as_mut() else {
            self.stats.frames_vision_busy += 1;
            return;
        };
        let h_agl = height_at_frame(frame.t_us, self.h_agl, self.cfg.flat_terrain, &self.history);
        let denied = self.ins.as_ref().is_some_and(Ins::gnss_denied);
        let offset = self.fusion.start_offset_ne_m(denied);
        let job = visual.job(frame, &self.history, h_agl.as_ref(), offset.as_ref());
        if self.cfg.vision_deferred {
            if let Some(systems) = self.visual.take() {
                self.vision_out_t_us = Some(frame.t_us);
                self.vision_task = Some(VisionTask::new(job, systems));
            }
        } else {
            if visual.run(&job).is_err() {
                self.stats.frames_rejected += 1;
            }
            self.vision_status = *visual.status();
            self.vision_fix = visual.fix().copied();
            self.stats.vision_restarts = visual.restarts();
        }
    }

    /// The deferred frame's visual navigation, to run away from the IMU path
    /// ([`NavConfig::vision_deferred`]); `None` when no frame waits.
    pub fn take_vision_task(&mut self) -> Option<VisionTask> {
        self.vision_task.take()
    }

    /// Hand back a finished task at this point of the event stream: the solutions from here on
    /// carry its result. Returns the marker to record with the events
    /// ([`SensorEvent::VisionApplied`]), or `None` (counted `vision_results_unmatched`, the
    /// result dropped) when it is not the task that is out.
    pub fn apply_vision(&mut self, done: VisionDone) -> Option<SensorEvent> {
        if self.visual.is_some() || self.vision_out_t_us != Some(done.frame_t_us()) {
            self.stats.vision_results_unmatched += 1;
            return None;
        }
        self.vision_out_t_us = None;
        if done.refused {
            self.stats.frames_rejected += 1;
        }
        let t_us = done.frame_t_us();
        self.vision_status = *done.systems.status();
        self.vision_fix = done.systems.fix().copied();
        self.stats.vision_restarts = done.systems.restarts();
        self.visual = Some(done.systems);
        Some(SensorEvent::VisionApplied(VisionApplied { t_us }))
    }

    /// Whether a deferred frame's visual systems are out (taken or not yet taken).
    pub fn vision_out(&self) -> bool {
        self.vision_out_t_us.is_some()
    }

    /// The visual navigation's state and latest frame.
    pub fn vision(&self) -> &VisionStatus {
        &self.vision_status
    }

    /// The visual navigation's latest pose (while it tracks).
    pub fn vision_fix(&self) -> Option<&VisionFix> {
        self.vision_fix.as_ref()
    }

    /// Every visual system (with a camera; none while a deferred frame has them out): the
    /// configured one first (`name` `None`), then the
    /// compared ones in their configured order.
    pub fn visual_systems(&self) -> impl Iterator<Item = VisualSystemView<'_>> {
        self.visual.iter().flat_map(|v| v.views())
    }

    /// Counters of the visual navigation (with a camera; `None` while a deferred frame has
    /// the systems out).
    pub fn vns_counters(&self) -> Option<&VnsCounters> {
        self.visual.as_ref().map(|v| v.counters())
    }

    /// Counters of the IA-VNS's steps (with a camera and any of them switched on; `None` while
    /// a deferred frame has the systems out).
    pub fn aiding_counters(&self) -> Option<&crate::vision::vns::AidingCounters> {
        self.visual.as_ref().and_then(|v| v.aiding_counters())
    }

    fn start_at(&mut self, record: StartRecord, init: &InsInit) {
        if self.initialise(init).is_err() {
            self.stats.starts_refused += 1;
            return;
        }
        self.last_start = Some(record);
        if let Some(ins) = self.ins.as_mut() {
            for event in &self.since_imu {
                ins.push(event);
            }
        }
    }
    /// The IMU's measured white noise against the configuration (`None` until ~5 s of IMU).
    pub fn imu_noise(&self) -> Option<ImuNoise> {
        self.imu_noise.noise(&self.ins_cfg)
    }

    /// The IMU noise the INS uses: the configured model, or the one adopted from the
    /// measurement ([`NavigatorStats::imu_noise_adoptions`]).
    pub fn imu_noise_model(&self) -> ImuNoiseModel {
        ImuNoiseModel::from_config(&self.ins_cfg)
    }

    /// Whether the IMU is currently noisier than configured (ratio over
    /// [`NOISY_RATIO`], until it falls under [`QUIET_RATIO`]).
    pub fn imu_noisier_than_configured(&self) -> bool {
        self.imu_noisy
    }

    fn check_imu_noise(&mut self, s: &crate::sensors::ImuSample) {
        // The estimate changes only when a window closes.
        if !self.imu_noise.push(s) {
            return;
        }
        let Some(mut n) = self.imu_noise() else {
            return;
        };
        let policy = &self.cfg.ins.imu_noise;
        if policy.adopt
            && let Some(a) = ImuNoiseModel::from_config(&self.ins_cfg).adopted(
                &n,
                self.ins_cfg.reference_period_s,
                self.imu_model_at_takeoff.as_ref(),
                policy,
            )
        {
            a.model.apply_to(&mut self.ins_cfg);
            if let Some(ins) = self.ins.as_mut() {
                ins.set_imu_noise(&a.model);
            }
            self.stats.imu_noise_adoptions += 1;
            self.stats.imu_noise_capped += u64::from(a.capped);
            // The ratios against the model now in use (a capped one stays reported).
            n = self.imu_noise().unwrap_or(n);
        }
        let worst = n.gyro_ratio.max(n.accel_ratio);
        // Reported again when it doubles: the first report often comes on the ground, before
        // the motor and the airflow add their vibration (PX4 SIH: ×80 disarmed, ×4000 flying).
        let escalated = self.imu_noisy && worst > IMU_NOISE_ESCALATION * self.imu_noisy_ratio;
        if (!self.imu_noisy && worst > NOISY_RATIO) || escalated {
            self.imu_noisy = true;
            self.imu_noisy_ratio = worst;
            self.stats.imu_noisier_than_configured += 1;
        } else if self.imu_noisy && worst < QUIET_RATIO {
            self.imu_noisy = false;
        }
    }

    /// The configuration.
    pub fn config(&self) -> &NavConfig {
        &self.cfg
    }

    /// Counters of the navigator.
    pub fn stats(&self) -> &NavigatorStats {
        &self.stats
    }

    /// Counters of the INS (`None` before the initialisation).
    pub fn ins_stats(&self) -> Option<&crate::ins::InsStats> {
        self.ins.as_ref().map(Ins::stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::wgs84::Geodetic;
    use crate::sensors::{AirSample, ImuSample};
    use nalgebra::{UnitQuaternion, Vector3};

    fn init() -> InsInit {
        let pos = Geodetic {
            lat_rad: 0.7,
            lon_rad: -1.5,
            h_m: 1_000.0,
        };
        InsInit::new(
            UnitQuaternion::identity(),
            pos,
            Vector3::new(30.0, 0.0, 0.0),
            2026.5,
        )
    }

    fn air(t_us: u64) -> SensorEvent {
        SensorEvent::Air(AirSample {
            t_us,
            tas_mps: 30.0,
            aoa_rad: Some(0.05),
            aos_rad: Some(0.0),
            p_pa: 89_874.0,
            temp_k: 281.65,
        })
    }

    fn imu(t_us: u64) -> SensorEvent {
        SensorEvent::Imu(ImuSample {
            t_us,
            gyro_rps: Vector3::zeros(),
            accel_mps2: Vector3::new(0.0, 0.0, -9.8),
        })
    }

    #[test]
    fn events_before_the_initialisation_are_counted_and_resets_are_numbered() {
        let mut nav = Navigator::new(&NavConfig::new(InsConfig::default(), 2026.5)).unwrap();
        assert!(nav.push(&imu(0)).is_none());
        assert_eq!(nav.stats().events_before_init, 1);
        nav.initialise(&init()).unwrap();
        assert!(nav.push(&air(5_000)).is_none());
        let first = nav.push(&imu(10_000)).expect("solution after air + IMU");
        assert_eq!(
            (first.reset_counter, first.vision.state, first.vision_fix),
            (0, VisionState::Inactive, None)
        );
        let next = nav.push(&imu(20_000)).expect("solution");
        assert_eq!(next.ins.t_us, 20_000);
        nav.initialise(&init()).unwrap();
        nav.push(&air(25_000));
        assert_eq!(nav.push(&imu(30_000)).unwrap().reset_counter, 1);
        assert_eq!(nav.stats().initialisations, 2);
    }

    /// The rules start the INS at the fix; the air sample of the same instant, received before
    /// the fix, reaches the new INS, so the IMU sample of that instant already steps it.
    #[test]
    fn a_start_fuses_the_aiding_samples_of_its_instant() {
        let mut nav = Navigator::new(&NavConfig::new(InsConfig::default(), 2026.5)).unwrap();
        for k in 0..100 {
            assert!(nav.push(&imu(k * 10_000)).is_none());
        }
        let t_us = 1_000_000;
        let i = init();
        nav.push(&air(t_us));
        nav.push(&SensorEvent::RefAttitude(crate::sensors::RefAttitude {
            t_us,
            q_nb: i.q_nb,
        }));
        assert!(!nav.is_initialised());
        nav.push(&SensorEvent::Gnss(crate::sensors::GnssFix {
            t_us,
            pos: i.pos,
            v_ned_mps: i.v_ned_mps,
            sigma_hor_m: 2.0,
            sigma_ver_m: 4.0,
            sigma_vel_mps: 0.1,
        }));
        assert_eq!(nav.last_start().map(|s| s.kind), Some(StartKind::First));
        let sol = nav.push(&imu(t_us)).expect("stepped at the fix's instant");
        assert_eq!((sol.t_us, sol.reset_counter), (t_us, 0));
        let ins = nav.ins_stats().unwrap();
        assert_eq!((ins.air.accepted, ins.gnss.accepted), (1, 1));
        assert_eq!(nav.stats().events_before_init, 102);
    }

    /// A non-finite or non-positive height over the terrain is counted and dropped; without a
    /// camera frames are counted and the vision stays inactive.
    #[test]
    fn bad_heights_over_the_terrain_are_rejected() {
        let mut nav = Navigator::new(&NavConfig::new(InsConfig::default(), 2026.5)).unwrap();
        for h_agl_m in [f64::NAN, -5.0, 0.0, 2_500.0] {
            nav.push(&SensorEvent::HeightAboveTerrain(HeightAboveTerrain {
                t_us: 1_000,
                h_agl_m,
                sigma_m: 50.0,
            }));
        }
        assert_eq!(nav.stats().heights_rejected, 3);
        assert_eq!(nav.h_agl.map(|h| h.h_agl_m), Some(2_500.0));
        nav.push(&SensorEvent::Frame(Frame {
            t_us: 2_000,
            width: 4,
            height: 4,
            pixels: std::sync::Arc::from(vec![0_u8; 16]),
        }));
        assert_eq!(nav.stats().frames, 1);
        assert_eq!(nav.vision().state, VisionState::Inactive);
        assert!(nav.vns_counters().is_none());
    }

    #[test]
    fn a_frame_takes_a_fresh_measured_height_else_the_flat_terrains() {
        let mut history = PoseHistory::new(POSE_HISTORY_US);
        for t_us in [1_000_000, 1_010_000] {
            history.push(HistoryPose {
                t_us,
                pos: crate::math::wgs84::Geodetic {
                    lat_rad: 0.7,
                    lon_rad: 0.1,
                    h_m: 2_700.0,
                },
                v_ned_mps: Vector3::zeros(),
                q_nb: UnitQuaternion::identity(),
            });
        }
        let measured = |t_us| HeightAboveTerrain {
            t_us,
            h_agl_m: 2_400.0,
            sigma_m: 10.0,
        };
        let flat = FlatTerrain {
            h_m: 200.0,
            sigma_m: 50.0,
        };
        let at = |m, f| height_at_frame(1_005_000, m, f, &history).map(|h| (h.h_agl_m, h.sigma_m));
        assert_eq!(
            at(Some(measured(1_000_000)), Some(flat)),
            Some((2_400.0, 10.0))
        );
        // Measured 2 s before the frame: stale, the flat terrain's.
        assert_eq!(
            at(Some(measured(3_005_000)), Some(flat)),
            Some((2_500.0, 50.0))
        );
        assert_eq!(at(Some(measured(3_005_000)), None), None);
        assert_eq!(at(None, None), None);
        // Below the ground, or no INS pose at the frame: none.
        let deep = FlatTerrain {
            h_m: 3_000.0,
            ..flat
        };
        assert_eq!(at(None, Some(deep)), None);
        assert_eq!(height_at_frame(9_000_000, None, Some(flat), &history), None);
        // Refused settings.
        let mut cfg = NavConfig::new(InsConfig::default(), 2026.5);
        cfg.flat_terrain = Some(FlatTerrain {
            h_m: f64::NAN,
            ..flat
        });
        assert!(matches!(
            Navigator::new(&cfg),
            Err(NavError::FlatTerrain(..))
        ));
    }

    #[test]
    fn a_bad_initialisation_keeps_the_running_ins() {
        let mut nav = Navigator::new(&NavConfig::new(InsConfig::default(), 2026.5)).unwrap();
        nav.initialise(&init()).unwrap();
        let mut bad = init();
        bad.pos.h_m = f64::NAN;
        assert!(nav.initialise(&bad).is_err());
        assert!(nav.is_initialised());
        assert_eq!(nav.stats().initialisations, 1);
    }

    /// Feeds sample `k` (100 Hz) of a still IMU whose gyro has deterministic ±σ noise (a
    /// pseudo-random sign per axis: white enough for the second differences).
    fn noisy_gyro(seed: u64) -> impl FnMut(&mut Navigator, u64, f64) {
        let mut state = seed;
        let mut sign = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            if state & 1 == 0 { 1.0 } else { -1.0 }
        };
        move |nav, k, sigma| {
            let gyro_rps = Vector3::new(sign(), sign(), sign()) * sigma;
            nav.push(&SensorEvent::Imu(ImuSample {
                t_us: k * 10_000,
                gyro_rps,
                accel_mps2: Vector3::new(0.0, 0.0, -9.81),
            }));
        }
    }

    /// An IMU first a little, then much noisier than configured (ground, then flight): one
    /// report, then one more when the ratio has doubled; none while it stays there.
    #[test]
    fn a_noisy_imu_is_reported_and_reported_again_when_it_gets_worse() {
        let mut cfg = InsConfig::default();
        cfg.imu_noise.adopt = false;
        let mut nav = Navigator::new(&NavConfig::new(cfg.clone(), 2026.5)).unwrap();
        let r_gyro = cfg.attitude.r_gyro_rad2ps2;
        let mut push = noisy_gyro(0x2545_f491_4f6c_dd1d);
        // 40 s at ×10 of the configured variance, 40 s at ×1000.
        for k in 0..4_000 {
            push(&mut nav, k, (10.0 * r_gyro).sqrt());
        }
        assert!(nav.imu_noisier_than_configured());
        assert_eq!(nav.stats().imu_noisier_than_configured, 1);
        let n = nav.imu_noise().unwrap();
        assert!((n.gyro_ratio / 10.0 - 1.0).abs() < 0.1, "{n:?}");
        for k in 4_000..8_000 {
            push(&mut nav, k, (1000.0 * r_gyro).sqrt());
        }
        assert_eq!(nav.stats().imu_noisier_than_configured, 2);
        assert!((nav.imu_noise().unwrap().gyro_ratio / 1000.0 - 1.0).abs() < 0.1);
        // The events count as received before the initialisation, as any other.
        assert_eq!(nav.stats().events_before_init, 8_000);
        assert_eq!(nav.stats().imu_noise_adoptions, 0);
        assert_eq!(nav.imu_noise_model(), ImuNoiseModel::from_config(&cfg));
    }

    /// Adoption: on the ground the measured noise replaces the configured one, in the running
    /// INS too; in flight it may grow up to `max_flight_growth` × the take-off model, beyond
    /// which the ceiling is adopted and the IMU stays reported.
    #[test]
    fn the_measured_imu_noise_is_adopted_on_the_ground_and_bounded_in_flight() {
        let cfg = InsConfig::default();
        let policy = cfg.imu_noise.clone();
        let mut nav = Navigator::new(&NavConfig::new(cfg.clone(), 2026.5)).unwrap();
        nav.initialise(&init()).unwrap();
        let configured = ImuNoiseModel::from_config(&cfg);
        let mut push_sigma = noisy_gyro(0x9e37_79b9_7f4a_7c15);
        let mut push = |nav: &mut Navigator, k: u64, gyro_factor: f64| {
            push_sigma(nav, k, (gyro_factor * configured.r_gyro_rad2ps2).sqrt());
        };
        // On the ground, ×10 the configured gyro variance: adopted, not reported.
        for k in 0..4_000 {
            push(&mut nav, k, 10.0);
        }
        let ground = nav.imu_noise_model();
        assert_eq!(nav.stats().imu_noise_adoptions, 1);
        assert!((ground.r_gyro_rad2ps2 / configured.r_gyro_rad2ps2 / 10.0 - 1.0).abs() < 0.1);
        // The body-rate Q̃ keeps its ratio to the gyro R (the same lag).
        let lag_ratio = |m: &ImuNoiseModel| m.q_w_nb_rad2ps2 / m.r_gyro_rad2ps2;
        assert!((lag_ratio(&ground) / lag_ratio(&configured) - 1.0).abs() < 1e-12);
        assert_eq!(
            nav.ins.as_ref().unwrap().config().attitude.r_gyro_rad2ps2,
            ground.r_gyro_rad2ps2
        );
        assert!(!nav.imu_noisier_than_configured());
        assert_eq!(nav.stats().imu_noisier_than_configured, 0);
        // Take-off, then ×5000 the configured (×500 the ground model): capped at ×100 the
        // take-off model, and reported (×5 over what is in use).
        let air = |t_us| {
            SensorEvent::Air(AirSample {
                t_us,
                tas_mps: 25.0,
                aoa_rad: None,
                aos_rad: None,
                p_pa: 90_000.0,
                temp_k: 280.0,
            })
        };
        nav.push(&air(40_000_005));
        for k in 4_000..8_000 {
            push(&mut nav, k, 5000.0);
        }
        let flight = nav.imu_noise_model();
        assert_eq!(
            flight.r_gyro_rad2ps2,
            policy.max_flight_growth * ground.r_gyro_rad2ps2
        );
        assert!(nav.stats().imu_noise_capped >= 1);
        assert!(nav.imu_noisier_than_configured());
        let r = nav.imu_noise().unwrap().gyro_ratio;
        assert!((r / 5.0 - 1.0).abs() < 0.15, "{r}");
        // The accelerometer held still: nothing adopted for it.
        assert_eq!(flight.q_velocity_m2ps2, configured.q_velocity_m2ps2);
        assert_eq!(flight.r_accel_white_m2ps4, configured.r_accel_white_m2ps4);
        // A re-initialised INS starts with the model in use.
        nav.initialise(&init()).unwrap();
        assert_eq!(
            nav.ins.as_ref().unwrap().config().attitude.r_gyro_rad2ps2,
            flight.r_gyro_rad2ps2
        );
    }

    #[test]
    fn the_vision_settings_are_used_and_bad_ones_refused_at_construction() {
        let camera = NavCamera {
            intrinsics: CameraConfig::default(),
            mounting: Mounting {
                q_bc: UnitQuaternion::identity(),
                t_rc_b_m: Vector3::zeros(),
            },
        };
        let mut cfg = NavConfig::new(InsConfig::default(), 2026.5);
        cfg.vision.pose.max_iterations = 5;
        for with_camera in [false, true] {
            cfg.camera = with_camera.then(|| camera.clone());
            let nav = Navigator::new(&cfg).unwrap();
            assert_eq!(nav.config().vision.pose.max_iterations, 5);
            assert_eq!(
                nav.visual.as_ref().map(|v| v.config().pose.max_iterations),
                with_camera.then_some(5)
            );
        }
        type Spoil = fn(&mut VnsConfig);
        let bad: [(&str, Spoil); 4] = [
            ("pose.tukey_k", |v| v.pose.tukey_k = f64::NAN),
            ("sparse_align.min_level", |v| {
                v.sparse_align.min_level = 3;
                v.sparse_align.max_level = 2;
            }),
            ("detector.cell_size_px", |v| v.detector.cell_size_px = 0),
            ("seed_keyframes", |v| v.seed_keyframes = 0),
        ];
        for with_camera in [false, true] {
            for (key, spoil) in bad {
                let mut cfg = cfg.clone();
                cfg.camera = with_camera.then(|| camera.clone());
                spoil(&mut cfg.vision);
                let err = Navigator::new(&cfg).expect_err(key);
                assert!(
                    matches!(err, NavError::Vision(VnsError::Config(_))),
                    "{key}: {err:?}"
                );
                assert!(
                    err.to_string().contains(&format!("vision.{key} =")),
                    "{err}"
                );
            }
        }
    }

    #[test]
    fn compared_systems_are_built_in_order_and_bad_ones_refused() {
        let mut cfg = NavConfig::new(InsConfig::default(), 2026.5);
        cfg.camera = Some(NavCamera {
            intrinsics: CameraConfig::default(),
            mounting: Mounting {
                q_bc: UnitQuaternion::identity(),
                t_rc_b_m: Vector3::zeros(),
            },
        });
        let compared = |name: &str| ComparedVision {
            name: name.to_owned(),
            vision: VnsConfig::default(),
        };
        cfg.compared_vision = vec![compared("vns"), compared("ia-vns")];
        let nav = Navigator::new(&cfg).unwrap();
        let names: Vec<Option<&str>> = nav.visual_systems().map(|v| v.name).collect();
        assert_eq!(names, [None, Some("vns"), Some("ia-vns")]);
        // Recorded in sensor logs: the TOML form reads back.
        let text = toml::to_string(&cfg).unwrap();
        assert_eq!(toml::from_str::<NavConfig>(&text).unwrap(), cfg);

        for name in ["", "a b", "a,b", "vns"] {
            let mut bad = cfg.clone();
            bad.compared_vision.push(compared(name));
            assert!(matches!(
                Navigator::new(&bad),
                Err(NavError::ComparedVision(ComparedVisionError::Name(n))) if n == name
            ));
        }
        let mut bad = cfg.clone();
        bad.compared_vision[1].vision.pose.tukey_k = f64::NAN;
        let err = Navigator::new(&bad).expect_err("NaN setting");
        assert!(err.to_string().contains("`ia-vns`"), "{err}");
        // Without a camera there is nothing to run them on.
        cfg.camera = None;
        assert_eq!(Navigator::new(&cfg).unwrap().visual_systems().count(), 0);
    }
}
