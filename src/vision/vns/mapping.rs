//! Mapping (SVO; Forster, Pizzoli and Scaramuzza, ICRA 2014, section "Mapping"; SVO 1's
//! `FrameHandlerMono::needNewKf` and `DepthFilter`), run synchronously after the motion
//! estimation of the same frame: keyframe selection; the depth-filter update of every live seed
//! by epipolar search ([`crate::vision::depth_filter`], [`crate::vision::matcher`]), converged
//! seeds becoming candidates; and for a selected frame the keyframe's insertion: the furthest
//! keyframe dropped beyond the map's size, the matched points observed, candidates promoted,
//! seeds past their lifetime dropped, new seeds on the free cells.

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};

use super::Vns;
use super::reprojection::FrameMatch;
use crate::math::stats::median;
use crate::vision::depth_filter::{Seed, SeedUpdate, inverse_depth_variance};
use crate::vision::map::{Keyframe, KeyframeFeature, KeyframeId, Observation, PointKind};
use crate::vision::matcher::find_epipolar_match;
use crate::vision::pyramid::Pyramid;

/// Seeds are updated only from frames that see them with at least this parallax, px.
const MIN_SEED_PARALLAX_PX: f64 = 2.0;

/// A depth-filter seed and the keyframe feature it belongs to.
#[derive(Debug, Clone)]
pub(super) struct LiveSeed {
    keyframe: KeyframeId,
    feature: usize,
    /// Unit bearing in the keyframe's camera.
    f_ref: Vector3<f64>,
    seed: Seed,
}

impl Vns {
    /// Median depth (camera z) of the matched points; `None` without points in front.
    fn median_depth(&self, zeta_ec: &Isometry3<f64>, matches: &[FrameMatch]) -> Option<(f64, f64)> {
        let depths: Vec<f64> = matches
            .iter()
            .filter_map(|m| {
                let z = zeta_ec
                    .inverse_transform_point(&self.map.point(m.point)?.p_e.into())
                    .z;
                (z > 0.0).then_some(z)
            })
            .collect();
        let min = depths.iter().copied().fold(f64::INFINITY, f64::min);
        median(depths).map(|m| (m, min))
    }

    /// SVO 1's keyframe rule: a new keyframe unless an overlapping keyframe is within
    /// (1, 0.8, 1.3) × `keyframe_min_distance` × the median depth along the camera's axes.
    pub(super) fn needs_keyframe(&self, zeta_ec: &Isometry3<f64>, matches: &[FrameMatch]) -> bool {
        let Some((depth, _)) = self.median_depth(zeta_ec, matches) else {
            return false;
        };
        let d = self.cfg.keyframe_min_distance * depth;
        let close = self
            .map
            .overlapping_keyframes(&self.camera, zeta_ec, self.cfg.reprojection_keyframes)
            .into_iter()
            .filter_map(|id| self.map.keyframe(id))
            .any(|kf| {
                let rel = zeta_ec.inverse_transform_point(&kf.centre_e().into());
                rel.x.abs() < d && rel.y.abs() < 0.8 * d && rel.z.abs() < 1.3 * d
            });
        !close
    }

    /// Make the current frame a keyframe: observations of the matched points, candidates
    /// promoted, new seeds on free cells, the map bounded.
    pub(super) fn insert_keyframe(
        &mut self,
        t_us: u64,
        pyramid: &Arc<Pyramid>,
        zeta_ec: &Isometry3<f64>,
        matches: &[FrameMatch],
    ) {
        let Some((depth_median, depth_min)) = self.median_depth(zeta_ec, matches) else {
            return;
        };
        if self.map.n_keyframes() >= self.cfg.max_keyframes
            && let Some(far) = self.map.furthest_keyframe(&zeta_ec.translation.vector)
        {
            self.map.remove_keyframe(far);
            self.seeds.retain(|s| s.keyframe != far);
        }
        let features: Vec<KeyframeFeature> = matches
            .iter()
            .map(|m| KeyframeFeature {
                px: m.px,
                level: m.level,
                point: None,
            })
            .collect();
        let id = self.map.add_keyframe(Keyframe {
            id: 0,
            t_us,
            zeta_ec: *zeta_ec,
            pyramid: pyramid.clone(),
            features,
        });
        for (k, m) in matches.iter().enumerate() {
            self.map.observe(
                m.point,
                Observation {
                    keyframe: id,
                    feature: k,
                },
            );
            if let Some(p) = self.map.point_mut(m.point)
                && p.kind == PointKind::Candidate
            {
                p.kind = PointKind::Unknown;
                p.failures = 0;
            }
        }
        // Seeds of keyframes older than the seed lifetime go.
        let oldest = id.saturating_sub(self.cfg.seed_keyframes - 1);
        self.seeds.retain(|s| s.keyframe >= oldest);
        self.add_seeds(id, pyramid, zeta_ec, depth_median, depth_min);
        self.counters.keyframes += 1;
    }

    /// Detect features on the keyframe's free cells and start a seed for each.
    pub(super) fn add_seeds(
        &mut self,
        id: KeyframeId,
        pyramid: &Pyramid,
        zeta_ec: &Isometry3<f64>,
        depth_median_m: f64,
        depth_min_m: f64,
    ) {
        let _ = zeta_ec;
        let Some(kf) = self.map.keyframe(id) else {
            return;
        };
        let mut occupancy = self.detector.empty_occupancy();
        for f in &kf.features {
            occupancy.occupy(&f.px);
        }
        let Ok(found) = self.detector.detect(pyramid, &occupancy) else {
            return;
        };
        let Some(seed) = Seed::new(depth_median_m, depth_min_m) else {
            return;
        };
        let Some(kf) = self.map.keyframe_mut(id) else {
            return;
        };
        for f in found {
            let feature = kf.features.len();
            kf.features.push(KeyframeFeature {
                px: f.px,
                level: f.level,
                point: None,
            });
            self.seeds.push(LiveSeed {
                keyframe: id,
                feature,
                f_ref: self.camera.back_project(&f.px),
                seed,
            });
        }
    }

    /// Update every live seed by epipolar search in the current frame; converged seeds become
    /// candidates.
    pub(super) fn update_seeds(&mut self, pyramid: &Pyramid, zeta_ec: &Isometry3<f64>) {
        let mut converged = Vec::new();
        let mut keep = Vec::with_capacity(self.seeds.len());
        for mut s in std::mem::take(&mut self.seeds) {
            let Some(kf) = self.map.keyframe(s.keyframe) else {
                continue;
            };
            let Some(feature) = kf.features.get(s.feature).copied() else {
                continue;
            };
            let t_cur_ref = zeta_ec.inverse() * kf.zeta_ec;
            // Below ~2 px of parallax a triangulation says nothing: wait for more baseline
            // rather than count a miss. (`f b / d` is the parallax on the optical axis, where
            // a pixel subtends 1/f rad for every lens model; a rough gate elsewhere too.)
            let baseline_m = t_cur_ref.translation.vector.norm();
            if baseline_m * self.camera.f_px() < MIN_SEED_PARALLAX_PX * s.seed.depth_m() {
                keep.push(s);
                continue;
            }
            // Predicted point in the current camera; skip if not visible.
            let p_cur = t_cur_ref * nalgebra::Point3::from(s.f_ref * s.seed.depth_m());
            if !self
                .camera
                .project(&p_cur.coords)
                .is_some_and(|px| self.camera.contains(&px, 9.0))
            {
                keep.push(s);
                continue;
            }
            let found = find_epipolar_match(
                &self.camera,
                &kf.pyramid,
                &feature.px,
                feature.level,
                s.seed.depth_m(),
                s.seed.search_depths_m(),
                &t_cur_ref,
                pyramid,
            );
            let Ok(m) = found else {
                s.seed.miss();
                keep.push(s);
                continue;
            };
            let t_ref_cur = t_cur_ref.inverse().translation.vector;
            // SVO's pixel angle 2 atan(1 / 2f): a pixel's angle on the optical axis for every
            // lens model, and over the whole field of an equidistant fisheye; off axis a
            // perspective pixel subtends less (cos² θ), which SVO ignores too (σ a little
            // pessimistic there).
            let Some(tau2) =
                inverse_depth_variance(&s.f_ref, m.range_m, &t_ref_cur, 1.0, self.camera.f_px())
            else {
                keep.push(s);
                continue;
            };
            match s.seed.update(1.0 / m.range_m, tau2) {
                SeedUpdate::Updated => keep.push(s),
                SeedUpdate::Converged => converged.push(s),
                SeedUpdate::Diverged => {}
            }
        }
        self.seeds = keep;
        for s in converged {
            let Some(kf) = self.map.keyframe(s.keyframe) else {
                continue;
            };
            let p_e = kf.zeta_ec * nalgebra::Point3::from(s.f_ref * s.seed.depth_m());
            self.map.add_point(
                p_e.coords,
                PointKind::Candidate,
                vec![Observation {
                    keyframe: s.keyframe,
                    feature: s.feature,
                }],
            );
            self.counters.seeds_converged += 1;
        }
    }
}
