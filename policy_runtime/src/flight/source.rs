//! Action sources: what chooses the action of each tick. A source sees the tick's
//! observation; it may answer every tick or hold a chunk of actions.
//!
//! - [`TrajectorySource`]: a reference trajectory (`amstack track`, `fly`): a base + joint
//!   target of time;
//! - [`ScriptedTask`]: a task's scripted demonstration (the benchmark's rollouts), built from
//!   the first observation;
//! - the logged actions of a flight (`replay`: [`crate::validation::replay`]).

use nalgebra::Isometry3;
use platform::{Measurement, RandomStream, Vehicle};
use sim_twin::{TaskId, TaskSnapshot};

use crate::bench::EpisodeLength;
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
