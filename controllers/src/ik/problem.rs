//! The least-squares problem: variables, residuals of both levels and their Jacobians.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6xX, UnitQuaternion, Vector3, Vector6};

use super::chain::{Chain, ChainPoses, Motion};
use super::config::{IkConfig, IkSolverSettings};
use crate::so3::left_jacobian_inverse;

/// A limit hinge becomes active only beyond this (m or rad). Without it a variable resting on
/// its bound flips the hinge row on and off with round-off, which changes the task nullspace
/// from one iteration to the next; the regularisation step's bound constraints hold such a
/// variable instead.
const HINGE_DEAD_ZONE: f64 = 1e-9;

/// A point of the search space: base pose and arm joints (command order).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct State {
    pub(crate) position: Vector3<f64>,
    pub(crate) rotation: UnitQuaternion<f64>,
    pub(crate) arm: Vec<f64>,
}

impl State {
    pub(crate) fn is_finite(&self) -> bool {
        self.position.iter().all(|v| v.is_finite())
            && self.rotation.coords.iter().all(|v| v.is_finite())
            && self.arm.iter().all(|v| v.is_finite())
    }

    /// Copies `other` into `self` without reallocating (same arm length).
    pub(crate) fn copy_from(&mut self, other: &Self) {
        self.position = other.position;
        self.rotation = other.rotation;
        self.arm.copy_from_slice(&other.arm);
    }

    /// |x| of the parameter tolerance: (position, unit quaternion, arm joints).
    pub(crate) fn norm(&self) -> f64 {
        (self.position.norm_squared() + 1.0 + self.arm.iter().map(|q| q * q).sum::<f64>()).sqrt()
    }
}

/// Which tangent entries are variables: free base position axes, free base rotation axes
/// (world frame), then the arm joints.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Layout {
    /// World axis of each base position variable.
    pub(crate) position_axes: Vec<usize>,
    /// World axis of each base rotation variable.
    pub(crate) orientation_axes: Vec<usize>,
    /// Variable of each world axis of the base position (None when locked).
    pub(crate) position_variable: [Option<usize>; 3],
    /// Index of the first arm joint variable.
    pub(crate) arm_offset: usize,
    /// Number of variables.
    pub(crate) n: usize,
}

impl Layout {
    pub(crate) fn new(config: &IkConfig, arm_dof: usize) -> Self {
        let position_axes: Vec<usize> = (0..3).filter(|&a| !config.fix_base_position[a]).collect();
        let orientation_axes: Vec<usize> = (0..3)
            .filter(|&a| !config.fix_base_orientation[a])
            .collect();
        let mut position_variable = [None; 3];
        for (i, &axis) in position_axes.iter().enumerate() {
            position_variable[axis] = Some(i);
        }
        let arm_offset = position_axes.len() + orientation_axes.len();
        Self {
            position_axes,
            orientation_axes,
            position_variable,
            arm_offset,
            n: arm_offset + arm_dof,
        }
    }
}

/// What stays fixed between solves: the vehicle's chain and the configuration.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Problem {
    pub(crate) config: IkConfig,
    pub(crate) chain: Chain,
    pub(crate) layout: Layout,
    /// Configuration index of each arm joint (command order).
    pub(crate) arm_dofs: Vec<usize>,
    /// The full configuration every non-arm joint keeps.
    pub(crate) held: Vec<f64>,
    /// Rest posture of the arm (command order).
    pub(crate) rest: Vec<f64>,
    /// The configured rest posture (`IkConfig::rest_posture`), which `rest` returns to.
    pub(crate) configured_rest: Vec<f64>,
    /// Arm joint limits (command order), ±∞ where unbounded.
    pub(crate) arm_lower: Vec<f64>,
    pub(crate) arm_upper: Vec<f64>,
    /// Most change of each arm joint from the previous solution in one solve (command order):
    /// its drive's velocity limit times the solve period, ∞ unless set
    /// (`WholeBodyIk::limit_joint_rates`).
    pub(crate) arm_step: Vec<f64>,
    /// Task-cost band within which the task level counts as met when a regularisation step
    /// is judged: the smaller of the costs of a position error at its tolerance and of an
    /// orientation error at its tolerance (inside the band both errors are within tolerance).
    pub(crate) task_tie: f64,
}

/// The target of one solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Target {
    pub(crate) position: Vector3<f64>,
    pub(crate) rotation: UnitQuaternion<f64>,
    /// R_targetᵀ as a matrix.
    pub(crate) rotation_transposed: Matrix3<f64>,
    /// Base position bounds per world axis, ±∞ where none.
    pub(crate) base_bounds: [(f64, f64); 3],
}

/// Costs, errors and Gauss–Newton terms of both levels at one state.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Linearization {
    /// Task cost C₁ = |r₁|².
    pub(crate) task_cost: f64,
    /// Regularisation cost C₂ = |r₂|².
    pub(crate) regularisation_cost: f64,
    pub(crate) position_error_m: f64,
    pub(crate) orientation_error_rad: f64,
    pub(crate) limit_violation: f64,
    /// Weighted pose Jacobian (6 × n), rows [position; orientation].
    pub(crate) jacobian: Matrix6xX<f64>,
    /// Active limit hinges: (variable, slope ±w) of each J₁ row beyond the pose rows.
    pub(crate) hinges: Vec<(usize, f64)>,
    /// J₁ᵀr₁.
    pub(crate) g: DVector<f64>,
    /// J₂ᵀJ₂.
    pub(crate) b: DMatrix<f64>,
    /// J₂ᵀr₂.
    pub(crate) c: DVector<f64>,
}

impl Linearization {
    pub(crate) fn new(n: usize) -> Self {
        Self {
            task_cost: 0.0,
            regularisation_cost: 0.0,
            position_error_m: 0.0,
            orientation_error_rad: 0.0,
            limit_violation: 0.0,
            jacobian: Matrix6xX::zeros(n),
            hinges: Vec::with_capacity(n),
            g: DVector::zeros(n),
            b: DMatrix::zeros(n, n),
            c: DVector::zeros(n),
        }
    }

    /// J₁ᵀJ₁ + λI (pose rows and active hinges) into `out`.
    pub(crate) fn damped_normal_matrix(&self, lambda: f64, out: &mut DMatrix<f64>) {
        self.jacobian.tr_mul_to(&self.jacobian, out);
        for &(i, slope) in &self.hinges {
            out[(i, i)] += slope * slope;
        }
        for i in 0..out.nrows() {
            out[(i, i)] += lambda;
        }
    }

    /// The pose is met and the limits respected, within the solver's tolerances.
    pub(crate) fn meets(&self, s: &IkSolverSettings) -> bool {
        self.position_error_m <= s.pose_position_tolerance_m
            && self.orientation_error_rad <= s.pose_orientation_tolerance_rad
            && self.limit_violation <= s.limit_tolerance
    }

    pub(crate) fn is_finite(&self) -> bool {
        self.task_cost.is_finite()
            && self.regularisation_cost.is_finite()
            && self.g.iter().all(|v| v.is_finite())
            && self.c.iter().all(|v| v.is_finite())
    }
}

/// Weighted pose residual r_pose = [w_pos(p_ee − p_t); w_ori·log(R_tᵀR_ee)] at `x`, with its
/// Jacobian written into `jacobian`; also returns the unweighted errors' norms.
pub(crate) fn pose_residual(
    p: &Problem,
    x: &State,
    target: &Target,
    poses: &mut ChainPoses,
    jacobian: &mut Matrix6xX<f64>,
) -> (Vector6<f64>, f64, f64) {
    let w = &p.config.weights;
    let l = &p.layout;
    p.chain.evaluate(&x.arm, poses);
    let base_from_ee = poses.base_from_ee.translation.vector;
    let lever = x.rotation * base_from_ee; // p_ee − p_base, world
    let ee_rotation = x.rotation * poses.base_from_ee.rotation;
    let position_error = x.position + lever - target.position;
    let orientation_error = (target.rotation.inverse() * ee_rotation).scaled_axis();
    // Every variable turns the EE by a world-frame (left) increment ω: R_ee ← exp(ω)·R_ee, so
    // the orientation residual moves by J_l⁻¹(e)·R_targetᵀ·ω.
    let to_residual =
        left_jacobian_inverse(&orientation_error) * target.rotation_transposed * w.pose_orientation;
    let mut set_column = |col: usize, linear: Vector3<f64>, angular: Vector3<f64>| {
        let lin = linear * w.pose_position;
        let ang = to_residual * angular;
        for r in 0..3 {
            jacobian[(r, col)] = lin[r];
            jacobian[(r + 3, col)] = ang[r];
        }
    };
    for (i, &axis) in l.position_axes.iter().enumerate() {
        set_column(i, Vector3::ith(axis, 1.0), Vector3::zeros());
    }
    for (i, &axis) in l.orientation_axes.iter().enumerate() {
        let e = Vector3::ith(axis, 1.0);
        set_column(l.position_axes.len() + i, e.cross(&lever), e);
    }
    for (k, joint) in p.chain.joints.iter().enumerate() {
        let axis = x.rotation * poses.axes[k];
        let col = l.arm_offset + joint.arm_index;
        match joint.motion {
            Motion::Rotation => {
                let arm_lever = x.rotation * (base_from_ee - poses.origins[k]);
                set_column(col, axis.cross(&arm_lever), axis);
            }
            Motion::Translation => set_column(col, axis, Vector3::zeros()),
        }
    }
    let mut r = Vector6::zeros();
    r.fixed_rows_mut::<3>(0)
        .copy_from(&(position_error * w.pose_position));
    r.fixed_rows_mut::<3>(3)
        .copy_from(&(orientation_error * w.pose_orientation));
    (r, position_error.norm(), orientation_error.norm())
}

impl Problem {
    /// Where arm joint `k` may go in a solve anchored at `anchor`: its limits, narrowed to
    /// the step its drive can make in one period from the previous solution.
    pub(crate) fn arm_bounds(&self, k: usize, anchor: &State) -> (f64, f64) {
        let step = self.arm_step[k];
        (
            self.arm_lower[k].max(anchor.arm[k] - step),
            self.arm_upper[k].min(anchor.arm[k] + step),
        )
    }
}

/// Costs, errors and Gauss–Newton terms of both levels at `x`, into `out`.
pub(crate) fn linearize(
    p: &Problem,
    x: &State,
    target: &Target,
    anchor: &State,
    poses: &mut ChainPoses,
    out: &mut Linearization,
) {
    let w = &p.config.weights;
    let l = &p.layout;

    // Task level: pose.
    let (r_pose, position_error, orientation_error) =
        pose_residual(p, x, target, poses, &mut out.jacobian);
    out.position_error_m = position_error;
    out.orientation_error_rad = orientation_error;
    out.task_cost = r_pose.norm_squared();
    out.jacobian.tr_mul_to(&r_pose, &mut out.g);

    // Task level: limit hinges. A locked base axis still pays its hinge but has no column.
    let mut violation: f64 = 0.0;
    let mut task_cost = out.task_cost;
    out.hinges.clear();
    let mut hinge = |value: f64, (lo, hi): (f64, f64), weight: f64, var: Option<usize>| {
        let (r, slope) = if value > hi + HINGE_DEAD_ZONE {
            (weight * (value - hi), weight)
        } else if value < lo - HINGE_DEAD_ZONE {
            (weight * (lo - value), -weight)
        } else {
            return;
        };
        violation = violation.max(r / weight);
        task_cost += r * r;
        if let Some(i) = var {
            out.g[i] += slope * r;
            out.hinges.push((i, slope));
        }
    };
    for axis in 0..3 {
        hinge(
            x.position[axis],
            target.base_bounds[axis],
            w.base_position_limit,
            l.position_variable[axis],
        );
    }
    for k in 0..p.arm_dofs.len() {
        hinge(
            x.arm[k],
            p.arm_bounds(k, anchor),
            w.joint_limit,
            Some(l.arm_offset + k),
        );
    }
    out.task_cost = task_cost;
    out.limit_violation = violation;

    // Regularisation level.
    out.b.fill(0.0);
    out.c.fill(0.0);
    let mut cost = 0.0;
    let wp = w.smoothness_base_position;
    for axis in 0..3 {
        let r = wp * (x.position[axis] - anchor.position[axis]);
        cost += r * r;
        if let Some(i) = l.position_variable[axis] {
            out.b[(i, i)] += wp * wp;
            out.c[i] += wp * r;
        }
    }
    let wo = w.smoothness_base_orientation;
    let base_error = (x.rotation * anchor.rotation.inverse()).scaled_axis();
    let r_base = base_error * wo;
    cost += r_base.norm_squared();
    if !l.orientation_axes.is_empty() {
        let jb = left_jacobian_inverse(&base_error) * wo;
        let first = l.position_axes.len();
        for (i, &ai) in l.orientation_axes.iter().enumerate() {
            out.c[first + i] += jb.column(ai).dot(&r_base);
            for (j, &aj) in l.orientation_axes.iter().enumerate() {
                out.b[(first + i, first + j)] += jb.column(ai).dot(&jb.column(aj));
            }
        }
    }
    let (wj, wr) = (w.smoothness_joints, w.rest_arm);
    for k in 0..p.arm_dofs.len() {
        let i = l.arm_offset + k;
        let rs = wj * (x.arm[k] - anchor.arm[k]);
        let rr = wr * (x.arm[k] - p.rest[k]);
        cost += rs * rs + rr * rr;
        out.b[(i, i)] += wj * wj + wr * wr;
        out.c[i] += wj * rs + wr * rr;
    }
    out.regularisation_cost = cost;
}

/// x ⊕ δ: base position += δ_p, base rotation ← exp(δ_θ)·R (world frame), arm += δ_q.
pub(crate) fn retract(layout: &Layout, x: &State, delta: &[f64], out: &mut State) {
    out.position = x.position;
    for (i, &axis) in layout.position_axes.iter().enumerate() {
        out.position[axis] += delta[i];
    }
    out.rotation = if layout.orientation_axes.is_empty() {
        x.rotation
    } else {
        let mut omega = Vector3::zeros();
        for (i, &axis) in layout.orientation_axes.iter().enumerate() {
            omega[axis] = delta[layout.position_axes.len() + i];
        }
        UnitQuaternion::from_scaled_axis(omega) * x.rotation
    };
    for (k, (o, &q)) in out.arm.iter_mut().zip(&x.arm).enumerate() {
        *o = q + delta[layout.arm_offset + k];
    }
}

/// The coordinate of variable `i` that its bounds apply to (base position axis or arm joint;
/// rotation variables have none and give 0).
pub(crate) fn bounded_value(layout: &Layout, x: &State, i: usize) -> f64 {
    if i < layout.position_axes.len() {
        x.position[layout.position_axes[i]]
    } else if i < layout.arm_offset {
        0.0
    } else {
        x.arm[i - layout.arm_offset]
    }
}
