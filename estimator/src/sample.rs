//! What the estimator is fed: IMU samples, pose measurements, odometry. Every one carries
//! the time it was measured at (the sensor's capture time, not its arrival), seconds on the
//! caller's clock.

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// One IMU sample: the mean specific force and angular rate over the interval that ends at
/// `time_s` (an integrating IMU, as PX4's delta velocity / delta angle divided by the
/// interval). Both in the body frame (FLU) at the interval's middle.
///
/// Specific force f = Rᵀ(a − g) with g = (0, 0, −9.81) m/s²: a level vehicle at rest reads
/// f = (0, 0, +9.81) m/s².
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    /// End of the interval the sample covers, s.
    pub time_s: f64,
    /// Specific force, body frame, m/s².
    pub specific_force_in_body_mps2: Vector3<f64>,
    /// Angular velocity, body frame, rad/s.
    pub angular_velocity_in_body_radps: Vector3<f64>,
}

impl ImuSample {
    /// The name of the first non-finite field, if any.
    pub(crate) fn non_finite_field(&self) -> Option<&'static str> {
        if !self.time_s.is_finite() {
            Some("imu.time_s")
        } else if !all_finite(&self.specific_force_in_body_mps2) {
            Some("imu.specific_force_in_body_mps2")
        } else if !all_finite(&self.angular_velocity_in_body_radps) {
            Some("imu.angular_velocity_in_body_radps")
        } else {
            None
        }
    }
}

/// A measured pose of the body (motion capture, an autopilot's local position and attitude):
/// position of the body origin and attitude, each with an isotropic noise level.
///
/// The attitude noise is a rotation vector n in the body frame: measured = true ⊗ Exp(n),
/// n ~ N(0, σ²·I).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseMeasurement {
    /// When the pose was captured (not when it arrived), s.
    pub time_s: f64,
    /// Body origin in the world frame, m.
    pub position_in_world_m: Vector3<f64>,
    /// Body attitude, body → world.
    pub world_from_body: UnitQuaternion<f64>,
    /// Standard deviation of each position component, m.
    pub position_std_m: f64,
    /// Standard deviation of each attitude-error component, rad.
    pub attitude_std_rad: f64,
}

impl PoseMeasurement {
    /// The name of the first bad field (non-finite, or a noise level not positive), if any.
    pub(crate) fn bad_field(&self) -> Option<&'static str> {
        if !self.time_s.is_finite() {
            Some("pose.time_s")
        } else if !all_finite(&self.position_in_world_m) {
            Some("pose.position_in_world_m")
        } else if !self.world_from_body.coords.iter().all(|x| x.is_finite()) {
            Some("pose.world_from_body")
        } else if !(self.position_std_m.is_finite() && self.position_std_m > 0.0) {
            Some("pose.position_std_m")
        } else if !(self.attitude_std_rad.is_finite() && self.attitude_std_rad > 0.0) {
            Some("pose.attitude_std_rad")
        } else {
            None
        }
    }
}

/// Odometry: a pose and the world-frame velocity of the body origin (an autopilot's
/// ODOMETRY, converted to the world frame by the bridge).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometryMeasurement {
    /// The pose part, with its capture time.
    pub pose: PoseMeasurement,
    /// Velocity of the body origin, world frame, m/s.
    pub velocity_in_world_mps: Vector3<f64>,
    /// Standard deviation of each velocity component, m/s.
    pub velocity_std_mps: f64,
}

impl OdometryMeasurement {
    /// The name of the first bad field, if any.
    pub(crate) fn bad_field(&self) -> Option<&'static str> {
        if let Some(f) = self.pose.bad_field() {
            Some(f)
        } else if !all_finite(&self.velocity_in_world_mps) {
            Some("odometry.velocity_in_world_mps")
        } else if !(self.velocity_std_mps.is_finite() && self.velocity_std_mps > 0.0) {
            Some("odometry.velocity_std_mps")
        } else {
            None
        }
    }
}

/// A measurement of the [`Estimator`](crate::Estimator): pose alone or odometry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Measurement {
    /// Position and attitude.
    Pose(PoseMeasurement),
    /// Position, attitude and velocity.
    Odometry(OdometryMeasurement),
}

impl Measurement {
    /// Capture time, s.
    pub fn time_s(&self) -> f64 {
        match self {
            Self::Pose(p) => p.time_s,
            Self::Odometry(o) => o.pose.time_s,
        }
    }

    /// The pose part.
    pub fn pose(&self) -> &PoseMeasurement {
        match self {
            Self::Pose(p) => p,
            Self::Odometry(o) => &o.pose,
        }
    }

    /// The name of the first bad field, if any.
    pub(crate) fn bad_field(&self) -> Option<&'static str> {
        match self {
            Self::Pose(p) => p.bad_field(),
            Self::Odometry(o) => o.bad_field(),
        }
    }

    /// Short name for diagnostics (`pose`, `odometry`).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Pose(_) => "pose",
            Self::Odometry(_) => "odometry",
        }
    }
}

pub(crate) fn all_finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}
