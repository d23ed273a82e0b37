//! WGS84 ellipsoid (docs/REFERENCES.md A3.5, `env/geo`): geodetic ↔ ECEF, NED frame orientation,
//! radii of curvature, Somigliana normal gravity with the second-order height correction, Earth
//! rotation and transport rates, geodetic rates and exact local NED differences.
//!
//! ECEF → geodetic uses Vermeille's closed form (J. Geodesy 76, 2002), exact up to rounding
//! (≪ 1 µm) everywhere more than ~43 km from the Earth's centre; see [`ecef_to_geodetic`].

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Semi-major axis, m.
pub const A_M: f64 = 6_378_137.0;
/// Flattening.
pub const F: f64 = 1.0 / 298.257_223_563;
/// Earth gravitational constant GM, m³/s².
pub const GM_M3PS2: f64 = 3.986_004_418e14;
/// Earth rotation rate, rad/s.
pub const OMEGA_IE_RPS: f64 = 7.292_115e-5;
/// Semi-minor axis `b = a (1 − f)`, m.
pub const B_M: f64 = A_M * (1.0 - F);
/// First eccentricity squared `e² = f (2 − f)`.
pub const E2: f64 = F * (2.0 - F);
/// Normal gravity at the equator on the ellipsoid `g_e`, m/s² (docs/REFERENCES.md A3.5).
pub const GE_MPS2: f64 = 9.780_325_335_9;
/// Normal gravity at the poles on the ellipsoid `g_p`, m/s² (docs/REFERENCES.md A3.5).
pub const GP_MPS2: f64 = 9.832_184_937_8;

/// Somigliana constant `k = b g_p / (a g_e) − 1`.
const SOMIGLIANA_K: f64 = B_M * GP_MPS2 / (A_M * GE_MPS2) - 1.0;
/// Geodetic parameter `m = ω² a² b / GM` of the height correction.
const GRAVITY_M: f64 = OMEGA_IE_RPS * OMEGA_IE_RPS * A_M * A_M * B_M / GM_M3PS2;
/// `e⁴`, used by the closed-form ECEF → geodetic conversion.
const E4: f64 = E2 * E2;
/// Fixed-point iterations of the fallback ECEF → geodetic solver (only used within ~43 km of
/// the Earth's centre, where the geodetic coordinates are not unique anyway). Bounded so the
/// function always terminates.
const FALLBACK_ITERATIONS: usize = 16;

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
    let (s_lat, c_lat) = pos.lat_rad.sin_cos();
    let (s_lon, c_lon) = pos.lon_rad.sin_cos();
    let n = A_M / (1.0 - E2 * s_lat * s_lat).sqrt();
    let r_xy = (n + pos.h_m) * c_lat;
    Vector3::new(
        r_xy * c_lon,
        r_xy * s_lon,
        (n * (1.0 - E2) + pos.h_m) * s_lat,
    )
}

/// ECEF position (m) → geodetic.
///
/// Vermeille's closed form (2002), valid and exact (up to f64 rounding: ≈1e-9 m in height,
/// ≈1e-16 rad in latitude) for every point outside the ellipse `(ρ² + (1−e²) z²)/a² = e⁴`, i.e.
/// more than ~43 km from the Earth's centre, poles included. Inside that region (never reached
/// by a vehicle) a bounded fixed-point iteration returns one of the non-unique solutions. NaN in
/// gives NaN out; the function never panics and never loops unboundedly.
pub fn ecef_to_geodetic(p_e_m: &Vector3<f64>) -> Geodetic {
    let (x, y, z) = (p_e_m.x, p_e_m.y, p_e_m.z);
    let lon_rad = y.atan2(x);
    let rho2 = x * x + y * y;
    let rho = rho2.sqrt();
    let p = rho2 / (A_M * A_M);
    let q = (1.0 - E2) * z * z / (A_M * A_M);
    let r = (p + q - E4) / 6.0;
    if r > 0.0 {
        let s = E4 * p * q / (4.0 * r * r * r);
        let t = (1.0 + s + (s * (2.0 + s)).sqrt()).cbrt();
        let u = r * (1.0 + t + 1.0 / t);
        let v = (u * u + E4 * q).sqrt();
        let w = E2 * (u + v - q) / (2.0 * v);
        let k = (u + v + w * w).sqrt() - w;
        let d = k * rho / (k + E2);
        let dz = (d * d + z * z).sqrt();
        // Half-angle form: well conditioned at the equator and at the poles.
        let lat_rad = 2.0 * z.atan2(d + dz);
        let h_m = (k + E2 - 1.0) / k * dz;
        Geodetic {
            lat_rad,
            lon_rad,
            h_m,
        }
    } else {
        // Deep inside the Earth (or NaN): φ ← atan2(z + e² N(φ) sin φ, ρ), bounded count.
        let mut lat_rad = z.atan2(rho * (1.0 - E2));
        for _ in 0..FALLBACK_ITERATIONS {
            let s_lat = lat_rad.sin();
            let n = A_M / (1.0 - E2 * s_lat * s_lat).sqrt();
            lat_rad = (z + E2 * n * s_lat).atan2(rho);
        }
        let (s_lat, c_lat) = lat_rad.sin_cos();
        // Valid at any latitude: projection on the ellipsoid normal minus the normal's foot.
        let h_m = rho * c_lat + z * s_lat - A_M * (1.0 - E2 * s_lat * s_lat).sqrt();
        Geodetic {
            lat_rad,
            lon_rad,
            h_m,
        }
    }
}

/// Orientation of NED at (lat, lon) with respect to ECEF: `v_e = q_en * v_n`.
///
/// `q_en = R_z(λ) · R_y(−φ − π/2)`, multiplied out in closed form.
pub fn q_en(lat_rad: f64, lon_rad: f64) -> UnitQuaternion<f64> {
    let (s1, c1) = (0.5 * lon_rad).sin_cos();
    let (s2, c2) = (0.5 * (-lat_rad - std::f64::consts::FRAC_PI_2)).sin_cos();
    // (c1 + s1 k)(c2 + s2 j) = c1c2 − s1s2 i + c1s2 j + s1c2 k; unit norm by construction.
    UnitQuaternion::new_unchecked(Quaternion::new(c1 * c2, -s1 * s2, c1 * s2, s1 * c2))
}

/// Meridian and prime-vertical radii `(M, N)` from `sin φ` (one square root, no trig), m.
#[inline]
fn radii_from_sin_m(s_lat: f64) -> (f64, f64) {
    let w2 = 1.0 - E2 * s_lat * s_lat;
    let n = A_M / w2.sqrt();
    (n * (1.0 - E2) / w2, n)
}

/// Meridian radius of curvature M(φ) = a(1−e²)/(1−e² sin²φ)^{3/2}, m.
pub fn radius_meridian_m(lat_rad: f64) -> f64 {
    radii_from_sin_m(lat_rad.sin()).0
}

/// Prime-vertical radius of curvature N(φ) = a/√(1−e² sin²φ), m.
pub fn radius_prime_vertical_m(lat_rad: f64) -> f64 {
    radii_from_sin_m(lat_rad.sin()).1
}

/// Normal gravity magnitude (Somigliana with the second-order height correction), m/s².
/// Includes the centrifugal term; points along NED down.
///
/// `g = g_e (1 + k sin²φ)/√(1 − e² sin²φ) · [1 − (2/a)(1 + f + m − 2f sin²φ) h + 3h²/a²]`
/// (docs/REFERENCES.md A3.5).
pub fn normal_gravity_mps2(lat_rad: f64, h_m: f64) -> f64 {
    let s2 = lat_rad.sin().powi(2);
    let g0 = GE_MPS2 * (1.0 + SOMIGLIANA_K * s2) / (1.0 - E2 * s2).sqrt();
    let hc = 1.0 - 2.0 / A_M * (1.0 + F + GRAVITY_M - 2.0 * F * s2) * h_m
        + 3.0 * h_m * h_m / (A_M * A_M);
    g0 * hc
}

/// Normal gravity vector in NED, `(0, 0, g(φ, h))`, m/s².
pub fn gravity_ned_mps2(pos: &Geodetic) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, normal_gravity_mps2(pos.lat_rad, pos.h_m))
}

/// Earth rotation rate `w_ie` viewed in NED at latitude φ, rad/s: `ω (cos φ, 0, −sin φ)`.
pub fn omega_ie_n(lat_rad: f64) -> Vector3<f64> {
    let (s, c) = lat_rad.sin_cos();
    Vector3::new(OMEGA_IE_RPS * c, 0.0, -OMEGA_IE_RPS * s)
}

/// Transport rate `w_en` viewed in NED for ground velocity `v_ned_mps`, rad/s:
/// `(v_E/(N+h), −v_N/(M+h), −v_E tan φ/(N+h))`.
///
/// The down component is singular at the poles (tan φ); at exactly ±π/2 in f64 it is large but
/// finite (cos(π/2) ≈ 6e-17 in f64), as for any NED mechanisation.
pub fn omega_en_n(pos: &Geodetic, v_ned_mps: &Vector3<f64>) -> Vector3<f64> {
    let (s_lat, c_lat) = pos.lat_rad.sin_cos();
    let (m, n) = radii_from_sin_m(s_lat);
    let (m_h, n_h) = (m + pos.h_m, n + pos.h_m);
    Vector3::new(
        v_ned_mps.y / n_h,
        -v_ned_mps.x / m_h,
        -v_ned_mps.y * s_lat / (c_lat * n_h),
    )
}

/// Time derivative of the geodetic coordinates `(lat_dot, lon_dot, h_dot)` for a NED ground
/// velocity, in rad/s, rad/s and m/s: `(v_N/(M+h), v_E/((N+h) cos φ), −v_D)`.
///
/// `lon_dot` is singular at the poles (division by cos φ), like the coordinates themselves.
pub fn geodetic_rates(pos: &Geodetic, v_ned_mps: &Vector3<f64>) -> Vector3<f64> {
    let (s_lat, c_lat) = pos.lat_rad.sin_cos();
    let (m, n) = radii_from_sin_m(s_lat);
    Vector3::new(
        v_ned_mps.x / (m + pos.h_m),
        v_ned_mps.y / ((n + pos.h_m) * c_lat),
        -v_ned_mps.z,
    )
}

/// Vector from `from` to `to` viewed in the NED frame at `from`, m (exact, through ECEF).
pub fn ned_difference_m(from: &Geodetic, to: &Geodetic) -> Vector3<f64> {
    let d_e = geodetic_to_ecef(to) - geodetic_to_ecef(from);
    q_en(from.lat_rad, from.lon_rad).inverse_transform_vector(&d_e)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    /// Round-trip accuracy: geodetic → ECEF rounds each coordinate to ~|p|·ε ≈ 7e6·1.1e-16
    /// ≈ 1e-9 m; the inverse adds a few more ulps. 1e-7 m (0.1 µm) leaves a 100× margin yet is
    /// far below the sub-millimetre requirement. Angles: 1e-7 m / 6.4e6 m ≈ 1.6e-14 rad.
    const ROUND_TRIP_M: f64 = 1e-7;
    const ROUND_TRIP_RAD: f64 = 2e-14;

    #[test]
    fn round_trip_grid_including_poles_and_altitudes() {
        let lats_deg = [
            -90.0,
            -89.999_999,
            -89.0,
            -60.0,
            -45.0,
            -1e-7,
            0.0,
            1e-7,
            10.0,
            44.5,
            80.0,
            89.9,
            90.0,
        ];
        let lons_deg = [-180.0, -179.9, -90.0, -1.0, 0.0, 0.3, 45.0, 135.0, 179.99];
        let hs_m = [
            -10_000.0, -1_000.0, 0.0, 1e-6, 300.0, 10_000.0, 50_000.0, 100_000.0,
        ];
        let mut worst_m: f64 = 0.0;
        for &lat in &lats_deg {
            for &lon in &lons_deg {
                for &h in &hs_m {
                    let g = Geodetic {
                        lat_rad: f64::to_radians(lat),
                        lon_rad: f64::to_radians(lon),
                        h_m: h,
                    };
                    let p = geodetic_to_ecef(&g);
                    let back = ecef_to_geodetic(&p);
                    assert!(
                        (back.lat_rad - g.lat_rad).abs() < ROUND_TRIP_RAD,
                        "{g:?} {back:?}"
                    );
                    assert!((back.h_m - g.h_m).abs() < ROUND_TRIP_M, "{g:?} {back:?}");
                    // Longitude is undefined at the poles; elsewhere compare on the circle.
                    if lat.abs() < 90.0 {
                        let dlon = crate::math::angle::wrap_pi(back.lon_rad - g.lon_rad);
                        assert!(dlon.abs() < ROUND_TRIP_RAD, "{g:?} {back:?}");
                    }
                    // The ECEF point regenerated from the result must coincide as well.
                    let err = (geodetic_to_ecef(&back) - p).norm();
                    worst_m = worst_m.max(err);
                    assert!(err < ROUND_TRIP_M, "{g:?} {back:?} {err}");
                }
            }
        }
        eprintln!("worst ECEF round-trip error {worst_m:e} m");
    }

    #[test]
    fn ecef_to_geodetic_known_points() {
        let eq = ecef_to_geodetic(&Vector3::new(A_M, 0.0, 0.0));
        assert_eq!(eq.lat_rad, 0.0);
        assert_eq!(eq.lon_rad, 0.0);
        assert!(eq.h_m.abs() < 1e-9);
        let np = ecef_to_geodetic(&Vector3::new(0.0, 0.0, B_M + 1000.0));
        assert_eq!(np.lat_rad, FRAC_PI_2);
        assert!((np.h_m - 1000.0).abs() < 1e-8);
        let sp = ecef_to_geodetic(&Vector3::new(0.0, 0.0, -B_M + 5.0));
        assert_eq!(sp.lat_rad, -FRAC_PI_2);
        assert!((sp.h_m + 5.0).abs() < 1e-8);
    }

    #[test]
    fn ecef_to_geodetic_degenerate_inputs_do_not_panic() {
        let nan = ecef_to_geodetic(&Vector3::new(f64::NAN, 1.0, 2.0));
        assert!(nan.lat_rad.is_nan() && nan.h_m.is_nan());
        // Earth's centre and a point inside the evolute region: finite, consistent output.
        for p in [Vector3::zeros(), Vector3::new(10_000.0, 0.0, 5_000.0)] {
            let g = ecef_to_geodetic(&p);
            assert!(g.lat_rad.is_finite() && g.h_m.is_finite(), "{p:?} {g:?}");
            assert!((geodetic_to_ecef(&g) - p).norm() < 1e-6, "{p:?} {g:?}");
        }
        let inf = ecef_to_geodetic(&Vector3::new(f64::INFINITY, 0.0, 0.0));
        assert!(!inf.lat_rad.is_finite() || !inf.h_m.is_finite());
    }

    #[test]
    fn ecef_of_origin_is_semi_major_axis() {
        let p = geodetic_to_ecef(&Geodetic {
            lat_rad: 0.0,
            lon_rad: 0.0,
            h_m: 0.0,
        });
        assert_eq!(p, Vector3::new(A_M, 0.0, 0.0));
    }

    #[test]
    fn normal_gravity_known_values() {
        // Ellipsoid values are definitions of the formula; only rounding (1e-15 rel) differs.
        assert!((normal_gravity_mps2(0.0, 0.0) - 9.780_325_335_9).abs() < 1e-12);
        assert!((normal_gravity_mps2(FRAC_PI_2, 0.0) - 9.832_184_937_8).abs() < 1e-12);
        assert!((normal_gravity_mps2(-FRAC_PI_2, 0.0) - 9.832_184_937_8).abs() < 1e-12);
        // Free-air gradient ≈ −2 g/a ≈ −3.086e-6 s⁻² at the equator: 1 km up loses ≈ 3.08 mGal·1e3.
        let dg = normal_gravity_mps2(0.0, 1000.0) - normal_gravity_mps2(0.0, 0.0);
        let expect = -2.0 * GE_MPS2 / A_M * (1.0 + F + GRAVITY_M) * 1000.0
            + 3.0 * GE_MPS2 * 1e6 / (A_M * A_M);
        assert!((dg - expect).abs() < 1e-12, "{dg} {expect}");
        assert!((dg + 3.086e-3).abs() < 2e-6, "{dg}");
        assert_eq!(
            gravity_ned_mps2(&Geodetic {
                lat_rad: 0.3,
                lon_rad: 1.0,
                h_m: 200.0
            }),
            Vector3::new(0.0, 0.0, normal_gravity_mps2(0.3, 200.0))
        );
    }

    #[test]
    fn radii_known_values() {
        let m0 = A_M * (1.0 - E2);
        assert!((radius_meridian_m(0.0) - m0).abs() < 1e-8);
        assert!((radius_prime_vertical_m(0.0) - A_M).abs() < 1e-8);
        let np = A_M * A_M / B_M;
        assert!((radius_prime_vertical_m(FRAC_PI_2) - np).abs() < 1e-8);
        // At the poles both radii equal a²/b.
        assert!((radius_meridian_m(FRAC_PI_2) - np).abs() < 1e-8);
        // Published WGS84 values (m): M(0) = 6 335 439.327, N(90°) = 6 399 593.626.
        assert!((m0 - 6_335_439.327).abs() < 1e-3);
        assert!((np - 6_399_593.626).abs() < 1e-3);
    }

    #[test]
    fn q_en_at_origin_maps_north_up_and_down_to_minus_x() {
        let q = q_en(0.0, 0.0);
        let eps = 1e-15;
        assert!((q * Vector3::x() - Vector3::z()).norm() < eps);
        assert!((q * Vector3::y() - Vector3::y()).norm() < eps);
        assert!((q * Vector3::z() + Vector3::x()).norm() < eps);
        // Down is the negative ellipsoid normal everywhere, e.g. at (30°, 60°).
        let (lat, lon) = (0.5_f64, 1.0_f64);
        let down_e = q_en(lat, lon) * Vector3::z();
        let normal = Vector3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
        assert!((down_e + normal).norm() < eps);
        assert!((q_en(lat, lon).norm() - 1.0).abs() < eps);
    }

    #[test]
    fn ned_difference_matches_meridian_arc() {
        // Two points on the ellipsoid 1 km of meridian arc apart. Arc by Simpson's rule on M(φ):
        // error ≈ Δφ⁵ max|M⁗|/2880 ≈ (1.6e-4)⁵·1e5/2880 m, negligible. The chord's north component
        // differs from the arc by ≈ s³/(6R²) ≈ 4e-6 m and its down component is ≈ s²/(2M), so a
        // 1 mm tolerance is the requirement, with the geometry error 250× below it.
        for lat0_deg in [-70.0_f64, 0.0, 44.5] {
            let lat0 = lat0_deg.to_radians();
            let mut dlat = 1000.0 / radius_meridian_m(lat0);
            for _ in 0..3 {
                let arc = meridian_arc(lat0, lat0 + dlat);
                dlat *= 1000.0 / arc;
            }
            let arc = meridian_arc(lat0, lat0 + dlat);
            assert!((arc - 1000.0).abs() < 1e-9);
            let from = Geodetic {
                lat_rad: lat0,
                lon_rad: 0.2,
                h_m: 0.0,
            };
            let to = Geodetic {
                lat_rad: lat0 + dlat,
                ..from
            };
            let d = ned_difference_m(&from, &to);
            assert!((d.x - arc).abs() < 1e-3, "{d:?}");
            assert!(d.y.abs() < 1e-6, "{d:?}");
            let sag = arc * arc / (2.0 * radius_meridian_m(lat0));
            assert!((d.z - sag).abs() < 1e-3, "{d:?} {sag}");
            // Exactness: the NED vector maps back to the ECEF difference.
            let back = q_en(from.lat_rad, from.lon_rad) * d;
            assert!((back - (geodetic_to_ecef(&to) - geodetic_to_ecef(&from))).norm() < 1e-9);
        }
    }

    fn meridian_arc(lat0: f64, lat1: f64) -> f64 {
        let mid = 0.5 * (lat0 + lat1);
        (lat1 - lat0) / 6.0
            * (radius_meridian_m(lat0) + 4.0 * radius_meridian_m(mid) + radius_meridian_m(lat1))
    }

    #[test]
    fn geodetic_rates_match_finite_differences_of_ecef_motion() {
        // Move the ECEF point along q_en·v_ned by ±dt and difference the geodetic coordinates.
        // Central differences cancel the first truncation term; the rest is relative
        // ≈ (|v| dt / (R cos φ))², worst at 85° with |v| = 142 m/s: (14.2/5.6e5)² ≈ 6e-10.
        // Rounding: ~1e-9 m of ECEF/geodetic error over a 2·|v|·dt ≥ 1 m baseline ≈ 1e-9 m/s,
        // i.e. ≤ 2e-10 relative. Tolerance 1e-8 relative to the rate scale |v|/(R cos φ).
        let dt = 0.1;
        for &(lat_deg, lon_deg, h) in &[
            (0.0, 0.0, 0.0),
            (44.5, -89.5, 300.0),
            (-60.0, 170.0, 8_000.0),
            (85.0, 10.0, 100.0),
        ] {
            for v in [
                Vector3::new(30.0, -20.0, 2.0),
                Vector3::new(-100.0, 100.0, -10.0),
                Vector3::new(0.0, 0.0, 5.0),
            ] {
                let pos = Geodetic {
                    lat_rad: f64::to_radians(lat_deg),
                    lon_rad: f64::to_radians(lon_deg),
                    h_m: h,
                };
                let p = geodetic_to_ecef(&pos);
                let v_e = q_en(pos.lat_rad, pos.lon_rad) * v;
                let gp = ecef_to_geodetic(&(p + v_e * dt));
                let gm = ecef_to_geodetic(&(p - v_e * dt));
                let fd = Vector3::new(
                    (gp.lat_rad - gm.lat_rad) / (2.0 * dt),
                    (gp.lon_rad - gm.lon_rad) / (2.0 * dt),
                    (gp.h_m - gm.h_m) / (2.0 * dt),
                );
                let rates = geodetic_rates(&pos, &v);
                let scale_ang = v.norm() / (A_M * f64::to_radians(lat_deg).cos());
                assert!(
                    (fd.x - rates.x).abs() < 1e-8 * scale_ang,
                    "{fd:?} {rates:?}"
                );
                assert!(
                    (fd.y - rates.y).abs() < 1e-8 * scale_ang,
                    "{fd:?} {rates:?}"
                );
                assert!((fd.z - rates.z).abs() < 1e-8 * v.norm(), "{fd:?} {rates:?}");
            }
        }
    }

    #[test]
    fn earth_and_transport_rates() {
        let w = omega_ie_n(0.0);
        assert_eq!(w, Vector3::new(OMEGA_IE_RPS, 0.0, 0.0));
        let w = omega_ie_n(FRAC_PI_2);
        assert!((w - Vector3::new(0.0, 0.0, -OMEGA_IE_RPS)).norm() < 1e-20);
        // ω_ie^n is ω_ie^e = (0, 0, ω) viewed in NED.
        let (lat, lon) = (0.7, -1.2);
        let w_e = q_en(lat, lon) * omega_ie_n(lat);
        assert!((w_e - Vector3::new(0.0, 0.0, OMEGA_IE_RPS)).norm() < 1e-19);
        // Transport rate: rotation rate of NED wrt ECEF. Check it against the finite difference
        // of q_en along the geodetic rates: q_en(t+dt) ≈ q_en(t)·Exp(ω_en^n dt). Central
        // difference error ∝ dt² · |ω|³, relative ≈ (|ω| dt)² ≈ 1e-10.
        let pos = Geodetic {
            lat_rad: lat,
            lon_rad: lon,
            h_m: 1500.0,
        };
        let v = Vector3::new(60.0, -45.0, 3.0);
        let rates = geodetic_rates(&pos, &v);
        let dt = 1.0;
        let qp = q_en(lat + rates.x * dt, lon + rates.y * dt);
        let qm = q_en(lat - rates.x * dt, lon - rates.y * dt);
        let delta = (qm.inverse() * qp).scaled_axis() / (2.0 * dt);
        let w = omega_en_n(&pos, &v);
        assert!((delta - w).norm() < 1e-8 * w.norm(), "{delta:?} {w:?}");
    }
}
