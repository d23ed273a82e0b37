//! `ianav-sim mc`: a Monte Carlo batch (or one shard of it) in parallel, one metrics file per
//! run (the paper's 100 runs per scenario; docs/MONTECARLO.md).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::Result;
use ianav_sim::montecarlo::{self, Batch, RunOutcome};
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
    let bar = ProgressBar::new(to_fly.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} runs (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let shard = args
        .shard
        .map(|s| format!(" shard {s}"))
        .unwrap_or_default();
    bar.set_message(format!("scenario {}{shard}", args.setup.scenario));
    let failed = AtomicUsize::new(0);
    let started = Instant::now();
    let summary = montecarlo::run_batch(&batch, &args.out, |record| {
        if let RunOutcome::Failed { reason } = &record.outcome {
            let n = failed.fetch_add(1, Ordering::Relaxed) + 1;
            bar.println(format!("seed {} failed: {reason}", record.seed));
            bar.set_message(format!(
                "scenario {}{shard} ({n} failed)",
                args.setup.scenario
            ));
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
