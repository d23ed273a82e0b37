//! Compact binary log of [`SensorEvent`]s, so that a flight's sensor samples can be stored,
//! read back bit for bit, and replayed into the navigation core.
//!
//! Layout (all integers and floats little-endian):
//! - header: the 8 bytes `IANAVLOG`, then `u16` format version, then `u16` reserved (0);
//! - records: `u8` kind, `u32` payload length in bytes, payload. Every payload starts with the
//!   `u64` time `t_us`; then `f64` values:
//!   - 1 IMU: gyro x y z (rad/s), accel x y z (m/s²);
//!   - 2 air: `u8` flags (bit 0 AoA present, bit 1 AoS present), TAS (m/s), AoA (rad), AoS (rad),
//!     static pressure (Pa), temperature (K); absent vane values are stored as 0;
//!   - 3 magnetometer: x y z (nT);
//!   - 4 GNSS: lat (rad), lon (rad), h (m), v N E D (m/s), σ horizontal, σ vertical (m),
//!     σ velocity (m/s);
//!   - 5 frame: `u32` width, `u32` height, then width·height grey bytes;
//!   - 6 reference attitude: unit quaternion body → NED, w i j k;
//!   - 7 start alignment: unit quaternion body → NED (w i j k), AoA (rad), then the sensor-error
//!     priors `E_gyr` and its σ (rad/s), `E_acc` and σ (m/s²), `E_mag` and σ (nT), `ΔB_n` and
//!     σ (nT), three values each;
//!   - 8 navigation configuration: `t_us` 0, then the navigator's settings (`nav::NavConfig`) as
//!     UTF-8 TOML. Written once, right after the header, by the simulator and by `ianav run
//!     --record`, so that `ianav replay` runs a log with the settings it was flown with;
//!   - 9 height over the terrain: height (m), its σ (m);
//!   - 10 a deferred frame's visual navigation handed back to the navigator: the frame's time
//!     only (`nav::NavConfig::vision_deferred`; a replay applies the result there).
//!
//! Readers skip record kinds they do not know (the length says how far), so the format can
//! grow without breaking old readers.

use std::io::{self, Read, Write};
use std::sync::Arc;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::math::wgs84::Geodetic;
use crate::sensors::{
    AirSample, Alignment, Frame, GnssFix, HeightAboveTerrain, ImuSample, MagSample, RefAttitude,
    SensorErrorPriors, SensorEvent, VisionApplied,
};

/// File magic.
pub const MAGIC: &[u8; 8] = b"IANAVLOG";
/// Current format version.
pub const VERSION: u16 = 1;
/// Largest accepted record payload (a 4096 × 4096 frame plus its header), bytes.
const MAX_PAYLOAD: u32 = 4096 * 4096 + 16;

const KIND_IMU: u8 = 1;
const KIND_AIR: u8 = 2;
const KIND_MAG: u8 = 3;
const KIND_GNSS: u8 = 4;
const KIND_FRAME: u8 = 5;
const KIND_REF_ATTITUDE: u8 = 6;
const KIND_ALIGNMENT: u8 = 7;
const KIND_NAV_CONFIG: u8 = 8;
const KIND_HEIGHT_ABOVE_TERRAIN: u8 = 9;
const KIND_VISION_APPLIED: u8 = 10;

/// Errors reading a sensor log.
#[derive(Debug, thiserror::Error)]
pub enum SensorLogError {
    /// Underlying I/O failure.
    #[error("sensor log I/O: {0}")]
    Io(#[from] io::Error),
    /// The file does not start with the magic, or has an unknown version.
    #[error("not an ianav sensor log (bad magic or version {0})")]
    BadHeader(u16),
    /// A record is shorter than its kind requires, or longer than any valid record.
    #[error("corrupt record of kind {kind} with {len} payload bytes")]
    BadRecord {
        /// Record kind.
        kind: u8,
        /// Declared payload length.
        len: u32,
    },
}

/// Writes events to any [`Write`] (wrap files in a `BufWriter`).
#[derive(Debug)]
pub struct SensorLogWriter<W: Write> {
    out: W,
    payload: Vec<u8>,
}

impl<W: Write> SensorLogWriter<W> {
    /// Start a log: writes the header.
    pub fn new(mut out: W) -> io::Result<Self> {
        out.write_all(MAGIC)?;
        out.write_all(&VERSION.to_le_bytes())?;
        out.write_all(&0_u16.to_le_bytes())?;
        Ok(Self {
            out,
            payload: Vec::with_capacity(128),
        })
    }

    /// Append one event.
    pub fn write(&mut self, event: &SensorEvent) -> io::Result<()> {
        let p = &mut self.payload;
        p.clear();
        p.extend_from_slice(&event.t_us().to_le_bytes());
        let mut put = |values: &[f64]| {
            for v in values {
                p.extend_from_slice(&v.to_le_bytes());
            }
        };
        let kind = match event {
            SensorEvent::Imu(s) => {
                put(s.gyro_rps.as_slice());
                put(s.accel_mps2.as_slice());
                KIND_IMU
            }
            SensorEvent::Air(s) => {
                let flags = u8::from(s.aoa_rad.is_some()) | (u8::from(s.aos_rad.is_some()) << 1);
                self.payload.push(flags);
                let p = &mut self.payload;
                for v in [
                    s.tas_mps,
                    s.aoa_rad.unwrap_or(0.0),
                    s.aos_rad.unwrap_or(0.0),
                    s.p_pa,
                    s.temp_k,
                ] {
                    p.extend_from_slice(&v.to_le_bytes());
                }
                KIND_AIR
            }
            SensorEvent::Mag(s) => {
                put(s.mag_b_nt.as_slice());
                KIND_MAG
            }
            SensorEvent::Gnss(s) => {
                put(&[s.pos.lat_rad, s.pos.lon_rad, s.pos.h_m]);
                put(s.v_ned_mps.as_slice());
                put(&[s.sigma_hor_m, s.sigma_ver_m, s.sigma_vel_mps]);
                KIND_GNSS
            }
            SensorEvent::Frame(f) => {
                p.extend_from_slice(&f.width.to_le_bytes());
                p.extend_from_slice(&f.height.to_le_bytes());
                p.extend_from_slice(&f.pixels);
                KIND_FRAME
            }
            SensorEvent::RefAttitude(a) => {
                let q = a.q_nb.quaternion();
                put(&[q.w, q.i, q.j, q.k]);
                KIND_REF_ATTITUDE
            }
            SensorEvent::Alignment(a) => {
                let q = a.q_nb.quaternion();
                put(&[q.w, q.i, q.j, q.k, a.aoa_rad]);
                let e = &a.priors;
                for v in [
                    &e.e_gyr_rps,
                    &e.e_gyr_sigma_rps,
                    &e.e_acc_mps2,
                    &e.e_acc_sigma_mps2,
                    &e.e_mag_nt,
                    &e.e_mag_sigma_nt,
                    &e.delta_b_n_nt,
                    &e.delta_b_n_sigma_nt,
                ] {
                    put(v.as_slice());
                }
                KIND_ALIGNMENT
            }
            SensorEvent::HeightAboveTerrain(h) => {
                put(&[h.h_agl_m, h.sigma_m]);
                KIND_HEIGHT_ABOVE_TERRAIN
            }
            SensorEvent::VisionApplied(_) => KIND_VISION_APPLIED,
        };
        let len = u32::try_from(self.payload.len())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "record too large"))?;
        self.out.write_all(&[kind])?;
        self.out.write_all(&len.to_le_bytes())?;
        self.out.write_all(&self.payload)
    }

    /// Record the navigator's settings (TOML); call once, before the first event.
    pub fn write_nav_config(&mut self, toml_text: &str) -> io::Result<()> {
        let len = u32::try_from(8 + toml_text.len())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "record too large"))?;
        self.out.write_all(&[KIND_NAV_CONFIG])?;
        self.out.write_all(&len.to_le_bytes())?;
        self.out.write_all(&0_u64.to_le_bytes())?;
        self.out.write_all(toml_text.as_bytes())
    }

    /// Flush and return the inner writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

/// Reads events back; an iterator of `Result<SensorEvent, SensorLogError>`.
#[derive(Debug)]
pub struct SensorLogReader<R: Read> {
    input: R,
    payload: Vec<u8>,
    failed: bool,
    nav_config: Option<String>,
    /// The first item, read while looking for the configuration record.
    first: Option<Result<SensorEvent, SensorLogError>>,
}

impl<R: Read> SensorLogReader<R> {
    /// Open a log: checks the header.
    pub fn new(mut input: R) -> Result<Self, SensorLogError> {
        let mut header = [0_u8; 12];
        input.read_exact(&mut header)?;
        let version = u16::from_le_bytes([header[8], header[9]]);
        if &header[..8] != MAGIC || version != VERSION {
            return Err(SensorLogError::BadHeader(version));
        }
        let mut reader = Self {
            input,
            payload: Vec::new(),
            failed: false,
            nav_config: None,
            first: None,
        };
        reader.first = reader.next_record().transpose();
        Ok(reader)
    }

    /// The navigator's settings recorded in the log (TOML), if it has them.
    pub fn nav_config(&self) -> Option<&str> {
        self.nav_config.as_deref()
    }

    fn next_record(&mut self) -> Result<Option<SensorEvent>, SensorLogError> {
        loop {
            let mut head = [0_u8; 5];
            match self.input.read_exact(&mut head[..1]) {
                Ok(()) => {}
                Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => return Ok(None),
                Err(e) => return Err(e.into()),
            }
            self.input.read_exact(&mut head[1..])?;
            let kind = head[0];
            let len = u32::from_le_bytes([head[1], head[2], head[3], head[4]]);
            if !(8..=MAX_PAYLOAD).contains(&len) {
                return Err(SensorLogError::BadRecord { kind, len });
            }
            self.payload.resize(len as usize, 0);
            self.input.read_exact(&mut self.payload)?;
            if kind == KIND_NAV_CONFIG {
                let text = std::str::from_utf8(&self.payload[8..])
                    .map_err(|_| SensorLogError::BadRecord { kind, len })?;
                self.nav_config = Some(text.to_owned());
                continue;
            }
            if let Some(event) = decode(kind, &self.payload) {
                return Ok(Some(event));
            }
            if (KIND_IMU..=KIND_ALIGNMENT).contains(&kind) {
                return Err(SensorLogError::BadRecord { kind, len });
            }
            // Unknown kind from a newer writer: skip it.
        }
    }
}

impl<R: Read> Iterator for SensorLogReader<R> {
    type Item = Result<SensorEvent, SensorLogError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        if let Some(first) = self.first.take() {
            self.failed = first.is_err();
            return Some(first);
        }
        let item = self.next_record().transpose();
        if matches!(item, Some(Err(_))) {
            self.failed = true;
        }
        item
    }
}

/// Little-endian cursor over a payload; `None` when it runs out.
struct Cursor<'a>(&'a [u8]);

impl Cursor<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let (head, rest) = self.0.split_first_chunk::<N>()?;
        self.0 = rest;
        Some(*head)
    }
    fn f64(&mut self) -> Option<f64> {
        self.take::<8>().map(f64::from_le_bytes)
    }
    fn vec3(&mut self) -> Option<Vector3<f64>> {
        Some(Vector3::new(self.f64()?, self.f64()?, self.f64()?))
    }
    /// A stored unit quaternion, kept bit for bit; anything else is a corrupt record.
    fn unit_quaternion(&mut self) -> Option<UnitQuaternion<f64>> {
        let q = Quaternion::new(self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        ((q.norm() - 1.0).abs() <= 1e-9).then(|| UnitQuaternion::new_unchecked(q))
    }
}

fn decode(kind: u8, payload: &[u8]) -> Option<SensorEvent> {
    let mut c = Cursor(payload);
    let t_us = u64::from_le_bytes(c.take::<8>()?);
    let event = match kind {
        KIND_IMU => SensorEvent::Imu(ImuSample {
            t_us,
            gyro_rps: c.vec3()?,
            accel_mps2: c.vec3()?,
        }),
        KIND_AIR => {
            let [flags] = c.take::<1>()?;
            let tas_mps = c.f64()?;
            let aoa = c.f64()?;
            let aos = c.f64()?;
            SensorEvent::Air(AirSample {
                t_us,
                tas_mps,
                aoa_rad: (flags & 1 != 0).then_some(aoa),
                aos_rad: (flags & 2 != 0).then_some(aos),
                p_pa: c.f64()?,
                temp_k: c.f64()?,
            })
        }
        KIND_MAG => SensorEvent::Mag(MagSample {
            t_us,
            mag_b_nt: c.vec3()?,
        }),
        KIND_GNSS => SensorEvent::Gnss(GnssFix {
            t_us,
            pos: Geodetic {
                lat_rad: c.f64()?,
                lon_rad: c.f64()?,
                h_m: c.f64()?,
            },
            v_ned_mps: c.vec3()?,
            sigma_hor_m: c.f64()?,
            sigma_ver_m: c.f64()?,
            sigma_vel_mps: c.f64()?,
        }),
        KIND_FRAME => {
            let width = u32::from_le_bytes(c.take::<4>()?);
            let height = u32::from_le_bytes(c.take::<4>()?);
            let n = (width as usize).checked_mul(height as usize)?;
            if c.0.len() != n {
                return None;
            }
            SensorEvent::Frame(Frame {
                t_us,
                width,
                height,
                pixels: Arc::from(c.0),
            })
        }
        KIND_REF_ATTITUDE => SensorEvent::RefAttitude(RefAttitude {
            t_us,
            q_nb: c.unit_quaternion()?,
        }),
        KIND_ALIGNMENT => {
            let q_nb = c.unit_quaternion()?;
            let aoa_rad = c.f64()?;
            let priors = SensorErrorPriors {
                e_gyr_rps: c.vec3()?,
                e_gyr_sigma_rps: c.vec3()?,
                e_acc_mps2: c.vec3()?,
                e_acc_sigma_mps2: c.vec3()?,
                e_mag_nt: c.vec3()?,
                e_mag_sigma_nt: c.vec3()?,
                delta_b_n_nt: c.vec3()?,
                delta_b_n_sigma_nt: c.vec3()?,
            };
            SensorEvent::Alignment(Box::new(Alignment {
                t_us,
                q_nb,
                aoa_rad,
                priors,
            }))
        }
        KIND_HEIGHT_ABOVE_TERRAIN => SensorEvent::HeightAboveTerrain(HeightAboveTerrain {
            t_us,
            h_agl_m: c.f64()?,
            sigma_m: c.f64()?,
        }),
        KIND_VISION_APPLIED => SensorEvent::VisionApplied(VisionApplied { t_us }),
        _ => return None,
    };
    Some(event)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_events() -> Vec<SensorEvent> {
        vec![
            SensorEvent::Imu(ImuSample {
                t_us: 10_000,
                gyro_rps: Vector3::new(0.01, -0.02, 1e-9),
                accel_mps2: Vector3::new(0.1, 0.2, -9.81),
            }),
            SensorEvent::Air(AirSample {
                t_us: 10_000,
                tas_mps: 29.0,
                aoa_rad: Some(0.03),
                aos_rad: None,
                p_pa: 73_000.0,
                temp_k: 270.5,
            }),
            SensorEvent::Mag(MagSample {
                t_us: 10_000,
                mag_b_nt: Vector3::new(17e3, -700.0, 5e4),
            }),
            SensorEvent::Gnss(GnssFix {
                t_us: 1_000_000,
                pos: Geodetic {
                    lat_rad: 0.785,
                    lon_rad: -1.57,
                    h_m: 2700.0,
                },
                v_ned_mps: Vector3::new(20.0, -20.0, 0.5),
                sigma_hor_m: 2.12,
                sigma_ver_m: 4.25,
                sigma_vel_mps: 0.0741,
            }),
            SensorEvent::Frame(Frame {
                t_us: 100_000,
                width: 3,
                height: 2,
                pixels: Arc::from(&[1_u8, 2, 3, 4, 5, 6][..]),
            }),
            SensorEvent::RefAttitude(RefAttitude {
                t_us: 100_500,
                q_nb: UnitQuaternion::from_euler_angles(0.1, -0.05, 2.9),
            }),
            SensorEvent::Alignment(Box::new(Alignment {
                t_us: 1_000_000,
                q_nb: UnitQuaternion::from_euler_angles(-0.02, 0.04, 1.3),
                aoa_rad: 0.06,
                priors: SensorErrorPriors {
                    e_gyr_rps: Vector3::new(1e-4, -2e-4, 3e-5),
                    e_gyr_sigma_rps: Vector3::repeat(1e-6),
                    e_acc_mps2: Vector3::new(0.01, -0.02, 0.03),
                    e_acc_sigma_mps2: Vector3::repeat(1e-4),
                    e_mag_nt: Vector3::new(100.0, -50.0, 25.0),
                    e_mag_sigma_nt: Vector3::repeat(1.0),
                    delta_b_n_nt: Vector3::new(-80.0, 40.0, 120.0),
                    delta_b_n_sigma_nt: Vector3::repeat(10.0),
                },
            })),
            SensorEvent::HeightAboveTerrain(HeightAboveTerrain {
                t_us: 1_100_000,
                h_agl_m: 2_567.25,
                sigma_m: 50.0,
            }),
        ]
    }

    #[test]
    fn round_trip_is_bit_exact() {
        let events = sample_events();
        let mut w = SensorLogWriter::new(Vec::new()).unwrap();
        for e in &events {
            w.write(e).unwrap();
        }
        let bytes = w.finish().unwrap();
        let back: Vec<SensorEvent> = SensorLogReader::new(&bytes[..])
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(back, events);
        // With the navigator's settings recorded first, and without.
        let mut w = SensorLogWriter::new(Vec::new()).unwrap();
        w.write_nav_config("[start]\nmag_decimal_year = 2026.5\n")
            .unwrap();
        for e in &events {
            w.write(e).unwrap();
        }
        let bytes = w.finish().unwrap();
        let mut r = SensorLogReader::new(&bytes[..]).unwrap();
        assert_eq!(r.nav_config(), Some("[start]\nmag_decimal_year = 2026.5\n"));
        assert_eq!(r.by_ref().collect::<Result<Vec<_>, _>>().unwrap(), events);
        assert_eq!(
            SensorLogReader::new(&b"IANAVLOG\x01\x00\x00\x00"[..])
                .unwrap()
                .nav_config(),
            None
        );
    }

    #[test]
    fn unknown_kinds_are_skipped_and_corruption_is_an_error() {
        let mut w = SensorLogWriter::new(Vec::new()).unwrap();
        w.write(&sample_events()[0]).unwrap();
        let mut bytes = w.finish().unwrap();
        // A record of an unknown kind 200 with a 9-byte payload, then a truncated IMU record.
        bytes.extend_from_slice(&[200, 9, 0, 0, 0]);
        bytes.extend_from_slice(&[0; 9]);
        bytes.extend_from_slice(&[KIND_IMU, 56, 0, 0, 0, 1, 2, 3]);
        let items: Vec<_> = SensorLogReader::new(&bytes[..]).unwrap().collect();
        assert_eq!(items.len(), 2);
        assert!(items[0].is_ok());
        assert!(items[1].is_err());
        assert!(SensorLogReader::new(&b"NOTALOG!\x01\x00\x00\x00"[..]).is_err());
        // A short IMU payload (valid length field, too few values) is a corrupt record.
        let mut short = SensorLogWriter::new(Vec::new()).unwrap().finish().unwrap();
        short.extend_from_slice(&[KIND_IMU, 16, 0, 0, 0]);
        short.extend_from_slice(&[0; 16]);
        let items: Vec<_> = SensorLogReader::new(&short[..]).unwrap().collect();
        assert!(matches!(
            items[0],
            Err(SensorLogError::BadRecord { kind: 1, len: 16 })
        ));
    }
}
