//! Tests of the position filter, the GNSS-phase estimates and the GNSS-denied navigation.

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use super::denied::*;
use super::gnss_phase::*;
use super::*;
use crate::env::atmosphere::{self, AtmosphereOffsets};
use crate::ins::air_data;
use crate::ins::config::{AirDataFilterConfig, PositionFilterConfig};
use crate::math::wgs84::Geodetic;

fn init() -> PositionInit {
    PositionInit {
        pos: Geodetic {
            lat_rad: 0.78,
            lon_rad: -1.57,
            h_m: 1500.0,
        },
        v_n: Vector3::new(20.0, -15.0, 1.0),
        f_b: Vector3::new(0.2, 0.1, -9.8),
        e_acc: Vector3::new(0.1, -0.1, 0.05),
        e_acc_sigma: Vector3::repeat(1e-3),
    }
}

#[test]
fn transition_matches_matrix_exponential() {
    let cfg = PositionFilterConfig {
        q_position_m2: 0.0,
        q_velocity_m2ps2: 0.0,
        q_specific_force_m2ps4: 0.0,
        q_e_acc_m2ps4: 0.0,
        ..PositionFilterConfig::default()
    };
    let mut f = GnssFilter::new(&cfg, &init());
    let mut p = SMatrix::<f64, NX, NX>::identity();
    for i in 0..NX {
        for j in 0..NX {
            p[(i, j)] += 0.2 / (1.0 + (i as f64 - j as f64).abs());
        }
    }
    f.p = p;
    let q_nb = so3::from_euler_zyx(0.4, 0.1, -0.2);
    let dt = 0.05;
    let w = wgs84::omega_ie_n(f.pos.lat_rad) * 2.0 + wgs84::omega_en_n(&f.pos, &f.v_n);
    let mut a = SMatrix::<f64, NX, NX>::zeros();
    a.fixed_view_mut::<3, 3>(P, V).fill_with_identity();
    a.fixed_view_mut::<3, 3>(V, V).copy_from(&(-so3::skew(&w)));
    a.fixed_view_mut::<3, 3>(V, F)
        .copy_from(&q_nb.to_rotation_matrix().into_inner());
    let big_f = (a * dt).exp();
    let expect = big_f * p * big_f.transpose();
    f.predict(&cfg, &q_nb, dt, 1.0);
    // Closed form is exact up to (|Ω|Δt)³ ≈ (1.5e-4·0.05)³ ≈ 4e-16 relative; the products
    // of 12×12 matrices round at ~1e-15 relative.
    assert!(
        (f.p - expect).norm() < 1e-13 * expect.norm(),
        "{}",
        f.p - expect
    );
}

#[test]
fn air_velocity_jacobians_match_finite_differences() {
    let (v0, j) = v_tas_b(30.0, 0.06, -0.03);
    let e = 1e-6;
    for k in 0..3 {
        let mut a = [30.0, 0.06, -0.03];
        let mut b = a;
        a[k] += e;
        b[k] -= e;
        let fd = (v_tas_b(a[0], a[1], a[2]).0 - v_tas_b(b[0], b[1], b[2]).0) / (2.0 * e);
        // Truncation e²/6·|v'''| ≤ 30e-12; rounding ε·30/e ≈ 3e-9.
        assert!((fd - j.column(k)).norm() < 1e-8, "{k}");
    }
    assert!((v0.norm() - 30.0).abs() < 1e-12);
    // The attitude error of the dead reckoning: (Ĉ − C) v = [Ĉ v]× Ĉ δθ_b for
    // C = Ĉ Exp(δθ_b), to first order (second order |δθ|²·30/2 ≈ 1.5e-11 m/s).
    let q = so3::from_euler_zyx(1.0, 0.1, 0.3);
    let c = q.to_rotation_matrix().into_inner();
    for k in 0..3 {
        let mut d = Vector3::zeros();
        d[k] = e;
        let diff = q * v0 - so3::plus(&q, &d) * v0;
        let model = so3::skew(&(c * v0)) * (c * d);
        assert!((diff - model).norm() < 1e-9, "{k}: {diff} vs {model}");
    }
    // The air-data part: Jacobian of v_TAS^b rotated to NED.
    let mut x = SVector::<f64, { air_data::NX }>::zeros();
    x[air_data::TAS] = 30.0;
    x[air_data::AOA] = 0.06;
    x[air_data::AOS] = -0.03;
    let mut p_air = SMatrix::<f64, { air_data::NX }, { air_data::NX }>::zeros();
    p_air[(air_data::TAS, air_data::TAS)] = 0.04;
    let (v_n, cov) = air_velocity_n(&q, &x, &p_air);
    let (vb, jb) = v_tas_b(30.0, 0.06, -0.03);
    assert!((v_n - c * vb).norm() < 1e-12);
    let col = c * jb.column(0);
    assert!((cov - col * col.transpose() * 0.04).norm() < 1e-12);
}

#[test]
fn baro_altitude_derivatives_match_finite_differences() {
    let (hp, dt, dp) = (2500.0, 7.0, -900.0);
    let (h0, d) = baro_altitude(hp, dt, dp);
    let fd = |f: &dyn Fn(f64) -> f64, e: f64| (f(e) - f(-e)) / (2.0 * e);
    let d_hp = fd(&|e| baro_altitude(hp + e, dt, dp).0, 1e-2);
    let d_dt = fd(&|e| baro_altitude(hp, dt + e, dp).0, 1e-3);
    let d_dp = fd(&|e| baro_altitude(hp, dt, dp + e).0, 1e-1);
    // h is smooth on scales of km, K and kPa: truncation ≪ 1e-6, rounding ≈ ε·h/e ≈ 3e-11/e.
    assert!((d.x - d_hp).abs() < 1e-7, "{} {d_hp}", d.x);
    assert!((d.y - d_dt).abs() < 1e-6, "{} {d_dt}", d.y);
    assert!((d.z - d_dp).abs() < 1e-7, "{} {d_dp}", d.z);
    // Consistency with the atmosphere module.
    let off = AtmosphereOffsets {
        delta_t_k: dt,
        delta_p_pa: dp,
    };
    assert!((h0 - atmosphere::geometric_from_pressure_altitude_m(hp, &off)).abs() < 1e-9);
}

#[test]
fn raw_delta_p_inverts_baro_altitude_and_its_variance_matches() {
    let (hp, dt, dp) = (2000.0, -5.0, 1200.0);
    let (h, d) = baro_altitude(hp, dt, dp);
    let (dp_back, var) = raw_delta_p(hp, 0.0, h, 1.0, dt);
    assert!((dp_back - dp).abs() < 1e-6, "{dp_back}");
    // 1 m² of altitude variance ↔ (∂Δp/∂h)² = 1/(∂h/∂Δp)² (dH/dh ≈ 1 to 5e-4).
    let expect = 1.0 / (d.z * d.z);
    assert!((var - expect).abs() < 2e-3 * expect, "{var} {expect}");
}

#[test]
fn ned_offset_and_displace_are_inverse() {
    let mut p = init().pos;
    let from = p;
    let d = Vector3::new(80.0, -60.0, 5.0);
    displace(&mut p, &d);
    let back = ned_offset_m(&from, &p);
    // Second-order terms ≈ |d|²/R ≈ 1e4/6.4e6 ≈ 1.6e-3 m.
    assert!((back - d).norm() < 2e-3, "{back}");
}

/// The window fractions of a unit Gauss–Markov gust against many simulated windows
/// (the latest sample and the mean of the last `W`, from the stationary start).
#[test]
fn gust_in_window_fractions_match_simulation() {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut normal = move || crate::ins::tests::standard_normal(&mut rng);
    let (tau_c, w, dt, runs): (f64, f64, f64, u32) = (10.0, 30.0, 0.05, 4000);
    let a = (-dt / tau_c).exp();
    let steps = (w / dt) as usize;
    let (mut s_mm, mut s_gm, mut s_dd) = (0.0, 0.0, 0.0);
    for _ in 0..runs {
        let mut g = normal();
        let mut sum = 0.0;
        for _ in 0..steps {
            g = a * g + (1.0 - a * a).sqrt() * normal();
            sum += g;
        }
        let m = sum / steps as f64;
        s_mm += m * m;
        s_gm += g * m;
        s_dd += (g - m) * (g - m);
    }
    let n = f64::from(runs);
    let f = GustInWindow::new(tau_c, w);
    // Sample second moments of unit-scale Gaussians: standard error ≤ √(2/n); 5 of them.
    let tol = 5.0 * (2.0 / n).sqrt();
    for (got, want, what) in [
        (s_mm / n, f.mean_var, "var m"),
        (s_gm / n, f.cov_with_latest, "cov(g, m)"),
        (s_dd / n, f.deviation_var, "var(g − m)"),
    ] {
        assert!(
            (got - want).abs() < tol,
            "{what}: {got:.4} vs {want:.4} (tol {tol:.3})"
        );
    }
    // Far shorter than the window: the mean holds 2τ_c/W of the variance, the latest
    // sample τ_c/W of it (a first-order filter of W/2 would hold 2τ_c/W of both).
    let f = GustInWindow::new(1.0, 1000.0);
    assert!((f.mean_var - 2e-3).abs() < 1e-5 && (f.cov_with_latest - 1e-3).abs() < 1e-6);
}

/// Exponentially correlated (first-order Gauss–Markov) gusts along the body axes fed as
/// the raw wind: the measured per-axis variance is the gusts' σ².
/// GNSS-phase estimates fed only with a raw wind (fixed pressure altitude, height, ΔT and
/// wind covariance): the wind and turbulence tests.
fn wind_only_estimates(
    cfg: &PositionFilterConfig,
    q_nb: &UnitQuaternion<f64>,
    wind_n: Vector3<f64>,
    v_air_n: Vector3<f64>,
) -> GnssPhaseEstimates {
    GnssPhaseEstimates::new(
        cfg.lpf_window_s,
        cfg.turbulence_integral_scale_m,
        q_nb,
        2000.0,
        1.0,
        2100.0,
        1.0,
        5.0,
        wind_n,
        Matrix3::identity() * 0.01,
        v_air_n,
    )
}

fn step_wind_only(
    est: &mut GnssPhaseEstimates,
    dt_s: f64,
    q_nb: &UnitQuaternion<f64>,
    tas_mps: f64,
    wind_n: Vector3<f64>,
    v_air_n: Vector3<f64>,
) {
    est.step(
        dt_s,
        &air_inputs(q_nb, tas_mps, v_air_n),
        &GnssFilterState {
            h_m: 2100.0,
            var_h_m2: 1.0,
            v_n: wind_n + v_air_n,
            v_cov: Matrix3::identity() * 0.01,
        },
    );
}

#[test]
fn gust_intensity_is_measured_from_the_raw_wind() {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut normal = move || crate::ins::tests::standard_normal(&mut rng);
    let cfg = PositionFilterConfig::default();
    let scale = cfg.turbulence_integral_scale_m;
    let (tas, dt, t_end) = (30.0, 0.05, 20_000.0);
    let sigma = Vector3::new(0.9, 0.6, 0.5);
    let q_nb = so3::from_euler_zyx(2.0, 0.1, 0.3);
    let c_nb = q_nb.to_rotation_matrix().into_inner();
    let w0 = Vector3::new(5.0, -3.0, 0.0);
    let mut est = wind_only_estimates(&cfg, &q_nb, w0, c_nb * Vector3::new(tas, 0.0, 0.0));
    let a = Vector3::from_fn(|i, _| (-dt * tas / scale[i]).exp());
    let mut g = Vector3::from_fn(|i, _| sigma[i] * normal());
    let steps = (t_end / dt) as usize;
    // One estimate per window (each from that window's samples only), after the first.
    let per_window = (cfg.lpf_window_s / dt).round() as usize;
    let mut estimates: Vec<Vector3<f64>> = Vec::new();
    for k in 1..=steps {
        for i in 0..3 {
            g[i] = a[i] * g[i] + sigma[i] * (1.0 - a[i] * a[i]).sqrt() * normal();
        }
        let wind = w0 + c_nb * g;
        step_wind_only(
            &mut est,
            dt,
            &q_nb,
            tas,
            wind,
            c_nb * Vector3::new(tas, 0.0, 0.0),
        );
        if k % per_window == 0 && k > per_window {
            estimates.push(est.gust(tas).0);
        }
    }
    let (_, held_var, held_cov) = est.gust(tas);
    let n = estimates.len() as f64;
    for i in 0..3 {
        let tau_c = scale[i] / tas;
        // Unbiased: the mean of the window estimates within 5 standard errors of σ²
        // (the windows hold a few correlation times each, so they are nearly independent).
        let mean = estimates.iter().map(|e| e[i]).sum::<f64>() / n;
        let var_est = estimates.iter().map(|e| (e[i] - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let s2 = sigma[i] * sigma[i];
        assert!(
            (mean - s2).abs() < 5.0 * (var_est / n).sqrt(),
            "axis {i}: mean {mean} vs {s2} (standard error {})",
            (var_est / n).sqrt()
        );
        // And useful: one window's estimate scatters by less than σ² itself.
        assert!(
            var_est.sqrt() < s2,
            "axis {i}: scatter {} vs {s2}",
            var_est.sqrt()
        );
        // The window covers its length ± one 1-s bin; both fractions fall with it.
        let at = |w: f64| GustInWindow::new(tau_c, w);
        let (lo, hi) = (at(cfg.lpf_window_s + 1.0), at(cfg.lpf_window_s - 1.0));
        assert!((lo.mean_var..=hi.mean_var).contains(&held_var[i]), "{i}");
        assert!(
            (lo.cov_with_latest..=hi.cov_with_latest).contains(&held_cov[i]),
            "{i}"
        );
    }
}

#[test]
fn a_wind_change_older_than_the_window_is_not_taken_for_turbulence() {
    // Circling in a steady wind, which steps by 6 m/s (a SITL setting the wind after the
    // climb, a front): while the window holds the step the wind estimate is that uncertain
    // and the spread says so; one window later the wind is steady again and no gust is left.
    let cfg = PositionFilterConfig::default();
    let (tas, dt) = (20.0, 0.01);
    let w0 = Vector3::new(1.0, -2.0, 0.0);
    let q_at = |t: f64| so3::from_euler_zyx(0.1 * t, 0.3, 0.05);
    let v_air = |t: f64| q_at(t).to_rotation_matrix().into_inner() * Vector3::new(tas, 0.0, 0.0);
    let mut est = wind_only_estimates(&cfg, &q_at(0.0), w0, v_air(0.0));
    let mut t = 0.0;
    let mut fly = |until_s: f64, wind: Vector3<f64>, est: &mut GnssPhaseEstimates| {
        while t < until_s {
            t += dt;
            step_wind_only(est, dt, &q_at(t), tas, wind, v_air(t));
        }
    };
    fly(200.0, w0, &mut est);
    assert!(est.gust(tas).0.max() < 1e-9, "{}", est.gust(tas).0);
    let w1 = w0 + Vector3::new(6.0, 0.0, 0.0);
    fly(260.0, w1, &mut est);
    let inside = est.gust(tas).0;
    assert!(inside.x + inside.y > 1.0, "{inside}");
    fly(260.0 + cfg.lpf_window_s + 2.0, w1, &mut est);
    let after = est.gust(tas).0;
    assert!(after.max() < 1e-9, "{after}");
    assert!((est.wind().0 - w1).norm() < 1e-9);
}

/// A GNSS filter with zero covariance, the air-data bias σ's zeroed and a 30 m/s air
/// state: the dead-reckoning tests switch on one error source at a time.
fn denied_setup() -> (
    PositionFilterConfig,
    AirDataFilterConfig,
    SVector<f64, { air_data::NX }>,
    GnssFilter,
) {
    let cfg = PositionFilterConfig {
        q_position_m2: 0.0,
        ..PositionFilterConfig::default()
    };
    let mut f = GnssFilter::new(&cfg, &init());
    f.p = SMatrix::zeros();
    let air_cfg = AirDataFilterConfig {
        tas_bias_sigma_mps: 0.0,
        aoa_bias_sigma_deg: 0.0,
        aos_bias_sigma_deg: 0.0,
        ..AirDataFilterConfig::default()
    };
    let mut air_x = SVector::<f64, { air_data::NX }>::zeros();
    air_x[air_data::TAS] = 30.0;
    (cfg, air_cfg, air_x, f)
}

/// GNSS-phase estimates of a calm wind, started with the NED air velocity `v_air_n`.
fn calm_estimates(cfg: &PositionFilterConfig, v_air_n: Vector3<f64>) -> GnssPhaseEstimates {
    GnssPhaseEstimates::new(
        cfg.lpf_window_s,
        cfg.turbulence_integral_scale_m,
        &UnitQuaternion::identity(),
        2000.0,
        1.0,
        2100.0,
        1.0,
        5.0,
        Vector3::zeros(),
        Matrix3::zeros(),
        v_air_n,
    )
}

/// `n` dead-reckoning steps of `dt_s` at 30 m/s with attitude `q_nb`, air velocity
/// `v_air_n` and no air-data noise.
/// Air data at 2,000 m of pressure altitude, ΔT 5 K, unit `[T, Hp]` covariance and no
/// white air-velocity uncertainty.
fn air_inputs(q_nb: &UnitQuaternion<f64>, tas_mps: f64, v_air_n: Vector3<f64>) -> AirInputs {
    AirInputs {
        q_nb: *q_nb,
        tas_mps,
        hp_m: 2000.0,
        delta_t_k: 5.0,
        t_hp_cov: Matrix2::identity(),
        v_air_n,
        v_air_cov: Matrix3::zeros(),
    }
}

fn propagate_steps(
    nav: &mut DeniedNav,
    cfg: &PositionFilterConfig,
    q_nb: &UnitQuaternion<f64>,
    v_air_n: &Vector3<f64>,
    dt_s: f64,
    n: usize,
) {
    for _ in 0..n {
        nav.propagate(
            cfg,
            &air_inputs(q_nb, 30.0, *v_air_n),
            SubSteps {
                dt_s,
                n: 1,
                q_scale: 1.0,
            },
        );
    }
}

/// With only the gust uncertain, the dead-reckoning position variance along a straight
/// leg is that of an integrated Gauss–Markov process, `2σ²τ (T − τ (1 − e^{−T/τ}))`, and
/// the velocity variance stays σ².
#[test]
fn dead_reckoning_integrates_the_gust_as_a_gauss_markov_process() {
    let (cfg, air_cfg, air_x, f) = denied_setup();
    let est = calm_estimates(&cfg, Vector3::new(30.0, 0.0, 0.0));
    let mut nav = DeniedNav::new(
        &cfg,
        &air_cfg,
        &air_x,
        [false; 2],
        &Matrix3::zeros(),
        &f,
        &est,
    );
    let sigma2 = Vector3::new(0.81, 0.36, 0.25);
    nav.gust_var_b = sigma2;
    nav.p_dr = SMatrix::zeros();
    nav.p_dr
        .fixed_view_mut::<3, 3>(DR_G, DR_G)
        .copy_from(&Matrix3::from_diagonal(&sigma2));
    // Heading 90°: body x is east, body y is south.
    let q_nb = so3::from_euler_zyx(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
    let (dt, t_end) = (0.01, 200.0);
    let east_air = Vector3::new(0.0, 30.0, 0.0);
    propagate_steps(&mut nav, &cfg, &q_nb, &east_air, dt, (t_end / dt) as usize);
    let p = nav.position_cov();
    let gm = |s2: f64, tau: f64| 2.0 * s2 * tau * (t_end - tau * (1.0 - (-t_end / tau).exp()));
    let scale = cfg.turbulence_integral_scale_m;
    let east = gm(sigma2.x, scale[0] / 30.0);
    let north = gm(sigma2.y, scale[1] / 30.0);
    // Discretisation: the position is integrated with the start-of-step gust, a relative
    // error of order Δt/τ ≤ 0.01/4.4.
    assert!(
        (p[(1, 1)] / east - 1.0).abs() < 5e-3,
        "{} {east}",
        p[(1, 1)]
    );
    assert!(
        (p[(0, 0)] / north - 1.0).abs() < 5e-3,
        "{} {north}",
        p[(0, 0)]
    );
    assert!(p[(0, 1)].abs() < 1e-9 * east);
    let v = nav.velocity_cov();
    assert!((v[(1, 1)] / sigma2.x - 1.0).abs() < 1e-9, "{}", v[(1, 1)]);
    assert!((v[(0, 0)] / sigma2.y - 1.0).abs() < 1e-9, "{}", v[(0, 0)]);
    assert!((v[(2, 2)] / sigma2.z - 1.0).abs() < 1e-9, "{}", v[(2, 2)]);
}

/// A heading error present while the wind was averaged (wind estimated on a northbound
/// leg at 30 m/s) cancels on that heading and doubles on the reverse one: velocity σ east
/// 2·30 m/s·σ_ψ, position σ growing linearly with it.
#[test]
fn a_heading_error_absorbed_by_the_wind_cancels_on_its_heading_and_doubles_reversed() {
    let (cfg, air_cfg, air_x, f) = denied_setup();
    let north = Vector3::new(30.0, 0.0, 0.0);
    let mut est = calm_estimates(&cfg, north);
    let q_north = UnitQuaternion::identity();
    for _ in 0..1500 {
        est.step(
            0.1,
            &air_inputs(&q_north, 30.0, north),
            &GnssFilterState {
                h_m: 2100.0,
                var_h_m2: 1.0,
                v_n: north,
                v_cov: Matrix3::zeros(),
            },
        );
    }
    let sigma_psi = 1f64.to_radians();
    let att_cov_n = Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, sigma_psi.powi(2)));
    let fly = |q: UnitQuaternion<f64>, v_air: Vector3<f64>| {
        let mut nav = DeniedNav::new(&cfg, &air_cfg, &air_x, [false; 2], &att_cov_n, &f, &est);
        nav.gust_var_b = Vector3::zeros();
        nav.p_dr.fixed_view_mut::<3, 3>(DR_G, DR_G).fill(0.0);
        nav.p_dr.fixed_view_mut::<3, 3>(DR_P, DR_P).fill(0.0);
        propagate_steps(&mut nav, &cfg, &q, &v_air, 0.1, 1000);
        (nav.velocity_cov(), nav.position_cov())
    };
    let (v, p) = fly(q_north, north);
    assert!(
        v.norm() < 1e-9 && p.fixed_view::<2, 2>(0, 0).norm() < 1e-6,
        "{v} {p}"
    );
    let south = so3::from_euler_zyx(std::f64::consts::PI, 0.0, 0.0);
    let (v, p) = fly(south, -north);
    let sv = 2.0 * 30.0 * sigma_psi;
    assert!(
        (v[(1, 1)].sqrt() / sv - 1.0).abs() < 1e-9,
        "{}",
        v[(1, 1)].sqrt()
    );
    assert!(v[(0, 0)].abs() < 1e-9);
    assert!(
        (p[(1, 1)].sqrt() / (sv * 100.0) - 1.0).abs() < 1e-9,
        "{}",
        p[(1, 1)].sqrt()
    );
}

/// A fix 0.1 s old in a 0.74 rad/s level turn at 30 m/s (2.3 g): moved forward with the
/// INS's acceleration its velocity matches the current one within 0.01 m/s (third-order
/// term a·ω²·lag³/6 ≈ 2e-3 m/s), while the raw fix velocity is 2.2 m/s off — 30 times the
/// GNSS velocity σ, which would gate the fix.
#[test]
fn lagged_fix_velocity_is_moved_forward_with_the_ins_acceleration() {
    let cfg = PositionFilterConfig::default();
    let (tas, omega, lag) = (30.0, 0.74, 0.1);
    let psi = 0.6;
    let pos = init().pos;
    let v_at = |psi: f64| Vector3::new(tas * psi.cos(), tas * psi.sin(), 0.0);
    let v_now = v_at(psi);
    let a_n = Vector3::new(-psi.sin(), psi.cos(), 0.0) * (tas * omega);
    let g_n = wgs84::gravity_ned_mps2(&pos);
    let bank = (tas * omega / g_n.z).atan();
    let q_nb = so3::from_euler_zyx(psi, 0.0, bank);
    let c_nb = q_nb.to_rotation_matrix().into_inner();
    let coriolis =
        (wgs84::omega_ie_n(pos.lat_rad) * 2.0 + wgs84::omega_en_n(&pos, &v_now)).cross(&v_now);
    let f_b = c_nb.transpose() * (a_n - g_n + coriolis);
    let w_nb_b = c_nb.transpose() * Vector3::new(0.0, 0.0, omega);
    let mut filter = GnssFilter::new(
        &cfg,
        &PositionInit {
            pos,
            v_n: v_now,
            f_b,
            e_acc: Vector3::zeros(),
            e_acc_sigma: Vector3::repeat(1e-3),
        },
    );
    // The fix: where the aircraft was `lag` earlier on the circle.
    let psi_fix = psi - omega * lag;
    let chord =
        Vector3::new(psi.sin() - psi_fix.sin(), psi_fix.cos() - psi.cos(), 0.0) * (tas / omega);
    let mut fix_pos = pos;
    displace(&mut fix_pos, &(-chord));
    let fix = GnssFix {
        t_us: 0,
        pos: fix_pos,
        v_ned_mps: v_at(psi_fix),
        sigma_hor_m: f64::NAN,
        sigma_ver_m: f64::NAN,
        sigma_vel_mps: f64::NAN,
    };
    let raw = (fix.v_ned_mps - v_now).norm();
    assert!(raw > 2.0, "{raw}");
    let (p, v) = filter.fix_at_step(&fix, lag, &q_nb, &w_nb_b);
    assert!((v - v_now).norm() < 0.01, "{}", (v - v_now).norm());
    assert!(
        ned_offset_m(&pos, &p).norm() < 0.01,
        "{}",
        ned_offset_m(&pos, &p)
    );
    // Without the compensation the velocity alone gives a NIS far beyond the gate.
    let s_vel = filter.velocity_cov()[(0, 0)] + cfg.gnss_sigma_vel_mps.powi(2);
    assert!(raw * raw / s_vel > 10.0 * cfg.gnss_gate_chi2);
    let nis = filter
        .update_gnss(&cfg, &fix, lag, &q_nb, &w_nb_b)
        .expect("fused");
    assert!(nis < 0.1, "{nis}");
}

/// A turn entry (lateral acceleration from 0 to 2 g in 0.5 s, then held) seen by a fix
/// 0.4 s old — ArduPlane's GPS_RAW_INT arrives that late at 40 Hz IMU. Compared with the
/// filter's own state at the fix's time the innovation is nil; moved forward with the
/// current acceleration instead, the velocity is 1.8 m/s off and the fix is gated.
#[test]
fn a_lagged_fix_at_a_turn_entry_is_compared_with_the_state_at_its_time() {
    let cfg = PositionFilterConfig::default();
    let (speed, a_max, ramp_s, lag_s, dt_s) = (30.0, 2.0 * 9.81, 0.5, 0.4, 0.025);
    let accel = |t: f64| a_max * (t / ramp_s).clamp(0.0, 1.0);
    // Lateral (east) velocity: the integral of the ramp; north speed held.
    let v_east = |t: f64| {
        let t = t.max(0.0);
        if t < ramp_s {
            a_max * t * t / (2.0 * ramp_s)
        } else {
            a_max * ramp_s / 2.0 + a_max * (t - ramp_s)
        }
    };
    let start = init().pos;
    let state = |t: f64| {
        let v = Vector3::new(speed, v_east(t), 0.0);
        // East displacement: the integral of v_east (exact for both pieces).
        let e = if t < ramp_s {
            a_max * t.powi(3) / (6.0 * ramp_s)
        } else {
            a_max * ramp_s.powi(2) / 6.0
                + a_max * ramp_s / 2.0 * (t - ramp_s)
                + a_max * (t - ramp_s).powi(2) / 2.0
        };
        let mut pos = start;
        displace(&mut pos, &Vector3::new(speed * t, e, 0.0));
        (pos, v)
    };
    let now_s = 0.6;
    let (pos, v_n) = state(now_s);
    let g_n = wgs84::gravity_ned_mps2(&pos);
    let f_b = Vector3::new(0.0, accel(now_s), 0.0) - g_n;
    let init_at_now = PositionInit {
        pos,
        v_n,
        f_b,
        e_acc: Vector3::zeros(),
        e_acc_sigma: Vector3::repeat(1e-3),
    };
    let mut filter = GnssFilter::new(&cfg, &init_at_now);
    // The history of the flown states, one per IMU step up to the one before now.
    let steps = (now_s / dt_s).round() as u64;
    for k in 0..steps {
        let t = k as f64 * dt_s;
        (filter.pos, filter.v_n) = state(t);
        filter.record((t * 1e6).round() as u64, cfg.gnss_max_lag_s);
    }
    (filter.pos, filter.v_n) = (pos, v_n);
    let fix_t_s = now_s - lag_s;
    let (fix_pos, fix_v) = state(fix_t_s);
    let fix = GnssFix {
        t_us: (fix_t_s * 1e6).round() as u64,
        pos: fix_pos,
        v_ned_mps: fix_v,
        sigma_hor_m: f64::NAN,
        sigma_ver_m: f64::NAN,
        sigma_vel_mps: f64::NAN,
    };
    let level = UnitQuaternion::identity();
    let mut extrapolating = filter.clone();
    extrapolating.history.clear();
    let nis = filter
        .update_gnss(&cfg, &fix, lag_s, &level, &Vector3::zeros())
        .expect("fused");
    // Linear interpolation between 25 ms steps of a quadratic/cubic path: millimetres.
    assert!(nis < 0.01, "{nis}");
    // The old way: 0.4 s at the current 2 g (7.85 m/s) against the 6.08 m/s actually
    // gained on the ramp: 1.77 m/s off, 24 times the GNSS velocity σ.
    let (_, moved_v) = extrapolating.fix_at_step(&fix, lag_s, &level, &Vector3::zeros());
    let off = (moved_v - v_n).norm();
    assert!((off - 1.77).abs() < 0.01, "{off}");
    assert!(matches!(
        extrapolating.update_gnss(&cfg, &fix, lag_s, &level, &Vector3::zeros()),
        Err(UpdateRejection::Gated { .. })
    ));
}

/// `airspeed_bias_from_turns`: raw wind `w + c δ` (the airspeed 0.3 m/s too high, white noise
/// of 0.2 m/s per sample) over three 40-s legs 120° apart: the least squares give `δ` and the
/// wind back to well within the noise's bound (σ_δ ≈ 0.2 / √(12,000 · 0.9) ≈ 0.002 m/s); on one
/// heading `δ` is not observable and no estimate is given; without the setting, none either.
#[test]
fn airspeed_bias_is_estimated_from_turns_and_only_then() {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut normal = move || crate::ins::tests::standard_normal(&mut rng);
    let cfg = PositionFilterConfig::default();
    let (tas, delta, dt) = (25.0, -0.3, 0.01);
    let wind = Vector3::new(3.0, -2.0, 0.0);
    let fly = |headings_deg: &[f64], gather: bool, normal: &mut dyn FnMut() -> f64| {
        let q0 = UnitQuaternion::from_euler_angles(0.0, 0.0, headings_deg[0].to_radians());
        let mut est = wind_only_estimates(&cfg, &q0, wind, q0 * Vector3::new(tas, 0.0, 0.0));
        if gather {
            est = est.with_airspeed_bias(cfg.lpf_window_s);
        }
        for h in headings_deg {
            let q = UnitQuaternion::from_euler_angles(0.0, 0.0, h.to_radians());
            let c = q * Vector3::x();
            for _ in 0..4000 {
                let noise = Vector3::new(normal(), normal(), 0.0) * 0.2;
                step_wind_only(&mut est, dt, &q, tas, wind + c * delta + noise, c * tas);
            }
        }
        est
    };
    let est = fly(&[10.0, 130.0, 250.0], true, &mut normal);
    let (d, c_bar) = est
        .airspeed_bias(cfg.airspeed_bias_min_heading_spread)
        .expect("observable after three headings");
    assert!((d - delta).abs() < 0.02, "δ {d} against {delta}");
    let wind_corrected = est.wind().0 - c_bar * d;
    assert!((wind_corrected - wind).norm() < 0.02, "{wind_corrected}");
    // Uncorrected, the wind holds `c̄ δ`: near zero after three even legs, so check the
    // single-heading case, where the whole bias sits in the wind and cannot be told apart.
    let one = fly(&[10.0, 10.0, 10.0], true, &mut normal);
    assert!(
        one.airspeed_bias(cfg.airspeed_bias_min_heading_spread)
            .is_none()
    );
    let off = fly(&[10.0, 130.0, 250.0], false, &mut normal);
    assert!(
        off.airspeed_bias(cfg.airspeed_bias_min_heading_spread)
            .is_none()
    );
}
