//! Camera sources of the daemon (docs/REFERENCES.md M4):
//!
//! - `frame_stream`: TCP client of the vehicle's frame stream ([`crate::io::frame_stream`]), on
//!   its own thread (`camera_stream.rs`: exposure times mapped with the time-sync offset,
//!   refusals, reconnection).
//! - `directory`: PNG / PGM files in name order, converted to 8-bit grey ([`decode_image`]). A file
//!   whose stem is an integer is shown at that many µs after the first such file; otherwise
//!   frames are paced at `camera.rate_hz`. Frames are stamped with the daemon's clock when
//!   emitted (no autopilot clock is involved). The directory is read once.
//! - `v4l2` / `gstreamer`: OpenCV `VideoCapture` on its own thread (`camera_cv.rs`),
//!   with the `opencv` feature (without it the configuration check refuses them).
//!
//! With intrinsics configured (`camera.calibration_file` or the nominal pinhole's keys), a
//! frame of another size, or whose buffer is not 8-bit grey of that size, is refused and
//! counted in `frames_refused` ([`check_frame`]); the daemon goes on.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::nav_thread::{FrameQueue, NavInput};
use super::{Clock, Shared, stopped_after};
use crate::daemon::config::{CameraSourceKind, DaemonConfig};
use crate::sensors::Frame;

/// Run the configured source until stopped.
pub(super) async fn run(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    frames: Arc<FrameQueue>,
    wake: mpsc::Sender<NavInput>,
    shared: Arc<Shared>,
    stop: watch::Receiver<bool>,
) {
    let out = Out {
        frames,
        wake,
        shared,
        expected: cfg.camera.intrinsics.map(|c| (c.width_px, c.height_px)),
        refused_size: std::sync::atomic::AtomicU64::new(0),
    };
    match cfg.camera.source {
        CameraSourceKind::FrameStream => {
            blocking(move || super::camera_stream::run_blocking(cfg, clock, out, stop)).await;
        }
        CameraSourceKind::Directory => directory(cfg, clock, out, stop).await,
        #[cfg(feature = "opencv")]
        CameraSourceKind::V4l2 | CameraSourceKind::Gstreamer => {
            blocking(move || super::camera_cv::run_blocking(cfg, clock, out, stop)).await;
        }
        // No camera, or a source this build cannot open (refused by the configuration).
        _ => {}
    }
}

/// Run a blocking source on a thread of its own. Its panic is the camera task's own: the
/// supervisor (`daemon::run`) restarts it or stops the daemon, never a silently dead camera.
async fn blocking(source: impl FnOnce() + Send + 'static) {
    if let Err(e) = tokio::task::spawn_blocking(source).await
        && e.is_panic()
    {
        std::panic::resume_unwind(e.into_panic());
    }
}

/// Where frames go.
pub(super) struct Out {
    frames: Arc<FrameQueue>,
    wake: mpsc::Sender<NavInput>,
    pub(super) shared: Arc<Shared>,
    /// Frame size `(width, height)` of the configured intrinsics, if any.
    expected: Option<(u32, u32)>,
    /// Frames refused for their size or format (for the log's pace).
    refused_size: std::sync::atomic::AtomicU64,
}

/// Whether a frame is what the camera's intrinsics describe: their size, 8-bit grey (one byte
/// per pixel). The reason if not.
pub fn check_frame(f: &Frame, expected: (u32, u32)) -> Result<(), String> {
    let (w, h) = expected;
    if (f.width, f.height) != (w, h) {
        return Err(format!(
            "{} × {} px, the camera's intrinsics are for {w} × {h} px",
            f.width, f.height
        ));
    }
    let bytes = u64::from(w) * u64::from(h);
    if f.pixels.len() as u64 != bytes {
        return Err(format!(
            "{} bytes for {w} × {h} px: not 8-bit grey ({bytes} bytes)",
            f.pixels.len()
        ));
    }
    Ok(())
}

impl Out {
    /// Queue a frame for the navigation thread, unless its size or format disagrees with the
    /// configured intrinsics: then it is refused and counted (`frames_refused`), logged
    /// (the first and every 100th), and the camera is not taken as alive for it.
    pub(super) fn deliver(&self, f: Frame, now_us: u64) {
        if let Some(expected) = self.expected
            && let Err(reason) = check_frame(&f, expected)
        {
            let n = self
                .refused_size
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            if n.is_multiple_of(100) {
                tracing::warn!("camera: frame refused ({} so far): {reason}", n + 1);
            }
            self.shared.count(|c| c.frames_refused += 1);
            return;
        }
        let dropped = self.frames.push(f);
        self.shared.count(|c| {
            c.frames_received += 1;
            c.frames_dropped += dropped;
        });
        self.shared.state(|s| s.last_frame_us = Some(now_us));
        let _ = self.wake.try_send(NavInput::FramesReady);
    }
}

/// Sleep for `d`, in short slices so that a stop is seen promptly (blocking sources); `true`
/// when stopped.
pub(super) fn wait_unless_stopped(stop: &watch::Receiver<bool>, d: Duration) -> bool {
    let end = std::time::Instant::now() + d;
    while !*stop.borrow() && std::time::Instant::now() < end {
        std::thread::sleep(Duration::from_millis(20));
    }
    *stop.borrow()
}

/// Image files of a directory in name order.
pub fn list_images(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("png") || e.eq_ignore_ascii_case("pgm"))
        })
        .collect();
    v.sort();
    Ok(v)
}

/// Decode a PNG or PNM (PGM, PPM; binary or ASCII) image to 8-bit grey with the `image`
/// crate, the format told by the magic bytes. PNM samples below a maxval of 255 are scaled to
/// the full range, 16-bit ones reduced to 8 bits. Allocation is bounded like the frame stream:
/// at most 4,096 × 4,096 pixels, [`MAX_DECODE_BYTES`] in all.
pub fn decode_image(bytes: &[u8]) -> Option<(u32, u32, Vec<u8>)> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .ok()?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(4_096);
    limits.max_image_height = Some(4_096);
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    reader.limits(limits);
    let img = reader.decode().ok()?.into_luma8();
    let (w, h) = img.dimensions();
    // The crate accepts an empty image; a frame is not empty.
    (w > 0 && h > 0).then(|| (w, h, img.into_raw()))
}

/// Largest allocation while decoding one directory image: an RGBA frame of the largest size
/// the frame stream carries ([`crate::io::frame_stream::MAX_PAYLOAD_BYTES`] grey pixels).
pub const MAX_DECODE_BYTES: u64 = 4 * crate::io::frame_stream::MAX_PAYLOAD_BYTES as u64;

fn load_image(path: &Path) -> Option<(u32, u32, Vec<u8>)> {
    decode_image(&std::fs::read(path).ok()?)
}

async fn directory(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    out: Out,
    mut stop: watch::Receiver<bool>,
) {
    let shared = out.shared.clone();
    let dir = PathBuf::from(&cfg.camera.path);
    let max_backoff = Duration::from_secs_f64(cfg.camera.retry_max_s);
    let mut backoff = Duration::from_millis(200);
    let files = loop {
        match list_images(&dir) {
            Ok(f) if !f.is_empty() => break f,
            Ok(_) | Err(_) => {
                shared.count(|c| c.camera_errors += 1);
                tracing::warn!(
                    "camera directory {} has no images yet (retrying)",
                    dir.display()
                );
                if stopped_after(&mut stop, backoff).await {
                    return;
                }
                backoff = (backoff * 2).min(max_backoff);
            }
        }
    };
    shared.count(|c| c.camera_connects += 1);
    let start_us = clock.now_us();
    let mut first_stamp: Option<u64> = None;
    let period_us = (1e6 / cfg.camera.rate_hz) as u64;
    for (k, path) in files.iter().enumerate() {
        let stamp = path
            .file_stem()
            .and_then(|s| s.to_str())
            .and_then(|s| s.parse::<u64>().ok());
        let due_us = match stamp {
            Some(s) => s.saturating_sub(*first_stamp.get_or_insert(s)),
            None => k as u64 * period_us,
        };
        let wait_us = (start_us + due_us).saturating_sub(clock.now_us());
        if stopped_after(&mut stop, Duration::from_micros(wait_us)).await {
            return;
        }
        let p = path.clone();
        let img = tokio::task::spawn_blocking(move || load_image(&p))
            .await
            .ok()
            .flatten();
        let Some((width, height, pixels)) = img else {
            tracing::warn!("camera: cannot decode {}", path.display());
            shared.count(|c| c.camera_errors += 1);
            continue;
        };
        let now = clock.now_us();
        let f = Frame {
            t_us: now,
            width,
            height,
            pixels: Arc::from(pixels),
        };
        out.deliver(f, now);
    }
    tracing::info!("camera directory {} exhausted", dir.display());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pgm_headers_with_comments_decode_and_bad_ones_do_not() {
        let mut b = b"P5\n# a comment\n3 2\n255\n".to_vec();
        b.extend_from_slice(&[1, 2, 3, 4, 5, 6]);
        assert_eq!(decode_image(&b), Some((3, 2, vec![1, 2, 3, 4, 5, 6])));
        assert_eq!(decode_image(&b[..b.len() - 1]), None, "truncated");
        assert_eq!(decode_image(b"P5\n0 1\n255\n"), None);
        assert_eq!(decode_image(b"P5\n1 1\n0\n\0"), None, "maxval 0");
        assert_eq!(decode_image(b""), None);
        assert_eq!(decode_image(b"not an image"), None);
        // Beyond the hand-written P5 decoder this replaced: samples scaled to 8 bits.
        assert_eq!(
            decode_image(b"P5\n2 1\n15\n\x00\x0f"),
            Some((2, 1, vec![0, 255]))
        );
        assert_eq!(
            decode_image(b"P5\n1 1\n65535\n\xff\xff"),
            Some((1, 1, vec![255]))
        );
        // Too large to be a frame: refused before allocating.
        assert_eq!(decode_image(b"P5\n5000 5000\n255\n\0"), None);
    }

    #[test]
    fn png_frames_decode_to_grey() {
        let img = image::GrayImage::from_raw(2, 2, vec![0, 64, 128, 255]).unwrap();
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        assert_eq!(decode_image(&png), Some((2, 2, vec![0, 64, 128, 255])));
    }

    #[test]
    fn frames_that_disagree_with_the_intrinsics_are_refused() {
        let frame = |width: u32, height: u32, bytes: usize| Frame {
            t_us: 0,
            width,
            height,
            pixels: Arc::from(vec![0_u8; bytes]),
        };
        assert!(check_frame(&frame(1280, 960, 1280 * 960), (1280, 960)).is_ok());
        let e = check_frame(&frame(960, 1280, 1280 * 960), (1280, 960)).unwrap_err();
        assert_eq!(
            e,
            "960 × 1280 px, the camera's intrinsics are for 1280 × 960 px"
        );
        // A colour buffer where grey is expected.
        let e = check_frame(&frame(4, 2, 24), (4, 2)).unwrap_err();
        assert_eq!(e, "24 bytes for 4 × 2 px: not 8-bit grey (8 bytes)");
    }
}
