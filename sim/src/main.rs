//! `ianav-sim`: fly the paper's GNSS-denied scenarios in the high-fidelity simulator.
//!
//! - `run`: one flight, with a progress bar, writing trajectory, sensor samples, summary,
//!   plots and a report.
//! - `bench`: one flight without output, timing the simulator (real-time factor, memory).
//! - `mc`: a Monte Carlo batch (or one shard of it) in parallel, one metrics file per run.
//! - `report`: the navigation-error tables and plots of one or several `mc` directories.
//! - `render`: one camera image of a procedural terrain zone, from a given pose.
//! - `sitl`: the simulator as a MAVLink vehicle for the ianav daemon (`docs/SITL.md`).
//!
//! This file holds the command line (clap) and the dispatch; each command's implementation is
//! in its own module under `cmd/`.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};
use ianav_sim::montecarlo::{SeedRange, Shard};

mod cmd;

/// High-fidelity stochastic flight simulator for GNSS-denied navigation.
#[derive(Debug, Parser)]
#[command(name = "ianav-sim", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Options of the commands that fly one seed.
#[derive(Debug, clap::Args)]
struct FlyArgs {
    #[command(flatten)]
    setup: SetupArgs,
    /// Run seed (every random draw of the flight derives from it).
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// What every flight of a command flies (shared by `run`, `bench` and `mc`).
#[derive(Debug, clap::Args)]
struct SetupArgs {
    /// Scenario: 1 (3,800 s benchmark) or 2 (500 s, eight turns).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    scenario: u8,
    /// Mission duration override, s (shorter flights for quick looks).
    #[arg(long)]
    duration: Option<f64>,
    /// Turbulence factor override (0 = calm; the scenarios use 0.5).
    #[arg(long)]
    turbulence: Option<f64>,
    /// Directory with `aircraft.toml`, `sensors.toml`, `control.toml`, `ins.toml`,
    /// `vision.toml` (the `[vision]` settings of the navigator), `camera.toml` (with --terrain)
    /// and
    /// `scenarios/scenario{1,2}.toml` replacing the built-in defaults (each file optional).
    #[arg(long)]
    config_dir: Option<PathBuf>,
    /// What guidance and control fly on: the simulator's truth, or the INS fed with the
    /// simulated sensors.
    #[arg(long, value_enum, default_value_t = Navigation::Ins)]
    navigation: Navigation,
    /// Fly over this terrain zone with the down-looking camera rendering 10 Hz frames
    /// (ds, fm, fr, mx, pr, ur); the flight starts at the zone's start point. Off by default.
    #[arg(long)]
    terrain: Option<String>,
    /// Terrain seed (with --terrain).
    #[arg(long, default_value_t = 0)]
    terrain_seed: u64,
    /// The visual systems run on the same frames (with --terrain), comma-separated: each is
    /// `vision.toml`'s settings with the IA-VNS's switches set its way (`config`: as they
    /// are). The first is the navigator's configured system. The ablation's list is
    /// `vns,vns+init,vns+prediction,vns+priors,vns+structure,ia-vns,ia-vns-pitch,ia-vns-slerp`.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "vns,ia-vns")]
    vision_systems: Vec<ianav_sim::flight::systems::VisionSystem>,
}

/// Navigation source of guidance and control (`--navigation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Navigation {
    /// The simulator's truth.
    Truth,
    /// The GNSS-denied INS.
    Ins,
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
        /// Save camera frames (with --terrain) as PNG files in this directory (frames never go
        /// into the sensor log of `run`: 0.8 MB each).
        #[arg(long, requires = "terrain")]
        frames: Option<PathBuf>,
        /// Save every N-th frame only (with --frames).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
        every: u64,
        /// Fly on the daemon's fused solution: the IA-VNS's horizontal position after the GNSS
        /// loss, restarts after a long loss or a gap in the frames (docs/FUSION.md); the
        /// navigation outputs are the fused solution's.
        #[arg(long, requires = "terrain")]
        fused: bool,
        /// No frames from mission time START for LENGTH seconds, `START:LENGTH` (a stalled
        /// camera; repeatable).
        #[arg(long, requires = "terrain", value_parser = parse_outage)]
        frame_outage: Vec<(f64, f64)>,
        /// Rows and columns between the renderer's exact ray intersections: 2 (the images of
        /// every committed camera result) or 4 (a quarter of the intersections; images within
        /// one grey level, docs/PERFORMANCE.md "Camera renderer"). `run` only: Monte Carlo run
        /// files do not record it.
        #[arg(long, requires = "terrain", default_value_t = 2, value_parser = parse_spacing)]
        render_solve_spacing: usize,
    },
    /// Time one flight of physics, environment, sensors and control (no output files).
    Bench {
        #[command(flatten)]
        fly: FlyArgs,
    },
    /// Time the visual navigation per frame over a camera flight (--terrain ZONE): a
    /// navigator of its own takes the flight's sensor events and each frame's handling is
    /// timed on one thread (no output files).
    BenchVns {
        #[command(flatten)]
        fly: FlyArgs,
    },
    /// Fly a Monte Carlo batch (or one shard of it) and write one metrics file per run.
    Mc(McArgs),
    /// Render one down-looking camera image of a terrain zone (8-bit grey PNG).
    Render(RenderArgs),
    /// Fly as a MAVLink vehicle (software in the loop) for the ianav daemon: stream
    /// PX4-like or ArduPilot-like autopilot messages in real time × --speed, answer TIMESYNC
    /// and SET_MESSAGE_INTERVAL, serve the camera frames (with --terrain), read the daemon's
    /// ODOMETRY / VISION_POSITION_ESTIMATE / GPS_INPUT, fly on its position after GNSS loss,
    /// and log estimate versus truth to DIR/sitl.csv. See docs/SITL.md.
    Sitl(SitlArgs),
    /// Build the Monte Carlo report (`report.md`, plots) from `mc` directories; with
    /// --status, tell how a batch in progress stands instead.
    Report {
        /// Batch directories (holding `runs/`), or parents whose subdirectories are batch
        /// directories (shards copied side by side); runs are merged by seed.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where to write the report (default: the first directory).
        #[arg(long, conflicts_with = "status")]
        out: Option<PathBuf>,
        /// Write no report: per shard, the runs done, failed and to fly (with their seeds), and
        /// an estimate of the time left, from the directory's files alone (any engine).
        #[arg(long)]
        status: bool,
    },
    /// One of the paper's result tables, ours beside the paper's numbers (Markdown): the
    /// MX tables take `1=DIR` and/or `2=DIR` (scenario #1, #2), the terrain tables `ZONE=DIR`
    /// (e.g. `mx=DIR fr=DIR`); each DIR as for `report`.
    Table {
        /// Which table.
        #[arg(value_enum)]
        table: ianav_sim::report::PaperTable,
        /// `LABEL=DIR` pairs.
        #[arg(required = true)]
        inputs: Vec<String>,
        /// Also write the table to this file.
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// Options of `mc`.
#[derive(Debug, clap::Args)]
struct McArgs {
    #[command(flatten)]
    setup: SetupArgs,
    /// Number of runs: seeds 1..=N (unless --seeds is given).
    #[arg(long, required_unless_present = "seeds")]
    runs: Option<u64>,
    /// Inclusive seed range A..B (also written A..=B).
    #[arg(long)]
    seeds: Option<SeedRange>,
    /// Worker threads (default: all cores).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=4096))]
    jobs: Option<u64>,
    /// Fly only shard i of n (1-based): the k-th seed of the list (from 0) goes to shard
    /// k mod n + 1.
    #[arg(long)]
    shard: Option<Shard>,
    /// Output directory (created if missing): `runs/run_NNNN.csv` and the manifest.
    #[arg(long)]
    out: PathBuf,
    /// Keep the run files of this batch already in `--out` and fly only the missing seeds
    /// (an interrupted batch goes on; runs are deterministic, so the files are the same).
    #[arg(long)]
    resume: bool,
}

/// Autopilot imitated by `sitl` (`--autopilot`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum AutopilotArg {
    /// PX4 v1.16 on an onboard link: HIGHRES_IMU at 50 Hz (box averages, pressures in Pa),
    /// no AIRSPEED or AOA_SSA stream.
    Px4,
    /// ArduPlane: 1 Hz stream groups, intervals under 25 ms DENIED, latest IMU samples
    /// truncated to int16, AOA_SSA from its own estimate, lagged GNSS, drifting gyros.
    Ardupilot,
    /// Not a real autopilot: PX4 identity, every simulated sample at its native rate
    /// (HIGHRES_IMU, AIRSPEED, vane AOA_SSA at 100 Hz).
    Ideal,
}

/// Options of `sitl`.
#[derive(Debug, clap::Args)]
struct SitlArgs {
    #[command(flatten)]
    fly: FlyArgs,
    /// MAVLink link to the daemon: udpout:HOST:PORT (send to the daemon), udpin:IP:PORT
    /// (listen; replies go to the last sender), tcpin:IP:PORT (serve one client),
    /// tcpout:HOST:PORT (connect).
    #[arg(long)]
    connect: String,
    /// Autopilot imitated (message set, default rates, interval limits, HEARTBEAT).
    #[arg(long, value_enum, default_value_t = AutopilotArg::Px4)]
    autopilot: AutopilotArg,
    /// Simulated seconds per wall second (1 = real time, 10 = ten times faster, 0 = as fast
    /// as possible).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Serve the camera frames (with --terrain) to one client on this address: host:port
    /// (TCP, e.g. 127.0.0.1:5600) or unix:PATH (a Unix socket, for a daemon on this machine:
    /// lighter on its IMU latency, docs/PERFORMANCE.md).
    #[arg(long, requires = "terrain")]
    frames_listen: Option<ianav::io::frame_stream::StreamAddress>,
    /// Directory for sitl.csv (estimate versus truth); none: no log file.
    #[arg(long)]
    out: Option<PathBuf>,
    /// MAVLink system id of the vehicle.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..))]
    system_id: u8,
    /// Keep flying on the vehicle's own INS after GNSS loss (do not use the daemon's
    /// position).
    #[arg(long)]
    no_external_position: bool,
    /// Age beyond which the daemon's position is no longer flown on, s of simulated time.
    #[arg(long, default_value_t = 1.0)]
    estimate_timeout: f64,
    /// Add ArduPilot SITL's gyro drift triangle (0.05°/s per minute, up to 0.25°/s) to the
    /// gyro rates sent (default: off).
    #[arg(long)]
    gyro_drift: Option<bool>,
    /// GNSS receiver lag, ms: GPS_RAW_INT reports a fix this much after it was taken
    /// (default: 100 for ardupilot, 0 otherwise).
    #[arg(long)]
    gnss_lag_ms: Option<f64>,
    /// ardupilot: from this mission time (s) on, flag the airspeed sensor unhealthy (AIRSPEED
    /// UNHEALTHY, VFR_HUD airspeed = the autopilot's own estimate), as ArduPlane does when it
    /// stops trusting it.
    #[arg(long)]
    airspeed_unhealthy_from: Option<f64>,
    /// Transport and processing latency of every stream, ms of simulated time.
    #[arg(long, default_value_t = 0.0)]
    latency_ms: f64,
    /// Latency of one stream, NAME=MS (e.g. HIGHRES_IMU=40); repeatable, overrides
    /// --latency-ms for that message.
    #[arg(long, value_name = "NAME=MS")]
    stream_latency: Vec<String>,
}

/// Options of `render`.
#[derive(Debug, clap::Args)]
struct RenderArgs {
    /// Terrain zone: ds, fm, fr, mx, pr, ur (or desert, farm, forest, mix, prairie, urban).
    #[arg(long)]
    terrain: String,
    /// Terrain seed.
    #[arg(long, default_value_t = 0)]
    terrain_seed: u64,
    /// Latitude of the aircraft, degrees (default: the zone's start point).
    #[arg(long, allow_hyphen_values = true)]
    lat: Option<f64>,
    /// Longitude of the aircraft, degrees (default: the zone's start point).
    #[arg(long, allow_hyphen_values = true)]
    lon: Option<f64>,
    /// Height of the aircraft above the WGS84 ellipsoid, m (default: 2,700 m above the
    /// terrain below).
    #[arg(long, allow_hyphen_values = true)]
    h: Option<f64>,
    /// Body yaw, degrees.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    yaw: f64,
    /// Body pitch, degrees.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pitch: f64,
    /// Body bank, degrees.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    bank: f64,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
}

/// `START:LENGTH` in seconds, both finite, the length positive.
fn parse_outage(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("{s:?}: expected START:LENGTH (seconds)"))?;
    let start: f64 = a.trim().parse().map_err(|e| format!("{a:?}: {e}"))?;
    let length: f64 = b.trim().parse().map_err(|e| format!("{b:?}: {e}"))?;
    if !(start.is_finite() && length.is_finite() && length > 0.0) {
        return Err(format!("{s:?}: START finite, LENGTH positive"));
    }
    Ok((start, start + length))
}

/// `--render-solve-spacing`: 2 or 4.
fn parse_spacing(s: &str) -> Result<usize, String> {
    match s {
        "2" => Ok(2),
        "4" => Ok(4),
        _ => Err(format!("{s:?}: the spacing is 2 or 4")),
    }
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match &cli.command {
        Command::Run {
            fly,
            out,
            no_sensor_log,
            frames,
            every,
            fused,
            frame_outage,
            render_solve_spacing,
        } => cmd::run::run(
            fly,
            out,
            &cmd::run::RunOptions {
                sensor_log: !*no_sensor_log,
                frames: frames.as_ref(),
                every: *every,
                fused: *fused,
                frame_outages_s: frame_outage,
                render_solve_spacing_px: *render_solve_spacing,
            },
        ),
        Command::Bench { fly } => cmd::bench::bench(fly),
        Command::BenchVns { fly } => cmd::bench::bench_vns(fly),
        Command::Mc(args) => cmd::mc::mc(args),
        Command::Render(args) => cmd::render::render(args),
        Command::Sitl(args) => cmd::sitl::sitl(args),
        Command::Report { dirs, out, status } => {
            if *status {
                cmd::report::status(dirs)
            } else {
                cmd::report::report(dirs, out.as_ref())
            }
        }
        Command::Table { table, inputs, out } => cmd::report::table(*table, inputs, out.as_ref()),
    }
}
