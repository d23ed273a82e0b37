//! The simulated world around the aircraft (docs/REFERENCES.md A3): weather offsets (ΔT, Δp) ramps,
//! wind ramps, Dryden turbulence, and the "true" gravity and magnetic fields that differ from
//! the navigation's models by per-run random errors.

pub mod geophysics;
pub mod offsets;
pub mod turbulence;
pub mod wind;

pub use geophysics::{TrueGravity, TrueMagneticField};
pub use offsets::{OffsetsConfig, WeatherOffsets};
pub use turbulence::{DrydenParams, Severity, Turbulence, TurbulenceConfig};
pub use wind::{WindConfig, WindField};
