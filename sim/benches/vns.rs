//! Criterion bench of the visual navigation per frame over a rendered frame sequence, the
//! paper's VNS and IA-VNS (targets on one core: VNS median ≤ 5 ms, p99 ≤ 15 ms; IA-VNS median
//! ≤ 3 ms, p99 ≤ 8 ms; docs/PERFORMANCE.md).
//!
//! Set-up (not timed): the first 20 s of scenario #2 over a zone, seed 1, flown with the camera;
//! every sensor event is recorded. A navigator with the flight's camera takes the events up to
//! mission time 5 s (the two-view initialisation is over by then) and is kept as a snapshot.
//!
//! `vns/frame/<zone>` (the VNS) and `vns/ia-vns-frame/<zone>` (the IA-VNS): one iteration is
//! one frame of the remaining 15 s (tracking, and a
//! keyframe every few seconds), the IMU and air-data events between frames applied untimed;
//! at the end of the sequence the navigator starts again from the snapshot, untimed. The
//! per-frame distribution (p99, initialisation, keyframes) is `ianav-sim bench-vns`'s.

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use ianav::nav::Navigator;
use ianav::sensors::SensorEvent;
use ianav_sim::flight::systems::VisionSystem;
use ianav_sim::flight::{CameraSetup, Flight, FlightSetup};
use ianav_sim::terrain::{Terrain, Zone};
use ianav_sim::vns_timing::{EventRecorder, vision_config};

/// Recorded flight length and the snapshot's mission time, s.
const RECORDED_S: f64 = 20.0;
const SNAPSHOT_S: f64 = 5.0;

/// The navigator at the snapshot and the events after it.
fn sequence(zone: Zone, system: VisionSystem) -> Option<(Navigator, Vec<SensorEvent>)> {
    let mut setup = FlightSetup::builtin(2).ok()?;
    setup.scenario.duration_s = RECORDED_S;
    let mut camera = CameraSetup::new(Arc::new(Terrain::new(zone, 0)));
    camera.vision_navigation = false;
    setup.camera = Some(camera);
    let mut flight = Flight::new(&setup, 1).ok()?;
    let cfg = vision_config(&setup, &flight, system).ok()?;
    let warmup_us = setup.scenario.warmup_s * 1e6;
    let mut recorder = EventRecorder::default();
    flight.run(&mut recorder, |_| {}).ok()?;
    let mut nav = Navigator::new(&cfg).ok()?;
    let snapshot_us = warmup_us + SNAPSHOT_S * 1e6;
    let split = recorder
        .events
        .iter()
        .position(|e| e.t_us() as f64 > snapshot_us)?;
    for e in &recorder.events[..split] {
        nav.push(e);
    }
    Some((nav, recorder.events.split_off(split)))
}

fn bench_vns(c: &mut Criterion) {
    let mut group = c.benchmark_group("vns");
    group.sample_size(20);
    group.warm_up_time(Duration::from_secs(2));
    group.measurement_time(Duration::from_secs(10));
    let runs = [
        (Zone::Mix, VisionSystem::Vns, "frame"),
        (Zone::Urban, VisionSystem::Vns, "frame"),
        (Zone::Mix, VisionSystem::IaVns, "ia-vns-frame"),
        (Zone::Urban, VisionSystem::IaVns, "ia-vns-frame"),
    ];
    for (zone, system, name) in runs {
        let Some((snapshot, events)) = sequence(zone, system) else {
            eprintln!("vns bench: the {} flight could not be set up", zone.code());
            continue;
        };
        let frames = events
            .iter()
            .filter(|e| matches!(e, SensorEvent::Frame(_)))
            .count();
        eprintln!(
            "vns bench {} {}: {frames} frames after the snapshot, {:?}",
            zone.code(),
            system.name(),
            snapshot.vision().state
        );
        let mut nav = snapshot.clone();
        let mut next = 0_usize;
        group.bench_function(format!("{name}/{}", zone.code()), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                let mut timed = 0;
                while timed < iters {
                    if next == events.len() {
                        nav = snapshot.clone();
                        next = 0;
                    }
                    let event = &events[next];
                    next += 1;
                    if matches!(event, SensorEvent::Frame(_)) {
                        let t0 = Instant::now();
                        black_box(nav.push(event));
                        total += t0.elapsed();
                        timed += 1;
                    } else {
                        nav.push(event);
                    }
                }
                total
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_vns);
criterion_main!(benches);
