//! `amstack track`: fly a reference trajectory in the twin and measure how well it is
//! tracked — the validation experiments of the paper.
//!
//! Metrics, over the ticks after `settle_s` (the start transient is not scored):
//! - `ee_pos_rmse_m`: RMS of ‖p_ee − p_ee,ref‖, with p_ee,ref the end-effector link where
//!   the reference's base and joint targets put it (forward kinematics of the vehicle
//!   description); with the EE interface this is the EE target handed to the IK;
//! - `base_pos_rmse_m`, `base_z_rmse_m`: RMS of the base position error against the base
//!   target the controller tracked (the IK's, with the EE interface), and of its z part;
//! - `tilt_use_rad`: the largest √(roll² + pitch²) of the base;
//! - `saturation_rate`: share of ticks with the saturation indicator set (any realised
//!   rotor thrust at a limit, or a command the motors clamped); null without rotors;
//! - `max_rotor_thrust_n`: the largest realised rotor thrust over the whole flight.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

use controllers::ControllerConfig;
use platform::{RandomStream, Vehicle};
use serde::Serialize;
use sim_twin::{Twin, TwinConfig};

use crate::flight::{
    ActionNoise, CameraConfig, End, FlightError, FlightSpec, Observer, Progress, TrackMetrics,
    TrajectorySource,
};
use crate::flight_log::FlightLog;
use crate::link::{Link, LinkError, TwinLink};
use crate::record::{McapRecorder, RecordError, RunMetadata};
use crate::stack::{Clock, FlightStack, StackError};
use crate::state_source::{EstimateError, EstimatorSummary, StateSource};
use crate::trajectory::Trajectory;

pub use crate::stack::Interface;

/// What to fly.
#[derive(Debug, Clone)]
pub struct TrackConfig {
    /// The vehicle.
    pub vehicle: Vehicle,
    /// Its base controller and gains.
    pub controller: ControllerConfig,
    /// The reference.
    pub trajectory: Trajectory,
    /// The action interface.
    pub interface: Interface,
    /// Flight length, s.
    pub duration_s: f64,
    /// Start transient excluded from the error metrics, s.
    pub settle_s: f64,
    /// The twin: rates, disturbances, motor model, noise, seed.
    pub twin: TwinConfig,
    /// Where to write the MCAP log, if anywhere.
    pub mcap: Option<PathBuf>,
    /// Where the controllers' base state comes from (the measurement, or the estimator).
    pub state_source: StateSource,
    /// The MPC's solve-budget clock (None in the twin: results must not depend on the wall
    /// clock; a flight on hardware may pass one).
    pub clock: Option<Clock>,
    /// The cameras rendered in the flight (the in-process twin only), if any.
    pub cameras: Option<CameraConfig>,
    /// The live view the flight's log channels stream to (`--live`), if any.
    pub live: Option<std::sync::Arc<crate::live::LiveServer>>,
}

/// The scores of one flight.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrackResult {
    /// Vehicle id.
    pub vehicle: String,
    /// Controller (`pid6`, `pid4`, `l1`).
    pub controller: String,
    /// Trajectory name.
    pub trajectory: String,
    /// Action interface (`base-joint` or `ee`).
    pub interface: String,
    /// Disturbances on.
    pub disturbances: Vec<String>,
    /// Motor time constant, s (null: instantaneous).
    pub motor_tau_s: Option<f64>,
    /// Motor rate limit, 1/s (null: none).
    pub motor_rate_limit_per_s: Option<f64>,
    /// Seed.
    pub seed: u64,
    /// Flight length, s.
    pub duration_s: f64,
    /// Start transient excluded from the error metrics, s.
    pub settle_s: f64,
    /// Control ticks flown.
    pub ticks: u64,
    /// RMS end-effector position error, m.
    pub ee_pos_rmse_m: f64,
    /// RMS base position error, m.
    pub base_pos_rmse_m: f64,
    /// RMS base z error, m.
    pub base_z_rmse_m: f64,
    /// Largest base tilt √(roll² + pitch²), rad.
    pub tilt_use_rad: f64,
    /// Share of ticks with saturated rotors (None without rotors).
    pub saturation_rate: Option<f64>,
    /// Largest realised rotor thrust, N (None without rotors).
    pub max_rotor_thrust_n: Option<f64>,
    /// Wall-clock time of the flight, s.
    pub wall_time_s: f64,
    /// Control ticks per wall-clock second.
    pub ticks_per_second: f64,
    /// The MCAP log written, if any.
    pub mcap: Option<PathBuf>,
    /// `truth` or `estimator`.
    pub state_source: String,
    /// The estimator's figures (with `--state-source estimator`).
    pub estimator: Option<EstimatorSummary>,
}

/// A flight that could not be flown.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// The stack cannot be built (controller/vehicle mismatch).
    #[error(transparent)]
    Stack(#[from] StackError),
    /// The twin refused its configuration or a command.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The log could not be written.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The state estimator could not start or diverged.
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    /// A setting out of range.
    #[error("{0}")]
    Config(String),
    /// Stopped on request (Ctrl-C) after `at_s` simulated seconds; the log was finished.
    #[error("interrupted at t = {at_s:.2} s; the flight log was closed")]
    Interrupted {
        /// Simulated time reached, s.
        at_s: f64,
    },
    /// The cameras could not be rendered.
    #[error("{0}")]
    Cameras(String),
    /// The flight stack produced a non-finite setpoint (nothing was sent).
    #[error("the flight stack produced a non-finite setpoint at t = {at_s:.3} s; it was not sent")]
    NonFinite {
        /// Simulated time of the tick, s.
        at_s: f64,
    },
}

impl From<FlightError> for TrackError {
    fn from(e: FlightError) -> Self {
        match e {
            FlightError::Link(e) => Self::Link(e),
            FlightError::Record(e) => Self::Record(e),
            FlightError::Estimate(e) => Self::Estimate(e),
            FlightError::Stack(e) => Self::Stack(e),
            FlightError::Source(e) => Self::Config(e.to_string()),
            // Cameras over a link that cannot render them: the user's choice of link.
            e @ FlightError::CamerasNeedTwin(_) => Self::Link(LinkError::Refused(e.to_string())),
            e @ FlightError::Cameras(_) => Self::Cameras(e.to_string()),
        }
    }
}

/// Checks the flight length and the settling time.
fn validate(config: &TrackConfig) -> Result<(), TrackError> {
    if !(config.duration_s.is_finite() && config.duration_s > 0.0) {
        return Err(TrackError::Config(format!(
            "duration {} s must be finite and positive",
            config.duration_s
        )));
    }
    if !(config.settle_s.is_finite()
        && config.settle_s >= 0.0
        && config.settle_s < config.duration_s)
    {
        return Err(TrackError::Config(format!(
            "settle time {} s must be within [0, {}) s",
            config.settle_s, config.duration_s
        )));
    }
    Ok(())
}

/// Flies `config` and scores it. `progress` is called with the simulated time about once a
/// simulated second; returning `ControlFlow::Break` stops the flight (the log is finished,
/// the result is [`TrackError::Interrupted`]).
pub fn run_track(
    config: &TrackConfig,
    progress: impl FnMut(f64) -> ControlFlow<()>,
) -> Result<TrackResult, TrackError> {
    validate(config)?;
    let twin = Twin::new(config.vehicle.clone(), config.twin.clone()).map_err(LinkError::from)?;
    run_track_with_link(config, &mut TwinLink::new(twin), progress)
}

/// [`run_track`] over any link — the twin in another process, say. `config.twin` must
/// describe the twin behind the link (its rate, limits, tilt model and noise settings shape
/// the flight stack and the action noise). A link that fails mid-flight ends the flight
/// with its error, the log finished.
pub fn run_track_with_link(
    config: &TrackConfig,
    link: &mut dyn Link,
    progress: impl FnMut(f64) -> ControlFlow<()>,
) -> Result<TrackResult, TrackError> {
    validate(config)?;
    let vehicle = &config.vehicle;
    let dt = config.twin.control_dt_s();
    let mut stack = FlightStack::for_twin(vehicle.clone(), &config.controller, &config.twin)?
        .with_clock(config.clock.clone());
    // The cameras first: a machine that cannot render leaves no log behind.
    let mut rig = match &config.cameras {
        Some(c) => Some(
            c.rig(vehicle)
                .map_err(|e| TrackError::Cameras(e.to_string()))?,
        ),
        None => None,
    };
    let recorder = McapRecorder::for_flight(
        config.mcap.as_deref(),
        config.live.as_ref().map(|l| l.tap()),
        || {
            RunMetadata::new(&vehicle.id, config.controller.name(), config.twin.seed)
                .with_interface(config.interface.name())
                .with_trajectory(config.trajectory.name())
                .with_config(&config.twin)?
                .with_controller_config(&config.controller)
        },
    )?;
    let mut log = match recorder {
        None => None,
        Some(recorder) => Some(
            FlightLog::new(recorder, vehicle)?
                .with_rotor_limits(config.twin.disturbances.saturation)
                .with_camera_log(config.cameras.as_ref().map_or(0, |c| c.log_every)),
        ),
    };
    let action_noise = if config.twin.disturbances.action_noise {
        ActionNoise::new(
            config.twin.noise.action_std,
            RandomStream::TrackActionNoise,
            config.twin.seed,
        )
    } else {
        None
    };
    let mut video = config
        .cameras
        .as_ref()
        .and_then(|c| c.video.as_ref())
        .map(|v| v.writer(v.path.clone()));
    let ticks = (config.duration_s / dt).round() as u64;
    let mut metrics = TrackMetrics::new(
        config.settle_s,
        (vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n),
    );
    let mut progress = Progress::new(progress);
    let started = Instant::now();
    let mut source = TrajectorySource::new(config.trajectory, vehicle.clone());
    let flown = {
        let mut observers: Vec<&mut dyn Observer> = Vec::with_capacity(3);
        if let Some(log) = &mut log {
            observers.push(log);
        }
        observers.push(&mut metrics);
        observers.push(&mut progress);
        if let Some(v) = &mut video {
            observers.push(v);
        }
        crate::flight::run(
            link,
            &mut stack,
            &mut source,
            &mut observers,
            FlightSpec {
                max_ticks: ticks,
                dt_s: dt,
                control_rate_hz: config.twin.control_rate_hz,
                seed: config.twin.seed,
                state_source: config.state_source,
                score_from_s: config.settle_s,
                interface: Some(config.interface),
                action_noise,
                stop: None,
                cameras: rig.as_mut(),
            },
        )
    };
    // The log is closed whatever happened (a link that stopped answering, Ctrl-C).
    let mcap = match log {
        Some(log) => Some(log.finish()?.path).filter(|_| config.mcap.is_some()),
        None => None,
    };
    if let Some(v) = video {
        v.finish()?;
    }
    let flown = flown?;
    match flown.end {
        End::Completed | End::Success => {}
        End::Interrupted => {
            return Err(TrackError::Interrupted {
                at_s: progress.stopped_at_s.unwrap_or(flown.last_time_s),
            });
        }
        End::NanAction => {
            return Err(TrackError::NonFinite {
                at_s: flown.last_time_s,
            });
        }
        End::Diverged(why) => return Err(TrackError::Link(LinkError::Diverged(why))),
        End::PolicyFailed(why) => return Err(TrackError::Config(why)),
    }
    let wall_time_s = started.elapsed().as_secs_f64();
    Ok(TrackResult {
        vehicle: vehicle.id.clone(),
        controller: config.controller.name().to_owned(),
        trajectory: config.trajectory.name().to_owned(),
        interface: config.interface.name().to_owned(),
        disturbances: config
            .twin
            .disturbances
            .names()
            .into_iter()
            .map(str::to_owned)
            .collect(),
        motor_tau_s: config.twin.motor.time_constant_s,
        motor_rate_limit_per_s: config.twin.motor.rate_limit_per_s,
        seed: config.twin.seed,
        duration_s: config.duration_s,
        settle_s: config.settle_s,
        ticks,
        ee_pos_rmse_m: metrics.rms(metrics.ee),
        base_pos_rmse_m: metrics.rms(metrics.base),
        base_z_rmse_m: metrics.rms(metrics.base_z),
        tilt_use_rad: metrics.tilt,
        saturation_rate: (metrics.rotor_ticks > 0)
            .then(|| metrics.saturated as f64 / metrics.rotor_ticks as f64),
        max_rotor_thrust_n: metrics.max_thrust,
        wall_time_s,
        ticks_per_second: ticks as f64 / wall_time_s.max(1e-9),
        mcap,
        state_source: config.state_source.name().to_owned(),
        estimator: flown.estimator,
    })
}
