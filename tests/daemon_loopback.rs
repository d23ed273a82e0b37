//! The daemon against a fake PX4-like autopilot on loopback UDP (the daemon's acceptance: rates,
//! nothing before initialisation, TIMESYNC, interval requests, heartbeats; robustness: garbage,
//! truncated and bad-CRC frames, MAVLink 1, unknown ids, a 10× IMU flood, an autopilot reboot, link
//! loss and return, a frame stream absent at start, stalling and resuming). Every wait is bounded;
//! the daemon runs in-process so its counters can be read.

#![expect(
    clippy::unwrap_used,
    reason = "helpers outside #[test] functions: a failed loopback setup should fail the test loudly"
)]

mod common;

use std::time::{Duration, Instant};

use common::daemon_run::{start, stop};
use common::fake_autopilot::{self as fa, Fake, Rx, wait_for};
use ianav::daemon::config::DaemonConfig;
use mavlink::MavlinkVersion;
use mavlink::dialects::ardupilotmega as apm;

fn config(port: u16, extra: &str) -> DaemonConfig {
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nlink_timeout_s = 1.0\n\
         timesync_rate_hz = 10.0\n\
         [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         [navigation]\nmag_decimal_year = 2026.5\n\
         [logging]\ncounters_period_s = 0.0\n{extra}"
    );
    DaemonConfig::from_toml_str(&text, None).unwrap()
}

fn is_odometry(r: &Rx) -> bool {
    matches!(r.msg, apm::MavMessage::ODOMETRY(_))
}

fn rss_kb() -> u64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[expect(
    deprecated,
    reason = "SET_GPS_GLOBAL_ORIGIN, deprecated but what the daemon sends (src/io/mavlink_out.rs)"
)]
async fn initialises_publishes_at_rate_answers_timesync_and_requests_intervals() {
    let port = fa::free_udp_port();
    let (h, task) = start(config(port, "")).await;
    // The fake starts with GNSS off: no fix, so no initialisation and nothing published.
    let fake = Fake::start(port).await;
    fake.ctl.lock().unwrap().gnss_off = true;
    let got_hb = wait_for(Duration::from_secs(5), || {
        !fake
            .received(|r| matches!(r.msg, apm::MavMessage::HEARTBEAT(_)))
            .is_empty()
    })
    .await;
    assert!(got_hb, "daemon HEARTBEAT");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(
        fake.received(is_odometry).is_empty(),
        "published before the INS initialised"
    );
    assert_eq!(h.shared.counters().solutions, 0);
    let gnss_on_at = Instant::now();
    fake.ctl.lock().unwrap().gnss_off = false;
    assert!(
        wait_for(Duration::from_secs(5), || !fake
            .received(is_odometry)
            .is_empty())
        .await,
        "ODOMETRY after the first fix"
    );
    let first = fake.received(is_odometry)[0].at;
    assert!(first > gnss_on_at, "nothing before the first GNSS fix");
    // Rate over 3 s: 30 Hz ± 10 %.
    let t0 = Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let t1 = Instant::now();
    let n = fake
        .received(|r| is_odometry(r) && r.at >= t0 && r.at < t1)
        .len();
    let rate = n as f64 / (t1 - t0).as_secs_f64();
    assert!((27.0..=33.0).contains(&rate), "ODOMETRY at {rate:.1} Hz");
    let lat = h.shared.latency_percentiles().expect("latencies measured");
    eprintln!(
        "IMU received → ODOMETRY written latency (µs): p50 {} p99 {} max {}",
        lat.0, lat.1, lat.2
    );
    let c = stop(h, task).await;
    // One latency per published ODOMETRY (those not sent before the peer was known aside).
    assert!(c.latency_samples + 5 >= c.published, "{c:?}");

    // HEARTBEAT: onboard controller, component 197, system id adopted from the autopilot.
    let hb = fake.received(|r| matches!(r.msg, apm::MavMessage::HEARTBEAT(_)));
    assert!(hb.len() >= 4, "1 Hz heartbeats: {}", hb.len());
    let apm::MavMessage::HEARTBEAT(d) = &hb[0].msg else {
        unreachable!()
    };
    assert_eq!(d.mavtype, apm::MavType::MAV_TYPE_ONBOARD_CONTROLLER);
    assert_eq!(
        (
            hb[0].header.component_id,
            hb.last().unwrap().header.system_id
        ),
        (197, 1)
    );
    // Interval requests for the PX4 stream set, HIGHRES_IMU at 100 Hz.
    let cmds = fake.received(|r| {
        matches!(&r.msg, apm::MavMessage::COMMAND_LONG(c)
        if c.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL)
    });
    let imu_req = cmds.iter().any(|r| {
        matches!(&r.msg, apm::MavMessage::COMMAND_LONG(c)
        if c.param1 == 105.0 && c.param2 == 10_000.0 && c.target_system == 1)
    });
    assert!(imu_req, "HIGHRES_IMU interval requested: {cmds:?}");
    // TIMESYNC: our requests were answered by the fake, so the daemon has offset samples.
    assert!(c.timesync.samples >= 10, "{:?}", c.timesync);
    // Origin and ODOMETRY content: local NED, VIO, moving north at 30 m/s.
    assert!(
        !fake
            .received(|r| matches!(r.msg, apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(_)))
            .is_empty()
    );
    let odo: Vec<apm::ODOMETRY_DATA> = fake
        .received(is_odometry)
        .into_iter()
        .filter_map(|r| match r.msg {
            apm::MavMessage::ODOMETRY(o) => Some(o),
            _ => None,
        })
        .collect();
    let (a, b) = (odo[5].clone(), odo.last().unwrap().clone());
    assert_eq!(b.frame_id, apm::MavFrame::MAV_FRAME_LOCAL_NED);
    assert_eq!(
        b.estimator_type,
        apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO
    );
    let dt_s = (b.time_usec - a.time_usec) as f64 / 1e6;
    let vn = f64::from(b.x - a.x) / dt_s;
    assert!(
        (vn - 30.0).abs() < 3.0,
        "north speed {vn:.2} m/s over {dt_s:.2} s"
    );
    assert!((b.vx - 30.0).abs() < 1.0, "forward speed {}", b.vx);
    assert!(b.quality >= 1);
    // Time stamps strictly increase (the daemon's clock).
    assert!(odo.windows(2).all(|w| w[1].time_usec >= w[0].time_usec));
    assert_eq!(c.rx_parse_errors, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn survives_garbage_floods_reboots_link_loss_and_a_flaky_camera() {
    let port = fa::free_udp_port();
    let cam_port = fa::free_tcp_port();
    let (h, task) = start(config(
        port,
        &format!(
            "[camera]\nsource = \"frame_stream\"\naddress = \"127.0.0.1:{cam_port}\"\n\
             timeout_s = 0.5\nretry_max_s = 0.4\nqueue_frames = 2\n\
             [input]\ngnss_loss_timeout_s = 0.5\n"
        ),
    ))
    .await;
    let fake = Fake::start(port).await;
    let odo_since = |t: Instant| fake.received(|r| is_odometry(r) && r.at >= t).len();
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(6), || odo_since(t) > 10).await,
        "publishing"
    );
    let rss0 = rss_kb();

    // 1. Garbage: random bytes, truncated frames, bad CRCs, MAVLink 1, unknown message ids.
    let hb_v1 = fa::frame(
        MavlinkVersion::V1,
        1,
        1,
        0,
        &apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
            autopilot: apm::MavAutopilot::MAV_AUTOPILOT_PX4,
            ..Default::default()
        }),
    );
    let good = fa::frame(
        MavlinkVersion::V2,
        1,
        1,
        0,
        &apm::MavMessage::VFR_HUD(apm::VFR_HUD_DATA::default()),
    );
    let mut seed = 0x1234_5678_u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for k in 0..300 {
        let mut bytes: Vec<u8> = (0..(rnd() % 300) as usize).map(|_| rnd() as u8).collect();
        match k % 5 {
            0 => {}
            1 => bytes = good[..(rnd() as usize % good.len())].to_vec(),
            2 => {
                bytes = good.clone();
                let i = 10 + (rnd() as usize % (bytes.len() - 10));
                bytes[i] ^= 0x5a; // payload or CRC corrupted
            }
            3 => bytes = hb_v1.clone(),
            _ => {
                // A well-formed MAVLink 2 frame with an unknown message id (60000).
                bytes = vec![0xfd, 4, 0, 0, 0, 1, 1, 0x60, 0xea, 0x00, 1, 2, 3, 4, 0, 0];
            }
        }
        fake.send_raw(&bytes).await;
        if k % 10 == 9 {
            // Pace the burst so the kernel's socket buffer does not overflow.
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    }
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(3), || odo_since(t) > 10).await,
        "publishing after garbage"
    );
    let c = h.shared.counters();
    // 60 sent; UDP on loopback may still lose a few under load.
    assert!(
        c.rx_v1_frames >= 54,
        "MAVLink 1 frames accepted and counted: {}",
        c.rx_v1_frames
    );

    // Frames of the autopilot's own stream with a bad CRC or an unknown id: the mavlink crate
    // drops them silently; the gaps they leave in its sequence numbers are counted.
    let lost0 = h.shared.counters().rx_seq_lost;
    for k in 0..20 {
        let hud = apm::MavMessage::VFR_HUD(apm::VFR_HUD_DATA::default());
        fake.send_dropped_frame(&hud, k % 2 == 0).await;
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(3), || odo_since(t) > 10).await,
        "publishing after dropped frames"
    );
    let lost = h.shared.counters().rx_seq_lost - lost0;
    assert!(
        (20..40).contains(&lost),
        "{lost} frames counted missing for 20 dropped (plus any UDP loss)"
    );

    // 2. 10× IMU flood for 1 s: nothing decoded is lost on the way to the navigation thread.
    let sent0 = fake.ctl.lock().unwrap().imu_sent;
    fake.ctl.lock().unwrap().imu_per_tick = 10;
    tokio::time::sleep(Duration::from_secs(1)).await;
    fake.ctl.lock().unwrap().imu_per_tick = 1;
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(3), || odo_since(t) > 10).await,
        "publishing after the flood"
    );
    let sent = fake.ctl.lock().unwrap().imu_sent - sent0;
    // Compare the counters at a quiet moment (0.3 s of silence, well under the 1 s link
    // timeout): a message being handed over would otherwise be counted on one side only.
    fake.ctl.lock().unwrap().silent = true;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let c = h.shared.counters();
    fake.ctl.lock().unwrap().silent = false;
    assert!(
        sent > 900,
        "flood sent {sent} IMU messages in 1 s (10× 100 Hz)"
    );
    let decoded = c.input.imu + c.input.air + c.input.mag + c.input.gnss + c.input.attitude;
    assert_eq!(
        c.events_to_nav + c.time_order_rejected + c.time_repeated,
        decoded,
        "events lost: {c:?}"
    );
    // Every decoded IMU sample reached the navigator: counted there before the initialisation
    // (with the other kinds), or by the INS (accepted or refused), or refused by the time gate.
    // The navigation thread publishes its counters every 50 events: allow that lag.
    let ins = c.ins.unwrap();
    let seen = ins.imu.accepted + ins.imu.rejected_invalid + ins.imu.rejected_time;
    assert!(
        seen + c.nav.events_before_init + c.time_order_rejected + c.time_repeated + 60
            >= c.input.imu,
        "{ins:?} vs {} IMU decoded",
        c.input.imu
    );

    // 3. Autopilot reboot: boot time and sequence restart.
    let req0 = c.interval_requests;
    fake.ctl.lock().unwrap().reboot = true;
    assert!(
        wait_for(Duration::from_secs(3), || h
            .shared
            .counters()
            .autopilot_reboots
            == 1)
        .await,
        "reboot detected"
    );
    assert!(
        wait_for(Duration::from_secs(2), || h
            .shared
            .counters()
            .interval_requests
            > req0)
        .await,
        "intervals requested again"
    );
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(3), || odo_since(t) > 10).await,
        "publishing after reboot"
    );

    // 4. GNSS loss for 2.5 s (INS GNSS-denied after its 1.5 s timeout): announced, the
    // heartbeat turns CRITICAL, publishing goes on; when GNSS is back for 5 s the INS is
    // re-initialised at the fix (reset counter +1, announced).
    fake.ctl.lock().unwrap().gnss_off = true;
    let t = Instant::now();
    tokio::time::sleep(Duration::from_millis(2500)).await;
    assert!(
        odo_since(t) > 60,
        "publishing without GNSS: {}",
        odo_since(t)
    );
    let texts = fake.statustexts();
    assert!(texts.iter().any(|t| t.contains("GNSS lost")), "{texts:?}");
    let critical = fake.received(|r| {
        r.at > t
            && matches!(&r.msg, apm::MavMessage::HEARTBEAT(h)
        if h.system_status == apm::MavState::MAV_STATE_CRITICAL)
    });
    assert!(!critical.is_empty(), "CRITICAL heartbeat while GNSS-denied");
    let reset_before = match fake.received(is_odometry).last().map(|r| r.msg.clone()) {
        Some(apm::MavMessage::ODOMETRY(o)) => o.reset_counter,
        _ => unreachable!(),
    };
    fake.ctl.lock().unwrap().gnss_off = false;
    assert!(
        wait_for(Duration::from_secs(8), || fake
            .statustexts()
            .iter()
            .any(|t| t.contains("estimator reset")))
        .await,
        "re-initialised after GNSS return: {:?}",
        fake.statustexts()
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    let reset_after = match fake.received(is_odometry).last().map(|r| r.msg.clone()) {
        Some(apm::MavMessage::ODOMETRY(o)) => o.reset_counter,
        _ => unreachable!(),
    };
    assert_eq!(reset_after, reset_before.wrapping_add(1));
    assert!(
        fake.statustexts()
            .iter()
            .any(|t| t.contains("GNSS regained"))
    );

    // 5. Link loss: 5 s of silence (5× the configured 1 s link timeout), then back.
    fake.ctl.lock().unwrap().silent = true;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let quiet_from = Instant::now() + Duration::from_millis(300);
    tokio::time::sleep(Duration::from_millis(4700)).await;
    let stale_odo = fake
        .received(|r| is_odometry(r) && r.at >= quiet_from)
        .len();
    assert_eq!(
        stale_odo, 0,
        "a stale solution was published during the outage"
    );
    assert_eq!(h.shared.counters().link_losses, 1);
    let req1 = h.shared.counters().interval_requests;
    fake.ctl.lock().unwrap().silent = false;
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(3), || odo_since(t) > 10).await,
        "publishing after link loss"
    );
    assert!(h.shared.counters().interval_requests > req1);

    // 6. Camera: absent so far (retries counted); then frames, a 1.5 s stall, frames again.
    assert!(
        h.shared.counters().camera_errors >= 2,
        "{:?}",
        h.shared.counters().camera_errors
    );
    let listener = tokio::net::TcpListener::bind(("127.0.0.1", cam_port))
        .await
        .unwrap();
    let (mut sock, _) = tokio::time::timeout(Duration::from_secs(3), listener.accept())
        .await
        .expect("daemon reconnects to the camera")
        .unwrap();
    use tokio::io::AsyncWriteExt;
    let frames = |n: usize| {
        let mut buf = Vec::new();
        for k in 0..n {
            let f = ianav::sensors::Frame {
                t_us: fake.boot_us() + 1_000 * k as u64,
                width: 64,
                height: 48,
                pixels: std::sync::Arc::from(vec![k as u8; 64 * 48]),
            };
            ianav::io::frame_stream::write_frame(&mut buf, &f, k as u32).unwrap();
        }
        buf
    };
    for _ in 0..5 {
        sock.write_all(&frames(1)).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        wait_for(Duration::from_secs(2), || h
            .shared
            .counters()
            .frames_received
            >= 5)
        .await
    );
    tokio::time::sleep(Duration::from_millis(1200)).await; // stall > camera.timeout_s
    let texts = fake.statustexts();
    assert!(texts.iter().any(|t| t.contains("camera lost")), "{texts:?}");
    // A burst of 20 frames: the navigation thread keeps the newest 2, so late ones are dropped
    // (or all consumed if it keeps up); frames keep flowing.
    sock.write_all(&frames(20)).await.unwrap();
    assert!(
        wait_for(Duration::from_secs(2), || h
            .shared
            .counters()
            .frames_received
            >= 25)
        .await
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    let texts = fake.statustexts();
    assert!(
        texts
            .iter()
            .filter(|t| t.contains("camera frames received"))
            .count()
            >= 2,
        "{texts:?}"
    );

    let rss1 = rss_kb();
    let c = stop(h, task).await;
    // Every condition reported.
    let texts = fake.statustexts();
    for want in ["INS initialised", "autopilot reboot", "link restored"] {
        assert!(
            texts.iter().any(|t| t.contains(want)),
            "{want} missing from {texts:?}"
        );
    }
    assert!(c.publish_stale > 0, "stale ticks counted during the outage");
    assert_eq!(c.frames_received, 25);
    // Memory bounded: channels are bounded (see docs/DAEMON.md); growth over the whole
    // ordeal stays far below what unbounded queues of the flood would need.
    assert!(rss1 < rss0 + 50_000, "RSS grew from {rss0} kB to {rss1} kB");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_a_key_unsigned_input_is_refused_and_everything_sent_is_signed() {
    let key: [u8; 32] = std::array::from_fn(|i| (i * 7 + 3) as u8);
    let hex: String = key.iter().map(|b| format!("{b:02x}")).collect();
    let port = fa::free_udp_port();
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nsigning_key = \"{hex}\"\n\
         refuse_unsigned = true\n[output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         [navigation]\nmag_decimal_year = 2026.5\n[logging]\ncounters_period_s = 0.0\n"
    );
    let (h, task) = start(DaemonConfig::from_toml_str(&text, None).unwrap()).await;
    let fake = Fake::start(port).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(
        h.shared.state(|s| s.autopilot),
        None,
        "unsigned HEARTBEAT accepted"
    );
    assert_eq!(h.shared.counters().rx_frames, 0);
    assert!(fake.received(is_odometry).is_empty());
    *fake.signing.lock().unwrap() = Some(fa::signing_data(key));
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(6), || fake
            .received(|r| is_odometry(r) && r.at > t)
            .len()
            > 10)
        .await,
        "signed input accepted: {:?}",
        h.shared.counters()
    );
    let c = stop(h, task).await;
    assert!(
        c.rx_signed_frames > 100 && c.rx_signed_frames == c.rx_frames,
        "{c:?}"
    );
    // Everything the daemon sent after the fake had the key verifies with it.
    let after: Vec<Rx> = fake.received(|r| r.at > t);
    assert!(after.len() > 20);
    let bad: Vec<String> = after
        .iter()
        .filter(|r| !r.signed_ok)
        .map(|r| format!("{} {:?}", mavlink::Message::message_name(&r.msg), r.version))
        .collect();
    assert!(
        bad.is_empty(),
        "unsigned or badly signed frames from the daemon: {bad:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn directory_camera_absent_at_start_then_read_in_name_order() {
    let port = fa::free_udp_port();
    let dir = std::env::temp_dir().join(format!("ianav-frames-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (h, task) = start(config(
        port,
        &format!(
            "[camera]\nsource = \"directory\"\npath = \"{}\"\nretry_max_s = 0.2\n",
            dir.display()
        ),
    ))
    .await;
    // No directory yet: retried and counted, the daemon keeps running.
    assert!(
        wait_for(Duration::from_secs(2), || h.shared.counters().camera_errors
            >= 2)
        .await
    );
    std::fs::create_dir_all(&dir).unwrap();
    // Stems are exposure times in µs: 0, 0.1 s, 0.2 s; one file is not an image.
    for (name, v) in [
        ("000200000.pgm", 3_u8),
        ("000000000.pgm", 1),
        ("000100000.pgm", 2),
    ] {
        let mut b = b"P5\n4 2\n255\n".to_vec();
        b.extend_from_slice(&[v; 8]);
        std::fs::write(dir.join(name), b).unwrap();
    }
    std::fs::write(dir.join("notes.txt"), "not a frame").unwrap();
    let t0 = Instant::now();
    assert!(
        wait_for(Duration::from_secs(3), || h
            .shared
            .counters()
            .frames_received
            == 3)
        .await
    );
    // Paced by the stems: the last frame 0.2 s after the first (after the retry delay).
    assert!(t0.elapsed() >= Duration::from_millis(200));
    let c = stop(h, task).await;
    assert_eq!((c.frames_received, c.camera_connects), (3, 1));
    // The navigator received them (it counts frames until vision lands).
    assert_eq!(c.nav.frames, 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_the_autopilot_clock_a_vehicle_at_10x_speed_is_navigated_in_its_own_time() {
    let port = fa::free_udp_port();
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nclock = \"autopilot\"\n\
         [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
         [navigation]\nmag_decimal_year = 2026.5\n[logging]\ncounters_period_s = 0.0\n"
    );
    let (h, task) = start(DaemonConfig::from_toml_str(&text, None).unwrap()).await;
    let fake = Fake::start(port).await;
    // 100 Hz IMU and 5 Hz GNSS in vehicle time, 10× faster than real time.
    fake.ctl.lock().unwrap().time_scale = 10;
    assert!(
        wait_for(Duration::from_secs(5), || fake.received(is_odometry).len()
            > 40)
        .await
    );
    tokio::time::sleep(Duration::from_secs(2)).await;
    let c = stop(h, task).await;
    let odo: Vec<apm::ODOMETRY_DATA> = fake
        .received(is_odometry)
        .into_iter()
        .filter_map(|r| match r.msg {
            apm::MavMessage::ODOMETRY(o) => Some(o),
            _ => None,
        })
        .collect();
    let (a, b) = (odo[10].clone(), odo.last().unwrap().clone());
    let dt_vehicle_s = (b.time_usec - a.time_usec) as f64 / 1e6;
    // Stamps are vehicle time: ~2 s real = ~20 s vehicle between them.
    assert!(dt_vehicle_s > 10.0, "{dt_vehicle_s} s of vehicle time");
    // 30 Hz of vehicle time, and the INS integrated vehicle Δt: 30 m/s north.
    let rate = (odo.len() - 11) as f64 / dt_vehicle_s;
    assert!(
        (27.0..=33.0).contains(&rate),
        "{rate:.1} Hz of vehicle time"
    );
    let vn = f64::from(b.x - a.x) / dt_vehicle_s;
    assert!((vn - 30.0).abs() < 3.0, "north speed {vn:.2} m/s");
    assert_eq!(c.time_order_rejected, 0);
    assert_eq!(
        c.ins.unwrap().imu_gaps,
        0,
        "no compressed or stretched IMU steps"
    );
}
