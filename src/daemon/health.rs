//! Self-checks before a solution is published: the autopilot weighs our position by the
//! accuracy we claim, so a solution the daemon cannot back must not reach it. Pure: fed the
//! solutions and the GNSS fixes in sensor time, no clock.
//!
//! A solution is withheld while either holds:
//! - **IMU stream too slow**: fewer than [`MIN_IMU_RATE_HZ`] solutions per second over the
//!   last [`IMU_WINDOW_US`] (the INS is validated from 25 Hz; ArduPlane's default
//!   RAW_IMU stream is 1 Hz, on which the INS ran kilometres off while claiming 50–350 m).
//! - **The INS disagrees with GNSS that is still there**: [`MAX_GATED_OF_RECENT`] of the last
//!   [`RECENT_FIXES`] fixes were refused by the INS's innovation gate while fixes keep
//!   arriving (five in a row latch its GNSS-denied mode). Whatever the INS then publishes
//!   contradicts the receiver the autopilot also has. GNSS returning after a real loss is
//!   not a disagreement: the denied INS tests no fix until it is re-initialised at one.
//!
//! Publication resumes after [`RECOVERY_US`] without either condition.

use std::collections::VecDeque;

use crate::nav::NavSolution;

/// Slowest IMU rate at which solutions are published, Hz.
pub const MIN_IMU_RATE_HZ: f64 = 20.0;
/// Window over which the IMU rate is measured, µs.
pub const IMU_WINDOW_US: u64 = 2_000_000;
/// Fixes arriving within this fraction of the INS's GNSS timeout mean GNSS is present: below
/// 1, a real loss (no fix for the whole timeout) is never taken for a disagreement.
pub const FIX_PRESENT_FRACTION: f64 = 0.8;
/// Number of recent fix innovations watched.
pub const RECENT_FIXES: usize = 10;
/// This many gated fixes among the recent ones withhold the solution.
pub const MAX_GATED_OF_RECENT: usize = 3;
/// Healthy time needed before publishing again, µs.
pub const RECOVERY_US: u64 = 5_000_000;

/// Why solutions are withheld.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Problem {
    /// The IMU stream runs at this rate, Hz.
    ImuRate(f64),
    /// The INS refuses the GNSS fixes that keep arriving.
    GnssDisagreement,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::ImuRate(hz) => write!(f, "IMU at {hz:.0} Hz"),
            Self::GnssDisagreement => write!(f, "INS disagrees with GNSS"),
        }
    }
}

/// A change of the publication state, to announce.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Transition {
    /// Publication stops.
    Withheld(Problem),
    /// Publication resumes.
    Resumed,
}

/// The checks' state.
#[derive(Debug, Clone)]
pub struct OutputHealth {
    gate_chi2: f64,
    fix_present_us: u64,
    imu_times_us: VecDeque<u64>,
    last_fix_us: Option<u64>,
    recent_gated: VecDeque<bool>,
    reset_counter: Option<u8>,
    /// Current problem, if any, and the last time one was seen.
    problem: Option<Problem>,
    last_problem_us: Option<u64>,
}

impl OutputHealth {
    /// Checks with the INS's GNSS gate (χ², 6 degrees of freedom) and GNSS timeout.
    pub fn new(gate_chi2: f64, gnss_timeout_s: f64) -> Self {
        Self {
            gate_chi2,
            fix_present_us: (FIX_PRESENT_FRACTION * gnss_timeout_s * 1e6) as u64,
            imu_times_us: VecDeque::new(),
            last_fix_us: None,
            recent_gated: VecDeque::new(),
            reset_counter: None,
            problem: None,
            last_problem_us: None,
        }
    }

    /// A valid GNSS fix reached the navigation at `t_us`.
    pub fn on_fix(&mut self, t_us: u64) {
        self.last_fix_us = Some(t_us);
    }

    /// The problem in force, if solutions are withheld.
    pub fn problem(&self) -> Option<Problem> {
        self.problem
    }

    /// Observe a solution: whether it may be published, and the change to announce.
    pub fn check(&mut self, sol: &NavSolution) -> (bool, Option<Transition>) {
        let t_us = sol.ins.t_us;
        // A reset (time going back) restarts the window.
        if self.imu_times_us.back().is_some_and(|b| *b > t_us) {
            self.imu_times_us.clear();
        }
        self.imu_times_us.push_back(t_us);
        while self
            .imu_times_us
            .front()
            .is_some_and(|f| t_us.saturating_sub(*f) > IMU_WINDOW_US)
        {
            self.imu_times_us.pop_front();
        }
        // A re-initialisation starts a new INS: its predecessor's gated fixes say nothing.
        if self.reset_counter != Some(sol.reset_counter) {
            self.reset_counter = Some(sol.reset_counter);
            self.recent_gated.clear();
        }
        if let Some(nis) = sol.ins.gnss_nis {
            self.recent_gated.push_back(nis > self.gate_chi2);
            if self.recent_gated.len() > RECENT_FIXES {
                self.recent_gated.pop_front();
            }
        }
        let found = self.find_problem(sol);
        let before = self.problem;
        if let Some(p) = found {
            self.last_problem_us = Some(t_us);
            self.problem = Some(p);
        } else if self.problem.is_some()
            && self
                .last_problem_us
                .is_none_or(|l| t_us.saturating_sub(l) >= RECOVERY_US)
        {
            self.problem = None;
        }
        let transition = match (before, self.problem) {
            (None, Some(p)) => Some(Transition::Withheld(p)),
            (Some(_), None) => Some(Transition::Resumed),
            _ => None,
        };
        (self.problem.is_none(), transition)
    }

    fn find_problem(&self, sol: &NavSolution) -> Option<Problem> {
        let t_us = sol.ins.t_us;
        // The rate once a whole window has been seen (the first samples after a start say
        // nothing about it). A single gap (a reboot, a link hiccup) in a fast stream leaves
        // the window rate high: only a stream that stays slow is caught.
        let span_us = self
            .imu_times_us
            .front()
            .map_or(0, |f| t_us.saturating_sub(*f));
        if span_us * 10 >= IMU_WINDOW_US * 9 {
            let rate_hz = (self.imu_times_us.len() - 1) as f64 * 1e6 / span_us as f64;
            if rate_hz < MIN_IMU_RATE_HZ {
                return Some(Problem::ImuRate(rate_hz));
            }
        }
        let fixes_present = self
            .last_fix_us
            .is_some_and(|f| t_us.abs_diff(f) <= self.fix_present_us);
        let gated = self.recent_gated.iter().filter(|g| **g).count();
        if fixes_present && gated >= MAX_GATED_OF_RECENT {
            return Some(Problem::GnssDisagreement);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sol(t_us: u64, dt_s: f64, gap: bool) -> NavSolution {
        let mut s = crate::io::mavlink_out::tests::solution();
        s.ins.t_us = t_us;
        s.ins.dt_s = dt_s;
        s.ins.imu_gap = gap;
        s.ins.gnss_denied = false;
        s.ins.gnss_nis = None;
        s
    }

    #[test]
    fn a_one_hertz_imu_stream_is_never_published_and_40_hz_is() {
        let mut h = OutputHealth::new(27.86, 1.5);
        // 40 Hz for 3 s: published throughout.
        for k in 0..120 {
            assert!(h.check(&sol(k * 25_000, 0.025, false)).0);
        }
        // The autopilot falls back to 1 Hz: from the second 1 s step on (the window then
        // holds 3 samples over 2 s), nothing is published.
        assert!(h.check(&sol(3_975_000, 1.0, true)).0);
        let (ok, tr) = h.check(&sol(4_975_000, 1.0, true));
        assert!(!ok);
        assert_eq!(tr, Some(Transition::Withheld(Problem::ImuRate(1.0))));
        for k in 2..10 {
            assert!(!h.check(&sol(3_975_000 + k * 1_000_000, 1.0, true)).0);
        }
        // 40 Hz again: withheld for the recovery time, then published.
        let t0 = 13_975_000;
        let mut resumed_at = None;
        for k in 1..400 {
            let t = t0 + k * 25_000;
            let (ok, tr) = h.check(&sol(t, 0.025, false));
            if tr == Some(Transition::Resumed) {
                resumed_at = Some(t);
            }
            assert_eq!(ok, resumed_at.is_some());
        }
        let r = resumed_at.expect("resumed");
        // The 2 s window still holds 1 Hz samples for about a second after the return.
        assert!(
            r - t0 >= RECOVERY_US && r - t0 <= RECOVERY_US + IMU_WINDOW_US,
            "{}",
            r - t0
        );
    }

    #[test]
    fn a_slow_stream_without_gap_flags_is_caught_by_the_window_rate() {
        let mut h = OutputHealth::new(27.86, 1.5);
        // 10 Hz, below the INS's gap threshold: the 2 s window measures it.
        let mut withheld = false;
        for k in 0..40 {
            withheld |= !h.check(&sol(k * 100_000, 0.1, false)).0;
        }
        assert!(withheld);
        assert!(matches!(h.problem(), Some(Problem::ImuRate(r)) if (r - 10.0).abs() < 0.5));
    }

    #[test]
    fn an_ins_refusing_gnss_that_is_still_there_is_withheld_but_a_real_loss_is_not() {
        let mut h = OutputHealth::new(27.86, 1.5);
        let mut s = sol(0, 0.01, false);
        // Fixes every second, three of the last ten gated.
        for k in 0..1_000_u64 {
            s.ins.t_us = k * 10_000;
            s.ins.gnss_nis = (k % 100 == 0).then_some(if k >= 700 { 50.0 } else { 3.0 });
            if k % 100 == 0 {
                h.on_fix(s.ins.t_us);
            }
            let ok = h.check(&s).0;
            assert_eq!(ok, k < 900, "k {k}");
        }
        // GNSS really lost: fixes at 1 Hz up to 10 s, then none; the INS declares the loss
        // after its 1.5 s timeout. Nothing is ever withheld.
        let mut h = OutputHealth::new(27.86, 1.5);
        let mut published = 0;
        for k in 0..3_000_u64 {
            s.ins.t_us = k * 10_000;
            let fix = k % 100 == 0 && k <= 1_000;
            s.ins.gnss_nis = fix.then_some(3.0);
            if fix {
                h.on_fix(s.ins.t_us);
            }
            s.ins.gnss_denied = s.ins.t_us > 11_500_000;
            published += usize::from(h.check(&s).0);
        }
        assert_eq!(published, 3_000);
    }
}
