//! Configuration of the guidance and control loops (docs/REFERENCES.md A5.2 structure, gains tuned
//! for our aircraft — see `docs/CONTROL.md`), loaded from `config/control.toml`.
//!
//! Units in the file: angles in **degrees**, altitudes in m, speeds in m/s, times in s. Each
//! loop's gains are in its own input/output units (listed on the [`ControlConfig`] fields);
//! [`PidConfig::gains`] converts them to the SI/radian gains the code runs on.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::pid::PidGains;

/// Errors of a control configuration.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ControlConfigError {
    /// The TOML text does not parse into the structure (the message names the key).
    #[error("control config: {0}")]
    Parse(String),
    /// A field has an unusable value.
    #[error("control config: field `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field.
        field: String,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
}

/// One PID loop, in the loop's configuration units (see the field of [`ControlConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PidConfig {
    /// Proportional gain, output per input.
    pub kp: f64,
    /// Integral gain, output per (input · s).
    pub ki: f64,
    /// Derivative gain on the measurement rate, output per (input/s).
    pub kd: f64,
    /// Time constant of the low-pass on the measurement rate, s.
    pub d_filter_tau_s: f64,
    /// Back-calculation anti-windup time constant, s (0: conditional integration).
    pub tracking_tau_s: f64,
    /// Largest magnitude of the integral term, output units.
    pub integral_limit: f64,
    /// Lower output limit, output units.
    pub min: f64,
    /// Upper output limit, output units.
    pub max: f64,
}

impl PidConfig {
    /// SI gains: `in_si`/`out_si` convert one configuration unit of the input/output to SI
    /// (`π/180` for degrees, 1 otherwise).
    pub fn gains(&self, in_si: f64, out_si: f64) -> PidGains {
        let k = out_si / in_si;
        PidGains {
            kp: self.kp * k,
            ki: self.ki * k,
            kd: self.kd * k,
            d_filter_tau_s: self.d_filter_tau_s,
            tracking_tau_s: self.tracking_tau_s,
            integral_limit: self.integral_limit * out_si,
            out_min: self.min * out_si,
            out_max: self.max * out_si,
        }
    }

    fn validate(&self, name: &str) -> Result<(), ControlConfigError> {
        let field = |f: &str| format!("{name}.{f}");
        for (f, v) in [("kp", self.kp), ("ki", self.ki), ("kd", self.kd)] {
            finite(&field(f), v)?;
        }
        for (f, v) in [
            ("d_filter_tau_s", self.d_filter_tau_s),
            ("tracking_tau_s", self.tracking_tau_s),
            ("integral_limit", self.integral_limit),
        ] {
            non_negative(&field(f), v)?;
        }
        finite(&field("min"), self.min)?;
        finite(&field("max"), self.max)?;
        if self.min >= self.max {
            return Err(ControlConfigError::Invalid {
                field: field("max"),
                value: self.max,
                reason: "must be greater than `min`",
            });
        }
        Ok(())
    }
}

/// Time constants of the first-order "ramp" filters that smooth each primary target
/// (docs/REFERENCES.md A5.2), s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RampConfig {
    /// Airspeed target.
    pub tas_s: f64,
    /// Pitch target (direct, or from the altitude / path-angle loops).
    pub pitch_s: f64,
    /// Bank target of a turn (`AileronTarget::Bank`).
    pub bank_turn_s: f64,
    /// Bank target from the bearing loop.
    pub bank_bearing_s: f64,
    /// Sideslip target.
    pub sideslip_s: f64,
}

/// Yaw damper: rudder proportional to the body yaw rate in excess of the coordinated-turn
/// rate `g·sin ξ·cos θ / V`, optionally through a washout (high-pass) filter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YawDamperConfig {
    /// Rudder per yaw rate, deg per (deg/s) (i.e. s); 0 disables the damper.
    pub gain_s: f64,
    /// Washout time constant, s (0: no washout).
    pub washout_tau_s: f64,
}

/// Limits on direct attitude targets (`ElevatorTarget::Pitch`, `AileronTarget::Bank`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetLimits {
    /// Largest pitch target magnitude, deg.
    pub pitch_deg: f64,
    /// Largest bank target magnitude, deg.
    pub bank_deg: f64,
}

/// All guidance and control settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlConfig {
    /// Control period, s (the paper's 50 Hz: 0.02 s).
    pub period_s: f64,
    /// Airspeed \[m/s\] → throttle \[0–1\].
    pub throttle: PidConfig,
    /// Pitch θ \[deg\] → elevator \[deg\].
    pub elevator: PidConfig,
    /// Bank ξ \[deg\] → ailerons \[deg\].
    pub aileron: PidConfig,
    /// Sideslip β \[deg\] → rudder \[deg\].
    pub rudder: PidConfig,
    /// Pressure altitude Hp \[m\] → pitch target \[deg\]; its rate is the climb rate −v_D.
    pub altitude: PidConfig,
    /// Air path angle γ_TAS \[deg\] → pitch target \[deg\].
    pub path_angle: PidConfig,
    /// Ground-track bearing χ \[deg\] → bank target \[deg\].
    pub bearing: PidConfig,
    /// Yaw damper on the rudder.
    pub yaw_damper: YawDamperConfig,
    /// Target ramp filters.
    pub ramp: RampConfig,
    /// Limits on direct attitude targets.
    pub limits: TargetLimits,
}

fn finite(field: &str, value: f64) -> Result<(), ControlConfigError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(ControlConfigError::Invalid {
            field: field.to_owned(),
            value,
            reason: "not finite",
        })
    }
}

fn non_negative(field: &str, value: f64) -> Result<(), ControlConfigError> {
    finite(field, value)?;
    if value < 0.0 {
        return Err(ControlConfigError::Invalid {
            field: field.to_owned(),
            value,
            reason: "must not be negative",
        });
    }
    Ok(())
}

fn positive(field: &str, value: f64) -> Result<(), ControlConfigError> {
    finite(field, value)?;
    if value <= 0.0 {
        return Err(ControlConfigError::Invalid {
            field: field.to_owned(),
            value,
            reason: "must be positive",
        });
    }
    Ok(())
}

impl ControlConfig {
    /// Parse and validate a TOML text.
    pub fn from_toml_str(text: &str) -> Result<Self, ControlConfigError> {
        let cfg: Self =
            toml::from_str(text).map_err(|e| ControlConfigError::Parse(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check every field (finite gains, non-negative time constants, ordered limits).
    pub fn validate(&self) -> Result<(), ControlConfigError> {
        positive("period_s", self.period_s)?;
        for (name, pid) in [
            ("throttle", &self.throttle),
            ("elevator", &self.elevator),
            ("aileron", &self.aileron),
            ("rudder", &self.rudder),
            ("altitude", &self.altitude),
            ("path_angle", &self.path_angle),
            ("bearing", &self.bearing),
        ] {
            pid.validate(name)?;
        }
        finite("yaw_damper.gain_s", self.yaw_damper.gain_s)?;
        non_negative("yaw_damper.washout_tau_s", self.yaw_damper.washout_tau_s)?;
        let r = &self.ramp;
        for (f, v) in [
            ("ramp.tas_s", r.tas_s),
            ("ramp.pitch_s", r.pitch_s),
            ("ramp.bank_turn_s", r.bank_turn_s),
            ("ramp.bank_bearing_s", r.bank_bearing_s),
            ("ramp.sideslip_s", r.sideslip_s),
        ] {
            non_negative(f, v)?;
        }
        positive("limits.pitch_deg", self.limits.pitch_deg)?;
        positive("limits.bank_deg", self.limits.bank_deg)?;
        Ok(())
    }
}

impl Default for ControlConfig {
    /// The tuned gains (identical to `config/control.toml`; see `docs/CONTROL.md`).
    fn default() -> Self {
        Self {
            period_s: 0.02,
            throttle: PidConfig {
                kp: 0.1,
                ki: 0.03,
                kd: 0.0,
                d_filter_tau_s: 0.2,
                tracking_tau_s: 0.0,
                integral_limit: 1.0,
                min: 0.0,
                max: 1.0,
            },
            elevator: PidConfig {
                kp: -1.5,
                ki: -0.5,
                kd: -0.1,
                d_filter_tau_s: 0.05,
                tracking_tau_s: 0.0,
                integral_limit: 8.0,
                min: -8.0,
                max: 8.0,
            },
            aileron: PidConfig {
                kp: 1.5,
                ki: 0.2,
                kd: 0.05,
                d_filter_tau_s: 0.05,
                tracking_tau_s: 0.0,
                integral_limit: 3.0,
                min: -8.0,
                max: 8.0,
            },
            rudder: PidConfig {
                kp: 2.0,
                ki: 0.5,
                kd: 0.0,
                d_filter_tau_s: 0.1,
                tracking_tau_s: 0.0,
                integral_limit: 4.0,
                min: -8.0,
                max: 8.0,
            },
            altitude: PidConfig {
                kp: 0.5,
                ki: 0.02,
                kd: 2.0,
                d_filter_tau_s: 0.2,
                tracking_tau_s: 0.0,
                integral_limit: 6.0,
                min: -8.0,
                max: 10.0,
            },
            path_angle: PidConfig {
                kp: 1.0,
                ki: 0.3,
                kd: 0.0,
                d_filter_tau_s: 0.2,
                tracking_tau_s: 0.0,
                integral_limit: 10.0,
                min: -10.0,
                max: 12.0,
            },
            bearing: PidConfig {
                kp: 2.0,
                ki: 0.02,
                kd: 0.0,
                d_filter_tau_s: 0.2,
                tracking_tau_s: 0.0,
                integral_limit: 5.0,
                min: -15.0,
                max: 15.0,
            },
            yaw_damper: YawDamperConfig {
                gain_s: 0.6,
                washout_tau_s: 0.0,
            },
            ramp: RampConfig {
                tas_s: 1.0,
                pitch_s: 0.3,
                bank_turn_s: 0.5,
                bank_bearing_s: 0.2,
                sideslip_s: 0.2,
            },
            limits: TargetLimits {
                pitch_deg: 20.0,
                bank_deg: 30.0,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_matches_the_shipped_file() {
        ControlConfig::default().validate().unwrap();
        let text = include_str!("../../../config/control.toml");
        let cfg = ControlConfig::from_toml_str(text).unwrap();
        assert_eq!(cfg, ControlConfig::default());
    }

    #[test]
    fn errors_name_the_field() {
        let mut text = toml::to_string(&ControlConfig::default()).unwrap();
        // Unknown key.
        text.push_str("\n[extra]\nfoo = 1\n");
        let e = ControlConfig::from_toml_str(&text).unwrap_err().to_string();
        assert!(e.contains("extra"), "{e}");
        // Wrong type.
        let text = toml::to_string(&ControlConfig::default())
            .unwrap()
            .replace("period_s = 0.02", "period_s = \"fast\"");
        let e = ControlConfig::from_toml_str(&text).unwrap_err().to_string();
        assert!(e.contains("period_s"), "{e}");
        // Bad values.
        let mut cfg = ControlConfig::default();
        cfg.bearing.max = -20.0;
        let e = cfg.validate().unwrap_err().to_string();
        assert!(e.contains("bearing.max"), "{e}");
        let mut cfg = ControlConfig::default();
        cfg.elevator.kd = f64::NAN;
        assert!(
            cfg.validate()
                .unwrap_err()
                .to_string()
                .contains("elevator.kd")
        );
        let cfg = ControlConfig {
            period_s: 0.0,
            ..Default::default()
        };
        assert!(cfg.validate().unwrap_err().to_string().contains("period_s"));
    }

    #[test]
    fn gains_convert_units() {
        let c = PidConfig {
            kp: 0.5,
            ki: 0.1,
            kd: 2.0,
            d_filter_tau_s: 0.1,
            tracking_tau_s: 0.0,
            integral_limit: 5.0,
            min: -8.0,
            max: 10.0,
        };
        // Hp [m] → θ [deg]: 0.5 deg/m is 0.5·π/180 rad/m.
        let g = c.gains(1.0, 1_f64.to_radians());
        assert!((g.kp - 0.5_f64.to_radians()).abs() < 1e-15);
        assert!((g.out_max - 10_f64.to_radians()).abs() < 1e-15);
        // deg → deg loops keep their gains.
        let d = 1_f64.to_radians();
        let g = c.gains(d, d);
        assert!((g.kd - 2.0).abs() < 1e-12);
    }
}
