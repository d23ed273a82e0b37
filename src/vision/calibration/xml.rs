//! OpenCV `FileStorage` XML calibrations through `roxmltree`: the root `<opencv_storage>`, one
//! child element per key; a matrix is an element with `type_id="opencv-matrix"` holding
//! `<rows>`, `<cols>`, `<dt>` and `<data>` (numbers separated by white space). OpenCV quotes
//! some strings (`"plumb_bob"`): the quotes are removed. Document type declarations (and so
//! entity expansion) are refused by the parser.

use super::{CalibrationErrorKind, CalibrationFormat, Matrix, Source, assemble, invalid};
use crate::vision::calibration::Calibration;

/// Parse an XML calibration (leading whitespace removed).
pub(super) fn parse(text: &str) -> Result<Calibration, CalibrationErrorKind> {
    let doc =
        roxmltree::Document::parse(text).map_err(|e| CalibrationErrorKind::Xml(e.to_string()))?;
    let root = doc.root_element();
    if root.tag_name().name() != "opencv_storage" {
        return Err(CalibrationErrorKind::Format(format!(
            "the root element is <{}>: an OpenCV FileStorage file's is <opencv_storage>",
            root.tag_name().name()
        )));
    }
    assemble(&XmlSource { root }, CalibrationFormat::OpenCvXml)
}

struct XmlSource<'a, 'i> {
    root: roxmltree::Node<'a, 'i>,
}

/// The child element `name` of `node`.
fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, name: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children()
        .find(|c| c.is_element() && c.tag_name().name() == name)
}

/// The text of an element, trimmed, without OpenCV's quotes.
fn text_of(node: roxmltree::Node<'_, '_>) -> String {
    let t = node.text().unwrap_or_default().trim();
    t.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .unwrap_or(t)
        .to_owned()
}

impl Source for XmlSource<'_, '_> {
    fn has(&self, key: &str) -> bool {
        child(self.root, key).is_some()
    }

    fn integer(&self, key: &str) -> Result<Option<i64>, CalibrationErrorKind> {
        child(self.root, key)
            .map(|n| {
                text_of(n)
                    .parse::<i64>()
                    .map_err(|_| invalid(key, "must be an integer"))
            })
            .transpose()
    }

    fn text(&self, key: &str) -> Result<Option<String>, CalibrationErrorKind> {
        Ok(child(self.root, key).map(text_of))
    }

    fn matrix(&self, key: &str) -> Result<Option<Matrix>, CalibrationErrorKind> {
        let Some(node) = child(self.root, key) else {
            return Ok(None);
        };
        if node.attribute("type_id") != Some("opencv-matrix") {
            return Err(invalid(
                key,
                "must be an element with type_id=\"opencv-matrix\"",
            ));
        }
        let field = |name: &str| {
            child(node, name)
                .map(text_of)
                .ok_or_else(|| invalid(key, format!("<{name}> missing")))
        };
        let size = |name: &str| {
            let t = field(name)?;
            t.parse::<usize>()
                .ok()
                .filter(|v| (1..=64).contains(v))
                .ok_or_else(|| invalid(key, format!("<{name}> = {t}: must be 1 to 64")))
        };
        let (rows, cols) = (size("rows")?, size("cols")?);
        let dt = field("dt")?;
        if dt != "d" && dt != "f" {
            return Err(invalid(
                key,
                format!("<dt> = {dt}: must be d or f (a matrix of floating-point numbers)"),
            ));
        }
        let data = field("data")?
            .split_whitespace()
            .enumerate()
            .map(|(i, v)| {
                v.parse::<f64>()
                    .map_err(|_| invalid(key, format!("data element {i} ({v}) is not a number")))
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
