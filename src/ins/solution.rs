//! The INS solution assembled from the three filters (docs/INS.md "Outputs"), with the
//! attitude covariance widened by the tilt an accelerometer-error uncertainty implies.

use super::*;

/// What the position part of the cascade (GNSS filter or GNSS-denied propagation) gives the
/// solution.
struct PositionOutputs {
    pos: Geodetic,
    v_n: Vector3<f64>,
    f_b: Vector3<f64>,
    e_acc: Vector3<f64>,
    /// Wind, NED, m/s, and its covariance, m²/s².
    wind: (Vector3<f64>, Matrix3<f64>),
    /// Pressure offset Δp, Pa, and its variance, Pa².
    delta_p: (f64, f64),
    p_pos: Matrix3<f64>,
    p_vel: Matrix3<f64>,
    p_eacc: Matrix3<f64>,
    gnss_denied: bool,
}

impl PositionOutputs {
    fn of(cfg: &InsConfig, position: &PositionMode) -> Self {
        match position {
            PositionMode::Gnss { filter, est } => Self {
                pos: filter.pos(),
                v_n: filter.v_n(),
                f_b: filter.f_b(),
                e_acc: filter.e_acc(),
                wind: est.wind(),
                delta_p: est.delta_p(),
                p_pos: filter.position_cov_with_bias(&cfg.position),
                p_vel: filter.velocity_cov(),
                p_eacc: filter.e_acc_cov(),
                gnss_denied: false,
            },
            PositionMode::Denied(nav) => Self {
                pos: nav.pos(),
                v_n: nav.v_n(),
                f_b: nav.f_b(),
                e_acc: nav.e_acc(),
                wind: nav.wind(),
                delta_p: nav.delta_p(),
                p_pos: nav.position_cov(),
                p_vel: nav.velocity_cov(),
                p_eacc: nav.e_acc_cov(),
                gnss_denied: true,
            },
        }
    }
}

/// Assemble the solution from the filters.
pub(super) fn assemble_solution(
    cfg: &InsConfig,
    core: &Core,
    dt_s: f64,
    gap: bool,
    gnss_nis: Option<f64>,
    imu: &ImuSample,
) -> InsSolution {
    let ax = core.air.state();
    let pa = core.att.covariance();
    let PositionOutputs {
        pos,
        v_n,
        f_b,
        e_acc,
        wind,
        delta_p: dp,
        p_pos,
        p_vel,
        p_eacc,
        gnss_denied,
    } = PositionOutputs::of(cfg, &core.position);
    let block = |i: usize| -> Matrix3<f64> { pa.fixed_view::<3, 3>(i, i).into_owned() };
    // The attitude filter takes E_acc as known; an error δE in it tilts the attitude by
    // δθ = −[f]× δE / |f|² (the rotation that explains δE as a turn of the specific force),
    // a persistent error its own covariance does not contain.
    let f_norm2 = f_b.norm_squared();
    let tilt_from_eacc = if f_norm2 > 1.0 {
        let j = -so3::skew(&f_b) / f_norm2;
        let c = j * p_eacc * j.transpose();
        (c + c.transpose()) * 0.5
    } else {
        Matrix3::zeros()
    };
    InsSolution {
        t_us: imu.t_us,
        dt_s,
        imu_gap: gap,
        pos,
        v_ned_mps: v_n,
        q_nb: core.att.q_nb(),
        w_nb_b_rps: core.att.w_nb_b(),
        hp_m: ax[air_data::HP],
        roc_mps: ax[air_data::ROC],
        tas_mps: ax[air_data::TAS],
        aoa_rad: ax[air_data::AOA],
        aos_rad: ax[air_data::AOS],
        temp_k: ax[air_data::TEMP],
        delta_t_k: core.air.delta_t_k(),
        delta_p_pa: dp.0,
        wind_ned_mps: wind.0,
        f_ib_b_mps2: f_b,
        e_gyr_rps: core.att.e_gyr(),
        e_acc_mps2: e_acc,
        e_mag_nt: core.att.e_mag(),
        delta_b_n_nt: core.att.delta_b_n(),
        ref_attitude_err_rad: core.att.ref_err(),
        gnss_denied,
        gnss_nis,
        cov: InsCovariance {
            attitude_rad2: block(attitude::TH) + tilt_from_eacc,
            w_nb_b_rad2ps2: block(attitude::W),
            e_gyr_rad2ps2: block(attitude::EG),
            velocity_m2ps2: p_vel,
            position_m2: p_pos,
            wind_m2ps2: wind.1,
            air_data: *core.air.covariance(),
            delta_t_k2: core.air.delta_t_var_k2(),
            delta_p_pa2: dp.1,
        },
    }
}
