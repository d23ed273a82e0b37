//! What defines a flight (paper table "Working frequencies" for the rates): [`FlightSetup`]
//! and its parts, their validation and errors, and the set-up of a [`Flight`] from a setup
//! and a seed (draws, initial trim, camera, navigator).

use ianav::env::atmosphere;
use ianav::env::magnetic::{MagneticGrid, MagneticModel};
use ianav::ins::InsConfig;
use ianav::math::wgs84::Geodetic;
use ianav::math::{so3, wgs84};
use ianav::nav::{NavCamera, NavConfig, Navigator};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::systems::{DEFAULT_VISION_SYSTEMS, VisionSystem, navigator_vision};
use super::{Flight, FlightCamera, to_us};
use crate::aircraft::{Actuators, AirInputs, Aircraft, AircraftParams, TruthState, air_relative};
use crate::control::{ControlConfig, Controller, Guidance, Navigation, TruthNavigation};
use crate::env::{
    DrydenParams, TrueGravity, TrueMagneticField, Turbulence, TurbulenceConfig, WeatherOffsets,
    WindField,
};
use crate::rng;
use crate::scenario::{Mission, ScenarioConfig};
use crate::sensors::{SensorSuite, SensorsConfig};
use crate::terrain::Terrain;
use crate::terrain::render::{RenderOptions, Renderer};
use ianav::vision::camera::{Camera, CameraConfig, MountingConfig};
use ianav::vision::vns::VnsConfig;

/// Errors setting up a flight.
#[derive(Debug, thiserror::Error)]
pub enum FlightError {
    /// A rate is not a whole multiple of the integration step, or not positive.
    #[error(
        "rates: `{field}` = {value} s must be a positive whole multiple of the {step_s} s integration step"
    )]
    Rate {
        /// Offending key.
        field: &'static str,
        /// Its value, s.
        value: f64,
        /// Integration step, s.
        step_s: f64,
    },
    /// The magnetic model rejected the scenario's epoch or position.
    #[error(transparent)]
    Magnetic(#[from] ianav::env::magnetic::MagneticError),
    /// The aircraft cannot trim at the initial conditions.
    #[error("initial trim: {0}")]
    Trim(String),
    /// The scenario configuration is invalid.
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    /// The aircraft parameters are invalid.
    #[error("aircraft: {0}")]
    Aircraft(#[from] crate::aircraft::AircraftError),
    /// The sensor configuration is invalid.
    #[error("sensors: {0}")]
    Sensors(#[from] crate::sensors::SensorConfigError),
    /// The INS configuration or initialisation is invalid.
    #[error("ins: {0}")]
    Ins(#[from] ianav::ins::InsError),
    /// The navigation core could not be built.
    #[error("navigation: {0}")]
    Nav(#[from] ianav::nav::NavError),
    /// The control configuration is invalid.
    #[error("control: {0}")]
    Control(#[from] crate::control::ControlConfigError),
    /// The camera could not be set up (a frame that cannot be rendered, e.g. because the
    /// aircraft flew into the terrain, ends the flight as `Departed`).
    #[error("camera: {0}")]
    Camera(String),
    /// The visual systems' list is empty or names one twice.
    #[error("vision systems `{0}`: give at least one, each once")]
    VisionSystems(String),
    /// The aircraft left the physical envelope (non-finite state, below sea level, stalled
    /// far below the minimum airspeed or overspeeding): the models are no longer valid.
    #[error("flight departed at mission time {t_s:.2} s: {reason}")]
    Departed {
        /// Mission time, s.
        t_s: f64,
        /// What left the envelope.
        reason: String,
    },
}

/// Discrete rates of the simulation (paper table "Working frequencies"); the sensor and GNSS
/// periods come from the sensor configuration, the control period from the control one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RatesConfig {
    /// Truth integration step, s (500 Hz).
    pub truth_step_s: f64,
    /// Truth output period, s (10 Hz).
    pub output_period_s: f64,
}

impl Default for RatesConfig {
    fn default() -> Self {
        Self {
            truth_step_s: 0.002,
            output_period_s: 0.1,
        }
    }
}

/// What guidance and control fly on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NavigationMode {
    /// The simulator's truth (tests of the aircraft and control that must not depend on
    /// the navigation).
    Truth,
    /// The GNSS-denied INS fed with the simulated sensors (the paper's set-up; default).
    #[default]
    Ins,
}

/// A horizontal position from an external navigation source (after GNSS loss an autopilot
/// can fly on a companion computer's position, docs/SITL.md). While a fresh aid is set,
/// guidance and control fly on its latitude and longitude, carried from its time of validity
/// to the current instant with the INS ground velocity; everything else (height, velocity,
/// attitude, air data) stays the vehicle's own INS. This models an autopilot EKF that trusts
/// the external position far more than its own dead-reckoned one, which is the case once
/// GNSS has been lost for a while. Never set by `run`/`mc`: their flights are unchanged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionAid {
    /// Time of validity, µs on the flight's sensor clock.
    pub t_us: u64,
    /// Latitude, rad.
    pub lat_rad: f64,
    /// Longitude, rad.
    pub lon_rad: f64,
}

/// σ of the height-over-terrain error of the visual navigation's initialisation, m (the
/// authors' "initial height over terrain" error, 50 m · N(0, 1)).
pub const H_AGL_SIGMA_M: f64 = 50.0;

/// The down-looking camera and the terrain it sees; off unless set.
#[derive(Debug, Clone)]
pub struct CameraSetup {
    /// The terrain (shared: its tile cache serves every flight that flies over it).
    pub terrain: std::sync::Arc<Terrain>,
    /// Intrinsics.
    pub camera: CameraConfig,
    /// Mounting and its error model.
    pub mounting: MountingConfig,
    /// Frame period, s (0.1: the paper's 10 Hz).
    pub period_s: f64,
    /// Photometric options (noise-free by default).
    pub options: RenderOptions,
    /// σ of the error of the height over the terrain offered to the visual navigation, m
    /// (one draw per flight; the authors' 50 m, docs/REFERENCES.md).
    pub h_agl_sigma_m: f64,
    /// The flight's own navigator runs the visual navigation on the frames (off for the SITL
    /// vehicle, whose frames are the daemon's to navigate on).
    pub vision_navigation: bool,
    /// Mission-time windows `[start, end)`, s, without frames (a stalled camera): nothing is
    /// rendered or sent in them.
    pub outages_s: Vec<(f64, f64)>,
}

impl CameraSetup {
    /// The authors' camera, nadir-looking, at 10 Hz over `terrain`.
    pub fn new(terrain: std::sync::Arc<Terrain>) -> Self {
        Self {
            terrain,
            camera: CameraConfig::default(),
            mounting: MountingConfig::default(),
            period_s: 0.1,
            options: RenderOptions::default(),
            h_agl_sigma_m: H_AGL_SIGMA_M,
            vision_navigation: true,
            outages_s: Vec::new(),
        }
    }
}

/// Everything that defines a flight but the seed.
#[derive(Debug, Clone)]
pub struct FlightSetup {
    /// Scenario (mission draws, weather, wind, timing).
    pub scenario: ScenarioConfig,
    /// Aircraft parameters.
    pub aircraft: AircraftParams,
    /// Sensor models.
    pub sensors: SensorsConfig,
    /// Control gains.
    pub control: ControlConfig,
    /// Simulation rates.
    pub rates: RatesConfig,
    /// Fly this mission instead of drawing one (tests and custom missions).
    pub mission_override: Option<Mission>,
    /// Navigation source of guidance and control.
    pub navigation: NavigationMode,
    /// INS configuration (used when `navigation` is `Ins`).
    pub ins: InsConfig,
    /// Visual navigation settings (used when the navigator runs on the camera's frames): the
    /// base of every system of `vision_systems`.
    pub vision: VnsConfig,
    /// The visual systems run on the same frames (with a camera): the first is the
    /// navigator's configured system, the others run beside it.
    pub vision_systems: Vec<VisionSystem>,
    /// Camera and terrain (`None`: no frames, the default).
    pub camera: Option<CameraSetup>,
    /// The navigator publishes the daemon's fused solution (the visual horizontal position
    /// after the GNSS loss, restarts after a loss or a gap; docs/FUSION.md) and guidance flies
    /// on it. Off: the paper's evaluation (the INS, each visual system scored beside it).
    pub fused: bool,
}

impl FlightSetup {
    /// Validate every part; errors name the offending key.
    pub fn validate(&self) -> Result<(), FlightError> {
        self.scenario.validate()?;
        self.aircraft.validate()?;
        self.sensors.validate()?;
        self.control.validate()?;
        self.ins
            .validate()
            .map_err(|e| FlightError::Ins(ianav::ins::InsError::Config(e)))?;
        self.vision
            .validate()
            .map_err(|e| FlightError::Nav(ianav::nav::NavError::Vision(e.into())))?;
        let names: Vec<&str> = self.vision_systems.iter().map(|s| s.name()).collect();
        let repeated = (1..names.len()).any(|i| names[..i].contains(&names[i]));
        if names.is_empty() || repeated {
            return Err(FlightError::VisionSystems(names.join(",")));
        }
        Ok(())
    }

    /// The built-in scenario `number` with the default aircraft, sensors and control.
    pub fn builtin(number: u8) -> Result<Self, crate::scenario::ScenarioError> {
        Ok(Self {
            scenario: ScenarioConfig::builtin(number)?,
            aircraft: AircraftParams::default(),
            sensors: SensorsConfig::default(),
            control: ControlConfig::default(),
            rates: RatesConfig::default(),
            mission_override: None,
            navigation: NavigationMode::default(),
            ins: InsConfig::default(),
            vision: VnsConfig::default(),
            vision_systems: DEFAULT_VISION_SYSTEMS.to_vec(),
            camera: None,
            fused: false,
        })
    }
}

fn steps_per(field: &'static str, period_s: f64, step_s: f64) -> Result<u64, FlightError> {
    let ratio = period_s / step_s;
    let n = ratio.round();
    if !(period_s.is_finite() && n >= 1.0 && (ratio - n).abs() < 1e-6) {
        return Err(FlightError::Rate {
            field,
            value: period_s,
            step_s,
        });
    }
    Ok(n as u64)
}

impl Flight {
    /// Set up the flight of `setup` with seed `seed`: draw the mission, weather, wind,
    /// turbulence, geophysics and sensor errors from their own streams; trim the aircraft at
    /// the initial airspeed and pressure altitude, heading so that the ground track has the
    /// initial bearing.
    pub fn new(setup: &FlightSetup, seed: u64) -> Result<Self, FlightError> {
        setup.validate()?;
        let scn = &setup.scenario;
        let rates = setup.rates;
        let step_s = rates.truth_step_s;
        if !(step_s.is_finite() && step_s > 0.0) {
            return Err(FlightError::Rate {
                field: "rates.truth_step_s",
                value: step_s,
                step_s,
            });
        }
        let steps_per_sensor =
            steps_per("sensors.imu_period_s", setup.sensors.imu_period_s, step_s)?;
        let steps_per_air = steps_per("sensors.air.period_s", setup.sensors.air.period_s, step_s)?;
        let steps_per_mag = steps_per("sensors.mag.period_s", setup.sensors.mag.period_s, step_s)?;
        let steps_per_gnss =
            steps_per("sensors.gnss.period_s", setup.sensors.gnss.period_s, step_s)?;
        let steps_per_control = steps_per("control.period_s", setup.control.period_s, step_s)?;
        let steps_per_output = steps_per("rates.output_period_s", rates.output_period_s, step_s)?;

        let mission = match &setup.mission_override {
            Some(m) => m.clone(),
            None => Mission::draw(scn, &mut rng::stream(seed, "guidance")),
        };
        let weather = WeatherOffsets::draw(&scn.offsets, &mut rng::stream(seed, "offsets"));
        let wind = WindField::draw(&scn.wind, &mut rng::stream(seed, "wind"));
        let turbulence = Turbulence::with_params(
            &TurbulenceConfig {
                factor: scn.turbulence_factor,
            },
            DrydenParams::calibrated(scn.turbulence_severity)
                .with_span(setup.aircraft.aero.wing_span_m),
            rng::stream(seed, "turbulence"),
        );
        let mut geo_rng = rng::stream(seed, "geophysics");
        let gravity = TrueGravity::draw(&mut geo_rng);
        let magnetic =
            TrueMagneticField::draw(MagneticModel::new(scn.magnetic_decimal_year)?, &mut geo_rng);

        let mut magnetic_grid = MagneticGrid::new(magnetic.model.clone());
        let aircraft = Aircraft::new(setup.aircraft.clone());
        let t0_s = -scn.warmup_s;
        let offsets = weather.at(t0_s);
        let hp_m = mission.hp_ini_m;
        let h_m = atmosphere::geometric_from_pressure_altitude_m(hp_m, &offsets);
        let p_pa = atmosphere::pressure_pa(hp_m);
        let temp_k = atmosphere::temperature_k(hp_m, offsets.delta_t_k);
        let wind_ned_mps = wind.at(t0_s);
        let still_air = AirInputs {
            p_pa,
            temp_k,
            rho_kgpm3: atmosphere::density_kgpm3(p_pa, temp_k),
            wind_ned_mps: Vector3::zeros(),
            turb_b_mps: Vector3::zeros(),
            turb_rate_b_rps: Vector3::zeros(),
        };
        let mass_kg = setup.aircraft.initial_mass_kg;
        let trim = aircraft
            .trim(mission.tas_ini_mps, 0.0, &still_air, mass_kg)
            .map_err(|e| FlightError::Trim(e.to_string()))?;

        // Heading that cancels the crosswind so the ground track has bearing χ_ini.
        let chi = mission.chi_ini_rad;
        let v_air_hor = mission.tas_ini_mps * (trim.pitch_rad - trim.aoa_rad).cos();
        let crosswind = -wind_ned_mps.x * chi.sin() + wind_ned_mps.y * chi.cos();
        let psi = chi - (crosswind / v_air_hor).clamp(-0.9, 0.9).asin();
        let q_nb = so3::from_euler_zyx(psi, trim.pitch_rad, 0.0);
        let v_tas_b =
            mission.tas_ini_mps * Vector3::new(trim.aoa_rad.cos(), 0.0, trim.aoa_rad.sin());
        let pos = Geodetic {
            lat_rad: scn.start.lat_deg.to_radians(),
            lon_rad: scn.start.lon_deg.to_radians(),
            h_m,
        };
        let v_b_mps = v_tas_b + q_nb.inverse() * wind_ned_mps;
        let v_ned = q_nb * v_b_mps;
        let w_in_n = wgs84::omega_ie_n(pos.lat_rad) + wgs84::omega_en_n(&pos, &v_ned);
        let x = TruthState {
            pos,
            v_b_mps,
            q_nb,
            w_ib_b_rps: q_nb.inverse() * w_in_n,
            mass_kg,
        };
        // Trim deflections, including the aileron and rudder against propeller torque.
        let command = trim.controls();
        let actuators = Actuators::new(&setup.aircraft.actuators, command);
        let air = AirInputs {
            wind_ned_mps,
            ..still_air
        };
        let air_rel = air_relative(&x, &air);
        let navigation = TruthNavigation::from_truth(0, &x, &air_rel, &w_in_n, hp_m);
        let mut controller = Controller::new(&setup.control, &navigation.estimate());
        controller.set_trim(&command);
        let guidance = Guidance::new(mission.operations.clone());
        let sensors = SensorSuite::new(&setup.sensors, seed);
        let camera = match &setup.camera {
            None => None,
            Some(c) => {
                let model = Camera::from_config(&c.camera)
                    .map_err(|e| FlightError::Camera(e.to_string()))?;
                c.mounting
                    .validate()
                    .map_err(|e| FlightError::Camera(e.to_string()))?;
                let renderer = Renderer::with_options(model, c.options)
                    .map_err(|e| FlightError::Camera(e.to_string()))?;
                Some(FlightCamera {
                    terrain: std::sync::Arc::clone(&c.terrain),
                    renderer,
                    mounting: crate::sensors::camera::draw_mounting(&c.mounting, seed),
                    steps_per_frame: steps_per("camera.period_s", c.period_s, step_s)?,
                    noise_seed: rand::Rng::next_u64(&mut rng::stream(seed, "camera_noise")),
                    h_agl_error_m: c.h_agl_sigma_m
                        * rng::normal(&mut rng::stream(seed, "height_over_terrain_error")),
                    h_agl_sigma_m: c.h_agl_sigma_m,
                    outages_s: c.outages_s.clone(),
                })
            }
        };

        let nav = match setup.navigation {
            NavigationMode::Truth => None,
            NavigationMode::Ins => {
                let mut cfg = NavConfig::new(setup.ins.clone(), scn.magnetic_decimal_year);
                cfg.vision = setup.vision.clone();
                if let Some((vision, compared)) =
                    navigator_vision(&setup.vision_systems, &setup.vision)
                {
                    cfg.vision = vision;
                    cfg.compared_vision = compared;
                }
                cfg.camera = setup
                    .camera
                    .as_ref()
                    .filter(|c| c.vision_navigation)
                    .zip(camera.as_ref())
                    .map(|(c, fc)| NavCamera {
                        intrinsics: c.camera,
                        mounting: fc.mounting.estimate,
                    });
                if setup.fused {
                    cfg.fusion = Some(ianav::nav::fusion::FusionConfig::default());
                    cfg.vision_restart = Some(ianav::nav::VisionRestart::default());
                }
                Some(Navigator::new(&cfg)?)
            }
        };

        Ok(Self {
            seed,
            scenario_name: scn.name.clone(),
            rates,
            steps_per_sensor,
            steps_per_air,
            steps_per_mag,
            steps_per_control,
            steps_per_output,
            steps_per_gnss,
            warmup_us: to_us(scn.warmup_s),
            end_us: to_us(scn.warmup_s + scn.duration_s),
            gnss_loss_us: to_us(scn.warmup_s + scn.gnss_loss_s),
            step_index: 0,
            aircraft,
            actuators,
            x,
            command,
            initial_mass_kg: mass_kg,
            weather,
            wind,
            turbulence,
            gravity,
            mag_ned_nt: magnetic_grid.field_ned_nt(&pos)? + magnetic.error_ned_nt,
            magnetic,
            magnetic_grid,
            air,
            hp_m,
            offsets,
            sensors,
            guidance,
            controller,
            estimate: navigation.estimate(),
            ins_init_rng: rng::stream(seed, "ins.init"),
            nav,
            vision_names: setup.vision_systems.iter().map(|s| s.name()).collect(),
            vision_outputs: Vec::new(),
            nav_solution: None,
            pending_events: Vec::with_capacity(8),
            position_aid: None,
            position_aid_used: false,
            camera,
            mission,
            distance_m: 0.0,
            h_range_m: [f64::INFINITY, f64::NEG_INFINITY],
            sensor_events: 0,
            operations: Vec::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_setups_are_refused_with_the_key() {
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.aircraft.actuators.elevator_travel_deg = -1.0;
        let err = Flight::new(&setup, 1).err().unwrap().to_string();
        assert!(err.contains("elevator_travel_deg"), "{err}");
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.sensors.imu_period_s = 0.003; // not a multiple of the 2 ms step
        let err = Flight::new(&setup, 1).err().unwrap().to_string();
        assert!(err.contains("imu_period_s"), "{err}");
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.vision.pose.tukey_k = 0.0;
        let err = Flight::new(&setup, 1).err().unwrap().to_string();
        assert!(err.contains("vision.pose.tukey_k"), "{err}");
    }

    #[test]
    fn the_navigator_runs_the_setup_s_vision_settings() {
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.vision.pose.max_iterations = 5;
        let flight = Flight::new(&setup, 1).unwrap();
        let nav = flight.navigator().unwrap();
        assert_eq!(nav.config().vision, setup.vision);
    }
}
