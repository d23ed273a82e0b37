//! The visual navigation system (VNS) of the paper: semi-direct visual odometry (SVO 1) on the
//! down-looking camera, fed with the images and the initial estimate `x̊₀` only (paper,
//! "VNS flow diagram"; sections "SVO" and "SVO pose optimization"). Synchronous and
//! deterministic: the mapping work of SVO's second thread (depth filter, new keyframes) runs
//! inside [`Vns::process`] after the motion work of the same frame.
//!
//! Per frame, after the two-view initialisation ([`crate::vision::homography`]):
//! 1. sparse image alignment against the previous frame ([`crate::vision::sparse_align`]);
//! 2. reprojection of the points of the closest overlapping keyframes and of the candidates
//!    into the grid, one direct match per cell ([`crate::vision::matcher`]);
//! 3. pose optimisation ([`crate::vision::pose_opt`]), outliers dropped;
//! 4. tracking-quality check; on a failure, steps 2–4 again from second starts (sparse
//!    alignment can settle a texture period away; [`Vns::second_chance`]), and only then a
//!    tracking loss, which starts relocalisation against the closest keyframe. Steps 2–4 do not
//!    touch the map ([`Vns::attempt`]); what follows applies to the start that tracked;
//! 5. structure optimisation of the least recently refined points
//!    ([`crate::vision::structure_opt`]);
//! 6. keyframe selection (no overlapping keyframe within 0.12 × the median depth), new seeds on
//!    free cells, the furthest keyframe dropped beyond the map's size;
//! 7. depth-filter update of every live seed by epipolar search; converged seeds become
//!    candidates.
//!
//! Settings are SVO 1's defaults adapted to the 768 × 1024 camera (docs/REFERENCES.md); the map
//! keeps [`VnsConfig::max_keyframes`] keyframes (SVO's "accurate" preset, 50) so that terrain
//! seen before a turn can be re-observed after it.

mod init;
mod mapping;
mod reprojection;
#[cfg(test)]
mod tests;

use std::sync::Arc;

use nalgebra::{Isometry3, Vector2, Vector6};

use super::camera::Camera;
use super::features::{DetectorConfig, FeatureDetector, FeatureError};
use super::homography::HomographyConfig;
use super::map::{Map, PointId, PointKind};
use super::pose_opt::{PoseObservation, PoseOptConfig, optimize_pose};
use super::pyramid::{Pyramid, PyramidError};
use super::sparse_align::{AlignFeature, SparseAlignConfig, sparse_align};
use super::structure_opt::{PointObservation, optimize_point};
use crate::math::se3;
use crate::sensors::Frame;
use init::InitTracks;
use mapping::LiveSeed;
use reprojection::{FrameMatch, PointVerdict};

/// Settings of the VNS.
#[derive(Debug, Clone, PartialEq)]
pub struct VnsConfig {
    /// Feature detection.
    pub detector: DetectorConfig,
    /// Sparse image alignment.
    pub sparse_align: SparseAlignConfig,
    /// Pose optimisation.
    pub pose: PoseOptConfig,
    /// Two-view initialisation.
    pub homography: HomographyConfig,
    /// Largest number of keyframes kept (the furthest is dropped beyond it).
    pub max_keyframes: usize,
    /// Keyframes whose points are reprojected into a frame (the closest overlapping ones).
    pub reprojection_keyframes: usize,
    /// Matches per frame at most (SVO `max_fts`).
    pub max_matches: usize,
    /// Fewer matches or inliers than this is a tracking failure (SVO `quality_min_fts`).
    pub min_matches: usize,
    /// A drop of more inliers than this from the previous frame is a tracking failure (SVO
    /// `quality_max_drop_fts`).
    pub max_match_drop: usize,
    /// Keyframe distance over the median depth (SVO `kfselect_mindist`).
    pub keyframe_min_distance: f64,
    /// Points refined per frame by structure optimisation.
    pub structure_points: usize,
    /// Gauss-Newton iterations per refined point.
    pub structure_iterations: u32,
    /// Median feature displacement that triggers the two-view initialisation, px.
    pub init_min_disparity_px: f64,
    /// Fewer tracked features than this restarts the initialisation.
    pub init_min_tracked: usize,
    /// Features needed in the first image of an initialisation.
    pub init_min_features: usize,
    /// Grid cell of the first image's detection, px (finer than tracking's: the homography
    /// and the first map want many points).
    pub init_cell_size_px: u32,
    /// Features sparse alignment must use for a relocalisation attempt to go on.
    pub relocalise_min_tracked: usize,
    /// Seeds live for this many keyframes.
    pub seed_keyframes: u64,
    /// Projections closer than this to the image border are not matched, px.
    pub reprojection_border_px: f64,
    /// A keyframe observation is a reference for matching only within this viewing-angle
    /// cosine of the current view (SVO: 0.5, 60°).
    pub min_view_cos: f64,
}

impl Default for VnsConfig {
    fn default() -> Self {
        Self {
            detector: DetectorConfig::default(),
            sparse_align: SparseAlignConfig::default(),
            pose: PoseOptConfig::default(),
            homography: HomographyConfig::default(),
            max_keyframes: 50,
            reprojection_keyframes: 10,
            max_matches: 160,
            min_matches: 50,
            max_match_drop: 40,
            keyframe_min_distance: 0.12,
            structure_points: 20,
            structure_iterations: 5,
            init_min_disparity_px: 50.0,
            init_min_tracked: 50,
            init_min_features: 100,
            init_cell_size_px: 32,
            relocalise_min_tracked: 30,
            seed_keyframes: 3,
            reprojection_border_px: 8.0,
            min_view_cos: 0.5,
        }
    }
}

/// Why the VNS could not be built or a frame not used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VnsError {
    /// The detector settings are invalid.
    #[error("vns: {0}")]
    Detector(#[from] FeatureError),
    /// The frame does not fit the camera (size, buffer).
    #[error("vns: bad frame: {0}")]
    BadFrame(#[from] PyramidError),
    /// A frame not after the previous one.
    #[error("vns: frame at {t_us} µs is not after the previous one at {previous_us} µs")]
    OutOfOrder {
        /// The frame's time, µs.
        t_us: u64,
        /// The previous frame's time, µs.
        previous_us: u64,
    },
}

/// Where the VNS starts: the initial estimate `x̊₀` at the first image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VnsStart {
    /// Camera pose at the image (camera → Earth).
    pub zeta_ec: Isometry3<f64>,
    /// Height of the camera over the terrain, m (the initialisation's scale).
    pub h_agl_m: f64,
}

/// State of the VNS.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VnsState {
    /// No first image yet (or no start estimate for it).
    WaitingForStart,
    /// Tracking the first image's features until the two-view initialisation succeeds.
    Initialising,
    /// Tracking.
    Tracking,
    /// Tracking was lost; each frame tries to relocalise against the closest keyframe.
    Relocalising,
}

/// What one frame gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VnsOutput {
    /// Exposure time, µs.
    pub t_us: u64,
    /// The visual camera pose `zeta_ec` (while tracking; the last good one while relocalising).
    pub zeta_ec: Isometry3<f64>,
    /// State after the frame.
    pub state: VnsState,
    /// Features matched in the frame (before pose optimisation).
    pub n_matched: usize,
    /// Inliers of the pose optimisation.
    pub n_inliers: usize,
    /// Keyframes in the map.
    pub n_keyframes: usize,
    /// Points in the map (candidates included).
    pub n_points: usize,
    /// Live depth-filter seeds.
    pub n_seeds: usize,
    /// RMS reprojection error of the inliers, px.
    pub reprojection_rms_px: f64,
    /// The frame became a keyframe.
    pub keyframe: bool,
}

/// Counters of the VNS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VnsCounters {
    /// Frames processed.
    pub frames: u64,
    /// Frames rejected (size, buffer, time).
    pub bad_frames: u64,
    /// Successful two-view initialisations.
    pub initialisations: u64,
    /// Initialisations restarted (too few tracks, homography failures).
    pub init_restarts: u64,
    /// Tracking losses.
    pub tracking_losses: u64,
    /// Successful relocalisations.
    pub relocalisations: u64,
    /// Frames tracked from a second start after tracking from sparse alignment's pose failed
    /// (`Vns::second_chance`): the motion model's guess aligned again on the fine levels,
    /// bare, or turned by ±δ, ±2δ. Not losses; a relocalisation that tracks this way counts
    /// here and in `relocalisations`.
    pub motion_model_recoveries: u64,
    /// Of `motion_model_recoveries`, those from a turned start.
    pub turned_start_recoveries: u64,
    /// Keyframes created.
    pub keyframes: u64,
    /// Seeds converged into candidates.
    pub seeds_converged: u64,
}

/// The previous frame, for sparse alignment.
#[derive(Debug, Clone)]
struct LastFrame {
    t_us: u64,
    zeta_ec: Isometry3<f64>,
    pyramid: Arc<Pyramid>,
    /// Matched features: level-0 pixel, level, point.
    features: Vec<(Vector2<f64>, u32, PointId)>,
    /// It was a keyframe (or a keyframe stood in for it): its feature count is not comparable
    /// with a tracked frame's, so the next frame skips the drop test (as SVO Pro does).
    keyframe: bool,
}

/// A frame tracked from one start pose, not yet committed to the map.
#[derive(Debug, Clone)]
struct Attempt {
    zeta_ec: Isometry3<f64>,
    inliers: Vec<FrameMatch>,
    n_matched: usize,
    rms_px: f64,
    verdicts: Vec<PointVerdict>,
}

/// Which second chance tracked a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SecondChance {
    /// The constant-velocity guess, aligned on the fine levels or bare.
    Guess,
    /// A start turned away from the guess.
    TurnedStart,
}

/// The turn δ between the second-chance starts, degrees: 14.6 px at level 0, about half the
/// reach of sparse alignment over the city's street grid (a roll-rate step of 10–15°/s puts
/// the constant-velocity guess 1–1.5° off).
const SECOND_CHANCE_TURN_DEG: f64 = 0.75;

/// The visual navigation system.
#[derive(Debug, Clone)]
pub struct Vns {
    camera: Camera,
    cfg: VnsConfig,
    detector: FeatureDetector,
    init_detector: FeatureDetector,
    state: VnsState,
    map: Map,
    seeds: Vec<LiveSeed>,
    last: Option<LastFrame>,
    init: Option<InitTracks>,
    /// Cells in the fixed random order matching visits them.
    cell_order: Vec<usize>,
    /// Frame counter (structure optimisation's age).
    frame_index: u64,
    counters: VnsCounters,
    /// The motion between the last two tracked frames (`zeta_prev⁻¹ zeta_last`).
    last_motion: Option<Isometry3<f64>>,
    /// Last good pose and its time (what relocalisation starts from).
    last_good: Option<(u64, Isometry3<f64>)>,
}

impl Vns {
    /// A VNS for `camera`; `seed` fixes the order in which grid cells are matched.
    pub fn new(camera: Camera, cfg: VnsConfig, seed: u64) -> Result<Self, VnsError> {
        let detector = FeatureDetector::new(cfg.detector, &camera)?;
        let init_detector = FeatureDetector::new(
            DetectorConfig {
                cell_size_px: cfg.init_cell_size_px,
                ..cfg.detector
            },
            &camera,
        )?;
        let n = detector.grid().n_cells();
        let mut cell_order: Vec<usize> = (0..n).collect();
        // Fisher-Yates with SplitMix64.
        let mut state = seed;
        for i in (1..n).rev() {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            cell_order.swap(i, (z % (i as u64 + 1)) as usize);
        }
        Ok(Self {
            camera,
            cfg,
            detector,
            init_detector,
            state: VnsState::WaitingForStart,
            map: Map::new(),
            seeds: Vec::new(),
            last: None,
            init: None,
            cell_order,
            frame_index: 0,
            counters: VnsCounters::default(),
            last_motion: None,
            last_good: None,
        })
    }

    /// The state.
    pub fn state(&self) -> VnsState {
        self.state
    }

    /// The counters.
    pub fn counters(&self) -> &VnsCounters {
        &self.counters
    }

    /// The map.
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Process one frame. `start` is the initial estimate at this frame's time; it is used only
    /// while the VNS waits for its first image (the VNS never reads the INS afterwards).
    /// Returns the visual pose once initialised.
    pub fn process(
        &mut self,
        frame: &Frame,
        start: Option<&VnsStart>,
    ) -> Result<Option<VnsOutput>, VnsError> {
        let previous_us = self
            .last
            .as_ref()
            .map(|l| l.t_us)
            .or(self.init.as_ref().map(|i| i.t_us));
        if let Some(previous_us) = previous_us
            && frame.t_us <= previous_us
        {
            self.counters.bad_frames += 1;
            return Err(VnsError::OutOfOrder {
                t_us: frame.t_us,
                previous_us,
            });
        }
        let pyramid = match Pyramid::from_frame(frame, &self.camera) {
            Ok(p) => Arc::new(p),
            Err(e) => {
                self.counters.bad_frames += 1;
                return Err(e.into());
            }
        };
        self.counters.frames += 1;
        self.frame_index += 1;
        match self.state {
            VnsState::WaitingForStart | VnsState::Initialising => {
                Ok(self.initialise(frame.t_us, pyramid, start))
            }
            VnsState::Tracking | VnsState::Relocalising => {
                Ok(Some(self.track(frame.t_us, pyramid)))
            }
        }
    }

    // ---------------------------------------------------------------- tracking

    fn track(&mut self, t_us: u64, pyramid: Arc<Pyramid>) -> VnsOutput {
        let Some(last) = self.last.take() else {
            self.state = VnsState::WaitingForStart;
            return self.output(t_us, Isometry3::identity(), 0, 0, f64::NAN, false);
        };
        let relocalising = self.state == VnsState::Relocalising;
        // The reference for sparse alignment: the previous frame, or when relocalising the
        // keyframe closest to the last good pose.
        let reference = if relocalising {
            self.closest_keyframe_frame(&last.zeta_ec)
        } else {
            Some(last.clone())
        };
        // The guess: the last pose moved on by the last inter-frame motion (constant
        // velocity, beyond SVO 1's last pose: turbulence turns the camera by degrees per
        // second, more than sparse alignment's coarse levels recover on fine textures).
        let guess = match self.last_motion {
            Some(m) if !relocalising => se3::renormalized(&(last.zeta_ec * m)),
            _ => last.zeta_ec,
        };
        let aligned = reference
            .as_ref()
            .and_then(|r| self.align(r, &pyramid, &guess, &self.cfg.sparse_align));
        let min_aligned = if relocalising {
            self.cfg.relocalise_min_tracked
        } else {
            1
        };
        let first = match aligned {
            Some((zeta, n)) if n >= min_aligned => self.attempt(&pyramid, zeta, &last),
            _ => Err(0),
        };
        let result = first.or_else(|n| {
            let second = self.second_chance(
                reference.as_ref(),
                &pyramid,
                &guess,
                aligned
                    .filter(|&(_, n)| n >= min_aligned)
                    .map(|(zeta, _)| zeta),
                &last,
                min_aligned,
                relocalising,
            );
            match second {
                Ok((attempt, kind)) => {
                    self.counters.motion_model_recoveries += 1;
                    if kind == SecondChance::TurnedStart {
                        self.counters.turned_start_recoveries += 1;
                    }
                    Ok(attempt)
                }
                Err(most_matched) => Err(n.max(most_matched)),
            }
        });
        match result {
            Ok(mut attempt) => {
                let keyframe = self.commit(t_us, &pyramid, &mut attempt);
                let zeta_ec = attempt.zeta_ec;
                if relocalising {
                    self.counters.relocalisations += 1;
                }
                self.state = VnsState::Tracking;
                self.last_motion =
                    (!relocalising).then(|| se3::renormalized(&(last.zeta_ec.inverse() * zeta_ec)));
                self.last_good = Some((t_us, zeta_ec));
                let n_inliers = attempt.inliers.len();
                self.last = Some(LastFrame {
                    t_us,
                    zeta_ec,
                    pyramid,
                    features: attempt
                        .inliers
                        .iter()
                        .map(|m| (m.px, m.level, m.point))
                        .collect(),
                    keyframe: keyframe || relocalising,
                });
                self.output(
                    t_us,
                    zeta_ec,
                    attempt.n_matched,
                    n_inliers,
                    attempt.rms_px,
                    keyframe,
                )
            }
            Err(n_matched) => {
                if !relocalising {
                    self.counters.tracking_losses += 1;
                }
                self.state = VnsState::Relocalising;
                // Keep the last good pose and image: the next frame relocalises from there.
                let zeta = last.zeta_ec;
                self.last = Some(LastFrame { t_us, ..last });
                self.output(t_us, zeta, n_matched, 0, f64::NAN, false)
            }
        }
    }

    /// The second chances of a frame that did not track from its sparse alignment (ORB-SLAM's
    /// tracking chain, widened). Over periodic texture (a city's street grid and rows of
    /// houses) sparse alignment's coarse levels can lock a pattern period away: tens to
    /// hundreds of metres and up to degrees from the guess, where a tilt and a lateral shift
    /// together move the pattern by about one period. In order:
    /// 1. alignment from the guess on the two finest alignment levels only (3→2), where the
    ///    guess is within reach and the coarse period is not seen; then the bare guess. The
    ///    first that tracks is taken;
    /// 2. while tracking (not relocalising), alignments on the fine levels and on all levels
    ///    from the guess turned by ±δ and ±2δ about the camera's x and y axes: an aileron or
    ///    a gust changes the roll rate by 10–15°/s within one frame, so the constant-velocity
    ///    guess is off by more than sparse alignment reaches over a street grid. There the
    ///    coarse levels pull every start into the same wrong basin, and the fine levels reach
    ///    only a fraction of a degree; each covers where the other fails. Of the starts that
    ///    pass the quality test the most inliers win: a pose a period away keeps about half.
    ///
    /// A frame that tracks from its first alignment never comes here, so a flight in which
    /// every frame does is unchanged by it. `Err` carries the most matches any start found.
    #[allow(clippy::too_many_arguments)]
    fn second_chance(
        &self,
        reference: Option<&LastFrame>,
        pyramid: &Pyramid,
        guess: &Isometry3<f64>,
        aligned: Option<Isometry3<f64>>,
        last: &LastFrame,
        min_aligned: usize,
        relocalising: bool,
    ) -> Result<(Attempt, SecondChance), usize> {
        let mut tried: Vec<Isometry3<f64>> = aligned.into_iter().collect();
        let mut most_matched = 0;
        let mut try_start = |start: Isometry3<f64>| {
            if tried.contains(&start) {
                return None;
            }
            tried.push(start);
            self.attempt(pyramid, start, last)
                .map_err(|n| most_matched = most_matched.max(n))
                .ok()
        };
        let fine_cfg = SparseAlignConfig {
            max_level: (self.cfg.sparse_align.min_level + 1).min(self.cfg.sparse_align.max_level),
            ..self.cfg.sparse_align
        };
        let fine = reference
            .and_then(|r| self.align(r, pyramid, guess, &fine_cfg))
            .filter(|&(_, n)| n >= min_aligned)
            .map(|(zeta, _)| zeta);
        if let Some(a) = fine.and_then(&mut try_start) {
            return Ok((a, SecondChance::Guess));
        }
        if let Some(a) = try_start(*guess) {
            return Ok((a, SecondChance::Guess));
        }
        let mut best: Option<Attempt> = None;
        if let Some(reference) = reference.filter(|_| !relocalising) {
            let delta = SECOND_CHANCE_TURN_DEG.to_radians();
            for (k, axis) in [
                (1.0, 0),
                (-1.0, 0),
                (1.0, 1),
                (-1.0, 1),
                (2.0, 0),
                (-2.0, 0),
                (2.0, 1),
                (-2.0, 1),
            ] {
                // τ = [v; ω]: a turn about the camera's x (index 3) or y (index 4) axis.
                let mut tau = Vector6::zeros();
                tau[3 + axis] = k * delta;
                let turned = se3::plus(guess, &tau);
                for cfg in [&fine_cfg, &self.cfg.sparse_align] {
                    let Some((start, n)) = self.align(reference, pyramid, &turned, cfg) else {
                        continue;
                    };
                    if n < min_aligned {
                        continue;
                    }
                    if let Some(a) = try_start(start)
                        && best
                            .as_ref()
                            .is_none_or(|b| a.inliers.len() > b.inliers.len())
                    {
                        best = Some(a);
                    }
                }
            }
        }
        best.map(|a| (a, SecondChance::TurnedStart))
            .ok_or(most_matched)
    }

    /// Sparse alignment of `pyramid` against `reference`, starting from `guess`; the pose and
    /// the features used.
    fn align(
        &self,
        reference: &LastFrame,
        pyramid: &Pyramid,
        guess: &Isometry3<f64>,
        cfg: &SparseAlignConfig,
    ) -> Option<(Isometry3<f64>, usize)> {
        let centre = reference.zeta_ec.translation.vector;
        let features: Vec<AlignFeature> = reference
            .features
            .iter()
            .filter_map(|(px, _, pid)| {
                let p = self.map.point(*pid)?;
                let range = (p.p_e - centre).norm();
                Some(AlignFeature {
                    px: *px,
                    p_ref: self.camera.back_project(px) * range,
                })
            })
            .collect();
        let t_cur_ref_guess = guess.inverse() * reference.zeta_ec;
        let r = sparse_align(
            &self.camera,
            &reference.pyramid,
            pyramid,
            &features,
            &t_cur_ref_guess,
            cfg,
        )
        .ok()?;
        Some((
            se3::renormalized(&(reference.zeta_ec * r.t_cur_ref.inverse())),
            r.n_features,
        ))
    }

    /// The keyframe closest to `zeta_ec`, as a reference frame with its matched features.
    fn closest_keyframe_frame(&self, zeta_ec: &Isometry3<f64>) -> Option<LastFrame> {
        let centre = zeta_ec.translation.vector;
        let kf = self.map.keyframes().min_by(|a, b| {
            (a.centre_e() - centre)
                .norm()
                .total_cmp(&(b.centre_e() - centre).norm())
        })?;
        Some(LastFrame {
            t_us: kf.t_us,
            zeta_ec: kf.zeta_ec,
            pyramid: kf.pyramid.clone(),
            features: kf
                .features
                .iter()
                .filter_map(|f| {
                    let pid = f.point?;
                    (self.map.point(pid)?.kind != PointKind::Candidate)
                        .then_some((f.px, f.level, pid))
                })
                .collect(),
            keyframe: true,
        })
    }

    /// Steps 2–4 from a start pose (matching, pose optimisation, the quality test), without
    /// touching the map: `Err(matched)` on a tracking failure.
    fn attempt(
        &self,
        pyramid: &Pyramid,
        start: Isometry3<f64>,
        last: &LastFrame,
    ) -> Result<Attempt, usize> {
        let (matches, verdicts) = self.reproject_and_match(pyramid, &start);
        let n_matched = matches.len();
        if n_matched < self.cfg.min_matches {
            return Err(n_matched);
        }
        let observations: Vec<PoseObservation> = matches
            .iter()
            .filter_map(|m| {
                Some(PoseObservation {
                    p_e: self.map.point(m.point)?.p_e,
                    px: m.px,
                    level: m.level,
                })
            })
            .collect();
        // A plane seen through a narrow field of view has two poses that explain it almost
        // equally (the tilt flip): sparse alignment, which stops at level 2, cannot tell them
        // apart and may start the optimisation in the wrong basin. The constant-velocity
        // prediction from the previous frames is a second start; the lower cost wins.
        // (The prediction is skipped when it is the start itself: the bare-guess attempt.)
        let starts = std::iter::once(start).chain(
            self.last_motion
                .map(|m| se3::renormalized(&(last.zeta_ec * m)))
                .filter(|predicted| *predicted != start),
        );
        let Some(opt) = starts
            .filter_map(|start| {
                optimize_pose(&self.camera, &start, &observations, &self.cfg.pose, None).ok()
            })
            .min_by(|a, b| a.final_cost_px.total_cmp(&b.final_cost_px))
        else {
            return Err(n_matched);
        };
        let inliers: Vec<FrameMatch> = matches
            .iter()
            .zip(&opt.inliers)
            .filter(|(_, ok)| **ok)
            .map(|(m, _)| *m)
            .collect();
        // Quality (SVO: at least `min_matches`, no drop of more than `max_match_drop`).
        let previous = if last.keyframe {
            0
        } else {
            last.features.len().min(self.cfg.max_matches)
        };
        if inliers.len() < self.cfg.min_matches
            || previous.saturating_sub(inliers.len()) > self.cfg.max_match_drop
        {
            return Err(n_matched);
        }
        Ok(Attempt {
            zeta_ec: opt.zeta_ec,
            inliers,
            n_matched,
            rms_px: opt.inlier_rms_px,
            verdicts,
        })
    }

    /// Steps 5–7 for a frame that tracked: the match verdicts, structure, keyframe, seeds.
    /// The verdicts wait until here: matching around a wrong start fails good points, and
    /// charging them would starve the second chances and the relocalisation that follow.
    fn commit(&mut self, t_us: u64, pyramid: &Arc<Pyramid>, attempt: &mut Attempt) -> bool {
        self.apply_verdicts(std::mem::take(&mut attempt.verdicts));
        self.optimize_structure(&attempt.inliers);
        let keyframe = self.needs_keyframe(&attempt.zeta_ec, &attempt.inliers);
        self.update_seeds(pyramid, &attempt.zeta_ec);
        if keyframe {
            self.insert_keyframe(t_us, pyramid, &attempt.zeta_ec, &attempt.inliers);
        }
        keyframe
    }

    /// Refine the least recently refined matched points over their keyframe observations.
    fn optimize_structure(&mut self, matches: &[FrameMatch]) {
        let mut order: Vec<(u64, PointId)> = matches
            .iter()
            .filter_map(|m| Some((self.map.point(m.point)?.last_structure_opt, m.point)))
            .collect();
        order.sort_unstable();
        for &(_, pid) in order.iter().take(self.cfg.structure_points) {
            let Some(p) = self.map.point(pid) else {
                continue;
            };
            let observations: Vec<PointObservation> = p
                .observations
                .iter()
                .filter_map(|o| {
                    let kf = self.map.keyframe(o.keyframe)?;
                    Some(PointObservation {
                        zeta_ec: kf.zeta_ec,
                        px: kf.features.get(o.feature)?.px,
                    })
                })
                .collect();
            let refined = optimize_point(
                &self.camera,
                &p.p_e,
                &observations,
                self.cfg.structure_iterations,
            );
            let frame_index = self.frame_index;
            if let Some(p) = self.map.point_mut(pid) {
                p.p_e = refined;
                p.last_structure_opt = frame_index;
            }
        }
    }

    fn output(
        &self,
        t_us: u64,
        zeta_ec: Isometry3<f64>,
        n_matched: usize,
        n_inliers: usize,
        rms: f64,
        keyframe: bool,
    ) -> VnsOutput {
        VnsOutput {
            t_us,
            zeta_ec,
            state: self.state,
            n_matched,
            n_inliers,
            n_keyframes: self.map.n_keyframes(),
            n_points: self.map.n_points(),
            n_seeds: self.seeds.len(),
            reprojection_rms_px: rms,
            keyframe,
        }
    }
}
