//! `ianav`: the onboard navigation daemon. `ianav run --config FILE` talks MAVLink to a PX4 or
//! ArduPilot autopilot (docs/DAEMON.md); `ianav check-config FILE` validates a configuration.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use clap::Parser;

use ianav::config::ConfigError;
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
    },
    /// Validate a configuration file with every check `run` makes before it opens the link
    /// (keys, ranges, files, log filter, connection address resolved): prints "OK", or the
    /// same error as `run` (naming the key) and exits with status 1.
    CheckConfig {
        /// Configuration file to check.
        #[arg(value_name = "FILE")]
        file: PathBuf,
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
        Some(Command::Run { config }) => {
            let p = preflight(&config).map_err(|e| in_file(&config, e))?;
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

/// A configuration error prefixed with its file, unless it already names it.
fn in_file(file: &Path, e: ConfigError) -> anyhow::Error {
    match &e {
        ConfigError::Read { path, .. } if path == file => e.into(),
        _ => anyhow::Error::new(e).context(file.display().to_string()),
    }
}

/// The daemon until SIGINT / SIGTERM (exit 0) or a worker failure (the error: exit 1, and
/// systemd restarts the daemon).
async fn run(cfg: ianav::config::DaemonConfig) -> anyhow::Result<()> {
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
    if let Some((p50, p99, max)) = handle.shared.latency_percentiles() {
        tracing::info!(
            p50_us = p50,
            p99_us = p99,
            max_us = max,
            "IMU received → solution written latency"
        );
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
