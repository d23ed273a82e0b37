//! Synthetic scenes for the vision tests: a textured plane seen by a pinhole camera, rendered by
//! ray casting, so that every stage can be checked against exact geometry. Tests only.
//!
//! The world frame `W` of a scene has z **down** (like NED), the ground plane at `z = ground_z_m`
//! and a camera pose `zeta_wc` maps camera points into `W` (`p_w = zeta_wc · p_c`), the same
//! convention as `zeta_ec` in the navigation.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};
use std::sync::Arc;

use crate::sensors::Frame;
use crate::vision::camera::{Camera, CameraConfig};
use crate::vision::pyramid::Pyramid;

/// SplitMix64: deterministic draws without a dependency.
#[derive(Debug, Clone)]
pub struct SplitMix(pub u64);

impl SplitMix {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1_u64 << 53) as f64
    }

    /// Uniform in [−1, 1).
    pub fn symmetric(&mut self) -> f64 {
        2.0 * self.unit() - 1.0
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.unit().max(1e-300);
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Hash of a lattice node to [0, 1).
fn lattice(seed: u64, i: i64, j: i64) -> f64 {
    let mut h = SplitMix(
        seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F),
    );
    h.unit()
}

/// Value noise with a smooth (C¹) interpolation between lattice nodes `cell_m` apart.
fn value_noise(seed: u64, x_m: f64, y_m: f64, cell_m: f64) -> f64 {
    let (x, y) = (x_m / cell_m, y_m / cell_m);
    let (i, j) = (x.floor(), y.floor());
    let (fx, fy) = (x - i, y - j);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let (i, j) = (i as i64, j as i64);
    let a = lattice(seed, i, j);
    let b = lattice(seed, i + 1, j);
    let c = lattice(seed, i, j + 1);
    let d = lattice(seed, i + 1, j + 1);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// A textured ground plane: grey level of a point of the plane, a sum of value-noise octaves
/// (4, 12 and 40 m) that gives FAST corners and smooth gradients at 1–3 m per pixel.
#[derive(Debug, Clone, Copy)]
pub struct Ground {
    /// Texture seed.
    pub seed: u64,
    /// Height of the plane along W's z (down), m.
    pub ground_z_m: f64,
}

impl Ground {
    /// Grey level (0–255) at plane coordinates `(x, y)`, m.
    pub fn grey(&self, x_m: f64, y_m: f64) -> f64 {
        let n = 0.5 * value_noise(self.seed, x_m, y_m, 4.0)
            + 0.3 * value_noise(self.seed ^ 0xA5A5, x_m, y_m, 12.0)
            + 0.2 * value_noise(self.seed ^ 0x5A5A, x_m, y_m, 40.0);
        // Stretch the contrast: sums of noise cluster around the middle.
        (128.0 + 2.2 * 127.0 * (n - 0.5)).clamp(0.0, 255.0)
    }

    /// Where the ray of pixel `px` from camera pose `zeta_wc` meets the plane, if in front.
    pub fn intersect(
        &self,
        camera: &Camera,
        zeta_wc: &Isometry3<f64>,
        px: &Vector2<f64>,
    ) -> Option<Vector3<f64>> {
        let dir_w = zeta_wc.rotation * camera.ray(px);
        let origin = zeta_wc.translation.vector;
        if dir_w.z.abs() < 1e-12 {
            return None;
        }
        let s = (self.ground_z_m - origin.z) / dir_w.z;
        (s > 0.0).then(|| origin + dir_w * s)
    }

    /// Depth (along the optical axis) of the plane at pixel `px`.
    pub fn depth_m(
        &self,
        camera: &Camera,
        zeta_wc: &Isometry3<f64>,
        px: &Vector2<f64>,
    ) -> Option<f64> {
        let p_w = self.intersect(camera, zeta_wc, px)?;
        Some(zeta_wc.inverse_transform_point(&p_w.into()).z)
    }

    /// The image seen from `zeta_wc`: each pixel the mean of 2 × 2 samples of the texture
    /// (a little anti-aliasing), rounded to grey levels.
    pub fn render(&self, camera: &Camera, zeta_wc: &Isometry3<f64>) -> Vec<u8> {
        let (w, h) = (camera.width_px(), camera.height_px());
        let mut pixels = vec![0_u8; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                let mut sum = 0.0;
                for (du, dv) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let px = Vector2::new(f64::from(u) + du, f64::from(v) + dv);
                    sum += self
                        .intersect(camera, zeta_wc, &px)
                        .map_or(0.0, |p| self.grey(p.x, p.y));
                }
                pixels[(v * w + u) as usize] = (0.25 * sum).round() as u8;
            }
        }
        pixels
    }

    /// [`Ground::render`] as a frame at `t_us`.
    pub fn frame(&self, camera: &Camera, zeta_wc: &Isometry3<f64>, t_us: u64) -> Frame {
        Frame {
            t_us,
            width: camera.width_px(),
            height: camera.height_px(),
            pixels: Arc::from(self.render(camera, zeta_wc)),
        }
    }

    /// [`Ground::render`] as a pyramid.
    pub fn pyramid(&self, camera: &Camera, zeta_wc: &Isometry3<f64>) -> Pyramid {
        Pyramid::from_frame(&self.frame(camera, zeta_wc, 0), camera)
            .unwrap_or_else(|e| panic!("test pyramid: {e}"))
    }
}

/// A camera of `width × height` px with the paper's focal length and pixel pitch.
pub fn camera(width_px: u32, height_px: u32) -> Camera {
    Camera::from_config(&CameraConfig {
        width_px,
        height_px,
        ..Default::default()
    })
    .unwrap_or_else(|e| panic!("test camera: {e}"))
}

/// A nadir-looking camera pose at `(x, y)` and height `h_m` over a plane at z = 0 of W (z down),
/// with image rows along W's x (the direction of flight) and a small roll, pitch and yaw
/// (rad) about the camera axes.
pub fn nadir_pose(x_m: f64, y_m: f64, h_m: f64, rpy_rad: [f64; 3]) -> Isometry3<f64> {
    // Camera z = W z (down); camera y (rows, down the image) = −W x, so the scene moves down
    // the image as the camera flies along +x; camera x = W y.
    let r_wc = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
        0.0, -1.0, 0.0, //
        1.0, 0.0, 0.0, //
        0.0, 0.0, 1.0,
    ));
    let tilt = UnitQuaternion::from_euler_angles(rpy_rad[0], rpy_rad[1], rpy_rad[2]);
    Isometry3::from_parts(
        Translation3::new(x_m, y_m, -h_m),
        UnitQuaternion::from_rotation_matrix(&r_wc) * tilt,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rendered_plane_has_texture_and_exact_depth() {
        let cam = camera(96, 128);
        let ground = Ground {
            seed: 7,
            ground_z_m: 0.0,
        };
        let pose = nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]);
        let pixels = ground.render(&cam, &pose);
        let mean = pixels.iter().map(|&p| f64::from(p)).sum::<f64>() / pixels.len() as f64;
        let var = pixels
            .iter()
            .map(|&p| (f64::from(p) - mean).powi(2))
            .sum::<f64>()
            / pixels.len() as f64;
        assert!(var.sqrt() > 20.0, "contrast σ {}", var.sqrt());
        let centre = cam.principal_point_px();
        let depth = ground.depth_m(&cam, &pose, &centre).unwrap();
        assert!((depth - 1_000.0).abs() < 1e-9);
        // Flying along +x moves the scene down the image (rows).
        let ahead = nadir_pose(10.0, 0.0, 1_000.0, [0.0; 3]);
        let p = ground.intersect(&cam, &pose, &centre).unwrap();
        let px = cam.project_ecef(&ahead, &p).unwrap();
        assert!(
            px.y > centre.y + 10.0 && (px.x - centre.x).abs() < 1e-9,
            "{px}"
        );
    }
}
