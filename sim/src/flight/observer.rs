//! What a flight produces: the [`FlightObserver`] it reports to, truth at the output rate
//! ([`TruthSample`]) and the facts of a finished flight ([`FlightSummary`]).

use ianav::env::atmosphere::AtmosphereOffsets;
use ianav::math::wgs84::Geodetic;
use ianav::nav::{NavSolution, VisionFix, VisionStatus};
use ianav::sensors::SensorEvent;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::aircraft::{AirRelative, Controls};
use crate::control::{NavEstimate, Operation};

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
    /// Every visual system's state at the output rate (a camera flight on the INS navigation),
    /// right after `nav_solution` of time `t_us`, in the order of
    /// [`FlightSetup::vision_systems`](super::FlightSetup::vision_systems).
    fn vision_outputs(&mut self, _truth: &TruthSample, _t_us: u64, _systems: &[VisionOutput]) {}
    /// A guidance operation started at mission time `t_s`.
    fn operation_started(&mut self, _t_s: f64, _index: usize, _operation: &Operation) {}
}

/// One visual system's state at an output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionOutput {
    /// Its name (`vns`, `ia-vns`, …: [`super::systems::VisionSystem::name`]).
    pub name: &'static str,
    /// State and latest frame.
    pub status: VisionStatus,
    /// Latest pose, while it tracks (its `t_us` is the frame's).
    pub fix: Option<VisionFix>,
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
