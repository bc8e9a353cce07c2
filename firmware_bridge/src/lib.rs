//! MAVLink link between amstack and a PX4-style autopilot.
//!
//! The flight loop is synchronous; MAVLink I/O is not. [`Bridge`] runs one connection (UDP,
//! TCP or serial, see [`address`]) on a tokio runtime of its own thread and offers a blocking
//! API: queue messages, send a COMMAND_LONG and wait for its COMMAND_ACK (retries, timeouts,
//! errors that name the command and the result), wait for the next tick's measurement.
//!
//! - [`frames`] is the one place where PX4's NED world and FRD body frames are converted to
//!   amstack's ENU-like Z-up world and FLU body (the twin's MAVLink autopilot uses it too).
//! - [`setpoint`]: commands → SET_ACTUATOR_CONTROL_TARGET (actuator level: motors through
//!   the vehicle's thrust curve, tilt servos, arm joints and gripper normalised over their
//!   limits), SET_ATTITUDE_TARGET (attitude level: attitude + `thrust_body`) or
//!   SET_POSITION_TARGET_LOCAL_NED (position level: position + heading); a non-finite value
//!   is refused, never sent.
//! - [`telemetry`]: HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE, HIGHRES_IMU,
//!   ATTITUDE_QUATERNION, LOCAL_POSITION_NED, ACTUATOR_OUTPUT_STATUS, DEBUG_FLOAT_ARRAY
//!   "joints" and ODOMETRY (which closes a tick) → a [`platform::Measurement`] and the
//!   autopilot's state.
//! - [`task_array`]: the task scene's state (DEBUG_FLOAT_ARRAY "task"), a SITL extension
//!   the twin's autopilot sends so a task flown over MAVLink can be judged.
//! - [`wire`]: the MAVLink 2 codec of both ends of the link (the twin's autopilot uses it
//!   too): framing that never panics and counts garbage, bad CRCs, unknown ids, truncated and
//!   unsupported frames and frames refused by MAVLink 2 signing; encoding, signed or not.
//! - [`capture`]: with [`BridgeConfig::capture_raw`], every frame in and out with its bytes
//!   as on the wire, handed to the flight side through a bounded queue (the flight log's
//!   `/mavlink/raw`).
//!
//! The contract with the other end (ids, modes, groups, lockstep) is `docs/mavlink.md`.

pub mod address;
pub mod bridge;
pub mod capture;
pub mod frames;
pub mod setpoint;
pub mod task_array;
pub mod telemetry;
pub mod wire;

pub use address::Address;
pub use bridge::{Bridge, BridgeConfig, BridgeError};
pub use capture::{CaptureStats, Direction, RawFrame};
pub use setpoint::{ActuatorUpdate, AttitudeSetpoint, SetpointCodec, SetpointError};
pub use task_array::TaskArray;
pub use telemetry::{AutopilotState, AutopilotVersion, Telemetry};
pub use wire::{CounterSnapshot, Signing, SigningKey};

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]
mod tests;
