//! One simulated flight (paper figure "flow diagram", table "Working frequencies"): the
//! environment and the 6-DOF aircraft integrated at 500 Hz, sensors sampled at 100 Hz (GNSS at
//! 1 Hz until it is lost), guidance and control at 50 Hz closing the loop on the *navigation
//! estimate*, and truth output at 10 Hz. A flight is a pure function of its setup and seed.
//! With a camera set up, a 10 Hz frame rendered from the true camera pose is delivered as
//! `SensorEvent::Frame` from mission time 0 on.
//!
//! This module holds [`Flight`] and its stepping; [`FlightSetup`] and the set-up of a flight
//! are in `setup.rs`, sensor sampling and the start alignment in `sensors.rs`, and what a
//! flight reports ([`FlightObserver`], [`FlightSummary`]) in `observer.rs`.

use ianav::env::atmosphere::{self, AtmosphereOffsets};
use ianav::env::magnetic::MagneticGrid;
use ianav::math::{so3, wgs84};
use ianav::nav::{NavSolution, Navigator};
use ianav::sensors::SensorEvent;
use nalgebra::Vector3;

use crate::aircraft::{Actuators, AirInputs, Aircraft, Controls, TruthState, air_relative};
use crate::control::{Controller, Guidance, NavEstimate};
use crate::env::{TrueGravity, TrueMagneticField, Turbulence, WeatherOffsets, WindField};
use crate::rng;
use crate::scenario::Mission;
use crate::sensors::SensorSuite;
use crate::terrain::Terrain;
use crate::terrain::render::Renderer;
use ianav::vision::camera::MountingPair;

mod observer;
mod sensors;
mod setup;
pub mod systems;

pub use observer::{
    FlightObserver, FlightSummary, NoObserver, OperationRecord, TruthSample, VisionOutput,
};
pub(crate) use sensors::estimate_from_nav;
pub use setup::{CameraSetup, FlightError, FlightSetup, NavigationMode, PositionAid, RatesConfig};

/// Envelope outside which a flight is declared departed: the aerodynamic model holds up to
/// the stall and the atmosphere model well above these altitudes.
const MIN_TAS_MPS: f64 = 10.0;
const MAX_TAS_MPS: f64 = 80.0;
const MIN_H_M: f64 = -500.0;
const MAX_H_M: f64 = 15_000.0;

/// The camera of a flight in progress.
struct FlightCamera {
    terrain: std::sync::Arc<Terrain>,
    renderer: Renderer,
    mounting: MountingPair,
    steps_per_frame: u64,
    noise_seed: u64,
    /// Error of the height over the terrain offered with each frame (drawn once), m.
    h_agl_error_m: f64,
    /// Its σ, m.
    h_agl_sigma_m: f64,
    /// Mission-time windows without frames, s.
    outages_s: Vec<(f64, f64)>,
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
    /// Names of the navigator's visual systems, in its order (with a camera).
    vision_names: Vec<&'static str>,
    /// The visual systems' states at the latest output (kept to reuse its allocation).
    vision_outputs: Vec<VisionOutput>,
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

/// Seconds → microseconds, rounded (times are validated finite and non-negative).
fn to_us(t_s: f64) -> u64 {
    (t_s * 1e6).round().max(0.0) as u64
}

impl Flight {
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
        let mission_s = self.mission_time_s();
        if let Some(cam) = &self.camera
            && k.is_multiple_of(cam.steps_per_frame)
            && self.t_us() >= self.warmup_us
            && !cam
                .outages_s
                .iter()
                .any(|(a, b)| (*a..*b).contains(&mission_s))
        {
            // The height over the terrain (with its drawn error) comes with every frame: the
            // visual navigation takes it at the image it starts from. Frames go before the
            // output of the same step, so that the output shows the visual pose of its instant.
            let height = SensorEvent::HeightAboveTerrain(self.height_above_terrain(cam));
            let frame = SensorEvent::Frame(self.render_frame(cam, k)?);
            for event in [height, frame] {
                self.sensor_events += 1;
                observer.sensor_event(&event);
                if let Some(nav) = self.nav.as_mut() {
                    // No solution: neither steps the navigation.
                    nav.push(&event);
                }
            }
            // The solution of this step predates the frame: give it the frame's visual pose.
            if let (Some(nav), Some(sol)) = (self.nav.as_ref(), self.nav_solution.as_mut()) {
                sol.vision = *nav.vision();
                sol.vision_fix = nav.vision_fix().copied();
            }
        }
        if k.is_multiple_of(self.steps_per_output) {
            let truth = self.truth_sample();
            observer.truth_sample(&truth);
            observer.estimate_sample(&truth, &self.estimate);
            if let Some(solution) = &self.nav_solution {
                observer.nav_solution(&truth, solution);
                if let Some(nav) = self.nav.as_ref()
                    && self.camera.is_some()
                {
                    self.vision_outputs.clear();
                    self.vision_outputs
                        .extend(
                            nav.visual_systems()
                                .zip(&self.vision_names)
                                .map(|(v, name)| VisionOutput {
                                    name,
                                    status: *v.status,
                                    fix: v.fix.copied(),
                                }),
                        );
                    if !self.vision_outputs.is_empty() {
                        observer.vision_outputs(&truth, solution.t_us, &self.vision_outputs);
                    }
                }
            }
        }
        Ok(())
    }

    /// The true and estimated camera mountings of this run (with a camera set up).
    pub fn camera_mounting(&self) -> Option<&MountingPair> {
        self.camera.as_ref().map(|c| &c.mounting)
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
