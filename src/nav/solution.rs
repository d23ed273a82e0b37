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
    /// The inertial navigation (GNSS-aided until the loss, dead reckoning after it; with a
    /// camera, dead reckoning from the last visual position once fixes stop).
    Ins,
    /// The visual navigation's latest fix, carried to the solution's time by the INS
    /// ([`super::fusion`]).
    Vision,
}

/// State of the visual navigation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VisionState {
    /// No visual navigation (no camera; frames are counted and dropped).
    Inactive,
    /// Waiting for a first image with an initial estimate (INS pose and height over the
    /// terrain at its time).
    WaitingForStart,
    /// Tracking the first image's features until the two-view initialisation succeeds.
    Initialising,
    /// Tracking.
    Tracking,
    /// Tracking lost: relocalising against the closest keyframe.
    Relocalising,
}

/// The visual navigation's state and the quality of its latest frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionStatus {
    /// State.
    pub state: VisionState,
    /// Features matched in the latest frame.
    pub n_matched: u32,
    /// Inliers of its pose optimisation.
    pub n_inliers: u32,
    /// Keyframes in the map.
    pub n_keyframes: u32,
    /// Points in the map (candidates included).
    pub n_points: u32,
    /// RMS reprojection error of the inliers, px (`None` when not tracking).
    pub reprojection_rms_px: Option<f64>,
}

impl VisionStatus {
    /// No visual navigation.
    pub const INACTIVE: Self = Self {
        state: VisionState::Inactive,
        n_matched: 0,
        n_inliers: 0,
        n_keyframes: 0,
        n_points: 0,
        reprojection_rms_px: None,
    };
}

/// The visual navigation's body pose at a frame (paper: `zeta_eb = zeta_ec ⊗ zeta_bc*`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionFix {
    /// The frame's exposure time, µs.
    pub t_us: u64,
    /// Geodetic position of the body origin.
    pub pos: Geodetic,
    /// Attitude, body to NED.
    pub q_nb: UnitQuaternion<f64>,
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
    /// The visual navigation's latest pose (while it tracks).
    pub vision_fix: Option<VisionFix>,
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
            vision: VisionStatus::INACTIVE,
            vision_fix: None,
            reset_counter,
            ins,
        }
    }
}

/// A solution to test consumers with.
#[cfg(test)]
pub(crate) mod fixtures {
    use super::*;
    use crate::ins::InsCovariance;
    use crate::math::so3;
    use nalgebra::SMatrix;

    /// A level solution heading east at 30 m/s, reset counter 3, with distinct variances.
    pub(crate) fn solution() -> NavSolution {
        let pos = Geodetic {
            lat_rad: 45.0_f64.to_radians(),
            lon_rad: -75.0_f64.to_radians(),
            h_m: 500.0,
        };
        let z3 = Matrix3::zeros();
        NavSolution::from_ins(
            InsSolution {
                t_us: 1_000_000,
                dt_s: 0.01,
                imu_gap: false,
                pos,
                v_ned_mps: Vector3::new(0.0, 30.0, -1.0),
                // Heading east (yaw 90°), level.
                q_nb: so3::from_euler_zyx(std::f64::consts::FRAC_PI_2, 0.0, 0.0),
                w_nb_b_rps: Vector3::new(0.01, 0.02, 0.03),
                hp_m: 500.0,
                roc_mps: 1.0,
                tas_mps: 30.0,
                aoa_rad: 0.05,
                aos_rad: 0.0,
                temp_k: 285.0,
                delta_t_k: 0.0,
                delta_p_pa: 0.0,
                wind_ned_mps: Vector3::zeros(),
                f_ib_b_mps2: Vector3::zeros(),
                e_gyr_rps: Vector3::zeros(),
                e_acc_mps2: Vector3::zeros(),
                e_mag_nt: Vector3::zeros(),
                delta_b_n_nt: Vector3::zeros(),
                ref_attitude_err_rad: Vector3::zeros(),
                gnss_denied: false,
                gnss_nis: None,
                cov: InsCovariance {
                    attitude_rad2: Matrix3::from_diagonal(&Vector3::new(1e-4, 4e-4, 9e-4)),
                    w_nb_b_rad2ps2: Matrix3::from_diagonal(&Vector3::new(1e-6, 2e-6, 3e-6)),
                    e_gyr_rad2ps2: z3,
                    velocity_m2ps2: Matrix3::from_diagonal(&Vector3::new(0.04, 0.09, 0.16)),
                    position_m2: Matrix3::from_diagonal(&Vector3::new(9.0, 16.0, 4.0)),
                    wind_m2ps2: z3,
                    air_data: SMatrix::zeros(),
                    delta_t_k2: 0.0,
                    delta_p_pa2: 0.0,
                },
            },
            3,
        )
    }
}
