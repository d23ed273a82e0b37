//! Camera calibration files (docs/CAMERA.md): OpenCV `FileStorage` YAML (`%YAML:1.0`,
//! `!!opencv-matrix`) and XML (`<opencv_storage>`, `type_id="opencv-matrix"`), and ROS
//! `camera_info` YAML, read into the image size, intrinsics and lens model of
//! [`crate::vision::camera`].
//!
//! What is read: `image_width`, `image_height`; the camera matrix (`camera_matrix` or `K`,
//! 3 × 3, no skew); the distortion coefficients (`distortion_coefficients` or `D`, a row or
//! column) and `distortion_model` (ROS: required; OpenCV: optional, `cv::calibrateCamera`'s
//! model without it). ROS's `rectification_matrix` and `projection_matrix` are checked for
//! shape and finiteness and otherwise not used: they describe the rectified image, and this
//! project works on the raw image with K and D. Other keys are ignored. Every refusal is a
//! [`CalibrationError`] naming the file and the key, never a panic.

mod xml;
mod yaml;

use std::io::Read as _;
use std::path::{Path, PathBuf};

use crate::vision::camera::{Camera, CameraConfig, CameraConfigError, Intrinsics};
use crate::vision::lens::Distortion;

/// Largest calibration file read, bytes (real ones are a few kB).
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// The file formats read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CalibrationFormat {
    /// OpenCV `FileStorage` YAML (first line `%YAML:1.0`).
    OpenCvYaml,
    /// OpenCV `FileStorage` XML (root `<opencv_storage>`).
    OpenCvXml,
    /// ROS `camera_info` YAML (`camera_calibration_parsers`).
    RosCameraInfo,
}

/// A camera calibration: image size, intrinsics and lens.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Image width (columns) the calibration is for, px.
    pub width_px: u32,
    /// Image height (rows), px.
    pub height_px: u32,
    /// Focal lengths, principal point (pixel-centre convention, as in the file) and lens.
    pub intrinsics: Intrinsics,
    /// `camera_name` (ROS), if given.
    pub camera_name: Option<String>,
    /// The file's format.
    pub format: CalibrationFormat,
}

/// A calibration file refused: the file and what is wrong, naming the key.
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", path.display())]
pub struct CalibrationError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub kind: CalibrationErrorKind,
}

/// What is wrong with a calibration file.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationErrorKind {
    /// The file could not be read.
    #[error("cannot read: {0}")]
    Read(std::io::Error),
    /// Larger than [`MAX_FILE_BYTES`].
    #[error("larger than {MAX_FILE_BYTES} bytes: not a calibration file")]
    TooLarge,
    /// Not YAML (or not UTF-8).
    #[error("not valid YAML: {0}")]
    Yaml(String),
    /// Not XML.
    #[error("not valid XML: {0}")]
    Xml(String),
    /// Parsed, but not one of the formats read.
    #[error("{0}")]
    Format(String),
    /// A required key is absent.
    #[error("`{key}` missing")]
    Missing {
        /// The key (or its alternatives).
        key: String,
    },
    /// A key's value is refused.
    #[error("`{key}`: {reason}")]
    Invalid {
        /// The key.
        key: String,
        /// Why.
        reason: String,
    },
}

fn invalid(key: &str, reason: impl Into<String>) -> CalibrationErrorKind {
    CalibrationErrorKind::Invalid {
        key: key.to_owned(),
        reason: reason.into(),
    }
}

/// A matrix as stored: `rows × cols`, row-major.
#[derive(Debug, Clone, PartialEq)]
struct Matrix {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

impl Matrix {
    fn at(&self, r: usize, c: usize) -> f64 {
        self.data[r * self.cols + c]
    }

    /// Check the size and that every element is finite.
    fn checked(self, key: &str, rows: usize, cols: usize) -> Result<Self, CalibrationErrorKind> {
        if (self.rows, self.cols) != (rows, cols) {
            return Err(invalid(
                key,
                format!("must be {rows} × {cols}, is {} × {}", self.rows, self.cols),
            ));
        }
        self.finite(key)
    }

    fn finite(self, key: &str) -> Result<Self, CalibrationErrorKind> {
        match self.data.iter().position(|v| !v.is_finite()) {
            Some(i) => Err(invalid(
                key,
                format!("element {i} is {}: must be finite", self.data[i]),
            )),
            None => Ok(self),
        }
    }
}

/// Read access to the top-level keys of a parsed file, whatever its syntax.
trait Source {
    /// Whether the key is present.
    fn has(&self, key: &str) -> bool;
    /// An integer, `None` if absent.
    fn integer(&self, key: &str) -> Result<Option<i64>, CalibrationErrorKind>;
    /// A string, `None` if absent.
    fn text(&self, key: &str) -> Result<Option<String>, CalibrationErrorKind>;
    /// A matrix, `None` if absent.
    fn matrix(&self, key: &str) -> Result<Option<Matrix>, CalibrationErrorKind>;
}

/// The first of `keys` present, if any.
fn first_of<'k>(source: &dyn Source, keys: &[&'k str]) -> Option<&'k str> {
    keys.iter().copied().find(|k| source.has(k))
}

fn required_matrix(
    source: &dyn Source,
    keys: &[&str],
) -> Result<(String, Matrix), CalibrationErrorKind> {
    let missing = || CalibrationErrorKind::Missing {
        key: keys.join("` or `"),
    };
    let key = first_of(source, keys).ok_or_else(missing)?;
    let m = source.matrix(key)?.ok_or_else(missing)?;
    Ok((key.to_owned(), m))
}

fn image_side(source: &dyn Source, key: &str) -> Result<u32, CalibrationErrorKind> {
    let v = source
        .integer(key)?
        .ok_or_else(|| CalibrationErrorKind::Missing {
            key: key.to_owned(),
        })?;
    u32::try_from(v)
        .ok()
        .filter(|v| (2..=16_384).contains(v))
        .ok_or_else(|| invalid(key, format!("{v}: must be 2 to 16384 px")))
}

/// The distortion model named by `model` (or implied by the coefficient count without one)
/// from the coefficients `d`, in OpenCV's order.
fn distortion(
    key: &str,
    model: Option<&str>,
    d: &[f64],
) -> Result<Distortion, CalibrationErrorKind> {
    let n = d.len();
    let count = |what: &str| invalid(key, format!("{n} coefficients: {what}"));
    let radial_tangential = |d: &[f64]| {
        let c = |i: usize| d.get(i).copied().unwrap_or(0.0);
        Distortion::RadialTangential {
            k1: c(0),
            k2: c(1),
            p1: c(2),
            p2: c(3),
            k3: c(4),
            k4: c(5),
            k5: c(6),
            k6: c(7),
        }
    };
    match model {
        Some("plumb_bob" | "radtan" | "radial_tangential") => match n {
            4 | 5 => Ok(radial_tangential(d)),
            _ => Err(count(
                "plumb_bob takes 5 (k1, k2, p1, p2, k3) or 4 (k3 = 0)",
            )),
        },
        Some("rational_polynomial") => match n {
            8 => Ok(radial_tangential(d)),
            _ => Err(count(
                "rational_polynomial takes 8 (k1, k2, p1, p2, k3, k4, k5, k6)",
            )),
        },
        Some("equidistant" | "fisheye") => match d {
            &[k1, k2, k3, k4] => Ok(Distortion::Fisheye { k1, k2, k3, k4 }),
            _ => Err(count("equidistant (fisheye) takes 4 (k1, k2, k3, k4)")),
        },
        Some(other) => Err(invalid(
            "distortion_model",
            format!(
                "unknown model `{other}`: plumb_bob, rational_polynomial and equidistant \
                 (or fisheye) are read"
            ),
        )),
        // cv::calibrateCamera's vector: 4, 5, 8, 12 (thin prism) or 14 (tilted sensor).
        None => match n {
            4 | 5 | 8 => Ok(radial_tangential(d)),
            12 | 14 if d[8..].iter().all(|c| *c == 0.0) => Ok(radial_tangential(d)),
            12 | 14 => Err(invalid(
                key,
                "thin-prism (s1–s4) and tilted-sensor (τx, τy) terms are not supported: \
                 recalibrate without CALIB_THIN_PRISM_MODEL / CALIB_TILTED_MODEL",
            )),
            _ => Err(count("OpenCV's model takes 4, 5, 8, 12 or 14")),
        },
    }
}

/// Assemble and check a calibration from a parsed file.
fn assemble(
    source: &dyn Source,
    format: CalibrationFormat,
) -> Result<Calibration, CalibrationErrorKind> {
    let width_px = image_side(source, "image_width")?;
    let height_px = image_side(source, "image_height")?;
    let (k_key, k) = required_matrix(source, &["camera_matrix", "K"])?;
    let k = k.checked(&k_key, 3, 3)?;
    let (fx, skew, cx, fy, cy) = (k.at(0, 0), k.at(0, 1), k.at(0, 2), k.at(1, 1), k.at(1, 2));
    if [k.at(1, 0), k.at(2, 0), k.at(2, 1)] != [0.0; 3] || k.at(2, 2) != 1.0 {
        return Err(invalid(
            &k_key,
            "must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]",
        ));
    }
    if !(fx > 0.0 && fy > 0.0) {
        return Err(invalid(
            &k_key,
            format!("focal lengths fx = {fx}, fy = {fy}: must be positive"),
        ));
    }
    if skew != 0.0 {
        return Err(invalid(
            &k_key,
            format!(
                "skew {skew} is not supported: calibrate with zero skew (OpenCV's and ROS's \
                 default)"
            ),
        ));
    }
    let inside = |c: f64, size: u32| (-0.5..=f64::from(size) - 0.5).contains(&c);
    if !(inside(cx, width_px) && inside(cy, height_px)) {
        return Err(invalid(
            &k_key,
            format!("principal point ({cx}, {cy}) outside the {width_px} × {height_px} px image"),
        ));
    }
    let (d_key, d) = required_matrix(source, &["distortion_coefficients", "D"])?;
    let d = d.finite(&d_key)?;
    if d.rows != 1 && d.cols != 1 {
        return Err(invalid(
            &d_key,
            format!("must be a row or a column, is {} × {}", d.rows, d.cols),
        ));
    }
    let model = source.text("distortion_model")?;
    if format == CalibrationFormat::RosCameraInfo && model.is_none() {
        return Err(CalibrationErrorKind::Missing {
            key: "distortion_model".to_owned(),
        });
    }
    let distortion = distortion(&d_key, model.as_deref(), &d.data)?;
    for (key, rows, cols) in [("rectification_matrix", 3, 3), ("projection_matrix", 3, 4)] {
        if let Some(m) = source.matrix(key)? {
            m.checked(key, rows, cols)?;
        }
    }
    let calibration = Calibration {
        width_px,
        height_px,
        intrinsics: Intrinsics {
            fx_px: fx,
            fy_px: fy,
            cx_px: cx,
            cy_px: cy,
            distortion,
        },
        camera_name: source.text("camera_name")?,
        format,
    };
    // The camera's own checks: focal range, principal point in the image, a lens that
    // inverts over the whole image.
    Camera::from_config(&calibration.camera_config()).map_err(|e| match e {
        CameraConfigError::Lens { u_px, v_px, reason } => invalid(
            &d_key,
            format!(
                "the lens model cannot be undistorted at pixel ({u_px}, {v_px}) of the \
                 {width_px} × {height_px} px image ({reason}): it folds inside the field"
            ),
        ),
        CameraConfigError::Distortion(e) => invalid(&d_key, e.to_string()),
        e => invalid(&k_key, e.to_string()),
    })?;
    Ok(calibration)
}

impl Calibration {
    /// Read a calibration file, its format told by its content: XML if it starts with `<`,
    /// OpenCV YAML if with `%YAML`, otherwise ROS `camera_info` YAML.
    pub fn from_file(path: &Path) -> Result<Self, CalibrationError> {
        let error = |kind| CalibrationError {
            path: path.to_owned(),
            kind,
        };
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_FILE_BYTES + 1).read_to_end(&mut bytes))
            .map_err(|e| error(CalibrationErrorKind::Read(e)))?;
        if bytes.len() as u64 > MAX_FILE_BYTES {
            return Err(error(CalibrationErrorKind::TooLarge));
        }
        let text = String::from_utf8(bytes)
            .map_err(|e| error(CalibrationErrorKind::Yaml(format!("not UTF-8: {e}"))))?;
        Self::parse(&text, path)
    }

    /// Parse a calibration's text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, CalibrationError> {
        let error = |kind| CalibrationError {
            path: path.to_owned(),
            kind,
        };
        let body = text.trim_start_matches('\u{feff}').trim_start();
        let result = if body.starts_with('<') {
            xml::parse(body)
        } else {
            yaml::parse(body)
        };
        result.map_err(error)
    }

    /// The camera configuration of this calibration (focal length and pixel pitch 0: a
    /// calibration gives focal lengths in pixels only).
    pub fn camera_config(&self) -> CameraConfig {
        CameraConfig {
            width_px: self.width_px,
            height_px: self.height_px,
            focal_length_mm: 0.0,
            pixel_pitch_um: 0.0,
            calibration: Some(self.intrinsics),
        }
    }
}

#[cfg(test)]
mod tests;
