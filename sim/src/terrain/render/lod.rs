//! Levels of detail: a pixel's ground footprint and the mip level it selects, per group of four
//! pixels along a row (module doc of [`super`], "Band-limiting").

use super::super::tiles::MAX_LEVEL;
use super::rays::RowRays;

/// Level of detail (mip level, clamped to the levels there are) and footprint on level
/// ground, m, of the ray with height coefficients `ch1`, `ch2` and `|u|² = n2` at depth `t`.
///
/// The footprint is `t|u|/f / cos(incidence)` with `cos(incidence) = descent/|u|` floored at
/// 0.05: `t|u|²/(f·descent)`, or `t|u|/(0.05 f)` for grazing rays. Both are computed and one is
/// selected (no branch), so that [`lods_of_row`] vectorises; the values are those of the
/// branching form.
#[inline(always)]
pub(super) fn lod_footprint(ch1: f64, ch2: f64, n2: f64, t: f64, f_px: f64) -> (f64, f64) {
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
pub(super) fn lods_of_row(rays: &RowRays, t_row: &[f64], f_px: f64, out: &mut Vec<f64>) {
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
pub(super) fn fast_log2(x: f64) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_log2_is_accurate() {
        for k in 0..2000 {
            let x = 1e-3 * 1.0071_f64.powi(k);
            assert!((fast_log2(x) - x.log2()).abs() < 1e-4, "{x}");
        }
    }
}
