//! Live-camera sources through OpenCV (feature `opencv`, docs/DAEMON.md "Camera sources"): a
//! GStreamer test pipeline delivers grey frames to the navigation thread, and an absent V4L2
//! device is retried and counted without stopping the daemon. Needs the system OpenCV and GStreamer's
//! base plugins (`.ci/run` installs them); loopback only, every wait bounded.
#![cfg(feature = "opencv")]
#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

mod common;

use std::time::Duration;

use common::daemon_run::{start, stop};
use common::fake_autopilot::{self as fa, wait_for};
use ianav::daemon::Counters;
use ianav::daemon::config::DaemonConfig;

fn config(port: u16, camera: &str) -> DaemonConfig {
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nlink_timeout_s = 1.0\n\
         [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         [navigation]\nmag_decimal_year = 2026.5\n\
         [logging]\ncounters_period_s = 0.0\n[camera]\nretry_max_s = 0.2\n{camera}"
    );
    DaemonConfig::from_toml_str(&text, None).unwrap()
}

async fn run_for(cfg: DaemonConfig, until: impl Fn(&Counters) -> bool) -> (bool, Counters) {
    let (h, task) = start(cfg).await;
    let reached = wait_for(Duration::from_secs(10), || until(&h.shared.counters())).await;
    (reached, stop(h, task).await)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gstreamer_pipeline_delivers_grey_frames() {
    // 25 frames of 160 × 120 BGR; at the end of the stream the source reopens the pipeline.
    let pipeline = "videotestsrc num-buffers=25 pattern=ball ! \
                    video/x-raw,width=160,height=120,framerate=50/1 ! videoconvert ! \
                    video/x-raw,format=BGR ! appsink";
    let cfg = config(
        fa::free_udp_port(),
        &format!("source = \"gstreamer\"\npipeline = \"{pipeline}\"\n"),
    );
    let (reached, c) = run_for(cfg, |c| c.frames_received >= 20).await;
    assert!(reached, "frames: {c:?}");
    assert!(c.camera_connects >= 1, "{c:?}");
    // Every frame reached the navigator, was dropped oldest-first, or still waits in the
    // queue (4 frames by default) when the counters were read.
    let accounted = c.nav.frames + c.frames_dropped;
    assert!(
        accounted <= c.frames_received && accounted + 4 >= c.frames_received,
        "{c:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_absent_v4l2_device_is_retried_and_counted() {
    let cfg = config(
        fa::free_udp_port(),
        "source = \"v4l2\"\ndevice = \"/dev/video-ianav-absent\"\n",
    );
    let (reached, c) = run_for(cfg, |c| c.camera_errors >= 3).await;
    assert!(reached, "{c:?}");
    assert_eq!((c.frames_received, c.camera_connects), (0, 0), "{c:?}");
}
