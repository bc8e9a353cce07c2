//! Where a rollout's episode runs: a twin built in this thread, or a session of the twin
//! in another process over iceoryx2 (`amstack twin serve --ipc <service>
//! --flight-chooses-episode`). Both answer the same questions with the same bits, so a
//! rollout's result does not depend on where it ran.

use platform::{ActuatorCommand, Measurement, Vehicle};
use sim_twin::{TaskSnapshot, Twin, TwinConfig, TwinError};

use crate::ipc_link::{IpcLink, IpcLinkConfig, IpcLinkError};
use crate::link::{Link, LinkError};

/// Where the benchmark's rollouts run.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum BenchLink {
    /// A twin per rollout in the runner's threads (the default; fastest).
    #[default]
    InProcess,
    /// Every rollout a lockstep session of the twin served on this iceoryx2 service; the
    /// session's task and seed are the rollout's. One rollout at a time.
    Ipc(IpcLinkConfig),
}

impl BenchLink {
    /// `twin` or `ipc:<service>`.
    pub fn name(&self) -> String {
        match self {
            Self::InProcess => "twin".to_owned(),
            Self::Ipc(c) => format!("ipc:{}", c.service),
        }
    }
}

/// Why a step did not happen.
#[derive(Debug)]
pub(crate) enum StepFailure {
    /// The command held a non-finite value (it was not applied).
    NonFinite,
    /// The simulation diverged.
    Diverged,
    /// The link failed (the twin process stopped answering): the run cannot go on.
    Link(IpcLinkError),
}

/// One episode: the twin it runs in.
#[derive(Debug)]
pub(crate) enum Episode {
    InProcess(Box<Twin>),
    Ipc(Box<IpcLink>),
}

impl Episode {
    /// Opens the episode of `config` (its task and seed set) on `link`.
    pub(crate) fn open(
        link: &BenchLink,
        vehicle: &Vehicle,
        config: &TwinConfig,
    ) -> Result<Self, EpisodeError> {
        Ok(match link {
            BenchLink::InProcess => {
                Self::InProcess(Box::new(Twin::new(vehicle.clone(), config.clone())?))
            }
            BenchLink::Ipc(c) => Self::Ipc(Box::new(IpcLink::connect(vehicle, config, c.clone())?)),
        })
    }

    /// The measurement now (before the first step: the state at reset).
    pub(crate) fn measurement(&mut self) -> Result<Measurement, EpisodeError> {
        match self {
            Self::InProcess(twin) => Ok(twin.truth().clone()),
            Self::Ipc(link) => link.receive().map_err(EpisodeError::from_link),
        }
    }

    /// Applies `command` for one control period.
    pub(crate) fn step(&mut self, command: &ActuatorCommand) -> Result<Measurement, StepFailure> {
        match self {
            Self::InProcess(twin) => twin.step(command).map_err(|e| match e {
                TwinError::Command(_) => StepFailure::NonFinite,
                _ => StepFailure::Diverged,
            }),
            Self::Ipc(link) => {
                // The in-process twin refuses such a command without stepping; never send one.
                let finite = command
                    .rotor_thrusts_n
                    .iter()
                    .chain(&command.joint_targets)
                    .all(|x| x.is_finite())
                    && command.direct_wrench_in_body.is_none_or(|w| w.is_finite());
                if !finite {
                    return Err(StepFailure::NonFinite);
                }
                let answered = link.send(command).and_then(|()| link.receive());
                answered.map_err(|e| match e {
                    LinkError::Ipc(IpcLinkError::TwinFailed { .. }) => StepFailure::Diverged,
                    LinkError::Ipc(e) => StepFailure::Link(e),
                    LinkError::Twin(_) => StepFailure::Diverged,
                })
            }
        }
    }

    /// The task scene after the last step.
    pub(crate) fn task(&self) -> Option<TaskSnapshot> {
        match self {
            Self::InProcess(twin) => twin.task_snapshot(),
            Self::Ipc(link) => link.task(),
        }
    }
}

/// An episode could not be opened or observed.
#[derive(Debug, thiserror::Error)]
pub enum EpisodeError {
    /// The in-process twin refused its configuration.
    #[error("twin: {0}")]
    Twin(#[from] TwinError),
    /// The twin process refused, failed or is not there.
    #[error(transparent)]
    Ipc(#[from] IpcLinkError),
}

impl EpisodeError {
    fn from_link(e: LinkError) -> Self {
        match e {
            LinkError::Twin(e) => Self::Twin(e),
            LinkError::Ipc(e) => Self::Ipc(e),
        }
    }
}
