//! Constrained allocation: the thrusts within bounds that come closest to the requested
//! wrench, in a weighted least-squares sense, solved as a QP with clarabel.
//!
//! ```text
//!     minimise    ½ (A x − w)ᵀ W (A x − w)  +  ½ ε κ ‖x / T_max‖²      (ε = 0 by default)
//!     subject to  T_min ≤ x_i ≤ T_max                      (fixed rotors)
//!                 ‖(c_i, s_i)‖ ≤ T_max                     (tilting rotors)
//! ```
//!
//! A is the allocation matrix of the vehicle class (6×N, 4×N or 6×2N), w the commanded rows of
//! the wrench and W = diag of [`ConstrainedSettings::wrench_error_weights`]. The weights are the
//! axis priorities (the role of PX4's desaturation logic): with the defaults an attitude torque
//! error costs 10⁴× a force error and 10⁶× a yaw error of the same size, so roll and pitch are
//! kept first, then thrust, and yaw gives way first.
//!
//! In clarabel form (x = T_max·u, so u is O(1)): P = (T_max² AᵀWA)/κ + εI, q = −T_max AᵀWw/κ,
//! with κ the largest diagonal entry of T_max² AᵀWA (so P is O(1) too). The bounds are two
//! `NonnegativeConeT(N)` blocks (u ≤ 1 and −u ≤ −T_min/T_max), or one `SecondOrderConeT(3)` per
//! tilting rotor on (1, u_c, u_s). P, A, b and the cones do not depend on the wrench: the solver
//! is built once (presolve off) and each allocation only updates q.
//!
//! After a solve the result is projected onto the bounds (removing interior-point tolerance
//! violations) and polished, because an interior-point method resolves the weakly weighted
//! directions (yaw, 10⁻⁶ of roll) only loosely. Polish: hold the rotors at a bound; take the
//! minimum-norm weighted least-squares step over the others, Δ = B_Fᵀ(B_F B_Fᵀ)⁺ W^{½} r with
//! B_F = W^{½}A_F and r = w − A x, only as far as the first rotor reaching a bound (the error
//! falls monotonically along Δ); hold that rotor too and repeat; finish with one refinement
//! step. For a wrench the rotors can produce this removes the residual the solver leaves; for
//! one they cannot it lands on the optimum of the identified active set. The polished point is
//! kept only if its weighted error is lower.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SecondOrderConeT,
    SolverStatus, SupportedConeT,
};
use nalgebra::{DMatrix, DVector, Matrix6, Vector6};
use serde::{Deserialize, Serialize};

use crate::bounds::ThrustBounds;
use crate::{AllocationError, AllocationStatus, SolverFailure};

/// Settings of the constrained (QP) allocation, which solves
///
/// ```text
///     minimise    ½ (A x − w)ᵀ W (A x − w)  +  ½ ε κ ‖x / T_max‖²      (ε = 0 by default)
///     subject to  T_min ≤ x_i ≤ T_max          fixed rotors
///                 ‖(c_i, s_i)‖ ≤ T_max         tilting rotors (T_min applied afterwards by scaling)
/// ```
///
/// with clarabel (built once, only the linear cost term changes per tick), then projects the
/// result onto the bounds and polishes it with an active-set least-squares step. A request
/// whose pseudo-inverse solution is already within bounds never reaches the solver.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ConstrainedSettings {
    /// Weights W of the squared wrench error, order `[F_x, F_y, F_z, τ_x, τ_y, τ_z]`
    /// (N⁻² for forces, (N·m)⁻² for torques; only their ratios matter). An under-actuated
    /// vehicle uses the last four. Default `[1e2, 1e2, 1e2, 1e6, 1e6, 1]`: roll/pitch torque
    /// first, then force, then yaw. In error-size terms 1 N·m of roll ≙ 100 N of force ≙
    /// 1000 N·m of yaw (the square roots of the ratios). Weights are soft priorities: at the
    /// optimum a kept axis gives up about lever·w_low·e_low/w_high — 0.02 N·m of roll when a
    /// UA-Hexa is 67 N short of thrust (a 10² ratio, `[.., 1e4, 1e4, ..]`, gives up 1.7 N·m).
    pub wrench_error_weights: [f64; 6],
    /// Tikhonov weight ε on ½‖T/T_max‖², relative to the normalised Hessian (largest
    /// diagonal entry 1). A positive ε makes the minimiser unique on redundant layouts
    /// (UA-Hexa, Omni-Hexa) at the price of raising the weighted error by up to ε·N·κ/2
    /// (κ = the largest diagonal entry of T_max²AᵀWA, ~10⁸ with the default weights). Default 0:
    /// not needed — clarabel converges on the positive semi-definite problem and the polish
    /// takes minimum-norm steps — and it keeps "never worse than clipping" exact.
    pub regularisation: f64,
    /// Interior-point iteration limit (clarabel `max_iter`). Default 50 (a solve takes ~10–20).
    pub max_iterations: u32,
    /// clarabel's absolute/relative gap and feasibility tolerances. Default 1e-9.
    pub tolerance: f64,
}

impl Default for ConstrainedSettings {
    fn default() -> Self {
        Self {
            wrench_error_weights: [1e2, 1e2, 1e2, 1e6, 1e6, 1.0],
            regularisation: 0.0,
            max_iterations: 50,
            tolerance: 1e-9,
        }
    }
}

impl ConstrainedSettings {
    /// Largest accepted [`ConstrainedSettings::regularisation`]: beyond it the regularisation
    /// would visibly trade wrench error for smaller thrusts.
    pub const MAX_REGULARISATION: f64 = 1e-6;

    /// Checks every field.
    ///
    /// # Errors
    /// [`AllocationError::InvalidSettings`] naming the field out of range.
    pub fn validate(&self) -> Result<(), AllocationError> {
        if !self
            .wrench_error_weights
            .iter()
            .all(|w| w.is_finite() && *w > 0.0)
        {
            return Err(AllocationError::InvalidSettings(format!(
                "wrench_error_weights must be finite and positive, got {:?}",
                self.wrench_error_weights
            )));
        }
        if !(self.regularisation.is_finite()
            && (0.0..=Self::MAX_REGULARISATION).contains(&self.regularisation))
        {
            return Err(AllocationError::InvalidSettings(format!(
                "regularisation must be in [0, {}], got {}",
                Self::MAX_REGULARISATION,
                self.regularisation
            )));
        }
        if self.max_iterations == 0 {
            return Err(AllocationError::InvalidSettings(
                "max_iterations must be at least 1".into(),
            ));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0 && self.tolerance <= 1e-3) {
            return Err(AllocationError::InvalidSettings(format!(
                "tolerance must be in (0, 1e-3], got {}",
                self.tolerance
            )));
        }
        Ok(())
    }
}

/// A rotor within this fraction of T_max of a bound starts the polish held (the interior-point
/// solution approaches an active bound to about the solver tolerance).
const ACTIVE_BOUND_FRACTION: f64 = 1e-7;
/// Full least-squares steps the polish takes (the second one is iterative refinement: the
/// Gram matrix B Bᵀ squares the condition number of B, about 1e4 between roll and yaw rows,
/// so one step leaves ~1e-8 of the residual in the weakest direction).
const REFINEMENT_STEPS: usize = 2;
/// Eigenvalues of B Bᵀ below this fraction of the largest are treated as zero.
const GRAM_RANK_TOLERANCE: f64 = 1e-12;

/// The QP of one vehicle, built once.
pub(crate) struct ConstrainedQp {
    solver: DefaultSolver<f64>,
    bounds: ThrustBounds,
    /// A, m × n.
    matrix: DMatrix<f64>,
    /// Diagonal of W for the commanded rows.
    weights: DVector<f64>,
    /// Its square roots.
    sqrt_weights: DVector<f64>,
    /// q = cost_map · w, n × m.
    cost_map: DMatrix<f64>,
    q: Vec<f64>,
    // Polish work buffers.
    residual: DVector<f64>,
    weighted_matrix: DMatrix<f64>,
    candidate: DVector<f64>,
    step: DVector<f64>,
    free: Vec<bool>,
}

impl std::fmt::Debug for ConstrainedQp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConstrainedQp")
            .field("bounds", &self.bounds)
            .field("rows", &self.matrix.nrows())
            .field("variables", &self.matrix.ncols())
            .field("weights", &self.weights.as_slice())
            .finish_non_exhaustive()
    }
}

impl ConstrainedQp {
    /// Builds the QP for allocation matrix `matrix` (rows = commanded wrench rows `rows`).
    pub(crate) fn new(
        matrix: &DMatrix<f64>,
        rows: &[usize],
        bounds: ThrustBounds,
        settings: &ConstrainedSettings,
    ) -> Result<Self, AllocationError> {
        settings.validate()?;
        let (m, n) = matrix.shape();
        let weights =
            DVector::from_iterator(m, rows.iter().map(|&r| settings.wrench_error_weights[r]));
        let sqrt_weights = weights.map(f64::sqrt);
        let t_max = bounds.max_n;

        // Hessian of the weighted error in u = x / T_max, normalised to a unit largest diagonal.
        let weighted_t = matrix.transpose() * DMatrix::from_diagonal(&weights); // Aᵀ W, n × m
        let hessian = (&weighted_t * matrix) * (t_max * t_max);
        let kappa = hessian.diagonal().max();
        if !(kappa.is_finite() && kappa > 0.0) {
            return Err(AllocationError::SolverSetup(format!(
                "degenerate Hessian scale {kappa}"
            )));
        }
        let p = hessian / kappa + DMatrix::identity(n, n) * settings.regularisation;
        let cost_map = weighted_t * (-t_max / kappa);

        let p_csc = upper_triangle_csc(&p);
        let (a_csc, b, cones) = constraint_data(n, bounds);
        let clarabel_settings = DefaultSettingsBuilder::default()
            .verbose(false)
            .presolve_enable(false)
            .max_iter(settings.max_iterations)
            .tol_gap_abs(settings.tolerance)
            .tol_gap_rel(settings.tolerance)
            .tol_feas(settings.tolerance)
            .build()
            .map_err(|e| AllocationError::SolverSetup(e.to_string()))?;
        let q = vec![0.0; n];
        let solver = DefaultSolver::new(&p_csc, &q, &a_csc, &b, &cones, clarabel_settings)
            .map_err(|e| AllocationError::SolverSetup(e.to_string()))?;

        Ok(Self {
            solver,
            bounds,
            matrix: matrix.clone(),
            weights,
            sqrt_weights,
            cost_map,
            q,
            residual: DVector::zeros(m),
            weighted_matrix: DMatrix::zeros(m, n),
            candidate: DVector::zeros(n),
            step: DVector::zeros(n),
            free: vec![true; n / bounds.variables_per_rotor()],
        })
    }

    /// Solves for commanded rows `request`; on success writes the (projected, polished)
    /// solution into `x` and returns [`AllocationStatus::Solved`]. On failure leaves `x` alone
    /// and returns [`AllocationStatus::SolverFailed`].
    pub(crate) fn solve(
        &mut self,
        request: &DVector<f64>,
        x: &mut DVector<f64>,
    ) -> AllocationStatus {
        for (j, q) in self.q.iter_mut().enumerate() {
            *q = (0..request.len())
                .map(|i| self.cost_map[(j, i)] * request[i])
                .sum();
        }
        if self.solver.update_q(&self.q).is_err() {
            return AllocationStatus::SolverFailed {
                reason: SolverFailure::DataUpdateRejected,
            };
        }
        self.solver.solve();
        let reduced_accuracy = match self.solver.solution.status {
            SolverStatus::Solved => false,
            SolverStatus::AlmostSolved => true,
            other => {
                return AllocationStatus::SolverFailed {
                    reason: failure_of(other),
                };
            }
        };
        let t_max = self.bounds.max_n;
        for (xi, ui) in x.iter_mut().zip(&self.solver.solution.x) {
            *xi = t_max * ui;
        }
        self.bounds.project_onto_convex_set(x.as_mut_slice());
        let polished = self.polish(request, x);
        AllocationStatus::Solved {
            reduced_accuracy,
            iterations: self.solver.solution.iterations,
            polished,
        }
    }

    /// ½ rᵀWr of r = request − A x, leaving r in `self.residual`.
    fn weighted_error(&mut self, request: &DVector<f64>, x: &DVector<f64>) -> f64 {
        weighted_residual(&self.matrix, &self.weights, request, x, &mut self.residual)
    }

    /// The active-set least-squares refinement described in the module doc. Returns true when
    /// it lowered the weighted error (the result is then in `x`).
    ///
    /// Each pass takes the minimum-norm weighted least-squares step Δ over the free rotors
    /// (Δ = B_Fᵀ(B_F B_Fᵀ)⁺ W^{½} r), moves along it until the first free rotor reaches a bound
    /// (the error falls monotonically along Δ, which minimises it over the free subspace), and
    /// holds that rotor from then on. It stops after [`REFINEMENT_STEPS`] full steps.
    fn polish(&mut self, request: &DVector<f64>, x: &mut DVector<f64>) -> bool {
        let bounds = self.bounds;
        let per_rotor = bounds.variables_per_rotor();
        let (m, n) = self.matrix.shape();
        let rotors = self.free.len();
        let active_tolerance = ACTIVE_BOUND_FRACTION * bounds.max_n;

        let error_before = self.weighted_error(request, x);
        if error_before == 0.0 {
            return false;
        }
        // Rotors the solver left next to a bound start held, exactly on it.
        self.candidate.copy_from(x);
        for (rotor, free) in self.free.iter_mut().enumerate() {
            *free = !bounds.at_convex_bound(x.as_slice(), rotor, active_tolerance);
            if !*free {
                bounds.snap_to_nearest_bound(self.candidate.as_mut_slice(), rotor);
            }
        }
        weighted_residual(
            &self.matrix,
            &self.weights,
            request,
            &self.candidate,
            &mut self.residual,
        );
        let mut full_steps = 0;
        for _ in 0..rotors + REFINEMENT_STEPS {
            if !self.free.iter().any(|&f| f) {
                break;
            }
            // B = W^{½} A with the held rotors' columns zeroed; y = W^{½} r (r of the candidate).
            let mut y = Vector6::zeros();
            for i in 0..m {
                y[i] = self.sqrt_weights[i] * self.residual[i];
            }
            for j in 0..n {
                let free = self.free[j / per_rotor];
                for i in 0..m {
                    self.weighted_matrix[(i, j)] = if free {
                        self.sqrt_weights[i] * self.matrix[(i, j)]
                    } else {
                        0.0
                    };
                }
            }
            // z = (B Bᵀ)⁺ y through the eigen-decomposition of the (padded) 6×6 Gram matrix.
            let mut gram = Matrix6::zeros();
            for i in 0..m {
                for k in i..m {
                    let g = self
                        .weighted_matrix
                        .row(i)
                        .dot(&self.weighted_matrix.row(k));
                    gram[(i, k)] = g;
                    gram[(k, i)] = g;
                }
            }
            let eigen = gram.symmetric_eigen();
            let largest = eigen.eigenvalues.amax();
            if largest <= 0.0 {
                break;
            }
            let mut z = Vector6::zeros();
            for (k, &lambda) in eigen.eigenvalues.iter().enumerate() {
                if lambda > GRAM_RANK_TOLERANCE * largest {
                    let v = eigen.eigenvectors.column(k);
                    z += v * (v.dot(&y) / lambda);
                }
            }
            // Δ = Bᵀ z, kept in `step`.
            for j in 0..n {
                let mut d = 0.0;
                for i in 0..m {
                    d += self.weighted_matrix[(i, j)] * z[i];
                }
                self.step[j] = d;
            }
            // Longest step t ≤ 1 that keeps every free rotor within the convex set.
            let mut length = 1.0;
            let mut blocking = None;
            for rotor in 0..rotors {
                if !self.free[rotor] {
                    continue;
                }
                let t = bounds.max_step(self.candidate.as_slice(), self.step.as_slice(), rotor);
                if t < length {
                    length = t;
                    blocking = Some(rotor);
                }
            }
            self.candidate.axpy(length, &self.step, 1.0);
            if let Some(rotor) = blocking {
                bounds.snap_to_bound(self.candidate.as_mut_slice(), self.step.as_slice(), rotor);
                self.free[rotor] = false;
            }
            bounds.project_onto_convex_set(self.candidate.as_mut_slice());
            weighted_residual(
                &self.matrix,
                &self.weights,
                request,
                &self.candidate,
                &mut self.residual,
            );
            if blocking.is_none() {
                full_steps += 1;
                if full_steps == REFINEMENT_STEPS {
                    break;
                }
            }
        }
        let error_after = weighted_residual(
            &self.matrix,
            &self.weights,
            request,
            &self.candidate,
            &mut self.residual,
        );
        if error_after < error_before {
            x.copy_from(&self.candidate);
            true
        } else {
            false
        }
    }
}

/// ½ rᵀWr of r = request − A x (W diagonal), writing r into `residual`.
pub(crate) fn weighted_residual(
    matrix: &DMatrix<f64>,
    weights: &DVector<f64>,
    request: &DVector<f64>,
    x: &DVector<f64>,
    residual: &mut DVector<f64>,
) -> f64 {
    residual.copy_from(request);
    residual.gemv(-1.0, matrix, x, 1.0);
    0.5 * residual
        .iter()
        .zip(weights.iter())
        .map(|(r, w)| w * r * r)
        .sum::<f64>()
}

/// The upper triangle of a dense symmetric matrix in CSC form (what clarabel expects for P).
fn upper_triangle_csc(p: &DMatrix<f64>) -> CscMatrix<f64> {
    let n = p.ncols();
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    colptr.push(0);
    for j in 0..n {
        for i in 0..=j {
            rowval.push(i);
            nzval.push(p[(i, j)]);
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(n, n, colptr, rowval, nzval)
}

/// Constraint matrix, right-hand side and cones (clarabel: A x + s = b, s ∈ K) in u = x/T_max.
fn constraint_data(
    n: usize,
    bounds: ThrustBounds,
) -> (CscMatrix<f64>, Vec<f64>, Vec<SupportedConeT<f64>>) {
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    colptr.push(0);
    if bounds.tilting {
        // Rotor i: s = (1, u_c, u_s) ∈ SOC(3), rows 3i..3i+3.
        let rotors = n / 2;
        for j in 0..n {
            rowval.push(3 * (j / 2) + 1 + j % 2);
            nzval.push(-1.0);
            colptr.push(rowval.len());
        }
        let b = (0..rotors).flat_map(|_| [1.0, 0.0, 0.0]).collect();
        let cones = (0..rotors).map(|_| SecondOrderConeT(3)).collect();
        (
            CscMatrix::new(3 * rotors, n, colptr, rowval, nzval),
            b,
            cones,
        )
    } else {
        // u ≤ 1:  u + s = 1;   u ≥ lo:  −u + s = −lo.
        for j in 0..n {
            rowval.extend([j, n + j]);
            nzval.extend([1.0, -1.0]);
            colptr.push(rowval.len());
        }
        let lo = bounds.min_n / bounds.max_n;
        let b = std::iter::repeat_n(1.0, n)
            .chain(std::iter::repeat_n(-lo, n))
            .collect();
        let cones = vec![NonnegativeConeT(n), NonnegativeConeT(n)];
        (CscMatrix::new(2 * n, n, colptr, rowval, nzval), b, cones)
    }
}

fn failure_of(status: SolverStatus) -> SolverFailure {
    match status {
        SolverStatus::MaxIterations => SolverFailure::MaxIterations,
        SolverStatus::MaxTime => SolverFailure::MaxTime,
        SolverStatus::NumericalError => SolverFailure::NumericalError,
        SolverStatus::InsufficientProgress => SolverFailure::InsufficientProgress,
        SolverStatus::PrimalInfeasible
        | SolverStatus::DualInfeasible
        | SolverStatus::AlmostPrimalInfeasible
        | SolverStatus::AlmostDualInfeasible => SolverFailure::Infeasible,
        _ => SolverFailure::Other,
    }
}

#[cfg(test)]
#[expect(clippy::unwrap_used, reason = "a test fails loudly")]
mod tests {
    use super::*;

    #[test]
    fn default_settings_are_valid() {
        assert_eq!(ConstrainedSettings::default().validate(), Ok(()));
    }

    #[test]
    fn settings_reject_out_of_range_fields() {
        let base = ConstrainedSettings::default();
        let mut weights = base;
        weights.wrench_error_weights[5] = 0.0;
        assert!(weights.validate().is_err());
        weights.wrench_error_weights[5] = f64::NAN;
        assert!(weights.validate().is_err());
        let regularisation = ConstrainedSettings {
            regularisation: 1e-3,
            ..base
        };
        assert!(regularisation.validate().is_err());
        let iterations = ConstrainedSettings {
            max_iterations: 0,
            ..base
        };
        assert!(iterations.validate().is_err());
        let tolerance = ConstrainedSettings {
            tolerance: -1.0,
            ..base
        };
        let message = tolerance.validate().unwrap_err().to_string();
        assert!(message.contains("tolerance"), "{message}");
    }

    #[test]
    fn upper_triangle_keeps_diagonal_and_above() {
        let p = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 3.0]);
        let csc = upper_triangle_csc(&p);
        assert_eq!(csc.colptr, vec![0, 1, 3]);
        assert_eq!(csc.rowval, vec![0, 0, 1]);
        assert_eq!(csc.nzval, vec![1.0, 2.0, 3.0]);
    }
}
