//! The twin over iceoryx2 shared memory: one process runs the twin ([`TwinServer`]), another
//! flies it (`policy_runtime`'s `IpcLink`).
//!
//! # Services
//!
//! A name `N` given by the user (`amstack twin serve --ipc N`) opens three iceoryx2 services:
//!
//! | service | pattern | payload | direction |
//! |---|---|---|---|
//! | `amstack/N/handshake` | request-response | [`Hello`] → [`Welcome`] | flight → twin → flight |
//! | `amstack/N/command` | publish-subscribe | [`CommandMsg`] | flight → twin |
//! | `amstack/N/measurement` | publish-subscribe | [`MeasurementMsg`] | twin → flight |
//!
//! Both sides open them through the builders here, so their settings always agree.
//!
//! # Protocol
//!
//! 1. The flight process subscribes to the measurements, then sends a [`Hello`]: message
//!    version, vehicle id and description hash, control rate, twin configuration (JSON) and its
//!    hash. The twin refuses a mismatch with a [`Welcome`] whose reason names both values
//!    ([`check_hello`]); otherwise it resets its twin, opens a new session and publishes the
//!    state at its start (tick 0).
//! 2. Each tick the flight sends a [`CommandMsg`] answering measurement tick k.
//!    - **Lockstep** (the PX4 SITL contract, one command per measurement): the twin applies the
//!      command for its current tick, advances exactly one control period and publishes
//!      tick k + 1. Simulated time does not move without commands; a run is bit-identical to
//!      the in-process twin.
//!    - **Realtime**: the twin steps on the wall clock at the control rate (from the first
//!      command on) with the latest command it has, as hardware would.
//! 3. A command flagged [`COMMAND_END_OF_SESSION`] ends the session; the twin waits for the
//!    next one.
//!
//! # Faults
//!
//! - The flight process watches for each answer with a deadline (50 ms by default) and checks
//!   the twin's iceoryx2 node: a killed or hung twin is reported, never waited for.
//! - The twin watches the flight process's node. When the process is gone — or, in realtime,
//!   silent — it holds the last command for the hold timeout (on the wall clock, at the control
//!   rate), then applies the [`Failsafe`] and keeps running a few seconds so the vehicle comes
//!   to rest; a new flight process can connect at any time (its session restarts the twin).
//! - Resources of dead processes (files under `/dev/shm` and iceoryx2's folder) are removed
//!   when a side starts ([`cleanup_dead_nodes`]).

mod handshake;
mod messages;
mod server;
mod wait;

use std::sync::Once;

use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{publish_subscribe, request_response};

pub use handshake::{Offer, check_hello, config_hash, config_json, vehicle_hash};
pub use messages::{
    COMMAND_END_OF_SESSION, COMMAND_HAS_DIRECT_WRENCH, CommandMsg, Hello, ImuMsg, MAX_CONFIG_BYTES,
    MAX_ID_BYTES, MAX_JOINTS, MAX_REASON_BYTES, MAX_ROTORS, MEASUREMENT_FAILSAFE,
    MEASUREMENT_HOLDING, MEASUREMENT_SESSION_FAILED, MESSAGE_VERSION, MeasurementMsg, RotorMsg,
    TaskMsg, TooLarge, Welcome, get_str, join_id, joint_role, put_str, split_id,
};
pub use server::{Failsafe, Mode, ServeConfig, ServeError, ServeEvent, ServeSummary, TwinServer};
pub use wait::Waiter;

/// The iceoryx2 service flavour used: inter-process, single-threaded ports.
pub type Ipc = ipc::Service;
/// The handshake service.
pub type HandshakeService = request_response::PortFactory<Ipc, Hello, (), Welcome, ()>;
/// The command service.
pub type CommandService = publish_subscribe::PortFactory<Ipc, CommandMsg, ()>;
/// The measurement service.
pub type MeasurementService = publish_subscribe::PortFactory<Ipc, MeasurementMsg, ()>;

/// Samples a subscriber may hold unread; older ones are dropped first (safe overflow).
const BUFFER: usize = 8;
/// Flight processes (and tools) that may be attached to one twin's services at once.
const MAX_PEERS: usize = 8;

/// Any failure of iceoryx2, as text (its error types are many and not `Clone`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("iceoryx2: {0}")]
pub struct IpcError(pub String);

impl IpcError {
    /// `what` failed with `e`.
    pub fn new(what: &str, e: impl std::fmt::Debug) -> Self {
        Self(format!("{what}: {e:?}"))
    }
}

/// Lowers iceoryx2's logging to errors (it warns about a missing config file otherwise);
/// `IOX2_LOG_LEVEL` overrides.
pub fn quiet_logging() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| set_log_level_from_env_or(LogLevel::Error));
}

/// A node of this process (no signal handling: the binary handles Ctrl-C itself). Creating
/// it removes the resources of dead nodes (iceoryx2's default).
pub fn node(name: &str) -> Result<Node<Ipc>, IpcError> {
    quiet_logging();
    let name = NodeName::new(name).map_err(|e| IpcError::new("node name", e))?;
    NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| IpcError::new("creating a node", e))
}

/// Removes what dead processes left behind (shared memory, their ports in every service);
/// returns how many dead nodes were cleaned.
pub fn cleanup_dead_nodes(node: &Node<Ipc>) -> u64 {
    node.try_cleanup_dead_nodes().cleanups
}

/// Removes what dead processes left behind, without a node of this process (for test
/// harnesses after they killed a process). Returns how many dead nodes were cleaned.
pub fn cleanup_dead_nodes_now() -> u64 {
    quiet_logging();
    let mut dead = Vec::new();
    let listed = Node::<Ipc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    });
    if listed.is_err() {
        return 0;
    }
    dead.into_iter()
        .filter(|view| view.clone().try_remove_stale_resources().is_ok())
        .count() as u64
}

/// Whether the node with this id is alive: `Some(true)` alive, `Some(false)` dead or gone,
/// `None` when it cannot be told (no permission, listing failed).
pub fn node_alive(id: u128) -> Option<bool> {
    let mut state = Some(false);
    let listed = Node::<Ipc>::list(Config::global_config(), |s| {
        let (this, verdict) = match &s {
            NodeState::Alive(v) => (v.id().value(), Some(true)),
            NodeState::Dead(v) => (v.id().value(), Some(false)),
            NodeState::Inaccessible(n) | NodeState::Undefined(n) => (n.value(), None),
        };
        if this == id {
            state = verdict;
            CallbackProgression::Stop
        } else {
            CallbackProgression::Continue
        }
    });
    listed.ok().and(state)
}

fn service_name(name: &str, part: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(&format!("amstack/{name}/{part}"))
        .map_err(|e| IpcError::new(&format!("service name '{name}'"), e))
}

/// Opens (or creates) the handshake service of `name`.
pub fn handshake_service(node: &Node<Ipc>, name: &str) -> Result<HandshakeService, IpcError> {
    node.service_builder(&service_name(name, "handshake")?)
        .request_response::<Hello, Welcome>()
        .max_servers(1)
        .max_clients(MAX_PEERS)
        .max_nodes(MAX_PEERS + 1)
        .max_active_requests_per_client(2)
        .max_response_buffer_size(2)
        .open_or_create()
        .map_err(|e| IpcError::new(&format!("opening amstack/{name}/handshake"), e))
}

/// Opens (or creates) the command service of `name`.
pub fn command_service(node: &Node<Ipc>, name: &str) -> Result<CommandService, IpcError> {
    node.service_builder(&service_name(name, "command")?)
        .publish_subscribe::<CommandMsg>()
        .max_publishers(MAX_PEERS)
        .max_subscribers(MAX_PEERS)
        .max_nodes(MAX_PEERS + 1)
        .history_size(0)
        .subscriber_max_buffer_size(BUFFER)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| IpcError::new(&format!("opening amstack/{name}/command"), e))
}

/// Opens (or creates) the measurement service of `name`. One publisher: a second twin on the
/// same name is refused.
pub fn measurement_service(node: &Node<Ipc>, name: &str) -> Result<MeasurementService, IpcError> {
    node.service_builder(&service_name(name, "measurement")?)
        .publish_subscribe::<MeasurementMsg>()
        .max_publishers(1)
        .max_subscribers(MAX_PEERS)
        .max_nodes(MAX_PEERS + 1)
        .history_size(0)
        .subscriber_max_buffer_size(BUFFER)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| IpcError::new(&format!("opening amstack/{name}/measurement"), e))
}

#[cfg(test)]
mod tests;
