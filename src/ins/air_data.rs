//! Air-data filter (docs/REFERENCES.md A1.4, `filter_air02`): 9-state EKF
//! `x = [v_TAS, α, β, T, Hp, ROC, v̇_TAS, α̇, β̇]` with the kinematic model
//! `ẋ = [v̇_TAS, α̇, β̇, 0, ROC, 0, 0, 0, 0]` and observations Pitot, vanes, thermometer and
//! static pressure `p = p_ISA(Hp)` (A3.1). Derived output: `ΔT = T − T_ISA(Hp)`, estimated in
//! both phases.
//!
//! `A² = 0`, so `F = expm(A Δt) = I + A Δt` exactly, and the authors' Euler state step is
//! exact too. The observations have independent noise and are processed one at a time
//! (identical to the batch update for the linear rows; the pressure row is linearised at the
//! latest estimate), which handles missing vanes without a second code path.
//!
//! Without a vane (degraded mode, `AirSample::aoa_rad`/`aos_rad` = `None`) the angle is a
//! state without observation: it is held at its initial guess, its rate is pinned to zero, and
//! its variance is kept at least `no_vane_angle_sigma_deg²` (left alone, the rate's random
//! walk would grow the variance as t³ without bound while the estimate never moves).

use nalgebra::{SMatrix, SVector};

use super::config::AirDataFilterConfig;
use super::ekf::{self, UpdateRejection};
use crate::env::atmosphere;
use crate::sensors::AirSample;

/// Number of states.
pub(crate) const NX: usize = 9;

/// Variances of the held AoA and AoS guesses without vanes, rad².
fn no_vane_floors(cfg: &AirDataFilterConfig) -> [f64; 2] {
    [
        cfg.no_vane_angle_sigma_deg.to_radians().powi(2),
        cfg.no_vane_aos_sigma_deg.to_radians().powi(2),
    ]
}
/// State index of the true airspeed, m/s.
pub(crate) const TAS: usize = 0;
/// State index of the angle of attack, rad.
pub(crate) const AOA: usize = 1;
/// State index of the angle of sideslip, rad.
pub(crate) const AOS: usize = 2;
/// State index of the outside air temperature, K.
pub(crate) const TEMP: usize = 3;
/// State index of the pressure altitude, m.
pub(crate) const HP: usize = 4;
/// State index of the rate of climb (pressure altitude rate), m/s.
pub(crate) const ROC: usize = 5;
/// State index of the airspeed rate, m/s².
const TAS_DOT: usize = 6;
/// State index of the AoA rate, rad/s.
const AOA_DOT: usize = 7;
/// State index of the AoS rate, rad/s.
const AOS_DOT: usize = 8;

/// The air-data EKF.
#[derive(Debug, Clone)]
pub(crate) struct AirDataFilter {
    x: SVector<f64, NX>,
    p: SMatrix<f64, NX, NX>,
    /// Whether the latest sample carried an AoA (resp. AoS) vane reading.
    vane: [bool; 2],
    /// Updates refused for numerical reasons.
    pub numerical_rejections: u64,
}

impl AirDataFilter {
    /// Initialise from the first sample (docs/REFERENCES.md A1.4 `x₀`, `P₀`): airspeed, vanes,
    /// temperature and `Hp = Hp(p)` from the readings, rates zero; missing vanes take
    /// `aoa_guess_rad` and 0.
    pub fn new(cfg: &AirDataFilterConfig, sample: &AirSample, aoa_guess_rad: f64) -> Self {
        let mut x = SVector::<f64, NX>::zeros();
        x[TAS] = sample.tas_mps;
        x[AOA] = sample.aoa_rad.unwrap_or(aoa_guess_rad);
        x[AOS] = sample.aos_rad.unwrap_or(0.0);
        x[TEMP] = sample.temp_k;
        x[HP] = atmosphere::pressure_altitude_m(sample.p_pa);
        let mut p = SMatrix::<f64, NX, NX>::zeros();
        let hyp2 = |a: f64, b: f64| a * a + b * b;
        p[(TAS, TAS)] = hyp2(cfg.tas_noise_sigma_mps, cfg.tas_bias_sigma_mps);
        let [no_aoa_vane, no_aos_vane] = no_vane_floors(cfg);
        p[(AOA, AOA)] = match sample.aoa_rad {
            Some(_) => hyp2(
                cfg.aoa_noise_sigma_deg.to_radians(),
                cfg.aoa_bias_sigma_deg.to_radians(),
            ),
            None => no_aoa_vane,
        };
        p[(AOS, AOS)] = match sample.aos_rad {
            Some(_) => hyp2(
                cfg.aos_noise_sigma_deg.to_radians(),
                cfg.aos_bias_sigma_deg.to_radians(),
            ),
            None => no_aos_vane,
        };
        p[(TEMP, TEMP)] = hyp2(cfg.temp_noise_sigma_k, cfg.temp_bias_sigma_k);
        // Hp: (Hp(p₀ + σ_p) − Hp(p₀))² with σ_p = noise ⊕ bias, evaluated at the first reading.
        let sigma_p = hyp2(cfg.p_noise_sigma_pa, cfg.p_bias_sigma_pa).sqrt();
        let dhp = atmosphere::pressure_altitude_m(sample.p_pa + sigma_p) - x[HP];
        p[(HP, HP)] = dhp * dhp;
        Self {
            x,
            p,
            vane: [sample.aoa_rad.is_some(), sample.aos_rad.is_some()],
            numerical_rejections: 0,
        }
    }

    /// Time update over `dt_s` with `Q̃·q_scale`.
    pub fn predict(&mut self, cfg: &AirDataFilterConfig, dt_s: f64, q_scale: f64) {
        let mut f = SMatrix::<f64, NX, NX>::identity();
        for (i, j) in [(TAS, TAS_DOT), (AOA, AOA_DOT), (AOS, AOS_DOT), (HP, ROC)] {
            f[(i, j)] = dt_s;
        }
        self.x = f * self.x;
        let q = SVector::<f64, NX>::from_column_slice(&cfg.q) * q_scale;
        // Rows from ROC on are the identity's.
        ekf::predict_covariance_top(&mut self.p, &f.fixed_rows::<ROC>(0).into_owned(), &q);
        self.hold_angles_without_vane(cfg);
    }

    /// Measurement update with one air-data sample.
    pub fn update(&mut self, cfg: &AirDataFilterConfig, s: &AirSample) {
        self.vane = [s.aoa_rad.is_some(), s.aos_rad.is_some()];
        self.scalar(TAS, s.tas_mps - self.x[TAS], 1.0, cfg.tas_noise_sigma_mps);
        if let Some(aoa) = s.aoa_rad {
            let sigma = cfg.aoa_noise_sigma_deg.to_radians();
            self.scalar(AOA, aoa - self.x[AOA], 1.0, sigma);
        }
        if let Some(aos) = s.aos_rad {
            let sigma = cfg.aos_noise_sigma_deg.to_radians();
            self.scalar(AOS, aos - self.x[AOS], 1.0, sigma);
        }
        self.scalar(TEMP, s.temp_k - self.x[TEMP], 1.0, cfg.temp_noise_sigma_k);
        let hp = self.x[HP];
        self.scalar(
            HP,
            s.p_pa - atmosphere::pressure_pa(hp),
            atmosphere::pressure_derivative_pa_per_m(hp),
            cfg.p_noise_sigma_pa,
        );
        self.hold_angles_without_vane(cfg);
    }

    /// One scalar observation `y = h·x[index] + v`, with innovation `r` and noise σ.
    fn scalar(&mut self, index: usize, r: f64, h: f64, sigma: f64) {
        let mut hm = SMatrix::<f64, 1, NX>::zeros();
        hm[index] = h;
        let res = ekf::update_rows(
            &mut self.p,
            &hm,
            &SVector::<f64, 1>::new(sigma * sigma),
            &SVector::<f64, 1>::new(r),
        );
        match res {
            Ok(dx) => self.x += dx,
            Err(UpdateRejection::Numerical | UpdateRejection::Gated { .. }) => {
                self.numerical_rejections += 1;
            }
        }
    }

    /// Degraded mode (module doc): pin the rate of an unobserved angle and keep its variance at
    /// least the no-vane prior. Raising a diagonal entry keeps `P` positive semi-definite.
    fn hold_angles_without_vane(&mut self, cfg: &AirDataFilterConfig) {
        let floors = no_vane_floors(cfg);
        for (k, (angle, rate)) in [(AOA, AOA_DOT), (AOS, AOS_DOT)].into_iter().enumerate() {
            if self.vane[k] {
                continue;
            }
            let floor = floors[k];
            self.x[rate] = 0.0;
            self.p.row_mut(rate).fill(0.0);
            self.p.column_mut(rate).fill(0.0);
            if self.p[(angle, angle)] < floor {
                self.p[(angle, angle)] = floor;
            }
        }
    }

    /// State vector `[v_TAS, α, β, T, Hp, ROC, v̇_TAS, α̇, β̇]`.
    pub fn state(&self) -> &SVector<f64, NX> {
        &self.x
    }

    /// The angles held without a vane, `[α, β]` (module doc).
    pub fn held_angles(&self) -> [bool; 2] {
        [!self.vane[0], !self.vane[1]]
    }

    /// The covariance without the rows and columns of the held angles. A held angle's whole
    /// uncertainty is a bias (the true angle against the guess), constant in body axes: the
    /// navigation models it as such ([`super::position::DeniedNav`]) and must not also count
    /// it as noise of every sample.
    pub fn covariance_without_held_angles(&self) -> SMatrix<f64, NX, NX> {
        let mut p = self.p;
        for (k, angle) in [AOA, AOS].into_iter().enumerate() {
            if !self.vane[k] {
                p.row_mut(angle).fill(0.0);
                p.column_mut(angle).fill(0.0);
            }
        }
        p
    }

    /// Covariance.
    pub fn covariance(&self) -> &SMatrix<f64, NX, NX> {
        &self.p
    }

    /// Temperature offset `ΔT = T − T_ISA(Hp)`, K.
    pub fn delta_t_k(&self) -> f64 {
        atmosphere::delta_t_k(self.x[HP], self.x[TEMP])
    }

    /// Variance of `ΔT`: `∂ΔT/∂T = 1`, `∂ΔT/∂Hp = −dT_ISA/dHp`, K².
    pub fn delta_t_var_k2(&self) -> f64 {
        let hp = self.x[HP];
        // Finite slope of T_ISA (−6.5e-3 K/m below the tropopause, 0 above).
        let slope = if hp > atmosphere::HP_TROPOPAUSE_M {
            0.0
        } else {
            atmosphere::BETA_T_KPM
        };
        let p = &self.p;
        (p[(TEMP, TEMP)] - 2.0 * slope * p[(TEMP, HP)] + slope * slope * p[(HP, HP)]).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_us: u64, tas: f64, p_pa: f64) -> AirSample {
        AirSample {
            t_us,
            tas_mps: tas,
            aoa_rad: Some(0.05),
            aos_rad: Some(0.0),
            p_pa,
            temp_k: 280.0,
        }
    }

    #[test]
    fn initial_state_from_first_sample() {
        let cfg = AirDataFilterConfig::default();
        let s = sample(0, 30.0, atmosphere::pressure_pa(1000.0));
        let f = AirDataFilter::new(&cfg, &s, 0.0);
        assert!((f.state()[HP] - 1000.0).abs() < 1e-6);
        assert_eq!(f.state()[TAS], 30.0);
        // P₀ of Hp: σ_p = 141.4 Pa over |dp/dHp| ≈ 11.3 Pa/m at 1 km ≈ 12.5 m.
        let sigma_hp = f.covariance()[(HP, HP)].sqrt();
        let expect = 2f64.sqrt() * 100.0 / atmosphere::pressure_derivative_pa_per_m(1000.0).abs();
        assert!(
            (sigma_hp - expect).abs() < 0.05 * expect,
            "{sigma_hp} {expect}"
        );
    }

    #[test]
    fn missing_vanes_hold_angles_with_bounded_variance() {
        let cfg = AirDataFilterConfig::default();
        let mut s = sample(0, 30.0, 90_000.0);
        s.aoa_rad = None;
        s.aos_rad = None;
        let mut f = AirDataFilter::new(&cfg, &s, 0.04);
        for _ in 0..100_000 {
            f.predict(&cfg, 0.01, 1.0);
            f.update(&cfg, &s);
        }
        assert_eq!(f.state()[AOA], 0.04);
        assert_eq!(f.state()[AOS], 0.0);
        // 1e5 steps of the tiny angle process noise (1e-15) add 1e-10 rad² at most.
        for (i, floor) in [AOA, AOS].into_iter().zip(no_vane_floors(&cfg)) {
            assert!((f.covariance()[(i, i)] - floor).abs() < 1e-9);
        }
    }
}
