//! The visual navigation system (VNS) of the paper: semi-direct visual odometry (SVO 1) on the
//! down-looking camera, fed with the images and the initial estimate `x̊₀` only (paper,
//! "VNS flow diagram"; sections "SVO" and "SVO pose optimization"). Synchronous and
//! deterministic: the mapping work of SVO's second thread (depth filter, new keyframes) runs
//! inside [`Vns::process`] after the motion work of the same frame.
//!
//! The per-frame driver ([`Vns::process`], `Vns::commit`) and the public types are here; the
//! stages are in the submodules. Per frame, in the order the code runs them (docs/VNS.md,
//! "Per frame", has the details):
//! 1. two-view initialisation until it succeeds (`init.rs`; [`crate::vision::homography`]);
//!    afterwards `Vns::track` (`tracking.rs`) runs steps 2–6:
//! 2. sparse image alignment against the previous frame ([`crate::vision::sparse_align`]);
//! 3. reprojection of the points of the closest overlapping keyframes and of the candidates
//!    into the grid, one direct match per cell (`reprojection.rs`; [`crate::vision::matcher`]);
//! 4. pose optimisation ([`crate::vision::pose_opt`]), outliers dropped;
//! 5. tracking-quality check. Steps 3–5 do not touch the map (`Vns::attempt`);
//! 6. on a failure, steps 3–5 again from second starts (sparse alignment can settle a texture
//!    period away; `Vns::second_chance`), and only then a tracking loss, which starts
//!    relocalisation against the closest keyframe. What follows (`Vns::commit`) applies to
//!    the start that tracked:
//! 7. the match verdicts of step 3 applied to the map points (`reprojection.rs`);
//! 8. structure optimisation of the least recently refined points (`tracking.rs`;
//!    [`crate::vision::structure_opt`]);
//! 9. keyframe selection (no overlapping keyframe within 0.12 × the median depth), decided
//!    before the seeds are updated (`mapping.rs`);
//! 10. depth-filter update of every live seed by epipolar search; converged seeds become
//!     candidates (`mapping.rs`);
//! 11. insertion of the keyframe selected in step 9: the furthest keyframe dropped beyond the
//!     map's size, new seeds on free cells (`mapping.rs`).
//!
//! Settings are SVO 1's defaults adapted to the 768 × 1024 camera (docs/REFERENCES.md); the map
//! keeps [`VnsConfig::max_keyframes`] keyframes (SVO's "accurate" preset, 50) so that terrain
//! seen before a turn can be re-observed after it.

mod aiding;
mod init;
mod mapping;
mod reprojection;
#[cfg(test)]
mod tests;
mod tracking;

use std::sync::Arc;

use nalgebra::{Isometry3, Vector2};

use super::camera::Camera;
use super::features::{DetectorConfig, FeatureDetector, FeatureError};
use super::homography::{HomographyConfig, HomographyError};
use super::map::{Map, PointId};
use super::pose_opt::PoseOptConfig;
use super::pyramid::{PYRAMID_LEVELS, Pyramid, PyramidError};
use super::sparse_align::SparseAlignConfig;
use crate::sensors::Frame;
use aiding::AidingState;
pub use aiding::{AidingConfig, AidingCounters, InertialFrame};
use init::InitTracks;
use mapping::LiveSeed;
use tracking::Attempt;

/// Settings of the VNS: the `[vision]` table of the navigation settings (`nav::NavConfig`),
/// recorded in sensor logs; docs/VNS.md "Settings" lists them. A missing key takes its
/// default; an unknown one is an error. [`VnsConfig::validate`] checks the values.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VnsConfig {
    /// Feature detection (`[vision.detector]`).
    pub detector: DetectorConfig,
    /// Sparse image alignment (`[vision.sparse_align]`).
    pub sparse_align: SparseAlignConfig,
    /// Pose optimisation (`[vision.pose]`).
    pub pose: PoseOptConfig,
    /// Two-view initialisation (`[vision.homography]`).
    pub homography: HomographyConfig,
    /// Largest number of keyframes kept, a count (at least 2, the initialisation's): beyond
    /// it the keyframe furthest from the camera is dropped.
    pub max_keyframes: usize,
    /// Keyframes whose points are reprojected into a frame, a count (the closest overlapping
    /// ones; also those the keyframe selection compares against).
    pub reprojection_keyframes: usize,
    /// Matches per frame at most, a count (SVO `max_fts`).
    pub max_matches: usize,
    /// Fewer matches or inliers than this is a tracking failure, a count (SVO
    /// `quality_min_fts`; at most `max_matches`).
    pub min_matches: usize,
    /// A drop of more inliers than this from the previous frame is a tracking failure, a count
    /// (SVO `quality_max_drop_fts`).
    pub max_match_drop: usize,
    /// Keyframe distance as a fraction of the median scene depth, dimensionless (SVO
    /// `kfselect_mindist`): a frame becomes a keyframe unless an overlapping keyframe lies
    /// within (1, 0.8, 1.3) × this × the median depth along the camera's axes.
    pub keyframe_min_distance: f64,
    /// Matched points refined per frame by structure optimisation, a count (the least
    /// recently refined first).
    pub structure_points: usize,
    /// Gauss-Newton iterations per refined point, a count.
    pub structure_iterations: u32,
    /// Median feature displacement since the first image that triggers the two-view
    /// initialisation, px.
    pub init_min_disparity_px: f64,
    /// Fewer features still tracked than this restarts the initialisation, a count.
    pub init_min_tracked: usize,
    /// Features needed in the first image of an initialisation, a count (an image with fewer
    /// is skipped).
    pub init_min_features: usize,
    /// Grid cell of the first image's detection, level-0 px (8–1024; finer than tracking's:
    /// the homography and the first map want many points).
    pub init_cell_size_px: u32,
    /// Features sparse alignment must use for a relocalisation attempt to go on, a count.
    pub relocalise_min_tracked: usize,
    /// Seeds (depth filters) live for this many keyframes, a count (at least 1).
    pub seed_keyframes: u64,
    /// Projections closer than this to the image border are not matched, level-0 px.
    pub reprojection_border_px: f64,
    /// A keyframe observation is a reference for matching only if the cosine of the angle
    /// between its viewing direction and the current one is at least this, dimensionless in
    /// [−1, 1] (SVO: 0.5, i.e. within 60°).
    pub min_view_cos: f64,
    /// The IA-VNS's changes (all off: the VNS).
    pub aiding: AidingConfig,
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
            aiding: AidingConfig::default(),
        }
    }
}

/// Why VNS settings are invalid.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VnsConfigError {
    /// A setting is outside its domain.
    #[error("invalid setting vision.{key} = {value}: {reason}")]
    Invalid {
        /// Its TOML key under `vision.`.
        key: String,
        /// The rejected value.
        value: String,
        /// What it must satisfy.
        reason: String,
    },
    /// The settings have no TOML form, so a sensor log could not record them.
    #[error("vision settings: no TOML form ({0}): integers must be at most 2⁶³ − 1")]
    NotToml(String),
}

fn invalid(key: &str, value: impl std::fmt::Display, reason: &str) -> VnsConfigError {
    VnsConfigError::Invalid {
        key: key.to_owned(),
        value: value.to_string(),
        reason: reason.to_owned(),
    }
}

impl VnsConfig {
    /// Check every setting the VNS would otherwise fail on, per frame or by a panic: values
    /// outside their domain, non-finite numbers, sizes of zero, crossed level bounds.
    pub fn validate(&self) -> Result<(), VnsConfigError> {
        self.detector.validate().map_err(|e| {
            let field = match &e {
                FeatureError::InvalidConfig { field, .. } => field,
                _ => "",
            };
            detector_error(&format!("detector.{field}"), e)
        })?;
        // The initialisation's detector differs only in its cell size.
        DetectorConfig {
            cell_size_px: self.init_cell_size_px,
            ..self.detector
        }
        .validate()
        .map_err(|e| detector_error("init_cell_size_px", e))?;

        let sa = &self.sparse_align;
        if sa.max_level >= PYRAMID_LEVELS {
            return Err(invalid(
                "sparse_align.max_level",
                sa.max_level,
                "must be at most 4, the pyramid's coarsest level",
            ));
        }
        if sa.min_level > sa.max_level {
            return Err(invalid(
                "sparse_align.min_level",
                sa.min_level,
                "must not exceed sparse_align.max_level",
            ));
        }
        non_negative("sparse_align.min_step", sa.min_step)?;

        let pose = &self.pose;
        positive("pose.tukey_k", pose.tukey_k)?;
        positive("pose.fixed_scale_px", pose.fixed_scale_px)?;
        non_negative("pose.min_cost_decrease_px", pose.min_cost_decrease_px)?;
        non_negative("pose.min_step", pose.min_step)?;
        positive("pose.outlier_threshold_px", pose.outlier_threshold_px)?;

        self.homography.validate().map_err(|e| match e {
            HomographyError::Invalid {
                field,
                value,
                reason,
            } => invalid(&format!("homography.{field}"), value, reason),
            other => invalid("homography", "", &other.to_string()),
        })?;
        if i64::try_from(self.homography.seed).is_err() {
            return Err(invalid(
                "homography.seed",
                self.homography.seed,
                "must be at most 2⁶³ − 1, the largest TOML integer",
            ));
        }

        if self.max_keyframes < 2 {
            return Err(invalid(
                "max_keyframes",
                self.max_keyframes,
                "must be at least 2 (the initialisation makes two keyframes)",
            ));
        }
        if self.reprojection_keyframes == 0 {
            return Err(invalid("reprojection_keyframes", 0, "must be at least 1"));
        }
        if self.max_matches == 0 {
            return Err(invalid("max_matches", 0, "must be at least 1"));
        }
        if self.min_matches > self.max_matches {
            return Err(invalid(
                "min_matches",
                self.min_matches,
                "must not exceed max_matches (no frame could track)",
            ));
        }
        non_negative("keyframe_min_distance", self.keyframe_min_distance)?;
        non_negative("init_min_disparity_px", self.init_min_disparity_px)?;
        if self.seed_keyframes == 0 {
            return Err(invalid("seed_keyframes", 0, "must be at least 1"));
        }
        non_negative("reprojection_border_px", self.reprojection_border_px)?;
        if !(-1.0..=1.0).contains(&self.min_view_cos) {
            return Err(invalid(
                "min_view_cos",
                self.min_view_cos,
                "must be a cosine, −1 to 1",
            ));
        }
        self.aiding
            .activation
            .validate()
            .map_err(|e| invalid("aiding.activation", "", &e.to_string()))?;
        if !(self.aiding.prior.min_attitude_error_rad.is_finite()
            && self.aiding.prior.min_attitude_error_rad >= 0.0)
        {
            return Err(invalid(
                "aiding.prior.min_attitude_error_rad",
                self.aiding.prior.min_attitude_error_rad,
                "must be finite and ≥ 0",
            ));
        }
        // Sensor logs record the settings as TOML, whose integers end at i64::MAX.
        toml::Value::try_from(self).map_err(|e| VnsConfigError::NotToml(e.to_string()))?;
        Ok(())
    }
}

fn detector_error(key: &str, e: FeatureError) -> VnsConfigError {
    match e {
        FeatureError::InvalidConfig { value, reason, .. } => invalid(key, value, reason),
        other => invalid(key, "", &other.to_string()),
    }
}

fn positive(key: &str, value: f64) -> Result<(), VnsConfigError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(invalid(key, value, "must be finite and positive"))
    }
}

fn non_negative(key: &str, value: f64) -> Result<(), VnsConfigError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(invalid(key, value, "must be finite and ≥ 0"))
    }
}

/// Why the VNS could not be built or a frame not used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VnsError {
    /// The settings are invalid.
    #[error("vns: {0}")]
    Config(#[from] VnsConfigError),
    /// The detector does not fit the camera.
    #[error("vns: {0}")]
    Detector(#[from] FeatureError),
    /// The frame does not fit the camera (size, buffer).
    #[error("vns: bad frame: {0}")]
    BadFrame(#[from] PyramidError),
    /// The IA-VNS's activation settings are invalid.
    #[error("vns: {0}")]
    Aiding(#[from] crate::vision::iavns::activation::ActivationError),
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
    /// The IA-VNS's state (with any of its changes switched on).
    aiding: Option<AidingState>,
}

impl Vns {
    /// A VNS for `camera`; `seed` fixes the order in which grid cells are matched.
    pub fn new(camera: Camera, cfg: VnsConfig, seed: u64) -> Result<Self, VnsError> {
        cfg.validate()?;
        let detector = FeatureDetector::new(cfg.detector, &camera)?;
        let init_detector = FeatureDetector::new(
            DetectorConfig {
                cell_size_px: cfg.init_cell_size_px,
                ..cfg.detector
            },
            &camera,
        )?;
        let a = &cfg.aiding;
        let aiding = a.any().then(|| AidingState::new(a)).transpose()?;
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
            aiding,
        })
    }

    /// Start over (beyond the paper: the navigator's restart after a long loss or a gap in
    /// the frames, docs/FUSION.md): the map, the seeds, the previous frame and the IA-VNS's
    /// state go; the next frame with a start estimate `x̊₀` initialises again. The counters
    /// are kept.
    pub fn restart(&mut self) {
        self.state = VnsState::WaitingForStart;
        self.map = Map::new();
        self.seeds.clear();
        self.last = None;
        self.init = None;
        self.last_motion = None;
        self.last_good = None;
        if let Some(a) = self.aiding.as_mut() {
            // The settings were checked when the VNS was built: a new state cannot fail.
            if let Ok(mut fresh) = AidingState::new(&self.cfg.aiding) {
                fresh.counters = a.counters;
                *a = fresh;
            }
        }
    }

    /// The state.
    pub fn state(&self) -> VnsState {
        self.state
    }

    /// The counters.
    pub fn counters(&self) -> &VnsCounters {
        &self.counters
    }

    /// While tracking, the latest frame's exposure time and the level-0 pixels of its pose
    /// optimisation's inliers (what a viewer draws on the image).
    pub fn tracked_features(
        &self,
    ) -> Option<(u64, impl ExactSizeIterator<Item = Vector2<f64>> + '_)> {
        let last = self
            .last
            .as_ref()
            .filter(|_| self.state == VnsState::Tracking)?;
        Some((last.t_us, last.features.iter().map(|f| f.0)))
    }

    /// The map.
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The settings.
    pub fn config(&self) -> &VnsConfig {
        &self.cfg
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Process one frame. `start` is the initial estimate at this frame's time; it is used only
    /// while the VNS waits for its first image (the VNS never reads the INS afterwards). `ins`
    /// is the INS at the frame's time, read only by the IA-VNS's changes ([`AidingConfig`]).
    /// Returns the visual pose once initialised.
    pub fn process(
        &mut self,
        frame: &Frame,
        start: Option<&VnsStart>,
        ins: Option<&InertialFrame>,
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
                let out = self.initialise(frame.t_us, pyramid, start, ins);
                if self.state == VnsState::Tracking {
                    // The first keyframe's INS pose: the next frame's prediction starts there.
                    self.remember_ins(ins);
                }
                Ok(out)
            }
            VnsState::Tracking | VnsState::Relocalising => {
                Ok(Some(self.track(frame.t_us, pyramid, ins)))
            }
        }
    }

    /// Steps 7–11 for a frame that tracked: the match verdicts, structure, keyframe selection,
    /// seeds, keyframe insertion.
    /// The verdicts wait until here: matching around a wrong start fails good points, and
    /// charging them would starve the second chances and the relocalisation that follow.
    fn commit(&mut self, t_us: u64, pyramid: &Arc<Pyramid>, attempt: &mut Attempt) -> bool {
        self.apply_verdicts(std::mem::take(&mut attempt.verdicts));
        let current = self
            .cfg
            .aiding
            .current_features_in_structure
            .then_some(attempt.zeta_ec);
        self.optimize_structure(&attempt.inliers, current.as_ref());
        let keyframe = self.needs_keyframe(&attempt.zeta_ec, &attempt.inliers);
        self.update_seeds(pyramid, &attempt.zeta_ec);
        if keyframe {
            self.insert_keyframe(t_us, pyramid, &attempt.zeta_ec, &attempt.inliers);
        }
        keyframe
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
