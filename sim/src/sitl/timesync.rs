//! The vehicle's side of TIMESYNC as a requester (MAVLink "Time Synchronization Protocol v2";
//! docs/REFERENCES.md M3.4: PX4 sends requests at 10 Hz on onboard links): each answered
//! request gives a pair (companion clock `tc1`, vehicle clock at the round trip's midpoint).
//! A least-squares line through the recent pairs maps companion timestamps to vehicle time,
//! with a skew term because at `--speed K` the vehicle clock runs K times faster than the
//! companion's. Round trips longer than [`MAX_RTT_US`] are discarded, as PX4 does above 10 ms.

use std::collections::VecDeque;

/// Longest round trip kept, µs of vehicle time (10 ms of wall time at 10× speed).
pub const MAX_RTT_US: u64 = 100_000;
/// Pairs kept for the fit.
pub const WINDOW: usize = 64;
/// Fewest pairs, and shortest span of companion time, µs, before the map is used.
pub const MIN_PAIRS: usize = 8;
/// See [`MIN_PAIRS`].
pub const MIN_SPAN_US: f64 = 200_000.0;

/// Companion clock → vehicle clock.
#[derive(Debug, Clone, Default)]
pub struct ClockMap {
    /// (companion µs, vehicle µs).
    pairs: VecDeque<(f64, f64)>,
    /// Answers used and discarded.
    pub used: u64,
    /// Answers discarded (round trip too long, or not one of ours).
    pub discarded: u64,
}

impl ClockMap {
    /// Record the answer `tc1_ns` to our request sent at vehicle time `ts1_ns`, received at
    /// `now_us`.
    pub fn add(&mut self, ts1_ns: i64, tc1_ns: i64, now_us: u64) {
        let Ok(sent_us) = u64::try_from(ts1_ns / 1000) else {
            self.discarded += 1;
            return;
        };
        if sent_us > now_us || now_us - sent_us > MAX_RTT_US || tc1_ns <= 0 {
            self.discarded += 1;
            return;
        }
        let mid_us = (sent_us as f64 + now_us as f64) * 0.5;
        self.pairs.push_back((tc1_ns as f64 * 1e-3, mid_us));
        if self.pairs.len() > WINDOW {
            self.pairs.pop_front();
        }
        self.used += 1;
    }

    /// Vehicle time of companion time `companion_us` (`None` until enough pairs).
    pub fn to_vehicle_us(&self, companion_us: u64) -> Option<f64> {
        let n = self.pairs.len();
        if n < MIN_PAIRS {
            return None;
        }
        let (mut sx, mut sy) = (0.0, 0.0);
        for &(x, y) in &self.pairs {
            sx += x;
            sy += y;
        }
        let (mx, my) = (sx / n as f64, sy / n as f64);
        let (mut sxx, mut sxy) = (0.0, 0.0);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &(x, y) in &self.pairs {
            sxx += (x - mx) * (x - mx);
            sxy += (x - mx) * (y - my);
            lo = lo.min(x);
            hi = hi.max(x);
        }
        if hi - lo < MIN_SPAN_US || sxx <= 0.0 {
            return None;
        }
        let skew = sxy / sxx;
        Some(my + skew * (companion_us as f64 - mx))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_skewed_offset_clock_is_recovered_and_slow_round_trips_are_ignored() {
        let mut map = ClockMap::default();
        // Companion clock c = v/10 + 5e12 µs (vehicle at 10× speed); 2 ms round trips.
        let companion = |v_us: f64| v_us / 10.0 + 5e12;
        for k in 0..40_u64 {
            let sent = 1_000_000 + k * 100_000;
            let now = sent + 2_000;
            let tc1 = (companion((sent + now) as f64 * 0.5) * 1e3) as i64;
            map.add((sent * 1000) as i64, tc1, now);
            if k < MIN_PAIRS as u64 - 1 {
                assert!(map.to_vehicle_us(5_000_000_000_000).is_none());
            }
        }
        // A 1 s round trip and an answer from the future are discarded.
        map.add(1_000_000_000, 1, 2_000_000);
        map.add(9_000_000_000, 1, 2_000_000);
        assert_eq!((map.used, map.discarded), (40, 2));
        let v = map.to_vehicle_us(companion(2_345_678.0) as u64).unwrap();
        assert!((v - 2_345_678.0).abs() < 20.0, "{v}");
    }
}
