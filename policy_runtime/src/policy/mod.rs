//! Learned policies in the flight loop: a [`PolicySource`] (an [`ActionSource`]) queries a
//! [`Policy`] — a remote openpi policy server ([`openpi`]) or an ONNX model ([`onnx`]) — at
//! the paper's chunked interface (AMBENCH_SPEC §5.3–5.4):
//!
//! - every `action_steps` macro steps at `policy_hz` (20 Hz) the policy sees the observation
//!   (state keys, prompt, images) and answers a chunk of H ≥ `action_steps` actions;
//! - each macro action becomes `control_hz / policy_hz` (6) setpoints at the control rate,
//!   interpolated from the commanded setpoint ([`chunk::interpolate`]);
//! - relative actions are decoded against the measured pose at the chunk's start, and such a
//!   policy sees the localised state;
//! - a chunk with a wrong shape, a non-finite value or an unnormalised quaternion, and a
//!   policy that cannot be reached or fails, end the flight as `policy_failed` with the
//!   reason ([`crate::flight::End::PolicyFailed`]): nothing of it reaches the stack.
//!
//! Latency: by default the policy is awaited with simulated time frozen (the reference's
//! way). With [`PolicyLatency::Measured`] or [`PolicyLatency::Fixed`] a chunk takes effect
//! only ⌈latency / dt⌉ ticks after its observation, the vehicle executing what is left of the
//! previous chunk (then holding its last setpoint) meanwhile, as it would fly.

pub mod chunk;
pub mod onnx;
pub mod openpi;
mod source;
pub mod state;

use std::sync::Arc;
use std::time::Duration;

pub use self::chunk::{ActionChunk, ActionLayout, ActionSemantics};
pub use self::onnx::{OnnxError, OnnxPolicy, Sidecar};
pub use self::openpi::OpenpiClient;
pub use self::source::{PolicySource, PolicyStats};
pub use self::state::{StateKey, StateReader};

/// A camera image for the policy: RGB, 8 bits, row-major H × W × 3.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyImage {
    /// The observation key without its prefix (`ee_image`, `base_image`).
    pub key: String,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// H·W·3 bytes.
    pub rgb: Vec<u8>,
}

/// What a policy sees at one query.
#[derive(Debug, Clone, Copy)]
pub struct PolicyObservation<'a> {
    /// Each state key with its values (localised for a relative policy).
    pub state: &'a [(StateKey, Vec<f64>)],
    /// The task's language instruction.
    pub prompt: &'a str,
    /// Camera images (none for a state-only policy).
    pub images: &'a [PolicyImage],
}

/// A policy could not answer: the reason ends the rollout as `policy_failed`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PolicyError(pub String);

/// A learned policy: one observation in, one chunk of actions out.
pub trait Policy: std::fmt::Debug + Send {
    /// The chunk for `observation`.
    fn query(&mut self, observation: &PolicyObservation<'_>) -> Result<ActionChunk, PolicyError>;
}

/// When a policy's answer takes effect in simulated time.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PolicyLatency {
    /// Time frozen while the policy answers (the reference's way).
    Frozen,
    /// The query's measured wall-clock time passes in simulated time.
    Measured,
    /// A fixed latency, ms.
    Fixed(f64),
}

impl PolicyLatency {
    /// `frozen`, `measured` or a number of milliseconds.
    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "frozen" => Ok(Self::Frozen),
            "measured" => Ok(Self::Measured),
            ms => match ms.parse::<f64>() {
                Ok(x) if x.is_finite() && x >= 0.0 => Ok(Self::Fixed(x)),
                _ => Err(format!(
                    "{ms:?}: not frozen, measured or a number of milliseconds >= 0"
                )),
            },
        }
    }
}

/// Where a policy comes from.
#[derive(Debug, Clone)]
pub enum PolicyEndpoint {
    /// An openpi policy server.
    Remote {
        /// `ws://HOST:PORT`.
        url: String,
        /// How long connecting and the server's metadata may take.
        connect_timeout: Duration,
        /// How long one answer may take.
        query_timeout: Duration,
    },
    /// An ONNX model with its sidecar, loaded once and shared by every rollout.
    Onnx(Arc<OnnxPolicy>),
}

impl PolicyEndpoint {
    /// The `--policy` text of this endpoint.
    pub fn describe(&self) -> String {
        match self {
            Self::Remote { url, .. } => format!("remote:{url}"),
            Self::Onnx(model) => format!("onnx:{}", model.path().display()),
        }
    }

    /// How the endpoint's actions relate to the state: a remote openpi server answers
    /// absolute actions (the reference's adapter); a model says so in its sidecar.
    pub fn semantics(&self) -> ActionSemantics {
        match self {
            Self::Remote { .. } => ActionSemantics::Absolute,
            Self::Onnx(model) => model.sidecar().output.semantics,
        }
    }

    /// A policy for one flight (a remote endpoint connects now).
    pub fn open(&self) -> Result<Box<dyn Policy>, PolicyError> {
        match self {
            Self::Remote {
                url,
                connect_timeout,
                query_timeout,
            } => Ok(Box::new(OpenpiClient::connect(
                url,
                *connect_timeout,
                *query_timeout,
            )?)),
            Self::Onnx(model) => Ok(Box::new(onnx::OnnxSession::new(Arc::clone(model)))),
        }
    }
}

/// How a learned policy flies.
#[derive(Debug, Clone)]
pub struct PolicyConfig {
    /// The policy.
    pub endpoint: PolicyEndpoint,
    /// Policy rate, Hz (AMBENCH_SPEC §5.3: 20).
    pub policy_hz: f64,
    /// Macro actions executed per query (default 8).
    pub action_steps: usize,
    /// The observation state; None: the interface's default (AMBENCH_SPEC §7.1).
    pub state_keys: Option<Vec<StateKey>>,
    /// The language instruction; None: the task's (AMBENCH_SPEC §7.1).
    pub prompt: Option<String>,
    /// When answers take effect.
    pub latency: PolicyLatency,
}

impl PolicyConfig {
    /// `endpoint` at the reference's defaults: 20 Hz, 8 steps per query, time frozen.
    pub fn new(endpoint: PolicyEndpoint) -> Self {
        Self {
            endpoint,
            policy_hz: 20.0,
            action_steps: 8,
            state_keys: None,
            prompt: None,
            latency: PolicyLatency::Frozen,
        }
    }
}

/// The reference's language instruction of `task` (AMBENCH_SPEC §7.1; NDT has none: its
/// title).
pub fn task_prompt(task: sim_twin::TaskId) -> &'static str {
    use sim_twin::TaskId as T;
    match task {
        T::CabinetPickPlace => {
            "open the cabinet sliding door, pick up the red can, and place it on top of the cabinet"
        }
        T::FrameAssembly => "pick up the frame and install it on the four posts",
        T::LemonHarvesting => "pick the yellow lemon and place it in the bin",
        T::OpenDoor => "open the door",
        T::PegInHole => "insert the peg into the hole",
        T::PressButton => "press the button",
        T::PullLever => "pull the lever upwards",
        T::PushSlider => "push the slider to the right",
        T::RotateValve => "rotate the valve clockwise",
        T::TossBall => "toss the ball into the bin",
        T::WipeWindow => "clear the red stain on the window",
        T::Ndt => "NDT inspection",
    }
}
