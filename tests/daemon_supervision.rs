//! No silent worker death (a reliability requirement of the daemon): the `ianav` binary against the
//! fake PX4 autopilot, with a worker made to fail by the `IANAV_FAULT` test hook (docs/DAEMON.md
//! "Worker failures"), exits non-zero with a message naming the worker after a STATUSTEXT saying
//! so; the camera task is restarted, then the daemon stops if it keeps failing. The systemd
//! watchdog is fed only while IMU samples are processed.
//!
//! The hook is compiled only with debug assertions (the `ci` test profile); in a build without
//! them these tests say so and pass without running.

#![expect(
    clippy::unwrap_used,
    reason = "helpers outside #[test] functions: a failed loopback setup should fail the test loudly"
)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use common::fake_autopilot::{self as fa, Fake};

fn hook_available() -> bool {
    if !cfg!(debug_assertions) {
        eprintln!("SKIPPED: IANAV_FAULT is compiled only with debug assertions (--profile ci)");
    }
    cfg!(debug_assertions)
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ianav-sup-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write_config(dir: &Path, port: u16, extra: &str) -> PathBuf {
    let path = dir.join("ianav.toml");
    std::fs::write(
        &path,
        format!(
            "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\n\
             [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
             [navigation]\nmag_decimal_year = 2026.5\n\
             [logging]\nlevel = \"info\"\ncounters_period_s = 0.0\n{extra}"
        ),
    )
    .unwrap();
    path
}

fn spawn(config: &Path, env: &[(&str, &str)]) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_ianav"));
    cmd.args(["run", "--config"])
        .arg(config)
        .env_remove("RUST_LOG")
        .env_remove("IANAV_FAULT")
        .env_remove("NOTIFY_SOCKET")
        .env("RUST_BACKTRACE", "0")
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.spawn().unwrap()
}

/// Wait for the process to exit (at most `limit`); its status and stderr.
async fn exit_within(mut child: Child, limit: Duration) -> (ExitStatus, String) {
    let end = Instant::now() + limit;
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > end {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!(
                "still running after {limit:?}: alive with a dead worker?\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let out = child.wait_with_output().unwrap();
    (
        out.status,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Each worker in turn: running against the autopilot (the navigation thread fails while it
/// processes the autopilot's events), then its injected failure ends the daemon with exit
/// status 1, the reason on stderr once, and a STATUSTEXT to the autopilot.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failing_worker_ends_the_daemon_with_a_non_zero_exit() {
    if !hook_available() {
        return;
    }
    let cases = [
        ("reader", "link reader panicked"),
        ("reader:stop", "link reader stopped unexpectedly"),
        ("writer", "link writer panicked"),
        ("nav", "navigation thread panicked"),
        ("nav:stop", "navigation thread stopped unexpectedly"),
        ("monitor", "monitor panicked"),
        ("intervals", "interval requests panicked"),
        ("timesync", "TIMESYNC requests panicked"),
    ];
    for (fault, expect) in cases {
        let dir = temp_dir(&fault.replace(':', "-"));
        let port = fa::free_udp_port();
        let cfg = write_config(&dir, port, "");
        let child = spawn(&cfg, &[("IANAV_FAULT", fault)]);
        let fake = Fake::start(port).await;
        let (status, stderr) = exit_within(child, Duration::from_secs(20)).await;
        assert_eq!(status.code(), Some(1), "{fault}: {stderr}");
        let line = format!("ianav: daemon stopped: {expect}");
        assert_eq!(
            stderr.matches(&line).count(),
            1,
            "{fault}: `{line}` once in:\n{stderr}"
        );
        // The writer announces it, unless the writer is the one that failed.
        if fault != "writer" {
            // The datagram was sent before the exit; the fake's receiving task may not have
            // taken it yet on a loaded machine: give it up to a second.
            let mut texts = fake.statustexts();
            for _ in 0..20 {
                if texts.iter().any(|t| t.ends_with("failed, exiting")) {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
                texts = fake.statustexts();
            }
            assert!(
                texts.iter().any(|t| t.ends_with("failed, exiting")),
                "{fault}: {texts:?}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// The camera task (an absent frame stream, retried) is restarted after each panic, counted and
/// announced, [`ianav::daemon::MAX_CAMERA_RESTARTS`] times; the next panic ends the daemon.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_camera_task_is_restarted_then_the_daemon_stops() {
    if !hook_available() {
        return;
    }
    let dir = temp_dir("camera");
    let port = fa::free_udp_port();
    let cam = fa::free_tcp_port();
    let cfg = write_config(
        &dir,
        port,
        &format!("[camera]\nsource = \"frame_stream\"\naddress = \"127.0.0.1:{cam}\"\n"),
    );
    let child = spawn(&cfg, &[("IANAV_FAULT", "camera")]);
    let fake = Fake::start(port).await;
    let (status, stderr) = exit_within(child, Duration::from_secs(30)).await;
    assert_eq!(status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("ianav: daemon stopped: camera panicked"),
        "{stderr}"
    );
    let texts = fake.statustexts();
    let max = ianav::daemon::MAX_CAMERA_RESTARTS;
    for n in 1..=max {
        let t = format!("ianav: camera failed, restart {n}/{max}");
        assert!(texts.contains(&t), "{t} in {texts:?}");
    }
    assert!(
        texts.iter().any(|t| t == "ianav: camera failed, exiting"),
        "{texts:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// sd_notify: READY=1 once the INS runs, then WATCHDOG=1 about every second while the IMU
/// stream is processed, and none while the IMU is silent although the rest of the link (GNSS,
/// attitude, air data, heartbeats) keeps flowing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_watchdog_is_fed_only_while_imu_samples_are_processed() {
    let dir = temp_dir("watchdog");
    let sock_path = dir.join("notify.sock");
    let sock = tokio::net::UnixDatagram::bind(&sock_path).unwrap();
    let port = fa::free_udp_port();
    let cfg = write_config(&dir, port, "");
    let mut child = spawn(&cfg, &[("NOTIFY_SOCKET", sock_path.to_str().unwrap())]);
    let fake = Fake::start(port).await;
    let mut buf = [0_u8; 512];
    // READY=1 (with the first WATCHDOG=1) once the INS runs on the fake's first fix.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let n = tokio::time::timeout(left, sock.recv(&mut buf))
            .await
            .expect("READY=1 within 30 s")
            .unwrap();
        let m = String::from_utf8_lossy(&buf[..n]).into_owned();
        if m.contains("READY=1") {
            assert!(m.contains("WATCHDOG=1"), "{m}");
            break;
        }
    }
    let fed = watchdogs(&sock, Duration::from_secs(4)).await;
    assert!(fed >= 3, "{fed} WATCHDOG=1 in 4 s with the IMU flowing");
    // The IMU stops; everything else goes on.
    let gnss_before = fake.ctl.lock().unwrap().gnss_sent;
    fake.ctl.lock().unwrap().imu_period_us = 3_600_000_000;
    // The last solution goes stale (0.5 s) before the next 1 Hz feed at the latest.
    let _ = watchdogs(&sock, Duration::from_millis(1_600)).await;
    let starved = watchdogs(&sock, Duration::from_secs(4)).await;
    assert_eq!(starved, 0, "WATCHDOG=1 without IMU samples");
    assert!(
        fake.ctl.lock().unwrap().gnss_sent >= gnss_before + 20,
        "the link kept flowing"
    );
    assert!(child.try_wait().unwrap().is_none(), "the daemon still runs");
    child.kill().unwrap();
    let _ = child.wait();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// WATCHDOG=1 notifications received during `d`.
async fn watchdogs(sock: &tokio::net::UnixDatagram, d: Duration) -> usize {
    let end = Instant::now() + d;
    let mut buf = [0_u8; 512];
    let mut n_fed = 0;
    while let Ok(Ok(n)) = tokio::time::timeout(
        end.saturating_duration_since(Instant::now()),
        sock.recv(&mut buf),
    )
    .await
    {
        n_fed += usize::from(String::from_utf8_lossy(&buf[..n]).contains("WATCHDOG=1"));
    }
    n_fed
}
