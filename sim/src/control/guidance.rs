//! Guidance (docs/REFERENCES.md A5.1): a mission is a list of [`Operation`]s, each ended by its
//! [`Trigger`]; plus the flight-path quantities guidance and control read off the navigation
//! estimate (Euler rates, ground-track bearing χ, air path angle γ_TAS; the Euler angles
//! themselves come from [`ianav::math::so3::euler_zyx`]).
//!
//! Triggers on a continuous value fire when `sign(value − threshold)` differs from its sign
//! when the operation started (so the threshold may be approached from either side). Bearing
//! triggers use the wrapped difference and are *inactive* while it exceeds ±90°: the sign
//! reference is taken at the first active sample, which avoids the false sign flip of the
//! ±180° wrap on the far side of the circle. Time triggers fire once `t ≥ threshold`.

use std::f64::consts::FRAC_PI_2;

use ianav::math::angle::wrap_pi;
use nalgebra::Vector3;
use thiserror::Error;

use super::{AileronTarget, ElevatorTarget, NavEstimate, Operation, Trigger};

/// Euler angle rates `(ψ̇, θ̇, ξ̇)` from the body rates relative to NED `ω_nb^b = (p, q, r)`
/// (standard ZYX kinematics; singular only at θ = ±90°, where the result is non-finite and
/// the controller holds its last command).
pub fn euler_rates(theta_rad: f64, xi_rad: f64, w_nb_b_rps: &Vector3<f64>) -> Vector3<f64> {
    let (p, q, r) = (w_nb_b_rps.x, w_nb_b_rps.y, w_nb_b_rps.z);
    let (s, c) = xi_rad.sin_cos();
    let qr = q * s + r * c;
    Vector3::new(
        qr / theta_rad.cos(),
        q * c - r * s,
        p + qr * theta_rad.tan(),
    )
}

/// Ground-track bearing χ = atan2(v_E, v_N), rad in (−π, π].
pub fn bearing_rad(nav: &NavEstimate) -> f64 {
    nav.v_ned_mps.y.atan2(nav.v_ned_mps.x)
}

/// Air velocity direction in body axes from α and β: `v_tas_b / V`.
pub fn air_direction_b(aoa_rad: f64, aos_rad: f64) -> Vector3<f64> {
    let (sa, ca) = aoa_rad.sin_cos();
    let (sb, cb) = aos_rad.sin_cos();
    Vector3::new(ca * cb, sb, sa * cb)
}

/// Air path angle γ_TAS = −asin(v_tas_D / V) with `v_tas_n = q_nb · v_tas_b(V, α, β)`, rad.
/// Only the direction of the air velocity matters, so V does not enter (no division by a
/// possibly tiny airspeed); the argument is clamped to [−1, 1] against rounding.
pub fn air_path_angle_rad(nav: &NavEstimate) -> f64 {
    let dir_n = nav.q_nb * air_direction_b(nav.aoa_rad, nav.aos_rad);
    -dir_n.z.clamp(-1.0, 1.0).asin()
}

/// Errors of a guidance plan.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GuidanceError {
    /// The plan has no operation.
    #[error("the guidance plan has no operation")]
    Empty,
    /// A target or threshold is not finite (or a duration is negative).
    #[error("operation {index}: {field} is not a finite value ({value})")]
    BadValue {
        /// Index of the operation.
        index: usize,
        /// Offending field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
}

/// Check that every number of an operation is usable.
fn validate(index: usize, op: &Operation) -> Result<(), GuidanceError> {
    let bad = |field: &'static str, value: f64| {
        if value.is_finite() {
            Ok(())
        } else {
            Err(GuidanceError::BadValue {
                index,
                field,
                value,
            })
        }
    };
    bad("tas_mps", op.tas_mps)?;
    match op.elevator {
        ElevatorTarget::PressureAltitude { hp_m } => bad("elevator.hp_m", hp_m)?,
        ElevatorTarget::PathAngle { gamma_rad } => bad("elevator.gamma_rad", gamma_rad)?,
        ElevatorTarget::Pitch { theta_rad } => bad("elevator.theta_rad", theta_rad)?,
    }
    match op.aileron {
        AileronTarget::Bearing { chi_rad } => bad("aileron.chi_rad", chi_rad)?,
        AileronTarget::Bank { xi_rad } => bad("aileron.xi_rad", xi_rad)?,
    }
    match op.trigger {
        Trigger::Time { t_s } => bad("trigger.t_s", t_s)?,
        Trigger::Elapsed { dt_s } => {
            bad("trigger.dt_s", dt_s)?;
            if dt_s < 0.0 {
                return Err(GuidanceError::BadValue {
                    index,
                    field: "trigger.dt_s",
                    value: dt_s,
                });
            }
        }
        Trigger::PressureAltitude { hp_m } => bad("trigger.hp_m", hp_m)?,
        Trigger::Bearing { chi_rad } => bad("trigger.chi_rad", chi_rad)?,
    }
    Ok(())
}

/// Signed distance of the estimate from a sign-change trigger's threshold, or `None` for
/// time triggers and for an inactive bearing trigger (more than 90° away) or a non-finite
/// estimate.
fn trigger_offset(trigger: &Trigger, nav: &NavEstimate) -> Option<f64> {
    let d = match *trigger {
        Trigger::Time { .. } | Trigger::Elapsed { .. } => return None,
        Trigger::PressureAltitude { hp_m } => nav.hp_m - hp_m,
        Trigger::Bearing { chi_rad } => {
            let d = wrap_pi(bearing_rad(nav) - chi_rad);
            if d.abs() > FRAC_PI_2 {
                return None;
            }
            d
        }
    };
    d.is_finite().then_some(d)
}

/// Sign with zero kept apart (reaching the threshold exactly counts as crossing it).
fn sign3(x: f64) -> i8 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

/// Sign-change detector of one operation's trigger.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TriggerState {
    /// Sign of `value − threshold` at the first active sample (`None` until then).
    reference: Option<i8>,
}

impl TriggerState {
    /// Whether `trigger` fires at mission time `t_s` for an operation that started at
    /// `op_start_s`. The first active sample of a sign-change trigger fixes the reference
    /// sign; it fires at once only if the value sits exactly on the threshold.
    pub fn fires(
        &mut self,
        trigger: &Trigger,
        t_s: f64,
        op_start_s: f64,
        nav: &NavEstimate,
    ) -> bool {
        match *trigger {
            Trigger::Time { t_s: t_end } => t_s >= t_end,
            Trigger::Elapsed { dt_s } => t_s - op_start_s >= dt_s,
            Trigger::PressureAltitude { .. } | Trigger::Bearing { .. } => {
                let Some(d) = trigger_offset(trigger, nav) else {
                    // Inactive bearing (or no usable estimate): forget the reference so it is
                    // taken afresh when the bearing comes back within ±90°.
                    if matches!(trigger, Trigger::Bearing { .. }) {
                        self.reference = None;
                    }
                    return false;
                };
                let s = sign3(d);
                match self.reference {
                    None => {
                        self.reference = Some(s);
                        s == 0
                    }
                    Some(r) => s != r,
                }
            }
        }
    }
}

/// Placeholder flown by a plan built from no operation: non-finite targets, which the
/// controller answers by holding its last command (and counting the step).
const NO_OPERATION: Operation = Operation {
    tas_mps: f64::NAN,
    elevator: ElevatorTarget::Pitch {
        theta_rad: f64::NAN,
    },
    aileron: AileronTarget::Bank { xi_rad: f64::NAN },
    trigger: Trigger::Time {
        t_s: f64::NEG_INFINITY,
    },
};

/// The guidance: the operations, the current one and when it started.
#[derive(Debug, Clone, PartialEq)]
pub struct Guidance {
    ops: Vec<Operation>,
    index: usize,
    /// Mission time at which the current operation started (`None` before the first
    /// [`update`](Self::update), whose time starts operation 0).
    op_start_s: Option<f64>,
    trigger: TriggerState,
    finished: bool,
}

impl Guidance {
    /// Plan starting with operation 0 at the time of the first [`update`](Self::update).
    /// Never fails: an empty plan is finished at once and flies a placeholder with non-finite
    /// targets (the controller then holds its command); use [`try_new`](Self::try_new) to
    /// reject empty or non-finite plans instead.
    pub fn new(ops: Vec<Operation>) -> Self {
        let finished = ops.is_empty();
        let ops = if finished { vec![NO_OPERATION] } else { ops };
        Self {
            ops,
            index: 0,
            op_start_s: None,
            trigger: TriggerState::default(),
            finished,
        }
    }

    /// [`new`](Self::new) after checking that the plan is not empty and that every target and
    /// threshold is finite (and durations non-negative).
    pub fn try_new(ops: Vec<Operation>) -> Result<Self, GuidanceError> {
        if ops.is_empty() {
            return Err(GuidanceError::Empty);
        }
        for (i, op) in ops.iter().enumerate() {
            validate(i, op)?;
        }
        Ok(Self::new(ops))
    }

    /// Evaluate the current operation's trigger at mission time `t_s`; when it fires, move to
    /// the next operation (started at `t_s`) and return its index. When the last operation's
    /// trigger fires the plan is [`finished`](Self::finished) and the last operation stays
    /// current (the aircraft keeps flying it). At most one transition per call.
    pub fn update(&mut self, t_s: f64, nav: &NavEstimate) -> Option<usize> {
        if self.finished {
            return None;
        }
        let op_start_s = *self.op_start_s.get_or_insert(t_s);
        let op = self.ops[self.index];
        if !self.trigger.fires(&op.trigger, t_s, op_start_s, nav) {
            return None;
        }
        if self.index + 1 == self.ops.len() {
            self.finished = true;
            return None;
        }
        self.index += 1;
        self.op_start_s = Some(t_s);
        self.trigger = TriggerState::default();
        // Fix the new trigger's reference sign now, on the estimate at the switch (a value
        // exactly on the threshold then makes any later departure count as the crossing).
        let next = self.ops[self.index];
        if matches!(
            next.trigger,
            Trigger::PressureAltitude { .. } | Trigger::Bearing { .. }
        ) {
            self.trigger.fires(&next.trigger, t_s, t_s, nav);
        }
        Some(self.index)
    }

    /// The current operation.
    pub fn current(&self) -> &Operation {
        &self.ops[self.index]
    }

    /// Index of the current operation.
    pub fn index(&self) -> usize {
        self.index
    }

    /// Mission time at which the current operation started, s (`None` before the first
    /// update).
    pub fn op_start_s(&self) -> Option<f64> {
        self.op_start_s
    }

    /// All operations.
    pub fn operations(&self) -> &[Operation] {
        &self.ops
    }

    /// Whether the last operation's trigger has fired.
    pub fn finished(&self) -> bool {
        self.finished
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ianav::math::so3;
    use ianav::math::wgs84::Geodetic;
    use nalgebra::UnitQuaternion;

    fn nav(chi_deg: f64, hp_m: f64) -> NavEstimate {
        let chi = chi_deg.to_radians();
        NavEstimate {
            t_us: 0,
            pos: Geodetic {
                lat_rad: 0.7,
                lon_rad: -1.5,
                h_m: hp_m,
            },
            v_ned_mps: Vector3::new(29.0 * chi.cos(), 29.0 * chi.sin(), 0.0),
            q_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, chi),
            w_nb_b_rps: Vector3::zeros(),
            tas_mps: 29.0,
            aoa_rad: 0.0,
            aos_rad: 0.0,
            hp_m,
        }
    }

    fn op(trigger: Trigger) -> Operation {
        Operation {
            tas_mps: 29.0,
            elevator: ElevatorTarget::PressureAltitude { hp_m: 2700.0 },
            aileron: AileronTarget::Bank { xi_rad: 0.17 },
            trigger,
        }
    }

    #[test]
    fn bearing_and_path_angle() {
        let n = nav(-135.0, 0.0);
        assert!((bearing_rad(&n).to_degrees() + 135.0).abs() < 1e-9);
        // Pitch 5° with α = 3°, wings level, β = 0: γ = θ − α = 2°.
        let mut n = nav(30.0, 0.0);
        n.q_nb = UnitQuaternion::from_euler_angles(0.0, 5_f64.to_radians(), 0.3);
        n.aoa_rad = 3_f64.to_radians();
        assert!((air_path_angle_rad(&n).to_degrees() - 2.0).abs() < 1e-9);
        // Banked 30° the same α, θ: γ = asin(sinθ cosα − cosθ sinα cosξ) (0 sideslip).
        n.q_nb = UnitQuaternion::from_euler_angles(30_f64.to_radians(), 5_f64.to_radians(), 0.3);
        let (t, a, x) = (5_f64.to_radians(), 3_f64.to_radians(), 30_f64.to_radians());
        let expect = (t.sin() * a.cos() - t.cos() * a.sin() * x.cos()).asin();
        assert!((air_path_angle_rad(&n) - expect).abs() < 1e-12);
    }

    #[test]
    fn euler_rates_match_finite_differences() {
        // Rotate q_nb by a small body rate and compare the Euler differences.
        let q0 = UnitQuaternion::from_euler_angles(0.4, -0.2, 1.0);
        let w = Vector3::new(0.3, -0.2, 0.5);
        let h = 1e-6;
        let q1 = q0 * UnitQuaternion::from_scaled_axis(w * h);
        let (e0, e1) = (so3::euler_zyx(&q0), so3::euler_zyx(&q1));
        let fd = (e1 - e0) / h;
        let an = euler_rates(e0.y, e0.z, &w);
        assert!((fd - an).norm() < 1e-5, "{fd:?} vs {an:?}");
    }

    #[test]
    fn time_and_elapsed_triggers() {
        let n = nav(0.0, 2700.0);
        let mut s = TriggerState::default();
        assert!(!s.fires(&Trigger::Time { t_s: 10.0 }, 9.99, 0.0, &n));
        assert!(s.fires(&Trigger::Time { t_s: 10.0 }, 10.0, 0.0, &n));
        assert!(!s.fires(&Trigger::Elapsed { dt_s: 5.0 }, 14.9, 10.0, &n));
        assert!(s.fires(&Trigger::Elapsed { dt_s: 5.0 }, 15.0, 10.0, &n));
    }

    #[test]
    fn altitude_trigger_fires_on_sign_change_from_either_side() {
        let trg = Trigger::PressureAltitude { hp_m: 3000.0 };
        for (start, path) in [
            (2700.0, [2900.0, 2999.9, 3000.1]),
            (3300.0, [3100.0, 3000.1, 2999.9]),
        ] {
            let mut s = TriggerState::default();
            assert!(!s.fires(&trg, 0.0, 0.0, &nav(0.0, start)));
            assert!(!s.fires(&trg, 1.0, 0.0, &nav(0.0, path[0])));
            assert!(!s.fires(&trg, 2.0, 0.0, &nav(0.0, path[1])));
            assert!(s.fires(&trg, 3.0, 0.0, &nav(0.0, path[2])));
        }
        // A NaN altitude neither fires nor loses the reference.
        let mut s = TriggerState::default();
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(0.0, 2900.0)));
        assert!(!s.fires(&trg, 1.0, 0.0, &nav(0.0, f64::NAN)));
        assert!(s.fires(&trg, 2.0, 0.0, &nav(0.0, 3001.0)));
    }

    #[test]
    fn bearing_trigger_is_inactive_beyond_90_deg_and_wraps() {
        // Threshold 175°; a right turn from −10° passes through 0, 90, 170, 180 (= −180)...
        let trg = Trigger::Bearing {
            chi_rad: 175_f64.to_radians(),
        };
        let mut s = TriggerState::default();
        // At −10° the wrapped difference is 175°: inactive. Passing the back of the circle
        // (difference going through ±180° at χ = −5°) must not fire.
        for chi in [-10.0, -5.0, -4.0, 0.0, 40.0, 84.0] {
            assert!(!s.fires(&trg, 0.0, 0.0, &nav(chi, 0.0)), "chi {chi}");
        }
        // Active from 85° (difference −90°) with reference sign −.
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(86.0, 0.0)));
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(174.0, 0.0)));
        assert!(s.fires(&trg, 0.0, 0.0, &nav(176.0, 0.0)));
        // Threshold near ±180°: crossing it across the wrap (179° → −179°) fires.
        let trg = Trigger::Bearing {
            chi_rad: 180_f64.to_radians(),
        };
        let mut s = TriggerState::default();
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(100.0, 0.0)));
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(179.0, 0.0)));
        assert!(s.fires(&trg, 0.0, 0.0, &nav(-179.0, 0.0)));
        // Leaving the active window resets the reference: a left turn away and back from the
        // other side is a new approach, not a crossing.
        let trg = Trigger::Bearing { chi_rad: 0.0 };
        let mut s = TriggerState::default();
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(-30.0, 0.0)));
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(-120.0, 0.0)));
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(150.0, 0.0)));
        assert!(!s.fires(&trg, 0.0, 0.0, &nav(30.0, 0.0)));
        assert!(s.fires(&trg, 0.0, 0.0, &nav(-1.0, 0.0)));
    }

    #[test]
    fn guidance_sequences_operations() {
        let ops = vec![
            op(Trigger::Time { t_s: 10.0 }),
            op(Trigger::Bearing {
                chi_rad: 85_f64.to_radians(),
            }),
            op(Trigger::Elapsed { dt_s: 5.0 }),
        ];
        let mut g = Guidance::try_new(ops).unwrap();
        assert_eq!(g.op_start_s(), None);
        assert_eq!(g.update(5.0, &nav(0.0, 0.0)), None);
        assert_eq!(g.op_start_s(), Some(5.0));
        assert_eq!(g.update(10.0, &nav(0.0, 0.0)), Some(1));
        assert_eq!(g.op_start_s(), Some(10.0));
        assert_eq!(g.update(11.0, &nav(50.0, 0.0)), None);
        assert_eq!(g.update(12.0, &nav(86.0, 0.0)), Some(2));
        assert_eq!(g.update(16.9, &nav(90.0, 0.0)), None);
        assert!(!g.finished());
        assert_eq!(g.update(17.0, &nav(90.0, 0.0)), None);
        assert!(g.finished());
        assert_eq!(g.index(), 2);
        assert_eq!(g.current().trigger, Trigger::Elapsed { dt_s: 5.0 });
    }

    #[test]
    fn guidance_rejects_bad_plans() {
        assert_eq!(Guidance::try_new(vec![]), Err(GuidanceError::Empty));
        let mut bad = op(Trigger::Time { t_s: 1.0 });
        bad.tas_mps = f64::NAN;
        assert!(matches!(
            Guidance::try_new(vec![bad]),
            Err(GuidanceError::BadValue {
                index: 0,
                field: "tas_mps",
                ..
            })
        ));
        let bad = op(Trigger::Elapsed { dt_s: -1.0 });
        assert!(Guidance::try_new(vec![op(Trigger::Time { t_s: 1.0 }), bad]).is_err());
        // The infallible constructor flies a placeholder the controller refuses.
        let mut g = Guidance::new(vec![]);
        assert!(g.finished());
        assert!(g.current().tas_mps.is_nan());
        assert_eq!(g.update(0.0, &nav(0.0, 0.0)), None);
    }
}
