//! Negotiation of the message intervals with the autopilot (MAVLink "Message interval"
//! service, MAV_CMD_SET_MESSAGE_INTERVAL). Pure: no I/O, no clock; the link task feeds it the
//! time and the COMMAND_ACKs.
//!
//! Why a negotiation: an autopilot may refuse a rate. ArduPlane DENIES any interval shorter than
//! 80 % of its main-loop period (20 ms at its 50 Hz loop: 50 Hz is refused, 40 Hz is accepted)
//! and then keeps streaming its default rate — RAW_IMU at 1 Hz — on which no INS can run.
//! A fire-and-forget request silently left the daemon on that 1 Hz stream. So requests go out
//! one at a time; each waits for its COMMAND_ACK (acks of one command type carry no message
//! id, so at most one request is in flight); a DENIED request is retried at
//! the next slower rate of [`RATE_LADDER_HZ`] (other refusals give the message up); an unanswered one is re-sent up to
//! [`MAX_TRIES`] times. Every refusal is reported to the caller (logged, counted, STATUSTEXT).

use std::collections::VecDeque;

use mavlink::dialects::ardupilotmega as apm;

/// Rates tried in turn after a refusal, Hz (intervals of 2.5 ms to 1 s; 40 Hz is the fastest
/// ArduPlane accepts at its 50 Hz loop, 25 Hz the slowest the INS is validated at).
pub const RATE_LADDER_HZ: [f64; 12] = [
    400.0, 250.0, 200.0, 100.0, 50.0, 40.0, 25.0, 20.0, 10.0, 5.0, 2.0, 1.0,
];
/// A request without an ACK after this long is sent again, µs.
pub const ACK_TIMEOUT_US: u64 = 1_000_000;
/// Sends of one request before it is given up as unanswered.
pub const MAX_TRIES: u32 = 3;

/// What happened to one request (`msg_id`: the message; `rate_hz`: the rate asked for).
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(
    missing_docs,
    reason = "the fields `msg_id` and `rate_hz` are the same in every variant and documented \
              once, on the enum"
)]
pub enum Outcome {
    /// Accepted at this rate.
    Accepted { msg_id: u32, rate_hz: f64 },
    /// Refused with `result`; retried at `retry_hz` (`None`: given up).
    Refused {
        msg_id: u32,
        rate_hz: f64,
        result: apm::MavResult,
        retry_hz: Option<f64>,
    },
    /// No ACK after [`MAX_TRIES`] sends (autopilots that do not acknowledge: the stream is
    /// then verified by the input rate check, not by the ACK).
    Unanswered { msg_id: u32, rate_hz: f64 },
}

#[derive(Debug, Clone, Copy)]
struct InFlight {
    msg_id: u32,
    rate_hz: f64,
    sent_us: u64,
    tries: u32,
}

/// One negotiation round over a set of (message id, rate) requests.
#[derive(Debug, Clone, Default)]
pub struct Negotiator {
    queue: VecDeque<(u32, f64)>,
    in_flight: Option<InFlight>,
    /// Rates accepted so far (message id, Hz).
    granted: Vec<(u32, f64)>,
}

/// The next slower rate of the ladder below `rate_hz`.
pub fn slower_rate(rate_hz: f64) -> Option<f64> {
    RATE_LADDER_HZ
        .iter()
        .copied()
        .find(|r| *r < rate_hz * (1.0 - 1e-9))
}

impl Negotiator {
    /// A round over `requests` (rates ≤ 0 stop a stream and are sent like the others).
    pub fn new(requests: impl IntoIterator<Item = (u32, f64)>) -> Self {
        Self {
            queue: requests.into_iter().collect(),
            in_flight: None,
            granted: Vec::new(),
        }
    }

    /// Whether every request has been answered or given up.
    pub fn done(&self) -> bool {
        self.queue.is_empty() && self.in_flight.is_none()
    }

    /// The rates accepted so far.
    pub fn granted(&self) -> &[(u32, f64)] {
        &self.granted
    }

    /// The request to send now, if any: the next one when nothing is in flight, or the one in
    /// flight again after [`ACK_TIMEOUT_US`]. Gives up after [`MAX_TRIES`] sends.
    pub fn poll(&mut self, now_us: u64) -> (Option<(u32, f64)>, Option<Outcome>) {
        let mut outcome = None;
        if let Some(f) = &mut self.in_flight {
            if now_us.saturating_sub(f.sent_us) < ACK_TIMEOUT_US {
                return (None, None);
            }
            if f.tries < MAX_TRIES {
                f.tries += 1;
                f.sent_us = now_us;
                return (Some((f.msg_id, f.rate_hz)), None);
            }
            outcome = Some(Outcome::Unanswered {
                msg_id: f.msg_id,
                rate_hz: f.rate_hz,
            });
            self.in_flight = None;
        }
        let next = self.queue.pop_front().map(|(msg_id, rate_hz)| {
            self.in_flight = Some(InFlight {
                msg_id,
                rate_hz,
                sent_us: now_us,
                tries: 1,
            });
            (msg_id, rate_hz)
        });
        (next, outcome)
    }

    /// A COMMAND_ACK for MAV_CMD_SET_MESSAGE_INTERVAL arrived. `None` when nothing was in
    /// flight (a late duplicate) or the result is not final (IN_PROGRESS).
    pub fn on_ack(&mut self, result: apm::MavResult) -> Option<Outcome> {
        use apm::MavResult as R;
        let f = self.in_flight?;
        match result {
            R::MAV_RESULT_IN_PROGRESS => None,
            R::MAV_RESULT_ACCEPTED => {
                self.in_flight = None;
                self.granted.push((f.msg_id, f.rate_hz));
                Some(Outcome::Accepted {
                    msg_id: f.msg_id,
                    rate_hz: f.rate_hz,
                })
            }
            // DENIED is how a rate limit answers (ArduPilot): try slower. UNSUPPORTED,
            // FAILED, ...: no other rate would do better, give up on this message.
            _ => {
                self.in_flight = None;
                let retry_hz = if f.rate_hz > 0.0 && result == R::MAV_RESULT_DENIED {
                    slower_rate(f.rate_hz)
                } else {
                    None
                };
                if let Some(r) = retry_hz {
                    self.queue.push_front((f.msg_id, r));
                }
                Some(Outcome::Refused {
                    msg_id: f.msg_id,
                    rate_hz: f.rate_hz,
                    result,
                    retry_hz,
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use apm::MavResult as R;

    /// An autopilot that refuses intervals shorter than `min_interval_us` (ArduPlane at a 50 Hz
    /// loop: 25 ms) and acknowledges everything else.
    fn ardupilot_like(rate_hz: f64, min_interval_us: f64) -> R {
        if rate_hz > 0.0 && 1e6 / rate_hz < min_interval_us {
            R::MAV_RESULT_DENIED
        } else {
            R::MAV_RESULT_ACCEPTED
        }
    }

    #[test]
    fn a_denied_imu_rate_steps_down_to_the_fastest_accepted_one() {
        let mut n = Negotiator::new([(26, 100.0), (29, 25.0)]);
        let mut t = 0;
        let mut sent = Vec::new();
        let mut refused = 0;
        while !n.done() {
            let (req, out) = n.poll(t);
            assert!(out.is_none());
            let (id, rate) = req.expect("a request while not done");
            sent.push((id, rate));
            match n.on_ack(ardupilot_like(rate, 25_000.0)) {
                Some(Outcome::Refused { .. }) => refused += 1,
                Some(Outcome::Accepted { .. }) => {}
                o => panic!("{o:?}"),
            }
            t += 10_000;
        }
        // 100 and 50 Hz refused, 40 Hz (25 ms) accepted; 25 Hz accepted at once.
        assert_eq!(sent, vec![(26, 100.0), (26, 50.0), (26, 40.0), (29, 25.0)]);
        assert_eq!(refused, 2);
        assert_eq!(n.granted(), &[(26, 40.0), (29, 25.0)]);
    }

    #[test]
    fn one_request_in_flight_resent_on_timeout_then_given_up() {
        let mut n = Negotiator::new([(105, 100.0), (29, 25.0)]);
        assert_eq!(n.poll(0).0, Some((105, 100.0)));
        // Nothing else goes out while the first waits for its ACK.
        assert_eq!(n.poll(ACK_TIMEOUT_US - 1), (None, None));
        assert_eq!(n.poll(ACK_TIMEOUT_US).0, Some((105, 100.0)));
        assert_eq!(n.poll(2 * ACK_TIMEOUT_US).0, Some((105, 100.0)));
        // Third send unanswered: given up, the next request goes out.
        let (next, out) = n.poll(3 * ACK_TIMEOUT_US);
        assert_eq!(
            out,
            Some(Outcome::Unanswered {
                msg_id: 105,
                rate_hz: 100.0
            })
        );
        assert_eq!(next, Some((29, 25.0)));
        assert_eq!(
            n.on_ack(R::MAV_RESULT_ACCEPTED),
            Some(Outcome::Accepted {
                msg_id: 29,
                rate_hz: 25.0
            })
        );
        assert!(n.done());
        // A late duplicate ACK changes nothing.
        assert_eq!(n.on_ack(R::MAV_RESULT_ACCEPTED), None);
    }

    #[test]
    fn the_ladder_ends_and_says_so() {
        let mut n = Negotiator::new([(26, 1.0)]);
        n.poll(0);
        assert_eq!(
            n.on_ack(R::MAV_RESULT_UNSUPPORTED),
            Some(Outcome::Refused {
                msg_id: 26,
                rate_hz: 1.0,
                result: R::MAV_RESULT_UNSUPPORTED,
                retry_hz: None
            })
        );
        assert!(n.done());
        // Unsupported is not a rate limit: no slower retry.
        let mut n = Negotiator::new([(26, 100.0)]);
        n.poll(0);
        assert!(matches!(
            n.on_ack(R::MAV_RESULT_UNSUPPORTED),
            Some(Outcome::Refused { retry_hz: None, .. })
        ));
        assert!(n.done());
        assert_eq!(slower_rate(40.0), Some(25.0));
        assert_eq!(slower_rate(45.0), Some(40.0));
        assert_eq!(slower_rate(0.5), None);
    }
}
