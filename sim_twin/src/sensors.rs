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

use estimator::{
    ConfigError, ImuModel, ImuSample, ImuSensor, PoseMeasurement, PoseModel, PoseSensor,
};
use nalgebra::Vector3;
use platform::{GRAVITY_MPS2, Measurement, RandomStream, RigidBodyState};
use rand_chacha::ChaCha8Rng;

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
        })
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
