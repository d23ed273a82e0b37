//! The fused navigation solution (paper, "IA-VNS flow diagram": the output `x̂` of the
//! navigation system): position, velocity and attitude with their covariances, where the
//! horizontal position comes from, one status record per aid, and the reset counter. The
//! INS solution it was built from stays available as detail.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::ins::InsSolution;
use crate::math::wgs84::Geodetic;

/// Which estimator the fused horizontal position comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PositionSource {
    /// The inertial navigation (GNSS-aided until the loss, dead reckoning after it).
    Ins,
}

/// What the visual navigation contributes to a solution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VisionStatus {
    /// No visual navigation (frames are counted and dropped).
    Inactive,
}

/// State of the INS behind a solution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InsStatus {
    /// GNSS-denied: latched at the loss until the navigator re-initialises the INS.
    pub gnss_denied: bool,
    /// The step bridged an IMU gap (propagated in sub-steps).
    pub imu_gap: bool,
}

/// Covariances of the fused solution (tangent spaces as in [`crate::ins::InsCovariance`]:
/// position north-east-down in metres, velocity NED, attitude the right perturbation of
/// `q_nb` in body axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavCovariance {
    /// Position, NED, m².
    pub position_m2: Matrix3<f64>,
    /// Velocity, NED, m²/s².
    pub velocity_m2ps2: Matrix3<f64>,
    /// Attitude, rad².
    pub attitude_rad2: Matrix3<f64>,
}

/// One fused solution, produced at every accepted IMU sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavSolution {
    /// Time of validity (the IMU sample's), µs.
    pub t_us: u64,
    /// Geodetic position (WGS84).
    pub pos: Geodetic,
    /// NED ground velocity, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Attitude, body to NED.
    pub q_nb: UnitQuaternion<f64>,
    /// Covariances of position, velocity and attitude.
    pub cov: NavCovariance,
    /// Where the horizontal position comes from.
    pub horizontal_source: PositionSource,
    /// The INS.
    pub ins_status: InsStatus,
    /// The visual navigation.
    pub vision: VisionStatus,
    /// Incremented at every re-initialisation: consumers must not difference positions across
    /// a change (MAVLink `reset_counter`).
    pub reset_counter: u8,
    /// The INS solution the fused one was built from (air data, wind, sensor errors, …).
    pub ins: InsSolution,
}

impl NavSolution {
    /// The fused solution while the INS is the only estimator.
    pub fn from_ins(ins: InsSolution, reset_counter: u8) -> Self {
        Self {
            t_us: ins.t_us,
            pos: ins.pos,
            v_ned_mps: ins.v_ned_mps,
            q_nb: ins.q_nb,
            cov: NavCovariance {
                position_m2: ins.cov.position_m2,
                velocity_m2ps2: ins.cov.velocity_m2ps2,
                attitude_rad2: ins.cov.attitude_rad2,
            },
            horizontal_source: PositionSource::Ins,
            ins_status: InsStatus {
                gnss_denied: ins.gnss_denied,
                imu_gap: ins.imu_gap,
            },
            vision: VisionStatus::Inactive,
            reset_counter,
            ins,
        }
    }
}
