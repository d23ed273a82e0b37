//! Property tests of the shared mathematics (`ianav::math`): WGS84 round trips and geodetic
//! rates, SO(3)/SE(3) Exp/Log round trips, ⊕/⊖ consistency and every hand-derived Jacobian
//! against central finite differences, over random inputs that include angles near 0
//! (1e-9 … 1e-4 rad) and near π (π − 1e-6 … π).
//!
//! Finite-difference tolerances. A central difference with step h has truncation error
//! ≈ h²/6·|f'''| and rounding error ≈ ε_f/h, where ε_f is the absolute rounding error of one
//! evaluation of f. Here f is a Log of a product of a few O(1) quaternions/matrices, so
//! ε_f ≲ 8ε·(1 + |ρ|) ≈ 2e-15·(1 + |ρ|), and |f'''| ≲ 1·(1 + |ρ|) for |φ| ≤ π (the Jacobians
//! and their derivatives are bounded there; they blow up only at 2π). With h = 1e-5:
//! truncation ≈ 1.7e-11, rounding ≈ 2e-10, per unit of (1 + |ρ|). The tolerance
//! [`FD_TOL`]·(1 + |ρ|) = 2e-9·(1 + |ρ|) keeps a ~10× margin over their sum.

use std::f64::consts::{FRAC_PI_2, PI};

use ianav::math::angle::wrap_pi;
use ianav::math::{se3, so3, wgs84};
use nalgebra::{Isometry3, Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector3, Vector6};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};

/// Finite-difference step (see the module doc).
const FD_STEP: f64 = 1e-5;
/// Finite-difference tolerance per unit of `(1 + |ρ|)` (see the module doc).
const FD_TOL: f64 = 2e-9;
/// Relative round-trip tolerance of Exp/Log: a handful of roundings in sin/cos/atan2 and a few
/// products, ≈ 10–50 ε ≈ 1e-14; 1e-12 leaves a wide margin and is far below the 1e-9 target.
const ROUND_TRIP_REL: f64 = 1e-12;
/// Absolute error of composing/inverting unit quaternions or isometries with O(1) entries:
/// a few ε per product. Used where a result passes through a group product first.
const PRODUCT_ABS: f64 = 1e-14;

fn config() -> Config {
    Config {
        cases: 512,
        // Reproducible runs (the project is deterministic by seed); failures print the input.
        rng_seed: RngSeed::Fixed(0x1a_2a_71),
        failure_persistence: None,
        ..Config::default()
    }
}

/// Unit direction, uniform-ish on the sphere (rejecting near-zero samples).
fn direction() -> impl Strategy<Value = Vector3<f64>> {
    (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
        .prop_map(|(x, y, z)| Vector3::new(x, y, z))
        .prop_filter("non-degenerate direction", |v| v.norm() > 0.1)
        .prop_map(|v| v.normalize())
}

/// Rotation angle: log-uniform near 0, uniform in the bulk, and within 1e-6 of π.
fn angle() -> impl Strategy<Value = f64> {
    prop_oneof![
        (-9.0..-4.0f64).prop_map(|e| 10f64.powf(e)),
        1e-4..(PI - 1e-6),
        (PI - 1e-6)..=PI,
        Just(0.0),
        Just(PI),
    ]
}

/// Rotation vector with `|φ| ≤ π`.
fn rotation_vector() -> impl Strategy<Value = Vector3<f64>> {
    (direction(), angle()).prop_map(|(d, a)| d * a)
}

/// Arbitrary unit quaternion, including w < 0 (sampled on S³, not through Exp).
fn unit_quaternion() -> impl Strategy<Value = UnitQuaternion<f64>> {
    (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
        .prop_filter("non-degenerate", |(w, x, y, z)| {
            w * w + x * x + y * y + z * z > 0.01
        })
        .prop_map(|(w, x, y, z)| UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)))
}

/// Translation part of a twist.
fn translation() -> impl Strategy<Value = Vector3<f64>> {
    prop_oneof![
        (-10.0..10.0f64, -10.0..10.0f64, -10.0..10.0f64)
            .prop_map(|(x, y, z)| Vector3::new(x, y, z)),
        Just(Vector3::zeros()),
    ]
}

/// Twist `[ρ; φ]` with `|φ| ≤ π`.
fn twist() -> impl Strategy<Value = Vector6<f64>> {
    (translation(), rotation_vector()).prop_map(|(r, p)| stack(&r, &p))
}

fn pose() -> impl Strategy<Value = Isometry3<f64>> {
    (translation(), unit_quaternion()).prop_map(|(t, q)| Isometry3::from_parts(t.into(), q))
}

fn stack(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

fn rho_of(tau: &Vector6<f64>) -> Vector3<f64> {
    tau.fixed_rows::<3>(0).into_owned()
}

fn phi_of(tau: &Vector6<f64>) -> Vector3<f64> {
    tau.fixed_rows::<3>(3).into_owned()
}

/// The rotation vector of the same rotation as `v` (|v| ≤ π) that is nearest to `reference`:
/// undoes the branch cut of Log at π so that finite differences stay continuous.
fn unwrap_near(v: &Vector3<f64>, reference: &Vector3<f64>) -> Vector3<f64> {
    let n = v.norm();
    if n > 0.0 && (v - reference).norm() > PI {
        v * (1.0 - 2.0 * PI / n)
    } else {
        *v
    }
}

/// SE(3) counterpart of [`unwrap_near`]: re-expresses the same pose with the other branch of
/// φ (and the matching ρ = J_l⁻¹(φ') t).
fn unwrap_twist_near(tau: &Vector6<f64>, reference: &Vector6<f64>) -> Vector6<f64> {
    let phi = phi_of(tau);
    let phi_u = unwrap_near(&phi, &phi_of(reference));
    if phi_u == phi {
        return *tau;
    }
    let t = so3::left_jacobian(&phi) * rho_of(tau);
    stack(&(so3::left_jacobian_inv(&phi_u) * t), &phi_u)
}

/// Quaternion distance up to sign.
fn quat_dist(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    (a.coords - b.coords)
        .norm()
        .min((a.coords + b.coords).norm())
}

// ------------------------------------------------------------------------------------------
// SO(3)
// ------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(config())]

    #[test]
    fn so3_log_exp_round_trip(phi in rotation_vector()) {
        let back = so3::log(&so3::exp(&phi));
        let theta = phi.norm();
        // At exactly π both ±φ are valid logarithms.
        let err = if theta > PI - 1e-12 {
            (back - phi).norm().min((back + phi).norm())
        } else {
            (back - phi).norm()
        };
        prop_assert!(err <= ROUND_TRIP_REL * theta, "{phi:?} → {back:?}: {err:e}");
        prop_assert!(back.norm() <= PI * (1.0 + 1e-15));
    }

    #[test]
    fn so3_exp_log_round_trip(q in unit_quaternion()) {
        let phi = so3::log(&q);
        prop_assert!(phi.norm() <= PI * (1.0 + 1e-15), "{phi:?}");
        let back = so3::exp(&phi);
        prop_assert!(quat_dist(&back, &q) < PRODUCT_ABS, "{q:?} → {back:?}");
    }

    #[test]
    fn so3_plus_minus_consistent(q in unit_quaternion(), y in unit_quaternion(),
                                 tau in rotation_vector()) {
        // q ⊕ (y ⊖ q) = y, as rotations.
        let z = so3::plus(&q, &so3::minus(&y, &q));
        prop_assert!(quat_dist(&z, &y) < PRODUCT_ABS, "{z:?} {y:?}");
        // (q ⊕ τ) ⊖ q = τ up to the product's absolute rounding (relative for large τ).
        let back = so3::minus(&so3::plus(&q, &tau), &q);
        let err = (unwrap_near(&back, &tau) - tau).norm();
        prop_assert!(err < PRODUCT_ABS + ROUND_TRIP_REL * tau.norm(), "{tau:?} {back:?}");
    }

    #[test]
    fn so3_right_jacobian_matches_finite_differences(phi in rotation_vector()) {
        // Exp(φ + δ) ≈ Exp(φ)·Exp(J_r(φ) δ): column j = d/dh [Exp(φ + h e_j) ⊖ Exp(φ)].
        let x = so3::exp(&phi);
        let mut fd = Matrix3::zeros();
        for j in 0..3 {
            let mut d = Vector3::zeros();
            d[j] = FD_STEP;
            let fp = so3::minus(&so3::exp(&(phi + d)), &x);
            let fm = so3::minus(&so3::exp(&(phi - d)), &x);
            fd.set_column(j, &((fp - fm) / (2.0 * FD_STEP)));
        }
        let jr = so3::right_jacobian(&phi);
        prop_assert!((fd - jr).amax() < FD_TOL, "{phi:?}\n{fd}\n{jr}");
    }

    #[test]
    fn so3_right_jacobian_inverse(phi in rotation_vector()) {
        // As a matrix inverse: entries O(1) for |φ| ≤ π, a few ε per product.
        let prod = so3::right_jacobian(&phi) * so3::right_jacobian_inv(&phi);
        prop_assert!((prod - Matrix3::identity()).amax() < 1e-13, "{phi:?}\n{prod}");
        // As the derivative of Log: Log(Exp(φ)·Exp(δ)) ≈ φ + J_r⁻¹(φ) δ.
        let x = so3::exp(&phi);
        let mut fd = Matrix3::zeros();
        for j in 0..3 {
            let mut d = Vector3::zeros();
            d[j] = FD_STEP;
            let fp = unwrap_near(&so3::log(&so3::plus(&x, &d)), &phi);
            let fm = unwrap_near(&so3::log(&so3::plus(&x, &-d)), &phi);
            fd.set_column(j, &((fp - fm) / (2.0 * FD_STEP)));
        }
        let jri = so3::right_jacobian_inv(&phi);
        prop_assert!((fd - jri).amax() < FD_TOL, "{phi:?}\n{fd}\n{jri}");
    }

    #[test]
    fn so3_left_jacobians_are_transposed_right(phi in rotation_vector()) {
        // J_l(φ) = J_r(−φ) = J_r(φ)ᵀ, likewise for the inverses: exact up to rounding.
        prop_assert!((so3::left_jacobian(&phi) - so3::right_jacobian(&phi).transpose()).amax()
            < 1e-15);
        prop_assert!((so3::left_jacobian_inv(&phi)
            - so3::right_jacobian_inv(&phi).transpose()).amax() < 1e-15);
    }

    #[test]
    fn euler_round_trip_away_from_gimbal_lock(
        yaw in -PI..PI,
        pitch in (-FRAC_PI_2 + 0.01)..(FRAC_PI_2 - 0.01),
        bank in -PI..PI,
    ) {
        // ψ and ξ are conditioned as 1/cos θ ≤ 100: a few ε·100 ≈ 1e-13.
        let e = so3::euler_zyx(&so3::from_euler_zyx(yaw, pitch, bank));
        prop_assert!(wrap_pi(e.x - yaw).abs() < 1e-12, "{e:?}");
        prop_assert!((e.y - pitch).abs() < 1e-12, "{e:?}");
        prop_assert!(wrap_pi(e.z - bank).abs() < 1e-12, "{e:?}");
    }

    #[test]
    fn euler_reproduces_any_rotation(q in unit_quaternion(),
                                     yaw in -PI..PI, bank in -PI..PI,
                                     dp in prop_oneof![Just(0.0), 0.0..1e-6f64]) {
        // Anywhere, gimbal lock included, the angles reproduce the rotation (a few ε).
        for q in [q, so3::from_euler_zyx(yaw, FRAC_PI_2 - dp, bank),
                  so3::from_euler_zyx(yaw, -FRAC_PI_2 + dp, bank)] {
            let e = so3::euler_zyx(&q);
            prop_assert!(e.iter().all(|a| a.is_finite()));
            prop_assert!(e.y.abs() <= FRAC_PI_2 && e.x.abs() <= PI && e.z.abs() <= PI);
            let back = so3::from_euler_zyx(e.x, e.y, e.z);
            prop_assert!(quat_dist(&back, &q) < PRODUCT_ABS, "{q:?} {e:?}");
        }
    }
}

// ------------------------------------------------------------------------------------------
// SE(3)
// ------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(config())]

    #[test]
    fn se3_log_exp_round_trip(tau in twist()) {
        let back = se3::log(&se3::exp(&tau));
        let err = if phi_of(&tau).norm() > PI - 1e-12 {
            (unwrap_twist_near(&back, &tau) - tau).norm()
        } else {
            (back - tau).norm()
        };
        prop_assert!(err <= ROUND_TRIP_REL * tau.norm(), "{tau:?} → {back:?}: {err:e}");
    }

    #[test]
    fn se3_exp_log_round_trip(x in pose()) {
        let back = se3::exp(&se3::log(&x));
        let scale = 1.0 + x.translation.vector.norm();
        prop_assert!(quat_dist(&back.rotation, &x.rotation) < PRODUCT_ABS);
        prop_assert!((back.translation.vector - x.translation.vector).norm()
            < PRODUCT_ABS * scale, "{x:?} → {back:?}");
    }

    #[test]
    fn se3_plus_minus_consistent(x in pose(), y in pose(), tau in twist()) {
        let z = se3::plus(&x, &se3::minus(&y, &x));
        let scale = 1.0 + x.translation.vector.norm() + y.translation.vector.norm();
        prop_assert!(quat_dist(&z.rotation, &y.rotation) < PRODUCT_ABS);
        prop_assert!((z.translation.vector - y.translation.vector).norm() < PRODUCT_ABS * scale);
        let back = se3::minus(&se3::plus(&x, &tau), &x);
        let err = (unwrap_twist_near(&back, &tau) - tau).norm();
        prop_assert!(err < PRODUCT_ABS * scale + ROUND_TRIP_REL * tau.norm(), "{tau:?} {back:?}");
    }

    #[test]
    fn se3_right_jacobian_matches_finite_differences(tau in twist()) {
        let x = se3::exp(&tau);
        let mut fd = Matrix6::zeros();
        for j in 0..6 {
            let mut d = Vector6::zeros();
            d[j] = FD_STEP;
            let fp = se3::minus(&se3::exp(&(tau + d)), &x);
            let fm = se3::minus(&se3::exp(&(tau - d)), &x);
            fd.set_column(j, &((fp - fm) / (2.0 * FD_STEP)));
        }
        let jr = se3::right_jacobian(&tau);
        let tol = FD_TOL * (1.0 + rho_of(&tau).norm());
        prop_assert!((fd - jr).amax() < tol, "{tau:?}\n{fd}\n{jr}");
    }

    #[test]
    fn se3_right_jacobian_inverse(tau in twist()) {
        let scale = 1.0 + rho_of(&tau).norm();
        let prod = se3::right_jacobian(&tau) * se3::right_jacobian_inv(&tau);
        prop_assert!((prod - Matrix6::identity()).amax() < 1e-13 * scale, "{tau:?}\n{prod}");
        let x = se3::exp(&tau);
        let mut fd = Matrix6::zeros();
        for j in 0..6 {
            let mut d = Vector6::zeros();
            d[j] = FD_STEP;
            let fp = unwrap_twist_near(&se3::log(&se3::plus(&x, &d)), &tau);
            let fm = unwrap_twist_near(&se3::log(&se3::plus(&x, &-d)), &tau);
            fd.set_column(j, &((fp - fm) / (2.0 * FD_STEP)));
        }
        let jri = se3::right_jacobian_inv(&tau);
        prop_assert!((fd - jri).amax() < FD_TOL * scale, "{tau:?}\n{fd}\n{jri}");
    }
}

// ------------------------------------------------------------------------------------------
// WGS84
// ------------------------------------------------------------------------------------------

/// Latitude: uniform, plus within 1e-12 … 1e-3 rad of either pole, plus the poles themselves.
fn latitude() -> impl Strategy<Value = f64> {
    prop_oneof![
        -FRAC_PI_2..=FRAC_PI_2,
        (-12.0..-3.0f64).prop_map(|e| FRAC_PI_2 - 10f64.powf(e)),
        (-12.0..-3.0f64).prop_map(|e| -FRAC_PI_2 + 10f64.powf(e)),
        Just(FRAC_PI_2),
        Just(-FRAC_PI_2),
        Just(0.0),
    ]
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn geodetic_ecef_round_trip(lat in latitude(), lon in -PI..PI, h in -10_000.0..100_000.0f64) {
        // ECEF rounding is |p|·ε ≈ 1.5e-9 m per coordinate; 1e-7 m (0.1 µm) is a 60× margin
        // and 1e4 below the sub-millimetre requirement; 1e-7 m / 6.3e6 m ≈ 1.6e-14 rad.
        let g = wgs84::Geodetic { lat_rad: lat, lon_rad: lon, h_m: h };
        let p = wgs84::geodetic_to_ecef(&g);
        let back = wgs84::ecef_to_geodetic(&p);
        prop_assert!((back.lat_rad - lat).abs() < 2e-14, "{g:?} {back:?}");
        prop_assert!((back.h_m - h).abs() < 1e-7, "{g:?} {back:?}");
        // Longitude: compare the arc on the parallel (undefined on the axis itself).
        let rho = p.xy().norm();
        prop_assert!(rho * wrap_pi(back.lon_rad - lon).abs() < 1e-7, "{g:?} {back:?}");
        prop_assert!((wgs84::geodetic_to_ecef(&back) - p).norm() < 1e-7);
    }

    #[test]
    fn geodetic_rates_match_ecef_motion(
        lat in -1.48..1.48f64, lon in -PI..PI, h in -1_000.0..20_000.0f64,
        vn in -100.0..100.0f64, ve in -100.0..100.0f64, vd in -20.0..20.0f64,
    ) {
        // Central difference of geodetic coordinates along the straight ECEF path p ± v_e·dt.
        // Truncation ≈ (|v| dt/(R cos φ))² ≤ (17.5/5.7e5)² ≈ 1e-9 relative at |φ| ≤ 84.8°;
        // rounding ≈ 1e-9 m / (2|v|dt) ≤ 1e-9 relative for |v| ≥ 5 m/s, and is ≤ 2e-16 rad/s
        // absolute, well below 1e-8 × the rate scale |v|/(R cos φ) ≥ 1.6e-14 rad/s otherwise.
        let pos = wgs84::Geodetic { lat_rad: lat, lon_rad: lon, h_m: h };
        let v = Vector3::new(vn, ve, vd);
        let dt = 0.1;
        let p = wgs84::geodetic_to_ecef(&pos);
        let v_e = wgs84::q_en(lat, lon) * v;
        let gp = wgs84::ecef_to_geodetic(&(p + v_e * dt));
        let gm = wgs84::ecef_to_geodetic(&(p - v_e * dt));
        let fd = Vector3::new(
            (gp.lat_rad - gm.lat_rad) / (2.0 * dt),
            wrap_pi(gp.lon_rad - gm.lon_rad) / (2.0 * dt),
            (gp.h_m - gm.h_m) / (2.0 * dt),
        );
        let rates = wgs84::geodetic_rates(&pos, &v);
        let scale = v.norm() / (wgs84::A_M * lat.cos());
        prop_assert!((fd.x - rates.x).abs() <= 1e-8 * scale + 1e-15, "{fd:?} {rates:?}");
        prop_assert!((fd.y - rates.y).abs() <= 1e-8 * scale + 1e-15, "{fd:?} {rates:?}");
        prop_assert!((fd.z - rates.z).abs() <= 1e-8 * v.norm() + 1e-8, "{fd:?} {rates:?}");
    }

    #[test]
    fn ned_difference_round_trips_through_ecef(
        lat in -1.5..1.5f64, lon in -PI..PI, h in 0.0..5_000.0f64,
        dn in -5_000.0..5_000.0f64, de in -5_000.0..5_000.0f64, dd in -500.0..500.0f64,
    ) {
        // Place `to` at from + q_en·d in ECEF; ned_difference_m must return d. Errors: ECEF
        // coordinates round at ≈1e-9 m, the geodetic conversion adds ≈1e-9 m: 1e-7 m.
        let from = wgs84::Geodetic { lat_rad: lat, lon_rad: lon, h_m: h };
        let d = Vector3::new(dn, de, dd);
        let p_to = wgs84::geodetic_to_ecef(&from) + wgs84::q_en(lat, lon) * d;
        let to = wgs84::ecef_to_geodetic(&p_to);
        let back = wgs84::ned_difference_m(&from, &to);
        prop_assert!((back - d).norm() < 1e-7, "{d:?} {back:?}");
    }
}
