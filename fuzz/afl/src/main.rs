//! AFL++ target over the same path and oracle as `ianav-fuzz run`: the input is the byte form
//! of [`Input`] (`ianav-fuzz corpus` writes seeds). A panic or a new violation aborts (an AFL
//! crash); findings listed in `fuzz/known-findings.txt` do not, or they would drown the rest.

use ianav_fuzz::input::{Input, Starts};
use ianav_fuzz::{Outcome, known_findings};

fn main() {
    let starts = Starts::build().expect("warm-up on valid traffic");
    let known = known_findings();
    afl::fuzz!(|data: &[u8]| {
        if let Err(v) = starts.run(&Input::from_bytes(data)) {
            let sig = Outcome::Violation(v.0.clone()).signature();
            if !known.iter().any(|(k, _)| *k == sig) {
                panic!("{v}");
            }
        }
    });
}
