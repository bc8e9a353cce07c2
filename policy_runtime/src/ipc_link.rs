//! The twin in another process over iceoryx2 shared memory: the flight side of
//! [`sim_twin::ipc`] (protocol, services and faults are described there).
//!
//! [`IpcLink::connect`] subscribes to the twin's measurements, sends the handshake and waits
//! for the state at the session's start. Each [`Link::send`] publishes one command answering
//! the latest measurement; the next [`Link::receive`] waits for the twin's answer with a
//! deadline (50 ms by default) and, while it waits, looks at the twin's iceoryx2 node, so a
//! killed twin is reported within milliseconds and a hung one at the deadline. Dropping the
//! link ends the session (the twin does not apply its failsafe).

use std::fmt;
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use platform::{Measurement, Vehicle};
use sim_twin::ipc::{
    COMMAND_END_OF_SESSION, CommandMsg, CommandService, Hello, ImuMsg, Ipc, IpcError,
    MEASUREMENT_SESSION_FAILED, MeasurementMsg, MeasurementService, Mode, Offer, TooLarge, Waiter,
    Welcome, cleanup_dead_nodes_now, command_service, get_str, handshake_service, join_id,
    measurement_service, node, node_alive, split_id,
};
use sim_twin::{TaskSnapshot, TwinConfig};

use crate::link::{Link, LinkError, Setpoint};

/// How the flight side connects and waits.
#[derive(Debug, Clone, PartialEq)]
pub struct IpcLinkConfig {
    /// The twin's service name (`amstack twin serve --ipc <service>`).
    pub service: String,
    /// How long each answer of the twin may take before the twin counts as silent (the
    /// flight then stops). Default 50 ms.
    pub answer_timeout: Duration,
    /// How long to wait for a twin to answer the handshake. Default 10 s.
    pub connect_timeout: Duration,
    /// Keep every tick's round trip ([`IpcLink::timings`]).
    pub record_timing: bool,
}

impl IpcLinkConfig {
    /// Defaults for `service`.
    pub fn new(service: impl Into<String>) -> Self {
        Self {
            service: service.into(),
            answer_timeout: Duration::from_millis(50),
            connect_timeout: Duration::from_secs(10),
            record_timing: false,
        }
    }
}

/// What can go wrong on the iceoryx2 link.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IpcLinkError {
    /// No twin answered the handshake.
    #[error(
        "no twin answered on '{service}' within {waited_ms} ms (start one with: amstack twin serve --ipc {service} ...)"
    )]
    NoTwin {
        /// Service name.
        service: String,
        /// How long the flight waited, ms.
        waited_ms: u64,
    },
    /// The twin refused the handshake.
    #[error("the twin on '{service}' refused this flight: {reason}")]
    Refused {
        /// Service name.
        service: String,
        /// The twin's reason, naming both values.
        reason: String,
    },
    /// The twin stopped answering.
    #[error(
        "the twin on '{service}' stopped answering: {} (no measurement for tick {tick}, {waited_ms:.1} ms after the command; deadline {deadline_ms} ms)",
        if *process_gone { "its process is gone" } else { "no answer before the deadline" }
    )]
    TwinSilent {
        /// Service name.
        service: String,
        /// The tick whose answer never came.
        tick: u64,
        /// Time from sending the command to noticing, ms.
        waited_ms: f64,
        /// The deadline, ms.
        deadline_ms: u64,
        /// The twin's node was found dead (rather than the deadline passing).
        process_gone: bool,
    },
    /// The twin could not step (its simulation diverged, say) and ended the session.
    #[error(
        "the twin on '{service}' failed at t = {at_s:.3} s and ended the session (its log says why)"
    )]
    TwinFailed {
        /// Service name.
        service: String,
        /// Simulated time of the last good step, s.
        at_s: f64,
    },
    /// iceoryx2 failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// The vehicle or a command does not fit the wire.
    #[error(transparent)]
    TooLarge(#[from] TooLarge),
}

impl From<IpcLinkError> for LinkError {
    fn from(e: IpcLinkError) -> Self {
        let text = e.to_string();
        match e {
            IpcLinkError::Refused { .. } | IpcLinkError::TooLarge(_) => LinkError::Refused(text),
            IpcLinkError::NoTwin { .. } | IpcLinkError::TwinSilent { .. } => {
                LinkError::Silent(text)
            }
            // The twin could not step (its simulation diverged) and ended the session.
            IpcLinkError::TwinFailed { .. } => LinkError::Diverged(text),
            IpcLinkError::Ipc(_) => LinkError::Failed(text),
        }
    }
}

/// One tick's timing, seen from the flight process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TickTiming {
    /// From publishing the command to holding the answer, ns.
    pub round_trip_ns: u64,
    /// Of which the twin spent stepping and encoding, ns (as the twin reports it).
    pub twin_busy_ns: u64,
}

/// The flight side of the twin's iceoryx2 services.
pub struct IpcLink {
    config: IpcLinkConfig,
    // Ports before services before the node: fields drop in declaration order.
    commands: Publisher<Ipc, CommandMsg, ()>,
    measurements: Subscriber<Ipc, MeasurementMsg, ()>,
    _services: (CommandService, MeasurementService),
    _node: Node<Ipc>,
    session: u64,
    mode: Mode,
    twin_node: u128,
    twin_pid: u32,
    latest: MeasurementMsg,
    /// The command sent and not yet answered: its tick and when it left.
    pending: Option<(u64, Instant)>,
    timings: Vec<TickTiming>,
    stale_nodes_cleaned: u64,
}

impl fmt::Debug for IpcLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("IpcLink")
            .field("config", &self.config)
            .field("session", &self.session)
            .field("mode", &self.mode)
            .field("twin_pid", &self.twin_pid)
            .field("tick", &self.latest.tick)
            .finish_non_exhaustive()
    }
}

/// How often the twin's node is looked at while an answer is late.
const LIVENESS_PERIOD: Duration = Duration::from_millis(5);
/// How long the twin may take to reset and publish the state at a session's start.
const FIRST_MEASUREMENT_TIMEOUT: Duration = Duration::from_secs(5);

impl IpcLink {
    /// Connects to the twin on `config.service`, offering to fly `vehicle` in a twin
    /// configured as `twin` (the twin refuses any mismatch, naming both values).
    pub fn connect(
        vehicle: &Vehicle,
        twin: &TwinConfig,
        config: IpcLinkConfig,
    ) -> Result<Self, IpcLinkError> {
        let offer = Offer::new(vehicle, twin)?;
        // Before this process's node exists: creating it would clean silently.
        let stale_nodes_cleaned = cleanup_dead_nodes_now();
        let node = node("amstack-fly")?;
        let measurement_svc = measurement_service(&node, &config.service)?;
        let command_svc = command_service(&node, &config.service)?;
        let handshake_svc = handshake_service(&node, &config.service)?;
        // Subscribe before saying hello: the state at the session's start must not be missed.
        let measurements = measurement_svc
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::new("creating the measurement subscriber", e))?;
        let commands = command_svc
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::new("creating the command publisher", e))?;
        let client = handshake_svc
            .client_builder()
            .create()
            .map_err(|e| IpcError::new("creating the handshake client", e))?;
        let hello = offer.hello(std::process::id(), split_id(node.id().value()));
        let welcome = handshake(&client, &hello, &config)?;
        if welcome.accepted == 0 {
            return Err(IpcLinkError::Refused {
                service: config.service.clone(),
                reason: get_str(&welcome.reason, welcome.reason_len),
            });
        }
        let mut link = Self {
            commands,
            measurements,
            _services: (command_svc, measurement_svc),
            _node: node,
            session: welcome.session,
            mode: if welcome.mode == 1 {
                Mode::Realtime
            } else {
                Mode::Lockstep
            },
            twin_node: join_id(welcome.node_id),
            twin_pid: welcome.pid,
            latest: MeasurementMsg::default(),
            pending: None,
            timings: Vec::new(),
            stale_nodes_cleaned,
            config,
        };
        link.await_measurement(None, FIRST_MEASUREMENT_TIMEOUT)?;
        Ok(link)
    }

    /// Lockstep or realtime, as the twin serves.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The session id the twin gave.
    pub fn session(&self) -> u64 {
        self.session
    }

    /// The twin process's id.
    pub fn twin_pid(&self) -> u32 {
        self.twin_pid
    }

    /// The simulated IMU of the latest measurement.
    pub fn imu(&self) -> ImuMsg {
        self.latest.imu
    }

    /// The task scene of the latest measurement (None without a task).
    pub fn task(&self) -> Option<TaskSnapshot> {
        self.latest.task.to_snapshot()
    }

    /// The gripper opening of the latest measurement ([−1, 1]; NaN without a gripper).
    pub fn gripper_opening(&self) -> f64 {
        self.latest.gripper_opening
    }

    /// Every tick's timing so far (with `record_timing`).
    pub fn timings(&self) -> &[TickTiming] {
        &self.timings
    }

    /// Dead nodes of crashed processes whose resources were removed at connect.
    pub fn stale_nodes_cleaned(&self) -> u64 {
        self.stale_nodes_cleaned
    }

    /// Waits for a measurement of this session newer than `after` (any, for `None`): the
    /// newest one queued. Fails when `timeout` passes or the twin's node dies first.
    fn await_measurement(
        &mut self,
        after: Option<u64>,
        timeout: Duration,
    ) -> Result<(), IpcLinkError> {
        let waiter = Waiter::start();
        let mut next_check = LIVENESS_PERIOD;
        loop {
            let mut found = false;
            while let Some(sample) = self
                .measurements
                .receive()
                .map_err(|e| IpcError::new("receiving a measurement", e))?
            {
                let m = sample.payload();
                if m.session == self.session && m.flags & MEASUREMENT_SESSION_FAILED != 0 {
                    return Err(IpcLinkError::TwinFailed {
                        service: self.config.service.clone(),
                        at_s: m.time_s,
                    });
                }
                if m.session == self.session && after.is_none_or(|t| m.tick > t) {
                    self.latest = *m;
                    found = true;
                }
            }
            if found {
                return Ok(());
            }
            let waited = waiter.elapsed();
            let gone = waited >= next_check && {
                next_check = waited + LIVENESS_PERIOD;
                node_alive(self.twin_node) == Some(false)
            };
            if gone || waited >= timeout {
                return Err(IpcLinkError::TwinSilent {
                    service: self.config.service.clone(),
                    tick: after.map_or(0, |t| t + 1),
                    waited_ms: self
                        .pending
                        .map_or(waited, |(_, sent)| sent.elapsed())
                        .as_secs_f64()
                        * 1e3,
                    deadline_ms: timeout.as_millis() as u64,
                    process_gone: gone,
                });
            }
            waiter.pause();
        }
    }
}

/// Sends `hello` until a twin answers or the connect timeout passes. A hello that reached
/// a twin is never sent twice (each accepted hello opens a session).
fn handshake(
    client: &iceoryx2::port::client::Client<Ipc, Hello, (), Welcome, ()>,
    hello: &Hello,
    config: &IpcLinkConfig,
) -> Result<Welcome, IpcLinkError> {
    let started = Instant::now();
    let receive_error = |e| IpcError::new("receiving the handshake answer", e);
    while started.elapsed() < config.connect_timeout {
        let pending = client
            .send_copy(*hello)
            .map_err(|e| IpcError::new("sending the handshake", e))?;
        if pending.number_of_server_connections() == 0 {
            // No twin yet: it may be starting.
            drop(pending);
            std::thread::sleep(Duration::from_millis(20));
            continue;
        }
        while started.elapsed() < config.connect_timeout {
            if let Some(response) = pending.receive().map_err(receive_error)? {
                return Ok(*response.payload());
            }
            // The twin answers and lets go of the request at once: read once more after it
            // let go, then give up on this hello (a twin that died while answering).
            if !pending.is_connected() {
                if let Some(response) = pending.receive().map_err(receive_error)? {
                    return Ok(*response.payload());
                }
                break;
            }
            std::thread::sleep(Duration::from_micros(100));
        }
    }
    Err(IpcLinkError::NoTwin {
        service: config.service.clone(),
        waited_ms: started.elapsed().as_millis() as u64,
    })
}

impl Link for IpcLink {
    fn receive(&mut self) -> Result<Measurement, LinkError> {
        if let Some((tick, sent)) = self.pending {
            self.await_measurement(Some(tick), self.config.answer_timeout)?;
            if self.config.record_timing {
                self.timings.push(TickTiming {
                    round_trip_ns: sent.elapsed().as_nanos() as u64,
                    twin_busy_ns: self.latest.twin_busy_ns,
                });
            }
            self.pending = None;
        }
        Ok(self.latest.to_measurement())
    }

    fn send(&mut self, setpoint: &Setpoint) -> Result<(), LinkError> {
        let Setpoint::Actuators(command) = setpoint else {
            return Err(LinkError::Refused(format!(
                "the twin over iceoryx2 flies actuator setpoints, not {} ones",
                setpoint.level().name()
            )));
        };
        let msg = CommandMsg::from_command(command, self.session, self.latest.tick)
            .map_err(IpcLinkError::from)?;
        let sent = Instant::now();
        self.commands
            .send_copy(msg)
            .map_err(|e| IpcLinkError::from(IpcError::new("publishing a command", e)))?;
        self.pending = Some((self.latest.tick, sent));
        Ok(())
    }

    fn name(&self) -> String {
        format!("ipc:{}", self.config.service)
    }

    fn task(&self) -> Option<TaskSnapshot> {
        IpcLink::task(self)
    }
}

impl Drop for IpcLink {
    fn drop(&mut self) {
        // Ends the session so the twin waits for the next flight instead of holding and
        // applying its failsafe. Best effort: a twin that is gone hears nothing.
        let end = CommandMsg {
            flags: COMMAND_END_OF_SESSION,
            session: self.session,
            tick: self.latest.tick,
            ..CommandMsg::default()
        };
        let _ = self.commands.send_copy(end);
    }
}
