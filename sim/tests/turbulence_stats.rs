//! Statistics of the Dryden turbulence generator over long series (docs/ENVIRONMENT.md,
//! "Turbulence"): velocity σ per axis = table intensity, gust-acceleration σ per axis = the
//! authors' 0.61 / 0.75 / 0.75 m/s² at 30 m/s and factor 1, measured by finite differences of
//! the simulated series; independence of the step; scaling with airspeed.
//!
//! Tolerances follow from the sampling error of each estimate. For a stationary process with
//! normalised two-sided spectrum `S` (in time), the variance estimate over a length `T` has
//! relative standard error `√(2τ₂/T)` with `τ₂ = ∫ρ² dτ = 2π∫S² dω`, so σ̂ has `√(τ₂/(2T))`;
//! the mean has standard error `σ√(τ₁/T)` with `τ₁ = ∫ρ dτ = 2πS(0)`. τ₁ and τ₂ are computed
//! here by quadrature of the model spectra. Bounds are 4.5 standard errors plus a small
//! allowance for the discretisation bias (finite differences at Δt: relative bias of the
//! acceleration variance ≈ (V/L + V/ℓ)·Δt/3 ≤ 0.3 %; trapezoidal filters ≤ 1e-5).

use ianav_sim::env::turbulence::{
    CALIBRATION_ACCEL_VAR_X, CALIBRATION_ACCEL_VAR_YZ, CALIBRATION_H_M, CALIBRATION_TAS_MPS,
    DrydenParams, Severity,
};
use ianav_sim::env::{Turbulence, TurbulenceConfig};
use ianav_sim::rng::stream;
use nalgebra::Vector3;

/// Standard errors in the bounds.
const K: f64 = 4.5;
/// Allowance for discretisation bias on σ estimates (relative).
const BIAS: f64 = 0.005;

/// Sample statistics of one series.
struct Stats {
    mean_v: Vector3<f64>,
    sd_v: Vector3<f64>,
    mean_a: Vector3<f64>,
    sd_a: Vector3<f64>,
}

fn run(factor: f64, dt_s: f64, tas_mps: f64, duration_s: f64, seed: u64) -> Stats {
    let mut t = Turbulence::new(&TurbulenceConfig { factor }, stream(seed, "turbulence"));
    let n = (duration_s / dt_s).round() as usize;
    let mut prev = t.velocity_b_mps();
    let (mut s1, mut s2, mut a1, mut a2) = (
        Vector3::zeros(),
        Vector3::zeros(),
        Vector3::<f64>::zeros(),
        Vector3::<f64>::zeros(),
    );
    for _ in 0..n {
        let v = t.step(dt_s, tas_mps, CALIBRATION_H_M);
        let a = (v - prev) / dt_s;
        prev = v;
        s1 += v;
        s2 += v.component_mul(&v);
        a1 += a;
        a2 += a.component_mul(&a);
    }
    let nf = n as f64;
    let sd = |s1: Vector3<f64>, s2: Vector3<f64>| {
        (s2 / nf - (s1 / nf).component_mul(&(s1 / nf))).map(f64::sqrt)
    };
    Stats {
        mean_v: s1 / nf,
        sd_v: sd(s1, s2),
        mean_a: a1 / nf,
        sd_a: sd(a1, a2),
    }
}

/// Two-sided integral of `f` over all spatial frequencies (midpoint rule after Ω = tan θ /
/// scale; the transformed integrand is smooth, error ≪ 1e-6).
fn integrate(f: &dyn Fn(f64) -> f64, scale: f64) -> f64 {
    let n = 100_000;
    let h = std::f64::consts::FRAC_PI_2 / f64::from(n);
    let mut s = 0.0;
    for i in 0..n {
        let th = (f64::from(i) + 0.5) * h;
        let c = th.cos();
        s += f(th.tan() / scale) / (scale * c * c);
    }
    2.0 * s * h
}

/// (τ₁, τ₂) in seconds of a process with spatial spectrum `phi` (any normalisation) seen at
/// airspeed `v`.
fn time_scales(phi: &dyn Fn(f64) -> f64, scale: f64, v: f64) -> (f64, f64) {
    let total = integrate(phi, scale);
    let sq = integrate(&|o| phi(o).powi(2), scale);
    let two_pi = 2.0 * std::f64::consts::PI;
    (
        two_pi * phi(0.0) / total / v,
        two_pi * sq / (total * total) / v,
    )
}

/// Spatial spectra (unnormalised) of the rolled-off u and v/w velocities.
fn spectra(p: &DrydenParams) -> [Box<dyn Fn(f64) -> f64>; 2] {
    let (lu, lx) = (p.scale_length_u_m, p.rolloff_length_x_m);
    let (l, ly) = (p.scale_length_vw_m, p.rolloff_length_yz_m);
    [
        Box::new(move |o: f64| 1.0 / ((1.0 + (lu * o).powi(2)) * (1.0 + (lx * o).powi(2)))),
        Box::new(move |o: f64| {
            let x2 = (l * o).powi(2);
            (1.0 + 3.0 * x2) / ((1.0 + x2).powi(2) * (1.0 + (ly * o).powi(2)))
        }),
    ]
}

/// Standard-error scales for (velocity mean, velocity σ, acceleration σ) per axis.
fn standard_errors(v: f64, duration_s: f64) -> [[f64; 3]; 3] {
    let p = DrydenParams::default();
    let [su, sv] = spectra(&p);
    let scales = [
        (p.scale_length_u_m, p.rolloff_length_x_m),
        (p.scale_length_vw_m, p.rolloff_length_yz_m),
    ];
    let mut out = [[0.0; 3]; 3];
    for (axis, (phi, (l, ell))) in [&su, &sv].into_iter().zip(scales).enumerate() {
        let (t1, t2) = time_scales(phi.as_ref(), l, v);
        let (_, t2a) = time_scales(&|o| o * o * phi(o), ell, v);
        let se = [
            (t1 / duration_s).sqrt(),
            (t2 / (2.0 * duration_s)).sqrt(),
            (t2a / (2.0 * duration_s)).sqrt(),
        ];
        let idx: &[usize] = if axis == 0 { &[0] } else { &[1, 2] };
        for &i in idx {
            for (k, s) in se.iter().enumerate() {
                out[k][i] = *s;
            }
        }
    }
    out
}

fn target_accel_sd(v: f64) -> Vector3<f64> {
    let r = v / CALIBRATION_TAS_MPS;
    Vector3::new(
        CALIBRATION_ACCEL_VAR_X.sqrt() * r,
        CALIBRATION_ACCEL_VAR_YZ.sqrt() * r,
        CALIBRATION_ACCEL_VAR_YZ.sqrt() * r,
    )
}

fn check(st: &Stats, factor: f64, v: f64, duration_s: f64) {
    let sigma = factor * Severity::Moderate.intensity_mps(CALIBRATION_H_M);
    let [se_mean, se_sd, se_acc] = standard_errors(v, duration_s);
    let acc = factor * target_accel_sd(v);
    for i in 0..3 {
        assert!(
            st.mean_v[i].abs() < K * sigma * se_mean[i],
            "axis {i}: mean {} (SE {})",
            st.mean_v[i],
            sigma * se_mean[i]
        );
        let rel = st.sd_v[i] / sigma - 1.0;
        assert!(
            rel.abs() < K * se_sd[i] + BIAS,
            "axis {i}: σ_v {} vs {sigma} (rel SE {})",
            st.sd_v[i],
            se_sd[i]
        );
        let rel = st.sd_a[i] / acc[i] - 1.0;
        assert!(
            rel.abs() < K * se_acc[i] + BIAS,
            "axis {i}: σ_a {} vs {} (rel SE {})",
            st.sd_a[i],
            acc[i],
            se_acc[i]
        );
        // The mean of the finite differences is (v_end − v_start)/T: bounded by a few σ/T.
        assert!(st.mean_a[i].abs() < K * 2.0_f64.sqrt() * sigma / duration_s);
    }
}

#[test]
fn calibration_statistics_at_500_hz() {
    // 40,000 s at 500 Hz, 30 m/s: velocity σ to ~1.6 % (1σ) on x, acceleration σ to ~0.3 %.
    let t = 40_000.0;
    let st = run(1.0, 0.002, CALIBRATION_TAS_MPS, t, 1);
    check(&st, 1.0, CALIBRATION_TAS_MPS, t);
}

#[test]
fn acceleration_sigma_is_step_independent_and_scales_with_speed() {
    // 100 Hz instead of 500 Hz: the same acceleration σ (the roll-off makes it a property of
    // the field, not of the step).
    let t = 20_000.0;
    let st = run(1.0, 0.01, CALIBRATION_TAS_MPS, t, 2);
    check(&st, 1.0, CALIBRATION_TAS_MPS, t);
    // Frozen field: at 20 m/s the same gusts are met 2/3 as fast → acceleration σ × 2/3,
    // velocity σ unchanged. Factor 0.5 halves both.
    let st = run(0.5, 0.002, 20.0, t, 3);
    check(&st, 0.5, 20.0, t);
}

/// Numbers for docs/ENVIRONMENT.md: `cargo test -p ianav-sim --profile ci --test
/// turbulence_stats -- --ignored --nocapture`.
#[test]
#[ignore = "report for the documentation"]
fn calibration_report() {
    let t = 5000.0;
    for (factor, duration) in [(1.0, t), (0.5, t), (1.0, 40_000.0)] {
        let st = run(factor, 0.002, CALIBRATION_TAS_MPS, duration, 1);
        println!(
            "factor {factor}, {duration} s: σ_v = {:.3} {:.3} {:.3} m/s, mean_v = {:.3} {:.3} {:.3}, \
             σ_a = {:.3} {:.3} {:.3} m/s², mean_a = {:.1e} {:.1e} {:.1e}",
            st.sd_v.x,
            st.sd_v.y,
            st.sd_v.z,
            st.mean_v.x,
            st.mean_v.y,
            st.mean_v.z,
            st.sd_a.x,
            st.sd_a.y,
            st.sd_a.z,
            st.mean_a.x,
            st.mean_a.y,
            st.mean_a.z
        );
    }
    let [m, s, a] = standard_errors(CALIBRATION_TAS_MPS, t);
    println!("relative SE over {t} s: mean {m:.3?}, σ_v {s:.4?}, σ_a {a:.4?}");
    let p = DrydenParams::default();
    println!("{p:?}");
    for dt in [0.002, 0.01] {
        let st = run(1.0, dt, CALIBRATION_TAS_MPS, 20_000.0, 9);
        println!(
            "dt {dt}: σ_a = {:.4} {:.4} {:.4}",
            st.sd_a.x, st.sd_a.y, st.sd_a.z
        );
    }
    let mut tb = Turbulence::new(&TurbulenceConfig { factor: 0.5 }, stream(1, "turbulence"));
    let n = 10_000_000;
    let start = std::time::Instant::now();
    let mut acc = Vector3::zeros();
    for i in 0..n {
        // Slightly varying airspeed, as in flight.
        acc += tb.step(0.002, 30.0 + 1e-4 * f64::from(i % 1000), 3000.0);
    }
    println!("per step: {:?} ({acc:?})", start.elapsed() / n);
}
