//! Errors of the allocation crate, one small enum per layer.
//!
//! Only misuse is an error (a bad layout or setting, a slice of the wrong length, a `dt` that is
//! not a time step). A constrained solve that does not converge is *not* an error: it is
//! reported in [`crate::AllocationStatus`] and the allocator falls back on its own.

use platform::Actuation;
use thiserror::Error;

/// Why an [`crate::Allocator`] could not be built or asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AllocationError {
    /// The layout has no rotors (the EE-only oracle): there is nothing to allocate to.
    #[error("the rotor layout has no rotors: nothing to allocate to")]
    NoRotors,
    /// The actuation class has no rotor allocation.
    #[error("actuation `{}` has no rotor allocation", .0.as_str())]
    UnsupportedActuation(Actuation),
    /// Variable-tilt allocation was asked of a rotor without a tilt hinge.
    #[error("rotor {rotor} has no tilt hinge; variable-tilt allocation needs one on every rotor")]
    MissingTilt {
        /// Index of the first rotor without a hinge.
        rotor: usize,
    },
    /// A figure of the rotor layout is unusable (non-finite geometry, inverted thrust limits…).
    #[error("invalid rotor layout: {0}")]
    InvalidLayout(String),
    /// A field of [`crate::ConstrainedSettings`] is out of range.
    #[error("invalid allocation settings: {0}")]
    InvalidSettings(String),
    /// A slice argument has the wrong length.
    #[error("{what}: expected {expected} values, got {got}")]
    LengthMismatch {
        /// What the slice holds.
        what: &'static str,
        /// Length expected.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// clarabel refused the problem data at set-up (a bug: the data are built here).
    #[error("the constrained allocation QP could not be set up: {0}")]
    SolverSetup(String),
}

/// Why a [`crate::RotorActuator`] could not be built or stepped.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ActuatorError {
    /// A field of [`crate::RotorActuatorConfig`] is out of range.
    #[error("invalid rotor actuator config: {0}")]
    InvalidConfig(String),
    /// The time step is NaN, infinite, zero or negative.
    #[error("dt must be finite and positive, got {0} s")]
    InvalidTimeStep(f64),
    /// The thrust command does not have one entry per rotor.
    #[error("thrust command shape mismatch: expected {expected} rotors, got {got}")]
    CommandLength {
        /// Rotors of the actuator.
        expected: usize,
        /// Entries given.
        got: usize,
    },
    /// A rotor index past the last rotor.
    #[error("rotor index {index} is outside 0..{count}")]
    RotorIndex {
        /// Index given.
        index: usize,
        /// Rotors of the actuator.
        count: usize,
    },
}
