//! Temperature and pressure offset ramps (author_impl §3.3): constant, then linear, then
//! constant, with stochastic times and values.

use ianav::env::atmosphere::AtmosphereOffsets;
use serde::{Deserialize, Serialize};

use crate::rng::Stream;

/// Parameters of the offsets draw (one row of the author_impl §3.3 table).
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

impl WeatherOffsets {
    /// Draw the offsets of one run in the order of author_impl §3.3.
    pub fn draw(cfg: &OffsetsConfig, rng: &mut Stream) -> Self {
        todo!("{cfg:?} {rng:?}")
    }

    /// Offsets at mission time `t_s`.
    pub fn at(&self, t_s: f64) -> AtmosphereOffsets {
        todo!("{t_s}")
    }
}
