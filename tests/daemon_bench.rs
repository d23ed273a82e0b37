//! Performance of the daemon binary on loopback against its targets (docs/DAEMON.md
//! "Performance": CPU ≤ 10 % of a core, p99 latency ≤ 2 ms): CPU use at a 100 Hz IMU with the
//! INS only, resident memory, and the latency from an IMU message received to the solution
//! written. Not a CI test (timing depends on the machine): run with
//! `cargo test --profile ci --test daemon_bench -- --ignored --nocapture`; figures in
//! docs/DAEMON.md.

mod common;

use std::process::{Command, Stdio};
use std::time::Duration;

use common::fake_autopilot::{self as fa, Fake};

#[path = "support/proc_stat.rs"]
mod proc_stat;
use proc_stat::{cpu_ticks, rss_kb};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "benchmark: run by hand, see the module doc"]
async fn cpu_memory_and_latency_at_100_hz_imu() {
    let port = fa::free_udp_port();
    let dir = std::env::temp_dir().join(format!("ianav-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("ianav.toml");
    std::fs::write(
        &cfg,
        format!(
            "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\n\
             [output]\nmode = \"odometry\"\nrate_hz = 50.0\n\
             [navigation]\nmag_decimal_year = 2026.5\n[logging]\nlevel = \"info\"\n\
             counters_period_s = 0.0\n"
        ),
    )
    .unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_ianav"))
        .args(["run", "--config"])
        .arg(&cfg)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let fake = Fake::start(port).await;
    // Warm-up: link, TIMESYNC, INS initialisation.
    tokio::time::sleep(Duration::from_secs(5)).await;
    let (c0, t0) = (cpu_ticks(pid), std::time::Instant::now());
    let rss0 = rss_kb(pid);
    tokio::time::sleep(Duration::from_secs(30)).await;
    let (c1, dt) = (cpu_ticks(pid), t0.elapsed().as_secs_f64());
    let rss1 = rss_kb(pid);
    let hz = 100.0; // clock ticks per second (Linux USER_HZ)
    let cpu = (c1 - c0) as f64 / hz / dt;
    let odo = fake
        .received(|r| {
            matches!(
                r.msg,
                mavlink::dialects::ardupilotmega::MavMessage::ODOMETRY(_)
            )
        })
        .len();
    Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    let lat = log
        .lines()
        .rev()
        .find(|l| l.contains("latency"))
        .unwrap_or("no latency line");
    println!(
        "daemon at 100 Hz IMU, 50 Hz ODOMETRY: CPU {:.1} % of one core over {dt:.0} s; \
         RSS {rss0} kB → {rss1} kB; {odo} ODOMETRY received\n{lat}",
        cpu * 100.0
    );
    assert!(out.status.success(), "{log}");
    std::fs::remove_dir_all(&dir).unwrap();
}
