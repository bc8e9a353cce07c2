//! Per-rotor conversion of a variable-tilt solution (c, s) into a thrust magnitude and a tilt
//! angle, and the magnitude bounds of a tilting rotor.
//!
//! The allocation over the interleaved 6×2N matrix gives, for rotor i, the components (c, s)
//! of its thrust vector c·c_i + s·s_i. Then
//!
//! ```text
//!     T = ‖(c, s)‖,    α = atan2(s, c)   unwrapped against the measured angle α_m:
//!     α ← α − 2π if α − α_m ≥ π;   α ← α + 2π if α − α_m ≤ −π
//! ```
//!
//! so the hinge never turns the long way round. The bound is on the magnitude only:
//! (c, s) ← scale·(c, s) with scale = max(min(1, T_max/‖·‖), T_min/‖·‖), ‖·‖ floored at
//! [`MAGNITUDE_FLOOR_N`] for the division.
//!
//! Two deliberate departures from the reference, both for a rotor with (almost) no thrust
//! vector, ‖(c, s)‖ < [`MAGNITUDE_FLOOR_N`]: it has no direction, so it keeps its measured
//! angle instead of being sent to atan2(0, 0) = 0, and when T_min > 0 it is given T_min along
//! that angle (the reference's scaling of a zero vector leaves it at 0 < T_min).

/// Thrust magnitude, N, below which a rotor's (c, s) has no usable direction (the reference's
/// floor for the scaling division).
pub const MAGNITUDE_FLOOR_N: f64 = 1e-6;

/// `angle_rad` moved by ±2π to within (−π, π) of `measured_rad`, one step as the reference.
/// A non-finite measurement counts as 0.
pub fn unwrap_tilt(angle_rad: f64, measured_rad: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let measured = if measured_rad.is_finite() {
        measured_rad
    } else {
        0.0
    };
    let difference = angle_rad - measured;
    if difference >= PI {
        angle_rad - TAU
    } else if difference <= -PI {
        angle_rad + TAU
    } else {
        angle_rad
    }
}

/// Thrust magnitude and tilt angle of the thrust vector (c, s); a vector shorter than
/// [`MAGNITUDE_FLOOR_N`] keeps the measured angle.
pub(crate) fn magnitude_and_angle(c: f64, s: f64, measured_rad: f64) -> (f64, f64) {
    let magnitude = c.hypot(s);
    if magnitude < MAGNITUDE_FLOOR_N {
        (magnitude, held_angle(measured_rad))
    } else {
        (magnitude, unwrap_tilt(s.atan2(c), measured_rad))
    }
}

/// The measured angle, or 0 when it is not finite.
pub(crate) fn held_angle(measured_rad: f64) -> f64 {
    if measured_rad.is_finite() {
        measured_rad
    } else {
        0.0
    }
}

/// (c, s) scaled so its magnitude lies in `[t_min, t_max]` (the reference's rule, with the
/// zero-vector departure described in the module doc). Returns the bounded pair and whether it
/// changed.
pub(crate) fn bound_thrust_vector(
    c: f64,
    s: f64,
    t_min: f64,
    t_max: f64,
    measured_rad: f64,
) -> ((f64, f64), bool) {
    let magnitude = c.hypot(s);
    if magnitude >= t_min && magnitude <= t_max {
        return ((c, s), false);
    }
    if magnitude < MAGNITUDE_FLOOR_N {
        // No direction to scale: keep the hinge where it is, at T_min.
        let angle = held_angle(measured_rad);
        return ((t_min * angle.cos(), t_min * angle.sin()), true);
    }
    let scale = (t_max / magnitude).min(1.0).max(t_min / magnitude);
    ((c * scale, s * scale), true)
}

/// True when the magnitude of (c, s) lies in `[t_min, t_max]`.
pub(crate) fn within_magnitude_bounds(c: f64, s: f64, t_min: f64, t_max: f64) -> bool {
    let magnitude = c.hypot(s);
    magnitude >= t_min && magnitude <= t_max
}

#[cfg(test)]
#[expect(
    clippy::float_cmp,
    reason = "exact values are the contract: clamps, zeros, replays"
)]
mod tests {
    use super::*;
    use crate::fixtures::assert_close;
    use std::f64::consts::PI;

    /// Round-off of a hypot/atan2 pair.
    const TRIG_TOLERANCE: f64 = 1e-12;

    #[test]
    fn magnitude_and_angle_of_the_spec_vector() {
        // Spec pipeline case: (c, s) = (3, 4) → 5 N at atan2(4, 3) = 0.9273 rad.
        let (t, a) = magnitude_and_angle(3.0, 4.0, 0.0);
        assert_close(t, 5.0, TRIG_TOLERANCE, "magnitude");
        assert_close(a, 4f64.atan2(3.0), TRIG_TOLERANCE, "angle");
        assert_close(a, 0.9273, 1e-4, "angle, spec digits");
    }

    #[test]
    fn angle_unwraps_towards_the_measured_angle() {
        // atan2 gives −3.0; a hinge measured at +3.0 should go to −3.0 + 2π, not swing back.
        assert_close(
            unwrap_tilt(-3.0, 3.0),
            -3.0 + 2.0 * PI,
            TRIG_TOLERANCE,
            "+2π",
        );
        assert_close(
            unwrap_tilt(3.0, -3.0),
            3.0 - 2.0 * PI,
            TRIG_TOLERANCE,
            "−2π",
        );
        assert_close(
            unwrap_tilt(1.0, 0.5),
            1.0,
            TRIG_TOLERANCE,
            "near: unchanged",
        );
        // Exactly π away subtracts (the reference's ≥).
        assert_close(unwrap_tilt(PI, 0.0), -PI, TRIG_TOLERANCE, "≥ π");
        assert_close(unwrap_tilt(-PI, 0.0), PI, TRIG_TOLERANCE, "≤ −π");
        assert_close(
            unwrap_tilt(2.0, f64::NAN),
            2.0,
            TRIG_TOLERANCE,
            "NaN measured",
        );
    }

    #[test]
    fn zero_thrust_vector_holds_the_measured_angle() {
        let (t, a) = magnitude_and_angle(0.0, 0.0, 0.7);
        assert_eq!(t, 0.0);
        assert_close(a, 0.7, 0.0, "held angle");
    }

    #[test]
    fn magnitude_scales_into_bounds() {
        let ((c, s), changed) = bound_thrust_vector(30.0, 40.0, 0.0, 23.0, 0.0);
        assert!(changed);
        assert_close(c.hypot(s), 23.0, TRIG_TOLERANCE, "scaled to T_max");
        assert_close(
            s.atan2(c),
            40f64.atan2(30.0),
            TRIG_TOLERANCE,
            "direction kept",
        );
        let ((c, s), changed) = bound_thrust_vector(0.3, 0.4, 1.0, 23.0, 0.0);
        assert!(changed);
        assert_close(c.hypot(s), 1.0, TRIG_TOLERANCE, "scaled up to T_min");
        let (pair, changed) = bound_thrust_vector(3.0, 4.0, 1.0, 23.0, 0.0);
        assert!(!changed);
        assert_eq!(pair, (3.0, 4.0));
    }

    #[test]
    fn zero_vector_with_positive_minimum_gets_minimum_along_measured_angle() {
        let ((c, s), changed) = bound_thrust_vector(0.0, 0.0, 2.0, 23.0, PI / 2.0);
        assert!(changed);
        assert_close(c, 0.0, TRIG_TOLERANCE, "c");
        assert_close(s, 2.0, TRIG_TOLERANCE, "s");
    }
}
