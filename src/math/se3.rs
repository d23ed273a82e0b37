//! SE(3) poses (`nalgebra::Isometry3`) with right perturbations (paper, "Mathematical
//! Notation"; Sola et al., "A micro Lie theory", 2018, SE(3) appendix; Barfoot, "State
//! Estimation for Robotics", 2017, SE(3) Jacobians). Tangent vectors are ordered
//! `[ρ (translation); φ (rotation)]`, matching the paper's twist `[v; ω]`.
//!
//! `Exp([ρ; φ]) = (Exp_SO3(φ), J_l(φ) ρ)`. The right Jacobian is `J_r(τ) = J_l(−τ)`, built from
//! the SO(3) right Jacobian and Barfoot's Q-matrix evaluated at `(−ρ, −φ)`.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, Vector3, Vector6};

use super::so3::{self, SERIES_THRESHOLD_RAD, horner, skew};

/// Splits a twist into `(ρ, φ)`.
#[inline]
fn split(tau: &Vector6<f64>) -> (Vector3<f64>, Vector3<f64>) {
    (
        Vector3::new(tau[0], tau[1], tau[2]),
        Vector3::new(tau[3], tau[4], tau[5]),
    )
}

/// Exponential map of a twist `[ρ; φ]`: rotation `Exp(φ)`, translation `J_l(φ) ρ`.
pub fn exp(tau: &Vector6<f64>) -> Isometry3<f64> {
    let (rho, phi) = split(tau);
    let t = so3::left_jacobian(&phi) * rho;
    Isometry3::from_parts(Translation3::from(t), so3::exp(&phi))
}

/// Logarithmic map of a pose, returning `[ρ; φ]` with `|φ| ≤ π`.
pub fn log(pose: &Isometry3<f64>) -> Vector6<f64> {
    let phi = so3::log(&pose.rotation);
    let rho = so3::left_jacobian_inv(&phi) * pose.translation.vector;
    Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

/// The pose with its rotation quaternion renormalised. Compositions of `Isometry3` keep the
/// quaternion's norm error and inverses (conjugates) double it, so chains of relative poses
/// that feed back into themselves (visual odometry) let it grow geometrically, and a
/// quaternion off unit norm distorts every vector it rotates (a scale error the camera sees as
/// a change of height): renormalise what is stored.
pub fn renormalized(pose: &Isometry3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        pose.translation,
        nalgebra::UnitQuaternion::new_normalize(pose.rotation.into_inner()),
    )
}

/// `X ⊕ τ = X ∘ Exp(τ)`.
pub fn plus(x: &Isometry3<f64>, tau: &Vector6<f64>) -> Isometry3<f64> {
    x * exp(tau)
}

/// `Y ⊖ X = Log(X⁻¹ ∘ Y)`.
pub fn minus(y: &Isometry3<f64>, x: &Isometry3<f64>) -> Vector6<f64> {
    log(&(x.inverse() * y))
}

/// Barfoot's `Q(ρ, φ)`, the upper-right block of the SE(3) *left* Jacobian
/// `J_l = [[J_l(φ), Q(ρ, φ)], [0, J_l(φ)]]` (Barfoot; Sola et al.):
///
/// `Q = ½[ρ]× + c₁ ([φ]×[ρ]× + [ρ]×[φ]× + [φ]×[ρ]×[φ]×)
///    + c₂ ([φ]×²[ρ]× + [ρ]×[φ]×² − 3[φ]×[ρ]×[φ]×)
///    + c₃ ([φ]×[ρ]×[φ]×² + [φ]×²[ρ]×[φ]×)`
///
/// with `c₁ = (θ − sin θ)/θ³`, `c₂ = (θ² + 2cos θ − 2)/(2θ⁴)`,
/// `c₃ = (2θ − 3 sin θ + θ cos θ)/(2θ⁵)`.
fn q_matrix(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let (c1, c2, c3) = if theta < SERIES_THRESHOLD_RAD {
        // Taylor series to θ⁸ (first omitted terms < 1e-16 relative at the threshold):
        // c₂ = Σ_{k≥2} (−1)^k θ^(2k−4)/(2k)!, c₃ = Σ_{k≥2} (−1)^k (k−1) θ^(2k−4)/(2k+1)!.
        let t2 = theta * theta;
        (
            so3::coefficients(theta).c,
            horner(
                t2,
                &[
                    1.0 / 24.0,
                    -1.0 / 720.0,
                    1.0 / 40_320.0,
                    -1.0 / 3_628_800.0,
                    1.0 / 479_001_600.0,
                ],
            ),
            horner(
                t2,
                &[
                    1.0 / 120.0,
                    -1.0 / 2_520.0,
                    1.0 / 120_960.0,
                    -1.0 / 9_979_200.0,
                    1.0 / 1_245_404_160.0,
                ],
            ),
        )
    } else {
        let t2 = theta * theta;
        let (s, c) = theta.sin_cos();
        (
            (theta - s) / (t2 * theta),
            // θ² − 2(1 − cos θ) with 1 − cos θ = 2 sin²(θ/2) to limit cancellation.
            (t2 - 4.0 * (0.5 * theta).sin().powi(2)) / (2.0 * t2 * t2),
            (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t2 * t2 * theta),
        )
    };
    let r = skew(rho);
    let p = skew(phi);
    let pr = p * r;
    let rp = r * p;
    let prp = pr * p;
    let pp = p * p;
    r * 0.5 + (pr + rp + prp) * c1 + (pp * r + rp * p - prp * 3.0) * c2 + (prp * p + p * prp) * c3
}

/// Right Jacobian of SE(3) for `[ρ; φ]` ordering, `Exp(τ + δ) ≈ Exp(τ)·Exp(J_r(τ) δ)`:
/// `J_r(τ) = J_l(−τ) = [[J_r(φ), Q(−ρ, −φ)], [0, J_r(φ)]]`.
pub fn right_jacobian(tau: &Vector6<f64>) -> Matrix6<f64> {
    let (rho, phi) = split(tau);
    let jr = so3::right_jacobian(&phi);
    let q = q_matrix(&-rho, &-phi);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&jr);
    out.fixed_view_mut::<3, 3>(0, 3).copy_from(&q);
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&jr);
    out
}

/// Inverse right Jacobian of SE(3), `Log(Exp(τ)·Exp(δ)) ≈ τ + J_r⁻¹(τ) δ`:
/// `[[J_r⁻¹(φ), −J_r⁻¹(φ) Q(−ρ, −φ) J_r⁻¹(φ)], [0, J_r⁻¹(φ)]]` (block-triangular inverse).
/// Singular at |φ| = 2π, like its SO(3) block.
pub fn right_jacobian_inv(tau: &Vector6<f64>) -> Matrix6<f64> {
    let (rho, phi) = split(tau);
    let jr_inv = so3::right_jacobian_inv(&phi);
    let q = q_matrix(&-rho, &-phi);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&jr_inv);
    out.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(-jr_inv * q * jr_inv));
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&jr_inv);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// A quaternion off unit norm distorts the vectors it rotates; renormalising restores the
    /// rotation it stands for and leaves the translation alone.
    #[test]
    fn renormalized_restores_a_unit_quaternion() {
        let unit = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let drifted = UnitQuaternion::new_unchecked(unit.into_inner() * 0.999);
        let pose = Isometry3::from_parts(Translation3::new(1.0, -2.0, 3.0), drifted);
        let v: Vector3<f64> = Vector3::new(100.0, 0.0, 0.0);
        let rotated: Vector3<f64> = pose.rotation * v;
        // 0.1 % off in norm distorts lengths by ~0.1 %: 10 cm in 100 m.
        assert!((rotated.norm() - 100.0).abs() > 0.05, "{}", rotated.norm());
        let fixed = renormalized(&pose);
        assert!((fixed.rotation.coords.norm() - 1.0).abs() < 1e-15);
        assert!(((fixed.rotation * v) - unit * v).norm() < 1e-12);
        assert_eq!(fixed.translation, pose.translation);
    }

    #[test]
    fn exp_of_pure_translation_and_pure_rotation() {
        let tau = Vector6::new(1.0, -2.0, 3.0, 0.0, 0.0, 0.0);
        let x = exp(&tau);
        assert_eq!(x.translation.vector, Vector3::new(1.0, -2.0, 3.0));
        assert_eq!(x.rotation, UnitQuaternion::identity());
        let tau = Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.5);
        let x = exp(&tau);
        assert!(x.translation.vector.norm() == 0.0);
        assert!((x.rotation.angle() - 0.5).abs() < 1e-15);
    }

    #[test]
    fn exp_is_screw_motion() {
        // A twist with ρ ∥ φ is a screw: translation along the axis equals ρ exactly.
        let axis = Vector3::new(1.0, 2.0, -2.0) / 3.0;
        let tau = Vector6::new(
            axis.x * 4.0,
            axis.y * 4.0,
            axis.z * 4.0,
            axis.x,
            axis.y,
            axis.z,
        );
        let x = exp(&tau);
        assert!((x.translation.vector - axis * 4.0).norm() < 1e-14);
        // One-parameter subgroup: Exp(τ/n)ⁿ = Exp(τ) exactly, so only rounding (a few ε per
        // composition, 8 compositions, |t| ≈ 2) separates the two: 1e-14.
        let tau = Vector6::new(0.3, -1.0, 2.0, 0.4, -0.7, 1.1);
        let small = exp(&(tau / 8.0));
        let mut acc = Isometry3::identity();
        for _ in 0..8 {
            acc *= small;
        }
        let big = exp(&tau);
        assert!((acc.translation.vector - big.translation.vector).norm() < 1e-14);
        assert!(acc.rotation.angle_to(&big.rotation) < 1e-14);
    }

    #[test]
    fn q_series_matches_closed_form_at_threshold() {
        // The closed form of c₃ loses ≈ log10(60/θ⁴) digits at θ = 0.2 (≈ 1e-12 relative);
        // its contribution is scaled by θ³|ρ|, so 1e-13 relative on Q is the bound.
        let rho = Vector3::new(0.8, -1.5, 2.0);
        let dir = Vector3::new(0.2, 0.5, -0.84).normalize();
        let below = q_matrix(&rho, &(dir * SERIES_THRESHOLD_RAD * (1.0 - 1e-15)));
        let above = q_matrix(&rho, &(dir * SERIES_THRESHOLD_RAD));
        assert!(
            (below - above).norm() < 1e-13 * above.norm(),
            "{below} {above}"
        );
    }
}
