//! Criterion benches of the SVO front end on one textured 768 × 1024 synthetic frame:
//! building the 5-level pyramid from a camera frame (`vision::pyramid`), and grid FAST
//! detection with Shi-Tomasi scoring on levels 0–2 with every cell free (`vision::features`;
//! SVO runs it on keyframes only).
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

criterion_group!(benches, bench_vision);
criterion_main!(benches);
