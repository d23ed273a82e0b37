//! Pyramidal Lucas-Kanade tracking of the VNS's two-view initialisation (paper, section "SVO":
//! "using feature matching ... to obtain a first estimation of the terrain"; SVO 1 tracks the
//! first image's corners with pyramidal KLT, a 30 × 30 window over 4 levels, 30 iterations,
//! until their median displacement is large enough for the homography).
//!
//! Translation only, inverse compositional: the first image's window and its gradients are the
//! template, the current image is searched from the previous estimate, coarse to fine. A large
//! window (31 × 31 px at level 0) is what makes this robust on fine, noise-like textures
//! (forest canopy) where the 8 × 8 patches of feature alignment are not.

use nalgebra::{Matrix2, Vector2};

use super::camera::Camera;
use super::pyramid::{Pyramid, bilinear_at, bilinear_axis, interpolate_with_gradient};

/// Half-width of the window per level, px: 31 × 31 at level 0, smaller at the coarse levels
/// so that features near the border keep them (the coarse levels only bring the estimate
/// into the fine levels' basin).
pub const HALF_WINDOW_PX: [i32; 4] = [15, 11, 7, 5];
/// Coarsest level tracked (4 levels: 3, 2, 1, 0).
pub const MAX_LEVEL: u32 = 3;
/// Gauss-Newton iterations per level at most.
pub const MAX_ITERATIONS: u32 = 30;
/// A step below this ends a level, px.
pub const CONVERGED_PX: f64 = 0.01;
/// Windows whose smallest gradient eigenvalue per pixel is below this cannot be tracked
/// ((grey levels / px)²).
pub const MIN_EIGENVALUE: f64 = 1e-2;

/// One level of a feature's template: samples and gradients of the window.
#[derive(Debug, Clone)]
struct LevelTemplate {
    /// Half-width of the window, px.
    half: i32,
    values: Vec<f32>,
    grad: Vec<[f32; 2]>,
    /// Inverse of the window's structure tensor.
    h_inv: Matrix2<f64>,
}

/// A feature of the first image, ready to be tracked.
#[derive(Debug, Clone)]
pub struct KltFeature {
    /// Level-0 pixel in the first image.
    pub px0: Vector2<f64>,
    /// Templates for levels `0..=MAX_LEVEL` (`None` where the window leaves the image or has no
    /// texture).
    levels: Vec<Option<LevelTemplate>>,
}

impl KltFeature {
    /// The templates of the feature at `px0` (level 0) of `first`.
    pub fn new(first: &Pyramid, px0: &Vector2<f64>) -> Self {
        let levels = (0..=MAX_LEVEL)
            .map(|level| template(first, px0, level))
            .collect();
        Self { px0: *px0, levels }
    }

    /// Track into `image` from `previous` (level 0); `None` if the finest level does not
    /// converge.
    pub fn track(&self, image: &Pyramid, previous: &Vector2<f64>) -> Option<Vector2<f64>> {
        let mut estimate = *previous;
        for level in (0..=MAX_LEVEL).rev() {
            let aligned = self
                .levels
                .get(level as usize)
                .and_then(Option::as_ref)
                .and_then(|t| {
                    let img = image.level(level)?;
                    let start = Camera::base_to_level(&estimate, level);
                    align(img, t, start)
                });
            match aligned {
                Some(px) => estimate = Camera::level_to_base(&px, level),
                None if level == 0 => return None,
                None => {}
            }
        }
        Some(estimate)
    }
}

fn template(first: &Pyramid, px0: &Vector2<f64>, level: u32) -> Option<LevelTemplate> {
    let img = first.level(level)?;
    let c = Camera::base_to_level(px0, level);
    let half = HALF_WINDOW_PX[level as usize];
    let n = (2 * half + 1) as usize;
    let mut values = Vec::with_capacity(n * n);
    let mut grad = Vec::with_capacity(n * n);
    let mut h = Matrix2::zeros();
    for dy in -half..=half {
        for dx in -half..=half {
            let s = interpolate_with_gradient(img, c.x + f64::from(dx), c.y + f64::from(dy))?;
            let (gu, gv) = (f64::from(s.di_du), f64::from(s.di_dv));
            h += Matrix2::new(gu * gu, gu * gv, gu * gv, gv * gv);
            values.push(s.intensity);
            grad.push([s.di_du, s.di_dv]);
        }
    }
    let per_px = h / (n * n) as f64;
    let spread = ((per_px[(0, 0)] - per_px[(1, 1)]).powi(2) + 4.0 * per_px[(0, 1)].powi(2)).sqrt();
    let min_eig = 0.5 * (per_px.trace() - spread);
    if min_eig.is_nan() || min_eig < MIN_EIGENVALUE {
        return None;
    }
    Some(LevelTemplate {
        half,
        values,
        grad,
        h_inv: h.try_inverse()?,
    })
}

/// Inverse-compositional translation alignment of one level's template in `img`, from
/// `start` (that level's pixels).
///
/// Every window pixel sits a whole number of pixels from `p`, so the bilinear look-ups share
/// one column stencil per column and one row stencil per row: computed once per iteration,
/// they give the same samples as per-pixel [`interpolate`](super::pyramid::interpolate) calls,
/// bit for bit.
fn align(img: &image::GrayImage, t: &LevelTemplate, start: Vector2<f64>) -> Option<Vector2<f64>> {
    let (w, h) = img.dimensions();
    let pixels = img.as_raw();
    let mut columns = Vec::with_capacity((2 * t.half + 1) as usize);
    let mut p = start;
    for _ in 0..MAX_ITERATIONS {
        columns.clear();
        for dx in -t.half..=t.half {
            columns.push(bilinear_axis(p.x + f64::from(dx), w)?);
        }
        let mut b = Vector2::zeros();
        let mut k = 0;
        for dy in -t.half..=t.half {
            let (y0, fv) = bilinear_axis(p.y + f64::from(dy), h)?;
            let row = y0 * w as usize;
            for &(x0, fu) in &columns {
                let v = bilinear_at(pixels, w as usize, row + x0, fu, fv);
                let r = f64::from(v - t.values[k]);
                let g = t.grad[k];
                b += Vector2::new(f64::from(g[0]), f64::from(g[1])) * r;
                k += 1;
            }
        }
        let step = -(t.h_inv * b);
        if !step.iter().all(|v| v.is_finite()) {
            return None;
        }
        p += step;
        if step.norm() < CONVERGED_PX {
            return Some(p);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::test_scene::{Ground, camera, nadir_pose};

    /// Features of the first image found in a view displaced by ~15 px (translation, a little
    /// pitch and roll, a 0.6° in-plane rotation: a few frames of turbulence) to a twentieth of a
    /// pixel (the window averages the resampling error), starting from where they were.
    #[test]
    fn tracks_features_across_a_large_displacement() {
        let cam = camera(384, 512);
        let ground = Ground {
            seed: 9,
            ground_z_m: 0.0,
        };
        let first_pose = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let first = ground.pyramid(&cam, &first_pose);
        let moved_pose = nadir_pose(10.0, 4.0, 1_000.0, [0.004, -0.003, 0.01]);
        let moved = ground.pyramid(&cam, &moved_pose);
        let mut tracked = 0;
        for i in 0..6 {
            for j in 0..8 {
                let px0 = Vector2::new(60.0 + 50.0 * f64::from(i), 60.0 + 50.0 * f64::from(j));
                let p_w = ground.intersect(&cam, &first_pose, &px0).unwrap();
                let truth = cam.project_ecef(&moved_pose, &p_w).unwrap();
                if !cam.contains(&truth, 40.0) {
                    continue;
                }
                let f = KltFeature::new(&first, &px0);
                // Start from the first image's position: the whole motion is to be found.
                let found = f.track(&moved, &px0).expect("tracked");
                assert!((found - truth).norm() < 0.05, "{px0}: {found} vs {truth}");
                tracked += 1;
            }
        }
        assert!(tracked >= 25, "{tracked}");
    }

    /// The per-pixel alignment the shared stencils replace.
    fn align_per_pixel(
        img: &image::GrayImage,
        t: &LevelTemplate,
        start: Vector2<f64>,
    ) -> Option<Vector2<f64>> {
        let mut p = start;
        for _ in 0..MAX_ITERATIONS {
            let mut b = Vector2::zeros();
            let mut k = 0;
            for dy in -t.half..=t.half {
                for dx in -t.half..=t.half {
                    let v = crate::vision::pyramid::interpolate(
                        img,
                        p.x + f64::from(dx),
                        p.y + f64::from(dy),
                    )?;
                    let g = t.grad[k];
                    b +=
                        Vector2::new(f64::from(g[0]), f64::from(g[1])) * f64::from(v - t.values[k]);
                    k += 1;
                }
            }
            let step = -(t.h_inv * b);
            if !step.iter().all(|v| v.is_finite()) {
                return None;
            }
            p += step;
            if step.norm() < CONVERGED_PX {
                return Some(p);
            }
        }
        None
    }

    /// Shared row and column stencils give the per-pixel look-ups' result bit for bit, from
    /// starts inside, near the border of and outside the image.
    #[test]
    fn shared_stencils_match_per_pixel_lookups() {
        let cam = camera(256, 320);
        let ground = Ground {
            seed: 4,
            ground_z_m: 0.0,
        };
        let first = ground.pyramid(&cam, &nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]));
        let moved = ground.pyramid(&cam, &nadir_pose(6.0, -3.0, 1_000.0, [0.002, 0.0, 0.01]));
        let mut rng = crate::vision::test_scene::SplitMix(17);
        let mut compared = 0;
        for _ in 0..60 {
            let px0 = Vector2::new(340.0 * rng.unit() - 10.0, 276.0 * rng.unit() - 10.0);
            let f = KltFeature::new(&first, &px0);
            for (level, t) in f.levels.iter().enumerate() {
                let (Some(t), Some(img)) = (t, moved.level(level as u32)) else {
                    continue;
                };
                let start = Camera::base_to_level(&(px0 + Vector2::new(2.3, -1.7)), level as u32);
                let fast = align(img, t, start);
                let reference = align_per_pixel(img, t, start);
                assert_eq!(
                    fast.map(|p| (p.x.to_bits(), p.y.to_bits())),
                    reference.map(|p| (p.x.to_bits(), p.y.to_bits())),
                    "{px0} level {level}"
                );
                compared += 1;
            }
        }
        assert!(compared > 100, "{compared}");
    }

    #[test]
    fn flat_windows_and_bad_starts_are_not_tracked() {
        let cam = camera(128, 128);
        let flat = Pyramid::from_pixels(128, 128, &vec![77_u8; 128 * 128], 5).unwrap();
        let f = KltFeature::new(&flat, &Vector2::new(64.0, 64.0));
        assert!(f.track(&flat, &Vector2::new(64.0, 64.0)).is_none());
        let ground = Ground {
            seed: 2,
            ground_z_m: 0.0,
        };
        let img = ground.pyramid(&cam, &nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]));
        let f = KltFeature::new(&img, &Vector2::new(64.0, 64.0));
        assert!(f.track(&img, &Vector2::new(f64::NAN, 3.0)).is_none());
        assert!(f.track(&img, &Vector2::new(-500.0, 3.0)).is_none());
        let edge = KltFeature::new(&img, &Vector2::new(2.0, 2.0));
        assert!(edge.track(&img, &Vector2::new(2.0, 2.0)).is_none());
    }
}
