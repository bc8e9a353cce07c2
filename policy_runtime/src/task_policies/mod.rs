//! Scripted policies of the twelve tasks (AMBENCH_SPEC §4 "Scripted policy"): the
//! demonstrations of the benchmark. Each is built at reset from the task's observation, the
//! end-effector link position at reset ("init") and the wall pose, with its per-rollout random
//! offsets drawn from the rollout's policy stream; it then emits end-effector targets in the
//! command frame with a gripper action (+1 open, −1 closed), at 120 Hz env steps.
//!
//! Waypoint segments use smootherstep position, slerp orientation and a linear gripper
//! ([`crate::scripted::WaypointPolicy`]); Rotate Valve adds its circle segment.

mod cabinet_pick_place;
mod frame_assembly;
mod lemon_harvesting;
mod ndt;
mod open_door;
mod peg_in_hole;
mod press_button;
mod pull_lever;
mod push_slider;
mod rotate_valve;
mod toss_ball;
mod wipe_window;

use nalgebra::{Isometry3, Quaternion, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use sim_twin::{TaskId, TaskObservation};

use crate::scripted::{Waypoint, WaypointPolicy};

/// What a scripted policy is built from at reset.
#[derive(Debug, Clone)]
pub struct PolicyContext {
    /// End-effector link position at reset ("init").
    pub init: Vector3<f64>,
    /// The task's observation at reset.
    pub task: TaskObservation,
    /// The task's wall pose, where it has one.
    pub wall: Option<Isometry3<f64>>,
}

/// A scripted policy: the action at each env step.
pub trait TaskPolicy: Send + std::fmt::Debug {
    /// End-effector target (command frame) and gripper action at env step `step`.
    fn action(&mut self, step: u64) -> (Isometry3<f64>, f64);

    /// The env step of the script's last waypoint (it holds afterwards).
    fn end_step(&self) -> u64;
}

impl TaskPolicy for WaypointPolicy {
    fn action(&mut self, step: u64) -> (Isometry3<f64>, f64) {
        WaypointPolicy::action(self, step)
    }

    fn end_step(&self) -> u64 {
        self.end_tick()
    }
}

/// The scripted policy of `task`, with its random offsets from `rng`.
pub fn scripted(
    task: TaskId,
    ctx: &PolicyContext,
    rng: &mut ChaCha8Rng,
) -> Result<Box<dyn TaskPolicy>, String> {
    let policy: Box<dyn TaskPolicy> = match task {
        TaskId::PressButton => Box::new(press_button::policy(ctx, rng)?),
        TaskId::PegInHole => Box::new(peg_in_hole::policy(ctx, rng)?),
        TaskId::FrameAssembly => Box::new(frame_assembly::policy(ctx, rng)?),
        TaskId::CabinetPickPlace => Box::new(cabinet_pick_place::policy(ctx, rng)?),
        TaskId::LemonHarvesting => Box::new(lemon_harvesting::policy(ctx, rng)?),
        TaskId::TossBall => Box::new(toss_ball::policy(ctx, rng)?),
        TaskId::RotateValve => rotate_valve::policy(ctx, rng)?,
        TaskId::PushSlider => Box::new(push_slider::policy(ctx, rng)?),
        TaskId::PullLever => Box::new(pull_lever::policy(ctx, rng)?),
        TaskId::OpenDoor => Box::new(open_door::policy(ctx, rng)?),
        TaskId::WipeWindow => Box::new(wipe_window::policy(ctx, rng)?),
        TaskId::Ndt => Box::new(ndt::policy(ctx, rng)?),
    };
    Ok(policy)
}

/// The gripper action the environment forces every step, if the task has one (Wipe Window
/// holds the sponge with −0.6, AMBENCH_SPEC §4.12).
pub fn gripper_override(task: TaskId) -> Option<f64> {
    (task == TaskId::WipeWindow).then_some(-0.6)
}

/// U(lo, hi) (lo when the interval is empty).
pub(crate) fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

/// A waypoint.
pub(crate) fn wp(
    tick: u64,
    position: Vector3<f64>,
    orientation: UnitQuaternion<f64>,
    gripper: f64,
) -> Waypoint {
    Waypoint {
        tick,
        position,
        orientation,
        gripper,
    }
}

/// Identity orientation.
pub(crate) fn identity() -> UnitQuaternion<f64> {
    UnitQuaternion::identity()
}

/// A quaternion from w, x, y, z.
pub(crate) fn quat_wxyz(w: f64, x: f64, y: f64, z: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
}

/// The wall helpers of the reference (AMBENCH_SPEC §4.0 "Wall helpers").
#[derive(Debug, Clone, Copy)]
pub(crate) struct WallFrame {
    /// Normal, pointing away from the robot (R_wall·x̂).
    pub n: Vector3<f64>,
    /// R_wall·ŷ.
    pub w_y: Vector3<f64>,
    /// R_wall·ẑ.
    pub w_z: Vector3<f64>,
    /// The wall's rotation.
    pub rotation: UnitQuaternion<f64>,
}

impl WallFrame {
    /// The helpers of the context's wall; an error if the task has none.
    pub fn of(ctx: &PolicyContext) -> Result<Self, String> {
        let rotation = ctx
            .wall
            .ok_or_else(|| "the scene has no wall".to_owned())?
            .rotation;
        Ok(Self {
            n: rotation * Vector3::x(),
            w_y: rotation * Vector3::y(),
            w_z: rotation * Vector3::z(),
            rotation,
        })
    }

    /// Wall-aligned orientation: the shortest arc from x̂ to n (identity if degenerate).
    pub fn aligned(&self) -> UnitQuaternion<f64> {
        let x = Vector3::x();
        let v = x.cross(&self.n);
        let q = Quaternion::new(1.0 + x.dot(&self.n), v.x, v.y, v.z);
        if q.norm() < 1e-6 {
            identity()
        } else {
            UnitQuaternion::from_quaternion(q)
        }
    }
}

#[cfg(test)]
mod tests;
