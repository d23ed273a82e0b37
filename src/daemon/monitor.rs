//! The monitor task: the 1 Hz HEARTBEAT, a STATUSTEXT on each change of the link, estimator,
//! GNSS and camera health, sd_notify (READY, WATCHDOG) and the periodic counter line in the log.

use std::time::Duration;

use tokio::sync::watch;

use super::shared::{Context, Counters, Latest};
use super::{MAX_SOLUTION_AGE_US, stopped_after};
use crate::io::mavlink_out::{self, Health};
use crate::nav::PositionSource;
use mavlink::dialects::ardupilotmega as apm;

/// Health flags watched by the monitor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Flags {
    link_up: bool,
    initialised: bool,
    /// `None` until the first fix (the first fix is not a "regained").
    gnss_ok: Option<bool>,
    camera_ok: bool,
    reset_counter: u8,
    horizontal_source: Option<PositionSource>,
}

/// HEARTBEAT at 1 Hz, STATUSTEXT on state changes, counters in the log, sd_notify.
pub(super) async fn monitor(ctx: Context, latest: watch::Receiver<Option<Latest>>) {
    let Context {
        cfg,
        clock,
        outbox,
        shared,
        mut stop,
    } = ctx;
    use apm::MavSeverity as S;
    // systemd (sd_notify(3); no-ops without $NOTIFY_SOCKET): STATUS while waiting; READY=1
    // when the estimator first runs, so the start timeout, not the watchdog, covers the wait
    // for the first fix; then WATCHDOG=1 each second only while solutions come from IMU
    // messages received less than MAX_SOLUTION_AGE_US ago (`running` below: the INS yields a
    // solution only on an IMU sample), i.e. only while the navigation processes IMU samples.
    use sd_notify::NotifyState as N;
    let notify = |states: &[N]| {
        if let Err(e) = sd_notify::notify(states) {
            tracing::warn!("sd_notify: {e}");
        }
    };
    notify(&[N::Status("waiting for the autopilot and a GNSS fix")]);
    let mut ready_sent = false;
    let mut flags = Flags::default();
    let mut link_lost_at: Option<u64> = None;
    let mut last_heartbeat_us: Option<u64> = None;
    let mut last_log_us = 0_u64;
    let camera_used = cfg.camera.source != crate::daemon::config::CameraSourceKind::None;
    loop {
        if stopped_after(&mut stop, Duration::from_millis(100)).await {
            return;
        }
        let now = clock.now_us();
        let st = shared.state(|s| s.clone());
        let l = *latest.borrow();
        // Link.
        let link_up = st
            .last_rx_us
            .is_some_and(|t| now.saturating_sub(t) < (cfg.mavlink.link_timeout_s * 1e6) as u64);
        if flags.link_up && !link_up {
            shared.count(|c| c.link_losses += 1);
            link_lost_at = Some(now);
            tracing::warn!("link to the autopilot lost");
        } else if !flags.link_up
            && link_up
            && let Some(t) = link_lost_at.take()
        {
            // From the last message before the silence to the first after it (measured by the
            // reader): the loss was only noticed a link timeout after it began.
            let s = st.last_outage_us.unwrap_or(now.saturating_sub(t)) as f64 / 1e6;
            outbox.status(
                S::MAV_SEVERITY_NOTICE,
                &format!("ianav: link restored ({s:.1} s)"),
            );
            // The autopilot may have restarted meanwhile: ask for the streams again.
            shared.state(|s| s.request_generation += 1);
        }
        flags.link_up = link_up;
        // Estimator.
        if let Some(l) = l {
            let source = l.sol.horizontal_source;
            if !flags.initialised {
                flags.initialised = true;
                flags.reset_counter = l.sol.reset_counter;
                outbox.status(S::MAV_SEVERITY_INFO, "ianav: INS initialised");
            } else if l.sol.reset_counter != flags.reset_counter {
                flags.reset_counter = l.sol.reset_counter;
                // A change of the horizontal source also moves the reset counter: say which.
                let changed = flags.horizontal_source != Some(source);
                match (changed, source, l.sol.ins.gnss_denied) {
                    (true, PositionSource::Vision, _) => outbox.status(
                        S::MAV_SEVERITY_NOTICE,
                        "ianav: horizontal position from vision",
                    ),
                    (true, PositionSource::Ins, true) => outbox.status(
                        S::MAV_SEVERITY_WARNING,
                        "ianav: vision lost, INS dead reckoning",
                    ),
                    _ => outbox.status(S::MAV_SEVERITY_WARNING, "ianav: estimator reset"),
                }
            }
            flags.horizontal_source = Some(source);
        }
        let timeout_us = (cfg.input.gnss_loss_timeout_s * 1e6) as u64;
        // In sensor time while solutions flow (with the autopilot clock a vehicle at 10× real
        // time would otherwise be announced 20 s of its time late), else in reception time.
        let gnss_ok = match (l, st.last_fix_sensor_us) {
            (Some(l), Some(fix_us)) => l.sol.ins.t_us.saturating_sub(fix_us) < timeout_us,
            _ => st
                .last_fix_us
                .is_some_and(|t| now.saturating_sub(t) < timeout_us),
        };
        if st.last_fix_us.is_some() && flags.gnss_ok.is_some_and(|was| was != gnss_ok) {
            if gnss_ok {
                outbox.status(S::MAV_SEVERITY_NOTICE, "ianav: GNSS regained");
            } else {
                outbox.status(
                    S::MAV_SEVERITY_WARNING,
                    "ianav: GNSS lost, INS dead reckoning",
                );
            }
        }
        if st.last_fix_us.is_some() {
            flags.gnss_ok = Some(gnss_ok);
        }
        if camera_used {
            let cam_ok = st
                .last_frame_us
                .is_some_and(|t| now.saturating_sub(t) < (cfg.camera.timeout_s * 1e6) as u64);
            if cam_ok != flags.camera_ok && (cam_ok || st.last_frame_us.is_some()) {
                if cam_ok {
                    outbox.status(S::MAV_SEVERITY_INFO, "ianav: camera frames received");
                } else {
                    outbox.status(S::MAV_SEVERITY_WARNING, "ianav: camera lost");
                }
            }
            flags.camera_ok = cam_ok;
        }
        // Fresh = computed from an IMU message received less than 0.5 s ago (real time, so
        // it also holds with the autopilot clock).
        let running =
            l.is_some_and(|l| l.imu_rx.elapsed() < Duration::from_micros(MAX_SOLUTION_AGE_US));
        if l.is_some() && !running {
            // Nothing is published from a stale solution (the publisher runs on new ones).
            shared.count(|c| c.publish_stale += 1);
        }
        // HEARTBEAT at 1 Hz (sent regardless of the link: UDP/routers learn us from it).
        if last_heartbeat_us.is_none_or(|t| now.saturating_sub(t) >= 1_000_000) {
            last_heartbeat_us = Some(now);
            let health = match (
                running,
                l.is_some_and(|l| l.sol.ins.gnss_denied) || !gnss_ok,
            ) {
                (false, _) => Health::Standby,
                (true, false) => Health::Active,
                (true, true) => Health::Critical,
            };
            outbox.send(apm::MavMessage::HEARTBEAT(mavlink_out::heartbeat(health)));
            // The watchdog is fed only while the estimator runs on fresh IMU samples.
            if running {
                if ready_sent {
                    notify(&[N::Watchdog]);
                } else {
                    ready_sent = true;
                    notify(&[N::Ready, N::Status("estimator running"), N::Watchdog]);
                }
            }
        }
        let period_us = (cfg.logging.counters_period_s * 1e6) as u64;
        if period_us > 0 && now.saturating_sub(last_log_us) >= period_us {
            last_log_us = now;
            log_counters(&shared.counters());
        }
    }
}

// Beside the counter line that prints it rather than with the counters' definition.
impl Counters {
    /// Every input refused, by kind, as `kind=n` for the non-zero ones ("none" otherwise).
    pub fn rejections(&self) -> String {
        let (i, t) = (&self.input, &self.timesync);
        let kinds = [
            ("parse", self.rx_parse_errors),
            ("non_finite", i.non_finite),
            ("out_of_range", i.out_of_range),
            ("no_fix", i.no_fix),
            ("unscaled_raw_imu", i.unscaled_raw_imu),
            ("time_unmapped", i.time),
            ("no_airspeed", i.no_airspeed),
            ("airspeed_unhealthy", i.airspeed_unhealthy),
            ("time_implausible", t.implausible),
            ("clock_outlier", t.clock_outliers),
            ("clock_held", t.clock_held),
            ("time_order", self.time_order_rejected),
            ("time_repeated", self.time_repeated),
            ("timesync_rtt", t.rtt_rejected),
            ("timesync_outlier", t.outliers),
            ("gnss_echo", self.gnss_echo),
            ("foreign", self.rx_foreign),
            ("before_heartbeat", self.rx_before_heartbeat),
        ];
        let v: Vec<String> = kinds
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(k, n)| format!("{k}={n}"))
            .collect();
        if v.is_empty() {
            "none".to_owned()
        } else {
            v.join(" ")
        }
    }
}

/// One log line with the counters that matter in operation (periodically and at exit).
pub fn log_counters(c: &Counters) {
    tracing::info!(
        rx = c.rx_frames,
        rx_v1 = c.rx_v1_frames,
        parse_err = c.rx_parse_errors,
        seq_lost = c.rx_seq_lost,
        seq_lost_v1 = c.rx_seq_lost_v1,
        foreign = c.rx_foreign,
        foreign_hb = c.rx_foreign_heartbeats,
        foreign_autopilot = c.rx_foreign_autopilots,
        foreign_input = c.rx_foreign_input,
        imu = c.input.imu,
        air = c.input.air,
        mag = c.input.mag,
        gnss = c.input.gnss,
        rejected = c.input.rejected(),
        time_order = c.time_order_rejected,
        repeated = c.time_repeated,
        ts_samples = c.timesync.samples,
        reboots = c.autopilot_reboots,
        time_jumps = c.autopilot_time_jumps,
        autopilot_changes = c.autopilot_changes,
        solutions = c.solutions,
        published = c.published,
        withheld = c.publish_withheld,
        gnss_echo = c.gnss_echo,
        interval_refused = c.interval_refused,
        airspeed_unhealthy = c.input.airspeed_unhealthy,
        stale = c.publish_stale,
        tx = c.tx_messages,
        tx_failed = c.tx_failed,
        tx_full = c.tx_queue_full,
        frames = c.frames_received,
        frames_dropped = c.frames_dropped,
        frames_vision_busy = c.nav.frames_vision_busy,
        vision_fixes_fused = c.nav.fused_vision_fixes,
        source_changes = c.nav.horizontal_source_changes,
        vision_failures = c.vision_failures,
        camera_err = c.camera_errors,
        restarts = c.worker_restarts,
        latency_samples = c.latency_samples,
        latency_max_us = c.latency_max_us,
        frame_latency_max_us = c.frame_latency_max_us,
        refused = %c.rejections(),
        "counters"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_counter_line_names_every_refusal_by_kind() {
        let mut c = Counters::default();
        assert_eq!(c.rejections(), "none");
        c.input.out_of_range = 3;
        c.timesync.clock_outliers = 1;
        c.rx_foreign = 40;
        assert_eq!(c.rejections(), "out_of_range=3 clock_outlier=1 foreign=40");
    }
}
