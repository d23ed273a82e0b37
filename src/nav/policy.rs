//! When the navigator starts and re-initialises the INS (paper, "GNSS-denied scenarios": the
//! INS navigates GNSS-aided from the first fix until the loss; docs/DAEMON.md "Start"). The
//! rules are the core's, so that the simulator, the SITL vehicle, the daemon and a replay all
//! start the INS at the same event from the same inputs:
//!
//! - **First start**, at a GNSS fix, when an attitude is known at the fix's time (a start
//!   [`Alignment`] offered by the vehicle, else the autopilot's [`RefAttitude`]), the IMU
//!   streams, and the fix's velocity is precise (a fix without a measured down velocity says
//!   0 m/s with a σ of metres: fine to fuse, wrong to start from).
//! - **Start again once flying**: an INS started on the ground went through the take-off
//!   roll with models of a flying aircraft; the first fix at a flying airspeed starts it anew.
//! - **GNSS back**: the INS latches its GNSS-denied mode; valid fixes continuously for
//!   [`StartPolicy::reinit_after_us`] re-initialise it at the newest fix with the current
//!   attitude and sensor-error estimates.

use std::collections::VecDeque;

use crate::ins::{InsInit, InsSolution};
use crate::math::wgs84::Geodetic;
use crate::sensors::{Alignment, GnssFix, RefAttitude, SensorEvent};

/// The start rules' settings.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartPolicy {
    /// Epoch of the magnetic model the INS starts with, decimal year.
    pub mag_decimal_year: f64,
    /// Largest difference between a fix's time and the start attitude's, µs.
    pub attitude_max_age_us: u64,
    /// IMU rate needed over [`StartPolicy::imu_window_us`] before a start, Hz: before an
    /// autopilot grants the requested rates, its IMU can come at 1–4 Hz.
    pub min_imu_rate_hz: f64,
    /// Window of the IMU rate, µs.
    pub imu_window_us: u64,
    /// Largest velocity σ of a fix to start from, m/s.
    pub start_max_velocity_sigma_mps: f64,
    /// Fixes over that σ after which any fix will do (a receiver that never reports one).
    pub imprecise_fixes_before_any: u64,
    /// Start again at the first fix at or above this true airspeed, m/s, when first started
    /// below it (`None`: never).
    #[serde(default)]
    pub restart_airspeed_mps: Option<f64>,
    /// Continuous valid GNSS after a loss that re-initialises the INS, µs.
    pub reinit_after_us: u64,
    /// A gap between fixes longer than this restarts that count, µs.
    pub reinit_max_fix_gap_us: u64,
}

impl StartPolicy {
    /// The rules with their default settings and the magnetic model of `mag_decimal_year`.
    pub fn new(mag_decimal_year: f64) -> Self {
        Self {
            mag_decimal_year,
            attitude_max_age_us: 1_000_000,
            min_imu_rate_hz: 20.0,
            imu_window_us: 1_000_000,
            start_max_velocity_sigma_mps: 1.0,
            imprecise_fixes_before_any: 10,
            restart_airspeed_mps: None,
            reinit_after_us: 5_000_000,
            reinit_max_fix_gap_us: 1_500_000,
        }
    }
}

/// Why the INS was (re)started.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StartKind {
    /// The first start.
    First,
    /// Started again at a flying airspeed.
    Flying,
    /// Re-initialised after GNSS came back.
    GnssBack,
}

/// A (re)start of the INS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartRecord {
    /// Why.
    pub kind: StartKind,
    /// Time of the fix it started at, µs.
    pub t_us: u64,
    /// Position of that fix.
    pub pos: Geodetic,
}

/// What a start decision needs to know of the running INS.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Running<'a> {
    /// Whether the INS is GNSS-denied.
    pub gnss_denied: bool,
    /// Its latest solution, if any.
    pub last: Option<&'a InsSolution>,
}

/// What the rules have seen so far.
#[derive(Debug, Clone, Default)]
pub(crate) struct StartState {
    imu_times_us: VecDeque<u64>,
    tas_mps: Option<f64>,
    alignment: Option<Alignment>,
    ref_attitude: Option<RefAttitude>,
    imprecise_fixes: u64,
    started: bool,
    started_flying: bool,
    /// (first, newest) fix time of the current run of fixes while GNSS-denied.
    gnss_back: Option<(u64, u64)>,
    /// Fixes that could have started the INS but had no attitude at their time.
    pub fixes_without_attitude: u64,
}

impl StartState {
    /// See `event` (before the INS does); returns the start to make now, if any.
    pub fn observe(
        &mut self,
        policy: &StartPolicy,
        event: &SensorEvent,
        running: Option<Running<'_>>,
    ) -> Option<(StartRecord, InsInit)> {
        match event {
            SensorEvent::Imu(s) => {
                if self.imu_times_us.back().is_some_and(|t| *t > s.t_us) {
                    // The clock went back (an autopilot reboot): the rate starts over.
                    self.imu_times_us.clear();
                }
                self.imu_times_us.push_back(s.t_us);
                while self
                    .imu_times_us
                    .front()
                    .is_some_and(|t| s.t_us - *t >= policy.imu_window_us)
                {
                    self.imu_times_us.pop_front();
                }
                None
            }
            SensorEvent::Air(s) => {
                self.tas_mps = Some(s.tas_mps);
                None
            }
            SensorEvent::RefAttitude(a) => {
                self.ref_attitude = Some(*a);
                None
            }
            SensorEvent::Alignment(a) => {
                self.alignment = Some(**a);
                None
            }
            SensorEvent::Gnss(fix) => self.on_fix(policy, fix, running),
            SensorEvent::Mag(_)
            | SensorEvent::Frame(_)
            | SensorEvent::HeightAboveTerrain(_)
            | SensorEvent::VisionApplied(_) => None,
        }
    }

    fn on_fix(
        &mut self,
        policy: &StartPolicy,
        fix: &GnssFix,
        running: Option<Running<'_>>,
    ) -> Option<(StartRecord, InsInit)> {
        if let Some(Running {
            gnss_denied: true,
            last: Some(last),
        }) = running
        {
            let first = match self.gnss_back {
                Some((first, newest))
                    if fix.t_us.saturating_sub(newest) <= policy.reinit_max_fix_gap_us =>
                {
                    first
                }
                _ => fix.t_us,
            };
            self.gnss_back = Some((first, fix.t_us));
            if fix.t_us.saturating_sub(first) < policy.reinit_after_us {
                return None;
            }
            self.gnss_back = None;
            let mut init = InsInit::new(last.q_nb, fix.pos, fix.v_ned_mps, policy.mag_decimal_year);
            init.priors.e_gyr_rps = last.e_gyr_rps;
            init.priors.e_acc_mps2 = last.e_acc_mps2;
            init.priors.e_mag_nt = last.e_mag_nt;
            init.priors.delta_b_n_nt = last.delta_b_n_nt;
            init.aoa_rad = last.aoa_rad;
            init.valid_at_us = Some(fix.t_us);
            return Some((self.record(StartKind::GnssBack, fix), init));
        }
        self.gnss_back = None;

        if fix.sigma_vel_mps > policy.start_max_velocity_sigma_mps {
            self.imprecise_fixes += 1;
        }
        let flying = policy
            .restart_airspeed_mps
            .is_some_and(|v| self.tas_mps.is_some_and(|tas| tas >= v));
        let wanted = !self.started || (flying && !self.started_flying);
        let imu_ready = self.imu_times_us.len() as f64
            >= policy.min_imu_rate_hz * policy.imu_window_us as f64 * 1e-6;
        let velocity_ready = fix.sigma_vel_mps <= policy.start_max_velocity_sigma_mps
            || self.imprecise_fixes >= policy.imprecise_fixes_before_any;
        if !(wanted && imu_ready && velocity_ready) {
            return None;
        }
        let near = |t_us: u64| t_us.abs_diff(fix.t_us) <= policy.attitude_max_age_us;
        let mut init = match (&self.alignment, &self.ref_attitude) {
            (Some(a), _) if near(a.t_us) => {
                let mut init =
                    InsInit::new(a.q_nb, fix.pos, fix.v_ned_mps, policy.mag_decimal_year);
                init.priors = a.priors;
                init.aoa_rad = a.aoa_rad;
                init
            }
            (_, Some(r)) if near(r.t_us) => {
                InsInit::new(r.q_nb, fix.pos, fix.v_ned_mps, policy.mag_decimal_year)
            }
            _ => {
                self.fixes_without_attitude += 1;
                return None;
            }
        };
        init.valid_at_us = Some(fix.t_us);
        let kind = if self.started {
            StartKind::Flying
        } else {
            StartKind::First
        };
        self.started = true;
        self.started_flying = flying;
        Some((self.record(kind, fix), init))
    }

    fn record(&self, kind: StartKind, fix: &GnssFix) -> StartRecord {
        StartRecord {
            kind,
            t_us: fix.t_us,
            pos: fix.pos,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::{AirSample, ImuSample, SensorErrorPriors};
    use nalgebra::{UnitQuaternion, Vector3};

    const YEAR: f64 = 2026.5;

    fn imu(t_us: u64) -> SensorEvent {
        SensorEvent::Imu(ImuSample {
            t_us,
            gyro_rps: Vector3::zeros(),
            accel_mps2: Vector3::new(0.0, 0.0, -9.81),
        })
    }

    fn air(t_us: u64, tas_mps: f64) -> SensorEvent {
        SensorEvent::Air(AirSample {
            t_us,
            tas_mps,
            aoa_rad: None,
            aos_rad: None,
            p_pa: 90_000.0,
            temp_k: 280.0,
        })
    }

    fn fix(t_us: u64, sigma_vel_mps: f64) -> SensorEvent {
        SensorEvent::Gnss(GnssFix {
            t_us,
            pos: Geodetic {
                lat_rad: 0.7,
                lon_rad: -1.5,
                h_m: 1_000.0 + t_us as f64 * 1e-6,
            },
            v_ned_mps: Vector3::new(25.0, 0.0, 0.0),
            sigma_hor_m: 2.0,
            sigma_ver_m: 4.0,
            sigma_vel_mps,
        })
    }

    fn attitude(t_us: u64, yaw_rad: f64) -> SensorEvent {
        SensorEvent::RefAttitude(RefAttitude {
            t_us,
            q_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
        })
    }

    /// Feed `events` to a fresh state with no INS running; the starts made.
    fn starts(
        policy: &StartPolicy,
        events: &[SensorEvent],
    ) -> (StartState, Vec<(StartRecord, InsInit)>) {
        let mut st = StartState::default();
        let mut out = Vec::new();
        for e in events {
            let running = (!out.is_empty()).then_some(Running {
                gnss_denied: false,
                last: None,
            });
            out.extend(st.observe(policy, e, running));
        }
        (st, out)
    }

    /// IMU at `rate_hz` from 0 to `until_us`.
    fn imu_stream(rate_hz: u64, until_us: u64) -> Vec<SensorEvent> {
        (0..=until_us)
            .step_by((1_000_000 / rate_hz) as usize)
            .map(imu)
            .collect()
    }

    #[test]
    fn the_first_start_needs_an_attitude_at_the_fix_a_running_imu_and_a_precise_velocity() {
        let policy = StartPolicy::new(YEAR);
        // No attitude at all: counted, not started.
        let mut ev = imu_stream(100, 1_500_000);
        ev.push(fix(1_500_000, 0.1));
        let (st, s) = starts(&policy, &ev);
        assert!(s.is_empty());
        assert_eq!(st.fixes_without_attitude, 1);
        // An attitude 1.2 s before the fix is too old (1 s); one 0.5 s before will do.
        let mut ev = imu_stream(100, 1_500_000);
        ev.push(attitude(300_000, 0.3));
        ev.push(fix(1_500_000, 0.1));
        assert!(starts(&policy, &ev).1.is_empty());
        ev.push(attitude(1_000_000, 0.4));
        ev.push(fix(1_510_000, 0.1));
        let (_, s) = starts(&policy, &ev);
        assert_eq!(s.len(), 1);
        let (record, init) = &s[0];
        assert_eq!((record.kind, record.t_us), (StartKind::First, 1_510_000));
        assert!((init.q_nb.euler_angles().2 - 0.4).abs() < 1e-12);
        assert_eq!(init.valid_at_us, Some(1_510_000));
        // An IMU at 4 Hz (before the autopilot grants the rates) does not start it.
        let mut ev = imu_stream(4, 1_500_000);
        ev.extend([attitude(1_500_000, 0.0), fix(1_500_000, 0.1)]);
        assert!(starts(&policy, &ev).1.is_empty());
        // Fixes without a measured down velocity (σ 3 m/s): the tenth starts it anyway.
        let mut ev = imu_stream(100, 1_000_000);
        for k in 1..=10 {
            ev.push(attitude(1_000_000 + k * 100_000, 0.0));
            ev.push(fix(1_000_000 + k * 100_000, 3.0));
        }
        let (_, s) = starts(&policy, &ev);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].0.t_us, 2_000_000);
    }

    #[test]
    fn an_alignment_gives_its_attitude_and_priors_and_wins_over_the_autopilots_attitude() {
        let policy = StartPolicy::new(YEAR);
        let priors = SensorErrorPriors {
            e_gyr_rps: Vector3::new(1e-4, 2e-4, 3e-4),
            e_gyr_sigma_rps: Vector3::repeat(1e-6),
            e_acc_mps2: Vector3::new(0.01, 0.02, 0.03),
            e_acc_sigma_mps2: Vector3::repeat(1e-4),
            e_mag_nt: Vector3::new(10.0, 20.0, 30.0),
            e_mag_sigma_nt: Vector3::repeat(0.1),
            delta_b_n_nt: Vector3::new(-5.0, 5.0, 50.0),
            delta_b_n_sigma_nt: Vector3::repeat(5.0),
        };
        let mut ev = imu_stream(100, 1_000_000);
        ev.push(attitude(1_000_000, 0.1));
        ev.push(SensorEvent::Alignment(Box::new(Alignment {
            t_us: 1_000_000,
            q_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2),
            aoa_rad: 0.07,
            priors,
        })));
        ev.push(fix(1_000_000, 0.07));
        let (_, s) = starts(&policy, &ev);
        let init = &s[0].1;
        assert!((init.q_nb.euler_angles().2 - 0.2).abs() < 1e-12);
        assert_eq!(init.aoa_rad, 0.07);
        assert_eq!(
            (
                init.priors.e_gyr_rps,
                init.priors.e_acc_sigma_mps2,
                init.priors.delta_b_n_nt
            ),
            (
                priors.e_gyr_rps,
                priors.e_acc_sigma_mps2,
                priors.delta_b_n_nt
            )
        );
    }

    #[test]
    fn an_ins_started_on_the_ground_is_started_again_once_flying_and_only_once() {
        let mut policy = StartPolicy::new(YEAR);
        policy.restart_airspeed_mps = Some(18.0);
        // IMU at 100 Hz; each second an air sample, the autopilot's attitude and a fix.
        let tas_at = [0.0, 0.0, 10.0, 19.0, 25.0];
        let mut ev = Vec::new();
        for t_us in (0..=4_000_000).step_by(10_000) {
            ev.push(imu(t_us));
            if t_us > 0 && t_us % 1_000_000 == 0 {
                let tas = tas_at[(t_us / 1_000_000) as usize];
                ev.extend([air(t_us, tas), attitude(t_us, 0.0), fix(t_us, 0.1)]);
            }
        }
        let kinds: Vec<(StartKind, u64)> = starts(&policy, &ev)
            .1
            .iter()
            .map(|(r, _)| (r.kind, r.t_us))
            .collect();
        assert_eq!(
            kinds,
            vec![
                (StartKind::First, 1_000_000),
                (StartKind::Flying, 3_000_000)
            ]
        );
        // Started while flying: never again.
        let mut ev = imu_stream(100, 1_000_000);
        ev.extend([
            air(1_000_000, 25.0),
            attitude(1_000_000, 0.0),
            fix(1_000_000, 0.1),
        ]);
        ev.extend([
            air(2_000_000, 25.0),
            attitude(2_000_000, 0.0),
            fix(2_000_000, 0.1),
        ]);
        assert_eq!(starts(&policy, &ev).1.len(), 1);
    }

    #[test]
    fn gnss_back_for_five_seconds_without_a_long_gap_re_initialises_from_the_current_estimate() {
        let policy = StartPolicy::new(YEAR);
        let mut last = crate::nav::solution::fixtures::solution().ins;
        last.gnss_denied = true;
        last.e_gyr_rps = Vector3::new(1e-5, -1e-5, 2e-5);
        let running = Some(Running {
            gnss_denied: true,
            last: Some(&last),
        });
        let mut st = StartState::default();
        // Fixes each second from 100 s, one 2-s gap after 102 s: the count restarts at 104 s.
        let times = [100, 101, 102, 104, 105, 106, 107, 108, 109];
        let mut made = Vec::new();
        for t_s in times {
            if let Some((r, init)) = st.observe(&policy, &fix(t_s * 1_000_000, 0.1), running) {
                made.push((r.kind, r.t_us, init));
            }
        }
        assert_eq!(made.len(), 1);
        let (kind, t_us, init) = &made[0];
        assert_eq!((*kind, *t_us), (StartKind::GnssBack, 109_000_000));
        assert_eq!(
            (init.q_nb, init.priors.e_gyr_rps),
            (last.q_nb, last.e_gyr_rps)
        );
        // Not denied: fixes do nothing.
        let running = Some(Running {
            gnss_denied: false,
            last: Some(&last),
        });
        let mut st = StartState {
            started: true,
            ..StartState::default()
        };
        for t_s in 100..120 {
            assert!(
                st.observe(&policy, &fix(t_s * 1_000_000, 0.1), running)
                    .is_none()
            );
        }
    }
}
