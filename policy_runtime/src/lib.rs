//! The flight loop of amstack and everything around it.
//!
//! This crate will own, once its issue lands: the `Link` seam between the flight stack and
//! the world (in-process twin, iceoryx2 twin, MAVLink autopilot); the loop policy → action
//! interface (EE target through IK, or base + joint target) → base controller → allocation →
//! link, which owns the clock and feeds saturation back to the controller; scripted task
//! policies; the benchmark runner and its metrics; and MCAP recording and comparison.
//!
//! # What exists
//!
//! - [`link`]: the [`Link`] seam and its first implementation, the in-process twin.
//! - [`ipc_link`]: the twin in another process over iceoryx2 ([`IpcLink`]), lockstep or
//!   realtime, with a handshake and a deadline on every answer.
//! - [`stack`]: one tick of the flight stack — target → base controller → allocation →
//!   actuator command, with the allocator's unallocated wrench fed back to the controller.
//! - [`trajectory`] and [`track`]: the reference trajectories of `amstack track` and the
//!   flight that scores them.
//! - [`state_source`]: `--state-source truth|estimator`: the controllers fly on the link's
//!   measurement, or on the estimator fed by the twin's simulated IMU and pose sensor.
//! - [`flight_log`]: the channels of a flight's MCAP log.
//! - [`metrics`]: the benchmark's metrics (AMBENCH_SPEC §6): per-tick records, rollout and
//!   run summaries, latched subtask criteria, the reference's N/A rules.
//! - [`scripted`]: waypoint scripts, the scripted demonstrations' interpolation.
//! - [`record`]: the MCAP flight-log recorder. [`record::McapRecorder`] writes one file per
//!   run: an `amstack.run` metadata record ([`record::RunMetadata`]), JSON-encoded channels
//!   with JSON-Schema schemas derived from the Rust types, Foxglove's well-known pose and
//!   transform types ([`record::foxglove`]), timestamps from the caller's (simulated) clock,
//!   chunks flushed as they fill so a killed run leaves a readable file.
//!   [`record::Recording`] reads a file back by streaming, complete or cut short.
//! - [`validation`]: sim-to-real validation — replay a logged flight in the twin, compare two
//!   logs signal by signal (RMSE, max error, bias, over intervals).

pub mod bench;
pub mod flight_log;
pub mod ipc_link;
pub mod link;
pub mod metrics;
pub mod record;
pub mod scripted;
pub mod stack;
pub mod state_source;
pub mod task_policies;
pub mod track;
pub mod trajectory;
pub mod validation;

pub use ipc_link::{IpcLink, IpcLinkConfig, IpcLinkError};
pub use link::{Link, LinkError, TwinLink};
pub use stack::{
    Action, BaseJointTarget, EeTarget, FlightStack, StackError, ThrustLimits, TickRecord,
};
pub use state_source::{EstimatorSettings, EstimatorSummary, StateSource};
pub use track::{Interface, TrackConfig, TrackError, TrackResult, run_track, run_track_with_link};
pub use trajectory::Trajectory;
