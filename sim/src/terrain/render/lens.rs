//! The lens stage (docs/TERRAIN.md "Lens distortion"): a camera with a distortion model
//! (`ianav::vision::lens`, OpenCV's radial-tangential or fisheye) is rendered as an ideal
//! pinhole of the same size whose focal length is chosen so that every pixel's undistorted ray
//! falls inside it, then resampled: each output pixel takes the bilinear interpolation of the
//! pinhole image where its own ray lands. The map is computed once per camera.
//!
//! What it costs in fidelity: the pinhole image is sampled at the narrower focal length (for
//! barrel distortion), so detail finer than its pixels is lost, and the photometric noise of
//! the pinhole render is interpolated (slightly smoothed). The geometry is the camera model's
//! (tests: markers appear where `Camera::project_ecef` with the lens puts them).

use ianav::vision::camera::{Camera, CameraConfig, Intrinsics};
use ianav::vision::lens::Distortion;
use nalgebra::Vector2;

use super::GreyImage;

/// Where each output pixel samples the pinhole image.
#[derive(Debug)]
pub(super) struct LensRemap {
    /// The pinhole camera the frame is rendered with.
    pub(super) pinhole: Camera,
    /// Per output pixel: index of the top-left pinhole pixel of its 2 × 2 neighbourhood, or
    /// `u32::MAX` where the ray does not exist (beyond the lens model's field: black).
    index: Vec<u32>,
    /// Per output pixel: the bilinear weights' fractions along the columns and the rows.
    frac: Vec<[f32; 2]>,
}

impl LensRemap {
    /// The remap for `camera`, `None` for a pinhole (the image is rendered directly).
    pub(super) fn new(camera: &Camera) -> Option<Self> {
        if camera.lens().is_pinhole() {
            return None;
        }
        let (w, h) = (camera.width_px(), camera.height_px());
        let c = camera.principal_point_px();
        let rays: Vec<Option<Vector2<f64>>> = (0..h)
            .flat_map(|v| (0..w).map(move |u| (u, v)))
            .map(|(u, v)| {
                let r = camera.ray(&Vector2::new(f64::from(u), f64::from(v)));
                (r.x.is_finite() && r.y.is_finite()).then(|| Vector2::new(r.x, r.y))
            })
            .collect();
        // The largest focal length that keeps every ray one pixel inside the pinhole image
        // (the bilinear neighbourhood), at most 4× the camera's.
        let (wf, hf) = (f64::from(w), f64::from(h));
        let mut f_px = 4.0 * camera.f_px();
        for x in rays.iter().flatten() {
            let fit = |offset: f64, low: f64, high: f64| {
                if offset > 0.0 {
                    high / offset
                } else if offset < 0.0 {
                    low / -offset
                } else {
                    f64::INFINITY
                }
            };
            f_px = f_px.min(fit(x.x, c.x - 1.0, wf - 2.0 - c.x)).min(fit(
                x.y,
                c.y - 1.0,
                hf - 2.0 - c.y,
            ));
        }
        let pinhole = Camera::from_config(&CameraConfig {
            width_px: w,
            height_px: h,
            focal_length_mm: 0.0,
            pixel_pitch_um: 0.0,
            calibration: Some(Intrinsics {
                fx_px: f_px,
                fy_px: f_px,
                cx_px: c.x,
                cy_px: c.y,
                distortion: Distortion::None,
            }),
        })
        .ok()?;
        let mut index = Vec::with_capacity(rays.len());
        let mut frac = Vec::with_capacity(rays.len());
        for x in &rays {
            let at = x.map(|x| (c.x + f_px * x.x, c.y + f_px * x.y));
            match at {
                Some((pu, pv)) if pu >= 0.0 && pv >= 0.0 && pu < wf - 1.0 && pv < hf - 1.0 => {
                    let (u0, v0) = (pu.floor(), pv.floor());
                    index.push(v0 as u32 * w + u0 as u32);
                    frac.push([(pu - u0) as f32, (pv - v0) as f32]);
                }
                _ => {
                    index.push(u32::MAX);
                    frac.push([0.0; 2]);
                }
            }
        }
        Some(Self {
            pinhole,
            index,
            frac,
        })
    }

    /// The distorted image from the pinhole one.
    pub(super) fn apply(&self, pinhole: &GreyImage) -> GreyImage {
        let w = pinhole.width as usize;
        let p = &pinhole.pixels;
        let pixels = self
            .index
            .iter()
            .zip(&self.frac)
            .map(|(&i, &[a, b])| {
                if i == u32::MAX {
                    return 0;
                }
                let i = i as usize;
                let g = |k: usize| f32::from(p[k]);
                let top = g(i) + a * (g(i + 1) - g(i));
                let bottom = g(i + w) + a * (g(i + w + 1) - g(i + w));
                (top + b * (bottom - top)).round().clamp(0.0, 255.0) as u8
            })
            .collect();
        GreyImage {
            width: pinhole.width,
            height: pinhole.height,
            pixels,
        }
    }
}
