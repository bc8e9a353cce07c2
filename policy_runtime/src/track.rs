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
use nalgebra::{Isometry3, Quaternion, UnitQuaternion};
use platform::Vehicle;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;
use sim_twin::{Twin, TwinConfig};

use crate::flight_log::{FlightLog, rotors_saturated};
use crate::link::{Link, LinkError, TwinLink};
use crate::record::{McapRecorder, RecordError, RunMetadata};
use crate::stack::{Action, BaseJointTarget, EeTarget, FlightStack, StackError};
use crate::state_source::{
    EstimateError, EstimatorSummary, StateEstimate, StateSource, VehicleSensors,
};
use crate::trajectory::Trajectory;

/// Which action interface carries the reference to the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Interface {
    /// Base pose and arm joints straight to the controller and the joint drives.
    BaseJoint,
    /// The end-effector pose the reference implies, through whole-body IK (the paper's
    /// ground-effect comparison flies this way).
    Ee,
}

impl Interface {
    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Self::BaseJoint => "base-joint",
            Self::Ee => "ee",
        }
    }
}

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
}

#[derive(Debug, Default)]
struct Sums {
    n: u64,
    ee: f64,
    base: f64,
    base_z: f64,
    tilt: f64,
    saturated: u64,
    rotor_ticks: u64,
    max_thrust: Option<f64>,
}

/// Adds action noise (AMBENCH_SPEC §3.1: N(0, σ) on every action value) to a target.
fn noisy(target: &mut BaseJointTarget, rng: &mut ChaCha8Rng, noise: &Normal<f64>) {
    let t = &mut target.world_from_base.translation.vector;
    for x in t.iter_mut() {
        *x += noise.sample(rng);
    }
    let q = target
        .world_from_base
        .rotation
        .into_inner()
        .coords
        .map(|c| c + noise.sample(rng));
    target.world_from_base.rotation = UnitQuaternion::new_normalize(Quaternion::from(q));
    for q in &mut target.arm_joints {
        *q += noise.sample(rng);
    }
    target.gripper += noise.sample(rng);
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
    mut progress: impl FnMut(f64) -> ControlFlow<()>,
) -> Result<TrackResult, TrackError> {
    validate(config)?;
    let vehicle = &config.vehicle;
    let dt = config.twin.control_dt_s();
    let mut stack = FlightStack::for_twin(vehicle.clone(), &config.controller, &config.twin)?;
    let mut log = match &config.mcap {
        None => None,
        Some(path) => {
            let run = RunMetadata::new(&vehicle.id, config.controller.name(), config.twin.seed)
                .with_interface(config.interface.name())
                .with_trajectory(config.trajectory.name())
                .with_config(&config.twin)?
                .with_controller_config(&config.controller)?;
            Some(FlightLog::new(McapRecorder::create(path, &run)?, vehicle)?)
        }
    };
    let action_noise = config
        .twin
        .disturbances
        .action_noise
        .then(|| Normal::new(0.0, config.twin.noise.action_std).ok())
        .flatten();
    let mut rng = ChaCha8Rng::seed_from_u64(config.twin.seed ^ 0x6163_7469_6f6e);
    let limits_n = (vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n);

    let ticks = (config.duration_s / dt).round() as u64;
    let mut sums = Sums::default();
    let started = Instant::now();
    let mut measurement = link.receive()?;
    if let Some(log) = &mut log {
        link.log_tick(log, measurement.time_s)?;
    }
    // The controllers' view of the vehicle: the measurement, or the estimator's.
    // A link with sensors of its own (a MAVLink autopilot) feeds the estimator with them.
    let mut estimate = match (&config.state_source, link.vehicle_sensors()) {
        (StateSource::Truth, _) => None,
        (StateSource::Estimator(settings), Some(sensors)) => Some(StateEstimate::from_vehicle(
            settings,
            &measurement,
            &sensors,
        )?),
        (StateSource::Estimator(settings), None) => Some(StateEstimate::new(
            settings,
            config.twin.control_rate_hz,
            config.twin.seed,
            &measurement,
        )?),
    };
    let mut fed = match &mut estimate {
        None => None,
        Some(e) => Some(observe(e, &measurement, None, false, &mut log)?),
    };
    let start = fed.as_ref().unwrap_or(&measurement);
    stack.reset_at(&start.base, &start.joint_positions);
    let mut next_progress = 1.0;
    for k in 0..ticks {
        let t = k as f64 * dt;
        let mut target = config.trajectory.target(vehicle, t);
        if let Some(n) = &action_noise {
            noisy(&mut target, &mut rng, n);
        }
        let ee_reference = ee_link_target(vehicle, &target);
        let action = match config.interface {
            Interface::BaseJoint => Action::BaseJoint(target.clone()),
            Interface::Ee => {
                let mut world_from_ee_command = ee_reference;
                world_from_ee_command.rotation =
                    vehicle.command_to_link.inverse() * ee_reference.rotation;
                Action::Ee(EeTarget {
                    world_from_ee_command,
                    gripper: target.gripper,
                })
            }
        };
        let record = stack.act(fed.as_ref().unwrap_or(&measurement), &action);
        if let Some(log) = &mut log {
            log.action(measurement.time_s, &action)?;
            log.tick(&measurement, &record, &ee_reference)?;
        }
        if t >= config.settle_s {
            score(&mut sums, &measurement, &record.base_target, &ee_reference);
        }
        measurement = match link.send_tick(&record).and_then(|()| link.receive()) {
            Ok(m) => m,
            Err(e) => {
                // The world stopped answering (a twin process gone): the log is still closed,
                // with what the link has to say about it (a MAVLink link: the frames up to the
                // failure), best effort: the link's error is the one reported.
                if let Some(mut log) = log {
                    let _ = link.log_tick(&mut log, measurement.time_s);
                    log.finish()?;
                }
                return Err(e.into());
            }
        };
        if let Some(log) = &mut log {
            log.outcome(&measurement)?;
            link.log_tick(log, measurement.time_s)?;
        }
        if let Some(e) = &mut estimate {
            let scored = t + dt >= config.settle_s;
            let sensors = link.vehicle_sensors();
            fed = match observe(e, &measurement, sensors.as_ref(), scored, &mut log) {
                Ok(m) => Some(m),
                Err(err) => {
                    if let Some(log) = log {
                        log.finish()?;
                    }
                    return Err(err);
                }
            };
        }
        if !measurement.rotors.is_empty() {
            let peak = measurement
                .rotors
                .iter()
                .map(|r| r.realised_n)
                .fold(f64::NEG_INFINITY, f64::max);
            sums.max_thrust = Some(sums.max_thrust.map_or(peak, |m: f64| m.max(peak)));
            if t >= config.settle_s {
                sums.rotor_ticks += 1;
                sums.saturated += u64::from(rotors_saturated(&measurement, limits_n));
            }
        }
        if measurement.time_s >= next_progress {
            next_progress += 1.0;
            if progress(measurement.time_s).is_break() {
                if let Some(log) = log {
                    log.finish()?;
                }
                return Err(TrackError::Interrupted {
                    at_s: measurement.time_s,
                });
            }
        }
    }
    let mcap = match log {
        Some(log) => Some(log.finish()?.path),
        None => None,
    };
    let wall_time_s = started.elapsed().as_secs_f64();
    let rms = |sum: f64| {
        if sums.n > 0 {
            (sum / sums.n as f64).sqrt()
        } else {
            f64::NAN
        }
    };
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
        ee_pos_rmse_m: rms(sums.ee),
        base_pos_rmse_m: rms(sums.base),
        base_z_rmse_m: rms(sums.base_z),
        tilt_use_rad: sums.tilt,
        saturation_rate: (sums.rotor_ticks > 0)
            .then(|| sums.saturated as f64 / sums.rotor_ticks as f64),
        max_rotor_thrust_n: sums.max_thrust,
        wall_time_s,
        ticks_per_second: ticks as f64 / wall_time_s.max(1e-9),
        mcap,
        state_source: config.state_source.name().to_owned(),
        estimator: estimate.as_ref().map(StateEstimate::summary),
    })
}

/// One tick of the state estimator: the measurement the controllers get, the estimate logged.
fn observe(
    estimate: &mut StateEstimate,
    measurement: &platform::Measurement,
    vehicle: Option<&VehicleSensors>,
    scored: bool,
    log: &mut Option<FlightLog>,
) -> Result<platform::Measurement, TrackError> {
    let (fed, report) = estimate.observe(measurement, vehicle, scored)?;
    if let Some(log) = log {
        log.estimate(
            measurement.time_s,
            &crate::flight_log::EstimatorState::from_report(&report),
        )?;
    }
    Ok(fed)
}

/// Where a base + joint target puts the end-effector link.
fn ee_link_target(vehicle: &Vehicle, target: &BaseJointTarget) -> Isometry3<f64> {
    let mut q = vehicle.initial_configuration();
    for (&dof, &value) in vehicle.arm_dofs().iter().zip(&target.arm_joints) {
        q[dof] = value;
    }
    target.world_from_base * vehicle.model.root_from_link(&q, vehicle.ee_link)
}

fn score(
    sums: &mut Sums,
    m: &platform::Measurement,
    base_reference: &Isometry3<f64>,
    ee_reference: &Isometry3<f64>,
) {
    let base_error = base_reference.translation.vector - m.base.position_in_world_m;
    let ee_error = ee_reference.translation.vector - m.world_from_ee.translation.vector;
    let (roll, pitch, _) = m.base.world_from_body.euler_angles();
    sums.n += 1;
    sums.ee += ee_error.norm_squared();
    sums.base += base_error.norm_squared();
    sums.base_z += base_error.z * base_error.z;
    sums.tilt = sums.tilt.max(roll.hypot(pitch));
}
