//! `ianav-sim`: fly the paper's GNSS-denied scenarios in the high-fidelity simulator.
//!
//! - `run`: one flight, with a progress bar, writing trajectory, sensor samples, summary,
//!   plots and a report.
//! - `bench`: one flight without output, timing the simulator (real-time factor, memory).
//! - `mc`: a Monte Carlo batch (or one shard of it) in parallel, one metrics file per run.
//! - `report`: the navigation-error tables and plots of one or several `mc` directories.
//! - `render`: one camera image of a procedural terrain zone, from a given pose.
//! - `sitl`: the simulator as a MAVLink vehicle for the ianav daemon (`docs/SITL.md`).

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use ianav_sim::flight::{Flight, FlightSetup, NavigationMode, NoObserver};
use ianav_sim::montecarlo::{self, Batch, RunOutcome, SeedRange, Shard};
use ianav_sim::output::RunWriter;
use indicatif::{ProgressBar, ProgressStyle};

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
    /// `camera.toml` (with --terrain) and
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
        /// Save camera frames (with --terrain) as PNG files in this directory; frames are
        /// not written to the sensor log.
        #[arg(long, requires = "terrain")]
        frames: Option<PathBuf>,
        /// Save every N-th frame only (with --frames).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
        every: u64,
    },
    /// Time one flight of physics, environment, sensors and control (no output files).
    Bench {
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
    /// Build the Monte Carlo report (`report.md`, plots) from `mc` directories.
    Report {
        /// Batch directories (holding `runs/`), or parents whose subdirectories are batch
        /// directories (shards copied side by side); runs are merged by seed.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where to write the report (default: the first directory).
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
    /// Serve the camera frames (with --terrain) to one TCP client on this address, e.g.
    /// 127.0.0.1:5600.
    #[arg(long, requires = "terrain")]
    frames_listen: Option<String>,
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

/// Milliseconds of an option → µs (finite, ≥ 0).
fn option_ms_to_us(name: &str, ms: f64) -> anyhow::Result<u64> {
    if !(ms.is_finite() && ms >= 0.0) {
        anyhow::bail!("{name} must be a non-negative number of ms, got {ms}");
    }
    Ok((ms * 1e3).round() as u64)
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

fn render(args: &RenderArgs) -> Result<()> {
    use ianav::math::{so3, wgs84::Geodetic};
    use ianav::vision::camera::{Camera, MountingConfig};
    use ianav_sim::terrain::{Terrain, Zone, render::Renderer};
    let zone: Zone = args.terrain.parse()?;
    let terrain = Terrain::new(zone, args.terrain_seed);
    let start = zone.start();
    let lat_deg = args.lat.unwrap_or(start.lat_deg);
    let lon_deg = args.lon.unwrap_or(start.lon_deg);
    for (name, v) in [
        ("--lat", lat_deg),
        ("--lon", lon_deg),
        ("--yaw", args.yaw),
        ("--pitch", args.pitch),
        ("--bank", args.bank),
    ] {
        if !v.is_finite() {
            bail!("{name} must be a finite number, got {v}");
        }
    }
    if !(-90.0..=90.0).contains(&lat_deg) {
        bail!("--lat must be within ±90°, got {lat_deg}");
    }
    let (lat_rad, lon_rad) = (lat_deg.to_radians(), lon_deg.to_radians());
    let h_m = match args.h {
        Some(h) => h,
        None => terrain.height_m(lat_rad, lon_rad) + 2_700.0,
    };
    let pos = Geodetic {
        lat_rad,
        lon_rad,
        h_m,
    };
    let q_nb = so3::from_euler_zyx(
        args.yaw.to_radians(),
        args.pitch.to_radians(),
        args.bank.to_radians(),
    );
    let mounting = MountingConfig::default().nominal();
    let zeta_ec = mounting.zeta_ec(&pos, &q_nb, &nalgebra::Vector3::zeros());
    let renderer = Renderer::new(Camera::paper());
    let started = Instant::now();
    let (image, stats) = renderer.render_with_stats(&terrain, &zeta_ec)?;
    let elapsed = started.elapsed();
    image
        .save_png(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let ground_m = terrain.height_m(lat_rad, lon_rad);
    println!(
        "{}: {}x{} px from {:.0} m ({:.0} m above the terrain) in {:.1} ms ({} sky px, {} marched rays, {} exact albedo samples); {}",
        zone,
        image.width,
        image.height,
        h_m,
        h_m - ground_m,
        elapsed.as_secs_f64() * 1e3,
        stats.sky,
        stats.marched,
        stats.exact_albedo,
        args.out.display()
    );
    Ok(())
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

fn setup(args: &SetupArgs) -> Result<FlightSetup> {
    let mut setup = FlightSetup::builtin(args.scenario)?;
    let dir = args.config_dir.as_ref();
    // Each file in it is optional, so a mistyped directory would silently fly the defaults.
    if let Some(d) = dir {
        let meta = std::fs::metadata(d).with_context(|| format!("--config-dir {}", d.display()))?;
        if !meta.is_dir() {
            bail!("--config-dir {}: not a directory", d.display());
        }
    }
    if let Some((path, text)) =
        read_optional(dir, &format!("scenarios/scenario{}.toml", args.scenario))?
    {
        setup.scenario = ianav_sim::scenario::ScenarioConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "ins.toml")? {
        setup.ins = ianav::ins::InsConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    setup.navigation = match args.navigation {
        Navigation::Truth => NavigationMode::Truth,
        Navigation::Ins => NavigationMode::Ins,
    };
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
    if let Some(name) = &args.terrain {
        let zone: ianav_sim::terrain::Zone = name.parse()?;
        let start = zone.start();
        setup.scenario.start.lat_deg = start.lat_deg;
        setup.scenario.start.lon_deg = start.lon_deg;
        let terrain = ianav_sim::terrain::Terrain::new(zone, args.terrain_seed);
        setup.camera = Some(ianav_sim::flight::CameraSetup::new(std::sync::Arc::new(
            terrain,
        )));
    }
    setup.scenario.validate()?;
    Ok(setup)
}

/// Observer that saves camera frames as PNG files and passes everything else on.
struct FrameSaver<'a, O> {
    inner: &'a mut O,
    dir: Option<PathBuf>,
    every: u64,
    count: u64,
    error: Option<anyhow::Error>,
}

impl<O: ianav_sim::flight::FlightObserver> ianav_sim::flight::FlightObserver for FrameSaver<'_, O> {
    fn sensor_event(&mut self, event: &ianav::sensors::SensorEvent) {
        let ianav::sensors::SensorEvent::Frame(frame) = event else {
            self.inner.sensor_event(event);
            return;
        };
        let k = self.count;
        self.count += 1;
        let Some(dir) = &self.dir else { return };
        if !k.is_multiple_of(self.every) || self.error.is_some() {
            return;
        }
        // Frame index (10 Hz from mission time 0) and sensor-clock time (µs since the start
        // of the warm-up, as in `sensors.bin` and `truth.csv`).
        let path = dir.join(format!("frame_{k:06}_t{}us.png", frame.t_us));
        if let Err(e) = image::save_buffer(
            &path,
            &frame.pixels,
            frame.width,
            frame.height,
            image::ExtendedColorType::L8,
        ) {
            self.error = Some(anyhow::Error::new(e).context(format!("writing {}", path.display())));
        }
    }
    fn truth_sample(&mut self, sample: &ianav_sim::flight::TruthSample) {
        self.inner.truth_sample(sample);
    }
    fn estimate_sample(
        &mut self,
        truth: &ianav_sim::flight::TruthSample,
        estimate: &ianav_sim::control::NavEstimate,
    ) {
        self.inner.estimate_sample(truth, estimate);
    }
    fn nav_solution(
        &mut self,
        truth: &ianav_sim::flight::TruthSample,
        solution: &ianav::nav::NavSolution,
    ) {
        self.inner.nav_solution(truth, solution);
    }
    fn operation_started(
        &mut self,
        t_s: f64,
        index: usize,
        operation: &ianav_sim::control::Operation,
    ) {
        self.inner.operation_started(t_s, index, operation);
    }
}

fn run(
    fly: &FlyArgs,
    out: &std::path::Path,
    no_sensor_log: bool,
    frames: Option<&PathBuf>,
    every: u64,
) -> Result<()> {
    let setup = setup(&fly.setup)?;
    let mut flight = Flight::new(&setup, fly.seed)?;
    let mut writer = RunWriter::new(out, !no_sensor_log)?;
    if let Some(nav) = flight.navigator() {
        writer.record_nav_config(nav.config())?;
    }
    if let Some(dir) = frames {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let end_s = flight.end_time_s();
    let bar = ProgressBar::new(end_s.ceil() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} s mission time (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("scenario {} seed {}", fly.setup.scenario, fly.seed));
    let started = Instant::now();
    let mut saver = FrameSaver {
        inner: &mut writer,
        dir: frames.cloned(),
        every,
        count: 0,
        error: None,
    };
    let summary = flight.run(&mut saver, |t_s| bar.set_position(t_s.max(0.0) as u64))?;
    if let Some(e) = saver.error.take() {
        return Err(e);
    }
    let n_frames = saver.count;
    bar.finish();
    if let (Some(cam), true) = (setup.camera.as_ref(), n_frames > 0) {
        let (h, a) = cam.terrain.cache_stats();
        let mb = |b: usize| b as f64 / 1e6;
        println!(
            "{n_frames} camera frames rendered, {:.1} ms each (wall, flight included); tile caches: \
             heights {} held ({} generated, {} evicted, peak {:.1} MB), albedo {} held ({} \
             generated, {} evicted, peak {:.1} MB); budget {:.1} MB",
            started.elapsed().as_secs_f64() * 1e3 / n_frames as f64,
            h.tiles,
            h.generated,
            h.evicted,
            mb(h.peak_bytes),
            a.tiles,
            a.generated,
            a.evicted,
            mb(a.peak_bytes),
            mb(cam.terrain.cache_budget_bytes())
        );
    }
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
    println!(
        "scenario {} seed {}: {:.0} s simulated ({} steps at 500 Hz, physics + environment + sensors + control)",
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

fn mc(args: &McArgs) -> Result<()> {
    let setup = setup(&args.setup)?;
    let seeds = montecarlo::seed_list(args.runs, args.seeds)?;
    let batch = Batch {
        scenario: args.setup.scenario,
        setup,
        seeds,
        shard: args.shard,
        jobs: args.jobs.map(|j| j as usize),
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

fn report(dirs: &[PathBuf], out: Option<&PathBuf>) -> Result<()> {
    let Some(out) = out.or(dirs.first()) else {
        bail!("give at least one directory");
    };
    let started = Instant::now();
    let summary = ianav_sim::report::report(dirs, out)?;
    println!(
        "{} runs ({} completed) in {:.2} s; report: {}",
        summary.runs,
        summary.completed,
        started.elapsed().as_secs_f64(),
        summary.report_path.display()
    );
    Ok(())
}

fn sitl(args: &SitlArgs) -> Result<()> {
    use ianav_sim::sitl::{self, Autopilot, FramesListen, SitlOptions, VehicleConfig};
    if !(args.speed.is_finite() && args.speed >= 0.0) {
        bail!("--speed must be a non-negative factor, got {}", args.speed);
    }
    if !(args.estimate_timeout.is_finite() && args.estimate_timeout > 0.0) {
        bail!(
            "--estimate-timeout must be a positive number of seconds, got {}",
            args.estimate_timeout
        );
    }
    let setup = setup(&args.fly.setup)?;
    let autopilot = match args.autopilot {
        AutopilotArg::Px4 => Autopilot::Px4,
        AutopilotArg::Ardupilot => Autopilot::ArduPilot,
        AutopilotArg::Ideal => Autopilot::Ideal,
    };
    let mut vehicle = VehicleConfig {
        system_id: args.system_id,
        fly_on_estimates: !args.no_external_position,
        estimate_timeout_us: (args.estimate_timeout * 1e6).round() as u64,
        ..VehicleConfig::for_autopilot(autopilot)
    }
    .with_latency_us(option_ms_to_us("--latency-ms", args.latency_ms)?);
    if let Some(on) = args.gyro_drift {
        vehicle.gyro_drift = on;
    }
    if let Some(t_s) = args.airspeed_unhealthy_from {
        let boot_s = setup.scenario.warmup_s + t_s;
        if !(boot_s.is_finite() && boot_s >= 0.0) {
            bail!("--airspeed-unhealthy-from must be a mission time in seconds, got {t_s}");
        }
        vehicle.airspeed_unhealthy_from_us = Some((boot_s * 1e6).round() as u64);
    }
    if let Some(ms) = args.gnss_lag_ms {
        vehicle.gnss_lag_us = option_ms_to_us("--gnss-lag-ms", ms)?;
    }
    for spec in &args.stream_latency {
        let Some((name, ms)) = spec.split_once('=') else {
            bail!("--stream-latency wants NAME=MS, got {spec:?}");
        };
        let Some(i) = sitl::streams::stream_index_by_name(name.trim()) else {
            bail!(
                "--stream-latency: unknown stream {name:?} (one of {})",
                sitl::streams::stream_names().join(", ")
            );
        };
        let ms: f64 = ms
            .trim()
            .parse()
            .map_err(|e| anyhow::anyhow!("--stream-latency {spec:?}: {e}"))?;
        vehicle.latency_us[i] = option_ms_to_us("--stream-latency", ms)?;
    }
    let options = SitlOptions {
        connect: args.connect.clone(),
        vehicle,
        speed: args.speed,
        frames: args.frames_listen.clone().map(FramesListen::Addr),
        out_dir: args.out.clone(),
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {wide_bar} {pos}/{len} s {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let pace = if args.speed == 0.0 {
        "as fast as possible".to_owned()
    } else {
        format!("at {}× real time", args.speed)
    };
    println!(
        "sitl: scenario {} seed {} as {:?} on {} {pace}",
        args.fly.setup.scenario, args.fly.seed, args.autopilot, args.connect
    );
    // Without a terminal the bar is hidden (and drops its log lines): print plain lines,
    // a status line every 10 s of mission time.
    let plain = bar.is_hidden();
    let mut next_status_s = 0.0;
    let summary = runtime.block_on(sitl::run(&setup, args.fly.seed, options, |p, notices| {
        bar.set_length(p.end_s.max(0.0).ceil() as u64);
        bar.set_position(p.t_s.max(0.0) as u64);
        for n in notices {
            if plain {
                println!("{n}");
            } else {
                bar.println(n);
            }
        }
        let err = p.hor_err_m.map_or_else(
            || "no estimate yet".to_owned(),
            |e| format!("hor err {e:.1} m"),
        );
        let lag = if p.lag_s > 0.5 {
            format!(", {:.1} s behind", p.lag_s)
        } else {
            String::new()
        };
        let status = format!(
            "t {:.0} s, {err}, {:.0} Hz, flying on {}{lag}",
            p.t_s,
            p.estimate_rate_hz,
            if p.aided { "daemon" } else { "own INS" }
        );
        if plain && p.t_s >= next_status_s {
            println!("{status}");
            next_status_s = (p.t_s / 10.0).floor() * 10.0 + 10.0;
        }
        bar.set_message(status);
    }))?;
    bar.finish();
    let v = &summary.vehicle;
    println!(
        "flew {:.0} s in {:.1} s wall (max lag {:.2} s); sent {} messages ({} dropped, {} errors), received {}; TIMESYNC: {} requests answered, {} answers to ours",
        summary.mission_s,
        summary.wall_s,
        summary.max_lag_s,
        summary.sent,
        summary.send_dropped,
        summary.send_errors,
        v.received,
        v.timesync_answered,
        v.timesync_pairs
    );
    println!(
        "daemon estimates: {} used, {} refused, mean rate {}; flew on the daemon's position {:.0} % of the time after GNSS loss",
        v.estimates,
        v.estimates_refused,
        summary
            .estimate_rate_hz
            .map_or_else(|| "-".to_owned(), |r| format!("{r:.1} Hz")),
        if v.ticks_after_loss > 0 {
            100.0 * v.aided_ticks as f64 / v.ticks_after_loss as f64
        } else {
            0.0
        }
    );
    if let Some(rms) = summary.hor_err_rms_after_loss_m {
        println!(
            "horizontal error after GNSS loss: RMS {rms:.1} m, last {:.1} m",
            summary.last_hor_err_m.unwrap_or(f64::NAN)
        );
    }
    if v.frames > 0 {
        println!(
            "camera frames: {} rendered, {} sent, {} dropped (slow client), {} without a client",
            v.frames, summary.frames_sent, summary.frames_dropped, summary.frames_without_client
        );
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
            frames,
            every,
        } => run(fly, out, *no_sensor_log, frames.as_ref(), *every),
        Command::Bench { fly } => bench(fly),
        Command::Mc(args) => mc(args),
        Command::Render(args) => render(args),
        Command::Sitl(args) => sitl(args),
        Command::Report { dirs, out } => report(dirs, out.as_ref()),
    }
}
