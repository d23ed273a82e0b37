//! Autopilot time → the daemon's monotonic clock (MAVLink "Time Synchronization Protocol v2",
//! TIMESYNC #111; docs/REFERENCES.md M3.4). Pure: every function takes the current time of the
//! daemon's clock as an argument.
//!
//! - Both sides of TIMESYNC: a request `tc1 = 0` from the autopilot is answered with our time
//!   in `tc1` and its `ts1` echoed; our requests carry our time in `ts1`, and a response gives
//!   one offset sample `(ts1 + now) / 2 − tc1` (our clock minus the autopilot's), used only when
//!   the round trip is below the configured limit. The samples are averaged (1/n for the first
//!   [`WARMUP_SAMPLES`], then an exponential filter of gain [`ALPHA`]); [`RESET_AFTER`]
//!   consecutive samples farther than [`OUTLIER_NS`] from the estimate restart it (a clock jump).
//! - Until TIMESYNC has converged, the offset is the lower envelope of `receipt − stamp` over
//!   the clock messages (IMU, ATTITUDE): transport delay is never negative, so the minimum is
//!   the offset plus the smallest latency. The envelope rises by [`ENVELOPE_LEAK_US`] per
//!   sample to follow clock drift.
//! - The autopilot's clock is a *track* of its clock-message stamps (IMU, ATTITUDE,
//!   SYSTEM_TIME). A stamp fits the track unless it is more than [`REBOOT_BACKSTEP_US`] older
//!   than the newest one, or newer than the time received since allows: the reception
//!   interval × the clock's rate (1 on the daemon clock: a real vehicle; on the autopilot
//!   clock [`RATE_MARGIN`] × the rate measured over the last second or two, [`MAX_CLOCK_RATE`]
//!   until measured) + [`FORWARD_SLACK_US`]. The slack is under the backstep, so a stamp
//!   accepted just inside it cannot put the next ones out of the track. A stamp that does not
//!   fit is held (its message is not used) as a candidate track; the candidate replaces the
//!   track only once [`CLOCK_CONFIRM_SAMPLES`] consecutive stamps fit it and none fits the old
//!   track: a reboot when it went back, a time jump when it went forward. A stamp fitting the
//!   old track discards the candidate, whose stamps are counted as outliers: one IMU sample
//!   stamped an hour ahead is refused, not taken for a reboot and a jump. The sync is reset
//!   after a reboot or jump and the caller re-requests its message intervals. (A
//!   sequence-number reset alone is not used: on UDP it also follows loss and reordering.)
//! - Autopilot clock ([`TimeSync::with_autopilot_clock`], for a simulated vehicle running
//!   faster than real time, where the daemon's clock would compress every Δt): `t_us` is the
//!   autopilot's own time, continued across reboots (each reboot adds the newest time seen
//!   before it); unstamped messages take the newest clock-message stamp.
//! - [`MonotonicGate`]: per sensor kind, mapped times must strictly increase; repeats and
//!   out-of-order samples are rejected and counted.

use crate::io::mavlink_in::ApTime;
use mavlink::dialects::ardupilotmega as apm;

/// Offset samples averaged uniformly before the exponential filter takes over.
pub const WARMUP_SAMPLES: u32 = 10;
/// Gain of the exponential offset filter.
pub const ALPHA: f64 = 0.05;
/// A sample farther than this from the estimate is an outlier, ns.
pub const OUTLIER_NS: f64 = 20e6;
/// Consecutive outliers that restart the estimate.
pub const RESET_AFTER: u32 = 5;
/// A clock message this much older than the newest seen does not fit the clock track, µs.
pub const REBOOT_BACKSTEP_US: u64 = 1_000_000;
/// Fastest an autopilot clock may run against ours (a simulated vehicle 100× faster than real
/// time): the rate assumed on the autopilot clock until it is measured.
pub const MAX_CLOCK_RATE: f64 = 100.0;
/// The measured rate of a simulated vehicle's clock is multiplied by this for the lead a
/// stamp may have (its speed varies with the simulator's load).
pub const RATE_MARGIN: f64 = 2.0;
/// The autopilot clock's rate is measured over at least this much reception time, µs.
pub const RATE_WINDOW_US: u64 = 1_000_000;
/// Lead a stamp may have beyond what the reception interval allows, µs: the spread of the
/// transport latency between consecutive messages. Below [`REBOOT_BACKSTEP_US`] (see the
/// module documentation).
pub const FORWARD_SLACK_US: u64 = 500_000;
/// Consecutive stamps that must fit a candidate track, none fitting the current one, before it
/// replaces it (a reboot or a time jump), and that must fit the first track before it is more
/// than provisional. Five: 50 ms of a 100 Hz
/// IMU, 125 ms of ArduPlane's 40 Hz; a lone outlier, or a few, never reach it.
pub const CLOCK_CONFIRM_SAMPLES: u32 = 5;
/// Rise of the receipt envelope per clock message, µs.
pub const ENVELOPE_LEAK_US: i64 = 1;
/// Stamps above this are Unix times, not boot times (≈ 31.7 years), µs.
pub const UNIX_STAMP_US: u64 = 1_000_000_000_000_000;
/// A mapped time older than this at reception is refused, µs.
pub const MAX_AGE_US: u64 = 2_000_000;

/// Counters of the time synchronisation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TimeSyncCounters {
    /// TIMESYNC requests from the autopilot answered.
    pub answered: u64,
    /// Responses to our requests used.
    pub samples: u64,
    /// Responses refused for a long round trip (or a `ts1` that is not ours).
    pub rtt_rejected: u64,
    /// Offset samples counted as outliers.
    pub outliers: u64,
    /// Filter restarts after consecutive outliers.
    pub resets: u64,
    /// Reboots of the autopilot detected.
    pub reboots: u64,
    /// Stamps that looked like Unix time (reception time used instead).
    pub unix_stamps: u64,
    /// Stamps refused because the mapped time was implausible (more than [`MAX_AGE_US`]
    /// before its reception or [`FORWARD_SLACK_US`] after it, on the autopilot clock after its
    /// newest stamp; or not representable).
    pub implausible: u64,
    /// Clock stamps that fitted neither the autopilot's clock nor a confirmed new one (lone
    /// outliers): their messages were refused.
    pub clock_outliers: u64,
    /// Clock stamps held while a new clock track was confirmed (at the start, a reboot or a
    /// jump): their messages were refused.
    pub clock_held: u64,
    /// Forward jumps of the autopilot's clock confirmed over [`CLOCK_CONFIRM_SAMPLES`] stamps.
    pub jumps: u64,
}

/// What a clock stamp says about the autopilot's clock ([`TimeSync::observe_clock`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockStamp {
    /// It fits the clock: the message may be used.
    Fits,
    /// It does not fit (yet): the message must not be used.
    Held,
    /// It confirmed a reboot (the clock went back): the sync was reset; the message may be
    /// used.
    Reboot,
    /// It confirmed a forward jump of the clock: the sync was reset; the message may be used.
    Jump,
}

/// A run of clock stamps: the newest one and when it was received, and the clock's rate.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Track {
    newest_ap_us: u64,
    newest_rx_us: u64,
    /// Start of the window the rate is being measured over (stamp, reception).
    anchor: (u64, u64),
    /// Rate of the autopilot's clock against ours, measured over the last window.
    rate: Option<f64>,
    /// Stamps that fitted it, the first included.
    fitted: u32,
}

impl Track {
    fn start(ap_us: u64, rx_us: u64) -> Self {
        Self {
            newest_ap_us: ap_us,
            newest_rx_us: rx_us,
            anchor: (ap_us, rx_us),
            rate: None,
            fitted: 1,
        }
    }

    /// Not more than [`REBOOT_BACKSTEP_US`] back, and not further ahead than the time received
    /// since the newest stamp allows at the rate `fixed_rate` (else the measured one).
    fn fits(&self, ap_us: u64, rx_us: u64, fixed_rate: Option<f64>) -> bool {
        if ap_us.saturating_add(REBOOT_BACKSTEP_US) < self.newest_ap_us {
            return false;
        }
        let rate = fixed_rate.unwrap_or(self.rate.map_or(MAX_CLOCK_RATE, |r| RATE_MARGIN * r));
        // f64 → u64 saturates.
        let lead_us = (rate * rx_us.saturating_sub(self.newest_rx_us) as f64) as u64;
        ap_us
            <= self
                .newest_ap_us
                .saturating_add(lead_us)
                .saturating_add(FORWARD_SLACK_US)
    }

    fn add(&mut self, ap_us: u64, rx_us: u64) {
        self.fitted = self.fitted.saturating_add(1);
        if ap_us <= self.newest_ap_us {
            return;
        }
        self.newest_ap_us = ap_us;
        self.newest_rx_us = rx_us;
        let span_rx_us = rx_us.saturating_sub(self.anchor.1);
        if span_rx_us >= RATE_WINDOW_US {
            let span_ap_us = ap_us.saturating_sub(self.anchor.0);
            self.rate = Some((span_ap_us as f64 / span_rx_us as f64).clamp(1.0, MAX_CLOCK_RATE));
            self.anchor = (ap_us, rx_us);
        }
    }
}

/// A track being confirmed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Candidate {
    track: Track,
    /// Stamps that fitted it.
    n: u32,
    /// It started before the current track's newest stamp (a reboot, once confirmed).
    went_back: bool,
}

/// Offset estimator and time mapper.
#[derive(Debug, Clone)]
pub struct TimeSync {
    max_rtt_ns: u64,
    /// Our clock minus the autopilot's, ns (TIMESYNC).
    offset_ns: Option<f64>,
    n: u32,
    consecutive_outliers: u32,
    /// Receipt envelope, µs.
    envelope_us: Option<i64>,
    /// The autopilot's clock (µs of its boot time), once confirmed.
    track: Option<Track>,
    /// A new clock being confirmed (stamps that do not fit the track).
    candidate: Option<Candidate>,
    counters: TimeSyncCounters,
    /// Use the autopilot's time as `t_us` (plus `epoch_us`).
    autopilot_clock: bool,
    /// Sum of the autopilot times reached before each reboot, µs.
    epoch_us: u64,
}

impl TimeSync {
    /// An estimator using round trips up to `max_rtt_ns`.
    pub fn new(max_rtt_ns: u64) -> Self {
        Self {
            max_rtt_ns,
            offset_ns: None,
            n: 0,
            consecutive_outliers: 0,
            envelope_us: None,
            track: None,
            candidate: None,
            counters: TimeSyncCounters::default(),
            autopilot_clock: false,
            epoch_us: 0,
        }
    }

    /// Map to the autopilot's own (reboot-continued) time instead of the daemon's clock.
    pub fn with_autopilot_clock(mut self) -> Self {
        self.autopilot_clock = true;
        self
    }

    /// The offset that maps a vehicle time (camera frame stamps) to `t_us`: the TIMESYNC /
    /// envelope offset, or the reboot epoch with the autopilot clock.
    pub fn vehicle_offset_us(&self) -> Option<i64> {
        if self.autopilot_clock {
            i64::try_from(self.epoch_us).ok()
        } else {
            self.offset_us()
        }
    }

    /// Counters.
    pub fn counters(&self) -> &TimeSyncCounters {
        &self.counters
    }

    /// Whether TIMESYNC has given enough samples to be used.
    pub fn converged(&self) -> bool {
        self.offset_ns.is_some() && self.n >= 3
    }

    /// The offset in use (our µs − autopilot µs), if any.
    pub fn offset_us(&self) -> Option<i64> {
        if self.converged() {
            self.offset_ns.map(|o| (o / 1e3).round() as i64)
        } else {
            self.envelope_us
        }
    }

    /// Our request at `now_ns`.
    pub fn request(now_ns: u64, target_system: u8, target_component: u8) -> apm::TIMESYNC_DATA {
        apm::TIMESYNC_DATA {
            tc1: 0,
            ts1: i64::try_from(now_ns).unwrap_or(i64::MAX),
            target_system,
            target_component,
        }
    }

    /// Handle a TIMESYNC message received at `now_ns` from (`sys`, `comp`). A request is
    /// answered (the reply is returned); a response to one of our requests updates the offset.
    pub fn handle(
        &mut self,
        m: &apm::TIMESYNC_DATA,
        now_ns: u64,
        sys: u8,
        comp: u8,
    ) -> Option<apm::TIMESYNC_DATA> {
        if m.tc1 == 0 {
            self.counters.answered += 1;
            // With the autopilot clock our outputs are stamped in the autopilot's time: answer
            // in that time too (its newest stamp, at most one message period old), or the
            // autopilot's own sync maps our stamps with the wall clock's offset (PX4 SITL at
            // 3.85× logged time jumps and EKF2 stopped fusing our ODOMETRY).
            let tc1_ns = match (self.autopilot_clock, self.track) {
                (true, Some(t)) => t
                    .newest_ap_us
                    .saturating_add(self.epoch_us)
                    .saturating_mul(1_000),
                _ => now_ns,
            };
            return Some(apm::TIMESYNC_DATA {
                tc1: i64::try_from(tc1_ns).unwrap_or(i64::MAX),
                ts1: m.ts1,
                target_system: sys,
                target_component: comp,
            });
        }
        self.response(m.tc1, m.ts1, now_ns);
        None
    }

    fn response(&mut self, tc1_ns: i64, ts1_ns: i64, now_ns: u64) {
        let Ok(ts1) = u64::try_from(ts1_ns) else {
            self.counters.rtt_rejected += 1;
            return;
        };
        if ts1 > now_ns || now_ns - ts1 > self.max_rtt_ns {
            self.counters.rtt_rejected += 1;
            return;
        }
        let sample = (ts1 as f64 + now_ns as f64) / 2.0 - tc1_ns as f64;
        self.counters.samples += 1;
        match self.offset_ns {
            None => {
                self.offset_ns = Some(sample);
                self.n = 1;
            }
            Some(o) => {
                let dev = sample - o;
                if dev.abs() > OUTLIER_NS {
                    self.counters.outliers += 1;
                    self.consecutive_outliers += 1;
                    if self.consecutive_outliers >= RESET_AFTER {
                        self.counters.resets += 1;
                        self.offset_ns = Some(sample);
                        self.n = 1;
                        self.consecutive_outliers = 0;
                    }
                    return;
                }
                self.consecutive_outliers = 0;
                self.n = self.n.saturating_add(1);
                let gain = if self.n <= WARMUP_SAMPLES {
                    1.0 / f64::from(self.n)
                } else {
                    ALPHA
                };
                self.offset_ns = Some(o + gain * dev);
            }
        }
    }

    /// Note the stamp of a clock message (IMU, ATTITUDE, SYSTEM_TIME) received at `rx_us`:
    /// whether it fits the autopilot's clock, is held, or confirmed a reboot or a jump (module
    /// documentation). Stamps that look like Unix time are not clock stamps ([`Self::map`]
    /// uses the reception time): `Fits`.
    pub fn observe_clock(&mut self, ap_us: u64, rx_us: u64) -> ClockStamp {
        if ap_us >= UNIX_STAMP_US {
            return ClockStamp::Fits;
        }
        let fixed_rate = self.fixed_rate();
        let Some(track) = &mut self.track else {
            // The first stamp starts the track at once: nothing is held at the start. Until
            // CLOCK_CONFIRM_SAMPLES have fitted it, a confirmed candidate replaces it as no
            // reboot, should that first stamp have been an outlier.
            self.track = Some(Track::start(ap_us, rx_us));
            self.update_envelope(ap_us, rx_us);
            return ClockStamp::Fits;
        };
        if track.fits(ap_us, rx_us, fixed_rate) {
            track.add(ap_us, rx_us);
            if let Some(c) = self.candidate.take() {
                self.counters.clock_outliers += u64::from(c.n);
            }
            self.update_envelope(ap_us, rx_us);
            return ClockStamp::Fits;
        }
        let c = match self.candidate {
            Some(mut c) if c.track.fits(ap_us, rx_us, fixed_rate) => {
                c.track.add(ap_us, rx_us);
                c.n += 1;
                c
            }
            other => {
                if let Some(c) = other {
                    self.counters.clock_outliers += u64::from(c.n);
                }
                Candidate {
                    track: Track::start(ap_us, rx_us),
                    n: 1,
                    went_back: self.track.is_some_and(|t| ap_us < t.newest_ap_us),
                }
            }
        };
        if c.n < CLOCK_CONFIRM_SAMPLES {
            self.candidate = Some(c);
            return ClockStamp::Held;
        }
        self.candidate = None;
        self.counters.clock_held += u64::from(c.n - 1);
        let outcome = match self.track {
            None => ClockStamp::Fits,
            Some(old) if old.fitted < CLOCK_CONFIRM_SAMPLES => {
                // A provisional first track replaced: it was the outliers.
                self.counters.clock_outliers += u64::from(old.fitted);
                ClockStamp::Fits
            }
            Some(old) if c.went_back => {
                self.counters.reboots += 1;
                // Autopilot clock: continue after the last time of the previous boot.
                self.epoch_us = self
                    .epoch_us
                    .saturating_add(old.newest_ap_us.saturating_add(1));
                ClockStamp::Reboot
            }
            Some(_) => {
                self.counters.jumps += 1;
                ClockStamp::Jump
            }
        };
        self.reset_sync();
        self.track = Some(c.track);
        self.update_envelope(ap_us, rx_us);
        outcome
    }

    /// The rate of the autopilot's clock against ours, when known: 1 on the daemon clock (a
    /// real vehicle); measured on the autopilot clock (a simulator).
    fn fixed_rate(&self) -> Option<f64> {
        (!self.autopilot_clock).then_some(1.0)
    }

    /// Forget the autopilot's clock without counting a reboot (another autopilot took over
    /// the link); with the autopilot clock, time continues after the newest stamp.
    pub fn restart(&mut self) {
        if let Some(t) = self.track.take() {
            self.epoch_us = self
                .epoch_us
                .saturating_add(t.newest_ap_us.saturating_add(1));
        }
        self.candidate = None;
        self.reset_sync();
    }

    fn reset_sync(&mut self) {
        self.offset_ns = None;
        self.n = 0;
        self.consecutive_outliers = 0;
        self.envelope_us = None;
    }

    fn update_envelope(&mut self, ap_us: u64, rx_us: u64) {
        // Both below 2⁶³ (ap_us < UNIX_STAMP_US, rx_us from a monotonic clock).
        let sample = i64::try_from(rx_us).unwrap_or(i64::MAX) - i64::try_from(ap_us).unwrap_or(0);
        self.envelope_us = Some(match self.envelope_us {
            Some(e) => e.saturating_add(ENVELOPE_LEAK_US).min(sample),
            None => sample,
        });
    }

    /// Map a message stamp received at `rx_us` to the daemon's clock, µs. `None` when no
    /// offset is known yet or the result is implausible (counted).
    pub fn map(&mut self, t: ApTime, rx_us: u64) -> Option<u64> {
        if self.autopilot_clock {
            let newest = self
                .track
                .map(|t| t.newest_ap_us.saturating_add(self.epoch_us));
            let ap_us = match t {
                ApTime::Receipt => return newest,
                ApTime::BootUs(u) if u >= UNIX_STAMP_US => {
                    self.counters.unix_stamps += 1;
                    return newest;
                }
                ApTime::BootUs(u) => u,
                ApTime::BootMs(m) => u64::from(m) * 1_000,
            };
            let mapped = ap_us.saturating_add(self.epoch_us);
            // Ahead of the autopilot's clock: a future stamp would hold its kind's monotonic
            // gate shut until that time.
            if newest.is_none_or(|n| mapped > n.saturating_add(FORWARD_SLACK_US)) {
                self.counters.implausible += 1;
                return None;
            }
            return Some(mapped);
        }
        let ap_us = match t {
            ApTime::Receipt => return Some(rx_us),
            ApTime::BootUs(u) => u,
            ApTime::BootMs(m) => u64::from(m) * 1_000,
        };
        if ap_us >= UNIX_STAMP_US {
            self.counters.unix_stamps += 1;
            return Some(rx_us);
        }
        let offset = self.offset_us()?;
        let mapped = i64::try_from(ap_us)
            .ok()
            .and_then(|a| a.checked_add(offset))
            .and_then(|m| u64::try_from(m).ok());
        let Some(mapped) = mapped else {
            self.counters.implausible += 1;
            return None;
        };
        if mapped.saturating_add(MAX_AGE_US) < rx_us
            || mapped > rx_us.saturating_add(FORWARD_SLACK_US)
        {
            self.counters.implausible += 1;
            return None;
        }
        // A sample cannot be taken after it was received (offset error, small jitter).
        Some(mapped.min(rx_us))
    }
}

/// The boot-time stamp of a clock message (IMU, ATTITUDE, SYSTEM_TIME), µs.
pub fn clock_stamp_us(msg: &apm::MavMessage) -> Option<u64> {
    use apm::MavMessage as M;
    match msg {
        M::HIGHRES_IMU(m) => Some(m.time_usec),
        M::RAW_IMU(m) => Some(m.time_usec),
        M::SCALED_IMU(m) => Some(u64::from(m.time_boot_ms) * 1_000),
        M::ATTITUDE(m) => Some(u64::from(m.time_boot_ms) * 1_000),
        M::SYSTEM_TIME(m) => Some(u64::from(m.time_boot_ms) * 1_000),
        _ => None,
    }
}

/// Sensor kinds for [`MonotonicGate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// IMU.
    Imu = 0,
    /// Air data.
    Air = 1,
    /// Magnetometer.
    Mag = 2,
    /// GNSS.
    Gnss = 3,
    /// Camera frames.
    Frame = 4,
    /// The autopilot's attitude.
    RefAttitude = 5,
}

/// Per-kind strictly increasing times.
#[derive(Debug, Clone, Default)]
pub struct MonotonicGate {
    last_us: [Option<u64>; 6],
    /// Samples refused as older than the previous one of their kind (reordering).
    pub rejected: u64,
    /// Samples refused as repeats: the same time as the previous one of their kind (a 1 Hz
    /// fix resent at a 5 Hz message rate, the pressure of both AIRSPEED and HIGHRES_IMU).
    pub repeated: u64,
}

impl MonotonicGate {
    /// Accept `t_us` for `kind` if it is after the previous accepted one.
    pub fn accept(&mut self, kind: Kind, t_us: u64) -> bool {
        let slot = &mut self.last_us[kind as usize];
        match *slot {
            Some(last) if t_us == last => {
                self.repeated += 1;
                false
            }
            Some(last) if t_us < last => {
                self.rejected += 1;
                false
            }
            _ => {
                *slot = Some(t_us);
                true
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000; // ns

    /// Simulated exchange: the autopilot's clock is ours − `offset_ns`; the request takes
    /// `up` ns to arrive and the response `down` ns to come back.
    fn exchange(ts: &mut TimeSync, t0: u64, offset_ns: i64, up: u64, down: u64) {
        let req = TimeSync::request(t0, 1, 1);
        let ap_now = (t0 + up) as i64 - offset_ns;
        let resp = apm::TIMESYNC_DATA {
            tc1: ap_now,
            ts1: req.ts1,
            target_system: 1,
            target_component: 197,
        };
        assert!(ts.handle(&resp, t0 + up + down, 1, 1).is_none());
    }

    #[test]
    fn requests_are_answered_with_our_time_and_their_ts1() {
        let mut ts = TimeSync::new(10 * MS);
        let req = apm::TIMESYNC_DATA {
            tc1: 0,
            ts1: 123_456,
            target_system: 0,
            target_component: 0,
        };
        let r = ts.handle(&req, 5_000_000_000, 1, 1).unwrap();
        assert_eq!(
            (r.tc1, r.ts1, r.target_system, r.target_component),
            (5_000_000_000, 123_456, 1, 1)
        );
        assert_eq!(ts.counters().answered, 1);
    }

    #[test]
    fn symmetric_round_trips_give_the_exact_offset_and_long_ones_are_refused() {
        let mut ts = TimeSync::new(10 * MS);
        let offset = 7_000_000_000_i64; // our clock reads 7 s more than the autopilot's
        for k in 0..20 {
            exchange(&mut ts, 10_000 * MS + k * 200 * MS, offset, 2 * MS, 2 * MS);
        }
        assert!(ts.converged());
        assert_eq!(ts.offset_us(), Some(offset / 1000));
        // A 30 ms round trip is not used.
        exchange(&mut ts, 20_000 * MS, 0, 15 * MS, 15 * MS);
        assert_eq!(ts.counters().rtt_rejected, 1);
        assert_eq!(ts.offset_us(), Some(offset / 1000));
        // Asymmetric delay: the error is half the asymmetry (1 ms up, 5 ms down → −2 ms).
        let mut ts = TimeSync::new(10 * MS);
        for k in 0..20 {
            exchange(&mut ts, 10_000 * MS + k * 100 * MS, 0, MS, 5 * MS);
        }
        assert_eq!(ts.offset_us(), Some(2_000));
    }

    #[test]
    fn isolated_outliers_are_ignored_and_a_clock_jump_restarts_the_filter() {
        let mut ts = TimeSync::new(10 * MS);
        for k in 0..20 {
            exchange(
                &mut ts,
                10_000 * MS + k * 100 * MS,
                1_000 * MS as i64,
                MS,
                MS,
            );
        }
        // One 100 ms outlier: ignored.
        exchange(&mut ts, 13_000 * MS, 1_100 * MS as i64, MS, MS);
        assert_eq!(ts.offset_us(), Some(1_000_000));
        assert_eq!(ts.counters().outliers, 1);
        for k in 0..RESET_AFTER as u64 {
            exchange(
                &mut ts,
                14_000 * MS + k * 100 * MS,
                1_500 * MS as i64,
                MS,
                MS,
            );
        }
        assert_eq!(ts.counters().resets, 1);
        for k in 0..5 {
            exchange(
                &mut ts,
                15_000 * MS + k * 100 * MS,
                1_500 * MS as i64,
                MS,
                MS,
            );
        }
        assert_eq!(ts.offset_us(), Some(1_500_000));
    }

    #[test]
    fn envelope_maps_before_timesync_and_a_reboot_is_detected() {
        let mut ts = TimeSync::new(10 * MS);
        assert_eq!(ts.map(ApTime::BootMs(10), 1_000), None, "no offset yet");
        // Autopilot boot time 0 = our 5 s; latency 3 ms, once only 1 ms. Nothing held at the
        // start.
        for k in 0..100_u64 {
            let ap = k * 20_000;
            let lat = if k == 50 { 1_000 } else { 3_000 };
            assert_eq!(ts.observe_clock(ap, 5_000_000 + ap + lat), ClockStamp::Fits);
        }
        let off = ts.offset_us().unwrap();
        // Envelope = 5 s + 1 ms, plus at most 49 µs of leak since the 1 ms sample.
        assert!((5_001_000..=5_001_049).contains(&off), "{off}");
        assert_eq!(
            ts.map(ApTime::BootMs(1_000), 6_010_000),
            Some(1_000_000 + off as u64)
        );
        // Receipt and Unix stamps use the reception time.
        assert_eq!(ts.map(ApTime::Receipt, 42), Some(42));
        assert_eq!(ts.map(ApTime::BootUs(1_700_000_000_000_000), 43), Some(43));
        // A stamp mapping 3 s before or after its reception is refused.
        assert_eq!(ts.map(ApTime::BootUs(0), 8_010_000), None);
        assert_eq!(ts.map(ApTime::BootUs(6_000_000), 8_010_000), None);
        assert_eq!(ts.counters().implausible, 2);
        // Reboot: time goes back from 1.98 s to 0, confirmed by the fifth stamp of the new boot.
        for k in 0..u64::from(CLOCK_CONFIRM_SAMPLES) {
            let r = ts.observe_clock(k * 10_000, 20_000_000 + k * 10_000);
            let want = if k == 4 {
                ClockStamp::Reboot
            } else {
                ClockStamp::Held
            };
            assert_eq!(r, want);
        }
        assert_eq!(ts.counters().reboots, 1);
        assert_eq!(ts.offset_us(), Some(20_000_000));
        assert_eq!(ts.observe_clock(50_000, 20_050_500), ClockStamp::Fits);
        assert_eq!(
            (ts.counters().clock_held, ts.counters().clock_outliers),
            (4, 0)
        );
    }

    #[test]
    fn with_the_autopilot_clock_timesync_requests_are_answered_in_its_time() {
        let mut ts = TimeSync::new(10 * MS).with_autopilot_clock();
        // Before any stamp: the daemon's clock.
        let req = TimeSync::request(5, 1, 1);
        assert_eq!(ts.handle(&req, 777, 1, 1).map(|r| r.tc1), Some(777));
        // The vehicle runs 10× faster: its stamps, not our wall clock, answer.
        for k in 0..u64::from(CLOCK_CONFIRM_SAMPLES) {
            ts.observe_clock(39_960_000 + k * 10_000, 3_996_000 + k * 1_000);
        }
        let r = ts.handle(&req, 4_000_100_000, 1, 1).unwrap();
        assert_eq!(r.tc1, 40_000_000_000);
        assert_eq!(r.ts1, 5);
    }

    #[test]
    fn the_autopilot_clock_is_used_as_is_and_continued_across_a_reboot() {
        let mut ts = TimeSync::new(10 * MS).with_autopilot_clock();
        assert_eq!(ts.map(ApTime::Receipt, 5), None, "no clock message yet");
        // The vehicle runs 10× faster than our clock: its times are used unchanged.
        for k in 0..30_u64 {
            ts.observe_clock(k * 100_000, 1_000_000 + k * 10_000);
        }
        assert_eq!(ts.map(ApTime::BootUs(2_900_000), 0), Some(2_900_000));
        assert_eq!(ts.map(ApTime::BootMs(3_000), 0), Some(3_000_000));
        assert_eq!(
            ts.map(ApTime::Receipt, 0),
            Some(2_900_000),
            "newest clock stamp"
        );
        assert_eq!(ts.vehicle_offset_us(), Some(0));
        // A stamp ahead of the clock would shut the gate of its kind: refused.
        assert_eq!(ts.map(ApTime::BootUs(3_600_000_000), 0), None);
        // Reboot at 2.9 s: the new boot's time 0 continues at 2.9 s + 1 µs.
        for k in 0..u64::from(CLOCK_CONFIRM_SAMPLES) {
            ts.observe_clock(k * 100_000, 2_000_000 + k * 10_000);
        }
        assert_eq!(ts.counters().reboots, 1);
        assert_eq!(ts.map(ApTime::BootUs(0), 0), Some(2_900_001));
        assert_eq!(ts.vehicle_offset_us(), Some(2_900_001));
    }

    /// A 100 Hz clock stream, boot time 0 = our 5 s, 2 ms latency, from `k0` to `k1`.
    fn stream(ts: &mut TimeSync, ks: std::ops::Range<u64>) -> Vec<ClockStamp> {
        ks.map(|k| ts.observe_clock(k * 10_000, 5_002_000 + k * 10_000))
            .collect()
    }

    #[test]
    fn a_first_stamp_that_is_an_outlier_is_replaced_without_a_reboot() {
        let mut ts = TimeSync::new(10 * MS);
        assert_eq!(ts.observe_clock(3_600_000_000, 5_001_000), ClockStamp::Fits);
        let r = stream(&mut ts, 0..10);
        assert_eq!(r[..4], [ClockStamp::Held; 4]);
        assert!(r[4..].iter().all(|r| *r == ClockStamp::Fits));
        let c = *ts.counters();
        assert_eq!(
            (c.clock_outliers, c.clock_held, c.reboots, c.jumps),
            (1, 4, 0, 0)
        );
        assert!((5_001_900..=5_002_000).contains(&ts.offset_us().unwrap()));
    }

    #[test]
    fn a_lone_outlier_stamp_is_refused_and_only_a_consistent_run_is_a_reboot_or_a_jump() {
        for autopilot_clock in [false, true] {
            let mut ts = TimeSync::new(10 * MS);
            if autopilot_clock {
                ts = ts.with_autopilot_clock();
            }
            stream(&mut ts, 0..100);
            let off = ts.offset_us();
            // One IMU sample stamped an hour ahead, then the stream goes on.
            assert_eq!(ts.observe_clock(3_600_000_000, 6_000_500), ClockStamp::Held);
            assert!(
                stream(&mut ts, 100..110)
                    .iter()
                    .all(|r| *r == ClockStamp::Fits)
            );
            // One stamped back at boot (what a reboot looks like), and four ahead in a row.
            assert_eq!(ts.observe_clock(0, 6_100_500), ClockStamp::Held);
            assert!(
                stream(&mut ts, 110..120)
                    .iter()
                    .all(|r| *r == ClockStamp::Fits)
            );
            for k in 0..4 {
                assert_eq!(
                    ts.observe_clock(3_600_000_000 + k * 10_000, 6_200_500 + k * 10_000),
                    ClockStamp::Held
                );
            }
            assert!(
                stream(&mut ts, 124..130)
                    .iter()
                    .all(|r| *r == ClockStamp::Fits)
            );
            let c = *ts.counters();
            assert_eq!((c.clock_outliers, c.reboots, c.jumps), (6, 0, 0));
            assert_eq!(ts.offset_us(), off, "offset untouched");
            if autopilot_clock {
                assert_eq!(ts.map(ApTime::Receipt, 0), Some(1_290_000), "newest stamp");
            }
            // The clock really jumps by an hour: the fifth consistent stamp confirms it.
            let run: Vec<ClockStamp> = (0..5)
                .map(|k| ts.observe_clock(3_600_000_000 + k * 10_000, 6_400_000 + k * 10_000))
                .collect();
            assert_eq!(run[..4], [ClockStamp::Held; 4]);
            assert_eq!(run[4], ClockStamp::Jump);
            assert_eq!(ts.counters().jumps, 1);
            assert_eq!(ts.counters().clock_outliers, 6);
        }
    }

    #[test]
    fn outages_bursts_and_a_fast_simulator_stay_on_the_track() {
        const { assert!(FORWARD_SLACK_US < REBOOT_BACKSTEP_US) };
        // Daemon clock: a 5 s link outage while the autopilot runs on, then 0.3 s of samples
        // queued behind a stall and read at once.
        let mut ts = TimeSync::new(10 * MS);
        stream(&mut ts, 0..100);
        assert!(
            stream(&mut ts, 600..700)
                .iter()
                .all(|r| *r == ClockStamp::Fits)
        );
        let burst: Vec<ClockStamp> = (700..730)
            .map(|k| ts.observe_clock(k * 10_000, 5_002_000 + 7_300_000))
            .collect();
        assert!(burst.iter().all(|r| *r == ClockStamp::Fits));
        // Autopilot clock, a vehicle 10× faster than real time, its link stalling for 0.3 s.
        let mut ts = TimeSync::new(10 * MS).with_autopilot_clock();
        let mut rx = 1_000_000;
        let mut out = Vec::new();
        for k in 0..500_u64 {
            rx += if k == 300 { 300_000 } else { 10_000 };
            out.push(ts.observe_clock((rx - 1_000_000) * 10, rx));
        }
        assert!(out[4..].iter().all(|r| *r == ClockStamp::Fits));
        let c = *ts.counters();
        assert_eq!((c.clock_outliers, c.reboots, c.jumps), (0, 0, 0));
    }

    #[test]
    fn extreme_timesync_fields_and_stamps_neither_panic_nor_poison_the_offset() {
        let mut ts = TimeSync::new(10 * MS);
        for k in 0..20 {
            exchange(
                &mut ts,
                10_000 * MS + k * 100 * MS,
                1_000 * MS as i64,
                MS,
                MS,
            );
        }
        let off = ts.offset_us();
        for tc1 in [i64::MIN, -1, 1, i64::MAX] {
            for ts1 in [i64::MIN, -1, 0, 1, i64::MAX] {
                let m = apm::TIMESYNC_DATA {
                    tc1,
                    ts1,
                    target_system: 0,
                    target_component: 0,
                };
                assert!(ts.handle(&m, 20_000 * MS, 1, 1).is_none());
            }
        }
        assert_eq!(ts.offset_us(), off);
        let req = apm::TIMESYNC_DATA {
            tc1: 0,
            ts1: i64::MIN,
            target_system: 0,
            target_component: 0,
        };
        assert_eq!(
            ts.handle(&req, u64::MAX, 1, 1).map(|r| r.ts1),
            Some(i64::MIN)
        );
        for stamp in [
            0,
            1,
            u64::from(u32::MAX) * 1_000,
            UNIX_STAMP_US - 1,
            u64::MAX,
        ] {
            for rx in [0, 1, u64::MAX] {
                ts.observe_clock(stamp, rx);
                for t in [
                    ApTime::BootUs(stamp),
                    ApTime::BootMs(u32::MAX),
                    ApTime::Receipt,
                ] {
                    ts.map(t, rx);
                }
            }
        }
    }

    #[test]
    fn the_gate_refuses_duplicates_and_reordering_per_kind() {
        let mut g = MonotonicGate::default();
        assert!(g.accept(Kind::Imu, 10));
        assert!(g.accept(Kind::Air, 5), "kinds are independent");
        assert!(!g.accept(Kind::Imu, 10));
        assert!(!g.accept(Kind::Imu, 9));
        assert!(g.accept(Kind::Imu, 11));
        assert_eq!((g.rejected, g.repeated), (1, 1));
    }
}
