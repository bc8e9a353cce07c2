//! The autopilot's loop: receive frames, answer commands, run the commander, step the twin
//! (lockstep on setpoints, or on the wall clock), send telemetry. Commands (COMMAND_LONG and
//! COMMAND_INT) are in [`commands`], the parameter and mission protocols in [`protocols`],
//! where the internal controller flies (hold, takeoff, land, RTL, missions, offboard position)
//! in [`guidance`].

#![allow(
    deprecated,
    reason = "PX4 still serves the deprecated MISSION_ITEM, MISSION_REQUEST, MISSION_SET_CURRENT, frames and commands: so does the twin"
)]

mod commands;
mod guidance;
mod protocols;

use std::fmt;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use estimator::ImuSample;
use mavlink::dialects::common::{
    COMMAND_ACK_DATA, MavCmd, MavMessage, MavResult, MavSeverity, MavType, MissionState,
    STATUSTEXT_DATA,
};
use mavlink::{MavHeader, MavlinkVersion, Message};
use nalgebra::Vector3;
use platform::{Actuation, ActuatorCommand, GRAVITY_MPS2, Measurement, RigidBodyState, Vehicle};

use crate::control::Control;
use crate::mission::Missions;
use crate::modes::{Commander, FlightMode, LossAction, Refusal, Transition, VehicleFacts};
use crate::navigator::Carrot;
use crate::offboard::{self, AttitudeTarget, PositionTarget, RateLimits};
use crate::params::{Param, Params};
use crate::realtime::{RealtimeMonitor, RealtimePolicy};
use crate::telemetry::{self, Landed};
use crate::transport::{Endpoint, Incoming, Transport};
use crate::wire::{Frame, LinkCounters, Signing, Wire};
use firmware_bridge::setpoint::GROUP_ARM;
use firmware_bridge::{ActuatorUpdate, SetpointCodec};
use guidance::Guidance;
use sim_twin::ipc::Mode;
use sim_twin::sensors::{NavigationModels, NavigationSensors};
use sim_twin::{Twin, TwinConfig, TwinError, TwinObserver};

/// The autopilot's MAVLink system id.
pub const SYSTEM_ID: u8 = 1;
/// The autopilot's MAVLink component id (MAV_COMP_ID_AUTOPILOT1).
pub const COMPONENT_ID: u8 = 1;
/// The STATUSTEXT (≤ 50 characters) refusing SET_ACTUATOR_CONTROL_TARGET without
/// `--allow-actuator-setpoints`; the log line adds how to allow them.
pub const ACTUATOR_REFUSAL: &str = "Actuator setpoints refused: not in PX4 (SITL flag)";

/// Refusals of the same kind are announced by STATUSTEXT at most this often (a refused
/// setpoint stream would flood the link otherwise); every one is counted.
pub const REFUSAL_TEXT_PERIOD: Duration = Duration::from_secs(1);
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
    /// Accept SET_ACTUATOR_CONTROL_TARGET (a SITL extension current PX4 does not have).
    /// Default off: refused with a STATUSTEXT saying why.
    pub allow_actuator_setpoints: bool,
    /// What a realtime twin that cannot keep up does.
    pub realtime_policy: RealtimePolicy,
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
            allow_actuator_setpoints: false,
            realtime_policy: RealtimePolicy::Warn,
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
    /// A realtime twin could not keep up and `--realtime-policy fail` stopped it.
    #[error("{0}")]
    Realtime(String),
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
    /// A realtime twin ran slower than the wall clock over the last second.
    RealtimeFactor {
        /// Twin time, s.
        at_s: f64,
        /// Twin time advanced per wall time over the window.
        factor: f64,
    },
    /// Something a peer changed or asked for (a parameter set, a mission uploaded, an item
    /// reached).
    Notice {
        /// Twin time, s.
        at_s: f64,
        /// What.
        text: String,
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
            Self::RealtimeFactor { at_s, factor } => write!(
                f,
                "t = {at_s:.3} s: real-time factor {factor:.3} over the last second (the twin cannot keep up with the wall clock; it runs at this slower pace)"
            ),
            Self::Notice { at_s, text } => write!(f, "t = {at_s:.3} s: {text}"),
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
    /// Rotor thrusts, N (SET_ACTUATOR_CONTROL_TARGET, with --allow-actuator-setpoints).
    Motors(Vec<f64>),
    /// SET_ATTITUDE_TARGET (attitude or rates; the body force resolved).
    Attitude(AttitudeTarget),
    /// SET_POSITION_TARGET_LOCAL_NED.
    Position(PositionTarget),
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
const GPS_RAW_INT_ID: u32 = 24;
const ALTITUDE_ID: u32 = 141;
const MISSION_CURRENT_ID: u32 = 42;
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
    /// The body force of the last attitude setpoint that carried one (thrust-ignore bit), N.
    last_force_in_body_n: Vector3<f64>,
    last_setpoint: Option<Instant>,
    /// Where the internal controller (and offboard position) flies.
    guidance: Guidance,
    /// The moving position target (None: take the vehicle's pose at the next step).
    carrot: Option<Carrot>,
    landed_since_s: Option<f64>,
    params: Params,
    missions: Missions,
    /// The mission item flown (or to fly next).
    mission_seq: u16,
    /// Home: the ground under the point where the vehicle last armed (world, m).
    home_m: Vector3<f64>,
    /// UDP peers that spoke MAVLink 1 and never MAVLink 2 (answered in MAVLink 1, as PX4).
    v1_peers: Vec<SocketAddr>,
    /// UDP peers that spoke MAVLink 2 (stay on MAVLink 2).
    v2_peers: Vec<SocketAddr>,
    /// Serial: the peer speaks MAVLink 1 only.
    serial_v1: bool,
    /// The peer (address) of the frame being handled.
    current_peer: Option<SocketAddr>,
    /// The horizontal speed commanded by DO_CHANGE_SPEED / DO_REPOSITION / a mission, m/s.
    cruise_override_mps: Option<f64>,
    /// What the last step decided, reported after it.
    deferred: Vec<guidance::Deferred>,
    /// When each kind of refusal was last announced.
    refusal_texts: Vec<(&'static str, Instant)>,
    realtime: RealtimeMonitor,
    /// The twin's navigation sensors (GNSS for GPS_RAW_INT), sampled after every step.
    navigation: NavigationSensors,
    /// The GNSS receiver's latest fix.
    gnss_fix: Option<estimator::GnssFix>,
    /// Set when `--realtime-policy fail` stops the autopilot.
    realtime_failure: Option<String>,
    /// The base before the last step (the IMU's period start).
    previous_base: RigidBodyState,
    /// The IMU sample of the last step (HIGHRES_IMU).
    imu: ImuSample,
    /// Wall clock of the next step while the twin runs on the clock.
    next_step: Option<Instant>,
    /// Realtime: the clock has started (first arming).
    clock_started: bool,
    /// Wall clock of the next per-step telemetry while the twin stands still.
    next_idle_telemetry: Instant,
    streams: Vec<Stream>,
    steps: u64,
    out: Vec<u8>,
    out_v1: Vec<u8>,
    /// Hears every reset and step (the live view of `twin serve --live`).
    observer: Option<Box<dyn TwinObserver>>,
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
            stream(GPS_RAW_INT_ID, 5.0),
            stream(ALTITUDE_ID, 10.0),
            stream(MISSION_CURRENT_ID, 1.0),
            stream(HOME_POSITION_ID, 0.5),
        ];
        let mut params = Params::default();
        params
            .set(Param::ComOfLossT, config.offboard_timeout.as_secs_f64())
            .map_err(|e| AutopilotError::Vehicle(format!("--offboard-timeout-ms: {e}")))?;
        let hover_force = Vector3::z() * (control.body().mass_kg * GRAVITY_MPS2);
        let mut navigation = NavigationSensors::new(NavigationModels::default(), seed)
            .map_err(|e| AutopilotError::Vehicle(format!("navigation sensors: {e}")))?;
        let gnss_fix = navigation.sample(twin.truth()).gnss;
        let previous_base = twin.truth().base;
        Ok(Self {
            imu: telemetry::imu(&previous_base, twin.truth(), dt_s),
            previous_base,
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
            last_force_in_body_n: hover_force,
            last_setpoint: None,
            guidance: Guidance::Hold,
            carrot: None,
            landed_since_s: None,
            params,
            missions: Missions::default(),
            mission_seq: 0,
            home_m: Vector3::zeros(),
            v1_peers: Vec::new(),
            v2_peers: Vec::new(),
            serial_v1: false,
            current_peer: None,
            cruise_override_mps: None,
            deferred: Vec::new(),
            refusal_texts: Vec::new(),
            realtime: RealtimeMonitor::new(),
            navigation,
            gnss_fix,
            realtime_failure: None,
            next_step: None,
            clock_started: false,
            next_idle_telemetry: now,
            streams,
            steps: 0,
            out: Vec::with_capacity(4096),
            out_v1: Vec::with_capacity(4096),
            observer: None,
            config,
        })
    }

    /// Shows every step and reset of the twin to `observer` from now on (told of the twin's
    /// current state at once).
    pub fn set_observer(&mut self, mut observer: Box<dyn TwinObserver>) {
        observer.reset(&self.twin);
        self.observer = Some(observer);
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
    pub fn local_addr(&self) -> Option<SocketAddr> {
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
                let (new_peer, from) = match incoming {
                    Incoming::Datagram { len, from } => {
                        self.wire
                            .datagram(buf.get(..len).unwrap_or(&[]), &mut received);
                        // Only a sender of an accepted frame is a peer (with signing required,
                        // an unsigned sender gets nothing).
                        let new = !received.is_empty() && self.transport.note_peer(from);
                        (new.then_some(from), Some(from))
                    }
                    Incoming::Stream(n) => {
                        self.wire.stream(buf.get(..n).unwrap_or(&[]), &mut received);
                        (None, None)
                    }
                };
                self.note_versions(from, &received);
                if let (Some(addr), Some(r)) = (new_peer, received.first()) {
                    on_event(&AutopilotEvent::Peer {
                        addr: addr.to_string(),
                        system: r.header.system_id,
                        component: r.header.component_id,
                    });
                }
                self.current_peer = from;
                for r in std::mem::take(&mut received) {
                    self.handle(&r, &mut on_event);
                }
                self.current_peer = None;
            }
            self.tick(&mut on_event);
            if let Some(why) = self.realtime_failure.take() {
                on_event(&AutopilotEvent::Stopped {
                    steps: self.steps,
                    counters: self.wire.counters(),
                });
                return Err(AutopilotError::Realtime(why));
            }
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

    /// Records which MAVLink version each peer speaks: MAVLink 1 until it is heard speaking
    /// MAVLink 2, then MAVLink 2 for good (PX4's MAV_PROTO_VER = 0 behaviour).
    fn note_versions(&mut self, from: Option<SocketAddr>, frames: &[Frame]) {
        for r in frames {
            match (from, r.version) {
                (Some(a), MavlinkVersion::V2) => {
                    self.v1_peers.retain(|p| *p != a);
                    if !self.v2_peers.contains(&a) {
                        self.v2_peers.push(a);
                    }
                }
                (Some(a), MavlinkVersion::V1) => {
                    if !self.v2_peers.contains(&a) && !self.v1_peers.contains(&a) {
                        self.v1_peers.push(a);
                    }
                }
                (None, MavlinkVersion::V2) => self.serial_v1 = false,
                (None, MavlinkVersion::V1) => self.serial_v1 = true,
            }
        }
    }

    /// The offboard timeout, COM_OF_LOSS_T.
    fn offboard_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.params.get(Param::ComOfLossT).max(0.0))
    }

    fn streaming(&self) -> bool {
        let timeout = self.offboard_timeout();
        self.last_setpoint.is_some_and(|t| t.elapsed() <= timeout)
    }

    /// Whether arming would be accepted now (SYS_STATUS's pre-arm check).
    fn armable(&self) -> bool {
        let mut c = self.commander.clone();
        !self.commander.armed() && c.arm(&self.facts()).is_ok()
    }

    /// The rate limits of offboard rates (MC_*RATE_MAX), rad/s.
    fn rate_limits(&self) -> RateLimits {
        RateLimits {
            roll_radps: self.params.get(Param::McRollrateMax).to_radians(),
            pitch_radps: self.params.get(Param::McPitchrateMax).to_radians(),
            yaw_radps: self.params.get(Param::McYawrateMax).to_radians(),
        }
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
            has_mission: !self.missions.items().is_empty(),
        }
    }

    fn landed_state(&self) -> Landed {
        let z = self.truth().base.position_in_world_m.z;
        if !self.commander.armed() {
            Landed::OnGround
        } else if self.commander.mode() == FlightMode::AutoLand || self.guidance.landing() {
            Landed::Landing
        } else if self.guidance.taking_off() {
            Landed::Takeoff
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
        let action = LossAction::from_param(self.params.get(Param::ComOblRcAct));
        if let Some(t) = self
            .commander
            .update(self.twin.time_s(), self.streaming(), landed, action)
        {
            self.transition(t, on_event);
        }
        let now = Instant::now();
        let mut replies = Vec::new();
        if let crate::mission::Outcome::Failed(why) = self.missions.poll(now, &mut replies) {
            self.notice(format!("mission upload failed: {why}"), on_event);
        }
        self.send(&replies);
        if self.config.mode == Mode::Realtime && self.runs_on_clock() {
            if let Some(factor) = self.realtime.update(now, self.twin.time_s()) {
                on_event(&AutopilotEvent::RealtimeFactor {
                    at_s: self.twin.time_s(),
                    factor,
                });
                if self.config.realtime_policy == RealtimePolicy::Fail {
                    self.realtime_failure = Some(format!(
                        "the realtime twin ran at {factor:.3} of the wall clock over the last second (below {}): stopped (--realtime-policy fail)",
                        crate::realtime::SLOW_FACTOR
                    ));
                }
            }
        } else {
            self.realtime.reset();
        }
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
                self.carrot = None;
                // Home: the ground under the vehicle at arming, as PX4 sets it.
                let p = self.truth().base.position_in_world_m;
                let home = Vector3::new(p.x, p.y, 0.0);
                if (home - self.home_m).norm() > 1e-3 {
                    self.home_m = home;
                    let msg = telemetry::home_position(self.twin.truth(), &self.home_m);
                    self.send(&[msg]);
                }
                self.enter(self.commander.mode());
            }
            Transition::Disarmed(_) => {
                self.carrot = None;
                self.landed_since_s = None;
                self.guidance = Guidance::Hold;
            }
            Transition::Mode { mode, .. } => {
                let mode = *mode;
                self.landed_since_s = None;
                self.enter(mode);
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
            _ => self.internal_command(),
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
            Offboard::Attitude(AttitudeTarget::Attitude {
                world_from_body,
                body_rates_radps,
                force_in_body_n,
            }) => {
                let force = force_in_body_n.unwrap_or(self.last_force_in_body_n);
                let sp = firmware_bridge::AttitudeSetpoint {
                    world_from_body: *world_from_body,
                    force_in_body_n: force,
                    body_rates_radps: Some(*body_rates_radps),
                };
                self.control
                    .attitude(self.twin.truth(), &sp, &self.joint_targets)
            }
            Offboard::Attitude(AttitudeTarget::Rates {
                body_rates_radps,
                force_in_body_n,
            }) => {
                let force = force_in_body_n.unwrap_or(self.last_force_in_body_n);
                let rates = *body_rates_radps;
                self.control
                    .rates(self.twin.truth(), &rates, &force, &self.joint_targets)
            }
            Offboard::Position(target) => {
                let target = *target;
                self.offboard_position_command(&target)
            }
        }
    }

    /// One twin step, then its telemetry. A failed step disarms and resets the twin.
    fn step(&mut self, command: &ActuatorCommand, on_event: &mut impl FnMut(&AutopilotEvent)) {
        self.previous_base = self.truth().base;
        match self.twin.step(command) {
            Ok(_) => {
                self.steps += 1;
                if let Some(o) = &mut self.observer {
                    o.stepped(&self.twin, command);
                }
                // Idle telemetry resumes a period after the last step.
                self.next_idle_telemetry = Instant::now() + IDLE_TELEMETRY_PERIOD;
                self.imu = telemetry::imu(&self.previous_base, self.truth(), self.dt_s);
                let readings = self.navigation.sample(self.twin.truth());
                if readings.gnss.is_some() {
                    self.gnss_fix = readings.gnss;
                }
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
                    if let Some(o) = &mut self.observer {
                        o.reset(&self.twin);
                    }
                }
                self.clock_started = false;
            }
        }
        self.flush_deferred(on_event);
    }

    /// Reports what the last step decided (transitions, reached items).
    fn flush_deferred(&mut self, on_event: &mut impl FnMut(&AutopilotEvent)) {
        for d in std::mem::take(&mut self.deferred) {
            match d {
                guidance::Deferred::Transition(t) => self.transition(t, on_event),
                guidance::Deferred::Notice(text) => self.notice(text, on_event),
                guidance::Deferred::Send(msg) => self.send(&[*msg]),
            }
        }
    }

    /// Sends `messages` to every peer: MAVLink 2, or MAVLink 1 to a peer that speaks only
    /// that (messages with ids above 255 are not sent to it, as PX4).
    fn send(&mut self, messages: &[MavMessage]) {
        if messages.is_empty() {
            return;
        }
        self.out.clear();
        for m in messages {
            self.wire.encode(m, &mut self.out);
        }
        let any_v1 = !self.v1_peers.is_empty() || self.serial_v1;
        self.out_v1.clear();
        if any_v1 {
            for m in messages {
                self.wire.encode_v1(m, &mut self.out_v1);
            }
        }
        let out = std::mem::take(&mut self.out);
        let out_v1 = std::mem::take(&mut self.out_v1);
        let v1_peers = &self.v1_peers;
        let serial_v1 = self.serial_v1;
        self.transport.send_each(|peer| {
            let v1 = match peer {
                Some(a) => v1_peers.contains(&a),
                None => serial_v1,
            };
            if v1 { &out_v1 } else { &out }
        });
        self.out = out;
        self.out_v1 = out_v1;
    }

    fn send_per_step(&mut self) {
        if !self.transport.has_peers() {
            return;
        }
        let [joints, actuators, imu, attitude, position, odometry] =
            telemetry::per_step(self.twin.truth(), &self.imu);
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
            SYS_STATUS_ID => telemetry::sys_status(&self.wire.counters(), self.armable()),
            EXTENDED_SYS_STATE_ID => telemetry::extended_sys_state(self.landed_state()),
            ATTITUDE_ID => telemetry::attitude(m),
            GLOBAL_POSITION_INT_ID => telemetry::global_position_int(m),
            GPS_RAW_INT_ID => telemetry::gps_raw_int(m, self.gnss_fix.as_ref()?),
            ALTITUDE_ID => telemetry::altitude(m, &self.home_m),
            MISSION_CURRENT_ID => self.mission_current(),
            HOME_POSITION_ID => telemetry::home_position(m, &self.home_m),
            AUTOPILOT_VERSION_ID => {
                telemetry::autopilot_version(self.config.allow_actuator_setpoints)
            }
            id => {
                let per_step = telemetry::per_step(m, &self.imu);
                return per_step.into_iter().find(|msg| msg.message_id() == id);
            }
        })
    }

    /// One received message.
    fn handle(&mut self, r: &Frame, on_event: &mut impl FnMut(&AutopilotEvent)) {
        let for_us = |system: u8, component: u8| {
            (system == 0 || system == SYSTEM_ID) && (component == 0 || component == COMPONENT_ID)
        };
        let peer = (
            u8::try_from(r.header.system_id).unwrap_or(0),
            r.header.component_id,
        );
        match &r.message {
            MavMessage::HEARTBEAT(_) => {}
            MavMessage::COMMAND_LONG(c) => {
                if for_us(c.target_system, c.target_component) {
                    let cmd = commands::Cmd::from_long(c);
                    self.command(&r.header, &cmd, on_event);
                } else {
                    self.wire.count_rejected_input();
                }
            }
            MavMessage::COMMAND_INT(c) => {
                if for_us(c.target_system, c.target_component) {
                    let cmd = commands::Cmd::from_int(c);
                    self.command(&r.header, &cmd, on_event);
                } else {
                    self.wire.count_rejected_input();
                }
            }
            MavMessage::SET_ACTUATOR_CONTROL_TARGET(s) => {
                if !for_us(s.target_system, s.target_component) {
                    self.wire.count_rejected_input();
                    return;
                }
                // Groups 0 (motors) and 1 (tilt servos) are what PX4 would fly: a SITL
                // extension. Group 2 (arm and gripper) is not PX4's on a real vehicle either (the
                // companion drives the arm on its own bus): accepted as that bus's stand-in.
                if !self.config.allow_actuator_setpoints && s.group_mlx != GROUP_ARM {
                    self.wire.count_rejected_input();
                    self.refuse_input("actuator", ACTUATOR_REFUSAL, on_event);
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
                let scale =
                    self.decoder.rotor_count() as f64 * self.twin.vehicle().rotors.thrust_max_n;
                match offboard::attitude_target(s, &self.rate_limits(), scale) {
                    Ok(target) => {
                        let (AttitudeTarget::Attitude {
                            force_in_body_n, ..
                        }
                        | AttitudeTarget::Rates {
                            force_in_body_n, ..
                        }) = target;
                        if let Some(f) = force_in_body_n {
                            self.last_force_in_body_n = f;
                        }
                        if !matches!(self.offboard, Offboard::Attitude(_)) {
                            self.control.reset_attitude();
                        }
                        self.offboard = Offboard::Attitude(target);
                        self.setpoint_arrived(on_event);
                    }
                    Err(why) => {
                        self.wire.count_rejected_input();
                        self.refuse_input(
                            "attitude",
                            &format!("Attitude refused: {why}"),
                            on_event,
                        );
                    }
                }
            }
            MavMessage::SET_POSITION_TARGET_LOCAL_NED(s) => {
                if !for_us(s.target_system, s.target_component) {
                    self.wire.count_rejected_input();
                    return;
                }
                let base = &self.truth().base;
                let (_, _, yaw) = base.world_from_body.euler_angles();
                match offboard::position_target(s, &base.position_in_world_m, yaw) {
                    Ok(target) => {
                        if !matches!(self.offboard, Offboard::Position(_)) {
                            // A new position stream starts from where the vehicle is.
                            self.carrot = None;
                        }
                        self.offboard = Offboard::Position(target);
                        self.setpoint_arrived(on_event);
                    }
                    Err(why) => {
                        self.wire.count_rejected_input();
                        self.refuse_input(
                            "position",
                            &format!("Position refused: {why}"),
                            on_event,
                        );
                    }
                }
            }
            MavMessage::PARAM_REQUEST_LIST(p) if for_us(p.target_system, p.target_component) => {
                self.param_list();
            }
            MavMessage::PARAM_REQUEST_READ(p) if for_us(p.target_system, p.target_component) => {
                self.param_read(p);
            }
            MavMessage::PARAM_SET(p) if for_us(p.target_system, p.target_component) => {
                self.param_set(p, on_event);
            }
            MavMessage::MISSION_COUNT(m) if for_us(m.target_system, m.target_component) => {
                let mut out = Vec::new();
                let outcome = self.missions.count(peer, m, Instant::now(), &mut out);
                self.send(&out);
                self.mission_outcome(outcome, on_event);
            }
            MavMessage::MISSION_ITEM_INT(m) if for_us(m.target_system, m.target_component) => {
                let mut out = Vec::new();
                let outcome =
                    self.missions
                        .item(peer, m, &telemetry::HOME, Instant::now(), &mut out);
                self.send(&out);
                self.mission_outcome(outcome, on_event);
            }
            MavMessage::MISSION_ITEM(m) if for_us(m.target_system, m.target_component) => {
                let item = crate::mission::item_int_of(m);
                let mut out = Vec::new();
                let outcome =
                    self.missions
                        .item(peer, &item, &telemetry::HOME, Instant::now(), &mut out);
                self.send(&out);
                self.mission_outcome(outcome, on_event);
            }
            MavMessage::MISSION_REQUEST_LIST(m) if for_us(m.target_system, m.target_component) => {
                let mut out = Vec::new();
                self.missions.request_list(peer, m.mission_type, &mut out);
                self.send(&out);
            }
            MavMessage::MISSION_REQUEST_INT(m) if for_us(m.target_system, m.target_component) => {
                let mut out = Vec::new();
                self.missions
                    .request_item(peer, m.seq, m.mission_type, &mut out);
                self.send(&out);
            }
            MavMessage::MISSION_REQUEST(m) if for_us(m.target_system, m.target_component) => {
                let mut out = Vec::new();
                self.missions
                    .request_item(peer, m.seq, m.mission_type, &mut out);
                self.send(&out);
            }
            MavMessage::MISSION_CLEAR_ALL(m) if for_us(m.target_system, m.target_component) => {
                let mut out = Vec::new();
                let outcome = self.missions.clear(peer, m.mission_type, &mut out);
                self.send(&out);
                self.mission_outcome(outcome, on_event);
            }
            MavMessage::MISSION_SET_CURRENT(m) if for_us(m.target_system, m.target_component) => {
                if let Err(why) = self.set_mission_current(m.seq) {
                    self.status_text(MavSeverity::MAV_SEVERITY_WARNING, &why);
                }
            }
            // Everything else in the common dialect is understood and ignored, as PX4 ignores
            // what it does not handle.
            _ => {}
        }
    }

    /// A refused input, announced by STATUSTEXT at most every [`REFUSAL_TEXT_PERIOD`] per
    /// kind (and logged as often).
    fn refuse_input(
        &mut self,
        kind: &'static str,
        text: &str,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        let now = Instant::now();
        if let Some((_, last)) = self.refusal_texts.iter_mut().find(|(k, _)| *k == kind) {
            if now.duration_since(*last) < REFUSAL_TEXT_PERIOD {
                return;
            }
            *last = now;
        } else {
            self.refusal_texts.push((kind, now));
        }
        self.status_text(MavSeverity::MAV_SEVERITY_WARNING, text);
        let reason = if text == ACTUATOR_REFUSAL {
            "current PX4 has no actuator offboard over MAVLink (fly SET_ATTITUDE_TARGET or SET_POSITION_TARGET_LOCAL_NED; in SITL: twin serve --allow-actuator-setpoints)".to_owned()
        } else {
            text.to_owned()
        };
        on_event(&AutopilotEvent::Refused {
            at_s: self.twin.time_s(),
            command: format!("{kind} setpoint"),
            reason,
        });
    }

    fn notice(&mut self, text: String, on_event: &mut impl FnMut(&AutopilotEvent)) {
        on_event(&AutopilotEvent::Notice {
            at_s: self.twin.time_s(),
            text,
        });
    }

    /// MISSION_CURRENT of the mission state now.
    fn mission_current(&self) -> MavMessage {
        let total = u16::try_from(self.missions.items().len()).unwrap_or(u16::MAX);
        let state = if total == 0 {
            MissionState::MISSION_STATE_NO_MISSION
        } else if self.mission_seq >= total {
            MissionState::MISSION_STATE_COMPLETE
        } else if self.commander.mode() == FlightMode::AutoMission && self.commander.armed() {
            MissionState::MISSION_STATE_ACTIVE
        } else {
            MissionState::MISSION_STATE_NOT_STARTED
        };
        telemetry::mission_current(
            self.mission_seq.min(total.saturating_sub(1)),
            total,
            state,
            self.missions.id(),
        )
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
}
