//! A batch in progress, on any engine (one machine, a Slurm array, a Kubernetes indexed Job):
//! the plan each shard writes when it starts, and the status read back from the directory
//! alone — plans, manifests and run files (`ianav-sim report --status`, docs/MONTECARLO.md).
//!
//! A shard's state comes from its files: no plan and no manifest, it has not started; a plan
//! newer than its manifest (or no manifest), it started and has not ended (it flies, waits, or
//! died: only the engine knows); a manifest at least as new as its plan, it ended. Each seed is
//! done, failed, or to fly (no run file, or one that `--resume` would fly again). The time left
//! is estimated from the run files' modification times.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use serde::{Deserialize, Serialize};

use super::{
    Batch, Manifest, McError, RUNS_DIR, RunOutcome, RunRecord, RunSpec, Shard, io_error,
    manifest_name, seed_of_file_name,
};
use crate::flight::RatesConfig;

/// What a shard (or a whole batch) flies: `mc.plan.toml` or `mc_shard_2of4.plan.toml`,
/// written when it starts. Like the manifest, nothing machine-dependent (no times, paths or
/// thread counts): the same command writes the same plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Program and version.
    pub generator: String,
    /// Scenario name.
    pub scenario_name: String,
    /// What every run file holds.
    #[serde(flatten)]
    pub spec: RunSpec,
    /// Number of seeds of the whole batch.
    pub batch_runs: usize,
    /// First and last seed of the whole batch (seed lists are ranges).
    pub batch_seed_range: [u64; 2],
    /// Shard `i/n`, if sharded.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub shard: Option<String>,
    /// The seeds this shard flies.
    pub seeds: Vec<u64>,
}

impl Plan {
    /// The plan of `batch`.
    pub fn of(batch: &Batch, spec: &RunSpec) -> Self {
        Self {
            generator: format!("ianav-sim {}", env!("CARGO_PKG_VERSION")),
            scenario_name: batch.setup.scenario.name.clone(),
            spec: spec.clone(),
            batch_runs: batch.seeds.len(),
            batch_seed_range: [
                batch.seeds.iter().copied().min().unwrap_or(0),
                batch.seeds.iter().copied().max().unwrap_or(0),
            ],
            shard: batch.shard.map(|s| s.to_string()),
            seeds: batch.seeds_to_fly(),
        }
    }
}

/// Plan file name of `shard` (of the whole batch if `None`).
pub fn plan_name(shard: Option<Shard>) -> String {
    manifest_name(shard).replace(".toml", ".plan.toml")
}

/// The batch directories of `dirs`: each is one (it holds `runs/`) or a parent whose
/// immediate subdirectories are (shards copied side by side), in name order.
pub fn batch_dirs(dirs: &[PathBuf]) -> Result<Vec<PathBuf>, McError> {
    let mut out = Vec::new();
    for dir in dirs {
        if dir.join(RUNS_DIR).is_dir() {
            out.push(dir.clone());
            continue;
        }
        let mut subs: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_error(dir))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join(RUNS_DIR).is_dir())
            .collect();
        subs.sort();
        out.extend(subs);
    }
    Ok(out)
}

/// Which batch a plan or manifest belongs to: shards of one batch share all of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct BatchKey {
    first: u64,
    last: u64,
    shards: u32,
    scenario: u8,
    duration_ms: i64,
}

/// The least time between a shard's start and its latest run that measures a rate, s.
const MIN_MEASURED_S: f64 = 1.0;

/// A plan or manifest found.
struct Found {
    key: BatchKey,
    shard: Option<Shard>,
    scenario_name: String,
    duration_s: f64,
    /// The plan's run spec (manifests do not hold the navigation and the visual systems).
    spec: Option<RunSpec>,
    modified: SystemTime,
}

/// How a shard stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardState {
    /// Neither plan nor manifest: not started (queued, or never submitted).
    NotStarted,
    /// A plan and no newer manifest: flying, waiting, or dead.
    Started,
    /// A manifest at least as new as its plan.
    Ended,
}

/// One shard of a batch (the whole batch when it is not sharded).
#[derive(Debug, Clone, PartialEq)]
pub struct ShardStatus {
    /// Its number, `None` for an unsharded batch.
    pub shard: Option<Shard>,
    /// Its state.
    pub state: ShardState,
    /// Seeds with a whole completed run.
    pub done: Vec<u64>,
    /// Seeds whose run failed (kept by `--resume`; the report lists them).
    pub failed: Vec<u64>,
    /// Seeds to fly: no run file, or (with the reason) one that `--resume` flies again.
    pub to_fly: Vec<(u64, Option<String>)>,
    /// When its plan was written (its latest start), if it started.
    pub started: Option<SystemTime>,
    /// Run files of its seeds written since then.
    pub flown_since_start: usize,
    /// Modification time of its latest run file written since its start.
    pub last_run: Option<SystemTime>,
}

impl ShardStatus {
    /// Mean wall time between runs since the shard's start, s (its rate: with several jobs, a
    /// fraction of one run's flight). `None` below a second in all: a fresh copy or checkout
    /// gives the plan and its runs one time, which measures no rate.
    fn per_run_s(&self) -> Option<f64> {
        let (start, last) = (self.started?, self.last_run?);
        let elapsed = last.duration_since(start).ok()?.as_secs_f64();
        (self.flown_since_start > 0 && elapsed >= MIN_MEASURED_S)
            .then(|| elapsed / self.flown_since_start as f64)
    }
}

/// One batch found in the directories.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchStatus {
    /// Scenario number and name.
    pub scenario: u8,
    /// Scenario name.
    pub scenario_name: String,
    /// Mission duration, s.
    pub duration_s: f64,
    /// First and last seed.
    pub seed_range: [u64; 2],
    /// Its shards, in order.
    pub shards: Vec<ShardStatus>,
}

/// The estimate of the time left.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeLeft {
    /// Seconds until the last shard ends.
    pub seconds: f64,
    /// Mean wall time between runs of a shard, s, from the run files' times.
    pub per_run_s: f64,
}

impl BatchStatus {
    /// Counts over the shards: done, failed, to fly.
    pub fn totals(&self) -> (usize, usize, usize) {
        self.shards.iter().fold((0, 0, 0), |(d, f, m), s| {
            (d + s.done.len(), f + s.failed.len(), m + s.to_fly.len())
        })
    }

    /// Every seed to fly, in order.
    pub fn to_fly(&self) -> Vec<u64> {
        let mut seeds: Vec<u64> = self
            .shards
            .iter()
            .flat_map(|s| s.to_fly.iter().map(|(seed, _)| *seed))
            .collect();
        seeds.sort_unstable();
        seeds
    }

    /// The time left if every shard with runs to fly flies from now on, in parallel, at its
    /// own measured rate (or the mean rate of the shards measured, for one not yet measured).
    /// `None` when no shard has measured its pace (a run a second or more after its start).
    pub fn time_left(&self) -> Option<TimeLeft> {
        let rates: Vec<f64> = self
            .shards
            .iter()
            .filter_map(ShardStatus::per_run_s)
            .collect();
        let all_done = self.shards.iter().all(|s| s.to_fly.is_empty());
        if rates.is_empty() {
            return all_done.then_some(TimeLeft {
                seconds: 0.0,
                per_run_s: f64::NAN,
            });
        }
        let mean = rates.iter().sum::<f64>() / rates.len() as f64;
        let seconds = self
            .shards
            .iter()
            .map(|s| s.to_fly.len() as f64 * s.per_run_s().unwrap_or(mean))
            .fold(0.0, f64::max);
        Some(TimeLeft {
            seconds,
            per_run_s: mean,
        })
    }
}

/// What the directories hold.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// The batches planned (usually one), in order of seed range.
    pub batches: Vec<BatchStatus>,
    /// Seeds of run files that belong to no plan or manifest (all of them for a batch flown
    /// before plan files existed), with their outcome: `Ok(true)` done, `Ok(false)` failed,
    /// `Err` unreadable or cut short.
    pub unplanned: BTreeMap<u64, Result<bool, String>>,
    /// Plans or manifests that could not be read.
    pub unreadable: Vec<String>,
}

/// A run file found, with its modification time.
struct RunFile {
    path: PathBuf,
    modified: Option<SystemTime>,
}

fn modified(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// The plans and manifests of `dir`; unreadable ones are named in `unreadable`.
fn read_plans(dir: &Path, found: &mut Vec<Found>, unreadable: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for path in paths {
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        if !(name.starts_with("mc") && name.ends_with(".toml")) {
            continue;
        }
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) => {
                unreadable.push(format!("{}: {e}", path.display()));
                continue;
            }
        };
        let parsed = if name.ends_with(".plan.toml") {
            toml::from_str::<Plan>(&text).map(|p| {
                (
                    p.spec.scenario,
                    p.scenario_name,
                    p.spec.duration_s,
                    p.batch_seed_range,
                    p.shard,
                    Some(p.spec),
                )
            })
        } else {
            toml::from_str::<Manifest>(&text).map(|m| {
                (
                    m.scenario,
                    m.scenario_name,
                    m.duration_s,
                    m.batch_seed_range,
                    m.shard,
                    None,
                )
            })
        };
        let (scenario, scenario_name, duration_s, [first, last], shard, spec) = match parsed {
            Ok(p) => p,
            Err(e) => {
                unreadable.push(format!("{}: {e}", path.display()));
                continue;
            }
        };
        let shard = match shard.as_deref().map(str::parse::<Shard>).transpose() {
            Ok(s) => s,
            Err(e) => {
                unreadable.push(format!("{}: {e}", path.display()));
                continue;
            }
        };
        found.push(Found {
            key: BatchKey {
                first,
                last,
                shards: shard.map_or(1, |s| s.count),
                scenario,
                duration_ms: (duration_s * 1000.0).round() as i64,
            },
            shard,
            scenario_name,
            duration_s,
            spec,
            modified: modified(&path).unwrap_or(SystemTime::UNIX_EPOCH),
        });
    }
}

/// Whether the run file of `seed` holds a whole run of the batch: `Ok(true)` completed,
/// `Ok(false)` failed, `Err` why `--resume` flies it again.
fn judge(file: &RunFile, seed: u64, spec: &RunSpec) -> Result<bool, String> {
    let text = std::fs::read_to_string(&file.path).map_err(|e| e.to_string())?;
    let record = RunRecord::parse(&text).map_err(|e| format!("unreadable ({e})"))?;
    spec.check(&record, seed, RatesConfig::default().output_period_s)?;
    Ok(matches!(record.outcome, RunOutcome::Completed { .. }))
}

/// The status of the batches of `dirs` (batch directories, or parents of shard directories, as
/// `ianav-sim report` takes them).
pub fn status(dirs: &[PathBuf]) -> Result<Status, McError> {
    let mut found = Vec::new();
    let mut unreadable = Vec::new();
    let mut runs: BTreeMap<u64, RunFile> = BTreeMap::new();
    for dir in batch_dirs(dirs)? {
        read_plans(&dir, &mut found, &mut unreadable);
        let runs_dir = dir.join(RUNS_DIR);
        for entry in std::fs::read_dir(&runs_dir).map_err(io_error(&runs_dir))? {
            let path = entry.map_err(io_error(&runs_dir))?.path();
            let seed = path
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(seed_of_file_name);
            if let Some(seed) = seed {
                // The first directory's file: `report` refuses two different files of a seed.
                runs.entry(seed).or_insert_with(|| RunFile {
                    modified: modified(&path),
                    path,
                });
            }
        }
    }
    let mut keys: Vec<BatchKey> = found.iter().map(|f| f.key).collect();
    keys.sort();
    keys.dedup();
    let mut planned = std::collections::BTreeSet::new();
    let mut batches = Vec::new();
    for key in keys {
        let of_batch: Vec<&Found> = found.iter().filter(|f| f.key == key).collect();
        let Some(first) = of_batch.first() else {
            continue;
        };
        // A manifest tells only the scenario and the duration: check what it tells.
        let spec = of_batch
            .iter()
            .find_map(|f| f.spec.clone())
            .unwrap_or(RunSpec {
                scenario: key.scenario,
                navigation: crate::flight::NavigationMode::Ins,
                duration_s: first.duration_s,
                vision_systems: Vec::new(),
            });
        let has_spec = of_batch.iter().any(|f| f.spec.is_some());
        let seeds: Vec<u64> = (key.first..=key.last).collect();
        planned.extend(seeds.iter().copied());
        let shard_list: Vec<Option<Shard>> = if key.shards > 1 || of_batch[0].shard.is_some() {
            (1..=key.shards)
                .map(|index| {
                    Some(Shard {
                        index,
                        count: key.shards,
                    })
                })
                .collect()
        } else {
            vec![None]
        };
        let mut shards = Vec::new();
        for shard in shard_list {
            let latest = |plan: bool| {
                of_batch
                    .iter()
                    .filter(|f| f.shard == shard && f.spec.is_some() == plan)
                    .map(|f| f.modified)
                    .max()
            };
            let (plan, manifest) = (latest(true), latest(false));
            let state = match (plan, manifest) {
                (_, Some(m)) if plan.is_none_or(|p| m >= p) => ShardState::Ended,
                (Some(_), _) => ShardState::Started,
                (None, _) => ShardState::NotStarted,
            };
            let mut s = ShardStatus {
                shard,
                state,
                done: Vec::new(),
                failed: Vec::new(),
                to_fly: Vec::new(),
                started: plan,
                flown_since_start: 0,
                last_run: None,
            };
            let own = shard.map_or_else(|| seeds.clone(), |sh| sh.select(&seeds));
            for seed in own {
                let Some(file) = runs.get(&seed) else {
                    s.to_fly.push((seed, None));
                    continue;
                };
                let verdict = if has_spec {
                    judge(file, seed, &spec)
                } else {
                    judge_without_spec(file, seed, &spec)
                };
                match verdict {
                    Ok(true) => s.done.push(seed),
                    Ok(false) => s.failed.push(seed),
                    Err(reason) => {
                        s.to_fly.push((seed, Some(reason)));
                        continue;
                    }
                }
                if let (Some(start), Some(m)) = (plan, file.modified)
                    && m >= start
                {
                    s.flown_since_start += 1;
                    s.last_run = s.last_run.max(Some(m));
                }
            }
            shards.push(s);
        }
        batches.push(BatchStatus {
            scenario: key.scenario,
            scenario_name: first.scenario_name.clone(),
            duration_s: first.duration_s,
            seed_range: [key.first, key.last],
            shards,
        });
    }
    let unplanned = runs
        .iter()
        .filter(|(seed, _)| !planned.contains(*seed))
        .map(|(&seed, file)| {
            let verdict = std::fs::read_to_string(&file.path)
                .map_err(|e| e.to_string())
                .and_then(|t| RunRecord::parse(&t))
                .and_then(|r| {
                    r.incomplete(RatesConfig::default().output_period_s)
                        .map_or(Ok(r), Err)
                })
                .map(|r| matches!(r.outcome, RunOutcome::Completed { .. }));
            (seed, verdict)
        })
        .collect();
    Ok(Status {
        batches,
        unplanned,
        unreadable,
    })
}

/// [`judge`] for batches known from manifests only (flown before plan files): the scenario,
/// the duration and the file's own completeness.
fn judge_without_spec(file: &RunFile, seed: u64, spec: &RunSpec) -> Result<bool, String> {
    let text = std::fs::read_to_string(&file.path).map_err(|e| e.to_string())?;
    let record = RunRecord::parse(&text).map_err(|e| format!("unreadable ({e})"))?;
    let as_planned = RunSpec {
        navigation: record.navigation,
        vision_systems: match &record.outcome {
            RunOutcome::Completed { vision, .. } => {
                vision.iter().map(|v| v.system.clone()).collect()
            }
            RunOutcome::Failed { .. } => Vec::new(),
        },
        ..spec.clone()
    };
    judge(file, seed, &as_planned)
}

/// Every seed planned by the plans and manifests of `dirs` (empty if there are none: a batch
/// flown before plan files, or no `mc` output).
pub fn planned_seeds(dirs: &[PathBuf]) -> Result<Vec<u64>, McError> {
    let mut found = Vec::new();
    let mut unreadable = Vec::new();
    for dir in batch_dirs(dirs)? {
        read_plans(&dir, &mut found, &mut unreadable);
    }
    let mut seeds: Vec<u64> = found
        .iter()
        .flat_map(|f| f.key.first..=f.key.last)
        .collect();
    seeds.sort_unstable();
    seeds.dedup();
    Ok(seeds)
}

/// `1 h 02 min`, `3 min 20 s`, `12 s`, `0.4 s`.
pub fn format_duration(seconds: f64) -> String {
    if seconds < 9.95 {
        return format!("{:.1} s", seconds.max(0.0));
    }
    let s = seconds.round() as u64;
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

/// A started shard without a new run for this many times its pace, and at least
/// [`STALLED_MIN_S`], is marked "stalled?".
const STALLED_RUNS: f64 = 5.0;
/// See [`STALLED_RUNS`], s.
const STALLED_MIN_S: f64 = 60.0;

/// At most `max` seeds, then how many more.
fn seed_list(seeds: impl Iterator<Item = u64>, max: usize) -> String {
    let all: Vec<u64> = seeds.collect();
    let mut t = all
        .iter()
        .take(max)
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    if all.len() > max {
        let _ = write!(t, ", … ({} more)", all.len() - max);
    }
    if t.is_empty() { "–".into() } else { t }
}

fn age(now: SystemTime, then: SystemTime) -> String {
    format_duration(now.duration_since(then).map_or(0.0, |d| d.as_secs_f64()))
}

impl Status {
    /// The status as text: per batch, one line per shard (state, done, failed, to fly and
    /// which seeds), totals, the files to fly again with why, and the time left.
    pub fn render(&self, now: SystemTime) -> String {
        let mut t = String::new();
        for b in &self.batches {
            let count = b.shards.len();
            let _ = writeln!(
                t,
                "scenario {} ({}), {} s, seeds {}..={}{}",
                b.scenario,
                b.scenario_name,
                crate::metrics::format_fixed(b.duration_s, 1),
                b.seed_range[0],
                b.seed_range[1],
                if b.shards.iter().any(|s| s.shard.is_some()) {
                    format!(" in {count} shards")
                } else {
                    String::new()
                }
            );
            let _ = writeln!(
                t,
                "{:<9} {:>5} {:>6} {:>6}  state",
                "shard", "done", "failed", "to fly"
            );
            let mean_pace = b.time_left().map(|l| l.per_run_s);
            for s in &b.shards {
                let state = match (s.state, s.started) {
                    (ShardState::NotStarted, _) => "not started".to_owned(),
                    (ShardState::Ended, _) => "ended".to_owned(),
                    (ShardState::Started, None) => "started".to_owned(),
                    (ShardState::Started, Some(start)) => {
                        let quiet_since = s.last_run.unwrap_or(start);
                        let quiet = now
                            .duration_since(quiet_since)
                            .map_or(0.0, |d| d.as_secs_f64());
                        // Quiet for many runs' time: the task probably died (the engine knows).
                        let stalled = s
                            .per_run_s()
                            .or(mean_pace)
                            .is_some_and(|pace| quiet > (STALLED_RUNS * pace).max(STALLED_MIN_S));
                        format!(
                            "started {} ago, {}{}",
                            age(now, start),
                            s.last_run.map_or("no run yet".to_owned(), |last| format!(
                                "last run {} ago",
                                age(now, last)
                            )),
                            if stalled { ": stalled?" } else { "" }
                        )
                    }
                };
                let _ = writeln!(
                    t,
                    "{:<9} {:>5} {:>6} {:>6}  {state}",
                    s.shard.map_or("all".to_owned(), |x| x.to_string()),
                    s.done.len(),
                    s.failed.len(),
                    s.to_fly.len(),
                );
                if !s.to_fly.is_empty() {
                    let _ = writeln!(
                        t,
                        "          seeds to fly: {}",
                        seed_list(s.to_fly.iter().map(|(seed, _)| *seed), 20)
                    );
                }
            }
            let (done, failed, to_fly) = b.totals();
            let _ = writeln!(t, "{:<9} {done:>5} {failed:>6} {to_fly:>6}", "total");
            for s in &b.shards {
                for (seed, reason) in &s.to_fly {
                    if let Some(reason) = reason {
                        let _ = writeln!(
                            t,
                            "  {}: not a whole run of this batch: {reason} (--resume flies it again)",
                            super::run_file_name(*seed)
                        );
                    }
                }
            }
            if to_fly == 0 {
                let _ = writeln!(t, "complete: `ianav-sim report` merges it");
            } else {
                let shards: Vec<String> = b
                    .shards
                    .iter()
                    .filter(|s| !s.to_fly.is_empty())
                    .map(|s| s.shard.map_or("all".to_owned(), |x| x.index.to_string()))
                    .collect();
                let _ = writeln!(
                    t,
                    "shards with runs to fly: {} (once they no longer run, fly them again with \
                     `--resume`; on Slurm, resubmit these array indexes)",
                    shards.join(",")
                );
                match b.time_left() {
                    Some(left) => {
                        let _ = writeln!(
                            t,
                            "time left ≈ {} if these shards fly from now on, in parallel (one run \
                             every {} per shard, measured from the run files' times)",
                            format_duration(left.seconds),
                            format_duration(left.per_run_s)
                        );
                    }
                    None => {
                        let _ = writeln!(
                            t,
                            "time left: unknown (no shard has written a run a second or more after its start)"
                        );
                    }
                }
            }
            t.push('\n');
        }
        if !self.unplanned.is_empty() {
            let done = self.unplanned.values().filter(|v| v == &&Ok(true)).count();
            let failed = self.unplanned.values().filter(|v| v == &&Ok(false)).count();
            let bad: Vec<String> = self
                .unplanned
                .iter()
                .filter_map(|(seed, v)| v.as_ref().err().map(|e| format!("{seed} ({e})")))
                .collect();
            let _ = writeln!(
                t,
                "{} run files of seeds that no plan or manifest names (flown before plan files \
                 existed: the seed list of their batch is unknown): {done} done, {failed} \
                 failed{}",
                self.unplanned.len(),
                if bad.is_empty() {
                    String::new()
                } else {
                    format!(", not whole: {}", bad.join(", "))
                }
            );
        }
        if self.batches.is_empty() && self.unplanned.is_empty() {
            let _ = writeln!(t, "no plan, manifest or run file");
        }
        for u in &self.unreadable {
            let _ = writeln!(t, "unreadable: {u}");
        }
        t
    }
}
