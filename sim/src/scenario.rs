//! The paper's two GNSS-denied scenarios (section "Scenarios"; docs/REFERENCES.md A6): scenario #1
//! (3,800 s: a turn, an airspeed change and a climb or descent under weather and wind ramps)
//! and scenario #2 (500 s: up to eight turns in constant weather and wind). Every stochastic
//! parameter is drawn from its own seeded stream.

use ianav::math::angle::wrap_180_deg;
use serde::{Deserialize, Serialize};

use crate::control::{AileronTarget, ElevatorTarget, Operation, Trigger};
use crate::env::{OffsetsConfig, Severity, WindConfig};
use crate::rng::{self, Stream};

/// Errors of scenario configuration.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The TOML could not be parsed or has unknown/missing keys.
    #[error("scenario configuration: {0}")]
    Parse(#[from] toml::de::Error),
    /// A value is out of its allowed range.
    #[error("scenario configuration: `{field}` {reason}")]
    Invalid {
        /// Dotted path of the offending key.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
}

/// Which of the paper's missions a scenario flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MissionKind {
    /// Scenario #1: turn, airspeed change, climb or descent (docs/REFERENCES.md A6.2).
    Benchmark,
    /// Scenario #2: up to eight turns at constant airspeed and altitude (docs/REFERENCES.md A6.3).
    Alternate,
}

/// Start point of the flight.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartConfig {
    /// Geodetic latitude, degrees.
    pub lat_deg: f64,
    /// Longitude, degrees.
    pub lon_deg: f64,
}

/// Distributions of the mission draws (docs/REFERENCES.md A6.2; `N` is a standard normal draw).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissionDrawConfig {
    /// Mean initial airspeed, m/s (V_ini = mean + σ·N, redrawn outside the band).
    pub airspeed_mean_mps: f64,
    /// σ of the initial airspeed and of the airspeed change, m/s.
    pub airspeed_sigma_mps: f64,
    /// Lowest allowed airspeed, m/s.
    pub airspeed_min_mps: f64,
    /// Highest allowed airspeed, m/s.
    pub airspeed_max_mps: f64,
    /// Smallest airspeed change, m/s.
    pub airspeed_change_min_mps: f64,
    /// Mean initial pressure altitude, m.
    pub hp_mean_m: f64,
    /// σ of the initial pressure altitude, m.
    pub hp_sigma_m: f64,
    /// σ of the pressure-altitude change, m.
    pub hp_change_sigma_m: f64,
    /// Smallest pressure-altitude change, m.
    pub hp_change_min_m: f64,
    /// Air path angle of climbs and descents, degrees.
    pub climb_path_angle_deg: f64,
    /// Bank angle of turns, degrees.
    pub turn_bank_deg: f64,
    /// A turn ends when the bearing is this far from the target, degrees.
    pub turn_lead_deg: f64,
    /// Smallest bearing change of a turn, degrees.
    pub bearing_change_min_deg: f64,
    /// Mean duration before the airspeed change and before the altitude change, s.
    pub phase_mean_s: f64,
    /// σ of those durations, s.
    pub phase_sigma_s: f64,
    /// Shortest of those durations, s.
    pub phase_min_s: f64,
    /// Longest sum of both durations, s.
    pub phases_max_sum_s: f64,
    /// Mean delay of the first turn after GNSS loss, s.
    pub turn_delay_mean_s: f64,
    /// σ of that delay, s.
    pub turn_delay_sigma_s: f64,
    /// Shortest delay of the first turn after GNSS loss, s.
    pub turn_delay_min_s: f64,
    /// Number of turns of the alternate mission (scenario #2).
    pub alternate_turns: usize,
    /// Shortest straight leg between turns of the alternate mission, s.
    pub alternate_leg_min_s: i64,
    /// Longest straight leg between turns of the alternate mission, s.
    pub alternate_leg_max_s: i64,
}

impl Default for MissionDrawConfig {
    fn default() -> Self {
        Self {
            airspeed_mean_mps: 29.0,
            airspeed_sigma_mps: 1.5,
            airspeed_min_mps: 24.0,
            airspeed_max_mps: 34.0,
            airspeed_change_min_mps: 0.5,
            hp_mean_m: 2700.0,
            hp_sigma_m: 200.0,
            hp_change_sigma_m: 300.0,
            hp_change_min_m: 100.0,
            climb_path_angle_deg: 2.0,
            turn_bank_deg: 10.0,
            turn_lead_deg: 5.0,
            bearing_change_min_deg: 10.0,
            phase_mean_s: 500.0,
            phase_sigma_s: 100.0,
            phase_min_s: 150.0,
            phases_max_sum_s: 2500.0,
            turn_delay_mean_s: 30.0,
            turn_delay_sigma_s: 50.0,
            turn_delay_min_s: 15.0,
            alternate_turns: 8,
            alternate_leg_min_s: 10,
            alternate_leg_max_s: 50,
        }
    }
}

/// One scenario, as read from `config/scenarios/*.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioConfig {
    /// Human-readable name.
    pub name: String,
    /// Mission type.
    pub mission: MissionKind,
    /// Mission end time, s (mission clock: 0 is the start of the evaluated flight).
    pub duration_s: f64,
    /// Settling time flown before mission time 0 (the controller and filters settle), s.
    pub warmup_s: f64,
    /// Mission time of the last GNSS fix, s.
    pub gnss_loss_s: f64,
    /// Turbulence intensity factor (1 = calibrated Dryden, the paper uses 0.5).
    pub turbulence_factor: f64,
    /// MIL-F-8785C intensity curve the Dryden field is calibrated on (docs/ENVIRONMENT.md §5).
    #[serde(default)]
    pub turbulence_severity: Severity,
    /// Epoch of the magnetic model, decimal year.
    pub magnetic_decimal_year: f64,
    /// Start point.
    pub start: StartConfig,
    /// Mission draw distributions.
    #[serde(default)]
    pub draws: MissionDrawConfig,
    /// Temperature and pressure offsets.
    pub offsets: OffsetsConfig,
    /// Low-frequency wind.
    pub wind: WindConfig,
}

impl ScenarioConfig {
    /// Parse and validate a scenario file.
    pub fn from_toml_str(text: &str) -> Result<Self, ScenarioError> {
        let cfg: Self = toml::from_str(text)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The built-in scenario `1` or `2` (the files of `config/scenarios/`).
    pub fn builtin(number: u8) -> Result<Self, ScenarioError> {
        match number {
            1 => Self::from_toml_str(include_str!("../../config/scenarios/scenario1.toml")),
            2 => Self::from_toml_str(include_str!("../../config/scenarios/scenario2.toml")),
            _ => Err(ScenarioError::Invalid {
                field: "scenario",
                reason: format!("must be 1 or 2, not {number}"),
            }),
        }
    }

    /// Check ranges; the error names the offending key. The bounds keep every redraw loop of
    /// the mission, offsets and wind draws feasible (acceptance probability per draw well
    /// above 1 %), and keep the flight inside the aircraft's envelope and the models' domain.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let d = &self.draws;
        let (o, w) = (&self.offsets, &self.wind);
        // (key, value, lowest, highest), both inclusive.
        let ranges: &[(&'static str, f64, f64, f64)] = &[
            ("duration_s", self.duration_s, 1e-3, 100_000.0),
            ("warmup_s", self.warmup_s, 0.0, 3_600.0),
            ("gnss_loss_s", self.gnss_loss_s, 0.0, 100_000.0),
            ("turbulence_factor", self.turbulence_factor, 0.0, 5.0),
            (
                "magnetic_decimal_year",
                self.magnetic_decimal_year,
                2025.0,
                2029.99,
            ),
            ("start.lat_deg", self.start.lat_deg, -89.0, 89.0),
            ("start.lon_deg", self.start.lon_deg, -180.0, 360.0),
            ("draws.airspeed_min_mps", d.airspeed_min_mps, 20.0, 40.0),
            (
                "draws.airspeed_max_mps",
                d.airspeed_max_mps,
                d.airspeed_min_mps + 1.0,
                40.0,
            ),
            (
                "draws.airspeed_mean_mps",
                d.airspeed_mean_mps,
                d.airspeed_min_mps,
                d.airspeed_max_mps,
            ),
            ("draws.airspeed_sigma_mps", d.airspeed_sigma_mps, 0.1, 10.0),
            (
                "draws.airspeed_change_min_mps",
                d.airspeed_change_min_mps,
                0.0,
                5.0,
            ),
            ("draws.hp_mean_m", d.hp_mean_m, 500.0, 5_000.0),
            ("draws.hp_sigma_m", d.hp_sigma_m, 0.0, 1_000.0),
            ("draws.hp_change_sigma_m", d.hp_change_sigma_m, 1.0, 1_500.0),
            ("draws.hp_change_min_m", d.hp_change_min_m, 0.0, 1_000.0),
            (
                "draws.climb_path_angle_deg",
                d.climb_path_angle_deg,
                0.5,
                5.0,
            ),
            ("draws.turn_bank_deg", d.turn_bank_deg, 2.0, 30.0),
            ("draws.turn_lead_deg", d.turn_lead_deg, 0.0, 30.0),
            (
                "draws.bearing_change_min_deg",
                d.bearing_change_min_deg,
                0.0,
                150.0,
            ),
            ("draws.phase_mean_s", d.phase_mean_s, 0.0, 100_000.0),
            ("draws.phase_sigma_s", d.phase_sigma_s, 1.0, 100_000.0),
            (
                "draws.phase_min_s",
                d.phase_min_s,
                0.0,
                d.phase_mean_s + 2.0 * d.phase_sigma_s,
            ),
            (
                "draws.phases_max_sum_s",
                d.phases_max_sum_s,
                2.0 * d.phase_mean_s,
                200_000.0,
            ),
            (
                "draws.turn_delay_mean_s",
                d.turn_delay_mean_s,
                0.0,
                100_000.0,
            ),
            (
                "draws.turn_delay_sigma_s",
                d.turn_delay_sigma_s,
                1.0,
                100_000.0,
            ),
            (
                "draws.turn_delay_min_s",
                d.turn_delay_min_s,
                0.0,
                d.turn_delay_mean_s + 2.0 * d.turn_delay_sigma_s,
            ),
            (
                "draws.alternate_turns",
                d.alternate_turns as f64,
                1.0,
                100.0,
            ),
            (
                "draws.alternate_leg_min_s",
                d.alternate_leg_min_s as f64,
                1.0,
                10_000.0,
            ),
            (
                "draws.alternate_leg_max_s",
                d.alternate_leg_max_s as f64,
                d.alternate_leg_min_s as f64,
                10_000.0,
            ),
            ("offsets.mean_start_s", o.mean_start_s, 0.0, 100_000.0),
            ("offsets.duration_s", o.duration_s, 0.0, 100_000.0),
            ("offsets.sigma_time_s", o.sigma_time_s, 0.0, 100_000.0),
            (
                "offsets.min_start_s",
                o.min_start_s,
                0.0,
                o.mean_start_s + 2.0 * o.sigma_time_s,
            ),
            ("offsets.sigma_delta_t_k", o.sigma_delta_t_k, 0.0, 20.0),
            (
                "offsets.sigma_delta_t_change_k",
                o.sigma_delta_t_change_k,
                0.0,
                20.0,
            ),
            ("offsets.sigma_delta_p_pa", o.sigma_delta_p_pa, 0.0, 3_000.0),
            (
                "offsets.sigma_delta_p_change_pa",
                o.sigma_delta_p_change_pa,
                0.0,
                3_000.0,
            ),
            ("wind.mean_start_s", w.mean_start_s, 0.0, 100_000.0),
            ("wind.sigma_time_s", w.sigma_time_s, 0.0, 100_000.0),
            (
                "wind.min_start_s",
                w.min_start_s,
                0.0,
                w.mean_start_s + 2.0 * w.sigma_time_s,
            ),
            ("wind.sigma_speed_mps", w.sigma_speed_mps, 0.0, 15.0),
            (
                "wind.sigma_speed_change_mps",
                w.sigma_speed_change_mps,
                0.0,
                10.0,
            ),
            ("wind.duration_s", w.duration_s, 0.0, 100_000.0),
            (
                "wind.sigma_direction_change_deg",
                w.sigma_direction_change_deg,
                0.0,
                180.0,
            ),
        ];
        for &(field, value, lo, hi) in ranges {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(ScenarioError::Invalid {
                    field,
                    reason: format!("must lie in [{lo}, {hi}], got {value}"),
                });
            }
        }
        Ok(())
    }
}

/// The drawn mission of one run: the values the paper lists per run, and the operations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mission {
    /// Initial bearing χ_ini, rad.
    pub chi_ini_rad: f64,
    /// Bearings after each turn, rad.
    pub chi_turns_rad: Vec<f64>,
    /// Initial airspeed, m/s.
    pub tas_ini_mps: f64,
    /// Final airspeed, m/s (scenario #1).
    pub tas_end_mps: f64,
    /// Initial pressure altitude, m.
    pub hp_ini_m: f64,
    /// Final pressure altitude, m (scenario #1).
    pub hp_end_m: f64,
    /// Mission time of the first turn, s.
    pub t_turn_s: f64,
    /// The guidance operations, in order.
    pub operations: Vec<Operation>,
}

/// A bearing in whole degrees U_int{−179..180} differing from `from_deg` (whole degrees) by at
/// least `min_deg` (redrawn; after [`rng::MAX_REDRAWS`] rejections, the opposite bearing,
/// which differs by 180° and so satisfies any `min_deg` ≤ 180°).
fn draw_bearing_change(rng: &mut Stream, from_deg: f64, min_deg: f64) -> f64 {
    rng::redraw_until(
        rng,
        |r| rng::uniform_int(r, -179, 180) as f64,
        |chi| wrap_180_deg(chi - from_deg).abs() >= min_deg,
        wrap_180_deg(from_deg + 180.0),
    )
}

/// A turn towards `chi_to_deg` from `chi_from_deg`: bank sign by the shortest way round, and
/// a trigger `lead` degrees before the target.
fn turn(
    tas_mps: f64,
    hp_m: f64,
    chi_from_deg: f64,
    chi_to_deg: f64,
    d: &MissionDrawConfig,
) -> Operation {
    let right = wrap_180_deg(chi_to_deg - chi_from_deg) > 0.0;
    let sign = if right { 1.0 } else { -1.0 };
    Operation {
        tas_mps,
        elevator: ElevatorTarget::PressureAltitude { hp_m },
        aileron: AileronTarget::Bank {
            xi_rad: (sign * d.turn_bank_deg).to_radians(),
        },
        trigger: Trigger::Bearing {
            chi_rad: wrap_180_deg(chi_to_deg - sign * d.turn_lead_deg).to_radians(),
        },
    }
}

fn hold(tas_mps: f64, hp_m: f64, chi_deg: f64, trigger: Trigger) -> Operation {
    Operation {
        tas_mps,
        elevator: ElevatorTarget::PressureAltitude { hp_m },
        aileron: AileronTarget::Bearing {
            chi_rad: chi_deg.to_radians(),
        },
        trigger,
    }
}

impl Mission {
    /// Draw the mission of one run (docs/REFERENCES.md A6.2 draws 1–9, then A6.3 for scenario #2).
    ///
    /// Each constrained draw is redrawn until it satisfies its rule ([`rng::normal_until`]);
    /// should the cap be reached (a degenerate configuration), the fallback is the acceptable
    /// value nearest the distribution's mean, so the rule still holds whenever it can.
    pub fn draw(cfg: &ScenarioConfig, rng: &mut Stream) -> Self {
        let d = &cfg.draws;
        let (v_min, v_max) = (d.airspeed_min_mps, d.airspeed_max_mps);
        let chi_ini = rng::uniform_int(rng, -179, 180) as f64;
        let chi_end = draw_bearing_change(rng, chi_ini, d.bearing_change_min_deg);
        let dt_tas = rng::normal_until(
            rng,
            d.phase_mean_s,
            d.phase_sigma_s,
            |t| t >= d.phase_min_s,
            d.phase_mean_s.max(d.phase_min_s),
        );
        // The validation keeps the mean inside the band, so it is a valid fallback.
        let tas_ini = rng::normal_until(
            rng,
            d.airspeed_mean_mps,
            d.airspeed_sigma_mps,
            |v| (v_min..=v_max).contains(&v),
            d.airspeed_mean_mps,
        );
        // Fallback: the smallest allowed change towards the side with more room, which is
        // inside the band whenever any allowed change is.
        let dv_min = d.airspeed_change_min_mps;
        let dv = rng::normal_until(
            rng,
            0.0,
            d.airspeed_sigma_mps,
            |dv| dv.abs() >= dv_min && (v_min..=v_max).contains(&(tas_ini + dv)),
            if v_max - tas_ini >= tas_ini - v_min {
                dv_min
            } else {
                -dv_min
            },
        );
        let tas_end = tas_ini + dv;
        let dt_hp = rng::normal_until(
            rng,
            d.phase_mean_s,
            d.phase_sigma_s,
            |t| t >= d.phase_min_s && t + dt_tas <= d.phases_max_sum_s,
            (d.phases_max_sum_s - dt_tas)
                .min(d.phase_mean_s)
                .max(d.phase_min_s),
        );
        let hp_ini = d.hp_mean_m + d.hp_sigma_m * rng::normal(rng);
        let dhp = rng::normal_until(
            rng,
            0.0,
            d.hp_change_sigma_m,
            |dh| dh.abs() >= d.hp_change_min_m,
            d.hp_change_min_m,
        );
        let hp_end = hp_ini + dhp;
        let t_turn = rng::normal_until(
            rng,
            cfg.gnss_loss_s + d.turn_delay_mean_s,
            d.turn_delay_sigma_s,
            |t| t >= cfg.gnss_loss_s + d.turn_delay_min_s,
            cfg.gnss_loss_s + d.turn_delay_mean_s.max(d.turn_delay_min_s),
        );

        let mut operations = vec![hold(
            tas_ini,
            hp_ini,
            chi_ini,
            Trigger::Time { t_s: t_turn },
        )];
        let mut chi_turns = vec![chi_end];
        match cfg.mission {
            MissionKind::Benchmark => {
                let gamma = d.climb_path_angle_deg.to_radians() * dhp.signum();
                operations.push(turn(tas_ini, hp_ini, chi_ini, chi_end, d));
                operations.push(hold(
                    tas_ini,
                    hp_ini,
                    chi_end,
                    Trigger::Elapsed { dt_s: dt_tas },
                ));
                operations.push(hold(
                    tas_end,
                    hp_ini,
                    chi_end,
                    Trigger::Elapsed { dt_s: dt_hp },
                ));
                operations.push(Operation {
                    tas_mps: tas_end,
                    elevator: ElevatorTarget::PathAngle { gamma_rad: gamma },
                    aileron: AileronTarget::Bearing {
                        chi_rad: chi_end.to_radians(),
                    },
                    trigger: Trigger::PressureAltitude { hp_m: hp_end },
                });
                operations.push(hold(
                    tas_end,
                    hp_end,
                    chi_end,
                    Trigger::Time {
                        t_s: cfg.duration_s,
                    },
                ));
            }
            MissionKind::Alternate => {
                let legs: Vec<f64> = (1..d.alternate_turns)
                    .map(|_| {
                        rng::uniform_int(rng, d.alternate_leg_min_s, d.alternate_leg_max_s) as f64
                    })
                    .collect();
                for _ in 1..d.alternate_turns {
                    let last = chi_turns.last().copied().unwrap_or(chi_end);
                    chi_turns.push(draw_bearing_change(rng, last, d.bearing_change_min_deg));
                }
                let mut chi_from = chi_ini;
                for (k, &chi_to) in chi_turns.iter().enumerate() {
                    operations.push(turn(tas_ini, hp_ini, chi_from, chi_to, d));
                    let trigger = match legs.get(k) {
                        Some(&dt_s) => Trigger::Elapsed { dt_s },
                        None => Trigger::Time {
                            t_s: cfg.duration_s,
                        },
                    };
                    operations.push(hold(tas_ini, hp_ini, chi_to, trigger));
                    chi_from = chi_to;
                }
            }
        }
        Self {
            chi_ini_rad: chi_ini.to_radians(),
            chi_turns_rad: chi_turns.iter().map(|c| c.to_radians()).collect(),
            tas_ini_mps: tas_ini,
            tas_end_mps: tas_end,
            hp_ini_m: hp_ini,
            hp_end_m: hp_end,
            t_turn_s: t_turn,
            operations,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scenarios_parse_and_validate() {
        let s1 = ScenarioConfig::builtin(1).unwrap();
        let s2 = ScenarioConfig::builtin(2).unwrap();
        assert_eq!(s1.mission, MissionKind::Benchmark);
        assert_eq!(s2.mission, MissionKind::Alternate);
        assert_eq!(s1.duration_s, 3800.0);
        assert_eq!(s2.duration_s, 500.0);
        assert!(ScenarioConfig::builtin(3).is_err());
    }

    #[test]
    fn unknown_and_bad_keys_are_named() {
        let text = include_str!("../../config/scenarios/scenario2.toml");
        let err = ScenarioConfig::from_toml_str(&format!("{text}\nbogus_key = 1\n")).unwrap_err();
        assert!(err.to_string().contains("bogus_key"), "{err}");
        let err = ScenarioConfig::from_toml_str(
            &text.replace("turbulence_factor = 0.5", "turbulence_factor = -1.0"),
        )
        .unwrap_err();
        assert!(err.to_string().contains("turbulence_factor"), "{err}");
        let err = ScenarioConfig::from_toml_str(
            &text.replace("sigma_speed_mps = 7.0", "sigma_speed_mps = 1e5"),
        )
        .unwrap_err();
        assert!(err.to_string().contains("wind.sigma_speed_mps"), "{err}");
        let err = ScenarioConfig::from_toml_str(
            &text.replace("duration_s = 500.0", "duration_s = 1e300"),
        )
        .unwrap_err();
        assert!(err.to_string().contains("`duration_s`"), "{err}");
    }

    #[test]
    fn benchmark_mission_respects_the_draw_rules() {
        let cfg = ScenarioConfig::builtin(1).unwrap();
        for seed in 0..200 {
            let m = Mission::draw(&cfg, &mut rng::stream(seed, "guidance"));
            assert_eq!(m.operations.len(), 6);
            assert!((24.0..=34.0).contains(&m.tas_ini_mps));
            assert!((24.0..=34.0).contains(&m.tas_end_mps));
            assert!((m.tas_end_mps - m.tas_ini_mps).abs() >= 0.5);
            assert!((m.hp_end_m - m.hp_ini_m).abs() >= 100.0);
            assert!(m.t_turn_s >= 115.0);
            // Bearings are drawn in whole degrees: undo the rad round trip (error ~1e-14°,
            // which a rounding wrap used to hide) before checking the change exactly.
            let whole_deg = |rad: f64| {
                let deg = rad.to_degrees();
                assert!((deg - deg.round()).abs() < 1e-9, "{deg}");
                deg.round()
            };
            let turn = wrap_180_deg(whole_deg(m.chi_turns_rad[0]) - whole_deg(m.chi_ini_rad));
            assert!(turn.abs() >= 10.0);
            // The bank of the turn goes the short way round.
            let AileronTarget::Bank { xi_rad } = m.operations[1].aileron else {
                panic!("op 1 must be a turn")
            };
            assert_eq!(xi_rad.signum(), turn.signum());
        }
    }

    #[test]
    fn degenerate_draws_fall_back_to_values_that_keep_the_rules() {
        // σ = 0 makes every constrained draw equal its mean, which each rule rejects, so
        // every loop hits the cap. (The validation forbids this; `Mission::draw` must still
        // return values that keep the rules rather than the rejected means.)
        let mut cfg = ScenarioConfig::builtin(1).unwrap();
        let d = &mut cfg.draws;
        d.airspeed_sigma_mps = 0.0;
        d.hp_change_sigma_m = 0.0;
        d.phase_sigma_s = 0.0;
        d.phase_mean_s = d.phase_min_s - 50.0;
        d.turn_delay_sigma_s = 0.0;
        d.turn_delay_mean_s = d.turn_delay_min_s - 5.0;
        // Mean at the top of the band: the airspeed change must go down.
        d.airspeed_mean_mps = d.airspeed_max_mps;
        let m = Mission::draw(&cfg, &mut rng::stream(1, "guidance"));
        let d = &cfg.draws;
        assert_eq!(m.tas_ini_mps, d.airspeed_max_mps);
        let dv = m.tas_end_mps - m.tas_ini_mps;
        // Sums and differences near 30 m/s and 2700 m round by < 1e-12.
        assert!((dv + d.airspeed_change_min_mps).abs() < 1e-12, "{dv}");
        let dhp = m.hp_end_m - m.hp_ini_m;
        assert!((dhp - d.hp_change_min_m).abs() < 1e-12, "{dhp}");
        assert_eq!(m.t_turn_s, cfg.gnss_loss_s + d.turn_delay_min_s);
        let Trigger::Elapsed { dt_s } = m.operations[2].trigger else {
            panic!("op 2 must end after the first phase")
        };
        assert_eq!(dt_s, d.phase_min_s);
    }

    #[test]
    fn alternate_mission_has_eight_turns() {
        let cfg = ScenarioConfig::builtin(2).unwrap();
        let m = Mission::draw(&cfg, &mut rng::stream(3, "guidance"));
        assert_eq!(m.chi_turns_rad.len(), 8);
        assert_eq!(m.operations.len(), 17);
        assert!(matches!(m.operations[16].trigger, Trigger::Time { t_s } if t_s == 500.0));
    }
}
