//! SO(3) with right perturbations (paper, "Mathematical Notation"; Sola et al., "A micro Lie
//! theory"): Exp, Log, ⊕, ⊖, right Jacobian and its inverse, skew; ZYX Euler angles.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// Skew-symmetric matrix `[v]×` such that `[v]× w = v × w`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    todo!("{v:?}")
}

/// Exponential map: rotation vector (rad) → unit quaternion.
pub fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    todo!("{phi:?}")
}

/// Logarithmic map: unit quaternion → rotation vector with norm in [0, π].
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    todo!("{q:?}")
}

/// `q ⊕ τ = q ∘ Exp(τ)`.
pub fn plus(q: &UnitQuaternion<f64>, tau: &Vector3<f64>) -> UnitQuaternion<f64> {
    todo!("{q:?} {tau:?}")
}

/// `y ⊖ x = Log(x⁻¹ ∘ y)`.
pub fn minus(y: &UnitQuaternion<f64>, x: &UnitQuaternion<f64>) -> Vector3<f64> {
    todo!("{y:?} {x:?}")
}

/// Right Jacobian `J_r(φ)`.
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    todo!("{phi:?}")
}

/// Inverse right Jacobian `J_r⁻¹(φ)`.
pub fn right_jacobian_inv(phi: &Vector3<f64>) -> Matrix3<f64> {
    todo!("{phi:?}")
}

/// ZYX Euler angles `[yaw ψ, pitch θ, bank ξ]` (rad) of `q_nb`.
pub fn euler_zyx(q_nb: &UnitQuaternion<f64>) -> Vector3<f64> {
    todo!("{q_nb:?}")
}

/// `q_nb` from ZYX Euler angles yaw ψ, pitch θ, bank ξ (rad).
pub fn from_euler_zyx(yaw_rad: f64, pitch_rad: f64, bank_rad: f64) -> UnitQuaternion<f64> {
    todo!("{yaw_rad} {pitch_rad} {bank_rad}")
}
