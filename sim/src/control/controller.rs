//! Flight controller (docs/REFERENCES.md A5.2): primary PID loops throttle ← airspeed, elevator ←
//! pitch θ, ailerons ← bank ξ, rudder ← sideslip β (+ yaw damper); secondary loops pressure
//! altitude → θ, air path angle γ_TAS → θ and ground-track bearing χ → ξ; first-order ramp
//! filters on every primary target. Runs on the navigation estimate, never on truth.
//!
//! Mode switches (see `docs/CONTROL.md`): when an operation changes the elevator or aileron
//! mode, the newly engaged outer loop's integral is *initialised*, not zeroed:
//! - altitude or path-angle hold: to the pitch trim estimate of the new steady state,
//!   `θ − γ_TAS + γ_new` (with `θ − γ_TAS ≈ α` wings level; `γ_new` = 0 for altitude hold,
//!   the target for path-angle hold), so neither loop has to integrate up the trim;
//! - bearing hold: to 0, the steady bank of straight flight. With the configured kp 2 this is
//!   also bumpless at the end of the scenarios' turns (5° before the target at 10° bank:
//!   kp·5° = 10°); other jumps are smoothed by the bank ramp. (A bumpless integral
//!   `bank − kp·e` would instead store a bias when the error is large, which the small
//!   bearing integral gain then takes minutes to bleed.)
//!
//! The ramp filters keep their state across switches (only their time constant changes), so
//! no primary target jumps. The primary loops are never reset.

use ianav::math::angle::wrap_pi;
use ianav::math::so3;

use super::config::ControlConfig;
use super::guidance::{air_path_angle_rad, bearing_rad, euler_rates};
use super::pid::{Differentiator, LowPass, Pid};
use super::{AileronTarget, ElevatorTarget, NavEstimate, Operation};
use crate::aircraft::Controls;

/// Elevator-channel mode, to detect switches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ElevatorMode {
    PressureAltitude,
    PathAngle,
    Pitch,
}

/// Aileron-channel mode, to detect switches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum AileronMode {
    Bearing,
    Bank,
}

fn elevator_mode(t: &ElevatorTarget) -> ElevatorMode {
    match t {
        ElevatorTarget::PressureAltitude { .. } => ElevatorMode::PressureAltitude,
        ElevatorTarget::PathAngle { .. } => ElevatorMode::PathAngle,
        ElevatorTarget::Pitch { .. } => ElevatorMode::Pitch,
    }
}

fn aileron_mode(t: &AileronTarget) -> AileronMode {
    match t {
        AileronTarget::Bearing { .. } => AileronMode::Bearing,
        AileronTarget::Bank { .. } => AileronMode::Bank,
    }
}

/// Everything the loops need from one estimate, checked finite.
#[derive(Debug, Clone, Copy)]
struct Measured {
    theta_rad: f64,
    xi_rad: f64,
    theta_dot_rps: f64,
    xi_dot_rps: f64,
    /// Yaw rate about the body z axis (for the yaw damper), rad/s.
    r_rps: f64,
    chi_rad: f64,
    gamma_rad: f64,
    climb_rate_mps: f64,
    tas_mps: f64,
    aos_rad: f64,
    hp_m: f64,
}

impl Measured {
    fn from_nav(nav: &NavEstimate) -> Option<Self> {
        // [ψ, θ, ξ], never NaN for a finite quaternion; at gimbal lock (θ = ±90°, where only
        // ψ ∓ ξ is observable) ξ is set to 0, and the Euler rates are singular there.
        let e = so3::euler_zyx(&nav.q_nb);
        let (theta_rad, xi_rad) = (e.y, e.z);
        let rates = euler_rates(theta_rad, xi_rad, &nav.w_nb_b_rps);
        let m = Self {
            theta_rad,
            xi_rad,
            theta_dot_rps: rates.y,
            xi_dot_rps: rates.z,
            r_rps: nav.w_nb_b_rps.z,
            chi_rad: bearing_rad(nav),
            gamma_rad: air_path_angle_rad(nav),
            climb_rate_mps: -nav.v_ned_mps.z,
            tas_mps: nav.tas_mps,
            aos_rad: nav.aos_rad,
            hp_m: nav.hp_m,
        };
        let all = [
            m.theta_rad,
            m.xi_rad,
            m.theta_dot_rps,
            m.xi_dot_rps,
            m.r_rps,
            m.chi_rad,
            m.gamma_rad,
            m.climb_rate_mps,
            m.tas_mps,
            m.aos_rad,
            m.hp_m,
            e.x,
        ];
        all.iter().all(|v| v.is_finite()).then_some(m)
    }
}

fn op_is_finite(op: &Operation) -> bool {
    let e = match op.elevator {
        ElevatorTarget::PressureAltitude { hp_m } => hp_m,
        ElevatorTarget::PathAngle { gamma_rad } => gamma_rad,
        ElevatorTarget::Pitch { theta_rad } => theta_rad,
    };
    let a = match op.aileron {
        AileronTarget::Bearing { chi_rad } => chi_rad,
        AileronTarget::Bank { xi_rad } => xi_rad,
    };
    op.tas_mps.is_finite() && e.is_finite() && a.is_finite()
}

/// The guidance and control loops of one aircraft.
#[derive(Debug, Clone)]
pub struct Controller {
    dt_s: f64,
    // Primary loops (SI gains: rad, m/s).
    throttle: Pid,
    elevator: Pid,
    aileron: Pid,
    rudder: Pid,
    // Secondary loops.
    altitude: Pid,
    path_angle: Pid,
    bearing: Pid,
    // Target ramps.
    ramp_tas: LowPass,
    ramp_pitch: LowPass,
    ramp_bank: LowPass,
    ramp_sideslip: LowPass,
    ramp_bank_turn_tau_s: f64,
    ramp_bank_bearing_tau_s: f64,
    // Measurement differentiators (derivative terms where no rate is measured).
    d_tas: Differentiator,
    d_gamma: Differentiator,
    d_chi: Differentiator,
    d_aos: Differentiator,
    // Yaw damper: low-pass whose complement is the washed-out yaw-rate error.
    yaw_lowpass: LowPass,
    yaw_washout: bool,
    yaw_damper_gain: f64,
    // Limits on direct targets, rad.
    pitch_limit_rad: f64,
    bank_limit_rad: f64,
    elevator_mode: Option<ElevatorMode>,
    aileron_mode: Option<AileronMode>,
    last: Controls,
    nonfinite_steps: u64,
    /// Whether the ramps were seeded from a finite estimate.
    seeded: bool,
}

impl Controller {
    /// Controller whose target ramps start at the current estimate (no initial jump), with
    /// zero integrals (see [`set_trim`](Self::set_trim)). If `nav` is not finite, the ramps
    /// start at the first finite estimate instead, and until then the command is held.
    pub fn new(cfg: &ControlConfig, nav: &NavEstimate) -> Self {
        let d = 1_f64.to_radians();
        let dt_s = cfg.period_s;
        let m = Measured::from_nav(nav);
        let zero_if_nan = |v: Option<f64>| v.unwrap_or(0.0);
        let r = &cfg.ramp;
        Self {
            dt_s,
            throttle: Pid::new(cfg.throttle.gains(1.0, 1.0)),
            elevator: Pid::new(cfg.elevator.gains(d, d)),
            aileron: Pid::new(cfg.aileron.gains(d, d)),
            rudder: Pid::new(cfg.rudder.gains(d, d)),
            altitude: Pid::new(cfg.altitude.gains(1.0, d)),
            path_angle: Pid::new(cfg.path_angle.gains(d, d)),
            bearing: Pid::new(cfg.bearing.gains(d, d)),
            ramp_tas: LowPass::new(r.tas_s, zero_if_nan(m.map(|m| m.tas_mps))),
            ramp_pitch: LowPass::new(r.pitch_s, zero_if_nan(m.map(|m| m.theta_rad))),
            ramp_bank: LowPass::new(r.bank_turn_s, zero_if_nan(m.map(|m| m.xi_rad))),
            ramp_sideslip: LowPass::new(r.sideslip_s, zero_if_nan(m.map(|m| m.aos_rad))),
            ramp_bank_turn_tau_s: r.bank_turn_s,
            ramp_bank_bearing_tau_s: r.bank_bearing_s,
            d_tas: Differentiator::default(),
            d_gamma: Differentiator::default(),
            d_chi: Differentiator::default(),
            d_aos: Differentiator::default(),
            yaw_lowpass: LowPass::new(cfg.yaw_damper.washout_tau_s, 0.0),
            yaw_washout: cfg.yaw_damper.washout_tau_s > 0.0,
            yaw_damper_gain: cfg.yaw_damper.gain_s,
            pitch_limit_rad: cfg.limits.pitch_deg.to_radians(),
            bank_limit_rad: cfg.limits.bank_deg.to_radians(),
            elevator_mode: None,
            aileron_mode: None,
            last: Controls::default(),
            nonfinite_steps: 0,
            seeded: m.is_some(),
        }
    }

    /// Start the target ramps at the measured values.
    fn seed_ramps(&mut self, m: &Measured) {
        self.ramp_tas.y = m.tas_mps;
        self.ramp_pitch.y = m.theta_rad;
        self.ramp_bank.y = m.xi_rad;
        self.ramp_sideslip.y = m.aos_rad;
        self.seeded = true;
    }

    /// Start from known trim controls (e.g. `Aircraft::trim`): the primary integrals are set
    /// so that zero errors reproduce `u`, which is also the command held until the first
    /// finite estimate.
    pub fn set_trim(&mut self, u: &Controls) {
        self.throttle.reset_to(u.throttle);
        self.elevator.reset_to(u.elevator_rad);
        self.aileron.reset_to(u.aileron_rad);
        self.rudder.reset_to(u.rudder_rad);
        self.last = *u;
    }

    /// Control period, s.
    pub fn period_s(&self) -> f64 {
        self.dt_s
    }

    /// The last command.
    pub fn last_command(&self) -> Controls {
        self.last
    }

    /// Number of steps whose estimate (or operation) was not finite and whose command was
    /// therefore held.
    pub fn nonfinite_steps(&self) -> u64 {
        self.nonfinite_steps
    }

    /// Current (ramped) primary targets: airspeed m/s, pitch rad, bank rad, sideslip rad.
    pub fn targets(&self) -> [f64; 4] {
        [
            self.ramp_tas.y,
            self.ramp_pitch.y,
            self.ramp_bank.y,
            self.ramp_sideslip.y,
        ]
    }

    /// One control step (period [`period_s`](Self::period_s)) flying operation `op` on the
    /// estimate `nav`. Returns throttle in [0, 1] and surface deflections in rad.
    pub fn step(&mut self, op: &Operation, nav: &NavEstimate) -> Controls {
        let Some(m) = Measured::from_nav(nav).filter(|_| op_is_finite(op)) else {
            self.nonfinite_steps += 1;
            return self.last;
        };
        if !self.seeded {
            self.seed_ramps(&m);
        }
        let dt = self.dt_s;

        // Elevator channel: outer loop → pitch target → ramp → elevator.
        let e_mode = elevator_mode(&op.elevator);
        let e_switch = self.elevator_mode != Some(e_mode);
        self.elevator_mode = Some(e_mode);
        let theta_raw = match op.elevator {
            ElevatorTarget::PressureAltitude { hp_m } => {
                let err = hp_m - m.hp_m;
                if e_switch {
                    self.altitude.reset_to(m.theta_rad - m.gamma_rad);
                }
                // dHp/dt ≈ dh/dt = −v_D: the ratio T_ISA/T (a few %) only scales the damping.
                self.altitude.step(err, m.climb_rate_mps, dt)
            }
            ElevatorTarget::PathAngle { gamma_rad } => {
                if e_switch {
                    self.path_angle
                        .reset_to(m.theta_rad - m.gamma_rad + gamma_rad);
                    self.d_gamma.reset();
                }
                let rate = self.d_gamma.rate(m.gamma_rad, dt);
                self.path_angle.step(gamma_rad - m.gamma_rad, rate, dt)
            }
            ElevatorTarget::Pitch { theta_rad } => {
                clamp_safe(theta_rad, -self.pitch_limit_rad, self.pitch_limit_rad)
            }
        };
        let theta_c = self.ramp_pitch.step(theta_raw, dt);
        let elevator = self
            .elevator
            .step(theta_c - m.theta_rad, m.theta_dot_rps, dt);

        // Aileron channel: bearing loop or direct bank → ramp → ailerons.
        let a_mode = aileron_mode(&op.aileron);
        let a_switch = self.aileron_mode != Some(a_mode);
        self.aileron_mode = Some(a_mode);
        let xi_raw = match op.aileron {
            AileronTarget::Bearing { chi_rad } => {
                let err = wrap_pi(chi_rad - m.chi_rad);
                if a_switch {
                    self.ramp_bank.tau_s = self.ramp_bank_bearing_tau_s;
                    self.bearing.reset();
                    self.d_chi.reset();
                }
                let rate = self.d_chi.rate_angle(m.chi_rad, dt);
                self.bearing.step(err, rate, dt)
            }
            AileronTarget::Bank { xi_rad } => {
                if a_switch {
                    self.ramp_bank.tau_s = self.ramp_bank_turn_tau_s;
                }
                clamp_safe(xi_rad, -self.bank_limit_rad, self.bank_limit_rad)
            }
        };
        let xi_c = self.ramp_bank.step(xi_raw, dt);
        let aileron = self.aileron.step(xi_c - m.xi_rad, m.xi_dot_rps, dt);

        // Throttle channel.
        let tas_c = self.ramp_tas.step(op.tas_mps, dt);
        let tas_rate = self.d_tas.rate(m.tas_mps, dt);
        let throttle = self.throttle.step(tas_c - m.tas_mps, tas_rate, dt);

        // Rudder: sideslip to zero plus the yaw damper on the yaw rate in excess of the
        // coordinated-turn rate (so it damps the Dutch roll without opposing turns, and
        // leads the yaw on roll-in against the adverse yaw), optionally washed out.
        let beta_c = self.ramp_sideslip.step(0.0, dt);
        let aos_rate = self.d_aos.rate(m.aos_rad, dt);
        let rudder_pid = self.rudder.step(beta_c - m.aos_rad, aos_rate, dt);
        let r_coord = STANDARD_GRAVITY_MPS2 * m.xi_rad.sin() * m.theta_rad.cos()
            / m.tas_mps.max(MIN_TAS_FOR_COORDINATION_MPS);
        let r_err = m.r_rps - r_coord;
        let r_washed = if self.yaw_washout {
            r_err - self.yaw_lowpass.step(r_err, dt)
        } else {
            r_err
        };
        let g = &self.rudder.gains;
        let rudder = clamp_safe(
            rudder_pid + self.yaw_damper_gain * r_washed,
            g.out_min,
            g.out_max,
        );

        self.last = Controls {
            throttle,
            elevator_rad: elevator,
            aileron_rad: aileron,
            rudder_rad: rudder,
        };
        self.last
    }
}

/// Gravity used in the coordinated-turn yaw rate `r = g·sin ξ·cos θ / V`, m/s² (a reference
/// for the damper only; the local value differs by < 0.3 %).
const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;
/// Airspeed floor of the coordinated-turn rate (avoids dividing by ~0 on the ground), m/s.
const MIN_TAS_FOR_COORDINATION_MPS: f64 = 5.0;

/// `max(min(x, hi), lo)`: never panics, unlike `f64::clamp` with unvalidated limits.
fn clamp_safe(x: f64, lo: f64, hi: f64) -> f64 {
    x.min(hi).max(lo)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::Trigger;
    use ianav::math::wgs84::Geodetic;
    use nalgebra::{UnitQuaternion, Vector3};

    /// Estimate of a wings-level aircraft (or banked by `xi_deg`) flying bearing `chi_deg` at
    /// 29 m/s with pitch 2°, α 2° (so γ_TAS = 0).
    fn nav(chi_deg: f64, xi_deg: f64, hp_m: f64) -> NavEstimate {
        let chi = chi_deg.to_radians();
        NavEstimate {
            t_us: 0,
            pos: Geodetic {
                lat_rad: 0.7,
                lon_rad: -1.5,
                h_m: hp_m,
            },
            v_ned_mps: Vector3::new(29.0 * chi.cos(), 29.0 * chi.sin(), 0.0),
            q_nb: UnitQuaternion::from_euler_angles(xi_deg.to_radians(), 2_f64.to_radians(), chi),
            w_nb_b_rps: Vector3::zeros(),
            tas_mps: 29.0,
            aoa_rad: 2_f64.to_radians(),
            aos_rad: 0.0,
            hp_m,
        }
    }

    fn op(elevator: ElevatorTarget, aileron: AileronTarget) -> Operation {
        Operation {
            tas_mps: 29.0,
            elevator,
            aileron,
            trigger: Trigger::Time { t_s: 1e9 },
        }
    }

    const HOLD: ElevatorTarget = ElevatorTarget::PressureAltitude { hp_m: 2700.0 };

    #[test]
    fn ramps_start_at_the_estimate() {
        let n = nav(30.0, 5.0, 2700.0);
        let c = Controller::new(&ControlConfig::default(), &n);
        let t = c.targets();
        assert!((t[0] - 29.0).abs() < 1e-12);
        assert!((t[1] - 2_f64.to_radians()).abs() < 1e-12);
        assert!((t[2] - 5_f64.to_radians()).abs() < 1e-12);
        assert!(t[3].abs() < 1e-12);
    }

    #[test]
    fn trimmed_start_holds_trim_without_a_jump() {
        // On target in every channel, with trim controls set, the first command is the trim
        // (all errors and rates zero; the climb rate is 0 and the altitude integral starts at
        // θ − γ = θ, the current pitch).
        let n = nav(30.0, 0.0, 2700.0);
        let mut c = Controller::new(&ControlConfig::default(), &n);
        let trim = Controls {
            throttle: 0.3,
            elevator_rad: -0.02,
            aileron_rad: 0.001,
            rudder_rad: 0.002,
        };
        c.set_trim(&trim);
        let u = c.step(
            &op(
                HOLD,
                AileronTarget::Bearing {
                    chi_rad: 30_f64.to_radians(),
                },
            ),
            &n,
        );
        assert!((u.throttle - trim.throttle).abs() < 1e-9);
        assert!((u.elevator_rad - trim.elevator_rad).abs() < 1e-9);
        assert!((u.aileron_rad - trim.aileron_rad).abs() < 1e-9);
        assert!((u.rudder_rad - trim.rudder_rad).abs() < 1e-9);
    }

    #[test]
    fn nonfinite_estimate_holds_the_command() {
        let cfg = ControlConfig::default();
        let n = nav(0.0, 0.0, 2700.0);
        let mut c = Controller::new(&cfg, &n);
        let o = op(HOLD, AileronTarget::Bearing { chi_rad: 0.3 });
        let u0 = c.step(&o, &n);
        for corrupt in [
            |n: &mut NavEstimate| n.tas_mps = f64::NAN,
            |n: &mut NavEstimate| n.hp_m = f64::INFINITY,
            |n: &mut NavEstimate| n.v_ned_mps.x = f64::NAN,
            |n: &mut NavEstimate| n.w_nb_b_rps.z = f64::NAN,
            |n: &mut NavEstimate| n.aos_rad = f64::NAN,
        ] {
            let mut bad = n;
            corrupt(&mut bad);
            assert_eq!(c.step(&o, &bad), u0);
        }
        // A NaN quaternion too.
        let mut bad = n;
        bad.q_nb =
            UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(f64::NAN, 0.0, 0.0, 0.0));
        assert_eq!(c.step(&o, &bad), u0);
        // A non-finite target as well.
        let mut bad_op = o;
        bad_op.tas_mps = f64::NAN;
        assert_eq!(c.step(&bad_op, &n), u0);
        assert_eq!(c.nonfinite_steps(), 7);
        // The state was not polluted: the next finite step gives finite commands.
        let u = c.step(&o, &n);
        for v in [u.throttle, u.elevator_rad, u.aileron_rad, u.rudder_rad] {
            assert!(v.is_finite());
        }
        // A controller created on a NaN estimate holds until the estimate is finite.
        let mut bad = n;
        bad.tas_mps = f64::NAN;
        let mut c = Controller::new(&cfg, &bad);
        assert_eq!(c.step(&o, &bad), Controls::default());
        c.step(&o, &n);
        // ... and its ramps start at that first finite estimate, not at 0.
        assert!((c.targets()[0] - 29.0).abs() < 1e-9);
        assert!((c.targets()[1] - 2_f64.to_radians()).abs() < 1e-9);
    }

    #[test]
    fn turn_to_bearing_hold_is_bumpless() {
        // Turn at 10° bank until the ramp has converged, then switch to bearing hold 5° ahead
        // (the scenarios' turn lead): with kp = 2 and the integral reset to 0, the bearing
        // loop's proportional term alone asks for exactly the turn's 10°.
        let cfg = ControlConfig::default();
        let n = nav(85.0, 10.0, 2700.0);
        let mut c = Controller::new(&cfg, &n);
        let turn = op(
            HOLD,
            AileronTarget::Bank {
                xi_rad: 10_f64.to_radians(),
            },
        );
        for _ in 0..500 {
            c.step(&turn, &n);
        }
        let before = c.targets()[2];
        assert!((before.to_degrees() - 10.0).abs() < 1e-6);
        c.step(
            &op(
                HOLD,
                AileronTarget::Bearing {
                    chi_rad: 90_f64.to_radians(),
                },
            ),
            &n,
        );
        let after = c.targets()[2];
        // One step of the rate term at most: χ̇ is 0 on the first sample after the switch.
        assert!(
            (after - before).abs() < 1e-9,
            "{} → {}",
            before.to_degrees(),
            after.to_degrees()
        );
    }

    #[test]
    fn altitude_hold_after_climb_starts_from_level_trim() {
        // Climbing at γ = 2° (θ 4°, α 2°) then switching to altitude hold on target: the hold's
        // integral starts at θ − γ = α = 2° (level-flight pitch), and the climb-rate damping
        // lowers the pitch target below that (to arrest the climb) — never above θ.
        let cfg = ControlConfig::default();
        let mut n = nav(0.0, 0.0, 3000.0);
        n.q_nb = UnitQuaternion::from_euler_angles(0.0, 4_f64.to_radians(), 0.0);
        n.v_ned_mps.z = -29.0 * 2_f64.to_radians().sin();
        let mut c = Controller::new(&cfg, &n);
        let climb = op(
            ElevatorTarget::PathAngle {
                gamma_rad: 2_f64.to_radians(),
            },
            AileronTarget::Bank { xi_rad: 0.0 },
        );
        for _ in 0..200 {
            c.step(&climb, &n);
        }
        // On target: the path-angle integral initialised at θ − γ + γ_t = 4° holds.
        assert!((c.targets()[1].to_degrees() - 4.0).abs() < 1e-6);
        c.step(
            &op(
                ElevatorTarget::PressureAltitude { hp_m: 3000.0 },
                AileronTarget::Bank { xi_rad: 0.0 },
            ),
            &n,
        );
        assert!((c.altitude.integral().to_degrees() - 2.0).abs() < 1e-9);
        let theta_c = c.targets()[1].to_degrees();
        assert!(theta_c < 4.0, "{theta_c}");
    }

    #[test]
    fn bearing_error_wraps_across_180_degrees() {
        // Flying 179°, target −179°: the short way is 2° to the right, so the bank target is
        // +kp·2° = +4° (not −716°, nor clamped at −15°); mirrored for the left.
        let cfg = ControlConfig::default();
        for (chi, target, expect_deg) in [(179.0, -179.0, 4.0), (-179.0, 179.0, -4.0)] {
            let n = nav(chi, 0.0, 2700.0);
            let mut c = Controller::new(&cfg, &n);
            let o = op(
                HOLD,
                AileronTarget::Bearing {
                    chi_rad: f64::to_radians(target),
                },
            );
            for _ in 0..100 {
                c.step(&o, &n);
            }
            // 2 s: the ramp has converged; the integral adds ki·e·t = 0.02·2·2 = 0.08°.
            let xi_c = c.targets()[2].to_degrees();
            assert!((xi_c - expect_deg).abs() < 0.1, "{chi} → {target}: {xi_c}");
        }
    }
}
