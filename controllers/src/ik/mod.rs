//! Whole-body inverse kinematics: the base pose and arm joints that put the end effector at a
//! target pose (AMBENCH_SPEC §2.6, paper appendix "Inverse Kinematics").
//!
//! # Problem
//!
//! Given the target `T_t = (R_t, p_t)` of the vehicle's `ee_link` frame in the world, find the
//! base pose `(R, p)` and the arm joints `q` (the vehicle's arm joints only; every other movable
//! joint — fingers, Omni-Hexa tilt hinges and servo4 — is held at its initial drive position and
//! returned there, as the reference resets non-arm joints) such that
//!
//! ```text
//! p_ee(R, p, q) = p + R·p_be(q),      R_ee(R, q) = R·R_be(q),
//! ```
//!
//! with `(R_be, p_be)` the forward kinematics of the arm in the base frame. Residuals, each
//! multiplied by its weight (`IkWeights`; a cost term scales with the weight squared):
//!
//! ```text
//! task (level 1):
//!   r_pos   = w_pos · (p_ee − p_t)                              3
//!   r_ori   = w_ori · log(R_tᵀ R_ee)                            3
//!   r_joint = w_jl  · max(0, q − q_max), w_jl · max(0, q_min − q)   per arm joint
//!   r_base  = w_bl  · max(0, p − p_max), w_bl · max(0, p_min − p)   per bounded world axis
//! regularisation (level 2):
//!   r_sq    = w_sj · (q − q_prev)                               smoothness of the arm joints
//!   r_sp    = w_sp · (p − p_prev)                               smoothness of the base position
//!   r_sR    = w_sR · log(R R_prevᵀ)                             smoothness of the base rotation
//!   r_rest  = w_r  · (q − q_rest)                               rest posture of the arm
//! ```
//!
//! `(R_prev, p_prev, q_prev)` is the previous solution, which is also the warm start; `q_rest`
//! is the profile's rest posture (zeros, or the Omni-Hexa's initial joints). Base limits come
//! per call ([`BaseLimits`]: in front of a wall `max_x = face_x − safety_margin`, always
//! `min_z = 0`).
//!
//! Variables: base position (3), base rotation as a 3-vector *left* (world-frame) increment
//! `R ← exp(δθ^)·R`, and the arm joints. Locked axes (`fix_base_position`,
//! `fix_base_orientation` = roll, pitch, yaw about world x, y, z) are removed from the variable
//! set, not masked: locking roll and pitch keeps a level base level and leaves yaw about world
//! z; locking all three keeps the warm start's rotation exactly.
//!
//! Jacobians are analytic. Every variable moves the EE by a world-frame twist `(v, ω)`:
//! base position `[I; 0]`; base rotation `[−(p_ee − p)^; I]`; arm joint j with base-frame axis
//! `a_j` through `o_j` (from the flattened chain, equal to `KinematicModel::jacobian`)
//! `[R(a_j × (p_be − o_j)); R a_j]` (prismatic: `[R a_j; 0]`). The orientation residual moves by
//! `J_l⁻¹(e)·R_tᵀ·ω` (`e = log(R_tᵀR_ee)`, `J_l⁻¹` the inverse left Jacobian of SO(3), exact,
//! so convergence is quadratic near the solution); the base-rotation smoothness by
//! `J_l⁻¹(log(R R_prevᵀ))·δθ`.
//!
//! # Formulation: task priority (where this differs from the reference)
//!
//! The reference (pyroki + jaxls) minimises one weighted sum of all residuals above. Its
//! optimum is a compromise: the smoothness and rest terms pull the EE off the target by an
//! amount that grows with their weights (a bias toward the previous and rest postures). Here
//! the two levels are solved lexicographically — minimise C₂ = |r₂|² over the minimisers of
//! C₁ = |r₁|² — by a Levenberg–Marquardt iteration whose every step is:
//!
//! 1. **Task step.** SVD of J₁ (pose rows and active hinge rows; nalgebra's Golub–Kahan),
//!    `J₁ = Σ σ_i u_i v_iᵀ`; with `g = J₁ᵀr₁`,
//!    `δ₁ = −Σ_{σ_i > ε·σ_max} v_i (v_iᵀg)/(σ_i² + λ)` = `−(J₁ᵀJ₁ + λI)⁻¹J₁ᵀr₁` on the range of
//!    J₁ᵀ (ε = `nullspace_singular_value_ratio`). The damping matrix is the identity, as in
//!    jaxls; one decomposition then serves every λ tried at a point. Working on J₁ rather than
//!    J₁ᵀJ₁ does not square its condition number.
//! 2. **Regularisation step** in the task nullspace `N` (the other right singular vectors, an
//!    orthonormal basis of the complement of the range vectors): `δ = δ₁ + N z`,
//!    `z = −(H + μI)⁻¹ Nᵀ(B δ₁ + c)`, with `B = J₂ᵀJ₂`, `c = J₂ᵀr₂` and H the Hessian of the
//!    Lagrangian `C₂/2 + νᵀr₁` on the nullspace, ν the multipliers with which the pose holds
//!    the regularisation's pull. H is obtained by finite differences of `J₂ᵀr₂ + J₁ᵀν` along
//!    the nullspace directions, once per solve and again only when the iterate has moved
//!    away. Gauss–Newton's `NᵀBN` alone misses the curvature of the set of exact solutions
//!    (rotating joints make it curved), and converges only linearly there; with H the regularisation converges quadratically (2–3 iterations per
//!    flight-loop solve). μ is a second LM damping, adapted to how well C₂ follows its model.
//!    The regularisation may not push a bounded variable (base position axis, arm joint) across
//!    its limit and uses its freedom to bring one back that the task step pushed out: the first
//!    bound hit becomes an equality `(N z)_i = bound − x_i − δ₁_i`, z is re-solved, and so on.
//! 3. **Second-order correction.** A nullspace step is tangent to the (curved) solution set
//!    and leaves a task error of second order; if that error fails the step test, task
//!    Gauss–Newton corrections from the trial point remove it (variables on a bound frozen).
//! 4. **Step test.** Accept if the task cost fell by at least `step_quality_min` of the
//!    decrease predicted for δ₁ — or stays inside the tie band (the cost of a pose error at
//!    the pose tolerances, an absolute band, so it cannot accumulate) — and, unless the task
//!    cost fell by more than the band, C₂ behaves as its model predicts (tie-break).
//!    Accepted: λ ← max(λ/f, λ_min); task rejected: λ ← λ·f (μ follows its own test).
//!
//! After the loop a task correction polishes the pose left inside the band. Consequences: a
//! target reachable within the limits is met to round-off (typically 1e-11 m) and the
//! regularisers only choose among exact solutions; an unreachable one gives the closest pose
//! the task level allows (status [`IkReason::ClosestPose`]). The limits stay soft hinges as in
//! the reference (with a 1e-9 dead zone so a variable resting on its bound does not switch its
//! row on and off), so against a limit the pose error and the violation trade off as
//! `(w_pos/w_limit)²`: a target 1 m beyond a wall puts the base about 2.5 mm past its limit.
//!
//! Stopping rules follow jaxls: at most `max_iterations` step attempts; stop on a step below
//! the parameter tolerance, on settled costs (the task level counts as settled when its pose
//! is met), or — from iteration 10 — on gradients below the gradient tolerance. Differences: a
//! step rejected at a damping above λ_max ends the solve (jaxls keeps iterating at λ_max until
//! its budget is spent). Non-convergence is a status, never an error: the solution is always
//! finite, and on a non-finite target, non-finite limits or a numerical failure it is the
//! previous solution unchanged (reference: "on exception: previous solution reused").
//!
//! Other conscious differences: the reference perturbs the base on the right (body frame) and
//! masks the tangent; with the shipped locks (all three, or roll and pitch) both give the same
//! motions. The IK works on the `ee_link` frame; callers map command quaternions with
//! `Vehicle::command_to_link` first, and build [`BaseLimits`] from obstacles with the profile's
//! `safety_margin_m`.
//!
//! # Joint rates (opt-in; not the reference)
//!
//! Neither the reference nor the default IK knows how fast the arm moves: a target that
//! moves faster than the drives (5 rad/s on every AM-Bench arm, AMBENCH_SPEC §1.2) gets joint
//! targets the arm reaches several periods later, while the base already flies toward the
//! base pose computed with them. [`WholeBodyIk::limit_joint_rates`] bounds each arm joint to
//! `previous ± velocity_limit·period` in every solve (a hinge at the task level, weighted as
//! the joint limits, and a hard bound of the regularisation step), so the base takes what the
//! arm cannot. The flight stack does not turn it on: measured on the FA-Hexa (README, Toss
//! Ball) it makes the toss's throw coherent but moves Rotate Valve from 10 of 10 to 0 of 10,
//! whose turn relies on the arm following a 40 rad/s jump of its IK targets.
//!
//! Cost: the iteration's buffers are allocated when the IK is built. A solve also allocates
//! the small matrices of nalgebra's dynamic SVD and Cholesky factorisations (n ≤ a dozen, so
//! a few hundred bytes each, a handful per iteration) and the two vectors of its
//! [`IkSolution`]. `cargo bench -p controllers --bench ik` measures 9–16 µs per warm-started
//! flight-loop solve.

pub(crate) mod chain;
mod config;
mod iteration;
mod limits;
mod linalg;
mod problem;
mod solver;

#[cfg(test)]
mod tests;

pub use config::{IkConfig, IkConfigError, IkSolverSettings, IkWeights, RestPosture};
pub use limits::{AXIS_X, AXIS_Y, AXIS_Z, BaseLimits};
pub use solver::{IkError, IkReason, IkSolution, IkStatus, WholeBodyIk};
