//! The paper's five result tables (section "Results", tables `tab:Res_vis_assist_results_euler`,
//! `…_h`, `…_hor`, and section "Influence of the terrain", `tab:Ana_vis_assist_zone_results_hor_*`),
//! ours from the run files beside the paper's printed numbers, for `ianav-sim table`.
//!
//! Every statistic is over the runs where both visual systems track at t_end (the paper's
//! systems never lose track over these zones); how many runs that is, of how many flown, is
//! stated with each block. mean, population σ and the value of largest magnitude with its sign,
//! as the paper's tables (docs/MONTECARLO.md).

use std::fmt::Write as _;

use super::{Stats, stats};
use crate::metrics::{NseSample, format_fixed};
use crate::montecarlo::{RunOutcome, RunRecord};

/// One of the paper's tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PaperTable {
    /// Final body attitude errors (Euler angles and norm), scenarios #1 and #2 over MX.
    Attitude,
    /// Final altitude errors, scenarios #1 and #2 over MX.
    Altitude,
    /// Final horizontal position errors, scenarios #1 and #2 over MX.
    Horizontal,
    /// Final horizontal IA-VNS error over MX, FR, FM and DS, scenario #1.
    Terrain1,
    /// Final horizontal IA-VNS error over the six zones, scenario #2.
    Terrain2,
}

/// The paper's mean, σ and largest of one quantity (NaN where it prints none).
type Printed = [f64; 3];

/// The paper's attitude table, per scenario: INS, VNS, IA-VNS × (ψ, θ, ξ, norm), each
/// (mean, σ, max).
const PAPER_ATTITUDE: [[[Printed; 4]; 3]; 2] = [
    [
        [
            [0.03, 0.18, -0.61],
            [-0.03, 0.05, -0.27],
            [-0.00, 0.06, -0.23],
            [0.158, 0.114, 0.611],
        ],
        [
            [0.03, 0.13, 0.63],
            [0.08, 0.23, 0.74],
            [0.00, 0.21, 0.78],
            [0.296, 0.158, 0.791],
        ],
        [
            [0.03, 0.11, 0.55],
            [-0.01, 0.16, -0.37],
            [-0.03, 0.14, -0.51],
            [0.218, 0.103, 0.606],
        ],
    ],
    [
        [
            [-0.02, 0.13, 0.33],
            [0.01, 0.05, -0.15],
            [0.00, 0.05, 0.15],
            [0.128, 0.078, 0.369],
        ],
        [
            [0.02, 0.08, 0.22],
            [-0.02, 0.21, -0.65],
            [0.00, 0.20, -0.73],
            [0.253, 0.161, 0.730],
        ],
        [
            [0.02, 0.08, 0.24],
            [-0.00, 0.16, 0.62],
            [0.01, 0.19, 0.74],
            [0.221, 0.137, 0.788],
        ],
    ],
];

/// The paper's altitude table, per scenario: INS, VNS, IA-VNS, each (mean, σ, max), m.
const PAPER_ALTITUDE: [[Printed; 3]; 2] = [
    [
        [-4.18, 25.78, -70.49],
        [82.91, 287.58, 838.32],
        [22.86, 49.17, 175.76],
    ],
    [
        [0.76, 7.55, -19.86],
        [3.45, 20.56, 72.69],
        [3.59, 13.01, 71.64],
    ],
];

/// The paper's horizontal table, per scenario: distance, INS m, INS %, VNS m, VNS %,
/// IA-VNS m, IA-VNS %, each (mean, σ, max).
const PAPER_HORIZONTAL: [[Printed; 7]; 2] = [
    [
        [107_873.0, 19_756.0, 172_842.0],
        [7276.0, 4880.0, 25_288.0],
        [7.10, 5.69, 32.38],
        [4179.0, 3308.0, 21_924.0],
        [3.82, 2.73, 14.22],
        [488.0, 350.0, 1957.0],
        [0.46, 0.31, 1.48],
    ],
    [
        [14_198.0, 1176.0, 18_253.0],
        [216.0, 119.0, 586.0],
        [1.52, 0.86, 4.38],
        [251.0, 210.0, 954.0],
        [1.77, 1.48, 7.08],
        [33.0, 26.0, 130.0],
        [0.23, 0.18, 0.98],
    ],
];

/// The paper's terrain tables: zone, IA-VNS m and % (mean, σ, max).
const PAPER_TERRAIN1: [(&str, Printed, Printed); 4] = [
    ("mx", [488.0, 350.0, 1957.0], [0.46, 0.31, 1.48]),
    ("fr", [566.0, 406.0, 2058.0], [0.53, 0.38, 1.71]),
    ("fm", [489.0, 322.0, 1783.0], [0.45, 0.28, 1.34]),
    ("ds", [514.0, 352.0, 1667.0], [0.48, 0.31, 1.37]),
];
const PAPER_TERRAIN2: [(&str, Printed, Printed); 6] = [
    ("mx", [33.0, 26.0, 130.0], [0.23, 0.18, 0.98]),
    ("fr", [40.0, 35.0, 188.0], [0.28, 0.24, 1.29]),
    ("fm", [33.0, 24.0, 117.0], [0.23, 0.17, 0.85]),
    ("ds", [31.0, 24.0, 114.0], [0.22, 0.17, 0.86]),
    ("ur", [32.0, 25.0, 128.0], [0.23, 0.18, 0.96]),
    ("pr", [31.0, 25.0, 119.0], [0.22, 0.17, 0.90]),
];

/// The final samples of one batch's runs where both the VNS and the IA-VNS track at t_end.
struct Finals {
    flown: usize,
    /// INS, VNS, IA-VNS final samples, one triple per compared run.
    runs: Vec<[NseSample; 3]>,
    /// Runs whose IA-VNS tracks at t_end (the terrain tables' population).
    ia_vns: Vec<NseSample>,
}

fn finals(runs: &[RunRecord]) -> Finals {
    let mut f = Finals {
        flown: runs.len(),
        runs: Vec::new(),
        ia_vns: Vec::new(),
    };
    for r in runs {
        let RunOutcome::Completed {
            samples, vision, ..
        } = &r.outcome
        else {
            continue;
        };
        let end = |name: &str| {
            vision
                .iter()
                .find(|v| v.system == name)
                .and_then(|v| v.samples.last())
                .filter(|s| !s.att_norm_deg.is_nan())
                .copied()
        };
        let (ins, vns, ia) = (samples.last().copied(), end("vns"), end("ia-vns"));
        if let Some(ia) = ia {
            f.ia_vns.push(ia);
        }
        if let (Some(i), Some(v), Some(a)) = (ins, vns, ia) {
            f.runs.push([i, v, a]);
        }
    }
    f
}

/// `mean`, `std` and `max` of a column, `d` decimals; "–" when empty.
fn cells(s: Option<Stats>, d: usize) -> [String; 3] {
    match s {
        Some(s) => [s.mean, s.std, s.largest].map(|x| format_fixed(x, d)),
        None => ["–".into(), "–".into(), "–".into()],
    }
}

fn printed(p: Printed, d: usize) -> [String; 3] {
    p.map(|x| {
        if x.is_nan() {
            "–".into()
        } else {
            format_fixed(x, d)
        }
    })
}

/// Rows `{prefix}stat`, `{prefix}stat (paper)` for the three statistics, from per-column ours
/// and the paper's.
fn interleaved(md: &mut String, prefix: &str, ours: &[[String; 3]], paper: &[[String; 3]]) {
    for (k, stat) in ["mean", "std", "max"].iter().enumerate() {
        let row = |cols: &[[String; 3]]| cols.iter().map(|c| c[k].clone()).collect::<Vec<_>>();
        let _ = writeln!(md, "| {prefix}{stat} | {} |", row(ours).join(" | "));
        let _ = writeln!(
            md,
            "| {prefix}{stat} (paper) | {} |",
            row(paper).join(" | ")
        );
    }
}

/// Columns per scenario (ours, the paper's).
type ScenarioColumns = (Vec<[String; 3]>, Vec<[String; 3]>);

/// A table with one block of rows per scenario present under `header`, then each scenario's
/// population.
fn scenario_rows(
    md: &mut String,
    header: &str,
    inputs: &[(String, Vec<RunRecord>)],
    columns: impl Fn(usize, &Finals) -> ScenarioColumns,
) {
    let _ = writeln!(md, "{header}");
    let present: Vec<(usize, Finals)> = [1, 2]
        .into_iter()
        .filter_map(|n| {
            let (_, runs) = inputs.iter().find(|(l, _)| *l == n.to_string())?;
            Some((n, finals(runs)))
        })
        .collect();
    for (n, f) in &present {
        let (ours, paper) = columns(*n, f);
        interleaved(md, &format!("#{n} "), &ours, &paper);
    }
    md.push('\n');
    for (n, f) in &present {
        population(md, &format!("Scenario #{n}"), f);
    }
}

fn population(md: &mut String, label: &str, f: &Finals) {
    let _ = writeln!(
        md,
        "{label}: {} of {} runs (those where the VNS and the IA-VNS both track at t_end).\n",
        f.runs.len(),
        f.flown
    );
}

/// The table `kind` from `inputs`: `(label, runs)` with labels `1`/`2` (scenario) for the MX
/// tables and zone codes for the terrain tables; absent inputs are left out.
pub fn paper_table(kind: PaperTable, inputs: &[(String, Vec<RunRecord>)]) -> String {
    let mut md = String::new();
    let scenario = |n: usize| inputs.iter().find(|(l, _)| *l == n.to_string());
    let column = |f: &Finals, system: usize, get: fn(&NseSample) -> f64| {
        stats(&f.runs.iter().map(|r| get(&r[system])).collect::<Vec<_>>())
    };
    match kind {
        PaperTable::Attitude => {
            let gets: [fn(&NseSample) -> f64; 4] = [
                |s| s.yaw_deg,
                |s| s.pitch_deg,
                |s| s.bank_deg,
                |s| s.att_norm_deg,
            ];
            for n in [1, 2] {
                let Some((_, runs)) = scenario(n) else {
                    continue;
                };
                let f = finals(runs);
                population(&mut md, &format!("Scenario #{n} over MX"), &f);
                let mut head = format!("| #{n} MX, deg");
                for sys in ["INS", "VNS", "IA-VNS"] {
                    let _ = write!(head, " | {sys} Δψ | {sys} Δθ | {sys} Δξ | {sys} ‖Δr‖");
                }
                let _ = writeln!(md, "{head} |\n{}|", "|---".repeat(13));
                let ours: Vec<[String; 3]> = (0..3)
                    .flat_map(|sys| gets.map(|g| (sys, g)))
                    .enumerate()
                    .map(|(k, (sys, g))| cells(column(&f, sys, g), if k % 4 == 3 { 3 } else { 2 }))
                    .collect();
                let paper: Vec<[String; 3]> = PAPER_ATTITUDE[n - 1]
                    .iter()
                    .flat_map(|sys| {
                        sys.iter()
                            .enumerate()
                            .map(|(k, p)| printed(*p, if k == 3 { 3 } else { 2 }))
                    })
                    .collect();
                interleaved(&mut md, "", &ours, &paper);
                md.push('\n');
            }
        }
        PaperTable::Altitude => scenario_rows(
            &mut md,
            "| scenario, stat | INS Δh [m] | VNS Δh [m] | IA-VNS Δh [m] |\n|---|---|---|---|",
            inputs,
            |n, f| {
                let ours = (0..3)
                    .map(|sys| cells(column(f, sys, |s| s.alt_m), 2))
                    .collect();
                let paper = PAPER_ALTITUDE[n - 1]
                    .iter()
                    .map(|p| printed(*p, 2))
                    .collect();
                (ours, paper)
            },
        ),
        PaperTable::Horizontal => scenario_rows(
            &mut md,
            "| scenario, stat | distance [m] | INS [m] | INS [%] | VNS [m] | VNS [%] | IA-VNS [m] | IA-VNS [%] |\n|---|---|---|---|---|---|---|---|",
            inputs,
            |n, f| {
                let mut ours = vec![cells(column(f, 0, |s| s.distance_m), 0)];
                for sys in 0..3 {
                    ours.push(cells(column(f, sys, |s| s.hor_m), 0));
                    ours.push(cells(column(f, sys, |s| s.hor_pct), 2));
                }
                let paper = PAPER_HORIZONTAL[n - 1]
                    .iter()
                    .enumerate()
                    .map(|(k, p)| printed(*p, if k > 0 && k % 2 == 0 { 2 } else { 0 }))
                    .collect();
                (ours, paper)
            },
        ),
        PaperTable::Terrain1 | PaperTable::Terrain2 => {
            let zones: &[(&str, Printed, Printed)] = if kind == PaperTable::Terrain1 {
                &PAPER_TERRAIN1
            } else {
                &PAPER_TERRAIN2
            };
            let present: Vec<&(&str, Printed, Printed)> = zones
                .iter()
                .filter(|z| inputs.iter().any(|(l, _)| l == z.0))
                .collect();
            let mut head = String::from("| IA-VNS");
            for z in &present {
                let code = z.0.to_uppercase();
                let _ = write!(head, " | {code} [m] | {code} [%]");
            }
            let _ = writeln!(md, "{head} |\n{}|", "|---".repeat(1 + 2 * present.len()));
            let mut ours = Vec::new();
            let mut paper = Vec::new();
            let mut counts = Vec::new();
            for z in &present {
                let Some((_, runs)) = inputs.iter().find(|(l, _)| l == z.0) else {
                    continue;
                };
                let f = finals(runs);
                let col = |get: fn(&NseSample) -> f64| {
                    stats(&f.ia_vns.iter().map(get).collect::<Vec<_>>())
                };
                ours.push(cells(col(|s| s.hor_m), 0));
                ours.push(cells(col(|s| s.hor_pct), 2));
                paper.push(printed(z.1, 0));
                paper.push(printed(z.2, 2));
                counts.push(format!(
                    "{} {} of {}",
                    z.0.to_uppercase(),
                    f.ia_vns.len(),
                    f.flown
                ));
            }
            interleaved(&mut md, "", &ours, &paper);
            let _ = writeln!(
                md,
                "\nRuns whose IA-VNS tracks at t_end, of those flown: {}.\n",
                counts.join(", ")
            );
        }
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::montecarlo::VisionRun;

    fn run(seed: u64, hor: [f64; 3], ia_lost: bool) -> RunRecord {
        let sample = |hor_m: f64| NseSample {
            t_s: 500.0,
            yaw_deg: 0.1,
            pitch_deg: -0.1,
            bank_deg: 0.0,
            att_norm_deg: 0.2,
            alt_m: 1.0,
            hor_m,
            hor_pct: hor_m / 100.0,
            distance_m: 10_000.0,
        };
        let system = |name: &str, s: NseSample| VisionRun {
            system: name.into(),
            samples: vec![s],
            initialisations: 1,
            tracking_losses: 0,
            relocalisations: 0,
            motion_model_recoveries: 0,
            aiding: None,
        };
        let ia = if ia_lost {
            crate::metrics::missing_sample(500.0, 10_000.0)
        } else {
            sample(hor[2])
        };
        RunRecord {
            scenario: 2,
            scenario_name: "s".into(),
            navigation: crate::flight::NavigationMode::Ins,
            duration_s: 500.0,
            seed,
            outcome: RunOutcome::Completed {
                distance_m: 10_000.0,
                samples: vec![sample(hor[0])],
                vision: vec![system("vns", sample(hor[1])), system("ia-vns", ia)],
            },
        }
    }

    #[test]
    fn the_horizontal_table_is_over_the_runs_where_both_systems_track() {
        let runs = vec![
            run(1, [200.0, 60.0, 20.0], false),
            run(2, [100.0, 40.0, 40.0], false),
            run(3, [900.0, 900.0, 0.0], true),
        ];
        let md = paper_table(PaperTable::Horizontal, &[("2".into(), runs.clone())]);
        // INS 150 (50) 200, VNS 50 (10) 60, IA-VNS 30 (10) 40 over seeds 1–2.
        assert!(
            md.contains("| #2 mean | 10000 | 150 | 1.50 | 50 | 0.50 | 30 | 0.30 |"),
            "{md}"
        );
        assert!(
            md.contains("| #2 std | 0 | 50 | 0.50 | 10 | 0.10 | 10 | 0.10 |"),
            "{md}"
        );
        assert!(
            md.contains("| #2 mean (paper) | 14198 | 216 | 1.52 | 251 | 1.77 | 33 | 0.23 |"),
            "{md}"
        );
        assert!(md.contains("Scenario #2: 2 of 3 runs"), "{md}");
        // The terrain table counts the IA-VNS's runs alone.
        let md = paper_table(PaperTable::Terrain2, &[("fm".into(), runs)]);
        assert!(md.contains("| mean | 30 | 0.30 |"), "{md}");
        assert!(md.contains("FM 2 of 3"), "{md}");
        assert!(!md.contains("MX"), "{md}");
    }
}
