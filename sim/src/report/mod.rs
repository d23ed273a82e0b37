//! Monte Carlo report (the paper's INSE tables and its mean ± σ error figures, docs/REFERENCES.md
//! P4; the authors' post-processing, A6.6: mean, σ and largest value across runs of histories
//! sampled every 10 s): reads the run files of one or several batch directories (shards merge by
//! seed), and writes `report.md` with the navigation system error at `t_end`, the time histories as
//! PNG plots and as `nse_timeseries.csv`; with a camera, every visual system beside the INS
//! (`vision.rs`).
//!
//! Everything written depends only on the set of run files: runs are sorted by seed, sums run
//! in that order and numbers are printed with fixed decimals, so shards merged give the same
//! bytes as one batch.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io;
use std::path::{Path, PathBuf};

use crate::metrics::{NseSample, format_fixed};
use crate::montecarlo::{RUNS_DIR, RunOutcome, RunRecord};
use crate::plots::{self, Chart, PALETTE, Series};

mod tables;
mod vision;

pub use tables::{PaperTable, paper_table};
pub use vision::{display_name, system_colour};

/// The report file.
pub const REPORT_FILE: &str = "report.md";
/// Mean and σ of every error at every sample time.
pub const TIMESERIES_FILE: &str = "nse_timeseries.csv";
/// Fraction of the flight, at its end, over which the attitude-norm drift is fitted (the
/// "no drift" acceptance criterion: the mean over the last 25% of the flight grows less than
/// 0.05° per 1,000 s).
const DRIFT_WINDOW_FRACTION: f64 = 0.25;
/// Run files of one batch must agree on the mission duration to this tolerance, s (they
/// store it with 1 ms resolution).
const DURATION_TOLERANCE_S: f64 = 1e-3;
/// Plot size, pixels (as the single-run plots).
const PLOT_SIZE: (u32, u32) = (900, 560);

/// Errors building a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// File system failure, with the file concerned.
    #[error("{path}: {source}")]
    Io {
        /// File or directory.
        path: String,
        /// Cause.
        source: io::Error,
    },
    /// A run file is malformed.
    #[error("{path}: {message} (a file cut short? `ianav-sim mc … --resume` flies it again)")]
    RunFile {
        /// File.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// No run files under the given directories.
    #[error("no run files (`{RUNS_DIR}/run_*.csv`) under {0}")]
    NoRuns(String),
    /// Two different files hold the same seed.
    #[error("seed {seed} appears twice with different content: {first} and {second}")]
    DuplicateSeed {
        /// Seed.
        seed: u64,
        /// One file.
        first: String,
        /// The other.
        second: String,
    },
    /// The runs do not belong to one experiment (scenario or duration differ).
    #[error("runs of different experiments cannot be merged: seed {seed} has {what}")]
    Mixed {
        /// Seed of the odd run.
        seed: u64,
        /// What differs.
        what: String,
    },
    /// A run file does not hold a whole run (cut short).
    #[error(
        "{path}: not a whole run: {reason}; fly it again with `ianav-sim mc … --resume` (or delete it)"
    )]
    Incomplete {
        /// File.
        path: String,
        /// What is missing.
        reason: String,
    },
    /// A plot could not be drawn.
    #[error(transparent)]
    Plot(#[from] plots::PlotError),
    /// The batch directories could not be listed.
    #[error(transparent)]
    Batch(#[from] crate::montecarlo::McError),
}

fn io_error(path: &Path) -> impl FnOnce(io::Error) -> ReportError + '_ {
    move |source| ReportError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Statistics of one quantity over the runs, as the paper's tables.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stats {
    /// Number of values.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Population standard deviation `sqrt(Σ(x − mean)² / n)` (the paper reports σ of its
    /// 100 runs; with n = 100 the sample std would be 0.5% larger).
    pub std: f64,
    /// The value of largest magnitude, with its sign (the first in seed order on ties).
    pub largest: f64,
}

/// Statistics of `values` (`None` if empty). Two-pass mean and deviation, summed in the
/// given order; a NaN value makes every statistic NaN.
pub fn stats(values: &[f64]) -> Option<Stats> {
    let first = *values.first()?;
    let n = values.len();
    let mean = values.iter().sum::<f64>() / n as f64;
    let var = values.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
    let mut largest = first;
    for &x in values {
        if x.is_nan() {
            largest = f64::NAN;
            break;
        }
        if x.abs() > largest.abs() {
            largest = x;
        }
    }
    Some(Stats {
        n,
        mean,
        std: var.sqrt(),
        largest,
    })
}

/// Least-squares slope of `points` (`None` with fewer than two distinct abscissae).
pub fn slope(points: &[(f64, f64)]) -> Option<f64> {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(sx, sy), (x, y)| (sx + x / n, sy + y / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(sxy, sxx), (x, y)| {
        (sxy + (x - mx) * (y - my), sxx + (x - mx) * (x - mx))
    });
    (points.len() >= 2 && sxx > 0.0).then(|| sxy / sxx)
}

/// One error of the report: how to get it from a sample, its names and its decimals.
struct Metric {
    /// Column prefix in the time-series file.
    key: &'static str,
    /// Table row label.
    label: &'static str,
    /// Unit in the table.
    unit: &'static str,
    /// Plot file and title.
    plot: &'static str,
    title: &'static str,
    y_label: &'static str,
    /// Decimals in the table (as the paper: 0.001° and 0.01 m or %).
    table_decimals: usize,
    /// Decimals in the time-series file (as the run files).
    series_decimals: usize,
    get: fn(&NseSample) -> f64,
}

const METRICS: [Metric; 7] = [
    Metric {
        key: "yaw_deg",
        label: "yaw ψ",
        unit: "deg",
        plot: "nse_yaw.png",
        title: "Yaw error",
        y_label: "yaw error [deg]",
        table_decimals: 3,
        series_decimals: 6,
        get: |s| s.yaw_deg,
    },
    Metric {
        key: "pitch_deg",
        label: "pitch θ",
        unit: "deg",
        plot: "nse_pitch.png",
        title: "Pitch error",
        y_label: "pitch error [deg]",
        table_decimals: 3,
        series_decimals: 6,
        get: |s| s.pitch_deg,
    },
    Metric {
        key: "bank_deg",
        label: "bank ξ",
        unit: "deg",
        plot: "nse_bank.png",
        title: "Bank error",
        y_label: "bank error [deg]",
        table_decimals: 3,
        series_decimals: 6,
        get: |s| s.bank_deg,
    },
    Metric {
        key: "att_norm_deg",
        label: "attitude ‖Log(q_truth⁻¹ q_est)‖",
        unit: "deg",
        plot: "nse_attitude_norm.png",
        title: "Attitude error norm",
        y_label: "attitude error [deg]",
        table_decimals: 3,
        series_decimals: 6,
        get: |s| s.att_norm_deg,
    },
    Metric {
        key: "alt_m",
        label: "altitude h",
        unit: "m",
        plot: "nse_altitude.png",
        title: "Altitude error",
        y_label: "altitude error [m]",
        table_decimals: 2,
        series_decimals: 4,
        get: |s| s.alt_m,
    },
    Metric {
        key: "hor_m",
        label: "horizontal position",
        unit: "m",
        plot: "nse_horizontal_m.png",
        title: "Horizontal position error",
        y_label: "horizontal error [m]",
        table_decimals: 2,
        series_decimals: 4,
        get: |s| s.hor_m,
    },
    Metric {
        key: "hor_pct",
        label: "horizontal position",
        unit: "% of distance",
        plot: "nse_horizontal_pct.png",
        title: "Horizontal position error / distance flown",
        y_label: "horizontal error [% of distance]",
        table_decimals: 2,
        series_decimals: 6,
        get: |s| s.hor_pct,
    },
];

/// The run files of `dirs`: each is a batch directory (holding `runs/`) or a parent whose
/// immediate subdirectories are batch directories (shards copied side by side).
pub fn run_files(dirs: &[PathBuf]) -> Result<Vec<PathBuf>, ReportError> {
    let batch_dirs: Vec<PathBuf> = crate::montecarlo::status::batch_dirs(dirs)?
        .into_iter()
        .map(|d| d.join(RUNS_DIR))
        .collect();
    let mut files = Vec::new();
    for runs in &batch_dirs {
        for entry in std::fs::read_dir(runs).map_err(io_error(runs))? {
            let path = entry.map_err(io_error(runs))?.path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if name.starts_with("run_") && name.ends_with(".csv") {
                files.push(path);
            }
        }
    }
    if files.is_empty() {
        let names: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
        return Err(ReportError::NoRuns(names.join(", ")));
    }
    files.sort();
    Ok(files)
}

/// Read the runs of `dirs`, sorted by seed. The same seed in two files is accepted only if
/// the files are identical (a shard copied twice); a file cut short is an error, and so are
/// runs of different experiments (scenario, navigation, duration or visual systems).
pub fn load_runs(dirs: &[PathBuf]) -> Result<Vec<RunRecord>, ReportError> {
    let mut by_seed: BTreeMap<u64, (PathBuf, String, RunRecord)> = BTreeMap::new();
    for path in run_files(dirs)? {
        let text = std::fs::read_to_string(&path).map_err(io_error(&path))?;
        let record = RunRecord::parse(&text).map_err(|message| ReportError::RunFile {
            path: path.display().to_string(),
            message,
        })?;
        if let Some(reason) =
            record.incomplete(crate::flight::RatesConfig::default().output_period_s)
        {
            return Err(ReportError::Incomplete {
                path: path.display().to_string(),
                reason,
            });
        }
        if let Some((first, first_text, _)) = by_seed.get(&record.seed) {
            if *first_text != text {
                return Err(ReportError::DuplicateSeed {
                    seed: record.seed,
                    first: first.display().to_string(),
                    second: path.display().to_string(),
                });
            }
            continue;
        }
        by_seed.insert(record.seed, (path, text, record));
    }
    let runs: Vec<RunRecord> = by_seed.into_values().map(|(_, _, r)| r).collect();
    // The visual systems of a completed run (a file cut just before a section loses one).
    let systems = |r: &RunRecord| match &r.outcome {
        RunOutcome::Completed { vision, .. } => {
            Some(vision.iter().map(|v| v.system.clone()).collect::<Vec<_>>())
        }
        RunOutcome::Failed { .. } => None,
    };
    let first_systems = runs.iter().find_map(|r| systems(r).map(|s| (r.seed, s)));
    if let Some(first) = runs.first() {
        for r in &runs {
            let what = if r.navigation != first.navigation {
                Some(format!(
                    "navigation `{}`, seed {} flew on `{}`",
                    crate::montecarlo::navigation_name(r.navigation),
                    first.seed,
                    crate::montecarlo::navigation_name(first.navigation)
                ))
            } else if r.scenario != first.scenario || r.scenario_name != first.scenario_name {
                Some(format!(
                    "scenario {} `{}`, seed {} has scenario {} `{}`",
                    r.scenario, r.scenario_name, first.seed, first.scenario, first.scenario_name
                ))
            } else if (r.duration_s - first.duration_s).abs() > DURATION_TOLERANCE_S {
                Some(format!(
                    "duration {} s, seed {} has {} s",
                    r.duration_s, first.seed, first.duration_s
                ))
            } else if let (Some(own), Some((seed, theirs))) = (systems(r), &first_systems)
                && own != *theirs
            {
                Some(format!(
                    "the visual systems [{}], seed {seed} has [{}]",
                    own.join(", "),
                    theirs.join(", ")
                ))
            } else {
                None
            };
            if let Some(what) = what {
                return Err(ReportError::Mixed { seed: r.seed, what });
            }
        }
    }
    Ok(runs)
}

/// `1–50, 52, 54–100`.
fn seed_ranges(seeds: &[u64]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < seeds.len() {
        let mut j = i;
        while j + 1 < seeds.len() && seeds[j + 1] == seeds[j] + 1 {
            j += 1;
        }
        parts.push(if j == i {
            seeds[i].to_string()
        } else {
            format!("{}–{}", seeds[i], seeds[j])
        });
        i = j + 1;
    }
    parts.join(", ")
}

/// Mission time in milliseconds: the key that aligns samples of different runs.
fn time_key_ms(t_s: f64) -> i64 {
    (t_s * 1000.0).round() as i64
}

/// Statistics of every metric at one sample time.
struct TimeRow {
    t_s: f64,
    n: usize,
    stats: Vec<Stats>,
    distance: Stats,
}

fn time_rows(completed: &[(&RunRecord, f64, &[NseSample])]) -> Vec<TimeRow> {
    let mut by_time: BTreeMap<i64, Vec<&NseSample>> = BTreeMap::new();
    for (_, _, samples) in completed {
        // Samples without a solution (the VNS before it tracks or while it relocalises) are
        // left out of that instant's statistics.
        for s in samples.iter().filter(|s| !s.att_norm_deg.is_nan()) {
            by_time.entry(time_key_ms(s.t_s)).or_default().push(s);
        }
    }
    by_time
        .into_iter()
        .filter_map(|(key, samples)| {
            let column =
                |f: fn(&NseSample) -> f64| -> Vec<f64> { samples.iter().map(|s| f(s)).collect() };
            let per_metric: Option<Vec<Stats>> =
                METRICS.iter().map(|m| stats(&column(m.get))).collect();
            Some(TimeRow {
                t_s: key as f64 / 1000.0,
                n: samples.len(),
                stats: per_metric?,
                distance: stats(&column(|s| s.distance_m))?,
            })
        })
        .collect()
}

fn timeseries_csv(rows: &[TimeRow]) -> String {
    let mut t = String::from("t_s,n");
    for m in &METRICS {
        let _ = write!(t, ",{0}_mean,{0}_std", m.key);
    }
    t.push_str(",distance_m_mean\n");
    for r in rows {
        let _ = write!(t, "{},{}", format_fixed(r.t_s, 3), r.n);
        for (m, s) in METRICS.iter().zip(&r.stats) {
            let d = m.series_decimals;
            let _ = write!(t, ",{},{}", format_fixed(s.mean, d), format_fixed(s.std, d));
        }
        let _ = writeln!(t, ",{}", format_fixed(r.distance.mean, 3));
    }
    t
}

/// Draw mean (solid) and mean ± σ (dashed) of each metric; returns the plots drawn with
/// their captions (a metric without a single finite point is skipped).
fn draw_plots(
    rows: &[TimeRow],
    out: &Path,
) -> Result<Vec<(&'static str, &'static str)>, ReportError> {
    let mut drawn = Vec::new();
    for (k, m) in METRICS.iter().enumerate() {
        let line = |label: &str, f: &dyn Fn(&Stats) -> f64, dashed: bool| Series {
            label: label.to_owned(),
            points: rows.iter().map(|r| (r.t_s, f(&r.stats[k]))).collect(),
            rgb: PALETTE[0],
            dashed,
        };
        let chart = Chart {
            title: m.title,
            x_label: "mission time [s]",
            y_label: m.y_label,
            series: vec![
                line("mean", &|s| s.mean, false),
                line("mean ± σ (dashed)", &|s| s.mean + s.std, true),
                line("", &|s| s.mean - s.std, true),
            ],
            ..Chart::default()
        };
        let any_finite = chart
            .series
            .iter()
            .flat_map(|s| &s.points)
            .any(|(x, y)| x.is_finite() && y.is_finite());
        if any_finite {
            plots::draw(&out.join(m.plot), &chart, PLOT_SIZE.0, PLOT_SIZE.1)?;
            drawn.push((m.plot, m.title));
        }
    }
    Ok(drawn)
}

/// What [`write_report`] produced.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportSummary {
    /// The Markdown report.
    pub report_path: PathBuf,
    /// Runs read.
    pub runs: usize,
    /// Runs that completed (the statistics use these).
    pub completed: usize,
    /// Attitude-norm error at `t_end` over the completed runs, if any.
    pub att_norm_deg: Option<Stats>,
    /// Seeds of the batch's plan without a run file (the report says so).
    pub missing: Vec<u64>,
}

/// Write `report.md`, the plots and the time-series file of `runs` (sorted by seed) to `out`.
pub fn write_report(runs: &[RunRecord], out: &Path) -> Result<ReportSummary, ReportError> {
    write_batch_report(runs, &[], out)
}

/// [`write_report`] of a batch of which the seeds `missing` have no run (yet): the report
/// names them.
pub fn write_batch_report(
    runs: &[RunRecord],
    missing: &[u64],
    out: &Path,
) -> Result<ReportSummary, ReportError> {
    std::fs::create_dir_all(out).map_err(io_error(out))?;
    let completed: Vec<(&RunRecord, f64, &[NseSample])> = runs
        .iter()
        .filter_map(|r| match &r.outcome {
            RunOutcome::Completed {
                distance_m,
                samples,
                ..
            } if !samples.is_empty() => Some((r, *distance_m, samples.as_slice())),
            _ => None,
        })
        .collect();
    let failed: Vec<(u64, &str)> = runs
        .iter()
        .filter_map(|r| match &r.outcome {
            RunOutcome::Failed { reason } => Some((r.seed, reason.as_str())),
            RunOutcome::Completed { samples, .. } if samples.is_empty() => {
                Some((r.seed, "completed without samples"))
            }
            RunOutcome::Completed { .. } => None,
        })
        .collect();

    let mut md = String::new();
    let name = runs.first().map_or("", |r| r.scenario_name.as_str());
    let _ = writeln!(md, "# Monte Carlo navigation system error: {name}\n");
    if let Some(r) = runs.first() {
        let seeds: Vec<u64> = runs.iter().map(|r| r.seed).collect();
        let _ = writeln!(
            md,
            "Scenario {}, mission duration {} s, guidance and control on the `{}` navigation. \
             {} runs (seeds {}): {} completed, {} failed. \
             Produced by `ianav-sim report` from the run files of `ianav-sim mc`.\n",
            r.scenario,
            format_fixed(r.duration_s, 1),
            crate::montecarlo::navigation_name(r.navigation),
            runs.len(),
            seed_ranges(&seeds),
            completed.len(),
            failed.len()
        );
    }
    if !missing.is_empty() {
        let _ = writeln!(
            md,
            "**Incomplete batch**: the `mc` plan and manifest files name {} more seeds, which \
             have no run file: {}. `ianav-sim report --status DIR` shows their shards; \
             `ianav-sim mc … --resume` flies them.\n",
            missing.len(),
            seed_ranges(missing)
        );
    }
    if !failed.is_empty() {
        let _ = writeln!(
            md,
            "Failed runs (excluded from the statistics):\n\n| seed | reason |\n|---|---|"
        );
        for (seed, reason) in &failed {
            let _ = writeln!(md, "| {seed} | {} |", reason.replace('|', "\\|"));
        }
        md.push('\n');
    }

    let mut att_norm = None;
    if completed.is_empty() {
        let _ = writeln!(md, "No completed run: no statistics.");
    } else {
        let finals: Vec<&NseSample> = completed.iter().filter_map(|(_, _, s)| s.last()).collect();
        let t_end_s = finals
            .iter()
            .map(|s| s.t_s)
            .fold(f64::NEG_INFINITY, f64::max);
        let _ = writeln!(
            md,
            "## Navigation system error at t_end = {} s\n\n\
             Error = estimate − truth, over the {} completed runs.\n\n\
             | error | unit | mean | std | largest magnitude |\n|---|---|---|---|---|",
            format_fixed(t_end_s, 1),
            completed.len()
        );
        for m in &METRICS {
            let values: Vec<f64> = finals.iter().map(|s| (m.get)(s)).collect();
            if let Some(s) = stats(&values) {
                let d = m.table_decimals;
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {} | {} |",
                    m.label,
                    m.unit,
                    format_fixed(s.mean, d),
                    format_fixed(s.std, d),
                    format_fixed(s.largest, d)
                );
                if m.key == "att_norm_deg" {
                    att_norm = Some(s);
                }
            }
        }
        let distances: Vec<f64> = completed.iter().map(|(_, d, _)| *d).collect();
        if let Some(s) = stats(&distances) {
            let _ = writeln!(
                md,
                "| distance flown | m | {} | {} | {} |",
                format_fixed(s.mean, 0),
                format_fixed(s.std, 0),
                format_fixed(s.largest, 0)
            );
        }
        let _ = writeln!(
            md,
            "\nmean = arithmetic mean; std = population standard deviation \
             (√(Σ(x − mean)²/n), n = number of completed runs); largest magnitude = the signed \
             value of largest |x| (first in seed order on ties). Horizontal error: distance \
             between estimated and true positions on the local level plane; % of the ground \
             distance flown since t = 0.\n"
        );

        let rows = time_rows(&completed);
        let k_norm = METRICS
            .iter()
            .position(|m| m.key == "att_norm_deg")
            .unwrap_or(3);
        let window: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.t_s >= (1.0 - DRIFT_WINDOW_FRACTION) * t_end_s)
            .map(|r| (r.t_s, r.stats[k_norm].mean))
            .collect();
        if let (Some(b), Some(first)) = (slope(&window), window.first()) {
            let _ = writeln!(
                md,
                "Attitude-norm error drift: the least-squares slope of its mean over the last \
                 {:.0}% of the flight (t ≥ {} s, {} samples) is {}° per 1,000 s.\n",
                DRIFT_WINDOW_FRACTION * 100.0,
                format_fixed(first.0, 1),
                window.len(),
                format_fixed(b * 1000.0, 4)
            );
        }
        let ts_path = out.join(TIMESERIES_FILE);
        std::fs::write(&ts_path, timeseries_csv(&rows)).map_err(io_error(&ts_path))?;
        let drawn = draw_plots(&rows, out)?;
        let _ = writeln!(
            md,
            "## Time histories\n\nMean over the completed runs (solid) and mean ± σ (dashed), \
             sampled every 10 s of mission time and at t_end; data in `{TIMESERIES_FILE}`.\n"
        );
        for (file, caption) in &drawn {
            let _ = writeln!(md, "![{caption}]({file})\n");
        }
    }
    vision::section(&mut md, &completed, out)?;
    let report_path = out.join(REPORT_FILE);
    std::fs::write(&report_path, &md).map_err(io_error(&report_path))?;
    Ok(ReportSummary {
        report_path,
        runs: runs.len(),
        completed: completed.len(),
        att_norm_deg: att_norm,
        missing: missing.to_vec(),
    })
}

/// Read the runs of `dirs` and write the report to `out`; seeds that the batch's plan or
/// manifest files name and that have no run file are named in the report (and returned).
pub fn report(dirs: &[PathBuf], out: &Path) -> Result<ReportSummary, ReportError> {
    let runs = load_runs(dirs)?;
    let planned = crate::montecarlo::status::planned_seeds(dirs)?;
    let missing: Vec<u64> = planned
        .into_iter()
        .filter(|s| runs.binary_search_by_key(s, |r| r.seed).is_err())
        .collect();
    write_batch_report(&runs, &missing, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_ranges_compress_runs_of_consecutive_seeds() {
        assert_eq!(seed_ranges(&[1, 2, 3, 5, 7, 8]), "1–3, 5, 7–8");
        assert_eq!(seed_ranges(&[4]), "4");
        assert_eq!(seed_ranges(&[]), "");
    }

    #[test]
    fn slope_of_a_line_is_exact() {
        let pts: Vec<(f64, f64)> = (0..5)
            .map(|i| (f64::from(i), 2.0 + 0.5 * f64::from(i)))
            .collect();
        assert!((slope(&pts).unwrap() - 0.5).abs() < 1e-12);
        assert!(slope(&pts[..1]).is_none());
    }
}
