//! Camera frame stream between the vehicle (the simulator in SITL) and the daemon (docs/DAEMON.md
//! "Camera sources"; docs/REFERENCES.md M4): length-prefixed 8-bit grey frames over a byte
//! stream, timestamped in the vehicle's clock. The stream is TCP (`host:port`) or, between
//! processes of one machine, a Unix stream socket (`unix:PATH`, [`StreamAddress`]).
//!
//! Wire format, little-endian, one record per frame:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `b"IANF"` |
//! | 4 | 2 | version (1) |
//! | 6 | 2 | pixel format (1 = 8-bit grey, row-major) |
//! | 8 | 4 | sequence number (wraps) |
//! | 12 | 4 | width, px |
//! | 16 | 4 | height, px |
//! | 20 | 8 | exposure time, µs in the vehicle's clock (the autopilot's `time_usec` base) |
//! | 28 | 4 | payload length, bytes (= width × height) |
//! | 32 | … | payload |
//!
//! The header is validated before any payload is read, so a corrupt or hostile stream can
//! never make the reader allocate more than [`MAX_PAYLOAD_BYTES`].

use std::fmt;
use std::io::{self, Read, Write};
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::Arc;

use crate::sensors::Frame;

/// Record magic.
pub const MAGIC: [u8; 4] = *b"IANF";
/// Protocol version this module writes and reads.
pub const VERSION: u16 = 1;
/// Pixel format code of 8-bit grey, row-major.
pub const FORMAT_GREY8: u16 = 1;
/// Header size, bytes.
pub const HEADER_BYTES: usize = 32;
/// Largest accepted image side, px.
pub const MAX_SIDE_PX: u32 = 8_192;
/// Largest accepted payload, bytes (a 4,096 × 4,096 grey image).
pub const MAX_PAYLOAD_BYTES: usize = 4_096 * 4_096;

/// Header of one frame record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    /// Sequence number set by the sender (gaps mean frames dropped upstream).
    pub seq: u32,
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Exposure time in the vehicle's clock, µs.
    pub t_us: u64,
    /// Payload length, bytes.
    pub payload_bytes: u32,
}

/// Why a frame record was refused.
#[derive(Debug, thiserror::Error)]
pub enum FrameStreamError {
    /// The stream is not aligned on a record (or is not a frame stream at all).
    #[error("frame stream: bad magic {0:02x?}")]
    BadMagic([u8; 4]),
    /// A newer or unknown protocol version.
    #[error("frame stream: unsupported version {0}")]
    UnsupportedVersion(u16),
    /// A pixel format this reader does not handle.
    #[error("frame stream: unsupported pixel format {0}")]
    UnsupportedFormat(u16),
    /// Zero or oversized dimensions, or a payload length that does not match them.
    #[error("frame stream: bad geometry {width}×{height} with {payload_bytes} payload bytes")]
    BadGeometry {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
        /// Declared payload, bytes.
        payload_bytes: u32,
    },
    /// The underlying stream failed (or ended inside a record).
    #[error("frame stream: {0}")]
    Io(#[from] io::Error),
}

/// Where a frame stream is served and read.
///
/// A Unix socket serves the SITL vehicle and the daemon on one machine: loopback TCP made the
/// reader wait on the socket lock the writer holds while it copies a frame in, which showed as
/// milliseconds on the daemon's IMU path (docs/PERFORMANCE.md "Where the IMU tail is").
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StreamAddress {
    /// `host:port` over TCP.
    Tcp(String),
    /// `unix:PATH`: a Unix stream socket at `PATH`.
    Unix(PathBuf),
}

/// The prefix that marks a Unix socket path in a [`StreamAddress`].
pub const UNIX_PREFIX: &str = "unix:";

/// A frame stream address that is neither `host:port` nor `unix:PATH`.
#[derive(Debug, thiserror::Error)]
#[error("frame stream address {0:?}: expected host:port or unix:PATH")]
pub struct AddressError(pub String);

impl FromStr for StreamAddress {
    type Err = AddressError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if let Some(path) = s.strip_prefix(UNIX_PREFIX) {
            if path.is_empty() {
                return Err(AddressError(s.to_owned()));
            }
            return Ok(Self::Unix(PathBuf::from(path)));
        }
        // host:port with a non-empty host and a port number (IPv6 hosts in brackets).
        let valid = s
            .rsplit_once(':')
            .is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok());
        if valid {
            Ok(Self::Tcp(s.to_owned()))
        } else {
            Err(AddressError(s.to_owned()))
        }
    }
}

impl fmt::Display for StreamAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Tcp(a) => f.write_str(a),
            Self::Unix(p) => write!(f, "{UNIX_PREFIX}{}", p.display()),
        }
    }
}

impl FrameHeader {
    /// Header of `frame` with sequence number `seq`.
    pub fn of(frame: &Frame, seq: u32) -> Self {
        Self {
            seq,
            width: frame.width,
            height: frame.height,
            t_us: frame.t_us,
            payload_bytes: u32::try_from(frame.pixels.len()).unwrap_or(u32::MAX),
        }
    }

    /// The 32 header bytes.
    pub fn encode(&self) -> [u8; HEADER_BYTES] {
        let mut b = [0_u8; HEADER_BYTES];
        b[0..4].copy_from_slice(&MAGIC);
        b[4..6].copy_from_slice(&VERSION.to_le_bytes());
        b[6..8].copy_from_slice(&FORMAT_GREY8.to_le_bytes());
        b[8..12].copy_from_slice(&self.seq.to_le_bytes());
        b[12..16].copy_from_slice(&self.width.to_le_bytes());
        b[16..20].copy_from_slice(&self.height.to_le_bytes());
        b[20..28].copy_from_slice(&self.t_us.to_le_bytes());
        b[28..32].copy_from_slice(&self.payload_bytes.to_le_bytes());
        b
    }

    /// Parse and validate 32 header bytes.
    pub fn decode(b: &[u8; HEADER_BYTES]) -> Result<Self, FrameStreamError> {
        let u16_at = |i: usize| u16::from_le_bytes([b[i], b[i + 1]]);
        let u32_at = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        let magic = [b[0], b[1], b[2], b[3]];
        if magic != MAGIC {
            return Err(FrameStreamError::BadMagic(magic));
        }
        let version = u16_at(4);
        if version != VERSION {
            return Err(FrameStreamError::UnsupportedVersion(version));
        }
        let format = u16_at(6);
        if format != FORMAT_GREY8 {
            return Err(FrameStreamError::UnsupportedFormat(format));
        }
        let mut t = [0_u8; 8];
        t.copy_from_slice(&b[20..28]);
        let header = Self {
            seq: u32_at(8),
            width: u32_at(12),
            height: u32_at(16),
            t_us: u64::from_le_bytes(t),
            payload_bytes: u32_at(28),
        };
        let (w, h) = (header.width, header.height);
        let sides_ok = (1..=MAX_SIDE_PX).contains(&w) && (1..=MAX_SIDE_PX).contains(&h);
        let expected = u64::from(w) * u64::from(h);
        if !sides_ok
            || expected != u64::from(header.payload_bytes)
            || header.payload_bytes as usize > MAX_PAYLOAD_BYTES
        {
            return Err(FrameStreamError::BadGeometry {
                width: w,
                height: h,
                payload_bytes: header.payload_bytes,
            });
        }
        Ok(header)
    }
}

/// Write one frame record.
pub fn write_frame(w: &mut impl Write, frame: &Frame, seq: u32) -> Result<(), FrameStreamError> {
    let header = FrameHeader::of(frame, seq);
    // Refuse to send what a reader would refuse.
    FrameHeader::decode(&header.encode())?;
    w.write_all(&header.encode())?;
    w.write_all(&frame.pixels)?;
    Ok(())
}

/// Read one frame record. `Ok(None)` on a clean end of stream (between records).
pub fn read_frame(r: &mut impl Read) -> Result<Option<(FrameHeader, Frame)>, FrameStreamError> {
    let mut b = [0_u8; HEADER_BYTES];
    // Distinguish a clean end (no byte of a new record) from a truncated header.
    let mut got = 0;
    while got < HEADER_BYTES {
        match r.read(&mut b[got..]) {
            Ok(0) if got == 0 => return Ok(None),
            Ok(0) => return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into()),
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e.into()),
        }
    }
    let header = FrameHeader::decode(&b)?;
    let mut pixels = vec![0_u8; header.payload_bytes as usize];
    r.read_exact(&mut pixels)?;
    let frame = Frame {
        t_us: header.t_us,
        width: header.width,
        height: header.height,
        pixels: Arc::from(pixels),
    };
    Ok(Some((header, frame)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_are_host_port_or_a_unix_path() {
        let tcp: StreamAddress = "127.0.0.1:5600".parse().expect("tcp");
        assert_eq!(tcp, StreamAddress::Tcp("127.0.0.1:5600".into()));
        assert!(matches!("[::1]:5600".parse(), Ok(StreamAddress::Tcp(_))));
        assert!(matches!(
            "localhost:5600".parse(),
            Ok(StreamAddress::Tcp(_))
        ));
        let unix: StreamAddress = "unix:/run/ianav/frames.sock".parse().expect("unix");
        assert_eq!(unix, StreamAddress::Unix("/run/ianav/frames.sock".into()));
        assert_eq!(unix.to_string(), "unix:/run/ianav/frames.sock");
        for bad in [
            "",
            "5600",
            ":5600",
            "host:",
            "host:port",
            "host:70000",
            "unix:",
        ] {
            assert!(bad.parse::<StreamAddress>().is_err(), "{bad:?} accepted");
        }
    }

    fn frame(t_us: u64, w: u32, h: u32) -> Frame {
        let pixels: Vec<u8> = (0..w * h).map(|i| (i % 251) as u8).collect();
        Frame {
            t_us,
            width: w,
            height: h,
            pixels: Arc::from(pixels),
        }
    }

    #[test]
    fn frames_round_trip_and_the_stream_ends_cleanly() {
        let mut buf = Vec::new();
        let a = frame(1_000, 3, 2);
        let b = frame(u64::MAX - 1, 5, 7);
        write_frame(&mut buf, &a, 0).unwrap();
        write_frame(&mut buf, &b, u32::MAX).unwrap();
        assert_eq!(buf.len(), 2 * HEADER_BYTES + 6 + 35);
        let mut r = buf.as_slice();
        let (ha, fa) = read_frame(&mut r).unwrap().unwrap();
        let (hb, fb) = read_frame(&mut r).unwrap().unwrap();
        assert_eq!((ha.seq, hb.seq), (0, u32::MAX));
        assert_eq!((fa, fb), (a, b));
        assert!(read_frame(&mut r).unwrap().is_none());
    }

    #[test]
    fn corrupt_headers_are_refused_before_any_allocation() {
        let mut buf = Vec::new();
        write_frame(&mut buf, &frame(5, 4, 4), 1).unwrap();
        let good: [u8; HEADER_BYTES] = buf[..HEADER_BYTES].try_into().unwrap();
        let with = |i: usize, v: u8| {
            let mut b = good;
            b[i] = v;
            FrameHeader::decode(&b)
        };
        assert!(matches!(with(0, b'X'), Err(FrameStreamError::BadMagic(_))));
        assert!(matches!(
            with(4, 9),
            Err(FrameStreamError::UnsupportedVersion(9))
        ));
        assert!(matches!(
            with(6, 3),
            Err(FrameStreamError::UnsupportedFormat(3))
        ));
        // Width 0, a payload that disagrees with the geometry, and a 4 GB claim.
        assert!(matches!(
            with(12, 0),
            Err(FrameStreamError::BadGeometry { .. })
        ));
        assert!(matches!(
            with(28, 17),
            Err(FrameStreamError::BadGeometry { .. })
        ));
        let mut huge = good;
        huge[12..16].copy_from_slice(&8_192_u32.to_le_bytes());
        huge[16..20].copy_from_slice(&8_192_u32.to_le_bytes());
        huge[28..32].copy_from_slice(&(8_192_u32 * 8_192).to_le_bytes());
        assert!(matches!(
            FrameHeader::decode(&huge),
            Err(FrameStreamError::BadGeometry { .. })
        ));
    }

    #[test]
    fn a_stream_cut_inside_a_record_is_an_error_not_an_end() {
        let mut buf = Vec::new();
        write_frame(&mut buf, &frame(5, 4, 4), 1).unwrap();
        for cut in [1, HEADER_BYTES - 1, HEADER_BYTES + 3] {
            let mut r = &buf[..cut];
            assert!(matches!(read_frame(&mut r), Err(FrameStreamError::Io(_))));
        }
    }
}
