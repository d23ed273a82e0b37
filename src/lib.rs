//! ianav: GNSS-denied navigation for fixed-wing UAVs.
//!
//! The navigation core is synchronous and deterministic: it is fed timestamped
//! [`sensors::SensorEvent`]s and returns estimates. The simulator (`ianav-sim`), the Monte
//! Carlo and the MAVLink daemon drive the same core.
//!
//! Conventions (frames, rotations, units, time) follow `docs/ARCHITECTURE.md` and the paper:
//! ECEF `E`, NED `N`, body `B`, camera `C`; Hamilton quaternions with `v_a = q_ab * v_b`;
//! right perturbations `X ⊕ τ = X ∘ Exp(τ)`; SI units and radians; time in `t_us: u64`.

#[cfg(feature = "daemon")]
pub mod daemon;
pub mod env;
pub mod ins;
pub mod io;
pub mod math;
pub mod nav;
pub mod sensors;
pub mod vision;
