//! Errors of loading a vehicle description: each names the file, the field and the value.

use std::fmt;

/// A vehicle description that could not be loaded. Its `Display` is one line:
/// `<file>: <field>: <problem>`, e.g.
/// `fa-hexa.urdf: joint 'arm_link1_pitch_joint' axis: (0, 2, 0) is not a unit vector (norm 2)`.
#[derive(Debug, Clone, PartialEq)]
pub struct DescriptionError {
    /// The file the problem is in, as the caller named it.
    pub file: String,
    /// Where in the file: an element or a dotted field path.
    pub field: String,
    /// What is wrong, with the offending value.
    pub problem: Problem,
}

impl fmt::Display for DescriptionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.field.is_empty() {
            write!(f, "{}: {}", self.file, self.problem)
        } else {
            write!(f, "{}: {}: {}", self.file, self.field, self.problem)
        }
    }
}

impl std::error::Error for DescriptionError {}

/// What is wrong with a vehicle description.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Problem {
    /// The file is not valid XML/URDF or TOML, or has a field of the wrong type.
    #[error("cannot parse: {0}")]
    Syntax(String),
    /// A link name that the URDF does not define.
    #[error("unknown link '{0}'")]
    UnknownLink(String),
    /// A joint name that the URDF does not define.
    #[error("unknown joint '{0}'")]
    UnknownJoint(String),
    /// Two links with one name.
    #[error("duplicate link '{0}'")]
    DuplicateLink(String),
    /// Two joints with one name.
    #[error("duplicate joint '{0}'")]
    DuplicateJoint(String),
    /// A joint or rotor axis whose norm is not 1.
    #[error("({x}, {y}, {z}) is not a unit vector (norm {norm})")]
    NonUnitAxis {
        /// Axis x component.
        x: f64,
        /// Axis y component.
        y: f64,
        /// Axis z component.
        z: f64,
        /// Its norm.
        norm: f64,
    },
    /// A mass below zero.
    #[error("negative mass {0} kg")]
    NegativeMass(f64),
    /// The rotor count declared does not match the rotors listed.
    #[error("rotors.count = {declared} but {listed} rotors are listed")]
    RotorCountMismatch {
        /// `rotors.count`.
        declared: usize,
        /// Entries of `rotors.rotor`.
        listed: usize,
    },
    /// Any other value out of its valid range; the message holds the value.
    #[error("{0}")]
    Invalid(String),
}

impl DescriptionError {
    pub(crate) fn new(file: &str, field: impl Into<String>, problem: Problem) -> Self {
        Self {
            file: file.to_owned(),
            field: field.into(),
            problem,
        }
    }
}

/// Collapses a multi-line parser message into one line.
pub(crate) fn one_line(message: &str) -> String {
    message.split_whitespace().collect::<Vec<_>>().join(" ")
}
