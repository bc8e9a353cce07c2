//! The geometric attitude law on its own (Lee et al.), for a caller that is given an attitude
//! or body-rate setpoint rather than a pose: an autopilot's attitude and rate loops (the
//! twin's PX4-style autopilot flies SET_ATTITUDE_TARGET through it). [`Pid6`](crate::Pid6)
//! and [`Pid4`](crate::Pid4) run the same law ([`attitude_torque`]) inside their cascades.
//!
//! ```text
//! e_R = ½ (R_dᵀR − RᵀR_d)^∨,   e_Ω = Ω − RᵀR_d Ω_d                       (body)
//! τ = J(−K_R e_R − K_Ω e_Ω − K_I,R ∫e_R dt) + Ω×JΩ − J(Ω^ RᵀR_dΩ_d − RᵀR_dΩ̇_d) + c × Rᵀ(m g ẑ)
//! ```
//!
//! Rates only (attitude ignored): R_d = R, so e_R = 0 and τ = J(−K_Ω(Ω − Ω_d)) + Ω×JΩ −
//! J Ω^Ω_d + c × Rᵀ(m g ẑ). The integrator stops per axis while the allocator reports the
//! torque saturated in that direction ([`AttitudeLaw::saturation_feedback`]).

use nalgebra::{UnitQuaternion, Vector3};
use platform::{RigidBodyState, Wrench};

use crate::controller::{
    AttitudeErrors, BodyParams, DT_MAX_S, DT_MIN_S, WindupGuard, attitude_errors, geometric_torque,
};
use crate::gains::{ControllerConfig, Pid4Gains, Pid6Gains, limit_norm};

/// Gains and limits of the attitude law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeGains {
    /// Attitude P, 1/s² (scaled by the inertia).
    pub kp_rot: f64,
    /// Rate D, 1/s (scaled by the inertia).
    pub kd_rot: f64,
    /// Attitude I, 1/s³ (scaled by the inertia).
    pub ki_rot: f64,
    /// Norm limit of the attitude integral (none: unbounded).
    pub integral_limit: Option<f64>,
    /// Norm limit of the torque, N·m (none: unbounded).
    pub max_torque_nm: Option<f64>,
}

impl From<&Pid6Gains> for AttitudeGains {
    fn from(g: &Pid6Gains) -> Self {
        Self {
            kp_rot: g.kp_rot,
            kd_rot: g.kd_rot,
            ki_rot: g.ki_rot,
            integral_limit: g.integral_limit,
            max_torque_nm: g.max_torque_nm,
        }
    }
}

impl From<&Pid4Gains> for AttitudeGains {
    fn from(g: &Pid4Gains) -> Self {
        Self {
            kp_rot: g.kp_rot,
            kd_rot: g.kd_rot,
            ki_rot: g.ki_rot,
            integral_limit: g.integral_limit,
            max_torque_nm: g.max_torque_nm,
        }
    }
}

impl AttitudeGains {
    /// The attitude gains of a PID profile (PID6 or PID4); `None` for the other controllers.
    pub fn from_config(config: &ControllerConfig) -> Option<Self> {
        match config {
            ControllerConfig::Pid6(g) => Some(g.into()),
            ControllerConfig::Pid4(g) => Some(g.into()),
            _ => None,
        }
    }
}

/// One step of the law with its integrator: `integral` advances by e_R dt (gated by the
/// allocator's saturation through `guard`, bounded by the integral limit), then τ, bounded by
/// the torque limit. The one implementation of the attitude loop (PID6, PID4, [`AttitudeLaw`]).
#[allow(
    clippy::too_many_arguments,
    reason = "the law's inputs, each needed once"
)]
pub(crate) fn attitude_torque(
    body: &BodyParams,
    state: &RigidBodyState,
    errors: &AttitudeErrors,
    gains: &AttitudeGains,
    integral: &mut Vector3<f64>,
    dt: f64,
    guard: &WindupGuard,
    blocked: &mut [bool; 6],
) -> Vector3<f64> {
    let mut increment = errors.e_r * dt;
    let torque_change = -(body.inertia_kgm2 * increment) * gains.ki_rot;
    guard.gate_torque(&mut increment, &torque_change, blocked);
    *integral = limit_norm(*integral + increment, gains.integral_limit);
    let torque = geometric_torque(
        body,
        state,
        errors,
        &Vector3::repeat(gains.kp_rot),
        &Vector3::repeat(gains.kd_rot),
        &(*integral * gains.ki_rot),
    );
    limit_norm(torque, gains.max_torque_nm)
}

/// The attitude law with its state (the integral and the anti-windup guard): pure, `dt` an
/// argument.
#[derive(Debug, Clone)]
pub struct AttitudeLaw {
    gains: AttitudeGains,
    integral: Vector3<f64>,
    guard: WindupGuard,
}

impl AttitudeLaw {
    /// A law with `gains`, integral empty.
    pub fn new(gains: AttitudeGains) -> Self {
        Self {
            gains,
            integral: Vector3::zeros(),
            guard: WindupGuard::default(),
        }
    }

    /// The gains in use.
    pub fn gains(&self) -> &AttitudeGains {
        &self.gains
    }

    /// The attitude integral ∫e_R dt.
    pub fn integral(&self) -> Vector3<f64> {
        self.integral
    }

    /// Clears the integral and the saturation memory.
    pub fn reset(&mut self) {
        self.integral = Vector3::zeros();
        self.guard.clear();
    }

    /// Body torque (N·m) toward the attitude `world_from_body_desired` with the rate
    /// feed-forward `body_rates_desired_radps` (given in the desired body frame), after `dt`
    /// seconds (clamped to [`DT_MIN_S`], [`DT_MAX_S`]). A non-finite input gives zero torque
    /// and leaves the integral unchanged: the output is always finite.
    pub fn attitude(
        &mut self,
        body: &BodyParams,
        state: &RigidBodyState,
        world_from_body_desired: &UnitQuaternion<f64>,
        body_rates_desired_radps: &Vector3<f64>,
        dt: f64,
    ) -> Vector3<f64> {
        let r_d = world_from_body_desired.to_rotation_matrix().into_inner();
        self.step(body, state, &r_d, body_rates_desired_radps, dt, true)
    }

    /// Body torque (N·m) tracking the body rates `body_rates_desired_radps` with no attitude
    /// feedback (the attitude is ignored, as PX4's rate setpoints). The integral is cleared.
    pub fn rates(
        &mut self,
        body: &BodyParams,
        state: &RigidBodyState,
        body_rates_desired_radps: &Vector3<f64>,
        dt: f64,
    ) -> Vector3<f64> {
        self.integral = Vector3::zeros();
        let r = state.world_from_body.to_rotation_matrix().into_inner();
        self.step(body, state, &r, body_rates_desired_radps, dt, false)
    }

    fn step(
        &mut self,
        body: &BodyParams,
        state: &RigidBodyState,
        r_d: &nalgebra::Matrix3<f64>,
        omega_d: &Vector3<f64>,
        dt: f64,
        integrate: bool,
    ) -> Vector3<f64> {
        let finite = r_d.iter().all(|x| x.is_finite())
            && omega_d.iter().all(|x| x.is_finite())
            && state.world_from_body.coords.iter().all(|x| x.is_finite())
            && state
                .angular_velocity_in_body_radps
                .iter()
                .all(|x| x.is_finite())
            && !dt.is_nan();
        if !finite {
            return Vector3::zeros();
        }
        let dt = dt.clamp(DT_MIN_S, DT_MAX_S);
        let errors = attitude_errors(state, r_d, omega_d, &Vector3::zeros());
        let mut gains = self.gains;
        if !integrate {
            gains.ki_rot = 0.0;
        }
        let before = self.integral;
        let mut blocked = [false; 6];
        let torque = attitude_torque(
            body,
            state,
            &errors,
            &gains,
            &mut self.integral,
            if integrate { dt } else { 0.0 },
            &self.guard,
            &mut blocked,
        );
        if torque.iter().all(|x| x.is_finite()) {
            torque
        } else {
            self.integral = before;
            Vector3::zeros()
        }
    }

    /// What the allocator could not achieve for the last torque (body frame): the next
    /// update does not integrate further into that saturation.
    pub fn saturation_feedback(
        &mut self,
        unallocated_in_body: &Wrench,
        world_from_body: &UnitQuaternion<f64>,
    ) {
        self.guard.record(unallocated_in_body, world_from_body);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Matrix3};

    fn body() -> BodyParams {
        BodyParams {
            mass_kg: 2.0,
            inertia_kgm2: Matrix3::from_diagonal(&Vector3::new(0.02, 0.02, 0.04)),
            com_in_body_m: Vector3::zeros(),
        }
    }

    fn gains() -> AttitudeGains {
        AttitudeGains {
            kp_rot: 200.0,
            kd_rot: 50.0,
            ki_rot: 0.0,
            integral_limit: None,
            max_torque_nm: None,
        }
    }

    #[test]
    fn all_zero_smoke_case_gives_no_torque() {
        let mut law = AttitudeLaw::new(gains());
        let state = RigidBodyState::at_rest(Isometry3::identity());
        let t = law.attitude(
            &body(),
            &state,
            &UnitQuaternion::identity(),
            &Vector3::zeros(),
            0.01,
        );
        assert_eq!(t, Vector3::zeros());
        assert_eq!(law.rates(&body(), &state, &Vector3::zeros(), 0.01), t);
    }

    #[test]
    fn a_roll_error_gives_a_restoring_torque_and_rates_a_rate_torque() {
        let mut law = AttitudeLaw::new(gains());
        let state = RigidBodyState::at_rest(Isometry3::identity());
        let rolled = UnitQuaternion::from_euler_angles(0.1, 0.0, 0.0);
        let t = law.attitude(&body(), &state, &rolled, &Vector3::zeros(), 0.01);
        // Desired roll +0.1 rad: torque +x, J k_R sin(0.1).
        assert!((t.x - 0.02 * 200.0 * 0.1f64.sin()).abs() < 1e-9, "{t}");
        assert!(t.y.abs() < 1e-12 && t.z.abs() < 1e-12);
        let t = law.rates(&body(), &state, &Vector3::new(0.0, 0.0, 1.0), 0.01);
        assert!((t.z - 0.04 * 50.0).abs() < 1e-9, "{t}");
    }

    #[test]
    fn non_finite_inputs_give_zero_torque() {
        let mut law = AttitudeLaw::new(AttitudeGains {
            ki_rot: 10.0,
            ..gains()
        });
        let state = RigidBodyState::at_rest(Isometry3::identity());
        let t = law.rates(&body(), &state, &Vector3::new(f64::NAN, 0.0, 0.0), 0.01);
        assert_eq!(t, Vector3::zeros());
        let t = law.attitude(
            &body(),
            &state,
            &UnitQuaternion::identity(),
            &Vector3::new(0.0, f64::INFINITY, 0.0),
            0.01,
        );
        assert_eq!(t, Vector3::zeros());
        assert_eq!(law.integral(), Vector3::zeros());
    }
}
