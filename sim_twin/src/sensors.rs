//! The twin's simulated state sensors: an IMU and a pose sensor (motion capture) driven by
//! the truth of each control tick, through the `estimator` crate's sensor models.
//!
//! The twin exposes the measurement at the end of each control period only, so the IMU
//! samples once per period ([`ImuModel::rate_hz`] is set to the control rate) and reads what
//! an integrating IMU would over that period: the mean world acceleration
//! ā = (v_k − v_{k−1})/dt, as specific force in the body frame at mid-period,
//! f = R(q_mid)ᵀ(ā + g e_z), q_mid the attitude halfway between q_{k−1} and q_k; and the mean
//! body rate Log(q_{k−1}⁻¹ ⊗ q_k)/dt (the delta angle over the period). The noise streams
//! come from the run seed's [`RandomStream::Sensors`] stream, apart from every other draw.
//!
//! The navigation sensors an autopilot reads ([`NavigationSensors`]: magnetometer, barometer,
//! GNSS, each on its own schedule) sample the same truth, each from its own stream
//! ([`RandomStream::Magnetometer`], [`RandomStream::Barometer`], [`RandomStream::Gnss`]), so turning
//! them on shifts no IMU or pose draw. The world frame sits on the globe at
//! [`NavigationModels::origin`]: the barometer reads the ISA pressure at the origin's
//! altitude plus the base height, the GNSS the geodetic position of the base.

use estimator::{
    BarometerModel, BarometerSample, BarometerSensor, ConfigError, GeodeticOrigin, GnssFix,
    GnssModel, GnssSensor, ImuModel, ImuSample, ImuSensor, MagnetometerModel, MagnetometerSample,
    MagnetometerSensor, PoseMeasurement, PoseModel, PoseSensor,
};
use nalgebra::Vector3;
use platform::{GRAVITY_MPS2, Measurement, RandomStream, RigidBodyState};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// What a perfect integrating IMU at the base origin reads over the control period from
/// `previous` to `current` (`dt_s` apart), stamped `time_s` (the period's end).
pub fn ideal_imu(
    previous: &RigidBodyState,
    current: &RigidBodyState,
    time_s: f64,
    dt_s: f64,
) -> ImuSample {
    let acceleration = (current.velocity_in_world_mps - previous.velocity_in_world_mps) / dt_s;
    let delta = previous.world_from_body.inverse() * current.world_from_body;
    let mid = previous.world_from_body * delta.powf(0.5);
    ImuSample {
        time_s,
        specific_force_in_body_mps2: mid.inverse()
            * (acceleration + Vector3::new(0.0, 0.0, GRAVITY_MPS2)),
        angular_velocity_in_body_radps: delta.scaled_axis() / dt_s,
    }
}

/// The readings of one control tick.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorReadings {
    /// The IMU sample of the period that just ended (None on the first tick: no period yet).
    pub imu: Option<ImuSample>,
    /// The poses that arrived during the period, oldest first, stamped with their capture
    /// time.
    pub poses: Vec<PoseMeasurement>,
}

/// The simulated IMU and pose sensor of one flight.
#[derive(Debug, Clone)]
pub struct SimulatedSensors {
    imu: ImuSensor,
    pose: PoseSensor,
    rng: ChaCha8Rng,
    previous: Option<(f64, RigidBodyState)>,
    navigation: NavigationSensors,
    seed: u64,
}

impl SimulatedSensors {
    /// Sensors for a twin at `control_rate_hz` (the IMU samples at that rate, whatever
    /// `imu.rate_hz` says), their noise and turn-on biases drawn from `seed`.
    pub fn new(
        imu: ImuModel,
        pose: PoseModel,
        control_rate_hz: f64,
        seed: u64,
    ) -> Result<Self, ConfigError> {
        let mut rng = RandomStream::Sensors.rng(seed);
        let imu = ImuSensor::new(
            ImuModel {
                rate_hz: control_rate_hz,
                ..imu
            },
            &mut rng,
        )?;
        Ok(Self {
            imu,
            pose: PoseSensor::new(pose)?,
            rng,
            previous: None,
            navigation: NavigationSensors::new(NavigationModels::default(), seed)?,
            seed,
        })
    }

    /// The same sensors with the navigation sensors of `models` (their draws start afresh
    /// from their streams of the seed; the IMU and pose draws are untouched).
    pub fn with_navigation(mut self, models: NavigationModels) -> Result<Self, ConfigError> {
        self.navigation = NavigationSensors::new(models, self.seed)?;
        Ok(self)
    }

    /// The navigation sensors (magnetometer, barometer, GNSS).
    pub fn navigation(&self) -> &NavigationSensors {
        &self.navigation
    }

    /// The navigation readings due at the time of `truth` (each sensor on its own schedule).
    pub fn sample_navigation(&mut self, truth: &Measurement) -> NavigationReadings {
        self.navigation.sample(truth)
    }

    /// The IMU's current biases: accelerometer m/s², gyroscope rad/s, body frame.
    pub fn imu_biases(&self) -> (Vector3<f64>, Vector3<f64>) {
        self.imu.biases()
    }

    /// One noisy capture of the base pose in `truth`, outside the schedule and without
    /// latency: the pose the estimator starts from (the vehicle on the motion-capture stage
    /// before the flight).
    pub fn initial_pose(&mut self, truth: &Measurement) -> PoseMeasurement {
        self.pose.capture(
            truth.time_s,
            &truth.base.position_in_world_m,
            &truth.base.world_from_body,
            &mut self.rng,
        )
    }

    /// The readings at the end of the control period that ends with `truth`. A truth that
    /// does not advance time gives no IMU sample.
    pub fn sample(&mut self, truth: &Measurement) -> SensorReadings {
        let imu = match &self.previous {
            Some((t0, previous)) if truth.time_s > *t0 => {
                let ideal = ideal_imu(previous, &truth.base, truth.time_s, truth.time_s - t0);
                Some(self.imu.measure(&ideal, &mut self.rng))
            }
            _ => None,
        };
        if self
            .previous
            .as_ref()
            .is_none_or(|(t0, _)| truth.time_s > *t0)
        {
            self.previous = Some((truth.time_s, truth.base));
        }
        let poses = self.pose.step(
            truth.time_s,
            &truth.base.position_in_world_m,
            &truth.base.world_from_body,
            &mut self.rng,
        );
        SensorReadings { imu, poses }
    }
}

/// The navigation sensors' models and where the world is on the globe. Defaults: PX4's
/// default SITL home and the models' defaults.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NavigationModels {
    /// The world origin on the globe (the ground under the vehicle's start).
    pub origin: GeodeticOrigin,
    /// The magnetometer and the Earth's field at the origin.
    pub magnetometer: MagnetometerModel,
    /// The barometer.
    pub barometer: BarometerModel,
    /// The GNSS receiver.
    pub gnss: GnssModel,
}

/// The navigation readings of one tick: each present when its sensor sampled.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NavigationReadings {
    /// Magnetometer, body frame (FLU), gauss.
    pub magnetometer: Option<MagnetometerSample>,
    /// Barometer: pressure at the base's altitude above mean sea level.
    pub barometer: Option<BarometerSample>,
    /// GNSS fix of the base origin.
    pub gnss: Option<GnssFix>,
}

/// The simulated magnetometer, barometer and GNSS receiver of one flight, each with its own
/// random stream of the seed.
#[derive(Debug, Clone)]
pub struct NavigationSensors {
    origin: GeodeticOrigin,
    magnetometer: MagnetometerSensor,
    barometer: BarometerSensor,
    gnss: GnssSensor,
    magnetometer_rng: ChaCha8Rng,
    barometer_rng: ChaCha8Rng,
    gnss_rng: ChaCha8Rng,
}

impl NavigationSensors {
    /// The sensors of `models`, their biases drawn from their streams of `seed`.
    pub fn new(models: NavigationModels, seed: u64) -> Result<Self, ConfigError> {
        models.origin.validate()?;
        let mut magnetometer_rng = RandomStream::Magnetometer.rng(seed);
        let mut barometer_rng = RandomStream::Barometer.rng(seed);
        Ok(Self {
            origin: models.origin,
            magnetometer: MagnetometerSensor::new(models.magnetometer, &mut magnetometer_rng)?,
            barometer: BarometerSensor::new(models.barometer, &mut barometer_rng)?,
            gnss: GnssSensor::new(models.gnss)?,
            magnetometer_rng,
            barometer_rng,
            gnss_rng: RandomStream::Gnss.rng(seed),
        })
    }

    /// Where the world origin is on the globe.
    pub fn origin(&self) -> &GeodeticOrigin {
        &self.origin
    }

    /// The magnetometer (its model and bias).
    pub fn magnetometer(&self) -> &MagnetometerSensor {
        &self.magnetometer
    }

    /// The barometer (its model and offset).
    pub fn barometer(&self) -> &BarometerSensor {
        &self.barometer
    }

    /// The GNSS receiver.
    pub fn gnss(&self) -> &GnssSensor {
        &self.gnss
    }

    /// The readings due at the time of `truth`, from its base state.
    pub fn sample(&mut self, truth: &Measurement) -> NavigationReadings {
        let base = &truth.base;
        let t = truth.time_s;
        NavigationReadings {
            magnetometer: self.magnetometer.step(
                t,
                &base.world_from_body,
                &mut self.magnetometer_rng,
            ),
            barometer: self.barometer.step(
                t,
                self.origin.altitude_amsl_m + base.position_in_world_m.z,
                &mut self.barometer_rng,
            ),
            gnss: self.gnss.step(
                t,
                &self.origin,
                &base.position_in_world_m,
                &base.velocity_in_world_mps,
                &mut self.gnss_rng,
            ),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use nalgebra::{UnitQuaternion, Vector3};
    use platform::RigidBodyState;

    use super::ideal_imu;

    /// Hand-made: a vehicle yawing at 0.5 rad/s while accelerating along world x at 2 m/s²,
    /// from yaw 0 to 0.5·dt. At mid-period the body x axis points at yaw 0.25·dt, so the
    /// specific force is Rz(−0.25 dt)(2, 0, 9.81).
    #[test]
    fn ideal_imu_reads_mean_acceleration_at_mid_period_and_the_delta_angle() {
        let dt = 0.1;
        let previous = RigidBodyState::default();
        let current = RigidBodyState {
            world_from_body: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5 * dt),
            velocity_in_world_mps: Vector3::new(2.0 * dt, 0.0, 0.0),
            ..RigidBodyState::default()
        };
        let s = ideal_imu(&previous, &current, 1.0, dt);
        let yaw: f64 = 0.25 * dt;
        let expected = Vector3::new(2.0 * yaw.cos(), -2.0 * yaw.sin(), 9.81);
        assert!((s.specific_force_in_body_mps2 - expected).norm() < 1e-12);
        assert!((s.angular_velocity_in_body_radps - Vector3::new(0.0, 0.0, 0.5)).norm() < 1e-12);
        assert_eq!(s.time_s, 1.0);
        // At rest, level: +g along body z.
        let rest = ideal_imu(&previous, &previous, 0.0, dt);
        assert_eq!(
            rest.specific_force_in_body_mps2,
            Vector3::new(0.0, 0.0, 9.81)
        );
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod navigation_tests {
    use estimator::{ImuModel, PoseModel};
    use nalgebra::Vector3;
    use platform::Measurement;

    use super::{NavigationModels, SimulatedSensors};

    fn at(time_s: f64, height_m: f64) -> Measurement {
        let mut m = Measurement {
            time_s,
            ..Measurement::default()
        };
        m.base.position_in_world_m = Vector3::new(0.0, 0.0, height_m);
        m
    }

    /// Sampling the navigation sensors draws from their own streams: the IMU and pose
    /// readings are bit-identical with and without them.
    #[test]
    fn navigation_sensors_shift_no_imu_or_pose_draw() {
        let make =
            || SimulatedSensors::new(ImuModel::default(), PoseModel::default(), 120.0, 42).unwrap();
        let (mut plain, mut with_nav) = (make(), make());
        for k in 0..240 {
            let truth = at(f64::from(k) / 120.0, 1.0);
            let a = plain.sample(&truth);
            let nav = with_nav.sample_navigation(&truth);
            let b = with_nav.sample(&truth);
            assert_eq!(format!("{a:?}"), format!("{b:?}"));
            if k == 0 {
                assert!(nav.gnss.is_some() && nav.barometer.is_some());
            }
        }
    }

    /// At rest 1 m above PX4's home (488 m): the barometer reads about p(489 m) =
    /// 95 587 Pa (ISA), the GNSS the home latitude, the magnetometer a field of 0.485 G.
    #[test]
    fn navigation_readings_at_rest_above_home() {
        let mut s = SimulatedSensors::new(ImuModel::default(), PoseModel::default(), 120.0, 3)
            .unwrap()
            .with_navigation(NavigationModels::default())
            .unwrap();
        let r = s.sample_navigation(&at(0.0, 1.0));
        let baro = r.barometer.unwrap();
        let isa = estimator::barometer::isa_pressure_pa(489.0, 101_325.0);
        assert!((isa - 95_586.8).abs() < 0.1, "{isa}");
        assert!((baro.pressure_pa - isa).abs() < 5.0);
        let fix = r.gnss.unwrap();
        assert!((fix.position.latitude_deg - 47.397742).abs() < 1e-4);
        assert!((fix.position.altitude_amsl_m - 489.0).abs() < 4.0);
        let mag = r.magnetometer.unwrap();
        assert!((mag.field_in_body_gauss.norm() - 0.485).abs() < 0.03);
    }
}
