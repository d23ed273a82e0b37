//! Stage 1 and the joint prior-based pose optimisation of the IA-VNS (paper sections "IA-VNS
//! rationale" and "IA-VNS prior"; eqs. `nav_vis_assist_pose_optim_*` and
//! `nav_vis_assist_optim_joint_*`).
//!
//! Stage 1 is SVO's reprojection-only pose optimisation ([`crate::vision::pose_opt`]); its
//! result `zeta_ec**` gives the body pose `zeta_eb** = zeta_ec** ⊗ zeta_bc*`, its altitude and
//! Euler angles ([`VisualBodyPose`]). The activation rules turn those into a target body attitude
//! that differs from `q_nb**` in pitch and bank only (the yaw stays the visual one: the INS
//! yaw is never used), and the target camera attitude `q_ec°° = q_en** ⊗ q_nb°° ⊗ q_bc` with
//! `q_en**` frozen ([`target_q_ec`]). The joint optimisation minimises
//! `E_PO = E_RP + f_q · E_q` over all six degrees of freedom ([`AttitudePrior`], a
//! [`PosePrior`] of the reprojection-only optimiser), where `E_q` is the distance between the
//! camera attitude's rotation vector and the target's ([`attitude_error`]) and
//! `f_q = E_RP(ζ_i0) / E_q(ζ_i0)` is set per image at the initial pose.
//!
//! Decided where the paper is ambiguous (docs/IAVNS.md):
//! - **`f_q` against `f_q²`.** The paper's Hessian carries `f_q²` and its gradient `f_q`. The
//!   default ([`PriorWeighting::Consistent`]) is Gauss-Newton on `½Σw‖e‖² + ½f_q²‖E_q‖²`, with
//!   `f_q²` in both, whose result does not depend on the residuals' units;
//!   [`PriorWeighting::PaperLiteral`] keeps the printed equations.
//! - **The rotation-vector difference near π.** `Log(q_ec) − Log(q_ec°°)` jumps by 2π where the
//!   two rotation vectors straddle the branch cut; the literal form then takes the target's
//!   equivalent vector on the other side ([`AttitudeErrorForm::PaperLiteral`]).
//!   [`AttitudeErrorForm::Geodesic`] uses `Log(q_ec°°* ⊗ q_ec)` instead.

use nalgebra::{Isometry3, Matrix3, Matrix3x6, Matrix6, UnitQuaternion, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use crate::math::{so3, wgs84};
use crate::vision::camera::Camera;
use crate::vision::pose_opt::{PoseObservation, PosePrior, PriorCost, residual};

/// How the attitude term enters the Gauss-Newton step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PriorWeighting {
    /// `f_q²` in the Hessian and in the gradient: Gauss-Newton on the attitude residual scaled
    /// by `f_q` (independent of the residuals' units).
    #[default]
    Consistent,
    /// The paper's printed equations: `f_q²` in the Hessian, `f_q` in the gradient.
    PaperLiteral,
}

/// How the attitude adjustment error `E_q` is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AttitudeErrorForm {
    /// The paper's Euclidean difference of rotation vectors `Log(q_ec) − Log(q_ec°°)`, with the
    /// target's equivalent vector taken across the branch cut when the two straddle it.
    #[default]
    PaperLiteral,
    /// The geodesic error `Log(q_ec°°* ⊗ q_ec)`.
    Geodesic,
}

/// Where the joint optimisation starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointStart {
    /// The initial pose `ζ_i0` of the reprojection-only optimisation (the paper: `f_q` and the
    /// `E_q` iteration are defined there).
    #[default]
    InitialPose,
    /// The reprojection-only solution `ζ**` (cheaper; the same fixed point).
    ReprojectionOnly,
}

/// Settings of the prior-based pose optimisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PriorConfig {
    /// `f_q` or `f_q²` in the gradient.
    pub weighting: PriorWeighting,
    /// The form of `E_q`.
    pub attitude_error: AttitudeErrorForm,
    /// Where the joint iteration starts.
    pub joint_start: JointStart,
    /// An attitude error `E_q(ζ_i0)` below this leaves `f_q` undefined: the prior is skipped
    /// and the reprojection-only solution kept, rad.
    pub min_attitude_error_rad: f64,
}

impl Default for PriorConfig {
    fn default() -> Self {
        Self {
            weighting: PriorWeighting::Consistent,
            attitude_error: AttitudeErrorForm::PaperLiteral,
            joint_start: JointStart::InitialPose,
            min_attitude_error_rad: 1e-12,
        }
    }
}

/// The body pose of a visual camera pose (stage 1 of the paper's section "IA-VNS rationale").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisualBodyPose {
    /// Body pose, body → Earth (`zeta_eb = zeta_ec ⊗ zeta_bc*`).
    pub zeta_eb: Isometry3<f64>,
    /// Geodetic position of the body's reference point.
    pub pos: wgs84::Geodetic,
    /// Earth → NED rotation at `pos` (`q_en`).
    pub q_en: UnitQuaternion<f64>,
    /// Body attitude `q_nb = q_en* ⊗ q_eb`.
    pub q_nb: UnitQuaternion<f64>,
    /// ZYX Euler angles of `q_nb`: `[yaw ψ, pitch θ, bank ξ]`, rad.
    pub euler_rad: Vector3<f64>,
}

impl VisualBodyPose {
    /// The body pose of the camera pose `zeta_ec`, with the camera mounted at `zeta_bc`
    /// (camera → body).
    pub fn from_camera(zeta_ec: &Isometry3<f64>, zeta_bc: &Isometry3<f64>) -> Self {
        let zeta_eb = zeta_ec * zeta_bc.inverse();
        let pos = wgs84::ecef_to_geodetic(&zeta_eb.translation.vector);
        let q_en = wgs84::q_en(pos.lat_rad, pos.lon_rad);
        let q_nb = q_en.inverse() * zeta_eb.rotation;
        Self {
            zeta_eb,
            pos,
            q_en,
            q_nb,
            euler_rad: so3::euler_zyx(&q_nb),
        }
    }

    /// Altitude above the ellipsoid, m.
    pub fn h_m(&self) -> f64 {
        self.pos.h_m
    }
}

/// The target camera attitude `q_ec°° = q_en** ⊗ q_nb°° ⊗ q_bc`: the visual body attitude with
/// its pitch and bank moved by `dpitch_rad` and `dbank_rad` and its yaw kept, seen through the
/// NED frame of the visual position (frozen over the iterations).
pub fn target_q_ec(
    body: &VisualBodyPose,
    dpitch_rad: f64,
    dbank_rad: f64,
    q_bc: &UnitQuaternion<f64>,
) -> UnitQuaternion<f64> {
    let [yaw, pitch, bank] = [body.euler_rad[0], body.euler_rad[1], body.euler_rad[2]];
    let q_nb_target = so3::from_euler_zyx(yaw, pitch + dpitch_rad, bank + dbank_rad);
    body.q_en * q_nb_target * q_bc
}

/// The SLERP mode's target camera attitude (beyond the paper; its eq.
/// `nav_vis_assist_priors_activation_pitch_atttitude`): the visual body attitude turned by
/// `slerp_rad` towards the INS attitude `q_nb_ins` along the geodesic,
/// `q** ⊗ Exp(t·Log(q**⁻¹ ⊗ q̂))` with `t = Δφ°°/Δφ**` (at most 1), then its pitch moved by
/// `dpitch_rad` (the altitude and rate-of-climb terms), seen through the frozen `q_en**`.
pub fn target_q_ec_slerp(
    body: &VisualBodyPose,
    q_nb_ins: &UnitQuaternion<f64>,
    slerp_rad: f64,
    dpitch_rad: f64,
    q_bc: &UnitQuaternion<f64>,
) -> UnitQuaternion<f64> {
    let dr = so3::log(&(body.q_nb.inverse() * q_nb_ins));
    let dphi = dr.norm();
    let turned = if dphi > 0.0 {
        body.q_nb * so3::exp(&(dr * (slerp_rad / dphi).min(1.0)))
    } else {
        body.q_nb
    };
    let e = so3::euler_zyx(&turned);
    let q_nb_target = so3::from_euler_zyx(e[0], e[1] + dpitch_rad, e[2]);
    body.q_en * q_nb_target * q_bc
}

/// The attitude adjustment error `E_q` of `q_ec` against `target` and its Jacobian with
/// respect to the right perturbation `q_ec ∘ Exp(δθ)` (eq.
/// `nav_vis_assist_pose_optim_pitch_objective`; `J_R⁻¹` of eq.
/// `nav_vis_assist_pose_optim_pitch_jacobian`).
pub fn attitude_error(
    q_ec: &UnitQuaternion<f64>,
    target: &UnitQuaternion<f64>,
    form: AttitudeErrorForm,
) -> (Vector3<f64>, Matrix3<f64>) {
    match form {
        AttitudeErrorForm::PaperLiteral => {
            let r = so3::log(q_ec);
            let mut r_target = so3::log(target);
            // Straddling the branch cut at π: the same target rotation, 2π along its axis.
            let angle = r_target.norm();
            if (r - r_target).norm() > std::f64::consts::PI && angle > 0.0 {
                r_target -= r_target * (2.0 * std::f64::consts::PI / angle);
            }
            (r - r_target, so3::right_jacobian_inv(&r))
        }
        AttitudeErrorForm::Geodesic => {
            let e = so3::log(&(target.inverse() * q_ec));
            (e, so3::right_jacobian_inv(&e))
        }
    }
}

/// The sum of the reprojection-error norms `E_RP` at `zeta_ec`, px (level-scaled, as the
/// optimiser's; observations not in front of the camera or not finite do not count).
pub fn reprojection_cost_px(
    camera: &Camera,
    zeta_ec: &Isometry3<f64>,
    observations: &[PoseObservation],
) -> f64 {
    observations
        .iter()
        .filter(|o| o.p_e.iter().chain(o.px.iter()).all(|v| v.is_finite()))
        .filter_map(|o| residual(camera, zeta_ec, o))
        .map(|(e, _)| e.norm())
        .sum()
}

/// The attitude term of `E_PO = E_RP + f_q · E_q`, added to the reprojection-only optimiser's
/// normal equations at every iteration (eqs. `nav_vis_assist_optim_joint_hes` and
/// `nav_vis_assist_pose_optim_joint_solution`, with `J_RR⁻¹ = [0₃ₓ₃ J_R⁻¹]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudePrior {
    /// Target camera attitude `q_ec°°`.
    pub target_q_ec: UnitQuaternion<f64>,
    /// The weight `f_q`, px/rad.
    pub f_q: f64,
    /// `f_q` or `f_q²` in the gradient.
    pub weighting: PriorWeighting,
    /// The form of `E_q`.
    pub form: AttitudeErrorForm,
}

impl AttitudePrior {
    /// The prior towards `target_q_ec` with `f_q = E_RP(ζ_i0) / E_q(ζ_i0)`: the weighted attitude
    /// error equals the reprojection error at the initial pose `zeta_i0` (the paper: "the same
    /// weight to the two active components"). `None` when `E_q(ζ_i0)` is below
    /// `cfg.min_attitude_error_rad` or either cost is not finite.
    pub fn at_initial_pose(
        camera: &Camera,
        zeta_i0: &Isometry3<f64>,
        observations: &[PoseObservation],
        target_q_ec: &UnitQuaternion<f64>,
        cfg: &PriorConfig,
    ) -> Option<Self> {
        let (e_q, _) = attitude_error(&zeta_i0.rotation, target_q_ec, cfg.attitude_error);
        let e_q_rad = e_q.norm();
        let e_rp_px = reprojection_cost_px(camera, zeta_i0, observations);
        if !(e_q_rad.is_finite() && e_rp_px.is_finite()) || e_q_rad < cfg.min_attitude_error_rad {
            return None;
        }
        Some(Self {
            target_q_ec: *target_q_ec,
            f_q: e_rp_px / e_q_rad,
            weighting: cfg.weighting,
            form: cfg.attitude_error,
        })
    }

    /// `E_q` at `zeta_ec`, rad.
    pub fn attitude_error_rad(&self, zeta_ec: &Isometry3<f64>) -> f64 {
        attitude_error(&zeta_ec.rotation, &self.target_q_ec, self.form)
            .0
            .norm()
    }

    /// The multiplier of `J_RRᵀ E_q` in the gradient.
    fn gradient_weight(&self) -> f64 {
        match self.weighting {
            PriorWeighting::Consistent => self.f_q * self.f_q,
            PriorWeighting::PaperLiteral => self.f_q,
        }
    }
}

impl PosePrior for AttitudePrior {
    fn add(
        &self,
        zeta_ec: &Isometry3<f64>,
        h: &mut Matrix6<f64>,
        g: &mut Vector6<f64>,
    ) -> PriorCost {
        let (e_q, j_r_inv) = attitude_error(&zeta_ec.rotation, &self.target_q_ec, self.form);
        // J_RR⁻¹ = [0₃ₓ₃ J_R⁻¹]: the rotation is the twist's second half, and the rotation of
        // ζ ∘ Exp([ρ; φ]) is q ∘ Exp(φ) whatever ρ is.
        let mut j_rr = Matrix3x6::zeros();
        j_rr.fixed_view_mut::<3, 3>(0, 3).copy_from(&j_r_inv);
        let jt = j_rr.transpose();
        *h += jt * j_rr * (self.f_q * self.f_q);
        let w = self.gradient_weight();
        *g += jt * e_q * w;
        PriorCost {
            // The objective whose gradient is the one above: ½·w·‖E_q‖² (doubled, as χ²).
            squared_px2: w * e_q.norm_squared(),
            norm_px: self.f_q * e_q.norm(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::se3;
    use crate::vision::pose_opt::{PoseOptConfig, optimize_pose};
    use crate::vision::test_scene::SplitMix;
    use nalgebra::{Translation3, Vector2};

    /// The camera pose of a body 1,000 m over the ellipsoid near 34.7° N, 89° W (the MX zone),
    /// flying heading `yaw`, with a nadir camera mounted at `zeta_bc`.
    fn nadir_pose(yaw: f64, pitch: f64, bank: f64) -> (Isometry3<f64>, Isometry3<f64>) {
        let pos = wgs84::Geodetic {
            lat_rad: 34.72_f64.to_radians(),
            lon_rad: (-89.0_f64).to_radians(),
            h_m: 1_100.0,
        };
        let q_eb = wgs84::q_en(pos.lat_rad, pos.lon_rad) * so3::from_euler_zyx(yaw, pitch, bank);
        let zeta_eb =
            Isometry3::from_parts(Translation3::from(wgs84::geodetic_to_ecef(&pos)), q_eb);
        // Camera z (optical axis) along body z (down), camera x along body y (right wing).
        let q_bc = UnitQuaternion::from_matrix(&Matrix3::new(
            0.0, -1.0, 0.0, //
            1.0, 0.0, 0.0, //
            0.0, 0.0, 1.0,
        ));
        let zeta_bc = Isometry3::from_parts(Translation3::new(0.3, 0.0, 0.2), q_bc);
        (zeta_eb * zeta_bc, zeta_bc)
    }

    /// Ground points 1,000 m below the camera (±50 m of relief) seen without noise.
    fn observations(camera: &Camera, zeta_ec: &Isometry3<f64>, n: usize) -> Vec<PoseObservation> {
        let mut rng = SplitMix(0x001A_B5EE);
        (0..n)
            .map(|_| {
                let px = Vector2::new(
                    (rng.symmetric() * 0.45 + 0.5) * 767.0,
                    (rng.symmetric() * 0.45 + 0.5) * 1023.0,
                );
                let p_c = camera.back_project_depth(&px, 1_000.0 + 50.0 * rng.symmetric());
                PoseObservation {
                    p_e: zeta_ec.transform_point(&p_c.into()).coords,
                    px,
                    level: 0,
                }
            })
            .collect()
    }

    /// Stage 1 reads back the body pose it was built from: altitude, yaw, pitch and bank.
    #[test]
    fn the_visual_body_pose_reads_back_altitude_and_euler_angles() {
        let (zeta_ec, zeta_bc) = nadir_pose(2.0, 0.05, -0.1);
        let body = VisualBodyPose::from_camera(&zeta_ec, &zeta_bc);
        assert!((body.h_m() - 1_100.0).abs() < 1e-6, "{}", body.h_m());
        let e = body.euler_rad;
        assert!((e - Vector3::new(2.0, 0.05, -0.1)).amax() < 1e-12, "{e:?}");
    }

    /// The target differs from the visual attitude by the adjustments in pitch and bank and
    /// keeps its yaw; with zero adjustments it is the visual camera attitude itself.
    #[test]
    fn the_target_moves_pitch_and_bank_only() {
        let (zeta_ec, zeta_bc) = nadir_pose(-2.5, 0.03, 0.2);
        let body = VisualBodyPose::from_camera(&zeta_ec, &zeta_bc);
        let same = target_q_ec(&body, 0.0, 0.0, &zeta_bc.rotation);
        assert!(same.angle_to(&zeta_ec.rotation) < 1e-14);
        let (dp, db) = (1e-5, -2e-5);
        let target = target_q_ec(&body, dp, db, &zeta_bc.rotation);
        let q_nb = body.q_en.inverse() * target * zeta_bc.rotation.inverse();
        let e = so3::euler_zyx(&q_nb) - body.euler_rad;
        assert!((e - Vector3::new(0.0, dp, db)).amax() < 1e-13, "{e:?}");
    }

    /// The SLERP target lies on the geodesic from the visual attitude to the INS's, `Δφ°°`
    /// from the first and `Δφ** − Δφ°°` from the second (yaw included), never past the INS's;
    /// the altitude term's pitch is added on top.
    #[test]
    fn the_slerp_target_turns_along_the_geodesic_towards_the_ins() {
        let (zeta_ec, zeta_bc) = nadir_pose(1.2, 0.02, -0.05);
        let body = VisualBodyPose::from_camera(&zeta_ec, &zeta_bc);
        let q_ins = body.q_nb * so3::exp(&Vector3::new(2e-3, -1e-3, 4e-3));
        let dphi = body.q_nb.angle_to(&q_ins);
        let body_of =
            |q_ec: UnitQuaternion<f64>| body.q_en.inverse() * q_ec * zeta_bc.rotation.inverse();
        let slerp = 1e-3;
        let target = body_of(target_q_ec_slerp(
            &body,
            &q_ins,
            slerp,
            0.0,
            &zeta_bc.rotation,
        ));
        assert!((body.q_nb.angle_to(&target) - slerp).abs() < 1e-12);
        assert!((target.angle_to(&q_ins) - (dphi - slerp)).abs() < 1e-12);
        // The yaw moves too (the INS is 4 mrad off about the body's z axis, mostly yaw).
        let dyaw = so3::euler_zyx(&target)[0] - body.euler_rad[0];
        assert!(dyaw.abs() > 1e-4, "{dyaw}");
        // Capped at the INS attitude.
        let past = body_of(target_q_ec_slerp(
            &body,
            &q_ins,
            1.0,
            0.0,
            &zeta_bc.rotation,
        ));
        assert!(past.angle_to(&q_ins) < 1e-12);
        // Zero rotation and zero pitch: the visual attitude itself; the pitch adds on top.
        let same = target_q_ec_slerp(&body, &q_ins, 0.0, 0.0, &zeta_bc.rotation);
        assert!(same.angle_to(&zeta_ec.rotation) < 1e-14);
        let pitched = body_of(target_q_ec_slerp(
            &body,
            &q_ins,
            0.0,
            1e-5,
            &zeta_bc.rotation,
        ));
        let e = so3::euler_zyx(&pitched) - body.euler_rad;
        assert!((e - Vector3::new(0.0, 1e-5, 0.0)).amax() < 1e-13, "{e:?}");
    }

    /// The Jacobian of `E_q` is its derivative with respect to the right perturbation, in both
    /// forms (central differences of 1e-7 rad).
    #[test]
    fn the_attitude_error_jacobian_matches_finite_differences() {
        let (zeta_ec, _) = nadir_pose(1.0, 0.1, 0.2);
        let q = zeta_ec.rotation;
        let target = q * so3::exp(&Vector3::new(2e-3, -1e-3, 3e-3));
        for form in [AttitudeErrorForm::PaperLiteral, AttitudeErrorForm::Geodesic] {
            let (_, j) = attitude_error(&q, &target, form);
            for k in 0..3 {
                let mut d = Vector3::zeros();
                d[k] = 1e-7;
                let ep = attitude_error(&so3::plus(&q, &d), &target, form).0;
                let em = attitude_error(&so3::plus(&q, &(-d)), &target, form).0;
                let fd = (ep - em) / 2e-7;
                assert!((fd - j.column(k)).amax() < 1e-7, "{form:?} column {k}");
            }
        }
    }

    /// Near a rotation of π the two rotation vectors can lie on opposite sides of the branch
    /// cut: 0.001° apart as rotations, yet their plain difference is ≈ 2π. Both forms give the
    /// small error.
    #[test]
    fn the_attitude_error_is_small_across_the_branch_cut_at_pi() {
        let axis = Vector3::new(0.3, -0.5, 0.8).normalize();
        let pi = std::f64::consts::PI;
        let q = so3::exp(&(axis * (pi - 1e-5)));
        let target = so3::exp(&(axis * (pi + 1e-5)));
        let plain = so3::log(&q) - so3::log(&target);
        assert!(plain.norm() > 6.0, "{}", plain.norm());
        for form in [AttitudeErrorForm::PaperLiteral, AttitudeErrorForm::Geodesic] {
            let (e, _) = attitude_error(&q, &target, form);
            assert!((e.norm() - 2e-5).abs() < 1e-9, "{form:?}: {}", e.norm());
        }
    }

    /// `f_q` makes the weighted attitude error equal the reprojection error at the initial
    /// pose, and the prior is skipped when the initial pose already has the target attitude.
    #[test]
    fn f_q_balances_the_two_costs_at_the_initial_pose() {
        let camera = Camera::paper();
        let (truth, _) = nadir_pose(0.7, 0.0, 0.0);
        let obs = observations(&camera, &truth, 150);
        let start = se3::plus(&truth, &Vector6::new(4.0, -3.0, 2.0, 2e-4, -1e-4, 3e-4));
        let target = truth.rotation * so3::exp(&Vector3::new(0.0, 5e-4, 0.0));
        let cfg = PriorConfig::default();
        let prior = AttitudePrior::at_initial_pose(&camera, &start, &obs, &target, &cfg).unwrap();
        let e_rp = reprojection_cost_px(&camera, &start, &obs);
        assert!(e_rp > 100.0, "{e_rp}");
        let weighted = prior.f_q * prior.attitude_error_rad(&start);
        assert!(
            (weighted - e_rp).abs() < 1e-9 * e_rp,
            "{weighted} vs {e_rp}"
        );
        assert!(
            AttitudePrior::at_initial_pose(&camera, &start, &obs, &start.rotation, &cfg).is_none()
        );
    }

    /// The joint step is Gauss-Newton on the joint objective: the Hessian and gradient the
    /// prior adds (consistent form) are those of `½·f_q²·‖E_q‖²`, checked against finite
    /// differences of the objective along each tangent axis.
    #[test]
    fn the_consistent_prior_is_the_gradient_and_hessian_of_its_objective() {
        let (zeta, _) = nadir_pose(-1.2, 0.02, 0.05);
        let target = zeta.rotation * so3::exp(&Vector3::new(-3e-3, 2e-3, 1e-3));
        let prior = AttitudePrior {
            target_q_ec: target,
            f_q: 1e5,
            weighting: PriorWeighting::Consistent,
            form: AttitudeErrorForm::PaperLiteral,
        };
        let objective = |z: &Isometry3<f64>| {
            let (mut h, mut g) = (Matrix6::zeros(), Vector6::zeros());
            0.5 * prior.add(z, &mut h, &mut g).squared_px2
        };
        let (mut h, mut g) = (Matrix6::zeros(), Vector6::zeros());
        prior.add(&zeta, &mut h, &mut g);
        let d = 1e-6;
        for k in 0..6 {
            let mut t = Vector6::zeros();
            t[k] = d;
            let fp = objective(&se3::plus(&zeta, &t));
            let fm = objective(&se3::plus(&zeta, &(-t)));
            let f0 = objective(&zeta);
            let grad = (fp - fm) / (2.0 * d);
            let curv = (fp - 2.0 * f0 + fm) / (d * d);
            let scale = prior.f_q * prior.f_q;
            assert!(
                (grad - g[k]).abs() < 1e-6 * scale * 1e-2,
                "g[{k}]: {grad} vs {}",
                g[k]
            );
            // Gauss-Newton's Hessian drops the residual's curvature, O(‖E_q‖) of it.
            assert!(
                (curv - h[(k, k)]).abs() < 1e-2 * scale,
                "H[{k}{k}]: {curv} vs {}",
                h[(k, k)]
            );
        }
        // Translation does not enter the attitude term.
        assert!(h.fixed_view::<3, 6>(0, 0).amax() == 0.0 && g.fixed_rows::<3>(0).amax() == 0.0);
    }

    /// The joint normal equations (reprojection terms with unit weights plus the consistent
    /// prior) are the gradient and Gauss-Newton Hessian of `½(Σ‖e_j‖² + f_q²‖E_q‖²)`: central
    /// differences of that objective along each tangent axis.
    #[test]
    fn the_joint_gradient_and_hessian_match_finite_differences_of_e_po() {
        let camera = Camera::paper();
        let (truth, _) = nadir_pose(2.2, 0.01, -0.03);
        let obs = observations(&camera, &truth, 60);
        let zeta = se3::plus(&truth, &Vector6::new(1.5, -2.0, 0.5, 2e-4, -1e-4, 1e-4));
        let target = truth.rotation * so3::exp(&Vector3::new(0.0, 3e-4, 0.0));
        let prior =
            AttitudePrior::at_initial_pose(&camera, &zeta, &obs, &target, &PriorConfig::default())
                .unwrap();
        let joint = |z: &Isometry3<f64>| {
            let (mut h, mut g, mut chi2) = (Matrix6::zeros(), Vector6::zeros(), 0.0);
            for o in &obs {
                let (e, j) = residual(&camera, z, o).unwrap();
                h += j.transpose() * j;
                g += j.transpose() * e;
                chi2 += e.norm_squared();
            }
            let c = prior.add(z, &mut h, &mut g);
            (h, g, 0.5 * (chi2 + c.squared_px2))
        };
        let (h, g, f0) = joint(&zeta);
        for k in 0..6 {
            // Metres for translation, radians for rotation: steps of similar image effect.
            let d = if k < 3 { 1e-4 } else { 1e-8 };
            let mut t = Vector6::zeros();
            t[k] = d;
            let fp = joint(&se3::plus(&zeta, &t)).2;
            let fm = joint(&se3::plus(&zeta, &(-t))).2;
            let grad = (fp - fm) / (2.0 * d);
            let curv = (fp - 2.0 * f0 + fm) / (d * d);
            assert!(
                (grad - g[k]).abs() < 1e-4 * g[k].abs().max(1.0),
                "g[{k}]: {grad} vs {}",
                g[k]
            );
            // Gauss-Newton drops the residuals' own curvature: small at a few pixels.
            assert!(
                (curv - h[(k, k)]).abs() < 2e-2 * h[(k, k)],
                "H[{k}{k}]: {curv} vs {}",
                h[(k, k)]
            );
        }
    }

    /// What `f_q` does in each weighting (noise-free, 150 points 1,000 m below, a start 4 m
    /// and 0.014° off, a pitch target 0.01° from the truth):
    /// - consistent: the prior's stiffness `f_q²` (≈ 1e12 px²/rad² here) dwarfs the
    ///   reprojection terms' (≈ N·f² ≈ 2e8), so the attitude reaches the target and the
    ///   translation takes up the rest: the reprojection cost stays below what the rotation
    ///   alone would cost (1.7e-4 rad · 1,118 px ≈ 0.19 px per point). This is also where the
    ///   paper's sums of norms put it: `f_q` ≫ `N·f` makes the attitude term's slope dominate.
    /// - paper-literal: the step in rotation is `f_q / f_q²` of the consistent one, so the
    ///   attitude stays where it started (`ζ_i0`) while the translation converges.
    #[test]
    fn the_joint_optimum_meets_the_target_and_the_literal_form_freezes_the_rotation() {
        let camera = Camera::paper();
        let (truth, _) = nadir_pose(0.3, 0.0, 0.0);
        let obs = observations(&camera, &truth, 150);
        let start = se3::plus(&truth, &Vector6::new(3.0, 2.0, -1.0, 1e-4, 2e-4, -1e-4));
        // A target 1.7e-4 rad from the truth about the camera's x axis (a pitch change for a
        // nadir camera whose x is the right wing).
        let target = truth.rotation * so3::exp(&Vector3::new(1.7e-4, 0.0, 0.0));
        let cfg = PoseOptConfig {
            outlier_threshold_px: 1e3,
            ..PoseOptConfig::default()
        };
        let free = optimize_pose(&camera, &start, &obs, &cfg, None).unwrap();
        assert!(free.zeta_ec.rotation.angle_to(&truth.rotation) < 1e-9);
        let joint = |weighting| {
            let prior_cfg = PriorConfig {
                weighting,
                ..PriorConfig::default()
            };
            let prior =
                AttitudePrior::at_initial_pose(&camera, &start, &obs, &target, &prior_cfg).unwrap();
            (
                prior.f_q,
                optimize_pose(&camera, &start, &obs, &cfg, Some(&prior)).unwrap(),
            )
        };
        let (f_q, consistent) = joint(PriorWeighting::Consistent);
        assert!(f_q > 1e5, "f_q {f_q}");
        let to_target = consistent.zeta_ec.rotation.angle_to(&target);
        assert!(to_target < 0.01 * 1.7e-4, "{to_target} rad from the target");
        let per_point_px = consistent.final_cost_px / obs.len() as f64;
        assert!(per_point_px < 0.19, "{per_point_px} px per point");
        let moved_m = (consistent.zeta_ec.translation.vector - truth.translation.vector).norm();
        assert!(
            moved_m > 0.05,
            "the translation did not compensate: {moved_m} m"
        );
        let (_, literal) = joint(PriorWeighting::PaperLiteral);
        let rotated = literal.zeta_ec.rotation.angle_to(&start.rotation);
        let start_to_target = start.rotation.angle_to(&target);
        assert!(
            rotated < 0.01 * start_to_target,
            "literal: rotated {rotated} rad of {start_to_target}"
        );
    }
}
