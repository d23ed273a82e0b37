//! One simulated flight (paper figure "flow diagram", table "Working frequencies"): the
//! environment and the 6-DOF aircraft integrated at 500 Hz, sensors sampled at 100 Hz (GNSS at
//! 1 Hz until it is lost), guidance and control at 50 Hz closing the loop on the *navigation
//! estimate*, and truth output at 10 Hz. A flight is a pure function of its setup and seed.
//! With a camera set up, a 10 Hz frame rendered from the true camera pose is delivered as
//! `SensorEvent::Frame` from mission time 0 on.

use ianav::env::atmosphere::{self, AtmosphereOffsets};
use ianav::env::magnetic::{MagneticGrid, MagneticModel};
use ianav::ins::InsConfig;
use ianav::math::wgs84::Geodetic;
use ianav::math::{so3, wgs84};
use ianav::nav::{NavCamera, NavConfig, NavSolution, Navigator};
use ianav::sensors::{Alignment, Frame, SensorErrorPriors, SensorEvent};
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::aircraft::{
    Actuators, AirInputs, AirRelative, Aircraft, AircraftParams, Controls, Loads, TruthState,
    air_relative,
};
use crate::control::{
    ControlConfig, Controller, Guidance, NavEstimate, Navigation, Operation, TruthNavigation,
};
use crate::env::{
    DrydenParams, TrueGravity, TrueMagneticField, Turbulence, TurbulenceConfig, WeatherOffsets,
    WindField,
};
use crate::rng;
use crate::scenario::{Mission, ScenarioConfig};
use crate::sensors::{SensorSuite, SensorTruth, SensorsConfig};
use crate::terrain::Terrain;
use crate::terrain::render::{RenderError, RenderOptions, Renderer};
use ianav::vision::camera::{Camera, CameraConfig, MountingConfig, MountingPair};

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
    /// The control configuration is invalid.
    #[error("control: {0}")]
    Control(#[from] crate::control::ControlConfigError),
    /// The camera could not be set up (a frame that cannot be rendered, e.g. because the
    /// aircraft flew into the terrain, ends the flight as `Departed`).
    #[error("camera: {0}")]
    Camera(String),
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

/// Envelope outside which a flight is declared departed: the aerodynamic model holds up to
/// the stall and the atmosphere model well above these altitudes.
const MIN_TAS_MPS: f64 = 10.0;
const MAX_TAS_MPS: f64 = 80.0;
const MIN_H_M: f64 = -500.0;
const MAX_H_M: f64 = 15_000.0;

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
        }
    }
}

/// The camera of a flight in progress.
struct FlightCamera {
    terrain: std::sync::Arc<Terrain>,
    renderer: Renderer,
    mounting: MountingPair,
    steps_per_frame: u64,
    noise_seed: u64,
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
    /// Camera and terrain (`None`: no frames, the default).
    pub camera: Option<CameraSetup>,
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
            camera: None,
        })
    }
}

/// Truth at the output rate: what the trajectory file holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    /// Simulation time since the start of the warm-up (the sensor clock), microseconds.
    pub t_us: u64,
    /// Mission time, s (negative during the warm-up).
    pub t_s: f64,
    /// Position of the CG.
    pub pos: Geodetic,
    /// Ground velocity, NED, m/s.
    pub v_ned_mps: Vector3<f64>,
    /// Attitude.
    pub q_nb: UnitQuaternion<f64>,
    /// Yaw, pitch, bank, rad.
    pub euler_rad: Vector3<f64>,
    /// Angular velocity relative to NED, body axes, rad/s.
    pub w_nb_b_rps: Vector3<f64>,
    /// Air-relative motion.
    pub air: AirRelative,
    /// Pressure altitude, m.
    pub hp_m: f64,
    /// Low-frequency wind, NED, m/s.
    pub wind_ned_mps: Vector3<f64>,
    /// Turbulence, body axes, m/s.
    pub turb_b_mps: Vector3<f64>,
    /// Rotational turbulence (angular velocity of the air), body axes, rad/s.
    pub turb_rate_b_rps: Vector3<f64>,
    /// Atmosphere offsets.
    pub offsets: AtmosphereOffsets,
    /// Control surface and throttle positions.
    pub controls: Controls,
    /// Ground distance flown since mission time 0, m.
    pub distance_m: f64,
    /// Mass, kg.
    pub mass_kg: f64,
    /// Index of the guidance operation being flown.
    pub operation: usize,
}

/// Receives what a flight produces; every method has an empty default.
pub trait FlightObserver {
    /// Every sensor sample, in time order.
    fn sensor_event(&mut self, _event: &SensorEvent) {}
    /// Truth at the output rate.
    fn truth_sample(&mut self, _sample: &TruthSample) {}
    /// Truth and the navigation estimate guidance and control are flying on, at the output
    /// rate (right after `truth_sample`): what navigation-error metrics are computed from.
    fn estimate_sample(&mut self, _truth: &TruthSample, _estimate: &NavEstimate) {}
    /// Truth and the full INS solution at the output rate (INS navigation only, once the INS
    /// has started), right after `estimate_sample`.
    fn nav_solution(&mut self, _truth: &TruthSample, _solution: &NavSolution) {}
    /// A guidance operation started at mission time `t_s`.
    fn operation_started(&mut self, _t_s: f64, _index: usize, _operation: &Operation) {}
}

/// Observer that ignores everything (benchmarks).
#[derive(Debug, Default, Clone, Copy)]
pub struct NoObserver;
impl FlightObserver for NoObserver {}

/// Facts about a finished flight.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlightSummary {
    /// Seed of the run.
    pub seed: u64,
    /// Scenario name.
    pub scenario: String,
    /// Warm-up flown before mission time 0, s: sensor times `t_us` count from the start of
    /// the warm-up, so mission time = `t_us`·1e-6 − `warmup_s`.
    pub warmup_s: f64,
    /// Mission time of the last GNSS fix, s.
    pub gnss_loss_s: f64,
    /// Mission time flown after the warm-up, s.
    pub duration_s: f64,
    /// Ground distance flown from mission time 0, m.
    pub distance_m: f64,
    /// Guidance operations started (including the first), in order, with mission start times.
    pub operations: Vec<OperationRecord>,
    /// Number of truth integration steps.
    pub truth_steps: u64,
    /// Number of sensor events produced.
    pub sensor_events: u64,
    /// Final position.
    pub final_pos: Geodetic,
    /// Lowest and highest geometric altitude after mission time 0, m.
    pub h_range_m: [f64; 2],
    /// Fuel burnt, kg.
    pub fuel_burnt_kg: f64,
}

/// One executed operation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OperationRecord {
    /// Index in the mission.
    pub index: usize,
    /// Mission time it started, s.
    pub t_start_s: f64,
    /// The operation.
    pub operation: Operation,
}

/// A flight in progress.
pub struct Flight {
    seed: u64,
    scenario_name: String,
    rates: RatesConfig,
    /// Truth steps per sensor, control and output period, and per GNSS fix.
    steps_per_sensor: u64,
    steps_per_air: u64,
    steps_per_mag: u64,
    steps_per_control: u64,
    steps_per_output: u64,
    steps_per_gnss: u64,
    warmup_us: u64,
    end_us: u64,
    gnss_loss_us: u64,
    step_index: u64,

    aircraft: Aircraft,
    actuators: Actuators,
    x: TruthState,
    command: Controls,
    initial_mass_kg: f64,

    weather: WeatherOffsets,
    wind: WindField,
    turbulence: Turbulence,
    gravity: TrueGravity,
    magnetic: TrueMagneticField,
    /// Cached interpolation of the magnetic model (the exact WMM costs ~0.8 µs per call).
    magnetic_grid: MagneticGrid,
    /// Last true magnetic field, NED, nT (kept if the model cannot be evaluated).
    mag_ned_nt: Vector3<f64>,
    /// Turbulence and air at the current state.
    air: AirInputs,
    hp_m: f64,
    offsets: AtmosphereOffsets,

    sensors: SensorSuite,
    guidance: Guidance,
    controller: Controller,
    /// The estimate guidance and control fly on (truth until the INS has a solution).
    estimate: NavEstimate,
    /// Initial-error draws of the start alignment (docs/REFERENCES.md A1.9).
    ins_init_rng: rng::Stream,
    /// The navigation core (`None` under truth navigation).
    nav: Option<Navigator>,
    /// Latest navigation solution.
    nav_solution: Option<NavSolution>,
    /// Sensor events of the current sample instant, in the order the navigator consumes them.
    pending_events: Vec<SensorEvent>,
    /// External horizontal position and the largest age at which it is still used, µs.
    position_aid: Option<(PositionAid, u64)>,
    /// Whether the current estimate's horizontal position came from `position_aid`.
    position_aid_used: bool,

    camera: Option<FlightCamera>,
    mission: Mission,
    distance_m: f64,
    h_range_m: [f64; 2],
    sensor_events: u64,
    operations: Vec<OperationRecord>,
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

/// The estimate guidance and control need, from a navigation solution (rates and air data
/// from its INS detail).
pub(crate) fn estimate_from_nav(sol: &NavSolution) -> NavEstimate {
    NavEstimate {
        t_us: sol.t_us,
        pos: sol.pos,
        v_ned_mps: sol.v_ned_mps,
        q_nb: sol.q_nb,
        w_nb_b_rps: sol.ins.w_nb_b_rps,
        tas_mps: sol.ins.tas_mps,
        aoa_rad: sol.ins.aoa_rad,
        aos_rad: sol.ins.aos_rad,
        hp_m: sol.ins.hp_m,
    }
}

/// Seconds → microseconds, rounded (times are validated finite and non-negative).
fn to_us(t_s: f64) -> u64 {
    (t_s * 1e6).round().max(0.0) as u64
}

/// Replace the horizontal position of `estimate` (at `t_us`) by `aid`, carried from its time
/// of validity to `t_us` with the estimate's ground velocity on the ellipsoid's radii.
fn apply_position_aid(estimate: &mut NavEstimate, aid: &PositionAid, t_us: u64) {
    let dt_s = (t_us as f64 - aid.t_us as f64) * 1e-6;
    let h_m = estimate.pos.h_m;
    let v = estimate.v_ned_mps;
    let lat_rad = aid.lat_rad + v.x * dt_s / (wgs84::radius_meridian_m(aid.lat_rad) + h_m);
    let lon_rad = aid.lon_rad
        + v.y * dt_s / ((wgs84::radius_prime_vertical_m(aid.lat_rad) + h_m) * aid.lat_rad.cos());
    estimate.pos.lat_rad = lat_rad;
    estimate.pos.lon_rad = lon_rad;
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
                })
            }
        };

        let nav = match setup.navigation {
            NavigationMode::Truth => None,
            NavigationMode::Ins => {
                let mut cfg = NavConfig::new(setup.ins.clone(), scn.magnetic_decimal_year);
                cfg.camera = setup
                    .camera
                    .as_ref()
                    .zip(camera.as_ref())
                    .map(|(c, fc)| NavCamera {
                        intrinsics: c.camera,
                        mounting: fc.mounting.estimate,
                    });
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

    /// Simulation time since the start of the warm-up, microseconds.
    pub fn t_us(&self) -> u64 {
        self.step_index * to_us(self.rates.truth_step_s)
    }

    /// Mission time, s (negative during the warm-up).
    pub fn mission_time_s(&self) -> f64 {
        (self.t_us() as f64 - self.warmup_us as f64) * 1e-6
    }

    /// Mission end, s.
    pub fn end_time_s(&self) -> f64 {
        (self.end_us - self.warmup_us) as f64 * 1e-6
    }

    /// Whether the mission end has been reached.
    pub fn finished(&self) -> bool {
        self.t_us() >= self.end_us
    }

    /// Sensor-clock time of the last GNSS fix (the scenario's GNSS loss), µs.
    pub fn gnss_loss_t_us(&self) -> u64 {
        self.gnss_loss_us
    }

    /// Sensor-clock time of mission time 0 (the end of the warm-up), µs.
    pub fn warmup_us(&self) -> u64 {
        self.warmup_us
    }

    /// The estimate guidance and control fly on now.
    pub fn estimate(&self) -> &NavEstimate {
        &self.estimate
    }

    /// The vehicle's own navigation solution (`None` before the first fix or under truth
    /// navigation): what an autopilot derives its reported estimates from (e.g. its wind).
    pub fn nav_solution(&self) -> Option<&NavSolution> {
        self.nav_solution.as_ref()
    }

    /// The navigation core (`None` under truth navigation).
    pub fn navigator(&self) -> Option<&Navigator> {
        self.nav.as_ref()
    }

    /// Fly on `aid` (see [`PositionAid`]) as long as it is at most `max_age_us` old, from the
    /// next sensor instant on; a newer call replaces it. Ignored under truth navigation.
    pub fn set_position_aid(&mut self, aid: PositionAid, max_age_us: u64) {
        self.position_aid = Some((aid, max_age_us));
    }

    /// Stop using an external position.
    pub fn clear_position_aid(&mut self) {
        self.position_aid = None;
    }

    /// Whether the current estimate's horizontal position comes from the external aid.
    pub fn position_aid_used(&self) -> bool {
        self.position_aid_used
    }

    /// The current truth state.
    pub fn truth(&self) -> &TruthState {
        &self.x
    }

    /// The drawn mission.
    pub fn mission(&self) -> &Mission {
        &self.mission
    }

    /// The drawn weather offsets.
    pub fn weather(&self) -> &WeatherOffsets {
        &self.weather
    }

    /// The drawn wind.
    pub fn wind(&self) -> &WindField {
        &self.wind
    }

    /// The sensors (their true errors initialise the INS of the next issue).
    pub fn sensors(&self) -> &SensorSuite {
        &self.sensors
    }

    /// Truth at the current instant.
    pub fn truth_sample(&self) -> TruthSample {
        TruthSample {
            t_us: self.t_us(),
            t_s: self.mission_time_s(),
            pos: self.x.pos,
            v_ned_mps: self.x.q_nb * self.x.v_b_mps,
            q_nb: self.x.q_nb,
            euler_rad: so3::euler_zyx(&self.x.q_nb),
            w_nb_b_rps: {
                let v_ned_mps = self.x.q_nb * self.x.v_b_mps;
                let w_in_n = wgs84::omega_ie_n(self.x.pos.lat_rad)
                    + wgs84::omega_en_n(&self.x.pos, &v_ned_mps);
                self.x.w_ib_b_rps - self.x.q_nb.inverse() * w_in_n
            },
            air: air_relative(&self.x, &self.air),
            hp_m: self.hp_m,
            wind_ned_mps: self.air.wind_ned_mps,
            turb_b_mps: self.air.turb_b_mps,
            turb_rate_b_rps: self.air.turb_rate_b_rps,
            offsets: self.offsets,
            controls: self.actuators.position(),
            distance_m: self.distance_m,
            mass_kg: self.x.mass_kg,
            operation: self.guidance.index(),
        }
    }

    /// Error if the aircraft left the envelope in which the models hold.
    fn check_envelope(&self) -> Result<(), FlightError> {
        let x = &self.x;
        let finite = x.pos.lat_rad.is_finite()
            && x.pos.lon_rad.is_finite()
            && x.v_b_mps
                .iter()
                .chain(x.w_ib_b_rps.iter())
                .all(|v| v.is_finite())
            && x.q_nb.coords.iter().all(|v| v.is_finite());
        let tas_mps = air_relative(x, &self.air).tas_mps;
        let reason = if !finite {
            "non-finite state".to_owned()
        } else if !(MIN_H_M..=MAX_H_M).contains(&x.pos.h_m) {
            format!(
                "altitude {:.0} m outside [{MIN_H_M}, {MAX_H_M}] m",
                x.pos.h_m
            )
        } else if !(MIN_TAS_MPS..=MAX_TAS_MPS).contains(&tas_mps) {
            format!("airspeed {tas_mps:.1} m/s outside [{MIN_TAS_MPS}, {MAX_TAS_MPS}] m/s")
        } else {
            return Ok(());
        };
        Err(FlightError::Departed {
            t_s: self.mission_time_s(),
            reason,
        })
    }

    /// Advance one truth step; an error means the flight departed and must stop.
    pub fn step(&mut self, observer: &mut impl FlightObserver) -> Result<(), FlightError> {
        let k = self.step_index;
        let t_mission_s = self.mission_time_s();
        if k.is_multiple_of(self.steps_per_control) {
            let nav = self.estimate;
            if let Some(index) = self.guidance.update(t_mission_s, &nav) {
                self.record_operation(t_mission_s, index, observer);
            } else if k == 0 {
                self.record_operation(t_mission_s, 0, observer);
            }
            self.command = self.controller.step(self.guidance.current(), &nav);
        }
        let dt_s = self.rates.truth_step_s;
        let position = self.actuators.step(&self.command, dt_s);

        // Air at the current position and time; turbulence advanced by one step.
        self.offsets = self.weather.at(t_mission_s);
        self.hp_m = atmosphere::pressure_altitude_from_geometric_m(self.x.pos.h_m, &self.offsets);
        let p_pa = atmosphere::pressure_pa(self.hp_m);
        let temp_k = atmosphere::temperature_k(self.hp_m, self.offsets.delta_t_k);
        let tas_prev = air_relative(&self.x, &self.air).tas_mps;
        self.air = AirInputs {
            p_pa,
            temp_k,
            rho_kgpm3: atmosphere::density_kgpm3(p_pa, temp_k),
            wind_ned_mps: self.wind.at(t_mission_s),
            turb_b_mps: self.turbulence.step(dt_s, tas_prev, self.x.pos.h_m),
            turb_rate_b_rps: self.turbulence.rate_b_rps(),
        };
        let gravity = self.gravity.gravity_ned_mps2(&self.x.pos);
        let v_before = self.x.q_nb * self.x.v_b_mps;
        self.x = self
            .aircraft
            .step(&self.x, &position, &self.air, &gravity, dt_s);
        self.step_index += 1;
        self.check_envelope()?;

        if self.t_us() > self.warmup_us {
            // Trapezoidal integral of the horizontal ground speed (2nd order in the step).
            let v_after = self.x.q_nb * self.x.v_b_mps;
            self.distance_m +=
                0.5 * (v_before.x.hypot(v_before.y) + v_after.x.hypot(v_after.y)) * dt_s;
            self.h_range_m = [
                self.h_range_m[0].min(self.x.pos.h_m),
                self.h_range_m[1].max(self.x.pos.h_m),
            ];
        }
        let k = self.step_index;
        let due = |every: u64| k.is_multiple_of(every);
        if due(self.steps_per_sensor)
            || due(self.steps_per_air)
            || due(self.steps_per_mag)
            || due(self.steps_per_gnss)
        {
            self.sample_sensors(&position, observer)?;
        }
        if k.is_multiple_of(self.steps_per_output) {
            let truth = self.truth_sample();
            observer.truth_sample(&truth);
            observer.estimate_sample(&truth, &self.estimate);
            if let Some(solution) = &self.nav_solution {
                observer.nav_solution(&truth, solution);
            }
        }
        if let Some(cam) = &self.camera
            && k.is_multiple_of(cam.steps_per_frame)
            && self.t_us() >= self.warmup_us
        {
            let frame = SensorEvent::Frame(self.render_frame(cam, k)?);
            self.sensor_events += 1;
            observer.sensor_event(&frame);
            if let Some(nav) = self.nav.as_mut() {
                // No solution: frames do not step the navigation.
                nav.push(&frame);
            }
        }
        Ok(())
    }

    /// The true and estimated camera mountings of this run (with a camera set up).
    pub fn camera_mounting(&self) -> Option<&MountingPair> {
        self.camera.as_ref().map(|c| &c.mounting)
    }

    /// The frame seen now from the true camera pose.
    fn render_frame(&self, cam: &FlightCamera, k: u64) -> Result<Frame, FlightError> {
        let cg = self.aircraft.cg_from_reference_b_m(self.x.mass_kg);
        let zeta_ec = cam.mounting.truth.zeta_ec(&self.x.pos, &self.x.q_nb, &cg);
        let mut renderer = cam.renderer.clone();
        renderer.set_noise_seed(cam.noise_seed ^ k);
        let img = renderer
            .render(&cam.terrain, &zeta_ec)
            .map_err(|e: RenderError| FlightError::Departed {
                t_s: self.mission_time_s(),
                reason: format!("camera: {e}"),
            })?;
        Ok(Frame {
            t_us: self.t_us(),
            width: img.width,
            height: img.height,
            pixels: img.pixels.into(),
        })
    }

    fn record_operation(&mut self, t_s: f64, index: usize, observer: &mut impl FlightObserver) {
        let operation = *self.guidance.current();
        observer.operation_started(t_s, index, &operation);
        self.operations.push(OperationRecord {
            index,
            t_start_s: t_s,
            operation,
        });
    }

    fn sample_sensors(
        &mut self,
        controls: &Controls,
        observer: &mut impl FlightObserver,
    ) -> Result<(), FlightError> {
        let t_us = self.t_us();
        let loads: Loads = self.aircraft.loads(&self.x, controls, &self.air);
        let v_ned_mps = self.x.q_nb * self.x.v_b_mps;
        if let Ok(model_ned_nt) = self.magnetic_grid.field_ned_nt(&self.x.pos) {
            self.mag_ned_nt = model_ned_nt + self.magnetic.error_ned_nt;
        }
        let mag_ned_nt = self.mag_ned_nt;
        let truth = SensorTruth {
            t_us,
            pos: self.x.pos,
            v_ned_mps,
            q_nb: self.x.q_nb,
            w_ib_b_rps: self.x.w_ib_b_rps,
            w_dot_ib_b_rps2: loads.w_dot_ib_b_rps2,
            f_ib_b_mps2: loads.f_ib_b_mps2,
            cg_from_ref_b_m: self.aircraft.cg_from_reference_b_m(self.x.mass_kg),
            mag_ned_nt,
            tas_mps: loads.air.tas_mps,
            aoa_rad: loads.air.aoa_rad,
            aos_rad: loads.air.aos_rad,
            p_pa: self.air.p_pa,
            temp_k: self.air.temp_k,
        };
        let k = self.step_index;
        // Aiding samples first, then the IMU sample on which the INS steps, so that samples
        // taken at the same instant are fused in the same INS step.
        let mut events = std::mem::take(&mut self.pending_events);
        events.clear();
        if k.is_multiple_of(self.steps_per_air) {
            events.push(SensorEvent::Air(self.sensors.sample_air(&truth)));
        }
        if k.is_multiple_of(self.steps_per_mag) {
            events.push(SensorEvent::Mag(self.sensors.sample_mag(&truth)));
        }
        let fix_now = k.is_multiple_of(self.steps_per_gnss) && t_us <= self.gnss_loss_us;
        let w_in_n =
            wgs84::omega_ie_n(self.x.pos.lat_rad) + wgs84::omega_en_n(&self.x.pos, &v_ned_mps);
        let truth_estimate =
            TruthNavigation::from_truth(t_us, &self.x, &loads.air, &w_in_n, self.hp_m).estimate();
        if fix_now {
            events.push(SensorEvent::Gnss(self.sensors.sample_gnss(&truth)));
        }
        if k.is_multiple_of(self.steps_per_sensor) {
            events.push(SensorEvent::Imu(self.sensors.sample_imu(&truth)));
        }
        // The navigator starts the INS at the first GNSS fix (as the authors' filters do) from
        // the start alignment offered just before it; guidance flies on the truth until then
        // (the first second). Drawn after the IMU sample: the true sensor errors it is drawn
        // about are those of this instant's samples.
        if fix_now && self.nav.as_ref().is_some_and(|n| !n.is_initialised()) {
            let alignment = self.start_alignment(&truth_estimate);
            let at = events
                .iter()
                .position(|e| matches!(e, SensorEvent::Gnss(_)))
                .unwrap_or(events.len());
            events.insert(at, SensorEvent::Alignment(Box::new(alignment)));
        }
        self.sensor_events += events
            .iter()
            .filter(|e| !matches!(e, SensorEvent::Alignment(_)))
            .count() as u64;
        for event in &events {
            observer.sensor_event(event);
            if let Some(solution) = self.nav.as_mut().and_then(|nav| nav.push(event)) {
                self.nav_solution = Some(solution);
            }
        }
        self.pending_events = events;
        self.estimate = match &self.nav_solution {
            Some(sol) => estimate_from_nav(sol),
            None => truth_estimate,
        };
        self.position_aid_used = false;
        if let (Some((aid, max_age_us)), Some(_)) = (self.position_aid, &self.nav_solution)
            && t_us.abs_diff(aid.t_us) <= max_age_us
        {
            apply_position_aid(&mut self.estimate, &aid, t_us);
            self.position_aid_used = true;
        }
        Ok(())
    }

    /// The start alignment the simulated vehicle offers at the first fix, with the initial
    /// errors of docs/REFERENCES.md A1.9: attitude off by 0.1°·N about a random axis,
    /// sensor-error estimates within 1 % (10 % for the magnetic-model error) of the truth.
    fn start_alignment(&mut self, truth: &NavEstimate) -> Alignment {
        let r = &mut self.ins_init_rng;
        let axis = Vector3::new(rng::normal(r), rng::normal(r), rng::normal(r));
        let angle_rad = (0.1_f64).to_radians() * rng::normal(r);
        let q_err = so3::exp(&(axis.try_normalize(1e-12).unwrap_or(Vector3::x()) * angle_rad));
        let errors = self.sensors.true_errors();
        let mut scaled = |v: Vector3<f64>, rel: f64| -> (Vector3<f64>, Vector3<f64>) {
            (
                v.map(|x| x * (1.0 + rel * rng::normal(r))),
                v.map(|x| (rel * x).abs()),
            )
        };
        let (e_gyr_rps, e_gyr_sigma_rps) = scaled(errors.e_gyr_rps, 0.01);
        let (e_acc_mps2, e_acc_sigma_mps2) = scaled(errors.e_acc_mps2, 0.01);
        let (e_mag_nt, e_mag_sigma_nt) = scaled(errors.e_mag_nt, 0.01);
        let (delta_b_n_nt, delta_b_n_sigma_nt) = scaled(-self.magnetic.error_ned_nt, 0.1);
        Alignment {
            t_us: truth.t_us,
            q_nb: q_err * truth.q_nb,
            aoa_rad: truth.aoa_rad,
            priors: SensorErrorPriors {
                e_gyr_rps,
                e_gyr_sigma_rps,
                e_acc_mps2,
                e_acc_sigma_mps2,
                e_mag_nt,
                e_mag_sigma_nt,
                delta_b_n_nt,
                delta_b_n_sigma_nt,
            },
        }
    }

    /// Fly to the end of the mission, reporting progress (mission seconds) to `progress`.
    /// Stops with [`FlightError::Departed`] if the aircraft leaves the envelope.
    pub fn run(
        &mut self,
        observer: &mut impl FlightObserver,
        mut progress: impl FnMut(f64),
    ) -> Result<FlightSummary, FlightError> {
        let report_every = self.steps_per_output * 10;
        while !self.finished() {
            self.step(observer)?;
            if self.step_index.is_multiple_of(report_every) {
                progress(self.mission_time_s());
            }
        }
        Ok(self.summary())
    }

    /// Summary of the flight so far.
    pub fn summary(&self) -> FlightSummary {
        FlightSummary {
            seed: self.seed,
            scenario: self.scenario_name.clone(),
            warmup_s: self.warmup_us as f64 * 1e-6,
            gnss_loss_s: (self.gnss_loss_us - self.warmup_us) as f64 * 1e-6,
            duration_s: self.mission_time_s().max(0.0),
            distance_m: self.distance_m,
            operations: self.operations.clone(),
            truth_steps: self.step_index,
            sensor_events: self.sensor_events,
            final_pos: self.x.pos,
            h_range_m: self.h_range_m,
            fuel_burnt_kg: self.initial_mass_kg - self.x.mass_kg,
        }
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
    }

    #[test]
    fn a_fresh_position_aid_replaces_the_horizontal_estimate_and_a_stale_one_does_not() {
        let setup = FlightSetup::builtin(2).unwrap();
        let mut flight = Flight::new(&setup, 3).unwrap();
        while flight.nav_solution.is_none() {
            flight.step(&mut NoObserver).unwrap();
        }
        let t_us = flight.t_us();
        let truth = flight.truth().pos;
        // 1 km north of the truth, valid now, usable for 0.5 s.
        let aid = PositionAid {
            t_us,
            lat_rad: truth.lat_rad + 1_000.0 / wgs84::radius_meridian_m(truth.lat_rad),
            lon_rad: truth.lon_rad,
        };
        flight.set_position_aid(aid, 500_000);
        // Step to the next sensor instant (10 ms): the aid, carried by the INS velocity.
        for _ in 0..5 {
            flight.step(&mut NoObserver).unwrap();
        }
        assert!(flight.position_aid_used());
        let est = *flight.estimate();
        let carried = wgs84::ned_difference_m(&flight.truth().pos, &est.pos);
        assert!((carried.x - 1_000.0).abs() < 2.0, "{carried:?}");
        assert!(carried.y.abs() < 2.0, "{carried:?}");
        let ins_pos = flight.nav_solution.unwrap().pos;
        assert!(
            (est.pos.h_m - ins_pos.h_m).abs() < 1e-9,
            "height stays the INS's"
        );
        // 0.6 s later the aid is stale: back to the INS (within metres of the truth).
        for _ in 0..300 {
            flight.step(&mut NoObserver).unwrap();
        }
        assert!(!flight.position_aid_used());
        let d = wgs84::ned_difference_m(&flight.truth().pos, &flight.estimate().pos);
        assert!(d.x.hypot(d.y) < 50.0, "{d:?}");
        flight.clear_position_aid();
        assert!(flight.position_aid.is_none());
    }

    #[test]
    fn a_departed_flight_stops_with_an_error() {
        let setup = FlightSetup::builtin(2).unwrap();
        let mut flight = Flight::new(&setup, 1).unwrap();
        for _ in 0..10 {
            flight.step(&mut NoObserver).unwrap();
        }
        flight.x.pos.h_m = -1_000.0;
        let err = flight.step(&mut NoObserver).unwrap_err();
        assert!(matches!(err, FlightError::Departed { .. }), "{err}");
        let mut flight = Flight::new(&setup, 1).unwrap();
        flight.x.v_b_mps.x = f64::NAN;
        assert!(flight.run(&mut NoObserver, |_| {}).is_err());
    }
}
