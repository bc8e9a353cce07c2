//! Cross-crate functional tests of amstack.
//!
//! This crate will own, once the flight loop exists: tests that fly whole stacks — hover and
//! tracking in the twin, task success, the split-process twin over iceoryx2, MAVLink peers —
//! and that start and stop any second process they need themselves.
