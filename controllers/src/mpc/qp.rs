//! The stage-wise QP of one SQP-RTI step, shared by both QP paths.
//!
//! ```text
//! min  Σ_{k<N} ½[x_k;u_k]ᵀ[Q_k S_kᵀ; S_k R_k][x_k;u_k] + q_kᵀx_k + r_kᵀu_k  + ½x_NᵀQ_Nx_N + q_Nᵀx_N
//! s.t. x_0 = x̄_0,   x_{k+1} = A x_k + B u_k + c_k,
//!      lower ≤ x_k[i] ≤ upper (i ∈ state_indices),  lower ≤ u_k[i] ≤ upper (i ∈ input_indices),
//!      lower ≤ g_jᵀ x_k ≤ upper (general rows on the state),
//!      lower ≤ e_jᵀ u_k ≤ upper (general rows on the input)
//! ```
//!
//! With a `soft_penalty` ρ the state rows (bounds and general rows on x_k, k ≥ 1) are soft:
//! each one-sided row `r(x) ≤ b` becomes `r(x) ≤ b + t`, `t ≥ 0`, and `ρ·Σt` is added to the
//! objective (an exact L1 penalty: when the hard QP is feasible and its multipliers are below
//! ρ, both have the same solution and every t is 0). The input rows stay hard.
//!
//! In an SQP step the variables are the deltas from the linearisation point. A and B do not
//! change between stages (the MPC's integrator is time-invariant); their sparsity is found once
//! and used by the Riccati solver.

use nalgebra::{SMatrix, SVector};
use serde::Serialize;

/// States.
pub const NX: usize = 16;
/// Inputs.
pub const NU: usize = 10;

/// A state vector.
pub type StateVector = SVector<f64, NX>;
/// An input vector.
pub type InputVector = SVector<f64, NU>;
/// NX × NX.
pub type StateMatrix = SMatrix<f64, NX, NX>;
/// NX × NU.
pub type StateInputMatrix = SMatrix<f64, NX, NU>;
/// NU × NX.
pub type InputStateMatrix = SMatrix<f64, NU, NX>;
/// NU × NU.
pub type InputMatrix = SMatrix<f64, NU, NU>;

/// The inequalities of one stage.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StageConstraints {
    /// Bounded state entries.
    pub state_indices: Vec<usize>,
    /// Their lower bounds.
    pub state_lower: Vec<f64>,
    /// Their upper bounds.
    pub state_upper: Vec<f64>,
    /// Bounded input entries.
    pub input_indices: Vec<usize>,
    /// Their lower bounds.
    pub input_lower: Vec<f64>,
    /// Their upper bounds.
    pub input_upper: Vec<f64>,
    /// General rows on the state, `lower ≤ gᵀx ≤ upper`.
    pub general: Vec<StateVector>,
    /// Their lower bounds.
    pub general_lower: Vec<f64>,
    /// Their upper bounds.
    pub general_upper: Vec<f64>,
    /// General rows on the input, `lower ≤ eᵀu ≤ upper`.
    pub input_general: Vec<InputVector>,
    /// Their lower bounds.
    pub input_general_lower: Vec<f64>,
    /// Their upper bounds.
    pub input_general_upper: Vec<f64>,
}

impl StageConstraints {
    /// Number of two-sided constraints.
    pub fn len(&self) -> usize {
        self.state_indices.len()
            + self.input_indices.len()
            + self.general.len()
            + self.input_general.len()
    }

    /// True without any constraint.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Same rows (indices and count), values aside.
    pub fn same_structure(&self, other: &Self) -> bool {
        self.state_indices == other.state_indices
            && self.input_indices == other.input_indices
            && self.general.len() == other.general.len()
            && self.input_general.len() == other.input_general.len()
    }

    /// Largest violation by (x, u) (u ignored when None), ≥ 0.
    pub fn violation(&self, x: &StateVector, u: Option<&InputVector>) -> f64 {
        let mut worst: f64 = 0.0;
        for (j, &i) in self.state_indices.iter().enumerate() {
            worst = worst
                .max(self.state_lower[j] - x[i])
                .max(x[i] - self.state_upper[j]);
        }
        if let Some(u) = u {
            for (j, &i) in self.input_indices.iter().enumerate() {
                worst = worst
                    .max(self.input_lower[j] - u[i])
                    .max(u[i] - self.input_upper[j]);
            }
            for (j, e) in self.input_general.iter().enumerate() {
                let v = e.dot(u);
                worst = worst
                    .max(self.input_general_lower[j] - v)
                    .max(v - self.input_general_upper[j]);
            }
        }
        for (j, g) in self.general.iter().enumerate() {
            let v = g.dot(x);
            worst = worst
                .max(self.general_lower[j] - v)
                .max(v - self.general_upper[j]);
        }
        worst
    }
}

/// A stage-wise QP (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct StructuredQp {
    /// Intervals N.
    pub intervals: usize,
    /// State transition (all stages).
    pub a: StateMatrix,
    /// Input matrix (all stages).
    pub b: StateInputMatrix,
    /// Defects c_k, k < N.
    pub defects: Vec<StateVector>,
    /// The fixed initial state x̄_0.
    pub x0: StateVector,
    /// Q_k, k ≤ N.
    pub q: Vec<StateMatrix>,
    /// S_k, k < N.
    pub s: Vec<InputStateMatrix>,
    /// R_k, k < N.
    pub r: Vec<InputMatrix>,
    /// q_k, k ≤ N.
    pub q_vec: Vec<StateVector>,
    /// r_k, k < N.
    pub r_vec: Vec<InputVector>,
    /// Inequalities of stage k ≤ N (stage N: state rows only; stage 0: its state is fixed, so
    /// its state rows are ignored).
    pub constraints: Vec<StageConstraints>,
    /// Weight ρ of the L1 penalty on the state rows' slacks (None: the state rows are hard).
    pub soft_penalty: Option<f64>,
}

impl StructuredQp {
    /// A QP with all data zero and no constraints.
    pub fn zeros(intervals: usize) -> Self {
        Self {
            intervals,
            a: StateMatrix::identity(),
            b: StateInputMatrix::zeros(),
            defects: vec![StateVector::zeros(); intervals],
            x0: StateVector::zeros(),
            q: vec![StateMatrix::zeros(); intervals + 1],
            s: vec![InputStateMatrix::zeros(); intervals],
            r: vec![InputMatrix::identity(); intervals],
            q_vec: vec![StateVector::zeros(); intervals + 1],
            r_vec: vec![InputVector::zeros(); intervals],
            constraints: vec![StageConstraints::default(); intervals + 1],
            soft_penalty: None,
        }
    }

    /// Number of soft rows (one-sided): two per state bound and general row of stages 1..N
    /// with a `soft_penalty`, none without.
    pub fn soft_rows(&self) -> usize {
        if self.soft_penalty.is_none() {
            return 0;
        }
        self.constraints
            .iter()
            .skip(1)
            .map(|c| 2 * (c.state_indices.len() + c.general.len()))
            .sum()
    }

    /// Same dimensions and constraint rows as `other` (what a solver built for one QP needs to
    /// take the other's values).
    pub fn same_structure(&self, other: &Self) -> bool {
        self.intervals == other.intervals
            && self.soft_penalty.is_some() == other.soft_penalty.is_some()
            && self
                .constraints
                .iter()
                .zip(&other.constraints)
                .all(|(a, b)| a.same_structure(b))
    }

    /// Objective value at (x, u).
    pub fn objective(&self, x: &[StateVector], u: &[InputVector]) -> f64 {
        let mut f = 0.0;
        for k in 0..self.intervals {
            f += 0.5 * x[k].dot(&(self.q[k] * x[k]))
                + u[k].dot(&(self.s[k] * x[k]))
                + 0.5 * u[k].dot(&(self.r[k] * u[k]))
                + self.q_vec[k].dot(&x[k])
                + self.r_vec[k].dot(&u[k]);
        }
        let n = self.intervals;
        f + 0.5 * x[n].dot(&(self.q[n] * x[n])) + self.q_vec[n].dot(&x[n])
    }

    /// Largest violation of the dynamics (and the initial state) by (x, u).
    pub fn dynamics_violation(&self, x: &[StateVector], u: &[InputVector]) -> f64 {
        let mut worst = (x[0] - self.x0).amax();
        for k in 0..self.intervals {
            let next = self.a * x[k] + self.b * u[k] + self.defects[k];
            worst = worst.max((x[k + 1] - next).amax());
        }
        worst
    }

    /// Largest inequality violation by (x, u) over stages 1..=N (stage 0 inputs included).
    pub fn inequality_violation(&self, x: &[StateVector], u: &[InputVector]) -> f64 {
        let mut worst: f64 = 0.0;
        for (k, c) in self.constraints.iter().enumerate() {
            let v = if k == 0 {
                let only_inputs = StageConstraints {
                    input_indices: c.input_indices.clone(),
                    input_lower: c.input_lower.clone(),
                    input_upper: c.input_upper.clone(),
                    input_general: c.input_general.clone(),
                    input_general_lower: c.input_general_lower.clone(),
                    input_general_upper: c.input_general_upper.clone(),
                    ..StageConstraints::default()
                };
                only_inputs.violation(&x[0], u.first())
            } else {
                c.violation(&x[k], u.get(k))
            };
            worst = worst.max(v);
        }
        worst
    }
}

/// How a QP solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum QpStatus {
    /// Converged to the tolerances.
    #[default]
    Solved,
    /// The iteration budget ran out first.
    MaxIterations,
    /// No feasible point (or the solver stalled on one it could not find).
    Infeasible,
    /// A factorisation failed or a value became non-finite.
    NumericalFailure,
}

/// A QP solution: states, inputs, and what it took.
#[derive(Debug, Clone, PartialEq)]
pub struct QpSolution {
    /// x_0..x_N.
    pub x: Vec<StateVector>,
    /// u_0..u_{N−1}.
    pub u: Vec<InputVector>,
    /// Slacks t ≥ 0 of the soft rows ([`StructuredQp::soft_rows`]), in row order: per stage
    /// 1..N, each state bound's lower then upper row, then each general row's lower then
    /// upper row. Empty without soft rows.
    pub slack: Vec<f64>,
    /// Interior-point iterations.
    pub iterations: u32,
    /// Outcome.
    pub status: QpStatus,
}

impl QpSolution {
    /// A zero solution for `intervals`.
    pub fn zeros(intervals: usize) -> Self {
        Self {
            x: vec![StateVector::zeros(); intervals + 1],
            u: vec![InputVector::zeros(); intervals],
            slack: Vec::new(),
            iterations: 0,
            status: QpStatus::Solved,
        }
    }

    /// Largest absolute difference to `other` over every state and input.
    pub fn max_difference(&self, other: &Self) -> f64 {
        let dx = self
            .x
            .iter()
            .zip(&other.x)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        let du = self
            .u
            .iter()
            .zip(&other.u)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        dx.max(du)
    }
}

/// A solver of [`StructuredQp`]s.
pub trait QpSolver: std::fmt::Debug + Send {
    /// Solves `qp` into `out` (always finite; on failure the status says so) and returns the
    /// status.
    fn solve(&mut self, qp: &StructuredQp, out: &mut QpSolution) -> QpStatus;

    /// `riccati` or `clarabel`.
    fn name(&self) -> &'static str;
}
