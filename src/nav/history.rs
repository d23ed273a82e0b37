//! A short history of the INS pose (paper, "IA-VNS": the inertial priors pull the visual pose
//! optimisation of an image towards the INS attitude and altitude *at the instant the image
//! was taken*). Frames reach the navigation tens of milliseconds after their exposure, when
//! the INS has moved on by several IMU steps: the pose at the exposure is interpolated between
//! the two solutions around it (linear in position and velocity, spherical in attitude, over
//! one IMU period).

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};

use crate::math::wgs84::Geodetic;

/// The INS pose at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HistoryPose {
    /// Time, µs.
    pub t_us: u64,
    /// Geodetic position.
    pub pos: Geodetic,
    /// NED ground velocity, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Attitude, body to NED.
    pub q_nb: UnitQuaternion<f64>,
}

/// The poses of the last `span_us`, oldest first.
#[derive(Debug, Clone)]
pub struct PoseHistory {
    span_us: u64,
    poses: VecDeque<HistoryPose>,
}

impl PoseHistory {
    /// An empty history keeping `span_us` of poses.
    pub fn new(span_us: u64) -> Self {
        Self {
            span_us,
            poses: VecDeque::new(),
        }
    }

    /// Add the newest pose; forget those older than the span. A pose not after the newest
    /// (a restarted clock) starts the history over.
    pub fn push(&mut self, pose: HistoryPose) {
        if self.poses.back().is_some_and(|p| p.t_us >= pose.t_us) {
            self.poses.clear();
        }
        self.poses.push_back(pose);
        while self
            .poses
            .front()
            .is_some_and(|p| pose.t_us - p.t_us > self.span_us)
        {
            self.poses.pop_front();
        }
    }

    /// Forget every pose (a new INS).
    pub fn clear(&mut self) {
        self.poses.clear();
    }

    /// Time of the newest pose, µs.
    pub fn newest_t_us(&self) -> Option<u64> {
        self.poses.back().map(|p| p.t_us)
    }

    /// The pose at `t_us`, interpolated between the poses around it; `None` outside the
    /// history.
    pub fn at(&self, t_us: u64) -> Option<HistoryPose> {
        let after = self.poses.partition_point(|p| p.t_us < t_us);
        let b = self.poses.get(after)?;
        if b.t_us == t_us {
            return Some(*b);
        }
        let a = self.poses.get(after.checked_sub(1)?)?;
        let s = (t_us - a.t_us) as f64 / (b.t_us - a.t_us) as f64;
        let lerp = |x: f64, y: f64| x + (y - x) * s;
        Some(HistoryPose {
            t_us,
            pos: Geodetic {
                lat_rad: lerp(a.pos.lat_rad, b.pos.lat_rad),
                lon_rad: lerp(a.pos.lon_rad, b.pos.lon_rad),
                h_m: lerp(a.pos.h_m, b.pos.h_m),
            },
            v_ned_mps: a.v_ned_mps.lerp(&b.v_ned_mps, s),
            q_nb: a.q_nb.slerp(&b.q_nb, s),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(t_us: u64) -> HistoryPose {
        let t_s = t_us as f64 * 1e-6;
        HistoryPose {
            t_us,
            pos: Geodetic {
                lat_rad: 0.7 + 1e-6 * t_s,
                lon_rad: -1.5,
                h_m: 1_000.0 + 2.0 * t_s,
            },
            v_ned_mps: Vector3::new(30.0, 0.0, -2.0 * t_s),
            // A steady 0.1 rad/s yaw rate.
            q_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1 * t_s),
        }
    }

    #[test]
    fn poses_between_samples_are_interpolated_and_old_ones_forgotten() {
        let mut h = PoseHistory::new(2_000_000);
        for k in 0..=300 {
            h.push(pose(k * 10_000));
        }
        // 3 s of poses at 100 Hz, 2 s kept.
        assert!(h.at(900_000).is_none());
        assert_eq!(h.at(1_000_000), Some(pose(1_000_000)));
        assert!(h.at(3_000_001).is_none());
        // Midway between two samples: the motion's own value (linear here) within rounding.
        let p = h.at(2_345_678).unwrap();
        let e = pose(2_345_678);
        assert!((p.pos.h_m - e.pos.h_m).abs() < 1e-9);
        assert!((p.pos.lat_rad - e.pos.lat_rad).abs() < 1e-15);
        assert!((p.v_ned_mps - e.v_ned_mps).norm() < 1e-9);
        assert!(p.q_nb.angle_to(&e.q_nb) < 1e-12);
        assert_eq!(h.newest_t_us(), Some(3_000_000));
        // A restarted clock starts over.
        h.push(pose(5_000));
        assert_eq!((h.newest_t_us(), h.at(2_000_000)), (Some(5_000), None));
    }
}
