//! Two-view initialisation of the VNS (SVO 1's `KltHomographyInit`; the paper's "VNS flow
//! diagram", first box): the FAST corners of the first image are tracked by pyramidal KLT
//! ([`crate::vision::klt`]) until their median displacement reaches
//! [`VnsConfig::init_min_disparity_px`](super::VnsConfig::init_min_disparity_px); then the
//! homography by RANSAC, its decomposition and the metric scale from the height over the
//! terrain in `x̊₀` ([`crate::vision::homography`]). The two images become the first keyframes,
//! the triangulated points the first map, and the second keyframe's free cells get seeds.

use std::sync::Arc;

use nalgebra::{Unit, Vector2, Vector3};

use super::aiding::{inertial_displacement_e, inertial_motion};
use super::{InertialFrame, LastFrame, Vns, VnsOutput, VnsStart, VnsState};
use crate::math::stats::median;
use crate::math::{se3, wgs84};
use crate::vision::homography::{UnitPlaneMatch, initialise_two_view, triangulate_metric};
use crate::vision::klt::KltFeature;
use crate::vision::map::{Keyframe, KeyframeFeature, Observation, PointKind};
use crate::vision::pyramid::Pyramid;

/// Largest frame-to-frame motion of an initial track, px (rotations in turbulence move the
/// image by ~20 px per degree).
const MAX_INIT_TRACK_JUMP_PX: f64 = 40.0;

/// The first image of an initialisation and its tracks.
#[derive(Debug, Clone)]
pub(super) struct InitTracks {
    pub(super) t_us: u64,
    start: VnsStart,
    pyramid: Arc<Pyramid>,
    /// Detected features: level-0 pixel and level.
    features: Vec<(Vector2<f64>, u32)>,
    /// Their tracking templates.
    klt: Vec<KltFeature>,
    /// Latest tracked level-0 pixel of each feature (`None`: lost).
    tracked: Vec<Option<Vector2<f64>>>,
    /// The IA-VNS: the INS displacement since the first image (Earth axes, m) and the INS
    /// at the latest image; `None` once a frame came without the INS.
    ins_path: Option<(Vector3<f64>, InertialFrame)>,
}

impl Vns {
    fn start_init(
        &mut self,
        t_us: u64,
        pyramid: Arc<Pyramid>,
        start: &VnsStart,
        ins: Option<&InertialFrame>,
    ) {
        let occupancy = self.init_detector.empty_occupancy();
        let features = self
            .init_detector
            .detect(&pyramid, &occupancy)
            .unwrap_or_default();
        if features.len() < self.cfg.init_min_features
            || !(start.h_agl_m.is_finite() && start.h_agl_m > 0.0)
        {
            self.init = None;
            self.state = VnsState::WaitingForStart;
            return;
        }
        let features: Vec<_> = features.iter().map(|f| (f.px, f.level)).collect();
        self.init = Some(InitTracks {
            t_us,
            start: *start,
            klt: features
                .iter()
                .map(|(px, _)| KltFeature::new(&pyramid, px))
                .collect(),
            pyramid,
            tracked: features.iter().map(|f| Some(f.0)).collect(),
            features,
            ins_path: ins.map(|i| (Vector3::zeros(), *i)),
        });
        self.state = VnsState::Initialising;
    }

    pub(super) fn initialise(
        &mut self,
        t_us: u64,
        pyramid: Arc<Pyramid>,
        start: Option<&VnsStart>,
        ins: Option<&InertialFrame>,
    ) -> Option<VnsOutput> {
        let Some(mut init) = self.init.take() else {
            if let Some(start) = start {
                self.start_init(t_us, pyramid, start, ins);
            }
            return None;
        };
        // Track every feature from its last position with its first-image patch, coarse to
        // fine (the image moves a few pixels per frame).
        for (k, klt) in init.klt.iter().enumerate() {
            let Some(prev) = init.tracked[k] else {
                continue;
            };
            init.tracked[k] = klt
                .track(&pyramid, &prev)
                .filter(|px| (px - prev).norm() < MAX_INIT_TRACK_JUMP_PX)
                .filter(|px| self.camera.contains(px, 0.0));
        }
        init.t_us = t_us;
        init.ins_path = init.ins_path.zip(ins).and_then(|((path, last), now)| {
            Some((path + inertial_displacement_e(&last, now)?, *now))
        });
        let pairs: Vec<(Vector2<f64>, Vector2<f64>)> = init
            .features
            .iter()
            .zip(&init.tracked)
            .filter_map(|((p0, _), t)| t.map(|t| (*p0, t)))
            .collect();
        if pairs.len() < self.cfg.init_min_tracked {
            self.counters.init_restarts += 1;
            self.init = None;
            self.state = VnsState::WaitingForStart;
            if let Some(start) = start {
                self.start_init(t_us, pyramid, start, ins);
            }
            return None;
        }
        let disparity = median(pairs.iter().map(|(a, b)| (b - a).norm()).collect()).unwrap_or(0.0);
        if disparity < self.cfg.init_min_disparity_px {
            self.init = Some(init);
            return None;
        }
        let matches: Vec<UnitPlaneMatch> = pairs
            .iter()
            .map(|(a, b)| UnitPlaneMatch::from_pixels(&self.camera, a, b))
            .collect();
        // The terrain normal (down) in the first camera, from x̊₀: only a tie-breaker.
        let zeta_ec1 = init.start.zeta_ec;
        let pos = wgs84::ecef_to_geodetic(&zeta_ec1.translation.vector);
        let down_e = wgs84::q_en(pos.lat_rad, pos.lon_rad) * Vector3::z();
        let down_c1 = Unit::new_normalize(zeta_ec1.rotation.inverse() * down_e);
        // `f_px` turns the pixel thresholds into distances on the unit plane of the
        // undistorted bearings: exact at the image centre for every lens; towards the edges
        // a pixel spans a different distance there (a barrel lens: more), so the RANSAC and
        // tie-break thresholds become somewhat stricter or looser in pixels, which they
        // tolerate (they are gates, not weights).
        let result = initialise_two_view(
            &matches,
            self.camera.f_px(),
            init.start.h_agl_m,
            Some(&down_c1),
            &self.cfg.homography,
        );
        let Ok(two_view) = result else {
            // More parallax may help; give up only when the tracks thin out (above).
            self.init = Some(init);
            return None;
        };
        // The IA-VNS: the INS relative pose between the two images (rotation, and translation
        // integrated from the velocity), which fixes the scale (the height) and the path angle
        // (docs/IAVNS.md, "Initialisation"); the plane's distance, which the VNS takes from
        // the height over the terrain, is not needed.
        let inertial = init
            .ins_path
            .filter(|_| self.cfg.aiding.inertial_initialisation)
            .and_then(|(path_e, ins)| {
                // The camera's path: the body's plus the lens's turn about the body.
                let lever_now = ins.zeta_eb.rotation * ins.zeta_bc.translation.vector;
                let lever_first = zeta_ec1.rotation
                    * ins.zeta_bc.rotation.inverse()
                    * ins.zeta_bc.translation.vector;
                let t_ins_e = path_e + lever_now - lever_first;
                let q_ec2 = ins.zeta_eb.rotation * ins.zeta_bc.rotation;
                let motion =
                    inertial_motion(&two_view.selection.chosen, &zeta_ec1, &q_ec2, &t_ins_e)?;
                triangulate_metric(
                    &matches,
                    &motion,
                    1.0,
                    self.camera.f_px(),
                    &self.cfg.homography,
                )
                .ok()
            });
        let metric = inertial.as_ref().unwrap_or(&two_view.metric);
        let zeta_ec2 = se3::renormalized(&(zeta_ec1 * metric.zeta_c2c1.inverse()));
        // Keyframes 1 and 2 with the triangulated points.
        let mut f1 = Vec::with_capacity(metric.points.len());
        let mut f2 = Vec::with_capacity(metric.points.len());
        let mut points_e = Vec::with_capacity(metric.points.len());
        let pair_features: Vec<(Vector2<f64>, u32, Vector2<f64>)> = init
            .features
            .iter()
            .zip(&init.tracked)
            .filter_map(|((p0, l), t)| t.map(|t| (*p0, *l, t)))
            .collect();
        for tp in &metric.points {
            let Some(&(p0, level, p2)) = pair_features.get(tp.index) else {
                continue;
            };
            f1.push(KeyframeFeature {
                px: p0,
                level,
                point: None,
            });
            f2.push(KeyframeFeature {
                px: p2,
                level,
                point: None,
            });
            points_e.push(zeta_ec1 * nalgebra::Point3::from(tp.p_c1_m));
        }
        self.map.clear();
        self.seeds.clear();
        self.last_motion = None;
        let kf1 = self.map.add_keyframe(Keyframe {
            id: 0,
            t_us: init.t_us,
            zeta_ec: zeta_ec1,
            pyramid: init.pyramid.clone(),
            features: f1,
        });
        let kf2 = self.map.add_keyframe(Keyframe {
            id: 0,
            t_us,
            zeta_ec: zeta_ec2,
            pyramid: pyramid.clone(),
            features: f2.clone(),
        });
        let mut last_features = Vec::with_capacity(points_e.len());
        for (k, p_e) in points_e.iter().enumerate() {
            let id = self.map.add_point(
                p_e.coords,
                PointKind::Unknown,
                vec![
                    Observation {
                        keyframe: kf1,
                        feature: k,
                    },
                    Observation {
                        keyframe: kf2,
                        feature: k,
                    },
                ],
            );
            last_features.push((f2[k].px, f2[k].level, id));
        }
        // New seeds in the second keyframe's free cells.
        self.add_seeds(
            kf2,
            &pyramid,
            &zeta_ec2,
            metric.median_depth_c1_m,
            metric.min_depth_c1_m,
        );
        self.counters.initialisations += 1;
        self.counters.keyframes += 2;
        self.state = VnsState::Tracking;
        self.last_good = Some((t_us, zeta_ec2));
        let n = last_features.len();
        self.last = Some(LastFrame {
            t_us,
            zeta_ec: zeta_ec2,
            pyramid,
            features: last_features,
            keyframe: true,
        });
        Some(self.output(t_us, zeta_ec2, n, n, f64::NAN, true))
    }
}
