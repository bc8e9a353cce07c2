//! QP path A: clarabel on the sparse multiple-shooting QP — the reference path.
//!
//! Variables `z = [x_0, u_0, x_1, u_1, …, x_{N−1}, u_{N−1}, x_N]`. Constraints in clarabel's
//! form `A z + s = b`: the zero cone holds `x_0 = x̄_0` and `x_{k+1} − A x_k − B u_k = c_k`;
//! the non-negative cone holds every inequality row as `G z ≤ h`, in the same order as the
//! Riccati solver's rows. P is the upper triangle of each stage's dense `[Q Sᵀ; S R]` block.
//! With soft state rows, one slack variable per soft row follows z (cost ρ each): each soft
//! row reads `G z − t ≤ h`, and `−t ≤ 0` rows close the non-negative cone.
//!
//! The solver is built on the first QP and then only updated in place (P, q, the general
//! rows of A, and b): the sparsity pattern is fixed, so presolve and zero-dropping are off.
//! A QP of another structure rebuilds it.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};

use crate::mpc::config::QpSettings;
use crate::mpc::qp::{
    InputVector, NU, NX, QpSolution, QpSolver, QpStatus, StateInputMatrix, StateMatrix,
    StateVector, StructuredQp,
};

const NZ: usize = NX + NU;

fn x_col(k: usize) -> usize {
    k * NZ
}

fn u_col(k: usize) -> usize {
    k * NZ + NX
}

/// A compressed-sparse-column pattern built from triplets, remembering where tagged entries
/// land.
struct CscBuilder {
    rows: usize,
    cols: usize,
    entries: Vec<(usize, usize, f64, Option<usize>)>,
}

impl CscBuilder {
    fn new(rows: usize, cols: usize) -> Self {
        Self {
            rows,
            cols,
            entries: Vec::new(),
        }
    }

    fn push(&mut self, row: usize, col: usize, value: f64, tag: Option<usize>) {
        self.entries.push((row, col, value, tag));
    }

    /// The matrix, and the position in nzval of each tag.
    fn build(mut self, tags: usize) -> (CscMatrix<f64>, Vec<usize>) {
        self.entries.sort_by_key(|e| (e.1, e.0));
        let mut colptr = vec![0; self.cols + 1];
        let mut rowval = Vec::with_capacity(self.entries.len());
        let mut nzval = Vec::with_capacity(self.entries.len());
        let mut positions = vec![0; tags];
        for (pos, &(row, col, value, tag)) in self.entries.iter().enumerate() {
            colptr[col + 1] += 1;
            rowval.push(row);
            nzval.push(value);
            if let Some(t) = tag {
                positions[t] = pos;
            }
        }
        for c in 0..self.cols {
            colptr[c + 1] += colptr[c];
        }
        (
            CscMatrix::new(self.rows, self.cols, colptr, rowval, nzval),
            positions,
        )
    }
}

/// The built solver and the maps used to update it.
struct Built {
    solver: DefaultSolver<f64>,
    template: StructuredQp,
    p_values: Vec<f64>,
    q: Vec<f64>,
    a_values: Vec<f64>,
    b: Vec<f64>,
    /// nzval position of general-row entry (stage, row, column), in build order.
    general_positions: Vec<usize>,
}

/// clarabel on the multiple-shooting QP (see the module documentation).
pub struct ClarabelQp {
    settings: QpSettings,
    built: Option<Built>,
}

impl std::fmt::Debug for ClarabelQp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClarabelQp")
            .field("settings", &self.settings)
            .field("built", &self.built.is_some())
            .finish()
    }
}

impl ClarabelQp {
    /// A solver with `settings`; clarabel itself is built on the first QP.
    pub fn new(settings: QpSettings) -> Self {
        Self {
            settings,
            built: None,
        }
    }

    /// Replaces the settings (rebuilds on the next solve).
    pub fn set_settings(&mut self, settings: QpSettings) {
        self.settings = settings;
        self.built = None;
    }

    fn clarabel_settings(&self) -> Option<DefaultSettings<f64>> {
        let tol = self.settings.tolerance;
        DefaultSettingsBuilder::default()
            .verbose(false)
            .presolve_enable(false)
            .input_sparse_dropzeros(false)
            .max_iter(self.settings.max_iterations)
            .tol_gap_abs(tol)
            .tol_gap_rel(tol)
            .tol_feas(tol)
            .tol_ktratio(tol.min(1e-6))
            .build()
            .ok()
    }

    fn p_values(qp: &StructuredQp, out: &mut Vec<f64>) {
        out.clear();
        let n = qp.intervals;
        for k in 0..n {
            for jl in 0..NZ {
                for il in 0..=jl {
                    let v = match (il < NX, jl < NX) {
                        (true, true) => qp.q[k][(il, jl)],
                        (true, false) => qp.s[k][(jl - NX, il)],
                        _ => qp.r[k][(il - NX, jl - NX)],
                    };
                    out.push(v);
                }
            }
        }
        for jl in 0..NX {
            for il in 0..=jl {
                out.push(qp.q[n][(il, jl)]);
            }
        }
    }

    fn q_vector(qp: &StructuredQp, out: &mut Vec<f64>) {
        out.clear();
        for k in 0..qp.intervals {
            out.extend(qp.q_vec[k].iter());
            out.extend(qp.r_vec[k].iter());
        }
        out.extend(qp.q_vec[qp.intervals].iter());
        let rho = qp.soft_penalty.unwrap_or(0.0);
        out.extend(std::iter::repeat_n(rho, qp.soft_rows()));
    }

    /// b, with the inequality rows in the Riccati solver's order.
    fn b_vector(qp: &StructuredQp, out: &mut Vec<f64>) {
        out.clear();
        let n = qp.intervals;
        out.extend(qp.x0.iter());
        for c in &qp.defects {
            out.extend(c.iter());
        }
        for (k, c) in qp.constraints.iter().enumerate() {
            if k > 0 {
                for j in 0..c.state_indices.len() {
                    out.push(-c.state_lower[j]);
                    out.push(c.state_upper[j]);
                }
            }
            if k < n {
                for j in 0..c.input_indices.len() {
                    out.push(-c.input_lower[j]);
                    out.push(c.input_upper[j]);
                }
                for j in 0..c.input_general.len() {
                    out.push(-c.input_general_lower[j]);
                    out.push(c.input_general_upper[j]);
                }
            }
            if k > 0 {
                for j in 0..c.general.len() {
                    out.push(-c.general_lower[j]);
                    out.push(c.general_upper[j]);
                }
            }
        }
        out.extend(std::iter::repeat_n(0.0, qp.soft_rows()));
    }

    fn build(&self, qp: &StructuredQp) -> Option<Built> {
        let n = qp.intervals;
        let z_vars = NZ * n + NX;
        let soft_rows = qp.soft_rows();
        let vars = z_vars + soft_rows;
        // P: the upper triangle of each stage block, column by column.
        let mut p_values = Vec::new();
        Self::p_values(qp, &mut p_values);
        let mut colptr = vec![0usize];
        let mut rowval = Vec::with_capacity(p_values.len());
        for k in 0..=n {
            let width = if k < n { NZ } else { NX };
            for jl in 0..width {
                for il in 0..=jl {
                    rowval.push(k * NZ + il);
                }
                colptr.push(rowval.len());
            }
        }
        for _ in 0..soft_rows {
            colptr.push(rowval.len());
        }
        let p = CscMatrix::new(vars, vars, colptr, rowval, p_values.clone());

        let eq_rows = NX * (n + 1);
        let mut ineq_rows = 0;
        for (k, c) in qp.constraints.iter().enumerate() {
            if k > 0 {
                ineq_rows += 2 * (c.state_indices.len() + c.general.len());
            }
            if k < n {
                ineq_rows += 2 * (c.input_indices.len() + c.input_general.len());
            }
        }
        ineq_rows += soft_rows;
        let mut a = CscBuilder::new(eq_rows + ineq_rows, vars);
        for i in 0..NX {
            a.push(i, x_col(0) + i, 1.0, None);
        }
        for k in 0..n {
            let base = NX * (k + 1);
            for i in 0..NX {
                a.push(base + i, x_col(k + 1) + i, 1.0, None);
                for j in 0..NX {
                    if qp.a[(i, j)] != 0.0 {
                        a.push(base + i, x_col(k) + j, -qp.a[(i, j)], None);
                    }
                }
                for j in 0..NU {
                    if qp.b[(i, j)] != 0.0 {
                        a.push(base + i, u_col(k) + j, -qp.b[(i, j)], None);
                    }
                }
            }
        }
        let mut row = eq_rows;
        let mut tag = 0;
        // The next soft row's slack column (soft rows only when soft_rows > 0).
        let mut slack = z_vars;
        let mut soften = |a: &mut CscBuilder, row: usize| {
            if soft_rows > 0 {
                a.push(row, slack, -1.0, None);
                a.push(row + 1, slack + 1, -1.0, None);
                slack += 2;
            }
        };
        for (k, c) in qp.constraints.iter().enumerate() {
            if k > 0 {
                for &i in &c.state_indices {
                    a.push(row, x_col(k) + i, -1.0, None);
                    a.push(row + 1, x_col(k) + i, 1.0, None);
                    soften(&mut a, row);
                    row += 2;
                }
            }
            if k < n {
                for &i in &c.input_indices {
                    a.push(row, u_col(k) + i, -1.0, None);
                    a.push(row + 1, u_col(k) + i, 1.0, None);
                    row += 2;
                }
                for e in &c.input_general {
                    for j in 0..NU {
                        a.push(row, u_col(k) + j, -e[j], Some(tag));
                        a.push(row + 1, u_col(k) + j, e[j], Some(tag + 1));
                        tag += 2;
                    }
                    row += 2;
                }
            }
            if k > 0 {
                for g in &c.general {
                    for j in 0..NX {
                        a.push(row, x_col(k) + j, -g[j], Some(tag));
                        a.push(row + 1, x_col(k) + j, g[j], Some(tag + 1));
                        tag += 2;
                    }
                    soften(&mut a, row);
                    row += 2;
                }
            }
        }
        for i in 0..soft_rows {
            a.push(row + i, z_vars + i, -1.0, None);
        }
        let (a_csc, general_positions) = a.build(tag);
        let a_values = a_csc.nzval.clone();
        let mut q = Vec::new();
        Self::q_vector(qp, &mut q);
        let mut b = Vec::new();
        Self::b_vector(qp, &mut b);
        let cones = [
            SupportedConeT::ZeroConeT(eq_rows),
            SupportedConeT::NonnegativeConeT(ineq_rows),
        ];
        let settings = self.clarabel_settings()?;
        let solver = DefaultSolver::new(&p, &q, &a_csc, &b, &cones, settings).ok()?;
        Some(Built {
            solver,
            template: qp.clone(),
            p_values,
            q,
            a_values,
            b,
            general_positions,
        })
    }

    /// Writes `qp`'s values into the built solver. False if clarabel refused.
    fn update(built: &mut Built, qp: &StructuredQp) -> bool {
        Self::p_values(qp, &mut built.p_values);
        Self::q_vector(qp, &mut built.q);
        Self::b_vector(qp, &mut built.b);
        // Tags were given in build order: per stage, input rows (k < N) then state rows (k > 0).
        let n = qp.intervals;
        let mut t = 0;
        for (k, c) in qp.constraints.iter().enumerate() {
            if k < n {
                for e in &c.input_general {
                    for j in 0..NU {
                        built.a_values[built.general_positions[t]] = -e[j];
                        built.a_values[built.general_positions[t + 1]] = e[j];
                        t += 2;
                    }
                }
            }
            if k == 0 {
                continue;
            }
            for g in &c.general {
                for j in 0..NX {
                    built.a_values[built.general_positions[t]] = -g[j];
                    built.a_values[built.general_positions[t + 1]] = g[j];
                    t += 2;
                }
            }
        }
        let s = &mut built.solver;
        s.update_P(&built.p_values).is_ok()
            && s.update_q(&built.q).is_ok()
            && s.update_A(&built.a_values).is_ok()
            && s.update_b(&built.b).is_ok()
    }

    fn same_dynamics(a: &StructuredQp, b: &StructuredQp) -> bool {
        let pattern_a = |m: &StateMatrix, n: &StateMatrix| m == n;
        let pattern_b = |m: &StateInputMatrix, n: &StateInputMatrix| m == n;
        pattern_a(&a.a, &b.a) && pattern_b(&a.b, &b.b)
    }
}

impl QpSolver for ClarabelQp {
    fn solve(&mut self, qp: &StructuredQp, out: &mut QpSolution) -> QpStatus {
        let n = qp.intervals;
        out.x.resize(n + 1, StateVector::zeros());
        out.u.resize(n, InputVector::zeros());
        let reusable = self
            .built
            .as_ref()
            .is_some_and(|b| b.template.same_structure(qp) && Self::same_dynamics(&b.template, qp));
        let ok = if reusable {
            self.built.as_mut().is_some_and(|b| Self::update(b, qp))
        } else {
            self.built = self.build(qp);
            self.built.is_some()
        };
        let Some(built) = self.built.as_mut().filter(|_| ok) else {
            out.status = QpStatus::NumericalFailure;
            out.iterations = 0;
            return out.status;
        };
        built.solver.solve();
        let sol = &built.solver.solution;
        out.iterations = sol.iterations;
        out.status = match sol.status {
            SolverStatus::Solved => QpStatus::Solved,
            SolverStatus::MaxIterations | SolverStatus::MaxTime | SolverStatus::AlmostSolved => {
                QpStatus::MaxIterations
            }
            SolverStatus::PrimalInfeasible
            | SolverStatus::AlmostPrimalInfeasible
            | SolverStatus::DualInfeasible
            | SolverStatus::AlmostDualInfeasible => QpStatus::Infeasible,
            _ => QpStatus::NumericalFailure,
        };
        let finite = sol.x.iter().all(|v| v.is_finite());
        let z_vars = NZ * n + NX;
        out.slack.clear();
        out.slack.extend(
            sol.x[z_vars.min(sol.x.len())..]
                .iter()
                .map(|t| if finite { *t } else { 0.0 }),
        );
        for k in 0..=n {
            for i in 0..NX {
                out.x[k][i] = if finite { sol.x[x_col(k) + i] } else { 0.0 };
            }
            if k < n {
                for i in 0..NU {
                    out.u[k][i] = if finite { sol.x[u_col(k) + i] } else { 0.0 };
                }
            }
        }
        if !finite {
            out.status = QpStatus::NumericalFailure;
        }
        out.status
    }

    fn name(&self) -> &'static str {
        "clarabel"
    }
}
