//! Position filter with GNSS (docs/REFERENCES.md A1.6, `filter_gps01`), the GNSS-phase estimates of
//! the pressure offset and the low-frequency wind (A1.6, `gnss_phase.rs`), and the GNSS-denied
//! propagation (A1.7, `filter_pos` + `filter_pos02B`, `denied.rs`).
//!
//! **GNSS filter** (this file). Nominal state: geodetic position, NED velocity `v_n`, specific force
//! `f_ib_b`, accelerometer error `E_acc`. Process (explicit Euler as the authors):
//! `ṗ = geodetic_rates(v)`, `v̇ = C_nb f + g − (2 w_ie + w_en) × v`, `ḟ = 0`, `Ė_acc = 0`.
//! Observations: every IMU step `f̃ = f + E_acc` (fast), and at each fix GNSS velocity and
//! position (slow; the authors' dual-rate EKF). The authors' filter keeps (λ, φ, h) as
//! additive states; here the 12 error states are `[δp_NED (m), δv, δf, δE_acc]`, a diagonal
//! change of variables (`δp_N = (M+h)δφ`, `δp_E = (N+h)cos φ δλ`, `δp_D = −δh`) that makes
//! the position covariance metric and well conditioned. `A` is the authors' plus the Coriolis
//! term in `A_vv = −[2 w_ie + w_en]×`; `F = expm(AΔt)` is evaluated in closed form (series in
//! `Ω = [2 w_ie + w_en]×` up to `Ω²`; error `O((|Ω|Δt)³)` ≈ 1e-18).

use std::collections::VecDeque;

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use super::air_data;
use super::config::PositionFilterConfig;
use super::ekf::{self, UpdateRejection};
use crate::math::so3;
use crate::math::wgs84::{self, Geodetic};
use crate::sensors::GnssFix;
mod denied;
mod gnss_phase;
#[cfg(test)]
mod tests;

pub use denied::DeniedBudget;
pub(crate) use denied::DeniedNav;
pub(crate) use gnss_phase::GnssPhaseEstimates;

/// Number of error states of the GNSS filter.
/// What the position part of the cascade takes from the air-data and attitude filters at one
/// step.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AirInputs {
    /// Attitude, body to NED.
    pub q_nb: UnitQuaternion<f64>,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Pressure altitude, m.
    pub hp_m: f64,
    /// Temperature offset ΔT, K.
    pub delta_t_k: f64,
    /// Covariance of the air-data temperature and pressure altitude `[T, Hp]`.
    pub t_hp_cov: Matrix2<f64>,
    /// Air velocity, NED, m/s.
    pub v_air_n: Vector3<f64>,
    /// Its covariance, m²/s².
    pub v_air_cov: Matrix3<f64>,
}

/// The GNSS filter's height and ground velocity with their (co)variances, for the estimates
/// frozen at the loss.
#[derive(Debug, Clone, Copy)]
pub(crate) struct GnssFilterState {
    /// Geometric height, m, and its variance, m².
    pub h_m: f64,
    pub var_h_m2: f64,
    /// Ground velocity, NED, m/s, and its covariance.
    pub v_n: Vector3<f64>,
    pub v_cov: Matrix3<f64>,
}

/// The propagation sub-steps of one IMU interval.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SubSteps {
    /// Length of one sub-step, s.
    pub dt_s: f64,
    /// Number of sub-steps.
    pub n: u32,
    /// Scale of the per-step Q̃ for one sub-step.
    pub q_scale: f64,
}

pub(crate) const NX: usize = 12;
/// Offset of the NED position error, m.
const P: usize = 0;
/// Offset of the velocity error, m/s.
const V: usize = 3;
/// Offset of the specific-force error, m/s².
const F: usize = 6;
/// Offset of the accelerometer-error error, m/s².
const EA: usize = 9;

/// Meridian and prime-vertical radii plus height, `(M + h, N + h)`, m.
fn radii_h(pos: &Geodetic) -> (f64, f64) {
    (
        wgs84::radius_meridian_m(pos.lat_rad) + pos.h_m,
        wgs84::radius_prime_vertical_m(pos.lat_rad) + pos.h_m,
    )
}

/// Move `pos` by a small NED displacement (m).
fn displace(pos: &mut Geodetic, d_ned_m: &Vector3<f64>) {
    let (m_h, n_h) = radii_h(pos);
    let lat = pos.lat_rad;
    pos.lat_rad += d_ned_m.x / m_h;
    pos.lon_rad += d_ned_m.y / (n_h * lat.cos());
    pos.h_m -= d_ned_m.z;
}

/// Small NED displacement (m) from `from` to `to` (first order; ≈ 1.6 mm error at 100 m).
fn ned_offset_m(from: &Geodetic, to: &Geodetic) -> Vector3<f64> {
    let (m_h, n_h) = radii_h(from);
    let dlon = crate::math::angle::wrap_pi(to.lon_rad - from.lon_rad);
    Vector3::new(
        (to.lat_rad - from.lat_rad) * m_h,
        dlon * n_h * from.lat_rad.cos(),
        -(to.h_m - from.h_m),
    )
}

/// Air-relative velocity in body axes `V·[cos α cos β, sin β, sin α cos β]` and its Jacobian
/// with respect to `(V, α, β)`.
pub(crate) fn v_tas_b(tas_mps: f64, aoa_rad: f64, aos_rad: f64) -> (Vector3<f64>, Matrix3<f64>) {
    let (sa, ca) = aoa_rad.sin_cos();
    let (sb, cb) = aos_rad.sin_cos();
    let v = Vector3::new(ca * cb, sb, sa * cb);
    let j = Matrix3::new(
        ca * cb,
        -tas_mps * sa * cb,
        -tas_mps * ca * sb,
        sb,
        0.0,
        tas_mps * cb,
        sa * cb,
        tas_mps * ca * cb,
        -tas_mps * sa * sb,
    );
    (v * tas_mps, j)
}

/// Air-relative velocity `C_nb v_TAS^b` in NED and its covariance from the air-data
/// covariance. The attitude's share is not in it: an attitude error `δθ_b` (right
/// perturbation, `C = Ĉ Exp(δθ_b)`) moves it by `(Ĉ − C) v = [Ĉ v]× Ĉ δθ_b`, slowly and the same
/// way for the wind estimate and the dead reckoning, so the dead-reckoning covariance carries
/// it as the state `δθ_n = Ĉ δθ_b` ([`DeniedNav`]), not as noise.
pub(crate) fn air_velocity_n(
    q_nb: &UnitQuaternion<f64>,
    air_x: &SVector<f64, { air_data::NX }>,
    air_p: &SMatrix<f64, { air_data::NX }, { air_data::NX }>,
) -> (Vector3<f64>, Matrix3<f64>) {
    let (v_b, j_air) = v_tas_b(
        air_x[air_data::TAS],
        air_x[air_data::AOA],
        air_x[air_data::AOS],
    );
    let c_nb = q_nb.to_rotation_matrix().into_inner();
    let j_a = c_nb * j_air;
    let p_air = air_p.fixed_view::<3, 3>(air_data::TAS, air_data::TAS);
    let cov = j_a * p_air * j_a.transpose();
    (c_nb * v_b, (cov + cov.transpose()) * 0.5)
}

/// Inputs of the GNSS filter's initialisation (docs/REFERENCES.md A1.6 `x₀`, `P₀`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PositionInit {
    pub pos: Geodetic,
    pub v_n: Vector3<f64>,
    pub f_b: Vector3<f64>,
    pub e_acc: Vector3<f64>,
    pub e_acc_sigma: Vector3<f64>,
}

/// The 12-state GNSS position filter.
#[derive(Debug, Clone)]
pub(crate) struct GnssFilter {
    pos: Geodetic,
    v_n: Vector3<f64>,
    f_b: Vector3<f64>,
    e_acc: Vector3<f64>,
    p: SMatrix<f64, NX, NX>,
    /// Position and velocity at the recent IMU steps, oldest first (see
    /// [`GnssFilter::record`]).
    history: VecDeque<StateAt>,
}

/// The filter's position and velocity at one IMU step.
#[derive(Debug, Clone, Copy)]
struct StateAt {
    t_us: u64,
    pos: Geodetic,
    v_n: Vector3<f64>,
}

impl GnssFilter {
    /// Filter at the initial estimates; P₀: GNSS position and velocity variances,
    /// `σ²_Eacc + σ²_acc,wn` for `f`, `σ²_Eacc` for `E_acc`.
    pub fn new(cfg: &PositionFilterConfig, init: &PositionInit) -> Self {
        let mut d = SVector::<f64, NX>::zeros();
        d[P] = cfg.gnss_sigma_hor_m.powi(2);
        d[P + 1] = cfg.gnss_sigma_hor_m.powi(2);
        d[P + 2] = cfg.gnss_sigma_ver_m.powi(2);
        for i in 0..3 {
            d[V + i] = cfg.gnss_sigma_vel_mps.powi(2);
            d[F + i] = init.e_acc_sigma[i].powi(2) + cfg.r_accel_m2ps4;
            d[EA + i] = init.e_acc_sigma[i].powi(2);
        }
        Self {
            pos: init.pos,
            v_n: init.v_n,
            f_b: init.f_b,
            e_acc: init.e_acc,
            p: SMatrix::from_diagonal(&d),
            history: VecDeque::new(),
        }
    }

    /// Remember the state at the end of the step at `t_us`, and forget what is older than
    /// `keep_s` (the oldest fix still fused): a lagged fix is compared with the state at its
    /// own time.
    pub fn record(&mut self, t_us: u64, keep_s: f64) {
        if self.history.back().is_some_and(|b| b.t_us >= t_us) {
            self.history.clear();
        }
        self.history.push_back(StateAt {
            t_us,
            pos: self.pos,
            v_n: self.v_n,
        });
        let keep_us = (keep_s * 1e6) as u64 + 1;
        while self
            .history
            .front()
            .is_some_and(|f| t_us.saturating_sub(f.t_us) > keep_us)
        {
            self.history.pop_front();
        }
    }

    /// Position and velocity at `t_us` from the history, linear between the two steps around
    /// it; `None` outside the recorded span.
    fn state_at(&self, t_us: u64) -> Option<(Geodetic, Vector3<f64>)> {
        let i = self.history.partition_point(|s| s.t_us < t_us);
        let b = self.history.get(i)?;
        if b.t_us == t_us {
            return Some((b.pos, b.v_n));
        }
        let a = self.history.get(i.checked_sub(1)?)?;
        let w = (t_us - a.t_us) as f64 / (b.t_us - a.t_us) as f64;
        let mut pos = a.pos;
        displace(&mut pos, &(ned_offset_m(&a.pos, &b.pos) * w));
        Some((pos, a.v_n + (b.v_n - a.v_n) * w))
    }

    /// Time update over `dt_s` with the current attitude and `Q̃·q_scale`.
    pub fn predict(
        &mut self,
        cfg: &PositionFilterConfig,
        q_nb: &UnitQuaternion<f64>,
        dt_s: f64,
        q_scale: f64,
    ) {
        let w_ie = wgs84::omega_ie_n(self.pos.lat_rad);
        let w_en = wgs84::omega_en_n(&self.pos, &self.v_n);
        let w = w_ie * 2.0 + w_en;
        let c_nb = q_nb.to_rotation_matrix().into_inner();
        let v_dot = c_nb * self.f_b + wgs84::gravity_ned_mps2(&self.pos) - w.cross(&self.v_n);
        let rates = wgs84::geodetic_rates(&self.pos, &self.v_n);
        self.pos.lat_rad += rates.x * dt_s;
        self.pos.lon_rad += rates.y * dt_s;
        self.pos.h_m += rates.z * dt_s;
        self.v_n += v_dot * dt_s;
        // expm(AΔt) with A_pv = I, A_vv = −Ω, A_vf = C: series in Ω, truncated after Ω², so
        // the error is O((|Ω|Δt)³) ≈ (1.5e-4 rad/s · 0.01 s)³ ≈ 3e-18.
        let om = so3::skew(&w);
        let eye = Matrix3::identity();
        let om2 = om * om;
        let (dt2, dt3, dt4) = (dt_s * dt_s, dt_s.powi(3), dt_s.powi(4));
        // ∫₀^Δt exp(−Ωs) ds and ∫₀^Δt ∫₀^s exp(−Ωu) du ds, to second order in Ω.
        let int1 = eye * dt_s - om * (dt2 / 2.0) + om2 * (dt3 / 6.0);
        let int2 = eye * (dt2 / 2.0) - om * (dt3 / 6.0) + om2 * (dt4 / 24.0);
        // The transition's rows P and V; rows F and E_acc are the identity's.
        let mut f_top = SMatrix::<f64, F, NX>::zeros();
        f_top.fixed_view_mut::<3, 3>(P, P).fill_with_identity();
        f_top.fixed_view_mut::<3, 3>(P, V).copy_from(&int1);
        f_top
            .fixed_view_mut::<3, 3>(V, V)
            .copy_from(&(eye - om * dt_s + om2 * (dt2 / 2.0)));
        f_top.fixed_view_mut::<3, 3>(V, F).copy_from(&(int1 * c_nb));
        f_top.fixed_view_mut::<3, 3>(P, F).copy_from(&(int2 * c_nb));
        let mut q = SVector::<f64, NX>::zeros();
        for i in 0..3 {
            q[P + i] = cfg.q_position_m2 * q_scale;
            q[V + i] = cfg.q_velocity_m2ps2 * q_scale;
            q[F + i] = cfg.q_specific_force_m2ps4 * q_scale;
            q[EA + i] = cfg.q_e_acc_m2ps4 * q_scale;
        }
        ekf::predict_covariance_top(&mut self.p, &f_top, &q);
    }

    /// Fast update with the accelerometer: `f̃ = f + E_acc`.
    pub fn update_accel(
        &mut self,
        cfg: &PositionFilterConfig,
        accel_mps2: &Vector3<f64>,
        r_scale: f64,
    ) -> Result<(), UpdateRejection> {
        let mut h = SMatrix::<f64, 3, NX>::zeros();
        h.fixed_view_mut::<3, 3>(0, F).fill_with_identity();
        h.fixed_view_mut::<3, 3>(0, EA).fill_with_identity();
        let r = Vector3::repeat(cfg.r_accel_m2ps4 * r_scale);
        let innov = accel_mps2 - (self.f_b + self.e_acc);
        let dx = ekf::update_rows(&mut self.p, &h, &r, &innov)?;
        self.apply(&dx);
        Ok(())
    }

    /// NED acceleration of the process model, `C_nb f + g − (2 w_ie + w_en) × v`, m/s².
    fn acceleration_n(&self, c_nb: &Matrix3<f64>, f_b: &Vector3<f64>) -> Vector3<f64> {
        let w_ie = wgs84::omega_ie_n(self.pos.lat_rad);
        let w_en = wgs84::omega_en_n(&self.pos, &self.v_n);
        c_nb * f_b + wgs84::gravity_ned_mps2(&self.pos) - (w_ie * 2.0 + w_en).cross(&self.v_n)
    }

    /// A fix taken `lag_s` before the current step, moved forward to it: the velocity by the
    /// INS's acceleration over the lag, the position by the fix's velocity and that
    /// acceleration. The acceleration is taken at the middle of the lag: the specific force
    /// is rotated back by half the body rotation (`f − (w_nb × f) lag/2`; in a 0.74 rad/s turn
    /// at 2 g over 0.1 s the end-point value would be off by ≈ 0.08 m/s, the GNSS velocity σ).
    /// Gravity is the bulk of `C_nb f` in level flight and must be added back; the Coriolis
    /// term (≈ 4e-3 m/s² at 30 m/s) is kept as in the process model.
    pub fn fix_at_step(
        &self,
        fix: &GnssFix,
        lag_s: f64,
        q_nb: &UnitQuaternion<f64>,
        w_nb_b: &Vector3<f64>,
    ) -> (Geodetic, Vector3<f64>) {
        let c_nb = q_nb.to_rotation_matrix().into_inner();
        let f_mid = self.f_b - w_nb_b.cross(&self.f_b) * (lag_s / 2.0);
        let dv = self.acceleration_n(&c_nb, &f_mid) * lag_s;
        let mut fix_pos = fix.pos;
        let rates = wgs84::geodetic_rates(&fix.pos, &(fix.v_ned_mps + dv * 0.5));
        fix_pos.lat_rad += rates.x * lag_s;
        fix_pos.lon_rad += rates.y * lag_s;
        fix_pos.h_m += rates.z * lag_s;
        (fix_pos, fix.v_ned_mps + dv)
    }

    /// Slow update with a GNSS fix taken `lag_s` before the current step, gated on the 6-D
    /// innovation. Returns the NIS. The fix is compared with the filter's own position and
    /// velocity at the fix's time ([`GnssFilter::record`]), and the correction applied now
    /// (the error is taken as constant over the lag: the velocity error times a 0.4 s lag is
    /// centimetres). A fix older than the history, or newer than the step, is moved to the
    /// step instead ([`GnssFilter::fix_at_step`], with the current attitude `q_nb` and body
    /// rate `w_nb_b`), which holds only while the acceleration is steady: at a turn entry
    /// (0 to 2 g within 1 s) that extrapolation over 0.4 s is off by metres per second.
    pub fn update_gnss(
        &mut self,
        cfg: &PositionFilterConfig,
        fix: &GnssFix,
        lag_s: f64,
        q_nb: &UnitQuaternion<f64>,
        w_nb_b: &Vector3<f64>,
    ) -> Result<f64, UpdateRejection> {
        let innov_at = match (lag_s > 0.0).then(|| self.state_at(fix.t_us)).flatten() {
            Some((pos, v_n)) => (fix.pos, fix.v_ned_mps, pos, v_n),
            None => {
                let (fix_pos, fix_v) = self.fix_at_step(fix, lag_s, q_nb, w_nb_b);
                (fix_pos, fix_v, self.pos, self.v_n)
            }
        };
        let (fix_pos, fix_v, ins_pos, ins_v) = innov_at;
        let mut innov = SVector::<f64, 6>::zeros();
        innov.fixed_rows_mut::<3>(0).copy_from(&(fix_v - ins_v));
        innov
            .fixed_rows_mut::<3>(3)
            .copy_from(&ned_offset_m(&ins_pos, &fix_pos));
        let mut h = SMatrix::<f64, 6, NX>::zeros();
        h.fixed_view_mut::<3, 3>(0, V).fill_with_identity();
        h.fixed_view_mut::<3, 3>(3, P).fill_with_identity();
        // The receiver's σ when it reports a larger one than configured.
        let larger = |cfg_sigma: f64, reported: f64| {
            if reported.is_finite() && reported > cfg_sigma {
                reported
            } else {
                cfg_sigma
            }
        };
        let s_vel = larger(cfg.gnss_sigma_vel_mps, fix.sigma_vel_mps);
        let s_hor = larger(cfg.gnss_sigma_hor_m, fix.sigma_hor_m);
        let s_ver = larger(cfg.gnss_sigma_ver_m, fix.sigma_ver_m);
        let r = SVector::<f64, 6>::from([
            s_vel * s_vel,
            s_vel * s_vel,
            s_vel * s_vel,
            s_hor * s_hor,
            s_hor * s_hor,
            s_ver * s_ver,
        ]);
        let c = ekf::update(&mut self.p, &h, &r, &innov, Some(cfg.gnss_gate_chi2))?;
        self.apply(&c.dx);
        Ok(c.nis)
    }

    fn apply(&mut self, dx: &SVector<f64, NX>) {
        displace(&mut self.pos, &dx.fixed_rows::<3>(P).into_owned());
        self.v_n += dx.fixed_rows::<3>(V);
        self.f_b += dx.fixed_rows::<3>(F);
        self.e_acc += dx.fixed_rows::<3>(EA);
    }

    /// Geodetic position.
    pub fn pos(&self) -> Geodetic {
        self.pos
    }
    /// NED ground velocity, m/s.
    pub fn v_n(&self) -> Vector3<f64> {
        self.v_n
    }
    /// Specific force estimate, body, m/s².
    pub fn f_b(&self) -> Vector3<f64> {
        self.f_b
    }
    /// Accelerometer error estimate, m/s².
    pub fn e_acc(&self) -> Vector3<f64> {
        self.e_acc
    }
    /// Error-state covariance `[δp_NED, δv, δf, δE_acc]` (tests).
    #[cfg(test)]
    pub fn covariance(&self) -> &SMatrix<f64, NX, NX> {
        &self.p
    }
    /// NED position covariance, m².
    pub fn position_cov(&self) -> Matrix3<f64> {
        self.p.fixed_view::<3, 3>(P, P).into_owned()
    }
    /// NED velocity covariance, (m/s)².
    pub fn velocity_cov(&self) -> Matrix3<f64> {
        self.p.fixed_view::<3, 3>(V, V).into_owned()
    }
    /// Accelerometer-error covariance, (m/s²)².
    pub fn e_acc_cov(&self) -> Matrix3<f64> {
        self.p.fixed_view::<3, 3>(EA, EA).into_owned()
    }
    /// Position covariance with the GNSS bias the filter does not estimate, m².
    pub fn position_cov_with_bias(&self, cfg: &PositionFilterConfig) -> Matrix3<f64> {
        self.position_cov() + Matrix3::identity() * cfg.gnss_bias_sigma_m.powi(2)
    }
}
