//! Setpoints out: amstack's commands → MAVLink messages, at the two levels of the contract
//! (`docs/mavlink.md`), and back (for tests and for whoever receives them).
//!
//! **Actuator level** — SET_ACTUATOR_CONTROL_TARGET (id 139), one message per group, sent
//! back to back with group 0 last (group 0 completes a tick):
//!
//! ```text
//! group 2: arm joint j (command order):  c_j = 2 (q_j − lower_j) / (upper_j − lower_j) − 1
//!          then the gripper:             c   = 2 (q − closed) / (open − closed) − 1  (mean over fingers)
//! group 1: tilt joint i (rotor order):   c_i = 2 (α_i − lower_i) / (upper_i − lower_i) − 1
//! group 0: rotor i:                      u_i = curve⁻¹(T_i),  T = T_min + (k u² + (1 − k) u)(T_max − T_min)
//! ```
//!
//! Controls are clamped to their range ([−1, 1], or [0, 1] for motors); unused controls are 0.
//!
//! **Attitude level** — SET_ATTITUDE_TARGET (id 82) with the desired attitude `ned_from_frd`,
//! `thrust_body` = body force (FRD) / (rotor count · T_max) clamped to [−1, 1] per component
//! (type_mask THRUST_BODY_SET, for the vehicles that can push sideways: fully actuated and
//! tilting), or for the under-actuated ones the collective `thrust` = F_z / (rotor count ·
//! T_max) clamped to [0, 1] alone, and the body-rate feed-forward (FRD), preceded by the
//! group-2 arm message.
//!
//! **Rate level** — SET_ATTITUDE_TARGET with ATTITUDE_IGNORE (128): the body rates (FRD) and
//! the attitude level's thrust fields (q identity, not read).
//!
//! **Position level** — SET_POSITION_TARGET_LOCAL_NED (id 84), MAV_FRAME_LOCAL_NED: x/y/z =
//! `ned_from_world(p)`, yaw = π/2 − ψ (PX4's heading, clockwise from north), type_mask
//! ignoring velocity (8/16/32), acceleration (64/128/256) and yaw rate (2048): PX4's
//! position controller flies to the point, preceded by the group-2 arm message.
//!
//! The group-2 arm message at the attitude and position levels is the arm's channel when the
//! receiver is amstack's twin (which stands in for the arm's own servo bus); toward another
//! autopilot the link leaves it out ([`SetpointCodec::with_arm_channel`]).
//!
//! A command holding a non-finite number is refused with an error naming the field: the
//! bridge never sends one.
//!
//! **Receiving** (the twin's autopilot; tests): [`SetpointCodec::decode_actuator`] and
//! [`SetpointCodec::decode_attitude`] invert both with the same layout. A setpoint with a
//! non-finite or out-of-range value (beyond f32 slack), or for a group the vehicle does not
//! use, is refused whole; values within range are clamped to their limits.

use mavlink::dialects::common::{
    AttitudeTargetTypemask, MavFrame, MavMessage, PositionTargetTypemask,
    SET_ACTUATOR_CONTROL_TARGET_DATA, SET_ATTITUDE_TARGET_DATA, SET_POSITION_TARGET_LOCAL_NED_DATA,
};
use nalgebra::Vector3;
use platform::{Actuation, ActuatorCommand, PositionSetpoint, RateSetpoint, ThrustCurve, Vehicle};

use crate::frames;

/// Controls per SET_ACTUATOR_CONTROL_TARGET group.
pub const CONTROLS_PER_GROUP: usize = 8;
/// Group of the motors.
pub const GROUP_MOTORS: u8 = 0;
/// Group of the tilt servos.
pub const GROUP_TILT: u8 = 1;
/// Group of the arm joints and the gripper.
pub const GROUP_ARM: u8 = 2;

/// A setpoint that cannot be sent.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetpointError {
    /// A value was NaN or infinite.
    #[error("refusing to send a non-finite setpoint: {field} = {value}")]
    NonFinite {
        /// Which value (`rotor_thrusts_n[2]`, `joint_targets[5]`, `force_in_body_n.z`).
        field: String,
        /// The value.
        value: f64,
    },
    /// The command does not match the vehicle.
    #[error("setpoint does not fit the vehicle: {0}")]
    Shape(String),
    /// A received setpoint is refused (the receiver's side).
    #[error("setpoint refused: {0}")]
    Refused(String),
}

/// Slack on the [−1, 1] and [0, 1] ranges before a received control counts as out of range
/// (f32 rounding of a sender at the limits).
const RANGE_SLACK: f32 = 1e-3;

/// What one received SET_ACTUATOR_CONTROL_TARGET commanded.
#[derive(Debug, Clone, PartialEq)]
pub enum ActuatorUpdate {
    /// Group 0: the rotor thrusts, N; a control tick is complete.
    Motors(Vec<f64>),
    /// Group 1 or 2: joint targets updated.
    Joints,
}

/// One linear channel: a configuration index and the range mapped onto [−1, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
struct Channel {
    dof: usize,
    lower: f64,
    upper: f64,
}

impl Channel {
    fn to_control(self, q: f64) -> f32 {
        let span = self.upper - self.lower;
        let c = if span > 0.0 {
            2.0 * (q - self.lower) / span - 1.0
        } else {
            0.0
        };
        // MAVLink carries f32; the narrowing is the protocol's.
        #[allow(clippy::cast_possible_truncation)]
        let c = c.clamp(-1.0, 1.0) as f32;
        c
    }

    fn position_of(self, c: f32) -> f64 {
        let c = f64::from(c).clamp(-1.0, 1.0);
        self.lower + 0.5 * (c + 1.0) * (self.upper - self.lower)
    }
}

/// The gripper's finger joints: configuration index, closed and open positions.
#[derive(Debug, Clone, PartialEq)]
struct Fingers {
    fingers: Vec<(usize, f64, f64)>,
}

/// The attitude level's setpoint, in amstack's frames (`platform`'s; a `None` body rate sets
/// the type mask's rate-ignore bits).
pub use platform::AttitudeSetpoint;

/// The vehicle's command layout on the wire, built once from its description.
#[derive(Debug, Clone, PartialEq)]
pub struct SetpointCodec {
    rotor_count: usize,
    curve: ThrustCurve,
    thrust_max_n: f64,
    dof: usize,
    tilts: Vec<Channel>,
    arm: Vec<Channel>,
    gripper: Option<Fingers>,
    /// Whether the attitude level sends `thrust_body` (a vehicle that can push sideways) or
    /// the collective thrust alone.
    thrust_body: bool,
    /// Whether the attitude and position levels send the group-2 arm message.
    arm_channel: bool,
    target_system: u8,
    target_component: u8,
}

fn check_finite(field: impl FnOnce() -> String, value: f64) -> Result<(), SetpointError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(SetpointError::NonFinite {
            field: field(),
            value,
        })
    }
}

impl SetpointCodec {
    /// The layout of `vehicle`, addressed to `target_system`/`target_component` (1/1 for a
    /// PX4 autopilot). Fails if a group would need more than 8 controls or a joint has no
    /// limits.
    pub fn new(
        vehicle: &Vehicle,
        target_system: u8,
        target_component: u8,
    ) -> Result<Self, SetpointError> {
        let model = &vehicle.model;
        let channel = |joint: usize, what: &str| -> Result<Channel, SetpointError> {
            let j = &model.joints[joint];
            let dof = j.dof.ok_or_else(|| {
                SetpointError::Shape(format!("{what} joint '{}' does not move", j.name))
            })?;
            let limits = j.limits.ok_or_else(|| {
                SetpointError::Shape(format!("{what} joint '{}' has no limits", j.name))
            })?;
            Ok(Channel {
                dof,
                lower: limits.lower,
                upper: limits.upper,
            })
        };
        let arm = vehicle
            .arm_joints
            .iter()
            .map(|&j| channel(j, "arm"))
            .collect::<Result<Vec<_>, _>>()?;
        let mut tilts = Vec::new();
        for rotor in &vehicle.rotors.rotors {
            if let Some(t) = &rotor.tilt {
                let j = model.joint_id(&t.joint).ok_or_else(|| {
                    SetpointError::Shape(format!("tilt joint '{}' is not in the model", t.joint))
                })?;
                let mut c = channel(j, "tilt")?;
                (c.lower, c.upper) = t.limits_rad;
                tilts.push(c);
            }
        }
        let gripper = match &vehicle.gripper {
            None => None,
            Some(g) => {
                let mut fingers = Vec::new();
                for ((&j, &closed), &open) in g.joints.iter().zip(&g.closed).zip(&g.open) {
                    let dof = model.joints[j].dof.ok_or_else(|| {
                        SetpointError::Shape(format!(
                            "gripper joint '{}' does not move",
                            model.joints[j].name
                        ))
                    })?;
                    fingers.push((dof, closed, open));
                }
                Some(Fingers { fingers })
            }
        };
        let rotor_count = vehicle.rotors.len();
        let group2 = arm.len() + usize::from(gripper.is_some());
        for (what, n) in [
            ("rotors (group 0)", rotor_count),
            ("tilt servos (group 1)", tilts.len()),
            ("arm joints + gripper (group 2)", group2),
        ] {
            if n > CONTROLS_PER_GROUP {
                return Err(SetpointError::Shape(format!(
                    "{n} {what} do not fit the {CONTROLS_PER_GROUP} controls of a group"
                )));
            }
        }
        Ok(Self {
            rotor_count,
            curve: vehicle.rotors.thrust_curve,
            thrust_max_n: vehicle.rotors.thrust_max_n,
            dof: model.dof(),
            tilts,
            arm,
            gripper,
            thrust_body: vehicle.actuation != Actuation::UnderActuated,
            arm_channel: true,
            target_system,
            target_component,
        })
    }

    /// Whether the attitude and position levels send the arm and gripper as group 2 (on by
    /// default). amstack's twin takes group 2 as the arm's servo bus; a PX4 has no arm and no
    /// SET_ACTUATOR_CONTROL_TARGET: toward it the link turns the channel off.
    pub fn with_arm_channel(mut self, on: bool) -> Self {
        self.arm_channel = on;
        self
    }

    /// Whether the attitude and position levels send group 2.
    pub fn arm_channel(&self) -> bool {
        self.arm_channel
    }

    /// Whether the attitude level sends `thrust_body` (THRUST_BODY_SET) rather than the
    /// collective thrust alone.
    pub fn sends_thrust_body(&self) -> bool {
        self.thrust_body
    }

    /// The group-2 message when the arm channel is on.
    fn arm_messages(&self, time_usec: u64, joint_targets: &[f64]) -> Vec<MavMessage> {
        if self.arm_channel {
            vec![self.arm_group(time_usec, joint_targets)]
        } else {
            Vec::new()
        }
    }

    /// Number of rotors.
    pub fn rotor_count(&self) -> usize {
        self.rotor_count
    }

    /// Whether group 1 (tilt servos) is sent.
    pub fn has_tilt(&self) -> bool {
        !self.tilts.is_empty()
    }

    fn check_command(&self, command: &ActuatorCommand, thrusts: bool) -> Result<(), SetpointError> {
        if command.direct_wrench_in_body.is_some() {
            return Err(SetpointError::Shape(
                "a direct wrench (the EE-only oracle) has no MAVLink form".to_owned(),
            ));
        }
        if thrusts && command.rotor_thrusts_n.len() != self.rotor_count {
            return Err(SetpointError::Shape(format!(
                "{} rotor thrusts for {} rotors",
                command.rotor_thrusts_n.len(),
                self.rotor_count
            )));
        }
        if command.joint_targets.len() != self.dof {
            return Err(SetpointError::Shape(format!(
                "{} joint targets for {} movable joints",
                command.joint_targets.len(),
                self.dof
            )));
        }
        if thrusts {
            for (i, &t) in command.rotor_thrusts_n.iter().enumerate() {
                check_finite(|| format!("rotor_thrusts_n[{i}]"), t)?;
            }
        }
        for (i, &q) in command.joint_targets.iter().enumerate() {
            check_finite(|| format!("joint_targets[{i}]"), q)?;
        }
        Ok(())
    }

    fn group(&self, time_usec: u64, group: u8, controls: [f32; 8]) -> MavMessage {
        MavMessage::SET_ACTUATOR_CONTROL_TARGET(SET_ACTUATOR_CONTROL_TARGET_DATA {
            time_usec,
            controls,
            group_mlx: group,
            target_system: self.target_system,
            target_component: self.target_component,
        })
    }

    fn arm_group(&self, time_usec: u64, joint_targets: &[f64]) -> MavMessage {
        let mut controls = [0f32; 8];
        for (c, ch) in controls.iter_mut().zip(&self.arm) {
            *c = ch.to_control(joint_targets[ch.dof]);
        }
        if let Some(g) = &self.gripper {
            let n = g.fingers.len().max(1) as f64;
            let mean: f64 = g
                .fingers
                .iter()
                .map(|&(dof, closed, open)| {
                    Channel {
                        dof,
                        lower: closed,
                        upper: open,
                    }
                    .to_control(joint_targets[dof])
                    .into()
                })
                .map(|c: f64| c / n)
                .sum();
            // MAVLink carries f32; the narrowing is the protocol's.
            #[allow(clippy::cast_possible_truncation)]
            let mean = mean as f32;
            controls[self.arm.len()] = mean;
        }
        self.group(time_usec, GROUP_ARM, controls)
    }

    /// The actuator-level messages of one tick, in sending order (group 2, group 1 if the
    /// vehicle tilts, group 0 last). `time_usec` is the flight stack's time of the command.
    pub fn actuator_messages(
        &self,
        time_usec: u64,
        command: &ActuatorCommand,
    ) -> Result<Vec<MavMessage>, SetpointError> {
        self.check_command(command, true)?;
        let mut out = vec![self.arm_group(time_usec, &command.joint_targets)];
        if self.has_tilt() {
            let mut controls = [0f32; 8];
            for (c, ch) in controls.iter_mut().zip(&self.tilts) {
                *c = ch.to_control(command.joint_targets[ch.dof]);
            }
            out.push(self.group(time_usec, GROUP_TILT, controls));
        }
        let mut controls = [0f32; 8];
        for (c, &t) in controls.iter_mut().zip(&command.rotor_thrusts_n) {
            // MAVLink carries f32; the narrowing is the protocol's.
            #[allow(clippy::cast_possible_truncation)]
            let u = self.curve.command(t) as f32;
            *c = u;
        }
        out.push(self.group(time_usec, GROUP_MOTORS, controls));
        Ok(out)
    }

    /// The attitude-level messages of one tick: group 2 (arm and gripper from
    /// `command.joint_targets`; its rotor thrusts are ignored), then SET_ATTITUDE_TARGET.
    /// `time_boot_ms` stamps the attitude target.
    pub fn attitude_messages(
        &self,
        time_usec: u64,
        command: &ActuatorCommand,
        setpoint: &AttitudeSetpoint,
    ) -> Result<Vec<MavMessage>, SetpointError> {
        self.check_command(command, false)?;
        let q = setpoint.world_from_body.as_ref().coords;
        for (i, name) in ["x", "y", "z", "w"].iter().enumerate() {
            check_finite(|| format!("world_from_body.{name}"), q[i])?;
        }
        for (i, name) in ["x", "y", "z"].iter().enumerate() {
            check_finite(
                || format!("force_in_body_n.{name}"),
                setpoint.force_in_body_n[i],
            )?;
            if let Some(r) = &setpoint.body_rates_radps {
                check_finite(|| format!("body_rates_radps.{name}"), r[i])?;
            }
        }
        let scale = self.rotor_count as f64 * self.thrust_max_n;
        if scale <= 0.0 {
            return Err(SetpointError::Shape(
                "attitude level needs rotors with a positive T_max".to_owned(),
            ));
        }
        let force_frd = frames::frd_from_flu(&setpoint.force_in_body_n) / scale;
        // MAVLink carries f32; the narrowing is the protocol's.
        #[allow(clippy::cast_possible_truncation)]
        let thrust_body = force_frd.map(|f| f.clamp(-1.0, 1.0) as f32);
        // Collective thrust: the z component's magnitude (all a vehicle whose rotors are
        // parallel can give, and what receivers that ignore thrust_body read).
        let thrust = (-thrust_body[2]).clamp(0.0, 1.0);
        let (rates, rate_mask) = match &setpoint.body_rates_radps {
            Some(r) => (frames::frd_from_flu(r), AttitudeTargetTypemask::empty()),
            None => (
                Vector3::zeros(),
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                    | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                    | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
            ),
        };
        // PX4 reads thrust_body only with THRUST_BODY_SET (else the collective `thrust`).
        let (type_mask, thrust_body) = if self.thrust_body {
            (
                rate_mask | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET,
                [thrust_body.x, thrust_body.y, thrust_body.z],
            )
        } else {
            (rate_mask, [0.0; 3])
        };
        let q = frames::quaternion_to_mavlink(&frames::ned_from_frd_attitude(
            &setpoint.world_from_body,
        ));
        // time_boot_ms wraps after 49 days; the protocol's field is 32 bits.
        #[allow(clippy::cast_possible_truncation)]
        let time_boot_ms = (time_usec / 1000) as u32;
        #[allow(clippy::cast_possible_truncation)]
        let attitude = MavMessage::SET_ATTITUDE_TARGET(SET_ATTITUDE_TARGET_DATA {
            time_boot_ms,
            q,
            body_roll_rate: rates.x as f32,
            body_pitch_rate: rates.y as f32,
            body_yaw_rate: rates.z as f32,
            thrust,
            target_system: self.target_system,
            target_component: self.target_component,
            type_mask,
            thrust_body,
        });
        let mut out = self.arm_messages(time_usec, &command.joint_targets);
        out.push(attitude);
        Ok(out)
    }

    /// The rate-level messages of one tick: group 2 (when the arm channel is on), then
    /// SET_ATTITUDE_TARGET with ATTITUDE_IGNORE, the body rates of `setpoint` (FRD) and its
    /// body force as at the attitude level (`thrust_body` or the collective thrust); q is the
    /// identity and not read.
    pub fn rate_messages(
        &self,
        time_usec: u64,
        command: &ActuatorCommand,
        setpoint: &RateSetpoint,
    ) -> Result<Vec<MavMessage>, SetpointError> {
        let attitude = AttitudeSetpoint {
            world_from_body: nalgebra::UnitQuaternion::identity(),
            force_in_body_n: setpoint.force_in_body_n,
            body_rates_radps: Some(setpoint.body_rates_radps),
        };
        let mut out = self.attitude_messages(time_usec, command, &attitude)?;
        if let Some(MavMessage::SET_ATTITUDE_TARGET(a)) = out.last_mut() {
            a.q = [1.0, 0.0, 0.0, 0.0];
            a.type_mask |= AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE;
        }
        Ok(out)
    }

    /// The position-level messages of one tick: group 2 (arm and gripper from
    /// `command.joint_targets`, when the arm channel is on; its rotor thrusts are ignored),
    /// then SET_POSITION_TARGET_LOCAL_NED with the position and heading of `setpoint` and
    /// every other field ignored by the type mask (PX4 flies to the point within its
    /// MPC_* limits).
    pub fn position_messages(
        &self,
        time_usec: u64,
        command: &ActuatorCommand,
        setpoint: &PositionSetpoint,
    ) -> Result<Vec<MavMessage>, SetpointError> {
        self.check_command(command, false)?;
        for (i, name) in ["x", "y", "z"].iter().enumerate() {
            check_finite(
                || format!("position_in_world_m.{name}"),
                setpoint.position_in_world_m[i],
            )?;
        }
        check_finite(|| "yaw_rad".to_owned(), setpoint.yaw_rad)?;
        let p = frames::ned_from_world(&setpoint.position_in_world_m);
        let type_mask = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VX_IGNORE
            | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VY_IGNORE
            | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AX_IGNORE
            | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AY_IGNORE
            | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE;
        // time_boot_ms wraps after 49 days; the protocol's fields are 32 bits and f32.
        #[allow(clippy::cast_possible_truncation)]
        let position =
            MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
                time_boot_ms: (time_usec / 1000) as u32,
                x: p.x as f32,
                y: p.y as f32,
                z: p.z as f32,
                yaw: frames::ned_yaw_from_world_yaw(setpoint.yaw_rad) as f32,
                type_mask,
                target_system: self.target_system,
                target_component: self.target_component,
                coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
                ..SET_POSITION_TARGET_LOCAL_NED_DATA::default()
            });
        let mut out = self.arm_messages(time_usec, &command.joint_targets);
        out.push(position);
        Ok(out)
    }

    /// Decodes one SET_ACTUATOR_CONTROL_TARGET (the receiver's side): group 0 → rotor thrusts
    /// through the thrust curve; groups 1 and 2 → their joints' targets in `joint_targets`
    /// (configuration order), which is left unchanged when the message is refused.
    pub fn decode_actuator(
        &self,
        data: &SET_ACTUATOR_CONTROL_TARGET_DATA,
        joint_targets: &mut [f64],
    ) -> Result<ActuatorUpdate, SetpointError> {
        let refuse = |why: String| Err(SetpointError::Refused(why));
        let group = data.group_mlx;
        if let Some(c) = data.controls.iter().find(|c| !c.is_finite()) {
            return refuse(format!("group {group}: control {c} not finite"));
        }
        let in_unit = |c: &f32| (-1.0 - RANGE_SLACK..=1.0 + RANGE_SLACK).contains(c);
        let mut set = |ch: &Channel, c: f32| {
            if let Some(q) = joint_targets.get_mut(ch.dof) {
                *q = ch.position_of(c);
            }
        };
        match group {
            GROUP_MOTORS => {
                let controls = &data.controls[..self.rotor_count.min(CONTROLS_PER_GROUP)];
                if let Some(u) = controls
                    .iter()
                    .find(|&&u| !(-RANGE_SLACK..=1.0 + RANGE_SLACK).contains(&u))
                {
                    return refuse(format!("group 0: motor command {u} outside [0, 1]"));
                }
                Ok(ActuatorUpdate::Motors(
                    controls
                        .iter()
                        .map(|&u| self.curve.thrust_n(f64::from(u).clamp(0.0, 1.0)))
                        .collect(),
                ))
            }
            GROUP_TILT if self.has_tilt() => {
                let controls = &data.controls[..self.tilts.len()];
                if let Some(c) = controls.iter().find(|c| !in_unit(c)) {
                    return refuse(format!("group 1: control {c} outside [-1, 1]"));
                }
                for (ch, &c) in self.tilts.iter().zip(controls) {
                    set(ch, c);
                }
                Ok(ActuatorUpdate::Joints)
            }
            GROUP_ARM => {
                let used = self.arm.len() + usize::from(self.gripper.is_some());
                let controls = &data.controls[..used];
                if let Some(c) = controls.iter().find(|c| !in_unit(c)) {
                    return refuse(format!("group 2: control {c} outside [-1, 1]"));
                }
                for (ch, &c) in self.arm.iter().zip(controls) {
                    set(ch, c);
                }
                if let Some(g) = &self.gripper {
                    let c = controls[self.arm.len()];
                    for &(dof, closed, open) in &g.fingers {
                        let finger = Channel {
                            dof,
                            lower: closed,
                            upper: open,
                        };
                        set(&finger, c);
                    }
                }
                Ok(ActuatorUpdate::Joints)
            }
            g => refuse(format!("group {g}: not used by this vehicle")),
        }
    }

    /// Decodes one SET_ATTITUDE_TARGET (the receiver's side): the attitude, the body force
    /// (`thrust_body` × rotor count × T_max; without `thrust_body`, the collective `thrust`
    /// along body up, as PX4 takes it for a multicopter) and the body rates (ignored ones 0).
    pub fn decode_attitude(
        &self,
        data: &SET_ATTITUDE_TARGET_DATA,
    ) -> Result<AttitudeSetpoint, SetpointError> {
        let refuse = |why: String| Err(SetpointError::Refused(why));
        if data
            .type_mask
            .contains(AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE)
        {
            return refuse("attitude ignored by type_mask: an attitude is needed".to_owned());
        }
        let Some(ned_from_frd) = frames::quaternion_from_mavlink(data.q) else {
            return refuse(format!("q {:?} is not a unit quaternion", data.q));
        };
        let mut thrust: Vector3<f64> =
            Vector3::from_iterator(data.thrust_body.iter().map(|&t| f64::from(t)));
        if thrust == Vector3::zeros() && data.thrust != 0.0 {
            thrust = Vector3::new(0.0, 0.0, -f64::from(data.thrust));
        }
        if thrust
            .iter()
            .any(|t| !t.is_finite() || t.abs() > 1.0 + f64::from(RANGE_SLACK))
        {
            return refuse(format!(
                "thrust_body {:?} (thrust {}) outside [-1, 1]",
                data.thrust_body, data.thrust
            ));
        }
        let mask = data.type_mask;
        let rate = |v: f32, ignore: AttitudeTargetTypemask| {
            if mask.contains(ignore) {
                0.0
            } else {
                f64::from(v)
            }
        };
        let rates_frd = Vector3::new(
            rate(
                data.body_roll_rate,
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE,
            ),
            rate(
                data.body_pitch_rate,
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE,
            ),
            rate(
                data.body_yaw_rate,
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
            ),
        );
        if rates_frd.iter().any(|r| !r.is_finite()) {
            return refuse(format!("body rates {rates_frd:?} not finite"));
        }
        let scale = self.rotor_count as f64 * self.thrust_max_n;
        Ok(AttitudeSetpoint {
            world_from_body: frames::world_from_body_attitude(&ned_from_frd),
            force_in_body_n: frames::flu_from_frd(&thrust.map(|t| t.clamp(-1.0, 1.0))) * scale,
            body_rates_radps: Some(frames::flu_from_frd(&rates_frd)),
        })
    }
}
