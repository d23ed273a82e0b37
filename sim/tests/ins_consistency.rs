//! Consistency of the INS covariances: the normalised
//! estimation error squared (NEES), averaged over a 20-run sample of scenario #2 flown on the
//! INS, stays within the two-sided 95% χ² band of the mean
//!
//! * while GNSS is available (mission time 0 to the loss at 100 s; the warm-up before t = 0
//!   holds the filter's initial convergence): attitude and velocity, for at least 90% of the
//!   output samples;
//! * after the loss (100 s to the end at 500 s, the GNSS-denied dead reckoning): velocity and
//!   horizontal position, for at least 80% of the output samples.
//!
//! With N independent runs and a consistent k-D error, N·mean NEES ~ χ²(kN), so the band of
//! the mean is [χ²₀.₀₂₅(kN), χ²₀.₉₇₅(kN)] / N ([2.02, 4.17] for k = 3 and [1.22, 2.97] for
//! k = 2, N = 20). The 20 flights are flown once and shared by both tests.

use std::sync::OnceLock;

use ianav::nav::NavSolution;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup, NavigationMode, TruthSample};
use ianav_sim::metrics;

const RUNS: u64 = 20;
const MIN_FRACTION_IN_BAND_GNSS: f64 = 0.9;
const MIN_FRACTION_IN_BAND_DENIED: f64 = 0.8;

/// NEES at one output sample.
#[derive(Debug, Clone, Copy)]
struct Nees {
    t_s: f64,
    gnss_denied: bool,
    attitude: f64,
    velocity: f64,
    position_hor: f64,
}

/// NEES at each output sample from mission time 0.
#[derive(Default)]
struct NeesRecorder {
    samples: Vec<Nees>,
}

impl FlightObserver for NeesRecorder {
    fn nav_solution(&mut self, truth: &TruthSample, sol: &NavSolution) {
        if truth.t_s < 0.0 {
            return;
        }
        let (attitude, velocity) = metrics::nees(truth, sol).expect("invertible covariances");
        let position_hor =
            metrics::nees_horizontal_position(truth, sol).expect("invertible covariance");
        self.samples.push(Nees {
            t_s: truth.t_s,
            gnss_denied: sol.ins_status.gnss_denied,
            attitude,
            velocity,
            position_hor,
        });
    }
}

/// The 20 runs of scenario #2 (seeds 1–20), flown once.
fn runs() -> &'static (f64, Vec<Vec<Nees>>) {
    static RUNS_CELL: OnceLock<(f64, Vec<Vec<Nees>>)> = OnceLock::new();
    RUNS_CELL.get_or_init(|| {
        let mut per_run = Vec::new();
        let mut loss_s = 0.0;
        for seed in 1..=RUNS {
            let mut setup = FlightSetup::builtin(2).expect("scenario 2");
            setup.navigation = NavigationMode::Ins;
            loss_s = setup.scenario.gnss_loss_s;
            let mut flight = Flight::new(&setup, seed).expect("flight setup");
            let mut rec = NeesRecorder::default();
            flight.run(&mut rec, |_| {}).expect("flight");
            assert!(
                rec.samples.len() > 4900,
                "seed {seed}: {} samples",
                rec.samples.len()
            );
            per_run.push(rec.samples);
        }
        let n = per_run.iter().map(Vec::len).min().expect("runs");
        // Output instants are the same in every run.
        for run in &per_run {
            assert!((run[n - 1].t_s - per_run[0][n - 1].t_s).abs() < 1e-9);
        }
        (loss_s, per_run)
    })
}

/// Wilson–Hilferty approximation of the χ²(k) quantile for the standard normal quantile z
/// (relative error < 1e-3 at k ≥ 40, ample against the band's width).
fn chi2_quantile(k: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Band of the mean of `RUNS` χ²(dof) values.
fn band(dof: f64) -> (f64, f64) {
    let k = dof * RUNS as f64;
    (
        chi2_quantile(k, -1.959_964) / RUNS as f64,
        chi2_quantile(k, 1.959_964) / RUNS as f64,
    )
}

/// Fraction of the output samples `range` whose run-mean of `pick` lies in the band of
/// `dof` degrees of freedom; prints and asserts at least `min_fraction`.
fn check(
    name: &str,
    range: std::ops::Range<usize>,
    dof: f64,
    pick: fn(&Nees) -> f64,
    min_fraction: f64,
) {
    let (_, per_run) = runs();
    let (lo, hi) = band(dof);
    let means: Vec<f64> = range
        .map(|i| per_run.iter().map(|r| pick(&r[i])).sum::<f64>() / RUNS as f64)
        .collect();
    let inside = means.iter().filter(|m| (lo..=hi).contains(*m)).count();
    let below = means.iter().filter(|m| **m < lo).count();
    let fraction = inside as f64 / means.len() as f64;
    let overall = means.iter().sum::<f64>() / means.len() as f64;
    eprintln!(
        "{name}: mean NEES {overall:.2} (consistent: {dof}), {:.1}% of {} samples in [{lo:.2}, {hi:.2}], {:.1}% below",
        100.0 * fraction,
        means.len(),
        100.0 * below as f64 / means.len() as f64,
    );
    assert!(
        fraction >= min_fraction,
        "{name}: only {:.1}% of the samples in the band (mean NEES {overall:.2})",
        100.0 * fraction
    );
}

#[test]
fn chi2_bands_of_the_20_run_mean() {
    let (lo, hi) = band(3.0);
    assert!(
        (lo - 2.024).abs() < 0.01 && (hi - 4.165).abs() < 0.01,
        "{lo} {hi}"
    );
    // χ²(40): 24.433 and 59.342.
    let (lo, hi) = band(2.0);
    assert!(
        (lo - 1.2217).abs() < 0.01 && (hi - 2.9671).abs() < 0.01,
        "{lo} {hi}"
    );
}

#[test]
fn attitude_and_velocity_nees_stay_in_the_95_percent_band_while_gnss_is_available() {
    let (loss_s, per_run) = runs();
    let r = &per_run[0];
    let end = r.iter().position(|s| s.t_s >= *loss_s).unwrap();
    assert!(end > 900, "{end} samples before the loss");
    // The INS is never told the loss time: it declares the loss on its own later.
    assert!(per_run.iter().all(|r| !r[end - 1].gnss_denied));
    check(
        "GNSS phase, attitude",
        0..end,
        3.0,
        |s| s.attitude,
        MIN_FRACTION_IN_BAND_GNSS,
    );
    check(
        "GNSS phase, velocity",
        0..end,
        3.0,
        |s| s.velocity,
        MIN_FRACTION_IN_BAND_GNSS,
    );
}

#[test]
fn velocity_and_horizontal_position_nees_stay_in_the_95_percent_band_after_gnss_loss() {
    let (loss_s, per_run) = runs();
    let n = per_run.iter().map(Vec::len).min().unwrap();
    let r = &per_run[0];
    let start = r.iter().position(|s| s.t_s >= *loss_s).unwrap();
    assert!(n - start > 3900, "{} samples after the loss", n - start);
    // Every run is in GNSS-denied mode within the timeout after the loss.
    assert!(
        per_run
            .iter()
            .all(|r| r[start + 20..n].iter().all(|s| s.gnss_denied))
    );
    check(
        "after GNSS loss, velocity",
        start..n,
        3.0,
        |s| s.velocity,
        MIN_FRACTION_IN_BAND_DENIED,
    );
    check(
        "after GNSS loss, horizontal position",
        start..n,
        2.0,
        |s| s.position_hor,
        MIN_FRACTION_IN_BAND_DENIED,
    );
}
