//! Nested 4-DoF geometric PID for the under-actuated vehicles (AMBENCH_SPEC §2.3): the
//! position loop builds a desired thrust vector and, with the target's heading, a desired
//! attitude; the attitude loop tracks it every tick. The body force is restricted to
//! [0, 0, f].
//!
//! Outer loop, every `outer_loop_decimation` ticks (and on the first tick):
//!
//! ```text
//! A = m (K_p e_p + K_v e_v + K_i ∫e_p + g ẑ + a_d)      K = diag(xy, xy, z)
//! A ← A tilted at most θ_max from ẑ                    (horizontal part scaled, A_z kept)
//! f = A · (R ê3)                                        held until the next outer update
//! b3d = A/|A|,  b2d = (b3d × b1)/|b3d × b1|,  b1d = b2d × b3d,  b1 = heading x axis
//! R_d = [b1d b2d b3d]
//! ```
//!
//! Inner loop: the torque law of [`crate::Pid6`] toward R_d.
//!
//! Differences from the reference, each noted where it is made:
//! - the desired thrust direction is held within `max_tilt_rad` (default 45°, PX4's
//!   MPC_TILTMAX_AIR; π/2 or more, or none, for no limit) of the vertical: its horizontal part is scaled down, its vertical part
//!   kept (at least a tenth of the weight, so a demand to fall still has a direction). The
//!   reference has no limit, and its position loop, wound up against a wall or a held load,
//!   asks for thrust directions past 90°: the vehicle turns over (`amstack bench --platform
//!   ua-hexa --rollouts 30`, seed 0: Lemon Harvesting 16 of 30 rollouts, Wipe Window 8);
//! - the reference differentiates R_d every tick although R_d only changes at outer
//!   updates, so its Ω_d is a spike of 3× the rate on one tick in three and zero otherwise;
//!   here Ω_d = log(R_d,prevᵀ R_d)/outer_dt is computed at each outer update and held;
//! - the reference's decimation counter is global across environments; here it belongs to
//!   the controller;
//! - the velocity error is that of the centre of mass (v + R (Ω × c), c from the stack's
//!   posture-following body model), not of the base origin. The rate loop of the UA-Hexa's
//!   gains is deadbeat (kd_rot·dt = 1): each outer update's rate feed-forward turns the base
//!   about its centre of mass within one tick, which moves the base origin's velocity by
//!   Ω × c. Fed back through k_d,xy and differentiated into the next Ω_d, that jump returns
//!   with a gain of k_d,xy·|c|/(g·outer_dt), above one once the arm carries the centre of
//!   mass ~3 cm from the base origin: the UA-Hexa's arm-sweep diverged at t = 4.6 s. The
//!   centre of mass does not jump when the body turns about it.

use nalgebra::{Isometry3, Matrix3, Rotation3, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState, Wrench};

use crate::attitude::attitude_torque;
use crate::controller::{
    BaseController, BodyParams, ControllerCore, ControllerStatus, attitude_errors,
};
use crate::gains::{Pid4Gains, limit_norm};
use crate::so3::clamp_elementwise;

/// Below this norm (N) the desired thrust vector has no direction: body +z is used.
const THRUST_DIRECTION_EPS: f64 = 1e-6;
/// Under a tilt limit, the least vertical part of the desired thrust, as a fraction of the
/// weight.
const TILT_LIMIT_MIN_VERTICAL: f64 = 0.1;

/// `thrust` (N, world) with its direction at most `max_tilt` (rad, below π/2) from the
/// vertical: the horizontal part scaled down to `A_z·tan(max_tilt)`, the vertical part kept
/// but at least `min_vertical`. Unchanged when already within the limit.
pub(crate) fn limit_tilt(thrust: &Vector3<f64>, max_tilt: f64, min_vertical: f64) -> Vector3<f64> {
    let vertical = thrust.z.max(min_vertical);
    let horizontal = Vector3::new(thrust.x, thrust.y, 0.0);
    let allowed = vertical * max_tilt.tan();
    let norm = horizontal.norm();
    let horizontal = if norm > allowed {
        horizontal * (allowed / norm)
    } else {
        horizontal
    };
    Vector3::new(horizontal.x, horizontal.y, vertical)
}

/// The nested 4-DoF geometric PID.
#[derive(Debug, Clone)]
pub struct Pid4 {
    gains: Pid4Gains,
    core: ControllerCore,
    position_integral: Vector3<f64>,
    attitude_integral: Vector3<f64>,
    tick: u64,
    outer: Option<Outer>,
}

/// What the outer loop hands the inner loop, held between outer updates.
#[derive(Debug, Clone, Copy)]
struct Outer {
    thrust_n: f64,
    r_d: Matrix3<f64>,
    omega_d: Vector3<f64>,
    omega_dot_d: Vector3<f64>,
}

impl Pid4 {
    /// A controller with validated `gains` for a body with `body` mass properties.
    pub fn new(gains: Pid4Gains, body: BodyParams) -> Self {
        Self {
            gains,
            core: ControllerCore::new("pid4", body),
            position_integral: Vector3::zeros(),
            attitude_integral: Vector3::zeros(),
            tick: 0,
            outer: None,
        }
    }

    /// The gains in use.
    pub fn gains(&self) -> &Pid4Gains {
        &self.gains
    }
}

/// Desired attitude from the thrust vector and the heading (the target's x axis).
fn desired_attitude(thrust: &Vector3<f64>, heading: &Matrix3<f64>) -> Matrix3<f64> {
    let norm = thrust.norm();
    let b3 = if norm > THRUST_DIRECTION_EPS {
        thrust / norm
    } else {
        Vector3::z()
    };
    let b1 = heading.column(0).into_owned();
    let c = b3.cross(&b1);
    let c_norm = c.norm();
    let (b1d, b2d) = if c_norm > THRUST_DIRECTION_EPS {
        let b2d = c / c_norm;
        (b2d.cross(&b3), b2d)
    } else {
        // Heading along the thrust: fall back to the heading's own axes.
        (b1, heading.column(1).into_owned())
    };
    Matrix3::from_columns(&[b1d, b2d, b3])
}

impl BaseController for Pid4 {
    fn reset(&mut self, _state: &RigidBodyState) {
        self.core.reset();
        self.position_integral = Vector3::zeros();
        self.attitude_integral = Vector3::zeros();
        self.tick = 0;
        self.outer = None;
    }

    fn update(&mut self, state: &RigidBodyState, target: &Isometry3<f64>, dt: f64) -> Wrench {
        let (dt, mut status) = match self.core.begin(state, target, dt) {
            Ok(ok) => ok,
            Err(safe) => return safe,
        };
        let g = self.gains;
        let m = self.core.body.mass_kg;
        let d = self.core.desired.update(target, dt, &state.pose());
        let e_p = d.pose.translation.vector - state.position_in_world_m;
        // The velocity of the centre of mass, not of the base origin (see the module doc).
        let com_velocity = state.velocity_in_world_mps
            + state.world_from_body
                * state
                    .angular_velocity_in_body_radps
                    .cross(&self.core.body.com_in_body_m);
        let e_v = d.velocity_mps - com_velocity;

        let decimation = u64::from(g.outer_loop_decimation.max(1));
        let outer = match self.outer {
            Some(held) if !self.tick.is_multiple_of(decimation) => held,
            previous => {
                let outer_dt = dt * decimation as f64;
                let mut increment = e_p * outer_dt;
                let ki = Vector3::new(g.ki_xy, g.ki_xy, g.ki_z);
                let change = increment.component_mul(&ki) * m;
                self.core
                    .guard
                    .gate_force(&mut increment, &change, &mut status.windup_blocked);
                self.position_integral =
                    limit_norm(self.position_integral + increment, g.integral_limit);
                let kp = Vector3::new(g.kp_xy, g.kp_xy, g.kp_z);
                let kd = Vector3::new(g.kd_xy, g.kd_xy, g.kd_z);
                let mut thrust_vector = (kp.component_mul(&e_p)
                    + kd.component_mul(&e_v)
                    + ki.component_mul(&self.position_integral)
                    + Vector3::z() * GRAVITY_MPS2
                    + d.acceleration_mps2)
                    * m;
                // π/2 or more: no limit (the reference).
                if let Some(max_tilt) = g.max_tilt_rad.filter(|t| *t < std::f64::consts::FRAC_PI_2)
                {
                    let min_vertical = TILT_LIMIT_MIN_VERTICAL * m * GRAVITY_MPS2;
                    thrust_vector = limit_tilt(&thrust_vector, max_tilt, min_vertical);
                }
                let body_z = state.world_from_body * Vector3::z();
                let mut thrust_n = thrust_vector.dot(&body_z);
                if let Some(max) = g.max_force_n {
                    thrust_n = thrust_n.clamp(-max, max);
                }
                let heading = d.pose.rotation.to_rotation_matrix().into_inner();
                let r_d = desired_attitude(&thrust_vector, &heading);
                // Desired rate from consecutive outer updates (see the module doc).
                let (omega_d, omega_dot_d) = match previous {
                    None => (Vector3::zeros(), Vector3::zeros()),
                    Some(p) => {
                        let step = Rotation3::from_matrix_unchecked(p.r_d.transpose() * r_d);
                        let omega = step.scaled_axis() / outer_dt;
                        (omega, (omega - p.omega_d) / outer_dt)
                    }
                };
                let held = Outer {
                    thrust_n,
                    r_d,
                    omega_d,
                    omega_dot_d,
                };
                self.outer = Some(held);
                held
            }
        };
        self.tick = self.tick.wrapping_add(1);

        let limit = self.core.desired.derivative_limit;
        let omega_d = clamp_elementwise(&outer.omega_d, limit);
        let omega_dot_d = clamp_elementwise(&outer.omega_dot_d, limit);
        let errors = attitude_errors(state, &outer.r_d, &omega_d, &omega_dot_d);
        let torque = attitude_torque(
            &self.core.body,
            state,
            &errors,
            &(&g).into(),
            &mut self.attitude_integral,
            dt,
            &self.core.guard,
            &mut status.windup_blocked,
        );

        let mut status = status.with_errors(e_p, e_v, &errors);
        status.position_integral = self.position_integral;
        status.attitude_integral = self.attitude_integral;
        self.core.finish(
            state,
            Wrench::new(Vector3::new(0.0, 0.0, outer.thrust_n), torque),
            status,
        )
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
