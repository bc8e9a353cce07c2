//! L1 adaptive control on the geometric PID baseline (AMBENCH_SPEC §2.4; the paper's
//! "L1 Adaptive Base Tracking", after Wu et al. 2025).
//!
//! Baseline: the PID6 law without integrators, F_pd = m(a_d + K_p e_p + K_v e_v + g ẑ),
//! τ_pd = J(−K_R e_R − K_Ω e_Ω) + Ω×JΩ − J(Ω^ RᵀR_dΩ_d − RᵀR_dΩ̇_d). Each tick:
//!
//! ```text
//! predictor   v̂⁺ = v̂ + dt(−g ẑ + R F_b/m + h_v + A_v ṽ)
//!             ω̂⁺ = ω̂ + dt(−J⁻¹(Ω×JΩ) + J⁻¹τ + h_ω + A_ω ω̃)
//! errors      ṽ = v̂ − v,   ω̃ = ω̂ − Ω
//! adaptation  h = −(e^{A dt} − 1)⁻¹ A e^{A dt} x̃           (elementwise, A diagonal)
//! estimates   σ_F = m Rᵀ h_v,  σ_τ = J h_ω,  each projected onto its norm bound
//! filter      σ̄ ← β σ̄ + (1 − β) σ,  β = e^{−2π f_c dt}
//! command     F_b = Rᵀ F_pd − mix_lin σ̄_F,   τ = τ_pd − mix_ang σ̄_τ
//! ```
//!
//! Differences from the reference, on purpose:
//! - order: the predictor is propagated over the last interval with the wrench that was
//!   actually applied in it, then compared with the new measurement (the reference
//!   propagates first and compares the prediction for t + dt with the measurement at t);
//! - the wrench fed to the predictor is the one the allocator achieved (requested minus
//!   unallocated), so saturation does not look like a disturbance and the estimate does not
//!   wind up; the filter state also stops, per axis, growing a request already saturated;
//! - the desired rate term uses RᵀR_dΩ_d as the PID does (the reference's L1 uses R_dᵀR);
//! - the angular predictor turns the body under the torque about its centre of mass,
//!   τ − c × F (the reference's bodies are controlled at their centre of mass).

use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState, Wrench};

use crate::controller::{
    BaseController, BodyParams, ControllerCore, ControllerStatus, attitude_errors, geometric_torque,
};
use crate::gains::{L1Config, limit_norm};

/// Where |e^{A dt} − 1| is below this the adaptation gain is taken as zero.
const ADAPTATION_EPS: f64 = 1e-10;

/// The L1 adaptive controller.
#[derive(Debug, Clone)]
pub struct L1Adaptive {
    config: L1Config,
    core: ControllerCore,
    inertia_inverse: Matrix3<f64>,
    predictor: Option<Predictor>,
    /// σ̄_F, body frame, N.
    filtered_force: Vector3<f64>,
    /// σ̄_τ, body frame, N·m.
    filtered_torque: Vector3<f64>,
    /// What the allocator could not achieve of the last request.
    last_unallocated: Wrench,
}

/// Predictor state and what propagating it needs from the last tick.
#[derive(Debug, Clone, Copy)]
struct Predictor {
    /// v̂, world, m/s.
    velocity: Vector3<f64>,
    /// ω̂, body, rad/s.
    angular_velocity: Vector3<f64>,
    /// ṽ, ω̃ of the last tick.
    velocity_error: Vector3<f64>,
    angular_velocity_error: Vector3<f64>,
    /// h_v, h_ω of the last tick.
    h_v: Vector3<f64>,
    h_w: Vector3<f64>,
    /// Attitude and body rate at the last tick.
    attitude: UnitQuaternion<f64>,
    omega: Vector3<f64>,
}

/// −(e^{a dt} − 1)⁻¹ a e^{a dt}, elementwise.
pub(crate) fn adaptation_gain(a: &Vector3<f64>, dt: f64) -> Vector3<f64> {
    a.map(|a| {
        let e = (a * dt).exp();
        let denom = e - 1.0;
        if denom.abs() <= ADAPTATION_EPS {
            0.0
        } else {
            -a * e / denom
        }
    })
}

impl L1Adaptive {
    /// A controller with a validated `config` for a body with `body` mass properties.
    pub fn new(config: L1Config, body: BodyParams) -> Self {
        Self {
            config,
            inertia_inverse: body.inertia_inverse(),
            core: ControllerCore::new("l1", body),
            predictor: None,
            filtered_force: Vector3::zeros(),
            filtered_torque: Vector3::zeros(),
            last_unallocated: Wrench::ZERO,
        }
    }

    /// The configuration in use.
    pub fn config(&self) -> &L1Config {
        &self.config
    }
}

impl BaseController for L1Adaptive {
    fn reset(&mut self, _state: &RigidBodyState) {
        self.core.reset();
        // The predictor restarts from the first measurement after the reset.
        self.predictor = None;
        self.filtered_force = Vector3::zeros();
        self.filtered_torque = Vector3::zeros();
        self.last_unallocated = Wrench::ZERO;
    }

    fn update(&mut self, state: &RigidBodyState, target: &Isometry3<f64>, dt: f64) -> Wrench {
        let (dt, mut status) = match self.core.begin(state, target, dt) {
            Ok(ok) => ok,
            Err(safe) => return safe,
        };
        let c = self.config;
        let m = self.core.body.mass_kg;
        let j = self.core.body.inertia_kgm2;
        let r = state.world_from_body;
        let v = state.velocity_in_world_mps;
        let omega = state.angular_velocity_in_body_radps;

        // 1–2. Propagate the predictor over the last interval with the wrench applied in it,
        // then compare with this measurement.
        let (v_hat, w_hat) = match (self.predictor, self.core.last_output()) {
            (Some(p), Some(requested)) => {
                let applied = requested - self.last_unallocated;
                let v_dot = -Vector3::z() * GRAVITY_MPS2
                    + p.attitude * applied.force / m
                    + p.h_v
                    + c.a_lin.component_mul(&p.velocity_error);
                // The force acts at the control frame's origin, not at the centre of mass c:
                // the body turns under τ − c × F (at hover this cancels the gravity-moment
                // term of τ; leaving it out makes the predictor invent a disturbance).
                let torque_about_com =
                    applied.torque - self.core.body.com_in_body_m.cross(&applied.force);
                let w_dot = -self.inertia_inverse * p.omega.cross(&(j * p.omega))
                    + self.inertia_inverse * torque_about_com
                    + p.h_w
                    + c.a_ang.component_mul(&p.angular_velocity_error);
                (p.velocity + v_dot * dt, p.angular_velocity + w_dot * dt)
            }
            _ => (v, omega),
        };
        let velocity_error = v_hat - v;
        let angular_velocity_error = w_hat - omega;

        // 3–4. Piecewise-constant adaptation and the projected estimates.
        let h_v = adaptation_gain(&c.a_lin, dt).component_mul(&velocity_error);
        let h_w = adaptation_gain(&c.a_ang, dt).component_mul(&angular_velocity_error);
        let sigma_force = limit_norm(r.inverse() * (h_v * m), c.sigma_max_lin_n);
        let sigma_torque = limit_norm(j * h_w, c.sigma_max_ang_nm);
        self.predictor = Some(Predictor {
            velocity: v_hat,
            angular_velocity: w_hat,
            velocity_error,
            angular_velocity_error,
            h_v,
            h_w,
            attitude: r,
            omega,
        });

        // 5. Low-pass filter, not growing a request the allocator reports saturated.
        let beta_lin = (-2.0 * std::f64::consts::PI * c.filter_bandwidth_lin_hz * dt).exp();
        let beta_ang = (-2.0 * std::f64::consts::PI * c.filter_bandwidth_ang_hz * dt).exp();
        let mut step_force = (sigma_force - self.filtered_force) * (1.0 - beta_lin);
        let mut step_torque = (sigma_torque - self.filtered_torque) * (1.0 - beta_ang);
        // The command moves by −mix·step: gate in the frames the allocator reports in.
        let mut step_force_world = r * step_force;
        let change = -step_force_world * c.adaptive_mix_lin;
        self.core
            .guard
            .gate_force(&mut step_force_world, &change, &mut status.windup_blocked);
        step_force = r.inverse() * step_force_world;
        let change = -step_torque * c.adaptive_mix_ang;
        self.core
            .guard
            .gate_torque(&mut step_torque, &change, &mut status.windup_blocked);
        self.filtered_force += step_force;
        self.filtered_torque += step_torque;
        let adaptive_force = -self.filtered_force;
        let adaptive_torque = -self.filtered_torque;

        // 6. Baseline plus adaptation.
        let d = self.core.desired.update(target, dt, &state.pose());
        let e_p = d.pose.translation.vector - state.position_in_world_m;
        let e_v = d.velocity_mps - v;
        let force_pd_world = (d.acceleration_mps2
            + c.k_pos.component_mul(&e_p)
            + c.k_vel.component_mul(&e_v)
            + Vector3::z() * GRAVITY_MPS2)
            * m;
        let r_d = d.pose.rotation.to_rotation_matrix().into_inner();
        let errors = attitude_errors(
            state,
            &r_d,
            &d.angular_velocity_radps,
            &d.angular_acceleration_radps2,
        );
        let torque_pd = geometric_torque(
            &self.core.body,
            state,
            &errors,
            &c.k_ori,
            &c.k_ang_vel,
            &Vector3::zeros(),
        );
        let force = r.inverse() * force_pd_world + adaptive_force * c.adaptive_mix_lin;
        let torque = torque_pd + adaptive_torque * c.adaptive_mix_ang;

        let mut status = status.with_errors(e_p, e_v, &errors);
        status.adaptive_force_n = Some(adaptive_force);
        status.adaptive_torque_nm = Some(adaptive_torque);
        self.last_unallocated = Wrench::ZERO;
        self.core.finish(state, Wrench::new(force, torque), status)
    }

    fn saturation_feedback(&mut self, unallocated_in_body: &Wrench) {
        if unallocated_in_body.is_finite() {
            self.last_unallocated = *unallocated_in_body;
            self.core.record_saturation(unallocated_in_body);
        }
    }

    fn set_body(&mut self, body: BodyParams) {
        self.inertia_inverse = body.inertia_inverse();
        self.core.set_body(body);
    }

    fn status(&self) -> ControllerStatus {
        self.core.status()
    }
}
