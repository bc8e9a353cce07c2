//! Tests of flights across the crate's modules (the flight loop with a link, the stack and the
//! log together). They sit above every module, so no module depends on another's tests.

mod cameras;
mod mavlink_flight;
mod mpc_flight;
mod mpc_stack;
mod rotor_log;
mod saturated_allocation;
mod task_ik;
