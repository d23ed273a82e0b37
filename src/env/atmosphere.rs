//! ISA atmosphere with temperature offset ΔT and pressure offset Δp (the non-standard
//! atmosphere of Gallo's simulation paper): pressure altitude ↔ static pressure, temperature,
//! density, geopotential ↔ geometric altitude, geometric altitude from pressure altitude.

use serde::{Deserialize, Serialize};

/// Specific gas constant of air, J/(kg·K).
pub const R_JPKGK: f64 = 287.052_87;
/// Ratio of specific heats.
pub const KAPPA: f64 = 1.4;
/// Troposphere temperature gradient, K/m.
pub const BETA_T_KPM: f64 = -6.5e-3;
/// Standard mean-sea-level pressure, Pa.
pub const P0_PA: f64 = 101_325.0;
/// Standard mean-sea-level temperature, K.
pub const T0_K: f64 = 288.15;
/// Standard gravity, m/s².
pub const G0_MPS2: f64 = 9.806_65;
/// Earth radius of the spherical geopotential approximation, m.
pub const R_GEOPOTENTIAL_M: f64 = 6_356_766.0;

/// Offsets of the actual atmosphere from ISA.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct AtmosphereOffsets {
    /// Temperature offset ΔT, K.
    pub delta_t_k: f64,
    /// Pressure offset at mean sea level Δp, Pa.
    pub delta_p_pa: f64,
}

/// Static pressure at pressure altitude `hp_m`, Pa.
pub fn pressure_pa(hp_m: f64) -> f64 {
    todo!("{hp_m}")
}

/// Pressure altitude for static pressure `p_pa`, m.
pub fn pressure_altitude_m(p_pa: f64) -> f64 {
    todo!("{p_pa}")
}

/// Outside air temperature at pressure altitude `hp_m` with offset `delta_t_k`, K.
pub fn temperature_k(hp_m: f64, delta_t_k: f64) -> f64 {
    todo!("{hp_m} {delta_t_k}")
}

/// Temperature offset ΔT from a measured temperature at pressure altitude `hp_m`, K.
pub fn delta_t_k(hp_m: f64, temp_k: f64) -> f64 {
    todo!("{hp_m} {temp_k}")
}

/// Air density from pressure and temperature, kg/m³.
pub fn density_kgpm3(p_pa: f64, temp_k: f64) -> f64 {
    todo!("{p_pa} {temp_k}")
}

/// Speed of sound, m/s.
pub fn speed_of_sound_mps(temp_k: f64) -> f64 {
    todo!("{temp_k}")
}

/// Geopotential altitude H from geometric altitude h, m.
pub fn geopotential_from_geometric_m(h_m: f64) -> f64 {
    todo!("{h_m}")
}

/// Geometric altitude h from geopotential altitude H, m.
pub fn geometric_from_geopotential_m(geopotential_m: f64) -> f64 {
    todo!("{geopotential_m}")
}

/// Geopotential altitude H for pressure altitude `hp_m` under `offsets`, m.
pub fn geopotential_from_pressure_altitude_m(hp_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    todo!("{hp_m} {offsets:?}")
}

/// Pressure altitude for geopotential altitude H under `offsets`, m.
pub fn pressure_altitude_from_geopotential_m(
    geopotential_m: f64,
    offsets: &AtmosphereOffsets,
) -> f64 {
    todo!("{geopotential_m} {offsets:?}")
}

/// Geometric altitude h for pressure altitude `hp_m` under `offsets`, m.
pub fn geometric_from_pressure_altitude_m(hp_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    todo!("{hp_m} {offsets:?}")
}

/// Pressure altitude for geometric altitude `h_m` under `offsets`, m.
pub fn pressure_altitude_from_geometric_m(h_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    todo!("{h_m} {offsets:?}")
}

/// Pressure offset Δp that makes pressure altitude `hp_m` correspond to geopotential altitude
/// `geopotential_m` at temperature offset `delta_t_k`, Pa (used by the INS while GNSS is
/// available).
pub fn delta_p_pa(hp_m: f64, geopotential_m: f64, delta_t_k: f64) -> f64 {
    todo!("{hp_m} {geopotential_m} {delta_t_k}")
}
