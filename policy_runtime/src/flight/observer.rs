//! Observers: what consumes a flight's ticks. Each is a value the runner calls; none is code
//! inside the loop.
//!
//! - [`crate::flight_log::FlightLog`]: the MCAP log (every channel of `docs/mcap-format.md`);
//! - [`TaskCriteria`]: the task's criteria latch and its stop rule (success ends a rollout);
//! - [`TrackMetrics`]: the tracking figures of `amstack track`;
//! - [`BenchMetrics`]: the per-step records of the benchmark's metrics (AMBENCH_SPEC §6);
//! - [`Progress`]: a callback about once a simulated second, which may stop the flight.

use std::ops::ControlFlow;

use nalgebra::Isometry3;
use platform::Measurement;
use sim_twin::{SceneVisual, TaskSnapshot};

use super::FlightError;
use crate::cameras::{FrameUse, Frames};
use crate::flight_log::{FlightLog, TaskState, rotors_saturated};
use crate::link::LinkMessage;
use crate::metrics::{CriteriaLatch, TrackingRecord};
use crate::stack::{Action, TickRecord};
use crate::state_source::EstimateReport;

/// The start of a flight.
#[derive(Debug, Clone, Copy)]
pub struct Start<'a> {
    /// The measurement at start.
    pub measurement: &'a Measurement,
    /// The link's log messages at start.
    pub link_messages: &'a [LinkMessage],
    /// The scene's shapes (floor, walls, task objects), when an observer
    /// [wants the scene](Observer::wants_scene) and the link has one to show.
    pub scene_visuals: Option<&'a [SceneVisual]>,
}

/// What tick `k` decided, before its setpoint is sent.
#[derive(Debug, Clone, Copy)]
pub struct Decided<'a> {
    /// Tick index.
    pub k: u64,
    /// t_k = k·dt, s.
    pub time_s: f64,
    /// The link's measurement the tick acted on.
    pub measurement: &'a Measurement,
    /// The action handed to the stack (None: an open-loop command).
    pub action: Option<&'a Action>,
    /// What the stack decided.
    pub record: &'a TickRecord,
    /// The end-effector reference of the tick.
    pub ee_reference: &'a Isometry3<f64>,
    /// The camera images of observation k (the state `measurement` was taken in), when the
    /// source or an observer asked for them at [`FrameUse::Decided`].
    pub frames: Option<&'a Frames>,
}

/// Tick `k` after the link applied it.
#[derive(Debug)]
pub struct Stepped<'a> {
    /// Tick index.
    pub k: u64,
    /// t_k = k·dt, s (the tick's start).
    pub time_s: f64,
    /// The measurement at the end of the tick.
    pub measurement: &'a Measurement,
    /// The task scene after the step.
    pub scene: Option<&'a TaskSnapshot>,
    /// Whether the scene's state is observed (not only the scene model of a vehicle that
    /// sends none).
    pub scene_observed: bool,
    /// The link's log messages of this step.
    pub link_messages: &'a [LinkMessage],
    /// The task's state with its latched criteria, filled by [`TaskCriteria`] for the
    /// observers after it (the log).
    pub task_state: Option<TaskState>,
    /// The camera images of observation k (the state at the tick's start, before this
    /// step), whenever they were rendered for anyone at tick k. The images after this step
    /// are those of observation k+1 (the next tick's).
    pub frames: Option<&'a Frames>,
    /// The world poses of [`Start::scene_visuals`] after the step (same order), when they
    /// were given.
    pub scene_poses: Option<&'a [Isometry3<f64>]>,
}

/// Why an observer stops a flight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// The task's success criterion held.
    Success,
    /// Stopped on request.
    Interrupted,
}

/// An observer's verdict after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Go on.
    Continue,
    /// End the flight after this tick.
    Stop(StopReason),
}

/// A consumer of a flight's ticks. Every method has a default that does nothing.
pub trait Observer {
    /// When this observer needs the camera images of observation `k`; asked before every
    /// tick of a flight with cameras. Default: never (nothing is rendered for it).
    fn wants_frames(&self, k: u64) -> FrameUse {
        let _ = k;
        FrameUse::None
    }

    /// Whether this observer draws the scene: the runner then gives it the scene's shapes at
    /// start ([`Start::scene_visuals`]) and their poses after every step
    /// ([`Stepped::scene_poses`]). Default: no.
    fn wants_scene(&self) -> bool {
        false
    }

    /// The start measurement and the link's first messages.
    fn start(&mut self, start: &Start<'_>) -> Result<(), FlightError> {
        let _ = start;
        Ok(())
    }

    /// What a tick decided, before its setpoint is sent.
    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        let _ = tick;
        Ok(())
    }

    /// The tick after the link applied it; may stop the flight.
    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        let _ = step;
        Ok(Flow::Continue)
    }

    /// The estimator's report at `time_s` (with the estimator as state source).
    fn estimated(&mut self, time_s: f64, report: &EstimateReport) -> Result<(), FlightError> {
        let _ = (time_s, report);
        Ok(())
    }

    /// The link failed; its last messages (best effort: the flight ends with the link's
    /// error whatever happens here).
    fn link_failed(&mut self, messages: &[LinkMessage]) {
        let _ = messages;
    }
}

impl Observer for FlightLog {
    fn wants_frames(&self, k: u64) -> FrameUse {
        let every = self.camera_log_every();
        if every > 0 && k.is_multiple_of(every) {
            FrameUse::Stepped
        } else {
            FrameUse::None
        }
    }

    fn wants_scene(&self) -> bool {
        true
    }

    fn start(&mut self, start: &Start<'_>) -> Result<(), FlightError> {
        if let Some(scene) = start.scene_visuals {
            self.set_scene(scene.to_vec());
        }
        Ok(self.link_messages(start.link_messages)?)
    }

    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        if let Some(action) = tick.action {
            self.action(tick.measurement.time_s, action)?;
        }
        Ok(self.tick(tick.measurement, tick.record, tick.ee_reference)?)
    }

    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        // The images of observation k (time t_k) before the outcome of its step (t_k+1).
        if let Some(frames) = step.frames {
            let every = self.camera_log_every();
            if every > 0 && frames.k.is_multiple_of(every) {
                self.cameras(frames)?;
            }
        }
        if let Some(poses) = step.scene_poses {
            self.set_scene_poses(poses);
        }
        self.outcome(step.measurement)?;
        self.link_messages(step.link_messages)?;
        if let Some(state) = &step.task_state {
            self.task_state(step.measurement.time_s, state)?;
        }
        Ok(Flow::Continue)
    }

    fn estimated(&mut self, time_s: f64, report: &EstimateReport) -> Result<(), FlightError> {
        Ok(self.estimate(
            time_s,
            &crate::flight_log::EstimatorState::from_report(report),
        )?)
    }

    fn link_failed(&mut self, messages: &[LinkMessage]) {
        let _ = self.link_messages(messages);
    }
}

/// The task's criteria, latched "ever true" over the flight, and the stop rule: with
/// `stop_on_success`, the flight ends on the first step whose success criterion holds.
/// Only an observed scene counts.
#[derive(Debug, Clone)]
pub struct TaskCriteria {
    latch: CriteriaLatch,
    stop_on_success: bool,
}

impl TaskCriteria {
    /// A latch of `count` criteria.
    pub fn new(count: usize, stop_on_success: bool) -> Self {
        Self {
            latch: CriteriaLatch::new(count),
            stop_on_success,
        }
    }

    /// The latch.
    pub fn latch(&self) -> &CriteriaLatch {
        &self.latch
    }
}

impl Observer for TaskCriteria {
    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        let Some(snapshot) = step.scene.filter(|_| step.scene_observed) else {
            return Ok(Flow::Continue);
        };
        self.latch.observe(&snapshot.status.criteria);
        step.task_state = Some(TaskState::from_snapshot(snapshot, self.latch.reached()));
        Ok(if self.stop_on_success && snapshot.status.success {
            Flow::Stop(StopReason::Success)
        } else {
            Flow::Continue
        })
    }
}

/// Sums of `amstack track`'s tracking figures (see [`crate::track`]): errors over the ticks
/// from `settle_s` on, the largest tilt and rotor thrust, the saturated share.
#[derive(Debug, Clone, Default)]
pub struct TrackMetrics {
    settle_s: f64,
    limits_n: (f64, f64),
    /// Scored ticks.
    pub n: u64,
    /// Σ‖e_ee‖², m².
    pub ee: f64,
    /// Σ‖e_base‖², m².
    pub base: f64,
    /// Σ e_base,z², m².
    pub base_z: f64,
    /// Largest √(roll² + pitch²), rad.
    pub tilt: f64,
    /// Scored ticks with saturated rotors.
    pub saturated: u64,
    /// Scored ticks with rotors.
    pub rotor_ticks: u64,
    /// Largest realised rotor thrust over the flight, N.
    pub max_thrust: Option<f64>,
}

impl TrackMetrics {
    /// Scoring from `settle_s` on, with rotor limits `limits_n` (min, max), N.
    pub fn new(settle_s: f64, limits_n: (f64, f64)) -> Self {
        Self {
            settle_s,
            limits_n,
            ..Self::default()
        }
    }

    /// The RMS of a sum of squares over the scored ticks (NaN without any).
    pub fn rms(&self, sum: f64) -> f64 {
        if self.n > 0 {
            (sum / self.n as f64).sqrt()
        } else {
            f64::NAN
        }
    }
}

impl Observer for TrackMetrics {
    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        if tick.time_s >= self.settle_s {
            let m = tick.measurement;
            let base_error =
                tick.record.base_target.translation.vector - m.base.position_in_world_m;
            let ee_error =
                tick.ee_reference.translation.vector - m.world_from_ee.translation.vector;
            let (roll, pitch, _) = m.base.world_from_body.euler_angles();
            self.n += 1;
            self.ee += ee_error.norm_squared();
            self.base += base_error.norm_squared();
            self.base_z += base_error.z * base_error.z;
            self.tilt = self.tilt.max(roll.hypot(pitch));
        }
        Ok(())
    }

    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        let m = step.measurement;
        if !m.rotors.is_empty() {
            let peak = m
                .rotors
                .iter()
                .map(|r| r.realised_n)
                .fold(f64::NEG_INFINITY, f64::max);
            self.max_thrust = Some(self.max_thrust.map_or(peak, |x| x.max(peak)));
            if step.time_s >= self.settle_s {
                self.rotor_ticks += 1;
                self.saturated += u64::from(rotors_saturated(m, self.limits_n));
            }
        }
        Ok(Flow::Continue)
    }
}

/// The benchmark's per-step records (AMBENCH_SPEC §6): desired and measured EE and base
/// poses of each step's start, and its saturation indicator (the allocation's, or the
/// rotors' over the step).
#[derive(Debug, Clone)]
pub struct BenchMetrics {
    limits_n: Option<(f64, f64)>,
    pending: Option<(TrackingRecord, bool)>,
    /// One record per step flown.
    pub records: Vec<TrackingRecord>,
}

impl BenchMetrics {
    /// Records for a vehicle with rotor limits `limits_n` (None: no rotors), room for
    /// `capacity` steps.
    pub fn new(limits_n: Option<(f64, f64)>, capacity: usize) -> Self {
        Self {
            limits_n,
            pending: None,
            records: Vec::with_capacity(capacity),
        }
    }
}

impl Observer for BenchMetrics {
    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        let m = tick.measurement;
        self.pending = Some((
            TrackingRecord {
                ee_desired: *tick.ee_reference,
                ee_actual: m.world_from_ee,
                base_desired: tick.record.base_target,
                base_actual: m.base.pose(),
                saturated: None,
                fallback: tick
                    .record
                    .mpc
                    .map(|s| s.mode == controllers::mpc::MpcMode::IkPid),
            },
            tick.record.allocation_saturated,
        ));
        Ok(())
    }

    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        if let Some((mut record, allocation_saturated)) = self.pending.take() {
            record.saturated = self
                .limits_n
                .map(|limits| allocation_saturated || rotors_saturated(step.measurement, limits));
            self.records.push(record);
        }
        Ok(Flow::Continue)
    }
}

/// Calls back about once a simulated second with the measurement's time; the callback's
/// `Break` stops the flight ([`StopReason::Interrupted`]).
pub struct Progress<F: FnMut(f64) -> ControlFlow<()>> {
    callback: F,
    next_s: f64,
    /// Simulated time at which the callback stopped the flight.
    pub stopped_at_s: Option<f64>,
}

impl<F: FnMut(f64) -> ControlFlow<()>> std::fmt::Debug for Progress<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Progress")
            .field("next_s", &self.next_s)
            .finish()
    }
}

impl<F: FnMut(f64) -> ControlFlow<()>> Progress<F> {
    /// `callback` at simulated seconds 1, 2, ….
    pub fn new(callback: F) -> Self {
        Self {
            callback,
            next_s: 1.0,
            stopped_at_s: None,
        }
    }
}

impl<F: FnMut(f64) -> ControlFlow<()>> Observer for Progress<F> {
    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        let t = step.measurement.time_s;
        if t >= self.next_s {
            self.next_s += 1.0;
            if (self.callback)(t).is_break() {
                self.stopped_at_s = Some(t);
                return Ok(Flow::Stop(StopReason::Interrupted));
            }
        }
        Ok(Flow::Continue)
    }
}
