//! Navigation solution → MAVLink messages for the autopilot (common.xml ODOMETRY #331, GPS_INPUT
//! #232, VISION_POSITION_ESTIMATE #102, SET_GPS_GLOBAL_ORIGIN #48, HEARTBEAT, STATUSTEXT,
//! COMMAND_LONG; docs/REFERENCES.md M2). Pure builders.
//!
//! - Local positions use the autopilots' own projection ([`MapProjection`], azimuthal
//!   equidistant on the 6,371 km sphere) about the origin announced by SET_GPS_GLOBAL_ORIGIN.
//! - Pose covariance (ODOMETRY `pose_covariance`, VISION_POSITION_ESTIMATE `covariance`): the
//!   row-major upper triangle of the 6×6 covariance of `[x, y, z, roll, pitch, yaw]`. The INS
//!   reports the attitude error as a body-axis rotation vector δθ; the Euler-angle covariance is
//!   `E P Eᵀ` with `E` the body-rate → Euler-rate matrix (first order). Position and attitude
//!   are taken as uncorrelated (the INS cascade keeps them in separate filters).
//! - ODOMETRY velocity is in the child frame (body FRD): `v_b = R_bn v_n`, covariance
//!   `R_bn P_v R_bnᵀ` (the attitude uncertainty's share is neglected: 0.1° on 30 m/s is
//!   0.05 m/s); the angular-rate block is the INS body-rate covariance.
//! - Accuracies for GPS_INPUT: horizontal = √(P_nn + P_ee) (DRMS), vertical = √P_dd, speed =
//!   √trace(P_v); HDOP/VDOP = accuracy / [`crate::io::mavlink_in::UERE_M`].
//! - ODOMETRY `quality` = 100 − σ_h (m), clamped to [1, 100] (σ_h = horizontal DRMS): 0 and −1
//!   are never sent (an invalid estimate is not published at all).

use nalgebra::{Matrix3, SMatrix};

use crate::io::mavlink_in::UERE_M;
use crate::math::map_projection::MapProjection;
use crate::math::so3;
use crate::math::wgs84::Geodetic;
use crate::nav::NavSolution;
use mavlink::dialects::ardupilotmega as apm;

/// Seconds between the Unix epoch and the GPS epoch (1980-01-06).
pub const GPS_EPOCH_UNIX_S: u64 = 315_964_800;
/// Seconds per GPS week.
pub const WEEK_S: u64 = 604_800;
/// STATUSTEXT text capacity, bytes.
pub const STATUSTEXT_LEN: usize = 50;

/// Row-major upper triangle of a 6×6 matrix (21 values).
pub fn upper_triangle(m: &SMatrix<f64, 6, 6>) -> [f32; 21] {
    let mut out = [0.0_f32; 21];
    let mut k = 0;
    for i in 0..6 {
        for j in i..6 {
            out[k] = m[(i, j)] as f32;
            k += 1;
        }
    }
    out
}

/// Body-rate → Euler-rate matrix for `[roll, pitch, yaw]` at the given bank and pitch.
fn euler_rate_matrix(bank: f64, pitch: f64) -> Matrix3<f64> {
    let (sb, cb) = bank.sin_cos();
    // Keep away from the singularity at ±90° pitch.
    let cp = pitch.cos().abs().max(1e-3).copysign(pitch.cos());
    let tp = pitch.sin() / cp;
    Matrix3::new(1.0, sb * tp, cb * tp, 0.0, cb, -sb, 0.0, sb / cp, cb / cp)
}

/// Covariance of `[x, y, z, roll, pitch, yaw]` (NED m, rad).
pub fn pose_covariance(sol: &NavSolution) -> SMatrix<f64, 6, 6> {
    let e = so3::euler_zyx(&sol.q_nb);
    let jac = euler_rate_matrix(e.z, e.y);
    let att = jac * sol.cov.attitude_rad2 * jac.transpose();
    let mut p = SMatrix::<f64, 6, 6>::zeros();
    p.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&sol.cov.position_m2);
    p.fixed_view_mut::<3, 3>(3, 3).copy_from(&att);
    p
}

/// Horizontal DRMS, vertical σ and speed σ of a solution.
pub fn accuracies(sol: &NavSolution) -> (f64, f64, f64) {
    let p = &sol.cov.position_m2;
    let v = &sol.cov.velocity_m2ps2;
    let nonneg = |x: f64| {
        if x.is_finite() {
            x.max(0.0)
        } else {
            f64::INFINITY
        }
    };
    (
        nonneg(p[(0, 0)] + p[(1, 1)]).sqrt(),
        nonneg(p[(2, 2)]).sqrt(),
        nonneg(v.trace()).sqrt(),
    )
}

/// ODOMETRY quality in [1, 100] from the horizontal DRMS.
pub fn quality(sigma_h_m: f64) -> i8 {
    if !sigma_h_m.is_finite() {
        return 1;
    }
    (100.0 - sigma_h_m).round().clamp(1.0, 100.0) as i8
}

/// ODOMETRY in the local NED frame about `proj`'s origin, child frame body FRD, stamped
/// `time_usec` (the daemon's clock).
pub fn odometry(sol: &NavSolution, proj: &MapProjection, time_usec: u64) -> apm::ODOMETRY_DATA {
    let ins = &sol.ins;
    let [x, y, z] = proj.project(&sol.pos);
    let r_bn = sol.q_nb.inverse().to_rotation_matrix();
    let v_b = r_bn * sol.v_ned_mps;
    let mut vel = SMatrix::<f64, 6, 6>::zeros();
    vel.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(r_bn.matrix() * sol.cov.velocity_m2ps2 * r_bn.matrix().transpose()));
    vel.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&ins.cov.w_nb_b_rad2ps2);
    let q = sol.q_nb.quaternion();
    let (sigma_h, _, _) = accuracies(sol);
    apm::ODOMETRY_DATA {
        time_usec,
        frame_id: apm::MavFrame::MAV_FRAME_LOCAL_NED,
        child_frame_id: apm::MavFrame::MAV_FRAME_BODY_FRD,
        x: x as f32,
        y: y as f32,
        z: z as f32,
        q: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
        vx: v_b.x as f32,
        vy: v_b.y as f32,
        vz: v_b.z as f32,
        rollspeed: ins.w_nb_b_rps.x as f32,
        pitchspeed: ins.w_nb_b_rps.y as f32,
        yawspeed: ins.w_nb_b_rps.z as f32,
        pose_covariance: upper_triangle(&pose_covariance(sol)),
        velocity_covariance: upper_triangle(&vel),
        reset_counter: sol.reset_counter,
        estimator_type: apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
        quality: quality(sigma_h),
    }
}

/// VISION_POSITION_ESTIMATE in the local NED frame about `proj`'s origin.
pub fn vision_position_estimate(
    sol: &NavSolution,
    proj: &MapProjection,
    usec: u64,
) -> apm::VISION_POSITION_ESTIMATE_DATA {
    let [x, y, z] = proj.project(&sol.pos);
    let e = so3::euler_zyx(&sol.q_nb);
    apm::VISION_POSITION_ESTIMATE_DATA {
        usec,
        x: x as f32,
        y: y as f32,
        z: z as f32,
        roll: e.z as f32,
        pitch: e.y as f32,
        yaw: e.x as f32,
        covariance: upper_triangle(&pose_covariance(sol)),
        reset_counter: sol.reset_counter,
    }
}

/// GPS week and milliseconds of week from Unix time (µs) and the GPS − UTC leap seconds.
pub fn gps_week(unix_us: u64, leap_s: u8) -> (u16, u32) {
    let gps_us = unix_us
        .saturating_sub(GPS_EPOCH_UNIX_S * 1_000_000)
        .saturating_add(u64::from(leap_s) * 1_000_000);
    let week = gps_us / (WEEK_S * 1_000_000);
    let ms = (gps_us % (WEEK_S * 1_000_000)) / 1_000;
    (
        u16::try_from(week).unwrap_or(u16::MAX),
        u32::try_from(ms).unwrap_or(u32::MAX),
    )
}

/// Settings of GPS_INPUT.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsInputSettings {
    /// GPS instance (0 = GPS1).
    pub gps_id: u8,
    /// Reported satellites.
    pub satellites_visible: u8,
    /// GPS − UTC leap seconds.
    pub leap_s: u8,
    /// Geoid undulation N (ellipsoid − MSL), m; MSL altitude = h − N.
    pub undulation_m: f64,
}

/// GPS_INPUT stamped `time_usec` (the daemon's clock) at Unix time `unix_us`.
pub fn gps_input(
    sol: &NavSolution,
    s: &GpsInputSettings,
    time_usec: u64,
    unix_us: u64,
) -> apm::GPS_INPUT_DATA {
    let (week, week_ms) = gps_week(unix_us, s.leap_s);
    let (h_acc, v_acc, s_acc) = accuracies(sol);
    let dop = |acc: f64| (acc / UERE_M).clamp(0.01, 99.0) as f32;
    let deg_e7 = |rad: f64| (rad.to_degrees() * 1e7).round() as i32;
    apm::GPS_INPUT_DATA {
        time_usec,
        gps_id: s.gps_id,
        ignore_flags: apm::GpsInputIgnoreFlags::empty(),
        time_week_ms: week_ms,
        time_week: week,
        fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
        lat: deg_e7(sol.pos.lat_rad),
        lon: deg_e7(sol.pos.lon_rad),
        alt: (sol.pos.h_m - s.undulation_m) as f32,
        hdop: dop(h_acc),
        vdop: dop(v_acc),
        vn: sol.v_ned_mps.x as f32,
        ve: sol.v_ned_mps.y as f32,
        vd: sol.v_ned_mps.z as f32,
        speed_accuracy: s_acc as f32,
        horiz_accuracy: h_acc as f32,
        vert_accuracy: v_acc as f32,
        satellites_visible: s.satellites_visible,
        // 0 = yaw not provided (36000 would mean north).
        yaw: 0,
    }
}

/// SET_GPS_GLOBAL_ORIGIN at `origin`. The message is deprecated in favour of
/// MAV_CMD_DO_SET_GLOBAL_ORIGIN (2025-04), but it is the one PX4 and ArduPilot releases in the
/// field handle (docs/REFERENCES.md M2.1–M2.3). The height is ellipsoidal, sent as MSL with N.
#[expect(
    deprecated,
    reason = "SET_GPS_GLOBAL_ORIGIN, deprecated in favour of MAV_CMD_DO_SET_GLOBAL_ORIGIN but \
              what PX4 and ArduPilot releases in the field handle"
)]
pub fn set_gps_global_origin(
    target_system: u8,
    origin: &Geodetic,
    undulation_m: f64,
    time_usec: u64,
) -> apm::SET_GPS_GLOBAL_ORIGIN_DATA {
    apm::SET_GPS_GLOBAL_ORIGIN_DATA {
        target_system,
        latitude: (origin.lat_rad.to_degrees() * 1e7).round() as i32,
        longitude: (origin.lon_rad.to_degrees() * 1e7).round() as i32,
        altitude: ((origin.h_m - undulation_m) * 1e3).round() as i32,
        time_usec,
    }
}

/// Health reported in our HEARTBEAT.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Health {
    /// Waiting for the INS initialisation.
    Standby,
    /// Publishing.
    Active,
    /// Publishing without GNSS (the position drifts) or with inputs missing.
    Critical,
}

/// Our HEARTBEAT: an onboard controller, not an autopilot.
pub fn heartbeat(health: Health) -> apm::HEARTBEAT_DATA {
    apm::HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: apm::MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: apm::MavModeFlag::empty(),
        system_status: match health {
            Health::Standby => apm::MavState::MAV_STATE_STANDBY,
            Health::Active => apm::MavState::MAV_STATE_ACTIVE,
            Health::Critical => apm::MavState::MAV_STATE_CRITICAL,
        },
        mavlink_version: 3,
    }
}

/// STATUSTEXT, cut to 50 bytes on a character boundary.
pub fn statustext(severity: apm::MavSeverity, text: &str) -> apm::STATUSTEXT_DATA {
    let mut end = text.len().min(STATUSTEXT_LEN);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let mut bytes = [0_u8; STATUSTEXT_LEN];
    bytes[..end].copy_from_slice(&text.as_bytes()[..end]);
    apm::STATUSTEXT_DATA {
        severity,
        text: bytes.into(),
        id: 0,
        chunk_seq: 0,
    }
}

/// MAV_CMD_SET_MESSAGE_INTERVAL for message `msg_id` at `rate_hz` (≤ 0: stop the stream).
pub fn set_message_interval(
    target_system: u8,
    target_component: u8,
    msg_id: u32,
    rate_hz: f64,
) -> apm::COMMAND_LONG_DATA {
    let interval_us = if rate_hz > 0.0 {
        (1e6 / rate_hz).round() as f32
    } else {
        -1.0
    };
    apm::COMMAND_LONG_DATA {
        target_system,
        target_component,
        command: apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        confirmation: 0,
        param1: msg_id as f32,
        param2: interval_us,
        param3: 0.0,
        param4: 0.0,
        param5: 0.0,
        param6: 0.0,
        param7: 0.0,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    pub(crate) fn solution() -> NavSolution {
        crate::nav::solution::fixtures::solution()
    }

    #[test]
    fn upper_triangle_is_row_major() {
        let m = SMatrix::<f64, 6, 6>::from_fn(|i, j| (10 * i + j) as f64);
        let u = upper_triangle(&m);
        assert_eq!(&u[..7], &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 11.0]);
        assert_eq!((u[11], u[15], u[18], u[20]), (22.0, 33.0, 44.0, 55.0));
    }

    #[test]
    fn odometry_fields_frames_and_covariances() {
        let sol = solution();
        // Origin 1 km south of the vehicle, same height + 100 m.
        let mut origin = sol.ins.pos;
        origin.lat_rad -= 1_000.0 / crate::math::map_projection::EARTH_RADIUS_M;
        origin.h_m = 600.0;
        let proj = MapProjection::new(&origin);
        let o = odometry(&sol, &proj, 42);
        assert_eq!(o.time_usec, 42);
        assert_eq!(o.frame_id, apm::MavFrame::MAV_FRAME_LOCAL_NED);
        assert_eq!(o.child_frame_id, apm::MavFrame::MAV_FRAME_BODY_FRD);
        assert_eq!(
            o.estimator_type,
            apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO
        );
        assert!((o.x - 1_000.0).abs() < 1e-3 && o.y.abs() < 1e-3);
        assert!((o.z - 100.0).abs() < 1e-4, "100 m below the origin");
        // Yaw 90°: q = (cos 45°, 0, 0, sin 45°); flying east at 30 m/s = forward 30 m/s.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        assert!((o.q[0] - h).abs() < 1e-6 && (o.q[3] - h).abs() < 1e-6);
        assert!((o.vx - 30.0).abs() < 1e-4 && o.vy.abs() < 1e-4 && (o.vz + 1.0).abs() < 1e-4);
        assert_eq!(o.pose_covariance[0], 9.0);
        assert_eq!(o.pose_covariance[6], 16.0);
        assert_eq!(o.pose_covariance[11], 4.0);
        // Level flight: Euler covariance = body covariance.
        assert!((o.pose_covariance[15] - 1e-4).abs() < 1e-10);
        assert!((o.pose_covariance[20] - 9e-4).abs() < 1e-10);
        // Velocity rotated into the body: east variance 0.09 becomes forward.
        assert!((o.velocity_covariance[0] - 0.09).abs() < 1e-7);
        assert!((o.velocity_covariance[6] - 0.04).abs() < 1e-7);
        assert!((o.velocity_covariance[20] - 3e-6).abs() < 1e-10);
        assert_eq!(o.reset_counter, 3);
        // σ_h = √(9 + 16) = 5 m → quality 95.
        assert_eq!(o.quality, 95);
        assert_eq!(
            (quality(0.2), quality(500.0), quality(f64::NAN)),
            (100, 1, 1)
        );
    }

    #[test]
    fn banked_attitude_maps_through_the_euler_jacobian() {
        // At bank 90°, a body-y (pitch) rotation error is a yaw error in Euler angles.
        let mut sol = solution();
        sol.q_nb = UnitQuaternion::from_euler_angles(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        let p = pose_covariance(&sol);
        assert!((p[(4, 4)] - 9e-4).abs() < 1e-9, "pitch gets body-z");
        assert!((p[(5, 5)] - 4e-4).abs() < 1e-9, "yaw gets body-y");
    }

    #[test]
    fn gps_week_of_known_dates() {
        // GPS epoch itself: week 0, 0 ms (with zero leap seconds).
        assert_eq!(gps_week(GPS_EPOCH_UNIX_S * 1_000_000, 0), (0, 0));
        // 2017-01-01T00:00:00Z = Unix 1483228800: GPS week 1930, Sunday 00:00:18 with 18 leap s.
        assert_eq!(gps_week(1_483_228_800_000_000, 18), (1930, 18_000));
    }

    #[test]
    fn gps_input_fields() {
        let sol = solution();
        let s = GpsInputSettings {
            gps_id: 1,
            satellites_visible: 10,
            leap_s: 18,
            undulation_m: -34.0,
        };
        let g = gps_input(&sol, &s, 7, 1_483_228_800_000_000);
        assert_eq!((g.gps_id, g.time_week, g.time_week_ms), (1, 1930, 18_000));
        assert_eq!(g.fix_type, apm::GpsFixType::GPS_FIX_TYPE_3D_FIX);
        assert_eq!((g.lat, g.lon), (450_000_000, -750_000_000));
        assert_eq!(g.alt, 534.0);
        assert_eq!((g.vn, g.ve, g.vd), (0.0, 30.0, -1.0));
        assert_eq!((g.horiz_accuracy, g.vert_accuracy), (5.0, 2.0));
        assert!((g.speed_accuracy - 0.29_f32.sqrt()).abs() < 1e-6);
        assert!((g.hdop - 5.0 / 3.0).abs() < 1e-6);
        assert_eq!((g.satellites_visible, g.yaw), (10, 0));
        assert!(g.ignore_flags.is_empty());
    }

    #[test]
    fn statustext_is_cut_on_a_character_boundary() {
        let t = statustext(apm::MavSeverity::MAV_SEVERITY_WARNING, "GNSS lost");
        assert_eq!(&t.text[..10], b"GNSS lost\0");
        let long = format!("a{}", "é".repeat(40)); // 81 bytes
        let t = statustext(apm::MavSeverity::MAV_SEVERITY_INFO, &long);
        assert_eq!(t.text[49], 0, "the 26th é would straddle byte 50");
        assert_eq!(t.text[48], 0xa9);
    }

    #[test]
    #[expect(
        deprecated,
        reason = "checks the SET_GPS_GLOBAL_ORIGIN the daemon sends"
    )]
    fn command_and_origin_and_heartbeat() {
        let c = set_message_interval(1, 1, 105, 50.0);
        assert_eq!((c.param1, c.param2), (105.0, 20_000.0));
        assert_eq!(c.command, apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL);
        assert_eq!(set_message_interval(1, 1, 105, 0.0).param2, -1.0);
        let o = set_gps_global_origin(
            1,
            &Geodetic {
                lat_rad: 0.5_f64.to_radians(),
                lon_rad: 10.0_f64.to_radians(),
                h_m: 66.0,
            },
            -34.0,
            0,
        );
        assert_eq!(
            (o.latitude, o.longitude, o.altitude),
            (5_000_000, 100_000_000, 100_000)
        );
        let h = heartbeat(Health::Standby);
        assert_eq!(h.mavtype, apm::MavType::MAV_TYPE_ONBOARD_CONTROLLER);
        assert_eq!(h.autopilot, apm::MavAutopilot::MAV_AUTOPILOT_INVALID);
        assert_eq!(h.system_status, apm::MavState::MAV_STATE_STANDBY);
    }
}
