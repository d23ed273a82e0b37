//! `ianav-sim report`: the navigation-error tables and plots (the paper's INSE tables and
//! error figures, `ianav_sim::report`) of one or several `mc` directories; `ianav-sim table`:
//! one of the paper's result tables beside its printed numbers.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};

pub(crate) fn report(dirs: &[PathBuf], out: Option<&PathBuf>) -> Result<()> {
    let Some(out) = out.or(dirs.first()) else {
        bail!("give at least one directory");
    };
    let started = Instant::now();
    let summary = ianav_sim::report::report(dirs, out)?;
    if !summary.missing.is_empty() {
        eprintln!(
            "warning: incomplete batch: no run file for {} seeds of its plan ({}); \
             `ianav-sim report --status` shows their shards",
            summary.missing.len(),
            summary
                .missing
                .iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    println!(
        "{} runs ({} completed) in {:.2} s; report: {}",
        summary.runs,
        summary.completed,
        started.elapsed().as_secs_f64(),
        summary.report_path.display()
    );
    Ok(())
}

/// `report --status`: how the batches of `dirs` stand.
pub(crate) fn status(dirs: &[PathBuf]) -> Result<()> {
    let status = ianav_sim::montecarlo::status::status(dirs)?;
    print!("{}", status.render(std::time::SystemTime::now()));
    Ok(())
}

pub(crate) fn table(
    kind: ianav_sim::report::PaperTable,
    inputs: &[String],
    out: Option<&PathBuf>,
) -> Result<()> {
    use ianav_sim::report::PaperTable;
    let mx = matches!(
        kind,
        PaperTable::Attitude | PaperTable::Altitude | PaperTable::Horizontal
    );
    let mut loaded = Vec::new();
    for input in inputs {
        let Some((label, dir)) = input.split_once('=') else {
            bail!("`{input}`: expected LABEL=DIR");
        };
        let ok = if mx {
            matches!(label, "1" | "2")
        } else {
            label.parse::<ianav_sim::terrain::Zone>().is_ok()
        };
        if !ok {
            bail!(
                "`{input}`: the label must be {}",
                if mx {
                    "1 or 2 (the scenario)"
                } else {
                    "a zone code (ds, fm, fr, mx, pr, ur)"
                }
            );
        }
        let runs = ianav_sim::report::load_runs(&[PathBuf::from(dir)])?;
        loaded.push((label.to_lowercase(), runs));
    }
    let md = ianav_sim::report::paper_table(kind, &loaded);
    print!("{md}");
    if let Some(path) = out {
        std::fs::write(path, &md).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    Ok(())
}
