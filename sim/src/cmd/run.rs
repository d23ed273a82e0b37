//! `ianav-sim run`: one flight, with a progress bar, writing trajectory, sensor samples,
//! summary, plots and a report (`ianav_sim::output`); with `--frames`, the camera frames as
//! PNG files.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use ianav_sim::flight::Flight;
use ianav_sim::output::RunWriter;
use indicatif::{ProgressBar, ProgressStyle};

use super::setup;
use crate::FlyArgs;

/// Observer that saves camera frames as PNG files and passes everything else on.
struct FrameSaver<'a, O> {
    inner: &'a mut O,
    dir: Option<PathBuf>,
    every: u64,
    count: u64,
    error: Option<anyhow::Error>,
}

impl<O: ianav_sim::flight::FlightObserver> ianav_sim::flight::FlightObserver for FrameSaver<'_, O> {
    fn sensor_event(&mut self, event: &ianav::sensors::SensorEvent) {
        let ianav::sensors::SensorEvent::Frame(frame) = event else {
            self.inner.sensor_event(event);
            return;
        };
        let k = self.count;
        self.count += 1;
        let Some(dir) = &self.dir else { return };
        if !k.is_multiple_of(self.every) || self.error.is_some() {
            return;
        }
        // Frame index (10 Hz from mission time 0) and sensor-clock time (µs since the start
        // of the warm-up, as in `sensors.bin` and `truth.csv`).
        let path = dir.join(format!("frame_{k:06}_t{}us.png", frame.t_us));
        if let Err(e) = image::save_buffer(
            &path,
            &frame.pixels,
            frame.width,
            frame.height,
            image::ExtendedColorType::L8,
        ) {
            self.error = Some(anyhow::Error::new(e).context(format!("writing {}", path.display())));
        }
    }
    fn truth_sample(&mut self, sample: &ianav_sim::flight::TruthSample) {
        self.inner.truth_sample(sample);
    }
    fn estimate_sample(
        &mut self,
        truth: &ianav_sim::flight::TruthSample,
        estimate: &ianav_sim::control::NavEstimate,
    ) {
        self.inner.estimate_sample(truth, estimate);
    }
    fn nav_solution(
        &mut self,
        truth: &ianav_sim::flight::TruthSample,
        solution: &ianav::nav::NavSolution,
    ) {
        self.inner.nav_solution(truth, solution);
    }
    fn vision_outputs(
        &mut self,
        truth: &ianav_sim::flight::TruthSample,
        t_us: u64,
        systems: &[ianav_sim::flight::VisionOutput],
    ) {
        self.inner.vision_outputs(truth, t_us, systems);
    }
    fn operation_started(
        &mut self,
        t_s: f64,
        index: usize,
        operation: &ianav_sim::control::Operation,
    ) {
        self.inner.operation_started(t_s, index, operation);
    }
}

/// What `run` does beside flying.
pub(crate) struct RunOptions<'a> {
    /// Write the sensor sample log.
    pub sensor_log: bool,
    /// Save the frames as PNG files here.
    pub frames: Option<&'a PathBuf>,
    /// Save every N-th frame only.
    pub every: u64,
    /// Fly on the daemon's fused solution ([`ianav_sim::flight::FlightSetup::fused`]).
    pub fused: bool,
    /// Mission-time windows `[start, end)` without frames, s.
    pub frame_outages_s: &'a [(f64, f64)],
    /// The renderer's rows and columns between exact intersections (2 or 4).
    pub render_solve_spacing_px: usize,
}

pub(crate) fn run(fly: &FlyArgs, out: &std::path::Path, options: &RunOptions) -> Result<()> {
    let (no_sensor_log, frames, every) = (!options.sensor_log, options.frames, options.every);
    let mut setup = setup(&fly.setup)?;
    setup.fused = options.fused;
    if let Some(camera) = setup.camera.as_mut() {
        camera.outages_s = options.frame_outages_s.to_vec();
        camera.options.solve_spacing_px = options.render_solve_spacing_px;
    }
    let mut flight = Flight::new(&setup, fly.seed)?;
    let mut writer = RunWriter::new(out, !no_sensor_log)?;
    if let Some(nav) = flight.navigator() {
        writer.record_nav_config(nav.config())?;
    }
    if let Some(dir) = frames {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let end_s = flight.end_time_s();
    let bar = ProgressBar::new(end_s.ceil() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} s mission time (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("scenario {} seed {}", fly.setup.scenario, fly.seed));
    let started = Instant::now();
    let mut saver = FrameSaver {
        inner: &mut writer,
        dir: frames.cloned(),
        every,
        count: 0,
        error: None,
    };
    let summary = flight.run(&mut saver, |t_s| bar.set_position(t_s.max(0.0) as u64))?;
    if let Some(e) = saver.error.take() {
        return Err(e);
    }
    let n_frames = saver.count;
    bar.finish();
    if let (Some(cam), true) = (setup.camera.as_ref(), n_frames > 0) {
        let (h, a) = cam.terrain.cache_stats();
        let mb = |b: usize| b as f64 / 1e6;
        println!(
            "{n_frames} camera frames rendered, {:.1} ms each (wall, flight included); tile caches: \
             heights {} held ({} generated, {} evicted, peak {:.1} MB), albedo {} held ({} \
             generated, {} evicted, peak {:.1} MB); budget {:.1} MB",
            started.elapsed().as_secs_f64() * 1e3 / n_frames as f64,
            h.tiles,
            h.generated,
            h.evicted,
            mb(h.peak_bytes),
            a.tiles,
            a.generated,
            a.evicted,
            mb(a.peak_bytes),
            mb(cam.terrain.cache_budget_bytes())
        );
    }
    let report = writer.finish(&summary)?;
    println!(
        "{}: flew {:.0} s, {:.0} m in {:.1} s wall; report: {}",
        summary.scenario,
        summary.duration_s,
        summary.distance_m,
        started.elapsed().as_secs_f64(),
        report.display()
    );
    Ok(())
}
