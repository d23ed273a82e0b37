//! Monte Carlo batches (the paper's 100 runs per scenario, docs/REFERENCES.md P1, A6.1 and
//! A6.4): fly one scenario for a list of seeds in parallel, record the navigation system
//! error of each run (`crate::metrics`) in its own file so that shards flown on different
//! machines merge by copying files, and write a manifest of the batch.
//!
//! Layout of an output directory (`docs/MONTECARLO.md`):
//! - `runs/run_0007.csv`: one file per seed, written atomically when the run ends;
//! - `mc.plan.toml` (or `mc_shard_1of4.plan.toml`): what a shard flies, written when it
//!   starts (`status.rs` reads the plans back to tell a batch in progress);
//! - `mc.toml` (or `mc_shard_1of4.toml` for a shard): what was run and how it ended.

use std::io;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::flight::{Flight, FlightSetup, NavigationMode};
use crate::metrics::MetricsRecorder;

mod run_file;
pub mod status;

use run_file::seed_of_file_name;
pub use run_file::{
    AidingRun, RUN_COLUMNS, RUN_FILE_MAGIC, RUN_VISION_COLUMNS, RunOutcome, RunRecord, VisionRun,
    navigation_name, run_file_name,
};

/// Directory of the per-run files inside a batch directory.
pub const RUNS_DIR: &str = "runs";

/// Errors of a Monte Carlo batch (a failing *flight* is not one: it is a failed run).
#[derive(Debug, thiserror::Error)]
pub enum McError {
    /// `--seeds` is not an inclusive range.
    #[error("--seeds `{0}`: expected an inclusive range A..B (or A..=B) of seeds with A ≤ B")]
    SeedRange(String),
    /// `--shard` is not `i/n` with `1 ≤ i ≤ n`.
    #[error("--shard `{0}`: expected i/n with 1 ≤ i ≤ n (shards are numbered from 1)")]
    Shard(String),
    /// `--runs` disagrees with `--seeds`, or neither is given, or the list is empty.
    #[error("seeds: {0}")]
    Seeds(String),
    /// File system failure, with the file concerned.
    #[error("{path}: {source}")]
    Io {
        /// File or directory.
        path: String,
        /// Cause.
        source: io::Error,
    },
    /// The output directory already holds runs of another batch.
    #[error(
        "{path} holds the run of seed {seed}, which is not in this batch: use a fresh --out directory"
    )]
    ForeignRun {
        /// Directory of run files.
        path: String,
        /// Seed of the foreign run.
        seed: u64,
    },
    /// The thread pool could not be built.
    #[error("thread pool: {0}")]
    Pool(String),
    /// The manifest could not be serialised.
    #[error("manifest: {0}")]
    Manifest(#[from] toml::ser::Error),
}

fn io_error(path: &Path) -> impl FnOnce(io::Error) -> McError + '_ {
    move |source| McError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// An inclusive range of seeds, written `A..B` or `A..=B` (both inclusive, as the paper's
/// "seed orders 1…100").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SeedRange {
    /// First seed.
    pub first: u64,
    /// Last seed (included).
    pub last: u64,
}

impl FromStr for SeedRange {
    type Err = McError;
    fn from_str(s: &str) -> Result<Self, McError> {
        let bad = || McError::SeedRange(s.to_owned());
        let (a, b) = s.split_once("..").ok_or_else(bad)?;
        let b = b.strip_prefix('=').unwrap_or(b);
        let first: u64 = a.trim().parse().map_err(|_| bad())?;
        let last: u64 = b.trim().parse().map_err(|_| bad())?;
        if first > last {
            return Err(bad());
        }
        Ok(Self { first, last })
    }
}

impl std::fmt::Display for SeedRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}..={}", self.first, self.last)
    }
}

/// Shard `index` of `count` (1-based): the k-th seed of the batch list (k from 0) belongs to
/// shard `k mod count + 1`, so shards are interleaved and of equal size within one seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Shard number, 1 ≤ index ≤ count.
    pub index: u32,
    /// Number of shards.
    pub count: u32,
}

impl FromStr for Shard {
    type Err = McError;
    fn from_str(s: &str) -> Result<Self, McError> {
        let bad = || McError::Shard(s.to_owned());
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: u32 = i.trim().parse().map_err(|_| bad())?;
        let count: u32 = n.trim().parse().map_err(|_| bad())?;
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// The seeds of `seeds` that belong to this shard, in order.
    pub fn select(&self, seeds: &[u64]) -> Vec<u64> {
        let (i, n) = (self.index as usize - 1, self.count as usize);
        seeds
            .iter()
            .enumerate()
            .filter(|(k, _)| k % n == i)
            .map(|(_, &s)| s)
            .collect()
    }
}

/// Largest batch accepted: the seed list is held in memory, and a typo such as
/// `--seeds 1..1000000000` should be an error rather than an allocation failure.
pub const MAX_RUNS: u64 = 1_000_000;

/// The seed list of a batch: `1..=runs`, or the explicit range (whose length must then equal
/// `runs` if both are given).
pub fn seed_list(runs: Option<u64>, range: Option<SeedRange>) -> Result<Vec<u64>, McError> {
    let seeds: Vec<u64> = match (runs, range) {
        (_, Some(r)) => {
            let len = (r.last - r.first).saturating_add(1);
            if len > MAX_RUNS {
                return Err(McError::Seeds(format!(
                    "--seeds {r} holds {len} seeds, more than {MAX_RUNS}"
                )));
            }
            if let Some(n) = runs
                && n != len
            {
                return Err(McError::Seeds(format!(
                    "--runs {n} disagrees with --seeds {r} ({len} seeds)"
                )));
            }
            (r.first..=r.last).collect()
        }
        (Some(n), None) if n > MAX_RUNS => {
            return Err(McError::Seeds(format!(
                "--runs {n} is more than {MAX_RUNS}"
            )));
        }
        (Some(n), None) => (1..=n).collect(),
        (None, None) => return Err(McError::Seeds("give --runs or --seeds".into())),
    };
    if seeds.is_empty() {
        return Err(McError::Seeds("the batch has no seeds".into()));
    }
    Ok(seeds)
}

/// Fly `setup` with `seed`, recording its navigation errors. Setup errors, departures and
/// panics become a failed run: one bad seed must not stop a batch of hundreds.
pub fn fly(scenario: u8, setup: &FlightSetup, seed: u64) -> RunRecord {
    let result = catch_unwind(AssertUnwindSafe(|| {
        let mut recorder = MetricsRecorder::new();
        let mut flight = Flight::new(setup, seed)?;
        let summary = flight.run(&mut recorder, |_| {})?;
        let mut tracks = recorder.vision_samples();
        let vision = flight
            .navigator()
            .into_iter()
            .flat_map(|n| n.visual_systems())
            .zip(&setup.vision_systems)
            .map(|(v, system)| {
                let samples = tracks
                    .iter_mut()
                    .find(|(name, _)| *name == system.name())
                    .map(|(_, s)| std::mem::take(s))
                    .unwrap_or_default();
                let c = v.counters;
                VisionRun {
                    system: system.name().to_owned(),
                    samples,
                    initialisations: c.initialisations,
                    tracking_losses: c.tracking_losses,
                    relocalisations: c.relocalisations,
                    motion_model_recoveries: c.motion_model_recoveries,
                    aiding: v.aiding.map(|a| AidingRun {
                        inertial_starts: a.inertial_starts,
                        inertial_start_failures: a.inertial_start_failures,
                        priors_active: a.priors_active,
                        joint_failures: a.joint_failures,
                    }),
                }
            })
            .collect::<Vec<_>>();
        Ok::<_, crate::flight::FlightError>((summary.distance_m, recorder.finish(), vision))
    }));
    let outcome = match result {
        Ok(Ok((distance_m, samples, vision))) => RunOutcome::Completed {
            distance_m,
            samples,
            vision,
        },
        Ok(Err(e)) => RunOutcome::Failed {
            reason: e.to_string(),
        },
        Err(panic) => {
            let message = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            RunOutcome::Failed {
                reason: format!("panicked: {message}"),
            }
        }
    };
    RunRecord {
        scenario,
        scenario_name: setup.scenario.name.clone(),
        navigation: setup.navigation,
        duration_s: setup.scenario.duration_s,
        seed,
        outcome,
    }
}

/// A batch to fly.
#[derive(Debug, Clone)]
pub struct Batch {
    /// Built-in scenario number (recorded in the files).
    pub scenario: u8,
    /// What every run flies.
    pub setup: FlightSetup,
    /// All the seeds of the batch, before sharding.
    pub seeds: Vec<u64>,
    /// The shard of `seeds` this process flies (all of them if `None`).
    pub shard: Option<Shard>,
    /// Worker threads (all cores if `None`).
    pub jobs: Option<usize>,
    /// Keep the run files already in the output directory that hold a run of this batch
    /// (same scenario, navigation, duration and seed, and the same visual systems in the same
    /// order) instead of flying their seeds again: an interrupted
    /// batch goes on where it stopped. Runs are deterministic, so a kept file is the file
    /// flying the seed again would write.
    pub resume: bool,
}

impl Batch {
    /// The seeds this process flies.
    pub fn seeds_to_fly(&self) -> Vec<u64> {
        match self.shard {
            Some(shard) => shard.select(&self.seeds),
            None => self.seeds.clone(),
        }
    }

    /// What every run file of this batch holds.
    pub fn run_spec(&self) -> RunSpec {
        let vision_systems = match (&self.setup.camera, &self.setup.navigation) {
            (Some(c), NavigationMode::Ins) if c.vision_navigation => self
                .setup
                .vision_systems
                .iter()
                .map(|s| s.name().to_owned())
                .collect(),
            _ => Vec::new(),
        };
        RunSpec {
            scenario: self.scenario,
            navigation: self.setup.navigation,
            duration_s: self.setup.scenario.duration_s,
            vision_systems,
        }
    }

    /// The run of `seed` already at `path`, if it is a whole run of this batch (see
    /// [`Batch::resume`]); anything else (missing, unreadable, cut short, another set-up) is
    /// flown again.
    fn kept_run(&self, spec: &RunSpec, path: &Path, seed: u64) -> Option<RunRecord> {
        let record = RunRecord::parse(&std::fs::read_to_string(path).ok()?).ok()?;
        spec.check(&record, seed, self.setup.rates.output_period_s)
            .is_ok()
            .then_some(record)
    }

    /// Manifest file name: `mc.toml`, or `mc_shard_2of4.toml` for a shard (shards may share
    /// an output directory).
    pub fn manifest_name(&self) -> String {
        manifest_name(self.shard)
    }
}

/// Manifest file name of `shard` (of the whole batch if `None`).
pub fn manifest_name(shard: Option<Shard>) -> String {
    match shard {
        Some(s) => format!("mc_shard_{}of{}.toml", s.index, s.count),
        None => "mc.toml".to_owned(),
    }
}

/// What every run file of a batch holds beside its seed: a file that says otherwise is not a
/// run of the batch (`--resume` flies it again, `report --status` counts it to fly).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSpec {
    /// Built-in scenario number.
    pub scenario: u8,
    /// What guidance and control fly on.
    pub navigation: NavigationMode,
    /// Mission duration, s.
    pub duration_s: f64,
    /// The visual systems' sections, in order (none without a camera).
    pub vision_systems: Vec<String>,
}

impl RunSpec {
    /// Whether `record` is a whole run of `seed` of this batch; the error says why not.
    pub fn check(&self, record: &RunRecord, seed: u64, output_period_s: f64) -> Result<(), String> {
        if record.seed != seed {
            return Err(format!("it holds seed {}", record.seed));
        }
        if record.scenario != self.scenario {
            return Err(format!(
                "scenario {}, not {}",
                record.scenario, self.scenario
            ));
        }
        if record.navigation != self.navigation {
            return Err(format!(
                "navigation `{}`, not `{}`",
                navigation_name(record.navigation),
                navigation_name(self.navigation)
            ));
        }
        // Durations are written to 1 ms.
        if (record.duration_s - self.duration_s).abs() >= 5e-4 {
            return Err(format!(
                "duration {} s, not {} s",
                record.duration_s, self.duration_s
            ));
        }
        if let RunOutcome::Completed { vision, .. } = &record.outcome
            && !vision.iter().map(|v| &v.system).eq(&self.vision_systems)
        {
            let names: Vec<&str> = vision.iter().map(|v| v.system.as_str()).collect();
            return Err(format!(
                "visual systems [{}], not [{}]",
                names.join(", "),
                self.vision_systems.join(", ")
            ));
        }
        record.incomplete(output_period_s).map_or(Ok(()), Err)
    }
}

/// A failed run in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FailedRun {
    /// Seed.
    pub seed: u64,
    /// What happened.
    pub reason: String,
}

/// The manifest of a batch (or shard): what was asked and how it ended. Contains nothing
/// that depends on the machine (no times, paths or thread counts).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Program and version.
    pub generator: String,
    /// Built-in scenario number.
    pub scenario: u8,
    /// Scenario name.
    pub scenario_name: String,
    /// Mission duration, s.
    pub duration_s: f64,
    /// Number of seeds of the whole batch.
    pub batch_runs: usize,
    /// First and last seed of the whole batch.
    pub batch_seed_range: [u64; 2],
    /// Shard `i/n` flown, if sharded.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub shard: Option<String>,
    /// Seeds flown by this process.
    pub seeds: Vec<u64>,
    /// Runs that completed.
    pub completed: usize,
    /// Runs that failed.
    pub failed: Vec<FailedRun>,
}

/// Write `text` to `path` through a temporary file and a rename, so that an interrupted
/// batch never leaves a truncated file. The temporary file is this process's own: a shard
/// resubmitted while its first copy still flies may write the same run at the same time.
fn write_atomic(path: &Path, text: &str) -> Result<(), McError> {
    let mut name = path.file_name().unwrap_or_default().to_owned();
    name.push(format!(".{}.tmp", std::process::id()));
    let tmp = path.with_file_name(name);
    std::fs::write(&tmp, text).map_err(io_error(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_error(path))
}

/// Refuse an output directory holding runs of seeds outside this batch (a stale batch
/// would otherwise be merged into the report silently). Other shards' runs are fine.
fn check_no_foreign_runs(runs_dir: &Path, batch_seeds: &[u64]) -> Result<(), McError> {
    let entries = std::fs::read_dir(runs_dir).map_err(io_error(runs_dir))?;
    let mut sorted = batch_seeds.to_vec();
    sorted.sort_unstable();
    let mut foreign: Option<u64> = None;
    for entry in entries {
        let entry = entry.map_err(io_error(runs_dir))?;
        let name = entry.file_name();
        if let Some(seed) = name.to_str().and_then(seed_of_file_name)
            && sorted.binary_search(&seed).is_err()
        {
            // The smallest, so that the message does not depend on the listing order.
            foreign = Some(foreign.map_or(seed, |f| f.min(seed)));
        }
    }
    match foreign {
        Some(seed) => Err(McError::ForeignRun {
            path: runs_dir.display().to_string(),
            seed,
        }),
        None => Ok(()),
    }
}

/// What a batch did.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchSummary {
    /// The manifest written.
    pub manifest: Manifest,
    /// Its path.
    pub manifest_path: PathBuf,
}

/// A run of the batch has ended (or was kept by `--resume`).
#[derive(Debug, Clone, Copy)]
pub struct RunDone<'a> {
    /// The run.
    pub record: &'a RunRecord,
    /// Kept from an earlier flight (`--resume`), not flown.
    pub kept: bool,
    /// Wall time of its flight, s (0 when kept).
    pub wall_s: f64,
}

/// Fly `batch` into `out` with [`fly`], calling `on_done` after each run's file is written.
pub fn run_batch(
    batch: &Batch,
    out: &Path,
    on_done: impl Fn(&RunDone<'_>) + Sync,
) -> Result<BatchSummary, McError> {
    run_batch_with(
        batch,
        out,
        |seed| fly(batch.scenario, &batch.setup, seed),
        on_done,
    )
}

/// [`run_batch`] with the function that flies one seed supplied by the caller (tests inject
/// failures; other navigation set-ups can plug in here).
pub fn run_batch_with(
    batch: &Batch,
    out: &Path,
    fly_seed: impl Fn(u64) -> RunRecord + Sync,
    on_done: impl Fn(&RunDone<'_>) + Sync,
) -> Result<BatchSummary, McError> {
    let seeds = batch.seeds_to_fly();
    let runs_dir = out.join(RUNS_DIR);
    std::fs::create_dir_all(&runs_dir).map_err(io_error(&runs_dir))?;
    check_no_foreign_runs(&runs_dir, &batch.seeds)?;
    let spec = batch.run_spec();
    let plan = status::Plan::of(batch, &spec);
    let plan_path = out.join(status::plan_name(batch.shard));
    write_atomic(&plan_path, &toml::to_string(&plan)?)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(batch.jobs.unwrap_or(0))
        .build()
        .map_err(|e| McError::Pool(e.to_string()))?;
    // Each worker writes its run file as soon as the run ends; only the outcome is kept.
    let ended: Vec<Result<Option<FailedRun>, McError>> = pool.install(|| {
        seeds
            .par_iter()
            .map(|&seed| {
                let path = runs_dir.join(run_file_name(seed));
                let kept = batch
                    .resume
                    .then(|| batch.kept_run(&spec, &path, seed))
                    .flatten();
                let started = std::time::Instant::now();
                let (record, kept) = match kept {
                    Some(record) => (record, true),
                    None => {
                        let record = fly_seed(seed);
                        write_atomic(&path, &record.to_text())?;
                        (record, false)
                    }
                };
                on_done(&RunDone {
                    record: &record,
                    kept,
                    wall_s: if kept {
                        0.0
                    } else {
                        started.elapsed().as_secs_f64()
                    },
                });
                Ok(match record.outcome {
                    RunOutcome::Completed { .. } => None,
                    RunOutcome::Failed { reason } => Some(FailedRun { seed, reason }),
                })
            })
            .collect()
    });
    let mut failed = Vec::new();
    for e in ended {
        if let Some(f) = e? {
            failed.push(f);
        }
    }
    let manifest = Manifest {
        generator: format!("ianav-sim {}", env!("CARGO_PKG_VERSION")),
        scenario: batch.scenario,
        scenario_name: batch.setup.scenario.name.clone(),
        duration_s: batch.setup.scenario.duration_s,
        batch_runs: batch.seeds.len(),
        batch_seed_range: [
            batch.seeds.iter().copied().min().unwrap_or(0),
            batch.seeds.iter().copied().max().unwrap_or(0),
        ],
        shard: batch.shard.map(|s| s.to_string()),
        completed: seeds.len() - failed.len(),
        seeds,
        failed,
    };
    let manifest_path = out.join(batch.manifest_name());
    write_atomic(&manifest_path, &toml::to_string(&manifest)?)?;
    Ok(BatchSummary {
        manifest,
        manifest_path,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_ranges_and_shards_parse_and_partition() {
        assert_eq!(
            "3..7".parse::<SeedRange>().unwrap(),
            SeedRange { first: 3, last: 7 }
        );
        assert_eq!(
            "3..=7".parse::<SeedRange>().unwrap(),
            SeedRange { first: 3, last: 7 }
        );
        for bad in ["7..3", "3-7", "a..b", "..5"] {
            assert!(bad.parse::<SeedRange>().is_err(), "{bad}");
        }
        for bad in ["0/2", "3/2", "1", "x/2", "1/0"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        assert_eq!(seed_list(Some(3), None).unwrap(), vec![1, 2, 3]);
        assert_eq!(
            seed_list(None, Some("5..6".parse().unwrap())).unwrap(),
            vec![5, 6]
        );
        assert!(seed_list(Some(3), Some("5..6".parse().unwrap())).is_err());
        assert!(seed_list(Some(0), None).is_err());
        assert!(seed_list(None, None).is_err());
        assert!(seed_list(None, Some("0..18446744073709551615".parse().unwrap())).is_err());
        assert!(seed_list(Some(MAX_RUNS + 1), None).is_err());
        // Every seed lands in exactly one shard; shards interleave.
        let seeds: Vec<u64> = (10..=20).collect();
        let shards: Vec<Vec<u64>> = (1..=3)
            .map(|i| Shard { index: i, count: 3 }.select(&seeds))
            .collect();
        assert_eq!(shards[0], vec![10, 13, 16, 19]);
        assert_eq!(shards[1], vec![11, 14, 17, 20]);
        assert_eq!(shards[2], vec![12, 15, 18]);
    }
}
