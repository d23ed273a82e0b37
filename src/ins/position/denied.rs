//! The GNSS-denied navigation (docs/REFERENCES.md A1.7, `filter_pos` + `filter_pos02B`): the
//! 6-state EKF `[f_ib_b, E_acc]` (`F = I`, `y = f̃`, `H = [I I]`) starts from the GNSS filter's
//! blocks; Δp and the wind are frozen; `v_n = v_lf + C_nb v_TAS^b`; `h = h(Hp, ΔT̂, Δp)`;
//! latitude and longitude are Euler-integrated with the previous step's radii. Covariances:
//! velocity and horizontal position from the dead-reckoning error model
//! `δv = δw + C_nb (δg + δb) + δv_air` (frozen-wind error, Gauss–Markov gust with the
//! turbulence intensity measured while GNSS is available, air-velocity bias, white air-velocity
//! error; [`DeniedNav`], docs/INS.md); vertical = the barometric altitude's first-order
//! variance from `Hp`, `ΔT` and the frozen `Δp`.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use super::gnss_phase::{GnssPhaseEstimates, baro_altitude, gust_tau_s};
use super::{AirInputs, F, GnssFilter, P, SubSteps, v_tas_b};
use crate::env::atmosphere;
use crate::ins::air_data;
use crate::ins::config::{AirDataFilterConfig, PositionFilterConfig};
use crate::ins::ekf::{self, UpdateRejection};
use crate::math::so3;
use crate::math::wgs84::{self, Geodetic};

/// Number of error states of the dead-reckoning covariance.
const NDR: usize = 15;
/// Offsets in it: NED position, frozen-wind error, gust (body), air-velocity bias (body),
/// attitude error (NED).
pub(super) const DR_P: usize = 0;
const DR_W: usize = 3;
pub(super) const DR_G: usize = 6;
const DR_B: usize = 9;
const DR_A: usize = 12;

/// The GNSS-denied navigation (docs/REFERENCES.md A1.7, variant 02B).
///
/// Velocity error model (docs/INS.md "GNSS-denied covariance"): with the estimate
/// `v̂ = ŵ + Ĉ v̂_air` and the truth `v = w + C (v_air + v_gust)`,
/// `δv = δw + C (δg + δb) + [v_air,n]× δθ_n + δv_air`: the frozen-wind error `δw` (a random
/// constant), the gust the frozen wind cannot follow `δg = −v_gust` (body axes, first-order
/// Gauss–Markov with the measured intensity and correlation time `L/V`), the air-velocity bias
/// `δb` (Pitot and vane biases through `∂v_air/∂(V, α, β)`, or without vanes the held angles'
/// errors `no_vane_angle_sigma_deg`, `no_vane_aos_sigma_deg`; constant in body axes), the
/// attitude error `δθ_n` (NED, a random constant with the attitude filter's covariance at the
/// loss: a heading error from the magnetometer's error estimates persists for minutes) and
/// the white remainder `δv_air` (air-data filter covariance). `δw` is correlated with `δg`
/// (the window holds part of the last gusts), with `δb` (the wind estimate absorbed the bias at
/// the averaged attitude `C̄`: `δw ∋ −C̄ δb`) and with `δθ_n` (it absorbed the attitude error at
/// the averaged air velocity: `δw ∋ −[v̄_air]× δθ_n`, so a heading error costs nothing on the
/// heading the wind was averaged on and up to `2 V δψ` on the opposite one).
/// What the GNSS-denied covariance started from at the loss, as 1-σ values (horizontal ones
/// are DRMS, `√(σ_N² + σ_E²)`): why the published accuracy grows as it does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeniedBudget {
    /// Turbulence measured while GNSS was available, per body axis, m/s.
    pub gust_sigma_b_mps: Vector3<f64>,
    /// Its correlation times `L/V` per body axis, s.
    pub gust_tau_s: Vector3<f64>,
    /// Frozen-wind error, horizontal, m/s: the sum of the four parts below.
    pub wind_sigma_mps: f64,
    /// Part: the averaged covariance of the raw-wind samples, m/s.
    pub wind_avg_sigma_mps: f64,
    /// Part: the gusts the wind average still holds, m/s.
    pub wind_gust_sigma_mps: f64,
    /// Part: the air-velocity bias the wind absorbed, m/s.
    pub wind_air_bias_sigma_mps: f64,
    /// Part: the attitude error the wind absorbed, m/s.
    pub wind_attitude_sigma_mps: f64,
    /// Heading σ at the loss, rad.
    pub heading_sigma_rad: f64,
    /// Airspeed correction estimated from the turns before the loss and applied to the dead
    /// reckoning, m/s (`position.airspeed_bias_from_turns`; 0 when off or not observable).
    pub airspeed_correction_mps: f64,
}

/// Horizontal DRMS of a NED covariance.
fn horizontal_drms(m: &Matrix3<f64>) -> f64 {
    (m[(0, 0)] + m[(1, 1)]).max(0.0).sqrt()
}

#[derive(Debug, Clone)]
pub(crate) struct DeniedNav {
    /// 6-state EKF `[f_ib_b, E_acc]`.
    f_b: Vector3<f64>,
    e_acc: Vector3<f64>,
    p6: SMatrix<f64, 6, 6>,
    pos: Geodetic,
    v_n: Vector3<f64>,
    wind_n: Vector3<f64>,
    delta_p_pa: f64,
    delta_p_var: f64,
    /// Covariance of `[δp_NED, δw_NED, δg_b, δb_b]`; its down position block is replaced by
    /// the barometric variance when reported.
    pub(super) p_dr: SMatrix<f64, NDR, NDR>,
    /// Turbulence variance per body axis, (m/s)², and integral scales, m.
    pub(super) gust_var_b: Vector3<f64>,
    gust_scale_m: [f64; 3],
    h_var: f64,
    v_cov: Matrix3<f64>,
    budget: DeniedBudget,
    /// Airspeed correction applied to the air velocity, m/s (0 = none).
    airspeed_correction_mps: f64,
}

impl DeniedNav {
    /// Switch from the GNSS phase: the 6-state EKF takes the GNSS filter's `[f, E_acc]` blocks,
    /// the wind and Δp freeze at their low-pass values; the dead-reckoning covariance starts
    /// from the GNSS position covariance, the wind's, the measured turbulence and the
    /// air-data bias σ's (`air_cfg`) at the current air state.
    pub fn new(
        cfg: &PositionFilterConfig,
        air_cfg: &AirDataFilterConfig,
        air_x: &SVector<f64, { air_data::NX }>,
        held_angles: [bool; 2],
        att_cov_n: &Matrix3<f64>,
        gnss: &GnssFilter,
        est: &GnssPhaseEstimates,
    ) -> Self {
        let (mut wind_n, wind_cov) = est.wind();
        // The wind absorbed `c̄ δ` of an airspeed bias: take it out and correct the airspeed.
        let airspeed_correction_mps = match cfg.airspeed_bias_from_turns {
            true => match est.airspeed_bias(cfg.airspeed_bias_min_heading_spread) {
                Some((delta, c_bar)) => {
                    wind_n -= c_bar * delta;
                    delta
                }
                None => 0.0,
            },
            false => 0.0,
        };
        let (delta_p_pa, delta_p_var) = est.delta_p();
        let tas = air_x[air_data::TAS];
        let (_, j_air) = v_tas_b(tas, air_x[air_data::AOA], air_x[air_data::AOS]);
        // A vane's bias, or without the vane the held guess's error (its whole uncertainty).
        let angle_sigma_deg = |held: bool, held_deg: f64, vane_bias_deg: f64| {
            if held { held_deg } else { vane_bias_deg }
        };
        let bias_var = Matrix3::from_diagonal(&Vector3::new(
            air_cfg.tas_bias_sigma_mps.powi(2),
            angle_sigma_deg(
                held_angles[0],
                air_cfg.no_vane_angle_sigma_deg,
                air_cfg.aoa_bias_sigma_deg,
            )
            .to_radians()
            .powi(2),
            angle_sigma_deg(
                held_angles[1],
                air_cfg.no_vane_aos_sigma_deg,
                air_cfg.aos_bias_sigma_deg,
            )
            .to_radians()
            .powi(2),
        ));
        let p_bb = j_air * bias_var * j_air.transpose();
        let (gust_var_b, held_var, held_cov) = est.gust(tas);
        let p_wg = -est.c_nb_lpf() * Matrix3::from_diagonal(&gust_var_b.component_mul(&held_cov));
        let p_wb = -est.c_nb_lpf() * p_bb;
        let c_bar = est.c_nb_lpf();
        // Raw wind error ∋ −(Ĉ − C) v_air = −[v_air,n]× δθ_n, averaged over the window.
        let j_wa = -so3::skew(&est.v_air_n_mean());
        let p_wa = j_wa * att_cov_n;
        let p_w_gust = c_bar
            * Matrix3::from_diagonal(&gust_var_b.component_mul(&held_var))
            * c_bar.transpose();
        let p_w_bias = c_bar * p_bb * c_bar.transpose();
        let p_w_att = j_wa * att_cov_n * j_wa.transpose();
        let p_ww = wind_cov + p_w_gust + p_w_bias + p_w_att;
        let budget = DeniedBudget {
            gust_sigma_b_mps: gust_var_b.map(|v| v.max(0.0).sqrt()),
            gust_tau_s: Vector3::from_fn(|i, _| {
                gust_tau_s(cfg.turbulence_integral_scale_m[i], tas)
            }),
            wind_sigma_mps: horizontal_drms(&p_ww),
            wind_avg_sigma_mps: horizontal_drms(&wind_cov),
            wind_gust_sigma_mps: horizontal_drms(&p_w_gust),
            wind_air_bias_sigma_mps: horizontal_drms(&p_w_bias),
            wind_attitude_sigma_mps: horizontal_drms(&p_w_att),
            heading_sigma_rad: att_cov_n[(2, 2)].max(0.0).sqrt(),
            airspeed_correction_mps,
        };
        let mut p_dr = SMatrix::<f64, NDR, NDR>::zeros();
        p_dr.fixed_view_mut::<3, 3>(DR_P, DR_P)
            .copy_from(&gnss.position_cov_with_bias(cfg));
        p_dr.fixed_view_mut::<3, 3>(DR_W, DR_W).copy_from(&p_ww);
        p_dr.fixed_view_mut::<3, 3>(DR_G, DR_G)
            .copy_from(&Matrix3::from_diagonal(&gust_var_b));
        p_dr.fixed_view_mut::<3, 3>(DR_B, DR_B).copy_from(&p_bb);
        p_dr.fixed_view_mut::<3, 3>(DR_W, DR_G).copy_from(&p_wg);
        p_dr.fixed_view_mut::<3, 3>(DR_G, DR_W)
            .copy_from(&p_wg.transpose());
        p_dr.fixed_view_mut::<3, 3>(DR_W, DR_B).copy_from(&p_wb);
        p_dr.fixed_view_mut::<3, 3>(DR_B, DR_W)
            .copy_from(&p_wb.transpose());
        p_dr.fixed_view_mut::<3, 3>(DR_A, DR_A).copy_from(att_cov_n);
        p_dr.fixed_view_mut::<3, 3>(DR_W, DR_A).copy_from(&p_wa);
        p_dr.fixed_view_mut::<3, 3>(DR_A, DR_W)
            .copy_from(&p_wa.transpose());
        ekf::symmetrize(&mut p_dr);
        Self {
            f_b: gnss.f_b,
            e_acc: gnss.e_acc,
            p6: gnss.p.fixed_view::<6, 6>(F, F).into_owned(),
            pos: gnss.pos,
            v_n: gnss.v_n,
            wind_n,
            delta_p_pa,
            delta_p_var,
            p_dr,
            gust_var_b,
            gust_scale_m: cfg.turbulence_integral_scale_m,
            h_var: gnss.p[(P + 2, P + 2)],
            v_cov: gnss.velocity_cov(),
            budget,
            airspeed_correction_mps,
        }
    }

    /// The covariance budget at the loss.
    pub fn budget(&self) -> &DeniedBudget {
        &self.budget
    }

    /// The 6-state EKF step: predict (`F = I`) and update with the accelerometer.
    pub fn filter_accel(
        &mut self,
        cfg: &PositionFilterConfig,
        accel_mps2: &Vector3<f64>,
        q_scale: f64,
        r_scale: f64,
    ) -> Result<(), UpdateRejection> {
        let q = SVector::<f64, 6>::from([
            cfg.q_specific_force_m2ps4 * q_scale,
            cfg.q_specific_force_m2ps4 * q_scale,
            cfg.q_specific_force_m2ps4 * q_scale,
            cfg.q_e_acc_m2ps4 * q_scale,
            cfg.q_e_acc_m2ps4 * q_scale,
            cfg.q_e_acc_m2ps4 * q_scale,
        ]);
        for i in 0..6 {
            self.p6[(i, i)] += q[i];
        }
        let mut h = SMatrix::<f64, 3, 6>::zeros();
        h.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
        h.fixed_view_mut::<3, 3>(0, 3).fill_with_identity();
        let r = Vector3::repeat(cfg.r_accel_m2ps4 * r_scale);
        let innov = accel_mps2 - (self.f_b + self.e_acc);
        let dx = ekf::update_rows(&mut self.p6, &h, &r, &innov)?;
        self.f_b += dx.fixed_rows::<3>(0);
        self.e_acc += dx.fixed_rows::<3>(3);
        Ok(())
    }

    /// Dead-reckoning step: ground velocity from the frozen wind and the air-relative
    /// velocity, altitude from the barometer, horizontal position integrated over the
    /// sub-steps; the attitude and airspeed map and time the gust and bias errors, the air
    /// velocity the attitude error. Its covariance `v_air_cov` is the white remainder: the
    /// air-data part (the attitude part is the `δθ_n` state).
    pub fn propagate(&mut self, cfg: &PositionFilterConfig, air: &AirInputs, sub: SubSteps) {
        let (q_nb, tas_mps, v_air_n, v_air_cov) =
            (&air.q_nb, air.tas_mps, &air.v_air_n, &air.v_air_cov);
        let (hp_m, delta_t_k, air_t_hp_cov) = (air.hp_m, air.delta_t_k, &air.t_hp_cov);
        let (dt_sub_s, n_sub, q_scale_sub) = (sub.dt_s, sub.n, sub.q_scale);
        let c_nb = q_nb.to_rotation_matrix().into_inner();
        // The airspeed correction as a scale of the air velocity (exactly 1 without one).
        let scale = match tas_mps > 0.0 {
            true => 1.0 + self.airspeed_correction_mps / tas_mps,
            false => 1.0,
        };
        self.v_n = self.wind_n + v_air_n * scale;
        // Altitude: h(Hp, ΔT(T, Hp), Δp); ∂/∂T = ∂h/∂ΔT, ∂/∂Hp = ∂h/∂Hp − β_T ∂h/∂ΔT.
        let (h, d) = baro_altitude(hp_m, delta_t_k, self.delta_p_pa);
        let slope = if hp_m > atmosphere::HP_TROPOPAUSE_M {
            0.0
        } else {
            atmosphere::BETA_T_KPM
        };
        let j = nalgebra::RowVector2::new(d.y, d.x - slope * d.y);
        let h_var = (j * air_t_hp_cov * j.transpose())[(0, 0)] + d.z * d.z * self.delta_p_var;
        if h.is_finite() && h_var.is_finite() {
            self.pos.h_m = h;
            self.h_var = h_var;
        }
        // Horizontal: previous-step radii and latitude, current height (docs/REFERENCES.md A1.7).
        let (m, n) = (
            wgs84::radius_meridian_m(self.pos.lat_rad),
            wgs84::radius_prime_vertical_m(self.pos.lat_rad),
        );
        // δp' = δp + Δt (δw + C δg + C δb), δg' = a δg + noise (a = exp(−Δt V/L)): the
        // transition's rows δp (`phi_p`), then a diagonal (`decay`: a on δg, 1 elsewhere).
        let mut decay = SVector::<f64, NDR>::repeat(1.0);
        let mut q_g = Vector3::zeros();
        if tas_mps.is_finite() {
            for i in 0..3 {
                let a = (-dt_sub_s / gust_tau_s(self.gust_scale_m[i], tas_mps)).exp();
                decay[DR_G + i] = a;
                q_g[i] = self.gust_var_b[i] * (1.0 - a * a);
            }
        }
        let mut phi_p = SMatrix::<f64, 3, NDR>::zeros();
        phi_p.fixed_view_mut::<3, 3>(0, DR_P).fill_with_identity();
        phi_p
            .fixed_view_mut::<3, 3>(0, DR_W)
            .copy_from(&(Matrix3::identity() * dt_sub_s));
        phi_p
            .fixed_view_mut::<3, 3>(0, DR_G)
            .copy_from(&(c_nb * dt_sub_s));
        phi_p
            .fixed_view_mut::<3, 3>(0, DR_B)
            .copy_from(&(c_nb * dt_sub_s));
        // (Ĉ − C) v_air = [v_air,n]× δθ_n.
        let j_va = so3::skew(v_air_n);
        phi_p
            .fixed_view_mut::<3, 3>(0, DR_A)
            .copy_from(&(j_va * dt_sub_s));
        let add = v_air_cov * (dt_sub_s * dt_sub_s);
        for _ in 0..n_sub {
            let lat = self.pos.lat_rad;
            self.pos.lat_rad += dt_sub_s * self.v_n.x / (m + self.pos.h_m);
            self.pos.lon_rad += dt_sub_s * self.v_n.y / ((n + self.pos.h_m) * lat.cos());
            ekf::transform_covariance_top(&mut self.p_dr, &phi_p, Some(&decay));
            for r in 0..3 {
                for c in 0..3 {
                    self.p_dr[(DR_P + r, DR_P + c)] += add[(r, c)];
                }
                self.p_dr[(DR_P + r, DR_P + r)] += cfg.q_position_m2 * q_scale_sub;
                self.p_dr[(DR_G + r, DR_G + r)] += q_g[r];
            }
            ekf::symmetrize(&mut self.p_dr);
        }
        // δv = δw + C (δg + δb) + [v_air,n]× δθ_n + δv_air.
        let mut hv = SMatrix::<f64, 3, NDR>::zeros();
        hv.fixed_view_mut::<3, 3>(0, DR_W).fill_with_identity();
        hv.fixed_view_mut::<3, 3>(0, DR_G).copy_from(&c_nb);
        hv.fixed_view_mut::<3, 3>(0, DR_B).copy_from(&c_nb);
        hv.fixed_view_mut::<3, 3>(0, DR_A).copy_from(&j_va);
        let v_cov = hv * self.p_dr * hv.transpose() + v_air_cov;
        self.v_cov = (v_cov + v_cov.transpose()) * 0.5;
    }

    /// Geodetic position.
    pub fn pos(&self) -> Geodetic {
        self.pos
    }
    /// NED ground velocity, m/s.
    pub fn v_n(&self) -> Vector3<f64> {
        self.v_n
    }
    /// Specific force estimate, m/s².
    pub fn f_b(&self) -> Vector3<f64> {
        self.f_b
    }
    /// Accelerometer error estimate, m/s².
    pub fn e_acc(&self) -> Vector3<f64> {
        self.e_acc
    }
    /// Frozen wind and the covariance of its error.
    pub fn wind(&self) -> (Vector3<f64>, Matrix3<f64>) {
        (
            self.wind_n,
            self.p_dr.fixed_view::<3, 3>(DR_W, DR_W).into_owned(),
        )
    }
    /// Frozen Δp and its variance.
    pub fn delta_p(&self) -> (f64, f64) {
        (self.delta_p_pa, self.delta_p_var)
    }
    /// NED position covariance: horizontal from the dead-reckoning model, vertical from the
    /// barometric altitude (no horizontal–vertical correlation), m².
    pub fn position_cov(&self) -> Matrix3<f64> {
        let mut c = Matrix3::zeros();
        c.fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&self.p_dr.fixed_view::<2, 2>(DR_P, DR_P));
        c[(2, 2)] = self.h_var;
        c
    }
    /// Accelerometer-error covariance, (m/s²)².
    pub fn e_acc_cov(&self) -> Matrix3<f64> {
        self.p6.fixed_view::<3, 3>(3, 3).into_owned()
    }
    /// NED velocity covariance, (m/s)².
    pub fn velocity_cov(&self) -> Matrix3<f64> {
        self.v_cov
    }
    /// Covariance of the 6-state `[f, E_acc]` EKF (tests).
    #[cfg(test)]
    pub fn accel_cov(&self) -> &SMatrix<f64, 6, 6> {
        &self.p6
    }
    /// Covariance of `[δp_NED, δw_NED, δg_b, δb_b, δθ_n]` of the dead reckoning (tests).
    #[cfg(test)]
    pub fn dead_reckoning_cov(&self) -> &SMatrix<f64, NDR, NDR> {
        &self.p_dr
    }
}
