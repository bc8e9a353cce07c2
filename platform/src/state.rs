//! The kinematic state of a rigid body as every controller sees it.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Pose and velocity of the controlled body (the base, or `ee_link` for the EE-only oracle):
/// the 13 numbers of AM-Bench's controller input `[p_w, q_wxyz, v_w, ω_b]` (AMBENCH_SPEC §2.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidBodyState {
    /// Body origin in the world frame, m.
    pub position_in_world_m: Vector3<f64>,
    /// Body orientation: rotates body-frame vectors into the world frame.
    pub world_from_body: UnitQuaternion<f64>,
    /// Linear velocity of the body origin in the world frame, m/s.
    pub velocity_in_world_mps: Vector3<f64>,
    /// Angular velocity in the body frame, rad/s.
    pub angular_velocity_in_body_radps: Vector3<f64>,
}

impl Default for RigidBodyState {
    fn default() -> Self {
        Self::at_rest(Isometry3::identity())
    }
}

impl RigidBodyState {
    /// At rest at `world_from_body`.
    pub fn at_rest(world_from_body: Isometry3<f64>) -> Self {
        Self {
            position_in_world_m: world_from_body.translation.vector,
            world_from_body: world_from_body.rotation,
            velocity_in_world_mps: Vector3::zeros(),
            angular_velocity_in_body_radps: Vector3::zeros(),
        }
    }

    /// The pose as an isometry `world_from_body`.
    pub fn pose(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.position_in_world_m),
            self.world_from_body,
        )
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        let q = self.world_from_body.as_ref();
        self.position_in_world_m
            .iter()
            .chain(self.velocity_in_world_mps.iter())
            .chain(self.angular_velocity_in_body_radps.iter())
            .chain(q.coords.iter())
            .all(|x| x.is_finite())
    }
}
