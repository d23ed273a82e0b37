//! Shared mathematics: WGS84 geodesy, the SO(3)/SE(3) Lie-group tools of the paper's
//! "Mathematical Notation" (right perturbations, `X ⊕ τ = X ∘ Exp(τ)`), angle wrapping and
//! order statistics.

pub mod angle;
pub mod map_projection;
pub mod se3;
pub mod so3;
pub mod stats;
pub mod wgs84;
