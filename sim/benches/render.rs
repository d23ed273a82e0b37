//! Renderer benchmarks (target: ≤ 25 ms per 768 × 1024 frame on 2 cores, tile generation included,
//! amortised along a scenario #2-like flight).
//!
//! - `render/warm_nadir/<zone>`: the same nadir view again and again (all tiles cached): the
//!   cost of ray casting and albedo sampling alone.
//! - `render/path/<zone>`: consecutive 10 Hz frames along a scenario #2-like path (30 m/s at
//!   2,700 m above the start, 10° banked turns between 10–50 s straight legs); each iteration
//!   renders the next frame, generating the tiles that come into view, so tile generation is
//!   amortised over the frames exactly as in a flight.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav::vision::camera::{Camera, MountingConfig};
use ianav_sim::terrain::render::Renderer;
use ianav_sim::terrain::{Terrain, Zone};
use nalgebra::{Isometry3, Vector3};

/// Camera poses along a scenario #2-like path: frame `k` at 10 Hz.
struct Path {
    zone: Zone,
    h_m: f64,
}

impl Path {
    fn pose(&self, k: u64) -> Isometry3<f64> {
        // Piecewise: straight 30 s, then a 10°-bank turn through 120° (≈ 37 s at 30 m/s),
        // repeated; integrate heading and position at 10 Hz.
        let start = self.zone.start();
        let (mut n, mut e, mut psi) = (0.0_f64, 0.0_f64, 0.3_f64);
        let v = 30.0;
        let turn_rate = 9.81 * 10_f64.to_radians().tan() / v;
        let mut bank = 0.0;
        for i in 0..k {
            let t = i as f64 * 0.1;
            let phase = t % 67.0;
            bank = if phase < 30.0 {
                0.0
            } else {
                10_f64.to_radians()
            };
            if bank != 0.0 {
                psi += turn_rate * 0.1;
            }
            n += v * psi.cos() * 0.1;
            e += v * psi.sin() * 0.1;
        }
        let lat = start.lat_deg.to_radians() + n / wgs84::A_M;
        let lon = start.lon_deg.to_radians() + e / (wgs84::A_M * start.lat_deg.to_radians().cos());
        let pos = Geodetic {
            lat_rad: lat,
            lon_rad: lon,
            h_m: self.h_m,
        };
        let q_nb = so3::from_euler_zyx(psi, 2_f64.to_radians(), bank);
        MountingConfig::default()
            .nominal()
            .zeta_ec(&pos, &q_nb, &Vector3::zeros())
    }
}

fn bench_render(c: &mut Criterion) {
    let renderer = Renderer::new(Camera::paper());
    let mut group = c.benchmark_group("render");
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(2));
    group.measurement_time(Duration::from_secs(8));
    for zone in [Zone::Mix, Zone::Desert, Zone::Urban, Zone::Farm] {
        let terrain = Terrain::new(zone, 0);
        let start = zone.start();
        let ground = terrain.height_m(start.lat_deg.to_radians(), start.lon_deg.to_radians());
        let path = Path {
            zone,
            h_m: ground + 2_700.0,
        };
        let pose0 = path.pose(0);
        renderer.render(&terrain, &pose0).expect("render");
        let (_, st) = renderer
            .render_with_stats(&terrain, &pose0)
            .expect("render");
        eprintln!(
            "{}: warm phases: setup {:.1} ms, coarse {:.1} ms, albedo tiles {:.1} ms, main {:.1} ms; {:.2} height look-ups per pixel",
            zone.code(),
            st.setup_s * 1e3,
            st.coarse_s * 1e3,
            st.albedo_tiles_s * 1e3,
            st.main_s * 1e3,
            st.height_lookups as f64 / (768.0 * 1024.0)
        );
        group.bench_function(format!("warm_nadir/{}", zone.code()), |b| {
            b.iter(|| black_box(renderer.render(&terrain, &pose0).expect("render")))
        });
        let path_terrain = Terrain::new(zone, 1);
        let mut next = 0_u64;
        group.bench_function(format!("path/{}", zone.code()), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let pose = path.pose(next);
                    next += 1;
                    let t0 = Instant::now();
                    black_box(renderer.render(&path_terrain, &pose).expect("render"));
                    total += t0.elapsed();
                }
                total
            })
        });
        let (h, a) = path_terrain.cache_stats();
        eprintln!(
            "{}: {} frames along the path; caches: heights {} tiles ({} generated), albedo {} tiles ({} generated), {:.1} MB held",
            zone.code(),
            next,
            h.tiles,
            h.generated,
            a.tiles,
            a.generated,
            (h.bytes + a.bytes) as f64 / 1e6
        );
    }
    group.finish();
}

criterion_group!(benches, bench_render);
criterion_main!(benches);
