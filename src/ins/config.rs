//! INS configuration (`config/ins.toml`): the process noise Q̃, observation noise R and initial
//! covariance P₀ of the authors' filters (docs/REFERENCES.md A1.4–A1.7, values and units restated
//! in `docs/INS.md`), the GNSS-loss logic, and the bounds of the input validation.
//!
//! The authors' Q̃ is a constant *per-step* matrix at 100 Hz (A1.3). To run at any IMU rate the
//! INS scales every Q̃ entry by `Δt / reference_period_s` (a constant spectral density), and the
//! white-noise part of the IMU observation noise by `reference_period_s / Δt_imu` (per-sample
//! white-noise variance ∝ 1/Δt). At `Δt = reference_period_s` = 0.01 s the filters are exactly
//! the authors'.

use serde::{Deserialize, Serialize};

/// Why a configuration was rejected.
#[derive(Debug, thiserror::Error)]
pub enum InsConfigError {
    /// The TOML text does not parse or does not match the structure.
    #[error("INS configuration: {0}")]
    Toml(#[from] toml::de::Error),
    /// A field has a value outside its domain.
    #[error("INS configuration: `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field.
        field: String,
        /// The rejected value.
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
}

/// Air-data filter (docs/REFERENCES.md A1.4, `filter_air02`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AirDataFilterConfig {
    /// Q̃ diagonal per reference period, state order `[v_TAS (m/s)², α rad², β rad², T K²,
    /// Hp m², ROC (m/s)², v̇_TAS (m/s²)², α̇ (rad/s)², β̇ (rad/s)²]`.
    pub q: [f64; 9],
    /// Pitot white noise σ (R), m/s.
    pub tas_noise_sigma_mps: f64,
    /// Pitot bias σ (enters P₀ only), m/s.
    pub tas_bias_sigma_mps: f64,
    /// AoA vane white noise σ, deg.
    pub aoa_noise_sigma_deg: f64,
    /// AoA vane bias σ (P₀), deg.
    pub aoa_bias_sigma_deg: f64,
    /// AoS vane white noise σ, deg.
    pub aos_noise_sigma_deg: f64,
    /// AoS vane bias σ (P₀), deg.
    pub aos_bias_sigma_deg: f64,
    /// Thermometer white noise σ, K.
    pub temp_noise_sigma_k: f64,
    /// Thermometer bias σ (P₀), K.
    pub temp_bias_sigma_k: f64,
    /// Static-pressure white noise σ, Pa.
    pub p_noise_sigma_pa: f64,
    /// Static-pressure bias σ (P₀ of Hp), Pa.
    pub p_bias_sigma_pa: f64,
    /// Without an AoA vane the angle of attack is held at its initial guess; this is the σ of
    /// that guess (lower bound of its variance while the vane is absent), deg.
    pub no_vane_angle_sigma_deg: f64,
    /// The same for the sideslip without an AoS vane, deg: a fixed wing with turn coordination
    /// flies within about a degree of zero sideslip, and the sideslip is what turns a held
    /// angle into a horizontal velocity error (25 m/s × 1° = 0.44 m/s).
    #[serde(default = "default_no_vane_aos_sigma_deg")]
    pub no_vane_aos_sigma_deg: f64,
}

fn default_no_vane_aos_sigma_deg() -> f64 {
    1.0
}

impl Default for AirDataFilterConfig {
    fn default() -> Self {
        Self {
            q: [1e-15, 1e-15, 1e-15, 1e-4, 1e-15, 1e-3, 1e-4, 1e-4, 1e-4],
            tas_noise_sigma_mps: 0.333,
            tas_bias_sigma_mps: 0.333,
            aoa_noise_sigma_deg: 0.333,
            aoa_bias_sigma_deg: 0.333,
            aos_noise_sigma_deg: 0.333,
            aos_bias_sigma_deg: 0.333,
            temp_noise_sigma_k: 0.05,
            temp_bias_sigma_k: 0.05,
            p_noise_sigma_pa: 100.0,
            p_bias_sigma_pa: 100.0,
            no_vane_angle_sigma_deg: 3.0,
            no_vane_aos_sigma_deg: default_no_vane_aos_sigma_deg(),
        }
    }
}

/// Attitude filter (docs/REFERENCES.md A1.5, `filter_att02`), error-state form (see `attitude.rs`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttitudeFilterConfig {
    /// Q̃ of each attitude error axis per reference period, rad². The authors' 5e-15 per
    /// quaternion component is 4 × 5e-15 per rotation-vector axis (δq_v ≈ δθ/2).
    pub q_attitude_rad2: f64,
    /// Q̃ of the body rate `w_nb_b` per axis, (rad/s)². With the gyro as a measurement of
    /// that state, the ratio Q̃/R sets how far the state lags the gyro in a changing turn rate
    /// ([`AttitudeFilterConfig::body_rate_lag_s`]): the paper's 1e-6 against its 5.63e-7 lags
    /// 4 ms, against PX4 SIH's 2.3e-3 it lags 0.48 s and the attitude ~0.1 s (docs/INS.md,
    /// "Body-rate lag"). Raise it with `r_gyro_rad2ps2`.
    pub q_w_nb_rad2ps2: f64,
    /// Q̃ of the gyro error `E_gyr` per axis, (rad/s)².
    pub q_e_gyr_rad2ps2: f64,
    /// Q̃ of the magnetometer error `E_mag` per axis, nT².
    pub q_e_mag_nt2: f64,
    /// Q̃ of the magnetic-model error `ΔB_n` per axis, nT².
    pub q_delta_b_nt2: f64,
    /// Gyro R per axis at the reference period, (rad/s)²: the white-noise variance (the
    /// authors' 10× makes the filter believe its attitude random-walks √10 faster than it
    /// does and its attitude covariance pessimistic, docs/INS.md); scaled by
    /// `reference_period_s / Δt_imu`.
    pub r_gyro_rad2ps2: f64,
    /// White part of the accelerometer R at the reference period, (m/s²)²; scaled like the
    /// gyro's.
    pub r_accel_white_m2ps4: f64,
    /// Rate-independent part of the accelerometer R per body axis at the airspeed
    /// `r_accel_turbulence_ref_tas_mps`, (m/s²)²: the neglected time derivative of the
    /// air-relative velocity, whose residual in turbulence is coloured (1–10 s), stated as its
    /// equivalent white noise at the filter's 100 Hz. Scaled by `(|v − v_lf| / V_ref)²`, the
    /// frozen-field scaling of gust accelerations (zero at rest). docs/INS.md, deviation 10.
    pub r_accel_turbulence_m2ps4: [f64; 3],
    /// Airspeed at which `r_accel_turbulence_m2ps4` holds, m/s.
    pub r_accel_turbulence_ref_tas_mps: f64,
    /// Magnetometer R per axis, nT² (10× the authors': it must cover the unmodelled,
    /// heading-dependent soft-iron error, tens of nT for minutes, and keeps transient tilt
    /// errors from leaking into yaw through the 70° field inclination; docs/INS.md).
    pub r_mag_nt2: f64,
    /// P₀ of each attitude error axis, σ in deg. The authors' 1e-8 per quaternion component
    /// (0.0115° per axis) is ~5× below the initial error they draw (0.1°·N(0,1) in norm,
    /// 0.1°/√3 per axis); the default is that draw's σ so the filter starts consistent.
    pub p0_attitude_sigma_deg: f64,
    /// Per-sample gyro white-noise variance at the reference period (P₀ of `w_nb_b`),
    /// (rad/s)².
    pub gyro_noise_var_rad2ps2: f64,
    /// Relative σ of the modelled turn acceleration `w × u` (the centripetal term of the
    /// accelerometer model): the angle-of-attack and sideslip guesses without vanes, the
    /// airspeed's scale and an uncoordinated turn make it wrong by a few percent for as long
    /// as the turn lasts. Enters R on each axis as `(rel · |w × u|)²` times
    /// `r_accel_turn_correlation_s` over the reference period (equivalent white noise).
    /// 0 (the paper's: 10° of bank, vanes) leaves it out; beside PX4 SIH (50° of bank, no
    /// vanes) 0.1 halved the heading error after the GNSS loss (docs/INS.md, "Steep turns").
    #[serde(default)]
    pub r_accel_turn_rel: f64,
    /// Correlation time of that error, s (a turn's duration).
    #[serde(default = "default_r_accel_turn_correlation_s")]
    pub r_accel_turn_correlation_s: f64,
}

fn default_r_accel_turn_correlation_s() -> f64 {
    1.0
}

/// Q̃_w / R_gyro of the paper's settings (1e-6 / 5.63e-7): the body-rate state then lags the
/// gyro by 0.4 of a reference period.
pub const PAPER_BODY_RATE_Q_OVER_R: f64 = 1e-6 / 5.63e-7;
/// Body-rate lag above which the daemon warns at start (two reference periods), s.
pub const MAX_BODY_RATE_LAG_S: f64 = 0.02;

impl AttitudeFilterConfig {
    /// Steady-state lag of the body-rate state behind a gyro rate that changes steadily (a
    /// roll into a turn), s. The state is a random walk measured by the gyro each reference
    /// period `T`: a scalar Kalman filter whose steady gain `K` solves `K² + λK − λ = 0`,
    /// `λ = Q̃/R`; as exponential smoothing with gain `K` it trails a ramp by `T (1 − K)/K`.
    /// (The accelerometer and magnetometer pull the attitude back part of the way.)
    pub fn body_rate_lag_s(&self, reference_period_s: f64) -> f64 {
        let lambda = self.q_w_nb_rad2ps2 / self.r_gyro_rad2ps2;
        if lambda.is_nan() || lambda <= 0.0 {
            return f64::INFINITY;
        }
        let k = 0.5 * (-lambda + (lambda * lambda + 4.0 * lambda).sqrt());
        reference_period_s * (1.0 - k) / k
    }

    /// The body-rate Q̃ that keeps the paper's lag with a gyro R of `r_gyro_rad2ps2`.
    pub fn matching_q_w_nb_rad2ps2(r_gyro_rad2ps2: f64) -> f64 {
        r_gyro_rad2ps2 * PAPER_BODY_RATE_Q_OVER_R
    }
}

impl Default for AttitudeFilterConfig {
    fn default() -> Self {
        Self {
            q_attitude_rad2: 2e-14,
            q_w_nb_rad2ps2: 1e-6,
            q_e_gyr_rad2ps2: 3e-14,
            q_e_mag_nt2: 1e-14,
            q_delta_b_nt2: 1e-12,
            r_gyro_rad2ps2: 5.63e-7,
            r_accel_white_m2ps4: 2.33e-5,
            r_accel_turbulence_m2ps4: [5.0, 10.0, 10.0],
            r_accel_turbulence_ref_tas_mps: 30.0,
            r_mag_nt2: 2e6,
            p0_attitude_sigma_deg: 0.057_735,
            gyro_noise_var_rad2ps2: 5.63e-7,
            r_accel_turn_rel: 0.0,
            r_accel_turn_correlation_s: default_r_accel_turn_correlation_s(),
        }
    }
}

/// Position filter with GNSS (docs/REFERENCES.md A1.6, `filter_gps01`) and GNSS-denied propagation
/// (A1.7, `filter_pos02B`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionFilterConfig {
    /// Q̃ of each NED position error axis per reference period, m². The authors' 1e-6 is in
    /// m² for the height but in rad² for latitude and longitude (≈ (6.4 km)² per step, which
    /// makes any innovation gate useless); here it is 1e-6 m² on all three axes.
    pub q_position_m2: f64,
    /// Q̃ of the NED velocity per axis, (m/s)².
    pub q_velocity_m2ps2: f64,
    /// Q̃ of the specific force `f_ib_b` per axis, (m/s²)².
    pub q_specific_force_m2ps4: f64,
    /// Q̃ of the accelerometer error `E_acc` per axis, (m/s²)² (1e-3 × drift step variance).
    pub q_e_acc_m2ps4: f64,
    /// Accelerometer R per axis at the reference period, (m/s²)²; scaled by
    /// `reference_period_s / Δt_imu`.
    pub r_accel_m2ps4: f64,
    /// GNSS horizontal position σ (R and P₀; the receiver's own σ is used if larger), m.
    pub gnss_sigma_hor_m: f64,
    /// GNSS vertical position σ, m.
    pub gnss_sigma_ver_m: f64,
    /// GNSS velocity σ per axis, m/s.
    pub gnss_sigma_vel_mps: f64,
    /// Chi-square gate on the 6-D GNSS innovation (velocity, position). 27.86 is the
    /// 1 − 1e-4 quantile with 6 degrees of freedom.
    pub gnss_gate_chi2: f64,
    /// No valid fix for longer than this → GNSS-denied mode, s.
    pub gnss_timeout_s: f64,
    /// This many consecutive gated fixes → GNSS-denied mode.
    pub gnss_max_consecutive_rejections: u32,
    /// Fixes older than this at the IMU step that consumes them are not fused, s.
    pub gnss_max_lag_s: f64,
    /// Window of the moving averages that estimate the pressure offset and the wind while
    /// GNSS is available, s (running means until it is full). It averages out the
    /// low-frequency turbulence (correlation time `L_u/V` ≈ 18 s) like a first-order filter
    /// of half its length, and forgets a wind that changed (the climb, the take-off roll)
    /// after one window; docs/INS.md, deviation 12.
    pub lpf_window_s: f64,
    /// Integral scales of the turbulence along the body axes `[x, y, z]`, m: its correlation
    /// time is `scale / airspeed`. MIL-F-8785C Dryden above 2,000 ft: `L_u = 2 L_v = 2 L_w =
    /// 1,750 ft`; the integral scale of the `u` spectrum is `L_u`, that of `v` and `w` is
    /// `L/2`, so `[533.4, 133.35, 133.35]`. Used by the GNSS-denied covariance (docs/INS.md).
    pub turbulence_integral_scale_m: [f64; 3],
    /// Slowly varying GNSS position error per axis (ionosphere) that the filter cannot
    /// average out, added to the reported position variance, to the altitude variance behind
    /// Δp and to the dead-reckoning start, m (docs/REFERENCES.md A2.5: 8 m at the start of a run).
    pub gnss_bias_sigma_m: f64,
    /// Estimate an airspeed bias while GNSS is available and correct the dead reckoning by
    /// it: over the wind's window the raw wind is `w + c δ` (`c` the horizontal direction of
    /// the air velocity, `δ` the airspeed correction), solvable once the window holds turns
    /// (least squares; [`Self::airspeed_bias_min_heading_spread`]). Without it, an airspeed
    /// bias is absorbed into the frozen wind on the headings flown before the loss and comes
    /// back as `δ (c − c̄)` on the others. false = the paper's (its frozen wind absorbs it).
    /// docs/INS.md, "Airspeed bias from turns".
    #[serde(default)]
    pub airspeed_bias_from_turns: bool,
    /// Smallest spread of the air-velocity direction over the window,
    /// `mean |c|² − |c̄|²` (0 on one heading, 1 for headings spread evenly), for the estimate
    /// to be used.
    #[serde(default = "default_airspeed_bias_min_heading_spread")]
    pub airspeed_bias_min_heading_spread: f64,
}

fn default_airspeed_bias_min_heading_spread() -> f64 {
    0.2
}

impl Default for PositionFilterConfig {
    fn default() -> Self {
        Self {
            q_position_m2: 1e-6,
            q_velocity_m2ps2: 1e-5,
            q_specific_force_m2ps4: 1e-4,
            q_e_acc_m2ps4: 4.7e-14,
            r_accel_m2ps4: 2.33e-5,
            gnss_sigma_hor_m: 2.12,
            gnss_sigma_ver_m: 4.25,
            gnss_sigma_vel_mps: 0.0741,
            gnss_gate_chi2: 27.86,
            gnss_timeout_s: 1.5,
            gnss_max_consecutive_rejections: 5,
            gnss_max_lag_s: 0.5,
            lpf_window_s: 120.0,
            turbulence_integral_scale_m: [533.4, 133.35, 133.35],
            gnss_bias_sigma_m: 8.0,
            airspeed_bias_from_turns: false,
            airspeed_bias_min_heading_spread: default_airspeed_bias_min_heading_spread(),
        }
    }
}

/// Transfer alignment: while GNSS is available the attitude filter also fuses another
/// estimator's attitude ([`crate::sensors::RefAttitude`], the autopilot's GNSS-aided ATTITUDE),
/// which makes the gyro and magnetometer errors observable within seconds of a start in
/// flight with unknown sensor errors (docs/INS.md "Starting in flight"). Never used after GNSS loss, when the
/// reference's heading is only as good as its compass.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlignmentConfig {
    /// Fuse reference attitudes at all.
    pub enabled: bool,
    /// σ of the reference attitude's white error per axis, deg.
    pub ref_attitude_sigma_deg: f64,
    /// σ of the reference attitude's slowly varying error about the body axes x, y, z
    /// (roll, pitch, yaw when level), deg: a GNSS-aided autopilot EKF is off by a degree or
    /// two for tens of seconds (PX4 v1.16 beside SIH: yaw 1.1–1.5°, roll 1.1–1.6° RMS;
    /// docs/INS.md). Zeros: white errors only.
    pub ref_error_sigma_deg: [f64; 3],
    /// Correlation time of that error, s.
    pub ref_error_time_s: f64,
    /// Shortest time between two fused references, s: the reference's errors are correlated
    /// over seconds, so fusing every 25–50 Hz sample would make the filter trust it far more
    /// than its σ says; once a second was too slow to hold a cold start at a 25 Hz IMU
    /// (docs/INS.md).
    pub min_interval_s: f64,
    /// References older than this at the IMU step that consumes them are not fused, s.
    pub max_lag_s: f64,
    /// Chi-square gate on the 3-D attitude innovation (an autopilot in a bad state is not
    /// followed). 16.27 is the 1 − 1e-3 quantile with 3 degrees of freedom.
    pub gate_chi2: f64,
    /// This many consecutive gated references restart the attitude at the reference: the
    /// INS, not the autopilot, is then the one that is off (e.g. after a re-initialisation
    /// that kept an attitude which drifted while GNSS was lost).
    pub max_consecutive_rejections: u32,
}

impl Default for AlignmentConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            ref_attitude_sigma_deg: 0.5,
            ref_error_sigma_deg: [1.0, 1.0, 1.5],
            ref_error_time_s: 60.0,
            min_interval_s: 0.2,
            max_lag_s: 0.1,
            gate_chi2: 16.27,
            max_consecutive_rejections: 5,
        }
    }
}

/// Bounds beyond which a sample is physically impossible (or outside any sensor's range) and
/// is rejected before it reaches a filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputLimits {
    /// Largest specific-force magnitude, m/s² (50 g).
    pub max_specific_force_mps2: f64,
    /// Largest angular-rate magnitude, rad/s (2000 °/s, the widest common MEMS range).
    pub max_angular_rate_rps: f64,
    /// Largest true airspeed, m/s.
    pub max_tas_mps: f64,
    /// Largest vane angle magnitude, deg.
    pub max_vane_angle_deg: f64,
    /// Largest static pressure, Pa (the record sea-level high is 108.4 kPa).
    pub max_pressure_pa: f64,
    /// Lowest outside air temperature, K.
    pub min_temp_k: f64,
    /// Highest outside air temperature, K.
    pub max_temp_k: f64,
    /// Largest magnetic-field magnitude, nT (3× the strongest geomagnetic field).
    pub max_mag_nt: f64,
    /// Largest GNSS ground speed, m/s.
    pub max_gnss_speed_mps: f64,
    /// Lowest GNSS height above the ellipsoid, m.
    pub min_gnss_h_m: f64,
    /// Highest GNSS height above the ellipsoid, m.
    pub max_gnss_h_m: f64,
}

impl Default for InputLimits {
    fn default() -> Self {
        Self {
            max_specific_force_mps2: 50.0 * 9.806_65,
            max_angular_rate_rps: 34.906_585,
            max_tas_mps: 150.0,
            max_vane_angle_deg: 90.0,
            max_pressure_pa: 120_000.0,
            min_temp_k: 150.0,
            max_temp_k: 350.0,
            max_mag_nt: 200_000.0,
            max_gnss_speed_mps: 600.0,
            min_gnss_h_m: -1_000.0,
            max_gnss_h_m: 50_000.0,
        }
    }
}

/// Configuration of the whole INS. Any section may be omitted (it takes its defaults); a
/// section that is present must be complete; unknown keys are errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InsConfig {
    /// Period at which the per-step Q̃ and the IMU R are specified, s (the authors' 100 Hz).
    #[serde(default = "default_reference_period_s")]
    pub reference_period_s: f64,
    /// IMU steps longer than this are flagged as gaps in the solution and counted, s.
    #[serde(default = "default_imu_gap_s")]
    pub imu_gap_s: f64,
    /// Longest propagation sub-step: longer IMU intervals are split, s.
    #[serde(default = "default_max_substep_s")]
    pub max_substep_s: f64,
    /// Air-data filter.
    #[serde(default)]
    pub air: AirDataFilterConfig,
    /// Attitude filter.
    #[serde(default)]
    pub attitude: AttitudeFilterConfig,
    /// Position filter and GNSS-loss logic.
    #[serde(default)]
    pub position: PositionFilterConfig,
    /// Transfer alignment on the autopilot's attitude.
    #[serde(default)]
    pub alignment: AlignmentConfig,
    /// Input validation bounds.
    #[serde(default)]
    pub limits: InputLimits,
    /// Adopting the IMU's measured white noise (docs/INS.md "IMU noise adoption").
    #[serde(default)]
    pub imu_noise: ImuNoiseAdoptionConfig,
}

/// When the INS replaces the configured IMU noise by the measured one (`src/ins/imu_noise.rs`).
/// The model is only ever raised: a configured R above the measured white noise often holds
/// vibration or model error on purpose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImuNoiseAdoptionConfig {
    /// Adopt the measured noise; `false` pins the configured model (the check still reports).
    pub adopt: bool,
    /// Measured over the model in use above which it is adopted (the report's threshold).
    pub adopt_ratio: f64,
    /// Airspeed above which the aircraft counts as flying, m/s: before, the measurement is the
    /// sensor's own (no vibration, no gusts) and adopted up to the ceilings below; after, the
    /// gyro and velocity random walk may grow by at most `max_flight_growth`.
    pub flying_tas_mps: f64,
    /// In flight, the adopted variances stay within this factor of those in use at take-off
    /// (100 = 10× in σ): vibration raises the noise, a sensor fault must not make the INS
    /// ignore its gyro.
    pub max_flight_growth: f64,
    /// Gyro R never adopted above this, (rad/s)² at the reference period.
    pub max_gyro_var_rad2ps2: f64,
    /// Accelerometer variance never adopted above this, (m/s²)² at the reference period.
    pub max_accel_var_m2ps4: f64,
}

impl Default for ImuNoiseAdoptionConfig {
    fn default() -> Self {
        Self {
            adopt: true,
            adopt_ratio: 4.0,
            flying_tas_mps: 10.0,
            max_flight_growth: 100.0,
            // σ 0.1 rad/s (5.7 °/s) and 2 m/s² per 10 ms sample: 40× PX4 SIH's gyro variance.
            max_gyro_var_rad2ps2: 1e-2,
            max_accel_var_m2ps4: 4.0,
        }
    }
}

fn default_reference_period_s() -> f64 {
    0.01
}
fn default_imu_gap_s() -> f64 {
    0.1
}
fn default_max_substep_s() -> f64 {
    0.02
}

impl Default for InsConfig {
    fn default() -> Self {
        Self {
            reference_period_s: default_reference_period_s(),
            imu_gap_s: default_imu_gap_s(),
            max_substep_s: default_max_substep_s(),
            air: AirDataFilterConfig::default(),
            attitude: AttitudeFilterConfig::default(),
            position: PositionFilterConfig::default(),
            alignment: AlignmentConfig::default(),
            limits: InputLimits::default(),
            imu_noise: ImuNoiseAdoptionConfig::default(),
        }
    }
}

impl InsConfig {
    /// Parse a TOML document (see `config/ins.toml`) and validate it.
    pub fn from_toml_str(s: &str) -> Result<Self, InsConfigError> {
        let cfg: Self = toml::from_str(s)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check every field: process noises finite and ≥ 0, observation noises, periods and
    /// bounds finite and > 0 (bounds ordered). The error names the offending field.
    pub fn validate(&self) -> Result<(), InsConfigError> {
        positive("reference_period_s", self.reference_period_s)?;
        positive("imu_gap_s", self.imu_gap_s)?;
        positive("max_substep_s", self.max_substep_s)?;
        let a = &self.air;
        for (i, q) in a.q.iter().enumerate() {
            non_negative(&format!("air.q[{i}]"), *q)?;
        }
        positive("air.tas_noise_sigma_mps", a.tas_noise_sigma_mps)?;
        non_negative("air.tas_bias_sigma_mps", a.tas_bias_sigma_mps)?;
        positive("air.aoa_noise_sigma_deg", a.aoa_noise_sigma_deg)?;
        non_negative("air.aoa_bias_sigma_deg", a.aoa_bias_sigma_deg)?;
        positive("air.aos_noise_sigma_deg", a.aos_noise_sigma_deg)?;
        non_negative("air.aos_bias_sigma_deg", a.aos_bias_sigma_deg)?;
        positive("air.temp_noise_sigma_k", a.temp_noise_sigma_k)?;
        non_negative("air.temp_bias_sigma_k", a.temp_bias_sigma_k)?;
        positive("air.p_noise_sigma_pa", a.p_noise_sigma_pa)?;
        non_negative("air.p_bias_sigma_pa", a.p_bias_sigma_pa)?;
        positive("air.no_vane_angle_sigma_deg", a.no_vane_angle_sigma_deg)?;
        positive("air.no_vane_aos_sigma_deg", a.no_vane_aos_sigma_deg)?;
        let t = &self.attitude;
        non_negative("attitude.q_attitude_rad2", t.q_attitude_rad2)?;
        non_negative("attitude.q_w_nb_rad2ps2", t.q_w_nb_rad2ps2)?;
        non_negative("attitude.q_e_gyr_rad2ps2", t.q_e_gyr_rad2ps2)?;
        non_negative("attitude.q_e_mag_nt2", t.q_e_mag_nt2)?;
        non_negative("attitude.q_delta_b_nt2", t.q_delta_b_nt2)?;
        positive("attitude.r_gyro_rad2ps2", t.r_gyro_rad2ps2)?;
        positive("attitude.r_accel_white_m2ps4", t.r_accel_white_m2ps4)?;
        positive(
            "attitude.r_accel_turbulence_ref_tas_mps",
            t.r_accel_turbulence_ref_tas_mps,
        )?;
        for (i, r) in t.r_accel_turbulence_m2ps4.iter().enumerate() {
            non_negative(&format!("attitude.r_accel_turbulence_m2ps4[{i}]"), *r)?;
        }
        positive("attitude.r_mag_nt2", t.r_mag_nt2)?;
        positive("attitude.p0_attitude_sigma_deg", t.p0_attitude_sigma_deg)?;
        non_negative("attitude.gyro_noise_var_rad2ps2", t.gyro_noise_var_rad2ps2)?;
        non_negative("attitude.r_accel_turn_rel", t.r_accel_turn_rel)?;
        positive(
            "attitude.r_accel_turn_correlation_s",
            t.r_accel_turn_correlation_s,
        )?;
        let p = &self.position;
        non_negative("position.q_position_m2", p.q_position_m2)?;
        non_negative("position.q_velocity_m2ps2", p.q_velocity_m2ps2)?;
        non_negative("position.q_specific_force_m2ps4", p.q_specific_force_m2ps4)?;
        non_negative("position.q_e_acc_m2ps4", p.q_e_acc_m2ps4)?;
        positive("position.r_accel_m2ps4", p.r_accel_m2ps4)?;
        positive("position.gnss_sigma_hor_m", p.gnss_sigma_hor_m)?;
        positive("position.gnss_sigma_ver_m", p.gnss_sigma_ver_m)?;
        positive("position.gnss_sigma_vel_mps", p.gnss_sigma_vel_mps)?;
        positive("position.gnss_gate_chi2", p.gnss_gate_chi2)?;
        positive("position.gnss_timeout_s", p.gnss_timeout_s)?;
        if p.gnss_max_consecutive_rejections == 0 {
            return Err(invalid(
                "position.gnss_max_consecutive_rejections",
                0.0,
                "must be at least 1",
            ));
        }
        non_negative("position.gnss_max_lag_s", p.gnss_max_lag_s)?;
        non_negative("position.lpf_window_s", p.lpf_window_s)?;
        for l in p.turbulence_integral_scale_m {
            positive("position.turbulence_integral_scale_m", l)?;
        }
        non_negative("position.gnss_bias_sigma_m", p.gnss_bias_sigma_m)?;
        positive(
            "position.airspeed_bias_min_heading_spread",
            p.airspeed_bias_min_heading_spread,
        )?;
        let g = &self.alignment;
        positive("alignment.ref_attitude_sigma_deg", g.ref_attitude_sigma_deg)?;
        for v in g.ref_error_sigma_deg {
            non_negative("alignment.ref_error_sigma_deg", v)?;
        }
        positive("alignment.ref_error_time_s", g.ref_error_time_s)?;
        non_negative("alignment.min_interval_s", g.min_interval_s)?;
        non_negative("alignment.max_lag_s", g.max_lag_s)?;
        positive("alignment.gate_chi2", g.gate_chi2)?;
        if g.max_consecutive_rejections == 0 {
            return Err(invalid(
                "alignment.max_consecutive_rejections",
                0.0,
                "must be at least 1",
            ));
        }
        let n = &self.imu_noise;
        if !(n.adopt_ratio.is_finite() && n.adopt_ratio >= 1.0) {
            return Err(invalid(
                "imu_noise.adopt_ratio",
                n.adopt_ratio,
                "must be at least 1",
            ));
        }
        non_negative("imu_noise.flying_tas_mps", n.flying_tas_mps)?;
        if !(n.max_flight_growth.is_finite() && n.max_flight_growth >= 1.0) {
            return Err(invalid(
                "imu_noise.max_flight_growth",
                n.max_flight_growth,
                "must be at least 1",
            ));
        }
        positive("imu_noise.max_gyro_var_rad2ps2", n.max_gyro_var_rad2ps2)?;
        positive("imu_noise.max_accel_var_m2ps4", n.max_accel_var_m2ps4)?;
        let l = &self.limits;
        positive("limits.max_specific_force_mps2", l.max_specific_force_mps2)?;
        positive("limits.max_angular_rate_rps", l.max_angular_rate_rps)?;
        positive("limits.max_tas_mps", l.max_tas_mps)?;
        positive("limits.max_vane_angle_deg", l.max_vane_angle_deg)?;
        positive("limits.max_pressure_pa", l.max_pressure_pa)?;
        positive("limits.min_temp_k", l.min_temp_k)?;
        positive("limits.max_temp_k", l.max_temp_k)?;
        if l.max_temp_k <= l.min_temp_k {
            return Err(invalid(
                "limits.max_temp_k",
                l.max_temp_k,
                "must exceed limits.min_temp_k",
            ));
        }
        positive("limits.max_mag_nt", l.max_mag_nt)?;
        positive("limits.max_gnss_speed_mps", l.max_gnss_speed_mps)?;
        finite("limits.min_gnss_h_m", l.min_gnss_h_m)?;
        finite("limits.max_gnss_h_m", l.max_gnss_h_m)?;
        if l.max_gnss_h_m <= l.min_gnss_h_m {
            return Err(invalid(
                "limits.max_gnss_h_m",
                l.max_gnss_h_m,
                "must exceed limits.min_gnss_h_m",
            ));
        }
        Ok(())
    }
}

fn invalid(field: &str, value: f64, reason: &'static str) -> InsConfigError {
    InsConfigError::Invalid {
        field: field.to_owned(),
        value,
        reason,
    }
}

fn finite(field: &str, v: f64) -> Result<(), InsConfigError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(field, v, "must be finite"))
    }
}

fn non_negative(field: &str, v: f64) -> Result<(), InsConfigError> {
    finite(field, v)?;
    if v >= 0.0 {
        Ok(())
    } else {
        Err(invalid(field, v, "must be non-negative"))
    }
}

fn positive(field: &str, v: f64) -> Result<(), InsConfigError> {
    finite(field, v)?;
    if v > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, v, "must be positive"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = include_str!("../../config/ins.toml");

    #[test]
    fn shipped_file_is_the_default() {
        assert_eq!(
            InsConfig::from_toml_str(FILE).unwrap(),
            InsConfig::default()
        );
        InsConfig::default().validate().unwrap();
    }

    #[test]
    fn omitted_sections_take_defaults_and_round_trip() {
        assert_eq!(InsConfig::from_toml_str("").unwrap(), InsConfig::default());
        let mut cfg = InsConfig::default();
        cfg.position.gnss_timeout_s = 3.0;
        cfg.air.q[3] = 2e-4;
        let text = toml::to_string(&cfg).unwrap();
        assert_eq!(InsConfig::from_toml_str(&text).unwrap(), cfg);
    }

    #[test]
    fn invalid_values_name_the_field() {
        let field = |text: &str| match InsConfig::from_toml_str(text) {
            Err(InsConfigError::Invalid { field, .. }) => field,
            other => panic!("expected Invalid, got {other:?}"),
        };
        let bad = FILE.replace("gnss_timeout_s = 1.5", "gnss_timeout_s = -1.0");
        assert_eq!(field(&bad), "position.gnss_timeout_s");
        let bad = FILE.replace("r_mag_nt2 = 2e6", "r_mag_nt2 = nan");
        assert_eq!(field(&bad), "attitude.r_mag_nt2");
        assert_eq!(field("reference_period_s = 0.0"), "reference_period_s");
        // Unknown keys and incomplete sections are structural errors.
        assert!(matches!(
            InsConfig::from_toml_str("imu_rate_hz = 100.0"),
            Err(InsConfigError::Toml(_))
        ));
        assert!(matches!(
            InsConfig::from_toml_str("[position]\ngnss_timeout_s = 2.0"),
            Err(InsConfigError::Toml(_))
        ));
    }
}
