//! The ground points of a block of image rows: every other row and column intersected
//! exactly, predicted from the solved pixels above, the points between as midpoints of their
//! neighbours'; every pixel exact without interpolation.

use super::RenderStats;
use super::intersect::{FAST_RUN, FastRun, Scene, fast_run, intersect};
use super::rays::{Ray, RowRays};

/// Pixel-to-pixel memory of a row: the last two solutions' depths.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Pred {
    pub(super) t1: Option<f64>,
    pub(super) t2: Option<f64>,
}

impl Pred {
    /// Linear extrapolation of the depth from the last two pixels (or the last one).
    pub(super) fn guess(&self) -> Option<f64> {
        match (self.t1, self.t2) {
            (Some(a), Some(b)) => Some(2.0 * a - b),
            (Some(a), None) => Some(a),
            _ => None,
        }
    }
    pub(super) fn push(&mut self, t: f64) {
        self.t2 = self.t1;
        self.t1 = Some(t);
    }
}

/// Ground points of a block of rows: depth along the optical axis (NaN for sky) and texture
/// offsets from the camera, row after row.
pub(super) struct GroundBlock {
    pub(super) t: Vec<f64>,
    pub(super) x: Vec<f64>,
    pub(super) y: Vec<f64>,
    pub(super) wu: usize,
    /// Level of detail of one row at every 4th column (NaN for sky).
    pub(super) lod: Vec<f64>,
    /// Grey levels of one row before noise and rounding.
    pub(super) vals: Vec<f32>,
}

impl GroundBlock {
    pub(super) fn new(wu: usize, rows: usize) -> Self {
        Self {
            t: vec![f64::NAN; wu * rows],
            x: vec![0.0; wu * rows],
            y: vec![0.0; wu * rows],
            wu,
            lod: Vec::with_capacity(wu.div_ceil(4)),
            vals: Vec::with_capacity(wu),
        }
    }

    pub(super) fn row(&self, r: usize) -> (&[f64], &[f64], &[f64]) {
        let k = r * self.wu..(r + 1) * self.wu;
        (&self.t[k.clone()], &self.x[k.clone()], &self.y[k])
    }

    pub(super) fn set(&mut self, k: usize, (t, x, y): (f64, f64, f64)) {
        self.t[k] = t;
        self.x[k] = x;
        self.y[k] = y;
    }

    /// Row `r` as the midpoints of rows `r − d` and `r + d`, in branch-free (vectorised) loops.
    /// A ground depth is finite, so the midpoint depth is NaN exactly where a neighbour is sky;
    /// returns whether the row has such pixels (the caller solves them).
    pub(super) fn mid_row(&mut self, r: usize, d: usize) -> bool {
        let wu = self.wu;
        for a in [&mut self.t, &mut self.x, &mut self.y] {
            let (head, tail) = a.split_at_mut(r * wu);
            let above = &head[(r - d) * wu..];
            let (row, below) = tail.split_at_mut(wu);
            let below = &below[(d - 1) * wu..d * wu];
            for ((m, &p), &q) in row.iter_mut().zip(above).zip(below) {
                *m = 0.5 * (p + q);
            }
        }
        any_nan(&self.t[r * wu..(r + 1) * wu])
    }

    /// Columns `first, first + 2d, …` of row `r` that have both neighbours `d` columns away
    /// as the midpoints of those neighbours, branch-free; returns whether the row has a NaN
    /// depth (sky, or a midpoint next to it).
    pub(super) fn mid_columns(&mut self, r: usize, first: usize, d: usize) -> bool {
        let row = r * self.wu..(r + 1) * self.wu;
        for a in [&mut self.t, &mut self.x, &mut self.y] {
            let a = &mut a[row.clone()];
            for col in (first..a.len().saturating_sub(d)).step_by(2 * d) {
                a[col] = 0.5 * (a[col - d] + a[col + d]);
            }
        }
        any_nan(&self.t[row])
    }
}

/// Whether any value is NaN (a fold without early exit, so it vectorises).
#[inline]
pub(super) fn any_nan(a: &[f64]) -> bool {
    a.iter().fold(false, |any, v| any | v.is_nan())
}

/// The intersection of the rays of a block of rows with the terrain.
///
/// With interpolation, the rays of every `spacing`-th row and column (2 or 4) are intersected
/// exactly and the ground points in between are the midpoints of their neighbours' (with 4:
/// first the midpoints 2 apart, then those between), which is linear interpolation. On a monotone frame
/// the ground point is a continuous function of the pixel whose derivative only jumps where
/// the ray's trace crosses an 8 m lattice edge of the bilinear height field, so over a 2-px
/// span (≈ 5 m at 2,700 m) the midpoint is off by at most a quarter of the span times that
/// jump: at 25° off nadir and a slope change of 0.2 across an edge, ~0.1 m on the ground
/// (0.05 px); on gentle terrain millimetres. The error grows with the square of the spacing:
/// ~0.4 m (0.16 px) at spacing 4. Without interpolation every pixel is exact.
pub(super) struct BlockGeometry<'a, F: Fn(f64) -> RowRays> {
    pub(super) rays_of_row: &'a F,
    pub(super) scene: &'a Scene<'a>,
    pub(super) wu: usize,
    /// Rows and columns between exact solves when interpolating: 2 or 4.
    pub(super) spacing: usize,
}

impl<F: Fn(f64) -> RowRays> BlockGeometry<'_, F> {
    /// Exact intersections of row `r` (image row `v`) at every `step`-th column and the last
    /// one, predicted from the block's rows `r − gap` and `r − 2 gap` when they exist, else
    /// from the pixels to the left; with `step` 2 the columns between are midpoints (or exact
    /// where a neighbour is sky).
    pub(super) fn solve_row(
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
            self.fill_columns(blk, r, 1, 1, gap, &rays, st);
        }
    }

    /// [`Self::solve_row`] with step and gap `spacing` for the rows `rs` (block rows `spacing`
    /// apart, each predicted from the one before), in turn, the columns between filled
    /// ([`Self::fill_between`]). Row 0 of a block is predicted from the left only, column
    /// after column; the rows below it are predicted from above, so their solved columns are
    /// independent of one another and go through [`Self::solve_from_above`].
    #[inline(always)]
    pub(super) fn solve_rows(
        &self,
        blk: &mut GroundBlock,
        rs: &[usize],
        v0: usize,
        st: &mut RenderStats,
    ) {
        let (wu, gap) = (self.wu, self.spacing);
        for &r in rs {
            let rays = (self.rays_of_row)((v0 + r) as f64);
            if r >= gap {
                self.solve_from_above(blk, r, &rays, st);
            } else {
                let mut pred = Pred::default();
                let mut col = 0;
                while col < wu {
                    self.solve_at(blk, r, gap, &rays, col, &mut pred, st);
                    col = next_col(col, gap, wu);
                }
            }
            self.fill_between(blk, r, &rays, st);
        }
    }

    /// The columns of solved row `r` between its solved ones: with spacing 4 those 2 apart
    /// first, then the odd ones; midpoints, or exact next to sky.
    #[inline(always)]
    fn fill_between(&self, blk: &mut GroundBlock, r: usize, rays: &RowRays, st: &mut RenderStats) {
        for &(first, d) in self.midpoint_levels() {
            self.fill_columns(blk, r, first, d, self.spacing, rays, st);
        }
    }

    /// The midpoint levels between solved rows or columns, coarsest first: `(first, d)`, the
    /// first interpolated index and the distance to its two neighbours.
    fn midpoint_levels(&self) -> &'static [(usize, usize)] {
        if self.spacing == 4 {
            &[(2, 2), (1, 1)]
        } else {
            &[(1, 1)]
        }
    }

    /// [`Self::solve_at`] (gap `spacing`) of row `r ≥ spacing` at every solved column, the same values: the
    /// fast paths of the columns with a ground pixel above first, [`FAST_RUN`] at a time in
    /// vectorised phases ([`fast_run`]), then, column after column, [`intersect`] where the fast
    /// path failed and the left-to-right prediction where the pixel above is sky.
    #[inline(always)]
    fn solve_from_above(
        &self,
        blk: &mut GroundBlock,
        r: usize,
        rays: &RowRays,
        st: &mut RenderStats,
    ) {
        let (wu, gap) = (self.wu, self.spacing);
        let mut pred = Pred::default();
        let mut fast = FastRun::default();
        let mut cols = [0_usize; FAST_RUN];
        let mut a1 = [0.0_f64; FAST_RUN];
        let mut guess = [0.0_f64; FAST_RUN];
        let mut col = 0;
        while col < wu {
            let mut m = 0;
            while m < FAST_RUN && col < wu {
                cols[m] = col;
                m += 1;
                col = next_col(col, gap, wu);
            }
            for j in 0..m {
                let (p1, p2) = (
                    self.above(blk, r, gap, cols[j], 1),
                    self.above(blk, r, gap, cols[j], 2),
                );
                a1[j] = p1;
                // `predict` with a ground pixel above (NaN, and not used, without one).
                guess[j] = if p2.is_nan() { p1 } else { 2.0 * p1 - p2 };
            }
            fast_run(rays, &cols[..m], &guess[..m], self.scene.table, &mut fast);
            for j in 0..m {
                let c = cols[j];
                let sol = if a1[j].is_nan() {
                    intersect(&rays.at(c as f64), self.scene, pred.guess(), st)
                } else if fast.ok[j] {
                    st.height_lookups += 1;
                    Some((fast.t[j], fast.x[j], fast.y[j]))
                } else {
                    intersect(&rays.at(c as f64), self.scene, Some(guess[j]), st)
                };
                match sol {
                    Some((t, _, _)) => pred.push(t),
                    None => pred = Pred::default(),
                }
                blk.set(r * wu + c, sol.unwrap_or((f64::NAN, 0.0, 0.0)));
            }
        }
    }

    /// Depth of row `r` at `gap · k` rows above, NaN when outside the block.
    #[inline(always)]
    pub(super) fn above(
        &self,
        blk: &GroundBlock,
        r: usize,
        gap: usize,
        col: usize,
        k: usize,
    ) -> f64 {
        if r >= k * gap {
            blk.t[(r - k * gap) * self.wu + col]
        } else {
            f64::NAN
        }
    }

    /// Exact intersection of row `r` at `col`, predicted from above or from the left.
    #[inline(always)]
    #[expect(
        clippy::too_many_arguments,
        reason = "inner-loop state the four callers borrow from different places (interleaved \
                  rows share the block and statistics); inlined"
    )]
    pub(super) fn solve_at(
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

    /// Columns `first, first + 2d, …` of row `r` (their neighbours `d` away filled): midpoints,
    /// or exact next to sky, predicted from the rows `gap` and `2 gap` above.
    #[expect(
        clippy::too_many_arguments,
        reason = "the columns' pattern, the row's predictors and the statistics; inlined"
    )]
    pub(super) fn fill_columns(
        &self,
        blk: &mut GroundBlock,
        r: usize,
        first: usize,
        d: usize,
        gap: usize,
        rays: &RowRays,
        st: &mut RenderStats,
    ) {
        let wu = self.wu;
        let base = r * wu;
        if !blk.mid_columns(r, first, d) {
            return;
        }
        for col in (first..wu.saturating_sub(d)).step_by(2 * d) {
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
    pub(super) fn solve_alone(
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

    /// Rows `0, s, 2s, …` of the block (image rows from `v0`, `s` the spacing) solved by
    /// [`Self::solve_rows`], the rows between as midpoints of the rows `d` above and below
    /// (with spacing 4: `d` = 2, then 1; the block's extra last row is the first row of the
    /// next block, solved here too; rows at the image's bottom without a filled row below are
    /// solved directly).
    #[inline(always)]
    pub(super) fn solve_interpolated(
        &self,
        blk: &mut GroundBlock,
        v0: usize,
        n_rows: usize,
        image_rows: usize,
        st: &mut RenderStats,
    ) {
        let (wu, s) = (self.wu, self.spacing);
        let below_last = v0 + n_rows < image_rows;
        let extra = (n_rows.is_multiple_of(s) && below_last).then_some(n_rows);
        let rs: Vec<usize> = (0..n_rows).step_by(s).chain(extra).collect();
        self.solve_rows(blk, &rs, v0, st);
        // Row `r + d` is filled: inside the block (solved, or filled at the previous level) or
        // the next block's first row.
        let filled_below = |r: usize, d: usize| r + d < n_rows || extra == Some(r + d);
        for &(first, d) in self.midpoint_levels() {
            for r in (first..n_rows).step_by(2 * d) {
                if !filled_below(r, d) {
                    // Predicted from the filled rows `d` and `2d` above (never a row of this
                    // level still to come: the buffer holds an earlier block's values there).
                    self.solve_row(blk, r, v0 + r, 2, d, st);
                    continue;
                }
                if !blk.mid_row(r, d) {
                    continue;
                }
                let rays = (self.rays_of_row)((v0 + r) as f64);
                for col in 0..wu {
                    let k = r * wu + col;
                    if blk.t[k].is_nan() {
                        let guess = predict(blk.t[k - d * wu], f64::NAN, &Pred::default());
                        blk.set(k, self.solve_alone(&rays, col, guess, st));
                    }
                }
            }
        }
    }
}

/// Next solved column after `col`: every `step`-th, then (step 4) every 2nd where the row
/// ends before the next 4th, and the last one.
#[inline(always)]
pub(super) fn next_col(col: usize, step: usize, wu: usize) -> usize {
    if col + step < wu || col + 1 >= wu {
        col + step
    } else if step > 2 && col + 2 < wu {
        col + 2
    } else {
        wu - 1
    }
}

/// Depth prediction from the two pixels above (`a1` nearer; NaN when absent), else from the
/// pixels to the left.
#[inline(always)]
pub(super) fn predict(a1: f64, a2: f64, pred: &Pred) -> Option<f64> {
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
pub(super) fn solve_ray(
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
