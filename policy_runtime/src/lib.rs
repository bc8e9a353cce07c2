//! The flight loop of amstack and everything around it.
//!
//! Every flight — a `track` reference, a benchmark rollout, a `replay`, a `fly` over any
//! link — runs through one runner, [`flight::run`]; what differs between them is plugged in:
//!
//! - **the link** ([`link`], the crate's floor: it knows no stack and no log): the twin in
//!   this process ([`TwinLink`]), the twin in another process over iceoryx2 ([`IpcLink`]), a
//!   PX4-style autopilot over MAVLink ([`MavlinkLink`]). It takes a [`Setpoint`] (actuator
//!   commands, or the controller's attitude setpoint), returns measurements and, as data, its
//!   own sensor readings, the task scene's state and its log messages ([`link_channels`]).
//!   Its errors are categorical ([`LinkError`]: refused, silent, failed, diverged).
//! - **the state source** ([`state_source`]): the measurement, or the estimator fed by
//!   simulated sensors or by the vehicle's own;
//! - **the action source** ([`flight::ActionSource`]): a reference trajectory, a task's
//!   scripted policy ([`task_policies`]), the logged actions of a flight (replay), a learned
//!   policy — a remote openpi server or an ONNX model — at the 20 Hz chunked interface
//!   ([`policy`]);
//! - **the flight stack** ([`stack`]): interface (IK | MPC) → base controller → allocation,
//!   with saturation fed back; its [`TickRecord`] holds the whole cascade;
//! - **observers** ([`flight::Observer`]): the MCAP log ([`flight_log`], written by
//!   [`record`]), the task criteria latch and stop rule, the tracking and benchmark metrics
//!   ([`metrics`]), progress, the demonstration recorder ([`dataset::Recorder`]: LeRobot
//!   datasets, [`dataset`]).
//!
//! Around the loop: [`trajectory`] and [`track`] (`amstack track`), [`bench`] (the benchmark
//! runner: tasks × rollouts on worker threads), [`validation`] (replay a logged flight,
//! compare two logs), [`scripted`] (the scripted demonstrations' interpolation).

pub mod bench;
pub mod cameras;
pub mod dataset;
pub mod flight;
pub mod flight_log;
pub mod ipc_link;
pub mod link;
pub mod link_channels;
pub mod live;
pub mod mavlink_link;
mod mavlink_scene;
pub mod metrics;
pub mod policy;
pub mod record;
pub mod scene3d;
pub mod scripted;
pub mod stack;
pub mod state_source;
pub mod task_policies;
pub mod track;
pub mod trajectory;
pub mod twin_view;
pub mod validation;
pub mod video;

pub use ipc_link::{IpcLink, IpcLinkConfig, IpcLinkError};
pub use link::{Link, LinkError, Setpoint, SetpointLevel, TwinLink, VehicleSensors};
pub use mavlink_link::{Level, MavlinkLink, MavlinkLinkConfig, MavlinkLinkError};
pub use stack::{
    Action, BaseJointTarget, Clock, EeTarget, FlightStack, Interface, StackError, ThrustLimits,
    TickRecord, TimeSource, WallClock,
};
pub use state_source::{EstimatorSettings, EstimatorSummary, StateSource};
pub use track::{TrackConfig, TrackError, TrackResult, run_track, run_track_with_link};
pub use trajectory::Trajectory;

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]
mod tests;
