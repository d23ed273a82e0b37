//! The visual navigation systems the navigator runs on the camera's frames (paper, "IA-VNS flow
//! diagram"): the one whose pose the solution carries ([`NavConfig::vision`]), and any others
//! run beside it on the same frames for comparison ([`NavConfig::compared_vision`]: the VNS
//! beside the IA-VNS, the ablation's variants, docs/IAVNS.md). Every system reads the same INS
//! pose history and height over the terrain, and none reads another's output, so a system run
//! beside others gives what it gives alone, bit for bit.
//!
//! [`NavConfig::vision`]: super::NavConfig::vision
//! [`NavConfig::compared_vision`]: super::NavConfig::compared_vision

use nalgebra::{Isometry3, Vector2, Vector3};

use super::history::PoseHistory;
use super::solution::{VisionFix, VisionState, VisionStatus};
use super::{MAX_HEIGHT_AGE_US, NavCamera, NavError};
use crate::math::wgs84;
use crate::sensors::{Frame, HeightAboveTerrain};
use crate::vision::camera::Camera;
use crate::vision::vns::{
    AidingCounters, InertialFrame, Vns, VnsConfig, VnsConfigError, VnsCounters, VnsError,
    VnsOutput, VnsStart, VnsState,
};

/// Seed of the VNS's grid-cell order (any fixed value: the order only has to be arbitrary).
const VNS_CELL_ORDER_SEED: u64 = 0x5653_4f43_454c_4c53; // "VSOCELLS"

/// A visual navigation system run beside the navigating one on the same frames; its pose is
/// reported ([`VisualSystemView`]) and used for nothing else.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComparedVision {
    /// Its name in reports and run files (`vns`, `ia-vns`, …): unique, not empty, no spaces.
    pub name: String,
    /// Its settings.
    pub vision: VnsConfig,
}

/// Why the compared systems are refused.
#[derive(Debug, thiserror::Error)]
pub enum ComparedVisionError {
    /// A name is empty, repeated, or holds a space or a comma.
    #[error("compared_vision: the name `{0}` must be unique, not empty, without spaces or commas")]
    Name(String),
    /// A system's settings are invalid.
    #[error("compared_vision `{name}`: {source}")]
    Settings {
        /// The system.
        name: String,
        /// What is wrong.
        source: VnsConfigError,
    },
}

/// Check the compared systems' names and settings.
pub(super) fn validate_compared(compared: &[ComparedVision]) -> Result<(), ComparedVisionError> {
    for (i, c) in compared.iter().enumerate() {
        let bad_name = c.name.is_empty()
            || c.name.chars().any(|ch| ch.is_whitespace() || ch == ',')
            || compared[..i].iter().any(|o| o.name == c.name);
        if bad_name {
            return Err(ComparedVisionError::Name(c.name.clone()));
        }
        c.vision
            .validate()
            .map_err(|source| ComparedVisionError::Settings {
                name: c.name.clone(),
                source,
            })?;
    }
    Ok(())
}

/// One visual navigation system and what it last produced.
#[derive(Debug, Clone)]
struct VisualSystem {
    vns: Vns,
    status: VisionStatus,
    fix: Option<VisionFix>,
    /// Exposure of the previous frame, µs.
    last_frame_us: Option<u64>,
    /// Exposure of the first frame of the current loss (relocalising), µs.
    lost_since_us: Option<u64>,
    /// Restarts made ([`VisionRestart`]).
    restarts: u64,
}

/// When the navigator starts a visual system over (beyond the paper, which never restarts;
/// [`super::NavConfig::vision_restart`]). The restart starts from the fused pose
/// (docs/FUSION.md "Losing vision and getting it back").
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VisionRestart {
    /// Relocalising for longer than this: start over, µs.
    pub after_lost_us: u64,
    /// A gap between two frames longer than this (a stalled stream, a camera back): start over
    /// rather than relocalise from a pose that far behind, µs.
    pub after_gap_us: u64,
}

impl Default for VisionRestart {
    fn default() -> Self {
        Self {
            after_lost_us: 3_000_000,
            after_gap_us: 1_000_000,
        }
    }
}

impl VisualSystem {
    fn new(camera: Camera, cfg: &VnsConfig) -> Result<Self, VnsError> {
        Ok(Self {
            vns: Vns::new(camera, cfg.clone(), VNS_CELL_ORDER_SEED)?,
            status: VisionStatus {
                state: VisionState::WaitingForStart,
                ..VisionStatus::INACTIVE
            },
            fix: None,
            last_frame_us: None,
            lost_since_us: None,
            restarts: 0,
        })
    }

    /// Start over if the restart rule says so before `t_us`'s frame.
    fn restart_if_due(&mut self, t_us: u64, rule: &VisionRestart) {
        let started = matches!(
            self.vns.state(),
            VnsState::Tracking | VnsState::Relocalising
        );
        let gap = self
            .last_frame_us
            .is_some_and(|t| t_us.saturating_sub(t) > rule.after_gap_us);
        let lost = self
            .lost_since_us
            .is_some_and(|t| t_us.saturating_sub(t) > rule.after_lost_us);
        if started && (gap || lost) {
            self.vns.restart();
            self.restarts += 1;
            self.lost_since_us = None;
            self.status.state = VisionState::WaitingForStart;
            self.fix = None;
        }
    }

    /// Run on one frame; `Err` when the frame was refused (size, buffer, time order).
    fn process(
        &mut self,
        frame: &Frame,
        start: Option<&VnsStart>,
        ins: Option<&InertialFrame>,
        zeta_bc: &Isometry3<f64>,
        restart: Option<&VisionRestart>,
    ) -> Result<(), VnsError> {
        if let Some(rule) = restart {
            self.restart_if_due(frame.t_us, rule);
        }
        let waiting = matches!(
            self.vns.state(),
            VnsState::WaitingForStart | VnsState::Initialising
        );
        let start = start.filter(|_| waiting);
        let ins = ins.filter(|_| self.vns.config().aiding.needs_ins());
        let out = self.vns.process(frame, start, ins)?;
        self.last_frame_us = Some(frame.t_us);
        match out {
            Some(out) => {
                self.status = vision_status(&out);
                self.fix = (out.state == VnsState::Tracking).then(|| body_fix(&out, zeta_bc));
            }
            None => {
                self.status.state = vision_state(self.vns.state());
                self.fix = None;
            }
        }
        self.lost_since_us = match self.vns.state() {
            VnsState::Relocalising => self.lost_since_us.or(Some(frame.t_us)),
            _ => None,
        };
        Ok(())
    }

    fn view<'a>(&'a self, name: Option<&'a str>) -> VisualSystemView<'a> {
        VisualSystemView {
            name,
            status: &self.status,
            fix: self.fix.as_ref(),
            counters: self.vns.counters(),
            aiding: self.vns.aiding_counters(),
            vns: &self.vns,
        }
    }
}

/// A visual system's state as its drivers read it.
#[derive(Debug, Clone, Copy)]
pub struct VisualSystemView<'a> {
    /// `None` for the navigating system ([`NavConfig::vision`](super::NavConfig::vision)),
    /// the compared system's name otherwise.
    pub name: Option<&'a str>,
    /// State and latest frame.
    pub status: &'a VisionStatus,
    /// Latest pose, while it tracks.
    pub fix: Option<&'a VisionFix>,
    /// Counters.
    pub counters: &'a VnsCounters,
    /// The IA-VNS's counters (any of its changes switched on).
    pub aiding: Option<&'a AidingCounters>,
    vns: &'a Vns,
}

impl<'a> VisualSystemView<'a> {
    /// While it tracks, its latest frame's exposure time and the pixels of the features its
    /// pose rests on ([`Vns::tracked_features`]).
    pub fn tracked_features(
        &self,
    ) -> Option<(u64, impl ExactSizeIterator<Item = Vector2<f64>> + 'a)> {
        self.vns.tracked_features()
    }
}

/// One frame and what the navigator knew of the INS at its time: all the visual systems read
/// of the navigator, so that they can run away from the IMU path ([`VisionTask`]).
#[derive(Debug, Clone)]
pub(super) struct VisionJob {
    frame: Frame,
    /// `x̊₀` at the frame, for a system waiting for its start.
    start: Option<VnsStart>,
    /// The INS at the frame, for the IA-VNS.
    ins: Option<InertialFrame>,
}

/// A frame's visual navigation taken out of a navigator whose vision is deferred
/// ([`NavConfig::vision_deferred`](super::NavConfig::vision_deferred)): the job and the visual
/// systems themselves, so that a worker thread can run it ([`VisionTask::run`]) while the
/// navigator goes on with the IMU. The navigator has no visual systems until the result comes
/// back ([`Navigator::apply_vision`](super::Navigator::apply_vision)).
#[derive(Debug, Clone)]
pub struct VisionTask {
    job: VisionJob,
    systems: Box<VisualSystems>,
}

impl VisionTask {
    pub(super) fn new(job: VisionJob, systems: Box<VisualSystems>) -> Self {
        Self { job, systems }
    }

    /// The frame's exposure time, µs.
    pub fn frame_t_us(&self) -> u64 {
        self.job.frame.t_us
    }

    /// Run the visual systems on the frame (the heavy part: tens of milliseconds).
    pub fn run(self) -> VisionDone {
        let Self { job, mut systems } = self;
        let refused = systems.run(&job).is_err();
        VisionDone {
            frame_t_us: job.frame.t_us,
            systems,
            refused,
        }
    }
}

/// A finished [`VisionTask`], to hand back to its navigator.
#[derive(Debug)]
pub struct VisionDone {
    frame_t_us: u64,
    pub(super) systems: Box<VisualSystems>,
    pub(super) refused: bool,
}

impl VisionDone {
    /// The frame's exposure time, µs.
    pub fn frame_t_us(&self) -> u64 {
        self.frame_t_us
    }
}

/// The systems of a navigator with a camera.
#[derive(Debug, Clone)]
pub(super) struct VisualSystems {
    /// The estimated camera mounting.
    zeta_bc: Isometry3<f64>,
    restart: Option<VisionRestart>,
    navigating: VisualSystem,
    compared: Vec<(String, VisualSystem)>,
}

impl VisualSystems {
    pub(super) fn new(
        camera: &NavCamera,
        vision: &VnsConfig,
        compared: &[ComparedVision],
        restart: Option<VisionRestart>,
    ) -> Result<Self, NavError> {
        let cam = Camera::from_config(&camera.intrinsics)?;
        // The CG is taken at the reference point: its offset (decimetres) is far below the
        // visual navigation's resolution at flight heights.
        let zeta_bc = camera.mounting.zeta_bc(&Vector3::zeros());
        let compared = compared
            .iter()
            .map(|c| Ok((c.name.clone(), VisualSystem::new(cam, &c.vision)?)))
            .collect::<Result<_, NavError>>()?;
        Ok(Self {
            zeta_bc,
            restart,
            navigating: VisualSystem::new(cam, vision)?,
            compared,
        })
    }

    /// What the systems need of the navigator for `frame`: the INS at its time, read now from
    /// the pose history (cheap; the systems may run later, on another thread). A start is
    /// moved by `start_offset_ne_m` (the fused position's offset from the INS, after the
    /// GNSS loss).
    pub(super) fn job(
        &self,
        frame: &Frame,
        history: &PoseHistory,
        h_agl: Option<&HeightAboveTerrain>,
        start_offset_ne_m: Option<&Vector2<f64>>,
    ) -> VisionJob {
        // Both are read whether or not a system needs them: each system takes what its state
        // and settings call for (`VisualSystem::process`), so the results do not change.
        VisionJob {
            frame: frame.clone(),
            start: start_at(frame.t_us, history, h_agl, &self.zeta_bc, start_offset_ne_m),
            ins: inertial_frame(frame.t_us, history, &self.zeta_bc),
        }
    }

    /// Run every system on the job's frame; `Err` when the navigating system refused it (the
    /// frame is the same for all, so the others refuse it too).
    pub(super) fn run(&mut self, job: &VisionJob) -> Result<(), VnsError> {
        let zeta_bc = self.zeta_bc;
        let (start, ins) = (job.start.as_ref(), job.ins.as_ref());
        let restart = self.restart.as_ref();
        for (_, system) in &mut self.compared {
            // A refused frame is counted once, by the navigating system below.
            let _ = system.process(&job.frame, start, ins, &zeta_bc, restart);
        }
        self.navigating
            .process(&job.frame, start, ins, &zeta_bc, restart)
    }

    /// The navigating system's state and latest frame.
    pub(super) fn status(&self) -> &VisionStatus {
        &self.navigating.status
    }

    /// The navigating system's latest pose (while it tracks).
    pub(super) fn fix(&self) -> Option<&VisionFix> {
        self.navigating.fix.as_ref()
    }

    /// The navigating system's settings.
    #[cfg(test)]
    pub(super) fn config(&self) -> &VnsConfig {
        self.navigating.vns.config()
    }

    /// The navigating system's restarts ([`VisionRestart`]).
    pub(super) fn restarts(&self) -> u64 {
        self.navigating.restarts
    }

    /// The navigating system's counters.
    pub(super) fn counters(&self) -> &VnsCounters {
        self.navigating.vns.counters()
    }

    /// The navigating system's IA-VNS counters.
    pub(super) fn aiding_counters(&self) -> Option<&AidingCounters> {
        self.navigating.vns.aiding_counters()
    }

    /// Every system: the navigating one first, then the compared ones in their order.
    pub(super) fn views(&self) -> impl Iterator<Item = VisualSystemView<'_>> {
        std::iter::once(self.navigating.view(None)).chain(
            self.compared
                .iter()
                .map(|(name, s)| s.view(Some(name.as_str()))),
        )
    }
}

/// The INS at `t_us` as the IA-VNS reads it.
fn inertial_frame(
    t_us: u64,
    history: &PoseHistory,
    zeta_bc: &Isometry3<f64>,
) -> Option<InertialFrame> {
    let pose = history.at(t_us)?;
    let q_en = wgs84::q_en(pose.pos.lat_rad, pose.pos.lon_rad);
    Some(InertialFrame {
        t_us,
        zeta_eb: Isometry3::from_parts(
            nalgebra::Translation3::from(wgs84::geodetic_to_ecef(&pose.pos)),
            q_en * pose.q_nb,
        ),
        v_e_mps: q_en * pose.v_ned_mps,
        q_nb: pose.q_nb,
        h_m: pose.pos.h_m,
        zeta_bc: *zeta_bc,
    })
}

/// `x̊₀` at `t_us`: the INS camera pose (moved horizontally by `offset_ne_m`: the fused pose)
/// and the height over the terrain, when both are known then.
fn start_at(
    t_us: u64,
    history: &PoseHistory,
    h_agl: Option<&HeightAboveTerrain>,
    zeta_bc: &Isometry3<f64>,
    offset_ne_m: Option<&Vector2<f64>>,
) -> Option<VnsStart> {
    let h = h_agl.filter(|h| t_us.abs_diff(h.t_us) <= MAX_HEIGHT_AGE_US)?;
    let mut pose = history.at(t_us)?;
    if let Some(ne_m) = offset_ne_m {
        pose.pos = super::fusion::offset(&pose.pos, ne_m);
    }
    let q_eb = wgs84::q_en(pose.pos.lat_rad, pose.pos.lon_rad) * pose.q_nb;
    let zeta_eb = Isometry3::from_parts(
        nalgebra::Translation3::from(wgs84::geodetic_to_ecef(&pose.pos)),
        q_eb,
    );
    // The camera's height over the terrain: the body's, less the lens's offset along the
    // vertical (below the CG: higher up is smaller).
    let zeta_ec = zeta_eb * zeta_bc;
    let lens_down_m = (pose.q_nb * zeta_bc.translation.vector).z;
    Some(VnsStart {
        zeta_ec,
        h_agl_m: h.h_agl_m - lens_down_m,
    })
}

fn vision_state(state: VnsState) -> VisionState {
    match state {
        VnsState::WaitingForStart => VisionState::WaitingForStart,
        VnsState::Initialising => VisionState::Initialising,
        VnsState::Tracking => VisionState::Tracking,
        VnsState::Relocalising => VisionState::Relocalising,
    }
}

fn vision_status(out: &VnsOutput) -> VisionStatus {
    let n = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
    VisionStatus {
        state: vision_state(out.state),
        n_matched: n(out.n_matched),
        n_inliers: n(out.n_inliers),
        n_keyframes: n(out.n_keyframes),
        n_points: n(out.n_points),
        reprojection_rms_px: Some(out.reprojection_rms_px).filter(|v| v.is_finite()),
    }
}

/// The body pose of a visual camera pose: `zeta_eb = zeta_ec ⊗ zeta_bc*`.
fn body_fix(out: &VnsOutput, zeta_bc: &Isometry3<f64>) -> VisionFix {
    let zeta_eb = out.zeta_ec * zeta_bc.inverse();
    let pos = wgs84::ecef_to_geodetic(&zeta_eb.translation.vector);
    let q_ne = wgs84::q_en(pos.lat_rad, pos.lon_rad).inverse();
    VisionFix {
        t_us: out.t_us,
        pos,
        q_nb: q_ne * zeta_eb.rotation,
    }
}
