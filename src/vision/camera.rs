//! Down-looking camera (docs/REFERENCES.md A2.6; paper appendix "Optical Flow"; docs/CAMERA.md).
//!
//! - Pinhole with focal lengths `f_x`, `f_y` and principal point `c` in pixels, and a lens
//!   ([`crate::vision::lens`]) acting on normalised coordinates:
//!   `u = f_x x_d + c_u`, `v = f_y y_d + c_v` with `x_d = D(x/z, y/z)`. Without distortion
//!   (the default) it is the paper's ideal pinhole `u = f x/z + c_u`, `v = f y/z + c_v`, with
//!   `f = focal length / pixel pitch`: the authors' camera is 768 px wide (columns) × 1024 px
//!   high (rows), f = 19 mm, 17 µm pixels (f = 1117.65 px, vertical field of view 49.2255°),
//!   principal point (383.5, 511.5). [`Camera::project`] gives the distorted (raw-image) pixel,
//!   [`Camera::ray`] and [`Camera::back_project`] undistort, so every stage that samples image
//!   intensities through these methods carries the lens while the geometry works on
//!   undistorted bearings. A distortion whose coefficients are all zero is the pinhole, with
//!   the pinhole's arithmetic bit for bit. Skew is not modelled (calibrations with skew are
//!   refused when read).
//! - Pixel-centre convention: integer image coordinates are pixel centres, so the image spans
//!   `[-0.5, W - 0.5]` and the principal point of an even-sized image at its centre is
//!   `W/2 - 0.5` (OpenCV's and ROS's convention too). Pyramid level `l` halves the image `l`
//!   times: pixel `k` of level `l` covers level-0 pixels `2^l k … 2^l k + 2^l − 1`, so
//!   `f_l = f / 2^l` and `c_l = (c_0 + 0.5) / 2^l − 0.5` (`u_0 = 2^l (u_l + 0.5) − 0.5`); the
//!   lens, on normalised coordinates, is the same on every level.
//! - The optical-flow Jacobian `J_OF` (paper appendix) is the derivative of the projection of
//!   an Earth-fixed point with respect to a right perturbation `τ = [ρ; φ]` of the camera pose
//!   `zeta_ec`: `Π(g(zeta_ec ⊕ τ)⁻¹ p_e) ≈ Π(g(zeta_ec)⁻¹ p_e) + J_OF τ`.
//! - Intrinsics and mounting configuration: [`CameraConfig`], [`CameraSettings`] (`config.rs`);
//!   the body → camera mounting `zeta_bc`: [`Mounting`], [`MountingConfig`] (`mounting.rs`).

mod config;
mod mounting;

pub use config::{CameraConfig, CameraConfigError, CameraSettings, Intrinsics, IntrinsicsKeys};
pub use mounting::{Mounting, MountingConfig, MountingDraws, MountingPair};

use nalgebra::{Isometry3, Matrix2, Matrix2x3, Matrix2x6, Vector2, Vector3};

use crate::math::so3::skew;
use crate::vision::lens::{Distortion, Lens, UndistortError};

/// Pinhole camera with an optional lens distortion: image size, focal lengths and principal
/// point in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    width_px: u32,
    height_px: u32,
    fx_px: f64,
    fy_px: f64,
    c_px: Vector2<f64>,
    lens: Lens,
}

impl Default for Camera {
    fn default() -> Self {
        Self::paper()
    }
}

/// Pixels sampled along each image edge, at most this far apart, when a lens is checked to
/// invert over the image.
const LENS_CHECK_STEP_PX: f64 = 4.0;
/// Interior grid (per side) of the same check.
const LENS_CHECK_GRID: u32 = 16;

impl Camera {
    /// The authors' camera (768 × 1024 px, f = 1117.65 px, principal point (383.5, 511.5)).
    pub fn paper() -> Self {
        Self::from_config(&CameraConfig::default())
            .unwrap_or_else(|_| unreachable!("the default configuration is valid"))
    }

    /// Camera from its configuration: the nominal pinhole with its principal point at the
    /// image centre (`W/2 − 0.5`, `H/2 − 0.5` in the pixel-centre convention), or the
    /// calibrated intrinsics and lens. A lens must invert over the whole image.
    pub fn from_config(config: &CameraConfig) -> Result<Self, CameraConfigError> {
        config.validate()?;
        let camera = match &config.calibration {
            None => {
                let f_px = config.focal_length_mm * 1e-3 / (config.pixel_pitch_um * 1e-6);
                Self {
                    width_px: config.width_px,
                    height_px: config.height_px,
                    fx_px: f_px,
                    fy_px: f_px,
                    c_px: Vector2::new(
                        0.5 * f64::from(config.width_px) - 0.5,
                        0.5 * f64::from(config.height_px) - 0.5,
                    ),
                    lens: Lens::pinhole(),
                }
            }
            Some(k) => Self {
                width_px: config.width_px,
                height_px: config.height_px,
                fx_px: k.fx_px,
                fy_px: k.fy_px,
                c_px: Vector2::new(k.cx_px, k.cy_px),
                lens: Lens::new(k.distortion)?,
            },
        };
        camera.check_lens_over_image()?;
        Ok(camera)
    }

    /// Every pixel of the image must undistort: the edges (where the distortion is largest)
    /// densely, the interior on a grid.
    fn check_lens_over_image(&self) -> Result<(), CameraConfigError> {
        if self.lens.is_pinhole() {
            return Ok(());
        }
        let (w, h) = (f64::from(self.width_px), f64::from(self.height_px));
        let along = |length: f64| {
            let n = (length / LENS_CHECK_STEP_PX).ceil().max(1.0) as u32;
            (0..=n).map(move |i| -0.5 + length * f64::from(i) / f64::from(n))
        };
        let edges = along(w)
            .flat_map(|u| [Vector2::new(u, -0.5), Vector2::new(u, h - 0.5)])
            .chain(along(h).flat_map(|v| [Vector2::new(-0.5, v), Vector2::new(w - 0.5, v)]));
        let grid = (0..=LENS_CHECK_GRID).flat_map(|i| {
            (0..=LENS_CHECK_GRID).map(move |k| {
                let s = |n: u32, size: f64| -0.5 + size * f64::from(n) / f64::from(LENS_CHECK_GRID);
                Vector2::new(s(i, w), s(k, h))
            })
        });
        for px in edges.chain(grid) {
            self.try_ray(&px)
                .map_err(|reason| CameraConfigError::Lens {
                    u_px: px.x,
                    v_px: px.y,
                    reason,
                })?;
        }
        Ok(())
    }

    /// Image width (columns), px.
    pub fn width_px(&self) -> u32 {
        self.width_px
    }

    /// Image height (rows), px.
    pub fn height_px(&self) -> u32 {
        self.height_px
    }

    /// Focal length, px: `f_x` when `f_x = f_y` (every camera built from a focal length and a
    /// pixel pitch), else their geometric mean. For thresholds in pixels; the projection uses
    /// [`Camera::fx_px`] and [`Camera::fy_px`].
    pub fn f_px(&self) -> f64 {
        if self.fx_px == self.fy_px {
            self.fx_px
        } else {
            (self.fx_px * self.fy_px).sqrt()
        }
    }

    /// Focal length along the columns, px.
    pub fn fx_px(&self) -> f64 {
        self.fx_px
    }

    /// Focal length along the rows, px.
    pub fn fy_px(&self) -> f64 {
        self.fy_px
    }

    /// Principal point `(c_u, c_v)`, px.
    pub fn principal_point_px(&self) -> Vector2<f64> {
        self.c_px
    }

    /// The lens.
    pub fn lens(&self) -> &Lens {
        &self.lens
    }

    /// Vertical field of view (along the rows, through the principal point), rad; NaN if the
    /// lens does not invert at the image's edge.
    pub fn vertical_fov_rad(&self) -> f64 {
        let off_axis = |v: f64| self.angle_off_axis_rad(&Vector2::new(self.c_px.x, v));
        off_axis(-0.5) + off_axis(f64::from(self.height_px) - 0.5)
    }

    /// Horizontal field of view (along the columns, through the principal point), rad; NaN if
    /// the lens does not invert at the image's edge.
    pub fn horizontal_fov_rad(&self) -> f64 {
        let off_axis = |u: f64| self.angle_off_axis_rad(&Vector2::new(u, self.c_px.y));
        off_axis(-0.5) + off_axis(f64::from(self.width_px) - 0.5)
    }

    fn angle_off_axis_rad(&self, px: &Vector2<f64>) -> f64 {
        self.try_ray(px).map_or(f64::NAN, |r| r.xy().norm().atan())
    }

    /// Projection `Π` of a point in camera coordinates, the lens included; `None` unless it
    /// lies in front of the camera (z > 0) and within the lens model's field. The result may
    /// fall outside the image (see [`Camera::contains`]).
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        if !(p_c.z > 0.0 && p_c.iter().all(|v| v.is_finite())) {
            return None;
        }
        match self.lens.distortion() {
            Distortion::None => Some(Vector2::new(
                self.fx_px * p_c.x / p_c.z + self.c_px.x,
                self.fy_px * p_c.y / p_c.z + self.c_px.y,
            )),
            _ => {
                let d = self
                    .lens
                    .distort(&Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z))?;
                Some(Vector2::new(
                    self.fx_px * d.x + self.c_px.x,
                    self.fy_px * d.y + self.c_px.y,
                ))
            }
        }
    }

    /// Homogeneous ray `[x/z, y/z, 1]` through image point `px` (pixel-centre convention),
    /// undistorted. The lens inverts over the whole image ([`Camera::from_config`] checks it);
    /// beyond the lens model's field the ray is NaN ([`Camera::try_ray`] says why), which
    /// [`Camera::project`] and the geometry's finiteness checks refuse.
    pub fn ray(&self, px: &Vector2<f64>) -> Vector3<f64> {
        let x_d = Vector2::new(
            (px.x - self.c_px.x) / self.fx_px,
            (px.y - self.c_px.y) / self.fy_px,
        );
        match self.lens.distortion() {
            Distortion::None => Vector3::new(x_d.x, x_d.y, 1.0),
            _ => self
                .lens
                .undistort(&x_d)
                .map_or(Vector3::repeat(f64::NAN), |x| Vector3::new(x.x, x.y, 1.0)),
        }
    }

    /// [`Camera::ray`], with the reason when the lens cannot be undistorted at `px`.
    pub fn try_ray(&self, px: &Vector2<f64>) -> Result<Vector3<f64>, UndistortError> {
        let x_d = Vector2::new(
            (px.x - self.c_px.x) / self.fx_px,
            (px.y - self.c_px.y) / self.fy_px,
        );
        let x = self.lens.undistort(&x_d)?;
        Ok(Vector3::new(x.x, x.y, 1.0))
    }

    /// Unit bearing (camera frame) through image point `px`.
    pub fn back_project(&self, px: &Vector2<f64>) -> Vector3<f64> {
        self.ray(px).normalize()
    }

    /// Point at depth `z_m` (along the optical axis) seen at image point `px`.
    pub fn back_project_depth(&self, px: &Vector2<f64>, z_m: f64) -> Vector3<f64> {
        self.ray(px) * z_m
    }

    /// Whether `px` lies in the image at least `margin_px` from its border (pixel edges at
    /// −0.5 and W − 0.5).
    pub fn contains(&self, px: &Vector2<f64>, margin_px: f64) -> bool {
        px.x >= -0.5 + margin_px
            && px.y >= -0.5 + margin_px
            && px.x <= f64::from(self.width_px) - 0.5 - margin_px
            && px.y <= f64::from(self.height_px) - 0.5 - margin_px
    }

    /// Projection of an Earth-fixed point `p_e` (ECEF, m) seen from the camera pose `zeta_ec`.
    pub fn project_ecef(
        &self,
        zeta_ec: &Isometry3<f64>,
        p_e: &Vector3<f64>,
    ) -> Option<Vector2<f64>> {
        self.project(&zeta_ec.inverse_transform_point(&(*p_e).into()).coords)
    }

    /// `diag(f_x, f_y) ∂x_d/∂x` at the normalised point of `p_c`: pixels per unit of
    /// normalised coordinates (a distorted lens only).
    fn pixel_jacobian(&self, p_c: &Vector3<f64>) -> Matrix2<f64> {
        let x = Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z);
        let j = match self.lens.distort_with_jacobian(&x) {
            Some((_, j)) => j,
            None => Matrix2::repeat(f64::NAN),
        };
        Matrix2::new(self.fx_px, 0.0, 0.0, self.fy_px) * j
    }

    /// Derivative of the projection with respect to the camera-frame point, `∂Π/∂p_c` (2×3),
    /// the lens included (NaN beyond its field, where [`Camera::project`] gives `None`).
    pub fn projection_jacobian(&self, p_c: &Vector3<f64>) -> Matrix2x3<f64> {
        let iz = 1.0 / p_c.z;
        if let Distortion::None = self.lens.distortion() {
            let (fx, fy) = (self.fx_px, self.fy_px);
            return Matrix2x3::new(
                fx * iz,
                0.0,
                -fx * p_c.x * iz * iz,
                0.0,
                fy * iz,
                -fy * p_c.y * iz * iz,
            );
        }
        // ∂(x/z, y/z)/∂p_c, then through the lens and the focal lengths.
        let normalised = Matrix2x3::new(iz, 0.0, -p_c.x * iz * iz, 0.0, iz, -p_c.y * iz * iz);
        self.pixel_jacobian(p_c) * normalised
    }

    /// The paper's optical-flow Jacobian `J_OF` (appendix, eq. "optical flow") at the
    /// camera-frame point `p_c`: image motion per right perturbation `[ρ; φ]` of the camera
    /// pose `zeta_ec`, px per (m, rad). With `p̄ = p_c / z`, for the pinhole:
    ///
    /// `J_OF = [[f_x, 0], [0, f_y]] [[−1/z, 0, p̄₁/z, p̄₁p̄₂, −1 − p̄₁², p̄₂], [0, −1/z, p̄₂/z, 1 + p̄₂², −p̄₁p̄₂, −p̄₁]]`;
    /// with a lens, `∂x_d/∂x` stands between the two factors.
    pub fn optical_flow_jacobian(&self, p_c: &Vector3<f64>) -> Matrix2x6<f64> {
        let iz = 1.0 / p_c.z;
        let (x, y) = (p_c.x * iz, p_c.y * iz);
        if let Distortion::None = self.lens.distortion() {
            let (fx, fy) = (self.fx_px, self.fy_px);
            return Matrix2x6::new(
                -fx * iz,
                0.0,
                fx * x * iz,
                fx * x * y,
                -fx * (1.0 + x * x),
                fx * y,
                0.0,
                -fy * iz,
                fy * y * iz,
                fy * (1.0 + y * y),
                -fy * x * y,
                -fy * x,
            );
        }
        let normalised = Matrix2x6::new(
            -iz,
            0.0,
            x * iz,
            x * y,
            -(1.0 + x * x),
            y,
            0.0,
            -iz,
            y * iz,
            1.0 + y * y,
            -x * y,
            -x,
        );
        self.pixel_jacobian(p_c) * normalised
    }

    /// The camera of pyramid level `level` (each level halves the image; sizes rounded
    /// down): `f_l = f / 2^l`, `c_l = (c_0 + 0.5) / 2^l − 0.5`, the same lens.
    pub fn level(&self, level: u32) -> Self {
        let scale = f64::from(1_u32 << level.min(16));
        Self {
            width_px: (self.width_px >> level.min(16)).max(1),
            height_px: (self.height_px >> level.min(16)).max(1),
            fx_px: self.fx_px / scale,
            fy_px: self.fy_px / scale,
            c_px: self.c_px.map(|c| (c + 0.5) / scale - 0.5),
            lens: self.lens,
        }
    }

    /// Level-0 image coordinates of the point `px_l` of pyramid level `level`.
    pub fn level_to_base(px_l: &Vector2<f64>, level: u32) -> Vector2<f64> {
        let scale = f64::from(1_u32 << level.min(16));
        px_l.map(|c| (c + 0.5) * scale - 0.5)
    }

    /// Pyramid-level coordinates of the level-0 point `px`.
    pub fn base_to_level(px: &Vector2<f64>, level: u32) -> Vector2<f64> {
        let scale = f64::from(1_u32 << level.min(16));
        px.map(|c| (c + 0.5) / scale - 0.5)
    }
}

/// Rotation taking a tangent perturbation of the camera pose to the change of the camera-frame
/// point: `∂(g(zeta ⊕ τ)⁻¹ p)/∂τ = [−I, [p_c]×]` (used by [`Camera::optical_flow_jacobian`]).
pub fn point_jacobian(p_c: &Vector3<f64>) -> nalgebra::Matrix3x6<f64> {
    let mut j = nalgebra::Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-nalgebra::Matrix3::identity()));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&skew(p_c));
    j
}

#[cfg(test)]
mod tests;
