//! A PX4-style autopilot over MAVLink as a [`Link`] of the flight loop: the twin's autopilot
//! in SITL (`amstack twin serve --mavlink ...`) or a real vehicle.
//!
//! [`MavlinkLink::connect`] opens the [`firmware_bridge::Bridge`] and waits for the first
//! ODOMETRY (the vehicle's state at start). The first [`Link::send`] runs the contract's
//! start sequence with that tick's setpoint: stream it (≥ 2 Hz, as PX4 requires before
//! offboard), switch to OFFBOARD, ARM, then send it once more — in lockstep that is the
//! setpoint that steps the twin from its reset state, as an in-process run starts. Every
//! [`Link::receive`] after a send waits for an ODOMETRY newer than the last one returned
//! (in lockstep, the one closing this tick; in real time, the next step), up to
//! `tick_timeout`; a timeout is an error naming ODOMETRY and the tick.
//!
//! Levels (what a real PX4 accepts: attitude and position; `docs/mavlink.md`):
//! [`Level::Attitude`] sends a SET_ATTITUDE_TARGET of the base controller's cascade (its
//! desired attitude and body rates, the body force the allocation produces:
//! [`crate::TickRecord::setpoint`]). [`Level::Position`] sends a SET_POSITION_TARGET_LOCAL_NED
//! of the stack's base target (position and heading): the autopilot's position controller
//! flies. [`Level::Rates`] sends the attitude level's cascade through amstack's attitude law as
//! body rates (SET_ATTITUDE_TARGET with ATTITUDE_IGNORE): the autopilot's rate loop flies.
//! [`Level::Actuator`] sends the rotor thrusts, tilts, arm and gripper
//! (SET_ACTUATOR_CONTROL_TARGET groups 2, 1, 0): only to an autopilot that declares
//! MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET in its AUTOPILOT_VERSION (current PX4 does not;
//! the twin's autopilot does with `--allow-actuator-setpoints`), asked for at connection:
//! otherwise the flight is refused before anything is armed.
//!
//! The arm and gripper: at the actuator level in group 2. At the attitude and position levels
//! group 2 goes before each setpoint only when the autopilot is amstack's twin (its
//! AUTOPILOT_VERSION says so), which stands in for the arm's own servo bus; a PX4 has no arm
//! output and no SET_ACTUATOR_CONTROL_TARGET, so toward it nothing is sent for the arm
//! ([`MavlinkLink::arm_channel`]): on a real vehicle the companion drives the arm on its own
//! bus.
//!
//! With a task scene ([`MavlinkLink::with_scene_model`]) the link reports the scene's state
//! the twin's autopilot sends (`mavlink_scene`), checked at connection against the scene
//! built here from the task and the seed.
//!
//! Dropping the link stops the setpoints and never disarms: the vehicle may be flying, and
//! the autopilot's offboard-loss failsafe (hold, then land) is the safe end.
//!
//! Log messages ([`Link::drain_messages`], once per measurement): `/autopilot/state`, the
//! bridge's view of the autopilot and its counters at the measurement's time; and, when the
//! bridge captures them ([`BridgeConfig::capture_raw`]), every frame captured since the last
//! call on `/mavlink/raw`, each at the flight time it carries (`docs/mcap-format.md`).

use std::time::{Duration, Instant};

use estimator::ImuSample;
use firmware_bridge::{
    AutopilotVersion, Bridge, BridgeConfig, BridgeError, CounterSnapshot, RawFrame, SetpointCodec,
};
use platform::{ActuatorCommand, Measurement, Vehicle};
use sim_twin::TaskSnapshot;

use crate::link::{Link, LinkError, LinkMessage, Setpoint, SetpointLevel, VehicleSensors};
use crate::link_channels::{AutopilotStateMessage, LinkPayload, MavlinkRawFrame};
use crate::mavlink_scene::{check_scene, snapshot_from_wire};

/// Which setpoints the flight stack sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// Rotor thrusts (our allocation flies the vehicle): SET_ACTUATOR_CONTROL_TARGET. Only
    /// toward an autopilot that declares the capability (not PX4).
    Actuator,
    /// Attitude + body force (the autopilot's own attitude loop and allocation):
    /// SET_ATTITUDE_TARGET. The default toward a real vehicle.
    Attitude,
    /// Body rates + body force (amstack's attitude law, the autopilot's rate loop and
    /// allocation): SET_ATTITUDE_TARGET with ATTITUDE_IGNORE.
    Rates,
    /// Base position + heading (the autopilot's position controller, attitude loop and
    /// allocation): SET_POSITION_TARGET_LOCAL_NED.
    Position,
}

impl Level {
    /// The command-line name.
    pub fn name(self) -> &'static str {
        self.setpoint_level().name()
    }

    /// The flight loop's setpoint of this level.
    pub fn setpoint_level(self) -> SetpointLevel {
        match self {
            Self::Actuator => SetpointLevel::Actuators,
            Self::Attitude => SetpointLevel::Attitude,
            Self::Rates => SetpointLevel::Rates,
            Self::Position => SetpointLevel::Position,
        }
    }
}

/// How the flight side connects and waits.
#[derive(Debug, Clone)]
pub struct MavlinkLinkConfig {
    /// The bridge (address, ids, signing, command retries).
    pub bridge: BridgeConfig,
    /// Setpoint level.
    pub level: Level,
    /// How long to wait for the first ODOMETRY after connecting (default 10 s).
    pub connect_timeout: Duration,
    /// How long each tick's ODOMETRY may take after its setpoint (default 200 ms).
    pub tick_timeout: Duration,
    /// Setpoints streamed before switching to offboard (default 6, at `stream_period`).
    pub stream_count: u32,
    /// Period of that stream (default 50 ms: 20 Hz, PX4 needs ≥ 2 Hz).
    pub stream_period: Duration,
    /// Record per-tick send → telemetry round trips ([`MavlinkLink::round_trips_ns`]).
    pub record_timing: bool,
    /// How long to wait for AUTOPILOT_VERSION after the autopilot acknowledged the request
    /// (default 1 s).
    pub version_timeout: Duration,
}

impl MavlinkLinkConfig {
    /// Defaults for a bridge configuration.
    pub fn new(bridge: BridgeConfig, level: Level) -> Self {
        Self {
            bridge,
            level,
            connect_timeout: Duration::from_secs(10),
            tick_timeout: Duration::from_millis(200),
            stream_count: 6,
            stream_period: Duration::from_millis(50),
            record_timing: false,
            version_timeout: Duration::from_secs(1),
        }
    }
}

/// What can go wrong on the MAVLink link.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MavlinkLinkError {
    /// The bridge failed (open, command refused or unanswered, no telemetry, bad setpoint).
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    /// The autopilot disarmed or left OFFBOARD during the flight (its failsafe, a pilot
    /// taking over): the flight stops.
    #[error(
        "the autopilot {what} during the flight (tick {tick}): now {mode}, {armed}; the flight stack stopped sending"
    )]
    Dropped {
        /// `disarmed` or `left OFFBOARD`.
        what: String,
        /// The tick it was noticed at.
        tick: u64,
        /// The mode its last HEARTBEAT gave.
        mode: String,
        /// `armed` or `disarmed`.
        armed: String,
    },
    /// A setpoint of another level than the link's.
    #[error("this link flies the {link} level; a setpoint of the {setpoint} level was sent")]
    WrongLevel {
        /// The link's level.
        link: &'static str,
        /// The setpoint's.
        setpoint: &'static str,
    },
    /// The autopilot serves another task scene than the flight's.
    #[error("{0}")]
    Scene(String),
    /// The actuator level was asked of an autopilot that does not declare it.
    #[error(
        "the actuator level needs an autopilot that declares MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET in its AUTOPILOT_VERSION; {why} (current PX4 takes no actuator setpoints over MAVLink; amstack's twin takes them with `twin serve --allow-actuator-setpoints`): fly the attitude or the position level"
    )]
    NoActuatorLevel {
        /// What the autopilot said (`this one does not`, or why it said nothing).
        why: String,
    },
}

impl From<MavlinkLinkError> for LinkError {
    fn from(e: MavlinkLinkError) -> Self {
        let text = e.to_string();
        match e {
            MavlinkLinkError::Bridge(b) => b.into(),
            MavlinkLinkError::Dropped { .. } => LinkError::Failed(text),
            MavlinkLinkError::WrongLevel { .. }
            | MavlinkLinkError::Scene(_)
            | MavlinkLinkError::NoActuatorLevel { .. } => LinkError::Refused(text),
        }
    }
}

impl From<BridgeError> for LinkError {
    fn from(e: BridgeError) -> Self {
        let text = e.to_string();
        match e {
            // A vehicle whose commands do not fit MAVLink, an address that cannot be opened:
            // the flight's configuration.
            BridgeError::Setpoint(_) | BridgeError::Open { .. } => LinkError::Refused(text),
            BridgeError::CommandTimeout { .. } | BridgeError::NoTelemetry { .. } => {
                LinkError::Silent(text)
            }
            _ => LinkError::Failed(text),
        }
    }
}

/// The flight side of a MAVLink autopilot.
#[derive(Debug)]
pub struct MavlinkLink {
    config: MavlinkLinkConfig,
    bridge: Bridge,
    codec: SetpointCodec,
    latest: Measurement,
    started: bool,
    /// Heartbeats received when the start sequence finished: later ones describe the flight.
    heartbeats_at_start: u64,
    ticks: u64,
    sent_at: Option<Instant>,
    round_trips_ns: Vec<u64>,
    /// The rotor thrusts of the last actuator-level command, N (the autopilot reports only
    /// the realised ones).
    commanded_n: Option<Vec<f64>>,
    thrust_range_n: (f64, f64),
    /// When the link was opened: the origin of `/mavlink/raw`'s wall times.
    opened_at: Instant,
    /// Frames drained from the bridge's capture, reused between ticks.
    raw: Vec<RawFrame>,
    /// The task scene built on this side from the task and the seed, with a task.
    scene_model: Option<TaskSnapshot>,
    /// Whether the autopilot sends the task's state.
    scene_observed: bool,
    /// What the autopilot declared at connection (None: it did not answer the request).
    version: Option<AutopilotVersion>,
}

impl MavlinkLink {
    /// Connects to the autopilot, waits for its first ODOMETRY and asks what it declares
    /// (AUTOPILOT_VERSION): the actuator level is refused ([`LinkError::Refused`]) unless it
    /// declares MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET; the arm channel of the other
    /// levels is on only toward amstack's twin.
    pub fn connect(vehicle: &Vehicle, config: MavlinkLinkConfig) -> Result<Self, LinkError> {
        let codec = SetpointCodec::new(
            vehicle,
            config.bridge.target_system,
            config.bridge.target_component,
        )
        .map_err(BridgeError::from)?;
        let opened_at = Instant::now();
        let mut bridge = Bridge::connect(config.bridge.clone(), vehicle)?;
        let latest = bridge.next_measurement(
            None,
            config.connect_timeout,
            "ODOMETRY (the vehicle's state at start)",
        )?;
        let version = bridge.request_autopilot_version(config.version_timeout);
        if config.level == Level::Actuator {
            let why = match &version {
                Ok(v) if v.accepts_actuator_setpoints() => None,
                Ok(_) => Some("this one does not".to_owned()),
                Err(e) => Some(format!("this one did not say ({e})")),
            };
            if let Some(why) = why {
                return Err(MavlinkLinkError::NoActuatorLevel { why }.into());
            }
        }
        // A PX4 that does not answer flies without the arm channel, as any PX4 does.
        let version = version.ok();
        let arm_channel =
            config.level == Level::Actuator || version.is_some_and(|v| v.is_amstack_twin());
        let codec = codec.with_arm_channel(arm_channel);
        Ok(Self {
            config,
            bridge,
            codec,
            latest,
            started: false,
            heartbeats_at_start: 0,
            ticks: 0,
            sent_at: None,
            round_trips_ns: Vec::new(),
            commanded_n: None,
            thrust_range_n: (vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n),
            opened_at,
            raw: Vec::new(),
            scene_model: None,
            scene_observed: false,
            version,
        })
    }

    /// What the autopilot declared at connection (None: it did not answer).
    pub fn autopilot_version(&self) -> Option<AutopilotVersion> {
        self.version
    }

    /// Whether the arm and gripper targets are sent (group 2): at the actuator level, and
    /// toward amstack's twin at the others. Toward a PX4 the arm is not the autopilot's.
    pub fn arm_channel(&self) -> bool {
        self.codec.arm_channel()
    }

    /// The flight's task scene, built here from the task and the seed (`None`: no task).
    /// When the autopilot sends the task's state (the twin's autopilot does), it must be this
    /// scene's — the same task, keys and layout (seed) — or the flight is refused naming the
    /// difference; a vehicle that sends none flies from the model, its success not observed.
    pub fn with_scene_model(mut self, model: Option<TaskSnapshot>) -> Result<Self, LinkError> {
        let wire = self.bridge.task();
        if let (Some(model), Some(wire)) = (&model, &wire) {
            check_scene(model, wire).map_err(MavlinkLinkError::Scene)?;
        }
        self.scene_observed = wire.is_some();
        self.scene_model = model;
        Ok(self)
    }

    /// The bridge (autopilot state, counters).
    pub fn bridge(&self) -> &Bridge {
        &self.bridge
    }

    /// The wire counters.
    pub fn counters(&self) -> CounterSnapshot {
        self.bridge.counters()
    }

    /// Per-tick round trips (setpoint queued → its ODOMETRY decoded), ns, when recorded.
    pub fn round_trips_ns(&self) -> &[u64] {
        &self.round_trips_ns
    }

    fn time_usec(&self) -> u64 {
        // The flight stack's time of the command: the measurement time it answers, µs.
        (self.latest.time_s.max(0.0) * 1e6).round() as u64
    }

    fn messages(
        &self,
        setpoint: &Setpoint,
    ) -> Result<Vec<mavlink::dialects::common::MavMessage>, LinkError> {
        let t = self.time_usec();
        let messages = match (self.config.level, setpoint) {
            (Level::Actuator, Setpoint::Actuators(command)) => {
                self.codec.actuator_messages(t, command)
            }
            (Level::Attitude, Setpoint::Attitude { command, attitude }) => {
                self.codec.attitude_messages(t, command, attitude)
            }
            (Level::Rates, Setpoint::Rates { command, rates }) => {
                self.codec.rate_messages(t, command, rates)
            }
            (Level::Position, Setpoint::Position { command, position }) => {
                self.codec.position_messages(t, command, position)
            }
            (level, _) => {
                return Err(MavlinkLinkError::WrongLevel {
                    link: level.name(),
                    setpoint: setpoint.level().name(),
                }
                .into());
            }
        };
        Ok(messages.map_err(BridgeError::from)?)
    }

    /// The contract's start: stream the first setpoint, OFFBOARD, ARM.
    fn start(
        &mut self,
        messages: &[mavlink::dialects::common::MavMessage],
    ) -> Result<(), LinkError> {
        for _ in 0..self.config.stream_count {
            self.bridge.send(messages.to_vec())?;
            std::thread::sleep(self.config.stream_period);
        }
        self.bridge.set_offboard()?;
        self.bridge.arm()?;
        self.started = true;
        self.heartbeats_at_start = self.bridge.autopilot().heartbeats;
        Ok(())
    }

    fn send_messages(
        &mut self,
        messages: Vec<mavlink::dialects::common::MavMessage>,
    ) -> Result<(), LinkError> {
        if !self.started {
            self.start(&messages)?;
        }
        self.sent_at = Some(Instant::now());
        self.bridge.send(messages)?;
        self.ticks += 1;
        Ok(())
    }
}

impl MavlinkLink {
    /// An error if a HEARTBEAT since the start says the autopilot disarmed or left OFFBOARD.
    fn check_still_flying(&self) -> Result<(), MavlinkLinkError> {
        let state = self.bridge.autopilot();
        if !self.started || state.heartbeats <= self.heartbeats_at_start {
            return Ok(());
        }
        let what = if !state.armed {
            "disarmed"
        } else if !state.in_offboard() {
            "left OFFBOARD"
        } else {
            return Ok(());
        };
        Err(MavlinkLinkError::Dropped {
            what: what.to_owned(),
            tick: self.ticks,
            mode: state.mode_name(),
            armed: if state.armed { "armed" } else { "disarmed" }.to_owned(),
        })
    }

    /// Keeps the commanded rotor thrusts for the next measurement's rotor reports (actuator
    /// level; at the attitude level the autopilot chooses them).
    fn remember(&mut self, command: &ActuatorCommand) {
        self.commanded_n =
            (self.config.level == Level::Actuator).then(|| command.rotor_thrusts_n.clone());
    }
}

impl Link for MavlinkLink {
    fn receive(&mut self) -> Result<Measurement, LinkError> {
        if self.sent_at.is_none() {
            return Ok(self.latest.clone());
        }
        self.check_still_flying()?;
        let what = format!("ODOMETRY for tick {}", self.ticks);
        let m = match self.bridge.next_measurement(
            Some(self.latest.time_s),
            self.config.tick_timeout,
            &what,
        ) {
            Ok(m) => m,
            Err(e) => {
                // A silent autopilot that said why (disarmed, failsafe mode) is reported so.
                self.check_still_flying()?;
                return Err(e.into());
            }
        };
        if let (true, Some(t)) = (self.config.record_timing, self.sent_at) {
            self.round_trips_ns
                .push(u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX));
        }
        self.sent_at = None;
        let mut m = m;
        if let Some(commanded) = &self.commanded_n {
            let (lo, hi) = self.thrust_range_n;
            for (r, &c) in m.rotors.iter_mut().zip(commanded) {
                r.commanded_n = c;
                r.saturated = c < lo || c > hi;
            }
        }
        self.latest = m.clone();
        Ok(m)
    }

    fn send(&mut self, setpoint: &Setpoint) -> Result<(), LinkError> {
        let messages = self.messages(setpoint)?;
        self.send_messages(messages)?;
        self.remember(setpoint.command());
        Ok(())
    }

    fn level(&self) -> SetpointLevel {
        self.config.level.setpoint_level()
    }

    fn task(&self) -> Option<TaskSnapshot> {
        let model = self.scene_model.as_ref()?;
        if !self.scene_observed {
            // The scene model: the script's context and the obstacle face. Its status is not
            // an observation ([`Link::task_observed`]).
            return Some(model.clone());
        }
        snapshot_from_wire(model, &self.bridge.task()?)
    }

    fn task_observed(&self) -> bool {
        self.scene_model.is_none() || self.scene_observed
    }

    fn name(&self) -> String {
        format!("mavlink:{}", self.bridge.config().address)
    }

    /// HIGHRES_IMU and ODOMETRY of the tick last received. The autopilot sends the step's
    /// HIGHRES_IMU before the ODOMETRY that closes it, so both are the tick's; the IMU sample
    /// is stamped with the tick's time. ODOMETRY's covariances are not read (the contract
    /// sends NaN): the estimator's settings give the noise.
    fn vehicle_sensors(&self) -> Option<VehicleSensors> {
        let m = &self.latest;
        let state = self.bridge.autopilot();
        let imu = match (state.imu_accel_in_body_mps2, state.imu_gyro_in_body_radps) {
            (Some(a), Some(g)) if self.sent_at.is_none() && self.ticks > 0 => Some(ImuSample {
                time_s: m.time_s,
                specific_force_in_body_mps2: a,
                angular_velocity_in_body_radps: g,
            }),
            _ => None,
        };
        Some(VehicleSensors {
            imu,
            odometry: Some(VehicleSensors::odometry_of(m)),
        })
    }

    fn drain_messages(&mut self, time_s: f64, out: &mut Vec<LinkMessage>) {
        let b = &self.bridge;
        let state = AutopilotStateMessage::new(
            &b.autopilot(),
            b.heartbeat_age(),
            b.rejected_values(),
            &b.counters(),
            b.capture_stats(),
        );
        out.push(LinkMessage {
            time_s,
            payload: LinkPayload::AutopilotState(Box::new(state)),
        });
        self.raw.clear();
        self.bridge.drain_raw(&mut self.raw);
        for frame in &self.raw {
            out.push(LinkMessage {
                time_s: frame.flight_time_s,
                payload: LinkPayload::MavlinkRaw(Box::new(MavlinkRawFrame::new(
                    frame,
                    self.opened_at,
                ))),
            });
        }
    }
}
