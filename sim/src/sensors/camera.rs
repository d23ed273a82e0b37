//! Camera mounting errors of one run (docs/REFERENCES.md A2.6): true Euler angles body → camera =
//! nominal + 0.1°·N, estimated = true + 0.01°·N, estimated lens position = true + 0.002 m·N per
//! axis, drawn from the run's own `camera_mounting` stream (the types and the arithmetic live
//! in `ianav::vision::camera`).

use ianav::vision::camera::{MountingConfig, MountingDraws, MountingPair};

use crate::rng;

/// Name of the random stream of the mounting draws.
pub const STREAM: &str = "camera_mounting";

/// True and estimated camera mountings of run `seed`.
pub fn draw_mounting(config: &MountingConfig, seed: u64) -> MountingPair {
    let mut r = rng::stream(seed, STREAM);
    let mut three = || {
        [
            rng::normal(&mut r),
            rng::normal(&mut r),
            rng::normal(&mut r),
        ]
    };
    let draws = MountingDraws {
        angle_true: three(),
        angle_estimate: three(),
        position_estimate: three(),
    };
    config.with_errors(&draws)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ianav::math::so3;

    #[test]
    fn mounting_errors_have_the_configured_spread() {
        let cfg = MountingConfig::default();
        let nominal = cfg.nominal();
        let n = 2_000;
        let (mut s_true, mut s_est, mut s_pos) = (0.0, 0.0, 0.0);
        for seed in 0..n {
            let pair = draw_mounting(&cfg, seed);
            s_true += so3::minus(&pair.truth.q_bc, &nominal.q_bc).norm_squared();
            s_est += so3::minus(&pair.estimate.q_bc, &pair.truth.q_bc).norm_squared();
            s_pos += (pair.estimate.t_rc_b_m - pair.truth.t_rc_b_m).norm_squared();
        }
        // E|δ|² = 3σ²; with 2,000 runs the sample mean is within ±10 % (≈ 5 standard errors
        // of a χ²₃/3 mean: sd = sqrt(2/3/2000) ≈ 1.8 %).
        let rms = |s: f64| (s / (3.0 * n as f64)).sqrt();
        assert!((rms(s_true).to_degrees() / 0.1 - 1.0).abs() < 0.1);
        assert!((rms(s_est).to_degrees() / 0.01 - 1.0).abs() < 0.1);
        assert!((rms(s_pos) / 0.002 - 1.0).abs() < 0.1);
        // Same seed, same draws.
        assert_eq!(draw_mounting(&cfg, 5), draw_mounting(&cfg, 5));
    }
}
