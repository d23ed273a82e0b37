//! Pose optimisation ("motion-only bundle adjustment") of the paper's section "SVO pose
//! optimisation", eqs. `svo_pose_optim_*`: the camera pose `zeta_ec` that minimises the
//! reprojection errors of map points with known Earth-fixed positions against their aligned
//! image positions, by Gauss-Newton on SE(3) with the right perturbation
//! `zeta_ec ← zeta_ec ∘ Exp(Δτ)`, `Δτ = [v; ω]`, through the optical-flow Jacobian `J_OF`
//! (paper appendix, `Camera::optical_flow_jacobian`), made robust with Tukey weights
//! (eq. `svo_pose_optim_solution_tukey`).
//!
//! Choices where the paper is silent (docs/REFERENCES.md, SVO's defaults): residuals of a
//! feature detected at pyramid level `L` count at `1/2^L` of their pixel size; Tukey's
//! `k = 4.685` on the residual norm over a robust scale, `1.48 · median` of the initial norms
//! but never below 0.85 px (a start already within a fraction of a pixel would otherwise cut
//! off observations a pixel away, below the alignment noise), then 0.85 px from the fifth
//! iteration; at most 10 iterations, stopping when the sum of
//! residual norms `E_RP` decreases by less than `min_cost_decrease_px` or the step is negligible,
//! and returning to the previous pose if the weighted squared error grows; afterwards,
//! observations off by more than 2 px (at their level) are outliers.
//!
//! [`PosePrior`] lets a caller add a term to the normal equations at every iteration: the
//! IA-VNS pulls the attitude and altitude towards the INS that way.

use nalgebra::{Isometry3, Matrix6, Vector2, Vector3, Vector6};

use super::camera::Camera;
use crate::math::se3;
use crate::math::stats::median;

/// One map point and where the feature alignment found it in the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseObservation {
    /// The point, Earth-fixed (the frame `zeta_ec` maps camera points into), m.
    pub p_e: Vector3<f64>,
    /// Its aligned position in the level-0 image, px.
    pub px: Vector2<f64>,
    /// Pyramid level the feature was detected at (its residual counts at `1/2^level`).
    pub level: u32,
}

/// Settings of the optimisation. TOML table `[vision.pose]` of the navigation settings; a
/// missing key takes its default.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseOptConfig {
    /// Largest number of Gauss-Newton iterations, a count.
    pub max_iterations: u32,
    /// Tukey's constant on the residual norm over the robust scale, dimensionless: residuals
    /// beyond `tukey_k` × scale get zero weight.
    pub tukey_k: f64,
    /// Robust scale from iteration [`PoseOptConfig::fixed_scale_from_iteration`] on, px; also
    /// the floor of the initial scale (1.48 × the median initial residual).
    pub fixed_scale_px: f64,
    /// First iteration (0-based count) that uses the fixed scale instead of the initial
    /// median's.
    pub fixed_scale_from_iteration: u32,
    /// Stop when the sum of residual norms `E_RP` decreases by less than this, px.
    pub min_cost_decrease_px: f64,
    /// Stop when every component of the step is at most this: m for the translation, rad for
    /// the rotation.
    pub min_step: f64,
    /// Observations off by more than this after the optimisation are outliers, px (at their
    /// pyramid level).
    pub outlier_threshold_px: f64,
    /// Fewer inliers than this at the end is a failure, a count; the optimisation also needs
    /// this many usable observations (at least 3) to start.
    pub min_inliers: usize,
}

impl Default for PoseOptConfig {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            tukey_k: 4.685,
            fixed_scale_px: 0.85,
            fixed_scale_from_iteration: 5,
            min_cost_decrease_px: 1e-3,
            min_step: 1e-10,
            outlier_threshold_px: 2.0,
            min_inliers: 20,
        }
    }
}

/// A term added to the normal equations `H Δτ = −g` at each iteration, at the current pose
/// (e.g. the IA-VNS's inertial priors). `h` and `g` are in the units of the reprojection terms:
/// squared pixels (at level 0) per squared tangent unit.
pub trait PosePrior {
    /// Add the prior's `H` and gradient `g` at `zeta_ec` and return its share of the costs
    /// there, which the iteration's roll-back and stopping tests then see beside the
    /// reprojection terms.
    fn add(
        &self,
        zeta_ec: &Isometry3<f64>,
        h: &mut Matrix6<f64>,
        g: &mut Vector6<f64>,
    ) -> PriorCost;
}

/// A prior's share of the optimisation's costs at a pose.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PriorCost {
    /// Its term of the weighted squared error that the Gauss-Newton step minimises (the
    /// quantity whose growth rolls a step back), px².
    pub squared_px2: f64,
    /// Its term of the sum of norms `E_RP` that the stopping test watches, px.
    pub norm_px: f64,
}

/// Why the optimisation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseOptError {
    /// Too few usable observations (finite, in front of the camera) to start, or too few
    /// inliers at the end.
    #[error("pose optimisation: {found} usable observations or inliers, {needed} needed")]
    TooFewObservations {
        /// Observations or inliers found.
        found: usize,
        /// The minimum.
        needed: usize,
    },
    /// The normal equations were singular or the result not finite.
    #[error("pose optimisation: singular or non-finite normal equations")]
    Numerical,
}

/// The optimised pose and what it rests on.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseOptResult {
    /// The optimised camera pose.
    pub zeta_ec: Isometry3<f64>,
    /// Gauss-Newton iterations taken.
    pub iterations: u32,
    /// Per observation: an inlier at the end.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub n_inliers: usize,
    /// Sum of residual norms `E_RP` at the start and at the end, px (level-scaled).
    pub initial_cost_px: f64,
    /// See [`PoseOptResult::initial_cost_px`].
    pub final_cost_px: f64,
    /// RMS reprojection error of the inliers at the end, px (level 0).
    pub inlier_rms_px: f64,
    /// Covariance of the pose's tangent `[ρ; φ]` for 1 px² of (level-scaled) measurement
    /// noise, m² / rad²: `H⁻¹` of the final weighted normal equations (optimistic, as SVO's).
    pub covariance: Matrix6<f64>,
}

/// Residual of one observation at `zeta_ec` (level-scaled px) and its Jacobian with respect
/// to the right perturbation of the pose; `None` if the point is not in front of the camera.
pub fn residual(
    camera: &Camera,
    zeta_ec: &Isometry3<f64>,
    obs: &PoseObservation,
) -> Option<(Vector2<f64>, nalgebra::Matrix2x6<f64>)> {
    let p_c = zeta_ec.inverse_transform_point(&obs.p_e.into()).coords;
    let u = camera.project(&p_c)?;
    let scale = 1.0 / f64::from(1_u32 << obs.level.min(16));
    Some((
        (u - obs.px) * scale,
        camera.optical_flow_jacobian(&p_c) * scale,
    ))
}

/// Tukey's bisquare weight of the scaled residual norm `e` with constant `k`.
fn tukey_weight(e: f64, k: f64) -> f64 {
    if e.abs() <= k {
        let r = 1.0 - (e / k) * (e / k);
        r * r
    } else {
        0.0
    }
}

/// Weighted normal equations at `zeta_ec` with robust scale `scale_px`: `(H, g, Σ w‖e‖², E_RP)`.
fn normal_equations(
    camera: &Camera,
    zeta_ec: &Isometry3<f64>,
    observations: &[PoseObservation],
    scale_px: f64,
    k: f64,
) -> (Matrix6<f64>, Vector6<f64>, f64, f64) {
    let mut h = Matrix6::zeros();
    let mut g = Vector6::zeros();
    let (mut chi2, mut cost) = (0.0, 0.0);
    for obs in observations {
        let Some((e, j)) = residual(camera, zeta_ec, obs) else {
            continue;
        };
        let norm = e.norm();
        cost += norm;
        let w = tukey_weight(norm / scale_px, k);
        if w == 0.0 {
            continue;
        }
        let jt = j.transpose();
        h += jt * j * w;
        g += jt * e * w;
        chi2 += w * norm * norm;
    }
    (h, g, chi2, cost)
}

/// Optimise `zeta_ec` from `initial` against `observations` (eqs. `svo_pose_optim_*`), with an
/// optional prior term added to the normal equations at each iteration.
pub fn optimize_pose(
    camera: &Camera,
    initial: &Isometry3<f64>,
    observations: &[PoseObservation],
    cfg: &PoseOptConfig,
    prior: Option<&dyn PosePrior>,
) -> Result<PoseOptResult, PoseOptError> {
    let finite = |o: &PoseObservation| o.p_e.iter().chain(o.px.iter()).all(|v| v.is_finite());
    let initial_norms: Vec<f64> = observations
        .iter()
        .filter(|o| finite(o))
        .filter_map(|o| residual(camera, initial, o))
        .map(|(e, _)| e.norm())
        .collect();
    if initial_norms.len() < cfg.min_inliers.max(3) {
        return Err(PoseOptError::TooFewObservations {
            found: initial_norms.len(),
            needed: cfg.min_inliers.max(3),
        });
    }
    let usable: Vec<PoseObservation> = observations.iter().filter(|o| finite(o)).copied().collect();
    // Never below the fixed scale: a start already within a fraction of a pixel would
    // otherwise give the first iterations a cut-off below the alignment noise, and they could
    // not move the pose towards observations a pixel away (see the module doc).
    let initial_scale_px =
        median(initial_norms).map_or(cfg.fixed_scale_px, |m| (1.48 * m).max(cfg.fixed_scale_px));
    let mut zeta = *initial;
    let mut prev: Option<(Isometry3<f64>, f64, f64)> = None;
    let mut iterations = 0;
    let mut initial_cost_px = f64::NAN;
    for iter in 0..cfg.max_iterations {
        let scale_px = if iter >= cfg.fixed_scale_from_iteration {
            cfg.fixed_scale_px
        } else {
            initial_scale_px
        };
        let (mut h, mut g, chi2, cost) =
            normal_equations(camera, &zeta, &usable, scale_px, cfg.tukey_k);
        if iter == 0 {
            initial_cost_px = cost;
        }
        // With a prior the tests below watch the joint costs (`E_PO` for the stopping test).
        let prior_cost = prior.map_or(PriorCost::default(), |p| p.add(&zeta, &mut h, &mut g));
        let (chi2, cost) = if prior.is_some() {
            (chi2 + prior_cost.squared_px2, cost + prior_cost.norm_px)
        } else {
            (chi2, cost)
        };
        // The weighted error grew: the last step overshot; keep the pose before it.
        if let Some((before, chi2_before, cost_before)) = prev {
            if chi2.is_nan() || chi2 > chi2_before {
                zeta = before;
                break;
            }
            if cost_before - cost < cfg.min_cost_decrease_px {
                break;
            }
        }
        let step = -(h.cholesky().ok_or(PoseOptError::Numerical)?.solve(&g));
        if !step.iter().all(|v| v.is_finite()) {
            return Err(PoseOptError::Numerical);
        }
        prev = Some((zeta, chi2, cost));
        zeta = se3::plus(&zeta, &step);
        iterations = iter + 1;
        if step.amax() <= cfg.min_step {
            break;
        }
    }
    // Final state: inliers, cost, covariance at the fixed scale.
    let (mut h, mut g, _, final_cost_px) =
        normal_equations(camera, &zeta, &usable, cfg.fixed_scale_px, cfg.tukey_k);
    if let Some(p) = prior {
        p.add(&zeta, &mut h, &mut g);
    }
    let covariance = h.try_inverse().ok_or(PoseOptError::Numerical)?;
    let mut inliers = Vec::with_capacity(observations.len());
    let (mut n_inliers, mut sq_px2) = (0, 0.0);
    for obs in observations {
        let r = finite(obs)
            .then(|| residual(camera, &zeta, obs))
            .flatten()
            .map(|(e, _)| e.norm());
        let inlier = r.is_some_and(|n| n <= cfg.outlier_threshold_px);
        if let (true, Some(n)) = (inlier, r) {
            n_inliers += 1;
            let level0 = n * f64::from(1_u32 << obs.level.min(16));
            sq_px2 += level0 * level0;
        }
        inliers.push(inlier);
    }
    if n_inliers < cfg.min_inliers {
        return Err(PoseOptError::TooFewObservations {
            found: n_inliers,
            needed: cfg.min_inliers,
        });
    }
    Ok(PoseOptResult {
        zeta_ec: se3::renormalized(&zeta),
        iterations,
        inliers,
        n_inliers,
        initial_cost_px,
        final_cost_px,
        inlier_rms_px: (sq_px2 / n_inliers as f64).sqrt(),
        covariance,
    })
}

/// Median of a non-empty list.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::so3;
    use crate::vision::test_scene::SplitMix;
    use nalgebra::Translation3;

    /// A nadir camera 1,000 m over rolling terrain (the "E" frame here is a local level frame
    /// with z down; the optimiser only needs a fixed frame), slightly banked.
    fn scene(n: usize, rng: &mut SplitMix) -> (Camera, Isometry3<f64>, Vec<Vector3<f64>>) {
        let camera = Camera::paper();
        let truth = Isometry3::from_parts(
            Translation3::new(120.0, -40.0, -1_000.0),
            so3::from_euler_zyx(0.3, 0.02, -0.03),
        );
        let mut points = Vec::with_capacity(n);
        while points.len() < n {
            let px = Vector2::new(
                (rng.symmetric() * 0.5 + 0.5) * 767.0,
                (rng.symmetric() * 0.5 + 0.5) * 1023.0,
            );
            // Terrain height varies by ±60 m: depths 940–1,060 m.
            let depth = 1_000.0 + 60.0 * rng.symmetric();
            let p_c = camera.back_project_depth(&px, depth);
            points.push(truth.transform_point(&p_c.into()).coords);
        }
        (camera, truth, points)
    }

    fn observe(
        camera: &Camera,
        zeta: &Isometry3<f64>,
        points: &[Vector3<f64>],
        noise_px: f64,
        rng: &mut SplitMix,
    ) -> Vec<PoseObservation> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let u = camera.project_ecef(zeta, p).unwrap();
                PoseObservation {
                    p_e: *p,
                    px: u + Vector2::new(rng.normal(), rng.normal()) * noise_px,
                    level: (i % 3) as u32,
                }
            })
            .collect()
    }

    /// The residual's Jacobian is the derivative of the level-scaled reprojection error with
    /// respect to the right perturbation of the pose (central differences, 1e-6 m / rad).
    #[test]
    fn the_step_jacobian_matches_finite_differences() {
        let mut rng = SplitMix(0x1234_5678_9abc_def1);
        let (camera, truth, points) = scene(5, &mut rng);
        let obs = observe(&camera, &truth, &points, 0.0, &mut rng);
        let zeta = se3::plus(&truth, &Vector6::new(3.0, -2.0, 5.0, 0.01, -0.005, 0.02));
        for o in &obs {
            let (_, j) = residual(&camera, &zeta, o).unwrap();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = 1e-6;
                let ep = residual(&camera, &se3::plus(&zeta, &d), o).unwrap().0;
                let em = residual(&camera, &se3::plus(&zeta, &(-d)), o).unwrap().0;
                let fd = (ep - em) / 2e-6;
                let err = (fd - j.column(k)).norm();
                assert!(
                    err < 1e-4 * j.column(k).norm().max(1.0),
                    "column {k}: {err}"
                );
            }
        }
    }

    /// 250 points, 0.3 px noise, 20 % of the matches replaced by random image positions, the
    /// start 8 m and 0.7° off: the pose comes back within 4 σ of the reported covariance (scaled
    /// by the noise) on every axis and jointly, the outliers are found, the inliers kept.
    #[test]
    fn a_known_pose_is_recovered_with_twenty_percent_outliers() {
        let mut rng = SplitMix(0x0dd_ba11_cafe_f00d);
        let (camera, truth, points) = scene(250, &mut rng);
        let noise_px = 0.3;
        let mut obs = observe(&camera, &truth, &points, noise_px, &mut rng);
        let mut is_outlier = vec![false; obs.len()];
        for (i, o) in obs.iter_mut().enumerate() {
            if i % 5 == 0 {
                o.px = Vector2::new(
                    (rng.symmetric() * 0.5 + 0.5) * 767.0,
                    (rng.symmetric() * 0.5 + 0.5) * 1023.0,
                );
                is_outlier[i] = true;
            }
        }
        let start = se3::plus(&truth, &Vector6::new(5.0, -4.0, 5.0, 0.006, -0.006, 0.008));
        let r = optimize_pose(&camera, &start, &obs, &PoseOptConfig::default(), None).unwrap();
        let err = se3::minus(&r.zeta_ec, &truth);
        // The covariance is for 1 px² of level-scaled noise: scale by the noise variance.
        let cov = r.covariance * noise_px * noise_px;
        for k in 0..6 {
            let sigma = cov[(k, k)].sqrt();
            assert!(
                err[k].abs() < 4.0 * sigma,
                "axis {k}: {} vs σ {sigma}",
                err[k]
            );
        }
        // Jointly: the normalised error squared is χ²(6); 22.5 is its 99.9 % point. (Along-track
        // translation and pitch trade against each other under a narrow nadir view, so the
        // error lies along their correlation, not within a box.)
        let nees = err.dot(&(cov.try_inverse().unwrap() * err));
        assert!(nees < 22.5, "NEES {nees}: {err}");
        let found = (0..obs.len())
            .filter(|&i| is_outlier[i] && !r.inliers[i])
            .count();
        let lost = (0..obs.len())
            .filter(|&i| !is_outlier[i] && !r.inliers[i])
            .count();
        let n_out = is_outlier.iter().filter(|&&o| o).count();
        // A random position lands within 2 px of the truth with probability ≈ 1e-5.
        assert!(found >= n_out - 1, "{found} of {n_out} outliers found");
        // 0.3 px noise at level 0: 2 px is > 6 σ at every level.
        assert_eq!(lost, 0);
        assert!(r.inlier_rms_px < 2.0 * noise_px, "{}", r.inlier_rms_px);
        assert!(r.final_cost_px < r.initial_cost_px);
    }

    /// A prior term is added to the normal equations: a stiff prior holding the pose at its
    /// start against consistent observations of another pose keeps it there.
    #[test]
    fn a_prior_enters_the_normal_equations() {
        struct Hold(Isometry3<f64>, f64);
        impl PosePrior for Hold {
            fn add(
                &self,
                zeta: &Isometry3<f64>,
                h: &mut Matrix6<f64>,
                g: &mut Vector6<f64>,
            ) -> PriorCost {
                // Stiffness `s` on `zeta ⊖ target` (first order).
                let d = se3::minus(zeta, &self.0);
                *h += Matrix6::identity() * self.1;
                *g += d * self.1;
                PriorCost {
                    squared_px2: self.1 * d.norm_squared(),
                    norm_px: self.1.sqrt() * d.norm(),
                }
            }
        }
        let mut rng = SplitMix(42);
        let (camera, truth, points) = scene(100, &mut rng);
        let obs = observe(&camera, &truth, &points, 0.0, &mut rng);
        let start = se3::plus(&truth, &Vector6::new(2.0, 0.0, 0.0, 0.0, 0.0, 0.002));
        let free = optimize_pose(&camera, &start, &obs, &PoseOptConfig::default(), None).unwrap();
        assert!(se3::minus(&free.zeta_ec, &truth).norm() < 1e-6);
        let cfg = PoseOptConfig {
            outlier_threshold_px: 1e6,
            ..PoseOptConfig::default()
        };
        let held = optimize_pose(&camera, &start, &obs, &cfg, Some(&Hold(start, 1e12))).unwrap();
        assert!(se3::minus(&held.zeta_ec, &start).norm() < 1e-3);
    }

    #[test]
    fn too_few_or_bad_observations_are_an_error_not_a_panic() {
        let mut rng = SplitMix(7);
        let (camera, truth, points) = scene(30, &mut rng);
        let mut obs = observe(&camera, &truth, &points, 0.0, &mut rng);
        for o in obs.iter_mut().skip(5) {
            o.p_e.x = f64::NAN;
        }
        let cfg = PoseOptConfig::default();
        assert!(matches!(
            optimize_pose(&camera, &truth, &obs, &cfg, None),
            Err(PoseOptError::TooFewObservations { found: 5, .. })
        ));
        // Points behind the camera do not count either.
        let behind = se3::plus(
            &truth,
            &Vector6::new(0.0, 0.0, 0.0, std::f64::consts::PI, 0.0, 0.0),
        );
        let obs = observe(&camera, &truth, &points, 0.0, &mut rng);
        assert!(optimize_pose(&camera, &behind, &obs, &cfg, None).is_err());
    }
}
