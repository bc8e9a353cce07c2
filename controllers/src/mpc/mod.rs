//! Whole-body nonlinear MPC of the FA-Hexa by SQP real-time iterations (AMBENCH_SPEC §2.5,
//! paper appendix "Model Predictive Control").
//!
//! - [`model`]: the prediction model — base double integrators, Euler-rate attitude, the
//!   first-order arm servo — its RK4 integrator with exact sensitivities, and the end
//!   effector's whole-body forward kinematics (from the `platform` description) with
//!   analytic Jacobians; the rotors' thrust envelope that bounds the force.
//! - [`SqpRti`]: the OCP (horizon 0.8 s in 32 intervals, nonlinear least-squares cost on the EE
//!   pose and the regularisation terms, wall-aware position, attitude, joint and EE-height
//!   bounds) and one Gauss–Newton SQP iteration per tick, warm-started by shifting.
//! - Two QP paths that solve the same [`StructuredQp`]: [`ClarabelQp`] (clarabel on the sparse
//!   multiple-shooting QP, built once and updated in place) and [`RiccatiIpm`] (a Riccati
//!   recursion interior-point method written for this stage-wise structure).
//! - [`WholeBodyMpc`]: the `mpc` controller — output filter, gravity compensation after the
//!   solve, and the fallback (hold the shifted solution, then IK-PID; IK-PID at once for a
//!   wrench the rotors cannot deliver) reported in [`MpcStatus`].
//! - [`grasp`]: the grasp model — while the hand holds an object on a joint, rows keep the
//!   predicted EE on that joint's motion.
//! - [`scenario`]: the standard scenario of `amstack mpc-bench` and the tests (a 0.3 m EE
//!   step toward a wall, the loop closed on the model).
//!
//! Measured (`amstack mpc-bench`, release, 2 cores): one RTI step takes ≈ 0.7–0.9 ms median
//! with the Riccati path (5 interior-point iterations; the factorisation is ~40 % of it, the
//! per-row work on the ~1000 inequality rows ~35 %, preparation 0.035 ms) and ≈ 15–17 ms
//! with clarabel.

mod clarabel_qp;
mod config;
mod controller;
pub mod grasp;
pub mod model;
mod qp;
mod riccati;
mod rti;
pub mod scenario;

#[cfg(test)]
mod tests;

pub use clarabel_qp::ClarabelQp;
pub use config::{MpcConfig, MpcConfigError, MpcWeights, QpPath, QpSettings};
pub use controller::{
    FallbackEvent, MpcCommand, MpcMode, MpcProblem, MpcStatus, SolveFailure, WholeBodyMpc,
};
pub use model::{EeKinematics, ModelError, MpcModel};
pub use qp::{
    InputVector, NU, NX, QpSolution, QpSolver, QpStatus, StageConstraints, StateVector,
    StructuredQp,
};
pub use riccati::{
    InfeasibilityExit, RiccatiIpm, RowScreening, ScreeningReport, ShotOutcome, kernel_target,
};
pub use rti::{MpcError, MpcReference, RtiReport, SqpRti, wrap_angle};
