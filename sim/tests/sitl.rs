//! `ianav-sim sitl` against a minimal MAVLink client on loopback: rates, interval requests,
//! TIMESYNC, unit conversions against the simulator's own samples, GNSS loss, companion estimates
//! versus truth, flying on them, and the camera frame stream. Every run is a few simulated seconds
//! (short warm-up) so the file stays well under a minute.
#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use ianav::math::map_projection::MapProjection;
use ianav::math::wgs84::{self, Geodetic};
use ianav::sensors::SensorEvent;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup};
use ianav_sim::sitl::{self, Autopilot, FramesListen, SitlOptions, SitlSummary, VehicleConfig};
use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncConnectable, AsyncMavConnection, MavHeader, MessageData};
use tokio::sync::mpsc;
use tokio::time::Instant;

type Conn = mavlink::AsyncConnection<apm::MavMessage>;
type Rx = mpsc::UnboundedReceiver<(Instant, MavHeader, apm::MavMessage)>;

const SEED: u64 = 7;
const CLIENT: MavHeader = MavHeader {
    system_id: 1,
    component_id: 197,
    sequence: 0,
};

/// The vehicle of `autopilot` that keeps flying on its own navigation after GNSS loss (these
/// tests have no companion whose position it could fly on).
fn own_navigation(autopilot: Autopilot) -> VehicleConfig {
    VehicleConfig {
        fly_on_estimates: false,
        ..VehicleConfig::for_autopilot(autopilot)
    }
}

fn short_setup(warmup_s: f64, loss_s: f64, duration_s: f64) -> FlightSetup {
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.scenario.warmup_s = warmup_s;
    setup.scenario.gnss_loss_s = loss_s;
    setup.scenario.duration_s = duration_s;
    setup
}

/// A udpin client on an ephemeral loopback port, and a task forwarding what it receives.
async fn client() -> (Arc<Conn>, u16, Rx) {
    let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = sock.local_addr().unwrap().port();
    let cfg = mavlink::UdpConfig::from_socket(sock, mavlink::UdpMode::Udpin).unwrap();
    let conn = Arc::new(cfg.connect_async::<apm::MavMessage>().await.unwrap());
    let (tx, rx) = mpsc::unbounded_channel();
    let reader = Arc::clone(&conn);
    tokio::spawn(async move {
        while let Ok((h, m)) = reader.recv().await {
            if tx.send((Instant::now(), h, m)).is_err() {
                break;
            }
        }
    });
    (conn, port, rx)
}

fn start(
    setup: &FlightSetup,
    port: u16,
    autopilot: Autopilot,
    speed: f64,
    frames: Option<FramesListen>,
    out_dir: Option<std::path::PathBuf>,
) -> tokio::task::JoinHandle<SitlSummary> {
    let setup = setup.clone();
    let options = SitlOptions {
        connect: format!("udpout:127.0.0.1:{port}"),
        vehicle: VehicleConfig {
            autopilot,
            ..VehicleConfig::for_autopilot(autopilot)
        },
        speed,
        frames,
        out_dir,
    };
    tokio::spawn(async move { sitl::run(&setup, SEED, options, |_, _| {}).await.unwrap() })
}

/// Receive until the SITL run ends, letting `on` react (and send) to each message.
async fn pump(
    rx: &mut Rx,
    run: &mut tokio::task::JoinHandle<SitlSummary>,
    mut on: impl AsyncFnMut(Instant, &MavHeader, &apm::MavMessage),
) -> SitlSummary {
    let deadline = Instant::now() + Duration::from_secs(40);
    loop {
        tokio::select! {
            m = rx.recv() => {
                if let Some((t, h, m)) = m { on(t, &h, &m).await; }
            }
            done = &mut *run => {
                // Let the last datagrams arrive.
                while let Ok(Some((t, h, m))) = tokio::time::timeout(Duration::from_millis(100), rx.recv()).await {
                    on(t, &h, &m).await;
                }
                return done.unwrap();
            }
        }
        assert!(Instant::now() < deadline, "the SITL run did not end");
    }
}

/// The same flight, offline: sensor samples and truth at every sensor instant.
#[derive(Default)]
struct Twin {
    events: Vec<SensorEvent>,
}
impl FlightObserver for Twin {
    fn sensor_event(&mut self, e: &SensorEvent) {
        self.events.push(e.clone());
    }
}

struct TwinFlight {
    imu: BTreeMap<u64, ianav::sensors::ImuSample>,
    air: BTreeMap<u64, ianav::sensors::AirSample>,
    mag: BTreeMap<u64, ianav::sensors::MagSample>,
    gnss: BTreeMap<u64, ianav::sensors::GnssFix>,
    truth: BTreeMap<u64, Geodetic>,
    loss_us: u64,
}

fn twin(setup: &FlightSetup) -> TwinFlight {
    let mut flight = Flight::new(setup, SEED).unwrap();
    let mut obs = Twin::default();
    let mut tw = TwinFlight {
        imu: BTreeMap::new(),
        air: BTreeMap::new(),
        mag: BTreeMap::new(),
        gnss: BTreeMap::new(),
        truth: BTreeMap::new(),
        loss_us: flight.gnss_loss_t_us(),
    };
    while !flight.finished() {
        flight.step(&mut obs).unwrap();
        if flight.t_us().is_multiple_of(10_000) {
            tw.truth.insert(flight.t_us(), flight.truth().pos);
        }
    }
    for e in obs.events {
        match e {
            SensorEvent::Imu(s) => drop(tw.imu.insert(s.t_us, s)),
            SensorEvent::Air(s) => drop(tw.air.insert(s.t_us, s)),
            SensorEvent::Mag(s) => drop(tw.mag.insert(s.t_us, s)),
            SensorEvent::Gnss(s) => drop(tw.gnss.insert(s.t_us, s)),
            SensorEvent::Frame(_)
            | SensorEvent::RefAttitude(_)
            | SensorEvent::Alignment(_)
            | SensorEvent::HeightAboveTerrain(_)
            | SensorEvent::VisionApplied(_) => {}
        }
    }
    tw
}

fn set_interval(id: u32, interval_us: f32) -> apm::MavMessage {
    apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
        param1: id as f32,
        param2: interval_us,
        command: apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        target_system: 1,
        target_component: 1,
        ..Default::default()
    })
}

fn close(a: f32, b: f64, tol: f64) -> bool {
    (f64::from(a) - b).abs() <= tol * b.abs().max(1.0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ideal_vehicle_streams_converts_answers_and_loses_gnss() {
    let setup = short_setup(2.0, 4.0, 10.0);
    let tw = twin(&setup);
    let (conn, port, mut rx) = client().await;
    let speed = 10.0;
    let mut run = start(&setup, port, Autopilot::Ideal, speed, None, None);
    let mut heartbeats = Vec::new();
    let mut imu: Vec<(Instant, apm::HIGHRES_IMU_DATA)> = Vec::new();
    let mut gps = Vec::new();
    let mut timesync_sent: Option<u64> = None;
    let mut timesync_reply = None;
    let mut interval_sent_at: Option<u64> = None;
    let mut acks = Vec::new();
    let mut order: Vec<(u32, u64)> = Vec::new();
    let summary = pump(&mut rx, &mut run, async |t, h, m| match m {
        apm::MavMessage::AOA_SSA(d) => order.push((apm::AOA_SSA_DATA::ID, d.time_usec)),
        apm::MavMessage::HEARTBEAT(hb) => {
            heartbeats.push((*h, hb.clone()));
            if timesync_sent.is_none() {
                let last_imu = imu.last().map_or(0, |(_, m)| m.time_usec);
                timesync_sent = Some(last_imu);
                let req = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                    tc1: 0,
                    ts1: 777,
                    target_system: 1,
                    target_component: 1,
                });
                conn.send(&CLIENT, &req).await.unwrap();
            }
        }
        apm::MavMessage::HIGHRES_IMU(d) => {
            order.push((apm::HIGHRES_IMU_DATA::ID, d.time_usec));
            imu.push((t, d.clone()));
            if d.time_usec >= 6_000_000 && interval_sent_at.is_none() {
                interval_sent_at = Some(d.time_usec);
                let cmd = set_interval(apm::HIGHRES_IMU_DATA::ID, 40_000.0);
                conn.send(&CLIENT, &cmd).await.unwrap();
            }
        }
        apm::MavMessage::TIMESYNC(d) if d.tc1 != 0 => {
            let last_imu = imu.last().map_or(0, |(_, m)| m.time_usec);
            timesync_reply = Some((*h, d.clone(), last_imu));
        }
        apm::MavMessage::COMMAND_ACK(a) => {
            let last_imu = imu.last().map_or(0, |(_, m)| m.time_usec);
            acks.push((a.clone(), last_imu));
        }
        apm::MavMessage::GPS_RAW_INT(g) => {
            order.push((apm::GPS_RAW_INT_DATA::ID, g.time_usec));
            gps.push(g.clone());
        }
        _ => {}
    })
    .await;
    assert!(
        summary.send_dropped == 0 && summary.send_errors == 0,
        "{summary:?}"
    );

    // HEARTBEAT: a PX4 fixed-wing autopilot, 1 Hz of vehicle time.
    let (h, hb) = heartbeats[0].clone();
    assert_eq!((h.system_id, h.component_id), (1, 1));
    assert_eq!(hb.autopilot, apm::MavAutopilot::MAV_AUTOPILOT_PX4);
    assert_eq!(hb.mavtype, apm::MavType::MAV_TYPE_FIXED_WING);
    assert!(
        (11..=13).contains(&heartbeats.len()),
        "{}",
        heartbeats.len()
    );

    // HIGHRES_IMU at 100 Hz of vehicle time, every sample, and 100 × speed per wall second.
    let before: Vec<_> = imu
        .iter()
        .filter(|(_, d)| d.time_usec <= 6_000_000)
        .collect();
    for w in before.windows(2) {
        assert_eq!(w[1].1.time_usec - w[0].1.time_usec, 10_000);
    }
    let window: Vec<_> = before
        .iter()
        .filter(|(_, d)| d.time_usec >= 1_000_000)
        .collect();
    let (first, last) = (window[0], window[window.len() - 1]);
    let wall_rate = (window.len() - 1) as f64 / (last.0 - first.0).as_secs_f64();
    let expected = 100.0 * speed;
    assert!(
        (wall_rate / expected - 1.0).abs() < 0.1,
        "HIGHRES_IMU at {wall_rate:.0} /s wall, expected {expected:.0}"
    );

    // Within an instant, aiding data (vanes, GNSS) arrive before the IMU sample, the order
    // in which the simulator's INS fuses them.
    let imu_index: BTreeMap<u64, usize> = order
        .iter()
        .enumerate()
        .filter(|(_, (id, _))| *id == apm::HIGHRES_IMU_DATA::ID)
        .map(|(i, &(_, t))| (t, i))
        .collect();
    let mut checked = 0;
    for (i, &(id, t)) in order.iter().enumerate() {
        if id != apm::HIGHRES_IMU_DATA::ID
            && let Some(&j) = imu_index.get(&t)
        {
            assert!(i < j, "message {id} at {t} µs after its IMU sample");
            checked += 1;
        }
    }
    assert!(checked > 500, "{checked}");

    // SET_MESSAGE_INTERVAL: acknowledged ACCEPTED, then 25 Hz (40 ms) from shortly after.
    let (ack, acked_at_us) = acks
        .iter()
        .find(|(a, _)| a.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL)
        .cloned()
        .unwrap();
    assert_eq!(ack.result, apm::MavResult::MAV_RESULT_ACCEPTED);
    assert_eq!((ack.target_system, ack.target_component), (1, 197));
    let after: Vec<_> = imu
        .iter()
        .filter(|(_, d)| d.time_usec > acked_at_us + 20_000)
        .collect();
    assert!(after.len() > 50, "{}", after.len());
    for w in after.windows(2) {
        assert_eq!(w[1].1.time_usec - w[0].1.time_usec, 40_000);
    }

    // TIMESYNC: ts1 echoed, tc1 the vehicle's clock in ns at the time of the reply.
    let (h, ts, imu_at_reply) = timesync_reply.clone().unwrap();
    assert_eq!((h.system_id, h.component_id), (1, 1));
    assert_eq!(ts.ts1, 777);
    assert_eq!((ts.target_system, ts.target_component), (1, 197));
    let tc1_us = (ts.tc1 / 1000) as u64;
    let sent_at = timesync_sent.unwrap();
    assert!(
        sent_at <= tc1_us && tc1_us <= imu_at_reply + 10_000,
        "tc1 {tc1_us} µs outside [{sent_at}, {imu_at_reply}]"
    );

    // Values decode back to the simulator's samples (f32 precision at 100 Hz).
    const G_PER_NT: f64 = 1e-5;
    for (_, d) in &before {
        let s = &tw.imu[&d.time_usec];
        let (air, mag) = (&tw.air[&d.time_usec], &tw.mag[&d.time_usec]);
        assert!(close(d.xacc, s.accel_mps2.x, 1e-6) && close(d.zacc, s.accel_mps2.z, 1e-6));
        assert!(close(d.ygyro, s.gyro_rps.y, 1e-6) && close(d.zgyro, s.gyro_rps.z, 1e-6));
        assert!(close(d.xmag, mag.mag_b_nt.x * G_PER_NT, 1e-6));
        assert!(close(d.abs_pressure, air.p_pa / 100.0, 1e-6));
        assert!(close(d.temperature, air.temp_k - 273.15, 1e-5));
        let tas = sitl::convert::tas_from_impact_pressure_mps(
            f64::from(d.diff_pressure) * 100.0,
            f64::from(d.abs_pressure) * 100.0,
            f64::from(d.temperature) + 273.15,
        );
        assert!((tas - air.tas_mps).abs() < 2e-3, "{tas} vs {}", air.tas_mps);
        assert_eq!(d.fields_updated.bits(), 0x1FFF);
    }

    // GPS_RAW_INT: 1 Hz; fixes up to the loss decode within half a quantum; then NO_FIX.
    let valid: Vec<_> = gps
        .iter()
        .filter(|g| g.fix_type == apm::GpsFixType::GPS_FIX_TYPE_3D_FIX)
        .collect();
    assert!(valid.len() >= 4, "{}", valid.len());
    for g in &valid {
        assert!(g.time_usec <= tw.loss_us);
        let fix = &tw.gnss[&g.time_usec];
        assert!((f64::from(g.lat) - fix.pos.lat_rad.to_degrees() * 1e7).abs() <= 0.5);
        assert!((f64::from(g.lon) - fix.pos.lon_rad.to_degrees() * 1e7).abs() <= 0.5);
        assert!((f64::from(g.alt) - fix.pos.h_m * 1e3).abs() <= 0.5);
        assert_eq!(g.alt, g.alt_ellipsoid);
        let speed_cms = fix.v_ned_mps.x.hypot(fix.v_ned_mps.y) * 100.0;
        assert!((f64::from(g.vel) - speed_cms).abs() <= 0.5);
        assert!((f64::from(g.h_acc) - fix.sigma_hor_m * 1e3).abs() <= 0.5);
    }
    let invalid: Vec<_> = gps
        .iter()
        .filter(|g| g.fix_type == apm::GpsFixType::GPS_FIX_TYPE_NO_FIX)
        .collect();
    assert!(!invalid.is_empty());
    assert!(invalid.iter().all(|g| g.time_usec > tw.loss_us));
    assert_eq!(invalid[0].time_usec, tw.loss_us + 1_000_000);
    assert_eq!(valid.last().unwrap().time_usec, tw.loss_us);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ardupilot_vehicle_denies_intervals_under_25_ms_and_streams_40_hz() {
    let setup = short_setup(2.0, 100.0, 6.0);
    let (conn, port, mut rx) = client().await;
    let speed = 10.0;
    let mut run = start(&setup, port, Autopilot::ArduPilot, speed, None, None);
    let mut heartbeat = None;
    let mut by_id: BTreeMap<u32, usize> = BTreeMap::new();
    let mut raw_t_us = Vec::new();
    let mut scaled: Vec<(Instant, apm::SCALED_IMU_DATA)> = Vec::new();
    let mut acks = Vec::new();
    let mut texts: Vec<apm::STATUSTEXT_DATA> = Vec::new();
    let mut asked_at_us = None;
    pump(&mut rx, &mut run, async |t, _, m| {
        *by_id.entry(mavlink::Message::message_id(m)).or_default() += 1;
        match m {
            apm::MavMessage::HEARTBEAT(hb) => heartbeat = Some(hb.clone()),
            apm::MavMessage::RAW_IMU(d) => {
                raw_t_us.push(d.time_usec);
                if d.time_usec >= 3_000_000 && asked_at_us.is_none() {
                    asked_at_us = Some(d.time_usec);
                    for (id, us) in [
                        // 50 Hz: faster than 80 % of the 50 Hz loop.
                        (apm::SCALED_IMU_DATA::ID, 20_000.0),
                        // 40 Hz: the fastest it accepts.
                        (apm::SCALED_IMU_DATA::ID, 25_000.0),
                        // Not in a default ArduPlane build.
                        (apm::HIGHRES_IMU_DATA::ID, 100_000.0),
                    ] {
                        conn.send(&CLIENT, &set_interval(id, us)).await.unwrap();
                    }
                }
            }
            apm::MavMessage::SCALED_IMU(d) => scaled.push((t, d.clone())),
            apm::MavMessage::COMMAND_ACK(a) => acks.push(a.clone()),
            apm::MavMessage::STATUSTEXT(s) => texts.push(s.clone()),
            _ => {}
        }
    })
    .await;
    let hb = heartbeat.unwrap();
    assert_eq!(hb.autopilot, apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA);
    assert_eq!(hb.custom_mode, 10, "ArduPlane AUTO");

    // Unrequested streams run at the stream groups' 1 Hz: RAW_IMU on whole seconds.
    assert!(raw_t_us.len() >= 7, "{raw_t_us:?}");
    for w in raw_t_us.windows(2) {
        assert_eq!(w[1] - w[0], 1_000_000);
    }
    for id in [
        apm::AIRSPEED_DATA::ID,
        apm::SCALED_PRESSURE_DATA::ID,
        apm::SCALED_PRESSURE2_DATA::ID,
        apm::VFR_HUD_DATA::ID,
        apm::ATTITUDE_DATA::ID,
    ] {
        let n = by_id.get(&id).copied().unwrap_or(0);
        assert!((7..=9).contains(&n), "message {id}: {n} in 8 s");
    }
    assert_eq!(by_id.get(&apm::HIGHRES_IMU_DATA::ID), None);

    // 20 ms: DENIED plus ArduPilot's text; 25 ms: ACCEPTED; HIGHRES_IMU: DENIED.
    let results: Vec<_> = acks.iter().map(|a| (a.command, a.result)).collect();
    let cmd = apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL;
    assert_eq!(
        results,
        [
            (cmd, apm::MavResult::MAV_RESULT_DENIED),
            (cmd, apm::MavResult::MAV_RESULT_ACCEPTED),
            (cmd, apm::MavResult::MAV_RESULT_DENIED),
        ]
    );
    assert!(
        acks.iter()
            .all(|a| (a.target_system, a.target_component) == (1, 197))
    );
    // Long texts come in 50-byte chunks sharing a non-zero id.
    let mut joined: BTreeMap<u16, Vec<(u8, String)>> = BTreeMap::new();
    for s in &texts {
        assert_eq!(s.severity, apm::MavSeverity::MAV_SEVERITY_INFO);
        let bytes: Vec<u8> = s.text.iter().copied().take_while(|&b| b != 0).collect();
        joined
            .entry(s.id)
            .or_default()
            .push((s.chunk_seq, String::from_utf8(bytes).unwrap()));
    }
    let texts: Vec<String> = joined
        .into_iter()
        .flat_map(|(id, mut chunks)| {
            chunks.sort();
            if id == 0 {
                chunks.into_iter().map(|(_, c)| c).collect::<Vec<_>>()
            } else {
                vec![chunks.into_iter().map(|(_, c)| c).collect::<String>()]
            }
        })
        .collect();
    assert!(
        texts.contains(
            &"Requested rate for message ID 26 too fast. Increase SCHED_LOOP_RATE".to_owned()
        ),
        "{texts:?}"
    );
    assert!(
        texts.contains(&"No ap_message for mavlink id (105)".to_owned()),
        "{texts:?}"
    );

    // SCALED_IMU at 40 Hz on average from the 50 Hz loop: 20 or 40 ms apart, 4 per 100 ms.
    let asked_at_ms = asked_at_us.unwrap() / 1000;
    assert!(
        scaled
            .iter()
            .all(|(_, d)| u64::from(d.time_boot_ms) > asked_at_ms)
    );
    assert!(scaled.len() > 100, "{}", scaled.len());
    for w in scaled.windows(2) {
        let dt = w[1].1.time_boot_ms - w[0].1.time_boot_ms;
        assert!(dt == 20 || dt == 40, "{dt} ms");
    }
    let (first, last) = (&scaled[0], &scaled[scaled.len() - 1]);
    let span_ms = f64::from(last.1.time_boot_ms - first.1.time_boot_ms);
    let rate_hz = (scaled.len() - 1) as f64 / span_ms * 1e3;
    // One message more or less than 4 per 100 ms over the span.
    assert!((rate_hz - 40.0).abs() <= 1e3 / span_ms, "{rate_hz} Hz");
    let wall_rate = (scaled.len() - 1) as f64 / (last.0 - first.0).as_secs_f64();
    assert!(
        (wall_rate / (40.0 * speed) - 1.0).abs() < 0.1,
        "{wall_rate} /s"
    );
}

/// Drive a [`sitl::Vehicle`] without a network, one 10 ms sensor instant at a time, and
/// collect what it queues with the instant it was queued at.
fn drive(
    setup: &FlightSetup,
    cfg: VehicleConfig,
    requests: &[(u32, f32)],
    mut each_tick: impl FnMut(&sitl::Vehicle),
) -> Vec<(u64, apm::MavMessage)> {
    let mut v = sitl::Vehicle::new(setup, SEED, cfg).unwrap();
    for &(id, us) in requests {
        v.handle(&CLIENT, &set_interval(id, us));
    }
    let mut out: Vec<(u64, apm::MavMessage)> =
        v.take_outbox().into_iter().map(|m| (0, m)).collect();
    while !v.finished() {
        let t = v.t_us() + 10_000;
        v.advance_to(t).unwrap();
        each_tick(&v);
        out.extend(v.take_outbox().into_iter().map(|m| (v.t_us(), m)));
    }
    out
}

#[test]
fn ardupilot_messages_carry_arduplane_semantics() {
    let setup = short_setup(2.0, 100.0, 10.0);
    let tw = twin(&setup);
    let cfg = VehicleConfig {
        gyro_drift: true,
        ..own_navigation(Autopilot::ArduPilot)
    };
    assert_eq!(cfg.gnss_lag_us, 100_000);
    // Per instant: the angles derived from the vehicle's estimate and the true ones, deg.
    let mut from_estimate: BTreeMap<u64, (f64, f64)> = BTreeMap::new();
    let mut truth_angles: BTreeMap<u64, (f64, f64)> = BTreeMap::new();
    let mut p_true: BTreeMap<u64, f64> = BTreeMap::new();
    let out = drive(
        &setup,
        cfg,
        &[
            (apm::SCALED_IMU_DATA::ID, 25_000.0),
            (apm::AOA_SSA_DATA::ID, 25_000.0),
            (apm::GPS_RAW_INT_DATA::ID, 200_000.0),
            (apm::SCALED_PRESSURE2_DATA::ID, 100_000.0),
            (apm::AIRSPEED_DATA::ID, 100_000.0),
        ],
        |v| {
            let t = v.t_us();
            let est = v.flight().estimate();
            from_estimate.insert(
                t,
                sitl::vehicle::aoa_ssa_from_estimate_deg(est, &v.nav_wind_ned_mps()),
            );
            let air = v.flight().truth_sample().air;
            truth_angles.insert(t, (air.aoa_rad.to_degrees(), air.aos_rad.to_degrees()));
            p_true.insert(
                t,
                ianav::env::atmosphere::pressure_pa(v.flight().truth_sample().hp_m),
            );
        },
    );
    let acks: Vec<_> = out
        .iter()
        .filter_map(|(_, m)| match m {
            apm::MavMessage::COMMAND_ACK(a) => Some(a.result),
            _ => None,
        })
        .collect();
    assert_eq!(acks, [apm::MavResult::MAV_RESULT_ACCEPTED; 5]);

    // SCALED_IMU: the latest 100 Hz sample (no averaging), gyro plus SITL's drift, each value
    // `float × 1000` truncated toward zero.
    let trunc = |x: f64| x.trunc() as i16;
    let (mut n_imu, mut rounding_differs) = (0, 0);
    for (t, m) in &out {
        let apm::MavMessage::SCALED_IMU(d) = m else {
            continue;
        };
        assert_eq!(u64::from(d.time_boot_ms) * 1000, *t);
        let s = &tw.imu[t];
        let mag = tw.mag.range(..=t).next_back().unwrap().1;
        let drift = sitl::vehicle::ardupilot_gyro_drift_rps(*t);
        let gyro_mrad = (s.gyro_rps + nalgebra::Vector3::repeat(drift)) * 1e3;
        let acc_mg = s.accel_mps2 / 9.806_65 * 1e3;
        let mag_mg = mag.mag_b_nt / 100.0;
        let got = [
            d.xgyro, d.ygyro, d.zgyro, d.xacc, d.yacc, d.zacc, d.xmag, d.ymag, d.zmag,
        ];
        let exact = [
            gyro_mrad.x,
            gyro_mrad.y,
            gyro_mrad.z,
            acc_mg.x,
            acc_mg.y,
            acc_mg.z,
            mag_mg.x,
            mag_mg.y,
            mag_mg.z,
        ];
        for (g, x) in got.iter().zip(exact) {
            assert_eq!(*g, trunc(x), "at {t} µs: {g} vs {x}");
            if x.round() != x.trunc() {
                rounding_differs += 1;
            }
        }
        n_imu += 1;
    }
    // 12 s at 40 Hz, and truncation was visible in many values.
    assert!((479..=481).contains(&n_imu), "{n_imu}");
    assert!(rounding_differs > n_imu, "{rounding_differs}");

    // AOA_SSA: ArduPlane's AHRS angles from the vehicle's own velocity and wind estimates,
    // refreshed every 60 ms (50 ms on 20 ms ticks), not a vane.
    let (mut n_aoa, mut sq_vs_truth) = (0, 0.0);
    for (t, m) in &out {
        let apm::MavMessage::AOA_SSA(d) = m else {
            continue;
        };
        assert_eq!(d.time_usec, *t);
        let matches = from_estimate
            .range(t.saturating_sub(60_000)..=*t)
            .any(|(_, &(a, b))| {
                (f64::from(d.AOA) - a).abs() < 1e-4 && (f64::from(d.SSA) - b).abs() < 1e-4
            });
        assert!(matches, "AOA_SSA at {t} µs is not the estimate's");
        let (ta, tb) = truth_angles[t];
        sq_vs_truth += (f64::from(d.AOA) - ta).powi(2) + (f64::from(d.SSA) - tb).powi(2);
        n_aoa += 1;
    }
    assert!(n_aoa > 300, "{n_aoa}");
    let rms_vs_truth_deg = (sq_vs_truth / n_aoa as f64).sqrt();
    eprintln!(
        "AOA_SSA: {n_aoa} messages, RMS difference from the true angles {rms_vs_truth_deg:.4}°"
    );
    // It differs from the true angles (turbulence, wind-estimate error: 2.2° RMS on this
    // flight) by far more than the 1e-4° match above.
    assert!(rms_vs_truth_deg > 0.2, "{rms_vs_truth_deg}");

    // GPS_RAW_INT: stamped when the autopilot received the fix (100 ms after it was taken),
    // carrying that older fix; repeated at 5 Hz until the next; no speed accuracy.
    let gps: Vec<_> = out
        .iter()
        .filter_map(|(t, m)| match m {
            apm::MavMessage::GPS_RAW_INT(g) => Some((*t, g.clone())),
            _ => None,
        })
        .collect();
    assert!(gps.len() > 40, "{}", gps.len());
    for (t, g) in &gps {
        assert!(g.time_usec <= *t);
        let fix = &tw.gnss[&(g.time_usec - 100_000)];
        assert_eq!(g.lat, sitl::convert::deg_e7(fix.pos.lat_rad));
        assert_eq!(g.lon, sitl::convert::deg_e7(fix.pos.lon_rad));
        assert_eq!(g.vel_acc, 0);
        assert!(g.h_acc > 0 && g.v_acc > 0);
        assert!(!tw.gnss.contains_key(&g.time_usec));
    }

    // SCALED_PRESSURE2: a second barometer, its own constant offset and ±0.2 m of noise
    // (±2.5 Pa at ≤ 1 km), no differential pressure.
    let mut p2_err = Vec::new();
    for (t, m) in &out {
        if let apm::MavMessage::SCALED_PRESSURE2(d) = m {
            assert_eq!(d.press_diff, 0.0);
            p2_err.push(f64::from(d.press_abs) * 100.0 - p_true[t]);
        }
    }
    assert!(p2_err.len() > 90, "{}", p2_err.len());
    let (lo, hi) = p2_err
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &e| (a.min(e), b.max(e)));
    eprintln!("SCALED_PRESSURE2 error {lo:.2}..{hi:.2} Pa");
    assert!(hi - lo <= 2.0 * 0.2 * 12.1 + 0.05, "spread {lo}..{hi} Pa");

    // AIRSPEED: calibrated airspeed, and the differential pressure in Pa.
    for (t, m) in &out {
        if let apm::MavMessage::AIRSPEED(d) = m {
            let air = tw.air.range(..=t).next_back().unwrap().1;
            let qc_pa = sitl::convert::impact_pressure_pa(air.tas_mps, air.p_pa, air.temp_k);
            assert!(
                close(d.raw_press, qc_pa, 1e-6),
                "{} vs {qc_pa}",
                d.raw_press
            );
        }
    }
}

#[test]
fn ardupilot_gyro_drift_is_sitls_triangle() {
    let drift_dps =
        |min: f64| sitl::vehicle::ardupilot_gyro_drift_rps((min * 60e6) as u64).to_degrees();
    for (min, expected_dps) in [
        (0.0, 0.0),
        (1.0, 0.05),
        (5.0, 0.25),
        (7.5, 0.125),
        (10.0, 0.0),
        (12.0, 0.1),
    ] {
        assert!(
            (drift_dps(min) - expected_dps).abs() < 1e-12,
            "{min} min: {}",
            drift_dps(min)
        );
    }
}

#[test]
fn px4_vehicle_streams_v1_16_onboard_defaults() {
    let setup = short_setup(2.0, 100.0, 2.0);
    let tw = twin(&setup);
    let cfg = own_navigation(Autopilot::Px4);
    let out = drive(
        &setup,
        cfg,
        &[
            (apm::AIRSPEED_DATA::ID, 10_000.0),
            (apm::AOA_SSA_DATA::ID, 10_000.0),
        ],
        |_| {},
    );
    let acks: Vec<_> = out
        .iter()
        .filter_map(|(_, m)| match m {
            apm::MavMessage::COMMAND_ACK(a) => Some(a.result),
            _ => None,
        })
        .collect();
    // PX4 v1.16.0 has no AIRSPEED or AOA_SSA stream.
    assert_eq!(acks, [apm::MavResult::MAV_RESULT_FAILED; 2]);
    assert!(!out.iter().any(|(_, m)| matches!(
        m,
        apm::MavMessage::AIRSPEED(_) | apm::MavMessage::AOA_SSA(_)
    )));
    // HIGHRES_IMU at 50 Hz: the mean of the two 100 Hz samples of each 20 ms; pressures in
    // Pa; `fields_updated` flags the magnetometer and air data only when new.
    let imu: Vec<_> = out
        .iter()
        .filter_map(|(_, m)| match m {
            apm::MavMessage::HIGHRES_IMU(d) => Some(d.clone()),
            _ => None,
        })
        .collect();
    // The first goes out at the first sample (10 ms), then every 20 ms.
    assert_eq!(imu[0].time_usec, 10_000);
    assert_eq!(imu.len(), 201, "4 s at 50 Hz");
    for w in imu[1..].windows(2) {
        assert_eq!(w[1].time_usec - w[0].time_usec, 20_000);
    }
    let (mut mag_new, mut air_new) = (0, 0);
    for d in imu.iter().skip(2) {
        let a = &tw.imu[&d.time_usec];
        let b = &tw.imu[&(d.time_usec - 10_000)];
        let mean = (a.gyro_rps + b.gyro_rps) / 2.0;
        assert!(close(d.xgyro, mean.x, 1e-6) && close(d.zgyro, mean.z, 1e-6));
        let air = tw.air.range(..=d.time_usec).next_back().unwrap().1;
        assert!(close(d.abs_pressure, air.p_pa, 1e-6), "{}", d.abs_pressure);
        let bits = d.fields_updated.bits();
        assert_eq!(bits & 0x3F, 0x3F);
        let mag_t = tw.mag.range(..=d.time_usec).next_back().unwrap().0;
        assert_eq!(bits & 0x1C0 != 0, *mag_t > d.time_usec - 20_000);
        mag_new += usize::from(bits & 0x1C0 != 0);
        air_new += usize::from(bits & 0x1E00 != 0);
    }
    assert!(mag_new > 0 && air_new > 0);
}

#[test]
fn stream_latency_delays_a_stream_without_changing_its_content() {
    let setup = short_setup(2.0, 100.0, 2.0);
    let mut cfg = own_navigation(Autopilot::Px4);
    let i = sitl::streams::stream_index_by_name("HIGHRES_IMU").unwrap();
    cfg.latency_us[i] = 250_000;
    let delayed = drive(&setup, cfg, &[], |_| {});
    let prompt = drive(&setup, own_navigation(Autopilot::Px4), &[], |_| {});
    let imu = |out: &[(u64, apm::MavMessage)]| -> Vec<(u64, apm::HIGHRES_IMU_DATA)> {
        out.iter()
            .filter_map(|(t, m)| match m {
                apm::MavMessage::HIGHRES_IMU(d) => Some((*t, d.clone())),
                _ => None,
            })
            .collect()
    };
    let (late, on_time) = (imu(&delayed), imu(&prompt));
    assert!(late.iter().all(|(t, d)| t - d.time_usec == 250_000));
    assert!(on_time.iter().all(|(t, d)| *t == d.time_usec));
    // Same content; those of the last 250 ms are still in flight when the mission ends.
    let end_us = delayed.last().unwrap().0;
    let deliverable = on_time
        .iter()
        .filter(|(_, d)| d.time_usec + 250_000 <= end_us)
        .count();
    assert_eq!(late.len(), deliverable);
    assert!(late.iter().zip(&on_time).all(|(a, b)| a.1 == b.1));
    // Other streams keep their timing.
    for (t, m) in &delayed {
        if let apm::MavMessage::ATTITUDE(d) = m {
            assert_eq!(u64::from(d.time_boot_ms) * 1000, *t);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn companion_odometry_is_logged_against_truth_and_flown_on_after_gnss_loss() {
    let setup = short_setup(2.0, 2.0, 8.0);
    let tw = twin(&setup);
    let dir = std::env::temp_dir().join(format!("ianav_sitl_odometry_{}", std::process::id()));
    let (conn, port, mut rx) = client().await;
    // Ideal: estimates are paced by its 100 Hz HIGHRES_IMU.
    let mut run = start(&setup, port, Autopilot::Ideal, 5.0, None, Some(dir.clone()));
    let mut origin: Option<MapProjection> = None;
    let mut sent_stamped = false;
    let mut last_sent: Option<Geodetic> = None;
    let mut gpi_vs_sent = Vec::new();
    // The client's own clock: wall time since the test started plus ~58 days, in µs.
    let epoch = std::time::Instant::now();
    let client_us = move || epoch.elapsed().as_micros() as u64 + 5_000_000_000_000;
    let mut companion_stamped: Option<(u64, u64, apm::MavMessage)> = None;
    let mut companion_sent_for: Option<u64> = None;
    let odometry = |t_us: u64, ned: [f64; 3], frame| {
        apm::MavMessage::ODOMETRY(apm::ODOMETRY_DATA {
            time_usec: t_us,
            x: ned[0] as f32,
            y: ned[1] as f32,
            z: ned[2] as f32,
            q: [1.0, 0.0, 0.0, 0.0],
            frame_id: frame,
            child_frame_id: apm::MavFrame::MAV_FRAME_BODY_FRD,
            estimator_type: apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
            quality: 100,
            ..Default::default()
        })
    };
    let summary = pump(&mut rx, &mut run, async |_, _, m| match m {
        apm::MavMessage::TIMESYNC(d) if d.tc1 == 0 => {
            let reply = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                tc1: (client_us() * 1000) as i64,
                ts1: d.ts1,
                target_system: 1,
                target_component: 1,
            });
            conn.send(&CLIENT, &reply).await.unwrap();
        }
        apm::MavMessage::GPS_GLOBAL_ORIGIN(o) => {
            origin = Some(MapProjection::new(&Geodetic {
                lat_rad: sitl::convert::rad_from_deg_e7(o.latitude),
                lon_rad: sitl::convert::rad_from_deg_e7(o.longitude),
                h_m: f64::from(o.altitude) * 1e-3,
            }));
        }
        apm::MavMessage::HIGHRES_IMU(d) => {
            let Some(proj) = origin else { return };
            let t = d.time_usec;
            let truth = tw.truth[&t];
            let ned = proj.project(&truth);
            // Stamped on the client's clock when the IMU sample of 3.0 s arrives, sent 0.3 s
            // of vehicle time later: only the TIMESYNC map recovers its time of validity.
            if t == 3_000_000 {
                let m = odometry(
                    client_us(),
                    [ned[0] + 30.0, ned[1] + 40.0, ned[2]],
                    apm::MavFrame::MAV_FRAME_LOCAL_NED,
                );
                companion_stamped = Some((t, t + 300_000, m));
            }
            if let Some((t_valid, send_at, m)) = companion_stamped.clone()
                && t >= send_at
            {
                conn.send(&CLIENT, &m).await.unwrap();
                companion_sent_for = Some(t_valid);
                companion_stamped = None;
            }
            if t >= 2_500_000 && !sent_stamped {
                // Before the loss (t < 4 s): 30 m north, 40 m east of the truth, stamped on
                // the vehicle clock; plus refused ones (bad frame, NaN) and one on a foreign clock.
                sent_stamped = true;
                let m = odometry(
                    t,
                    [ned[0] + 30.0, ned[1] + 40.0, ned[2] - 5.0],
                    apm::MavFrame::MAV_FRAME_LOCAL_NED,
                );
                conn.send(&CLIENT, &m).await.unwrap();
                let m = odometry(t, ned, apm::MavFrame::MAV_FRAME_BODY_FRD);
                conn.send(&CLIENT, &m).await.unwrap();
                let m = odometry(t, [f64::NAN, 0.0, 0.0], apm::MavFrame::MAV_FRAME_LOCAL_NED);
                conn.send(&CLIENT, &m).await.unwrap();
                let m = odometry(3_600_000_000_000, ned, apm::MavFrame::MAV_FRAME_LOCAL_NED);
                conn.send(&CLIENT, &m).await.unwrap();
                // The same instant as VISION_POSITION_ESTIMATE and GPS_INPUT, on the truth.
                let vpe =
                    apm::MavMessage::VISION_POSITION_ESTIMATE(apm::VISION_POSITION_ESTIMATE_DATA {
                        usec: t,
                        x: ned[0] as f32,
                        y: ned[1] as f32,
                        z: ned[2] as f32,
                        ..Default::default()
                    });
                conn.send(&CLIENT, &vpe).await.unwrap();
                let gps = apm::MavMessage::GPS_INPUT(apm::GPS_INPUT_DATA {
                    time_usec: t,
                    lat: sitl::convert::deg_e7(truth.lat_rad),
                    lon: sitl::convert::deg_e7(truth.lon_rad),
                    alt: truth.h_m as f32,
                    fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
                    ..Default::default()
                });
                conn.send(&CLIENT, &gps).await.unwrap();
            }
            // After the loss, from 4.5 s to 7 s: positions 200 m east of the (twin) truth at
            // 20 Hz; the vehicle must report them as its own position.
            if (4_500_000..7_000_000).contains(&t) && t.is_multiple_of(50_000) {
                let sent = [ned[0], ned[1] + 200.0, ned[2]];
                let m = odometry(t, sent, apm::MavFrame::MAV_FRAME_LOCAL_NED);
                conn.send(&CLIENT, &m).await.unwrap();
                last_sent = Some(proj.reproject(&sent));
            }
        }
        apm::MavMessage::GLOBAL_POSITION_INT(g) => {
            let t = u64::from(g.time_boot_ms) * 1000;
            if let Some(sent) = last_sent
                && (5_000_000..7_000_000).contains(&t)
            {
                let pos = Geodetic {
                    lat_rad: sitl::convert::rad_from_deg_e7(g.lat),
                    lon_rad: sitl::convert::rad_from_deg_e7(g.lon),
                    h_m: sent.h_m,
                };
                let d = wgs84::ned_difference_m(&sent, &pos);
                gpi_vs_sent.push(d.x.hypot(d.y));
            }
        }
        _ => {}
    })
    .await;
    let csv = std::fs::read_to_string(dir.join("sitl.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    // The stamped pre-loss estimate: 50 m horizontal, +5 m vertical error, on the vehicle clock.
    // The offsets are metres of the autopilots' spherical local frame, so the ellipsoidal
    // error is 50 m scaled by the local radii ratio (≈ 0.2 %): compute it exactly.
    let expected = |t_us: u64, offset: [f64; 3]| {
        let proj = origin.unwrap();
        let truth = tw.truth[&t_us];
        let ned = proj.project(&truth);
        let est = proj.reproject(&[ned[0] + offset[0], ned[1] + offset[1], ned[2] + offset[2]]);
        let d = wgs84::ned_difference_m(&truth, &est);
        d.x.hypot(d.y)
    };
    let first = &rows[0];
    assert_eq!(first[3], "stamp");
    assert_eq!(first[4], "ODOMETRY");
    let t_first: u64 = first[2].parse().unwrap();
    let hor: f64 = first[13].parse().unwrap();
    let ver: f64 = first[14].parse().unwrap();
    let want = expected(t_first, [30.0, 40.0, -5.0]);
    assert!((want - 50.0).abs() < 0.2, "{want}");
    // f32 local coordinates (0.1 mm at km range), 1 cm of degE7/mm origin quantisation.
    assert!((hor - want).abs() < 0.02, "{hor} vs {want}");
    assert!((ver - 5.0).abs() < 0.01, "{ver}");
    assert_eq!(
        rows[1][3], "arrival",
        "a stamp on no known clock falls back to arrival time"
    );
    // The companion-clock stamp maps within a few ms of vehicle time (a few cm/ms at
    // ~50 m/s); taken at arrival it would be 0.3 s (~15 m) off.
    for (row, name) in [
        (&rows[2], "VISION_POSITION_ESTIMATE"),
        (&rows[3], "GPS_INPUT"),
    ] {
        assert_eq!((row[3], row[4]), ("stamp", name));
        // On the truth: f32 metres and degE7 (≤ 0.8 cm) quantisation only.
        let hor: f64 = row[13].parse().unwrap();
        let ver: f64 = row[14].parse().unwrap();
        assert!(hor < 0.01 && ver.abs() < 0.01, "{name}: {hor} {ver}");
    }
    let t_valid = companion_sent_for.unwrap();
    let row = rows.iter().find(|r| r[3] == "timesync").unwrap();
    assert_eq!(row[3], "timesync");
    let t_mapped: u64 = row[2].parse().unwrap();
    assert!(
        t_mapped.abs_diff(t_valid) < 20_000,
        "{t_mapped} vs {t_valid}"
    );
    let hor: f64 = row[13].parse().unwrap();
    let want = expected(t_valid, [30.0, 40.0, 0.0]);
    assert!((hor - want).abs() < 1.5, "{hor} vs {want}");
    assert!(summary.vehicle.timesync_pairs >= 20, "{summary:?}");
    assert_eq!(summary.vehicle.estimates_refused, 2);
    // After the loss the estimates arrive at 20 Hz and the vehicle flies on them: the position
    // it reports is the one sent (carried by at most 50 ms of its velocity), ~200 m from its INS.
    let post: Vec<_> = rows
        .iter()
        .filter(|r| r[1].parse::<f64>().unwrap() > 2.0)
        .collect();
    assert!(post.len() >= 45, "{}", post.len());
    for r in &post {
        let e: f64 = r[13].parse().unwrap();
        let want = expected(r[2].parse().unwrap(), [0.0, 200.0, 0.0]);
        assert!((e - want).abs() < 0.02, "{e} vs {want}");
    }
    assert!(!gpi_vs_sent.is_empty());
    assert!(gpi_vs_sent.iter().all(|&d| d < 5.0), "{gpi_vs_sent:?}");
    // Aided from the first post-loss estimate (4.5 s) until 1 s after the last (~7 s).
    let aided_s = summary.vehicle.aided_ticks as f64 / 100.0;
    assert!((aided_s - 3.5).abs() < 0.15, "aided {aided_s} s");
    let rate = summary.estimate_rate_hz.unwrap();
    assert!(rate > 10.0, "{rate}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_stream_serves_late_and_reconnecting_clients_on_the_imu_clock() {
    let mut setup = short_setup(1.0, 100.0, 6.0);
    let zone: ianav_sim::terrain::Zone = "fm".parse().unwrap();
    let start_pt = zone.start();
    setup.scenario.start.lat_deg = start_pt.lat_deg;
    setup.scenario.start.lon_deg = start_pt.lon_deg;
    setup.camera = Some(ianav_sim::flight::CameraSetup::new(Arc::new(
        ianav_sim::terrain::Terrain::new(zone, 0),
    )));
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let frames_addr = listener.local_addr().unwrap();
    let (_conn, port, mut rx) = client().await;
    let mut run = start(
        &setup,
        port,
        Autopilot::Px4,
        2.0,
        Some(FramesListen::Listener(listener)),
        None,
    );
    // Frames read on a blocking thread: connect late (after ~1.5 s of vehicle time), read 3,
    // reconnect, read 3 more.
    let reader = tokio::task::spawn_blocking(move || {
        std::thread::sleep(Duration::from_millis(700));
        let mut got = Vec::new();
        for _ in 0..2 {
            let mut s = std::net::TcpStream::connect(frames_addr).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
            for _ in 0..3 {
                let (h, f) = ianav::io::frame_stream::read_frame(&mut s)
                    .unwrap()
                    .unwrap();
                got.push((std::time::Instant::now(), h, f.pixels.len()));
            }
        }
        // A third client that never reads: the socket buffers fill, then frames are dropped.
        let stalled = std::net::TcpStream::connect(frames_addr).unwrap();
        (got, stalled)
    });
    let mut imu_times = Vec::new();
    let summary = pump(&mut rx, &mut run, async |_, _, m| {
        if let apm::MavMessage::HIGHRES_IMU(d) = m {
            imu_times.push((std::time::Instant::now(), d.time_usec));
        }
    })
    .await;
    let (frames, _stalled) = reader.await.unwrap();
    assert_eq!(frames.len(), 6);
    // The stalled client cost frames, never the flight: the run reached its end.
    assert!(summary.frames_dropped > 0, "{summary:?}");
    assert!(summary.mission_s >= 6.0);
    assert!(summary.frames_without_client >= 3, "{summary:?}");
    assert!(summary.vehicle.frames >= 40);
    for (t_rx, h, n) in &frames {
        assert_eq!(*n as u32, h.width * h.height);
        // On the 10 Hz camera grid of the vehicle clock, from mission time 0 (1 s of warm-up).
        assert!(
            h.t_us.is_multiple_of(100_000) && h.t_us >= 1_000_000,
            "{}",
            h.t_us
        );
        // Lines up with the IMU clock: the IMU sample received just before the frame is at
        // most a few ticks of vehicle time away from its exposure.
        let imu_before = imu_times
            .iter()
            .rev()
            .find(|(t, _)| t <= t_rx)
            .map(|(_, u)| *u)
            .unwrap();
        assert!(
            imu_before.abs_diff(h.t_us) <= 200_000,
            "{imu_before} vs {}",
            h.t_us
        );
    }
    // Sequence numbers count produced frames: increasing within a connection.
    assert!(frames[1].1.seq > frames[0].1.seq && frames[5].1.seq > frames[4].1.seq);
    assert!(frames[3].1.seq > frames[2].1.seq);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cli_flies_a_short_sitl_run_and_writes_its_log() {
    let (_conn, port, mut rx) = client().await;
    let dir = std::env::temp_dir().join(format!("ianav_sitl_cli_{}", std::process::id()));
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_ianav-sim"))
        .args([
            "sitl",
            "--scenario",
            "2",
            "--duration",
            "1",
            "--speed",
            "0",
            "--autopilot",
            "ardupilot",
            "--gyro-drift",
            "false",
            "--gnss-lag-ms",
            "150",
            "--latency-ms",
            "20",
            "--stream-latency",
            "raw_imu=300",
        ])
        .args(["--connect", &format!("udpout:127.0.0.1:{port}")])
        .arg("--out")
        .arg(&dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut exited = tokio::task::spawn_blocking(move || child.wait_with_output());
    // The first message, or the child's failure, whichever comes first.
    let first = tokio::select! {
        m = tokio::time::timeout(Duration::from_secs(30), rx.recv()) => m.unwrap(),
        out = &mut exited => {
            let out = out.unwrap().unwrap();
            panic!("ianav-sim sitl exited early: {}", String::from_utf8_lossy(&out.stderr));
        }
    };
    let (_, h, _) = first.unwrap();
    assert_eq!((h.system_id, h.component_id), (1, 1));
    let out = exited.await.unwrap().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(dir.join("sitl.csv")).unwrap();
    assert!(csv.starts_with("t_rx_s,t_valid_s"));
    let _ = std::fs::remove_dir_all(&dir);
    let help = std::process::Command::new(env!("CARGO_BIN_EXE_ianav-sim"))
        .args(["sitl", "--help"])
        .output()
        .unwrap();
    let text = String::from_utf8(help.stdout).unwrap();
    for opt in [
        "--connect",
        "--autopilot",
        "--speed",
        "--terrain",
        "--frames-listen",
        "--out",
        "--duration",
        "--seed",
        "--gyro-drift",
        "--gnss-lag-ms",
        "--latency-ms",
        "--stream-latency",
    ] {
        assert!(text.contains(opt), "{opt} missing from --help");
    }
    // Bad latency options are refused before anything flies.
    for bad in [
        ["--stream-latency", "NO_SUCH_MESSAGE=5"],
        ["--stream-latency", "HIGHRES_IMU"],
        ["--latency-ms", "-1"],
        ["--gnss-lag-ms", "NaN"],
    ] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_ianav-sim"))
            .args([
                "sitl",
                "--connect",
                "udpout:127.0.0.1:9",
                "--duration",
                "1",
                "--speed",
                "0",
            ])
            .args(bad)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{bad:?} accepted");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_and_hostile_input_is_refused_or_skipped_without_stopping_the_vehicle() {
    // The vehicle listens (udpin) and the test talks to it from a raw socket, so that it can
    // send bytes no MAVLink library would produce.
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let setup = short_setup(1.0, 1.0, 3.0);
    let options = SitlOptions {
        connect: format!("udpin:127.0.0.1:{port}"),
        vehicle: VehicleConfig::default(),
        speed: 2.0,
        frames: None,
        out_dir: None,
    };
    let run = tokio::spawn(async move { sitl::run(&setup, SEED, options, |_, _| {}).await });
    let sock = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    sock.connect(("127.0.0.1", port)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let frame = |msg: &apm::MavMessage| {
        let mut v = Vec::new();
        mavlink::write_v2_msg(&mut v, CLIENT, msg).unwrap();
        v
    };
    let odo = |x: f32| {
        apm::MavMessage::ODOMETRY(apm::ODOMETRY_DATA {
            x,
            frame_id: apm::MavFrame::MAV_FRAME_LOCAL_NED,
            ..Default::default()
        })
    };
    let timesync = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
        tc1: 0,
        ts1: 1,
        target_system: 1,
        target_component: 1,
    });
    let mut garbage: Vec<Vec<u8>> = vec![
        (0..=255).collect(),
        vec![0xFD; 300],
        vec![0xFE, 9, 0, 1, 1, 0],
    ];
    let good = frame(&timesync);
    garbage.push(good[..good.len() / 2].to_vec()); // truncated
    let mut bad_crc = good.clone();
    let n = bad_crc.len();
    bad_crc[n - 1] ^= 0xFF;
    garbage.push(bad_crc);
    let mut v1 = Vec::new();
    mavlink::write_v1_msg(&mut v1, CLIENT, &timesync).unwrap();
    garbage.push(v1);
    for g in &garbage {
        sock.send(g).await.unwrap();
    }
    // Well-formed messages with absurd content: refused, never a panic.
    let hostile = [
        odo(f32::INFINITY),
        odo(1e30),
        apm::MavMessage::GPS_INPUT(apm::GPS_INPUT_DATA {
            lat: i32::MAX,
            lon: i32::MIN,
            alt: f32::NAN,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
            ..Default::default()
        }),
        apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
            param1: f32::NAN,
            param2: -5.0,
            command: apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            ..Default::default()
        }),
        apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
            param1: -3.0,
            command: apm::MavCmd::MAV_CMD_REQUEST_MESSAGE,
            ..Default::default()
        }),
        timesync.clone(),
    ];
    for m in &hostile {
        sock.send(&frame(m)).await.unwrap();
    }
    // The vehicle keeps answering: TIMESYNC replies and COMMAND_ACKs come back.
    let mut buf = vec![0_u8; 65_536];
    let mut acks = 0;
    let mut timesync_replies = 0;
    while let Ok(Ok(n)) = tokio::time::timeout(Duration::from_secs(3), sock.recv(&mut buf)).await {
        let mut r = mavlink::MavlinkReader::new(&buf[..n]);
        while let Ok((_, m)) = r.read_message::<apm::MavMessage>(mavlink::MavlinkVersion::V2) {
            match m {
                apm::MavMessage::COMMAND_ACK(a) => {
                    acks += 1;
                    assert_eq!(a.result, apm::MavResult::MAV_RESULT_DENIED);
                }
                apm::MavMessage::TIMESYNC(t) if t.tc1 != 0 => timesync_replies += 1,
                _ => {}
            }
        }
        if acks == 2 && timesync_replies >= 1 {
            break;
        }
    }
    assert_eq!(acks, 2);
    assert!(timesync_replies >= 1);
    let summary = run.await.unwrap().unwrap();
    assert_eq!(summary.vehicle.estimates, 0);
    assert_eq!(summary.vehicle.estimates_refused, 3);
    assert!(summary.mission_s >= 3.0);
}

#[test]
fn ardupilot_vfr_hud_airspeed_becomes_its_own_estimate_when_the_sensor_is_unhealthy() {
    let setup = short_setup(2.0, 100.0, 8.0);
    let cfg = VehicleConfig {
        airspeed_unhealthy_from_us: Some(6_000_000),
        ..own_navigation(Autopilot::ArduPilot)
    };
    let mut eas: BTreeMap<u64, f64> = BTreeMap::new();
    let out = drive(
        &setup,
        cfg,
        &[
            (apm::VFR_HUD_DATA::ID, 100_000.0),
            (apm::AIRSPEED_DATA::ID, 100_000.0),
        ],
        |v| {
            eas.insert(v.t_us(), v.ahrs_eas_mps());
        },
    );
    let mut sensor: BTreeMap<u64, f32> = BTreeMap::new();
    let (mut healthy, mut unhealthy) = (0, 0);
    for (t, m) in &out {
        match m {
            apm::MavMessage::AIRSPEED(a) => {
                let flags = if *t >= 6_000_000 {
                    apm::AirspeedSensorFlags::AIRSPEED_SENSOR_UNHEALTHY
                } else {
                    apm::AirspeedSensorFlags::AIRSPEED_SENSOR_USING
                };
                assert_eq!(a.flags, flags, "at {t} µs");
                sensor.insert(*t, a.airspeed);
            }
            apm::MavMessage::VFR_HUD(h) if *t >= 6_000_000 => {
                // The estimate, which differs from the sensor by its own errors.
                assert!(
                    close(h.airspeed, eas[t], 1e-6),
                    "{} vs {}",
                    h.airspeed,
                    eas[t]
                );
                unhealthy += 1;
            }
            apm::MavMessage::VFR_HUD(h) => {
                if let Some(s) = sensor.get(t) {
                    assert_eq!(h.airspeed, *s);
                    healthy += 1;
                }
            }
            _ => {}
        }
    }
    assert!(healthy > 30 && unhealthy > 30, "{healthy} {unhealthy}");
}

#[test]
fn ardupilot_reports_no_fix_with_the_last_fix_time_after_the_loss() {
    let setup = short_setup(2.0, 4.0, 10.0);
    let tw = twin(&setup);
    let cfg = own_navigation(Autopilot::ArduPilot);
    let out = drive(
        &setup,
        cfg,
        &[(apm::GPS_RAW_INT_DATA::ID, 200_000.0)],
        |_| {},
    );
    let last_fix_rx_us = tw.loss_us + 100_000;
    let (mut last_fix_repeats, mut no_fix) = (0, 0);
    for (t, m) in &out {
        let apm::MavMessage::GPS_RAW_INT(g) = m else {
            continue;
        };
        if *t <= tw.loss_us {
            continue;
        }
        // The last fix's reception time throughout.
        assert_eq!(g.time_usec, last_fix_rx_us, "at {t} µs");
        if *t < tw.loss_us + 1_100_000 {
            // Until the receiver's next report arrives, the last fix.
            assert_eq!(
                g.fix_type,
                apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
                "at {t} µs"
            );
            assert_eq!(
                g.lat,
                sitl::convert::deg_e7(tw.gnss[&tw.loss_us].pos.lat_rad)
            );
            last_fix_repeats += 1;
        } else {
            assert_eq!(
                g.fix_type,
                apm::GpsFixType::GPS_FIX_TYPE_NO_FIX,
                "at {t} µs"
            );
            assert_eq!((g.lat, g.lon, g.satellites_visible), (0, 0, 3));
            no_fix += 1;
        }
    }
    // 1 s of repeats at 5 Hz, then NO_FIX until the end (12 s of flight).
    assert!((4..=5).contains(&last_fix_repeats), "{last_fix_repeats}");
    assert!(no_fix >= 25, "{no_fix}");
}
