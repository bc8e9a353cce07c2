//! The `mpc` controller of the FA-Hexa: SQP-RTI every tick, the reference's output filter and
//! gravity compensation, and a fallback when a solve fails.
//!
//! Per tick (AMBENCH_SPEC §2.5):
//! 1. x̂ = [p, v, rpy of the base quaternion, body rates ω_b, arm joints]; one RTI step toward
//!    the EE target (the EE command held over the horizon), previous solution shifted by dt.
//! 2. u = g∘u_opt + (1 − g)∘u_last (g = `output_filter_gain`; no filter on the first tick);
//!    u_last ← u (without gravity: see `rti`'s conscious differences).
//! 3. Gravity compensation after the solve: F_w += m g ẑ. The wrench goes to the allocator in
//!    the body frame, `F_b = Rᵀ F_w`, `τ_b = Rᵀ τ_w + c × Rᵀ(m g ẑ)` — R from the measured
//!    quaternion (the reference uses an XYZ Euler matrix, equal within its ±0.01 rad tilt), and
//!    the last term cancels the gravity moment of a centre of mass c off the base origin (as
//!    the PID controllers do; the reference leaves it to the MPC's feedback). Arm targets are
//!    the filtered references, clipped to the joint bounds.
//!
//! # Fallback
//!
//! A solve *fails* when its QP does not reach `Solved` within `qp.max_iterations` (the
//! deterministic budget) or, when a `solve_budget_s` is set, when the step took longer by the
//! caller's clock. Then:
//! - for up to `fallback_hold_ticks` consecutive failed ticks the shifted previous solution
//!   is held (RTI keeps it when a QP fails: its first input, at the current time, is applied
//!   through the same filter and gravity compensation) — mode [`MpcMode::Hold`];
//! - after that, the IK-PID path flies — mode [`MpcMode::IkPid`]. The MPC does not fly it: it
//!   reports the mode (and [`FallbackEvent::IkPidTookOver`] on the tick it starts), and the
//!   caller flies its own end-effector path (the flight stack's whole-body IK with the
//!   vehicle's preset and PID6 with the reference gains, both reset from the measured state
//!   when it takes over; after a saturation hand-over the IK's rest posture is the arm
//!   posture it was handed, fading to its configured one over
//!   [`MpcConfig::fallback_posture_time_constant_s`]), then hands the
//!   MPC what it flew ([`WholeBodyMpc::fallback_flown`])
//!   so the filter continues from the applied command. The command returned on such a tick
//!   is the held solution, for reference only;
//! - a solution whose wrench the rotors cannot deliver (allocated linearly around hover, a
//!   rotor beyond its limits by more than [`ROTOR_LIMIT_TOLERANCE_N`]) is not flown: the
//!   IK-PID path takes over at once ([`SolveFailure::RotorSaturation`]) — holding the previous
//!   solution would ask for the same impossible wrench;
//! - the MPC is still solved every tick; the first solve that succeeds (after at least
//!   `fallback_hold_ticks` ticks of IK-PID, so the two paths do not chatter) hands control
//!   back (mode [`MpcMode::Mpc`]), with the filter continuing from the last applied command.
//!
//! Every change of mode is reported in [`MpcStatus::event`] for that tick.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState, Vehicle, Wrench};
use serde::Serialize;

use crate::controller::{BodyParams, guard_dt};
use crate::ik::BaseLimits;
use crate::mpc::config::MpcConfig;
use crate::mpc::model::{
    IU_F, IU_QREF, IU_TAU, IX_ETA, IX_OMEGA, IX_P, IX_Q, IX_V, NQ, RotorEnvelope,
};
use crate::mpc::qp::{InputVector, QpStatus, StateVector};
use crate::mpc::rti::{MpcError, MpcReference, RtiReport, SqpRti};

/// How far past a rotor limit the linearised allocation of an MPC wrench may go before the
/// solution counts as one the rotors cannot deliver, N (the hover linearisation ignores the
/// arm's posture).
pub const ROTOR_LIMIT_TOLERANCE_N: f64 = 1.0;

/// Who flies the vehicle this tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MpcMode {
    /// The MPC's fresh solution.
    #[default]
    Mpc,
    /// The shifted previous MPC solution, after a failed solve.
    Hold,
    /// Whole-body IK + PID6, after `fallback_hold_ticks` failed solves.
    IkPid,
}

/// A change of mode, reported on the tick it happens.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FallbackEvent {
    /// A solve failed: holding the shifted previous solution.
    HoldStarted,
    /// Too many failed solves: the IK-PID path took over.
    IkPidTookOver,
    /// A solve succeeded again: the MPC flies.
    MpcRecovered,
}

/// Why a solve counted as failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveFailure {
    /// The QP did not converge (status in the report).
    QpNotSolved,
    /// The step exceeded `solve_budget_s`.
    OverBudget,
    /// The measured state or the target was not finite (nothing was solved).
    NonFiniteInput,
    /// The MPC's wrench (gravity compensation included, at the measured attitude and
    /// posture) would take a rotor beyond its thrust limits through the pseudo-inverse
    /// allocation: the IK-PID path takes over at once.
    RotorSaturation,
}

/// What one tick's RTI step was given: enough to pose the same QP again ([`SqpRti::step`]
/// with these arguments, after [`SqpRti::reset`] when `warm` is false). `amstack mpc-bench`
/// replays a benchmark rollout's problems through the solver this way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcProblem {
    /// The measured state x̂.
    pub x_hat: StateVector,
    /// The EE target and the last applied input.
    pub reference: MpcReference,
    /// The base limits.
    pub limits: BaseLimits,
    /// Time since the previous solution, s (the shift of the warm start).
    pub elapsed_s: f64,
    /// Whether the solver started from its previous solution (false: a cold start).
    pub warm: bool,
    /// The held object's joint ([`SqpRti::set_grasp`] before the step; None: nothing held).
    pub grasp: Option<platform::HeldJoint>,
    /// The normal of the hand's blocking contact ([`SqpRti::set_contact`] before the step;
    /// None: none).
    pub contact: Option<Vector3<f64>>,
    /// The weight (N) and centre of mass (base frame, m) the rotor rows compensate, the flown
    /// posture's ([`SqpRti::set_compensated_weight`] before the step).
    pub compensated_weight: (f64, Vector3<f64>),
}

/// The controller's report of one tick.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MpcStatus {
    /// Who flew this tick.
    pub mode: MpcMode,
    /// A change of mode on this tick.
    pub event: Option<FallbackEvent>,
    /// Why this tick's solve failed (None: it succeeded).
    pub failure: Option<SolveFailure>,
    /// Consecutive failed solves up to this tick.
    pub failed_ticks: u32,
    /// The RTI step (None when nothing was solved).
    pub rti: Option<RtiReport>,
    /// Time the step took by the caller's clock, s (None without a clock).
    pub solve_time_s: Option<f64>,
    /// EE position error at the measured state, m.
    pub ee_error_m: f64,
    /// Predicted base position at the end of the horizon, m.
    pub predicted_terminal_position_m: Vector3<f64>,
    /// The EE target's velocity extrapolated over the horizon, world, m/s
    /// ([`MpcConfig::target_velocity_limit_mps`]; zero for a held target or a jump).
    pub target_velocity_mps: Vector3<f64>,
    /// The normal of the hand's blocking contact this tick was given
    /// ([`WholeBodyMpc::set_hand_contact`]; None: none).
    pub hand_contact: Option<Vector3<f64>>,
    /// What the RTI step was given (None when nothing was solved); not logged.
    #[serde(skip)]
    pub problem: Option<MpcProblem>,
}

/// What the controller commands.
#[derive(Debug, Clone, PartialEq)]
pub struct MpcCommand {
    /// Body wrench for the allocator (gravity included).
    pub wrench_in_body: Wrench,
    /// Arm joint position targets, command order, rad.
    pub arm_targets_rad: [f64; NQ],
    /// The base pose the flown path aims at (the MPC's terminal prediction, or the IK's base
    /// target), for logs.
    pub base_target: Isometry3<f64>,
    /// The tick's report.
    pub status: MpcStatus,
}

/// The FA-Hexa's whole-body MPC with its fallback (see the module documentation).
#[derive(Debug)]
pub struct WholeBodyMpc {
    rti: SqpRti,
    config: MpcConfig,
    arm_dofs: Vec<usize>,
    body: BodyParams,
    u_last: Option<InputVector>,
    envelope: Option<RotorEnvelope>,
    /// Ticks flown by the IK-PID path since it took over.
    ik_pid_ticks: u32,
    solved_once: bool,
    failed: u32,
    mode: MpcMode,
    status: MpcStatus,
    last_command: Option<MpcCommand>,
    /// The offset added to the EE position target (world, m): see
    /// [`MpcConfig::ee_offset_rate_per_s`].
    ee_offset: Vector3<f64>,
    /// The EE target position of the previous tick (None: first tick since a reset).
    previous_target_m: Option<Vector3<f64>>,
}

impl WholeBodyMpc {
    /// The controller of `vehicle` (FA-Hexa) with `config`.
    pub fn new(vehicle: &Vehicle, config: MpcConfig) -> Result<Self, MpcError> {
        let rti = SqpRti::new(vehicle, config)?;
        let body = BodyParams::from_vehicle(vehicle);
        Ok(Self {
            rti,
            config,
            arm_dofs: vehicle.arm_dofs(),
            body,
            u_last: None,
            envelope: RotorEnvelope::of(vehicle),
            ik_pid_ticks: 0,
            solved_once: false,
            failed: 0,
            mode: MpcMode::Mpc,
            status: MpcStatus {
                mode: MpcMode::Mpc,
                event: None,
                failure: None,
                failed_ticks: 0,
                rti: None,
                solve_time_s: None,
                ee_error_m: 0.0,
                predicted_terminal_position_m: Vector3::zeros(),
                target_velocity_mps: Vector3::zeros(),
                hand_contact: None,
                problem: None,
            },
            last_command: None,
            ee_offset: Vector3::zeros(),
            previous_target_m: None,
        })
    }

    /// The settings.
    pub fn config(&self) -> &MpcConfig {
        &self.config
    }

    /// The RTI solver (predictions, QP).
    pub fn rti(&self) -> &SqpRti {
        &self.rti
    }

    /// The RTI solver, mutable (QP settings, path).
    pub fn rti_mut(&mut self) -> &mut SqpRti {
        &mut self.rti
    }

    /// The report of the last tick.
    pub fn status(&self) -> &MpcStatus {
        &self.status
    }

    /// The joint of the object the hand holds (None: nothing held, or a free object), for
    /// the next ticks: the grasp model of [`crate::mpc::grasp`]. Given
    /// every tick by the flight stack from the scene, as the wall's face.
    pub fn set_held_joint(&mut self, joint: Option<platform::HeldJoint>) {
        self.rti
            .set_grasp(joint.filter(platform::HeldJoint::is_valid));
    }

    /// The normal (unit, world, out of what the hand touches) of the hand's contact with
    /// something that does not give way along it (None: no such contact), for the next
    /// ticks: the contact model of [`MpcConfig::contact_reference`]. Given every tick by the
    /// flight stack from the scene, as the held joint.
    pub fn set_hand_contact(&mut self, normal: Option<Vector3<f64>>) {
        self.rti.set_contact(normal);
    }

    /// Replaces the mass properties used for gravity compensation.
    pub fn set_body(&mut self, body: BodyParams) {
        self.rti
            .set_compensated_weight(body.mass_kg * GRAVITY_MPS2, body.com_in_body_m);
        self.body = body;
    }

    /// Clears the solver memory, the filter and the fallback for a new flight from `state`
    /// with the joints at `configuration` (full configuration vector). The last applied input
    /// is seeded with zero force and torque and the measured arm (the reference seeds zeros,
    /// which pulls the arm toward 0 through the rate term).
    pub fn reset(&mut self, state: &RigidBodyState, configuration: &[f64]) {
        self.rti.reset();
        self.u_last = None;
        self.solved_once = false;
        self.failed = 0;
        self.ik_pid_ticks = 0;
        self.mode = MpcMode::Mpc;
        self.last_command = None;
        self.ee_offset = Vector3::zeros();
        self.previous_target_m = None;
        let _ = (state, configuration);
        self.status.event = None;
        self.status.failure = None;
        self.status.failed_ticks = 0;
        self.status.mode = MpcMode::Mpc;
        self.status.rti = None;
    }

    /// The MPC state x̂ from a measurement.
    pub fn state_vector(&self, state: &RigidBodyState, configuration: &[f64]) -> StateVector {
        let mut x = StateVector::zeros();
        let (roll, pitch, yaw) = state.world_from_body.euler_angles();
        for i in 0..3 {
            x[IX_P + i] = state.position_in_world_m[i];
            x[IX_V + i] = state.velocity_in_world_mps[i];
            x[IX_OMEGA + i] = state.angular_velocity_in_body_radps[i];
        }
        x[IX_ETA] = roll;
        x[IX_ETA + 1] = pitch;
        x[IX_ETA + 2] = yaw;
        for (j, &d) in self.arm_dofs.iter().enumerate() {
            x[IX_Q + j] = configuration.get(d).copied().unwrap_or(f64::NAN);
        }
        x
    }

    /// One control tick of `dt` seconds toward `target_world_from_ee` (the `ee_link` pose),
    /// with the base within `limits`. `clock` (seconds, any epoch) times the solve against
    /// `solve_budget_s`; pass None for a run that must not depend on wall time.
    pub fn update(
        &mut self,
        state: &RigidBodyState,
        configuration: &[f64],
        target_world_from_ee: &Isometry3<f64>,
        limits: &BaseLimits,
        dt: f64,
        clock: Option<&dyn Fn() -> f64>,
    ) -> MpcCommand {
        let started = clock.map(|c| c());
        let previous_mode = self.mode;
        let x_hat = self.state_vector(state, configuration);
        let dt_ok = guard_dt(dt);
        let inputs_finite = x_hat.iter().all(|v| v.is_finite())
            && crate::desired::is_finite_pose(target_world_from_ee)
            && limits.is_finite()
            && dt_ok.is_some();
        let dt = dt_ok.map_or(crate::controller::DT_MIN_S, |(dt, _)| dt);
        let mut failure = None;
        let mut report = None;
        let mut problem = None;
        let target_velocity_mps = if inputs_finite {
            self.target_velocity(&target_world_from_ee.translation.vector, dt)
        } else {
            Vector3::zeros()
        };
        if inputs_finite {
            let reference = MpcReference {
                ee_position_m: target_world_from_ee.translation.vector + self.ee_offset,
                ee_velocity_mps: target_velocity_mps,
                ee_rotation: target_world_from_ee.rotation,
                ee_offset_m: self.ee_offset,
                input_previous: self.u_last.unwrap_or_else(|| self.seed_input(&x_hat)),
            };
            let elapsed = if self.solved_once { dt } else { 0.0 };
            problem = Some(MpcProblem {
                x_hat,
                reference,
                limits: *limits,
                elapsed_s: elapsed,
                warm: self.rti.is_warm(),
                grasp: self.rti.grasp().copied(),
                contact: self.rti.contact(),
                compensated_weight: (self.body.mass_kg * GRAVITY_MPS2, self.body.com_in_body_m),
            });
            let r = self
                .rti
                .step(&x_hat, &reference, limits, elapsed, self.config.qp_path);
            self.solved_once = true;
            if r.status != QpStatus::Solved {
                failure = Some(SolveFailure::QpNotSolved);
            }
            report = Some(r);
        } else {
            failure = Some(SolveFailure::NonFiniteInput);
        }
        let solve_time_s = match (clock, started) {
            (Some(c), Some(t0)) => Some(c() - t0),
            _ => None,
        };
        if failure.is_none()
            && let (Some(budget), Some(t)) = (self.config.solve_budget_s, solve_time_s)
            && t > budget
        {
            failure = Some(SolveFailure::OverBudget);
        }
        // A solution the rotors cannot deliver is not flown; after such a takeover the IK-PID
        // path flies at least `fallback_hold_ticks` ticks (no chattering between the two).
        if failure.is_none() && self.config.rotor_saturation_fallback && self.would_saturate(state)
        {
            failure = Some(SolveFailure::RotorSaturation);
        }
        let settling =
            previous_mode == MpcMode::IkPid && self.ik_pid_ticks < self.config.fallback_hold_ticks;
        self.failed = if failure.is_some() {
            self.failed.saturating_add(1)
        } else {
            0
        };
        self.mode = match failure {
            None if settling => MpcMode::IkPid,
            None => MpcMode::Mpc,
            Some(SolveFailure::RotorSaturation) => MpcMode::IkPid,
            // Once the IK-PID path flies, a failed solve keeps it flying.
            Some(_) if previous_mode == MpcMode::IkPid => MpcMode::IkPid,
            Some(_) if self.failed <= self.config.fallback_hold_ticks => MpcMode::Hold,
            Some(_) => MpcMode::IkPid,
        };
        self.ik_pid_ticks = if self.mode == MpcMode::IkPid {
            if previous_mode == MpcMode::IkPid {
                self.ik_pid_ticks.saturating_add(1)
            } else {
                0
            }
        } else {
            0
        };
        if self.mode == MpcMode::Mpc {
            self.integrate_ee_offset(&target_world_from_ee.translation.vector, &x_hat, dt);
        }
        // A non-finite state cannot be flown by either path: hold the last command.
        if failure == Some(SolveFailure::NonFiniteInput)
            && let Some(last) = &self.last_command
        {
            let mut command = last.clone();
            self.status = MpcStatus {
                mode: self.mode,
                event: event(previous_mode, self.mode),
                failure,
                failed_ticks: self.failed,
                rti: None,
                solve_time_s,
                problem: None,
                ..command.status
            };
            command.status = self.status;
            return command;
        }
        // In IkPid mode the caller flies its own IK-PID path and reports it
        // ([`Self::fallback_flown`]); the held solution is returned for reference.
        let mut command = self.mpc_command(state);
        let ee_error_m = if x_hat.iter().all(|v| v.is_finite()) {
            (self.rti.ee_kinematics(&x_hat).position - target_world_from_ee.translation.vector)
                .norm()
        } else {
            f64::NAN
        };
        let terminal = self.rti.states().last().copied().unwrap_or(x_hat);
        self.status = MpcStatus {
            mode: self.mode,
            event: event(previous_mode, self.mode),
            failure,
            failed_ticks: self.failed,
            rti: report,
            solve_time_s,
            ee_error_m,
            predicted_terminal_position_m: Vector3::new(
                terminal[IX_P],
                terminal[IX_P + 1],
                terminal[IX_P + 2],
            ),
            target_velocity_mps,
            hand_contact: self.rti.contact(),
            problem,
        };
        command.status = self.status;
        self.last_command = Some(command.clone());
        command
    }

    /// Ticks the IK-PID path has flown since it took over: 0 on the takeover tick, and
    /// while the MPC (or its held solution) flies.
    pub fn fallback_ticks(&self) -> u32 {
        self.ik_pid_ticks
    }

    /// The input the MPC path applied last (world force without gravity, world torque, arm
    /// references; None before the first tick).
    pub fn last_input(&self) -> Option<InputVector> {
        self.u_last
    }

    /// The offset added to the EE position target, world, m (zero without
    /// [`MpcConfig::ee_offset_rate_per_s`]).
    pub fn ee_offset(&self) -> Vector3<f64> {
        self.ee_offset
    }

    /// The EE target's velocity from this tick's target and the previous one (see
    /// [`MpcConfig::target_velocity_limit_mps`]; zero while the hand holds an object on a
    /// joint); remembers `target_m` for the next tick.
    fn target_velocity(&mut self, target_m: &Vector3<f64>, dt: f64) -> Vector3<f64> {
        let previous = self.previous_target_m.replace(*target_m);
        let (Some(limit), Some(previous)) = (self.config.target_velocity_limit_mps, previous)
        else {
            return Vector3::zeros();
        };
        if self.rti.grasp().is_some() {
            return Vector3::zeros();
        }
        let velocity = (target_m - previous) / dt;
        if velocity.iter().all(|v| v.is_finite()) && velocity.norm() <= limit {
            velocity
        } else {
            Vector3::zeros()
        }
    }

    /// One step of the offset-free EE reference after a solve the MPC flies:
    /// `b ← b + rate·dt·e`, with `e` the error the solution predicts at the end of its
    /// horizon, `p_ref(t_N) − p_ee(x_N)` (the target there, extrapolated along its
    /// velocity), or, once the measured EE lies within `ee_offset_gap_m` of that prediction,
    /// the measured error `p_target − p_ee(x̂)` (at `ee_offset_measured_rate_per_s`); taken
    /// only while `e` is within `ee_offset_limit_m` (a larger one is a move still under way,
    /// not a steady-state offset), and `‖b‖` clipped to the same bound. The offset is part of
    /// the reference, so the errors are taken against the target without it.
    fn integrate_ee_offset(&mut self, target_m: &Vector3<f64>, x_hat: &StateVector, dt: f64) {
        let Some(rate) = self.config.ee_offset_rate_per_s else {
            return;
        };
        let (Some(terminal), Some(reference_end)) = (
            self.rti.states().last().copied(),
            self.rti.terminal_target(),
        ) else {
            return;
        };
        let predicted = self.rti.ee_kinematics(&terminal).position;
        let settled = self.config.ee_offset_gap_m.and_then(|gap| {
            let measured = self.rti.ee_kinematics(x_hat).position;
            ((measured - predicted).norm() <= gap).then_some(measured)
        });
        let (at, error, rate) = match settled {
            Some(measured) => (
                measured,
                target_m - measured,
                self.config.ee_offset_measured_rate_per_s,
            ),
            None => (predicted, reference_end - self.ee_offset - predicted, rate),
        };
        // Holding an object on a joint, only what the joint lets the hand move is an offset
        // the MPC can remove.
        let error = self.rti.allowed_ee_error(&at, &error);
        let limit = self.config.ee_offset_limit_m;
        if !(error.iter().all(|v| v.is_finite()) && error.norm() <= limit) {
            return;
        }
        let offset = self.ee_offset + error * (rate * dt).min(1.0);
        let norm = offset.norm();
        self.ee_offset = if norm > limit {
            offset * (limit / norm)
        } else {
            offset
        };
    }

    /// The last applied input before any: no force or torque, the arm where it is.
    fn seed_input(&self, x_hat: &StateVector) -> InputVector {
        let mut u = InputVector::zeros();
        let (lower, upper) = self.rti.joint_bounds();
        for j in 0..NQ {
            u[IU_QREF + j] = x_hat[IX_Q + j].clamp(lower[j], upper[j]);
        }
        u
    }

    /// The input the MPC path would apply this tick: the iterate's first input through the
    /// output filter.
    fn filtered_input(&self) -> InputVector {
        let u_opt = self.rti.inputs()[0];
        let g = &self.config.output_filter_gain;
        match self.u_last {
            None => u_opt,
            Some(last) => InputVector::from_fn(|i, _| g[i] * u_opt[i] + (1.0 - g[i]) * last[i]),
        }
    }

    /// Whether the filtered input would take a rotor beyond its limits (by more than
    /// `ROTOR_LIMIT_TOLERANCE_N`): the body wrench it commands (gravity compensation
    /// included, at the measured attitude and posture) through the pseudo-inverse allocation.
    fn would_saturate(&self, state: &RigidBodyState) -> bool {
        let Some(envelope) = &self.envelope else {
            return false;
        };
        let w = self.body_wrench(&self.filtered_input(), state);
        envelope.allocation_rows.iter().any(|row| {
            let thrust = (0..3)
                .map(|i| row[i] * w.force[i] + row[3 + i] * w.torque[i])
                .sum::<f64>();
            thrust < envelope.thrust_min_n - ROTOR_LIMIT_TOLERANCE_N
                || thrust > envelope.thrust_max_n + ROTOR_LIMIT_TOLERANCE_N
        })
    }

    /// The body wrench of input `u`: gravity compensation added, `F_b = Rᵀ(F_w + m g ẑ)`,
    /// `τ_b = Rᵀτ_w + c × Rᵀ(m g ẑ)`.
    fn body_wrench(&self, u: &InputVector, state: &RigidBodyState) -> Wrench {
        let weight = self.body.mass_kg * GRAVITY_MPS2;
        let force_w = Vector3::new(u[IU_F], u[IU_F + 1], u[IU_F + 2] + weight);
        let torque_w = Vector3::new(u[IU_TAU], u[IU_TAU + 1], u[IU_TAU + 2]);
        let body_from_world = state.world_from_body.inverse();
        Wrench::new(
            body_from_world * force_w,
            body_from_world * torque_w
                + self
                    .body
                    .gravity_moment_compensation(&state.world_from_body),
        )
    }

    /// Filter, gravity compensation and frame change of the RTI iterate's first input.
    fn mpc_command(&mut self, state: &RigidBodyState) -> MpcCommand {
        let u = self.filtered_input();
        self.u_last = Some(u);
        let wrench = self.body_wrench(&u, state);
        let (lower, upper) = self.rti.joint_bounds();
        let mut arm = [0.0; NQ];
        for j in 0..NQ {
            arm[j] = u[IU_QREF + j].clamp(lower[j], upper[j]);
        }
        let terminal = self.rti.states().last().copied().unwrap_or_default();
        let base_target = Isometry3::from_parts(
            Vector3::new(terminal[IX_P], terminal[IX_P + 1], terminal[IX_P + 2]).into(),
            UnitQuaternion::from_euler_angles(
                terminal[IX_ETA],
                terminal[IX_ETA + 1],
                terminal[IX_ETA + 2],
            ),
        );
        MpcCommand {
            wrench_in_body: wrench,
            arm_targets_rad: arm,
            base_target,
            status: self.status,
        }
    }

    /// What the caller's IK-PID path flew on an [`MpcMode::IkPid`] tick: its body wrench, arm
    /// targets and base target. The filter's memory continues from it, and it is the command
    /// held if the next state is not finite.
    pub fn fallback_flown(
        &mut self,
        state: &RigidBodyState,
        wrench_in_body: &Wrench,
        arm_targets_rad: &[f64],
        base_target: &Isometry3<f64>,
    ) {
        let mut arm = [0.0; NQ];
        for (a, q) in arm.iter_mut().zip(arm_targets_rad) {
            *a = *q;
        }
        let force_w = state.world_from_body * wrench_in_body.force;
        let torque_w = state.world_from_body * wrench_in_body.torque;
        let weight = self.body.mass_kg * GRAVITY_MPS2;
        let mut u = InputVector::zeros();
        for i in 0..3 {
            u[IU_F + i] = force_w[i];
            u[IU_TAU + i] = torque_w[i];
        }
        u[IU_F + 2] -= weight;
        for j in 0..NQ {
            u[IU_QREF + j] = arm[j];
        }
        self.u_last = Some(u);
        self.last_command = Some(MpcCommand {
            wrench_in_body: *wrench_in_body,
            arm_targets_rad: arm,
            base_target: *base_target,
            status: self.status,
        });
    }
}

fn event(previous: MpcMode, now: MpcMode) -> Option<FallbackEvent> {
    match (previous, now) {
        (a, b) if a == b => None,
        (_, MpcMode::Hold) => Some(FallbackEvent::HoldStarted),
        (_, MpcMode::IkPid) => Some(FallbackEvent::IkPidTookOver),
        (_, MpcMode::Mpc) => Some(FallbackEvent::MpcRecovered),
    }
}
