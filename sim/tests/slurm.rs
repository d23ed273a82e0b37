//! The Monte Carlo job array on a real one-node Slurm (tools/slurm/, docs/MONTECARLO.md
//! "Slurm"), as a user runs it: start Slurm from Debian's packages
//! (`tools/slurm/local-cluster.sh`, on 127.0.0.1), submit `tools/slurm/mc-array.sh` as an
//! array of 4 tasks into one shared directory, cancel one task after its first run, read
//! `report --status` of the partial batch, resubmit that task, merge with `report`, and compare
//! with `mc` of the same seeds on one machine: the same run files and the same report, byte for
//! byte.
//!
//! Without the Slurm and MUNGE programs (`local-cluster.sh install` puts them in) the test says
//! SKIP and passes, unless `IANAV_REQUIRE_SLURM=1` (as `.ci/run` sets), where it fails.

#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

/// The batch: 4 shards of 5 seeds, short INS-only flights (a few tenths of a second of CPU
/// each), long enough that the cancelled task still has runs to fly.
const SHARDS: u32 = 4;
const MC_OPTIONS: [&str; 6] = ["--scenario", "2", "--seeds", "1..=20", "--duration", "300"];
/// The task cancelled, and its seeds (the k-th seed goes to shard k mod 4 + 1).
const KILLED: u32 = 2;
const KILLED_SEEDS: [u64; 5] = [2, 6, 10, 14, 18];
/// Bound of the whole test, Slurm's start and both batches included.
const DEADLINE: Duration = Duration::from_secs(300);

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The one-node cluster of this test: started in its own directory, stopped when dropped
/// (also when the test fails).
struct Cluster {
    dir: PathBuf,
    script: PathBuf,
}

impl Cluster {
    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", self.dir.join("slurm.conf"));
        c
    }

    fn run(&self, program: &str, args: &[&str]) -> Output {
        self.command(program).args(args).output().unwrap()
    }

    fn local_cluster(dir: &Path, script: &Path, action: &str) -> Output {
        Command::new("bash")
            .arg(script)
            .arg(action)
            .env("IANAV_SLURM_DIR", dir)
            .output()
            .unwrap()
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let out = Self::local_cluster(&self.dir, &self.script, "stop");
        if !out.status.success() {
            eprintln!("stopping Slurm: {}", text(&out.stderr));
        }
    }
}

/// Skip (or fail, where Slurm is required) with `why`.
fn skip(why: &str) {
    assert!(
        std::env::var("IANAV_REQUIRE_SLURM").as_deref() != Ok("1"),
        "IANAV_REQUIRE_SLURM=1 and {why}"
    );
    eprintln!("SKIP slurm_array: {why}");
}

/// Array task index → state (`scontrol show job`, while the controller keeps the job).
fn task_states(cluster: &Cluster, job: &str) -> BTreeMap<u32, String> {
    let out = cluster.run("scontrol", &["-o", "show", "job", job]);
    let mut states = BTreeMap::new();
    for line in text(&out.stdout).lines() {
        let field = |key: &str| {
            line.split_whitespace()
                .find_map(|f| f.strip_prefix(key))
                .map(str::to_owned)
        };
        if let (Some(task), Some(state)) = (field("ArrayTaskId="), field("JobState=")) {
            // A pending array's record holds its tasks as a range (`1-4`); skip it.
            if let Ok(task) = task.parse() {
                states.insert(task, state);
            }
        }
    }
    states
}

/// Wait until no task of `job` is pending or running.
fn wait_for_job(cluster: &Cluster, job: &str, started: Instant) {
    loop {
        let out = cluster.run("squeue", &["-h", "-j", job, "-o", "%i %T"]);
        let listed = text(&out.stdout);
        if listed.trim().is_empty() {
            return;
        }
        assert!(
            started.elapsed() < DEADLINE,
            "job {job} still queued after {DEADLINE:?}:\n{listed}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Submit the shipped array script (the guide's command) and return the job id.
fn submit(cluster: &Cluster, work: &Path, out: &Path, array: &str) -> String {
    let script = repo_root().join("tools/slurm/mc-array.sh");
    let o = cluster
        .command("sbatch")
        .env("IANAV_SIM", env!("CARGO_BIN_EXE_ianav-sim"))
        .args(["--parsable", &format!("--array={array}")])
        .arg(format!("--output={}/logs/mc_%A_%a.log", out.display()))
        .arg(format!("--chdir={}", work.display()))
        .arg(&script)
        .arg(SHARDS.to_string())
        .arg(out)
        .args(MC_OPTIONS)
        .output()
        .unwrap();
    assert!(o.status.success(), "sbatch: {}", text(&o.stderr));
    let id = text(&o.stdout);
    id.trim().split(';').next().unwrap().to_owned()
}

/// The run files of `dir` (name → bytes); temporary files of a killed task are not runs.
fn run_files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir.join("runs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&p).unwrap())
        })
        .collect()
}

fn sim(args: &[&str], dirs: &[&Path]) -> Output {
    let o = Command::new(env!("CARGO_BIN_EXE_ianav-sim"))
        .args(args)
        .args(dirs)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "ianav-sim {args:?}: {}",
        text(&o.stderr)
    );
    o
}

#[test]
fn slurm_array_killed_task_resubmitted_merges_as_one_machine() {
    let started = Instant::now();
    let script = repo_root().join("tools/slurm/local-cluster.sh");
    let found = Command::new("sh")
        .args([
            "-c",
            "PATH=$PATH:/usr/sbin:/sbin command -v slurmctld slurmd sbatch munged",
        ])
        .output()
        .unwrap();
    if !found.status.success() {
        skip("Slurm or MUNGE is not installed (tools/slurm/local-cluster.sh install)");
        return;
    }
    let base = std::env::temp_dir().join(format!("ianav-slurm-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&base);
    let (dir, work) = (base.join("slurm"), base.join("work"));
    std::fs::create_dir_all(&work).unwrap();
    let up = Cluster::local_cluster(&dir, &script, "start");
    let cluster = Cluster {
        dir: dir.clone(),
        script,
    };
    if !up.status.success() {
        skip(&format!(
            "Slurm did not start (root is needed to start munged):\n{}{}",
            text(&up.stdout),
            text(&up.stderr)
        ));
        return;
    }
    eprintln!("Slurm up in {:.1} s", started.elapsed().as_secs_f64());
    let out = work.join("mc");
    std::fs::create_dir_all(out.join("logs")).unwrap();

    // The array; cancel task 2 once its first run file is written.
    let job = submit(&cluster, &work, &out, &format!("1-{SHARDS}"));
    let first = out.join(format!("runs/run_{:04}.csv", KILLED_SEEDS[0]));
    while !first.exists() {
        assert!(
            started.elapsed() < DEADLINE,
            "no run file from task {KILLED}: {:?}",
            task_states(&cluster, &job)
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = cluster.run("scancel", &[&format!("{job}_{KILLED}")]);
    assert!(o.status.success(), "scancel: {}", text(&o.stderr));
    wait_for_job(&cluster, &job, started);
    let states = task_states(&cluster, &job);
    eprintln!("array {job} after the cancel: {states:?}");
    assert_eq!(
        states.get(&KILLED).map(String::as_str),
        Some("CANCELLED"),
        "{states:?}"
    );
    for task in (1..=SHARDS).filter(|&t| t != KILLED) {
        assert_eq!(
            states.get(&task).map(String::as_str),
            Some("COMPLETED"),
            "{states:?}"
        );
    }
    let killed_left: Vec<u64> = KILLED_SEEDS
        .into_iter()
        .filter(|s| !out.join(format!("runs/run_{s:04}.csv")).exists())
        .collect();
    assert!(
        !killed_left.is_empty(),
        "task {KILLED} flew all its runs before it was cancelled: nothing to resume"
    );

    // The status of the partial batch names the cancelled shard and its missing seeds.
    let status = text(&sim(&["report", "--status"], &[&out]).stdout);
    eprintln!("{status}");
    let lines: Vec<&str> = status.lines().collect();
    let shard_line = |task: u32| {
        lines
            .iter()
            .position(|l| l.starts_with(&format!("{task}/{SHARDS} ")))
            .unwrap_or_else(|| panic!("no line for shard {task}:\n{status}"))
    };
    // The shard's line, then its seeds to fly.
    let listed = lines[shard_line(KILLED) + 1]
        .trim()
        .strip_prefix("seeds to fly: ")
        .unwrap_or_else(|| panic!("no seeds to fly under shard {KILLED}:\n{status}"));
    let expected: Vec<String> = killed_left.iter().map(u64::to_string).collect();
    assert_eq!(listed, expected.join(", "), "{status}");
    assert!(
        status.contains(&format!("shards with runs to fly: {KILLED} ")),
        "{status}"
    );
    for task in (1..=SHARDS).filter(|&t| t != KILLED) {
        let state = lines[shard_line(task)].split_whitespace().nth(4);
        assert_eq!(state, Some("ended"), "{status}");
    }
    // A report of the partial batch says what is missing.
    let partial = sim(&["report", "--out"], &[&work.join("partial"), &out]);
    assert!(
        text(&partial.stderr).contains("incomplete batch"),
        "{}",
        text(&partial.stderr)
    );

    // Resubmit the cancelled task, as the guide says; it flies only the missing runs.
    let again = submit(&cluster, &work, &out, &KILLED.to_string());
    wait_for_job(&cluster, &again, started);
    let states = task_states(&cluster, &again);
    assert_eq!(
        states.get(&KILLED).map(String::as_str),
        Some("COMPLETED"),
        "{states:?}"
    );
    let log = std::fs::read_to_string(out.join(format!("logs/mc_{again}_{KILLED}.log"))).unwrap();
    eprintln!("{log}");
    for seed in KILLED_SEEDS {
        let how = if killed_left.contains(&seed) {
            "completed in"
        } else {
            "kept"
        };
        assert!(
            log.contains(&format!(
                "zone none shard {KILLED}/{SHARDS}: seed {seed} {how}"
            )),
            "seed {seed} should be {how}:\n{log}"
        );
    }
    assert!(
        log.contains(&format!("[{}/5 runs", KILLED_SEEDS.len())),
        "{log}"
    );
    let status = text(&sim(&["report", "--status"], &[&out]).stdout);
    assert!(status.contains("complete: "), "{status}");

    // Merge, and compare with the same seeds flown on one machine.
    let merged = sim(&["report"], &[&out]);
    assert!(text(&merged.stderr).is_empty(), "{}", text(&merged.stderr));
    let one = work.join("one");
    let mut args = vec!["mc", "--jobs", "2"];
    args.extend(MC_OPTIONS);
    args.push("--out");
    sim(&args, &[&one]);
    sim(&["report"], &[&one]);
    let (runs, runs_one) = (run_files(&out), run_files(&one));
    assert_eq!(runs.len(), 20);
    assert!(runs == runs_one, "the run files differ from one machine's");
    for file in ["report.md", "nse_timeseries.csv", "nse_horizontal_m.png"] {
        assert!(
            std::fs::read(out.join(file)).unwrap() == std::fs::read(one.join(file)).unwrap(),
            "{file} differs from one machine's"
        );
    }
    eprintln!(
        "slurm array test done in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    drop(cluster);
    let _ = std::fs::remove_dir_all(&base);
}
