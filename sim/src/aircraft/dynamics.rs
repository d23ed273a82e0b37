//! Six-degree-of-freedom rigid-body equations of motion on the rotating WGS84 Earth
//! (docs/REFERENCES.md A4.4) and their classical fourth-order Runge–Kutta integration.
//!
//! State: geodetic position, ground velocity viewed in body `v^b = C_bn v^n`, attitude
//! `q_nb`, inertial angular velocity `ω_ib^b`, mass. From `v̇^n = C_nb f + g^n − (2ω_ie^n +
//! ω_en^n) × v^n` and `Ċ_bn = −[ω_nb^b]× C_bn` with `ω_nb^b = ω_ib^b − C_bn(ω_ie^n + ω_en^n)`:
//!
//! ```text
//! v̇^b = f^b + C_bn g^n − (ω_ib^b + C_bn ω_ie^n) × v^b     (the transport rate cancels)
//! q̇_nb = ½ q_nb ⊗ (0, ω_nb^b)
//! ω̇_ib^b = I⁻¹ (M^b − ω_ib^b × I ω_ib^b)                  (İ neglected)
//! ṁ = −ṁ_fuel,  (φ̇, λ̇, ḣ) = wgs84::geodetic_rates(pos, C_nb v^b)
//! ```
//!
//! which is the authors' `f − ω_eb^b × v^b + C_bn(g^n − 2ω_ie^n × v^n)` rearranged. `g^n` is
//! normal (or "true") gravity, which already contains the centrifugal term.

use ianav::math::angle::wrap_pi;
use ianav::math::wgs84::{self, Geodetic};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::TruthState;

/// What the force/moment model hands to the rigid-body equations at one state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyAccelerations {
    /// Specific force at the CG, body axes, m/s².
    pub f_ib_b_mps2: Vector3<f64>,
    /// Inertial angular acceleration, body axes, rad/s².
    pub w_dot_ib_b_rps2: Vector3<f64>,
    /// Mass rate, kg/s (negative while burning fuel).
    pub mass_rate_kgps: f64,
}

/// Time derivative of a [`TruthState`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateRate {
    /// `(φ̇, λ̇, ḣ)`: rad/s, rad/s, m/s.
    pub geodetic_rate: Vector3<f64>,
    /// `v̇^b`, m/s².
    pub v_dot_b_mps2: Vector3<f64>,
    /// `q̇_nb` (not unit).
    pub q_dot_nb: Quaternion<f64>,
    /// `ω̇_ib^b`, rad/s².
    pub w_dot_ib_b_rps2: Vector3<f64>,
    /// `ṁ`, kg/s.
    pub mass_rate_kgps: f64,
}

/// Angular velocity of the body relative to NED, `ω_nb^b = ω_ib^b − C_bn(ω_ie^n + ω_en^n)`.
pub fn w_nb_b(x: &TruthState) -> Vector3<f64> {
    let v_ned = x.q_nb * x.v_b_mps;
    let w_in_n = wgs84::omega_ie_n(x.pos.lat_rad) + wgs84::omega_en_n(&x.pos, &v_ned);
    x.w_ib_b_rps - x.q_nb.inverse_transform_vector(&w_in_n)
}

/// State derivative. `accelerations(x, ω_nb^b)` supplies the specific force, angular
/// acceleration and mass rate at `x` (ω_nb^b is passed because the aerodynamics need it and
/// it is computed here anyway).
#[inline]
pub fn state_rate<F>(
    x: &TruthState,
    gravity_ned_mps2: &Vector3<f64>,
    accelerations: &mut F,
) -> StateRate
where
    F: FnMut(&TruthState, &Vector3<f64>) -> BodyAccelerations,
{
    let r_nb = x.q_nb.to_rotation_matrix();
    let c_bn = r_nb.matrix().transpose();
    let v_ned = r_nb * x.v_b_mps;
    let w_ie_n = wgs84::omega_ie_n(x.pos.lat_rad);
    let w_en_n = wgs84::omega_en_n(&x.pos, &v_ned);
    let w_ie_b = c_bn * w_ie_n;
    let w_nb_b = x.w_ib_b_rps - w_ie_b - c_bn * w_en_n;
    let acc = accelerations(x, &w_nb_b);
    let v_dot_b_mps2 =
        acc.f_ib_b_mps2 + c_bn * gravity_ned_mps2 - (x.w_ib_b_rps + w_ie_b).cross(&x.v_b_mps);
    let q_dot_nb = x.q_nb.quaternion() * Quaternion::from_imag(w_nb_b) * 0.5;
    StateRate {
        geodetic_rate: wgs84::geodetic_rates(&x.pos, &v_ned),
        v_dot_b_mps2,
        q_dot_nb,
        w_dot_ib_b_rps2: acc.w_dot_ib_b_rps2,
        mass_rate_kgps: acc.mass_rate_kgps,
    }
}

/// `x + h·k` with the quaternion added component-wise and renormalised (any smooth extension
/// of the dynamics off the unit sphere keeps RK4 fourth order; normalising is the natural one).
#[inline]
fn advance(x: &TruthState, k: &StateRate, h: f64) -> TruthState {
    TruthState {
        pos: Geodetic {
            lat_rad: x.pos.lat_rad + h * k.geodetic_rate.x,
            lon_rad: x.pos.lon_rad + h * k.geodetic_rate.y,
            h_m: x.pos.h_m + h * k.geodetic_rate.z,
        },
        v_b_mps: x.v_b_mps + k.v_dot_b_mps2 * h,
        q_nb: UnitQuaternion::new_normalize(x.q_nb.quaternion() + k.q_dot_nb * h),
        w_ib_b_rps: x.w_ib_b_rps + k.w_dot_ib_b_rps2 * h,
        mass_kg: x.mass_kg + h * k.mass_rate_kgps,
    }
}

/// Weighted sum `k1 + 2k2 + 2k3 + k4` of RK4.
#[inline]
fn rk4_combine(k1: &StateRate, k2: &StateRate, k3: &StateRate, k4: &StateRate) -> StateRate {
    StateRate {
        geodetic_rate: k1.geodetic_rate
            + (k2.geodetic_rate + k3.geodetic_rate) * 2.0
            + k4.geodetic_rate,
        v_dot_b_mps2: k1.v_dot_b_mps2 + (k2.v_dot_b_mps2 + k3.v_dot_b_mps2) * 2.0 + k4.v_dot_b_mps2,
        q_dot_nb: k1.q_dot_nb + (k2.q_dot_nb + k3.q_dot_nb) * 2.0 + k4.q_dot_nb,
        w_dot_ib_b_rps2: k1.w_dot_ib_b_rps2
            + (k2.w_dot_ib_b_rps2 + k3.w_dot_ib_b_rps2) * 2.0
            + k4.w_dot_ib_b_rps2,
        mass_rate_kgps: k1.mass_rate_kgps
            + 2.0 * (k2.mass_rate_kgps + k3.mass_rate_kgps)
            + k4.mass_rate_kgps,
    }
}

/// One classical RK4 step of `dt_s` with gravity (and whatever `accelerations` captures:
/// controls, air) held constant; the quaternion is renormalised and the longitude wrapped.
#[inline]
pub fn rk4_step<F>(
    x: &TruthState,
    gravity_ned_mps2: &Vector3<f64>,
    dt_s: f64,
    mut accelerations: F,
) -> TruthState
where
    F: FnMut(&TruthState, &Vector3<f64>) -> BodyAccelerations,
{
    let h = 0.5 * dt_s;
    let k1 = state_rate(x, gravity_ned_mps2, &mut accelerations);
    let k2 = state_rate(&advance(x, &k1, h), gravity_ned_mps2, &mut accelerations);
    let k3 = state_rate(&advance(x, &k2, h), gravity_ned_mps2, &mut accelerations);
    let k4 = state_rate(&advance(x, &k3, dt_s), gravity_ned_mps2, &mut accelerations);
    let mut next = advance(x, &rk4_combine(&k1, &k2, &k3, &k4), dt_s / 6.0);
    next.pos.lon_rad = wrap_pi(next.pos.lon_rad);
    next
}

/// One Heun (explicit trapezoidal, second-order) step, the authors' integrator; kept for the
/// order comparison in the tests and in `docs/AIRCRAFT.md`.
pub fn heun_step<F>(
    x: &TruthState,
    gravity_ned_mps2: &Vector3<f64>,
    dt_s: f64,
    mut accelerations: F,
) -> TruthState
where
    F: FnMut(&TruthState, &Vector3<f64>) -> BodyAccelerations,
{
    let k1 = state_rate(x, gravity_ned_mps2, &mut accelerations);
    let k2 = state_rate(&advance(x, &k1, dt_s), gravity_ned_mps2, &mut accelerations);
    let sum = StateRate {
        geodetic_rate: k1.geodetic_rate + k2.geodetic_rate,
        v_dot_b_mps2: k1.v_dot_b_mps2 + k2.v_dot_b_mps2,
        q_dot_nb: k1.q_dot_nb + k2.q_dot_nb,
        w_dot_ib_b_rps2: k1.w_dot_ib_b_rps2 + k2.w_dot_ib_b_rps2,
        mass_rate_kgps: k1.mass_rate_kgps + k2.mass_rate_kgps,
    };
    let mut next = advance(x, &sum, 0.5 * dt_s);
    next.pos.lon_rad = wrap_pi(next.pos.lon_rad);
    next
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_wrap_longitude_across_the_antimeridian() {
        use crate::aircraft::TruthState;
        use ianav::math::so3;
        use std::f64::consts::{FRAC_PI_2, PI};
        // Flying east at 30 m/s for 0.1 s moves λ by 3 m / ((N + h) cos φ) ≈ 6.7e-7 rad. The
        // geodetic rates do not depend on λ, so a step started 1e-7 rad before the
        // antimeridian must advance λ exactly as one started at λ = 0.5, only wrapped.
        let state = |lon_rad: f64| TruthState {
            pos: Geodetic {
                lat_rad: 0.8,
                lon_rad,
                h_m: 2500.0,
            },
            v_b_mps: Vector3::new(30.0, 0.0, 0.0),
            q_nb: so3::from_euler_zyx(FRAC_PI_2, 0.0, 0.0),
            w_ib_b_rps: Vector3::zeros(),
            mass_kg: 19.5,
        };
        let coast = |_: &TruthState, _: &Vector3<f64>| BodyAccelerations {
            f_ib_b_mps2: Vector3::zeros(),
            w_dot_ib_b_rps2: Vector3::zeros(),
            mass_rate_kgps: 0.0,
        };
        let g = Vector3::new(0.0, 0.0, 9.8);
        let start = PI - 1e-7;
        type Coast = fn(&TruthState, &Vector3<f64>) -> BodyAccelerations;
        type Step = fn(&TruthState, &Vector3<f64>, f64, Coast) -> TruthState;
        let steps: [Step; 2] = [rk4_step, heun_step];
        for step in steps {
            let far = step(&state(0.5), &g, 0.1, coast).pos.lon_rad - 0.5;
            let seam = step(&state(start), &g, 0.1, coast).pos.lon_rad;
            assert!(seam > -PI && seam < 0.0, "{seam}");
            // Rounding: λ + Δλ near π (≤ 2.2e-16), near 0.5 (≤ 5.6e-17), and `seam − start`
            // near −2π (≤ 4.4e-16); the wrapping itself is exact. Sum < 1e-15.
            assert!((wrap_pi(seam - start) - far).abs() < 1e-15, "{seam} {far}");
            // Westwards from the other side.
            let west = |lon| TruthState {
                q_nb: so3::from_euler_zyx(-FRAC_PI_2, 0.0, 0.0),
                ..state(lon)
            };
            let seam = step(&west(-start), &g, 0.1, coast).pos.lon_rad;
            assert!(seam > 0.0 && seam <= PI, "{seam}");
        }
    }
}
