//! The `ianav` command line: help texts and `check-config` exit codes.

use std::process::Command;

fn ianav(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_ianav"))
        .args(args)
        .output()
        .expect("the ianav binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn help_names_every_subcommand_and_their_arguments() {
    let (ok, out, _) = ianav(&["--help"]);
    assert!(ok);
    for sub in ["run", "check-config", "replay", "export-mcap", "version"] {
        assert!(out.contains(sub), "{sub} missing from:\n{out}");
    }
    let (ok, out, _) = ianav(&["run", "--help"]);
    assert!(
        ok && out.contains("--config") && out.contains("SIGTERM"),
        "{out}"
    );
    let (ok, out, _) = ianav(&["check-config", "--help"]);
    assert!(
        ok && out.contains("FILE") && out.contains("status 1"),
        "{out}"
    );
}

#[test]
fn check_config_prints_ok_or_the_key_and_exits_non_zero() {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/config/ianav.toml");
    let (ok, out, _) = ianav(&["check-config", shipped]);
    assert!(ok, "{out}");
    assert_eq!(out.trim(), "OK");
    let dir = std::env::temp_dir().join(format!("ianav-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "[mavlink]\nconnection = \"udpin:0.0.0.0:14540\"\n[output]\nrate_hz = 500\n",
    )
    .unwrap();
    let (ok, _, err) = ianav(&["check-config", bad.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("output.rate_hz = 500: must be in [1, 200]"),
        "{err}"
    );
    let (ok, _, err) = ianav(&["check-config", dir.join("missing.toml").to_str().unwrap()]);
    assert!(!ok && err.contains("missing.toml"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `ianav run --config FILE`, killed after 10 s (a config it accepts would run on).
fn run_briefly(file: &std::path::Path, env: &[(&str, &str)]) -> (Option<i32>, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_ianav"));
    cmd.args(["run", "--config"])
        .arg(file)
        .env_remove("RUST_LOG")
        .env_remove("IANAV_FAULT")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("the ianav binary runs");
    let end = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while child.try_wait().expect("wait").is_none() && std::time::Instant::now() < end {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let _ = child.kill();
    let out = child.wait_with_output().expect("ianav ends");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// One validation for `run` and `check-config`: for every rule `run` enforces before it opens the
/// link, `check-config` refuses the same file with exit status 1 and the same message, byte for
/// byte.
#[test]
fn check_config_refuses_what_run_refuses_with_the_same_error() {
    let dir = std::env::temp_dir().join(format!("ianav-cli-parity-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let ok = "[mavlink]\nconnection = \"udpin:127.0.0.1:14540\"\n[output]\nrate_hz = 30\n";
    let with = |extra_mavlink: &str, tail: &str| {
        ok.replace("[output]", &format!("{extra_mavlink}[output]")) + tail
    };
    // (name, file text or None for a missing file, RUST_LOG, what the error must name)
    let cases: Vec<(&str, Option<String>, Option<&str>, &str)> = vec![
        ("missing", None, None, "No such file"),
        ("toml", Some("[mavlink\n".into()), None, "TOML parse error"),
        ("unknown-key", Some(with("bogus = 1\n", "")), None, "bogus"),
        (
            "range",
            Some(ok.replace("rate_hz = 30", "rate_hz = 500")),
            None,
            "output.rate_hz = 500: must be in [1, 200]",
        ),
        (
            "timesync-rate",
            Some(with("timesync_rate_hz = 1e-300\n", "")),
            None,
            "mavlink.timesync_rate_hz = 1e-300",
        ),
        (
            "log-level",
            Some(with("", "[logging]\nlevel = \"info,ianav=loud\"\n")),
            None,
            "logging.level",
        ),
        (
            "rust-log",
            Some(ok.to_owned()),
            Some("ianav=loud"),
            "RUST_LOG",
        ),
        (
            "connection-syntax",
            Some(ok.replace("udpin:127.0.0.1:14540", "udp:127.0.0.1:14540")),
            None,
            "mavlink.connection",
        ),
        (
            "connection-unresolvable",
            Some(ok.replace("127.0.0.1", "999.1.1.1")),
            None,
            "cannot resolve \"999.1.1.1\"",
        ),
        (
            "ins-file",
            Some(with("", "[navigation]\nins_config = \"absent.toml\"\n")),
            None,
            "absent.toml",
        ),
        (
            "ins-value",
            Some(with("", "[ins]\nimu_gap_s = -1.0\n")),
            None,
            "imu_gap_s",
        ),
        (
            "signing-key",
            Some(with("signing_key = \"abc\"\n", "")),
            None,
            "mavlink.signing_key",
        ),
        (
            "refuse-unsigned",
            Some(with("refuse_unsigned = true\n", "")),
            None,
            "mavlink.refuse_unsigned",
        ),
        (
            "camera",
            Some(with("", "[camera]\nqueue_frames = 0\n")),
            None,
            "camera.queue_frames",
        ),
    ];
    for (name, text, rust_log, needle) in cases {
        let file = dir.join(format!("{name}.toml"));
        if let Some(t) = &text {
            std::fs::write(&file, t).unwrap();
        }
        let env: Vec<(&str, &str)> = rust_log.map(|v| ("RUST_LOG", v)).into_iter().collect();
        let mut check = Command::new(env!("CARGO_BIN_EXE_ianav"));
        check.arg("check-config").arg(&file).env_remove("RUST_LOG");
        for (k, v) in &env {
            check.env(k, v);
        }
        let out = check.output().unwrap();
        let check_err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert_eq!(out.status.code(), Some(1), "{name}: {check_err}");
        assert!(check_err.contains(needle), "{name}: {check_err}");
        let (code, run_err) = run_briefly(&file, &env);
        assert_eq!(code, Some(1), "{name}: run accepted it:\n{run_err}");
        assert_eq!(run_err, check_err, "{name}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `ianav export-mcap` on the committed replay log (no camera): an MCAP file with the format's
/// magic at both ends and position and status messages; a missing log is a clear error.
#[test]
fn export_mcap_writes_a_file_and_counts_its_messages() {
    let log = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/replay/scenario2-short.bin"
    );
    let out = std::env::temp_dir().join(format!("ianav_cli_{}.mcap", std::process::id()));
    let out_s = out.to_str().expect("a UTF-8 temp path");
    let (ok, stdout, stderr) = ianav(&["export-mcap", log, "--out", out_s]);
    assert!(ok, "{stderr}");
    let bytes = std::fs::read(&out).expect("the MCAP file");
    let _ = std::fs::remove_file(&out);
    // MCAP's magic: 0x89 "MCAP0" \r \n, at both ends.
    let magic = b"\x89MCAP0\r\n";
    assert!(bytes.starts_with(magic) && bytes.ends_with(magic));
    assert!(
        stdout.contains("/ianav/position") && stdout.contains("/ianav/status"),
        "{stdout}"
    );
    let (ok, _, stderr) = ianav(&["export-mcap", "/nonexistent.bin", "--out", out_s]);
    assert!(!ok && stderr.contains("/nonexistent.bin"), "{stderr}");
}
