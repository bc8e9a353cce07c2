//! Sensor models: what an IMU and a pose sensor (motion capture) read, given the truth.
//! Pure: the caller passes the time and an `&mut impl Rng`, so a run is reproducible from a
//! seed. The twin's simulated sensors are these models fed with its truth.
//!
//! IMU: each sample is the mean over one sample period T = 1/rate of the true specific
//! force and rate, plus the bias, plus white noise of density N, whose mean over T has the
//! standard deviation N/√T = N·√rate. The bias starts at a constant turn-on value (drawn
//! once, or given) and random-walks: b ← b + σ_w·√T·ξ, ξ ~ N(0, I).
//!
//! Pose: captured at `rate_hz` (on the first call at or after each scheduled time), with
//! position noise N(0, σ_p²·I) and attitude noise q ⊗ Exp(n), n ~ N(0, σ_θ²·I) in the body
//! frame; it arrives `latency_s` after its capture and carries its capture time.

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::config::ConfigError;
use crate::sample::{ImuSample, PoseMeasurement};

/// Times closer than this are the same instant, s (schedules on a float clock).
pub(crate) const TIME_EPSILON_S: f64 = 1e-9;

pub(crate) fn normal3(rng: &mut impl Rng, std: f64) -> Vector3<f64> {
    let mut draw = || rng.sample::<f64, _>(StandardNormal) * std;
    Vector3::new(draw(), draw(), draw())
}

pub(crate) fn check(
    section: &'static str,
    fields: &[(&'static str, f64)],
    positive: bool,
) -> Result<(), ConfigError> {
    for &(field, value) in fields {
        let ok = value.is_finite() && if positive { value > 0.0 } else { value >= 0.0 };
        if !ok {
            return Err(ConfigError {
                section,
                field,
                value,
                requirement: if positive {
                    "must be finite and positive"
                } else {
                    "must be finite and not negative"
                },
            });
        }
    }
    Ok(())
}

/// An IMU's error model. Defaults: a good MEMS IMU (ICM-42688-class densities, raised for
/// vibration) sampled once per control period of the twin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuModel {
    /// Sample rate, Hz: each sample averages one period. Default 120 (the twin's control
    /// rate).
    pub rate_hz: f64,
    /// Accelerometer white-noise density, m/s²/√Hz. Default 0.002.
    pub accel_noise_mps2_per_sqrt_hz: f64,
    /// Gyroscope white-noise density, rad/s/√Hz. Default 0.0005.
    pub gyro_noise_radps_per_sqrt_hz: f64,
    /// Accelerometer bias random walk, m/s³/√Hz. Default 0.0002.
    pub accel_bias_walk_mps3_per_sqrt_hz: f64,
    /// Gyroscope bias random walk, rad/s²/√Hz. Default 0.00002.
    pub gyro_bias_walk_radps2_per_sqrt_hz: f64,
    /// Standard deviation of each component of the constant (turn-on) accelerometer bias,
    /// m/s². Default 0.05.
    pub accel_bias_std_mps2: f64,
    /// Standard deviation of each component of the constant (turn-on) gyroscope bias, rad/s.
    /// Default 0.005.
    pub gyro_bias_std_radps: f64,
}

impl Default for ImuModel {
    fn default() -> Self {
        Self {
            rate_hz: 120.0,
            accel_noise_mps2_per_sqrt_hz: 0.002,
            gyro_noise_radps_per_sqrt_hz: 0.0005,
            accel_bias_walk_mps3_per_sqrt_hz: 0.0002,
            gyro_bias_walk_radps2_per_sqrt_hz: 0.00002,
            accel_bias_std_mps2: 0.05,
            gyro_bias_std_radps: 0.005,
        }
    }
}

impl ImuModel {
    /// A perfect IMU at `rate_hz`: no noise, no bias.
    pub fn ideal(rate_hz: f64) -> Self {
        Self {
            rate_hz,
            accel_noise_mps2_per_sqrt_hz: 0.0,
            gyro_noise_radps_per_sqrt_hz: 0.0,
            accel_bias_walk_mps3_per_sqrt_hz: 0.0,
            gyro_bias_walk_radps2_per_sqrt_hz: 0.0,
            accel_bias_std_mps2: 0.0,
            gyro_bias_std_radps: 0.0,
        }
    }

    /// Checks every field: the rate finite and positive, the rest finite and not negative.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check("imu", &[("rate_hz", self.rate_hz)], true)?;
        check(
            "imu",
            &[
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
                ("accel_bias_std_mps2", self.accel_bias_std_mps2),
                ("gyro_bias_std_radps", self.gyro_bias_std_radps),
            ],
            false,
        )
    }
}

/// A simulated IMU: the model and its current biases.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuSensor {
    model: ImuModel,
    accel_bias_mps2: Vector3<f64>,
    gyro_bias_radps: Vector3<f64>,
}

impl ImuSensor {
    /// An IMU whose turn-on biases are drawn from the model's deviations.
    pub fn new(model: ImuModel, rng: &mut impl Rng) -> Result<Self, ConfigError> {
        model.validate()?;
        let accel = normal3(rng, model.accel_bias_std_mps2);
        let gyro = normal3(rng, model.gyro_bias_std_radps);
        Ok(Self {
            model,
            accel_bias_mps2: accel,
            gyro_bias_radps: gyro,
        })
    }

    /// An IMU with the given turn-on biases (m/s², rad/s, body frame).
    pub fn with_biases(
        model: ImuModel,
        accel_bias_mps2: Vector3<f64>,
        gyro_bias_radps: Vector3<f64>,
    ) -> Result<Self, ConfigError> {
        model.validate()?;
        check(
            "imu",
            &[
                ("accel_bias_mps2", accel_bias_mps2.norm()),
                ("gyro_bias_radps", gyro_bias_radps.norm()),
            ],
            false,
        )?;
        Ok(Self {
            model,
            accel_bias_mps2,
            gyro_bias_radps,
        })
    }

    /// The model.
    pub fn model(&self) -> &ImuModel {
        &self.model
    }

    /// The current biases: accelerometer m/s², gyroscope rad/s.
    pub fn biases(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.accel_bias_mps2, self.gyro_bias_radps)
    }

    /// What the IMU reads for the true mean specific force and rate `truth` (its time is kept):
    /// the biases walk one period, then bias and white noise are added.
    pub fn measure(&mut self, truth: &ImuSample, rng: &mut impl Rng) -> ImuSample {
        let m = &self.model;
        let period = 1.0 / m.rate_hz;
        self.accel_bias_mps2 += normal3(rng, m.accel_bias_walk_mps3_per_sqrt_hz * period.sqrt());
        self.gyro_bias_radps += normal3(rng, m.gyro_bias_walk_radps2_per_sqrt_hz * period.sqrt());
        let rate_sqrt = m.rate_hz.sqrt();
        let accel_noise = normal3(rng, m.accel_noise_mps2_per_sqrt_hz * rate_sqrt);
        let gyro_noise = normal3(rng, m.gyro_noise_radps_per_sqrt_hz * rate_sqrt);
        ImuSample {
            time_s: truth.time_s,
            specific_force_in_body_mps2: truth.specific_force_in_body_mps2
                + self.accel_bias_mps2
                + accel_noise,
            angular_velocity_in_body_radps: truth.angular_velocity_in_body_radps
                + self.gyro_bias_radps
                + gyro_noise,
        }
    }
}

/// A pose sensor's model (motion capture). Defaults: a motion-capture system at 60 Hz with
/// 2 mm and 0.3° noise and 20 ms latency.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseModel {
    /// Capture rate, Hz. Default 60.
    pub rate_hz: f64,
    /// Standard deviation of each position component, m. Default 0.002.
    pub position_std_m: f64,
    /// Standard deviation of each attitude-error component, rad. Default 0.005.
    pub attitude_std_rad: f64,
    /// Capture → arrival, s. Default 0.02.
    pub latency_s: f64,
}

impl Default for PoseModel {
    fn default() -> Self {
        Self {
            rate_hz: 60.0,
            position_std_m: 0.002,
            attitude_std_rad: 0.005,
            latency_s: 0.02,
        }
    }
}

impl PoseModel {
    /// Checks every field: the rate and both deviations finite and positive (a measurement
    /// states its noise, and the estimator divides by it), the latency finite and not
    /// negative.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            "pose",
            &[
                ("rate_hz", self.rate_hz),
                ("position_std_m", self.position_std_m),
                ("attitude_std_rad", self.attitude_std_rad),
            ],
            true,
        )?;
        check("pose", &[("latency_s", self.latency_s)], false)
    }
}

/// A simulated pose sensor: the model, its capture schedule and the captures in flight.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseSensor {
    model: PoseModel,
    next_capture_s: Option<f64>,
    /// (arrival time, measurement), oldest first.
    in_flight: VecDeque<(f64, PoseMeasurement)>,
}

impl PoseSensor {
    /// A pose sensor with `model`; its first capture is at its first [`PoseSensor::step`].
    pub fn new(model: PoseModel) -> Result<Self, ConfigError> {
        model.validate()?;
        Ok(Self {
            model,
            next_capture_s: None,
            in_flight: VecDeque::new(),
        })
    }

    /// The model.
    pub fn model(&self) -> &PoseModel {
        &self.model
    }

    /// One noisy capture of the true pose at `time_s`, outside the schedule (no latency).
    pub fn capture(
        &self,
        time_s: f64,
        position_in_world_m: &Vector3<f64>,
        world_from_body: &UnitQuaternion<f64>,
        rng: &mut impl Rng,
    ) -> PoseMeasurement {
        let m = &self.model;
        let position = position_in_world_m + normal3(rng, m.position_std_m);
        let attitude =
            world_from_body * UnitQuaternion::from_scaled_axis(normal3(rng, m.attitude_std_rad));
        PoseMeasurement {
            time_s,
            position_in_world_m: position,
            world_from_body: attitude,
            position_std_m: m.position_std_m,
            attitude_std_rad: m.attitude_std_rad,
        }
    }

    /// Advances the sensor to `time_s` with the true pose at that time: captures if a
    /// capture is due, and returns the captures that have arrived by `time_s` (oldest first),
    /// each stamped with its capture time.
    pub fn step(
        &mut self,
        time_s: f64,
        position_in_world_m: &Vector3<f64>,
        world_from_body: &UnitQuaternion<f64>,
        rng: &mut impl Rng,
    ) -> Vec<PoseMeasurement> {
        let period = 1.0 / self.model.rate_hz;
        let due = self.next_capture_s.unwrap_or(time_s);
        if time_s + TIME_EPSILON_S >= due {
            let m = self.capture(time_s, position_in_world_m, world_from_body, rng);
            self.in_flight.push_back((time_s + self.model.latency_s, m));
            // The next capture one period after the scheduled one; after a long pause, one
            // period from now.
            let next = due + period;
            self.next_capture_s = Some(if next + TIME_EPSILON_S < time_s {
                time_s + period
            } else {
                next
            });
        }
        let mut arrived = Vec::new();
        while self
            .in_flight
            .front()
            .is_some_and(|(arrival, _)| *arrival <= time_s + TIME_EPSILON_S)
        {
            if let Some((_, m)) = self.in_flight.pop_front() {
                arrived.push(m);
            }
        }
        arrived
    }
}
