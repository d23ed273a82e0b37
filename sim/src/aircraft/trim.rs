//! Steady wings-level trim (no wind) by Newton's method on the full force/moment model, and
//! small-perturbation modes (short period, phugoid, Dutch roll, roll, spiral) from a
//! numerical linearisation about the trim. Not part of the per-step path.

use ianav::env::atmosphere::G0_MPS2;
use ianav::math::wgs84::Geodetic;
use nalgebra::{Complex, Matrix4, SMatrix, SVector, Schur, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::{AirInputs, Aircraft, AircraftError, Controls, TruthState};

/// Residual norm (m/s² for forces, dimensionless moment coefficients) accepted as trimmed.
const TRIM_RESIDUAL_TOL: f64 = 1e-10;
/// Newton iteration bound of the trim.
const TRIM_MAX_ITERATIONS: usize = 60;
/// Finite-difference step of the trim Jacobian (rad for angles, throttle units).
const TRIM_FD_STEP: f64 = 1e-7;
/// Trim searches are restricted to |α| below this, rad (well past the stall).
const TRIM_AOA_LIMIT_RAD: f64 = 0.5;

/// A steady wings-level, zero-sideslip trim point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Trim {
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Path angle γ (climb positive), rad.
    pub gamma_rad: f64,
    /// Mass, kg.
    pub mass_kg: f64,
    /// Angle of attack, rad.
    pub aoa_rad: f64,
    /// Pitch angle θ = α + γ, rad.
    pub pitch_rad: f64,
    /// Elevator, rad.
    pub elevator_rad: f64,
    /// Throttle.
    pub throttle: f64,
    /// Aileron that balances the propeller torque, rad.
    pub aileron_rad: f64,
    /// Rudder that balances the adverse yaw of that aileron, rad.
    pub rudder_rad: f64,
    /// Thrust, N.
    pub thrust_n: f64,
    /// Shaft power, W.
    pub power_w: f64,
    /// Shaft speed, rev/s.
    pub shaft_rps: f64,
    /// Wing-body lift coefficient.
    pub c_lift_wing: f64,
    /// Stall angle minus trim angle of attack, rad.
    pub aoa_margin_rad: f64,
    /// `C_Lmax / C_L,wing`: the load factor available before the stall at this speed.
    pub load_factor_to_stall: f64,
    /// 1-g stall speed at this weight and density, `V·√(C_L,wing/C_Lmax)`, m/s.
    pub stall_speed_mps: f64,
    /// Residual side acceleration left by wings-level, zero-sideslip trim, m/s².
    pub side_accel_mps2: f64,
}

impl Trim {
    /// The trim control positions.
    pub fn controls(&self) -> Controls {
        Controls {
            throttle: self.throttle,
            elevator_rad: self.elevator_rad,
            aileron_rad: self.aileron_rad,
            rudder_rad: self.rudder_rad,
        }
    }
}

/// Natural frequency and damping of a pair of eigenvalues (complex or real).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModePair {
    /// Undamped natural frequency `√(λ₁λ₂)`, rad/s.
    pub omega_n_rps: f64,
    /// Damping ratio `−(λ₁ + λ₂)/(2ω_n)` (> 1 for two real roots).
    pub zeta: f64,
}

/// Small-perturbation modes about a trim (flat Earth, still air).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Modes {
    /// Short period.
    pub short_period: ModePair,
    /// Phugoid.
    pub phugoid: ModePair,
    /// Dutch roll.
    pub dutch_roll: ModePair,
    /// Roll subsidence eigenvalue, 1/s (negative: stable).
    pub roll_eigenvalue_ps: f64,
    /// Spiral eigenvalue, 1/s (negative: convergent; positive: divergent).
    pub spiral_eigenvalue_ps: f64,
}

/// Trim state for the unknowns `[α, δe, δT, δa, δr]`: wings level, zero sideslip, ω = 0.
fn trim_state(tas: f64, gamma: f64, mass_kg: f64, aoa: f64) -> TruthState {
    TruthState {
        pos: Geodetic {
            lat_rad: 0.0,
            lon_rad: 0.0,
            h_m: 0.0,
        },
        v_b_mps: Vector3::new(aoa.cos(), 0.0, aoa.sin()) * tas,
        q_nb: UnitQuaternion::from_euler_angles(0.0, aoa + gamma, 0.0),
        w_ib_b_rps: Vector3::zeros(),
        mass_kg,
    }
}

fn controls_of(z: &SVector<f64, 5>) -> Controls {
    Controls {
        throttle: z[2],
        elevator_rad: z[1],
        aileron_rad: z[3],
        rudder_rad: z[4],
    }
}

/// Residuals: `f + C_bn g` along body x and z (m/s²) and the three moment coefficients.
fn residual(
    ac: &Aircraft,
    tas: f64,
    gamma: f64,
    air: &AirInputs,
    mass_kg: f64,
    z: &SVector<f64, 5>,
) -> SVector<f64, 5> {
    let x = trim_state(tas, gamma, mass_kg, z[0]);
    let loads = ac.loads_with_rates(&x, &controls_of(z), air, &Vector3::zeros());
    let theta = z[0] + gamma;
    let g_b = Vector3::new(-theta.sin(), 0.0, theta.cos()) * G0_MPS2;
    let a = ac.params().aero;
    let qbar_s = 0.5 * air.rho_kgpm3 * tas * tas * a.wing_area_m2;
    let m = loads.moment_b_nm;
    SVector::<f64, 5>::new(
        loads.f_ib_b_mps2.x + g_b.x,
        loads.f_ib_b_mps2.z + g_b.z,
        m.x / (qbar_s * a.wing_span_m),
        m.y / (qbar_s * a.mean_chord_m),
        m.z / (qbar_s * a.wing_span_m),
    )
}

/// Solves the trim (see [`Aircraft::trim`]).
pub(super) fn solve(
    ac: &Aircraft,
    tas_mps: f64,
    gamma_rad: f64,
    air: &AirInputs,
    mass_kg: f64,
) -> Result<Trim, AircraftError> {
    let inputs_ok = tas_mps.is_finite()
        && tas_mps > 1.0
        && gamma_rad.is_finite()
        && gamma_rad.abs() < 0.5
        && air.rho_kgpm3.is_finite()
        && air.rho_kgpm3 > 0.0
        && mass_kg.is_finite()
        && mass_kg > 0.0;
    if !inputs_ok {
        return Err(AircraftError::TrimInputs);
    }
    let a = ac.params().aero;
    // Initial guess: lift = weight, elevator from the linear moment balance, throttle 0.3.
    let qbar_s = 0.5 * air.rho_kgpm3 * tas_mps * tas_mps * a.wing_area_m2;
    let cl = mass_kg * G0_MPS2 * gamma_rad.cos() / qbar_s;
    let aoa0 = a.alpha_zero_lift_deg.to_radians() + cl / a.c_lift_alpha_prad;
    let de0 = -(a.c_pitch_0 + a.c_pitch_alpha_prad * aoa0) / a.c_pitch_elevator_prad;
    let mut z = SVector::<f64, 5>::new(aoa0, de0, 0.3, 0.0, 0.0);
    let mut r = residual(ac, tas_mps, gamma_rad, air, mass_kg, &z);
    let mut converged = false;
    for _ in 0..TRIM_MAX_ITERATIONS {
        if r.norm() < TRIM_RESIDUAL_TOL {
            converged = true;
            break;
        }
        let mut jac = SMatrix::<f64, 5, 5>::zeros();
        for i in 0..5 {
            let mut zp = z;
            let mut zm = z;
            zp[i] += TRIM_FD_STEP;
            zm[i] -= TRIM_FD_STEP;
            let col = (residual(ac, tas_mps, gamma_rad, air, mass_kg, &zp)
                - residual(ac, tas_mps, gamma_rad, air, mass_kg, &zm))
                / (2.0 * TRIM_FD_STEP);
            jac.set_column(i, &col);
        }
        let Some(step) = jac.lu().solve(&r) else {
            return Err(AircraftError::TrimNotConverged { tas_mps, gamma_rad });
        };
        z -= step;
        z[0] = z[0].clamp(-TRIM_AOA_LIMIT_RAD, TRIM_AOA_LIMIT_RAD);
        r = residual(ac, tas_mps, gamma_rad, air, mass_kg, &z);
    }
    if !converged || !z.iter().all(|v| v.is_finite()) {
        return Err(AircraftError::TrimNotConverged { tas_mps, gamma_rad });
    }
    if !(0.0..=1.0).contains(&z[2]) || z[2] == 0.0 {
        return Err(AircraftError::TrimOutOfLimits {
            what: "throttle",
            value: z[2],
        });
    }
    let lim = ac.params().actuators;
    let surfaces = [
        ("elevator", z[1], lim.elevator_travel_deg),
        ("aileron", z[3], lim.aileron_travel_deg),
        ("rudder", z[4], lim.rudder_travel_deg),
    ];
    for (what, value, travel_deg) in surfaces {
        if value.abs() > travel_deg.to_radians() {
            return Err(AircraftError::TrimOutOfLimits { what, value });
        }
    }
    let x = trim_state(tas_mps, gamma_rad, mass_kg, z[0]);
    let loads = ac.loads_with_rates(&x, &controls_of(&z), air, &Vector3::zeros());
    let aero = ac.aero_model();
    let c_lift_wing = aero.c_lift_wing(z[0]);
    let c_lift_max = a.c_lift_max;
    Ok(Trim {
        tas_mps,
        gamma_rad,
        mass_kg,
        aoa_rad: z[0],
        pitch_rad: z[0] + gamma_rad,
        elevator_rad: z[1],
        throttle: z[2],
        aileron_rad: z[3],
        rudder_rad: z[4],
        thrust_n: loads.thrust_n,
        power_w: loads.power_w,
        shaft_rps: loads.shaft_rps,
        c_lift_wing,
        aoa_margin_rad: aero.stall_aoa_rad() - z[0],
        load_factor_to_stall: c_lift_max / c_lift_wing,
        stall_speed_mps: tas_mps * (c_lift_wing / c_lift_max).sqrt(),
        side_accel_mps2: loads.f_ib_b_mps2.y,
    })
}

/// Flat-Earth small-perturbation rates of `s = [u, v, w, p, q, r, φ, θ]` (ψ is neutral).
fn flat_rate(ac: &Aircraft, trim: &Trim, air: &AirInputs, s: &SVector<f64, 8>) -> SVector<f64, 8> {
    let (phi, theta) = (s[6], s[7]);
    let w = Vector3::new(s[3], s[4], s[5]);
    let x = TruthState {
        pos: Geodetic {
            lat_rad: 0.0,
            lon_rad: 0.0,
            h_m: 0.0,
        },
        v_b_mps: Vector3::new(s[0], s[1], s[2]),
        q_nb: UnitQuaternion::from_euler_angles(phi, theta, 0.0),
        w_ib_b_rps: w,
        mass_kg: trim.mass_kg,
    };
    let loads = ac.loads_with_rates(&x, &trim.controls(), air, &w);
    let g_b = x
        .q_nb
        .inverse_transform_vector(&Vector3::new(0.0, 0.0, G0_MPS2));
    let v_dot = loads.f_ib_b_mps2 + g_b - w.cross(&x.v_b_mps);
    let phi_dot = w.x + (w.y * phi.sin() + w.z * phi.cos()) * theta.tan();
    let theta_dot = w.y * phi.cos() - w.z * phi.sin();
    let wd = loads.w_dot_ib_b_rps2;
    SVector::<f64, 8>::from_column_slice(&[
        v_dot.x, v_dot.y, v_dot.z, wd.x, wd.y, wd.z, phi_dot, theta_dot,
    ])
}

fn pair(l1: Complex<f64>, l2: Complex<f64>) -> ModePair {
    let omega_n = (l1 * l2).re.abs().sqrt();
    ModePair {
        omega_n_rps: omega_n,
        zeta: -(l1 + l2).re / (2.0 * omega_n),
    }
}

fn eigenvalues(m: &Matrix4<f64>) -> Result<[Complex<f64>; 4], AircraftError> {
    let schur = Schur::try_new(*m, 1e-14, 10_000).ok_or(AircraftError::Linearisation)?;
    let ev = schur.complex_eigenvalues();
    let mut out = [ev[0], ev[1], ev[2], ev[3]];
    out.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
    Ok(out)
}

/// Linear modes about `trim` (see [`Aircraft::linear_modes`]).
pub(super) fn modes(ac: &Aircraft, trim: &Trim, air: &AirInputs) -> Result<Modes, AircraftError> {
    let still = AirInputs {
        wind_ned_mps: Vector3::zeros(),
        turb_b_mps: Vector3::zeros(),
        turb_rate_b_rps: Vector3::zeros(),
        ..*air
    };
    let s0 = SVector::<f64, 8>::from_column_slice(&[
        trim.tas_mps * trim.aoa_rad.cos(),
        0.0,
        trim.tas_mps * trim.aoa_rad.sin(),
        0.0,
        0.0,
        0.0,
        0.0,
        trim.pitch_rad,
    ]);
    // Central differences; steps scaled to each variable (m/s, rad/s, rad).
    let steps = [1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6];
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    for (i, h) in steps.iter().enumerate() {
        let mut sp = s0;
        let mut sm = s0;
        sp[i] += h;
        sm[i] -= h;
        let col = (flat_rate(ac, trim, &still, &sp) - flat_rate(ac, trim, &still, &sm)) / (2.0 * h);
        a.set_column(i, &col);
    }
    let block = |idx: [usize; 4]| Matrix4::from_fn(|r, c| a[(idx[r], idx[c])]);
    let lon = eigenvalues(&block([0, 2, 4, 7]))?;
    let lat = eigenvalues(&block([1, 3, 5, 6]))?;
    // Lateral: the complex pair is the Dutch roll; of the two real roots the smaller is the
    // spiral, the larger the roll subsidence.
    let complex: Vec<usize> = (0..4).filter(|&i| lat[i].im.abs() > 1e-9).collect();
    let (dutch_roll, spiral, roll) = if complex.len() == 2 {
        let real: Vec<usize> = (0..4).filter(|i| !complex.contains(i)).collect();
        (
            pair(lat[complex[0]], lat[complex[1]]),
            lat[real[0]].re,
            lat[real[1]].re,
        )
    } else {
        (pair(lat[1], lat[2]), lat[0].re, lat[3].re)
    };
    Ok(Modes {
        short_period: pair(lon[2], lon[3]),
        phugoid: pair(lon[0], lon[1]),
        dutch_roll,
        roll_eigenvalue_ps: roll,
        spiral_eigenvalue_ps: spiral,
    })
}
