//! Procedural terrain of the visual experiments (paper section "Influence of Terrain Type"; start
//! points after docs/REFERENCES.md A6.5): six zones whose height and albedo are pure functions of
//! geodetic position and a terrain seed, cached in tiles, and the renderer of the down-looking
//! camera's images ([`render`]).
//!
//! Geodetic position → texture coordinates: an equirectangular map with the zone's reference
//! latitude `φ_ref` (its start point), `x = a cos φ_ref · λ`, `y = a · φ` (m, `a` the WGS84
//! semi-major axis), so texture metres are ground metres to within 1 % near the start and
//! within 3 % over the ±125 km of scenario #1. Longitude wraps at ±180° (no zone start lies
//! near it). Heights are above the WGS84 ellipsoid (no geoid model: a procedural terrain has no
//! mean sea level of its own).
//!
//! The terrain height is the bilinear interpolation of the zone's height function sampled on
//! an 8 m lattice of texture coordinates (the lattice is part of the definition, so the cached
//! tiles and [`Terrain::height_m`] agree exactly); the albedo at a filter width `w` is the zone's
//! band-limited albedo function. `docs/TERRAIN.md` describes the zones.

pub mod noise;
pub mod render;
pub mod tiles;
pub mod zones;

use std::str::FromStr;

use noise::fast_floor;

use ianav::math::wgs84;
use serde::{Deserialize, Serialize};

use tiles::{
    ALBEDO_STRIDE, ALBEDO_TILE, AlbedoTile, CacheStats, HEIGHT_SPACING_M, HEIGHT_STRIDE,
    HEIGHT_TILE, HeightTile, TileCache, TileKey,
};

/// Errors of the terrain and the renderer.
#[derive(Debug, thiserror::Error)]
pub enum TerrainError {
    /// The terrain name is not one of the six zones.
    #[error(
        "unknown terrain `{0}`: expected one of ds, fm, fr, mx, pr, ur (or desert, farm, forest, mix, prairie, urban)"
    )]
    UnknownTerrain(String),
}

/// The paper's terrain types.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Zone {
    /// DS: Sonoran desert bajadas and steep ranges, cacti, dry creeks.
    Desert,
    /// FM: flat farmland of large, nearly textureless plots, roads, farmhouses, towns.
    Farm,
    /// FR: forested hills, dense canopy, clearcuts, roads.
    Forest,
    /// MX: rolling hills, woods and farmland in halves, small towns.
    Mix,
    /// PR: Everglades grassland, swamps, tree islands, dirt roads.
    Prairie,
    /// UR: urban street grid, houses, commercial buildings, freeways.
    Urban,
}

/// Start point of a zone (docs/REFERENCES.md A6.5; heights are the authors' ground heights above
/// mean sea level, quoted for reference: the procedural ground differs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZoneStart {
    /// Latitude, degrees.
    pub lat_deg: f64,
    /// Longitude, degrees (east positive, in [−180, 180]).
    pub lon_deg: f64,
    /// The authors' ground height at the point, m.
    pub ground_m: f64,
}

impl Zone {
    /// All zones, in the paper's order.
    pub const ALL: [Zone; 6] = [
        Zone::Desert,
        Zone::Farm,
        Zone::Forest,
        Zone::Mix,
        Zone::Prairie,
        Zone::Urban,
    ];

    /// The paper's two-letter code.
    pub fn code(self) -> &'static str {
        match self {
            Zone::Desert => "ds",
            Zone::Farm => "fm",
            Zone::Forest => "fr",
            Zone::Mix => "mx",
            Zone::Prairie => "pr",
            Zone::Urban => "ur",
        }
    }

    /// Start point (docs/REFERENCES.md A6.5, longitudes converted from [0, 360)).
    pub fn start(self) -> ZoneStart {
        let (lon360, lat_deg, ground_m) = match self {
            Zone::Desert => (248.001_185, 32.157_903, 661.0),
            Zone::Farm => (272.122_371, 38.865_625, 144.0),
            Zone::Forest => (287.490_805, 43.354_486, 200.0),
            Zone::Mix => (270.984_538, 34.720_636, 133.0),
            Zone::Prairie => (279.088_834, 25.855_172, 10.0),
            Zone::Urban => (241.799_731, 33.924_426, 26.0),
        };
        ZoneStart {
            lat_deg,
            lon_deg: lon360 - 360.0,
            ground_m,
        }
    }
}

impl FromStr for Zone {
    type Err = TerrainError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "ds" | "desert" => Zone::Desert,
            "fm" | "farm" => Zone::Farm,
            "fr" | "forest" => Zone::Forest,
            "mx" | "mix" => Zone::Mix,
            "pr" | "prairie" => Zone::Prairie,
            "ur" | "urban" => Zone::Urban,
            _ => return Err(TerrainError::UnknownTerrain(s.to_owned())),
        })
    }
}

impl std::fmt::Display for Zone {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.code())
    }
}

/// A synthetic marker painted into the albedo (tests): a bright Gaussian spot of standard
/// deviation `sigma_m` on a dark disc, centred on a geodetic position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    /// Latitude, rad.
    pub lat_rad: f64,
    /// Longitude, rad.
    pub lon_rad: f64,
    /// Standard deviation of the spot, m.
    pub sigma_m: f64,
}

/// Marker in texture coordinates.
#[derive(Debug, Clone, Copy)]
struct MarkerXy {
    x: f64,
    y: f64,
    sigma_m: f64,
}

/// Default memory bounds of the tile caches: 64 MiB of heights (≈ 1,000 km² of terrain) and
/// 192 MiB of albedo (≈ 2,900 tiles: 760 km² at level 1).
pub const DEFAULT_HEIGHT_BUDGET_BYTES: usize = 64 << 20;
/// See [`DEFAULT_HEIGHT_BUDGET_BYTES`].
pub const DEFAULT_ALBEDO_BUDGET_BYTES: usize = 192 << 20;

/// One zone with one seed: its height and albedo everywhere on Earth, and its tile caches.
#[derive(Debug)]
pub struct Terrain {
    zone: Zone,
    seed: u64,
    /// `a cos φ_ref`, m per radian of longitude.
    x_per_rad: f64,
    markers: Vec<MarkerXy>,
    heights: TileCache<HeightTile>,
    albedo: TileCache<AlbedoTile>,
    /// The renderer's albedo atlases of the last frame.
    atlases: render::AtlasCache,
}

impl Terrain {
    /// Zone `zone` with terrain seed `seed` and the default cache bounds.
    pub fn new(zone: Zone, seed: u64) -> Self {
        Self::with_budgets(
            zone,
            seed,
            DEFAULT_HEIGHT_BUDGET_BYTES,
            DEFAULT_ALBEDO_BUDGET_BYTES,
        )
    }

    /// Zone `zone` with terrain seed `seed` and caches bounded to the given bytes.
    pub fn with_budgets(zone: Zone, seed: u64, height_bytes: usize, albedo_bytes: usize) -> Self {
        let lat_ref_rad = zone.start().lat_deg.to_radians();
        Self {
            zone,
            seed,
            x_per_rad: wgs84::A_M * lat_ref_rad.cos(),
            markers: Vec::new(),
            heights: TileCache::new(height_bytes, HeightTile::BYTES),
            albedo: TileCache::new(albedo_bytes, AlbedoTile::BYTES),
            atlases: render::AtlasCache::default(),
        }
    }

    /// The same terrain with synthetic markers painted into its albedo (a fresh cache).
    pub fn with_markers(self, markers: &[Marker]) -> Self {
        let mut t = Self::with_budgets(
            self.zone,
            self.seed,
            self.heights.budget_bytes(),
            self.albedo.budget_bytes(),
        );
        t.markers = markers
            .iter()
            .map(|m| {
                let (x, y) = t.texture_xy(m.lat_rad, m.lon_rad);
                MarkerXy {
                    x,
                    y,
                    sigma_m: m.sigma_m.max(0.1),
                }
            })
            .collect();
        t
    }

    /// The zone.
    pub fn zone(&self) -> Zone {
        self.zone
    }

    /// The terrain seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Texture coordinates `(x, y)`, m, of a geodetic position.
    pub fn texture_xy(&self, lat_rad: f64, lon_rad: f64) -> (f64, f64) {
        (self.x_per_rad * lon_rad, wgs84::A_M * lat_rad)
    }

    /// Height bounds of the zone, m (every terrain height lies within).
    pub fn height_bounds_m(&self) -> (f64, f64) {
        zones::height_bounds_m(self.zone)
    }

    /// Lattice height sample `(i, j)` (as stored in the tiles).
    #[inline]
    fn lattice_m(&self, i: i64, j: i64) -> f32 {
        zones::raw_height_m(
            self.zone,
            self.seed,
            i as f64 * HEIGHT_SPACING_M,
            j as f64 * HEIGHT_SPACING_M,
        ) as f32
    }

    /// Terrain height (above the WGS84 ellipsoid), m, at texture coordinates.
    pub fn height_xy_m(&self, x: f64, y: f64) -> f64 {
        let gx = x / HEIGHT_SPACING_M;
        let gy = y / HEIGHT_SPACING_M;
        let (fx, fy) = (fast_floor(gx), fast_floor(gy));
        let (i, j) = (fx as i64, fy as i64);
        bilinear(
            self.lattice_m(i, j),
            self.lattice_m(i + 1, j),
            self.lattice_m(i, j + 1),
            self.lattice_m(i + 1, j + 1),
            gx - fx,
            gy - fy,
        )
    }

    /// Terrain height, m, and its gradient (m per texture metre) at texture coordinates.
    pub fn height_grad_xy_m(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let gx = x / HEIGHT_SPACING_M;
        let gy = y / HEIGHT_SPACING_M;
        let (fx, fy) = (fast_floor(gx), fast_floor(gy));
        let (i, j) = (fx as i64, fy as i64);
        bilinear_grad(
            self.lattice_m(i, j),
            self.lattice_m(i + 1, j),
            self.lattice_m(i, j + 1),
            self.lattice_m(i + 1, j + 1),
            gx - fx,
            gy - fy,
        )
    }

    /// Terrain height (above the WGS84 ellipsoid), m, at a geodetic position.
    pub fn height_m(&self, lat_rad: f64, lon_rad: f64) -> f64 {
        let (x, y) = self.texture_xy(lat_rad, lon_rad);
        self.height_xy_m(x, y)
    }

    /// Albedo in [0, 1] at texture coordinates, band-limited to a box filter of `filter_m`.
    pub fn albedo_xy(&self, x: f64, y: f64, filter_m: f64) -> f64 {
        let mut a = zones::albedo(self.zone, self.seed, x, y, filter_m);
        for m in &self.markers {
            let (dx, dy) = (x - m.x, y - m.y);
            let r2 = dx * dx + dy * dy;
            let disc_m = 6.0 * m.sigma_m;
            if r2 < (disc_m + filter_m + 2.0).powi(2) {
                // Dark disc, then a bright Gaussian spot widened by the filter's variance
                // (a box of width w has variance w²/12) with its integral kept.
                let disc = noise::inside(r2.sqrt() - disc_m, filter_m);
                a = noise::lerp(a, 0.08, disc);
                let s2 = m.sigma_m * m.sigma_m + filter_m * filter_m / 12.0;
                let peak = 0.8 * m.sigma_m * m.sigma_m / s2;
                a += peak * (-0.5 * r2 / s2).exp();
            }
        }
        a.clamp(0.0, 1.0)
    }

    /// Albedo in [0, 1] at a geodetic position, band-limited to `filter_m`.
    pub fn albedo(&self, lat_rad: f64, lon_rad: f64, filter_m: f64) -> f64 {
        let (x, y) = self.texture_xy(lat_rad, lon_rad);
        self.albedo_xy(x, y, filter_m)
    }

    /// Counters of the height and albedo caches.
    pub fn cache_stats(&self) -> (CacheStats, CacheStats) {
        (self.heights.stats(), self.albedo.stats())
    }

    /// Memory bound of the two caches together, bytes.
    pub fn cache_budget_bytes(&self) -> usize {
        self.heights.budget_bytes() + self.albedo.budget_bytes()
    }

    fn make_height_tile(&self, key: TileKey) -> HeightTile {
        let (i0, j0) = (key.tx * HEIGHT_TILE as i64, key.ty * HEIGHT_TILE as i64);
        let mut h = Vec::with_capacity(HEIGHT_STRIDE * HEIGHT_STRIDE);
        for j in 0..HEIGHT_STRIDE as i64 {
            for i in 0..HEIGHT_STRIDE as i64 {
                h.push(self.lattice_m(i0 + i, j0 + j));
            }
        }
        HeightTile::from_samples(h)
    }

    fn make_albedo_tile(&self, key: TileKey) -> AlbedoTile {
        let texel_m = f64::from(1_u32 << key.level);
        let (i0, j0) = (key.tx * ALBEDO_TILE as i64, key.ty * ALBEDO_TILE as i64);
        let mut a = Vec::with_capacity(ALBEDO_STRIDE * ALBEDO_STRIDE);
        for j in 0..ALBEDO_STRIDE as i64 {
            let y = ((j0 + j) as f64 + 0.5) * texel_m;
            for i in 0..ALBEDO_STRIDE as i64 {
                let x = ((i0 + i) as f64 + 0.5) * texel_m;
                a.push((self.albedo_xy(x, y, texel_m) * 255.0).round() as u8);
            }
        }
        AlbedoTile { a }
    }

    /// Height tiles of `keys` (cached or generated).
    pub fn height_tiles(&self, keys: &[TileKey]) -> Vec<std::sync::Arc<HeightTile>> {
        self.heights.get_many(keys, |k| self.make_height_tile(k))
    }

    /// Albedo tiles of `keys` (cached or generated).
    pub fn albedo_tiles(&self, keys: &[TileKey]) -> Vec<std::sync::Arc<AlbedoTile>> {
        self.albedo.get_many(keys, |k| self.make_albedo_tile(k))
    }
}

/// Bilinear interpolation of four lattice samples at fractions `(fx, fy)` (shared by the
/// exact height and the renderer so both give the same surface).
#[inline]
pub fn bilinear(h00: f32, h10: f32, h01: f32, h11: f32, fx: f64, fy: f64) -> f64 {
    let (h00, h10, h01, h11) = (
        f64::from(h00),
        f64::from(h10),
        f64::from(h01),
        f64::from(h11),
    );
    h00 + fx * (h10 - h00) + fy * (h01 - h00) + fx * fy * (h00 - h10 - h01 + h11)
}

/// [`bilinear`] and its gradient per texture metre `(h, ∂h/∂x, ∂h/∂y)`.
#[inline]
pub fn bilinear_grad(h00: f32, h10: f32, h01: f32, h11: f32, fx: f64, fy: f64) -> (f64, f64, f64) {
    let (h00, h10, h01, h11) = (
        f64::from(h00),
        f64::from(h10),
        f64::from(h01),
        f64::from(h11),
    );
    let (a, b, c) = (h10 - h00, h01 - h00, h00 - h10 - h01 + h11);
    (
        h00 + fx * a + fy * b + fx * fy * c,
        (a + fy * c) * (1.0 / HEIGHT_SPACING_M),
        (b + fx * c) * (1.0 / HEIGHT_SPACING_M),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zone_names_parse_and_unknown_names_are_refused() {
        for z in Zone::ALL {
            assert_eq!(z.code().parse::<Zone>().unwrap(), z);
        }
        assert_eq!("Desert".parse::<Zone>().unwrap(), Zone::Desert);
        let err = "moon".parse::<Zone>().unwrap_err().to_string();
        assert!(err.contains("moon") && err.contains("ds"), "{err}");
    }

    #[test]
    fn tiles_hold_the_exact_terrain() {
        let t = Terrain::new(Zone::Forest, 3);
        let start = Zone::Forest.start();
        let (x, y) = t.texture_xy(start.lat_deg.to_radians(), start.lon_deg.to_radians());
        let key = TileKey {
            level: 0,
            tx: fast_floor(x / (HEIGHT_SPACING_M * HEIGHT_TILE as f64)) as i64,
            ty: fast_floor(y / (HEIGHT_SPACING_M * HEIGHT_TILE as f64)) as i64,
        };
        let tile = &t.height_tiles(&[key])[0];
        let (i0, j0) = (key.tx * 128, key.ty * 128);
        for (i, j) in [(0, 0), (17, 99), (128, 128)] {
            let h = t.height_xy_m((i0 + i) as f64 * 8.0, (j0 + j) as f64 * 8.0);
            assert_eq!(h, f64::from(tile.h_m[j as usize * 129 + i as usize]));
        }
        // Purity: same position, same answer, from a fresh terrain.
        let other = Terrain::new(Zone::Forest, 3);
        assert_eq!(t.height_m(0.75, -1.27), other.height_m(0.75, -1.27));
        assert_ne!(
            t.height_m(0.75, -1.27),
            Terrain::new(Zone::Forest, 4).height_m(0.75, -1.27)
        );
    }
}
