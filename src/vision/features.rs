//! Feature detection of semi-direct visual odometry (SVO; Forster, Pizzoli and Scaramuzza, "SVO:
//! Fast Semi-Direct Monocular Visual Odometry", ICRA 2014; the paper's SVO figure: mapping
//! thread, "Feature Detection", run on keyframes), as SVO's reference implementation does it:
//! FAST corners on the finer pyramid levels, each scored by Shi and Tomasi's "good features to
//! track" score, and at most one feature per cell of a grid over the level-0 image, the best
//! over all levels; cells that already hold a tracked feature are skipped.
//!
//! - FAST-9: segment test on the radius-3 circle of 16 pixels, 9 contiguous all brighter or all
//!   darker. Its threshold is a difference in grey levels (0–255) that the circle pixels must
//!   exceed strictly, the same unit as OpenCV's and SVO's; SVO uses 20. Non-maximum suppression
//!   over 3 × 3 neighbours on the FAST score, the largest threshold at which the pixel is still
//!   a corner (`imageproc`'s score). Ties (common on synthetic images) keep the first pixel in
//!   row-major order, so a plateau keeps one corner. The test and the score are computed here,
//!   16 pixels at a time, and only where the result depends on them (pixels of free cells
//!   inside the border, and their neighbours); the corners and scores are exactly those of
//!   `imageproc::corners::corners_fast9`, which the tests use as the oracle (it scores every
//!   corner of the image by a binary search on the threshold: 30–50 ms per 768 × 1024 frame).
//! - Shi-Tomasi score: the smaller eigenvalue of the mean structure tensor `⟨∇I ∇Iᵀ⟩` over the
//!   8 × 8 window `[x − 4, x + 4) × [y − 4, y + 4)` of the detection level, with central
//!   differences `(I(x+1) − I(x−1)) / 2`. Scores are compared across levels at level-0 scale:
//!   a gradient per level-`l` pixel is `2^l` times the gradient per level-0 pixel, so the score
//!   is divided by `4^l`. Unit: (grey levels / level-0 pixel)². SVO's score uses undivided
//!   differences and divides the sums by twice the window size, so it is twice this one at
//!   level 0; its minimum corner score of 20 is 10 here.
//! - Grid: square cells of [`DetectorConfig::cell_size_px`] level-0 pixels, `⌈W/s⌉ × ⌈H/s⌉`
//!   cells, cell `(c, r)` spanning `[c s − 0.5, (c+1) s − 0.5) × [r s − 0.5, (r+1) s − 0.5)` in
//!   the pixel-centre convention. A corner of level `l` at level pixel `(x, y)` sits at
//!   `u_0 = 2^l (x + 0.5) − 0.5` on level 0 (the camera module's level convention).
//! - Cell size 64 px: 12 × 16 = 192 cells on the 768 × 1024 frame, which divides both sides
//!   and is a whole 4 × 4 block of the coarsest level. SVO uses 25–30 px cells for 752 × 480
//!   images (≈ 400 cells, at most 120–200 features kept); 192 cells give the 150–250 features
//!   wanted per keyframe on this larger image. Measured on synthetic 768 × 1024 frames of
//!   random grey rectangles: all 192 cells get a feature when the texture is dense (test
//!   `textured_frame_count`), 180 with 600 rectangles and a 3 × 3 blur, 154 with 300.
//! - Levels 0–2 by default, as SVO (its `n_pyr_levels` = 3): levels 3 and 4 exist for sparse
//!   image alignment, and a level-4 corner would stand for a 128-px patch on level 0.
//! - A border of 8 level pixels is kept clear (room for the 8 × 8 alignment patch and its
//!   one-pixel margin after small warps).

use image::GrayImage;
use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use crate::vision::camera::Camera;
use crate::vision::pyramid::{PYRAMID_LEVELS, Pyramid};

/// Side of the Shi-Tomasi window, px of the detection level.
pub const SHI_TOMASI_WINDOW_PX: u32 = 8;

/// Half of [`SHI_TOMASI_WINDOW_PX`].
const HALF_WINDOW: u32 = SHI_TOMASI_WINDOW_PX / 2;

/// Smallest border the detector accepts: the Shi-Tomasi window reaches 5 pixels left of and
/// above the corner (4 for the window, 1 for the central difference).
const MIN_BORDER_PX: u32 = HALF_WINDOW + 1;

/// Why detection could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FeatureError {
    /// A configuration field has a value outside its domain.
    #[error("feature detector: `{field}` = {value}: {reason}")]
    InvalidConfig {
        /// Field name.
        field: &'static str,
        /// The rejected value.
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
    /// The pyramid or the occupancy mask was made for another image size or grid.
    #[error(
        "feature detector: expected a {expected_width}×{expected_height} px image with {cell_size_px}-px cells, got {actual_width}×{actual_height} px with {actual_cell_size_px}-px cells"
    )]
    SizeMismatch {
        /// Detector image width, px.
        expected_width: u32,
        /// Detector image height, px.
        expected_height: u32,
        /// Detector cell size, px.
        cell_size_px: u32,
        /// Width of the pyramid's level 0 or of the mask's grid, px.
        actual_width: u32,
        /// Height of the pyramid's level 0 or of the mask's grid, px.
        actual_height: u32,
        /// Cell size of the mask's grid (the detector's own for a pyramid), px.
        actual_cell_size_px: u32,
    },
    /// The pyramid has fewer levels than the detector searches.
    #[error("feature detector: needs {needed} pyramid levels, the pyramid has {available}")]
    TooFewLevels {
        /// Levels searched.
        needed: u32,
        /// Levels in the pyramid.
        available: u32,
    },
}

/// Detector settings (SVO defaults adapted to the 768 × 1024 camera). TOML table
/// `[vision.detector]` of the navigation settings; a missing key takes its default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Side of a grid cell, level-0 px (8–1024): at most one feature per cell, so this sets
    /// how many features a keyframe gets (192 cells of 64 px on 768 × 1024).
    pub cell_size_px: u32,
    /// FAST-9 threshold, grey levels (1–255): the circle pixels must differ from the centre by
    /// more than this for a corner.
    pub fast_threshold: u8,
    /// Minimum Shi-Tomasi score a feature must exceed, (grey levels / level-0 px)² (half of
    /// SVO's score, module doc); weaker corners are not kept.
    pub min_shi_tomasi_score: f32,
    /// Pyramid levels searched for corners, a count from level 0 (1–5).
    pub n_levels: u32,
    /// Corners closer than this to the image edge are ignored, px of their level (5–64).
    pub border_px: u32,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            cell_size_px: 64,
            fast_threshold: 20,
            min_shi_tomasi_score: 10.0,
            n_levels: 3,
            border_px: 8,
        }
    }
}

fn invalid(field: &'static str, value: f64, reason: &'static str) -> FeatureError {
    FeatureError::InvalidConfig {
        field,
        value,
        reason,
    }
}

impl DetectorConfig {
    /// Validate; errors name the field.
    pub fn validate(&self) -> Result<(), FeatureError> {
        if !(8..=1024).contains(&self.cell_size_px) {
            return Err(invalid(
                "cell_size_px",
                f64::from(self.cell_size_px),
                "must be 8 to 1024 px",
            ));
        }
        if self.fast_threshold == 0 {
            // A zero threshold would also make a zero FAST score, which marks "no corner".
            return Err(invalid("fast_threshold", 0.0, "must be 1 to 255"));
        }
        if !(self.min_shi_tomasi_score.is_finite() && self.min_shi_tomasi_score >= 0.0) {
            return Err(invalid(
                "min_shi_tomasi_score",
                f64::from(self.min_shi_tomasi_score),
                "must be finite and ≥ 0",
            ));
        }
        if !(1..=PYRAMID_LEVELS).contains(&self.n_levels) {
            return Err(invalid(
                "n_levels",
                f64::from(self.n_levels),
                "must be 1 to 5",
            ));
        }
        if !(MIN_BORDER_PX..=64).contains(&self.border_px) {
            return Err(invalid(
                "border_px",
                f64::from(self.border_px),
                "must be 5 to 64 px",
            ));
        }
        Ok(())
    }
}

/// Grid of square cells over the level-0 image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    width_px: u32,
    height_px: u32,
    cell_size_px: u32,
    cols: u32,
    rows: u32,
}

impl Grid {
    /// Grid of `cell_size_px` cells over a `width_px × height_px` image (the last column and
    /// row of cells may be cut by the image edge).
    pub fn new(width_px: u32, height_px: u32, cell_size_px: u32) -> Result<Self, FeatureError> {
        if cell_size_px == 0 {
            return Err(invalid("cell_size_px", 0.0, "must be positive"));
        }
        if width_px == 0 || height_px == 0 {
            return Err(invalid(
                "image size",
                f64::from(width_px.min(height_px)),
                "must be positive",
            ));
        }
        Ok(Self {
            width_px,
            height_px,
            cell_size_px,
            cols: width_px.div_ceil(cell_size_px),
            rows: height_px.div_ceil(cell_size_px),
        })
    }

    /// Cell side, level-0 px.
    pub fn cell_size_px(&self) -> u32 {
        self.cell_size_px
    }

    /// Columns of cells.
    pub fn cols(&self) -> u32 {
        self.cols
    }

    /// Rows of cells.
    pub fn rows(&self) -> u32 {
        self.rows
    }

    /// Number of cells.
    pub fn n_cells(&self) -> usize {
        self.cols as usize * self.rows as usize
    }

    /// Index (row-major) of the cell holding the level-0 point `px`; `None` outside the image
    /// `[-0.5, W − 0.5) × [-0.5, H − 0.5)` or for non-finite coordinates.
    pub fn cell_of(&self, px: &Vector2<f64>) -> Option<usize> {
        let (u, v) = (px.x + 0.5, px.y + 0.5);
        // Written so that NaN fails the test.
        if !(u >= 0.0 && v >= 0.0 && u < f64::from(self.width_px) && v < f64::from(self.height_px))
        {
            return None;
        }
        let s = f64::from(self.cell_size_px);
        let (col, row) = ((u / s) as usize, (v / s) as usize);
        Some(row * self.cols as usize + col)
    }
}

/// Which grid cells already hold a tracked feature.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Occupancy {
    grid: Grid,
    occupied: Vec<bool>,
}

impl Occupancy {
    /// All cells free.
    pub fn new(grid: Grid) -> Self {
        Self {
            occupied: vec![false; grid.n_cells()],
            grid,
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Mark the cell holding the level-0 point `px`; `false` if it lies outside the image.
    pub fn occupy(&mut self, px: &Vector2<f64>) -> bool {
        match self.grid.cell_of(px) {
            Some(i) => self.occupy_cell(i),
            None => false,
        }
    }

    /// Mark cell `index`; `false` if there is no such cell.
    pub fn occupy_cell(&mut self, index: usize) -> bool {
        match self.occupied.get_mut(index) {
            Some(cell) => {
                *cell = true;
                true
            }
            None => false,
        }
    }

    /// Whether cell `index` is occupied (`false` for a nonexistent cell).
    pub fn is_occupied(&self, index: usize) -> bool {
        self.occupied.get(index).copied().unwrap_or(false)
    }

    /// Number of occupied cells.
    pub fn n_occupied(&self) -> usize {
        self.occupied.iter().filter(|&&o| o).count()
    }

    /// Free every cell.
    pub fn clear(&mut self) {
        self.occupied.fill(false);
    }
}

/// A new feature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feature {
    /// Position on level 0 (pixel-centre convention), px.
    pub px: Vector2<f64>,
    /// Pyramid level it was detected on.
    pub level: u32,
    /// Shi-Tomasi score at level-0 scale, (grey levels / level-0 px)².
    pub score: f32,
}

/// Grid FAST detector with Shi-Tomasi scoring.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureDetector {
    config: DetectorConfig,
    grid: Grid,
}

impl FeatureDetector {
    /// Detector for frames of `camera`.
    pub fn new(config: DetectorConfig, camera: &Camera) -> Result<Self, FeatureError> {
        config.validate()?;
        let grid = Grid::new(camera.width_px(), camera.height_px(), config.cell_size_px)?;
        Ok(Self { config, grid })
    }

    /// The settings.
    pub fn config(&self) -> &DetectorConfig {
        &self.config
    }

    /// The grid over level 0.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// An occupancy mask of this detector's grid with every cell free.
    pub fn empty_occupancy(&self) -> Occupancy {
        Occupancy::new(self.grid)
    }

    fn mismatch(&self, w: u32, h: u32, cell: u32) -> FeatureError {
        FeatureError::SizeMismatch {
            expected_width: self.grid.width_px,
            expected_height: self.grid.height_px,
            cell_size_px: self.grid.cell_size_px,
            actual_width: w,
            actual_height: h,
            actual_cell_size_px: cell,
        }
    }

    /// New features of `pyramid`: in every free cell of `occupancy`, the corner with the best
    /// Shi-Tomasi score above the minimum over the searched levels. Sorted by cell (row-major);
    /// equal scores keep the finer level, then the first corner in row-major order.
    pub fn detect(
        &self,
        pyramid: &Pyramid,
        occupancy: &Occupancy,
    ) -> Result<Vec<Feature>, FeatureError> {
        let (w, h) = pyramid.base().dimensions();
        if (w, h) != (self.grid.width_px, self.grid.height_px) {
            return Err(self.mismatch(w, h, self.grid.cell_size_px));
        }
        if occupancy.grid != self.grid {
            let g = occupancy.grid;
            return Err(self.mismatch(g.width_px, g.height_px, g.cell_size_px));
        }
        if pyramid.n_levels() < self.config.n_levels {
            return Err(FeatureError::TooFewLevels {
                needed: self.config.n_levels,
                available: pyramid.n_levels(),
            });
        }
        let mut best: Vec<Option<Feature>> = vec![None; self.grid.n_cells()];
        let mut scratch = Scratch::default();
        for (level, img) in (0..self.config.n_levels).zip(pyramid.levels()) {
            self.detect_level(level, img, occupancy, &mut scratch, &mut best);
        }
        Ok(best.into_iter().flatten().collect())
    }

    /// One level's corners into `best`.
    ///
    /// Rows are scanned top to bottom with the FAST scores of three rows kept: the scores of
    /// row `y + 1` are computed, then the corners of row `y` are suppressed against rows
    /// `y − 1` to `y + 1`. Only the pixels the result depends on are tested: the corner
    /// candidates of free cells inside the border, and their 8 neighbours.
    fn detect_level(
        &self,
        level: u32,
        img: &GrayImage,
        occupancy: &Occupancy,
        scratch: &mut Scratch,
        best: &mut [Option<Feature>],
    ) {
        let (w, h) = img.dimensions();
        let border = self.config.border_px;
        if w <= 2 * border || h <= 2 * border {
            return;
        }
        let (w, h, b) = (w as usize, h as usize, border as usize);
        let cols = self.grid.cols as usize;
        let threshold = self.config.fast_threshold;
        let pixels = img.as_raw();
        scratch.prepare(&self.grid, level, w, h, b);
        let Scratch {
            scores,
            col_span,
            col_cell,
            row_cell,
            spans,
        } = scratch;
        let free = |r: usize, c: usize| !occupancy.occupied[r * cols + c];
        // FAST scores of row `y` (0 = no corner) into its slot of `scores`, over the columns
        // of the cells that hold a candidate on rows `y − 1` to `y + 1`, widened by one pixel.
        let score_row = |y: usize, scores: &mut [u8], spans: &mut Vec<(usize, usize)>| {
            spans.clear();
            let cell_rows = &row_cell[y - 1..=y + 1];
            for (c, span) in col_span.iter().enumerate() {
                let Some((x0, x1)) = *span else { continue };
                if !cell_rows.iter().flatten().any(|&r| free(r, c)) {
                    continue;
                }
                let (x0, x1) = (x0 - 1, x1 + 1);
                match spans.last_mut() {
                    Some(last) if last.1 >= x0 => last.1 = last.1.max(x1),
                    _ => spans.push((x0, x1)),
                }
            }
            if spans.is_empty() {
                return;
            }
            let rows: [&[u8]; 7] = std::array::from_fn(|i| &pixels[(y + i - 3) * w..][..w]);
            let out = &mut scores[(y % 3) * w..][..w];
            for &(x0, x1) in spans.iter() {
                fast9_span(&rows, x0, x1, threshold, out);
            }
        };
        score_row(b - 1, scores, spans);
        score_row(b, scores, spans);
        let to_level_0 = 0.25_f32.powi(level as i32);
        // A corner that survived the suppression: its Shi-Tomasi score against its cell's best.
        let mut consider = |x: usize, y: usize, r: usize| {
            let Some(c) = col_cell[x] else {
                return;
            };
            let (x, y) = (x as u32, y as u32);
            let Some(score) = shi_tomasi_score(img, x, y) else {
                return;
            };
            let score = score * to_level_0;
            if score <= self.config.min_shi_tomasi_score {
                return;
            }
            let slot = &mut best[r * cols + c];
            if slot.is_none_or(|f| score > f.score) {
                let px = Camera::level_to_base(&Vector2::new(f64::from(x), f64::from(y)), level);
                *slot = Some(Feature { px, level, score });
            }
        };
        for y in b..h - b {
            score_row(y + 1, scores, spans);
            let Some(r) = row_cell[y] else { continue };
            let up = &scores[((y - 1) % 3) * w..][..w];
            let mid = &scores[(y % 3) * w..][..w];
            let down = &scores[((y + 1) % 3) * w..][..w];
            // Candidate columns: the free cells of this row, adjacent ones merged.
            spans.clear();
            for (c, span) in col_span.iter().enumerate() {
                let Some((x0, x1)) = *span else { continue };
                if !free(r, c) {
                    continue;
                }
                match spans.last_mut() {
                    Some(last) if last.1 == x0 => last.1 = x1,
                    _ => spans.push((x0, x1)),
                }
            }
            for &(x0, x1) in spans.iter() {
                let mut x = x0;
                while x < x1 {
                    // Blocks as in `fast9_span`; lanes outside `[x, x1)` are dropped.
                    let start = if x1 - x0 >= LANES {
                        x.min(x1 - LANES)
                    } else {
                        x
                    };
                    let keep = x1.min(start + LANES);
                    let mut mask = if start + LANES < w {
                        local_max_mask(up, mid, down, start)
                    } else {
                        (start..keep).fold(0_u16, |m, i| {
                            let max = mid[i] != 0 && is_local_max(up, mid, down, i);
                            m | u16::from(max) << (i - start)
                        })
                    };
                    mask &= ((1_u32 << (keep - start)) - (1_u32 << (x - start))) as u16;
                    while mask != 0 {
                        consider(start + mask.trailing_zeros() as usize, y, r);
                        mask &= mask - 1;
                    }
                    x = keep;
                }
            }
        }
    }
}

/// Per-level work space of [`FeatureDetector::detect`].
#[derive(Debug, Default)]
struct Scratch {
    /// FAST scores of three consecutive rows, row `y` in slot `y mod 3`.
    scores: Vec<u8>,
    /// Per grid column: the level columns `[x0, x1)` inside the border that fall in it.
    col_span: Vec<Option<(usize, usize)>>,
    /// Per level column: the grid column it falls in, `None` outside the border.
    col_cell: Vec<Option<usize>>,
    /// Per level row: the grid row it falls in, `None` outside the border.
    row_cell: Vec<Option<usize>>,
    /// Column spans of the FAST scores to compute on the current row.
    spans: Vec<(usize, usize)>,
}

impl Scratch {
    /// Size the buffers for a `w × h` level with border `b` and map its pixels to cells, with
    /// the same arithmetic as [`Grid::cell_of`] on the level-0 position.
    fn prepare(&mut self, grid: &Grid, level: u32, w: usize, h: usize, b: usize) {
        let cols = grid.cols as usize;
        self.scores.clear();
        self.scores.resize(3 * w, 0);
        self.col_span.clear();
        self.col_span.resize(cols, None);
        self.col_cell.clear();
        self.col_cell.resize(w, None);
        for x in b..w - b {
            let px = Camera::level_to_base(&Vector2::new(x as f64, 0.0), level);
            // On row 0 the cell index is the column.
            if let Some(c) = grid.cell_of(&px) {
                let span = self.col_span[c].get_or_insert((x, x));
                span.1 = x + 1;
                self.col_cell[x] = Some(c);
            }
        }
        self.row_cell.clear();
        self.row_cell.extend((0..h).map(|y| {
            if y < b || y >= h - b {
                return None;
            }
            let px = Camera::level_to_base(&Vector2::new(0.0, y as f64), level);
            grid.cell_of(&px).map(|i| i / cols)
        }));
    }
}

/// The 16 pixels of the Bresenham circle of radius 3, `(dx, dy)`, clockwise from the top.
const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Pixels tested at once by [`fast9_span`]: one SSE2 register of bytes.
const LANES: usize = 16;

/// Columns of the pixels a block of [`LANES`] pixels reads: 3 either side.
const WINDOW: usize = LANES + 6;

/// FAST-9 scores of the pixels `[x0, x1)` of the middle row of `rows` (rows `y − 3` to
/// `y + 3`, of equal length) into `out[x0..x1]`; the caller keeps `3 ≤ x0` and
/// `x1 + 3 ≤ width`.
fn fast9_span(rows: &[&[u8]; 7], x0: usize, x1: usize, threshold: u8, out: &mut [u8]) {
    let width = rows[3].len();
    let mut x = x0;
    while x < x1 {
        // Blocks of `LANES` pixels; the last one is shifted left to end at `x1` (a few pixels
        // scored twice) unless the span is shorter than a block.
        let start = if x1 - x0 >= LANES {
            x.min(x1 - LANES)
        } else {
            x
        };
        let full: [Option<&[u8; WINDOW]>; 7] =
            std::array::from_fn(|i| rows[i].get(start - 3..start + LANES + 3)?.try_into().ok());
        let scores = if let [
            Some(a),
            Some(b),
            Some(c),
            Some(d),
            Some(e),
            Some(f),
            Some(g),
        ] = full
        {
            fast9_block(&[a, b, c, d, e, f, g], threshold)
        } else {
            // Near the right edge of a narrow image the window is padded with zeros; only
            // lanes left of `x1`, which read real pixels, are kept.
            let mut padded = [[0_u8; WINDOW]; 7];
            let end = (start + LANES + 3).min(width);
            for (win, row) in padded.iter_mut().zip(rows) {
                win[..end + 3 - start].copy_from_slice(&row[start - 3..end]);
            }
            fast9_block(&padded.each_ref(), threshold)
        };
        let keep = x1.min(start + LANES);
        out[x..keep].copy_from_slice(&scores[x - start..keep - start]);
        x = keep;
    }
}

/// FAST-9 scores of the [`LANES`] pixels `window[3][3..3 + LANES]`, 0 for a pixel that is no
/// corner.
///
/// The score is the largest threshold at which the pixel still passes the segment test: over
/// the 16 arcs of 9 contiguous circle pixels, the largest of the smallest difference to the
/// centre along the arc (brighter or darker), minus one as the test is strict. The pixel is a
/// corner for `threshold` iff that score is at least `threshold`. An arc holding both a
/// brighter and a darker pixel has a smallest saturated difference of 0 either way, and a
/// brighter and a darker arc of 9 cannot coexist on 16 pixels, so saturating differences
/// give the same score. Blocks where no pixel passes the high-speed test (an arc of 9 holds
/// two consecutive pixels of 1, 5, 9, 13, the compass points) are rejected first. Written lane
/// by lane on fixed-size arrays so that it compiles to byte-vector instructions.
#[inline(always)]
fn fast9_block(window: &[&[u8; WINDOW]; 7], threshold: u8) -> [u8; LANES] {
    let centre: [u8; LANES] = std::array::from_fn(|j| window[3][3 + j]);
    // Circle pixel `k` of every lane.
    let ring = |k: usize| -> [u8; LANES] {
        let (dx, dy) = CIRCLE[k];
        let row = window[3_usize.wrapping_add_signed(dy)];
        let start = 3_usize.wrapping_add_signed(dx);
        std::array::from_fn(|j| row[start + j])
    };
    // Listed rather than looped over, so that every load has a constant offset.
    let rings = [
        ring(0),
        ring(1),
        ring(2),
        ring(3),
        ring(4),
        ring(5),
        ring(6),
        ring(7),
        ring(8),
        ring(9),
        ring(10),
        ring(11),
        ring(12),
        ring(13),
        ring(14),
        ring(15),
    ];
    let (north, east, south, west) = (rings[0], rings[4], rings[8], rings[12]);
    let (mut pass_bright, mut pass_dark) = (false, false);
    for j in 0..LANES {
        let c = centre[j];
        let b = |p: u8| p.saturating_sub(c);
        let d = |p: u8| c.saturating_sub(p);
        let bright = b(north[j]).max(b(south[j])).min(b(east[j]).max(b(west[j])));
        let dark = d(north[j]).max(d(south[j])).min(d(east[j]).max(d(west[j])));
        pass_bright |= bright > threshold;
        pass_dark |= dark > threshold;
    }
    // Each polarity only where some pixel passes its high-speed test.
    let mut diff = [[0_u8; LANES]; 16];
    let bright = if pass_bright {
        for (d, p) in diff.iter_mut().zip(&rings) {
            for j in 0..LANES {
                d[j] = p[j].saturating_sub(centre[j]);
            }
        }
        best_arc(&diff)
    } else {
        [0; LANES]
    };
    let dark = if pass_dark {
        for (d, p) in diff.iter_mut().zip(&rings) {
            for j in 0..LANES {
                d[j] = centre[j].saturating_sub(p[j]);
            }
        }
        best_arc(&diff)
    } else {
        [0; LANES]
    };
    let mut out = [0_u8; LANES];
    for j in 0..LANES {
        let m = bright[j].max(dark[j]);
        out[j] = if m > threshold { m - 1 } else { 0 };
    }
    out
}

/// Per lane, the largest over the 16 circular arcs of 9 of the smallest of `d` along the arc:
/// minima over runs of 2, 4, 8, then 9 pixels.
#[inline(always)]
fn best_arc(d: &[[u8; LANES]; 16]) -> [u8; LANES] {
    #[inline(always)]
    fn runs(a: &[[u8; LANES]; 16], b: &[[u8; LANES]; 16], shift: usize) -> [[u8; LANES]; 16] {
        let mut out = [[0_u8; LANES]; 16];
        for k in 0..16 {
            let (p, q) = (&a[k], &b[(k + shift) & 15]);
            for j in 0..LANES {
                out[k][j] = p[j].min(q[j]);
            }
        }
        out
    }
    let run2 = runs(d, d, 1);
    let run4 = runs(&run2, &run2, 2);
    let run8 = runs(&run4, &run4, 4);
    let run9 = runs(&run8, d, 8);
    let mut best = [0_u8; LANES];
    for r in &run9 {
        for j in 0..LANES {
            best[j] = best[j].max(r[j]);
        }
    }
    best
}

/// Bit `j` set iff pixel `x + j` of `mid`, `j < LANES`, is a corner (non-zero score) and
/// passes [`is_local_max`]. The caller keeps `1 ≤ x` and `x + LANES < width`.
#[inline(always)]
fn local_max_mask(up: &[u8], mid: &[u8], down: &[u8], x: usize) -> u16 {
    let at = |row: &[u8], start: usize| -> [u8; LANES] {
        let mut v = [0_u8; LANES];
        v.copy_from_slice(&row[start..start + LANES]);
        v
    };
    let s = at(mid, x);
    let (ul, uc, ur) = (at(up, x - 1), at(up, x), at(up, x + 1));
    let (ml, mr) = (at(mid, x - 1), at(mid, x + 1));
    let (dl, dc, dr) = (at(down, x - 1), at(down, x), at(down, x + 1));
    let mut mask = 0_u16;
    for j in 0..LANES {
        let v = s[j];
        let before = (ul[j] < v) & (uc[j] < v) & (ur[j] < v) & (ml[j] < v);
        let after = (mr[j] <= v) & (dl[j] <= v) & (dc[j] <= v) & (dr[j] <= v);
        mask |= u16::from((v != 0) & before & after) << j;
    }
    mask
}

/// 3 × 3 non-maximum test of pixel `x` of `mid` between rows `up` and `down` of FAST scores:
/// strictly above the neighbours that come first in row-major order, at least equal to the
/// others (a plateau keeps its first pixel). The caller keeps `x` at least one pixel from the
/// edge.
fn is_local_max(up: &[u8], mid: &[u8], down: &[u8], x: usize) -> bool {
    let s = mid[x];
    up[x - 1] < s
        && up[x] < s
        && up[x + 1] < s
        && mid[x - 1] < s
        && mid[x + 1] <= s
        && down[x - 1] <= s
        && down[x] <= s
        && down[x + 1] <= s
}

/// Shi-Tomasi score at pixel `(x, y)`: the smaller eigenvalue of the mean of `∇I ∇Iᵀ` over
/// `[x − 4, x + 4) × [y − 4, y + 4)`, central differences, in (grey levels / pixel)² of this
/// image. `None` if the window or its differences leave the image.
pub fn shi_tomasi_score(img: &GrayImage, x: u32, y: u32) -> Option<f32> {
    let (w, h) = img.dimensions();
    if x < MIN_BORDER_PX || y < MIN_BORDER_PX || x + HALF_WINDOW >= w || y + HALF_WINDOW >= h {
        return None;
    }
    const SIDE: usize = SHI_TOMASI_WINDOW_PX as usize;
    let p = img.as_raw();
    let w = w as usize;
    let (x, y) = (x as usize, y as usize);
    let half = HALF_WINDOW as usize;
    // Sums of products of undivided differences: |d| ≤ 255, 64 terms, well inside i32.
    let (mut sxx, mut sxy, mut syy) = ([0_i32; SIDE], [0_i32; SIDE], [0_i32; SIDE]);
    for r in y - half..y + half {
        let row = &p[r * w + x - half - 1..][..SIDE + 2];
        let up = &p[(r - 1) * w + x - half..][..SIDE];
        let down = &p[(r + 1) * w + x - half..][..SIDE];
        for j in 0..SIDE {
            let dx = i32::from(i16::from(row[j + 2]) - i16::from(row[j]));
            let dy = i32::from(i16::from(down[j]) - i16::from(up[j]));
            sxx[j] += dx * dx;
            sxy[j] += dx * dy;
            syy[j] += dy * dy;
        }
    }
    let (sxx, sxy, syy): (i32, i32, i32) = (sxx.iter().sum(), sxy.iter().sum(), syy.iter().sum());
    // Each difference is twice the gradient: divide the products by 4, the sums by the count.
    let norm = 1.0 / (4.0 * f64::from(SHI_TOMASI_WINDOW_PX * SHI_TOMASI_WINDOW_PX));
    let (a, b, c) = (
        f64::from(sxx) * norm,
        f64::from(sxy) * norm,
        f64::from(syy) * norm,
    );
    // Smaller eigenvalue of [[a, b], [b, c]], in a form without cancellation under the root.
    let lambda_min = 0.5 * (a + c - ((a - c) * (a - c) + 4.0 * b * b).sqrt());
    Some(lambda_min.max(0.0) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::Frame;
    use std::sync::Arc;

    const BACKGROUND: u8 = 40;
    const FOREGROUND: u8 = 200;

    /// SplitMix64: deterministic draws without a dependency.
    struct SplitMix(u64);

    impl SplitMix {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }

        /// Uniform in `lo..hi`.
        fn range(&mut self, lo: u32, hi: u32) -> u32 {
            lo + (self.next() % u64::from(hi - lo)) as u32
        }
    }

    fn fill_rect(pixels: &mut [u8], w: u32, x0: u32, y0: u32, side: (u32, u32), value: u8) {
        for y in y0..y0 + side.1 {
            let row = (y * w) as usize;
            pixels[row + x0 as usize..row + (x0 + side.0) as usize].fill(value);
        }
    }

    /// One bright square of side `side` px in every 64-px cell, at least 12 px from the
    /// cell's edges; returns the pixels and each square's top-left pixel (cells row-major).
    fn squares(w: u32, h: u32, side: u32, seed: u64) -> (Vec<u8>, Vec<(u32, u32)>) {
        let mut rng = SplitMix(seed);
        let mut pixels = vec![BACKGROUND; (w * h) as usize];
        let mut tops = Vec::new();
        for cy in 0..h / 64 {
            for cx in 0..w / 64 {
                let x0 = 64 * cx + rng.range(12, 64 - 12 - side + 1);
                let y0 = 64 * cy + rng.range(12, 64 - 12 - side + 1);
                fill_rect(&mut pixels, w, x0, y0, (side, side), FOREGROUND);
                tops.push((x0, y0));
            }
        }
        (pixels, tops)
    }

    /// Dense texture: 6000 rectangles of 3–40 px with random grey levels, painted over one
    /// another, on a random-grey background.
    fn texture(w: u32, h: u32, seed: u64) -> Vec<u8> {
        let mut rng = SplitMix(seed);
        let mut pixels = vec![128_u8; (w * h) as usize];
        for _ in 0..6000 {
            let side = (rng.range(3, 41), rng.range(3, 41));
            let x0 = rng.range(0, w - side.0 + 1);
            let y0 = rng.range(0, h - side.1 + 1);
            let grey = rng.range(0, 256) as u8;
            fill_rect(&mut pixels, w, x0, y0, side, grey);
        }
        pixels
    }

    fn pyramid(w: u32, h: u32, pixels: Vec<u8>) -> Pyramid {
        let frame = Frame {
            t_us: 0,
            width: w,
            height: h,
            pixels: Arc::from(pixels),
        };
        let cam = camera(w, h);
        Pyramid::from_frame(&frame, &cam).unwrap()
    }

    fn camera(w: u32, h: u32) -> Camera {
        Camera::from_config(&crate::vision::camera::CameraConfig {
            width_px: w,
            height_px: h,
            ..Default::default()
        })
        .unwrap()
    }

    /// Hand-computed score of a step corner: a 160-grey square corner at the window's
    /// centre pixel. The vertical edge gives gradient 80 on 2 columns × 4 rows, the horizontal
    /// one likewise, and both only at the corner pixel: ⟨gx²⟩ = ⟨gy²⟩ = 8·6400/64 = 800,
    /// ⟨gx gy⟩ = 6400/64 = 100, so λ_min = 800 − 100 = 700. A straight edge has λ_min = 0.
    #[test]
    fn shi_tomasi_known_values() {
        let (w, h) = (32_u32, 32_u32);
        let mut pixels = vec![BACKGROUND; (w * h) as usize];
        fill_rect(&mut pixels, w, 12, 12, (16, 16), FOREGROUND);
        let img = GrayImage::from_raw(w, h, pixels).unwrap();
        assert_eq!(shi_tomasi_score(&img, 12, 12), Some(700.0));
        assert_eq!(shi_tomasi_score(&img, 20, 12), Some(0.0));
        // The window and its differences, [x − 5, x + 4] × [y − 5, y + 4], must lie inside.
        assert_eq!(shi_tomasi_score(&img, 5, 5), Some(0.0));
        assert_eq!(shi_tomasi_score(&img, 4, 5), None);
        assert_eq!(shi_tomasi_score(&img, 5, 4), None);
        // The opposite corner pixel: the window, centred half a pixel up and left of its
        // pixel, now holds 5 rows of each edge: 10·6400/64 − 100 = 900.
        assert_eq!(shi_tomasi_score(&img, 27, 27), Some(900.0));
        assert_eq!(shi_tomasi_score(&img, 28, 27), None);
        assert_eq!(shi_tomasi_score(&img, 27, 28), None);
    }

    /// Detections in a `w × h` image of `side`-px squares, checked for one per cell.
    fn detect_squares(w: u32, h: u32, side: u32, seed: u64) -> (Vec<Feature>, Vec<(u32, u32)>) {
        let (pixels, tops) = squares(w, h, side, seed);
        let pyr = pyramid(w, h, pixels);
        let det = FeatureDetector::new(DetectorConfig::default(), &camera(w, h)).unwrap();
        let features = det.detect(&pyr, &det.empty_occupancy()).unwrap();
        assert_eq!(features.len(), det.grid().n_cells(), "one per cell");
        let mut cells: Vec<_> = features
            .iter()
            .map(|f| det.grid().cell_of(&f.px).unwrap())
            .collect();
        cells.dedup();
        assert_eq!(cells.len(), features.len(), "at most one per cell");
        for f in &features {
            assert!(f.score > det.config().min_shi_tomasi_score);
        }
        (features, tops)
    }

    /// 3 × 3 blobs: the segment test fires on the 9 blob pixels (all 16 circle pixels are
    /// background) and on no background pixel (at most 3 circle pixels fall on the blob), so
    /// every detection is within one pixel per axis of its blob's centre. A coarser level
    /// would see the blob smeared, with a weaker gradient and a score divided by `4^l`.
    #[test]
    fn blobs_give_corners_at_their_centres() {
        let (features, tops) = detect_squares(384, 256, 3, 11);
        for (f, &(x0, y0)) in features.iter().zip(&tops) {
            let centre = Vector2::new(f64::from(x0 + 1), f64::from(y0 + 1));
            let d = f.px - centre;
            assert!(
                d.x.abs() <= 1.0 && d.y.abs() <= 1.0,
                "{f:?}, blob at {centre}"
            );
        }
    }

    /// 16-px squares: FAST-9 fires on a corner pixel of the square and on the pixels inside it
    /// at offsets (1, 0), (0, 1), (1, 1), (2, 0), (0, 2) from it (further along an edge, or
    /// diagonally inside, fewer than 9 contiguous circle pixels lie outside; a straight edge
    /// leaves at most 7), so every detection is a square pixel within 2 px per axis of a
    /// corner pixel. Level 0 wins because the same sharp step on level `l` has at most the
    /// same gradient per level pixel, so a score `4^l` times smaller at level-0 scale.
    #[test]
    fn squares_give_corners_at_their_corners() {
        let side = 16;
        let (features, tops) = detect_squares(384, 256, side, 5);
        for (f, &(x0, y0)) in features.iter().zip(&tops) {
            let (x0, y0) = (f64::from(x0), f64::from(y0));
            let (x1, y1) = (x0 + f64::from(side - 1), y0 + f64::from(side - 1));
            let inside = (x0..=x1).contains(&f.px.x) && (y0..=y1).contains(&f.px.y);
            let near = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
                .iter()
                .any(|&(x, y)| (f.px.x - x).abs() <= 2.0 && (f.px.y - y).abs() <= 2.0);
            assert!(inside && near, "{f:?}, square at ({x0}, {y0})");
            assert_eq!(f.level, 0);
        }
    }

    /// Gaussian blobs `20 + 220 exp(−r²/2σ²)`, σ = 8 px, one per cell: on level 0 the
    /// intensity 3 px from the top is only 220 (1 − e^(−9/128)) ≈ 15 grey levels lower, below
    /// the FAST threshold of 20, and on the flanks fewer than 9 circle pixels differ enough, so
    /// level 0 has no corner. On level 1 (σ = 4 level px) the drop is ≈ 54. A corner of level `l`
    /// lies within one level pixel of the blob's top, i.e. `2^l` level-0 px.
    #[test]
    fn smooth_blobs_are_found_on_coarser_levels() {
        let (w, h) = (384_u32, 256_u32);
        let sigma2 = 2.0 * 8.0_f64 * 8.0;
        let mut rng = SplitMix(3);
        let centres: Vec<(f64, f64)> = (0..h / 64)
            .flat_map(|cy| (0..w / 64).map(move |cx| (cx, cy)))
            .map(|(cx, cy)| {
                let x = 64 * cx + rng.range(20, 45);
                let y = 64 * cy + rng.range(20, 45);
                (f64::from(x), f64::from(y))
            })
            .collect();
        let pixels: Vec<u8> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (f64::from(x), f64::from(y))))
            .map(|(x, y)| {
                let i: f64 = centres
                    .iter()
                    .map(|&(cx, cy)| (-((x - cx).powi(2) + (y - cy).powi(2)) / sigma2).exp())
                    .sum();
                (20.0 + 220.0 * i.min(1.0)).round() as u8
            })
            .collect();
        let pyr = pyramid(w, h, pixels);
        let cam = camera(w, h);
        let level_0_only = DetectorConfig {
            n_levels: 1,
            ..Default::default()
        };
        let det = FeatureDetector::new(level_0_only, &cam).unwrap();
        assert!(det.detect(&pyr, &det.empty_occupancy()).unwrap().is_empty());
        let det = FeatureDetector::new(DetectorConfig::default(), &cam).unwrap();
        let features = det.detect(&pyr, &det.empty_occupancy()).unwrap();
        assert_eq!(features.len(), centres.len());
        for (f, &(cx, cy)) in features.iter().zip(&centres) {
            let tol = f64::from(1_u32 << f.level);
            assert!(f.level >= 1, "{f:?}");
            assert!(
                (f.px.x - cx).abs() <= tol && (f.px.y - cy).abs() <= tol,
                "{f:?}, blob at ({cx}, {cy})"
            );
        }
    }

    #[test]
    fn occupied_cells_get_nothing() {
        let (w, h) = (384_u32, 256_u32);
        let pyr = pyramid(w, h, squares(w, h, 16, 5).0);
        let det = FeatureDetector::new(DetectorConfig::default(), &camera(w, h)).unwrap();
        let free = det.detect(&pyr, &det.empty_occupancy()).unwrap();
        let mut occupancy = det.empty_occupancy();
        // Cell 7 by index, cell 0 through a tracked feature's position.
        assert!(occupancy.occupy_cell(7));
        assert!(occupancy.occupy(&Vector2::new(10.3, 60.0)));
        assert!(!occupancy.occupy_cell(det.grid().n_cells()));
        assert!(!occupancy.occupy(&Vector2::new(-0.6, 0.0)));
        assert_eq!(occupancy.n_occupied(), 2);
        let some = det.detect(&pyr, &occupancy).unwrap();
        let cell = |f: &Feature| det.grid().cell_of(&f.px).unwrap();
        let expected: Vec<_> = free
            .iter()
            .filter(|f| cell(f) != 0 && cell(f) != 7)
            .copied()
            .collect();
        assert_eq!(some, expected);
        assert_eq!(some.len(), free.len() - 2);
    }

    #[test]
    fn flat_image_has_no_features() {
        let (w, h) = (128_u32, 128_u32);
        let pyr = pyramid(w, h, vec![90; (w * h) as usize]);
        let det = FeatureDetector::new(DetectorConfig::default(), &camera(w, h)).unwrap();
        assert!(det.detect(&pyr, &det.empty_occupancy()).unwrap().is_empty());
    }

    /// The requirement: 150–250 features on a textured 768 × 1024 frame. The upper bound also
    /// follows from the grid (192 cells, at most one feature each).
    #[test]
    fn textured_frame_count() {
        let (w, h) = (768_u32, 1024_u32);
        let pyr = pyramid(w, h, texture(w, h, 2026));
        let det = FeatureDetector::new(DetectorConfig::default(), &Camera::paper()).unwrap();
        assert_eq!(det.grid().n_cells(), 192);
        let features = det.detect(&pyr, &det.empty_occupancy()).unwrap();
        let n = features.len();
        assert!((150..=192).contains(&n), "{n} features");
        let mut cells: Vec<_> = features
            .iter()
            .map(|f| det.grid().cell_of(&f.px).unwrap())
            .collect();
        cells.dedup();
        assert_eq!(cells.len(), n);
        for f in &features {
            assert!(f.level < 3);
            let border = f64::from(8_u32 << f.level);
            assert!(Camera::paper().contains(&f.px, border - 0.5), "{f:?}");
        }
        // Deterministic.
        assert_eq!(features, det.detect(&pyr, &det.empty_occupancy()).unwrap());
    }

    /// FAST scores of every pixel of `img` by [`fast9_span`], as `(x, y, score)` of the
    /// corners in row-major order.
    fn fast9_image(img: &GrayImage, threshold: u8) -> Vec<(u32, u32, u8)> {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let mut corners = Vec::new();
        if w < 7 || h < 7 {
            return corners;
        }
        let p = img.as_raw();
        let mut row = vec![0_u8; w];
        for y in 3..h - 3 {
            let rows: [&[u8]; 7] = std::array::from_fn(|i| &p[(y + i - 3) * w..][..w]);
            fast9_span(&rows, 3, w - 3, threshold, &mut row);
            for (x, &s) in row.iter().enumerate().take(w - 3).skip(3) {
                if s > 0 {
                    corners.push((x as u32, y as u32, s));
                }
            }
        }
        corners
    }

    /// The oracle: `imageproc`'s FAST-9 corners and scores.
    fn imageproc_fast9(img: &GrayImage, threshold: u8) -> Vec<(u32, u32, u8)> {
        imageproc::corners::corners_fast9(img, threshold)
            .iter()
            .map(|c| (c.x, c.y, c.score as u8))
            .collect()
    }

    /// 3 × 3 box blur with rounding, edges kept (the bench's frame).
    fn blur(pixels: &[u8], w: u32, h: u32) -> Vec<u8> {
        let (w, h) = (w as usize, h as usize);
        let mut out = pixels.to_vec();
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let sum: u32 = (y - 1..=y + 1)
                    .flat_map(|r| (x - 1..=x + 1).map(move |c| r * w + c))
                    .map(|i| u32::from(pixels[i]))
                    .sum();
                out[y * w + x] = ((sum + 4) / 9) as u8;
            }
        }
        out
    }

    /// Noise with many saturated pixels: each pixel 0, 255 or uniform.
    fn noise(w: u32, h: u32, seed: u64) -> Vec<u8> {
        let mut rng = SplitMix(seed);
        (0..w * h)
            .map(|_| match rng.range(0, 4) {
                0 => 0,
                1 => 255,
                _ => rng.range(0, 256) as u8,
            })
            .collect()
    }

    #[test]
    fn fast9_agrees_with_imageproc() {
        let (w, h) = (384_u32, 256_u32);
        let images = [
            texture(w, h, 7),
            blur(&texture(w, h, 8), w, h),
            noise(w, h, 9),
            squares(w, h, 16, 5).0,
            squares(w, h, 3, 11).0,
            vec![90; (w * h) as usize],
        ];
        for (i, pixels) in images.into_iter().enumerate() {
            let img = GrayImage::from_raw(w, h, pixels).unwrap();
            for threshold in [1, 2, 10, 19, 20, 21, 50, 100, 200, 254, 255] {
                let expected = imageproc_fast9(&img, threshold);
                assert_eq!(
                    fast9_image(&img, threshold),
                    expected,
                    "image {i}, threshold {threshold}"
                );
            }
        }
        // The full frame of `textured_frame_count`, at the default threshold.
        let img = GrayImage::from_raw(768, 1024, texture(768, 1024, 2026)).unwrap();
        let expected = imageproc_fast9(&img, 20);
        assert!(expected.len() > 10_000, "{} corners", expected.len());
        assert_eq!(fast9_image(&img, 20), expected);
    }

    /// Narrow images: spans shorter than a vector of pixels, and a last block shifted left.
    #[test]
    fn fast9_agrees_with_imageproc_on_narrow_images() {
        for w in 1..=40_u32 {
            for (seed, h) in [(1, 7_u32), (2, 12), (3, 40)] {
                let img = GrayImage::from_raw(w, h, noise(w, h, seed + u64::from(w))).unwrap();
                for threshold in [1, 20, 100] {
                    assert_eq!(
                        fast9_image(&img, threshold),
                        imageproc_fast9(&img, threshold),
                        "{w} × {h}, threshold {threshold}"
                    );
                }
            }
        }
    }

    /// The detector as it was written on `imageproc`'s FAST-9 (every pixel tested and scored,
    /// suppression on a full score image, occupancy checked per corner): the reference for
    /// [`FeatureDetector::detect`].
    fn detect_reference(
        det: &FeatureDetector,
        pyramid: &Pyramid,
        occupancy: &Occupancy,
    ) -> Vec<Feature> {
        let mut best: Vec<Option<Feature>> = vec![None; det.grid().n_cells()];
        for (level, img) in (0..det.config().n_levels).zip(pyramid.levels()) {
            let (w, h) = img.dimensions();
            let border = det.config().border_px;
            if w <= 2 * border || h <= 2 * border {
                continue;
            }
            let corners = imageproc::corners::corners_fast9(img, det.config().fast_threshold);
            let mut fast_scores = vec![0_u8; w as usize * h as usize];
            for c in &corners {
                fast_scores[c.y as usize * w as usize + c.x as usize] = c.score as u8;
            }
            let to_level_0 = 0.25_f32.powi(level as i32);
            for c in &corners {
                if c.x < border || c.y < border || c.x >= w - border || c.y >= h - border {
                    continue;
                }
                let (x, y, w) = (c.x as usize, c.y as usize, w as usize);
                let row = |r: usize| &fast_scores[r * w..(r + 1) * w];
                if !is_local_max(row(y - 1), row(y), row(y + 1), x) {
                    continue;
                }
                let px =
                    Camera::level_to_base(&Vector2::new(f64::from(c.x), f64::from(c.y)), level);
                let Some(cell) = det.grid().cell_of(&px) else {
                    continue;
                };
                if occupancy.is_occupied(cell) {
                    continue;
                }
                let Some(score) = shi_tomasi_score(img, c.x, c.y) else {
                    continue;
                };
                let score = score * to_level_0;
                if score <= det.config().min_shi_tomasi_score {
                    continue;
                }
                let slot = &mut best[cell];
                if slot.is_none_or(|f| score > f.score) {
                    *slot = Some(Feature { px, level, score });
                }
            }
        }
        best.into_iter().flatten().collect()
    }

    /// Random occupancy: each cell occupied with probability `percent` %.
    fn random_occupancy(det: &FeatureDetector, percent: u32, seed: u64) -> Occupancy {
        let mut rng = SplitMix(seed);
        let mut occupancy = det.empty_occupancy();
        for i in 0..det.grid().n_cells() {
            if rng.range(0, 100) < percent {
                occupancy.occupy_cell(i);
            }
        }
        occupancy
    }

    /// The fast detector returns exactly the features of the reference on textures, blobs and
    /// squares, odd image sizes (levels that round down, cells cut by the edge), other
    /// settings, and free, partly and fully occupied grids.
    #[test]
    fn detect_matches_the_imageproc_reference() {
        let cases = [
            (768_u32, 1024_u32, texture(768, 1024, 2026)),
            (768, 1024, blur(&texture(768, 1024, 2027), 768, 1024)),
            (384, 256, squares(384, 256, 16, 5).0),
            (384, 256, squares(384, 256, 3, 11).0),
            (203, 131, blur(&noise(203, 131, 4), 203, 131)),
            (203, 131, texture(203, 131, 12)),
        ];
        let configs = [
            DetectorConfig::default(),
            DetectorConfig {
                cell_size_px: 24,
                fast_threshold: 7,
                min_shi_tomasi_score: 0.0,
                n_levels: 5,
                border_px: 5,
            },
            DetectorConfig {
                cell_size_px: 37,
                fast_threshold: 40,
                min_shi_tomasi_score: 30.0,
                n_levels: 2,
                border_px: 13,
            },
        ];
        for (i, (w, h, pixels)) in cases.into_iter().enumerate() {
            let pyr = pyramid(w, h, pixels);
            for (j, config) in configs.iter().enumerate() {
                let det = FeatureDetector::new(*config, &camera(w, h)).unwrap();
                for (k, percent) in [0, 10, 50, 90, 100].into_iter().enumerate() {
                    let occupancy = random_occupancy(&det, percent, 100 + k as u64);
                    let features = det.detect(&pyr, &occupancy).unwrap();
                    assert_eq!(
                        features,
                        detect_reference(&det, &pyr, &occupancy),
                        "image {i}, config {j}, {percent} % occupied"
                    );
                    if percent == 0 && j == 0 && i < 2 {
                        assert!(features.len() > 150, "{} features", features.len());
                    }
                }
            }
        }
    }

    #[test]
    fn grid_cells_follow_the_pixel_centre_convention() {
        let g = Grid::new(768, 1024, 64).unwrap();
        assert_eq!((g.cols(), g.rows(), g.n_cells()), (12, 16, 192));
        assert_eq!(g.cell_of(&Vector2::new(-0.5, -0.5)), Some(0));
        assert_eq!(g.cell_of(&Vector2::new(63.49, 0.0)), Some(0));
        assert_eq!(g.cell_of(&Vector2::new(63.5, 0.0)), Some(1));
        assert_eq!(g.cell_of(&Vector2::new(0.0, 64.0)), Some(12));
        assert_eq!(g.cell_of(&Vector2::new(767.49, 1023.49)), Some(191));
        assert_eq!(g.cell_of(&Vector2::new(767.5, 0.0)), None);
        assert_eq!(g.cell_of(&Vector2::new(f64::NAN, 0.0)), None);
        // Cut cells at the edge: 100 px in 64-px cells is 2 columns.
        assert_eq!(Grid::new(100, 64, 64).unwrap().n_cells(), 2);
    }

    #[test]
    fn mismatches_and_bad_settings_are_refused() {
        let cam = Camera::paper();
        let det = FeatureDetector::new(DetectorConfig::default(), &cam).unwrap();
        let small = pyramid(384, 256, squares(384, 256, 16, 1).0);
        assert!(matches!(
            det.detect(&small, &det.empty_occupancy()),
            Err(FeatureError::SizeMismatch { .. })
        ));
        let pyr = pyramid(768, 1024, vec![0; 768 * 1024]);
        let other_grid = Occupancy::new(Grid::new(768, 1024, 32).unwrap());
        assert!(matches!(
            det.detect(&pyr, &other_grid),
            Err(FeatureError::SizeMismatch { .. })
        ));
        let two = Pyramid::from_pixels(768, 1024, &vec![0; 768 * 1024], 2).unwrap();
        assert_eq!(
            det.detect(&two, &det.empty_occupancy()),
            Err(FeatureError::TooFewLevels {
                needed: 3,
                available: 2
            })
        );
        let bad = [
            DetectorConfig {
                cell_size_px: 4,
                ..Default::default()
            },
            DetectorConfig {
                fast_threshold: 0,
                ..Default::default()
            },
            DetectorConfig {
                min_shi_tomasi_score: f32::NAN,
                ..Default::default()
            },
            DetectorConfig {
                n_levels: 6,
                ..Default::default()
            },
            DetectorConfig {
                border_px: 4,
                ..Default::default()
            },
        ];
        for config in bad {
            assert!(
                FeatureDetector::new(config, &cam).is_err(),
                "{config:?} accepted"
            );
        }
    }
}
