//! Discrete PID loop and first-order filters of the guidance and control (docs/REFERENCES.md A5.2).
//!
//! Unlike the authors' per-step form (no Δt scaling, derivative on the filtered *error*,
//! plain accumulator), this PID is written in continuous-time units and discretised with the
//! step `dt_s`, so its gains do not change meaning with the control rate:
//!
//! `u = clamp(I + Kp·e − Kd·ẏ_f, [u_min, u_max])`,
//! `ẏ_f = LPF_τd(ẏ)` (derivative on the filtered *measurement*, so target steps do not kick),
//! `I ← clamp(I + Ki·e·Δt + (u − u_unsat)·Δt/T_t, ±I_max)` (back-calculation anti-windup
//! with tracking time constant `T_t`), or, with `T_t = 0`, conditional integration (the
//! integral is frozen while the output is saturated and the error would drive it further in).
//! Either way the integral term is also hard-clamped to `±I_max` and to the output range.
//!
//! The integral is stored as its contribution to the output (output units), so a change of
//! gains or a bumpless transfer only needs the integral term to be set, never rescaled.

use ianav::math::angle::wrap_pi;

/// Gains and limits of one PID loop, in SI units (rad, m, m/s, s) of its input and output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidGains {
    /// Proportional gain, output per input.
    pub kp: f64,
    /// Integral gain, output per (input · s).
    pub ki: f64,
    /// Derivative gain on the measurement rate, output per (input / s).
    pub kd: f64,
    /// Time constant of the first-order filter on the measurement rate, s (0: no filter).
    pub d_filter_tau_s: f64,
    /// Back-calculation tracking time constant, s (0: conditional integration instead).
    pub tracking_tau_s: f64,
    /// Largest magnitude of the integral term, output units.
    pub integral_limit: f64,
    /// Lower output limit.
    pub out_min: f64,
    /// Upper output limit.
    pub out_max: f64,
}

/// First-order low-pass filter `y ← y + a·(u − y)` with `a = Δt/(τ + Δt)` (backward Euler:
/// unconditionally stable and exact in the limit τ → 0, where it passes the input through).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass {
    /// Time constant, s.
    pub tau_s: f64,
    /// Filter state.
    pub y: f64,
}

impl LowPass {
    /// Filter with time constant `tau_s` starting at `y0`.
    pub fn new(tau_s: f64, y0: f64) -> Self {
        Self { tau_s, y: y0 }
    }

    /// Gain `a` of one step of `dt_s`.
    fn gain(&self, dt_s: f64) -> f64 {
        if self.tau_s > 0.0 {
            dt_s / (self.tau_s + dt_s)
        } else {
            1.0
        }
    }

    /// Advance one step of `dt_s` with input `u`; returns the new output.
    pub fn step(&mut self, u: f64, dt_s: f64) -> f64 {
        self.y += self.gain(dt_s) * (u - self.y);
        self.y
    }

    /// Advance one step for an *angle* input: the filter moves along the shortest arc and its
    /// state stays wrapped to (−π, π].
    pub fn step_angle(&mut self, u_rad: f64, dt_s: f64) -> f64 {
        self.y = wrap_pi(self.y + self.gain(dt_s) * wrap_pi(u_rad - self.y));
        self.y
    }
}

/// Rate of a sampled signal by backward difference (`0` on the first sample), optionally
/// wrapping the increment of an angle so a ±180° crossing is not seen as a huge rate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Differentiator {
    prev: Option<f64>,
}

impl Differentiator {
    /// `(x − x_prev)/Δt`, or 0 on the first call after a reset.
    pub fn rate(&mut self, x: f64, dt_s: f64) -> f64 {
        let r = self.prev.map_or(0.0, |p| (x - p) / dt_s);
        self.prev = Some(x);
        r
    }

    /// Same for an angle, wrapping the increment.
    pub fn rate_angle(&mut self, x_rad: f64, dt_s: f64) -> f64 {
        let r = self.prev.map_or(0.0, |p| wrap_pi(x_rad - p) / dt_s);
        self.prev = Some(x_rad);
        r
    }

    /// Forget the previous sample.
    pub fn reset(&mut self) {
        self.prev = None;
    }
}

/// One PID loop (see the module documentation for the law).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pid {
    /// Gains and limits.
    pub gains: PidGains,
    /// Integral term, in output units.
    integral: f64,
    /// Filtered measurement rate.
    rate_filter: LowPass,
    /// Whether the rate filter has been seeded (the first rate passes through unfiltered so a
    /// loop engaged mid-manoeuvre does not see a derivative transient).
    rate_seeded: bool,
    /// Last (saturated) output.
    last_output: f64,
}

impl Pid {
    /// Loop with zero integral.
    pub fn new(gains: PidGains) -> Self {
        Self {
            gains,
            integral: 0.0,
            rate_filter: LowPass::new(gains.d_filter_tau_s, 0.0),
            rate_seeded: false,
            last_output: 0.0,
        }
    }

    /// The integral term, output units.
    pub fn integral(&self) -> f64 {
        self.integral
    }

    /// The last output.
    pub fn last_output(&self) -> f64 {
        self.last_output
    }

    /// Clear the integral and the derivative filter.
    pub fn reset(&mut self) {
        self.reset_to(0.0);
    }

    /// Set the integral term (clamped to the output range) and restart the derivative filter.
    pub fn reset_to(&mut self, integral: f64) {
        self.integral = self.clamp_integral(integral);
        self.rate_seeded = false;
    }

    /// Clamp an integral value to `±integral_limit` and to the output range.
    fn clamp_integral(&self, i: f64) -> f64 {
        let g = &self.gains;
        let i = clamp_nan_safe(i, -g.integral_limit, g.integral_limit);
        let i = clamp_nan_safe(i, g.out_min, g.out_max);
        // A NaN integral (only possible from NaN gains, which the config rejects) restarts at 0.
        if i.is_finite() { i } else { 0.0 }
    }

    /// Bumpless transfer: choose the integral so that, with error `error` and no derivative
    /// contribution, the next output equals `output` (clamped to the range). The derivative
    /// term is deliberately left out: it then acts at once as damping of the motion in
    /// progress (e.g. the climb rate when an altitude hold engages after a climb).
    pub fn transfer_to(&mut self, output: f64, error: f64) {
        self.reset_to(output - self.gains.kp * error);
    }

    /// One step: error `e = target − measured`, measurement rate `meas_rate` (its time
    /// derivative, from a sensor or a [`Differentiator`]), step `dt_s`. Returns the clamped
    /// output. Non-finite inputs leave the state untouched and return the last output.
    pub fn step(&mut self, e: f64, meas_rate: f64, dt_s: f64) -> f64 {
        if !(e.is_finite() && meas_rate.is_finite() && dt_s.is_finite() && dt_s > 0.0) {
            return self.last_output;
        }
        let g = &self.gains;
        let rate_f = if self.rate_seeded {
            self.rate_filter.step(meas_rate, dt_s)
        } else {
            self.rate_seeded = true;
            self.rate_filter.y = meas_rate;
            meas_rate
        };
        let unsat = self.integral + g.kp * e - g.kd * rate_f;
        let u = clamp_nan_safe(unsat, g.out_min, g.out_max);
        let di = g.ki * e * dt_s;
        let next = if g.tracking_tau_s > 0.0 {
            // Back-calculation: bleed the integral by the saturation excess. The factor is
            // capped at 1 so a tracking time constant shorter than the step cannot overshoot.
            self.integral + di + (u - unsat) * (dt_s / g.tracking_tau_s).min(1.0)
        } else if (unsat > g.out_max && di > 0.0) || (unsat < g.out_min && di < 0.0) {
            // Conditional integration: saturated and the error pushes further in.
            self.integral
        } else {
            self.integral + di
        };
        self.integral = self.clamp_integral(next);
        self.last_output = u;
        u
    }
}

/// `clamp` that never panics (f64::clamp panics if min > max or either is NaN): the result
/// is `max(min(x, hi), lo)`.
fn clamp_nan_safe(x: f64, lo: f64, hi: f64) -> f64 {
    x.min(hi).max(lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gains() -> PidGains {
        PidGains {
            kp: 2.0,
            ki: 1.0,
            kd: 0.0,
            d_filter_tau_s: 0.0,
            tracking_tau_s: 0.5,
            integral_limit: 1.0,
            out_min: -1.0,
            out_max: 1.0,
        }
    }

    #[test]
    fn integral_is_dt_aware() {
        // Constant error 0.1 for 1 s: the integral must be Ki·e·t = 0.1 whatever the step.
        for dt in [0.001, 0.02, 0.1] {
            let mut pid = Pid::new(gains());
            let n = (1.0 / dt) as usize;
            for _ in 0..n {
                pid.step(0.1, 0.0, dt);
            }
            assert!((pid.integral() - 0.1).abs() < 1e-9, "dt {dt}");
        }
    }

    #[test]
    fn anti_windup_limits_integral_and_recovers_fast() {
        // Saturate with a large error for 100 s, then reverse the error: a naive integrator
        // would hold Ki·e·t = 100 and stay saturated for ~100 s; with back-calculation the
        // integral stays near the limit (the steady state of the tracking law is
        // I = u_max − Kp·e + Ki·e·T_t ≤ u_max, then clamped), and the output leaves
        // saturation within a few tracking time constants.
        let mut pid = Pid::new(gains());
        let dt = 0.02;
        for _ in 0..5000 {
            let u = pid.step(1.0, 0.0, dt);
            assert!(u <= 1.0);
        }
        assert!(pid.integral() <= 1.0 + 1e-12);
        // With e = −0.1 the unsaturated output is I − 0.2 < 1: out of saturation at once.
        let u = pid.step(-0.1, 0.0, dt);
        assert!(u < 1.0, "output {u}");
        // Conditional integration (no tracking): the integral stops as soon as the output
        // saturates. Kp·e = 0.2 alone does not saturate; the integral grows at Ki·e = 0.1/s
        // until I + 0.2 = 1, i.e. I = 0.8 (± one step's increment), and stays there.
        let mut g = gains();
        g.tracking_tau_s = 0.0;
        let mut pid = Pid::new(g);
        for _ in 0..5000 {
            pid.step(0.1, 0.0, dt);
        }
        assert!(
            (pid.integral() - 0.8).abs() <= 0.1 * dt + 1e-12,
            "{}",
            pid.integral()
        );
        // The explicit integral limit binds before the output range.
        g.integral_limit = 0.3;
        let mut pid = Pid::new(g);
        for _ in 0..5000 {
            pid.step(0.1, 0.0, dt);
        }
        assert!((pid.integral() - 0.3).abs() < 1e-12);
    }

    #[test]
    fn derivative_acts_on_measurement_not_on_target_steps() {
        let mut g = gains();
        g.ki = 0.0;
        g.kd = 0.5;
        g.d_filter_tau_s = 0.1;
        let mut pid = Pid::new(g);
        // A target step changes the error but not the measurement rate: output is Kp·e only.
        let u = pid.step(0.2, 0.0, 0.02);
        assert!((u - 0.4).abs() < 1e-12);
        // A measured rate opposes the motion (damping) once filtered in.
        let mut u = 0.0;
        for _ in 0..100 {
            u = pid.step(0.0, 1.0, 0.02);
        }
        assert!((u + 0.5).abs() < 1e-6);
    }

    #[test]
    fn bumpless_transfer_reproduces_output() {
        let mut pid = Pid::new(gains());
        pid.transfer_to(0.3, 0.1);
        let u = pid.step(0.1, 0.0, 1e-9);
        assert!((u - 0.3).abs() < 1e-6);
    }

    #[test]
    fn nan_inputs_do_not_propagate() {
        let mut pid = Pid::new(gains());
        let u0 = pid.step(0.1, 0.0, 0.02);
        let u = pid.step(f64::NAN, 0.0, 0.02);
        assert_eq!(u, u0);
        let u = pid.step(0.1, f64::INFINITY, 0.02);
        assert_eq!(u, u0);
        assert!(pid.integral().is_finite());
    }

    #[test]
    fn low_pass_and_angle_ramp() {
        let mut f = LowPass::new(1.0, 0.0);
        for _ in 0..1000 {
            f.step(1.0, 0.01);
        }
        // After 10 τ the backward-Euler filter is within (1+Δt/τ)^−1000 ≈ e^−9.95 of the input.
        assert!((f.y - 1.0).abs() < 1e-4);
        // The angle ramp from 170° towards −170° goes through 180°, not through 0°.
        let mut a = LowPass::new(0.5, 170_f64.to_radians());
        let mut max_abs: f64 = 0.0;
        for _ in 0..500 {
            let y = a.step_angle((-170_f64).to_radians(), 0.02);
            max_abs = max_abs.max(y.abs());
            assert!(y.abs() >= 169.999_f64.to_radians());
        }
        assert!((a.y.to_degrees() + 170.0).abs() < 1e-3);
        assert!(max_abs > 179.0_f64.to_radians());
        // τ = 0 passes through.
        let mut p = LowPass::new(0.0, 0.0);
        assert_eq!(p.step(3.0, 0.02), 3.0);
    }

    #[test]
    fn differentiator_wraps_angles() {
        let mut d = Differentiator::default();
        assert_eq!(d.rate_angle(179_f64.to_radians(), 0.02), 0.0);
        let r = d.rate_angle((-179_f64).to_radians(), 0.02);
        assert!((r.to_degrees() - 100.0).abs() < 1e-9);
    }
}
