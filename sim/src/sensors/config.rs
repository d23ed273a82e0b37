//! Sensor error-model parameters (docs/REFERENCES.md A2.1–A2.5), their defaults (the authors'
//! "base" grades), the other grades as named presets, TOML loading and validation.
//!
//! Units: SI inside the structs except where a field name says `_deg` (configuration only;
//! converted to radians when the sensors are built). The inertial parameters are shared by
//! the gyroscope (rad/s based) and the accelerometer (m/s² based), so their field docs give
//! both units.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Radians per degree, for the defaults that docs/REFERENCES.md A2 states in degrees.
const RAD_PER_DEG: f64 = std::f64::consts::PI / 180.0;

/// Soft band limit `L` of the bias random walks and of the ionospheric walk, in steps
/// (docs/REFERENCES.md A2.1 `band_id_base`).
pub const DEFAULT_BAND_LIMIT_STEPS: f64 = 100.0;
/// Safety margin of the soft band, in steps (docs/REFERENCES.md A2.1).
pub const DEFAULT_BAND_SAFETY_STEPS: f64 = 20.0;

/// Structure of the scale and cross-coupling matrix `M` (docs/REFERENCES.md A2.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CrossCoupling {
    /// Full 3×3 (gyroscope): diagonal `s·ν`, off-diagonal `m·ν`.
    Full,
    /// Lower-triangular (accelerometer): diagonal `s·ν`, below-diagonal `m·ν`, above zero.
    LowerTriangular,
}

/// Error model of one inertial triad (gyroscope or accelerometer), docs/REFERENCES.md A2.1.
///
/// Units are those of the measured quantity `u` (rad/s for the gyroscope, m/s² for the
/// accelerometer).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InertialConfig {
    /// σ of the constant per-run bias offset `B₀`, per axis: rad/s (gyro) or m/s² (accel).
    pub bias_offset_sigma: f64,
    /// Bias random-walk density `σ_u`: rad/s^1.5 (gyro) or m/s^2.5 (accel). Each sample the
    /// walk moves by `σ_u·√Δt·ν`.
    pub bias_rw_sigma: f64,
    /// White-noise density `σ_v`: rad/s^0.5 (gyro) or m/s^1.5 (accel). Per-sample σ is
    /// `σ_v/√Δt`.
    pub noise_density: f64,
    /// σ of the scale-factor errors `s` (diagonal of `M`), dimensionless.
    pub scale_sigma: f64,
    /// σ of the cross-coupling errors `m` (off-diagonal of `M`), dimensionless.
    pub cross_coupling_sigma: f64,
    /// Structure of `M`: `"full"` (gyro) or `"lower_triangular"` (accel).
    pub cross_coupling: CrossCoupling,
    /// Soft band limit `L` of the bias walk, in walk steps (`inf` = unbounded walk).
    pub band_limit_steps: f64,
    /// Safety margin of the soft band, in walk steps: the pull starts at `L − safety`.
    pub band_safety_steps: f64,
}

impl InertialConfig {
    /// Gyroscope from the docs/REFERENCES.md A2.1 grade tuple
    /// (σ_u °/s^1.5, σ_v °/s^0.5, s, m, B₀ °/s).
    fn gyro_grade(sigma_u_deg: f64, sigma_v_deg: f64, s: f64, m: f64, b0_deg: f64) -> Self {
        Self {
            bias_offset_sigma: b0_deg * RAD_PER_DEG,
            bias_rw_sigma: sigma_u_deg * RAD_PER_DEG,
            noise_density: sigma_v_deg * RAD_PER_DEG,
            scale_sigma: s,
            cross_coupling_sigma: m,
            cross_coupling: CrossCoupling::Full,
            band_limit_steps: DEFAULT_BAND_LIMIT_STEPS,
            band_safety_steps: DEFAULT_BAND_SAFETY_STEPS,
        }
    }

    /// Accelerometer from the docs/REFERENCES.md A2.1 grade tuple
    /// (σ_u m/s^2.5, σ_v m/s^1.5, s, m, B₀ m/s²).
    fn accel_grade(sigma_u: f64, sigma_v: f64, s: f64, m: f64, b0: f64) -> Self {
        Self {
            bias_offset_sigma: b0,
            bias_rw_sigma: sigma_u,
            noise_density: sigma_v,
            scale_sigma: s,
            cross_coupling_sigma: m,
            cross_coupling: CrossCoupling::LowerTriangular,
            band_limit_steps: DEFAULT_BAND_LIMIT_STEPS,
            band_safety_steps: DEFAULT_BAND_SAFETY_STEPS,
        }
    }

    /// Gyroscope, "base" grade (the default; docs/REFERENCES.md A2.1 table).
    pub fn gyro_base() -> Self {
        Self::gyro_grade(1.42e-4, 4.30e-3, 1.50e-5, 4.35e-5, 0.200)
    }

    /// Gyroscope, "better" grade.
    pub fn gyro_better() -> Self {
        Self::gyro_grade(1.38e-5, 2.5e-3, 5e-6, 1.5e-5, 0.03)
    }

    /// Gyroscope, "worse" grade.
    pub fn gyro_worse() -> Self {
        Self::gyro_grade(5e-4, 8e-3, 5e-5, 1.5e-4, 0.75)
    }

    /// Gyroscope, "worst" grade.
    pub fn gyro_worst() -> Self {
        Self::gyro_grade(1.5e-3, 2.5e-2, 1e-4, 4.5e-4, 1.5)
    }

    /// Accelerometer, "base" grade (the default; docs/REFERENCES.md A2.1 table).
    pub fn accel_base() -> Self {
        Self::accel_grade(6.86e-5, 4.83e-4, 5.00e-5, 3.05e-5, 0.157)
    }

    /// Accelerometer, "better" grade.
    pub fn accel_better() -> Self {
        Self::accel_grade(4.9e-5, 3.3e-4, 1.5e-5, 1.5e-5, 1.96e-2)
    }

    /// Accelerometer, "worse" grade.
    pub fn accel_worse() -> Self {
        Self::accel_grade(8.5e-5, 5e-4, 8.5e-5, 5e-5, 0.45)
    }

    /// Accelerometer, "worst" grade.
    pub fn accel_worst() -> Self {
        Self::accel_grade(1.2e-4, 6.5e-4, 1.4e-4, 9.5e-5, 0.85)
    }

    /// The same triad with every error source set to zero (structure and band kept).
    pub fn perfect(mut self) -> Self {
        self.bias_offset_sigma = 0.0;
        self.bias_rw_sigma = 0.0;
        self.noise_density = 0.0;
        self.scale_sigma = 0.0;
        self.cross_coupling_sigma = 0.0;
        self
    }

    fn validate(&self, section: &str) -> Result<(), SensorConfigError> {
        non_negative(section, "bias_offset_sigma", self.bias_offset_sigma)?;
        non_negative(section, "bias_rw_sigma", self.bias_rw_sigma)?;
        non_negative(section, "noise_density", self.noise_density)?;
        non_negative(section, "scale_sigma", self.scale_sigma)?;
        non_negative(section, "cross_coupling_sigma", self.cross_coupling_sigma)?;
        band(
            section,
            "band_limit_steps",
            "band_safety_steps",
            self.band_limit_steps,
            self.band_safety_steps,
        )
    }
}

/// IMU platform mounting: position and orientation of the IMU in the airframe, true and as
/// the navigation believes them (docs/REFERENCES.md A2.2; drawn from the aircraft stream).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlatformConfig {
    /// Nominal (true) IMU position from the aircraft reference point, body axes `T_rp^b`, m.
    pub t_rp_b_m: [f64; 3],
    /// σ of the navigation's error in `T_rp^b`, per axis, m (estimated = true + σ·ν).
    pub t_rp_est_sigma_m: f64,
    /// σ of the true body→platform Euler angles (yaw, pitch, bank) about zero, deg.
    pub euler_bp_sigma_deg: [f64; 3],
    /// σ of the navigation's error in each body→platform Euler angle, deg.
    pub euler_bp_est_sigma_deg: f64,
}

impl Default for PlatformConfig {
    fn default() -> Self {
        Self {
            t_rp_b_m: [0.30, 0.0, 0.10],
            t_rp_est_sigma_m: 0.01,
            euler_bp_sigma_deg: [0.5, 2.0, 0.1],
            euler_bp_est_sigma_deg: 0.03,
        }
    }
}

impl PlatformConfig {
    fn validate(&self) -> Result<(), SensorConfigError> {
        for (i, v) in self.t_rp_b_m.iter().enumerate() {
            finite("platform", &format!("t_rp_b_m[{i}]"), *v)?;
        }
        non_negative("platform", "t_rp_est_sigma_m", self.t_rp_est_sigma_m)?;
        for (i, v) in self.euler_bp_sigma_deg.iter().enumerate() {
            non_negative("platform", &format!("euler_bp_sigma_deg[{i}]"), *v)?;
        }
        non_negative(
            "platform",
            "euler_bp_est_sigma_deg",
            self.euler_bp_est_sigma_deg,
        )
    }
}

/// Magnetometer error model (docs/REFERENCES.md A2.3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagConfig {
    /// Sample period Δt of the magnetometer, s (scales the white noise).
    pub period_s: f64,
    /// White-noise density `σ_v`, nT·s^0.5 (per-sample σ is `σ_v/√Δt`).
    pub noise_density_nt_sqrt_s: f64,
    /// σ of the soft-iron diagonal (scale) terms `s`, dimensionless.
    pub soft_iron_scale_sigma: f64,
    /// σ of the soft-iron off-diagonal terms `m` (full 3×3), dimensionless.
    pub soft_iron_cross_sigma: f64,
    /// σ of the per-run offset `B_off` (run stream), per axis, nT.
    pub offset_sigma_nt: f64,
    /// σ of the hard iron `B_hi` (aircraft stream), per axis, nT.
    pub hard_iron_sigma_nt: f64,
}

impl MagConfig {
    /// "base" grade (the default).
    pub fn base() -> Self {
        Self::grade(5.0, 7.5e-4, 9.16e-4, 500.0, 175.0)
    }

    /// "better" grade.
    pub fn better() -> Self {
        Self::grade(3.0, 5e-4, 7e-4, 300.0, 125.0)
    }

    /// "worse" grade.
    pub fn worse() -> Self {
        Self::grade(10.0, 1.25e-3, 1.5e-3, 750.0, 350.0)
    }

    fn grade(sigma_v: f64, s: f64, m: f64, off: f64, hi: f64) -> Self {
        Self {
            period_s: 0.01,
            noise_density_nt_sqrt_s: sigma_v,
            soft_iron_scale_sigma: s,
            soft_iron_cross_sigma: m,
            offset_sigma_nt: off,
            hard_iron_sigma_nt: hi,
        }
    }

    fn validate(&self) -> Result<(), SensorConfigError> {
        positive("mag", "period_s", self.period_s)?;
        non_negative(
            "mag",
            "noise_density_nt_sqrt_s",
            self.noise_density_nt_sqrt_s,
        )?;
        non_negative("mag", "soft_iron_scale_sigma", self.soft_iron_scale_sigma)?;
        non_negative("mag", "soft_iron_cross_sigma", self.soft_iron_cross_sigma)?;
        non_negative("mag", "offset_sigma_nt", self.offset_sigma_nt)?;
        non_negative("mag", "hard_iron_sigma_nt", self.hard_iron_sigma_nt)
    }
}

impl Default for MagConfig {
    fn default() -> Self {
        Self::base()
    }
}

/// Air-data sensors: Pitot (TAS), AoA and AoS vanes, static pressure, outside air temperature
/// (docs/REFERENCES.md A2.4). Each is `ỹ = x + B₀ν₀ + σν_k`, with a per-sample σ independent of the
/// sample rate (docs/REFERENCES.md A9.10, kept on purpose).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AirDataConfig {
    /// Sample period of the air-data sensors, s (scheduling only: the noise does not depend
    /// on it).
    pub period_s: f64,
    /// Whether AoA and AoS vanes are fitted (`false` → `None` in `AirSample`).
    pub vanes_enabled: bool,
    /// Per-sample white-noise σ of the true airspeed, m/s.
    pub tas_noise_sigma_mps: f64,
    /// σ of the constant per-run true-airspeed bias, m/s.
    pub tas_bias_sigma_mps: f64,
    /// Per-sample white-noise σ of the angle of attack, deg.
    pub aoa_noise_sigma_deg: f64,
    /// σ of the constant per-run angle-of-attack bias, deg.
    pub aoa_bias_sigma_deg: f64,
    /// Per-sample white-noise σ of the angle of sideslip, deg.
    pub aos_noise_sigma_deg: f64,
    /// σ of the constant per-run angle-of-sideslip bias, deg.
    pub aos_bias_sigma_deg: f64,
    /// Per-sample white-noise σ of the static pressure, Pa.
    pub p_noise_sigma_pa: f64,
    /// σ of the constant per-run static-pressure bias, Pa.
    pub p_bias_sigma_pa: f64,
    /// Per-sample white-noise σ of the outside air temperature, K.
    pub temp_noise_sigma_k: f64,
    /// σ of the constant per-run outside-air-temperature bias, K.
    pub temp_bias_sigma_k: f64,
}

impl Default for AirDataConfig {
    fn default() -> Self {
        Self {
            period_s: 0.01,
            vanes_enabled: true,
            tas_noise_sigma_mps: 0.333,
            tas_bias_sigma_mps: 0.333,
            aoa_noise_sigma_deg: 0.333,
            aoa_bias_sigma_deg: 0.333,
            aos_noise_sigma_deg: 0.333,
            aos_bias_sigma_deg: 0.333,
            p_noise_sigma_pa: 100.0,
            p_bias_sigma_pa: 100.0,
            temp_noise_sigma_k: 0.05,
            temp_bias_sigma_k: 0.05,
        }
    }
}

impl AirDataConfig {
    fn validate(&self) -> Result<(), SensorConfigError> {
        positive("air", "period_s", self.period_s)?;
        let fields = [
            ("tas_noise_sigma_mps", self.tas_noise_sigma_mps),
            ("tas_bias_sigma_mps", self.tas_bias_sigma_mps),
            ("aoa_noise_sigma_deg", self.aoa_noise_sigma_deg),
            ("aoa_bias_sigma_deg", self.aoa_bias_sigma_deg),
            ("aos_noise_sigma_deg", self.aos_noise_sigma_deg),
            ("aos_bias_sigma_deg", self.aos_bias_sigma_deg),
            ("p_noise_sigma_pa", self.p_noise_sigma_pa),
            ("p_bias_sigma_pa", self.p_bias_sigma_pa),
            ("temp_noise_sigma_k", self.temp_noise_sigma_k),
            ("temp_bias_sigma_k", self.temp_bias_sigma_k),
        ];
        fields
            .iter()
            .try_for_each(|(name, v)| non_negative("air", name, *v))
    }
}

/// GNSS receiver (docs/REFERENCES.md A2.5): white position and velocity noise plus a slowly varying
/// ionospheric position error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssConfig {
    /// Fix period, s.
    pub period_s: f64,
    /// White horizontal position noise σ, per axis (north, east), m.
    pub sigma_hor_m: f64,
    /// White vertical position noise σ, m.
    pub sigma_ver_m: f64,
    /// White velocity noise σ, per NED axis, m/s.
    pub sigma_vel_mps: f64,
    /// Ionospheric walk scale `σ_iono` (metres per walk step), m.
    pub iono_sigma_m: f64,
    /// σ of the initial ionospheric walk position, in walk steps (×`σ_iono` → metres).
    pub iono_initial_sigma_steps: f64,
    /// Number of fixes between two ionospheric walk nodes (one walk step per node).
    pub iono_fixes_per_step: u32,
    /// Soft band limit `L` of the ionospheric walk, in steps (`inf` = unbounded).
    pub iono_band_limit_steps: f64,
    /// Safety margin of the ionospheric soft band, in steps.
    pub iono_band_safety_steps: f64,
}

impl Default for GnssConfig {
    fn default() -> Self {
        Self {
            period_s: 1.0,
            sigma_hor_m: 2.12,
            sigma_ver_m: 4.25,
            sigma_vel_mps: 0.0741,
            iono_sigma_m: 0.16,
            iono_initial_sigma_steps: 50.0,
            iono_fixes_per_step: 60,
            iono_band_limit_steps: DEFAULT_BAND_LIMIT_STEPS,
            iono_band_safety_steps: DEFAULT_BAND_SAFETY_STEPS,
        }
    }
}

impl GnssConfig {
    fn validate(&self) -> Result<(), SensorConfigError> {
        positive("gnss", "period_s", self.period_s)?;
        non_negative("gnss", "sigma_hor_m", self.sigma_hor_m)?;
        non_negative("gnss", "sigma_ver_m", self.sigma_ver_m)?;
        non_negative("gnss", "sigma_vel_mps", self.sigma_vel_mps)?;
        non_negative("gnss", "iono_sigma_m", self.iono_sigma_m)?;
        non_negative(
            "gnss",
            "iono_initial_sigma_steps",
            self.iono_initial_sigma_steps,
        )?;
        if self.iono_fixes_per_step == 0 {
            return Err(SensorConfigError::Invalid {
                field: "gnss.iono_fixes_per_step".into(),
                value: 0.0,
                reason: "must be at least 1",
            });
        }
        band(
            "gnss",
            "iono_band_limit_steps",
            "iono_band_safety_steps",
            self.iono_band_limit_steps,
            self.iono_band_safety_steps,
        )
    }
}

/// All simulated-sensor parameters. `Default` = the docs/REFERENCES.md A2 "base" values.
///
/// In TOML every section may be omitted (it then takes its default); a section that is
/// present must give all its fields, and unknown fields are rejected.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorsConfig {
    /// IMU (gyroscope and accelerometer) sample period Δt, s.
    pub imu_period_s: f64,
    /// Gyroscope error model.
    pub gyro: InertialConfig,
    /// Accelerometer error model.
    pub accel: InertialConfig,
    /// IMU mounting (misalignment and lever arm).
    pub platform: PlatformConfig,
    /// Magnetometer error model.
    pub mag: MagConfig,
    /// Air-data sensors.
    pub air: AirDataConfig,
    /// GNSS receiver.
    pub gnss: GnssConfig,
}

impl Default for SensorsConfig {
    fn default() -> Self {
        Self {
            imu_period_s: 0.01,
            gyro: InertialConfig::gyro_base(),
            accel: InertialConfig::accel_base(),
            platform: PlatformConfig::default(),
            mag: MagConfig::base(),
            air: AirDataConfig::default(),
            gnss: GnssConfig::default(),
        }
    }
}

impl SensorsConfig {
    /// Every error source set to zero: the sensors return the truth (rates kept, lever arm
    /// kept but estimated exactly).
    pub fn perfect() -> Self {
        let d = Self::default();
        Self {
            gyro: d.gyro.perfect(),
            accel: d.accel.perfect(),
            platform: PlatformConfig {
                t_rp_est_sigma_m: 0.0,
                euler_bp_sigma_deg: [0.0; 3],
                euler_bp_est_sigma_deg: 0.0,
                ..d.platform
            },
            mag: MagConfig {
                noise_density_nt_sqrt_s: 0.0,
                soft_iron_scale_sigma: 0.0,
                soft_iron_cross_sigma: 0.0,
                offset_sigma_nt: 0.0,
                hard_iron_sigma_nt: 0.0,
                ..d.mag
            },
            air: AirDataConfig {
                tas_noise_sigma_mps: 0.0,
                tas_bias_sigma_mps: 0.0,
                aoa_noise_sigma_deg: 0.0,
                aoa_bias_sigma_deg: 0.0,
                aos_noise_sigma_deg: 0.0,
                aos_bias_sigma_deg: 0.0,
                p_noise_sigma_pa: 0.0,
                p_bias_sigma_pa: 0.0,
                temp_noise_sigma_k: 0.0,
                temp_bias_sigma_k: 0.0,
                ..d.air
            },
            gnss: GnssConfig {
                sigma_hor_m: 0.0,
                sigma_ver_m: 0.0,
                sigma_vel_mps: 0.0,
                iono_sigma_m: 0.0,
                ..d.gnss
            },
            ..d
        }
    }

    /// Parse a TOML document (see `config/sensors.toml`) and validate it.
    pub fn from_toml_str(s: &str) -> Result<Self, SensorConfigError> {
        let cfg: Self = toml::from_str(s)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check every field: periods finite and positive, σ finite and non-negative, band limits
    /// above their safety margins. The error names the offending field.
    pub fn validate(&self) -> Result<(), SensorConfigError> {
        positive("", "imu_period_s", self.imu_period_s)?;
        self.gyro.validate("gyro")?;
        self.accel.validate("accel")?;
        self.platform.validate()?;
        self.mag.validate()?;
        self.air.validate()?;
        self.gnss.validate()
    }
}

/// Why a sensors configuration was rejected.
#[derive(Debug, Error)]
pub enum SensorConfigError {
    /// The TOML text does not parse or does not match the structure (unknown or missing
    /// field, wrong type).
    #[error("sensors configuration: {0}")]
    Toml(#[from] toml::de::Error),
    /// A field has a value outside its domain.
    #[error("sensors configuration: `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field, e.g. `gyro.noise_density`.
        field: String,
        /// The rejected value.
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
}

fn path(section: &str, name: &str) -> String {
    if section.is_empty() {
        name.to_owned()
    } else {
        format!("{section}.{name}")
    }
}

fn finite(section: &str, name: &str, v: f64) -> Result<(), SensorConfigError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(SensorConfigError::Invalid {
            field: path(section, name),
            value: v,
            reason: "must be finite",
        })
    }
}

fn non_negative(section: &str, name: &str, v: f64) -> Result<(), SensorConfigError> {
    finite(section, name, v)?;
    if v >= 0.0 {
        Ok(())
    } else {
        Err(SensorConfigError::Invalid {
            field: path(section, name),
            value: v,
            reason: "must be non-negative",
        })
    }
}

fn positive(section: &str, name: &str, v: f64) -> Result<(), SensorConfigError> {
    finite(section, name, v)?;
    if v > 0.0 {
        Ok(())
    } else {
        Err(SensorConfigError::Invalid {
            field: path(section, name),
            value: v,
            reason: "must be positive",
        })
    }
}

/// Band limit may be infinite (no band); the safety margin must be positive and below it.
fn band(
    section: &str,
    limit_name: &str,
    safety_name: &str,
    limit: f64,
    safety: f64,
) -> Result<(), SensorConfigError> {
    positive(section, safety_name, safety)?;
    if limit.is_nan() || limit <= safety {
        return Err(SensorConfigError::Invalid {
            field: path(section, limit_name),
            value: limit,
            reason: "must exceed the band safety margin (use inf for no band)",
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = include_str!("../../../config/sensors.toml");

    fn invalid_field(r: Result<SensorsConfig, SensorConfigError>) -> String {
        match r {
            Err(SensorConfigError::Invalid { field, .. }) => field,
            other => panic!("expected an Invalid error, got {other:?}"),
        }
    }

    #[test]
    fn shipped_file_is_the_default() {
        assert_eq!(
            SensorsConfig::from_toml_str(FILE).unwrap(),
            SensorsConfig::default()
        );
    }

    #[test]
    fn omitted_sections_take_defaults_and_round_trip() {
        assert_eq!(
            SensorsConfig::from_toml_str("").unwrap(),
            SensorsConfig::default()
        );
        let cfg = SensorsConfig::from_toml_str("imu_period_s = 0.005").unwrap();
        assert_eq!(cfg.imu_period_s, 0.005);
        assert_eq!(cfg.gyro, InertialConfig::gyro_base());
        let mut odd = SensorsConfig::perfect();
        odd.gyro.band_limit_steps = f64::INFINITY;
        odd.air.vanes_enabled = false;
        let text = toml::to_string(&odd).unwrap();
        assert_eq!(SensorsConfig::from_toml_str(&text).unwrap(), odd);
    }

    #[test]
    fn structural_errors_are_rejected() {
        // Unknown field, in a section and at the top level.
        let bad = FILE.replace("period_s = 1.0", "period_s = 1.0\nrate_hz = 1.0");
        assert!(matches!(
            SensorsConfig::from_toml_str(&bad),
            Err(SensorConfigError::Toml(_))
        ));
        assert!(SensorsConfig::from_toml_str("imu_rate_hz = 100.0").is_err());
        // A present section must be complete.
        assert!(SensorsConfig::from_toml_str("[mag]\nperiod_s = 0.01").is_err());
        // Wrong enum spelling.
        let bad = FILE.replace("\"lower_triangular\"", "\"upper\"");
        assert!(SensorsConfig::from_toml_str(&bad).is_err());
    }

    #[test]
    fn domain_errors_name_the_field() {
        let with = |from: &str, to: &str| {
            assert!(FILE.contains(from), "{from}");
            SensorsConfig::from_toml_str(&FILE.replacen(from, to, 1))
        };
        assert_eq!(
            invalid_field(with("imu_period_s = 0.01", "imu_period_s = 0.0")),
            "imu_period_s"
        );
        assert_eq!(
            invalid_field(with("noise_density = 4.83e-4", "noise_density = -4.83e-4")),
            "accel.noise_density"
        );
        assert_eq!(
            invalid_field(with("offset_sigma_nt = 500.0", "offset_sigma_nt = nan")),
            "mag.offset_sigma_nt"
        );
        assert_eq!(
            invalid_field(with(
                "t_rp_b_m = [0.30, 0.0, 0.10]",
                "t_rp_b_m = [0.3, inf, 0.1]"
            )),
            "platform.t_rp_b_m[1]"
        );
        assert_eq!(
            invalid_field(with("p_bias_sigma_pa = 100.0", "p_bias_sigma_pa = -1.0")),
            "air.p_bias_sigma_pa"
        );
        assert_eq!(
            invalid_field(with("iono_fixes_per_step = 60", "iono_fixes_per_step = 0")),
            "gnss.iono_fixes_per_step"
        );
        assert_eq!(
            invalid_field(with("band_limit_steps = 100.0", "band_limit_steps = 20.0")),
            "gyro.band_limit_steps"
        );
        assert_eq!(
            invalid_field(with("band_safety_steps = 20.0", "band_safety_steps = 0.0")),
            "gyro.band_safety_steps"
        );
        // An infinite band limit means "no band" and is accepted.
        assert!(with("band_limit_steps = 100.0", "band_limit_steps = inf").is_ok());
    }

    #[test]
    fn presets_are_valid_and_distinct() {
        let gyros = [
            InertialConfig::gyro_better(),
            InertialConfig::gyro_base(),
            InertialConfig::gyro_worse(),
            InertialConfig::gyro_worst(),
        ];
        let accels = [
            InertialConfig::accel_better(),
            InertialConfig::accel_base(),
            InertialConfig::accel_worse(),
            InertialConfig::accel_worst(),
        ];
        for (g, a) in gyros.iter().zip(&accels) {
            let cfg = SensorsConfig {
                gyro: *g,
                accel: *a,
                ..SensorsConfig::default()
            };
            cfg.validate().unwrap();
        }
        // Grades are ordered by white noise.
        assert!(
            gyros
                .windows(2)
                .all(|w| w[0].noise_density < w[1].noise_density)
        );
        assert!(
            accels
                .windows(2)
                .all(|w| w[0].noise_density < w[1].noise_density)
        );
        for mag in [MagConfig::better(), MagConfig::base(), MagConfig::worse()] {
            SensorsConfig {
                mag,
                ..SensorsConfig::default()
            }
            .validate()
            .unwrap();
        }
        SensorsConfig::perfect().validate().unwrap();
    }
}
