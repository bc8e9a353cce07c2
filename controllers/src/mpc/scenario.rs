//! The standard MPC scenario of `amstack mpc-bench` and the tests: the FA-Hexa, hovering at
//! (0, 0, 1) m with its arm at the initial posture, tracks a 0.3 m step of its end effector
//! along world x toward a wall whose face is at x = 1.15 m. With the 0.85 m safety margin the
//! base may not pass x = 0.3 m, so it ends against its bound; on the way the roll/pitch bounds
//! and the EE-height band become active too.
//!
//! The loop is closed on the prediction model itself (RK4 over one control period), so a run
//! measures the solver alone and is deterministic. Preparation and feedback are separate calls
//! so a caller can time them.

use nalgebra::{UnitQuaternion, Vector3};
use platform::Vehicle;

use crate::ik::BaseLimits;
use crate::mpc::config::{MpcConfig, QpPath};
use crate::mpc::model::{IX_P, IX_Q};
use crate::mpc::qp::{InputVector, StateVector};
use crate::mpc::rti::{MpcError, MpcReference, RtiReport, SqpRti};

/// Size of the EE step along world x, m.
pub const STEP_M: f64 = 0.3;
/// World x of the wall's face, m.
pub const WALL_FACE_X_M: f64 = 1.15;
/// The reference's wall margin, m (AMBENCH_SPEC §2.5 `update_pos_max_from_wall`).
pub const WALL_MARGIN_M: f64 = 0.85;
/// Control rate, Hz.
pub const RATE_HZ: f64 = 120.0;

/// The scenario in progress.
#[derive(Debug)]
pub struct WallStepScenario {
    rti: SqpRti,
    x: StateVector,
    reference: MpcReference,
    limits: BaseLimits,
    goal: Vector3<f64>,
    ticks: usize,
}

impl WallStepScenario {
    /// The scenario for `vehicle` (FA-Hexa) with `config`.
    pub fn new(vehicle: &Vehicle, config: MpcConfig) -> Result<Self, MpcError> {
        let mut rti = SqpRti::new(vehicle, config)?;
        let mut x = StateVector::zeros();
        x[IX_P + 2] = 1.0;
        let q = vehicle.initial_configuration();
        for (j, &d) in vehicle.arm_dofs().iter().enumerate() {
            x[IX_Q + j] = q[d];
        }
        let ee = rti.ee_kinematics(&x);
        let goal = ee.position + Vector3::new(STEP_M, 0.0, 0.0);
        let mut input_previous = InputVector::zeros();
        for j in 0..4 {
            input_previous[crate::mpc::model::IU_QREF + j] = x[IX_Q + j];
        }
        Ok(Self {
            rti,
            x,
            reference: MpcReference {
                ee_position_m: goal,
                ee_velocity_mps: Vector3::zeros(),
                ee_rotation: UnitQuaternion::from_rotation_matrix(&ee.rotation),
                ee_offset_m: Vector3::zeros(),
                input_previous,
            },
            limits: BaseLimits::in_front_of_face_x(WALL_FACE_X_M, WALL_MARGIN_M),
            goal,
            ticks: 0,
        })
    }

    /// The control period, s.
    pub fn dt_s(&self) -> f64 {
        1.0 / RATE_HZ
    }

    /// Highest base x the wall allows, m.
    pub fn base_max_x_m(&self) -> f64 {
        WALL_FACE_X_M - WALL_MARGIN_M
    }

    /// Builds this tick's QP (shift, roll-out, linearisation).
    pub fn prepare(&mut self) {
        let elapsed = if self.ticks == 0 { 0.0 } else { self.dt_s() };
        let x = self.x;
        let reference = self.reference;
        let limits = self.limits;
        self.rti.prepare(&x, &reference, &limits, elapsed);
    }

    /// Solves this tick's QP with `path` and takes the step.
    pub fn feedback(&mut self, path: QpPath) -> RtiReport {
        self.rti.feedback(path)
    }

    /// Applies the first input for one control period (the model is the plant).
    pub fn advance(&mut self) {
        let u = self.rti.inputs()[0];
        self.reference.input_previous = u;
        let (next, _, _) = self.rti.model().rk4(&self.x, &u, self.dt_s());
        self.x = next;
        self.ticks += 1;
    }

    /// The plant's state.
    pub fn state(&self) -> &StateVector {
        &self.x
    }

    /// The solver.
    pub fn rti(&self) -> &SqpRti {
        &self.rti
    }

    /// The solver, mutable.
    pub fn rti_mut(&mut self) -> &mut SqpRti {
        &mut self.rti
    }

    /// Distance of the EE from its goal, m.
    pub fn ee_error_m(&mut self) -> f64 {
        let x = self.x;
        (self.rti.ee_kinematics(&x).position - self.goal).norm()
    }
}
