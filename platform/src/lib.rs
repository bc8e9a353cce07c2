//! One description of each vehicle of amstack, read by the twin, the allocation, IK and MPC.
//!
//! A vehicle is a URDF (links, inertials, joints with origins, axes and limits, primitive
//! collision and visual shapes) plus a vehicle file in TOML (base and end-effector links, tool
//! tip, rotor layout, gripper, the twin's joint drives, cameras, the metric normaliser). The
//! five vehicles of AM-Bench — UA-Quad, UA-Hexa, FA-Hexa, Omni-Hexa and the EE-only oracle —
//! are compiled in from `platform/vehicles/`; a user adds one by writing the same two files.
//! Loading validates both and cross-checks them; a bad file is refused with an error naming
//! the file, the field and the value.
//!
//! From a description this crate computes, at any joint configuration q:
//! - forward kinematics `root_from_link(q)` of every link and of the tool tip;
//! - the geometric Jacobian of any point, columns `[a × (p − o); a]` per revolute joint and
//!   `[a; 0]` per prismatic joint, in the base frame;
//! - total mass, centre of mass and composite inertia about it,
//!   `J = Σ R_i I_i R_iᵀ + m_i(‖r_i‖²·1 − r_i r_iᵀ)`, r_i = c_i − c.
//!
//! Frames: base frame FLU, world ENU-like Z-up (AMBENCH_SPEC §0), quaternions w x y z on every
//! wire and file. This crate is pure: it reads no file, clock or socket; callers pass text in.

mod actuation;
mod builtin;
mod dynamics;
mod error;
mod held_joint;
mod kinematics;
mod link;
mod mass;
mod model;
mod parts;
mod px4_hil;
pub mod random;
mod rotor;
mod state;
mod tree_factor;
mod vehicle;
mod vehicle_file;
mod wrench;

#[cfg(test)]
mod tests;

pub use actuation::Actuation;
pub use builtin::BUILTIN_IDS;
pub use dynamics::{ArticulatedBody, Drive, TreeState, Workspace as DynamicsWorkspace};
pub use error::{DescriptionError, Problem};
pub use held_joint::HeldJoint;
pub use link::{
    ActuatorCommand, AttitudeSetpoint, DisturbanceReport, Measurement, PositionSetpoint,
    RateSetpoint, RotorReport,
};
pub use mass::MassProperties;
pub use model::{
    Geometry, Inertial, Joint, JointId, JointKind, JointLimits, KinematicModel, Link, LinkId,
    Shape, UNIT_AXIS_TOLERANCE,
};
pub use parts::{CameraMount, Gripper, JointDrive};
pub use px4_hil::{PX4_HIL_CONTROLS, Px4HilFile, Px4HilMap};
pub use random::RandomStream;
pub use rotor::{Rotor, RotorLayout, Spin, ThrustCurve, Tilt};
pub use state::RigidBodyState;
pub use vehicle::{ControlPresets, GRAVITY_MPS2, Vehicle};
pub use vehicle_file::{VEHICLE_SCHEMA, VehicleFile};
pub use wrench::Wrench;
