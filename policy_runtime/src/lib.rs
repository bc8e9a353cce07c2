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
//! - [`record`]: the MCAP flight-log recorder. [`record::McapRecorder`] writes one file per
//!   run: an `amstack.run` metadata record ([`record::RunMetadata`]), JSON-encoded channels
//!   with JSON-Schema schemas derived from the Rust types, Foxglove's well-known pose and
//!   transform types ([`record::foxglove`]), timestamps from the caller's (simulated) clock,
//!   chunks flushed as they fill so a killed run leaves a readable file.
//!   [`record::Recording`] reads a file back by streaming, complete or cut short.

pub mod record;
