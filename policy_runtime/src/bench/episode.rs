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

use std::borrow::Cow;

use firmware_bridge::TaskArray;
use platform::{ActuatorCommand, Measurement, Vehicle};
use sim_twin::{TaskId, TaskObservation, TaskSnapshot, TaskStatus, Twin, TwinConfig, TwinError};

use crate::flight_log::FlightLog;
use crate::ipc_link::{IpcLink, IpcLinkConfig, IpcLinkError};
use crate::link::{Link, LinkError};
use crate::mavlink_link::{MavlinkLink, MavlinkLinkConfig};
use crate::record::RecordError;
use crate::stack::TickRecord;

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

/// Why a step did not happen.
#[derive(Debug)]
pub(crate) enum StepFailure {
    /// The command held a non-finite value (it was not applied).
    NonFinite,
    /// The simulation diverged.
    Diverged,
    /// The link failed (the twin process stopped answering): the run cannot go on.
    Link(EpisodeError),
}

/// One episode: the twin it runs in.
#[derive(Debug)]
pub(crate) enum Episode {
    InProcess(Box<Twin>),
    Ipc(Box<IpcLink>),
    Mavlink {
        link: Box<MavlinkLink>,
        /// The scene model at reset (the task's keys; the context when the vehicle sends no
        /// task state).
        model: Option<TaskSnapshot>,
        /// Whether the autopilot sends the task's state.
        observed: bool,
    },
}

/// Whether every value of `command` is finite (the twin refuses the others without
/// stepping; they are never sent).
fn finite(command: &ActuatorCommand) -> bool {
    command
        .rotor_thrusts_n
        .iter()
        .chain(&command.joint_targets)
        .all(|x| x.is_finite())
        && command.direct_wrench_in_body.is_none_or(|w| w.is_finite())
}

/// The most a value of the autopilot's task state at reset may differ from the scene
/// model's: f32 rounding of values of a few metres is below 1e-6; a different seed moves
/// objects by centimetres.
const SCENE_MATCH_TOLERANCE: f64 = 1e-4;

/// The scene model's snapshot with the state the autopilot sent. `None` if the array does not
/// fit the model's keys.
fn snapshot_from_wire(model: &TaskSnapshot, wire: &TaskArray) -> Option<TaskSnapshot> {
    let lengths: usize = model.observation.entries.iter().map(|(_, v)| v.len()).sum();
    if lengths != wire.values.len() || wire.criteria.len() != model.status.criteria.len() {
        return None;
    }
    let mut values = wire.values.iter().copied();
    let entries = model
        .observation
        .entries
        .iter()
        .map(|(name, v)| (name.clone(), values.by_ref().take(v.len()).collect()))
        .collect::<Vec<(Cow<'static, str>, Vec<f64>)>>();
    Some(TaskSnapshot {
        task: model.task,
        status: TaskStatus {
            success: wire.success,
            criteria: wire.criteria.clone(),
        },
        observation: TaskObservation { entries },
        wall: wire.wall,
        obstacle_face_x: wire.obstacle_face_x_m,
        holding: wire.holding,
        steps: wire.steps,
    })
}

/// Checks that the autopilot's task state at reset is the scene model's: the same task, the
/// same keys, the same layout (the same seed).
fn check_scene(model: &TaskSnapshot, wire: &TaskArray) -> Result<(), String> {
    let served = usize::try_from(wire.task_number)
        .ok()
        .and_then(|n| n.checked_sub(1))
        .and_then(|i| TaskId::ALL.get(i));
    if served != Some(&model.task) {
        return Err(format!(
            "the autopilot serves {}, the flight is {}: start it with --task {}",
            served.map_or("no task".to_owned(), |t| format!("task {}", t.name())),
            model.task.name(),
            model.task.name()
        ));
    }
    let Some(snapshot) = snapshot_from_wire(model, wire) else {
        return Err(format!(
            "the autopilot's {} state has {} observation values and {} criteria, the scene \
             model {} and {}",
            model.task.name(),
            wire.values.len(),
            wire.criteria.len(),
            model
                .observation
                .entries
                .iter()
                .map(|(_, v)| v.len())
                .sum::<usize>(),
            model.status.criteria.len()
        ));
    };
    for ((name, ours), (_, theirs)) in model
        .observation
        .entries
        .iter()
        .zip(&snapshot.observation.entries)
    {
        let d = ours
            .iter()
            .zip(theirs)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if d > SCENE_MATCH_TOLERANCE {
            return Err(format!(
                "the autopilot's {} scene differs from this rollout's: {name} is {theirs:.4?} \
                 there, {ours:.4?} here (serve it with the same --seed and settings)",
                model.task.name()
            ));
        }
    }
    Ok(())
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
            BenchLink::Mavlink(c) => {
                let model = Twin::new(vehicle.clone(), config.clone())?.task_snapshot();
                let link = MavlinkLink::connect(vehicle, c.clone()).map_err(EpisodeError::Link)?;
                let wire = link.bridge().task();
                if let (Some(model), Some(wire)) = (&model, &wire) {
                    check_scene(model, wire).map_err(EpisodeError::Scene)?;
                }
                Self::Mavlink {
                    link: Box::new(link),
                    observed: wire.is_some(),
                    model,
                }
            }
        })
    }

    /// Adds the link's own channels to the rollout's log (over MAVLink: `/autopilot/state`,
    /// `/mavlink/raw`); nothing for the twin.
    pub(crate) fn log_tick(&mut self, log: &mut FlightLog, time_s: f64) -> Result<(), RecordError> {
        match self {
            Self::Mavlink { link, .. } => link.log_tick(log, time_s),
            _ => Ok(()),
        }
    }

    /// Whether the task's state is observed (always, but over MAVLink from a vehicle that
    /// does not send it).
    pub(crate) fn task_observed(&self) -> bool {
        match self {
            Self::Mavlink { observed, .. } => *observed,
            _ => true,
        }
    }

    /// The measurement now (before the first step: the state at reset).
    pub(crate) fn measurement(&mut self) -> Result<Measurement, EpisodeError> {
        match self {
            Self::InProcess(twin) => Ok(twin.truth().clone()),
            Self::Ipc(link) => link.receive().map_err(EpisodeError::from_link),
            Self::Mavlink { link, .. } => link.receive().map_err(EpisodeError::from_link),
        }
    }

    /// Applies the tick's command for one control period.
    pub(crate) fn step(&mut self, record: &TickRecord) -> Result<Measurement, StepFailure> {
        let command = &record.command;
        match self {
            Self::InProcess(twin) => twin.step(command).map_err(|e| match e {
                TwinError::Command(_) => StepFailure::NonFinite,
                _ => StepFailure::Diverged,
            }),
            Self::Ipc(link) => {
                if !finite(command) {
                    return Err(StepFailure::NonFinite);
                }
                let answered = link.send(command).and_then(|()| link.receive());
                answered.map_err(|e| match e {
                    LinkError::Ipc(IpcLinkError::TwinFailed { .. }) => StepFailure::Diverged,
                    e => StepFailure::Link(EpisodeError::from_link(e)),
                })
            }
            Self::Mavlink { link, .. } => {
                if !finite(command) {
                    return Err(StepFailure::NonFinite);
                }
                // The attitude level needs the controller's output, not only the command.
                let answered = link.send_tick(record).and_then(|()| link.receive());
                answered.map_err(|e| StepFailure::Link(EpisodeError::from_link(e)))
            }
        }
    }

    /// The task scene after the last step.
    pub(crate) fn task(&self) -> Option<TaskSnapshot> {
        match self {
            Self::InProcess(twin) => twin.task_snapshot(),
            Self::Ipc(link) => link.task(),
            Self::Mavlink {
                link,
                model,
                observed,
            } => {
                let model = model.as_ref()?;
                if !*observed {
                    // The scene model: the script's context and the obstacle face. Its status
                    // is not an observation ([`Episode::task_observed`]).
                    return Some(model.clone());
                }
                snapshot_from_wire(model, &link.bridge().task()?)
            }
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
    /// Another link failed.
    #[error(transparent)]
    Link(LinkError),
    /// The autopilot serves another task scene than the rollout's.
    #[error("{0}")]
    Scene(String),
}

impl EpisodeError {
    fn from_link(e: LinkError) -> Self {
        match e {
            LinkError::Twin(e) => Self::Twin(e),
            LinkError::Ipc(e) => Self::Ipc(e),
            e => Self::Link(e),
        }
    }
}

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]
mod tests {
    use mavlink::dialects::common::MavMessage;
    use twin_autopilot::telemetry::task_array;

    use super::*;

    /// The scene of `task` at `seed` (FA-Hexa), and its state as the twin's autopilot sends it.
    fn scene(task: TaskId, seed: u64) -> (TaskSnapshot, TaskArray) {
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let config = TwinConfig {
            task: Some(task),
            seed,
            ..TwinConfig::default()
        };
        let twin = Twin::new(vehicle, config).unwrap();
        let snapshot = twin.task_snapshot().unwrap();
        let Some(MavMessage::DEBUG_FLOAT_ARRAY(d)) = task_array(twin.truth(), &snapshot) else {
            panic!("a task array");
        };
        (snapshot, TaskArray::decode(&d).unwrap())
    }

    #[test]
    fn the_wire_state_of_the_same_scene_is_the_model_to_f32_precision() {
        let (model, wire) = scene(TaskId::PushSlider, 3);
        check_scene(&model, &wire).unwrap();
        let got = snapshot_from_wire(&model, &wire).unwrap();
        assert_eq!(
            got.observation.entries.len(),
            model.observation.entries.len()
        );
        for ((n, a), (m, b)) in got
            .observation
            .entries
            .iter()
            .zip(&model.observation.entries)
        {
            assert_eq!(n, m);
            for (x, y) in a.iter().zip(b) {
                // f32 keeps 24 bits: ≤ 2⁻²⁴ relative.
                assert!((x - y).abs() <= y.abs() * 6e-8 + 1e-12, "{n}: {x} vs {y}");
            }
        }
        assert_eq!(got.status, model.status);
        assert_eq!(got.steps, model.steps);
    }

    #[test]
    fn another_seed_or_task_on_the_autopilot_is_refused_by_name() {
        let (model, _) = scene(TaskId::PushSlider, 3);
        let (_, other_seed) = scene(TaskId::PushSlider, 4);
        let e = check_scene(&model, &other_seed).unwrap_err();
        assert!(e.contains("slider_body_pos") && e.contains("--seed"), "{e}");
        let (_, other_task) = scene(TaskId::PressButton, 3);
        let e = check_scene(&model, &other_task).unwrap_err();
        assert!(
            e.contains("serves task press-button") && e.contains("--task push-slider"),
            "{e}"
        );
    }
}
