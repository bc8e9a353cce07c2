//! The flight loop of amstack and everything around it.
//!
//! This crate will own, once its issue lands: the `Link` seam between the flight stack and
//! the world (in-process twin, iceoryx2 twin, MAVLink autopilot); the loop policy → action
//! interface (EE target through IK, or base + joint target) → base controller → allocation →
//! link, which owns the clock and feeds saturation back to the controller; scripted task
//! policies; the benchmark runner and its metrics; and MCAP recording and comparison.
