//! A fuzz input, its byte form (reproducer files, external fuzzers) and the warmed-up
//! pipelines inputs start from.

use anyhow::Context;

use crate::pipeline::{Datagram, LinkMode, Pipeline, Variant, Violation, config};
use crate::scenario::{self, Autopilot, Stream};
use crate::wire;
use mavlink::MavlinkVersion;

/// One input: the warmed-up daemon it is fed to, the link's signing mode, the datagrams.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Input {
    /// Index into [`Starts`] (taken modulo their number).
    pub start: u8,
    /// Index into [`LinkMode::ALL`] (modulo 3).
    pub link: u8,
    /// What arrives, in order.
    pub datagrams: Vec<Datagram>,
}

impl Input {
    /// Byte form: `start`, `link`, then per datagram `dt_us` (u32 LE), length (u16 LE), bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = vec![self.start, self.link];
        for d in &self.datagrams {
            b.extend_from_slice(&d.dt_us.to_le_bytes());
            let n = d.bytes.len().min(usize::from(u16::MAX));
            b.extend_from_slice(&(n as u16).to_le_bytes());
            b.extend_from_slice(&d.bytes[..n]);
        }
        b
    }

    /// Parse the byte form. Total: any bytes are an input (a short tail is one datagram), so
    /// that a byte-level fuzzer's every mutation is run.
    pub fn from_bytes(b: &[u8]) -> Self {
        let start = b.first().copied().unwrap_or(0);
        let link = b.get(1).copied().unwrap_or(0);
        let mut rest = b.get(2..).unwrap_or(&[]);
        let mut datagrams = Vec::new();
        while !rest.is_empty() {
            if rest.len() < 6 {
                datagrams.push(Datagram {
                    dt_us: 0,
                    bytes: rest.to_vec(),
                });
                break;
            }
            let dt_us = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]);
            let n = usize::from(u16::from_le_bytes([rest[4], rest[5]]));
            let body = &rest[6..];
            let n = n.min(body.len());
            datagrams.push(Datagram {
                dt_us,
                bytes: body[..n].to_vec(),
            });
            rest = &body[n..];
        }
        Self {
            start,
            link,
            datagrams,
        }
    }
}

/// How far a start's daemon got.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Just started: no autopilot yet.
    Fresh,
    /// Autopilot locked and time mapped, the INS not started.
    Linked,
    /// The INS runs with GNSS, started for flight.
    Flying,
    /// GNSS lost for 3 s: the INS is in GNSS-denied mode.
    Denied,
    /// GNSS back for 4.8 s after the loss: the fix 0.2 s later re-initialises the INS.
    Returning,
}

/// A warmed-up daemon and where the autopilot's stream continues.
#[derive(Debug, Clone)]
pub struct Start {
    /// The configuration.
    pub variant: Variant,
    /// How far it got.
    pub stage: Stage,
    /// The stream it was fed.
    pub stream: Stream,
    /// The next tick of that stream.
    pub tick: u64,
    /// The next sequence number.
    pub seq: u8,
    /// The daemon.
    pub pipeline: Pipeline,
}

/// All starts, in [`Input::start`] order.
#[derive(Debug, Clone)]
pub struct Starts(pub Vec<Start>);

fn feed_ticks(
    p: &mut Pipeline,
    stream: Stream,
    ticks: std::ops::Range<u64>,
    seq: &mut u8,
) -> Result<(), Violation> {
    let mut datagrams = Vec::new();
    let mut now = p.now_us();
    for tick in ticks {
        for m in scenario::messages(stream, tick) {
            let bytes = wire::frame(
                &m.msg,
                MavlinkVersion::V2,
                u32::from(scenario::AP_SYS),
                scenario::AP_COMP,
                *seq,
            );
            *seq = seq.wrapping_add(1);
            datagrams.push(Datagram {
                dt_us: u32::try_from(m.rx_us.saturating_sub(now)).unwrap_or(u32::MAX),
                bytes,
            });
            now = now.max(m.rx_us);
        }
    }
    p.feed(LinkMode::Open, &datagrams)
}

impl Starts {
    /// Warm up every (variant, stage) on valid traffic. Fails if a stage is not reached: the
    /// fuzzer would silently stop covering it.
    pub fn build() -> anyhow::Result<Self> {
        let mut out = Vec::new();
        for (variant, autopilot) in [
            (Variant::Px4, Autopilot::Px4),
            (Variant::Ardupilot, Autopilot::Ardupilot),
        ] {
            let with_gnss = Stream {
                autopilot,
                gnss: true,
            };
            let without = Stream {
                autopilot,
                gnss: false,
            };
            let mut p = Pipeline::new(config(variant)?, scenario::rx_us(0) - 1_000)?;
            let mut seq = 0_u8;
            let mut push = |stage, stream, tick, seq, p: &Pipeline| {
                out.push(Start {
                    variant,
                    stage,
                    stream,
                    tick,
                    seq,
                    pipeline: p.clone(),
                })
            };
            push(Stage::Fresh, with_gnss, 0, seq, &p);
            let fail = |v: Violation| anyhow::anyhow!("warm-up of {variant:?}: {v}");
            feed_ticks(&mut p, with_gnss, 0..20, &mut seq).map_err(fail)?;
            anyhow::ensure!(!p.nav_running(), "{variant:?}: INS started within 0.2 s");
            push(Stage::Linked, with_gnss, 20, seq, &p);
            feed_ticks(&mut p, with_gnss, 20..400, &mut seq).map_err(fail)?;
            anyhow::ensure!(
                p.nav_running() && !p.gnss_denied(),
                "{variant:?}: INS not running with GNSS after 4 s: {:?}",
                p.stats
            );
            push(Stage::Flying, with_gnss, 400, seq, &p);
            feed_ticks(&mut p, without, 400..700, &mut seq).map_err(fail)?;
            anyhow::ensure!(p.gnss_denied(), "{variant:?}: not GNSS-denied after 3 s");
            push(Stage::Denied, without, 700, seq, &p);
            feed_ticks(&mut p, with_gnss, 700..1_200, &mut seq).map_err(fail)?;
            anyhow::ensure!(p.gnss_denied(), "{variant:?}: re-initialised before 5 s");
            push(Stage::Returning, with_gnss, 1_200, seq, &p);
        }
        Ok(Self(out))
    }

    /// The start of `input`.
    pub fn of(&self, input: &Input) -> &Start {
        &self.0[usize::from(input.start) % self.0.len()]
    }

    /// Run `input`: a clone of its start's daemon reads its datagrams. Returns the counters
    /// of this input, or the broken property.
    pub fn run(&self, input: &Input) -> Result<crate::pipeline::Stats, Violation> {
        let mut p = self.of(input).pipeline.clone();
        p.stats = Default::default();
        let mode = LinkMode::ALL[usize::from(input.link) % LinkMode::ALL.len()];
        p.feed(mode, &input.datagrams)?;
        Ok(p.stats)
    }
}

/// Read an input file (the byte form).
pub fn read_input(path: &std::path::Path) -> anyhow::Result<Input> {
    let b = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(Input::from_bytes(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_byte_form_round_trips_and_any_bytes_parse() {
        let i = Input {
            start: 3,
            link: 1,
            datagrams: vec![
                Datagram {
                    dt_us: 7,
                    bytes: vec![1, 2, 3],
                },
                Datagram {
                    dt_us: u32::MAX,
                    bytes: vec![],
                },
            ],
        };
        assert_eq!(Input::from_bytes(&i.to_bytes()), i);
        for b in [&[][..], &[1], &[1, 2, 3], &[0, 0, 1, 0, 0, 0, 255, 255, 9]] {
            let _ = Input::from_bytes(b);
        }
    }
}
