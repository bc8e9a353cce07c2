//! The simulator twin of amstack: the five vehicles in rapier3d (f64), with the
//! disturbances of AM-Bench, driven one control period per actuator command.
//!
//! - [`Twin`]: a vehicle built from its `platform` description as one multibody (floating
//!   base, arm joints on position drives, gripper fingers, tilt hinges), per-rotor thrust at
//!   the rotor positions along their current axes with reaction torques, the `allocation`
//!   crate's rotor actuator as the motor model.
//! - [`aero`]: ground effect, near-wall effect, drag and wind (AMBENCH_SPEC §3.2), with
//!   distances from parry ray casts that skip the robot's own colliders.
//! - [`TwinConfig`]: control rate (120 Hz), physics substeps, disturbance switches, motor
//!   dynamics, noise, seed. Same seed, same commands → bit-identical results.
//! - [`sensors`]: the simulated IMU and pose sensor (motion capture) the flight stack's
//!   estimator is fed with, from the truth of each control tick and the `estimator` crate's
//!   sensor models.
//! - [`ipc`]: the twin in its own process, served over iceoryx2 shared memory
//!   (`amstack twin serve`), lockstep or realtime, with a handshake, loss detection and a
//!   failsafe.
//! - [`visuals`]: the scene as a renderer sees it (shapes, poses, roles of every scene
//!   collider), read-only; the renderer itself is the `render` crate, so the physics core and
//!   its tests do not link wgpu.
//!
//! The twin as a PX4-style autopilot over MAVLink 2 (`amstack twin serve --mavlink`) is the
//! `twin_autopilot` crate: this one builds without the MAVLink crates.
//!
//! Frames: world Z-up, gravity (0, 0, −9.81) m/s²; body FLU. rapier's glam types stay
//! inside this crate ([`convert`] is the one boundary).

pub mod aero;
mod config;
mod convert;
mod error;
pub mod ipc;
mod observer;
pub mod sensors;
pub mod tasks;
mod twin;
mod vehicle_body;
pub mod visuals;

#[cfg(test)]
mod tests;

pub use config::{
    Disturbances, MotorConfig, NoiseConfig, SaturatedAllocation, TiltThrust, TwinConfig,
    VehicleDynamics,
};
pub use error::TwinError;
pub use observer::TwinObserver;
pub use tasks::{GraspMode, HeldJoint, TaskId, TaskObservation, TaskSnapshot, TaskStatus};
pub use twin::Twin;
pub use vehicle_body::{ROBOT_GROUP, WORLD_GROUP};
pub use visuals::{SceneVisual, VisualRole, VisualShape};
