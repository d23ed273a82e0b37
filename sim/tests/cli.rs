//! The `ianav-sim` command line: a short flight writes its outputs; bad arguments and bad
//! configuration files exit non-zero with a message naming the offending field, never a panic.

#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

use std::path::PathBuf;
use std::process::{Command, Output};

fn ianav_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ianav-sim"))
        .args(args)
        .output()
        .unwrap()
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ianav-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn assert_clean_failure(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail: {stderr}");
    assert!(
        stderr.contains(needle),
        "stderr should name `{needle}`: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "must not panic: {stderr}");
}

#[test]
fn run_writes_report_trajectory_sensors_and_plots() {
    let dir = temp_dir("run");
    let out_dir = dir.join("out");
    let out = ianav_sim(&[
        "run",
        "--scenario",
        "2",
        "--seed",
        "3",
        "--duration",
        "20",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for file in [
        "report.md",
        "truth.csv",
        "sensors.bin",
        "summary.toml",
        "ground_track.png",
        "altitude.png",
        "airspeed.png",
        "attitude.png",
        "navigation.csv",
        "nav_attitude_error.png",
        "nav_position_error.png",
    ] {
        assert!(out_dir.join(file).is_file(), "missing {file}");
    }
    // The INS solution against the truth at 10 Hz from its start in the warm-up.
    let nav_rows = std::fs::read_to_string(out_dir.join("navigation.csv"))
        .unwrap()
        .lines()
        .count();
    assert!((1 + 200..=1 + 700).contains(&nav_rows), "{nav_rows} rows");
    // 70 s of flight (50 s warm-up + 20 s) at 10 Hz, plus the header.
    let rows = std::fs::read_to_string(out_dir.join("truth.csv"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(rows, 1 + 700);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_arguments_are_refused() {
    let out = ianav_sim(&["run", "--scenario", "3", "--out", "/tmp/never"]);
    assert_clean_failure(&out, "--scenario");
    let out = ianav_sim(&[
        "run",
        "--scenario",
        "2",
        "--duration=-5",
        "--out",
        "/tmp/never",
    ]);
    assert_clean_failure(&out, "--duration");
    let out = ianav_sim(&[
        "run",
        "--scenario",
        "2",
        "--turbulence",
        "nan",
        "--out",
        "/tmp/never",
    ]);
    assert_clean_failure(&out, "--turbulence");
}

/// `bench-vns` times every frame of a camera flight (10 Hz from mission time 0: 31 frames in
/// 3 s) and refuses a flight without a camera.
#[test]
fn bench_vns_times_every_frame_and_needs_a_camera() {
    let out = ianav_sim(&["bench-vns", "--scenario", "2", "--duration", "3"]);
    assert_clean_failure(&out, "--terrain");
    let out = ianav_sim(&[
        "bench-vns",
        "--scenario",
        "2",
        "--duration",
        "3",
        "--terrain",
        "mx",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.contains("over mx: 31 frames"), "{stdout}");
    let all = stdout
        .lines()
        .find(|l| l.trim_start().starts_with("all "))
        .unwrap();
    assert_eq!(all.split_whitespace().nth(1), Some("31"), "{all}");
    assert!(stdout.contains("0 bad frames"), "{stdout}");
    // Each system is timed alone.
    for system in ["vns", "ia-vns"] {
        assert!(
            stdout.contains(&format!("{system}: time per frame")),
            "{stdout}"
        );
    }
}

/// A camera `run` (the README's main job, shortened) writes every visual system's rows and
/// the report's section; frames stay out of the sensor log.
#[test]
fn a_camera_run_reports_every_visual_system() {
    let dir = temp_dir("camera-run");
    let out = ianav_sim(&[
        "run",
        "--scenario",
        "2",
        "--duration",
        "5",
        "--terrain",
        "ur",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(dir.join("vision.csv")).unwrap();
    for system in ["vns", "ia-vns"] {
        assert!(
            csv.contains(&format!(",{system},tracking,")),
            "{system}: {csv}"
        );
    }
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(report.contains("| IA-VNS | tracking |"), "{report}");
    // 51 frames of 768 × 1024 would be 40 MB: the log holds no frames.
    let log = std::fs::metadata(dir.join("sensors.bin")).unwrap().len();
    assert!(log < 3_000_000, "{log} bytes");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_configuration_files_name_the_field() {
    let dir = temp_dir("config");
    let repo_config = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config");
    let cases = [
        (
            "sensors.toml",
            "imu_period_s = 0.01",
            "imu_period_s = -0.01",
            "imu_period_s",
        ),
        (
            "sensors.toml",
            "imu_period_s = 0.01",
            "imu_period_s = 0.01\nmystery = 3",
            "mystery",
        ),
        (
            "scenarios/scenario2.toml",
            "warmup_s = 50.0",
            "warmup_s = \"long\"",
            "warmup_s",
        ),
        (
            "vision.toml",
            "tukey_k = 4.685",
            "tukey_k = 0.0",
            "vision.pose.tukey_k",
        ),
        (
            "vision.toml",
            "[pose]",
            "[pose]\nmystery_vns = 1",
            "mystery_vns",
        ),
    ];
    for (file, from, to, needle) in cases {
        let case_dir = dir.join(needle);
        std::fs::create_dir_all(case_dir.join("scenarios")).unwrap();
        let text = std::fs::read_to_string(repo_config.join(file)).unwrap();
        assert!(text.contains(from), "{file} should contain `{from}`");
        std::fs::write(case_dir.join(file), text.replacen(from, to, 1)).unwrap();
        let out = ianav_sim(&[
            "run",
            "--scenario",
            "2",
            "--config-dir",
            case_dir.to_str().unwrap(),
            "--out",
            dir.join("never").to_str().unwrap(),
        ]);
        assert_clean_failure(&out, needle);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_missing_config_directory_is_refused_not_replaced_by_the_defaults() {
    let dir = temp_dir("nodir");
    let file = dir.join("a-file");
    std::fs::write(&file, "").unwrap();
    for (config_dir, needle) in [
        (
            "/nonexistent/ianav-config",
            "--config-dir /nonexistent/ianav-config",
        ),
        (file.to_str().unwrap(), "not a directory"),
    ] {
        let out = ianav_sim(&[
            "run",
            "--scenario",
            "2",
            "--config-dir",
            config_dir,
            "--out",
            dir.join("never").to_str().unwrap(),
        ]);
        assert_clean_failure(&out, needle);
        assert!(!dir.join("never").exists(), "nothing flown");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The lens example (config/lens-example: a camera.toml naming its calibration file
/// relatively) flies: the calibration is found beside camera.toml whatever the working
/// directory, the renderer distorts the frames and the navigation records the lens.
#[test]
fn the_lens_example_flies_with_its_calibration_beside_its_camera_toml() {
    let dir = temp_dir("lens");
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/lens-example");
    let out_dir = dir.join("out");
    let frames = dir.join("frames");
    let out = Command::new(env!("CARGO_BIN_EXE_ianav-sim"))
        .current_dir(&dir)
        .args([
            "run",
            "--scenario",
            "2",
            "--duration",
            "0.5",
            "--terrain",
            "mx",
            "--vision-systems",
            "ia-vns",
            "--config-dir",
            example,
            "--frames",
            frames.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pngs = std::fs::read_dir(&frames).unwrap().count();
    assert!(pngs >= 5, "{pngs} frames");
    // The recorded navigation settings carry the calibration's lens.
    let log = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "bin"))
        .expect("a sensor log");
    let reader = ianav::io::sensor_log::SensorLogReader::new(std::io::BufReader::new(
        std::fs::File::open(&log).unwrap(),
    ))
    .unwrap();
    let camera = ianav::nav::replay::config_of(&reader)
        .unwrap()
        .camera
        .expect("a camera");
    let lens = camera.intrinsics.calibration.expect("the calibration");
    assert!(!lens.distortion.is_identity(), "{lens:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
