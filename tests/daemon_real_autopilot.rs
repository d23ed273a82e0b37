//! The daemon against a fake autopilot that behaves as the real ones did beside it
//! (docs/ARDUPILOT.md "What went wrong before"): an interval request DENIED as too fast, an
//! IMU stream left at its 1 Hz default, and the daemon's own GPS_INPUT reported back as the
//! autopilot's GNSS. Loopback UDP only; every wait is bounded.

#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

mod common;

use std::time::{Duration, Instant};

use common::daemon_run::{start, stop};
use common::fake_autopilot::{self as fa, Fake, wait_for};
use ianav::daemon::config::DaemonConfig;
use mavlink::dialects::ardupilotmega as apm;

fn config(port: u16, extra: &str) -> DaemonConfig {
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nlink_timeout_s = 1.0\n\
         {extra}\n[navigation]\nmag_decimal_year = 2026.5\n\
         [logging]\ncounters_period_s = 0.0\n"
    );
    DaemonConfig::from_toml_str(&text, None).unwrap()
}

fn published_since(fake: &Fake, t: Instant) -> usize {
    fake.received(|r| {
        r.at > t
            && matches!(
                r.msg,
                apm::MavMessage::ODOMETRY(_) | apm::MavMessage::GPS_INPUT(_)
            )
    })
    .len()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_denied_imu_interval_is_retried_at_the_fastest_allowed_rate() {
    let port = fa::free_udp_port();
    let (h, task) = start(config(
        port,
        "[input]\nimu_rate_hz = 100.0\n[output]\nmode = \"odometry\"\nrate_hz = 10.0",
    ))
    .await;
    let fake = Fake::start(port).await;
    // ArduPlane at its 50 Hz loop: intervals under 25 ms are DENIED.
    fake.ctl.lock().unwrap().min_interval_us = 25_000.0;
    let imu_id = <apm::HIGHRES_IMU_DATA as mavlink::MessageData>::ID;
    assert!(
        wait_for(Duration::from_secs(10), || fake
            .ctl
            .lock()
            .unwrap()
            .interval_requests
            .iter()
            .any(|(id, us, ok)| *id == imu_id
                && *ok
                && (*us - 25_000.0).abs() < 1.0))
        .await,
        "IMU interval stepped down to 25 ms: {:?}",
        fake.ctl.lock().unwrap().interval_requests
    );
    let requests: Vec<(u32, f32, bool)> = fake
        .ctl
        .lock()
        .unwrap()
        .interval_requests
        .iter()
        .copied()
        .filter(|r| r.0 == imu_id)
        .collect();
    // 100 Hz and 50 Hz refused, then 40 Hz accepted; nothing after it.
    let intervals: Vec<f32> = requests.iter().map(|r| r.1).collect();
    assert_eq!(
        intervals,
        vec![10_000.0, 20_000.0, 25_000.0],
        "{requests:?}"
    );
    assert!(
        wait_for(Duration::from_secs(2), || h
            .shared
            .state(|s| s.granted_intervals.contains(&(imu_id, 40.0))))
        .await
    );
    let texts = fake.statustexts();
    assert!(
        texts.iter().filter(|t| t.contains("refused")).count() >= 2,
        "{texts:?}"
    );
    let c = stop(h, task).await;
    assert_eq!(c.interval_refused, 2, "{c:?}");
}

/// ArduPilot's default RAW_IMU stream is one sample a second until the requested interval is
/// granted: the INS does not start on it; once it runs, a stream that falls to 1 Hz is
/// withheld, said, and publication resumes when the rate is back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_one_hertz_imu_stream_is_never_published_and_publication_resumes_at_100_hz() {
    let port = fa::free_udp_port();
    let (h, task) = start(config(
        port,
        "[output]\nmode = \"odometry\"\nrate_hz = 10.0",
    ))
    .await;
    let fake = Fake::start(port).await;
    fake.ctl.lock().unwrap().imu_period_us = 1_000_000;
    // Fixes and attitudes arrive (5 Hz, 50 Hz): only the IMU rate holds the start back.
    tokio::time::sleep(Duration::from_secs(3)).await;
    let c = h.shared.counters();
    assert!(c.input.gnss >= 5, "{c:?}");
    assert_eq!(c.nav.initialisations, 0, "INS started on a 1 Hz IMU: {c:?}");
    assert_eq!(c.published, 0, "published on a 1 Hz IMU");
    // 100 Hz: the INS starts and publishes.
    fake.ctl.lock().unwrap().imu_period_us = 0;
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(6), || published_since(&fake, t) > 10).await,
        "{:?}",
        h.shared.counters()
    );
    // Down to 1 Hz in flight: withheld within the 2 s window, and said.
    fake.ctl.lock().unwrap().imu_period_us = 1_000_000;
    assert!(
        wait_for(Duration::from_secs(8), || h
            .shared
            .counters()
            .publish_withheld
            >= 3)
        .await,
        "{:?}",
        h.shared.counters()
    );
    let t = Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(published_since(&fake, t), 0, "published on a 1 Hz IMU");
    assert!(
        fake.statustexts()
            .iter()
            .any(|t| t.contains("not publishing")),
        "{:?}",
        fake.statustexts()
    );
    // Back to 100 Hz: publication resumes after the recovery time (5 s) once the 2 s window
    // is fast again — or, when the 1 Hz INS also refused the GNSS fixes (the disagreement
    // check), once GNSS has re-initialised it (5 s of fixes) and 5 s more have passed.
    fake.ctl.lock().unwrap().imu_period_us = 0;
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(16), || published_since(&fake, t) > 10).await,
        "{:?} {:?}",
        h.shared.counters(),
        fake.statustexts()
    );
    assert!(
        fake.statustexts()
            .iter()
            .any(|t| t.contains("publishing again"))
    );
    let c = stop(h, task).await;
    assert_eq!(c.publish_withheld_episodes, 1, "{c:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn our_own_gps_input_reported_back_as_gnss_is_refused() {
    let port = fa::free_udp_port();
    let (h, task) = start(config(
        port,
        "[output]\nmode = \"gps_input\"\nrate_hz = 5.0\ngps_id = 1",
    ))
    .await;
    let fake = Fake::start(port).await;
    assert!(
        wait_for(Duration::from_secs(6), || fake
            .ctl
            .lock()
            .unwrap()
            .last_gps_input
            .is_some())
        .await,
        "GPS_INPUT published"
    );
    fake.ctl.lock().unwrap().echo_gps_input = true;
    assert!(
        wait_for(Duration::from_secs(4), || h.shared.counters().gnss_echo
            >= 5)
        .await,
        "{:?}",
        h.shared.counters()
    );
    assert!(
        fake.statustexts()
            .iter()
            .any(|t| t.contains("our GPS_INPUT")),
        "{:?}",
        fake.statustexts()
    );
    // While the echo lasts, no fix reaches the navigation.
    let last_fix = h.shared.state(|s| s.last_fix_us);
    tokio::time::sleep(Duration::from_millis(1000)).await;
    assert_eq!(h.shared.state(|s| s.last_fix_us), last_fix);
    // The real fix again: accepted as before.
    fake.ctl.lock().unwrap().echo_gps_input = false;
    assert!(
        wait_for(Duration::from_secs(2), || h.shared.state(|s| s.last_fix_us)
            != last_fix)
        .await
    );
    let c = stop(h, task).await;
    assert!(c.gnss_echo >= 5, "{c:?}");
}
