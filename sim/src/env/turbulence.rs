//! Dryden turbulence (MIL-F-8785C, high-altitude form, body axes), generated on the fly from
//! the run's seed (docs/REFERENCES.md A3.4; the authors pre-generated files that are not public, so
//! this generator is calibrated to the one statistic they documented — see
//! `docs/ENVIRONMENT.md`, "Turbulence").
//!
//! Model, per body axis, as a *spatial* filter driven by white noise (frozen-field hypothesis:
//! the aircraft flies the distance `Δs = V·Δt` through the field each step):
//! - Dryden shaping (MIL-F-8785C above 2,000 ft): `u` first order with scale length
//!   `L_u = 1750 ft`; `v`, `w` second order `(1 + √3·L·Ω)/(1 + L·Ω)²` with `L_v = L_w = 875 ft`;
//!   intensities `σ_u = σ_v = σ_w` from the high-altitude probability-of-exceedance table
//!   (moderate, 10⁻³, by default), interpolated in altitude.
//! - A first-order spatial roll-off `1/(1 + ℓ·Ω)` on each axis' output (ℓ_x for `u`, ℓ_yz for
//!   `v`, `w`). Without it the derivative of a Dryden process is white noise (infinite
//!   variance; its finite-difference estimate grows like 1/√Δt). With it the gust acceleration
//!   has a finite, step-independent σ; ℓ_x and ℓ_yz are calibrated so that at 30 m/s,
//!   3,000 m and factor 1 the acceleration σ is 0.61 / 0.75 / 0.75 m/s², as the authors
//!   measured on their series. The output is renormalised so the velocity σ stays the table
//!   intensity.
//!
//! Discretisation: the white-noise-driven first section of each axis is an exact
//! Ornstein–Uhlenbeck step (`φ = e^{−Δs/L}`, noise `√(1−φ²)`), so its variance is exact for any
//! step; the following first-order sections use the exact decay `φ` with a trapezoidal input
//! (error O((Δs/ℓ)²) ≈ 3e-6 at 500 Hz). Coefficients are recomputed only when `Δs` changes by
//! more than [`COEFF_REL_TOL`]; four normal draws per step (three with the rotation off).
//!
//! Rotational gusts (MIL-F-8785C / MIL-HDBK-1797 Dryden angular rates, span `b` from
//! [`DrydenParams::span_m`]): the angular velocity of the air `ω_g` in body axes, defined so
//! that the aerodynamic rate terms see `ω_nb − ω_g` (`p_g = ∂w/∂y`, `q_g = −∂w/∂x`,
//! `r_g = ∂v/∂x`, the rigid rotation that matches the local gust gradients):
//! - `p_g`: the spanwise distribution of `w`, an independent first-order spatial process of
//!   length `λ_p = 4b/π` with the specification's intensity
//!   `σ_p² = 0.4π σ_w² / (λ_p^{4/3} L_w^{2/3})` (spectrum
//!   `(σ_w²/L_w)·0.8·(πL_w/4b)^{1/3}/(1 + (4bΩ/π)²)`).
//! - `q_g = −D/(1 + λ_q D)·w_g`, `r_g = +D/(1 + λ_r D)·v_g` with `D = d/ds`, `λ_q = 4b/π`,
//!   `λ_r = 3b/π`, applied to this generator's own (rolled-off) `v`, `w` so that the rotation is
//!   the gradient of the very field the aircraft flies through. The specification writes
//!   `q_g`, `r_g` with the opposite signs (`q_g = ∂w/∂x`, `r_g = −∂v/∂x`) and a "±" between
//!   sources; only the sign relative to the aerodynamic convention matters, see
//!   `docs/ENVIRONMENT.md`, "Rotational gusts".

use std::f64::consts::{FRAC_1_SQRT_2, PI};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::aircraft::AeroParams;
use crate::rng::{self, Stream};

/// Feet in metres.
const FT_M: f64 = 0.3048;
/// √3, the zero of the Dryden lateral/vertical filter.
const SQRT_3: f64 = 1.732_050_807_568_877_2;

/// Longitudinal scale length above 2,000 ft, m (1750 ft).
pub const SCALE_LENGTH_U_M: f64 = 1750.0 * FT_M;
/// Lateral and vertical scale lengths above 2,000 ft, m (875 ft = L_u/2).
pub const SCALE_LENGTH_VW_M: f64 = 875.0 * FT_M;

/// True airspeed at which the roll-off lengths are calibrated, m/s (the authors' ~30 m/s).
pub const CALIBRATION_TAS_MPS: f64 = 30.0;
/// Altitude at which the roll-off lengths are calibrated, m (the scenarios fly 2.3–3.5 km).
pub const CALIBRATION_H_M: f64 = 3000.0;
/// Target variance of the x (longitudinal) gust acceleration at factor 1, (m/s²)²
/// (docs/REFERENCES.md A1.5, A3.4: 0.372, σ ≈ 0.61 m/s²).
pub const CALIBRATION_ACCEL_VAR_X: f64 = 0.372;
/// Target variance of the y and z gust accelerations at factor 1, (m/s²)² (0.563, σ ≈
/// 0.75 m/s²).
pub const CALIBRATION_ACCEL_VAR_YZ: f64 = 0.563;

/// Length of the roll- and pitch-gust filters per unit span, 4/π (MIL-F-8785C: time constant
/// `4b/(πV)` of `p_g` and `q_g`).
pub const ROLL_PITCH_LENGTH_PER_SPAN: f64 = 4.0 / PI;
/// Length of the yaw-gust filter per unit span, 3/π (time constant `3b/(πV)` of `r_g`).
pub const YAW_LENGTH_PER_SPAN: f64 = 3.0 / PI;
/// The 0.8 of the MIL-F-8785C roll-gust spectrum
/// `(σ_w²/L_w)·0.8·(πL_w/(4b))^{1/3}/(1 + (4bΩ/π)²)`.
const ROLL_SPECTRUM_COEFF: f64 = 0.8;

/// Relative change of the spatial step `Δs = V·Δt` that triggers recomputing the filter
/// coefficients. Reusing coefficients computed for a step within 0.1 % means the state is
/// advanced by a distance off by at most 0.1 % (a negligible warp of the frozen field); the
/// process statistics are unaffected because the discrete filters are stationary-exact for
/// whatever step they were computed for.
pub const COEFF_REL_TOL: f64 = 1e-3;

/// Altitudes of the MIL-F-8785C high-altitude intensity table (Figure 7), ft.
const TABLE_ALT_FT: [f64; 12] = [
    500.0, 1750.0, 3750.0, 7500.0, 15000.0, 25000.0, 35000.0, 45000.0, 55000.0, 65000.0, 75000.0,
    80000.0,
];
/// σ for probability of exceedance 10⁻² ("light"), ft/s.
const TABLE_LIGHT_FTPS: [f64; 12] = [6.6, 6.9, 7.4, 6.7, 4.6, 2.7, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0];
/// σ for probability of exceedance 10⁻³ ("moderate"), ft/s.
const TABLE_MODERATE_FTPS: [f64; 12] =
    [8.6, 9.6, 10.6, 10.1, 8.0, 6.6, 5.0, 4.2, 2.7, 0.0, 0.0, 0.0];
/// σ for probability of exceedance 10⁻⁵ ("severe"), ft/s.
const TABLE_SEVERE_FTPS: [f64; 12] = [
    15.6, 17.6, 23.0, 23.6, 22.1, 20.0, 16.0, 15.1, 12.1, 7.9, 6.2, 5.1,
];

/// Turbulence settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TurbulenceConfig {
    /// Scale factor on the turbulence velocity (0 switches it off; the scenarios use 0.5).
    pub factor: f64,
}

/// Turbulence severity: a curve of the MIL-F-8785C high-altitude probability-of-exceedance
/// table.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// Probability of exceedance 10⁻² (σ ≈ 1.8 m/s at 3 km).
    Light,
    /// Probability of exceedance 10⁻³ (σ ≈ 2.9 m/s at 3 km).
    #[default]
    Moderate,
    /// Probability of exceedance 10⁻⁵ (σ ≈ 7.2 m/s at 3 km).
    Severe,
}

impl Severity {
    /// Turbulence intensity σ (= σ_u = σ_v = σ_w) at geometric altitude `h_m`, m/s: linear
    /// interpolation of the table in altitude, held constant below 500 ft and above 80,000 ft
    /// (the high-altitude form is used at all altitudes: flights stay above 2 km). NaN gives
    /// NaN.
    pub fn intensity_mps(self, h_m: f64) -> f64 {
        IntensitySegment::new(self, h_m).eval(h_m)
    }
}

/// The linear piece of the intensity table containing an altitude (cached by the generator so
/// the per-step lookup is one multiply-add).
#[derive(Debug, Clone, Copy)]
struct IntensitySegment {
    /// Altitude range of validity, m (infinite at the clamped ends).
    lo_m: f64,
    hi_m: f64,
    /// σ at `lo_m` (or the clamped value), m/s, and slope, (m/s)/m.
    sigma_mps: f64,
    slope_per_m: f64,
    /// Altitude `sigma_mps` refers to, m.
    h0_m: f64,
}

impl IntensitySegment {
    fn new(severity: Severity, h_m: f64) -> Self {
        let table = match severity {
            Severity::Light => &TABLE_LIGHT_FTPS,
            Severity::Moderate => &TABLE_MODERATE_FTPS,
            Severity::Severe => &TABLE_SEVERE_FTPS,
        };
        let h_ft = h_m / FT_M;
        let last = TABLE_ALT_FT.len() - 1;
        if h_ft.is_nan() {
            return Self {
                lo_m: f64::NAN,
                hi_m: f64::NAN,
                sigma_mps: f64::NAN,
                slope_per_m: 0.0,
                h0_m: 0.0,
            };
        }
        if h_ft <= TABLE_ALT_FT[0] {
            return Self {
                lo_m: f64::NEG_INFINITY,
                hi_m: TABLE_ALT_FT[0] * FT_M,
                sigma_mps: table[0] * FT_M,
                slope_per_m: 0.0,
                h0_m: 0.0,
            };
        }
        if h_ft >= TABLE_ALT_FT[last] {
            return Self {
                lo_m: TABLE_ALT_FT[last] * FT_M,
                hi_m: f64::INFINITY,
                sigma_mps: table[last] * FT_M,
                slope_per_m: 0.0,
                h0_m: 0.0,
            };
        }
        let i = TABLE_ALT_FT[1..last]
            .iter()
            .take_while(|&&a| a < h_ft)
            .count();
        let slope_per_ft = (table[i + 1] - table[i]) / (TABLE_ALT_FT[i + 1] - TABLE_ALT_FT[i]);
        Self {
            lo_m: TABLE_ALT_FT[i] * FT_M,
            hi_m: TABLE_ALT_FT[i + 1] * FT_M,
            sigma_mps: table[i] * FT_M,
            // (ft/s per ft) is the same ratio as (m/s per m).
            slope_per_m: slope_per_ft,
            h0_m: TABLE_ALT_FT[i] * FT_M,
        }
    }

    /// Whether `h_m` lies in this piece (false for NaN).
    fn contains(&self, h_m: f64) -> bool {
        h_m >= self.lo_m && h_m <= self.hi_m
    }

    fn eval(&self, h_m: f64) -> f64 {
        if self.slope_per_m == 0.0 {
            // Clamped ends (and flat pieces): no dependence on h, NaN only for NaN input.
            if h_m.is_nan() {
                f64::NAN
            } else {
                self.sigma_mps
            }
        } else {
            self.sigma_mps + self.slope_per_m * (h_m - self.h0_m)
        }
    }
}

/// Fraction of the unit-variance Dryden `u` variance left after the roll-off of length `ell_m`.
pub fn rolloff_variance_ratio_u(scale_m: f64, ell_m: f64) -> f64 {
    scale_m / (scale_m + ell_m)
}

/// Variance of the spatial derivative `du/ds` per unit variance of the rolled-off `u`, 1/m²:
/// `1/(L·ℓ)`. Multiply by `σ²·V²` for the time-derivative variance.
pub fn derivative_variance_u(scale_m: f64, ell_m: f64) -> f64 {
    1.0 / (scale_m * ell_m)
}

/// Fraction of the unit-variance Dryden `v`/`w` variance left after the roll-off:
/// `(r + 2)/(2(r + 1)²)`, `r = ℓ/L`.
pub fn rolloff_variance_ratio_vw(scale_m: f64, ell_m: f64) -> f64 {
    let r = ell_m / scale_m;
    (r + 2.0) / (2.0 * (r + 1.0) * (r + 1.0))
}

/// Variance of the spatial derivative of the rolled-off `v`/`w` per unit variance, 1/m²:
/// `(2ℓ + 3L)/(L·ℓ·(ℓ + 2L))`.
pub fn derivative_variance_vw(scale_m: f64, ell_m: f64) -> f64 {
    (2.0 * ell_m + 3.0 * scale_m) / (scale_m * ell_m * (ell_m + 2.0 * scale_m))
}

/// σ of the roll gust `p_g` per unit intensity σ_w, 1/m (multiply by σ_w for rad/s):
/// `√(0.4π) / (λ^{2/3} L_w^{1/3})`, `λ = 4b/π` — the integral over `Ω ∈ [0, ∞)` of the
/// MIL-F-8785C spectrum `(1/L_w)·0.8·(L_w/λ)^{1/3}/(1 + λ²Ω²)`, which is
/// `0.4π/(λ^{4/3} L_w^{2/3})`.
/// The frozen-field spectrum has no airspeed in it, so neither has σ_p.
pub fn roll_rate_sigma_per_intensity(scale_length_w_m: f64, span_m: f64) -> f64 {
    let lambda = ROLL_PITCH_LENGTH_PER_SPAN * span_m;
    (0.5 * ROLL_SPECTRUM_COEFF * PI).sqrt() / (lambda.powf(2.0 / 3.0) * scale_length_w_m.cbrt())
}

/// Variance, per unit variance of the rolled-off `v`/`w`, of its spatial slope seen through the
/// first-order lag of length `lag_m` (`D/(1 + λD)`, the form of `q_g` and `r_g`), 1/m²:
/// `(R(λ) − R(ℓ)) / ((ℓ² − λ²)·R(ℓ))` with `R(a)` = [`rolloff_variance_ratio_vw`]`(L, a)`.
/// From `Ω²/(1 + λ²Ω²) = (1 − 1/(1 + λ²Ω²))/λ²` and the partial fractions of
/// `1/((1 + ℓ²Ω²)(1 + λ²Ω²))`. Tends to [`derivative_variance_vw`] as `λ → 0`; requires
/// `λ ≠ ℓ` (NaN otherwise).
pub fn lagged_slope_variance_vw(scale_m: f64, ell_m: f64, lag_m: f64) -> f64 {
    let r_ell = rolloff_variance_ratio_vw(scale_m, ell_m);
    let r_lag = rolloff_variance_ratio_vw(scale_m, lag_m);
    let den = (ell_m * ell_m - lag_m * lag_m) * r_ell;
    if den == 0.0 {
        f64::NAN
    } else {
        (r_lag - r_ell) / den
    }
}

/// Span of the default aircraft, m (the rotational gusts scale with the span; the flight sets
/// the actual aircraft's span with [`DrydenParams::with_span`]).
fn default_span_m() -> f64 {
    AeroParams::default().wing_span_m
}

/// Parameters of the Dryden generator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DrydenParams {
    /// Intensity curve of the MIL-F-8785C table.
    pub severity: Severity,
    /// Longitudinal scale length L_u, m.
    pub scale_length_u_m: f64,
    /// Lateral/vertical scale length L_v = L_w, m.
    pub scale_length_vw_m: f64,
    /// Roll-off length ℓ_x of the longitudinal component, m.
    pub rolloff_length_x_m: f64,
    /// Roll-off length ℓ_yz of the lateral and vertical components, m.
    pub rolloff_length_yz_m: f64,
    /// Wing span b of the aircraft, m: sets the rotational gusts (`λ_p = λ_q = 4b/π`,
    /// `λ_r = 3b/π`). A non-finite or non-positive span switches them off (exact zeros).
    #[serde(default = "default_span_m")]
    pub span_m: f64,
}

impl DrydenParams {
    /// MIL-F-8785C high-altitude scale lengths with roll-off lengths solved so that, at
    /// [`CALIBRATION_TAS_MPS`], [`CALIBRATION_H_M`] and factor 1, the gust acceleration
    /// variances are [`CALIBRATION_ACCEL_VAR_X`] and [`CALIBRATION_ACCEL_VAR_YZ`]:
    /// `σ²V²/(L_u ℓ_x) = a_x` and `σ²V²(2ℓ + 3L)/(Lℓ(ℓ + 2L)) = a_yz` (closed forms in
    /// [`derivative_variance_u`], [`derivative_variance_vw`]).
    pub fn calibrated(severity: Severity) -> Self {
        let sigma = severity.intensity_mps(CALIBRATION_H_M);
        let sv2 = (sigma * CALIBRATION_TAS_MPS).powi(2);
        let l_u = SCALE_LENGTH_U_M;
        let l = SCALE_LENGTH_VW_M;
        let k_x = CALIBRATION_ACCEL_VAR_X / sv2;
        let k_yz = CALIBRATION_ACCEL_VAR_YZ / sv2;
        // k·L·ℓ² + (2kL² − 2)·ℓ − 3L = 0; positive root in the cancellation-free form.
        let b = 2.0 * k_yz * l * l - 2.0;
        let disc = b * b + 12.0 * k_yz * l * l;
        Self {
            severity,
            scale_length_u_m: l_u,
            scale_length_vw_m: l,
            rolloff_length_x_m: 1.0 / (l_u * k_x),
            rolloff_length_yz_m: 6.0 * l / (b + disc.sqrt()),
            span_m: default_span_m(),
        }
    }

    /// The same parameters for an aircraft of span `span_m`.
    pub fn with_span(self, span_m: f64) -> Self {
        Self { span_m, ..self }
    }

    /// Whether the rotational gusts are on (finite, positive span).
    pub fn rotation_enabled(&self) -> bool {
        self.span_m.is_finite() && self.span_m > 0.0
    }

    /// Length of the `p_g` and `q_g` filters `4b/π`, m.
    pub fn roll_pitch_length_m(&self) -> f64 {
        ROLL_PITCH_LENGTH_PER_SPAN * self.span_m
    }

    /// Length of the `r_g` filter `3b/π`, m.
    pub fn yaw_length_m(&self) -> f64 {
        YAW_LENGTH_PER_SPAN * self.span_m
    }
}

impl Default for DrydenParams {
    /// Moderate turbulence, calibrated roll-offs, the default aircraft's span.
    fn default() -> Self {
        Self::calibrated(Severity::Moderate)
    }
}

/// Discrete filter coefficients for one spatial step.
#[derive(Debug, Clone, Copy)]
struct Coeffs {
    /// Spatial step they were computed for, m.
    ds_m: f64,
    /// `e^{−Δs/L_u}` and the matching OU noise gain `√(1 − φ²)`.
    phi_u: f64,
    noise_u: f64,
    /// `e^{−Δs/L_vw}`, `1 − φ`, and the OU noise gain.
    phi_vw: f64,
    one_minus_phi_vw: f64,
    noise_vw: f64,
    /// Roll-off decays `e^{−Δs/ℓ}` and `1 − φ`.
    phi_x: f64,
    one_minus_phi_x: f64,
    phi_yz: f64,
    one_minus_phi_yz: f64,
    /// Rotational filters: `e^{−Δs/λ}` and `1 − φ` for `λ_p = λ_q = 4b/π` (with the OU noise
    /// gain of `p`) and `λ_r = 3b/π`; `1/Δs` for the slopes. NaN when the rotation is off
    /// (never used then).
    phi_pq: f64,
    one_minus_phi_pq: f64,
    noise_p: f64,
    phi_r: f64,
    one_minus_phi_r: f64,
    inv_ds: f64,
}

impl Coeffs {
    fn new(p: &DrydenParams, ds_m: f64) -> Self {
        // expm1 keeps 1 − φ accurate for Δs ≪ L (Δs/L ≈ 1e-4 at 500 Hz).
        let one_minus = |len: f64| -(-ds_m / len).exp_m1();
        let noise = |len: f64| (-(-2.0 * ds_m / len).exp_m1()).sqrt();
        let (omx, omyz, omvw) = (
            one_minus(p.rolloff_length_x_m),
            one_minus(p.rolloff_length_yz_m),
            one_minus(p.scale_length_vw_m),
        );
        let (ompq, omr) = (
            one_minus(p.roll_pitch_length_m()),
            one_minus(p.yaw_length_m()),
        );
        Self {
            ds_m,
            phi_u: 1.0 - one_minus(p.scale_length_u_m),
            noise_u: noise(p.scale_length_u_m),
            phi_vw: 1.0 - omvw,
            one_minus_phi_vw: omvw,
            noise_vw: noise(p.scale_length_vw_m),
            phi_x: 1.0 - omx,
            one_minus_phi_x: omx,
            phi_yz: 1.0 - omyz,
            one_minus_phi_yz: omyz,
            phi_pq: 1.0 - ompq,
            one_minus_phi_pq: ompq,
            noise_p: noise(p.roll_pitch_length_m()),
            phi_r: 1.0 - omr,
            one_minus_phi_r: omr,
            inv_ds: 1.0 / ds_m,
        }
    }
}

/// Warm-up: distance flown before the first output, in units of the longest length scale
/// (the zero initial state decays like `(1 + s/L)e^{−s/L}` ≈ 8e-5 after 12 L).
const WARMUP_LENGTHS: f64 = 12.0;
/// Warm-up step as a fraction of the shortest length scale (trapezoid error ~ (1/20)²).
const WARMUP_STEP_FRACTION: f64 = 0.05;
/// Cap on the warm-up steps (only reached with extreme, non-default parameters).
const WARMUP_MAX_STEPS: usize = 100_000;
/// The rotational filters (lengths of a few metres) get a second warm-up over
/// [`WARMUP_LENGTHS`] × 4b/π at a step of this fraction of 3b/π: the main warm-up's step (a
/// twentieth of the shortest roll-off, ~2 m) is too coarse to resolve them, and a fine step
/// over the whole main warm-up would cost 15× more.
const ROTATION_WARMUP_STEP_FRACTION: f64 = 0.05;

/// Stateful Dryden generator: advance it once per integration step.
///
/// Outputs after each [`Turbulence::step`]: the gust velocity (returned, also
/// [`Turbulence::velocity_b_mps`]) and the gust angular velocity [`Turbulence::rate_b_rps`].
///
/// Behaviour on unusual input: a non-finite `factor` is treated as 0 (no turbulence). A step
/// with a non-finite or non-positive `Δs = tas·dt` (aircraft not moving through the air, NaN,
/// negative time step) does not advance the field — velocity and rates are held (frozen field).
/// A non-finite altitude keeps the previous intensity.
#[derive(Debug, Clone)]
pub struct Turbulence {
    rng: Stream,
    factor: f64,
    params: DrydenParams,
    /// Gains restoring unit variance after the roll-off.
    gain_u: f64,
    gain_vw: f64,
    coeffs: Coeffs,
    /// Current intensity σ(h), m/s, and the table piece it came from.
    sigma_mps: f64,
    segment: IntensitySegment,
    /// u channel: OU state and rolled-off output (unit-variance scale).
    x_u: f64,
    y_u: f64,
    /// v, w channels: the two cascaded first-order states, the Dryden output, the rolled-off
    /// output.
    z1: [f64; 2],
    z2: [f64; 2],
    r: [f64; 2],
    y_vw: [f64; 2],
    velocity_b_mps: Vector3<f64>,
    /// Rotational gusts on ([`DrydenParams::rotation_enabled`]).
    rotation: bool,
    /// σ_p per unit intensity, 1/m ([`roll_rate_sigma_per_intensity`]).
    gain_p: f64,
    /// p channel: unit-variance OU state.
    x_p: f64,
    /// Lagged spatial slopes of the unit-scale rolled-off v and w outputs (`y_vw`), 1/m.
    slope_vw: [f64; 2],
    rate_b_rps: Vector3<f64>,
}

impl Turbulence {
    /// Generator for one run, drawing from `rng` (default calibrated moderate turbulence).
    pub fn new(cfg: &TurbulenceConfig, rng: Stream) -> Self {
        Self::with_params(cfg, DrydenParams::default(), rng)
    }

    /// Generator with explicit Dryden parameters. The filters are warmed up over a distance
    /// of 12 scale lengths so the first output is already statistically stationary.
    pub fn with_params(cfg: &TurbulenceConfig, params: DrydenParams, rng: Stream) -> Self {
        let factor = if cfg.factor.is_finite() {
            cfg.factor
        } else {
            0.0
        };
        let lengths = [
            params.scale_length_u_m,
            params.scale_length_vw_m,
            params.rolloff_length_x_m,
            params.rolloff_length_yz_m,
        ];
        let longest = lengths.iter().fold(0.0_f64, |a, &b| a.max(b));
        let shortest = lengths.iter().fold(f64::INFINITY, |a, &b| a.min(b));
        let warmup_ds = WARMUP_STEP_FRACTION * shortest;
        let rotation = params.rotation_enabled();
        let mut t = Self {
            rng,
            factor,
            params,
            gain_u: 1.0
                / rolloff_variance_ratio_u(params.scale_length_u_m, params.rolloff_length_x_m)
                    .sqrt(),
            gain_vw: 1.0
                / rolloff_variance_ratio_vw(params.scale_length_vw_m, params.rolloff_length_yz_m)
                    .sqrt(),
            coeffs: Coeffs::new(&params, warmup_ds),
            sigma_mps: params.severity.intensity_mps(CALIBRATION_H_M),
            segment: IntensitySegment::new(params.severity, CALIBRATION_H_M),
            x_u: 0.0,
            y_u: 0.0,
            z1: [0.0; 2],
            z2: [0.0; 2],
            r: [0.0; 2],
            y_vw: [0.0; 2],
            velocity_b_mps: Vector3::zeros(),
            rotation,
            gain_p: if rotation {
                roll_rate_sigma_per_intensity(params.scale_length_vw_m, params.span_m)
            } else {
                0.0
            },
            x_p: 0.0,
            slope_vw: [0.0; 2],
            rate_b_rps: Vector3::zeros(),
        };
        if factor != 0.0 && warmup_ds.is_finite() && warmup_ds > 0.0 {
            let n = (WARMUP_LENGTHS * longest / warmup_ds).ceil();
            let n = if n.is_finite() {
                (n as usize).min(WARMUP_MAX_STEPS)
            } else {
                0
            };
            for _ in 0..n {
                t.advance();
            }
            // The rotational states start from zero too; 12 of their lengths at a resolving
            // step leave e^{−12} ≈ 6e-6 of that (the velocity states are already stationary
            // and stay so).
            let fine_ds = ROTATION_WARMUP_STEP_FRACTION * params.yaw_length_m();
            if rotation && fine_ds.is_finite() && fine_ds > 0.0 {
                let n = (WARMUP_LENGTHS * params.roll_pitch_length_m() / fine_ds).ceil();
                let n = if n.is_finite() {
                    (n as usize).min(WARMUP_MAX_STEPS)
                } else {
                    0
                };
                t.coeffs = Coeffs::new(&params, fine_ds);
                for _ in 0..n {
                    t.advance();
                }
            }
            t.update_output();
        }
        t
    }

    /// The parameters in use.
    pub fn params(&self) -> &DrydenParams {
        &self.params
    }

    /// Advance by `dt_s` at true airspeed `tas_mps` and geometric altitude `h_m`; returns the
    /// high-frequency wind velocity in body axes, m/s. The matching angular velocity of the air
    /// is then [`Self::rate_b_rps`].
    pub fn step(&mut self, dt_s: f64, tas_mps: f64, h_m: f64) -> Vector3<f64> {
        if self.factor == 0.0 {
            return self.velocity_b_mps;
        }
        if h_m.is_finite() {
            if !self.segment.contains(h_m) {
                self.segment = IntensitySegment::new(self.params.severity, h_m);
            }
            self.sigma_mps = self.segment.eval(h_m);
        }
        let ds_m = tas_mps * dt_s;
        if ds_m.is_finite() && ds_m > 0.0 {
            let close = (ds_m - self.coeffs.ds_m).abs() <= COEFF_REL_TOL * self.coeffs.ds_m;
            if !close {
                self.coeffs = Coeffs::new(&self.params, ds_m);
            }
            self.advance();
        }
        self.update_output();
        self.velocity_b_mps
    }

    /// The current turbulence velocity in body axes, m/s.
    pub fn velocity_b_mps(&self) -> Vector3<f64> {
        self.velocity_b_mps
    }

    /// The current angular velocity of the air (rotational gust) in body axes after the last
    /// step, rad/s: `(p_g, q_g, r_g)` with `p_g = ∂w/∂y`, `q_g = −∂w/∂x`, `r_g = ∂v/∂x` (the
    /// rigid rotation matching the local gust gradients), so the aerodynamic rate terms use
    /// `ω_nb − ω_g`. Exactly zero with factor 0 or the rotation off.
    pub fn rate_b_rps(&self) -> Vector3<f64> {
        self.rate_b_rps
    }

    /// One spatial step of all filters with the cached coefficients.
    fn advance(&mut self) {
        let c = self.coeffs;
        let y_vw_old = self.y_vw;
        let eta = [
            rng::normal(&mut self.rng),
            rng::normal(&mut self.rng),
            rng::normal(&mut self.rng),
        ];
        let x_new = c.phi_u * self.x_u + c.noise_u * eta[0];
        self.y_u = c.phi_x * self.y_u + c.one_minus_phi_x * 0.5 * (self.x_u + x_new);
        self.x_u = x_new;
        for i in 0..2 {
            let z1 = c.phi_vw * self.z1[i] + c.noise_vw * eta[1 + i];
            let z2 = c.phi_vw * self.z2[i] + c.one_minus_phi_vw * 0.5 * (self.z1[i] + z1);
            // (1 + √3 LΩ)/(1 + LΩ)² = √3/(1 + LΩ) + (1 − √3)/(1 + LΩ)²; the sum has variance 2
            // for a unit-variance z1, hence 1/√2.
            let r = (SQRT_3 * z1 + (1.0 - SQRT_3) * z2) * FRAC_1_SQRT_2;
            self.y_vw[i] = c.phi_yz * self.y_vw[i] + c.one_minus_phi_yz * 0.5 * (self.r[i] + r);
            self.z1[i] = z1;
            self.z2[i] = z2;
            self.r[i] = r;
        }
        if self.rotation {
            self.x_p = c.phi_pq * self.x_p + c.noise_p * rng::normal(&mut self.rng);
            // Lag of the slope of the piecewise-linear y: exact for a slope constant over the
            // step (zero-order hold on Δy/Δs), so the discrete q, r are the continuous filters
            // applied to the linear interpolation of the samples.
            let dv = (self.y_vw[0] - y_vw_old[0]) * c.inv_ds;
            let dw = (self.y_vw[1] - y_vw_old[1]) * c.inv_ds;
            self.slope_vw[0] = c.phi_r * self.slope_vw[0] + c.one_minus_phi_r * dv;
            self.slope_vw[1] = c.phi_pq * self.slope_vw[1] + c.one_minus_phi_pq * dw;
        }
    }

    fn update_output(&mut self) {
        let s = self.factor * self.sigma_mps;
        self.velocity_b_mps = Vector3::new(
            s * self.gain_u * self.y_u,
            s * self.gain_vw * self.y_vw[0],
            s * self.gain_vw * self.y_vw[1],
        );
        if self.rotation {
            // p_g = ∂w/∂y (independent spanwise process); q_g = −∂w/∂x; r_g = +∂v/∂x.
            let sv = s * self.gain_vw;
            self.rate_b_rps = Vector3::new(
                s * self.gain_p * self.x_p,
                -(sv * self.slope_vw[1]),
                sv * self.slope_vw[0],
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream;

    fn turb(factor: f64, seed: u64) -> Turbulence {
        Turbulence::new(&TurbulenceConfig { factor }, stream(seed, "env.turbulence"))
    }

    #[test]
    fn intensity_table() {
        // Table nodes (ft/s → m/s) and a midpoint.
        let m = Severity::Moderate;
        assert!((m.intensity_mps(7500.0 * FT_M) - 10.1 * FT_M).abs() < 1e-12);
        assert!((m.intensity_mps(15000.0 * FT_M) - 8.0 * FT_M).abs() < 1e-12);
        assert!((m.intensity_mps(11250.0 * FT_M) - 9.05 * FT_M).abs() < 1e-12);
        // 3000 m = 9842.5 ft: 10.1 − 2.1·2342.5/7500 = 9.4441 ft/s = 2.8786 m/s.
        assert!((m.intensity_mps(3000.0) - 2.878_56).abs() < 1e-5);
        assert!((Severity::Light.intensity_mps(500.0 * FT_M) - 6.6 * FT_M).abs() < 1e-12);
        assert!((Severity::Severe.intensity_mps(80000.0 * FT_M) - 5.1 * FT_M).abs() < 1e-12);
        // Clamped outside the table.
        assert_eq!(m.intensity_mps(-100.0), m.intensity_mps(0.0));
        assert_eq!(m.intensity_mps(1e6), 0.0);
        assert!(m.intensity_mps(f64::NAN).is_nan());
    }

    #[test]
    fn calibration_closed_forms_hit_the_targets() {
        let p = DrydenParams::default();
        let sv2 = (Severity::Moderate.intensity_mps(CALIBRATION_H_M) * CALIBRATION_TAS_MPS).powi(2);
        let ax = sv2 * derivative_variance_u(p.scale_length_u_m, p.rolloff_length_x_m);
        let ayz = sv2 * derivative_variance_vw(p.scale_length_vw_m, p.rolloff_length_yz_m);
        assert!((ax - CALIBRATION_ACCEL_VAR_X).abs() < 1e-12);
        assert!((ayz - CALIBRATION_ACCEL_VAR_YZ).abs() < 1e-12);
        // For ℓ ≪ L the lateral form tends to the Dryden slope 3/(2Lℓ).
        let l = SCALE_LENGTH_VW_M;
        assert!((derivative_variance_vw(l, 1e-3) * 2.0 * l * 1e-3 / 3.0 - 1.0).abs() < 1e-5);
        assert!((rolloff_variance_ratio_vw(l, 0.0) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn closed_forms_match_spectral_quadrature() {
        // Integrate the spectra numerically (Ω = tan θ / scale, midpoint rule, error O(h²)
        // ≈ 1e-8) and compare with the closed forms used for the calibration.
        let (l, ell) = (SCALE_LENGTH_VW_M, 77.0);
        let (lu, ellx) = (SCALE_LENGTH_U_M, 37.0);
        let integrate = |f: &dyn Fn(f64) -> f64, scale: f64| {
            // Open (midpoint) rule: the transformed integrand is smooth on [0, π/2] and
            // tends to a finite limit at π/2, which the rule never evaluates.
            let n = 20_000;
            let h = std::f64::consts::FRAC_PI_2 / f64::from(n);
            let mut s = 0.0;
            for i in 0..n {
                let th = (f64::from(i) + 0.5) * h;
                let c = th.cos();
                s += f(th.tan() / scale) / (scale * c * c);
            }
            2.0 * s * h // two-sided
        };
        let pi = std::f64::consts::PI;
        let phi_v = |o: f64| {
            let x = l * o;
            l / (2.0 * pi) * (1.0 + 3.0 * x * x)
                / ((1.0 + x * x).powi(2))
                / (1.0 + (ell * o).powi(2))
        };
        let phi_u = |o: f64| lu / pi / (1.0 + (lu * o).powi(2)) / (1.0 + (ellx * o).powi(2));
        let var_v = integrate(&phi_v, l);
        let dvar_v = integrate(&|o| o * o * phi_v(o), ell);
        assert!((var_v - rolloff_variance_ratio_vw(l, ell)).abs() < 1e-6);
        assert!((dvar_v / var_v - derivative_variance_vw(l, ell)).abs() < 1e-6 * dvar_v / var_v);
        let var_u = integrate(&phi_u, lu);
        let dvar_u = integrate(&|o| o * o * phi_u(o), ellx);
        assert!((var_u - rolloff_variance_ratio_u(lu, ellx)).abs() < 1e-6);
        assert!((dvar_u / var_u - derivative_variance_u(lu, ellx)).abs() < 1e-6 * dvar_u / var_u);
        // Slope through the q_g/r_g lag, for both gust lengths of a 2.68 m span.
        for lag in [4.0 / pi * 2.68, 3.0 / pi * 2.68] {
            let qvar = integrate(&|o| o * o * phi_v(o) / (1.0 + (lag * o).powi(2)), lag);
            let want = lagged_slope_variance_vw(l, ell, lag);
            assert!((qvar / var_v - want).abs() < 1e-6 * want, "{lag}");
        }
        // Roll gust: the MIL-F-8785C spectrum (one-sided, so half the two-sided integral).
        let (lw, b) = (SCALE_LENGTH_VW_M, 2.68);
        let lam = 4.0 * b / pi;
        let phi_p = |o: f64| 0.8 / lw * (pi * lw / (4.0 * b)).cbrt() / (1.0 + (lam * o).powi(2));
        let var_p = 0.5 * integrate(&phi_p, lam);
        let want = roll_rate_sigma_per_intensity(lw, b).powi(2);
        assert!((var_p - want).abs() < 1e-6 * want);
    }

    #[test]
    fn lagged_slope_tends_to_the_slope() {
        let (l, ell) = (SCALE_LENGTH_VW_M, 77.0);
        let d = derivative_variance_vw(l, ell);
        // O(λ/ℓ) below the unlagged slope variance, converging to it.
        assert!((lagged_slope_variance_vw(l, ell, 1e-4) - d).abs() < 1e-5 * d);
        assert!(lagged_slope_variance_vw(l, ell, 3.0) < d);
        assert!(lagged_slope_variance_vw(l, ell, ell).is_nan());
    }

    #[test]
    fn factor_zero_is_exactly_zero() {
        let mut t = turb(0.0, 1);
        for _ in 0..1000 {
            assert_eq!(t.step(0.002, 30.0, 3000.0), Vector3::zeros());
            assert_eq!(t.rate_b_rps(), Vector3::zeros());
        }
        assert_eq!(t.velocity_b_mps(), Vector3::zeros());
        let mut t = turb(f64::NAN, 1);
        assert_eq!(t.step(0.002, 30.0, 3000.0), Vector3::zeros());
        assert_eq!(t.rate_b_rps(), Vector3::zeros());
    }

    #[test]
    fn zero_or_invalid_span_switches_only_the_rotation_off() {
        for span in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let p = DrydenParams::default().with_span(span);
            let mut t = Turbulence::with_params(
                &TurbulenceConfig { factor: 1.0 },
                p,
                stream(5, "env.turbulence"),
            );
            for _ in 0..1000 {
                let v = t.step(0.002, 30.0, 3000.0);
                assert!(v.iter().all(|x| x.is_finite()) && v != Vector3::zeros());
                assert_eq!(t.rate_b_rps(), Vector3::zeros());
            }
        }
    }

    #[test]
    fn deterministic_and_factor_scales_exactly() {
        let (mut a, mut b, mut h) = (turb(1.0, 3), turb(1.0, 3), turb(0.5, 3));
        for _ in 0..10_000 {
            let va = a.step(0.002, 30.0, 2800.0);
            assert_eq!(va, b.step(0.002, 30.0, 2800.0));
            assert_eq!(a.rate_b_rps(), b.rate_b_rps());
            // 0.5 is a power of two: the scaled output is exactly half.
            assert_eq!(h.step(0.002, 30.0, 2800.0), 0.5 * va);
            assert_eq!(h.rate_b_rps(), 0.5 * a.rate_b_rps());
        }
        assert_ne!(turb(1.0, 4).velocity_b_mps(), a.velocity_b_mps());
        assert_ne!(turb(1.0, 4).rate_b_rps(), a.rate_b_rps());
    }

    #[test]
    fn span_scales_the_roll_gust_as_the_specification() {
        // σ_p ∝ b^{−2/3}: halving the span raises it by 2^{2/3}.
        let l = SCALE_LENGTH_VW_M;
        let ratio = roll_rate_sigma_per_intensity(l, 1.34) / roll_rate_sigma_per_intensity(l, 2.68);
        assert!((ratio - 2.0_f64.powf(2.0 / 3.0)).abs() < 1e-12);
        let p = DrydenParams::default();
        assert_eq!(p.span_m, AeroParams::default().wing_span_m);
        assert!((p.roll_pitch_length_m() / p.yaw_length_m() - 4.0 / 3.0).abs() < 1e-15);
    }

    #[test]
    fn stationary_from_the_start() {
        // After the warm-up the first sample is a draw from the stationary law: over many
        // seeds its per-axis σ matches σ(h_cal) (SE of σ̂ ≈ σ/√(2n); 4.5 SE bound: 10 %).
        // The same for the rotational gusts against their closed-form σ.
        let n = 1000;
        let sigma = Severity::Moderate.intensity_mps(CALIBRATION_H_M);
        let p = DrydenParams::default();
        let (l, ell) = (p.scale_length_vw_m, p.rolloff_length_yz_m);
        let sigma_rate = sigma
            * Vector3::new(
                roll_rate_sigma_per_intensity(l, p.span_m),
                lagged_slope_variance_vw(l, ell, p.roll_pitch_length_m()).sqrt(),
                lagged_slope_variance_vw(l, ell, p.yaw_length_m()).sqrt(),
            );
        let (mut ss, mut sr) = (Vector3::zeros(), Vector3::zeros());
        for s in 0..n {
            let t = turb(1.0, s);
            let (v, w) = (t.velocity_b_mps(), t.rate_b_rps());
            ss += v.component_mul(&v);
            sr += w.component_mul(&w);
        }
        let bound = 4.5 / (2.0 * n as f64).sqrt();
        for i in 0..3 {
            let sd = (ss[i] / n as f64).sqrt();
            assert!((sd - sigma).abs() < bound * sigma, "{i}: {sd}");
            let sd = (sr[i] / n as f64).sqrt();
            assert!(
                (sd - sigma_rate[i]).abs() < bound * sigma_rate[i],
                "rate {i}: {sd} vs {}",
                sigma_rate[i]
            );
        }
    }

    #[test]
    fn bad_inputs_hold_the_field() {
        let mut t = turb(1.0, 7);
        let v0 = t.step(0.002, 30.0, 3000.0);
        let w0 = t.rate_b_rps();
        // Not moving through the air, NaN speed/step, negative step: state held.
        for (dt, tas) in [
            (0.002, 0.0),
            (0.002, f64::NAN),
            (f64::NAN, 30.0),
            (-0.002, 30.0),
        ] {
            assert_eq!(t.step(dt, tas, 3000.0), v0);
            assert_eq!(t.rate_b_rps(), w0);
        }
        // NaN altitude keeps the previous intensity.
        assert_eq!(t.step(0.0, 30.0, f64::NAN), v0);
        assert_eq!(t.rate_b_rps(), w0);
        // Huge steps and speeds stay finite.
        let finite = |t: &Turbulence| t.rate_b_rps().iter().all(|x| x.is_finite());
        for (dt, tas) in [(1e6, 30.0), (0.002, 1e12), (1e-12, 1e-9)] {
            assert!(t.step(dt, tas, 3000.0).iter().all(|x| x.is_finite()));
            assert!(finite(&t));
        }
        assert!(t.step(0.002, 30.0, -1e9).iter().all(|x| x.is_finite()));
        assert!(finite(&t));
    }

    #[test]
    fn coefficients_are_reused_within_tolerance() {
        let mut t = turb(1.0, 2);
        t.step(0.002, 30.0, 3000.0);
        let ds = t.coeffs.ds_m;
        t.step(0.002, 30.0 * (1.0 + 0.5 * COEFF_REL_TOL), 3000.0);
        assert_eq!(t.coeffs.ds_m, ds);
        t.step(0.002, 30.0 * (1.0 + 2.0 * COEFF_REL_TOL), 3000.0);
        assert!(t.coeffs.ds_m > ds);
    }
}
