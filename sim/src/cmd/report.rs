//! `ianav-sim report`: the navigation-error tables and plots (the paper's INSE tables and
//! error figures, `ianav_sim::report`) of one or several `mc` directories.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};

pub(crate) fn report(dirs: &[PathBuf], out: Option<&PathBuf>) -> Result<()> {
    let Some(out) = out.or(dirs.first()) else {
        bail!("give at least one directory");
    };
    let started = Instant::now();
    let summary = ianav_sim::report::report(dirs, out)?;
    println!(
        "{} runs ({} completed) in {:.2} s; report: {}",
        summary.runs,
        summary.completed,
        started.elapsed().as_secs_f64(),
        summary.report_path.display()
    );
    Ok(())
}
