//! Input checks of the INS (docs/INS.md "Input limits"): a sample is used only if it is
//! finite, physically possible (`InputLimits`) and strictly later than the previous accepted
//! one of its kind; the rest are counted.

use super::*;

/// Count and filter a sample: valid and strictly after the previous accepted one of its kind.
pub(super) fn accept(
    counters: &mut SensorCounters,
    last_us: &mut Option<u64>,
    t_us: u64,
    valid: bool,
) -> bool {
    if !valid {
        counters.rejected_invalid += 1;
        return false;
    }
    if last_us.is_some_and(|last| t_us <= last) {
        counters.rejected_time += 1;
        return false;
    }
    *last_us = Some(t_us);
    counters.accepted += 1;
    true
}

pub(super) fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

pub(super) fn valid_imu(l: &InputLimits, s: &ImuSample) -> bool {
    finite3(&s.gyro_rps)
        && finite3(&s.accel_mps2)
        && s.accel_mps2.norm() <= l.max_specific_force_mps2
        && s.gyro_rps.norm() <= l.max_angular_rate_rps
}

pub(super) fn valid_air(l: &InputLimits, s: &AirSample) -> bool {
    let vane_ok = |a: Option<f64>| {
        a.is_none_or(|a| a.is_finite() && a.abs() <= l.max_vane_angle_deg.to_radians())
    };
    s.tas_mps.is_finite()
        && s.tas_mps >= 0.0
        && s.tas_mps <= l.max_tas_mps
        && s.p_pa.is_finite()
        && s.p_pa > 0.0
        && s.p_pa <= l.max_pressure_pa
        && s.temp_k.is_finite()
        && s.temp_k >= l.min_temp_k
        && s.temp_k <= l.max_temp_k
        && vane_ok(s.aoa_rad)
        && vane_ok(s.aos_rad)
}

pub(super) fn valid_ref_attitude(s: &RefAttitude) -> bool {
    let q = s.q_nb.quaternion();
    q.coords.iter().all(|x| x.is_finite()) && (q.norm() - 1.0).abs() < 1e-6
}

pub(super) fn valid_mag(l: &InputLimits, s: &MagSample) -> bool {
    finite3(&s.mag_b_nt) && s.mag_b_nt.norm() <= l.max_mag_nt
}

pub(super) fn valid_gnss(l: &InputLimits, s: &GnssFix) -> bool {
    let sigma_ok = |x: f64| x.is_finite() && x >= 0.0;
    s.pos.lat_rad.is_finite()
        && s.pos.lat_rad.abs() < std::f64::consts::FRAC_PI_2
        && s.pos.lon_rad.is_finite()
        && s.pos.h_m.is_finite()
        && s.pos.h_m >= l.min_gnss_h_m
        && s.pos.h_m <= l.max_gnss_h_m
        && finite3(&s.v_ned_mps)
        && s.v_ned_mps.norm() <= l.max_gnss_speed_mps
        && sigma_ok(s.sigma_hor_m)
        && sigma_ok(s.sigma_ver_m)
        && sigma_ok(s.sigma_vel_mps)
}
