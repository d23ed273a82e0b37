//! Tile cache of the terrain (docs/TERRAIN.md): height and albedo rasters generated lazily
//! from the procedural zone functions and kept in a least-recently-used cache of bounded size,
//! so that rendering a frame is a lookup. Thread-safe: a frame asks for all its tiles at once,
//! the missing ones are generated in parallel (rayon) outside the lock.
//!
//! - Heights: an 8 m lattice, tiles of 128 × 128 cells (1,024 m), stored with one extra row
//!   and column (129 × 129 `f32`, 66.6 kB) so bilinear interpolation never leaves the tile,
//!   plus the tile's height range and a bound on its slope.
//! - Albedo: mip levels `L = 0 … MAX_LEVEL` of texel size `2^L` m, tiles of 256 × 256 texels,
//!   stored with one extra row and column (257 × 257 `u8`, 66 kB). Level `L` is sampled from
//!   the band-limited albedo with a filter of `2^L` m, so every level is already low-passed
//!   and levels are generated independently (no level 0 is needed at altitude).
//! - Memory bound: each cache holds at most `budget_bytes` of tiles it can evict; tiles in use
//!   by a frame being rendered are never evicted, so the peak is the budget plus one frame's
//!   working set (about 16 height and 60 albedo tiles, ≈ 5 MB, for a nadir frame at 2,700 m).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

/// Lattice spacing of the height field, m.
pub const HEIGHT_SPACING_M: f64 = 8.0;
/// Height cells per tile side.
pub const HEIGHT_TILE: usize = 128;
/// Stored height samples per tile row (cells + 1).
pub const HEIGHT_STRIDE: usize = HEIGHT_TILE + 1;
/// Albedo texels per tile side.
pub const ALBEDO_TILE: usize = 256;
/// Stored albedo samples per tile row (texels + 1).
pub const ALBEDO_STRIDE: usize = ALBEDO_TILE + 1;
/// Coarsest albedo mip level (texels of 2^MAX_LEVEL m).
pub const MAX_LEVEL: u32 = 10;

/// Identity of a tile: mip level (0 for heights) and tile indices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TileKey {
    /// Mip level.
    pub level: u32,
    /// Tile column (texture x).
    pub tx: i64,
    /// Tile row (texture y).
    pub ty: i64,
}

/// Heights of one tile: lattice points `(tx·128 + i, ty·128 + j)`, `i, j ∈ 0…128`.
#[derive(Debug)]
pub struct HeightTile {
    /// Heights, m, row after row (`j·129 + i`).
    pub h_m: Vec<f32>,
    /// Lowest height, m.
    pub min_m: f32,
    /// Highest height, m.
    pub max_m: f32,
    /// Upper bound of the slope `|∇h|` of the bilinear surface in the tile.
    pub max_slope: f64,
}

impl HeightTile {
    /// Build from the stored samples.
    pub fn from_samples(h_m: Vec<f32>) -> Self {
        let mut min_m = f32::INFINITY;
        let mut max_m = f32::NEG_INFINITY;
        for &h in &h_m {
            min_m = min_m.min(h);
            max_m = max_m.max(h);
        }
        let mut max_slope: f64 = 0.0;
        for j in 0..HEIGHT_TILE {
            for i in 0..HEIGHT_TILE {
                let k = j * HEIGHT_STRIDE + i;
                let (h00, h10) = (f64::from(h_m[k]), f64::from(h_m[k + 1]));
                let (h01, h11) = (
                    f64::from(h_m[k + HEIGHT_STRIDE]),
                    f64::from(h_m[k + HEIGHT_STRIDE + 1]),
                );
                // On a bilinear cell ∂h/∂x lies between the differences of its two edges.
                let gx = (h10 - h00).abs().max((h11 - h01).abs());
                let gy = (h01 - h00).abs().max((h11 - h10).abs());
                max_slope = max_slope.max(gx.hypot(gy) / HEIGHT_SPACING_M);
            }
        }
        Self {
            h_m,
            min_m,
            max_m,
            max_slope,
        }
    }

    /// Bytes held.
    pub const BYTES: usize = HEIGHT_STRIDE * HEIGHT_STRIDE * 4 + 64;
}

/// Albedo of one tile at one mip level: texel centres `((tx·256 + i + ½)·2^L, …)`,
/// `i, j ∈ 0…256`, grey levels 0–255.
#[derive(Debug)]
pub struct AlbedoTile {
    /// Albedo × 255, row after row (`j·257 + i`).
    pub a: Vec<u8>,
}

impl AlbedoTile {
    /// Bytes held.
    pub const BYTES: usize = ALBEDO_STRIDE * ALBEDO_STRIDE + 48;
}

/// Counters of a cache.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Tiles held.
    pub tiles: usize,
    /// Bytes held.
    pub bytes: usize,
    /// Tiles generated since the start.
    pub generated: u64,
    /// Tiles evicted since the start.
    pub evicted: u64,
    /// Requests served from the cache.
    pub hits: u64,
    /// Largest number of bytes held at once.
    pub peak_bytes: usize,
}

struct Inner<T> {
    map: HashMap<TileKey, (Arc<T>, u64)>,
    clock: u64,
    stats: CacheStats,
}

/// Least-recently-used cache of tiles of one kind, bounded to `budget_bytes`.
pub struct TileCache<T> {
    inner: Mutex<Inner<T>>,
    budget_bytes: usize,
    tile_bytes: usize,
}

impl<T: Send + Sync> std::fmt::Debug for TileCache<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TileCache")
            .field("budget_bytes", &self.budget_bytes)
            .field("stats", &self.stats())
            .finish()
    }
}

impl<T: Send + Sync> TileCache<T> {
    /// Empty cache of tiles of `tile_bytes` each, holding at most `budget_bytes`.
    pub fn new(budget_bytes: usize, tile_bytes: usize) -> Self {
        Self {
            inner: Mutex::new(Inner {
                map: HashMap::new(),
                clock: 0,
                stats: CacheStats::default(),
            }),
            budget_bytes,
            tile_bytes,
        }
    }

    /// The memory bound, bytes.
    pub fn budget_bytes(&self) -> usize {
        self.budget_bytes
    }

    /// Counters.
    pub fn stats(&self) -> CacheStats {
        match self.inner.lock() {
            Ok(g) => g.stats,
            Err(p) => p.into_inner().stats,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner<T>> {
        // A panic while holding the lock cannot leave the map inconsistent (every update is
        // a single insert or remove), so a poisoned lock is still usable.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The tiles of `keys` (in order), generating the missing ones in parallel with
    /// `generate`, then evicting the least recently used tiles beyond the budget.
    pub fn get_many(
        &self,
        keys: &[TileKey],
        generate: impl Fn(TileKey) -> T + Sync,
    ) -> Vec<Arc<T>> {
        let mut out: Vec<Option<Arc<T>>> = vec![None; keys.len()];
        let missing: Vec<(usize, TileKey)> = {
            let mut g = self.lock();
            g.clock += 1;
            let now = g.clock;
            let mut missing = Vec::new();
            let mut hits = 0;
            for (i, key) in keys.iter().enumerate() {
                if let Some((tile, used)) = g.map.get_mut(key) {
                    *used = now;
                    out[i] = Some(Arc::clone(tile));
                    hits += 1;
                } else {
                    missing.push((i, *key));
                }
            }
            g.stats.hits += hits;
            missing
        };
        let made: Vec<(usize, TileKey, Arc<T>)> = missing
            .par_iter()
            .map(|&(i, key)| (i, key, Arc::new(generate(key))))
            .collect();
        let mut g = self.lock();
        g.clock += 1;
        let now = g.clock;
        for (i, key, tile) in made {
            // Another frame may have made the same tile meanwhile: keep one.
            let entry = g.map.entry(key).or_insert_with(|| (Arc::clone(&tile), now));
            entry.1 = now;
            out[i] = Some(Arc::clone(&entry.0));
            g.stats.generated += 1;
        }
        for key in keys {
            if let Some(e) = g.map.get_mut(key) {
                e.1 = now;
            }
        }
        self.evict(&mut g, now);
        out.into_iter()
            .map(|t| t.unwrap_or_else(|| unreachable!("every key was found or generated")))
            .collect()
    }

    fn evict(&self, g: &mut Inner<T>, now: u64) {
        let bytes = g.map.len() * self.tile_bytes;
        if bytes > self.budget_bytes {
            // Evict down to 90 % of the budget in one sort (amortises the O(n log n)),
            // never a tile of the current request.
            let target = (self.budget_bytes / 10 * 9) / self.tile_bytes.max(1);
            let mut ages: Vec<(u64, TileKey)> = g.map.iter().map(|(k, v)| (v.1, *k)).collect();
            ages.sort_unstable_by_key(|a| a.0);
            let mut n = g.map.len();
            for (used, key) in ages {
                if n <= target || used >= now {
                    break;
                }
                g.map.remove(&key);
                g.stats.evicted += 1;
                n -= 1;
            }
        }
        g.stats.tiles = g.map.len();
        g.stats.bytes = g.map.len() * self.tile_bytes;
        g.stats.peak_bytes = g.stats.peak_bytes.max(g.stats.bytes);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cache_stays_within_its_budget_and_keeps_recent_tiles() {
        let cache: TileCache<u64> = TileCache::new(10 * 100, 100);
        let key = |i: i64| TileKey {
            level: 0,
            tx: i,
            ty: 0,
        };
        for i in 0..50 {
            let got = cache.get_many(&[key(i), key(i + 1)], |k| k.tx as u64 * 3);
            assert_eq!(*got[0], i as u64 * 3);
            assert!(cache.stats().bytes <= 1000);
        }
        let s = cache.stats();
        assert!(s.evicted > 0 && s.tiles <= 10);
        // The most recent tiles are still there: no regeneration.
        let before = cache.stats().generated;
        cache.get_many(&[key(50), key(49)], |_| 0);
        assert_eq!(cache.stats().generated, before);
    }

    #[test]
    fn height_tile_slope_bound_holds() {
        // A plane of slope 0.5 along x: the bound is exactly 0.5.
        let h: Vec<f32> = (0..HEIGHT_STRIDE * HEIGHT_STRIDE)
            .map(|k| ((k % HEIGHT_STRIDE) as f64 * HEIGHT_SPACING_M * 0.5) as f32)
            .collect();
        let t = HeightTile::from_samples(h);
        assert!((t.max_slope - 0.5).abs() < 1e-6);
        assert_eq!(t.min_m, 0.0);
    }
}
