//! Publication of solutions (docs/REFERENCES.md M2.2–M2.4): called by the navigation thread right
//! after each solution, so a message leaves one queue hop after its IMU sample was processed. No
//! clock is read: the rate uses the solutions' own times.
//!
//! Rate: the first solution at or after each due time is published; due times advance by
//! `1 / output.rate_hz` of solution time (30 Hz from a 100 Hz IMU alternates 30/40 ms and
//! averages 30 Hz; the output rate cannot exceed the IMU rate); after a gap longer than a
//! period the schedule restarts from the first new solution (no burst to catch up).

use std::sync::Arc;
use std::time::Instant;

use super::health::{OutputHealth, Transition};
use super::{Clock, Outbox, Shared, resolved_mode};
use crate::daemon::config::{DaemonConfig, OutputMode};
use crate::io::mavlink_out::{self, GpsInputSettings};
use crate::math::map_projection::MapProjection;
use crate::math::wgs84::Geodetic;
use crate::nav::NavSolution;
use mavlink::dialects::ardupilotmega as apm;

/// The publisher's state.
#[derive(Debug)]
pub struct Publisher {
    cfg: Arc<DaemonConfig>,
    /// Used only to convert solution times to Unix time (GPS week), never read.
    clock: Clock,
    outbox: Outbox,
    shared: Arc<Shared>,
    period_us: u64,
    next_due_us: Option<u64>,
    /// Link generation and origin of the last SET_GPS_GLOBAL_ORIGIN.
    origin_sent_for: Option<(u64, Geodetic)>,
    /// Self-checks that withhold solutions the daemon cannot back.
    health: OutputHealth,
}

impl Publisher {
    /// A publisher at `cfg.output.rate_hz`.
    pub fn new(cfg: Arc<DaemonConfig>, clock: Clock, outbox: Outbox, shared: Arc<Shared>) -> Self {
        let period_us = (1e6 / cfg.output.rate_hz) as u64;
        let health = OutputHealth::new(
            cfg.ins.position.gnss_gate_chi2,
            cfg.ins.position.gnss_timeout_s,
        );
        Self {
            cfg,
            clock,
            outbox,
            shared,
            period_us,
            next_due_us: None,
            origin_sent_for: None,
            health,
        }
    }

    /// A valid GNSS fix reached the navigation (for the self-checks).
    pub fn on_fix(&mut self, t_us: u64) {
        self.health.on_fix(t_us);
    }

    /// Handle a new solution computed from an IMU message received at `imu_rx`.
    pub fn on_solution(&mut self, sol: &NavSolution, imu_rx: Instant) {
        let t_us = sol.ins.t_us;
        let (healthy, transition) = self.health.check(sol);
        match transition {
            Some(Transition::Withheld(p)) => {
                self.shared.count(|c| c.publish_withheld_episodes += 1);
                self.outbox.status(
                    apm::MavSeverity::MAV_SEVERITY_ERROR,
                    &format!("ianav: not publishing: {p}"),
                );
            }
            Some(Transition::Resumed) => self.outbox.status(
                apm::MavSeverity::MAV_SEVERITY_NOTICE,
                "ianav: self-checks pass, publishing again",
            ),
            None => {}
        }
        if !healthy {
            self.shared.count(|c| c.publish_withheld += 1);
            return;
        }
        let due = *self.next_due_us.get_or_insert(t_us);
        if t_us < due {
            return;
        }
        // After a gap longer than a period the schedule restarts from this solution.
        let next = due + self.period_us;
        self.next_due_us = Some(if next <= t_us {
            t_us + self.period_us
        } else {
            next
        });
        let (ap, origin, undulation_m, generation) = self
            .shared
            .state(|s| (s.autopilot, s.origin, s.undulation_m, s.request_generation));
        let Some(mode) = resolved_mode(&self.cfg, ap.map(|a| a.2)) else {
            return;
        };
        let target_system = ap.map_or(1, |a| a.0);
        let msg = match mode {
            OutputMode::GpsInput => {
                let s = GpsInputSettings {
                    gps_id: self.cfg.output.gps_id,
                    satellites_visible: self.cfg.output.satellites_visible,
                    leap_s: self.cfg.output.gps_leap_seconds,
                    undulation_m,
                };
                let g = mavlink_out::gps_input(sol, &s, t_us, self.clock.unix_us(t_us));
                // As the autopilot would report it back: h_acc in whole mm.
                let h_acc_mm = (f64::from(g.horiz_accuracy) * 1e3).round() as u32;
                self.shared
                    .state(|st| st.remember_sent(g.lat, g.lon, h_acc_mm));
                apm::MavMessage::GPS_INPUT(g)
            }
            OutputMode::Odometry | OutputMode::VisionPositionEstimate | OutputMode::Auto => {
                let Some(origin) = origin else { return };
                self.announce_origin(target_system, origin, undulation_m, generation, t_us);
                let proj = MapProjection::new(&origin);
                if mode == OutputMode::VisionPositionEstimate {
                    apm::MavMessage::VISION_POSITION_ESTIMATE(
                        mavlink_out::vision_position_estimate(sol, &proj, t_us),
                    )
                } else {
                    apm::MavMessage::ODOMETRY(mavlink_out::odometry(sol, &proj, t_us))
                }
            }
        };
        self.outbox.send_timed(msg, Some(imu_rx));
        self.shared.count(|c| c.published += 1);
    }

    /// SET_GPS_GLOBAL_ORIGIN once per link generation (after a reboot or a link restoration
    /// the autopilot may have lost it). The message is deprecated in favour of
    /// MAV_CMD_DO_SET_GLOBAL_ORIGIN (2025-04), but it is what PX4 and ArduPilot releases in
    /// the field handle.
    #[expect(
        deprecated,
        reason = "SET_GPS_GLOBAL_ORIGIN, deprecated but what PX4 and ArduPilot releases in the \
                  field handle"
    )]
    fn announce_origin(
        &mut self,
        target_system: u8,
        origin: Geodetic,
        undulation_m: f64,
        generation: u64,
        t_us: u64,
    ) {
        if !self.cfg.output.set_origin
            || self
                .origin_sent_for
                .is_some_and(|(g, o)| g == generation && o == origin)
        {
            return;
        }
        self.outbox.send(apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(
            mavlink_out::set_gps_global_origin(target_system, &origin, undulation_m, t_us),
        ));
        self.shared.count(|c| c.origins_sent += 1);
        self.origin_sent_for = Some((generation, origin));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::config::AutopilotKind;
    use tokio::sync::mpsc;

    fn publisher(
        rate_hz: f64,
        mode: &str,
    ) -> (
        Publisher,
        mpsc::Receiver<super::super::Outgoing>,
        Arc<Shared>,
    ) {
        let cfg = DaemonConfig::from_toml_str(
            &format!(
                "[mavlink]\nconnection = \"udpin:127.0.0.1:1\"\n\
                 [output]\nmode = \"{mode}\"\nrate_hz = {rate_hz}\n"
            ),
            None,
        )
        .unwrap();
        let shared = Arc::new(Shared::default());
        let (tx, rx) = mpsc::channel(10_000);
        let outbox = Outbox {
            tx,
            shared: shared.clone(),
        };
        let p = Publisher::new(Arc::new(cfg), Clock::new(), outbox, shared.clone());
        (p, rx, shared)
    }

    fn solution(t_us: u64) -> NavSolution {
        let mut s = crate::io::mavlink_out::tests::solution();
        s.ins.t_us = t_us;
        s
    }

    fn count(rx: &mut mpsc::Receiver<super::super::Outgoing>, name: &str) -> usize {
        let mut n = 0;
        while let Ok((m, _)) = rx.try_recv() {
            n += usize::from(mavlink::Message::message_name(&m) == name);
        }
        n
    }

    #[test]
    fn rates_follow_solution_time_without_bursts() {
        let (mut p, mut rx, shared) = publisher(30.0, "odometry");
        let origin = solution(0).ins.pos;
        shared.state(|s| {
            s.autopilot = Some((1, 1, AutopilotKind::Px4));
            s.origin = Some(origin);
        });
        let now = Instant::now();
        // 10 s of 100 Hz solutions: exactly 300 ODOMETRY and one origin.
        for k in 0..1_000 {
            p.on_solution(&solution(k * 10_000), now);
        }
        assert_eq!(count(&mut rx, "ODOMETRY"), 300);
        assert_eq!(shared.counters().origins_sent, 1);
        // A 2 s gap, then 1 s more: 30 messages, not a burst of 60 to catch up.
        for k in 0..100 {
            p.on_solution(&solution(12_000_000 + k * 10_000), now);
        }
        assert_eq!(count(&mut rx, "ODOMETRY"), 30);
        // A new link generation re-announces the origin.
        shared.state(|s| s.request_generation += 1);
        p.on_solution(&solution(14_000_000), now);
        assert_eq!(shared.counters().origins_sent, 2);
    }

    #[test]
    fn the_output_rate_cannot_exceed_the_imu_rate_and_waits_for_the_autopilot_kind() {
        let (mut p, mut rx, shared) = publisher(30.0, "auto");
        let now = Instant::now();
        for k in 0..25 {
            p.on_solution(&solution(k * 40_000), now);
        }
        assert_eq!(
            count(&mut rx, "GPS_INPUT") + count(&mut rx, "ODOMETRY"),
            0,
            "kind unknown"
        );
        shared.state(|s| s.autopilot = Some((1, 1, AutopilotKind::Ardupilot)));
        // 25 Hz solutions for 1 s at a 30 Hz setting: every one published (25), as GPS_INPUT.
        for k in 25..50 {
            p.on_solution(&solution(k * 40_000), now);
        }
        assert_eq!(count(&mut rx, "GPS_INPUT"), 25);
    }
}
