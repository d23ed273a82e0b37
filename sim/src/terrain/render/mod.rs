//! Renderer of the down-looking camera's images over the procedural terrain (docs/TERRAIN.md;
//! camera of docs/REFERENCES.md A2.6).
//!
//! For every pixel the ray through its centre is intersected with the terrain height field
//! and the albedo there, band-limited to the pixel's ground footprint, is the grey level
//! (Lambertian surface under constant illumination: a terrain point has the same grey level in
//! every image). 8-bit output, rows in parallel (rayon).
//!
//! Geometry, per frame:
//! - Local NED frame at the camera, origin at the optical centre. The map from a local point
//!   `q` to (texture x, texture y, ellipsoidal height) is fitted by a quadratic (central
//!   differences of the exact ECEF → geodetic conversion, 1 km steps). Its error grows as
//!   `|q|³/R²`: < 1 mm within 3 km, < 1 m at 30 km where a pixel spans ~30 m. The Earth's
//!   curvature over the footprint is therefore exact to well below a pixel.
//! - Along a ray `q(t) = t·u` (`t` the depth along the optical axis) the three outputs are
//!   quadratics in `t`, and `f(t) = h_ray(t) − h_terrain(x(t), y(t))` is what is solved.
//! - The search interval is where the ray crosses the zone's height slab (every height lies in
//!   it by construction). If the terrain's slope bound `L` (per tile, from the lattice) is
//!   below the ray's descent rate over its horizontal rate, `f` is strictly decreasing: one
//!   root, found by one Newton step (exact gradient of the bilinear surface) from a depth
//!   predicted by the two solved pixels above (one height look-up per solved pixel), with a
//!   bracketed Newton/bisection fallback. When every ray of the frame is monotone, only every
//!   other row and column is solved (every 4th with `solve_spacing_px = 4`) and the ground
//!   points between are midpoints of their neighbours' (error ≤ 0.1 m on steep relief, ≤ 0.4 m
//!   at spacing 4, mm on gentle ground; `exact_geometry` turns it off). Otherwise (grazing
//!   rays, steep desert flanks) a
//!   Lipschitz march (steps `f/D`, `D` the largest rate at which `f` can fall) finds the first
//!   crossing without skipping any, then refines it. Every loop has a fixed cap, so the
//!   renderer always terminates; a ray that meets nothing within 15 km is sky (the frame's
//!   height tiles then always cover every ray: at most 31 × 31 tiles of 1,024 m).
//! - Band-limiting: the footprint of a pixel on the level ground, `t|u|/(f cos i)` with `i`
//!   the incidence angle, selects the mip level (trilinear interpolation between the two
//!   nearest levels, bilinear within each), so moving frames do not shimmer. A coarse pass
//!   (every 16 px) finds the levels and ground in view so that the albedo tiles are fetched
//!   before the main pass; a pixel that would still fall outside them is evaluated exactly.
//!   Each level's tiles are copied side by side into one atlas, kept for the next frame
//!   ([`AtlasCache`]), which usually sees the same tiles.
//! - Speed without changing a bit: the hot loops are split into phases of independent,
//!   branch-free iterations (the solves of rows predicted from above, midpoints, levels of
//!   detail, texel coordinates, blends) that the compiler vectorises, and the main pass,
//!   geometry included, has an AVX2 build chosen at run time (`pass::MainPass`). The Monte
//!   Carlo run files, which hold the visual systems' errors on these images, stay reproducible
//!   (docs/PERFORMANCE.md).

//!
//! The stages, one file each:
//! - `rays.rs`: the local map and each pixel's ray;
//! - `intersect.rs`: one ray against the height field (fast path, Newton, march);
//! - `ground.rs`: the ground points of a block of rows (solved pixels and midpoints);
//! - `lod.rs`: levels of detail;
//! - `atlas.rs`: the albedo atlases of a frame and their sampling; `shading.rs`: grey levels;
//! - `pass.rs`: the main pass over a block and its baseline and AVX2 builds;
//! - `fixed.rs`: the fixed-point coordinates the look-ups share.
//!
//! This file sets up a frame: the pose checks, the height tiles under the view, the coarse
//! pass that finds the mip levels in use and the albedo tiles they need, then the main pass
//! over blocks of rows in parallel.

mod atlas;
mod fixed;
mod ground;
mod intersect;
mod lens;
mod lod;
mod pass;
mod rays;
mod shading;

use ianav::math::wgs84;
use ianav::vision::camera::Camera;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

use super::Terrain;
use super::tiles::{ALBEDO_TILE, HEIGHT_SPACING_M, HEIGHT_TILE, MAX_LEVEL, TileKey};
use atlas::AlbedoLevel;
pub use atlas::AtlasCache;
use ground::GroundBlock;
use intersect::{HeightTable, Scene, intersect, monotone};
use lens::LensRemap;
use lod::lod_footprint;
use pass::{MainPass, has_avx2};
use rays::{LocalMap, Ray, RowRays};
use shading::Shader;

/// Rays that meet no terrain within this range are sky, m.
pub const MAX_RANGE_M: f64 = 15_000.0;
/// Highest camera accepted, m above the ellipsoid.
pub const MAX_CAMERA_H_M: f64 = 100_000.0;
/// Closest the camera may be to the terrain, m.
pub const MIN_CLEARANCE_M: f64 = 0.5;
/// Height-field tiles fetched per frame at most (the rest is evaluated directly, slowly).
const MAX_FRAME_HEIGHT_TILES: usize = 1_024;
/// Albedo tiles fetched per level and frame at most.
const MAX_FRAME_ALBEDO_TILES: usize = 400;

/// Errors of the renderer: bad requests get an error, never a panic or an endless loop.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The pose has a NaN or infinite component.
    #[error("camera pose is not finite: {0}")]
    NonFinitePose(String),
    /// The camera is below (or within half a metre of) the terrain.
    #[error(
        "camera below the terrain: camera at {camera_h_m:.1} m, terrain {terrain_h_m:.1} m at lat {lat_deg:.6}°, lon {lon_deg:.6}°"
    )]
    CameraBelowTerrain {
        /// Camera height above the ellipsoid, m.
        camera_h_m: f64,
        /// Terrain height there, m.
        terrain_h_m: f64,
        /// Latitude, degrees.
        lat_deg: f64,
        /// Longitude, degrees.
        lon_deg: f64,
    },
    /// The camera is too high (or deep inside the Earth) for the terrain model.
    #[error("camera height {0:.0} m is outside [-1000, {MAX_CAMERA_H_M}] m")]
    OutOfRange(f64),
    /// The render options are invalid.
    #[error("render options: {0}")]
    Options(String),
}

/// Photometric options (all off by default: noise-free, unit exposure).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Exposure gain applied to the albedo (1 = albedo 1 is grey 255).
    pub exposure: f64,
    /// Standard deviation of additive sensor noise, grey levels (0 = none).
    pub noise_sigma_grey: f64,
    /// Seed of the sensor noise of this frame.
    pub noise_seed: u64,
    /// Grey level of rays that meet no terrain.
    pub sky_grey: u8,
    /// Intersect every pixel's ray exactly (reference renders, 3× the height look-ups) instead of
    /// every `solve_spacing_px`-th row and column with midpoints in between (see
    /// `ground::BlockGeometry`).
    pub exact_geometry: bool,
    /// Rows and columns between exact intersections when interpolating: 2 (the default, the
    /// images of every committed camera result) or 4 (a quarter of the solves; interpolation
    /// error up to ~0.16 px on steep relief).
    pub solve_spacing_px: usize,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            exposure: 1.0,
            noise_sigma_grey: 0.0,
            noise_seed: 0,
            sky_grey: 210,
            exact_geometry: false,
            solve_spacing_px: 2,
        }
    }
}

/// An 8-bit grey image, row after row.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// `width × height` grey levels.
    pub pixels: Vec<u8>,
}

impl GreyImage {
    /// Grey level at column `u`, row `v`.
    pub fn get(&self, u: u32, v: u32) -> u8 {
        self.pixels[v as usize * self.width as usize + u as usize]
    }

    /// Write as an 8-bit grey PNG.
    pub fn save_png(&self, path: &std::path::Path) -> Result<(), image::ImageError> {
        image::save_buffer(
            path,
            &self.pixels,
            self.width,
            self.height,
            image::ExtendedColorType::L8,
        )
    }
}

/// Statistics of one render (for benchmarks and tests).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RenderStats {
    /// Pixels that met the terrain.
    pub hits: u64,
    /// Pixels of sky.
    pub sky: u64,
    /// Height look-ups.
    pub height_lookups: u64,
    /// Rays that needed the Lipschitz march.
    pub marched: u64,
    /// Albedo samples evaluated exactly because they fell outside the frame's tiles.
    pub exact_albedo: u64,
    /// Wall time of the set-up and height tiles, s.
    pub setup_s: f64,
    /// Wall time of the coarse pass (mip levels and ground in view), s.
    pub coarse_s: f64,
    /// Wall time of fetching (and generating) the albedo tiles, s.
    pub albedo_tiles_s: f64,
    /// Wall time of the main pass (intersection and albedo of every pixel), s.
    pub main_s: f64,
}

/// The renderer: a camera and photometric options.
#[derive(Debug, Clone)]
pub struct Renderer {
    camera: Camera,
    options: RenderOptions,
    /// Never run the AVX2 build of the main pass (tests compare the two).
    portable: bool,
    /// A camera with lens distortion: rendered as a pinhole, then resampled (`lens.rs`).
    lens: Option<Arc<LensRemap>>,
}

impl Renderer {
    /// Renderer for `camera` with the default (noise-free) options.
    pub fn new(camera: Camera) -> Self {
        Self {
            lens: LensRemap::new(&camera).map(Arc::new),
            camera,
            options: RenderOptions::default(),
            portable: false,
        }
    }

    /// Renderer with photometric options.
    pub fn with_options(camera: Camera, options: RenderOptions) -> Result<Self, RenderError> {
        if !(options.exposure.is_finite() && options.exposure > 0.0 && options.exposure < 100.0) {
            return Err(RenderError::Options(format!(
                "exposure {} must be in (0, 100)",
                options.exposure
            )));
        }
        if !matches!(options.solve_spacing_px, 2 | 4) {
            return Err(RenderError::Options(format!(
                "solve_spacing_px {} must be 2 or 4",
                options.solve_spacing_px
            )));
        }
        if !(options.noise_sigma_grey.is_finite() && options.noise_sigma_grey >= 0.0) {
            return Err(RenderError::Options(format!(
                "noise_sigma_grey {} must be ≥ 0",
                options.noise_sigma_grey
            )));
        }
        Ok(Self {
            lens: LensRemap::new(&camera).map(Arc::new),
            camera,
            options,
            portable: false,
        })
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The options.
    pub fn options(&self) -> &RenderOptions {
        &self.options
    }

    /// The same renderer restricted to the baseline-CPU build of its main pass (the AVX2 build
    /// must give the same bits; tests compare them).
    #[doc(hidden)]
    pub fn portable(mut self) -> Self {
        self.portable = true;
        self
    }

    /// Replace the noise seed (one per frame).
    pub fn set_noise_seed(&mut self, seed: u64) {
        self.options.noise_seed = seed;
    }

    /// Render the view of `terrain` from the camera pose `zeta_ec` (camera → ECEF).
    pub fn render(
        &self,
        terrain: &Terrain,
        zeta_ec: &Isometry3<f64>,
    ) -> Result<GreyImage, RenderError> {
        self.render_with_stats(terrain, zeta_ec).map(|(img, _)| img)
    }

    /// Render and report statistics.
    pub fn render_with_stats(
        &self,
        terrain: &Terrain,
        zeta_ec: &Isometry3<f64>,
    ) -> Result<(GreyImage, RenderStats), RenderError> {
        if let Some(lens) = &self.lens {
            let pinhole = Self {
                camera: lens.pinhole,
                options: self.options,
                portable: self.portable,
                lens: None,
            };
            let (img, stats) = pinhole.render_with_stats(terrain, zeta_ec)?;
            return Ok((lens.apply(&img), stats));
        }
        let clock = std::time::Instant::now();
        let t_ec_e = zeta_ec.translation.vector;
        let q_ec = zeta_ec.rotation;
        if !(t_ec_e.iter().all(|v| v.is_finite()) && q_ec.coords.iter().all(|v| v.is_finite())) {
            return Err(RenderError::NonFinitePose(format!("{zeta_ec:?}")));
        }
        // Re-normalise: a quaternion a few ulps off unit norm is still a valid attitude.
        let q_ec = UnitQuaternion::new_normalize(q_ec.into_inner());
        let cam = wgs84::ecef_to_geodetic(&t_ec_e);
        if !(cam.h_m.is_finite() && (-1_000.0..=MAX_CAMERA_H_M).contains(&cam.h_m)) {
            return Err(RenderError::OutOfRange(cam.h_m));
        }
        let ground_m = terrain.height_m(cam.lat_rad, cam.lon_rad);
        if cam.h_m < ground_m + MIN_CLEARANCE_M {
            return Err(RenderError::CameraBelowTerrain {
                camera_h_m: cam.h_m,
                terrain_h_m: ground_m,
                lat_deg: cam.lat_rad.to_degrees(),
                lon_deg: cam.lon_rad.to_degrees(),
            });
        }
        let q_en = wgs84::q_en(cam.lat_rad, cam.lon_rad);
        let r_nc = (q_en.inverse() * q_ec).to_rotation_matrix().into_inner();
        let (xc, yc) = terrain.texture_xy(cam.lat_rad, cam.lon_rad);
        let map = LocalMap::fit(|q| {
            let p = wgs84::ecef_to_geodetic(&(t_ec_e + q_en * q));
            let (x, y) = terrain.texture_xy(p.lat_rad, p.lon_rad);
            Vector3::new(x - xc, y - yc, p.h_m)
        });
        let (h_lo, h_hi) = terrain.height_bounds_m();
        let cam_model = self.camera;
        let (w, h) = (cam_model.width_px(), cam_model.height_px());
        let f_px = cam_model.f_px();
        let c_px = cam_model.principal_point_px();
        let row_rays = |v: f64| RowRays::new(&map, &r_nc, f_px, c_px.x, (v - c_px.y) / f_px);
        let make_ray = |u: f64, v: f64| row_rays(v).at(u);

        // Height tiles over the footprint of the slab (a coarse grid of rays).
        let mut bbox = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let step = 32;
        let mut us: Vec<f64> = (0..w).step_by(step).map(f64::from).collect();
        us.push(f64::from(w - 1));
        let mut vs: Vec<f64> = (0..h).step_by(step).map(f64::from).collect();
        vs.push(f64::from(h - 1));
        for &v in &vs {
            for &u in &us {
                let ray = make_ray(u, v);
                let t_far = MAX_RANGE_M / ray.norm();
                let t0 = ray.cross(h_hi).unwrap_or(t_far).min(t_far);
                let t1 = ray.cross(h_lo).unwrap_or(t_far).min(t_far);
                for t in [t0, t1] {
                    let (x, y, _) = ray.xyh(t);
                    bbox = [
                        bbox[0].min(x),
                        bbox[1].min(y),
                        bbox[2].max(x),
                        bbox[3].max(y),
                    ];
                }
            }
        }
        let tile_m = HEIGHT_SPACING_M * HEIGHT_TILE as f64;
        let margin = 2.0 * HEIGHT_SPACING_M;
        let tx0 = ((xc + bbox[0] - margin) / tile_m).floor() as i64;
        let ty0 = ((yc + bbox[1] - margin) / tile_m).floor() as i64;
        let mut ntx = ((xc + bbox[2] + margin) / tile_m).floor() as i64 - tx0 + 1;
        let mut nty = ((yc + bbox[3] + margin) / tile_m).floor() as i64 - ty0 + 1;
        let covers_frame = (ntx * nty) as usize <= MAX_FRAME_HEIGHT_TILES;
        if !covers_frame {
            // Huge footprints (views near the horizon): keep the tiles nearest the camera,
            // evaluate the far ones directly.
            let side = (MAX_FRAME_HEIGHT_TILES as f64).sqrt() as i64;
            ntx = ntx.min(side);
            nty = nty.min(side);
        }
        let tx0 = tx0
            .max((xc / tile_m).floor() as i64 - ntx / 2)
            .min(tx0 + ntx);
        let ty0 = ty0
            .max((yc / tile_m).floor() as i64 - nty / 2)
            .min(ty0 + nty);
        let keys: Vec<TileKey> = (0..nty)
            .flat_map(|j| {
                (0..ntx).map(move |i| TileKey {
                    level: 0,
                    tx: tx0 + i,
                    ty: ty0 + j,
                })
            })
            .collect();
        let tiles = terrain.height_tiles(&keys);
        let max_slope = tiles.iter().fold(0.0_f64, |m, t| m.max(t.max_slope));
        let table = HeightTable {
            terrain,
            tiles: tiles.iter().map(|t| t.h_m.as_slice()).collect(),
            ntx,
            nty,
            ox: xc / HEIGHT_SPACING_M - (tx0 * HEIGHT_TILE as i64) as f64,
            oy: yc / HEIGHT_SPACING_M - (ty0 * HEIGHT_TILE as i64) as f64,
            xc,
            yc,
            covers_frame,
        };

        // Beyond the table the slope is not bounded by its tiles: use a generous bound.
        let slope_bound = max_slope.max(1e-3) * 1.001 + 1e-6;
        let far_slope_bound = slope_bound.max(20.0);

        // Every ray monotone? The off-nadir angle peaks on the image border (rays within a
        // cone about the vertical form a convex set), so checking the border rays with a
        // margin settles it for the whole frame.
        let all_monotone = covers_frame && {
            let mut ok = true;
            let border = (0..w)
                .step_by(4)
                .flat_map(|u| [(f64::from(u), 0.0), (f64::from(u), f64::from(h - 1))])
                .chain(
                    (0..h)
                        .step_by(4)
                        .flat_map(|v| [(0.0, f64::from(v)), (f64::from(w - 1), f64::from(v))]),
                );
            for (u, v) in border {
                let ray = make_ray(u, v);
                let t_far = MAX_RANGE_M / ray.norm();
                match ray.cross(h_lo) {
                    Some(t_bot) if t_bot < t_far && monotone(&ray, t_bot, slope_bound, 0.05) => {}
                    _ => {
                        ok = false;
                        break;
                    }
                }
            }
            ok
        };

        // Coarse pass: intersections every COARSE px give the mip levels in use and the
        // ground each of them covers, so the albedo tiles are fetched before the main pass.
        let t_setup = clock.elapsed().as_secs_f64();
        let n_px = (w as usize) * (h as usize);
        let rows_per_chunk = 16;
        let camera_ground_t = {
            // Depth of the ground straight below along the optical axis, for the first
            // prediction of each chunk.
            let ray = make_ray(c_px.x, c_px.y);
            ray.cross(ground_m)
        };
        let scene = Scene {
            table: &table,
            h_lo,
            h_hi,
            slope_bound,
            far_slope_bound,
            all_monotone,
            camera_ground_t,
        };
        let lod_of = |ray: &Ray, t: f64| lod_footprint(ray.ch1, ray.ch2, ray.n2, t, f_px);
        const COARSE: u32 = 16;
        let coarse: Vec<(RenderStats, [[f64; 4]; (MAX_LEVEL + 1) as usize])> = (0..h)
            .step_by(COARSE as usize)
            .chain(std::iter::once(h - 1))
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|v| {
                let mut st = RenderStats::default();
                let mut bb = [[
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ]; (MAX_LEVEL + 1) as usize];
                let rays = row_rays(f64::from(v));
                for u in (0..w)
                    .step_by(COARSE as usize)
                    .chain(std::iter::once(w - 1))
                {
                    let ray = rays.at(f64::from(u));
                    let Some((t, x, y)) = intersect(&ray, &scene, None, &mut st) else {
                        continue;
                    };
                    let (lod, foot_m) = lod_of(&ray, t);
                    // Pixels up to a coarse cell away: margin of 1.5 cells of footprint; their
                    // level of detail differs by a few hundredths at most (it varies slowly),
                    // so the levels needed are those of lod ± 0.05.
                    let m = 1.5 * f64::from(COARSE) * foot_m;
                    let lo = (lod - 0.05).max(0.0) as i64;
                    let hi = (lod + 0.05) as i64 + 1;
                    for l in lo.max(0)..=hi.min(i64::from(MAX_LEVEL)) {
                        let b = &mut bb[l as usize];
                        *b = [
                            b[0].min(x - m),
                            b[1].min(y - m),
                            b[2].max(x + m),
                            b[3].max(y + m),
                        ];
                    }
                }
                (st, bb)
            })
            .collect();
        let mut lvl_bbox = [[
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ]; (MAX_LEVEL + 1) as usize];
        for (_, b) in &coarse {
            for l in 0..=MAX_LEVEL as usize {
                let a = &mut lvl_bbox[l];
                *a = [
                    a[0].min(b[l][0]),
                    a[1].min(b[l][1]),
                    a[2].max(b[l][2]),
                    a[3].max(b[l][3]),
                ];
            }
        }
        let t_geometry = clock.elapsed().as_secs_f64();

        // Albedo tiles of every level in use.
        let mut levels: Vec<Option<AlbedoLevel>> = (0..=MAX_LEVEL).map(|_| None).collect();
        let mut all_keys = Vec::new();
        let mut spans = Vec::new();
        for l in 0..=MAX_LEVEL {
            let b = lvl_bbox[l as usize];
            // Empty (never updated) boxes keep min > max.
            if b[0] > b[2] || b[0].is_nan() {
                continue;
            }
            let texel = f64::from(1_u32 << l);
            let scale = 1.0 / texel;
            let tile_m = texel * ALBEDO_TILE as f64;
            let m = 2.0 * texel;
            let tx0 = ((xc + b[0] - m) / tile_m).floor() as i64;
            let ty0 = ((yc + b[1] - m) / tile_m).floor() as i64;
            let mut ntx = ((xc + b[2] + m) / tile_m).floor() as i64 - tx0 + 1;
            let mut nty = ((yc + b[3] + m) / tile_m).floor() as i64 - ty0 + 1;
            if (ntx * nty) as usize > MAX_FRAME_ALBEDO_TILES {
                let side = (MAX_FRAME_ALBEDO_TILES as f64).sqrt() as i64;
                ntx = ntx.min(side);
                nty = nty.min(side);
            }
            let first = all_keys.len();
            for j in 0..nty {
                for i in 0..ntx {
                    all_keys.push(TileKey {
                        level: l,
                        tx: tx0 + i,
                        ty: ty0 + j,
                    });
                }
            }
            spans.push((l, first, all_keys.len(), tx0, ty0, ntx, nty, scale));
        }
        let mut albedo_tiles = terrain.albedo_tiles(&all_keys).into_iter();
        for (l, first, last, tx0, ty0, ntx, nty, scale) in spans {
            let tiles: Vec<_> = albedo_tiles.by_ref().take(last - first).collect();
            let key = (l, tx0, ty0, ntx, nty);
            let data = terrain.atlases.get(key).unwrap_or_else(|| {
                let data = Arc::new(AlbedoLevel::build(&tiles, ntx, nty));
                terrain.atlases.put(key, Arc::clone(&data));
                data
            });
            levels[l as usize] = Some(AlbedoLevel::new(
                data,
                ntx,
                nty,
                // Texel centres at (i + ½)·texel: s = x/texel − ½.
                xc * scale - 0.5 - (tx0 * ALBEDO_TILE as i64) as f64,
                yc * scale - 0.5 - (ty0 * ALBEDO_TILE as i64) as f64,
                scale,
            ));
        }
        let t_tiles = clock.elapsed().as_secs_f64();

        // Main pass, in blocks of rows: the ground point of every pixel, then the albedo at
        // its mip level.
        let opts = self.options;
        let gain = opts.exposure as f32;
        let wu = w as usize;
        // Interpolating ground points between solved pixels needs a unique intersection that
        // moves continuously with the pixel: true when every ray is monotone (no occlusion).
        let interpolate = scene.all_monotone && !self.options.exact_geometry;

        let shade = Shader {
            levels: levels
                .iter()
                .map(|l| l.as_ref().map(AlbedoLevel::view))
                .collect(),
            terrain,
            xc,
            yc,
            gain,
            sky: f32::from(opts.sky_grey),
        };
        let pass = MainPass {
            row_rays: &row_rays,
            scene: &scene,
            shade: &shade,
            f_px,
            wu,
            image_rows: h as usize,
            rows_per_chunk,
            interpolate,
            opts,
            avx2: !self.portable && has_avx2(),
        };
        let mut pixels = vec![0_u8; n_px];
        let stats: Vec<RenderStats> = pixels
            .par_chunks_mut(wu * rows_per_chunk)
            .enumerate()
            // One block buffer per worker, with an extra row below the block for the
            // interpolation of its last row; every value read is written first in each block.
            .map_init(
                || GroundBlock::new(wu, rows_per_chunk + 1),
                |blk, (chunk, rows)| pass.block(blk, chunk, rows),
            )
            .collect();
        let mut total = RenderStats::default();
        for st in stats.iter().chain(coarse.iter().map(|c| &c.0)) {
            total.hits += st.hits;
            total.sky += st.sky;
            total.height_lookups += st.height_lookups;
            total.marched += st.marched;
            total.exact_albedo += st.exact_albedo;
        }
        total.hits -= coarse.iter().map(|c| c.0.hits).sum::<u64>();
        total.sky -= coarse.iter().map(|c| c.0.sky).sum::<u64>();
        let t_end = clock.elapsed().as_secs_f64();
        total.setup_s = t_setup;
        total.coarse_s = t_geometry - t_setup;
        total.albedo_tiles_s = t_tiles - t_geometry;
        total.main_s = t_end - t_tiles;
        Ok((
            GreyImage {
                width: w,
                height: h,
                pixels,
            },
            total,
        ))
    }
}
