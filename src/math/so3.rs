//! SO(3) with right perturbations (paper, "Mathematical Notation"; Sola et al., "A micro Lie
//! theory", 2018, SO(3) appendix): Exp, Log, ⊕, ⊖, right Jacobian and its inverse,
//! skew; ZYX Euler angles (yaw ψ, pitch θ, bank ξ) of `q_nb`.
//!
//! The Jacobian coefficients are ratios that cancel catastrophically near θ = 0, so below
//! `SERIES_THRESHOLD_RAD` (0.2 rad) they are evaluated by their Taylor series (`coefficients`).

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// Below this rotation angle (rad) the Jacobian coefficients use their Taylor series (five
/// terms, up to θ⁸). At 0.2 rad the first omitted term is < 5e-16 relative, while the closed
/// forms, used above, lose at most ~2e-11 relative to cancellation in a term that is itself
/// multiplied by θ³ (≈ 1e-15 absolute). See the `series_matches_closed_form` test.
pub(crate) const SERIES_THRESHOLD_RAD: f64 = 0.2;
/// Below this angle (rad) Exp/Log use the two-term series of sin(θ/2)/θ and atan(n/w)/n; the
/// first omitted term is θ⁴/3840 ≈ 3e-20 relative at 1e-4 rad.
const EXP_LOG_SERIES_RAD: f64 = 1e-4;
/// `cos θ` below which ZYX Euler angles are treated as gimbal-locked: the matrix entries that
/// give yaw (≈ cos θ in size) are then pure rounding noise (~ε each), so yaw is taken from the
/// second column with bank = 0 (only ψ ∓ ξ is observable there). Forcing ξ = 0 costs at most
/// cos θ·π ≈ 3e-15 rad of rotation error.
const GIMBAL_LOCK_COS: f64 = 4.0 * f64::EPSILON;

/// Scalar coefficients of the SO(3) Jacobians at angle θ = |φ|:
/// `b = (1 − cos θ)/θ²`, `c = (θ − sin θ)/θ³`, `d = 1/θ² − (1 + cos θ)/(2θ sin θ)`.
///
/// `J_r = I − b[φ]× + c[φ]×²`, `J_r⁻¹ = I + ½[φ]× + d[φ]×²` (left: flip the sign of `[φ]×`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Coefficients {
    /// `(1 − cos θ)/θ²`.
    pub b: f64,
    /// `(θ − sin θ)/θ³`.
    pub c: f64,
    /// `1/θ² − (1 + cos θ)/(2θ sin θ)`; singular at θ = 2π (never reached through `log`).
    pub d: f64,
}

/// Evaluates [`Coefficients`] at angle `theta` (rad, ≥ 0).
pub(crate) fn coefficients(theta: f64) -> Coefficients {
    if theta < SERIES_THRESHOLD_RAD {
        let t2 = theta * theta;
        Coefficients {
            // Σ (−1)^(k+1) θ^(2k−2)/(2k)!
            b: horner(
                t2,
                &[
                    1.0 / 2.0,
                    -1.0 / 24.0,
                    1.0 / 720.0,
                    -1.0 / 40_320.0,
                    1.0 / 3_628_800.0,
                ],
            ),
            // Σ (−1)^(k+1) θ^(2k−2)/(2k+1)!
            c: horner(
                t2,
                &[
                    1.0 / 6.0,
                    -1.0 / 120.0,
                    1.0 / 5_040.0,
                    -1.0 / 362_880.0,
                    1.0 / 39_916_800.0,
                ],
            ),
            // (1 − x cot x)/θ² with x = θ/2 (Bernoulli series of x cot x).
            d: horner(
                t2,
                &[
                    1.0 / 12.0,
                    1.0 / 720.0,
                    1.0 / 30_240.0,
                    1.0 / 1_209_600.0,
                    1.0 / 47_900_160.0,
                ],
            ),
        }
    } else {
        let t2 = theta * theta;
        let half = 0.5 * theta;
        // 1 − cos θ = 2 sin²(θ/2) avoids the cancellation of the naive form.
        let s_half = half.sin();
        Coefficients {
            b: 2.0 * s_half * s_half / t2,
            c: (theta - theta.sin()) / (t2 * theta),
            // (1 + cos θ)/(2θ sin θ) = cot(θ/2)/(2θ).
            d: (1.0 - half / half.tan()) / t2,
        }
    }
}

/// Evaluates `Σ coeffs[i]·x^i` by Horner's rule.
#[inline]
pub(crate) fn horner(x: f64, coeffs: &[f64]) -> f64 {
    coeffs.iter().rev().fold(0.0, |acc, &k| acc * x + k)
}

/// Skew-symmetric matrix `[v]×` such that `[v]× w = v × w`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Exponential map: rotation vector (rad) → unit quaternion `(cos θ/2, sin(θ/2) φ/θ)`.
pub fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (w, k) = if theta < EXP_LOG_SERIES_RAD {
        // cos(θ/2) ≈ 1 − θ²/8 + θ⁴/384; sin(θ/2)/θ ≈ 1/2 − θ²/48 (next terms < 1e-18).
        (1.0 - theta2 / 8.0, 0.5 - theta2 / 48.0)
    } else {
        let (s, c) = (0.5 * theta).sin_cos();
        (c, s / theta)
    };
    UnitQuaternion::new_unchecked(Quaternion::new(w, k * phi.x, k * phi.y, k * phi.z))
}

/// Logarithmic map: unit quaternion → rotation vector with norm in [0, π].
///
/// The sign of `q` is chosen with `w ≥ 0` so that the angle `2·atan2(|v|, w)` is at most π.
/// The formula is invariant to the scale of `q`, so slightly denormalised inputs are fine.
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let n = v.norm();
    let k = if n < EXP_LOG_SERIES_RAD * w {
        // 2·atan(n/w)/n = (2/w)(1 − n²/(3w²) + …); next term n⁴/(5w⁴) < 1e-16 relative here.
        let r2 = n * n / (w * w);
        2.0 / w * (1.0 - r2 / 3.0)
    } else {
        2.0 * n.atan2(w) / n
    };
    v * k
}

/// `q ⊕ τ = q ∘ Exp(τ)`.
pub fn plus(q: &UnitQuaternion<f64>, tau: &Vector3<f64>) -> UnitQuaternion<f64> {
    q * exp(tau)
}

/// `y ⊖ x = Log(x⁻¹ ∘ y)`.
pub fn minus(y: &UnitQuaternion<f64>, x: &UnitQuaternion<f64>) -> Vector3<f64> {
    log(&(x.inverse() * y))
}

/// Right Jacobian `J_r(φ) = I − b[φ]× + c[φ]×²`, with `Exp(φ + δ) ≈ Exp(φ)·Exp(J_r(φ) δ)`.
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let k = coefficients(phi.norm());
    let s = skew(phi);
    Matrix3::identity() - s * k.b + s * s * k.c
}

/// Inverse right Jacobian `J_r⁻¹(φ) = I + ½[φ]× + d[φ]×²`, with
/// `Log(Exp(φ)·Exp(δ)) ≈ φ + J_r⁻¹(φ) δ`. Singular at |φ| = 2π (outside the range of `log`).
pub fn right_jacobian_inv(phi: &Vector3<f64>) -> Matrix3<f64> {
    let k = coefficients(phi.norm());
    let s = skew(phi);
    Matrix3::identity() + s * 0.5 + s * s * k.d
}

/// Left Jacobian `J_l(φ) = J_r(−φ) = I + b[φ]× + c[φ]×²` (the `V` matrix of SE(3) Exp).
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let k = coefficients(phi.norm());
    let s = skew(phi);
    Matrix3::identity() + s * k.b + s * s * k.c
}

/// Inverse left Jacobian `J_l⁻¹(φ) = J_r⁻¹(−φ) = I − ½[φ]× + d[φ]×²`.
pub fn left_jacobian_inv(phi: &Vector3<f64>) -> Matrix3<f64> {
    let k = coefficients(phi.norm());
    let s = skew(phi);
    Matrix3::identity() - s * 0.5 + s * s * k.d
}

/// ZYX Euler angles `[yaw ψ, pitch θ, bank ξ]` (rad) of `q_nb`, with `q_nb = R_z(ψ) R_y(θ)
/// R_x(ξ)`; ψ, ξ ∈ [−π, π], θ ∈ [−π/2, π/2].
///
/// Pitch uses `atan2(sin θ, cos θ)` (accurate at ±90°). Bank is extracted from the residual
/// rotation `R_y(θ)ᵀ R_z(ψ)ᵀ R_nb`, so the angles always reproduce `q_nb` even when ψ and ξ are
/// ill-conditioned; at gimbal lock (cos θ < 4ε) yaw comes from the second matrix column,
/// which gives ξ = 0. Never NaN for finite input.
pub fn euler_zyx(q_nb: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, x, y, z) = (q_nb.w, q_nb.i, q_nb.j, q_nb.k);
    // Needed rotation-matrix entries (unit quaternion).
    let r00 = 1.0 - 2.0 * (y * y + z * z);
    let r10 = 2.0 * (x * y + w * z);
    let r20 = 2.0 * (x * z - w * y);
    // Entries are ≤ 1 in magnitude: no overflow, so a plain square root (not hypot) is safe.
    let cos_pitch = (r00 * r00 + r10 * r10).sqrt();
    let pitch = (-r20).atan2(cos_pitch);
    let yaw = if cos_pitch > GIMBAL_LOCK_COS {
        r10.atan2(r00)
    } else {
        // With ξ = 0 at θ = ±π/2: R01 = −sin ψ, R11 = cos ψ.
        let r01 = 2.0 * (x * y - w * z);
        let r11 = 1.0 - 2.0 * (x * x + z * z);
        (-r01).atan2(r11)
    };
    // Residual r = q_y(θ)⁻¹ q_z(ψ)⁻¹ q = q_x(ξ) (up to sign); only its w and i parts are needed.
    let (sy, cy) = (0.5 * yaw).sin_cos();
    let (sp, cp) = (0.5 * pitch).sin_cos();
    // a = q_z(ψ)⁻¹ q = (cy − sy k)(w + x i + y j + z k)
    let aw = cy * w + sy * z;
    let ax = cy * x + sy * y;
    let ay = cy * y - sy * x;
    let az = cy * z - sy * w;
    // r = q_y(θ)⁻¹ a = (cp − sp j) a
    let rw = cp * aw + sp * ay;
    let rx = cp * ax - sp * az;
    let (rw, rx) = if rw < 0.0 { (-rw, -rx) } else { (rw, rx) };
    let bank = 2.0 * rx.atan2(rw);
    Vector3::new(yaw, pitch, bank)
}

/// `q_nb` from ZYX Euler angles yaw ψ, pitch θ, bank ξ (rad): `q_z(ψ) ∘ q_y(θ) ∘ q_x(ξ)`.
pub fn from_euler_zyx(yaw_rad: f64, pitch_rad: f64, bank_rad: f64) -> UnitQuaternion<f64> {
    let (sy, cy) = (0.5 * yaw_rad).sin_cos();
    let (sp, cp) = (0.5 * pitch_rad).sin_cos();
    let (sb, cb) = (0.5 * bank_rad).sin_cos();
    UnitQuaternion::new_unchecked(Quaternion::new(
        cy * cp * cb + sy * sp * sb,
        cy * cp * sb - sy * sp * cb,
        cy * sp * cb + sy * cp * sb,
        sy * cp * cb - cy * sp * sb,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_6, PI};

    #[test]
    fn skew_is_cross_product() {
        let a = Vector3::new(0.3, -1.2, 2.5);
        let b = Vector3::new(-0.7, 0.4, 1.1);
        assert!((skew(&a) * b - a.cross(&b)).norm() < 1e-15);
    }

    #[test]
    fn exp_matches_nalgebra_and_log_inverts() {
        for phi in [
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(2.0, 1.0, -0.5),
            Vector3::new(0.0, 0.0, PI),
            Vector3::new(1e-9, 0.0, -2e-9),
        ] {
            let q = exp(&phi);
            let reference = UnitQuaternion::from_scaled_axis(phi);
            assert!(q.angle_to(&reference) < 1e-15);
            assert!((log(&q) - phi).norm() <= 1e-15 * (1.0 + phi.norm()));
        }
        assert_eq!(log(&UnitQuaternion::identity()), Vector3::zeros());
        assert_eq!(exp(&Vector3::zeros()), UnitQuaternion::identity());
    }

    #[test]
    fn log_takes_short_way_for_negative_w() {
        // A quaternion with w < 0 representing a 0.5 rad rotation about x.
        let q = UnitQuaternion::new_unchecked(-exp(&Vector3::new(0.5, 0.0, 0.0)).into_inner());
        assert!((log(&q) - Vector3::new(0.5, 0.0, 0.0)).norm() < 1e-15);
        // 3π/2 about z via w < 0 ⇒ −π/2 about z.
        let q = UnitQuaternion::new_unchecked(Quaternion::new(
            (0.75 * PI).cos(),
            0.0,
            0.0,
            (0.75 * PI).sin(),
        ));
        assert!((log(&q) - Vector3::new(0.0, 0.0, -FRAC_PI_2)).norm() < 1e-15);
    }

    #[test]
    fn series_matches_closed_form_at_threshold() {
        // Both branches evaluated at the switch point must agree: the closed forms are accurate
        // to ~2e-11 relative there (c's numerator θ − sin θ ≈ θ³/6 loses log10(6/θ²) ≈ 2.2
        // digits, d's ≈ 1.1 digits), so 1e-10 relative bounds the jump.
        let t = SERIES_THRESHOLD_RAD;
        let series = coefficients(t * (1.0 - 1e-15));
        let closed = coefficients(t);
        let (s, co) = t.sin_cos();
        for (a, b) in [
            (series.b, closed.b),
            (series.c, closed.c),
            (series.d, closed.d),
            (series.b, (1.0 - co) / (t * t)),
            (series.d, 1.0 / (t * t) - (1.0 + co) / (2.0 * t * s)),
        ] {
            assert!((a - b).abs() < 1e-10 * b.abs(), "{a} {b}");
        }
    }

    #[test]
    fn euler_known_values_and_order() {
        let (psi, theta, xi) = (0.4, -0.3, 1.2);
        let q = from_euler_zyx(psi, theta, xi);
        let reference = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), psi)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), theta)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), xi);
        assert!(q.angle_to(&reference) < 1e-15);
        let e = euler_zyx(&q);
        assert!((e - Vector3::new(psi, theta, xi)).norm() < 1e-14);
        // Yaw 90°: body x (forward) points east.
        let q = from_euler_zyx(FRAC_PI_2, 0.0, 0.0);
        assert!((q * Vector3::x() - Vector3::y()).norm() < 1e-15);
        // Pitch up 30°: body x points north and up (negative down).
        let q = from_euler_zyx(0.0, FRAC_PI_6, 0.0);
        assert!((q * Vector3::x()).z < 0.0);
    }

    #[test]
    fn euler_gimbal_lock_is_finite_and_consistent() {
        for pitch in [FRAC_PI_2, -FRAC_PI_2, FRAC_PI_2 - 1e-13, -FRAC_PI_2 + 1e-9] {
            for (yaw, bank) in [(0.3, -0.8), (-2.0, 2.9), (0.0, 0.0), (PI, PI)] {
                let q = from_euler_zyx(yaw, pitch, bank);
                let e = euler_zyx(&q);
                assert!(e.iter().all(|a| a.is_finite()), "{e:?}");
                // The angles must reproduce the rotation (ψ, ξ individually are not unique).
                // 1e-15 rad of rounding per angle, a few angles: 1e-14.
                let back = from_euler_zyx(e.x, e.y, e.z);
                assert!(back.angle_to(&q) < 1e-14, "{pitch} {yaw} {bank} {e:?}");
                assert!((e.y - pitch).abs() < 1e-7, "{e:?}");
            }
        }
        let e = euler_zyx(&from_euler_zyx(0.7, FRAC_PI_2, 0.0));
        assert!(
            (e - Vector3::new(0.7, FRAC_PI_2, 0.0)).norm() < 1e-15,
            "{e:?}"
        );
    }

    #[test]
    fn euler_nan_does_not_panic() {
        let q = UnitQuaternion::new_unchecked(Quaternion::new(f64::NAN, 0.0, 0.0, 0.0));
        let _ = euler_zyx(&q);
        let _ = log(&q);
        let _ = exp(&Vector3::new(f64::NAN, 0.0, 0.0));
        let _ = right_jacobian(&Vector3::new(f64::NAN, 0.0, 0.0));
    }
}
