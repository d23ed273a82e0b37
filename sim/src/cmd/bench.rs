//! `ianav-sim bench`: one flight without output, timing the simulator (real-time factor,
//! memory); `ianav-sim bench-vns`: the visual navigation's time per frame over a camera flight
//! (docs/PERFORMANCE.md).

use std::time::Instant;

use anyhow::{Result, bail};
use ianav::nav::VisionState;
use ianav_sim::flight::{Flight, NoObserver};
use ianav_sim::vns_timing::{TimeSummary, VnsTimer, VnsTimers, vision_config};

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

/// One summary line: `label` frames and their time order statistics.
fn print_summary(label: &str, ns: impl IntoIterator<Item = u64>) {
    match TimeSummary::of(ns) {
        Some(s) => println!(
            "  {label:<28} {:>6}  {:>7.2} {:>7.2} {:>7.2} {:>7.2} {:>7.2}",
            s.n, s.mean_ms, s.median_ms, s.p90_ms, s.p99_ms, s.max_ms
        ),
        None => println!("  {label:<28} {:>6}", 0),
    }
}

pub(crate) fn bench_vns(fly: &FlyArgs) -> Result<()> {
    let mut setup = setup(&fly.setup)?;
    let Some(camera) = setup.camera.as_mut() else {
        bail!("bench-vns needs --terrain ZONE");
    };
    // The flight's own navigator leaves the frames to the timer's navigator.
    camera.vision_navigation = false;
    let terrain = std::sync::Arc::clone(&camera.terrain);
    let mut flight = Flight::new(&setup, fly.seed)?;
    let mut timers = VnsTimers(
        setup
            .vision_systems
            .iter()
            .map(|&system| {
                Ok((
                    system,
                    VnsTimer::new(&vision_config(&setup, &flight, system)?)?,
                ))
            })
            .collect::<Result<_>>()?,
    );
    let end_s = flight.end_time_s();
    let mut next_mark = 0.0;
    // Mission time, memory and the renderer's tile caches (bytes held), which grow with the
    // ground flown over and are the simulator's, not the navigation's.
    let mut marks = Vec::new();
    let started = Instant::now();
    flight.run(&mut timers, |t_s| {
        if t_s >= next_mark {
            let (heights, albedo) = terrain.cache_stats();
            marks.push((t_s, memory_kb(), heights.bytes + albedo.bytes));
            next_mark += end_s / 8.0;
        }
    })?;
    let wall_s = started.elapsed().as_secs_f64();
    let Some((_, first)) = timers.0.first() else {
        bail!("no visual system to time (--vision-systems)");
    };
    println!(
        "scenario {} seed {} over {}: {} frames in {wall_s:.1} s of flight simulation (renderer and every system included)",
        fly.setup.scenario,
        fly.seed,
        fly.setup.terrain.as_deref().unwrap_or("?"),
        first.frames().len()
    );
    for (system, timer) in &timers.0 {
        print_system(system.name(), timer);
    }
    let frames = first.frames();
    println!(
        "memory (RSS, every system's navigator included; the renderer's tile caches; the map of {} at the latest frame):",
        setup.vision_systems.first().map_or("?", |s| s.name())
    );
    for (t_s, mem, tiles_bytes) in marks {
        let t_us = (t_s + setup.scenario.warmup_s).max(0.0) * 1e6;
        let n_before = frames.partition_point(|f| f.t_us as f64 <= t_us);
        let map = n_before.checked_sub(1).map(|i| &frames[i]);
        if let Some((rss, peak)) = mem {
            println!(
                "  at mission t = {t_s:7.1} s: RSS {rss:>7} kB (peak {peak:>7} kB), tile caches {:>7} kB, map {:>3} keyframes {:>5} points",
                tiles_bytes / 1024,
                map.map_or(0, |f| f.n_keyframes),
                map.map_or(0, |f| f.n_points),
            );
        }
    }
    if let Some((rss, peak)) = memory_kb() {
        println!("  at the end:             RSS {rss:>7} kB (peak {peak:>7} kB)");
    }
    Ok(())
}

/// One system's frame times and counters.
fn print_system(name: &str, timer: &VnsTimer) {
    let frames = timer.frames();
    println!(
        "{name}: time per frame (Navigator::push of the frame, one thread, this system alone), ms:\n  {:<28} {:>6}  {:>7} {:>7} {:>7} {:>7} {:>7}",
        "frames", "n", "mean", "median", "p90", "p99", "max"
    );
    print_summary("all", frames.iter().map(|f| f.ns));
    print_summary(
        "tracking, not keyframes",
        frames
            .iter()
            .filter(|f| f.state == VisionState::Tracking && !f.keyframe)
            .map(|f| f.ns),
    );
    print_summary(
        "keyframes",
        frames.iter().filter(|f| f.keyframe).map(|f| f.ns),
    );
    print_summary(
        "initialising / waiting",
        frames
            .iter()
            .filter(|f| {
                matches!(
                    f.state,
                    VisionState::Initialising | VisionState::WaitingForStart
                )
            })
            .map(|f| f.ns),
    );
    print_summary(
        "relocalising",
        frames
            .iter()
            .filter(|f| f.state == VisionState::Relocalising)
            .map(|f| f.ns),
    );
    if let Some(c) = timer.navigator().vns_counters() {
        println!(
            "{name}: {} initialisations, {} keyframes, {} tracking losses, {} relocalisations, {} second-chance recoveries ({} from turned starts), {} bad frames",
            c.initialisations,
            c.keyframes,
            c.tracking_losses,
            c.relocalisations,
            c.motion_model_recoveries,
            c.turned_start_recoveries,
            c.bad_frames
        );
    }
    if let Some(a) = timer.navigator().aiding_counters() {
        println!(
            "{name}: {} frames from ζ* ({} failed), {} activations evaluated, {} priors active ({} joint not kept)",
            a.inertial_starts,
            a.inertial_start_failures,
            a.activations_evaluated,
            a.priors_active,
            a.joint_failures
        );
    }
}
