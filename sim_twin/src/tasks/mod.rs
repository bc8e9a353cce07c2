//! The twelve manipulation tasks of AM-Bench as twin scenes (AMBENCH_SPEC §4).
//!
//! A task scene is built into the twin's world at every reset, after the vehicle, from a
//! random stream of its own (derived from the twin's seed, so observation noise never shifts
//! the domain randomisation). Every control tick, after the physics, the scene updates what
//! it owns (breakable joints, stains, hold counters) and evaluates its success and subtask
//! criteria exactly as the spec states them; the runner latches the subtasks.
//!
//! Conventions shared by the scenes:
//! - Positions are world positions (one environment, origin at zero).
//! - Static scene parts are fixed rapier bodies (the reference's kinematic bodies never
//!   move). Articulated objects ([`objects::ReducedJoint`]) are a fixed root and a dynamic
//!   link on a multibody (reduced-coordinate, as PhysX articulations) joint with the spec's
//!   limits; stiffness and damping are the joint motor (implicit), Coulomb joint friction a
//!   second velocity motor whose force is capped at the friction value (also implicit, so
//!   stable at any damping-to-inertia ratio). An impulse joint would let a load through its
//!   anchor leak past a heavily damped drive.
//! - Grasping ([`GraspMode`]): physical contact and friction between fingers and object,
//!   plus, by default, a grasp constraint that engages only while both fingers press the
//!   object with the gripper closing and releases when the gripper opens.
//! - Where the reference keeps geometry or masses only in USD assets ([U] in the spec), each
//!   scene module writes the value it chose beside the constant.

/// The observation keys of the task scenes (AMBENCH_SPEC §5.1), one constant each: the scenes
/// push them, the scripted policies read them, and nothing spells one twice.
pub mod keys {
    /// `ball_lin_vel`.
    pub const BALL_LIN_VEL: &str = "ball_lin_vel";
    /// `ball_pos`.
    pub const BALL_POS: &str = "ball_pos";
    /// `button_pressed`.
    pub const BUTTON_PRESSED: &str = "button_pressed";
    /// `can_pos`.
    pub const CAN_POS: &str = "can_pos";
    /// `container_pos`.
    pub const CONTAINER_POS: &str = "container_pos";
    /// `door_joint_pos`.
    pub const DOOR_JOINT_POS: &str = "door_joint_pos";
    /// `door_pos`.
    pub const DOOR_POS: &str = "door_pos";
    /// `frame_pos`.
    pub const FRAME_POS: &str = "frame_pos";
    /// `goal_pos`.
    pub const GOAL_POS: &str = "goal_pos";
    /// `lemon_pos`.
    pub const LEMON_POS: &str = "lemon_pos";
    /// `lever_joint_pos`.
    pub const LEVER_JOINT_POS: &str = "lever_joint_pos";
    /// `lever_pos`.
    pub const LEVER_POS: &str = "lever_pos";
    /// `peg_center_pos`.
    pub const PEG_CENTER_POS: &str = "peg_center_pos";
    /// `peg_pos`.
    pub const PEG_POS: &str = "peg_pos";
    /// `plunger_pos`.
    pub const PLUNGER_POS: &str = "plunger_pos";
    /// `pulling_door_pos`.
    pub const PULLING_DOOR_POS: &str = "pulling_door_pos";
    /// `slider_body_pos`.
    pub const SLIDER_BODY_POS: &str = "slider_body_pos";
    /// `slider_pos`.
    pub const SLIDER_POS: &str = "slider_pos";
    /// `slider_pushed`.
    pub const SLIDER_PUSHED: &str = "slider_pushed";
    /// `stain_pos`.
    pub const STAIN_POS: &str = "stain_pos";
    /// `stain_visible`.
    pub const STAIN_VISIBLE: &str = "stain_visible";
    /// `target_pos`.
    pub const TARGET_POS: &str = "target_pos";
    /// `valve_angle`.
    pub const VALVE_ANGLE: &str = "valve_angle";
}

pub mod objects;

mod cabinet_pick_place;
mod frame_assembly;
mod lemon_harvesting;
mod ndt;
mod open_door;
mod peg_in_hole;
/// Peg-in-Hole's geometry and success threshold (AMBENCH_SPEC §4.1), for its scripted policy.
pub mod peg {
    pub use super::peg_in_hole::{HOLE_THICKNESS_M, INSERTION_DEPTH_MIN_M, PEG_LENGTH_M};
}
mod press_button;
mod pull_lever;
mod push_slider;
mod rotate_valve;
mod toss_ball;
mod wipe_window;

use std::borrow::Cow;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use platform::Vehicle;
use rand_chacha::ChaCha8Rng;
use rapier3d_f64::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::TwinError;

/// The tasks of the suite, in the order of the paper's tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TaskId {
    /// Press a spring-loaded button on a wall.
    PressButton,
    /// Insert a held peg into a hole in a wall.
    PegInHole,
    /// Pick a frame off the ground and hang it on four pegs.
    FrameAssembly,
    /// Open a cabinet's sliding door, pick a can and place it on top.
    CabinetPickPlace,
    /// Pick a lemon off a wall (breakable attachment) and drop it in a container.
    LemonHarvesting,
    /// Throw a held ball into a container.
    TossBall,
    /// Turn a valve handle 170°.
    RotateValve,
    /// Push a slider along its rail.
    PushSlider,
    /// Pull a lever down 40°.
    PullLever,
    /// Push a hinged door open 20°.
    OpenDoor,
    /// Wipe four stains off a window with a held sponge.
    WipeWindow,
    /// Hold the end effector at an inspection point 7 m up.
    Ndt,
}

impl TaskId {
    /// Every task.
    pub const ALL: [Self; 12] = [
        Self::PressButton,
        Self::PegInHole,
        Self::FrameAssembly,
        Self::CabinetPickPlace,
        Self::LemonHarvesting,
        Self::TossBall,
        Self::RotateValve,
        Self::PushSlider,
        Self::PullLever,
        Self::OpenDoor,
        Self::WipeWindow,
        Self::Ndt,
    ];

    /// The command-line and JSON name (`press-button`, …).
    pub fn name(self) -> &'static str {
        match self {
            Self::PressButton => "press-button",
            Self::PegInHole => "peg-in-hole",
            Self::FrameAssembly => "frame-assembly",
            Self::CabinetPickPlace => "cabinet-pick-place",
            Self::LemonHarvesting => "lemon-harvesting",
            Self::TossBall => "toss-ball",
            Self::RotateValve => "rotate-valve",
            Self::PushSlider => "push-slider",
            Self::PullLever => "pull-lever",
            Self::OpenDoor => "open-door",
            Self::WipeWindow => "wipe-window",
            Self::Ndt => "ndt",
        }
    }

    /// The paper's name ("Press Button", …).
    pub fn title(self) -> &'static str {
        match self {
            Self::PressButton => "Press Button",
            Self::PegInHole => "Peg-in-Hole",
            Self::FrameAssembly => "Frame Assembly",
            Self::CabinetPickPlace => "Cabinet Pick-and-Place",
            Self::LemonHarvesting => "Lemon Harvesting",
            Self::TossBall => "Toss Ball",
            Self::RotateValve => "Rotate Valve",
            Self::PushSlider => "Push Slider",
            Self::PullLever => "Pull Lever",
            Self::OpenDoor => "Open Door",
            Self::WipeWindow => "Wipe Window",
            Self::Ndt => "NDT",
        }
    }

    /// The task named `name` (kebab-case, as [`TaskId::name`]); the error lists the choices.
    pub fn parse(name: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|t| t.name() == name)
            .ok_or_else(|| format!("unknown task '{name}' (valid: {})", Self::names()))
    }

    /// The valid names, comma-separated.
    pub fn names() -> String {
        Self::ALL.map(Self::name).join(", ")
    }

    /// Episode length, s (AMBENCH_SPEC §4).
    pub fn episode_length_s(self) -> f64 {
        match self {
            Self::PressButton
            | Self::PegInHole
            | Self::RotateValve
            | Self::PullLever
            | Self::WipeWindow
            | Self::Ndt => 20.0,
            Self::FrameAssembly | Self::LemonHarvesting => 30.0,
            Self::CabinetPickPlace => 60.0,
            Self::TossBall => 10.0,
            Self::PushSlider => 26.0,
            Self::OpenDoor => 15.0,
        }
    }

    /// The most env steps a rollout runs at `rate_hz`: the reference truncates when the
    /// episode counter reaches ⌈length·rate⌉ − 1 (AMBENCH_SPEC §0).
    pub fn max_steps(self, rate_hz: f64) -> u64 {
        // Lengths and rates are small positive numbers: the cast is exact.
        let max_episode_length = (self.episode_length_s() * rate_hz).ceil() as u64;
        max_episode_length.saturating_sub(1)
    }

    /// A fresh scene of this task.
    pub(crate) fn scene(self) -> Box<dyn Scene> {
        match self {
            Self::PressButton => Box::new(press_button::PressButton::default()),
            Self::PegInHole => Box::new(peg_in_hole::PegInHole::default()),
            Self::FrameAssembly => Box::new(frame_assembly::FrameAssembly::default()),
            Self::CabinetPickPlace => Box::new(cabinet_pick_place::CabinetPickPlace::default()),
            Self::LemonHarvesting => Box::new(lemon_harvesting::LemonHarvesting::default()),
            Self::TossBall => Box::new(toss_ball::TossBall::default()),
            Self::RotateValve => Box::new(rotate_valve::RotateValve::default()),
            Self::PushSlider => Box::new(push_slider::PushSlider::default()),
            Self::PullLever => Box::new(pull_lever::PullLever::default()),
            Self::OpenDoor => Box::new(open_door::OpenDoor::default()),
            Self::WipeWindow => Box::new(wipe_window::WipeWindow::default()),
            Self::Ndt => Box::new(ndt::Ndt::default()),
        }
    }

    /// The names of the task's criteria (subtasks, the success criterion last where the
    /// reference lists it among them); empty when the task reports none.
    pub fn criteria_names(self) -> &'static [&'static str] {
        self.scene().criteria_names()
    }
}

impl std::fmt::Display for TaskId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How grasps hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GraspMode {
    /// Contact and friction, plus a constraint between the end-effector body and the object
    /// (fixed; a round bar may spin about its own axis) while both fingers press it with their
    /// inner faces (each within 2 cm, normal within 60° of the closing direction) and the
    /// gripper is closing (action < 0); released as soon as the gripper opens (action ≥ 0).
    /// Pre-grasped objects start constrained.
    #[default]
    Assisted,
    /// Contact and friction only (pre-grasped objects still start constrained).
    Friction,
}

/// A task's verdict at one tick.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct TaskStatus {
    /// The success criterion (terminates the rollout).
    pub success: bool,
    /// Each criterion of [`TaskId::criteria_names`], at this tick (not latched).
    pub criteria: Vec<bool>,
}

/// Everything a runner needs of a task scene after a tick: what the in-process twin answers
/// from its methods, and what the iceoryx2 twin sends with every measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskSnapshot {
    /// The task.
    pub task: TaskId,
    /// Success and criteria now.
    pub status: TaskStatus,
    /// The observation keys now.
    pub observation: TaskObservation,
    /// The wall's (or wall-like object's) pose.
    pub wall: Option<Isometry3<f64>>,
    /// World x of the obstacle face the base must stay in front of.
    pub obstacle_face_x: Option<f64>,
    /// Whether the grasp constraint holds an object.
    pub holding: bool,
    /// The joint the held object moves on, now (None: nothing held, or a free object).
    pub held_joint: Option<HeldJoint>,
    /// The normal (unit, world, out of what the hand touches) of the hand's contacts with
    /// what does not give way along them (`Twin::hand_contact`; None: no such contact).
    pub hand_contact: Option<Vector3<f64>>,
    /// Env steps since reset.
    pub steps: u64,
}

/// The joint a held object moves on (`platform::HeldJoint`, shared with the wires).
pub use platform::HeldJoint;

/// A task's observation keys (AMBENCH_SPEC §5.1 "task keys"): name → values, world frame.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TaskObservation {
    /// Entries in the scene's order. The scenes' names are static (no allocation per tick);
    /// names read off the wire are owned.
    pub entries: Vec<(Cow<'static, str>, Vec<f64>)>,
}

impl TaskObservation {
    /// Adds an entry.
    pub fn push(
        &mut self,
        name: impl Into<Cow<'static, str>>,
        values: impl IntoIterator<Item = f64>,
    ) {
        self.entries
            .push((name.into(), values.into_iter().collect()));
    }

    /// Adds a 3-vector entry.
    pub fn push_vec3(&mut self, name: impl Into<Cow<'static, str>>, v: &Vector3<f64>) {
        self.push(name, v.iter().copied());
    }

    /// The values of `name`.
    pub fn get(&self, name: &str) -> Result<&[f64], String> {
        self.entries
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, v)| v.as_slice())
            .ok_or_else(|| {
                let names: Vec<&str> = self.entries.iter().map(|(n, _)| n.as_ref()).collect();
                format!("observation '{name}' missing (have: {})", names.join(", "))
            })
    }

    /// The 3-vector `name` (or the `index`-th 3-vector of a longer entry).
    pub fn vec3(&self, name: &str, index: usize) -> Result<Vector3<f64>, String> {
        let v = self.get(name)?;
        v.get(3 * index..3 * index + 3)
            .map(Vector3::from_column_slice)
            .ok_or_else(|| format!("observation '{name}' has no 3-vector {index}"))
    }

    /// The scalar `name`.
    pub fn scalar(&self, name: &str) -> Result<f64, String> {
        self.get(name)?
            .first()
            .copied()
            .ok_or_else(|| format!("observation '{name}' is empty"))
    }
}

/// Initial robot state a task asks for (Pull Lever turns the wrist).
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct InitialOverrides {
    /// Extra rotation of the base at reset, applied after the default orientation.
    pub base_rotation: Option<UnitQuaternion<f64>>,
    /// Joint positions by joint name.
    pub joints: Vec<(&'static str, f64)>,
}

/// What a scene may use while it builds itself at reset.
pub(crate) struct Build<'a> {
    /// The world, with the vehicle already in it.
    pub world: &'a mut PhysicsWorld,
    /// The scene's random stream.
    pub rng: &'a mut ChaCha8Rng,
    /// The tool tip at reset: position ee + R_ee·tool_tip and the command-frame orientation.
    pub tool_tip: Isometry3<f64>,
    /// Objects the fingers may grasp, and the one held from the start (pre-grasped).
    pub graspable: Vec<RigidBodyHandle>,
    /// An object attached to the end effector at reset (AMBENCH_SPEC §4.0 pre-grasp).
    pub pre_grasped: Option<RigidBodyHandle>,
    /// The pre-grasped object's width between the fingers (the spec's grasp width), m.
    pub pre_grasp_width_m: f64,
}

/// What a scene sees after a control tick.
#[derive(Debug, Clone)]
pub(crate) struct View {
    /// Env steps completed in this episode (1 after the first step).
    pub step: u64,
    /// Physics substep, s (joint and contact impulses are per substep).
    pub substep_s: f64,
    /// End-effector link pose.
    pub world_from_ee: Isometry3<f64>,
    /// Tool tip position (ee + R_ee·tool_tip offset).
    pub tool_tip: Vector3<f64>,
    /// Base link position.
    pub base_position: Vector3<f64>,
    /// Sum of the gripper joint positions (the reference's gripper width), m.
    pub gripper_width_m: f64,
}

/// One task's scene: bodies, randomisation, per-tick logic and criteria.
pub(crate) trait Scene: Send + std::fmt::Debug {
    /// Which task.
    fn task(&self) -> TaskId;

    /// Criterion names, in the order of [`TaskStatus::criteria`].
    fn criteria_names(&self) -> &'static [&'static str];

    /// Robot start overrides for this vehicle.
    fn initial_overrides(&self, _vehicle: &Vehicle) -> InitialOverrides {
        InitialOverrides::default()
    }

    /// Adds the scene to the world at reset, drawing its randomisation from `b.rng`.
    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError>;

    /// After each control tick: what the scene owns changes (breakable joints, stains,
    /// counters), then the criteria.
    fn after_step(&mut self, world: &mut PhysicsWorld, view: &View) -> TaskStatus;

    /// The task's observation keys.
    fn observation(&self, world: &PhysicsWorld) -> TaskObservation;

    /// The wall (or wall-like object) pose the scripted policies take normals from.
    fn wall(&self) -> Option<Isometry3<f64>> {
        None
    }

    /// The world x of the obstacle face the base must stay in front of (the IK's per-env
    /// `max_x` before its safety margin, AMBENCH_SPEC §2.6); None without an obstacle.
    fn obstacle_face_x(&self, _world: &PhysicsWorld) -> Option<f64> {
        None
    }

    /// The joint a grasped `object` moves on relative to the world, now (None: a free
    /// object, or one not of this scene). An object on a chain of joints answers with the
    /// joint that moves the grasp point (the valve's handle: the shaft; its own spin on the
    /// wheel turns the hand about its axis without moving it).
    fn held_joint(&self, _world: &PhysicsWorld, _object: RigidBodyHandle) -> Option<HeldJoint> {
        None
    }
}

#[cfg(test)]
mod tests;
