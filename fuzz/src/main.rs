//! `ianav-fuzz`: the fuzzer's command line (docs/RELIABILITY.md). Build it in the `ci`
//! profile so that overflow checks and debug assertions are part of the oracle:
//! `cargo run -p ianav-fuzz --profile ci -- run --seed 1 --inputs 10000000`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::{Parser, Subcommand};
use mavlink::Message;
use mavlink::dialects::ardupilotmega as apm;

use ianav_fuzz::input::{Input, Starts, read_input};
use ianav_fuzz::pipeline::Stats;
use ianav_fuzz::{
    FNV_BASIS, Outcome, extremes, fnv1a, is_known, known_findings, minimise, mutate, run_catching,
};

#[derive(Parser)]
#[command(
    about = "Fuzz ianav's MAVLink input path: bytes → frames → messages → events → navigation"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Generate and run inputs `from..from + inputs` of `seed` (stops early after `seconds`).
    Run {
        /// Seed of the run.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// First input index (to split one run over processes: same inputs).
        #[arg(long, default_value_t = 0)]
        from: u64,
        /// Inputs to run.
        #[arg(long, default_value_t = 1_000_000)]
        inputs: u64,
        /// Stop after this many seconds (0: no limit); the inputs run are still a prefix of
        /// the seed's sequence.
        #[arg(long, default_value_t = 0.0)]
        seconds: f64,
        /// Go on after a new finding (up to 20 distinct ones). Known findings
        /// (`fuzz/known-findings.txt`) never stop a run.
        #[arg(long)]
        keep_going: bool,
        /// Fail on known findings too.
        #[arg(long)]
        strict: bool,
        /// Minimise the first input of each known finding too (new ones always are).
        #[arg(long)]
        minimise_known: bool,
        /// Directory for reproducers of findings.
        #[arg(long, default_value = "target/fuzz-findings")]
        out: PathBuf,
        /// Progress line every this many seconds (0: none).
        #[arg(long, default_value_t = 60.0)]
        progress: f64,
    },
    /// Regenerate input `index` of `seed`, run it and optionally write it.
    Replay {
        /// Seed.
        #[arg(long)]
        seed: u64,
        /// Input index.
        #[arg(long)]
        index: u64,
        /// Write the input (byte form) here.
        #[arg(long)]
        write: Option<PathBuf>,
        /// Minimise a failing input before writing it.
        #[arg(long)]
        minimise: bool,
    },
    /// Run inputs saved in the byte form.
    Exec {
        /// Files.
        files: Vec<PathBuf>,
    },
    /// Print what a saved input carries: per datagram its time and the frames in it.
    Show {
        /// File (byte form).
        file: PathBuf,
    },
    /// Every accepted message with every field at its extremes (the property sweep).
    Extremes,
    /// Write generated inputs in the byte form (seeds for a byte-level fuzzer).
    Corpus {
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Number of inputs.
        #[arg(long, default_value_t = 200)]
        count: u64,
        /// Directory.
        #[arg(long)]
        out: PathBuf,
    },
}

fn print_stats(s: &Stats) {
    let f = s.fields();
    let line: Vec<String> = f.iter().map(|(k, v)| format!("{k}={v}")).collect();
    println!("totals: {}", line.join(" "));
    let never: Vec<&str> = f.iter().filter(|(_, v)| *v == 0).map(|(k, _)| *k).collect();
    println!(
        "never reached: {}",
        if never.is_empty() {
            "-".to_owned()
        } else {
            never.join(" ")
        }
    );
}

fn save(out: &std::path::Path, name: &str, input: &Input) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let p = out.join(name);
    std::fs::write(&p, input.to_bytes()).with_context(|| format!("writing {}", p.display()))?;
    Ok(p)
}

#[expect(
    clippy::too_many_arguments,
    reason = "the `run` subcommand's options, passed one by one from the parsed command line"
)]
fn run(
    starts: &Starts,
    seed: u64,
    indices: std::ops::Range<u64>,
    seconds: f64,
    keep_going: bool,
    strict: bool,
    minimise_known: bool,
    out: &std::path::Path,
    progress: f64,
) -> anyhow::Result<bool> {
    let known = known_findings();
    let is_known = |sig: &str| !strict && known.iter().any(|(k, _)| k == sig);
    let t0 = Instant::now();
    let mut totals = Stats::default();
    let mut digest = FNV_BASIS;
    // Distinct findings and how many inputs showed each.
    let mut findings: Vec<(String, u64)> = Vec::new();
    let mut last_progress = 0.0;
    let mut done = 0;
    let from = indices.start;
    for index in indices {
        if index % 1024 == 0 {
            let el = t0.elapsed().as_secs_f64();
            if seconds > 0.0 && el >= seconds {
                break;
            }
            if progress > 0.0 && el - last_progress >= progress {
                last_progress = el;
                println!(
                    "progress: {} inputs, {el:.0} s, {:.0}/s, {} findings",
                    index - from,
                    (index - from) as f64 / el,
                    findings.len()
                );
            }
        }
        let input = mutate::generate(starts, seed, index);
        digest = fnv1a(digest, &input.to_bytes());
        let o = run_catching(starts, &input);
        done = index + 1 - from;
        match &o {
            Outcome::Pass(s) => {
                totals.add(s);
                digest = fnv1a(digest, &[s.frames as u8, s.events as u8, s.solutions as u8]);
            }
            _ => {
                let sig = o.signature();
                if let Some(f) = findings.iter_mut().find(|(s, _)| *s == sig) {
                    f.1 += 1;
                } else {
                    let known = is_known(&sig);
                    let tag = if known {
                        "known finding"
                    } else {
                        "NEW FINDING"
                    };
                    println!("{tag} at seed {seed} index {index}: {o:?}");
                    let saved = if known && !minimise_known {
                        input
                    } else {
                        minimise(starts, &input, 20_000)
                    };
                    let p = save(out, &format!("seed{seed}-index{index}.bin"), &saved)?;
                    println!(
                        "  {} datagrams, {} bytes: {} (replay: ianav-fuzz exec {})",
                        saved.datagrams.len(),
                        saved.datagrams.iter().map(|d| d.bytes.len()).sum::<usize>(),
                        p.display(),
                        p.display()
                    );
                    findings.push((sig, 1));
                }
                let new = findings.iter().filter(|(s, _)| !is_known(s)).count();
                if new > 0 && (!keep_going || new >= 20) {
                    break;
                }
            }
        }
    }
    let el = t0.elapsed().as_secs_f64();
    println!(
        "seed {seed}: {done} inputs (from {from}) in {el:.1} s ({:.0} inputs/s), {} findings, digest {digest:016x}",
        done as f64 / el.max(1e-9),
        findings.len()
    );
    for (sig, n) in &findings {
        match known.iter().find(|(k, _)| k == sig) {
            Some((_, why)) if !strict => println!("known finding, {n} inputs: {sig} ({why})"),
            _ => println!("NEW FINDING, {n} inputs: {sig}"),
        }
    }
    print_stats(&totals);
    Ok(findings.iter().all(|(s, _)| is_known(s)))
}

fn main() -> anyhow::Result<ExitCode> {
    let cli = Cli::parse();
    let t0 = Instant::now();
    let starts = Starts::build()?;
    eprintln!(
        "{} warmed-up daemons in {:.2} s",
        starts.0.len(),
        t0.elapsed().as_secs_f64()
    );
    let ok = match cli.cmd {
        Cmd::Run {
            seed,
            from,
            inputs,
            seconds,
            keep_going,
            strict,
            minimise_known,
            out,
            progress,
        } => run(
            &starts,
            seed,
            from..from.saturating_add(inputs),
            seconds,
            keep_going,
            strict,
            minimise_known,
            &out,
            progress,
        )?,
        Cmd::Replay {
            seed,
            index,
            write,
            minimise: min,
        } => {
            let mut input = mutate::generate(&starts, seed, index);
            let o = run_catching(&starts, &input);
            println!("{o:?}");
            if min && o.failed() {
                input = minimise(&starts, &input, 50_000);
                println!("minimised: {input:?}");
            }
            if let Some(p) = write {
                std::fs::write(&p, input.to_bytes())
                    .with_context(|| format!("writing {}", p.display()))?;
            }
            !o.failed()
        }
        Cmd::Exec { files } => {
            let mut ok = true;
            for f in files {
                let o = run_catching(&starts, &read_input(&f)?);
                println!("{}: {o:?}", f.display());
                ok &= !o.failed();
            }
            ok
        }
        Cmd::Show { file } => {
            let input = read_input(&file)?;
            let start = starts.of(&input);
            println!(
                "start {:?} {:?} at {} µs, link {}",
                start.variant,
                start.stage,
                start.pipeline.now_us(),
                input.link
            );
            for d in &input.datagrams {
                println!("+{} µs, {} bytes", d.dt_us, d.bytes.len());
                let mut r = mavlink::MavlinkReader::new(d.bytes.as_slice());
                while let Ok(raw) = r.read_any_raw_message::<apm::MavMessage>() {
                    let msg =
                        apm::MavMessage::parse(raw.version(), raw.message_id(), raw.payload());
                    println!(
                        "  {:?} sys {} comp {} seq {}: {msg:?}",
                        raw.version(),
                        raw.system_id(),
                        raw.component_id(),
                        raw.sequence()
                    );
                }
            }
            true
        }
        Cmd::Extremes => {
            let t = Instant::now();
            match extremes::sweep(&starts, |i| match run_catching(&starts, i) {
                Outcome::Pass(s) => Ok(Some((s.solutions, s.parse_errors))),
                o if is_known(&o) => Ok(None),
                o => Err(format!("{o:?}")),
            }) {
                Ok(report) => {
                    let cases: u64 = report.iter().map(|r| r.cases).sum();
                    for r in &report {
                        println!(
                            "{:<20} {:>6} cases, {:>5} refused by the parser, {:>5} known findings, {:>5} without a solution after",
                            r.name, r.cases, r.parse_errors, r.known, r.stalled
                        );
                        if !r.stalled_at.is_empty() {
                            println!("    stalled after bytes: {}", r.stalled_at.join(", "));
                        }
                    }
                    println!(
                        "{cases} cases in {:.1} s, no finding",
                        t.elapsed().as_secs_f64()
                    );
                    true
                }
                Err(f) => {
                    println!("FINDING {}: {}", f.case, f.message);
                    let p = save(
                        std::path::Path::new("target/fuzz-findings"),
                        "extremes.bin",
                        &f.input,
                    )?;
                    println!("  input: {}", p.display());
                    false
                }
            }
        }
        Cmd::Corpus { seed, count, out } => {
            for index in 0..count {
                save(
                    &out,
                    &format!("seed{seed}-{index:06}.bin"),
                    &mutate::generate(&starts, seed, index),
                )?;
            }
            println!("{count} inputs written to {}", out.display());
            true
        }
    };
    Ok(if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
