//! Shading: the trilinear albedo of each ground pixel at its level of detail times the exposure,
//! sky elsewhere, and the sensor noise.

use super::super::Terrain;
use super::super::tiles::MAX_LEVEL;
use super::RenderStats;
use super::atlas::LevelView;

/// Albedo (grey levels) at mip level `level` outside the frame's tiles: direct evaluation.
#[cold]
#[inline(never)]
pub(super) fn slow_albedo(terrain: &Terrain, x: f64, y: f64, level: u32) -> f32 {
    (terrain.albedo_xy(x, y, f64::from(1_u32 << level)) * 255.0) as f32
}

/// Columns per strip of the shading (a multiple of 4: strips start new level-of-detail groups).
pub(super) const SHADE_STRIP: usize = 64;

/// Groups of four pixels shaded together by [`Shader::run`] at most (a strip's).
pub(super) const RUN_GROUPS: usize = SHADE_STRIP / 4;

/// Round half up to a grey level (`f32::round` is a libm call on baseline x86-64).
#[inline(always)]
pub(super) fn to_grey(v: f32) -> u8 {
    (v.clamp(0.0, 255.0) + 0.5) as u8
}

/// Albedo sampling of the main pass: the frame's atlases and photometric constants.
pub(super) struct Shader<'a> {
    pub(super) levels: Vec<Option<LevelView<'a>>>,
    pub(super) terrain: &'a Terrain,
    pub(super) xc: f64,
    pub(super) yc: f64,
    pub(super) gain: f32,
    pub(super) sky: f32,
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
    pub(super) fn row(
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
    pub(super) fn run(&self, l0: u32, lods: &[f64], x: &[f64], y: &[f64], out: &mut [f32]) -> bool {
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
    pub(super) fn row_general(
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
    pub(super) fn group4(
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
pub(super) fn approx_normal(seed: u64, idx: i64) -> f32 {
    let h = super::super::noise::hash2(seed, idx, 0x6e6f_6973);
    let s: f64 = (0..4).map(|k| super::super::noise::unit16(h, k)).sum();
    ((s - 2.0) * 3.0_f64.sqrt()) as f32
}
