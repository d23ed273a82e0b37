//! Monte Carlo machinery: navigation-error metrics of known synthetic errors, statistics on
//! hand-made numbers, determinism of whole batches, shards merging into the same report as
//! one batch, and failed runs being reported rather than fatal.

#![allow(clippy::unwrap_used)] // tests: a failed unwrap is a failed test

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use ianav::math::{so3, wgs84};
use ianav_sim::control::NavEstimate;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup, TruthSample};
use ianav_sim::metrics::{self, MetricsRecorder, NseSample};
use ianav_sim::montecarlo::{self, Batch, RunOutcome, RunRecord, Shard};
use ianav_sim::report::{self, stats};
use ianav_sim::rng;
use nalgebra::UnitQuaternion;

/// Short flights keep the suite fast: 45 s of mission (after the 50 s warm-up) exercises the
/// 10-s grid and a `t_end` off the grid.
const SHORT_DURATION_S: f64 = 45.0;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ianav-mc-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn short_setup() -> FlightSetup {
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.scenario.duration_s = SHORT_DURATION_S;
    setup
}

/// A real truth sample (scenario 2, seed 1, at the start), to perturb.
fn truth() -> TruthSample {
    let mut t = Flight::new(&FlightSetup::builtin(2).unwrap(), 1)
        .unwrap()
        .truth_sample();
    t.t_s = 300.0;
    t.distance_m = 10_000.0;
    t
}

/// The estimate equal to the truth.
fn exact_estimate(t: &TruthSample) -> NavEstimate {
    NavEstimate {
        t_us: t.t_us,
        pos: t.pos,
        v_ned_mps: t.v_ned_mps,
        q_nb: t.q_nb,
        w_nb_b_rps: nalgebra::Vector3::zeros(),
        tas_mps: t.air.tas_mps,
        aoa_rad: t.air.aoa_rad,
        aos_rad: t.air.aos_rad,
        hp_m: t.hp_m,
    }
}

#[test]
fn known_yaw_and_north_offsets_give_known_errors() {
    let truth = truth();
    let mut est = exact_estimate(&truth);
    // 1° of yaw about the NED down axis: the ZYX yaw grows by exactly 1°, pitch and bank are
    // unchanged, and q_truth⁻¹ Rz(1°) q_truth is a 1° rotation, so the norm is 1°.
    est.q_nb = UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), 1f64.to_radians())
        * truth.q_nb;
    // 100 m north along the meridian: Δφ = 100 m / (M + h). The level distance differs from
    // 100 m by the variation of M over 100 m (relative ~e²·Δφ ≈ 1e-7, i.e. 1e-5 m) and the
    // chord-arc difference s³/(6R²) ≈ 4e-9 m: 1e-4 m covers both with margin.
    est.pos.lat_rad += 100.0 / (wgs84::radius_meridian_m(truth.pos.lat_rad) + truth.pos.h_m);
    let e = metrics::nse(&truth, &est);
    // Angles: the Euler extraction and Log are accurate to ~1e-15 rad; 1e-9° is far above.
    assert!((e.yaw_deg - 1.0).abs() < 1e-9, "yaw {}", e.yaw_deg);
    assert!(e.pitch_deg.abs() < 1e-9 && e.bank_deg.abs() < 1e-9, "{e:?}");
    assert!(
        (e.att_norm_deg - 1.0).abs() < 1e-9,
        "norm {}",
        e.att_norm_deg
    );
    assert!((e.hor_m - 100.0).abs() < 1e-4, "horizontal {}", e.hor_m);
    // Horizontal percentage of the 10 km flown; altitude unchanged (ellipsoidal h is a
    // coordinate of the estimate, independent of the horizontal offset).
    assert!((e.hor_pct - 1.0).abs() < 1e-6, "pct {}", e.hor_pct);
    assert_eq!(e.alt_m, 0.0);
    assert_eq!(e.t_s, 300.0);

    // The exact estimate gives zero errors; at distance 0 the percentage is undefined.
    let mut at_start = truth;
    at_start.distance_m = 0.0;
    let zero = metrics::nse(&at_start, &exact_estimate(&at_start));
    assert_eq!(
        [zero.yaw_deg, zero.pitch_deg, zero.bank_deg, zero.alt_m],
        [0.0; 4]
    );
    assert!(zero.att_norm_deg < 1e-12 && zero.hor_m < 1e-9, "{zero:?}");
    assert!(zero.hor_pct.is_nan());
}

#[test]
fn euler_errors_wrap_across_180_degrees_and_altitude_is_signed() {
    let mut truth = truth();
    truth.q_nb = so3::from_euler_zyx(
        179.5f64.to_radians(),
        3f64.to_radians(),
        179.5f64.to_radians(),
    );
    let mut est = exact_estimate(&truth);
    // Bank +2° about the body x axis (right-multiplied: ZYX bank adds exactly): the estimated
    // bank is 181.5° ≡ −178.5°, the wrapped error +2°, and the norm 2°.
    est.q_nb = truth.q_nb
        * UnitQuaternion::from_axis_angle(&nalgebra::Vector3::x_axis(), 2f64.to_radians());
    est.pos.h_m -= 5.0;
    let e = metrics::nse(&truth, &est);
    assert!((e.bank_deg - 2.0).abs() < 1e-9, "bank {}", e.bank_deg);
    assert!(e.yaw_deg.abs() < 1e-9 && e.pitch_deg.abs() < 1e-9, "{e:?}");
    assert!((e.att_norm_deg - 2.0).abs() < 1e-9);
    // Altitude −5 m exactly (a difference of two f64 of ~3e3 m: error ≲ 1e-12 m); the
    // vertical offset has no horizontal component in the truth's level frame (< 1e-6 m).
    assert!((e.alt_m + 5.0).abs() < 1e-9, "alt {}", e.alt_m);
    assert!(e.hor_m < 1e-6, "hor {}", e.hor_m);

    // Yaw 179.5° + 1° wraps to −179.5°: the error is +1°, not −359°.
    let mut est = exact_estimate(&truth);
    est.q_nb = UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), 1f64.to_radians())
        * truth.q_nb;
    let e = metrics::nse(&truth, &est);
    assert!((e.yaw_deg - 1.0).abs() < 1e-9, "yaw {}", e.yaw_deg);
}

#[test]
fn recorder_samples_every_10_s_from_0_and_at_the_end() {
    let truth0 = truth();
    let mut recorder = MetricsRecorder::new();
    // Output samples at 10 Hz from −2 s to 25 s, times computed as the flight does (integer
    // microseconds, so grid times are not exact in f64); 1 m north error throughout.
    let warmup_us: u64 = 50_000_000;
    for k in 480..=750u64 {
        let t_us = k * 100_000;
        let mut t = truth0;
        t.t_us = t_us;
        t.t_s = (t_us as f64 - warmup_us as f64) * 1e-6;
        t.distance_m = 30.0 * t.t_s.max(0.0);
        let mut est = exact_estimate(&t);
        est.pos.lat_rad += 1.0 / (wgs84::radius_meridian_m(t.pos.lat_rad) + t.pos.h_m);
        recorder.estimate_sample(&t, &est);
    }
    let samples = recorder.finish();
    let times: Vec<f64> = samples.iter().map(|s| s.t_s).collect();
    let expected = [0.0, 10.0, 20.0, 25.0];
    assert_eq!(times.len(), expected.len(), "{times:?}");
    for (t, x) in times.iter().zip(expected) {
        assert!((t - x).abs() < 1e-6, "{times:?}");
    }
    assert!(samples[0].hor_pct.is_nan(), "undefined at t = 0");
    // 1 m of 300 m flown at 10 s.
    assert!((samples[1].hor_pct - 100.0 / 300.0).abs() < 1e-6);

    // A flight ending on the grid does not repeat its last sample.
    let mut recorder = MetricsRecorder::new();
    for k in 0..=200u64 {
        let mut t = truth0;
        t.t_s = k as f64 * 0.1;
        recorder.estimate_sample(&t, &exact_estimate(&t));
    }
    assert_eq!(recorder.finish().len(), 3); // 0, 10, 20
}

#[test]
fn statistics_of_hand_made_numbers() {
    // mean (1 − 3 + 2)/3 = 0; population variance (1 + 9 + 4)/3 = 14/3; largest |x| is −3.
    let s = stats(&[1.0, -3.0, 2.0]).unwrap();
    assert_eq!(s.n, 3);
    assert!(s.mean.abs() < 1e-15);
    assert!((s.std - (14.0f64 / 3.0).sqrt()).abs() < 1e-15);
    assert_eq!(s.largest, -3.0);
    // mean 5, deviations ±1, ±3 → variance (1 + 1 + 9 + 9)/4 = 5 (the sample std would be
    // √(20/3)); a tie of magnitudes keeps the first value.
    let s = stats(&[4.0, 6.0, 2.0, 8.0]).unwrap();
    assert!((s.mean - 5.0).abs() < 1e-15 && (s.std - 5f64.sqrt()).abs() < 1e-15);
    assert_eq!(stats(&[2.0, -2.0]).unwrap().largest, 2.0);
    assert_eq!(stats(&[-2.0, 2.0]).unwrap().largest, -2.0);
    let one = stats(&[-7.5]).unwrap();
    assert_eq!((one.mean, one.std, one.largest), (-7.5, 0.0, -7.5));
    assert!(stats(&[]).is_none());
    let nan = stats(&[1.0, f64::NAN]).unwrap();
    assert!(nan.mean.is_nan() && nan.std.is_nan() && nan.largest.is_nan());
}

/// Every regular file under `dir` (relative path → bytes), excluding the manifests, which
/// name the shard.
fn files_under(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                let rel = path.strip_prefix(root).unwrap().display().to_string();
                if !rel.starts_with("mc") {
                    out.insert(rel, std::fs::read(&path).unwrap());
                }
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

fn batch(seeds: Vec<u64>, shard: Option<Shard>) -> Batch {
    Batch {
        scenario: 2,
        setup: short_setup(),
        seeds,
        shard,
        jobs: Some(2),
        resume: false,
    }
}

#[test]
fn batches_are_deterministic_and_shards_merge_into_the_same_report() {
    let dir = temp_dir("shards");
    let seeds: Vec<u64> = (1..=4).collect();
    let (full, again) = (dir.join("full"), dir.join("again"));
    for out in [&full, &again] {
        let summary = montecarlo::run_batch(&batch(seeds.clone(), None), out, |_| {}).unwrap();
        assert_eq!(summary.manifest.completed, 4);
        report::report(std::slice::from_ref(out), out).unwrap();
    }
    // Same seeds → byte-identical run files, report, plots and time series.
    let full_files = files_under(&full);
    assert!(full_files.contains_key("report.md") && full_files.contains_key("runs/run_0004.csv"));
    assert!(full_files.contains_key("nse_attitude_norm.png"));
    assert_eq!(full_files, files_under(&again));

    // Shards 1/2 and 2/2 in separate directories, merged by `report` → the same report.
    let parent = dir.join("shards");
    for i in 1..=2 {
        let shard = Shard { index: i, count: 2 };
        let out = parent.join(format!("shard{i}"));
        let s = montecarlo::run_batch(&batch(seeds.clone(), Some(shard)), &out, |_| {}).unwrap();
        assert_eq!(s.manifest.seeds, shard.select(&seeds));
    }
    let merged = dir.join("merged");
    let dirs = [parent.join("shard1"), parent.join("shard2")];
    report::report(&dirs, &merged).unwrap();
    report::report(std::slice::from_ref(&parent), &parent).unwrap();
    let report_of = |d: &Path| std::fs::read(d.join(report::REPORT_FILE)).unwrap();
    assert_eq!(report_of(&merged), report_of(&full));
    assert_eq!(report_of(&parent), report_of(&full));
    for name in ["nse_timeseries.csv", "nse_horizontal_m.png"] {
        assert_eq!(
            std::fs::read(merged.join(name)).unwrap(),
            std::fs::read(full.join(name)).unwrap()
        );
    }
    // The report's seed list and distance statistics come from the runs.
    let text = String::from_utf8(report_of(&full)).unwrap();
    assert!(
        text.contains("4 runs (seeds 1–4): 4 completed, 0 failed"),
        "{text}"
    );
    assert!(text.contains("t_end = 45.0 s"), "{text}");

    // A stale directory holding runs of other seeds is refused.
    let err = montecarlo::run_batch(&batch(vec![7], None), &full, |_| {}).unwrap_err();
    assert!(err.to_string().contains("seed 1"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A completed run with made-up errors drawn from the seed's own stream.
fn synthetic_run(seed: u64) -> RunRecord {
    let mut r = rng::stream(seed, "test.synthetic");
    let samples: Vec<NseSample> = (0..=5)
        .map(|k| {
            let t_s = 10.0 * k as f64;
            let mut n = || rng::normal(&mut r);
            NseSample {
                t_s,
                yaw_deg: 0.1 * n(),
                pitch_deg: 0.05 * n(),
                bank_deg: 0.05 * n(),
                att_norm_deg: 0.1 * n().abs(),
                alt_m: 7.0 * n(),
                hor_m: 50.0 * n().abs() * k as f64,
                hor_pct: if k == 0 { f64::NAN } else { 1.5 * n().abs() },
                distance_m: 300.0 * t_s / 10.0,
            }
        })
        .collect();
    RunRecord {
        scenario: 2,
        scenario_name: "synthetic".into(),
        navigation: ianav_sim::flight::NavigationMode::Truth,
        duration_s: 50.0,
        seed,
        outcome: RunOutcome::Completed {
            distance_m: 1500.0,
            samples,
            vision: Vec::new(),
        },
    }
}

fn write_runs(dir: &Path, runs: &[RunRecord]) {
    let runs_dir = dir.join(montecarlo::RUNS_DIR);
    std::fs::create_dir_all(&runs_dir).unwrap();
    for r in runs {
        std::fs::write(
            runs_dir.join(montecarlo::run_file_name(r.seed)),
            r.to_text(),
        )
        .unwrap();
    }
}

#[test]
fn report_table_holds_the_statistics_at_t_end_whatever_the_sharding() {
    let dir = temp_dir("synthetic");
    let runs: Vec<RunRecord> = (1..=9).map(synthetic_run).collect();
    write_runs(&dir.join("all"), &runs);
    // Uneven shards of scattered seeds, written in reverse order.
    let (odd, even): (Vec<RunRecord>, Vec<RunRecord>) =
        runs.iter().rev().cloned().partition(|r| r.seed % 2 == 1);
    write_runs(&dir.join("parts/a"), &odd);
    write_runs(&dir.join("parts/b"), &even);
    let all = report::report(&[dir.join("all")], &dir.join("all")).unwrap();
    report::report(&[dir.join("parts")], &dir.join("parts")).unwrap();
    let bytes = |d: &str| std::fs::read(dir.join(d).join(report::REPORT_FILE)).unwrap();
    assert_eq!(bytes("all"), bytes("parts"));

    // The table's attitude row is the statistics of the runs' last samples (as written,
    // i.e. rounded to the run files' 1e-6°), printed with 3 decimals.
    let finals: Vec<f64> = (1..=9)
        .map(|s| {
            let RunOutcome::Completed { samples, .. } = synthetic_run(s).outcome else {
                unreachable!()
            };
            let written = metrics::format_fixed(samples[5].att_norm_deg, 6);
            written.parse().unwrap()
        })
        .collect();
    let expected = stats(&finals).unwrap();
    assert_eq!(all.att_norm_deg, Some(expected));
    let text = String::from_utf8(bytes("all")).unwrap();
    let row = format!(
        "| attitude ‖Log(q_truth⁻¹ q_est)‖ | deg | {} | {} | {} |",
        metrics::format_fixed(expected.mean, 3),
        metrics::format_fixed(expected.std, 3),
        metrics::format_fixed(expected.largest, 3)
    );
    assert!(text.contains(&row), "{row}\n{text}");
    assert!(text.contains("t_end = 50.0 s"));

    // A file with the same seed but other content is an error, not a silent choice.
    let mut other = synthetic_run(3);
    if let RunOutcome::Completed { distance_m, .. } = &mut other.outcome {
        *distance_m += 1.0;
    }
    write_runs(&dir.join("parts/c"), &[other]);
    let err = report::report(&[dir.join("parts")], &dir.join("x")).unwrap_err();
    assert!(err.to_string().contains("seed 3"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `synthetic_run` with two visual systems whose final horizontal errors are known: the VNS
/// `10 × seed` m, the IA-VNS `seed` m; the IA-VNS of `lost_seed` does not track at t_end.
fn synthetic_vision_run(seed: u64, lost_seed: u64) -> RunRecord {
    let mut run = synthetic_run(seed);
    let RunOutcome::Completed {
        samples, vision, ..
    } = &mut run.outcome
    else {
        unreachable!()
    };
    let system = |name: &str, hor_m: f64, lost: bool| {
        let mut s = samples.clone();
        let last = s.last_mut().unwrap();
        last.hor_m = hor_m;
        if lost {
            *last = metrics::missing_sample(last.t_s, last.distance_m);
        }
        montecarlo::VisionRun {
            system: name.to_owned(),
            samples: s,
            initialisations: 1,
            tracking_losses: u64::from(lost),
            relocalisations: 0,
            motion_model_recoveries: 0,
            aiding: None,
        }
    };
    *vision = vec![
        system("vns", 10.0 * seed as f64, false),
        system("ia-vns", seed as f64, seed == lost_seed),
    ];
    run
}

#[test]
fn the_report_compares_every_visual_system_on_the_runs_where_all_track() {
    let dir = temp_dir("vision-report");
    // Seed 4's IA-VNS is lost at t_end: the comparison is over seeds 1–3 and 5.
    let runs: Vec<RunRecord> = (1..=5).map(|s| synthetic_vision_run(s, 4)).collect();
    write_runs(&dir, &runs);
    report::report(std::slice::from_ref(&dir), &dir).unwrap();
    let text = std::fs::read_to_string(dir.join(report::REPORT_FILE)).unwrap();
    assert!(text.contains("VNS, IA-VNS on the same 5 flights"), "{text}");
    assert!(
        text.contains("over the 4 runs where every system tracks then"),
        "{text}"
    );
    // Tracking counters: one loss in one run for the IA-VNS, 4 of 5 tracking at t_end.
    assert!(
        text.contains("| IA-VNS | 5 | 0 | 1 (1) | 0 | 0 | 4 | – | – |"),
        "{text}"
    );
    // Horizontal [m], mean (σ) over seeds 1, 2, 3, 5: VNS 27.5 (14.79), IA-VNS 2.75 (1.48).
    let hor = |name: &str| {
        let line = text
            .lines()
            .find(|l| {
                l.starts_with(&format!("| {name} | "))
                    && l.contains(" (")
                    && l.matches('|').count() == 9
            })
            .unwrap_or_else(|| panic!("no {name} row in\n{text}"));
        line.split(" | ").nth(6).unwrap().to_owned()
    };
    let std = |v: &[f64]| stats(v).unwrap();
    let (vns, ia) = (std(&[10.0, 20.0, 30.0, 50.0]), std(&[1.0, 2.0, 3.0, 5.0]));
    let cell = |s: report::Stats| {
        format!(
            "{} ({})",
            metrics::format_fixed(s.mean, 2),
            metrics::format_fixed(s.std, 2)
        )
    };
    assert_eq!(hor("VNS"), cell(vns));
    assert_eq!(hor("IA-VNS"), cell(ia));
    for png in [
        "vision_horizontal_pct.png",
        "vision_horizontal_m.png",
        "vision_attitude_norm.png",
        "vision_altitude.png",
    ] {
        assert!(dir.join(png).is_file(), "{png}");
    }
    // A run without the sections (a file cut just before them) is not merged with the others.
    write_runs(&dir, &[synthetic_run(6)]);
    let err = report::report(std::slice::from_ref(&dir), &dir).unwrap_err();
    assert!(err.to_string().contains("visual systems"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Rendering once for several systems changes none of them: each system's section of a
/// two-system flight is the section it gets flown alone, byte for byte.
#[test]
fn systems_flown_together_give_what_each_gives_alone() {
    use ianav_sim::flight::systems::VisionSystem;
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.scenario.duration_s = 10.0;
    let zone = ianav_sim::terrain::Zone::Urban;
    let start = zone.start();
    setup.scenario.start.lat_deg = start.lat_deg;
    setup.scenario.start.lon_deg = start.lon_deg;
    setup.camera = Some(ianav_sim::flight::CameraSetup::new(std::sync::Arc::new(
        ianav_sim::terrain::Terrain::new(zone, 0),
    )));
    let sections = |systems: &[VisionSystem]| {
        let mut s = setup.clone();
        s.vision_systems = systems.to_vec();
        match montecarlo::fly(2, &s, 5).outcome {
            RunOutcome::Completed { vision, .. } => vision,
            RunOutcome::Failed { reason } => panic!("{reason}"),
        }
    };
    let together = sections(&[VisionSystem::Vns, VisionSystem::IaVns]);
    let vns = sections(&[VisionSystem::Vns]);
    let ia_vns = sections(&[VisionSystem::IaVns]);
    assert_eq!(together.len(), 2);
    assert!(
        together[1].aiding.is_some_and(|a| a.inertial_starts > 0),
        "the IA-VNS never predicted from the INS: {:?}",
        together[1]
    );
    assert!(
        together[0].samples.iter().any(|s| !s.hor_m.is_nan()),
        "the VNS never tracked"
    );
    // Compared through their debug form: NaN samples (not tracking yet) are not `==`.
    let text = |v: &montecarlo::VisionRun| format!("{v:?}");
    assert_eq!(text(&together[0]), text(&vns[0]));
    assert_eq!(text(&together[1]), text(&ia_vns[0]));
    // The two differ (otherwise the comparison would prove nothing).
    assert_ne!(
        format!("{:?}", together[0].samples),
        format!("{:?}", together[1].samples)
    );
}

#[test]
fn a_departed_run_is_reported_not_fatal() {
    let dir = temp_dir("failed");
    let setup = short_setup();
    // Seed 2 starts below the envelope's −500 m floor: the flight departs at its first step.
    let mut departing = setup.clone();
    let mut mission = Flight::new(&setup, 2).unwrap().mission().clone();
    mission.hp_ini_m = -600.0;
    departing.mission_override = Some(mission);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let summary = montecarlo::run_batch_with(
        &batch(vec![1, 2, 3], None),
        &dir,
        |seed| {
            let s = if seed == 2 { &departing } else { &setup };
            montecarlo::fly(2, s, seed)
        },
        |_| {
            done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        },
    )
    .unwrap();
    assert_eq!(done.into_inner(), 3);
    assert_eq!(summary.manifest.completed, 2);
    assert_eq!(summary.manifest.failed.len(), 1);
    assert_eq!(summary.manifest.failed[0].seed, 2);
    assert!(summary.manifest.failed[0].reason.contains("departed"));
    let run2 = std::fs::read_to_string(dir.join("runs/run_0002.csv")).unwrap();
    assert!(
        run2.contains("# status = failed") && run2.contains("departed"),
        "{run2}"
    );
    let manifest = std::fs::read_to_string(&summary.manifest_path).unwrap();
    assert!(manifest.contains("seed = 2"), "{manifest}");

    let r = report::report(std::slice::from_ref(&dir), &dir).unwrap();
    assert_eq!((r.runs, r.completed), (3, 2));
    let text = std::fs::read_to_string(&r.report_path).unwrap();
    assert!(
        text.contains("3 runs (seeds 1–3): 2 completed, 1 failed"),
        "{text}"
    );
    assert!(text.contains("| 2 | flight departed"), "{text}");
    assert!(text.contains("over the 2 completed runs"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `resume` keeps the runs of the batch already written (an interrupted batch goes on), flies
/// the missing ones and anything that is not a run of this batch, and ends with the same files
/// as a batch flown in one go.
#[test]
fn a_resumed_batch_flies_only_what_is_missing() {
    let dir = temp_dir("resume");
    let (whole, resumed) = (dir.join("whole"), dir.join("resumed"));
    montecarlo::run_batch(&batch(vec![1, 2, 3], None), &whole, |_| {}).unwrap();
    // Interrupted after seed 1; seed 3's file is from another duration.
    montecarlo::run_batch(
        &batch(vec![1, 2, 3], Some("1/3".parse().unwrap())),
        &resumed,
        |_| {},
    )
    .unwrap();
    let mut other = batch(vec![1, 2, 3], Some("3/3".parse().unwrap()));
    other.setup.scenario.duration_s = SHORT_DURATION_S - 1.0;
    montecarlo::run_batch(&other, &resumed, |_| {}).unwrap();
    for shard in ["mc_shard_1of3.toml", "mc_shard_3of3.toml"] {
        std::fs::remove_file(resumed.join(shard)).unwrap();
    }
    let mut again = batch(vec![1, 2, 3], None);
    again.resume = true;
    let flown = std::sync::Mutex::new(Vec::new());
    let summary = montecarlo::run_batch_with(
        &again,
        &resumed,
        |seed| {
            flown.lock().unwrap().push(seed);
            montecarlo::fly(2, &again.setup, seed)
        },
        |_| {},
    )
    .unwrap();
    let mut flown = flown.into_inner().unwrap();
    flown.sort_unstable();
    assert_eq!(flown, vec![2, 3]);
    assert_eq!(summary.manifest.completed, 3);
    assert_eq!(files_under(&whole), files_under(&resumed));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn cli_mc_shards_and_report_and_refuses_bad_shards() {
    let dir = temp_dir("cli");
    let bin = env!("CARGO_BIN_EXE_ianav-sim");
    let out = dir.join("s1");
    let status = Command::new(bin)
        .args(["mc", "--scenario", "2", "--seeds", "5..6", "--jobs", "1"])
        .args(["--shard", "2/2", "--duration", "12", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    // Shard 2/2 of seeds [5, 6] is seed 6 only.
    assert!(out.join("runs/run_0006.csv").is_file());
    assert!(!out.join("runs/run_0005.csv").exists());
    assert!(out.join("mc_shard_2of2.toml").is_file());
    let rep = Command::new(bin).arg("report").arg(&out).output().unwrap();
    assert!(
        rep.status.success(),
        "{}",
        String::from_utf8_lossy(&rep.stderr)
    );
    assert!(out.join("report.md").is_file());
    for bad in [&["--shard", "0/2"][..], &["--seeds", "9..3"][..]] {
        let o = Command::new(bin)
            .args(["mc", "--scenario", "2", "--runs", "2", "--out"])
            .arg(dir.join("bad"))
            .args(bad)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains(bad[0]), "{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Sets a file's modification time to `t0 + secs`.
fn touch_at(path: &Path, t0: std::time::SystemTime, secs: u64) {
    std::fs::File::options()
        .write(true)
        .open(path)
        .unwrap()
        .set_modified(t0 + std::time::Duration::from_secs(secs))
        .unwrap();
}

/// A batch of 5 seeds in 3 shards, caught in progress: shard 1 ended, shard 2 started and
/// its last run file was cut at a line, shard 3 never started. The status names each shard's
/// runs to fly and estimates the time left from the files' times; `report` refuses the cut
/// file, then names the missing seeds; `--resume` flies exactly those.
#[test]
fn a_batch_in_progress_tells_its_status_and_the_report_names_what_is_missing() {
    use montecarlo::status::{self, ShardState};
    let dir = temp_dir("status");
    let (out, whole) = (dir.join("batch"), dir.join("whole"));
    let seeds: Vec<u64> = (1..=5).collect();
    let shard = |i: u32| Some(Shard { index: i, count: 3 });
    for i in [1, 2] {
        montecarlo::run_batch(&batch(seeds.clone(), shard(i)), &out, |_| {}).unwrap();
    }
    // Shard 2 (seeds 2 and 5) "dies": no manifest, seed 5 cut after its 3rd row.
    std::fs::remove_file(out.join("mc_shard_2of3.toml")).unwrap();
    let run5 = out.join("runs/run_0005.csv");
    let text = std::fs::read_to_string(&run5).unwrap();
    let rows = text
        .lines()
        .position(|l| l == montecarlo::RUN_COLUMNS)
        .unwrap()
        + 4;
    let cut: String = text.lines().take(rows).map(|l| format!("{l}\n")).collect();
    std::fs::write(&run5, cut).unwrap();
    // Times: shard 1 started at t0 and wrote a run every 4 s; shard 2 started at t0 + 20 s and
    // wrote seed 2 at t0 + 50 s (30 s per run).
    let t0 = std::time::SystemTime::now() - std::time::Duration::from_secs(600);
    touch_at(&out.join("mc_shard_1of3.plan.toml"), t0, 0);
    touch_at(&out.join("runs/run_0001.csv"), t0, 4);
    touch_at(&out.join("runs/run_0004.csv"), t0, 8);
    touch_at(&out.join("mc_shard_1of3.toml"), t0, 9);
    touch_at(&out.join("mc_shard_2of3.plan.toml"), t0, 20);
    touch_at(&out.join("runs/run_0002.csv"), t0, 50);

    let st = status::status(std::slice::from_ref(&out)).unwrap();
    assert_eq!(st.batches.len(), 1, "{st:?}");
    assert!(
        st.unplanned.is_empty() && st.unreadable.is_empty(),
        "{st:?}"
    );
    let b = &st.batches[0];
    assert_eq!((b.scenario, b.seed_range), (2, [1, 5]));
    let states: Vec<ShardState> = b.shards.iter().map(|s| s.state).collect();
    assert_eq!(
        states,
        [
            ShardState::Ended,
            ShardState::Started,
            ShardState::NotStarted
        ]
    );
    assert_eq!(b.shards[0].done, vec![1, 4]);
    assert_eq!(b.shards[1].done, vec![2]);
    let to_fly = |i: usize| -> Vec<u64> { b.shards[i].to_fly.iter().map(|t| t.0).collect() };
    assert_eq!(to_fly(0), Vec::<u64>::new());
    assert_eq!(to_fly(1), vec![5]);
    assert_eq!(to_fly(2), vec![3]);
    assert_eq!(b.shards[2].to_fly[0].1, None, "seed 3 has no file");
    let why = b.shards[1].to_fly[0].1.clone().unwrap();
    assert!(why.contains("t = 20.000 s"), "{why}");
    assert_eq!(b.totals(), (3, 0, 2));
    // Shard 1 flew a run every 4 s, shard 2 every 30 s; shard 3, not measured, at the mean
    // (17 s). The longest: shard 2's one run at its own rate, 30 s.
    let left = b.time_left().unwrap();
    assert!((left.seconds - 30.0).abs() < 1e-6, "{left:?}");
    assert!((left.per_run_s - 17.0).abs() < 1e-6, "{left:?}");
    // A fresh checkout gives every file one time: no rate, no estimate (not "0 s").
    let checkout = std::time::SystemTime::now();
    for f in std::fs::read_dir(&out)
        .unwrap()
        .chain(std::fs::read_dir(out.join("runs")).unwrap())
    {
        let path = f.unwrap().path();
        if path.is_file() {
            touch_at(&path, checkout, 0);
        }
    }
    let fresh = status::status(std::slice::from_ref(&out)).unwrap();
    assert_eq!(fresh.batches[0].time_left(), None, "{fresh:?}");
    for (f, secs) in [
        ("mc_shard_1of3.plan.toml", 0),
        ("runs/run_0001.csv", 4),
        ("runs/run_0004.csv", 8),
        ("mc_shard_1of3.toml", 9),
        ("mc_shard_2of3.plan.toml", 20),
        ("runs/run_0002.csv", 50),
    ] {
        touch_at(&out.join(f), t0, secs);
    }
    let text = st.render(std::time::SystemTime::now());
    for expected in [
        "shards with runs to fly: 2,3",
        "run_0005.csv: not a whole run",
        "time left ≈ 30 s",
        "not started",
        // Shard 2 has written nothing for 550 s, 18 times its pace.
        "ago: stalled?",
        "seeds to fly: 5\n",
    ] {
        assert!(text.contains(expected), "{expected}:\n{text}");
    }

    // The report refuses the cut file, then names the missing seeds.
    let err = report::report(std::slice::from_ref(&out), &out).unwrap_err();
    assert!(err.to_string().contains("run_0005.csv"), "{err}");
    std::fs::rename(&run5, dir.join("cut_0005.csv")).unwrap();
    let r = report::report(std::slice::from_ref(&out), &out).unwrap();
    assert_eq!(r.missing, vec![3, 5]);
    let md = std::fs::read_to_string(&r.report_path).unwrap();
    assert!(md.contains("**Incomplete batch**"), "{md}");
    assert!(md.contains("no run file: 3, 5."), "{md}");
    std::fs::rename(dir.join("cut_0005.csv"), &run5).unwrap();

    // Resuming flies the cut run, then the last shard; the batch is then whole and its files
    // those of one batch flown in one go.
    let flown = std::sync::Mutex::new(Vec::new());
    for i in [2, 3] {
        let mut again = batch(seeds.clone(), shard(i));
        again.resume = true;
        montecarlo::run_batch_with(
            &again,
            &out,
            |seed| {
                flown.lock().unwrap().push(seed);
                montecarlo::fly(2, &again.setup, seed)
            },
            |_| {},
        )
        .unwrap();
    }
    assert_eq!(flown.into_inner().unwrap(), vec![5, 3]);
    let st = status::status(std::slice::from_ref(&out)).unwrap();
    assert_eq!(st.batches[0].totals(), (5, 0, 0));
    assert!(st.render(std::time::SystemTime::now()).contains("complete"));
    montecarlo::run_batch(&batch(seeds, None), &whole, |_| {}).unwrap();
    let r = report::report(std::slice::from_ref(&out), &out).unwrap();
    report::report(std::slice::from_ref(&whole), &whole).unwrap();
    assert!(r.missing.is_empty());
    assert_eq!(files_under(&out), files_under(&whole));
    std::fs::remove_dir_all(&dir).unwrap();
}
