//! The `frame_stream` camera source (docs/REFERENCES.md M4): client of the vehicle's frame
//! stream ([`crate::io::frame_stream`]) over TCP or a Unix socket, on a thread of its own.
//!
//! Why not a tokio task: a 768 × 1024 frame arrives as a run of reads that kept a tokio worker
//! busy for milliseconds while the sender was still writing it, and a worker busy in a task
//! polls no other socket (the MAVLink link shares the runtime). Each frame is read straight
//! into the shared buffer the navigation gets: one allocation, no copy (docs/PERFORMANCE.md
//! "Daemon with vision").
//!
//! Exposure times are in the vehicle's clock and are mapped with the time-sync offset; frames
//! that arrive before an offset is known, out of order, or more than 1 s in the future are
//! refused and counted. An absent server is retried with exponential back-off (0.2 s doubling up
//! to `camera.retry_max_s`); a frame that takes longer than 3 × `camera.timeout_s` to arrive is
//! taken as a silent stream and the connection is reopened.

use std::io::{ErrorKind, Read};
use std::net::{TcpStream, ToSocketAddrs};
#[cfg(unix)]
use std::os::unix::net::UnixStream;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::watch;

use super::Clock;
use super::camera::{Out, wait_unless_stopped};
use crate::daemon::config::{ClockSource, DaemonConfig};
use crate::io::frame_stream::{FrameHeader, HEADER_BYTES, StreamAddress};
use crate::sensors::Frame;

/// How often a blocked read looks at the stop signal.
const POLL: Duration = Duration::from_millis(100);

/// Why a frame could not be read.
enum ReadFailure {
    /// The daemon is stopping.
    Stopped,
    /// Nothing complete within the silence limit.
    Silent,
    /// The connection failed or sent something that is not a frame.
    Io(std::io::Error),
}

/// Read and deliver frames until stopped (blocking; run on its own thread).
pub(super) fn run_blocking(
    cfg: Arc<DaemonConfig>,
    clock: Clock,
    out: Out,
    stop: watch::Receiver<bool>,
) {
    let shared = out.shared.clone();
    let autopilot_clock = cfg.mavlink.clock == ClockSource::Autopilot;
    let max_backoff = Duration::from_secs_f64(cfg.camera.retry_max_s);
    let silence = Duration::from_secs_f64(3.0 * cfg.camera.timeout_s);
    let address = match cfg.camera.address.parse::<StreamAddress>() {
        Ok(a) => a,
        Err(e) => {
            // The configuration is validated at load; this is a daemon built around a bad one.
            tracing::error!("camera: {e}");
            shared.count(|c| c.camera_errors += 1);
            return;
        }
    };
    let address = &address;
    let mut backoff = Duration::from_millis(200);
    let mut last_t_us: Option<u64> = None;
    let mut failures = 0_u64;
    while !*stop.borrow() {
        let mut sock = match connect(address) {
            Ok(s) => s,
            Err(e) => {
                failures += 1;
                // Log the first failure and then every 10th, not every attempt.
                if failures % 10 == 1 {
                    tracing::warn!("camera {address}: {e} (retrying)");
                }
                shared.count(|c| c.camera_errors += 1);
                if wait_unless_stopped(&stop, backoff) {
                    return;
                }
                backoff = (backoff * 2).min(max_backoff);
                continue;
            }
        };
        failures = 0;
        backoff = Duration::from_millis(200);
        shared.count(|c| c.camera_connects += 1);
        tracing::info!("camera frame stream connected: {address}");
        loop {
            let (header, pixels) = match read_frame(&mut sock, &stop, silence) {
                Ok(x) => x,
                Err(ReadFailure::Stopped) => return,
                Err(ReadFailure::Io(e)) => {
                    tracing::warn!("camera stream: {e} (reconnecting)");
                    shared.count(|c| c.camera_errors += 1);
                    break;
                }
                Err(ReadFailure::Silent) => {
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
                pixels,
            };
            out.deliver(f, now);
        }
        if wait_unless_stopped(&stop, backoff) {
            return;
        }
    }
}

/// A connected frame stream.
enum Connection {
    Tcp(TcpStream),
    #[cfg(unix)]
    Unix(UnixStream),
}

impl Read for Connection {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Self::Tcp(s) => s.read(buf),
            #[cfg(unix)]
            Self::Unix(s) => s.read(buf),
        }
    }
}

/// Connect to the stream, with a read timeout of [`POLL`] so that reads can watch the stop
/// signal.
fn connect(address: &StreamAddress) -> std::io::Result<Connection> {
    match address {
        StreamAddress::Tcp(a) => connect_tcp(a).map(Connection::Tcp),
        #[cfg(unix)]
        StreamAddress::Unix(path) => {
            let s = UnixStream::connect(path)?;
            s.set_read_timeout(Some(POLL))?;
            Ok(Connection::Unix(s))
        }
        #[cfg(not(unix))]
        StreamAddress::Unix(_) => Err(std::io::Error::new(
            ErrorKind::Unsupported,
            "Unix sockets need a Unix system",
        )),
    }
}

/// Connect to the first address `address` resolves to that accepts.
fn connect_tcp(address: &str) -> std::io::Result<TcpStream> {
    let mut last = std::io::Error::new(ErrorKind::NotFound, "the address resolves to nothing");
    for addr in address.to_socket_addrs()? {
        match TcpStream::connect_timeout(&addr, Duration::from_secs(2)) {
            Ok(s) => {
                s.set_read_timeout(Some(POLL))?;
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) => last = e,
        }
    }
    Err(last)
}

/// One frame record: its header and its pixels, read into the buffer the frame will share.
fn read_frame(
    sock: &mut impl Read,
    stop: &watch::Receiver<bool>,
    silence: Duration,
) -> Result<(FrameHeader, Arc<[u8]>), ReadFailure> {
    let deadline = Instant::now() + silence;
    let mut h = [0_u8; HEADER_BYTES];
    fill(sock, &mut h, stop, deadline)?;
    let header = FrameHeader::decode(&h)
        .map_err(|e| ReadFailure::Io(std::io::Error::new(ErrorKind::InvalidData, e)))?;
    // `decode` bounds the payload (MAX_PAYLOAD_BYTES): one allocation, filled in place.
    let mut pixels: Arc<[u8]> = std::iter::repeat_n(0_u8, header.payload_bytes as usize).collect();
    let Some(buf) = Arc::get_mut(&mut pixels) else {
        // A fresh Arc has no other owner; unreachable, but never a panic on the camera path.
        return Err(ReadFailure::Io(std::io::Error::other(
            "frame buffer shared",
        )));
    };
    fill(sock, buf, stop, deadline)?;
    Ok((header, pixels))
}

/// Fill `buf` from the socket, watching the stop signal and the deadline before each read.
fn fill(
    sock: &mut impl Read,
    buf: &mut [u8],
    stop: &watch::Receiver<bool>,
    deadline: Instant,
) -> Result<(), ReadFailure> {
    let mut filled = 0;
    while filled < buf.len() {
        if *stop.borrow() {
            return Err(ReadFailure::Stopped);
        }
        if Instant::now() >= deadline {
            return Err(ReadFailure::Silent);
        }
        match sock.read(&mut buf[filled..]) {
            Ok(0) => {
                return Err(ReadFailure::Io(std::io::Error::new(
                    ErrorKind::UnexpectedEof,
                    "the stream ended",
                )));
            }
            Ok(n) => filled += n,
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(ReadFailure::Io(e)),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::frame_stream::write_frame;
    use std::io::Write;
    use std::net::TcpListener;

    /// A connected pair on loopback: (the daemon's side, the sender's side).
    fn pair() -> (Connection, TcpStream) {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
        let address = StreamAddress::Tcp(listener.local_addr().expect("address").to_string());
        let client = connect(&address).expect("connect");
        let (server, _) = listener.accept().expect("accept");
        (client, server)
    }

    fn frame(t_us: u64) -> Frame {
        Frame {
            t_us,
            width: 64,
            height: 48,
            pixels: (0..64 * 48).map(|i| (i % 251) as u8).collect(),
        }
    }

    #[test]
    fn frames_sent_in_pieces_arrive_whole_and_in_order() {
        let (mut client, mut server) = pair();
        let (_stop_tx, stop) = watch::channel(false);
        let sender = std::thread::spawn(move || {
            for t in [10, 20] {
                let mut bytes = Vec::new();
                write_frame(&mut bytes, &frame(t), 0).expect("encode");
                // In three pieces with pauses, as a busy sender writes.
                for piece in bytes.chunks(bytes.len() / 3 + 1) {
                    server.write_all(piece).expect("send");
                    std::thread::sleep(Duration::from_millis(30));
                }
            }
        });
        for t in [10, 20] {
            let Ok((header, pixels)) = read_frame(&mut client, &stop, Duration::from_secs(5))
            else {
                panic!("frame {t} not read");
            };
            assert_eq!(header.t_us, t);
            assert_eq!((header.width, header.height), (64, 48));
            assert_eq!(&pixels[..], &frame(t).pixels[..]);
        }
        sender.join().expect("sender");
    }

    #[cfg(unix)]
    #[test]
    fn frames_arrive_over_a_unix_socket_and_its_silence_is_seen() {
        let dir = std::env::temp_dir().join(format!("ianav-frames-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join("frames.sock");
        let _ = std::fs::remove_file(&path);
        let listener = std::os::unix::net::UnixListener::bind(&path).expect("bind");
        let address: StreamAddress = format!("unix:{}", path.display()).parse().expect("address");
        let mut client = connect(&address).expect("connect");
        let (mut server, _) = listener.accept().expect("accept");
        let (_stop_tx, stop) = watch::channel(false);
        let mut bytes = Vec::new();
        write_frame(&mut bytes, &frame(7), 3).expect("encode");
        server.write_all(&bytes).expect("send");
        let Ok((header, pixels)) = read_frame(&mut client, &stop, Duration::from_secs(5)) else {
            panic!("frame not read");
        };
        assert_eq!((header.t_us, header.seq), (7, 3));
        assert_eq!(&pixels[..], &frame(7).pixels[..]);
        // Nothing more: silence within the deadline (the read timeout applies here too).
        let r = read_frame(&mut client, &stop, Duration::from_millis(300));
        assert!(matches!(r, Err(ReadFailure::Silent)));
        drop(server);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_frame_cut_short_is_silence_and_a_stop_ends_the_read() {
        let (mut client, mut server) = pair();
        let mut bytes = Vec::new();
        write_frame(&mut bytes, &frame(1), 0).expect("encode");
        server.write_all(&bytes[..bytes.len() / 2]).expect("send");
        let (stop_tx, stop) = watch::channel(false);
        let t0 = Instant::now();
        let r = read_frame(&mut client, &stop, Duration::from_millis(300));
        assert!(matches!(r, Err(ReadFailure::Silent)));
        // The deadline is seen within a read timeout of it.
        assert!(t0.elapsed() < Duration::from_millis(300) + 3 * POLL);

        stop_tx.send_replace(true);
        let r = read_frame(&mut client, &stop, Duration::from_secs(60));
        assert!(matches!(r, Err(ReadFailure::Stopped)));

        // A closed stream and a header that is not a frame are I/O failures.
        let (mut client, mut server) = pair();
        let (_stop_tx, stop) = watch::channel(false);
        server.write_all(&[0_u8; HEADER_BYTES]).expect("send");
        let r = read_frame(&mut client, &stop, Duration::from_secs(5));
        assert!(matches!(r, Err(ReadFailure::Io(e)) if e.kind() == ErrorKind::InvalidData));
        drop(server);
        let r = read_frame(&mut client, &stop, Duration::from_secs(5));
        assert!(matches!(r, Err(ReadFailure::Io(e)) if e.kind() == ErrorKind::UnexpectedEof));
    }
}
