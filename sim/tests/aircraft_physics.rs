//! Physics acceptance tests of the simulated aircraft (`docs/AIRCRAFT.md`): balance at rest
//! on the rotating Earth, equivalence with the strapdown navigation equation, energy
//! conservation without drag and thrust, trim table and stall margin, linear modes and free
//! responses, propeller solver convergence, integrator order, configuration file.

use std::f64::consts::PI;

use ianav::env::atmosphere;
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav_sim::aircraft::dynamics::{self, BodyAccelerations};
use ianav_sim::aircraft::{
    AirInputs, Aircraft, AircraftError, AircraftParams, Controls, Trim, TruthState,
};
use nalgebra::{UnitQuaternion, Vector3};

fn isa(hp_m: f64) -> AirInputs {
    let p_pa = atmosphere::pressure_pa(hp_m);
    let temp_k = atmosphere::temperature_k(hp_m, 0.0);
    AirInputs {
        p_pa,
        temp_k,
        rho_kgpm3: atmosphere::density_kgpm3(p_pa, temp_k),
        wind_ned_mps: Vector3::zeros(),
        turb_b_mps: Vector3::zeros(),
        turb_rate_b_rps: Vector3::zeros(),
    }
}

/// State flying the trim `t` (no wind) at `pos` with heading `psi_rad`, rotating with NED.
fn trimmed_state(t: &Trim, pos: Geodetic, psi_rad: f64) -> TruthState {
    let q_nb = so3::from_euler_zyx(psi_rad, t.pitch_rad, 0.0);
    let v_b_mps = Vector3::new(t.aoa_rad.cos(), 0.0, t.aoa_rad.sin()) * t.tas_mps;
    let v_ned = q_nb * v_b_mps;
    let w_in_n = wgs84::omega_ie_n(pos.lat_rad) + wgs84::omega_en_n(&pos, &v_ned);
    TruthState {
        pos,
        v_b_mps,
        q_nb,
        w_ib_b_rps: q_nb.inverse() * w_in_n,
        mass_kg: t.mass_kg,
    }
}

fn start_pos(h_m: f64) -> Geodetic {
    Geodetic {
        lat_rad: 45_f64.to_radians(),
        lon_rad: (-90_f64).to_radians(),
        h_m,
    }
}

fn gravity(pos: &Geodetic) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, wgs84::normal_gravity_mps2(pos.lat_rad, pos.h_m))
}

#[test]
fn body_at_rest_on_the_rotating_earth_balances() {
    let ac = Aircraft::new(AircraftParams::default());
    let pos = start_pos(300.0);
    let q_nb = so3::from_euler_zyx(0.5, 0.08, -0.05);
    let w_ie_n = wgs84::omega_ie_n(pos.lat_rad);
    let x0 = TruthState {
        pos,
        v_b_mps: Vector3::zeros(),
        q_nb,
        w_ib_b_rps: q_nb.inverse() * w_ie_n,
        mass_kg: 19.5,
    };
    let g_n = gravity(&pos);
    let g = g_n.z;
    let inertia = ac.mass_model().inertia(x0.mass_kg);
    // Euler's equation with no external moment: ω̇ = −I⁻¹(ω × Iω).
    let euler = |x: &TruthState| inertia.solve(&-x.w_ib_b_rps.cross(&inertia.mul(&x.w_ib_b_rps)));

    // The specific force a stationary accelerometer measures is the one that makes v̇ = 0:
    // v̇ is affine in f, so f_req = −v̇(f = 0).
    let free = dynamics::state_rate(&x0, &g_n, &mut |x: &TruthState, _: &Vector3<f64>| {
        BodyAccelerations {
            f_ib_b_mps2: Vector3::zeros(),
            w_dot_ib_b_rps2: euler(x),
            mass_rate_kgps: 0.0,
        }
    });
    let f_req_n = q_nb * -free.v_dot_b_mps2;
    // Normal gravity already contains the centrifugal term, so f = −g^n exactly: 1e-6 g.
    assert!(
        (f_req_n - Vector3::new(0.0, 0.0, -g)).norm() < 1e-6 * g,
        "f_n {f_req_n:?}"
    );

    // With the support force the state is stationary: v̇, q̇ and the position rates vanish to
    // rounding; ω̇ is the tiny gyroscopic term of a body spinning at the Earth rate about a
    // non-principal axis, bounded by |ω|²·(I_max − I_min)/I_min.
    let mut support = |x: &TruthState, _: &Vector3<f64>| BodyAccelerations {
        f_ib_b_mps2: -(x.q_nb.inverse() * g_n),
        w_dot_ib_b_rps2: euler(x),
        mass_rate_kgps: 0.0,
    };
    let rate = dynamics::state_rate(&x0, &g_n, &mut support);
    assert!(rate.v_dot_b_mps2.norm() < 1e-14 * g);
    assert!(rate.q_dot_nb.norm() < 1e-18);
    assert!(rate.geodetic_rate.norm() < 1e-18);
    let w2 = wgs84::OMEGA_IE_RPS.powi(2);
    assert!(rate.w_dot_ib_b_rps2.norm() < w2 * (5.49 - 2.2) / 2.2 * 1.01);

    // 60 s of RK4 at 500 Hz: position drift below 1 mm.
    let mut x = x0;
    for _ in 0..30_000 {
        x = dynamics::rk4_step(&x, &g_n, 0.002, &mut support);
    }
    let drift_m = wgs84::ned_difference_m(&pos, &x.pos).norm();
    assert!(drift_m < 1e-3, "drift {drift_m} m");
    assert!(x.v_b_mps.norm() < 1e-9);
}

#[test]
fn body_velocity_equation_matches_the_strapdown_equation() {
    // v̇^n = C_nb(v̇^b + ω_nb^b × v^b) must equal C_nb f + g − (2ω_ie + ω_en) × v^n.
    let states = [
        (
            0.7,
            -1.2,
            2500.0,
            Vector3::new(28.0, 1.5, 2.0),
            (0.3, 0.05, 0.1),
            Vector3::new(0.1, -0.2, 0.05),
        ),
        (
            -0.3,
            2.9,
            100.0,
            Vector3::new(33.0, -2.0, -1.0),
            (-2.0, -0.1, 0.4),
            Vector3::new(-0.4, 0.3, -0.2),
        ),
        (
            1.3,
            0.1,
            3500.0,
            Vector3::new(24.0, 0.0, 3.0),
            (1.0, 0.2, -0.6),
            Vector3::new(0.0, 0.0, 0.8),
        ),
    ];
    for (lat, lon, h, v_b, (yaw, pitch, bank), w_ib) in states {
        let pos = Geodetic {
            lat_rad: lat,
            lon_rad: lon,
            h_m: h,
        };
        let q_nb = so3::from_euler_zyx(yaw, pitch, bank);
        let x = TruthState {
            pos,
            v_b_mps: v_b,
            q_nb,
            w_ib_b_rps: w_ib,
            mass_kg: 19.0,
        };
        let f_b = Vector3::new(1.0, -0.5, -9.0);
        let g_n = gravity(&pos);
        let rate = dynamics::state_rate(&x, &g_n, &mut |_: &TruthState, _: &Vector3<f64>| {
            BodyAccelerations {
                f_ib_b_mps2: f_b,
                w_dot_ib_b_rps2: Vector3::zeros(),
                mass_rate_kgps: 0.0,
            }
        });
        let v_n = q_nb * v_b;
        let w_ie = wgs84::omega_ie_n(lat);
        let w_en = wgs84::omega_en_n(&pos, &v_n);
        let w_nb_b = w_ib - q_nb.inverse() * (w_ie + w_en);
        assert!((dynamics::w_nb_b(&x) - w_nb_b).norm() < 1e-15);
        let v_dot_n = q_nb * (rate.v_dot_b_mps2 + w_nb_b.cross(&v_b));
        let strapdown = q_nb * f_b + g_n - (2.0 * w_ie + w_en).cross(&v_n);
        // Same quantity through two groupings of the terms: rounding level of |g| = 1e-14·10.
        assert!(
            (v_dot_n - strapdown).norm() < 1e-13,
            "{v_dot_n:?} vs {strapdown:?}"
        );
        // q̇ = ½ q ⊗ (0, ω_nb).
        let q_dot = x.q_nb.quaternion() * nalgebra::Quaternion::from_imag(w_nb_b) * 0.5;
        assert!((rate.q_dot_nb - q_dot).norm() < 1e-16);
        // Same function of v^n rotated by the matrix vs the quaternion: rounding of 30 m/s.
        let rates = wgs84::geodetic_rates(&pos, &v_n);
        assert!((rate.geodetic_rate.xy() - rates.xy()).norm() < 1e-14 * rates.xy().norm());
        assert!((rate.geodetic_rate.z - rates.z).abs() < 1e-13);
    }
}

/// Normal-gravity potential above the ellipsoid along the normal, `∫₀ʰ γ(φ, h') dh'`: γ is
/// quadratic in h, so Simpson's rule is exact.
fn potential_jpkg(pos: &Geodetic) -> f64 {
    let g = |h: f64| wgs84::normal_gravity_mps2(pos.lat_rad, h);
    pos.h_m / 6.0 * (g(0.0) + 4.0 * g(0.5 * pos.h_m) + g(pos.h_m))
}

fn specific_energy_jpkg(x: &TruthState) -> f64 {
    0.5 * x.v_b_mps.norm_squared() + potential_jpkg(&x.pos)
}

#[test]
fn energy_is_conserved_without_drag_and_thrust() {
    let air = isa(2500.0);
    let ac = Aircraft::new(AircraftParams::default());
    let trim = ac.trim(29.0, 0.0, &air, 19.5).unwrap();
    let mut params = AircraftParams::default();
    params.aero.drag_enabled = false;
    let glider = Aircraft::new(params);
    // Disturbed start heading north-east: 4 m/s fast (an undamped phugoid without drag), 2°
    // bank, 2° sideslip, pitch-rate kick. Elevator at trim, engine off, so no aileron/rudder
    // (they balanced the propeller torque).
    let mut x = trimmed_state(&trim, start_pos(2500.0), 45_f64.to_radians());
    x.v_b_mps = x.v_b_mps * (33.0 / 29.0) + Vector3::new(0.0, 33.0 * 2_f64.to_radians(), 0.0);
    x.q_nb *= UnitQuaternion::from_euler_angles(2_f64.to_radians(), 0.0, 0.0);
    x.w_ib_b_rps += Vector3::new(0.0, 0.1, 0.0);
    let u = Controls {
        throttle: 0.0,
        aileron_rad: 0.0,
        rudder_rad: 0.0,
        ..trim.controls()
    };
    let e0 = specific_energy_jpkg(&x);
    let (mut h_min, mut h_max, mut v_min, mut v_max) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let (mut worst, mut lat_work, mut worst_exact) = (0.0_f64, 0.0_f64, 0.0_f64);
    for _ in 0..30_000 {
        // The simulator's gravity: normal gravity at the start of the step, held over it.
        let g = gravity(&x.pos);
        let lat_old = x.pos.lat_rad;
        x = glider.step(&x, &u, &air, &g, 0.002);
        // A purely vertical field whose magnitude depends on latitude is not exactly
        // conservative: ∫γ dh changes with φ at constant h although the field does no work
        // on a horizontal displacement. Book that change separately.
        lat_work += potential_jpkg(&x.pos)
            - potential_jpkg(&Geodetic {
                lat_rad: lat_old,
                ..x.pos
            });
        let e = specific_energy_jpkg(&x);
        worst = worst.max((e - e0).abs());
        worst_exact = worst_exact.max((e - lat_work - e0).abs());
        h_min = h_min.min(x.pos.h_m);
        h_max = h_max.max(x.pos.h_m);
        let v = x.v_b_mps.norm();
        v_min = v_min.min(v);
        v_max = v_max.max(v);
    }
    println!(
        "energy: |ΔE|max = {worst:.3e} J/kg of {e0:.1}, {worst_exact:.3e} without the latitude term; \
         h {h_min:.1}..{h_max:.1} m, V {v_min:.2}..{v_max:.2} m/s"
    );
    // The flight really exchanges kinetic and potential energy.
    assert!(h_max - h_min > 20.0 && v_max - v_min > 8.0);
    // Acceptance criterion: 0.1 % of the specific energy.
    assert!(worst < 1e-3 * e0);
    // Latitude term: h·∂γ/∂φ·Δφ ≈ 2,500 m·0.052 m/s²/rad·(1.3 km/6.4e6 m) ≈ 0.03 J/kg.
    assert!(worst < 0.05);
    // Without it, what is left is integration error: RK4's 10-s state error at 2 ms is
    // ~1e-7 (test below); over 60 s at V ≈ 30 m/s that is V·δv ≈ 2e-5 J/kg; 1e-4 allows 5×.
    // (A spurious force of 1e-6 g along the velocity would add ~0.02 J/kg; gravity rotated
    // with the wrong attitude or a wrong ḣ would add joules.)
    assert!(worst_exact < 1e-4, "ΔE {worst_exact} J/kg");
}

#[test]
fn trim_table_within_limits_with_stall_margin() {
    let ac = Aircraft::new(AircraftParams::default());
    let limits = ac.params().actuators;
    let stall_aoa = ac.aero_model().stall_aoa_rad();
    println!("stall angle of attack {:.2}°", stall_aoa.to_degrees());
    println!(
        "  m kg  Hp m  V m/s  γ°   α°     θ°     δe°    δT     δa°    δr°   T N   P W   n rps  C_L   V/Vs  n_stall"
    );
    for mass in [19.5, 17.9] {
        for hp in [1500.0, 2500.0, 3500.0] {
            let air = isa(hp);
            for v in [24.0, 29.0, 34.0] {
                for gamma_deg in [0.0_f64, 2.0, -2.0] {
                    let t = ac.trim(v, gamma_deg.to_radians(), &air, mass).unwrap();
                    println!(
                        "{mass:6.2} {hp:5.0} {v:5.1} {gamma_deg:4.1} {:6.2} {:6.2} {:6.2} {:6.3} {:6.2} {:6.2} {:5.1} {:5.0} {:5.1} {:5.3} {:5.2} {:5.2}",
                        t.aoa_rad.to_degrees(),
                        t.pitch_rad.to_degrees(),
                        t.elevator_rad.to_degrees(),
                        t.throttle,
                        t.aileron_rad.to_degrees(),
                        t.rudder_rad.to_degrees(),
                        t.thrust_n,
                        t.power_w,
                        t.shaft_rps,
                        t.c_lift_wing,
                        v / t.stall_speed_mps,
                        t.load_factor_to_stall,
                    );
                    // Elevator: at least 3° of the travel left for manoeuvring.
                    assert!(t.elevator_rad.abs() < (limits.elevator_travel_deg - 3.0).to_radians());
                    assert!(
                        t.aileron_rad.abs() < 2_f64.to_radians()
                            && t.rudder_rad.abs() < 2_f64.to_radians()
                    );
                    // Throttle: 2° climb with at least 0.2 of throttle in reserve.
                    assert!(t.throttle > 0.0 && t.throttle < 0.8);
                    // Stall: speed ≥ 1.2 V_s (the usual approach margin) and α ≥ 4° from stall.
                    assert!(
                        v / t.stall_speed_mps >= 1.2,
                        "V/Vs {}",
                        v / t.stall_speed_mps
                    );
                    assert!(t.aoa_margin_rad > 4_f64.to_radians());
                    // Residual side acceleration of wings-level zero-sideslip trim is negligible.
                    assert!(t.side_accel_mps2.abs() < 0.02);
                    // The trim really is steady: loads + gravity ≈ 0 at the trimmed state.
                    let x = trimmed_state(&t, start_pos(hp), 0.3);
                    let l = ac.loads_with_rates(&x, &t.controls(), &air, &Vector3::zeros());
                    let residual = l.f_ib_b_mps2
                        + x.q_nb.inverse() * Vector3::new(0.0, 0.0, atmosphere::G0_MPS2);
                    // (Tolerances: trim residual 1e-10 in m/s² and moment coefficients, i.e.
                    // ≲ 1e-10·q̄Sb/I ≈ 5e-8 rad/s², plus the Earth-rate gyroscopic ~1e-8.)
                    assert!(residual.x.abs() < 1e-8 && residual.z.abs() < 1e-8);
                    assert!(l.w_dot_ib_b_rps2.norm() < 1e-7);
                }
            }
        }
    }
}

#[test]
fn trim_reports_infeasible_requests() {
    let ac = Aircraft::new(AircraftParams::default());
    let air = isa(3500.0);
    // A 25° climb at 24 m/s needs D + W sin γ ≈ 16 + 81 N, i.e. 2.3 kW of thrust power or
    // ~3.5 kW at the shaft: more than the 2.84 kW available at 3,500 m.
    assert!(ac.trim(24.0, 25_f64.to_radians(), &air, 19.5).is_err());
    assert_eq!(
        ac.trim(f64::NAN, 0.0, &air, 19.5),
        Err(AircraftError::TrimInputs)
    );
    // An empty tank has no engine.
    assert!(
        ac.trim(29.0, 0.0, &air, ac.params().mass.mass_empty_kg)
            .is_err()
    );
}

#[test]
fn linear_modes_are_stable_and_plausible() {
    let ac = Aircraft::new(AircraftParams::default());
    println!(
        "  m kg  Hp m  V m/s  γ°  | SP ωn ζ     | PH ωn ζ      | DR ωn ζ      | roll 1/s  spiral 1/s (T2 s)"
    );
    for mass in [19.5, 17.9] {
        for hp in [1500.0, 2500.0, 3500.0] {
            let air = isa(hp);
            for v in [24.0, 29.0, 34.0] {
                for gamma_deg in [0.0_f64, 2.0] {
                    let t = ac.trim(v, gamma_deg.to_radians(), &air, mass).unwrap();
                    let m = ac.linear_modes(&t, &air).unwrap();
                    let t2 = if m.spiral_eigenvalue_ps > 0.0 {
                        2_f64.ln() / m.spiral_eigenvalue_ps
                    } else {
                        f64::INFINITY
                    };
                    println!(
                        "{mass:6.2} {hp:5.0} {v:5.1} {gamma_deg:4.1} | {:5.2} {:5.3} | {:5.3} {:6.3} | {:5.2} {:5.3} | {:7.2} {:8.4} ({t2:.0})",
                        m.short_period.omega_n_rps,
                        m.short_period.zeta,
                        m.phugoid.omega_n_rps,
                        m.phugoid.zeta,
                        m.dutch_roll.omega_n_rps,
                        m.dutch_roll.zeta,
                        m.roll_eigenvalue_ps,
                        m.spiral_eigenvalue_ps,
                    );
                    // Short period well damped (design target: ζ > 0.4), frequency of a small UAV.
                    assert!(
                        m.short_period.zeta > 0.4
                            && (2.0..15.0).contains(&m.short_period.omega_n_rps)
                    );
                    // Phugoid: Lanchester ω ≈ √2·g/V, lightly damped (ζ ≈ 1/(√2·L/D) ≈ 0.07).
                    let lanchester = 2_f64.sqrt() * atmosphere::G0_MPS2 / v;
                    assert!((m.phugoid.omega_n_rps / lanchester - 1.0).abs() < 0.25);
                    assert!(m.phugoid.zeta > 0.0 && m.phugoid.zeta < 0.3);
                    // Dutch roll damped (MIL-F-8785C level 2: ζ ≥ 0.02).
                    assert!(m.dutch_roll.zeta > 0.02 && m.dutch_roll.omega_n_rps > 1.0);
                    // Roll subsidence fast (τ < 0.3 s); spiral slow: time to double > 12 s
                    // (MIL-F-8785C level 1 for flight phases A and C; level 2 needs 8 s).
                    assert!(m.roll_eigenvalue_ps < -1.0 / 0.3);
                    assert!(m.spiral_eigenvalue_ps < 2_f64.ln() / 12.0);
                }
            }
        }
    }
}

#[test]
fn free_response_short_period_and_dutch_roll_damp_out() {
    let air = isa(2500.0);
    let ac = Aircraft::new(AircraftParams::default());
    let trim = ac.trim(29.0, 0.0, &air, 19.5).unwrap();
    let x_trim = trimmed_state(&trim, start_pos(2500.0), 0.0);
    let mut x = x_trim;
    // Pitch-rate kick of 0.2 rad/s and a 3° sideslip.
    x.w_ib_b_rps += Vector3::new(0.0, 0.2, 0.0);
    x.v_b_mps =
        nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 3_f64.to_radians()) * x.v_b_mps;
    let u = trim.controls();
    let dt = 0.002;
    let (mut q_late, mut beta_early, mut beta_late) = (0.0_f64, 0.0_f64, 0.0_f64);
    for k in 1..=5000 {
        x = ac.step(&x, &u, &air, &gravity(&x.pos), dt);
        let t = f64::from(k) * dt;
        let w_nb = dynamics::w_nb_b(&x);
        let beta = ac.loads(&x, &u, &air).air.aos_rad;
        if (2.0..4.0).contains(&t) {
            beta_early = beta_early.max(beta.abs());
        }
        if (3.0..=5.0).contains(&t) {
            q_late = q_late.max(w_nb.y.abs());
        }
        if t >= 8.0 {
            beta_late = beta_late.max(beta.abs());
        }
    }
    println!(
        "free response: |q| 3–5 s {q_late:.4} rad/s; |β| 2–4 s {beta_early:.4}, 8–10 s {beta_late:.4} rad"
    );
    // Short period ζω ≈ 2.7 1/s: after 3 s the kick is down by e^-8; what remains is the
    // phugoid's slow pitch rate (ω_ph·Δθ ≈ 0.4·0.03 rad/s).
    assert!(q_late < 0.1 * 0.2);
    // Dutch roll ζω ≈ 0.35 1/s: the envelope 6 s later is down by e^-2 ≈ 0.14 (0.3 allows
    // for the slow spiral/roll coupling).
    assert!(beta_late < 0.3 * beta_early.max(1e-4));
    assert!(beta_late < 0.3 * 3_f64.to_radians());
}

#[test]
fn propeller_solver_converges_across_the_envelope() {
    let ac = Aircraft::new(AircraftParams::default());
    let prop = ac.propulsion();
    let pp = *prop.params();
    let d = pp.prop_diameter_m;
    let mut worst = 0.0_f64;
    let mut max_iterations = 0;
    for hp in [0.0, 1500.0, 2500.0, 3500.0, 4500.0] {
        let air = isa(hp);
        for throttle in [0.02, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0] {
            let power = prop.available_power_w(throttle, air.p_pa, air.temp_k);
            for v in [0.0, 5.0, 15.0, 20.0, 24.0, 29.0, 34.0, 40.0, 50.0] {
                for warm in [None, Some(27.0), Some(70.0), Some(129.0)] {
                    let (n, it) = prop.solve_shaft_speed(power, air.rho_kgpm3, v, warm);
                    max_iterations = max_iterations.max(it);
                    if n > pp.shaft_min_rps && n < pp.shaft_max_rps {
                        let absorbed =
                            prop.c_power(v / (n * d)) * air.rho_kgpm3 * n.powi(3) * d.powi(5);
                        worst = worst.max((absorbed / power - 1.0).abs());
                    }
                }
            }
        }
    }
    println!("propeller: worst relative residual {worst:.2e}, max iterations {max_iterations}");
    assert!(worst < 1e-9);
    assert!(max_iterations <= 20);

    // Plausibility. Static, sea level, full throttle: n = (P/(ρ C_P0 D⁵))^(1/3) ≈ 110 rev/s
    // and T = C_T0 ρ n² D⁴ ≈ 125 N, between 0.4 and 0.8 of the weight.
    let air = isa(0.0);
    let s = prop.evaluate(1.0, air.p_pa, air.temp_k, air.rho_kgpm3, 0.0, true);
    assert!(
        (100.0..120.0).contains(&s.shaft_rps) && (0.4..0.8).contains(&(s.thrust_n / (19.5 * 9.81)))
    );
    // Full throttle at sea level sits exactly on the corner of min(δ_T, δ/√θ), rounded by
    // w/4 = 0.005 of P_max.
    assert!(
        (s.power_w / (4180.0 * (1.0 - 0.005)) - 1.0).abs() < 1e-9,
        "{}",
        s.power_w
    );
    // Cruise (29 m/s, 2,500 m, 700 W): efficiency T·V/P between 0.6 and the curve peak.
    let air = isa(2500.0);
    let c = prop.evaluate_at_power(700.0, air.rho_kgpm3, 29.0, None).0;
    let eta = c.thrust_n * 29.0 / c.power_w;
    assert!((0.6..0.78).contains(&eta), "η {eta}");
    assert!((c.torque_x_nm + 700.0 / (2.0 * PI * c.shaft_rps)).abs() < 1e-9);
    assert!((c.fuel_flow_kgps - 700.0e-7).abs() < 1e-15);
}

/// Error of a state against a reference: NED position (m) + velocity (m/s) + attitude (rad,
/// scaled by 30 m/s into metres-per-second-like units).
fn state_error(a: &TruthState, b: &TruthState) -> f64 {
    wgs84::ned_difference_m(&b.pos, &a.pos).norm()
        + (a.v_b_mps - b.v_b_mps).norm()
        + 30.0 * so3::minus(&a.q_nb, &b.q_nb).norm()
        + (a.w_ib_b_rps - b.w_ib_b_rps).norm()
}

#[test]
fn integrators_converge_at_their_order() {
    let air = isa(2500.0);
    let ac = Aircraft::new(AircraftParams::default());
    let trim = ac.trim(29.0, 0.0, &air, 19.5).unwrap();
    let mut x0 = trimmed_state(&trim, start_pos(2500.0), 0.3);
    x0.w_ib_b_rps += Vector3::new(0.3, 0.2, -0.1);
    let u = Controls {
        aileron_rad: 0.02,
        rudder_rad: -0.01,
        ..trim.controls()
    };
    let g = gravity(&x0.pos);
    let run = |dt: f64, heun: bool| {
        let mut x = x0;
        let n = (10.0 / dt).round() as usize;
        for _ in 0..n {
            x = if heun {
                ac.step_heun(&x, &u, &air, &g, dt)
            } else {
                ac.step(&x, &u, &air, &g, dt)
            };
        }
        x
    };
    // RK4: error ∝ dt⁴, so successive differences shrink 16× per halving.
    let (a, b, c) = (run(0.02, false), run(0.01, false), run(0.005, false));
    let ratio4 = state_error(&a, &b) / state_error(&b, &c);
    // Heun: ∝ dt², 4× per halving.
    let (a2, b2, c2) = (run(0.008, true), run(0.004, true), run(0.002, true));
    let ratio2 = state_error(&a2, &b2) / state_error(&b2, &c2);
    // Errors at the simulator's 2 ms step, from Richardson extrapolation.
    let rk4_2ms = state_error(&run(0.002, false), &run(0.001, false)) * 16.0 / 15.0;
    let heun_2ms = state_error(&b2, &c2) / 3.0;
    println!(
        "RK4 ratio {ratio4:.2}, Heun ratio {ratio2:.2}; 10 s error at 2 ms: RK4 {rk4_2ms:.2e}, Heun {heun_2ms:.2e}"
    );
    assert!((12.0..20.0).contains(&ratio4), "RK4 ratio {ratio4}");
    assert!((3.0..5.0).contains(&ratio2), "Heun ratio {ratio2}");
    assert!(rk4_2ms < heun_2ms);
}

#[test]
fn configuration_file_matches_the_defaults_and_errors_name_the_field() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/aircraft.toml");
    let from_file = AircraftParams::from_toml_file(&path).unwrap();
    assert_eq!(from_file, AircraftParams::default());
    let text = std::fs::read_to_string(&path).unwrap();
    let unknown = text.replace("c_drag_0 =", "c_drag_zero =");
    let err = AircraftParams::from_toml_str(&unknown)
        .unwrap_err()
        .to_string();
    assert!(err.contains("c_drag_zero"), "{err}");
    let invalid = text.replace("mass_empty_kg = 17.835", "mass_empty_kg = 25.0");
    let err = AircraftParams::from_toml_str(&invalid)
        .unwrap_err()
        .to_string();
    assert!(err.contains("mass.mass_full_kg"), "{err}");
    let invalid = text.replace("c_power_1 = 0.05", "c_power_1 = -0.05");
    let err = AircraftParams::from_toml_str(&invalid)
        .unwrap_err()
        .to_string();
    assert!(err.contains("propulsion.c_power_1"), "{err}");
}

#[test]
fn cg_shift_transfers_the_moment_and_inertia_follows_the_mass() {
    let ac = Aircraft::new(AircraftParams::default());
    let air = isa(2500.0);
    let trim = ac.trim(29.0, 0.0, &air, 19.715).unwrap();
    let full = trimmed_state(&trim, start_pos(2500.0), 0.0);
    let empty = TruthState {
        mass_kg: 17.9,
        ..full
    };
    let u = trim.controls();
    let (lf, le) = (
        ac.loads_with_rates(&full, &u, &air, &Vector3::zeros()),
        ac.loads_with_rates(&empty, &u, &air, &Vector3::zeros()),
    );
    // Same air, same forces; the moment about the CG changes by (r_ref − r_cg) × F.
    let force = lf.f_ib_b_mps2 * 19.715;
    assert!((le.f_ib_b_mps2 * 17.9 - force).norm() < 1e-9);
    let arm = ac.cg_from_reference_b_m(19.715) - ac.cg_from_reference_b_m(17.9);
    assert!((le.moment_b_nm - lf.moment_b_nm - arm.cross(&force)).norm() < 1e-9);
    // The CG moves 12 mm forward when the tank empties: nose-down pitching moment.
    assert!(arm.x < 0.0 && le.moment_b_nm.y < lf.moment_b_nm.y);
    // Fuel burns at c_f·P and the engine stops at the empty mass.
    assert!((lf.fuel_flow_kgps - 1e-7 * lf.power_w).abs() < 1e-15 && lf.power_w > 100.0);
    let dry = TruthState {
        mass_kg: ac.params().mass.mass_empty_kg,
        ..full
    };
    let ld = ac.loads(&dry, &u, &air);
    assert_eq!(
        (ld.thrust_n, ld.fuel_flow_kgps, ld.shaft_rps),
        (0.0, 0.0, 0.0)
    );
}

#[test]
fn air_relative_motion_subtracts_wind_and_is_robust_at_zero_airspeed() {
    let q_nb = so3::from_euler_zyx(0.4, 0.05, 0.1);
    let wind_ned = Vector3::new(5.0, -3.0, 0.5);
    let turb_b = Vector3::new(0.2, -0.1, 0.3);
    let v_air_b = Vector3::new(28.0, 1.0, 2.0);
    let x = TruthState {
        pos: start_pos(1000.0),
        v_b_mps: v_air_b + q_nb.inverse() * wind_ned + turb_b,
        q_nb,
        w_ib_b_rps: Vector3::zeros(),
        mass_kg: 19.5,
    };
    let air = AirInputs {
        wind_ned_mps: wind_ned,
        turb_b_mps: turb_b,
        ..isa(1000.0)
    };
    let rel = ianav_sim::aircraft::air_relative(&x, &air);
    assert!((rel.v_tas_b_mps - v_air_b).norm() < 1e-12);
    assert!((rel.aoa_rad - (2.0_f64).atan2(28.0)).abs() < 1e-13);
    assert!((rel.aos_rad - (1.0 / v_air_b.norm()).asin()).abs() < 1e-13);
    // Moving with the air: V = 0, angles 0, loads finite.
    let still = TruthState {
        v_b_mps: q_nb.inverse() * wind_ned + turb_b,
        ..x
    };
    let rel0 = ianav_sim::aircraft::air_relative(&still, &air);
    assert!(rel0.tas_mps < 1e-12 && rel0.aos_rad.abs() < 1e-6);
    let ac = Aircraft::new(AircraftParams::default());
    let l = ac.loads(
        &still,
        &Controls {
            throttle: 0.5,
            ..Controls::default()
        },
        &air,
    );
    assert!(
        l.f_ib_b_mps2
            .iter()
            .chain(l.w_dot_ib_b_rps2.iter())
            .all(|v| v.is_finite())
    );
    // NaN controls are treated as neutral, not propagated.
    let nan = Controls {
        throttle: f64::NAN,
        elevator_rad: f64::NAN,
        aileron_rad: 0.0,
        rudder_rad: 0.0,
    };
    let l = ac.loads(&x, &nan, &air);
    assert!(l.f_ib_b_mps2.iter().all(|v| v.is_finite()) && l.thrust_n == 0.0);
}
