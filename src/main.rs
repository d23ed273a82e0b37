//! `ianav`: the onboard navigation daemon. `ianav run --config FILE` talks MAVLink to a PX4 or
//! ArduPilot autopilot (docs/DAEMON.md); `ianav check-config FILE` validates a configuration.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use clap::Parser;

use ianav::daemon::config::ConfigError;
use ianav::daemon::preflight::preflight;

/// GNSS-denied navigation daemon for fixed-wing UAVs.
///
/// Reads IMU, air data, magnetometer and GNSS from the autopilot over MAVLink, runs the
/// navigation core, and publishes a position the autopilot can fly on after GNSS is lost
/// (ODOMETRY for PX4, GPS_INPUT for ArduPilot). See docs/DAEMON.md, docs/PX4.md and
/// docs/ARDUPILOT.md.
#[derive(Debug, Parser)]
#[command(name = "ianav", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Run the daemon until SIGINT or SIGTERM.
    ///
    /// Connects to the autopilot named by `mavlink.connection`, waits for its HEARTBEAT,
    /// requests the sensor streams, starts the INS on the first GNSS fix and publishes at
    /// `output.rate_hz`. Logs go to stderr (`logging.level`; a RUST_LOG set in the environment
    /// replaces it); under systemd it sends READY=1 and feeds the watchdog while the estimator
    /// runs on IMU samples. Exits non-zero (after a STATUSTEXT) if any worker fails.
    Run {
        /// Configuration file (see config/ianav.toml).
        #[arg(long, short, value_name = "FILE")]
        config: PathBuf,
        /// Record every sensor event fed to the navigation core, camera frames inline, and
        /// the navigation settings into this sensor log (`ianav replay` runs it; format in
        /// docs/REPLAY.md). Overwritten if it exists.
        #[arg(long, value_name = "FILE")]
        record: Option<PathBuf>,
    },
    /// Validate a configuration file with every check `run` makes before it opens the link
    /// (keys, ranges, files, log filter, connection address resolved): prints "OK", or the
    /// same error as `run` (naming the key) and exits with status 1.
    CheckConfig {
        /// Configuration file to check.
        #[arg(value_name = "FILE")]
        file: PathBuf,
    },
    /// Run a sensor log (the simulator's `sensors.bin`, or a daemon's recording) through the
    /// navigation core with the settings recorded in it, and write the solutions to
    /// `OUT/solutions.csv` (numbers in their shortest exact decimal form: the same log gives
    /// the same file, bit for bit).
    Replay {
        /// Sensor log.
        #[arg(value_name = "FILE")]
        log: PathBuf,
        /// Output directory (created).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Write every N-th solution (the first included); 1 = every IMU step.
        #[arg(long, default_value_t = 1, value_name = "N")]
        every: u64,
        /// Replace one recorded setting (repeatable): a dotted key of the recorded
        /// navigation settings and a TOML value, e.g. `ins.attitude.q_w_nb_rad2ps2=1e-3` or
        /// `vision.pose.max_iterations=5`. An unknown key is an error.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Also write the INS's internal estimates at the same solutions to `OUT/states.csv`
        /// (air data, wind, specific force, sensor errors, magnetic-model error, reference
        /// attitude error, GNSS NIS; columns in docs/REPLAY.md).
        #[arg(long)]
        states: bool,
    },
    /// Replay a sensor log (a daemon's recording, the simulator's `sensors.bin`) with the
    /// settings recorded in it and write an MCAP file Foxglove opens: the frames, the
    /// published position with its covariance, the visual fixes and a status to plot
    /// (docs/REPLAY.md "MCAP").
    ExportMcap {
        /// Sensor log.
        #[arg(value_name = "FILE")]
        log: PathBuf,
        /// MCAP file to write.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Period of the position and status messages, ms.
        #[arg(long, default_value_t = 100, value_name = "MS")]
        period_ms: u64,
        /// Write every N-th frame.
        #[arg(long, default_value_t = 1, value_name = "N")]
        frame_every: u64,
        /// A simulated run's `truth.csv`: its track and the errors go in too.
        #[arg(long, value_name = "FILE")]
        truth: Option<PathBuf>,
    },
    /// Print the version and exit.
    Version,
}

fn main() -> std::process::ExitCode {
    match cli(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // The one place an error is printed: the context chain on one line.
            eprintln!("ianav: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn cli(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Some(Command::Version) | None => {
            println!("ianav {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Some(Command::CheckConfig { file }) => {
            preflight(&file).map_err(|e| in_file(&file, e))?;
            println!("OK");
            Ok(())
        }
        Some(Command::Replay {
            log,
            out,
            every,
            overrides,
            states,
        }) => replay(&log, &out, every, &overrides, states),
        Some(Command::ExportMcap {
            log,
            out,
            period_ms,
            frame_every,
            truth,
        }) => export_mcap(&log, &out, period_ms, frame_every, truth.as_deref()),
        Some(Command::Run { config, record }) => {
            let mut p = preflight(&config).map_err(|e| in_file(&config, e))?;
            p.config.record = record;
            tracing_subscriber::fmt()
                .with_env_filter(p.log_filter)
                .with_writer(std::io::stderr)
                .init();
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .context("tokio runtime")?;
            let result = rt.block_on(run(p.config));
            // Blocking tasks (an image decode, the camera capture loop) get 2 s to notice the
            // stop; a runtime dropped normally would wait for them without bound.
            rt.shutdown_timeout(Duration::from_secs(2));
            result
        }
    }
}

/// `ianav export-mcap`: the log through the navigator, to MCAP.
fn export_mcap(
    log: &Path,
    out: &Path,
    period_ms: u64,
    frame_every: u64,
    truth: Option<&Path>,
) -> anyhow::Result<()> {
    use std::io::BufReader;
    let truth = match truth {
        Some(path) => {
            let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
            ianav::io::mcap_export::truth_from_csv(&text)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
        }
        None => Vec::new(),
    };
    let file = std::fs::File::open(log).with_context(|| log.display().to_string())?;
    let reader = ianav::io::sensor_log::SensorLogReader::new(BufReader::new(file))
        .with_context(|| log.display().to_string())?;
    let cfg = ianav::nav::replay::config_of(&reader).with_context(|| log.display().to_string())?;
    let mcap = std::io::BufWriter::new(
        std::fs::File::create(out).with_context(|| out.display().to_string())?,
    );
    let options = ianav::io::mcap_export::McapOptions {
        period_us: period_ms.saturating_mul(1_000),
        frame_every,
    };
    let s = ianav::io::mcap_export::export_mcap(reader, &cfg, mcap, &options, &truth)
        .with_context(|| format!("{} -> {}", log.display(), out.display()))?;
    let counts: Vec<String> = s
        .messages
        .iter()
        .map(|(topic, n)| format!("{topic} {n}"))
        .collect();
    println!(
        "{} events, {} solutions; wrote {}: {}",
        s.replay.events,
        s.replay.solutions,
        out.display(),
        counts.join(", ")
    );
    Ok(())
}

/// `ianav replay`: the log through the navigator, the solutions to `out/solutions.csv`.
fn replay(
    log: &Path,
    out: &Path,
    every: u64,
    overrides: &[String],
    states: bool,
) -> anyhow::Result<()> {
    use std::io::{BufReader, BufWriter, Write};
    let file = std::fs::File::open(log).with_context(|| log.display().to_string())?;
    let reader = ianav::io::sensor_log::SensorLogReader::new(BufReader::new(file))
        .with_context(|| log.display().to_string())?;
    std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
    let path = out.join("solutions.csv");
    let mut csv =
        BufWriter::new(std::fs::File::create(&path).with_context(|| path.display().to_string())?);
    let states_path = out.join("states.csv");
    let mut states_csv = match states {
        true => Some(BufWriter::new(
            std::fs::File::create(&states_path)
                .with_context(|| states_path.display().to_string())?,
        )),
        false => None,
    };
    let s = ianav::nav::replay::replay_to_csvs(
        reader,
        overrides,
        every,
        &mut csv,
        states_csv.as_mut().map(|w| w as &mut dyn Write),
    )
    .with_context(|| log.display().to_string())?;
    csv.flush().with_context(|| path.display().to_string())?;
    if let Some(mut w) = states_csv {
        w.flush()
            .with_context(|| states_path.display().to_string())?;
    }
    println!(
        "{} events, {} solutions ({} written to {}), {} starts",
        s.events,
        s.solutions,
        s.written,
        path.display(),
        s.nav.initialisations
    );
    if let Some(last) = s.last {
        println!(
            "last solution at {} µs: lat {:.7}°, lon {:.7}°, h {:.1} m, GNSS-denied {}",
            last.t_us,
            last.pos.lat_rad.to_degrees(),
            last.pos.lon_rad.to_degrees(),
            last.pos.h_m,
            last.ins_status.gnss_denied
        );
    }
    Ok(())
}

/// A configuration error prefixed with its file, unless it already names it.
fn in_file(file: &Path, e: ConfigError) -> anyhow::Error {
    match &e {
        ConfigError::Read { path, .. } if path == file => e.into(),
        _ => anyhow::Error::new(e).context(file.display().to_string()),
    }
}

/// The daemon until SIGINT / SIGTERM (exit 0) or a worker failure (the error: exit 1, and
/// systemd restarts the daemon).
async fn run(cfg: ianav::daemon::config::DaemonConfig) -> anyhow::Result<()> {
    let (htx, hrx) = tokio::sync::oneshot::channel();
    let mut daemon = tokio::spawn(ianav::daemon::run(cfg, Some(htx)));
    let Ok(handle) = hrx.await else {
        daemon.await.context("daemon task")??;
        anyhow::bail!("the daemon stopped before starting");
    };
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .context("SIGTERM handler")?;
    let ended = tokio::select! {
        _ = tokio::signal::ctrl_c() => {
            tracing::info!("SIGINT: stopping");
            None
        }
        _ = term.recv() => {
            tracing::info!("SIGTERM: stopping");
            None
        }
        r = &mut daemon => Some(r),
    };
    ianav::daemon::log_counters(&handle.shared.counters());
    let shared = &handle.shared;
    for (label, percentiles) in [
        (
            "IMU received → solution written latency",
            shared.latency_percentiles(),
        ),
        (
            "frame received → visual result applied latency",
            shared.frame_latency_percentiles(),
        ),
        (
            "frame due (the INS at its time) → visual result applied latency",
            shared.frame_due_latency_percentiles(),
        ),
    ] {
        if let Some((p50, p99, max)) = percentiles {
            tracing::info!(p50_us = p50, p99_us = p99, max_us = max, "{label}");
        }
    }
    let result = match ended {
        Some(r) => r,
        None => {
            handle.stop();
            daemon.await
        }
    };
    result.context("daemon task")?.context("daemon stopped")?;
    Ok(())
}
