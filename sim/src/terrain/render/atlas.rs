//! The albedo of one mip level over a frame's ground as one raster (an atlas of its tiles), the
//! cache that hands it to the next frame, and bilinear sampling in fixed point.

use std::sync::{Arc, Mutex};

use super::super::tiles::{ALBEDO_STRIDE, ALBEDO_TILE, AlbedoTile};
use super::fixed::{FIX_BITS, FIX_MASK, FIX_ONE, round_i64};
use super::shading::RUN_GROUPS;

/// Atlas of one level over a block of tiles: level, first tile (x, y), tiles along x and y.
pub(super) type AtlasKey = (u32, i64, i64, i64, i64);

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
    pub(super) fn lock(&self) -> std::sync::MutexGuard<'_, Vec<(AtlasKey, Arc<Vec<u8>>)>> {
        // Every update is a single push or replacement: a poisoned lock is still consistent.
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(super) fn get(&self, key: AtlasKey) -> Option<Arc<Vec<u8>>> {
        let g = self.lock();
        g.iter()
            .find(|(k, _)| *k == key)
            .map(|(_, d)| Arc::clone(d))
    }

    /// Keep `data` as the atlas of its level (replacing the level's previous one).
    pub(super) fn put(&self, key: AtlasKey, data: Arc<Vec<u8>>) {
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
pub(super) struct AlbedoLevel {
    pub(super) data: Arc<Vec<u8>>,
    /// Samples per atlas row and number of rows (tiles × 256 + 1).
    pub(super) stride: usize,
    pub(super) width: i64,
    pub(super) height: i64,
    /// Fixed-point texel coordinates of the camera relative to the atlas origin, and
    /// fixed-point texels per metre: `2¹⁶ ×` the texel figures. Both factors are powers of
    /// two, so `x·s + o` rounds exactly as `(x·scale + ox)·2¹⁶` did: same samples, one
    /// multiplication less per coordinate.
    pub(super) fox: f64,
    pub(super) foy: f64,
    pub(super) fscale: f64,
}

impl AlbedoLevel {
    pub(super) fn new(
        data: Arc<Vec<u8>>,
        ntx: i64,
        nty: i64,
        ox: f64,
        oy: f64,
        scale: f64,
    ) -> Self {
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
    pub(super) fn build(tiles: &[Arc<AlbedoTile>], ntx: i64, nty: i64) -> Vec<u8> {
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

    pub(super) fn view(&self) -> LevelView<'_> {
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
pub(super) struct LevelView<'a> {
    pub(super) data: &'a [u8],
    pub(super) stride: usize,
    pub(super) width: i64,
    pub(super) height: i64,
    pub(super) fox: f64,
    pub(super) foy: f64,
    pub(super) fscale: f64,
}

impl LevelView<'_> {
    /// Fixed-point texel coordinates of the texture offsets `(x, y)`.
    #[inline(always)]
    pub(super) fn fixed(&self, x: f64, y: f64) -> (i64, i64) {
        (
            round_i64(x * self.fscale + self.fox),
            round_i64(y * self.fscale + self.foy),
        )
    }

    /// Bilinear sample at fixed-point texel coordinates (from [`Self::fixed`]); `None` outside
    /// the frame's tiles.
    #[inline(always)]
    pub(super) fn sample_fixed(&self, (gx, gy): (i64, i64)) -> Option<f32> {
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
    pub(super) fn sample_run(&self, x: &[f64], y: &[f64], out: &mut [f32]) -> bool {
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
    pub(super) fn sample4(&self, x: &[f64; 4], y: &[f64; 4]) -> Option<[f32; 4]> {
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
