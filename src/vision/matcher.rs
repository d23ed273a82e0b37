//! Direct patch matching of semi-direct visual odometry (SVO; Forster, Pizzoli and Scaramuzza,
//! ICRA 2014, section "Relaxation through feature alignment", and SVO's depth filter): a map
//! point's patch in its reference keyframe is warped into the current image's geometry and
//! aligned there with sub-pixel accuracy; a depth-filter seed is searched along its epipolar
//! segment and triangulated.
//!
//! - Affine warp ([`affine_warp`]): the patch is assumed fronto-parallel in the reference camera
//!   (a plane of constant z through the point); probes 5 px (of the reference level) right of and
//!   below the feature are back-projected onto that plane and projected into the current image;
//!   `A_cur_ref` maps reference-level pixels to current level-0 pixels.
//! - Search level ([`search_level`]): the pyramid level where `det A` is nearest 1 (SVO: while
//!   `det > 3`, next level and `det /= 4`), at most [`MAX_SEARCH_LEVEL`].
//! - Warped patch ([`warp_patch`]): 10 × 10 samples (8 × 8 and a 1-px border) at offsets
//!   `k ∈ [−5, 4]²` of the search level around the feature, bilinear in the reference level; the
//!   8 × 8 patch uses `k ∈ [−4, 3]²` like SVO (its centre is the feature, so positions are not
//!   biased); gradients are central differences on the 10 × 10 samples.
//! - Alignment ([`align_2d`]): inverse-compositional Gauss-Newton on the position and an
//!   intensity offset, `J = [g_u, g_v, 1]` of the reference patch, the 3 × 3 normal matrix
//!   inverted once; at most 10 iterations, converged when the step is below 0.03 px.
//! - Epipolar search ([`find_epipolar_match`]): the seed's range interval projected into the
//!   current image at the search level; shorter than 2 px: alignment from the midpoint;
//!   otherwise a zero-mean SSD ([`zmssd`]) scan at 0.7-px steps from the far end to the near end
//!   (at most 1000 steps), the best below `2000 × 64` refined by [`align_2d`]; then the range
//!   along the reference bearing by least-squares two-ray triangulation ([`triangulate_range`]).
//!
//! Coordinates follow [`crate::vision::camera`]: pixel centres at integers, level `l` pixel
//! `u_l = (u_0 + 0.5) / 2^l − 0.5`. "Range" is the distance along the unit bearing, as in the
//! depth filter. Beyond SVO 1: a reference patch too flat to be located (smallest eigenvalue of
//! its mean gradient covariance below [`MIN_PATCH_TEXTURE`]) is refused by both searches, since
//! it would otherwise "match" any flat area (and the alignment would then return its start).
//!
//! Hot path: no allocation; patches and their sums are `f32`, geometry `f64`.

use image::GrayImage;
use nalgebra::{Isometry3, Matrix2, Matrix3, Point3, Vector2, Vector3};

use crate::vision::camera::Camera;
use crate::vision::pyramid::{Pyramid, interpolate};

/// Side of the aligned patch (SVO: 8).
pub const PATCH_PX: usize = 8;
/// Side of the patch with its 1-px border (10), from which the gradients are taken.
pub const PATCH_WITH_BORDER_PX: usize = 10;
/// Half the aligned patch: the patch spans offsets `−4 … 3` around its centre.
const HALF_PATCH: usize = PATCH_PX / 2;
/// Number of pixels of the aligned patch.
const PATCH_AREA: usize = PATCH_PX * PATCH_PX;

/// Coarsest pyramid level used for matching (SVO: `n_pyr_levels = 3`, levels 0–2).
pub const MAX_SEARCH_LEVEL: u32 = 2;
/// Largest number of [`align_2d`] iterations (SVO `align_max_iter`).
pub const ALIGN_MAX_ITERATIONS: u32 = 10;
/// [`align_2d`] has converged when its position step is below this, px of its level.
pub const ALIGN_CONVERGENCE_PX: f64 = 0.03;
/// Distance of the affine-warp probes from the feature, px of the reference level.
pub const AFFINE_PROBE_PX: f64 = 5.0;
/// A warp whose determinant exceeds this moves the search one level up (SVO).
pub const SEARCH_LEVEL_DET: f64 = 3.0;
/// Step of the epipolar scan, px of the search level.
pub const EPIPOLAR_STEP_PX: f64 = 0.7;
/// Longest epipolar scan, steps (SVO `max_epi_search_steps`); longer segments fail.
pub const MAX_EPIPOLAR_STEPS: f64 = 1000.0;
/// Segments shorter than this (px of the search level) skip the scan: alignment from the midpoint.
pub const SHORT_SEGMENT_PX: f64 = 2.0;
/// A scan match must score below this zero-mean SSD over the 8 × 8 patch (SVO: 2000 per pixel).
pub const ZMSSD_THRESHOLD: f32 = 2000.0 * PATCH_AREA as f32;
/// Two rays closer to parallel than `det(AᵀA) = sin² angle < MIN_TRIANGULATION_DET` are not
/// triangulated (SVO's `depthFromTriangulation`; 1 mrad of parallax).
pub const MIN_TRIANGULATION_DET: f64 = 1e-6;
/// Least texture of a reference patch that the searches accept: the smallest eigenvalue of the
/// mean covariance of its gradients, (grey levels per pixel of the search level)². Beyond SVO 1,
/// which would "match" a flat patch anywhere flat. Chosen between the noise of a flat patch
/// (central differences of noise σ have variance σ²/2: 2 for σ = 2 grey levels) and the
/// detector's minimum Shi-Tomasi score (10 at level 0, which warping to a 1.4× larger scale
/// halves); rendered flat patches score 0, textured ground tens to hundreds.
pub const MIN_PATCH_TEXTURE: f32 = 4.0;

/// Affine warp `A_cur_ref` (2 × 2) of a patch at reference pixel `ref_px` (level 0) observed at
/// pyramid level `ref_level`, assumed fronto-parallel in the reference camera at range `range_m`
/// (along the unit bearing), into the current image: `A` maps a displacement in `ref_level`
/// pixels of the reference image to one in level-0 pixels of the current image. `t_cur_ref` maps
/// reference-camera points into current-camera points. `None` if a probe point falls behind the
/// current camera or an input is not finite (or the range not positive).
pub fn affine_warp(
    camera: &Camera,
    ref_px: &Vector2<f64>,
    ref_level: u32,
    range_m: f64,
    t_cur_ref: &Isometry3<f64>,
) -> Option<Matrix2<f64>> {
    if !(range_m.is_finite() && range_m > 0.0 && ref_px.iter().all(|c| c.is_finite())) {
        return None;
    }
    let p_ref = camera.back_project(ref_px) * range_m;
    let z = p_ref.z;
    if z.is_nan() || z <= 0.0 {
        return None;
    }
    let probe = AFFINE_PROBE_PX * f64::from(1_u32 << ref_level.min(16));
    let project =
        |p: Vector3<f64>| camera.project(&t_cur_ref.transform_point(&Point3::from(p)).coords);
    let centre = project(p_ref)?;
    let du = project(camera.ray(&(ref_px + Vector2::new(probe, 0.0))) * z)?;
    let dv = project(camera.ray(&(ref_px + Vector2::new(0.0, probe))) * z)?;
    let a = Matrix2::from_columns(&[
        (du - centre) / AFFINE_PROBE_PX,
        (dv - centre) / AFFINE_PROBE_PX,
    ]);
    a.iter().all(|c| c.is_finite()).then_some(a)
}

/// SVO's search level: starting at level 0, while `det A > 3` go one level up (the determinant
/// shrinks by 4 per level), at most `max_level`. A non-finite determinant gives level 0.
pub fn search_level(a_cur_ref: &Matrix2<f64>, max_level: u32) -> u32 {
    let mut det = a_cur_ref.determinant();
    let mut level = 0;
    while det > SEARCH_LEVEL_DET && level < max_level {
        level += 1;
        det *= 0.25;
    }
    level
}

/// The reference patch warped into the current image's geometry at its search level.
#[derive(Debug, Clone, PartialEq)]
pub struct WarpedPatch {
    /// 10 × 10 samples with border, row-major.
    with_border: [f32; PATCH_WITH_BORDER_PX * PATCH_WITH_BORDER_PX],
    /// Inner 8 × 8 samples, row-major.
    patch: [f32; PATCH_AREA],
    /// `∂T/∂u` of the inner samples (central differences), grey levels per search-level pixel.
    grad_u: [f32; PATCH_AREA],
    /// `∂T/∂v` of the inner samples.
    grad_v: [f32; PATCH_AREA],
    /// Sum and sum of squares of the inner samples (for the ZMSSD).
    sum: f32,
    sum_sq: f32,
    /// Inverse of `Σ J Jᵀ`, `J = [g_u, g_v, 1]`; `None` if singular (a flat patch).
    h_inv: Option<Matrix3<f64>>,
    /// Smallest eigenvalue of the mean gradient covariance, (grey levels / px)².
    texture: f32,
    /// The pyramid level whose geometry the patch has.
    level: u32,
}

impl WarpedPatch {
    /// The 10 × 10 samples with their border, row-major.
    pub fn samples_with_border(&self) -> &[f32; PATCH_WITH_BORDER_PX * PATCH_WITH_BORDER_PX] {
        &self.with_border
    }

    /// The inner 8 × 8 samples, row-major; sample `(i, j)` lies at offset `(i − 4, j − 4)` from
    /// the patch centre.
    pub fn samples(&self) -> &[f32; PATCH_AREA] {
        &self.patch
    }

    /// The search level the patch was warped for.
    pub fn level(&self) -> u32 {
        self.level
    }

    /// Smallest eigenvalue of the mean covariance of the patch gradients, (grey levels per
    /// search-level pixel)²: how well the patch can be located (compare [`MIN_PATCH_TEXTURE`]).
    pub fn texture(&self) -> f32 {
        self.texture
    }

    /// Whether the patch has at least [`MIN_PATCH_TEXTURE`] (the searches refuse it otherwise).
    pub fn is_textured(&self) -> bool {
        self.texture >= MIN_PATCH_TEXTURE
    }

    /// Build from the 10 × 10 samples.
    fn from_samples(
        with_border: [f32; PATCH_WITH_BORDER_PX * PATCH_WITH_BORDER_PX],
        level: u32,
    ) -> Self {
        const W: usize = PATCH_WITH_BORDER_PX;
        let mut patch = [0.0_f32; PATCH_AREA];
        let mut grad_u = [0.0_f32; PATCH_AREA];
        let mut grad_v = [0.0_f32; PATCH_AREA];
        let (mut sum, mut sum_sq) = (0.0_f32, 0.0_f32);
        // Normal matrix and gradient moments in f64 (64 terms of up to 255²).
        let mut h = Matrix3::<f64>::zeros();
        for y in 0..PATCH_PX {
            for x in 0..PATCH_PX {
                let i = (y + 1) * W + x + 1;
                let k = y * PATCH_PX + x;
                let t = with_border[i];
                let gu = 0.5 * (with_border[i + 1] - with_border[i - 1]);
                let gv = 0.5 * (with_border[i + W] - with_border[i - W]);
                patch[k] = t;
                grad_u[k] = gu;
                grad_v[k] = gv;
                sum += t;
                sum_sq += t * t;
                let j = Vector3::new(f64::from(gu), f64::from(gv), 1.0);
                h += j * j.transpose();
            }
        }
        // Gradient covariance: the Schur complement of the offset in H, per pixel.
        let n = PATCH_AREA as f64;
        let cuu = (h[(0, 0)] - h[(0, 2)] * h[(0, 2)] / n) / n;
        let cvv = (h[(1, 1)] - h[(1, 2)] * h[(1, 2)] / n) / n;
        let cuv = (h[(0, 1)] - h[(0, 2)] * h[(1, 2)] / n) / n;
        let half_trace = 0.5 * (cuu + cvv);
        let root = (0.25 * (cuu - cvv) * (cuu - cvv) + cuv * cuv).sqrt();
        let texture = (half_trace - root).max(0.0) as f32;
        let h_inv = h
            .try_inverse()
            .filter(|m| texture > 0.0 && m.iter().all(|c| c.is_finite()));
        Self {
            with_border,
            patch,
            grad_u,
            grad_v,
            sum,
            sum_sq,
            h_inv,
            texture,
            level,
        }
    }
}

/// The reference patch warped into the current image's geometry at `search_level`: 10 × 10
/// samples (with border) at search-level offsets `k ∈ [−5, 4]²` around the feature, read in the
/// reference image at `A⁻¹ k 2^search_level + ref_px` (reference level `ref_level`). `None` if a
/// sample leaves the reference image, the level does not exist, or `A` is singular.
pub fn warp_patch(
    ref_pyr: &Pyramid,
    a_cur_ref: &Matrix2<f64>,
    ref_px: &Vector2<f64>,
    ref_level: u32,
    search_level: u32,
) -> Option<WarpedPatch> {
    const W: usize = PATCH_WITH_BORDER_PX;
    let img = ref_pyr.level(ref_level)?;
    let a_inv = a_cur_ref
        .try_inverse()
        .filter(|m| m.iter().all(|c| c.is_finite()))?;
    let centre = Camera::base_to_level(ref_px, ref_level);
    let scaled = a_inv * f64::from(1_u32 << search_level.min(16));
    let mut samples = [0.0_f32; W * W];
    let half = (W / 2) as f64;
    for (y, row) in samples.chunks_exact_mut(W).enumerate() {
        let ky = y as f64 - half;
        for (x, s) in row.iter_mut().enumerate() {
            let kx = x as f64 - half;
            let p = centre + scaled * Vector2::new(kx, ky);
            *s = interpolate(img, p.x, p.y)?;
        }
    }
    Some(WarpedPatch::from_samples(samples, search_level))
}

/// 2-D inverse-compositional alignment of `patch` in `cur_img` (one pyramid level, the patch's
/// search level) from `start_px` (that level's pixels), estimating an intensity offset: at most
/// `max_iterations` Gauss-Newton steps on `(u, v, offset)` with the reference patch's Jacobian
/// `[g_u, g_v, 1]`; converged when the position step is below [`ALIGN_CONVERGENCE_PX`]. Returns
/// the aligned patch centre at that level; `None` if the patch comes within 4 px of the border
/// (so that the 8 × 8 bilinear window fits), a value is not finite, the patch is flat, or it does
/// not converge.
pub fn align_2d(
    cur_img: &GrayImage,
    patch: &WarpedPatch,
    start_px: &Vector2<f64>,
    max_iterations: u32,
) -> Option<Vector2<f64>> {
    let h_inv = patch.h_inv?;
    let (w, h) = cur_img.dimensions();
    let (w, h) = (w as usize, h as usize);
    let half = HALF_PATCH as f64;
    // Top-left pixel u0 − 4 ≥ 0 and the last one u0 + 3 + 1 ≤ W − 1.
    let (max_u, max_v) = ((w as f64) - 1.0 - half, (h as f64) - 1.0 - half);
    let pixels = cur_img.as_raw();
    let (mut u, mut v) = (start_px.x, start_px.y);
    let mut offset = 0.0_f64;
    let conv2 = ALIGN_CONVERGENCE_PX * ALIGN_CONVERGENCE_PX;
    for _ in 0..max_iterations {
        let (u0, v0) = (u.floor(), v.floor());
        // Written so that NaN fails.
        if !(u0 >= half && v0 >= half && u0 <= max_u && v0 <= max_v) {
            return None;
        }
        let (fu, fv) = ((u - u0) as f32, (v - v0) as f32);
        let (w_tl, w_tr) = ((1.0 - fu) * (1.0 - fv), fu * (1.0 - fv));
        let (w_bl, w_br) = ((1.0 - fu) * fv, fu * fv);
        let top_left = (v0 as usize - HALF_PATCH) * w + (u0 as usize - HALF_PATCH);
        let m = offset as f32;
        let (mut ju, mut jv, mut jm) = (0.0_f32, 0.0_f32, 0.0_f32);
        for y in 0..PATCH_PX {
            let row = top_left + y * w;
            let above = &pixels[row..row + PATCH_PX + 1];
            let below = &pixels[row + w..row + w + PATCH_PX + 1];
            let k0 = y * PATCH_PX;
            for x in 0..PATCH_PX {
                let i = w_tl * f32::from(above[x])
                    + w_tr * f32::from(above[x + 1])
                    + w_bl * f32::from(below[x])
                    + w_br * f32::from(below[x + 1]);
                let k = k0 + x;
                let r = i + m - patch.patch[k];
                ju += patch.grad_u[k] * r;
                jv += patch.grad_v[k] * r;
                jm += r;
            }
        }
        let step = -(h_inv * Vector3::new(f64::from(ju), f64::from(jv), f64::from(jm)));
        if !step.iter().all(|c| c.is_finite()) {
            return None;
        }
        u += step.x;
        v += step.y;
        offset += step.z;
        if step.x * step.x + step.y * step.y < conv2 {
            return Some(Vector2::new(u, v));
        }
    }
    None
}

/// Zero-mean SSD of the patch (its inner 8 × 8) against the 8 × 8 block of `cur_img` centred at
/// integer pixel `(u, v)` (columns `u − 4 … u + 3`, rows likewise):
/// `Σ ((R − R̄) − (C − C̄))² = S_RR − 2 S_RC + S_CC − (S_R − S_C)² / 64`. `None` if the block
/// leaves the image.
pub fn zmssd(cur_img: &GrayImage, patch: &WarpedPatch, u: i32, v: i32) -> Option<f32> {
    let (w, h) = cur_img.dimensions();
    let half = HALF_PATCH as i64;
    let (u, v) = (i64::from(u), i64::from(v));
    if u < half || v < half || u + half > i64::from(w) || v + half > i64::from(h) {
        return None;
    }
    let w = w as usize;
    let top_left = (v - half) as usize * w + (u - half) as usize;
    let pixels = cur_img.as_raw();
    let (mut s_c, mut s_cc, mut s_rc) = (0.0_f32, 0.0_f32, 0.0_f32);
    for y in 0..PATCH_PX {
        let row = &pixels[top_left + y * w..top_left + y * w + PATCH_PX];
        let refs = &patch.patch[y * PATCH_PX..(y + 1) * PATCH_PX];
        for (&c, &r) in row.iter().zip(refs) {
            let c = f32::from(c);
            s_c += c;
            s_cc += c * c;
            s_rc += r * c;
        }
    }
    let d = patch.sum - s_c;
    Some(patch.sum_sq - 2.0 * s_rc + s_cc - d * d / PATCH_AREA as f32)
}

/// A map point found in the current image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectMatch {
    /// Aligned position, level-0 px.
    pub px: Vector2<f64>,
    /// The pyramid level it was aligned on (the search level).
    pub level: u32,
}

/// Direct match of a map point (SVO `findMatchDirect`, steps 2–6): the patch of the reference
/// keyframe observation (`ref_px` at level 0, detected at `ref_level`), at range `range_m` from
/// the reference camera, warped with the relative pose `t_cur_ref` into the current image and
/// aligned there from the predicted level-0 pixel `predicted_px`. `None` if the warp, the patch
/// (off the reference image, flat) or the alignment fail.
#[expect(
    clippy::too_many_arguments,
    reason = "camera, reference observation (image, pixel, level, range), relative pose, current \
              image and predicted pixel: separate pieces of tracking state at each call"
)]
pub fn find_match_direct(
    camera: &Camera,
    ref_pyr: &Pyramid,
    ref_px: &Vector2<f64>,
    ref_level: u32,
    range_m: f64,
    t_cur_ref: &Isometry3<f64>,
    cur_pyr: &Pyramid,
    predicted_px: &Vector2<f64>,
) -> Option<DirectMatch> {
    let a = affine_warp(camera, ref_px, ref_level, range_m, t_cur_ref)?;
    let max_level = MAX_SEARCH_LEVEL.min(cur_pyr.n_levels().saturating_sub(1));
    let level = search_level(&a, max_level);
    let patch = warp_patch(ref_pyr, &a, ref_px, ref_level, level)?;
    if !patch.is_textured() {
        return None;
    }
    let cur_img = cur_pyr.level(level)?;
    let start = Camera::base_to_level(predicted_px, level);
    let px_l = align_2d(cur_img, &patch, &start, ALIGN_MAX_ITERATIONS)?;
    Some(DirectMatch {
        px: Camera::level_to_base(&px_l, level),
        level,
    })
}

/// A depth-filter seed found along its epipolar segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpipolarMatch {
    /// Aligned position in the current image, level-0 px.
    pub px: Vector2<f64>,
    /// The pyramid level it was found on (the search level).
    pub level: u32,
    /// Triangulated range along the reference bearing, m.
    pub range_m: f64,
}

/// Why an epipolar search failed (for the depth filter, every failure is a miss).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum EpipolarError {
    /// A non-finite input, a range interval that is not `0 < near ≤ far`, or a missing level.
    #[error("epipolar search: invalid input")]
    InvalidInput,
    /// An end of the range interval (or a warp probe) lies behind the current camera.
    #[error("epipolar search: the segment lies behind the current camera")]
    BehindCamera,
    /// The reference patch leaves the reference image, or no position of the segment has its
    /// patch inside the current image.
    #[error("epipolar search: off the image")]
    OffImage,
    /// The segment needs more than [`MAX_EPIPOLAR_STEPS`] steps.
    #[error("epipolar search: segment of {steps:.0} steps is too long")]
    SegmentTooLong {
        /// Steps the scan would take.
        steps: f64,
    },
    /// No position scores below [`ZMSSD_THRESHOLD`], or the reference patch is too flat to be
    /// located (texture below [`MIN_PATCH_TEXTURE`]).
    #[error("epipolar search: no match (best ZMSSD {best_score})")]
    NoMatch {
        /// Best score along the segment (infinite when the patch was refused as flat).
        best_score: f32,
    },
    /// The sub-pixel alignment did not converge.
    #[error("epipolar search: sub-pixel refinement failed")]
    RefinementFailed,
    /// The rays are (nearly) parallel or meet behind a camera.
    #[error("epipolar search: triangulation failed")]
    TriangulationFailed,
}

/// Epipolar search for a depth-filter seed (SVO `findEpipolarMatchDirect`): the reference
/// feature (`ref_px` at level 0, `ref_level`), its range interval `near_far_m = (near, far)`
/// along the reference bearing and current estimate `range_m` (for the warp); the segment
/// between the projections of the near and far points into the current image is scanned at
/// [`EPIPOLAR_STEP_PX`] steps of the search level with [`zmssd`] (accepted below
/// [`ZMSSD_THRESHOLD`]), the best position refined by [`align_2d`], and the range along the
/// reference bearing triangulated from the aligned pixel. Segments shorter than
/// [`SHORT_SEGMENT_PX`] are aligned from their midpoint without a scan.
#[expect(
    clippy::too_many_arguments,
    reason = "camera, reference feature (image, pixel, level, range and its interval), relative \
              pose and current image: separate pieces of depth-filter state at each call"
)]
pub fn find_epipolar_match(
    camera: &Camera,
    ref_pyr: &Pyramid,
    ref_px: &Vector2<f64>,
    ref_level: u32,
    range_m: f64,
    near_far_m: (f64, f64),
    t_cur_ref: &Isometry3<f64>,
    cur_pyr: &Pyramid,
) -> Result<EpipolarMatch, EpipolarError> {
    let (near, far) = near_far_m;
    let finite_pose = t_cur_ref
        .translation
        .vector
        .iter()
        .chain(t_cur_ref.rotation.coords.iter())
        .all(|c| c.is_finite());
    if !(near.is_finite()
        && far.is_finite()
        && range_m.is_finite()
        && near > 0.0
        && near <= far
        && range_m > 0.0
        && finite_pose
        && ref_px.iter().all(|c| c.is_finite()))
    {
        return Err(EpipolarError::InvalidInput);
    }
    let f_ref = camera.back_project(ref_px);
    let project =
        |d: f64| camera.project(&t_cur_ref.transform_point(&Point3::from(f_ref * d)).coords);
    let (px_near, px_far) = match (project(near), project(far)) {
        (Some(a), Some(b)) => (a, b),
        _ => return Err(EpipolarError::BehindCamera),
    };
    let a = affine_warp(camera, ref_px, ref_level, range_m, t_cur_ref)
        .ok_or(EpipolarError::BehindCamera)?;
    let max_level = MAX_SEARCH_LEVEL.min(cur_pyr.n_levels().saturating_sub(1));
    let level = search_level(&a, max_level);
    let cur_img = cur_pyr.level(level).ok_or(EpipolarError::InvalidInput)?;
    if ref_level >= ref_pyr.n_levels() {
        return Err(EpipolarError::InvalidInput);
    }
    let patch = warp_patch(ref_pyr, &a, ref_px, ref_level, level).ok_or(EpipolarError::OffImage)?;
    if !patch.is_textured() {
        return Err(EpipolarError::NoMatch {
            best_score: f32::INFINITY,
        });
    }
    let near_l = Camera::base_to_level(&px_near, level);
    let far_l = Camera::base_to_level(&px_far, level);
    let length = (near_l - far_l).norm();
    let (w, h) = cur_img.dimensions();
    // Scan positions keep one pixel more than the 8 × 8 block so the alignment can move.
    let margin = HALF_PATCH as i64 + 1;
    let inside = |u: i64, v: i64| {
        u >= margin && v >= margin && u + margin < i64::from(w) && v + margin < i64::from(h)
    };
    let start = if length < SHORT_SEGMENT_PX {
        let mid = 0.5 * (near_l + far_l);
        if !inside(mid.x.round() as i64, mid.y.round() as i64) {
            return Err(EpipolarError::OffImage);
        }
        mid
    } else {
        let steps = (length / EPIPOLAR_STEP_PX).ceil();
        if steps > MAX_EPIPOLAR_STEPS {
            return Err(EpipolarError::SegmentTooLong { steps });
        }
        let n = steps as u32;
        let step = (near_l - far_l) / steps;
        let mut best: Option<(f32, i64, i64)> = None;
        let mut last = None;
        for i in 0..=n {
            let p = far_l + step * f64::from(i);
            let (u, v) = (p.x.round() as i64, p.y.round() as i64);
            if last == Some((u, v)) || !inside(u, v) {
                continue;
            }
            last = Some((u, v));
            // `inside` keeps u, v well within i32.
            let Some(score) = zmssd(cur_img, &patch, u as i32, v as i32) else {
                continue;
            };
            if best.is_none_or(|(s, _, _)| score < s) {
                best = Some((score, u, v));
            }
        }
        let (score, u, v) = best.ok_or(EpipolarError::OffImage)?;
        if score.is_nan() || score >= ZMSSD_THRESHOLD {
            return Err(EpipolarError::NoMatch { best_score: score });
        }
        Vector2::new(u as f64, v as f64)
    };
    let px_l = align_2d(cur_img, &patch, &start, ALIGN_MAX_ITERATIONS)
        .ok_or(EpipolarError::RefinementFailed)?;
    let px = Camera::level_to_base(&px_l, level);
    let f_cur = camera.back_project(&px);
    let range_m =
        triangulate_range(&f_ref, &f_cur, t_cur_ref).ok_or(EpipolarError::TriangulationFailed)?;
    Ok(EpipolarMatch { px, level, range_m })
}

/// Range along the reference bearing `f_ref` (unit; normalised here) that best agrees with the
/// current bearing `f_cur` (current camera) given `t_cur_ref` (SVO's least-squares two-ray
/// triangulation): with `A = [R f_ref, f_cur]`, `λ = −(AᵀA)⁻¹ Aᵀ t`, the range is `λ₀`. `None`
/// if the rays are nearly parallel (`det AᵀA < MIN_TRIANGULATION_DET`), the point lies behind
/// either camera, or an input is not finite.
pub fn triangulate_range(
    f_ref: &Vector3<f64>,
    f_cur: &Vector3<f64>,
    t_cur_ref: &Isometry3<f64>,
) -> Option<f64> {
    let r = t_cur_ref.rotation * f_ref.try_normalize(1e-12)?;
    let f = f_cur.try_normalize(1e-12)?;
    let t = t_cur_ref.translation.vector;
    let (a11, a12, a22) = (r.dot(&r), r.dot(&f), f.dot(&f));
    let det = a11 * a22 - a12 * a12;
    if det.is_nan() || det < MIN_TRIANGULATION_DET {
        return None;
    }
    let (b0, b1) = (r.dot(&t), f.dot(&t));
    let range_ref = -(a22 * b0 - a12 * b1) / det;
    let range_cur = (a11 * b1 - a12 * b0) / det;
    (range_ref.is_finite() && range_ref > 0.0 && range_cur > 0.0).then_some(range_ref)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::depth_filter::{Seed, inverse_depth_variance};
    use crate::vision::features::{DetectorConfig, Feature, FeatureDetector};
    use crate::vision::test_scene::{Ground, SplitMix, camera, nadir_pose};

    const GROUND: Ground = Ground {
        seed: 0x5eed_0042,
        ground_z_m: 0.0,
    };

    /// `t_cur_ref` from two camera poses in the scene frame.
    fn relative(zeta_wc_ref: &Isometry3<f64>, zeta_wc_cur: &Isometry3<f64>) -> Isometry3<f64> {
        zeta_wc_cur.inverse() * zeta_wc_ref
    }

    /// Range of the ground point seen at `ref_px` and its exact position in the current image.
    fn truth(
        cam: &Camera,
        zeta_wc_ref: &Isometry3<f64>,
        zeta_wc_cur: &Isometry3<f64>,
        ref_px: &Vector2<f64>,
    ) -> (f64, Vector2<f64>) {
        let p_w = GROUND.intersect(cam, zeta_wc_ref, ref_px).unwrap();
        let range = (p_w - zeta_wc_ref.translation.vector).norm();
        (range, cam.project_ecef(zeta_wc_cur, &p_w).unwrap())
    }

    /// FAST corners with the Shi-Tomasi score, one per 32-px cell, on levels 0–2.
    fn features(cam: &Camera, pyr: &Pyramid) -> Vec<Feature> {
        let config = DetectorConfig {
            cell_size_px: 32,
            ..DetectorConfig::default()
        };
        let det = FeatureDetector::new(config, cam).unwrap();
        det.detect(pyr, &det.empty_occupancy()).unwrap()
    }

    /// The rendered view with `offset` grey levels added (saturating).
    fn pyramid_with_offset(cam: &Camera, zeta_wc: &Isometry3<f64>, offset: i16) -> Pyramid {
        let pixels: Vec<u8> = GROUND
            .render(cam, zeta_wc)
            .into_iter()
            .map(|p| (i16::from(p) + offset).clamp(0, 255) as u8)
            .collect();
        Pyramid::from_pixels(cam.width_px(), cam.height_px(), &pixels, 5).unwrap()
    }

    #[test]
    fn affine_warp_is_identity_scale_and_matches_finite_differences() {
        let cam = camera(192, 256);
        let px = Vector2::new(40.3, 200.8);
        // Identity pose: A = I at level 0, 2^L I at level L (A maps level-L px to level-0 px).
        for level in 0..3 {
            let a = affine_warp(&cam, &px, level, 1_000.0, &Isometry3::identity()).unwrap();
            let scale = f64::from(1_u32 << level);
            assert!((a - Matrix2::identity() * scale).norm() < 1e-9, "{a}");
        }
        // Moving half the depth along the optical axis doubles a fronto-parallel plane about
        // the principal point: A = 2 I at every pixel.
        let closer = Isometry3::translation(0.0, 0.0, -500.0);
        for px in [px, cam.principal_point_px(), Vector2::new(180.0, 3.0)] {
            let z = 1_000.0;
            let range = z * cam.ray(&px).norm();
            let a = affine_warp(&cam, &px, 0, range, &closer).unwrap();
            assert!((a - Matrix2::identity() * 2.0).norm() < 1e-9, "{a}");
            assert_eq!(search_level(&a, MAX_SEARCH_LEVEL), 1);
        }
        // A general pose: the Jacobian of the plane-induced mapping by central differences.
        // The 5-px one-sided probe differs from the derivative by the homography's curvature,
        // about 5 px / f × A ≈ 0.5 % here; 1e-2 leaves room.
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let zeta_cur = nadir_pose(120.0, -80.0, 850.0, [0.05, -0.03, 0.35]);
        let t = relative(&zeta_ref, &zeta_cur);
        for px in [Vector2::new(20.0, 30.0), Vector2::new(150.5, 222.2)] {
            let range = 1_000.0 * cam.ray(&px).norm();
            let z = 1_000.0;
            let map = |q: Vector2<f64>| {
                cam.project(&t.transform_point(&Point3::from(cam.ray(&q) * z)).coords)
                    .unwrap()
            };
            let h = 1e-3;
            let fd = Matrix2::from_columns(&[
                (map(px + Vector2::new(h, 0.0)) - map(px - Vector2::new(h, 0.0))) / (2.0 * h),
                (map(px + Vector2::new(0.0, h)) - map(px - Vector2::new(0.0, h))) / (2.0 * h),
            ]);
            let a = affine_warp(&cam, &px, 0, range, &t).unwrap();
            assert!((a - fd).norm() < 1e-2 * fd.norm(), "{a} vs {fd}");
            // The ground is the plane z = 1000 of the nadir reference camera: the true
            // position of a probe is the warp's prediction.
            let (_, cur) = truth(&cam, &zeta_ref, &zeta_cur, &px);
            let (_, cur_probe) = truth(&cam, &zeta_ref, &zeta_cur, &(px + Vector2::new(5.0, 0.0)));
            assert!((cur_probe - cur - a.column(0) * 5.0).norm() < 1e-6);
        }
    }

    #[test]
    fn search_level_follows_the_determinant() {
        let level = |s: f64| search_level(&(Matrix2::identity() * s), MAX_SEARCH_LEVEL);
        assert_eq!(level(1.0), 0);
        assert_eq!(level(1.7), 0); // det 2.9
        assert_eq!(level(1.8), 1); // det 3.24
        assert_eq!(level(3.0), 1); // det 9 → 2.25
        assert_eq!(level(3.6), 2); // det 13 → 3.2 → 0.8
        assert_eq!(level(100.0), MAX_SEARCH_LEVEL);
        assert_eq!(search_level(&(Matrix2::identity() * 100.0), 0), 0);
        assert_eq!(search_level(&Matrix2::from_element(f64::NAN), 2), 0);
    }

    /// Every feature of the reference view, aligned in a second view (translated and slightly
    /// rotated, with or without 12 grey levels of offset) from 2 px off its true position in 8
    /// directions, at the search level. Tolerance: the rendering's anti-aliasing, rounding
    /// (0.3 grey rms) and the bilinear resampling of both patches leave a few hundredths of a
    /// pixel; 0.03 px of convergence step on top; 0.1 px is the bound.
    #[test]
    fn align_2d_converges_from_two_pixels_in_every_direction() {
        let cam = camera(192, 256);
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let zeta_cur = nadir_pose(7.3, -4.1, 990.0, [0.004, -0.003, 0.02]);
        let t = relative(&zeta_ref, &zeta_cur);
        let ref_pyr = pyramid_with_offset(&cam, &zeta_ref, 0);
        let feats = features(&cam, &ref_pyr);
        assert!(feats.len() >= 20, "{} features", feats.len());
        for offset in [0, 12] {
            let cur_pyr = pyramid_with_offset(&cam, &zeta_cur, offset);
            let (mut n, mut worst) = (0, 0.0_f64);
            for f in &feats {
                let (range, cur_px) = truth(&cam, &zeta_ref, &zeta_cur, &f.px);
                if !cam.contains(&cur_px, 12.0 * f64::from(1_u32 << f.level)) {
                    continue;
                }
                let a = affine_warp(&cam, &f.px, f.level, range, &t).unwrap();
                let level = search_level(&a, MAX_SEARCH_LEVEL);
                let patch = warp_patch(&ref_pyr, &a, &f.px, f.level, level).unwrap();
                let img = cur_pyr.level(level).unwrap();
                let true_l = Camera::base_to_level(&cur_px, level);
                for k in 0..8 {
                    let angle = f64::from(k) * std::f64::consts::FRAC_PI_4;
                    let start = true_l + 2.0 * Vector2::new(angle.cos(), angle.sin());
                    let got = align_2d(img, &patch, &start, ALIGN_MAX_ITERATIONS)
                        .unwrap_or_else(|| panic!("{f:?} from {start} (offset {offset})"));
                    let err = (got - true_l).norm();
                    worst = worst.max(err);
                    assert!(err < 0.1, "{f:?} from {start}: {got} vs {true_l}");
                }
                n += 1;
            }
            eprintln!("offset {offset}: {n} features, worst {worst:.4} px");
            assert!(n >= 20);
        }
    }

    /// Match every reference feature (at its level, or at `ref_level`) in `zeta_cur` from a
    /// prediction off by up to 1.5 px; returns (features tried, matched, worst error in px of
    /// the search level, matches per search level, determinants of the warps).
    fn direct_matches(
        zeta_cur: &Isometry3<f64>,
        ref_level: Option<u32>,
        seed: u64,
    ) -> (usize, usize, f64, [usize; 3], Vec<f64>) {
        // The 55 % lower camera sees a fifth of the reference footprint: a larger image.
        let cam = if zeta_cur.translation.z > -500.0 {
            camera(384, 512)
        } else {
            camera(192, 256)
        };
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let t = relative(&zeta_ref, zeta_cur);
        let ref_pyr = GROUND.pyramid(&cam, &zeta_ref);
        let cur_pyr = GROUND.pyramid(&cam, zeta_cur);
        let mut rng = SplitMix(seed);
        let (mut tried, mut matched, mut worst) = (0, 0, 0.0_f64);
        let mut levels = [0; 3];
        let mut dets = Vec::new();
        for mut f in features(&cam, &ref_pyr) {
            f.level = ref_level.unwrap_or(f.level);
            let (range, cur_px) = truth(&cam, &zeta_ref, zeta_cur, &f.px);
            // SVO's condition on the reference feature: 6 px inside the image at its level.
            let scale = f64::from(1_u32 << f.level);
            if !cam.contains(&cur_px, 16.0 * scale) || !cam.contains(&f.px, 6.0 * scale) {
                continue;
            }
            tried += 1;
            dets.push(
                affine_warp(&cam, &f.px, f.level, range, &t)
                    .unwrap()
                    .determinant(),
            );
            let predicted = cur_px + 1.5 * Vector2::new(rng.symmetric(), rng.symmetric());
            let Some(m) = find_match_direct(
                &cam, &ref_pyr, &f.px, f.level, range, &t, &cur_pyr, &predicted,
            ) else {
                continue;
            };
            matched += 1;
            levels[m.level as usize] += 1;
            let err = (m.px - cur_px).norm() / f64::from(1_u32 << m.level);
            worst = worst.max(err);
        }
        (tried, matched, worst, levels, dets)
    }

    /// Map points found in a second view with a rotation and translation, a 30 % lower camera
    /// (scale 1.43, det A ≈ 2.0), a 20° in-plane rotation, and a 55 % lower one (det 4.9,
    /// search level 1); also with the reference patches taken at level 1 (det ≈ 4–8, search
    /// levels 1–2, det up to 20): every one matched, to within 0.1 px at the search level (the
    /// warp is exact for the ground plane seen from a nadir reference, so the error is that of
    /// `align_2d_converges_from_two_pixels_in_every_direction`).
    #[test]
    fn find_match_direct_handles_motion_scale_and_in_plane_rotation() {
        let cases = [
            (
                "rotation and translation",
                nadir_pose(35.0, -20.0, 960.0, [0.02, -0.015, 0.05]),
            ),
            ("30 % lower", nadir_pose(4.0, 3.0, 700.0, [0.0; 3])),
            (
                "20° in-plane",
                nadir_pose(-6.0, 2.0, 1_000.0, [0.0, 0.0, 20_f64.to_radians()]),
            ),
            (
                "lower and turned",
                nadir_pose(10.0, 0.0, 745.0, [0.01, 0.0, -0.3]),
            ),
            ("55 % lower", nadir_pose(0.0, -2.0, 450.0, [0.0, 0.01, 0.1])),
        ];
        let with_levels = cases
            .iter()
            .map(|&(name, zeta)| (name, zeta, None))
            .chain([cases[0], cases[1], cases[4]].map(|(name, zeta)| (name, zeta, Some(1))));
        for (i, (name, zeta_cur, ref_level)) in with_levels.enumerate() {
            let (tried, matched, worst, levels, dets) =
                direct_matches(&zeta_cur, ref_level, i as u64);
            let det_mean = dets.iter().sum::<f64>() / dets.len() as f64;
            eprintln!(
                "{name}, reference level {ref_level:?}: {matched}/{tried} matched, \
                 worst {worst:.4} px, levels {levels:?}, mean det {det_mean:.2}"
            );
            let min_tried = if ref_level.is_some() { 10 } else { 15 };
            assert!(tried >= min_tried, "{name}: {tried}");
            assert_eq!(matched, tried, "{name}");
            assert!(worst < 0.1, "{name}: {worst}");
        }
    }

    /// Epipolar search of fresh seeds (`Seed::new(1000, 1000)`: ranges 750–1,500 m) of every
    /// reference feature, from a second camera 30, 60 and 100 m along and across the track
    /// (with some attitude change) at 1,000 m: the triangulated inverse range is within the
    /// 1-px triangulation uncertainty (`inverse_depth_variance`) of the true one.
    #[test]
    fn epipolar_search_triangulates_within_one_pixel_of_uncertainty() {
        let cam = camera(192, 256);
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let ref_pyr = GROUND.pyramid(&cam, &zeta_ref);
        let feats = features(&cam, &ref_pyr);
        let seed = Seed::new(1_000.0, 1_000.0).unwrap();
        let near_far = seed.search_depths_m();
        assert!((near_far.0 - 750.0).abs() < 1e-9 && (near_far.1 - 1_500.0).abs() < 1e-9);
        for (baseline, zeta_cur) in [
            (30.0, nadir_pose(30.0, 0.0, 1_000.0, [0.003, 0.0, 0.01])),
            (60.0, nadir_pose(55.0, 24.0, 1_010.0, [-0.002, 0.004, 0.0])),
            (100.0, nadir_pose(100.0, -5.0, 995.0, [0.0, -0.005, -0.02])),
        ] {
            let cur_pyr = GROUND.pyramid(&cam, &zeta_cur);
            let t = relative(&zeta_ref, &zeta_cur);
            let t_ref_cur = t.inverse().translation.vector;
            assert!((t_ref_cur.norm() / baseline - 1.0).abs() < 0.1);
            let (mut tried, mut worst_sigmas, mut worst_px) = (0, 0.0_f64, 0.0_f64);
            for f in &feats {
                let (range, cur_px) = truth(&cam, &zeta_ref, &zeta_cur, &f.px);
                let scale = f64::from(1_u32 << f.level);
                if !cam.contains(&cur_px, 12.0 * scale) || !cam.contains(&f.px, 6.0 * scale) {
                    continue;
                }
                tried += 1;
                let m = find_epipolar_match(
                    &cam,
                    &ref_pyr,
                    &f.px,
                    f.level,
                    seed.depth_m(),
                    near_far,
                    &t,
                    &cur_pyr,
                )
                .unwrap_or_else(|e| panic!("baseline {baseline} m, {f:?}: {e}"));
                let f_ref = cam.back_project(&f.px);
                let var =
                    inverse_depth_variance(&f_ref, range, &t_ref_cur, 1.0, cam.f_px()).unwrap();
                let sigmas = (1.0 / m.range_m - 1.0 / range).abs() / var.sqrt();
                worst_sigmas = worst_sigmas.max(sigmas);
                worst_px = worst_px.max((m.px - cur_px).norm() / f64::from(1_u32 << m.level));
                assert!(
                    sigmas < 1.0,
                    "baseline {baseline} m, {f:?}: range {} vs {range} ({sigmas} of 1 px)",
                    m.range_m
                );
            }
            eprintln!(
                "baseline {baseline} m: {tried} seeds, worst {worst_sigmas:.3} of the 1-px \
                 uncertainty, {worst_px:.4} px at the search level"
            );
            assert!(tried >= 15, "{tried}");
        }
    }

    /// A reference patch on a flat area (a "lake" painted on the ground in both views) cannot
    /// be located: the search refuses it as a non-match, instead of matching any flat area.
    #[test]
    fn a_flat_patch_has_no_epipolar_match() {
        let cam = camera(192, 256);
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let zeta_cur = nadir_pose(50.0, 0.0, 1_000.0, [0.0; 3]);
        // Ground within 70 m of the lake's centre, straight below the reference camera, is grey.
        let lake = |zeta: &Isometry3<f64>| {
            let mut pixels = GROUND.render(&cam, zeta);
            for (i, p) in pixels.iter_mut().enumerate() {
                let (u, v) = (i % cam.width_px() as usize, i / cam.width_px() as usize);
                let px = Vector2::new(u as f64, v as f64);
                let g = GROUND.intersect(&cam, zeta, &px).unwrap();
                if g.x.hypot(g.y) < 70.0 {
                    *p = 120;
                }
            }
            Pyramid::from_pixels(cam.width_px(), cam.height_px(), &pixels, 5).unwrap()
        };
        let (ref_pyr, cur_pyr) = (lake(&zeta_ref), lake(&zeta_cur));
        let t = relative(&zeta_ref, &zeta_cur);
        let seed = Seed::new(1_000.0, 1_000.0).unwrap();
        let centre = cam.principal_point_px();
        let result = find_epipolar_match(
            &cam,
            &ref_pyr,
            &centre,
            0,
            seed.depth_m(),
            seed.search_depths_m(),
            &t,
            &cur_pyr,
        );
        assert_eq!(
            result,
            Err(EpipolarError::NoMatch {
                best_score: f32::INFINITY
            })
        );
        // The same place in the textured scene matches.
        let (textured_ref, textured_cur) = (
            GROUND.pyramid(&cam, &zeta_ref),
            GROUND.pyramid(&cam, &zeta_cur),
        );
        let m = find_epipolar_match(
            &cam,
            &textured_ref,
            &centre,
            0,
            seed.depth_m(),
            seed.search_depths_m(),
            &t,
            &textured_cur,
        )
        .unwrap();
        assert!((m.range_m - 1_000.0).abs() < 30.0, "{m:?}");
        // The texture measure separates flat from textured patches by orders of magnitude.
        let a = affine_warp(&cam, &centre, 0, 1_000.0, &t).unwrap();
        let flat = warp_patch(&ref_pyr, &a, &centre, 0, 0).unwrap();
        let textured = warp_patch(&textured_ref, &a, &centre, 0, 0).unwrap();
        eprintln!(
            "texture: flat {}, textured {}",
            flat.texture(),
            textured.texture()
        );
        assert!(flat.texture() < 1e-3 && textured.texture() > 10.0 * MIN_PATCH_TEXTURE);
        // The alignment refuses the flat patch too.
        assert!(align_2d(cur_pyr.base(), &flat, &centre, ALIGN_MAX_ITERATIONS).is_none());
    }

    #[test]
    fn triangulate_range_is_exact_and_refuses_degenerate_rays() {
        // A point 10 m ahead of the reference camera, seen from 1 m to its right.
        let t = Isometry3::translation(-1.0, 0.0, 0.0);
        let f_cur = Vector3::new(-1.0, 0.0, 10.0).normalize();
        let r = triangulate_range(&Vector3::z(), &f_cur, &t).unwrap();
        assert!((r - 10.0).abs() < 1e-9, "{r}");
        // Non-unit bearings are normalised.
        let r = triangulate_range(&(Vector3::z() * 3.0), &(f_cur * 0.2), &t).unwrap();
        assert!((r - 10.0).abs() < 1e-9, "{r}");
        // A general pose and point.
        let t = Isometry3::from_parts(
            nalgebra::Translation3::new(3.0, -40.0, 7.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
        );
        let p_ref = Vector3::new(120.0, -60.0, 950.0);
        let p_cur = t.transform_point(&Point3::from(p_ref)).coords;
        let r = triangulate_range(&p_ref.normalize(), &p_cur.normalize(), &t).unwrap();
        assert!((r - p_ref.norm()).abs() < 1e-6 * p_ref.norm(), "{r}");
        // No baseline, parallel rays, rays meeting behind the cameras, bad numbers.
        let id = Isometry3::identity();
        assert_eq!(triangulate_range(&Vector3::z(), &Vector3::z(), &id), None);
        let side = Isometry3::translation(-1.0, 0.0, 0.0);
        assert_eq!(triangulate_range(&Vector3::z(), &Vector3::z(), &side), None);
        let diverging = Vector3::new(1.0, 0.0, 10.0).normalize();
        assert_eq!(triangulate_range(&Vector3::z(), &diverging, &side), None);
        let nan = Vector3::new(f64::NAN, 0.0, 1.0);
        assert_eq!(triangulate_range(&nan, &f_cur, &side), None);
        assert_eq!(
            triangulate_range(&Vector3::z(), &Vector3::zeros(), &side),
            None
        );
    }

    #[test]
    fn zmssd_is_zero_mean_and_refuses_blocks_off_the_image() {
        let cam = camera(192, 256);
        let zeta = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let pyr = GROUND.pyramid(&cam, &zeta);
        let px = Vector2::new(60.0, 70.0);
        let patch = warp_patch(&pyr, &Matrix2::identity(), &px, 0, 0).unwrap();
        // The patch against its own image: 0, also with an offset.
        assert!(zmssd(pyr.base(), &patch, 60, 70).unwrap().abs() < 1.0);
        let offset = pyramid_with_offset(&cam, &zeta, 10);
        let s = zmssd(offset.base(), &patch, 60, 70).unwrap();
        assert!(s.abs() < 1.0, "{s}");
        // Direct sum elsewhere.
        let (u, v) = (100_i32, 30_i32);
        let r = patch.samples();
        let c: Vec<f32> = (0..64)
            .map(|k| {
                let (x, y) = (u - 4 + k % 8, v - 4 + k / 8);
                f32::from(pyr.base()[(x as u32, y as u32)][0])
            })
            .collect();
        let (mr, mc) = (r.iter().sum::<f32>() / 64.0, c.iter().sum::<f32>() / 64.0);
        let direct: f32 = r
            .iter()
            .zip(&c)
            .map(|(a, b)| ((a - mr) - (b - mc)).powi(2))
            .sum();
        let s = zmssd(pyr.base(), &patch, u, v).unwrap();
        assert!((s - direct).abs() < 1e-4 * direct, "{s} vs {direct}");
        // Block u − 4 … u + 3 inside the 192 × 256 image.
        assert!(zmssd(pyr.base(), &patch, 4, 4).is_some());
        assert!(zmssd(pyr.base(), &patch, 188, 252).is_some());
        for (u, v) in [
            (3, 50),
            (50, 3),
            (189, 50),
            (50, 253),
            (-100, 5),
            (i32::MAX, i32::MIN),
        ] {
            assert!(zmssd(pyr.base(), &patch, u, v).is_none(), "({u}, {v})");
        }
    }

    /// NaN, off-image, behind-camera and degenerate inputs give `None` or an error, never a
    /// panic.
    #[test]
    fn bad_inputs_fail_cleanly() {
        let cam = camera(192, 256);
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let zeta_cur = nadir_pose(60.0, 0.0, 1_000.0, [0.0; 3]);
        let ref_pyr = GROUND.pyramid(&cam, &zeta_ref);
        let cur_pyr = GROUND.pyramid(&cam, &zeta_cur);
        let t = relative(&zeta_ref, &zeta_cur);
        let px = Vector2::new(96.0, 60.0);
        let (range, cur_px) = truth(&cam, &zeta_ref, &zeta_cur, &px);
        let nan2 = Vector2::new(f64::NAN, 10.0);
        // Turned upside down: everything is behind the current camera.
        let behind = Isometry3::rotation(Vector3::new(std::f64::consts::PI, 0.0, 0.0)) * t;

        // affine_warp.
        assert!(affine_warp(&cam, &px, 0, range, &t).is_some());
        assert!(affine_warp(&cam, &nan2, 0, range, &t).is_none());
        for r in [f64::NAN, 0.0, -5.0, f64::INFINITY] {
            assert!(affine_warp(&cam, &px, 0, r, &t).is_none(), "{r}");
        }
        assert!(affine_warp(&cam, &px, 0, range, &behind).is_none());
        assert!(
            affine_warp(&cam, &px, 40, range, &t).is_some_and(|a| a.iter().all(|c| c.is_finite()))
        );

        // warp_patch.
        let a = affine_warp(&cam, &px, 0, range, &t).unwrap();
        assert!(warp_patch(&ref_pyr, &Matrix2::zeros(), &px, 0, 0).is_none());
        assert!(warp_patch(&ref_pyr, &Matrix2::from_element(f64::NAN), &px, 0, 0).is_none());
        assert!(warp_patch(&ref_pyr, &a, &nan2, 0, 0).is_none());
        assert!(warp_patch(&ref_pyr, &a, &Vector2::new(3.0, 60.0), 0, 0).is_none());
        assert!(warp_patch(&ref_pyr, &a, &Vector2::new(-300.0, 1e9), 0, 0).is_none());
        assert!(warp_patch(&ref_pyr, &a, &px, 5, 0).is_none());
        assert!(warp_patch(&ref_pyr, &a, &px, 0, 40).is_none());

        // align_2d.
        let patch = warp_patch(&ref_pyr, &a, &px, 0, 0).unwrap();
        let img = cur_pyr.base();
        assert!(align_2d(img, &patch, &cur_px, ALIGN_MAX_ITERATIONS).is_some());
        assert!(align_2d(img, &patch, &cur_px, 0).is_none());
        for start in [
            nan2,
            Vector2::new(3.9, 100.0),
            Vector2::new(100.0, 251.5),
            Vector2::new(-1e12, 1e12),
            Vector2::new(f64::INFINITY, 5.0),
        ] {
            assert!(
                align_2d(img, &patch, &start, ALIGN_MAX_ITERATIONS).is_none(),
                "{start}"
            );
        }
        let flat = Pyramid::from_pixels(192, 256, &[77; 192 * 256], 5).unwrap();
        let flat_patch = warp_patch(&flat, &a, &px, 0, 0).unwrap();
        assert!(align_2d(img, &flat_patch, &cur_px, ALIGN_MAX_ITERATIONS).is_none());

        // find_match_direct.
        let direct =
            |ref_px: &Vector2<f64>, level: u32, r: f64, t: &Isometry3<f64>, p: &Vector2<f64>| {
                find_match_direct(&cam, &ref_pyr, ref_px, level, r, t, &cur_pyr, p)
            };
        assert!(direct(&px, 0, range, &t, &cur_px).is_some());
        assert!(direct(&px, 0, range, &t, &nan2).is_none());
        assert!(direct(&px, 0, range, &t, &Vector2::new(-50.0, 10.0)).is_none());
        assert!(direct(&px, 0, f64::NAN, &t, &cur_px).is_none());
        assert!(direct(&px, 0, range, &behind, &cur_px).is_none());
        assert!(direct(&nan2, 0, range, &t, &cur_px).is_none());
        assert!(direct(&px, 9, range, &t, &cur_px).is_none());
        assert!(find_match_direct(&cam, &ref_pyr, &px, 0, range, &t, &flat, &cur_px).is_none());

        // find_epipolar_match.
        let epi = |ref_px: &Vector2<f64>, level: u32, near_far: (f64, f64), t: &Isometry3<f64>| {
            find_epipolar_match(
                &cam, &ref_pyr, ref_px, level, 1_000.0, near_far, t, &cur_pyr,
            )
        };
        assert!(epi(&px, 0, (750.0, 1_500.0), &t).is_ok());
        use EpipolarError as E;
        for near_far in [
            (1_500.0, 750.0),
            (0.0, 100.0),
            (-1.0, 10.0),
            (f64::NAN, 1.0),
            (1.0, f64::INFINITY),
        ] {
            assert_eq!(
                epi(&px, 0, near_far, &t),
                Err(E::InvalidInput),
                "{near_far:?}"
            );
        }
        assert_eq!(epi(&nan2, 0, (750.0, 1_500.0), &t), Err(E::InvalidInput));
        let nan_pose = Isometry3::translation(f64::NAN, 0.0, 0.0);
        assert_eq!(
            epi(&px, 0, (750.0, 1_500.0), &nan_pose),
            Err(E::InvalidInput)
        );
        assert_eq!(
            find_epipolar_match(
                &cam,
                &ref_pyr,
                &px,
                0,
                f64::NAN,
                (750.0, 1_500.0),
                &t,
                &cur_pyr
            ),
            Err(E::InvalidInput)
        );
        assert_eq!(epi(&px, 9, (750.0, 1_500.0), &t), Err(E::InvalidInput));
        assert_eq!(epi(&px, 0, (750.0, 1_500.0), &behind), Err(E::BehindCamera));
        // The reference patch leaves the reference image.
        assert_eq!(
            epi(&Vector2::new(2.0, 60.0), 0, (750.0, 1_500.0), &t),
            Err(E::OffImage)
        );
        // The whole segment projects off the current image (600 m to the side).
        let aside = relative(&zeta_ref, &nadir_pose(0.0, 600.0, 1_000.0, [0.0; 3]));
        assert_eq!(epi(&px, 0, (750.0, 1_500.0), &aside), Err(E::OffImage));
        // Ranges from 1 m: the near end projects 67,000 px away.
        assert!(matches!(
            epi(&px, 0, (1.0, 1e8), &t),
            Err(E::SegmentTooLong { .. })
        ));
        // No baseline: a zero-length segment aligns, but cannot be triangulated.
        assert_eq!(
            find_epipolar_match(
                &cam,
                &ref_pyr,
                &px,
                0,
                1_000.0,
                (750.0, 1_500.0),
                &Isometry3::identity(),
                &ref_pyr
            ),
            Err(E::TriangulationFailed)
        );
        // A current image of pixel noise (σ ≈ 74 grey levels): every position scores above
        // the threshold.
        let mut rng = SplitMix(5);
        let noise: Vec<u8> = (0..192 * 256)
            .map(|_| (rng.next_u64() >> 56) as u8)
            .collect();
        let noise_pyr = Pyramid::from_pixels(192, 256, &noise, 5).unwrap();
        let r = find_epipolar_match(
            &cam,
            &ref_pyr,
            &px,
            0,
            1_000.0,
            (750.0, 1_500.0),
            &t,
            &noise_pyr,
        );
        assert!(
            matches!(r, Err(E::NoMatch { best_score })
                if best_score.is_finite() && best_score >= ZMSSD_THRESHOLD),
            "{r:?}"
        );
        // A different ground (this scene, deterministic): SVO's lax threshold (2000 per pixel)
        // accepts some position, the refinement then fails to converge.
        let other = Ground {
            seed: 99,
            ground_z_m: 0.0,
        };
        let other_pyr = other.pyramid(&cam, &zeta_cur);
        let r = find_epipolar_match(
            &cam,
            &ref_pyr,
            &px,
            0,
            1_000.0,
            (750.0, 1_500.0),
            &t,
            &other_pyr,
        );
        assert!(r.is_err(), "{r:?}");
    }

    /// Rough cost of the two searches (printed with `--nocapture`; no assertion): features of
    /// a 384 × 512 view matched in a second view 30 m on, and their seeds searched.
    #[test]
    fn timing_of_the_searches() {
        let cam = camera(384, 512);
        let zeta_ref = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let zeta_cur = nadir_pose(30.0, 3.0, 1_000.0, [0.002, 0.0, 0.01]);
        let ref_pyr = GROUND.pyramid(&cam, &zeta_ref);
        let cur_pyr = GROUND.pyramid(&cam, &zeta_cur);
        let t = relative(&zeta_ref, &zeta_cur);
        let seed = Seed::new(1_000.0, 1_000.0).unwrap();
        let cases: Vec<(Feature, f64, Vector2<f64>)> = features(&cam, &ref_pyr)
            .into_iter()
            .filter_map(|f| {
                let (range, cur_px) = truth(&cam, &zeta_ref, &zeta_cur, &f.px);
                cam.contains(&cur_px, 40.0)
                    .then_some((f, range, cur_px + Vector2::new(1.0, -1.0)))
            })
            .collect();
        let reps = 20;
        let start = std::time::Instant::now();
        let mut ok = 0;
        for _ in 0..reps {
            for (f, range, pred) in &cases {
                ok += usize::from(
                    find_match_direct(&cam, &ref_pyr, &f.px, f.level, *range, &t, &cur_pyr, pred)
                        .is_some(),
                );
            }
        }
        let direct_us = start.elapsed().as_secs_f64() * 1e6 / (reps * cases.len()) as f64;
        let start = std::time::Instant::now();
        let mut ok_epi = 0;
        for _ in 0..reps {
            for (f, _, _) in &cases {
                ok_epi += usize::from(
                    find_epipolar_match(
                        &cam,
                        &ref_pyr,
                        &f.px,
                        f.level,
                        seed.depth_m(),
                        seed.search_depths_m(),
                        &t,
                        &cur_pyr,
                    )
                    .is_ok(),
                );
            }
        }
        let epi_us = start.elapsed().as_secs_f64() * 1e6 / (reps * cases.len()) as f64;
        eprintln!(
            "{} features: find_match_direct {direct_us:.2} µs/call ({ok} ok), \
             find_epipolar_match {epi_us:.2} µs/call ({ok_epi} ok; 22-px segments, 32 steps)",
            cases.len()
        );
        assert!(ok > 0 && ok_epi > 0);
    }
}
