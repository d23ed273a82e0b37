//! The simulated aircraft (docs/REFERENCES.md A4): a ~20 kg piston-engine fixed-wing UAV with a
//! stability-derivative aerodynamic model, engine and propeller, mass and inertia with fuel
//! burn, actuators, and the 6-DOF equations of motion on the rotating WGS84 Earth.
//!
//! Derivations and numbers: `docs/AIRCRAFT.md`; default parameters: `config/aircraft.toml`.
//!
//! Sign conventions of the controls (Etkin; Stevens & Lewis): δe > 0 trailing edge down →
//! nose down; δa > 0 right aileron trailing edge up → roll right (right wing down); δr > 0
//! trailing edge left → nose left; throttle in [0, 1].

pub mod actuators;
pub mod aero;
pub mod dynamics;
pub mod mass;
pub mod propulsion;
pub mod trim;

use std::path::Path;

use ianav::math::wgs84::Geodetic;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

pub use actuators::{ActuatorLimits, Actuators};
pub use aero::{AeroModel, AeroParams};
pub use mass::{Inertia, MassModel, MassParams};
pub use propulsion::{Propulsion, PropulsionOutput, PropulsionParams};
pub use trim::{ModePair, Modes, Trim};

/// Aircraft truth state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruthState {
    /// Position of the centre of gravity.
    pub pos: Geodetic,
    /// Ground velocity (relative to the Earth) viewed in body axes, m/s.
    pub v_b_mps: Vector3<f64>,
    /// Attitude: `v_n = q_nb * v_b`.
    pub q_nb: UnitQuaternion<f64>,
    /// Inertial angular velocity of the body viewed in body axes, rad/s.
    pub w_ib_b_rps: Vector3<f64>,
    /// Mass, kg (decreases as fuel burns).
    pub mass_kg: f64,
}

/// Control positions (or commands): throttle in [0, 1], surfaces in rad.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Controls {
    /// Throttle δ_T in [0, 1].
    pub throttle: f64,
    /// Elevator δ_E, rad (positive trailing edge down).
    pub elevator_rad: f64,
    /// Ailerons δ_A, rad (positive: right aileron trailing edge up, left down: rolls right).
    pub aileron_rad: f64,
    /// Rudder δ_R, rad (positive: trailing edge left, yaws nose left).
    pub rudder_rad: f64,
}

/// Atmosphere and wind around the aircraft, held constant over one integration step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AirInputs {
    /// Static pressure, Pa.
    pub p_pa: f64,
    /// Air temperature, K.
    pub temp_k: f64,
    /// Air density, kg/m³.
    pub rho_kgpm3: f64,
    /// Low-frequency wind, NED, m/s.
    pub wind_ned_mps: Vector3<f64>,
    /// High-frequency (turbulence) wind, body axes, m/s.
    pub turb_b_mps: Vector3<f64>,
    /// Angular velocity of the air (rotational turbulence `(p_g, q_g, r_g)`, the rigid rotation
    /// matching the local gust gradients: `p_g = ∂w/∂y`, `q_g = −∂w/∂x`, `r_g = ∂v/∂x`), body
    /// axes, rad/s. The aerodynamic rate terms use the body rate relative to the air,
    /// `ω_nb^b − turb_rate_b`.
    pub turb_rate_b_rps: Vector3<f64>,
}

/// Air-relative motion derived from the state and the wind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AirRelative {
    /// Air velocity in body axes `v_tas_b = v_b − C_bn·wind_n − turb_b`, m/s.
    pub v_tas_b_mps: Vector3<f64>,
    /// True airspeed, m/s.
    pub tas_mps: f64,
    /// Angle of attack α = atan2(w, u), rad.
    pub aoa_rad: f64,
    /// Angle of sideslip β = asin(v / V), rad.
    pub aos_rad: f64,
}

/// Forces, moments and by-products evaluated at one state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loads {
    /// Specific force at the CG `f_ib_b = (F_aero + F_prop)/m`, m/s².
    pub f_ib_b_mps2: Vector3<f64>,
    /// Total moment about the CG, body axes, N·m.
    pub moment_b_nm: Vector3<f64>,
    /// Inertial angular acceleration `dw_ib_b/dt`, rad/s².
    pub w_dot_ib_b_rps2: Vector3<f64>,
    /// Propeller thrust, N.
    pub thrust_n: f64,
    /// Shaft power, W.
    pub power_w: f64,
    /// Propeller shaft speed, rev/s.
    pub shaft_rps: f64,
    /// Fuel flow, kg/s (positive when burning).
    pub fuel_flow_kgps: f64,
    /// Air-relative motion.
    pub air: AirRelative,
}

/// Errors of the aircraft configuration and trim.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AircraftError {
    /// The configuration text could not be read or parsed (the message names the key).
    #[error("aircraft configuration: {0}")]
    Parse(String),
    /// A parameter is out of its physical range.
    #[error("aircraft configuration: `{field}` {reason}")]
    Invalid {
        /// Offending field, `section.key`.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Trim inputs outside the supported range (airspeed > 1 m/s, |γ| < 0.5 rad, ρ > 0, m > 0).
    #[error("trim: airspeed, path angle, density or mass out of range")]
    TrimInputs,
    /// Newton's method did not converge (typically: not enough power or lift).
    #[error("trim did not converge at {tas_mps} m/s, path angle {gamma_rad} rad")]
    TrimNotConverged {
        /// Airspeed, m/s.
        tas_mps: f64,
        /// Path angle, rad.
        gamma_rad: f64,
    },
    /// The trim needs a control outside its range (throttle in (0, 1], surfaces within travel; rad).
    #[error("trim needs {what} = {value}, outside its range")]
    TrimOutOfLimits {
        /// Which control.
        what: &'static str,
        /// Required value.
        value: f64,
    },
    /// The eigenvalue decomposition of the linearisation failed.
    #[error("modes: eigenvalue decomposition failed")]
    Linearisation,
}

/// Every parameter of the simulated aircraft (defaults: `config/aircraft.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AircraftParams {
    /// Mass at the start of a flight, kg (docs/REFERENCES.md A5.3: 19.5 kg).
    pub initial_mass_kg: f64,
    /// Mass, CG and inertia.
    pub mass: MassParams,
    /// Aerodynamic coefficients.
    pub aero: AeroParams,
    /// Engine and propeller.
    pub propulsion: PropulsionParams,
    /// Actuator travel and rate limits.
    pub actuators: ActuatorLimits,
}

impl Default for AircraftParams {
    fn default() -> Self {
        Self {
            initial_mass_kg: 19.5,
            mass: MassParams::default(),
            aero: AeroParams::default(),
            propulsion: PropulsionParams::default(),
            actuators: ActuatorLimits::default(),
        }
    }
}

impl AircraftParams {
    /// Parses a TOML configuration (unknown keys are errors) and validates it.
    pub fn from_toml_str(s: &str) -> Result<Self, AircraftError> {
        let p: Self = toml::from_str(s).map_err(|e| AircraftError::Parse(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    /// Reads and parses a TOML configuration file.
    pub fn from_toml_file(path: &Path) -> Result<Self, AircraftError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| AircraftError::Parse(format!("{}: {e}", path.display())))?;
        Self::from_toml_str(&text)
    }

    /// Checks every section; the error names the offending field.
    pub fn validate(&self) -> Result<(), AircraftError> {
        self.mass.validate()?;
        self.aero.validate()?;
        self.propulsion.validate()?;
        self.actuators.validate()?;
        let m = &self.mass;
        if !(self.initial_mass_kg >= m.mass_empty_kg && self.initial_mass_kg <= m.mass_full_kg) {
            return Err(AircraftError::Invalid {
                field: "initial_mass_kg",
                reason: "must lie between mass.mass_empty_kg and mass.mass_full_kg".to_owned(),
            });
        }
        Ok(())
    }
}

/// Below this airspeed the sideslip angle is undefined and reported as 0, m/s.
const TAS_TINY_MPS: f64 = 1e-9;

/// Air-relative motion: `v_tas_b = v_b − C_bn·wind_n − turb_b`, `α = atan2(w, u)`,
/// `β = asin(v/V)` (0 when V → 0).
#[inline]
pub fn air_relative(x: &TruthState, air: &AirInputs) -> AirRelative {
    let v = x.v_b_mps - x.q_nb.inverse_transform_vector(&air.wind_ned_mps) - air.turb_b_mps;
    let tas_mps = v.norm();
    let aos_rad = if tas_mps > TAS_TINY_MPS {
        (v.y / tas_mps).clamp(-1.0, 1.0).asin()
    } else {
        0.0
    };
    AirRelative {
        v_tas_b_mps: v,
        tas_mps,
        aoa_rad: v.z.atan2(v.x),
        aos_rad,
    }
}

/// Non-finite control positions are treated as neutral (0) so that the truth stays finite;
/// the actuators never produce them.
#[inline]
fn sanitize(u: &Controls) -> Controls {
    let finite_or_zero = |v: f64| if v.is_finite() { v } else { 0.0 };
    Controls {
        throttle: finite_or_zero(u.throttle),
        elevator_rad: finite_or_zero(u.elevator_rad),
        aileron_rad: finite_or_zero(u.aileron_rad),
        rudder_rad: finite_or_zero(u.rudder_rad),
    }
}

/// Rigid-body inputs from the loads.
#[inline]
fn accelerations(l: &Loads) -> dynamics::BodyAccelerations {
    dynamics::BodyAccelerations {
        f_ib_b_mps2: l.f_ib_b_mps2,
        w_dot_ib_b_rps2: l.w_dot_ib_b_rps2,
        mass_rate_kgps: -l.fuel_flow_kgps,
    }
}

/// The simulated aircraft: parameters plus the models built from them.
#[derive(Debug, Clone, PartialEq)]
pub struct Aircraft {
    params: AircraftParams,
    mass: MassModel,
    aero: AeroModel,
    propulsion: Propulsion,
}

impl Aircraft {
    /// Builds the aircraft (validate `params` first when they come from outside:
    /// [`AircraftParams::from_toml_str`] does).
    pub fn new(params: AircraftParams) -> Self {
        Self {
            mass: MassModel::new(&params.mass),
            aero: AeroModel::new(&params.aero),
            propulsion: Propulsion::new(&params.propulsion),
            params,
        }
    }

    /// Parameters.
    pub fn params(&self) -> &AircraftParams {
        &self.params
    }

    /// The aerodynamic model.
    pub fn aero_model(&self) -> &AeroModel {
        &self.aero
    }

    /// The engine and propeller model.
    pub fn propulsion(&self) -> &Propulsion {
        &self.propulsion
    }

    /// The mass model.
    pub fn mass_model(&self) -> &MassModel {
        &self.mass
    }

    /// CG position from the aircraft reference point, body axes, m, at this mass.
    pub fn cg_from_reference_b_m(&self, mass_kg: f64) -> Vector3<f64> {
        self.mass.cg_from_ref_b_m(mass_kg)
    }

    /// Forces, moments, specific force, angular acceleration, propulsion by-products at `x`
    /// (pure). Aerodynamic rates are ω_nb^b − `air.turb_rate_b_rps`.
    pub fn loads(&self, x: &TruthState, u: &Controls, air: &AirInputs) -> Loads {
        self.loads_with_rates(x, u, air, &dynamics::w_nb_b(x))
    }

    /// [`Self::loads`] with the body rate relative to NED `w_nb_b_rps` given (the equations of
    /// motion compute it anyway; trim and linearisation use a flat Earth). The rotational gust
    /// `air.turb_rate_b_rps` is subtracted from it for the aerodynamics.
    pub fn loads_with_rates(
        &self,
        x: &TruthState,
        u: &Controls,
        air: &AirInputs,
        w_nb_b_rps: &Vector3<f64>,
    ) -> Loads {
        let u = sanitize(u);
        let power_w = self
            .propulsion
            .available_power_w(u.throttle, air.p_pa, air.temp_k);
        self.loads_inner(x, &u, air, w_nb_b_rps, power_w, None).0
    }

    /// Loads with finite controls `u`, the engine's available power `power_avail_w` (constant
    /// over a step: it depends on throttle, pressure and temperature only) and an optional warm
    /// start of the shaft-speed solve; also returns the shaft-speed root for the next stage.
    #[inline]
    fn loads_inner(
        &self,
        x: &TruthState,
        u: &Controls,
        air: &AirInputs,
        w_nb_b_rps: &Vector3<f64>,
        power_avail_w: f64,
        shaft_warm_rps: Option<f64>,
    ) -> (Loads, Option<f64>) {
        let rel = air_relative(x, air);
        // The rate damping acts on the rotation relative to the air (docs/AIRCRAFT.md §1).
        let w_air_b_rps = w_nb_b_rps - air.turb_rate_b_rps;
        let aero = self.aero.loads(&rel, air.rho_kgpm3, &w_air_b_rps, u);
        // The engine stops when the tank is empty (m at or below the empty mass).
        let power_w = if x.mass_kg > self.mass.empty_kg() {
            power_avail_w
        } else {
            0.0
        };
        let (prop, shaft_root_rps) = self.propulsion.evaluate_at_power(
            power_w,
            air.rho_kgpm3,
            rel.v_tas_b_mps.x,
            shaft_warm_rps,
        );
        let force_b = aero.force_b_n + Vector3::new(prop.thrust_n, 0.0, 0.0);
        // Aerodynamic data and the thrust line refer to the full-tank CG; transfer to the
        // actual CG: M_cg = M_ref + (r_ref − r_cg) × F.
        let arm_b = self.mass.cg_full_from_ref_b_m() - self.mass.cg_from_ref_b_m(x.mass_kg);
        let moment_b_nm =
            aero.moment_ref_b_nm + arm_b.cross(&force_b) + Vector3::new(prop.torque_x_nm, 0.0, 0.0);
        let inertia = self.mass.inertia(x.mass_kg);
        let w = &x.w_ib_b_rps;
        let w_dot_ib_b_rps2 = inertia.solve(&(moment_b_nm - w.cross(&inertia.mul(w))));
        // Below the empty mass the force is divided by the empty mass (fuel cannot go negative).
        let mass_kg = x.mass_kg.max(self.mass.empty_kg());
        let loads = Loads {
            f_ib_b_mps2: force_b / mass_kg,
            moment_b_nm,
            w_dot_ib_b_rps2,
            thrust_n: prop.thrust_n,
            power_w: prop.power_w,
            shaft_rps: prop.shaft_rps,
            fuel_flow_kgps: prop.fuel_flow_kgps,
            air: rel,
        };
        (loads, shaft_root_rps)
    }

    /// One RK4 integration step of `dt_s` with controls, air and gravity held constant (pure).
    /// The shaft-speed solve of each stage is warm-started from the previous stage's root.
    #[inline]
    pub fn step(
        &self,
        x: &TruthState,
        u: &Controls,
        air: &AirInputs,
        gravity_ned_mps2: &Vector3<f64>,
        dt_s: f64,
    ) -> TruthState {
        let u = sanitize(u);
        let power_w = self
            .propulsion
            .available_power_w(u.throttle, air.p_pa, air.temp_k);
        let mut warm = None;
        dynamics::rk4_step(x, gravity_ned_mps2, dt_s, |xs, w_nb| {
            let (l, root) = self.loads_inner(xs, &u, air, w_nb, power_w, warm);
            warm = root;
            accelerations(&l)
        })
    }

    /// One Heun step (the authors' integrator), for comparisons.
    pub fn step_heun(
        &self,
        x: &TruthState,
        u: &Controls,
        air: &AirInputs,
        gravity_ned_mps2: &Vector3<f64>,
        dt_s: f64,
    ) -> TruthState {
        let u = sanitize(u);
        let power_w = self
            .propulsion
            .available_power_w(u.throttle, air.p_pa, air.temp_k);
        dynamics::heun_step(x, gravity_ned_mps2, dt_s, |xs, w_nb| {
            accelerations(&self.loads_inner(xs, &u, air, w_nb, power_w, None).0)
        })
    }

    /// Steady wings-level trim at true airspeed `tas_mps` and path angle `gamma_rad` in the
    /// given air (no wind), with standard gravity: α, θ, elevator, throttle, plus the small
    /// aileron and rudder that balance the propeller torque at zero sideslip.
    pub fn trim(
        &self,
        tas_mps: f64,
        gamma_rad: f64,
        air: &AirInputs,
        mass_kg: f64,
    ) -> Result<Trim, AircraftError> {
        trim::solve(self, tas_mps, gamma_rad, air, mass_kg)
    }

    /// Short period, phugoid, Dutch roll, roll and spiral modes from a numerical
    /// linearisation about `trim` (flat Earth, still air with the density etc. of `air`).
    pub fn linear_modes(&self, trim: &Trim, air: &AirInputs) -> Result<Modes, AircraftError> {
        trim::modes(self, trim, air)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ianav::env::atmosphere;
    use ianav::math::so3;

    fn setup() -> (Aircraft, TruthState, AirInputs, Controls) {
        let ac = Aircraft::new(AircraftParams::default());
        let hp_m = 2500.0;
        let p_pa = atmosphere::pressure_pa(hp_m);
        let temp_k = atmosphere::temperature_k(hp_m, 0.0);
        let air = AirInputs {
            p_pa,
            temp_k,
            rho_kgpm3: atmosphere::density_kgpm3(p_pa, temp_k),
            wind_ned_mps: Vector3::zeros(),
            turb_b_mps: Vector3::zeros(),
            turb_rate_b_rps: Vector3::zeros(),
        };
        let x = TruthState {
            pos: Geodetic {
                lat_rad: 0.8,
                lon_rad: 0.1,
                h_m: 2500.0,
            },
            v_b_mps: Vector3::new(28.9, 0.4, 1.5),
            q_nb: so3::from_euler_zyx(0.3, 0.05, 0.02),
            w_ib_b_rps: Vector3::zeros(),
            mass_kg: 19.5,
        };
        let u = Controls {
            throttle: 0.4,
            elevator_rad: -0.02,
            aileron_rad: 0.01,
            rudder_rad: 0.0,
        };
        (ac, x, air, u)
    }

    #[test]
    fn air_rotating_with_the_body_cancels_the_rate_terms() {
        // ω_nb = ω_g: no rotation relative to the air, the same loads as no rotation at all
        // (only the aerodynamic rate terms see ω; the gyroscopic term uses ω_ib and is the same
        // in both since the state is unchanged).
        let (ac, x, air, u) = setup();
        let w = Vector3::new(0.3, -0.2, 0.15);
        let rotating = AirInputs {
            turb_rate_b_rps: w,
            ..air
        };
        let l0 = ac.loads_with_rates(&x, &u, &air, &Vector3::zeros());
        let l1 = ac.loads_with_rates(&x, &u, &rotating, &w);
        assert!((l1.moment_b_nm - l0.moment_b_nm).norm() < 1e-12 * l0.moment_b_nm.norm().max(1.0));
        assert!((l1.f_ib_b_mps2 - l0.f_ib_b_mps2).norm() < 1e-12 * l0.f_ib_b_mps2.norm());
        // And a rotation of the air alone acts as the opposite body rate.
        let l2 = ac.loads_with_rates(&x, &u, &rotating, &Vector3::zeros());
        let l3 = ac.loads_with_rates(&x, &u, &air, &(-w));
        assert_eq!(l2.moment_b_nm, l3.moment_b_nm);
    }

    #[test]
    fn rotational_gusts_push_the_aircraft_the_physical_way() {
        // p_g = ∂w/∂y > 0: more downdraft on the right wing, less lift there → roll right.
        // q_g = −∂w/∂x > 0: more updraft at the wing than at the tail → the tail lifts less →
        // nose up. r_g = ∂v/∂x > 0: the fin meets air moving left relative to the nose → side
        // force to the left on the fin → nose right.
        let (ac, x, air, u) = setup();
        let base = ac.loads(&x, &u, &air).moment_b_nm;
        for i in 0..3 {
            let mut w = Vector3::zeros();
            w[i] = 0.1;
            let gust = AirInputs {
                turb_rate_b_rps: w,
                ..air
            };
            let m = ac.loads(&x, &u, &gust).moment_b_nm;
            assert!(m[i] > base[i], "axis {i}: {} vs {}", m[i], base[i]);
        }
    }
}
