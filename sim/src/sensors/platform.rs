//! IMU platform mounting (docs/REFERENCES.md A2.2): the true and the navigation-estimated
//! orientation of the IMU platform axes `P` in the body axes `B`, and the IMU position from the
//! aircraft reference point, drawn once per aircraft.

use nalgebra::{UnitQuaternion, Vector3};

use super::config::PlatformConfig;
use crate::rng::{self, Stream};

/// Radians per degree.
const RAD_PER_DEG: f64 = std::f64::consts::PI / 180.0;

/// One aircraft's IMU mounting, true and as the navigation believes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Platform {
    /// True platform orientation in body axes: `v_b = q_bp_true * v_p`.
    pub q_bp_true: UnitQuaternion<f64>,
    /// The navigation's estimate of `q_bp`.
    pub q_bp_est: UnitQuaternion<f64>,
    /// True IMU position from the aircraft reference point, body axes `T_rp^b`, m.
    pub t_rp_b_true_m: Vector3<f64>,
    /// The navigation's estimate of `T_rp^b`, m.
    pub t_rp_b_est_m: Vector3<f64>,
}

impl Platform {
    /// Draw the mounting from the aircraft stream, in this order: true yaw, pitch, bank;
    /// their estimation errors (yaw, pitch, bank); the position errors (x, y, z).
    pub fn draw(cfg: &PlatformConfig, rng: &mut Stream) -> Self {
        let mut euler_true = [0.0; 3];
        for (e, s) in euler_true.iter_mut().zip(cfg.euler_bp_sigma_deg) {
            *e = s * RAD_PER_DEG * rng::normal(rng);
        }
        let mut euler_est = euler_true;
        for e in &mut euler_est {
            *e += cfg.euler_bp_est_sigma_deg * RAD_PER_DEG * rng::normal(rng);
        }
        let t_true = Vector3::from(cfg.t_rp_b_m);
        let mut t_est = t_true;
        for t in t_est.iter_mut() {
            *t += cfg.t_rp_est_sigma_m * rng::normal(rng);
        }
        Self {
            q_bp_true: q_from_yaw_pitch_bank(euler_true),
            q_bp_est: q_from_yaw_pitch_bank(euler_est),
            t_rp_b_true_m: t_true,
            t_rp_b_est_m: t_est,
        }
    }
}

/// ZYX Euler angles `[yaw, pitch, bank]` (rad) of frame `P` relative to `B` → `q_bp`.
fn q_from_yaw_pitch_bank([yaw, pitch, bank]: [f64; 3]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(bank, pitch, yaw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_sigmas_give_identity_and_nominal_position() {
        let cfg = PlatformConfig {
            t_rp_est_sigma_m: 0.0,
            euler_bp_sigma_deg: [0.0; 3],
            euler_bp_est_sigma_deg: 0.0,
            ..PlatformConfig::default()
        };
        let p = Platform::draw(&cfg, &mut rng::stream(1, "test.platform"));
        assert_eq!(p.q_bp_true, UnitQuaternion::identity());
        assert_eq!(p.q_bp_est, UnitQuaternion::identity());
        assert_eq!(p.t_rp_b_true_m, Vector3::new(0.30, 0.0, 0.10));
        assert_eq!(p.t_rp_b_est_m, p.t_rp_b_true_m);
    }

    #[test]
    fn euler_order_is_yaw_pitch_bank() {
        // A pure yaw of 90° maps platform x to body y.
        let q = q_from_yaw_pitch_bank([std::f64::consts::FRAC_PI_2, 0.0, 0.0]);
        let v = q * Vector3::x();
        assert!((v - Vector3::y()).norm() < 1e-15);
        // A pure pitch of 90° maps platform x to body −z (nose up).
        let q = q_from_yaw_pitch_bank([0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        assert!((q * Vector3::x() + Vector3::z()).norm() < 1e-15);
    }
}
