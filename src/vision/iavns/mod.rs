//! The inertially assisted visual navigation system (IA-VNS) of the paper's sections
//! "IA-VNS rationale" to "IA-VNS other modifications": SVO's pose optimisation pulled towards the
//! INS attitude and altitude by priors that a PI-inspired rule switches on only when the
//! visual estimate has drifted beyond what the INS can vouch for.
//!
//! - [`activation`]: the PI-inspired activation (paper table "priors activation"): from the
//!   visual-minus-inertial altitude, pitch, rate of climb and bank errors, the per-image pitch
//!   and bank adjustments of the target attitude.
//! - [`prior`]: stage 1 (the reprojection-only solution, its body pose, the target camera
//!   attitude `q_ec°°`), the attitude adjustment error `E_q` and the joint prior-based pose
//!   optimisation `E_PO = E_RP + f_q·E_q`.

pub mod activation;
pub mod prior;
