//! The daemon's camera path with a calibration (docs/CAMERA.md, docs/DAEMON.md "Camera
//! sources"): frames of the calibration's size reach the navigation thread; a frame of
//! another size is refused and counted, and the daemon goes on. Loopback only, every wait
//! bounded.

mod common;

use std::time::Duration;

use common::daemon_run::{start, stop};
use common::fake_autopilot::{self as fa, wait_for};
use ianav::daemon::config::DaemonConfig;

/// A small ROS `camera_info` calibration of an 8 × 6 px camera.
const CALIBRATION: &str = "image_width: 8\nimage_height: 6\ncamera_name: tiny\n\
camera_matrix:\n  rows: 3\n  cols: 3\n  data: [10.0, 0.0, 3.5, 0.0, 10.5, 2.5, 0.0, 0.0, 1.0]\n\
distortion_model: plumb_bob\n\
distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.05, 0.01, 0.0, 0.0, 0.0]\n";

fn pgm(width: u32, height: u32, value: u8) -> Vec<u8> {
    let mut b = format!("P5\n{width} {height}\n255\n").into_bytes();
    b.extend(std::iter::repeat_n(value, (width * height) as usize));
    b
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_of_another_size_than_the_calibration_are_refused_and_counted() {
    let dir = std::env::temp_dir().join(format!("ianav-cal-frames-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    std::fs::write(dir.join("cam.yaml"), CALIBRATION).unwrap();
    // Stems are exposure times in µs; the second frame is rotated (6 × 8).
    for (name, image) in [
        ("000000000.pgm", pgm(8, 6, 10)),
        ("000050000.pgm", pgm(6, 8, 20)),
        ("000100000.pgm", pgm(8, 6, 30)),
    ] {
        std::fs::write(frames.join(name), image).unwrap();
    }
    let port = fa::free_udp_port();
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nlink_timeout_s = 1.0\n\
         [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         [navigation]\nmag_decimal_year = 2026.5\n\
         [logging]\ncounters_period_s = 0.0\n\
         [camera]\nsource = \"directory\"\npath = \"{}\"\ncalibration_file = \"cam.yaml\"\n\
         euler_bc_deg = [90.0, 0.0, 0.0]\n",
        frames.display()
    );
    let cfg = DaemonConfig::from_toml_str(&text, Some(&dir)).unwrap();
    assert_eq!(cfg.camera.intrinsics.unwrap().width_px, 8);
    let (h, task) = start(cfg).await;
    let done = wait_for(Duration::from_secs(5), || {
        let c = h.shared.counters();
        c.frames_received + c.frames_refused >= 3
    })
    .await;
    assert!(done, "{:?}", h.shared.counters());
    // Still running: stopping it returns its counters.
    let c = stop(h, task).await;
    assert_eq!((c.frames_received, c.frames_refused), (2, 1), "{c:?}");
    assert_eq!(c.camera_errors, 0);
    std::fs::remove_dir_all(&dir).unwrap();
}
