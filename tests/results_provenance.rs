//! The committed results can be re-flown from the repository alone: every setting a result
//! depends on is in the repository, named by a path that resolves inside it.
//!
//! Three rules, every offender reported in one failure message:
//!
//! 1. Every `.toml` file under `docs/results/` parses, and every string in it that names a file
//!    is a relative path to an existing file inside the repository. A string names a file when
//!    its key (the last dotted segment, split at `_`) holds one of the words `config`, `path`,
//!    `file` or `dir`, or when the string holds a `/` or `\` and ends in a data-file extension
//!    (`.toml`, `.bin`, `.csv`, `.yaml`, ...). Empty strings name nothing (the daemon's
//!    "not set", e.g. `camera.path = ""`). A relative path is resolved against the directory
//!    of the TOML file that names it: the daemon's own rule for `navigation.ins_config`
//!    (`ianav::daemon::config`), so a flight directory holding `ianav.toml` and `ins.toml` is
//!    complete as it stands and can be copied or moved as a whole.
//! 2. A directory under `docs/results/` holding a `daemon.log` (the daemon flew there) holds
//!    the daemon configuration it flew with, `ianav.toml` (whose references rule 1 checks).
//! 3. No text file under `docs/`, `tools/` or `tests/`, nor `README.md`, holds a machine path:
//!    a home or work directory or a Windows drive (the patterns of `MACHINE_PATHS`: home,
//!    root's home, macOS users, the work tree of the machine these results were flown on, and
//!    drive C). Not checked, because nothing depends on them: `/tmp/...` output directories in
//!    example commands, and `/dev/...` device names. Binary files (holding a NUL byte: PNG
//!    plots, recordings) are skipped. The patterns are built from pieces below so that this
//!    file, which is scanned too, does not hold them.

use std::fmt::Write as _;
use std::fs;
use std::path::{Component, Path, PathBuf};

/// Machine-path patterns, each split in two so that this file does not contain it.
const MACHINE_PATHS: [[&str; 2]; 5] = [
    ["/ho", "me/"],
    ["/ro", "ot/"],
    ["/Us", "ers/"],
    ["/wo", "rk/"],
    ["C:", "\\"],
];

/// Key words that make a string value a file reference (rule 1).
const FILE_KEY_WORDS: [&str; 4] = ["config", "path", "file", "dir"];

/// Extensions that make a string holding a path separator a file reference (rule 1).
const FILE_EXTENSIONS: [&str; 13] = [
    ".toml", ".bin", ".csv", ".yaml", ".yml", ".json", ".parm", ".param", ".txt", ".log", ".png",
    ".ulg", ".tlog",
];

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every file under `dir`, recursively, in a stable order.
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            match e.file_type() {
                Ok(t) if t.is_dir() => stack.push(p),
                Ok(t) if t.is_file() => out.push(p),
                _ => {}
            }
        }
    }
    out.sort();
    out
}

fn rel(p: &Path) -> String {
    p.strip_prefix(repo_root())
        .unwrap_or(p)
        .display()
        .to_string()
}

/// Whether the string value `v` under key `key` names a file (rule 1).
fn names_a_file(key: &str, v: &str) -> bool {
    if v.is_empty() {
        return false;
    }
    let words_match = key
        .to_ascii_lowercase()
        .split(['_', '-'])
        .any(|w| FILE_KEY_WORDS.contains(&w));
    let lower = v.to_ascii_lowercase();
    let path_like =
        (v.contains('/') || v.contains('\\')) && FILE_EXTENSIONS.iter().any(|e| lower.ends_with(e));
    words_match || path_like
}

/// `base.join(reference)`, normalised lexically; `None` if it climbs above `root`.
fn resolve_inside(root: &Path, base: &Path, reference: &str) -> Option<PathBuf> {
    let mut parts: Vec<Component> = Vec::new();
    let root_depth = root.components().count();
    let joined = base.join(reference);
    for c in joined.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                if parts.len() <= root_depth {
                    return None;
                }
                parts.pop();
            }
            other => parts.push(other),
        }
    }
    let p: PathBuf = parts.iter().collect();
    p.starts_with(root).then_some(p)
}

fn is_absolute_anywhere(v: &str) -> bool {
    let b = v.as_bytes();
    v.starts_with('/')
        || v.starts_with('\\')
        || v.starts_with('~')
        || (b.len() >= 2 && b[0].is_ascii_alphabetic() && b[1] == b':')
}

/// Rule 1 for one string value.
fn check_reference(file: &Path, key_path: &str, key: &str, v: &str, offenders: &mut Vec<String>) {
    if !names_a_file(key, v) {
        return;
    }
    let root = repo_root();
    let at = format!("{}: {key_path} = {v:?}", rel(file));
    if is_absolute_anywhere(v) {
        offenders.push(format!("{at}: absolute path (outside the repository)"));
        return;
    }
    let base = file.parent().unwrap_or(&root);
    match resolve_inside(&root, base, v) {
        None => offenders.push(format!("{at}: resolves outside the repository")),
        Some(p) if !p.is_file() => {
            offenders.push(format!("{at}: no such file ({})", rel(&p)));
        }
        Some(_) => {}
    }
}

fn walk_toml(file: &Path, key_path: &str, key: &str, v: &toml::Value, offenders: &mut Vec<String>) {
    match v {
        toml::Value::String(s) => check_reference(file, key_path, key, s, offenders),
        toml::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                walk_toml(file, &format!("{key_path}[{i}]"), key, x, offenders);
            }
        }
        toml::Value::Table(t) => {
            for (k, x) in t {
                let kp = if key_path.is_empty() {
                    k.clone()
                } else {
                    format!("{key_path}.{k}")
                };
                walk_toml(file, &kp, k, x, offenders);
            }
        }
        _ => {}
    }
}

/// Rules 1 and 2 over `docs/results/`.
fn check_results(offenders: &mut Vec<String>) {
    let results = repo_root().join("docs/results");
    let files = files_under(&results);
    for f in &files {
        if f.extension().is_some_and(|e| e == "toml") {
            let text = match fs::read_to_string(f) {
                Ok(t) => t,
                Err(e) => {
                    offenders.push(format!("{}: unreadable: {e}", rel(f)));
                    continue;
                }
            };
            match text.parse::<toml::Table>() {
                Ok(t) => walk_toml(f, "", "", &toml::Value::Table(t), offenders),
                Err(e) => offenders.push(format!(
                    "{}: not valid TOML: {}",
                    rel(f),
                    e.to_string().lines().next().unwrap_or("")
                )),
            }
        }
        if f.file_name().is_some_and(|n| n == "daemon.log") {
            let dir = f.parent().unwrap_or(&results);
            if !dir.join("ianav.toml").is_file() {
                offenders.push(format!(
                    "{}: the daemon flew here (daemon.log) but its configuration, ianav.toml, \
                     is missing",
                    rel(dir)
                ));
            }
        }
    }
}

/// Rule 3 over one file.
fn check_machine_paths(file: &Path, offenders: &mut Vec<String>) {
    let Ok(bytes) = fs::read(file) else {
        offenders.push(format!("{}: unreadable", rel(file)));
        return;
    };
    if bytes.contains(&0) {
        return; // binary
    }
    let text = String::from_utf8_lossy(&bytes);
    let patterns: Vec<String> = MACHINE_PATHS.iter().map(|p| p.concat()).collect();
    for (n, line) in text.lines().enumerate() {
        if let Some(p) = patterns.iter().find(|p| line.contains(p.as_str())) {
            let excerpt: String = line.trim().chars().take(140).collect();
            offenders.push(format!(
                "{}:{}: machine path {p:?}: {excerpt}",
                rel(file),
                n + 1
            ));
        }
    }
}

#[test]
fn results_and_docs_depend_only_on_the_repository() {
    let root = repo_root();
    let mut offenders = Vec::new();
    check_results(&mut offenders);
    let mut scanned = vec![root.join("README.md")];
    for d in ["docs", "tools", "tests"] {
        scanned.extend(files_under(&root.join(d)));
    }
    for f in &scanned {
        check_machine_paths(f, &mut offenders);
    }
    if !offenders.is_empty() {
        let mut msg = format!(
            "{} offender(s) against the provenance rules (tests/results_provenance.rs):\n",
            offenders.len()
        );
        for o in &offenders {
            let _ = writeln!(msg, "  {o}");
        }
        panic!("{msg}");
    }
}

#[test]
fn the_rules_catch_what_they_should() {
    assert!(names_a_file("ins_config", "ins.toml"));
    assert!(names_a_file("path", "x"));
    assert!(names_a_file("out_dir", "flights"));
    assert!(names_a_file("note", "see ../x/flight.csv"));
    assert!(!names_a_file("connection", "udpin:127.0.0.1:14550"));
    assert!(!names_a_file("signing_key", ""));
    assert!(!names_a_file("path", ""));
    assert!(!names_a_file("statustext", "xaccel = -0.0 m/s/s"));
    assert!(!names_a_file("daemon_gnss_lag_s", "n/a"));
    assert!(is_absolute_anywhere("/x/ins.toml"));
    assert!(is_absolute_anywhere("~/ins.toml"));
    assert!(is_absolute_anywhere(&["C:", "\\x\\ins.toml"].concat()));
    assert!(!is_absolute_anywhere("ins.toml"));
    let root = Path::new("/r");
    let base = Path::new("/r/docs/results/a");
    assert_eq!(
        resolve_inside(root, base, "../../../config/ins.toml"),
        Some(PathBuf::from("/r/config/ins.toml"))
    );
    assert_eq!(resolve_inside(root, base, "../../../../ins.toml"), None);
    assert_eq!(
        resolve_inside(root, base, "./ins.toml"),
        Some(PathBuf::from("/r/docs/results/a/ins.toml"))
    );
}
