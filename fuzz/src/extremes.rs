//! The exhaustive part: every message the daemon acts on, with every field at its extremes,
//! through the whole input path of a flying daemon and followed by valid traffic.
//!
//! Fields are not looked up by name: every byte offset of the full (untrimmed) payload gets
//! every width (1, 2, 4, 8 bytes) at every extreme pattern of [`mutate::extremes`] (integer 0,
//! all ones, signed max and min; for 4 and 8 bytes NaN, ±∞, ±max, and for 4 bytes the
//! smallest normal and −0). That covers each field of each type at its min/max (and each
//! float at NaN/±∞) whatever the layout, extension fields at odd offsets included.

use mavlink::MessageData;
use mavlink::dialects::ardupilotmega as apm;

use crate::input::{Input, Stage, Start, Starts};
use crate::mutate;
use crate::pipeline::{Datagram, Variant};
use crate::scenario::{self, Autopilot, Stream};
use crate::wire::FrameSpec;

/// (name, id, full payload length) of every message the input path acts on.
pub const ACCEPTED: [(&str, u32, usize); 15] = [
    (
        "HEARTBEAT",
        apm::HEARTBEAT_DATA::ID,
        apm::HEARTBEAT_DATA::ENCODED_LEN,
    ),
    (
        "SYSTEM_TIME",
        apm::SYSTEM_TIME_DATA::ID,
        apm::SYSTEM_TIME_DATA::ENCODED_LEN,
    ),
    (
        "TIMESYNC",
        apm::TIMESYNC_DATA::ID,
        apm::TIMESYNC_DATA::ENCODED_LEN,
    ),
    (
        "HIGHRES_IMU",
        apm::HIGHRES_IMU_DATA::ID,
        apm::HIGHRES_IMU_DATA::ENCODED_LEN,
    ),
    (
        "SCALED_IMU",
        apm::SCALED_IMU_DATA::ID,
        apm::SCALED_IMU_DATA::ENCODED_LEN,
    ),
    (
        "RAW_IMU",
        apm::RAW_IMU_DATA::ID,
        apm::RAW_IMU_DATA::ENCODED_LEN,
    ),
    (
        "SCALED_PRESSURE",
        apm::SCALED_PRESSURE_DATA::ID,
        apm::SCALED_PRESSURE_DATA::ENCODED_LEN,
    ),
    (
        "SCALED_PRESSURE2",
        apm::SCALED_PRESSURE2_DATA::ID,
        apm::SCALED_PRESSURE2_DATA::ENCODED_LEN,
    ),
    (
        "AIRSPEED",
        apm::AIRSPEED_DATA::ID,
        apm::AIRSPEED_DATA::ENCODED_LEN,
    ),
    (
        "VFR_HUD",
        apm::VFR_HUD_DATA::ID,
        apm::VFR_HUD_DATA::ENCODED_LEN,
    ),
    (
        "AOA_SSA",
        apm::AOA_SSA_DATA::ID,
        apm::AOA_SSA_DATA::ENCODED_LEN,
    ),
    (
        "ATTITUDE",
        apm::ATTITUDE_DATA::ID,
        apm::ATTITUDE_DATA::ENCODED_LEN,
    ),
    (
        "GLOBAL_POSITION_INT",
        apm::GLOBAL_POSITION_INT_DATA::ID,
        apm::GLOBAL_POSITION_INT_DATA::ENCODED_LEN,
    ),
    (
        "GPS_RAW_INT",
        apm::GPS_RAW_INT_DATA::ID,
        apm::GPS_RAW_INT_DATA::ENCODED_LEN,
    ),
    (
        "COMMAND_ACK",
        apm::COMMAND_ACK_DATA::ID,
        apm::COMMAND_ACK_DATA::ENCODED_LEN,
    ),
];

/// Valid ticks after each patched message (the daemon must keep navigating on them).
pub const FOLLOW_TICKS: u64 = 6;

/// Outcome of the sweep for one message type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MessageSweep {
    /// Message name.
    pub name: &'static str,
    /// Cases run.
    pub cases: u64,
    /// Payloads the dialect refused (an invalid enum value).
    pub parse_errors: u64,
    /// Cases that ended in a known finding (`fuzz/known-findings.txt`).
    pub known: u64,
    /// Cases after which the valid traffic gave no solution (a time jump, a reboot taken, an
    /// autopilot change: the daemon's time handling, reported, not an oracle failure).
    pub stalled: u64,
    /// The patched byte ranges (and variant) of the stalled cases.
    pub stalled_at: Vec<String>,
}

/// A failed case: which, why, and the input that reproduces it.
#[derive(Debug, Clone)]
pub struct SweepFailure {
    /// What was patched.
    pub case: String,
    /// The violation or panic message.
    pub message: String,
    /// The reproducer.
    pub input: Input,
}

fn template(start: &Start, id: u32) -> Option<(u64, u64, apm::MavMessage)> {
    // The start's own stream first, then the other autopilot's (HIGHRES_IMU to ArduPilot…).
    let other = Stream {
        autopilot: match start.stream.autopilot {
            Autopilot::Px4 => Autopilot::Ardupilot,
            Autopilot::Ardupilot => Autopilot::Px4,
        },
        gnss: true,
    };
    for s in [start.stream, other] {
        for tick in start.tick..start.tick + 100 {
            let found = scenario::messages(s, tick)
                .into_iter()
                .find(|m| mavlink::Message::message_id(&m.msg) == id);
            if let Some(m) = found {
                return Some((tick, m.rx_us, m.msg));
            }
        }
    }
    None
}

/// Run the sweep on the flying daemons of both variants. `run` executes one input (catching
/// panics) and returns its solution count and parse errors (`None`: a known finding), or the
/// failure message.
pub fn sweep(
    starts: &Starts,
    mut run: impl FnMut(&Input) -> Result<Option<(u64, u64)>, String>,
) -> Result<Vec<MessageSweep>, Box<SweepFailure>> {
    let mut out: Vec<MessageSweep> = ACCEPTED
        .iter()
        .map(|(name, _, _)| MessageSweep {
            name,
            cases: 0,
            parse_errors: 0,
            known: 0,
            stalled: 0,
            stalled_at: Vec::new(),
        })
        .collect();
    for (si, start) in starts.0.iter().enumerate() {
        if start.stage != Stage::Flying {
            continue;
        }
        for (k, (name, id, len)) in ACCEPTED.iter().enumerate() {
            let Some((tick, rx_us, msg)) = template(start, *id) else {
                continue;
            };
            let mut seq = start.seq;
            let mut base = FrameSpec::of(
                &msg,
                mavlink::MavlinkVersion::V2,
                u32::from(scenario::AP_SYS),
                scenario::AP_COMP,
                seq,
            );
            base.payload.resize(*len, 0);
            // The valid traffic after it, from the next tick on.
            let mut follow = Vec::new();
            let mut t = rx_us;
            for tk in tick + 1..=tick + FOLLOW_TICKS {
                for m in scenario::messages(start.stream, tk) {
                    seq = seq.wrapping_add(1);
                    follow.push(Datagram {
                        dt_us: u32::try_from(m.rx_us - t).unwrap_or(u32::MAX),
                        bytes: crate::wire::frame(
                            &m.msg,
                            mavlink::MavlinkVersion::V2,
                            u32::from(scenario::AP_SYS),
                            scenario::AP_COMP,
                            seq,
                        ),
                    });
                    t = m.rx_us;
                }
            }
            let first_dt =
                u32::try_from(rx_us.saturating_sub(start.pipeline.now_us())).unwrap_or(u32::MAX);
            for w in [1_usize, 2, 4, 8] {
                for at in 0..=len.saturating_sub(w) {
                    for pat in mutate::extremes(w) {
                        let mut f = base.clone();
                        f.payload[at..at + w].copy_from_slice(&pat);
                        let mut datagrams = vec![Datagram {
                            dt_us: first_dt,
                            bytes: f.encode(),
                        }];
                        datagrams.extend(follow.iter().cloned());
                        let input = Input {
                            start: si as u8,
                            link: 0,
                            datagrams,
                        };
                        let s = &mut out[k];
                        s.cases += 1;
                        let variant = match start.variant {
                            Variant::Px4 => "PX4",
                            Variant::Ardupilot => "ArduPilot",
                        };
                        match run(&input) {
                            Ok(None) => s.known += 1,
                            Ok(Some((solutions, parse_errors))) => {
                                s.parse_errors += parse_errors;
                                if solutions == 0 {
                                    s.stalled += 1;
                                    let at = format!("{variant} {at}..{}", at + w);
                                    if !s.stalled_at.contains(&at) {
                                        s.stalled_at.push(at);
                                    }
                                }
                            }
                            Err(message) => {
                                return Err(Box::new(SweepFailure {
                                    case: format!(
                                        "{name} bytes {at}..{} = {pat:02x?} ({variant})",
                                        at + w
                                    ),
                                    message,
                                    input,
                                }));
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(out)
}
