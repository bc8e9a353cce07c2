//! The joint a held object moves on: the twin's scene reports it, the MAVLink and iceoryx2
//! wires carry it, the whole-body MPC models it (one type for all of them).

use nalgebra::Vector3;
use serde::Serialize;

/// The motion the joint of a held articulated object allows the hand holding it, in the
/// world frame at this instant: what a controller needs to know that its end effector is
/// pinned to the object (the whole-body MPC's grasp rows, `docs/mpc-contact.md` §5).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum HeldJoint {
    /// The object slides along `axis` (unit, world).
    Prismatic {
        /// The sliding direction.
        axis: Vector3<f64>,
    },
    /// The object turns about `axis` (unit, world) through `point` (world, m).
    Revolute {
        /// The turning axis.
        axis: Vector3<f64>,
        /// A point on the axis.
        point: Vector3<f64>,
    },
}
