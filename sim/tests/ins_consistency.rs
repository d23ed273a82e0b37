//! Consistency of the INS covariances while GNSS is available (issue 3 acceptance): the
//! normalised estimation error squared (NEES) of attitude and velocity, averaged over a
//! 20-run sample of scenario #2 flown on the INS, stays within the two-sided 95% χ² band for
//! at least 90% of the output samples of the mission's GNSS phase (t = 0 to the loss at
//! 100 s; the warm-up before t = 0 holds the filter's initial convergence).
//!
//! With N independent runs and a consistent 3-D error, N·mean NEES ~ χ²(3N), so the band of
//! the mean is [χ²₀.₀₂₅(3N), χ²₀.₉₇₅(3N)] / N ([2.02, 4.17] for N = 20).

use ianav::ins::InsSolution;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup, NavigationMode, TruthSample};
use ianav_sim::metrics;

const RUNS: u64 = 20;
const DOF_PER_RUN: f64 = 3.0;
const MIN_FRACTION_IN_BAND: f64 = 0.9;

/// NEES (attitude, velocity) at each GNSS-phase output sample from mission time 0.
#[derive(Default)]
struct NeesRecorder {
    samples: Vec<(f64, f64, f64)>,
}

impl FlightObserver for NeesRecorder {
    fn nav_solution(&mut self, truth: &TruthSample, sol: &InsSolution) {
        if truth.t_s < 0.0 || sol.gnss_denied {
            return;
        }
        let (att, vel) = metrics::nees(truth, sol).expect("invertible covariances");
        self.samples.push((truth.t_s, att, vel));
    }
}

/// Wilson–Hilferty approximation of the χ²(k) quantile for the standard normal quantile z
/// (relative error < 1e-3 at k = 60, ample against the band's width).
fn chi2_quantile(k: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

#[test]
fn attitude_and_velocity_nees_stay_in_the_95_percent_band_while_gnss_is_available() {
    let mut per_run = Vec::new();
    for seed in 1..=RUNS {
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.navigation = NavigationMode::Ins;
        setup.scenario.duration_s = setup.scenario.gnss_loss_s;
        let mut flight = Flight::new(&setup, seed).unwrap();
        let mut rec = NeesRecorder::default();
        flight.run(&mut rec, |_| {}).unwrap();
        assert!(
            rec.samples.len() > 900,
            "seed {seed}: {} samples",
            rec.samples.len()
        );
        per_run.push(rec.samples);
    }
    let n = per_run.iter().map(Vec::len).min().unwrap();
    // Output instants are the same in every run.
    for run in &per_run {
        assert!((run[n - 1].0 - per_run[0][n - 1].0).abs() < 1e-9);
    }
    let k = DOF_PER_RUN * RUNS as f64;
    let lo = chi2_quantile(k, -1.959_964) / RUNS as f64;
    let hi = chi2_quantile(k, 1.959_964) / RUNS as f64;
    assert!(
        (lo - 2.024).abs() < 0.01 && (hi - 4.165).abs() < 0.01,
        "{lo} {hi}"
    );
    for (name, pick) in [
        (
            "attitude",
            (|s: &(f64, f64, f64)| s.1) as fn(&(f64, f64, f64)) -> f64,
        ),
        ("velocity", |s: &(f64, f64, f64)| s.2),
    ] {
        let means: Vec<f64> = (0..n)
            .map(|i| per_run.iter().map(|r| pick(&r[i])).sum::<f64>() / RUNS as f64)
            .collect();
        let inside = means.iter().filter(|m| (lo..=hi).contains(*m)).count();
        let fraction = inside as f64 / n as f64;
        let overall = means.iter().sum::<f64>() / n as f64;
        eprintln!(
            "{name}: mean NEES {overall:.2} (consistent: 3), {:.1}% of {n} samples in [{lo:.2}, {hi:.2}]",
            100.0 * fraction
        );
        assert!(
            fraction >= MIN_FRACTION_IN_BAND,
            "{name}: only {:.1}% of the samples in the band (mean NEES {overall:.2})",
            100.0 * fraction
        );
    }
}
