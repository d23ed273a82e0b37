//! ianav-sim: the high-fidelity stochastic flight simulator of the paper's section
//! "Testing: High Fidelity Simulation and Scenarios" — environment, aircraft, guidance and
//! control, sensors, scenarios — driving the `ianav` navigation core.

pub mod aircraft;
pub mod control;
pub mod env;
pub mod flight;
pub mod metrics;
pub mod montecarlo;
pub mod output;
pub mod plots;
pub mod report;
pub mod rng;
pub mod scenario;
pub mod sensors;
pub mod sitl;
pub mod terrain;
pub mod vns_timing;
