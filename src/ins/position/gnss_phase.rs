//! The GNSS-phase estimates (docs/REFERENCES.md A1.6): every step `Δp = LPF(Δp(ΔT̂, Ĥp, H(ĥ)))`
//! and `v_lf = LPF(v̂ − C_nb v_TAS^b(V̂, α̂, β̂))`, moving means over `lpf_window_s` initialised
//! with their first raw value; the turbulence intensity from the raw wind's spread about its
//! mean; the barometric altitude `h(Hp, ΔT, Δp)`.

use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

use super::{AirInputs, GnssFilterState};
use crate::env::atmosphere::{self, AtmosphereOffsets};
use crate::ins::ekf::WindowMean;

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
    /// Moments for the airspeed bias (`airspeed_bias_from_turns`; `None` when off).
    airspeed_moments: Option<AirspeedMoments>,
}

/// Window means of the horizontal air-velocity direction `c = v_air,h / V` and of its products
/// with itself and with the raw wind, from which the least-squares airspeed bias follows
/// ([`GnssPhaseEstimates::airspeed_bias`]).
#[derive(Debug, Clone)]
struct AirspeedMoments {
    /// The raw wind over the same samples (the wind's own mean also holds those below
    /// `AIRSPEED_BIAS_MIN_TAS_MPS`).
    r: WindowMean<Vector3<f64>>,
    c: WindowMean<Vector3<f64>>,
    c_dot_c: WindowMean<f64>,
    c_dot_r: WindowMean<f64>,
}

/// No airspeed direction below this airspeed (on the ground), m/s.
const AIRSPEED_BIAS_MIN_TAS_MPS: f64 = 5.0;

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
pub(super) fn gust_tau_s(scale_m: f64, tas_mps: f64) -> f64 {
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
pub(super) fn raw_delta_p(
    hp_m: f64,
    var_hp: f64,
    h_m: f64,
    var_h: f64,
    delta_t_k: f64,
) -> (f64, f64) {
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
            airspeed_moments: None,
        }
    }

    /// Also gather what the airspeed bias needs (`airspeed_bias_from_turns`).
    pub fn with_airspeed_bias(mut self, window_s: f64) -> Self {
        self.airspeed_moments = Some(AirspeedMoments {
            r: WindowMean::new(window_s, Vector3::zeros()),
            c: WindowMean::new(window_s, Vector3::zeros()),
            c_dot_c: WindowMean::new(window_s, 0.0),
            c_dot_r: WindowMean::new(window_s, 0.0),
        });
        self
    }

    /// Least-squares airspeed correction `δ` (m/s, to add to the airspeed) over the wind's
    /// window, with the window's mean direction `c̄` (3-D, vertical zero): the raw wind is
    /// `r = w + c δ`, so `δ = (⟨c·r⟩ − c̄·r̄) / (⟨|c|²⟩ − |c̄|²)`. `None` when not gathered or
    /// when the headings flown spread less than `min_spread` (δ is then not observable).
    pub fn airspeed_bias(&self, min_spread: f64) -> Option<(f64, Vector3<f64>)> {
        let m = self.airspeed_moments.as_ref()?;
        let c_bar = m.c.value();
        let spread = m.c_dot_c.value() - c_bar.norm_squared();
        // Also refuses a NaN spread.
        if spread.is_nan() || spread < min_spread {
            return None;
        }
        let r_bar = m.r.value();
        let delta = (m.c_dot_r.value() - c_bar.dot(&r_bar)) / spread;
        delta.is_finite().then_some((delta, c_bar))
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
            if let Some(m) = self.airspeed_moments.as_mut()
                && tas_mps >= AIRSPEED_BIAS_MIN_TAS_MPS
            {
                let c = Vector3::new(v_air_n.x, v_air_n.y, 0.0) / tas_mps;
                m.r.step(wind_n, dt_s);
                m.c.step(c, dt_s);
                m.c_dot_c.step(c.norm_squared(), dt_s);
                m.c_dot_r.step(c.dot(&wind_n), dt_s);
            }
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
