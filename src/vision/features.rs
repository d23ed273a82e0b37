//! Feature detection of semi-direct visual odometry (SVO; Forster, Pizzoli and Scaramuzza, "SVO:
//! Fast Semi-Direct Monocular Visual Odometry", ICRA 2014; the paper's SVO figure: mapping
//! thread, "Feature Detection", run on keyframes), as SVO's reference implementation does it:
//! FAST corners on the finer pyramid levels, each scored by Shi and Tomasi's "good features to
//! track" score, and at most one feature per cell of a grid over the level-0 image, the best
//! over all levels; cells that already hold a tracked feature are skipped.
//!
//! - FAST-9 (segment test on the radius-3 circle of 16 pixels, 9 contiguous) from `imageproc`.
//!   Its threshold is a difference in grey levels (0–255) that the circle pixels must exceed
//!   strictly, the same unit as OpenCV's and SVO's; SVO uses 20. `imageproc` has no non-maximum
//!   suppression, so it is done here on the FAST score over 3 × 3 neighbours. Ties (common on
//!   synthetic images) keep the first pixel in row-major order, so a plateau keeps one corner.
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
use imageproc::corners::corners_fast9;
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

/// Detector settings (SVO defaults adapted to the 768 × 1024 camera).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Side of a grid cell, level-0 px.
    pub cell_size_px: u32,
    /// FAST-9 threshold, grey levels (0–255).
    pub fast_threshold: u8,
    /// Minimum Shi-Tomasi score a feature must exceed, (grey levels / level-0 px)².
    pub min_shi_tomasi_score: f32,
    /// Pyramid levels searched, from level 0.
    pub n_levels: u32,
    /// Corners closer than this to the image edge are ignored, px of their level.
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
        let mut fast_scores = Vec::new();
        for (level, img) in (0..self.config.n_levels).zip(pyramid.levels()) {
            self.detect_level(level, img, occupancy, &mut fast_scores, &mut best);
        }
        Ok(best.into_iter().flatten().collect())
    }

    /// One level's corners into `best`; `fast_scores` is scratch space for the suppression.
    fn detect_level(
        &self,
        level: u32,
        img: &GrayImage,
        occupancy: &Occupancy,
        fast_scores: &mut Vec<u8>,
        best: &mut [Option<Feature>],
    ) {
        let (w, h) = img.dimensions();
        let border = self.config.border_px;
        if w <= 2 * border || h <= 2 * border {
            return;
        }
        let corners = corners_fast9(img, self.config.fast_threshold);
        // FAST scores as an image (0 = no corner) for the 3 × 3 suppression.
        fast_scores.clear();
        fast_scores.resize(w as usize * h as usize, 0);
        for c in &corners {
            // imageproc's score is a u8 threshold stored as f32.
            fast_scores[c.y as usize * w as usize + c.x as usize] = c.score as u8;
        }
        let to_level_0 = 0.25_f32.powi(level as i32);
        for c in &corners {
            if c.x < border || c.y < border || c.x >= w - border || c.y >= h - border {
                continue;
            }
            if !is_local_max(fast_scores, w as usize, c.x as usize, c.y as usize) {
                continue;
            }
            let px = Camera::level_to_base(&Vector2::new(f64::from(c.x), f64::from(c.y)), level);
            let Some(cell) = self.grid.cell_of(&px) else {
                continue;
            };
            if occupancy.is_occupied(cell) {
                continue;
            }
            let Some(score) = shi_tomasi_score(img, c.x, c.y) else {
                continue;
            };
            let score = score * to_level_0;
            if score <= self.config.min_shi_tomasi_score {
                continue;
            }
            let slot = &mut best[cell];
            if slot.is_none_or(|f| score > f.score) {
                *slot = Some(Feature { px, level, score });
            }
        }
    }
}

/// 3 × 3 non-maximum test on the FAST-score image: strictly above the neighbours that come
/// first in row-major order, at least equal to the others (a plateau keeps its first pixel).
/// The caller keeps `(x, y)` at least one pixel from the edge.
fn is_local_max(scores: &[u8], w: usize, x: usize, y: usize) -> bool {
    let i = y * w + x;
    let s = scores[i];
    let before = [i - w - 1, i - w, i - w + 1, i - 1];
    let after = [i + 1, i + w - 1, i + w, i + w + 1];
    before.iter().all(|&j| scores[j] < s) && after.iter().all(|&j| scores[j] <= s)
}

/// Shi-Tomasi score at pixel `(x, y)`: the smaller eigenvalue of the mean of `∇I ∇Iᵀ` over
/// `[x − 4, x + 4) × [y − 4, y + 4)`, central differences, in (grey levels / pixel)² of this
/// image. `None` if the window or its differences leave the image.
pub fn shi_tomasi_score(img: &GrayImage, x: u32, y: u32) -> Option<f32> {
    let (w, h) = img.dimensions();
    if x < MIN_BORDER_PX || y < MIN_BORDER_PX || x + HALF_WINDOW >= w || y + HALF_WINDOW >= h {
        return None;
    }
    let p = img.as_raw();
    let w = w as usize;
    let (x, y) = (x as usize, y as usize);
    let half = HALF_WINDOW as usize;
    // Sums of products of undivided differences: |d| ≤ 255, 64 terms, well inside i32.
    let (mut sxx, mut sxy, mut syy) = (0_i32, 0_i32, 0_i32);
    for r in y - half..y + half {
        let row = r * w;
        for c in x - half..x + half {
            let dx = i32::from(p[row + c + 1]) - i32::from(p[row + c - 1]);
            let dy = i32::from(p[row + w + c]) - i32::from(p[row - w + c]);
            sxx += dx * dx;
            sxy += dx * dy;
            syy += dy * dy;
        }
    }
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
