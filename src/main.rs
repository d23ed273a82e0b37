//! `ianav`: the onboard navigation daemon (subcommands arrive with the MAVLink issue).

use clap::Parser;

/// GNSS-denied navigation daemon for fixed-wing UAVs.
#[derive(Debug, Parser)]
#[command(name = "ianav", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Print the version and exit.
    Version,
}

fn main() {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Version) | None => println!("ianav {}", env!("CARGO_PKG_VERSION")),
    }
}
