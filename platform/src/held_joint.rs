//! The joint a held object moves on: the twin's scene reports it, the MAVLink and iceoryx2
//! wires carry it, the whole-body MPC models it (one type for all of them).

use nalgebra::Vector3;
use serde::Serialize;

/// The motion the joint of a held articulated object allows the hand holding it, in the
/// world frame at this instant: what a controller needs to know that its end effector is
/// pinned to the object (the whole-body MPC's grasp model, `docs/mpc-contact.md` §5). The
/// axis is unit as the scene and the wires give it; a consumer normalises it on use.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum HeldJoint {
    /// The object slides along `axis` (world).
    Prismatic {
        /// The sliding direction.
        axis: Vector3<f64>,
    },
    /// The object turns about `axis` (world) through `point` (world, m).
    Revolute {
        /// The turning axis.
        axis: Vector3<f64>,
        /// A point on the axis.
        point: Vector3<f64>,
    },
}

impl HeldJoint {
    /// Whether the description is usable: finite, with a non-zero axis.
    pub fn is_valid(&self) -> bool {
        match self {
            Self::Prismatic { axis } => axis.iter().all(|v| v.is_finite()) && axis.norm() > 1e-9,
            Self::Revolute { axis, point } => {
                axis.iter().chain(point.iter()).all(|v| v.is_finite()) && axis.norm() > 1e-9
            }
        }
    }

    /// The axis, normalised (an invalid joint's is not finite).
    pub fn unit_axis(&self) -> Vector3<f64> {
        match self {
            Self::Prismatic { axis } | Self::Revolute { axis, .. } => axis.normalize(),
        }
    }
}
