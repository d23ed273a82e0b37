//! The visual systems beside the INS on the same flights (runs with a camera; paper section
//! "Results", its tables of mean and σ at t_end and its figures of μ ± σ against time with the
//! worst run, INS blue, VNS red, IA-VNS green).

use std::fmt::Write as _;
use std::path::Path;

use super::{METRICS, PLOT_SIZE, ReportError, Stats, TimeRow, stats, time_rows};
use crate::metrics::{NseSample, format_fixed};
use crate::montecarlo::{RunOutcome, RunRecord, VisionRun};
use crate::plots::{self, Chart, PALETTE, Series};

/// Worst-run lines are drawn for at most this many systems (beyond, the plot is unreadable).
const MAX_WORST_RUN_LINES: usize = 3;

/// How a system is named in the report.
pub fn display_name(system: &str) -> String {
    match system {
        "vns" => "VNS".to_owned(),
        "ia-vns" => "IA-VNS".to_owned(),
        "ia-vns-pitch" => "IA-VNS (pitch only)".to_owned(),
        "ia-vns-slerp" => "IA-VNS (SLERP, beyond the paper)".to_owned(),
        "vns+init" => "VNS + INS initialisation".to_owned(),
        "vns+prediction" => "VNS + ζ* from the INS".to_owned(),
        "vns+priors" => "VNS + priors".to_owned(),
        "vns+structure" => "VNS + current features in structure".to_owned(),
        other => other.to_owned(),
    }
}

/// A system's colour: the paper's (INS blue is `PALETTE[0]`, VNS red, IA-VNS green), the
/// palette's others after them by its index in the flight's list.
pub fn system_colour(system: &str, index: usize) -> (u8, u8, u8) {
    match system {
        "vns" => PALETTE[1],
        "ia-vns" => PALETTE[2],
        _ => PALETTE[3 + index % (PALETTE.len() - 3)],
    }
}

/// Half way to white: the worst run beside its system's mean.
fn lighter((r, g, b): (u8, u8, u8)) -> (u8, u8, u8) {
    let half = |c: u8| c / 2 + 128;
    (half(r), half(g), half(b))
}

/// A run with a camera: its INS samples and its visual systems.
type WithVision<'a> = (&'a RunRecord, &'a [NseSample], &'a [VisionRun]);

/// The visual system `name` of a run.
fn system<'a>(runs: &'a [VisionRun], name: &str) -> Option<&'a VisionRun> {
    runs.iter().find(|v| v.system == name)
}

/// The sample at t_end of a system that tracks then.
fn tracked_end(v: &VisionRun) -> Option<&NseSample> {
    v.samples.last().filter(|s| !s.att_norm_deg.is_nan())
}

/// The section: counters per system, the table at t_end over the runs where every system
/// tracks, the per-seed horizontal errors, and the μ ± σ plots.
pub(super) fn section(
    md: &mut String,
    completed: &[(&RunRecord, f64, &[NseSample])],
    out: &Path,
) -> Result<(), ReportError> {
    let with_vision: Vec<WithVision> = completed
        .iter()
        .filter_map(|(r, _, ins)| match &r.outcome {
            RunOutcome::Completed { vision, .. } if !vision.is_empty() => {
                Some((*r, *ins, vision.as_slice()))
            }
            _ => None,
        })
        .collect();
    if with_vision.is_empty() {
        return Ok(());
    }
    // The systems in the order they first appear (runs of one batch share it).
    let mut names: Vec<&str> = Vec::new();
    for (_, _, vision) in &with_vision {
        for v in *vision {
            if !names.contains(&v.system.as_str()) {
                names.push(&v.system);
            }
        }
    }
    let shown: Vec<String> = names.iter().map(|n| display_name(n)).collect();
    let _ = writeln!(
        md,
        "## Visual navigation beside the INS\n\n\
         {} on the same {} flights: each frame was rendered once and given to every system. \
         The VNS is the paper's baseline (the images and the initial estimate at its first \
         image only); the IA-VNS adds the inertial priors, `ζ*` from the INS, the current \
         features in structure optimisation and the INS initialisation (docs/IAVNS.md).\n",
        shown.join(", "),
        with_vision.len()
    );
    counters_table(md, &with_vision, &names);

    // The runs where every system tracks at t_end are compared.
    let tracked: Vec<(&RunRecord, &NseSample, Vec<&NseSample>)> = with_vision
        .iter()
        .filter_map(|(r, ins, vision)| {
            let ends = names
                .iter()
                .map(|n| system(vision, n).and_then(tracked_end))
                .collect::<Option<Vec<_>>>()?;
            Some((*r, ins.last()?, ends))
        })
        .collect();
    let _ = writeln!(
        md,
        "Errors at t_end over the {} runs where every system tracks then: mean (σ), then the \
         value of largest magnitude.\n",
        tracked.len()
    );
    if !tracked.is_empty() {
        end_tables(md, &tracked, &shown);
        seed_table(md, &tracked, &shown);
    }
    plots_for(md, &with_vision, &names, &tracked, out)
}

/// Tracking and the IA-VNS's counters, summed over the runs.
fn counters_table(md: &mut String, with_vision: &[WithVision], names: &[&str]) {
    let _ = writeln!(
        md,
        "| system | runs | never initialised | tracking losses (runs) | relocalisations | \
         second starts | tracks at t_end | frames from ζ* (failed) | priors active (joint \
         not kept) |\n|---|---|---|---|---|---|---|---|---|"
    );
    for name in names {
        let runs: Vec<&VisionRun> = with_vision
            .iter()
            .filter_map(|(_, _, v)| system(v, name))
            .collect();
        let sum = |f: fn(&VisionRun) -> u64| runs.iter().map(|v| f(v)).sum::<u64>();
        let aided = runs.iter().any(|v| v.aiding.is_some());
        let aiding_sum = |f: fn(&crate::montecarlo::AidingRun) -> u64| {
            runs.iter()
                .filter_map(|v| v.aiding.as_ref())
                .map(f)
                .sum::<u64>()
        };
        let (starts, priors) = if aided {
            (
                format!(
                    "{} ({})",
                    aiding_sum(|a| a.inertial_starts),
                    aiding_sum(|a| a.inertial_start_failures)
                ),
                format!(
                    "{} ({})",
                    aiding_sum(|a| a.priors_active),
                    aiding_sum(|a| a.joint_failures)
                ),
            )
        } else {
            ("–".to_owned(), "–".to_owned())
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} ({}) | {} | {} | {} | {starts} | {priors} |",
            display_name(name),
            runs.len(),
            runs.iter().filter(|v| v.initialisations == 0).count(),
            sum(|v| v.tracking_losses),
            runs.iter().filter(|v| v.tracking_losses > 0).count(),
            sum(|v| v.relocalisations),
            sum(|v| v.motion_model_recoveries),
            runs.iter().filter(|v| tracked_end(v).is_some()).count(),
        );
    }
    md.push('\n');
}

/// One row per system (the INS first), one column per error: mean (σ); then the largest.
fn end_tables(
    md: &mut String,
    tracked: &[(&RunRecord, &NseSample, Vec<&NseSample>)],
    shown: &[String],
) {
    let head: Vec<String> = METRICS
        .iter()
        .map(|m| format!("{} [{}]", m.label, m.unit))
        .collect();
    let rule = "|---".repeat(METRICS.len() + 1);
    let columns = |pick: &dyn Fn(usize) -> Vec<f64>| -> Vec<Stats> {
        METRICS
            .iter()
            .enumerate()
            .filter_map(|(k, _)| stats(&pick(k)))
            .collect()
    };
    let ins = columns(&|k| {
        tracked
            .iter()
            .map(|(_, i, _)| (METRICS[k].get)(i))
            .collect()
    });
    let systems: Vec<Vec<Stats>> = (0..shown.len())
        .map(|j| {
            columns(&|k| {
                tracked
                    .iter()
                    .map(|(_, _, e)| (METRICS[k].get)(e[j]))
                    .collect()
            })
        })
        .collect();
    let rows = std::iter::once(("INS", &ins)).chain(shown.iter().map(String::as_str).zip(&systems));
    let rows: Vec<(&str, &Vec<Stats>)> = rows.collect();
    for (title, cell) in [
        (
            "mean (σ)",
            &(|s: &Stats, d: usize| {
                format!("{} ({})", format_fixed(s.mean, d), format_fixed(s.std, d))
            }) as &dyn Fn(&Stats, usize) -> String,
        ),
        ("largest", &|s: &Stats, d: usize| format_fixed(s.largest, d)),
    ] {
        let _ = writeln!(md, "| {title} | {} |\n{rule}|", head.join(" | "));
        for (name, st) in &rows {
            let cells: Vec<String> = st
                .iter()
                .zip(&METRICS)
                .map(|(s, m)| cell(s, m.table_decimals))
                .collect();
            let _ = writeln!(md, "| {name} | {} |", cells.join(" | "));
        }
        md.push('\n');
    }
}

/// Per seed: the horizontal error of every system and of the INS, and the distance flown.
fn seed_table(
    md: &mut String,
    tracked: &[(&RunRecord, &NseSample, Vec<&NseSample>)],
    shown: &[String],
) {
    let mut head = String::from("| seed | distance [km] | INS [m] (%)");
    for s in shown {
        let _ = write!(head, " | {s} [m] (%) | {s} Δh [m]");
    }
    let _ = writeln!(md, "{head} |\n{}|", "|---".repeat(3 + 2 * shown.len()));
    for (r, ins, ends) in tracked {
        let mut row = format!(
            "| {} | {} | {} ({})",
            r.seed,
            format_fixed(ins.distance_m / 1000.0, 2),
            format_fixed(ins.hor_m, 1),
            format_fixed(ins.hor_pct, 2)
        );
        for e in ends {
            let _ = write!(
                row,
                " | {} ({}) | {}",
                format_fixed(e.hor_m, 1),
                format_fixed(e.hor_pct, 2),
                format_fixed(e.alt_m, 1)
            );
        }
        let _ = writeln!(md, "{row} |");
    }
    md.push('\n');
}

/// μ ± σ against time for the INS and every system, with each system's run of largest final
/// horizontal error (for up to [`MAX_WORST_RUN_LINES`] systems).
fn plots_for(
    md: &mut String,
    with_vision: &[WithVision],
    names: &[&str],
    tracked: &[(&RunRecord, &NseSample, Vec<&NseSample>)],
    out: &Path,
) -> Result<(), ReportError> {
    let ins_runs: Vec<(&RunRecord, f64, &[NseSample])> = with_vision
        .iter()
        .map(|(r, ins, _)| (*r, 0.0, *ins))
        .collect();
    let ins_rows = time_rows(&ins_runs);
    let system_rows: Vec<Vec<TimeRow>> = names
        .iter()
        .map(|n| {
            let runs: Vec<(&RunRecord, f64, &[NseSample])> = with_vision
                .iter()
                .filter_map(|(r, _, v)| Some((*r, 0.0, system(v, n)?.samples.as_slice())))
                .collect();
            time_rows(&runs)
        })
        .collect();
    let worst: Vec<Option<(&RunRecord, &VisionRun)>> = (0..names.len())
        .map(|j| {
            let (r, _, _) = tracked
                .iter()
                .max_by(|a, b| a.2[j].hor_m.total_cmp(&b.2[j].hor_m))?;
            let (_, _, v) = with_vision.iter().find(|(w, _, _)| w.seed == r.seed)?;
            Some((*r, system(v, names[j])?))
        })
        .collect();
    let plots_to_draw = [
        (
            "hor_pct",
            "vision_horizontal_pct.png",
            "Horizontal error / distance flown",
        ),
        ("hor_m", "vision_horizontal_m.png", "Horizontal error"),
        (
            "att_norm_deg",
            "vision_attitude_norm.png",
            "Attitude error norm",
        ),
        ("alt_m", "vision_altitude.png", "Altitude error"),
    ];
    let mut drawn = Vec::new();
    for (key, file, title) in plots_to_draw {
        let Some(k) = METRICS.iter().position(|m| m.key == key) else {
            continue;
        };
        let band = |rows: &[TimeRow], name: &str, rgb| {
            let pts = |f: &dyn Fn(&Stats) -> f64| -> Vec<(f64, f64)> {
                rows.iter().map(|r| (r.t_s, f(&r.stats[k]))).collect()
            };
            [
                Series {
                    label: format!("{name} mean"),
                    points: pts(&|s| s.mean),
                    rgb,
                    dashed: false,
                },
                Series {
                    label: format!("{name} mean ± σ"),
                    points: pts(&|s| s.mean + s.std),
                    rgb,
                    dashed: true,
                },
                Series {
                    label: String::new(),
                    points: pts(&|s| s.mean - s.std),
                    rgb,
                    dashed: true,
                },
            ]
        };
        let mut series: Vec<Series> = band(&ins_rows, "INS", PALETTE[0]).into();
        for (j, name) in names.iter().enumerate() {
            series.extend(band(
                &system_rows[j],
                &display_name(name),
                system_colour(name, j),
            ));
        }
        if names.len() <= MAX_WORST_RUN_LINES {
            for (j, name) in names.iter().enumerate() {
                let Some((r, v)) = worst[j] else { continue };
                series.push(Series {
                    label: format!("{} worst run (seed {})", display_name(name), r.seed),
                    points: v
                        .samples
                        .iter()
                        .filter(|s| !s.att_norm_deg.is_nan())
                        .map(|s| (s.t_s, (METRICS[k].get)(s)))
                        .collect(),
                    rgb: lighter(system_colour(name, j)),
                    dashed: false,
                });
            }
        }
        let chart = Chart {
            title,
            x_label: "mission time [s]",
            y_label: METRICS[k].y_label,
            series,
            ..Chart::default()
        };
        plots::draw(&out.join(file), &chart, PLOT_SIZE.0, PLOT_SIZE.1)?;
        drawn.push((file, title));
    }
    let worst_note = if names.len() <= MAX_WORST_RUN_LINES {
        " and, in a lighter shade of its colour, its run of largest final horizontal error"
    } else {
        ""
    };
    let _ = writeln!(
        md,
        "Mean (solid) and mean ± σ (dashed) of every system against time{worst_note}; INS \
         blue, VNS red, IA-VNS green.\n"
    );
    for (file, caption) in drawn {
        let _ = writeln!(md, "![{caption}]({file})\n");
    }
    Ok(())
}
