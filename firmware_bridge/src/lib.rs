//! MAVLink link between amstack and a PX4-style autopilot.
//!
//! This crate will own, once its issue lands: MAVLink 2 over serial (tokio-serial) and
//! UDP/TCP as a `Link` of the flight loop — telemetry in, setpoints out (actuator level with
//! SET_ACTUATOR_CONTROL_TARGET, or attitude level with SET_ATTITUDE_TARGET), heartbeats,
//! arming and offboard mode with COMMAND_LONG/COMMAND_ACK, failsafes and message signing.
//! It is the one place where NED/FRD frames are converted to our ENU-like world and FLU body.
