//! Visual navigation: the down-looking camera shared by the simulator's renderer and the
//! semi-direct visual odometry of the paper's sections "Semi-Direct Visual Odometry" and
//! "Optical Flow" (appendix), with the numbers of docs/REFERENCES.md A2.6.
//!
//! - [`camera`]: pinhole (by default the authors' 768 × 1024 px, f = 19 mm, 17 µm pixels) with
//!   an optional lens distortion, projection and back-projection, the paper's optical-flow
//!   Jacobian, image-pyramid geometry, and the body → camera mounting `zeta_bc` with its
//!   true-versus-estimated error model.
//! - [`lens`]: the radial-tangential and fisheye distortion models, their Jacobians and
//!   checked inverses.
//! - [`calibration`]: OpenCV (YAML, XML) and ROS `camera_info` calibration files.
//! - [`pose_opt`]: the pose optimisation of eqs. `svo_pose_optim_*` (Gauss-Newton on SE(3),
//!   Tukey weights, outliers), open to a prior term for the IA-VNS.
//! - [`depth_filter`]: the inverse-depth seeds of new features and their Gaussian × Beta update.
//! - [`pyramid`]: the 5-level image pyramid (2 × 2 box average) and sub-pixel interpolation.
//! - [`sparse_align`]: sparse model-based image alignment (inverse compositional, 4 × 4 patches).
//! - [`features`]: grid FAST detection with the Shi-Tomasi score, one feature per cell.
//! - [`homography`]: the two-view initialisation: homography by RANSAC, its decomposition, the
//!   metric scale from the height over the terrain, triangulation.
//! - [`iavns`]: the IA-VNS's own steps: the PI-inspired activation of the inertial priors and
//!   the joint prior-based pose optimisation.
//! - [`matcher`]: direct matching: affine-warped patches, 2-D feature alignment, epipolar search.
//! - [`klt`]: pyramidal Lucas-Kanade tracking of the first image's corners for the
//!   initialisation.
//! - [`map`]: keyframes, points and candidates, the bounded map.
//! - [`structure_opt`]: refinement of a point over its observations.
//! - [`vns`]: the visual navigation system, frame by frame (initialisation, tracking, mapping,
//!   failure and relocalisation).
//!
//! Frames follow docs/ARCHITECTURE.md ("Conventions"): camera `C` has z along the optical axis (out
//! of the lens), x along image columns (right), y along image rows (down); image coordinates
//! `(u, v)` are in pixels with integer values at pixel *centres*, so the image spans
//! `[-0.5, W - 0.5] × [-0.5, H - 0.5]`.

pub mod calibration;
pub mod camera;
pub mod depth_filter;
pub mod features;
pub mod homography;
pub mod iavns;
pub mod klt;
pub mod lens;
pub mod map;
pub mod matcher;
pub mod pose_opt;
pub mod pyramid;
pub mod sparse_align;
pub mod structure_opt;
#[cfg(test)]
pub(crate) mod test_scene;
pub mod vns;
