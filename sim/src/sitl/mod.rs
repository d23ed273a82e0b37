//! `ianav-sim sitl`: the simulator as a MAVLink vehicle for the ianav daemon (docs/REFERENCES.md M3
//! autopilot output, M3.3 message intervals, M3.4 TIMESYNC, M4–M5 camera frames and SITL;
//! `docs/SITL.md` for what is sent and why).
//!
//! - [`vehicle`]: the flight seen through an autopilot's MAVLink interface (synchronous,
//!   transport-free).
//! - [`streams`]: ArduPilot's, PX4 v1.16's and the `ideal` vehicle's message scheduling and
//!   interval requests (as the real autopilots behave).
//! - [`convert`]: SI ↔ MAVLink units.
//! - [`frames`]: the camera frame stream server.
//! - [`timesync`]: the vehicle's TIMESYNC requests and its map of the companion's clock.
//! - [`link`]: the async driver: MAVLink connection, real-time pacing, `sitl.csv`.

pub mod convert;
pub mod frames;
pub mod link;
pub mod streams;
pub mod timesync;
pub mod vehicle;

pub use link::{FramesListen, Progress, SitlError, SitlOptions, SitlSummary, run};
pub use streams::Autopilot;
pub use vehicle::{Vehicle, VehicleConfig};
