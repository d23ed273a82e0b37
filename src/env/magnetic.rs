//! Earth magnetic field from the World Magnetic Model (through the `world_magnetic_model`
//! crate), in NED, nT.

use nalgebra::Vector3;

use crate::math::wgs84::Geodetic;

/// Errors of the magnetic model.
#[derive(Debug, thiserror::Error)]
pub enum MagneticError {
    /// The date or position is outside the model's validity.
    #[error("magnetic model unavailable: {0}")]
    Unavailable(String),
}

/// World Magnetic Model evaluated at a fixed epoch (the field's secular variation over one
/// flight is negligible).
#[derive(Debug, Clone)]
pub struct MagneticModel {
    /// Decimal year of evaluation.
    pub decimal_year: f64,
}

impl MagneticModel {
    /// Model at the given decimal year (must lie within the WMM validity span).
    pub fn new(decimal_year: f64) -> Result<Self, MagneticError> {
        todo!("{decimal_year}")
    }

    /// Field at `pos` in NED, nT.
    pub fn field_ned_nt(&self, pos: &Geodetic) -> Result<Vector3<f64>, MagneticError> {
        todo!("{pos:?}")
    }
}
