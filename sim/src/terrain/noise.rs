//! Procedural-noise building blocks of the terrain zones (docs/TERRAIN.md): integer hashing,
//! value noise with analytic derivatives, band-limited fractal sums, cellular (Worley) noise
//! and anti-aliased masks.
//!
//! Band-limiting: every function that produces texture takes `filter_m`, the width of the box
//! the caller averages over (a mip level's texel size). Octaves whose wavelength is below
//! `2·filter_m` (beyond the texel grid's Nyquist limit) are faded out, and edges of discrete
//! features are blurred over the filter width, so a mip level sampled from these functions is
//! already low-passed and does not alias (Ebert et al., "Texturing and Modeling", ch. 2,
//! clamping and analytic anti-aliasing).

/// `⌊x⌋`, equal to `f64::floor` for |x| < 2⁶³ (all texture coordinates), without the libm
/// call `floor` becomes on baseline x86-64 (it was ~12 % of the tile generation time).
#[inline(always)]
pub fn fast_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// 64-bit mix of a seed and two lattice indices (SplitMix64 finaliser).
#[inline]
pub fn hash2(seed: u64, ix: i64, iy: i64) -> u64 {
    let mut h = seed
        ^ (ix as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
        ^ (iy as u64)
            .wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
            .rotate_left(29);
    h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^ (h >> 31)
}

/// Derived seed for a named layer.
#[inline]
pub fn sub_seed(seed: u64, layer: u64) -> u64 {
    hash2(seed, layer as i64, 0x5eed)
}

/// Uniform in [0, 1) from the top 53 bits of a hash.
#[inline]
pub fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1_u64 << 53) as f64)
}

/// Uniform in [0, 1) from bits `k·16 … k·16 + 15` of a hash (four cheap draws per hash).
#[inline]
pub fn unit16(h: u64, k: u32) -> f64 {
    f64::from(((h >> (16 * k)) & 0xffff) as u16) * (1.0 / 65_536.0)
}

/// Cubic smoothstep of `x` between `e0` and `e1` (clamped).
#[inline]
pub fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Linear interpolation.
#[inline]
pub fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

/// Value noise in [−1, 1] at lattice coordinates `(x, y)` (unit cell), with its gradient.
/// Quintic interpolation: C² and with zero derivative at lattice points.
#[inline]
pub fn value_noise_d(seed: u64, x: f64, y: f64) -> (f64, f64, f64) {
    let (xf, yf) = (fast_floor(x), fast_floor(y));
    let (ix, iy) = (xf as i64, yf as i64);
    let (fx, fy) = (x - xf, y - yf);
    let v = |i: i64, j: i64| unit(hash2(seed, ix + i, iy + j)) * 2.0 - 1.0;
    let (a, b, c, d) = (v(0, 0), v(1, 0), v(0, 1), v(1, 1));
    let ux = fx * fx * fx * (fx * (fx * 6.0 - 15.0) + 10.0);
    let uy = fy * fy * fy * (fy * (fy * 6.0 - 15.0) + 10.0);
    let dux = 30.0 * fx * fx * (fx * (fx - 2.0) + 1.0);
    let duy = 30.0 * fy * fy * (fy * (fy - 2.0) + 1.0);
    let k1 = b - a;
    let k2 = c - a;
    let k3 = a - b - c + d;
    (
        a + k1 * ux + k2 * uy + k3 * ux * uy,
        (k1 + k3 * uy) * dux,
        (k2 + k3 * ux) * duy,
    )
}

/// Value noise in [−1, 1] (no gradient).
#[inline]
pub fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    value_noise_d(seed, x, y).0
}

/// Weight of an octave of wavelength `wavelength_m` under a box filter of `filter_m`: 1 above
/// four filter widths, 0 below two (the texel grid's Nyquist limit), smooth between.
#[inline]
pub fn octave_weight(wavelength_m: f64, filter_m: f64) -> f64 {
    if filter_m <= 0.0 {
        1.0
    } else {
        smoothstep(2.0 * filter_m, 4.0 * filter_m, wavelength_m)
    }
}

/// Fractal sum of `octaves` value-noise octaves, the first of wavelength `wavelength_m`, each
/// next one half the wavelength and `gain` times the amplitude; normalised so that the
/// unfiltered sum stays in [−1, 1]. Octaves are rotated and offset against each other so their
/// lattices do not line up. Band-limited by `filter_m`.
pub fn fbm(
    seed: u64,
    x: f64,
    y: f64,
    wavelength_m: f64,
    octaves: u32,
    gain: f64,
    filter_m: f64,
) -> f64 {
    // Rotation by ~36.87° (3-4-5 triangle) between octaves.
    const C: f64 = 0.8;
    const S: f64 = 0.6;
    let (mut px, mut py) = (x / wavelength_m, y / wavelength_m);
    let mut amp = 1.0;
    let mut norm = 0.0;
    for _ in 0..octaves {
        norm += amp;
        amp *= gain;
    }
    let mut amp = 1.0;
    let mut sum = 0.0;
    let mut wl = wavelength_m;
    for k in 0..octaves {
        let w = octave_weight(wl, filter_m);
        if w <= 0.0 {
            // Later octaves are finer still: nothing left to add.
            break;
        }
        sum += amp * w * value_noise(seed.wrapping_add(u64::from(k) * 0x632b_e59b), px, py);
        let (nx, ny) = (C * px - S * py, S * px + C * py);
        px = 2.0 * nx + 17.31;
        py = 2.0 * ny - 9.87;
        amp *= gain;
        wl *= 0.5;
    }
    sum / norm
}

/// Ridged fractal in [0, 1]: sharp crests where the noise crosses zero (mountain ridges).
pub fn ridged(seed: u64, x: f64, y: f64, wavelength_m: f64, octaves: u32, filter_m: f64) -> f64 {
    const C: f64 = 0.8;
    const S: f64 = 0.6;
    let (mut px, mut py) = (x / wavelength_m, y / wavelength_m);
    let norm = 2.0 - 0.5_f64.powi(octaves.max(1) as i32 - 1);
    let mut amp = 1.0;
    let mut sum = 0.0;
    let mut wl = wavelength_m;
    let mut prev = 1.0;
    for k in 0..octaves {
        let w = octave_weight(wl, filter_m);
        if w <= 0.0 {
            break;
        }
        let n = value_noise(seed.wrapping_add(u64::from(k) * 0x1f12_3bb5), px, py);
        let r = 1.0 - n.abs();
        let r = r * r * prev;
        prev = r;
        // A filtered-out octave contributes its mean (≈ 0.45 of the crest weight).
        sum += amp * (w * r + (1.0 - w) * 0.45 * prev);
        let (nx, ny) = (C * px - S * py, S * px + C * py);
        px = 2.0 * nx + 5.13;
        py = 2.0 * ny + 11.7;
        amp *= 0.5;
        wl *= 0.5;
    }
    (sum / norm).clamp(0.0, 1.0)
}

/// Nearest jittered feature point of a cellular (Worley) pattern of cell size `cell_m`.
#[derive(Debug, Clone, Copy)]
pub struct Cell {
    /// Distance to the nearest feature point, m.
    pub d1_m: f64,
    /// Distance to the second nearest, m.
    pub d2_m: f64,
    /// Hash of the nearest point's cell (its identity).
    pub id: u64,
    /// Offset from the nearest feature point to the query, m.
    pub dx_m: f64,
    /// Offset from the nearest feature point to the query, m.
    pub dy_m: f64,
}

/// Cellular noise: one feature point per cell at a hashed position (jitter `jitter` ∈ [0, 1]
/// of the cell).
pub fn cellular(seed: u64, x: f64, y: f64, cell_m: f64, jitter: f64) -> Cell {
    let (gx, gy) = (x / cell_m, y / cell_m);
    let (cx, cy) = (fast_floor(gx) as i64, fast_floor(gy) as i64);
    let mut best = Cell {
        d1_m: f64::INFINITY,
        d2_m: f64::INFINITY,
        id: 0,
        dx_m: 0.0,
        dy_m: 0.0,
    };
    // Square of `best.d2_m`: a point whose squared distance is not below it cannot be among
    // the two nearest (the square root is monotone), so its square root is skipped. The
    // comparisons that decide stay those of the distances: the same result, ties included.
    let (mut d1_sq, mut d2_sq) = (f64::INFINITY, f64::INFINITY);
    for j in -1..=1 {
        for i in -1..=1 {
            let h = hash2(seed, cx + i, cy + j);
            let px = (cx + i) as f64 + 0.5 + jitter * (unit16(h, 0) - 0.5);
            let py = (cy + j) as f64 + 0.5 + jitter * (unit16(h, 1) - 0.5);
            let (dx, dy) = ((gx - px) * cell_m, (gy - py) * cell_m);
            let sq = dx * dx + dy * dy;
            if sq >= d2_sq {
                continue;
            }
            let d = sq.sqrt();
            if d < best.d1_m {
                (d1_sq, d2_sq) = (sq, d1_sq);
                best.d2_m = best.d1_m;
                best = Cell {
                    d1_m: d,
                    d2_m: best.d2_m,
                    id: h,
                    dx_m: dx,
                    dy_m: dy,
                };
            } else if d < best.d2_m {
                best.d2_m = d;
                d2_sq = sq;
            }
        }
    }
    best
}

/// Anti-aliased inside-mask of a region whose signed distance to its edge is `d_m` (negative
/// inside): 1 deep inside, 0 outside, linear over the filter width.
#[inline]
pub fn inside(d_m: f64, filter_m: f64) -> f64 {
    let w = 0.5 * filter_m.max(0.5);
    (0.5 - d_m / (2.0 * w)).clamp(0.0, 1.0)
}

/// Anti-aliased mask of a band of half-width `half_width_m` around a centre line at distance
/// `d_m`. A band thinner than the filter keeps its area (coverage `2·half_width/filter`).
#[inline]
pub fn band(d_m: f64, half_width_m: f64, filter_m: f64) -> f64 {
    let w = 0.5 * filter_m.max(0.5);
    if half_width_m >= w {
        inside(d_m.abs() - half_width_m, filter_m)
    } else {
        // Tent of width 2w and the band's area.
        (half_width_m / w) * (1.0 - d_m.abs() / (2.0 * w)).clamp(0.0, 1.0)
    }
}

/// Weight of a feature of size `size_m` under the filter: 1 when it is resolved (≥ 2 filter
/// widths), 0 when it is smaller than half a filter width (the caller then uses the feature's
/// mean contribution instead), smooth between.
#[inline]
pub fn detail(size_m: f64, filter_m: f64) -> f64 {
    if filter_m <= 0.0 {
        1.0
    } else {
        smoothstep(0.5 * filter_m, 2.0 * filter_m, size_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_floor_equals_floor() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.999_999_999,
            -2.000_000_1,
            1e15 + 0.5,
            -1e15 - 0.5,
            4.5e15,
            -4.5e15,
            1e18,
            -1e18,
            f64::EPSILON,
            -f64::EPSILON,
        ] {
            assert_eq!(fast_floor(x), x.floor(), "{x}");
        }
    }

    #[test]
    fn value_noise_gradient_matches_finite_differences() {
        for (x, y) in [(0.3, 0.7), (12.9, -3.2), (-100.5, 44.01)] {
            let (_, gx, gy) = value_noise_d(7, x, y);
            let h = 1e-6;
            let fx = (value_noise(7, x + h, y) - value_noise(7, x - h, y)) / (2.0 * h);
            let fy = (value_noise(7, x, y + h) - value_noise(7, x, y - h)) / (2.0 * h);
            assert!((gx - fx).abs() < 1e-6 && (gy - fy).abs() < 1e-6);
        }
    }

    #[test]
    fn noise_is_bounded_and_deterministic() {
        for k in 0..2000 {
            let x = k as f64 * 0.731 - 300.0;
            let y = k as f64 * -0.377 + 12.0;
            let v = fbm(3, x, y, 10.0, 6, 0.5, 0.0);
            assert!((-1.0..=1.0).contains(&v));
            assert_eq!(v, fbm(3, x, y, 10.0, 6, 0.5, 0.0));
            let r = ridged(3, x, y, 10.0, 5, 0.0);
            assert!((0.0..=1.0).contains(&r));
        }
        // A different seed gives a different field.
        assert_ne!(
            fbm(3, 1.3, 2.7, 10.0, 4, 0.5, 0.0),
            fbm(4, 1.3, 2.7, 10.0, 4, 0.5, 0.0)
        );
    }

    #[test]
    fn filtering_removes_fine_octaves() {
        // With a filter wider than the whole octave ladder only the coarse octave is left:
        // the filtered field is smoother (smaller mean finite difference).
        let rough = |f: f64| -> f64 {
            (0..500)
                .map(|k| {
                    let x = k as f64 * 0.5;
                    (fbm(1, x + 0.5, 3.0, 64.0, 7, 0.6, f) - fbm(1, x, 3.0, 64.0, 7, 0.6, f)).abs()
                })
                .sum()
        };
        assert!(rough(8.0) < 0.5 * rough(0.0));
    }

    #[test]
    fn thin_bands_keep_their_area() {
        // Integral across a 1 m band under a 4 m filter ≈ 1 m.
        let area: f64 = (-2000..2000)
            .map(|k| band(k as f64 * 0.01, 0.5, 4.0) * 0.01)
            .sum();
        assert!((area - 1.0).abs() < 0.02, "{area}");
        let area: f64 = (-2000..2000)
            .map(|k| band(k as f64 * 0.01, 3.0, 1.0) * 0.01)
            .sum();
        assert!((area - 6.0).abs() < 0.02, "{area}");
    }
}
