//! Where the flight stack's base state comes from: the link's measurement as it is (`truth`),
//! or the estimator (`estimator`), fed by one of two sensor sets:
//! - **simulated** (the twin in this process or over iceoryx2): each control tick the twin's
//!   measurement drives a simulated IMU and pose sensor ([`sim_twin::sensors`]);
//! - **the vehicle's own** (a link that reports them: over MAVLink, HIGHRES_IMU and ODOMETRY
//!   from the autopilot, [`VehicleSensors`]): the autopilot's IMU sample and odometry (pose
//!   and velocity, at its capture time) of each tick. The noise the filter assumes for them is
//!   the settings' pose model (ODOMETRY's covariances are optional in MAVLink).
//!
//! The [`estimator::Estimator`] fuses them, and the controllers receive the measurement with
//! its `base` replaced by the estimate (and `world_from_ee` moved with it). Scores and the
//! log's truth channels keep the measurement.

use estimator::{
    Accepted, ConfigError, Estimator, EstimatorConfig, ImuModel, Innovation, Measurement as Fix,
    OdometryMeasurement, PoseModel, Rejection,
};
use nalgebra::Vector3;
use platform::{Measurement, RigidBodyState};
use serde::{Deserialize, Serialize};
use sim_twin::sensors::SimulatedSensors;

pub use crate::link::VehicleSensors;

/// The sensors and the filter of `--state-source estimator`. Every section has defaults
/// (see each type); a TOML file may set any subset:
///
/// ```toml
/// [imu]
/// accel_noise_mps2_per_sqrt_hz = 0.004
/// [pose]
/// latency_s = 0.03
/// [estimator]
/// history_s = 0.5
/// ```
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EstimatorSettings {
    /// The simulated IMU (its rate is the control rate, whatever `rate_hz` says).
    pub imu: ImuModel,
    /// The simulated pose sensor.
    pub pose: PoseModel,
    /// The filter.
    pub estimator: EstimatorConfig,
}

impl EstimatorSettings {
    /// Checks every section.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.imu.validate()?;
        self.pose.validate()?;
        self.estimator.validate()
    }
}

/// Where the controllers' base state comes from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum StateSource {
    /// The link's measurement (the twin's truth, with its observation noise if that is on).
    #[default]
    Truth,
    /// The estimator, fed by simulated sensors.
    Estimator(EstimatorSettings),
}

impl StateSource {
    /// The command-line name (`truth`, `estimator`).
    pub fn name(&self) -> &'static str {
        match self {
            Self::Truth => "truth",
            Self::Estimator(_) => "estimator",
        }
    }
}

/// The estimator could not give a state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimateError {
    /// A setting out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The first pose was refused.
    #[error("the estimator refused its first pose: {0}")]
    Start(Rejection),
    /// The estimate is not finite (a diverged filter).
    #[error("the state estimate is not finite at t = {time_s:.3} s")]
    NotFinite {
        /// Simulated time, s.
        time_s: f64,
    },
}

/// One tick's report of the estimator, for the log.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimateReport {
    /// The estimate handed to the controllers.
    pub state: RigidBodyState,
    /// Position error against the measurement it was estimated from, world, m.
    pub position_error_m: Vector3<f64>,
    /// One standard deviation of position (m), velocity (m/s), attitude (rad), world/body.
    pub position_std_m: Vector3<f64>,
    /// Velocity deviation, m/s.
    pub velocity_std_mps: Vector3<f64>,
    /// Attitude deviation, rad.
    pub attitude_std_rad: Vector3<f64>,
    /// Estimated accelerometer bias, body, m/s².
    pub accel_bias_mps2: Vector3<f64>,
    /// Estimated gyroscope bias, body, rad/s.
    pub gyro_bias_radps: Vector3<f64>,
    /// The simulated IMU's true accelerometer bias, m/s² (unknown for a vehicle's IMU).
    pub true_accel_bias_mps2: Option<Vector3<f64>>,
    /// The simulated IMU's true gyroscope bias, rad/s (unknown for a vehicle's IMU).
    pub true_gyro_bias_radps: Option<Vector3<f64>>,
    /// Innovations of the poses fused this tick.
    pub innovations: Vec<Innovation>,
    /// Reasons of the inputs refused this tick.
    pub rejections: Vec<Rejection>,
}

/// Summary of the estimator over a flight.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EstimatorSummary {
    /// RMS of the 3-D position error of the estimate against the measurement, over the
    /// scored ticks, m.
    pub position_rmse_m: f64,
    /// Largest 3-D position error over the scored ticks, m.
    pub position_max_error_m: f64,
    /// Whose sensors fed the filter: `simulated` (the twin's, through the sensor models) or
    /// `vehicle` (the autopilot's HIGHRES_IMU and ODOMETRY).
    pub sensors: &'static str,
    /// Poses fused.
    pub fused: u64,
    /// Inputs refused.
    pub rejected: u64,
    /// Mean normalised innovation squared of the fused poses (6 when consistent).
    pub mean_nis: f64,
}

/// Where the filter's inputs come from.
#[derive(Debug)]
enum Feed {
    /// The twin's measurement through simulated sensors.
    Simulated(Box<SimulatedSensors>),
    /// The vehicle's sensors as the link reports them.
    Vehicle {
        /// The noise assumed where the link gives none.
        noise: OdometryNoise,
        /// Capture time of the last odometry fused, s (a repeated one is not fused twice).
        last_odometry_s: Option<f64>,
        /// Time of the last IMU sample fed, s (likewise).
        last_imu_s: Option<f64>,
    },
}

/// The noise the filter assumes for a vehicle's odometry that does not report it.
#[derive(Debug, Clone, Copy)]
struct OdometryNoise {
    position_std_m: f64,
    attitude_std_rad: f64,
    velocity_std_mps: f64,
}

impl OdometryNoise {
    /// `o` with the link's noise where it gave one, else this.
    fn fill(&self, mut o: OdometryMeasurement) -> OdometryMeasurement {
        let keep = |given: f64, default: f64| {
            if given.is_finite() && given > 0.0 {
                given
            } else {
                default
            }
        };
        o.pose.position_std_m = keep(o.pose.position_std_m, self.position_std_m);
        o.pose.attitude_std_rad = keep(o.pose.attitude_std_rad, self.attitude_std_rad);
        o.velocity_std_mps = keep(o.velocity_std_mps, self.velocity_std_mps);
        o
    }
}

/// Velocity noise assumed for a vehicle's odometry that does not report it, m/s: a
/// motion-capture-grade velocity (a few mm of position noise differentiated over a few
/// samples).
const ODOMETRY_VELOCITY_STD_MPS: f64 = 0.02;

/// The running estimator of a flight: its sensors + filter.
#[derive(Debug)]
pub(crate) struct StateEstimate {
    feed: Feed,
    estimator: Estimator,
    nis_sum: f64,
    error_sum: f64,
    error_max: f64,
    scored: u64,
}

impl StateEstimate {
    /// Sensors seeded from `seed`, the filter started from a noisy pose of `first`.
    pub(crate) fn new(
        settings: &EstimatorSettings,
        control_rate_hz: f64,
        seed: u64,
        first: &Measurement,
    ) -> Result<Self, EstimateError> {
        settings.validate()?;
        let mut sensors =
            SimulatedSensors::new(settings.imu, settings.pose, control_rate_hz, seed)?;
        let mut estimator = Estimator::new(settings.estimator)?;
        let pose = sensors.initial_pose(first);
        estimator
            .correct(&Fix::Pose(pose))
            .map_err(EstimateError::Start)?;
        // The first tick's sample starts the IMU's period.
        let _ = sensors.sample(first);
        Ok(Self {
            feed: Feed::Simulated(Box::new(sensors)),
            estimator,
            nis_sum: 0.0,
            error_sum: 0.0,
            error_max: 0.0,
            scored: 0,
        })
    }

    /// The filter fed by the vehicle's own sensors, started from the first tick's odometry
    /// (`first` when the link gave none yet).
    pub(crate) fn from_vehicle(
        settings: &EstimatorSettings,
        first: &Measurement,
        sensors: &VehicleSensors,
    ) -> Result<Self, EstimateError> {
        settings.validate()?;
        let mut estimator = Estimator::new(settings.estimator)?;
        let noise = OdometryNoise {
            position_std_m: settings.pose.position_std_m,
            attitude_std_rad: settings.pose.attitude_std_rad,
            velocity_std_mps: ODOMETRY_VELOCITY_STD_MPS,
        };
        let start = sensors
            .odometry
            .unwrap_or_else(|| VehicleSensors::odometry_of(first));
        let start = noise.fill(start);
        estimator
            .correct(&Fix::Pose(start.pose))
            .map_err(EstimateError::Start)?;
        Ok(Self {
            feed: Feed::Vehicle {
                noise,
                last_odometry_s: Some(start.pose.time_s),
                last_imu_s: None,
            },
            estimator,
            nis_sum: 0.0,
            error_sum: 0.0,
            error_max: 0.0,
            scored: 0,
        })
    }

    /// Whether the filter is fed by the vehicle's own sensors.
    pub(crate) fn on_vehicle_sensors(&self) -> bool {
        matches!(self.feed, Feed::Vehicle { .. })
    }

    /// Feeds the tick's readings of the sensors — the simulated ones' of `m` (the
    /// measurement at the end of a control period), or the vehicle's `vehicle` — to the
    /// filter and returns `m` with its base replaced by the estimate.
    pub(crate) fn observe(
        &mut self,
        m: &Measurement,
        vehicle: Option<&VehicleSensors>,
        score: bool,
    ) -> Result<(Measurement, EstimateReport), EstimateError> {
        let (imu, fixes) = match &mut self.feed {
            Feed::Simulated(sensors) => {
                let readings = sensors.sample(m);
                (
                    readings.imu,
                    readings
                        .poses
                        .into_iter()
                        .map(Fix::Pose)
                        .collect::<Vec<_>>(),
                )
            }
            Feed::Vehicle {
                noise,
                last_odometry_s,
                last_imu_s,
            } => {
                // Only readings newer than the last ones fed: a link that did not advance
                // repeats them.
                let newer = |last: Option<f64>, t: f64| last.is_none_or(|l| t > l);
                let imu = vehicle
                    .and_then(|v| v.imu)
                    .filter(|i| newer(*last_imu_s, i.time_s));
                let odometry = vehicle
                    .and_then(|v| v.odometry)
                    .filter(|o| newer(*last_odometry_s, o.pose.time_s));
                if let Some(i) = &imu {
                    *last_imu_s = Some(i.time_s);
                }
                if let Some(o) = &odometry {
                    *last_odometry_s = Some(o.pose.time_s);
                }
                let fixes = odometry
                    .map(|o| Fix::Odometry(noise.fill(o)))
                    .into_iter()
                    .collect();
                (imu, fixes)
            }
        };
        let mut innovations = Vec::new();
        let mut rejections = Vec::new();
        if let Some(imu) = &imu {
            match self.estimator.predict(imu) {
                Ok(Accepted::Propagated { fused, .. }) if fused > 0 => {
                    innovations.extend(self.estimator.diagnostics().last_innovation);
                }
                Ok(_) => {}
                Err(r) => rejections.push(r),
            }
        }
        for fix in &fixes {
            match self.estimator.correct(fix) {
                Ok(Accepted::Fused(i)) => innovations.push(i),
                Ok(_) => {}
                Err(r) => rejections.push(r),
            }
        }
        let (Some(state), Some(std), Some((ba, bg))) = (
            self.estimator.state(),
            self.estimator.std_devs(),
            self.estimator.biases(),
        ) else {
            return Err(EstimateError::NotFinite { time_s: m.time_s });
        };
        if !state.is_finite() {
            return Err(EstimateError::NotFinite { time_s: m.time_s });
        }
        let error = state.position_in_world_m - m.base.position_in_world_m;
        self.nis_sum += innovations.iter().map(|i| i.nis).sum::<f64>();
        if score {
            let e = error.norm();
            self.scored += 1;
            self.error_sum += e * e;
            self.error_max = self.error_max.max(e);
        }
        let (true_ba, true_bg) = match &self.feed {
            Feed::Simulated(sensors) => {
                let (a, g) = sensors.imu_biases();
                (Some(a), Some(g))
            }
            // A real IMU's biases are not known.
            Feed::Vehicle { .. } => (None, None),
        };
        let mut fed = m.clone();
        // The end effector rides on the estimated base: the arm's base → EE transform
        // (what the joint encoders give) composed with the estimated pose.
        fed.world_from_ee = state.pose() * m.base.pose().inverse() * m.world_from_ee;
        fed.base = state;
        Ok((
            fed,
            EstimateReport {
                state,
                position_error_m: error,
                position_std_m: std.position_m,
                velocity_std_mps: std.velocity_mps,
                attitude_std_rad: std.attitude_rad,
                accel_bias_mps2: ba,
                gyro_bias_radps: bg,
                true_accel_bias_mps2: true_ba,
                true_gyro_bias_radps: true_bg,
                innovations,
                rejections,
            },
        ))
    }

    /// The flight's summary.
    pub(crate) fn summary(&self) -> EstimatorSummary {
        let d = self.estimator.diagnostics();
        EstimatorSummary {
            sensors: if self.on_vehicle_sensors() {
                "vehicle"
            } else {
                "simulated"
            },
            position_rmse_m: if self.scored > 0 {
                (self.error_sum / self.scored as f64).sqrt()
            } else {
                f64::NAN
            },
            position_max_error_m: self.error_max,
            fused: d.fused,
            rejected: d.rejected,
            mean_nis: if d.fused > 0 {
                self.nis_sum / d.fused as f64
            } else {
                f64::NAN
            },
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use platform::{Measurement, RigidBodyState};

    use estimator::ImuSample;
    use nalgebra::Vector3;

    use super::{EstimatorSettings, StateEstimate, VehicleSensors};

    fn hovering(t: f64) -> Measurement {
        let base = Isometry3::from_parts(
            Translation3::new(0.5, -0.2, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        );
        Measurement {
            time_s: t,
            base: RigidBodyState::at_rest(base),
            world_from_ee: base * Isometry3::translation(0.3, 0.0, -0.2),
            ..Measurement::default()
        }
    }

    /// A vehicle holding still for 2 s: the estimate stays within 3·σ_p = 6 mm of it, the
    /// end effector keeps the arm's base → EE transform on the estimated base, nothing is
    /// refused, and the same seed gives the same bits.
    #[test]
    fn holding_still_the_controllers_get_the_estimate_with_the_ee_on_it() {
        let run = || {
            let settings = EstimatorSettings::default();
            let mut e = StateEstimate::new(&settings, 120.0, 3, &hovering(0.0)).unwrap();
            let mut last = None;
            for k in 1..=240 {
                let m = hovering(f64::from(k) / 120.0);
                let (fed, report) = e.observe(&m, None, true).unwrap();
                assert!(report.rejections.is_empty(), "{:?}", report.rejections);
                let arm = fed.base.pose().inverse() * fed.world_from_ee;
                let truth_arm = m.base.pose().inverse() * m.world_from_ee;
                assert!((arm.translation.vector - truth_arm.translation.vector).norm() < 1e-12);
                assert!((fed.base.position_in_world_m - m.base.position_in_world_m).norm() < 0.006);
                last = Some(fed);
            }
            (last.unwrap(), e.summary())
        };
        let (a, summary) = run();
        let (b, _) = run();
        assert_eq!(
            a.base.position_in_world_m.map(f64::to_bits),
            b.base.position_in_world_m.map(f64::to_bits)
        );
        // 60 Hz for 2 s, less the captures in flight: 118 or 119 poses, plus the first.
        assert!((118..=120).contains(&summary.fused), "{summary:?}");
        assert!(summary.position_rmse_m < 0.003, "{summary:?}");
    }

    /// What a vehicle's autopilot reports of `m`: its IMU (hovering: the specific force is
    /// gravity's reaction, body up; no rotation) and its odometry, without covariances.
    fn vehicle(m: &Measurement) -> VehicleSensors {
        VehicleSensors {
            imu: Some(ImuSample {
                time_s: m.time_s,
                specific_force_in_body_mps2: m.base.world_from_body.inverse()
                    * Vector3::new(0.0, 0.0, platform::GRAVITY_MPS2),
                angular_velocity_in_body_radps: Vector3::zeros(),
            }),
            odometry: Some(VehicleSensors::odometry_of(m)),
        }
    }

    /// Fed by the vehicle's sensors: one odometry fused per new capture time (a tick that
    /// repeats the last one fuses nothing), the settings' noise in place of the missing
    /// covariances, the estimate on the reported pose, the true biases unknown.
    #[test]
    fn on_the_vehicles_sensors_each_odometry_is_fused_once() {
        let settings = EstimatorSettings::default();
        let first = hovering(0.0);
        let mut e = StateEstimate::from_vehicle(&settings, &first, &vehicle(&first)).unwrap();
        assert!(e.on_vehicle_sensors());
        for k in 1..=120 {
            let m = hovering(f64::from(k) / 120.0);
            let (fed, report) = e.observe(&m, Some(&vehicle(&m)), true).unwrap();
            assert!(report.rejections.is_empty(), "{:?}", report.rejections);
            assert_eq!(report.innovations.len(), 1, "tick {k}");
            assert!(report.true_accel_bias_mps2.is_none());
            assert!((fed.base.position_in_world_m - m.base.position_in_world_m).norm() < 1e-3);
            // The same tick again (a link that did not advance): nothing new to fuse.
            let (_, again) = e.observe(&m, Some(&vehicle(&m)), true).unwrap();
            assert!(again.innovations.is_empty(), "tick {k} fused twice");
        }
        let summary = e.summary();
        assert_eq!(summary.sensors, "vehicle");
        // One odometry per tick (the start pose initialises the filter), nothing refused.
        assert_eq!((summary.fused, summary.rejected), (120, 0), "{summary:?}");
    }
}
