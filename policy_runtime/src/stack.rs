//! The flight stack of one tick: action → interface → base controller → allocation →
//! actuator command, with saturation fed back to the controller.

use allocation::{Allocation, AllocationMethod, Allocator, any_rotor_saturated};
use controllers::ik::{BaseLimits, IkConfig, IkStatus, WholeBodyIk};
use controllers::mpc::{FallbackEvent, MpcMode, MpcStatus, SolveFailure, WholeBodyMpc};
use controllers::{
    BaseController, BodyParams, ControllerConfig, ControllerStatus, InputHealth, Pid6Gains, build,
};
use nalgebra::{Isometry3, Matrix3};
use platform::{
    ActuatorCommand, AttitudeSetpoint, Measurement, PositionSetpoint, RigidBodyState, Vehicle,
    Wrench,
};
use serde::Serialize;
use sim_twin::{SaturatedAllocation, TiltThrust, TwinConfig};

use crate::link::{Setpoint, SetpointLevel};

/// A clock for the MPC's solve budget, seconds from any epoch. Injected: a run in the twin
/// has none (its results must not depend on the wall clock), a flight on hardware may pass
/// [`WallClock`].
pub trait TimeSource: Send + Sync + std::fmt::Debug {
    /// Now, s.
    fn now_s(&self) -> f64;
}

/// A shared [`TimeSource`].
pub type Clock = std::sync::Arc<dyn TimeSource>;

/// The wall clock, seconds since it was made.
#[derive(Debug, Clone, Copy)]
pub struct WallClock(std::time::Instant);

impl WallClock {
    /// A clock starting now.
    pub fn new() -> Self {
        Self(std::time::Instant::now())
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl TimeSource for WallClock {
    fn now_s(&self) -> f64 {
        self.0.elapsed().as_secs_f64()
    }
}

/// What the flight stack is asked to do at one tick: the base + arm-joint interface.
/// (The end-effector interface maps onto this through whole-body IK.)
#[derive(Debug, Clone, PartialEq)]
pub struct BaseJointTarget {
    /// Target base pose `world_from_base` (for the EE-only oracle: the EE body).
    pub world_from_base: Isometry3<f64>,
    /// Arm joint targets in the vehicle's command order, rad.
    pub arm_joints: Vec<f64>,
    /// Gripper action in [−1, 1]: −1 closed, +1 open.
    pub gripper: f64,
}

/// An end-effector target: the end-effector interface of AM-Bench.
#[derive(Debug, Clone, PartialEq)]
pub struct EeTarget {
    /// Target end-effector pose in the command frame (AMBENCH_SPEC §1.1): the link is at
    /// `command_to_link ⊗ rotation`.
    pub world_from_ee_command: Isometry3<f64>,
    /// Gripper action in [−1, 1].
    pub gripper: f64,
}

/// The action interfaces of AM-Bench.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// End-effector target, through whole-body IK (or directly, for the EE-only oracle).
    Ee(EeTarget),
    /// Base pose and arm joints.
    BaseJoint(BaseJointTarget),
}

/// Which action interface carries an action to the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Interface {
    /// Base pose and arm joints straight to the controller and the joint drives.
    BaseJoint,
    /// An end-effector target, through whole-body IK (or the MPC).
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

/// Whole-body IK for the end-effector interface, and the base limits it keeps.
#[derive(Debug)]
struct EeInterface {
    ik: WholeBodyIk,
    limits: BaseLimits,
}

/// The whole-body MPC as the end-effector interface (the `mpc` controller), and the base
/// limits it keeps.
#[derive(Debug)]
struct MpcInterface {
    controller: WholeBodyMpc,
    limits: BaseLimits,
    /// While the IK-PID fallback flies after a hand-over for the rotors' sake: the joint
    /// configuration it was handed (its IK's rest posture fades from it over the fallback's
    /// ticks, `MpcConfig::fallback_posture_time_constant_s`).
    handed_posture: Option<Vec<f64>>,
}

/// How thrusts are chosen from the allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ThrustLimits {
    /// Rotors limited to [T_min, T_max]: the allocation's bounded thrusts are sent and what
    /// it could not achieve is fed back to the controller.
    Enforced,
    /// Ideal unbounded rotors (the reference without `enable_saturation`): the
    /// pseudo-inverse thrusts are sent as they are, negative ones included.
    Ideal,
}

/// Everything one tick decided, for logs and metrics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TickRecord {
    /// Measurement time the tick acted on, s.
    pub time_s: f64,
    /// The base target handed to the controller.
    pub base_target: Isometry3<f64>,
    /// Requested body wrench.
    pub wrench: Wrench,
    /// What the allocator could not achieve (zero with ideal rotors).
    pub unallocated: Wrench,
    /// The paper's saturation indicator on the sent thrusts (any rotor at a limit).
    pub allocation_saturated: bool,
    /// Controller status after the update.
    pub controller: ControllerStatus,
    /// The command sent.
    pub command: ActuatorCommand,
    /// The IK's status, for an end-effector action through IK.
    #[serde(skip)]
    pub ik: Option<IkStatus>,
    /// The MPC's report (mode, fallback event, RTI step), for an end-effector action flown
    /// by the `mpc` controller.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mpc: Option<MpcStatus>,
    /// The attitude level of the tick's cascade: the base controller's desired attitude and
    /// body rates with the body force the allocation produces (the requested force minus
    /// the unallocated part, so the saturation feedback the controller receives stays true).
    /// None when the tick was not flown by an attitude loop (the whole-body MPC's solution,
    /// an open-loop command).
    #[serde(skip)]
    pub attitude: Option<AttitudeSetpoint>,
}

impl TickRecord {
    /// The tick's setpoint at `level`. The attitude level needs the cascade of a base
    /// controller: a tick flown otherwise (the whole-body MPC) is refused with why. The
    /// position level is the base target handed to the controller (the IK's, the MPC's, or
    /// the action's base pose): its position and heading. The rate level is the attitude
    /// level through amstack's attitude law ([`controllers::rate_setpoint`] with PX4's
    /// attitude gains [`controllers::PX4_ATTITUDE_P_PER_S`]).
    pub fn setpoint(&self, level: SetpointLevel) -> Result<Setpoint, StackError> {
        let no_attitude_loop = || {
            StackError(format!(
                "the {} controller has no attitude loop: its tick cannot be flown at the {} level (fly it at the position or the actuator level)",
                self.controller.controller,
                level.name()
            ))
        };
        match level {
            SetpointLevel::Rates => match self.attitude {
                Some(attitude) => Ok(Setpoint::Rates {
                    command: self.command.clone(),
                    rates: controllers::rate_setpoint(
                        &attitude,
                        &self.controller.attitude_error,
                        controllers::PX4_ATTITUDE_P_PER_S,
                    ),
                }),
                None => Err(no_attitude_loop()),
            },
            SetpointLevel::Actuators => Ok(Setpoint::Actuators(self.command.clone())),
            SetpointLevel::Position => Ok(Setpoint::Position {
                command: self.command.clone(),
                position: PositionSetpoint::of_pose(&self.base_target),
            }),
            SetpointLevel::Attitude => match self.attitude {
                Some(attitude) => Ok(Setpoint::Attitude {
                    command: self.command.clone(),
                    attitude,
                }),
                None => Err(no_attitude_loop()),
            },
        }
    }
}

/// Who asked for the wrench of a tick: the allocator's feedback goes back to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Requester {
    /// The stack's base controller.
    Base,
    /// The whole-body MPC's own solution.
    Mpc,
}

/// Controller, allocator and the vehicle's command layout, built once.
#[derive(Debug)]
pub struct FlightStack {
    vehicle: Vehicle,
    controller: Box<dyn BaseController>,
    allocator: Option<Allocator>,
    allocation: Allocation,
    limits: ThrustLimits,
    arm_dofs: Vec<usize>,
    gripper_dofs: Vec<usize>,
    tilt_dofs: Vec<usize>,
    measured_tilt: Vec<f64>,
    project_on_measured_tilt: bool,
    /// Low-passed joint configuration the mass properties follow.
    posture: Vec<f64>,
    /// The vehicle's initial configuration: the targets of joints no action commands.
    initial: Vec<f64>,
    /// The vehicle's inertia about its centre of mass at `initial`: the base controller's.
    initial_inertia_kgm2: Matrix3<f64>,
    ee: Option<EeInterface>,
    mpc: Option<MpcInterface>,
    /// The vehicle IK profile's safety margin from obstacle faces, m.
    safety_margin_m: f64,
    dt_s: f64,
    /// The MPC's solve-budget clock (none by default: deterministic).
    clock: Option<Clock>,
}

/// Time constant of the posture the controller's mass properties follow, s.
pub const POSTURE_FILTER_TIME_CONSTANT_S: f64 = 0.25;

/// The stack cannot be built for this vehicle and controller.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct StackError(pub String);

impl FlightStack {
    /// A stack for `vehicle` with the controller `config`, running every `dt_s` seconds.
    ///
    /// With [`ControllerConfig::Mpc`] (FA-Hexa only) end-effector actions are flown by the
    /// whole-body MPC ([`WholeBodyMpc`], with its own fallback); base + joint actions, which
    /// the MPC does not take, by PID6 with the reference gains.
    pub fn new(
        vehicle: Vehicle,
        config: &ControllerConfig,
        method: AllocationMethod,
        limits: ThrustLimits,
        dt_s: f64,
    ) -> Result<Self, StackError> {
        let (mpc, base_config) = match config {
            ControllerConfig::Mpc(c) => (
                Some(MpcInterface {
                    // Ideal rotors have no limits for the MPC's saturation fallback to protect.
                    controller: WholeBodyMpc::new(
                        &vehicle,
                        controllers::mpc::MpcConfig {
                            rotor_saturation_fallback: c.rotor_saturation_fallback
                                && limits == ThrustLimits::Enforced,
                            ..*c
                        },
                    )
                    .map_err(|e| StackError(format!("mpc: {e}")))?,
                    limits: BaseLimits::above_ground(),
                    handed_posture: None,
                }),
                ControllerConfig::Pid6(Pid6Gains::am_bench()),
            ),
            other => (None, *other),
        };
        let controller = build(&base_config, BodyParams::from_vehicle(&vehicle))
            .map_err(|e| StackError(e.to_string()))?;
        let allocator = if vehicle.rotors.is_empty() {
            None
        } else {
            Some(
                Allocator::new(&vehicle.rotors, vehicle.actuation, method)
                    .map_err(|e| StackError(e.to_string()))?,
            )
        };
        let allocation = allocator
            .as_ref()
            .map(Allocator::new_allocation)
            .unwrap_or_default();
        let dof_of = |joint: usize| vehicle.model.joints[joint].dof;
        let arm_dofs = vehicle.arm_dofs();
        let gripper_dofs = vehicle.gripper.as_ref().map_or_else(Vec::new, |g| {
            g.joints.iter().filter_map(|&j| dof_of(j)).collect()
        });
        let tilt_dofs = vehicle.tilt_dofs();
        let vehicle_initial = vehicle.initial_configuration();
        let initial_inertia_kgm2 =
            BodyParams::at_configuration(&vehicle, &vehicle_initial).inertia_kgm2;
        // The vehicle's IK profile: the EE interface's solver, and the margin the base keeps
        // from obstacle faces (also for the MPC, which has no IK).
        let ik_config = IkConfig::for_vehicle(&vehicle).map_err(|e| StackError(e.to_string()))?;
        let safety_margin_m = ik_config.safety_margin_m;
        // The EE interface needs IK unless the end effector is the controlled body.
        let ee = if vehicle.ee_link == vehicle.base_link {
            None
        } else {
            let ik = WholeBodyIk::new(&vehicle, ik_config)
                .map_err(|e| StackError(format!("whole-body IK: {e}")))?;
            Some(EeInterface {
                ik,
                limits: BaseLimits::above_ground(),
            })
        };
        Ok(Self {
            measured_tilt: vec![0.0; tilt_dofs.len()],
            vehicle,
            controller,
            allocator,
            allocation,
            limits,
            arm_dofs,
            gripper_dofs,
            tilt_dofs,
            project_on_measured_tilt: false,
            posture: vehicle_initial.clone(),
            initial_inertia_kgm2,
            initial: vehicle_initial,
            ee,
            mpc,
            safety_margin_m,
            dt_s,
            clock: None,
        })
    }

    /// Times the MPC's solves with `clock` against its solve budget (none by default: a run
    /// in the twin must not depend on the wall clock; a flight on hardware may pass it).
    pub fn with_clock(mut self, clock: Option<Clock>) -> Self {
        self.clock = clock;
        self
    }

    /// The base limits the IK keeps (e.g. a wall's face minus the safety margin); by
    /// default, above the ground. End-effector actions go through whole-body IK with the
    /// vehicle's reference profile (AMBENCH_SPEC §2.6; the default profile for a vehicle
    /// added by a user), or straight to the controller when the end effector is the
    /// controlled body (the EE-only oracle).
    pub fn set_base_limits(&mut self, limits: BaseLimits) {
        if let Some(ee) = &mut self.ee {
            ee.limits = limits;
        }
        if let Some(mpc) = &mut self.mpc {
            mpc.limits = limits;
        }
    }

    /// Keeps the base in front of an obstacle face at world x `face_x_m` (a wall, a door, a
    /// window: AMBENCH_SPEC §2.6 per-env limits), minus the vehicle's IK safety margin;
    /// `None` keeps it above the ground only. Called every tick by the benchmark, as the
    /// reference recomputes the limits every step.
    pub fn keep_in_front_of(&mut self, face_x_m: Option<f64>) {
        let margin = self.safety_margin_m;
        self.set_base_limits(face_x_m.map_or_else(BaseLimits::above_ground, |x| {
            BaseLimits::in_front_of_face_x(x, margin)
        }));
    }

    /// Tells the whole-body MPC the joint of the object the hand holds (None: nothing held,
    /// or a free object), world frame, now: its grasp rows keep the predicted end effector on
    /// that joint's motion (`controllers::mpc::grasp`). Called every tick by the flight loop
    /// from the task's scene, as [`Self::keep_in_front_of`]; the other controllers do not
    /// use it.
    pub fn hold_on_joint(&mut self, joint: Option<platform::HeldJoint>) {
        if let Some(mpc) = &mut self.mpc {
            mpc.controller.set_held_joint(joint);
        }
    }

    /// Tells the whole-body MPC the normal (unit, world, out of what the hand touches) of the
    /// hand's contact with something that does not give way along it (None: none): its
    /// target then stays on the hand's side of the contact (`MpcConfig::contact_reference`).
    /// Called every tick by the flight loop from the task's scene; the other controllers do
    /// not use it.
    pub fn touch(&mut self, normal: Option<nalgebra::Vector3<f64>>) {
        if let Some(mpc) = &mut self.mpc {
            mpc.controller.set_hand_contact(normal);
        }
    }

    /// Where `action` asks the end-effector link to be: the forward kinematics of a base +
    /// joint target (joints no action commands at their initial configuration), or an EE
    /// target's link pose.
    pub fn ee_reference(&self, action: &Action) -> Isometry3<f64> {
        match action {
            Action::Ee(ee) => self.link_target(ee),
            Action::BaseJoint(target) => ee_link_target(&self.vehicle, target),
        }
    }

    /// `action` in `interface`: an EE target through the whole-body IK as a base + joint
    /// target (as the reference converts its scripted policies), or a base + joint target as
    /// the EE target at `ee_reference` (its [`Self::ee_reference`]).
    pub fn convert(
        &mut self,
        action: Action,
        interface: Interface,
        ee_reference: &Isometry3<f64>,
    ) -> Action {
        match (action, interface) {
            (Action::Ee(ee), Interface::BaseJoint) => {
                Action::BaseJoint(self.ee_to_base_joint_target(&ee))
            }
            (Action::BaseJoint(target), Interface::Ee) => {
                let mut world_from_ee_command = *ee_reference;
                world_from_ee_command.rotation =
                    self.vehicle.command_to_link.inverse() * ee_reference.rotation;
                Action::Ee(EeTarget {
                    world_from_ee_command,
                    gripper: target.gripper,
                })
            }
            (action, _) => action,
        }
    }

    /// An end-effector action as the base + joint target the IK makes of it (the base +
    /// joint interface of the scripted policies, converted as the reference does).
    pub fn ee_to_base_joint_target(&mut self, ee: &EeTarget) -> BaseJointTarget {
        self.ee_to_base_joint(ee).0
    }

    /// The stack that flies the twin of `twin` (in this process or over a link): the rotor
    /// limits the twin enforces (ideal unbounded rotors unless `saturation` is on), allocated
    /// as `twin.saturated_allocation` says under them (the pseudo-inverse with ideal rotors),
    /// the twin's control period, and the tilt projection where its tilting rotors push along
    /// the measured hinge angle.
    pub fn for_twin(
        vehicle: Vehicle,
        config: &ControllerConfig,
        twin: &TwinConfig,
    ) -> Result<Self, StackError> {
        let limits = if twin.disturbances.saturation {
            ThrustLimits::Enforced
        } else {
            ThrustLimits::Ideal
        };
        let method = match (limits, twin.saturated_allocation) {
            (ThrustLimits::Enforced, SaturatedAllocation::Prioritized) => {
                AllocationMethod::Constrained(allocation::ConstrainedSettings::default())
            }
            _ => AllocationMethod::PseudoInverse,
        };
        let mut stack = Self::new(vehicle, config, method, limits, twin.control_dt_s())?
            .with_tilt_projection(twin.tilt_thrust == TiltThrust::Measured);
        // The reference's task-specific IK profiles belong to its PID profiles.
        if let (Some(task), ControllerConfig::Pid6(_) | ControllerConfig::Pid4(_)) =
            (twin.task, config)
        {
            stack.use_task_ik_profile(task.name())?;
        }
        Ok(stack)
    }

    /// Switches the whole-body IK to the reference's profile for `task` where the vehicle's
    /// preset has one ([`IkConfig::task_override`]); otherwise nothing changes.
    pub fn use_task_ik_profile(&mut self, task: &str) -> Result<(), StackError> {
        let Some(preset) = self.vehicle.control.ik.as_deref() else {
            return Ok(());
        };
        let Some(config) = IkConfig::task_override(preset, task) else {
            return Ok(());
        };
        self.safety_margin_m = config.safety_margin_m;
        if let Some(ee) = &mut self.ee {
            ee.ik = WholeBodyIk::new(&self.vehicle, config)
                .map_err(|e| StackError(format!("whole-body IK: {e}")))?;
        }
        Ok(())
    }

    /// Whether each tilting rotor's thrust is projected on its measured direction (for links
    /// whose rotors push along the hinge's actual angle: hardware, or the twin's
    /// `TiltThrust::Measured`). Off by default.
    pub fn with_tilt_projection(mut self, on: bool) -> Self {
        self.project_on_measured_tilt = on;
        self
    }

    /// The vehicle flown.
    pub fn vehicle(&self) -> &Vehicle {
        &self.vehicle
    }

    /// Control period, s.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }

    /// Clears the controller for a new flight from `state`.
    pub fn reset(&mut self, state: &RigidBodyState) {
        let initial = self.initial.clone();
        self.reset_at(state, &initial);
    }

    /// Clears the controller for a new flight from `state` with the joints at
    /// `configuration`; the IK warm-starts from them (as the reference does at an episode's
    /// start).
    pub fn reset_at(&mut self, state: &RigidBodyState, configuration: &[f64]) {
        self.controller.reset(state);
        self.posture.clone_from(&self.initial);
        if let Some(ee) = &mut self.ee {
            // A seed of the wrong length or non-finite is refused; the IK then keeps its rest seed.
            let _ = ee.ik.reset(&state.pose(), configuration);
            ee.ik.restore_rest_configuration();
        }
        if let Some(mpc) = &mut self.mpc {
            mpc.controller.reset(state, configuration);
            mpc.handed_posture = None;
        }
    }

    /// The whole-body MPC, when the stack flies the `mpc` controller.
    pub fn mpc(&self) -> Option<&WholeBodyMpc> {
        self.mpc.as_ref().map(|m| &m.controller)
    }

    /// One tick of either interface.
    pub fn act(&mut self, measurement: &Measurement, action: &Action) -> TickRecord {
        match action {
            Action::BaseJoint(target) => self.tick(measurement, target),
            Action::Ee(ee) if self.mpc.is_some() => self.mpc_tick(measurement, ee),
            Action::Ee(ee) => {
                let (target, status) = self.ee_to_base_joint(ee);
                let mut record = self.tick(measurement, &target);
                record.ik = status;
                record
            }
        }
    }

    /// The end-effector link pose an EE action asks for.
    pub fn link_target(&self, ee: &EeTarget) -> Isometry3<f64> {
        let mut link = ee.world_from_ee_command;
        link.rotation = self.vehicle.command_to_link * link.rotation;
        link
    }

    /// An EE target as a base + joint target: through IK, or as the base itself for a
    /// vehicle whose controlled body is the end effector.
    fn ee_to_base_joint(&mut self, ee: &EeTarget) -> (BaseJointTarget, Option<IkStatus>) {
        let link = self.link_target(ee);
        match &mut self.ee {
            Some(interface) => {
                let solution = interface.ik.solve(&link, &interface.limits);
                let target = BaseJointTarget {
                    world_from_base: solution.world_from_base,
                    arm_joints: solution.arm_joints,
                    gripper: ee.gripper,
                };
                (target, Some(solution.status))
            }
            None => (
                BaseJointTarget {
                    world_from_base: link,
                    arm_joints: Vec::new(),
                    gripper: ee.gripper,
                },
                None,
            ),
        }
    }

    /// The arm moves the centre of mass: the model-based terms follow the arm's posture,
    /// low-passed so the quasi-static feed-forward does not couple the arm's fast dynamics
    /// (a drive at its effort limit swinging) into the attitude loop.
    ///
    /// The base controller's inertia stays the vehicle's at its initial configuration, as
    /// the reference's (AMBENCH_SPEC §2.1): the PID attitude laws' rate loop is deadbeat
    /// (kd_rot·dt = 1 with the reference gains), so a model inertia more than twice the
    /// inertia the torque actually turns makes it unstable. An arm whose drives are at
    /// their effort limit (the UA-Hexa's 20 N·m) no longer turns with the base, leaving the
    /// base's own inertia; the posture-following inertia of the extended arm is 2.3–2.8 times
    /// that, and the UA-Hexa's rate loop diverged at 20 Hz within a second on NDT's arm sweep
    /// (and on six more tasks). The folded arm's inertia is within 1.3 times the base's. The
    /// MPC, whose model is not deadbeat, keeps the posture-following inertia.
    fn follow_posture(&mut self, measurement: &Measurement) {
        if measurement.joint_positions.len() == self.posture.len()
            && measurement.joint_positions.iter().all(|q| q.is_finite())
        {
            let a = (self.dt_s / POSTURE_FILTER_TIME_CONSTANT_S).min(1.0);
            for (p, q) in self.posture.iter_mut().zip(&measurement.joint_positions) {
                *p += a * (q - *p);
            }
            let body = BodyParams::at_configuration(&self.vehicle, &self.posture);
            self.controller.set_body(BodyParams {
                inertia_kgm2: self.initial_inertia_kgm2,
                ..body
            });
            if let Some(mpc) = &mut self.mpc {
                mpc.controller.set_body(body);
            }
        }
    }

    /// One tick of the `mpc` controller toward an EE target.
    fn mpc_tick(&mut self, measurement: &Measurement, ee: &EeTarget) -> TickRecord {
        self.follow_posture(measurement);
        let link = self.link_target(ee);
        let dt = self.dt_s;
        let Some(mpc) = &mut self.mpc else {
            // Only called with an MPC; a bug otherwise: fly the IK path's base controller.
            let target = BaseJointTarget {
                world_from_base: measurement.base.pose(),
                arm_joints: Vec::new(),
                gripper: ee.gripper,
            };
            return self.tick(measurement, &target);
        };
        let clock = self.clock.clone();
        let now = move || clock.as_ref().map_or(0.0, |c| c.now_s());
        let command = mpc.controller.update(
            &measurement.base,
            &measurement.joint_positions,
            &link,
            &mpc.limits,
            dt,
            self.clock.is_some().then_some(&now as &dyn Fn() -> f64),
        );
        let flies_fallback = command.status.mode == MpcMode::IkPid
            && command.status.failure != Some(SolveFailure::NonFiniteInput);
        if flies_fallback {
            return self.mpc_fallback_tick(measurement, ee, &command.status);
        }
        if mpc.handed_posture.take().is_some()
            && let Some(interface) = &mut self.ee
        {
            interface.ik.restore_rest_configuration();
        }
        let target = BaseJointTarget {
            world_from_base: command.base_target,
            arm_joints: command.arm_targets_rad.to_vec(),
            gripper: ee.gripper,
        };
        let status = ControllerStatus {
            controller: "mpc",
            position_error_m: link.translation.vector
                - measurement.world_from_ee.translation.vector,
            velocity_error_mps: -measurement.base.velocity_in_world_mps,
            attitude_error: nalgebra::Vector3::zeros(),
            angular_velocity_error_radps: -measurement.base.angular_velocity_in_body_radps,
            position_integral: nalgebra::Vector3::zeros(),
            attitude_integral: nalgebra::Vector3::zeros(),
            adaptive_force_n: None,
            adaptive_torque_nm: None,
            windup_blocked: [false; 6],
            input: if command.wrench_in_body.is_finite() {
                InputHealth::Ok
            } else {
                InputHealth::NonFiniteState
            },
            dt_clamped: false,
            output: command.wrench_in_body,
            attitude_target: None,
        };
        let mut record = self.command(
            measurement,
            command.wrench_in_body,
            &target,
            status,
            Requester::Mpc,
        );
        record.mpc = Some(command.status);
        record
    }

    /// A tick the MPC hands to its fallback: the stack's own end-effector path — whole-body IK
    /// and the base controller (PID6 with the reference gains for the `mpc` controller), both
    /// reset from the measured state on the tick it takes over, the IK (after a hand-over for
    /// the rotors' sake) resolving the arm's redundancy about the posture it was handed
    /// (fading to its configured rest,
    /// `MpcConfig::fallback_posture_time_constant_s`) — then what it flew goes back to the
    /// MPC, whose filter continues from it.
    fn mpc_fallback_tick(
        &mut self,
        measurement: &Measurement,
        ee: &EeTarget,
        status: &MpcStatus,
    ) -> TickRecord {
        if status.event == Some(FallbackEvent::IkPidTookOver) {
            self.controller.reset(&measurement.base);
            if let Some(interface) = &mut self.ee {
                let _ = interface
                    .ik
                    .reset(&measurement.base.pose(), &measurement.joint_positions);
                interface.ik.restore_rest_configuration();
            }
            // Only a hand-over for the rotors' sake continues the MPC's motion: after failed
            // solves the MPC's own posture is where its QP stopped being solvable, and the
            // IK's rest posture takes the arm out of it.
            if let Some(mpc) = &mut self.mpc {
                mpc.handed_posture = (status.failure == Some(SolveFailure::RotorSaturation))
                    .then(|| measurement.joint_positions.clone());
            }
        }
        // The IK keeps the posture it was handed, fading to its configured rest.
        if let (Some(mpc), Some(interface)) = (&self.mpc, &mut self.ee)
            && let Some(handed) = &mpc.handed_posture
        {
            let tau = mpc.controller.config().fallback_posture_time_constant_s;
            let flown_s = f64::from(mpc.controller.fallback_ticks()) * self.dt_s;
            let share = if tau > 0.0 {
                (-flown_s / tau).exp()
            } else {
                0.0
            };
            // A handed configuration of the wrong length or non-finite is refused; the IK
            // then keeps the rest it has.
            let _ = interface.ik.blend_rest_configuration(handed, share);
        }
        let (target, ik) = self.ee_to_base_joint(ee);
        // The posture was followed at the start of the MPC's tick.
        let wrench = self
            .controller
            .update(&measurement.base, &target.world_from_base, self.dt_s);
        let controller = self.controller.status();
        let mut record = self.command(measurement, wrench, &target, controller, Requester::Base);
        if let Some(mpc) = &mut self.mpc {
            mpc.controller.fallback_flown(
                &measurement.base,
                &wrench,
                &target.arm_joints,
                &target.world_from_base,
            );
        }
        record.ik = ik;
        record.mpc = Some(*status);
        record
    }

    /// One tick: from the latest measurement and the target, the command to send.
    pub fn tick(&mut self, measurement: &Measurement, target: &BaseJointTarget) -> TickRecord {
        self.follow_posture(measurement);
        let wrench = self
            .controller
            .update(&measurement.base, &target.world_from_base, self.dt_s);
        let status = self.controller.status();
        self.command(measurement, wrench, target, status, Requester::Base)
    }

    /// Joint targets and allocation of a requested body wrench; the unallocated part is fed
    /// back to whoever requested it.
    fn command(
        &mut self,
        measurement: &Measurement,
        wrench: Wrench,
        target: &BaseJointTarget,
        status: ControllerStatus,
        requester: Requester,
    ) -> TickRecord {
        let mut joint_targets = self.initial.clone();
        for (&dof, &q) in self.arm_dofs.iter().zip(&target.arm_joints) {
            joint_targets[dof] = q;
        }
        if let Some(g) = &self.vehicle.gripper {
            for (&dof, q) in self.gripper_dofs.iter().zip(g.targets(target.gripper)) {
                joint_targets[dof] = q;
            }
        }
        let mut command = ActuatorCommand {
            rotor_thrusts_n: Vec::new(),
            joint_targets,
            direct_wrench_in_body: None,
        };
        let mut unallocated = Wrench::ZERO;
        let mut allocation_saturated = false;
        match &mut self.allocator {
            None => command.direct_wrench_in_body = Some(wrench),
            Some(allocator) => {
                for (m, &dof) in self.measured_tilt.iter_mut().zip(&self.tilt_dofs) {
                    *m = measurement.joint_positions.get(dof).copied().unwrap_or(0.0);
                }
                let result =
                    allocator.allocate_into(&wrench, &self.measured_tilt, &mut self.allocation);
                let a = &self.allocation;
                if result.is_ok() {
                    command.rotor_thrusts_n = match self.limits {
                        ThrustLimits::Enforced => a.thrusts_n.clone(),
                        ThrustLimits::Ideal => a.unconstrained_thrusts_n.clone(),
                    };
                    for (&dof, &angle) in self.tilt_dofs.iter().zip(&a.tilt_rad) {
                        command.joint_targets[dof] = angle;
                    }
                    // Tilt hinges lag their targets: give each rotor the projection of its
                    // desired thrust vector on its measured direction, T·cos(α − α_measured),
                    // so a rotor whose hinge has not arrived never pushes the wrong way (the
                    // reference applies the commanded angle as if reached, AMBENCH_SPEC §9).
                    let (t_min, t_max) = (
                        self.vehicle.rotors.thrust_min_n,
                        self.vehicle.rotors.thrust_max_n,
                    );
                    let projecting =
                        self.project_on_measured_tilt && !self.measured_tilt.is_empty();
                    for ((thrust, &angle), &measured) in command
                        .rotor_thrusts_n
                        .iter_mut()
                        .zip(&a.tilt_rad)
                        .zip(&self.measured_tilt)
                        .filter(|_| projecting)
                    {
                        let projected = *thrust * (angle - measured).cos();
                        *thrust = match self.limits {
                            ThrustLimits::Enforced => projected.clamp(t_min, t_max),
                            ThrustLimits::Ideal => projected,
                        };
                    }
                    if self.limits == ThrustLimits::Enforced {
                        unallocated = a.unallocated;
                        // The base controller's integrators are guarded; the MPC's
                        // solution has none (its fallback ticks are the base controller's).
                        if requester == Requester::Base {
                            self.controller.saturation_feedback(&unallocated);
                        }
                    }
                } else {
                    // A measured-tilt length mismatch is a construction bug: idle safely.
                    command.rotor_thrusts_n =
                        vec![self.vehicle.rotors.thrust_min_n; self.vehicle.rotors.len()];
                }
                let (t_min, t_max) = (
                    self.vehicle.rotors.thrust_min_n,
                    self.vehicle.rotors.thrust_max_n,
                );
                allocation_saturated = any_rotor_saturated(&command.rotor_thrusts_n, t_min, t_max);
            }
        }
        // The attitude level: the base controller's target, or (a safe output before any
        // usable update) the measured attitude without rate feed-forward.
        let force = wrench.force - unallocated.force;
        let attitude = match requester {
            Requester::Mpc => None,
            Requester::Base => Some(status.attitude_setpoint(force).unwrap_or(AttitudeSetpoint {
                world_from_body: measurement.base.world_from_body,
                force_in_body_n: force,
                body_rates_radps: None,
            })),
        };
        TickRecord {
            time_s: measurement.time_s,
            base_target: target.world_from_base,
            wrench,
            unallocated,
            allocation_saturated,
            controller: status,
            command,
            ik: None,
            mpc: None,
            attitude,
        }
    }
}

/// Where a base + joint target puts the end-effector link (forward kinematics of the vehicle
/// description, joints no action commands at their initial configuration).
pub fn ee_link_target(vehicle: &Vehicle, target: &BaseJointTarget) -> Isometry3<f64> {
    let mut q = vehicle.initial_configuration();
    for (&dof, &value) in vehicle.arm_dofs().iter().zip(&target.arm_joints) {
        q[dof] = value;
    }
    target.world_from_base * vehicle.model.root_from_link(&q, vehicle.ee_link)
}
