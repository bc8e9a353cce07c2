//! The simulator twin of amstack.
//!
//! This crate will own, once its issue lands: rapier3d (f64) physics of the five vehicles
//! built from their `platform` descriptions and of the twelve task scenes; the aerodynamic
//! disturbances (body drag, wind, ground effect and near-wall effect from parry ray casts);
//! the rotor model (the `allocation` crate's rotor actuator, one implementation); simulated
//! sensors and cameras (wgpu); task success criteria; and the servers that offer the twin to
//! another process (iceoryx2 shared memory, a MAVLink autopilot emulator).
