//! Angle wrapping, the one implementation used by the whole workspace (docs/ARCHITECTURE.md
//! "Conventions": radians inside code; degrees only at configuration and output boundaries).
//!
//! Convention: every function maps onto the interval that is *open below and closed above*,
//! `(−π, π]` in radians and `(−180°, 180°]` in degrees, so `+π` and `−π` (or ±180°) both
//! map to `+π` (+180°), matching `atan2`'s range.
//!
//! The reduction is exact: an input already inside the interval is returned unchanged (bit
//! for bit, including `−0.0`), and any other finite input becomes `x − k·P` for an integer
//! `k` and the `f64` period `P` (`TAU` or 360) without rounding, because the remainder `x % P`
//! is exact in IEEE arithmetic and the final `± P` shift of a remainder in `(P/2, P)` is exact
//! by Sterbenz's lemma. (For huge inputs this is the reduction modulo the `f64` value of 2π,
//! not the real 2π; the result still lies in the interval.) NaN and ±∞ give NaN.

use std::f64::consts::{PI, TAU};

/// Half a turn, degrees.
const HALF_TURN_DEG: f64 = 180.0;
/// A full turn, degrees.
const FULL_TURN_DEG: f64 = 360.0;

/// Reduce `x` modulo `period` onto `(−half, half]` (`half = period/2`, both exact `f64`).
#[inline]
fn wrap_symmetric(x: f64, half: f64, period: f64) -> f64 {
    // Fast path: most calls (differences of wrapped angles, positions) are already in range,
    // and this keeps them bit-identical. NaN fails the test and propagates through `%`.
    if x > -half && x <= half {
        return x;
    }
    // Exact remainder with the sign of `x`, |r| < period; then one exact shift.
    let r = x % period;
    if r > half {
        r - period
    } else if r <= -half {
        r + period
    } else {
        r
    }
}

/// Wrap an angle in radians onto `(−π, π]` (see the module documentation: exact, identity
/// inside the interval, `−π ↦ π`, NaN/±∞ ↦ NaN).
#[inline]
pub fn wrap_pi(angle_rad: f64) -> f64 {
    wrap_symmetric(angle_rad, PI, TAU)
}

/// Wrap an angle in degrees onto `(−180°, 180°]` (exact, identity inside the interval,
/// `−180 ↦ 180`, NaN/±∞ ↦ NaN). Used for bearings, wind directions and longitudes in
/// degrees (the WMM accepts the closed range [−180°, 180°], so this convention serves it too).
#[inline]
pub fn wrap_180_deg(angle_deg: f64) -> f64 {
    wrap_symmetric(angle_deg, HALF_TURN_DEG, FULL_TURN_DEG)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn radian_boundaries_and_multiples() {
        assert_eq!(wrap_pi(PI), PI);
        // TAU is exactly 2·PI in f64, so −π + 2π is exactly π.
        assert_eq!(wrap_pi(-PI), PI);
        assert_eq!(wrap_pi(0.0), 0.0);
        assert!(wrap_pi(-0.0).is_sign_negative());
        assert_eq!(wrap_pi(0.5), 0.5);
        assert_eq!(wrap_pi(PI.next_down()), PI.next_down());
        assert_eq!(wrap_pi((-PI).next_up()), (-PI).next_up());
        assert_eq!(wrap_pi(TAU), 0.0);
        assert_eq!(wrap_pi(-TAU), 0.0);
        // Exact shifts: x ± TAU for x just outside the interval.
        assert_eq!(wrap_pi(PI + 0.1), PI + 0.1 - TAU);
        assert_eq!(wrap_pi(-PI - 0.1), -PI - 0.1 + TAU);
        // 3·PI happens to be exact in f64 and the reduction is exact: 3π ↦ π, the closed end.
        assert_eq!(wrap_pi(3.0 * PI), PI);
        assert_eq!(wrap_pi(-3.0 * PI), PI);
        // Angles k turns away: k·TAU + 0.3 is rounded once (≤ ½ ulp of ≤ 32, i.e. 3.6e-15),
        // and the reduction is exact, so the result is within that of 0.3.
        for k in -5..=5 {
            let base = 0.3 + TAU * f64::from(k);
            assert!((wrap_pi(base) - 0.3).abs() < 4e-15, "{k}");
        }
        // A difference across ±180°: 179° − (−179°) is −2°, not 358°.
        let d = wrap_pi(179_f64.to_radians() - (-179_f64).to_radians());
        assert!((d.to_degrees() + 2.0).abs() < 1e-9);
    }

    #[test]
    fn degree_boundaries_and_multiples() {
        assert_eq!(wrap_180_deg(180.0), 180.0);
        assert_eq!(wrap_180_deg(-180.0), 180.0);
        assert_eq!(wrap_180_deg(190.0), -170.0);
        assert_eq!(wrap_180_deg(-190.0), 170.0);
        assert_eq!(wrap_180_deg(540.0), 180.0);
        assert_eq!(wrap_180_deg(-540.0), 180.0);
        assert_eq!(wrap_180_deg(360.0), 0.0);
        assert_eq!(wrap_180_deg(-720.0), 0.0);
        assert_eq!(wrap_180_deg(270.0), -90.0);
        assert_eq!(wrap_180_deg(-270.0), 90.0);
        // In range: unchanged bit for bit (the old `(x + 180) mod 360 − 180` form rounded
        // here: it gave −0.09999999999999432 for −0.1).
        for x in [-0.1, 0.1, -89.4, 179.999_999_999, -179.999_999_999] {
            assert_eq!(wrap_180_deg(x).to_bits(), x.to_bits());
        }
        // Integer degrees stay integers (360 and the results are exact).
        for k in -1000..=1000 {
            let w = wrap_180_deg(f64::from(k));
            assert_eq!(w.fract(), 0.0);
            assert!(w > -180.0 && w <= 180.0);
            assert_eq!((f64::from(k) - w).rem_euclid(360.0), 0.0);
        }
    }

    #[test]
    fn non_finite_and_huge_inputs() {
        for f in [wrap_pi, wrap_180_deg] {
            assert!(f(f64::NAN).is_nan());
            assert!(f(f64::INFINITY).is_nan());
            assert!(f(f64::NEG_INFINITY).is_nan());
        }
        for x in [1e300, -1e300, f64::MAX, f64::MIN, -1e17, 2f64.powi(60)] {
            let r = wrap_pi(x);
            assert!(r > -PI && r <= PI, "{x} → {r}");
            let d = wrap_180_deg(x);
            assert!(d > -180.0 && d <= 180.0, "{x} → {d}");
        }
        // Exact even far out: 360 = 8·45 and 2¹² ≡ 1 (mod 45), so 2⁵⁷ ≡ 2⁹ ≡ 17 (mod 45)
        // and 2⁶⁰ = 8·2⁵⁷ ≡ 8·17 = 136 (mod 360).
        assert_eq!(wrap_180_deg(2f64.powi(60)), 136.0);
    }

    proptest! {
        /// In range, idempotent, and a whole number of periods away from the input. The last
        /// check: `w` is exactly `x − k·P`; forming `x − w` and dividing by `P` round by ≤ ½
        /// ulp each, so the quotient is within 2ε·|k| + ε < 1e-15·(|k| + 1) of the integer k.
        #[test]
        fn wraps_by_whole_turns(x in -1e6_f64..1e6) {
            type Wrap = fn(f64) -> f64;
            let cases: [(Wrap, f64, f64); 2] = [
                (wrap_pi, PI, TAU),
                (wrap_180_deg, HALF_TURN_DEG, FULL_TURN_DEG),
            ];
            for (wrap, half, period) in cases {
                let w = wrap(x);
                prop_assert!(w > -half && w <= half);
                prop_assert_eq!(wrap(w).to_bits(), w.to_bits());
                let turns = (x - w) / period;
                prop_assert!((turns - turns.round()).abs() <= 1e-15 * (turns.abs() + 1.0));
            }
        }
    }
}
