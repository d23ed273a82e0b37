//! Acceptance tests of the camera renderer over the procedural terrain: geometry against the camera
//! model, photometric consistency between overlapping views, feature content per zone (FAST-9,
//! threshold 20, 4 × 4 grid), and clean errors on bad requests.
//!
//! Ground points are found here independently of the renderer: marching along the exact ray
//! with the exact ECEF → geodetic conversion and the terrain's public height function.

use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav::vision::camera::{Camera, MountingConfig};
use ianav_sim::terrain::render::{GreyImage, RenderError, RenderOptions, Renderer};
use ianav_sim::terrain::{Marker, Terrain, TerrainError, Zone};
use nalgebra::{Isometry3, Vector2, Vector3};

/// Camera pose for a CG at `pos` with body Euler angles (degrees) and the nominal mounting.
fn pose(pos: &Geodetic, yaw_deg: f64, pitch_deg: f64, bank_deg: f64) -> Isometry3<f64> {
    let q_nb = so3::from_euler_zyx(
        yaw_deg.to_radians(),
        pitch_deg.to_radians(),
        bank_deg.to_radians(),
    );
    MountingConfig::default()
        .nominal()
        .zeta_ec(pos, &q_nb, &Vector3::zeros())
}

/// Position `agl_m` above the terrain at the zone's start, shifted `north_m`, `east_m`.
fn above(terrain: &Terrain, north_m: f64, east_m: f64, agl_m: f64) -> Geodetic {
    let s = terrain.zone().start();
    let lat = s.lat_deg.to_radians() + north_m / wgs84::A_M;
    let lon = s.lon_deg.to_radians() + east_m / (wgs84::A_M * s.lat_deg.to_radians().cos());
    Geodetic {
        lat_rad: lat,
        lon_rad: lon,
        h_m: terrain.height_m(lat, lon) + agl_m,
    }
}

/// First ground point along the ray through pixel `px` (exact geometry, no renderer code).
fn ground_point(
    terrain: &Terrain,
    zeta_ec: &Isometry3<f64>,
    cam: &Camera,
    px: &Vector2<f64>,
) -> (Geodetic, Vector3<f64>) {
    let o = zeta_ec.translation.vector;
    let dir = zeta_ec.rotation * cam.back_project(px);
    let f = |s: f64| {
        let g = wgs84::ecef_to_geodetic(&(o + dir * s));
        (g.h_m - terrain.height_m(g.lat_rad, g.lon_rad), g)
    };
    let (mut a, mut fa) = (0.0, f(0.0).0);
    assert!(fa > 0.0);
    let mut b = a;
    for _ in 0..100_000 {
        // Safe step: f falls at most (1 + slope·sin θ) per metre along the ray.
        b = a + (fa / 3.0).max(0.2);
        let (fb, _) = f(b);
        if fb <= 0.0 {
            break;
        }
        a = b;
        fa = fb;
    }
    for _ in 0..80 {
        let m = 0.5 * (a + b);
        if f(m).0 > 0.0 {
            a = m;
        } else {
            b = m;
        }
    }
    let (_, g) = f(0.5 * (a + b));
    let g = Geodetic {
        h_m: terrain.height_m(g.lat_rad, g.lon_rad),
        ..g
    };
    (g, wgs84::geodetic_to_ecef(&g))
}

/// Bilinear sample of an image at a sub-pixel position.
fn sample(img: &GreyImage, p: &Vector2<f64>) -> f64 {
    let (x0, y0) = (p.x.floor(), p.y.floor());
    let (fx, fy) = (p.x - x0, p.y - y0);
    let (x0, y0) = (x0 as u32, y0 as u32);
    let g = |x: u32, y: u32| f64::from(img.get(x, y));
    let top = g(x0, y0) * (1.0 - fx) + g(x0 + 1, y0) * fx;
    let bot = g(x0, y0 + 1) * (1.0 - fx) + g(x0 + 1, y0 + 1) * fx;
    top * (1.0 - fy) + bot * fy
}

/// Render ground markers seen by `cam` at a 4 × 4 grid of pixels over `zone` from the given
/// attitude; the worst distance between a marker's intensity centroid and where the camera
/// model (`Camera::project_ecef`, lens included) projects it, and the ECEF marker points.
fn worst_marker_error(
    cam: &Camera,
    zone: Zone,
    yaw: f64,
    pitch: f64,
    bank: f64,
) -> (f64, Isometry3<f64>, Vec<Vector3<f64>>) {
    let renderer = Renderer::new(*cam);
    let plain = Terrain::new(zone, 7);
    let pos = above(&plain, 1_500.0, -2_000.0, 2_700.0);
    let zeta_ec = pose(&pos, yaw, pitch, bank);
    let mut markers = Vec::new();
    let mut points = Vec::new();
    for j in 0..4 {
        for i in 0..4 {
            let px = Vector2::new(90.0 + 196.0 * f64::from(i), 110.0 + 268.0 * f64::from(j));
            let (g, p_e) = ground_point(&plain, &zeta_ec, cam, &px);
            markers.push(Marker {
                lat_rad: g.lat_rad,
                lon_rad: g.lon_rad,
                sigma_m: 4.0,
            });
            points.push(p_e);
        }
    }
    let terrain = Terrain::new(zone, 7).with_markers(&markers);
    let img = renderer
        .render(&terrain, &zeta_ec)
        .expect("the view renders");
    let mut worst: f64 = 0.0;
    for p_e in &points {
        let expected = cam
            .project_ecef(&zeta_ec, p_e)
            .expect("a marker in the field projects");
        // Intensity centroid above the marker's dark disc, iterated on a 6-px window.
        let mut c = expected;
        for _ in 0..4 {
            let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
            for dy in -6..=6 {
                for dx in -6..=6 {
                    let (x, y) = (c.x.round() as i64 + dx, c.y.round() as i64 + dy);
                    let (fx, fy) = (x as f64 - c.x, y as f64 - c.y);
                    if fx * fx + fy * fy > 36.0 {
                        continue;
                    }
                    let v = f64::from(img.get(x as u32, y as u32));
                    let w = (v - 0.08 * 255.0 - 4.0).max(0.0);
                    sw += w;
                    sx += w * x as f64;
                    sy += w * y as f64;
                }
            }
            assert!(sw > 1_000.0, "{zone:?}: no marker near {expected}");
            c = Vector2::new(sx / sw, sy / sw);
        }
        worst = worst.max((c - expected).norm());
    }
    (worst, zeta_ec, points)
}

#[test]
fn markers_appear_where_the_camera_model_projects_them() {
    // Desert relief (bajada and range flanks) seen with an off-nadir attitude.
    for (zone, yaw, pitch, bank) in [
        (Zone::Desert, 35.0, 6.0, 12.0),
        (Zone::Forest, -120.0, -4.0, -8.0),
    ] {
        let (worst, _, _) = worst_marker_error(&Camera::paper(), zone, yaw, pitch, bank);
        eprintln!("{zone:?}: worst marker error {worst:.3} px");
        assert!(worst < 0.5, "{zone:?}: worst marker error {worst:.3} px");
    }
}

/// A camera with lens distortion (the paper's intrinsics with a barrel radial-tangential
/// lens): the renderer draws it as a pinhole and resamples, and the markers must land where
/// the camera model with its lens projects them. Bilinear resampling of a slightly coarser
/// pinhole image moves a symmetric disc's centroid by a small fraction of a pixel: the pinhole
/// bound of 0.5 px holds. The lens moves these markers by up to ≈ 20 px, so a renderer that
/// ignored it would fail by far (asserted: more than 5 px).
#[test]
fn markers_appear_where_the_distorting_camera_projects_them() {
    use ianav::vision::camera::{CameraConfig, Intrinsics};
    use ianav::vision::lens::Distortion;
    let paper = Camera::paper();
    let c = paper.principal_point_px();
    let lens = Camera::from_config(&CameraConfig {
        calibration: Some(Intrinsics {
            fx_px: paper.fx_px(),
            fy_px: paper.fy_px(),
            cx_px: c.x,
            cy_px: c.y,
            distortion: Distortion::RadialTangential {
                k1: -0.2,
                k2: 0.05,
                p1: 1e-3,
                p2: -5e-4,
                k3: 0.0,
                k4: 0.0,
                k5: 0.0,
                k6: 0.0,
            },
        }),
        ..CameraConfig::default()
    })
    .unwrap();
    let (worst, zeta_ec, points) = worst_marker_error(&lens, Zone::Desert, 35.0, 6.0, 12.0);
    // What the lens does to these points: the same points through the pinhole.
    let moved = points
        .iter()
        .map(|p| {
            (lens.project_ecef(&zeta_ec, p).unwrap() - paper.project_ecef(&zeta_ec, p).unwrap())
                .norm()
        })
        .fold(0.0_f64, f64::max);
    eprintln!(
        "distorting lens: worst marker error {worst:.3} px; the lens moves them up to {moved:.1} px"
    );
    assert!(moved > 5.0, "the lens moves the markers by {moved} px only");
    assert!(worst < 0.5, "worst marker error {worst:.3} px");
}

/// Separable Gaussian blur, σ = 0.7 px (5 taps), borders clamped.
fn blur(img: &GreyImage) -> GreyImage {
    let k = [0.0301, 0.2326, 0.4746, 0.2326, 0.0301];
    let (w, h) = (img.width as i64, img.height as i64);
    let at =
        |x: i64, y: i64| f64::from(img.get(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32));
    let mut tmp = vec![0.0; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            tmp[(y * w + x) as usize] = (0..5).map(|i| k[i] * at(x + i as i64 - 2, y)).sum();
        }
    }
    let mut out = vec![0_u8; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let v: f64 = (0..5)
                .map(|i| k[i] * tmp[((y + i as i64 - 2).clamp(0, h - 1) * w + x) as usize])
                .sum();
            out[(y * w + x) as usize] = v.round().clamp(0.0, 255.0) as u8;
        }
    }
    GreyImage {
        width: img.width,
        height: img.height,
        pixels: out,
    }
}

/// Zero-mean normalised cross-correlation of two equal-length samples.
fn zncc(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt().max(1e-12)
}

#[test]
fn overlapping_views_agree_photometrically() {
    let cam = Camera::paper();
    let renderer = Renderer::new(cam);
    for zone in [Zone::Forest, Zone::Mix, Zone::Desert, Zone::Urban] {
        let terrain = Terrain::new(zone, 3);
        let pos1 = above(&terrain, 0.0, 0.0, 2_700.0);
        // Second pose: 100 m away (80 m north, 60 m east, level), attitude 3° apart.
        let pos2 = Geodetic {
            h_m: pos1.h_m,
            ..above(&terrain, 80.0, 60.0, 0.0)
        };
        let z1 = pose(&pos1, 20.0, 2.0, 0.0);
        let z2 = pose(&pos2, 22.0, 4.0, 1.0);
        let d_m = (z1.translation.vector - z2.translation.vector).norm();
        let d_deg = z1.rotation.angle_to(&z2.rotation).to_degrees();
        assert!(
            (d_m - 100.0).abs() < 2.0 && (d_deg - 3.0).abs() < 0.3,
            "{d_m} m {d_deg}°"
        );
        let img1 = renderer.render(&terrain, &z1).unwrap();
        let img2 = renderer.render(&terrain, &z2).unwrap();
        // Both images get the same slight blur (σ = 0.7 px) so that the bilinear resampling
        // of image 2 at sub-pixel positions does not by itself lower the correlation of
        // texture near the Nyquist frequency (image 1 is read at whole pixels).
        let (img1, img2) = (blur(&img1), blur(&img2));
        let mut scores = Vec::new();
        for j in 0..8 {
            for i in 0..6 {
                let p1 = Vector2::new(80.0 + 120.0 * f64::from(i), 90.0 + 120.0 * f64::from(j));
                // Local affine map image 1 → image 2 from three ground points.
                let q = |d: Vector2<f64>| {
                    let (_, p_e) = ground_point(&terrain, &z1, &cam, &(p1 + d));
                    cam.project_ecef(&z2, &p_e).unwrap()
                };
                let (c2, ax, ay) = (
                    q(Vector2::zeros()),
                    q(Vector2::new(6.0, 0.0)),
                    q(Vector2::new(0.0, 6.0)),
                );
                if !cam.contains(&c2, 12.0) {
                    continue;
                }
                let (ex, ey) = ((ax - c2) / 6.0, (ay - c2) / 6.0);
                let (mut a, mut b) = (Vec::new(), Vec::new());
                for dy in -7..=7 {
                    for dx in -7..=7 {
                        let (fx, fy) = (f64::from(dx), f64::from(dy));
                        a.push(f64::from(img1.get((p1.x + fx) as u32, (p1.y + fy) as u32)));
                        b.push(sample(&img2, &(c2 + ex * fx + ey * fy)));
                    }
                }
                scores.push(zncc(&a, &b));
            }
        }
        scores.sort_by(|a, b| a.total_cmp(b));
        let median = scores[scores.len() / 2];
        let frac = scores.iter().filter(|s| **s > 0.95).count() as f64 / scores.len() as f64;
        eprintln!(
            "{zone:?}: {} patches, ZNCC min {:.3} median {median:.3}, {:.0} % above 0.95",
            scores.len(),
            scores[0],
            frac * 100.0
        );
        assert!(
            scores.len() >= 30,
            "{zone:?}: too few patches in both views"
        );
        assert!(
            median > 0.95 && frac >= 0.9,
            "{zone:?}: ZNCC median {median}, {frac} above 0.95"
        );
    }
}

/// FAST-9 corners (threshold 20) of a frame and how many cells of a 4 × 4 grid hold one.
fn fast_features(img: &GreyImage) -> (usize, usize) {
    let gray =
        image::GrayImage::from_raw(img.width, img.height, img.pixels.clone()).expect("sizes match");
    let corners = imageproc::corners::corners_fast9(&gray, 20);
    let mut cells = [0_usize; 16];
    for c in &corners {
        let i = (c.x * 4 / img.width).min(3) as usize;
        let j = (c.y * 4 / img.height).min(3) as usize;
        cells[j * 4 + i] += 1;
    }
    (corners.len(), cells.iter().filter(|n| **n > 0).count())
}

#[test]
fn feature_content_per_zone() {
    let renderer = Renderer::new(Camera::paper());
    let mut rich_min = usize::MAX;
    let mut poor = Vec::new();
    eprintln!("zone | frame | FAST-9 corners | occupied cells of 4x4");
    for zone in Zone::ALL {
        let terrain = Terrain::new(zone, 0);
        // Nadir frames 2,700 m above the ground (the scenarios' pressure altitude over the
        // zone), at the start and 6 km away.
        for (k, (n, e)) in [(0.0, 0.0), (-4_000.0, 4_500.0)].into_iter().enumerate() {
            let pos = above(&terrain, n, e, 2_700.0);
            let img = renderer
                .render(&terrain, &pose(&pos, 0.0, 0.0, 0.0))
                .unwrap();
            let (count, cells) = fast_features(&img);
            eprintln!("{} | {k} | {count} | {cells}", zone.code());
            match zone {
                Zone::Forest | Zone::Mix | Zone::Desert | Zone::Urban => {
                    assert!(count >= 300, "{zone:?} frame {k}: only {count} corners");
                    assert!(
                        cells >= 12,
                        "{zone:?} frame {k}: corners in only {cells} cells"
                    );
                    rich_min = rich_min.min(count);
                }
                Zone::Farm | Zone::Prairie => poor.push((zone, k, count, cells)),
            }
        }
    }
    for (zone, k, count, cells) in poor {
        assert!(
            count * 2 < rich_min,
            "{zone:?} frame {k}: {count} corners vs {rich_min}"
        );
        assert!(
            cells <= 14,
            "{zone:?} frame {k}: no empty cells ({cells} occupied)"
        );
    }
}

#[test]
fn bad_requests_are_errors_not_panics() {
    let renderer = Renderer::new(Camera::paper());
    let terrain = Terrain::new(Zone::Desert, 0);
    let pos = above(&terrain, 0.0, 0.0, 2_700.0);
    // NaN pose.
    let mut nan = pose(&pos, 0.0, 0.0, 0.0);
    nan.translation.vector.x = f64::NAN;
    assert!(matches!(
        renderer.render(&terrain, &nan),
        Err(RenderError::NonFinitePose(_))
    ));
    let nan_att = pose(&pos, f64::NAN, 0.0, 0.0);
    assert!(matches!(
        renderer.render(&terrain, &nan_att),
        Err(RenderError::NonFinitePose(_))
    ));
    // Camera below the terrain.
    let below = Geodetic {
        h_m: terrain.height_m(pos.lat_rad, pos.lon_rad) - 3.0,
        ..pos
    };
    let err = renderer
        .render(&terrain, &pose(&below, 0.0, 0.0, 0.0))
        .unwrap_err();
    assert!(
        matches!(err, RenderError::CameraBelowTerrain { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("below the terrain"));
    // Far out in space.
    let space = Geodetic { h_m: 5.0e6, ..pos };
    assert!(matches!(
        renderer.render(&terrain, &pose(&space, 0.0, 0.0, 0.0)),
        Err(RenderError::OutOfRange(_))
    ));
    // Unknown terrain name.
    let err = "lunar".parse::<Zone>().unwrap_err();
    assert!(matches!(err, TerrainError::UnknownTerrain(_)));
    // Looking at the sky, and along the horizon from low height: they finish, sky is sky.
    let up = renderer
        .render(&terrain, &pose(&pos, 0.0, 0.0, 180.0))
        .unwrap();
    assert!(up.pixels.iter().all(|p| *p == 210));
    let low = above(&terrain, 0.0, 0.0, 500.0);
    let horizon = renderer
        .render(&terrain, &pose(&low, 45.0, 60.0, 0.0))
        .unwrap();
    assert_eq!(horizon.pixels.len(), 768 * 1024);
}

#[test]
fn a_flight_with_a_camera_delivers_10_hz_frames_from_the_true_pose() {
    use ianav::sensors::SensorEvent;
    use ianav_sim::flight::{CameraSetup, Flight, FlightObserver, FlightSetup};
    #[derive(Default)]
    struct Frames {
        t_us: Vec<u64>,
        sizes: Vec<(u32, u32, usize)>,
    }
    impl FlightObserver for Frames {
        fn sensor_event(&mut self, event: &SensorEvent) {
            if let SensorEvent::Frame(f) = event {
                self.t_us.push(f.t_us);
                self.sizes.push((f.width, f.height, f.pixels.len()));
            }
        }
    }
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.scenario.duration_s = 1.0;
    setup.scenario.warmup_s = 1.0;
    // Off by default: no frames.
    let mut none = Frames::default();
    Flight::new(&setup, 1)
        .unwrap()
        .run(&mut none, |_| {})
        .unwrap();
    assert!(none.t_us.is_empty());
    let zone = Zone::Mix;
    setup.scenario.start.lat_deg = zone.start().lat_deg;
    setup.scenario.start.lon_deg = zone.start().lon_deg;
    setup.camera = Some(CameraSetup::new(std::sync::Arc::new(Terrain::new(zone, 0))));
    let mut flight = Flight::new(&setup, 1).unwrap();
    let mounting = *flight.camera_mounting().unwrap();
    let mut frames = Frames::default();
    flight.run(&mut frames, |_| {}).unwrap();
    // Mission time 0 … 1 s at 10 Hz: 11 frames, 0.1 s apart, from the end of the warm-up.
    assert_eq!(frames.t_us.len(), 11);
    assert_eq!(frames.t_us[0], 1_000_000);
    assert!(frames.t_us.windows(2).all(|w| w[1] - w[0] == 100_000));
    assert!(frames.sizes.iter().all(|s| *s == (768, 1024, 768 * 1024)));
    // The true mounting is off nominal by about 0.1° per angle, the estimate close to it.
    let nominal = MountingConfig::default().nominal();
    let off_deg = nominal.q_bc.angle_to(&mounting.truth.q_bc).to_degrees();
    assert!(off_deg > 1e-4 && off_deg < 0.6, "{off_deg}");
}

/// The renderer intersects every other row and column exactly (or every 4th, the option) and
/// takes midpoints in between (when no ray can be occluded). Its ground points are off by at
/// most ~0.1 m on steep relief seen off nadir (a quarter of the 2-px span times the slope
/// change across a lattice edge), four times that at spacing 4 (the error grows with the
/// square of the span), millimetres on gentle ground; the band-limited albedo changes by at
/// most ~128 grey/m (an edge blurred over one 2 m texel), so a pixel may move by ≤ 13 grey in
/// the worst case (≤ 52 at spacing 4), and almost all by less than one grey level.
#[test]
fn interpolated_geometry_matches_the_exact_render() {
    for spacing in [2, 4] {
        interpolated_geometry_at_spacing_matches_the_exact_render(spacing);
    }
}

fn interpolated_geometry_at_spacing_matches_the_exact_render(spacing: usize) {
    let cam = Camera::paper();
    let fast = Renderer::with_options(
        cam,
        RenderOptions {
            solve_spacing_px: spacing,
            ..RenderOptions::default()
        },
    )
    .expect("spacing renderer");
    let exact = Renderer::with_options(
        cam,
        RenderOptions {
            exact_geometry: true,
            ..RenderOptions::default()
        },
    )
    .expect("exact renderer");
    // Views in which no ray can be occluded (steeper views of the desert ranges fall back to
    // exact intersections everywhere, which `markers_appear_…` covers).
    for (zone, yaw, pitch, bank) in [
        (Zone::Desert, 35.0, 3.0, 2.0),
        (Zone::Forest, -120.0, -4.0, -8.0),
        (Zone::Urban, 10.0, 2.0, 20.0),
    ] {
        let terrain = Terrain::new(zone, 0);
        let pos = above(&terrain, 0.0, 0.0, 2_700.0);
        let zeta_ec = pose(&pos, yaw, pitch, bank);
        let (a, st_fast) = fast.render_with_stats(&terrain, &zeta_ec).expect("render");
        let (b, st_exact) = exact.render_with_stats(&terrain, &zeta_ec).expect("render");
        // A 1/spacing² share of the pixels solved, with up to a few look-ups each.
        let fewer = (spacing * spacing / 2) as u64;
        assert!(
            st_fast.height_lookups * fewer < st_exact.height_lookups,
            "{zone:?}, spacing {spacing}: interpolation not used ({} vs {} look-ups)",
            st_fast.height_lookups,
            st_exact.height_lookups
        );
        let diffs: Vec<u8> = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .map(|(p, q)| p.abs_diff(*q))
            .collect();
        let max = diffs.iter().copied().max().unwrap_or(0);
        let above_one = diffs.iter().filter(|d| **d > 1).count() as f64 / diffs.len() as f64;
        println!(
            "{zone:?}, spacing {spacing}: interpolated vs exact geometry: max {max} grey, {:.4} % of pixels > 1 grey; look-ups {:.2} vs {:.2} per px",
            100.0 * above_one,
            st_fast.height_lookups as f64 / diffs.len() as f64,
            st_exact.height_lookups as f64 / diffs.len() as f64
        );
        let max_grey = 13 * (spacing * spacing / 4) as u8;
        assert!(
            max <= max_grey,
            "{zone:?}, spacing {spacing}: max difference {max} grey"
        );
        assert!(
            above_one < 1e-3,
            "{zone:?}, spacing {spacing}: {above_one} of pixels > 1 grey"
        );
        // The image's borders (its last column and row are solved apart from the regular
        // lattice) agree as well as the rest: a border left unsolved would carry the ground
        // points of another pixel, tens of metres away.
        let (w, h) = (a.width as usize, a.height as usize);
        let border: Vec<usize> = (0..h)
            .map(|v| v * w + w - 1)
            .chain((0..w).map(|u| (h - 1) * w + u))
            .collect();
        let border_mean =
            border.iter().map(|&k| f64::from(diffs[k])).sum::<f64>() / border.len() as f64;
        println!("{zone:?}: last column and row: mean difference {border_mean:.3} grey");
        assert!(
            border_mean < 0.5,
            "{zone:?}: borders differ by {border_mean} grey on average"
        );
    }
}

#[test]
fn the_avx2_build_renders_the_portable_bits() {
    // The main pass runs an AVX2 build where the CPU has it; both builds must give the same
    // bits (the Monte Carlo run files are reproduced across machines). Views cover the
    // interpolated and exact geometry, sky at a steep bank, sensor noise and every zone.
    let cam = Camera::paper();
    let noisy = RenderOptions {
        noise_sigma_grey: 2.0,
        noise_seed: 7,
        ..RenderOptions::default()
    };
    let exact = RenderOptions {
        exact_geometry: true,
        ..RenderOptions::default()
    };
    let spaced = RenderOptions {
        solve_spacing_px: 4,
        ..RenderOptions::default()
    };
    assert!(
        Renderer::with_options(
            cam,
            RenderOptions {
                solve_spacing_px: 3,
                ..RenderOptions::default()
            }
        )
        .is_err(),
        "a spacing other than 2 or 4 is refused"
    );
    let mut sky_seen = false;
    for (zone, yaw, pitch, bank, opts) in [
        (Zone::Mix, 0.0, 0.0, 0.0, RenderOptions::default()),
        (Zone::Urban, 10.0, 2.0, 20.0, noisy),
        (Zone::Desert, 35.0, 3.0, 2.0, exact),
        (Zone::Forest, -120.0, -4.0, -8.0, RenderOptions::default()),
        (Zone::Farm, 80.0, 5.0, 75.0, RenderOptions::default()),
        (Zone::Prairie, 200.0, -2.0, 5.0, RenderOptions::default()),
        (Zone::Mix, 50.0, 1.0, 3.0, spaced),
        (Zone::Urban, -30.0, 2.0, 70.0, spaced),
    ] {
        let terrain = Terrain::new(zone, 3);
        let pos = above(&terrain, 500.0, -300.0, 2_700.0);
        let zeta_ec = pose(&pos, yaw, pitch, bank);
        let fast = Renderer::with_options(cam, opts).unwrap();
        let (a, st) = fast.render_with_stats(&terrain, &zeta_ec).unwrap();
        let b = fast.clone().portable().render(&terrain, &zeta_ec).unwrap();
        sky_seen |= st.sky > 0;
        let differing = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .filter(|(p, q)| p != q)
            .count();
        assert_eq!(differing, 0, "{zone:?}: {differing} pixels differ");
    }
    assert!(sky_seen, "no view had sky: the sky path went untested");
}
