//! One Levenberg–Marquardt iteration of the two-level problem: the decomposition of the task
//! Jacobian, the task and regularisation steps, the second-order correction and the step test.
//! The iteration's buffers are allocated once, in [`Workspace::new`]; the decompositions
//! (nalgebra's SVD and Cholesky, see `linalg`) allocate their own small matrices per call.

use nalgebra::{Cholesky, DMatrix, DVector, DVectorViewMut, Dyn, Vector6};

use super::chain::ChainPoses;
use super::linalg::{cholesky, split_range_and_nullspace};
use super::problem::{Linearization, Problem, State, Target, bounded_value, linearize, retract};

/// Displacements (m or rad) below this count as not crossing a bound.
const BOUND_CROSSING_SLACK: f64 = 1e-12;
/// A variable whose row of the nullspace basis is shorter than this is not held on its bound by
/// the regularisation step (moving it would take a disproportionate step).
const NULLSPACE_PARTICIPATION_MIN: f64 = 1e-3;
/// Relative ridge on the bound-constraint Schur complement (guards dependent constraints).
const CONSTRAINT_RIDGE: f64 = 1e-12;
/// Relative round-off slack of the step test's cost comparisons.
const ROUND_OFF: f64 = 1e-12;
/// Step (m or rad) of the finite differences of the Lagrangian's gradient along the nullspace.
const CURVATURE_PROBE: f64 = 1e-6;
/// A variable this close to its bound (m or rad) counts as on it in the task correction.
const AT_BOUND: f64 = 1e-9;
/// Relative diagonal weight that freezes an on-bound variable in the task correction.
const FREEZE: f64 = 1e8;
/// The probed Hessian of the Lagrangian is reused while the iterate stays within this
/// distance (|Δp| m + rotation angle rad + Σ|Δq| rad) of where it was probed.
const HESSIAN_REUSE_RADIUS: f64 = 1e-2;
/// A task correction is evaluated only if its model predicts at least this fraction of the
/// task cost away.
const CORRECTION_MIN_PREDICTED_GAIN: f64 = 0.5;
/// Most attempts at a damping that makes the regularisation's reduced Hessian positive definite.
const MAX_DAMPING_INCREASES: usize = 30;

/// Preallocated buffers of the iteration.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Workspace {
    pub(crate) poses: ChainPoses,
    /// The iterate, its linearization, and the candidates of the current iteration.
    pub(crate) state: State,
    pub(crate) current: Linearization,
    pub(crate) trial_state: State,
    pub(crate) trial: Linearization,
    pub(crate) corrected_state: State,
    pub(crate) corrected: Linearization,
    /// A probe point of the Hessian's finite differences and its linearization.
    probe_state: State,
    probe: Linearization,
    /// The active hinge set (variables) of the last decomposition of J₁.
    decomposed_hinges: Vec<usize>,
    /// Right singular vectors of J₁ spanning the range of J₁ᵀ (first `range_count` columns),
    /// σ² and v_iᵀg of each.
    range_v: DMatrix<f64>,
    range_count: usize,
    range_sigma2: Vec<f64>,
    range_gradient: Vec<f64>,
    /// Nullspace basis N (the other right singular vectors) in the first `null_count` columns.
    null: DMatrix<f64>,
    pub(crate) null_count: usize,
    /// B·N.
    b_null: DMatrix<f64>,
    /// Nᵀ∇²L N, the Hessian of the Lagrangian on the nullspace.
    reduced_hessian: DMatrix<f64>,
    /// The last probed reduced Hessian, the nullspace basis it was probed on (first
    /// `hessian_count` columns), where, and Q = NᵀN₀ to carry it over to a new basis.
    hessian_probed: DMatrix<f64>,
    hessian_basis: DMatrix<f64>,
    hessian_count: usize,
    hessian_state: State,
    hessian_valid: bool,
    basis_change: DMatrix<f64>,
    /// ∇L at the iterate and at a probe (n).
    gradient_base: DVector<f64>,
    gradient_probe: DVector<f64>,
    /// Nᵀc, the regularisation gradient on the nullspace.
    pub(crate) null_gradient: Vec<f64>,
    /// M⁻¹Cᵀ of the bound constraints of the regularisation step (M its normal matrix).
    m_inv_ct: DMatrix<f64>,
    /// Task correction's normal matrix.
    restoration: DMatrix<f64>,
    /// Variable bounds (±∞ where none) and the values after the task step.
    pub(crate) lower: Vec<f64>,
    pub(crate) upper: Vec<f64>,
    values: Vec<f64>,
    /// Bound constraints of the regularisation step: (variable, displacement along N z).
    constraints: Vec<(usize, f64)>,
    delta1: Vec<f64>,
    pub(crate) delta: Vec<f64>,
    z0: Vec<f64>,
    z: Vec<f64>,
    scratch: Vec<f64>,
}

impl Workspace {
    pub(crate) fn new(p: &Problem, seed: &State) -> Self {
        let n = p.layout.n;
        Self {
            poses: p.chain.poses_buffer(),
            state: seed.clone(),
            current: Linearization::new(n),
            trial_state: seed.clone(),
            trial: Linearization::new(n),
            corrected_state: seed.clone(),
            corrected: Linearization::new(n),
            probe_state: seed.clone(),
            probe: Linearization::new(n),
            decomposed_hinges: Vec::with_capacity(n),
            range_v: DMatrix::zeros(n, n),
            range_count: 0,
            range_sigma2: vec![0.0; n],
            range_gradient: vec![0.0; n],
            null: DMatrix::zeros(n, n),
            null_count: 0,
            b_null: DMatrix::zeros(n, n),
            reduced_hessian: DMatrix::zeros(n, n),
            hessian_probed: DMatrix::zeros(n, n),
            hessian_basis: DMatrix::zeros(n, n),
            hessian_count: 0,
            hessian_state: seed.clone(),
            hessian_valid: false,
            basis_change: DMatrix::zeros(n, n),
            gradient_base: DVector::zeros(n),
            gradient_probe: DVector::zeros(n),
            null_gradient: vec![0.0; n],
            m_inv_ct: DMatrix::zeros(n, n),
            restoration: DMatrix::zeros(n, n),
            lower: vec![0.0; n],
            upper: vec![0.0; n],
            values: vec![0.0; n],
            constraints: Vec::with_capacity(n),
            delta1: vec![0.0; n],
            delta: vec![0.0; n],
            z0: vec![0.0; n],
            z: vec![0.0; n],
            scratch: vec![0.0; n],
        }
    }

    /// Fills the variable bounds: base position variables from the call's limits, arm joints
    /// from their limits and rate steps around `anchor`, rotation variables unbounded.
    pub(crate) fn set_bounds(&mut self, p: &Problem, target: &Target, anchor: &State) {
        let l = &p.layout;
        for (i, &axis) in l.position_axes.iter().enumerate() {
            (self.lower[i], self.upper[i]) = target.base_bounds[axis];
        }
        for i in l.position_axes.len()..l.arm_offset {
            self.lower[i] = f64::NEG_INFINITY;
            self.upper[i] = f64::INFINITY;
        }
        for k in 0..p.arm_dofs.len() {
            (self.lower[l.arm_offset + k], self.upper[l.arm_offset + k]) = p.arm_bounds(k, anchor);
        }
    }

    /// Largest |Nᵀc| entry: the regularisation gradient left on the task nullspace.
    pub(crate) fn null_gradient_max(&self) -> f64 {
        self.null_gradient[..self.null_count]
            .iter()
            .fold(0.0, |m, v| m.max(v.abs()))
    }

    /// Singular-value decomposition of J₁ at the current state, and the reduced regularisation
    /// problem on its nullspace (gradient, and Hessian of the Lagrangian). False on a
    /// numerical failure.
    pub(crate) fn decompose(
        &mut self,
        p: &Problem,
        target: &Target,
        anchor: &State,
        fresh: bool,
    ) -> bool {
        let n = p.layout.n;
        let ratio = p.config.solver.nullspace_singular_value_ratio;
        // Rows of J₁: the six pose rows, then one per active hinge (slope on its variable).
        let hinges = &self.current.hinges;
        let m = 6 + hinges.len();
        if hinges
            .iter()
            .map(|h| h.0)
            .ne(self.decomposed_hinges.iter().copied())
        {
            // Another row set, so another nullspace: the probed Hessian is not for it.
            self.hessian_valid = false;
            self.decomposed_hinges.clear();
            self.decomposed_hinges.extend(hinges.iter().map(|h| h.0));
        }
        // J₁, with zero rows up to n so that the SVD yields all n right singular vectors.
        let mut j1 = DMatrix::zeros(m.max(n), n);
        j1.rows_mut(0, 6).copy_from(&self.current.jacobian);
        for (h, &(var, slope)) in hinges.iter().enumerate() {
            j1[(6 + h, var)] = slope;
        }
        let Some((range_count, null_count)) = split_range_and_nullspace(
            j1,
            ratio,
            &mut self.range_v,
            &mut self.range_sigma2,
            &mut self.null,
        ) else {
            return false;
        };
        (self.range_count, self.null_count) = (range_count, null_count);
        for slot in 0..range_count {
            self.range_gradient[slot] = self.range_v.column(slot).dot(&self.current.g);
        }
        let k = self.null_count;
        self.b_null
            .columns_mut(0, k)
            .gemm(1.0, &self.current.b, &self.null.columns(0, k), 0.0);
        for j in 0..k {
            self.null_gradient[j] = self.null.column(j).dot(&self.current.c);
        }
        // The Hessian of the Lagrangian changes slowly: probe it at the first decomposition of
        // a solve (its anchor is new) and whenever the iterate has moved away from where it
        // was probed; otherwise carry it over to the new nullspace basis.
        let moved = (self.state.position - self.hessian_state.position).norm()
            + self.state.rotation.angle_to(&self.hessian_state.rotation)
            + self
                .state
                .arm
                .iter()
                .zip(&self.hessian_state.arm)
                .map(|(a, b)| (a - b).abs())
                .sum::<f64>();
        if fresh || moved > HESSIAN_REUSE_RADIUS || !self.hessian_valid {
            self.reduced_hessian_of_lagrangian(p, target, anchor);
            self.hessian_basis
                .columns_mut(0, k)
                .copy_from(&self.null.columns(0, k));
            self.hessian_probed
                .view_mut((0, 0), (k, k))
                .copy_from(&self.reduced_hessian.view((0, 0), (k, k)));
            self.hessian_count = k;
            self.hessian_state.copy_from(&self.state);
            self.hessian_valid = true;
        } else {
            self.carry_hessian_over();
        }
        true
    }

    /// H ← Q·H₀·Qᵀ, Q = NᵀN₀: the probed reduced Hessian moved to the current nullspace basis.
    fn carry_hessian_over(&mut self) {
        let (k, k0) = (self.null_count, self.hessian_count);
        self.basis_change.view_mut((0, 0), (k, k0)).gemm_tr(
            1.0,
            &self.null.columns(0, k),
            &self.hessian_basis.columns(0, k0),
            0.0,
        );
        for i in 0..k {
            for j in i..k {
                let mut v = 0.0;
                for a in 0..k0 {
                    for b in 0..k0 {
                        v += self.basis_change[(i, a)]
                            * self.hessian_probed[(a, b)]
                            * self.basis_change[(j, b)];
                    }
                }
                self.reduced_hessian[(i, j)] = v;
                self.reduced_hessian[(j, i)] = v;
            }
        }
    }

    /// H = Nᵀ∇²L N, the Hessian of the Lagrangian L = C₂/2 + νᵀr₁ on the nullspace, by
    /// finite differences of ∇L = J₂ᵀr₂ + J₁ᵀν along each nullspace direction.
    /// ν = −J_pose·(J₁ᵀJ₁)⁺c are the multipliers with which the pose holds the
    /// regularisation's pull (J₁ᵀν = −c on the range). The Gauss–Newton term NᵀBN alone misses
    /// the curvature of the task's solution set (νᵢ∇²r₁ᵢ) and of the rotation residuals; a
    /// step along the tangent nullspace then mispredicts the regularisation cost on the curved
    /// set and the iteration converges only linearly.
    fn reduced_hessian_of_lagrangian(&mut self, p: &Problem, target: &Target, anchor: &State) {
        let n = p.layout.n;
        let (k, r) = (self.null_count, self.range_count);
        if k == 0 {
            return;
        }
        // (J₁ᵀJ₁)⁺c = Σ v_i (v_iᵀc)/σ_i² over the range, then ν = −J_pose·(J₁ᵀJ₁)⁺c.
        let coefficients = &mut self.gradient_probe;
        coefficients.fill(0.0);
        for slot in 0..r {
            coefficients[slot] =
                self.range_v.column(slot).dot(&self.current.c) / self.range_sigma2[slot];
        }
        self.gradient_base.gemv(
            1.0,
            &self.range_v.columns(0, r),
            &coefficients.rows(0, r),
            0.0,
        );
        let multipliers: Vector6<f64> = -(&self.current.jacobian * &self.gradient_base);
        // ∇L at x.
        self.gradient_base.copy_from(&self.current.c);
        self.gradient_base
            .gemv_tr(1.0, &self.current.jacobian, &multipliers, 1.0);
        for j in 0..k {
            for row in 0..n {
                self.scratch[row] = CURVATURE_PROBE * self.null[(row, j)];
            }
            retract(
                &p.layout,
                &self.state,
                &self.scratch[..n],
                &mut self.probe_state,
            );
            linearize(
                p,
                &self.probe_state,
                target,
                anchor,
                &mut self.poses,
                &mut self.probe,
            );
            // h = (∇L(x ⊕ εN_j) − ∇L(x)) / ε, then H_ij = N_iᵀh.
            self.gradient_probe.copy_from(&self.probe.c);
            self.gradient_probe
                .gemv_tr(1.0, &self.probe.jacobian, &multipliers, 1.0);
            self.gradient_probe -= &self.gradient_base;
            for i in 0..k {
                self.reduced_hessian[(i, j)] =
                    self.null.column(i).dot(&self.gradient_probe) / CURVATURE_PROBE;
            }
        }
        for i in 0..k {
            for j in i + 1..k {
                let v = 0.5 * (self.reduced_hessian[(i, j)] + self.reduced_hessian[(j, i)]);
                self.reduced_hessian[(i, j)] = v;
                self.reduced_hessian[(j, i)] = v;
            }
        }
    }

    /// Computes the step δ = δ₁ + N·z at dampings `lambda` (task) and `mu` (regularisation)
    /// into `delta`; returns the task-cost decrease predicted for δ₁.
    pub(crate) fn step(&mut self, p: &Problem, lambda: f64, mu: f64) -> f64 {
        let n = p.layout.n;
        // Task level: δ₁ = −Σ v_i (v_iᵀg)/(σ_i² + λ) over the range.
        self.delta1[..n].fill(0.0);
        let mut predicted = 0.0;
        for slot in 0..self.range_count {
            let sigma2 = self.range_sigma2[slot];
            let gi = self.range_gradient[slot];
            let coefficient = gi / (sigma2 + lambda);
            for r in 0..n {
                self.delta1[r] -= coefficient * self.range_v[(r, slot)];
            }
            // |r + Jδ|² = C − Σ g̃²(σ² + 2λ)/(σ² + λ)² along the singular vectors.
            predicted += gi * gi * (sigma2 + 2.0 * lambda) / (sigma2 + lambda).powi(2);
        }
        self.delta[..n].copy_from_slice(&self.delta1[..n]);
        let k = self.null_count;
        self.z[..k].fill(0.0);
        if k == 0 {
            return predicted;
        }

        // Regularisation level on the nullspace: (H + (μ + ρ)I) z = −Nᵀ(B δ₁ + c). H may be
        // indefinite (the regularisation is not convex on a curved set): raise the damping until
        // it factors.
        let scale = (0..k)
            .map(|i| self.reduced_hessian[(i, i)].abs())
            .fold(0.0, f64::max);
        let mut damping = mu + p.config.solver.nullspace_ridge;
        let mut factor = None;
        for _ in 0..MAX_DAMPING_INCREASES {
            let mut m = self.reduced_hessian.view((0, 0), (k, k)).clone_owned();
            for i in 0..k {
                m[(i, i)] += damping;
            }
            factor = cholesky(m);
            if factor.is_some() {
                break;
            }
            damping = 4.0 * damping + 1e-3 * scale;
        }
        let Some(factor) = factor else {
            return predicted;
        };
        for i in 0..k {
            let b_delta1: f64 = (0..n).map(|r| self.b_null[(r, i)] * self.delta1[r]).sum();
            self.z0[i] = -(b_delta1 + self.null_gradient[i]);
        }
        factor.solve_mut(&mut DVectorViewMut::from_slice(&mut self.z0[..k], k));
        self.z[..k].copy_from_slice(&self.z0[..k]);
        self.hold_bounds(p, &factor);
        for r in 0..n {
            self.delta[r] += (0..k).map(|j| self.null[(r, j)] * self.z[j]).sum::<f64>();
        }
        predicted
    }

    /// The regularisation must not push a bounded variable across its limit (the task level
    /// owns the limits), and may use the nullspace to bring back one the task step pushed out:
    /// the first bound the step would hit becomes an equality `(N z)_i = t_i` that lands the
    /// variable on it, z is re-solved, and so on until no bound is crossed.
    fn hold_bounds(&mut self, p: &Problem, factor: &Cholesky<f64, Dyn>) {
        let n = p.layout.n;
        let k = self.null_count;
        for i in 0..n {
            self.values[i] = bounded_value(&p.layout, &self.state, i) + self.delta1[i];
        }
        self.constraints.clear();
        for _ in 0..n {
            let mut first: Option<(f64, usize, f64)> = None;
            for i in 0..n {
                if self.constraints.iter().any(|&(v, _)| v == i) {
                    continue;
                }
                let participation: f64 = (0..k).map(|j| self.null[(i, j)].powi(2)).sum();
                if participation < NULLSPACE_PARTICIPATION_MIN * NULLSPACE_PARTICIPATION_MIN {
                    continue;
                }
                let d: f64 = (0..k).map(|j| self.null[(i, j)] * self.z[j]).sum();
                let (y, lo, hi) = (self.values[i], self.lower[i], self.upper[i]);
                let hit = if y > hi + BOUND_CROSSING_SLACK {
                    Some((0.0, hi - y))
                } else if y < lo - BOUND_CROSSING_SLACK {
                    Some((0.0, lo - y))
                } else if y + d > hi + BOUND_CROSSING_SLACK {
                    Some(((hi - y) / d, hi - y))
                } else if y + d < lo - BOUND_CROSSING_SLACK {
                    Some(((lo - y) / d, lo - y))
                } else {
                    None
                };
                if let Some((fraction, target)) = hit
                    && first.is_none_or(|(f, _, _)| fraction < f)
                {
                    first = Some((fraction, i, target));
                }
            }
            let Some((_, var, target)) = first else {
                break;
            };
            self.constraints.push((var, target));
            if !self.constrained_solve(k, factor) {
                self.z[..k].fill(0.0);
                break;
            }
        }
    }

    /// z = z₀ − M⁻¹Cᵀ(C M⁻¹ Cᵀ)⁻¹(C z₀ − t): the least change of the regularisation step that
    /// meets the equality constraints (rows C_i = N_i of the constrained variables), with
    /// `factor` the Cholesky factor of M. False if the constraints are degenerate.
    fn constrained_solve(&mut self, k: usize, factor: &Cholesky<f64, Dyn>) -> bool {
        let nc = self.constraints.len();
        let mut m_inv_ct = self.m_inv_ct.view_mut((0, 0), (k, nc));
        for (col, &(var, _)) in self.constraints.iter().enumerate() {
            for j in 0..k {
                m_inv_ct[(j, col)] = self.null[(var, j)];
            }
        }
        factor.solve_mut(&mut m_inv_ct);
        let mut s = DMatrix::zeros(nc, nc);
        let mut largest: f64 = 0.0;
        for (a, &(va, ta)) in self.constraints.iter().enumerate() {
            for b in 0..nc {
                s[(a, b)] = (0..k)
                    .map(|j| self.null[(va, j)] * self.m_inv_ct[(j, b)])
                    .sum();
            }
            largest = largest.max(s[(a, a)]);
            self.scratch[a] = (0..k).map(|j| self.null[(va, j)] * self.z0[j]).sum::<f64>() - ta;
        }
        for a in 0..nc {
            s[(a, a)] += CONSTRAINT_RIDGE * largest + f64::MIN_POSITIVE;
        }
        let Some(s_factor) = cholesky(s) else {
            return false;
        };
        s_factor.solve_mut(&mut DVectorViewMut::from_slice(&mut self.scratch[..nc], nc));
        for j in 0..k {
            self.z[j] = self.z0[j]
                - (0..nc)
                    .map(|b| self.m_inv_ct[(j, b)] * self.scratch[b])
                    .sum::<f64>();
        }
        true
    }

    /// Predicted regularisation-cost decrease of the step on the task's solution set:
    /// −(2cᵀδ + δ₁ᵀBδ₁ + 2zᵀ(BN)ᵀδ₁ + zᵀHz), δ = δ₁ + Nz.
    pub(crate) fn predicted_regularisation_decrease(&self, n: usize) -> f64 {
        let lin = &self.current;
        let k = self.null_count;
        let mut linear = 0.0;
        let mut quadratic = 0.0;
        for i in 0..n {
            linear += lin.c[i] * self.delta[i];
            let bd: f64 = (0..n).map(|j| lin.b[(i, j)] * self.delta1[j]).sum();
            quadratic += self.delta1[i] * bd;
        }
        for i in 0..k {
            let cross: f64 = (0..n).map(|r| self.b_null[(r, i)] * self.delta1[r]).sum();
            quadratic += 2.0 * self.z[i] * cross;
            for j in 0..k {
                quadratic += self.z[i] * self.reduced_hessian[(i, j)] * self.z[j];
            }
        }
        -(2.0 * linear + quadratic)
    }

    /// True when the step has a regularisation part (z ≠ 0).
    pub(crate) fn has_null_step(&self) -> bool {
        self.z[..self.null_count].iter().any(|v| v.abs() > 0.0)
    }

    /// Evaluates the trial point x ⊕ δ into `trial_state` / `trial`.
    pub(crate) fn evaluate_trial(&mut self, p: &Problem, target: &Target, anchor: &State) {
        retract(&p.layout, &self.state, &self.delta, &mut self.trial_state);
        linearize(
            p,
            &self.trial_state,
            target,
            anchor,
            &mut self.poses,
            &mut self.trial,
        );
    }

    /// A task-level Gauss–Newton correction from the trial point, δ_c = −(A + λI)⁻¹g with A, g
    /// of the trial's linearization; the corrected point replaces the trial if its task cost is
    /// not higher. False if nothing was replaced.
    pub(crate) fn correct_trial(
        &mut self,
        p: &Problem,
        target: &Target,
        anchor: &State,
        lambda: f64,
    ) -> bool {
        let n = p.layout.n;
        self.trial
            .damped_normal_matrix(lambda, &mut self.restoration);
        let scale = (0..n).map(|i| self.restoration[(i, i)]).fold(1.0, f64::max);
        for i in 0..n {
            self.scratch[i] = -self.trial.g[i];
            // A variable on (or past) its bound stays put: the correction must not trade the
            // pose error for a limit violation. The next iteration may move it inward.
            let value = bounded_value(&p.layout, &self.trial_state, i);
            if value >= self.upper[i] - AT_BOUND || value <= self.lower[i] + AT_BOUND {
                self.restoration[(i, i)] += FREEZE * scale;
            }
        }
        let Some(factor) = cholesky(self.restoration.clone()) else {
            return false;
        };
        factor.solve_mut(&mut DVectorViewMut::from_slice(&mut self.scratch[..n], n));
        // The model predicts a decrease between −gᵀδ and −2gᵀδ: skip the evaluation when even
        // the larger is a small part of the cost (what is left is beyond Gauss–Newton's reach,
        // e.g. along a near-singular direction).
        let predicted: f64 = -2.0
            * (0..n)
                .map(|i| self.trial.g[i] * self.scratch[i])
                .sum::<f64>();
        if predicted < CORRECTION_MIN_PREDICTED_GAIN * self.trial.task_cost {
            return false;
        }
        retract(
            &p.layout,
            &self.trial_state,
            &self.scratch[..n],
            &mut self.corrected_state,
        );
        linearize(
            p,
            &self.corrected_state,
            target,
            anchor,
            &mut self.poses,
            &mut self.corrected,
        );
        if !(self.corrected.is_finite() && self.corrected.task_cost <= self.trial.task_cost) {
            return false;
        }
        std::mem::swap(&mut self.trial_state, &mut self.corrected_state);
        std::mem::swap(&mut self.trial, &mut self.corrected);
        true
    }

    /// A task-level correction of the iterate itself (the final polish); true if it lowered
    /// the task cost.
    pub(crate) fn polish(
        &mut self,
        p: &Problem,
        target: &Target,
        anchor: &State,
        lambda: f64,
    ) -> bool {
        // Run the trial correction on a copy of the iterate.
        self.trial_state.copy_from(&self.state);
        std::mem::swap(&mut self.trial, &mut self.current);
        let before = self.trial.task_cost;
        let replaced = self.correct_trial(p, target, anchor, lambda);
        if replaced && self.trial.task_cost < before {
            self.accept_trial();
            true
        } else {
            // The iterate's linearization is in `corrected` if the trial was replaced, else
            // still in `trial`.
            if replaced {
                std::mem::swap(&mut self.current, &mut self.corrected);
            } else {
                std::mem::swap(&mut self.current, &mut self.trial);
            }
            false
        }
    }

    /// Makes the trial the iterate.
    pub(crate) fn accept_trial(&mut self) {
        std::mem::swap(&mut self.state, &mut self.trial_state);
        std::mem::swap(&mut self.current, &mut self.trial);
    }

    /// The step test of the trial against the iterate.
    pub(crate) fn judge(&self, p: &Problem, predicted: f64, predicted2: f64) -> Verdict {
        let (current, trial) = (&self.current, &self.trial);
        if !trial.is_finite() {
            return Verdict::default();
        }
        let s = &p.config.solver;
        let actual = current.task_cost - trial.task_cost;
        let actual2 = current.regularisation_cost - trial.regularisation_cost;
        let tie2 = ROUND_OFF * current.regularisation_cost;
        let regularisation_ok = if predicted2 > 0.0 {
            actual2 >= s.step_quality_min * predicted2 - tie2
        } else {
            actual2 >= 2.0 * predicted2 - tie2
        };
        Verdict {
            task_ok: actual >= s.step_quality_min * predicted - ROUND_OFF * current.task_cost
                || trial.task_cost <= p.task_tie,
            task_progress: actual > p.task_tie,
            regularisation_ok,
        }
    }
}

/// The outcome of the step test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Verdict {
    /// The task level accepts: real progress (at least `step_quality_min` of the decrease
    /// predicted for δ₁), or a trial whose task cost stays inside the tie band. The band is
    /// absolute, so repeated regularisation steps cannot accumulate a pose error.
    pub(crate) task_ok: bool,
    /// The task cost fell by more than the tie band (the regularisation has no say then).
    pub(crate) task_progress: bool,
    /// The regularisation cost behaved as its model predicts: it fell by at least
    /// `step_quality_min` of a predicted decrease, or rose by at most twice a predicted rise
    /// (a rise the task step causes).
    pub(crate) regularisation_ok: bool,
}

impl Verdict {
    pub(crate) fn accept(&self) -> bool {
        self.task_ok && (self.task_progress || self.regularisation_ok)
    }
}
