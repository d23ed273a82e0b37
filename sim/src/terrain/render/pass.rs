//! The main pass over a block of image rows (ground points, levels of detail, shading,
//! rounding) and its two builds: the baseline CPU's and AVX2's, chosen at run time.

use super::ground::{BlockGeometry, GroundBlock};
use super::intersect::Scene;
use super::lod::{lod_footprint, lods_of_row};
use super::rays::RowRays;
use super::shading::{SHADE_STRIP, Shader, approx_normal, to_grey};
use super::{RenderOptions, RenderStats};

/// The main pass over one block of image rows: ground points, levels of detail, shading and
/// rounding. Compiled twice: for the baseline CPU and, where the CPU has them, with AVX2 and
/// its companions, under which the vectorised loops run twice as wide. Both builds perform
/// the same IEEE operations (Rust never fuses a multiply and an add on its own), so they give
/// the same bits (test `the_avx2_build_renders_the_portable_bits`).
pub(super) struct MainPass<'a, F: Fn(f64) -> RowRays> {
    pub(super) row_rays: &'a F,
    pub(super) scene: &'a Scene<'a>,
    pub(super) shade: &'a Shader<'a>,
    pub(super) f_px: f64,
    pub(super) wu: usize,
    pub(super) image_rows: usize,
    pub(super) rows_per_chunk: usize,
    pub(super) interpolate: bool,
    pub(super) opts: RenderOptions,
    /// Run the AVX2 build (set only where the CPU has been found to support it).
    pub(super) avx2: bool,
}

/// Whether this CPU runs [`MainPass::block_avx2`].
pub(super) fn has_avx2() -> bool {
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
    pub(super) fn block(
        &self,
        blk: &mut GroundBlock,
        chunk: usize,
        rows: &mut [u8],
    ) -> RenderStats {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is true only when `has_avx2` found every feature the function is
            // compiled for on this CPU.
            #[expect(
                unsafe_code,
                reason = "calling the AVX2 build needs `unsafe`; it runs only where `has_avx2` \
                          found the features"
            )]
            return unsafe { self.block_avx2(blk, chunk, rows) };
        }
        self.block_body(blk, chunk, rows)
    }

    /// [`Self::block_body`] compiled with the AVX2 features (the x86-64-v3 set less those the
    /// renderer cannot use); to be called only where the CPU has them.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    pub(super) fn block_avx2(
        &self,
        blk: &mut GroundBlock,
        chunk: usize,
        rows: &mut [u8],
    ) -> RenderStats {
        self.block_body(blk, chunk, rows)
    }

    /// The pass itself, inlined into each build.
    #[inline(always)]
    pub(super) fn block_body(
        &self,
        blk: &mut GroundBlock,
        chunk: usize,
        rows: &mut [u8],
    ) -> RenderStats {
        let rays_of_row = self.row_rays;
        let mut st = RenderStats::default();
        let v0 = chunk * self.rows_per_chunk;
        let wu = self.wu;
        let n_rows = rows.len() / wu;
        let geom = BlockGeometry {
            rays_of_row: self.row_rays,
            scene: self.scene,
            wu,
            spacing: self.opts.solve_spacing_px,
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
