//! Fuzzing of ianav's whole input path on stable Rust (docs/RELIABILITY.md):
//! bytes → MAVLink frames (the mavlink crate's reader, v1 and v2, signed and unsigned, as
//! the daemon's connection reads them) → messages (`MavMessage::parse`) → sensor events (the
//! daemon's [`InputDecoder`](ianav::io::mavlink_in::InputDecoder), time mapping and gates) →
//! navigation (the [`Navigator`](ianav::nav::Navigator) stepped as the navigation thread does).
//!
//! It is a structure-aware mutation fuzzer without coverage feedback: each input is generated
//! from a seeded RNG (same seed, same inputs), starting from a daemon warmed up on valid
//! traffic ([`input::Starts`]) and continuing its stream with mutations at the message, frame
//! and byte levels ([`mutate`]). [`extremes`] adds the exhaustive sweep of every field of every
//! accepted message at its extremes. The oracle is in [`pipeline`]: no panic (run it in the
//! `ci` profile: overflow checks and debug assertions on), every event within the decoder's
//! limits, counters consistent, every solution finite.

pub mod extremes;
pub mod input;
pub mod mutate;
pub mod pipeline;
pub mod scenario;
pub mod wire;

use std::cell::RefCell;
use std::panic::{self, AssertUnwindSafe};
use std::sync::Once;

use input::{Input, Starts};
use pipeline::Stats;

/// What running one input gave.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// All properties held.
    Pass(Box<Stats>),
    /// The oracle found a broken property.
    Violation(String),
    /// A panic: its message and location.
    Panic(String),
}

impl Outcome {
    /// Whether this is a finding.
    pub fn failed(&self) -> bool {
        !matches!(self, Outcome::Pass(_))
    }

    /// What identifies the finding: the violated property (its text before the first ':'),
    /// or the panic's location. Used to tell findings apart, to keep a minimised input
    /// failing the same way, and to match the known findings.
    pub fn signature(&self) -> String {
        match self {
            Outcome::Pass(_) => String::new(),
            Outcome::Violation(m) => {
                format!("violation: {}", m.split(':').next().unwrap_or(m))
            }
            Outcome::Panic(m) => {
                format!("panic at {}", m.rsplit(" at ").next().unwrap_or(m))
            }
        }
    }
}

/// Whether `o` is a finding listed in `fuzz/known-findings.txt`.
pub fn is_known(o: &Outcome) -> bool {
    static KNOWN: std::sync::OnceLock<Vec<(String, String)>> = std::sync::OnceLock::new();
    let sig = o.signature();
    o.failed()
        && KNOWN
            .get_or_init(known_findings)
            .iter()
            .any(|(k, _)| *k == sig)
}

/// Findings that are reported and tracked but do not fail a run (`fuzz/known-findings.txt`):
/// (signature, reason).
pub fn known_findings() -> Vec<(String, String)> {
    include_str!("../known-findings.txt")
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|l| match l.split_once('\t') {
            Some((sig, why)) => (sig.trim().to_owned(), why.trim().to_owned()),
            None => (l.trim().to_owned(), String::new()),
        })
        .collect()
}

thread_local! {
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

static HOOK: Once = Once::new();

/// Route panics into [`run_catching`]'s result instead of stderr (once per process; panics
/// outside it are still printed).
fn install_hook() {
    HOOK.call_once(|| {
        let default = panic::take_hook();
        panic::set_hook(Box::new(move |info| {
            let msg = match info.payload().downcast_ref::<&str>() {
                Some(s) => (*s).to_owned(),
                None => info
                    .payload()
                    .downcast_ref::<String>()
                    .cloned()
                    .unwrap_or_else(|| "non-string panic".to_owned()),
            };
            let loc = info
                .location()
                .map(|l| format!("{}:{}", l.file(), l.line()))
                .unwrap_or_default();
            let caught = LAST_PANIC.with(|p| {
                let mut p = p.borrow_mut();
                if p.is_some() {
                    *p = Some(format!("{msg} at {loc}"));
                    true
                } else {
                    false
                }
            });
            if !caught {
                default(info);
            }
        }));
    });
}

/// Run `f`, returning its panic's message and location instead of unwinding.
pub fn catching<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    install_hook();
    // A placeholder marks "inside `catching`" for the hook.
    LAST_PANIC.with(|p| *p.borrow_mut() = Some(String::new()));
    let r = panic::catch_unwind(AssertUnwindSafe(f));
    let msg = LAST_PANIC
        .with(|p| p.borrow_mut().take())
        .unwrap_or_default();
    r.map_err(|_| msg)
}

/// Run `input`, catching a panic.
pub fn run_catching(starts: &Starts, input: &Input) -> Outcome {
    match catching(|| starts.run(input)) {
        Ok(Ok(stats)) => Outcome::Pass(Box::new(stats)),
        Ok(Err(v)) => Outcome::Violation(v.0),
        Err(msg) => Outcome::Panic(msg),
    }
}

/// Shrink a failing input while it fails with the same [`Outcome::signature`]: drop
/// datagrams, then byte ranges, halving the chunk size (at most `budget` runs).
pub fn minimise(starts: &Starts, input: &Input, budget: u32) -> Input {
    let sig = run_catching(starts, input).signature();
    let mut best = input.clone();
    let mut runs = 0_u32;
    let still_fails = |c: &Input, runs: &mut u32| {
        *runs += 1;
        let o = run_catching(starts, c);
        o.failed() && o.signature() == sig
    };
    let mut chunk = best.datagrams.len().max(1);
    while chunk >= 1 && runs < budget {
        let mut i = 0;
        while i < best.datagrams.len() && runs < budget {
            let mut c = best.clone();
            let end = (i + chunk).min(c.datagrams.len());
            // Keep the time the removed datagrams carried.
            let dt: u64 = c.datagrams[i..end].iter().map(|d| u64::from(d.dt_us)).sum();
            c.datagrams.drain(i..end);
            if let Some(d) = c.datagrams.get_mut(i) {
                d.dt_us = u32::try_from(u64::from(d.dt_us) + dt).unwrap_or(u32::MAX);
            }
            if still_fails(&c, &mut runs) {
                best = c;
            } else {
                i += chunk;
            }
        }
        if chunk == 1 {
            break;
        }
        chunk /= 2;
    }
    for k in 0..best.datagrams.len() {
        let mut chunk = best.datagrams[k].bytes.len().max(1);
        while runs < budget {
            let mut i = 0;
            while i < best.datagrams[k].bytes.len() && runs < budget {
                let mut c = best.clone();
                let end = (i + chunk).min(c.datagrams[k].bytes.len());
                c.datagrams[k].bytes.drain(i..end);
                if still_fails(&c, &mut runs) {
                    best = c;
                } else {
                    i += chunk;
                }
            }
            if chunk == 1 {
                break;
            }
            chunk /= 2;
        }
    }
    best
}

/// FNV-1a, to fingerprint a run (same seed and count: same digest).
pub fn fnv1a(mut h: u64, bytes: &[u8]) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}

/// FNV-1a offset basis.
pub const FNV_BASIS: u64 = 0xcbf2_9ce4_8422_2325;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_is_returned_with_its_location_and_later_ones_still_print() {
        let r = catching(|| -> u8 { panic!("boom {}", 7) });
        let msg = r.unwrap_err();
        assert!(msg.starts_with("boom 7 at "), "{msg}");
        assert!(msg.contains("lib.rs"), "{msg}");
        assert_eq!(catching(|| 5), Ok(5));
        assert!(LAST_PANIC.with(|p| p.borrow().is_none()));
    }
}
