//! The map of semi-direct visual odometry (paper, section "SVO": the mapping thread's keyframes,
//! 3-D points and map candidates; SVO 1's map and point life cycle, docs/REFERENCES.md):
//! keyframes with their pyramids and features, Earth-fixed points with their keyframe
//! observations, and the bounded keyframe set.
//!
//! - Points are `Unknown` when created from a converged seed and matched in a keyframe,
//!   `Good` after more than [`GOOD_AFTER_SUCCESSES`] successful reprojections, `Candidate`
//!   while they have only the seed's reference observation. Unknown points are deleted after
//!   more than [`UNKNOWN_MAX_FAILURES`] failed reprojections, candidates after more than
//!   [`CANDIDATE_MAX_FAILURES`] failure units (3 per projection outside the image).
//! - Ordered maps keyed by increasing ids: iteration order, hence every result, is
//!   deterministic.

use std::collections::BTreeMap;
use std::sync::Arc;

use nalgebra::{Isometry3, Vector2, Vector3};

use super::camera::Camera;
use super::pyramid::Pyramid;

/// A point becomes `Good` after more than this many successful reprojections.
pub const GOOD_AFTER_SUCCESSES: u32 = 10;
/// An `Unknown` point is deleted after more than this many failed reprojections.
pub const UNKNOWN_MAX_FAILURES: u32 = 15;
/// A `Candidate` is deleted after more than this many failure units.
pub const CANDIDATE_MAX_FAILURES: u32 = 30;

/// Identifier of a keyframe (increasing).
pub type KeyframeId = u64;
/// Identifier of a map point (increasing).
pub type PointId = u64;

/// Life-cycle stage of a point, in matching priority order (best first).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum PointKind {
    /// Reprojected successfully many times.
    Good,
    /// Seen in at least two keyframes.
    Unknown,
    /// A converged seed seen only in its reference keyframe.
    Candidate,
}

/// A feature of a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeFeature {
    /// Level-0 pixel.
    pub px: Vector2<f64>,
    /// Pyramid level it was detected or matched at.
    pub level: u32,
    /// The point it observes.
    pub point: Option<PointId>,
}

/// A keyframe: its image, pose and features.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// Identifier.
    pub id: KeyframeId,
    /// Exposure time, µs.
    pub t_us: u64,
    /// Camera pose (camera → Earth).
    pub zeta_ec: Isometry3<f64>,
    /// The image.
    pub pyramid: Arc<Pyramid>,
    /// Features (detected or matched).
    pub features: Vec<KeyframeFeature>,
}

impl Keyframe {
    /// Camera centre, Earth-fixed, m.
    pub fn centre_e(&self) -> Vector3<f64> {
        self.zeta_ec.translation.vector
    }
}

/// One keyframe observation of a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Observation {
    /// The keyframe.
    pub keyframe: KeyframeId,
    /// Index of the feature in the keyframe's list.
    pub feature: usize,
}

/// A 3-D point of the terrain.
#[derive(Debug, Clone, PartialEq)]
pub struct MapPoint {
    /// Position, Earth-fixed, m.
    pub p_e: Vector3<f64>,
    /// Stage.
    pub kind: PointKind,
    /// Keyframe observations (the first is the reference of a candidate).
    pub observations: Vec<Observation>,
    /// Successful reprojections.
    pub successes: u32,
    /// Failure units (see the module doc).
    pub failures: u32,
    /// Frame counter at its last structure optimisation.
    pub last_structure_opt: u64,
}

/// Keyframes and points.
#[derive(Debug, Clone, Default)]
pub struct Map {
    keyframes: BTreeMap<KeyframeId, Keyframe>,
    points: BTreeMap<PointId, MapPoint>,
    next_keyframe: KeyframeId,
    next_point: PointId,
}

impl Map {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Drop everything (ids keep increasing).
    pub fn clear(&mut self) {
        self.keyframes.clear();
        self.points.clear();
    }

    /// Number of keyframes.
    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// Number of points (candidates included).
    pub fn n_points(&self) -> usize {
        self.points.len()
    }

    /// Keyframes, oldest first.
    pub fn keyframes(&self) -> impl Iterator<Item = &Keyframe> {
        self.keyframes.values()
    }

    /// One keyframe.
    pub fn keyframe(&self, id: KeyframeId) -> Option<&Keyframe> {
        self.keyframes.get(&id)
    }

    /// One keyframe, mutable.
    pub fn keyframe_mut(&mut self, id: KeyframeId) -> Option<&mut Keyframe> {
        self.keyframes.get_mut(&id)
    }

    /// The id the next keyframe will get.
    pub fn next_keyframe_id(&self) -> KeyframeId {
        self.next_keyframe
    }

    /// Insert a keyframe (its id is assigned here and returned).
    pub fn add_keyframe(&mut self, mut kf: Keyframe) -> KeyframeId {
        let id = self.next_keyframe;
        self.next_keyframe += 1;
        kf.id = id;
        self.keyframes.insert(id, kf);
        id
    }

    /// Points, by id.
    pub fn points(&self) -> impl Iterator<Item = (PointId, &MapPoint)> {
        self.points.iter().map(|(id, p)| (*id, p))
    }

    /// One point.
    pub fn point(&self, id: PointId) -> Option<&MapPoint> {
        self.points.get(&id)
    }

    /// One point, mutable.
    pub fn point_mut(&mut self, id: PointId) -> Option<&mut MapPoint> {
        self.points.get_mut(&id)
    }

    /// Insert a point observed by `observations` (each keyframe feature is linked to it).
    pub fn add_point(
        &mut self,
        p_e: Vector3<f64>,
        kind: PointKind,
        observations: Vec<Observation>,
    ) -> PointId {
        let id = self.next_point;
        self.next_point += 1;
        for o in &observations {
            if let Some(f) = self
                .keyframes
                .get_mut(&o.keyframe)
                .and_then(|kf| kf.features.get_mut(o.feature))
            {
                f.point = Some(id);
            }
        }
        self.points.insert(
            id,
            MapPoint {
                p_e,
                kind,
                observations,
                successes: 0,
                failures: 0,
                last_structure_opt: 0,
            },
        );
        id
    }

    /// Delete a point and unlink its keyframe features.
    pub fn remove_point(&mut self, id: PointId) {
        if let Some(p) = self.points.remove(&id) {
            for o in p.observations {
                if let Some(f) = self
                    .keyframes
                    .get_mut(&o.keyframe)
                    .and_then(|kf| kf.features.get_mut(o.feature))
                    && f.point == Some(id)
                {
                    f.point = None;
                }
            }
        }
    }

    /// Add a keyframe observation to a point (and link the feature).
    pub fn observe(&mut self, id: PointId, obs: Observation) {
        let Some(p) = self.points.get_mut(&id) else {
            return;
        };
        if p.observations.iter().any(|o| o.keyframe == obs.keyframe) {
            return;
        }
        p.observations.push(obs);
        if let Some(f) = self
            .keyframes
            .get_mut(&obs.keyframe)
            .and_then(|kf| kf.features.get_mut(obs.feature))
        {
            f.point = Some(id);
        }
    }

    /// Remove a keyframe: its observations go; a point left with fewer than two (or a
    /// candidate whose reference it was) is deleted.
    pub fn remove_keyframe(&mut self, id: KeyframeId) {
        let Some(kf) = self.keyframes.remove(&id) else {
            return;
        };
        for f in &kf.features {
            let Some(pid) = f.point else { continue };
            let delete = match self.points.get_mut(&pid) {
                Some(p) => {
                    let was_reference = p.observations.first().is_some_and(|o| o.keyframe == id);
                    p.observations.retain(|o| o.keyframe != id);
                    (p.kind == PointKind::Candidate && was_reference) || p.observations.len() < 2
                }
                None => false,
            };
            if delete {
                self.remove_point(pid);
            }
        }
    }

    /// The keyframe whose centre is furthest from `centre_e` (the one SVO drops when the map is
    /// full).
    pub fn furthest_keyframe(&self, centre_e: &Vector3<f64>) -> Option<KeyframeId> {
        self.keyframes
            .values()
            .map(|kf| (kf.id, (kf.centre_e() - centre_e).norm()))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(id, _)| id)
    }

    /// Keyframes that see any of their points inside the image from `zeta_ec`, closest first,
    /// at most `max` of them.
    pub fn overlapping_keyframes(
        &self,
        camera: &Camera,
        zeta_ec: &Isometry3<f64>,
        max: usize,
    ) -> Vec<KeyframeId> {
        let centre = zeta_ec.translation.vector;
        let mut close: Vec<(f64, KeyframeId)> = self
            .keyframes
            .values()
            .filter(|kf| {
                key_points(kf, self).any(|p_e| {
                    camera
                        .project_ecef(zeta_ec, &p_e)
                        .is_some_and(|px| camera.contains(&px, 0.0))
                })
            })
            .map(|kf| ((kf.centre_e() - centre).norm(), kf.id))
            .collect();
        close.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        close.truncate(max);
        close.into_iter().map(|(_, id)| id).collect()
    }
}

/// SVO's overlap test points of a keyframe: its point nearest the image centre and the most
/// extreme one in each quadrant.
fn key_points<'a>(kf: &'a Keyframe, map: &'a Map) -> impl Iterator<Item = Vector3<f64>> + 'a {
    let centre = kf
        .features
        .first()
        .map(|_| {
            let (w, h) = kf
                .pyramid
                .level(0)
                .map_or((0, 0), |img| (img.width(), img.height()));
            Vector2::new(0.5 * f64::from(w) - 0.5, 0.5 * f64::from(h) - 0.5)
        })
        .unwrap_or_else(Vector2::zeros);
    // Best per slot: 0 centre (smallest distance), 1–4 quadrants (largest distance).
    let mut best: [Option<(f64, PointId)>; 5] = [None; 5];
    for f in &kf.features {
        let Some(pid) = f.point else { continue };
        if !map.points.contains_key(&pid) {
            continue;
        }
        let d = f.px - centre;
        let dist = d.norm();
        if best[0].is_none_or(|(b, _)| dist < b) {
            best[0] = Some((dist, pid));
        }
        let q = 1 + usize::from(d.x >= 0.0) + 2 * usize::from(d.y >= 0.0);
        if best[q].is_none_or(|(b, _)| dist > b) {
            best[q] = Some((dist, pid));
        }
    }
    best.into_iter()
        .flatten()
        .filter_map(move |(_, pid)| map.points.get(&pid).map(|p| p.p_e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::test_scene::{Ground, camera, nadir_pose};

    fn keyframe(map: &Map, x_m: f64, n: usize) -> Keyframe {
        let cam = camera(96, 128);
        let pose = nadir_pose(x_m, 0.0, 1_000.0, [0.0; 3]);
        let ground = Ground {
            seed: 1,
            ground_z_m: 0.0,
        };
        Keyframe {
            id: map.next_keyframe_id(),
            t_us: 0,
            zeta_ec: pose,
            pyramid: Arc::new(ground.pyramid(&cam, &pose)),
            features: (0..n)
                .map(|i| KeyframeFeature {
                    px: Vector2::new(10.0 + 7.0 * i as f64, 20.0 + 9.0 * i as f64),
                    level: 0,
                    point: None,
                })
                .collect(),
        }
    }

    #[test]
    fn removing_a_keyframe_drops_points_left_with_one_observation() {
        let mut map = Map::new();
        let a = map.add_keyframe(keyframe(&map, 0.0, 3));
        let b = map.add_keyframe(keyframe(&map, 50.0, 3));
        let both = map.add_point(
            Vector3::new(1.0, 2.0, 0.0),
            PointKind::Unknown,
            vec![
                Observation {
                    keyframe: a,
                    feature: 0,
                },
                Observation {
                    keyframe: b,
                    feature: 0,
                },
            ],
        );
        let three = map.add_point(Vector3::zeros(), PointKind::Unknown, vec![]);
        let c = map.add_keyframe(keyframe(&map, 100.0, 3));
        for kf in [a, b, c] {
            map.observe(
                three,
                Observation {
                    keyframe: kf,
                    feature: 1,
                },
            );
        }
        let candidate = map.add_point(
            Vector3::zeros(),
            PointKind::Candidate,
            vec![Observation {
                keyframe: b,
                feature: 2,
            }],
        );
        assert_eq!(map.keyframe(b).unwrap().features[2].point, Some(candidate));
        map.remove_keyframe(a);
        // `both` fell to one observation; `three` keeps two; the candidate's reference stays.
        assert!(map.point(both).is_none());
        assert_eq!(map.keyframe(b).unwrap().features[0].point, None);
        assert_eq!(map.point(three).unwrap().observations.len(), 2);
        assert!(map.point(candidate).is_some());
        map.remove_keyframe(b);
        assert!(map.point(candidate).is_none());
        assert!(map.point(three).is_none());
        assert_eq!(map.n_points(), 0);
        assert_eq!(map.furthest_keyframe(&Vector3::zeros()), Some(c));
    }
}
