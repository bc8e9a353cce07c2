//! How a vehicle turns a body wrench into motion: the vehicle classes of AM-Bench.

use serde::{Deserialize, Serialize};

/// The actuation class of a vehicle; it picks the allocation method and the base controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Actuation {
    /// Fixed, non-parallel rotor axes spanning all six wrench directions (FA-Hexa):
    /// allocation over the 6×N effectiveness matrix.
    FullyActuated,
    /// All rotor axes parallel to body z (UA-Quad, UA-Hexa): only [F_z, τ_x, τ_y, τ_z] can be
    /// commanded, allocation over the reduced 4×N matrix.
    UnderActuated,
    /// Every rotor on a tilt hinge (Omni-Hexa): allocation over 6×2N (cos, sin) columns, then
    /// per-rotor magnitude and tilt angle.
    VariableTilt,
    /// No rotors: the wrench is applied directly to the end-effector body (EE-only oracle).
    FloatingEndEffector,
}

impl Actuation {
    /// Stable lowercase name, as written in vehicle files.
    pub fn as_str(self) -> &'static str {
        match self {
            Actuation::FullyActuated => "fully-actuated",
            Actuation::UnderActuated => "under-actuated",
            Actuation::VariableTilt => "variable-tilt",
            Actuation::FloatingEndEffector => "floating-end-effector",
        }
    }
}
