//! ISA atmosphere with temperature offset ΔT and pressure offset Δp (the non-standard atmosphere of
//! Gallo's simulation paper; docs/REFERENCES.md A3.1–A3.2): pressure altitude ↔ static pressure,
//! temperature, density, geopotential ↔ geometric altitude, geometric altitude from pressure
//! altitude.
//!
//! Model (see `docs/ENVIRONMENT.md`): the pressure altitude `Hp` is the ISA altitude of the
//! measured static pressure; the actual temperature is `T = T_ISA(Hp) + ΔT`; the actual
//! mean-sea-level pressure is `p₀ + Δp`. Hydrostatics give `dH/dHp = T / T_ISA(Hp)`, integrated
//! from `H = 0` at `Hp_MSL = Hp(p₀ + Δp)`:
//!
//! `H = Hp − Hp_MSL + (ΔT/β_T)·ln[(T₀ + β_T·Hp)/(T₀ + β_T·Hp_MSL)]` (troposphere).
//!
//! Above the tropopause (11 km) `T_ISA` is constant, so `H` grows linearly in `Hp` with slope
//! `(T₁ + ΔT)/T₁`. The isothermal layer is continued above 20 km (flights stay below 4 km).
//!
//! All functions are pure (no hidden warm-start state, unlike the authors' C++). The inverse
//! relations use Newton iterations with a fixed cap; NaN in gives NaN out.

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
/// Tropopause pressure altitude, m.
pub const HP_TROPOPAUSE_M: f64 = 11_000.0;
/// ISA temperature in the lower stratosphere (above the tropopause), K.
pub const T_TROPOPAUSE_K: f64 = T0_K + BETA_T_KPM * HP_TROPOPAUSE_M;

/// Exponent of the troposphere pressure law, `−g₀/(R β_T)` (≈ 5.2559).
const PRESSURE_EXPONENT: f64 = -G0_MPS2 / (R_JPKGK * BETA_T_KPM);

/// Newton step below which the inverse altitude relations stop, m. The relation `H(Hp)` has a
/// slope within a few % of 1 and a tiny curvature, so Newton converges quadratically: once a
/// step is below 1e-9 m the remaining error is far below the f64 resolution at flight
/// altitudes (~1e-12 m), comfortably inside the 1e-6 m round-trip requirement.
pub const NEWTON_TOL_M: f64 = 1e-9;
/// Iteration cap of the Newton solvers. Convergence from the initial guess takes 3–4
/// iterations for any realistic offset; the cap only bounds the work on pathological input
/// (NaN, or ΔT so negative that the absolute temperature is not positive), where the result is
/// whatever the last iterate is — NaN for NaN input.
pub const NEWTON_MAX_ITER: usize = 30;

/// Offsets of the actual atmosphere from ISA.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct AtmosphereOffsets {
    /// Temperature offset ΔT, K.
    pub delta_t_k: f64,
    /// Pressure offset at mean sea level Δp, Pa.
    pub delta_p_pa: f64,
}

/// ISA pressure at the tropopause, Pa (≈ 22632 Pa).
fn tropopause_pressure_pa() -> f64 {
    P0_PA * (T_TROPOPAUSE_K / T0_K).powf(PRESSURE_EXPONENT)
}

/// ISA temperature at pressure altitude `hp_m` (no offset), K.
pub fn isa_temperature_k(hp_m: f64) -> f64 {
    if hp_m > HP_TROPOPAUSE_M {
        T_TROPOPAUSE_K
    } else {
        T0_K + BETA_T_KPM * hp_m
    }
}

/// Static pressure at pressure altitude `hp_m`, Pa.
pub fn pressure_pa(hp_m: f64) -> f64 {
    if hp_m > HP_TROPOPAUSE_M {
        tropopause_pressure_pa()
            * (-G0_MPS2 * (hp_m - HP_TROPOPAUSE_M) / (R_JPKGK * T_TROPOPAUSE_K)).exp()
    } else {
        P0_PA * (1.0 + BETA_T_KPM * hp_m / T0_K).powf(PRESSURE_EXPONENT)
    }
}

/// Derivative of the static pressure with respect to pressure altitude, `dp/dHp =
/// −g₀·p/(R·T_ISA(Hp))`, Pa/m (the air-data filter's observation Jacobian).
pub fn pressure_derivative_pa_per_m(hp_m: f64) -> f64 {
    -G0_MPS2 * pressure_pa(hp_m) / (R_JPKGK * isa_temperature_k(hp_m))
}

/// Pressure altitude for static pressure `p_pa`, m. Non-positive or NaN pressure gives NaN
/// (or +∞ for exactly zero).
pub fn pressure_altitude_m(p_pa: f64) -> f64 {
    if p_pa < tropopause_pressure_pa() {
        HP_TROPOPAUSE_M
            - R_JPKGK * T_TROPOPAUSE_K / G0_MPS2 * (p_pa / tropopause_pressure_pa()).ln()
    } else {
        T0_K / BETA_T_KPM * ((p_pa / P0_PA).powf(1.0 / PRESSURE_EXPONENT) - 1.0)
    }
}

/// Outside air temperature at pressure altitude `hp_m` with offset `delta_t_k`, K.
pub fn temperature_k(hp_m: f64, delta_t_k: f64) -> f64 {
    isa_temperature_k(hp_m) + delta_t_k
}

/// Temperature offset ΔT from a measured temperature at pressure altitude `hp_m`, K.
pub fn delta_t_k(hp_m: f64, temp_k: f64) -> f64 {
    temp_k - isa_temperature_k(hp_m)
}

/// Air density from pressure and temperature, kg/m³.
pub fn density_kgpm3(p_pa: f64, temp_k: f64) -> f64 {
    p_pa / (R_JPKGK * temp_k)
}

/// Speed of sound, m/s (NaN for a negative temperature).
pub fn speed_of_sound_mps(temp_k: f64) -> f64 {
    (KAPPA * R_JPKGK * temp_k).sqrt()
}

/// Geopotential altitude H from geometric altitude h, m.
pub fn geopotential_from_geometric_m(h_m: f64) -> f64 {
    R_GEOPOTENTIAL_M * h_m / (R_GEOPOTENTIAL_M + h_m)
}

/// Geometric altitude h from geopotential altitude H, m.
pub fn geometric_from_geopotential_m(geopotential_m: f64) -> f64 {
    R_GEOPOTENTIAL_M * geopotential_m / (R_GEOPOTENTIAL_M - geopotential_m)
}

/// `G(x) = ∫₀ˣ (T_ISA(s) + ΔT)/T_ISA(s) ds`: the geopotential gained between pressure
/// altitudes 0 and `x` under temperature offset ΔT. Then `H(Hp) = G(Hp) − G(Hp_MSL)`.
fn geopotential_integral_m(hp_m: f64, delta_t_k: f64) -> f64 {
    let troposphere = |x: f64| x + delta_t_k / BETA_T_KPM * (1.0 + BETA_T_KPM * x / T0_K).ln();
    if hp_m > HP_TROPOPAUSE_M {
        troposphere(HP_TROPOPAUSE_M) + (hp_m - HP_TROPOPAUSE_M) * (1.0 + delta_t_k / T_TROPOPAUSE_K)
    } else {
        troposphere(hp_m)
    }
}

/// `dG/dx = (T_ISA(x) + ΔT)/T_ISA(x)`.
fn geopotential_slope(hp_m: f64, delta_t_k: f64) -> f64 {
    1.0 + delta_t_k / isa_temperature_k(hp_m)
}

/// Solve `G(x) = target_m` for `x` by Newton's method (see [`NEWTON_TOL_M`],
/// [`NEWTON_MAX_ITER`]). `G` is monotone with a monotone slope (T_ISA is monotone and
/// continuous), so Newton converges monotonically after the first step.
fn inverse_geopotential_integral_m(target_m: f64, delta_t_k: f64) -> f64 {
    if !target_m.is_finite() || !delta_t_k.is_finite() {
        return f64::NAN;
    }
    // Near MSL G(x) ≈ x·(1 + ΔT/T₀): a guess within metres of the root.
    let mut x = target_m / geopotential_slope(0.0, delta_t_k);
    for _ in 0..NEWTON_MAX_ITER {
        let step =
            (geopotential_integral_m(x, delta_t_k) - target_m) / geopotential_slope(x, delta_t_k);
        x -= step;
        // A NaN step also ends the loop (the result is then NaN).
        if step.abs() <= NEWTON_TOL_M || step.is_nan() {
            break;
        }
    }
    x
}

/// Derivative of the geopotential altitude with respect to the pressure altitude at fixed
/// offsets, `dH/dHp = (T_ISA(Hp) + ΔT)/T_ISA(Hp)` (dimensionless).
pub fn geopotential_derivative(hp_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    geopotential_slope(hp_m, offsets.delta_t_k)
}

/// Geopotential altitude H for pressure altitude `hp_m` under `offsets`, m.
pub fn geopotential_from_pressure_altitude_m(hp_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    let hp_msl_m = pressure_altitude_m(P0_PA + offsets.delta_p_pa);
    geopotential_integral_m(hp_m, offsets.delta_t_k)
        - geopotential_integral_m(hp_msl_m, offsets.delta_t_k)
}

/// Pressure altitude for geopotential altitude H under `offsets`, m.
pub fn pressure_altitude_from_geopotential_m(
    geopotential_m: f64,
    offsets: &AtmosphereOffsets,
) -> f64 {
    let hp_msl_m = pressure_altitude_m(P0_PA + offsets.delta_p_pa);
    inverse_geopotential_integral_m(
        geopotential_m + geopotential_integral_m(hp_msl_m, offsets.delta_t_k),
        offsets.delta_t_k,
    )
}

/// Geometric altitude h for pressure altitude `hp_m` under `offsets`, m.
pub fn geometric_from_pressure_altitude_m(hp_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    geometric_from_geopotential_m(geopotential_from_pressure_altitude_m(hp_m, offsets))
}

/// Pressure altitude for geometric altitude `h_m` under `offsets`, m.
pub fn pressure_altitude_from_geometric_m(h_m: f64, offsets: &AtmosphereOffsets) -> f64 {
    pressure_altitude_from_geopotential_m(geopotential_from_geometric_m(h_m), offsets)
}

/// Pressure offset Δp that makes pressure altitude `hp_m` correspond to geopotential altitude
/// `geopotential_m` at temperature offset `delta_t_k`, Pa (used by the INS while GNSS is
/// available).
///
/// Solves `G(Hp_MSL) = G(Hp) − H` for the MSL pressure altitude, then `Δp = p(Hp_MSL) − p₀`.
pub fn delta_p_pa(hp_m: f64, geopotential_m: f64, delta_t_k: f64) -> f64 {
    let hp_msl_m = inverse_geopotential_integral_m(
        geopotential_integral_m(hp_m, delta_t_k) - geopotential_m,
        delta_t_k,
    );
    pressure_pa(hp_msl_m) - P0_PA
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Offsets spanning well beyond the scenario draws (ΔT σ 10 K, Δp σ 1500 Pa).
    fn offset_grid() -> Vec<AtmosphereOffsets> {
        let mut v = Vec::new();
        for delta_t_k in [-40.0, -15.0, 0.0, 7.5, 40.0] {
            for delta_p_pa in [-5000.0, -1500.0, 0.0, 300.0, 5000.0] {
                v.push(AtmosphereOffsets {
                    delta_t_k,
                    delta_p_pa,
                });
            }
        }
        v
    }

    fn hp_grid() -> Vec<f64> {
        (-10..=30).map(|i| f64::from(i) * 500.0 + 13.7).collect()
    }

    #[test]
    fn known_isa_values() {
        // Reference values of the ISA tables (geopotential altitudes). The tables' R and
        // rounding differ in the 6th digit, hence 0.05 Pa (2e-6 relative) at 11 and 20 km.
        assert!((pressure_pa(0.0) - 101_325.0).abs() < 1e-9);
        assert!((pressure_pa(11_000.0) - 22_632.06).abs() < 0.05);
        assert!((pressure_pa(20_000.0) - 5_474.89).abs() < 0.05);
        assert!((temperature_k(0.0, 0.0) - 288.15).abs() < 1e-12);
        assert!((temperature_k(11_000.0, 0.0) - 216.65).abs() < 1e-9);
        assert!((temperature_k(15_000.0, 5.0) - 221.65).abs() < 1e-9);
        assert!((density_kgpm3(P0_PA, T0_K) - 1.2250).abs() < 5e-5);
        assert!((speed_of_sound_mps(T0_K) - 340.294).abs() < 1e-3);
        // 3000 m (geopotential): 70108.5 Pa, 268.65 K, 0.90912 kg/m³.
        assert!((pressure_pa(3000.0) - 70_108.5).abs() < 0.1);
        let rho = density_kgpm3(pressure_pa(3000.0), temperature_k(3000.0, 0.0));
        assert!((rho - 0.909_12).abs() < 1e-5);
    }

    #[test]
    fn pressure_and_pressure_altitude_round_trip() {
        for hp in hp_grid() {
            let back = pressure_altitude_m(pressure_pa(hp));
            assert!((back - hp).abs() < 1e-6, "{hp} -> {back}");
        }
        // Continuity at the tropopause.
        let below = pressure_pa(HP_TROPOPAUSE_M - 1e-7);
        let above = pressure_pa(HP_TROPOPAUSE_M + 1e-7);
        assert!((below - above).abs() < 1e-4);
    }

    #[test]
    fn pressure_derivative_matches_finite_differences() {
        // Central difference, step 0.01 m: truncation ~ p''' h²/6 ~ 1e-10 Pa/m, rounding
        // ~ 1e-16·1e5/0.01 ~ 1e-9 Pa/m; dp/dHp ~ 12 Pa/m, so 1e-6 relative is ample.
        for hp in hp_grid() {
            let d = 0.01;
            let fd = (pressure_pa(hp + d) - pressure_pa(hp - d)) / (2.0 * d);
            let an = pressure_derivative_pa_per_m(hp);
            assert!((fd - an).abs() < 1e-6 * an.abs(), "{hp}: {fd} vs {an}");
        }
    }

    #[test]
    fn temperature_offset_round_trip() {
        for hp in hp_grid() {
            let t = temperature_k(hp, 12.3);
            assert!((delta_t_k(hp, t) - 12.3).abs() < 1e-9);
        }
    }

    #[test]
    fn geometric_geopotential_round_trip() {
        for i in -10..=40 {
            let h = f64::from(i) * 503.1;
            let hh = geopotential_from_geometric_m(h);
            assert!((geometric_from_geopotential_m(hh) - h).abs() < 1e-6);
            // H < h above MSL by ~h²/R: 1.4 m at 3 km.
            if h > 0.0 {
                assert!(hh < h);
            }
        }
        let h = 3000.0;
        let dh = h - geopotential_from_geometric_m(h);
        assert!((dh - h * h / (R_GEOPOTENTIAL_M + h)).abs() < 1e-9);
    }

    #[test]
    fn standard_atmosphere_has_h_equal_hp() {
        let zero = AtmosphereOffsets::default();
        for hp in hp_grid() {
            assert!((geopotential_from_pressure_altitude_m(hp, &zero) - hp).abs() < 1e-9);
            assert!((pressure_altitude_from_geopotential_m(hp, &zero) - hp).abs() < 1e-9);
        }
    }

    #[test]
    fn geopotential_formula_matches_hydrostatic_integration() {
        // Independent check of the closed form: integrate dH = −R·T/(g₀·p) dp from the actual
        // MSL pressure p₀+Δp down to p(Hp) with composite Simpson (n = 2000 panels). The
        // integrand is smooth (error ~ (Δp)⁵ f⁗/n⁴ ≪ 1e-6 m); tolerance 1e-5 m.
        for off in offset_grid() {
            for hp in [-300.0, 1000.0, 3500.0, 9000.0] {
                let p_a = P0_PA + off.delta_p_pa;
                let p_b = pressure_pa(hp);
                let f = |p: f64| {
                    -R_JPKGK * temperature_k(pressure_altitude_m(p), off.delta_t_k) / (G0_MPS2 * p)
                };
                let n = 2000;
                let step = (p_b - p_a) / f64::from(n);
                let mut sum = f(p_a) + f(p_b);
                for i in 1..n {
                    let w = if i % 2 == 1 { 4.0 } else { 2.0 };
                    sum += w * f(p_a + f64::from(i) * step);
                }
                let integral = sum * step / 3.0;
                let closed = geopotential_from_pressure_altitude_m(hp, &off);
                assert!(
                    (integral - closed).abs() < 1e-5,
                    "{off:?} {hp}: {integral} {closed}"
                );
            }
        }
    }

    #[test]
    fn geopotential_derivative_matches_finite_differences() {
        // Central difference with step 0.1 m; d²H/dHp² ~ ΔT·β/T² ~ 1e-5 /m, third derivative
        // ~ 1e-7 /m², so the truncation error ~ 1e-10; rounding ~ 1e-16·4e3/0.1 ~ 1e-11.
        for off in offset_grid() {
            for hp in hp_grid() {
                let d = 0.1;
                let fd = (geopotential_from_pressure_altitude_m(hp + d, &off)
                    - geopotential_from_pressure_altitude_m(hp - d, &off))
                    / (2.0 * d);
                let an = geopotential_derivative(hp, &off);
                assert!((fd - an).abs() < 1e-8, "{off:?} {hp}: {fd} vs {an}");
            }
        }
    }

    #[test]
    fn altitude_round_trips_under_offsets() {
        for off in offset_grid() {
            for hp in hp_grid() {
                let hh = geopotential_from_pressure_altitude_m(hp, &off);
                let hp_back = pressure_altitude_from_geopotential_m(hh, &off);
                assert!((hp_back - hp).abs() < 1e-6, "{off:?} {hp} -> {hp_back}");
                let h = geometric_from_pressure_altitude_m(hp, &off);
                let hp_back2 = pressure_altitude_from_geometric_m(h, &off);
                assert!((hp_back2 - hp).abs() < 1e-6, "{off:?} {hp} -> {hp_back2}");
            }
        }
    }

    #[test]
    fn offsets_move_altitudes_the_right_way() {
        // Higher MSL pressure: a given pressure level is higher above MSL. Δp = +12 Pa is
        // ≈ +1 m at MSL (dp/dHp ≈ −12.0 Pa/m).
        let hp = 0.0;
        let up = AtmosphereOffsets {
            delta_t_k: 0.0,
            delta_p_pa: 12.013,
        };
        let hh = geopotential_from_pressure_altitude_m(hp, &up);
        assert!((hh - 1.0).abs() < 2e-3, "{hh}");
        // Warm air: layers thicker, 3000 m of Hp span ≈ 3000·(1 + ΔT/T̄) of H.
        let warm = AtmosphereOffsets {
            delta_t_k: 10.0,
            delta_p_pa: 0.0,
        };
        let hh = geopotential_from_pressure_altitude_m(3000.0, &warm);
        let t_mean = T0_K + BETA_T_KPM * 1500.0;
        assert!((hh - 3000.0 * (1.0 + 10.0 / t_mean)).abs() < 0.1, "{hh}");
    }

    #[test]
    fn delta_p_recovers_the_offset() {
        // The recovery goes through one Newton solve (≤ 1e-9 m) and dp/dHp ≈ 12 Pa/m.
        for off in offset_grid() {
            for hp in hp_grid() {
                let hh = geopotential_from_pressure_altitude_m(hp, &off);
                let dp = delta_p_pa(hp, hh, off.delta_t_k);
                assert!((dp - off.delta_p_pa).abs() < 1e-6, "{off:?} {hp}: {dp}");
            }
        }
    }

    #[test]
    fn nan_in_nan_out() {
        let off = AtmosphereOffsets::default();
        let nan_t = AtmosphereOffsets {
            delta_t_k: f64::NAN,
            delta_p_pa: 0.0,
        };
        assert!(pressure_pa(f64::NAN).is_nan());
        assert!(pressure_altitude_m(f64::NAN).is_nan());
        assert!(pressure_altitude_m(-5.0).is_nan());
        assert!(geopotential_from_pressure_altitude_m(f64::NAN, &off).is_nan());
        assert!(pressure_altitude_from_geopotential_m(f64::NAN, &off).is_nan());
        assert!(pressure_altitude_from_geopotential_m(1000.0, &nan_t).is_nan());
        assert!(pressure_altitude_from_geometric_m(f64::INFINITY, &off).is_nan());
        assert!(delta_p_pa(f64::NAN, 0.0, 0.0).is_nan());
        assert!(delta_p_pa(0.0, 0.0, f64::NAN).is_nan());
        // Unphysical temperature (absolute T ≤ 0): bounded work, no panic.
        let cold = AtmosphereOffsets {
            delta_t_k: -400.0,
            delta_p_pa: 0.0,
        };
        let _ = pressure_altitude_from_geopotential_m(1000.0, &cold);
        let _ = delta_p_pa(1000.0, 900.0, -400.0);
    }
}
