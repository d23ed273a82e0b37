//! Structure optimisation of the paper's SVO motion thread (section "SVO": "refining ... the
//! terrain coordinates of the 3D points associated to each feature ... based on nonlinear
//! minimization of the reprojection error"): Gauss-Newton on one point's Earth-fixed position
//! over its observations from cameras of known pose, SVO 1's `Point::optimize` (5 iterations,
//! no robust weights, roll back when the error grows).
//!
//! Residuals are level-0 pixels; the IA-VNS adds the current frame as one more observation.

use nalgebra::{Isometry3, Matrix3, Vector2, Vector3};

use super::camera::Camera;

/// One observation of the point: the camera pose and the level-0 pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointObservation {
    /// Camera pose (camera → Earth).
    pub zeta_ec: Isometry3<f64>,
    /// Observed pixel, level 0.
    pub px: Vector2<f64>,
}

/// Sum of squared residuals, the normal matrix and gradient at `p_e`; `None` if the point is
/// behind a camera.
fn normal_equations(
    camera: &Camera,
    p_e: &Vector3<f64>,
    observations: &[PointObservation],
) -> Option<(f64, Matrix3<f64>, Vector3<f64>)> {
    let (mut chi2, mut h, mut g) = (0.0, Matrix3::zeros(), Vector3::zeros());
    for o in observations {
        let p_c = o.zeta_ec.inverse_transform_point(&(*p_e).into()).coords;
        let px = camera.project(&p_c)?;
        let e = px - o.px;
        // d px / d p_e = (d px / d p_c) · R_ce.
        let j = camera.projection_jacobian(&p_c)
            * o.zeta_ec.rotation.to_rotation_matrix().matrix().transpose();
        chi2 += e.norm_squared();
        h += j.transpose() * j;
        g += j.transpose() * e;
    }
    Some((chi2, h, g))
}

/// Refine `p_e` over `observations` with at most `iterations` Gauss-Newton steps; returns the
/// refined point (the input when nothing improves it or the geometry is degenerate).
pub fn optimize_point(
    camera: &Camera,
    p_e: &Vector3<f64>,
    observations: &[PointObservation],
    iterations: u32,
) -> Vector3<f64> {
    let mut p = *p_e;
    if observations.len() < 2 || !p.iter().all(|v| v.is_finite()) {
        return p;
    }
    let mut prev_chi2 = f64::INFINITY;
    for _ in 0..iterations {
        let Some((chi2, h, g)) = normal_equations(camera, &p, observations) else {
            break;
        };
        if chi2.is_nan() || chi2 > prev_chi2 {
            break;
        }
        let Some(step) = h.cholesky().map(|c| -c.solve(&g)) else {
            break;
        };
        if !step.iter().all(|v| v.is_finite()) {
            break;
        }
        let candidate = p + step;
        // Keep the step only if it lowers the error (SVO's roll-back).
        match normal_equations(camera, &candidate, observations) {
            Some((next, _, _)) if next <= chi2 => {
                p = candidate;
                prev_chi2 = next;
            }
            _ => break,
        }
        if step.amax() <= 1e-10 {
            break;
        }
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::test_scene::nadir_pose;

    #[test]
    fn recovers_a_point_from_three_views() {
        let camera = Camera::paper();
        let truth = Vector3::new(30.0, -12.0, 40.0);
        let poses = [
            nadir_pose(0.0, 0.0, 1_000.0, [0.0; 3]),
            nadir_pose(120.0, 5.0, 1_010.0, [0.01, -0.02, 0.1]),
            nadir_pose(240.0, -8.0, 990.0, [-0.02, 0.01, -0.05]),
        ];
        let observations: Vec<_> = poses
            .iter()
            .map(|zeta_ec| PointObservation {
                zeta_ec: *zeta_ec,
                px: camera.project_ecef(zeta_ec, &truth).unwrap(),
            })
            .collect();
        // 20 m off along the depth and 5 m across.
        let start = truth + Vector3::new(5.0, -3.0, 20.0);
        let p = optimize_point(&camera, &start, &observations, 5);
        assert!((p - truth).norm() < 1e-3, "{}", (p - truth).norm());
        // One view cannot fix a point: unchanged.
        assert_eq!(
            optimize_point(&camera, &start, &observations[..1], 5),
            start
        );
        // NaN is left alone.
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert!(optimize_point(&camera, &nan, &observations, 5).x.is_nan());
    }
}
