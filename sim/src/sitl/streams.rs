//! Message streams of the SITL vehicle: which messages are sent, at what interval, and how
//! `MAV_CMD_SET_MESSAGE_INTERVAL` changes them (mavlink.io "Message interval" service), as
//! the real autopilots' MAVLink modules do it (ArduPilot `GCS_MAVLINK::set_message_interval`
//! and its deferred-message scheduler, October 2025 master; PX4 v1.16.0 `MavlinkReceiver::
//! set_message_interval`, `MavlinkStream::update` and the onboard-mode stream list).
//!
//! - **ArduPilot**: streams are serviced by ArduPlane's 50 Hz main loop. An interval request
//!   keeps whole milliseconds (`interval_us / 1000`, truncated); one shorter than 80 % of the
//!   loop period (`interval_ms · 800 < loop_period_us`, i.e. < 25 ms at 50 Hz) is **DENIED**
//!   and answered with the STATUSTEXT "Requested rate for message ID N too fast. Increase
//!   SCHED_LOOP_RATE"; an id ArduPilot has no message for is DENIED too. A message is due
//!   when `now_ms − last_ms ≥ interval_ms`; after sending, `last_ms += interval_ms` (back to
//!   `now_ms` if that leaves it more than one interval behind), so 25 ms on 20 ms ticks gives
//!   4 messages in 5 ticks: **40 Hz on average**. Defaults are the compiled-in ArduPlane
//!   stream-group rates (`SRn_*` = 1 Hz for every group).
//! - **PX4** (onboard link): the v1.16.0 onboard defaults (HIGHRES_IMU 50 Hz, ATTITUDE 100 Hz,
//!   GLOBAL_POSITION_INT 50 Hz, GPS_RAW_INT on each fix, TIMESYNC 10 Hz, SCALED_PRESSURE and
//!   SYSTEM_TIME 1 Hz, VFR_HUD 10 Hz). Every request for a message it has a stream for is
//!   ACCEPTED (any negative interval stops it, 0 restores the default); an id without a stream
//!   (AIRSPEED, AOA_SSA and RAW_IMU have none in v1.16.0), HEARTBEAT, or a non-zero param3 gives
//!   FAILED. Streams run on the sensor instants with an accumulating deadline; a stream only
//!   sends new data, so an interval shorter than the 10 ms sensor period gives 100 Hz.
//! - **Ideal** (not an autopilot; PX4 identity): every simulated sample at its native rate
//!   (HIGHRES_IMU, AIRSPEED and vane AOA_SSA at 100 Hz) and PX4's interval rules, so that a
//!   companion can get exactly what the simulator's own INS uses (the reference runs of the
//!   end-to-end tests).
//!
//! IMU streams: PX4 and Ideal send the **box average** of the 100 Hz samples since that
//! stream's previous message (PX4's `vehicle_imu` integrates its fast IMU: delta angle and
//! velocity over the interval divided by its length). ArduPilot sends the **latest sample**
//! (`AP_InertialSensor::get_gyro()` at send time), so a 40 Hz stream decimates the 100 Hz IMU.

use mavlink::MessageData;
use mavlink::dialects::ardupilotmega as apm;
use nalgebra::Vector3;

use ianav::sensors::ImuSample;

/// The autopilot the vehicle imitates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Autopilot {
    /// PX4 v1.16 on an onboard-mode link.
    #[default]
    Px4,
    /// ArduPilot (ArduPlane, 50 Hz loop).
    ArduPilot,
    /// Not a real autopilot: PX4 identity and rules, every simulated sample at its native
    /// rate (vanes included). The reference for comparing a companion with the offline INS.
    Ideal,
}

impl Autopilot {
    /// Whether the vehicle presents itself as PX4 (HEARTBEAT, interval and origin rules).
    pub fn is_px4_like(self) -> bool {
        matches!(self, Autopilot::Px4 | Autopilot::Ideal)
    }
}

/// ArduPlane's main loop period, µs (`SCHED_LOOP_RATE` = 50 Hz).
pub const ARDUPILOT_LOOP_US: u64 = 20_000;
/// ArduPilot's shortest accepted message interval, ms: 80 % of the loop rate.
pub const ARDUPILOT_MIN_INTERVAL_MS: u64 = ARDUPILOT_LOOP_US / 800;
/// ArduPilot's longest message interval, ms.
pub const ARDUPILOT_MAX_INTERVAL_MS: u64 = 60_000;

/// The messages the vehicle can stream, by id, in the order they leave within one sensor
/// instant: aiding data (GNSS, air data, vanes) before the IMU sample of the same instant, the
/// order in which the simulator's own INS consumes them (`flight/sensors.rs`, `sample_sensors`).
pub const STREAMABLE: [u32; 14] = [
    apm::HEARTBEAT_DATA::ID,
    apm::TIMESYNC_DATA::ID,
    apm::SYSTEM_TIME_DATA::ID,
    apm::GPS_RAW_INT_DATA::ID,
    apm::SCALED_PRESSURE_DATA::ID,
    apm::SCALED_PRESSURE2_DATA::ID,
    apm::AIRSPEED_DATA::ID,
    apm::AOA_SSA_DATA::ID,
    apm::HIGHRES_IMU_DATA::ID,
    apm::SCALED_IMU_DATA::ID,
    apm::RAW_IMU_DATA::ID,
    apm::ATTITUDE_DATA::ID,
    apm::GLOBAL_POSITION_INT_DATA::ID,
    apm::VFR_HUD_DATA::ID,
];

/// Index of `id` in [`STREAMABLE`].
pub fn stream_index(id: u32) -> Option<usize> {
    STREAMABLE.iter().position(|&s| s == id)
}

/// MAVLink names of [`STREAMABLE`], in its order.
pub fn stream_names() -> Vec<&'static str> {
    STREAMABLE
        .iter()
        .map(|&id| match id {
            apm::HEARTBEAT_DATA::ID => apm::HEARTBEAT_DATA::NAME,
            apm::TIMESYNC_DATA::ID => apm::TIMESYNC_DATA::NAME,
            apm::SYSTEM_TIME_DATA::ID => apm::SYSTEM_TIME_DATA::NAME,
            apm::GPS_RAW_INT_DATA::ID => apm::GPS_RAW_INT_DATA::NAME,
            apm::SCALED_PRESSURE_DATA::ID => apm::SCALED_PRESSURE_DATA::NAME,
            apm::SCALED_PRESSURE2_DATA::ID => apm::SCALED_PRESSURE2_DATA::NAME,
            apm::AIRSPEED_DATA::ID => apm::AIRSPEED_DATA::NAME,
            apm::AOA_SSA_DATA::ID => apm::AOA_SSA_DATA::NAME,
            apm::HIGHRES_IMU_DATA::ID => apm::HIGHRES_IMU_DATA::NAME,
            apm::SCALED_IMU_DATA::ID => apm::SCALED_IMU_DATA::NAME,
            apm::RAW_IMU_DATA::ID => apm::RAW_IMU_DATA::NAME,
            apm::ATTITUDE_DATA::ID => apm::ATTITUDE_DATA::NAME,
            apm::GLOBAL_POSITION_INT_DATA::ID => apm::GLOBAL_POSITION_INT_DATA::NAME,
            apm::VFR_HUD_DATA::ID => apm::VFR_HUD_DATA::NAME,
            _ => "?",
        })
        .collect()
}

/// Index in [`STREAMABLE`] of the stream called `name` (MAVLink name, any case).
pub fn stream_index_by_name(name: &str) -> Option<usize> {
    stream_names()
        .iter()
        .position(|n| n.eq_ignore_ascii_case(name))
}

/// Whether `autopilot` has a stream for message `id` at all (PX4 v1.16.0 has no AIRSPEED,
/// AOA_SSA or RAW_IMU stream; ArduPilot has no HIGHRES_IMU in a default ArduPlane build).
pub fn has_stream(autopilot: Autopilot, id: u32) -> bool {
    if stream_index(id).is_none() {
        return false;
    }
    match autopilot {
        Autopilot::Px4 => !matches!(
            id,
            apm::AIRSPEED_DATA::ID | apm::AOA_SSA_DATA::ID | apm::RAW_IMU_DATA::ID
        ),
        Autopilot::ArduPilot => !matches!(id, apm::HIGHRES_IMU_DATA::ID | apm::TIMESYNC_DATA::ID),
        Autopilot::Ideal => true,
    }
}

/// Default interval of each stream, µs (`None`: off until requested; `Some(0)`: each new
/// datum). See `docs/SITL.md`.
pub fn default_interval_us(autopilot: Autopilot, id: u32) -> Option<u64> {
    let hz = |f: u64| Some(1_000_000 / f);
    match (autopilot, id) {
        (_, apm::HEARTBEAT_DATA::ID | apm::SYSTEM_TIME_DATA::ID) => hz(1),
        // PX4 v1.16.0, MAVLINK_MODE_ONBOARD.
        (Autopilot::Px4, apm::HIGHRES_IMU_DATA::ID) => hz(50),
        (Autopilot::Px4 | Autopilot::Ideal, apm::TIMESYNC_DATA::ID) => hz(10),
        (Autopilot::Px4 | Autopilot::Ideal, apm::SCALED_PRESSURE_DATA::ID) => hz(1),
        (Autopilot::Px4, apm::ATTITUDE_DATA::ID) => hz(100),
        (Autopilot::Px4 | Autopilot::Ideal, apm::GLOBAL_POSITION_INT_DATA::ID) => hz(50),
        (Autopilot::Px4 | Autopilot::Ideal, apm::VFR_HUD_DATA::ID) => hz(10),
        (Autopilot::Px4 | Autopilot::Ideal, apm::GPS_RAW_INT_DATA::ID) => Some(0),
        // Ideal: the simulator's native rates (and the estimate at 50 Hz).
        (Autopilot::Ideal, apm::HIGHRES_IMU_DATA::ID) => hz(100),
        (Autopilot::Ideal, apm::ATTITUDE_DATA::ID) => hz(50),
        (Autopilot::Ideal, apm::AIRSPEED_DATA::ID | apm::AOA_SSA_DATA::ID) => hz(100),
        // ArduPlane's compiled-in stream-group rates: SRn_RAW_SENS (RAW_IMU, SCALED_PRESSURE,
        // SCALED_PRESSURE2, AIRSPEED), SRn_EXT_STAT (GPS_RAW_INT), SRn_POSITION
        // (GLOBAL_POSITION_INT), SRn_EXTRA1 (ATTITUDE, AOA_SSA), SRn_EXTRA2 (VFR_HUD): 1 Hz.
        (
            Autopilot::ArduPilot,
            apm::RAW_IMU_DATA::ID
            | apm::SCALED_PRESSURE_DATA::ID
            | apm::SCALED_PRESSURE2_DATA::ID
            | apm::AIRSPEED_DATA::ID
            | apm::GPS_RAW_INT_DATA::ID
            | apm::GLOBAL_POSITION_INT_DATA::ID
            | apm::ATTITUDE_DATA::ID
            | apm::AOA_SSA_DATA::ID
            | apm::VFR_HUD_DATA::ID,
        ) => hz(1),
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
    /// `None`: off; `Some(0)`: on each new datum; else interval, µs.
    interval_us: Option<u64>,
    /// PX4: next deadline, µs.
    next_due_us: u64,
    /// ArduPilot: the scheduler's `last_sent_ms` (advanced by the interval on each send).
    last_ms: u64,
}

/// Result of a SET_MESSAGE_INTERVAL request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IntervalOutcome {
    /// Applied; the interval now in force (µs, `None` = off).
    Accepted(Option<u64>),
    /// Invalid parameter (NaN, an interval below −1 on ArduPilot, a non-zero param3 on
    /// ArduPilot) or an id ArduPilot has no message for.
    Denied,
    /// ArduPilot: shorter than 80 % of the loop period (answered with a STATUSTEXT).
    TooFast,
    /// PX4: no stream for this id, HEARTBEAT, or an unsupported param3.
    Failed,
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
                last_ms: 0,
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
    /// −1 off, 0 default; param3 must be 0) at vehicle time `now_us`.
    pub fn set_interval(
        &mut self,
        id_param: f32,
        interval_param: f32,
        param3: f32,
        now_us: u64,
    ) -> IntervalOutcome {
        if !(id_param.is_finite() && interval_param.is_finite()) || id_param < 0.0 {
            return IntervalOutcome::Denied;
        }
        let autopilot = self.autopilot;
        let id = match autopilot {
            // ArduPilot casts to an integer; PX4 rounds.
            Autopilot::ArduPilot => id_param as u32,
            _ => (id_param + 0.5) as u32,
        };
        let known = has_stream(autopilot, id);
        let interval_us = match autopilot {
            Autopilot::ArduPilot => {
                if param3 != 0.0 || !known {
                    return IntervalOutcome::Denied;
                }
                let us = interval_param as i64;
                let ms = match us {
                    0 => default_interval_us(autopilot, id).map(|d| d / 1000),
                    -1 => None,
                    i64::MIN..=-2 => return IntervalOutcome::Denied,
                    1..=999 => Some(1),
                    60_000_001.. => Some(ARDUPILOT_MAX_INTERVAL_MS),
                    _ => Some(us as u64 / 1000),
                };
                if let Some(ms) = ms
                    && ms * 800 < ARDUPILOT_LOOP_US
                {
                    return IntervalOutcome::TooFast;
                }
                ms.map(|ms| ms * 1000)
            }
            Autopilot::Px4 | Autopilot::Ideal => {
                if !known || id == apm::HEARTBEAT_DATA::ID || (param3 + 0.5) as i64 != 0 {
                    return IntervalOutcome::Failed;
                }
                if interval_param < -0.000_01 {
                    None
                } else if interval_param > 0.000_01 {
                    Some(f64::from(interval_param).round().max(1.0) as u64)
                } else {
                    default_interval_us(autopilot, id)
                }
            }
        };
        let Some(stream) = self.streams.iter_mut().find(|s| s.id == id) else {
            return IntervalOutcome::Denied;
        };
        stream.interval_us = interval_us;
        // PX4 sends at the next opportunity; ArduPilot counts the new interval from now
        // (`last_sent_ms = millis()` when the message joins a new bucket).
        stream.next_due_us = now_us;
        stream.last_ms = now_us / 1000;
        IntervalOutcome::Accepted(stream.interval_us)
    }

    /// Whether `now_us` is a scheduling instant of the vehicle's loop.
    pub fn is_loop_tick(&self, now_us: u64) -> bool {
        match self.autopilot {
            Autopilot::Px4 | Autopilot::Ideal => true,
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
        let now_ms = now_us / 1000;
        for s in &mut self.streams {
            let Some(interval_us) = s.interval_us else {
                continue;
            };
            let send = if interval_us == 0 {
                fresh(s.id)
            } else {
                match self.autopilot {
                    Autopilot::Px4 | Autopilot::Ideal => {
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
                    Autopilot::ArduPilot => {
                        let interval_ms = interval_us / 1000;
                        if now_ms.saturating_sub(s.last_ms) >= interval_ms {
                            // Keep a regular clock, but do not catch up more than one
                            // interval.
                            s.last_ms += interval_ms;
                            if now_ms.saturating_sub(s.last_ms) > interval_ms {
                                s.last_ms = now_ms;
                            }
                            true
                        } else {
                            false
                        }
                    }
                }
            };
            if send {
                out.push(s.id);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Messages of `id` over `seconds` of vehicle time from `t0_s`, on 10 ms sensor instants.
    fn count_from(streams: &mut Streams, id: u32, t0_s: u64, seconds: u64) -> usize {
        (t0_s * 100..(t0_s + seconds) * 100)
            .map(|k| k * 10_000)
            .filter(|&t| streams.due(t, |_| true).contains(&id))
            .count()
    }

    #[test]
    fn px4_meets_requested_rates_on_average_up_to_the_sensor_rate() {
        let mut s = Streams::new(Autopilot::Px4);
        let id = apm::HIGHRES_IMU_DATA::ID;
        // v1.16.0 onboard default: 50 Hz.
        assert_eq!(count_from(&mut s, id, 0, 10), 500);
        // 30 Hz (33,333 µs) on 100 Hz instants: 300 messages in 10 s, ±1.
        assert_eq!(
            s.set_interval(id as f32, 33_333.0, 0.0, 10_000_000),
            IntervalOutcome::Accepted(Some(33_333))
        );
        let n = count_from(&mut s, id, 10, 10);
        assert!((299..=301).contains(&n), "{n}");
        // 200 Hz requested: accepted, but no faster than the 100 Hz sensor.
        s.set_interval(id as f32, 5_000.0, 0.0, 20_000_000);
        assert_eq!(count_from(&mut s, id, 20, 10), 1000);
        // Any negative interval stops the stream; 0 restores the default.
        s.set_interval(id as f32, -5.0, 0.0, 30_000_000);
        assert_eq!(count_from(&mut s, id, 30, 1), 0);
        assert_eq!(
            s.set_interval(id as f32, 0.0, 0.0, 31_000_000),
            IntervalOutcome::Accepted(Some(20_000))
        );
        // No stream for AIRSPEED, AOA_SSA or RAW_IMU in v1.16.0, nor for unknown ids: FAILED.
        for id in [
            apm::AIRSPEED_DATA::ID,
            apm::AOA_SSA_DATA::ID,
            apm::RAW_IMU_DATA::ID,
            9999,
        ] {
            assert_eq!(
                s.set_interval(id as f32, 1e4, 0.0, 0),
                IntervalOutcome::Failed
            );
        }
        assert_eq!(
            s.set_interval(apm::HEARTBEAT_DATA::ID as f32, 1e6, 0.0, 0),
            IntervalOutcome::Failed
        );
        assert_eq!(
            s.set_interval(id as f32, 1e4, 1.0, 0),
            IntervalOutcome::Failed
        );
        assert_eq!(
            s.set_interval(f32::NAN, 1e4, 0.0, 0),
            IntervalOutcome::Denied
        );
    }

    #[test]
    fn ardupilot_denies_intervals_below_80_percent_of_its_loop_and_meets_40_hz() {
        let mut s = Streams::new(Autopilot::ArduPilot);
        let id = apm::SCALED_IMU_DATA::ID;
        // Off by default; RAW_IMU streams at the SRn_RAW_SENS default of 1 Hz.
        assert_eq!(count_from(&mut s, id, 0, 10), 0);
        assert_eq!(count_from(&mut s, apm::RAW_IMU_DATA::ID, 10, 10), 10);
        // 50 Hz (20 ms) and 24.999 ms (truncated to 24 ms) are too fast for a 50 Hz loop.
        for us in [20_000.0, 24_999.0, 10_000.0, 1.0] {
            assert_eq!(
                s.set_interval(id as f32, us, 0.0, 20_000_000),
                IntervalOutcome::TooFast,
                "{us}"
            );
        }
        assert_eq!(s.interval_us(id), None, "a denied request changes nothing");
        // 25 ms is accepted and delivered at 40 Hz on average from the 20 ms loop: 4 per
        // 100 ms (20 or 40 ms apart). The first is due 25 ms after the request.
        assert_eq!(
            s.set_interval(id as f32, 25_000.0, 0.0, 20_000_000),
            IntervalOutcome::Accepted(Some(25_000))
        );
        assert_eq!(count_from(&mut s, id, 20, 1), 39);
        assert_eq!(count_from(&mut s, id, 21, 10), 400);
        // 30 Hz (33,333 µs → 33 ms): 30.3 Hz on average, never two messages per tick.
        s.set_interval(id as f32, 33_333.0, 0.0, 31_000_000);
        count_from(&mut s, id, 31, 1);
        let n = count_from(&mut s, id, 32, 10);
        assert!((302..=304).contains(&n), "{n}");
        // 10 Hz is met exactly.
        s.set_interval(id as f32, 100_000.0, 0.0, 42_000_000);
        count_from(&mut s, id, 42, 1);
        assert_eq!(count_from(&mut s, id, 43, 10), 100);
        // Off, and back to the default (off for SCALED_IMU).
        s.set_interval(id as f32, -1.0, 0.0, 53_000_000);
        assert_eq!(count_from(&mut s, id, 53, 1), 0);
        assert_eq!(
            s.set_interval(id as f32, 0.0, 0.0, 54_000_000),
            IntervalOutcome::Accepted(None)
        );
        // Invalid: interval below −1, param3, no such message in ArduPlane.
        assert_eq!(
            s.set_interval(id as f32, -2.0, 0.0, 0),
            IntervalOutcome::Denied
        );
        assert_eq!(
            s.set_interval(id as f32, 1e5, 1.0, 0),
            IntervalOutcome::Denied
        );
        assert_eq!(
            s.set_interval(apm::HIGHRES_IMU_DATA::ID as f32, 1e5, 0.0, 0),
            IntervalOutcome::Denied
        );
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
