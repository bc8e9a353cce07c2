//! The bridge: one MAVLink connection served by a tokio runtime on its own thread, with a
//! blocking API for the synchronous flight loop.
//!
//! ```text
//!  flight thread                        bridge thread (tokio, current-thread runtime)
//!  ─────────────                        ─────────────────────────────────────────────
//!  send(messages) ──── mpsc ──────────► encode (+ sign) → socket / serial
//!                                       HEARTBEAT every heartbeat_period
//!  command_long() ◄─── COMMAND_ACKs ─── decode (count garbage, CRC, ids, signing)
//!  next_measurement() ◄─ measurements ─ telemetry → Measurement when ODOMETRY closes a tick
//!  autopilot(), counters() ◄─ shared ── heartbeat state, counters
//!  drain_raw() ◄──── bounded queue ──── every frame in and out, bytes as on the wire
//!                                       (with `capture_raw`; full → dropped and counted)
//! ```
//!
//! Dropping the [`Bridge`] ends the thread (the runtime stops when the flight side's sender
//! is gone).

use std::net::SocketAddr;
use std::sync::mpsc as std_mpsc;
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    COMMAND_ACK_DATA, COMMAND_LONG_DATA, HEARTBEAT_DATA, MavAutopilot, MavCmd, MavMessage,
    MavModeFlag, MavResult, MavState, MavType,
};
use platform::{Measurement, Vehicle};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpStream, UdpSocket};
use tokio::sync::mpsc;

use crate::address::Address;
use crate::capture::{Capture, CaptureQueue, CaptureStats, RawFrame};
use crate::setpoint::SetpointError;
use crate::task_array::TaskArray;
use crate::telemetry::{AutopilotState, AutopilotVersion, Telemetry, px4_mode};
use crate::wire::{CounterSnapshot, Counters, Decoder, Encoder, Frame, Signing};

/// MAV_COMP_ID_AUTOPILOT1.
pub const COMP_ID_AUTOPILOT: u8 = 1;
/// MAV_COMP_ID_ONBOARD_COMPUTER.
pub const COMP_ID_ONBOARD_COMPUTER: u8 = 191;

/// How the bridge connects and behaves. Plain data; [`BridgeConfig::new`] gives the
/// contract's defaults.
#[derive(Debug, Clone)]
pub struct BridgeConfig {
    /// Where the autopilot is.
    pub address: Address,
    /// Our system id (default 1, the vehicle's: the bridge is a component of it).
    pub system_id: u8,
    /// Our component id (default 191, MAV_COMP_ID_ONBOARD_COMPUTER).
    pub component_id: u8,
    /// The autopilot's system id (default 1).
    pub target_system: u8,
    /// The autopilot's component id (default 1).
    pub target_component: u8,
    /// Signing, if any.
    pub signing: Option<Signing>,
    /// How long one COMMAND_LONG attempt waits for its COMMAND_ACK (default 250 ms).
    pub command_timeout: Duration,
    /// Attempts after the first when no COMMAND_ACK comes (default 3; the `confirmation`
    /// field counts them, as MAVLink's command protocol says).
    pub command_retries: u32,
    /// HEARTBEAT period (default 1 s).
    pub heartbeat_period: Duration,
    /// How long [`Bridge::connect`] waits for a TCP server to accept (default 5 s).
    pub connect_timeout: Duration,
    /// Capture every frame received (accepted) and sent, bytes as on the wire, for
    /// [`Bridge::drain_raw`] (default off; `amstack fly` turns it on when it logs MCAP).
    pub capture_raw: bool,
    /// Frames the capture holds until the flight side drains them; beyond, frames are
    /// dropped and counted (default 16384: over 10 s of a 120 Hz flight's traffic).
    pub capture_capacity: usize,
}

impl BridgeConfig {
    /// The contract's defaults for `address`.
    pub fn new(address: Address) -> Self {
        Self {
            address,
            system_id: 1,
            component_id: COMP_ID_ONBOARD_COMPUTER,
            target_system: 1,
            target_component: COMP_ID_AUTOPILOT,
            signing: None,
            command_timeout: Duration::from_millis(250),
            command_retries: 3,
            heartbeat_period: Duration::from_secs(1),
            connect_timeout: Duration::from_secs(5),
            capture_raw: false,
            capture_capacity: 16_384,
        }
    }
}

/// What can go wrong on the bridge.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BridgeError {
    /// The connection could not be opened.
    #[error("cannot open the MAVLink link {address}: {reason}")]
    Open {
        /// The address.
        address: String,
        /// Why.
        reason: String,
    },
    /// The autopilot answered a command with a result other than ACCEPTED.
    #[error("{what} refused by the autopilot: {result} ({command})")]
    CommandRefused {
        /// What the command was for (`arming`, `switching to offboard`).
        what: String,
        /// The command (`MAV_CMD_COMPONENT_ARM_DISARM`).
        command: String,
        /// The result (`MAV_RESULT_DENIED`).
        result: String,
    },
    /// No COMMAND_ACK after every attempt.
    #[error(
        "{what}: no COMMAND_ACK for {command} from the autopilot after {attempts} attempts of {timeout_ms} ms"
    )]
    CommandTimeout {
        /// What the command was for.
        what: String,
        /// The command.
        command: String,
        /// Attempts made.
        attempts: u32,
        /// Wait per attempt, ms.
        timeout_ms: u64,
    },
    /// No telemetry came in time.
    #[error("no {what} from the autopilot within {waited_ms} ms")]
    NoTelemetry {
        /// What was awaited (`ODOMETRY for the next tick`).
        what: String,
        /// How long, ms.
        waited_ms: u64,
    },
    /// A setpoint that cannot be sent (non-finite, wrong shape).
    #[error(transparent)]
    Setpoint(#[from] SetpointError),
    /// The bridge's I/O thread ended.
    #[error("the MAVLink link {address} closed: {reason}")]
    Closed {
        /// The address.
        address: String,
        /// Why.
        reason: String,
    },
}

/// State shared between the I/O thread and the flight side.
#[derive(Debug, Default)]
struct Shared {
    autopilot: AutopilotState,
    last_heartbeat: Option<Instant>,
    latest: Option<Measurement>,
    /// The latest task state (SITL).
    task: Option<TaskArray>,
    rejected_values: u64,
    closed: Option<String>,
}

enum Outgoing {
    /// Frames to send back to back.
    Messages(Vec<MavMessage>),
}

/// A MAVLink connection to a PX4-style autopilot.
pub struct Bridge {
    config: BridgeConfig,
    outgoing: mpsc::UnboundedSender<Outgoing>,
    acks: std_mpsc::Receiver<COMMAND_ACK_DATA>,
    measurements: std_mpsc::Receiver<Measurement>,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    raw: Option<CaptureQueue>,
    thread: Option<JoinHandle<()>>,
    confirmation: u8,
}

impl std::fmt::Debug for Bridge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bridge")
            .field("address", &self.config.address.to_string())
            .field("counters", &self.counters.snapshot())
            .finish_non_exhaustive()
    }
}

/// The open transport.
enum Transport {
    Udp {
        socket: UdpSocket,
        /// Where frames go (None for `udpin` until the autopilot is heard).
        peer: Option<SocketAddr>,
        /// Learn the peer from incoming frames (`udpin`).
        learn_peer: bool,
    },
    Stream {
        reader: Box<dyn AsyncRead + Unpin + Send>,
        writer: Box<dyn AsyncWrite + Unpin + Send>,
        /// A read of 0 bytes is the end of the stream (TCP), or only "no data" (a serial
        /// port with VMIN = 0, a pseudo-terminal whose other end is between writes).
        zero_is_end: bool,
    },
}

async fn open(config: &BridgeConfig) -> Result<Transport, String> {
    match &config.address {
        Address::Udp { host, port } => {
            let peer = tokio::net::lookup_host((host.as_str(), *port))
                .await
                .map_err(|e| format!("cannot resolve {host}: {e}"))?
                .next()
                .ok_or_else(|| format!("{host} resolves to no address"))?;
            let local: SocketAddr = if peer.is_ipv4() {
                ([0, 0, 0, 0], 0).into()
            } else {
                (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
            };
            let socket = UdpSocket::bind(local)
                .await
                .map_err(|e| format!("cannot bind a local UDP port: {e}"))?;
            Ok(Transport::Udp {
                socket,
                peer: Some(peer),
                learn_peer: false,
            })
        }
        Address::UdpIn { host, port } => {
            let socket = UdpSocket::bind((host.as_str(), *port))
                .await
                .map_err(|e| format!("cannot listen on {host}:{port}: {e}"))?;
            Ok(Transport::Udp {
                socket,
                peer: None,
                learn_peer: true,
            })
        }
        Address::Tcp { host, port } => {
            let deadline = Instant::now() + config.connect_timeout;
            let stream = loop {
                match TcpStream::connect((host.as_str(), *port)).await {
                    Ok(s) => break s,
                    Err(e) if Instant::now() >= deadline => {
                        return Err(format!("cannot connect to {host}:{port}: {e}"));
                    }
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            };
            stream.set_nodelay(true).map_err(|e| e.to_string())?;
            let (r, w) = stream.into_split();
            Ok(Transport::Stream {
                reader: Box::new(r),
                writer: Box::new(w),
                zero_is_end: true,
            })
        }
        Address::Serial { device, baud } => {
            use tokio_serial::SerialPortBuilderExt;
            let port = tokio_serial::new(device, *baud)
                .open_native_async()
                .map_err(|e| format!("cannot open serial device {device}: {e}"))?;
            let (r, w) = tokio::io::split(port);
            Ok(Transport::Stream {
                reader: Box::new(r),
                writer: Box::new(w),
                zero_is_end: false,
            })
        }
    }
}

impl Bridge {
    /// Opens the connection and starts the bridge's thread. Telemetry is decoded from the
    /// autopilot `config.target_system`/`config.target_component` (and COMMAND_ACKs from
    /// its system); a HEARTBEAT goes out every `config.heartbeat_period` from now on.
    pub fn connect(config: BridgeConfig, vehicle: &Vehicle) -> Result<Self, BridgeError> {
        let (out_tx, out_rx) = mpsc::unbounded_channel();
        let (ack_tx, ack_rx) = std_mpsc::channel();
        let (m_tx, m_rx) = std_mpsc::channel();
        let (ready_tx, ready_rx) = std_mpsc::channel();
        let shared = Arc::new(Mutex::new(Shared::default()));
        let counters = Arc::new(Counters::default());
        let (capture, raw) = if config.capture_raw {
            let (capture, queue) = crate::capture::capture(config.capture_capacity);
            (Some(capture), Some(queue))
        } else {
            (None, None)
        };
        let io = Io {
            config: config.clone(),
            telemetry: Telemetry::new(vehicle),
            shared: shared.clone(),
            counters: counters.clone(),
            acks: ack_tx,
            measurements: m_tx,
            capture,
        };
        let address = config.address.to_string();
        let thread = std::thread::Builder::new()
            .name("mavlink-bridge".to_owned())
            .spawn(move || io.run(out_rx, &ready_tx))
            .map_err(|e| BridgeError::Open {
                address: address.clone(),
                reason: format!("cannot start the bridge thread: {e}"),
            })?;
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(reason)) => return Err(BridgeError::Open { address, reason }),
            Err(_) => {
                return Err(BridgeError::Open {
                    address,
                    reason: "the bridge thread ended while opening".to_owned(),
                });
            }
        }
        Ok(Self {
            config,
            outgoing: out_tx,
            acks: ack_rx,
            measurements: m_rx,
            shared,
            counters,
            raw,
            thread: Some(thread),
            confirmation: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &BridgeConfig {
        &self.config
    }

    fn closed_error(&self) -> BridgeError {
        let reason = self
            .shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .closed
            .clone()
            .unwrap_or_else(|| "the bridge thread ended".to_owned());
        BridgeError::Closed {
            address: self.config.address.to_string(),
            reason,
        }
    }

    /// Queues messages to go out back to back, in order.
    pub fn send(&self, messages: Vec<MavMessage>) -> Result<(), BridgeError> {
        self.outgoing
            .send(Outgoing::Messages(messages))
            .map_err(|_| self.closed_error())
    }

    /// Sends a COMMAND_LONG and waits for its COMMAND_ACK: `command_timeout` per attempt,
    /// `command_retries` more attempts (with `confirmation` counting up) when none comes;
    /// MAV_RESULT_IN_PROGRESS keeps waiting. `what` names the command in errors
    /// (`arming refused by the autopilot: MAV_RESULT_DENIED`).
    pub fn command_long(
        &mut self,
        what: &str,
        command: MavCmd,
        params: [f32; 7],
    ) -> Result<(), BridgeError> {
        // Acks of earlier commands that came late must not answer this one.
        while self.acks.try_recv().is_ok() {}
        let attempts = self.config.command_retries + 1;
        for attempt in 0..attempts {
            self.confirmation = u8::try_from(attempt).unwrap_or(u8::MAX);
            self.send(vec![MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                param1: params[0],
                param2: params[1],
                param3: params[2],
                param4: params[3],
                param5: params[4],
                param6: params[5],
                param7: params[6],
                command,
                target_system: self.config.target_system,
                target_component: self.config.target_component,
                confirmation: self.confirmation,
            })])?;
            let mut deadline = Instant::now() + self.config.command_timeout;
            loop {
                let left = deadline.saturating_duration_since(Instant::now());
                match self.acks.recv_timeout(left) {
                    Ok(ack) if ack.command == command => match ack.result {
                        MavResult::MAV_RESULT_ACCEPTED => return Ok(()),
                        MavResult::MAV_RESULT_IN_PROGRESS => {
                            deadline = Instant::now() + self.config.command_timeout;
                        }
                        other => {
                            return Err(BridgeError::CommandRefused {
                                what: what.to_owned(),
                                command: format!("{command:?}"),
                                result: format!("{other:?}"),
                            });
                        }
                    },
                    Ok(_) => {} // an ack for another command
                    Err(std_mpsc::RecvTimeoutError::Timeout) => break,
                    Err(std_mpsc::RecvTimeoutError::Disconnected) => {
                        return Err(self.closed_error());
                    }
                }
            }
        }
        Err(BridgeError::CommandTimeout {
            what: what.to_owned(),
            command: format!("{command:?}"),
            attempts,
            timeout_ms: u64::try_from(self.config.command_timeout.as_millis()).unwrap_or(u64::MAX),
        })
    }

    /// Arms (MAV_CMD_COMPONENT_ARM_DISARM, param1 = 1).
    pub fn arm(&mut self) -> Result<(), BridgeError> {
        self.command_long(
            "arming",
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        )
    }

    /// Disarms (MAV_CMD_COMPONENT_ARM_DISARM, param1 = 0).
    pub fn disarm(&mut self) -> Result<(), BridgeError> {
        self.command_long(
            "disarming",
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        )
    }

    /// Switches to OFFBOARD (MAV_CMD_DO_SET_MODE, param1 = CUSTOM_MODE_ENABLED, param2 = 6).
    /// PX4 refuses unless setpoints have been streaming.
    pub fn set_offboard(&mut self) -> Result<(), BridgeError> {
        self.command_long(
            "switching to offboard",
            MavCmd::MAV_CMD_DO_SET_MODE,
            [
                MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits().into(),
                px4_mode::OFFBOARD.into(),
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
        )
    }

    /// Asks the autopilot what it declares (MAV_CMD_REQUEST_MESSAGE for AUTOPILOT_VERSION, as
    /// PX4 answers it: COMMAND_ACK, then the message) and waits up to `timeout` after the
    /// ack for the message.
    pub fn request_autopilot_version(
        &mut self,
        timeout: Duration,
    ) -> Result<AutopilotVersion, BridgeError> {
        const AUTOPILOT_VERSION_ID: f32 = 148.0;
        self.shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .autopilot
            .version = None;
        self.command_long(
            "requesting AUTOPILOT_VERSION",
            MavCmd::MAV_CMD_REQUEST_MESSAGE,
            [AUTOPILOT_VERSION_ID, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        )?;
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(v) = self.autopilot().version {
                return Ok(v);
            }
            if Instant::now() >= deadline {
                return Err(BridgeError::NoTelemetry {
                    what: "AUTOPILOT_VERSION (asked for with MAV_CMD_REQUEST_MESSAGE)".to_owned(),
                    waited_ms: u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX),
                });
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Waits up to `timeout` for a measurement newer than `after_s` (simulated or autopilot
    /// time, s; `None`: any), dropping older ones. `what` names it in the error.
    pub fn next_measurement(
        &self,
        after_s: Option<f64>,
        timeout: Duration,
        what: &str,
    ) -> Result<Measurement, BridgeError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.measurements.recv_timeout(left) {
                Ok(m) if after_s.is_none_or(|t| m.time_s > t) => return Ok(m),
                Ok(_) => {}
                Err(std_mpsc::RecvTimeoutError::Timeout) => {
                    return Err(BridgeError::NoTelemetry {
                        what: what.to_owned(),
                        waited_ms: u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX),
                    });
                }
                Err(std_mpsc::RecvTimeoutError::Disconnected) => return Err(self.closed_error()),
            }
        }
    }

    /// The latest measurement assembled, if any tick has closed.
    pub fn latest(&self) -> Option<Measurement> {
        self.shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .latest
            .clone()
    }

    /// The task state of the latest step, if the autopilot sends one (the twin's autopilot
    /// serving a task scene does, before the ODOMETRY of each step).
    pub fn task(&self) -> Option<TaskArray> {
        self.shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .task
            .clone()
    }

    /// What the autopilot last said about itself.
    pub fn autopilot(&self) -> AutopilotState {
        self.shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .autopilot
            .clone()
    }

    /// Time since the autopilot's last HEARTBEAT (None before the first).
    pub fn heartbeat_age(&self) -> Option<Duration> {
        self.shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .last_heartbeat
            .map(|t| t.elapsed())
    }

    /// Telemetry values ignored as non-finite or malformed.
    pub fn rejected_values(&self) -> u64 {
        self.shared
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .rejected_values
    }

    /// The wire counters.
    pub fn counters(&self) -> CounterSnapshot {
        self.counters.snapshot()
    }

    /// Moves the frames captured since the last call to `out`, oldest first; returns how
    /// many (always 0 without [`BridgeConfig::capture_raw`]). Never waits.
    pub fn drain_raw(&self, out: &mut Vec<RawFrame>) -> usize {
        self.raw.as_ref().map_or(0, |q| q.drain(out))
    }

    /// The capture's counts (None without [`BridgeConfig::capture_raw`]).
    pub fn capture_stats(&self) -> Option<CaptureStats> {
        self.raw.as_ref().map(CaptureQueue::stats)
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        // Closing the channel ends the runtime's loop.
        let (tx, _) = mpsc::unbounded_channel();
        drop(std::mem::replace(&mut self.outgoing, tx));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The I/O side, moved into the bridge's thread.
struct Io {
    config: BridgeConfig,
    telemetry: Telemetry,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    acks: std_mpsc::Sender<COMMAND_ACK_DATA>,
    measurements: std_mpsc::Sender<Measurement>,
    /// The raw frame capture, when configured.
    capture: Option<Capture>,
}

impl Io {
    fn run(
        mut self,
        outgoing: mpsc::UnboundedReceiver<Outgoing>,
        ready: &std_mpsc::Sender<Result<(), String>>,
    ) {
        let runtime = match tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        {
            Ok(r) => r,
            Err(e) => {
                let _ = ready.send(Err(format!("cannot start the tokio runtime: {e}")));
                return;
            }
        };
        let reason = runtime.block_on(async {
            let transport = match open(&self.config).await {
                Ok(t) => t,
                Err(e) => {
                    let _ = ready.send(Err(e));
                    return None;
                }
            };
            let _ = ready.send(Ok(()));
            self.serve(transport, outgoing).await
        });
        if let Some(reason) = reason {
            self.shared
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .closed = Some(reason);
        }
    }

    fn heartbeat(&self) -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    /// Serves the connection until the flight side hangs up (None) or the transport fails
    /// (Some(reason)).
    async fn serve(
        &mut self,
        mut transport: Transport,
        mut outgoing: mpsc::UnboundedReceiver<Outgoing>,
    ) -> Option<String> {
        let mut encoder = Encoder::new(
            self.config.system_id,
            self.config.component_id,
            self.config.signing.as_ref().map(|s| &s.key),
        );
        let mut decoder =
            Decoder::new(self.config.signing.as_ref()).keeping_bytes(self.capture.is_some());
        let mut heartbeat = tokio::time::interval(self.config.heartbeat_period);
        heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut buf = vec![0u8; 4096];
        let mut frames = Vec::new();
        loop {
            let to_send: Vec<MavMessage> = match &mut transport {
                Transport::Udp {
                    socket,
                    peer,
                    learn_peer,
                } => {
                    tokio::select! {
                        out = outgoing.recv() => match out {
                            Some(Outgoing::Messages(m)) => m,
                            None => return None,
                        },
                        _ = heartbeat.tick() => vec![self.heartbeat()],
                        got = socket.recv_from(&mut buf) => {
                            // An error is an ICMP report of an earlier send (nobody
                            // listening yet): not fatal on a datagram socket.
                            if let Ok((n, from)) = got {
                                decoder.push_datagram(&buf[..n], &self.counters, &mut frames);
                                let target = u32::from(self.config.target_system);
                                if *learn_peer && frames.iter().any(|f| f.header.system_id == target) {
                                    *peer = Some(from);
                                }
                            }
                            Vec::new()
                        }
                    }
                }
                Transport::Stream {
                    reader,
                    zero_is_end,
                    ..
                } => {
                    tokio::select! {
                        out = outgoing.recv() => match out {
                            Some(Outgoing::Messages(m)) => m,
                            None => return None,
                        },
                        _ = heartbeat.tick() => vec![self.heartbeat()],
                        got = reader.read(&mut buf) => {
                            match got {
                                Ok(0) if *zero_is_end => {
                                    return Some("the autopilot closed the connection".to_owned());
                                }
                                // Serial: no data now; do not spin on the device.
                                Ok(0) => tokio::time::sleep(Duration::from_millis(1)).await,
                                Ok(n) => {
                                    decoder.push_stream(&buf[..n], &self.counters, &mut frames);
                                }
                                Err(e) => return Some(format!("read failed: {e}")),
                            }
                            Vec::new()
                        }
                    }
                }
            };
            for frame in frames.drain(..) {
                self.handle(&frame);
            }
            for message in &to_send {
                let bytes = encoder.encode(message);
                let sent = match &mut transport {
                    Transport::Udp { socket, peer, .. } => match peer {
                        Some(p) => socket.send_to(&bytes, *p).await.map(|_| ()),
                        None => Ok(()), // udpin: nobody to answer yet
                    },
                    Transport::Stream { writer, .. } => writer.write_all(&bytes).await,
                };
                match sent {
                    Ok(()) => {
                        self.counters
                            .frames_sent
                            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if let Some(c) = &mut self.capture {
                            c.sent(message, &bytes, self.telemetry.current().time_s);
                        }
                    }
                    // A datagram to a port nobody listens on yet: keep going.
                    Err(_) if matches!(transport, Transport::Udp { .. }) => {}
                    Err(e) => return Some(format!("write failed: {e}")),
                }
            }
        }
    }

    fn handle(&mut self, frame: &Frame) {
        let from_target = frame.header.system_id == u32::from(self.config.target_system);
        let ack = match &frame.message {
            MavMessage::COMMAND_ACK(ack) => Some(ack),
            _ => None,
        };
        let telemetry = from_target
            && ack.is_none()
            && frame.header.component_id == self.config.target_component;
        let finished = if telemetry {
            self.telemetry.apply(&frame.message)
        } else {
            None
        };
        // The capture after the telemetry (an ODOMETRY carries its own time) and before
        // anything the frame brought reaches the flight side (a measurement, an ack): the
        // flight side's drain after a measurement then finds the frames that made it.
        if let Some(c) = &mut self.capture {
            c.received(frame, self.telemetry.current().time_s);
        }
        if !from_target {
            return;
        }
        if let Some(ack) = ack {
            let _ = self.acks.send(ack.clone());
            return;
        }
        if !telemetry {
            return;
        }
        let heartbeat = matches!(frame.message, MavMessage::HEARTBEAT(_));
        let mut shared = self.shared.lock().unwrap_or_else(PoisonError::into_inner);
        if heartbeat {
            shared.last_heartbeat = Some(Instant::now());
            shared.autopilot = self.telemetry.autopilot.clone();
        } else if !matches!(frame.message, MavMessage::ODOMETRY(_)) {
            shared.autopilot = self.telemetry.autopilot.clone();
        }
        shared.rejected_values = self.telemetry.rejected_values;
        if matches!(frame.message, MavMessage::DEBUG_FLOAT_ARRAY(_)) {
            shared.task.clone_from(&self.telemetry.task);
        }
        if let Some(m) = finished {
            shared.latest = Some(m.clone());
            drop(shared);
            let _ = self.measurements.send(m);
        }
    }
}
