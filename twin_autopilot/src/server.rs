//! The autopilot's loop: receive frames, answer commands, run the commander, step the twin
//! (lockstep on setpoints, or on the wall clock), send telemetry.

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    COMMAND_ACK_DATA, COMMAND_LONG_DATA, MavCmd, MavMessage, MavModeFlag, MavResult, MavSeverity,
    MavType, STATUSTEXT_DATA,
};
use mavlink::{MavHeader, Message};
use nalgebra::{Isometry3, Vector3};
use platform::{Actuation, ActuatorCommand, Measurement, Vehicle};

use crate::control::{Control, hold_target};
use crate::modes::{Commander, FORCE_DISARM_MAGIC, FlightMode, Refusal, Transition, VehicleFacts};
use crate::telemetry::{self, Landed};
use crate::transport::{Endpoint, Incoming, Transport};
use crate::wire::{Frame, LinkCounters, Signing, Wire};
use sim_twin::ipc::Mode;
use sim_twin::{Twin, TwinConfig, TwinError};
use firmware_bridge::{ActuatorUpdate, AttitudeSetpoint, SetpointCodec};

/// The autopilot's MAVLink system id.
pub const SYSTEM_ID: u8 = 1;
/// The autopilot's MAVLink component id (MAV_COMP_ID_AUTOPILOT1).
pub const COMPONENT_ID: u8 = 1;
/// Descent rate of AUTO.LAND, m/s.
pub const LAND_SPEED_MPS: f64 = 0.5;
/// Above its resting height by more than this, a running vehicle is in the air, m.
pub const IN_AIR_MARGIN_M: f64 = 0.1;
/// Landed: within this of the resting height, m …
pub const LANDED_MARGIN_M: f64 = 0.05;
/// … slower than this, m/s …
pub const LANDED_SPEED_MPS: f64 = 0.2;
/// … for this long (twin time), s.
pub const LANDED_FOR_S: f64 = 0.5;
/// AUTO.LAND: a vehicle that stays still this far above its descending target is held up by
/// the ground (or what stands on it) and counts as landed, m.
pub const LAND_STALL_M: f64 = 0.1;
/// Per-step telemetry while the twin stands still, wall clock.
pub const IDLE_TELEMETRY_PERIOD: Duration = Duration::from_millis(100);

/// How the autopilot runs.
#[derive(Debug, Clone, PartialEq)]
pub struct AutopilotConfig {
    /// UDP or serial.
    pub endpoint: Endpoint,
    /// Lockstep (steps on setpoints) or realtime (wall clock).
    pub mode: Mode,
    /// Offboard setpoints older than this are lost (and arming/offboard refused). Default 500 ms.
    pub offboard_timeout: Duration,
    /// Failsafe hold before landing, s (twin time). Default 5.
    pub failsafe_hold_s: f64,
    /// Message signing.
    pub signing: Option<Signing>,
}

impl AutopilotConfig {
    /// Defaults for `endpoint`.
    pub fn new(endpoint: Endpoint, mode: Mode) -> Self {
        Self {
            endpoint,
            mode,
            offboard_timeout: Duration::from_millis(500),
            failsafe_hold_s: 5.0,
            signing: None,
        }
    }
}

/// The autopilot cannot start or continue.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AutopilotError {
    /// The twin cannot be built.
    #[error(transparent)]
    Twin(#[from] TwinError),
    /// The vehicle cannot be flown by this autopilot.
    #[error("{0}")]
    Vehicle(String),
    /// The endpoint cannot be opened or failed.
    #[error("{0}")]
    Link(String),
}

/// What the autopilot reports as it runs (the CLI prints these on stderr).
#[derive(Debug, Clone, PartialEq)]
pub enum AutopilotEvent {
    /// Serving.
    Started {
        /// Vehicle id.
        vehicle: String,
        /// Where (the bound address for UDP).
        endpoint: String,
        /// Lockstep or realtime.
        mode: Mode,
        /// Control rate, Hz.
        rate_hz: f64,
        /// Resting height of the base origin on the ground, m.
        rest_z_m: f64,
        /// Signing: off, on, required.
        signing: &'static str,
    },
    /// A new UDP peer.
    Peer {
        /// Its address.
        addr: String,
        /// Its MAVLink system and component.
        system: u32,
        /// Component.
        component: u8,
    },
    /// Armed, disarmed, mode change, failsafe step.
    Transition {
        /// Twin time, s.
        at_s: f64,
        /// What.
        transition: Transition,
        /// Base position, world, m.
        position_m: Vector3<f64>,
    },
    /// A command was refused.
    Refused {
        /// Twin time, s.
        at_s: f64,
        /// The command.
        command: String,
        /// Why.
        reason: String,
    },
    /// The twin could not step: the vehicle was reset.
    TwinFailed {
        /// Twin time, s.
        at_s: f64,
        /// The twin's error.
        error: String,
    },
    /// Stopped.
    Stopped {
        /// Steps simulated.
        steps: u64,
        /// The link's counters.
        counters: LinkCounters,
    },
}

impl fmt::Display for AutopilotEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Started {
                vehicle,
                endpoint,
                mode,
                rate_hz,
                rest_z_m,
                signing,
            } => write!(
                f,
                "serving {vehicle} as MAVLink system {SYSTEM_ID} component {COMPONENT_ID} on {endpoint} ({}, {rate_hz} Hz, signing {signing}); resting height {rest_z_m:.3} m",
                mode.name()
            ),
            Self::Peer {
                addr,
                system,
                component,
            } => write!(f, "peer {addr} (system {system} component {component})"),
            Self::Transition {
                at_s,
                transition,
                position_m: p,
            } => write!(
                f,
                "t = {at_s:.3} s: {transition} at ({:.3}, {:.3}, {:.3}) m",
                p.x, p.y, p.z
            ),
            Self::Refused {
                at_s,
                command,
                reason,
            } => write!(f, "t = {at_s:.3} s: {command} refused: {reason}"),
            Self::TwinFailed { at_s, error } => {
                write!(
                    f,
                    "t = {at_s:.3} s: the twin failed ({error}); disarmed and reset"
                )
            }
            Self::Stopped { steps, counters } => {
                write!(f, "stopped after {steps} steps; link: {counters}")
            }
        }
    }
}

/// The latest offboard setpoint.
#[derive(Debug, Clone, PartialEq)]
enum Offboard {
    None,
    /// Rotor thrusts, N.
    Motors(Vec<f64>),
    Attitude(AttitudeSetpoint),
}

/// A slow stream's interval and next due time.
#[derive(Debug, Clone, Copy)]
struct Stream {
    id: u32,
    default: Duration,
    interval: Option<Duration>,
    next: Instant,
}

const HEARTBEAT_ID: u32 = 0;
const SYS_STATUS_ID: u32 = 1;
const ATTITUDE_ID: u32 = 30;
const GLOBAL_POSITION_INT_ID: u32 = 33;
const EXTENDED_SYS_STATE_ID: u32 = 245;
const HOME_POSITION_ID: u32 = 242;
const AUTOPILOT_VERSION_ID: u32 = 148;
/// The per-step messages (sent every twin step, not on an interval).
const PER_STEP_IDS: [u32; 6] = [350, 375, 105, 31, 32, 331];

/// The twin as a PX4-style autopilot (see the module documentation for the contract).
pub struct Autopilot {
    twin: Twin,
    seed: u64,
    config: AutopilotConfig,
    mav_type: MavType,
    /// The setpoints' layout on the wire (the bridge's codec, decoding).
    decoder: SetpointCodec,
    control: Control,
    commander: Commander,
    wire: Wire,
    transport: Transport,
    dt_s: f64,
    rest_z_m: f64,
    joint_targets: Vec<f64>,
    offboard: Offboard,
    last_setpoint: Option<Instant>,
    internal_target: Option<Isometry3<f64>>,
    landed_since_s: Option<f64>,
    previous_velocity: Vector3<f64>,
    specific_force: Vector3<f64>,
    /// Wall clock of the next step while the twin runs on the clock.
    next_step: Option<Instant>,
    /// Realtime: the clock has started (first arming).
    clock_started: bool,
    /// Wall clock of the next per-step telemetry while the twin stands still.
    next_idle_telemetry: Instant,
    streams: Vec<Stream>,
    steps: u64,
    out: Vec<u8>,
}

impl fmt::Debug for Autopilot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Autopilot")
            .field("config", &self.config)
            .field("commander", &self.commander)
            .field("transport", &self.transport)
            .finish_non_exhaustive()
    }
}

/// The height of the base origin when the vehicle rests on the ground: dropped in an empty
/// world with its rotors off for 3 s.
pub fn resting_height_m(vehicle: &Vehicle, config: &TwinConfig) -> Result<f64, TwinError> {
    let mut twin = Twin::new(
        vehicle.clone(),
        TwinConfig {
            task: None,
            ..config.clone()
        },
    )?;
    let command = ActuatorCommand {
        rotor_thrusts_n: vec![0.0; vehicle.rotors.len()],
        joint_targets: vehicle.initial_configuration(),
        direct_wrench_in_body: None,
    };
    let steps = (3.0 * config.control_rate_hz).ceil() as usize;
    for _ in 0..steps {
        twin.step(&command)?;
    }
    Ok(twin.truth().base.position_in_world_m.z)
}

impl Autopilot {
    /// Builds the twin and opens the endpoint.
    pub fn new(
        vehicle: Vehicle,
        twin_config: TwinConfig,
        config: AutopilotConfig,
    ) -> Result<Self, AutopilotError> {
        if vehicle.rotors.is_empty() || vehicle.actuation == Actuation::FloatingEndEffector {
            return Err(AutopilotError::Vehicle(format!(
                "{}: no rotors, nothing a MAVLink autopilot could fly (use a multirotor)",
                vehicle.id
            )));
        }
        // The setpoints' layout (at most 8 rotors, tilts and arm controls a group).
        let decoder = SetpointCodec::new(&vehicle, SYSTEM_ID, COMPONENT_ID)
            .map_err(|e| AutopilotError::Vehicle(format!("{}: {e}", vehicle.id)))?;
        let mav_type = match vehicle.rotors.len() {
            4 => MavType::MAV_TYPE_QUADROTOR,
            8 => MavType::MAV_TYPE_OCTOROTOR,
            _ => MavType::MAV_TYPE_HEXAROTOR,
        };
        let dt_s = twin_config.control_dt_s();
        let rest_z_m = resting_height_m(&vehicle, &twin_config)?;
        let control = Control::new(&vehicle, dt_s).map_err(AutopilotError::Vehicle)?;
        let seed = twin_config.seed;
        let joint_targets = vehicle.initial_configuration();
        let twin = Twin::new(vehicle, twin_config)?;
        let transport = Transport::open(&config.endpoint).map_err(AutopilotError::Link)?;
        let now = Instant::now();
        let stream = |id, hz: f64| Stream {
            id,
            default: Duration::from_secs_f64(1.0 / hz),
            interval: Some(Duration::from_secs_f64(1.0 / hz)),
            next: now,
        };
        let streams = vec![
            stream(HEARTBEAT_ID, 1.0),
            stream(SYS_STATUS_ID, 1.0),
            stream(EXTENDED_SYS_STATE_ID, 1.0),
            stream(ATTITUDE_ID, 50.0),
            stream(GLOBAL_POSITION_INT_ID, 10.0),
        ];
        let previous_velocity = twin.truth().base.velocity_in_world_mps;
        Ok(Self {
            specific_force: telemetry::specific_force(twin.truth(), &previous_velocity, dt_s),
            previous_velocity,
            twin,
            seed,
            mav_type,
            decoder,
            control,
            commander: Commander::new(config.failsafe_hold_s),
            wire: Wire::new(SYSTEM_ID, COMPONENT_ID, config.signing.as_ref()),
            transport,
            dt_s,
            rest_z_m,
            joint_targets,
            offboard: Offboard::None,
            last_setpoint: None,
            internal_target: None,
            landed_since_s: None,
            next_step: None,
            clock_started: false,
            next_idle_telemetry: now,
            streams,
            steps: 0,
            out: Vec::with_capacity(4096),
            config,
        })
    }

    /// The twin.
    pub fn twin(&self) -> &Twin {
        &self.twin
    }

    /// The link's counters.
    pub fn counters(&self) -> LinkCounters {
        self.wire.counters()
    }

    /// The local UDP address (e.g. when bound to port 0).
    pub fn local_addr(&self) -> Option<std::net::SocketAddr> {
        self.transport.local_addr()
    }

    /// Serves until `stop` is set; `on_event` hears the start, peers, every transition and
    /// refusal, and the stop.
    pub fn run(
        &mut self,
        stop: &AtomicBool,
        mut on_event: impl FnMut(&AutopilotEvent),
    ) -> Result<LinkCounters, AutopilotError> {
        on_event(&AutopilotEvent::Started {
            vehicle: self.twin.vehicle().id.clone(),
            endpoint: match self.transport.local_addr() {
                Some(a) => format!("udp:{a}"),
                None => self.config.endpoint.to_string(),
            },
            mode: self.config.mode,
            rate_hz: 1.0 / self.dt_s,
            rest_z_m: self.rest_z_m,
            signing: match &self.config.signing {
                None => "off",
                Some(s) if s.require => "required",
                Some(_) => "on",
            },
        });
        let mut buf = vec![0u8; 65_536];
        let mut received = Vec::new();
        while !stop.load(Ordering::Relaxed) {
            let wait = self.until_due();
            let mut first = true;
            // Drain what is there (the first read may wait).
            for _ in 0..64 {
                let got = self
                    .transport
                    .recv(&mut buf, if first { wait } else { Duration::ZERO })
                    .map_err(|e| {
                        AutopilotError::Link(format!("the link failed while receiving: {e}"))
                    })?;
                first = false;
                let Some(incoming) = got else { break };
                received.clear();
                let new_peer = match incoming {
                    Incoming::Datagram { len, from } => {
                        self.wire
                            .datagram(buf.get(..len).unwrap_or(&[]), &mut received);
                        // Only a sender of an accepted frame is a peer (with signing required,
                        // an unsigned sender gets nothing).
                        (!received.is_empty() && self.transport.note_peer(from)).then_some(from)
                    }
                    Incoming::Stream(n) => {
                        self.wire.stream(buf.get(..n).unwrap_or(&[]), &mut received);
                        None
                    }
                };
                if let (Some(addr), Some(r)) = (new_peer, received.first()) {
                    on_event(&AutopilotEvent::Peer {
                        addr: addr.to_string(),
                        system: r.header.system_id,
                        component: r.header.component_id,
                    });
                }
                for r in std::mem::take(&mut received) {
                    self.handle(&r, &mut on_event);
                }
            }
            self.tick(&mut on_event);
        }
        let counters = self.wire.counters();
        on_event(&AutopilotEvent::Stopped {
            steps: self.steps,
            counters,
        });
        Ok(counters)
    }

    /// How long the loop may wait for input before something is due.
    fn until_due(&self) -> Duration {
        let now = Instant::now();
        let mut due = now + Duration::from_millis(5);
        match self.next_step {
            Some(t) => due = due.min(t),
            None => due = due.min(self.next_idle_telemetry),
        }
        for s in &self.streams {
            if s.interval.is_some() {
                due = due.min(s.next);
            }
        }
        due.saturating_duration_since(now)
    }

    fn streaming(&self) -> bool {
        self.last_setpoint
            .is_some_and(|t| t.elapsed() <= self.config.offboard_timeout)
    }

    fn truth(&self) -> &Measurement {
        self.twin.truth()
    }

    /// Whether the twin advances on the wall clock now.
    fn runs_on_clock(&self) -> bool {
        match self.config.mode {
            Mode::Realtime => self.clock_started,
            Mode::Lockstep => self.commander.armed() && self.commander.mode().is_internal(),
        }
    }

    fn facts(&self) -> VehicleFacts {
        let base = &self.truth().base;
        VehicleFacts {
            setpoints_streaming: self.streaming(),
            speed_mps: base.velocity_in_world_mps.norm(),
            in_air: self.runs_on_clock()
                && base.position_in_world_m.z > self.rest_z_m + IN_AIR_MARGIN_M,
        }
    }

    fn landed_state(&self) -> Landed {
        let z = self.truth().base.position_in_world_m.z;
        if !self.commander.armed() {
            Landed::OnGround
        } else if self.commander.mode() == FlightMode::AutoLand {
            Landed::Landing
        } else if z > self.rest_z_m + IN_AIR_MARGIN_M {
            Landed::InAir
        } else {
            Landed::OnGround
        }
    }

    /// Periodic work: the commander, clock steps, telemetry streams.
    fn tick(&mut self, on_event: &mut impl FnMut(&AutopilotEvent)) {
        let landed = self
            .landed_since_s
            .is_some_and(|t| self.twin.time_s() - t >= LANDED_FOR_S);
        if let Some(t) = self
            .commander
            .update(self.twin.time_s(), self.streaming(), landed)
        {
            self.transition(t, on_event);
        }
        let now = Instant::now();
        if self.runs_on_clock() {
            let next = *self.next_step.get_or_insert(now);
            if now >= next {
                let period = Duration::from_secs_f64(self.dt_s);
                let after = next + period;
                self.next_step = Some(if after < now { now + period } else { after });
                let command = self.clock_command();
                self.step(&command, on_event);
            }
        } else {
            self.next_step = None;
            if now >= self.next_idle_telemetry {
                let after = self.next_idle_telemetry + IDLE_TELEMETRY_PERIOD;
                self.next_idle_telemetry = if after < now {
                    now + IDLE_TELEMETRY_PERIOD
                } else {
                    after
                };
                self.send_per_step();
            }
        }
        self.send_streams(now);
    }

    /// Logs a transition and follows it (internal-mode targets, the realtime clock).
    fn transition(&mut self, t: Transition, on_event: &mut impl FnMut(&AutopilotEvent)) {
        match &t {
            Transition::Armed => {
                self.clock_started |= self.config.mode == Mode::Realtime;
                self.internal_target = None;
            }
            Transition::Disarmed(_) => {
                self.internal_target = None;
                self.landed_since_s = None;
            }
            Transition::Mode { .. } => {
                self.internal_target = None;
                self.landed_since_s = None;
            }
        }
        on_event(&AutopilotEvent::Transition {
            at_s: self.twin.time_s(),
            transition: t,
            position_m: self.truth().base.position_in_world_m,
        });
        // The new state at once, as PX4 does.
        let hb = telemetry::heartbeat(self.mav_type, &self.commander);
        self.send(&[hb]);
    }

    /// The command of a clock step: offboard's latest setpoint, the internal controller, or
    /// rotors off when disarmed.
    fn clock_command(&mut self) -> ActuatorCommand {
        if !self.commander.armed() {
            return self.idle_command();
        }
        match self.commander.mode() {
            FlightMode::Offboard => self.offboard_command(),
            mode => self.internal_command(mode),
        }
    }

    fn idle_command(&self) -> ActuatorCommand {
        ActuatorCommand {
            rotor_thrusts_n: vec![0.0; self.twin.vehicle().rotors.len()],
            joint_targets: self.joint_targets.clone(),
            direct_wrench_in_body: None,
        }
    }

    fn offboard_command(&mut self) -> ActuatorCommand {
        match &self.offboard {
            Offboard::None => self.idle_command(),
            Offboard::Motors(thrusts) => ActuatorCommand {
                rotor_thrusts_n: thrusts.clone(),
                joint_targets: self.joint_targets.clone(),
                direct_wrench_in_body: None,
            },
            Offboard::Attitude(sp) => {
                let sp = *sp;
                self.control
                    .attitude(self.twin.truth(), &sp, &self.joint_targets)
            }
        }
    }

    fn internal_command(&mut self, mode: FlightMode) -> ActuatorCommand {
        let m = self.twin.truth().clone();
        let target = match self.internal_target {
            Some(t) => t,
            None => {
                self.control.reset(&m);
                hold_target(&m)
            }
        };
        let mut target = target;
        if mode == FlightMode::AutoLand {
            // Down to the resting height, not into the ground: a controller pushing into the
            // ground winds up and tips an under-actuated vehicle over.
            let floor = self.rest_z_m;
            target.translation.z = (target.translation.z - LAND_SPEED_MPS * self.dt_s).max(floor);
            let z = m.base.position_in_world_m.z;
            let still = m.base.velocity_in_world_mps.norm() < LANDED_SPEED_MPS;
            // On the ground: at the resting height, or held up (by an arm or an object below)
            // while the target is well below, as PX4's land detector.
            let held_up = target.translation.z < z - LAND_STALL_M;
            if (z < self.rest_z_m + LANDED_MARGIN_M || held_up) && still {
                self.landed_since_s.get_or_insert(m.time_s);
            } else {
                self.landed_since_s = None;
            }
        }
        self.internal_target = Some(target);
        self.control.hold(&m, &target, &self.joint_targets)
    }

    /// One twin step, then its telemetry. A failed step disarms and resets the twin.
    fn step(&mut self, command: &ActuatorCommand, on_event: &mut impl FnMut(&AutopilotEvent)) {
        self.previous_velocity = self.truth().base.velocity_in_world_mps;
        match self.twin.step(command) {
            Ok(_) => {
                self.steps += 1;
                // Idle telemetry resumes a period after the last step.
                self.next_idle_telemetry = Instant::now() + IDLE_TELEMETRY_PERIOD;
                self.specific_force =
                    telemetry::specific_force(self.truth(), &self.previous_velocity, self.dt_s);
                self.send_per_step();
            }
            Err(e) => {
                on_event(&AutopilotEvent::TwinFailed {
                    at_s: self.twin.time_s(),
                    error: e.to_string(),
                });
                let facts = self.facts();
                if let Ok(Some(t)) = self.commander.disarm(&facts, true) {
                    self.transition(t, on_event);
                }
                if self.twin.reset(self.seed).is_ok() {
                    self.joint_targets = self.twin.vehicle().initial_configuration();
                }
                self.clock_started = false;
            }
        }
    }

    fn send(&mut self, messages: &[MavMessage]) {
        self.out.clear();
        for m in messages {
            self.wire.encode(m, &mut self.out);
        }
        let out = std::mem::take(&mut self.out);
        self.transport.send(&out);
        self.out = out;
    }

    fn send_per_step(&mut self) {
        if !self.transport.has_peers() {
            return;
        }
        let [joints, actuators, imu, attitude, position, odometry] =
            telemetry::per_step(self.twin.truth(), &self.specific_force);
        // The task's state (SITL) before the ODOMETRY that closes the tick.
        let task = self
            .twin
            .task_snapshot()
            .and_then(|s| telemetry::task_array(self.twin.truth(), &s));
        let msgs: Vec<MavMessage> = [joints, actuators, imu, attitude, position]
            .into_iter()
            .chain(task)
            .chain([odometry])
            .collect();
        self.send(&msgs);
    }

    fn send_streams(&mut self, now: Instant) {
        let mut due = Vec::new();
        for s in &mut self.streams {
            if let Some(interval) = s.interval
                && now >= s.next
            {
                let after = s.next + interval;
                s.next = if after < now { now + interval } else { after };
                due.push(s.id);
            }
        }
        if due.is_empty() || !self.transport.has_peers() {
            return;
        }
        let msgs: Vec<MavMessage> = due.iter().filter_map(|&id| self.message(id)).collect();
        self.send(&msgs);
    }

    /// A message this autopilot can produce on request.
    fn message(&self, id: u32) -> Option<MavMessage> {
        let m = self.truth();
        Some(match id {
            HEARTBEAT_ID => telemetry::heartbeat(self.mav_type, &self.commander),
            SYS_STATUS_ID => telemetry::sys_status(&self.wire.counters()),
            EXTENDED_SYS_STATE_ID => telemetry::extended_sys_state(self.landed_state()),
            ATTITUDE_ID => telemetry::attitude(m),
            GLOBAL_POSITION_INT_ID => telemetry::global_position_int(m),
            HOME_POSITION_ID => telemetry::home_position(m),
            AUTOPILOT_VERSION_ID => telemetry::autopilot_version(),
            id => {
                let per_step = telemetry::per_step(m, &self.specific_force);
                return per_step.into_iter().find(|msg| msg.message_id() == id);
            }
        })
    }

    /// One received message.
    fn handle(&mut self, r: &Frame, on_event: &mut impl FnMut(&AutopilotEvent)) {
        let for_us = |system: u8, component: u8| {
            (system == 0 || system == SYSTEM_ID) && (component == 0 || component == COMPONENT_ID)
        };
        match &r.message {
            MavMessage::HEARTBEAT(_) => {}
            MavMessage::COMMAND_LONG(c) => {
                if for_us(c.target_system, c.target_component) {
                    self.command(&r.header, c, on_event);
                } else {
                    self.wire.count_rejected_input();
                }
            }
            MavMessage::SET_ACTUATOR_CONTROL_TARGET(s) => {
                if !for_us(s.target_system, s.target_component) {
                    self.wire.count_rejected_input();
                    return;
                }
                let mut targets = self.joint_targets.clone();
                match self.decoder.decode_actuator(s, &mut targets) {
                    Ok(ActuatorUpdate::Joints) => self.joint_targets = targets,
                    Ok(ActuatorUpdate::Motors(thrusts)) => {
                        self.offboard = Offboard::Motors(thrusts);
                        self.setpoint_arrived(on_event);
                    }
                    Err(_) => self.wire.count_rejected_input(),
                }
            }
            MavMessage::SET_ATTITUDE_TARGET(s) => {
                if !for_us(s.target_system, s.target_component) {
                    self.wire.count_rejected_input();
                    return;
                }
                match self.decoder.decode_attitude(s) {
                    Ok(sp) => {
                        self.offboard = Offboard::Attitude(sp);
                        self.setpoint_arrived(on_event);
                    }
                    Err(_) => self.wire.count_rejected_input(),
                }
            }
            // Everything else in the common dialect is understood and ignored, as PX4 ignores
            // what it does not handle.
            _ => {}
        }
    }

    /// A tick's completing setpoint: refreshes the stream; in lockstep, armed and in
    /// offboard, steps the twin once.
    fn setpoint_arrived(&mut self, on_event: &mut impl FnMut(&AutopilotEvent)) {
        self.last_setpoint = Some(Instant::now());
        let offboard = self.commander.armed() && self.commander.mode() == FlightMode::Offboard;
        if self.config.mode == Mode::Lockstep && offboard && !self.runs_on_clock() {
            let command = self.offboard_command();
            self.step(&command, on_event);
        }
    }

    fn ack(&mut self, to: &MavHeader, command: MavCmd, result: MavResult) {
        let msg = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command,
            result,
            progress: 0,
            result_param2: 0,
            target_system: u8::try_from(to.system_id).unwrap_or(0),
            target_component: to.component_id,
        });
        self.send(&[msg]);
    }

    fn status_text(&mut self, severity: MavSeverity, text: &str) {
        let mut bytes = [0u8; 50];
        for (b, c) in bytes.iter_mut().zip(text.bytes()) {
            *b = c;
        }
        let msg = MavMessage::STATUSTEXT(STATUSTEXT_DATA {
            severity,
            text: bytes.into(),
            id: 0,
            chunk_seq: 0,
        });
        self.send(&[msg]);
    }

    fn refuse(
        &mut self,
        to: &MavHeader,
        command: MavCmd,
        refusal: &Refusal,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        let result = if refusal.temporary {
            MavResult::MAV_RESULT_TEMPORARILY_REJECTED
        } else {
            MavResult::MAV_RESULT_DENIED
        };
        self.ack(to, command, result);
        self.status_text(MavSeverity::MAV_SEVERITY_CRITICAL, &refusal.reason);
        on_event(&AutopilotEvent::Refused {
            at_s: self.twin.time_s(),
            command: format!("{command:?}"),
            reason: refusal.reason.clone(),
        });
    }

    fn outcome(
        &mut self,
        to: &MavHeader,
        command: MavCmd,
        outcome: Result<Option<Transition>, Refusal>,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        match outcome {
            Ok(t) => {
                self.ack(to, command, MavResult::MAV_RESULT_ACCEPTED);
                if let Some(t) = t {
                    self.transition(t, on_event);
                }
            }
            Err(refusal) => self.refuse(to, command, &refusal, on_event),
        }
    }

    /// A COMMAND_LONG for this autopilot: every one gets a COMMAND_ACK.
    fn command(
        &mut self,
        from: &MavHeader,
        c: &COMMAND_LONG_DATA,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        let facts = self.facts();
        match c.command {
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => {
                let outcome = if c.param1 == 1.0 {
                    self.commander.arm(&facts)
                } else if c.param1 == 0.0 {
                    self.commander
                        .disarm(&facts, c.param2 == FORCE_DISARM_MAGIC)
                } else {
                    Err(Refusal {
                        temporary: false,
                        reason: format!("Arm/disarm: param1 {} not 0 or 1", c.param1),
                    })
                };
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_DO_SET_MODE => {
                let custom = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits();
                let outcome =
                    if !(c.param1.is_finite() && (c.param1 as u32) & u32::from(custom) != 0) {
                        Err(Refusal {
                            temporary: false,
                            reason: "Set mode: param1 lacks CUSTOM_MODE_ENABLED".to_owned(),
                        })
                    } else {
                        match FlightMode::from_main_and_sub(c.param2 as u8, c.param3 as u8) {
                            Ok(mode) => self.commander.set_mode(mode, &facts),
                            Err(reason) => Err(Refusal {
                                temporary: false,
                                reason: format!("Set mode: {reason}"),
                            }),
                        }
                    };
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_NAV_LAND => {
                let outcome = if self.commander.armed() {
                    self.commander.set_mode(FlightMode::AutoLand, &facts)
                } else {
                    Err(Refusal {
                        temporary: false,
                        reason: "Land denied: not armed".to_owned(),
                    })
                };
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_REQUEST_MESSAGE => {
                let id = c.param1;
                let msg = (id.is_finite() && id >= 0.0)
                    .then(|| self.message(id as u32))
                    .flatten();
                match msg {
                    Some(msg) => {
                        self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED);
                        self.send(&[msg]);
                    }
                    None => self.refuse(
                        from,
                        c.command,
                        &Refusal {
                            temporary: false,
                            reason: format!("Request: message {id} not available"),
                        },
                        on_event,
                    ),
                }
            }
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => {
                let outcome = self.set_interval(c.param1, c.param2);
                match outcome {
                    Ok(()) => self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED),
                    Err(reason) => self.refuse(
                        from,
                        c.command,
                        &Refusal {
                            temporary: false,
                            reason,
                        },
                        on_event,
                    ),
                }
            }
            other => {
                self.ack(from, other, MavResult::MAV_RESULT_UNSUPPORTED);
            }
        }
    }

    /// MAV_CMD_SET_MESSAGE_INTERVAL: param1 message id, param2 interval µs (−1 off, 0 default).
    fn set_interval(&mut self, id: f32, interval_us: f32) -> Result<(), String> {
        if !(id.is_finite() && interval_us.is_finite()) {
            return Err("Interval: parameters not finite".to_owned());
        }
        let id = id as u32;
        if PER_STEP_IDS.contains(&id) {
            return Err(format!("Interval: message {id} is sent every step"));
        }
        let Some(stream) = self.streams.iter_mut().find(|s| s.id == id) else {
            return Err(format!("Interval: message {id} not streamed"));
        };
        stream.interval = if interval_us < 0.0 {
            None
        } else if interval_us == 0.0 {
            Some(stream.default)
        } else {
            // At most 1 kHz.
            Some(Duration::from_micros(interval_us.max(1000.0) as u64))
        };
        stream.next = Instant::now();
        Ok(())
    }
}
