//! The twin as PX4's simulator: PX4 SITL firmware flies amstack's vehicles and task scenes
//! through PX4's simulator MAVLink interface (`simulator_mavlink`), as it flies Gazebo.
//!
//! PX4 connects over TCP (port 4560 by default) to [`HilServer`], which serves one PX4 at a
//! time. Each tick the twin sends HIL_SENSOR (IMU, magnetometer, barometer, from the twin's
//! simulated sensors with the seed's noise streams), HIL_GPS at the GNSS rate and
//! HIL_STATE_QUATERNION (ground truth) — [`messages`] — and applies PX4's
//! HIL_ACTUATOR_CONTROLS to the rotors, tilt servos, arm joints and gripper through the
//! vehicle's channel map ([`channels`]). In lockstep (PX4's SITL contract: the first
//! HIL_SENSOR sets PX4's clock, then one HIL_ACTUATOR_CONTROLS answers each HIL_SENSOR and the
//! twin advances one control period per reply) a run is bit-for-bit reproducible from the
//! seed; `--realtime` runs on the wall clock. [`airframe`] prints what PX4's control
//! allocation needs to know about the vehicle (`CA_ROTOR*`).
//!
//! Kept out of `sim_twin`'s physics core; frames: PX4 speaks NED/FRD, converted with
//! `firmware_bridge::frames` only. The protocol document is `docs/px4-hil.md`.

pub mod airframe;
pub mod channels;
pub mod messages;
pub mod server;

#[cfg(test)]
mod tests;

pub use airframe::Px4Airframe;
pub use channels::ChannelMap;
pub use server::{
    HilConfig, HilError, HilEvent, HilFrame, HilObserver, HilServer, HilTick, NoObserver,
    SessionEnd, SessionStats, parse_endpoint,
};
