//! The calibration readers against the fixtures of `tests/data/calibration/` (one camera
//! written in each format must read to the same model) and against malformed files (each a
//! clear error naming the file and the key).

use std::path::{Path, PathBuf};

use super::*;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/calibration")
        .join(name)
}

fn read(name: &str) -> Calibration {
    Calibration::from_file(&fixture(name)).unwrap_or_else(|e| panic!("{e}"))
}

fn text(name: &str) -> String {
    std::fs::read_to_string(fixture(name)).unwrap()
}

/// The error for `text` read as a file named `name`.
fn error(text: &str, name: &str) -> String {
    match Calibration::parse(text, Path::new(name)) {
        Ok(c) => panic!("{name} accepted: {c:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn the_plumb_bob_camera_reads_the_same_in_every_format() {
    let yaml = read("plumb_bob_opencv.yaml");
    let xml = read("plumb_bob_opencv.xml");
    let ros = read("plumb_bob_ros.yaml");
    assert_eq!(yaml.format, CalibrationFormat::OpenCvYaml);
    assert_eq!(xml.format, CalibrationFormat::OpenCvXml);
    assert_eq!(ros.format, CalibrationFormat::RosCameraInfo);
    let expected = Intrinsics {
        fx_px: 1108.47,
        fy_px: 1106.92,
        cx_px: 641.23,
        cy_px: 478.86,
        distortion: Distortion::RadialTangential {
            k1: -0.2847,
            k2: 0.0913,
            p1: 0.00031,
            p2: -0.00017,
            k3: -0.0125,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        },
    };
    for c in [&yaml, &xml, &ros] {
        assert_eq!((c.width_px, c.height_px), (1280, 960), "{:?}", c.format);
        assert_eq!(c.intrinsics, expected, "{:?}", c.format);
    }
    assert_eq!(ros.camera_name.as_deref(), Some("down_looking"));
    assert_eq!(yaml.camera_name, None);
    // The camera it gives works on the whole image.
    let cam = Camera::from_config(&yaml.camera_config()).unwrap();
    assert_eq!((cam.fx_px(), cam.fy_px()), (1108.47, 1106.92));
}

#[test]
fn the_fisheye_camera_reads_the_same_in_every_format() {
    let expected = Intrinsics {
        fx_px: 481.3,
        fy_px: 480.8,
        cx_px: 511.7,
        cy_px: 383.2,
        distortion: Distortion::Fisheye {
            k1: -0.0134,
            k2: 0.0048,
            k3: -0.0021,
            k4: 0.0003,
        },
    };
    for name in [
        "fisheye_opencv.yaml",
        "fisheye_opencv.xml",
        "fisheye_ros.yaml",
    ] {
        let c = read(name);
        assert_eq!((c.width_px, c.height_px), (1024, 768), "{name}");
        assert_eq!(c.intrinsics, expected, "{name}");
    }
    let rational = read("rational_ros.yaml");
    assert!(matches!(
        rational.intrinsics.distortion,
        Distortion::RadialTangential { k4, .. } if k4 == 0.72
    ));
}

#[test]
fn opencv_yaml_quirks_are_handled() {
    let t = text("plumb_bob_opencv.yaml");
    // The header may be absent: the typed camera matrix still marks the file as OpenCV's.
    let c = Calibration::parse(t.trim_start_matches("%YAML:1.0\n"), Path::new("x.yaml")).unwrap();
    assert_eq!(c.format, CalibrationFormat::OpenCvYaml);
    // OpenCV files carry no model: 4 coefficients are k1, k2, p1, p2.
    let four = t.replace("cols: 5", "cols: 4").replace(
        "3.1000000000000000e-04, -1.7000000000000001e-04,\n       -1.2500000000000001e-02 ]",
        "3.1000000000000000e-04, -1.7000000000000001e-04 ]",
    );
    let c = Calibration::parse(&four, Path::new("four.yaml")).unwrap();
    assert!(matches!(
        c.intrinsics.distortion,
        Distortion::RadialTangential { k3, p2, .. } if k3 == 0.0 && p2 == -0.00017
    ));
    // All-zero coefficients: the pinhole.
    let zeros = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n\
                 camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   \
                 data: [ 500., 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]\n\
                 distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   \
                 data: [ 0., 0., 0., 0., 0. ]\n";
    let c = Calibration::parse(zeros, Path::new("zeros.yaml")).unwrap();
    let cam = Camera::from_config(&c.camera_config()).unwrap();
    assert!(cam.lens().is_pinhole());
    // 14 coefficients with the thin-prism and tilt terms zero are OpenCV's rational model.
    let fourteen = zeros.replace("cols: 5", "cols: 14").replace(
        "[ 0., 0., 0., 0., 0. ]",
        "[ -0.1, 0.01, 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0. ]",
    );
    assert!(Calibration::parse(&fourteen, Path::new("14.yaml")).is_ok());
    let prism = fourteen.replace("0., 0., 0., 0. ]", "0., 0.001, 0., 0. ]");
    let e = error(&prism, "prism.yaml");
    assert!(
        e.starts_with("prism.yaml: `distortion_coefficients`: thin-prism"),
        "{e}"
    );
}

/// Replace `from` (which must occur) in the fixture `name`.
fn edited(name: &str, from: &str, to: &str) -> String {
    let t = text(name);
    assert!(t.contains(from), "{from:?} not in {name}");
    t.replacen(from, to, 1)
}

#[test]
fn malformed_files_are_errors_naming_the_file_and_key() {
    let ros = "plumb_bob_ros.yaml";
    let cases: Vec<(String, &str, &str)> = vec![
        // (text, file name, expected start of the message after the file name)
        (
            edited(ros, "image_width: 1280\n", ""),
            "a.yaml",
            "`image_width` missing",
        ),
        (
            edited(ros, "image_height: 960", "image_height: 1"),
            "a.yaml",
            "`image_height`: 1: must be 2 to 16384",
        ),
        (
            edited(ros, "image_width: 1280", "image_width: wide"),
            "a.yaml",
            "`image_width`: must be an integer",
        ),
        (
            edited(ros, "camera_matrix:", "camera_matricks:"),
            "a.yaml",
            "`camera_matrix` or `K` missing",
        ),
        (
            edited(
                ros,
                "  data: [1108.47, 0, 641.23,",
                "  data: [.nan, 0, 641.23,",
            ),
            "a.yaml",
            "`camera_matrix`: element 0 is NaN: must be finite",
        ),
        (
            edited(ros, "[1108.47, 0, 641.23,", "[-1108.47, 0, 641.23,"),
            "a.yaml",
            "`camera_matrix`: focal lengths fx = -1108.47",
        ),
        (
            edited(ros, "[1108.47, 0, 641.23,", "[1108.47, 0.5, 641.23,"),
            "a.yaml",
            "`camera_matrix`: skew 0.5 is not supported",
        ),
        (
            edited(ros, "478.86, 0, 0, 1]", "478.86, 0, 0, 2]"),
            "a.yaml",
            "`camera_matrix`: must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]",
        ),
        (
            edited(ros, "478.86, 0, 0, 1]", "478.86, 0, 0]"),
            "a.yaml",
            "`camera_matrix`: data holds 8 numbers, rows × cols = 3 × 3",
        ),
        (
            edited(
                ros,
                "  rows: 3\n  cols: 3\n  data: [1108",
                "  rows: 2\n  cols: 3\n  data: [1108",
            )
            .replacen("478.86, 0, 0, 1]", "478.86]", 1),
            "a.yaml",
            "`camera_matrix`: must be 3 × 3, is 2 × 3",
        ),
        (
            edited(ros, "641.23, 0, 1106.92", "1641.23, 0, 1106.92"),
            "a.yaml",
            "`camera_matrix`: principal point (1641.23, 478.86) outside the 1280 × 960 px image",
        ),
        (
            edited(
                ros,
                "distortion_model: plumb_bob",
                "distortion_model: kannala",
            ),
            "a.yaml",
            "`distortion_model`: unknown model `kannala`",
        ),
        (
            edited(ros, "distortion_model: plumb_bob\n", ""),
            "a.yaml",
            "`distortion_model` missing",
        ),
        (
            edited(
                ros,
                "  cols: 5\n  data: [-0.2847, 0.0913, 0.00031, -0.00017, -0.0125]",
                "  cols: 6\n  data: [-0.2847, 0.0913, 0.00031, -0.00017, -0.0125, 0.0]",
            ),
            "a.yaml",
            "`distortion_coefficients`: 6 coefficients: plumb_bob takes 5",
        ),
        (
            edited(
                ros,
                "  cols: 5\n  data: [-0.2847, 0.0913, 0.00031, -0.00017, -0.0125]",
                "  cols: 3\n  data: [-0.2847, 0.0913, 0.00031]",
            ),
            "a.yaml",
            "`distortion_coefficients`: 3 coefficients: plumb_bob takes 5",
        ),
        (
            edited(
                "fisheye_ros.yaml",
                "  cols: 4\n  data: [-0.0134, 0.0048, -0.0021, 0.0003]",
                "  cols: 5\n  data: [-0.0134, 0.0048, -0.0021, 0.0003, 0.0]",
            ),
            "f.yaml",
            "`distortion_coefficients`: 5 coefficients: equidistant (fisheye) takes 4",
        ),
        (
            edited(
                ros,
                "  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]",
                "  data: [1, 0, 0, 0, 1, 0, 0, 0, .inf]",
            ),
            "a.yaml",
            "`rectification_matrix`: element 8 is inf",
        ),
        (
            edited(ros, "  rows: 3\n  cols: 4", "  rows: 4\n  cols: 3"),
            "a.yaml",
            "`projection_matrix`: must be 3 × 4, is 4 × 3",
        ),
        // A lens that folds inside the image (strong barrel, 1280 px at f = 1108 px).
        (
            edited(ros, "[-0.2847, 0.0913,", "[-0.9, 0.0913,"),
            "a.yaml",
            "`distortion_coefficients`: the lens model cannot be undistorted at pixel",
        ),
        (
            edited(
                "plumb_bob_opencv.yaml",
                "   dt: d\n   data: [ 1.108",
                "   dt: u\n   data: [ 1.108",
            ),
            "o.yaml",
            "`camera_matrix`: dt must be d or f",
        ),
        (
            "image_width: 1280\nimage_height: 960\ncamera_matrix: 3\n".to_owned(),
            "o.yaml",
            "`camera_matrix`: must be a matrix",
        ),
        (
            "image_width: [1280\n".to_owned(),
            "s.yaml",
            "not valid YAML",
        ),
        (
            "- 1\n- 2\n".to_owned(),
            "s.yaml",
            "the document is not a mapping",
        ),
        ("".to_owned(), "e.yaml", "empty file"),
        ("a: 1\n---\nb: 2\n".to_owned(), "m.yaml", "2 YAML documents"),
        (
            edited(
                "plumb_bob_opencv.xml",
                "<rows>3</rows>",
                "<rows>three</rows>",
            ),
            "o.xml",
            "`camera_matrix`: <rows> = three: must be 1 to 64",
        ),
        (
            edited(
                "plumb_bob_opencv.xml",
                "<camera_matrix type_id=\"opencv-matrix\">",
                "<camera_matrix>",
            ),
            "o.xml",
            "`camera_matrix`: must be an element with type_id=\"opencv-matrix\"",
        ),
        (
            edited(
                "plumb_bob_opencv.xml",
                "-1.2500000000000001e-02</data>",
                "-1.25e-02 x</data>",
            ),
            "o.xml",
            "`distortion_coefficients`: data element 5 (x) is not a number",
        ),
        (
            edited(
                "plumb_bob_opencv.xml",
                "<image_height>960</image_height>\n",
                "",
            ),
            "o.xml",
            "`image_height` missing",
        ),
        (
            "<opencv_storage><a></opencv_storage>".to_owned(),
            "x.xml",
            "not valid XML",
        ),
        (
            "<storage/>".to_owned(),
            "x.xml",
            "the root element is <storage>",
        ),
    ];
    for (text, name, expected) in cases {
        let e = error(&text, name);
        let want = format!("{name}: {expected}");
        assert!(e.starts_with(&want), "got  {e}\nwant {want}…");
    }
}

#[test]
fn unreadable_and_oversized_files_are_errors() {
    let e = Calibration::from_file(Path::new("/nonexistent/ianav-cam.yaml")).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("/nonexistent/ianav-cam.yaml: cannot read"),
        "{e}"
    );
    let dir = std::env::temp_dir().join(format!("ianav-calibration-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let big = dir.join("big.yaml");
    std::fs::write(&big, vec![b'#'; MAX_FILE_BYTES as usize + 1]).unwrap();
    let e = Calibration::from_file(&big).unwrap_err().to_string();
    assert!(e.contains("larger than"), "{e}");
    let latin1 = dir.join("latin1.yaml");
    std::fs::write(&latin1, b"camera_name: \xe9\n").unwrap();
    let e = Calibration::from_file(&latin1).unwrap_err().to_string();
    assert!(e.contains("not UTF-8"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
