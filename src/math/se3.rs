//! SE(3) poses (`nalgebra::Isometry3`) with right perturbations. Tangent vectors are ordered
//! `[ρ (translation); φ (rotation)]`, matching the paper's twist `[v; ω]`.

use nalgebra::{Isometry3, Matrix6, Vector6};

/// Exponential map of a twist `[ρ; φ]`.
pub fn exp(tau: &Vector6<f64>) -> Isometry3<f64> {
    todo!("{tau:?}")
}

/// Logarithmic map of a pose, returning `[ρ; φ]`.
pub fn log(pose: &Isometry3<f64>) -> Vector6<f64> {
    todo!("{pose:?}")
}

/// `X ⊕ τ = X ∘ Exp(τ)`.
pub fn plus(x: &Isometry3<f64>, tau: &Vector6<f64>) -> Isometry3<f64> {
    todo!("{x:?} {tau:?}")
}

/// `Y ⊖ X = Log(X⁻¹ ∘ Y)`.
pub fn minus(y: &Isometry3<f64>, x: &Isometry3<f64>) -> Vector6<f64> {
    todo!("{y:?} {x:?}")
}

/// Right Jacobian of SE(3) for `[ρ; φ]` ordering.
pub fn right_jacobian(tau: &Vector6<f64>) -> Matrix6<f64> {
    todo!("{tau:?}")
}

/// Inverse right Jacobian of SE(3).
pub fn right_jacobian_inv(tau: &Vector6<f64>) -> Matrix6<f64> {
    todo!("{tau:?}")
}
