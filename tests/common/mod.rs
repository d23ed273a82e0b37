//! Helpers shared by the integration tests.

pub mod daemon_run;
pub mod extremes;
pub mod fake_autopilot;
