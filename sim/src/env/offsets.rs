//! Temperature and pressure offset ramps (docs/REFERENCES.md A3.3): constant, then linear, then
//! constant, with stochastic times and values. Offsets depend on time only.

use ianav::env::atmosphere::AtmosphereOffsets;
use serde::{Deserialize, Serialize};

use crate::rng::{self, Stream};

/// Parameters of the offsets draw (one row of the docs/REFERENCES.md A3.3 table).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OffsetsConfig {
    /// Mean ramp start time μ_t, s.
    pub mean_start_s: f64,
    /// Nominal ramp duration D, s.
    pub duration_s: f64,
    /// Standard deviation of the ramp times σ_t, s.
    pub sigma_time_s: f64,
    /// Earliest ramp start t_min, s.
    pub min_start_s: f64,
    /// σ of the initial temperature offset, K.
    pub sigma_delta_t_k: f64,
    /// σ of the temperature offset change over the ramp, K.
    pub sigma_delta_t_change_k: f64,
    /// σ of the initial pressure offset, Pa.
    pub sigma_delta_p_pa: f64,
    /// σ of the pressure offset change over the ramp, Pa.
    pub sigma_delta_p_change_pa: f64,
}

impl OffsetsConfig {
    /// `offsets_id02`: ramps, used by scenario 1.
    pub const ID02: Self = Self {
        mean_start_s: 400.0,
        duration_s: 1200.0,
        sigma_time_s: 600.0,
        min_start_s: 50.0,
        sigma_delta_t_k: 10.0,
        sigma_delta_t_change_k: 3.0,
        sigma_delta_p_pa: 1500.0,
        sigma_delta_p_change_pa: 300.0,
    };
    /// `offsets_id03`: constant random offsets, used by scenario 2.
    pub const ID03: Self = Self {
        sigma_delta_t_change_k: 0.0,
        sigma_delta_p_change_pa: 0.0,
        ..Self::ID02
    };
}

/// The drawn offsets history of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WeatherOffsets {
    /// ΔT ramp start and end times, s (mission clock).
    pub t_ramp_t_s: [f64; 2],
    /// Δp ramp start and end times, s.
    pub t_ramp_p_s: [f64; 2],
    /// ΔT before and after the ramp, K.
    pub delta_t_k: [f64; 2],
    /// Δp before and after the ramp, Pa.
    pub delta_p_pa: [f64; 2],
}

/// `mean + sigma·N(0,1)`, redrawn while below `min` ([`rng::normal_until`]). The rejection
/// probabilities of the scenario configurations are ≤ 0.28 per draw, so the cap
/// [`rng::MAX_REDRAWS`] only guards degenerate configurations (e.g. σ_t = 0 with μ_t < t_min);
/// there the value falls back to the bound it failed, `min`.
pub(crate) fn draw_at_least(rng: &mut Stream, mean: f64, sigma: f64, min: f64) -> f64 {
    rng::normal_until(rng, mean, sigma, |x| x >= min, min)
}

/// Piecewise constant–linear–constant ramp from `v[0]` (until `t[0]`) to `v[1]` (from `t[1]`).
/// A zero-length ramp is a step at `t[1]`. NaN time gives NaN.
pub(crate) fn ramp(t_s: f64, t: [f64; 2], v: [f64; 2]) -> f64 {
    if t_s <= t[0] {
        v[0]
    } else if t_s >= t[1] {
        v[1]
    } else {
        v[0] + (v[1] - v[0]) * (t_s - t[0]) / (t[1] - t[0])
    }
}

impl WeatherOffsets {
    /// Draw the offsets of one run in the order of docs/REFERENCES.md A3.3: ΔT start, Δp start,
    /// ΔT end, Δp end, ΔT initial, Δp initial, ΔT final, Δp final. Changes with σ = 0 still
    /// consume their normal draw, so the stream position does not depend on the config.
    pub fn draw(cfg: &OffsetsConfig, rng: &mut Stream) -> Self {
        let (mu, sig) = (cfg.mean_start_s, cfg.sigma_time_s);
        let t_ini_t = draw_at_least(rng, mu, sig, cfg.min_start_s);
        let t_ini_p = draw_at_least(rng, mu, sig, cfg.min_start_s);
        let t_end_t = draw_at_least(rng, t_ini_t + cfg.duration_s, sig, t_ini_t + sig);
        let t_end_p = draw_at_least(rng, t_ini_p + cfg.duration_s, sig, t_ini_p + sig);
        let dt_ini = cfg.sigma_delta_t_k * rng::normal(rng);
        let dp_ini = cfg.sigma_delta_p_pa * rng::normal(rng);
        let dt_end = dt_ini + cfg.sigma_delta_t_change_k * rng::normal(rng);
        let dp_end = dp_ini + cfg.sigma_delta_p_change_pa * rng::normal(rng);
        Self {
            t_ramp_t_s: [t_ini_t, t_end_t],
            t_ramp_p_s: [t_ini_p, t_end_p],
            delta_t_k: [dt_ini, dt_end],
            delta_p_pa: [dp_ini, dp_end],
        }
    }

    /// Offsets at mission time `t_s` (constant before the ramp, linear during it, constant
    /// after it; ΔT and Δp have their own ramp times).
    pub fn at(&self, t_s: f64) -> AtmosphereOffsets {
        AtmosphereOffsets {
            delta_t_k: ramp(t_s, self.t_ramp_t_s, self.delta_t_k),
            delta_p_pa: ramp(t_s, self.t_ramp_p_s, self.delta_p_pa),
        }
    }
}

/// Statistics helpers shared by the environment tests.
#[cfg(test)]
pub(crate) mod test_stats {
    /// Standard normal CDF by composite Simpson integration of the density from 0 (error
    /// ≪ 1e-9 with 2000 panels over |x| ≤ 8).
    pub fn normal_cdf(x: f64) -> f64 {
        let n = 2000;
        let h = x / f64::from(n);
        let pdf = |s: f64| (-0.5 * s * s).exp() / (2.0 * std::f64::consts::PI).sqrt();
        let mut sum = pdf(0.0) + pdf(x);
        for i in 1..n {
            let w = if i % 2 == 1 { 4.0 } else { 2.0 };
            sum += w * pdf(f64::from(i) * h);
        }
        0.5 + sum * h / 3.0
    }

    /// Mean and (unbiased) standard deviation.
    pub fn mean_std(x: &[f64]) -> (f64, f64) {
        let n = x.len() as f64;
        let mean = x.iter().sum::<f64>() / n;
        let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::test_stats::{mean_std, normal_cdf};
    use super::*;
    use crate::rng::stream;

    /// Runs for the statistical tests; bounds are 4.5 standard errors (two-sided false-alarm
    /// probability 7e-6 per check for a correct implementation; the seeds are fixed anyway).
    const RUNS: u64 = 20_000;
    const K: f64 = 4.5;

    fn draws(cfg: &OffsetsConfig) -> Vec<WeatherOffsets> {
        (0..RUNS)
            .map(|s| WeatherOffsets::draw(cfg, &mut stream(s, "env.offsets")))
            .collect()
    }

    #[test]
    fn ramp_shape() {
        let w = WeatherOffsets {
            t_ramp_t_s: [100.0, 300.0],
            t_ramp_p_s: [50.0, 60.0],
            delta_t_k: [2.0, -4.0],
            delta_p_pa: [100.0, 200.0],
        };
        assert_eq!(w.at(-50.0).delta_t_k, 2.0);
        assert_eq!(w.at(100.0).delta_t_k, 2.0);
        assert!((w.at(150.0).delta_t_k - 0.5).abs() < 1e-12);
        assert!((w.at(200.0).delta_t_k + 1.0).abs() < 1e-12);
        assert_eq!(w.at(300.0).delta_t_k, -4.0);
        assert_eq!(w.at(1e6).delta_t_k, -4.0);
        assert!((w.at(55.0).delta_p_pa - 150.0).abs() < 1e-12);
        assert_eq!(w.at(70.0).delta_p_pa, 200.0);
        // Zero-length ramp: a step, no division by zero.
        assert_eq!(ramp(5.0, [5.0, 5.0], [1.0, 2.0]), 1.0);
        assert_eq!(ramp(5.0 + 1e-12, [5.0, 5.0], [1.0, 2.0]), 2.0);
        assert!(ramp(f64::NAN, [5.0, 6.0], [1.0, 2.0]).is_nan());
    }

    #[test]
    fn draw_order_follows_the_authors_code() {
        let cfg = OffsetsConfig::ID02;
        let w = WeatherOffsets::draw(&cfg, &mut stream(42, "env.offsets"));
        // Replay the stream by hand in the documented order.
        let mut r = stream(42, "env.offsets");
        let t0t = draw_at_least(&mut r, 400.0, 600.0, 50.0);
        let t0p = draw_at_least(&mut r, 400.0, 600.0, 50.0);
        let t1t = draw_at_least(&mut r, t0t + 1200.0, 600.0, t0t + 600.0);
        let t1p = draw_at_least(&mut r, t0p + 1200.0, 600.0, t0p + 600.0);
        let a = 10.0 * rng::normal(&mut r);
        let b = 1500.0 * rng::normal(&mut r);
        let c = a + 3.0 * rng::normal(&mut r);
        let d = b + 300.0 * rng::normal(&mut r);
        assert_eq!(w.t_ramp_t_s, [t0t, t1t]);
        assert_eq!(w.t_ramp_p_s, [t0p, t1p]);
        assert_eq!(w.delta_t_k, [a, c]);
        assert_eq!(w.delta_p_pa, [b, d]);
    }

    #[test]
    fn draw_statistics() {
        let cfg = OffsetsConfig::ID02;
        let w = draws(&cfg);
        let n = RUNS as f64;
        // Initial values: N(0, σ). SE(mean) = σ/√n, SE(std) ≈ σ/√(2n).
        for (x, sigma) in [
            (w.iter().map(|o| o.delta_t_k[0]).collect::<Vec<_>>(), 10.0),
            (w.iter().map(|o| o.delta_p_pa[0]).collect(), 1500.0),
            (
                w.iter().map(|o| o.delta_t_k[1] - o.delta_t_k[0]).collect(),
                3.0,
            ),
            (
                w.iter()
                    .map(|o| o.delta_p_pa[1] - o.delta_p_pa[0])
                    .collect(),
                300.0,
            ),
        ] {
            let (m, s) = mean_std(&x);
            assert!(m.abs() < K * sigma / n.sqrt(), "mean {m} σ {sigma}");
            assert!(
                (s - sigma).abs() < K * sigma / (2.0 * n).sqrt(),
                "std {s} σ {sigma}"
            );
        }
        // Start times: N(400, 600) truncated below at 50. Check the bound and the fraction
        // below the mean, (½ − Φ(α))/(1 − Φ(α)) with α = (50 − 400)/600; binomial SE.
        let alpha = (50.0 - 400.0) / 600.0;
        let p = (0.5 - normal_cdf(alpha)) / (1.0 - normal_cdf(alpha));
        for t0 in [
            w.iter().map(|o| o.t_ramp_t_s[0]).collect::<Vec<_>>(),
            w.iter().map(|o| o.t_ramp_p_s[0]).collect(),
        ] {
            assert!(t0.iter().all(|&t| t >= 50.0));
            let frac = t0.iter().filter(|&&t| t < 400.0).count() as f64 / n;
            assert!(
                (frac - p).abs() < K * (p * (1.0 - p) / n).sqrt(),
                "{frac} vs {p}"
            );
        }
        // Durations: D + σN truncated below at σ: fraction below D is (½ − Φ(−1))/(1 − Φ(−1)).
        let p = (0.5 - normal_cdf(-1.0)) / (1.0 - normal_cdf(-1.0));
        let dur: Vec<f64> = w
            .iter()
            .map(|o| o.t_ramp_t_s[1] - o.t_ramp_t_s[0])
            .collect();
        assert!(dur.iter().all(|&d| d >= 600.0));
        let frac = dur.iter().filter(|&&d| d < 1200.0).count() as f64 / n;
        assert!(
            (frac - p).abs() < K * (p * (1.0 - p) / n).sqrt(),
            "{frac} vs {p}"
        );
        // ΔT and Δp draws are independent.
        let dt: Vec<f64> = w.iter().map(|o| o.delta_t_k[0] / 10.0).collect();
        let dp: Vec<f64> = w.iter().map(|o| o.delta_p_pa[0] / 1500.0).collect();
        let corr = dt.iter().zip(&dp).map(|(a, b)| a * b).sum::<f64>() / n;
        assert!(corr.abs() < K / n.sqrt());
    }

    #[test]
    fn constant_config_is_constant() {
        let w = WeatherOffsets::draw(&OffsetsConfig::ID03, &mut stream(3, "env.offsets"));
        assert_eq!(w.at(0.0), w.at(5000.0));
    }

    #[test]
    fn degenerate_config_terminates() {
        let cfg = OffsetsConfig {
            mean_start_s: 0.0,
            sigma_time_s: 0.0,
            min_start_s: 50.0,
            ..OffsetsConfig::ID02
        };
        let w = WeatherOffsets::draw(&cfg, &mut stream(1, "env.offsets"));
        assert_eq!(w.t_ramp_t_s[0], 50.0);
        let nan = OffsetsConfig {
            sigma_time_s: f64::NAN,
            ..OffsetsConfig::ID02
        };
        let _ = WeatherOffsets::draw(&nan, &mut stream(1, "env.offsets"));
    }
}
