//! `ianav`: the onboard navigation daemon (issue 5). `ianav run --config FILE` talks MAVLink to
//! a PX4 or ArduPilot autopilot (docs/DAEMON.md); `ianav check-config FILE` validates a
//! configuration.

use std::path::PathBuf;

use anyhow::Context;
use clap::Parser;

use ianav::config::DaemonConfig;

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
    /// `output.rate_hz`. Logs go to stderr (`logging.level`, overridden by RUST_LOG); under
    /// systemd it sends READY=1 and feeds the watchdog while the estimator runs.
    Run {
        /// Configuration file (see config/ianav.toml).
        #[arg(long, short, value_name = "FILE")]
        config: PathBuf,
    },
    /// Validate a configuration file: prints "OK" or the error (naming the key) and exits
    /// with status 1 on error.
    CheckConfig {
        /// Configuration file to check.
        #[arg(value_name = "FILE")]
        file: PathBuf,
    },
    /// Print the version and exit.
    Version,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Version) | None => {
            println!("ianav {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Some(Command::CheckConfig { file }) => match DaemonConfig::from_file(&file) {
            Ok(_) => {
                println!("OK");
                Ok(())
            }
            Err(e) => {
                eprintln!("{}: {e}", file.display());
                std::process::exit(1);
            }
        },
        Some(Command::Run { config }) => {
            let cfg = DaemonConfig::from_file(&config)
                .with_context(|| format!("configuration {}", config.display()))?;
            let filter = tracing_subscriber::EnvFilter::try_from_default_env()
                .or_else(|_| tracing_subscriber::EnvFilter::try_new(&cfg.logging.level))
                .context("logging.level")?;
            tracing_subscriber::fmt()
                .with_env_filter(filter)
                .with_writer(std::io::stderr)
                .init();
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .context("tokio runtime")?;
            rt.block_on(async {
                let (htx, hrx) = tokio::sync::oneshot::channel();
                let daemon = tokio::spawn(ianav::daemon::run(cfg, Some(htx)));
                let Ok(handle) = hrx.await else {
                    daemon.await.context("daemon task")??;
                    anyhow::bail!("the daemon stopped before starting");
                };
                let mut term =
                    tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                        .context("SIGTERM handler")?;
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => tracing::info!("SIGINT: stopping"),
                    _ = term.recv() => tracing::info!("SIGTERM: stopping"),
                }
                ianav::daemon::log_counters(&handle.shared.counters());
                if let Some((p50, p99, max)) = handle.shared.latency_percentiles() {
                    tracing::info!(
                        p50_us = p50,
                        p99_us = p99,
                        max_us = max,
                        "IMU received → solution written latency"
                    );
                }
                handle.stop();
                daemon.await.context("daemon task")??;
                Ok(())
            })
        }
    }
}
