//! A fake PX4-like autopilot on loopback UDP for the daemon tests: level flight north at
//! 30 m/s, 500 m above the ellipsoid, streaming HIGHRES_IMU (100 Hz, with magnetometer,
//! static pressure and temperature), VFR_HUD (10 Hz), ATTITUDE (10 Hz), GPS_RAW_INT and
//! GLOBAL_POSITION_INT (5 Hz) and HEARTBEAT (1 Hz), answering TIMESYNC, and recording every
//! message the daemon sends. Frames are written by hand so the tests can also inject garbage.

#![allow(
    dead_code,
    reason = "compiled into every test binary with `mod common`, each using a part of it; `expect` \
              would break as soon as one test binary used all of it"
)]
#![expect(
    clippy::unwrap_used,
    reason = "test helper: failing loudly on a broken loopback socket is the right behaviour"
)]

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ianav::env::atmosphere;
use ianav::env::magnetic::MagneticModel;
use ianav::math::wgs84::{self, Geodetic};
use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MAVLinkMessageRaw, MavHeader, MavlinkVersion, SigningConfig, SigningData};
use tokio::net::UdpSocket;

pub const LAT0_DEG: f64 = 45.0;
pub const LON0_DEG: f64 = 7.0;
pub const H0_M: f64 = 500.0;
pub const GEOID_M: f64 = 48.0;
pub const SPEED_MPS: f64 = 30.0;

/// A message received from the daemon.
#[derive(Debug, Clone)]
pub struct Rx {
    pub at: Instant,
    pub header: MavHeader,
    pub version: MavlinkVersion,
    pub msg: apm::MavMessage,
    /// The frame carried a signature valid for the fake's key (false without a key).
    pub signed_ok: bool,
}

/// Signing state shared by the fake's tasks (`None`: unsigned).
pub type Signing = Arc<Mutex<Option<Arc<SigningData>>>>;

/// Signing data for `key` (outgoing frames signed, link id 7).
pub fn signing_data(key: [u8; 32]) -> Arc<SigningData> {
    Arc::new(SigningData::from_config(SigningConfig::new(
        key, 7, true, false,
    )))
}

/// Test controls of the stream.
#[derive(Debug, Default)]
pub struct Ctl {
    /// IMU messages per 10 ms tick (1 = 100 Hz; 10 = a 10× flood).
    pub imu_per_tick: u32,
    /// Send nothing (link loss).
    pub silent: bool,
    /// Restart the boot clock and the sequence at the next tick.
    pub reboot: bool,
    /// GNSS has no fix.
    pub gnss_off: bool,
    /// Vehicle time runs this many times faster than real time (0 or 1: real time).
    pub time_scale: u64,
    /// IMU period in vehicle µs when non-zero (overrides `imu_per_tick`; 1_000_000: the 1 Hz
    /// default RAW_IMU stream of ArduPilot).
    pub imu_period_us: u64,
    /// SET_MESSAGE_INTERVAL requests shorter than this are DENIED, µs (0: all accepted;
    /// 25_000: ArduPlane at its 50 Hz loop).
    pub min_interval_us: f32,
    /// Report the daemon's last GPS_INPUT position in GPS_RAW_INT (an autopilot whose primary
    /// receiver became the daemon's GPS_INPUT instance).
    pub echo_gps_input: bool,
    /// The last GPS_INPUT received (lat, lon degE7, horizontal accuracy mm).
    pub last_gps_input: Option<(i32, i32, u32)>,
    /// Interval requests received: (message id, interval µs, accepted).
    pub interval_requests: Vec<(u32, f32, bool)>,
    /// Messages sent, by kind.
    pub imu_sent: u64,
    pub gnss_sent: u64,
}

pub struct Fake {
    pub sock: Arc<UdpSocket>,
    pub daemon: SocketAddr,
    pub rx: Arc<Mutex<Vec<Rx>>>,
    pub ctl: Arc<Mutex<Ctl>>,
    pub start: Instant,
    seq: Arc<Mutex<u8>>,
    boot: Arc<Mutex<Instant>>,
    pub signing: Signing,
}

/// A free UDP port on 127.0.0.1.
pub fn free_udp_port() -> u16 {
    let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    s.local_addr().unwrap().port()
}

/// A free TCP port on 127.0.0.1.
pub fn free_tcp_port() -> u16 {
    let s = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    s.local_addr().unwrap().port()
}

/// Encode one frame, signed when `signing` holds a key (MAVLink 2 only).
pub fn frame_signed(
    signing: &Signing,
    sys: u8,
    comp: u8,
    seq: u8,
    msg: &apm::MavMessage,
) -> Vec<u8> {
    let sd = signing.lock().unwrap().clone();
    let Some(sd) = sd else {
        return frame(MavlinkVersion::V2, sys, comp, seq, msg);
    };
    let mut buf = Vec::new();
    let h = MavHeader {
        system_id: u32::from(sys),
        component_id: comp,
        sequence: seq,
    };
    mavlink::write_v2_msg_signed(&mut buf, h, msg, Some(&sd)).unwrap();
    buf
}

/// Encode one frame.
pub fn frame(
    version: MavlinkVersion,
    sys: u8,
    comp: u8,
    seq: u8,
    msg: &apm::MavMessage,
) -> Vec<u8> {
    let mut buf = Vec::new();
    let h = MavHeader {
        system_id: u32::from(sys),
        component_id: comp,
        sequence: seq,
    };
    match version {
        MavlinkVersion::V2 => mavlink::write_v2_msg(&mut buf, h, msg).unwrap(),
        MavlinkVersion::V1 => mavlink::write_v1_msg(&mut buf, h, msg).unwrap(),
    };
    buf
}

/// Decode every frame of a datagram; checks signatures against `verify` when given.
pub fn decode_all(
    buf: &[u8],
    verify: Option<&SigningData>,
) -> Vec<(MavHeader, MavlinkVersion, apm::MavMessage, bool)> {
    use mavlink::Message;
    let mut out = Vec::new();
    let mut r = mavlink::MavlinkReader::new(buf);
    while let Ok(raw) = r.read_any_raw_message::<apm::MavMessage>() {
        let v = raw.version();
        let Ok(m) = apm::MavMessage::parse(v, raw.message_id(), raw.payload()) else {
            continue;
        };
        let h = MavHeader {
            system_id: raw.system_id(),
            component_id: raw.component_id(),
            sequence: raw.sequence(),
        };
        let signed_ok = match (&raw, verify) {
            (MAVLinkMessageRaw::V2(r2), Some(sd)) => {
                r2.incompatibility_flags() & 1 != 0 && sd.verify_signature(r2)
            }
            _ => false,
        };
        out.push((h, v, m, signed_ok));
    }
    out
}

impl Fake {
    /// Bind, and start the receiver (which answers TIMESYNC) and the sensor streamer.
    pub async fn start(daemon_port: u16) -> Fake {
        let sock = Arc::new(UdpSocket::bind("127.0.0.1:0").await.unwrap());
        let daemon: SocketAddr = format!("127.0.0.1:{daemon_port}").parse().unwrap();
        let fake = Fake {
            sock,
            daemon,
            rx: Arc::new(Mutex::new(Vec::new())),
            ctl: Arc::new(Mutex::new(Ctl {
                imu_per_tick: 1,
                ..Ctl::default()
            })),
            start: Instant::now(),
            seq: Arc::new(Mutex::new(0)),
            boot: Arc::new(Mutex::new(Instant::now())),
            signing: Arc::new(Mutex::new(None)),
        };
        fake.spawn_receiver();
        fake.spawn_streamer();
        fake
    }

    pub fn boot_us(&self) -> u64 {
        let scale = self.ctl.lock().unwrap().time_scale.max(1);
        self.boot.lock().unwrap().elapsed().as_micros() as u64 * scale
    }

    pub async fn send(&self, msg: &apm::MavMessage) {
        let seq = {
            let mut s = self.seq.lock().unwrap();
            *s = s.wrapping_add(1);
            *s
        };
        let f = frame_signed(&self.signing, 1, 1, seq, msg);
        let _ = self.sock.send_to(&f, self.daemon).await;
    }

    /// Send `msg` in the autopilot's sequence with its CRC broken (`crc = true`) or, with
    /// `crc = false`, a well-formed frame of an unknown message id (60000) in its place.
    pub async fn send_dropped_frame(&self, msg: &apm::MavMessage, crc: bool) {
        let seq = {
            let mut s = self.seq.lock().unwrap();
            *s = s.wrapping_add(1);
            *s
        };
        let mut f = frame(MavlinkVersion::V2, 1, 1, seq, msg);
        if crc {
            let n = f.len();
            f[n - 1] ^= 0xa5;
        } else {
            f = vec![0xfd, 4, 0, 0, seq, 1, 1, 0x60, 0xea, 0x00, 1, 2, 3, 4, 0, 0];
        }
        let _ = self.sock.send_to(&f, self.daemon).await;
    }

    pub async fn send_raw(&self, bytes: &[u8]) {
        let _ = self.sock.send_to(bytes, self.daemon).await;
    }

    fn spawn_receiver(&self) {
        let (sock, rx, boot, daemon, seq, ctl, signing) = (
            self.sock.clone(),
            self.rx.clone(),
            self.boot.clone(),
            self.daemon,
            self.seq.clone(),
            self.ctl.clone(),
            self.signing.clone(),
        );
        tokio::spawn(async move {
            let mut buf = vec![0_u8; 65_536];
            loop {
                let Ok((n, _)) = sock.recv_from(&mut buf).await else {
                    return;
                };
                // Signatures are checked per (link, system, component) stream, so one
                // SigningData can sign ours and verify the daemon's.
                let sd_verify = signing.lock().unwrap().clone();
                for (header, version, msg, signed_ok) in decode_all(&buf[..n], sd_verify.as_deref())
                {
                    if let apm::MavMessage::TIMESYNC(t) = &msg {
                        // A lost link is lost both ways.
                        if t.tc1 == 0 && !ctl.lock().unwrap().silent {
                            let scale = ctl.lock().unwrap().time_scale.max(1) as i64;
                            let now_ns = boot.lock().unwrap().elapsed().as_nanos() as i64 * scale;
                            let reply = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                                tc1: now_ns,
                                ts1: t.ts1,
                                target_system: header.system_id as u8,
                                target_component: header.component_id,
                            });
                            let s = {
                                let mut s = seq.lock().unwrap();
                                *s = s.wrapping_add(1);
                                *s
                            };
                            let f = frame_signed(&signing, 1, 1, s, &reply);
                            let _ = sock.send_to(&f, daemon).await;
                        }
                    }
                    if let apm::MavMessage::GPS_INPUT(g) = &msg {
                        ctl.lock().unwrap().last_gps_input =
                            Some((g.lat, g.lon, (g.horiz_accuracy * 1e3).round() as u32));
                    }
                    // Acknowledge interval requests (accepted, or DENIED below the minimum
                    // interval as ArduPlane does), unless silent.
                    if let apm::MavMessage::COMMAND_LONG(c) = &msg
                        && c.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL
                        && !ctl.lock().unwrap().silent
                    {
                        let accepted = {
                            let mut k = ctl.lock().unwrap();
                            let ok = c.param2 <= 0.0 || c.param2 >= k.min_interval_us;
                            k.interval_requests.push((c.param1 as u32, c.param2, ok));
                            ok
                        };
                        let ack = apm::MavMessage::COMMAND_ACK(apm::COMMAND_ACK_DATA {
                            command: c.command,
                            result: if accepted {
                                apm::MavResult::MAV_RESULT_ACCEPTED
                            } else {
                                apm::MavResult::MAV_RESULT_DENIED
                            },
                            target_system: header.system_id as u8,
                            target_component: header.component_id,
                            ..Default::default()
                        });
                        let s = {
                            let mut s = seq.lock().unwrap();
                            *s = s.wrapping_add(1);
                            *s
                        };
                        let f = frame_signed(&signing, 1, 1, s, &ack);
                        let _ = sock.send_to(&f, daemon).await;
                    }
                    rx.lock().unwrap().push(Rx {
                        at: Instant::now(),
                        header,
                        version,
                        msg,
                        signed_ok,
                    });
                }
            }
        });
    }

    fn spawn_streamer(&self) {
        let (sock, ctl, boot, daemon, seq, signing) = (
            self.sock.clone(),
            self.ctl.clone(),
            self.boot.clone(),
            self.daemon,
            self.seq.clone(),
            self.signing.clone(),
        );
        let mag_model = MagneticModel::new(2026.5).unwrap();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(10));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
            let t0 = Instant::now();
            let mut k: u64 = 0;
            // Vehicle (boot) time up to which samples have been sent, µs.
            let mut sent_to_us: Option<u64> = None;
            let p_pa = atmosphere::pressure_pa(H0_M);
            let temp_k = atmosphere::isa_temperature_k(H0_M);
            loop {
                tick.tick().await;
                k += 1;
                let (per_tick, silent, gnss_off, scale, imu_period_us, echo) = {
                    let mut c = ctl.lock().unwrap();
                    if c.reboot {
                        c.reboot = false;
                        *boot.lock().unwrap() = Instant::now();
                        *seq.lock().unwrap() = 0;
                        sent_to_us = None;
                    }
                    (
                        c.imu_per_tick.max(1),
                        c.silent,
                        c.gnss_off,
                        c.time_scale.max(1),
                        c.imu_period_us,
                        c.echo_gps_input.then_some(c.last_gps_input).flatten(),
                    )
                };
                if silent {
                    sent_to_us = None;
                    continue;
                }
                // Vehicle time runs `scale` times faster than real time.
                let now_us = boot.lock().unwrap().elapsed().as_micros() as u64 * scale;
                let from_us = sent_to_us.unwrap_or(now_us.saturating_sub(10_000 * scale));
                sent_to_us = Some(now_us);
                // Flight time since the stream started (continuous across a "reboot").
                let pos = position(t0.elapsed().as_secs_f64() * scale as f64);
                let b_n = mag_model.field_ned_nt(&pos).unwrap();
                // Grid points of a period in (from, now].
                let grid = |period: u64, phase: u64| {
                    let first = (from_us + period - phase) / period * period + phase;
                    let first = if first <= from_us {
                        first + period
                    } else {
                        first
                    };
                    (0..)
                        .map(move |i| first + i * period)
                        .take_while(move |t| *t <= now_us)
                };
                let mut out: Vec<apm::MavMessage> = Vec::new();
                let imu_period = if imu_period_us > 0 {
                    imu_period_us
                } else {
                    10_000 / u64::from(per_tick)
                };
                let mut n_imu = 0;
                for t_us in grid(imu_period, 0) {
                    n_imu += 1;
                    out.push(apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
                        time_usec: t_us,
                        xacc: 0.0,
                        yacc: 0.0,
                        zacc: -wgs84::normal_gravity_mps2(pos.lat_rad, pos.h_m) as f32,
                        xgyro: 0.0,
                        ygyro: 0.0,
                        zgyro: 0.0,
                        // Heading north, level: body = NED.
                        xmag: (b_n.x / 1e5) as f32,
                        ymag: (b_n.y / 1e5) as f32,
                        zmag: (b_n.z / 1e5) as f32,
                        abs_pressure: (p_pa / 100.0) as f32,
                        diff_pressure: 0.0,
                        pressure_alt: H0_M as f32,
                        temperature: (temp_k - 273.15) as f32,
                        fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x1fff),
                        id: 0,
                    }));
                }
                ctl.lock().unwrap().imu_sent += n_imu;
                for t_us in grid(100_000, 0) {
                    let rho = atmosphere::density_kgpm3(p_pa, temp_k);
                    let eas = SPEED_MPS * (rho / 1.225).sqrt();
                    out.push(apm::MavMessage::VFR_HUD(apm::VFR_HUD_DATA {
                        airspeed: eas as f32,
                        groundspeed: SPEED_MPS as f32,
                        heading: 0,
                        throttle: 50,
                        alt: (H0_M - GEOID_M) as f32,
                        climb: 0.0,
                    }));
                    out.push(apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA {
                        time_boot_ms: (t_us / 1000) as u32,
                        ..Default::default()
                    }));
                }
                for t_us in grid(200_000, 50_000) {
                    out.push(apm::MavMessage::GLOBAL_POSITION_INT(
                        apm::GLOBAL_POSITION_INT_DATA {
                            time_boot_ms: (t_us / 1000) as u32,
                            lat: (pos.lat_rad.to_degrees() * 1e7) as i32,
                            lon: (pos.lon_rad.to_degrees() * 1e7) as i32,
                            alt: ((H0_M - GEOID_M) * 1e3) as i32,
                            vx: (SPEED_MPS * 100.0) as i16,
                            ..Default::default()
                        },
                    ));
                    out.push(apm::MavMessage::GPS_RAW_INT(apm::GPS_RAW_INT_DATA {
                        time_usec: t_us,
                        fix_type: if gnss_off {
                            apm::GpsFixType::GPS_FIX_TYPE_NO_FIX
                        } else {
                            apm::GpsFixType::GPS_FIX_TYPE_3D_FIX
                        },
                        lat: echo.map_or((pos.lat_rad.to_degrees() * 1e7).round() as i32, |e| e.0),
                        lon: echo.map_or((pos.lon_rad.to_degrees() * 1e7).round() as i32, |e| e.1),
                        alt: ((H0_M - GEOID_M) * 1e3) as i32,
                        eph: 100,
                        epv: 150,
                        vel: (SPEED_MPS * 100.0) as u16,
                        cog: 0,
                        satellites_visible: 12,
                        alt_ellipsoid: (H0_M * 1e3) as i32,
                        h_acc: echo.map_or(1_000, |e| e.2),
                        v_acc: 1_500,
                        vel_acc: 200,
                        hdg_acc: 0,
                        yaw: 0,
                    }));
                    if !gnss_off {
                        ctl.lock().unwrap().gnss_sent += 1;
                    }
                }
                if k % 100 == 1 {
                    out.push(apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
                        custom_mode: 0,
                        mavtype: apm::MavType::MAV_TYPE_FIXED_WING,
                        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_PX4,
                        base_mode: apm::MavModeFlag::empty(),
                        system_status: apm::MavState::MAV_STATE_ACTIVE,
                        mavlink_version: 3,
                    }));
                }
                for m in out {
                    let s = {
                        let mut s = seq.lock().unwrap();
                        *s = s.wrapping_add(1);
                        *s
                    };
                    let f = frame_signed(&signing, 1, 1, s, &m);
                    let _ = sock.send_to(&f, daemon).await;
                }
            }
        });
    }

    /// Messages received so far that satisfy `f`.
    pub fn received(&self, f: impl Fn(&Rx) -> bool) -> Vec<Rx> {
        self.rx
            .lock()
            .unwrap()
            .iter()
            .filter(|r| f(r))
            .cloned()
            .collect()
    }

    /// STATUSTEXTs received so far.
    pub fn statustexts(&self) -> Vec<String> {
        self.received(|r| matches!(r.msg, apm::MavMessage::STATUSTEXT(_)))
            .into_iter()
            .filter_map(|r| match r.msg {
                apm::MavMessage::STATUSTEXT(s) => Some(
                    String::from_utf8_lossy(&s.text[..])
                        .trim_end_matches('\0')
                        .to_owned(),
                ),
                _ => None,
            })
            .collect()
    }
}

/// Position after `t` s of flight north.
pub fn position(t: f64) -> Geodetic {
    let lat0 = LAT0_DEG.to_radians();
    Geodetic {
        lat_rad: lat0 + SPEED_MPS * t / (wgs84::radius_meridian_m(lat0) + H0_M),
        lon_rad: LON0_DEG.to_radians(),
        h_m: H0_M,
    }
}

/// Wait until `cond` holds, polling every 20 ms, at most `timeout`.
pub async fn wait_for(timeout: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        if cond() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    cond()
}
