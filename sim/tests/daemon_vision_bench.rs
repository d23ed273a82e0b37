//! The daemon's cost with vision running (docs/PERFORMANCE.md "Daemon with vision"): the `ianav`
//! binary, a process of its own, navigates with the IA-VNS on the frames the SITL vehicle
//! renders over MX (768 × 1024 at 10 Hz) and streams, in real time, GNSS lost 20 s into a
//! 120-s scenario #2 mission. Measured: the daemon's CPU per second of flight and its resident
//! memory (from /proc), the IMU received → solution written latency and the frame received →
//! visual result applied latency (the daemon's own percentiles, logged at exit). Not a CI test
//! (timing depends on the machine):
//!
//! ```text
//! cargo build --profile ci --bin ianav
//! cargo test --profile ci -p ianav-sim --test daemon_vision_bench -- --ignored --nocapture
//! ```
//!
//! With `IANAV_BENCH_NO_CAMERA=1` the daemon runs without its camera while the vehicle still
//! renders every frame: the same machine load without the vision, for comparison. With
//! `IANAV_BENCH_DAEMON_CPUS=LIST` the daemon runs under `taskset -c LIST`; run the test itself
//! (the vehicle and its renderer) under `taskset -c` on the other CPUs so that the renderer,
//! which an aircraft does not have, stays off the daemon's core:
//!
//! ```text
//! IANAV_BENCH_DAEMON_CPUS=1 taskset -c 0 cargo test --profile ci -p ianav-sim \
//!     --test daemon_vision_bench -- --ignored --nocapture
//! ```
//!
//! With `IANAV_BENCH_FRAMES=tcp` the frames travel over loopback TCP instead of the Unix
//! socket a daemon beside its SITL vehicle uses (docs/PERFORMANCE.md "Where the IMU tail is").
#![expect(
    clippy::unwrap_used,
    reason = "a benchmark: a failed set-up should fail the run loudly"
)]

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ianav::io::frame_stream::StreamAddress;
use ianav_sim::sitl::FramesListen;
use ianav_sim::terrain::Zone;
use tokio::net::TcpListener;

mod common;

const MISSION_S: f64 = 120.0;
const LOSS_S: f64 = 20.0;

#[path = "../../tests/support/proc_stat.rs"]
mod proc_stat;
use proc_stat::{cpu_ticks, rss_kb};

/// The `ianav` binary of the same profile, beside this test's directory of dependencies.
fn ianav_binary() -> std::path::PathBuf {
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().unwrap().parent().unwrap().join("ianav");
    assert!(
        bin.exists(),
        "{} missing: build it first (cargo build --profile ci --bin ianav)",
        bin.display()
    );
    bin
}

/// `name=value` of a logged field in `line`.
fn field(line: &str, name: &str) -> Option<u64> {
    let at = line.find(&format!("{name}="))? + name.len() + 1;
    let digits: String = line[at..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().ok()
}

/// `s` without terminal colour sequences (`ESC [ … m`).
fn strip_ansi(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d == 'm' {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "benchmark: run by hand, see the module doc"]
async fn the_daemon_with_vision_in_real_time() {
    let setup = common::mx_camera_setup(MISSION_S, LOSS_S);
    let start = Zone::Mix.start();
    let cam = &setup.camera.as_ref().unwrap().camera;

    let daemon_side = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let vehicle_side = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let frames = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let dir = std::env::temp_dir().join(format!("ianav_vision_bench_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut ins = ianav::ins::InsConfig::default();
    ins.alignment.ref_error_sigma_deg = [0.0; 3];
    let cfg = dir.join("ianav.toml");
    let with_camera = std::env::var_os("IANAV_BENCH_NO_CAMERA").is_none();
    let over_tcp = std::env::var("IANAV_BENCH_FRAMES").is_ok_and(|v| v == "tcp");
    let frames_address = if over_tcp {
        StreamAddress::Tcp(frames.local_addr().unwrap().to_string())
    } else {
        StreamAddress::Unix(dir.join("frames.sock"))
    };
    let camera = format!(
        "[camera]\nsource = \"frame_stream\"\naddress = \"{}\"\n\
         width_px = {}\nheight_px = {}\nfocal_length_mm = {}\npixel_pitch_um = {}\n\
         terrain_height_m = {}\n",
        frames_address,
        cam.width_px,
        cam.height_px,
        cam.focal_length_mm,
        cam.pixel_pitch_um,
        start.ground_m,
    );
    std::fs::write(
        &cfg,
        format!(
            "[mavlink]\nconnection = \"tcpout:{}\"\nclock = \"autopilot\"\n\
             [input]\nimu_rate_hz = 100.0\nair_rate_hz = 100.0\naoa_ssa = \"vanes\"\n\
             [output]\nmode = \"odometry\"\nrate_hz = 30.0\n\
             {}\
             [navigation]\nmag_decimal_year = {}\n\
             [logging]\nlevel = \"info\"\ncounters_period_s = 0.0\n\
             [ins.alignment]\n{}",
            daemon_side.local_addr().unwrap(),
            if with_camera { camera.as_str() } else { "" },
            setup.scenario.magnetic_decimal_year,
            toml::to_string(&ins.alignment).unwrap(),
        ),
    )
    .unwrap();
    let cpus = std::env::var("IANAV_BENCH_DAEMON_CPUS").ok();
    let mut command = match &cpus {
        Some(list) => {
            let mut c = Command::new("taskset");
            c.args(["-c", list]).arg(ianav_binary());
            c
        }
        None => Command::new(ianav_binary()),
    };
    let child = command
        .args(["run", "--config"])
        .arg(&cfg)
        .env("NO_COLOR", "1")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let to_daemon = common::accept(&daemon_side, "the daemon").await;
    let mut options = common::camera_vehicle(vehicle_side.local_addr().unwrap(), frames, 1.0, None);
    if !over_tcp {
        options.frames = Some(FramesListen::Addr(frames_address.clone()));
    }
    let sitl_task = common::spawn_sitl(&setup, 1, options);
    let to_vehicle = common::accept(&vehicle_side, "the SITL vehicle").await;
    let relay = common::Relay::start(to_vehicle, to_daemon);
    // The window: from mission time 0 (after the 50 s warm-up, the vision running since the
    // INS started) to the end.
    let warmup = Duration::from_secs_f64(setup.scenario.warmup_s);
    tokio::time::sleep(warmup).await;
    let (c0, t0, rss0) = (cpu_ticks(pid), Instant::now(), rss_kb(pid));
    let summary = tokio::time::timeout(Duration::from_secs_f64(MISSION_S * 2.0), sitl_task)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let (c1, dt_s, rss1) = (cpu_ticks(pid), t0.elapsed().as_secs_f64(), rss_kb(pid));
    Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let _ = relay.finish().await;
    let log = strip_ansi(&String::from_utf8_lossy(&out.stderr));
    let line = |what: &str| {
        log.lines()
            .rev()
            .find(|l| l.contains(what))
            .unwrap_or_default()
            .to_owned()
    };
    let imu = line("IMU received → solution written latency");
    let frame = line("frame received → visual result applied latency");
    let frame_due = line("frame due (the INS at its time) → visual result applied latency");
    let counters = line("counters");
    let cpu_pct = (c1 - c0) as f64 / 100.0 / dt_s * 100.0;
    println!(
        "daemon {} the IA-VNS (CPUs {}, frames over {}), {} frames sent ({} dropped by the vehicle), {:.0} s of flight \
         measured: CPU {cpu_pct:.1} % of one core; RSS {rss0} kB → {rss1} kB; \
         IMU → solution p50 / p99 / max {:?} / {:?} / {:?} µs (target p99 ≤ 1,000); \
         frame → result p50 / p99 / max {:?} / {:?} / {:?} µs (target p99 ≤ 30,000), \
         of which from due (the INS at the frame's time) {:?} / {:?} / {:?} µs; \
         vision fixes fused {:?}, frames dropped by the daemon {:?}, busy {:?}; \
         SITL max lag {:.3} s",
        if with_camera { "with" } else { "without" },
        cpus.as_deref().unwrap_or("any"),
        if over_tcp { "TCP" } else { "a Unix socket" },
        summary.frames_sent,
        summary.frames_dropped,
        dt_s,
        field(&imu, "p50_us"),
        field(&imu, "p99_us"),
        field(&imu, "max_us"),
        field(&frame, "p50_us"),
        field(&frame, "p99_us"),
        field(&frame, "max_us"),
        field(&frame_due, "p50_us"),
        field(&frame_due, "p99_us"),
        field(&frame_due, "max_us"),
        field(&counters, "vision_fixes_fused"),
        field(&counters, "frames_dropped"),
        field(&counters, "frames_vision_busy"),
        summary.max_lag_s,
    );
    assert!(out.status.success(), "{log}");
    assert!(
        !with_camera || field(&frame, "p99_us").is_some(),
        "no frame latency logged:\n{log}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
