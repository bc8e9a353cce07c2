//! The learned-policy flags of `bench`, `track` and `fly` (`--policy …`), resolved against the
//! vehicle and interface flown.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Result;
use platform::Vehicle;
use policy_runtime::Interface;
use policy_runtime::policy::chunk::{ActionLayout, stride};
use policy_runtime::policy::{
    OnnxPolicy, PolicyConfig, PolicyEndpoint, PolicyLatency, StateKey, StateReader,
};

use crate::cli_error::bad_input;

/// A learned policy instead of the scripted one.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct PolicyFlags {
    /// Fly a learned policy instead of the task's script: `remote:ws://HOST:PORT` (an openpi
    /// policy server) or `onnx:FILE` (an ONNX model with its sidecar FILE.json,
    /// docs/policies.md). Queried every --action-steps macro steps at --policy-hz, each
    /// macro action interpolated into control-rate setpoints (AMBENCH_SPEC §5.3). With
    /// --cameras ee[,base] it also sees the cameras' images.
    #[arg(long, value_name = "remote:ws://HOST:PORT|onnx:FILE")]
    pub policy: Option<String>,
    /// Language instruction sent with each query [default: the task's, AMBENCH_SPEC §7.1].
    #[arg(long, value_name = "TEXT", requires = "policy")]
    pub prompt: Option<String>,
    /// Policy rate, Hz; must divide the control rate [default: the model's, else 20].
    #[arg(long, value_name = "HZ", requires = "policy")]
    pub policy_hz: Option<f64>,
    /// Actions of each chunk executed per query [default: the model's, else 8].
    #[arg(long, value_name = "N", requires = "policy")]
    pub action_steps: Option<usize>,
    /// Observation state keys, comma-separated, from ee_pos, ee_quat, gripper_width,
    /// arm_joint_pos, base_pos, base_quat [default: ee_pos,ee_quat,gripper_width with the
    /// end-effector interface, base_pos,base_quat,arm_joint_pos,gripper_width with base +
    /// joints; an ONNX model's sidecar names its own].
    #[arg(long, value_name = "KEYS", requires = "policy")]
    pub state_keys: Option<String>,
    /// When an answer takes effect: `frozen` (simulated time waits for the policy, the
    /// reference's way), `measured` (the query's wall-clock time passes in simulated time
    /// while the vehicle flies the rest of the previous chunk; not reproducible) or a fixed
    /// latency in ms.
    #[arg(long, value_name = "frozen|measured|MS", default_value = "frozen")]
    pub policy_latency: String,
    /// How long a remote policy may take to connect or to answer one query, ms; past it
    /// the rollout ends `policy_failed`.
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    pub policy_timeout_ms: u64,
}

impl PolicyFlags {
    /// The policy to fly `vehicle` through `interface` at `control_hz`, if one is asked for;
    /// `cameras`: the flight's (`--cameras`), whose `ee` and `base` images the policy sees.
    pub fn resolve(
        &self,
        vehicle: &Vehicle,
        interface: Interface,
        control_hz: f64,
        cameras: &[String],
    ) -> Result<Option<PolicyConfig>> {
        let Some(text) = &self.policy else {
            return Ok(None);
        };
        let reader = StateReader::new(vehicle);
        let layout = match interface {
            Interface::Ee => ActionLayout::Ee,
            Interface::BaseJoint => ActionLayout::BaseJoint {
                arm_joints: vehicle.arm_dof(),
            },
        };
        let mut state_keys = match &self.state_keys {
            None => None,
            Some(list) => Some(
                StateKey::parse_list(list).map_err(|e| bad_input(format!("--state-keys: {e}")))?,
            ),
        };
        let mut rates = None;
        let endpoint = if let Some(url) = text.strip_prefix("remote:") {
            if !url.starts_with("ws://") {
                return Err(bad_input(format!(
                    "--policy {text}: a remote policy is ws://HOST:PORT (openpi's server; no TLS)"
                )));
            }
            let timeout = Duration::from_millis(self.policy_timeout_ms.max(1));
            PolicyEndpoint::Remote {
                url: url.to_owned(),
                connect_timeout: timeout,
                query_timeout: timeout,
            }
        } else if let Some(file) = text.strip_prefix("onnx:") {
            let model = OnnxPolicy::load(Path::new(file), &|k| reader.len(k))
                .map_err(|e| bad_input(format!("--policy {text}: {e}")))?;
            let side = model.sidecar();
            if side.output.dim != layout.dim() {
                return Err(bad_input(format!(
                    "--policy {text}: the model answers {}-value actions; {} with the {} \
                     interface takes {}",
                    side.output.dim,
                    vehicle.id,
                    interface.name(),
                    layout.dim()
                )));
            }
            match &state_keys {
                Some(keys) if *keys != side.state.keys => {
                    return Err(bad_input(format!(
                        "--state-keys: the model's sidecar takes {}",
                        side.state
                            .keys
                            .iter()
                            .map(|k| k.name())
                            .collect::<Vec<_>>()
                            .join(",")
                    )));
                }
                _ => state_keys = Some(side.state.keys.clone()),
            }
            if let Some(image) = side.images.iter().find(|i| {
                let camera = i.key.trim_end_matches("_image");
                !cameras
                    .iter()
                    .any(|c| c == camera || *c == format!("{camera}_camera"))
            }) {
                return Err(bad_input(format!(
                    "--policy {text}: the model takes the image {}; add its camera to --cameras",
                    image.key
                )));
            }
            rates = side.rates;
            PolicyEndpoint::Onnx(Arc::new(model))
        } else {
            return Err(bad_input(format!(
                "--policy {text}: expected remote:ws://HOST:PORT or onnx:FILE"
            )));
        };
        if let Some(k) = state_keys.iter().flatten().find(|k| reader.len(**k) == 0) {
            return Err(bad_input(format!(
                "--state-keys: {} has no {}",
                vehicle.id,
                k.name()
            )));
        }
        let policy_hz = self
            .policy_hz
            .or(rates.map(|r| r.policy_hz))
            .unwrap_or(20.0);
        stride(control_hz, policy_hz).map_err(|e| bad_input(format!("--policy-hz: {e}")))?;
        let action_steps = self
            .action_steps
            .or(rates.map(|r| r.action_steps))
            .unwrap_or(8);
        if action_steps == 0 {
            return Err(bad_input(
                "--action-steps 0: execute at least one action per query",
            ));
        }
        let latency = PolicyLatency::parse(&self.policy_latency)
            .map_err(|e| bad_input(format!("--policy-latency {e}")))?;
        Ok(Some(PolicyConfig {
            endpoint,
            policy_hz,
            action_steps,
            state_keys,
            prompt: self.prompt.clone(),
            latency,
        }))
    }
}
