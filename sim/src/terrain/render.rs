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
//!   other row and column is solved and the ground points between are midpoints of their
//!   neighbours' (error ≤ 0.1 m on steep relief, mm on gentle ground; `exact_geometry` turns
//!   it off). Otherwise (grazing rays, steep desert flanks) a
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
//!   branch-free iterations (midpoints, levels of detail, texel coordinates, blends) that the
//!   compiler vectorises, solves below a block's first row run four at a time, and the main
//!   pass has an AVX2 build chosen at run time ([`MainPass`]). The Monte Carlo run files, which
//!   hold the VNS's errors on these images, stay reproducible (docs/PERFORMANCE.md).

use ianav::math::wgs84;
use ianav::vision::camera::Camera;
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::sync::{Arc, Mutex};

use super::Terrain;
use super::tiles::{
    ALBEDO_STRIDE, ALBEDO_TILE, AlbedoTile, HEIGHT_SPACING_M, HEIGHT_STRIDE, HEIGHT_TILE,
    MAX_LEVEL, TileKey,
};

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
/// Convergence of the intersection: height mismatch, m.
const TOL_H_M: f64 = 2e-3;
/// Caps of the root-finding loops.
const MAX_SECANT_ITER: usize = 60;
const MAX_MARCH_STEPS: usize = 20_000;

/// Fractional bits of the fixed-point lattice and texel coordinates: one conversion gives
/// both the cell and the interpolation weight. Weights are exact to 2⁻¹⁶ of a cell (0.1 mm of
/// height lattice, 2·10⁻⁵ of a texel): far below the 8-bit output and the 2 mm height
/// tolerance.
const FIX_BITS: u32 = 16;
const FIX_ONE: f64 = (1_u64 << FIX_BITS) as f64;
const FIX_MASK: i64 = (1 << FIX_BITS) - 1;

/// `1.5·2⁵²`: adding it to |g| < 2⁵¹ leaves `round(g)` in the low mantissa bits.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

/// `round(g)` for |g| < 2⁵¹, exactly, by the magic-number addition: three instructions where
/// the saturating `as i64` takes a dozen on x86-64 (the hot loops convert six coordinates per
/// pixel). Out of range (or NaN) gives a meaningless but finite integer, which the callers'
/// bounds checks reject.
#[inline(always)]
fn round_i64(g: f64) -> i64 {
    ((g + ROUND_MAGIC).to_bits() as i64).wrapping_sub(ROUND_MAGIC.to_bits() as i64)
}

/// Cell index and weight of the coordinate `g` (cells): `(⌊g⌋, g − ⌊g⌋)` to 2⁻¹⁶.
#[inline(always)]
fn split_fixed(g: f64) -> (i64, f64) {
    let i = round_i64(g * FIX_ONE);
    (i >> FIX_BITS, (i & FIX_MASK) as f64 * (1.0 / FIX_ONE))
}

/// Height and gradient outside the frame's tiles: direct evaluation (kept out of line so the
/// hot loop stays small).
#[cold]
#[inline(never)]
fn slow_height_grad(terrain: &Terrain, x: f64, y: f64) -> (f64, f64, f64) {
    terrain.height_grad_xy_m(x, y)
}

/// Albedo (grey levels) at mip level `level` outside the frame's tiles: direct evaluation.
#[cold]
#[inline(never)]
fn slow_albedo(terrain: &Terrain, x: f64, y: f64, level: u32) -> f32 {
    (terrain.albedo_xy(x, y, f64::from(1_u32 << level)) * 255.0) as f32
}

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
    /// every other row and column with midpoints in between (see [`BlockGeometry`]).
    pub exact_geometry: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            exposure: 1.0,
            noise_sigma_grey: 0.0,
            noise_seed: 0,
            sky_grey: 210,
            exact_geometry: false,
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
}

/// Quadratic map from the local NED offset `q` (m, from the camera) to
/// `(x − x_c, y − y_c, h)`: value, gradient and Hessian of each output.
#[derive(Debug, Clone, Copy)]
struct LocalMap {
    g0: Vector3<f64>,
    grad: [Vector3<f64>; 3],
    hess: [Matrix3<f64>; 3],
}

impl LocalMap {
    fn fit(exact: impl Fn(&Vector3<f64>) -> Vector3<f64>) -> Self {
        const S: f64 = 1_000.0;
        let f0 = exact(&Vector3::zeros());
        let e = [Vector3::x(), Vector3::y(), Vector3::z()];
        let mut grad = [Vector3::zeros(); 3];
        let mut hess = [Matrix3::zeros(); 3];
        let mut fp = [Vector3::zeros(); 3];
        let mut fm = [Vector3::zeros(); 3];
        for i in 0..3 {
            fp[i] = exact(&(e[i] * S));
            fm[i] = exact(&(-e[i] * S));
        }
        for k in 0..3 {
            for i in 0..3 {
                grad[k][i] = (fp[i][k] - fm[i][k]) / (2.0 * S);
                hess[k][(i, i)] = (fp[i][k] - 2.0 * f0[k] + fm[i][k]) / (S * S);
            }
        }
        for i in 0..3 {
            for j in (i + 1)..3 {
                let pp = exact(&((e[i] + e[j]) * S));
                let pm = exact(&((e[i] - e[j]) * S));
                let mp = exact(&((-e[i] + e[j]) * S));
                let mm = exact(&((-e[i] - e[j]) * S));
                for k in 0..3 {
                    let v = (pp[k] - pm[k] - mp[k] + mm[k]) / (4.0 * S * S);
                    hess[k][(i, j)] = v;
                    hess[k][(j, i)] = v;
                }
            }
        }
        Self { g0: f0, grad, hess }
    }
}

/// The height field of one frame: its tiles in a dense table.
struct HeightTable<'a> {
    terrain: &'a Terrain,
    /// The tiles' samples (slices of the frame's `Arc`s: one dependent load less per look-up).
    tiles: Vec<&'a [f32]>,
    ntx: i64,
    nty: i64,
    /// Lattice coordinates of the camera relative to the table origin.
    ox: f64,
    oy: f64,
    /// Camera texture coordinates (for the slow path).
    xc: f64,
    yc: f64,
    /// Whether the table holds every tile the frame's rays can reach within the slab (then
    /// its slope bound holds along every ray).
    covers_frame: bool,
}

impl HeightTable<'_> {
    /// Height and its gradient (per texture metre) at texture offsets `(x, y)`.
    #[inline(always)]
    fn height_grad(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let gx = x * (1.0 / HEIGHT_SPACING_M) + self.ox;
        let gy = y * (1.0 / HEIGHT_SPACING_M) + self.oy;
        let (ix, fx) = split_fixed(gx);
        let (iy, fy) = split_fixed(gy);
        let (tx, ty) = (
            ix >> HEIGHT_TILE.trailing_zeros(),
            iy >> HEIGHT_TILE.trailing_zeros(),
        );
        if tx < 0 || ty < 0 || tx >= self.ntx || ty >= self.nty {
            return slow_height_grad(self.terrain, self.xc + x, self.yc + y);
        }
        let h = self.tiles[(ty * self.ntx + tx) as usize];
        let lx = (ix - tx * HEIGHT_TILE as i64) as usize;
        let ly = (iy - ty * HEIGHT_TILE as i64) as usize;
        let k = ly * HEIGHT_STRIDE + lx;
        super::bilinear_grad(
            h[k],
            h[k + 1],
            h[k + HEIGHT_STRIDE],
            h[k + HEIGHT_STRIDE + 1],
            fx,
            fy,
        )
    }
}

/// Atlas of one level over a block of tiles: level, first tile (x, y), tiles along x and y.
type AtlasKey = (u32, i64, i64, i64, i64);

/// The atlases of the last frame rendered over a terrain, one per mip level: consecutive
/// 10 Hz frames mostly see the same tiles, so their atlases are shared rather than copied
/// again (a few MB per frame). An atlas is a pure function of its key: reuse changes no pixel.
#[derive(Default)]
pub struct AtlasCache(Mutex<Vec<(AtlasKey, Arc<Vec<u8>>)>>);

impl std::fmt::Debug for AtlasCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AtlasCache").finish_non_exhaustive()
    }
}

impl AtlasCache {
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<(AtlasKey, Arc<Vec<u8>>)>> {
        // Every update is a single push or replacement: a poisoned lock is still consistent.
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn get(&self, key: AtlasKey) -> Option<Arc<Vec<u8>>> {
        let g = self.lock();
        g.iter()
            .find(|(k, _)| *k == key)
            .map(|(_, d)| Arc::clone(d))
    }

    /// Keep `data` as the atlas of its level (replacing the level's previous one).
    fn put(&self, key: AtlasKey, data: Arc<Vec<u8>>) {
        let mut g = self.lock();
        match g.iter_mut().find(|(k, _)| k.0 == key.0) {
            Some(e) => *e = (key, data),
            None => g.push((key, data)),
        }
    }
}

/// The albedo of one mip level over the frame's ground: its tiles copied side by side into
/// one raster (an atlas), so that a sample is one index computation and four loads (the copy,
/// a few MB per frame, costs far less than the per-sample tile look-ups it saves).
struct AlbedoLevel {
    data: Arc<Vec<u8>>,
    /// Samples per atlas row and number of rows (tiles × 256 + 1).
    stride: usize,
    width: i64,
    height: i64,
    /// Fixed-point texel coordinates of the camera relative to the atlas origin, and
    /// fixed-point texels per metre: `2¹⁶ ×` the texel figures. Both factors are powers of
    /// two, so `x·s + o` rounds exactly as `(x·scale + ox)·2¹⁶` did: same samples, one
    /// multiplication less per coordinate.
    fox: f64,
    foy: f64,
    fscale: f64,
}

impl AlbedoLevel {
    fn new(data: Arc<Vec<u8>>, ntx: i64, nty: i64, ox: f64, oy: f64, scale: f64) -> Self {
        let stride = ntx as usize * ALBEDO_TILE + 1;
        let rows = nty as usize * ALBEDO_TILE + 1;
        Self {
            data,
            stride,
            width: stride as i64,
            height: rows as i64,
            fox: ox * FIX_ONE,
            foy: oy * FIX_ONE,
            fscale: scale * FIX_ONE,
        }
    }

    /// The atlas of `ntx × nty` tiles (row after row).
    fn build(tiles: &[Arc<AlbedoTile>], ntx: i64, nty: i64) -> Vec<u8> {
        let n = ALBEDO_TILE;
        let stride = ntx as usize * n + 1;
        let rows = nty as usize * n + 1;
        // Written once, row after row (no zeroing first). Each tile holds 257 × 257 samples;
        // neighbours share their edge samples (equal: the same texel of the same function), so
        // each tile gives its first 256 of a row, the last tile of a row all 257, and the last
        // tile row its 257th row too.
        let (ntx, nty) = (ntx as usize, nty as usize);
        let mut data = Vec::with_capacity(stride * rows);
        for row in 0..rows {
            let (ty, r) = if row == rows - 1 {
                (nty - 1, n)
            } else {
                (row / n, row % n)
            };
            for tx in 0..ntx {
                let tile = &tiles[ty * ntx + tx];
                let len = if tx + 1 == ntx { n + 1 } else { n };
                data.extend_from_slice(&tile.a[r * ALBEDO_STRIDE..r * ALBEDO_STRIDE + len]);
            }
        }
        data
    }

    fn view(&self) -> LevelView<'_> {
        LevelView {
            data: &self.data,
            stride: self.stride,
            width: self.width,
            height: self.height,
            fox: self.fox,
            foy: self.foy,
            fscale: self.fscale,
        }
    }
}

/// [`AlbedoLevel`] by value, so that the sampling loop keeps its fields in registers.
#[derive(Clone, Copy)]
struct LevelView<'a> {
    data: &'a [u8],
    stride: usize,
    width: i64,
    height: i64,
    fox: f64,
    foy: f64,
    fscale: f64,
}

impl LevelView<'_> {
    /// Fixed-point texel coordinates of the texture offsets `(x, y)`.
    #[inline(always)]
    fn fixed(&self, x: f64, y: f64) -> (i64, i64) {
        (
            round_i64(x * self.fscale + self.fox),
            round_i64(y * self.fscale + self.foy),
        )
    }

    /// Bilinear sample at fixed-point texel coordinates (from [`Self::fixed`]); `None` outside
    /// the frame's tiles.
    #[inline(always)]
    fn sample_fixed(&self, (gx, gy): (i64, i64)) -> Option<f32> {
        let (ix, iy) = (gx >> FIX_BITS, gy >> FIX_BITS);
        // One unsigned comparison per axis also rejects negative cells.
        if ix as u64 >= (self.width - 1) as u64 || iy as u64 >= (self.height - 1) as u64 {
            return None;
        }
        let k = iy as usize * self.stride + ix as usize;
        // One bounds check for the four samples (`s` is longer than `stride + 1`).
        let s = self.data.get(k..k + self.stride + 2)?;
        let wx = (gx & FIX_MASK) as f32 * (1.0 / FIX_ONE as f32);
        let wy = (gy & FIX_MASK) as f32 * (1.0 / FIX_ONE as f32);
        let (a00, a10) = (f32::from(s[0]), f32::from(s[1]));
        let (a01, a11) = (f32::from(s[self.stride]), f32::from(s[self.stride + 1]));
        let top = a00 + wx * (a10 - a00);
        let bot = a01 + wx * (a11 - a01);
        Some(top + wy * (bot - top))
    }

    /// [`Self::fixed`] and [`Self::sample_fixed`] of the points `(x, y)` (at most
    /// `4 · RUN_GROUPS`) into `out`, the same operations in three loops of independent
    /// iterations: texel indices and weights (vectorised), loads, bilinear blends
    /// (vectorised). `false` if any point falls outside the atlas.
    #[inline(always)]
    fn sample_run(&self, x: &[f64], y: &[f64], out: &mut [f32]) -> bool {
        const N: usize = 4 * RUN_GROUPS;
        let m = out.len().min(x.len()).min(y.len()).min(N);
        // Indices in u32 (vector multiplies): the atlas must be addressable so.
        if self.data.len() >= u32::MAX as usize {
            return false;
        }
        let (w1, h1) = ((self.width - 1) as u64, (self.height - 1) as u64);
        let stride = self.stride as u32;
        let mut idx = [0_u32; N];
        let mut wx = [0.0_f32; N];
        let mut wy = [0.0_f32; N];
        let mut outside = false;
        for i in 0..m {
            let (gx, gy) = self.fixed(x[i], y[i]);
            // A logical shift: a negative coordinate becomes a cell ≥ 2⁴⁷, rejected as the
            // arithmetic shift's negative cell is.
            let (ix, iy) = ((gx as u64) >> FIX_BITS, (gy as u64) >> FIX_BITS);
            outside |= (ix >= w1) | (iy >= h1);
            idx[i] = (iy as u32).wrapping_mul(stride).wrapping_add(ix as u32);
            wx[i] = ((gx & FIX_MASK) as i32) as f32 * (1.0 / FIX_ONE as f32);
            wy[i] = ((gy & FIX_MASK) as i32) as f32 * (1.0 / FIX_ONE as f32);
        }
        if outside {
            return false;
        }
        // The four texels of each point, packed a00 | a10 << 8 | a01 << 16 | a11 << 24.
        let s = self.stride;
        let mut texels = [0_u32; N];
        for i in 0..m {
            let k = idx[i] as usize;
            let Some(q) = self.data.get(k..k + s + 2) else {
                return false;
            };
            texels[i] = u32::from(q[0])
                | u32::from(q[1]) << 8
                | u32::from(q[s]) << 16
                | u32::from(q[s + 1]) << 24;
        }
        for i in 0..m {
            let p = texels[i];
            let texel = |b: u32| ((p >> b) & 0xff) as i32 as f32;
            let (a00, a10, a01, a11) = (texel(0), texel(8), texel(16), texel(24));
            let top = a00 + wx[i] * (a10 - a00);
            let bot = a01 + wx[i] * (a11 - a01);
            out[i] = top + wy[i] * (bot - top);
        }
        true
    }

    /// [`Self::fixed`] and [`Self::sample_fixed`] of four points in straight-line code (the
    /// same operations, so the same values), `None` if any of them falls outside the frame's
    /// tiles: the coordinates, bounds checks and blends of the four run side by side.
    #[inline(always)]
    fn sample4(&self, x: &[f64; 4], y: &[f64; 4]) -> Option<[f32; 4]> {
        let mut idx = [0_usize; 4];
        let mut wx = [0.0_f32; 4];
        let mut wy = [0.0_f32; 4];
        let mut outside = false;
        for i in 0..4 {
            let (gx, gy) = self.fixed(x[i], y[i]);
            let (ix, iy) = (gx >> FIX_BITS, gy >> FIX_BITS);
            outside |=
                (ix as u64 >= (self.width - 1) as u64) | (iy as u64 >= (self.height - 1) as u64);
            idx[i] = (iy as usize)
                .wrapping_mul(self.stride)
                .wrapping_add(ix as usize);
            // Below 2¹⁶: exact through i32 as through i64.
            wx[i] = ((gx & FIX_MASK) as i32) as f32 * (1.0 / FIX_ONE as f32);
            wy[i] = ((gy & FIX_MASK) as i32) as f32 * (1.0 / FIX_ONE as f32);
        }
        if outside {
            return None;
        }
        let mut a = [[0.0_f32; 4]; 4];
        for i in 0..4 {
            let s = self.data.get(idx[i]..idx[i] + self.stride + 2)?;
            a[i] = [
                f32::from(s[0]),
                f32::from(s[1]),
                f32::from(s[self.stride]),
                f32::from(s[self.stride + 1]),
            ];
        }
        let mut r = [0.0_f32; 4];
        for i in 0..4 {
            let [a00, a10, a01, a11] = a[i];
            let top = a00 + wx[i] * (a10 - a00);
            let bot = a01 + wx[i] * (a11 - a01);
            r[i] = top + wy[i] * (bot - top);
        }
        Some(r)
    }
}

/// Ray quadratics: `x(t) = cx1 t + cx2 t²`, `y` likewise, `h(t) = h0 + ch1 t + ch2 t²`.
#[derive(Debug, Clone, Copy)]
struct Ray {
    cx1: f64,
    cx2: f64,
    cy1: f64,
    cy2: f64,
    h0: f64,
    ch1: f64,
    ch2: f64,
    /// |u|² (the square root is taken only where needed: the fast path does without it).
    n2: f64,
}

impl Ray {
    /// |u|.
    #[inline]
    fn norm(&self) -> f64 {
        self.n2.sqrt()
    }

    #[inline]
    fn xyh(&self, t: f64) -> (f64, f64, f64) {
        (
            t * (self.cx1 + self.cx2 * t),
            t * (self.cy1 + self.cy2 * t),
            self.h0 + t * (self.ch1 + self.ch2 * t),
        )
    }

    /// Smallest `t ≥ 0` where the ray's height equals `level_m`, if any.
    fn cross(&self, level_m: f64) -> Option<f64> {
        let c = self.h0 - level_m;
        if c <= 0.0 {
            return Some(0.0);
        }
        let (a, b) = (self.ch2, self.ch1);
        if a.abs() < 1e-15 {
            return (b < 0.0).then(|| -c / b);
        }
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return None;
        }
        // Numerically stable roots of a t² + b t + c.
        let sq = disc.sqrt();
        let qq = -0.5 * (b + b.signum() * sq);
        let (r1, r2) = (qq / a, c / qq);
        let (lo, hi) = (r1.min(r2), r1.max(r2));
        if lo > 0.0 {
            Some(lo)
        } else if hi > 0.0 {
            Some(hi)
        } else {
            None
        }
    }
}

/// The rays of one image row: every coefficient of [`Ray`] as a polynomial in the column `u`
/// (the direction is affine in `u`), so a pixel's ray costs a few multiply-adds.
#[derive(Debug, Clone, Copy)]
struct RowRays {
    /// Linear coefficients `p + q u` of x, y, h.
    lin: [(f64, f64); 3],
    /// Quadratic coefficients `a + u (b + u c)` of x, y, h.
    quad: [(f64, f64, f64); 3],
    /// `|dir|²` as `a + u (b + u c)`.
    n2: (f64, f64, f64),
    h0: f64,
}

impl RowRays {
    fn new(map: &LocalMap, r_nc: &Matrix3<f64>, f_px: f64, cu_px: f64, y_norm: f64) -> Self {
        // dir(u) = d0 + u du with d0 = R (−c_u/f, y, 1) and du = R (1/f, 0, 0).
        let d0 = r_nc * Vector3::new(-cu_px / f_px, y_norm, 1.0);
        let du = r_nc * Vector3::new(1.0 / f_px, 0.0, 0.0);
        let mut lin = [(0.0, 0.0); 3];
        let mut quad = [(0.0, 0.0, 0.0); 3];
        for k in 0..3 {
            lin[k] = (map.grad[k].dot(&d0), map.grad[k].dot(&du));
            let hd0 = map.hess[k] * d0;
            let hdu = map.hess[k] * du;
            quad[k] = (0.5 * d0.dot(&hd0), d0.dot(&hdu), 0.5 * du.dot(&hdu));
        }
        Self {
            lin,
            quad,
            n2: (d0.dot(&d0), 2.0 * d0.dot(&du), du.dot(&du)),
            h0: map.g0[2],
        }
    }

    #[inline]
    fn at(&self, u: f64) -> Ray {
        let l = |k: usize| self.lin[k].0 + u * self.lin[k].1;
        let q = |k: usize| self.quad[k].0 + u * (self.quad[k].1 + u * self.quad[k].2);
        Ray {
            cx1: l(0),
            cx2: q(0),
            cy1: l(1),
            cy2: q(1),
            h0: self.h0,
            ch1: l(2),
            ch2: q(2),
            n2: self.n2.0 + u * (self.n2.1 + u * self.n2.2),
        }
    }
}

impl Renderer {
    /// Renderer for `camera` with the default (noise-free) options.
    pub fn new(camera: Camera) -> Self {
        Self {
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
        if !(options.noise_sigma_grey.is_finite() && options.noise_sigma_grey >= 0.0) {
            return Err(RenderError::Options(format!(
                "noise_sigma_grey {} must be ≥ 0",
                options.noise_sigma_grey
            )));
        }
        Ok(Self {
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

/// The main pass over one block of image rows: ground points, levels of detail, shading and
/// rounding. Compiled twice: for the baseline CPU and, where the CPU has them, with AVX2 and
/// its companions, under which the vectorised loops run twice as wide. Both builds perform
/// the same IEEE operations (Rust never fuses a multiply and an add on its own), so they give
/// the same bits (test `the_avx2_build_renders_the_portable_bits`).
struct MainPass<'a, F: Fn(f64) -> RowRays> {
    row_rays: &'a F,
    scene: &'a Scene<'a>,
    shade: &'a Shader<'a>,
    f_px: f64,
    wu: usize,
    image_rows: usize,
    rows_per_chunk: usize,
    interpolate: bool,
    opts: RenderOptions,
    /// Run the AVX2 build (set only where the CPU has been found to support it).
    avx2: bool,
}

/// Whether this CPU runs [`MainPass::block_avx2`].
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
            && std::arch::is_x86_feature_detected!("bmi1")
            && std::arch::is_x86_feature_detected!("bmi2")
            && std::arch::is_x86_feature_detected!("lzcnt")
            && std::arch::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

impl<F: Fn(f64) -> RowRays> MainPass<'_, F> {
    /// The grey levels of block `chunk` into `rows`; its statistics.
    fn block(&self, blk: &mut GroundBlock, chunk: usize, rows: &mut [u8]) -> RenderStats {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is true only when `has_avx2` found every feature the function is
            // compiled for on this CPU.
            #[allow(unsafe_code)]
            return unsafe { self.block_avx2(blk, chunk, rows) };
        }
        self.block_body(blk, chunk, rows)
    }

    /// [`Self::block_body`] compiled with the AVX2 features (the x86-64-v3 set less those the
    /// renderer cannot use); to be called only where the CPU has them.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    fn block_avx2(&self, blk: &mut GroundBlock, chunk: usize, rows: &mut [u8]) -> RenderStats {
        self.block_body(blk, chunk, rows)
    }

    /// The pass itself, inlined into each build.
    #[inline(always)]
    fn block_body(&self, blk: &mut GroundBlock, chunk: usize, rows: &mut [u8]) -> RenderStats {
        let rays_of_row = self.row_rays;
        let mut st = RenderStats::default();
        let v0 = chunk * self.rows_per_chunk;
        let wu = self.wu;
        let n_rows = rows.len() / wu;
        let geom = BlockGeometry {
            rays_of_row: self.row_rays,
            scene: self.scene,
            wu,
        };
        if self.interpolate {
            geom.solve_interpolated(blk, v0, n_rows, self.image_rows, &mut st);
        } else {
            for r in 0..n_rows {
                geom.solve_row(blk, r, v0 + r, 1, 1, &mut st);
            }
        }
        let ng = wu.div_ceil(4);
        // The footprint varies slowly along a row: its mip levels and blend are
        // recomputed every 4 pixels. Those levels of detail are computed first, in
        // a loop of independent iterations, so that their square root and
        // divisions overlap instead of stalling the sampling loop.
        let mut lods = std::mem::take(&mut blk.lod);
        lods.clear();
        for r in 0..n_rows {
            lods_of_row(
                &rays_of_row((v0 + r) as f64),
                blk.row(r).0,
                self.f_px,
                &mut lods,
            );
        }
        let mut vals = std::mem::take(&mut blk.vals);
        vals.clear();
        vals.resize(wu * n_rows, 0.0);
        // Shading in column strips across the block's rows, so that a strip's
        // texels can stay in the L1 cache from one row to the next even when rows
        // run along texture y (one cache line per texel row). Same pixels; no gain
        // measurable within the noise on the flights measured (docs/PERFORMANCE.md).
        for c0 in (0..wu).step_by(SHADE_STRIP) {
            let c1 = (c0 + SHADE_STRIP).min(wu);
            for r in 0..n_rows {
                let (row_t, row_x, row_y) = blk.row(r);
                self.shade.row(
                    &mut vals[r * wu + c0..r * wu + c1],
                    (&row_t[c0..c1], &row_x[c0..c1], &row_y[c0..c1]),
                    &lods[r * ng + c0 / 4..(r + 1) * ng],
                    |col, t| {
                        let ray = rays_of_row((v0 + r) as f64).at((c0 + col) as f64);
                        lod_footprint(ray.ch1, ray.ch2, ray.n2, t, self.f_px).0
                    },
                    &mut st,
                );
            }
        }
        // Noise and rounding in a loop of their own (vectorised without noise).
        let opts = &self.opts;
        if opts.noise_sigma_grey > 0.0 {
            let sigma = opts.noise_sigma_grey as f32;
            let base = chunk * self.rows_per_chunk * wu;
            for (k, (out, v)) in rows.iter_mut().zip(&vals).enumerate() {
                let n = approx_normal(opts.noise_seed, (base + k) as i64);
                *out = to_grey(v + sigma * n);
            }
        } else {
            for (out, v) in rows.iter_mut().zip(&vals) {
                *out = to_grey(*v);
            }
        }
        blk.vals = vals;
        blk.lod = lods;
        st
    }
}

/// Columns per strip of the shading (a multiple of 4: strips start new level-of-detail groups).
const SHADE_STRIP: usize = 64;

/// Groups of four pixels shaded together by [`Shader::run`] at most (a strip's).
const RUN_GROUPS: usize = SHADE_STRIP / 4;

/// Round half up to a grey level (`f32::round` is a libm call on baseline x86-64).
#[inline(always)]
fn to_grey(v: f32) -> u8 {
    (v.clamp(0.0, 255.0) + 0.5) as u8
}

/// Albedo sampling of the main pass: the frame's atlases and photometric constants.
struct Shader<'a> {
    levels: Vec<Option<LevelView<'a>>>,
    terrain: &'a Terrain,
    xc: f64,
    yc: f64,
    gain: f32,
    sky: f32,
}

impl Shader<'_> {
    /// Grey levels (before noise and rounding) of one row from its ground points `(t, x, y)`:
    /// sky where `t` is NaN, else the trilinear albedo times the gain. Pixels are shaded in
    /// groups sharing their mip levels and blend, which start at every 4th column (level of
    /// detail `lods[col / 4]`) and at the first ground pixel after sky (`lod_at(col, t)`).
    ///
    /// Runs of whole ground groups at the same mip level go through [`Self::run`] (vectorised
    /// phases); the rest, and runs with a sample outside the atlases, through
    /// [`Self::row_general`]. Both give the same values.
    #[inline(always)]
    fn row(
        &self,
        out: &mut [f32],
        (t, x, y): (&[f64], &[f64], &[f64]),
        lods: &[f64],
        lod_at: impl Fn(usize, f64) -> f64,
        st: &mut RenderStats,
    ) {
        let n = out.len().min(t.len()).min(x.len()).min(y.len());
        let ground4 = |g: usize| {
            4 * g + 4 <= n && !t[4 * g..4 * g + 4].iter().any(|v| v.is_nan()) && g < lods.len()
        };
        // Groups [g_done, g) still to be shaded by the general path.
        let mut g_done = 0;
        let mut g = 0;
        while 4 * g < n {
            if !ground4(g) {
                g += 1;
                continue;
            }
            let l0 = lods[g] as u32;
            let mut g_end = g + 1;
            while g_end - g < RUN_GROUPS && ground4(g_end) && lods[g_end] as u32 == l0 {
                g_end += 1;
            }
            let (c0, c1) = (4 * g, 4 * g_end);
            if self.run(
                l0,
                &lods[g..g_end],
                &x[c0..c1],
                &y[c0..c1],
                &mut out[c0..c1],
            ) {
                if g_done < g {
                    let (a, b) = (4 * g_done, c0);
                    self.row_general(
                        &mut out[a..b],
                        (&t[a..b], &x[a..b], &y[a..b]),
                        &lods[g_done..g],
                        |col, tc| lod_at(a + col, tc),
                        st,
                    );
                }
                st.hits += (c1 - c0) as u64;
                g_done = g_end;
            }
            g = g_end;
        }
        if 4 * g_done < n {
            let a = 4 * g_done;
            self.row_general(
                &mut out[a..n],
                (&t[a..n], &x[a..n], &y[a..n]),
                &lods[g_done..],
                |col, tc| lod_at(a + col, tc),
                st,
            );
        }
    }

    /// Grey levels of `x.len()` ground pixels (a multiple of 4, at most `4 · RUN_GROUPS`)
    /// whose groups all have mip level `l0`, their levels of detail `lods` (one per group), as
    /// [`Self::group4`] gives them, in phases of independent iterations (texel coordinates,
    /// loads, blends) that the compiler vectorises. `false` (and `out` unspecified) when a
    /// level is missing or a sample falls outside the atlases: the general path then shades
    /// these pixels.
    #[inline(always)]
    fn run(&self, l0: u32, lods: &[f64], x: &[f64], y: &[f64], out: &mut [f32]) -> bool {
        let m = out.len().min(x.len()).min(y.len()).min(4 * lods.len());
        if m == 0 || m > 4 * RUN_GROUPS {
            return false;
        }
        let l1 = (l0 + 1).min(MAX_LEVEL);
        let (Some(Some(lv0)), Some(Some(lv1))) =
            (self.levels.get(l0 as usize), self.levels.get(l1 as usize))
        else {
            return false;
        };
        // Level blend per pixel, as in `row_general`.
        let mut frac = [0.0_f32; 4 * RUN_GROUPS];
        for (f4, &lod) in frac[..m].chunks_exact_mut(4).zip(lods) {
            let mut f = (lod - f64::from(l0)) as f32;
            if f <= 1e-4 || l0 >= MAX_LEVEL {
                f = 0.0;
            }
            f4.fill(f);
        }
        let mut a0 = [0.0_f32; 4 * RUN_GROUPS];
        let mut a1 = [0.0_f32; 4 * RUN_GROUPS];
        if !(lv0.sample_run(&x[..m], &y[..m], &mut a0[..m])
            && lv1.sample_run(&x[..m], &y[..m], &mut a1[..m]))
        {
            return false;
        }
        // `(a0 + f (a1 − a0)) g`: with f = 0 exactly `a0 g`, the value of `group4` without the
        // second level.
        for i in 0..m {
            out[i] = (a0[i] + frac[i] * (a1[i] - a0[i])) * self.gain;
        }
        true
    }

    /// [`Self::row`] group by group: sky, partial groups and samples outside the atlases.
    #[inline(always)]
    fn row_general(
        &self,
        out: &mut [f32],
        (t, x, y): (&[f64], &[f64], &[f64]),
        lods: &[f64],
        lod_at: impl Fn(usize, f64) -> f64,
        st: &mut RenderStats,
    ) {
        let n = out.len().min(t.len()).min(x.len()).min(y.len());
        let mut col = 0;
        while col < n {
            if t[col].is_nan() {
                out[col] = self.sky;
                st.sky += 1;
                col += 1;
                continue;
            }
            let lod = if col % 4 == 0 {
                lods[col / 4]
            } else {
                lod_at(col, t[col])
            };
            let l0 = lod as u32;
            let mut frac = (lod - f64::from(l0)) as f32;
            if frac <= 1e-4 || l0 >= MAX_LEVEL {
                frac = 0.0;
            }
            let lv0 = self.levels[l0 as usize];
            let lv1 = self.levels[(l0 as usize + 1).min(MAX_LEVEL as usize)];
            let end = ((col / 4 + 1) * 4).min(n);
            // The group's ground pixels (sky ends the group: the outer loop shades it and
            // starts the next group).
            let mut k = 0;
            while k < end - col && !t[col + k].is_nan() {
                k += 1;
            }
            // Common case: four ground pixels, every sample inside the atlases.
            if k == 4
                && let Some(vals) = self.group4(lv0, lv1, frac, &x[col..col + 4], &y[col..col + 4])
            {
                out[col..col + 4].copy_from_slice(&vals);
                st.hits += 4;
                col += 4;
                continue;
            }
            // Texel coordinates of the whole group first, then its samples: the loads of up to
            // eight samples are issued together instead of each waiting for its own chain of
            // coordinate arithmetic.
            let mut g0 = [(0_i64, 0_i64); 4];
            let mut g1 = [(0_i64, 0_i64); 4];
            if let Some(lv) = lv0 {
                for i in 0..k {
                    g0[i] = lv.fixed(x[col + i], y[col + i]);
                }
            }
            if let Some(lv) = lv1.filter(|_| frac > 0.0) {
                for i in 0..k {
                    g1[i] = lv.fixed(x[col + i], y[col + i]);
                }
            }
            for i in 0..k {
                let (px, py) = (x[col + i], y[col + i]);
                let a0 = match lv0.and_then(|lv| lv.sample_fixed(g0[i])) {
                    Some(a) => a,
                    None => {
                        // Outside the tiles fetched for the frame: exact.
                        st.exact_albedo += 1;
                        slow_albedo(self.terrain, self.xc + px, self.yc + py, l0)
                    }
                };
                let a = if frac > 0.0 {
                    let a1 = match lv1.and_then(|lv| lv.sample_fixed(g1[i])) {
                        Some(a) => a,
                        None => {
                            st.exact_albedo += 1;
                            slow_albedo(self.terrain, self.xc + px, self.yc + py, l0 + 1)
                        }
                    };
                    a0 + frac * (a1 - a0)
                } else {
                    a0
                };
                out[col + i] = a * self.gain;
            }
            st.hits += k as u64;
            col += k;
        }
    }
}

impl Shader<'_> {
    /// Grey levels of a group of four ground pixels at `(x, y)` as [`Self::row`] gives them
    /// (same operations in the same order), or `None` when a level is missing or a sample
    /// falls outside the atlases (the general path then evaluates those exactly).
    #[inline(always)]
    fn group4(
        &self,
        lv0: Option<LevelView<'_>>,
        lv1: Option<LevelView<'_>>,
        frac: f32,
        x: &[f64],
        y: &[f64],
    ) -> Option<[f32; 4]> {
        let x: &[f64; 4] = x.try_into().ok()?;
        let y: &[f64; 4] = y.try_into().ok()?;
        let a0 = lv0?.sample4(x, y)?;
        let mut out = [0.0_f32; 4];
        if frac > 0.0 {
            let a1 = lv1?.sample4(x, y)?;
            for i in 0..4 {
                out[i] = (a0[i] + frac * (a1[i] - a0[i])) * self.gain;
            }
        } else {
            for i in 0..4 {
                out[i] = a0[i] * self.gain;
            }
        }
        Some(out)
    }
}

/// Standard normal approximation from one hash: the sum of four 16-bit uniforms (Irwin–Hall,
/// variance 1/3 after centring) scaled to unit variance. Deterministic per (seed, pixel).
#[inline]
fn approx_normal(seed: u64, idx: i64) -> f32 {
    let h = super::noise::hash2(seed, idx, 0x6e6f_6973);
    let s: f64 = (0..4).map(|k| super::noise::unit16(h, k)).sum();
    ((s - 2.0) * 3.0_f64.sqrt()) as f32
}

/// Level of detail (mip level, clamped to the levels there are) and footprint on level
/// ground, m, of the ray with height coefficients `ch1`, `ch2` and `|u|² = n2` at depth `t`.
///
/// The footprint is `t|u|/f / cos(incidence)` with `cos(incidence) = descent/|u|` floored at
/// 0.05: `t|u|²/(f·descent)`, or `t|u|/(0.05 f)` for grazing rays. Both are computed and one is
/// selected (no branch), so that [`lods_of_row`] vectorises; the values are those of the
/// branching form.
#[inline(always)]
fn lod_footprint(ch1: f64, ch2: f64, n2: f64, t: f64, f_px: f64) -> (f64, f64) {
    let descent = -(ch1 + 2.0 * ch2 * t);
    let steep = t * n2 / (f_px * descent);
    let grazing = t * n2.sqrt() / (f_px * 0.05);
    let foot_m = if descent > 0.0 && descent * descent >= 0.0025 * n2 {
        steep
    } else {
        grazing
    };
    (
        fast_log2(foot_m.max(1e-3)).clamp(0.0, f64::from(MAX_LEVEL)),
        foot_m,
    )
}

/// Levels of detail of one row at every 4th column (NaN for sky), appended to `out`: the
/// shading's mip levels and blend, which vary slowly along a row. A loop of independent,
/// branch-free iterations over contiguous depths, so that it vectorises (two divisions and a
/// square root per group of four pixels).
#[inline(always)]
fn lods_of_row(rays: &RowRays, t_row: &[f64], f_px: f64, out: &mut Vec<f64>) {
    let (h1, h1u) = rays.lin[2];
    let (h2, h2u, h2uu) = rays.quad[2];
    let (n0, nu, nuu) = rays.n2;
    let start = out.len();
    // Every 4th depth first (contiguous, so that the loop below vectorises).
    out.extend(t_row.iter().step_by(4));
    for (g, lod) in out[start..].iter_mut().enumerate() {
        let t = *lod;
        // The column as a float through i32 (which converts in vector registers).
        let u = f64::from(4 * g as i32);
        // The coefficients of `RowRays::at(u)`, same operations.
        let ch1 = h1 + u * h1u;
        let ch2 = h2 + u * (h2u + u * h2uu);
        let n2 = n0 + u * (nu + u * nuu);
        let l = lod_footprint(ch1, ch2, n2, t, f_px).0;
        *lod = if t.is_nan() { f64::NAN } else { l };
    }
}

/// Fast base-2 logarithm (|error| < 1e-4) for the mip level.
#[inline(always)]
fn fast_log2(x: f64) -> f64 {
    let bits = x.to_bits();
    // Through i32, which converts to f64 in vector registers (i64 does not before AVX-512).
    let e = (((bits >> 52) & 0x7ff) as i32) - 1023;
    let m = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000);
    // ln m = 2 atanh s, s = (m − 1)/(m + 1) ∈ [0, 1/3): four odd terms, error < 2e-5.
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let ln = 2.0 * s * (1.0 + s2 * (1.0 / 3.0 + s2 * (0.2 + s2 * (1.0 / 7.0))));
    let p = ln * std::f64::consts::LOG2_E;
    f64::from(e) + p
}

/// Pixel-to-pixel memory of a row: the last two solutions' depths.
#[derive(Debug, Clone, Copy, Default)]
struct Pred {
    t1: Option<f64>,
    t2: Option<f64>,
}

impl Pred {
    /// Linear extrapolation of the depth from the last two pixels (or the last one).
    fn guess(&self) -> Option<f64> {
        match (self.t1, self.t2) {
            (Some(a), Some(b)) => Some(2.0 * a - b),
            (Some(a), None) => Some(a),
            _ => None,
        }
    }
    fn push(&mut self, t: f64) {
        self.t2 = self.t1;
        self.t1 = Some(t);
    }
}

/// Ground points of a block of rows: depth along the optical axis (NaN for sky) and texture
/// offsets from the camera, row after row.
struct GroundBlock {
    t: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    wu: usize,
    /// Level of detail of one row at every 4th column (NaN for sky).
    lod: Vec<f64>,
    /// Grey levels of one row before noise and rounding.
    vals: Vec<f32>,
}

impl GroundBlock {
    fn new(wu: usize, rows: usize) -> Self {
        Self {
            t: vec![f64::NAN; wu * rows],
            x: vec![0.0; wu * rows],
            y: vec![0.0; wu * rows],
            wu,
            lod: Vec::with_capacity(wu.div_ceil(4)),
            vals: Vec::with_capacity(wu),
        }
    }

    fn row(&self, r: usize) -> (&[f64], &[f64], &[f64]) {
        let k = r * self.wu..(r + 1) * self.wu;
        (&self.t[k.clone()], &self.x[k.clone()], &self.y[k])
    }

    fn set(&mut self, k: usize, (t, x, y): (f64, f64, f64)) {
        self.t[k] = t;
        self.x[k] = x;
        self.y[k] = y;
    }

    /// Row `r` as the midpoints of rows `r − 1` and `r + 1`, in branch-free (vectorised) loops.
    /// A ground depth is finite, so the midpoint depth is NaN exactly where a neighbour is sky;
    /// returns whether the row has such pixels (the caller solves them).
    fn mid_row(&mut self, r: usize) -> bool {
        let wu = self.wu;
        for a in [&mut self.t, &mut self.x, &mut self.y] {
            let (head, tail) = a.split_at_mut(r * wu);
            let above = &head[(r - 1) * wu..];
            let (row, below) = tail.split_at_mut(wu);
            for ((m, &p), &q) in row.iter_mut().zip(above).zip(&below[..wu]) {
                *m = 0.5 * (p + q);
            }
        }
        any_nan(&self.t[r * wu..(r + 1) * wu])
    }

    /// The odd columns of row `r` as the midpoints of their even neighbours (but the last
    /// column), branch-free; returns whether any of them has a sky neighbour (NaN depth).
    fn mid_odd_columns(&mut self, r: usize) -> bool {
        let row = r * self.wu..(r + 1) * self.wu;
        for a in [&mut self.t, &mut self.x, &mut self.y] {
            let a = &mut a[row.clone()];
            for col in (1..a.len().saturating_sub(1)).step_by(2) {
                a[col] = 0.5 * (a[col - 1] + a[col + 1]);
            }
        }
        any_nan(&self.t[row])
    }
}

/// Whether any value is NaN (a fold without early exit, so it vectorises).
#[inline]
fn any_nan(a: &[f64]) -> bool {
    a.iter().fold(false, |any, v| any | v.is_nan())
}

/// The intersection of the rays of a block of rows with the terrain.
///
/// With interpolation, the rays of every other row and column are intersected exactly and
/// the ground points in between are the midpoints of their neighbours'. On a monotone frame
/// the ground point is a continuous function of the pixel whose derivative only jumps where
/// the ray's trace crosses an 8 m lattice edge of the bilinear height field, so over a 2-px
/// span (≈ 5 m at 2,700 m) the midpoint is off by at most a quarter of the span times that
/// jump: at 25° off nadir and a slope change of 0.2 across an edge, ~0.1 m on the ground
/// (0.05 px); on gentle terrain millimetres. Without interpolation every pixel is exact.
struct BlockGeometry<'a, F: Fn(f64) -> RowRays> {
    rays_of_row: &'a F,
    scene: &'a Scene<'a>,
    wu: usize,
}

impl<F: Fn(f64) -> RowRays> BlockGeometry<'_, F> {
    /// Exact intersections of row `r` (image row `v`) at every `step`-th column and the last
    /// one, predicted from the block's rows `r − gap` and `r − 2 gap` when they exist, else
    /// from the pixels to the left; with `step` 2 the columns between are midpoints (or exact
    /// where a neighbour is sky).
    fn solve_row(
        &self,
        blk: &mut GroundBlock,
        r: usize,
        v: usize,
        step: usize,
        gap: usize,
        st: &mut RenderStats,
    ) {
        let wu = self.wu;
        let rays = (self.rays_of_row)(v as f64);
        let mut pred = Pred::default();
        let mut col = 0;
        while col < wu {
            self.solve_at(blk, r, gap, &rays, col, &mut pred, st);
            col = next_col(col, step, wu);
        }
        if step == 2 {
            self.fill_odd(blk, r, gap, &rays, st);
        }
    }

    /// [`Self::solve_row`] with step 2 and gap 2 for the rows `rs` (block rows 2 apart, each
    /// predicted from the one before), their columns taken in turn. Row 0 of a block is
    /// predicted from the left only, one long chain of dependent solves; the solves of the
    /// rows below it hang off that chain without lengthening it, so the CPU overlaps them.
    /// Each solve sees the same guess as in row order: the same values. Rows below the block's
    /// first are solved four columns at a time ([`Self::solve_quad`]).
    fn solve_rows(&self, blk: &mut GroundBlock, rs: &[usize], v0: usize, st: &mut RenderStats) {
        let wu = self.wu;
        let n = rs.len().min(JOINT_ROWS);
        if n == 0 {
            return;
        }
        let rays: [RowRays; JOINT_ROWS] =
            std::array::from_fn(|i| (self.rays_of_row)((v0 + rs[i.min(n - 1)]) as f64));
        let mut preds = [Pred::default(); JOINT_ROWS];
        // Quads of solved columns (8 image columns), then the rest one by one.
        let quads = wu / 8;
        for q in 0..quads {
            for i in 0..n {
                if rs[i] >= 2 {
                    self.solve_quad(blk, rs[i], &rays[i], 8 * q, &mut preds[i], st);
                } else {
                    for col in (8 * q..8 * q + 8).step_by(2) {
                        self.solve_at(blk, rs[i], 2, &rays[i], col, &mut preds[i], st);
                    }
                }
            }
        }
        // The column after the quads' last (the image's last column is always solved).
        let mut col = if quads == 0 {
            0
        } else {
            next_col(8 * quads - 2, 2, wu)
        };
        while col < wu {
            for i in 0..n {
                self.solve_at(blk, rs[i], 2, &rays[i], col, &mut preds[i], st);
            }
            col = next_col(col, 2, wu);
        }
        for i in 0..n {
            self.fill_odd(blk, rs[i], 2, &rays[i], st);
        }
    }

    /// [`Self::solve_at`] (gap 2) of row `r ≥ 2` at the columns `col0, col0 + 2, col0 + 4,
    /// col0 + 6`, the same values: when all four are predicted from above (their guesses then
    /// do not depend on one another), their fast paths run side by side in straight-line code
    /// (independent chains the CPU overlaps, partly in vector registers); a column whose fast
    /// path fails is solved by [`intersect`] from its guess, as alone. Otherwise (sky above) the
    /// columns are solved one by one.
    #[inline(always)]
    fn solve_quad(
        &self,
        blk: &mut GroundBlock,
        r: usize,
        rays: &RowRays,
        col0: usize,
        pred: &mut Pred,
        st: &mut RenderStats,
    ) {
        let wu = self.wu;
        let cols = [col0, col0 + 2, col0 + 4, col0 + 6];
        let a1 = cols.map(|c| self.above(blk, r, 2, c, 1));
        if r < 2 || a1.iter().any(|t| t.is_nan()) {
            for c in cols {
                self.solve_at(blk, r, 2, rays, c, pred, st);
            }
            return;
        }
        let a2 = cols.map(|c| self.above(blk, r, 2, c, 2));
        // `predict` with a ground pixel above.
        let guess: [f64; 4] = std::array::from_fn(|i| {
            if a2[i].is_nan() {
                a1[i]
            } else {
                2.0 * a1[i] - a2[i]
            }
        });
        let fast = fast_quad(rays, &cols, &guess, self.scene.table);
        for i in 0..4 {
            let sol = match fast[i] {
                Some(sol) => {
                    st.height_lookups += 1;
                    Some(sol)
                }
                None => intersect(&rays.at(cols[i] as f64), self.scene, Some(guess[i]), st),
            };
            match sol {
                Some((t, _, _)) => pred.push(t),
                None => *pred = Pred::default(),
            }
            blk.set(r * wu + cols[i], sol.unwrap_or((f64::NAN, 0.0, 0.0)));
        }
    }

    /// Depth of row `r` at `gap · k` rows above, NaN when outside the block.
    #[inline(always)]
    fn above(&self, blk: &GroundBlock, r: usize, gap: usize, col: usize, k: usize) -> f64 {
        if r >= k * gap {
            blk.t[(r - k * gap) * self.wu + col]
        } else {
            f64::NAN
        }
    }

    /// Exact intersection of row `r` at `col`, predicted from above or from the left.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn solve_at(
        &self,
        blk: &mut GroundBlock,
        r: usize,
        gap: usize,
        rays: &RowRays,
        col: usize,
        pred: &mut Pred,
        st: &mut RenderStats,
    ) {
        let guess = predict(
            self.above(blk, r, gap, col, 1),
            self.above(blk, r, gap, col, 2),
            pred,
        );
        let sol = solve_ray(&rays.at(col as f64), self.scene, guess, pred, st);
        blk.set(r * self.wu + col, sol);
    }

    /// Odd columns of row `r` (its even ones solved): midpoints, or exact next to sky.
    fn fill_odd(
        &self,
        blk: &mut GroundBlock,
        r: usize,
        gap: usize,
        rays: &RowRays,
        st: &mut RenderStats,
    ) {
        let wu = self.wu;
        let base = r * wu;
        if !blk.mid_odd_columns(r) {
            return;
        }
        for col in (1..wu.saturating_sub(1)).step_by(2) {
            if blk.t[base + col].is_nan() {
                let guess = predict(
                    self.above(blk, r, gap, col, 1),
                    self.above(blk, r, gap, col, 2),
                    &Pred::default(),
                );
                blk.set(base + col, self.solve_alone(rays, col, guess, st));
            }
        }
    }

    /// A pixel between two solved ones that could not take their midpoint (one is sky).
    fn solve_alone(
        &self,
        rays: &RowRays,
        col: usize,
        guess: Option<f64>,
        st: &mut RenderStats,
    ) -> (f64, f64, f64) {
        solve_ray(
            &rays.at(col as f64),
            self.scene,
            guess,
            &mut Pred::default(),
            st,
        )
    }

    /// Rows `0, 2, 4, …` of the block (image rows from `v0`) solved by [`Self::solve_rows`],
    /// odd rows as midpoints of the rows above and below (the block's extra last row is the
    /// first row of the next block, solved here too; the image's last row, when odd, is
    /// solved directly).
    fn solve_interpolated(
        &self,
        blk: &mut GroundBlock,
        v0: usize,
        n_rows: usize,
        image_rows: usize,
        st: &mut RenderStats,
    ) {
        let wu = self.wu;
        let below_last = v0 + n_rows < image_rows;
        let extra = (n_rows.is_multiple_of(2) && below_last).then_some(n_rows);
        let rs: Vec<usize> = (0..n_rows).step_by(2).chain(extra).collect();
        for g in rs.chunks(JOINT_ROWS) {
            self.solve_rows(blk, g, v0, st);
        }
        for r in (1..n_rows).step_by(2) {
            if r + 1 >= n_rows && !below_last {
                self.solve_row(blk, r, v0 + r, 2, 1, st);
                continue;
            }
            if !blk.mid_row(r) {
                continue;
            }
            let rays = (self.rays_of_row)((v0 + r) as f64);
            for col in 0..wu {
                let k = r * wu + col;
                if blk.t[k].is_nan() {
                    let guess = predict(blk.t[k - wu], f64::NAN, &Pred::default());
                    blk.set(k, self.solve_alone(&rays, col, guess, st));
                }
            }
        }
    }
}

/// Next solved column after `col`: every `step`-th, and the last one.
#[inline(always)]
fn next_col(col: usize, step: usize, wu: usize) -> usize {
    if col + step < wu || col + 1 >= wu {
        col + step
    } else {
        wu - 1
    }
}

/// Solved rows taken together by [`BlockGeometry::solve_rows`]: all of a 16-row block's (its
/// even rows and the next block's first). Measured over a flight: 8–10 % less CPU per frame
/// with all of them, 6 % with pairs.
const JOINT_ROWS: usize = 9;

/// Depth prediction from the two pixels above (`a1` nearer; NaN when absent), else from the
/// pixels to the left.
#[inline(always)]
fn predict(a1: f64, a2: f64, pred: &Pred) -> Option<f64> {
    if a1.is_nan() {
        pred.guess()
    } else if a2.is_nan() {
        Some(a1)
    } else {
        Some(2.0 * a1 - a2)
    }
}

/// Intersection of one ray: `(t, x, y)`, or `(NaN, 0, 0)` for sky; updates the left-to-right
/// predictor.
#[inline(always)]
fn solve_ray(
    ray: &Ray,
    scene: &Scene<'_>,
    guess: Option<f64>,
    pred: &mut Pred,
    st: &mut RenderStats,
) -> (f64, f64, f64) {
    let sol = intersect(ray, scene, guess, st);
    match sol {
        Some((t, _, _)) => pred.push(t),
        None => *pred = Pred::default(),
    }
    sol.unwrap_or((f64::NAN, 0.0, 0.0))
}

/// Frame-wide constants of the intersection.
struct Scene<'a> {
    table: &'a HeightTable<'a>,
    h_lo: f64,
    h_hi: f64,
    slope_bound: f64,
    far_slope_bound: f64,
    /// Every ray of the frame has a strictly decreasing `f` over the slab.
    all_monotone: bool,
    camera_ground_t: Option<f64>,
}

/// Largest height mismatch accepted with one Newton correction and no further look-up, m:
/// the step is exact on a bilinear cell, and across a cell edge its error is below
/// `ACCEPT · Δslope`, a few centimetres on the ground.
const NEWTON_ACCEPT_M: f64 = 0.2;

/// `f(t)`, `f'(t)` and the texture point of the ray at `t`.
#[inline(always)]
fn eval(ray: &Ray, table: &HeightTable<'_>, t: f64, lookups: &mut u64) -> (f64, f64, f64, f64) {
    *lookups += 1;
    let (x, y, hr) = ray.xyh(t);
    let (h, hx, hy) = table.height_grad(x, y);
    let dh = ray.ch1 + 2.0 * ray.ch2 * t;
    let dx = ray.cx1 + 2.0 * ray.cx2 * t;
    let dy = ray.cy1 + 2.0 * ray.cy2 * t;
    (hr - h, dh - hx * dx - hy * dy, x, y)
}

/// The fast path of [`intersect`] (on a frame whose rays are all monotone) for the rays of
/// `rays` at four columns from their guesses, side by side: `Some((t, x, y))` where it
/// succeeds, with the values `intersect` gives; `None` where `intersect` would go on to its
/// general case.
#[inline(always)]
fn fast_quad(
    rays: &RowRays,
    cols: &[usize; 4],
    guess: &[f64; 4],
    table: &HeightTable<'_>,
) -> [Option<(f64, f64, f64)>; 4] {
    let ray: [Ray; 4] = std::array::from_fn(|i| rays.at(cols[i] as f64));
    let in_range = |t: f64, n2: f64| t > 0.0 && t * t * n2 < MAX_RANGE_M * MAX_RANGE_M;
    let mut out = [None; 4];
    let mut unused = 0;
    for i in 0..4 {
        let (ray, t0) = (&ray[i], guess[i]);
        let (f0, d0, x0, y0) = eval(ray, table, t0, &mut unused);
        let dt = -f0 / d0;
        let t1 = t0 + dt;
        if in_range(t0, ray.n2)
            && d0 < 0.0
            && f0.is_finite()
            && f0.abs() < NEWTON_ACCEPT_M
            && in_range(t1, ray.n2)
        {
            let x = x0 + (ray.cx1 + 2.0 * ray.cx2 * t0) * dt;
            let y = y0 + (ray.cy1 + 2.0 * ray.cy2 * t0) * dt;
            out[i] = Some((t1, x, y));
        }
    }
    out
}

/// Whether `f` is strictly decreasing on `[0, t_bot]` for this ray: `f' ≤ h' + L·|(x', y')|`
/// with `h' = ch1 + 2 ch2 t` and the horizontal rate at most `|(cx1, cy1)| + 2 t |(cx2, cy2)|`.
#[inline]
fn monotone(ray: &Ray, t_bot: f64, slope_bound: f64, margin: f64) -> bool {
    let hor1 = (ray.cx1 * ray.cx1 + ray.cy1 * ray.cy1).sqrt();
    let hor2 = (ray.cx2 * ray.cx2 + ray.cy2 * ray.cy2).sqrt();
    ray.ch1 + 2.0 * ray.ch2.max(0.0) * t_bot + slope_bound * (hor1 + 2.0 * hor2 * t_bot)
        < margin * ray.ch1
}

/// Intersection of `ray` with the terrain: `(t, x, y)`, or `None` for sky.
#[inline(always)]
fn intersect(
    ray: &Ray,
    sc: &Scene<'_>,
    guess: Option<f64>,
    st: &mut RenderStats,
) -> Option<(f64, f64, f64)> {
    let mut lookups = 0_u64;
    let mut start = None;
    if sc.all_monotone {
        // Fast path: one look-up at the predicted depth, one Newton step.
        // Range checks on squares: no square root on the fast path.
        let in_range = |t: f64| t > 0.0 && t * t * ray.n2 < MAX_RANGE_M * MAX_RANGE_M;
        if let Some(t0) = guess.filter(|t| in_range(*t)) {
            let (f0, d0, x0, y0) = eval(ray, sc.table, t0, &mut lookups);
            if d0 < 0.0 && f0.is_finite() {
                let dt = -f0 / d0;
                let t1 = t0 + dt;
                if f0.abs() < NEWTON_ACCEPT_M && in_range(t1) {
                    st.height_lookups += lookups;
                    // The point moves along the ray's tangent; the curvature term
                    // `c₂ δt²` of a centimetre-sized step is far below a micrometre.
                    let x = x0 + (ray.cx1 + 2.0 * ray.cx2 * t0) * dt;
                    let y = y0 + (ray.cy1 + 2.0 * ray.cy2 * t0) * dt;
                    return Some((t1, x, y));
                }
                start = Some(t1);
            }
        }
    }
    let result = intersect_slow(ray, sc, guess, start, &mut lookups, st);
    st.height_lookups += lookups;
    result
}

/// The general case of [`intersect`] (slab bracket, Newton or march), out of line so that the
/// fast path stays small.
#[inline(never)]
fn intersect_slow(
    ray: &Ray,
    sc: &Scene<'_>,
    guess: Option<f64>,
    start: Option<f64>,
    lookups: &mut u64,
    st: &mut RenderStats,
) -> Option<(f64, f64, f64)> {
    let t_far = MAX_RANGE_M / ray.norm();
    let t_top = ray.cross(sc.h_hi)?;
    if t_top >= t_far {
        return None;
    }
    let t_bot = ray.cross(sc.h_lo).map_or(t_far, |t| t.min(t_far));
    let in_table = sc.table.covers_frame;
    if t_bot < t_far && in_table && (sc.all_monotone || monotone(ray, t_bot, sc.slope_bound, 0.0)) {
        // Unique root in [t_top, t_bot].
        let guess = start
            .or(guess)
            .or(sc.camera_ground_t)
            .unwrap_or(0.5 * (t_top + t_bot));
        solve_newton(ray, sc.table, t_top, t_bot, guess, lookups)
    } else {
        st.marched += 1;
        let bound = if in_table {
            sc.slope_bound
        } else {
            sc.far_slope_bound
        };
        march(
            ray,
            sc.table,
            t_top,
            t_bot.max(t_top),
            t_far,
            bound,
            lookups,
        )
    }
}

/// Root of `f` in `[a, b]` where `f(a) ≥ 0 ≥ f(b)`: Newton steps (exact derivative of the
/// bilinear surface) kept inside the shrinking bracket, bisection when a step leaves it.
fn solve_newton(
    ray: &Ray,
    table: &HeightTable<'_>,
    mut a: f64,
    mut b: f64,
    guess: f64,
    lookups: &mut u64,
) -> Option<(f64, f64, f64)> {
    let mut t = if guess > a && guess < b {
        guess
    } else {
        0.5 * (a + b)
    };
    for _ in 0..MAX_SECANT_ITER {
        let (fv, dv, x, y) = eval(ray, table, t, lookups);
        if !fv.is_finite() {
            return None;
        }
        if fv.abs() < TOL_H_M {
            return Some((t, x, y));
        }
        if fv > 0.0 {
            a = t;
        } else {
            b = t;
        }
        if b - a <= 1e-9 * b.max(1.0) {
            return Some((t, x, y));
        }
        let tn = if dv < 0.0 { t - fv / dv } else { f64::NAN };
        t = if tn > a && tn < b { tn } else { 0.5 * (a + b) };
    }
    let (x, y, _) = ray.xyh(t);
    Some((t, x, y))
}

/// First root of `f` beyond `t_top` by a Lipschitz march: `f` can fall at most at rate
/// `D = |h'| + L |(x', y')|`, so a step of `f/D` never jumps over a crossing.
fn march(
    ray: &Ray,
    table: &HeightTable<'_>,
    t_top: f64,
    t_bot: f64,
    t_far: f64,
    slope_bound: f64,
    lookups: &mut u64,
) -> Option<(f64, f64, f64)> {
    let t_end = t_bot.max(t_top).min(t_far);
    let hor1 = (ray.cx1 * ray.cx1 + ray.cy1 * ray.cy1).sqrt();
    let hor2 = (ray.cx2 * ray.cx2 + ray.cy2 * ray.cy2).sqrt();
    let rate = ray.ch1.abs()
        + 2.0 * ray.ch2.abs() * t_end
        + slope_bound * (hor1 + 2.0 * hor2 * t_end)
        + 1e-9;
    // Smallest step: 5 cm along the ray.
    let min_step = 0.05 / ray.norm();
    let mut t = t_top;
    let (mut fv, _, x, y) = eval(ray, table, t, lookups);
    if !fv.is_finite() {
        return None;
    }
    if fv <= 0.0 {
        // Already below at the slab top (camera inside the slab, next to a wall).
        return Some((t, x, y));
    }
    for _ in 0..MAX_MARCH_STEPS {
        let t_next = (t + (fv / rate).max(min_step)).min(t_end);
        let (f_next, _, _, _) = eval(ray, table, t_next, lookups);
        if !f_next.is_finite() {
            return None;
        }
        if f_next <= 0.0 {
            return solve_newton(ray, table, t, t_next, t_next, lookups);
        }
        if t_next >= t_end {
            return None;
        }
        t = t_next;
        fv = f_next;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_point_split_matches_floor() {
        for g in [
            0.0,
            0.25,
            1.999_99,
            -0.25,
            -1.0,
            -1.5,
            123.456_789,
            -98_765.432_1,
            3.0e9,
            -3.0e9,
        ] {
            assert_eq!(round_i64(g), g.round_ties_even() as i64, "{g}");
            let (i, f) = split_fixed(g);
            assert_eq!(i, g.floor() as i64, "{g}");
            assert!((f - (g - g.floor())).abs() <= 0.5 / FIX_ONE + 1e-12, "{g}");
        }
        // Out of range: finite garbage, never a panic; bounds checks reject it.
        let _ = split_fixed(f64::NAN);
        let _ = split_fixed(1e300);
    }

    #[test]
    fn ray_slab_crossings() {
        let ray = Ray {
            cx1: 0.0,
            cx2: 0.0,
            cy1: 0.0,
            cy2: 0.0,
            h0: 1000.0,
            ch1: -1.0,
            ch2: 1e-7,
            n2: 1.0,
        };
        let t = ray.cross(200.0).unwrap();
        assert!((ray.xyh(t).2 - 200.0).abs() < 1e-9);
        assert_eq!(ray.cross(2000.0), Some(0.0));
        let up = Ray { ch1: 0.5, ..ray };
        assert_eq!(up.cross(200.0), None);
    }

    #[test]
    fn fast_log2_is_accurate() {
        for k in 0..2000 {
            let x = 1e-3 * 1.0071_f64.powi(k);
            assert!((fast_log2(x) - x.log2()).abs() < 1e-4, "{x}");
        }
    }
}
