//! Low-frequency wind ramps (author_impl §3.4): horizontal, function of time only.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::rng::Stream;

/// Parameters of the wind draw (one row of the author_impl §3.4 table).
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

/// The drawn wind history of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WindField {
    /// Ramp start and end times, s (mission clock).
    pub t_ramp_s: [f64; 2],
    /// Wind (NED, m/s, down component zero) before and after the ramp.
    pub wind_ned_mps: [Vector3<f64>; 2],
}

impl WindField {
    /// Draw the wind of one run in the order of author_impl §3.4.
    pub fn draw(cfg: &WindConfig, rng: &mut Stream) -> Self {
        todo!("{cfg:?} {rng:?}")
    }

    /// Low-frequency wind at mission time `t_s`, NED, m/s.
    pub fn at(&self, t_s: f64) -> Vector3<f64> {
        todo!("{t_s}")
    }
}
