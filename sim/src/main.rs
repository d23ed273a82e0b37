//! `ianav-sim`: fly the paper's GNSS-denied scenarios in the high-fidelity simulator.
//!
//! - `run`: one flight, with a progress bar, writing trajectory, sensor samples, summary,
//!   plots and a report.
//! - `bench`: one flight without output, timing the simulator (real-time factor, memory).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use ianav_sim::flight::{Flight, FlightSetup, NoObserver};
use ianav_sim::output::RunWriter;
use indicatif::{ProgressBar, ProgressStyle};

/// High-fidelity stochastic flight simulator for GNSS-denied navigation.
#[derive(Debug, Parser)]
#[command(name = "ianav-sim", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Options shared by the commands that fly.
#[derive(Debug, clap::Args)]
struct FlyArgs {
    /// Scenario: 1 (3,800 s benchmark) or 2 (500 s, eight turns).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    scenario: u8,
    /// Run seed (every random draw of the flight derives from it).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Mission duration override, s (shorter flights for quick looks).
    #[arg(long)]
    duration: Option<f64>,
    /// Turbulence factor override (0 = calm; the scenarios use 0.5).
    #[arg(long)]
    turbulence: Option<f64>,
    /// Directory with `aircraft.toml`, `sensors.toml`, `control.toml` and
    /// `scenarios/scenario{1,2}.toml` replacing the built-in defaults (each file optional).
    #[arg(long)]
    config_dir: Option<PathBuf>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Fly one flight and write its outputs.
    Run {
        #[command(flatten)]
        fly: FlyArgs,
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Do not write the sensor sample log.
        #[arg(long)]
        no_sensor_log: bool,
    },
    /// Time one flight of physics, environment, sensors and control (no output files).
    Bench {
        #[command(flatten)]
        fly: FlyArgs,
    },
}

fn read_optional(dir: Option<&PathBuf>, name: &str) -> Result<Option<(PathBuf, String)>> {
    let Some(dir) = dir else { return Ok(None) };
    let path = dir.join(name);
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    Ok(Some((path, text)))
}

fn setup(args: &FlyArgs) -> Result<FlightSetup> {
    let mut setup = FlightSetup::builtin(args.scenario)?;
    let dir = args.config_dir.as_ref();
    if let Some((path, text)) =
        read_optional(dir, &format!("scenarios/scenario{}.toml", args.scenario))?
    {
        setup.scenario = ianav_sim::scenario::ScenarioConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "aircraft.toml")? {
        setup.aircraft = ianav_sim::aircraft::AircraftParams::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "sensors.toml")? {
        setup.sensors = ianav_sim::sensors::SensorsConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "control.toml")? {
        setup.control = ianav_sim::control::ControlConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some(duration) = args.duration {
        if !(duration.is_finite() && duration > 0.0) {
            bail!("--duration must be a positive number of seconds, got {duration}");
        }
        setup.scenario.duration_s = duration;
    }
    if let Some(factor) = args.turbulence {
        if !(factor.is_finite() && factor >= 0.0) {
            bail!("--turbulence must be a non-negative factor, got {factor}");
        }
        setup.scenario.turbulence_factor = factor;
    }
    setup.scenario.validate()?;
    Ok(setup)
}

fn run(fly: &FlyArgs, out: &std::path::Path, no_sensor_log: bool) -> Result<()> {
    let setup = setup(fly)?;
    let mut flight = Flight::new(&setup, fly.seed)?;
    let mut writer = RunWriter::new(out, !no_sensor_log)?;
    let end_s = flight.end_time_s();
    let bar = ProgressBar::new(end_s.ceil() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} s mission time (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("scenario {} seed {}", fly.scenario, fly.seed));
    let started = Instant::now();
    let summary = flight.run(&mut writer, |t_s| bar.set_position(t_s.max(0.0) as u64))?;
    bar.finish();
    let report = writer.finish(&summary)?;
    println!(
        "{}: flew {:.0} s, {:.0} m in {:.1} s wall; report: {}",
        summary.scenario,
        summary.duration_s,
        summary.distance_m,
        started.elapsed().as_secs_f64(),
        report.display()
    );
    Ok(())
}

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

fn bench(fly: &FlyArgs) -> Result<()> {
    let setup = setup(fly)?;
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
    println!(
        "scenario {} seed {}: {:.0} s simulated ({} steps at 500 Hz, physics + environment + sensors + control)",
        fly.scenario, fly.seed, simulated_s, summary.truth_steps
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

fn main() -> Result<()> {
    let cli = Cli::parse();
    match &cli.command {
        Command::Run {
            fly,
            out,
            no_sensor_log,
        } => run(fly, out, *no_sensor_log),
        Command::Bench { fly } => bench(fly),
    }
}
