//! Tests of the camera: the pinhole's numbers, the lens models' round trips and Jacobians, the
//! pinhole kept bit for bit, configuration keys.

use super::*;
use crate::math::{se3, so3};
use nalgebra::{Translation3, Vector6};

use crate::vision::lens::{Distortion, UndistortError};

#[test]
fn paper_camera_numbers() {
    let cam = Camera::paper();
    assert_eq!((cam.width_px(), cam.height_px()), (768, 1024));
    // 19 mm / 17 µm.
    assert!((cam.f_px() - 19.0e-3 / 17.0e-6).abs() < 1e-9);
    assert!((cam.f_px() - 1117.647).abs() < 1e-3);
    assert_eq!(cam.principal_point_px(), Vector2::new(383.5, 511.5));
    // docs/REFERENCES.md A2.6: vfov 49.2255°, hfov 37.9°.
    assert!((cam.vertical_fov_rad().to_degrees() - 49.2255).abs() < 1e-3);
    assert!((cam.horizontal_fov_rad().to_degrees() - 37.9).abs() < 0.05);
}

#[test]
fn projection_round_trip() {
    let cam = Camera::paper();
    for (u, v) in [(0.0, 0.0), (383.5, 511.5), (767.0, 1023.0), (12.3, 900.7)] {
        let px = Vector2::new(u, v);
        for z in [1.0, 250.0, 3000.0] {
            let p = cam.back_project_depth(&px, z);
            let back = cam.project(&p).unwrap();
            assert!((back - px).norm() < 1e-9, "{px} -> {back}");
            // Unit bearing projects to the same pixel.
            let b = cam.back_project(&px);
            assert!((b.norm() - 1.0).abs() < 1e-12);
            assert!((cam.project(&(b * 7.0)).unwrap() - px).norm() < 1e-9);
        }
    }
    assert!(cam.project(&Vector3::new(1.0, 2.0, -3.0)).is_none());
    assert!(cam.project(&Vector3::new(f64::NAN, 2.0, 3.0)).is_none());
    // The optical axis hits the principal point; a point right and down of it projects
    // right and down (x along columns, y along rows).
    assert_eq!(
        cam.project(&Vector3::new(0.0, 0.0, 5.0)).unwrap(),
        cam.principal_point_px()
    );
    let p = cam.project(&Vector3::new(1.0, 1.0, 10.0)).unwrap();
    assert!(p.x > 383.5 && p.y > 511.5);
}

#[test]
fn optical_flow_jacobian_matches_finite_differences() {
    let cam = Camera::paper();
    let zeta_ec = Isometry3::from_parts(
        Translation3::new(4.1e6, -3.2e5, 4.8e6),
        so3::exp(&Vector3::new(0.4, -1.1, 2.0)),
    );
    for p_c in [
        Vector3::new(0.0, 0.0, 2700.0),
        Vector3::new(-800.0, 1100.0, 2500.0),
        Vector3::new(300.0, -40.0, 60.0),
    ] {
        let p_e = zeta_ec.transform_point(&p_c.into()).coords;
        let j = cam.optical_flow_jacobian(&p_c);
        let base = cam.project_ecef(&zeta_ec, &p_e).unwrap();
        for k in 0..6 {
            // Central differences; steps small against depth, large against rounding.
            let h = if k < 3 { 1e-3 } else { 1e-7 };
            let mut tau = Vector6::zeros();
            tau[k] = h;
            let plus = cam.project_ecef(&se3::plus(&zeta_ec, &tau), &p_e).unwrap();
            let minus = cam.project_ecef(&se3::plus(&zeta_ec, &-tau), &p_e).unwrap();
            let fd = (plus - minus) / (2.0 * h);
            let scale = j.column(k).norm().max(1e-3);
            assert!(
                (fd - j.column(k)).norm() < 1e-5 * scale + 1e-5,
                "column {k} at {p_c}: fd {fd} vs {}",
                j.column(k)
            );
            assert!((plus - base).norm() > 0.0 || j.column(k).norm() < 1e-9);
        }
        // Chain rule form: ∂Π/∂p · [−I, [p]×].
        let chain = cam.projection_jacobian(&p_c) * point_jacobian(&p_c);
        assert!((chain - j).norm() < 1e-9 * j.norm());
    }
}

#[test]
fn pyramid_levels_keep_the_geometry() {
    let cam = Camera::paper();
    let l2 = cam.level(2);
    assert_eq!((l2.width_px(), l2.height_px()), (192, 256));
    assert!((l2.f_px() - cam.f_px() / 4.0).abs() < 1e-12);
    assert_eq!(l2.principal_point_px(), Vector2::new(95.5, 127.5));
    // A point projects at corresponding coordinates on every level.
    let p = Vector3::new(-310.0, 520.0, 2600.0);
    let px0 = cam.project(&p).unwrap();
    for level in 0..5 {
        let cl = cam.level(level);
        let pxl = cl.project(&p).unwrap();
        assert!((Camera::level_to_base(&pxl, level) - px0).norm() < 1e-9);
        assert!((Camera::base_to_level(&px0, level) - pxl).norm() < 1e-9);
    }
    // Level-1 pixel 0 is the average of level-0 pixels 0 and 1: centre 0.5.
    assert!((Camera::level_to_base(&Vector2::new(0.0, 0.0), 1).x - 0.5).abs() < 1e-12);
}

#[test]
fn the_documented_configuration_file_holds_the_defaults() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/camera.toml"))
        .unwrap();
    assert_eq!(
        CameraSettings::from_toml_str(&text).unwrap(),
        CameraSettings::default()
    );
    let err = CameraSettings::from_toml_str("[camera]\nwidth_px = 768\n").unwrap_err();
    assert!(err.to_string().contains("missing field"), "{err}");
    let err = CameraSettings::from_toml_str("[mounting]\nbogus = 1\n").unwrap_err();
    assert!(err.to_string().contains("bogus"), "{err}");
}

#[test]
fn bad_configurations_name_the_key() {
    let cfg = CameraConfig {
        focal_length_mm: f64::NAN,
        ..CameraConfig::default()
    };
    let err = Camera::from_config(&cfg).unwrap_err().to_string();
    assert!(err.contains("focal_length_mm"), "{err}");
    let m = MountingConfig {
        angle_true_sigma_deg: -1.0,
        ..MountingConfig::default()
    };
    assert!(
        m.validate()
            .unwrap_err()
            .to_string()
            .contains("angle_true_sigma_deg")
    );
}

// ---- Lens models ----

fn calibrated(width_px: u32, height_px: u32, k: Intrinsics) -> Camera {
    Camera::from_config(&CameraConfig {
        width_px,
        height_px,
        focal_length_mm: 0.0,
        pixel_pitch_um: 0.0,
        calibration: Some(k),
    })
    .unwrap_or_else(|e| panic!("{e}"))
}

/// The fixtures' cameras (tests/data/calibration): plumb_bob and rational 1280 × 960,
/// fisheye 1024 × 768, and a pinhole with fx ≠ fy and an off-centre principal point.
fn real_cameras() -> Vec<(&'static str, Camera)> {
    let rt = |k: [f64; 8]| Distortion::RadialTangential {
        k1: k[0],
        k2: k[1],
        p1: k[2],
        p2: k[3],
        k3: k[4],
        k4: k[5],
        k5: k[6],
        k6: k[7],
    };
    let intr = |fx_px, fy_px, cx_px, cy_px, distortion| Intrinsics {
        fx_px,
        fy_px,
        cx_px,
        cy_px,
        distortion,
    };
    vec![
        (
            "plumb_bob",
            calibrated(
                1280,
                960,
                intr(
                    1108.47,
                    1106.92,
                    641.23,
                    478.86,
                    rt([-0.2847, 0.0913, 0.00031, -0.00017, -0.0125, 0.0, 0.0, 0.0]),
                ),
            ),
        ),
        (
            "rational",
            calibrated(
                1280,
                960,
                intr(
                    905.8,
                    905.2,
                    639.1,
                    481.4,
                    rt([0.41, -0.12, -0.0002, 0.0004, 0.02, 0.72, -0.05, 0.01]),
                ),
            ),
        ),
        (
            "fisheye",
            calibrated(
                1024,
                768,
                intr(
                    481.3,
                    480.8,
                    511.7,
                    383.2,
                    Distortion::Fisheye {
                        k1: -0.0134,
                        k2: 0.0048,
                        k3: -0.0021,
                        k4: 0.0003,
                    },
                ),
            ),
        ),
        (
            "pinhole fx ≠ fy",
            calibrated(
                640,
                480,
                intr(612.0, 598.5, 330.25, 228.75, Distortion::None),
            ),
        ),
    ]
}

/// Pixels every `step` px over the whole image, its edges and corners included.
fn image_grid(cam: &Camera, step: f64) -> Vec<Vector2<f64>> {
    let along = |size: u32| {
        let last = f64::from(size) - 0.5;
        let n = ((last + 0.5) / step).ceil() as u32;
        (0..=n).map(move |i| (-0.5 + step * f64::from(i)).min(last))
    };
    along(cam.width_px())
        .flat_map(|u| along(cam.height_px()).map(move |v| Vector2::new(u, v)))
        .collect()
}

fn angle(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.normalize().cross(&b.normalize()).norm().asin()
}

#[test]
fn project_and_unproject_round_trip_over_the_whole_image() {
    for (name, cam) in real_cameras() {
        let mut worst_rad = 0.0_f64;
        let mut worst_px = 0.0_f64;
        for px in image_grid(&cam, 8.0) {
            // The bearing of the pixel, projected at several ranges and unprojected again.
            let ray = cam
                .try_ray(&px)
                .unwrap_or_else(|e| panic!("{name} {px}: {e}"));
            for range_m in [0.7, 350.0, 4000.0] {
                let p_c = ray.normalize() * range_m;
                let back = cam.project(&p_c).unwrap();
                worst_px = worst_px.max((back - px).norm());
                worst_rad = worst_rad.max(angle(&cam.ray(&back), &p_c));
            }
            assert!((cam.back_project(&px).norm() - 1.0).abs() < 1e-12);
        }
        assert!(worst_rad < 1e-9, "{name}: {worst_rad} rad");
        assert!(worst_px < 1e-6, "{name}: {worst_px} px");
    }
}

#[test]
fn projection_jacobians_match_central_differences() {
    for (name, cam) in real_cameras() {
        let (w, h) = (f64::from(cam.width_px()), f64::from(cam.height_px()));
        for (u, v) in [
            (0.5, 0.5),
            (0.03, 0.97),
            (0.5, 0.01),
            (0.99, 0.6),
            (0.2, 0.3),
        ] {
            let px = Vector2::new(u * w - 0.5, v * h - 0.5);
            for range_m in [40.0, 2500.0] {
                let p_c = cam.back_project(&px) * range_m;
                let j = cam.projection_jacobian(&p_c);
                for k in 0..3 {
                    let mut dp = Vector3::zeros();
                    dp[k] = 1e-4 * range_m;
                    let fd = (cam.project(&(p_c + dp)).unwrap()
                        - cam.project(&(p_c - dp)).unwrap())
                        / (2.0 * dp[k]);
                    let scale = j.column(k).norm().max(1e-3);
                    assert!(
                        (fd - j.column(k)).norm() < 1e-6 * scale,
                        "{name} at {px}, column {k}: fd {fd} vs {}",
                        j.column(k)
                    );
                }
                // J_OF: the chain rule through the camera-frame point, and finite
                // differences of the pose perturbation.
                let jof = cam.optical_flow_jacobian(&p_c);
                let chain = j * point_jacobian(&p_c);
                assert!((chain - jof).norm() < 1e-9 * jof.norm(), "{name}");
                let zeta_ec = Isometry3::from_parts(
                    Translation3::new(4.1e6, -3.2e5, 4.8e6),
                    so3::exp(&Vector3::new(0.4, -1.1, 2.0)),
                );
                let p_e = zeta_ec.transform_point(&p_c.into()).coords;
                for k in 0..6 {
                    let step = if k < 3 { 1e-4 * range_m } else { 1e-7 };
                    let mut tau = Vector6::zeros();
                    tau[k] = step;
                    let plus = cam.project_ecef(&se3::plus(&zeta_ec, &tau), &p_e).unwrap();
                    let minus = cam.project_ecef(&se3::plus(&zeta_ec, &-tau), &p_e).unwrap();
                    let fd = (plus - minus) / (2.0 * step);
                    // The ECEF coordinates' rounding (1e-9 m) bounds the differences' precision.
                    let scale = jof.column(k).norm().max(1e-3);
                    assert!(
                        (fd - jof.column(k)).norm() < 1e-5 * scale + 1e-5,
                        "{name} J_OF column {k}: fd {fd} vs {}",
                        jof.column(k)
                    );
                }
            }
        }
    }
}

#[test]
fn pyramid_levels_keep_the_lens() {
    for (name, cam) in real_cameras() {
        for level in 0..5 {
            let cl = cam.level(level);
            assert_eq!(cl.lens(), cam.lens());
            for px in image_grid(&cam, 97.0) {
                let p = cam.back_project(&px) * 900.0;
                let pxl = cl.project(&p).unwrap();
                assert!(
                    (Camera::level_to_base(&pxl, level) - px).norm() < 1e-8,
                    "{name} level {level} at {px}"
                );
                assert!(angle(&cl.ray(&pxl), &p) < 1e-9, "{name} level {level}");
            }
        }
    }
}

/// Today's pinhole arithmetic, written out: the camera's pinhole arm must give these bits.
struct TodaysPinhole {
    f: f64,
    c: Vector2<f64>,
}

impl TodaysPinhole {
    fn project(&self, p: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(self.f * p.x / p.z + self.c.x, self.f * p.y / p.z + self.c.y)
    }
    fn ray(&self, px: &Vector2<f64>) -> Vector3<f64> {
        Vector3::new((px.x - self.c.x) / self.f, (px.y - self.c.y) / self.f, 1.0)
    }
    fn jacobian(&self, p: &Vector3<f64>) -> Matrix2x3<f64> {
        let (iz, f) = (1.0 / p.z, self.f);
        Matrix2x3::new(
            f * iz,
            0.0,
            -f * p.x * iz * iz,
            0.0,
            f * iz,
            -f * p.y * iz * iz,
        )
    }
    fn optical_flow(&self, p: &Vector3<f64>) -> Matrix2x6<f64> {
        let iz = 1.0 / p.z;
        let (x, y) = (p.x * iz, p.y * iz);
        let f = self.f;
        Matrix2x6::new(
            -f * iz,
            0.0,
            f * x * iz,
            f * x * y,
            -f * (1.0 + x * x),
            f * y,
            0.0,
            -f * iz,
            f * y * iz,
            f * (1.0 + y * y),
            -f * x * y,
            -f * x,
        )
    }
}

fn bits<const R: usize, const C: usize>(m: &nalgebra::SMatrix<f64, R, C>) -> Vec<u64> {
    m.iter().map(|v| v.to_bits()).collect()
}

/// Every pinhole output equals `pinhole`'s formulas bit for bit, on every level.
fn assert_todays_arithmetic(cam: &Camera) {
    for level in 0..5 {
        let cl = cam.level(level);
        let today = TodaysPinhole {
            f: cam.f_px() / f64::from(1_u32 << level),
            c: cam
                .principal_point_px()
                .map(|c| (c + 0.5) / f64::from(1_u32 << level) - 0.5),
        };
        assert_eq!(cl.f_px().to_bits(), today.f.to_bits());
        for px in image_grid(&cl, 13.7) {
            assert_eq!(bits(&cl.ray(&px)), bits(&today.ray(&px)), "{px}");
            for z in [0.5, 61.25, 2733.0] {
                let p = cl.back_project_depth(&px, z) + Vector3::new(0.1, -0.3, 0.0);
                assert_eq!(bits(&cl.project(&p).unwrap()), bits(&today.project(&p)));
                assert_eq!(bits(&cl.projection_jacobian(&p)), bits(&today.jacobian(&p)));
                assert_eq!(
                    bits(&cl.optical_flow_jacobian(&p)),
                    bits(&today.optical_flow(&p))
                );
            }
        }
    }
}

#[test]
fn the_pinhole_keeps_todays_arithmetic_bit_for_bit() {
    let paper = Camera::paper();
    assert_eq!(paper.fx_px(), paper.fy_px());
    assert_todays_arithmetic(&paper);
    // A calibration with every coefficient zero (and fx = fy) is that same camera.
    let f = paper.f_px();
    let c = paper.principal_point_px();
    for distortion in [
        Distortion::None,
        Distortion::RadialTangential {
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        },
        Distortion::Fisheye {
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        },
    ] {
        let zero = calibrated(
            768,
            1024,
            Intrinsics {
                fx_px: f,
                fy_px: f,
                cx_px: c.x,
                cy_px: c.y,
                distortion,
            },
        );
        assert_eq!(zero, paper, "{distortion:?}");
        assert_todays_arithmetic(&zero);
    }
}

#[test]
fn a_lens_that_folds_inside_the_image_is_refused_and_failures_are_reported() {
    let strong = Intrinsics {
        fx_px: 500.0,
        fy_px: 500.0,
        cx_px: 319.5,
        cy_px: 239.5,
        distortion: Distortion::RadialTangential {
            k1: -0.6,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        },
    };
    // r (1 − 0.6 r²) peaks at 0.497 (r = 0.745): the corners (0.8 normalised) have no inverse.
    let cfg = CameraConfig {
        width_px: 640,
        height_px: 480,
        focal_length_mm: 0.0,
        pixel_pitch_um: 0.0,
        calibration: Some(strong),
    };
    let err = Camera::from_config(&cfg).unwrap_err();
    assert!(
        matches!(
            err,
            CameraConfigError::Lens {
                reason: UndistortError::OutsideModel,
                ..
            }
        ),
        "{err}"
    );
    // The same lens on a smaller image is fine; beyond its field it reports, never loops.
    let small = Camera::from_config(&CameraConfig {
        width_px: 320,
        height_px: 240,
        calibration: Some(Intrinsics {
            cx_px: 159.5,
            cy_px: 119.5,
            ..strong
        }),
        ..cfg
    })
    .unwrap();
    let far = Vector2::new(159.5 + 0.6 * 500.0, 119.5);
    assert_eq!(small.try_ray(&far), Err(UndistortError::OutsideModel));
    assert!(small.ray(&far).iter().all(|v| v.is_nan()));
    // A point beyond the fold does not project (it would fold back into the image).
    assert!(small.project(&Vector3::new(0.9, 0.0, 1.0)).is_none());
    assert!(small.project(&Vector3::new(0.5, 0.0, 1.0)).is_some());
}

#[test]
fn fields_of_view_follow_the_lens() {
    let (_, fisheye) = &real_cameras()[2];
    // 1024 px across at 481 px focal length: a pinhole would see 93.5°, the fisheye sees
    // θ_d ≈ 512/481.3 rad each side.
    let hfov = fisheye.horizontal_fov_rad().to_degrees();
    assert!(hfov > 120.0 && hfov < 125.0, "{hfov}");
    let (_, pinhole) = &real_cameras()[3];
    let expected = ((330.25_f64 + 0.5) / 612.0).atan() + ((639.5_f64 - 330.25) / 612.0).atan();
    assert!((pinhole.horizontal_fov_rad() - expected).abs() < 1e-15);
}

// ---- Configuration keys ----

fn calibration_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/calibration")
}

#[test]
fn calibration_files_are_named_relative_to_the_configuration() {
    let dir = calibration_dir();
    let parse = |text: &str| CameraSettings::from_toml_str_in(text, Some(&dir));
    let s = parse("[camera]\ncalibration_file = \"plumb_bob_ros.yaml\"\n").unwrap();
    assert_eq!((s.camera.width_px, s.camera.height_px), (1280, 960));
    let k = s.camera.calibration.unwrap();
    assert_eq!((k.fx_px, k.cy_px), (1108.47, 478.86));
    assert_eq!(s.mounting, MountingConfig::default());
    // The size may be stated too, and must then agree.
    assert!(
        parse("[camera]\ncalibration_file = \"plumb_bob_ros.yaml\"\nwidth_px = 1280\n").is_ok()
    );
    let e = parse("[camera]\ncalibration_file = \"plumb_bob_ros.yaml\"\nheight_px = 1024\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("`camera.height_px`: 1024 px, but the calibration"),
        "{e}"
    );
    assert!(e.contains("is 1280 × 960 px"), "{e}");
    let e = parse("[camera]\ncalibration_file = \"fisheye_ros.yaml\"\nfocal_length_mm = 8.0\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("`camera.focal_length_mm`: not with camera.calibration_file"),
        "{e}"
    );
    // A missing or broken file: the key, then the file and its own key.
    let e = parse("[camera]\ncalibration_file = \"absent.yaml\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("`camera.calibration_file`:"), "{e}");
    assert!(e.contains("absent.yaml: cannot read"), "{e}");
    // Through a file: the path is taken from the file's directory.
    let tmp = std::env::temp_dir().join(format!("ianav-camera-toml-{}", std::process::id()));
    std::fs::create_dir_all(tmp.join("cal")).unwrap();
    std::fs::copy(dir.join("fisheye_opencv.xml"), tmp.join("cal/cam.xml")).unwrap();
    let toml_path = tmp.join("camera.toml");
    std::fs::write(
        &toml_path,
        "[camera]\ncalibration_file = \"cal/cam.xml\"\n[mounting]\neuler_bc_deg = [0.0, 0.0, 0.0]\n\
         lens_from_reference_b_m = [0.3, 0.0, 0.1]\nangle_true_sigma_deg = 0.0\n\
         angle_estimate_sigma_deg = 0.0\nposition_estimate_sigma_m = 0.0\n",
    )
    .unwrap();
    let s = CameraSettings::from_file(&toml_path).unwrap();
    assert_eq!(s.camera.width_px, 1024);
    assert!(matches!(
        s.camera.calibration.unwrap().distortion,
        Distortion::Fisheye { .. }
    ));
    assert_eq!(s.mounting.lens_from_reference_b_m, [0.3, 0.0, 0.1]);
    // The resolved configuration goes through TOML (the navigation's record) unchanged.
    let text = toml::to_string(&s.camera).unwrap();
    let back: CameraConfig = toml::from_str(&text).unwrap();
    assert_eq!(back, s.camera);
    std::fs::remove_dir_all(&tmp).unwrap();
    let e = CameraSettings::from_file(&tmp.join("camera.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("camera.toml"), "{e}");
}

#[test]
fn the_nominal_configuration_serialises_as_before() {
    // Sensor logs record `CameraConfig`: without a calibration nothing new is written.
    let text = toml::to_string(&CameraConfig::default()).unwrap();
    assert_eq!(
        text,
        "width_px = 768\nheight_px = 1024\nfocal_length_mm = 19.0\npixel_pitch_um = 17.0\n"
    );
}
