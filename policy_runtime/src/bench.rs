//! The benchmark runner (`amstack bench`): tasks × rollouts of the scripted policies in the
//! twin, through the flight stack, scored with the metrics of AMBENCH_SPEC §6.
//!
//! A rollout (AMBENCH_SPEC §4.0, §6):
//! 1. the twin is built with the task scene at rollout seed s = run seed + rollout index
//!    (the reference seeds batch b with base seed + b's first index); the scene's
//!    randomisation, the observation noise, the policy's offsets and the action noise are
//!    separate streams of s;
//! 2. the scripted policy is built from the reset observation; every env step it gives an
//!    end-effector target (command frame) and a gripper action; with the base + joint
//!    interface the target goes through the stack's whole-body IK first and the base + joint
//!    target is what the controller gets;
//! 3. the step's tracking record is taken, the command sent, the twin stepped; the criteria
//!    are latched; success terminates; otherwise the rollout ends after
//!    ⌈episode_length·120⌉ − 1 steps (timeout).
//!
//! Rollouts run in parallel threads; each is a pure function of its seed, so results do not
//! depend on the number of threads or their order.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

use controllers::ControllerConfig;
use platform::{RandomStream, Vehicle};
use serde::Serialize;
use sim_twin::{TaskId, TwinConfig, TwinError};

pub use self::episode::BenchLink;
pub use self::shard::{ASSIGNMENT as SHARD_ASSIGNMENT, Shard, ShardError, first_difference};
use crate::cameras::{CameraConfig, CameraRig};
use crate::flight::{
    ActionNoise, ActionSource, BenchMetrics, End, FlightError, FlightSpec, Observer, ScriptedTask,
    TaskCriteria,
};
use crate::flight_log::FlightLog;
use crate::link::LinkError;
use crate::metrics::{RolloutSummary, RunSummary, summarize_rollout, summarize_run};
use crate::policy::{PolicyConfig, PolicySource, PolicyStats, task_prompt};
use crate::record::{McapRecorder, RecordError, RunMetadata};
use crate::stack::{FlightStack, Interface, StackError};
use crate::state_source::{EstimateError, EstimatorSummary, StateSource};

mod episode;
mod shard;

/// What to run.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// The vehicle.
    pub vehicle: Vehicle,
    /// Base controller and gains.
    pub controller: ControllerConfig,
    /// The controller's benchmark name (`ik-pid`, `pid`, `ik-l1`, `l1`, `mpc`).
    pub controller_name: String,
    /// Action interface.
    pub interface: Interface,
    /// Tasks, in order.
    pub tasks: Vec<TaskId>,
    /// Rollouts per task.
    pub rollouts: usize,
    /// Run seed.
    pub seed: u64,
    /// The twin (disturbances, motor model, noise); its `task` and `seed` are set per
    /// rollout.
    pub twin: TwinConfig,
    /// Worker threads.
    pub jobs: usize,
    /// How long a rollout may run.
    pub episode: EpisodeLength,
    /// Directory for one MCAP log per rollout (`<task>/rollout-NNN.mcap`), if any.
    pub mcap_dir: Option<PathBuf>,
    /// Where the rollouts run (this process, or the twin's process over iceoryx2).
    pub link: BenchLink,
    /// Where the controllers' base state comes from (the measurement, or the estimator).
    pub state_source: StateSource,
    /// A learned policy instead of the scripted ones (its prompt defaults to the task's).
    pub policy: Option<PolicyConfig>,
    /// The cameras rendered in each rollout (the in-process twin only), if any.
    pub cameras: Option<CameraConfig>,
    /// The live view every rollout's log channels stream to as it flies (`--live`), if any.
    pub live: Option<std::sync::Arc<crate::live::LiveServer>>,
}

pub use crate::flight::EpisodeLength;

/// Why a rollout ended (the reference's termination reasons).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    /// The success criterion held.
    Success,
    /// The episode's time ran out.
    Timeout,
    /// The stack produced a command the twin refused (non-finite).
    NanAction,
    /// The simulation diverged.
    Diverged,
    /// Stopped on request.
    Interrupted,
    /// The learned policy failed (unreachable, died, timed out, or answered something that
    /// must not be flown): the rollout's `policy.failure` says why.
    PolicyFailed,
}

/// One rollout's result.
#[derive(Debug, Clone, Serialize)]
pub struct RolloutResult {
    /// Task.
    pub task: TaskId,
    /// Index within the task.
    pub index: usize,
    /// Rollout seed.
    pub seed: u64,
    /// Success.
    pub success: bool,
    /// Whether the task's state was observed: always in the twin; over MAVLink only from
    /// an autopilot that sends it (the twin's). Unobserved, `success` is false and the
    /// criteria unknown.
    pub task_observed: bool,
    /// Why it ended.
    pub termination: Termination,
    /// What the twin saw when the rollout ended `diverged` (which state, at what time).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub divergence: Option<String>,
    /// Env steps executed.
    pub executed_steps: u64,
    /// Each criterion, latched "ever true", by name.
    pub criteria: Vec<(String, bool)>,
    /// Metrics of the rollout.
    pub summary: RolloutSummary,
    /// Wall-clock time, s.
    pub wall_time_s: f64,
    /// The rollout's MCAP log.
    pub mcap: Option<PathBuf>,
    /// The estimator's figures (with `--state-source estimator`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimator: Option<EstimatorSummary>,
    /// The rollout's video (with `--video`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub video: Option<PathBuf>,
    /// The learned policy's queries, latencies and failure (with a policy).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub policy: Option<PolicyStats>,
}

/// A rollout that could not run at all.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The stack cannot be built.
    #[error(transparent)]
    Stack(#[from] StackError),
    /// The twin refused its configuration.
    #[error("twin: {0}")]
    Twin(#[from] TwinError),
    /// The scripted policy could not be built.
    #[error("{task} scripted policy: {message}")]
    Policy {
        /// The task.
        task: TaskId,
        /// What went wrong.
        message: String,
    },
    /// A log could not be written.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The link refused, failed or stopped answering (a refusal — another scene on the
    /// autopilot, a configuration the twin process does not serve — is the user's input).
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The state estimator could not start or diverged.
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    /// The cameras could not be rendered.
    #[error("{0}")]
    Cameras(String),
}

impl BenchError {
    fn of_flight(e: FlightError, task: TaskId) -> Self {
        match e {
            FlightError::Link(e) => Self::Link(e),
            FlightError::Record(e) => Self::Record(e),
            FlightError::Estimate(e) => Self::Estimate(e),
            FlightError::Stack(e) => Self::Stack(e),
            FlightError::Source(e) => Self::Policy {
                task,
                message: e.to_string(),
            },
            // Cameras over a link that cannot render them: the user's choice of link.
            e @ FlightError::CamerasNeedTwin(_) => Self::Link(LinkError::Refused(e.to_string())),
            e @ FlightError::Cameras(_) => Self::Cameras(e.to_string()),
        }
    }
}

/// Per-task aggregate.
#[derive(Debug, Clone, Serialize)]
pub struct TaskResult {
    /// Task.
    pub task: TaskId,
    /// Criteria names.
    pub criteria: Vec<String>,
    /// The run-level summary (success rate, subtask completion, spreads over successes).
    pub summary: RunSummary,
    /// Every rollout.
    pub rollouts: Vec<RolloutResult>,
}

/// Everything a benchmark run produced.
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    /// Per task, in the configured order.
    pub tasks: Vec<TaskResult>,
    /// Wall-clock time of the whole run, s.
    pub wall_time_s: f64,
    /// Env steps simulated over all rollouts.
    pub env_steps: u64,
    /// Whether the run was interrupted (results are partial).
    pub interrupted: bool,
}

impl BenchReport {
    /// Env steps per wall-clock second over the run.
    pub fn steps_per_second(&self) -> f64 {
        self.env_steps as f64 / self.wall_time_s.max(1e-9)
    }
}

/// The seed of rollout `index` of a run seeded `run_seed`.
pub fn rollout_seed(run_seed: u64, index: usize) -> u64 {
    run_seed.wrapping_add(index as u64)
}

/// Runs one rollout of `task`, logged under the run's `mcap_dir`. `stop` interrupts it
/// between steps.
pub fn run_rollout(
    config: &BenchConfig,
    task: TaskId,
    index: usize,
    stop: &AtomicBool,
) -> Result<RolloutResult, BenchError> {
    let log = config
        .mcap_dir
        .as_ref()
        .map(|dir| rollout_log_path(dir, task, index));
    run_rollout_logged(config, task, index, stop, log.as_deref())
}

/// Runs one rollout of `task`, logged to `log_path` if given (`amstack fly --trajectory scripted`
/// flies one rollout this way).
pub fn run_rollout_logged(
    config: &BenchConfig,
    task: TaskId,
    index: usize,
    stop: &AtomicBool,
    log_path: Option<&Path>,
) -> Result<RolloutResult, BenchError> {
    run_rollout_with(config, task, index, stop, log_path, RolloutHooks::default())
}

/// What a caller plugs into a rollout besides the benchmark's own parts (`amstack record`:
/// the script with its actions rounded to what the dataset stores, and the recorder).
#[derive(Default)]
pub struct RolloutHooks<'a> {
    /// The action source in place of the task's script (built for the rollout's seed).
    pub source: Option<&'a mut dyn ActionSource>,
    /// Observers after the benchmark's (criteria, log, metrics).
    pub observers: Vec<&'a mut dyn Observer>,
}

impl std::fmt::Debug for RolloutHooks<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RolloutHooks")
            .field("source", &self.source.is_some())
            .field("observers", &self.observers.len())
            .finish()
    }
}

/// Runs one rollout of `task` as [`run_rollout_logged`] does, with `hooks` plugged in.
pub fn run_rollout_with(
    config: &BenchConfig,
    task: TaskId,
    index: usize,
    stop: &AtomicBool,
    log_path: Option<&Path>,
    hooks: RolloutHooks<'_>,
) -> Result<RolloutResult, BenchError> {
    let started = Instant::now();
    let seed = rollout_seed(config.seed, index);
    let vehicle = &config.vehicle;
    let twin_config = TwinConfig {
        task: Some(task),
        seed,
        ..config.twin.clone()
    };
    let rate_hz = twin_config.control_rate_hz;
    let mut link = config.link.open(vehicle, &twin_config)?;
    let mut stack = FlightStack::for_twin(vehicle.clone(), &config.controller, &twin_config)?;
    // Action noise (AMBENCH_SPEC §3.1: N(0, σ²) on the whole action vector), its own stream.
    let action_noise = if config.twin.disturbances.action_noise {
        ActionNoise::new(
            config.twin.noise.action_std,
            RandomStream::ActionNoise,
            seed,
        )
    } else {
        None
    };
    let criteria_names = task.criteria_names();
    let mut criteria = TaskCriteria::new(criteria_names.len(), true);
    // The cameras first: a machine that cannot render leaves no log behind.
    let mut rig = match &config.cameras {
        Some(c) => Some(worker_rig(c, vehicle)?),
        None => None,
    };
    let recorder =
        McapRecorder::for_flight(log_path, config.live.as_ref().map(|l| l.tap()), || {
            RunMetadata::new(&vehicle.id, &config.controller_name, seed)
                .with_interface(config.interface.name())
                .with_trajectory(format!("task:{}", task.name()))
                .with_config(&twin_config)?
                .with_controller_config(&config.controller)
        })?;
    let mut log = match recorder {
        None => None,
        Some(recorder) => Some(
            FlightLog::new(recorder, vehicle)?
                .with_rotor_limits(twin_config.disturbances.saturation)
                .with_camera_log(config.cameras.as_ref().map_or(0, |c| c.log_every)),
        ),
    };
    let mut video = match config.cameras.as_ref().and_then(|c| c.video.as_ref()) {
        Some(v) => {
            let path = rollout_video_path(&v.path, task, index);
            if let Some(dir) = path.parent() {
                std::fs::create_dir_all(dir).map_err(|e| {
                    BenchError::Cameras(format!("cannot create {}: {e}", dir.display()))
                })?;
            }
            Some(v.writer(path))
        }
        None => None,
    };
    let limits_n = (!vehicle.rotors.is_empty())
        .then_some((vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n));
    let mut metrics = BenchMetrics::new(
        limits_n,
        usize::try_from(task.max_steps(rate_hz)).unwrap_or(0),
    );
    let mut scripted = ScriptedTask::new(task, seed, rate_hz, config.episode);
    let mut learned = match &config.policy {
        None => None,
        Some(policy) => Some(
            PolicySource::new(
                policy,
                vehicle,
                config.interface,
                rate_hz,
                task_prompt(task),
            )
            .map_err(|message| BenchError::Policy { task, message })?
            .with_tick_limit(config.episode.max_steps(task, rate_hz, 0)),
        ),
    };
    let RolloutHooks {
        source,
        observers: mut extra,
    } = hooks;
    // A caller's source (a recorder's), else the learned policy, else the task's script.
    let source: &mut dyn ActionSource = match (source, &mut learned) {
        (Some(s), _) => s,
        (None, Some(l)) => l,
        (None, None) => &mut scripted,
    };
    let flown = {
        // The criteria latch fills the task state the log writes after it.
        let mut observers: Vec<&mut dyn Observer> = vec![&mut criteria];
        if let Some(log) = &mut log {
            observers.push(log);
        }
        observers.push(&mut metrics);
        if let Some(v) = &mut video {
            observers.push(v);
        }
        for o in &mut extra {
            observers.push(&mut **o);
        }
        crate::flight::run(
            link.as_mut(),
            &mut stack,
            source,
            &mut observers,
            FlightSpec {
                max_ticks: task.max_steps(rate_hz),
                dt_s: twin_config.control_dt_s(),
                control_rate_hz: rate_hz,
                seed,
                state_source: config.state_source,
                score_from_s: 0.0,
                interface: Some(config.interface),
                action_noise,
                stop: Some(stop),
                cameras: rig.as_mut().and_then(WorkerRig::rig),
            },
        )
    };
    let observed = link.task_observed();
    // The log and the video are finished whether or not the flight ended well (what they
    // hold survives it), but a failed flight's own error comes first: a log whose write
    // failed mid-flight (a full disk) fails its finish too, and would only say that.
    let log = log.map(|log| log.finish());
    let video = video.map(|v| v.finish());
    let flown = flown.map_err(|e| BenchError::of_flight(e, task))?;
    let mcap = match log {
        Some(finished) => Some(finished?.path).filter(|_| log_path.is_some()),
        None => None,
    };
    let video = match video {
        Some(finished) => finished?.map(|s| s.path),
        None => None,
    };
    let divergence = match &flown.end {
        End::Diverged(why) => Some(why.clone()),
        _ => None,
    };
    let termination = match flown.end {
        End::Success => Termination::Success,
        End::Completed => Termination::Timeout,
        End::Interrupted => Termination::Interrupted,
        End::NanAction => Termination::NanAction,
        End::Diverged(_) => Termination::Diverged,
        End::PolicyFailed(_) => Termination::PolicyFailed,
    };
    let success = termination == Termination::Success;
    let reach = arm_reach_m(vehicle);
    let latch = criteria.latch();
    Ok(RolloutResult {
        task,
        index,
        seed,
        success,
        task_observed: observed,
        termination,
        divergence,
        executed_steps: flown.ticks,
        criteria: criteria_names
            .iter()
            .zip(latch.reached())
            .map(|(n, r)| ((*n).to_owned(), *r))
            .collect(),
        summary: summarize_rollout(&metrics.records, success, latch.completion(), reach),
        wall_time_s: started.elapsed().as_secs_f64(),
        mcap,
        estimator: flown.estimator,
        video,
        policy: learned.map(|l| l.stats()),
    })
}

thread_local! {
    /// The camera rig of this worker thread, kept from rollout to rollout (opening the adapter
    /// is the slow part), with the cameras and vehicle it was built for.
    static WORKER_RIG: std::cell::RefCell<Option<(CameraConfig, String, CameraRig)>> =
        const { std::cell::RefCell::new(None) };
}

/// This worker's rig for `cameras` on `vehicle` (built on its first rollout, or when the
/// configuration changed), lent to one rollout.
struct WorkerRig(Option<(CameraConfig, String, CameraRig)>);

impl WorkerRig {
    fn rig(&mut self) -> Option<&mut CameraRig> {
        self.0.as_mut().map(|(_, _, rig)| rig)
    }
}

impl Drop for WorkerRig {
    fn drop(&mut self) {
        let kept = self.0.take();
        // At thread exit the slot is gone: the rig is dropped with it.
        let _ = WORKER_RIG.try_with(|slot| *slot.borrow_mut() = kept);
    }
}

/// Drops this thread's kept camera rig now. A worker calls it before it ends: dropped with the
/// thread's other thread-locals instead, the graphics objects may reach for one already gone
/// (an abort at thread exit).
pub fn release_worker_rig() {
    let kept = WORKER_RIG
        .try_with(|slot| slot.borrow_mut().take())
        .ok()
        .flatten();
    drop(kept);
}

fn worker_rig(cameras: &CameraConfig, vehicle: &Vehicle) -> Result<WorkerRig, BenchError> {
    let kept = WORKER_RIG
        .try_with(|slot| slot.borrow_mut().take())
        .ok()
        .flatten()
        .filter(|(c, id, _)| c == cameras && *id == vehicle.id);
    let entry = match kept {
        Some(entry) => entry,
        None => {
            let rig = cameras
                .rig(vehicle)
                .map_err(|e| BenchError::Cameras(e.to_string()))?;
            (cameras.clone(), vehicle.id.clone(), rig)
        }
    };
    Ok(WorkerRig(Some(entry)))
}

/// Where rollout `index` of `task` writes its video under `dir`.
pub fn rollout_video_path(dir: &Path, task: TaskId, index: usize) -> PathBuf {
    dir.join(task.name())
        .join(format!("rollout-{index:03}.mp4"))
}

/// The arm reach the errors are normalised by: the vehicle's, or ‖p_ee − p_base‖ at the
/// initial configuration (0 for the EE-only oracle: its normalised errors are undefined).
fn arm_reach_m(vehicle: &Vehicle) -> f64 {
    vehicle.max_arm_reach_m.unwrap_or_else(|| {
        let q = vehicle.initial_configuration();
        vehicle.base_from_ee(&q).translation.vector.norm()
    })
}

/// Where rollout `index` of `task` logs under `dir`.
pub fn rollout_log_path(dir: &Path, task: TaskId, index: usize) -> PathBuf {
    dir.join(task.name())
        .join(format!("rollout-{index:03}.mcap"))
}

/// Runs every task's rollouts on `config.jobs` threads. `on_done` sees each rollout as it
/// finishes (progress); `stop` interrupts the run (finished rollouts are kept).
pub fn run_bench(
    config: &BenchConfig,
    on_done: &(dyn Fn(&RolloutResult) + Sync),
    stop: &AtomicBool,
) -> Result<BenchReport, BenchError> {
    run_bench_shard(config, Shard::WHOLE, on_done, stop)
}

/// Runs the rollouts of `shard` of the run (all of them for [`Shard::WHOLE`]) as
/// [`run_bench`] does; each task's result holds the shard's rollouts of that task.
pub fn run_bench_shard(
    config: &BenchConfig,
    shard: Shard,
    on_done: &(dyn Fn(&RolloutResult) + Sync),
    stop: &AtomicBool,
) -> Result<BenchReport, BenchError> {
    let started = Instant::now();
    let jobs: Vec<(TaskId, usize)> = shard.rollouts(&config.tasks, config.rollouts);
    if let Some(dir) = &config.mcap_dir {
        for task in &config.tasks {
            if !jobs.iter().any(|(t, _)| t == task) {
                continue;
            }
            let path = dir.join(task.name());
            std::fs::create_dir_all(&path)
                .map_err(|source| RecordError::Create { path, source })?;
        }
    }
    let results: Mutex<Vec<Option<Result<RolloutResult, BenchError>>>> =
        Mutex::new((0..jobs.len()).map(|_| None).collect());
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    std::thread::scope(|scope| {
        // The twin process serves one flight at a time.
        let threads = if config.link.parallel() {
            config.jobs.max(1)
        } else {
            1
        };
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    if stop.load(Ordering::Relaxed) || failed.load(Ordering::Relaxed) {
                        break;
                    }
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&(task, index)) = jobs.get(k) else {
                        break;
                    };
                    let result = run_rollout(config, task, index, stop);
                    match &result {
                        Ok(r) if r.termination != Termination::Interrupted => on_done(r),
                        Ok(_) => {}
                        Err(_) => failed.store(true, Ordering::Relaxed),
                    }
                    if let Ok(mut all) = results.lock() {
                        all[k] = Some(result);
                    }
                }
                release_worker_rig();
            });
        }
    });
    let all = results.into_inner().unwrap_or_default();
    let mut done: Vec<RolloutResult> = Vec::with_capacity(all.len());
    for r in all.into_iter().flatten() {
        let r = r?;
        if r.termination != Termination::Interrupted {
            done.push(r);
        }
    }
    let interrupted = stop.load(Ordering::Relaxed) || done.len() < jobs.len();
    let env_steps = done.iter().map(|r| r.executed_steps).sum();
    let tasks = config
        .tasks
        .iter()
        .map(|&task| {
            let rollouts: Vec<RolloutResult> =
                done.iter().filter(|r| r.task == task).cloned().collect();
            let summaries: Vec<RolloutSummary> =
                rollouts.iter().map(|r| r.summary.clone()).collect();
            TaskResult {
                task,
                criteria: task
                    .criteria_names()
                    .iter()
                    .map(|n| (*n).to_owned())
                    .collect(),
                summary: summarize_run(&summaries),
                rollouts,
            }
        })
        .collect();
    Ok(BenchReport {
        tasks,
        wall_time_s: started.elapsed().as_secs_f64(),
        env_steps,
        interrupted,
    })
}

#[cfg(test)]
mod tests;
