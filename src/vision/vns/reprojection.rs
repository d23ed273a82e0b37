//! Reprojection and feature alignment (SVO; Forster, Pizzoli and Scaramuzza, ICRA 2014, section
//! "Relaxation through feature alignment"; SVO 1's `Reprojector`): the points of the closest
//! overlapping keyframes and the candidates are projected into the frame's grid, and in each cell,
//! visited in the fixed random order, the first point that matches directly
//! ([`crate::vision::matcher`]) from the keyframe observation closest in viewing angle is kept,
//! at most one per cell. What matching said about each point (matched, failed) is kept as a
//! verdict and applied to the map only once the frame has tracked: successes promote an unknown
//! point to a good one, failures delete unknown points and candidates past their limits.

use nalgebra::{Isometry3, Vector2};

use super::Vns;
use crate::vision::map::{
    CANDIDATE_MAX_FAILURES, GOOD_AFTER_SUCCESSES, PointId, PointKind, UNKNOWN_MAX_FAILURES,
};
use crate::vision::matcher::find_match_direct;
use crate::vision::pyramid::Pyramid;

/// One matched feature of the current frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct FrameMatch {
    pub(super) point: PointId,
    pub(super) px: Vector2<f64>,
    pub(super) level: u32,
}

/// What matching said about one map point in the current frame, kept until the frame tracks.
#[derive(Debug, Clone, Copy)]
pub(super) enum PointVerdict {
    Matched { point: PointId },
    Failed { point: PointId, units: u32 },
}

impl Vns {
    /// Reprojection of the closest overlapping keyframes' points and of the candidates into
    /// the grid, then one direct match per cell in the fixed random order.
    pub(super) fn reproject_and_match(
        &self,
        pyramid: &Pyramid,
        zeta_ec: &Isometry3<f64>,
    ) -> (Vec<FrameMatch>, Vec<PointVerdict>) {
        let mut verdicts = Vec::new();
        let grid = *self.detector.grid();
        let mut cells: Vec<Vec<(PointKind, PointId, Vector2<f64>)>> =
            vec![Vec::new(); grid.n_cells()];
        let keyframes =
            self.map
                .overlapping_keyframes(&self.camera, zeta_ec, self.cfg.reprojection_keyframes);
        let mut seen = std::collections::BTreeSet::new();
        let border = self.cfg.reprojection_border_px;
        for kf_id in keyframes {
            let Some(kf) = self.map.keyframe(kf_id) else {
                continue;
            };
            for f in &kf.features {
                let Some(pid) = f.point else { continue };
                if !seen.insert(pid) {
                    continue;
                }
                let Some(p) = self.map.point(pid) else {
                    continue;
                };
                if p.kind == PointKind::Candidate {
                    continue;
                }
                if let Some(px) = self.camera.project_ecef(zeta_ec, &p.p_e)
                    && self.camera.contains(&px, border)
                    && let Some(cell) = grid.cell_of(&px)
                {
                    cells[cell].push((p.kind, pid, px));
                }
            }
        }
        // Candidates: all of them; out of the image costs 3 failure units.
        let candidates: Vec<PointId> = self
            .map
            .points()
            .filter(|(_, p)| p.kind == PointKind::Candidate)
            .map(|(id, _)| id)
            .collect();
        for pid in candidates {
            let Some(p) = self.map.point(pid) else {
                continue;
            };
            match self.camera.project_ecef(zeta_ec, &p.p_e) {
                Some(px) if self.camera.contains(&px, border) => {
                    if let Some(cell) = grid.cell_of(&px) {
                        cells[cell].push((PointKind::Candidate, pid, px));
                    }
                }
                _ => verdicts.push(PointVerdict::Failed {
                    point: pid,
                    units: 3,
                }),
            }
        }
        let mut matches = Vec::with_capacity(self.cfg.max_matches);
        for &cell in &self.cell_order {
            if matches.len() >= self.cfg.max_matches {
                break;
            }
            let list = &mut cells[cell];
            list.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
            for (_, pid, px) in std::mem::take(list) {
                match self.match_point(pid, &px, pyramid, zeta_ec) {
                    Some(m) => {
                        verdicts.push(PointVerdict::Matched { point: pid });
                        matches.push(m);
                        break;
                    }
                    None => verdicts.push(PointVerdict::Failed {
                        point: pid,
                        units: 1,
                    }),
                }
            }
        }
        (matches, verdicts)
    }

    /// Apply a tracked frame's match verdicts, in the order they were reached: a match counts
    /// towards promotion to a good point, a failure towards deletion.
    pub(super) fn apply_verdicts(&mut self, verdicts: Vec<PointVerdict>) {
        for verdict in verdicts {
            match verdict {
                PointVerdict::Matched { point } => {
                    if let Some(p) = self.map.point_mut(point) {
                        p.successes += 1;
                        if p.kind == PointKind::Unknown && p.successes > GOOD_AFTER_SUCCESSES {
                            p.kind = PointKind::Good;
                        }
                    }
                }
                PointVerdict::Failed { point, units } => self.fail_point(point, units),
            }
        }
    }

    /// Count failure units against a point; delete it past its kind's limit.
    fn fail_point(&mut self, pid: PointId, units: u32) {
        let Some(p) = self.map.point_mut(pid) else {
            return;
        };
        p.failures += units;
        let delete = match p.kind {
            PointKind::Unknown => p.failures > UNKNOWN_MAX_FAILURES,
            PointKind::Candidate => p.failures > CANDIDATE_MAX_FAILURES,
            PointKind::Good => false,
        };
        if delete {
            self.map.remove_point(pid);
        }
    }

    /// Direct match of one point from the keyframe observation closest in viewing angle.
    fn match_point(
        &self,
        pid: PointId,
        predicted_px: &Vector2<f64>,
        pyramid: &Pyramid,
        zeta_ec: &Isometry3<f64>,
    ) -> Option<FrameMatch> {
        let p = self.map.point(pid)?;
        let view = (zeta_ec.translation.vector - p.p_e).normalize();
        let (cos, kf, feature) = p
            .observations
            .iter()
            .filter_map(|o| {
                let kf = self.map.keyframe(o.keyframe)?;
                let f = kf.features.get(o.feature)?;
                let dir = (kf.centre_e() - p.p_e).normalize();
                Some((dir.dot(&view), kf, f))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0))?;
        if cos < self.cfg.min_view_cos {
            return None;
        }
        let range_m = (kf.centre_e() - p.p_e).norm();
        let t_cur_ref = zeta_ec.inverse() * kf.zeta_ec;
        let m = find_match_direct(
            &self.camera,
            &kf.pyramid,
            &feature.px,
            feature.level,
            range_m,
            &t_cur_ref,
            pyramid,
            predicted_px,
        )?;
        Some(FrameMatch {
            point: pid,
            px: m.px,
            level: m.level,
        })
    }
}
