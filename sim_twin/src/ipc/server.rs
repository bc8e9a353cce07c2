//! The twin's server: `amstack twin serve`.

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use platform::{ActuatorCommand, Measurement, RigidBodyState, Vehicle};

use super::handshake::{Offer, check_hello};
use super::messages::{
    COMMAND_END_OF_SESSION, CommandMsg, Hello, ImuMsg, MEASUREMENT_FAILSAFE, MEASUREMENT_HOLDING,
    MEASUREMENT_SESSION_FAILED, MeasurementMsg, TaskMsg, TooLarge, Welcome, get_str, join_id,
    joint_role, put_str, split_id,
};
use super::wait::Waiter;
use super::{
    CommandService, HandshakeService, Ipc, IpcError, MeasurementService, cleanup_dead_nodes,
    cleanup_dead_nodes_now, command_service, handshake_service, measurement_service, node,
    node_alive,
};
use crate::sensors::ideal_imu;
use crate::{TaskId, Twin, TwinConfig, TwinError, TwinObserver};

/// How the twin's time advances.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// One control period per command, when the command for the current tick arrives.
    Lockstep,
    /// The wall clock at the control rate, with the latest command.
    Realtime,
}

impl Mode {
    /// `lockstep` or `realtime`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Lockstep => "lockstep",
            Self::Realtime => "realtime",
        }
    }
}

/// What the twin applies once a lost flight process's last command has been held for the
/// hold timeout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Failsafe {
    /// Flight termination: every rotor thrust command 0 N (the motor model's lower limit when
    /// limits are on), no direct wrench; the joints keep their last targets (the arm holds
    /// its pose, the gripper keeps what it holds). The vehicle falls and comes to rest on
    /// the ground — the only action that needs no controller, and the one a flight test
    /// must survive.
    #[default]
    Disarm,
}

impl Failsafe {
    /// The failsafe's command, from the last one held.
    pub fn command(self, held: &ActuatorCommand) -> ActuatorCommand {
        match self {
            Self::Disarm => ActuatorCommand {
                rotor_thrusts_n: vec![0.0; held.rotor_thrusts_n.len()],
                joint_targets: held.joint_targets.clone(),
                direct_wrench_in_body: None,
            },
        }
    }
}

/// How the server runs.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeConfig {
    /// Service name (`amstack/<service>/…`).
    pub service: String,
    /// Lockstep or realtime.
    pub mode: Mode,
    /// How long the last command of a lost flight process is held before the failsafe,
    /// counted from its arrival. Default 500 ms.
    pub hold: Duration,
    /// What follows the hold.
    pub failsafe: Failsafe,
    /// Lockstep: a flight process that is alive but sends nothing for this long counts as
    /// lost (a slow controller is waited for up to here). Default 5 s.
    pub stall_timeout: Duration,
    /// Simulated time the twin keeps running after the failsafe, so the vehicle comes to
    /// rest, s. Default 3.
    pub after_failsafe_s: f64,
    /// Return after this many sessions have ended (None: serve until stopped).
    pub max_sessions: Option<u64>,
    /// Each flight process chooses its session's episode — the task scene and the seed —
    /// in its hello (`amstack bench --link ipc` runs every rollout as a session); the rest
    /// of the configuration must still match. Off: the served `task` and `seed` must match.
    pub flight_chooses_episode: bool,
}

impl ServeConfig {
    /// Defaults for `service`.
    pub fn new(service: impl Into<String>, mode: Mode) -> Self {
        Self {
            service: service.into(),
            mode,
            hold: Duration::from_millis(500),
            failsafe: Failsafe::Disarm,
            stall_timeout: Duration::from_secs(5),
            after_failsafe_s: 3.0,
            max_sessions: None,
            flight_chooses_episode: false,
        }
    }
}

/// Why a flight process counts as lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loss {
    /// Its process is gone (its iceoryx2 node is dead).
    ProcessGone,
    /// It sent nothing for the stall (lockstep) or hold (realtime) timeout.
    Silent,
}

/// What the server reports as it runs (the CLI prints these).
#[derive(Debug, Clone, PartialEq)]
pub enum ServeEvent {
    /// Serving.
    Started {
        /// Service name.
        service: String,
        /// Vehicle id.
        vehicle: String,
        /// Lockstep or realtime.
        mode: Mode,
        /// Control rate, Hz.
        rate_hz: f64,
        /// Dead nodes of crashed processes whose resources were removed at start.
        stale_nodes_cleaned: u64,
    },
    /// A flight process was refused.
    Refused {
        /// Its process id.
        pid: u32,
        /// Why, naming both values.
        reason: String,
    },
    /// A session started (the twin was reset).
    SessionOpened {
        /// Session id.
        session: u64,
        /// The flight process id.
        pid: u32,
    },
    /// The flight process ended its session.
    SessionEnded {
        /// Session id.
        session: u64,
        /// Ticks simulated.
        ticks: u64,
        /// Simulated time, s.
        at_s: f64,
    },
    /// The flight process was lost; its last command is held.
    FlightLost {
        /// Session id.
        session: u64,
        /// Its process id.
        pid: u32,
        /// Why.
        why: Loss,
        /// Simulated time, s.
        at_s: f64,
        /// How long the last command is held, from its arrival.
        hold: Duration,
    },
    /// The failsafe is applied.
    FailsafeApplied {
        /// Session id.
        session: u64,
        /// Which failsafe.
        failsafe: Failsafe,
        /// Simulated time, s.
        at_s: f64,
        /// Base height, m.
        z_m: f64,
    },
    /// The twin could not step; the session ended.
    SessionFailed {
        /// Session id.
        session: u64,
        /// Simulated time, s.
        at_s: f64,
        /// The twin's error.
        error: String,
    },
    /// The twin stopped running after the failsafe.
    FailsafeSettled {
        /// Session id.
        session: u64,
        /// Simulated time, s.
        at_s: f64,
        /// Base height, m.
        z_m: f64,
        /// Base speed, m/s.
        speed_mps: f64,
    },
}

impl fmt::Display for ServeEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Started {
                service,
                vehicle,
                mode,
                rate_hz,
                stale_nodes_cleaned,
            } => write!(
                f,
                "serving {vehicle} on '{service}' ({}, {rate_hz} Hz); removed the resources of {stale_nodes_cleaned} dead process node(s)",
                mode.name()
            ),
            Self::Refused { pid, reason } => {
                write!(f, "refused flight process {pid}: {reason}")
            }
            Self::SessionOpened { session, pid } => write!(
                f,
                "session {session:x}: flight process {pid} connected; twin reset"
            ),
            Self::SessionEnded {
                session,
                ticks,
                at_s,
            } => write!(
                f,
                "session {session:x}: ended by the flight process after {ticks} ticks (t = {at_s:.3} s)"
            ),
            Self::FlightLost {
                session,
                pid,
                why,
                at_s,
                hold,
            } => write!(
                f,
                "session {session:x}: flight process {pid} lost at t = {at_s:.3} s ({}); holding its last command for {} ms",
                match why {
                    Loss::ProcessGone => "its process is gone",
                    Loss::Silent => "it stopped sending commands",
                },
                hold.as_millis()
            ),
            Self::FailsafeApplied {
                session,
                failsafe,
                at_s,
                z_m,
            } => write!(
                f,
                "session {session:x}: failsafe {} at t = {at_s:.3} s (base z = {z_m:.3} m)",
                match failsafe {
                    Failsafe::Disarm => "disarm (rotors 0 N, joints held)",
                }
            ),
            Self::SessionFailed {
                session,
                at_s,
                error,
            } => write!(
                f,
                "session {session:x}: the twin failed at t = {at_s:.3} s ({error}); session ended"
            ),
            Self::FailsafeSettled {
                session,
                at_s,
                z_m,
                speed_mps,
            } => write!(
                f,
                "session {session:x}: after the failsafe, t = {at_s:.3} s: base z = {z_m:.3} m, speed {speed_mps:.3} m/s; waiting for a flight process"
            ),
        }
    }
}

/// What a server run did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ServeSummary {
    /// Sessions ended (by the flight process, or lost and settled).
    pub sessions: u64,
    /// Flight processes refused.
    pub refused: u64,
}

/// The server cannot start or continue.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ServeError {
    /// iceoryx2 failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// The twin cannot be built or stepped.
    #[error(transparent)]
    Twin(#[from] TwinError),
    /// The vehicle does not fit the wire.
    #[error(transparent)]
    TooLarge(#[from] TooLarge),
    /// Another twin already serves this name.
    #[error("another twin already serves '{0}' (stop it, or pick another --ipc name)")]
    Taken(String),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// No session: time stands still.
    Idle,
    /// A flight process flies.
    Flying,
    /// The flight process is lost: the last command is held, then the failsafe.
    Lost {
        /// When the failsafe started (simulated time), once it has.
        failsafe_at_s: Option<f64>,
    },
}

#[derive(Debug)]
struct Session {
    id: u64,
    pid: u32,
    flight_node: u128,
    tick: u64,
    held: ActuatorCommand,
    /// Arrival of the last command (or the session's start).
    last_command: Instant,
    last_liveness_check: Instant,
    /// Realtime (and lost): the wall-clock time of the next step, once the clock runs.
    next_step: Option<Instant>,
}

/// The twin served over iceoryx2 (see the module documentation for the protocol).
pub struct TwinServer {
    twin: Twin,
    config: ServeConfig,
    offer: Offer,
    joint_roles: [u8; super::MAX_JOINTS],
    seed: u64,
    // Ports before services before the node: fields drop in declaration order.
    handshake: Server<Ipc, Hello, (), Welcome, ()>,
    commands: Subscriber<Ipc, CommandMsg, ()>,
    measurements: Publisher<Ipc, MeasurementMsg, ()>,
    _services: (HandshakeService, CommandService, MeasurementService),
    node: Node<Ipc>,
    stale_nodes_cleaned: u64,
    session: Option<Session>,
    phase: Phase,
    next_session: u64,
    /// The base at the previous measurement: the IMU's period starts there.
    previous_base: RigidBodyState,
    /// The measurement handed out last (with observation noise when on).
    observed: Measurement,
    summary: ServeSummary,
    /// Hears every reset and step (the live view of `twin serve --live`).
    observer: Option<Box<dyn TwinObserver>>,
}

impl fmt::Debug for TwinServer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TwinServer")
            .field("config", &self.config)
            .field("vehicle", &self.offer.vehicle_id)
            .field("phase", &self.phase)
            .finish_non_exhaustive()
    }
}

/// The task and seed a flight process asks for in its hello's configuration.
fn episode_of(hello: &Hello) -> Option<(Option<TaskId>, u64)> {
    let json = get_str(&hello.config_json, hello.config_len);
    let config: TwinConfig = serde_json::from_str(&json).ok()?;
    Some((config.task, config.seed))
}

/// How often the flight process's node is looked at while no command comes.
const LIVENESS_PERIOD: Duration = Duration::from_millis(20);

impl TwinServer {
    /// Builds the twin and opens the services (removing what crashed processes left).
    pub fn new(
        vehicle: Vehicle,
        twin_config: TwinConfig,
        config: ServeConfig,
    ) -> Result<Self, ServeError> {
        let offer = Offer::new(&vehicle, &twin_config)?;
        let joint_roles = joint_roles(&vehicle);
        let seed = twin_config.seed;
        let twin = Twin::new(vehicle, twin_config)?;
        // Before this process's node exists: creating it would clean silently.
        let stale_nodes_cleaned = cleanup_dead_nodes_now();
        let node = node("amstack-twin")?;
        let handshake_svc = handshake_service(&node, &config.service)?;
        let command_svc = command_service(&node, &config.service)?;
        let measurement_svc = measurement_service(&node, &config.service)?;
        let measurements = match measurement_svc.publisher_builder().create() {
            Ok(p) => p,
            Err(PublisherCreateError::ExceedsMaxSupportedPublishers) => {
                return Err(ServeError::Taken(config.service.clone()));
            }
            Err(e) => return Err(IpcError::new("creating the measurement publisher", e).into()),
        };
        let handshake = handshake_svc
            .server_builder()
            .create()
            .map_err(|_| ServeError::Taken(config.service.clone()))?;
        let commands = command_svc
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::new("creating the command subscriber", e))?;
        let previous_base = twin.truth().base;
        let observed = twin.truth().clone();
        Ok(Self {
            twin,
            offer,
            joint_roles,
            seed,
            handshake,
            commands,
            measurements,
            _services: (handshake_svc, command_svc, measurement_svc),
            node,
            stale_nodes_cleaned,
            session: None,
            phase: Phase::Idle,
            next_session: u64::from(std::process::id()) << 32,
            previous_base,
            observed,
            summary: ServeSummary::default(),
            observer: None,
            config,
        })
    }

    /// Shows every session's reset and every step to `observer` from now on (told of the
    /// twin's current state at once).
    pub fn set_observer(&mut self, mut observer: Box<dyn TwinObserver>) {
        observer.reset(&self.twin);
        self.observer = Some(observer);
    }

    /// The twin served.
    pub fn twin(&self) -> &Twin {
        &self.twin
    }

    /// Serves until `stop` is set or `max_sessions` have ended; `on_event` hears every
    /// session's start, end, loss and failsafe.
    pub fn run(
        &mut self,
        stop: &AtomicBool,
        mut on_event: impl FnMut(&ServeEvent),
    ) -> Result<ServeSummary, ServeError> {
        on_event(&ServeEvent::Started {
            service: self.config.service.clone(),
            vehicle: self.offer.vehicle_id.clone(),
            mode: self.config.mode,
            rate_hz: self.offer.control_rate_hz,
            stale_nodes_cleaned: self.stale_nodes_cleaned,
        });
        let mut waiter = Waiter::start();
        while !stop.load(Ordering::Relaxed) {
            if self
                .config
                .max_sessions
                .is_some_and(|n| self.summary.sessions >= n)
            {
                break;
            }
            let mut busy = self.poll_handshake(&mut on_event)?;
            busy |= match self.phase {
                Phase::Idle => false,
                Phase::Flying => match self.config.mode {
                    Mode::Lockstep => self.lockstep(&mut on_event)?,
                    Mode::Realtime => self.realtime(&mut on_event)?,
                },
                Phase::Lost { failsafe_at_s } => self.lost(failsafe_at_s, &mut on_event)?,
            };
            if busy {
                waiter = Waiter::start();
            } else if self.phase == Phase::Idle {
                // Nobody connected: look for one every millisecond.
                std::thread::sleep(Duration::from_millis(1));
            } else {
                waiter.pause();
            }
        }
        Ok(self.summary)
    }

    /// Answers hellos; true when one was handled.
    fn poll_handshake(
        &mut self,
        on_event: &mut impl FnMut(&ServeEvent),
    ) -> Result<bool, ServeError> {
        let mut handled = false;
        while let Some(request) = self
            .handshake
            .receive()
            .map_err(|e| IpcError::new("receiving a handshake", e))?
        {
            handled = true;
            let hello = *request.payload();
            let mut welcome = self.welcome();
            let verdict = check_hello(&hello, &self.offer, self.config.flight_chooses_episode)
                .and_then(|()| self.busy(&hello));
            match verdict {
                Err(reason) => {
                    welcome.reason_len = put_str(&mut welcome.reason, &reason);
                    self.summary.refused += 1;
                    on_event(&ServeEvent::Refused {
                        pid: hello.pid,
                        reason,
                    });
                    request
                        .send_copy(welcome)
                        .map_err(|e| IpcError::new("answering a handshake", e))?;
                }
                Ok(()) => {
                    if self.session.is_some() {
                        // A lost session is replaced by the new connection.
                        self.summary.sessions += 1;
                    }
                    let session = self.open_session(&hello)?;
                    welcome.accepted = 1;
                    welcome.session = session;
                    request
                        .send_copy(welcome)
                        .map_err(|e| IpcError::new("answering a handshake", e))?;
                    on_event(&ServeEvent::SessionOpened {
                        session,
                        pid: hello.pid,
                    });
                    self.publish(Instant::now())?;
                }
            }
        }
        Ok(handled)
    }

    /// Refuses a second live flight process while one flies.
    fn busy(&self, hello: &Hello) -> Result<(), String> {
        match (&self.session, self.phase) {
            (Some(s), Phase::Flying)
                if s.flight_node != join_id(hello.node_id)
                    && node_alive(s.flight_node) != Some(false) =>
            {
                Err(format!(
                    "busy: flight process {} flies session {:x} (one flight process at a time)",
                    s.pid, s.id
                ))
            }
            _ => Ok(()),
        }
    }

    fn welcome(&self) -> Welcome {
        let mut w = Welcome {
            node_id: split_id(self.node.id().value()),
            pid: std::process::id(),
            mode: match self.config.mode {
                Mode::Lockstep => 0,
                Mode::Realtime => 1,
            },
            control_rate_hz: self.offer.control_rate_hz,
            vehicle_hash: self.offer.vehicle_hash,
            config_hash: self.offer.config_hash,
            rotor_count: self.offer.rotor_count as u32,
            joint_count: self.offer.joint_count as u32,
            joint_roles: self.joint_roles,
            ..Welcome::default()
        };
        w.id_len = put_str(&mut w.vehicle_id, &self.offer.vehicle_id);
        w
    }

    fn open_session(&mut self, hello: &Hello) -> Result<u64, ServeError> {
        match self.config.flight_chooses_episode {
            // The hello passed the check, so its configuration parses.
            true => match episode_of(hello) {
                Some((task, seed)) => self.twin.reset_episode(task, seed)?,
                None => self.twin.reset(self.seed)?,
            },
            false => self.twin.reset(self.seed)?,
        }
        if let Some(o) = &mut self.observer {
            o.reset(&self.twin);
        }
        self.previous_base = self.twin.truth().base;
        // As the in-process link: the state at the start is the exact one.
        self.observed = self.twin.truth().clone();
        // Commands of earlier sessions still queued are stale.
        while let Ok(Some(_)) = self.commands.receive() {}
        self.next_session += 1;
        let now = Instant::now();
        let held = ActuatorCommand {
            rotor_thrusts_n: vec![0.0; self.offer.rotor_count],
            joint_targets: self.twin.vehicle().initial_configuration(),
            direct_wrench_in_body: None,
        };
        self.session = Some(Session {
            id: self.next_session,
            pid: hello.pid,
            flight_node: join_id(hello.node_id),
            tick: 0,
            held,
            last_command: now,
            last_liveness_check: now,
            next_step: None,
        });
        self.phase = Phase::Flying;
        Ok(self.next_session)
    }

    /// The newest command of the session (and whether the session ended), draining the
    /// queue. In lockstep, only the command for the current tick counts.
    fn take_commands(&mut self) -> Result<(Option<CommandMsg>, bool), ServeError> {
        let Some(session) = &self.session else {
            return Ok((None, false));
        };
        let mut newest = None;
        let mut ended = false;
        loop {
            let sample = self
                .commands
                .receive()
                .map_err(|e| IpcError::new("receiving a command", e))?;
            let Some(sample) = sample else { break };
            let msg = *sample.payload();
            if msg.session != session.id {
                continue;
            }
            if msg.flags & COMMAND_END_OF_SESSION != 0 {
                ended = true;
                continue;
            }
            let wanted = match self.config.mode {
                Mode::Lockstep => msg.tick == session.tick,
                Mode::Realtime => true,
            };
            if wanted {
                newest = Some(msg);
                if self.config.mode == Mode::Lockstep {
                    break;
                }
            }
        }
        Ok((newest, ended))
    }

    fn end_session(&mut self, on_event: &mut impl FnMut(&ServeEvent)) {
        if let Some(s) = self.session.take() {
            on_event(&ServeEvent::SessionEnded {
                session: s.id,
                ticks: s.tick,
                at_s: self.twin.time_s(),
            });
        }
        self.summary.sessions += 1;
        self.phase = Phase::Idle;
    }

    /// Lockstep: step once when the command for the current tick is there.
    fn lockstep(&mut self, on_event: &mut impl FnMut(&ServeEvent)) -> Result<bool, ServeError> {
        let (command, ended) = self.take_commands()?;
        if let Some(msg) = command {
            let arrived = Instant::now();
            let command = msg.to_command();
            match self.twin.step(&command) {
                Ok(m) => self.observed = m,
                Err(e) => {
                    self.fail_session(&e, on_event)?;
                    return Ok(true);
                }
            }
            if let Some(o) = &mut self.observer {
                o.stepped(&self.twin, &command);
            }
            if let Some(s) = &mut self.session {
                s.tick += 1;
                s.held = command;
                s.last_command = arrived;
                s.last_liveness_check = arrived;
            }
            self.publish(arrived)?;
            return Ok(true);
        }
        if ended {
            self.end_session(on_event);
            return Ok(true);
        }
        self.check_flight(self.config.stall_timeout, on_event);
        Ok(false)
    }

    /// Realtime: take the latest command; step when the clock says so.
    fn realtime(&mut self, on_event: &mut impl FnMut(&ServeEvent)) -> Result<bool, ServeError> {
        let (command, ended) = self.take_commands()?;
        let now = Instant::now();
        let period = Duration::from_secs_f64(1.0 / self.offer.control_rate_hz);
        let Some(s) = &mut self.session else {
            return Ok(false);
        };
        if let Some(msg) = command {
            s.held = msg.to_command();
            s.last_command = now;
            s.last_liveness_check = now;
            // The clock starts with the first command.
            s.next_step.get_or_insert(now);
        }
        if ended {
            self.end_session(on_event);
            return Ok(true);
        }
        let due = s.next_step.is_some_and(|t| now >= t);
        if due {
            self.step_on_clock(now, period, None, on_event)?;
            return Ok(true);
        }
        self.check_flight(self.config.hold, on_event);
        Ok(command.is_some())
    }

    /// Looks at the flight process: lost when its node is dead or it has been silent for
    /// `silence`.
    fn check_flight(&mut self, silence: Duration, on_event: &mut impl FnMut(&ServeEvent)) {
        let Some(s) = &mut self.session else { return };
        let now = Instant::now();
        if now.duration_since(s.last_liveness_check) < LIVENESS_PERIOD {
            return;
        }
        s.last_liveness_check = now;
        let why = if node_alive(s.flight_node) == Some(false) {
            Loss::ProcessGone
        } else if now.duration_since(s.last_command) >= silence {
            Loss::Silent
        } else {
            return;
        };
        // From here on the wall clock drives the twin.
        s.next_step.get_or_insert(now);
        self.phase = Phase::Lost {
            failsafe_at_s: None,
        };
        on_event(&ServeEvent::FlightLost {
            session: s.id,
            pid: s.pid,
            why,
            at_s: self.twin.time_s(),
            hold: self.config.hold,
        });
        // The process's ports and shared memory are of no use to anyone now.
        if why == Loss::ProcessGone {
            cleanup_dead_nodes(&self.node);
        }
    }

    /// Lost: the held command on the wall clock until the hold has passed, then the failsafe
    /// until the vehicle has had time to come to rest.
    fn lost(
        &mut self,
        failsafe_at_s: Option<f64>,
        on_event: &mut impl FnMut(&ServeEvent),
    ) -> Result<bool, ServeError> {
        let now = Instant::now();
        let period = Duration::from_secs_f64(1.0 / self.offer.control_rate_hz);
        let Some(s) = &mut self.session else {
            self.phase = Phase::Idle;
            return Ok(false);
        };
        if s.next_step.is_none_or(|t| now < t) {
            return Ok(false);
        }
        let mut failsafe_at_s = failsafe_at_s;
        if failsafe_at_s.is_none() && now.duration_since(s.last_command) >= self.config.hold {
            s.held = self.config.failsafe.command(&s.held);
            let at_s = self.twin.time_s();
            failsafe_at_s = Some(at_s);
            self.phase = Phase::Lost { failsafe_at_s };
            on_event(&ServeEvent::FailsafeApplied {
                session: s.id,
                failsafe: self.config.failsafe,
                at_s,
                z_m: self.twin.truth().base.position_in_world_m.z,
            });
        }
        let flags = if failsafe_at_s.is_some() {
            MEASUREMENT_FAILSAFE
        } else {
            MEASUREMENT_HOLDING
        };
        self.step_on_clock(now, period, Some(flags), on_event)?;
        if let Some(at) = failsafe_at_s
            && self.twin.time_s() - at >= self.config.after_failsafe_s
        {
            let base = &self.twin.truth().base;
            let session = self.session.as_ref().map_or(0, |s| s.id);
            on_event(&ServeEvent::FailsafeSettled {
                session,
                at_s: self.twin.time_s(),
                z_m: base.position_in_world_m.z,
                speed_mps: base.velocity_in_world_mps.norm(),
            });
            self.session = None;
            self.summary.sessions += 1;
            self.phase = Phase::Idle;
        }
        Ok(true)
    }

    /// One step with the held command, the next one a period later (or a period from now
    /// when the twin fell behind).
    fn step_on_clock(
        &mut self,
        now: Instant,
        period: Duration,
        flags: Option<u32>,
        on_event: &mut impl FnMut(&ServeEvent),
    ) -> Result<(), ServeError> {
        let Some(s) = &mut self.session else {
            return Ok(());
        };
        let command = s.held.clone();
        let next = s.next_step.map_or(now, |t| t + period);
        s.next_step = Some(if next < now { now + period } else { next });
        s.tick += 1;
        match self.twin.step(&command) {
            Ok(m) => self.observed = m,
            Err(e) => return self.fail_session(&e, on_event),
        }
        if let Some(o) = &mut self.observer {
            o.stepped(&self.twin, &command);
        }
        self.publish_with(now, flags.unwrap_or(0))
    }

    /// The twin refused to step (a diverged simulation, a bad command): the flight process
    /// is told with a last measurement flagged [`MEASUREMENT_SESSION_FAILED`], the session
    /// ends, and the server goes on serving.
    fn fail_session(
        &mut self,
        error: &TwinError,
        on_event: &mut impl FnMut(&ServeEvent),
    ) -> Result<(), ServeError> {
        if let Some(s) = &mut self.session {
            s.tick += 1;
        }
        self.publish_with(Instant::now(), MEASUREMENT_SESSION_FAILED)?;
        if let Some(s) = self.session.take() {
            on_event(&ServeEvent::SessionFailed {
                session: s.id,
                at_s: self.twin.time_s(),
                error: error.to_string(),
            });
        }
        self.summary.sessions += 1;
        self.phase = Phase::Idle;
        Ok(())
    }

    fn publish(&mut self, started: Instant) -> Result<(), ServeError> {
        self.publish_with(started, 0)
    }

    /// Publishes the current measurement (the observed one, with the IMU from the truth).
    fn publish_with(&mut self, started: Instant, flags: u32) -> Result<(), ServeError> {
        let Some(s) = &self.session else {
            return Ok(());
        };
        let mut msg = MeasurementMsg::from_measurement(&self.observed)?;
        msg.session = s.id;
        msg.tick = s.tick;
        msg.flags = flags;
        let truth = self.twin.truth();
        msg.imu = self.imu(truth);
        msg.gripper_opening = gripper_opening(self.twin.vehicle(), truth);
        msg.task = TaskMsg::from_snapshot(self.twin.task_snapshot().as_ref())?;
        self.previous_base = truth.base;
        msg.twin_busy_ns = started.elapsed().as_nanos() as u64;
        let sample = self
            .measurements
            .loan_uninit()
            .map_err(|e| IpcError::new("loaning a measurement sample", e))?;
        sample
            .write_payload(msg)
            .send()
            .map_err(|e| IpcError::new("publishing a measurement", e))?;
        Ok(())
    }

    /// The IMU over the last period ([`crate::sensors::ideal_imu`], as the flight stack's
    /// simulated IMU reads it, without noise).
    fn imu(&self, truth: &Measurement) -> ImuMsg {
        let dt = 1.0 / self.offer.control_rate_hz;
        let s = ideal_imu(&self.previous_base, &truth.base, truth.time_s, dt);
        let (f, w) = (
            s.specific_force_in_body_mps2,
            s.angular_velocity_in_body_radps,
        );
        ImuMsg {
            specific_force_in_body_mps2: [f.x, f.y, f.z],
            angular_velocity_in_body_radps: [w.x, w.y, w.z],
        }
    }
}

/// The role of each movable joint, configuration order.
fn joint_roles(vehicle: &Vehicle) -> [u8; super::MAX_JOINTS] {
    let mut roles = [joint_role::OTHER; super::MAX_JOINTS];
    let dof = |j: usize| vehicle.model.joints.get(j).and_then(|joint| joint.dof);
    let mut set = |d: Option<usize>, role: u8| {
        if let Some(r) = d.and_then(|d| roles.get_mut(d)) {
            *r = role;
        }
    };
    for d in vehicle.arm_dofs() {
        set(Some(d), joint_role::ARM);
    }
    if let Some(g) = &vehicle.gripper {
        for &j in &g.joints {
            set(dof(j), joint_role::GRIPPER);
        }
    }
    for r in &vehicle.rotors.rotors {
        if let Some(t) = &r.tilt {
            set(
                vehicle.model.joint_id(&t.joint).and_then(dof),
                joint_role::TILT,
            );
        }
    }
    roles
}

/// The gripper's opening in [−1, 1] from its finger positions (mean over the fingers);
/// NaN without a gripper.
fn gripper_opening(vehicle: &Vehicle, m: &Measurement) -> f64 {
    let Some(g) = &vehicle.gripper else {
        return f64::NAN;
    };
    let openings: Vec<f64> = g
        .joints
        .iter()
        .zip(g.closed.iter().zip(&g.open))
        .filter_map(|(&j, (&c, &o))| {
            let d = vehicle.model.joints.get(j)?.dof?;
            let q = *m.joint_positions.get(d)?;
            ((o - c).abs() > f64::EPSILON).then(|| 2.0 * (q - c) / (o - c) - 1.0)
        })
        .collect();
    if openings.is_empty() {
        f64::NAN
    } else {
        openings.iter().sum::<f64>() / openings.len() as f64
    }
}
