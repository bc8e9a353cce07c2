//! Recording demonstrations: the observer that makes an episode's frames from the flight
//! loop, the source wrapper whose actions are exactly the float32 values recorded, the
//! source that flies recorded actions again, and the loop over rollouts (`amstack record`).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use platform::Vehicle;
use sim_twin::TaskId;

use super::layout::{
    ActionSemantics, StateKey, action_of_vector, action_vector, state_vector, task_prompt,
};
use super::write::{EpisodeFrames, EpisodeSource, encode_png};
use super::{DatasetError, DatasetWriter};
use crate::bench::{BenchConfig, BenchError, RolloutHooks, rollout_seed, run_rollout_with};
use crate::flight::{
    ActionSource, Decided, FlightError, FrameUse, Observation, Observer, ScriptedTask, SourceError,
    Step,
};
use crate::stack::{Action, FlightStack, Interface};

/// Builds an episode's frames: at every tick k, the observation state of the measurement
/// the tick acted on, and the action the stack was given after it (AMBENCH_SPEC §5.3: the
/// action recorded before the step, paired with the observation that preceded it).
#[derive(Debug)]
pub struct Recorder {
    vehicle: Vehicle,
    keys: Vec<StateKey>,
    action_dim: usize,
    cameras: Vec<String>,
    frames: EpisodeFrames,
}

impl Recorder {
    /// A recorder of `keys` on `vehicle`, with actions of `action_dim` values and the images
    /// of `cameras` (names of the flight's camera rig; each tick's frames are asked for).
    pub fn new(
        vehicle: &Vehicle,
        keys: &[StateKey],
        action_dim: usize,
        cameras: &[String],
    ) -> Self {
        Self {
            vehicle: vehicle.clone(),
            keys: keys.to_vec(),
            action_dim,
            cameras: cameras.to_vec(),
            frames: EpisodeFrames {
                images: vec![Vec::new(); cameras.len()],
                ..EpisodeFrames::default()
            },
        }
    }

    /// The frames so far.
    pub fn frames(&self) -> &EpisodeFrames {
        &self.frames
    }

    /// The episode, for `task` (its prompt), from `source`.
    pub fn finish(mut self, task: TaskId, source: EpisodeSource) -> EpisodeFrames {
        self.frames.task = task_prompt(task).to_owned();
        self.frames.source = source;
        self.frames
    }
}

impl Observer for Recorder {
    fn wants_frames(&self, _k: u64) -> FrameUse {
        if self.cameras.is_empty() {
            FrameUse::None
        } else {
            FrameUse::Decided
        }
    }

    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        if !self.cameras.is_empty() {
            let frames = tick.frames.filter(|f| f.k == tick.k).ok_or_else(|| {
                SourceError(format!("tick {}: no images of its observation", tick.k))
            })?;
            for (name, out) in self.cameras.iter().zip(&mut self.frames.images) {
                let frame = frames.get(name).ok_or_else(|| {
                    SourceError(format!("tick {}: no image of camera {name}", tick.k))
                })?;
                let png = encode_png(frame.image.width, frame.image.height, &frame.image.rgb)
                    .map_err(|e| SourceError(format!("tick {}: camera {name}: {e}", tick.k)))?;
                out.push(png);
            }
        }
        let action = tick.action.ok_or_else(|| {
            SourceError(
                "the recorder needs the action of every tick (not an open-loop command)".into(),
            )
        })?;
        let v = action_vector(action);
        if v.len() != self.action_dim {
            return Err(SourceError(format!(
                "tick {}: an action of {} values where the dataset records {}",
                tick.k,
                v.len(),
                self.action_dim
            ))
            .into());
        }
        state_vector(
            &self.vehicle,
            &self.keys,
            tick.measurement,
            &mut self.frames.state,
        );
        self.frames.action.extend(v);
        Ok(())
    }
}

/// A source whose every action is converted to `interface` (an EE target through the
/// whole-body IK, as the flight would) and rounded to float32 before the stack gets it: the
/// action the dataset records is then exactly the action applied, and a replay of it flies
/// the same flight bit for bit. The rounding moves a target by at most 6e-8 of its value.
#[derive(Debug)]
pub struct QuantizedActions<S> {
    inner: S,
    interface: Interface,
}

impl<S> QuantizedActions<S> {
    /// `inner`'s actions in `interface`, rounded.
    pub fn new(inner: S, interface: Interface) -> Self {
        Self { inner, interface }
    }
}

impl<S: ActionSource> ActionSource for QuantizedActions<S> {
    fn start(&mut self, first: &Observation<'_>) -> Result<(), SourceError> {
        self.inner.start(first)
    }

    fn tick_limit(&self) -> Option<u64> {
        self.inner.tick_limit()
    }

    fn wants_frames(&self, k: u64) -> bool {
        self.inner.wants_frames(k)
    }

    fn next(
        &mut self,
        k: u64,
        observation: &Observation<'_>,
        stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        match self.inner.next(k, observation, stack)? {
            Step::Act {
                action,
                ee_reference,
            } => {
                let reference = ee_reference.unwrap_or_else(|| stack.ee_reference(&action));
                let action = stack.convert(action, self.interface, &reference);
                let semantics = match action {
                    Action::Ee(_) => ActionSemantics::EeAbsolute,
                    Action::BaseJoint(_) => ActionSemantics::BaseJointAbsolute,
                };
                let rounded = action_of_vector(semantics, &action_vector(&action))
                    .ok_or_else(|| SourceError(format!("tick {k}: an action of too few values")))?;
                Ok(Step::Act {
                    action: rounded,
                    // The EE interface scores the target flown; the joint interface the
                    // script's EE target (as the benchmark does).
                    ee_reference: (self.interface == Interface::BaseJoint).then_some(reference),
                })
            }
            open_loop => Ok(open_loop),
        }
    }
}

/// Recorded actions flown again, one per tick (the dataset's `action` column of one
/// episode), through the whole flight stack.
#[derive(Debug, Clone)]
pub struct RecordedActions {
    semantics: ActionSemantics,
    dim: usize,
    actions: Vec<f32>,
}

impl RecordedActions {
    /// The actions (row-major, `dim` per tick) meaning `semantics`.
    pub fn new(semantics: ActionSemantics, dim: usize, actions: Vec<f32>) -> Self {
        Self {
            semantics,
            dim: dim.max(1),
            actions,
        }
    }
}

impl ActionSource for RecordedActions {
    fn tick_limit(&self) -> Option<u64> {
        Some((self.actions.len() / self.dim) as u64)
    }

    fn next(
        &mut self,
        k: u64,
        _observation: &Observation<'_>,
        _stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        let k = k as usize;
        let row = self
            .actions
            .get(k * self.dim..(k + 1) * self.dim)
            .ok_or_else(|| SourceError(format!("tick {k}: no recorded action")))?;
        let action = action_of_vector(self.semantics, row).ok_or_else(|| {
            SourceError(format!("tick {k}: not a {} action", self.semantics.name()))
        })?;
        Ok(Step::Act {
            action,
            ee_reference: None,
        })
    }
}

/// What `amstack record` runs.
#[derive(Debug, Clone)]
pub struct RecordConfig {
    /// The rollouts (platform, controller, interface, twin, episode length, jobs); its
    /// first task is recorded.
    pub bench: BenchConfig,
    /// Episodes the dataset should hold at the end (a shard: its quota).
    pub episodes: u64,
    /// Save failed episodes too.
    pub save_failed: bool,
    /// The observation state's keys.
    pub state_keys: Vec<StateKey>,
    /// The first attempt's index (its seed is the run seed + it); after a resume, the one
    /// after the last attempt the dataset holds (or, a shard, decided).
    pub first_attempt: u64,
    /// The attempts made are `first_attempt + j · attempt_step` (1; a shard of n: n).
    pub attempt_step: u64,
    /// Attempts are below this index.
    pub attempt_end: u64,
}

/// One attempt, when its episode was saved or dropped.
#[derive(Debug, Clone, PartialEq)]
pub struct Attempt {
    /// Its index (seed = run seed + index).
    pub index: u64,
    /// Whether the task succeeded.
    pub success: bool,
    /// Frames.
    pub frames: u64,
    /// Whether it was written to the dataset.
    pub saved: bool,
}

/// What a recording did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordReport {
    /// Attempts decided (saved or dropped) by this run.
    pub attempts: u64,
    /// Successful attempts among them.
    pub successes: u64,
    /// Episodes written by this run.
    pub saved: u64,
    /// Frames written by this run.
    pub frames: u64,
    /// Env steps flown by this run (every attempt run, including those past the end).
    pub env_steps: u64,
    /// Wall-clock time, s.
    pub wall_time_s: f64,
    /// Stopped before the target.
    pub interrupted: bool,
}

/// A recording that could not go on.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// A rollout could not run.
    #[error(transparent)]
    Rollout(#[from] BenchError),
    /// The dataset could not be written.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
}

type Outcome = Result<(Attempt, Option<EpisodeFrames>), BenchError>;

/// Records episodes of `config.bench.tasks[0]` into `writer` until it holds
/// `config.episodes` or the attempts up to `config.attempt_end` were made: attempts run on
/// `config.bench.jobs` threads, and are written in attempt order, so the dataset does not
/// depend on the number of threads. `on_attempt` sees each attempt as it is decided; `stop`
/// ends the run between episodes (what was written stays valid).
pub fn record(
    config: &RecordConfig,
    writer: &mut DatasetWriter,
    on_attempt: &mut dyn FnMut(&Attempt),
    stop: &AtomicBool,
) -> Result<RecordReport, RecordError> {
    let started = Instant::now();
    let task = *config
        .bench
        .tasks
        .first()
        .ok_or_else(|| DatasetError::invalid("record", "no task to record"))?;
    let mut report = RecordReport::default();
    let step = config.attempt_step.max(1);
    let next = AtomicU64::new(0);
    let done = AtomicBool::new(writer.episodes() >= config.episodes);
    let env_steps = AtomicU64::new(0);
    let action_dim = writer.spec().action_dim;
    let (tx, rx) = mpsc::channel::<(u64, Outcome)>();
    let result: Result<(), RecordError> = std::thread::scope(|scope| {
        let threads = if config.bench.link.parallel() {
            config.bench.jobs.max(1)
        } else {
            1
        };
        for _ in 0..threads {
            let tx = tx.clone();
            let (next, done, env_steps) = (&next, &done, &env_steps);
            scope.spawn(move || {
                loop {
                    if done.load(Ordering::Relaxed) || stop.load(Ordering::Relaxed) {
                        break;
                    }
                    let j = next.fetch_add(1, Ordering::Relaxed);
                    let i = config.first_attempt.saturating_add(j.saturating_mul(step));
                    if i >= config.attempt_end {
                        break;
                    }
                    let outcome = attempt(config, task, i, action_dim, stop);
                    if let Ok((a, _)) = &outcome {
                        env_steps.fetch_add(a.frames, Ordering::Relaxed);
                    }
                    if tx.send((i, outcome)).is_err() {
                        break;
                    }
                }
                crate::bench::release_worker_rig();
            });
        }
        drop(tx);
        // Write in attempt order as the attempts come in.
        let mut pending: BTreeMap<u64, Outcome> = BTreeMap::new();
        let mut want = config.first_attempt;
        for (i, outcome) in rx {
            pending.insert(i, outcome);
            while let Some(outcome) = pending.remove(&want) {
                want += step;
                if done.load(Ordering::Relaxed) {
                    continue;
                }
                let (mut a, episode) = match outcome {
                    Ok(x) => x,
                    Err(e) => {
                        done.store(true, Ordering::Relaxed);
                        return Err(e.into());
                    }
                };
                if stop.load(Ordering::Relaxed) && episode.is_none() {
                    continue;
                }
                report.attempts += 1;
                report.successes += u64::from(a.success);
                let kept = episode.filter(|_| a.success || config.save_failed);
                match writer.decide(a.index, a.success, kept) {
                    Err(e) => {
                        done.store(true, Ordering::Relaxed);
                        return Err(e.into());
                    }
                    Ok(true) => {
                        a.saved = true;
                        report.saved += 1;
                        report.frames += a.frames;
                    }
                    Ok(false) => {}
                }
                on_attempt(&a);
                if writer.episodes() >= config.episodes {
                    done.store(true, Ordering::Relaxed);
                }
            }
        }
        Ok(())
    });
    result?;
    report.env_steps = env_steps.load(Ordering::Relaxed);
    report.wall_time_s = started.elapsed().as_secs_f64();
    report.interrupted = stop.load(Ordering::Relaxed) && writer.episodes() < config.episodes;
    Ok(report)
}

/// One attempt: the rollout of `index`, recorded (None if it was interrupted).
fn attempt(
    config: &RecordConfig,
    task: TaskId,
    index: u64,
    action_dim: usize,
    stop: &AtomicBool,
) -> Outcome {
    let bench = &config.bench;
    let seed = rollout_seed(bench.seed, index as usize);
    let rate_hz = bench.twin.control_rate_hz;
    let mut source = QuantizedActions::new(
        ScriptedTask::new(task, seed, rate_hz, bench.episode),
        bench.interface,
    );
    let cameras: Vec<String> = bench
        .cameras
        .as_ref()
        .map(|c| c.cameras.iter().map(|s| s.name.clone()).collect())
        .unwrap_or_default();
    let mut recorder = Recorder::new(&bench.vehicle, &config.state_keys, action_dim, &cameras);
    let result = run_rollout_with(
        bench,
        task,
        index as usize,
        stop,
        None,
        RolloutHooks {
            source: Some(&mut source),
            observers: vec![&mut recorder],
        },
    )?;
    let attempt = Attempt {
        index,
        success: result.success,
        frames: result.executed_steps,
        saved: false,
    };
    if result.termination == crate::bench::Termination::Interrupted {
        return Ok((attempt, None));
    }
    let mut episode = recorder.finish(
        task,
        EpisodeSource {
            task_name: task.name().to_owned(),
            seed: Some(seed),
            success: result.success,
            attempt: index,
        },
    );
    // The recorder saw every decided tick; the last one's setpoint may not have been sent
    // (a non-finite command): keep the frames the twin applied.
    let applied = result.executed_steps as usize;
    let n = episode.action.len() / action_dim.max(1);
    if n > applied {
        let state_dim = episode.state.len() / n.max(1);
        episode.state.truncate(applied * state_dim);
        episode.action.truncate(applied * action_dim);
        for images in &mut episode.images {
            images.truncate(applied);
        }
    }
    Ok((attempt, Some(episode)))
}
