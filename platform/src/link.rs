//! What crosses the `Link` seam each control tick: actuator commands out, measurements in.
//! The same types serve the in-process twin, the twin in another process and a real
//! autopilot; fields a source cannot fill stay at their defaults.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::{RigidBodyState, Wrench};

/// Actuator commands for one control period.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct ActuatorCommand {
    /// Thrust per rotor, N, in the vehicle's rotor order (empty for the EE-only oracle).
    pub rotor_thrusts_n: Vec<f64>,
    /// Position target of every movable joint in configuration order — arm, gripper,
    /// Omni-Hexa tilt hinges — rad or m. Clamped to the joint limits.
    pub joint_targets: Vec<f64>,
    /// A wrench on the base body, about its origin, body frame: the EE-only oracle's
    /// actuation (no rotors, no allocation).
    pub direct_wrench_in_body: Option<Wrench>,
}

/// A desired attitude and body force: the attitude level of the control cascade (what a base
/// controller steers to, and what a vehicle's own attitude loop and allocation can fly).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AttitudeSetpoint {
    /// Desired attitude `world_from_body` (FLU body in the ENU-like world).
    pub world_from_body: UnitQuaternion<f64>,
    /// Desired body force, body frame (FLU), N.
    pub force_in_body_n: Vector3<f64>,
    /// Body-rate feed-forward (FLU), rad/s; `None`: no rate feed-forward.
    pub body_rates_radps: Option<Vector3<f64>>,
}

/// Body rates and a body force: the rate level of the control cascade (what a vehicle's own
/// rate loop and allocation can fly; the attitude law runs on the side that sends it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RateSetpoint {
    /// Desired body rates (FLU), rad/s.
    pub body_rates_radps: Vector3<f64>,
    /// Desired body force, body frame (FLU), N.
    pub force_in_body_n: Vector3<f64>,
}

impl RateSetpoint {
    /// Whether every value is finite.
    pub fn is_finite(&self) -> bool {
        self.body_rates_radps
            .iter()
            .chain(self.force_in_body_n.iter())
            .all(|x| x.is_finite())
    }
}

/// A base position and heading: the position level of the control cascade (what a vehicle's
/// own position controller — PX4's in OFFBOARD — can fly). Roll and pitch are the position
/// controller's to choose: a fully actuated vehicle's tilted target pose is flown level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PositionSetpoint {
    /// Target base origin, world (ENU-like, z up), m.
    pub position_in_world_m: Vector3<f64>,
    /// Target heading: rotation about world z, counter-clockwise from +x (east), rad.
    pub yaw_rad: f64,
}

impl PositionSetpoint {
    /// The position and heading of a target base pose (its yaw: the heading of body x
    /// projected on the ground plane, `atan2(R₁₀, R₀₀)`).
    pub fn of_pose(world_from_base: &Isometry3<f64>) -> Self {
        let r = world_from_base.rotation.to_rotation_matrix();
        Self {
            position_in_world_m: world_from_base.translation.vector,
            yaw_rad: r[(1, 0)].atan2(r[(0, 0)]),
        }
    }

    /// Whether every value is finite.
    pub fn is_finite(&self) -> bool {
        self.yaw_rad.is_finite() && self.position_in_world_m.iter().all(|x| x.is_finite())
    }
}

/// One rotor over the last control period.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RotorReport {
    /// Thrust commanded, N.
    pub commanded_n: f64,
    /// Thrust the motor produced (limits and dynamics), N.
    pub realised_n: f64,
    /// Magnitude of the thrust vector after ground and near-wall effects, N.
    pub applied_n: f64,
    /// The command was outside [T_min, T_max].
    pub saturated: bool,
    /// Ground-effect gain 1/ratio applied (1 when off or far).
    pub ground_effect_gain: f64,
    /// Distance to the surface below along −thrust axis, m (the cast's maximum on a miss).
    pub ground_distance_m: f64,
    /// Horizontal distance to the nearest wall in the rotor's fan, m (maximum on a miss).
    pub wall_distance_m: f64,
}

/// Forces of each disturbance model over the last control period, base body frame, N.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct DisturbanceReport {
    /// −c ∘ v_body.
    pub drag_n: Vector3<f64>,
    /// Rᵀ F_wind.
    pub wind_n: Vector3<f64>,
    /// Extra rotor force from the ground effect (sum over rotors).
    pub ground_effect_n: Vector3<f64>,
    /// Extra rotor force from the near-wall effect (sum over rotors).
    pub near_wall_n: Vector3<f64>,
}

/// What is measured at the end of a control period.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Measurement {
    /// Simulated time, s.
    pub time_s: f64,
    /// Base link: pose, world velocity of its origin, body angular velocity.
    pub base: RigidBodyState,
    /// Every movable joint, configuration order, rad or m.
    pub joint_positions: Vec<f64>,
    /// Every movable joint, rad/s or m/s.
    pub joint_velocities: Vec<f64>,
    /// End-effector link frame in the world.
    pub world_from_ee: Isometry3<f64>,
    /// Per rotor.
    pub rotors: Vec<RotorReport>,
    /// Per disturbance model.
    pub disturbances: DisturbanceReport,
}
