//! "True" gravity and magnetic fields (author_impl §3.5–3.6): the navigation models plus a
//! constant per-run error.

use ianav::env::magnetic::{MagneticError, MagneticModel};
use ianav::math::wgs84::Geodetic;
use nalgebra::{UnitQuaternion, Vector3};

use crate::rng::Stream;

/// True gravity: normal gravity rotated by a small deflection of the vertical and scaled by
/// a magnitude anomaly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueGravity {
    /// Deflection of the vertical.
    pub deflection: UnitQuaternion<f64>,
    /// Magnitude anomaly Δg, m/s².
    pub anomaly_mps2: f64,
}

impl TrueGravity {
    /// Draw the per-run deflection (σ 0.0028°) and anomaly (σ 1e-4 m/s²).
    pub fn draw(rng: &mut Stream) -> Self {
        todo!("{rng:?}")
    }

    /// Gravity vector in NED at `pos`, m/s².
    pub fn gravity_ned_mps2(&self, pos: &Geodetic) -> Vector3<f64> {
        todo!("{pos:?}")
    }
}

/// True magnetic field: WMM plus a constant per-run error N(0, diag[138, 89, 165] nT).
#[derive(Debug, Clone)]
pub struct TrueMagneticField {
    /// The model the navigation also uses.
    pub model: MagneticModel,
    /// Constant error added to the model (true − model), NED, nT.
    pub error_ned_nt: Vector3<f64>,
}

impl TrueMagneticField {
    /// Draw the per-run model error.
    pub fn draw(model: MagneticModel, rng: &mut Stream) -> Self {
        todo!("{model:?} {rng:?}")
    }

    /// True field at `pos` in NED, nT.
    pub fn field_ned_nt(&self, pos: &Geodetic) -> Result<Vector3<f64>, MagneticError> {
        todo!("{pos:?}")
    }
}
