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

/// `--states`: one line of internal estimates per written solution, at the same times, with
/// every column of the header; the solutions themselves unchanged by asking for them. The
/// estimates are the filters' own: the wind after the GNSS loss is the frozen one (constant),
/// and the magnetic-model error stays within 5 σ of the cold start.
#[test]
fn states_come_beside_the_same_solutions() {
    use ianav::nav::replay::{STATES_HEADER, replay_to_csvs};
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let log = std::fs::read(root.join(LOG)).unwrap();
    let reference = std::fs::read_to_string(root.join(REFERENCE)).unwrap();
    let (mut out, mut states) = (Vec::new(), Vec::new());
    replay_to_csvs(
        SensorLogReader::new(&log[..]).unwrap(),
        &[],
        10,
        &mut out,
        Some(&mut states),
    )
    .unwrap();
    assert_eq!(String::from_utf8(out).unwrap(), reference);
    let states = String::from_utf8(states).unwrap();
    let mut lines = states.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header.join(","), STATES_HEADER);
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.parse().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    let solution_times: Vec<f64> = reference
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(rows.len(), solution_times.len());
    for (row, t) in rows.iter().zip(&solution_times) {
        assert_eq!(row.len(), header.len());
        assert_eq!(row[0], *t);
        for i in 1..header.len() - 1 {
            assert!(row[i].is_finite(), "{} at {t}: {}", header[i], row[i]);
        }
    }
    // After the loss (the last quarter of the log) the wind is frozen.
    let tail = &rows[rows.len() * 3 / 4..];
    for c in ["wind_n_mps", "wind_e_mps"] {
        assert!(tail.iter().all(|r| r[col(c)] == tail[0][col(c)]), "{c}");
    }
    let sigma = ianav::ins::COLD_DELTA_B_SIGMA_NT;
    for (k, c) in ["delta_b_n_nt", "delta_b_e_nt", "delta_b_d_nt"]
        .into_iter()
        .enumerate()
    {
        assert!(rows.iter().all(|r| r[col(c)].abs() < 5.0 * sigma[k]), "{c}");
    }
}
