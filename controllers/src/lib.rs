//! Base-tracking controllers and whole-body IK of amstack — a pure crate: no I/O, no clock;
//! time arrives as `dt` in seconds.
//!
//! - [`Pid6`]: 6-DoF geometric PID for the fully actuated vehicles and the EE-only oracle,
//!   F_w = m(a_d + K_p e_p + K_v e_v + K_i∫e_p + g ẑ), τ = J(−K_R e_R − K_Ω e_Ω − K_I∫e_R) +
//!   Ω×JΩ − J(Ω^RᵀR_dΩ_d − RᵀR_dΩ̇_d), with e_R = ½(R_dᵀR − RᵀR_d)^∨.
//! - [`Pid4`]: the nested 4-DoF law of the under-actuated vehicles: thrust direction and
//!   heading from the position loop (decimated), the attitude law every tick, F_b = [0, 0, f].
//! - [`AttitudeLaw`]: the attitude law alone (attitude or body-rate setpoints, e.g. an
//!   autopilot's attitude loop); PID6 and PID4 run the same law inside their cascades.
//! - [`L1Adaptive`]: L1 adaptive control on the integrator-free PID baseline.
//! - [`DesiredStateGenerator`]: velocities, accelerations and rates from pose targets.
//! - [`ik`]: whole-body inverse kinematics over base pose and arm joints.
//!
//! All base controllers implement [`BaseController`]: update from the measured state, the
//! target and dt; reset; saturation feedback from the allocator (anti-windup); a
//! serialisable [`ControllerStatus`]. Gains are typed presets ([`Pid6Gains::am_bench`], …)
//! loadable from TOML ([`ControllerConfig::from_toml_str`]); [`profile`] picks the
//! reference's controller for a vehicle.

mod attitude;
mod controller;
mod desired;
mod gains;
pub mod ik;
mod l1;
pub mod mpc;
mod pid4;
mod pid6;
mod profile;
mod so3;

pub use attitude::{AttitudeGains, AttitudeLaw};
pub use controller::{
    AttitudeTarget, BaseController, BodyParams, ControllerStatus, DT_MAX_S, DT_MIN_S, InputHealth,
    PX4_ATTITUDE_P_PER_S, SATURATION_TOLERANCE, rate_setpoint,
};
pub use desired::{DesiredState, DesiredStateGenerator, is_finite_pose};
pub use gains::{ConfigError, ControllerConfig, L1Config, Pid4Gains, Pid6Gains};
pub use l1::L1Adaptive;
pub use pid4::Pid4;
pub use pid6::Pid6;
pub use profile::{ControllerKind, build, profile};
pub use so3::attitude_error;

#[cfg(test)]
mod tests;
