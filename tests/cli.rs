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
    for sub in ["run", "check-config", "version"] {
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
