//! WGS84 ellipsoid: geodetic ↔ ECEF, NED frame orientation, radii of curvature, Somigliana
//! normal gravity with height, Earth rotation, local NED differences.

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Semi-major axis, m.
pub const A_M: f64 = 6_378_137.0;
/// Flattening.
pub const F: f64 = 1.0 / 298.257_223_563;
/// Earth gravitational constant GM, m³/s².
pub const GM_M3PS2: f64 = 3.986_004_418e14;
/// Earth rotation rate, rad/s.
pub const OMEGA_IE_RPS: f64 = 7.292_115e-5;

/// Geodetic position on WGS84.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Geodetic {
    /// Geodetic latitude φ, rad.
    pub lat_rad: f64,
    /// Longitude λ, rad.
    pub lon_rad: f64,
    /// Height above the ellipsoid, m.
    pub h_m: f64,
}

/// Geodetic → ECEF position, m.
pub fn geodetic_to_ecef(pos: &Geodetic) -> Vector3<f64> {
    todo!("{pos:?}")
}

/// ECEF position (m) → geodetic.
pub fn ecef_to_geodetic(p_e_m: &Vector3<f64>) -> Geodetic {
    todo!("{p_e_m:?}")
}

/// Orientation of NED at (lat, lon) with respect to ECEF: `v_e = q_en * v_n`.
pub fn q_en(lat_rad: f64, lon_rad: f64) -> UnitQuaternion<f64> {
    todo!("{lat_rad} {lon_rad}")
}

/// Meridian radius of curvature M(φ), m.
pub fn radius_meridian_m(lat_rad: f64) -> f64 {
    todo!("{lat_rad}")
}

/// Prime-vertical radius of curvature N(φ), m.
pub fn radius_prime_vertical_m(lat_rad: f64) -> f64 {
    todo!("{lat_rad}")
}

/// Normal gravity magnitude (Somigliana with the second-order height correction), m/s².
/// Includes the centrifugal term; points along NED down.
pub fn normal_gravity_mps2(lat_rad: f64, h_m: f64) -> f64 {
    todo!("{lat_rad} {h_m}")
}

/// Earth rotation rate `w_ie` viewed in NED at latitude φ, rad/s.
pub fn omega_ie_n(lat_rad: f64) -> Vector3<f64> {
    todo!("{lat_rad}")
}

/// Transport rate `w_en` viewed in NED for ground velocity `v_ned_mps`, rad/s.
pub fn omega_en_n(pos: &Geodetic, v_ned_mps: &Vector3<f64>) -> Vector3<f64> {
    todo!("{pos:?} {v_ned_mps:?}")
}

/// Time derivative of the geodetic coordinates `(lat_dot, lon_dot, h_dot)` for a NED ground
/// velocity, in rad/s, rad/s and m/s.
pub fn geodetic_rates(pos: &Geodetic, v_ned_mps: &Vector3<f64>) -> Vector3<f64> {
    todo!("{pos:?} {v_ned_mps:?}")
}

/// Vector from `from` to `to` viewed in the NED frame at `from`, m (exact, through ECEF).
pub fn ned_difference_m(from: &Geodetic, to: &Geodetic) -> Vector3<f64> {
    todo!("{from:?} {to:?}")
}
