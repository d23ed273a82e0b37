//! Fixed-point lattice and texel coordinates: one conversion gives a cell index and its
//! interpolation weight (the height look-ups and the albedo samples share it).

/// Fractional bits of the fixed-point lattice and texel coordinates: one conversion gives
/// both the cell and the interpolation weight. Weights are exact to 2⁻¹⁶ of a cell (0.1 mm of
/// height lattice, 2·10⁻⁵ of a texel): far below the 8-bit output and the 2 mm height
/// tolerance.
pub(super) const FIX_BITS: u32 = 16;
pub(super) const FIX_ONE: f64 = (1_u64 << FIX_BITS) as f64;
pub(super) const FIX_MASK: i64 = (1 << FIX_BITS) - 1;

/// `1.5·2⁵²`: adding it to |g| < 2⁵¹ leaves `round(g)` in the low mantissa bits.
pub(super) const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

/// `round(g)` for |g| < 2⁵¹, exactly, by the magic-number addition: three instructions where
/// the saturating `as i64` takes a dozen on x86-64 (the hot loops convert six coordinates per
/// pixel). Out of range (or NaN) gives a meaningless but finite integer, which the callers'
/// bounds checks reject.
#[inline(always)]
pub(super) fn round_i64(g: f64) -> i64 {
    ((g + ROUND_MAGIC).to_bits() as i64).wrapping_sub(ROUND_MAGIC.to_bits() as i64)
}

/// Cell index and weight of the coordinate `g` (cells): `(⌊g⌋, g − ⌊g⌋)` to 2⁻¹⁶.
#[inline(always)]
pub(super) fn split_fixed(g: f64) -> (i64, f64) {
    let i = round_i64(g * FIX_ONE);
    (i >> FIX_BITS, (i & FIX_MASK) as f64 * (1.0 / FIX_ONE))
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
}
