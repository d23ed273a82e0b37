//! The SITL vehicle on a real MAVLink link (mavlink 0.21 async connections; docs/REFERENCES.md
//! M1.3–M1.4): one task reads the link, one writes it, and the flight loop runs the [`Vehicle`] on
//! the simulated clock, paced against the wall clock at `speed` × real time with absolute deadlines
//! (`tokio::time::sleep_until`), so late ticks catch up instead of accumulating drift. Pacing
//! decides only *when* messages leave; the flight is the same for the same seed until the
//! companion's estimates start steering it after GNSS loss.
//!
//! In real time (`speed` > 0) the flight loop never waits on a peer: outgoing messages go
//! through a bounded queue with `try_send` (a full queue drops and counts), camera frames
//! likewise ([`super::frames`]). As fast as possible (`speed` = 0) it waits for the queue
//! instead, so that the link, not the queue, sets the pace and no message is lost.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use ianav::io::frame_stream::StreamAddress;
use mavlink::dialects::ardupilotmega as apm;
use mavlink::error::MessageReadError;
use mavlink::{AsyncMavConnection, MavHeader};
use tokio::sync::mpsc;
use tokio::time::Instant;

use super::frames::{self, FrameListener};
use super::vehicle::{EstimateRow, TimeBasis, Vehicle, VehicleConfig};
use crate::flight::{FlightError, FlightSetup};

/// Vehicle time advanced per loop iteration, µs (one 100 Hz sensor period).
pub const TICK_US: u64 = 10_000;
/// Outgoing messages that may wait for the socket.
pub const SEND_QUEUE: usize = 4096;

/// Where the frame stream listens.
#[derive(Debug)]
pub enum FramesListen {
    /// `host:port` or `unix:PATH` to bind (a Unix socket file left by an earlier run is
    /// replaced; the run removes its own when it ends).
    Addr(StreamAddress),
    /// An already bound listener (tests bind port 0 and read the port first).
    Listener(std::net::TcpListener),
}

/// Options of a SITL run.
#[derive(Debug)]
pub struct SitlOptions {
    /// MAVLink connection string (`udpout:`, `udpin:`, `tcpin:`, `tcpout:`).
    pub connect: String,
    /// Vehicle settings.
    pub vehicle: VehicleConfig,
    /// Simulated seconds per wall second (0: as fast as possible).
    pub speed: f64,
    /// Frame stream listener (with a camera set up).
    pub frames: Option<FramesListen>,
    /// Directory for `sitl.csv` (none: no log file).
    pub out_dir: Option<PathBuf>,
}

/// Errors of a SITL run.
#[derive(Debug, thiserror::Error)]
pub enum SitlError {
    /// The flight could not be set up or departed.
    #[error(transparent)]
    Flight(#[from] FlightError),
    /// The MAVLink link or the frame listener could not be opened.
    #[error("{what}")]
    Io {
        /// What failed.
        what: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Invalid option.
    #[error("{0}")]
    Option(String),
}

/// Live state handed to the progress callback once per simulated second.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Mission time, s.
    pub t_s: f64,
    /// Mission end, s.
    pub end_s: f64,
    /// Horizontal error of the latest companion estimate, m.
    pub hor_err_m: Option<f64>,
    /// Companion estimates in the last simulated second, Hz.
    pub estimate_rate_hz: f64,
    /// Whether guidance flies on the companion's position.
    pub aided: bool,
    /// How far the loop is behind its wall-clock schedule, s.
    pub lag_s: f64,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct SitlSummary {
    /// Mission time flown, s.
    pub mission_s: f64,
    /// Vehicle counters.
    pub vehicle: super::vehicle::VehicleStats,
    /// Messages written to the link.
    pub sent: u64,
    /// Messages dropped because the send queue was full.
    pub send_dropped: u64,
    /// Write errors of the link.
    pub send_errors: u64,
    /// Frames written to a frame-stream client.
    pub frames_sent: u64,
    /// Frames dropped (slow client).
    pub frames_dropped: u64,
    /// Frames produced while no client was connected.
    pub frames_without_client: u64,
    /// Wall time, s.
    pub wall_s: f64,
    /// Largest lag behind the wall-clock schedule, s.
    pub max_lag_s: f64,
    /// Mean companion estimate rate between the first and last estimate, Hz of vehicle time.
    pub estimate_rate_hz: Option<f64>,
    /// RMS horizontal error of the companion's estimates after GNSS loss, m.
    pub hor_err_rms_after_loss_m: Option<f64>,
    /// Horizontal error of the last companion estimate, m.
    pub last_hor_err_m: Option<f64>,
}

/// Bind a Unix socket at `path`, replacing a socket file an earlier run left there (but no
/// other kind of file).
fn bind_unix(path: &Path) -> Result<tokio::net::UnixListener, SitlError> {
    use std::os::unix::fs::FileTypeExt;
    let what = || format!("frame stream listener unix:{}", path.display());
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        if !meta.file_type().is_socket() {
            return Err(SitlError::Io {
                what: what(),
                source: std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    "a file that is not a socket is in the way",
                ),
            });
        }
        std::fs::remove_file(path).map_err(io_err(what()))?;
    }
    tokio::net::UnixListener::bind(path).map_err(io_err(what()))
}

fn io_err(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> SitlError {
    let what = what.into();
    move |source| SitlError::Io { what, source }
}

const CSV_HEADER: &str = "t_rx_s,t_valid_s,t_valid_us,time_basis,message,sysid,compid,truth_lat_deg,truth_lon_deg,truth_h_m,est_lat_deg,est_lon_deg,est_h_m,hor_err_m,ver_err_m,rate_hz,aided";

fn csv_row(r: &EstimateRow, warmup_us: u64) -> String {
    let mission = |t_us: u64| (t_us as f64 - warmup_us as f64) * 1e-6;
    format!(
        "{:.3},{:.6},{},{},{},{},{},{:.9},{:.9},{:.3},{:.9},{:.9},{:.3},{:.3},{:.3},{:.1},{}",
        mission(r.t_rx_us),
        mission(r.t_valid_us),
        r.t_valid_us,
        match r.basis {
            TimeBasis::Stamp => "stamp",
            TimeBasis::Timesync => "timesync",
            TimeBasis::Arrival => "arrival",
        },
        r.kind.name(),
        r.system_id,
        r.component_id,
        r.truth.lat_rad.to_degrees(),
        r.truth.lon_rad.to_degrees(),
        r.truth.h_m,
        r.estimate.lat_rad.to_degrees(),
        r.estimate.lon_rad.to_degrees(),
        r.estimate.h_m,
        r.hor_err_m,
        r.ver_err_m,
        r.rate_hz,
        u8::from(r.aided)
    )
}

/// Fly `setup` with `seed` as a MAVLink vehicle until the mission ends.
pub async fn run(
    setup: &FlightSetup,
    seed: u64,
    options: SitlOptions,
    mut progress: impl FnMut(&Progress, &[String]),
) -> Result<SitlSummary, SitlError> {
    if !(options.speed.is_finite() && options.speed >= 0.0) {
        return Err(SitlError::Option(format!(
            "speed must be a non-negative number, got {}",
            options.speed
        )));
    }
    let mut vehicle = Vehicle::new(setup, seed, options.vehicle)?;
    let cfg = options.vehicle;
    let header = MavHeader {
        system_id: u32::from(cfg.system_id),
        component_id: cfg.component_id,
        sequence: 0,
    };

    // The daemon's opening: TCP without Nagle's delay, UDP with a large receive buffer.
    let mut conn = ianav::daemon::transport::open(&options.connect)
        .await
        .map_err(io_err(format!("MAVLink link {}", options.connect)))?;
    // Older PX4 and pymavlink peers may speak MAVLink 1 until they hear version 2.
    conn.set_allow_recv_any_version(true);
    let conn = Arc::new(conn);

    let (in_tx, mut in_rx) = mpsc::channel::<(MavHeader, apm::MavMessage)>(SEND_QUEUE);
    let reader = {
        let conn = Arc::clone(&conn);
        tokio::spawn(async move {
            loop {
                match conn.recv().await {
                    Ok(m) => {
                        if in_tx.send(m).await.is_err() {
                            break;
                        }
                    }
                    // Malformed content is skipped; transport errors (a TCP peer gone) are
                    // retried slowly: the peer may come back on a UDP link.
                    Err(MessageReadError::Io(_)) => {
                        tokio::time::sleep(Duration::from_millis(100)).await
                    }
                    Err(_) => {}
                }
            }
        })
    };
    let (out_tx, mut out_rx) = mpsc::channel::<apm::MavMessage>(SEND_QUEUE);
    let writer = {
        let conn = Arc::clone(&conn);
        tokio::spawn(async move {
            let (mut sent, mut errors) = (0_u64, 0_u64);
            while let Some(msg) = out_rx.recv().await {
                match conn.send(&header, &msg).await {
                    Ok(_) => sent += 1,
                    Err(_) => errors += 1,
                }
            }
            (sent, errors)
        })
    };

    let mut frames_socket_file = None;
    let frame_server = match options.frames {
        None => None,
        Some(listen) => {
            let listener = match listen {
                FramesListen::Addr(StreamAddress::Tcp(addr)) => FrameListener::Tcp(
                    tokio::net::TcpListener::bind(&addr)
                        .await
                        .map_err(io_err(format!("frame stream listener {addr}")))?,
                ),
                FramesListen::Addr(StreamAddress::Unix(path)) => {
                    let listener = bind_unix(&path)?;
                    frames_socket_file = Some(path);
                    FrameListener::Unix(listener)
                }
                FramesListen::Listener(l) => {
                    l.set_nonblocking(true)
                        .map_err(io_err("frame stream listener"))?;
                    FrameListener::Tcp(
                        tokio::net::TcpListener::from_std(l)
                            .map_err(io_err("frame stream listener"))?,
                    )
                }
            };
            Some(frames::spawn(listener))
        }
    };
    let (mut frame_tx, frame_stats, frame_task) = match frame_server {
        Some((tx, stats, task)) => (Some(tx), Some(stats), Some(task)),
        None => (None, None, None),
    };

    let mut csv = match &options.out_dir {
        None => None,
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(io_err(format!("creating {}", dir.display())))?;
            let path = dir.join("sitl.csv");
            let file = std::fs::File::create(&path)
                .map_err(io_err(format!("creating {}", path.display())))?;
            let mut w = std::io::BufWriter::new(file);
            writeln!(w, "{CSV_HEADER}").map_err(io_err("writing sitl.csv"))?;
            Some(w)
        }
    };

    let warmup_us = vehicle.flight().warmup_us();
    let loss_us = vehicle.flight().gnss_loss_t_us();
    let end_s = vehicle.flight().end_time_s();
    let t0_us = vehicle.t_us();
    let started = Instant::now();
    let (mut send_dropped, mut max_lag_s, mut lag_s) = (0_u64, 0.0_f64, 0.0_f64);
    let (mut last_err, mut err_sq_sum, mut err_n) = (None, 0.0, 0_u64);
    let mut next_progress_us = t0_us;
    let mut result: Result<(), SitlError> = Ok(());
    'flight: while !vehicle.finished() {
        while let Ok((h, m)) = in_rx.try_recv() {
            vehicle.handle(&h, &m);
        }
        if let Err(e) = vehicle.advance_to(vehicle.t_us() + TICK_US) {
            result = Err(e.into());
            break;
        }
        for msg in vehicle.take_outbox() {
            if options.speed == 0.0 {
                // As fast as possible: the link sets the pace, nothing is dropped.
                if out_tx.send(msg).await.is_err() {
                    send_dropped += 1;
                }
            } else if out_tx.try_send(msg).is_err() {
                send_dropped += 1;
            }
        }
        for frame in vehicle.take_frames() {
            if let Some(tx) = frame_tx.as_mut() {
                tx.offer(frame);
            }
        }
        for row in vehicle.take_rows() {
            last_err = Some(row.hor_err_m);
            if row.t_valid_us > loss_us {
                err_sq_sum += row.hor_err_m * row.hor_err_m;
                err_n += 1;
            }
            if let Some(w) = csv.as_mut()
                && let Err(e) = writeln!(w, "{}", csv_row(&row, warmup_us))
            {
                result = Err(SitlError::Io {
                    what: "writing sitl.csv".to_owned(),
                    source: e,
                });
                break 'flight;
            }
        }
        let notices = vehicle.take_notices();
        let t_us = vehicle.t_us();
        if t_us >= next_progress_us || !notices.is_empty() {
            if t_us >= next_progress_us {
                next_progress_us += 1_000_000;
            }
            progress(
                &Progress {
                    t_s: vehicle.flight().mission_time_s(),
                    end_s,
                    hor_err_m: last_err,
                    estimate_rate_hz: vehicle.estimate_rate_hz(),
                    aided: vehicle.aided(),
                    lag_s,
                },
                &notices,
            );
        }
        if options.speed > 0.0 {
            let due =
                started + Duration::from_secs_f64((t_us - t0_us) as f64 * 1e-6 / options.speed);
            let now = Instant::now();
            if due > now {
                lag_s = 0.0;
                tokio::time::sleep_until(due).await;
            } else {
                lag_s = (now - due).as_secs_f64() * options.speed;
                max_lag_s = max_lag_s.max(lag_s);
                tokio::task::yield_now().await;
            }
        } else {
            tokio::task::yield_now().await;
        }
    }
    // Let the last messages leave, then stop the tasks.
    drop(out_tx);
    let (sent, send_errors) = match tokio::time::timeout(Duration::from_secs(2), writer).await {
        Ok(Ok(counts)) => counts,
        _ => (0, 0),
    };
    reader.abort();
    drop(frame_tx);
    if let Some(task) = frame_task {
        let _ = tokio::time::timeout(Duration::from_secs(3), task).await;
    }
    if let Some(path) = frames_socket_file {
        let _ = std::fs::remove_file(path);
    }
    if let Some(mut w) = csv {
        w.flush().map_err(io_err("writing sitl.csv"))?;
    }
    result?;
    let stats = vehicle.stats().clone();
    let estimate_rate_hz = stats
        .estimate_span_us
        .filter(|(a, b)| b > a)
        .map(|(a, b)| (stats.estimates - 1) as f64 / ((b - a) as f64 * 1e-6));
    let load = |f: fn(&frames::FrameStats) -> &std::sync::atomic::AtomicU64| {
        frame_stats
            .as_ref()
            .map_or(0, |s| f(s).load(Ordering::Relaxed))
    };
    Ok(SitlSummary {
        mission_s: vehicle.flight().mission_time_s(),
        vehicle: stats,
        sent,
        send_dropped,
        send_errors,
        frames_sent: load(|s| &s.sent),
        frames_dropped: load(|s| &s.dropped),
        frames_without_client: load(|s| &s.without_client),
        wall_s: started.elapsed().as_secs_f64(),
        max_lag_s,
        estimate_rate_hz,
        hor_err_rms_after_loss_m: (err_n > 0).then(|| (err_sq_sum / err_n as f64).sqrt()),
        last_hor_err_m: last_err,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_stale_socket_file_is_replaced_and_any_other_file_refused() {
        let dir = std::env::temp_dir().join(format!("ianav-sitl-unix-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join("frames.sock");
        let _ = std::fs::remove_file(&path);
        // A listener dropped without removing its file leaves a stale socket behind.
        drop(bind_unix(&path).expect("first bind"));
        assert!(path.exists());
        let listener = bind_unix(&path).expect("bind over the stale socket");
        let client = tokio::net::UnixStream::connect(&path).await;
        assert!(client.is_ok(), "the new listener serves: {client:?}");
        drop(listener);
        // A regular file at the path is never deleted.
        std::fs::remove_file(&path).expect("remove");
        std::fs::write(&path, b"not a socket").expect("write");
        let e = bind_unix(&path).expect_err("a regular file refused");
        assert!(e.to_string().contains("frames.sock"), "{e}");
        assert_eq!(std::fs::read(&path).expect("still there"), b"not a socket");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
