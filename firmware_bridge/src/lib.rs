//! MAVLink link between amstack and a PX4-style autopilot.
//!
//! This crate owns MAVLink 2 over serial (tokio-serial) and UDP/TCP as a `Link` of the flight
//! loop — telemetry in, setpoints out (actuator level with SET_ACTUATOR_CONTROL_TARGET, or
//! attitude level with SET_ATTITUDE_TARGET), heartbeats, arming and offboard mode with
//! COMMAND_LONG/COMMAND_ACK, failsafes and message signing.
//!
//! [`frames`] is the one place where PX4's NED world and FRD body frames are converted to
//! amstack's ENU-like Z-up world and FLU body (the twin's MAVLink autopilot uses it too).

pub mod frames;
