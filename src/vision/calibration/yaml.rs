//! The YAML calibration formats: OpenCV `FileStorage` YAML and ROS `camera_info`, through the
//! `saphyr` YAML 1.2 loader.
//!
//! A file is OpenCV's if its first line is OpenCV's header or its camera matrix gives an
//! element type (`dt`), ROS's otherwise. OpenCV's files are not plain YAML 1.2, and are
//! handled as follows:
//! - the first line `%YAML:1.0` is not a valid YAML directive (YAML writes `%YAML 1.2`): it
//!   marks the file as OpenCV's and is removed before parsing (the `---` that follows it
//!   starts the document as usual);
//! - `!!opencv-matrix` is a tag in YAML's core-schema namespace that no schema defines; the
//!   loader drops tags of that namespace on mappings, so a matrix is recognised by its keys
//!   (`rows`, `cols`, `dt`, `data`), `dt` must be `d` or `f`, and `data` must hold
//!   `rows × cols` numbers. A node with another, application tag (`!name`) is read through
//!   the tag.

use saphyr::{LoadableYamlNode, Scalar, Yaml};

use super::{CalibrationErrorKind, CalibrationFormat, Matrix, Source, assemble, invalid};
use crate::vision::calibration::Calibration;

/// Parse a YAML calibration (leading whitespace removed).
pub(super) fn parse(text: &str) -> Result<Calibration, CalibrationErrorKind> {
    // OpenCV's header, `%YAML:1.0` (any version), on the first line.
    let first = text.lines().next().unwrap_or_default().trim_end();
    let opencv_header = first.starts_with("%YAML:");
    let body = if opencv_header {
        &text[first.len()..]
    } else {
        text
    };
    let docs = Yaml::load_from_str(body).map_err(|e| CalibrationErrorKind::Yaml(e.to_string()))?;
    let root = match docs.as_slice() {
        [doc] => untag(doc),
        [] => return Err(CalibrationErrorKind::Format("empty file".to_owned())),
        _ => {
            return Err(CalibrationErrorKind::Format(format!(
                "{} YAML documents: a calibration is one",
                docs.len()
            )));
        }
    };
    if !matches!(root, Yaml::Mapping(_)) {
        return Err(CalibrationErrorKind::Format(
            "the document is not a mapping of keys".to_owned(),
        ));
    }
    // Without OpenCV's header, a camera matrix with an element type is OpenCV's too.
    let typed_matrix = ["camera_matrix", "K"]
        .iter()
        .filter_map(|k| root.as_mapping_get(k))
        .any(|m| untag(m).contains_mapping_key("dt"));
    let format = if opencv_header || typed_matrix {
        CalibrationFormat::OpenCvYaml
    } else {
        CalibrationFormat::RosCameraInfo
    };
    assemble(&YamlSource { root, format }, format)
}

fn untag<'a, 'i>(node: &'a Yaml<'i>) -> &'a Yaml<'i> {
    match node {
        Yaml::Tagged(_, inner) => untag(inner),
        other => other,
    }
}

fn number(node: &Yaml<'_>) -> Option<f64> {
    match untag(node) {
        Yaml::Value(Scalar::FloatingPoint(v)) => Some(v.into_inner()),
        // Exact for every integer a calibration holds (|v| < 2^53).
        Yaml::Value(Scalar::Integer(v)) => Some(*v as f64),
        _ => None,
    }
}

struct YamlSource<'a, 'i> {
    root: &'a Yaml<'i>,
    format: CalibrationFormat,
}

impl YamlSource<'_, '_> {
    fn get(&self, key: &str) -> Option<&Yaml<'_>> {
        self.root.as_mapping_get(key).map(untag)
    }
}

impl Source for YamlSource<'_, '_> {
    fn has(&self, key: &str) -> bool {
        self.get(key).is_some()
    }

    fn integer(&self, key: &str) -> Result<Option<i64>, CalibrationErrorKind> {
        match self.get(key) {
            None => Ok(None),
            Some(Yaml::Value(Scalar::Integer(v))) => Ok(Some(*v)),
            Some(_) => Err(invalid(key, "must be an integer")),
        }
    }

    fn text(&self, key: &str) -> Result<Option<String>, CalibrationErrorKind> {
        match self.get(key) {
            None => Ok(None),
            Some(Yaml::Value(Scalar::String(s))) => Ok(Some(s.to_string())),
            Some(_) => Err(invalid(key, "must be a string")),
        }
    }

    fn matrix(&self, key: &str) -> Result<Option<Matrix>, CalibrationErrorKind> {
        let Some(node) = self.get(key) else {
            return Ok(None);
        };
        if !matches!(node, Yaml::Mapping(_)) {
            return Err(invalid(
                key,
                "must be a matrix (a mapping of rows, cols and data)",
            ));
        }
        let field = |name: &str| node.as_mapping_get(name).map(untag);
        let size = |name: &str| match field(name) {
            Some(Yaml::Value(Scalar::Integer(v))) => usize::try_from(*v)
                .ok()
                .filter(|v| (1..=64).contains(v))
                .ok_or_else(|| invalid(key, format!("{name} = {v}: must be 1 to 64"))),
            Some(_) => Err(invalid(key, format!("{name} must be an integer"))),
            None => Err(invalid(key, format!("{name} missing"))),
        };
        let (rows, cols) = (size("rows")?, size("cols")?);
        match (self.format, field("dt")) {
            (_, Some(Yaml::Value(Scalar::String(dt)))) if dt == "d" || dt == "f" => {}
            (_, Some(_)) => {
                return Err(invalid(
                    key,
                    "dt must be d or f (a matrix of floating-point numbers)",
                ));
            }
            (CalibrationFormat::OpenCvYaml, None) => {
                return Err(invalid(key, "dt missing (an OpenCV matrix gives its type)"));
            }
            (_, None) => {}
        }
        let Some(Yaml::Sequence(seq)) = field("data") else {
            return Err(invalid(key, "data must be a sequence of numbers"));
        };
        let data = seq
            .iter()
            .enumerate()
            .map(|(i, v)| {
                number(v).ok_or_else(|| invalid(key, format!("data element {i} is not a number")))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        if data.len() != rows * cols {
            return Err(invalid(
                key,
                format!(
                    "data holds {} numbers, rows × cols = {rows} × {cols}",
                    data.len()
                ),
            ));
        }
        Ok(Some(Matrix { rows, cols, data }))
    }
}
