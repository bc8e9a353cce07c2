//! Where a rollout's episode runs: a twin built in this thread, a session of the twin in
//! another process over iceoryx2 (`amstack twin serve --ipc <service>
//! --flight-chooses-episode`), or a PX4-style autopilot over MAVLink (`amstack twin serve
//! --mavlink ... --task T --seed S`, or a real vehicle). The first two answer the same
//! questions with the same bits, so a rollout's result does not depend on where it ran.
//!
//! Over MAVLink the wire carries f32 and the autopilot serves one episode per start: the
//! rollout is one flight, and its result matches the in-process one within the precision
//! of the wire (docs/mavlink.md). The task scene's state comes from the twin's autopilot as
//! the contract's SITL extension (DEBUG_FLOAT_ARRAY "task"); the names and lengths of its
//! observation keys come from the scene built here from the task and the seed (the
//! *scene model*), which also checks that the autopilot serves the same scene. A vehicle
//! that sends no task state (a real one) flies the script from the scene model, and the
//! rollout's success is not observed.

use platform::Vehicle;
use sim_twin::{Twin, TwinConfig};

use crate::ipc_link::{IpcLink, IpcLinkConfig};
use crate::link::{Link, LinkError, TwinLink};
use crate::mavlink_link::{MavlinkLink, MavlinkLinkConfig};

/// Where the benchmark's rollouts run.
#[derive(Debug, Clone, Default)]
pub enum BenchLink {
    /// A twin per rollout in the runner's threads (the default; fastest).
    #[default]
    InProcess,
    /// Every rollout a lockstep session of the twin served on this iceoryx2 service; the
    /// session's task and seed are the rollout's. One rollout at a time.
    Ipc(IpcLinkConfig),
    /// The rollout is one flight of the PX4-style autopilot at this address (the twin's
    /// serving the rollout's task and seed, or a real vehicle). One rollout per autopilot
    /// start.
    Mavlink(MavlinkLinkConfig),
}

impl BenchLink {
    /// `twin`, `ipc:<service>` or `mavlink:<address>`.
    pub fn name(&self) -> String {
        match self {
            Self::InProcess => "twin".to_owned(),
            Self::Ipc(c) => format!("ipc:{}", c.service),
            Self::Mavlink(c) => format!("mavlink:{}", c.bridge.address),
        }
    }

    /// Whether rollouts may run side by side on this link.
    pub fn parallel(&self) -> bool {
        matches!(self, Self::InProcess)
    }
}

impl BenchLink {
    /// The link of one rollout whose twin is `config` (its task and seed set): a twin built
    /// here, a session of the twin process, or the autopilot — whose task state, when it sends
    /// it, must be the scene built here from the task and the seed (the *scene model*).
    pub fn open(&self, vehicle: &Vehicle, config: &TwinConfig) -> Result<Box<dyn Link>, LinkError> {
        Ok(match self {
            Self::InProcess => Box::new(TwinLink::new(Twin::new(vehicle.clone(), config.clone())?)),
            Self::Ipc(c) => Box::new(IpcLink::connect(vehicle, config, c.clone())?),
            Self::Mavlink(c) => {
                let model = Twin::new(vehicle.clone(), config.clone())?.task_snapshot();
                Box::new(MavlinkLink::connect(vehicle, c.clone())?.with_scene_model(model)?)
            }
        })
    }
}
