//! The visual navigation's golden replay: a short camera flight at reduced resolution (8 s of
//! scenario #2 over UR, a 192 × 256 camera with the authors' field of view and the pixel
//! settings scaled with it; the activation's dead bands narrowed so that the priors act), with
//! the VNS and the IA-VNS on the same frames, is recorded as a
//! sensor log (frames and settings included) and replayed through a fresh navigator. Every
//! frame's output of both systems must equal, bit for bit, (1) what the flight's own navigator
//! gave and (2) the committed `tests/data/vision-golden.csv`. Any change of the VNS or IA-VNS
//! outputs (or of the rendered frames) fails here: fix it, or re-bless the reference with
//! `IANAV_BLESS=1 cargo test -p ianav-sim --profile ci --test vision_golden` and say in the
//! commit why it changed (docs/REPLAY.md).

#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

use std::fmt::Write as _;
use std::path::Path;

use ianav::io::sensor_log::{SensorLogReader, SensorLogWriter};
use ianav::nav::replay::{config_of, config_to_toml, replay};
use ianav::nav::{NavConfig, NavSolution, Navigator, VisionState};
use ianav::sensors::SensorEvent;
use ianav_sim::flight::{
    CameraSetup, Flight, FlightObserver, FlightSetup, TruthSample, VisionOutput,
};
use ianav_sim::terrain::{Terrain, Zone};

const REFERENCE: &str = "tests/data/vision-golden.csv";
/// Reduction of the authors' 768 × 1024 camera.
const SCALE: u32 = 4;

/// The flight: its events, each system's fix at every output where it tracks, and the truth.
#[derive(Default)]
struct Recorder {
    events: Vec<SensorEvent>,
    fixes: Vec<String>,
    truth: Vec<(
        u64,
        ianav::math::wgs84::Geodetic,
        nalgebra::UnitQuaternion<f64>,
    )>,
}

impl FlightObserver for Recorder {
    fn sensor_event(&mut self, event: &SensorEvent) {
        self.events.push(event.clone());
    }
    fn truth_sample(&mut self, sample: &TruthSample) {
        self.truth.push((sample.t_us, sample.pos, sample.q_nb));
    }
    fn vision_outputs(&mut self, _truth: &TruthSample, t_us: u64, systems: &[VisionOutput]) {
        for s in systems {
            if let Some(f) = s.fix.filter(|f| f.t_us == t_us) {
                self.fixes.push(fix_line(f.t_us, s.name, &f.pos, &f.q_nb));
            }
        }
    }
}

/// `{}` of an f64 is its shortest decimal form that parses back to the same bits.
fn fix_line(
    t_us: u64,
    name: &str,
    pos: &ianav::math::wgs84::Geodetic,
    q: &nalgebra::UnitQuaternion<f64>,
) -> String {
    let q = q.quaternion();
    format!(
        "{t_us},{name},{},{},{},{},{},{},{}",
        pos.lat_rad, pos.lon_rad, pos.h_m, q.w, q.i, q.j, q.k
    )
}

fn setup() -> FlightSetup {
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.scenario.duration_s = 8.0;
    let zone = Zone::Urban;
    let start = zone.start();
    setup.scenario.start.lat_deg = start.lat_deg;
    setup.scenario.start.lon_deg = start.lon_deg;
    let mut camera = CameraSetup::new(std::sync::Arc::new(Terrain::new(zone, 0)));
    camera.camera.width_px /= SCALE;
    camera.camera.height_px /= SCALE;
    camera.camera.pixel_pitch_um *= f64::from(SCALE);
    setup.camera = Some(camera);
    // The pixel-denominated settings scaled with the image.
    let v = &mut setup.vision;
    v.detector.cell_size_px /= SCALE;
    v.init_cell_size_px /= SCALE;
    v.init_min_disparity_px /= f64::from(SCALE);
    // Dead bands far below the paper's, so that the priors and the joint optimisation act
    // within the 8 s (with the paper's they stay off that early).
    let a = &mut v.aiding.activation;
    a.dh_low_m = 0.2;
    a.dtheta_low_deg = 0.002;
    a.dbank_low_deg = 0.002;
    setup
}

#[test]
fn the_vns_and_ia_vns_replay_bit_for_bit_and_match_the_reference() {
    let setup = setup();
    let mut flight = Flight::new(&setup, 2).unwrap();
    let cfg = flight.navigator().unwrap().config().clone();
    let mut rec = Recorder::default();
    flight.run(&mut rec, |_| {}).unwrap();

    // Through a sensor log, frames and settings included.
    let mut writer = SensorLogWriter::new(Vec::new()).unwrap();
    writer.write_nav_config(&config_to_toml(&cfg)).unwrap();
    for e in &rec.events {
        writer.write(e).unwrap();
    }
    let bytes = writer.finish().unwrap();
    let reader = SensorLogReader::new(&bytes[..]).unwrap();
    let recorded = config_of(&reader).unwrap();
    assert_eq!(recorded, cfg, "the settings must survive the log");
    assert_eq!(recorded.compared_vision.len(), 1);
    let mut nav = Navigator::new(&recorded).unwrap();
    let mut csv = String::from("t_us,system,state,inliers,lat_rad,lon_rad,h_m,q_w,q_x,q_y,q_z\n");
    let mut replayed_fixes = Vec::new();
    let mut frames = 0;
    for event in reader {
        let event = event.unwrap();
        nav.push(&event);
        let SensorEvent::Frame(frame) = &event else {
            continue;
        };
        frames += 1;
        let names = ["vns", "ia-vns"];
        for (v, name) in nav.visual_systems().zip(names) {
            let state = format!("{:?}", v.status.state);
            match v.fix.filter(|f| f.t_us == frame.t_us) {
                Some(f) => {
                    let line = fix_line(f.t_us, name, &f.pos, &f.q_nb);
                    let (head, tail) = line.split_at(line.find(name).unwrap() + name.len());
                    let _ = writeln!(csv, "{head},{state},{}{tail}", v.status.n_inliers);
                    replayed_fixes.push(line);
                }
                None => {
                    let _ = writeln!(csv, "{},{name},{state},,,,,,,,", frame.t_us);
                }
            }
        }
    }
    // Both systems initialised and tracked most of the frames: the golden covers tracking.
    let tracked = |name: &str| {
        csv.lines()
            .filter(|l| l.contains(&format!(",{name},{:?},", VisionState::Tracking)))
            .count()
    };
    assert!(frames >= 70, "{frames} frames");
    for name in ["vns", "ia-vns"] {
        assert!(
            tracked(name) >= frames / 2,
            "{name} tracked {} of {frames}\n{csv}",
            tracked(name)
        );
    }
    let ia_vns = nav
        .visual_systems()
        .nth(1)
        .unwrap()
        .aiding
        .copied()
        .unwrap();
    assert!(
        ia_vns.priors_active >= 10 && ia_vns.inertial_starts >= 40,
        "the golden must cover the priors and ζ*: {ia_vns:?}"
    );
    // The replay gives what the flight's own navigator gave, at every output where one tracked.
    let at_outputs: Vec<&String> = replayed_fixes
        .iter()
        .filter(|l| rec.fixes.contains(l))
        .collect();
    assert_eq!(
        at_outputs.len(),
        rec.fixes.len(),
        "replay and flight differ"
    );
    assert!(!rec.fixes.is_empty());

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join(REFERENCE);
    if std::env::var_os("IANAV_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &csv).unwrap();
        return;
    }
    let reference = std::fs::read_to_string(&path).unwrap_or_default();
    if csv == reference {
        return;
    }
    let new_path = std::env::temp_dir().join("ianav-vision-golden.csv");
    std::fs::write(&new_path, &csv).unwrap();
    let first = csv
        .lines()
        .zip(reference.lines())
        .position(|(a, b)| a != b)
        .unwrap_or(csv.lines().count().min(reference.lines().count()));
    panic!(
        "visual navigation output changed; first difference at line {}:\n  now: {}\n  ref: {}\n\
         new output written to {} (fix, or re-bless with IANAV_BLESS=1 and say why)",
        first + 1,
        csv.lines().nth(first).unwrap_or("(none)"),
        reference.lines().nth(first).unwrap_or("(none)"),
        new_path.display()
    );
}

/// The daemon's deferred vision (`NavConfig::vision_deferred`) on the golden flight's events:
/// each frame's task run and handed back at once gives the inline solutions bit for bit; handed
/// back late (as from a slow worker), the frames that come meanwhile are dropped and counted,
/// and the recording with its markers replays to the same solutions bit for bit.
#[test]
fn deferred_vision_equals_inline_and_replays_where_its_results_were_applied() {
    let setup = setup();
    let mut flight = Flight::new(&setup, 2).unwrap();
    let mut cfg = flight.navigator().unwrap().config().clone();
    let mut rec = Recorder::default();
    flight.run(&mut rec, |_| {}).unwrap();
    let mut inline = Navigator::new(&cfg).unwrap();
    let inline_solutions: Vec<NavSolution> =
        rec.events.iter().filter_map(|e| inline.push(e)).collect();
    let frames = rec
        .events
        .iter()
        .filter(|e| matches!(e, SensorEvent::Frame(_)))
        .count() as u64;
    assert_eq!(inline.stats().frames, frames);

    cfg.vision_deferred = true;
    let mut at_once = Navigator::new(&cfg).unwrap();
    let mut solutions = Vec::new();
    for e in &rec.events {
        solutions.extend(at_once.push(e));
        if let Some(task) = at_once.take_vision_task() {
            assert!(at_once.vision_out() && at_once.visual_systems().next().is_none());
            assert!(at_once.apply_vision(task.run()).is_some());
        }
    }
    assert_eq!(solutions, inline_solutions, "applied at once = inline");
    assert!(
        solutions.iter().filter(|s| s.vision_fix.is_some()).count() > 100,
        "the comparison covers tracking"
    );

    // A worker that hands each result back 25 IMU samples (0.25 s) later: of the 10-Hz frames,
    // those that come while one is out are dropped. The events fed, markers included, are what
    // `ianav run --record` writes.
    let mut late = Navigator::new(&cfg).unwrap();
    let (mut fed, mut late_solutions) = (Vec::new(), Vec::new());
    let mut out: Option<(ianav::nav::VisionDone, u32)> = None;
    for e in &rec.events {
        late_solutions.extend(late.push(e));
        fed.push(e.clone());
        if let Some(task) = late.take_vision_task() {
            out = Some((task.run(), 0));
        }
        if matches!(e, SensorEvent::Imu(_))
            && let Some((done, waited)) = out.take()
        {
            if waited < 25 {
                out = Some((done, waited + 1));
            } else {
                fed.push(late.apply_vision(done).unwrap());
            }
        }
    }
    let busy = late.stats().frames_vision_busy;
    assert!(
        busy >= frames / 2 && busy < frames,
        "{busy} of {frames} frames dropped while one was out"
    );
    assert_eq!(late.stats().vision_results_unmatched, 0);
    assert!(late_solutions.iter().any(|s| s.vision_fix.is_some()));
    assert_ne!(late_solutions, inline_solutions);

    let mut writer = SensorLogWriter::new(Vec::new()).unwrap();
    writer.write_nav_config(&config_to_toml(&cfg)).unwrap();
    for e in &fed {
        writer.write(e).unwrap();
    }
    let bytes = writer.finish().unwrap();
    let reader = SensorLogReader::new(&bytes[..]).unwrap();
    let recorded = config_of(&reader).unwrap();
    assert!(recorded.vision_deferred);
    let mut replayed = Vec::new();
    let summary = replay(reader, &recorded, |s| {
        replayed.push(*s);
        Ok(())
    })
    .unwrap();
    assert_eq!(summary.nav.frames_vision_busy, busy);
    assert_eq!(
        replayed, late_solutions,
        "the replay applies each result at its marker"
    );
}

/// The golden flight (seed 2) with the GNSS lost at 4 s: its set-up, its navigator's settings
/// and what it recorded.
fn flown_with_the_loss_at_4_s() -> (FlightSetup, NavConfig, Recorder) {
    let mut setup = setup();
    setup.scenario.gnss_loss_s = 4.0;
    let mut flight = Flight::new(&setup, 2).unwrap();
    let cfg = flight.navigator().unwrap().config().clone();
    let mut rec = Recorder::default();
    flight.run(&mut rec, |_| {}).unwrap();
    (setup, cfg, rec)
}

/// The fused solution on real frames (docs/FUSION.md): the golden flight with the GNSS lost
/// at 4 s. Before the loss the published solution is the INS's, bit for bit; after it, while
/// the IA-VNS tracks, the horizontal position is the latest fix carried by the INS (the fused
/// minus the INS position equals the fix minus the INS at its exposure), the source is vision,
/// the vertical and the attitude stay the INS's, and every change of source moved the reset
/// counter once.
#[test]
fn after_the_loss_the_published_position_is_the_ia_vns_fix_carried_by_the_ins() {
    let (_, mut cfg, rec) = flown_with_the_loss_at_4_s();
    let mut plain = Navigator::new(&cfg).unwrap();
    cfg.fusion = Some(ianav::nav::fusion::FusionConfig::default());
    let mut fused = Navigator::new(&cfg).unwrap();
    let (mut denied, mut from_vision) = (0, 0);
    let mut reset_counters = (0_u8, 0_u8);
    for e in &rec.events {
        let (p, f) = (plain.push(e), fused.push(e));
        assert_eq!(p.is_some(), f.is_some());
        let (Some(p), Some(f)) = (p, f) else { continue };
        reset_counters = (p.reset_counter, f.reset_counter);
        if !p.ins_status.gnss_denied {
            assert_eq!(f.pos, p.pos);
            assert_eq!(f.cov, p.cov);
            assert_eq!(f.horizontal_source, ianav::nav::PositionSource::Ins);
            continue;
        }
        denied += 1;
        assert_eq!(
            (f.pos.h_m, f.q_nb, f.v_ned_mps),
            (p.pos.h_m, p.q_nb, p.v_ned_mps)
        );
        assert_eq!(f.cov.position_m2[(2, 2)], p.cov.position_m2[(2, 2)]);
        let Some(fix) = f
            .vision_fix
            .filter(|_| f.vision.state == VisionState::Tracking)
        else {
            continue;
        };
        from_vision += 1;
        assert_eq!(f.horizontal_source, ianav::nav::PositionSource::Vision);
        let ins_at_fix = fused.ins_pose_at(fix.t_us).unwrap();
        let fix_offset = ianav::math::wgs84::ned_difference_m(&ins_at_fix.pos, &fix.pos).xy();
        let published = ianav::math::wgs84::ned_difference_m(&p.pos, &f.pos).xy();
        // First order about the current position: the offset's metres change by
        // |offset| × distance since the fix / R, far under a millimetre.
        assert!(
            (published - fix_offset).norm() < 1e-3,
            "t {} µs: published {published}, fix {fix_offset}",
            f.t_us
        );
        // At least the fix's own variance per axis (σ₀²).
        assert!(f.cov.position_m2[(0, 0)] >= 12.4 * 12.4 - 1e-9);
    }
    // The loss is declared 1.5 s after the last fix (the INS's timeout): 2.5 s of denial.
    assert!(
        denied >= 200 && from_vision >= 200,
        "{denied} denied, {from_vision} from vision"
    );
    let stats = fused.stats();
    assert!(stats.horizontal_source_changes >= 1);
    assert_eq!(
        reset_counters.1.wrapping_sub(reset_counters.0),
        stats.horizontal_source_changes as u8
    );
    assert!(stats.fused_vision_fixes > 30);
    assert_eq!(stats.vision_fixes_without_ins_pose, 0);
}

/// Losing the frames and getting them back (docs/FUSION.md): the golden flight with the GNSS
/// lost at 4 s and no frame for 1.5 s after 6 s. While none comes the published position
/// dead-reckons from the last fix (source INS, no jump); the first frame after the gap starts
/// the IA-VNS over from the fused pose; once it tracks again the source is vision, its
/// position continues the dead-reckoned one, and the covariance still covers the error.
#[test]
fn after_a_gap_in_the_frames_the_ia_vns_restarts_from_the_fused_pose() {
    frames_interrupted(1.5, 14.0, Interruption::NoFrames);
}

/// The same with the frames stopped for 10 s (a stalled stream that comes back).
#[test]
fn after_ten_seconds_without_frames_the_ia_vns_restarts_too() {
    frames_interrupted(10.0, 30.0, Interruption::NoFrames);
}

/// Featureless ground (water, a uniform field: every frame of 5 s one grey level, at the
/// frames' own times): tracking is lost, the position dead-reckons, after 3 s of
/// relocalisation the IA-VNS starts over and, once the ground has texture again, initialises
/// from the fused pose and tracks.
#[test]
fn over_five_seconds_of_featureless_ground_the_ia_vns_is_lost_then_restarts() {
    frames_interrupted(5.0, 20.0, Interruption::Featureless);
}

/// What the camera gives during the window.
#[derive(Clone, Copy, PartialEq)]
enum Interruption {
    /// Nothing.
    NoFrames,
    /// Frames of one grey level.
    Featureless,
}

/// The golden flight of `duration_s` with the GNSS lost at 4 s and the frames interrupted for
/// `window_s` after 6 s, navigated with the fused solution and the restarts.
fn frames_interrupted(window_s: f64, duration_s: f64, how: Interruption) {
    use ianav::math::wgs84::ned_difference_m;
    use ianav::nav::PositionSource;
    let mut setup = setup();
    setup.scenario.duration_s = duration_s;
    setup.scenario.gnss_loss_s = 4.0;
    let mut flight = Flight::new(&setup, 2).unwrap();
    let mut cfg = flight.navigator().unwrap().config().clone();
    let mut rec = Recorder::default();
    flight.run(&mut rec, |_| {}).unwrap();
    cfg.fusion = Some(ianav::nav::fusion::FusionConfig::default());
    cfg.vision_restart = Some(ianav::nav::VisionRestart::default());
    let mission_us = |s: f64| (setup.scenario.warmup_s + s) as u64 * 1_000_000;
    let window = mission_us(6.0)..mission_us(6.0) + (window_s * 1e6) as u64;
    let mut nav = Navigator::new(&cfg).unwrap();
    let truth_at = |t_us: u64| {
        let i = rec.truth.partition_point(|(t, _, _)| *t < t_us);
        rec.truth
            .get(i)
            .filter(|(t, _, _)| *t == t_us)
            .map(|(_, p, _)| *p)
    };
    let mut last: Option<NavSolution> = None;
    let (mut sources, mut worst_nees) = (Vec::new(), 0.0_f64);
    let mut featureless = 0;
    for e in &rec.events {
        let grey;
        let e = match e {
            SensorEvent::Frame(f) if window.contains(&f.t_us) => match how {
                Interruption::NoFrames => continue,
                Interruption::Featureless => {
                    featureless += 1;
                    grey = SensorEvent::Frame(ianav::sensors::Frame {
                        pixels: vec![128_u8; f.pixels.len()].into(),
                        ..f.clone()
                    });
                    &grey
                }
            },
            e => e,
        };
        let Some(s) = nav.push(e) else { continue };
        if s.ins_status.gnss_denied {
            if sources.last() != Some(&s.horizontal_source) {
                sources.push(s.horizontal_source);
            }
            // Consecutive published positions 10 ms apart differ by the motion, to within a
            // quarter of the published σ (fix-to-fix noise, larger in a map just started), or
            // 2 m; where the reset counter tells the consumer of a jump (the restarted
            // system's first fix) the jump stays within 3 σ of the published covariance.
            if let Some(l) = last.filter(|l| l.ins_status.gnss_denied) {
                let step = ned_difference_m(&l.pos, &s.pos).xy().norm();
                let moved = l.v_ned_mps.xy().norm() * (s.t_us - l.t_us) as f64 * 1e-6;
                let sigma_h = s.cov.position_m2.fixed_view::<2, 2>(0, 0).trace().sqrt();
                let allowed = if s.reset_counter == l.reset_counter {
                    (0.25 * sigma_h).max(2.0)
                } else {
                    3.0 * sigma_h
                };
                assert!(
                    (step - moved).abs() < allowed,
                    "t {} µs: a {step:.2} m step for {moved:.2} m flown",
                    s.t_us
                );
            }
            if let Some(truth) = truth_at(s.t_us) {
                let e_h = ned_difference_m(&truth, &s.pos).xy();
                let p = s.cov.position_m2.fixed_view::<2, 2>(0, 0).into_owned();
                let nees = e_h.dot(&(p.try_inverse().unwrap() * e_h));
                worst_nees = worst_nees.max(nees);
            }
        }
        last = Some(s);
    }
    if how == Interruption::Featureless {
        assert!(
            featureless as f64 >= 9.0 * window_s,
            "{featureless} grey frames"
        );
    }
    assert_eq!(nav.stats().vision_restarts, 1);
    assert_eq!(
        sources,
        [
            PositionSource::Vision,
            PositionSource::Ins,
            PositionSource::Vision
        ],
        "vision, lost in the gap, vision again"
    );
    assert_eq!(nav.vision().state, VisionState::Tracking);
    // χ²(2) exceeds 13.8 with probability 0.001: a short flight's errors are correlated, so
    // this bounds the covariance's honesty loosely.
    assert!(worst_nees < 13.8, "worst NEES {worst_nees:.1}");
}

/// The MCAP export (docs/REPLAY.md "MCAP"): the golden flight with the GNSS lost at 4 s,
/// fused, recorded and exported; read back with the `mcap` crate, every channel has its
/// Foxglove schema and JSON encoding, the counts are the frames, the 10-Hz solutions and the
/// fixes, and the positions are the replayed solutions'. With the flight's truth the true
/// track is there too, and each status carries the solution's horizontal error.
#[test]
fn a_recording_exports_to_mcap_with_foxglove_schemas() {
    use ianav::io::mcap_export::{self, McapOptions};
    let (setup, mut cfg, rec) = flown_with_the_loss_at_4_s();
    cfg.fusion = Some(ianav::nav::fusion::FusionConfig::default());
    let mut writer = SensorLogWriter::new(Vec::new()).unwrap();
    writer.write_nav_config(&config_to_toml(&cfg)).unwrap();
    for e in &rec.events {
        writer.write(e).unwrap();
    }
    let bytes = writer.finish().unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    let truth: Vec<mcap_export::TruthFix> = rec
        .truth
        .iter()
        .map(|&(t_us, pos, q_nb)| mcap_export::TruthFix {
            t_us,
            pos,
            q_nb: Some(q_nb),
        })
        .collect();
    let summary = mcap_export::export_mcap(
        SensorLogReader::new(&bytes[..]).unwrap(),
        &cfg,
        &mut out,
        &McapOptions::default(),
        &truth,
    )
    .unwrap();
    // The same log replayed alone: the solutions the export wrote from.
    let mut solutions = Vec::new();
    replay(SensorLogReader::new(&bytes[..]).unwrap(), &cfg, |s| {
        solutions.push(*s);
        Ok(())
    })
    .unwrap();
    let frames = rec
        .events
        .iter()
        .filter(|e| matches!(e, SensorEvent::Frame(_)))
        .count() as u64;
    let mut counts = std::collections::BTreeMap::<String, u64>::new();
    let mut positions = Vec::new();
    let mut errors = Vec::new();
    let (mut image_times, mut annotated, mut truth_poses) = (Vec::new(), Vec::new(), Vec::new());
    let cam = &setup.camera.as_ref().unwrap().camera;
    let (setup_w, setup_h) = (cam.width_px, cam.height_px);
    let mcap_bytes = out.into_inner();
    // Kept for a look in Foxglove or a check against its published schemas (docs/REPLAY.md).
    if let Some(path) = std::env::var_os("IANAV_MCAP_OUT") {
        std::fs::write(path, &mcap_bytes).unwrap();
    }
    for m in mcap::MessageStream::new(&mcap_bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        let expected = match m.channel.topic.as_str() {
            mcap_export::TOPIC_IMAGE => "foxglove.CompressedImage",
            mcap_export::TOPIC_POSITION
            | mcap_export::TOPIC_INS
            | mcap_export::TOPIC_VISION_FIX
            | mcap_export::TOPIC_TRUTH => "foxglove.LocationFix",
            mcap_export::TOPIC_STATUS => "ianav.Status",
            mcap_export::TOPIC_FEATURES => "foxglove.ImageAnnotations",
            mcap_export::TOPIC_POSE_FUSED
            | mcap_export::TOPIC_POSE_INS
            | mcap_export::TOPIC_POSE_VISION
            | mcap_export::TOPIC_POSE_TRUTH => "foxglove.PoseInFrame",
            other => panic!("unexpected topic {other}"),
        };
        assert_eq!(schema.name, expected);
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(m.channel.message_encoding, "json");
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        if m.channel.topic == mcap_export::TOPIC_POSITION {
            positions.push((m.log_time / 1_000, v["latitude"].as_f64().unwrap()));
        }
        if m.channel.topic == mcap_export::TOPIC_IMAGE {
            assert_eq!(v["format"], "png");
            image_times.push(m.log_time);
        }
        if m.channel.topic == mcap_export::TOPIC_FEATURES {
            let points = v["points"][0]["points"].as_array().unwrap();
            annotated.push((m.log_time, points.len()));
            for p in points {
                let (x, y) = (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap());
                assert!((0.0..=f64::from(setup_w)).contains(&x), "{p}");
                assert!((0.0..=f64::from(setup_h)).contains(&y), "{p}");
            }
        }
        if m.channel.topic.starts_with("/pose/") {
            assert_eq!(v["frame_id"], mcap_export::ENU_FRAME);
            let q = &v["pose"]["orientation"];
            let norm2: f64 = ["x", "y", "z", "w"]
                .iter()
                .map(|k| q[k].as_f64().unwrap().powi(2))
                .sum();
            assert!((norm2 - 1.0).abs() < 1e-9, "{v}");
        }
        if m.channel.topic == mcap_export::TOPIC_POSE_TRUTH {
            truth_poses.push((m.log_time / 1_000, v["pose"].clone()));
        }
        if m.channel.topic == mcap_export::TOPIC_STATUS
            && let Some(e) = v["horizontal_error_m"].as_f64()
        {
            errors.push((m.log_time / 1_000, e));
        }
        *counts.entry(m.channel.topic.clone()).or_insert(0) += 1;
    }
    assert_eq!(counts, summary.messages);
    assert_eq!(counts[mcap_export::TOPIC_IMAGE], frames);
    // One solution per 100 ms of the 100-Hz IMU.
    let n = solutions.len() as u64;
    assert!(
        counts[mcap_export::TOPIC_POSITION].abs_diff(n / 10) <= 1,
        "{counts:?}, {n}"
    );
    assert_eq!(
        counts[mcap_export::TOPIC_STATUS],
        counts[mcap_export::TOPIC_POSITION]
    );
    assert!(counts[mcap_export::TOPIC_VISION_FIX] > 30, "{counts:?}");
    for (a, b) in [
        (mcap_export::TOPIC_INS, mcap_export::TOPIC_POSITION),
        (mcap_export::TOPIC_POSE_FUSED, mcap_export::TOPIC_POSITION),
        (mcap_export::TOPIC_POSE_INS, mcap_export::TOPIC_POSITION),
        (
            mcap_export::TOPIC_POSE_VISION,
            mcap_export::TOPIC_VISION_FIX,
        ),
        (mcap_export::TOPIC_POSE_TRUTH, mcap_export::TOPIC_TRUTH),
    ] {
        assert_eq!(counts[a], counts[b], "{a} against {b}");
    }
    // Every tracked frame's features are drawn on it: one annotation per visual fix (each fix
    // is a tracked frame), at an image's time, each with the pose optimisation's inliers.
    assert_eq!(
        counts[mcap_export::TOPIC_FEATURES],
        counts[mcap_export::TOPIC_VISION_FIX]
    );
    for (t_ns, n) in &annotated {
        assert!(
            image_times.contains(t_ns),
            "annotation at {t_ns} ns without its image"
        );
        assert!(*n >= 10, "{n} features at {t_ns} ns");
    }
    // The true poses, in the ENU frame whose origin is the first solution written: at the
    // truth's offset from it, and with the body's x axis where the truth's points.
    let origin = solutions[0].pos;
    for (t_us, pose) in &truth_poses {
        let t = truth.iter().find(|t| t.t_us == *t_us).unwrap();
        let ned = ianav::math::wgs84::ned_difference_m(&origin, &t.pos);
        let p = &pose["position"];
        let enu = nalgebra::Vector3::new(
            p["x"].as_f64().unwrap(),
            p["y"].as_f64().unwrap(),
            p["z"].as_f64().unwrap(),
        );
        assert!((enu - nalgebra::Vector3::new(ned.y, ned.x, -ned.z)).norm() < 1e-6);
    }
    let (t0_us, pose0) = &truth_poses[0];
    let t0 = truth.iter().find(|t| t.t_us == *t0_us).unwrap();
    let q = &pose0["orientation"];
    let q_enu_b = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q["w"].as_f64().unwrap(),
        q["x"].as_f64().unwrap(),
        q["y"].as_f64().unwrap(),
        q["z"].as_f64().unwrap(),
    ));
    let x_enu = q_enu_b * nalgebra::Vector3::x();
    let x_ned = t0.q_nb.unwrap() * nalgebra::Vector3::x();
    assert!((x_enu - nalgebra::Vector3::new(x_ned.y, x_ned.x, -x_ned.z)).norm() < 1e-9);
    for (t_us, lat_deg) in positions {
        let s = solutions.iter().find(|s| s.t_us == t_us).unwrap();
        assert_eq!(lat_deg, s.pos.lat_rad.to_degrees());
    }
    // The truth comes at the solutions' 10 Hz on the same clock: every status has its error,
    // the solution's distance from the true position at its time.
    let last_t_us = solutions.last().unwrap().t_us;
    let truth_in_span = truth.iter().filter(|t| t.t_us <= last_t_us).count() as u64;
    assert_eq!(counts[mcap_export::TOPIC_TRUTH], truth_in_span);
    assert_eq!(errors.len() as u64, counts[mcap_export::TOPIC_STATUS]);
    for (t_us, e) in errors {
        let s = solutions.iter().find(|s| s.t_us == t_us).unwrap();
        let t = truth.iter().min_by_key(|t| t.t_us.abs_diff(t_us)).unwrap();
        let d = ianav::math::wgs84::ned_difference_m(&t.pos, &s.pos);
        // serde_json's default float parsing may miss the last bit.
        assert!(
            (e - d.x.hypot(d.y)).abs() < 1e-9,
            "{e} against {}",
            d.x.hypot(d.y)
        );
    }
}
