//! Criterion benches of the SVO front end on one textured 768 × 1024 synthetic frame:
//! building the 5-level pyramid from a camera frame (`vision::pyramid`), and grid FAST
//! detection with Shi-Tomasi scoring on levels 0–2 with every cell free (`vision::features`;
//! SVO runs it on keyframes only), and one sparse image alignment (`vision::sparse_align`,
//! levels 4 → 2) of that frame against a copy shifted by (3, 2) px.
//!
//! The frame is 6000 random grey rectangles of 3–40 px painted over one another, then a 3 × 3
//! box blur, from a fixed seed: every 64-px cell holds corners, so detection does its full work.

use std::hint::black_box;
use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use ianav::sensors::Frame;
use ianav::vision::camera::Camera;
use ianav::vision::features::{DetectorConfig, FeatureDetector};
use ianav::vision::pyramid::Pyramid;
use ianav::vision::sparse_align::{AlignFeature, SparseAlignConfig, SparseAligner};
use nalgebra::Isometry3;

/// SplitMix64 draws in `0..n`.
fn draw(state: &mut u64, n: u32) -> u32 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) % u64::from(n)) as u32
}

fn textured_frame(w: u32, h: u32) -> Frame {
    let mut state = 2026_u64;
    let mut pixels = vec![128_u8; (w * h) as usize];
    for _ in 0..6000 {
        let (sw, sh) = (3 + draw(&mut state, 38), 3 + draw(&mut state, 38));
        let x0 = draw(&mut state, w - sw + 1);
        let y0 = draw(&mut state, h - sh + 1);
        let grey = draw(&mut state, 256) as u8;
        for y in y0..y0 + sh {
            let row = (y * w) as usize;
            pixels[row + x0 as usize..row + (x0 + sw) as usize].fill(grey);
        }
    }
    let src = pixels.clone();
    let w = w as usize;
    for y in 1..h as usize - 1 {
        for x in 1..w - 1 {
            let sum: u32 = (y - 1..=y + 1)
                .flat_map(|r| (x - 1..=x + 1).map(move |c| r * w + c))
                .map(|i| u32::from(src[i]))
                .sum();
            pixels[y * w + x] = ((sum + 4) / 9) as u8;
        }
    }
    Frame {
        t_us: 0,
        width: w as u32,
        height: h,
        pixels: Arc::from(pixels),
    }
}

fn bench_vision(c: &mut Criterion) {
    let camera = Camera::paper();
    let frame = textured_frame(camera.width_px(), camera.height_px());
    let Ok(pyramid) = Pyramid::from_frame(&frame, &camera) else {
        return;
    };
    let Ok(detector) = FeatureDetector::new(DetectorConfig::default(), &camera) else {
        return;
    };
    let occupancy = detector.empty_occupancy();
    if let Ok(features) = detector.detect(&pyramid, &occupancy) {
        eprintln!(
            "vision bench: {} features in {} cells",
            features.len(),
            detector.grid().n_cells()
        );
    }
    let mut group = c.benchmark_group("vision");
    group.sample_size(30);
    group.bench_function("pyramid_768x1024_5_levels", |b| {
        b.iter(|| Pyramid::from_frame(black_box(&frame), &camera));
    });
    group.bench_function("detect_768x1024_levels_0_2", |b| {
        b.iter(|| detector.detect(black_box(&pyramid), &occupancy));
    });
    group.finish();
}

/// `frame` moved by `(dx, dy)` px (uncovered pixels mid-grey): what a camera sees after a
/// translation parallel to a fronto-parallel textured plane.
fn shifted(frame: &Frame, dx: usize, dy: usize) -> Frame {
    let w = frame.width as usize;
    let mut pixels = vec![128_u8; frame.pixels.len()];
    for (y, row) in pixels.chunks_exact_mut(w).enumerate().skip(dy) {
        let src = &frame.pixels[(y - dy) * w..(y - dy) * w + w - dx];
        row[dx..].copy_from_slice(src);
    }
    Frame {
        pixels: Arc::from(pixels),
        ..frame.clone()
    }
}

/// One sparse image alignment of a 768 × 1024 frame: the reference is the textured frame
/// with its detected features (one per 64-px cell, on a plane 1,000 m away), the current
/// frame the same shifted by (3, 2) px, the guess the reference pose (SVO 1: the last pose).
fn bench_sparse_align(c: &mut Criterion) {
    let camera = Camera::paper();
    let frame = textured_frame(camera.width_px(), camera.height_px());
    let (dx, dy) = (3, 2);
    let cur = shifted(&frame, dx, dy);
    let (Ok(ref_pyr), Ok(cur_pyr)) = (
        Pyramid::from_frame(&frame, &camera),
        Pyramid::from_frame(&cur, &camera),
    ) else {
        return;
    };
    let Ok(detector) = FeatureDetector::new(DetectorConfig::default(), &camera) else {
        return;
    };
    let Ok(detected) = detector.detect(&ref_pyr, &detector.empty_occupancy()) else {
        return;
    };
    let depth_m = 1_000.0;
    let features: Vec<AlignFeature> = detected
        .iter()
        .map(|f| AlignFeature {
            px: f.px,
            p_ref: camera.back_project_depth(&f.px, depth_m),
        })
        .collect();
    let guess = Isometry3::identity();
    let mut aligner = SparseAligner::new(SparseAlignConfig::default());
    if let Ok(r) = aligner.align(&camera, &ref_pyr, &cur_pyr, &features, &guess) {
        let scale = depth_m / camera.f_px();
        let t = r.t_cur_ref.translation.vector;
        eprintln!(
            "sparse alignment bench: {} of {} features, {} iterations, translation error \
             ({:.3}, {:.3}) px, rotation {:.2e} rad",
            r.n_features,
            features.len(),
            r.iterations,
            t.x / scale - dx as f64,
            t.y / scale - dy as f64,
            r.t_cur_ref.rotation.angle()
        );
    }
    let mut group = c.benchmark_group("vision");
    group.sample_size(50);
    group.bench_function("sparse_align_768x1024_levels_4_2", |b| {
        b.iter(|| {
            aligner.align(
                &camera,
                black_box(&ref_pyr),
                black_box(&cur_pyr),
                black_box(&features),
                &guess,
            )
        });
    });
    group.finish();
}

criterion_group!(benches, bench_vision, bench_sparse_align);
criterion_main!(benches);
