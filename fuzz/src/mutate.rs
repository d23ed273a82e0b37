//! Input generation: a stretch of the valid stream that continues a warmed-up daemon, then
//! mutations at three levels, all drawn from one seeded RNG per input (input `i` of seed `s`
//! is the same on every machine and run, and can be regenerated alone).
//!
//! - Messages: timestamps (0, maximum, an hour ahead, a reboot-sized step back, Unix time,
//!   jitter, a neighbour's), the rest of the stream restamped consistently (a reboot or a
//!   clock jump the clock can confirm), sensor values at and past the decoder's limits, flags and enums,
//!   foreign systems and our own component id, an intruding autopilot, duplication, deletion,
//!   reordering, other message types, the other autopilot's stream, link outages and bursts.
//! - Frames (CRC recomputed unless the mutation is the CRC): every field width at an extreme
//!   bit pattern (integer min/max, NaN, ±∞, ±max, tiny), random payload bytes, truncated and
//!   lengthened payloads, MAVLink 1 ↔ 2, another message id over the same payload, sequence,
//!   incompatibility and compatibility flags, 32-bit system ids, signatures removed, replayed,
//!   made with the wrong key or at extreme timestamps.
//! - Bytes: bit flips, special bytes (the start markers among them), insertions, deletions,
//!   duplications, truncation, splitting and merging datagrams, garbage datagrams, splices.

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MavlinkVersion, Message};
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::input::{Input, Starts};
use crate::pipeline::{Datagram, LinkMode};
use crate::scenario::{self, Autopilot, Stream};
use crate::wire::{FrameSpec, SIGNATURE_TS_BASE, SIGNING_KEY, Signature};

/// The RNG of input `index` of run `seed`.
pub fn rng_for(seed: u64, index: u64) -> ChaCha8Rng {
    fn splitmix(mut z: u64) -> u64 {
        z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    ChaCha8Rng::seed_from_u64(splitmix(seed) ^ splitmix(index ^ 0x5bd1_e995_u64.rotate_left(32)))
}

/// Message ids of other traffic on a real link (plus the accepted ones, to re-type payloads).
const OTHER_IDS: [u32; 24] = [
    0, 1, 2, 24, 26, 27, 29, 30, 31, 32, 33, 74, 77, 105, 111, 116, 129, 132, 137, 147, 178, 230,
    253, 331,
];

/// Extreme bit patterns of a field of `w` bytes, little-endian.
pub fn extremes(w: usize) -> Vec<Vec<u8>> {
    let ints = |w: usize| {
        let mut max = vec![0xff; w];
        max[w - 1] = 0x7f;
        let mut min = vec![0; w];
        min[w - 1] = 0x80;
        vec![vec![0; w], vec![0xff; w], max, min]
    };
    let mut v = ints(w);
    match w {
        4 => v.extend(
            [
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::MAX,
                f32::MIN,
                f32::MIN_POSITIVE,
                -0.0,
            ]
            .map(|x| x.to_le_bytes().to_vec()),
        ),
        8 => v.extend(
            [
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::MAX,
                f64::MIN,
            ]
            .map(|x| x.to_le_bytes().to_vec()),
        ),
        _ => {}
    }
    v
}

/// A message before framing.
#[derive(Debug, Clone)]
struct Item {
    rx_us: u64,
    msg: apm::MavMessage,
    sys: u32,
    comp: u8,
}

/// The autopilot time a message carries, µs.
fn time_of(msg: &apm::MavMessage) -> Option<u64> {
    use apm::MavMessage as M;
    Some(match msg {
        M::HIGHRES_IMU(m) => m.time_usec,
        M::RAW_IMU(m) => m.time_usec,
        M::GPS_RAW_INT(m) => m.time_usec,
        M::AOA_SSA(m) => m.time_usec,
        M::SCALED_IMU(m) => u64::from(m.time_boot_ms) * 1_000,
        M::SCALED_PRESSURE(m) => u64::from(m.time_boot_ms) * 1_000,
        M::SCALED_PRESSURE2(m) => u64::from(m.time_boot_ms) * 1_000,
        M::ATTITUDE(m) => u64::from(m.time_boot_ms) * 1_000,
        M::GLOBAL_POSITION_INT(m) => u64::from(m.time_boot_ms) * 1_000,
        M::SYSTEM_TIME(m) => u64::from(m.time_boot_ms) * 1_000,
        _ => return None,
    })
}

/// Set the time of a message (ms fields truncate, as a wrapping sender would).
fn set_time(msg: &mut apm::MavMessage, us: u64) {
    use apm::MavMessage as M;
    let ms = (us / 1_000) as u32;
    match msg {
        M::HIGHRES_IMU(m) => m.time_usec = us,
        M::RAW_IMU(m) => m.time_usec = us,
        M::GPS_RAW_INT(m) => m.time_usec = us,
        M::AOA_SSA(m) => m.time_usec = us,
        M::SCALED_IMU(m) => m.time_boot_ms = ms,
        M::SCALED_PRESSURE(m) => m.time_boot_ms = ms,
        M::SCALED_PRESSURE2(m) => m.time_boot_ms = ms,
        M::ATTITUDE(m) => m.time_boot_ms = ms,
        M::GLOBAL_POSITION_INT(m) => m.time_boot_ms = ms,
        M::SYSTEM_TIME(m) => m.time_boot_ms = ms,
        _ => {}
    }
}

fn pick<T: Copy>(r: &mut ChaCha8Rng, v: &[T]) -> T {
    v[r.random_range(0..v.len())]
}

/// A float at or near a limit, or a plain random one.
fn edge_f32(r: &mut ChaCha8Rng, limits: &[f32]) -> f32 {
    match r.random_range(0..4) {
        0 => pick(
            r,
            &[f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, -0.0],
        ),
        1 => {
            let l = pick(r, limits);
            l * pick(r, &[1.0, 1.000_001, 0.999_999, -1.0])
        }
        2 => f32::from_bits(r.next_u32()),
        _ => r.random_range(-1e4..1e4),
    }
}

/// Sensor values, flags and enums at and past the decoder's limits.
fn tweak(r: &mut ChaCha8Rng, msg: &mut apm::MavMessage) {
    use apm::MavMessage as M;
    // 16 g, 2000 °/s, 2 G: the decoder's limits in the message units.
    let acc = [156.906_4_f32, 0.0];
    let gyro = [34.906_586_f32, 0.0];
    match msg {
        M::HIGHRES_IMU(m) => match r.random_range(0..5) {
            0 => m.fields_updated = apm::HighresImuUpdatedFlags::from_bits_truncate(r.random()),
            1 => m.xacc = edge_f32(r, &acc),
            2 => m.zgyro = edge_f32(r, &gyro),
            3 => m.xmag = edge_f32(r, &[2.0, 0.0]),
            _ => {
                m.abs_pressure = edge_f32(r, &[1_500.0, 10.0, 1_200.0, 120_000.0, 1_000.0]);
                m.temperature = edge_f32(r, &[-90.0, 70.0, -273.15]);
            }
        },
        M::SCALED_IMU(m) => {
            let v = pick(r, &[i16::MIN, i16::MAX, 16_000, 16_001, -16_001, 0]);
            match r.random_range(0..3) {
                0 => m.zacc = v,
                1 => m.xgyro = v,
                _ => m.ymag = v,
            }
        }
        M::RAW_IMU(m) => m.xacc = pick(r, &[i16::MIN, i16::MAX, 16_001]),
        M::SCALED_PRESSURE(m) => {
            m.press_abs = edge_f32(r, &[10.0, 1_200.0, 0.0]);
            m.temperature = pick(r, &[i16::MIN, i16::MAX, -9_000, 7_000, -27_315]);
        }
        M::AIRSPEED(m) => {
            if r.random_bool(0.5) {
                m.flags = apm::AirspeedSensorFlags::from_bits_truncate(r.random());
            } else {
                m.airspeed = edge_f32(r, &[150.0, 0.0]);
            }
        }
        M::VFR_HUD(m) => m.airspeed = edge_f32(r, &[150.0, 0.0]),
        M::AOA_SSA(m) => {
            m.AOA = edge_f32(r, &[90.0, -90.0]);
            m.SSA = edge_f32(r, &[90.0, -90.0]);
        }
        M::ATTITUDE(m) => {
            m.roll = edge_f32(r, &[std::f32::consts::PI, 1e30]);
            m.yaw = edge_f32(r, &[std::f32::consts::TAU, 1e30]);
        }
        M::GLOBAL_POSITION_INT(m) => m.vz = pick(r, &[i16::MIN, i16::MAX, -1, 0]),
        M::GPS_RAW_INT(m) => match r.random_range(0..6) {
            0 => {
                m.fix_type = pick(
                    r,
                    &[
                        apm::GpsFixType::GPS_FIX_TYPE_NO_GPS,
                        apm::GpsFixType::GPS_FIX_TYPE_2D_FIX,
                        apm::GpsFixType::GPS_FIX_TYPE_RTK_FIXED,
                        apm::GpsFixType::GPS_FIX_TYPE_PPP,
                    ],
                )
            }
            1 => {
                m.lat = pick(r, &[900_000_000, -900_000_000, i32::MAX, i32::MIN, 0]);
                m.lon = pick(r, &[1_800_000_000, -1_800_000_001, i32::MAX, i32::MIN]);
            }
            2 => {
                m.alt = pick(r, &[i32::MIN, i32::MAX, 0]);
                m.alt_ellipsoid = pick(r, &[i32::MIN, i32::MAX, 0, 1]);
            }
            3 => {
                m.vel = pick(r, &[u16::MAX, u16::MAX - 1, 0]);
                m.cog = pick(r, &[u16::MAX, 35_999, 36_000, u16::MAX - 1]);
            }
            4 => {
                m.h_acc = pick(r, &[0, 1, u32::MAX]);
                m.v_acc = pick(r, &[0, 1, u32::MAX]);
                m.vel_acc = pick(r, &[0, 1, u32::MAX]);
                m.eph = pick(r, &[0, 1, u16::MAX]);
                m.epv = pick(r, &[0, 1, u16::MAX]);
            }
            _ => m.satellites_visible = r.random(),
        },
        M::HEARTBEAT(m) => {
            m.autopilot = pick(
                r,
                &[
                    apm::MavAutopilot::MAV_AUTOPILOT_INVALID,
                    apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                    apm::MavAutopilot::MAV_AUTOPILOT_PX4,
                    apm::MavAutopilot::MAV_AUTOPILOT_GENERIC,
                ],
            );
            m.mavtype = pick(
                r,
                &[
                    apm::MavType::MAV_TYPE_GCS,
                    apm::MavType::MAV_TYPE_FIXED_WING,
                    apm::MavType::MAV_TYPE_ONBOARD_CONTROLLER,
                ],
            );
        }
        M::TIMESYNC(m) => {
            let v = [i64::MIN, i64::MAX, -1, 0, 1, r.random()];
            m.tc1 = pick(r, &v);
            m.ts1 = pick(r, &v);
        }
        M::SYSTEM_TIME(m) => m.time_unix_usec = r.random(),
        _ => {}
    }
}

/// A new timestamp for a message now at `t` µs (`prev`: its neighbour's).
fn new_time(r: &mut ChaCha8Rng, t: u64, prev: Option<u64>) -> u64 {
    match r.random_range(0..10) {
        0 => 0,
        1 => u64::MAX,
        2 => t.saturating_add(3_600_000_000),
        3 => t.saturating_sub(1_500_000),
        4 => t.saturating_sub(20_000),
        5 => prev.unwrap_or(t),
        6 => 1_790_000_000_000_000,
        7 => t.saturating_add_signed(r.random_range(-5_000..5_000)),
        8 => u64::from(r.next_u32()) * 1_000,
        _ => r.random(),
    }
}

fn rand_bytes(r: &mut ChaCha8Rng, n: usize) -> Vec<u8> {
    (0..n).map(|_| r.random()).collect()
}

/// Generate input `index` of run `seed`.
pub fn generate(starts: &Starts, seed: u64, index: u64) -> Input {
    let r = &mut rng_for(seed, index);
    let start_i = r.random_range(0..starts.0.len());
    let start = &starts.0[start_i];
    let link_i = match r.random_range(0..100) {
        0..60 => 0,
        60..85 => 1,
        _ => 2,
    };
    let mode = LinkMode::ALL[link_i];
    let n = match r.random_range(0..100) {
        0..40 => r.random_range(1..=4),
        40..80 => r.random_range(5..=24),
        _ => r.random_range(25..=100),
    };
    // The valid stream from where the start left it.
    let mut items = Vec::with_capacity(n + 8);
    let mut tick = start.tick;
    while items.len() < n {
        for m in scenario::messages(start.stream, tick) {
            items.push(Item {
                rx_us: m.rx_us,
                msg: m.msg,
                sys: u32::from(scenario::AP_SYS),
                comp: scenario::AP_COMP,
            });
        }
        tick += 1;
    }
    items.truncate(n);
    let n_ops = if r.random_bool(0.05) {
        0
    } else {
        let mut k = 1;
        while k < 10 && r.random_bool(0.55) {
            k += 1;
        }
        k
    };
    let ops: Vec<u32> = (0..n_ops).map(|_| r.random_range(0..100)).collect();
    for &op in ops.iter().filter(|&&o| o < 45) {
        mutate_messages(r, &mut items, start.stream, tick, op);
    }
    // Arrival times follow the positions: a moved message arrives late, not early.
    let mut now = start.pipeline.now_us();
    let v1_share = match r.random_range(0..100) {
        0..80 => 0.0,
        80..95 => 0.2,
        _ => 1.0,
    };
    let sign = mode != LinkMode::Open || r.random_bool(0.05);
    let mut seq = start.seq;
    let mut frames: Vec<(u64, FrameSpec)> = items
        .iter()
        .enumerate()
        .map(|(k, it)| {
            let v1 = it.msg.message_id() <= 255 && r.random_bool(v1_share);
            let version = if v1 {
                MavlinkVersion::V1
            } else {
                MavlinkVersion::V2
            };
            let mut f = FrameSpec::of(&it.msg, version, it.sys, it.comp, seq);
            seq = seq.wrapping_add(1);
            if sign && !v1 {
                f.signature = Some(Signature {
                    link_id: 0,
                    timestamp: SIGNATURE_TS_BASE + k as u64,
                    key: SIGNING_KEY,
                });
            }
            now = now.max(it.rx_us);
            (now, f)
        })
        .collect();
    for _ in ops.iter().filter(|&&o| (45..80).contains(&o)) {
        if !frames.is_empty() {
            mutate_frame(r, &mut frames);
        }
    }
    let mut datagrams = Vec::with_capacity(frames.len());
    let mut t = start.pipeline.now_us();
    for (rx, f) in &frames {
        let bytes = f.encode();
        let dt = u32::try_from(rx.saturating_sub(t)).unwrap_or(u32::MAX);
        t = t.max(*rx);
        // Several frames in one datagram, as routers and ArduPilot's UDP output send them.
        match datagrams.last_mut() {
            Some(Datagram { bytes: b, .. }) if dt == 0 || r.random_bool(0.05) => b.extend(bytes),
            _ => datagrams.push(Datagram { dt_us: dt, bytes }),
        }
    }
    for &op in ops.iter().filter(|&&o| o >= 80) {
        mutate_bytes(r, &mut datagrams, op);
    }
    Input {
        start: start_i as u8,
        link: link_i as u8,
        datagrams,
    }
}

fn mutate_messages(
    r: &mut ChaCha8Rng,
    items: &mut Vec<Item>,
    stream: Stream,
    next_tick: u64,
    op: u32,
) {
    let n = items.len();
    let i = r.random_range(0..n.max(1));
    match (op % 13, n) {
        (_, 0) => {}
        (0 | 1, _) => {
            let prev = i.checked_sub(1).and_then(|j| time_of(&items[j].msg));
            // The nearest timestamped message at or after i.
            if let Some(j) = (i..n).find(|&j| time_of(&items[j].msg).is_some()) {
                let t = time_of(&items[j].msg).unwrap_or(0);
                let t = new_time(r, t, prev);
                set_time(&mut items[j].msg, t);
            }
        }
        (2 | 3, _) => tweak(r, &mut items[i].msg),
        (4, _) => {
            let it = &mut items[i];
            if r.random_bool(0.7) {
                it.sys = pick(r, &[0, 2, 255, 256, 70_000, u32::MAX]);
            } else {
                it.comp = pick(r, &[scenario::OUR_COMPONENT, 0, 190]);
            }
        }
        (5, _) => {
            // Another autopilot (or a ground station) on the link, with its own sensor data.
            let sys = r.random_range(2..=254);
            let mut hb = scenario::messages(stream, 0).remove(0).msg;
            tweak(r, &mut hb);
            let rx = items[i].rx_us;
            items.insert(
                i,
                Item {
                    rx_us: rx,
                    msg: hb,
                    sys,
                    comp: 1,
                },
            );
            for it in items.iter_mut().skip(i + 1).take(3) {
                if r.random_bool(0.5) {
                    it.sys = sys;
                }
            }
        }
        (6, _) => {
            let dup = items[i].clone();
            let at = r.random_range(i..=n);
            items.insert(at, dup);
        }
        (7, _) => {
            let k = r.random_range(1..=n.min(8));
            items.drain(i..(i + k).min(n));
        }
        (8, _) => {
            let j = r.random_range(0..n);
            items.swap(i, j);
        }
        (9, _) => {
            let id = pick(r, &OTHER_IDS);
            if let Some(mut msg) = apm::MavMessage::default_message_from_id(id) {
                tweak(r, &mut msg);
                let rx = items[i].rx_us;
                items.insert(
                    i,
                    Item {
                        rx_us: rx,
                        msg,
                        sys: items[i].sys,
                        comp: items[i].comp,
                    },
                );
            }
        }
        (10, _) => {
            // The other autopilot's messages spliced in.
            let other = Stream {
                autopilot: match stream.autopilot {
                    Autopilot::Px4 => Autopilot::Ardupilot,
                    Autopilot::Ardupilot => Autopilot::Px4,
                },
                gnss: r.random(),
            };
            let tick = next_tick.saturating_sub(r.random_range(0..40));
            let rx = items[i].rx_us;
            let extra: Vec<Item> = scenario::messages(other, tick)
                .into_iter()
                .map(|m| Item {
                    rx_us: rx,
                    msg: m.msg,
                    sys: u32::from(scenario::AP_SYS),
                    comp: scenario::AP_COMP,
                })
                .collect();
            items.splice(i..i, extra);
        }
        (11, _) => {
            // The autopilot's clock restarts (a reboot) or jumps, consistently from message i
            // on: every later stamp moves by the same step, so that the clock can confirm it
            // (a lone odd stamp is held, docs/RELIABILITY.md).
            let Some(t_i) = (i..n).find_map(|j| time_of(&items[j].msg)) else {
                return;
            };
            let to = pick(
                r,
                &[
                    0,
                    20_000,
                    1_000_000,
                    t_i.saturating_sub(5_000_000),
                    t_i.saturating_add(60_000_000),
                    t_i.saturating_add(3_600_000_000),
                ],
            );
            for it in items.iter_mut().skip(i) {
                if let Some(t) = time_of(&it.msg) {
                    set_time(&mut it.msg, t.saturating_sub(t_i).saturating_add(to));
                }
            }
        }
        _ => {
            // A link outage, or a burst (everything from i on arrives at once).
            let gap = pick(r, &[0, 5_000_000, 3_600_000_000, u64::from(u32::MAX)]);
            let base = items[i].rx_us;
            for it in items.iter_mut().skip(i) {
                it.rx_us = if gap == 0 {
                    base
                } else {
                    it.rx_us.saturating_add(gap)
                };
            }
        }
    }
}

fn mutate_frame(r: &mut ChaCha8Rng, frames: &mut [(u64, FrameSpec)]) {
    let i = r.random_range(0..frames.len());
    let prev_ts = i
        .checked_sub(1)
        .and_then(|j| frames[j].1.signature.map(|s| s.timestamp));
    let f = &mut frames[i].1;
    match r.random_range(0..12) {
        0..=2 => {
            let w = pick(r, &[1_usize, 2, 4, 8]);
            let at = r.random_range(0..=f.payload.len().max(w).min(255 - w));
            let pats = extremes(w);
            let p = &pats[r.random_range(0..pats.len())];
            if f.payload.len() < at + w {
                f.payload.resize(at + w, 0);
            }
            f.payload[at..at + w].copy_from_slice(p);
        }
        3 => {
            for _ in 0..r.random_range(1..=4) {
                if !f.payload.is_empty() {
                    let k = r.random_range(0..f.payload.len());
                    f.payload[k] = r.random();
                }
            }
        }
        4 => {
            if r.random_bool(0.5) {
                let k = r.random_range(0..=f.payload.len());
                f.payload.truncate(k);
            } else {
                let k = r.random_range(1..=32);
                let extra = rand_bytes(r, k);
                f.payload.extend(extra);
                f.payload.truncate(255);
            }
        }
        5 => {
            f.version = match f.version {
                MavlinkVersion::V1 => MavlinkVersion::V2,
                MavlinkVersion::V2 => MavlinkVersion::V1,
            }
        }
        6 => {
            f.msg_id = if r.random_bool(0.8) {
                pick(r, &OTHER_IDS)
            } else {
                r.random_range(0..1 << 24)
            }
        }
        7 => f.seq = r.random(),
        8 => f.crc_xor = r.random_range(1..=u16::MAX),
        9 => {
            if r.random_bool(0.5) {
                let any = r.random();
                f.extra_iflags = pick(r, &[0x02, 0x04, 0x80, any]);
            } else {
                f.compat = r.random();
            }
        }
        _ => {
            f.signature = match (f.signature, r.random_range(0..6)) {
                (_, 0) => None,
                (Some(s), 1) => Some(Signature {
                    key: [0x55; 32],
                    ..s
                }),
                (Some(s), 2) => Some(Signature {
                    timestamp: prev_ts.unwrap_or(s.timestamp),
                    ..s
                }),
                (Some(s), 3) => Some(Signature {
                    timestamp: pick(r, &[0, (1 << 48) - 1, 1, SIGNATURE_TS_BASE - 1]),
                    ..s
                }),
                (Some(s), 4) => Some(Signature {
                    link_id: r.random(),
                    ..s
                }),
                _ => Some(Signature {
                    link_id: 0,
                    timestamp: SIGNATURE_TS_BASE + 1_000,
                    key: SIGNING_KEY,
                }),
            }
        }
    }
}

fn mutate_bytes(r: &mut ChaCha8Rng, d: &mut Vec<Datagram>, op: u32) {
    if d.is_empty() {
        d.push(Datagram {
            dt_us: 0,
            bytes: Vec::new(),
        });
    }
    let i = r.random_range(0..d.len());
    let len = d[i].bytes.len();
    match (op - 80) % 10 {
        0 | 1 if len > 0 => {
            let k = r.random_range(0..len);
            d[i].bytes[k] ^= 1 << r.random_range(0..8);
        }
        2 if len > 0 => {
            let k = r.random_range(0..len);
            d[i].bytes[k] = pick(r, &[0x00, 0xff, 0xfd, 0xfe, 0x7f, 0x80, 0x01]);
        }
        3 => {
            let k = r.random_range(0..=len);
            let n = r.random_range(1..=16);
            let extra = rand_bytes(r, n);
            d[i].bytes.splice(k..k, extra);
        }
        4 if len > 0 => {
            let a = r.random_range(0..len);
            let b = r.random_range(a..=len.min(a + 24));
            d[i].bytes.drain(a..b);
        }
        5 if len > 0 => {
            let a = r.random_range(0..len);
            let b = r.random_range(a..=len);
            let copy = d[i].bytes[a..b].to_vec();
            d[i].bytes.splice(b..b, copy);
        }
        6 => {
            let k = r.random_range(0..=len);
            if r.random_bool(0.5) {
                d[i].bytes.truncate(k);
            } else {
                // Split: the rest arrives later in its own datagram.
                let tail = d[i].bytes.split_off(k);
                let dt_us = pick(r, &[0, 1, 10_000, 3_000_000]);
                d.insert(i + 1, Datagram { dt_us, bytes: tail });
            }
        }
        7 if d.len() > 1 && i + 1 < d.len() => {
            let next = d.remove(i + 1);
            d[i].bytes.extend(next.bytes);
        }
        8 => {
            // Garbage with a plausible start: a start marker and a length.
            let mut g = vec![pick(r, &[0xfd_u8, 0xfe]), r.random()];
            let n = r.random_range(0..64);
            g.extend(rand_bytes(r, n));
            let any = r.random();
            let dt_us = pick(r, &[0, 1_000, any]);
            d.insert(i, Datagram { dt_us, bytes: g });
        }
        _ => {
            let j = r.random_range(0..d.len());
            let src = d[j].bytes.clone();
            if !src.is_empty() {
                let a = r.random_range(0..src.len());
                let b = r.random_range(a..=src.len());
                let k = r.random_range(0..=d[i].bytes.len());
                d[i].bytes.splice(k..k, src[a..b].iter().copied());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extreme_patterns_are_the_integer_limits_and_float_specials() {
        assert_eq!(extremes(2)[2], i16::MAX.to_le_bytes());
        assert_eq!(extremes(2)[3], i16::MIN.to_le_bytes());
        assert_eq!(extremes(4)[2], i32::MAX.to_le_bytes());
        assert!(f32::from_le_bytes(extremes(4)[4][..].try_into().unwrap()).is_nan());
        assert_eq!(extremes(8)[3], i64::MIN.to_le_bytes());
        assert_eq!(extremes(1).len(), 4);
    }
}
