//! Monte Carlo batches (the paper's 100 runs per scenario, docs/REFERENCES.md P1, A6.1 and
//! A6.4): fly one scenario for a list of seeds in parallel, record the navigation system
//! error of each run (`crate::metrics`) in its own file so that shards flown on different
//! machines merge by copying files, and write a manifest of the batch.
//!
//! Layout of an output directory (`docs/MONTECARLO.md`):
//! - `runs/run_0007.csv`: one file per seed, written atomically when the run ends;
//! - `mc.toml` (or `mc_shard_1of4.toml` for a shard): what was run and how it ended.

use std::fmt::Write as _;
use std::io;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::flight::{Flight, FlightSetup, NavigationMode};
use crate::metrics::{MetricsRecorder, NseSample, format_fixed};

/// Directory of the per-run files inside a batch directory.
pub const RUNS_DIR: &str = "runs";
/// First line of every run file (format name and version): v2 holds one section per visual
/// system, each opened by `# system = NAME`; v1 (still read) held at most one, its counters
/// in the run's header. (Read by hand, not with the `csv` crate: the `# key = value` header
/// lines carry the run's facts, and the rows are plain numbers.)
pub const RUN_FILE_MAGIC: &str = "# ianav-sim mc run v2";
/// First line of the run files written before the visual systems had sections.
const RUN_FILE_MAGIC_V1: &str = "# ianav-sim mc run v1";
/// Column line of a completed run's samples.
pub const RUN_COLUMNS: &str =
    "t_s,yaw_deg,pitch_deg,bank_deg,att_norm_deg,alt_m,hor_m,hor_pct,distance_m";
/// Column line of a visual system's samples (runs with a camera), after the INS samples.
pub const RUN_VISION_COLUMNS: &str =
    "vns_t_s,yaw_deg,pitch_deg,bank_deg,att_norm_deg,alt_m,hor_m,hor_pct,distance_m";
/// Decimals of each column of [`RUN_COLUMNS`]: 1 ms, 1e-6° (far below the 0.01° the tables
/// show), 0.1 mm, 1e-6 %, 1 mm.
const RUN_DECIMALS: [usize; 9] = [3, 6, 6, 6, 6, 4, 4, 6, 3];

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

/// How one run ended.
#[derive(Debug, Clone, PartialEq)]
pub enum RunOutcome {
    /// The flight reached the mission end.
    Completed {
        /// Ground distance flown from mission time 0, m.
        distance_m: f64,
        /// Errors at 0, 10, 20, … s and at the end.
        samples: Vec<NseSample>,
        /// Each visual system's, with a camera, in the flight's order.
        vision: Vec<VisionRun>,
    },
    /// The flight could not be set up, departed, or panicked.
    Failed {
        /// What happened (one line).
        reason: String,
    },
}

/// A visual system of a run: its errors on the INS's grid (NaN where it did not track) and its
/// tracking losses.
#[derive(Debug, Clone, PartialEq)]
pub struct VisionRun {
    /// Its name (`vns`, `ia-vns`, …: `crate::flight::systems::VisionSystem::name`).
    pub system: String,
    /// Errors at 0, 10, 20, … s and at the end.
    pub samples: Vec<NseSample>,
    /// Successful two-view initialisations.
    pub initialisations: u64,
    /// Tracking losses.
    pub tracking_losses: u64,
    /// Successful relocalisations.
    pub relocalisations: u64,
    /// Frames tracked from a second start after sparse alignment's pose failed.
    pub motion_model_recoveries: u64,
    /// The IA-VNS's counters when any of its changes is switched on.
    pub aiding: Option<AidingRun>,
}

/// What the IA-VNS's steps did over a run (docs/IAVNS.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AidingRun {
    /// Frames started from the inertial prediction.
    pub inertial_starts: u64,
    /// Of those, frames that did not track from it.
    pub inertial_start_failures: u64,
    /// Frames with an active prior.
    pub priors_active: u64,
    /// Active frames whose joint optimisation was not kept.
    pub joint_failures: u64,
}

/// One run of a batch: the content of a run file.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRecord {
    /// Built-in scenario number.
    pub scenario: u8,
    /// Scenario name.
    pub scenario_name: String,
    /// What guidance and control flew on (`truth` or `ins`).
    pub navigation: NavigationMode,
    /// Mission duration configured, s.
    pub duration_s: f64,
    /// Seed.
    pub seed: u64,
    /// How it ended.
    pub outcome: RunOutcome,
}

/// Name of a navigation mode in run files and reports.
pub fn navigation_name(mode: NavigationMode) -> &'static str {
    match mode {
        NavigationMode::Truth => "truth",
        NavigationMode::Ins => "ins",
    }
}

/// File name of the run of `seed` (zero-padded to 4 digits so that listings sort).
pub fn run_file_name(seed: u64) -> String {
    format!("run_{seed:04}.csv")
}

/// Seed of a run file name, if it is one.
fn seed_of_file_name(name: &str) -> Option<u64> {
    name.strip_prefix("run_")?
        .strip_suffix(".csv")?
        .parse()
        .ok()
}

/// Text on one line (reasons and names go into `# key = value` header lines).
fn one_line(s: &str) -> String {
    s.replace(['\n', '\r'], " ")
}

impl RunRecord {
    /// The run file: `# key = value` header lines, then for a completed run the column line
    /// and one row per sample, every number with a fixed number of decimals (byte-stable).
    pub fn to_text(&self) -> String {
        let mut t = String::with_capacity(4096);
        let _ = writeln!(t, "{RUN_FILE_MAGIC}");
        let _ = writeln!(t, "# scenario = {}", self.scenario);
        let _ = writeln!(t, "# scenario_name = {}", one_line(&self.scenario_name));
        let _ = writeln!(t, "# navigation = {}", navigation_name(self.navigation));
        let _ = writeln!(t, "# duration_s = {}", format_fixed(self.duration_s, 3));
        let _ = writeln!(t, "# seed = {}", self.seed);
        match &self.outcome {
            RunOutcome::Failed { reason } => {
                let _ = writeln!(t, "# status = failed");
                let _ = writeln!(t, "# reason = {}", one_line(reason));
            }
            RunOutcome::Completed {
                distance_m,
                samples,
                vision,
            } => {
                let _ = writeln!(t, "# status = completed");
                let _ = writeln!(t, "# distance_m = {}", format_fixed(*distance_m, 3));
                let _ = writeln!(t, "{RUN_COLUMNS}");
                write_samples(&mut t, samples);
                for v in vision {
                    write_vision_section(&mut t, v);
                }
            }
        }
        t
    }

    /// Parse a run file written by [`RunRecord::to_text`] (or by its v1 form); the error
    /// names the line.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut lines = text.lines().enumerate();
        let v1 = match lines.next() {
            Some((_, RUN_FILE_MAGIC)) => false,
            Some((_, RUN_FILE_MAGIC_V1)) => true,
            _ => return Err(format!("line 1: expected `{RUN_FILE_MAGIC}`")),
        };
        let mut header: Vec<(String, String)> = Vec::new();
        let mut columns_seen = false;
        let mut samples = Vec::new();
        // Each visual system's header lines and samples, in the file's order.
        let mut sections: Vec<(HeaderLines, Vec<NseSample>)> = Vec::new();
        // Whether the latest section's column line has been read (its rows follow).
        let mut in_rows = false;
        for (i, line) in lines {
            let at = |m: &str| format!("line {}: {m}", i + 1);
            if let Some(kv) = line.strip_prefix("# ") {
                let (k, v) = kv
                    .split_once(" = ")
                    .ok_or_else(|| at("expected `# key = value`"))?;
                let kv = (k.to_owned(), v.to_owned());
                if !columns_seen {
                    header.push(kv);
                } else if k == "system" && !v1 {
                    sections.push((vec![kv], Vec::new()));
                    in_rows = false;
                } else {
                    match sections.last_mut() {
                        Some((h, _)) if !in_rows => h.push(kv),
                        _ => return Err(at("a header line outside a `# system` section")),
                    }
                }
                continue;
            }
            if !columns_seen {
                if line != RUN_COLUMNS {
                    return Err(at(&format!("expected the column line `{RUN_COLUMNS}`")));
                }
                columns_seen = true;
                continue;
            }
            if line == RUN_VISION_COLUMNS {
                if v1 && sections.is_empty() {
                    // v1's one section: its counters are in the run's header.
                    sections.push((v1_section_header(&header), Vec::new()));
                } else if v1 || in_rows || sections.is_empty() {
                    return Err(at("a vision column line outside a `# system` section"));
                }
                in_rows = true;
                continue;
            }
            let sample = parse_sample(line).map_err(|e| at(&e))?;
            match sections.last_mut() {
                None => samples.push(sample),
                Some((_, rows)) if in_rows => rows.push(sample),
                Some(_) => return Err(at("samples before the section's column line")),
            }
        }
        let get = |key: &str| find(&header, key);
        let num = |key: &str| -> Result<f64, String> {
            get(key)?
                .parse::<f64>()
                .map_err(|e| format!("header `{key}`: {e}"))
        };
        let scenario = get("scenario")?
            .parse::<u8>()
            .map_err(|e| format!("header `scenario`: {e}"))?;
        let seed = get("seed")?
            .parse::<u64>()
            .map_err(|e| format!("header `seed`: {e}"))?;
        let outcome = match get("status")? {
            "completed" => {
                if !columns_seen {
                    return Err("completed run without the column line".into());
                }
                let vision = sections
                    .into_iter()
                    .map(|(h, rows)| vision_run(&h, rows))
                    .collect::<Result<_, _>>()?;
                RunOutcome::Completed {
                    distance_m: num("distance_m")?,
                    samples,
                    vision,
                }
            }
            "failed" => RunOutcome::Failed {
                reason: get("reason")?.to_owned(),
            },
            other => return Err(format!("header `status`: unknown `{other}`")),
        };
        Ok(Self {
            scenario,
            scenario_name: get("scenario_name")?.to_owned(),
            navigation: match get("navigation")? {
                "truth" => NavigationMode::Truth,
                "ins" => NavigationMode::Ins,
                other => return Err(format!("header `navigation`: unknown `{other}`")),
            },
            duration_s: num("duration_s")?,
            seed,
            outcome,
        })
    }
}

/// `# key = value` lines as read.
type HeaderLines = Vec<(String, String)>;

/// The value of `key` among `# key = value` lines.
fn find<'a>(lines: &'a [(String, String)], key: &str) -> Result<&'a str, String> {
    lines
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
        .ok_or_else(|| format!("header: missing `{key}`"))
}

/// A v1 run's visual section header, from the run's header: `vision_*` counters, and the
/// IA-VNS's when `vision_system` is written (the VNS's otherwise).
fn v1_section_header(header: &[(String, String)]) -> Vec<(String, String)> {
    let system = if find(header, "vision_system").is_ok() {
        "ia-vns"
    } else {
        "vns"
    };
    let mut h = vec![("system".to_owned(), system.to_owned())];
    for (k, v) in header {
        if let Some(name) = k.strip_prefix("vision_").filter(|n| *n != "system") {
            h.push((name.to_owned(), v.clone()));
        } else if k.starts_with("aiding_") {
            h.push((k.clone(), v.clone()));
        }
    }
    h
}

/// A visual system's section from its header lines and samples.
fn vision_run(h: &[(String, String)], samples: Vec<NseSample>) -> Result<VisionRun, String> {
    let count = |key: &str| -> Result<u64, String> {
        find(h, key)?
            .parse::<u64>()
            .map_err(|e| format!("section `{key}`: {e}"))
    };
    let system = find(h, "system")?.to_owned();
    Ok(VisionRun {
        samples,
        initialisations: count("initialisations")?,
        tracking_losses: count("tracking_losses")?,
        relocalisations: count("relocalisations")?,
        // v1 wrote it only when not zero.
        motion_model_recoveries: match find(h, "motion_model_recoveries") {
            Ok(_) => count("motion_model_recoveries")?,
            Err(_) => 0,
        },
        aiding: match find(h, "aiding_inertial_starts") {
            Ok(_) => Some(AidingRun {
                inertial_starts: count("aiding_inertial_starts")?,
                inertial_start_failures: count("aiding_inertial_start_failures")?,
                priors_active: count("aiding_priors_active")?,
                joint_failures: count("aiding_joint_failures")?,
            }),
            Err(_) => None,
        },
        system,
    })
}

/// One sample row.
fn parse_sample(line: &str) -> Result<NseSample, String> {
    let v: Vec<f64> = line
        .split(',')
        .map(f64::from_str)
        .collect::<Result<_, _>>()
        .map_err(|e| format!("bad number: {e}"))?;
    let [
        t_s,
        yaw_deg,
        pitch_deg,
        bank_deg,
        att_norm_deg,
        alt_m,
        hor_m,
        hor_pct,
        distance_m,
    ] = v[..]
    else {
        return Err(format!("expected 9 values, got {}", v.len()));
    };
    Ok(NseSample {
        t_s,
        yaw_deg,
        pitch_deg,
        bank_deg,
        att_norm_deg,
        alt_m,
        hor_m,
        hor_pct,
        distance_m,
    })
}

/// A visual system's section: `# system = NAME`, its counters, its column line and samples.
fn write_vision_section(t: &mut String, v: &VisionRun) {
    let _ = writeln!(t, "# system = {}", one_line(&v.system));
    let _ = writeln!(t, "# initialisations = {}", v.initialisations);
    let _ = writeln!(t, "# tracking_losses = {}", v.tracking_losses);
    let _ = writeln!(t, "# relocalisations = {}", v.relocalisations);
    let _ = writeln!(
        t,
        "# motion_model_recoveries = {}",
        v.motion_model_recoveries
    );
    if let Some(a) = &v.aiding {
        let _ = writeln!(t, "# aiding_inertial_starts = {}", a.inertial_starts);
        let _ = writeln!(
            t,
            "# aiding_inertial_start_failures = {}",
            a.inertial_start_failures
        );
        let _ = writeln!(t, "# aiding_priors_active = {}", a.priors_active);
        let _ = writeln!(t, "# aiding_joint_failures = {}", a.joint_failures);
    }
    let _ = writeln!(t, "{RUN_VISION_COLUMNS}");
    write_samples(t, &v.samples);
}

/// One row per sample, every number at its fixed number of decimals.
fn write_samples(t: &mut String, samples: &[NseSample]) {
    for s in samples {
        let values = [
            s.t_s,
            s.yaw_deg,
            s.pitch_deg,
            s.bank_deg,
            s.att_norm_deg,
            s.alt_m,
            s.hor_m,
            s.hor_pct,
            s.distance_m,
        ];
        for (k, (v, d)) in values.iter().zip(RUN_DECIMALS).enumerate() {
            let sep = if k == 0 { "" } else { "," };
            let _ = write!(t, "{sep}{}", format_fixed(*v, d));
        }
        t.push('\n');
    }
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

    /// The run of `seed` already at `path`, if it is a run of this batch (see
    /// [`Batch::resume`]); anything else (missing, unreadable, another set-up) is flown again.
    fn kept_run(&self, path: &Path, seed: u64) -> Option<RunRecord> {
        let record = RunRecord::parse(&std::fs::read_to_string(path).ok()?).ok()?;
        // The same visual systems in the same order (none without a camera).
        let same_vision = match &record.outcome {
            RunOutcome::Completed { vision, .. } => {
                let flown = vision.iter().map(|v| v.system.as_str());
                match (&self.setup.camera, &self.setup.navigation) {
                    (Some(c), NavigationMode::Ins) if c.vision_navigation => {
                        flown.eq(self.setup.vision_systems.iter().map(|s| s.name()))
                    }
                    _ => vision.is_empty(),
                }
            }
            RunOutcome::Failed { .. } => true,
        };
        (record.seed == seed
            && record.scenario == self.scenario
            && record.navigation == self.setup.navigation
            && (record.duration_s - self.setup.scenario.duration_s).abs() < 5e-4
            && same_vision)
            .then_some(record)
    }

    /// Manifest file name: `mc.toml`, or `mc_shard_2of4.toml` for a shard (shards may share
    /// an output directory).
    pub fn manifest_name(&self) -> String {
        match self.shard {
            Some(s) => format!("mc_shard_{}of{}.toml", s.index, s.count),
            None => "mc.toml".to_owned(),
        }
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
/// batch never leaves a truncated run file.
fn write_atomic(path: &Path, text: &str) -> Result<(), McError> {
    let tmp = path.with_extension("csv.tmp");
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

/// Fly `batch` into `out` with [`fly`], calling `on_done` after each run's file is written.
pub fn run_batch(
    batch: &Batch,
    out: &Path,
    on_done: impl Fn(&RunRecord) + Sync,
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
    on_done: impl Fn(&RunRecord) + Sync,
) -> Result<BatchSummary, McError> {
    let seeds = batch.seeds_to_fly();
    let runs_dir = out.join(RUNS_DIR);
    std::fs::create_dir_all(&runs_dir).map_err(io_error(&runs_dir))?;
    check_no_foreign_runs(&runs_dir, &batch.seeds)?;
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
                let record = match batch.resume.then(|| batch.kept_run(&path, seed)).flatten() {
                    Some(kept) => kept,
                    None => {
                        let record = fly_seed(seed);
                        write_atomic(&path, &record.to_text())?;
                        record
                    }
                };
                on_done(&record);
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
    let text = toml::to_string(&manifest)?;
    std::fs::write(&manifest_path, text).map_err(io_error(&manifest_path))?;
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

    #[test]
    fn run_files_round_trip_with_nan_and_failures() {
        let sample = NseSample {
            t_s: 10.0,
            yaw_deg: -0.25,
            pitch_deg: 1e-9,
            bank_deg: -1e-9,
            att_norm_deg: 0.5,
            alt_m: -3.25,
            hor_m: 12.5,
            hor_pct: f64::NAN,
            distance_m: 0.0,
        };
        let record = RunRecord {
            scenario: 2,
            scenario_name: "two\nlines".into(),
            navigation: NavigationMode::Ins,
            duration_s: 500.0,
            seed: 7,
            outcome: RunOutcome::Completed {
                distance_m: 1234.5,
                samples: vec![sample],
                vision: Vec::new(),
            },
        };
        let text = record.to_text();
        assert!(text.contains("\n10.000,-0.250000,0.000000,0.000000,0.500000,-3.2500,"));
        let back = RunRecord::parse(&text).unwrap();
        assert_eq!(back.seed, 7);
        assert_eq!(back.scenario_name, "two lines");
        let RunOutcome::Completed { samples, .. } = &back.outcome else {
            panic!("should be completed")
        };
        assert!(samples[0].hor_pct.is_nan());
        assert_eq!(samples[0].alt_m, -3.25);
        // Writing what was parsed reproduces the file byte for byte.
        assert_eq!(back.to_text(), text);
        let failed = RunRecord {
            outcome: RunOutcome::Failed {
                reason: "departed".into(),
            },
            ..record.clone()
        };
        let back = RunRecord::parse(&failed.to_text()).unwrap();
        assert_eq!(
            back.outcome,
            RunOutcome::Failed {
                reason: "departed".into()
            }
        );
        assert!(RunRecord::parse("not a run file").is_err());
        let truncated = text.replace(RUN_COLUMNS, "t_s,yaw_deg");
        assert!(RunRecord::parse(&truncated).is_err());

        // With two visual systems: each one's samples (NaN where it did not track) and
        // counters come back in order, and the INS samples stay the INS's.
        let vns_sample = NseSample {
            hor_m: 40.0,
            ..sample
        };
        let vns = VisionRun {
            system: "vns".into(),
            samples: vec![crate::metrics::missing_sample(0.0, 0.0), vns_sample],
            initialisations: 1,
            tracking_losses: 3,
            relocalisations: 2,
            motion_model_recoveries: 4,
            aiding: None,
        };
        let ia_vns = VisionRun {
            system: "ia-vns".into(),
            samples: vec![sample],
            tracking_losses: 0,
            aiding: Some(AidingRun {
                inertial_starts: 4_990,
                inertial_start_failures: 3,
                priors_active: 120,
                joint_failures: 1,
            }),
            ..vns.clone()
        };
        let with_vision = RunRecord {
            outcome: RunOutcome::Completed {
                distance_m: 1234.5,
                samples: vec![sample],
                vision: vec![vns.clone(), ia_vns.clone()],
            },
            ..record.clone()
        };
        let text = with_vision.to_text();
        let back = RunRecord::parse(&text).unwrap();
        assert_eq!(back.to_text(), text);
        let RunOutcome::Completed {
            samples, vision, ..
        } = &back.outcome
        else {
            panic!("should be completed")
        };
        assert_eq!((samples.len(), samples[0].hor_m), (1, 12.5));
        assert_eq!(vision.len(), 2);
        assert_eq!(
            (vision[0].system.as_str(), vision[1].system.as_str()),
            ("vns", "ia-vns")
        );
        assert!(vision[0].samples[0].att_norm_deg.is_nan());
        assert_eq!(vision[0].samples[1].hor_m, 40.0);
        assert_eq!(
            (vision[0].tracking_losses, vision[0].motion_model_recoveries),
            (3, 4)
        );
        assert_eq!(vision[1].aiding, ia_vns.aiding);
        // A section without its counters is an error, not a silent zero.
        let no_counters = text.replacen("# tracking_losses = 3\n", "", 1);
        assert!(RunRecord::parse(&no_counters).is_err());
        // Rows before a section's column line, or a key outside a section, are errors.
        let orphan = text.replacen("# system = vns\n", "", 1);
        assert!(RunRecord::parse(&orphan).is_err());

        // A v1 file (one system, its counters in the run's header) reads as that system.
        let v1 = format!(
            "{RUN_FILE_MAGIC_V1}\n# scenario = 2\n# scenario_name = two lines\n\
             # navigation = ins\n# duration_s = 500.000\n# seed = 7\n# status = completed\n\
             # distance_m = 1234.500\n# vision_initialisations = 1\n\
             # vision_tracking_losses = 0\n# vision_relocalisations = 2\n\
             # vision_system = ia-vns\n# aiding_inertial_starts = 4990\n\
             # aiding_inertial_start_failures = 3\n# aiding_priors_active = 120\n\
             # aiding_joint_failures = 1\n{RUN_COLUMNS}\n{}{RUN_VISION_COLUMNS}\n{}",
            text.lines().nth(9).unwrap().to_owned() + "\n",
            text.lines().nth(9).unwrap().to_owned() + "\n",
        );
        let back = RunRecord::parse(&v1).unwrap();
        let RunOutcome::Completed { vision, .. } = &back.outcome else {
            panic!("should be completed")
        };
        assert_eq!(vision.len(), 1);
        assert_eq!(vision[0].system, "ia-vns");
        assert_eq!(vision[0].relocalisations, 2);
        assert_eq!(vision[0].motion_model_recoveries, 0);
        assert_eq!(vision[0].aiding, ia_vns.aiding);
        let v1_vns = v1.replace("# vision_system = ia-vns\n", "").replace(
            "# aiding_inertial_starts = 4990\n# aiding_inertial_start_failures = 3\n\
             # aiding_priors_active = 120\n# aiding_joint_failures = 1\n",
            "",
        );
        let back = RunRecord::parse(&v1_vns).unwrap();
        let RunOutcome::Completed { vision, .. } = &back.outcome else {
            panic!("should be completed")
        };
        assert_eq!((vision[0].system.as_str(), vision[0].aiding), ("vns", None));
    }
}
