//! Intersection of one ray with the bilinear height field: the frame's height table, the
//! one-Newton-step fast path from a predicted depth, the bracketed Newton/bisection and the
//! Lipschitz march (module doc of [`super`]).

use super::super::Terrain;
use super::super::tiles::{HEIGHT_SPACING_M, HEIGHT_STRIDE, HEIGHT_TILE};
use super::fixed::{FIX_BITS, FIX_MASK, FIX_ONE, round_i64, split_fixed};
use super::rays::{Ray, RowRays};
use super::{MAX_RANGE_M, RenderStats};

/// Convergence of the intersection: height mismatch, m.
pub(super) const TOL_H_M: f64 = 2e-3;
/// Caps of the root-finding loops.
pub(super) const MAX_SECANT_ITER: usize = 60;
pub(super) const MAX_MARCH_STEPS: usize = 20_000;

/// Height and gradient outside the frame's tiles: direct evaluation (kept out of line so the
/// hot loop stays small).
#[cold]
#[inline(never)]
pub(super) fn slow_height_grad(terrain: &Terrain, x: f64, y: f64) -> (f64, f64, f64) {
    terrain.height_grad_xy_m(x, y)
}

/// The height field of one frame: its tiles in a dense table.
pub(super) struct HeightTable<'a> {
    pub(super) terrain: &'a Terrain,
    /// The tiles' samples (slices of the frame's `Arc`s: one dependent load less per look-up).
    pub(super) tiles: Vec<&'a [f32]>,
    pub(super) ntx: i64,
    pub(super) nty: i64,
    /// Lattice coordinates of the camera relative to the table origin.
    pub(super) ox: f64,
    pub(super) oy: f64,
    /// Camera texture coordinates (for the slow path).
    pub(super) xc: f64,
    pub(super) yc: f64,
    /// Whether the table holds every tile the frame's rays can reach within the slab (then
    /// its slope bound holds along every ray).
    pub(super) covers_frame: bool,
}

impl HeightTable<'_> {
    /// Height and its gradient (per texture metre) at texture offsets `(x, y)`.
    #[inline(always)]
    pub(super) fn height_grad(&self, x: f64, y: f64) -> (f64, f64, f64) {
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
        super::super::bilinear_grad(
            h[k],
            h[k + 1],
            h[k + HEIGHT_STRIDE],
            h[k + HEIGHT_STRIDE + 1],
            fx,
            fy,
        )
    }
}

/// Frame-wide constants of the intersection.
pub(super) struct Scene<'a> {
    pub(super) table: &'a HeightTable<'a>,
    pub(super) h_lo: f64,
    pub(super) h_hi: f64,
    pub(super) slope_bound: f64,
    pub(super) far_slope_bound: f64,
    /// Every ray of the frame has a strictly decreasing `f` over the slab.
    pub(super) all_monotone: bool,
    pub(super) camera_ground_t: Option<f64>,
}

/// Largest height mismatch accepted with one Newton correction and no further look-up, m:
/// the step is exact on a bilinear cell, and across a cell edge its error is below
/// `ACCEPT · Δslope`, a few centimetres on the ground.
pub(super) const NEWTON_ACCEPT_M: f64 = 0.2;

/// `f(t)`, `f'(t)` and the texture point of the ray at `t`.
#[inline(always)]
pub(super) fn eval(
    ray: &Ray,
    table: &HeightTable<'_>,
    t: f64,
    lookups: &mut u64,
) -> (f64, f64, f64, f64) {
    *lookups += 1;
    let (x, y, hr) = ray.xyh(t);
    let (h, hx, hy) = table.height_grad(x, y);
    let dh = ray.ch1 + 2.0 * ray.ch2 * t;
    let dx = ray.cx1 + 2.0 * ray.cx2 * t;
    let dy = ray.cy1 + 2.0 * ray.cy2 * t;
    (hr - h, dh - hx * dx - hy * dy, x, y)
}

/// Solved pixels of one row handled together by [`fast_run`] at most.
pub(super) const FAST_RUN: usize = 128;

/// What [`fast_run`] found: the fast path's `(t, x, y)` where `ok`.
pub(super) struct FastRun {
    pub(super) t: [f64; FAST_RUN],
    pub(super) x: [f64; FAST_RUN],
    pub(super) y: [f64; FAST_RUN],
    pub(super) ok: [bool; FAST_RUN],
}

impl Default for FastRun {
    fn default() -> Self {
        Self {
            t: [0.0; FAST_RUN],
            x: [0.0; FAST_RUN],
            y: [0.0; FAST_RUN],
            ok: [false; FAST_RUN],
        }
    }
}

/// The fast path of [`intersect`] (on a frame whose rays are all monotone) for the rays of
/// `rays` at the columns `cols` (at most [`FAST_RUN`]) from their guesses: `ok` where it
/// succeeds, with the values `intersect` gives; not `ok` where `intersect` would go on to its
/// general case, or where the guess is NaN, or the point falls outside the frame's height
/// tiles (`intersect` then evaluates the height directly). The same operations as `intersect`
/// in three loops of independent iterations: rays, points and lattice cells (vectorised),
/// height loads, then the Newton step and its checks (vectorised).
#[inline(always)]
pub(super) fn fast_run(
    rays: &RowRays,
    cols: &[usize],
    guess: &[f64],
    table: &HeightTable<'_>,
    out: &mut FastRun,
) {
    const N: usize = FAST_RUN;
    let m = cols.len().min(guess.len()).min(N);
    let (mut hr, mut dh, mut dx, mut dy) = ([0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    let (mut n2, mut fx, mut fy) = ([0.0; N], [0.0; N], [0.0; N]);
    let (mut tile, mut cell) = ([0_u64; N], [0_u64; N]);
    let mut inside = [false; N];
    let (ntx, nty) = (table.ntx as u64, table.nty as u64);
    let tile_bits = HEIGHT_TILE.trailing_zeros();
    for j in 0..m {
        let ray = rays.at(cols[j] as f64);
        let t0 = guess[j];
        let (x, y, h) = ray.xyh(t0);
        out.x[j] = x;
        out.y[j] = y;
        hr[j] = h;
        dh[j] = ray.ch1 + 2.0 * ray.ch2 * t0;
        dx[j] = ray.cx1 + 2.0 * ray.cx2 * t0;
        dy[j] = ray.cy1 + 2.0 * ray.cy2 * t0;
        n2[j] = ray.n2;
        // `HeightTable::height_grad`'s cell and weights; a logical shift turns a negative
        // coordinate into a tile beyond the table, outside as the arithmetic shift's is.
        let gx = round_i64((x * (1.0 / HEIGHT_SPACING_M) + table.ox) * FIX_ONE);
        let gy = round_i64((y * (1.0 / HEIGHT_SPACING_M) + table.oy) * FIX_ONE);
        let (ix, iy) = ((gx as u64) >> FIX_BITS, (gy as u64) >> FIX_BITS);
        fx[j] = f64::from((gx & FIX_MASK) as i32) * (1.0 / FIX_ONE);
        fy[j] = f64::from((gy & FIX_MASK) as i32) * (1.0 / FIX_ONE);
        let (tx, ty) = (ix >> tile_bits, iy >> tile_bits);
        inside[j] = (tx < ntx) & (ty < nty);
        tile[j] = ty.wrapping_mul(ntx).wrapping_add(tx);
        let (lx, ly) = (ix & (HEIGHT_TILE as u64 - 1), iy & (HEIGHT_TILE as u64 - 1));
        cell[j] = ly * HEIGHT_STRIDE as u64 + lx;
    }
    let mut corners = [[0.0_f32; 4]; N];
    for j in 0..m {
        if !inside[j] {
            continue;
        }
        let k = cell[j] as usize;
        match table
            .tiles
            .get(tile[j] as usize)
            .and_then(|h| h.get(k..k + HEIGHT_STRIDE + 2))
        {
            Some(h) => corners[j] = [h[0], h[1], h[HEIGHT_STRIDE], h[HEIGHT_STRIDE + 1]],
            None => inside[j] = false,
        }
    }
    let in_range = |t: f64, n2: f64| t > 0.0 && t * t * n2 < MAX_RANGE_M * MAX_RANGE_M;
    for j in 0..m {
        let [h00, h10, h01, h11] = corners[j];
        let (h, hx, hy) = super::super::bilinear_grad(h00, h10, h01, h11, fx[j], fy[j]);
        let (f0, d0) = (hr[j] - h, dh[j] - hx * dx[j] - hy * dy[j]);
        let t0 = guess[j];
        let step = -f0 / d0;
        let t1 = t0 + step;
        out.ok[j] = inside[j]
            & in_range(t0, n2[j])
            & (d0 < 0.0)
            & f0.is_finite()
            & (f0.abs() < NEWTON_ACCEPT_M)
            & in_range(t1, n2[j]);
        out.t[j] = t1;
        out.x[j] += dx[j] * step;
        out.y[j] += dy[j] * step;
    }
}

/// Whether `f` is strictly decreasing on `[0, t_bot]` for this ray: `f' ≤ h' + L·|(x', y')|`
/// with `h' = ch1 + 2 ch2 t` and the horizontal rate at most `|(cx1, cy1)| + 2 t |(cx2, cy2)|`.
#[inline]
pub(super) fn monotone(ray: &Ray, t_bot: f64, slope_bound: f64, margin: f64) -> bool {
    let hor1 = (ray.cx1 * ray.cx1 + ray.cy1 * ray.cy1).sqrt();
    let hor2 = (ray.cx2 * ray.cx2 + ray.cy2 * ray.cy2).sqrt();
    ray.ch1 + 2.0 * ray.ch2.max(0.0) * t_bot + slope_bound * (hor1 + 2.0 * hor2 * t_bot)
        < margin * ray.ch1
}

/// Intersection of `ray` with the terrain: `(t, x, y)`, or `None` for sky.
#[inline(always)]
pub(super) fn intersect(
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
pub(super) fn intersect_slow(
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
pub(super) fn solve_newton(
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
pub(super) fn march(
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
