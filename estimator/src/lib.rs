//! State estimation for amstack (a pure crate: no I/O, no clock; time arrives as `f64`
//! seconds on every sample).
//!
//! [`Estimator`] is an error-state EKF over position, velocity, attitude and the
//! accelerometer and gyroscope biases (15 error states). It predicts with IMU samples
//! (specific force and angular rate, body frame FLU; world frame Z-up, gravity
//! [`platform::GRAVITY_MPS2`]) and corrects with pose measurements (motion capture) or
//! odometry (pose + world velocity, an autopilot's ODOMETRY). The equations are in [`ekf`].
//!
//! Time: every input carries the time it was measured at. The estimator keeps a short
//! history of states and IMU samples ([`EstimatorConfig::history_s`]); a measurement captured
//! before the newest IMU sample is fused at its capture time (the state there is propagated
//! to that instant, corrected, and the newer samples are integrated again on top), one from
//! ahead of the IMU waits for it. Out-of-order, too old and non-finite inputs are refused
//! with a [`Rejection`], never a panic, and the estimate is unchanged.
//!
//! The estimate comes out as a [`platform::RigidBodyState`] (position, `world_from_body`,
//! world velocity, body rate = gyro − bias) with its covariance, standard deviations and
//! [`Diagnostics`] (the latest innovation and its NIS, counters).
//!
//! [`sensors`] holds the sensor models the twin simulates its IMU and pose sensor with;
//! [`magnetometer`], [`barometer`] and [`gnss`] those of the navigation sensors an autopilot
//! reads (the Earth's field, the ISA pressure, a GNSS fix about a geodetic home origin).

pub mod barometer;
mod config;
pub mod ekf;
mod estimator;
pub mod gnss;
pub mod magnetometer;
mod sample;
mod schedule;
pub mod sensors;

#[cfg(test)]
mod navigation_tests;
#[cfg(test)]
mod tests;

pub use barometer::{BarometerModel, BarometerSample, BarometerSensor};
pub use config::{ConfigError, EstimatorConfig};
pub use ekf::Covariance;
pub use estimator::{
    Accepted, Diagnostics, Estimator, Innovation, MAX_HISTORY_SAMPLES, Rejection, StateStd,
};
pub use gnss::{Geodetic, GeodeticOrigin, GnssFix, GnssModel, GnssSensor};
pub use magnetometer::{MagnetometerModel, MagnetometerSample, MagnetometerSensor};
pub use sample::{ImuSample, Measurement, OdometryMeasurement, PoseMeasurement};
pub use sensors::{ImuModel, ImuSensor, PoseModel, PoseSensor};
