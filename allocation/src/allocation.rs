//! The result of one allocation: rotor setpoints, what they achieve, what they could not.

use platform::Wrench;
use serde::Serialize;

use crate::RotorSaturation;

/// How an [`Allocation`] was produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum AllocationStatus {
    /// The buffer has not been filled by an allocator yet.
    #[default]
    NotComputed,
    /// The pseudo-inverse solution lies within the thrust bounds and is returned as is. It is
    /// exact for a wrench the layout can produce, and optimal for every method.
    WithinBounds,
    /// The pseudo-inverse solution left the bounds and was clamped (fixed rotors) or its
    /// per-rotor magnitudes scaled (tilting rotors): the pseudo-inverse method's saturation.
    Clipped,
    /// The constrained QP converged.
    Solved {
        /// clarabel stopped at its reduced accuracy (`AlmostSolved`).
        reduced_accuracy: bool,
        /// Interior-point iterations taken.
        iterations: u32,
        /// The post-solve polish step was accepted (active-set least-squares correction).
        polished: bool,
    },
    /// The constrained QP did not converge; the clip-after-pseudo-inverse result is returned.
    SolverFailed {
        /// What the solver reported.
        reason: SolverFailure,
    },
    /// The requested wrench was not finite: every rotor is commanded T_min (tilting rotors
    /// hold their measured angle) and nothing is reported as unallocated.
    NonFiniteRequest,
}

impl AllocationStatus {
    /// True when the returned thrusts came from clipping rather than from an exact or optimal
    /// solution.
    pub fn is_fallback(self) -> bool {
        matches!(
            self,
            Self::SolverFailed { .. } | Self::NonFiniteRequest | Self::NotComputed
        )
    }
}

/// Why the constrained QP gave no solution (clarabel's non-converged statuses).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SolverFailure {
    /// Iteration limit reached.
    MaxIterations,
    /// Time limit reached (none is set by this crate).
    MaxTime,
    /// Numerical error in the factorisation.
    NumericalError,
    /// No progress between iterations.
    InsufficientProgress,
    /// An infeasibility certificate (impossible for a box or disc: a bug if seen).
    Infeasible,
    /// clarabel refused the cost update.
    DataUpdateRejected,
    /// Any other status.
    Other,
}

/// Rotor setpoints for one requested wrench and what they achieve.
///
/// All vectors are in actuator order. Reuse one `Allocation` across ticks with
/// [`crate::Allocator::allocate_into`]: its vectors keep their capacity.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Allocation {
    /// Thrust magnitude of each rotor, N, within `[T_min, T_max]`.
    pub thrusts_n: Vec<f64>,
    /// Tilt angle of each rotor, rad (variable-tilt allocation only; empty otherwise).
    pub tilt_rad: Vec<f64>,
    /// The pseudo-inverse thrust magnitudes before any bound, N: the paper's T^alloc, the
    /// "allocated" signal of the reference (a rotor actuator model clamps it itself).
    pub unconstrained_thrusts_n: Vec<f64>,
    /// The wrench asked for (body frame, about the base origin).
    pub requested: Wrench,
    /// The wrench the returned thrusts and angles produce (the forward map).
    pub achieved: Wrench,
    /// `requested − achieved`: what the rotors could not produce, for the controllers'
    /// anti-windup. For an under-actuated vehicle it includes the uncommanded F_x, F_y.
    pub unallocated: Wrench,
    /// Per-rotor saturation of the returned thrusts.
    pub saturation: Vec<RotorSaturation>,
    /// How the result was produced.
    pub status: AllocationStatus,
}

impl Allocation {
    /// True when any rotor is at a thrust limit: the paper's saturation indicator χ_sat.
    pub fn any_saturated(&self) -> bool {
        self.saturation.iter().any(|s| s.is_saturated())
    }
}
