//! Action sources: what chooses the action of each tick. A source sees the tick's
//! observation; it may answer every tick or hold a chunk of actions.
//!
//! - [`TrajectorySource`]: a reference trajectory (`amstack track`, `fly`): a base + joint
//!   target of time;
//! - [`ScriptedTask`]: a task's scripted demonstration (the benchmark's rollouts), built from
//!   the first observation;
//! - the logged actions of a flight (`replay`: [`crate::validation::replay`]);
//! - a learned policy at the chunked interface ([`crate::policy::PolicySource`]).

use nalgebra::Isometry3;
use platform::{Measurement, RandomStream, Vehicle};
use serde::Serialize;
use sim_twin::{TaskId, TaskSnapshot};

use crate::cameras::Frames;
use crate::stack::{Action, EeTarget, FlightStack, TickRecord};
use crate::task_policies::{PolicyContext, TaskPolicy, gripper_override, scripted};
use crate::trajectory::Trajectory;

/// What a source sees of one tick.
#[derive(Debug, Clone, Copy)]
pub struct Observation<'a> {
    /// t_k = k·dt, s (0 at the start).
    pub time_s: f64,
    /// The measurement the stack flies on (the estimate's with the estimator).
    pub measurement: &'a Measurement,
    /// The link's measurement.
    pub truth: &'a Measurement,
    /// The task scene's state, with a scene.
    pub scene: Option<&'a TaskSnapshot>,
    /// The camera images of this observation (the state of `truth`), on the ticks where
    /// [`ActionSource::wants_frames`] asked for them and the flight has cameras; `None`
    /// otherwise (and at [`ActionSource::start`]).
    pub frames: Option<&'a Frames>,
}

/// A source's answer for one tick.
#[derive(Debug, Clone)]
pub enum Step {
    /// An action for the stack (noise and the flight's interface apply to it).
    Act {
        /// The action, in the source's own interface.
        action: Action,
        /// The end-effector reference to score and log; None: where the action puts the
        /// end-effector link.
        ee_reference: Option<Isometry3<f64>>,
    },
    /// A command flown open loop, bypassing the stack (`replay --mode commands`).
    OpenLoop {
        /// The tick record to send and log.
        record: Box<TickRecord>,
        /// The end-effector reference to log.
        ee_reference: Isometry3<f64>,
    },
    /// The source cannot go on (a learned policy that failed or answered something that must
    /// not be flown): the flight ends [`super::End::PolicyFailed`] with the reason, nothing
    /// sent for this tick.
    Failed(String),
}

/// The source could not answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct SourceError(pub String);

/// What chooses the actions of a flight.
pub trait ActionSource {
    /// The first observation, before the first tick (a scripted policy is built from it).
    fn start(&mut self, first: &Observation<'_>) -> Result<(), SourceError> {
        let _ = first;
        Ok(())
    }

    /// The ticks this source can fly, when it decides (None: the flight's limit).
    fn tick_limit(&self) -> Option<u64> {
        None
    }

    /// Whether [`Self::next`] of tick `k` needs the camera images of observation k
    /// ([`Observation::frames`]); asked before every tick of a flight with cameras. Default:
    /// never (nothing is rendered for the source).
    fn wants_frames(&self, k: u64) -> bool {
        let _ = k;
        false
    }

    /// The action of tick `k`.
    fn next(
        &mut self,
        k: u64,
        observation: &Observation<'_>,
        stack: &mut FlightStack,
    ) -> Result<Step, SourceError>;
}

/// A reference trajectory: the base + joint target at t_k.
#[derive(Debug, Clone)]
pub struct TrajectorySource {
    trajectory: Trajectory,
    vehicle: Vehicle,
}

impl TrajectorySource {
    /// `trajectory` for `vehicle`.
    pub fn new(trajectory: Trajectory, vehicle: Vehicle) -> Self {
        Self {
            trajectory,
            vehicle,
        }
    }
}

impl ActionSource for TrajectorySource {
    fn next(
        &mut self,
        _k: u64,
        observation: &Observation<'_>,
        _stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        Ok(Step::Act {
            action: Action::BaseJoint(self.trajectory.target(&self.vehicle, observation.time_s)),
            ee_reference: None,
        })
    }
}

/// A task's scripted demonstration (AMBENCH_SPEC §4): end-effector targets (command frame)
/// and gripper actions, its random offsets from the rollout seed's policy stream.
#[derive(Debug)]
pub struct ScriptedTask {
    task: TaskId,
    seed: u64,
    rate_hz: f64,
    episode: EpisodeLength,
    policy: Option<Box<dyn TaskPolicy>>,
}

impl ScriptedTask {
    /// The script of `task` for the rollout seeded `seed`, its length as `episode` says at
    /// `rate_hz` env steps per second.
    pub fn new(task: TaskId, seed: u64, rate_hz: f64, episode: EpisodeLength) -> Self {
        Self {
            task,
            seed,
            rate_hz,
            episode,
            policy: None,
        }
    }
}

impl ActionSource for ScriptedTask {
    fn start(&mut self, first: &Observation<'_>) -> Result<(), SourceError> {
        let context = PolicyContext {
            init: first.measurement.world_from_ee.translation.vector,
            task: first
                .scene
                .map(|s| s.observation.clone())
                .unwrap_or_default(),
            wall: first.scene.and_then(|s| s.wall),
        };
        let mut rng = RandomStream::Policy.rng(self.seed);
        let policy = scripted(self.task, &context, &mut rng)
            .map_err(|message| SourceError(format!("{} scripted policy: {message}", self.task)))?;
        self.policy = Some(policy);
        Ok(())
    }

    fn tick_limit(&self) -> Option<u64> {
        let end = self.policy.as_ref().map_or(0, |p| p.end_step());
        Some(self.episode.max_steps(self.task, self.rate_hz, end))
    }

    fn next(
        &mut self,
        k: u64,
        _observation: &Observation<'_>,
        _stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        let policy = self
            .policy
            .as_mut()
            .ok_or_else(|| SourceError("the scripted policy was not started".to_owned()))?;
        let (world_from_ee_command, mut gripper) = policy.action(k);
        if let Some(g) = gripper_override(self.task) {
            gripper = g;
        }
        Ok(Step::Act {
            action: Action::Ee(EeTarget {
                world_from_ee_command,
                gripper,
            }),
            ee_reference: None,
        })
    }
}

/// How long a rollout may run before it times out.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EpisodeLength {
    /// The task's episode length (AMBENCH_SPEC §4): ⌈length·rate⌉ − 1 steps.
    Spec,
    /// The task's length, or longer where the scripted policy needs it: up to its last
    /// waypoint plus one second. The reference records its scripted demonstrations with the
    /// episode length given on the command line (`--env_length_s`), which longer scripts
    /// need (Wipe Window's script visits its four stains over 3540 steps, the task's
    /// episode has 2399); only Wipe Window is affected.
    Script,
    /// A fixed length, s.
    Seconds(f64),
}

impl EpisodeLength {
    /// The most env steps of a rollout of `task` whose script ends at `script_end`.
    pub fn max_steps(self, task: TaskId, rate_hz: f64, script_end: u64) -> u64 {
        let spec = task.max_steps(rate_hz);
        match self {
            Self::Spec => spec,
            // The rate is a small positive number: the cast is exact.
            Self::Script => spec.max(script_end + rate_hz.round() as u64),
            Self::Seconds(s) => ((s * rate_hz).ceil() as u64).saturating_sub(1),
        }
    }
}
