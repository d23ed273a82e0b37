//! Image pyramid of semi-direct visual odometry (SVO; Forster, Pizzoli and Scaramuzza, "SVO:
//! Fast Semi-Direct Monocular Visual Odometry", ICRA 2014), the first step of every frame in the
//! motion thread (the paper's SVO figure: "Sparse Image Alignment", "Feature Alignment"): the
//! frame becomes 5 levels, each a 2 × 2 box average of the one below, and intensities and
//! gradients are read at sub-pixel positions by bilinear interpolation.
//!
//! - 5 levels because sparse image alignment runs from level 4 down to level 2 and feature
//!   detection uses the finer levels. For the 768 × 1024 camera: 768×1024, 384×512, 192×256,
//!   96×128, 48×64.
//! - Level `l + 1` pixel `(k, m)` is the mean of level-`l` pixels `2k, 2k+1` × `2m, 2m+1`,
//!   rounded to the nearest integer (`(a + b + c + d + 2) / 4`; SVO truncates, which darkens
//!   every level by 0.375 grey levels more than the one below). Odd sizes round down and drop
//!   the last column or row. With the pixel-centre convention of [`crate::vision::camera`] this is
//!   exactly `u_0 = 2^l (u_l + 0.5) − 0.5` ([`Camera::level_to_base`]).
//! - Interpolation: intensity is defined on `[0, W − 1] × [0, H − 1]` (between the outermost
//!   pixel centres), the gradient on `[1, W − 2] × [1, H − 2]` (it needs one more pixel on each
//!   side). Outside, or for non-finite coordinates, the functions return `None`: no clamping,
//!   so a caller never aligns against invented border pixels.

use image::GrayImage;

use crate::sensors::Frame;
use crate::vision::camera::Camera;

/// Number of pyramid levels SVO builds (sparse alignment uses levels 4 → 2).
pub const PYRAMID_LEVELS: u32 = 5;

/// Largest number of levels accepted (a 65 536-px image halved 16 times is 1 px).
const MAX_LEVELS: u32 = 16;

/// Why a frame could not be turned into a pyramid.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PyramidError {
    /// The frame's size differs from the camera's.
    #[error(
        "frame is {frame_width}×{frame_height} px but the camera is {camera_width}×{camera_height} px"
    )]
    SizeMismatch {
        /// Frame width, px.
        frame_width: u32,
        /// Frame height, px.
        frame_height: u32,
        /// Camera width, px.
        camera_width: u32,
        /// Camera height, px.
        camera_height: u32,
    },
    /// The pixel buffer does not hold `width × height` bytes.
    #[error("a {width}×{height} px frame must carry {expected} bytes, it carries {actual}")]
    PixelCount {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
        /// `width × height`.
        expected: u64,
        /// Length of the buffer.
        actual: usize,
    },
    /// The image is too small for the requested number of levels (the coarsest would be empty),
    /// or the number of levels is outside `1..=16`.
    #[error("a {width}×{height} px image cannot make {levels} pyramid levels")]
    TooSmall {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
        /// Requested levels.
        levels: u32,
    },
}

/// Grey-level image pyramid; level 0 is the frame itself.
#[derive(Debug, Clone, PartialEq)]
pub struct Pyramid {
    levels: Vec<GrayImage>,
}

impl Pyramid {
    /// The [`PYRAMID_LEVELS`]-level pyramid of `frame`, which must have the camera's size and
    /// exactly `width × height` pixels.
    pub fn from_frame(frame: &Frame, camera: &Camera) -> Result<Self, PyramidError> {
        if frame.width != camera.width_px() || frame.height != camera.height_px() {
            return Err(PyramidError::SizeMismatch {
                frame_width: frame.width,
                frame_height: frame.height,
                camera_width: camera.width_px(),
                camera_height: camera.height_px(),
            });
        }
        Self::from_pixels(frame.width, frame.height, &frame.pixels, PYRAMID_LEVELS)
    }

    /// Pyramid of `n_levels` levels of a row-major `width × height` grey image.
    pub fn from_pixels(
        width: u32,
        height: u32,
        pixels: &[u8],
        n_levels: u32,
    ) -> Result<Self, PyramidError> {
        let expected = u64::from(width) * u64::from(height);
        if pixels.len() as u64 != expected {
            return Err(PyramidError::PixelCount {
                width,
                height,
                expected,
                actual: pixels.len(),
            });
        }
        if !(1..=MAX_LEVELS).contains(&n_levels)
            || (width >> (n_levels - 1)) == 0
            || (height >> (n_levels - 1)) == 0
        {
            return Err(PyramidError::TooSmall {
                width,
                height,
                levels: n_levels,
            });
        }
        let mut base = GrayImage::new(width, height);
        base.copy_from_slice(pixels);
        let mut levels = Vec::with_capacity(n_levels as usize);
        levels.push(base);
        for _ in 1..n_levels {
            let next = levels.last().map(half_sample);
            levels.extend(next);
        }
        Ok(Self { levels })
    }

    /// Number of levels.
    pub fn n_levels(&self) -> u32 {
        self.levels.len() as u32
    }

    /// Level `level` (0 = full resolution), if it exists.
    pub fn level(&self, level: u32) -> Option<&GrayImage> {
        self.levels.get(level as usize)
    }

    /// All levels, finest first.
    pub fn levels(&self) -> &[GrayImage] {
        &self.levels
    }

    /// Level 0, the frame itself.
    pub fn base(&self) -> &GrayImage {
        // A pyramid always has at least one level (checked in `from_pixels`).
        &self.levels[0]
    }
}

/// The next-coarser level: each pixel the rounded mean of a 2 × 2 block; sizes round down.
pub fn half_sample(src: &GrayImage) -> GrayImage {
    let (w, h) = src.dimensions();
    let (w_out, h_out) = (w / 2, h / 2);
    let mut out = GrayImage::new(w_out, h_out);
    if w_out == 0 || h_out == 0 {
        return out;
    }
    let (w, w_out) = (w as usize, w_out as usize);
    let src = src.as_raw();
    for (y, row_out) in out.chunks_exact_mut(w_out).enumerate() {
        let top = &src[2 * y * w..2 * y * w + 2 * w_out];
        let bottom = &src[(2 * y + 1) * w..(2 * y + 1) * w + 2 * w_out];
        for ((o, t), b) in row_out
            .iter_mut()
            .zip(top.chunks_exact(2))
            .zip(bottom.chunks_exact(2))
        {
            let sum = u16::from(t[0]) + u16::from(t[1]) + u16::from(b[0]) + u16::from(b[1]);
            // sum + 2 ≤ 1022, so the quotient fits in a u8.
            *o = ((sum + 2) / 4) as u8;
        }
    }
    out
}

/// Intensity and gradient at a sub-pixel position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GradientSample {
    /// Intensity, grey levels.
    pub intensity: f32,
    /// `∂I/∂u` (along columns), grey levels per pixel of the sampled level.
    pub di_du: f32,
    /// `∂I/∂v` (along rows), grey levels per pixel of the sampled level.
    pub di_dv: f32,
}

/// Bilinear stencil: index of the top-left pixel and the fractional offsets.
struct Stencil {
    index: usize,
    fu: f32,
    fv: f32,
}

impl Stencil {
    /// Stencil at `(u, v)` for a lookup that reaches `margin` pixels beyond the 2 × 2 block;
    /// `None` unless `margin ≤ u ≤ W − 1 − margin` (same for v) and the image is at least
    /// `2 + 2 margin` pixels wide and high.
    fn at(img: &GrayImage, u: f64, v: f64, margin: u32) -> Option<Self> {
        let (w, h) = img.dimensions();
        let (x0, fu) = axis(u, w, margin)?;
        let (y0, fv) = axis(v, h, margin)?;
        Some(Self {
            index: y0 * w as usize + x0,
            fu,
            fv,
        })
    }
}

/// Top-left index and fraction along one axis of length `n`; the last valid coordinate
/// `n − 1 − margin` uses the block to its left with fraction 1.
fn axis(x: f64, n: u32, margin: u32) -> Option<(usize, f32)> {
    if n < 2 + 2 * margin {
        return None;
    }
    let lo = f64::from(margin);
    let hi = f64::from(n - 1 - margin);
    // Written so that NaN fails the test.
    if !(x >= lo && x <= hi) {
        return None;
    }
    let x0 = x.floor().min(hi - 1.0);
    Some((x0 as usize, (x - x0) as f32))
}

/// The axis look-up of [`interpolate`] on its own: top-left index and fraction along an axis of
/// length `n`, `None` outside `[0, n − 1]`. A window sampled on a whole-pixel grid shares one
/// per column and one per row; [`bilinear_at`] then gives exactly what `interpolate` gives.
pub(crate) fn bilinear_axis(x: f64, n: u32) -> Option<(usize, f32)> {
    axis(x, n, 0)
}

/// The bilinear blend of [`interpolate`] at the 2 × 2 block whose top-left pixel is `index` in
/// `pixels` (row length `w`), with the fractions of [`bilinear_axis`].
#[inline]
pub(crate) fn bilinear_at(pixels: &[u8], w: usize, index: usize, fu: f32, fv: f32) -> f32 {
    let px = |i: usize| f32::from(pixels[i]);
    let top = lerp(px(index), px(index + 1), fu);
    let bottom = lerp(px(index + w), px(index + w + 1), fu);
    lerp(top, bottom, fv)
}

fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + t * (b - a)
}

/// Bilinear interpolation of the intensity at `(u, v)` (pixel centres at integers); `None`
/// outside `[0, W − 1] × [0, H − 1]`.
pub fn interpolate(img: &GrayImage, u: f64, v: f64) -> Option<f32> {
    let s = Stencil::at(img, u, v, 0)?;
    let p = img.as_raw();
    let w = img.width() as usize;
    Some(bilinear(&s, w, |i| f32::from(p[i])))
}

/// Bilinear interpolation of the intensity and of the central-difference gradient
/// (`(I(x+1) − I(x−1)) / 2`) at `(u, v)`; `None` outside `[1, W − 2] × [1, H − 2]`.
///
/// Interpolating the central differences equals taking central differences of the
/// interpolated image one pixel either side, so the gradient is continuous in `(u, v)` (unlike
/// the derivative of the bilinear surface) and exact on an affine intensity ramp.
pub fn interpolate_with_gradient(img: &GrayImage, u: f64, v: f64) -> Option<GradientSample> {
    let s = Stencil::at(img, u, v, 1)?;
    let p = img.as_raw();
    let w = img.width() as usize;
    let px = |i: usize| f32::from(p[i]);
    let du = |i: usize| 0.5 * (px(i + 1) - px(i - 1));
    let dv = |i: usize| 0.5 * (px(i + w) - px(i - w));
    Some(GradientSample {
        intensity: bilinear(&s, w, px),
        di_du: bilinear(&s, w, du),
        di_dv: bilinear(&s, w, dv),
    })
}

/// Bilinear blend of `f` over the 2 × 2 block of the stencil (`w` = image width).
fn bilinear(s: &Stencil, w: usize, f: impl Fn(usize) -> f32) -> f32 {
    let i = s.index;
    let top = lerp(f(i), f(i + 1), s.fu);
    let bottom = lerp(f(i + w), f(i + w + 1), s.fu);
    lerp(top, bottom, s.fv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::camera::CameraConfig;
    use nalgebra::Vector2;
    use std::sync::Arc;

    fn frame(width: u32, height: u32, pixels: Vec<u8>) -> Frame {
        Frame {
            t_us: 0,
            width,
            height,
            pixels: Arc::from(pixels),
        }
    }

    /// Deterministic pseudo-random bytes (SplitMix64).
    fn noise(n: usize, seed: u64) -> Vec<u8> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                ((z ^ (z >> 31)) >> 56) as u8
            })
            .collect()
    }

    #[test]
    fn paper_camera_levels() {
        let cam = Camera::paper();
        let f = frame(768, 1024, noise(768 * 1024, 1));
        let pyr = Pyramid::from_frame(&f, &cam).unwrap();
        let sizes: Vec<_> = pyr.levels().iter().map(GrayImage::dimensions).collect();
        assert_eq!(
            sizes,
            [(768, 1024), (384, 512), (192, 256), (96, 128), (48, 64)]
        );
        assert_eq!(pyr.n_levels(), PYRAMID_LEVELS);
        assert_eq!(pyr.base().as_raw().as_slice(), &f.pixels[..]);
        // Same sizes as the camera model's levels.
        for l in 0..PYRAMID_LEVELS {
            let img = pyr.level(l).unwrap();
            assert_eq!(img.width(), cam.level(l).width_px());
            assert_eq!(img.height(), cam.level(l).height_px());
        }
        assert!(pyr.level(PYRAMID_LEVELS).is_none());
    }

    #[test]
    fn box_average_rounds_and_drops_odd_edges() {
        let (w, h) = (13_u32, 9_u32);
        let pixels = noise((w * h) as usize, 7);
        let pyr = Pyramid::from_pixels(w, h, &pixels, 3).unwrap();
        assert_eq!(pyr.level(1).unwrap().dimensions(), (6, 4));
        assert_eq!(pyr.level(2).unwrap().dimensions(), (3, 2));
        for l in 1..3 {
            let (fine, coarse) = (pyr.level(l - 1).unwrap(), pyr.level(l).unwrap());
            for (x, y, p) in coarse.enumerate_pixels() {
                let s: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .iter()
                    .map(|&(dx, dy)| u32::from(fine.get_pixel(2 * x + dx, 2 * y + dy)[0]))
                    .sum();
                assert_eq!(u32::from(p[0]), (s + 2) / 4, "level {l} ({x}, {y})");
            }
        }
        // Ties round up: a 2 × 2 block 0, 0, 1, 1 averages 0.5 → 1.
        let pyr = Pyramid::from_pixels(2, 2, &[0, 0, 1, 1], 2).unwrap();
        assert_eq!(pyr.level(1).unwrap().as_raw().as_slice(), &[1]);
    }

    /// An affine ramp `I = 2u + 4v` (pixel centres) stays the same ramp in level-0
    /// coordinates on every level: the box average samples it at `u_0 = 2^l (u_l + 0.5) − 0.5`.
    #[test]
    fn levels_follow_the_camera_level_convention() {
        let (w, h) = (32_u32, 32_u32);
        let ramp = |u: f64, v: f64| 2.0 * u + 4.0 * v;
        let pixels: Vec<u8> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (2 * x + 4 * y) as u8))
            .collect();
        let pyr = Pyramid::from_pixels(w, h, &pixels, 3).unwrap();
        for l in 0..3 {
            for (x, y, p) in pyr.level(l).unwrap().enumerate_pixels() {
                let base = Camera::level_to_base(&Vector2::new(f64::from(x), f64::from(y)), l);
                assert_eq!(
                    f64::from(p[0]),
                    ramp(base.x, base.y),
                    "level {l} ({x}, {y})"
                );
            }
        }
    }

    #[test]
    fn interpolation_is_exact_on_a_ramp() {
        let (w, h) = (40_u32, 30_u32);
        let pixels: Vec<u8> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (2 * x + 3 * y + 5) as u8))
            .collect();
        let pyr = Pyramid::from_pixels(w, h, &pixels, 1).unwrap();
        let img = pyr.base();
        let ramp = |u: f64, v: f64| 2.0 * u + 3.0 * v + 5.0;
        // Values are below 256 and the weights are applied in f32: a few ulp of 256.
        let tol = 1e-4_f32;
        let (wm, hm) = (f64::from(w - 1), f64::from(h - 1));
        let points = [
            (0.0, 0.0),
            (0.25, 0.75),
            (3.5, 7.125),
            (17.3, 22.9),
            (wm, hm),
            (wm, 0.4),
            (38.999, 28.001),
        ];
        for &(u, v) in &points {
            let i = interpolate(img, u, v).unwrap();
            assert!((i - ramp(u, v) as f32).abs() < tol, "({u}, {v}): {i}");
        }
        for &(u, v) in &[(1.0, 1.0), (1.5, 2.25), (17.3, 22.9), (wm - 1.0, hm - 1.0)] {
            let g = interpolate_with_gradient(img, u, v).unwrap();
            assert!((g.intensity - ramp(u, v) as f32).abs() < tol);
            assert!(
                (g.di_du - 2.0).abs() < tol && (g.di_dv - 3.0).abs() < tol,
                "{g:?}"
            );
        }
        // At pixel centres the interpolation returns the pixel.
        assert_eq!(
            interpolate(img, 7.0, 11.0),
            Some(f32::from(img[(7, 11)][0]))
        );
    }

    #[test]
    fn interpolation_refuses_points_outside_its_domain() {
        let pyr = Pyramid::from_pixels(10, 8, &noise(80, 3), 1).unwrap();
        let img = pyr.base();
        for &(u, v) in &[
            (-0.001, 3.0),
            (9.001, 3.0),
            (3.0, -0.5),
            (3.0, 7.5),
            (f64::NAN, 1.0),
            (1.0, f64::INFINITY),
        ] {
            assert_eq!(interpolate(img, u, v), None, "({u}, {v})");
        }
        assert!(interpolate(img, 9.0, 7.0).is_some());
        // The gradient needs one more pixel on each side.
        assert!(interpolate_with_gradient(img, 0.99, 3.0).is_none());
        assert!(interpolate_with_gradient(img, 8.01, 3.0).is_none());
        assert!(interpolate_with_gradient(img, 3.0, 6.5).is_none());
        assert!(interpolate_with_gradient(img, 8.0, 6.0).is_some());
        assert!(interpolate_with_gradient(img, 1.0, 1.0).is_some());
        // Too small for a 2 × 2 block (intensity) or a 4 × 4 one (gradient).
        let tiny = Pyramid::from_pixels(3, 1, &[1, 2, 3], 1).unwrap();
        assert!(interpolate(tiny.base(), 1.0, 0.0).is_none());
        let small = Pyramid::from_pixels(3, 3, &[0; 9], 1).unwrap();
        assert!(interpolate(small.base(), 1.0, 1.0).is_some());
        assert!(interpolate_with_gradient(small.base(), 1.0, 1.0).is_none());
    }

    #[test]
    fn bad_frames_are_refused() {
        let cam = Camera::paper();
        let wrong_w = frame(767, 1024, vec![0; 767 * 1024]);
        assert!(matches!(
            Pyramid::from_frame(&wrong_w, &cam),
            Err(PyramidError::SizeMismatch {
                frame_width: 767,
                ..
            })
        ));
        let wrong_h = frame(768, 1023, vec![0; 768 * 1023]);
        assert!(matches!(
            Pyramid::from_frame(&wrong_h, &cam),
            Err(PyramidError::SizeMismatch { .. })
        ));
        let short = frame(768, 1024, vec![0; 768 * 1024 - 1]);
        assert_eq!(
            Pyramid::from_frame(&short, &cam),
            Err(PyramidError::PixelCount {
                width: 768,
                height: 1024,
                expected: 768 * 1024,
                actual: 768 * 1024 - 1
            })
        );
        let long = frame(768, 1024, vec![0; 768 * 1024 + 1]);
        assert!(matches!(
            Pyramid::from_frame(&long, &cam),
            Err(PyramidError::PixelCount { .. })
        ));
        // A valid 8 × 32 camera cannot give 5 levels (level 4 would be 0 px wide).
        let narrow = Camera::from_config(&CameraConfig {
            width_px: 8,
            height_px: 32,
            ..CameraConfig::default()
        })
        .unwrap();
        assert!(matches!(
            Pyramid::from_frame(&frame(8, 32, vec![0; 256]), &narrow),
            Err(PyramidError::TooSmall { .. })
        ));
        assert!(matches!(
            Pyramid::from_pixels(4, 4, &[0; 16], 0),
            Err(PyramidError::TooSmall { .. })
        ));
        // The error message names the sizes.
        let msg = Pyramid::from_frame(&wrong_w, &cam).unwrap_err().to_string();
        assert!(
            msg.contains("767×1024") && msg.contains("768×1024"),
            "{msg}"
        );
    }
}
