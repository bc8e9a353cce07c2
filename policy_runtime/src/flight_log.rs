//! The channels of a flight's MCAP log and their messages (log format version
//! [`LOG_FORMAT_VERSION`](crate::record::LOG_FORMAT_VERSION)). Times are the simulated (or
//! link) time of the measurement a message belongs to. Frames: `world` (Z-up), `base`
//! (base link, FLU), `ee` (end-effector link); quaternions in arrays are w, x, y, z.
//!
//! | topic | schema | content |
//! |---|---|---|
//! | `/tf` | foxglove.FrameTransforms | world→base, world→ee |
//! | `/base/pose`, `/ee/pose` | foxglove.PoseInFrame | measured poses in `world` |
//! | `/base/reference`, `/ee/reference` | foxglove.PoseInFrame | the targets of the tick |
//! | `/base/state` | amstack.BaseState | pose, world velocity, body rates |
//! | `/control/wrench` | amstack.BodyWrench | requested and unallocated wrench, `base` frame |
//! | `/rotors` | amstack.Rotors | commanded, realised, applied thrust per rotor; saturation |
//! | `/joints` | amstack.Joints | every movable joint: target and measured |
//! | `/disturbances` | amstack.Disturbances | drag, wind, ground and near-wall forces, `base` frame |
//! | `/controller/status` | amstack.ControllerStatus | errors, integrators, adaptive terms |
//! | `/action` | amstack.Action | the action handed to the flight stack (what `replay` re-flies) |
//! | `/estimator/state` | amstack.EstimatorState | the estimate the controllers flew on (`--state-source estimator`), its deviations, biases, innovations |
//! | `/autopilot/state` | amstack.AutopilotState | MAVLink flights: what the autopilot says about itself, the link's counters |
//! | `/mavlink/raw` | amstack.MavlinkRaw | MAVLink flights: every frame in and out, bytes as on the wire |
//! | `/camera/<name>/image` | foxglove.CompressedImage (protobuf, the Foxglove SDK's) | flights with cameras: the camera's PNG every Nth observation |
//! | `/camera/<name>/calibration` | foxglove.CameraCalibration (protobuf) | its intrinsics (K, P), with each image |
//! | `/camera/tf` | foxglove.FrameTransforms (protobuf) | world→camera (ROS optical frame), with each image set |
//! | `/scene/tf`, `/scene/static`, `/scene/dynamic`, `/scene/targets` | foxglove.FrameTransforms, foxglove.SceneUpdate (protobuf, the Foxglove SDK's) | the flight as a 3D scene: [`crate::scene3d`] |
//!
//! A link's own channels (the MAVLink link: the last two) are the messages it returns from
//! [`crate::Link::drain_messages`], written by [`FlightLog::link_messages`].
//!
//! The complete description, with units, frames and the compatibility rule, is
//! `docs/mcap-format.md`.

use std::any::Any;
use std::collections::BTreeMap;

use nalgebra::Isometry3;
use platform::{Measurement, Vehicle};
use schemars::JsonSchema;
use serde::Serialize;

use crate::cameras::Frames;
pub use crate::link_channels::{
    AUTOPILOT_STATE_TOPIC, AutopilotStateMessage, LinkCounters, MAVLINK_RAW_TOPIC, MavlinkRawFrame,
};
use crate::link_channels::{LinkMessage, LinkPayload};
use crate::record::foxglove::{FrameTransform, FrameTransforms, PoseInFrame};
use crate::record::{Channel, McapRecorder, RecordError, SchemaName};
use crate::scene3d::{
    SCENE_DYNAMIC_TOPIC, SCENE_STATIC_TOPIC, SCENE_TARGETS_TOPIC, SCENE_TF_TOPIC, Scene3d,
};
use crate::stack::{Action, BaseJointTarget, EeTarget, TickRecord};

fn v3(v: &nalgebra::Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// Measured state of the base link.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct BaseState {
    /// Position in `world`, m.
    pub position_m: [f64; 3],
    /// Orientation `world_from_base`, w x y z.
    pub orientation_wxyz: [f64; 4],
    /// Velocity of the base origin in `world`, m/s.
    pub velocity_world_mps: [f64; 3],
    /// Angular velocity in `base`, rad/s.
    pub angular_velocity_body_radps: [f64; 3],
}

/// The action handed to the flight stack at one tick, exactly as given: what
/// `amstack replay --mode reference` feeds the stack again.
#[derive(Debug, Clone, Serialize, serde::Deserialize, JsonSchema)]
pub struct ActionMessage {
    /// `ee` (an end-effector target in the command frame) or `base-joint` (a base pose and
    /// arm joint targets).
    pub interface: String,
    /// `ee`: `world_from_ee_command` translation; `base-joint`: `world_from_base`
    /// translation; world frame, m.
    pub position_m: [f64; 3],
    /// The pose's orientation in `world`, w x y z.
    pub orientation_wxyz: [f64; 4],
    /// Arm joint targets in the vehicle's command order, rad (empty for `ee`).
    pub arm_joints_rad: Vec<f64>,
    /// Gripper action in [−1, 1]: −1 closed, +1 open.
    pub gripper: f64,
}

impl ActionMessage {
    /// The message of `action`.
    pub fn of(action: &Action) -> Self {
        let (interface, pose, arm, gripper) = match action {
            Action::Ee(ee) => ("ee", &ee.world_from_ee_command, &[][..], ee.gripper),
            Action::BaseJoint(t) => (
                "base-joint",
                &t.world_from_base,
                t.arm_joints.as_slice(),
                t.gripper,
            ),
        };
        let q = pose.rotation;
        Self {
            interface: interface.to_owned(),
            position_m: v3(&pose.translation.vector),
            orientation_wxyz: [q.w, q.i, q.j, q.k],
            arm_joints_rad: arm.to_vec(),
            gripper,
        }
    }

    /// The action again, bit for bit (the quaternion is taken as stored, not renormalised);
    /// `None` for an unknown interface name.
    pub fn to_action(&self) -> Option<Action> {
        let [w, x, y, z] = self.orientation_wxyz;
        let [px, py, pz] = self.position_m;
        let pose = Isometry3::from_parts(
            nalgebra::Translation3::new(px, py, pz),
            nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(w, x, y, z)),
        );
        match self.interface.as_str() {
            "ee" => Some(Action::Ee(EeTarget {
                world_from_ee_command: pose,
                gripper: self.gripper,
            })),
            "base-joint" => Some(Action::BaseJoint(BaseJointTarget {
                world_from_base: pose,
                arm_joints: self.arm_joints_rad.clone(),
                gripper: self.gripper,
            })),
            _ => None,
        }
    }
}

/// The controller's wrench, `base` frame, about the base origin.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct BodyWrench {
    /// Requested force, N.
    pub force_n: [f64; 3],
    /// Requested torque, N·m.
    pub torque_nm: [f64; 3],
    /// Force the allocator could not produce, N.
    pub unallocated_force_n: [f64; 3],
    /// Torque the allocator could not produce, N·m.
    pub unallocated_torque_nm: [f64; 3],
}

/// Rotor thrusts over the last control period, in rotor order.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct Rotors {
    /// Commanded (allocated) thrust, N.
    pub commanded_n: Vec<f64>,
    /// Thrust the motors produced (limits and dynamics), N.
    pub realised_n: Vec<f64>,
    /// Thrust after ground and near-wall effects, N.
    pub applied_n: Vec<f64>,
    /// The saturation indicator: any realised thrust at a limit, or a command outside them.
    pub saturated: bool,
}

/// Every movable joint, configuration order.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct Joints {
    /// Joint names.
    pub names: Vec<String>,
    /// Targets sent, rad or m.
    pub target: Vec<f64>,
    /// Measured positions, rad or m.
    pub position: Vec<f64>,
}

/// Forces of each disturbance model, `base` frame, N.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct Disturbances {
    /// Linear drag.
    pub drag_n: [f64; 3],
    /// Wind.
    pub wind_n: [f64; 3],
    /// Extra rotor force from the ground effect.
    pub ground_effect_n: [f64; 3],
    /// Extra rotor force from the near-wall effect.
    pub near_wall_n: [f64; 3],
}

/// The base controller's status after its update.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct ControllerStatus {
    /// `pid6`, `pid4` or `l1`.
    pub controller: String,
    /// p_d − p, world, m.
    pub position_error_m: [f64; 3],
    /// v_d − v, world, m/s.
    pub velocity_error_mps: [f64; 3],
    /// e_R, body.
    pub attitude_error: [f64; 3],
    /// ∫e_p dt, world.
    pub position_integral: [f64; 3],
    /// ∫e_R dt, body.
    pub attitude_integral: [f64; 3],
    /// L1 adaptive force, body, N (null for PID).
    pub adaptive_force_n: Option<[f64; 3]>,
    /// L1 adaptive torque, body, N·m (null for PID).
    pub adaptive_torque_nm: Option<[f64; 3]>,
    /// Integration stopped by saturation feedback: force x y z, torque x y z.
    pub windup_blocked: [bool; 6],
    /// `ok`, `non_finite_state`, `non_finite_target`, `invalid_dt`.
    pub input: String,
}

impl BaseState {
    /// The base state of measurement `m`.
    pub fn of(m: &Measurement) -> Self {
        let q = m.base.world_from_body;
        Self {
            position_m: v3(&m.base.position_in_world_m),
            orientation_wxyz: [q.w, q.i, q.j, q.k],
            velocity_world_mps: v3(&m.base.velocity_in_world_mps),
            angular_velocity_body_radps: v3(&m.base.angular_velocity_in_body_radps),
        }
    }
}

impl Rotors {
    /// What the rotors of `m` did over its period; `limits` (min, max, N) when the rotors are
    /// limited — `None` (ideal rotors): no thrust is at a limit, only a clamped command counts.
    pub fn of(m: &Measurement, limits: Option<(f64, f64)>) -> Self {
        Self {
            commanded_n: m.rotors.iter().map(|r| r.commanded_n).collect(),
            realised_n: m.rotors.iter().map(|r| r.realised_n).collect(),
            applied_n: m.rotors.iter().map(|r| r.applied_n).collect(),
            saturated: match limits {
                Some(limits) => rotors_saturated(m, limits),
                None => m.rotors.iter().any(|r| r.saturated),
            },
        }
    }
}

impl Disturbances {
    /// The disturbance forces of `m`'s period, `base` frame.
    pub fn of(m: &Measurement) -> Self {
        let d = &m.disturbances;
        Self {
            drag_n: v3(&d.drag_n),
            wind_n: v3(&d.wind_n),
            ground_effect_n: v3(&d.ground_effect_n),
            near_wall_n: v3(&d.near_wall_n),
        }
    }
}

/// `/tf` of measurement `m` at `t_ns`: world→base and world→ee.
pub fn frame_transforms(t_ns: u64, m: &Measurement) -> FrameTransforms {
    FrameTransforms {
        transforms: vec![
            FrameTransform::new(t_ns, "world", "base", &m.base.pose()),
            FrameTransform::new(t_ns, "world", "ee", &m.world_from_ee),
        ],
    }
}

/// A task's state after one env step (benchmark rollouts): its criteria at this step and
/// latched, and its observation keys (AMBENCH_SPEC §5.1), world frame.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct TaskState {
    /// Task name (`press-button`, …).
    pub task: String,
    /// Env steps since reset.
    pub step: u64,
    /// The success criterion at this step.
    pub success: bool,
    /// Each criterion: name, at this step, reached at some step so far.
    pub criteria: Vec<TaskCriterion>,
    /// The task's observation keys and values.
    pub observation: Vec<TaskValue>,
    /// The grasp constraint holds an object.
    pub holding: bool,
}

impl TaskState {
    /// The state of `snapshot`, with each criterion's latched value from `reached`
    /// (criterion order, as [`crate::metrics::CriteriaLatch::reached`]).
    pub fn from_snapshot(snapshot: &sim_twin::TaskSnapshot, reached: &[bool]) -> Self {
        let status = &snapshot.status;
        Self {
            task: snapshot.task.name().to_owned(),
            step: snapshot.steps,
            success: status.success,
            criteria: snapshot
                .task
                .criteria_names()
                .iter()
                .zip(&status.criteria)
                .zip(reached)
                .map(|((name, now), reached)| TaskCriterion {
                    name: (*name).to_owned(),
                    now: *now,
                    reached: *reached,
                })
                .collect(),
            observation: snapshot
                .observation
                .entries
                .iter()
                .map(|(name, values)| TaskValue {
                    name: name.to_string(),
                    values: values.clone(),
                })
                .collect(),
            holding: snapshot.holding,
        }
    }
}

/// One criterion of a [`TaskState`].
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct TaskCriterion {
    /// Name (`slider_engaged`, …).
    pub name: String,
    /// True at this step.
    pub now: bool,
    /// True at some step so far.
    pub reached: bool,
}

/// One observation key of a [`TaskState`].
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct TaskValue {
    /// Key (`goal_pos`, …).
    pub name: String,
    /// Values (positions in m, world frame).
    pub values: Vec<f64>,
}

/// The whole-body MPC's report of one tick (flights with `--controller mpc`): who flew, the
/// fallback's events, and the RTI step.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct MpcStatus {
    /// `mpc`, `hold` (shifted previous solution) or `ik_pid` (the fallback path).
    pub mode: String,
    /// `hold_started`, `ik_pid_took_over`, `mpc_recovered`, or null.
    pub event: Option<String>,
    /// Why this tick's solve failed: `qp_not_solved`, `over_budget`, `non_finite_input`, or
    /// null.
    pub failure: Option<String>,
    /// Consecutive failed solves.
    pub failed_ticks: u32,
    /// QP outcome (`solved`, `max_iterations`, `infeasible`, `numerical_failure`), or null.
    pub qp_status: Option<String>,
    /// QP interior-point iterations.
    pub qp_iterations: u32,
    /// NLS cost of the solution.
    pub cost: f64,
    /// Largest violation of the OCP's inequalities at the solution's knots.
    pub max_constraint_violation: f64,
    /// Wall time of the RTI step, ms.
    pub solve_time_ms: Option<f64>,
    /// EE position error at the measured state, m.
    pub ee_error_m: f64,
    /// Predicted base position at the end of the horizon, world, m.
    pub predicted_terminal_position_m: [f64; 3],
    /// The EE target's velocity the MPC extrapolated over its horizon, world, m/s (zero for
    /// a held target or a jump).
    pub target_velocity_mps: [f64; 3],
    /// The normal (unit, world, out of what the hand touches) of the hand's blocking contact
    /// the MPC was given this tick (null: none).
    pub hand_contact: Option<[f64; 3]>,
}

/// The state estimator's tick (flights with `--state-source estimator`): the estimate handed
/// to the controllers next to the measurement logged on `/base/state`.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct EstimatorState {
    /// Estimated position in `world`, m.
    pub position_m: [f64; 3],
    /// Estimated orientation `world_from_base`, w x y z.
    pub orientation_wxyz: [f64; 4],
    /// Estimated velocity in `world`, m/s.
    pub velocity_world_mps: [f64; 3],
    /// Estimated angular velocity in `base` (gyro − bias), rad/s.
    pub angular_velocity_body_radps: [f64; 3],
    /// Estimate − measured position, `world`, m.
    pub position_error_m: [f64; 3],
    /// One standard deviation of position, `world`, m.
    pub position_std_m: [f64; 3],
    /// One standard deviation of velocity, `world`, m/s.
    pub velocity_std_mps: [f64; 3],
    /// One standard deviation of the attitude error, `base`, rad.
    pub attitude_std_rad: [f64; 3],
    /// Estimated accelerometer bias, `base`, m/s².
    pub accel_bias_mps2: [f64; 3],
    /// Estimated gyroscope bias, `base`, rad/s.
    pub gyro_bias_radps: [f64; 3],
    /// The simulated IMU's accelerometer bias, `base`, m/s²; null when the estimator fuses
    /// a vehicle's own IMU (its biases are not known).
    pub true_accel_bias_mps2: Option<[f64; 3]>,
    /// The simulated IMU's gyroscope bias, `base`, rad/s; null for a vehicle's own IMU.
    pub true_gyro_bias_radps: Option<[f64; 3]>,
    /// The measurements fused this tick.
    pub innovations: Vec<EstimatorInnovation>,
    /// Why inputs were refused this tick (one line each).
    pub rejections: Vec<String>,
}

/// One fused measurement of an [`EstimatorState`].
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct EstimatorInnovation {
    /// Capture time, s.
    pub time_s: f64,
    /// How far it was behind the newest IMU sample, s.
    pub delay_s: f64,
    /// Position residual, `world`, m.
    pub position_m: [f64; 3],
    /// Attitude residual, `base`, rad.
    pub attitude_rad: [f64; 3],
    /// Normalised innovation squared.
    pub nis: f64,
}

impl EstimatorState {
    /// The log message of an estimator report.
    pub fn from_report(r: &crate::state_source::EstimateReport) -> Self {
        let q = r.state.world_from_body;
        Self {
            position_m: v3(&r.state.position_in_world_m),
            orientation_wxyz: [q.w, q.i, q.j, q.k],
            velocity_world_mps: v3(&r.state.velocity_in_world_mps),
            angular_velocity_body_radps: v3(&r.state.angular_velocity_in_body_radps),
            position_error_m: v3(&r.position_error_m),
            position_std_m: v3(&r.position_std_m),
            velocity_std_mps: v3(&r.velocity_std_mps),
            attitude_std_rad: v3(&r.attitude_std_rad),
            accel_bias_mps2: v3(&r.accel_bias_mps2),
            gyro_bias_radps: v3(&r.gyro_bias_radps),
            true_accel_bias_mps2: r.true_accel_bias_mps2.as_ref().map(v3),
            true_gyro_bias_radps: r.true_gyro_bias_radps.as_ref().map(v3),
            innovations: r
                .innovations
                .iter()
                .map(|i| EstimatorInnovation {
                    time_s: i.time_s,
                    delay_s: i.delay_s,
                    position_m: v3(&i.position_m),
                    attitude_rad: v3(&i.attitude_rad),
                    nis: i.nis,
                })
                .collect(),
            rejections: r.rejections.iter().map(ToString::to_string).collect(),
        }
    }
}

/// A serde enum's name as a string.
fn name_of<T: Serialize>(value: &T) -> String {
    serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

macro_rules! schema_names {
    ($($t:ident),*) => {$(impl SchemaName for $t { const SCHEMA_NAME: &'static str = concat!("amstack.", stringify!($t)); })*};
}
impl SchemaName for ActionMessage {
    const SCHEMA_NAME: &'static str = "amstack.Action";
}

/// The channels links opened through [`FlightLog::link_message`], by topic (each a
/// `Channel<T>` of the message type it was opened with).
#[derive(Default)]
struct LinkChannels(BTreeMap<String, Box<dyn Any + Send + Sync>>);

impl std::fmt::Debug for LinkChannels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.0.keys()).finish()
    }
}
schema_names!(
    TaskState,
    BaseState,
    BodyWrench,
    Rotors,
    Joints,
    Disturbances,
    ControllerStatus,
    MpcStatus,
    EstimatorState
);

/// One camera's channels.
#[derive(Debug)]
struct CameraChannels {
    name: String,
    image: Channel<foxglove::schemas::CompressedImage>,
    calibration: Channel<foxglove::schemas::CameraCalibration>,
}

/// The 3D scene's channels (Foxglove SDK types, protobuf).
#[derive(Debug)]
struct SceneChannels {
    scene: Scene3d,
    tf: Channel<foxglove::schemas::FrameTransforms>,
    fixed: Channel<foxglove::schemas::SceneUpdate>,
    dynamic: Channel<foxglove::schemas::SceneUpdate>,
    targets: Channel<foxglove::schemas::SceneUpdate>,
    /// The scene objects' world poses after the last step (the order of the scene's shapes).
    poses: Vec<Isometry3<f64>>,
}

/// The open channels of one flight log.
#[derive(Debug)]
pub struct FlightLog {
    /// The 3D scene.
    scene: SceneChannels,
    recorder: McapRecorder,
    tf: Channel<FrameTransforms>,
    base_pose: Channel<PoseInFrame>,
    ee_pose: Channel<PoseInFrame>,
    base_reference: Channel<PoseInFrame>,
    ee_reference: Channel<PoseInFrame>,
    base_state: Channel<BaseState>,
    wrench: Channel<BodyWrench>,
    rotors: Channel<Rotors>,
    joints: Channel<Joints>,
    disturbances: Channel<Disturbances>,
    status: Channel<ControllerStatus>,
    /// Opened on the first action logged.
    action: Option<Channel<ActionMessage>>,
    /// Opened on the first tick that carries an MPC report.
    mpc: Option<Channel<MpcStatus>>,
    /// Opened on the first task state logged.
    task: Option<Channel<TaskState>>,
    /// Opened on the first estimate logged.
    estimate: Option<Channel<EstimatorState>>,
    /// A link's own channels, each opened on its first message.
    link_channels: LinkChannels,
    /// The cameras' channels, opened on the first images logged.
    cameras: Vec<CameraChannels>,
    /// `/camera/tf`, opened with the cameras' channels.
    camera_tf: Option<Channel<foxglove::schemas::FrameTransforms>>,
    /// The cameras are logged at every this many-th observation (0: never).
    camera_every: u64,
    /// PNG scratch.
    png: Vec<u8>,
    joint_names: Vec<String>,
    limits: (f64, f64),
    /// Whether the flight's rotors are limited (else `/rotors.saturated` counts only clamped
    /// commands).
    limits_enforced: bool,
}

fn nanos(time_s: f64) -> u64 {
    (time_s * 1e9).round().max(0.0) as u64
}

impl FlightLog {
    /// Opens every channel on `recorder`.
    pub fn new(mut recorder: McapRecorder, vehicle: &Vehicle) -> Result<Self, RecordError> {
        Ok(Self {
            scene: SceneChannels {
                scene: Scene3d::new(vehicle),
                tf: recorder.encoded_channel(SCENE_TF_TOPIC)?,
                fixed: recorder.encoded_channel(SCENE_STATIC_TOPIC)?,
                dynamic: recorder.encoded_channel(SCENE_DYNAMIC_TOPIC)?,
                targets: recorder.encoded_channel(SCENE_TARGETS_TOPIC)?,
                poses: Vec::new(),
            },
            tf: recorder.channel("/tf")?,
            base_pose: recorder.channel("/base/pose")?,
            ee_pose: recorder.channel("/ee/pose")?,
            base_reference: recorder.channel("/base/reference")?,
            ee_reference: recorder.channel("/ee/reference")?,
            base_state: recorder.channel("/base/state")?,
            wrench: recorder.channel("/control/wrench")?,
            rotors: recorder.channel("/rotors")?,
            joints: recorder.channel("/joints")?,
            disturbances: recorder.channel("/disturbances")?,
            status: recorder.channel("/controller/status")?,
            mpc: None,
            action: None,
            task: None,
            estimate: None,
            link_channels: LinkChannels::default(),
            cameras: Vec::new(),
            camera_tf: None,
            camera_every: 0,
            png: Vec::new(),
            joint_names: (0..vehicle.model.dof())
                .map(|d| vehicle.model.dof_joint(d).name.clone())
                .collect(),
            limits: (vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n),
            limits_enforced: true,
            recorder,
        })
    }

    /// Whether the flight's rotors are limited (the twin's `saturation` disturbance, or a real
    /// vehicle): with ideal rotors (`false`) no thrust is "at a limit", and `/rotors.saturated`
    /// reads true only for a command the motor model clamped. Limited by default.
    pub fn with_rotor_limits(mut self, enforced: bool) -> Self {
        self.limits_enforced = enforced;
        self
    }

    /// Logs the flight's camera images at every `every`-th observation (k = 0, every, 2·every,
    /// …; 0: never) — as a flight observer it asks for them on those ticks only.
    pub fn with_camera_log(mut self, every: u64) -> Self {
        self.camera_every = every;
        self
    }

    /// The camera log's period in observations (0: cameras not logged).
    pub fn camera_log_every(&self) -> u64 {
        self.camera_every
    }

    /// Logs the images of one observation: per camera its PNG (`/camera/<name>/image`), its
    /// calibration (`/camera/<name>/calibration`), and the cameras' world poses
    /// (`/camera/tf`), at the observation's time — the Foxglove SDK's protobuf types
    /// (`foxglove.CompressedImage`, `foxglove.CameraCalibration`, `foxglove.FrameTransforms`),
    /// as the 3D scene's channels.
    pub fn cameras(&mut self, frames: &Frames) -> Result<(), RecordError> {
        use foxglove::schemas::{CameraCalibration, CompressedImage, FrameTransforms};
        let t = nanos(frames.time_s);
        let stamp = crate::scene3d::timestamp(t);
        let mut tf = FrameTransforms::default();
        for frame in &frames.cameras {
            let index = match self.cameras.iter().position(|c| c.name == frame.name) {
                Some(i) => i,
                None => {
                    let topic = format!("/camera/{}", frame.name);
                    let channels = CameraChannels {
                        name: frame.name.clone(),
                        image: self.recorder.encoded_channel(&format!("{topic}/image"))?,
                        calibration: self
                            .recorder
                            .encoded_channel(&format!("{topic}/calibration"))?,
                    };
                    self.cameras.push(channels);
                    self.cameras.len() - 1
                }
            };
            let channels = &self.cameras[index];
            self.png.clear();
            frame
                .image
                .write_png(&mut self.png)
                .map_err(|e| RecordError::Image {
                    topic: channels.image.topic().to_owned(),
                    message: e.to_string(),
                })?;
            let image = CompressedImage {
                timestamp: Some(stamp),
                frame_id: frame.name.clone(),
                data: self.png.clone().into(),
                format: "png".to_owned(),
            };
            self.recorder.log_encoded(&channels.image, t, &image)?;
            let k = &frame.intrinsics;
            let calibration = CameraCalibration {
                timestamp: Some(stamp),
                frame_id: frame.name.clone(),
                width: frame.image.width,
                height: frame.image.height,
                distortion_model: "plumb_bob".to_owned(),
                d: Vec::new(),
                k: vec![k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
                r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                p: vec![
                    k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
                ],
            };
            self.recorder
                .log_encoded(&channels.calibration, t, &calibration)?;
            tf.transforms.push(crate::scene3d::frame_transform(
                stamp,
                crate::scene3d::WORLD_FRAME,
                &frame.name,
                &frame.world_from_camera,
            ));
        }
        let channel = match self.camera_tf.take() {
            Some(c) => c,
            None => self.recorder.encoded_channel("/camera/tf")?,
        };
        let logged = self.recorder.log_encoded(&channel, t, &tf);
        self.camera_tf = Some(channel);
        logged
    }

    /// The task scene's shapes of this flight (a link's [`crate::Link::camera_scene`]), drawn
    /// on the 3D scene's channels from the next tick on.
    pub fn set_scene(&mut self, scene: Vec<sim_twin::SceneVisual>) {
        self.scene.scene.set_scene(scene);
        self.scene.poses.clear();
    }

    /// The scene objects' world poses now (the order of [`Self::set_scene`]'s shapes), drawn
    /// by the next [`Self::outcome`].
    pub fn set_scene_poses(&mut self, poses: &[Isometry3<f64>]) {
        self.scene.poses.clear();
        self.scene.poses.extend_from_slice(poses);
    }

    /// Logs the vehicle's frames (`/scene/tf`) at measurement `m`, and the static scene when
    /// it is due.
    pub fn scene_frames(&mut self, m: &Measurement) -> Result<(), RecordError> {
        let t = nanos(m.time_s);
        let s = &mut self.scene;
        if s.scene.static_due(t) {
            self.recorder
                .log_encoded(&s.fixed, t, &s.scene.static_scene(t))?;
        }
        let tf = s.scene.transforms(t, m);
        self.recorder.log_encoded(&s.tf, t, &tf)
    }

    /// Logs one tick: the measurement it acted on, what it decided, the EE reference.
    pub fn tick(
        &mut self,
        m: &Measurement,
        record: &TickRecord,
        ee_reference: &Isometry3<f64>,
    ) -> Result<(), RecordError> {
        let t = nanos(m.time_s);
        self.scene_frames(m)?;
        let targets = self
            .scene
            .scene
            .targets(t, ee_reference, &record.base_target);
        self.recorder
            .log_encoded(&self.scene.targets, t, &targets)?;
        let r = &mut self.recorder;
        let base = m.base.pose();
        r.log(&self.tf, t, &frame_transforms(t, m))?;
        r.log(&self.base_pose, t, &PoseInFrame::new(t, "world", &base))?;
        r.log(
            &self.ee_pose,
            t,
            &PoseInFrame::new(t, "world", &m.world_from_ee),
        )?;
        r.log(
            &self.base_reference,
            t,
            &PoseInFrame::new(t, "world", &record.base_target),
        )?;
        r.log(
            &self.ee_reference,
            t,
            &PoseInFrame::new(t, "world", ee_reference),
        )?;
        r.log(&self.base_state, t, &BaseState::of(m))?;
        r.log(
            &self.wrench,
            t,
            &BodyWrench {
                force_n: v3(&record.wrench.force),
                torque_nm: v3(&record.wrench.torque),
                unallocated_force_n: v3(&record.unallocated.force),
                unallocated_torque_nm: v3(&record.unallocated.torque),
            },
        )?;
        r.log(
            &self.joints,
            t,
            &Joints {
                names: self.joint_names.clone(),
                target: record.command.joint_targets.clone(),
                position: m.joint_positions.clone(),
            },
        )?;
        let s = &record.controller;
        r.log(
            &self.status,
            t,
            &ControllerStatus {
                controller: s.controller.to_owned(),
                position_error_m: v3(&s.position_error_m),
                velocity_error_mps: v3(&s.velocity_error_mps),
                attitude_error: v3(&s.attitude_error),
                position_integral: v3(&s.position_integral),
                attitude_integral: v3(&s.attitude_integral),
                adaptive_force_n: s.adaptive_force_n.as_ref().map(v3),
                adaptive_torque_nm: s.adaptive_torque_nm.as_ref().map(v3),
                windup_blocked: s.windup_blocked,
                input: serde_json::to_value(s.input)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_owned))
                    .unwrap_or_default(),
            },
        )?;
        if let Some(status) = &record.mpc {
            let channel = match self.mpc.take() {
                Some(c) => c,
                None => self.recorder.channel("/mpc/status")?,
            };
            let rti = status.rti.as_ref();
            let message = MpcStatus {
                mode: name_of(&status.mode),
                event: status.event.as_ref().map(name_of),
                failure: status.failure.as_ref().map(name_of),
                failed_ticks: status.failed_ticks,
                qp_status: rti.map(|r| name_of(&r.status)),
                qp_iterations: rti.map_or(0, |r| r.qp_iterations),
                cost: rti.map_or(f64::NAN, |r| r.cost),
                max_constraint_violation: rti.map_or(f64::NAN, |r| r.max_constraint_violation),
                solve_time_ms: status.solve_time_s.map(|s| s * 1e3),
                ee_error_m: status.ee_error_m,
                predicted_terminal_position_m: v3(&status.predicted_terminal_position_m),
                target_velocity_mps: v3(&status.target_velocity_mps),
                hand_contact: status.hand_contact.as_ref().map(v3),
            };
            let logged = self.recorder.log(&channel, t, &message);
            self.mpc = Some(channel);
            logged?;
        }
        Ok(())
    }

    /// Logs the action handed to the stack at simulated time `time_s` on `/action` (call it
    /// with the tick's measurement time, before or after [`Self::tick`]).
    pub fn action(&mut self, time_s: f64, action: &Action) -> Result<(), RecordError> {
        let channel = match self.action.take() {
            Some(c) => c,
            None => self.recorder.channel("/action")?,
        };
        let logged = self
            .recorder
            .log(&channel, nanos(time_s), &ActionMessage::of(action));
        self.action = Some(channel);
        logged
    }

    /// Logs a task's state at simulated time `time_s` on `/task/state`.
    pub fn task_state(&mut self, time_s: f64, state: &TaskState) -> Result<(), RecordError> {
        let channel = match self.task.take() {
            Some(c) => c,
            None => self.recorder.channel("/task/state")?,
        };
        let logged = self.recorder.log(&channel, nanos(time_s), state);
        self.task = Some(channel);
        logged
    }

    /// Logs the state estimator's tick at simulated time `time_s` on `/estimator/state`.
    pub fn estimate(&mut self, time_s: f64, state: &EstimatorState) -> Result<(), RecordError> {
        let channel = match self.estimate.take() {
            Some(c) => c,
            None => self.recorder.channel("/estimator/state")?,
        };
        let logged = self.recorder.log(&channel, nanos(time_s), state);
        self.estimate = Some(channel);
        logged
    }

    /// Logs the messages of a link's own channels ([`crate::Link::drain_messages`]).
    pub fn link_messages(&mut self, messages: &[LinkMessage]) -> Result<(), RecordError> {
        for m in messages {
            match &m.payload {
                LinkPayload::AutopilotState(p) => {
                    self.link_message(m.payload.topic(), m.time_s, p.as_ref())?;
                }
                LinkPayload::MavlinkRaw(p) => {
                    self.link_message(m.payload.topic(), m.time_s, p.as_ref())?;
                }
            }
        }
        Ok(())
    }

    /// Logs a link's own message on `topic` at time `time_s` (the flight's time base, s):
    /// the channel is opened with `T`'s schema on its first message. Logging another type on
    /// a topic is an error ([`RecordError::TopicConflict`]) unless both have the same schema.
    pub fn link_message<T>(
        &mut self,
        topic: &str,
        time_s: f64,
        message: &T,
    ) -> Result<(), RecordError>
    where
        T: Serialize + JsonSchema + SchemaName + 'static,
    {
        if !self.link_channels.0.contains_key(topic) {
            let channel: Channel<T> = self.recorder.channel(topic)?;
            self.link_channels
                .0
                .insert(topic.to_owned(), Box::new(channel));
        }
        let t = nanos(time_s);
        match self
            .link_channels
            .0
            .get(topic)
            .and_then(|c| c.downcast_ref::<Channel<T>>())
        {
            Some(channel) => self.recorder.log(channel, t, message),
            None => {
                // Opened with another type: the recorder refuses a different schema.
                let channel: Channel<T> = self.recorder.channel(topic)?;
                self.recorder.log(&channel, t, message)
            }
        }
    }

    /// Logs what the rotors and disturbances did over the period that ended at `m.time_s`.
    pub fn outcome(&mut self, m: &Measurement) -> Result<(), RecordError> {
        let t = nanos(m.time_s);
        let s = &self.scene;
        let dynamic = s.scene.dynamic_scene(t, m, &s.poses);
        if !dynamic.entities.is_empty() {
            self.recorder.log_encoded(&s.dynamic, t, &dynamic)?;
        }
        if !m.rotors.is_empty() {
            let limits = self.limits_enforced.then_some(self.limits);
            self.recorder.log(&self.rotors, t, &Rotors::of(m, limits))?;
        }
        self.recorder
            .log(&self.disturbances, t, &Disturbances::of(m))
    }

    /// Finishes the file (summary, index).
    pub fn finish(self) -> Result<crate::record::RecordSummary, RecordError> {
        self.recorder.finish()
    }
}

/// The paper's saturation indicator on what the rotors did: any realised thrust at a limit
/// (within 1e-5 N) or any command the motor model had to clamp.
pub fn rotors_saturated(m: &Measurement, (t_min, t_max): (f64, f64)) -> bool {
    let realised: Vec<f64> = m.rotors.iter().map(|r| r.realised_n).collect();
    allocation::any_rotor_saturated(&realised, t_min, t_max) || m.rotors.iter().any(|r| r.saturated)
}
