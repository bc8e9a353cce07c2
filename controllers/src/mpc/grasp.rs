//! The grasp model of the whole-body MPC: while the hand holds an object on a joint, the end
//! effector can only move as that joint lets the object move.
//!
//! The twin's assisted grasp welds the gripper to a knob or handle whose joint (a rail, a
//! valve's shaft, a lever's pivot) lets it move one way only; the prediction model has no
//! contact, so without this model the MPC plans to close an EE error along a blocked
//! direction by extending the arm, which, the EE being pinned, pushes its own base back
//! (`docs/mpc-contact.md` §2). The scene describes the joint every tick ([`HeldJoint`],
//! world frame), anchored at the measured EE p(x̂):
//!
//! - **target on the joint's motion** (`MpcConfig::grasp_reference`, on by default): the EE
//!   position target handed to the QP is the point of the joint's motion through p(x̂)
//!   nearest the target (prismatic, axis a: p(x̂) + a·aᵀ(p_target − p(x̂)); revolute, axis a
//!   through c: the point of p(x̂)'s circle about the axis in the target's direction), and
//!   the EE offset integrates only the error along the motion; on a revolute joint
//!   (`MpcConfig::grasp_orientation`, on by default) the orientation target is the measured
//!   EE orientation turned about the axis by the angle from p(x̂) to that point
//!   (`AnchoredGrasp::turn_to`): the hand, welded to the object, turns with it;
//! - **grasp rows** (`MpcConfig::grasp_band_m`, off by default): on every state stage
//!   k = 1..N, two rows on the EE position p(x_k) (linearised with
//!   [`crate::mpc::EeKinematics::position_jacobian`] at the stage's iterate), each held within
//!   ±band of its value at the measured state — prismatic: the displacement p(x_k) − p(x̂)
//!   on two unit directions normal to a; revolute: the displacement along a, and the
//!   distance of p(x_k) from the axis less that of p(x̂). Soft state rows like the others.
//!
//! The anchor is the measured EE, so the measured state is on the joint's motion by
//! construction: the model's kinematics need not agree with the object's to the millimetre.
//! Measured in the twin (docs/mpc-contact.md §5) the target alone does what the rows do, and
//! the rows cost successes (their QPs need slacks the model's slow arm servo cannot avoid).

use nalgebra::{Unit, UnitQuaternion, Vector3};
use platform::HeldJoint;

use crate::mpc::model::EeKinematics;
use crate::mpc::qp::StateVector;

/// Rows per stage of a held joint.
pub const GRASP_ROWS: usize = 2;

/// A held joint with the EE position it is anchored at (the measured EE of this tick).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AnchoredGrasp {
    /// The joint, axis unit.
    joint: HeldJoint,
    /// Two unit directions normal to the axis (prismatic rows; the revolute's axial row is
    /// the axis).
    normals: [Vector3<f64>; 2],
    /// The measured EE position, world, m.
    anchor: Vector3<f64>,
    /// Revolute: the anchor's distance from the axis, m.
    radius: f64,
}

/// `joint` anchored at the EE position `anchor` (None for an invalid joint).
pub(crate) fn anchored(joint: &HeldJoint, anchor: Vector3<f64>) -> Option<AnchoredGrasp> {
    if !(joint.is_valid() && anchor.iter().all(|v| v.is_finite())) {
        return None;
    }
    let axis = joint.unit_axis();
    let joint = match *joint {
        HeldJoint::Prismatic { .. } => HeldJoint::Prismatic { axis },
        HeldJoint::Revolute { point, .. } => HeldJoint::Revolute { axis, point },
    };
    // Any vector not parallel to the axis gives the first normal.
    let seed = if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let n1 = axis.cross(&seed).normalize();
    let n2 = axis.cross(&n1);
    let radius = match joint {
        HeldJoint::Prismatic { .. } => 0.0,
        HeldJoint::Revolute { point, .. } => radial(&axis, &(anchor - point)).norm(),
    };
    Some(AnchoredGrasp {
        joint,
        normals: [n1, n2],
        anchor,
        radius,
    })
}

/// The part of `v` normal to the unit `axis`.
fn radial(axis: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    v - axis * axis.dot(v)
}

impl AnchoredGrasp {
    /// The rows' values and gradients (∂/∂x) at an EE: zero value at the anchor.
    pub(crate) fn rows(&self, ee: &EeKinematics) -> [(f64, StateVector); GRASP_ROWS] {
        let d = ee.position - self.anchor;
        let row = |direction: &Vector3<f64>, value: f64| -> (f64, StateVector) {
            (value, ee.position_jacobian.transpose() * direction)
        };
        match self.joint {
            HeldJoint::Prismatic { .. } => {
                let [n1, n2] = &self.normals;
                [row(n1, n1.dot(&d)), row(n2, n2.dot(&d))]
            }
            HeldJoint::Revolute { axis, point } => {
                let r = radial(&axis, &(ee.position - point));
                let distance = r.norm();
                // On the axis itself the distance has no gradient: take the anchor's.
                let outward = r
                    .try_normalize(1e-9)
                    .or_else(|| radial(&axis, &(self.anchor - point)).try_normalize(1e-9))
                    .unwrap_or(self.normals[0]);
                [
                    row(&axis, axis.dot(&d)),
                    row(&outward, distance - self.radius),
                ]
            }
        }
    }

    /// The point nearest `target` that the joint lets the anchored EE reach: on the rail
    /// through the anchor, or on the anchor's circle about the axis.
    pub(crate) fn project(&self, target: &Vector3<f64>) -> Vector3<f64> {
        match self.joint {
            HeldJoint::Prismatic { axis } => self.anchor + axis * axis.dot(&(target - self.anchor)),
            HeldJoint::Revolute { axis, point } => {
                let centre = point + axis * axis.dot(&(self.anchor - point));
                let direction = radial(&axis, &(target - point))
                    .try_normalize(1e-9)
                    .or_else(|| radial(&axis, &(self.anchor - point)).try_normalize(1e-9))
                    .unwrap_or(self.normals[0]);
                centre + direction * self.radius
            }
        }
    }

    /// The turn a revolute joint gives the held object (and the hand welded to it) as the EE
    /// goes from the anchor to `to`: the rotation about its axis by the angle between their
    /// radii. None for a prismatic joint (the object slides without turning).
    pub(crate) fn turn_to(&self, to: &Vector3<f64>) -> Option<UnitQuaternion<f64>> {
        match self.joint {
            HeldJoint::Prismatic { .. } => None,
            HeldJoint::Revolute { axis, point } => {
                let r0 = radial(&axis, &(self.anchor - point));
                let r1 = radial(&axis, &(to - point));
                // atan2(0, 0) = 0: a point on the axis turns nothing.
                let angle = axis.dot(&r0.cross(&r1)).atan2(r0.dot(&r1));
                angle
                    .is_finite()
                    .then(|| UnitQuaternion::from_axis_angle(&Unit::new_unchecked(axis), angle))
            }
        }
    }

    /// The part of an EE position error `error` (at the EE position `at`) the joint lets the
    /// hand move: along the rail, or along the circle's tangent.
    pub(crate) fn allowed_part(&self, at: &Vector3<f64>, error: &Vector3<f64>) -> Vector3<f64> {
        match self.joint {
            HeldJoint::Prismatic { axis } => axis * axis.dot(error),
            HeldJoint::Revolute { axis, point } => {
                match axis.cross(&(at - point)).try_normalize(1e-9) {
                    Some(tangent) => tangent * tangent.dot(error),
                    None => Vector3::zeros(),
                }
            }
        }
    }
}
