//! The simulator's loop: listen on TCP (PX4's `simulator_mavlink` connects to it), serve one
//! PX4 at a time, one session per connection from the twin's reset state.
//!
//! One tick n (n = 1, 2, …; PX4's clock `time_usec` = round(n · 10⁶ / rate)):
//! 1. the sensors sample the twin's state (its time set to PX4's clock): the IMU the period
//!    that ended (the first tick reads the vehicle at rest), the magnetometer, barometer and
//!    GNSS when due;
//! 2. HIL_SENSOR, HIL_GPS (when the GNSS has a fix), HIL_STATE_QUATERNION go out;
//! 3. the reply is awaited (below), its controls mapped through the vehicle's channel map;
//! 4. unless the vehicle is held, the twin advances one control period with that command.
//!
//! **Lockstep** (the default): until the first HIL_ACTUATOR_CONTROLS with the lockstep flag
//! (bit 0) each HIL_SENSOR waits at most `first_reply` (default one period: PX4 boots in real
//! time) and the twin moves on; after it, every HIL_SENSOR waits for exactly one
//! HIL_ACTUATOR_CONTROLS — one period of simulated time per reply. A reply stamped earlier
//! than the HIL_SENSOR it would answer was sent before lockstep began: it is counted stale and
//! skipped. **Realtime**: ticks on the wall clock at the control rate with the latest
//! controls; nothing waits.
//!
//! **Held until armed**: until PX4 first reports itself armed (HIL_ACTUATOR_CONTROLS.mode has
//! MAV_MODE_FLAG_SAFETY_ARMED), the vehicle is held at its reset pose (the task scene's start)
//! while PX4's clock runs and the sensors read it at rest, as on a stand; from then on it flies.
//!
//! A PX4 that disconnects, or that stops answering in lockstep for `stall_timeout`, ends the
//! session (reported); the twin then waits for the next connection.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use estimator::{ConfigError, ImuModel, PoseModel};
use firmware_bridge::Direction;
use firmware_bridge::wire::{Counters, Decoder, Encoder, Frame};
use mavlink::Message;
use mavlink::dialects::common::{HilActuatorControlsFlags, MavMessage, MavModeFlag};
use platform::{ActuatorCommand, Measurement, RigidBodyState, Vehicle};
use sim_twin::ipc::Mode;
use sim_twin::sensors::{NavigationModels, SimulatedSensors, ideal_imu};
use sim_twin::{Twin, TwinConfig, TwinError};

use crate::channels::{ChannelMap, MapError};
use crate::messages::{self, HeldReadings};

/// The simulator's MAVLink system id.
pub const SYSTEM_ID: u8 = 1;
/// The simulator's MAVLink component id (as PX4's Gazebo bridge uses).
pub const COMPONENT_ID: u8 = 200;
/// PX4's simulator port.
pub const DEFAULT_PORT: u16 = 4560;

/// How the simulator runs.
#[derive(Debug, Clone, PartialEq)]
pub struct HilConfig {
    /// Address to listen on.
    pub listen: SocketAddr,
    /// Lockstep or realtime.
    pub mode: Mode,
    /// Lockstep: a PX4 silent this long after a HIL_SENSOR is lost. Default 5 s.
    pub stall_timeout: Duration,
    /// Lockstep, before the first reply: how long each HIL_SENSOR waits for one. Default: one
    /// control period (PX4 boots in real time).
    pub first_reply: Option<Duration>,
    /// Stop after this many sessions (None: until stopped).
    pub max_sessions: Option<u64>,
    /// The IMU's model (its rate is the control rate).
    pub imu: ImuModel,
    /// The magnetometer, barometer, GNSS and the world's place on the globe.
    pub navigation: NavigationModels,
}

impl HilConfig {
    /// Defaults for `listen` and `mode`.
    pub fn new(listen: SocketAddr, mode: Mode) -> Self {
        Self {
            listen,
            mode,
            stall_timeout: Duration::from_secs(5),
            first_reply: None,
            max_sessions: None,
            imu: ImuModel::default(),
            navigation: NavigationModels::default(),
        }
    }
}

/// `tcp:HOST:PORT` (or `HOST:PORT`) → a socket address; the one-line reason otherwise.
pub fn parse_endpoint(text: &str) -> Result<SocketAddr, String> {
    let rest = text.strip_prefix("tcp:").unwrap_or(text);
    rest.parse().map_err(|_| {
        format!("'{text}': expected tcp:HOST:PORT with a numeric IP, e.g. tcp:0.0.0.0:4560")
    })
}

/// The simulator cannot start.
#[derive(Debug, thiserror::Error)]
pub enum HilError {
    /// The twin cannot be built.
    #[error(transparent)]
    Twin(#[from] TwinError),
    /// The vehicle has no usable channel map.
    #[error(transparent)]
    Map(#[from] MapError),
    /// A sensor model is invalid.
    #[error("sensor model: {0}")]
    Sensors(String),
    /// The port cannot be opened.
    #[error("cannot listen on {addr}: {source}")]
    Listen {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
}

impl From<ConfigError> for HilError {
    fn from(e: ConfigError) -> Self {
        Self::Sensors(e.to_string())
    }
}

/// Why a session ended.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionEnd {
    /// PX4 closed the connection (or it failed).
    Disconnected(String),
    /// Lockstep: no HIL_ACTUATOR_CONTROLS for the stall timeout.
    Stalled {
        /// How long it waited, ms.
        waited_ms: u128,
    },
    /// The simulation diverged.
    Diverged(String),
    /// The simulator was stopped.
    Stopped,
}

/// Counts of one session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SessionStats {
    /// HIL_SENSOR sent.
    pub hil_sensor: u64,
    /// HIL_GPS sent.
    pub hil_gps: u64,
    /// HIL_STATE_QUATERNION sent.
    pub hil_state_quaternion: u64,
    /// HIL_ACTUATOR_CONTROLS received and applied.
    pub actuator_controls: u64,
    /// HIL_ACTUATOR_CONTROLS skipped as stale (stamped before the HIL_SENSOR awaiting one).
    pub stale_controls: u64,
    /// Mapped controls that were not finite (not applied).
    pub non_finite_controls: u64,
    /// Other frames received (HEARTBEAT, COMMAND_LONG, …): read and ignored.
    pub other_frames: u64,
    /// Frames the decoder refused (CRC, unknown id, truncated…).
    pub bad_frames: u64,
    /// Ticks the twin advanced.
    pub steps: u64,
    /// Tick at which lockstep began (0: never).
    pub lockstep_from_tick: u64,
}

/// What the simulator reports as it runs (the CLI prints these on stderr).
#[derive(Debug, Clone, PartialEq)]
pub enum HilEvent {
    /// Listening.
    Listening {
        /// The bound address.
        addr: SocketAddr,
        /// Vehicle id.
        vehicle: String,
        /// Lockstep or realtime.
        mode: Mode,
        /// Control (and HIL_SENSOR) rate, Hz.
        rate_hz: f64,
    },
    /// PX4 connected: a session starts.
    Connected {
        /// Session number, from 1.
        session: u64,
        /// PX4's address.
        peer: SocketAddr,
    },
    /// The first lockstep reply.
    Lockstep {
        /// PX4 time, s.
        at_s: f64,
    },
    /// PX4 armed: the vehicle is released.
    Armed {
        /// PX4 time, s.
        at_s: f64,
    },
    /// A session ended.
    Ended {
        /// Session number.
        session: u64,
        /// PX4 time, s.
        at_s: f64,
        /// Why.
        why: SessionEnd,
        /// Its counts.
        stats: SessionStats,
    },
}

impl std::fmt::Display for HilEvent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Listening {
                addr,
                vehicle,
                mode,
                rate_hz,
            } => write!(
                f,
                "PX4 simulator for {vehicle} listening on tcp:{addr} ({}, HIL_SENSOR at {rate_hz} Hz)",
                mode.name()
            ),
            Self::Connected { session, peer } => {
                write!(f, "session {session}: PX4 connected from {peer}")
            }
            Self::Lockstep { at_s } => write!(f, "t = {at_s:.3} s: lockstep with PX4"),
            Self::Armed { at_s } => {
                write!(f, "t = {at_s:.3} s: PX4 armed, the vehicle is released")
            }
            Self::Ended {
                session,
                at_s,
                why,
                stats,
            } => {
                let why = match why {
                    SessionEnd::Disconnected(e) => format!("PX4 disconnected ({e})"),
                    SessionEnd::Stalled { waited_ms } => format!(
                        "PX4 stopped answering in lockstep: no HIL_ACTUATOR_CONTROLS for {waited_ms} ms"
                    ),
                    SessionEnd::Diverged(e) => format!("the simulation diverged: {e}"),
                    SessionEnd::Stopped => "stopped".to_owned(),
                };
                write!(
                    f,
                    "session {session} ended at t = {at_s:.3} s: {why}; HIL_SENSOR {}, HIL_GPS {}, HIL_ACTUATOR_CONTROLS {} (stale {}), non-finite controls {}, bad frames {}; waiting for the next connection",
                    stats.hil_sensor,
                    stats.hil_gps,
                    stats.actuator_controls,
                    stats.stale_controls,
                    stats.non_finite_controls,
                    stats.bad_frames
                )
            }
        }
    }
}

/// One frame of a tick, as on the wire.
#[derive(Debug, Clone, PartialEq)]
pub struct HilFrame {
    /// Received or sent.
    pub direction: Direction,
    /// Wall clock when it was sent or decoded.
    pub at: Instant,
    /// Sender's system id.
    pub system_id: u8,
    /// Sender's component id.
    pub component_id: u8,
    /// Sequence number.
    pub sequence: u8,
    /// Message id.
    pub message_id: u32,
    /// Message name (`HIL_SENSOR`).
    pub message_name: &'static str,
    /// The frame's bytes.
    pub bytes: Vec<u8>,
}

/// One tick, handed to the observer after the twin stepped.
#[derive(Debug)]
pub struct HilTick<'a> {
    /// Session number.
    pub session: u64,
    /// PX4's clock at the tick's HIL_SENSOR, s.
    pub time_s: f64,
    /// The state the sensors read (time: PX4's clock).
    pub state: &'a Measurement,
    /// The state one period later, with the rotors and disturbances of the period (time:
    /// PX4's clock one period on). Equal to `state` (but for the time) while held.
    pub after: &'a Measurement,
    /// The command applied over the period.
    pub command: &'a ActuatorCommand,
    /// The raw controls of the reply applied (None: no reply this tick).
    pub controls: Option<[f32; 16]>,
    /// The vehicle is still held (PX4 has not armed).
    pub held: bool,
    /// Frames sent and received during the tick, in order.
    pub frames: &'a [HilFrame],
    /// The twin (task state and the like).
    pub twin: &'a Twin,
}

/// Who watches the sessions (the flight log).
pub trait HilObserver {
    /// A session starts with `twin` at its reset state.
    fn session_started(&mut self, _session: u64, _twin: &Twin) {}
    /// A tick is done.
    fn tick(&mut self, _tick: &HilTick<'_>) {}
    /// A session ended.
    fn session_ended(&mut self, _session: u64, _stats: &SessionStats) {}
}

/// An observer that watches nothing.
#[derive(Debug, Default)]
pub struct NoObserver;
impl HilObserver for NoObserver {}

/// The twin as PX4's simulator.
#[derive(Debug)]
pub struct HilServer {
    vehicle: Vehicle,
    twin_config: TwinConfig,
    config: HilConfig,
    map: ChannelMap,
    listener: TcpListener,
}

impl HilServer {
    /// Checks the vehicle and models and binds the port.
    pub fn new(
        vehicle: Vehicle,
        twin_config: TwinConfig,
        config: HilConfig,
    ) -> Result<Self, HilError> {
        let map = ChannelMap::new(&vehicle)?;
        // Build one twin and the sensors now: a bad vehicle or model fails at start.
        Twin::new(vehicle.clone(), twin_config.clone())?;
        SimulatedSensors::new(
            config.imu,
            PoseModel::default(),
            twin_config.control_rate_hz,
            0,
        )?
        .with_navigation(config.navigation)?;
        let listener = TcpListener::bind(config.listen).map_err(|source| HilError::Listen {
            addr: config.listen,
            source,
        })?;
        listener
            .set_nonblocking(true)
            .map_err(|source| HilError::Listen {
                addr: config.listen,
                source,
            })?;
        Ok(Self {
            vehicle,
            twin_config,
            config,
            map,
            listener,
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.listener.local_addr().ok()
    }

    /// Serves until `stop` is set (or `max_sessions` sessions were served).
    pub fn run(
        &mut self,
        stop: &AtomicBool,
        observer: &mut dyn HilObserver,
        mut report: impl FnMut(&HilEvent),
    ) -> Result<u64, HilError> {
        report(&HilEvent::Listening {
            addr: self.local_addr().unwrap_or(self.config.listen),
            vehicle: self.vehicle.id.clone(),
            mode: self.config.mode,
            rate_hz: self.twin_config.control_rate_hz,
        });
        let mut sessions = 0;
        while !stop.load(Ordering::SeqCst) && self.config.max_sessions.is_none_or(|m| sessions < m)
        {
            match self.listener.accept() {
                Ok((stream, peer)) => {
                    sessions += 1;
                    report(&HilEvent::Connected {
                        session: sessions,
                        peer,
                    });
                    let mut session = Session::new(self, stream, sessions)?;
                    observer.session_started(sessions, &session.twin);
                    let why = session.run(stop, observer, &mut report);
                    observer.session_ended(sessions, &session.stats);
                    report(&HilEvent::Ended {
                        session: sessions,
                        at_s: session.time_s(),
                        why,
                        stats: session.stats,
                    });
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    std::thread::sleep(Duration::from_millis(10));
                }
                Err(e) => {
                    eprintln!("twin_hil: accept failed: {e}");
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
        }
        Ok(sessions)
    }
}

/// The reply a tick waits for.
enum Wait {
    /// Lockstep after the first reply: until one arrives (or the stall timeout).
    One,
    /// Until this wall-clock time; the latest reply counts.
    Until(Instant),
}

struct Session<'a> {
    server: &'a HilServer,
    number: u64,
    twin: Twin,
    sensors: SimulatedSensors,
    stream: TcpStream,
    decoder: Decoder,
    encoder: Encoder,
    counters: Counters,
    controls: VecDeque<(Frame, Instant)>,
    frames: Vec<HilFrame>,
    held_readings: HeldReadings,
    previous: Option<RigidBodyState>,
    command: ActuatorCommand,
    held: bool,
    lockstep: bool,
    tick: u64,
    stats: SessionStats,
    buffer: Vec<u8>,
}

impl<'a> Session<'a> {
    fn new(server: &'a HilServer, stream: TcpStream, number: u64) -> Result<Self, HilError> {
        let twin = Twin::new(server.vehicle.clone(), server.twin_config.clone())?;
        let sensors = SimulatedSensors::new(
            server.config.imu,
            PoseModel::default(),
            server.twin_config.control_rate_hz,
            server.twin_config.seed,
        )?
        .with_navigation(server.config.navigation)?;
        let truth = twin.truth();
        let command = ActuatorCommand {
            rotor_thrusts_n: vec![server.vehicle.rotors.thrust_min_n; server.vehicle.rotors.len()],
            joint_targets: truth.joint_positions.clone(),
            direct_wrench_in_body: None,
        };
        // Blocking reads with timeouts; small frames go out at once.
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_nodelay(true);
        Ok(Self {
            server,
            number,
            twin,
            sensors,
            stream,
            decoder: Decoder::new(None).keeping_bytes(true),
            encoder: Encoder::new(SYSTEM_ID, COMPONENT_ID, None),
            counters: Counters::default(),
            controls: VecDeque::new(),
            frames: Vec::new(),
            held_readings: HeldReadings::default(),
            previous: None,
            command,
            held: true,
            lockstep: false,
            tick: 0,
            stats: SessionStats::default(),
            buffer: vec![0; 4096],
        })
    }

    fn rate_hz(&self) -> f64 {
        self.server.twin_config.control_rate_hz
    }

    fn time_usec(&self, tick: u64) -> u64 {
        // Exact to the microsecond at any tick (no accumulated rounding).
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            clippy::cast_precision_loss
        )]
        let us = (tick as f64 * 1e6 / self.rate_hz()).round() as u64;
        us
    }

    fn time_s(&self) -> f64 {
        #[allow(clippy::cast_precision_loss)]
        let t = self.tick as f64 / self.rate_hz();
        t
    }

    fn run(
        &mut self,
        stop: &AtomicBool,
        observer: &mut dyn HilObserver,
        report: &mut impl FnMut(&HilEvent),
    ) -> SessionEnd {
        let period = Duration::from_secs_f64(1.0 / self.rate_hz());
        let started = Instant::now();
        loop {
            if stop.load(Ordering::SeqCst) {
                return SessionEnd::Stopped;
            }
            self.tick += 1;
            self.frames.clear();
            let time_s = self.time_s();
            let time_usec = self.time_usec(self.tick);
            let mut state = self.twin.truth().clone();
            state.time_s = time_s;
            if let Err(e) = self.send_sensors(&state, time_usec) {
                return SessionEnd::Disconnected(e);
            }
            let wait = match (self.server.config.mode, self.lockstep) {
                (Mode::Lockstep, true) => Wait::One,
                (Mode::Lockstep, false) => {
                    Wait::Until(Instant::now() + self.server.config.first_reply.unwrap_or(period))
                }
                #[allow(clippy::cast_possible_truncation)]
                (Mode::Realtime, _) => Wait::Until(started + period * (self.tick as u32)),
            };
            let reply = match self.await_reply(&wait, time_usec, stop) {
                Ok(r) => r,
                Err(end) => return end,
            };
            let mut controls = None;
            if let Some(data) = reply {
                if !self.lockstep
                    && self.server.config.mode == Mode::Lockstep
                    && data
                        .flags
                        .contains(HilActuatorControlsFlags::HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP)
                {
                    self.lockstep = true;
                    self.stats.lockstep_from_tick = self.tick;
                    report(&HilEvent::Lockstep { at_s: time_s });
                }
                if self.held && data.mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED) {
                    self.held = false;
                    report(&HilEvent::Armed { at_s: time_s });
                }
                let (command, mapped) = self.server.map.command(&data.controls, &self.command);
                self.stats.non_finite_controls += u64::from(mapped.non_finite);
                self.command = command;
                controls = Some(data.controls);
            }
            if !self.held {
                match self.twin.step(&self.command) {
                    Ok(_) => self.stats.steps += 1,
                    Err(e) => return SessionEnd::Diverged(e.to_string()),
                }
            }
            let mut after = self.twin.truth().clone();
            after.time_s = time_s + 1.0 / self.rate_hz();
            observer.tick(&HilTick {
                session: self.number,
                time_s,
                state: &state,
                after: &after,
                command: &self.command,
                controls,
                held: self.held,
                frames: &self.frames,
                twin: &self.twin,
            });
        }
    }

    fn send_sensors(&mut self, state: &Measurement, time_usec: u64) -> Result<(), String> {
        let dt = 1.0 / self.rate_hz();
        let readings = self.sensors.sample(state);
        // The noiseless IMU of the period (at rest on the first tick): ground truth.
        let previous = self.previous.replace(state.base).unwrap_or(state.base);
        let ideal = ideal_imu(&previous, &state.base, state.time_s, dt);
        let imu = readings.imu.unwrap_or(ideal);
        let nav = self.sensors.sample_navigation(state);
        let mut out = vec![MavMessage::HIL_SENSOR(messages::hil_sensor(
            time_usec,
            &imu,
            nav.magnetometer.as_ref(),
            nav.barometer.as_ref(),
            &mut self.held_readings,
        ))];
        self.stats.hil_sensor += 1;
        if let Some(fix) = &nav.gnss {
            out.push(MavMessage::HIL_GPS(messages::hil_gps(time_usec, fix)));
            self.stats.hil_gps += 1;
        }
        let force = ideal.specific_force_in_body_mps2;
        out.push(MavMessage::HIL_STATE_QUATERNION(
            messages::hil_state_quaternion(
                time_usec,
                state,
                &force,
                self.sensors.navigation().origin(),
            ),
        ));
        self.stats.hil_state_quaternion += 1;
        let mut bytes = Vec::new();
        for m in &out {
            let start = bytes.len();
            self.encoder.encode_into(m, &mut bytes);
            let frame = &bytes[start..];
            self.frames.push(HilFrame {
                direction: Direction::Out,
                at: Instant::now(),
                system_id: SYSTEM_ID,
                component_id: COMPONENT_ID,
                sequence: frame.get(4).copied().unwrap_or(0),
                message_id: m.message_id(),
                message_name: m.message_name(),
                bytes: frame.to_vec(),
            });
        }
        self.stream.write_all(&bytes).map_err(|e| e.to_string())
    }

    /// Reads until the tick's reply: the HIL_ACTUATOR_CONTROLS to apply (None: none came).
    fn await_reply(
        &mut self,
        wait: &Wait,
        time_usec: u64,
        stop: &AtomicBool,
    ) -> Result<Option<mavlink::dialects::common::HIL_ACTUATOR_CONTROLS_DATA>, SessionEnd> {
        let since = Instant::now();
        let mut latest = None;
        loop {
            while let Some((frame, at)) = self.controls.pop_front() {
                let MavMessage::HIL_ACTUATOR_CONTROLS(data) = &frame.message else {
                    continue;
                };
                let data = data.clone();
                // Sent before the HIL_SENSOR now awaiting a reply: left from before lockstep.
                if self.lockstep && data.time_usec < time_usec {
                    self.stats.stale_controls += 1;
                    continue;
                }
                self.stats.actuator_controls += 1;
                self.push_frame(Direction::In, &frame, at);
                match wait {
                    Wait::One => return Ok(Some(data)),
                    Wait::Until(_) => {
                        latest = Some(data);
                        // Before lockstep, a lockstep reply answers this tick at once.
                        if self.server.config.mode == Mode::Lockstep {
                            return Ok(latest);
                        }
                    }
                }
            }
            let now = Instant::now();
            let timeout = match wait {
                Wait::One => {
                    let waited = now.duration_since(since);
                    if waited >= self.server.config.stall_timeout {
                        return Err(SessionEnd::Stalled {
                            waited_ms: waited.as_millis(),
                        });
                    }
                    if stop.load(Ordering::SeqCst) {
                        return Err(SessionEnd::Stopped);
                    }
                    (self.server.config.stall_timeout - waited).min(Duration::from_millis(100))
                }
                Wait::Until(deadline) => {
                    if now >= *deadline {
                        return Ok(latest);
                    }
                    *deadline - now
                }
            };
            self.read_some(timeout.max(Duration::from_micros(100)))?;
        }
    }

    /// One read with `timeout`; decoded frames are queued (controls) or counted.
    fn read_some(&mut self, timeout: Duration) -> Result<(), SessionEnd> {
        let _ = self.stream.set_read_timeout(Some(timeout));
        match self.stream.read(&mut self.buffer) {
            Ok(0) => Err(SessionEnd::Disconnected("connection closed".to_owned())),
            Ok(n) => {
                let mut decoded = Vec::new();
                let bad_before = self.counters.snapshot().bad_frames();
                self.decoder
                    .push_stream(&self.buffer[..n], &self.counters, &mut decoded);
                self.stats.bad_frames += self.counters.snapshot().bad_frames() - bad_before;
                let at = Instant::now();
                for frame in decoded {
                    if matches!(frame.message, MavMessage::HIL_ACTUATOR_CONTROLS(_)) {
                        self.controls.push_back((frame, at));
                    } else {
                        self.stats.other_frames += 1;
                        self.push_frame(Direction::In, &frame, at);
                    }
                }
                Ok(())
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) =>
            {
                Ok(())
            }
            Err(e) => Err(SessionEnd::Disconnected(e.to_string())),
        }
    }

    fn push_frame(&mut self, direction: Direction, frame: &Frame, at: Instant) {
        self.frames.push(HilFrame {
            direction,
            at,
            system_id: u8::try_from(frame.header.system_id).unwrap_or(u8::MAX),
            component_id: frame.header.component_id,
            sequence: frame.header.sequence,
            message_id: frame.message.message_id(),
            message_name: frame.message.message_name(),
            bytes: frame.bytes.clone(),
        });
    }
}
