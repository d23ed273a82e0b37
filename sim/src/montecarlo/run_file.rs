//! The run file of a Monte Carlo run (`runs/run_0007.csv`, docs/MONTECARLO.md "Files"):
//! its content ([`RunRecord`]), writing and parsing (formats v1 and v2), and whether a parsed
//! file holds a whole run.

use std::fmt::Write as _;
use std::str::FromStr;

use crate::flight::NavigationMode;
use crate::metrics::{NseSample, format_fixed};

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
pub(super) fn seed_of_file_name(name: &str) -> Option<u64> {
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
    /// Why this record is not a whole run, if it is not. Run files are written whole (through
    /// a temporary file and a rename), but a file cut short elsewhere (a copy interrupted, a
    /// disk full, a crash before the data reached the disk) can still parse when it ends at a
    /// line: a completed run's INS samples end at its last output instant, less than one output
    /// period (`output_period_s`) before the mission end, and every visual system has a sample
    /// at each of the INS's times. Failed runs have no samples and are whole.
    pub fn incomplete(&self, output_period_s: f64) -> Option<String> {
        let RunOutcome::Completed {
            samples, vision, ..
        } = &self.outcome
        else {
            return None;
        };
        let Some(last) = samples.last() else {
            return Some("a completed run without samples".into());
        };
        // Times and durations are written to 1 ms: half of it absorbs their rounding.
        if self.duration_s - last.t_s > output_period_s - 5e-4 {
            return Some(format!(
                "its samples stop at t = {} s, before the mission end ({} s)",
                format_fixed(last.t_s, 3),
                format_fixed(self.duration_s, 3)
            ));
        }
        vision
            .iter()
            .find(|v| v.samples.len() != samples.len())
            .map(|v| {
                format!(
                    "its `{}` section has {} samples, the INS {}",
                    v.system,
                    v.samples.len(),
                    samples.len()
                )
            })
    }

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

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn a_file_cut_at_a_line_is_an_incomplete_run() {
        let sample = |t_s: f64| NseSample {
            t_s,
            yaw_deg: 0.1,
            pitch_deg: 0.1,
            bank_deg: 0.1,
            att_norm_deg: 0.2,
            alt_m: 1.0,
            hor_m: 2.0,
            hor_pct: 0.5,
            distance_m: 100.0 * t_s,
        };
        let samples: Vec<NseSample> = [0.0, 10.0, 20.0, 25.0].map(sample).to_vec();
        let record = RunRecord {
            scenario: 2,
            scenario_name: "s".into(),
            navigation: NavigationMode::Ins,
            duration_s: 25.0,
            seed: 3,
            outcome: RunOutcome::Completed {
                distance_m: 2500.0,
                samples: samples.clone(),
                vision: vec![VisionRun {
                    system: "vns".into(),
                    samples,
                    initialisations: 1,
                    tracking_losses: 0,
                    relocalisations: 0,
                    motion_model_recoveries: 0,
                    aiding: None,
                }],
            },
        };
        let text = record.to_text();
        let whole = RunRecord::parse(&text).unwrap();
        assert_eq!(whole.incomplete(0.1), None);
        // Its last output instant may be up to one period before the mission end.
        let early = RunRecord {
            duration_s: 25.099,
            ..whole.clone()
        };
        assert_eq!(early.incomplete(0.1), None);
        // Cut after any line but the last: it does not parse, or it is incomplete, or (cut
        // just before a section) it lost a visual system, which the batch's list of systems
        // tells (`RunSpec::mismatch`).
        let lines: Vec<&str> = text.lines().collect();
        for n in 1..lines.len() {
            let cut = lines[..n].join("\n") + "\n";
            if let Ok(r) = RunRecord::parse(&cut) {
                let lost_section = matches!(&r.outcome,
                    RunOutcome::Completed { vision, .. } if vision.is_empty());
                assert!(
                    r.incomplete(0.1).is_some() || lost_section,
                    "cut after line {n}:\n{cut}"
                );
            }
        }
        // The INS rows end at t = 20 s: named as such.
        let ins_cut = text.split("25.000,").next().unwrap();
        let reason = RunRecord::parse(ins_cut).unwrap().incomplete(0.1).unwrap();
        assert!(reason.contains("t = 20.000 s"), "{reason}");
        let failed = RunRecord {
            outcome: RunOutcome::Failed {
                reason: "departed".into(),
            },
            ..record
        };
        assert_eq!(failed.incomplete(0.1), None);
    }
}
