//! Piston engine and fixed-pitch propeller (docs/REFERENCES.md A4.3): shaft power with altitude
//! lapse `P = P_max·min(δ_T, δ/√θ)` (corner rounded), analytic propeller curves C_T(J),
//! C_P(J), shaft speed solved every evaluation from `C_P(J)·ρ n³ D⁵ = P` by Newton's method,
//! thrust along body x, torque reaction `−P/(2π n)` about x, fuel flow `c_f·P`.
//!
//! With `C_P(J) = c₀ + c₁J + c₂J²` and `J = V/(nD)`, the power balance is a cubic in n:
//! `ρD⁵c₀·n³ + ρD⁴V c₁·n² + ρD³V² c₂·n − P = 0`. With `c₀ > 0`, `c₁ ≥ 0`, `V ≥ 0` it is
//! convex on n > 0 and negative at n = 0, so it has exactly one positive root and Newton's
//! method started to the right of it (at `n_max`) decreases monotonically onto it — no
//! bracketing and no hidden state; a warm start from a nearby state may be passed explicitly.

use ianav::env::atmosphere::{P0_PA, T0_K};
use serde::{Deserialize, Serialize};

use super::AircraftError;

/// Newton stops after the update whose step was below this fraction of n: by quadratic
/// convergence the remaining relative error is then ≈ κ·(1e-7)² with κ = n f''/(2f') = O(1)
/// on this convex cubic, i.e. ~1e-14 — far below the 1e-9 residual the tests require.
const NEWTON_STEP_REL_TOL: f64 = 1e-7;
/// Advance ratio of the cold-start guess `n₀ = V/(J₀ D)`: near the cruise root (J ≈ 0.75–0.9),
/// so a cold solve takes 2–4 iterations instead of ~7 from `n_max`.
const COLD_START_ADVANCE_RATIO: f64 = 0.85;
/// Iteration bound of the shaft-speed Newton solve. From `n_max` = 130 rev/s to the slowest
/// realistic root (~45 rev/s) Newton on a convex cubic needs ~8 iterations.
const NEWTON_MAX_ITERATIONS: u32 = 40;
/// Iteration bound of a warm-started solve before it falls back to the cold start (a warm
/// start from a state one integration stage away converges in 1–2 iterations).
const NEWTON_WARM_MAX_ITERATIONS: u32 = 6;

/// Engine and propeller parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PropulsionParams {
    /// Maximum shaft power at sea level ISA, W.
    pub max_power_w: f64,
    /// Half-width of the quadratic rounding of `min(δ_T, δ/√θ)` (throttle units).
    pub power_corner_width: f64,
    /// Propeller diameter D, m.
    pub prop_diameter_m: f64,
    /// Static thrust coefficient C_T(0).
    pub c_thrust_0: f64,
    /// Advance ratio of zero thrust: `C_T(J) = C_T(0)·(1 − (J/J₀)²)`.
    pub advance_ratio_zero_thrust: f64,
    /// Power coefficient polynomial `C_P(J) = c₀ + c₁J + c₂J²`: c₀ (> 0).
    pub c_power_0: f64,
    /// c₁ (≥ 0, required by the Newton solver's convexity argument).
    pub c_power_1: f64,
    /// c₂.
    pub c_power_2: f64,
    /// Lower clamp of the shaft speed, rev/s.
    pub shaft_min_rps: f64,
    /// Upper clamp of the shaft speed, rev/s.
    pub shaft_max_rps: f64,
    /// Specific fuel consumption c_f, kg/J.
    pub fuel_per_energy_kgpj: f64,
}

impl Default for PropulsionParams {
    fn default() -> Self {
        Self {
            max_power_w: 4180.0,
            power_corner_width: 0.02,
            prop_diameter_m: 0.51,
            c_thrust_0: 0.125,
            advance_ratio_zero_thrust: 1.1,
            c_power_0: 0.075,
            c_power_1: 0.05,
            c_power_2: -0.085,
            shaft_min_rps: 27.0,
            shaft_max_rps: 130.0,
            fuel_per_energy_kgpj: 1e-7,
        }
    }
}

impl PropulsionParams {
    /// Checks the values and the signs the solver relies on; the error names the field.
    pub fn validate(&self) -> Result<(), AircraftError> {
        let bad = |field: &'static str, reason: &str| {
            Err(AircraftError::Invalid {
                field,
                reason: reason.to_owned(),
            })
        };
        let positive = [
            ("propulsion.max_power_w", self.max_power_w),
            ("propulsion.power_corner_width", self.power_corner_width),
            ("propulsion.prop_diameter_m", self.prop_diameter_m),
            ("propulsion.c_thrust_0", self.c_thrust_0),
            (
                "propulsion.advance_ratio_zero_thrust",
                self.advance_ratio_zero_thrust,
            ),
            ("propulsion.c_power_0", self.c_power_0),
            ("propulsion.shaft_min_rps", self.shaft_min_rps),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, "must be finite and positive");
            }
        }
        if !(self.c_power_1.is_finite() && self.c_power_1 >= 0.0) {
            return bad(
                "propulsion.c_power_1",
                "must be finite and >= 0 (solver convexity)",
            );
        }
        if !self.c_power_2.is_finite() {
            return bad("propulsion.c_power_2", "must be finite");
        }
        if !(self.shaft_max_rps.is_finite() && self.shaft_max_rps > self.shaft_min_rps) {
            return bad(
                "propulsion.shaft_max_rps",
                "must be finite and above shaft_min_rps",
            );
        }
        if !(self.fuel_per_energy_kgpj.is_finite() && self.fuel_per_energy_kgpj >= 0.0) {
            return bad("propulsion.fuel_per_energy_kgpj", "must be finite and >= 0");
        }
        Ok(())
    }
}

/// What the engine and propeller produce at one state.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PropulsionOutput {
    /// Thrust along body x, N (≥ 0).
    pub thrust_n: f64,
    /// Engine torque reaction about body x, N·m (negative for a right-hand propeller).
    pub torque_x_nm: f64,
    /// Shaft power absorbed by the propeller, W.
    pub power_w: f64,
    /// Shaft speed, rev/s (0 with the engine off).
    pub shaft_rps: f64,
    /// Fuel flow, kg/s.
    pub fuel_flow_kgps: f64,
    /// Newton iterations used.
    pub iterations: u32,
}

/// The power balance `C_P(V/(nD))·ρ n³ D⁵ − P` as the cubic `a n³ + b n² + c n − P`.
#[derive(Debug, Clone, Copy)]
struct PowerBalance {
    a: f64,
    b: f64,
    c: f64,
    power_w: f64,
}

impl PowerBalance {
    #[inline]
    fn new(p: &PropulsionParams, power_w: f64, rho_kgpm3: f64, v_axial_mps: f64) -> Self {
        let d = p.prop_diameter_m;
        let v = v_axial_mps.max(0.0);
        let d2 = d * d;
        let d3 = d2 * d;
        Self {
            a: rho_kgpm3 * d3 * d2 * p.c_power_0,
            b: rho_kgpm3 * d2 * d2 * v * p.c_power_1,
            c: rho_kgpm3 * d3 * v * v * p.c_power_2,
            power_w,
        }
    }

    #[inline]
    fn value(&self, n: f64) -> f64 {
        ((self.a * n + self.b) * n + self.c) * n - self.power_w
    }

    /// d(value)/dn.
    #[inline]
    fn slope(&self, n: f64) -> f64 {
        (3.0 * self.a * n + 2.0 * self.b) * n + self.c
    }
}

/// Engine and propeller model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Propulsion {
    p: PropulsionParams,
}

impl Propulsion {
    /// Builds the model.
    pub fn new(p: &PropulsionParams) -> Self {
        Self { p: *p }
    }

    /// Parameters.
    pub fn params(&self) -> &PropulsionParams {
        &self.p
    }

    /// Thrust coefficient at advance ratio J.
    #[inline]
    pub fn c_thrust(&self, j: f64) -> f64 {
        let x = j / self.p.advance_ratio_zero_thrust;
        self.p.c_thrust_0 * (1.0 - x * x)
    }

    /// Power coefficient at advance ratio J.
    #[inline]
    pub fn c_power(&self, j: f64) -> f64 {
        self.p.c_power_0 + j * (self.p.c_power_1 + j * self.p.c_power_2)
    }

    /// Available shaft power for throttle `throttle` (∈ [0, 1], NaN → 0) at static pressure
    /// `p_pa` and temperature `temp_k`, W: `P_max·min(δ_T, δ/√θ)`, the corner rounded with the
    /// C¹ quadratic blend `min(a, b) − h²/(4w)`, `h = max(w − |a − b|, 0)`, which leaves the
    /// function untouched farther than w from the corner (so throttle 0 gives exactly 0).
    #[inline]
    pub fn available_power_w(&self, throttle: f64, p_pa: f64, temp_k: f64) -> f64 {
        let throttle = if throttle.is_nan() {
            0.0
        } else {
            throttle.clamp(0.0, 1.0)
        };
        let lapse = (p_pa / P0_PA) / (temp_k / T0_K).sqrt();
        let w = self.p.power_corner_width;
        let h = (w - (throttle - lapse).abs()).max(0.0);
        let fraction = throttle.min(lapse) - h * h / (4.0 * w);
        let power = self.p.max_power_w * fraction;
        if power > 0.0 { power } else { 0.0 }
    }

    /// Solves `C_P(V/(nD))·ρ n³ D⁵ = power_w` for the shaft speed n (rev/s) with axial inflow
    /// `v_axial_mps` (clamped to ≥ 0), by Newton's method from a start point `n₀`: the warm
    /// start `warm_rps` (the root of a nearby state, passed explicitly) or else the guess
    /// `V/(J₀D)`. Where the cubic's slope at n₀ is positive, a first step from the left lands
    /// right of the root by convexity and the iterates then decrease monotonically onto it. If
    /// that has not converged within a few iterations (or the slope is not positive), the
    /// solve restarts at `n_max`, right of the root, with the same monotone convergence; if
    /// even `n_max` cannot absorb the power, `n_max` is returned. Returns `(n, iterations)`
    /// before clamping to `[n_min, n_max]`.
    #[inline]
    pub fn solve_shaft_speed(
        &self,
        power_w: f64,
        rho_kgpm3: f64,
        v_axial_mps: f64,
        warm_rps: Option<f64>,
    ) -> (f64, u32) {
        let cubic = PowerBalance::new(&self.p, power_w, rho_kgpm3, v_axial_mps);
        let f = |n: f64| cubic.value(n);
        let slope = |n: f64| cubic.slope(n);
        let v = v_axial_mps.max(0.0);
        let d = self.p.prop_diameter_m;
        let newton = |mut n: f64, max_iterations: u32| -> Option<(f64, u32)> {
            for k in 1..=max_iterations {
                let step = f(n) / slope(n);
                n -= step;
                if step.abs() <= NEWTON_STEP_REL_TOL * n {
                    return Some((n, k));
                }
            }
            None
        };
        // Without a warm start, guess from a typical advance ratio (falls back to n_max below).
        let n0 = warm_rps.unwrap_or(v / (COLD_START_ADVANCE_RATIO * d));
        if n0.is_finite()
            && n0 > 0.0
            && slope(n0) > 0.0
            && let Some(found) = newton(n0, NEWTON_WARM_MAX_ITERATIONS)
        {
            return found;
        }
        let n_max = self.p.shaft_max_rps;
        let f_max = f(n_max);
        if f_max.is_nan() || f_max <= 0.0 {
            return (n_max, 0);
        }
        newton(n_max, NEWTON_MAX_ITERATIONS).unwrap_or((n_max, NEWTON_MAX_ITERATIONS))
    }

    /// Engine and propeller output. `fuel_available` false (empty tank) or zero throttle stop
    /// the engine: no thrust, no torque, no fuel flow, propeller stopped. Windmilling drag is
    /// neglected (thrust floored at zero), which makes "engine off" the continuous limit of
    /// low power.
    #[inline]
    pub fn evaluate(
        &self,
        throttle: f64,
        p_pa: f64,
        temp_k: f64,
        rho_kgpm3: f64,
        v_axial_mps: f64,
        fuel_available: bool,
    ) -> PropulsionOutput {
        let power_avail = if fuel_available {
            self.available_power_w(throttle, p_pa, temp_k)
        } else {
            0.0
        };
        self.evaluate_at_power(power_avail, rho_kgpm3, v_axial_mps, None)
            .0
    }

    /// Propeller output for an available shaft power `power_w` (from
    /// [`Self::available_power_w`], 0 = engine off), with an optional warm start of the
    /// shaft-speed solve. Also returns the unclamped root, the warm start for a nearby state.
    #[inline]
    pub fn evaluate_at_power(
        &self,
        power_w: f64,
        rho_kgpm3: f64,
        v_axial_mps: f64,
        warm_rps: Option<f64>,
    ) -> (PropulsionOutput, Option<f64>) {
        if !(power_w > 0.0 && rho_kgpm3 > 0.0) {
            return (PropulsionOutput::default(), None);
        }
        let (n_raw, iterations) = self.solve_shaft_speed(power_w, rho_kgpm3, v_axial_mps, warm_rps);
        let n = n_raw.clamp(self.p.shaft_min_rps, self.p.shaft_max_rps);
        let d = self.p.prop_diameter_m;
        let j = v_axial_mps.max(0.0) / (n * d);
        let rho_n2_d4 = rho_kgpm3 * n * n * d * d * d * d;
        // Report the power the propeller absorbs: equal to the available power at the root (to
        // rounding), and the physically consistent value when n sits at a clamp.
        let absorbed_w = (self.c_power(j) * rho_n2_d4 * n * d).max(0.0);
        let thrust_n = (self.c_thrust(j) * rho_n2_d4).max(0.0);
        let out = PropulsionOutput {
            thrust_n,
            torque_x_nm: -absorbed_w / (2.0 * std::f64::consts::PI * n),
            power_w: absorbed_w,
            shaft_rps: n,
            fuel_flow_kgps: self.p.fuel_per_energy_kgpj * absorbed_w,
            iterations,
        };
        (out, Some(n_raw))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_have_the_documented_shape() {
        let prop = Propulsion::new(&PropulsionParams::default());
        assert!((prop.c_thrust(0.0) - 0.125).abs() < 1e-15);
        assert!(prop.c_thrust(1.1).abs() < 1e-15);
        assert!((prop.c_power(0.0) - 0.075).abs() < 1e-15);
        // Peak efficiency 0.75–0.80 at J 0.7–0.85 (design target), located on a fine grid.
        let (eta_max, j_max) = (1..1100)
            .map(|i| {
                let j = f64::from(i) * 1e-3;
                (j * prop.c_thrust(j) / prop.c_power(j), j)
            })
            .fold((0.0, 0.0), |acc, x| if x.0 > acc.0 { x } else { acc });
        assert!((0.75..=0.80).contains(&eta_max), "η_max {eta_max}");
        assert!((0.7..=0.85).contains(&j_max), "J at η_max {j_max}");
        // Power absorbed until past zero thrust (windmill brake state starts beyond J₀).
        assert!(prop.c_power(1.1) > 0.0 && prop.c_power(1.35) < 0.0);
    }

    #[test]
    fn engine_power_lapse_and_corner() {
        let prop = Propulsion::new(&PropulsionParams::default());
        assert_eq!(prop.available_power_w(0.0, P0_PA, T0_K), 0.0);
        assert_eq!(prop.available_power_w(f64::NAN, P0_PA, T0_K), 0.0);
        // Far from the corner the min is exact.
        assert!((prop.available_power_w(0.5, P0_PA, T0_K) - 2090.0).abs() < 1e-9);
        // Full throttle at 3,500 m ISA: δ/√θ = 0.6512/√0.9210 = 0.6786 → 2,836 W.
        let (p, t) = (65_780.0, 265.4);
        let lapse = (p / P0_PA) / (t / T0_K).sqrt();
        assert!((prop.available_power_w(1.0, p, t) - 4180.0 * lapse).abs() < 1e-9);
        // At the corner the rounding removes w/4 = 0.005 of P_max.
        assert!((prop.available_power_w(lapse, p, t) - 4180.0 * (lapse - 0.005)).abs() < 1e-9);
    }

    #[test]
    fn power_balance_cubic_and_its_slope() {
        let p = PropulsionParams::default();
        let prop = Propulsion::new(&p);
        let (rho, v, power) = (0.96, 29.0, 700.0);
        let cubic = PowerBalance::new(&p, power, rho, v);
        let d = p.prop_diameter_m;
        for n in [30.0, 55.0, 72.0, 110.0] {
            let direct = prop.c_power(v / (n * d)) * rho * n.powi(3) * d.powi(5) - power;
            // Same polynomial expanded: rounding of terms of ~2,000 W.
            assert!((cubic.value(n) - direct).abs() < 1e-10);
            // Central difference, h = 1e-3 rev/s: truncation a·h² ≈ 4e-8 W/rps, rounding
            // 1e-13/1e-3 ≈ 1e-10.
            let h = 1e-3;
            let fd = (cubic.value(n + h) - cubic.value(n - h)) / (2.0 * h);
            assert!((cubic.slope(n) - fd).abs() < 1e-6 * fd.abs().max(1.0));
        }
    }

    #[test]
    fn engine_off_gives_nothing() {
        let prop = Propulsion::new(&PropulsionParams::default());
        let out = prop.evaluate(0.0, P0_PA, T0_K, 1.225, 30.0, true);
        assert_eq!(out, PropulsionOutput::default());
        let out = prop.evaluate(0.5, P0_PA, T0_K, 1.225, 30.0, false);
        assert_eq!(out.thrust_n, 0.0);
    }
}
