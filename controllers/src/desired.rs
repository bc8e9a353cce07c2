//! Desired-state generation: velocities, accelerations, angular rate and its derivative by
//! finite differences of successive pose targets (AMBENCH_SPEC §2.2).
//!
//! With targets (p_k, R_k) arriving every dt:
//!
//! ```text
//! v_d = (p_k − p_{k−1}) / dt            a_d = (v_d,k − v_d,k−1) / dt
//! Ω_d = log(R_{k−1}ᵀ R_k)^∨ / dt        Ω̇_d = (Ω_d,k − Ω_d,k−1) / dt
//! ```
//!
//! Ω_d is the desired body rate expressed in the desired body frame, which is how the
//! geometric laws use it (e_Ω = Ω − RᵀR_d Ω_d). Two differences from the reference:
//! - the reference takes 2·log(q_k ⊗ q_{k−1}*)/dt with a log that already carries the full
//!   angle, which doubles the rate (AMBENCH_SPEC §9 item 3); we use the true rate;
//! - the reference's q_k ⊗ q_{k−1}* is the world-frame increment, then used as a body-frame
//!   rate; we take the body-frame increment R_{k−1}ᵀR_k.
//!
//! As in the reference, every derivative handed to a controller is clamped elementwise to
//! [−limit, limit] (default 1), while the values kept for the next difference are not; the
//! first target after a reset gives zero derivatives.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::so3::clamp_elementwise;

/// What the base controllers track at one tick.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DesiredState {
    /// Target pose `world_from_body`.
    pub pose: Isometry3<f64>,
    /// World frame, m/s.
    pub velocity_mps: Vector3<f64>,
    /// World frame, m/s².
    pub acceleration_mps2: Vector3<f64>,
    /// Desired body frame, rad/s.
    pub angular_velocity_radps: Vector3<f64>,
    /// Desired body frame, rad/s².
    pub angular_acceleration_radps2: Vector3<f64>,
}

impl DesiredState {
    /// Holding `pose` still.
    pub fn hold(pose: Isometry3<f64>) -> Self {
        Self {
            pose,
            velocity_mps: Vector3::zeros(),
            acceleration_mps2: Vector3::zeros(),
            angular_velocity_radps: Vector3::zeros(),
            angular_acceleration_radps2: Vector3::zeros(),
        }
    }
}

/// Finite-difference generator of [`DesiredState`]s.
#[derive(Debug, Clone)]
pub struct DesiredStateGenerator {
    /// Clamp of every derivative handed out (the reference's ±1).
    pub derivative_limit: f64,
    previous: Option<Previous>,
}

#[derive(Debug, Clone, Copy)]
struct Previous {
    pose: Isometry3<f64>,
    velocity: Vector3<f64>,
    angular_velocity: Vector3<f64>,
}

impl Default for DesiredStateGenerator {
    fn default() -> Self {
        Self::new(1.0)
    }
}

impl DesiredStateGenerator {
    /// A generator whose derivatives are clamped to ±`derivative_limit`.
    pub fn new(derivative_limit: f64) -> Self {
        Self {
            derivative_limit,
            previous: None,
        }
    }

    /// Forget the history: the next target gives zero derivatives.
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// The last accepted target, if any.
    pub fn last_target(&self) -> Option<Isometry3<f64>> {
        self.previous.map(|p| p.pose)
    }

    /// Desired state for `target` after `dt` seconds (dt > 0 and finite: the caller's
    /// guard). A target with a non-finite number is not accepted: the previous one is held
    /// with zero derivatives (and, before any target, `fallback` is).
    pub fn update(
        &mut self,
        target: &Isometry3<f64>,
        dt: f64,
        fallback: &Isometry3<f64>,
    ) -> DesiredState {
        if !is_finite_pose(target) {
            return DesiredState::hold(self.previous.map_or(*fallback, |p| p.pose));
        }
        let pose = Isometry3::from_parts(
            target.translation,
            UnitQuaternion::new_normalize(*target.rotation.quaternion()),
        );
        let Some(prev) = self.previous else {
            self.previous = Some(Previous {
                pose,
                velocity: Vector3::zeros(),
                angular_velocity: Vector3::zeros(),
            });
            return DesiredState::hold(pose);
        };
        let velocity = (pose.translation.vector - prev.pose.translation.vector) / dt;
        let acceleration = (velocity - prev.velocity) / dt;
        let angular_velocity = (prev.pose.rotation.inverse() * pose.rotation).scaled_axis() / dt;
        let angular_acceleration = (angular_velocity - prev.angular_velocity) / dt;
        self.previous = Some(Previous {
            pose,
            velocity,
            angular_velocity,
        });
        let l = self.derivative_limit;
        DesiredState {
            pose,
            velocity_mps: clamp_elementwise(&velocity, l),
            acceleration_mps2: clamp_elementwise(&acceleration, l),
            angular_velocity_radps: clamp_elementwise(&angular_velocity, l),
            angular_acceleration_radps2: clamp_elementwise(&angular_acceleration, l),
        }
    }
}

/// True when translation and rotation are finite.
pub fn is_finite_pose(pose: &Isometry3<f64>) -> bool {
    pose.translation.vector.iter().all(|x| x.is_finite())
        && pose.rotation.coords.iter().all(|x| x.is_finite())
}
