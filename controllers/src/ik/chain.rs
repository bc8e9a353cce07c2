//! The base → end-effector chain, flattened once for fast FK and Jacobians.
//!
//! The vehicle's kinematic tree is walked once, from the root (base) to `ee_link`. Fixed joints
//! and movable joints that are not arm joints (held at their initial value) are folded into
//! constant transforms, so evaluating the chain costs one isometry product and one axis
//! rotation per arm joint, with no allocation.

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use platform::{JointKind, Vehicle};

/// How an arm joint moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Motion {
    /// Rotation about the axis (revolute or continuous joint), rad.
    Rotation,
    /// Translation along the axis (prismatic joint), m.
    Translation,
}

/// One arm joint of the chain.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ChainJoint {
    /// The joint frame in the frame left by the previous arm joint (or the base), with every
    /// fixed and held joint in between folded in.
    pub(crate) previous_from_joint: Isometry3<f64>,
    /// Unit axis in the joint frame.
    pub(crate) axis: Unit<Vector3<f64>>,
    /// Rotation or translation.
    pub(crate) motion: Motion,
    /// Index of this joint in the arm joint vector (command order).
    pub(crate) arm_index: usize,
}

/// The flattened chain.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Chain {
    /// Arm joints from the base outward.
    pub(crate) joints: Vec<ChainJoint>,
    /// `ee_link` in the frame left by the last arm joint.
    pub(crate) last_from_ee: Isometry3<f64>,
}

/// What one chain evaluation yields, in the base frame.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ChainPoses {
    /// `base_from_ee`.
    pub(crate) base_from_ee: Isometry3<f64>,
    /// Per arm joint (chain order): its axis in the base frame.
    pub(crate) axes: Vec<Vector3<f64>>,
    /// Per arm joint (chain order): a point on its axis in the base frame, m.
    pub(crate) origins: Vec<Vector3<f64>>,
}

impl Chain {
    /// Flattens the chain of `vehicle.ee_link`. `held` is the full configuration that every
    /// non-arm movable joint keeps; `arm_dofs[k]` is the configuration index of arm joint k.
    pub(crate) fn new(vehicle: &Vehicle, held: &[f64], arm_dofs: &[usize]) -> Self {
        let model = &vehicle.model;
        let mut joints = Vec::with_capacity(arm_dofs.len());
        let mut pending = Isometry3::identity();
        for j in model.chain(vehicle.ee_link) {
            let joint = &model.joints[j];
            let arm_index = joint
                .dof
                .and_then(|d| arm_dofs.iter().position(|&a| a == d));
            match (arm_index, joint.kind) {
                (Some(arm_index), JointKind::Revolute | JointKind::Continuous) => {
                    joints.push(ChainJoint {
                        previous_from_joint: pending * joint.parent_from_joint,
                        axis: joint.axis,
                        motion: Motion::Rotation,
                        arm_index,
                    });
                    pending = Isometry3::identity();
                }
                (Some(arm_index), JointKind::Prismatic) => {
                    joints.push(ChainJoint {
                        previous_from_joint: pending * joint.parent_from_joint,
                        axis: joint.axis,
                        motion: Motion::Translation,
                        arm_index,
                    });
                    pending = Isometry3::identity();
                }
                // Fixed joints, and movable joints held at their value.
                _ => {
                    let q = joint.dof.map_or(0.0, |d| held[d]);
                    pending *= joint.parent_from_child(q);
                }
            }
        }
        Self {
            joints,
            last_from_ee: pending,
        }
    }

    /// An empty result buffer sized for this chain.
    pub(crate) fn poses_buffer(&self) -> ChainPoses {
        ChainPoses {
            base_from_ee: Isometry3::identity(),
            axes: vec![Vector3::zeros(); self.joints.len()],
            origins: vec![Vector3::zeros(); self.joints.len()],
        }
    }

    /// `base_from_ee` at arm joint values `arm` (command order).
    pub(crate) fn base_from_ee(&self, arm: &[f64]) -> Isometry3<f64> {
        let mut pose = Isometry3::identity();
        for joint in &self.joints {
            pose = pose * joint.previous_from_joint * joint.motion_by(arm[joint.arm_index]);
        }
        pose * self.last_from_ee
    }

    /// `base_from_ee` and every arm joint's axis and origin in the base frame, into `out`.
    pub(crate) fn evaluate(&self, arm: &[f64], out: &mut ChainPoses) {
        let mut pose = Isometry3::identity();
        for (k, joint) in self.joints.iter().enumerate() {
            pose *= joint.previous_from_joint;
            out.axes[k] = pose.rotation * joint.axis.into_inner();
            out.origins[k] = pose.translation.vector;
            pose *= joint.motion_by(arm[joint.arm_index]);
        }
        out.base_from_ee = pose * self.last_from_ee;
    }
}

impl ChainJoint {
    /// The joint's motion at position `q`.
    fn motion_by(&self, q: f64) -> Isometry3<f64> {
        match self.motion {
            Motion::Rotation => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&self.axis, q),
            ),
            Motion::Translation => Isometry3::from_parts(
                Translation3::from(self.axis.into_inner() * q),
                UnitQuaternion::identity(),
            ),
        }
    }
}
