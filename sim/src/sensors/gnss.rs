//! GNSS receiver (docs/REFERENCES.md A2.5): NED position error
//! `e = [σ_h ν, σ_h ν, σ_v ν] + σ_iono·I` and velocity error `σ_vel ν` per axis, where `I` is an
//! ionospheric walk (in steps) that starts at `50·N(0, 1)` and takes one band-limited step every 60
//! fixes.
//!
//! Deviation from the C++ (docs/REFERENCES.md A9.6): the ionospheric error is interpolated
//! **linearly** between its nodes, as the original intended; the C++ integer division made it
//! piecewise constant with a jump every 60 s.
//!
//! The position error is applied on the ellipsoid through the radii of curvature:
//! `φ̃ = φ + e_N/(M + h)`, `λ̃ = λ + e_E/((N + h)·cos φ)`, `h̃ = h − e_D`.

use ianav::math::wgs84;
use ianav::sensors::GnssFix;
use nalgebra::Vector3;

use super::SensorTruth;
use super::config::GnssConfig;
use super::random_walk::{BandedWalk3, SoftBand};
use crate::rng::{self, Stream};

/// Floor on `|cos φ|` when turning an east error into longitude: at the poles longitude is
/// undefined and the division would give an infinite longitude error.
const MIN_COS_LAT: f64 = 1e-9;

/// A GNSS receiver with its error state.
#[derive(Debug, Clone)]
pub struct Gnss {
    sigma_hor_m: f64,
    sigma_ver_m: f64,
    sigma_vel_mps: f64,
    iono_sigma_m: f64,
    fixes_per_step: u32,
    /// Ionospheric walk at the node before the current fix, steps.
    node_prev: BandedWalk3,
    /// Ionospheric walk at the next node, steps.
    node_next: BandedWalk3,
    /// Index of the next fix within the current node interval, `0..fixes_per_step`.
    fix_in_interval: u32,
    /// White-noise stream: 3 position then 3 velocity draws per fix.
    run: Stream,
    /// Ionospheric stream: 3 initial values, then 3 per node.
    iono: Stream,
    /// Ionospheric error of the last fix, NED, m.
    iono_ned_m: Vector3<f64>,
}

impl Gnss {
    /// Draw the initial ionospheric node and the next one.
    pub fn new(cfg: &GnssConfig, run: Stream, mut iono: Stream) -> Self {
        let band = SoftBand {
            limit_steps: cfg.iono_band_limit_steps,
            safety_steps: cfg.iono_band_safety_steps,
        };
        let initial = [(); 3].map(|()| cfg.iono_initial_sigma_steps * rng::normal(&mut iono));
        let node_prev = BandedWalk3::new(initial, band);
        let node_next = node_prev.stepped(&mut iono);
        Self {
            sigma_hor_m: cfg.sigma_hor_m,
            sigma_ver_m: cfg.sigma_ver_m,
            sigma_vel_mps: cfg.sigma_vel_mps,
            iono_sigma_m: cfg.iono_sigma_m,
            fixes_per_step: cfg.iono_fixes_per_step.max(1),
            node_prev,
            node_next,
            fix_in_interval: 0,
            run,
            iono,
            iono_ned_m: Vector3::from(initial) * cfg.iono_sigma_m,
        }
    }

    /// One fix of the truth (call once per configured GNSS period: the ionospheric walk
    /// advances per fix).
    pub fn sample(&mut self, truth: &SensorTruth) -> GnssFix {
        let frac = f64::from(self.fix_in_interval) / f64::from(self.fixes_per_step);
        let (a, b) = (self.node_prev.steps, self.node_next.steps);
        let iono = Vector3::from_fn(|i, _| self.iono_sigma_m * (a[i] + frac * (b[i] - a[i])));
        self.iono_ned_m = iono;
        self.fix_in_interval += 1;
        if self.fix_in_interval >= self.fixes_per_step {
            self.fix_in_interval = 0;
            self.node_prev = self.node_next;
            self.node_next = self.node_next.stepped(&mut self.iono);
        }

        let run = &mut self.run;
        let white = Vector3::new(
            self.sigma_hor_m * rng::normal(run),
            self.sigma_hor_m * rng::normal(run),
            self.sigma_ver_m * rng::normal(run),
        );
        let v_err = Vector3::from_fn(|_, _| self.sigma_vel_mps * rng::normal(run));
        let e_ned = iono + white;

        let pos = truth.pos;
        let m = wgs84::radius_meridian_m(pos.lat_rad);
        let n = wgs84::radius_prime_vertical_m(pos.lat_rad);
        let cos_lat = pos.lat_rad.cos().abs().max(MIN_COS_LAT);
        let mut meas = pos;
        meas.lat_rad = pos.lat_rad + e_ned.x / (m + pos.h_m);
        meas.lon_rad = pos.lon_rad + e_ned.y / ((n + pos.h_m) * cos_lat);
        meas.h_m = pos.h_m - e_ned.z;
        GnssFix {
            t_us: truth.t_us,
            pos: meas,
            v_ned_mps: truth.v_ned_mps + v_err,
            sigma_hor_m: self.sigma_hor_m,
            sigma_ver_m: self.sigma_ver_m,
            sigma_vel_mps: self.sigma_vel_mps,
        }
    }

    /// Ionospheric position error of the last fix (before the first fix: of the first one),
    /// NED, m.
    pub fn iono_ned_m(&self) -> Vector3<f64> {
        self.iono_ned_m
    }
}
