//! The messages on the wire: fixed-size, `#[repr(C)]`, zero-copy, versioned.
//!
//! Every data message carries [`MESSAGE_VERSION`] and its iceoryx2 type name ends in the same
//! version (`amstack.sitl.Measurement.v1`), so two builds with different layouts can neither
//! exchange data by accident nor open each other's services. The handshake messages
//! ([`Hello`], [`Welcome`]) keep one layout across versions: they are how a mismatch is named.
//!
//! Variable-length parts of [`Measurement`] and [`ActuatorCommand`] sit in arrays of
//! [`MAX_JOINTS`] and [`MAX_ROTORS`] entries with a count; entries past the count are zero.
//! Quaternions are w, x, y, z. Units SI; frames as in `platform` (world Z-up, body FLU).
//! Conversions copy every `f64` bit for bit, so a flight over the wire sees exactly what
//! the twin computed (the equivalence with the in-process twin rests on this).

use iceoryx2::prelude::ZeroCopySend;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use platform::{
    ActuatorCommand, DisturbanceReport, Measurement, RigidBodyState, RotorReport, Wrench,
};

use crate::{HeldJoint, TaskId, TaskObservation, TaskSnapshot, TaskStatus};

/// Version of the data messages' layout and meaning. Bump on any change of
/// [`MeasurementMsg`] or [`CommandMsg`] (and of the type names below).
pub const MESSAGE_VERSION: u32 = 3;
/// Most movable joints a vehicle may have on the wire (arm, gripper, tilt hinges).
pub const MAX_JOINTS: usize = 16;
/// Most rotors a vehicle may have on the wire.
pub const MAX_ROTORS: usize = 8;
/// Longest vehicle id, bytes (UTF-8).
pub const MAX_ID_BYTES: usize = 64;
/// Longest twin configuration (JSON) carried by the handshake, bytes.
pub const MAX_CONFIG_BYTES: usize = 4096;
/// Longest refusal reason, bytes.
pub const MAX_REASON_BYTES: usize = 512;
/// Most criteria a task may have on the wire.
pub const MAX_TASK_CRITERIA: usize = 8;
/// Most observation keys a task may have on the wire.
pub const MAX_TASK_KEYS: usize = 8;
/// Longest observation key name, bytes.
pub const MAX_TASK_KEY_BYTES: usize = 24;
/// Most observation values (all keys together) on the wire.
pub const MAX_TASK_VALUES: usize = 48;

/// [`TaskMsg::flags`]: the success criterion holds.
pub const TASK_SUCCESS: u32 = 1;
/// [`TaskMsg::flags`]: the grasp constraint holds an object.
pub const TASK_HOLDING: u32 = 2;
/// [`TaskMsg::flags`]: `wall_*` is set.
pub const TASK_HAS_WALL: u32 = 4;
/// [`TaskMsg::flags`]: `obstacle_face_x_m` is set.
pub const TASK_HAS_OBSTACLE_FACE: u32 = 8;
/// [`TaskMsg::flags`]: the held object slides along `held_axis` (a prismatic joint).
pub const TASK_HELD_PRISMATIC: u32 = 16;
/// [`TaskMsg::flags`]: the held object turns about `held_axis` through `held_point_m`.
pub const TASK_HELD_REVOLUTE: u32 = 32;
/// [`TaskMsg::flags`]: `hand_contact` is set.
pub const TASK_HAS_HAND_CONTACT: u32 = 64;

/// [`CommandMsg::flags`]: the flight process ends its session (no failsafe follows).
pub const COMMAND_END_OF_SESSION: u32 = 1;
/// [`CommandMsg::flags`]: `direct_wrench_in_body` is set (the EE-only oracle).
pub const COMMAND_HAS_DIRECT_WRENCH: u32 = 2;

/// [`MeasurementMsg::flags`]: the flight process was lost; the twin holds its last command.
pub const MEASUREMENT_HOLDING: u32 = 1;
/// [`MeasurementMsg::flags`]: the failsafe is applied.
pub const MEASUREMENT_FAILSAFE: u32 = 2;
/// [`MeasurementMsg::flags`]: the twin could not step (a diverged simulation, a bad command);
/// the session is over and the data are those of the last good step.
pub const MEASUREMENT_SESSION_FAILED: u32 = 4;

/// Role of a joint in the configuration order ([`Welcome::joint_roles`]).
pub mod joint_role {
    /// Not one of the roles below.
    pub const OTHER: u8 = 0;
    /// An arm joint.
    pub const ARM: u8 = 1;
    /// A gripper finger.
    pub const GRIPPER: u8 = 2;
    /// A rotor's tilt hinge (Omni-Hexa).
    pub const TILT: u8 = 3;
}

/// One rotor over the last control period (see [`RotorReport`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("amstack.sitl.Rotor.v3")]
pub struct RotorMsg {
    /// Thrust commanded, N.
    pub commanded_n: f64,
    /// Thrust the motor produced, N.
    pub realised_n: f64,
    /// Thrust after ground and near-wall effects, N.
    pub applied_n: f64,
    /// Ground-effect gain.
    pub ground_effect_gain: f64,
    /// Distance to the surface below, m.
    pub ground_distance_m: f64,
    /// Distance to the nearest wall, m.
    pub wall_distance_m: f64,
    /// 1 when the command was outside the thrust limits.
    pub saturated: u8,
    /// Zero.
    pub reserved: [u8; 7],
}

/// A simulated IMU at the base origin, from the twin's truth (no noise): what an
/// integrating accelerometer and gyro fixed to the base read over the last control period
/// ([`crate::sensors::ideal_imu`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("amstack.sitl.Imu.v3")]
pub struct ImuMsg {
    /// Specific force f = Rᵀ(a − g), base frame, m/s², with a the base origin's world
    /// acceleration averaged over the last control period, R the attitude at mid-period and
    /// g = (0, 0, −9.81) m/s² (at rest, level: (0, 0, +9.81)).
    pub specific_force_in_body_mps2: [f64; 3],
    /// Angular velocity, base frame, rad/s: the mean over the last control period (its
    /// delta angle over its length).
    pub angular_velocity_in_body_radps: [f64; 3],
}

/// The task scene after the tick (see [`TaskSnapshot`]); `task` 0 without a task.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("amstack.sitl.Task.v3")]
pub struct TaskMsg {
    /// 0: no task; k: `TaskId::ALL[k − 1]`.
    pub task: u32,
    /// `TASK_*` bits.
    pub flags: u32,
    /// Env steps since reset.
    pub steps: u64,
    /// Criteria in use ([`TaskId::criteria_names`] order).
    pub criteria_count: u32,
    /// Observation keys in use.
    pub key_count: u32,
    /// Each criterion now, 0 or 1.
    pub criteria: [u8; MAX_TASK_CRITERIA],
    /// Observation key names, UTF-8, `key_name_lens` bytes each.
    pub key_names: [[u8; MAX_TASK_KEY_BYTES]; MAX_TASK_KEYS],
    /// Length of each key name.
    pub key_name_lens: [u32; MAX_TASK_KEYS],
    /// Values of each key (they follow each other in `values`).
    pub key_value_counts: [u32; MAX_TASK_KEYS],
    /// Every key's values, in key order.
    pub values: [f64; MAX_TASK_VALUES],
    /// The wall's position in the world, m.
    pub wall_position_in_world_m: [f64; 3],
    /// The wall's orientation, w x y z.
    pub world_from_wall_wxyz: [f64; 4],
    /// World x of the obstacle face the base must stay in front of, m.
    pub obstacle_face_x_m: f64,
    /// The held object's joint axis, world (`TASK_HELD_*`; `TaskSnapshot::held_joint`).
    pub held_axis: [f64; 3],
    /// A point on a held revolute joint's axis, world, m.
    pub held_point_m: [f64; 3],
    /// The normal of the hand's blocking contact, world (`TASK_HAS_HAND_CONTACT`;
    /// `TaskSnapshot::hand_contact`).
    pub hand_contact: [f64; 3],
}

impl Default for TaskMsg {
    fn default() -> Self {
        Self {
            task: 0,
            flags: 0,
            steps: 0,
            criteria_count: 0,
            key_count: 0,
            criteria: [0; MAX_TASK_CRITERIA],
            key_names: [[0; MAX_TASK_KEY_BYTES]; MAX_TASK_KEYS],
            key_name_lens: [0; MAX_TASK_KEYS],
            key_value_counts: [0; MAX_TASK_KEYS],
            values: [0.0; MAX_TASK_VALUES],
            wall_position_in_world_m: [0.0; 3],
            world_from_wall_wxyz: [1.0, 0.0, 0.0, 0.0],
            obstacle_face_x_m: 0.0,
            held_axis: [0.0; 3],
            held_point_m: [0.0; 3],
            hand_contact: [0.0; 3],
        }
    }
}

impl TaskMsg {
    /// The wire form of `snapshot` (None: no task).
    pub fn from_snapshot(snapshot: Option<&TaskSnapshot>) -> Result<Self, TooLarge> {
        let mut msg = Self::default();
        let Some(t) = snapshot else {
            return Ok(msg);
        };
        fits("task criteria", t.status.criteria.len(), MAX_TASK_CRITERIA)?;
        fits(
            "task observation keys",
            t.observation.entries.len(),
            MAX_TASK_KEYS,
        )?;
        let values: usize = t.observation.entries.iter().map(|(_, v)| v.len()).sum();
        fits("task observation values", values, MAX_TASK_VALUES)?;
        msg.task = TaskId::ALL
            .iter()
            .position(|&id| id == t.task)
            .map_or(0, |i| i as u32 + 1);
        msg.steps = t.steps;
        msg.criteria_count = t.status.criteria.len() as u32;
        for (slot, &c) in msg.criteria.iter_mut().zip(&t.status.criteria) {
            *slot = u8::from(c);
        }
        msg.key_count = t.observation.entries.len() as u32;
        let mut at = 0;
        for (i, (name, v)) in t.observation.entries.iter().enumerate() {
            fits("task observation key bytes", name.len(), MAX_TASK_KEY_BYTES)?;
            msg.key_name_lens[i] = put_str(&mut msg.key_names[i], name);
            msg.key_value_counts[i] = v.len() as u32;
            msg.values[at..at + v.len()].copy_from_slice(v);
            at += v.len();
        }
        if t.status.success {
            msg.flags |= TASK_SUCCESS;
        }
        if t.holding {
            msg.flags |= TASK_HOLDING;
        }
        if let Some(w) = &t.wall {
            msg.flags |= TASK_HAS_WALL;
            msg.wall_position_in_world_m = w.translation.vector.into();
            let q = w.rotation.quaternion();
            msg.world_from_wall_wxyz = [q.w, q.i, q.j, q.k];
        }
        if let Some(x) = t.obstacle_face_x {
            msg.flags |= TASK_HAS_OBSTACLE_FACE;
            msg.obstacle_face_x_m = x;
        }
        match t.held_joint {
            Some(HeldJoint::Prismatic { axis }) => {
                msg.flags |= TASK_HELD_PRISMATIC;
                msg.held_axis = axis.into();
            }
            Some(HeldJoint::Revolute { axis, point }) => {
                msg.flags |= TASK_HELD_REVOLUTE;
                msg.held_axis = axis.into();
                msg.held_point_m = point.into();
            }
            None => {}
        }
        if let Some(n) = t.hand_contact {
            msg.flags |= TASK_HAS_HAND_CONTACT;
            msg.hand_contact = n.into();
        }
        Ok(msg)
    }

    /// Back to the twin's type (None without a task; counts clamped to the arrays). Every
    /// value is copied bit for bit.
    pub fn to_snapshot(&self) -> Option<TaskSnapshot> {
        let task = *TaskId::ALL.get((self.task as usize).checked_sub(1)?)?;
        let criteria = (self.criteria_count as usize).min(MAX_TASK_CRITERIA);
        let keys = (self.key_count as usize).min(MAX_TASK_KEYS);
        let mut observation = TaskObservation::default();
        let mut at = 0;
        for i in 0..keys {
            let n = (self.key_value_counts[i] as usize).min(MAX_TASK_VALUES - at);
            observation.push(
                get_str(&self.key_names[i], self.key_name_lens[i]),
                self.values[at..at + n].iter().copied(),
            );
            at += n;
        }
        let w = &self.world_from_wall_wxyz;
        Some(TaskSnapshot {
            task,
            status: TaskStatus {
                success: self.flags & TASK_SUCCESS != 0,
                criteria: self.criteria[..criteria].iter().map(|&c| c != 0).collect(),
            },
            observation,
            wall: (self.flags & TASK_HAS_WALL != 0).then(|| {
                Isometry3::from_parts(
                    Translation3::from(Vector3::from(self.wall_position_in_world_m)),
                    UnitQuaternion::new_unchecked(Quaternion::new(w[0], w[1], w[2], w[3])),
                )
            }),
            obstacle_face_x: (self.flags & TASK_HAS_OBSTACLE_FACE != 0)
                .then_some(self.obstacle_face_x_m),
            holding: self.flags & TASK_HOLDING != 0,
            held_joint: if self.flags & TASK_HELD_PRISMATIC != 0 {
                Some(HeldJoint::Prismatic {
                    axis: Vector3::from(self.held_axis),
                })
            } else if self.flags & TASK_HELD_REVOLUTE != 0 {
                Some(HeldJoint::Revolute {
                    axis: Vector3::from(self.held_axis),
                    point: Vector3::from(self.held_point_m),
                })
            } else {
                None
            },
            hand_contact: (self.flags & TASK_HAS_HAND_CONTACT != 0)
                .then(|| Vector3::from(self.hand_contact)),
            steps: self.steps,
        })
    }
}

/// Twin → flight: the measurement at the end of a control period.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("amstack.sitl.Measurement.v3")]
pub struct MeasurementMsg {
    /// [`MESSAGE_VERSION`].
    pub version: u32,
    /// `MEASUREMENT_*` bits.
    pub flags: u32,
    /// The session the measurement belongs to ([`Welcome::session`]).
    pub session: u64,
    /// Control periods simulated in this session: 0 for the state at its start, k after
    /// the k-th step.
    pub tick: u64,
    /// Wall-clock time the twin spent on this tick (stepping and publishing), ns.
    pub twin_busy_ns: u64,
    /// Simulated time, s.
    pub time_s: f64,
    /// Base origin in the world, m.
    pub position_in_world_m: [f64; 3],
    /// Base orientation `world_from_body`, w x y z.
    pub world_from_body_wxyz: [f64; 4],
    /// Base origin velocity in the world, m/s.
    pub velocity_in_world_mps: [f64; 3],
    /// Base angular velocity in the body frame, rad/s.
    pub angular_velocity_in_body_radps: [f64; 3],
    /// Movable joints in use.
    pub joint_count: u32,
    /// Rotors in use.
    pub rotor_count: u32,
    /// Joint positions, configuration order, rad or m.
    pub joint_positions: [f64; MAX_JOINTS],
    /// Joint velocities, rad/s or m/s.
    pub joint_velocities: [f64; MAX_JOINTS],
    /// Gripper opening in [−1, 1] (−1 closed, +1 open) from the finger positions; NaN
    /// without a gripper.
    pub gripper_opening: f64,
    /// End-effector link origin in the world, m.
    pub ee_position_in_world_m: [f64; 3],
    /// End-effector link orientation in the world, w x y z.
    pub world_from_ee_wxyz: [f64; 4],
    /// Per rotor.
    pub rotors: [RotorMsg; MAX_ROTORS],
    /// Drag, base frame, N.
    pub drag_n: [f64; 3],
    /// Wind, base frame, N.
    pub wind_n: [f64; 3],
    /// Ground-effect extra force, base frame, N.
    pub ground_effect_n: [f64; 3],
    /// Near-wall extra force, base frame, N.
    pub near_wall_n: [f64; 3],
    /// The simulated IMU.
    pub imu: ImuMsg,
    /// The task scene after the tick.
    pub task: TaskMsg,
}

/// Flight → twin: the actuator command for one control period.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("amstack.sitl.Command.v3")]
pub struct CommandMsg {
    /// [`MESSAGE_VERSION`].
    pub version: u32,
    /// `COMMAND_*` bits.
    pub flags: u32,
    /// The session ([`Welcome::session`]); commands of other sessions are ignored.
    pub session: u64,
    /// The measurement tick this command answers: in lockstep the twin applies it when it
    /// is the current tick, and steps once.
    pub tick: u64,
    /// Rotors in use.
    pub rotor_count: u32,
    /// Joint targets in use.
    pub joint_count: u32,
    /// Thrust per rotor, N, rotor order.
    pub rotor_thrusts_n: [f64; MAX_ROTORS],
    /// Position target of every movable joint in configuration order — arm, gripper
    /// fingers, tilt hinges ([`Welcome::joint_roles`] names each) — rad or m.
    pub joint_targets: [f64; MAX_JOINTS],
    /// Direct wrench on the base, body frame, `[F; τ]` (with [`COMMAND_HAS_DIRECT_WRENCH`]).
    pub direct_wrench_in_body: [f64; 6],
}

/// Flight → twin, at connect: who is asking and what it expects. One layout for every
/// message version.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("amstack.sitl.Hello")]
pub struct Hello {
    /// The flight's [`MESSAGE_VERSION`].
    pub version: u32,
    /// The flight process's id.
    pub pid: u32,
    /// The flight's iceoryx2 node id (watched for the process's death), low then high half.
    pub node_id: [u64; 2],
    /// Vehicle id, UTF-8, `id_len` bytes.
    pub vehicle_id: [u8; MAX_ID_BYTES],
    /// Length of `vehicle_id`.
    pub id_len: u32,
    /// Length of `config_json`.
    pub config_len: u32,
    /// Control rate, Hz.
    pub control_rate_hz: f64,
    /// Hash of the vehicle description (see [`super::vehicle_hash`]).
    pub vehicle_hash: u64,
    /// Hash of the twin configuration (see [`super::config_hash`]).
    pub config_hash: u64,
    /// The twin configuration the flight expects, JSON.
    pub config_json: [u8; MAX_CONFIG_BYTES],
}

/// Twin → flight, the answer to [`Hello`]. One layout for every message version.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("amstack.sitl.Welcome")]
pub struct Welcome {
    /// 1 accepted, 0 refused (`reason` says why).
    pub accepted: u32,
    /// The twin's [`MESSAGE_VERSION`].
    pub version: u32,
    /// The session opened (measurements and commands carry it).
    pub session: u64,
    /// The twin's iceoryx2 node id, low then high half.
    pub node_id: [u64; 2],
    /// The twin process's id.
    pub pid: u32,
    /// 0 lockstep, 1 realtime.
    pub mode: u32,
    /// Vehicle served, UTF-8.
    pub vehicle_id: [u8; MAX_ID_BYTES],
    /// Length of `vehicle_id`.
    pub id_len: u32,
    /// Length of `reason`.
    pub reason_len: u32,
    /// Control rate, Hz.
    pub control_rate_hz: f64,
    /// Hash of the vehicle description served.
    pub vehicle_hash: u64,
    /// Hash of the twin configuration served.
    pub config_hash: u64,
    /// Rotors.
    pub rotor_count: u32,
    /// Movable joints.
    pub joint_count: u32,
    /// Role of each joint in configuration order (`joint_role::*`).
    pub joint_roles: [u8; MAX_JOINTS],
    /// Why the connection was refused, UTF-8, naming both values.
    pub reason: [u8; MAX_REASON_BYTES],
}

/// `text` into a fixed buffer (cut at a character boundary if too long); the length used.
pub fn put_str<const N: usize>(buffer: &mut [u8; N], text: &str) -> u32 {
    let mut end = text.len().min(N);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    buffer[..end].copy_from_slice(&text.as_bytes()[..end]);
    buffer[end..].fill(0);
    end as u32
}

/// The text in the first `len` bytes of `buffer` (lossy).
pub fn get_str(buffer: &[u8], len: u32) -> String {
    let end = (len as usize).min(buffer.len());
    String::from_utf8_lossy(&buffer[..end]).into_owned()
}

fn v3(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn wxyz(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

/// A quaternion off the wire, bit for bit (it was unit when sent).
fn from_wxyz(q: &[f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// The vehicle's shape on the wire is too large.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{what}: {count} does not fit the wire's {max}")]
pub struct TooLarge {
    /// What overflowed.
    pub what: &'static str,
    /// How many there are.
    pub count: usize,
    /// The limit.
    pub max: usize,
}

fn fits(what: &'static str, count: usize, max: usize) -> Result<(), TooLarge> {
    if count > max {
        Err(TooLarge { what, count, max })
    } else {
        Ok(())
    }
}

impl Default for MeasurementMsg {
    fn default() -> Self {
        Self {
            version: MESSAGE_VERSION,
            flags: 0,
            session: 0,
            tick: 0,
            twin_busy_ns: 0,
            time_s: 0.0,
            position_in_world_m: [0.0; 3],
            world_from_body_wxyz: [1.0, 0.0, 0.0, 0.0],
            velocity_in_world_mps: [0.0; 3],
            angular_velocity_in_body_radps: [0.0; 3],
            joint_count: 0,
            rotor_count: 0,
            joint_positions: [0.0; MAX_JOINTS],
            joint_velocities: [0.0; MAX_JOINTS],
            gripper_opening: f64::NAN,
            ee_position_in_world_m: [0.0; 3],
            world_from_ee_wxyz: [1.0, 0.0, 0.0, 0.0],
            rotors: [RotorMsg::default(); MAX_ROTORS],
            drag_n: [0.0; 3],
            wind_n: [0.0; 3],
            ground_effect_n: [0.0; 3],
            near_wall_n: [0.0; 3],
            imu: ImuMsg::default(),
            task: TaskMsg::default(),
        }
    }
}

impl MeasurementMsg {
    /// The wire form of `m` (the IMU and gripper opening are the caller's to set).
    pub fn from_measurement(m: &Measurement) -> Result<Self, TooLarge> {
        fits("joints", m.joint_positions.len(), MAX_JOINTS)?;
        fits("joint velocities", m.joint_velocities.len(), MAX_JOINTS)?;
        fits("rotors", m.rotors.len(), MAX_ROTORS)?;
        let mut msg = Self {
            time_s: m.time_s,
            position_in_world_m: v3(&m.base.position_in_world_m),
            world_from_body_wxyz: wxyz(&m.base.world_from_body),
            velocity_in_world_mps: v3(&m.base.velocity_in_world_mps),
            angular_velocity_in_body_radps: v3(&m.base.angular_velocity_in_body_radps),
            joint_count: m.joint_positions.len() as u32,
            rotor_count: m.rotors.len() as u32,
            ee_position_in_world_m: v3(&m.world_from_ee.translation.vector),
            world_from_ee_wxyz: wxyz(&m.world_from_ee.rotation),
            drag_n: v3(&m.disturbances.drag_n),
            wind_n: v3(&m.disturbances.wind_n),
            ground_effect_n: v3(&m.disturbances.ground_effect_n),
            near_wall_n: v3(&m.disturbances.near_wall_n),
            ..Self::default()
        };
        msg.joint_positions[..m.joint_positions.len()].copy_from_slice(&m.joint_positions);
        msg.joint_velocities[..m.joint_velocities.len()].copy_from_slice(&m.joint_velocities);
        for (wire, r) in msg.rotors.iter_mut().zip(&m.rotors) {
            *wire = RotorMsg {
                commanded_n: r.commanded_n,
                realised_n: r.realised_n,
                applied_n: r.applied_n,
                ground_effect_gain: r.ground_effect_gain,
                ground_distance_m: r.ground_distance_m,
                wall_distance_m: r.wall_distance_m,
                saturated: u8::from(r.saturated),
                reserved: [0; 7],
            };
        }
        Ok(msg)
    }

    /// Back to the flight stack's type (counts clamped to the arrays).
    pub fn to_measurement(&self) -> Measurement {
        let joints = (self.joint_count as usize).min(MAX_JOINTS);
        let rotors = (self.rotor_count as usize).min(MAX_ROTORS);
        Measurement {
            time_s: self.time_s,
            base: RigidBodyState {
                position_in_world_m: Vector3::from(self.position_in_world_m),
                world_from_body: from_wxyz(&self.world_from_body_wxyz),
                velocity_in_world_mps: Vector3::from(self.velocity_in_world_mps),
                angular_velocity_in_body_radps: Vector3::from(self.angular_velocity_in_body_radps),
            },
            joint_positions: self.joint_positions[..joints].to_vec(),
            joint_velocities: self.joint_velocities[..joints].to_vec(),
            world_from_ee: Isometry3::from_parts(
                Translation3::from(Vector3::from(self.ee_position_in_world_m)),
                from_wxyz(&self.world_from_ee_wxyz),
            ),
            rotors: self.rotors[..rotors]
                .iter()
                .map(|r| RotorReport {
                    commanded_n: r.commanded_n,
                    realised_n: r.realised_n,
                    applied_n: r.applied_n,
                    saturated: r.saturated != 0,
                    ground_effect_gain: r.ground_effect_gain,
                    ground_distance_m: r.ground_distance_m,
                    wall_distance_m: r.wall_distance_m,
                })
                .collect(),
            disturbances: DisturbanceReport {
                drag_n: Vector3::from(self.drag_n),
                wind_n: Vector3::from(self.wind_n),
                ground_effect_n: Vector3::from(self.ground_effect_n),
                near_wall_n: Vector3::from(self.near_wall_n),
            },
        }
    }
}

impl Default for CommandMsg {
    fn default() -> Self {
        Self {
            version: MESSAGE_VERSION,
            flags: 0,
            session: 0,
            tick: 0,
            rotor_count: 0,
            joint_count: 0,
            rotor_thrusts_n: [0.0; MAX_ROTORS],
            joint_targets: [0.0; MAX_JOINTS],
            direct_wrench_in_body: [0.0; 6],
        }
    }
}

impl CommandMsg {
    /// The wire form of `command` for `tick` of `session`.
    pub fn from_command(
        command: &ActuatorCommand,
        session: u64,
        tick: u64,
    ) -> Result<Self, TooLarge> {
        fits("rotor thrusts", command.rotor_thrusts_n.len(), MAX_ROTORS)?;
        fits("joint targets", command.joint_targets.len(), MAX_JOINTS)?;
        let mut msg = Self {
            session,
            tick,
            rotor_count: command.rotor_thrusts_n.len() as u32,
            joint_count: command.joint_targets.len() as u32,
            ..Self::default()
        };
        msg.rotor_thrusts_n[..command.rotor_thrusts_n.len()]
            .copy_from_slice(&command.rotor_thrusts_n);
        msg.joint_targets[..command.joint_targets.len()].copy_from_slice(&command.joint_targets);
        if let Some(w) = command.direct_wrench_in_body {
            msg.flags |= COMMAND_HAS_DIRECT_WRENCH;
            msg.direct_wrench_in_body = [
                w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z,
            ];
        }
        Ok(msg)
    }

    /// Back to the twin's type (counts clamped to the arrays).
    pub fn to_command(&self) -> ActuatorCommand {
        let rotors = (self.rotor_count as usize).min(MAX_ROTORS);
        let joints = (self.joint_count as usize).min(MAX_JOINTS);
        let w = &self.direct_wrench_in_body;
        ActuatorCommand {
            rotor_thrusts_n: self.rotor_thrusts_n[..rotors].to_vec(),
            joint_targets: self.joint_targets[..joints].to_vec(),
            direct_wrench_in_body: (self.flags & COMMAND_HAS_DIRECT_WRENCH != 0).then(|| {
                Wrench::new(
                    Vector3::new(w[0], w[1], w[2]),
                    Vector3::new(w[3], w[4], w[5]),
                )
            }),
        }
    }
}

impl Default for Hello {
    fn default() -> Self {
        Self {
            version: MESSAGE_VERSION,
            pid: 0,
            node_id: [0; 2],
            vehicle_id: [0; MAX_ID_BYTES],
            id_len: 0,
            config_len: 0,
            control_rate_hz: 0.0,
            vehicle_hash: 0,
            config_hash: 0,
            config_json: [0; MAX_CONFIG_BYTES],
        }
    }
}

impl Default for Welcome {
    fn default() -> Self {
        Self {
            accepted: 0,
            version: MESSAGE_VERSION,
            session: 0,
            node_id: [0; 2],
            pid: 0,
            mode: 0,
            vehicle_id: [0; MAX_ID_BYTES],
            id_len: 0,
            reason_len: 0,
            control_rate_hz: 0.0,
            vehicle_hash: 0,
            config_hash: 0,
            rotor_count: 0,
            joint_count: 0,
            joint_roles: [joint_role::OTHER; MAX_JOINTS],
            reason: [0; MAX_REASON_BYTES],
        }
    }
}

/// A node id as two halves, and back.
pub fn split_id(id: u128) -> [u64; 2] {
    [id as u64, (id >> 64) as u64]
}

/// The node id of two halves.
pub fn join_id(halves: [u64; 2]) -> u128 {
    u128::from(halves[0]) | (u128::from(halves[1]) << 64)
}
