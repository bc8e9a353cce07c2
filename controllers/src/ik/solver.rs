//! The whole-body IK solver: a two-level (task-priority) Levenberg–Marquardt iteration over
//! the base pose and the arm joints. The formulation is stated in the `ik` module doc.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use platform::Vehicle;
use thiserror::Error;

use super::chain::Chain;
use super::config::{IkConfig, IkConfigError, RestPosture};
use super::iteration::Workspace;
use super::limits::BaseLimits;
use super::problem::{Layout, Problem, State, Target, linearize};

/// Why an IK cannot be built or seeded.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum IkError {
    /// The configuration is out of range.
    #[error(transparent)]
    Config(#[from] IkConfigError),
    /// A seed configuration of the wrong length.
    #[error("configuration has {got} entries, the model has {expected} degrees of freedom")]
    ConfigurationLength {
        /// The model's DoF.
        expected: usize,
        /// What was given.
        got: usize,
    },
    /// A seed with a non-finite number.
    #[error("the seed {0} is not finite")]
    NonFiniteSeed(&'static str),
    /// A rest posture share outside [0, 1] (`WholeBodyIk::blend_rest_configuration`).
    #[error("the rest posture share {0} is not within [0, 1]")]
    RestShare(f64),
}

/// Why a solve stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IkReason {
    /// Stationary (step, cost change or gradient below tolerance, or no damping gives progress)
    /// with the pose reached and the limits respected.
    PoseReached,
    /// Stationary short of the target: it is out of reach within the limits (or the solver sits
    /// in a local minimum). The solution is the closest pose found; the hinge residuals let the
    /// limits give by about `(w_pose/w_limit)²` times the remaining distance.
    ClosestPose,
    /// `max_iterations` step attempts used; the solution is the last accepted iterate (the
    /// status's `converged` still says whether it meets the pose).
    IterationLimit,
    /// The target had a non-finite component (or a zero quaternion): the previous solution is
    /// returned unchanged.
    NonFiniteTarget,
    /// A base limit was not finite: the previous solution is returned unchanged.
    NonFiniteLimits,
    /// A non-finite number appeared in the solve: the previous solution is returned unchanged.
    NumericalFailure,
}

/// How a solve went.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkStatus {
    /// The returned solution meets the target within `pose_position_tolerance_m` and
    /// `pose_orientation_tolerance_rad`, and every limit within `limit_tolerance`.
    pub converged: bool,
    /// Why the iteration stopped.
    pub reason: IkReason,
    /// Step attempts (accepted and rejected).
    pub iterations: u32,
    /// Task cost of the solution: Σ of squared weighted pose and limit-hinge residuals.
    pub final_cost: f64,
    /// Regularisation cost of the solution: Σ of squared weighted smoothness and rest residuals.
    pub regularisation_cost: f64,
    /// |p_ee − p_target|, m.
    pub position_error_m: f64,
    /// |log(R_targetᵀ R_ee)|, rad.
    pub orientation_error_rad: f64,
    /// Largest violation of a base-position or arm-joint limit, m or rad.
    pub limit_violation: f64,
}
// When no solve ran (`NonFiniteTarget`, `NonFiniteLimits`, `NumericalFailure`) the costs,
// errors and violation are +∞ (unknown), `iterations` is 0 and `converged` false: a caller
// comparing them with a tolerance reads them as failed. The solution itself is finite.

/// One IK answer.
#[derive(Debug, Clone, PartialEq)]
pub struct IkSolution {
    /// Base pose in the world.
    pub world_from_base: Isometry3<f64>,
    /// Full configuration (length `model.dof()`): arm joints solved, every other joint at its
    /// held value (the vehicle's initial drive position).
    pub configuration: Vec<f64>,
    /// Arm joints in command order (`Vehicle::arm_joints`).
    pub arm_joints: Vec<f64>,
    /// How the solve went.
    pub status: IkStatus,
}

/// Most task-level corrections tried on a trial point, and on the final point (see `iterate`).
const MAX_CORRECTIONS: usize = 3;
/// Task cost below which the final point is not polished (a pose error of ~1e-10).
const POLISHED_TASK_COST: f64 = 1e-20;
/// The polish stops once a correction leaves more than this fraction of the task cost (what
/// remains is not reachable by Gauss–Newton at λ_min, e.g. along a near-singular direction).
const POLISH_MIN_GAIN: f64 = 0.25;

/// A unit quaternion's norm may drift from 1 by more than this before it is renormalised.
const UNIT_NORM_DRIFT: f64 = 1e-9;

/// `q` as given when its norm is 1 to round-off (so a locked rotation is kept bit for bit),
/// else renormalised.
fn renormalized(q: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    if (q.coords.norm() - 1.0).abs() <= UNIT_NORM_DRIFT {
        *q
    } else {
        UnitQuaternion::new_normalize(*q.quaternion())
    }
}

/// Whole-body IK of one vehicle: base pose and arm joints that put `ee_link` at a target pose.
///
/// Keeps the previous solution between calls, as warm start and as the anchor of the smoothness
/// terms. See the `ik` module doc for the formulation.
#[derive(Debug, Clone, PartialEq)]
pub struct WholeBodyIk {
    problem: Problem,
    previous: State,
    ws: Workspace,
}

impl WholeBodyIk {
    /// Builds the IK of `vehicle` (its `ee_link` frame is the target frame) and seeds it with
    /// the base at `config.initial_base_position_m`, level, and the arm at rest.
    pub fn new(vehicle: &Vehicle, config: IkConfig) -> Result<Self, IkError> {
        config.validate()?;
        let model = &vehicle.model;
        let arm_dofs = vehicle.arm_dofs();
        let held = vehicle.initial_configuration();
        let rest: Vec<f64> = match config.rest_posture {
            RestPosture::Zero => vec![0.0; arm_dofs.len()],
            RestPosture::VehicleInitial => arm_dofs.iter().map(|&d| held[d]).collect(),
        };
        let (arm_lower, arm_upper): (Vec<f64>, Vec<f64>) = arm_dofs
            .iter()
            .map(|&d| {
                model
                    .dof_joint(d)
                    .limits
                    .map_or((f64::NEG_INFINITY, f64::INFINITY), |l| (l.lower, l.upper))
            })
            .unzip();
        let chain = Chain::new(vehicle, &held, &arm_dofs);
        let layout = Layout::new(&config, arm_dofs.len());
        let s = &config.solver;
        let w = &config.weights;
        // Inside this band both pose errors are within their tolerances.
        let task_tie = (w.pose_position * s.pose_position_tolerance_m)
            .powi(2)
            .min((w.pose_orientation * s.pose_orientation_tolerance_rad).powi(2));
        let previous = State {
            position: Vector3::from(config.initial_base_position_m),
            rotation: UnitQuaternion::identity(),
            arm: rest.clone(),
        };
        let problem = Problem {
            config,
            chain,
            layout,
            arm_dofs,
            held,
            configured_rest: rest.clone(),
            rest,
            arm_step: vec![f64::INFINITY; arm_lower.len()],
            arm_lower,
            arm_upper,
            task_tie,
        };
        let ws = Workspace::new(&problem, &previous);
        Ok(Self {
            problem,
            previous,
            ws,
        })
    }

    /// Bounds each arm joint's change between successive solves to what its drive can move in
    /// `period_s` (the drive's `velocity_limit` × `period_s`), so that the joint targets handed
    /// out are ones the arm can follow and the base takes the rest of a fast motion. Without
    /// it (the reference's IK) a target moving faster than the arm asks for joint steps the
    /// drives take several periods to make, while the base already flies the solution that
    /// assumed them. A joint without a drive, or a non-positive or non-finite `period_s`
    /// (which removes the bound), stays unbounded. See the module docs.
    pub fn limit_joint_rates(&mut self, vehicle: &Vehicle, period_s: f64) {
        let p = &mut self.problem;
        for (k, &dof) in p.arm_dofs.iter().enumerate() {
            let limit = vehicle
                .drives
                .iter()
                .find(|d| vehicle.model.joints[d.joint].dof == Some(dof))
                .map(|d| d.velocity_limit * period_s);
            p.arm_step[k] = match limit {
                Some(step) if period_s.is_finite() && period_s > 0.0 && step > 0.0 => step,
                _ => f64::INFINITY,
            };
        }
    }

    /// The most change of each arm joint per solve (command order), rad or m; ∞ where
    /// unbounded.
    pub fn joint_steps(&self) -> &[f64] {
        &self.problem.arm_step
    }

    /// The settings.
    pub fn config(&self) -> &IkConfig {
        &self.problem.config
    }

    /// Number of free variables (base axes not locked + arm joints).
    pub fn variable_count(&self) -> usize {
        self.problem.layout.n
    }

    /// The full configuration at the rest posture (non-arm joints at their held values).
    pub fn rest_configuration(&self) -> Vec<f64> {
        self.configuration_of(&self.problem.rest)
    }

    /// Seeds the warm start and the smoothness anchor with a measured state (the reference does
    /// so at the start of each episode). Only the arm entries of `configuration` are read;
    /// every other joint stays at its held value. The base pose is kept as given, locked axes
    /// included.
    pub fn reset(
        &mut self,
        world_from_base: &Isometry3<f64>,
        configuration: &[f64],
    ) -> Result<(), IkError> {
        self.check_length(configuration)?;
        let state = State {
            position: world_from_base.translation.vector,
            rotation: renormalized(&world_from_base.rotation),
            arm: self
                .problem
                .arm_dofs
                .iter()
                .map(|&d| configuration[d])
                .collect(),
        };
        if !state.is_finite() {
            return Err(IkError::NonFiniteSeed("state"));
        }
        self.previous = state;
        Ok(())
    }

    /// Moves the rest term's posture `share` of the way from the configured one
    /// (`IkConfig::rest_posture`) to the arm entries of `configuration`: 1 holds that posture,
    /// 0 is the configured rest. A caller taking over from another controller mid-motion
    /// holds the posture it was handed and lets it fade, so the arm's redundancy is resolved
    /// about it instead of jumping to the configured rest (which swings the arm against the
    /// motion it was making). [`Self::restore_rest_configuration`] undoes it.
    pub fn blend_rest_configuration(
        &mut self,
        configuration: &[f64],
        share: f64,
    ) -> Result<(), IkError> {
        self.check_length(configuration)?;
        if !(0.0..=1.0).contains(&share) {
            return Err(IkError::RestShare(share));
        }
        let p = &mut self.problem;
        if p.arm_dofs.iter().any(|&d| !configuration[d].is_finite()) {
            return Err(IkError::NonFiniteSeed("rest configuration"));
        }
        for ((rest, &configured), &d) in p.rest.iter_mut().zip(&p.configured_rest).zip(&p.arm_dofs)
        {
            *rest = configured + share * (configuration[d] - configured);
        }
        Ok(())
    }

    /// The rest term's posture back to the configured one (`IkConfig::rest_posture`).
    pub fn restore_rest_configuration(&mut self) {
        self.problem.rest.clone_from(&self.problem.configured_rest);
    }

    /// `world_from_ee` of a base pose and configuration (non-arm joints at their held values).
    ///
    /// # Panics
    /// If `configuration.len()` is not the model's DoF (a caller bug).
    pub fn world_from_ee(
        &self,
        world_from_base: &Isometry3<f64>,
        configuration: &[f64],
    ) -> Isometry3<f64> {
        assert_eq!(configuration.len(), self.problem.held.len());
        let arm: Vec<f64> = self
            .problem
            .arm_dofs
            .iter()
            .map(|&d| configuration[d])
            .collect();
        world_from_base * self.problem.chain.base_from_ee(&arm)
    }

    /// Solves for the base pose and arm joints that put `ee_link` at `target_world_from_ee`
    /// with the base within `limits`, warm-started from the previous solution, and keeps the
    /// answer as the next warm start. Never returns a non-finite number: on a non-finite input
    /// or a numerical failure it returns the previous solution with a status saying so.
    pub fn solve(
        &mut self,
        target_world_from_ee: &Isometry3<f64>,
        limits: &BaseLimits,
    ) -> IkSolution {
        let t = target_world_from_ee;
        let target_finite = t.translation.vector.iter().all(|v| v.is_finite())
            && t.rotation.coords.iter().all(|v| v.is_finite())
            && t.rotation.coords.norm() > 0.0;
        if !target_finite {
            return self.previous_with(IkReason::NonFiniteTarget);
        }
        if !limits.is_finite() {
            return self.previous_with(IkReason::NonFiniteLimits);
        }
        let rotation = renormalized(&t.rotation);
        let target = Target {
            position: t.translation.vector,
            rotation,
            rotation_transposed: rotation.to_rotation_matrix().matrix().transpose(),
            base_bounds: [limits.bounds(0), limits.bounds(1), limits.bounds(2)],
        };
        match self.iterate(&target) {
            Some(status) => {
                self.previous.copy_from(&self.ws.state);
                self.solution_from(&self.previous, status)
            }
            None => self.previous_with(IkReason::NumericalFailure),
        }
    }

    /// The Levenberg–Marquardt loop. Leaves the solution in `ws.state`; None on a numerical
    /// failure.
    fn iterate(&mut self, target: &Target) -> Option<IkStatus> {
        let p = &self.problem;
        let anchor = &self.previous;
        let ws = &mut self.ws;
        let s = &p.config.solver;
        let n = p.layout.n;
        ws.state.copy_from(anchor);
        ws.set_bounds(p, target, anchor);
        linearize(p, &ws.state, target, anchor, &mut ws.poses, &mut ws.current);
        if !ws.current.is_finite() {
            return None;
        }
        // λ damps the task step, μ the regularisation step; each adapts to how well its
        // level's model predicted the trial.
        let mut lambda = s.lambda_initial;
        let mut mu = s.lambda_initial;
        let mut iterations = 0;
        let mut decomposed = false;
        let mut stationary = false;
        while iterations < s.max_iterations {
            if !decomposed {
                if !ws.decompose(p, target, anchor, iterations == 0) {
                    return None;
                }
                decomposed = true;
                if iterations >= s.gradient_tolerance_start_iteration
                    && ws.current.g.amax() < s.gradient_tolerance
                    && ws.null_gradient_max() < s.gradient_tolerance
                {
                    stationary = true;
                    break;
                }
            }
            let predicted = ws.step(p, lambda, mu);
            let predicted2 = ws.predicted_regularisation_decrease(n);
            iterations += 1;
            ws.evaluate_trial(p, target, anchor);
            // Second-order correction: the regularisation step is tangent to the task's
            // solution set, so on a curved set it leaves a task error of second order. While
            // the task level rejects the trial, task Gauss–Newton steps from the trial point
            // (its J₁ is at hand) remove that error.
            let mut verdict = ws.judge(p, predicted, predicted2);
            for _ in 0..MAX_CORRECTIONS {
                if verdict.task_ok
                    || !ws.has_null_step()
                    || !ws.trial.is_finite()
                    || !ws.correct_trial(p, target, anchor, s.lambda_min)
                {
                    break;
                }
                verdict = ws.judge(p, predicted, predicted2);
            }
            let accept = verdict.accept();
            let step_norm = ws.delta[..n].iter().map(|d| d * d).sum::<f64>().sqrt();
            let small_step =
                step_norm <= s.parameter_tolerance * (ws.state.norm() + s.parameter_tolerance);
            // The regularisation model was good: trust it more; bad, or its step broke the
            // task level: less.
            mu = if verdict.task_ok && verdict.regularisation_ok {
                (mu / s.lambda_factor).max(s.lambda_min)
            } else {
                mu * s.lambda_factor
            };
            if accept {
                // The task level is done when its pose is met or its cost has settled; the
                // regularisation level when its cost has settled.
                let (cur, trial) = (&ws.current, &ws.trial);
                let task_done = trial.meets(s)
                    || (cur.task_cost - trial.task_cost).abs() <= s.cost_tolerance * cur.task_cost;
                let regularisation_settled = (cur.regularisation_cost - trial.regularisation_cost)
                    .abs()
                    <= s.cost_tolerance * cur.regularisation_cost;
                ws.accept_trial();
                decomposed = false;
                lambda = (lambda / s.lambda_factor).max(s.lambda_min);
                if small_step || (task_done && regularisation_settled) {
                    stationary = true;
                    break;
                }
            } else {
                if !verdict.task_ok {
                    lambda *= s.lambda_factor;
                }
                if small_step || lambda > s.lambda_max || mu > s.lambda_max {
                    stationary = true;
                    break;
                }
            }
        }
        // Polish: the regularisation steps may leave a pose error inside the tie band; task
        // corrections from the final point remove it (the regularisation barely moves).
        for _ in 0..MAX_CORRECTIONS {
            let before = ws.current.task_cost;
            if before <= POLISHED_TASK_COST
                || !ws.polish(p, target, anchor, s.lambda_min)
                || ws.current.task_cost > POLISH_MIN_GAIN * before
            {
                break;
            }
        }
        if !ws.state.is_finite() || !ws.current.is_finite() {
            return None;
        }
        let cur = &ws.current;
        let converged = cur.meets(s);
        let reason = match (stationary, converged) {
            (true, true) => IkReason::PoseReached,
            (true, false) => IkReason::ClosestPose,
            (false, _) => IkReason::IterationLimit,
        };
        Some(IkStatus {
            converged,
            reason,
            iterations,
            final_cost: cur.task_cost,
            regularisation_cost: cur.regularisation_cost,
            position_error_m: cur.position_error_m,
            orientation_error_rad: cur.orientation_error_rad,
            limit_violation: cur.limit_violation,
        })
    }

    /// The previous solution unchanged, with a status saying why no solve ran.
    fn previous_with(&self, reason: IkReason) -> IkSolution {
        self.solution_from(
            &self.previous,
            IkStatus {
                converged: false,
                reason,
                iterations: 0,
                final_cost: f64::INFINITY,
                regularisation_cost: f64::INFINITY,
                position_error_m: f64::INFINITY,
                orientation_error_rad: f64::INFINITY,
                limit_violation: f64::INFINITY,
            },
        )
    }

    /// A configuration must have the model's DoF.
    fn check_length(&self, configuration: &[f64]) -> Result<(), IkError> {
        let expected = self.problem.held.len();
        if configuration.len() == expected {
            Ok(())
        } else {
            Err(IkError::ConfigurationLength {
                expected,
                got: configuration.len(),
            })
        }
    }

    fn configuration_of(&self, arm: &[f64]) -> Vec<f64> {
        let mut q = self.problem.held.clone();
        for (&d, &v) in self.problem.arm_dofs.iter().zip(arm) {
            q[d] = v;
        }
        q
    }

    fn solution_from(&self, state: &State, status: IkStatus) -> IkSolution {
        IkSolution {
            world_from_base: Isometry3::from_parts(
                Translation3::from(state.position),
                state.rotation,
            ),
            configuration: self.configuration_of(&state.arm),
            arm_joints: state.arm.clone(),
            status,
        }
    }
}

#[cfg(test)]
impl WholeBodyIk {
    /// For each variable at (base, q), with the smoothness anchored at (anchor_base,
    /// anchor_q) and no base limits: (J₁ᵀr₁, J₂ᵀr₂, (∂C₁, ∂C₂) by central differences of
    /// step `h` along the variable's tangent direction).
    #[allow(clippy::type_complexity)]
    pub(crate) fn gradients_at(
        &self,
        base: &Isometry3<f64>,
        q: &[f64],
        anchor_base: &Isometry3<f64>,
        anchor_q: &[f64],
        target: &Isometry3<f64>,
        h: f64,
    ) -> Vec<(f64, f64, (f64, f64))> {
        use super::problem::{Linearization, retract};
        let p = &self.problem;
        let n = p.layout.n;
        let state = |b: &Isometry3<f64>, q: &[f64]| State {
            position: b.translation.vector,
            rotation: b.rotation,
            arm: p.arm_dofs.iter().map(|&d| q[d]).collect(),
        };
        let x = state(base, q);
        let anchor = state(anchor_base, anchor_q);
        let target = Target {
            position: target.translation.vector,
            rotation: target.rotation,
            rotation_transposed: target.rotation.to_rotation_matrix().matrix().transpose(),
            base_bounds: [(f64::NEG_INFINITY, f64::INFINITY); 3],
        };
        let mut poses = p.chain.poses_buffer();
        let mut lin = Linearization::new(n);
        linearize(p, &x, &target, &anchor, &mut poses, &mut lin);
        let (g, c) = (lin.g.clone(), lin.c.clone());
        let mut moved = x.clone();
        let mut costs = |delta: &[f64]| {
            retract(&p.layout, &x, delta, &mut moved);
            linearize(p, &moved, &target, &anchor, &mut poses, &mut lin);
            (lin.task_cost, lin.regularisation_cost)
        };
        (0..n)
            .map(|i| {
                let mut delta = vec![0.0; n];
                delta[i] = h;
                let plus = costs(&delta);
                delta[i] = -h;
                let minus = costs(&delta);
                let numeric = (
                    (plus.0 - minus.0) / (2.0 * h),
                    (plus.1 - minus.1) / (2.0 * h),
                );
                (g[i], c[i], numeric)
            })
            .collect()
    }
}
