//! 6-DoF geometric PID for the fully actuated vehicles and the EE-only oracle
//! (AMBENCH_SPEC §2.2, the paper's "Geometric PID Base Tracking"):
//!
//! ```text
//! e_p = p_d − p,   e_v = v_d − v                                        (world)
//! F_w = m (a_d + K_p e_p + K_v e_v + K_i ∫e_p dt + g ẑ),   F_b = Rᵀ F_w
//! e_R = ½ (R_dᵀR − RᵀR_d)^∨,   e_Ω = Ω − RᵀR_d Ω_d                       (body)
//! τ = J(−K_R e_R − K_Ω e_Ω − K_I,R ∫e_R dt) + Ω×JΩ − J(Ω^ RᵀR_dΩ_d − RᵀR_dΩ̇_d)
//! ```
//!
//! plus c × Rᵀ(m g ẑ) for a centre of mass c away from the control frame (see
//! [`BodyParams`]). Integration stops per axis while the allocator reports the request
//! saturated in that direction.

use nalgebra::{Isometry3, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState, Wrench};

use crate::attitude::attitude_torque;
use crate::controller::{
    BaseController, BodyParams, ControllerCore, ControllerStatus, attitude_errors,
};
use crate::gains::{Pid6Gains, limit_norm};

/// The 6-DoF geometric PID.
#[derive(Debug, Clone)]
pub struct Pid6 {
    gains: Pid6Gains,
    core: ControllerCore,
    position_integral: Vector3<f64>,
    attitude_integral: Vector3<f64>,
}

impl Pid6 {
    /// A controller with validated `gains` for a body with `body` mass properties.
    pub fn new(gains: Pid6Gains, body: BodyParams) -> Self {
        Self {
            gains,
            core: ControllerCore::new("pid6", body),
            position_integral: Vector3::zeros(),
            attitude_integral: Vector3::zeros(),
        }
    }

    /// The gains in use.
    pub fn gains(&self) -> &Pid6Gains {
        &self.gains
    }
}

impl BaseController for Pid6 {
    fn reset(&mut self, _state: &RigidBodyState) {
        self.core.reset();
        self.position_integral = Vector3::zeros();
        self.attitude_integral = Vector3::zeros();
    }

    fn update(&mut self, state: &RigidBodyState, target: &Isometry3<f64>, dt: f64) -> Wrench {
        let (dt, mut status) = match self.core.begin(state, target, dt) {
            Ok(ok) => ok,
            Err(safe) => return safe,
        };
        let g = &self.gains;
        let core = &mut self.core;
        let m = core.body.mass_kg;
        let d = core.desired.update(target, dt, &state.pose());

        // Position loop (world frame).
        let e_p = d.pose.translation.vector - state.position_in_world_m;
        let e_v = d.velocity_mps - state.velocity_in_world_mps;
        let mut increment = e_p * dt;
        let change = increment * (m * g.ki_pos);
        core.guard
            .gate_force(&mut increment, &change, &mut status.windup_blocked);
        self.position_integral = limit_norm(self.position_integral + increment, g.integral_limit);
        let force_in_world = (d.acceleration_mps2
            + e_p * g.kp_pos
            + e_v * g.kd_pos
            + self.position_integral * g.ki_pos
            + Vector3::z() * GRAVITY_MPS2)
            * m;
        let force = limit_norm(
            state.world_from_body.inverse() * force_in_world,
            g.max_force_n,
        );

        // Attitude loop (body frame).
        let r_d = d.pose.rotation.to_rotation_matrix().into_inner();
        let errors = attitude_errors(
            state,
            &r_d,
            &d.angular_velocity_radps,
            &d.angular_acceleration_radps2,
        );
        let torque = attitude_torque(
            &core.body,
            state,
            &errors,
            &g.into(),
            &mut self.attitude_integral,
            dt,
            &core.guard,
            &mut status.windup_blocked,
        );

        let mut status = status.with_errors(e_p, e_v, &errors);
        status.position_integral = self.position_integral;
        status.attitude_integral = self.attitude_integral;
        self.core.finish(state, Wrench::new(force, torque), status)
    }

    fn saturation_feedback(&mut self, unallocated_in_body: &Wrench) {
        self.core.record_saturation(unallocated_in_body);
    }

    fn set_body(&mut self, body: BodyParams) {
        self.core.set_body(body);
    }

    fn status(&self) -> ControllerStatus {
        self.core.status()
    }
}
