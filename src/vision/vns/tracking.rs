//! Motion estimation (SVO; Forster, Pizzoli and Scaramuzza, ICRA 2014, section "Motion
//! estimation"; the paper's sections "SVO" and "SVO pose optimization"): sparse image alignment
//! against the previous frame from the constant-velocity guess ([`crate::vision::sparse_align`]),
//! the reprojection of the map from the aligned pose ([`super::reprojection`]), pose
//! optimisation ([`crate::vision::pose_opt`]) and the tracking-quality check; on a failure the
//! second chances from other starts, and only then a tracking loss and relocalisation against
//! the keyframe closest to the last good pose. Structure optimisation
//! ([`crate::vision::structure_opt`]) refines points of a frame that tracked.

use std::sync::Arc;

use nalgebra::{Isometry3, Vector6};

use super::reprojection::{FrameMatch, PointVerdict};
use super::{InertialFrame, LastFrame, Vns, VnsOutput, VnsState};
use crate::math::se3;
use crate::vision::map::{PointId, PointKind};
use crate::vision::pose_opt::{PoseObservation, optimize_pose};
use crate::vision::pyramid::Pyramid;
use crate::vision::sparse_align::{AlignFeature, SparseAlignConfig, sparse_align};
use crate::vision::structure_opt::{PointObservation, optimize_point};

/// The turn δ between the second-chance starts, degrees: 14.6 px at level 0, about half the
/// reach of sparse alignment over the city's street grid (a roll-rate step of 10–15°/s puts
/// the constant-velocity guess 1–1.5° off).
const SECOND_CHANCE_TURN_DEG: f64 = 0.75;

/// A frame tracked from one start pose, not yet committed to the map.
#[derive(Debug, Clone)]
pub(super) struct Attempt {
    pub(super) zeta_ec: Isometry3<f64>,
    pub(super) inliers: Vec<FrameMatch>,
    pub(super) n_matched: usize,
    pub(super) rms_px: f64,
    pub(super) verdicts: Vec<PointVerdict>,
    /// The start the pose optimisation converged from (`ζ_i0`).
    pub(super) start: Isometry3<f64>,
    /// Every match and its observation, in the same order (the IA-VNS optimises again).
    pub(super) matches: Vec<FrameMatch>,
    pub(super) observations: Vec<PoseObservation>,
}

/// Which second chance tracked a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SecondChance {
    /// The constant-velocity guess, aligned on the fine levels or bare.
    Guess,
    /// A start turned away from the guess.
    TurnedStart,
}

impl Vns {
    pub(super) fn track(
        &mut self,
        t_us: u64,
        pyramid: Arc<Pyramid>,
        ins: Option<&InertialFrame>,
    ) -> VnsOutput {
        let Some(last) = self.last.take() else {
            self.state = VnsState::WaitingForStart;
            return self.output(t_us, Isometry3::identity(), 0, 0, f64::NAN, false);
        };
        let relocalising = self.state == VnsState::Relocalising;
        // The reference for sparse alignment: the previous frame, or when relocalising the
        // keyframe closest to the last good pose.
        let reference = if relocalising {
            self.closest_keyframe_frame(&last.zeta_ec)
        } else {
            Some(last.clone())
        };
        // The guess: the last pose moved on by the last inter-frame motion (constant
        // velocity, beyond SVO 1's last pose: turbulence turns the camera by degrees per
        // second, more than sparse alignment's coarse levels recover on fine textures).
        let guess = match self.last_motion {
            Some(m) if !relocalising => se3::renormalized(&(last.zeta_ec * m)),
            _ => last.zeta_ec,
        };
        // The IA-VNS's inertial prediction ζ* replaces sparse alignment; sparse alignment and
        // the second chances remain for a frame it does not track.
        let predicted = ins
            .filter(|_| !relocalising)
            .and_then(|i| self.inertial_prediction(&last.zeta_ec, i));
        let from_prediction = predicted.map(|p| self.attempt(&pyramid, p, &last));
        if let (Some(state), Some(tried)) = (self.aiding.as_mut(), from_prediction.as_ref()) {
            state.counters.inertial_starts += 1;
            if tried.is_err() {
                state.counters.inertial_start_failures += 1;
            }
        }
        let min_aligned = if relocalising {
            self.cfg.relocalise_min_tracked
        } else {
            1
        };
        let (aligned, first) = match from_prediction {
            Some(Ok(a)) => (None, Ok(a)),
            _ => {
                let aligned = reference
                    .as_ref()
                    .and_then(|r| self.align(r, &pyramid, &guess, &self.cfg.sparse_align));
                let first = match aligned {
                    Some((zeta, n)) if n >= min_aligned => self.attempt(&pyramid, zeta, &last),
                    _ => Err(0),
                };
                (aligned, first)
            }
        };
        let result = first.or_else(|n| {
            let second = self.second_chance(
                reference.as_ref(),
                &pyramid,
                &guess,
                aligned
                    .filter(|&(_, n)| n >= min_aligned)
                    .map(|(zeta, _)| zeta),
                &last,
                min_aligned,
                relocalising,
            );
            match second {
                Ok((attempt, kind)) => {
                    self.counters.motion_model_recoveries += 1;
                    if kind == SecondChance::TurnedStart {
                        self.counters.turned_start_recoveries += 1;
                    }
                    Ok(attempt)
                }
                Err(most_matched) => Err(n.max(most_matched)),
            }
        });
        match result {
            Ok(mut attempt) => {
                if let Some(i) = ins {
                    self.apply_priors(t_us, &mut attempt, i);
                }
                let keyframe = self.commit(t_us, &pyramid, &mut attempt);
                self.remember_ins(ins);
                let zeta_ec = attempt.zeta_ec;
                if relocalising {
                    self.counters.relocalisations += 1;
                }
                self.state = VnsState::Tracking;
                self.last_motion =
                    (!relocalising).then(|| se3::renormalized(&(last.zeta_ec.inverse() * zeta_ec)));
                self.last_good = Some((t_us, zeta_ec));
                let n_inliers = attempt.inliers.len();
                self.last = Some(LastFrame {
                    t_us,
                    zeta_ec,
                    pyramid,
                    features: attempt
                        .inliers
                        .iter()
                        .map(|m| (m.px, m.level, m.point))
                        .collect(),
                    keyframe: keyframe || relocalising,
                });
                self.output(
                    t_us,
                    zeta_ec,
                    attempt.n_matched,
                    n_inliers,
                    attempt.rms_px,
                    keyframe,
                )
            }
            Err(n_matched) => {
                if !relocalising {
                    self.counters.tracking_losses += 1;
                }
                self.state = VnsState::Relocalising;
                // Keep the last good pose and image: the next frame relocalises from there.
                let zeta = last.zeta_ec;
                self.last = Some(LastFrame { t_us, ..last });
                self.output(t_us, zeta, n_matched, 0, f64::NAN, false)
            }
        }
    }

    /// The second chances of a frame that did not track from its sparse alignment (ORB-SLAM's
    /// tracking chain, widened). Over periodic texture (a city's street grid and rows of
    /// houses) sparse alignment's coarse levels can lock a pattern period away: tens to
    /// hundreds of metres and up to degrees from the guess, where a tilt and a lateral shift
    /// together move the pattern by about one period. In order:
    /// 1. alignment from the guess on the two finest alignment levels only (3→2), where the
    ///    guess is within reach and the coarse period is not seen; then the bare guess. The
    ///    first that tracks is taken;
    /// 2. while tracking (not relocalising), alignments on the fine levels and on all levels
    ///    from the guess turned by ±δ and ±2δ about the camera's x and y axes: an aileron or
    ///    a gust changes the roll rate by 10–15°/s within one frame, so the constant-velocity
    ///    guess is off by more than sparse alignment reaches over a street grid. There the
    ///    coarse levels pull every start into the same wrong basin, and the fine levels reach
    ///    only a fraction of a degree; each covers where the other fails. Of the starts that
    ///    pass the quality test the most inliers win: a pose a period away keeps about half.
    ///
    /// A frame that tracks from its first alignment never comes here, so a flight in which
    /// every frame does is unchanged by it. `Err` carries the most matches any start found.
    #[expect(
        clippy::too_many_arguments,
        reason = "the frame's alignment inputs and the tracking state, each used once"
    )]
    fn second_chance(
        &self,
        reference: Option<&LastFrame>,
        pyramid: &Pyramid,
        guess: &Isometry3<f64>,
        aligned: Option<Isometry3<f64>>,
        last: &LastFrame,
        min_aligned: usize,
        relocalising: bool,
    ) -> Result<(Attempt, SecondChance), usize> {
        let mut tried: Vec<Isometry3<f64>> = aligned.into_iter().collect();
        let mut most_matched = 0;
        let mut try_start = |start: Isometry3<f64>| {
            if tried.contains(&start) {
                return None;
            }
            tried.push(start);
            self.attempt(pyramid, start, last)
                .map_err(|n| most_matched = most_matched.max(n))
                .ok()
        };
        let fine_cfg = SparseAlignConfig {
            max_level: (self.cfg.sparse_align.min_level + 1).min(self.cfg.sparse_align.max_level),
            ..self.cfg.sparse_align
        };
        let fine = reference
            .and_then(|r| self.align(r, pyramid, guess, &fine_cfg))
            .filter(|&(_, n)| n >= min_aligned)
            .map(|(zeta, _)| zeta);
        if let Some(a) = fine.and_then(&mut try_start) {
            return Ok((a, SecondChance::Guess));
        }
        if let Some(a) = try_start(*guess) {
            return Ok((a, SecondChance::Guess));
        }
        let mut best: Option<Attempt> = None;
        if let Some(reference) = reference.filter(|_| !relocalising) {
            let delta = SECOND_CHANCE_TURN_DEG.to_radians();
            for (k, axis) in [
                (1.0, 0),
                (-1.0, 0),
                (1.0, 1),
                (-1.0, 1),
                (2.0, 0),
                (-2.0, 0),
                (2.0, 1),
                (-2.0, 1),
            ] {
                // τ = [v; ω]: a turn about the camera's x (index 3) or y (index 4) axis.
                let mut tau = Vector6::zeros();
                tau[3 + axis] = k * delta;
                let turned = se3::plus(guess, &tau);
                for cfg in [&fine_cfg, &self.cfg.sparse_align] {
                    let Some((start, n)) = self.align(reference, pyramid, &turned, cfg) else {
                        continue;
                    };
                    if n < min_aligned {
                        continue;
                    }
                    if let Some(a) = try_start(start)
                        && best
                            .as_ref()
                            .is_none_or(|b| a.inliers.len() > b.inliers.len())
                    {
                        best = Some(a);
                    }
                }
            }
        }
        best.map(|a| (a, SecondChance::TurnedStart))
            .ok_or(most_matched)
    }

    /// Sparse alignment of `pyramid` against `reference`, starting from `guess`; the pose and
    /// the features used.
    fn align(
        &self,
        reference: &LastFrame,
        pyramid: &Pyramid,
        guess: &Isometry3<f64>,
        cfg: &SparseAlignConfig,
    ) -> Option<(Isometry3<f64>, usize)> {
        let centre = reference.zeta_ec.translation.vector;
        let features: Vec<AlignFeature> = reference
            .features
            .iter()
            .filter_map(|(px, _, pid)| {
                let p = self.map.point(*pid)?;
                let range = (p.p_e - centre).norm();
                Some(AlignFeature {
                    px: *px,
                    p_ref: self.camera.back_project(px) * range,
                })
            })
            .collect();
        let t_cur_ref_guess = guess.inverse() * reference.zeta_ec;
        let r = sparse_align(
            &self.camera,
            &reference.pyramid,
            pyramid,
            &features,
            &t_cur_ref_guess,
            cfg,
        )
        .ok()?;
        Some((
            se3::renormalized(&(reference.zeta_ec * r.t_cur_ref.inverse())),
            r.n_features,
        ))
    }

    /// The keyframe closest to `zeta_ec`, as a reference frame with its matched features.
    fn closest_keyframe_frame(&self, zeta_ec: &Isometry3<f64>) -> Option<LastFrame> {
        let centre = zeta_ec.translation.vector;
        let kf = self.map.keyframes().min_by(|a, b| {
            (a.centre_e() - centre)
                .norm()
                .total_cmp(&(b.centre_e() - centre).norm())
        })?;
        Some(LastFrame {
            t_us: kf.t_us,
            zeta_ec: kf.zeta_ec,
            pyramid: kf.pyramid.clone(),
            features: kf
                .features
                .iter()
                .filter_map(|f| {
                    let pid = f.point?;
                    (self.map.point(pid)?.kind != PointKind::Candidate)
                        .then_some((f.px, f.level, pid))
                })
                .collect(),
            keyframe: true,
        })
    }

    /// Steps 3–5 from a start pose (matching, pose optimisation, the quality test), without
    /// touching the map: `Err(matched)` on a tracking failure.
    fn attempt(
        &self,
        pyramid: &Pyramid,
        start: Isometry3<f64>,
        last: &LastFrame,
    ) -> Result<Attempt, usize> {
        let (matches, verdicts) = self.reproject_and_match(pyramid, &start);
        let n_matched = matches.len();
        if n_matched < self.cfg.min_matches {
            return Err(n_matched);
        }
        // Matches whose point is gone cannot be observed; keep the two lists aligned.
        let (matches, observations): (Vec<FrameMatch>, Vec<PoseObservation>) = matches
            .iter()
            .filter_map(|m| {
                Some((
                    *m,
                    PoseObservation {
                        p_e: self.map.point(m.point)?.p_e,
                        px: m.px,
                        level: m.level,
                    },
                ))
            })
            .unzip();
        // A plane seen through a narrow field of view has two poses that explain it almost
        // equally (the tilt flip): sparse alignment, which stops at level 2, cannot tell them
        // apart and may start the optimisation in the wrong basin. The constant-velocity
        // prediction from the previous frames is a second start; the lower cost wins.
        // (The prediction is skipped when it is the start itself: the bare-guess attempt.)
        let starts = std::iter::once(start).chain(
            self.last_motion
                .map(|m| se3::renormalized(&(last.zeta_ec * m)))
                .filter(|predicted| *predicted != start),
        );
        let Some((start, opt)) = starts
            .filter_map(|start| {
                optimize_pose(&self.camera, &start, &observations, &self.cfg.pose, None)
                    .ok()
                    .map(|opt| (start, opt))
            })
            .min_by(|a, b| a.1.final_cost_px.total_cmp(&b.1.final_cost_px))
        else {
            return Err(n_matched);
        };
        let inliers: Vec<FrameMatch> = matches
            .iter()
            .zip(&opt.inliers)
            .filter(|(_, ok)| **ok)
            .map(|(m, _)| *m)
            .collect();
        // Quality (SVO: at least `min_matches`, no drop of more than `max_match_drop`).
        let previous = if last.keyframe {
            0
        } else {
            last.features.len().min(self.cfg.max_matches)
        };
        if inliers.len() < self.cfg.min_matches
            || previous.saturating_sub(inliers.len()) > self.cfg.max_match_drop
        {
            return Err(n_matched);
        }
        Ok(Attempt {
            zeta_ec: opt.zeta_ec,
            inliers,
            n_matched,
            rms_px: opt.inlier_rms_px,
            verdicts,
            start,
            matches,
            observations,
        })
    }

    /// Refine the least recently refined matched points over their keyframe observations and,
    /// with `current` (the IA-VNS), the current frame's observation at that final pose.
    pub(super) fn optimize_structure(
        &mut self,
        matches: &[FrameMatch],
        current: Option<&Isometry3<f64>>,
    ) {
        let mut order: Vec<(u64, PointId)> = matches
            .iter()
            .filter_map(|m| Some((self.map.point(m.point)?.last_structure_opt, m.point)))
            .collect();
        order.sort_unstable();
        let current_px: std::collections::BTreeMap<PointId, nalgebra::Vector2<f64>> = current
            .map(|_| matches.iter().map(|m| (m.point, m.px)).collect())
            .unwrap_or_default();
        for &(_, pid) in order.iter().take(self.cfg.structure_points) {
            let Some(p) = self.map.point(pid) else {
                continue;
            };
            let observations: Vec<PointObservation> = p
                .observations
                .iter()
                .filter_map(|o| {
                    let kf = self.map.keyframe(o.keyframe)?;
                    Some(PointObservation {
                        zeta_ec: kf.zeta_ec,
                        px: kf.features.get(o.feature)?.px,
                    })
                })
                .chain(
                    current
                        .zip(current_px.get(&pid))
                        .map(|(z, px)| PointObservation {
                            zeta_ec: *z,
                            px: *px,
                        }),
                )
                .collect();
            let refined = optimize_point(
                &self.camera,
                &p.p_e,
                &observations,
                self.cfg.structure_iterations,
            );
            let frame_index = self.frame_index;
            if let Some(p) = self.map.point_mut(pid) {
                p.p_e = refined;
                p.last_structure_opt = frame_index;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use crate::vision::pyramid::Pyramid;
    use crate::vision::test_scene::{Ground, nadir_pose};
    use crate::vision::vns::tests::{GROUND_5, pose_at, small_vns, start_at, zeta_ew};
    use crate::vision::vns::{Vns, VnsState};

    /// Every output from frame `k0` on is tracking.
    fn assert_tracking_from(states: &[(u64, VnsState)], k0: u64) {
        assert!(
            states
                .iter()
                .filter(|(k, _)| *k >= k0)
                .all(|(_, s)| *s == VnsState::Tracking),
            "{states:?}"
        );
    }

    /// Sparse alignment that settles at a wrong pose (here: the reference image swapped for one
    /// taken 40 m away, so the alignment moves by about 2.3° of view, tens of px) fails the
    /// frame's matching; the motion model's guess tracks it instead. Not a loss: the frame
    /// keeps tracking and the recovery is counted.
    #[test]
    fn a_frame_whose_alignment_settles_wrong_is_tracked_from_the_motion_model() {
        let (cam, mut vns) = small_vns();
        let ground = GROUND_5;
        let zeta_ew = zeta_ew();
        let mut states = Vec::new();
        for k in 0..33_u64 {
            let t_us = 1_000_000 + k * 100_000;
            let pose_w = pose_at(k);
            if k == 30 {
                let last = vns.last.as_mut().expect("tracking before frame 30");
                let moved = nadir_pose(30.0 * 2.9 + 40.0, 1.5 * 2.9, 1_000.0, [0.0, 0.0, 0.0058]);
                let elsewhere = ground.frame(&cam, &moved, last.t_us);
                last.pyramid = Arc::new(Pyramid::from_frame(&elsewhere, &cam).unwrap());
            }
            let frame = ground.frame(&cam, &pose_w, t_us);
            let start = start_at(&zeta_ew, &pose_w);
            if let Some(out) = vns.process(&frame, Some(&start), None).unwrap() {
                if k == 30 {
                    let truth = zeta_ew * pose_w;
                    let err_m = (out.zeta_ec.translation.vector - truth.translation.vector).norm();
                    assert!(err_m < 5.0, "frame 30 tracked {err_m} m off");
                }
                states.push((k, out.state));
            }
        }
        assert_tracking_from(&states, 29);
        let c = *vns.counters();
        assert_eq!(
            (c.tracking_losses, c.motion_model_recoveries),
            (0, 1),
            "{c:?}"
        );
    }

    /// A roll-rate step at frame 30 (an aileron at a roll-in): the image turns by 3° (58 px,
    /// 3.6 px at sparse alignment's level 4) more than the constant-velocity guess says. On
    /// this texture alignment from the guess holds up to about 2.6°, and matching reaches a
    /// few pixels only, so the frame is tracked from a turned start (counted apart) or lost.
    /// The rate then stays, so the next frames track from their own alignment.
    #[test]
    fn a_roll_rate_step_beyond_the_alignment_basin_is_tracked_from_a_turned_start() {
        let (cam, mut vns) = small_vns();
        let ground = GROUND_5;
        let zeta_ew = zeta_ew();
        let step_deg: f64 = 3.0;
        let mut states = Vec::new();
        for k in 0..34_u64 {
            let t_us = 1_000_000 + k * 100_000;
            let t = k as f64 * 0.1;
            let roll_rad = step_deg.to_radians() * k.saturating_sub(29) as f64;
            let pose_w = nadir_pose(30.0 * t, 1.5 * t, 1_000.0, [roll_rad, 0.0, 0.002 * t]);
            let frame = ground.frame(&cam, &pose_w, t_us);
            let start = start_at(&zeta_ew, &pose_w);
            if let Some(out) = vns.process(&frame, Some(&start), None).unwrap() {
                if k >= 30 {
                    let truth = zeta_ew * pose_w;
                    let err_m = (out.zeta_ec.translation.vector - truth.translation.vector).norm();
                    let err_deg = (truth.rotation.inverse() * out.zeta_ec.rotation)
                        .angle()
                        .to_degrees();
                    assert!(
                        err_m < 5.0 && err_deg < 0.1,
                        "frame {k}: {err_m} m, {err_deg}°"
                    );
                }
                states.push((k, out.state));
            }
        }
        assert_tracking_from(&states, 29);
        let c = *vns.counters();
        assert_eq!(
            (
                c.tracking_losses,
                c.motion_model_recoveries,
                c.turned_start_recoveries
            ),
            (0, 1, 1),
            "{c:?}"
        );
    }

    /// A frame that tracks from no start is lost without touching the map: matching around
    /// wrong starts fails good points, and charging them would delete some of the points the
    /// relocalisation needs. Frame 30 shows other ground; frame 31 the right ground again.
    #[test]
    fn a_lost_frame_leaves_the_map_points_as_they_were() {
        let (cam, mut vns) = small_vns();
        let ground = GROUND_5;
        let elsewhere = Ground {
            seed: 99,
            ground_z_m: 0.0,
        };
        let zeta_ew = zeta_ew();
        let snapshot = |vns: &Vns| {
            let points: Vec<_> = vns
                .map()
                .points()
                .map(|(id, p)| (id, p.p_e, p.kind, p.successes, p.failures))
                .collect();
            (points, vns.map().keyframes().count(), vns.seeds.len())
        };
        let mut before = None;
        for k in 0..32_u64 {
            let t_us = 1_000_000 + k * 100_000;
            let pose_w = pose_at(k);
            let scene = if k == 30 { &elsewhere } else { &ground };
            let frame = scene.frame(&cam, &pose_w, t_us);
            let start = start_at(&zeta_ew, &pose_w);
            if k == 30 {
                assert_eq!(vns.state(), VnsState::Tracking);
                before = Some(snapshot(&vns));
            }
            let out = vns.process(&frame, Some(&start), None).unwrap();
            if k == 30 {
                assert_eq!(out.map(|o| o.state), Some(VnsState::Relocalising));
                assert_eq!(
                    Some(snapshot(&vns)),
                    before,
                    "the lost frame changed the map"
                );
            }
        }
        let c = *vns.counters();
        assert_eq!((c.tracking_losses, c.relocalisations), (1, 1), "{c:?}");
        assert_eq!(vns.state(), VnsState::Tracking);
    }
}
