//! V4L2 and GStreamer camera sources through OpenCV's `VideoCapture` (docs/REFERENCES.md M4),
//! behind the `opencv` Cargo feature.
//!
//! System packages (Debian 12): `libopencv-dev clang libclang-dev` to build; at run time the
//! OpenCV libraries, and `gstreamer1.0-plugins-base` (plus the plugins the pipeline names) for
//! GStreamer pipelines. The device is opened with `CAP_V4L2` (`camera.device`, e.g.
//! `/dev/video0`) or `CAP_GSTREAMER` (`camera.pipeline`, ending in an `appsink`).
//!
//! Capture blocks, so it runs on its own thread. Frames are converted to 8-bit grey and
//! stamped with the daemon's clock when `read` returns (the driver's exposure time is not
//! portable across backends; the capture latency, a few ms for V4L2, is not corrected). A
//! device that is absent, fails to open or stops delivering is reopened with exponential
//! back-off, counted in `camera_errors`, and never stops the daemon.

use std::sync::Arc;
use std::time::Duration;

use opencv::core::{Mat, MatTraitConst, MatTraitConstManual};
use opencv::imgproc;
use opencv::prelude::VideoCaptureTrait;
use opencv::prelude::VideoCaptureTraitConst;
use opencv::videoio;
use tokio::sync::watch;

use super::Clock;
use super::camera::{Out, wait_unless_stopped};
use crate::daemon::config::{CameraSourceKind, DaemonConfig};

/// Why a captured image could not be used.
#[derive(Debug, thiserror::Error)]
pub enum GreyError {
    /// OpenCV refused an operation.
    #[error("opencv: {0}")]
    OpenCv(#[from] opencv::Error),
    /// Not an 8-bit image with 1, 3 or 4 channels.
    #[error("unsupported image: depth {depth}, {channels} channels")]
    Unsupported {
        /// OpenCV depth code.
        depth: i32,
        /// Channels.
        channels: i32,
    },
    /// Empty or absurd dimensions.
    #[error("bad image size {0} x {1}")]
    Size(i32, i32),
}

/// 8-bit grey copy of a captured image (BGR, BGRA or grey): `(width, height, pixels)`.
pub fn grey_pixels(img: &Mat) -> Result<(u32, u32, Vec<u8>), GreyError> {
    let (w, h) = (img.cols(), img.rows());
    let (Ok(wu), Ok(hu)) = (u32::try_from(w), u32::try_from(h)) else {
        return Err(GreyError::Size(w, h));
    };
    if wu == 0 || hu == 0 || wu > 16_384 || hu > 16_384 {
        return Err(GreyError::Size(w, h));
    }
    let (depth, channels) = (img.depth(), img.channels());
    if depth != opencv::core::CV_8U {
        return Err(GreyError::Unsupported { depth, channels });
    }
    let code = match channels {
        1 => None,
        3 => Some(imgproc::COLOR_BGR2GRAY),
        4 => Some(imgproc::COLOR_BGRA2GRAY),
        _ => return Err(GreyError::Unsupported { depth, channels }),
    };
    let mut grey = Mat::default();
    let grey = match code {
        Some(code) => {
            imgproc::cvt_color_def(img, &mut grey, code)?;
            &grey
        }
        None => img,
    };
    // `data_bytes` needs a continuous matrix; a region of interest is copied first.
    let owned;
    let grey = if grey.is_continuous() {
        grey
    } else {
        owned = grey.try_clone()?;
        &owned
    };
    Ok((wu, hu, grey.data_bytes()?.to_vec()))
}

/// What to open.
fn target(cfg: &DaemonConfig) -> Option<(String, i32)> {
    match cfg.camera.source {
        CameraSourceKind::V4l2 => Some((cfg.camera.device.clone(), videoio::CAP_V4L2)),
        CameraSourceKind::Gstreamer => Some((cfg.camera.pipeline.clone(), videoio::CAP_GSTREAMER)),
        _ => None,
    }
}

fn open(name: &str, api: i32) -> Result<videoio::VideoCapture, String> {
    let cap = videoio::VideoCapture::from_file(name, api).map_err(|e| e.to_string())?;
    match cap.is_opened() {
        Ok(true) => Ok(cap),
        Ok(false) => Err("cannot be opened".into()),
        Err(e) => Err(e.to_string()),
    }
}

/// Capture until stopped (blocking; run on its own thread).
pub(super) fn run_blocking(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    out: Out,
    stop: watch::Receiver<bool>,
) {
    let Some((name, api)) = target(&cfg) else {
        return;
    };
    let max_backoff = Duration::from_secs_f64(cfg.camera.retry_max_s);
    let mut backoff = Duration::from_millis(200);
    let stopped = || *stop.borrow();
    let wait = |d: Duration| {
        wait_unless_stopped(&stop, d);
    };
    let mut failures = 0_u64;
    while !stopped() {
        let mut cap = match open(&name, api) {
            Ok(c) => c,
            Err(e) => {
                failures += 1;
                if failures % 10 == 1 {
                    tracing::warn!("camera {name}: {e} (retrying)");
                }
                out.shared.count(|c| c.camera_errors += 1);
                wait(backoff);
                backoff = (backoff * 2).min(max_backoff);
                continue;
            }
        };
        failures = 0;
        backoff = Duration::from_millis(200);
        out.shared.count(|c| c.camera_connects += 1);
        tracing::info!("camera opened: {name}");
        let mut img = Mat::default();
        while !stopped() {
            match cap.read(&mut img) {
                Ok(true) => {}
                Ok(false) | Err(_) => {
                    // End of stream or a device gone: reopen.
                    tracing::warn!("camera {name}: no frame (reopening)");
                    out.shared.count(|c| c.camera_errors += 1);
                    break;
                }
            }
            let now = clock.now_us();
            match grey_pixels(&img) {
                Ok((width, height, pixels)) => out.deliver(
                    crate::sensors::Frame {
                        t_us: now,
                        width,
                        height,
                        pixels: Arc::from(pixels),
                    },
                    now,
                ),
                Err(e) => {
                    tracing::warn!("camera {name}: {e}");
                    out.shared.count(|c| c.camera_errors += 1);
                }
            }
        }
        wait(backoff);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opencv::core::{CV_8UC1, CV_8UC3, CV_16UC1, Scalar};

    #[test]
    fn bgr_and_grey_images_become_grey_bytes() {
        // BT.601 weights: grey = 0.299 R + 0.587 G + 0.114 B.
        let bgr =
            Mat::new_rows_cols_with_default(2, 3, CV_8UC3, Scalar::new(10.0, 20.0, 30.0, 0.0))
                .unwrap();
        let (w, h, px) = grey_pixels(&bgr).unwrap();
        assert_eq!((w, h, px.len()), (3, 2, 6));
        let expected = 0.114 * 10.0 + 0.587 * 20.0 + 0.299 * 30.0;
        assert!(
            px.iter().all(|&p| (f64::from(p) - expected).abs() <= 1.0),
            "{px:?}"
        );
        let grey = Mat::new_rows_cols_with_default(4, 5, CV_8UC1, Scalar::all(77.0)).unwrap();
        assert_eq!(grey_pixels(&grey).unwrap(), (5, 4, vec![77; 20]));
    }

    #[test]
    fn unsupported_and_empty_images_are_errors() {
        let deep = Mat::new_rows_cols_with_default(2, 2, CV_16UC1, Scalar::all(1.0)).unwrap();
        assert!(matches!(
            grey_pixels(&deep),
            Err(GreyError::Unsupported { .. })
        ));
        assert!(matches!(
            grey_pixels(&Mat::default()),
            Err(GreyError::Size(..))
        ));
    }
}
