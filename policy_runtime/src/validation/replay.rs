//! Re-flying a logged flight in the twin.
//!
//! The twin starts from the logged initial state (the first `/base/state`: pose and world
//! velocity; the arm starts at the twin's initial configuration, and the largest difference
//! to the logged joints is reported). Then, one control tick per logged tick:
//!
//! - [`ReplayMode::Reference`]: the logged action (`/action`) goes through the whole flight
//!   stack — IK or MPC, base controller, allocation — as in the logged run. A log without
//!   `/action` (written before it was added, or by a writer that does not log it) gives the
//!   action from its references: `ee` interface, `/ee/reference` (the end-effector link pose,
//!   turned into the command frame); `base-joint`, `/base/reference` with the arm targets of
//!   `/joints.target`; the gripper is then closed (−1).
//! - [`ReplayMode::Commands`]: the logged actuator commands are applied open loop: rotor
//!   thrusts from `/rotors.commanded_n` (the command sent at the tick; logged with the
//!   outcome, one control period later), joint targets from `/joints.target`, and for a
//!   vehicle without rotors (the EE-only oracle) the wrench of `/control/wrench`.
//!
//! The replay is written as a flight log of the same format, so `compare` reads both.
//! Replay depends only on channels every flight log holds, the twin's and the MAVLink
//! bridge's alike (`docs/mcap-format.md`).

use std::path::PathBuf;

use controllers::{ControllerConfig, ControllerKind, InputHealth};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use platform::{ActuatorCommand, Measurement, Vehicle, Wrench};
use serde::{Deserialize, Serialize};
use sim_twin::{Twin, TwinConfig, TwinError};

use super::FlightLogFile;
use crate::flight::{
    ActionSource, End, FlightError, FlightSpec, Observation, SourceError, Step, TaskCriteria,
};
use crate::flight_log::{ActionMessage, FlightLog};
use crate::link::{LinkError, TwinLink};
use crate::record::foxglove::PoseInFrame;
use crate::record::{McapRecorder, RecordError, RecordedMessage, RunMetadata};
use crate::stack::{Action, BaseJointTarget, EeTarget, FlightStack, StackError, TickRecord};
use crate::state_source::StateSource;

/// What a replay feeds the twin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReplayMode {
    /// The logged actions through the whole flight stack (closed loop).
    Reference,
    /// The logged actuator commands, open loop.
    Commands,
}

impl ReplayMode {
    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Reference => "reference",
            Self::Commands => "commands",
        }
    }
}

/// A replay that cannot be flown. Every variant names the log or the tick.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The log lacks what the replay needs.
    #[error("{file}: {reason}")]
    Log {
        /// The log.
        file: String,
        /// What is missing or wrong.
        reason: String,
    },
    /// The stack cannot be built.
    #[error(transparent)]
    Stack(#[from] StackError),
    /// The twin refused its configuration.
    #[error(transparent)]
    Twin(#[from] TwinError),
    /// The twin refused a command.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The output log could not be written.
    #[error(transparent)]
    Record(#[from] RecordError),
}

/// How to replay.
#[derive(Debug, Clone)]
pub struct ReplayConfig {
    /// The vehicle (the logged one unless overridden).
    pub vehicle: Vehicle,
    /// The controller and gains (reference mode).
    pub controller: ControllerConfig,
    /// The twin (the logged configuration, overrides applied).
    pub twin: TwinConfig,
    /// What to feed the twin.
    pub mode: ReplayMode,
    /// The flight log to write.
    pub out: PathBuf,
}

/// What a replay did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayResult {
    /// The mode.
    pub mode: ReplayMode,
    /// Logged ticks.
    pub logged_ticks: usize,
    /// Ticks replayed (fewer when the twin diverged).
    pub replayed_ticks: usize,
    /// Why the replay stopped early (the twin diverged), if it did.
    pub stopped_early: Option<String>,
    /// Whether the actions came from `/action` (else from the references).
    pub actions_from_action_channel: bool,
    /// Whether the twin was moved to the logged initial pose/velocity (false: its reset
    /// state already matched within 1e-9).
    pub initial_state_from_log: bool,
    /// Largest |logged − twin| initial joint position, rad or m (null when another vehicle
    /// than the logged one flies the replay).
    pub initial_joint_mismatch: Option<f64>,
    /// The log written.
    pub out: PathBuf,
}

#[derive(Deserialize)]
struct BaseStateMsg {
    position_m: [f64; 3],
    orientation_wxyz: [f64; 4],
    velocity_world_mps: [f64; 3],
}

#[derive(Deserialize)]
struct JointsMsg {
    target: Vec<f64>,
    position: Vec<f64>,
}

#[derive(Deserialize)]
struct RotorsMsg {
    commanded_n: Vec<Option<f64>>,
}

#[derive(Deserialize)]
struct WrenchMsg {
    force_n: [f64; 3],
    torque_nm: [f64; 3],
}

/// The ticks of a logged flight: what replay needs, one entry per control tick.
#[derive(Debug, Clone)]
pub struct LoggedFlight {
    /// The log it was read from.
    pub path: PathBuf,
    /// The run's metadata.
    pub run: RunMetadata,
    /// Initial base pose, `world_from_base`.
    pub initial_pose: Isometry3<f64>,
    /// Initial base velocity, world, m/s.
    pub initial_velocity_mps: Vector3<f64>,
    /// Initial joint positions, rad or m.
    pub initial_joints: Vec<f64>,
    /// Per tick: the action (from `/action`, if logged).
    pub actions: Option<Vec<Action>>,
    /// Per tick: `/ee/reference`.
    pub ee_references: Vec<Isometry3<f64>>,
    /// Per tick: `/base/reference`.
    pub base_references: Vec<Isometry3<f64>>,
    /// Per tick: `/joints.target`.
    pub joint_targets: Vec<Vec<f64>>,
    /// Per tick: the rotor commands (`/rotors.commanded_n`; NaN where the log holds null),
    /// empty without rotors.
    pub rotor_commands: Vec<Vec<f64>>,
    /// Per tick: the requested wrench (`/control/wrench`).
    pub wrenches: Vec<Wrench>,
}

fn isometry(p: &PoseInFrame) -> Isometry3<f64> {
    let (t, q) = (&p.pose.position, &p.pose.orientation);
    Isometry3::from_parts(
        Translation3::new(t.x, t.y, t.z),
        UnitQuaternion::new_unchecked(Quaternion::new(q.w, q.x, q.y, q.z)),
    )
}

impl LoggedFlight {
    /// Reads the ticks of `log`. Needs the `amstack.run` metadata and the channels
    /// `/base/state`, `/base/reference`, `/ee/reference`, `/joints`, `/control/wrench` (and
    /// `/rotors` for a vehicle with rotors); `/action` is used when present.
    pub fn from_log(log: &FlightLogFile) -> Result<Self, ReplayError> {
        let file = log.path.display().to_string();
        let bad = |reason: String| ReplayError::Log {
            file: file.clone(),
            reason,
        };
        let run = log.recording.run.clone().ok_or_else(|| {
            bad(
                "no amstack.run metadata record: the vehicle and configuration are unknown"
                    .to_owned(),
            )
        })?;
        fn parse<T: for<'de> Deserialize<'de>>(
            messages: &[&RecordedMessage],
            bad: &dyn Fn(String) -> ReplayError,
        ) -> Result<Vec<T>, ReplayError> {
            messages
                .iter()
                .map(|m| {
                    serde_json::from_slice(&m.data).map_err(|e| {
                        bad(format!(
                            "{} message at t = {:.6} s: {e}",
                            m.topic,
                            m.log_time_ns as f64 * 1e-9
                        ))
                    })
                })
                .collect()
        }
        let on = |topic: &str| -> Vec<&RecordedMessage> {
            log.recording
                .messages
                .iter()
                .filter(|m| m.topic == topic)
                .collect()
        };
        let required = |topic: &str| -> Result<Vec<&RecordedMessage>, ReplayError> {
            let messages = on(topic);
            if messages.is_empty() {
                return Err(bad(format!(
                    "no {topic} messages: replay needs /base/state, /base/reference, /ee/reference, /joints, /control/wrench (docs/mcap-format.md)"
                )));
            }
            Ok(messages)
        };
        let states: Vec<BaseStateMsg> = parse(&required("/base/state")?, &bad)?;
        let base_refs: Vec<PoseInFrame> = parse(&required("/base/reference")?, &bad)?;
        let ee_refs: Vec<PoseInFrame> = parse(&required("/ee/reference")?, &bad)?;
        let joints: Vec<JointsMsg> = parse(&required("/joints")?, &bad)?;
        let wrenches: Vec<WrenchMsg> = parse(&required("/control/wrench")?, &bad)?;
        let rotors: Vec<RotorsMsg> = parse(&on("/rotors"), &bad)?;
        let actions: Vec<ActionMessage> = parse(&on("/action"), &bad)?;
        let mut ticks = [base_refs.len(), ee_refs.len(), joints.len(), wrenches.len()]
            .into_iter()
            .min()
            .unwrap_or(0);
        if !rotors.is_empty() {
            ticks = ticks.min(rotors.len());
        }
        let actions = if actions.is_empty() {
            None
        } else {
            ticks = ticks.min(actions.len());
            Some(
                actions
                    .iter()
                    .enumerate()
                    .map(|(i, a)| {
                        a.to_action().ok_or_else(|| {
                            bad(format!(
                                "/action message {i}: unknown interface '{}'",
                                a.interface
                            ))
                        })
                    })
                    .collect::<Result<Vec<_>, _>>()?,
            )
        };
        let first = &states[0];
        let [w, x, y, z] = first.orientation_wxyz;
        let [px, py, pz] = first.position_m;
        // A null (non-finite) command is kept as NaN: only commands mode flies it, and
        // `check_replay` refuses it there.
        let rotor_commands = rotors
            .iter()
            .take(ticks)
            .map(|r| {
                r.commanded_n
                    .iter()
                    .map(|x| x.unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        Ok(Self {
            initial_pose: Isometry3::from_parts(
                Translation3::new(px, py, pz),
                UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z)),
            ),
            initial_velocity_mps: Vector3::from(first.velocity_world_mps),
            initial_joints: joints[0].position.clone(),
            actions: actions.map(|mut a| {
                a.truncate(ticks);
                a
            }),
            ee_references: ee_refs.iter().take(ticks).map(isometry).collect(),
            base_references: base_refs.iter().take(ticks).map(isometry).collect(),
            joint_targets: joints.into_iter().take(ticks).map(|j| j.target).collect(),
            rotor_commands,
            wrenches: wrenches
                .iter()
                .take(ticks)
                .map(|w| Wrench {
                    force: Vector3::from(w.force_n),
                    torque: Vector3::from(w.torque_nm),
                })
                .collect(),
            run,
            path: log.path.clone(),
        })
    }

    /// Control ticks in the log.
    pub fn ticks(&self) -> usize {
        self.base_references.len()
    }

    /// The logged twin configuration (the `config` of the metadata record).
    pub fn twin_config(&self) -> Result<TwinConfig, String> {
        serde_json::from_str(&self.run.config_json)
            .map_err(|e| format!("metadata `config` is not a twin configuration: {e}"))
    }

    /// The logged controller: `controller_config` when recorded, else the reference profile
    /// of `vehicle` for the controller's name (`pid…`, `l1`, `mpc`, with or without `ik-`).
    pub fn controller_config(&self, vehicle: &Vehicle) -> Result<ControllerConfig, String> {
        if let Some(json) = &self.run.controller_config_json {
            let config: ControllerConfig = serde_json::from_str(json)
                .map_err(|e| format!("metadata `controller_config` is unusable: {e}"))?;
            return Ok(config);
        }
        controller_profile(vehicle, &self.run.controller)
    }
}

/// The reference profile for a controller name as logs and flags spell it (`pid`, `pid6`,
/// `pid4`, `ik-pid`, `l1`, `ik-l1`, `mpc`).
pub fn controller_profile(vehicle: &Vehicle, name: &str) -> Result<ControllerConfig, String> {
    let kind = match name.strip_prefix("ik-").unwrap_or(name) {
        "pid" | "pid6" | "pid4" => ControllerKind::Pid,
        "l1" => ControllerKind::L1,
        "mpc" => ControllerKind::Mpc,
        other => return Err(format!("unknown controller '{other}' (pid, l1, mpc)")),
    };
    controllers::profile(vehicle, kind).map_err(|e| format!("controller {name}: {e}"))
}

/// A twin at `logged`'s initial state: the reset state when it already matches (within
/// 1e-9 m, rad, m/s), else moved there. Returns the twin and whether it was moved.
fn twin_at_initial_state(
    vehicle: &Vehicle,
    config: &TwinConfig,
    logged: &LoggedFlight,
) -> Result<(Twin, bool), TwinError> {
    const SAME: f64 = 1e-9;
    let mut twin = Twin::new(vehicle.clone(), config.clone())?;
    let reset = twin.truth().base.pose();
    let pose_differs = (reset.translation.vector - logged.initial_pose.translation.vector).norm()
        > SAME
        || reset.rotation.angle_to(&logged.initial_pose.rotation) > SAME;
    let mut moved = false;
    if pose_differs {
        // The reset pose is `initial_base_pose` composed with any scene override on the right:
        // move the configured pose by the same correction.
        let mut moved_config = config.clone();
        moved_config.initial_base_pose =
            logged.initial_pose * reset.inverse() * config.initial_base_pose;
        twin = Twin::new(vehicle.clone(), moved_config)?;
        moved = true;
    }
    if (twin.truth().base.velocity_in_world_mps - logged.initial_velocity_mps).norm() > SAME {
        twin.set_base_velocity(&logged.initial_velocity_mps);
        moved = true;
    }
    Ok((twin, moved))
}

/// The action of tick `k` rebuilt from the references (logs without `/action`).
fn action_from_references(
    vehicle: &Vehicle,
    logged: &LoggedFlight,
    interface: &str,
    k: usize,
) -> Action {
    const GRIPPER_CLOSED: f64 = -1.0;
    if interface == "ee" {
        let mut world_from_ee_command = logged.ee_references[k];
        world_from_ee_command.rotation =
            vehicle.command_to_link.inverse() * logged.ee_references[k].rotation;
        Action::Ee(EeTarget {
            world_from_ee_command,
            gripper: GRIPPER_CLOSED,
        })
    } else {
        let targets = &logged.joint_targets[k];
        Action::BaseJoint(BaseJointTarget {
            world_from_base: logged.base_references[k],
            arm_joints: vehicle
                .arm_dofs()
                .iter()
                .map(|&d| targets.get(d).copied().unwrap_or(0.0))
                .collect(),
            gripper: GRIPPER_CLOSED,
        })
    }
}

/// The logged flight as an action source: its actions through the stack (reference mode),
/// or its commands open loop.
#[derive(Debug)]
struct LoggedActions<'a> {
    logged: &'a LoggedFlight,
    mode: ReplayMode,
    interface: &'a str,
    vehicle: &'a Vehicle,
}

impl ActionSource for LoggedActions<'_> {
    fn next(
        &mut self,
        k: u64,
        observation: &Observation<'_>,
        _stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        let k = usize::try_from(k).map_err(|e| SourceError(e.to_string()))?;
        let logged = self.logged;
        let ee_reference = logged.ee_references[k];
        Ok(match self.mode {
            ReplayMode::Reference => Step::Act {
                action: match &logged.actions {
                    Some(actions) => actions[k].clone(),
                    None => action_from_references(self.vehicle, logged, self.interface, k),
                },
                ee_reference: Some(ee_reference),
            },
            ReplayMode::Commands => {
                let command = ActuatorCommand {
                    rotor_thrusts_n: logged.rotor_commands.get(k).cloned().unwrap_or_default(),
                    joint_targets: logged.joint_targets[k].clone(),
                    direct_wrench_in_body: self
                        .vehicle
                        .rotors
                        .is_empty()
                        .then_some(logged.wrenches[k]),
                };
                Step::OpenLoop {
                    record: Box::new(open_loop_record(observation.truth, logged, k, command)),
                    ee_reference,
                }
            }
        })
    }
}

/// A tick record for a command replayed open loop: the logged references and wrench, no
/// controller.
fn open_loop_record(
    m: &Measurement,
    logged: &LoggedFlight,
    k: usize,
    command: ActuatorCommand,
) -> TickRecord {
    TickRecord {
        time_s: m.time_s,
        base_target: logged.base_references[k],
        wrench: logged.wrenches[k],
        unallocated: Wrench::ZERO,
        allocation_saturated: false,
        controller: controllers::ControllerStatus {
            controller: "open-loop",
            position_error_m: logged.base_references[k].translation.vector
                - m.base.position_in_world_m,
            velocity_error_mps: -m.base.velocity_in_world_mps,
            attitude_error: Vector3::zeros(),
            angular_velocity_error_radps: -m.base.angular_velocity_in_body_radps,
            position_integral: Vector3::zeros(),
            attitude_integral: Vector3::zeros(),
            adaptive_force_n: None,
            adaptive_torque_nm: None,
            windup_blocked: [false; 6],
            input: InputHealth::Ok,
            dt_clamped: false,
            output: logged.wrenches[k],
            attitude_target: None,
        },
        command,
        ik: None,
        mpc: None,
        attitude: None,
    }
}

/// Checks that `logged` can be replayed as `config` says (rotor and joint counts of the
/// commands that will be flown), before anything is flown or written.
pub fn check_replay(logged: &LoggedFlight, config: &ReplayConfig) -> Result<(), ReplayError> {
    let vehicle = &config.vehicle;
    let ticks = logged.ticks();
    let rotors = vehicle.rotors.len();
    let dof = vehicle.model.dof();
    let log_error = |reason: String| ReplayError::Log {
        file: logged.path.display().to_string(),
        reason,
    };
    if config.mode == ReplayMode::Commands {
        if rotors > 0 && logged.rotor_commands.len() < ticks {
            return Err(log_error(
                "commands mode needs /rotors (commanded thrusts) at every tick".to_owned(),
            ));
        }
        if let Some(bad) = logged.rotor_commands.iter().find(|c| c.len() != rotors) {
            return Err(log_error(format!(
                "/rotors holds {} thrusts, vehicle {} has {rotors} rotors",
                bad.len(),
                vehicle.id
            )));
        }
        if let Some(k) = logged
            .rotor_commands
            .iter()
            .position(|c| c.iter().any(|x| !x.is_finite()))
        {
            return Err(log_error(format!(
                "/rotors message {k}: a commanded thrust is not a number; commands mode cannot fly it"
            )));
        }
    }
    // Joint targets are flown as logged in commands mode, and read by vehicle dof for the
    // arm targets of a reference replay without `/action`: they must fit the vehicle.
    let joints_used = config.mode == ReplayMode::Commands || logged.actions.is_none();
    if let Some(bad) = logged
        .joint_targets
        .iter()
        .find(|t| joints_used && t.len() != dof)
    {
        return Err(log_error(format!(
            "/joints holds {} targets, vehicle {} has {dof} joints",
            bad.len(),
            vehicle.id
        )));
    }
    Ok(())
}

/// Re-flies `logged` in the twin as `config` says and writes the flight log `config.out`.
pub fn replay_flight(
    logged: &LoggedFlight,
    config: &ReplayConfig,
) -> Result<ReplayResult, ReplayError> {
    check_replay(logged, config)?;
    let vehicle = &config.vehicle;
    let ticks = logged.ticks();
    let (twin, moved) = twin_at_initial_state(vehicle, &config.twin, logged)?;
    let twin_joints = &twin.truth().joint_positions;
    let initial_joint_mismatch = (vehicle.id == logged.run.vehicle_id
        && twin_joints.len() == logged.initial_joints.len())
    .then(|| {
        twin_joints
            .iter()
            .zip(&logged.initial_joints)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    });
    let mut link = TwinLink::new(twin);
    let mut stack = FlightStack::for_twin(vehicle.clone(), &config.controller, &config.twin)?;
    let mut run = RunMetadata::new(&vehicle.id, config.controller.name(), config.twin.seed)
        .with_trajectory(format!(
            "replay-{}:{}",
            config.mode.name(),
            logged.run.trajectory.as_deref().unwrap_or("unknown")
        ))
        .with_config(&config.twin)?
        .with_controller_config(&config.controller)?;
    if let Some(interface) = &logged.run.interface {
        run = run.with_interface(interface.clone());
    }
    let mut log = FlightLog::new(McapRecorder::create(&config.out, &run)?, vehicle)?
        .with_rotor_limits(config.twin.disturbances.saturation);
    let task = link.twin().task();
    let criteria_names = task.map(|t| t.criteria_names()).unwrap_or_default();
    // The replay's own success, as a bench rollout logs it; the replay flies every tick.
    let mut criteria = TaskCriteria::new(criteria_names.len(), false);
    let mut source = LoggedActions {
        logged,
        mode: config.mode,
        interface: logged.run.interface.as_deref().unwrap_or("base-joint"),
        vehicle,
    };
    let flown = crate::flight::run(
        &mut link,
        &mut stack,
        &mut source,
        &mut [&mut criteria, &mut log],
        FlightSpec {
            max_ticks: ticks as u64,
            dt_s: config.twin.control_dt_s(),
            control_rate_hz: config.twin.control_rate_hz,
            seed: config.twin.seed,
            state_source: StateSource::Truth,
            score_from_s: 0.0,
            interface: None,
            action_noise: None,
            stop: None,
            cameras: None,
        },
    );
    let flown = match flown {
        Ok(f) => f,
        Err(e) => {
            log.finish()?;
            return Err(match e {
                FlightError::Link(e) => e.into(),
                FlightError::Record(e) => e.into(),
                FlightError::Stack(e) => e.into(),
                e => ReplayError::Log {
                    file: logged.path.display().to_string(),
                    reason: e.to_string(),
                },
            });
        }
    };
    let stopped_early = match flown.end {
        End::Diverged(why) => Some(why),
        End::NanAction => Some("the replayed command was not finite".to_owned()),
        End::PolicyFailed(why) => Some(why),
        _ => None,
    };
    let replayed = usize::try_from(flown.ticks).unwrap_or(usize::MAX);
    let out = log.finish()?.path;
    Ok(ReplayResult {
        mode: config.mode,
        logged_ticks: ticks,
        replayed_ticks: replayed,
        stopped_early,
        actions_from_action_channel: logged.actions.is_some(),
        initial_state_from_log: moved,
        initial_joint_mismatch,
        out,
    })
}
