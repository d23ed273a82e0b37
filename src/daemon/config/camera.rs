//! `[camera]` of the daemon's configuration: the source, the intrinsics (a calibration file
//! or the nominal pinhole; docs/CAMERA.md) and the mounting `zeta_bc`.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::{ConfigError, in_range, invalid};
use crate::io::frame_stream::StreamAddress;
use crate::nav::NavCamera;
use crate::vision::camera::{IntrinsicsKeys, Mounting, MountingConfig};

/// Camera source kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraSourceKind {
    /// No camera (INS only).
    None,
    /// The simulator's frame stream (`io::frame_stream`) at `camera.address` (TCP or a Unix
    /// socket).
    FrameStream,
    /// PNG / PGM files of `camera.path` in name order.
    Directory,
    /// A V4L2 device (`camera.device`): needs the `opencv` feature.
    V4l2,
    /// A GStreamer pipeline (`camera.pipeline`): needs the `opencv` feature.
    Gstreamer,
}

/// `[camera]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Source kind.
    #[serde(default = "default_camera_source")]
    pub source: CameraSourceKind,
    /// The frame stream's `host:port`, or `unix:PATH` for a Unix socket on this machine.
    #[serde(default)]
    pub address: String,
    /// Directory of images.
    #[serde(default)]
    pub path: String,
    /// Frame rate assumed for directory images whose name carries no timestamp, Hz.
    #[serde(default = "default_camera_rate_hz")]
    pub rate_hz: f64,
    /// V4L2 device.
    #[serde(default)]
    pub device: String,
    /// GStreamer pipeline ending in an appsink.
    #[serde(default)]
    pub pipeline: String,
    /// Frames waiting for the navigation thread; older ones are dropped beyond this.
    #[serde(default = "default_frame_queue")]
    pub queue_frames: usize,
    /// Longest wait between reconnection attempts, s.
    #[serde(default = "default_retry_max_s")]
    pub retry_max_s: f64,
    /// The camera is declared lost after this long without a frame, s.
    #[serde(default = "default_camera_timeout_s")]
    pub timeout_s: f64,
    /// Calibration file (OpenCV `FileStorage` YAML or XML, ROS `camera_info` YAML), relative
    /// to this file's directory; empty: the nominal pinhole of the four keys below, or none.
    #[serde(default)]
    pub calibration_file: String,
    /// Image width (columns), px: the nominal pinhole's, or a check of the calibration's.
    #[serde(default)]
    pub width_px: Option<u32>,
    /// Image height (rows), px.
    #[serde(default)]
    pub height_px: Option<u32>,
    /// Focal length of the nominal pinhole, mm (not with `calibration_file`).
    #[serde(default)]
    pub focal_length_mm: Option<f64>,
    /// Pixel pitch of the nominal pinhole, µm (not with `calibration_file`).
    #[serde(default)]
    pub pixel_pitch_um: Option<f64>,
    /// Mounting `zeta_bc`: Euler angles body → camera `[yaw, pitch, bank]`, degrees (ZYX).
    #[serde(default = "default_euler_bc_deg")]
    pub euler_bc_deg: [f64; 3],
    /// Mounting: optical centre from the aircraft reference point, body axes, m.
    #[serde(default = "default_lens_from_reference_b_m")]
    pub lens_from_reference_b_m: [f64; 3],
    /// Height of the ground under the flight above the WGS84 ellipsoid, m: the visual
    /// navigation starts from the INS's height over it (`NavConfig::flat_terrain`). `None`: no
    /// height over the terrain, so the visual navigation never starts.
    #[serde(default)]
    pub terrain_height_m: Option<f64>,
    /// Its standard deviation, m (the scale error of a visual start: 1σ of 50 m at 2,700 m
    /// over the ground is 1.9 % of the distance flown, without the IA-VNS's INS scale).
    #[serde(default = "default_terrain_height_sigma_m")]
    pub terrain_height_sigma_m: f64,
    /// The intrinsics the keys above give, resolved (calibration file read) when the file is
    /// loaded; `None` when none are configured. Not a key.
    #[serde(skip)]
    pub intrinsics: Option<crate::vision::camera::CameraConfig>,
}

fn default_terrain_height_sigma_m() -> f64 {
    50.0
}
fn default_camera_source() -> CameraSourceKind {
    CameraSourceKind::None
}
fn default_camera_rate_hz() -> f64 {
    10.0
}
fn default_frame_queue() -> usize {
    4
}
fn default_retry_max_s() -> f64 {
    5.0
}
fn default_camera_timeout_s() -> f64 {
    2.0
}
fn default_euler_bc_deg() -> [f64; 3] {
    MountingConfig::default().euler_bc_deg
}
fn default_lens_from_reference_b_m() -> [f64; 3] {
    MountingConfig::default().lens_from_reference_b_m
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            source: default_camera_source(),
            address: String::new(),
            path: String::new(),
            rate_hz: default_camera_rate_hz(),
            device: String::new(),
            pipeline: String::new(),
            queue_frames: default_frame_queue(),
            retry_max_s: default_retry_max_s(),
            timeout_s: default_camera_timeout_s(),
            calibration_file: String::new(),
            width_px: None,
            height_px: None,
            focal_length_mm: None,
            pixel_pitch_um: None,
            euler_bc_deg: default_euler_bc_deg(),
            lens_from_reference_b_m: default_lens_from_reference_b_m(),
            terrain_height_m: None,
            terrain_height_sigma_m: default_terrain_height_sigma_m(),
            intrinsics: None,
        }
    }
}

impl CameraConfig {
    /// The intrinsics keys as written.
    fn intrinsics_keys(&self) -> IntrinsicsKeys {
        IntrinsicsKeys {
            width_px: self.width_px,
            height_px: self.height_px,
            focal_length_mm: self.focal_length_mm,
            pixel_pitch_um: self.pixel_pitch_um,
            calibration_file: (!self.calibration_file.is_empty())
                .then(|| PathBuf::from(&self.calibration_file)),
        }
    }

    /// The mounting `zeta_bc` as configured (the navigation's estimate of it: a real
    /// aircraft has no simulated mounting errors).
    pub fn mounting(&self) -> Mounting {
        MountingConfig {
            euler_bc_deg: self.euler_bc_deg,
            lens_from_reference_b_m: self.lens_from_reference_b_m,
            ..MountingConfig::default()
        }
        .nominal()
    }

    /// The camera as the navigation knows it: the configured intrinsics (the authors' camera
    /// when none are) and mounting; `None` without a camera source.
    pub fn nav_camera(&self) -> Option<NavCamera> {
        (self.source != CameraSourceKind::None).then(|| NavCamera {
            intrinsics: self.intrinsics.unwrap_or_default(),
            mounting: self.mounting(),
        })
    }
}

/// Read the calibration file or build the nominal pinhole the keys name (into
/// `camera.intrinsics`); `base_dir` resolves a relative `calibration_file`.
pub(super) fn resolve(
    camera: &mut CameraConfig,
    base_dir: Option<&Path>,
) -> Result<(), ConfigError> {
    let keys = camera.intrinsics_keys();
    camera.intrinsics = if keys.is_empty() {
        None
    } else {
        Some(keys.resolve(base_dir).map_err(ConfigError::Camera)?)
    };
    Ok(())
}

/// Validate `[camera]`; errors name the key.
pub(super) fn validate(c: &CameraConfig) -> Result<(), ConfigError> {
    match c.source {
        CameraSourceKind::None => {}
        CameraSourceKind::FrameStream => {
            if c.address.parse::<StreamAddress>().is_err() {
                return Err(invalid(
                    "camera.address",
                    format!("{:?}", c.address),
                    "must be host:port or unix:PATH with camera.source = \"frame_stream\"",
                ));
            }
        }
        CameraSourceKind::Directory => {
            if c.path.is_empty() {
                return Err(invalid(
                    "camera.path",
                    "\"\"",
                    "must name a directory with camera.source = \"directory\"",
                ));
            }
        }
        CameraSourceKind::V4l2 | CameraSourceKind::Gstreamer if !cfg!(feature = "opencv") => {
            return Err(invalid(
                "camera.source",
                format!("{:?}", c.source).to_lowercase(),
                "requires the `opencv` feature, which this build does not have",
            ));
        }
        CameraSourceKind::V4l2 => {
            if c.device.is_empty() {
                return Err(invalid(
                    "camera.device",
                    "\"\"",
                    "must name a device (e.g. /dev/video0) with camera.source = \"v4l2\"",
                ));
            }
        }
        CameraSourceKind::Gstreamer => {
            if c.pipeline.is_empty() {
                return Err(invalid(
                    "camera.pipeline",
                    "\"\"",
                    "must be a pipeline ending in an appsink with camera.source = \"gstreamer\"",
                ));
            }
        }
    }
    in_range("camera.rate_hz", c.rate_hz, 0.1, 100.0)?;
    if !(1..=64).contains(&c.queue_frames) {
        return Err(invalid(
            "camera.queue_frames",
            c.queue_frames,
            "must be in [1, 64]",
        ));
    }
    in_range("camera.retry_max_s", c.retry_max_s, 0.1, 600.0)?;
    in_range("camera.timeout_s", c.timeout_s, 0.1, 600.0)?;
    if let Some(h) = c.terrain_height_m {
        in_range("camera.terrain_height_m", h, -500.0, 9_000.0)?;
    }
    in_range(
        "camera.terrain_height_sigma_m",
        c.terrain_height_sigma_m,
        0.0,
        1_000.0,
    )?;
    for i in 0..3 {
        in_range(
            &format!("camera.euler_bc_deg[{i}]"),
            c.euler_bc_deg[i],
            -360.0,
            360.0,
        )?;
        in_range(
            &format!("camera.lens_from_reference_b_m[{i}]"),
            c.lens_from_reference_b_m[i],
            -20.0,
            20.0,
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::DaemonConfig;
    use super::*;

    fn parse(s: &str) -> Result<DaemonConfig, ConfigError> {
        DaemonConfig::from_toml_str(s, Some(Path::new("config")))
    }

    const MINIMAL: &str = "[mavlink]\nconnection = \"udpin:0.0.0.0:14540\"\n\
                           [output]\nrate_hz = 30\n";

    #[test]
    fn camera_intrinsics_calibration_and_mounting_keys() {
        let cam = |keys: &str| parse(&format!("{MINIMAL}[camera]\n{keys}"));
        let err = |keys: &str| cam(keys).unwrap_err().to_string();
        // None configured: no intrinsics, the authors' camera for the navigation.
        let none = cam("source = \"frame_stream\"\naddress = \"127.0.0.1:5600\"\n").unwrap();
        assert_eq!(none.camera.intrinsics, None);
        let nav = none.camera.nav_camera().unwrap();
        assert_eq!(
            nav.intrinsics,
            crate::vision::camera::CameraConfig::default()
        );
        assert_eq!(nav.mounting, MountingConfig::default().nominal());
        assert!(parse(MINIMAL).unwrap().camera.nav_camera().is_none());
        // The frame stream over a Unix socket; an address that is neither form is refused.
        cam("source = \"frame_stream\"\naddress = \"unix:/run/ianav/frames.sock\"\n").unwrap();
        let e = err("source = \"frame_stream\"\naddress = \"5600\"\n");
        assert!(
            e.contains("camera.address = \"5600\": must be host:port or unix:PATH"),
            "{e}"
        );
        // The nominal pinhole: all four keys.
        let nominal =
            cam("width_px = 640\nheight_px = 480\nfocal_length_mm = 8.0\npixel_pitch_um = 5.0\n")
                .unwrap();
        let c = nominal.camera.intrinsics.unwrap();
        assert_eq!(
            (c.width_px, c.height_px, c.focal_length_mm),
            (640, 480, 8.0)
        );
        let e = err("width_px = 640\nheight_px = 480\nfocal_length_mm = 8.0\n");
        assert!(e.contains("`camera.pixel_pitch_um`: missing field"), "{e}");
        let e = err("width_px = 1\nheight_px = 480\nfocal_length_mm = 8.0\npixel_pitch_um = 5.0\n");
        assert!(
            e.contains("`camera.width_px` = 1: must be 2 to 16384 px"),
            "{e}"
        );
        let e =
            err("width_px = 640\nheight_px = 480\nfocal_length_mm = -8.0\npixel_pitch_um = 5.0\n");
        assert!(e.contains("`camera.focal_length_mm` = -8"), "{e}");
        // A calibration file, relative to the configuration's directory (`config/`).
        let file = "calibration_file = \"../tests/data/calibration/plumb_bob_ros.yaml\"\n";
        let calibrated = cam(&format!("{file}euler_bc_deg = [0.0, 0.0, 0.0]\n")).unwrap();
        let c = calibrated.camera.intrinsics.unwrap();
        assert_eq!((c.width_px, c.height_px), (1280, 960));
        assert_eq!(c.calibration.unwrap().fx_px, 1108.47);
        assert_eq!(
            calibrated.camera.mounting().q_bc,
            nalgebra::UnitQuaternion::identity()
        );
        assert!(cam(&format!("{file}width_px = 1280\nheight_px = 960\n")).is_ok());
        let e = err(&format!("{file}width_px = 768\n"));
        assert!(
            e.contains("`camera.width_px`: 768 px, but the calibration"),
            "{e}"
        );
        let e = err(&format!("{file}pixel_pitch_um = 3.0\n"));
        assert!(
            e.contains("`camera.pixel_pitch_um`: not with camera.calibration_file"),
            "{e}"
        );
        let e = err("calibration_file = \"missing.yaml\"\n");
        assert!(
            e.contains("`camera.calibration_file`: config/missing.yaml: cannot read"),
            "{e}"
        );
        // A broken file: the file and its key.
        let dir = std::env::temp_dir().join(format!("ianav-daemon-cal-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ros = include_str!("../../../tests/data/calibration/plumb_bob_ros.yaml");
        std::fs::write(
            dir.join("cam.yaml"),
            ros.replace("distortion_model: plumb_bob", "distortion_model: brown"),
        )
        .unwrap();
        let text = format!("{MINIMAL}[camera]\ncalibration_file = \"cam.yaml\"\n");
        let e = DaemonConfig::from_toml_str(&text, Some(&dir))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cam.yaml: `distortion_model`: unknown model `brown`"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
        // Mounting keys.
        let e = err("euler_bc_deg = [90.0, 400.0, 0.0]\n");
        assert_eq!(e, "camera.euler_bc_deg[1] = 400: must be in [-360, 360]");
        let e = err("lens_from_reference_b_m = [0.5, 0.0, nan]\n");
        assert_eq!(
            e,
            "camera.lens_from_reference_b_m[2] = NaN: must be in [-20, 20]"
        );
        let e = err("euler_bc_deg = [90.0, 0.0]\n");
        assert!(e.contains("euler_bc_deg"), "{e}");
        let e = err("calibration = \"x.yaml\"\n");
        assert!(e.contains("calibration"), "{e}");
    }
}
