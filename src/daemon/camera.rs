//! Camera sources of the daemon (issue 5 item 4; research/mavlink.md §4):
//!
//! - `frame_stream`: TCP client of the vehicle's frame stream ([`crate::io::frame_stream`]).
//!   Exposure times are in the vehicle's clock and are mapped with the time-sync offset; frames
//!   that arrive before an offset is known, out of order, or more than 1 s in the future are
//!   refused and counted. An absent
//!   server is retried with exponential back-off (0.2 s doubling up to `camera.retry_max_s`);
//!   a stream silent for 3 × `camera.timeout_s` is reconnected; a stall shorter than that
//!   simply resumes.
//! - `directory`: PNG / PGM (binary P5) files in name order, converted to 8-bit grey. A file
//!   whose stem is an integer is shown at that many µs after the first such file; otherwise
//!   frames are paced at `camera.rate_hz`. Frames are stamped with the daemon's clock when
//!   emitted (no autopilot clock is involved). The directory is read once.
//! - `v4l2` / `gstreamer` need the `opencv` feature (refused by the configuration check).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::AsyncReadExt;
use tokio::sync::{mpsc, watch};

use super::nav_thread::{FrameQueue, NavInput};
use super::{Clock, Shared, stopped_after};
use crate::config::{CameraSourceKind, DaemonConfig};
use crate::io::frame_stream::{FrameHeader, HEADER_BYTES};
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
    };
    match cfg.camera.source {
        CameraSourceKind::FrameStream => frame_stream(cfg, clock, out, stop).await,
        CameraSourceKind::Directory => directory(cfg, clock, out, stop).await,
        // No camera, or a source this build cannot open (refused by the configuration).
        _ => {}
    }
}

/// Where frames go.
struct Out {
    frames: Arc<FrameQueue>,
    wake: mpsc::Sender<NavInput>,
    shared: Arc<Shared>,
}

impl Out {
    fn deliver(&self, f: Frame, now_us: u64) {
        let dropped = self.frames.push(f);
        self.shared.count(|c| {
            c.frames_received += 1;
            c.frames_dropped += dropped;
        });
        self.shared.state(|s| s.last_frame_us = Some(now_us));
        let _ = self.wake.try_send(NavInput::FramesReady);
    }
}

async fn frame_stream(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    out: Out,
    mut stop: watch::Receiver<bool>,
) {
    let shared = out.shared.clone();
    let autopilot_clock = cfg.mavlink.clock == crate::config::ClockSource::Autopilot;
    let max_backoff = Duration::from_secs_f64(cfg.camera.retry_max_s);
    let silence = Duration::from_secs_f64(3.0 * cfg.camera.timeout_s);
    let mut backoff = Duration::from_millis(200);
    let mut last_t_us: Option<u64> = None;
    let mut failures = 0_u64;
    loop {
        let conn = tokio::select! {
            c = tokio::net::TcpStream::connect(&cfg.camera.address) => c,
            _ = stop.wait_for(|s| *s) => return,
        };
        let mut sock = match conn {
            Ok(s) => s,
            Err(e) => {
                failures += 1;
                // Log the first failure and then every 10th, not every attempt.
                if failures % 10 == 1 {
                    tracing::warn!("camera {}: {e} (retrying)", cfg.camera.address);
                }
                shared.count(|c| c.camera_errors += 1);
                if stopped_after(&mut stop, backoff).await {
                    return;
                }
                backoff = (backoff * 2).min(max_backoff);
                continue;
            }
        };
        failures = 0;
        backoff = Duration::from_millis(200);
        shared.count(|c| c.camera_connects += 1);
        tracing::info!("camera frame stream connected: {}", cfg.camera.address);
        loop {
            let read = async {
                let mut h = [0_u8; HEADER_BYTES];
                sock.read_exact(&mut h).await?;
                let header = FrameHeader::decode(&h)
                    .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
                let mut pixels = vec![0_u8; header.payload_bytes as usize];
                sock.read_exact(&mut pixels).await?;
                Ok::<_, std::io::Error>((header, pixels))
            };
            let r = tokio::select! {
                r = tokio::time::timeout(silence, read) => r,
                _ = stop.wait_for(|s| *s) => return,
            };
            let (header, pixels) = match r {
                Ok(Ok(x)) => x,
                Ok(Err(e)) => {
                    tracing::warn!("camera stream: {e} (reconnecting)");
                    shared.count(|c| c.camera_errors += 1);
                    break;
                }
                Err(_) => {
                    tracing::warn!("camera stream silent for {silence:?} (reconnecting)");
                    shared.count(|c| c.camera_errors += 1);
                    break;
                }
            };
            let now = clock.now_us();
            let offset = shared.state(|s| s.offset_us);
            let mapped = offset
                .and_then(|o| i64::try_from(header.t_us).ok()?.checked_add(o))
                .and_then(|t| u64::try_from(t).ok())
                // More than 1 s in the future: a bad offset, not a frame (daemon clock only:
                // a simulated vehicle's clock may run ahead of ours).
                .filter(|t| autopilot_clock || *t <= now + 1_000_000);
            let Some(t_us) = mapped.filter(|t| last_t_us.is_none_or(|l| *t > l)) else {
                shared.count(|c| c.frames_refused += 1);
                continue;
            };
            last_t_us = Some(t_us);
            let f = Frame {
                t_us,
                width: header.width,
                height: header.height,
                pixels: Arc::from(pixels),
            };
            out.deliver(f, now);
        }
        if stopped_after(&mut stop, backoff).await {
            return;
        }
    }
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

/// Decode a binary PGM (P5, maxval ≤ 255).
pub fn decode_pgm(b: &[u8]) -> Option<(u32, u32, Vec<u8>)> {
    // Header: "P5" whitespace width whitespace height whitespace maxval one-whitespace data;
    // comments start with '#' and run to the end of the line.
    let mut fields = Vec::with_capacity(4);
    let mut i = 0;
    while fields.len() < 4 {
        while i < b.len() && (b[i].is_ascii_whitespace() || b[i] == b'#') {
            if b[i] == b'#' {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            } else {
                i += 1;
            }
        }
        let start = i;
        while i < b.len() && !b[i].is_ascii_whitespace() {
            i += 1;
        }
        if start == i {
            return None;
        }
        fields.push(std::str::from_utf8(&b[start..i]).ok()?);
    }
    if fields[0] != "P5" {
        return None;
    }
    let w: u32 = fields[1].parse().ok()?;
    let h: u32 = fields[2].parse().ok()?;
    let maxval: u32 = fields[3].parse().ok()?;
    if maxval == 0 || maxval > 255 || w == 0 || h == 0 {
        return None;
    }
    let n = usize::try_from(u64::from(w) * u64::from(h)).ok()?;
    let data = b.get(i + 1..i + 1 + n)?;
    Some((w, h, data.to_vec()))
}

fn load_image(path: &Path) -> Option<(u32, u32, Vec<u8>)> {
    let bytes = std::fs::read(path).ok()?;
    if bytes.starts_with(b"P5") {
        return decode_pgm(&bytes);
    }
    let img = image::load_from_memory(&bytes).ok()?.into_luma8();
    let (w, h) = img.dimensions();
    Some((w, h, img.into_raw()))
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
        assert_eq!(decode_pgm(&b), Some((3, 2, vec![1, 2, 3, 4, 5, 6])));
        assert_eq!(decode_pgm(&b[..b.len() - 1]), None, "truncated");
        assert_eq!(decode_pgm(b"P6\n1 1\n255\n\0\0\0"), None);
        assert_eq!(decode_pgm(b"P5\n1 1\n65535\n\0\0"), None);
        assert_eq!(decode_pgm(b"P5\n0 1\n255\n"), None);
        assert_eq!(decode_pgm(b""), None);
    }
}
