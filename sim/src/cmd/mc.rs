//! `ianav-sim mc`: a Monte Carlo batch (or one shard of it) in parallel, one metrics file per
//! run (the paper's 100 runs per scenario; docs/MONTECARLO.md). On a terminal a progress bar
//! counts the runs; otherwise (a batch job's log) one line per run says its seed and outcome
//! and the progress.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::Result;
use ianav_sim::montecarlo::{self, Batch, RunDone, RunOutcome};
use indicatif::{ProgressBar, ProgressStyle};

use super::setup;
use crate::McArgs;

pub(crate) fn mc(args: &McArgs) -> Result<()> {
    let setup = setup(&args.setup)?;
    let seeds = montecarlo::seed_list(args.runs, args.seeds)?;
    let batch = Batch {
        scenario: args.setup.scenario,
        setup,
        seeds,
        shard: args.shard,
        jobs: args.jobs.map(|j| j as usize),
        resume: args.resume,
    };
    let to_fly = batch.seeds_to_fly();
    let shard = args
        .shard
        .map(|s| format!(" shard {s}"))
        .unwrap_or_default();
    let zone = args.setup.terrain.as_deref().unwrap_or("none");
    let label = format!("scenario {} zone {zone}{shard}", args.setup.scenario);
    let plain = !std::io::stderr().is_terminal();
    let bar = if plain {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(to_fly.len() as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} runs (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(label.clone());
    if plain {
        let first = batch.seeds.first().copied().unwrap_or(0);
        let last = batch.seeds.last().copied().unwrap_or(0);
        eprintln!(
            "{label}: seeds {first}..={last}, this process {} runs ({}), duration {} s, jobs \
             {}{}, out {}",
            to_fly.len(),
            abbreviate(&to_fly),
            batch.setup.scenario.duration_s,
            batch
                .jobs
                .map_or_else(|| "all cores".to_owned(), |j| j.to_string()),
            if batch.resume { ", --resume" } else { "" },
            args.out.display()
        );
    }
    let failed = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let started = Instant::now();
    let summary = montecarlo::run_batch(&batch, &args.out, |run: &RunDone<'_>| {
        let n_done = done.fetch_add(1, Ordering::Relaxed) + 1;
        let record = run.record;
        let outcome = match (&record.outcome, run.kept) {
            (RunOutcome::Completed { .. }, true) => "kept (already flown)".to_owned(),
            (RunOutcome::Failed { reason }, true) => format!("kept, failed: {reason}"),
            (RunOutcome::Completed { .. }, false) => format!("completed in {:.1} s", run.wall_s),
            (RunOutcome::Failed { reason }, false) => {
                format!("failed in {:.1} s: {reason}", run.wall_s)
            }
        };
        if let RunOutcome::Failed { reason } = &record.outcome {
            let n = failed.fetch_add(1, Ordering::Relaxed) + 1;
            if !plain {
                bar.println(format!("seed {} failed: {reason}", record.seed));
                bar.set_message(format!("{label} ({n} failed)"));
            }
        }
        if plain {
            eprintln!(
                "{label}: seed {} {outcome} [{n_done}/{} runs, {:.1} s elapsed]",
                record.seed,
                to_fly.len(),
                started.elapsed().as_secs_f64()
            );
        }
        bar.inc(1);
    })?;
    bar.finish();
    let m = &summary.manifest;
    println!(
        "scenario {}{shard}: {} runs, {} completed, {} failed, in {:.1} s wall; manifest {}",
        m.scenario,
        m.seeds.len(),
        m.completed,
        m.failed.len(),
        started.elapsed().as_secs_f64(),
        summary.manifest_path.display()
    );
    Ok(())
}

/// The seeds, the first 12 and how many more.
fn abbreviate(seeds: &[u64]) -> String {
    let mut t = seeds
        .iter()
        .take(12)
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    if seeds.len() > 12 {
        t.push_str(&format!(", … {} more", seeds.len() - 12));
    }
    t
}
