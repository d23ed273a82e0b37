//! End to end with the camera (docs/FUSION.md, docs/SITL.md "Camera frames"): the SITL
//! vehicle renders its down-looking camera over MX (the authors' 768 × 1024: at half of it
//! MX's fields give too few corners to start) and streams the frames; the `ianav` daemon (in-process) navigates on them with the IA-VNS,
//! publishes the fused position, and after the GNSS loss the vehicle flies on it. A shortened
//! scenario #2 (GNSS lost at 20 s, 60 s of mission) at 2× real time over loopback TCP.
#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

use std::time::Duration;

use ianav::daemon::config::DaemonConfig;
use ianav::nav::fusion::FusionConfig;
use ianav_sim::flight::FlightSetup;
use ianav_sim::montecarlo::RunOutcome;
use ianav_sim::sitl::SitlSummary;
use ianav_sim::terrain::Zone;
use tokio::net::TcpListener;

mod common;

/// Mission flown after the 50 s warm-up, s, and the GNSS loss in it, s.
const MISSION_S: f64 = 60.0;
const LOSS_S: f64 = 20.0;
/// Simulated seconds per wall second.
const SPEED: f64 = 2.0;

fn setup() -> FlightSetup {
    common::mx_camera_setup(MISSION_S, LOSS_S)
}

/// The camera mounting the simulator's own navigator is given for `seed` (the true mounting
/// with the flight's calibration error, docs/CAMERA.md): what a user's calibration would put in
/// the daemon's `[camera]`, as `euler_bc_deg` and `lens_from_reference_b_m` lines.
fn calibrated_mounting_toml(setup: &FlightSetup, seed: u64) -> String {
    let flight = ianav_sim::flight::Flight::new(setup, seed).unwrap();
    let m = flight
        .navigator()
        .unwrap()
        .config()
        .camera
        .as_ref()
        .unwrap()
        .mounting;
    let e = ianav::math::so3::euler_zyx(&m.q_bc);
    format!(
        "euler_bc_deg = [{}, {}, {}]\nlens_from_reference_b_m = [{}, {}, {}]\n",
        e.x.to_degrees(),
        e.y.to_degrees(),
        e.z.to_degrees(),
        m.t_rc_b_m.x,
        m.t_rc_b_m.y,
        m.t_rc_b_m.z,
    )
}

/// The daemon's configuration: with `frames`, the vehicle's camera, its mounting as calibrated
/// for `seed`'s airframe and the ground's height at the start (the daemon's flat terrain) and
/// the vision's default settings (the paper's IA-VNS); without, the INS alone.
fn daemon_toml(setup: &FlightSetup, seed: u64, vehicle: &str, frames: Option<&str>) -> String {
    // The vehicle's ATTITUDE is its own INS: white errors, nothing slow to estimate (as in
    // sim/tests/e2e_daemon_sitl).
    let mut ins = ianav::ins::InsConfig::default();
    ins.alignment.ref_error_sigma_deg = [0.0; 3];
    let alignment = toml::to_string(&ins.alignment).unwrap();
    let camera = frames.map_or_else(String::new, |frames| {
        let camera_setup = setup.camera.as_ref().unwrap();
        let cam = &camera_setup.camera;
        format!(
            "[camera]\nsource = \"frame_stream\"\naddress = \"{frames}\"\n\
             width_px = {}\nheight_px = {}\nfocal_length_mm = {}\npixel_pitch_um = {}\n\
             terrain_height_m = {}\n{}",
            cam.width_px,
            cam.height_px,
            cam.focal_length_mm,
            cam.pixel_pitch_um,
            camera_setup.terrain.zone().start().ground_m,
            calibrated_mounting_toml(setup, seed),
        )
    });
    format!(
        "[mavlink]\nconnection = \"tcpout:{vehicle}\"\nclock = \"autopilot\"\n\
         link_timeout_s = 3.0\n\
         [input]\nimu_rate_hz = 100.0\nair_rate_hz = 100.0\naoa_ssa = \"vanes\"\n\
         [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         {camera}\
         [navigation]\nmag_decimal_year = {}\n\
         [logging]\ncounters_period_s = 0.0\n\
         [ins.alignment]\n{alignment}",
        setup.scenario.magnetic_decimal_year,
    )
}

/// What a flight of the daemon beside the camera vehicle left.
struct Flown {
    summary: SitlSummary,
    counters: ianav::daemon::Counters,
    /// Everything the daemon sent.
    bytes: Vec<u8>,
    /// (mission time the estimate is valid at, s; its horizontal error, m), in arrival order.
    errors: Vec<(f64, f64)>,
}

/// The daemon (with the camera when `camera`) beside the vehicle flying `setup` with `seed` at
/// `speed`, after the loss on the daemon's estimates when `fly_on_estimates` (else on its own
/// INS: the offline flight of the same seed); the daemon's recording replayed against what it
/// published.
async fn fly(
    setup: &FlightSetup,
    seed: u64,
    speed: f64,
    camera: bool,
    fly_on_estimates: bool,
) -> Flown {
    let daemon_side = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let vehicle_side = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let frames = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let frames_addr = frames.local_addr().unwrap().to_string();
    let dir = std::env::temp_dir().join(format!(
        "ianav_e2e_camera_{}_{seed}_{camera}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let daemon_addr = daemon_side.local_addr().unwrap().to_string();
    let toml = daemon_toml(
        setup,
        seed,
        &daemon_addr,
        camera.then_some(frames_addr.as_str()),
    );
    let cfg = DaemonConfig::from_toml_str(&toml, None).unwrap();
    let recording = dir.join("daemon.bin");
    let (handle, daemon_task, to_daemon) =
        common::start_recording_daemon(cfg, &recording, &daemon_side).await;
    let mut options = common::camera_vehicle(
        vehicle_side.local_addr().unwrap(),
        frames,
        speed,
        Some(dir.clone()),
    );
    options.vehicle.fly_on_estimates = fly_on_estimates;
    let mut setup = setup.clone();
    if !camera {
        options.frames = None;
        setup.camera = None;
    }
    let mut sitl_task = common::spawn_sitl(&setup, seed, options);
    let to_vehicle = tokio::select! {
        s = common::accept(&vehicle_side, "the SITL vehicle") => s,
        r = &mut sitl_task => panic!("SITL ended before connecting: {r:?}"),
    };
    let relay = common::Relay::start(to_vehicle, to_daemon);
    let budget = Duration::from_secs_f64(
        (setup.scenario.warmup_s + setup.scenario.duration_s) / speed * 3.0,
    );
    let summary = tokio::time::timeout(budget, sitl_task)
        .await
        .unwrap_or_else(|_| panic!("the SITL run did not end within {budget:?}"))
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    common::stop_daemon(&handle, daemon_task).await;
    // Read after the stop: the daemon may still record an event while it winds down.
    let counters = handle.shared.counters();
    let bytes = relay.finish().await;

    let csv = std::fs::read_to_string(dir.join("sitl.csv")).unwrap();
    // The recording, frames and vision markers included, replays to the solutions the
    // daemon handed its publisher, bit for bit (docs/REPLAY.md).
    let replay = common::assert_replay_gives_the_daemons_solutions(&recording, &counters);
    assert_eq!(
        replay.nav.fused_vision_fixes,
        counters.nav.fused_vision_fixes
    );
    // IANAV_E2E_KEEP: keep the recording and sitl.csv for a look (the path is printed).
    if std::env::var_os("IANAV_E2E_KEEP").is_some() {
        eprintln!("kept {}", dir.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (c_t, c_err) = (col("t_valid_s"), col("hor_err_m"));
    let errors = lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .map(|f| (f[c_t].parse().unwrap(), f[c_err].parse().unwrap()))
        .collect();
    Flown {
        summary,
        counters,
        bytes,
        errors,
    }
}

/// The horizontal error of the published position after the loss stays within three times
/// the fused model's DRMS (σ₀ and the scale term over the distance flown since the start,
/// at most 110 s × 35 m/s; the INS's own growth between fixes is centimetres), and the vehicle
/// flies on it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_navigates_on_the_rendered_frames_and_the_vehicle_flies_on_its_position() {
    let setup = setup();
    let Flown {
        summary,
        counters,
        bytes,
        errors,
    } = fly(&setup, 1, SPEED, true, true).await;
    let after_loss: Vec<f64> = errors
        .iter()
        .filter(|(t, _)| *t > LOSS_S + 2.0)
        .map(|(_, e)| *e)
        .collect();
    let worst_m = after_loss.iter().copied().fold(0.0, f64::max);
    let fusion = FusionConfig::default();
    let d_max_m = (setup.scenario.warmup_s + MISSION_S) * 35.0;
    let drms_m = (2.0 * fusion.vision_variance_m2(d_max_m)).sqrt();
    eprintln!(
        "frames sent {} dropped {}, fixes fused {}, source changes {}, aided ticks {} of {}, \
         worst horizontal error after the loss {worst_m:.1} m (3 DRMS {:.1} m)",
        summary.frames_sent,
        summary.frames_dropped,
        counters.nav.fused_vision_fixes,
        counters.nav.horizontal_source_changes,
        summary.vehicle.aided_ticks,
        summary.vehicle.ticks_after_loss,
        3.0 * drms_m
    );
    assert!(counters.frames_received > 100, "{counters:?}");
    assert_eq!(counters.vision_failures, 0);
    assert!(counters.nav.fused_vision_fixes > 100, "{:?}", counters.nav);
    assert!(counters.nav.horizontal_source_changes >= 1);
    let said = |text: &str| bytes.windows(text.len()).any(|w| w == text.as_bytes());
    assert!(said("ianav: horizontal position from vision"));
    assert!(
        after_loss.len() > 100,
        "{} estimates after the loss",
        after_loss.len()
    );
    assert!(worst_m < 3.0 * drms_m, "{worst_m} m");
    // The vehicle flew on the daemon's position for most of the denied flight.
    assert!(
        summary.vehicle.aided_ticks * 10 > summary.vehicle.ticks_after_loss * 9,
        "{:?}",
        summary.vehicle
    );
}

/// The offline flight of `seed` over `zone` (docs/results/vision-mc-s2-ZONE, the simulator's
/// own inline INS and IA-VNS on every frame): distance flown by the mission end, and the INS's
/// and the IA-VNS's horizontal errors there, m.
fn offline_scenario_2(zone: Zone, seed: u64) -> (f64, f64, f64) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../docs/results/vision-mc-s2-{}/runs", zone.code()))
        .join(ianav_sim::montecarlo::run_file_name(seed));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let record = ianav_sim::montecarlo::RunRecord::parse(&text).unwrap();
    let RunOutcome::Completed {
        distance_m,
        samples,
        vision,
    } = record.outcome
    else {
        panic!("seed {seed}: the offline run did not complete")
    };
    let ia_vns = vision.iter().find(|v| v.system == "ia-vns").unwrap();
    (
        distance_m,
        samples.last().unwrap().hor_m,
        ia_vns.samples.last().unwrap().hor_m,
    )
}

/// The whole scenario #2 over MX (GNSS lost at 100 s, 400 s denied), seeds 1–3 or
/// `IANAV_E2E_SEEDS` (comma-separated), over another zone with `IANAV_E2E_ZONE` (its offline
/// batch must be committed), at `IANAV_E2E_SPEED` (default 2× real time; the daemon without a
/// camera at 10×). The vehicle flies on its own INS, as the offline flight does, so that all
/// three see the same flight and the same images; with `IANAV_E2E_FLY_ON_ESTIMATES=1` it flies
/// on the daemon's position after the loss (another flight from there on). The
/// daemon with the camera against the offline IA-VNS of the same seed, and against the daemon
/// without a camera (its INS alone) on the same seed. Tolerance: the two IA-VNS runs see the
/// same ground but start from their own INS and use different frames (the daemon drops the
/// ones that come while its vision is busy), so their errors are treated as independent draws
/// of the fused model's visual error (per axis σ(d)² = σ₀² + (k d)², d = the distance flown
/// since the start of the flight, warm-up included at 35 m/s): the difference of the two
/// positions is within 2.45 √2 σ(d) 95 % of the time, and so is the difference of their
/// errors' magnitudes. docs/E2E.md "With the camera, the whole scenario #2".
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "measurement, ≈ 5 min per seed at 2× real time"]
async fn scenario_2_the_daemons_ia_vns_matches_the_offline_one_and_beats_its_ins() {
    let seeds: Vec<u64> = std::env::var("IANAV_E2E_SEEDS")
        .map(|s| s.split(',').map(|x| x.trim().parse().unwrap()).collect())
        .unwrap_or_else(|_| vec![1, 2, 3]);
    let speed: f64 = std::env::var("IANAV_E2E_SPEED").map_or(2.0, |s| s.parse().unwrap());
    let fly_on_estimates = std::env::var_os("IANAV_E2E_FLY_ON_ESTIMATES").is_some();
    let zone: Zone = std::env::var("IANAV_E2E_ZONE").map_or(Zone::Mix, |z| z.parse().unwrap());
    let full = FlightSetup::builtin(2).unwrap();
    let setup = common::camera_setup(zone, full.scenario.duration_s, full.scenario.gnss_loss_s);
    let end_s = setup.scenario.duration_s;
    let at_end = |errors: &[(f64, f64)]| {
        errors
            .iter()
            .filter(|(t, _)| *t <= end_s)
            .min_by(|a, b| (end_s - a.0).total_cmp(&(end_s - b.0)))
            .map(|&(t, e)| {
                assert!(end_s - t < 1.0, "last estimate at {t} s");
                e
            })
            .unwrap()
    };
    let fusion = FusionConfig::default();
    let mut failures = Vec::new();
    for seed in seeds {
        let (distance_m, offline_ins_m, offline_ia_vns_m) = offline_scenario_2(zone, seed);
        let camera = fly(&setup, seed, speed, true, fly_on_estimates).await;
        let ins_only = fly(&setup, seed, speed.max(10.0), false, fly_on_estimates).await;
        let every_100_s = |errors: &[(f64, f64)]| -> String {
            (1..=5)
                .filter_map(|k| {
                    let t = 100.0 * f64::from(k);
                    errors
                        .iter()
                        .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
                        .map(|e| format!("{:.1}", e.1))
                })
                .collect::<Vec<_>>()
                .join(" / ")
        };
        eprintln!(
            "{zone} seed {seed}: at 100 / 200 / 300 / 400 / 500 s daemon with camera {} m, \
             INS alone {} m",
            every_100_s(&camera.errors),
            every_100_s(&ins_only.errors)
        );
        let daemon_m = at_end(&camera.errors);
        let daemon_ins_m = at_end(&ins_only.errors);
        let d_m = distance_m + setup.scenario.warmup_s * 35.0;
        let tolerance_m = 2.45 * std::f64::consts::SQRT_2 * fusion.vision_variance_m2(d_m).sqrt();
        eprintln!(
            "{zone} seed {seed} (vehicle on the daemon: {fly_on_estimates}): at {end_s} s daemon with camera {daemon_m:.1} m, offline IA-VNS \
             {offline_ia_vns_m:.1} m (tolerance {tolerance_m:.1} m), daemon INS alone \
             {daemon_ins_m:.1} m (offline INS {offline_ins_m:.1} m); frames sent {} dropped {}, \
             received {}, fused fixes {}, source changes {}, vision restarts {}, aided ticks {} \
             of {}, wall {:.0} s",
            camera.summary.frames_sent,
            camera.summary.frames_dropped,
            camera.counters.frames_received,
            camera.counters.nav.fused_vision_fixes,
            camera.counters.nav.horizontal_source_changes,
            camera.counters.nav.vision_restarts,
            camera.summary.vehicle.aided_ticks,
            camera.summary.vehicle.ticks_after_loss,
            camera.summary.wall_s + ins_only.summary.wall_s,
        );
        if (daemon_m - offline_ia_vns_m).abs() > tolerance_m {
            failures.push(format!(
                "seed {seed}: {daemon_m:.1} m against offline {offline_ia_vns_m:.1} m"
            ));
        }
        if daemon_m * 5.0 > daemon_ins_m {
            failures.push(format!(
                "seed {seed}: {daemon_m:.1} m against INS alone {daemon_ins_m:.1} m"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
