//! Telemetry in: the autopilot's messages → a [`platform::Measurement`] in amstack's frames
//! plus the autopilot's own state (armed, mode, status, last heartbeat).
//!
//! Per-step telemetry arrives in the contract's order — DEBUG_FLOAT_ARRAY "joints",
//! ACTUATOR_OUTPUT_STATUS, HIGHRES_IMU, ATTITUDE_QUATERNION, LOCAL_POSITION_NED — and
//! ODOMETRY last, which closes the tick: [`Telemetry::apply`] returns the finished
//! measurement then. Each message updates the fields it carries; every conversion of PX4's
//! NED/FRD goes through [`crate::frames`]:
//!
//! ```text
//! p_world = world_from_ned(x, y, z)          v_world = world_from_ned(vx, vy, vz)
//! world_from_body = world_from_body_attitude(q_ned_frd)
//! ω_body(FLU) = flu_from_frd(rollspeed, pitchspeed, yawspeed)
//! world_from_ee = pose · base_from_ee(q_joints)        (the vehicle's forward kinematics)
//! ```
//!
//! Values that are not finite, or a quaternion far from unit length, are ignored (the
//! field keeps its previous value) and counted in [`Telemetry::rejected_values`].

use mavlink::dialects::common::{
    MavFrame, MavMessage, MavModeFlag, MavProtocolCapability, MavState,
};
use nalgebra::Vector3;
use platform::{Measurement, RotorReport, Vehicle};

use crate::frames;
use crate::task_array::TaskArray;

/// PX4's main modes (custom_mode bits 16–23).
pub mod px4_mode {
    /// MANUAL.
    pub const MANUAL: u8 = 1;
    /// ALTCTL.
    pub const ALTCTL: u8 = 2;
    /// POSCTL.
    pub const POSCTL: u8 = 3;
    /// AUTO (sub mode in bits 24–31).
    pub const AUTO: u8 = 4;
    /// ACRO.
    pub const ACRO: u8 = 5;
    /// OFFBOARD.
    pub const OFFBOARD: u8 = 6;
    /// STABILIZED.
    pub const STABILIZED: u8 = 7;
    /// AUTO sub mode TAKEOFF.
    pub const AUTO_TAKEOFF: u8 = 2;
    /// AUTO sub mode LOITER.
    pub const AUTO_LOITER: u8 = 3;
    /// AUTO sub mode MISSION.
    pub const AUTO_MISSION: u8 = 4;
    /// AUTO sub mode RTL.
    pub const AUTO_RTL: u8 = 5;
    /// AUTO sub mode LAND.
    pub const AUTO_LAND: u8 = 6;

    /// `custom_mode` of a main and sub mode: `main << 16 | sub << 24`.
    pub fn custom_mode(main: u8, sub: u8) -> u32 {
        (u32::from(main) << 16) | (u32::from(sub) << 24)
    }

    /// (main, sub) of a `custom_mode`.
    pub fn split(custom_mode: u32) -> (u8, u8) {
        (
            ((custom_mode >> 16) & 0xFF) as u8,
            ((custom_mode >> 24) & 0xFF) as u8,
        )
    }

    /// A readable name (`OFFBOARD`, `AUTO.LOITER`, `MODE(9.0)`).
    pub fn name(custom_mode: u32) -> String {
        match split(custom_mode) {
            (MANUAL, _) => "MANUAL".to_owned(),
            (ALTCTL, _) => "ALTCTL".to_owned(),
            (POSCTL, _) => "POSCTL".to_owned(),
            (AUTO, AUTO_TAKEOFF) => "AUTO.TAKEOFF".to_owned(),
            (AUTO, AUTO_LOITER) => "AUTO.LOITER".to_owned(),
            (AUTO, AUTO_MISSION) => "AUTO.MISSION".to_owned(),
            (AUTO, AUTO_RTL) => "AUTO.RTL".to_owned(),
            (AUTO, AUTO_LAND) => "AUTO.LAND".to_owned(),
            (AUTO, s) => format!("AUTO.{s}"),
            (ACRO, _) => "ACRO".to_owned(),
            (OFFBOARD, _) => "OFFBOARD".to_owned(),
            (STABILIZED, _) => "STABILIZED".to_owned(),
            (m, s) => format!("MODE({m}.{s})"),
        }
    }
}

/// What the autopilot says about itself.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AutopilotState {
    /// Heartbeats received from the autopilot.
    pub heartbeats: u64,
    /// Armed (base_mode has MAV_MODE_FLAG_SAFETY_ARMED).
    pub armed: bool,
    /// PX4 custom mode (`main << 16 | sub << 24`).
    pub custom_mode: u32,
    /// MAV_STATE of the last heartbeat (`MAV_STATE_ACTIVE`...), None before one.
    pub system_status: Option<String>,
    /// Battery voltage from SYS_STATUS, V (None if unknown).
    pub battery_voltage_v: Option<f64>,
    /// Landed state from EXTENDED_SYS_STATE (`MAV_LANDED_STATE_IN_AIR`...).
    pub landed_state: Option<String>,
    /// Last HIGHRES_IMU: specific force, body FLU, m/s².
    pub imu_accel_in_body_mps2: Option<Vector3<f64>>,
    /// Last HIGHRES_IMU: angular rate, body FLU, rad/s.
    pub imu_gyro_in_body_radps: Option<Vector3<f64>>,
    /// What the last AUTOPILOT_VERSION declared (None before one).
    pub version: Option<AutopilotVersion>,
}

/// `flight_custom_version` of amstack's twin autopilot (`amstack twin serve --mavlink`), where
/// a PX4 puts its git hash: how the bridge knows it talks to the twin, which stands in for
/// the arm's servo bus (`docs/mavlink.md`).
pub const TWIN_FLIGHT_CUSTOM_VERSION: [u8; 8] = *b"amstack\0";

/// The AUTOPILOT_VERSION capability bit of SET_ACTUATOR_CONTROL_TARGET: 1024, which MAVLink
/// defined as MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET and, since the message was retired,
/// lists as MAV_PROTOCOL_CAPABILITY_RESERVED3 (the mavlink crate's name). PX4 set it while it
/// accepted the message and no longer does; the twin's autopilot sets it with
/// `--allow-actuator-setpoints`.
pub const CAPABILITY_SET_ACTUATOR_TARGET: MavProtocolCapability =
    MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_RESERVED3;

/// What an autopilot declares in AUTOPILOT_VERSION.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutopilotVersion {
    /// MAV_PROTOCOL_CAPABILITY bits.
    pub capabilities: MavProtocolCapability,
    /// `flight_custom_version` (PX4: the first bytes of its git hash).
    pub flight_custom_version: [u8; 8],
}

impl AutopilotVersion {
    /// Whether it declares [`CAPABILITY_SET_ACTUATOR_TARGET`]: it takes
    /// SET_ACTUATOR_CONTROL_TARGET (current PX4 does not; the twin's autopilot with
    /// `--allow-actuator-setpoints` does).
    pub fn accepts_actuator_setpoints(&self) -> bool {
        self.capabilities.contains(CAPABILITY_SET_ACTUATOR_TARGET)
    }

    /// Whether the autopilot is amstack's twin ([`TWIN_FLIGHT_CUSTOM_VERSION`]).
    pub fn is_amstack_twin(&self) -> bool {
        self.flight_custom_version == TWIN_FLIGHT_CUSTOM_VERSION
    }
}

impl AutopilotState {
    /// The main mode is OFFBOARD.
    pub fn in_offboard(&self) -> bool {
        px4_mode::split(self.custom_mode).0 == px4_mode::OFFBOARD
    }

    /// The mode's name.
    pub fn mode_name(&self) -> String {
        px4_mode::name(self.custom_mode)
    }
}

/// The assembler of measurements from telemetry.
#[derive(Debug, Clone)]
pub struct Telemetry {
    vehicle: Vehicle,
    current: Measurement,
    /// The autopilot's state.
    pub autopilot: AutopilotState,
    /// Ticks closed by ODOMETRY.
    pub ticks: u64,
    /// The task state of the latest step, if the autopilot sends one (SITL).
    pub task: Option<TaskArray>,
    /// Values ignored because not finite (or a non-unit quaternion, or a joint array of the
    /// wrong name).
    pub rejected_values: u64,
}

fn vec3(x: f32, y: f32, z: f32) -> Option<Vector3<f64>> {
    let v = Vector3::new(f64::from(x), f64::from(y), f64::from(z));
    v.iter().all(|c| c.is_finite()).then_some(v)
}

impl Telemetry {
    /// An assembler for `vehicle` (joint count, rotor count, forward kinematics), starting
    /// from its initial configuration at the origin.
    pub fn new(vehicle: &Vehicle) -> Self {
        let q = vehicle.initial_configuration();
        let current = Measurement {
            joint_velocities: vec![0.0; q.len()],
            world_from_ee: vehicle.base_from_ee(&q),
            joint_positions: q,
            rotors: vec![RotorReport::default(); vehicle.rotors.len()],
            ..Measurement::default()
        };
        Self {
            vehicle: vehicle.clone(),
            current,
            autopilot: AutopilotState::default(),
            ticks: 0,
            task: None,
            rejected_values: 0,
        }
    }

    /// The measurement as assembled so far.
    pub fn current(&self) -> &Measurement {
        &self.current
    }

    fn reject(&mut self) {
        self.rejected_values += 1;
    }

    /// Takes one message from the autopilot; returns the finished measurement when it closes
    /// a tick (ODOMETRY).
    pub fn apply(&mut self, message: &MavMessage) -> Option<Measurement> {
        match message {
            MavMessage::HEARTBEAT(h) => {
                self.autopilot.heartbeats += 1;
                self.autopilot.armed = h
                    .base_mode
                    .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                self.autopilot.custom_mode = h.custom_mode;
                self.autopilot.system_status = Some(mav_state_name(h.system_status));
            }
            MavMessage::SYS_STATUS(s) => {
                self.autopilot.battery_voltage_v =
                    (s.voltage_battery != u16::MAX).then(|| f64::from(s.voltage_battery) / 1000.0);
            }
            MavMessage::AUTOPILOT_VERSION(v) => {
                self.autopilot.version = Some(AutopilotVersion {
                    capabilities: v.capabilities,
                    flight_custom_version: v.flight_custom_version,
                });
            }
            MavMessage::EXTENDED_SYS_STATE(s) => {
                self.autopilot.landed_state = Some(format!("{:?}", s.landed_state));
            }
            MavMessage::HIGHRES_IMU(m) => {
                let acc = vec3(m.xacc, m.yacc, m.zacc);
                let gyro = vec3(m.xgyro, m.ygyro, m.zgyro);
                match (acc, gyro) {
                    (Some(a), Some(g)) => {
                        self.autopilot.imu_accel_in_body_mps2 = Some(frames::flu_from_frd(&a));
                        self.autopilot.imu_gyro_in_body_radps = Some(frames::flu_from_frd(&g));
                    }
                    _ => self.reject(),
                }
            }
            MavMessage::ATTITUDE_QUATERNION(a) => {
                match (
                    frames::quaternion_from_mavlink([a.q1, a.q2, a.q3, a.q4]),
                    vec3(a.rollspeed, a.pitchspeed, a.yawspeed),
                ) {
                    (Some(q), Some(w)) => {
                        self.current.base.world_from_body = frames::world_from_body_attitude(&q);
                        self.current.base.angular_velocity_in_body_radps = frames::flu_from_frd(&w);
                    }
                    _ => self.reject(),
                }
            }
            MavMessage::LOCAL_POSITION_NED(p) => {
                match (vec3(p.x, p.y, p.z), vec3(p.vx, p.vy, p.vz)) {
                    (Some(pos), Some(vel)) => {
                        self.current.base.position_in_world_m = frames::world_from_ned(&pos);
                        self.current.base.velocity_in_world_mps = frames::world_from_ned(&vel);
                    }
                    _ => self.reject(),
                }
            }
            MavMessage::ACTUATOR_OUTPUT_STATUS(a) => {
                let n = (a.active as usize).min(self.current.rotors.len());
                for (i, r) in self.current.rotors.iter_mut().enumerate().take(n) {
                    let t = f64::from(a.actuator[i]);
                    if t.is_finite() {
                        r.realised_n = t;
                        r.applied_n = t;
                    }
                }
            }
            MavMessage::DEBUG_FLOAT_ARRAY(d) if TaskArray::is_task_array(d) => {
                match TaskArray::decode(d) {
                    Ok(t) => self.task = Some(t),
                    Err(_) => self.reject(),
                }
            }
            MavMessage::DEBUG_FLOAT_ARRAY(d) => self.joints(d),
            MavMessage::ODOMETRY(o) => return self.odometry(o),
            _ => {}
        }
        None
    }

    fn joints(&mut self, d: &mavlink::dialects::common::DEBUG_FLOAT_ARRAY_DATA) {
        let name = d.name.to_str().unwrap_or("");
        if name != "joints" || d.array_id != 1 {
            return;
        }
        let n = self.current.joint_positions.len();
        if 2 * n > d.data.len() {
            self.reject();
            return;
        }
        let values: Vec<f64> = d.data[..2 * n].iter().map(|&x| f64::from(x)).collect();
        if values.iter().any(|x| !x.is_finite()) {
            self.reject();
            return;
        }
        self.current.joint_positions.copy_from_slice(&values[..n]);
        self.current.joint_velocities.copy_from_slice(&values[n..]);
    }

    fn odometry(&mut self, o: &mavlink::dialects::common::ODOMETRY_DATA) -> Option<Measurement> {
        let q = frames::quaternion_from_mavlink(o.q);
        let (Some(pos), Some(vel), Some(rates), Some(q)) = (
            vec3(o.x, o.y, o.z),
            vec3(o.vx, o.vy, o.vz),
            vec3(o.rollspeed, o.pitchspeed, o.yawspeed),
            q,
        ) else {
            self.reject();
            return None;
        };
        if o.frame_id != MavFrame::MAV_FRAME_LOCAL_NED {
            // Positions in another frame cannot be placed in our world.
            self.reject();
            return None;
        }
        let base = &mut self.current.base;
        base.position_in_world_m = frames::world_from_ned(&pos);
        base.world_from_body = frames::world_from_body_attitude(&q);
        // The contract: vx/vy/vz are the NED world velocity. (MAVLink's ODOMETRY has no
        // velocity_frame field; its spec puts the twist in child_frame_id, BODY_FRD for PX4.
        // amstack's autopilot sends child_frame_id BODY_FRD and a world velocity, as the
        // contract in docs/mavlink.md says.)
        base.velocity_in_world_mps = frames::world_from_ned(&vel);
        base.angular_velocity_in_body_radps = frames::flu_from_frd(&rates);
        // time_usec is µs; f64 holds it exactly for 285 years.
        self.current.time_s = o.time_usec as f64 * 1e-6;
        self.current.world_from_ee =
            self.current.base.pose() * self.vehicle.base_from_ee(&self.current.joint_positions);
        self.ticks += 1;
        Some(self.current.clone())
    }
}

fn mav_state_name(s: MavState) -> String {
    format!("{s:?}")
}
