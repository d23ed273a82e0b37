//! The navigation core's regression test on a committed sensor log (the PX4 EKF2 replay
//! practice): `tests/data/replay/scenario2-short.bin`, a simulated flight of scenario #2
//! shortened to 50 s (GNSS lost at 30 s of sensor time, docs/REPLAY.md), replayed with the
//! settings recorded in it, must give `scenario2-short.solutions.csv` (every 10th solution)
//! exactly. Any change of the navigation output fails here: fix it, or regenerate the
//! reference with the command in docs/REPLAY.md and say in the commit why it changed.

use std::path::Path;

use ianav::io::sensor_log::SensorLogReader;
use ianav::nav::replay::replay_to_csv;

const LOG: &str = "tests/data/replay/scenario2-short.bin";
const REFERENCE: &str = "tests/data/replay/scenario2-short.solutions.csv";

#[test]
fn the_committed_log_replays_to_the_committed_solutions() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let log = std::fs::read(root.join(LOG)).unwrap();
    let reference = std::fs::read_to_string(root.join(REFERENCE)).unwrap();
    let mut out = Vec::new();
    let summary = replay_to_csv(SensorLogReader::new(&log[..]).unwrap(), 10, &mut out).unwrap();
    let out = String::from_utf8(out).unwrap();
    // The log goes through the GNSS loss: the reference covers both phases.
    let last = summary.last.unwrap();
    assert!(last.ins_status.gnss_denied && summary.nav.initialisations == 1);
    if out == reference {
        return;
    }
    let new_path = std::env::temp_dir().join("ianav-replay-scenario2-short.solutions.csv");
    std::fs::write(&new_path, &out).unwrap();
    let (lines, ref_lines): (Vec<&str>, Vec<&str>) =
        (out.lines().collect(), reference.lines().collect());
    let first = lines
        .iter()
        .zip(&ref_lines)
        .position(|(a, b)| a != b)
        .unwrap_or(lines.len().min(ref_lines.len()));
    panic!(
        "navigation output changed: {} lines against {} in the reference; first difference at \
         line {}:\n  now: {}\n  ref: {}\nnew output written to {} (docs/REPLAY.md: fix, or \
         re-commit with the reason)",
        lines.len(),
        ref_lines.len(),
        first + 1,
        lines.get(first).unwrap_or(&"(none)"),
        ref_lines.get(first).unwrap_or(&"(none)"),
        new_path.display()
    );
}
