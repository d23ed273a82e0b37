//! PI-inspired activation of the IA-VNS priors: paper section "PI Control Inspired Pose
//! Adjustment Activation" (`subsec:IA-SVO_pi`), its equations
//! `eq:nav_vis_assist_priors_activation_pitch_pitch_formula` and `..._Deltathetah`, and its
//! settings table `tab:nav_vis_assist_priors_activation_pitch`.
//!
//! From the visual-minus-inertial altitude, pitch, rate-of-climb and bank errors of one image,
//! it gives the small pitch adjustment `Δθ°° = Δθ°°_h + Δθ°°_θ + Δθ°°_ROC` and bank adjustment
//! `Δξ°°` of the target attitude. Both zero means the priors stay off and the caller keeps the
//! reprojection-only pose.
//!
//! Where the paper is ambiguous, this module decides:
//! - the pitch term's sign rule ([`PitchRule`]): by default (reading B) the pitch term is zeroed
//!   only when it and the altitude term are both non-zero with opposite signs, so it acts alone
//!   while the altitude error is inside its dead-band; reading A (zero whenever the altitude term
//!   is zero) is an option;
//! - the ROC term is scaled by the magnitude `|Δθ°°_h|/Δθ°°_1,MAX`: with the signed ratio it
//!   would weaken the correction of a growing altitude error, the opposite of the paper's text;
//! - `ΔROC` is the change of the geometric altitude error `Δh` over the last
//!   [`ActivationConfig::roc_window_images`] image intervals divided by their duration (the
//!   paper's smoothing "over the last 100 images or 10 s"), not a visual rate minus the INS
//!   pressure-altitude rate: geometric and pressure rates differ by the temperature ratio, which
//!   in a 1 m/s climb 10 K off standard leaves a spurious ≈ 0.04 m/s, above `ΔROC_LOW`.
//!
//! Beyond the paper, the full-attitude mode ([`AdjustmentMode::Slerp`]) that the paper proposes
//! (eq. `nav_vis_assist_priors_activation_pitch_atttitude`) without a rule for the angle
//! `Δφ°°`: here `Δφ°° = min(Δφ°°_1,MAX·ramp(Δφ**, Δφ_LOW), Δφ**)`, the proportional term of
//! the other modes on the whole attitude error `Δφ** = ‖Log(q**⁻¹ ⊗ q̂)‖` (yaw included), and
//! the altitude and rate-of-climb terms still act on the pitch; the pitch and bank
//! proportional terms are replaced by the SLERP (docs/IAVNS.md, "The SLERP mode").
//!
//! The tests reproduce hand-computed cases of these rules (docs/IAVNS.md, "Tests").

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Which target angles the priors adjust (paper section `subsec:IA-SVO_pi`; yaw never).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AdjustmentMode {
    /// "Pitch adjustment activation": the bank target equals the reprojection-only bank.
    Pitch,
    /// "Pitch and bank adjustment activation", the mode behind all the paper's IA-VNS results.
    #[default]
    PitchBank,
    /// "Attitude adjustment activation" (beyond the paper, which proposes it without
    /// implementing it): the whole attitude, yaw included, turned by `Δφ°°` towards the INS's
    /// along the geodesic (SLERP), plus the altitude and rate-of-climb pitch terms.
    Slerp,
}

/// How the paper's rule "`Δθ°°_θ` is set to zero if its sign differs from that of `Δθ°°_h`"
/// treats a zero altitude term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PitchRule {
    /// Zero whenever the altitude term is zero (sign(0) differs from ±1): pitch only reinforces
    /// an active altitude correction.
    ReadingA,
    /// Zero only when both terms are non-zero with opposite signs: a large pitch error is
    /// corrected even while the altitude error is inside its dead-band.
    #[default]
    ReadingB,
}

/// Why the activation could not be configured or evaluated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ActivationError {
    /// A configuration field has a value outside its domain.
    #[error("IA-VNS activation: `{field}` = {value}: {reason}")]
    InvalidConfig {
        /// Field name.
        field: &'static str,
        /// The rejected value.
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
    /// An adjustment error (or the ΔROC derived from them) is NaN or infinite.
    #[error("IA-VNS activation: `{field}` = {value} is not finite")]
    NonFiniteInput {
        /// Input name.
        field: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// The image time does not advance, so no rate of climb can be formed.
    #[error(
        "IA-VNS activation: image time {t_us} µs is not after the previous image's {previous_us} µs"
    )]
    NonIncreasingTime {
        /// The rejected image time, µs.
        t_us: u64,
        /// The previous accepted image time, µs.
        previous_us: u64,
    },
}

/// Settings of the activation; the defaults are the paper's table
/// `tab:nav_vis_assist_priors_activation_pitch`. Angles are in degrees here for people and in
/// radians everywhere else.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ActivationConfig {
    /// `Δh_LOW`, m: dead-band of the geometric altitude error; the altitude term starts at this
    /// error and saturates at twice it.
    pub dh_low_m: f64,
    /// `Δθ_LOW`, °: dead-band of the body pitch error, set from the INS pitch accuracy.
    pub dtheta_low_deg: f64,
    /// `ΔROC_LOW`, m/s: dead-band of the rate-of-climb error.
    pub droc_low_mps: f64,
    /// `Δξ_LOW`, °: dead-band of the body bank error (equal to `Δθ_LOW` in the paper because the
    /// INS pitch and roll accuracies are similar).
    pub dbank_low_deg: f64,
    /// `Δθ°°_1,MAX`, ° per image: limit of the altitude term, of the pitch term and of their sum.
    pub dtheta1_max_deg: f64,
    /// `Δθ°°_2,MAX`, ° per image: limit of the rate-of-climb term.
    pub dtheta2_max_deg: f64,
    /// `Δξ°°_1,MAX`, ° per image: limit of the bank adjustment.
    pub dbank1_max_deg: f64,
    /// `Δφ_LOW`, °: dead-band of the whole attitude error (SLERP mode only; beyond the paper).
    pub dphi_low_deg: f64,
    /// `Δφ°°_1,MAX`, ° per image: limit of the SLERP rotation (SLERP mode only; beyond the
    /// paper).
    pub dphi1_max_deg: f64,
    /// Image intervals over which `ΔROC` is taken ("the last 100 images or 10 s"), images.
    pub roc_window_images: u32,
    /// Adjusted angles: pitch, or pitch and bank (the paper's results).
    pub mode: AdjustmentMode,
    /// Treatment of the pitch term when the altitude term is zero.
    pub pitch_rule: PitchRule,
}

impl Default for ActivationConfig {
    fn default() -> Self {
        Self {
            dh_low_m: 25.0,
            dtheta_low_deg: 0.2,
            droc_low_mps: 0.01,
            dbank_low_deg: 0.2,
            dtheta1_max_deg: 0.0005,
            dtheta2_max_deg: 0.0003,
            dbank1_max_deg: 0.0003,
            dphi_low_deg: 0.2,
            dphi1_max_deg: 0.0005,
            roc_window_images: 100,
            mode: AdjustmentMode::PitchBank,
            pitch_rule: PitchRule::ReadingB,
        }
    }
}

impl ActivationConfig {
    /// Validate; errors name the field.
    pub fn validate(&self) -> Result<(), ActivationError> {
        let thresholds = [
            ("dh_low_m", self.dh_low_m),
            ("dtheta_low_deg", self.dtheta_low_deg),
            ("droc_low_mps", self.droc_low_mps),
            ("dbank_low_deg", self.dbank_low_deg),
            ("dtheta1_max_deg", self.dtheta1_max_deg),
            ("dtheta2_max_deg", self.dtheta2_max_deg),
            ("dbank1_max_deg", self.dbank1_max_deg),
            ("dphi_low_deg", self.dphi_low_deg),
            ("dphi1_max_deg", self.dphi1_max_deg),
        ];
        // Zero is allowed: a zero limit switches its term off, a zero dead-band makes a step.
        for (field, value) in thresholds {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ActivationError::InvalidConfig {
                    field,
                    value,
                    reason: "must be finite and ≥ 0",
                });
            }
        }
        if self.roc_window_images == 0 {
            return Err(ActivationError::InvalidConfig {
                field: "roc_window_images",
                value: 0.0,
                reason: "must be ≥ 1 image",
            });
        }
        Ok(())
    }
}

/// The visual-minus-inertial errors of one image (paper footnote: "adjustment error").
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AdjustmentErrors {
    /// `Δh = h° − ĥ`, geometric altitude, m.
    pub dh_m: f64,
    /// `Δθ = θ° − θ̂`, body pitch, rad.
    pub dtheta_rad: f64,
    /// `Δξ = ξ° − ξ̂`, body bank, rad.
    pub dbank_rad: f64,
    /// `Δφ** = ‖Log(q°**⁻¹ ⊗ q̂)‖`, the whole attitude error, rad (read in SLERP mode only).
    pub dphi_rad: f64,
}

impl AdjustmentErrors {
    fn check_finite(&self) -> Result<(), ActivationError> {
        check_finite("dh_m", self.dh_m)?;
        check_finite("dtheta_rad", self.dtheta_rad)?;
        check_finite("dbank_rad", self.dbank_rad)?;
        check_finite("dphi_rad", self.dphi_rad)
    }
}

fn check_finite(field: &'static str, value: f64) -> Result<(), ActivationError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(ActivationError::NonFiniteInput { field, value })
    }
}

/// The per-image adjustment of the target attitude, rad.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Adjustment {
    /// `Δθ°°_h`, the altitude (integral) term, rad.
    pub altitude_term_rad: f64,
    /// `Δθ°°_θ`, the pitch (proportional) term after the sign rule and the combined limit, rad.
    pub pitch_term_rad: f64,
    /// `Δθ°°_ROC`, the rate-of-climb term, rad.
    pub roc_term_rad: f64,
    /// `Δθ°°`, the total pitch adjustment added to the reprojection-only pitch, rad.
    pub pitch_rad: f64,
    /// `Δξ°°`, the bank adjustment added to the reprojection-only bank, rad (0 in pitch and
    /// SLERP modes).
    pub bank_rad: f64,
    /// `Δφ°°`, the rotation towards the INS attitude along the geodesic, rad (SLERP mode only).
    pub slerp_rad: f64,
    /// `ΔROC`, the rate-of-climb error the ROC term used, m/s.
    pub droc_mps: f64,
}

impl Adjustment {
    /// Whether the target differs from the reprojection-only attitude, i.e. the prior-based
    /// optimisation runs; otherwise the caller keeps the reprojection-only pose.
    #[must_use]
    pub fn is_active(&self) -> bool {
        self.pitch_rad != 0.0 || self.bank_rad != 0.0 || self.slerp_rad != 0.0
    }
}

/// `sign` with sign(0) = 0 (`f64::signum` gives ±1 for ±0).
fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// The dead-band ramp of the paper's activation terms: 0 for `|e| < low`, `(|e| − low)/low` for
/// `low ≤ |e| ≤ 2·low`, 1 beyond. A non-positive `low` gives a step (0 at e = 0, else 1).
/// `e` and `low` share a unit.
#[must_use]
pub fn ramp(e: f64, low: f64) -> f64 {
    let a = e.abs();
    if low > 0.0 {
        ((a - low) / low).clamp(0.0, 1.0)
    } else if a > 0.0 {
        1.0
    } else {
        0.0
    }
}

/// The settings in radians, validated; evaluates the terms without state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActivationRules {
    dh_low_m: f64,
    dtheta_low_rad: f64,
    droc_low_mps: f64,
    dbank_low_rad: f64,
    dtheta1_max_rad: f64,
    dtheta2_max_rad: f64,
    dbank1_max_rad: f64,
    dphi_low_rad: f64,
    dphi1_max_rad: f64,
    mode: AdjustmentMode,
    pitch_rule: PitchRule,
}

impl ActivationRules {
    /// Validate `config` and convert its angles to radians.
    pub fn new(config: &ActivationConfig) -> Result<Self, ActivationError> {
        config.validate()?;
        Ok(Self {
            dh_low_m: config.dh_low_m,
            dtheta_low_rad: config.dtheta_low_deg.to_radians(),
            droc_low_mps: config.droc_low_mps,
            dbank_low_rad: config.dbank_low_deg.to_radians(),
            dtheta1_max_rad: config.dtheta1_max_deg.to_radians(),
            dtheta2_max_rad: config.dtheta2_max_deg.to_radians(),
            dbank1_max_rad: config.dbank1_max_deg.to_radians(),
            dphi_low_rad: config.dphi_low_deg.to_radians(),
            dphi1_max_rad: config.dphi1_max_deg.to_radians(),
            mode: config.mode,
            pitch_rule: config.pitch_rule,
        })
    }

    /// `Δθ°°_h = −sign(Δh)·Δθ°°_1,MAX·ramp(Δh, Δh_LOW)`, rad, from the altitude error `dh_m`.
    #[must_use]
    pub fn altitude_term_rad(&self, dh_m: f64) -> f64 {
        -sign(dh_m) * self.dtheta1_max_rad * ramp(dh_m, self.dh_low_m)
    }

    /// `Δθ°°_θ`, rad, from the pitch error `dtheta_rad` and the altitude term: the raw
    /// `−sign(Δθ)·Δθ°°_1,MAX·ramp(Δθ, Δθ_LOW)`, zeroed by the sign rule of [`PitchRule`], then
    /// shortened so that `|Δθ°°_h + Δθ°°_θ| ≤ Δθ°°_1,MAX`.
    #[must_use]
    pub fn pitch_term_rad(&self, dtheta_rad: f64, altitude_term_rad: f64) -> f64 {
        if self.mode == AdjustmentMode::Slerp {
            // The SLERP towards the INS attitude is this mode's proportional term.
            return 0.0;
        }
        let raw = -sign(dtheta_rad) * self.dtheta1_max_rad * ramp(dtheta_rad, self.dtheta_low_rad);
        let agree = sign(raw) * sign(altitude_term_rad) >= 0.0;
        let keep = match self.pitch_rule {
            PitchRule::ReadingA => agree && altitude_term_rad != 0.0,
            PitchRule::ReadingB => agree,
        };
        if !keep {
            return 0.0;
        }
        // Same sign (or a zero altitude term), so the sum's magnitude is the sum of magnitudes.
        let room = (self.dtheta1_max_rad - altitude_term_rad.abs()).max(0.0);
        sign(raw) * raw.abs().min(room)
    }

    /// `Δθ°°_ROC = −sign(ΔROC)·Δθ°°_2,MAX·ramp(ΔROC, ΔROC_LOW)·|Δθ°°_h|/Δθ°°_1,MAX`, rad, from
    /// the rate-of-climb error `droc_mps` and the altitude term. The ratio's magnitude (≤ 1) lets
    /// it strengthen the correction of a growing altitude error and weaken that of a shrinking
    /// one, never reverse it.
    #[must_use]
    pub fn roc_term_rad(&self, droc_mps: f64, altitude_term_rad: f64) -> f64 {
        let ratio = if self.dtheta1_max_rad > 0.0 {
            (altitude_term_rad.abs() / self.dtheta1_max_rad).min(1.0)
        } else {
            0.0
        };
        -sign(droc_mps) * self.dtheta2_max_rad * ramp(droc_mps, self.droc_low_mps) * ratio
    }

    /// `Δξ°° = −sign(Δξ)·Δξ°°_1,MAX·ramp(Δξ, Δξ_LOW)`, rad, in pitch-and-bank mode; 0 in pitch
    /// and SLERP modes.
    #[must_use]
    pub fn bank_term_rad(&self, dbank_rad: f64) -> f64 {
        match self.mode {
            AdjustmentMode::Pitch | AdjustmentMode::Slerp => 0.0,
            AdjustmentMode::PitchBank => {
                -sign(dbank_rad) * self.dbank1_max_rad * ramp(dbank_rad, self.dbank_low_rad)
            }
        }
    }

    /// `Δφ°° = min(Δφ°°_1,MAX·ramp(Δφ**, Δφ_LOW), Δφ**)`, rad, in SLERP mode (never past the
    /// INS attitude); 0 in the paper's modes.
    #[must_use]
    pub fn slerp_term_rad(&self, dphi_rad: f64) -> f64 {
        match self.mode {
            AdjustmentMode::Slerp => {
                (self.dphi1_max_rad * ramp(dphi_rad, self.dphi_low_rad)).min(dphi_rad.abs())
            }
            AdjustmentMode::Pitch | AdjustmentMode::PitchBank => 0.0,
        }
    }

    /// The adjustment for one image's errors and its rate-of-climb error `droc_mps`; rejects
    /// non-finite inputs.
    pub fn evaluate(
        &self,
        errors: &AdjustmentErrors,
        droc_mps: f64,
    ) -> Result<Adjustment, ActivationError> {
        errors.check_finite()?;
        check_finite("droc_mps", droc_mps)?;
        let altitude_term_rad = self.altitude_term_rad(errors.dh_m);
        let pitch_term_rad = self.pitch_term_rad(errors.dtheta_rad, altitude_term_rad);
        let roc_term_rad = self.roc_term_rad(droc_mps, altitude_term_rad);
        Ok(Adjustment {
            altitude_term_rad,
            pitch_term_rad,
            roc_term_rad,
            pitch_rad: altitude_term_rad + pitch_term_rad + roc_term_rad,
            bank_rad: self.bank_term_rad(errors.dbank_rad),
            slerp_rad: self.slerp_term_rad(errors.dphi_rad),
            droc_mps,
        })
    }
}

/// One accepted image: time, µs, and altitude error, m.
#[derive(Debug, Clone, Copy, PartialEq)]
struct DhSample {
    t_us: u64,
    dh_m: f64,
}

/// The activation with its `ΔROC` window: one [`Activation::update`] per image.
#[derive(Debug, Clone)]
pub struct Activation {
    config: ActivationConfig,
    rules: ActivationRules,
    /// The last `roc_window_images + 1` accepted samples, oldest first: the window spans
    /// `roc_window_images` intervals (10 s at 10 Hz, as the paper's "100 images or 10 s").
    window: VecDeque<DhSample>,
}

impl Activation {
    /// A validated activation with an empty `ΔROC` window.
    pub fn new(config: ActivationConfig) -> Result<Self, ActivationError> {
        Ok(Self {
            rules: ActivationRules::new(&config)?,
            config,
            window: VecDeque::new(),
        })
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &ActivationConfig {
        &self.config
    }

    /// The settings in radians.
    #[must_use]
    pub fn rules(&self) -> &ActivationRules {
        &self.rules
    }

    /// Images held in the `ΔROC` window (at most `roc_window_images + 1`).
    #[must_use]
    pub fn window_len(&self) -> usize {
        self.window.len()
    }

    /// The adjustment for the image at `t_us` (µs, strictly after the previous accepted image)
    /// with the visual-minus-inertial `errors`. `ΔROC = (Δh_i − Δh_{i−N})/(t_i − t_{i−N})` with
    /// N the window or the images available before it fills, 0 for the first image. A rejected
    /// image (non-finite input or ΔROC, non-increasing time) leaves the window unchanged.
    pub fn update(
        &mut self,
        t_us: u64,
        errors: &AdjustmentErrors,
    ) -> Result<Adjustment, ActivationError> {
        errors.check_finite()?;
        if let Some(last) = self.window.back()
            && t_us <= last.t_us
        {
            return Err(ActivationError::NonIncreasingTime {
                t_us,
                previous_us: last.t_us,
            });
        }
        // The oldest sample still in the window once this image is in; evaluated before any
        // change so a rejection leaves the state as it was.
        let full = self.window.len() > self.config.roc_window_images as usize;
        let oldest = self.window.get(usize::from(full));
        let droc_mps = oldest.map_or(0.0, |o| {
            (errors.dh_m - o.dh_m) / ((t_us - o.t_us) as f64 * 1e-6)
        });
        let adjustment = self.rules.evaluate(errors, droc_mps)?;
        if full {
            self.window.pop_front();
        }
        self.window.push_back(DhSample {
            t_us,
            dh_m: errors.dh_m,
        });
        Ok(adjustment)
    }

    /// Forget the `ΔROC` window (e.g. after a re-initialisation of the visual navigation).
    pub fn reset(&mut self) {
        self.window.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Degrees-equivalent tolerance of the hand values.
    const TOL_DEG: f64 = 1e-12;

    fn rules(mode: AdjustmentMode, pitch_rule: PitchRule) -> ActivationRules {
        let config = ActivationConfig {
            mode,
            pitch_rule,
            ..ActivationConfig::default()
        };
        ActivationRules::new(&config).expect("valid config")
    }

    fn errors(dh_m: f64, dtheta_deg: f64, dbank_deg: f64) -> AdjustmentErrors {
        AdjustmentErrors {
            dh_m,
            dtheta_rad: dtheta_deg.to_radians(),
            dbank_rad: dbank_deg.to_radians(),
            dphi_rad: 0.0,
        }
    }

    fn assert_deg(actual_rad: f64, expected_deg: f64, what: &str) {
        let actual_deg = actual_rad.to_degrees();
        assert!(
            (actual_deg - expected_deg).abs() <= TOL_DEG,
            "{what}: {actual_deg:e}° vs {expected_deg:e}°"
        );
    }

    /// One row of the hand table A.9.7: inputs (m, °, m/s, °) and the expected terms (°).
    struct Row {
        dh_m: f64,
        dtheta_deg: f64,
        droc_mps: f64,
        dbank_deg: f64,
        altitude_deg: f64,
        pitch_deg: f64,
        roc_deg: f64,
        total_deg: f64,
        bank_deg: f64,
    }

    #[expect(
        clippy::too_many_arguments,
        reason = "one argument per table column keeps the rows readable"
    )]
    const fn row(
        dh_m: f64,
        dtheta_deg: f64,
        droc_mps: f64,
        dbank_deg: f64,
        altitude_deg: f64,
        pitch_deg: f64,
        roc_deg: f64,
        total_deg: f64,
        bank_deg: f64,
    ) -> Row {
        Row {
            dh_m,
            dtheta_deg,
            droc_mps,
            dbank_deg,
            altitude_deg,
            pitch_deg,
            roc_deg,
            total_deg,
            bank_deg,
        }
    }

    /// Table A.9.7 under reading B; row 7 split into its four cases.
    const TABLE_B: [Row; 10] = [
        row(
            30.0, 0.1, 0.015, -0.3, -0.0001, 0.0, -0.00003, -0.00013, 0.00015,
        ),
        row(-60.0, -0.35, -0.05, 0.1, 0.0005, 0.0, 0.0003, 0.0008, 0.0),
        row(40.0, 0.0, -0.03, 0.0, -0.0003, 0.0, 0.00018, -0.00012, 0.0),
        row(40.0, -0.3, 0.0, 0.0, -0.0003, 0.0, 0.0, -0.0003, 0.0),
        row(10.0, 0.3, 0.05, 0.0, 0.0, -0.00025, 0.0, -0.00025, 0.0),
        row(30.0, 0.5, 0.0, 0.0, -0.0001, -0.0004, 0.0, -0.0005, 0.0),
        row(25.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        row(-25.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        row(50.0, 0.0, 0.0, 0.0, -0.0005, 0.0, 0.0, -0.0005, 0.0),
        row(-50.0, 0.0, 0.0, 0.0, 0.0005, 0.0, 0.0, 0.0005, 0.0),
    ];

    fn check_row(rules: &ActivationRules, r: &Row, label: &str) {
        let a = rules
            .evaluate(&errors(r.dh_m, r.dtheta_deg, r.dbank_deg), r.droc_mps)
            .expect("finite inputs");
        assert_deg(
            a.altitude_term_rad,
            r.altitude_deg,
            &format!("{label} Δθ_h"),
        );
        assert_deg(a.pitch_term_rad, r.pitch_deg, &format!("{label} Δθ_θ"));
        assert_deg(a.roc_term_rad, r.roc_deg, &format!("{label} Δθ_ROC"));
        assert_deg(a.pitch_rad, r.total_deg, &format!("{label} Δθ°°"));
        assert_deg(a.bank_rad, r.bank_deg, &format!("{label} Δξ°°"));
        assert_eq!(a.droc_mps, r.droc_mps, "{label} ΔROC");
        assert_eq!(
            a.is_active(),
            r.total_deg != 0.0 || r.bank_deg != 0.0,
            "{label} active"
        );
    }

    #[test]
    fn hand_table_reading_b() {
        let rules = rules(AdjustmentMode::PitchBank, PitchRule::ReadingB);
        for (i, r) in TABLE_B.iter().enumerate() {
            check_row(&rules, r, &format!("case {i}"));
        }
    }

    #[test]
    fn hand_table_reading_a() {
        let rules = rules(AdjustmentMode::PitchBank, PitchRule::ReadingA);
        for (i, r) in TABLE_B.iter().enumerate() {
            if i == 4 {
                // Row 5: Δh inside its dead-band, so reading A drops the pitch term.
                check_row(
                    &rules,
                    &row(10.0, 0.3, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                    "row 5 (A)",
                );
            } else {
                // Elsewhere the altitude term acts or the raw pitch term is zero: same as B.
                check_row(&rules, r, &format!("case {i} (A)"));
            }
        }
    }

    #[test]
    fn ramp_break_points() {
        let low = 25.0;
        for s in [1.0, -1.0] {
            assert_eq!(ramp(s * 24.999_999, low), 0.0);
            assert_eq!(ramp(s * low, low), 0.0);
            assert_eq!(ramp(s * 37.5, low), 0.5);
            assert_eq!(ramp(s * 2.0 * low, low), 1.0);
            assert_eq!(ramp(s * 1e9, low), 1.0);
        }
        assert_eq!(ramp(0.0, low), 0.0);
        // A zero dead-band is a step.
        assert_eq!(ramp(0.0, 0.0), 0.0);
        assert_eq!(ramp(-1e-300, 0.0), 1.0);
    }

    #[test]
    fn terms_saturate_at_their_limits() {
        let rules = rules(AdjustmentMode::PitchBank, PitchRule::ReadingB);
        for s in [1.0, -1.0] {
            let a = rules
                .evaluate(&errors(s * 1e6, s * 10.0, s * 10.0), s * 100.0)
                .expect("finite inputs");
            assert_deg(a.altitude_term_rad, -s * 0.0005, "Δθ_h");
            // Same sign as the altitude term but no room left under the combined limit.
            assert_deg(a.pitch_term_rad, 0.0, "Δθ_θ");
            assert_deg(a.roc_term_rad, -s * 0.0003, "Δθ_ROC");
            assert_deg(a.pitch_rad, -s * 0.0008, "Δθ°°");
            assert_deg(a.bank_rad, -s * 0.0003, "Δξ°°");
            // Pitch alone (Δh in its dead-band) saturates at Δθ°°_1,MAX.
            assert_deg(
                rules.pitch_term_rad((s * 10.0_f64).to_radians(), 0.0),
                -s * 0.0005,
                "Δθ_θ alone",
            );
        }
    }

    #[test]
    fn pitch_term_sign_rule() {
        let b = rules(AdjustmentMode::PitchBank, PitchRule::ReadingB);
        let a = rules(AdjustmentMode::PitchBank, PitchRule::ReadingA);
        let nose_up = 0.3_f64.to_radians();
        let h_down = b.altitude_term_rad(30.0);
        let h_up = b.altitude_term_rad(-30.0);
        assert!(h_down < 0.0 && h_up > 0.0);
        for r in [&a, &b] {
            // Opposite signs: zeroed under both readings.
            assert_eq!(r.pitch_term_rad(nose_up, h_up), 0.0);
            assert_eq!(r.pitch_term_rad(-nose_up, h_down), 0.0);
            // Same sign: kept under both readings.
            assert_deg(r.pitch_term_rad(nose_up, h_down), -0.00025, "same sign");
            assert_deg(r.pitch_term_rad(-nose_up, h_up), 0.00025, "same sign");
        }
        // Zero altitude term: B keeps the pitch term, A drops it.
        assert_deg(b.pitch_term_rad(nose_up, 0.0), -0.00025, "B alone");
        assert_eq!(a.pitch_term_rad(nose_up, 0.0), 0.0);
    }

    #[test]
    fn altitude_and_pitch_terms_respect_combined_limit() {
        let limit_rad = 0.0005_f64.to_radians();
        for rule in [PitchRule::ReadingA, PitchRule::ReadingB] {
            let r = rules(AdjustmentMode::PitchBank, rule);
            for i in -80..=80 {
                let dh_m = f64::from(i);
                let h = r.altitude_term_rad(dh_m);
                for j in -60..=60 {
                    let dtheta_rad = (f64::from(j) * 0.01).to_radians();
                    let sum = h + r.pitch_term_rad(dtheta_rad, h);
                    assert!(
                        sum.abs() <= limit_rad * (1.0 + 1e-12),
                        "Δh {dh_m} m, Δθ {j}/100°: {:e}°",
                        sum.to_degrees()
                    );
                }
            }
        }
    }

    #[test]
    fn roc_term_scales_with_and_never_reverses_altitude_term() {
        let r = rules(AdjustmentMode::PitchBank, PitchRule::ReadingB);
        for i in -80..=80 {
            let h = r.altitude_term_rad(f64::from(i));
            for j in -60..=60 {
                let droc_mps = f64::from(j) * 0.001;
                let roc = r.roc_term_rad(droc_mps, h);
                // Δθ°°_2,MAX / Δθ°°_1,MAX = 0.6.
                assert!(
                    roc.abs() <= 0.6 * h.abs() * (1.0 + 1e-12),
                    "Δh {i}, ΔROC {droc_mps}"
                );
                assert!((h + roc) * h >= 0.0, "Δh {i}, ΔROC {droc_mps}: reversed");
                if h == 0.0 {
                    assert_eq!(roc, 0.0);
                }
            }
        }
        // Growing error (ΔROC same sign as Δh) strengthens, shrinking weakens.
        let h = r.altitude_term_rad(40.0);
        assert!(r.roc_term_rad(0.03, h) < 0.0);
        assert!(r.roc_term_rad(-0.03, h) > 0.0);
    }

    #[test]
    fn bank_is_zero_in_pitch_mode() {
        let r = rules(AdjustmentMode::Pitch, PitchRule::ReadingB);
        let a = r
            .evaluate(&errors(0.0, 0.0, 5.0), 0.0)
            .expect("finite inputs");
        assert_eq!(a.bank_rad, 0.0);
        assert!(!a.is_active());
        // Pitch terms unchanged by the mode (row 1 of the table).
        let a = r
            .evaluate(&errors(30.0, 0.1, -0.3), 0.015)
            .expect("finite inputs");
        assert_deg(a.pitch_rad, -0.00013, "Δθ°°");
        assert_eq!(a.bank_rad, 0.0);
    }

    const DT_US: u64 = 100_000;

    #[test]
    fn roc_window_linear_growth() {
        let mut act = Activation::new(ActivationConfig::default()).expect("valid config");
        for i in 0..150_u64 {
            let t_s = i as f64 * 0.1;
            let a = act
                .update(i * DT_US, &errors(30.0 + 0.02 * t_s, 0.0, 0.0))
                .expect("finite inputs");
            let expected = if i == 0 { 0.0 } else { 0.02 };
            assert!(
                (a.droc_mps - expected).abs() <= 1e-12,
                "image {i}: ΔROC {}",
                a.droc_mps
            );
            assert_eq!(act.window_len(), (i as usize + 1).min(101));
        }
    }

    #[test]
    fn roc_window_spans_window_intervals() {
        // A step of 1 m after the first image: the window sees it until image 0 drops out.
        let mut act = Activation::new(ActivationConfig::default()).expect("valid config");
        for i in 0..=101_u64 {
            let dh_m = if i == 0 { 0.0 } else { 1.0 };
            let a = act
                .update(i * DT_US, &errors(dh_m, 0.0, 0.0))
                .expect("finite inputs");
            let expected = match i {
                0 => 0.0,
                1..=100 => 1.0 / (i as f64 * 0.1),
                _ => 0.0,
            };
            assert!(
                (a.droc_mps - expected).abs() <= 1e-12,
                "image {i}: ΔROC {} vs {expected}",
                a.droc_mps
            );
        }
        // With a one-image window ΔROC is the per-frame rate.
        let config = ActivationConfig {
            roc_window_images: 1,
            ..ActivationConfig::default()
        };
        let mut act = Activation::new(config).expect("valid config");
        let dhs = [0.0, 0.5, 0.5, 0.2];
        let rates = [0.0, 5.0, 0.0, -3.0];
        for (i, (dh_m, rate)) in dhs.iter().zip(rates).enumerate() {
            let a = act
                .update(i as u64 * DT_US, &errors(*dh_m, 0.0, 0.0))
                .expect("finite inputs");
            assert!((a.droc_mps - rate).abs() <= 1e-12, "image {i}");
        }
        assert_eq!(act.window_len(), 2);
    }

    /// The SLERP mode (beyond the paper): `Δφ°°` is the proportional ramp on the whole attitude
    /// error, capped at the error itself; the pitch and bank proportional terms are off and
    /// the altitude and rate-of-climb terms still act on the pitch.
    #[test]
    fn slerp_mode_ramps_the_whole_attitude_error_and_keeps_the_altitude_term() {
        let r = rules(AdjustmentMode::Slerp, PitchRule::ReadingB);
        let with_phi = |dh_m: f64, dphi_deg: f64| AdjustmentErrors {
            dphi_rad: dphi_deg.to_radians(),
            ..errors(dh_m, 0.5, 0.5)
        };
        // Δφ** in its dead band (≤ 0.2°): no rotation; at 0.3° half of 0.0005°; beyond 0.4°
        // saturated.
        for (dphi_deg, expected_deg) in [
            (0.1, 0.0),
            (0.2, 0.0),
            (0.3, 0.00025),
            (0.4, 0.0005),
            (3.0, 0.0005),
        ] {
            let a = r.evaluate(&with_phi(0.0, dphi_deg), 0.0).expect("finite");
            assert_deg(
                a.slerp_rad,
                expected_deg,
                &format!("Δφ°° at Δφ** = {dphi_deg}°"),
            );
            // The 0.5° pitch and bank errors would drive the paper's modes: not this one.
            assert_deg(a.pitch_term_rad, 0.0, "Δθ°°_θ");
            assert_deg(a.bank_rad, 0.0, "Δξ°°");
            assert_eq!(a.is_active(), expected_deg > 0.0);
        }
        // Never past the INS attitude: with no dead band, a tiny error is closed exactly.
        let step = ActivationRules::new(&ActivationConfig {
            mode: AdjustmentMode::Slerp,
            dphi_low_deg: 0.0,
            ..ActivationConfig::default()
        })
        .expect("valid config");
        let a = step.evaluate(&with_phi(0.0, 0.0001), 0.0).expect("finite");
        assert_deg(a.slerp_rad, 0.0001, "Δφ°° capped at Δφ**");
        // The altitude term: 60 m above the INS (past 2·Δh_LOW) pitches down by Δθ°°_1,MAX.
        let a = r.evaluate(&with_phi(60.0, 0.0), 0.0).expect("finite");
        assert_deg(a.altitude_term_rad, -0.0005, "Δθ°°_h");
        assert_deg(a.pitch_rad, -0.0005, "Δθ°°");
        assert!(a.is_active());
        // The paper's modes ignore Δφ**.
        let pb = rules(AdjustmentMode::PitchBank, PitchRule::ReadingB);
        assert_eq!(
            pb.evaluate(&with_phi(0.0, 3.0), 0.0)
                .expect("finite")
                .slerp_rad,
            0.0
        );
    }

    #[test]
    fn non_finite_input_rejected_without_changing_state() {
        let mut act = Activation::new(ActivationConfig::default()).expect("valid config");
        let mut twin = act.clone();
        for i in 0..5_u64 {
            let e = errors(60.0 + i as f64, 0.3, 0.3);
            act.update(i * DT_US, &e).expect("finite inputs");
            twin.update(i * DT_US, &e).expect("finite inputs");
        }
        let good = errors(70.0, 0.3, 0.3);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for e in [
                AdjustmentErrors { dh_m: bad, ..good },
                AdjustmentErrors {
                    dtheta_rad: bad,
                    ..good
                },
                AdjustmentErrors {
                    dbank_rad: bad,
                    ..good
                },
                AdjustmentErrors {
                    dphi_rad: bad,
                    ..good
                },
            ] {
                assert!(matches!(
                    act.update(5 * DT_US, &e),
                    Err(ActivationError::NonFiniteInput { .. })
                ));
            }
        }
        // A finite Δh whose ΔROC overflows is rejected as well.
        assert!(matches!(
            act.update(5 * DT_US, &errors(f64::MAX, 0.0, 0.0)),
            Err(ActivationError::NonFiniteInput {
                field: "droc_mps",
                ..
            })
        ));
        assert!(matches!(
            act.update(4 * DT_US, &good),
            Err(ActivationError::NonIncreasingTime {
                t_us: 400_000,
                previous_us: 400_000
            })
        ));
        assert_eq!(act.window_len(), 5);
        assert_eq!(act.update(5 * DT_US, &good), twin.update(5 * DT_US, &good));
    }

    #[test]
    fn reset_empties_window() {
        let mut act = Activation::new(ActivationConfig::default()).expect("valid config");
        act.update(0, &errors(0.0, 0.0, 0.0))
            .expect("finite inputs");
        act.update(DT_US, &errors(1.0, 0.0, 0.0))
            .expect("finite inputs");
        act.reset();
        assert_eq!(act.window_len(), 0);
        // Time may restart after a reset, and the first image has no ΔROC.
        let a = act
            .update(0, &errors(5.0, 0.0, 0.0))
            .expect("finite inputs");
        assert_eq!(a.droc_mps, 0.0);
    }

    #[test]
    fn default_config_is_the_paper_table() {
        let c = ActivationConfig::default();
        assert_eq!(
            (
                c.dh_low_m,
                c.dtheta_low_deg,
                c.droc_low_mps,
                c.dbank_low_deg
            ),
            (25.0, 0.2, 0.01, 0.2)
        );
        assert_eq!(
            (c.dtheta1_max_deg, c.dtheta2_max_deg, c.dbank1_max_deg),
            (0.0005, 0.0003, 0.0003)
        );
        assert_eq!(c.roc_window_images, 100);
        assert_eq!(c.mode, AdjustmentMode::PitchBank);
        assert_eq!(c.pitch_rule, PitchRule::ReadingB);
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn config_validation_and_serde() {
        for (field, value) in [
            ("dh_low_m", -1.0),
            ("dtheta_low_deg", f64::NAN),
            ("dtheta2_max_deg", f64::INFINITY),
        ] {
            let mut c = ActivationConfig::default();
            match field {
                "dh_low_m" => c.dh_low_m = value,
                "dtheta_low_deg" => c.dtheta_low_deg = value,
                _ => c.dtheta2_max_deg = value,
            }
            assert!(
                matches!(c.validate(), Err(ActivationError::InvalidConfig { field: f, .. }) if f == field)
            );
            assert!(Activation::new(c).is_err());
        }
        let c = ActivationConfig {
            roc_window_images: 0,
            ..ActivationConfig::default()
        };
        assert!(c.validate().is_err());

        let c: ActivationConfig =
            toml::from_str("mode = \"pitch\"\npitch_rule = \"reading_a\"\ndh_low_m = 30.0")
                .expect("valid TOML");
        assert_eq!(
            c,
            ActivationConfig {
                mode: AdjustmentMode::Pitch,
                pitch_rule: PitchRule::ReadingA,
                dh_low_m: 30.0,
                ..ActivationConfig::default()
            }
        );
        assert!(toml::from_str::<ActivationConfig>("dh_low = 30.0").is_err());
    }

    fn finite() -> impl Strategy<Value = f64> {
        use proptest::num::f64 as pf;
        prop_oneof![
            pf::POSITIVE | pf::NEGATIVE | pf::NORMAL | pf::SUBNORMAL | pf::ZERO,
            -200.0..200.0_f64,
            -0.1..0.1_f64,
        ]
    }

    proptest! {
        #[test]
        fn adjustment_bounded_for_finite_inputs(
            dh_m in finite(),
            dtheta_rad in finite(),
            droc_mps in finite(),
            dbank_rad in finite(),
            dphi_rad in finite(),
            reading_a in any::<bool>(),
            mode_index in 0..3_usize,
        ) {
            let mode = [AdjustmentMode::Pitch, AdjustmentMode::PitchBank, AdjustmentMode::Slerp][mode_index];
            let rule = if reading_a { PitchRule::ReadingA } else { PitchRule::ReadingB };
            let r = rules(mode, rule);
            let e = AdjustmentErrors { dh_m, dtheta_rad, dbank_rad, dphi_rad };
            let a = r.evaluate(&e, droc_mps).expect("finite inputs");
            // Never past the INS attitude, never beyond its limit.
            prop_assert!(a.slerp_rad >= 0.0 && a.slerp_rad <= 0.0005_f64.to_radians());
            prop_assert!(a.slerp_rad <= dphi_rad.abs());
            // The relative slack covers one rounding of the combined-limit subtraction.
            let pitch_max = (0.0005_f64 + 0.0003).to_radians() * (1.0 + 1e-12);
            let bank_max = 0.0003_f64.to_radians();
            prop_assert!(a.pitch_rad.abs() <= pitch_max, "Δθ°° {:e}°", a.pitch_rad.to_degrees());
            prop_assert!(a.bank_rad.abs() <= bank_max, "Δξ°° {:e}°", a.bank_rad.to_degrees());
        }
    }
}
