//! Camera intrinsics as configured (`[camera]` of `config/camera.toml` and of the daemon's
//! configuration; docs/CAMERA.md): the nominal pinhole from a focal length and a pixel pitch,
//! or the intrinsics and lens of a calibration file ([`crate::vision::calibration`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::mounting::MountingConfig;
use crate::vision::calibration::{Calibration, CalibrationError};
use crate::vision::lens::{Distortion, Lens, LensError, UndistortError};

/// Why a camera or mounting configuration was rejected.
#[derive(Debug, thiserror::Error)]
pub enum CameraConfigError {
    /// The TOML text does not parse or does not match the structure.
    #[error("camera configuration: {0}")]
    Toml(#[from] toml::de::Error),
    /// The configuration file could not be read.
    #[error("camera configuration: {path}: {error}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: std::io::Error,
    },
    /// A field has a value outside its domain.
    #[error("camera configuration: `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field.
        field: &'static str,
        /// The rejected value.
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
    /// A key is missing, or given where another key excludes it.
    #[error("camera configuration: `{field}`: {reason}")]
    Key {
        /// Dotted path of the key.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The calibration file named by `camera.calibration_file` was refused (the error names
    /// the file and its key).
    #[error("camera configuration: `camera.calibration_file`: {0}")]
    Calibration(#[from] Box<CalibrationError>),
    /// The distortion coefficients are unusable.
    #[error("camera configuration: `camera.calibration.distortion`: {0}")]
    Distortion(#[from] LensError),
    /// The lens model cannot be inverted somewhere in the image (it folds inside the field).
    #[error(
        "camera configuration: the lens model cannot be undistorted at pixel ({u_px}, {v_px}) \
         of the image: {reason}"
    )]
    Lens {
        /// Column of the failing pixel.
        u_px: f64,
        /// Row of the failing pixel.
        v_px: f64,
        /// Why.
        reason: UndistortError,
    },
}

pub(super) fn check(
    field: &'static str,
    value: f64,
    lo: f64,
    hi: f64,
    reason: &'static str,
) -> Result<(), CameraConfigError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(CameraConfigError::Invalid {
            field,
            value,
            reason,
        })
    }
}

/// Camera intrinsics as configured (docs/REFERENCES.md A2.6; docs/CAMERA.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Image width (columns), px.
    pub width_px: u32,
    /// Image height (rows), px.
    pub height_px: u32,
    /// Focal length, mm (not used with `calibration`: 0 when it came from a calibration file,
    /// which gives focal lengths in pixels only).
    pub focal_length_mm: f64,
    /// Pixel pitch, µm (not used with `calibration`; 0 when it came from a calibration file).
    pub pixel_pitch_um: f64,
    /// Calibrated intrinsics and lens: when set they replace the focal length, the pixel
    /// pitch and the centred principal point.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<Intrinsics>,
}

impl Default for CameraConfig {
    /// The authors' camera: 768 × 1024 px, 19 mm, 17 µm.
    fn default() -> Self {
        Self {
            width_px: 768,
            height_px: 1024,
            focal_length_mm: 19.0,
            pixel_pitch_um: 17.0,
            calibration: None,
        }
    }
}

/// Calibrated intrinsics in this project's pixel-centre convention (the same as OpenCV's and
/// ROS's: integer coordinates at pixel centres, so a calibration's cx, cy are used as they are).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Focal length along the columns, px.
    pub fx_px: f64,
    /// Focal length along the rows, px.
    pub fy_px: f64,
    /// Principal point, column, px.
    pub cx_px: f64,
    /// Principal point, row, px.
    pub cy_px: f64,
    /// Lens distortion on normalised coordinates.
    pub distortion: Distortion,
}

impl CameraConfig {
    /// Validate; errors name the key.
    pub fn validate(&self) -> Result<(), CameraConfigError> {
        check(
            "camera.width_px",
            f64::from(self.width_px),
            2.0,
            16_384.0,
            "must be 2 to 16384 px",
        )?;
        check(
            "camera.height_px",
            f64::from(self.height_px),
            2.0,
            16_384.0,
            "must be 2 to 16384 px",
        )?;
        let Some(k) = &self.calibration else {
            check(
                "camera.focal_length_mm",
                self.focal_length_mm,
                0.1,
                1000.0,
                "must be 0.1 to 1000 mm",
            )?;
            return check(
                "camera.pixel_pitch_um",
                self.pixel_pitch_um,
                0.1,
                1000.0,
                "must be 0.1 to 1000 µm",
            );
        };
        let f_range = "must be positive, at most 1e6 px";
        check("camera.calibration.fx_px", k.fx_px, 1e-3, 1e6, f_range)?;
        check("camera.calibration.fy_px", k.fy_px, 1e-3, 1e6, f_range)?;
        let (w, h) = (f64::from(self.width_px), f64::from(self.height_px));
        let inside = "must lie in the image (−0.5 to size − 0.5 px)";
        check("camera.calibration.cx_px", k.cx_px, -0.5, w - 0.5, inside)?;
        check("camera.calibration.cy_px", k.cy_px, -0.5, h - 0.5, inside)?;
        Lens::new(k.distortion)?;
        Ok(())
    }
}

/// The intrinsics keys of a `[camera]` table as written: the nominal pinhole's four keys, or
/// `calibration_file` (with `width_px` / `height_px` optional, checked against the file).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntrinsicsKeys {
    /// Image width (columns), px.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width_px: Option<u32>,
    /// Image height (rows), px.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height_px: Option<u32>,
    /// Focal length, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal_length_mm: Option<f64>,
    /// Pixel pitch, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_pitch_um: Option<f64>,
    /// OpenCV `FileStorage` YAML or XML, or ROS `camera_info` YAML, relative to the directory
    /// of the configuration file that names it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_file: Option<PathBuf>,
}

impl IntrinsicsKeys {
    /// No key given.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// The intrinsics these keys describe; a relative `calibration_file` is taken from
    /// `base_dir` (the directory of the file that names it; the working directory without).
    /// Errors name the key (and the calibration file's own key).
    pub fn resolve(&self, base_dir: Option<&Path>) -> Result<CameraConfig, CameraConfigError> {
        let Some(file) = &self.calibration_file else {
            let missing = |field: &'static str| CameraConfigError::Key {
                field,
                reason: "missing field (give the four of width_px, height_px, focal_length_mm \
                         and pixel_pitch_um, or calibration_file)"
                    .to_owned(),
            };
            let config = CameraConfig {
                width_px: self.width_px.ok_or_else(|| missing("camera.width_px"))?,
                height_px: self.height_px.ok_or_else(|| missing("camera.height_px"))?,
                focal_length_mm: self
                    .focal_length_mm
                    .ok_or_else(|| missing("camera.focal_length_mm"))?,
                pixel_pitch_um: self
                    .pixel_pitch_um
                    .ok_or_else(|| missing("camera.pixel_pitch_um"))?,
                calibration: None,
            };
            config.validate()?;
            return Ok(config);
        };
        let excluded = |field: &'static str| CameraConfigError::Key {
            field,
            reason: "not with camera.calibration_file, whose focal lengths are in pixels"
                .to_owned(),
        };
        if self.focal_length_mm.is_some() {
            return Err(excluded("camera.focal_length_mm"));
        }
        if self.pixel_pitch_um.is_some() {
            return Err(excluded("camera.pixel_pitch_um"));
        }
        let path = match base_dir {
            Some(dir) if file.is_relative() => dir.join(file),
            _ => file.clone(),
        };
        let cal = Calibration::from_file(&path).map_err(Box::new)?;
        for (field, given, actual) in [
            ("camera.width_px", self.width_px, cal.width_px),
            ("camera.height_px", self.height_px, cal.height_px),
        ] {
            if given.is_some_and(|g| g != actual) {
                return Err(CameraConfigError::Key {
                    field,
                    reason: format!(
                        "{} px, but the calibration {} is {} × {} px",
                        given.unwrap_or_default(),
                        path.display(),
                        cal.width_px,
                        cal.height_px
                    ),
                });
            }
        }
        Ok(cal.camera_config())
    }
}

/// Contents of `config/camera.toml`: intrinsics and mounting (each section optional).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSettings {
    /// Intrinsics.
    #[serde(default)]
    pub camera: CameraConfig,
    /// Mounting and its error model.
    #[serde(default)]
    pub mounting: MountingConfig,
}

/// `config/camera.toml` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSettings {
    #[serde(default)]
    camera: Option<IntrinsicsKeys>,
    #[serde(default)]
    mounting: Option<MountingConfig>,
}

impl CameraSettings {
    /// Parse and validate TOML text; errors name the key. A relative `camera.calibration_file`
    /// is taken from the working directory ([`CameraSettings::from_file`] takes it from the
    /// file's directory).
    pub fn from_toml_str(text: &str) -> Result<Self, CameraConfigError> {
        Self::from_toml_str_in(text, None)
    }

    /// Read and validate a file; a relative `camera.calibration_file` is taken from its
    /// directory.
    pub fn from_file(path: &Path) -> Result<Self, CameraConfigError> {
        let text = std::fs::read_to_string(path).map_err(|error| CameraConfigError::Read {
            path: path.to_owned(),
            error,
        })?;
        Self::from_toml_str_in(&text, path.parent())
    }

    /// Parse and validate TOML text, `base_dir` resolving a relative `calibration_file`.
    pub fn from_toml_str_in(
        text: &str,
        base_dir: Option<&Path>,
    ) -> Result<Self, CameraConfigError> {
        let raw: RawSettings = toml::from_str(text)?;
        let camera = match &raw.camera {
            Some(keys) => keys.resolve(base_dir)?,
            None => CameraConfig::default(),
        };
        let mounting = raw.mounting.unwrap_or_default();
        mounting.validate()?;
        Ok(Self { camera, mounting })
    }
}
