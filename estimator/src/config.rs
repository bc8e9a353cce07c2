//! The estimator's settings: process noise of the IMU, initial uncertainty, the delay
//! history, gating.

use serde::{Deserialize, Serialize};

/// Settings of the [`Estimator`](crate::Estimator). Plain data; [`EstimatorConfig::validate`]
/// checks it, and [`Estimator::new`](crate::Estimator::new) refuses a bad one.
///
/// The defaults describe the twin's default simulated IMU
/// ([`ImuModel::default`](crate::ImuModel::default)) with some margin on the bias random
/// walks, so the filter keeps adapting; for a real IMU take the datasheet's noise densities
/// and raise them for vibration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EstimatorConfig {
    /// Accelerometer white-noise density, m/s²/√Hz. Default 0.002.
    pub accel_noise_mps2_per_sqrt_hz: f64,
    /// Gyroscope white-noise density, rad/s/√Hz. Default 0.0005.
    pub gyro_noise_radps_per_sqrt_hz: f64,
    /// Accelerometer bias random walk, m/s³/√Hz. Default 0.0005.
    pub accel_bias_walk_mps3_per_sqrt_hz: f64,
    /// Gyroscope bias random walk, rad/s²/√Hz. Default 0.00005.
    pub gyro_bias_walk_radps2_per_sqrt_hz: f64,
    /// Initial standard deviation of each position component, m. Default 0.05.
    pub initial_position_std_m: f64,
    /// Initial standard deviation of each velocity component, m/s. Default 0.05: a vehicle
    /// starting at rest (motion capture on the ground, the twin at its reset); raise it for a
    /// start in motion.
    pub initial_velocity_std_mps: f64,
    /// Initial standard deviation of each attitude-error component, rad. Default 0.05.
    pub initial_attitude_std_rad: f64,
    /// Initial standard deviation of each accelerometer-bias component, m/s². Default 0.2.
    pub initial_accel_bias_std_mps2: f64,
    /// Initial standard deviation of each gyroscope-bias component, rad/s. Default 0.02.
    pub initial_gyro_bias_std_radps: f64,
    /// How far back a delayed measurement may reach, s: states and IMU samples are kept this
    /// long (at most [`MAX_HISTORY_SAMPLES`](crate::MAX_HISTORY_SAMPLES) of them). Older
    /// measurements are rejected as too old. Default 0.5.
    pub history_s: f64,
    /// Measurements newer than the latest IMU sample wait for it; at most this many. Default 16.
    pub max_pending: usize,
    /// An IMU interval longer than this is still integrated but counted as a gap in the
    /// diagnostics, s. Default 0.05.
    pub max_imu_interval_s: f64,
    /// Reject a measurement whose normalised innovation squared exceeds this (a χ² bound for
    /// 6 or 9 degrees of freedom); `None` fuses every measurement. Default `None`: a gated
    /// filter that has drifted can lock itself out, and nothing here would reset it yet.
    pub innovation_gate_nis: Option<f64>,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            accel_noise_mps2_per_sqrt_hz: 0.002,
            gyro_noise_radps_per_sqrt_hz: 0.0005,
            accel_bias_walk_mps3_per_sqrt_hz: 0.0005,
            gyro_bias_walk_radps2_per_sqrt_hz: 0.00005,
            initial_position_std_m: 0.05,
            initial_velocity_std_mps: 0.05,
            initial_attitude_std_rad: 0.05,
            initial_accel_bias_std_mps2: 0.2,
            initial_gyro_bias_std_radps: 0.02,
            history_s: 0.5,
            max_pending: 16,
            max_imu_interval_s: 0.05,
            innovation_gate_nis: None,
        }
    }
}

/// A setting out of range: the field, its value, and what it must be.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{section}.{field} = {value}: {requirement}")]
pub struct ConfigError {
    /// The settings the field belongs to (`estimator`, `imu`, `pose`).
    pub section: &'static str,
    /// Field name.
    pub field: &'static str,
    /// Its value.
    pub value: f64,
    /// What it must be.
    pub requirement: &'static str,
}

impl EstimatorConfig {
    /// Checks every field: noise levels and initial deviations finite and positive, the
    /// history positive, at least one pending slot, a gate positive when set.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let positive = [
            (
                "accel_noise_mps2_per_sqrt_hz",
                self.accel_noise_mps2_per_sqrt_hz,
            ),
            (
                "gyro_noise_radps_per_sqrt_hz",
                self.gyro_noise_radps_per_sqrt_hz,
            ),
            (
                "accel_bias_walk_mps3_per_sqrt_hz",
                self.accel_bias_walk_mps3_per_sqrt_hz,
            ),
            (
                "gyro_bias_walk_radps2_per_sqrt_hz",
                self.gyro_bias_walk_radps2_per_sqrt_hz,
            ),
            ("initial_position_std_m", self.initial_position_std_m),
            ("initial_velocity_std_mps", self.initial_velocity_std_mps),
            ("initial_attitude_std_rad", self.initial_attitude_std_rad),
            (
                "initial_accel_bias_std_mps2",
                self.initial_accel_bias_std_mps2,
            ),
            (
                "initial_gyro_bias_std_radps",
                self.initial_gyro_bias_std_radps,
            ),
            ("history_s", self.history_s),
            ("max_imu_interval_s", self.max_imu_interval_s),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(ConfigError {
                    section: "estimator",
                    field,
                    value,
                    requirement: "must be finite and positive",
                });
            }
        }
        if self.max_pending == 0 {
            return Err(ConfigError {
                section: "estimator",
                field: "max_pending",
                value: 0.0,
                requirement: "must be at least 1",
            });
        }
        if let Some(gate) = self.innovation_gate_nis
            && !(gate.is_finite() && gate > 0.0)
        {
            return Err(ConfigError {
                section: "estimator",
                field: "innovation_gate_nis",
                value: gate,
                requirement: "must be finite and positive when set",
            });
        }
        Ok(())
    }
}
