//! Down-looking pinhole camera (docs/REFERENCES.md A2.6; paper appendix "Optical Flow").
//!
//! - Ideal pinhole without distortion: `u = f x/z + c_u`, `v = f y/z + c_v` (paper eqs. of
//!   the image frame), with `f = focal length / pixel pitch` in pixels. The default is the
//!   authors' camera: 768 px wide (columns) × 1024 px high (rows), f = 19 mm, 17 µm pixels
//!   (f = 1117.65 px, vertical field of view 49.2255°), principal point (383.5, 511.5).
//! - Pixel-centre convention: integer image coordinates are pixel centres, so the image spans
//!   `[-0.5, W - 0.5]` and the principal point of an even-sized image at its centre is
//!   `W/2 - 0.5`. Pyramid level `l` halves the image `l` times: pixel `k` of level `l` covers
//!   level-0 pixels `2^l k … 2^l k + 2^l − 1`, so `f_l = f / 2^l` and
//!   `c_l = (c_0 + 0.5) / 2^l − 0.5` (`u_0 = 2^l (u_l + 0.5) − 0.5`).
//! - The optical-flow Jacobian `J_OF` (paper appendix) is the derivative of the projection of
//!   an Earth-fixed point with respect to a right perturbation `τ = [ρ; φ]` of the camera pose
//!   `zeta_ec`: `Π(g(zeta_ec ⊕ τ)⁻¹ p_e) ≈ Π(g(zeta_ec)⁻¹ p_e) + J_OF τ`.
//! - Mounting `zeta_bc` (body → camera): rotation from Euler (yaw, pitch, bank)_bc, ZYX as
//!   everywhere, and the lens position from the aircraft reference point. With zero angles the
//!   optical axis is body z (down): nadir-looking. The default yaw of 90° (the authors'
//!   `flag_rotate`) puts image x along the right wing and image "up" (−y) forward, so the long
//!   1024-px side lies along the track. True angles = nominal + 0.1°·N, estimated = true +
//!   0.01°·N; lens position estimated = true + 0.002 m·N per axis (A2.6). The normal draws
//!   come from the simulator's `camera_mounting` stream; this module only applies them.

use nalgebra::{Isometry3, Matrix2x3, Matrix2x6, Translation3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::math::so3::{self, skew};
use crate::math::wgs84::{self, Geodetic};

/// Why a camera or mounting configuration was rejected.
#[derive(Debug, thiserror::Error)]
pub enum CameraConfigError {
    /// The TOML text does not parse or does not match the structure.
    #[error("camera configuration: {0}")]
    Toml(#[from] toml::de::Error),
    /// A field has a value outside its domain.
    #[error("camera configuration: `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field.
        field: &'static str,
        /// The rejected value.
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
}

fn check(
    field: &'static str,
    value: f64,
    lo: f64,
    hi: f64,
    reason: &'static str,
) -> Result<(), CameraConfigError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(CameraConfigError::Invalid {
            field,
            value,
            reason,
        })
    }
}

/// Camera intrinsics as configured (docs/REFERENCES.md A2.6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Image width (columns), px.
    pub width_px: u32,
    /// Image height (rows), px.
    pub height_px: u32,
    /// Focal length, mm.
    pub focal_length_mm: f64,
    /// Pixel pitch, µm.
    pub pixel_pitch_um: f64,
}

impl Default for CameraConfig {
    /// The authors' camera: 768 × 1024 px, 19 mm, 17 µm.
    fn default() -> Self {
        Self {
            width_px: 768,
            height_px: 1024,
            focal_length_mm: 19.0,
            pixel_pitch_um: 17.0,
        }
    }
}

impl CameraConfig {
    /// Validate; errors name the key.
    pub fn validate(&self) -> Result<(), CameraConfigError> {
        check(
            "camera.width_px",
            f64::from(self.width_px),
            2.0,
            16_384.0,
            "must be 2 to 16384 px",
        )?;
        check(
            "camera.height_px",
            f64::from(self.height_px),
            2.0,
            16_384.0,
            "must be 2 to 16384 px",
        )?;
        check(
            "camera.focal_length_mm",
            self.focal_length_mm,
            0.1,
            1000.0,
            "must be 0.1 to 1000 mm",
        )?;
        check(
            "camera.pixel_pitch_um",
            self.pixel_pitch_um,
            0.1,
            1000.0,
            "must be 0.1 to 1000 µm",
        )
    }
}

/// Ideal pinhole camera: image size, focal length and principal point in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    width_px: u32,
    height_px: u32,
    f_px: f64,
    c_px: Vector2<f64>,
}

impl Default for Camera {
    fn default() -> Self {
        Self::paper()
    }
}

impl Camera {
    /// The authors' camera (768 × 1024 px, f = 1117.65 px, principal point (383.5, 511.5)).
    pub fn paper() -> Self {
        Self::from_config(&CameraConfig::default())
            .unwrap_or_else(|_| unreachable!("the default configuration is valid"))
    }

    /// Camera from its configuration; the principal point is the image centre
    /// (`W/2 − 0.5`, `H/2 − 0.5` in the pixel-centre convention).
    pub fn from_config(config: &CameraConfig) -> Result<Self, CameraConfigError> {
        config.validate()?;
        let f_px = config.focal_length_mm * 1e-3 / (config.pixel_pitch_um * 1e-6);
        Ok(Self {
            width_px: config.width_px,
            height_px: config.height_px,
            f_px,
            c_px: Vector2::new(
                0.5 * f64::from(config.width_px) - 0.5,
                0.5 * f64::from(config.height_px) - 0.5,
            ),
        })
    }

    /// Image width (columns), px.
    pub fn width_px(&self) -> u32 {
        self.width_px
    }

    /// Image height (rows), px.
    pub fn height_px(&self) -> u32 {
        self.height_px
    }

    /// Focal length, px.
    pub fn f_px(&self) -> f64 {
        self.f_px
    }

    /// Principal point `(c_u, c_v)`, px.
    pub fn principal_point_px(&self) -> Vector2<f64> {
        self.c_px
    }

    /// Vertical field of view (along the rows), rad.
    pub fn vertical_fov_rad(&self) -> f64 {
        2.0 * (0.5 * f64::from(self.height_px) / self.f_px).atan()
    }

    /// Horizontal field of view (along the columns), rad.
    pub fn horizontal_fov_rad(&self) -> f64 {
        2.0 * (0.5 * f64::from(self.width_px) / self.f_px).atan()
    }

    /// Projection `Π` of a point in camera coordinates; `None` unless it lies in front of the
    /// camera (z > 0). The result may fall outside the image (see [`Camera::contains`]).
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_c.z > 0.0 && p_c.iter().all(|v| v.is_finite()) {
            Some(Vector2::new(
                self.f_px * p_c.x / p_c.z + self.c_px.x,
                self.f_px * p_c.y / p_c.z + self.c_px.y,
            ))
        } else {
            None
        }
    }

    /// Homogeneous ray `[x/z, y/z, 1]` through image point `px` (pixel-centre convention).
    pub fn ray(&self, px: &Vector2<f64>) -> Vector3<f64> {
        Vector3::new(
            (px.x - self.c_px.x) / self.f_px,
            (px.y - self.c_px.y) / self.f_px,
            1.0,
        )
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

    /// Derivative of the projection with respect to the camera-frame point, `∂Π/∂p_c` (2×3).
    pub fn projection_jacobian(&self, p_c: &Vector3<f64>) -> Matrix2x3<f64> {
        let iz = 1.0 / p_c.z;
        let f = self.f_px;
        Matrix2x3::new(
            f * iz,
            0.0,
            -f * p_c.x * iz * iz,
            0.0,
            f * iz,
            -f * p_c.y * iz * iz,
        )
    }

    /// The paper's optical-flow Jacobian `J_OF` (appendix, eq. "optical flow") at the
    /// camera-frame point `p_c`: image motion per right perturbation `[ρ; φ]` of the camera
    /// pose `zeta_ec`, px per (m, rad). With `p̄ = p_c / z`:
    ///
    /// `J_OF = f [[−1/z, 0, p̄₁/z, p̄₁p̄₂, −1 − p̄₁², p̄₂], [0, −1/z, p̄₂/z, 1 + p̄₂², −p̄₁p̄₂, −p̄₁]]`.
    pub fn optical_flow_jacobian(&self, p_c: &Vector3<f64>) -> Matrix2x6<f64> {
        let iz = 1.0 / p_c.z;
        let (x, y) = (p_c.x * iz, p_c.y * iz);
        let f = self.f_px;
        Matrix2x6::new(
            -f * iz,
            0.0,
            f * x * iz,
            f * x * y,
            -f * (1.0 + x * x),
            f * y,
            0.0,
            -f * iz,
            f * y * iz,
            f * (1.0 + y * y),
            -f * x * y,
            -f * x,
        )
    }

    /// The camera of pyramid level `level` (each level halves the image; sizes rounded
    /// down): `f_l = f / 2^l`, `c_l = (c_0 + 0.5) / 2^l − 0.5`.
    pub fn level(&self, level: u32) -> Self {
        let scale = f64::from(1_u32 << level.min(16));
        Self {
            width_px: (self.width_px >> level.min(16)).max(1),
            height_px: (self.height_px >> level.min(16)).max(1),
            f_px: self.f_px / scale,
            c_px: self.c_px.map(|c| (c + 0.5) / scale - 0.5),
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

/// Body → camera rotation and lens position (`zeta_bc` without the CG offset).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mounting {
    /// Rotation `q_bc` (`v_b = q_bc * v_c`).
    pub q_bc: UnitQuaternion<f64>,
    /// Optical centre from the aircraft reference point, body axes, m.
    pub t_rc_b_m: Vector3<f64>,
}

impl Mounting {
    /// `zeta_bc` for the body frame centred at the CG, which lies at `cg_from_reference_b_m`
    /// from the reference point: `p_b = q_bc p_c + (t_rc − t_rb)`.
    pub fn zeta_bc(&self, cg_from_reference_b_m: &Vector3<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.t_rc_b_m - cg_from_reference_b_m),
            self.q_bc,
        )
    }

    /// Camera pose in ECEF, `zeta_ec = zeta_en · zeta_nb · zeta_bc`, for a CG at `pos` with
    /// attitude `q_nb`.
    pub fn zeta_ec(
        &self,
        pos: &Geodetic,
        q_nb: &UnitQuaternion<f64>,
        cg_from_reference_b_m: &Vector3<f64>,
    ) -> Isometry3<f64> {
        let q_en = wgs84::q_en(pos.lat_rad, pos.lon_rad);
        let q_eb = q_en * q_nb;
        let zeta_bc = self.zeta_bc(cg_from_reference_b_m);
        let t_ec_e = wgs84::geodetic_to_ecef(pos) + q_eb * zeta_bc.translation.vector;
        Isometry3::from_parts(Translation3::from(t_ec_e), q_eb * zeta_bc.rotation)
    }
}

/// Mounting configuration: nominal angles, lens position and the error model
/// (docs/REFERENCES.md A2.6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MountingConfig {
    /// Nominal Euler angles body → camera `[yaw, pitch, bank]`, degrees (ZYX).
    pub euler_bc_deg: [f64; 3],
    /// Optical centre from the aircraft reference point, body axes, m.
    pub lens_from_reference_b_m: [f64; 3],
    /// σ of each true angle about its nominal value, degrees.
    pub angle_true_sigma_deg: f64,
    /// σ of each estimated angle about its true value, degrees.
    pub angle_estimate_sigma_deg: f64,
    /// σ of each estimated lens coordinate about its true value, m.
    pub position_estimate_sigma_m: f64,
}

impl Default for MountingConfig {
    /// Nadir-looking with the image "up" forward; the authors' lens position and errors.
    fn default() -> Self {
        Self {
            euler_bc_deg: [90.0, 0.0, 0.0],
            lens_from_reference_b_m: [0.50, 0.0, 0.12],
            angle_true_sigma_deg: 0.1,
            angle_estimate_sigma_deg: 0.01,
            position_estimate_sigma_m: 0.002,
        }
    }
}

/// The true mounting (what the images are taken with) and the navigation's estimate of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MountingPair {
    /// True mounting.
    pub truth: Mounting,
    /// Estimated mounting.
    pub estimate: Mounting,
}

/// Standard normal draws that realise the mounting errors of one run (9 numbers).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MountingDraws {
    /// True angle errors in σ units `[yaw, pitch, bank]`.
    pub angle_true: [f64; 3],
    /// Estimate angle errors in σ units.
    pub angle_estimate: [f64; 3],
    /// Estimate lens-position errors in σ units, body axes.
    pub position_estimate: [f64; 3],
}

impl MountingConfig {
    /// Validate; errors name the key.
    pub fn validate(&self) -> Result<(), CameraConfigError> {
        let names = [
            "mounting.euler_bc_deg[0]",
            "mounting.euler_bc_deg[1]",
            "mounting.euler_bc_deg[2]",
        ];
        for (name, v) in names.into_iter().zip(self.euler_bc_deg) {
            check(name, v, -360.0, 360.0, "must be within ±360°")?;
        }
        let names = [
            "mounting.lens_from_reference_b_m[0]",
            "mounting.lens_from_reference_b_m[1]",
            "mounting.lens_from_reference_b_m[2]",
        ];
        for (name, v) in names.into_iter().zip(self.lens_from_reference_b_m) {
            check(name, v, -20.0, 20.0, "must be within ±20 m")?;
        }
        check(
            "mounting.angle_true_sigma_deg",
            self.angle_true_sigma_deg,
            0.0,
            10.0,
            "must be 0 to 10°",
        )?;
        check(
            "mounting.angle_estimate_sigma_deg",
            self.angle_estimate_sigma_deg,
            0.0,
            10.0,
            "must be 0 to 10°",
        )?;
        check(
            "mounting.position_estimate_sigma_m",
            self.position_estimate_sigma_m,
            0.0,
            1.0,
            "must be 0 to 1 m",
        )
    }

    /// The nominal (error-free) mounting.
    pub fn nominal(&self) -> Mounting {
        self.mounting(self.euler_bc_deg, self.lens_from_reference_b_m)
    }

    fn mounting(&self, euler_deg: [f64; 3], lens_m: [f64; 3]) -> Mounting {
        Mounting {
            q_bc: so3::from_euler_zyx(
                euler_deg[0].to_radians(),
                euler_deg[1].to_radians(),
                euler_deg[2].to_radians(),
            ),
            t_rc_b_m: Vector3::from(lens_m),
        }
    }

    /// True and estimated mountings for the standard normal draws `n` (docs/REFERENCES.md A2.6):
    /// true angles = nominal + σ_true·N, estimated angles = true + σ_est·N, true lens position =
    /// nominal, estimated = true + σ_pos·N.
    pub fn with_errors(&self, n: &MountingDraws) -> MountingPair {
        let mut true_deg = self.euler_bc_deg;
        let mut est_deg = [0.0; 3];
        let mut est_pos = self.lens_from_reference_b_m;
        for i in 0..3 {
            true_deg[i] += self.angle_true_sigma_deg * n.angle_true[i];
            est_deg[i] = true_deg[i] + self.angle_estimate_sigma_deg * n.angle_estimate[i];
            est_pos[i] += self.position_estimate_sigma_m * n.position_estimate[i];
        }
        MountingPair {
            truth: self.mounting(true_deg, self.lens_from_reference_b_m),
            estimate: self.mounting(est_deg, est_pos),
        }
    }
}

/// Contents of `config/camera.toml`: intrinsics and mounting (each section optional).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSettings {
    /// Intrinsics.
    #[serde(default)]
    pub camera: CameraConfig,
    /// Mounting and its error model.
    #[serde(default)]
    pub mounting: MountingConfig,
}

impl CameraSettings {
    /// Parse and validate TOML text; errors name the key.
    pub fn from_toml_str(text: &str) -> Result<Self, CameraConfigError> {
        let s: Self = toml::from_str(text)?;
        s.camera.validate()?;
        s.mounting.validate()?;
        Ok(s)
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
mod tests {
    use super::*;
    use crate::math::se3;
    use nalgebra::Vector6;

    #[test]
    fn paper_camera_numbers() {
        let cam = Camera::paper();
        assert_eq!((cam.width_px(), cam.height_px()), (768, 1024));
        // 19 mm / 17 µm.
        assert!((cam.f_px() - 19.0e-3 / 17.0e-6).abs() < 1e-9);
        assert!((cam.f_px() - 1117.647).abs() < 1e-3);
        assert_eq!(cam.principal_point_px(), Vector2::new(383.5, 511.5));
        // docs/REFERENCES.md A2.6: vfov 49.2255°, hfov 37.9°.
        assert!((cam.vertical_fov_rad().to_degrees() - 49.2255).abs() < 1e-3);
        assert!((cam.horizontal_fov_rad().to_degrees() - 37.9).abs() < 0.05);
    }

    #[test]
    fn projection_round_trip() {
        let cam = Camera::paper();
        for (u, v) in [(0.0, 0.0), (383.5, 511.5), (767.0, 1023.0), (12.3, 900.7)] {
            let px = Vector2::new(u, v);
            for z in [1.0, 250.0, 3000.0] {
                let p = cam.back_project_depth(&px, z);
                let back = cam.project(&p).unwrap();
                assert!((back - px).norm() < 1e-9, "{px} -> {back}");
                // Unit bearing projects to the same pixel.
                let b = cam.back_project(&px);
                assert!((b.norm() - 1.0).abs() < 1e-12);
                assert!((cam.project(&(b * 7.0)).unwrap() - px).norm() < 1e-9);
            }
        }
        assert!(cam.project(&Vector3::new(1.0, 2.0, -3.0)).is_none());
        assert!(cam.project(&Vector3::new(f64::NAN, 2.0, 3.0)).is_none());
        // The optical axis hits the principal point; a point right and down of it projects
        // right and down (x along columns, y along rows).
        assert_eq!(
            cam.project(&Vector3::new(0.0, 0.0, 5.0)).unwrap(),
            cam.principal_point_px()
        );
        let p = cam.project(&Vector3::new(1.0, 1.0, 10.0)).unwrap();
        assert!(p.x > 383.5 && p.y > 511.5);
    }

    #[test]
    fn optical_flow_jacobian_matches_finite_differences() {
        let cam = Camera::paper();
        let zeta_ec = Isometry3::from_parts(
            Translation3::new(4.1e6, -3.2e5, 4.8e6),
            so3::exp(&Vector3::new(0.4, -1.1, 2.0)),
        );
        for p_c in [
            Vector3::new(0.0, 0.0, 2700.0),
            Vector3::new(-800.0, 1100.0, 2500.0),
            Vector3::new(300.0, -40.0, 60.0),
        ] {
            let p_e = zeta_ec.transform_point(&p_c.into()).coords;
            let j = cam.optical_flow_jacobian(&p_c);
            let base = cam.project_ecef(&zeta_ec, &p_e).unwrap();
            for k in 0..6 {
                // Central differences; steps small against depth, large against rounding.
                let h = if k < 3 { 1e-3 } else { 1e-7 };
                let mut tau = Vector6::zeros();
                tau[k] = h;
                let plus = cam.project_ecef(&se3::plus(&zeta_ec, &tau), &p_e).unwrap();
                let minus = cam.project_ecef(&se3::plus(&zeta_ec, &-tau), &p_e).unwrap();
                let fd = (plus - minus) / (2.0 * h);
                let scale = j.column(k).norm().max(1e-3);
                assert!(
                    (fd - j.column(k)).norm() < 1e-5 * scale + 1e-5,
                    "column {k} at {p_c}: fd {fd} vs {}",
                    j.column(k)
                );
                assert!((plus - base).norm() > 0.0 || j.column(k).norm() < 1e-9);
            }
            // Chain rule form: ∂Π/∂p · [−I, [p]×].
            let chain = cam.projection_jacobian(&p_c) * point_jacobian(&p_c);
            assert!((chain - j).norm() < 1e-9 * j.norm());
        }
    }

    #[test]
    fn pyramid_levels_keep_the_geometry() {
        let cam = Camera::paper();
        let l2 = cam.level(2);
        assert_eq!((l2.width_px(), l2.height_px()), (192, 256));
        assert!((l2.f_px() - cam.f_px() / 4.0).abs() < 1e-12);
        assert_eq!(l2.principal_point_px(), Vector2::new(95.5, 127.5));
        // A point projects at corresponding coordinates on every level.
        let p = Vector3::new(-310.0, 520.0, 2600.0);
        let px0 = cam.project(&p).unwrap();
        for level in 0..5 {
            let cl = cam.level(level);
            let pxl = cl.project(&p).unwrap();
            assert!((Camera::level_to_base(&pxl, level) - px0).norm() < 1e-9);
            assert!((Camera::base_to_level(&px0, level) - pxl).norm() < 1e-9);
        }
        // Level-1 pixel 0 is the average of level-0 pixels 0 and 1: centre 0.5.
        assert!((Camera::level_to_base(&Vector2::new(0.0, 0.0), 1).x - 0.5).abs() < 1e-12);
    }

    #[test]
    fn nadir_mounting_looks_down_with_image_up_forward() {
        let m = MountingConfig::default().nominal();
        // Optical axis (camera z) is body z.
        assert!((m.q_bc * Vector3::z() - Vector3::z()).norm() < 1e-12);
        // Image x (columns) along the right wing, image up (−y) forward.
        assert!((m.q_bc * Vector3::x() - Vector3::y()).norm() < 1e-12);
        assert!((m.q_bc * -Vector3::y() - Vector3::x()).norm() < 1e-12);
        // Level flight north at lat 0 lon 0: the camera looks at the ground below.
        let pos = Geodetic {
            lat_rad: 0.0,
            lon_rad: 0.0,
            h_m: 2000.0,
        };
        let zeta_ec = m.zeta_ec(&pos, &UnitQuaternion::identity(), &Vector3::zeros());
        let ground = wgs84::geodetic_to_ecef(&Geodetic { h_m: 0.0, ..pos });
        let p_c = zeta_ec.inverse_transform_point(&ground.into()).coords;
        // Lens 0.5 m forward and 0.12 m below the reference point (= CG here).
        assert!(
            (p_c - Vector3::new(0.0, 0.5, 2000.0 - 0.12)).norm() < 1e-6,
            "{p_c}"
        );
    }

    #[test]
    fn mounting_errors_scale_with_their_sigmas() {
        let cfg = MountingConfig::default();
        let n = MountingDraws {
            angle_true: [1.0, -2.0, 0.5],
            angle_estimate: [3.0, 0.0, -1.0],
            position_estimate: [1.0, 2.0, -3.0],
        };
        let pair = cfg.with_errors(&n);
        let nominal = cfg.nominal();
        let true_err_deg = so3::minus(&pair.truth.q_bc, &nominal.q_bc)
            .norm()
            .to_degrees();
        // Three independent small angles: |δ| ≈ 0.1°·|(1, −2, 0.5)|.
        assert!(
            (true_err_deg - 0.1 * 5.25_f64.sqrt()).abs() < 1e-3,
            "{true_err_deg}"
        );
        let est_err_deg = so3::minus(&pair.estimate.q_bc, &pair.truth.q_bc)
            .norm()
            .to_degrees();
        assert!(
            (est_err_deg - 0.01 * 10.0_f64.sqrt()).abs() < 1e-4,
            "{est_err_deg}"
        );
        assert_eq!(pair.truth.t_rc_b_m, nominal.t_rc_b_m);
        let dp = pair.estimate.t_rc_b_m - pair.truth.t_rc_b_m;
        assert!((dp - Vector3::new(0.002, 0.004, -0.006)).norm() < 1e-12);
        // Zero draws: no error.
        let none = cfg.with_errors(&MountingDraws::default());
        assert_eq!(none.truth, nominal);
        assert_eq!(none.estimate, nominal);
    }

    #[test]
    fn the_documented_configuration_file_holds_the_defaults() {
        let text =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/camera.toml"))
                .unwrap();
        assert_eq!(
            CameraSettings::from_toml_str(&text).unwrap(),
            CameraSettings::default()
        );
        let err = CameraSettings::from_toml_str("[camera]\nwidth_px = 768\n").unwrap_err();
        assert!(err.to_string().contains("missing field"), "{err}");
        let err = CameraSettings::from_toml_str("[mounting]\nbogus = 1\n").unwrap_err();
        assert!(err.to_string().contains("bogus"), "{err}");
    }

    #[test]
    fn bad_configurations_name_the_key() {
        let cfg = CameraConfig {
            focal_length_mm: f64::NAN,
            ..CameraConfig::default()
        };
        let err = Camera::from_config(&cfg).unwrap_err().to_string();
        assert!(err.contains("focal_length_mm"), "{err}");
        let m = MountingConfig {
            angle_true_sigma_deg: -1.0,
            ..MountingConfig::default()
        };
        assert!(
            m.validate()
                .unwrap_err()
                .to_string()
                .contains("angle_true_sigma_deg")
        );
    }
}
