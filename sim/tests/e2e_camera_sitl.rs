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
use ianav::daemon::{self};
use ianav::nav::fusion::FusionConfig;
use ianav_sim::flight::FlightSetup;
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

/// The daemon's configuration: the vehicle's camera and the ground's height at the start
/// (the daemon's flat terrain); the vision's default settings (the paper's IA-VNS).
fn daemon_toml(setup: &FlightSetup, vehicle: &str, frames: &str) -> String {
    let cam = &setup.camera.as_ref().unwrap().camera;
    let ground_m = Zone::Mix.start().ground_m;
    // The vehicle's ATTITUDE is its own INS: white errors, nothing slow to estimate (as in
    // e2e_daemon_sitl.rs).
    let mut ins = ianav::ins::InsConfig::default();
    ins.alignment.ref_error_sigma_deg = [0.0; 3];
    let alignment = toml::to_string(&ins.alignment).unwrap();
    format!(
        "[mavlink]\nconnection = \"tcpout:{vehicle}\"\nclock = \"autopilot\"\n\
         link_timeout_s = 3.0\n\
         [input]\nimu_rate_hz = 100.0\nair_rate_hz = 100.0\naoa_ssa = \"vanes\"\n\
         [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         [camera]\nsource = \"frame_stream\"\naddress = \"{frames}\"\n\
         width_px = {}\nheight_px = {}\nfocal_length_mm = {}\npixel_pitch_um = {}\n\
         terrain_height_m = {ground_m}\n\
         [navigation]\nmag_decimal_year = {}\n\
         [logging]\ncounters_period_s = 0.0\n\
         [ins.alignment]\n{alignment}",
        cam.width_px,
        cam.height_px,
        cam.focal_length_mm,
        cam.pixel_pitch_um,
        setup.scenario.magnetic_decimal_year,
    )
}

/// The horizontal error of the published position after the loss stays within three times
/// the fused model's DRMS (σ₀ and the scale term over the distance flown since the start,
/// at most 110 s × 35 m/s; the INS's own growth between fixes is centimetres), and the vehicle
/// flies on it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_navigates_on_the_rendered_frames_and_the_vehicle_flies_on_its_position() {
    let setup = setup();
    let daemon_side = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let vehicle_side = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let frames = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let frames_addr = frames.local_addr().unwrap().to_string();
    let dir = std::env::temp_dir().join(format!("ianav_e2e_camera_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut cfg = DaemonConfig::from_toml_str(
        &daemon_toml(
            &setup,
            &daemon_side.local_addr().unwrap().to_string(),
            &frames_addr,
        ),
        None,
    )
    .unwrap();
    let recording = dir.join("daemon.bin");
    cfg.record = Some(recording.clone());
    let (htx, hrx) = tokio::sync::oneshot::channel();
    let daemon_task = tokio::spawn(daemon::run(cfg, Some(htx)));
    let handle = hrx.await.unwrap();
    let to_daemon = common::accept(&daemon_side, "the daemon").await;
    let options = common::camera_vehicle(
        vehicle_side.local_addr().unwrap(),
        frames,
        SPEED,
        Some(dir.clone()),
    );
    let mut sitl_task = common::spawn_sitl(&setup, 1, options);
    let to_vehicle = tokio::select! {
        s = common::accept(&vehicle_side, "the SITL vehicle") => s,
        r = &mut sitl_task => panic!("SITL ended before connecting: {r:?}"),
    };
    let relay = common::Relay::start(to_vehicle, to_daemon);
    let budget = Duration::from_secs_f64((setup.scenario.warmup_s + MISSION_S) / SPEED * 3.0);
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
    let _ = std::fs::remove_dir_all(&dir);
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (c_t, c_err) = (col("t_rx_s"), col("hor_err_m"));
    let after_loss: Vec<f64> = lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|f| f[c_t].parse::<f64>().unwrap() > LOSS_S + 2.0)
        .map(|f| f[c_err].parse().unwrap())
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
