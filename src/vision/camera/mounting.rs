//! Body → camera mounting `zeta_bc` (docs/REFERENCES.md A2.6): rotation from Euler
//! (yaw, pitch, bank)_bc, ZYX as everywhere, and the lens position from the aircraft reference
//! point, with the simulator's true-versus-estimated error model.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::config::{CameraConfigError, check};
use crate::math::so3;
use crate::math::wgs84::{self, Geodetic};

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

#[cfg(test)]
mod tests {
    use super::*;

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
}
