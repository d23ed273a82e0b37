//! Softly band-limited random walk in units of steps (docs/REFERENCES.md A2.1 "band" limit), used
//! for the inertial bias drift and the GNSS ionospheric error (A2.5).
//!
//! `S_k = S_{k−1} + ν_k + c(S_{k−1})`, ν ~ N(0, 1). Inside `|S| ≤ L − safety` the walk is
//! free (`c = 0`); beyond, a restoring pull `c = ∓g·(|S| − (L − safety))/safety` with gain
//! `g = 0.1` acts. The pull is an Ornstein–Uhlenbeck restoring rate of `g/safety = 0.005` per
//! step, so outside `L − safety` the walk has a stationary spread of `1/√(2·0.005) = 10` steps
//! and rarely exceeds `L` by more than a few tens of steps: an effective bound ≈ ±L.

use crate::rng::{self, Stream};

/// Gain of the restoring pull: drift per step at one safety margin beyond `L − safety`.
pub const BAND_PULL_GAIN: f64 = 0.1;

/// A soft band `(L, safety)`, in steps. `L = ∞` disables it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftBand {
    /// Band limit `L`, steps.
    pub limit_steps: f64,
    /// Safety margin, steps (the pull starts at `L − safety`).
    pub safety_steps: f64,
}

impl SoftBand {
    /// The restoring correction added to a step taken from `s`.
    #[inline]
    pub fn pull(&self, s: f64) -> f64 {
        let start = self.limit_steps - self.safety_steps;
        if s > start {
            -BAND_PULL_GAIN * (s - start) / self.safety_steps
        } else if s < -start {
            BAND_PULL_GAIN * (-start - s) / self.safety_steps
        } else {
            0.0
        }
    }
}

/// Three independent band-limited walks (one per axis), in steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandedWalk3 {
    /// Current position of each walk, steps.
    pub steps: [f64; 3],
    band: SoftBand,
}

impl BandedWalk3 {
    /// Walks starting at `initial` steps.
    pub fn new(initial: [f64; 3], band: SoftBand) -> Self {
        Self {
            steps: initial,
            band,
        }
    }

    /// Advance every axis by one step, drawing x, y, z in this order from `rng`.
    #[inline]
    pub fn step(&mut self, rng: &mut Stream) {
        for s in &mut self.steps {
            let nu = rng::normal(rng);
            *s += nu + self.band.pull(*s);
        }
    }

    /// The walk position after one step from `self` (without changing `self`).
    #[inline]
    pub fn stepped(mut self, rng: &mut Stream) -> Self {
        self.step(rng);
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BAND: SoftBand = SoftBand {
        limit_steps: 100.0,
        safety_steps: 20.0,
    };

    #[test]
    fn pull_is_zero_inside_and_restoring_outside() {
        assert_eq!(BAND.pull(0.0), 0.0);
        assert_eq!(BAND.pull(80.0), 0.0);
        assert_eq!(BAND.pull(-80.0), 0.0);
        // One safety margin beyond the pull start the correction equals the gain.
        assert!((BAND.pull(100.0) + BAND_PULL_GAIN).abs() < 1e-15);
        assert!((BAND.pull(-100.0) - BAND_PULL_GAIN).abs() < 1e-15);
        let none = SoftBand {
            limit_steps: f64::INFINITY,
            safety_steps: 20.0,
        };
        assert_eq!(none.pull(1e12), 0.0);
        assert_eq!(none.pull(-1e12), 0.0);
    }

    #[test]
    fn band_bounds_a_long_walk() {
        // 10⁶ steps: a free walk would spread σ = 1000 steps. With the band the excursion
        // beyond L − safety = 80 is an OU process of spread 10 steps (module doc), so
        // 140 steps is a 6σ bound; the walk must also reach the band (> 60) in that time.
        let mut rng = rng::stream(3, "test.walk");
        let mut w = BandedWalk3::new([0.0; 3], BAND);
        let mut max_abs = 0.0_f64;
        for _ in 0..1_000_000 {
            w.step(&mut rng);
            max_abs = w.steps.iter().fold(max_abs, |m, s| m.max(s.abs()));
        }
        assert!(max_abs > 60.0, "max |S| = {max_abs}");
        assert!(max_abs < 140.0, "max |S| = {max_abs}");
    }
}
