//! Control allocation for multirotors: which rotor thrusts (and, for a variable-tilt vehicle,
//! which tilt angles) produce a requested body wrench, what to do when the rotors cannot, and
//! how the rotors then respond. A pure crate: no I/O, no clock; time arrives as `dt` (s).
//!
//! **Effectiveness.** Rotor i at r_i, thrust direction d_i, spin sign s_i, reaction-torque ratio
//! k_f contributes the column a_i = [d_i ; r_i × d_i + s_i k_f d_i] (rows F_x F_y F_z τ_x τ_y
//! τ_z), so w = A·T with A the 6×N effectiveness matrix ([`effectiveness_matrix`]). An
//! under-actuated vehicle commands only [F_z, τ_x, τ_y, τ_z] (4×N). A variable-tilt rotor points
//! along cos α·c_i + sin α·s_i; in the variables (c, s) = T(cos α, sin α) the map is linear
//! again, 6×2N ([`variable_tilt_effectiveness_matrix`]).
//!
//! **Allocation** ([`Allocator`]), built once per vehicle:
//! - pseudo-inverse: x = A⁺w, then clamp each T_i into [T_min, T_max] (for a tilting rotor,
//!   scale ‖(c, s)‖ into it and take α = atan2(s, c) unwrapped against the measured angle);
//! - constrained: minimise ½(Ax − w)ᵀW(Ax − w) subject to the bounds (a QP, clarabel), W the
//!   axis priorities (roll/pitch before thrust before yaw, [`ConstrainedSettings`]).
//!
//! Every result ([`Allocation`]) carries the achieved wrench (forward map), the unallocated
//! wrench w − A x for the controllers' anti-windup, per-rotor [`RotorSaturation`] and a status.
//!
//! **Actuator** ([`RotorActuator`]): T_c = clip(T, T_min, T_max), q_c = √(T_c/T_max), an exact
//! first-order lag q ← q + (1 − e^{−Δt/τ})(q_c − q), a symmetric rate limit |Δq| ≤ q̇_max Δt,
//! q ∈ [√(T_min/T_max), 1], T = T_max q².

mod allocation;
mod allocator;
mod bounds;
mod constrained;
mod effectiveness;
mod error;
mod pseudo_inverse;
mod rotor_actuator;
mod saturation;
mod variable_tilt;

pub use allocation::{Allocation, AllocationStatus, SolverFailure};
pub use allocator::{AllocationMethod, Allocator};
pub use constrained::ConstrainedSettings;
pub use effectiveness::{
    FULL_WRENCH_ROWS, REDUCED_WRENCH_ROWS, effectiveness_column, effectiveness_matrix,
    reduced_effectiveness_matrix, variable_tilt_effectiveness_matrix, wrench_from_thrusts,
};
pub use error::{ActuatorError, AllocationError};
pub use pseudo_inverse::RANK_TOLERANCE;
pub use rotor_actuator::{RotorActuator, RotorActuatorConfig, RotorTelemetry};
pub use saturation::{RotorSaturation, SATURATION_TOLERANCE_N, any_rotor_saturated};
pub use variable_tilt::{MAGNITUDE_FLOOR_N, unwrap_tilt};

#[cfg(test)]
#[path = "../tests/fixtures/mod.rs"]
mod fixtures;
