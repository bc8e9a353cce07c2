//! The one flight loop: every flight — a `track` reference, a benchmark rollout, a `replay`,
//! a `fly` over any link, a recording, a learned-policy evaluation — is [`run`] with what
//! differs plugged in, never a copy of the loop.
//!
//! One tick `k` (t_k = k·dt):
//!
//! ```text
//! measurement (link) ─► state source: truth | estimator ─► observation (+ task scene,
//!    + camera images on the ticks a source or observer asks for them: [`crate::cameras`])
//!    ─► action source (trajectory | scripted task policy | logged actions | learned policy)
//!       (a source that fails ends the flight `PolicyFailed`, nothing sent)
//!    ─► action noise (one place, its own random stream) ─► interface (EE ⇄ base + joint)
//!    ─► flight stack: IK | MPC → base controller → allocation → TickRecord
//!    ─► observers.decided  (log: /action, the tick's channels; metrics)
//!    ─► setpoint at the link's level; a non-finite one is never sent (ends `NanAction`)
//!    ─► link: send, receive (its failure ends the flight with its error; `Diverged` ends it
//!       as a result)
//!    ─► observers.stepped  (criteria latch and stop rule, log, metrics, progress)
//!    ─► estimator fed with the new measurement ─► observers.estimated
//! ```
//!
//! Before the first tick: the start measurement, the link's first log messages
//! ([`Observer::start`]), the estimator's start, the stack's reset and the source's start
//! (a scripted policy is built from that first observation). The base limits follow the task
//! scene's obstacle face every tick (AMBENCH_SPEC §2.6). Observers are values the runner
//! calls in the order given: those that fill [`Stepped`] for others (the criteria latch)
//! come before those that read it (the log).

mod noise;
mod observer;
mod source;

use std::sync::atomic::{AtomicBool, Ordering};

use platform::Measurement;

pub use self::noise::ActionNoise;
pub use self::observer::{
    BenchMetrics, Decided, Flow, Observer, Progress, Start, Stepped, StopReason, TaskCriteria,
    TrackMetrics,
};
pub use self::source::{
    ActionSource, EpisodeLength, Observation, ScriptedTask, SourceError, Step, TrajectorySource,
};
pub use crate::cameras::{
    CAMERA_ALIASES, CameraConfig, CameraFrame, CameraRig, FrameUse, Frames, VideoConfig,
    full_camera_name, select_cameras,
};
use crate::link::{Link, LinkError, LinkMessage};
use crate::record::RecordError;
use crate::stack::{FlightStack, Interface, StackError};
use crate::state_source::{
    EstimateError, EstimateReport, EstimatorSummary, StateEstimate, StateSource,
};

/// How one flight runs.
#[derive(Debug)]
pub struct FlightSpec<'a> {
    /// Ticks to fly at most (the action source may set its own limit instead).
    pub max_ticks: u64,
    /// Control period, s.
    pub dt_s: f64,
    /// Control rate of the simulated sensors, Hz.
    pub control_rate_hz: f64,
    /// The run seed (the simulated sensors' stream).
    pub seed: u64,
    /// Where the stack's base state comes from.
    pub state_source: StateSource,
    /// The estimator's error is scored from this time on, s.
    pub score_from_s: f64,
    /// The interface that carries the source's actions to the stack; None: as the source
    /// gives them.
    pub interface: Option<Interface>,
    /// Noise on every action value, if on.
    pub action_noise: Option<ActionNoise>,
    /// Set from another thread to stop between ticks (the flight ends `Interrupted`).
    pub stop: Option<&'a AtomicBool>,
    /// The cameras, rendered on the ticks the source or an observer asks for them
    /// ([`crate::cameras`]); only a link that can render (the in-process twin) takes them. None:
    /// nothing is rendered.
    pub cameras: Option<&'a mut CameraRig>,
}

/// How a flight ended (it ran; see [`FlightError`] for one that could not go on).
#[derive(Debug, Clone, PartialEq)]
pub enum End {
    /// Every tick flown.
    Completed,
    /// An observer's stop rule held (the task's success criterion).
    Success,
    /// Stopped on request (the stop flag, or an observer: Ctrl-C).
    Interrupted,
    /// The stack produced a non-finite setpoint; nothing was sent.
    NanAction,
    /// The simulation behind the link diverged.
    Diverged(String),
    /// The action source (a learned policy) failed: the reason.
    PolicyFailed(String),
}

/// What a flight did.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightEnd {
    /// Why it ended.
    pub end: End,
    /// Ticks whose setpoint the link applied.
    pub ticks: u64,
    /// Time of the last measurement, s.
    pub last_time_s: f64,
    /// The estimator's figures (with the estimator as state source).
    pub estimator: Option<EstimatorSummary>,
    /// Observations whose camera images were rendered.
    pub frames_rendered: u64,
}

/// A flight that could not go on.
#[derive(Debug, thiserror::Error)]
pub enum FlightError {
    /// The link failed (its observers were told: [`Observer::link_failed`]).
    #[error(transparent)]
    Link(#[from] LinkError),
    /// A log could not be written.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The estimator could not start or diverged.
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    /// The action source failed.
    #[error(transparent)]
    Source(#[from] SourceError),
    /// The stack cannot produce the link's setpoint.
    #[error(transparent)]
    Stack(#[from] StackError),
    /// The cameras could not be rendered.
    #[error("cameras: {0}")]
    Cameras(#[from] render::RenderError),
    /// Cameras were asked for over a link that cannot render them.
    #[error(
        "cameras need the twin in this process (--link twin): the link '{0}' cannot render them"
    )]
    CamerasNeedTwin(String),
}

/// Flies one flight: `source` through `stack` over `link`, every tick shown to `observers`
/// in order. The caller built the stack for the link and owns the observers (it finishes a
/// log whatever the outcome).
pub fn run(
    link: &mut dyn Link,
    stack: &mut FlightStack,
    source: &mut dyn ActionSource,
    observers: &mut [&mut dyn Observer],
    spec: FlightSpec<'_>,
) -> Result<FlightEnd, FlightError> {
    let mut rig = spec.cameras;
    if let Some(r) = rig.as_deref_mut() {
        r.start(&*link, spec.seed).map_err(|e| match e {
            Some(e) => FlightError::Cameras(e),
            None => FlightError::CamerasNeedTwin(link.name()),
        })?;
    }
    let rendered_before = rig.as_deref().map_or(0, CameraRig::rendered);
    let mut messages: Vec<LinkMessage> = Vec::new();
    let mut m = link.receive()?;
    link.drain_messages(m.time_s, &mut messages);
    // The scene's shapes and, after each step, their poses: only for an observer that draws
    // them (read-only queries of the link: they change nothing in the flight).
    let scene_visuals = if observers.iter().any(|o| o.wants_scene()) {
        link.camera_scene()
    } else {
        None
    };
    let mut scene_state = render::Snapshot::default();
    for o in observers.iter_mut() {
        o.start(&Start {
            measurement: &m,
            link_messages: &messages,
            scene_visuals: scene_visuals.as_deref(),
        })?;
    }
    // The controllers' view of the vehicle: the measurement, or the estimator's. A link with
    // sensors of its own (a MAVLink autopilot) feeds the estimator with them.
    let mut estimate = match (&spec.state_source, link.vehicle_sensors()) {
        (StateSource::Truth, _) => None,
        (StateSource::Estimator(settings), Some(sensors)) => {
            Some(StateEstimate::from_vehicle(settings, &m, &sensors)?)
        }
        (StateSource::Estimator(settings), None) => Some(StateEstimate::new(
            settings,
            spec.control_rate_hz,
            spec.seed,
            &m,
        )?),
    };
    let mut fed = match &mut estimate {
        None => None,
        Some(e) => Some(estimated(e, &m, None, false, observers)?),
    };
    let start = fed.as_ref().unwrap_or(&m);
    stack.reset_at(&start.base, &start.joint_positions);
    let mut scene = link.task();
    let observed = link.task_observed();
    source.start(&Observation {
        time_s: 0.0,
        measurement: fed.as_ref().unwrap_or(&m),
        truth: &m,
        scene: scene.as_ref(),
        frames: None,
    })?;
    let max_ticks = source.tick_limit().unwrap_or(spec.max_ticks);
    let mut noise = spec.action_noise;
    let mut end = End::Completed;
    let mut ticks = 0;
    for k in 0..max_ticks {
        if spec.stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            end = End::Interrupted;
            break;
        }
        let t = k as f64 * spec.dt_s;
        stack.keep_in_front_of(scene.as_ref().and_then(|s| s.obstacle_face_x));
        stack.hold_on_joint(scene.as_ref().and_then(|s| s.held_joint));
        stack.touch(scene.as_ref().and_then(|s| s.hand_contact));
        // The images of observation k: begun now (the state after the last step), read back
        // before the first consumer that needs them.
        let (source_frames, frame_use) = match rig.as_deref() {
            None => (false, FrameUse::None),
            Some(_) => (
                source.wants_frames(k),
                observers
                    .iter()
                    .map(|o| o.wants_frames(k))
                    .min()
                    .unwrap_or(FrameUse::None),
            ),
        };
        let rendered = source_frames || frame_use != FrameUse::None;
        let decided_frames = source_frames || frame_use == FrameUse::Decided;
        if rendered && let Some(r) = rig.as_deref_mut() {
            r.begin(&*link, k, m.time_s)?;
            if source_frames {
                r.finish()?;
            }
        }
        let observation = Observation {
            time_s: t,
            measurement: fed.as_ref().unwrap_or(&m),
            truth: &m,
            scene: scene.as_ref(),
            frames: rig
                .as_deref()
                .filter(|_| source_frames)
                .map(CameraRig::frames),
        };
        let (action, record, ee_reference) = match source.next(k, &observation, stack)? {
            Step::Act {
                mut action,
                ee_reference,
            } => {
                if let Some(n) = &mut noise {
                    n.apply(&mut action);
                }
                let ee_reference = ee_reference.unwrap_or_else(|| stack.ee_reference(&action));
                let action = match spec.interface {
                    Some(interface) => stack.convert(action, interface, &ee_reference),
                    None => action,
                };
                let record = stack.act(fed.as_ref().unwrap_or(&m), &action);
                (Some(action), record, ee_reference)
            }
            Step::OpenLoop {
                record,
                ee_reference,
            } => (None, *record, ee_reference),
            Step::Failed(reason) => {
                end = End::PolicyFailed(reason);
                break;
            }
        };
        if decided_frames && let Some(r) = rig.as_deref_mut() {
            r.finish()?;
        }
        let frames = rig
            .as_deref()
            .filter(|_| decided_frames)
            .map(CameraRig::frames);
        for o in observers.iter_mut() {
            o.decided(&Decided {
                k,
                time_s: t,
                measurement: &m,
                action: action.as_ref(),
                record: &record,
                ee_reference: &ee_reference,
                frames,
            })?;
        }
        let setpoint = record.setpoint(link.level())?;
        if !setpoint.is_finite() {
            end = End::NanAction;
            break;
        }
        match link.send(&setpoint).and_then(|()| link.receive()) {
            Ok(next) => m = next,
            Err(LinkError::Diverged(why)) => {
                end = End::Diverged(why);
                break;
            }
            Err(e) => {
                // The world stopped answering: the observers get what the link has to say
                // about it (a MAVLink link: the frames up to the failure), best effort.
                messages.clear();
                link.drain_messages(m.time_s, &mut messages);
                for o in observers.iter_mut() {
                    o.link_failed(&messages);
                }
                return Err(e.into());
            }
        }
        ticks += 1;
        if rendered && let Some(r) = rig.as_deref_mut() {
            r.finish()?;
        }
        scene = link.task();
        messages.clear();
        link.drain_messages(m.time_s, &mut messages);
        let scene_poses = match scene_visuals {
            Some(_) if link.camera_state(&mut scene_state) => Some(&scene_state.scene_poses[..]),
            _ => None,
        };
        let mut stepped = Stepped {
            k,
            time_s: t,
            measurement: &m,
            scene: scene.as_ref(),
            scene_observed: observed,
            link_messages: &messages,
            task_state: None,
            frames: rig.as_deref().filter(|_| rendered).map(CameraRig::frames),
            scene_poses,
        };
        let mut stop = None;
        for o in observers.iter_mut() {
            if let Flow::Stop(reason) = o.stepped(&mut stepped)? {
                stop.get_or_insert(reason);
            }
        }
        if let Some(e) = &mut estimate {
            let scored = t + spec.dt_s >= spec.score_from_s;
            let sensors = link.vehicle_sensors();
            fed = Some(estimated(e, &m, sensors.as_ref(), scored, observers)?);
        }
        match stop {
            Some(StopReason::Success) => {
                end = End::Success;
                break;
            }
            Some(StopReason::Interrupted) => {
                end = End::Interrupted;
                break;
            }
            None => {}
        }
    }
    // A frame still in flight (a flight that ended before the step): drained, not shown.
    let frames_rendered = match rig {
        Some(r) => {
            r.finish()?;
            r.rendered() - rendered_before
        }
        None => 0,
    };
    Ok(FlightEnd {
        end,
        ticks,
        last_time_s: m.time_s,
        estimator: estimate.as_ref().map(StateEstimate::summary),
        frames_rendered,
    })
}

/// One tick of the estimator: the measurement the stack gets; the report to the observers.
fn estimated(
    estimate: &mut StateEstimate,
    m: &Measurement,
    sensors: Option<&crate::link::VehicleSensors>,
    scored: bool,
    observers: &mut [&mut dyn Observer],
) -> Result<Measurement, FlightError> {
    let (fed, report): (Measurement, EstimateReport) = estimate.observe(m, sensors, scored)?;
    for o in observers.iter_mut() {
        o.estimated(m.time_s, &report)?;
    }
    Ok(fed)
}
