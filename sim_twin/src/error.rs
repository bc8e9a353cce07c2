//! Errors of the twin.

/// What can go wrong building or stepping the twin.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TwinError {
    /// The configuration is invalid.
    #[error("twin config: {0}")]
    Config(String),
    /// The vehicle cannot be simulated.
    #[error("vehicle: {0}")]
    Vehicle(String),
    /// A command of the wrong size or with a non-finite value: a flight-loop bug.
    #[error("command: {0}")]
    Command(String),
    /// The physics state stopped being finite; the twin refuses to step until reset.
    #[error("{0}")]
    Diverged(String),
}
