//! Sparse model-based image alignment of semi-direct visual odometry (SVO; Forster, Pizzoli and
//! Scaramuzza, ICRA 2014, eqs. 7–9; docs/REFERENCES.md): the relative pose
//! `t_cur_ref` (reference camera → current camera) that minimises the photometric error of
//! 4 × 4 patches around reference features with known 3-D points, by inverse-compositional
//! Gauss-Newton (damped, see below) from a coarse pyramid level to a finer one (SVO 1: levels 4 → 2, 30 iterations
//! per level, stop at max |Δ| ≤ 1e-6).
//!
//! # Residual, warp and update
//!
//! At level `L` (camera [`Camera::level`], so `Π_L(p) = base_to_level(Π(p))` in the
//! pixel-centre convention), for a feature at reference pixel `u` with point `p` and patch
//! offsets `o ∈ {−2, −1, 0, 1}²`:
//!
//! `r(T) = I_cur(Π_L(T p) + o) − I_ref(Π_L(p) + o)`,  grey levels, `T = t_cur_ref`.
//!
//! Inverse compositional form: the increment `ξ` warps the *reference* side,
//! `I_ref(Π_L(Exp(ξ) p) + o)`, so its Jacobian is evaluated once per level on the reference
//! patch: `∂Π_L(Exp(ξ) p)/∂ξ = −J_OF,L(p)` ([`Camera::optical_flow_jacobian`] of the level
//! camera), hence `J = −∇I_ref · J_OF,L(p)` (1 × 6, `[v; ω]`), which is also the derivative of
//! `r` with respect to a **right perturbation of `t_cur_ref`** at the solution:
//! `r(T ∘ Exp(δ)) ≈ r(T) + J δ`. Each iteration solves `H δ = −Σ Jᵀ r` with `H = Σ Jᵀ J`
//! (Cholesky on the diagonally scaled 6 × 6 system) and composes
//! `t_cur_ref ← t_cur_ref ∘ Exp(δ)` (the inverse-compositional `T ∘ Exp(ξ)⁻¹` with `ξ = −δ`).
//! This is the project's right perturbation (docs: `X ⊕ τ = X ∘ Exp(τ)`) applied to the pose
//! `t_cur_ref`, which maps reference-camera points into the current camera; `δ` is a twist of
//! the reference camera frame (m, rad).
//!
//! # Details (SVO 1 unless said)
//!
//! - The 3-D point of a feature is taken as the unit bearing of its reference pixel times the
//!   range `‖p_ref‖`, so the patch centre is exactly the observation.
//! - Patches: offsets −2…+1 around the scaled sub-pixel feature position, bilinear with one set
//!   of weights per patch; reference gradients are half the central differences of the
//!   interpolated reference image (one more pixel either side). A feature is used at a level only
//!   if its reference patch plus a 1-px border lies inside the reference level image, and in an
//!   iteration only if its projected patch plus a 1-px border lies inside the current one.
//! - No robust weights; the cost is the mean squared residual over the patch pixels used.
//!   Levenberg-Marquardt rather than SVO 1's Gauss-Newton that ends a level at the first rise of
//!   the cost: a step that raises it is refused and the damping `λ` (on the unit-diagonal
//!   scaled system) grows tenfold; an accepted step divides it by ten, down to pure
//!   Gauss-Newton. On fine, noise-like textures (forest canopy) the coarse levels otherwise end
//!   after one or two steps, before they converge. A level ends at `λ > 10⁴`, at the iteration
//!   cap, or on a negligible step; a non-finite or singular step also ends it.
//! - Levels with fewer than [`SparseAlignConfig::min_features`] usable features are skipped,
//!   except the finest, where that is an error.
//! - Patches, gradients and residuals are `f32` (grey levels are 8-bit), geometry and the normal
//!   equations `f64`. The per-pixel Jacobian is kept factored as `∇I_ref,j · W` with the 2 × 6
//!   warp Jacobian `W = −J_OF,L(p)` of the feature, and `H` per feature as `Wᵀ S W` with the
//!   patch's 2 × 2 structure tensor `S`.

use image::GrayImage;
use nalgebra::{Isometry3, Matrix2, Matrix2x6, Matrix6, Vector2, Vector3, Vector6};

use super::camera::Camera;
use super::pyramid::Pyramid;
use crate::math::se3;

/// Side of the square patch, px.
const PATCH_SIZE: usize = 4;
/// Pixels per patch.
const PATCH_AREA: usize = PATCH_SIZE * PATCH_SIZE;
/// Offset of the first patch column/row from the floor of the feature position.
const PATCH_HALF: usize = 2;
/// Distance from the floor of the feature position to the farthest pixel read (patch, its 1-px
/// border and the bilinear neighbour): offsets −3 … +3.
const REACH: f64 = 3.0;
/// Side of the interpolated reference block (patch + 1-px border): offsets −3 … +2.
const BLOCK: usize = PATCH_SIZE + 2;

/// Smallest Levenberg-Marquardt damping (relative to the unit diagonal) before it drops to
/// pure Gauss-Newton, and the largest before a level gives up.
const LM_MIN_DAMPING: f64 = 1e-3;
const LM_MAX_DAMPING: f64 = 1e4;

/// Settings (SVO 1 defaults): levels 4 → 2, 30 iterations per level, stop when max |Δ| ≤ 1e-6.
/// TOML table `[vision.sparse_align]` of the navigation settings; a missing key takes its
/// default.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SparseAlignConfig {
    /// Coarsest pyramid level, where the alignment starts (level `l` is 2^l times coarser than
    /// the image; at most 4).
    pub max_level: u32,
    /// Finest pyramid level, where it ends (inclusive; at most `max_level`).
    pub min_level: u32,
    /// Largest number of Levenberg-Marquardt iterations per level, a count.
    pub max_iterations: u32,
    /// A level ends when every component of the step `δ` is at most this: m for the
    /// translation, rad for the rotation.
    pub min_step: f64,
    /// Fewest usable features, a count: a coarser level with fewer is skipped, the finest level
    /// with fewer is an error.
    pub min_features: usize,
}

impl Default for SparseAlignConfig {
    fn default() -> Self {
        Self {
            max_level: 4,
            min_level: 2,
            max_iterations: 30,
            min_step: 1e-6,
            min_features: 10,
        }
    }
}

/// A reference-frame feature with a known 3-D point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignFeature {
    /// Level-0 pixel of the feature in the reference image.
    pub px: Vector2<f64>,
    /// The point in reference-camera coordinates, m. Only its range `‖p_ref‖` is used: the
    /// alignment places the point on the bearing of `px` at that range (as SVO does), so the
    /// patch centre is exactly the observation.
    pub p_ref: Vector3<f64>,
}

/// The aligned pose and what it rests on.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseAlignResult {
    /// Pose of the reference camera in the current camera: p_cur = t_cur_ref · p_ref.
    pub t_cur_ref: Isometry3<f64>,
    /// Features used at the finest level.
    pub n_features: usize,
    /// Total iterations over all levels.
    pub iterations: u32,
    /// Mean squared photometric residual at the finest level, grey levels².
    pub mean_sq_residual: f64,
}

/// Why the alignment failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SparseAlignError {
    /// The settings are inconsistent.
    #[error("sparse alignment: invalid configuration: {0}")]
    InvalidConfig(&'static str),
    /// A pyramid lacks a level the alignment needs, or its size differs from the camera's.
    #[error(
        "sparse alignment: {which} pyramid level {level} is {width}×{height} px, the camera's is {expected_width}×{expected_height} px"
    )]
    PyramidMismatch {
        /// `"reference"` or `"current"`.
        which: &'static str,
        /// The level.
        level: u32,
        /// Its width, px (0 if the level is missing).
        width: u32,
        /// Its height, px (0 if the level is missing).
        height: u32,
        /// The camera level's width, px.
        expected_width: u32,
        /// The camera level's height, px.
        expected_height: u32,
    },
    /// Too few features could be used at the finest level (finite, in front of the camera,
    /// with their patches inside both images).
    #[error("sparse alignment: {found} usable features at level {level}, {needed} needed")]
    TooFewFeatures {
        /// The level.
        level: u32,
        /// Usable features.
        found: usize,
        /// The minimum.
        needed: usize,
    },
    /// The initial guess or the result is not finite.
    #[error("sparse alignment: non-finite pose")]
    NonFinite,
}

/// A feature prepared at one level: reference patch, its Jacobian and Hessian.
///
/// The Jacobian of patch pixel `j` is kept factored, `J_j = ∇I_j · W` with the 2 × 6 warp
/// Jacobian `W` shared by the patch, so that `Σ J_jᵀ r_j = Wᵀ Σ ∇I_jᵀ r_j` costs two
/// multiply-adds per pixel instead of six.
#[derive(Debug, Clone)]
struct LevelFeature {
    /// Point in the reference camera (bearing of the pixel × range), m.
    p_ref: Vector3<f64>,
    /// Reference patch intensities, row-major.
    patch: [f32; PATCH_AREA],
    /// Reference gradients `[∂I/∂u, ∂I/∂v]` per patch pixel, grey levels per level px.
    grad: [[f32; 2]; PATCH_AREA],
    /// `W = ∂Π_L(Exp(ξ) p)/∂ξ`, level px per (m, rad).
    warp: Matrix2x6<f64>,
    /// `Σ J_jᵀ J_j = Wᵀ (Σ ∇I_jᵀ ∇I_j) W` over the patch.
    hessian: Matrix6<f64>,
}

impl LevelFeature {
    /// `J_j = ∂r_j/∂δ` of patch pixel `j`: the derivative of its residual with respect to a
    /// right perturbation `δ` of `t_cur_ref`, grey levels per (m, rad).
    #[cfg(test)]
    fn jacobian(&self, j: usize) -> Vector6<f64> {
        let g = self.grad[j];
        (self.warp.row(0) * f64::from(g[0]) + self.warp.row(1) * f64::from(g[1])).transpose()
    }
}

/// Sums of one pass over the features at a pose.
#[derive(Debug, Clone)]
struct Evaluation {
    /// Features whose patch was inside the current image.
    n_features: usize,
    /// Mean squared residual over the patch pixels used, grey levels².
    mean_sq: f64,
    /// `Σ Jᵀ J`.
    hessian: Matrix6<f64>,
    /// `Σ Jᵀ r`.
    gradient: Vector6<f64>,
}

/// Floor of a level coordinate and its bilinear fraction, if the pixels at offsets −3 … +3
/// from the floor lie inside `0 … n − 1`.
#[inline]
fn stencil_axis(x: f64, n: u32) -> Option<(usize, f32)> {
    let x0 = x.floor();
    // Written so that NaN fails the test.
    if x0 >= REACH && x0 + REACH <= f64::from(n) - 1.0 {
        Some((x0 as usize, (x - x0) as f32))
    } else {
        None
    }
}

/// Bilinear weights `[w00, w01, w10, w11]` (top-left, top-right, bottom-left, bottom-right).
#[inline]
fn weights(fu: f32, fv: f32) -> [f32; 4] {
    [
        (1.0 - fu) * (1.0 - fv),
        fu * (1.0 - fv),
        (1.0 - fu) * fv,
        fu * fv,
    ]
}

/// Bilinear sample at raw index `i` (top-left pixel) of an image `w` wide.
#[inline]
fn sample(p: &[u8], i: usize, w: usize, k: &[f32; 4]) -> f32 {
    k[0] * f32::from(p[i])
        + k[1] * f32::from(p[i + 1])
        + k[2] * f32::from(p[i + w])
        + k[3] * f32::from(p[i + w + 1])
}

/// `∂Π_L(Exp(ξ) p)/∂ξ` at `ξ = 0`: how the reference projection of `p` moves when the
/// inverse-compositional increment `ξ = [v; ω]` moves the point, level-`L` px per (m, rad).
/// Equals `−J_OF,L(p)`.
fn reference_warp_jacobian(cam_l: &Camera, p_ref: &Vector3<f64>) -> Matrix2x6<f64> {
    -cam_l.optical_flow_jacobian(p_ref)
}

/// Prepare feature `feat` at a level (reference image `ref_img`, level camera `cam_l`, the
/// camera of level 0 `camera`); `None` if it is not finite or its patch leaves the image.
fn prepare_feature(
    camera: &Camera,
    cam_l: &Camera,
    level: u32,
    ref_img: &GrayImage,
    feat: &AlignFeature,
) -> Option<LevelFeature> {
    let range = feat.p_ref.norm();
    if !(range.is_finite() && range > 0.0 && feat.px.iter().all(|v| v.is_finite())) {
        return None;
    }
    let p_ref = camera.back_project(&feat.px) * range;
    let u = Camera::base_to_level(&feat.px, level);
    let (w, h) = ref_img.dimensions();
    let (x0, fu) = stencil_axis(u.x, w)?;
    let (y0, fv) = stencil_axis(u.y, h)?;
    let k = weights(fu, fv);
    let wu = w as usize;
    let pixels = ref_img.as_raw();
    // Interpolated block at offsets −3 … +2 from the floor.
    let mut block = [[0.0_f32; BLOCK]; BLOCK];
    for (m, row) in block.iter_mut().enumerate() {
        let start = (y0 + m - 3) * wu + x0 - 3;
        for (kk, value) in row.iter_mut().enumerate() {
            *value = sample(pixels, start + kk, wu, &k);
        }
    }
    let warp = reference_warp_jacobian(cam_l, &p_ref);
    let mut lf = LevelFeature {
        p_ref,
        patch: [0.0; PATCH_AREA],
        grad: [[0.0; 2]; PATCH_AREA],
        warp,
        hessian: Matrix6::zeros(),
    };
    // Structure tensor Σ ∇Iᵀ ∇I of the patch.
    let mut tensor = Matrix2::zeros();
    for y in 0..PATCH_SIZE {
        for x in 0..PATCH_SIZE {
            let (m, kk) = (y + 1, x + 1);
            let j = y * PATCH_SIZE + x;
            lf.patch[j] = block[m][kk];
            let gx = 0.5 * (block[m][kk + 1] - block[m][kk - 1]);
            let gy = 0.5 * (block[m + 1][kk] - block[m - 1][kk]);
            lf.grad[j] = [gx, gy];
            let (gx, gy) = (f64::from(gx), f64::from(gy));
            tensor += Matrix2::new(gx * gx, gx * gy, gx * gy, gy * gy);
        }
    }
    lf.hessian = warp.transpose() * tensor * warp;
    Some(lf)
}

/// Residuals of `lf` at pose `t` (rotation matrix `r`, translation `t`) into `out`; `false` if
/// the projected patch (plus border) leaves the current image or the point is behind.
#[inline]
fn feature_residuals(
    cam_l: &Camera,
    cur_img: &GrayImage,
    rot: &nalgebra::Matrix3<f64>,
    trans: &Vector3<f64>,
    lf: &LevelFeature,
    out: &mut [f32; PATCH_AREA],
) -> bool {
    let p_cur = rot * lf.p_ref + trans;
    let Some(u) = cam_l.project(&p_cur) else {
        return false;
    };
    let (w, h) = cur_img.dimensions();
    let (Some((x0, fu)), Some((y0, fv))) = (stencil_axis(u.x, w), stencil_axis(u.y, h)) else {
        return false;
    };
    let k = weights(fu, fv);
    let wu = w as usize;
    let pixels = cur_img.as_raw();
    for y in 0..PATCH_SIZE {
        let start = (y0 + y - PATCH_HALF) * wu + x0 - PATCH_HALF;
        for x in 0..PATCH_SIZE {
            let j = y * PATCH_SIZE + x;
            out[j] = sample(pixels, start + x, wu, &k) - lf.patch[j];
        }
    }
    true
}

/// Sparse image alignment with reusable buffers (no allocation per frame once warmed up).
#[derive(Debug, Clone)]
pub struct SparseAligner {
    cfg: SparseAlignConfig,
    level_features: Vec<LevelFeature>,
}

impl SparseAligner {
    /// An aligner with settings `cfg`.
    pub fn new(cfg: SparseAlignConfig) -> Self {
        Self {
            cfg,
            level_features: Vec::new(),
        }
    }

    /// The settings.
    pub fn config(&self) -> &SparseAlignConfig {
        &self.cfg
    }

    /// Align the current image to the reference one; see [`sparse_align`].
    pub fn align(
        &mut self,
        camera: &Camera,
        ref_pyr: &Pyramid,
        cur_pyr: &Pyramid,
        features: &[AlignFeature],
        t_cur_ref_guess: &Isometry3<f64>,
    ) -> Result<SparseAlignResult, SparseAlignError> {
        let cfg = self.cfg;
        if cfg.min_level > cfg.max_level {
            return Err(SparseAlignError::InvalidConfig(
                "min_level must not exceed max_level",
            ));
        }
        if cfg.max_level >= 16 {
            return Err(SparseAlignError::InvalidConfig(
                "max_level must be below 16",
            ));
        }
        if cfg.min_step.is_nan() || cfg.min_step < 0.0 {
            return Err(SparseAlignError::InvalidConfig(
                "min_step must be a non-negative number",
            ));
        }
        for level in cfg.min_level..=cfg.max_level {
            check_level(camera, ref_pyr, level, "reference")?;
            check_level(camera, cur_pyr, level, "current")?;
        }
        if !pose_is_finite(t_cur_ref_guess) {
            return Err(SparseAlignError::NonFinite);
        }
        let needed = cfg.min_features.max(1);
        let mut t = *t_cur_ref_guess;
        let mut iterations = 0_u32;
        for level in (cfg.min_level..=cfg.max_level).rev() {
            let cam_l = camera.level(level);
            let (Some(ref_img), Some(cur_img)) = (ref_pyr.level(level), cur_pyr.level(level))
            else {
                // Checked above.
                continue;
            };
            self.level_features.clear();
            self.level_features.extend(
                features
                    .iter()
                    .filter_map(|f| prepare_feature(camera, &cam_l, level, ref_img, f)),
            );
            if self.level_features.len() < needed {
                if level == cfg.min_level {
                    return Err(SparseAlignError::TooFewFeatures {
                        level,
                        found: self.level_features.len(),
                        needed,
                    });
                }
                continue;
            }
            // Levenberg-Marquardt: a step that raises the cost is refused and the damping
            // grows; an accepted one lowers it (SVO 1 stops the level at the first rise, which
            // on fine, noise-like textures ends the coarse levels before they converge).
            let mut eval = self.evaluate(&cam_l, cur_img, &t);
            if eval.n_features < needed || eval.mean_sq.is_nan() {
                continue;
            }
            let mut lambda = 0.0_f64;
            for _ in 0..cfg.max_iterations {
                let Some(step) = solve(&eval.hessian, &eval.gradient, lambda) else {
                    break;
                };
                iterations += 1;
                let candidate = t * se3::exp(&step);
                let next = self.evaluate(&cam_l, cur_img, &candidate);
                if next.n_features >= needed && next.mean_sq <= eval.mean_sq {
                    t = candidate;
                    eval = next;
                    lambda = if lambda < LM_MIN_DAMPING {
                        0.0
                    } else {
                        0.1 * lambda
                    };
                    if step.amax() <= cfg.min_step {
                        break;
                    }
                } else {
                    lambda = (10.0 * lambda).max(LM_MIN_DAMPING);
                    if lambda > LM_MAX_DAMPING {
                        break;
                    }
                }
            }
        }
        if !pose_is_finite(&t) {
            return Err(SparseAlignError::NonFinite);
        }
        let cam_l = camera.level(cfg.min_level);
        let Some(cur_img) = cur_pyr.level(cfg.min_level) else {
            return Err(SparseAlignError::TooFewFeatures {
                level: cfg.min_level,
                found: 0,
                needed,
            });
        };
        // The finest level's features are still in the buffer.
        let eval = self.evaluate(&cam_l, cur_img, &t);
        if eval.n_features < needed {
            return Err(SparseAlignError::TooFewFeatures {
                level: cfg.min_level,
                found: eval.n_features,
                needed,
            });
        }
        Ok(SparseAlignResult {
            t_cur_ref: se3::renormalized(&t),
            n_features: eval.n_features,
            iterations,
            mean_sq_residual: eval.mean_sq,
        })
    }

    /// Residuals, `Σ Jᵀ J` and `Σ Jᵀ r` of the prepared features at pose `t`.
    fn evaluate(&self, cam_l: &Camera, cur_img: &GrayImage, t: &Isometry3<f64>) -> Evaluation {
        let rot = t.rotation.to_rotation_matrix().into_inner();
        let trans = t.translation.vector;
        let mut hessian = Matrix6::zeros();
        let mut gradient = Vector6::zeros();
        let mut sum_sq = 0.0_f64;
        let mut n_features = 0;
        let mut r = [0.0_f32; PATCH_AREA];
        for lf in &self.level_features {
            if !feature_residuals(cam_l, cur_img, &rot, &trans, lf, &mut r) {
                continue;
            }
            let (mut gu, mut gv, mut sq) = (0.0_f32, 0.0_f32, 0.0_f32);
            for (rj, g) in r.iter().zip(&lf.grad) {
                sq += rj * rj;
                gu += g[0] * rj;
                gv += g[1] * rj;
            }
            gradient += lf.warp.transpose() * Vector2::new(f64::from(gu), f64::from(gv));
            sum_sq += f64::from(sq);
            hessian += lf.hessian;
            n_features += 1;
        }
        let n_pixels = (n_features * PATCH_AREA).max(1) as f64;
        Evaluation {
            n_features,
            mean_sq: sum_sq / n_pixels,
            hessian,
            gradient,
        }
    }
}

/// The Gauss-Newton step `δ = −H⁻¹ g`, by Cholesky on `H` scaled to a unit diagonal (the
/// translation and rotation columns differ by about the scene depth); `None` if `H` is not
/// positive definite or the step is not finite.
fn solve(hessian: &Matrix6<f64>, gradient: &Vector6<f64>, lambda: f64) -> Option<Vector6<f64>> {
    let mut d = Vector6::zeros();
    for i in 0..6 {
        let hii = hessian[(i, i)];
        if !(hii > 0.0 && hii.is_finite()) {
            return None;
        }
        d[i] = 1.0 / hii.sqrt();
    }
    // Scaled to a unit diagonal, so the damping `λ I` weighs every axis alike.
    let scaled =
        Matrix6::from_fn(|i, j| hessian[(i, j)] * d[i] * d[j]) + Matrix6::identity() * lambda;
    let y = scaled.cholesky()?.solve(&gradient.component_mul(&d));
    let step = -y.component_mul(&d);
    step.iter().all(|v| v.is_finite()).then_some(step)
}

fn pose_is_finite(t: &Isometry3<f64>) -> bool {
    t.translation
        .vector
        .iter()
        .chain(t.rotation.coords.iter())
        .all(|v| v.is_finite())
}

/// Whether `pyr` has level `level` with the size of the camera's level.
fn check_level(
    camera: &Camera,
    pyr: &Pyramid,
    level: u32,
    which: &'static str,
) -> Result<(), SparseAlignError> {
    let cam_l = camera.level(level);
    let expected = (cam_l.width_px(), cam_l.height_px());
    let actual = pyr.level(level).map_or((0, 0), GrayImage::dimensions);
    if actual == expected {
        Ok(())
    } else {
        Err(SparseAlignError::PyramidMismatch {
            which,
            level,
            width: actual.0,
            height: actual.1,
            expected_width: expected.0,
            expected_height: expected.1,
        })
    }
}

/// Sparse model-based image alignment: `t_cur_ref` (reference camera → current camera) that
/// best aligns 4 × 4 patches around `features` of the reference image with the current image,
/// starting from `t_cur_ref_guess` (module documentation). Both pyramids must have the levels
/// `cfg.min_level ..= cfg.max_level` at the camera's level sizes.
pub fn sparse_align(
    camera: &Camera,
    ref_pyr: &Pyramid,
    cur_pyr: &Pyramid,
    features: &[AlignFeature],
    t_cur_ref_guess: &Isometry3<f64>,
    cfg: &SparseAlignConfig,
) -> Result<SparseAlignResult, SparseAlignError> {
    SparseAligner::new(*cfg).align(camera, ref_pyr, cur_pyr, features, t_cur_ref_guess)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::features::{DetectorConfig, FeatureDetector};
    use crate::vision::test_scene::{Ground, SplitMix, camera, nadir_pose};
    use nalgebra::{Translation3, UnitQuaternion};
    use std::sync::OnceLock;

    /// Height of the reference camera over the plane, m.
    const H_M: f64 = 1_000.0;

    /// Two views of the textured plane and the reference features.
    struct Scene {
        camera: Camera,
        ground: Ground,
        zeta_ref: Isometry3<f64>,
        zeta_cur: Isometry3<f64>,
        ref_pyr: Pyramid,
        cur_pyr: Pyramid,
        features: Vec<AlignFeature>,
    }

    impl Scene {
        fn new(camera: Camera, zeta_cur: Isometry3<f64>, cell_size_px: u32) -> Self {
            let ground = Ground {
                seed: 11,
                ground_z_m: 0.0,
            };
            let zeta_ref = nadir_pose(0.0, 0.0, H_M, [0.0; 3]);
            let ref_pyr = ground.pyramid(&camera, &zeta_ref);
            let cur_pyr = ground.pyramid(&camera, &zeta_cur);
            let detector_cfg = DetectorConfig {
                cell_size_px,
                ..DetectorConfig::default()
            };
            let detector = FeatureDetector::new(detector_cfg, &camera).unwrap();
            let features = detector
                .detect(&ref_pyr, &detector.empty_occupancy())
                .unwrap()
                .iter()
                .map(|f| {
                    let z = ground.depth_m(&camera, &zeta_ref, &f.px).unwrap();
                    AlignFeature {
                        px: f.px,
                        p_ref: camera.back_project_depth(&f.px, z),
                    }
                })
                .collect();
            Self {
                camera,
                ground,
                zeta_ref,
                zeta_cur,
                ref_pyr,
                cur_pyr,
                features,
            }
        }

        fn t_true(&self) -> Isometry3<f64> {
            self.zeta_cur.inverse() * self.zeta_ref
        }

        /// `t_cur_ref` if the current camera were at `zeta_cur ∘ offset`.
        fn t_with_offset(&self, offset: &Isometry3<f64>) -> Isometry3<f64> {
            (self.zeta_cur * offset).inverse() * self.zeta_ref
        }

        /// Largest image distance between the projections through `t` and through the true
        /// pose of the feature points and of a 9 × 9 grid of ground points, level-0 px.
        fn max_reprojection_error_px(&self, t: &Isometry3<f64>) -> f64 {
            let (w, h) = (
                f64::from(self.camera.width_px()),
                f64::from(self.camera.height_px()),
            );
            let grid = (0..81).map(|i| {
                let px = Vector2::new(
                    (w - 1.0) * f64::from(i % 9) / 8.0,
                    (h - 1.0) * f64::from(i / 9) / 8.0,
                );
                let z = self
                    .ground
                    .depth_m(&self.camera, &self.zeta_ref, &px)
                    .unwrap();
                self.camera.back_project_depth(&px, z)
            });
            let t_true = self.t_true();
            self.features
                .iter()
                .map(|f| f.p_ref)
                .chain(grid)
                .map(|p| {
                    let a = self
                        .camera
                        .project(&t.transform_point(&p.into()).coords)
                        .unwrap();
                    let b = self
                        .camera
                        .project(&t_true.transform_point(&p.into()).coords)
                        .unwrap();
                    (a - b).norm()
                })
                .fold(0.0, f64::max)
        }
    }

    /// The paper's camera, 1,000 m over the plane; the current camera 3 m along the track,
    /// 2 m across, 2 m higher and rotated by 2–3 mrad: 2–6 px of true image motion.
    fn paper_scene() -> &'static Scene {
        static SCENE: OnceLock<Scene> = OnceLock::new();
        SCENE.get_or_init(|| {
            Scene::new(
                Camera::paper(),
                nadir_pose(3.0, -2.0, H_M + 2.0, [0.002, -0.0015, 0.003]),
                64,
            )
        })
    }

    fn offset(t: [f64; 3], rot: [f64; 3]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(rot)),
        )
    }

    /// The acceptance test: from guesses whose predicted image positions are 16 px off at
    /// level 0 (1 px at level 4) — by a translation of 16 GSD, by a rotation of 16/f rad, and
    /// both axes at once (a 22.6-px diagonal) — the alignment recovers the true motion.
    ///
    /// Tolerance: the alignment stops at level 2, where one pixel is 4 level-0 px. With ~190
    /// features × 16 pixels and only quantisation noise the random error is negligible; what
    /// remains is the bias of comparing bilinearly resampled level-2 images of two slightly
    /// different views (box filter and interpolation at different sub-pixel phases), about a
    /// tenth of a level-2 pixel. So every scene point must reproject within 0.5 level-0 px of
    /// its true position (an eighth of a level-2 pixel); SVO's feature alignment refines the
    /// rest at level 0.
    #[test]
    fn converges_from_16_px_at_level_0() {
        let s = paper_scene();
        assert_eq!(s.camera.height_px(), 1024);
        assert!(s.features.len() >= 150, "{} features", s.features.len());
        let gsd = H_M / s.camera.f_px();
        let a = 16.0 / s.camera.f_px();
        let d = 16.0 * gsd;
        let cases = [
            ("translation +x", offset([d, 0.0, 0.0], [0.0; 3])),
            ("translation -y", offset([0.0, -d, 0.0], [0.0; 3])),
            ("rotation about x", offset([0.0; 3], [a, 0.0, 0.0])),
            ("rotation about y", offset([0.0; 3], [0.0, -a, 0.0])),
            ("diagonal translation", offset([d, d, 0.0], [0.0; 3])),
            ("diagonal rotation", offset([0.0; 3], [-a, a, 0.0])),
            (
                "translation x, rotation x",
                offset([-d, 0.0, 0.0], [a, 0.0, 0.0]),
            ),
        ];
        let cfg = SparseAlignConfig::default();
        let mut aligner = SparseAligner::new(cfg);
        // The photometric cost at the true pose (no iterations): the optimum cannot be much
        // above it.
        let at_truth = sparse_align(
            &s.camera,
            &s.ref_pyr,
            &s.cur_pyr,
            &s.features,
            &s.t_true(),
            &SparseAlignConfig {
                max_iterations: 0,
                ..cfg
            },
        )
        .unwrap()
        .mean_sq_residual;
        for (name, off) in cases {
            let guess = s.t_with_offset(&off);
            let before = s.max_reprojection_error_px(&guess);
            assert!(before > 15.0, "{name}: guess only {before} px off");
            let r = aligner
                .align(&s.camera, &s.ref_pyr, &s.cur_pyr, &s.features, &guess)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            let after = s.max_reprojection_error_px(&r.t_cur_ref);
            eprintln!(
                "{name}: {before:.1} px -> {after:.3} px, {} features, {} iterations, \
                 mean sq residual {:.2}",
                r.n_features, r.iterations, r.mean_sq_residual
            );
            assert!(after <= 0.5, "{name}: {before} px -> {after} px");
            assert!(r.n_features * 10 >= s.features.len() * 9, "{name}: {r:?}");
            assert!(r.iterations >= 3 && r.iterations <= 3 * cfg.max_iterations);
            assert!(
                r.mean_sq_residual <= 1.05 * at_truth,
                "{name}: {r:?}, {at_truth} at the truth"
            );
        }
    }

    /// The geometric part of the Jacobian: `∂Π_L(Exp(ξ) p)/∂ξ` by central differences.
    #[test]
    fn warp_jacobian_matches_finite_differences() {
        let cam = Camera::paper();
        for level in [0, 2, 4] {
            let cam_l = cam.level(level);
            for p in [
                Vector3::new(120.0, -80.0, 1_000.0),
                Vector3::new(-300.0, 420.0, 950.0),
                Vector3::new(0.0, 0.0, 1_000.0),
            ] {
                let j = reference_warp_jacobian(&cam_l, &p);
                for k in 0..6 {
                    // 1 mm or 1 µrad.
                    let h = if k < 3 { 1e-3 } else { 1e-6 };
                    let mut d = Vector6::zeros();
                    d[k] = h;
                    let proj = |xi: &Vector6<f64>| {
                        cam_l
                            .project(&(se3::exp(xi) * nalgebra::Point3::from(p)).coords)
                            .unwrap()
                    };
                    let fd = (proj(&d) - proj(&(-d))) / (2.0 * h);
                    let err = (fd - j.column(k)).norm();
                    assert!(
                        err <= 1e-6 * j.column(k).norm().max(1e-3),
                        "level {level}, column {k}: {fd} vs {}",
                        j.column(k)
                    );
                }
            }
        }
    }

    /// The photometric Jacobian `J = −∇I_ref · J_OF,L` is the derivative of the patch residuals
    /// with respect to a right perturbation of `t_cur_ref` (at `t_cur_ref = I`, current image =
    /// reference image). On an affine intensity ramp the central-difference gradient and the
    /// bilinear interpolation are exact, so the finite differences must agree closely.
    #[test]
    fn photometric_jacobian_matches_finite_differences() {
        let (w, h) = (64_u32, 64_u32);
        let pixels: Vec<u8> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (2 * x + y + 10) as u8))
            .collect();
        let pyr = Pyramid::from_pixels(w, h, &pixels, 1).unwrap();
        let img = pyr.base();
        let cam = camera(w, h);
        let z = 50.0;
        for px in [
            Vector2::new(31.5, 31.5),
            Vector2::new(10.2, 50.7),
            Vector2::new(48.9, 12.3),
        ] {
            let feat = AlignFeature {
                px,
                // Off the bearing on purpose: only the range counts.
                p_ref: Vector3::new(0.0, 0.0, z),
            };
            let lf = prepare_feature(&cam, &cam, 0, img, &feat).unwrap();
            assert!((lf.p_ref.norm() - z).abs() < 1e-9);
            assert!((cam.project(&lf.p_ref).unwrap() - px).norm() < 1e-9);
            let jof = cam.optical_flow_jacobian(&lf.p_ref);
            let mut hessian = Matrix6::zeros();
            for pix in 0..PATCH_AREA {
                // J = −(2, 1) · J_OF.
                let j = lf.jacobian(pix);
                for c in 0..6 {
                    let expect = -(2.0 * jof[(0, c)] + jof[(1, c)]);
                    // The gradients are f32 differences of f32 interpolations: a few ulp of 255.
                    assert!((j[c] - expect).abs() <= 2e-5 * expect.abs().max(1.0));
                }
                hessian += j * j.transpose();
            }
            assert!((hessian - lf.hessian).amax() <= 1e-9 * hessian.amax());
            let residuals = |delta: &Vector6<f64>| {
                let t = se3::exp(delta);
                let rot = t.rotation.to_rotation_matrix().into_inner();
                let mut r = [0.0_f32; PATCH_AREA];
                assert!(feature_residuals(
                    &cam,
                    img,
                    &rot,
                    &t.translation.vector,
                    &lf,
                    &mut r
                ));
                r
            };
            assert!(residuals(&Vector6::zeros()).iter().all(|&r| r.abs() < 1e-4));
            for k in 0..6 {
                // About 0.2 px of image motion either way.
                let step = if k < 3 { 1e-2 } else { 2e-4 };
                let mut d = Vector6::zeros();
                d[k] = step;
                let (rp, rm) = (residuals(&d), residuals(&(-d)));
                for pix in 0..PATCH_AREA {
                    let fd = f64::from(rp[pix] - rm[pix]) / (2.0 * step);
                    let an = lf.jacobian(pix)[k];
                    assert!(
                        (fd - an).abs() <= 1e-3 * an.abs().max(1.0),
                        "px {px}, column {k}, pixel {pix}: {fd} vs {an}"
                    );
                }
            }
        }
    }

    /// A small scene for the error cases (192 × 256 px, levels 4 → 2 are 12×16 … 48×64 px; one
    /// feature per 32-px cell).
    fn small_scene() -> &'static Scene {
        static SCENE: OnceLock<Scene> = OnceLock::new();
        SCENE.get_or_init(|| {
            Scene::new(
                camera(192, 256),
                nadir_pose(2.0, 0.0, H_M, [0.0, 0.0, 0.001]),
                32,
            )
        })
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let s = small_scene();
        let cfg = SparseAlignConfig::default();
        let guess = Isometry3::identity();
        let run = |feats: &[AlignFeature], cfg: &SparseAlignConfig| {
            sparse_align(&s.camera, &s.ref_pyr, &s.cur_pyr, feats, &guess, cfg)
        };
        // The scene itself works.
        assert!(s.features.len() >= 30, "{}", s.features.len());
        let ok = run(&s.features, &cfg).unwrap();
        assert!(s.max_reprojection_error_px(&ok.t_cur_ref) < 0.5);
        // No features.
        assert!(matches!(
            run(&[], &cfg),
            Err(SparseAlignError::TooFewFeatures {
                level: 2,
                found: 0,
                needed: 10
            })
        ));
        // Features off the image or at its very edge.
        let off: Vec<_> = s
            .features
            .iter()
            .enumerate()
            .map(|(i, f)| AlignFeature {
                px: match i % 4 {
                    0 => Vector2::new(-50.0, 100.0),
                    1 => Vector2::new(100.0, 1e9),
                    2 => Vector2::new(0.0, 0.0),
                    _ => Vector2::new(191.0, 255.0),
                },
                ..*f
            })
            .collect();
        assert!(matches!(
            run(&off, &cfg),
            Err(SparseAlignError::TooFewFeatures { found: 0, .. })
        ));
        // Non-finite or degenerate points and pixels.
        let bad: Vec<_> = s
            .features
            .iter()
            .enumerate()
            .map(|(i, f)| match i % 4 {
                0 => AlignFeature {
                    p_ref: Vector3::new(f64::NAN, 0.0, 1.0),
                    ..*f
                },
                1 => AlignFeature {
                    p_ref: Vector3::new(0.0, f64::INFINITY, 1.0),
                    ..*f
                },
                2 => AlignFeature {
                    p_ref: Vector3::zeros(),
                    ..*f
                },
                _ => AlignFeature {
                    px: Vector2::new(f64::NAN, 3.0),
                    ..*f
                },
            })
            .collect();
        assert!(matches!(
            run(&bad, &cfg),
            Err(SparseAlignError::TooFewFeatures { found: 0, .. })
        ));
        // A non-finite guess.
        let nan_guess = Isometry3::translation(f64::NAN, 0.0, 0.0);
        assert_eq!(
            sparse_align(
                &s.camera,
                &s.ref_pyr,
                &s.cur_pyr,
                &s.features,
                &nan_guess,
                &cfg
            ),
            Err(SparseAlignError::NonFinite)
        );
        // A guess that puts every point behind the current camera.
        let behind = Isometry3::rotation(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        assert!(matches!(
            sparse_align(
                &s.camera,
                &s.ref_pyr,
                &s.cur_pyr,
                &s.features,
                &behind,
                &cfg
            ),
            Err(SparseAlignError::TooFewFeatures { found: 0, .. })
        ));
        // Pyramids of another size than the camera's, or of each other, or too shallow.
        let big = paper_scene();
        assert!(matches!(
            sparse_align(
                &s.camera,
                &s.ref_pyr,
                &big.cur_pyr,
                &s.features,
                &guess,
                &cfg
            ),
            Err(SparseAlignError::PyramidMismatch {
                which: "current",
                level: 2,
                width: 192,
                height: 256,
                expected_width: 48,
                expected_height: 64
            })
        ));
        assert!(matches!(
            sparse_align(
                &big.camera,
                &s.ref_pyr,
                &big.cur_pyr,
                &s.features,
                &guess,
                &cfg
            ),
            Err(SparseAlignError::PyramidMismatch {
                which: "reference",
                ..
            })
        ));
        let shallow = Pyramid::from_pixels(192, 256, s.cur_pyr.base().as_raw(), 3).unwrap();
        let err =
            sparse_align(&s.camera, &s.ref_pyr, &shallow, &s.features, &guess, &cfg).unwrap_err();
        assert!(
            matches!(
                err,
                SparseAlignError::PyramidMismatch {
                    level: 3,
                    width: 0,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("current pyramid level 3"), "{err}");
        // Inconsistent settings.
        for bad_cfg in [
            SparseAlignConfig {
                min_level: 3,
                max_level: 2,
                ..cfg
            },
            SparseAlignConfig {
                max_level: 40,
                ..cfg
            },
            SparseAlignConfig {
                min_step: f64::NAN,
                ..cfg
            },
        ] {
            assert!(matches!(
                run(&s.features, &bad_cfg),
                Err(SparseAlignError::InvalidConfig(_))
            ));
        }
        // Zero iterations return the guess.
        let none = run(
            &s.features,
            &SparseAlignConfig {
                max_iterations: 0,
                ..cfg
            },
        )
        .unwrap();
        assert_eq!(none.t_cur_ref, guess);
        assert_eq!(none.iterations, 0);
    }

    /// Random garbage (wild pixels, points, guesses) never panics.
    #[test]
    fn random_inputs_never_panic() {
        let s = small_scene();
        let cfg = SparseAlignConfig::default();
        let mut rng = SplitMix(99);
        let mut aligner = SparseAligner::new(cfg);
        for _ in 0..200 {
            let scale = 10_f64.powf(6.0 * rng.unit());
            let feats: Vec<_> = (0..20)
                .map(|_| AlignFeature {
                    px: Vector2::new(rng.symmetric(), rng.symmetric()) * 300.0
                        + Vector2::new(96.0, 128.0),
                    p_ref: Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * scale,
                })
                .collect();
            let guess = Isometry3::from_parts(
                Translation3::from(Vector3::new(rng.normal(), rng.normal(), rng.normal()) * scale),
                UnitQuaternion::from_scaled_axis(
                    Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.1,
                ),
            );
            if let Ok(r) = aligner.align(&s.camera, &s.ref_pyr, &s.cur_pyr, &feats, &guess) {
                assert!(pose_is_finite(&r.t_cur_ref));
                assert!(r.n_features >= cfg.min_features);
            }
        }
    }

    /// Same inputs, bit-identical result, from the free function and from a reused aligner.
    #[test]
    fn deterministic() {
        let s = paper_scene();
        let cfg = SparseAlignConfig::default();
        let guess = s.t_with_offset(&offset([5.0, -3.0, 1.0], [0.004, 0.002, -0.001]));
        let a = sparse_align(&s.camera, &s.ref_pyr, &s.cur_pyr, &s.features, &guess, &cfg).unwrap();
        let mut aligner = SparseAligner::new(cfg);
        // Warm the buffers with another problem first.
        aligner
            .align(
                &s.camera,
                &s.ref_pyr,
                &s.cur_pyr,
                &s.features[..50],
                &s.t_true(),
            )
            .unwrap();
        let b = aligner
            .align(&s.camera, &s.ref_pyr, &s.cur_pyr, &s.features, &guess)
            .unwrap();
        let bits = |r: &SparseAlignResult| {
            let t = &r.t_cur_ref;
            let mut v: Vec<u64> = t
                .translation
                .vector
                .iter()
                .chain(t.rotation.coords.iter())
                .map(|x| x.to_bits())
                .collect();
            v.extend([
                r.n_features as u64,
                u64::from(r.iterations),
                r.mean_sq_residual.to_bits(),
            ]);
            v
        };
        assert_eq!(bits(&a), bits(&b));
        assert!(s.max_reprojection_error_px(&a.t_cur_ref) < 0.5);
    }

    /// Identical images and a perfect guess: the pose stays, the residual is tiny.
    #[test]
    fn a_perfect_guess_on_identical_images_stays() {
        let s = small_scene();
        let r = sparse_align(
            &s.camera,
            &s.ref_pyr,
            &s.ref_pyr,
            &s.features,
            &Isometry3::identity(),
            &SparseAlignConfig::default(),
        )
        .unwrap();
        let tau = se3::log(&r.t_cur_ref);
        assert!(
            tau.amax() < 1e-9 || r.mean_sq_residual < 1e-6,
            "{tau}, {r:?}"
        );
        assert!(r.mean_sq_residual < 1e-6, "{r:?}");
        assert!(r.n_features >= 10 && r.n_features <= s.features.len());
    }
}
