//! The twin as a PX4-style autopilot over MAVLink 2 (`amstack twin serve --mavlink`): a flight
//! stack (amstack's `firmware_bridge`, or any offboard program) or a ground station
//! (QGroundControl, pymavlink) talks to it as to a PX4 vehicle. The contract, as implemented, is
//! `docs/mavlink.md`.
//!
//! A crate of its own, apart from `sim_twin`: the twin's physics, task scenes and iceoryx2
//! server build without the MAVLink crates (`mavlink`, `tokio-serial`, `firmware_bridge`) and
//! without `controllers`; only this crate (and the CLI's `twin serve --mavlink`) needs them.
//!
//! | file | concept |
//! |---|---|
//! | [`modes`] | PX4 custom modes, the commander: arming, mode switches, offboard-loss failsafe (COM_OBL_RC_ACT) |
//! | [`params`] | the PX4-named parameter set (typed, range-checked) and its MAVLink encoding |
//! | [`mission`] | missions and the MISSION_INT protocol (upload, download, clear) |
//! | [`offboard`] | SET_POSITION_TARGET_LOCAL_NED and SET_ATTITUDE_TARGET read as PX4 reads them (type masks, rate limits) |
//! | [`navigator`] | the moving position target of takeoff, land, RTL, missions and offboard position (MPC_* limits) |
//! | setpoints | the actuator level (`--allow-actuator-setpoints`, a SITL extension) decoded by `firmware_bridge::SetpointCodec` |
//! | [`control`] | the autopilot's own control: position hold (PID on the twin's truth), the attitude and rate loops (`controllers::AttitudeLaw`), allocation |
//! | [`realtime`] | the real-time factor of a realtime twin, `--realtime-policy` |
//! | [`telemetry`] | the twin's state → MAVLink messages (NED/FRD via `firmware_bridge::frames`) |
//! | [`wire`] | the link's end of `firmware_bridge::wire`, the one MAVLink 2 codec (parsing with counters for every bad byte, signing, encoding); the autopilot's signing settings |
//! | [`transport`] | UDP (every peer heard) or a serial device |
//! | [`server`] | the loop: lockstep or realtime stepping, telemetry streams, commands |
//!
//! Ids: the autopilot is system 1, component 1. It speaks MAVLink 2, and MAVLink 1 to a peer
//! until that peer speaks MAVLink 2 (as PX4). Lockstep (what the tests use): the twin
//! advances one control period when a tick's completing setpoint (group 0, or
//! SET_ATTITUDE_TARGET) arrives while armed in OFFBOARD; the internal modes (POSCTL,
//! AUTO.LOITER, AUTO.LAND, the failsafe) run on the wall clock. Realtime: the twin runs on the
//! wall clock from the first arming on.

pub mod control;
pub mod mission;
pub mod modes;
pub mod navigator;
pub mod offboard;
pub mod params;
pub mod realtime;
pub mod server;
pub mod telemetry;
pub mod transport;
pub mod wire;

pub use modes::{Commander, FlightMode, LossAction, Transition};
pub use params::{Param, Params};
pub use realtime::RealtimePolicy;
pub use server::{
    Autopilot, AutopilotConfig, AutopilotError, AutopilotEvent, COMPONENT_ID, SYSTEM_ID,
    resting_height_m,
};
pub use transport::Endpoint;
pub use wire::{LinkCounters, Signing, Wire};
