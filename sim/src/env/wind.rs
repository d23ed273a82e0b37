//! Low-frequency wind ramps (docs/REFERENCES.md A3.4): horizontal, function of time only; the North
//! and East components go linearly from the initial to the final wind over the ramp.

use ianav::math::angle::wrap_180_deg;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::offsets::{draw_at_least, ramp};
use crate::rng::{self, Stream};

/// Parameters of the wind draw (one row of the docs/REFERENCES.md A3.4 table).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindConfig {
    /// Mean ramp start time μ, s.
    pub mean_start_s: f64,
    /// Nominal ramp duration D, s.
    pub duration_s: f64,
    /// σ of the ramp times, s.
    pub sigma_time_s: f64,
    /// Earliest ramp start, s.
    pub min_start_s: f64,
    /// σ of the initial wind speed (speed = |σ N|), m/s.
    pub sigma_speed_mps: f64,
    /// σ of the wind speed change, m/s.
    pub sigma_speed_change_mps: f64,
    /// σ of the wind direction change, degrees.
    pub sigma_direction_change_deg: f64,
}

impl WindConfig {
    /// `wind_id03`: ramp, used by scenario 1.
    pub const ID03: Self = Self {
        mean_start_s: 400.0,
        duration_s: 1200.0,
        sigma_time_s: 600.0,
        min_start_s: 50.0,
        sigma_speed_mps: 7.0,
        sigma_speed_change_mps: 3.0,
        sigma_direction_change_deg: 15.0,
    };
    /// `wind_id04`: constant random wind, used by scenario 2.
    pub const ID04: Self = Self {
        sigma_speed_change_mps: 0.0,
        sigma_direction_change_deg: 0.0,
        ..Self::ID03
    };
}

/// The drawn wind history of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WindField {
    /// Ramp start and end times, s (mission clock).
    pub t_ramp_s: [f64; 2],
    /// Wind (NED, m/s, down component zero) before and after the ramp.
    pub wind_ned_mps: [Vector3<f64>; 2],
}

/// Horizontal NED wind blowing *towards* bearing `chi_deg` at `speed_mps`.
fn wind_towards(speed_mps: f64, chi_deg: f64) -> Vector3<f64> {
    let chi = chi_deg.to_radians();
    Vector3::new(speed_mps * chi.cos(), speed_mps * chi.sin(), 0.0)
}

impl WindField {
    /// Draw the wind of one run in the order of docs/REFERENCES.md A3.4: ramp start (redrawn while
    /// below the earliest start), ramp end (redrawn while shorter than σ_t/2; both loops
    /// capped by [`crate::rng::MAX_REDRAWS`], falling back to the bound), initial speed
    /// `|σ_V N|`, initial direction `U_int{−179..180}°`, speed change, direction change. A
    /// negative final speed flips the direction by 180°. Directions are where the wind blows
    /// towards.
    pub fn draw(cfg: &WindConfig, rng: &mut Stream) -> Self {
        let sig = cfg.sigma_time_s;
        let t_ini = draw_at_least(rng, cfg.mean_start_s, sig, cfg.min_start_s);
        let t_end = draw_at_least(rng, t_ini + cfg.duration_s, sig, t_ini + 0.5 * sig);
        let v_ini = (cfg.sigma_speed_mps * rng::normal(rng)).abs();
        // Integer-degree bearing, as the authors' U_int draw (exact in f64).
        let chi_ini = rng::uniform_int(rng, -179, 180) as f64;
        let mut v_end = v_ini + cfg.sigma_speed_change_mps * rng::normal(rng);
        let mut chi_end = chi_ini + cfg.sigma_direction_change_deg * rng::normal(rng);
        if v_end < 0.0 {
            v_end = -v_end;
            chi_end += 180.0;
        }
        Self {
            t_ramp_s: [t_ini, t_end],
            wind_ned_mps: [
                wind_towards(v_ini, chi_ini),
                wind_towards(v_end, wrap_180_deg(chi_end)),
            ],
        }
    }

    /// Low-frequency wind at mission time `t_s`, NED, m/s (N and E interpolated linearly over
    /// the ramp, constant outside it; NaN time gives NaN).
    pub fn at(&self, t_s: f64) -> Vector3<f64> {
        let [a, b] = self.wind_ned_mps;
        Vector3::new(
            ramp(t_s, self.t_ramp_s, [a.x, b.x]),
            ramp(t_s, self.t_ramp_s, [a.y, b.y]),
            0.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::super::offsets::test_stats::{mean_std, normal_cdf};
    use super::*;
    use crate::rng::stream;

    const RUNS: u64 = 20_000;
    /// Bounds in standard errors (see offsets tests).
    const K: f64 = 4.5;

    #[test]
    fn blows_towards_bearing() {
        let w = wind_towards(10.0, 90.0);
        assert!(w.x.abs() < 1e-12 && (w.y - 10.0).abs() < 1e-12 && w.z == 0.0);
        let w = wind_towards(5.0, 180.0);
        assert!((w.x + 5.0).abs() < 1e-12 && w.y.abs() < 1e-12);
    }

    #[test]
    fn ramp_interpolates_components() {
        let f = WindField {
            t_ramp_s: [100.0, 200.0],
            wind_ned_mps: [Vector3::new(10.0, 0.0, 0.0), Vector3::new(0.0, 10.0, 0.0)],
        };
        assert_eq!(f.at(0.0), Vector3::new(10.0, 0.0, 0.0));
        assert_eq!(f.at(100.0), Vector3::new(10.0, 0.0, 0.0));
        // Components, not speed/direction, are interpolated: speed dips to 5√2 mid-ramp.
        let mid = f.at(150.0);
        assert!((mid - Vector3::new(5.0, 5.0, 0.0)).norm() < 1e-12);
        assert_eq!(f.at(200.0), Vector3::new(0.0, 10.0, 0.0));
        assert_eq!(f.at(9e9), Vector3::new(0.0, 10.0, 0.0));
    }

    #[test]
    fn draw_order_follows_the_authors_code() {
        let cfg = WindConfig::ID03;
        let f = WindField::draw(&cfg, &mut stream(9, "env.wind"));
        let mut r = stream(9, "env.wind");
        let t0 = draw_at_least(&mut r, 400.0, 600.0, 50.0);
        let t1 = draw_at_least(&mut r, t0 + 1200.0, 600.0, t0 + 300.0);
        let v0 = (7.0 * rng::normal(&mut r)).abs();
        let chi0 = rng::uniform_int(&mut r, -179, 180) as f64;
        let mut v1 = v0 + 3.0 * rng::normal(&mut r);
        let mut chi1 = chi0 + 15.0 * rng::normal(&mut r);
        if v1 < 0.0 {
            v1 = -v1;
            chi1 += 180.0;
        }
        assert_eq!(f.t_ramp_s, [t0, t1]);
        assert_eq!(f.wind_ned_mps[0], wind_towards(v0, chi0));
        assert!((f.wind_ned_mps[1] - wind_towards(v1, chi1)).norm() < 1e-12);
    }

    #[test]
    fn draw_statistics() {
        let w: Vec<WindField> = (0..RUNS)
            .map(|s| WindField::draw(&WindConfig::ID03, &mut stream(s, "env.wind")))
            .collect();
        let n = RUNS as f64;
        // Initial speed |7 N|: half-normal, mean σ√(2/π), std σ√(1 − 2/π).
        let v0: Vec<f64> = w.iter().map(|f| f.wind_ned_mps[0].norm()).collect();
        let (m, s) = mean_std(&v0);
        let sd = 7.0 * (1.0 - 2.0 / std::f64::consts::PI).sqrt();
        assert!((m - 7.0 * (2.0 / std::f64::consts::PI).sqrt()).abs() < K * sd / n.sqrt());
        // SE(std) for the half-normal (kurtosis ≈ 3.87): √((κ−1)/4n)·σ ≈ 0.85σ/√n.
        assert!((s - sd).abs() < K * 0.85 * sd / n.sqrt(), "{s} {sd}");
        // Initial direction: uniform over 360 integer degrees → mean bearing vector ≈ 0,
        // each component SE = √(½/n).
        let (cx, cy) = w.iter().fold((0.0, 0.0), |(a, b), f| {
            let u = f.wind_ned_mps[0] / f.wind_ned_mps[0].norm();
            (a + u.x / n, b + u.y / n)
        });
        assert!(cx.abs() < K * (0.5 / n).sqrt() && cy.abs() < K * (0.5 / n).sqrt());
        // Ramp duration D + σN ≥ σ/2 = 300 s, i.e. N ≥ α = (σ/2 − D)/σ = −1.5; fraction
        // below D = (½ − Φ(α))/(1 − Φ(α)).
        let alpha = (300.0 - 1200.0) / 600.0;
        let p = (0.5 - normal_cdf(alpha)) / (1.0 - normal_cdf(alpha));
        let dur: Vec<f64> = w.iter().map(|f| f.t_ramp_s[1] - f.t_ramp_s[0]).collect();
        assert!(dur.iter().all(|&d| d >= 300.0));
        assert!(w.iter().all(|f| f.t_ramp_s[0] >= 50.0));
        let frac = dur.iter().filter(|&&d| d < 1200.0).count() as f64 / n;
        assert!((frac - p).abs() < K * (p * (1.0 - p) / n).sqrt());
        // Direction change: for speeds well above σ_ΔV the flip is rare, so the change of
        // bearing is ≈ N(0, 15°) (a flip needs N < −v0/σ_ΔV; for v0 > 15 m/s, Φ(−5) ≈ 3e-7).
        let dchi: Vec<f64> = w
            .iter()
            .filter(|f| f.wind_ned_mps[0].norm() > 15.0)
            .map(|f| {
                let [a, b] = f.wind_ned_mps;
                wrap_180_deg(b.y.atan2(b.x).to_degrees() - a.y.atan2(a.x).to_degrees())
            })
            .collect();
        let (m, s) = mean_std(&dchi);
        let k = dchi.len() as f64;
        assert!(m.abs() < K * 15.0 / k.sqrt(), "{m}");
        assert!((s - 15.0).abs() < K * 15.0 / (2.0 * k).sqrt(), "{s}");
        // Always horizontal.
        assert!(
            w.iter()
                .all(|f| f.wind_ned_mps[0].z == 0.0 && f.wind_ned_mps[1].z == 0.0)
        );
    }

    #[test]
    fn constant_config_is_constant() {
        let f = WindField::draw(&WindConfig::ID04, &mut stream(5, "env.wind"));
        assert!((f.at(0.0) - f.at(4000.0)).norm() < 1e-12);
    }
}
