//! Rotor saturation: which rotors sit at a thrust limit.
//!
//! The paper's saturation indicator of a tick (§ "Rotor saturation rate") is
//!
//! ```text
//!     χ_sat = 1[ ∃ i : ‖T_i‖ ≤ T_min  ∨  ‖T_i‖ ≥ T_max ]
//! ```
//!
//! evaluated, like the reference implementation, with a tolerance of
//! [`SATURATION_TOLERANCE_N`]. With T_min = 0 (every AM-Bench vehicle) an idle rotor counts as
//! saturated: it cannot push less, so the allocation has lost a direction.

use serde::Serialize;

/// Distance to a thrust limit, N, within which a rotor counts as at the limit (the reference's
/// `1e-5`). Well above the round-off of an allocation (~1e-12 N), well below any thrust a
/// controller would care about.
pub const SATURATION_TOLERANCE_N: f64 = 1e-5;

/// Where a rotor stands against its thrust limits: at or beyond a bound, within
/// [`SATURATION_TOLERANCE_N`]. This is the per-actuator feedback a controller's anti-windup
/// reads (PX4's upper/lower saturation flags).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum RotorSaturation {
    /// Strictly between the limits: the rotor can push more and less.
    #[default]
    None,
    /// At or below T_min: the rotor cannot push less.
    Lower,
    /// At or above T_max: the rotor cannot push more.
    Upper,
}

impl RotorSaturation {
    /// Classifies a thrust magnitude against `[thrust_min_n, thrust_max_n]`. The upper bound is
    /// tested first (it matters more to a controller when the band is narrower than the
    /// tolerance). A NaN thrust is [`RotorSaturation::None`]: the allocator never produces one;
    /// [`any_rotor_saturated`] treats it as saturated.
    pub fn of(thrust_n: f64, thrust_min_n: f64, thrust_max_n: f64) -> Self {
        if thrust_n >= thrust_max_n - SATURATION_TOLERANCE_N {
            Self::Upper
        } else if thrust_n <= thrust_min_n + SATURATION_TOLERANCE_N {
            Self::Lower
        } else {
            Self::None
        }
    }

    /// True for [`RotorSaturation::Lower`] and [`RotorSaturation::Upper`].
    pub fn is_saturated(self) -> bool {
        self != Self::None
    }
}

/// The saturation indicator χ_sat of one tick: true when any rotor's thrust magnitude is within
/// [`SATURATION_TOLERANCE_N`] of T_min or T_max, or beyond. A non-finite thrust counts as
/// saturated (the indicator exists to flag ticks where the rotors could not do what was asked).
pub fn any_rotor_saturated(thrusts_n: &[f64], thrust_min_n: f64, thrust_max_n: f64) -> bool {
    thrusts_n.iter().any(|&t| {
        !t.is_finite() || RotorSaturation::of(t, thrust_min_n, thrust_max_n).is_saturated()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const T_MIN: f64 = 0.0;
    const T_MAX: f64 = 23.0;

    #[test]
    fn rotor_strictly_inside_is_not_saturated() {
        assert_eq!(
            RotorSaturation::of(11.5, T_MIN, T_MAX),
            RotorSaturation::None
        );
        assert!(!any_rotor_saturated(&[1.0, 11.5, 22.9], T_MIN, T_MAX));
    }

    #[test]
    fn rotor_at_or_beyond_a_bound_is_saturated() {
        assert_eq!(
            RotorSaturation::of(23.0, T_MIN, T_MAX),
            RotorSaturation::Upper
        );
        assert_eq!(
            RotorSaturation::of(40.0, T_MIN, T_MAX),
            RotorSaturation::Upper
        );
        assert_eq!(
            RotorSaturation::of(0.0, T_MIN, T_MAX),
            RotorSaturation::Lower
        );
        assert_eq!(
            RotorSaturation::of(-3.0, T_MIN, T_MAX),
            RotorSaturation::Lower
        );
        assert!(any_rotor_saturated(&[5.0, 23.0], T_MIN, T_MAX));
    }

    #[test]
    fn saturation_tolerance_is_the_reference_one() {
        let just_inside = T_MAX - 2.0 * SATURATION_TOLERANCE_N;
        let within_tolerance = T_MAX - 0.5 * SATURATION_TOLERANCE_N;
        assert!(!any_rotor_saturated(&[just_inside, 5.0], T_MIN, T_MAX));
        assert!(any_rotor_saturated(&[within_tolerance, 5.0], T_MIN, T_MAX));
        assert!(any_rotor_saturated(
            &[0.5 * SATURATION_TOLERANCE_N],
            T_MIN,
            T_MAX
        ));
    }

    #[test]
    fn idle_rotor_counts_as_saturated_when_min_is_zero() {
        // The spec's metric: with T_min = 0 any idle rotor counts.
        assert!(any_rotor_saturated(&[0.0, 0.0, 0.0], T_MIN, T_MAX));
    }

    #[test]
    fn non_finite_thrust_counts_as_saturated() {
        assert!(any_rotor_saturated(&[5.0, f64::NAN], T_MIN, T_MAX));
        assert!(any_rotor_saturated(&[f64::INFINITY], T_MIN, T_MAX));
    }

    #[test]
    fn no_rotors_is_not_saturated() {
        assert!(!any_rotor_saturated(&[], T_MIN, T_MAX));
    }
}
