//! Actuators: travel and rate limits of the control surfaces and throttle. The authors'
//! simulator set the controls instantly (docs/REFERENCES.md A1.2, A9.8); here the commanded
//! positions pass through rate and travel limiters (no lag), which is what servos with a
//! saturated speed do.

use serde::{Deserialize, Serialize};

use super::{AircraftError, Controls};

/// Travel and rate limits (degrees in configuration, converted once in [`Actuators::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorLimits {
    /// Elevator travel ±, deg.
    pub elevator_travel_deg: f64,
    /// Aileron travel ±, deg.
    pub aileron_travel_deg: f64,
    /// Rudder travel ±, deg.
    pub rudder_travel_deg: f64,
    /// Rate limit of every control surface, deg/s.
    pub surface_rate_dps: f64,
    /// Throttle lower limit.
    pub throttle_min: f64,
    /// Throttle upper limit.
    pub throttle_max: f64,
    /// Throttle rate limit, 1/s.
    pub throttle_rate_ps: f64,
}

impl Default for ActuatorLimits {
    fn default() -> Self {
        Self {
            elevator_travel_deg: 8.0,
            aileron_travel_deg: 8.0,
            rudder_travel_deg: 8.0,
            surface_rate_dps: 80.0,
            throttle_min: 0.0,
            throttle_max: 1.0,
            throttle_rate_ps: 1.0,
        }
    }
}

impl ActuatorLimits {
    /// Checks the limits; the error names the offending field.
    pub fn validate(&self) -> Result<(), AircraftError> {
        let positive = [
            ("actuators.elevator_travel_deg", self.elevator_travel_deg),
            ("actuators.aileron_travel_deg", self.aileron_travel_deg),
            ("actuators.rudder_travel_deg", self.rudder_travel_deg),
            ("actuators.surface_rate_dps", self.surface_rate_dps),
            ("actuators.throttle_rate_ps", self.throttle_rate_ps),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(AircraftError::Invalid {
                    field,
                    reason: "must be finite and positive".to_owned(),
                });
            }
        }
        if !(self.throttle_min.is_finite() && (0.0..1.0).contains(&self.throttle_min)) {
            return Err(AircraftError::Invalid {
                field: "actuators.throttle_min",
                reason: "must be in [0, 1)".to_owned(),
            });
        }
        if !(self.throttle_max.is_finite()
            && self.throttle_max > self.throttle_min
            && self.throttle_max <= 1.0)
        {
            return Err(AircraftError::Invalid {
                field: "actuators.throttle_max",
                reason: "must be in (throttle_min, 1]".to_owned(),
            });
        }
        Ok(())
    }
}

/// Rate- and travel-limited actuator positions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Actuators {
    travel_rad: [f64; 3],
    surface_rate_rps: f64,
    throttle_range: (f64, f64),
    throttle_rate_ps: f64,
    position: Controls,
}

/// Moves `prev` toward `cmd` by at most `max_step`, then clamps to `[lo, hi]`; a NaN command
/// holds the previous position.
#[inline]
fn limit(prev: f64, cmd: f64, max_step: f64, lo: f64, hi: f64) -> f64 {
    if cmd.is_nan() {
        return prev;
    }
    let target = cmd.clamp(lo, hi);
    (prev + (target - prev).clamp(-max_step, max_step)).clamp(lo, hi)
}

impl Actuators {
    /// Actuators at the `initial` positions (clamped to travel; NaN → 0).
    pub fn new(limits: &ActuatorLimits, initial: Controls) -> Self {
        let travel_rad = [
            limits.elevator_travel_deg.to_radians(),
            limits.aileron_travel_deg.to_radians(),
            limits.rudder_travel_deg.to_radians(),
        ];
        let throttle_range = (limits.throttle_min, limits.throttle_max);
        let clamp0 = |x: f64, lo: f64, hi: f64| {
            if x.is_nan() {
                0.0_f64.clamp(lo, hi)
            } else {
                x.clamp(lo, hi)
            }
        };
        let position = Controls {
            throttle: clamp0(initial.throttle, throttle_range.0, throttle_range.1),
            elevator_rad: clamp0(initial.elevator_rad, -travel_rad[0], travel_rad[0]),
            aileron_rad: clamp0(initial.aileron_rad, -travel_rad[1], travel_rad[1]),
            rudder_rad: clamp0(initial.rudder_rad, -travel_rad[2], travel_rad[2]),
        };
        Self {
            travel_rad,
            surface_rate_rps: limits.surface_rate_dps.to_radians(),
            throttle_range,
            throttle_rate_ps: limits.throttle_rate_ps,
            position,
        }
    }

    /// Advances the actuators by `dt_s` toward `command` and returns the new positions. A
    /// non-finite or negative `dt_s` moves nothing.
    pub fn step(&mut self, command: &Controls, dt_s: f64) -> Controls {
        let dt = if dt_s.is_finite() && dt_s > 0.0 {
            dt_s
        } else {
            0.0
        };
        let ds = self.surface_rate_rps * dt;
        let [te, ta, tr] = self.travel_rad;
        let p = &mut self.position;
        p.throttle = limit(
            p.throttle,
            command.throttle,
            self.throttle_rate_ps * dt,
            self.throttle_range.0,
            self.throttle_range.1,
        );
        p.elevator_rad = limit(p.elevator_rad, command.elevator_rad, ds, -te, te);
        p.aileron_rad = limit(p.aileron_rad, command.aileron_rad, ds, -ta, ta);
        p.rudder_rad = limit(p.rudder_rad, command.rudder_rad, ds, -tr, tr);
        *p
    }

    /// Current positions.
    pub fn position(&self) -> Controls {
        self.position
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_and_travel_limits_and_nan_hold() {
        let limits = ActuatorLimits::default();
        let mut a = Actuators::new(
            &limits,
            Controls {
                throttle: 0.3,
                ..Controls::default()
            },
        );
        let cmd = Controls {
            throttle: 1.0,
            elevator_rad: 0.5,
            aileron_rad: -0.01,
            rudder_rad: f64::NAN,
        };
        let dt = 0.002;
        let p = a.step(&cmd, dt);
        // One step moves at most rate·dt: 80 °/s·2 ms = 0.16°, 1/s·2 ms = 0.002.
        assert!((p.throttle - 0.302).abs() < 1e-15);
        assert!((p.elevator_rad - 0.16_f64.to_radians()).abs() < 1e-15);
        assert!((p.aileron_rad + 0.01_f64.min(0.16_f64.to_radians())).abs() < 1e-15);
        assert_eq!(p.rudder_rad, 0.0);
        // After 1 s the elevator sits at the 8° stop, the throttle has reached 1.
        for _ in 0..500 {
            a.step(&cmd, dt);
        }
        let p = a.position();
        assert!((p.elevator_rad - 8.0_f64.to_radians()).abs() < 1e-15);
        assert!((p.throttle - 1.0).abs() < 1e-15);
        // A NaN command holds; a NaN dt moves nothing.
        let held = a.step(
            &Controls {
                throttle: f64::NAN,
                ..cmd
            },
            dt,
        );
        assert_eq!(held.throttle, 1.0);
        let same = a.step(&Controls::default(), f64::NAN);
        assert_eq!(same, held);
    }
}
