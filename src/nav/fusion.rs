//! The fused horizontal position (paper, "IA-VNS flow diagram": the navigation output `x̂`
//! takes its horizontal position from the IA-VNS once GNSS is lost, its attitude, altitude and
//! velocity from the INS).
//!
//! - The configured visual system's fix `zeta_eb` at a frame, against the INS position at the
//!   same exposure (pose history), gives a horizontal offset (NED metres). Every later solution
//!   is the INS's with that offset added: the visual position carried to the solution's time by
//!   the INS's ground velocity. A new fix replaces the offset.
//! - Before the GNSS loss the INS (GNSS-aided) is published unchanged; offsets are kept ready
//!   so that the first denied solution already has one.
//! - The visual position's variance per horizontal axis grows with the distance `d` flown since
//!   the visual system started: `σ²(d) = σ₀² + q·d + (k·d)²` (a start error, a random walk
//!   along the path and a scale error; fitted by `tools/fit_vision_sigma.py`, docs/FUSION.md).
//!   Between fixes, and after the last one when the track is lost, the INS's own horizontal
//!   variance growth since the fix is added: after a loss the position is the INS's dead
//!   reckoning from the last visual position, with a covariance that grows as the INS's does.
//! - The source is [`PositionSource::Vision`] while fixes are fresh and
//!   [`PositionSource::Ins`] otherwise; each change is reported so that the navigator moves the
//!   reset counter.

use nalgebra::{Matrix2, Vector2};

use super::history::PoseHistory;
use super::solution::{NavSolution, PositionSource, VisionFix, VisionState};
use crate::math::wgs84::{self, Geodetic};

/// Settings of the fused solution ([`super::NavConfig::fusion`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionConfig {
    /// σ₀: the visual position's error at its start, per horizontal axis, m.
    pub sigma0_m: f64,
    /// q: its random-walk growth along the path, m² per metre flown.
    pub q_m2_per_m: f64,
    /// k: its growth proportional to the distance flown (scale error), per axis, m/m.
    pub k_per_m: f64,
    /// A fix older than this no longer counts as the visual system's position, µs: the source
    /// falls back to the INS (dead reckoning from that fix).
    pub max_fix_age_us: u64,
}

impl Default for FusionConfig {
    /// The IA-VNS's error over scenario #2 over MX, seeds 1–100, fitted by
    /// `tools/fit_vision_sigma.py --fit docs/results/vision-mc-s2-mx` (docs/FUSION.md).
    fn default() -> Self {
        Self {
            sigma0_m: 12.4,
            q_m2_per_m: 0.0,
            k_per_m: 0.0024,
            max_fix_age_us: 1_000_000,
        }
    }
}

/// Why a fusion configuration is invalid.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("fusion.{0} = {1}: must be finite and ≥ 0")]
pub struct FusionConfigError(pub &'static str, pub f64);

impl FusionConfig {
    /// Check every parameter.
    pub fn validate(&self) -> Result<(), FusionConfigError> {
        for (name, v) in [
            ("sigma0_m", self.sigma0_m),
            ("q_m2_per_m", self.q_m2_per_m),
            ("k_per_m", self.k_per_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(FusionConfigError(name, v));
            }
        }
        Ok(())
    }

    /// The visual position's variance per horizontal axis after `distance_m` flown since its
    /// start, m².
    pub fn vision_variance_m2(&self, distance_m: f64) -> f64 {
        let d = distance_m.max(0.0);
        self.sigma0_m * self.sigma0_m + self.q_m2_per_m * d + (self.k_per_m * d).powi(2)
    }
}

/// The visual horizontal position, as an offset from the INS.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Anchor {
    /// Exposure time of the fix, µs.
    fix_t_us: u64,
    /// Fix minus INS at the exposure, north and east, m.
    offset_ne_m: Vector2<f64>,
    /// The fix's variance per horizontal axis, m².
    variance_m2: f64,
    /// The INS's horizontal covariance when the fix was taken in, m².
    ins_p_h_m2: Matrix2<f64>,
}

/// The fusion's state (owned by the navigator).
#[derive(Debug, Clone, Default)]
pub(crate) struct Fusion {
    /// Distance flown since the visual system started, m (`None` while it has not).
    distance_m: Option<f64>,
    /// The visual position's variance per axis at its start, m²: σ₀² at a start from the
    /// GNSS-aided INS, the fused variance then at a restart from the fused pose.
    start_variance_m2: Option<f64>,
    /// The relative variance of the start's scale beyond `k²`: a restart while denied takes
    /// its scale from the dead-reckoned INS distance, whose velocity error is then a scale
    /// error `σ_v / |v|` (0 at a start with GNSS, where `k` was fitted).
    start_scale_variance: f64,
    /// Time of the latest solution, µs.
    last_t_us: Option<u64>,
    anchor: Option<Anchor>,
    source: Option<PositionSource>,
    /// Fixes taken in.
    pub(crate) fixes: u64,
    /// Fixes without an INS pose at their exposure (outside the history), dropped.
    pub(crate) fixes_without_ins: u64,
}

/// Whether the visual system has a map whose scale dates from its start.
fn started(state: VisionState) -> bool {
    matches!(state, VisionState::Tracking | VisionState::Relocalising)
}

/// `pos` moved by `ne_m` metres north and east (first order about `pos`: offsets are a few
/// hundred metres at most).
pub(super) fn offset(pos: &Geodetic, ne_m: &Vector2<f64>) -> Geodetic {
    let m = wgs84::radius_meridian_m(pos.lat_rad) + pos.h_m;
    let n = wgs84::radius_prime_vertical_m(pos.lat_rad) + pos.h_m;
    Geodetic {
        lat_rad: pos.lat_rad + ne_m.x / m,
        lon_rad: pos.lon_rad + ne_m.y / (n * pos.lat_rad.cos()),
        h_m: pos.h_m,
    }
}

/// `(σ_v / |v|)²` of the INS's horizontal velocity (per axis) while denied, else 0.
fn restart_scale_variance(nav: &NavSolution) -> f64 {
    if !nav.ins_status.gnss_denied {
        return 0.0;
    }
    let p_v = &nav.cov.velocity_m2ps2;
    let speed2 = nav.v_ned_mps.xy().norm_squared();
    let r = 0.5 * (p_v[(0, 0)] + p_v[(1, 1)]) / speed2;
    if r.is_finite() { r.max(0.0) } else { 0.0 }
}

impl Fusion {
    /// A new INS: its covariance is no longer comparable with the anchor's.
    pub(crate) fn ins_restarted(&mut self) {
        self.anchor = None;
    }

    /// Fuse `nav` (the INS's solution, with the visual status and fix filled in) in place.
    /// Returns whether the horizontal source changed.
    pub(crate) fn fuse(
        &mut self,
        cfg: &FusionConfig,
        nav: &mut NavSolution,
        history: &PoseHistory,
    ) -> bool {
        let dt_s = self
            .last_t_us
            .map_or(0.0, |t| nav.t_us.saturating_sub(t) as f64 * 1e-6);
        self.last_t_us = Some(nav.t_us);
        if started(nav.vision.state) {
            let speed_mps = nav.v_ned_mps.xy().norm();
            self.distance_m = Some(match self.distance_m {
                Some(d) if speed_mps.is_finite() => d + speed_mps * dt_s,
                Some(d) => d,
                None => {
                    self.start_variance_m2 = Some(self.variance_now_m2(cfg, nav));
                    self.start_scale_variance = restart_scale_variance(nav);
                    0.0
                }
            });
        } else if self.distance_m.is_some() {
            // Re-initialising: a new map, a new scale.
            self.distance_m = None;
        }
        if let Some(fix) = nav.vision_fix.filter(|_| started(nav.vision.state))
            && self.anchor.is_none_or(|a| a.fix_t_us != fix.t_us)
        {
            self.take_fix(cfg, &fix, nav, history);
        }
        let source = self.apply(cfg, nav);
        let changed = self.source.is_some_and(|s| s != source);
        self.source = Some(source);
        nav.horizontal_source = source;
        changed
    }

    fn take_fix(
        &mut self,
        cfg: &FusionConfig,
        fix: &VisionFix,
        nav: &NavSolution,
        history: &PoseHistory,
    ) {
        let Some(ins_at_fix) = history.at(fix.t_us) else {
            self.fixes_without_ins += 1;
            return;
        };
        let d_ned = wgs84::ned_difference_m(&ins_at_fix.pos, &fix.pos);
        if !d_ned.iter().all(|x| x.is_finite()) {
            self.fixes_without_ins += 1;
            return;
        }
        self.fixes += 1;
        let d = self.distance_m.unwrap_or(0.0);
        let start_m2 = self
            .start_variance_m2
            .unwrap_or(cfg.sigma0_m * cfg.sigma0_m);
        self.anchor = Some(Anchor {
            fix_t_us: fix.t_us,
            offset_ne_m: d_ned.xy(),
            variance_m2: cfg.vision_variance_m2(d) - cfg.sigma0_m * cfg.sigma0_m
                + start_m2
                + self.start_scale_variance * d * d,
            ins_p_h_m2: nav.cov.position_m2.fixed_view::<2, 2>(0, 0).into_owned(),
        });
    }

    /// The horizontal offset a visual start takes from the INS ([`super::vision`]): the fused
    /// position's while denied with a visual position, none otherwise.
    pub(crate) fn start_offset_ne_m(&self, gnss_denied: bool) -> Option<Vector2<f64>> {
        self.anchor.filter(|_| gnss_denied).map(|a| a.offset_ne_m)
    }

    /// The per-axis variance a visual system starting now takes: σ₀² from the GNSS-aided INS,
    /// the fused position's (its larger axis) from the fused pose after the loss.
    fn variance_now_m2(&self, cfg: &FusionConfig, nav: &NavSolution) -> f64 {
        let sigma0_m2 = cfg.sigma0_m * cfg.sigma0_m;
        match self.anchor {
            Some(a) if nav.ins_status.gnss_denied => {
                let p_h = nav.cov.position_m2.fixed_view::<2, 2>(0, 0).into_owned();
                let grown = (p_h - a.ins_p_h_m2).diagonal().max().max(0.0);
                (a.variance_m2 + grown).max(sigma0_m2)
            }
            _ => sigma0_m2,
        }
    }

    fn apply(&self, cfg: &FusionConfig, nav: &mut NavSolution) -> PositionSource {
        if !nav.ins_status.gnss_denied {
            return PositionSource::Ins;
        }
        let Some(a) = self.anchor else {
            return PositionSource::Ins;
        };
        nav.pos = offset(&nav.pos, &a.offset_ne_m);
        let p_h = nav.cov.position_m2.fixed_view::<2, 2>(0, 0).into_owned();
        // The INS's growth since the fix (its horizontal variance only grows while denied; a
        // negative diagonal would only come from rounding).
        let mut grown = p_h - a.ins_p_h_m2;
        for i in 0..2 {
            grown[(i, i)] = grown[(i, i)].max(0.0);
        }
        let fused = Matrix2::identity() * a.variance_m2 + grown;
        nav.cov
            .position_m2
            .fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&fused);
        // The vertical stays the INS's; horizontal-vertical terms are dropped with the INS's
        // horizontal error.
        for i in 0..2 {
            nav.cov.position_m2[(i, 2)] = 0.0;
            nav.cov.position_m2[(2, i)] = 0.0;
        }
        let fresh = nav.vision.state == VisionState::Tracking
            && nav.t_us.saturating_sub(a.fix_t_us) <= cfg.max_fix_age_us;
        if fresh {
            PositionSource::Vision
        } else {
            PositionSource::Ins
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav::history::HistoryPose;
    use crate::nav::solution::{VisionStatus, fixtures};

    const DT_US: u64 = 100_000;

    /// The fixture flying east at 30 m/s, at `t_us`, denied or not, with the INS horizontal
    /// variance growing 1 m² per second.
    fn ins_at(t_us: u64, denied: bool) -> NavSolution {
        let mut nav = fixtures::solution();
        let dt_s = (t_us as f64 - 1e6) * 1e-6;
        let east_m = 30.0 * dt_s;
        nav.t_us = t_us;
        nav.pos = offset(&nav.pos, &Vector2::new(0.0, east_m));
        nav.ins_status.gnss_denied = denied;
        nav.cov.position_m2[(0, 0)] += dt_s.max(0.0);
        nav.cov.position_m2[(1, 1)] += dt_s.max(0.0);
        nav.cov.position_m2[(0, 2)] = 0.5;
        nav.cov.position_m2[(2, 0)] = 0.5;
        nav
    }

    fn pose(nav: &NavSolution) -> HistoryPose {
        HistoryPose {
            t_us: nav.t_us,
            pos: nav.pos,
            v_ned_mps: nav.v_ned_mps,
            q_nb: nav.q_nb,
        }
    }

    fn tracking(nav: &mut NavSolution, fix: Option<VisionFix>) {
        nav.vision = VisionStatus {
            state: VisionState::Tracking,
            ..VisionStatus::INACTIVE
        };
        nav.vision_fix = fix;
    }

    /// A fix `ne_m` away from the INS at `nav`'s time.
    fn fix_beside(nav: &NavSolution, ne_m: Vector2<f64>) -> VisionFix {
        VisionFix {
            t_us: nav.t_us,
            pos: offset(&nav.pos, &ne_m),
            q_nb: nav.q_nb,
        }
    }

    /// Horizontal distance between two positions, m.
    fn horizontal_m(a: &Geodetic, b: &Geodetic) -> Vector2<f64> {
        wgs84::ned_difference_m(a, b).xy()
    }

    #[test]
    fn before_the_loss_the_ins_is_published_unchanged() {
        let cfg = FusionConfig::default();
        let mut fusion = Fusion::default();
        let mut history = PoseHistory::new(2_000_000);
        let mut nav = ins_at(1_000_000, false);
        history.push(pose(&nav));
        let ins = nav;
        let fix = fix_beside(&nav, Vector2::new(40.0, -10.0));
        tracking(&mut nav, Some(fix));
        assert!(!fusion.fuse(&cfg, &mut nav, &history));
        assert_eq!(nav.pos, ins.pos);
        assert_eq!(nav.cov, ins.cov);
        assert_eq!(nav.horizontal_source, PositionSource::Ins);
        assert_eq!(fusion.fixes, 1, "the offset is kept ready for the loss");
    }

    /// The fix taken at one frame and carried by the INS over the next IMU steps: the fused
    /// position keeps the fix's offset from the INS; the covariance is the fix's variance
    /// plus the INS's growth since; the source changes once, to vision.
    #[test]
    fn after_the_loss_the_fix_is_carried_by_the_ins() {
        let cfg = FusionConfig::default();
        let mut fusion = Fusion::default();
        let mut history = PoseHistory::new(2_000_000);
        let mut before = ins_at(900_000, false);
        history.push(pose(&before));
        assert!(!fusion.fuse(&cfg, &mut before, &history));
        let mut at_fix = ins_at(1_000_000, true);
        history.push(pose(&at_fix));
        let ne_m = Vector2::new(40.0, -10.0);
        let fix = fix_beside(&at_fix, ne_m);
        tracking(&mut at_fix, Some(fix));
        assert!(fusion.fuse(&cfg, &mut at_fix, &history), "INS → vision");
        assert_eq!(at_fix.horizontal_source, PositionSource::Vision);
        for k in 1..=5 {
            let mut nav = ins_at(1_000_000 + k * DT_US, true);
            history.push(pose(&nav));
            let ins = nav;
            tracking(&mut nav, Some(fix));
            assert!(!fusion.fuse(&cfg, &mut nav, &history));
            assert_eq!(nav.horizontal_source, PositionSource::Vision);
            // The offset is applied to first order about the current position: the
            // east-west metres shrink by 30 m·k·0.1 s / R relative, far under a millimetre.
            let d = horizontal_m(&ins.pos, &nav.pos) - ne_m;
            assert!(d.norm() < 1e-3, "step {k}: {d}");
            assert_eq!(nav.pos.h_m, ins.pos.h_m);
            let grown_m2 = k as f64 * 0.1;
            let expected = cfg.vision_variance_m2(0.0) + grown_m2;
            for i in 0..2 {
                let p = nav.cov.position_m2[(i, i)];
                assert!(
                    (p - expected).abs() < 1e-9,
                    "step {k} axis {i}: {p} vs {expected}"
                );
                assert_eq!(nav.cov.position_m2[(i, 2)], 0.0);
            }
            assert_eq!(nav.cov.position_m2[(2, 2)], ins.cov.position_m2[(2, 2)]);
        }
    }

    /// σ²(d) = σ₀² + q·d + (k·d)² with d the distance flown since the visual start.
    #[test]
    fn the_variance_grows_with_the_distance_since_the_visual_start() {
        let cfg = FusionConfig {
            sigma0_m: 10.0,
            q_m2_per_m: 0.5,
            k_per_m: 0.003,
            max_fix_age_us: 1_000_000,
        };
        let mut fusion = Fusion::default();
        let mut history = PoseHistory::new(2_000_000);
        let steps = 1_000;
        let mut last = None;
        for k in 0..=steps {
            let mut nav = ins_at(1_000_000 + k * DT_US, true);
            history.push(pose(&nav));
            let fix = fix_beside(&nav, Vector2::new(5.0, 5.0));
            tracking(&mut nav, Some(fix));
            fusion.fuse(&cfg, &mut nav, &history);
            last = Some(nav);
        }
        // 100 s at 30 m/s. The system started while denied: its scale also carries the INS's
        // velocity error, (σ_v/|v|)² = ½(0.04 + 0.09) / 30² per axis.
        let d_m = 3_000.0;
        let scale_var = 0.5 * (0.04 + 0.09) / 900.0;
        let expected: f64 = 100.0 + 0.5 * d_m + (0.003_f64.powi(2) + scale_var) * d_m * d_m;
        let p = last.expect("solutions").cov.position_m2[(0, 0)];
        assert!((p - expected).abs() < 1e-6 * expected, "{p} vs {expected}");
    }

    /// Tracking lost: the source goes back to the INS (once), the position keeps the last
    /// offset (dead reckoning from the last fix, no jump) and the variance grows as the INS's.
    #[test]
    fn a_lost_track_falls_back_to_dead_reckoning_from_the_last_fix() {
        let cfg = FusionConfig::default();
        let mut fusion = Fusion::default();
        let mut history = PoseHistory::new(2_000_000);
        let ne_m = Vector2::new(-25.0, 60.0);
        let mut nav = ins_at(1_000_000, true);
        history.push(pose(&nav));
        let fix = fix_beside(&nav, ne_m);
        tracking(&mut nav, Some(fix));
        fusion.fuse(&cfg, &mut nav, &history);
        assert_eq!(nav.horizontal_source, PositionSource::Vision);
        let mut changes = 0;
        for k in 1..=50 {
            let mut nav = ins_at(1_000_000 + k * DT_US, true);
            history.push(pose(&nav));
            let ins = nav;
            nav.vision.state = VisionState::Relocalising;
            nav.vision_fix = None;
            changes += usize::from(fusion.fuse(&cfg, &mut nav, &history));
            assert_eq!(nav.horizontal_source, PositionSource::Ins);
            let d = horizontal_m(&ins.pos, &nav.pos) - ne_m;
            assert!(d.norm() < 1e-3, "step {k}: {d}");
            let expected = cfg.vision_variance_m2(0.0) + k as f64 * 0.1;
            assert!((nav.cov.position_m2[(1, 1)] - expected).abs() < 1e-9);
        }
        assert_eq!(changes, 1);
    }

    #[test]
    fn a_fix_older_than_the_limit_is_no_longer_the_source() {
        let cfg = FusionConfig::default();
        let mut fusion = Fusion::default();
        let mut history = PoseHistory::new(2_000_000);
        let mut nav = ins_at(1_000_000, true);
        history.push(pose(&nav));
        let fix = fix_beside(&nav, Vector2::new(1.0, 1.0));
        tracking(&mut nav, Some(fix));
        fusion.fuse(&cfg, &mut nav, &history);
        let late = 1_000_000 + cfg.max_fix_age_us;
        let mut nav = ins_at(late, true);
        tracking(&mut nav, Some(fix));
        fusion.fuse(&cfg, &mut nav, &history);
        assert_eq!(nav.horizontal_source, PositionSource::Vision);
        let mut nav = ins_at(late + 1, true);
        tracking(&mut nav, Some(fix));
        assert!(fusion.fuse(&cfg, &mut nav, &history));
        assert_eq!(nav.horizontal_source, PositionSource::Ins);
    }

    /// A fix outside the pose history has no INS pose to be compared with: not fused, counted.
    #[test]
    fn a_fix_without_an_ins_pose_is_counted_and_dropped() {
        let cfg = FusionConfig::default();
        let mut fusion = Fusion::default();
        let history = PoseHistory::new(2_000_000);
        let mut nav = ins_at(1_000_000, true);
        let ins = nav;
        let fix = fix_beside(&nav, Vector2::new(3.0, 4.0));
        tracking(&mut nav, Some(fix));
        fusion.fuse(&cfg, &mut nav, &history);
        assert_eq!((fusion.fixes, fusion.fixes_without_ins), (0, 1));
        assert_eq!(nav.pos, ins.pos);
        assert_eq!(nav.horizontal_source, PositionSource::Ins);
    }

    #[test]
    fn invalid_settings_are_refused_by_name() {
        let bad = FusionConfig {
            k_per_m: f64::NAN,
            ..FusionConfig::default()
        };
        assert_eq!(bad.validate().map_err(|e| e.0), Err("k_per_m"));
        let bad = FusionConfig {
            sigma0_m: -1.0,
            ..FusionConfig::default()
        };
        assert_eq!(bad.validate().map_err(|e| e.0), Err("sigma0_m"));
        assert!(FusionConfig::default().validate().is_ok());
    }
}
