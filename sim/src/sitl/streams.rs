//! Message streams of the SITL vehicle: which messages are sent, at what interval, and how
//! `MAV_CMD_SET_MESSAGE_INTERVAL` changes them (mavlink.io "Message interval" service;
//! research/mavlink.md §3.2–3.3).
//!
//! - **PX4-like**: streams are scheduled on the 100 Hz sensor instants with an accumulating
//!   deadline (`next += interval`), so any interval of 10 ms or more is met on average, and a
//!   shorter one runs at the sensor rate (PX4 cannot send data faster than it is produced).
//!   Every request is `ACCEPTED`.
//! - **ArduPilot-like**: streams are serviced by a 50 Hz main loop (ArduPlane's
//!   `SCHED_LOOP_RATE`); a message goes out on a loop tick when at least its interval has
//!   passed since it was last sent (`now − last ≥ interval`, milliseconds), and intervals are
//!   capped at 80 % of the loop rate (`interval_ms·800 < loop_period_us` → `loop_period/800`,
//!   as ArduPilot's `GCS_MAVLINK::set_ap_message_interval` does): 25 ms, which the 20 ms loop
//!   turns into an effective 25 Hz. Such requests are `ACCEPTED` (ArduPilot clamps silently).
//!
//! IMU streams slower than the 100 Hz simulated IMU carry the **box average** of the samples
//! taken since the previous message of that stream (each sample standing for the 10 ms before
//! it), i.e. the delta-angle and delta-velocity of the interval divided by its length — what
//! an autopilot that integrates its fast IMU would report. At 100 Hz it is the sample itself.

use mavlink::MessageData;
use mavlink::dialects::ardupilotmega as apm;
use nalgebra::Vector3;

use ianav::sensors::ImuSample;

/// The autopilot the vehicle imitates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Autopilot {
    /// PX4 on an onboard-mode link.
    #[default]
    Px4,
    /// ArduPilot (ArduPlane, 50 Hz loop).
    ArduPilot,
}

/// ArduPlane's main loop period, µs (`SCHED_LOOP_RATE` = 50 Hz).
pub const ARDUPILOT_LOOP_US: u64 = 20_000;
/// ArduPilot's shortest message interval, ms: 80 % of the loop rate.
pub const ARDUPILOT_MIN_INTERVAL_MS: u64 = ARDUPILOT_LOOP_US / 800;

/// The messages the vehicle can stream, by id, in the order they leave within one sensor
/// instant: aiding data (GNSS, air data, vanes) before the IMU sample of the same instant, the
/// order in which the simulator's own INS consumes them (`flight.rs`, `sample_sensors`).
pub const STREAMABLE: [u32; 13] = [
    apm::HEARTBEAT_DATA::ID,
    apm::TIMESYNC_DATA::ID,
    apm::SYSTEM_TIME_DATA::ID,
    apm::GPS_RAW_INT_DATA::ID,
    apm::SCALED_PRESSURE_DATA::ID,
    apm::AIRSPEED_DATA::ID,
    apm::AOA_SSA_DATA::ID,
    apm::HIGHRES_IMU_DATA::ID,
    apm::SCALED_IMU_DATA::ID,
    apm::RAW_IMU_DATA::ID,
    apm::ATTITUDE_DATA::ID,
    apm::GLOBAL_POSITION_INT_DATA::ID,
    apm::VFR_HUD_DATA::ID,
];

/// Default interval of each stream, µs (`None`: off until requested). See `docs/SITL.md`.
pub fn default_interval_us(autopilot: Autopilot, id: u32) -> Option<u64> {
    let hz = |f: u64| Some(1_000_000 / f);
    match (autopilot, id) {
        (_, apm::HEARTBEAT_DATA::ID | apm::SYSTEM_TIME_DATA::ID) => hz(1),
        // PX4 onboard link: HIGHRES_IMU at 100 Hz (ianav's recommended MAV_n_MODE set-up),
        // air data and vanes at the simulated air-data rate so that the companion's INS gets
        // what the offline INS gets; GPS_RAW_INT as produced (1 Hz receiver).
        (Autopilot::Px4, apm::HIGHRES_IMU_DATA::ID) => hz(100),
        // PX4 sends TIMESYNC requests at 10 Hz on onboard links.
        (Autopilot::Px4, apm::TIMESYNC_DATA::ID) => hz(10),
        (Autopilot::Px4, apm::AIRSPEED_DATA::ID | apm::AOA_SSA_DATA::ID) => hz(100),
        (Autopilot::Px4, apm::SCALED_PRESSURE_DATA::ID) => hz(1),
        (Autopilot::Px4, apm::ATTITUDE_DATA::ID | apm::GLOBAL_POSITION_INT_DATA::ID) => hz(50),
        (Autopilot::Px4, apm::VFR_HUD_DATA::ID) => hz(10),
        (Autopilot::Px4, apm::GPS_RAW_INT_DATA::ID) => Some(0),
        // ArduPlane with the companion's serial port set to SRn_RAW_SENS = SRn_EXTRA1 = 25
        // (the most its 50 Hz loop delivers) and SRn_EXT_STAT = 1.
        (Autopilot::ArduPilot, apm::RAW_IMU_DATA::ID) => hz(25),
        (Autopilot::ArduPilot, apm::SCALED_PRESSURE_DATA::ID) => hz(25),
        (Autopilot::ArduPilot, apm::AIRSPEED_DATA::ID | apm::AOA_SSA_DATA::ID) => hz(25),
        (Autopilot::ArduPilot, apm::ATTITUDE_DATA::ID) => hz(25),
        (Autopilot::ArduPilot, apm::GLOBAL_POSITION_INT_DATA::ID) => hz(10),
        (Autopilot::ArduPilot, apm::VFR_HUD_DATA::ID) => hz(10),
        (Autopilot::ArduPilot, apm::GPS_RAW_INT_DATA::ID) => hz(1),
        _ => None,
    }
}

/// Box average of IMU samples (see the module documentation).
#[derive(Debug, Clone, Copy, Default)]
pub struct ImuAverager {
    gyro_sum: Vector3<f64>,
    accel_sum: Vector3<f64>,
    n: u32,
}

impl ImuAverager {
    /// Add one sample.
    pub fn add(&mut self, s: &ImuSample) {
        self.gyro_sum += s.gyro_rps;
        self.accel_sum += s.accel_mps2;
        self.n += 1;
    }

    /// The average of the samples added since the last call, stamped `t_us`, and reset.
    pub fn take(&mut self, t_us: u64) -> Option<ImuSample> {
        if self.n == 0 {
            return None;
        }
        let k = 1.0 / f64::from(self.n);
        let s = ImuSample {
            t_us,
            gyro_rps: self.gyro_sum * k,
            accel_mps2: self.accel_sum * k,
        };
        *self = Self::default();
        Some(s)
    }

    /// Forget the samples added.
    pub fn clear(&mut self) {
        *self = Self::default();
    }
}

/// One stream's schedule.
#[derive(Debug, Clone, Copy)]
struct Stream {
    id: u32,
    /// `None`: off; `Some(0)`: on each new datum (GPS_RAW_INT on PX4); else interval, µs.
    interval_us: Option<u64>,
    next_due_us: u64,
    last_sent_us: Option<u64>,
}

/// Result of a SET_MESSAGE_INTERVAL request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IntervalOutcome {
    /// Applied; the interval now in force (µs, `None` = off).
    Accepted(Option<u64>),
    /// The message is not one the vehicle streams.
    Unsupported,
    /// Invalid parameter (e.g. NaN or an interval below −1).
    Denied,
}

/// The stream table of one link.
#[derive(Debug, Clone)]
pub struct Streams {
    autopilot: Autopilot,
    streams: Vec<Stream>,
}

impl Streams {
    /// The default streams of `autopilot`.
    pub fn new(autopilot: Autopilot) -> Self {
        let streams = STREAMABLE
            .iter()
            .map(|&id| Stream {
                id,
                interval_us: default_interval_us(autopilot, id),
                next_due_us: 0,
                last_sent_us: None,
            })
            .collect();
        Self { autopilot, streams }
    }

    /// The interval in force for message `id`, µs (`None`: off or not streamable).
    pub fn interval_us(&self, id: u32) -> Option<u64> {
        self.streams
            .iter()
            .find(|s| s.id == id)
            .and_then(|s| s.interval_us)
    }

    /// Apply `MAV_CMD_SET_MESSAGE_INTERVAL` (param1 = message id, param2 = interval µs:
    /// −1 off, 0 default) at vehicle time `now_us`.
    pub fn set_interval(
        &mut self,
        id_param: f32,
        interval_param: f32,
        now_us: u64,
    ) -> IntervalOutcome {
        if !(id_param.is_finite() && interval_param.is_finite())
            || id_param < 0.0
            || interval_param < -1.0
        {
            return IntervalOutcome::Denied;
        }
        let id = id_param.round() as u32;
        let autopilot = self.autopilot;
        let Some(stream) = self.streams.iter_mut().find(|s| s.id == id) else {
            return IntervalOutcome::Unsupported;
        };
        let requested = if interval_param <= -0.5 {
            None
        } else if interval_param < 0.5 {
            default_interval_us(autopilot, id)
        } else {
            Some(f64::from(interval_param).round() as u64)
        };
        stream.interval_us = match (autopilot, requested) {
            (Autopilot::ArduPilot, Some(us)) => {
                // ArduPilot keeps whole milliseconds and caps at 80 % of its loop rate.
                let ms = (us / 1000).max(ARDUPILOT_MIN_INTERVAL_MS);
                Some(ms * 1000)
            }
            (_, r) => r,
        };
        // PX4 sends at the next opportunity; ArduPilot keeps the message's last send time,
        // so the new interval counts from it.
        stream.next_due_us = now_us;
        if autopilot == Autopilot::Px4 {
            stream.last_sent_us = None;
        }
        IntervalOutcome::Accepted(stream.interval_us)
    }

    /// Whether `now_us` is a scheduling instant of the vehicle's loop.
    pub fn is_loop_tick(&self, now_us: u64) -> bool {
        match self.autopilot {
            Autopilot::Px4 => true,
            Autopilot::ArduPilot => now_us.is_multiple_of(ARDUPILOT_LOOP_US),
        }
    }

    /// The messages due at the loop tick `now_us`, marked as sent. `fresh(id)` tells whether
    /// a new datum arrived for on-update streams.
    pub fn due(&mut self, now_us: u64, fresh: impl Fn(u32) -> bool) -> Vec<u32> {
        let mut out = Vec::new();
        if !self.is_loop_tick(now_us) {
            return out;
        }
        for s in &mut self.streams {
            let Some(interval_us) = s.interval_us else {
                continue;
            };
            let send = if interval_us == 0 {
                fresh(s.id)
            } else {
                match self.autopilot {
                    Autopilot::Px4 => {
                        if now_us >= s.next_due_us {
                            s.next_due_us += interval_us;
                            if s.next_due_us <= now_us {
                                s.next_due_us = now_us + interval_us;
                            }
                            true
                        } else {
                            false
                        }
                    }
                    Autopilot::ArduPilot => match s.last_sent_us {
                        None => true,
                        Some(last) => now_us.saturating_sub(last) / 1000 >= interval_us / 1000,
                    },
                }
            };
            if send {
                s.last_sent_us = Some(now_us);
                out.push(s.id);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(streams: &mut Streams, id: u32, seconds: u64) -> usize {
        (0..seconds * 100)
            .map(|k| k * 10_000)
            .filter(|&t| streams.due(t, |_| true).contains(&id))
            .count()
    }

    #[test]
    fn px4_meets_requested_rates_on_average_up_to_the_sensor_rate() {
        let mut s = Streams::new(Autopilot::Px4);
        let id = apm::HIGHRES_IMU_DATA::ID;
        assert_eq!(count(&mut s, id, 10), 1000);
        // 30 Hz (33,333 µs) on 100 Hz instants: 300 messages in 10 s, ±1.
        assert_eq!(
            s.set_interval(id as f32, 33_333.0, 0),
            IntervalOutcome::Accepted(Some(33_333))
        );
        let n = count(&mut s, id, 10);
        assert!((299..=301).contains(&n), "{n}");
        // 200 Hz requested: the vehicle cannot exceed its 100 Hz sensor.
        s.set_interval(id as f32, 5_000.0, 0);
        assert_eq!(count(&mut s, id, 10), 1000);
        s.set_interval(id as f32, -1.0, 0);
        assert_eq!(count(&mut s, id, 1), 0);
        assert_eq!(
            s.set_interval(id as f32, 0.0, 0),
            IntervalOutcome::Accepted(Some(10_000))
        );
        assert_eq!(s.set_interval(9999.0, 1e4, 0), IntervalOutcome::Unsupported);
        assert_eq!(s.set_interval(f32::NAN, 1e4, 0), IntervalOutcome::Denied);
    }

    #[test]
    fn ardupilot_caps_at_its_loop_and_delivers_at_most_25_hz() {
        let mut s = Streams::new(Autopilot::ArduPilot);
        let id = apm::RAW_IMU_DATA::ID;
        // Messages of `id` over 10 s of vehicle time from `t0_s`.
        let count_from = |s: &mut Streams, t0_s: u64| {
            (t0_s * 100..(t0_s + 10) * 100)
                .map(|k| k * 10_000)
                .filter(|&t| s.due(t, |_| true).contains(&id))
                .count()
        };
        assert_eq!(count_from(&mut s, 0), 250);
        // 100 Hz requested → clamped to 25 ms, which the 20 ms loop runs at 25 Hz.
        assert_eq!(
            s.set_interval(id as f32, 10_000.0, 10_000_000),
            IntervalOutcome::Accepted(Some(25_000))
        );
        assert_eq!(count_from(&mut s, 10), 250);
        // 10 Hz is met exactly; 30 Hz (33 ms) becomes 40 ms on the loop: 25 Hz.
        s.set_interval(id as f32, 100_000.0, 20_000_000);
        assert_eq!(count_from(&mut s, 20), 100);
        s.set_interval(id as f32, 33_333.0, 30_000_000);
        assert_eq!(count_from(&mut s, 30), 250);
        assert_eq!(s.interval_us(apm::HIGHRES_IMU_DATA::ID), None);
    }

    #[test]
    fn the_imu_average_is_the_sample_at_the_native_rate_and_the_mean_below_it() {
        let sample = |k: u64| ImuSample {
            t_us: k * 10_000,
            gyro_rps: Vector3::new(k as f64, 0.0, -1.0),
            accel_mps2: Vector3::new(0.0, 2.0 * k as f64, -9.8),
        };
        let mut a = ImuAverager::default();
        assert!(a.take(0).is_none());
        a.add(&sample(3));
        assert_eq!(a.take(30_000), Some(sample(3)));
        for k in 1..=4 {
            a.add(&sample(k));
        }
        let avg = a.take(40_000).unwrap();
        assert_eq!(avg.t_us, 40_000);
        assert!((avg.gyro_rps - Vector3::new(2.5, 0.0, -1.0)).norm() < 1e-12);
        assert!((avg.accel_mps2 - Vector3::new(0.0, 5.0, -9.8)).norm() < 1e-12);
    }
}
