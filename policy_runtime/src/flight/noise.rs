//! Action noise (AMBENCH_SPEC §3.1): N(0, σ²) added to every value of the action vector, in
//! the vector's order, from one named random stream.

use nalgebra::{Quaternion, UnitQuaternion};
use platform::RandomStream;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::stack::Action;

/// Noise on every action value, from its own random stream.
#[derive(Debug, Clone)]
pub struct ActionNoise {
    rng: ChaCha8Rng,
    normal: Normal<f64>,
}

impl ActionNoise {
    /// N(0, `std`²) from `stream` of `seed`; None when `std` is not a standard deviation.
    pub fn new(std: f64, stream: RandomStream, seed: u64) -> Option<Self> {
        Some(Self {
            normal: Normal::new(0.0, std).ok()?,
            rng: stream.rng(seed),
        })
    }

    /// Adds noise to every value of `action`, in the order of its vector: an end-effector
    /// action's position, quaternion (then renormalised) and gripper; a base + joint action's
    /// base position, base quaternion, arm joints and gripper.
    pub fn apply(&mut self, action: &mut Action) {
        let (pose, joints, gripper) = match action {
            Action::Ee(ee) => (&mut ee.world_from_ee_command, None, &mut ee.gripper),
            Action::BaseJoint(t) => (
                &mut t.world_from_base,
                Some(&mut t.arm_joints),
                &mut t.gripper,
            ),
        };
        for x in pose.translation.vector.iter_mut() {
            *x += self.normal.sample(&mut self.rng);
        }
        let q = pose
            .rotation
            .into_inner()
            .coords
            .map(|c| c + self.normal.sample(&mut self.rng));
        pose.rotation = UnitQuaternion::new_normalize(Quaternion::from(q));
        for q in joints.into_iter().flatten() {
            *q += self.normal.sample(&mut self.rng);
        }
        *gripper += self.normal.sample(&mut self.rng);
    }
}
