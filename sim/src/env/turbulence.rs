//! Dryden turbulence (MIL-F-8785C, high-altitude intensities, body axes), generated on the fly
//! from the run's seed.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::rng::Stream;

/// Turbulence settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TurbulenceConfig {
    /// Scale factor on the turbulence velocity (0 switches it off; the scenarios use 0.5).
    pub factor: f64,
}

/// Stateful Dryden generator: advance it once per integration step.
#[derive(Debug, Clone)]
pub struct Turbulence {
    rng: Stream,
}

impl Turbulence {
    /// Generator for one run, drawing from `rng`.
    pub fn new(cfg: &TurbulenceConfig, rng: Stream) -> Self {
        let _ = cfg;
        Self { rng }
    }

    /// Advance by `dt_s` at true airspeed `tas_mps` and geometric altitude `h_m`; returns the
    /// high-frequency wind velocity in body axes, m/s.
    pub fn step(&mut self, dt_s: f64, tas_mps: f64, h_m: f64) -> Vector3<f64> {
        todo!("{dt_s} {tas_mps} {h_m} {:?}", self.rng)
    }

    /// The current turbulence velocity in body axes, m/s.
    pub fn velocity_b_mps(&self) -> Vector3<f64> {
        todo!()
    }
}
