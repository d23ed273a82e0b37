//! Navigation system error (NSE) of one flight, as the paper's INSE/VNSE tables and figures define
//! it (docs/MONTECARLO.md "Navigation system error"; docs/REFERENCES.md P4, and A6.6: per-run time
//! histories sampled every 10 s of mission time): Euler-angle and attitude-norm errors, vertical
//! error, horizontal error in metres and as a percentage of the distance flown. Errors are
//! `estimate − truth`.

use ianav::math::{angle, so3, wgs84};
use ianav::nav::NavSolution;

use crate::control::NavEstimate;
use crate::flight::{FlightObserver, TruthSample, VisionOutput};

/// Mission-time spacing of the metrics samples, s (the paper's post-processing samples the
/// error histories every 10 s: 381 samples over 3,800 s).
pub const SAMPLE_PERIOD_S: f64 = 10.0;

/// Below this ground distance flown, the horizontal error as a percentage of the distance is
/// undefined (reported as NaN): at mission time 0 the distance is exactly 0, and over the
/// first metre the ratio would only amplify the initial error.
pub const MIN_DISTANCE_FOR_PERCENT_M: f64 = 1.0;

/// Tolerance on the mission time when matching output samples to the 10-s grid, s. Output
/// samples come every 0.1 s and mission times are exact to ~1e-9 s, so any value between
/// those two scales selects the same samples.
const GRID_TOLERANCE_S: f64 = 1e-6;

/// The navigation errors at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NseSample {
    /// Mission time, s.
    pub t_s: f64,
    /// Yaw error ψ_est − ψ_truth wrapped onto (−180°, 180°], deg.
    pub yaw_deg: f64,
    /// Pitch error, deg.
    pub pitch_deg: f64,
    /// Bank error, wrapped onto (−180°, 180°], deg.
    pub bank_deg: f64,
    /// Attitude error `‖Log(q_nb_truth⁻¹ ∘ q_nb_est)‖`, deg (in [0°, 180°]).
    pub att_norm_deg: f64,
    /// Vertical error `h_est − h_truth`, m.
    pub alt_m: f64,
    /// Horizontal error: norm of the north and east components of the vector from the true
    /// to the estimated position, in the local level frame at the truth, m.
    pub hor_m: f64,
    /// Horizontal error as a percentage of the ground distance flown since mission time 0
    /// (NaN while that distance is below [`MIN_DISTANCE_FOR_PERCENT_M`]), %.
    pub hor_pct: f64,
    /// Ground distance flown since mission time 0 (truth), m.
    pub distance_m: f64,
}

/// Navigation errors of `estimate` against `truth`.
pub fn nse(truth: &TruthSample, estimate: &NavEstimate) -> NseSample {
    nse_pose(truth, &estimate.pos, &estimate.q_nb)
}

/// Navigation errors of a position and attitude against `truth` (the VNS's pose has no
/// velocity).
pub fn nse_pose(
    truth: &TruthSample,
    pos: &ianav::math::wgs84::Geodetic,
    q_nb: &nalgebra::UnitQuaternion<f64>,
) -> NseSample {
    let euler_est = so3::euler_zyx(q_nb);
    let euler_truth = so3::euler_zyx(&truth.q_nb);
    let d_euler_deg = (euler_est - euler_truth).map(|d| angle::wrap_pi(d).to_degrees());
    let att_norm_deg = so3::log(&(truth.q_nb.inverse() * q_nb)).norm().to_degrees();
    let d_ned_m = wgs84::ned_difference_m(&truth.pos, pos);
    let hor_m = d_ned_m.x.hypot(d_ned_m.y);
    let hor_pct = if truth.distance_m >= MIN_DISTANCE_FOR_PERCENT_M {
        100.0 * hor_m / truth.distance_m
    } else {
        f64::NAN
    };
    NseSample {
        t_s: truth.t_s,
        yaw_deg: d_euler_deg.x,
        pitch_deg: d_euler_deg.y,
        bank_deg: d_euler_deg.z,
        att_norm_deg,
        alt_m: pos.h_m - truth.pos.h_m,
        hor_m,
        hor_pct,
        distance_m: truth.distance_m,
    }
}

/// Normalised estimation error squared of the navigation attitude and velocity: `eᵀ P⁻¹ e` with
/// the attitude error in the filter's own tangent convention (`q_truth = q̂ ∘ Exp(δθ)`, so
/// `δθ = Log(q̂⁻¹ q_truth)`) against its 3×3 attitude covariance, and the NED ground-velocity
/// error against the velocity covariance. Each is χ²(3) when the filter is consistent. `None`
/// for a covariance that cannot be inverted.
pub fn nees(truth: &TruthSample, sol: &NavSolution) -> Option<(f64, f64)> {
    let d_theta = so3::log(&(sol.q_nb.inverse() * truth.q_nb));
    let d_v = sol.v_ned_mps - truth.v_ned_mps;
    let att = sol.cov.attitude_rad2.try_inverse()?;
    let vel = sol.cov.velocity_m2ps2.try_inverse()?;
    Some((d_theta.dot(&(att * d_theta)), d_v.dot(&(vel * d_v))))
}

/// Normalised estimation error squared of the navigation horizontal position: the north and east
/// components of the error (local level frame at the truth) against the 2×2 horizontal block
/// of the position covariance; χ²(2) when the filter is consistent. `None` for a covariance
/// that cannot be inverted.
pub fn nees_horizontal_position(truth: &TruthSample, sol: &NavSolution) -> Option<f64> {
    let d = wgs84::ned_difference_m(&truth.pos, &sol.pos);
    let e = nalgebra::Vector2::new(d.x, d.y);
    let p = sol
        .cov
        .position_m2
        .fixed_view::<2, 2>(0, 0)
        .into_owned()
        .try_inverse()?;
    Some(e.dot(&(p * e)))
}

/// Observer collecting the NSE at mission times 0, 10, 20, … s (the first output sample at or
/// after each grid time) and at the end of the flight; with a camera, every visual system's
/// too (NaN samples where it does not track: before its initialisation, while relocalising).
#[derive(Debug, Clone)]
pub struct MetricsRecorder {
    samples: Vec<NseSample>,
    /// Next grid time to record, s.
    next_t_s: f64,
    /// The latest pair seen, kept to record the final instant in [`MetricsRecorder::finish`].
    last: Option<(TruthSample, NavEstimate)>,
    /// The visual systems' samples on the same grid (empty without a camera).
    vision: Vec<VisionTrack>,
}

/// One visual system's samples.
#[derive(Debug, Clone)]
struct VisionTrack {
    name: &'static str,
    samples: Vec<NseSample>,
    next_t_s: f64,
    /// The sample of the latest output (NaN when not tracking).
    last: Option<NseSample>,
}

/// An NSE sample at `t_s` with every error NaN (the estimator had no solution then).
pub fn missing_sample(t_s: f64, distance_m: f64) -> NseSample {
    NseSample {
        t_s,
        yaw_deg: f64::NAN,
        pitch_deg: f64::NAN,
        bank_deg: f64::NAN,
        att_norm_deg: f64::NAN,
        alt_m: f64::NAN,
        hor_m: f64::NAN,
        hor_pct: f64::NAN,
        distance_m,
    }
}

impl Default for MetricsRecorder {
    fn default() -> Self {
        Self::new()
    }
}

impl MetricsRecorder {
    /// An empty recorder.
    pub fn new() -> Self {
        Self {
            samples: Vec::new(),
            next_t_s: 0.0,
            last: None,
            vision: Vec::new(),
        }
    }

    /// Each visual system's name and samples, in the flight's order (empty without a camera),
    /// completed like [`MetricsRecorder::finish`].
    pub fn vision_samples(&self) -> Vec<(&'static str, Vec<NseSample>)> {
        self.vision
            .iter()
            .map(|track| {
                let mut v = track.samples.clone();
                if let Some(last) = track.last {
                    let recorded_up_to = v.last().map_or(f64::NEG_INFINITY, |s| s.t_s);
                    if last.t_s >= 0.0 && last.t_s > recorded_up_to + GRID_TOLERANCE_S {
                        v.push(last);
                    }
                }
                (track.name, v)
            })
            .collect()
    }

    /// Samples recorded so far (without the final instant unless it fell on the grid).
    pub fn samples(&self) -> &[NseSample] {
        &self.samples
    }

    /// The samples, completed with the last output instant (`t_end`) if it was not on the
    /// 10-s grid.
    pub fn finish(mut self) -> Vec<NseSample> {
        if let Some((truth, estimate)) = self.last.take() {
            let recorded_up_to = self.samples.last().map_or(f64::NEG_INFINITY, |s| s.t_s);
            if truth.t_s >= 0.0 && truth.t_s > recorded_up_to + GRID_TOLERANCE_S {
                self.samples.push(nse(&truth, &estimate));
            }
        }
        self.samples
    }
}

impl FlightObserver for MetricsRecorder {
    fn estimate_sample(&mut self, truth: &TruthSample, estimate: &NavEstimate) {
        if truth.t_s >= self.next_t_s - GRID_TOLERANCE_S {
            self.samples.push(nse(truth, estimate));
            // Next grid point strictly after this sample (robust to output periods that do
            // not divide 10 s).
            let k = (truth.t_s / SAMPLE_PERIOD_S + GRID_TOLERANCE_S).floor() + 1.0;
            self.next_t_s = k * SAMPLE_PERIOD_S;
        }
        self.last = Some((*truth, *estimate));
    }

    fn vision_outputs(&mut self, truth: &TruthSample, t_us: u64, systems: &[VisionOutput]) {
        if truth.t_s < 0.0 {
            return;
        }
        for out in systems {
            if out.status.state == ianav::nav::VisionState::Inactive {
                continue;
            }
            let track = match self.vision.iter().position(|t| t.name == out.name) {
                Some(i) => &mut self.vision[i],
                None => {
                    self.vision.push(VisionTrack {
                        name: out.name,
                        samples: Vec::new(),
                        next_t_s: 0.0,
                        last: None,
                    });
                    let n = self.vision.len();
                    &mut self.vision[n - 1]
                }
            };
            let sample = match out.fix.filter(|f| f.t_us == t_us) {
                Some(f) => nse_pose(truth, &f.pos, &f.q_nb),
                None => missing_sample(truth.t_s, truth.distance_m),
            };
            if truth.t_s >= track.next_t_s - GRID_TOLERANCE_S {
                track.samples.push(sample);
                let k = (truth.t_s / SAMPLE_PERIOD_S + GRID_TOLERANCE_S).floor() + 1.0;
                track.next_t_s = k * SAMPLE_PERIOD_S;
            }
            track.last = Some(sample);
        }
    }
}

/// `x` with `decimals` fixed decimals, without a sign on a value that rounds to zero (so
/// `-0.0` and `-1e-12` print as `0.000`): a byte-stable text form for files and reports.
/// Non-finite values print as `NaN`, `inf` and `-inf`.
pub fn format_fixed(x: f64, decimals: usize) -> String {
    let s = format!("{x:.decimals$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.bytes().all(|b| b == b'0' || b == b'.') => rest.to_owned(),
        _ => s,
    }
}
