//! The link against other systems and absurd input (the daemon's link-robustness acceptance): a
//! ground station and two companions beside the fake autopilot for 20 s, every input message with
//! its fields at their extremes (over loopback and through the decoder, deterministically and as a
//! property), and a lone IMU sample stamped an hour ahead. Loopback UDP only; every wait is
//! bounded.

#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

mod common;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::daemon_run::{start, stop};
use common::extremes::{check_event, extreme_variants, nominal_inputs, seeded_variant};
use common::fake_autopilot::{self as fa, Fake, Rx, wait_for};
use ianav::daemon::config::{AutopilotKind, DaemonConfig, TemperatureSource};
use ianav::env::magnetic::MagneticModel;
use ianav::io::mavlink_in::{DecoderConfig, InputDecoder};
use ianav::io::timesync::{ClockStamp, TimeSync, clock_stamp_us};
use ianav::sensors::SensorEvent;
use mavlink::MavlinkVersion;
use mavlink::dialects::ardupilotmega as apm;
use nalgebra::Vector3;
use proptest::prelude::*;

/// ODOMETRY rate the daemon is configured for, Hz.
const ODOMETRY_HZ: f64 = 30.0;

fn config(port: u16, extra: &str) -> DaemonConfig {
    let text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{port}\"\nlink_timeout_s = 1.0\n\
         timesync_rate_hz = 10.0\n{extra}\n\
         [output]\nmode = \"odometry\"\nrate_hz = {ODOMETRY_HZ}\n\
         [navigation]\nmag_decimal_year = 2026.5\n\
         [logging]\ncounters_period_s = 0.0\n"
    );
    DaemonConfig::from_toml_str(&text, None).unwrap()
}

fn is_odometry(r: &Rx) -> bool {
    matches!(r.msg, apm::MavMessage::ODOMETRY(_))
}

/// Reception times of the ODOMETRY the fake received in [from, to].
fn odometry_between(fake: &Fake, from: Instant, to: Instant) -> Vec<Instant> {
    fake.received(|r| is_odometry(r) && r.at >= from && r.at <= to)
        .into_iter()
        .map(|r| r.at)
        .collect()
}

/// The longest interval without ODOMETRY in [from, to], the ends included.
fn longest_gap(times: &[Instant], from: Instant, to: Instant) -> Duration {
    let mut edges = vec![from];
    edges.extend_from_slice(times);
    edges.push(to);
    edges
        .windows(2)
        .map(|w| w[1].saturating_duration_since(w[0]))
        .max()
        .unwrap_or_default()
}

async fn publishing(fake: &Fake) {
    let t = Instant::now();
    assert!(
        wait_for(Duration::from_secs(8), || fake
            .received(|r| is_odometry(r) && r.at > t)
            .len()
            > 30)
        .await,
        "the daemon publishes"
    );
}

/// The fake autopilot's nominal inputs now (its position and magnetic field).
fn nominal_now(fake: &Fake, mag: &MagneticModel, ahead_us: u64) -> Vec<apm::MavMessage> {
    let pos = fa::position(fake.start.elapsed().as_secs_f64());
    let e7 = |rad: f64| (rad.to_degrees() * 1e7).round() as i32;
    nominal_inputs(
        fake.boot_us() + ahead_us,
        e7(pos.lat_rad),
        e7(pos.lon_rad),
        mag.field_ned_nt(&pos).unwrap(),
    )
}

fn texts_with(fake: &Fake, words: &[&str]) -> Vec<String> {
    fake.statustexts()
        .into_iter()
        .filter(|t| words.iter().any(|w| t.contains(w)))
        .collect()
}

/// Frames of the intruders, sent from the fake autopilot's socket: a link carries every
/// system through one peer (a router, the telemetry radio, a serial port).
struct Intruder {
    sys: u8,
    comp: u8,
    seq: u8,
}

impl Intruder {
    fn frame(&mut self, msg: &apm::MavMessage) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1);
        fa::frame(MavlinkVersion::V2, self.sys, self.comp, self.seq, msg)
    }
}

#[derive(Debug, Default)]
struct Sent {
    heartbeats: AtomicU64,
    autopilot_heartbeats: AtomicU64,
    inputs: AtomicU64,
}

/// Link-robustness acceptance: a ground station (HEARTBEAT at 1 Hz), a second flight controller on
/// system 2 and a companion on the autopilot's own system (HEARTBEAT at 1 Hz, IMU-looking messages
/// at 50 Hz on their own clocks, a GNSS fix 10 km away) beside the autopilot for 20 s: the
/// autopilot is never switched, ODOMETRY keeps its rate (≥ 95 %, no gap over 0.2 s), nothing of
/// theirs is decoded, and every message of theirs is counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ground_station_and_companions_on_the_link_neither_take_it_over_nor_deafen_it() {
    const RUN: Duration = Duration::from_secs(20);
    let port = fa::free_udp_port();
    let (h, task) = start(config(port, "")).await;
    let fake = Fake::start(port).await;
    publishing(&fake).await;
    assert_eq!(
        h.shared.state(|s| s.autopilot),
        Some((1, 1, AutopilotKind::Px4))
    );

    let sent = Arc::new(Sent::default());
    let done = Arc::new(AtomicBool::new(false));
    let intruders = {
        let (sock, daemon, sent, done) =
            (fake.sock.clone(), fake.daemon, sent.clone(), done.clone());
        tokio::spawn(async move {
            use apm::MavAutopilot as A;
            use apm::MavType as T;
            let mut gcs = Intruder {
                sys: 255,
                comp: 190,
                seq: 0,
            };
            let mut other_fc = Intruder {
                sys: 2,
                comp: 1,
                seq: 0,
            };
            let mut companion = Intruder {
                sys: 1,
                comp: 191,
                seq: 0,
            };
            let hb = |mavtype, autopilot| {
                apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
                    mavtype,
                    autopilot,
                    system_status: apm::MavState::MAV_STATE_ACTIVE,
                    mavlink_version: 3,
                    ..Default::default()
                })
            };
            let mut tick = tokio::time::interval(Duration::from_millis(20));
            // Their own clocks: 1,000 s and 7 s since boot.
            let t0 = Instant::now();
            for k in 0_u64.. {
                tick.tick().await;
                if done.load(Ordering::Relaxed) {
                    return;
                }
                let mut frames = Vec::new();
                if k % 50 == 0 {
                    frames.push(gcs.frame(&hb(T::MAV_TYPE_GCS, A::MAV_AUTOPILOT_INVALID)));
                    frames.push(other_fc.frame(&hb(T::MAV_TYPE_FIXED_WING, A::MAV_AUTOPILOT_PX4)));
                    frames.push(companion.frame(&hb(
                        T::MAV_TYPE_ONBOARD_CONTROLLER,
                        A::MAV_AUTOPILOT_INVALID,
                    )));
                    sent.heartbeats.fetch_add(3, Ordering::Relaxed);
                    sent.autopilot_heartbeats.fetch_add(1, Ordering::Relaxed);
                }
                let us = t0.elapsed().as_micros() as u64;
                // Turning at 0.5 rad/s and accelerating: decoded, it would turn the solution.
                let imu = |time_usec| {
                    apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
                        time_usec,
                        xacc: 5.0,
                        zacc: -9.8,
                        zgyro: 0.5,
                        xmag: 0.3,
                        abs_pressure: 900.0,
                        temperature: 10.0,
                        fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x1fff),
                        ..Default::default()
                    })
                };
                frames.push(other_fc.frame(&imu(1_000_000_000 + us)));
                frames.push(companion.frame(&imu(7_000_000 + us)));
                let mut n_inputs = 2;
                if k % 10 == 0 {
                    frames.push(other_fc.frame(&apm::MavMessage::GPS_RAW_INT(
                        apm::GPS_RAW_INT_DATA {
                            time_usec: 1_000_000_000 + us,
                            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
                            lat: 451_000_000,
                            lon: 70_000_000,
                            alt: 452_000,
                            alt_ellipsoid: 500_000,
                            vel: 1_000,
                            cog: 9_000,
                            h_acc: 500,
                            v_acc: 800,
                            vel_acc: 100,
                            ..Default::default()
                        },
                    )));
                    n_inputs += 1;
                }
                for f in frames {
                    let _ = sock.send_to(&f, daemon).await;
                }
                sent.inputs.fetch_add(n_inputs, Ordering::Relaxed);
            }
        })
    };

    // The autopilot listened to, sampled every 50 ms.
    let t0 = Instant::now();
    let mut switched = Vec::new();
    while t0.elapsed() < RUN {
        let ap = h.shared.state(|s| s.autopilot);
        if ap != Some((1, 1, AutopilotKind::Px4)) {
            switched.push((t0.elapsed(), ap));
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let t1 = Instant::now();
    done.store(true, Ordering::Relaxed);
    intruders.await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let imu_sent = fake.ctl.lock().unwrap().imu_sent;
    let c = stop(h, task).await;
    assert!(
        switched.is_empty(),
        "autopilot not the PX4 on 1/1 in {} samples, first {:?}",
        switched.len(),
        switched.first()
    );
    assert_eq!(c.autopilot_changes, 0);

    let odo = odometry_between(&fake, t0, t1);
    let expected = ODOMETRY_HZ * (t1 - t0).as_secs_f64();
    let gap = longest_gap(&odo, t0, t1);
    eprintln!(
        "{} ODOMETRY of {expected:.0} expected ({:.1} %), longest gap {:.0} ms",
        odo.len(),
        100.0 * odo.len() as f64 / expected,
        gap.as_secs_f64() * 1e3
    );
    assert!(
        odo.len() as f64 >= 0.95 * expected,
        "{} of {expected:.0}",
        odo.len()
    );
    assert!(gap <= Duration::from_millis(200), "ODOMETRY gap of {gap:?}");

    // Every intruder message counted (loopback UDP may lose a few under load), none decoded.
    let (hb, fc_hb, inputs) = (
        sent.heartbeats.load(Ordering::Relaxed),
        sent.autopilot_heartbeats.load(Ordering::Relaxed),
        sent.inputs.load(Ordering::Relaxed),
    );
    eprintln!(
        "sent {hb} HEARTBEATs ({fc_hb} of a flight controller), {inputs} inputs; counters: \
               foreign {} (heartbeats {}, flight controllers {}, inputs {}); refused: {}",
        c.rx_foreign,
        c.rx_foreign_heartbeats,
        c.rx_foreign_autopilots,
        c.rx_foreign_input,
        c.rejections()
    );
    assert!(hb >= 57 && inputs >= 1_900, "{hb} {inputs}");
    assert!(c.rx_foreign_heartbeats as f64 >= 0.95 * hb as f64);
    assert!(c.rx_foreign_autopilots as f64 >= 0.95 * fc_hb as f64);
    assert!(c.rx_foreign_input as f64 >= 0.95 * inputs as f64);
    assert!(c.rejections().contains("foreign="));
    assert!(
        c.input.imu <= imu_sent,
        "{} IMU samples decoded, the autopilot sent {imu_sent}",
        c.input.imu
    );
    assert_eq!((c.autopilot_reboots, c.autopilot_time_jumps), (0, 0));
    assert_eq!(c.timesync.clock_outliers, 0);
    // Still flying north at 30 m/s, level: the intruders' turning IMU never reached the INS.
    let Some(apm::MavMessage::ODOMETRY(o)) =
        fake.received(is_odometry).last().map(|r| r.msg.clone())
    else {
        unreachable!()
    };
    assert!(
        (o.vx - 30.0).abs() < 1.0 && o.vy.abs() < 1.0,
        "{} {}",
        o.vx,
        o.vy
    );
    // q = (w, x, y, z): |z| = |sin(yaw/2)| < 0.02 is within 2.3° of north.
    assert!(o.q[3].abs() < 0.02, "{:?}", o.q);
}

/// Link-robustness acceptance: every input message of the autopilot with its fields at their
/// extremes, in the `ci` profile (overflow checks on): no panic, the IMU is still read at its rate,
/// the values are refused and counted, no reboot or jump is taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn extreme_field_values_of_every_input_message_are_refused_and_counted_and_the_imu_is_still_read()
 {
    let port = fa::free_udp_port();
    let (h, task) = start(config(port, "")).await;
    let fake = Fake::start(port).await;
    publishing(&fake).await;
    let mag = MagneticModel::new(2026.5).unwrap();
    let n = nominal_now(&fake, &mag, 0)
        .iter()
        .map(|m| extreme_variants(m).len())
        .sum::<usize>();
    let c0 = h.shared.counters();
    let t0 = Instant::now();
    for i in 0..n {
        // Regenerated for each message: nominal stamps are the autopilot's time now.
        let v: Vec<(String, apm::MavMessage)> = nominal_now(&fake, &mag, 0)
            .iter()
            .flat_map(extreme_variants)
            .collect();
        fake.send(&v[i].1).await;
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let burst = t0.elapsed();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let t1 = Instant::now();
    let c1 = h.shared.counters();
    let after = Instant::now();
    assert!(
        wait_for(Duration::from_secs(8), || odometry_between(
            &fake,
            after,
            Instant::now()
        )
        .len()
            > 30)
        .await,
        "publishing after the extremes"
    );
    let c = stop(h, task).await;
    let imu_hz = (c1.input.imu - c0.input.imu) as f64 / (t1 - t0).as_secs_f64();
    eprintln!(
        "{n} messages in {burst:?}; IMU decoded at {imu_hz:.0} Hz meanwhile; refused: {}",
        c1.rejections()
    );
    assert!(
        imu_hz >= 90.0,
        "the reader went deaf: IMU at {imu_hz:.0} Hz"
    );
    let ins0 = c0.ins.unwrap().imu.accepted;
    assert!(
        c1.ins.unwrap().imu.accepted > ins0 + 200,
        "the INS keeps running"
    );
    for (kind, before, now) in [
        ("non_finite", c0.input.non_finite, c1.input.non_finite),
        ("out_of_range", c0.input.out_of_range, c1.input.out_of_range),
        ("no_fix", c0.input.no_fix, c1.input.no_fix),
        (
            "unscaled_raw_imu",
            c0.input.unscaled_raw_imu,
            c1.input.unscaled_raw_imu,
        ),
        (
            "clock_outliers",
            c0.timesync.clock_outliers,
            c1.timesync.clock_outliers,
        ),
        (
            "implausible",
            c0.timesync.implausible,
            c1.timesync.implausible,
        ),
    ] {
        assert!(now > before, "{kind} not counted: {before} → {now}");
    }
    assert_eq!(
        (
            c.autopilot_reboots,
            c.autopilot_time_jumps,
            c.autopilot_changes
        ),
        (0, 0, 0)
    );
    assert!(
        texts_with(&fake, &["reboot", "jump"]).is_empty(),
        "{:?}",
        fake.statustexts()
    );
}

/// Link-robustness acceptance: one IMU sample stamped an hour ahead, on either time base: refused
/// and counted; no reboot or jump announced or acted on (no interval requests, no IMU refused after
/// it, no IMU gap in the INS); ODOMETRY flows on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lone_imu_sample_stamped_an_hour_ahead_is_refused_not_taken_for_a_reboot() {
    for clock in ["daemon", "autopilot"] {
        let port = fa::free_udp_port();
        let (h, task) = start(config(port, &format!("clock = \"{clock}\""))).await;
        let fake = Fake::start(port).await;
        publishing(&fake).await;
        // Intervals negotiated, TIMESYNC converged.
        tokio::time::sleep(Duration::from_secs(2)).await;
        let mag = MagneticModel::new(2026.5).unwrap();
        let c0 = h.shared.counters();
        let t0 = Instant::now();
        let future = nominal_now(&fake, &mag, 3_600_000_000).swap_remove(0);
        assert!(matches!(future, apm::MavMessage::HIGHRES_IMU(_)));
        fake.send(&future).await;
        tokio::time::sleep(Duration::from_secs(3)).await;
        let t1 = Instant::now();
        let c = stop(h, task).await;
        let odo = odometry_between(&fake, t0, t1);
        let gap = longest_gap(&odo, t0, t1);
        eprintln!(
            "{clock} clock: {} ODOMETRY in {:?}, longest gap {gap:?}; refused: {}",
            odo.len(),
            t1 - t0,
            c.rejections()
        );
        assert_eq!(
            c.timesync.clock_outliers - c0.timesync.clock_outliers,
            1,
            "{clock}"
        );
        assert_eq!(
            (c.autopilot_reboots, c.autopilot_time_jumps),
            (0, 0),
            "{clock}"
        );
        assert_eq!((c.timesync.reboots, c.timesync.jumps), (0, 0), "{clock}");
        assert_eq!(
            c.interval_requests, c0.interval_requests,
            "{clock}: streams re-requested"
        );
        assert_eq!(
            c.time_order_rejected, c0.time_order_rejected,
            "{clock}: IMU refused after the outlier"
        );
        assert_eq!(c.ins.unwrap().imu_gaps, c0.ins.unwrap().imu_gaps, "{clock}");
        assert!(
            texts_with(&fake, &["reboot", "jump"]).is_empty(),
            "{:?}",
            fake.statustexts()
        );
        assert!(
            gap <= Duration::from_millis(200),
            "{clock}: ODOMETRY gap of {gap:?}"
        );
        let expected = ODOMETRY_HZ * (t1 - t0).as_secs_f64();
        assert!(
            odo.len() as f64 >= 0.95 * expected,
            "{clock}: {} of {expected:.0}",
            odo.len()
        );
    }
}

/// The reader's path without the link: clock check, then decoding with the mapped time.
#[derive(Clone)]
struct Pipeline {
    ts: TimeSync,
    dec: InputDecoder,
    rx_us: u64,
    /// Clock stamps held (refused) so far.
    held: u64,
    mag: Vector3<f64>,
}

/// Our clock minus the autopilot's, µs.
const OFFSET_US: u64 = 5_000_000;
/// Index of each message in `nominal_inputs`.
const HIGHRES: usize = 0;
const SCALED_PRESSURE: usize = 3;
const GPS_RAW_INT: usize = 10;
/// Input message types.
const TYPES: usize = 12;

impl Pipeline {
    /// Decoding at our 20 s, with the autopilot's clock established (ATTITUDE at 50 Hz), an
    /// airspeed and a vertical speed known.
    fn new(raw_imu_is_scaled: bool) -> Self {
        let mut p = Self {
            ts: TimeSync::new(10_000_000),
            dec: InputDecoder::new(DecoderConfig {
                temperature: TemperatureSource::Sensor,
                isa_delta_t_k: 0.0,
                raw_imu_is_scaled,
                default_sigma: (3.0, 5.0, 0.5),
                aoa_ssa_is_vanes: true,
                gnss_lag_us: 0,
                mag_from: ianav::io::mavlink_in::MagFrom::ImuMessage,
            }),
            rx_us: 20_000_000,
            held: 0,
            mag: Vector3::new(22_000.0, 1_000.0, 42_000.0),
        };
        for _ in 0..10 {
            p.feed(&p.nominal(8));
            p.rx_us += 20_000;
        }
        p.feed(&p.nominal(6));
        p.feed(&p.nominal(9));
        p
    }

    fn nominal(&self, i: usize) -> apm::MavMessage {
        nominal_inputs(self.rx_us - OFFSET_US, 450_000_000, 70_000_000, self.mag).swap_remove(i)
    }

    /// Receive `msg` 1 ms after it was stamped.
    fn feed(&mut self, msg: &apm::MavMessage) -> Vec<SensorEvent> {
        self.rx_us += 1_000;
        let rx = self.rx_us;
        if let Some(ap_us) = clock_stamp_us(msg)
            && self.ts.observe_clock(ap_us, rx) == ClockStamp::Held
        {
            self.held += 1;
            return Vec::new();
        }
        let ts = &mut self.ts;
        self.dec.decode(msg, &mut |t| ts.map(t, rx))
    }

    /// Messages refused or ignored so far, every kind.
    fn refusals(&self) -> u64 {
        let d = self.dec.counters();
        let t = self.ts.counters();
        d.rejected()
            + d.imu_lower_priority
            + d.aoa_ssa_ignored
            + d.second_baro_ignored
            + t.implausible
            + self.held
    }

    /// The IMU is still read and the air data and GNSS still decode to valid events.
    fn probe(&mut self, after: &str) {
        let imu = self.feed(&self.nominal(HIGHRES));
        assert!(
            imu.iter().any(|e| matches!(e, SensorEvent::Imu(_))),
            "IMU no longer read after {after}: {imu:?}"
        );
        for i in [SCALED_PRESSURE, GPS_RAW_INT] {
            for e in imu.iter().chain(&self.feed(&self.nominal(i))) {
                if let Err(e) = check_event(e) {
                    panic!("after {after}: {e}");
                }
            }
        }
    }
}

/// Every input message with each field, then all fields, at each extreme: the events that
/// come out are valid, a message giving fewer events than its nominal counts a refusal, and
/// the IMU, air data and GNSS are read normally after it.
#[test]
fn every_input_message_with_extreme_fields_decodes_to_valid_events_or_is_refused_and_counted() {
    let mut n = 0;
    for scaled in [false, true] {
        let p0 = Pipeline::new(scaled);
        for ti in 0..TYPES {
            let nominal = p0.nominal(ti);
            let nominal_events = p0.clone().feed(&nominal).len();
            for (name, msg) in extreme_variants(&nominal) {
                let mut p = p0.clone();
                let before = p.refusals();
                let ev = p.feed(&msg);
                for e in &ev {
                    if let Err(e) = check_event(e) {
                        panic!("{name}: {e}");
                    }
                }
                if ev.len() < nominal_events {
                    assert!(p.refusals() > before, "{name}: {ev:?} and nothing counted");
                }
                p.probe(&name);
                n += 1;
            }
        }
    }
    eprintln!("{n} extreme messages decoded");
    assert!(n > 600);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1_000, ..ProptestConfig::default() })]

    /// Up to four input messages with fields kept, at an extreme or any bit pattern: every
    /// event out is valid and the IMU is read normally afterwards (four: fewer than the five
    /// consistent stamps that would rightly be taken for a reboot).
    #[test]
    fn decoded_events_are_valid_whatever_the_fields(
        scaled in any::<bool>(),
        msgs in prop::collection::vec(
            (0..TYPES, prop::collection::vec((any::<u8>(), any::<u64>()), 16)),
            1..=4,
        ),
    ) {
        let mut p = Pipeline::new(scaled);
        for (ti, seeds) in &msgs {
            let msg = seeded_variant(&p.nominal(*ti), seeds);
            for e in p.feed(&msg) {
                prop_assert!(check_event(&e).is_ok(), "{msg:?} gave {e:?}");
            }
        }
        p.probe("random fields");
    }
}

/// The link-restored STATUSTEXT gives the outage from the last message before it to the first
/// after, not from the moment the loss was noticed (a link timeout later).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_restored_reports_the_length_of_the_silence() {
    let port = fa::free_udp_port();
    let (h, task) = start(config(port, "")).await;
    let fake = Fake::start(port).await;
    publishing(&fake).await;
    fake.ctl.lock().unwrap().silent = true;
    let t = Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    fake.ctl.lock().unwrap().silent = false;
    let silence = t.elapsed().as_secs_f64();
    let restored = || {
        fake.statustexts().iter().find_map(|t| {
            t.strip_prefix("ianav: link restored (")?
                .strip_suffix(" s)")?
                .parse::<f64>()
                .ok()
        })
    };
    let told = Mutex::new(None);
    assert!(
        wait_for(Duration::from_secs(3), || {
            *told.lock().unwrap() = restored();
            told.lock().unwrap().is_some()
        })
        .await,
        "{:?}",
        fake.statustexts()
    );
    let c = stop(h, task).await;
    let told = told.into_inner().unwrap().unwrap();
    // The 1 s link timeout is not subtracted; the fake's 10 ms ticks and the 0.1 s rounding
    // bound the difference.
    assert!(
        (told - silence).abs() <= 0.2,
        "told {told} s for {silence:.2} s"
    );
    assert_eq!(c.link_losses, 1);
}
