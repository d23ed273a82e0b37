//! `ianav-sim bench`: one flight without output, timing the simulator (real-time factor,
//! memory; docs/PERFORMANCE.md).

use std::time::Instant;

use anyhow::Result;
use ianav_sim::flight::{Flight, NoObserver};

use super::setup;
use crate::FlyArgs;

/// Resident set size and its peak, kB, from `/proc/self/status` (Linux; `None` elsewhere).
fn memory_kb() -> Option<(u64, u64)> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse::<u64>().ok())
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

pub(crate) fn bench(fly: &FlyArgs) -> Result<()> {
    let setup = setup(&fly.setup)?;
    let mut flight = Flight::new(&setup, fly.seed)?;
    let simulated_s = setup.scenario.warmup_s + flight.end_time_s();
    let end_s = flight.end_time_s();
    let mut next_mark = 0.0;
    let mut marks = Vec::new();
    let started = Instant::now();
    let summary = flight.run(&mut NoObserver, |t_s| {
        if t_s >= next_mark {
            marks.push((t_s, memory_kb()));
            next_mark += end_s / 4.0;
        }
    })?;
    let wall_s = started.elapsed().as_secs_f64();
    let navigation = match setup.navigation {
        ianav_sim::flight::NavigationMode::Ins => "the navigation core (INS) at 100 Hz",
        ianav_sim::flight::NavigationMode::Truth => "navigation on the truth",
    };
    println!(
        "scenario {} seed {}: {:.0} s simulated ({} steps at 500 Hz: physics, environment, sensors, control; {navigation})",
        fly.setup.scenario, fly.seed, simulated_s, summary.truth_steps
    );
    println!(
        "wall time {wall_s:.3} s, real-time factor {:.0}x, {:.0} ns per integration step",
        simulated_s / wall_s,
        wall_s * 1e9 / summary.truth_steps as f64
    );
    for (t_s, mem) in marks {
        if let Some((rss, peak)) = mem {
            println!("  at mission t = {t_s:7.1} s: RSS {rss} kB (peak {peak} kB)");
        }
    }
    if let Some((rss, peak)) = memory_kb() {
        println!("  at the end:             RSS {rss} kB (peak {peak} kB)");
    }
    Ok(())
}
