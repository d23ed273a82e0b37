//! Publication of solutions (issue 5 item 3; research/mavlink.md §2.4): called by the
//! navigation thread right after each solution, so a message leaves one queue hop after its IMU
//! sample was processed. No clock is read: the rate uses the solutions' own times.
//!
//! Rate: the first solution at or after each due time is published; due times advance by
//! `1 / output.rate_hz` of solution time (30 Hz from a 100 Hz IMU alternates 30/40 ms and
//! averages 30 Hz; the output rate cannot exceed the IMU rate) and never lag the newest
//! solution by more than a period (no burst after a gap).

use std::sync::Arc;
use std::time::Instant;

use super::{Clock, Outbox, Shared, resolved_mode};
use crate::config::{DaemonConfig, OutputMode};
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
}

impl Publisher {
    /// A publisher at `cfg.output.rate_hz`.
    pub fn new(cfg: Arc<DaemonConfig>, clock: Clock, outbox: Outbox, shared: Arc<Shared>) -> Self {
        let period_us = (1e6 / cfg.output.rate_hz) as u64;
        Self {
            cfg,
            clock,
            outbox,
            shared,
            period_us,
            next_due_us: None,
            origin_sent_for: None,
        }
    }

    /// Handle a new solution computed from an IMU message received at `imu_rx`.
    pub fn on_solution(&mut self, sol: &NavSolution, imu_rx: Instant) {
        let t_us = sol.ins.t_us;
        let due = *self.next_due_us.get_or_insert(t_us);
        if t_us < due {
            return;
        }
        self.next_due_us = Some((due + self.period_us).max(t_us.saturating_sub(self.period_us)));
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
                apm::MavMessage::GPS_INPUT(mavlink_out::gps_input(
                    sol,
                    &s,
                    t_us,
                    self.clock.unix_us(t_us),
                ))
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
    #[allow(deprecated)]
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
