//! The optimal control problem of the paper and its SQP real-time iteration.
//!
//! # OCP (AMBENCH_SPEC §2.5)
//!
//! ```text
//! min  Σ_{k<N} h·½‖y(x_k, u_k) − y_ref‖²_W + ½‖y_e(x_N) − y_ref,e‖²_{W_e}
//! s.t. x_0 = x̂,  x_{k+1} = RK4(x_k, u_k; h),  h = T/N = 0.025 s
//!      p_min ≤ p_k ≤ p_max (x upper bound lowered by a wall),  |roll|,|pitch| ≤ 0.01,
//!      |yaw| ≤ π,  q_min ≤ q_k ≤ q_max,  q_min ≤ q_ref,k ≤ q_max   (k = 1..N for states)
//!      0.1 ≤ (p_ee − p)_z ≤ 2.5                                   (path constraint, k = 1..N)
//! y = [p_ee − p_ref, rpy_ee − rpy_ref, v, η − (0, 0, yaw_ref), ω, q − q_0,
//!      u − (0, 0, q_0), u − u_prev],   y_e = the first 19 entries
//! ```
//!
//! W = blkdiag(Q, R, R_Δ) with the reference's weights ([`MpcWeights`]). Stage costs are
//! scaled by h and the terminal cost by 1 (acados' default `cost_scaling`; the reference's
//! acados version is not pinned [U]). Angle residuals (EE roll–pitch–yaw, base yaw) are wrapped
//! to (−π, π]. q_min/q_max are the URDF limits intersected with ±`joint_limit_rad`.
//!
//! Conscious differences from the reference:
//! - `u_prev` is the last applied input *without* gravity, like u (the reference stores the
//!   force with gravity added, so its rate term pulls every predicted force toward +m·g).
//! - A bound that the measured state already violates is not imposed at once: at stage k it
//!   is widened to `b + (v̂ − b)·exp(−t_k/τ)` (τ = `recovery_time_constant_s`, or 2/k_a for the
//!   joints and the EE height, which only the arm servo can move), so a state already out of
//!   bounds does not make the QP infeasible at once. Within its bounds the measured state
//!   sees the reference's constraints unchanged. (A state inside the tilt band but rotating
//!   out of it fast can still make the QP infeasible; the controller's fallback handles it.)
//! - The force is bounded: six rows per stage keep the thrust the force alone allocates to
//!   each rotor within `rotor_margin_for_force` of its margin around hover
//!   ([`crate::mpc::model::RotorEnvelope`]), with the measured heading over the horizon (roll
//!   and pitch, within ±0.01 rad, neglected). The reference's force is unbounded.
//! - Optionally (`rotor_margin_for_wrench`, off by default) the whole wrench as well: six
//!   more rows per stage keep the thrust the force, the torque and the gravity compensation
//!   allocate to each rotor (pseudo-inverse, measured attitude and posture) within that share
//!   of its margin, so the MPC plans only wrenches the rotors can deliver. The reference's
//!   torque is unbounded.
//! - Joint and arm-reference bounds are the URDF limits within ±π (the reference: ±π).
//! - The joint bounds of the states are not rows of the QP when the arm-reference bounds
//!   imply them ([`arm_state_rows_implied`]): the servo model's step is
//!   `q_{k+1} = φ q_k + (1 − φ) q_ref,k` with `0 ≤ φ ≤ e^{−h/τ}` (τ the joints' recovery time
//!   constant), so a joint whose reference keeps within the bounds keeps within them, and
//!   within the widened bounds of a measured joint past its limit. The feasible set is the
//!   same; the QP has 8 fewer rows per stage (256 of 1344), and none of the linearly
//!   dependent ones that a joint held on its limit makes active at every stage (its state
//!   row at k + 1 and its reference row at k, with the state row at k), whose multipliers are
//!   not unique.
//! - A grasp model ([`crate::mpc::grasp`], not in the reference): while the hand holds an
//!   object on a joint ([`SqpRti::set_grasp`]), the EE position target is moved onto the
//!   joint's motion through the measured EE, and optionally two EE rows per state stage
//!   keep the predictions on it.
//!
//! # SQP-RTI
//!
//! One Gauss–Newton SQP iteration per control tick. Preparation: the previous solution is
//! shifted by the time elapsed since it was computed (inputs interpolated over the shooting
//! grid, the last one held) and the states are rolled out from x̂ with the integrator, so the
//! linearisation point is dynamically consistent; residuals and their Jacobians are evaluated
//! at every knot and the QP in the deltas is assembled (`H = h·JᵀWJ`, `g = h·JᵀW(y − y_ref)`;
//! A, B are the integrator's exact sensitivities). Feedback: the QP is solved by the chosen
//! path and the full step is taken. A solve that fails leaves the shifted solution in place.
//! The Riccati path's interior point starts from the last solved QP's multipliers, shifted
//! the same way, and from the point the last factorisation's feedback gives for x̂'s offset
//! from the last solution's state at the shifted time ([`RiccatiIpm::warm_start_from_plan`]:
//! the open-loop rollout alone carries a model mismatch in contact, growing, to the horizon's
//! end); after a failed or infeasible solve, or [`SqpRti::reset`], it starts cold
//! ([`SqpRti::set_qp_warm_start`] turns this off).

use nalgebra::{Rotation3, SMatrix, UnitQuaternion, Vector3};
use platform::Vehicle;
use serde::Serialize;

use crate::ik::BaseLimits;
use crate::mpc::clarabel_qp::ClarabelQp;
use crate::mpc::config::{MpcConfig, MpcConfigError, QpPath};
use crate::mpc::grasp::{AnchoredGrasp, GRASP_ROWS, anchored};
use crate::mpc::model::{IU_QREF, IX_ETA, IX_OMEGA, IX_P, IX_Q, IX_V, ModelError, MpcModel, NQ};
use crate::mpc::qp::{
    InputMatrix, InputStateMatrix, InputVector, NU, NX, QpSolution, QpSolver, QpStatus,
    StateInputMatrix, StateMatrix, StateVector, StructuredQp,
};
use crate::mpc::riccati::{
    InfeasibilityExit, RiccatiIpm, RowScreening, ScreeningReport, ShotOutcome, SparseColumns,
};
use platform::HeldJoint;

/// Bounded state entries: position, Euler angles, arm joints.
const STATE_BOUND_INDICES: [usize; 10] = [
    IX_P,
    IX_P + 1,
    IX_P + 2,
    IX_ETA,
    IX_ETA + 1,
    IX_ETA + 2,
    IX_Q,
    IX_Q + 1,
    IX_Q + 2,
    IX_Q + 3,
];
/// State bounds that are rows of the QP when the arm's joint bounds are implied by its
/// reference bounds (position and Euler angles): the first six of [`STATE_BOUND_INDICES`].
const STATE_BOUND_ROWS_WITHOUT_ARM: usize = 6;
/// Bounded input entries: the arm references (force and torque: the rotor envelope rows).
const INPUT_BOUND_INDICES: [usize; NQ] = [IU_QREF, IU_QREF + 1, IU_QREF + 2, IU_QREF + 3];

/// Why the MPC cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpcError {
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] MpcConfigError),
    /// The vehicle does not fit the OCP.
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// What the MPC tracks at one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcReference {
    /// Target `ee_link` position in the world, m, now.
    pub ee_position_m: Vector3<f64>,
    /// The target position's velocity, world, m/s: the reference at stage k is
    /// `ee_position_m + ee_velocity_mps · min(t_k, target_extrapolation_s)` (zero: the target
    /// held over the horizon, as in the reference). A straight line: `WholeBodyMpc` gives
    /// none while a joint is held, whose motion it would leave.
    pub ee_velocity_mps: Vector3<f64>,
    /// Target `ee_link` orientation in the world.
    pub ee_rotation: UnitQuaternion<f64>,
    /// The offset-free EE reference's offset already added to `ee_position_m`, m
    /// (`WholeBodyMpc`'s `ee_offset`). While a joint is held, the target without it is moved
    /// onto the joint's motion and the offset added back, so the plan's steady state stays
    /// where the hand is along the directions the joint blocks.
    pub ee_offset_m: Vector3<f64>,
    /// The last applied input (world force without gravity, world torque, arm references).
    pub input_previous: InputVector,
}

/// What one RTI step did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RtiReport {
    /// QP outcome (not `solved`: the shifted previous solution was kept; `infeasible`: the
    /// soft state rows needed a slack beyond `state_row_slack_limit`).
    pub status: QpStatus,
    /// QP interior-point iterations.
    pub qp_iterations: u32,
    /// NLS cost of the solution (or of the kept one).
    pub cost: f64,
    /// Largest violation of the OCP's inequalities (path constraint evaluated on the
    /// nonlinear kinematics) at the solution's knots, m or rad.
    pub max_constraint_violation: f64,
}

/// `v` at the fractional index `t ≥ 0`: linear between neighbouring entries, the last entry
/// held beyond the end (the shift of a solution by the time elapsed). A non-finite `t` gives
/// the last entry.
fn at_fractional_index<T>(v: &[T], t: f64) -> T
where
    T: Copy
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<f64, Output = T>,
{
    let last = v.len() - 1;
    let floor = t.floor().clamp(0.0, last as f64);
    let f = if t.is_finite() { t - t.floor() } else { 0.0 };
    // The cast is exact: floor is an integer in 0..=last.
    let i = floor as usize;
    let (a, b) = (v[i], v[(i + 1).min(last)]);
    a + (b - a) * f
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let w = a - two_pi * (a / two_pi).round();
    if w <= -std::f64::consts::PI {
        w + two_pi
    } else {
        w
    }
}

/// Effective absolute bounds of one stage.
#[derive(Debug, Clone, Copy, PartialEq)]
struct StageBounds {
    state_lower: [f64; 10],
    state_upper: [f64; 10],
    height_lower: f64,
    height_upper: f64,
}

/// The OCP and its SQP-RTI solver.
#[derive(Debug)]
pub struct SqpRti {
    config: MpcConfig,
    model: MpcModel,
    h: f64,
    /// A and B (the model's step, the same every stage) by their non-zeros: the rollouts'
    /// products.
    a_sparse: SparseColumns,
    b_sparse: SparseColumns,
    joint_lower: [f64; NQ],
    joint_upper: [f64; NQ],
    /// The rotors' thrust envelope bounding force and torque (None: unbounded).
    envelope: Option<crate::mpc::model::RotorEnvelope>,
    /// This tick's rotor rows (`lower ≤ eᵀu ≤ upper`, the same at every stage), from
    /// [`rotor_rows`] once per linearisation.
    rotor_rows: Vec<(InputVector, f64, f64)>,
    /// Diagonal state weights of the linear residuals (v, η, ω, q), stage and terminal alike.
    state_weights: StateVector,
    input_weights: InputVector,
    rate_weights: InputVector,
    ee_weights: SMatrix<f64, 6, 1>,
    xs: Vec<StateVector>,
    us: Vec<InputVector>,
    /// The last inputs while they are shifted into `us` (kept: no allocation per tick).
    us_last: Vec<InputVector>,
    bounds: Vec<StageBounds>,
    reference: Option<MpcReference>,
    qp: StructuredQp,
    solution: QpSolution,
    riccati: RiccatiIpm,
    clarabel: ClarabelQp,
    warm: bool,
    /// Whether the Riccati path starts from the last solve's multipliers.
    qp_warm_start: bool,
    /// The joint of the object the hand holds (None: nothing held).
    grasp: Option<HeldJoint>,
    /// That joint anchored at the measured EE of the last preparation (None: no grasp rows).
    anchored_grasp: Option<AnchoredGrasp>,
    /// The normal of the hand's blocking contact (unit, world, pointing out of what the hand
    /// touches; None: no such contact).
    contact: Option<Vector3<f64>>,
    /// That normal and the measured EE of the last preparation, with `contact_reference`.
    anchored_contact: Option<(Vector3<f64>, Vector3<f64>)>,
}

impl SqpRti {
    /// The OCP of `vehicle` with `config`.
    pub fn new(vehicle: &Vehicle, config: MpcConfig) -> Result<Self, MpcError> {
        config.validate()?;
        let model = MpcModel::new(vehicle, config.arm_gain_per_s)?;
        let h = config.interval_s();
        let (_, a, b) = model.rk4(&StateVector::zeros(), &InputVector::zeros(), h);
        let arm_tau = Self::arm_recovery_time_constant(&config);
        let state_rows = if arm_state_rows_implied(&a, &b, h, arm_tau) {
            STATE_BOUND_ROWS_WITHOUT_ARM
        } else {
            STATE_BOUND_INDICES.len()
        };
        let mut joint_lower = [0.0; NQ];
        let mut joint_upper = [0.0; NQ];
        for j in 0..NQ {
            joint_lower[j] = model.arm_lower_rad[j].max(-config.joint_limit_rad);
            joint_upper[j] = model.arm_upper_rad[j].min(config.joint_limit_rad);
        }
        let envelope = config
            .rotor_margin_for_force
            .or(config.rotor_margin_for_wrench)
            .and_then(|_| crate::mpc::model::RotorEnvelope::of(vehicle));
        let rotor_rows = envelope.as_ref().map_or(0, |e| {
            e.allocation_rows.len()
                * (usize::from(config.rotor_margin_for_force.is_some())
                    + usize::from(config.rotor_margin_for_wrench.is_some()))
        });
        let w = &config.weights;
        let mut state_weights = StateVector::zeros();
        for i in 0..3 {
            state_weights[IX_V + i] = w.velocity[i];
            state_weights[IX_ETA + i] = w.attitude[i];
            state_weights[IX_OMEGA + i] = w.angular_velocity[i];
        }
        for j in 0..NQ {
            state_weights[IX_Q + j] = w.arm[j];
        }
        let ee_weights = SMatrix::<f64, 6, 1>::from_column_slice(&[
            w.ee_position[0],
            w.ee_position[1],
            w.ee_position[2],
            w.ee_orientation[0],
            w.ee_orientation[1],
            w.ee_orientation[2],
        ]);
        let n = config.intervals;
        let mut qp = StructuredQp::zeros(n);
        qp.a = a;
        qp.b = b;
        qp.soft_penalty = config.state_row_penalty;
        for (k, c) in qp.constraints.iter_mut().enumerate() {
            if k > 0 {
                c.state_indices = STATE_BOUND_INDICES[..state_rows].to_vec();
                c.state_lower = vec![0.0; state_rows];
                c.state_upper = vec![0.0; state_rows];
                c.general = vec![StateVector::zeros()];
                c.general_lower = vec![0.0];
                c.general_upper = vec![0.0];
            }
            if k < n {
                c.input_indices = INPUT_BOUND_INDICES.to_vec();
                c.input_lower = vec![0.0; NQ];
                c.input_upper = vec![0.0; NQ];
                c.input_general = vec![InputVector::zeros(); rotor_rows];
                c.input_general_lower = vec![0.0; rotor_rows];
                c.input_general_upper = vec![0.0; rotor_rows];
            }
        }
        let empty = StageBounds {
            state_lower: [0.0; 10],
            state_upper: [0.0; 10],
            height_lower: 0.0,
            height_upper: 0.0,
        };
        Ok(Self {
            model,
            h,
            a_sparse: SparseColumns::of(&a),
            b_sparse: SparseColumns::of(&b),
            joint_lower,
            joint_upper,
            envelope,
            state_weights,
            input_weights: InputVector::from_column_slice(&w.input),
            rate_weights: InputVector::from_column_slice(&w.input_rate),
            ee_weights,
            xs: vec![StateVector::zeros(); n + 1],
            us: vec![InputVector::zeros(); n],
            us_last: Vec::with_capacity(n),
            bounds: vec![empty; n + 1],
            reference: None,
            qp,
            solution: QpSolution::zeros(n),
            riccati: {
                let mut riccati = RiccatiIpm::new(config.qp);
                riccati.set_infeasibility_exit(Self::default_exit(&config));
                riccati.set_row_screening(Some(RowScreening::default()));
                riccati
            },
            clarabel: ClarabelQp::new(config.qp),
            warm: false,
            qp_warm_start: true,
            rotor_rows: Vec::with_capacity(rotor_rows),
            grasp: None,
            anchored_grasp: None,
            contact: None,
            anchored_contact: None,
            config,
        })
    }

    /// The settings.
    pub fn config(&self) -> &MpcConfig {
        &self.config
    }

    /// The prediction model.
    pub fn model(&self) -> &MpcModel {
        &self.model
    }

    /// Changes the QP settings of both paths.
    pub fn set_qp_settings(&mut self, settings: crate::mpc::config::QpSettings) {
        self.config.qp = settings;
        self.riccati.set_settings(settings);
        self.clarabel.set_settings(settings);
    }

    /// The rotors' thrust envelope that bounds force and torque (None: unbounded).
    pub fn rotor_envelope(&self) -> Option<&crate::mpc::model::RotorEnvelope> {
        self.envelope.as_ref()
    }

    /// The weight (N) and centre of mass (base frame, m) whose compensation the wrench rows
    /// add to the MPC's wrench: the controller's, which follows the arm's posture.
    pub fn set_compensated_weight(&mut self, weight_n: f64, com_in_body_m: Vector3<f64>) {
        if let Some(e) = &mut self.envelope {
            e.weight_n = weight_n;
            e.com_in_body_m = com_in_body_m;
        }
    }

    /// Arm joint bounds used (URDF ∩ ±joint_limit_rad), rad.
    pub fn joint_bounds(&self) -> ([f64; NQ], [f64; NQ]) {
        (self.joint_lower, self.joint_upper)
    }

    /// Whether the Riccati path's interior point starts from the previous solve's
    /// multipliers, shifted ([`RiccatiIpm::warm_start_next`]; default true), instead of its
    /// cold start.
    pub fn set_qp_warm_start(&mut self, on: bool) {
        self.qp_warm_start = on;
        if !on {
            self.riccati.forget();
        }
    }

    /// The Riccati path's early infeasibility exit for `config`: on with soft state rows and
    /// a slack limit.
    fn default_exit(config: &MpcConfig) -> Option<InfeasibilityExit> {
        config
            .state_row_penalty
            .and(config.state_row_slack_limit)
            .map(InfeasibilityExit::new)
    }

    /// Sets the Riccati path's early infeasibility exit (default: on with soft state rows and
    /// a slack limit, [`InfeasibilityExit::new`]; None: every QP runs to convergence). It
    /// stops a solve whose soft rows have proven the hard QP infeasible, status `infeasible`,
    /// as the converged solve and the slack limit would classify it.
    pub fn set_qp_infeasibility_exit(&mut self, exit: Option<InfeasibilityExit>) {
        self.riccati.set_infeasibility_exit(exit);
    }

    /// The default exit of this OCP's config (None without soft rows and a slack limit).
    pub fn default_qp_infeasibility_exit(&self) -> Option<InfeasibilityExit> {
        Self::default_exit(&self.config)
    }

    /// Sets the Riccati path's row screening (default: on, [`RowScreening::default`]; None:
    /// every row is walked at every iteration). Exact: a solve whose reduced solution
    /// violates a screened row is redone with every row; after such a QP, when its solution
    /// is taken, the screening pauses ([`RowScreening::pause_after_resolve`]).
    pub fn set_qp_row_screening(&mut self, screening: Option<RowScreening>) {
        self.riccati.set_row_screening(screening);
    }

    /// What the Riccati path's row screening did in the last solve.
    pub fn qp_screening_report(&self) -> ScreeningReport {
        self.riccati.screening_report()
    }

    /// What the Riccati path's active-set shot did in the last solve
    /// ([`crate::mpc::QpSettings::active_set_shot`]).
    pub fn qp_shot_outcome(&self) -> ShotOutcome {
        self.riccati.shot_outcome()
    }

    /// The joint of the object the hand holds from the next preparation on (None: nothing
    /// held): the grasp model of [`crate::mpc::grasp`] (the EE target on the joint's motion
    /// with `grasp_reference`, the grasp rows with `grasp_band_m`).
    pub fn set_grasp(&mut self, joint: Option<HeldJoint>) {
        self.grasp = joint;
    }

    /// The held joint (None: nothing held).
    pub fn grasp(&self) -> Option<&HeldJoint> {
        self.grasp.as_ref()
    }

    /// The hand's blocking contact from the next preparation on: the unit normal (world)
    /// pointing out of what it touches, which the hand cannot move against (None: none;
    /// a zero or non-finite normal counts as none). With `MpcConfig::contact_reference`
    /// the EE target handed to the QP stays on the hand's side of the contact plane
    /// through the measured EE.
    pub fn set_contact(&mut self, normal: Option<Vector3<f64>>) {
        self.contact = normal
            .filter(|n| n.iter().all(|v| v.is_finite()))
            .and_then(|n| n.try_normalize(1e-9));
    }

    /// The hand's blocking contact's normal (None: none).
    pub fn contact(&self) -> Option<Vector3<f64>> {
        self.contact
    }

    /// The part of an EE position error (at the EE position `at`) the held joint and the
    /// hand's contact let the hand move (the error itself when nothing is held or touched,
    /// or the models are off).
    pub fn allowed_ee_error(&self, at: &Vector3<f64>, error: &Vector3<f64>) -> Vector3<f64> {
        let error = match &self.anchored_grasp {
            Some(g) => g.allowed_part(at, error),
            None => *error,
        };
        match &self.anchored_contact {
            Some((normal, _)) => beyond_contact_dropped(normal, &error),
            None => error,
        }
    }

    /// Forgets the previous solution: the next step starts cold.
    pub fn reset(&mut self) {
        self.warm = false;
        self.riccati.forget();
    }

    /// Whether the next step starts from the previous solution.
    pub fn is_warm(&self) -> bool {
        self.warm
    }

    /// Predicted states x_0..x_N of the current iterate.
    pub fn states(&self) -> &[StateVector] {
        &self.xs
    }

    /// Inputs u_0..u_{N−1} of the current iterate.
    pub fn inputs(&self) -> &[InputVector] {
        &self.us
    }

    /// The QP of the last preparation.
    pub fn qp(&self) -> &StructuredQp {
        &self.qp
    }

    /// The end effector at state `x`.
    pub fn ee_kinematics(&mut self, x: &StateVector) -> crate::mpc::model::EeKinematics {
        self.model.ee(x)
    }

    /// Shifts the previous solution by `elapsed_s` (or starts cold), rolls the states out from
    /// `x_hat`, and assembles the QP for `reference` with the base within `limits`.
    pub fn prepare(
        &mut self,
        x_hat: &StateVector,
        reference: &MpcReference,
        limits: &BaseLimits,
        elapsed_s: f64,
    ) {
        prepare_vectorised(self, x_hat, reference, limits, elapsed_s);
    }

    #[inline(always)]
    fn prepare_impl(
        &mut self,
        x_hat: &StateVector,
        reference: &MpcReference,
        limits: &BaseLimits,
        elapsed_s: f64,
    ) {
        let n = self.config.intervals;
        if self.warm {
            let shift = (elapsed_s / self.h).max(0.0);
            if self.qp_warm_start && self.config.qp.plan_start {
                // The last solution's state at the shifted time (xs holds it: a failed solve
                // made the solver forget, and then no warm start is taken).
                let mut offset = x_hat - at_fractional_index(&self.xs, shift);
                for i in 0..3 {
                    // Roll, pitch, yaw: the offset across ±π is the short way round.
                    offset[IX_ETA + i] = wrap_angle(offset[IX_ETA + i]);
                }
                self.riccati.warm_start_from_plan(shift, offset);
            } else if self.qp_warm_start {
                self.riccati.warm_start_next(shift);
            }
            self.us_last.clone_from(&self.us);
            for k in 0..n {
                self.us[k] = at_fractional_index(&self.us_last, k as f64 + shift);
            }
        } else {
            for u in &mut self.us {
                *u = InputVector::zeros();
                for j in 0..NQ {
                    u[IU_QREF + j] =
                        x_hat[IX_Q + j].clamp(self.joint_lower[j], self.joint_upper[j]);
                }
            }
        }
        self.xs[0] = *x_hat;
        for k in 0..n {
            self.xs[k + 1] = self.a_sparse.times(&self.xs[k]) + self.b_sparse.times(&self.us[k]);
        }
        // The measured EE, while something is held (the grasp's anchor and turn).
        let held_ee = self
            .grasp
            .filter(|_| self.config.grasp_band_m.is_some() || self.config.grasp_reference)
            .map(|joint| (joint, self.model.ee(x_hat)));
        self.anchored_grasp = held_ee
            .as_ref()
            .and_then(|(joint, ee)| anchored(joint, ee.position));
        // Holding: the EE target moved onto the joint's motion through the measured EE (what
        // the hand can reach without leaving it), the offset added back: it makes up for the
        // arm regularisation's steady-state shortfall, which does not vanish along the
        // blocked directions. (Projected with it, its blocked part is dropped the tick the
        // grasp engages, the plan's EE settles that far back — 1–2 cm with the arm extended
        // against the wall — and the hand, welded to the object, pulls the base instead:
        // measured in Push Slider, 0.13 m/s into the wall bound on that tick.)
        let mut reference = *reference;
        if self.config.grasp_reference
            && let (Some(g), Some((_, ee))) = (&self.anchored_grasp, &held_ee)
        {
            let offset = reference.ee_offset_m;
            let on_motion = g.project(&(reference.ee_position_m - offset));
            reference.ee_position_m = on_motion + offset;
            // The hand is welded to the object: where a revolute joint takes the EE, it turns
            // the hand with it.
            if self.config.grasp_orientation
                && let Some(turn) = g.turn_to(&on_motion)
            {
                reference.ee_rotation = turn * UnitQuaternion::from_rotation_matrix(&ee.rotation);
            }
        }
        // Touching what does not give way: the target's part beyond the contact plane
        // through the measured EE is one the hand cannot reach (the model, without contact,
        // would stretch the arm for it and push its own base back), as is its velocity into
        // the contact; the offset added back as above.
        self.anchored_contact = self
            .contact
            .filter(|_| self.config.contact_reference)
            .map(|normal| (normal, self.model.ee(x_hat).position));
        if let Some((normal, anchor)) = &self.anchored_contact {
            let offset = reference.ee_offset_m;
            reference.ee_position_m = anchor
                + beyond_contact_dropped(normal, &(reference.ee_position_m - offset - anchor))
                + offset;
            reference.ee_velocity_mps = beyond_contact_dropped(normal, &reference.ee_velocity_mps);
        }
        self.reference = Some(reference);
        self.set_bounds(x_hat, limits);
        self.linearize(&reference);
    }

    fn set_bounds(&mut self, x_hat: &StateVector, limits: &BaseLimits) {
        let c = &self.config;
        let mut lower = [0.0; 10];
        let mut upper = [0.0; 10];
        for axis in 0..3 {
            let (lo, hi) = limits.bounds(axis);
            lower[axis] = c.position_min_m[axis].max(lo);
            upper[axis] = c.position_max_m[axis].min(hi);
        }
        lower[3] = -c.roll_pitch_limit_rad;
        upper[3] = c.roll_pitch_limit_rad;
        lower[4] = -c.roll_pitch_limit_rad;
        upper[4] = c.roll_pitch_limit_rad;
        lower[5] = -c.yaw_limit_rad;
        upper[5] = c.yaw_limit_rad;
        lower[6..].copy_from_slice(&self.joint_lower);
        upper[6..].copy_from_slice(&self.joint_upper);
        let arm_tau = Self::arm_recovery_time_constant(c);
        let height_hat = self.model.ee(x_hat).position.z - x_hat[IX_P + 2];
        let relax = |lo: f64, hi: f64, v: f64, decay: f64| -> (f64, f64) {
            (lo.min(lo + (v - lo) * decay), hi.max(hi + (v - hi) * decay))
        };
        for k in 1..=c.intervals {
            let t = k as f64 * self.h;
            let decay_fast = (-t / c.recovery_time_constant_s).exp();
            let decay_arm = (-t / arm_tau).exp();
            let b = &mut self.bounds[k];
            for (i, &ix) in STATE_BOUND_INDICES.iter().enumerate() {
                let decay = if i >= 6 { decay_arm } else { decay_fast };
                let (lo, hi) = relax(lower[i], upper[i], x_hat[ix], decay);
                b.state_lower[i] = lo;
                b.state_upper[i] = hi;
            }
            let (lo, hi) = relax(c.ee_height_min_m, c.ee_height_max_m, height_hat, decay_arm);
            b.height_lower = lo;
            b.height_upper = hi;
        }
    }

    /// Time constant with which the bounds of a joint (and of the EE height) measured past
    /// them close in over the horizon: the servo's 2/k_a, at least the base's.
    fn arm_recovery_time_constant(c: &MpcConfig) -> f64 {
        (2.0 / c.arm_gain_per_s).max(c.recovery_time_constant_s)
    }

    /// Whether the arm joints' state bounds are rows of the QP (false: implied by the
    /// arm-reference bounds, [`arm_state_rows_implied`]).
    pub fn has_arm_state_rows(&self) -> bool {
        self.qp
            .constraints
            .get(1)
            .is_some_and(|c| c.state_indices.len() == STATE_BOUND_INDICES.len())
    }

    fn stage_scale(&self, k: usize) -> f64 {
        if k < self.config.intervals {
            self.h
        } else {
            1.0
        }
    }

    /// The EE position reference at stage `k`: the target moved along its velocity for
    /// `min(t_k, target_extrapolation_s)`.
    fn stage_target(&self, reference: &MpcReference, k: usize) -> Vector3<f64> {
        let t = (k as f64 * self.h).min(self.config.target_extrapolation_s);
        reference.ee_position_m + reference.ee_velocity_mps * t
    }

    /// Residual vector of the EE (position against `target`, wrapped rpy) and its Jacobian
    /// at x.
    fn ee_residual(
        &mut self,
        x: &StateVector,
        target: &Vector3<f64>,
        ref_rpy: &Vector3<f64>,
    ) -> (SMatrix<f64, 6, 1>, SMatrix<f64, 6, NX>, f64, StateVector) {
        let ee = self.model.ee(x);
        let y = pose_residual(&ee.position, &ee.rpy, target, ref_rpy);
        let mut jac = SMatrix::<f64, 6, NX>::zeros();
        jac.fixed_rows_mut::<3>(0).copy_from(&ee.position_jacobian);
        jac.fixed_rows_mut::<3>(3).copy_from(&ee.rpy_jacobian);
        let height = ee.position.z - x[IX_P + 2];
        let mut height_gradient: StateVector = ee.position_jacobian.row(2).transpose();
        height_gradient[IX_P + 2] = 0.0;
        (y, jac, height, height_gradient)
    }

    /// Linear state residuals r (v, η − η_ref, ω, q − q_0) with zeros elsewhere.
    fn state_residual(&self, x: &StateVector, yaw_ref: f64) -> StateVector {
        let mut r = StateVector::zeros();
        for i in 0..3 {
            r[IX_V + i] = x[IX_V + i];
            r[IX_OMEGA + i] = x[IX_OMEGA + i];
        }
        r[IX_ETA] = x[IX_ETA];
        r[IX_ETA + 1] = x[IX_ETA + 1];
        r[IX_ETA + 2] = wrap_angle(x[IX_ETA + 2] - yaw_ref);
        for j in 0..NQ {
            r[IX_Q + j] = x[IX_Q + j] - self.config.default_arm_rad[j];
        }
        r
    }

    fn input_reference(&self) -> InputVector {
        let mut u = InputVector::zeros();
        for j in 0..NQ {
            u[IU_QREF + j] = self.config.default_arm_rad[j];
        }
        u
    }

    fn linearize(&mut self, reference: &MpcReference) {
        let n = self.config.intervals;
        let (rr, rp, ry) = reference.ee_rotation.euler_angles();
        let ref_rpy = Vector3::new(rr, rp, ry);
        let u_ref = self.input_reference();
        let r_diag = self.input_weights + self.rate_weights;
        self.rotor_rows.clear();
        self.rotor_rows
            .extend(rotor_rows(&self.envelope, &self.config, &self.xs[0]));
        for k in 0..=n {
            let x = self.xs[k];
            let scale = self.stage_scale(k);
            let target = self.stage_target(reference, k);
            let (y, jac, height, height_gradient) = self.ee_residual(&x, &target, &ref_rpy);
            let r_state = self.state_residual(&x, ry);
            // W J with W diagonal: each row of J scaled by its weight.
            let mut wj = jac;
            for (mut row, w) in wj.row_iter_mut().zip(self.ee_weights.iter()) {
                row *= *w;
            }
            let mut q = jac.transpose() * wj;
            let mut qv = wj.transpose() * y;
            for i in 0..NX {
                q[(i, i)] += self.state_weights[i];
                qv[i] += self.state_weights[i] * r_state[i];
            }
            self.qp.q[k] = q * scale;
            self.qp.q_vec[k] = qv * scale;
            if k < n {
                let u = self.us[k];
                self.qp.r[k] = InputMatrix::from_diagonal(&(r_diag * scale));
                self.qp.s[k] = InputStateMatrix::zeros();
                self.qp.r_vec[k] = (self.input_weights.component_mul(&(u - u_ref))
                    + self
                        .rate_weights
                        .component_mul(&(u - reference.input_previous)))
                    * scale;
                self.qp.defects[k] =
                    self.a_sparse.times(&x) + self.b_sparse.times(&u) - self.xs[k + 1];
                let c = &mut self.qp.constraints[k];
                for (j, &iu) in INPUT_BOUND_INDICES.iter().enumerate() {
                    c.input_lower[j] = self.joint_lower[j] - u[iu];
                    c.input_upper[j] = self.joint_upper[j] - u[iu];
                }
                for (j, &(e, lo, hi)) in self.rotor_rows.iter().enumerate() {
                    let v = e.dot(&u);
                    c.input_general[j] = e;
                    c.input_general_lower[j] = lo - v;
                    c.input_general_upper[j] = hi - v;
                }
            }
            if k > 0 {
                let b = self.bounds[k];
                let c = &mut self.qp.constraints[k];
                let rows = c.state_indices.len();
                for (i, &ix) in STATE_BOUND_INDICES.iter().enumerate().take(rows) {
                    c.state_lower[i] = b.state_lower[i] - x[ix];
                    c.state_upper[i] = b.state_upper[i] - x[ix];
                }
                c.general[0] = height_gradient;
                c.general_lower[0] = b.height_lower - height;
                c.general_upper[0] = b.height_upper - height;
                let band = self
                    .config
                    .grasp_band_m
                    .filter(|_| self.anchored_grasp.is_some());
                let rows = band.map_or(0, |_| GRASP_ROWS);
                c.general.resize(1 + rows, StateVector::zeros());
                c.general_lower.resize(1 + rows, 0.0);
                c.general_upper.resize(1 + rows, 0.0);
                if let (Some(grasp), Some(band)) = (&self.anchored_grasp, band) {
                    let ee = self.model.ee(&x);
                    for (j, (value, gradient)) in grasp.rows(&ee).into_iter().enumerate() {
                        c.general[1 + j] = gradient;
                        c.general_lower[1 + j] = -band - value;
                        c.general_upper[1 + j] = band - value;
                    }
                }
            }
        }
        self.qp.x0 = StateVector::zeros();
    }

    /// NLS cost and largest inequality violation of the current iterate.
    pub fn evaluate(&mut self) -> (f64, f64) {
        let Some(reference) = self.reference else {
            return (0.0, 0.0);
        };
        let n = self.config.intervals;
        let (rr, rp, ry) = reference.ee_rotation.euler_angles();
        let ref_rpy = Vector3::new(rr, rp, ry);
        let u_ref = self.input_reference();
        let mut cost = 0.0;
        let mut violation: f64 = 0.0;
        for k in 0..=n {
            let x = self.xs[k];
            let target = self.stage_target(&reference, k);
            let (position, rpy) = self.model.ee_pose(&x);
            let y = pose_residual(&position, &rpy, &target, &ref_rpy);
            let height = position.z - x[IX_P + 2];
            let r_state = self.state_residual(&x, ry);
            let mut stage = 0.0;
            for i in 0..6 {
                stage += self.ee_weights[i] * y[i] * y[i];
            }
            for i in 0..NX {
                stage += self.state_weights[i] * r_state[i] * r_state[i];
            }
            if k < n {
                let u = self.us[k];
                let du = u - u_ref;
                let dp = u - reference.input_previous;
                for i in 0..NU {
                    stage += self.input_weights[i] * du[i] * du[i]
                        + self.rate_weights[i] * dp[i] * dp[i];
                }
                for (j, &iu) in INPUT_BOUND_INDICES.iter().enumerate() {
                    violation = violation
                        .max(self.joint_lower[j] - u[iu])
                        .max(u[iu] - self.joint_upper[j]);
                }
                for (e, lo, hi) in &self.rotor_rows {
                    let v = e.dot(&u);
                    violation = violation.max(lo - v).max(v - hi);
                }
            }
            cost += 0.5 * self.stage_scale(k) * stage;
            if k > 0 {
                let b = &self.bounds[k];
                for (i, &ix) in STATE_BOUND_INDICES.iter().enumerate() {
                    violation = violation
                        .max(b.state_lower[i] - x[ix])
                        .max(x[ix] - b.state_upper[i]);
                }
                violation = violation
                    .max(b.height_lower - height)
                    .max(height - b.height_upper);
                if let (Some(grasp), Some(band)) = (&self.anchored_grasp, self.config.grasp_band_m)
                {
                    let ee = self.model.ee(&x);
                    for (value, _) in grasp.rows(&ee) {
                        violation = violation.max(value.abs() - band);
                    }
                }
            }
        }
        (cost, violation)
    }

    /// Solves the prepared QP with `path`; on success takes the full step. The QP solution
    /// (deltas) is left in [`Self::last_qp_solution`].
    pub fn feedback(&mut self, path: QpPath) -> RtiReport {
        let solver: &mut dyn QpSolver = match path {
            QpPath::Riccati => &mut self.riccati,
            QpPath::Clarabel => &mut self.clarabel,
        };
        let mut status = solver.solve(&self.qp, &mut self.solution);
        // Soft state rows: a slack beyond the limit means the hard QP has no solution.
        if status == QpStatus::Solved
            && let Some(limit) = self.config.state_row_slack_limit
            && self.solution.slack.iter().any(|t| *t > limit)
        {
            status = QpStatus::Infeasible;
        }
        if status != QpStatus::Solved {
            // Its multipliers (on an infeasible QP's soft rows: ρ) are no start for the next.
            self.riccati.forget();
        } else if path == QpPath::Riccati && self.riccati.screening_report().resolved {
            // A taken solution the screening had to redo: the next QPs likely cross too.
            self.riccati.pause_screening();
        }
        if status == QpStatus::Solved {
            for (x, dx) in self.xs.iter_mut().zip(&self.solution.x) {
                *x += dx;
            }
            for (u, du) in self.us.iter_mut().zip(&self.solution.u) {
                *u += du;
            }
        }
        self.warm = true;
        let (cost, max_constraint_violation) = self.evaluate();
        RtiReport {
            status,
            qp_iterations: self.solution.iterations,
            cost,
            max_constraint_violation,
        }
    }

    /// The EE position reference of the last prepared QP at the end of its horizon (the
    /// grasp model's projection and the target's extrapolation applied; None before any).
    pub fn terminal_target(&self) -> Option<Vector3<f64>> {
        self.reference
            .as_ref()
            .map(|r| self.stage_target(r, self.config.intervals))
    }

    /// The QP solution (deltas) of the last feedback.
    pub fn last_qp_solution(&self) -> &QpSolution {
        &self.solution
    }

    /// [`Self::prepare`] then [`Self::feedback`].
    pub fn step(
        &mut self,
        x_hat: &StateVector,
        reference: &MpcReference,
        limits: &BaseLimits,
        elapsed_s: f64,
        path: QpPath,
    ) -> RtiReport {
        self.prepare(x_hat, reference, limits, elapsed_s);
        self.feedback(path)
    }
}

/// [`SqpRti::prepare`] compiled for the baseline and for AVX2, chosen at run time (as the
/// interior point's kernels, `riccati::vectorised`: the same bits either way).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn prepare_vectorised(
    rti: &mut SqpRti,
    x_hat: &StateVector,
    reference: &MpcReference,
    limits: &BaseLimits,
    elapsed_s: f64,
) {
    rti.prepare_impl(x_hat, reference, limits, elapsed_s);
}

/// The EE residual: position against `target`, roll, pitch, yaw against `ref_rpy` (wrapped).
fn pose_residual(
    position: &Vector3<f64>,
    rpy: &Vector3<f64>,
    target: &Vector3<f64>,
    ref_rpy: &Vector3<f64>,
) -> SMatrix<f64, 6, 1> {
    let mut y = SMatrix::<f64, 6, 1>::zeros();
    for i in 0..3 {
        y[i] = position[i] - target[i];
        y[3 + i] = wrap_angle(rpy[i] - ref_rpy[i]);
    }
    y
}

/// Whether the arm joints' state bounds (`q_min ≤ q_k ≤ q_max`, k = 1..N, widened toward a
/// measured joint past them as `b + (q̂ − b)·e^{−t_k/τ}`) follow from the arm-reference
/// bounds (`q_min ≤ q_ref,k ≤ q_max`) through the dynamics, so that leaving them out of the
/// QP leaves its feasible set as it is. True when each joint's row of the step is
/// `q_{k+1} = φ q_k + β q_ref,k` (A and B without another entry on it) with
/// `0 ≤ φ ≤ e^{−h/τ}` and `φ + β = 1`: then by induction from `q_0 = q̂`,
/// `q_k − b ≤ φ^k (q̂ − b)⁺ ≤ (q̂ − b)⁺ e^{−t_k/τ}` on either side. The servo's exact step has
/// φ = e^{−k_a h} ≤ e^{−k_a h/2}; RK4's (the MPC's integrator) is its degree-4 polynomial,
/// which leaves [0, 1] for k_a h > 2.79 (then the rows stay).
pub(crate) fn arm_state_rows_implied(
    a: &StateMatrix,
    b: &StateInputMatrix,
    h: f64,
    tau: f64,
) -> bool {
    const ROUND_OFF: f64 = 1e-12;
    let decay = (-h / tau).exp();
    (0..NQ).all(|j| {
        let (row, input) = (IX_Q + j, IU_QREF + j);
        let phi = a[(row, row)];
        let beta = b[(row, input)];
        let others_zero = (0..NX).all(|c| c == row || a[(row, c)] == 0.0)
            && (0..NU).all(|c| c == input || b[(row, c)] == 0.0);
        others_zero && phi >= 0.0 && phi <= decay && (phi + beta - 1.0).abs() <= ROUND_OFF
    })
}

/// The rotor rows of a stage (`lower ≤ eᵀu ≤ upper`): the force's share of each rotor's
/// margin (`rotor_margin_for_force`) at the heading of the measured state `x0` (roll and
/// pitch, within ±0.01 rad, neglected, as the reference does for the frame change), then the
/// whole wrench's (`rotor_margin_for_wrench`) at its full attitude (the weight's share of
/// each rotor moves with the tilt), both over the whole horizon.
fn rotor_rows<'a>(
    envelope: &'a Option<crate::mpc::model::RotorEnvelope>,
    config: &MpcConfig,
    x0: &StateVector,
) -> impl Iterator<Item = (InputVector, f64, f64)> + 'a {
    let heading = Rotation3::from_euler_angles(0.0, 0.0, x0[IX_ETA + 2]);
    let attitude = Rotation3::from_euler_angles(x0[IX_ETA], x0[IX_ETA + 1], x0[IX_ETA + 2]);
    let force = envelope
        .as_ref()
        .zip(config.rotor_margin_for_force)
        .into_iter()
        .flat_map(move |(e, f)| e.input_rows(&heading, f));
    let wrench = envelope
        .as_ref()
        .zip(config.rotor_margin_for_wrench)
        .into_iter()
        .flat_map(move |(e, f)| e.wrench_rows(&attitude, f));
    force.chain(wrench)
}

/// `v` without its part against the unit contact `normal` (the part into what the hand
/// touches): `v − n·min(0, n·v)`.
fn beyond_contact_dropped(normal: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    v - normal * normal.dot(v).min(0.0)
}
