//! State estimation for amstack (a pure crate: no I/O, no clock).
//!
//! This crate will own, once its issue lands: an EKF that fuses IMU (accelerometer,
//! gyroscope) with pose or odometry measurements (autopilot ODOMETRY, motion capture) into
//! the vehicle state the controllers use, with timestamps and delayed measurements handled;
//! and the sensor noise models the twin uses to simulate those sensors.
