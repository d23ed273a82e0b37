//! One step of the INS cascade on an IMU sample (paper: the INS of Gallo & Barrientos;
//! docs/REFERENCES.md A1.4–A1.7): the GNSS-loss decision, the air-data filter, the attitude
//! filter with the previous step's outputs and the transfer alignment, then the position
//! filter with GNSS or the GNSS-denied propagation.

use super::*;
use position::{AirInputs, GnssFilterState, SubSteps};

/// One cascade step (module doc).
pub(super) fn run_step(
    cfg: &InsConfig,
    core: &mut Core,
    mag_model: &mut MagneticGrid,
    stats: &mut InsStats,
    step: &Step,
    imu: &ImuSample,
    aiding: Aiding<'_>,
) -> InsSolution {
    let Aiding {
        air,
        mag,
        fix,
        ref_attitude,
    } = aiding;
    // GNSS loss: no valid fix for longer than the timeout, or too many gated in a row.
    if let PositionMode::Gnss { filter, est } = &core.position {
        let since_fix_s = step.t_us.saturating_sub(core.last_fix_us) as f64 / US_PER_S;
        if since_fix_s > cfg.position.gnss_timeout_s
            || core.consecutive_gated >= cfg.position.gnss_max_consecutive_rejections
        {
            let c_nb = core.att.q_nb().to_rotation_matrix().into_inner();
            let att_cov_n = c_nb
                * core
                    .att
                    .covariance()
                    .fixed_view::<3, 3>(attitude::TH, attitude::TH)
                * c_nb.transpose();
            core.position = PositionMode::Denied(Box::new(DeniedNav::new(
                &cfg.position,
                &cfg.air,
                core.air.state(),
                core.air.held_angles(),
                &att_cov_n,
                filter,
                est,
            )));
            stats.gnss_denied_since_us = Some(step.t_us);
        }
    }

    // 1. Air data.
    let numerical_before = core.air.numerical_rejections;
    for _ in 0..step.n_sub {
        core.air.predict(&cfg.air, step.dt_sub_s, step.q_scale_sub);
    }
    if let Some(a) = air {
        core.air.update(&cfg.air, a);
    }
    stats.numerical_rejections += core.air.numerical_rejections - numerical_before;

    // 2. Attitude, with the previous step's outputs.
    let prev = core.prev;
    let w_ie = wgs84::omega_ie_n(prev.pos.lat_rad);
    let w_en = wgs84::omega_en_n(&prev.pos, &prev.v_n);
    let b_model_n = match mag_model.field_ned_nt(&prev.pos) {
        Ok(b) => Some(b),
        Err(_) => {
            stats.mag_model_errors += 1;
            None
        }
    };
    let ctx = AttitudeContext {
        w_in_n: w_ie + w_en,
        a_n: w_en.cross(&prev.v_n) + (w_ie * 2.0).cross(&prev.v_n)
            - wgs84::gravity_ned_mps2(&prev.pos),
        v_tashf_n: prev.v_n - prev.wind_n,
        e_acc_b: prev.e_acc,
        b_model_n,
        turn_var_per_m2ps4: cfg.attitude.r_accel_turn_rel.powi(2)
            * cfg.attitude.r_accel_turn_correlation_s
            / cfg.reference_period_s,
    };
    for _ in 0..step.n_sub {
        core.att
            .predict(&cfg.attitude, step.dt_sub_s, step.q_scale_sub);
    }
    if core
        .att
        .update(
            &cfg.attitude,
            &ctx,
            &imu.gyro_rps,
            &imu.accel_mps2,
            mag.map(|m| &m.mag_b_nt),
            step.r_scale,
        )
        .is_err()
    {
        stats.numerical_rejections += 1;
    }
    if let Some(r) = ref_attitude {
        fuse_ref_attitude(cfg, core, stats, step.t_us, r);
    }
    let q_nb = core.att.q_nb();
    let (v_air, v_air_cov) = position::air_velocity_n(
        &q_nb,
        core.air.state(),
        &core.air.covariance_without_held_angles(),
    );
    let p_air = core.air.covariance();
    let air_in = AirInputs {
        q_nb,
        tas_mps: core.air.state()[air_data::TAS],
        hp_m: core.air.state()[air_data::HP],
        delta_t_k: core.air.delta_t_k(),
        t_hp_cov: Matrix2::new(
            p_air[(air_data::TEMP, air_data::TEMP)],
            p_air[(air_data::TEMP, air_data::HP)],
            p_air[(air_data::HP, air_data::TEMP)],
            p_air[(air_data::HP, air_data::HP)],
        ),
        v_air_n: v_air,
        v_air_cov,
    };

    // 3. Position.
    let mut gnss_nis = None;
    match &mut core.position {
        PositionMode::Gnss { filter, est } => {
            for _ in 0..step.n_sub {
                filter.predict(&cfg.position, &q_nb, step.dt_sub_s, step.q_scale_sub);
            }
            if filter
                .update_accel(&cfg.position, &imu.accel_mps2, step.r_scale)
                .is_err()
            {
                stats.numerical_rejections += 1;
            }
            if let Some(fix) = fix {
                let lag_s = (step.t_us as f64 - fix.t_us as f64) / US_PER_S;
                if lag_s.abs() > cfg.position.gnss_max_lag_s {
                    stats.gnss_stale += 1;
                } else {
                    match filter.update_gnss(&cfg.position, fix, lag_s, &q_nb, &core.att.w_nb_b()) {
                        Ok(nis) => {
                            stats.gnss_fused += 1;
                            core.consecutive_gated = 0;
                            gnss_nis = Some(nis);
                        }
                        Err(ekf::UpdateRejection::Gated { nis }) => {
                            gnss_nis = Some(nis);
                            stats.gnss_gated += 1;
                            core.consecutive_gated += 1;
                        }
                        Err(ekf::UpdateRejection::Numerical) => {
                            stats.numerical_rejections += 1;
                        }
                    }
                }
            }
            filter.record(step.t_us, cfg.position.gnss_max_lag_s);
            let gnss = GnssFilterState {
                h_m: filter.pos().h_m,
                var_h_m2: filter.position_cov_with_bias(&cfg.position)[(2, 2)],
                v_n: filter.v_n(),
                v_cov: filter.velocity_cov(),
            };
            est.step(step.dt_s, &air_in, &gnss);
            core.prev = PrevOutputs {
                pos: filter.pos(),
                v_n: filter.v_n(),
                wind_n: est.wind().0,
                e_acc: filter.e_acc(),
            };
        }
        PositionMode::Denied(nav) => {
            let q_scale = step.dt_s / cfg.reference_period_s;
            if nav
                .filter_accel(&cfg.position, &imu.accel_mps2, q_scale, step.r_scale)
                .is_err()
            {
                stats.numerical_rejections += 1;
            }
            let sub = SubSteps {
                dt_s: step.dt_sub_s,
                n: step.n_sub,
                q_scale: step.q_scale_sub,
            };
            nav.propagate(&cfg.position, &air_in, sub);
            core.prev = PrevOutputs {
                pos: nav.pos(),
                v_n: nav.v_n(),
                wind_n: nav.wind().0,
                e_acc: nav.e_acc(),
            };
        }
    }
    core.t_us = step.t_us;
    assemble_solution(cfg, core, step.dt_s, step.gap, gnss_nis, imu)
}

/// Transfer alignment (`AlignmentConfig`): fuse the reference attitude if the INS is in its
/// GNSS phase, the last fused one is at least `min_interval_s` older and it is recent.
pub(super) fn fuse_ref_attitude(
    cfg: &InsConfig,
    core: &mut Core,
    stats: &mut InsStats,
    t_us: u64,
    r: &RefAttitude,
) {
    let a = &cfg.alignment;
    let lag_s = (t_us as f64 - r.t_us as f64) / US_PER_S;
    let due = core
        .last_ref_attitude_us
        .is_none_or(|last| (r.t_us.saturating_sub(last) as f64) / US_PER_S >= a.min_interval_s);
    let gnss_phase = matches!(core.position, PositionMode::Gnss { .. });
    if !gnss_phase || !due || lag_s.abs() > a.max_lag_s {
        stats.ref_attitude_unused += 1;
        return;
    }
    let var = a.ref_attitude_sigma_deg.to_radians().powi(2);
    match core.att.update_reference(&r.q_nb, lag_s, var, a.gate_chi2) {
        Ok(_) => {
            stats.ref_attitude_fused += 1;
            core.consecutive_ref_gated = 0;
            core.last_ref_attitude_us = Some(r.t_us);
        }
        Err(ekf::UpdateRejection::Gated { .. }) => {
            stats.ref_attitude_gated += 1;
            core.consecutive_ref_gated += 1;
            // Decimated like the fused ones, so the restart takes that many intervals.
            core.last_ref_attitude_us = Some(r.t_us);
            if core.consecutive_ref_gated >= a.max_consecutive_rejections {
                let q_then = r.q_nb * so3::exp(&(core.att.w_nb_b() * lag_s));
                core.att.reset_attitude(&q_then, var);
                core.consecutive_ref_gated = 0;
                stats.ref_attitude_resets += 1;
            }
        }
        Err(ekf::UpdateRejection::Numerical) => stats.numerical_rejections += 1,
    }
}
