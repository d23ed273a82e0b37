//! Position filter with GNSS (docs/REFERENCES.md A1.6, `filter_gps01`), the GNSS-phase estimates of
//! the pressure offset and the low-frequency wind (A1.6), and the GNSS-denied propagation
//! (A1.7, `filter_pos` + `filter_pos02B`).
//!
//! **GNSS filter.** Nominal state: geodetic position, NED velocity `v_n`, specific force
//! `f_ib_b`, accelerometer error `E_acc`. Process (explicit Euler as the authors):
//! `ṗ = geodetic_rates(v)`, `v̇ = C_nb f + g − (2 w_ie + w_en) × v`, `ḟ = 0`, `Ė_acc = 0`.
//! Observations: every IMU step `f̃ = f + E_acc` (fast), and at each fix GNSS velocity and
//! position (slow; the authors' dual-rate EKF). The authors' filter keeps (λ, φ, h) as
//! additive states; here the 12 error states are `[δp_NED (m), δv, δf, δE_acc]`, a diagonal
//! change of variables (`δp_N = (M+h)δφ`, `δp_E = (N+h)cos φ δλ`, `δp_D = −δh`) that makes
//! the position covariance metric and well conditioned. `A` is the authors' plus the Coriolis
//! term in `A_vv = −[2 w_ie + w_en]×`; `F = expm(AΔt)` is evaluated in closed form (series in
//! `Ω = [2 w_ie + w_en]×` up to `Ω²`; error `O((|Ω|Δt)³)` ≈ 1e-18).
//!
//! **GNSS phase.** Every step `Δp = LPF(Δp(ΔT̂, Ĥp, H(ĥ)))` and
//! `v_lf = LPF(v̂ − C_nb v_TAS^b(V̂, α̂, β̂))`, both initialised with their first raw value;
//! the turbulence intensity from the raw wind's deviation from `v_lf`.
//!
//! **GNSS-denied.** The 6-state EKF `[f_ib_b, E_acc]` (`F = I`, `y = f̃`, `H = [I I]`) starts
//! from the GNSS filter's blocks; Δp and the wind are frozen; `v_n = v_lf + C_nb v_TAS^b`;
//! `h = h(Hp, ΔT̂, Δp)`; latitude and longitude are Euler-integrated with the previous step's
//! radii. Covariances: velocity and horizontal position from the dead-reckoning error model
//! `δv = δw + C_nb (δg + δb) + δv_air` (frozen-wind error, Gauss–Markov gust with the
//! turbulence intensity measured while GNSS is available, air-velocity bias, white air-velocity
//! error; [`DeniedNav`], docs/INS.md); vertical = the barometric altitude's first-order
//! variance from `Hp`, `ΔT` and the frozen `Δp`.

use std::collections::VecDeque;

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use super::air_data;
use super::config::{AirDataFilterConfig, PositionFilterConfig};
use super::ekf::{self, UpdateRejection, WindowMean};
use crate::env::atmosphere::{self, AtmosphereOffsets};
use crate::math::so3;
use crate::math::wgs84::{self, Geodetic};
use crate::sensors::GnssFix;

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

/// Low-pass estimates of the pressure offset and the low-frequency wind while GNSS is
/// available, with their (first-order, low-passed) variances.
#[derive(Debug, Clone)]
pub(crate) struct GnssPhaseEstimates {
    delta_p_pa: WindowMean<f64>,
    delta_p_var: WindowMean<f64>,
    wind_n: WindowMean<Vector3<f64>>,
    wind_cov: WindowMean<Matrix3<f64>>,
    /// `C_nb` through the same window as the wind: the attitude at which the wind estimate
    /// absorbed the air-data biases and the turbulence.
    c_nb: WindowMean<Matrix3<f64>>,
    /// The NED air velocity `C_nb v_TAS^b` through the same window: an attitude error `δθ_n`
    /// put `−[v̄_air]× δθ_n` into the wind estimate.
    v_air_n: WindowMean<Vector3<f64>>,
    /// Moments of the raw wind in body axes over the same window, from which the gust
    /// variance is the raw wind's spread about the window's mean ([`GustMoments`]).
    gust_moments: WindowMean<GustMoments>,
    /// Turbulence integral scales along the body axes, m.
    gust_scale_m: [f64; 3],
}

/// Do not measure the turbulence before the wind low-pass has averaged this long, s (its
/// deviation is then a small, poorly known fraction of the gust).
const GUST_MIN_AVERAGING_S: f64 = 10.0;
/// Smallest fraction `1 − var m` of a gust's variance that the spread about a window's mean
/// is taken to show (a window much shorter than the gust's correlation time sees little of it).
const GUST_MIN_SEEN_FRACTION: f64 = 0.05;

/// Per-sample moments of the raw wind `r` with the attitude `C = C_nb`, whose window means
/// give the mean square of `(Cᵀ (r − m))_k` about any `m`:
/// `⟨b_k²⟩ − 2 mᵀ⟨b_k c_k⟩ + mᵀ⟨c_k c_kᵀ⟩ m`, with `b = Cᵀ r` and `c_k` the k-th body axis in
/// NED (the k-th column of `C`). Columns: `b_k²` (0), `b_k c_k` (1 + k), `c_k c_kᵀ` (4 + 3k..).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GustMoments(SMatrix<f64, 3, 13>);

impl GustMoments {
    fn zeros() -> Self {
        Self(SMatrix::zeros())
    }

    fn of_sample(c_nb: &Matrix3<f64>, wind_n: &Vector3<f64>) -> Self {
        let b = c_nb.transpose() * wind_n;
        let mut m = SMatrix::<f64, 3, 13>::zeros();
        m.set_column(0, &b.component_mul(&b));
        for k in 0..3 {
            let c_k = c_nb.column(k).into_owned();
            m.set_column(1 + k, &(c_k * b[k]));
            m.fixed_view_mut::<3, 3>(0, 4 + 3 * k)
                .copy_from(&(c_k * c_k.transpose()));
        }
        Self(m)
    }

    /// Mean square deviation of the body-axis raw wind from `mean_n`, per body axis.
    fn spread_b(&self, mean_n: &Vector3<f64>) -> Vector3<f64> {
        let m = &self.0;
        Vector3::from_fn(|k, _| {
            let cross = mean_n.dot(&m.column(1 + k));
            let quad = (mean_n.transpose() * m.fixed_view::<3, 3>(0, 4 + 3 * k) * mean_n)[(0, 0)];
            (m[(k, 0)] - 2.0 * cross + quad).max(0.0)
        })
    }
}

impl std::ops::Add for GustMoments {
    type Output = Self;
    fn add(self, rhs: Self) -> Self {
        Self(self.0 + rhs.0)
    }
}

impl std::ops::Mul<f64> for GustMoments {
    type Output = Self;
    fn mul(self, rhs: f64) -> Self {
        Self(self.0 * rhs)
    }
}

/// Correlation time `L/V` of the turbulence of integral scale `scale_m`, s (airspeed floored
/// at 1 m/s: at rest there is no flight through the field).
fn gust_tau_s(scale_m: f64, tas_mps: f64) -> f64 {
    scale_m / tas_mps.max(1.0)
}

/// A unit-variance exponentially correlated gust `g` (correlation time `τ_c`) averaged over
/// the last `W` seconds, `m = (1/W) ∫ g`, with `r = τ_c/W`, `ε = e^{−1/r}`:
/// `var m = 2r (1 − r(1 − ε))`, `cov(g_now, m) = r (1 − ε)`, and the deviation of the latest
/// sample from the mean `var(g_now − m) = 1 − 2 cov + var m = 1 + 2rε − 2r²(1 − ε)`.
/// (For a first-order filter `τ_f` the first two are both `τ_c/(τ_c + τ_f)`: a window holds
/// the latest gusts half as strongly as its noise-equivalent filter `τ_f = W/2`.)
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GustInWindow {
    pub mean_var: f64,
    pub cov_with_latest: f64,
    pub deviation_var: f64,
}

impl GustInWindow {
    pub fn new(tau_c_s: f64, window_s: f64) -> Self {
        let averaging = window_s > 0.0 && tau_c_s > 0.0;
        if !averaging {
            // No averaging yet (or a white gust): the mean is the latest sample.
            return Self {
                mean_var: if tau_c_s > 0.0 { 1.0 } else { 0.0 },
                cov_with_latest: if tau_c_s > 0.0 { 1.0 } else { 0.0 },
                deviation_var: if tau_c_s > 0.0 { 0.0 } else { 1.0 },
            };
        }
        let r = tau_c_s / window_s;
        let one_minus_eps = -(-1.0 / r).exp_m1();
        let cov = r * one_minus_eps;
        let var = 2.0 * r * (1.0 - cov);
        Self {
            mean_var: var,
            cov_with_latest: cov,
            deviation_var: 1.0 - 2.0 * cov + var,
        }
    }
}

/// Raw pressure offset from the GNSS-filter altitude and its first-order variance.
///
/// `Δp = p(Hp_MSL) − p₀` with `G(Hp_MSL) = G(Hp) − H(h)` (`G` the geopotential integral of
/// `atmosphere`, slope `G' = T/T_ISA`): `∂Hp_MSL/∂H = −1/G'(Hp_MSL)`,
/// `∂Hp_MSL/∂Hp = G'(Hp)/G'(Hp_MSL)`, `∂Δp/∂Hp_MSL = dp/dHp(Hp_MSL)`, `dH/dh ≈ 1`.
fn raw_delta_p(hp_m: f64, var_hp: f64, h_m: f64, var_h: f64, delta_t_k: f64) -> (f64, f64) {
    let geopotential = atmosphere::geopotential_from_geometric_m(h_m);
    let dp = atmosphere::delta_p_pa(hp_m, geopotential, delta_t_k);
    let hp_msl = atmosphere::pressure_altitude_m(atmosphere::P0_PA + dp);
    let off = AtmosphereOffsets {
        delta_t_k,
        delta_p_pa: dp,
    };
    let g_msl = atmosphere::geopotential_derivative(hp_msl, &off);
    let g_hp = atmosphere::geopotential_derivative(hp_m, &off);
    let dpdm = atmosphere::pressure_derivative_pa_per_m(hp_msl);
    let d_dh = dpdm / g_msl;
    let d_dhp = dpdm * g_hp / g_msl;
    (dp, d_dh * d_dh * var_h + d_dhp * d_dhp * var_hp)
}

impl GnssPhaseEstimates {
    /// Start both estimates at their first raw values (moving averages over `window_s`,
    /// running means until the window is full).
    #[expect(
        clippy::too_many_arguments,
        reason = "the first raw value of each estimate and its variance, each from a different \
                  part of the INS state at the call"
    )]
    pub fn new(
        window_s: f64,
        gust_scale_m: [f64; 3],
        q_nb: &UnitQuaternion<f64>,
        hp_m: f64,
        var_hp: f64,
        h_m: f64,
        var_h: f64,
        delta_t_k: f64,
        wind_n: Vector3<f64>,
        wind_cov: Matrix3<f64>,
        v_air_n: Vector3<f64>,
    ) -> Self {
        let (dp, dp_var) = raw_delta_p(hp_m, var_hp, h_m, var_h, delta_t_k);
        Self {
            delta_p_pa: WindowMean::new(window_s, dp),
            delta_p_var: WindowMean::new(window_s, dp_var),
            wind_n: WindowMean::new(window_s, wind_n),
            wind_cov: WindowMean::new(window_s, wind_cov),
            c_nb: WindowMean::new(window_s, q_nb.to_rotation_matrix().into_inner()),
            v_air_n: WindowMean::new(window_s, v_air_n),
            gust_moments: WindowMean::new(window_s, GustMoments::zeros()),
            gust_scale_m,
        }
    }

    /// Turbulence seen while GNSS is available: per body axis its variance σ², and the
    /// fractions of it in the wind average at this moment ([`GustInWindow`]).
    ///
    /// The variance is the raw wind's mean square deviation from the window's mean, per body
    /// axis, over the window: for a unit exponentially correlated gust its expectation is
    /// `1 − var m` (the window's time average of `var(g − m) = 1 − 2 cov(g, m) + var m`, and
    /// `cov(g, m)` averages to `var m`). A wind that changed more than one window ago (the
    /// climb, a take-off roll, a step) is then not taken for turbulence; one inside the window
    /// is, as the wind estimate is then that much less certain.
    pub fn gust(&self, tas_mps: f64) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let w = self.wind_n.covered_s();
        let f = |i: usize| GustInWindow::new(gust_tau_s(self.gust_scale_m[i], tas_mps), w);
        let fr = [f(0), f(1), f(2)];
        let var = if w >= GUST_MIN_AVERAGING_S {
            let spread = self.gust_moments.value().spread_b(&self.wind_n.value());
            Vector3::from_fn(|i, _| spread[i] / (1.0 - fr[i].mean_var).max(GUST_MIN_SEEN_FRACTION))
        } else {
            Vector3::zeros()
        };
        (
            var,
            Vector3::from_fn(|i, _| fr[i].mean_var),
            Vector3::from_fn(|i, _| fr[i].cov_with_latest),
        )
    }

    /// Low-passed attitude `C_nb` (not orthonormal after turns).
    pub fn c_nb_lpf(&self) -> Matrix3<f64> {
        self.c_nb.value()
    }

    /// Mean NED air velocity over the wind's window, m/s.
    pub fn v_air_n_mean(&self) -> Vector3<f64> {
        self.v_air_n.value()
    }

    /// One step of `dt_s`: the raw Δp from the air data and the filter's height, the raw wind
    /// from the filter's ground velocity and the air velocity. Non-finite raw values are
    /// skipped (the filters hold), so a transient numerical problem cannot poison the frozen
    /// values.
    pub fn step(&mut self, dt_s: f64, air: &AirInputs, gnss: &GnssFilterState) {
        let (q_nb, tas_mps, v_air_n) = (&air.q_nb, air.tas_mps, air.v_air_n);
        let wind_n = gnss.v_n - air.v_air_n;
        let wind_cov = gnss.v_cov + air.v_air_cov;
        let (dp, dp_var) = raw_delta_p(
            air.hp_m,
            air.t_hp_cov[(1, 1)],
            gnss.h_m,
            gnss.var_h_m2,
            air.delta_t_k,
        );
        if dp.is_finite() && dp_var.is_finite() {
            self.delta_p_pa.step(dp, dt_s);
            self.delta_p_var.step(dp_var, dt_s);
        }
        let finite = wind_n
            .iter()
            .chain(wind_cov.iter())
            .chain(v_air_n.iter())
            .all(|v| v.is_finite());
        if finite && tas_mps.is_finite() {
            let c_nb = q_nb.to_rotation_matrix().into_inner();
            self.wind_n.step(wind_n, dt_s);
            self.wind_cov.step(wind_cov, dt_s);
            self.c_nb.step(c_nb, dt_s);
            self.v_air_n.step(v_air_n, dt_s);
            self.gust_moments
                .step(GustMoments::of_sample(&c_nb, &wind_n), dt_s);
        }
    }

    /// Pressure offset Δp, Pa, and its variance, Pa².
    pub fn delta_p(&self) -> (f64, f64) {
        (self.delta_p_pa.value(), self.delta_p_var.value())
    }

    /// Low-frequency wind `v_lf_n`, m/s, and its covariance.
    pub fn wind(&self) -> (Vector3<f64>, Matrix3<f64>) {
        (self.wind_n.value(), self.wind_cov.value())
    }
}

/// Barometric geometric altitude `h(Hp, ΔT, Δp)` and its partial derivatives
/// `(∂h/∂Hp, ∂h/∂ΔT, ∂h/∂Δp)` (docs/REFERENCES.md A3.1–A3.2).
///
/// `H` is linear in ΔT, so `∂H/∂ΔT = H(ΔT = 1) − H(ΔT = 0)` exactly;
/// `∂H/∂Hp = G'(Hp)`, `∂H/∂Δp = −G'(Hp_MSL)/(dp/dHp)(Hp_MSL)`; `dh/dH = (R/(R − H))²`.
pub(crate) fn baro_altitude(hp_m: f64, delta_t_k: f64, delta_p_pa: f64) -> (f64, Vector3<f64>) {
    let off = AtmosphereOffsets {
        delta_t_k,
        delta_p_pa,
    };
    let geo = atmosphere::geopotential_from_pressure_altitude_m(hp_m, &off);
    let h = atmosphere::geometric_from_geopotential_m(geo);
    let r = atmosphere::R_GEOPOTENTIAL_M;
    let dh_dgeo = (r / (r - geo)).powi(2);
    let at = |dt: f64| {
        atmosphere::geopotential_from_pressure_altitude_m(
            hp_m,
            &AtmosphereOffsets {
                delta_t_k: dt,
                delta_p_pa,
            },
        )
    };
    let d_dt = at(1.0) - at(0.0);
    let hp_msl = atmosphere::pressure_altitude_m(atmosphere::P0_PA + delta_p_pa);
    let d_dp = -atmosphere::geopotential_derivative(hp_msl, &off)
        / atmosphere::pressure_derivative_pa_per_m(hp_msl);
    let d_dhp = atmosphere::geopotential_derivative(hp_m, &off);
    (h, Vector3::new(d_dhp, d_dt, d_dp) * dh_dgeo)
}

/// Number of error states of the dead-reckoning covariance.
const NDR: usize = 15;
/// Offsets in it: NED position, frozen-wind error, gust (body), air-velocity bias (body),
/// attitude error (NED).
const DR_P: usize = 0;
const DR_W: usize = 3;
const DR_G: usize = 6;
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
    p_dr: SMatrix<f64, NDR, NDR>,
    /// Turbulence variance per body axis, (m/s)², and integral scales, m.
    gust_var_b: Vector3<f64>,
    gust_scale_m: [f64; 3],
    h_var: f64,
    v_cov: Matrix3<f64>,
    budget: DeniedBudget,
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
        let (wind_n, wind_cov) = est.wind();
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
        self.v_n = self.wind_n + v_air_n;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn init() -> PositionInit {
        PositionInit {
            pos: Geodetic {
                lat_rad: 0.78,
                lon_rad: -1.57,
                h_m: 1500.0,
            },
            v_n: Vector3::new(20.0, -15.0, 1.0),
            f_b: Vector3::new(0.2, 0.1, -9.8),
            e_acc: Vector3::new(0.1, -0.1, 0.05),
            e_acc_sigma: Vector3::repeat(1e-3),
        }
    }

    #[test]
    fn transition_matches_matrix_exponential() {
        let cfg = PositionFilterConfig {
            q_position_m2: 0.0,
            q_velocity_m2ps2: 0.0,
            q_specific_force_m2ps4: 0.0,
            q_e_acc_m2ps4: 0.0,
            ..PositionFilterConfig::default()
        };
        let mut f = GnssFilter::new(&cfg, &init());
        let mut p = SMatrix::<f64, NX, NX>::identity();
        for i in 0..NX {
            for j in 0..NX {
                p[(i, j)] += 0.2 / (1.0 + (i as f64 - j as f64).abs());
            }
        }
        f.p = p;
        let q_nb = so3::from_euler_zyx(0.4, 0.1, -0.2);
        let dt = 0.05;
        let w = wgs84::omega_ie_n(f.pos.lat_rad) * 2.0 + wgs84::omega_en_n(&f.pos, &f.v_n);
        let mut a = SMatrix::<f64, NX, NX>::zeros();
        a.fixed_view_mut::<3, 3>(P, V).fill_with_identity();
        a.fixed_view_mut::<3, 3>(V, V).copy_from(&(-so3::skew(&w)));
        a.fixed_view_mut::<3, 3>(V, F)
            .copy_from(&q_nb.to_rotation_matrix().into_inner());
        let big_f = (a * dt).exp();
        let expect = big_f * p * big_f.transpose();
        f.predict(&cfg, &q_nb, dt, 1.0);
        // Closed form is exact up to (|Ω|Δt)³ ≈ (1.5e-4·0.05)³ ≈ 4e-16 relative; the products
        // of 12×12 matrices round at ~1e-15 relative.
        assert!(
            (f.p - expect).norm() < 1e-13 * expect.norm(),
            "{}",
            f.p - expect
        );
    }

    #[test]
    fn air_velocity_jacobians_match_finite_differences() {
        let (v0, j) = v_tas_b(30.0, 0.06, -0.03);
        let e = 1e-6;
        for k in 0..3 {
            let mut a = [30.0, 0.06, -0.03];
            let mut b = a;
            a[k] += e;
            b[k] -= e;
            let fd = (v_tas_b(a[0], a[1], a[2]).0 - v_tas_b(b[0], b[1], b[2]).0) / (2.0 * e);
            // Truncation e²/6·|v'''| ≤ 30e-12; rounding ε·30/e ≈ 3e-9.
            assert!((fd - j.column(k)).norm() < 1e-8, "{k}");
        }
        assert!((v0.norm() - 30.0).abs() < 1e-12);
        // The attitude error of the dead reckoning: (Ĉ − C) v = [Ĉ v]× Ĉ δθ_b for
        // C = Ĉ Exp(δθ_b), to first order (second order |δθ|²·30/2 ≈ 1.5e-11 m/s).
        let q = so3::from_euler_zyx(1.0, 0.1, 0.3);
        let c = q.to_rotation_matrix().into_inner();
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = e;
            let diff = q * v0 - so3::plus(&q, &d) * v0;
            let model = so3::skew(&(c * v0)) * (c * d);
            assert!((diff - model).norm() < 1e-9, "{k}: {diff} vs {model}");
        }
        // The air-data part: Jacobian of v_TAS^b rotated to NED.
        let mut x = SVector::<f64, { air_data::NX }>::zeros();
        x[air_data::TAS] = 30.0;
        x[air_data::AOA] = 0.06;
        x[air_data::AOS] = -0.03;
        let mut p_air = SMatrix::<f64, { air_data::NX }, { air_data::NX }>::zeros();
        p_air[(air_data::TAS, air_data::TAS)] = 0.04;
        let (v_n, cov) = air_velocity_n(&q, &x, &p_air);
        let (vb, jb) = v_tas_b(30.0, 0.06, -0.03);
        assert!((v_n - c * vb).norm() < 1e-12);
        let col = c * jb.column(0);
        assert!((cov - col * col.transpose() * 0.04).norm() < 1e-12);
    }

    #[test]
    fn baro_altitude_derivatives_match_finite_differences() {
        let (hp, dt, dp) = (2500.0, 7.0, -900.0);
        let (h0, d) = baro_altitude(hp, dt, dp);
        let fd = |f: &dyn Fn(f64) -> f64, e: f64| (f(e) - f(-e)) / (2.0 * e);
        let d_hp = fd(&|e| baro_altitude(hp + e, dt, dp).0, 1e-2);
        let d_dt = fd(&|e| baro_altitude(hp, dt + e, dp).0, 1e-3);
        let d_dp = fd(&|e| baro_altitude(hp, dt, dp + e).0, 1e-1);
        // h is smooth on scales of km, K and kPa: truncation ≪ 1e-6, rounding ≈ ε·h/e ≈ 3e-11/e.
        assert!((d.x - d_hp).abs() < 1e-7, "{} {d_hp}", d.x);
        assert!((d.y - d_dt).abs() < 1e-6, "{} {d_dt}", d.y);
        assert!((d.z - d_dp).abs() < 1e-7, "{} {d_dp}", d.z);
        // Consistency with the atmosphere module.
        let off = AtmosphereOffsets {
            delta_t_k: dt,
            delta_p_pa: dp,
        };
        assert!((h0 - atmosphere::geometric_from_pressure_altitude_m(hp, &off)).abs() < 1e-9);
    }

    #[test]
    fn raw_delta_p_inverts_baro_altitude_and_its_variance_matches() {
        let (hp, dt, dp) = (2000.0, -5.0, 1200.0);
        let (h, d) = baro_altitude(hp, dt, dp);
        let (dp_back, var) = raw_delta_p(hp, 0.0, h, 1.0, dt);
        assert!((dp_back - dp).abs() < 1e-6, "{dp_back}");
        // 1 m² of altitude variance ↔ (∂Δp/∂h)² = 1/(∂h/∂Δp)² (dH/dh ≈ 1 to 5e-4).
        let expect = 1.0 / (d.z * d.z);
        assert!((var - expect).abs() < 2e-3 * expect, "{var} {expect}");
    }

    #[test]
    fn ned_offset_and_displace_are_inverse() {
        let mut p = init().pos;
        let from = p;
        let d = Vector3::new(80.0, -60.0, 5.0);
        displace(&mut p, &d);
        let back = ned_offset_m(&from, &p);
        // Second-order terms ≈ |d|²/R ≈ 1e4/6.4e6 ≈ 1.6e-3 m.
        assert!((back - d).norm() < 2e-3, "{back}");
    }

    /// The window fractions of a unit Gauss–Markov gust against many simulated windows
    /// (the latest sample and the mean of the last `W`, from the stationary start).
    #[test]
    fn gust_in_window_fractions_match_simulation() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut normal = move || crate::ins::tests::standard_normal(&mut rng);
        let (tau_c, w, dt, runs): (f64, f64, f64, u32) = (10.0, 30.0, 0.05, 4000);
        let a = (-dt / tau_c).exp();
        let steps = (w / dt) as usize;
        let (mut s_mm, mut s_gm, mut s_dd) = (0.0, 0.0, 0.0);
        for _ in 0..runs {
            let mut g = normal();
            let mut sum = 0.0;
            for _ in 0..steps {
                g = a * g + (1.0 - a * a).sqrt() * normal();
                sum += g;
            }
            let m = sum / steps as f64;
            s_mm += m * m;
            s_gm += g * m;
            s_dd += (g - m) * (g - m);
        }
        let n = f64::from(runs);
        let f = GustInWindow::new(tau_c, w);
        // Sample second moments of unit-scale Gaussians: standard error ≤ √(2/n); 5 of them.
        let tol = 5.0 * (2.0 / n).sqrt();
        for (got, want, what) in [
            (s_mm / n, f.mean_var, "var m"),
            (s_gm / n, f.cov_with_latest, "cov(g, m)"),
            (s_dd / n, f.deviation_var, "var(g − m)"),
        ] {
            assert!(
                (got - want).abs() < tol,
                "{what}: {got:.4} vs {want:.4} (tol {tol:.3})"
            );
        }
        // Far shorter than the window: the mean holds 2τ_c/W of the variance, the latest
        // sample τ_c/W of it (a first-order filter of W/2 would hold 2τ_c/W of both).
        let f = GustInWindow::new(1.0, 1000.0);
        assert!((f.mean_var - 2e-3).abs() < 1e-5 && (f.cov_with_latest - 1e-3).abs() < 1e-6);
    }

    /// Exponentially correlated (first-order Gauss–Markov) gusts along the body axes fed as
    /// the raw wind: the measured per-axis variance is the gusts' σ².
    /// GNSS-phase estimates fed only with a raw wind (fixed pressure altitude, height, ΔT and
    /// wind covariance): the wind and turbulence tests.
    fn wind_only_estimates(
        cfg: &PositionFilterConfig,
        q_nb: &UnitQuaternion<f64>,
        wind_n: Vector3<f64>,
        v_air_n: Vector3<f64>,
    ) -> GnssPhaseEstimates {
        GnssPhaseEstimates::new(
            cfg.lpf_window_s,
            cfg.turbulence_integral_scale_m,
            q_nb,
            2000.0,
            1.0,
            2100.0,
            1.0,
            5.0,
            wind_n,
            Matrix3::identity() * 0.01,
            v_air_n,
        )
    }

    fn step_wind_only(
        est: &mut GnssPhaseEstimates,
        dt_s: f64,
        q_nb: &UnitQuaternion<f64>,
        tas_mps: f64,
        wind_n: Vector3<f64>,
        v_air_n: Vector3<f64>,
    ) {
        est.step(
            dt_s,
            &air_inputs(q_nb, tas_mps, v_air_n),
            &GnssFilterState {
                h_m: 2100.0,
                var_h_m2: 1.0,
                v_n: wind_n + v_air_n,
                v_cov: Matrix3::identity() * 0.01,
            },
        );
    }

    #[test]
    fn gust_intensity_is_measured_from_the_raw_wind() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut normal = move || crate::ins::tests::standard_normal(&mut rng);
        let cfg = PositionFilterConfig::default();
        let scale = cfg.turbulence_integral_scale_m;
        let (tas, dt, t_end) = (30.0, 0.05, 20_000.0);
        let sigma = Vector3::new(0.9, 0.6, 0.5);
        let q_nb = so3::from_euler_zyx(2.0, 0.1, 0.3);
        let c_nb = q_nb.to_rotation_matrix().into_inner();
        let w0 = Vector3::new(5.0, -3.0, 0.0);
        let mut est = wind_only_estimates(&cfg, &q_nb, w0, c_nb * Vector3::new(tas, 0.0, 0.0));
        let a = Vector3::from_fn(|i, _| (-dt * tas / scale[i]).exp());
        let mut g = Vector3::from_fn(|i, _| sigma[i] * normal());
        let steps = (t_end / dt) as usize;
        // One estimate per window (each from that window's samples only), after the first.
        let per_window = (cfg.lpf_window_s / dt).round() as usize;
        let mut estimates: Vec<Vector3<f64>> = Vec::new();
        for k in 1..=steps {
            for i in 0..3 {
                g[i] = a[i] * g[i] + sigma[i] * (1.0 - a[i] * a[i]).sqrt() * normal();
            }
            let wind = w0 + c_nb * g;
            step_wind_only(
                &mut est,
                dt,
                &q_nb,
                tas,
                wind,
                c_nb * Vector3::new(tas, 0.0, 0.0),
            );
            if k % per_window == 0 && k > per_window {
                estimates.push(est.gust(tas).0);
            }
        }
        let (_, held_var, held_cov) = est.gust(tas);
        let n = estimates.len() as f64;
        for i in 0..3 {
            let tau_c = scale[i] / tas;
            // Unbiased: the mean of the window estimates within 5 standard errors of σ²
            // (the windows hold a few correlation times each, so they are nearly independent).
            let mean = estimates.iter().map(|e| e[i]).sum::<f64>() / n;
            let var_est = estimates.iter().map(|e| (e[i] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            let s2 = sigma[i] * sigma[i];
            assert!(
                (mean - s2).abs() < 5.0 * (var_est / n).sqrt(),
                "axis {i}: mean {mean} vs {s2} (standard error {})",
                (var_est / n).sqrt()
            );
            // And useful: one window's estimate scatters by less than σ² itself.
            assert!(
                var_est.sqrt() < s2,
                "axis {i}: scatter {} vs {s2}",
                var_est.sqrt()
            );
            // The window covers its length ± one 1-s bin; both fractions fall with it.
            let at = |w: f64| GustInWindow::new(tau_c, w);
            let (lo, hi) = (at(cfg.lpf_window_s + 1.0), at(cfg.lpf_window_s - 1.0));
            assert!((lo.mean_var..=hi.mean_var).contains(&held_var[i]), "{i}");
            assert!(
                (lo.cov_with_latest..=hi.cov_with_latest).contains(&held_cov[i]),
                "{i}"
            );
        }
    }

    #[test]
    fn a_wind_change_older_than_the_window_is_not_taken_for_turbulence() {
        // Circling in a steady wind, which steps by 6 m/s (a SITL setting the wind after the
        // climb, a front): while the window holds the step the wind estimate is that uncertain
        // and the spread says so; one window later the wind is steady again and no gust is left.
        let cfg = PositionFilterConfig::default();
        let (tas, dt) = (20.0, 0.01);
        let w0 = Vector3::new(1.0, -2.0, 0.0);
        let q_at = |t: f64| so3::from_euler_zyx(0.1 * t, 0.3, 0.05);
        let v_air =
            |t: f64| q_at(t).to_rotation_matrix().into_inner() * Vector3::new(tas, 0.0, 0.0);
        let mut est = wind_only_estimates(&cfg, &q_at(0.0), w0, v_air(0.0));
        let mut t = 0.0;
        let mut fly = |until_s: f64, wind: Vector3<f64>, est: &mut GnssPhaseEstimates| {
            while t < until_s {
                t += dt;
                step_wind_only(est, dt, &q_at(t), tas, wind, v_air(t));
            }
        };
        fly(200.0, w0, &mut est);
        assert!(est.gust(tas).0.max() < 1e-9, "{}", est.gust(tas).0);
        let w1 = w0 + Vector3::new(6.0, 0.0, 0.0);
        fly(260.0, w1, &mut est);
        let inside = est.gust(tas).0;
        assert!(inside.x + inside.y > 1.0, "{inside}");
        fly(260.0 + cfg.lpf_window_s + 2.0, w1, &mut est);
        let after = est.gust(tas).0;
        assert!(after.max() < 1e-9, "{after}");
        assert!((est.wind().0 - w1).norm() < 1e-9);
    }

    /// A GNSS filter with zero covariance, the air-data bias σ's zeroed and a 30 m/s air
    /// state: the dead-reckoning tests switch on one error source at a time.
    fn denied_setup() -> (
        PositionFilterConfig,
        AirDataFilterConfig,
        SVector<f64, { air_data::NX }>,
        GnssFilter,
    ) {
        let cfg = PositionFilterConfig {
            q_position_m2: 0.0,
            ..PositionFilterConfig::default()
        };
        let mut f = GnssFilter::new(&cfg, &init());
        f.p = SMatrix::zeros();
        let air_cfg = AirDataFilterConfig {
            tas_bias_sigma_mps: 0.0,
            aoa_bias_sigma_deg: 0.0,
            aos_bias_sigma_deg: 0.0,
            ..AirDataFilterConfig::default()
        };
        let mut air_x = SVector::<f64, { air_data::NX }>::zeros();
        air_x[air_data::TAS] = 30.0;
        (cfg, air_cfg, air_x, f)
    }

    /// GNSS-phase estimates of a calm wind, started with the NED air velocity `v_air_n`.
    fn calm_estimates(cfg: &PositionFilterConfig, v_air_n: Vector3<f64>) -> GnssPhaseEstimates {
        GnssPhaseEstimates::new(
            cfg.lpf_window_s,
            cfg.turbulence_integral_scale_m,
            &UnitQuaternion::identity(),
            2000.0,
            1.0,
            2100.0,
            1.0,
            5.0,
            Vector3::zeros(),
            Matrix3::zeros(),
            v_air_n,
        )
    }

    /// `n` dead-reckoning steps of `dt_s` at 30 m/s with attitude `q_nb`, air velocity
    /// `v_air_n` and no air-data noise.
    /// Air data at 2,000 m of pressure altitude, ΔT 5 K, unit `[T, Hp]` covariance and no
    /// white air-velocity uncertainty.
    fn air_inputs(q_nb: &UnitQuaternion<f64>, tas_mps: f64, v_air_n: Vector3<f64>) -> AirInputs {
        AirInputs {
            q_nb: *q_nb,
            tas_mps,
            hp_m: 2000.0,
            delta_t_k: 5.0,
            t_hp_cov: Matrix2::identity(),
            v_air_n,
            v_air_cov: Matrix3::zeros(),
        }
    }

    fn propagate_steps(
        nav: &mut DeniedNav,
        cfg: &PositionFilterConfig,
        q_nb: &UnitQuaternion<f64>,
        v_air_n: &Vector3<f64>,
        dt_s: f64,
        n: usize,
    ) {
        for _ in 0..n {
            nav.propagate(
                cfg,
                &air_inputs(q_nb, 30.0, *v_air_n),
                SubSteps {
                    dt_s,
                    n: 1,
                    q_scale: 1.0,
                },
            );
        }
    }

    /// With only the gust uncertain, the dead-reckoning position variance along a straight
    /// leg is that of an integrated Gauss–Markov process, `2σ²τ (T − τ (1 − e^{−T/τ}))`, and
    /// the velocity variance stays σ².
    #[test]
    fn dead_reckoning_integrates_the_gust_as_a_gauss_markov_process() {
        let (cfg, air_cfg, air_x, f) = denied_setup();
        let est = calm_estimates(&cfg, Vector3::new(30.0, 0.0, 0.0));
        let mut nav = DeniedNav::new(
            &cfg,
            &air_cfg,
            &air_x,
            [false; 2],
            &Matrix3::zeros(),
            &f,
            &est,
        );
        let sigma2 = Vector3::new(0.81, 0.36, 0.25);
        nav.gust_var_b = sigma2;
        nav.p_dr = SMatrix::zeros();
        nav.p_dr
            .fixed_view_mut::<3, 3>(DR_G, DR_G)
            .copy_from(&Matrix3::from_diagonal(&sigma2));
        // Heading 90°: body x is east, body y is south.
        let q_nb = so3::from_euler_zyx(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        let (dt, t_end) = (0.01, 200.0);
        let east_air = Vector3::new(0.0, 30.0, 0.0);
        propagate_steps(&mut nav, &cfg, &q_nb, &east_air, dt, (t_end / dt) as usize);
        let p = nav.position_cov();
        let gm = |s2: f64, tau: f64| 2.0 * s2 * tau * (t_end - tau * (1.0 - (-t_end / tau).exp()));
        let scale = cfg.turbulence_integral_scale_m;
        let east = gm(sigma2.x, scale[0] / 30.0);
        let north = gm(sigma2.y, scale[1] / 30.0);
        // Discretisation: the position is integrated with the start-of-step gust, a relative
        // error of order Δt/τ ≤ 0.01/4.4.
        assert!(
            (p[(1, 1)] / east - 1.0).abs() < 5e-3,
            "{} {east}",
            p[(1, 1)]
        );
        assert!(
            (p[(0, 0)] / north - 1.0).abs() < 5e-3,
            "{} {north}",
            p[(0, 0)]
        );
        assert!(p[(0, 1)].abs() < 1e-9 * east);
        let v = nav.velocity_cov();
        assert!((v[(1, 1)] / sigma2.x - 1.0).abs() < 1e-9, "{}", v[(1, 1)]);
        assert!((v[(0, 0)] / sigma2.y - 1.0).abs() < 1e-9, "{}", v[(0, 0)]);
        assert!((v[(2, 2)] / sigma2.z - 1.0).abs() < 1e-9, "{}", v[(2, 2)]);
    }

    /// A heading error present while the wind was averaged (wind estimated on a northbound
    /// leg at 30 m/s) cancels on that heading and doubles on the reverse one: velocity σ east
    /// 2·30 m/s·σ_ψ, position σ growing linearly with it.
    #[test]
    fn a_heading_error_absorbed_by_the_wind_cancels_on_its_heading_and_doubles_reversed() {
        let (cfg, air_cfg, air_x, f) = denied_setup();
        let north = Vector3::new(30.0, 0.0, 0.0);
        let mut est = calm_estimates(&cfg, north);
        let q_north = UnitQuaternion::identity();
        for _ in 0..1500 {
            est.step(
                0.1,
                &air_inputs(&q_north, 30.0, north),
                &GnssFilterState {
                    h_m: 2100.0,
                    var_h_m2: 1.0,
                    v_n: north,
                    v_cov: Matrix3::zeros(),
                },
            );
        }
        let sigma_psi = 1f64.to_radians();
        let att_cov_n = Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, sigma_psi.powi(2)));
        let fly = |q: UnitQuaternion<f64>, v_air: Vector3<f64>| {
            let mut nav = DeniedNav::new(&cfg, &air_cfg, &air_x, [false; 2], &att_cov_n, &f, &est);
            nav.gust_var_b = Vector3::zeros();
            nav.p_dr.fixed_view_mut::<3, 3>(DR_G, DR_G).fill(0.0);
            nav.p_dr.fixed_view_mut::<3, 3>(DR_P, DR_P).fill(0.0);
            propagate_steps(&mut nav, &cfg, &q, &v_air, 0.1, 1000);
            (nav.velocity_cov(), nav.position_cov())
        };
        let (v, p) = fly(q_north, north);
        assert!(
            v.norm() < 1e-9 && p.fixed_view::<2, 2>(0, 0).norm() < 1e-6,
            "{v} {p}"
        );
        let south = so3::from_euler_zyx(std::f64::consts::PI, 0.0, 0.0);
        let (v, p) = fly(south, -north);
        let sv = 2.0 * 30.0 * sigma_psi;
        assert!(
            (v[(1, 1)].sqrt() / sv - 1.0).abs() < 1e-9,
            "{}",
            v[(1, 1)].sqrt()
        );
        assert!(v[(0, 0)].abs() < 1e-9);
        assert!(
            (p[(1, 1)].sqrt() / (sv * 100.0) - 1.0).abs() < 1e-9,
            "{}",
            p[(1, 1)].sqrt()
        );
    }

    /// A fix 0.1 s old in a 0.74 rad/s level turn at 30 m/s (2.3 g): moved forward with the
    /// INS's acceleration its velocity matches the current one within 0.01 m/s (third-order
    /// term a·ω²·lag³/6 ≈ 2e-3 m/s), while the raw fix velocity is 2.2 m/s off — 30 times the
    /// GNSS velocity σ, which would gate the fix.
    #[test]
    fn lagged_fix_velocity_is_moved_forward_with_the_ins_acceleration() {
        let cfg = PositionFilterConfig::default();
        let (tas, omega, lag) = (30.0, 0.74, 0.1);
        let psi = 0.6;
        let pos = init().pos;
        let v_at = |psi: f64| Vector3::new(tas * psi.cos(), tas * psi.sin(), 0.0);
        let v_now = v_at(psi);
        let a_n = Vector3::new(-psi.sin(), psi.cos(), 0.0) * (tas * omega);
        let g_n = wgs84::gravity_ned_mps2(&pos);
        let bank = (tas * omega / g_n.z).atan();
        let q_nb = so3::from_euler_zyx(psi, 0.0, bank);
        let c_nb = q_nb.to_rotation_matrix().into_inner();
        let coriolis =
            (wgs84::omega_ie_n(pos.lat_rad) * 2.0 + wgs84::omega_en_n(&pos, &v_now)).cross(&v_now);
        let f_b = c_nb.transpose() * (a_n - g_n + coriolis);
        let w_nb_b = c_nb.transpose() * Vector3::new(0.0, 0.0, omega);
        let mut filter = GnssFilter::new(
            &cfg,
            &PositionInit {
                pos,
                v_n: v_now,
                f_b,
                e_acc: Vector3::zeros(),
                e_acc_sigma: Vector3::repeat(1e-3),
            },
        );
        // The fix: where the aircraft was `lag` earlier on the circle.
        let psi_fix = psi - omega * lag;
        let chord =
            Vector3::new(psi.sin() - psi_fix.sin(), psi_fix.cos() - psi.cos(), 0.0) * (tas / omega);
        let mut fix_pos = pos;
        displace(&mut fix_pos, &(-chord));
        let fix = GnssFix {
            t_us: 0,
            pos: fix_pos,
            v_ned_mps: v_at(psi_fix),
            sigma_hor_m: f64::NAN,
            sigma_ver_m: f64::NAN,
            sigma_vel_mps: f64::NAN,
        };
        let raw = (fix.v_ned_mps - v_now).norm();
        assert!(raw > 2.0, "{raw}");
        let (p, v) = filter.fix_at_step(&fix, lag, &q_nb, &w_nb_b);
        assert!((v - v_now).norm() < 0.01, "{}", (v - v_now).norm());
        assert!(
            ned_offset_m(&pos, &p).norm() < 0.01,
            "{}",
            ned_offset_m(&pos, &p)
        );
        // Without the compensation the velocity alone gives a NIS far beyond the gate.
        let s_vel = filter.velocity_cov()[(0, 0)] + cfg.gnss_sigma_vel_mps.powi(2);
        assert!(raw * raw / s_vel > 10.0 * cfg.gnss_gate_chi2);
        let nis = filter
            .update_gnss(&cfg, &fix, lag, &q_nb, &w_nb_b)
            .expect("fused");
        assert!(nis < 0.1, "{nis}");
    }

    /// A turn entry (lateral acceleration from 0 to 2 g in 0.5 s, then held) seen by a fix
    /// 0.4 s old — ArduPlane's GPS_RAW_INT arrives that late at 40 Hz IMU. Compared with the
    /// filter's own state at the fix's time the innovation is nil; moved forward with the
    /// current acceleration instead, the velocity is 1.8 m/s off and the fix is gated.
    #[test]
    fn a_lagged_fix_at_a_turn_entry_is_compared_with_the_state_at_its_time() {
        let cfg = PositionFilterConfig::default();
        let (speed, a_max, ramp_s, lag_s, dt_s) = (30.0, 2.0 * 9.81, 0.5, 0.4, 0.025);
        let accel = |t: f64| a_max * (t / ramp_s).clamp(0.0, 1.0);
        // Lateral (east) velocity: the integral of the ramp; north speed held.
        let v_east = |t: f64| {
            let t = t.max(0.0);
            if t < ramp_s {
                a_max * t * t / (2.0 * ramp_s)
            } else {
                a_max * ramp_s / 2.0 + a_max * (t - ramp_s)
            }
        };
        let start = init().pos;
        let state = |t: f64| {
            let v = Vector3::new(speed, v_east(t), 0.0);
            // East displacement: the integral of v_east (exact for both pieces).
            let e = if t < ramp_s {
                a_max * t.powi(3) / (6.0 * ramp_s)
            } else {
                a_max * ramp_s.powi(2) / 6.0
                    + a_max * ramp_s / 2.0 * (t - ramp_s)
                    + a_max * (t - ramp_s).powi(2) / 2.0
            };
            let mut pos = start;
            displace(&mut pos, &Vector3::new(speed * t, e, 0.0));
            (pos, v)
        };
        let now_s = 0.6;
        let (pos, v_n) = state(now_s);
        let g_n = wgs84::gravity_ned_mps2(&pos);
        let f_b = Vector3::new(0.0, accel(now_s), 0.0) - g_n;
        let init_at_now = PositionInit {
            pos,
            v_n,
            f_b,
            e_acc: Vector3::zeros(),
            e_acc_sigma: Vector3::repeat(1e-3),
        };
        let mut filter = GnssFilter::new(&cfg, &init_at_now);
        // The history of the flown states, one per IMU step up to the one before now.
        let steps = (now_s / dt_s).round() as u64;
        for k in 0..steps {
            let t = k as f64 * dt_s;
            (filter.pos, filter.v_n) = state(t);
            filter.record((t * 1e6).round() as u64, cfg.gnss_max_lag_s);
        }
        (filter.pos, filter.v_n) = (pos, v_n);
        let fix_t_s = now_s - lag_s;
        let (fix_pos, fix_v) = state(fix_t_s);
        let fix = GnssFix {
            t_us: (fix_t_s * 1e6).round() as u64,
            pos: fix_pos,
            v_ned_mps: fix_v,
            sigma_hor_m: f64::NAN,
            sigma_ver_m: f64::NAN,
            sigma_vel_mps: f64::NAN,
        };
        let level = UnitQuaternion::identity();
        let mut extrapolating = filter.clone();
        extrapolating.history.clear();
        let nis = filter
            .update_gnss(&cfg, &fix, lag_s, &level, &Vector3::zeros())
            .expect("fused");
        // Linear interpolation between 25 ms steps of a quadratic/cubic path: millimetres.
        assert!(nis < 0.01, "{nis}");
        // The old way: 0.4 s at the current 2 g (7.85 m/s) against the 6.08 m/s actually
        // gained on the ramp: 1.77 m/s off, 24 times the GNSS velocity σ.
        let (_, moved_v) = extrapolating.fix_at_step(&fix, lag_s, &level, &Vector3::zeros());
        let off = (moved_v - v_n).norm();
        assert!((off - 1.77).abs() < 0.01, "{off}");
        assert!(matches!(
            extrapolating.update_gnss(&cfg, &fix, lag_s, &level, &Vector3::zeros()),
            Err(UpdateRejection::Gated { .. })
        ));
    }
}
