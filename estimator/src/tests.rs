//! The estimator against a trajectory whose accelerations and rates are known exactly, with
//! the sensor models of this crate in the loop.
#![allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]

use nalgebra::{UnitQuaternion, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::{
    Accepted, Estimator, EstimatorConfig, ImuModel, ImuSample, ImuSensor, Measurement,
    OdometryMeasurement, PoseMeasurement, PoseModel, PoseSensor, Rejection,
};

/// A circle in the horizontal plane with a height wave, a yaw sweep and a constant roll:
///
/// ```text
/// p(t) = (r cos Ωt, r sin Ωt, z0 + h sin νt)
/// v(t) = (−rΩ sin Ωt, rΩ cos Ωt, hν cos νt)
/// a(t) = (−rΩ² cos Ωt, −rΩ² sin Ωt, −hν² sin νt)
/// R(t) = Rz(ψ(t)) Rx(φ0),  ψ(t) = A sin λt,  ψ̇ = Aλ cos λt
/// ```
///
/// Ṙ = ψ̇ [e_z]× R, so the body rate is ω = Rᵀ e_z ψ̇ = Rx(φ0)ᵀ e_z ψ̇ = (0, sin φ0, cos φ0) ψ̇;
/// the specific force f = Rᵀ(a + g e_z) (g = 9.81 m/s²).
#[derive(Debug, Clone, Copy)]
struct Circle {
    radius_m: f64,
    omega_radps: f64,
    z0_m: f64,
    height_m: f64,
    nu_radps: f64,
    yaw_amplitude_rad: f64,
    lambda_radps: f64,
    roll_rad: f64,
}

/// 2 m radius at 0.8 rad/s (1.6 m/s, 1.28 m/s² centripetal), ±0.2 m at 0.5 rad/s, yaw ±1 rad
/// at 0.4 rad/s, 0.1 rad roll.
const CIRCLE: Circle = Circle {
    radius_m: 2.0,
    omega_radps: 0.8,
    z0_m: 1.0,
    height_m: 0.2,
    nu_radps: 0.5,
    yaw_amplitude_rad: 1.0,
    lambda_radps: 0.4,
    roll_rad: 0.1,
};

/// Standing still, level, 1 m up.
const STILL: Circle = Circle {
    radius_m: 0.0,
    omega_radps: 0.0,
    z0_m: 1.0,
    height_m: 0.0,
    nu_radps: 0.0,
    yaw_amplitude_rad: 0.0,
    lambda_radps: 0.0,
    roll_rad: 0.0,
};

impl Circle {
    fn position(&self, t: f64) -> Vector3<f64> {
        let (s, c) = (self.omega_radps * t).sin_cos();
        Vector3::new(
            self.radius_m * c,
            self.radius_m * s,
            self.z0_m + self.height_m * (self.nu_radps * t).sin(),
        )
    }

    fn velocity(&self, t: f64) -> Vector3<f64> {
        let (s, c) = (self.omega_radps * t).sin_cos();
        let w = self.omega_radps;
        Vector3::new(
            -self.radius_m * w * s,
            self.radius_m * w * c,
            self.height_m * self.nu_radps * (self.nu_radps * t).cos(),
        )
    }

    fn acceleration(&self, t: f64) -> Vector3<f64> {
        let (s, c) = (self.omega_radps * t).sin_cos();
        let w2 = self.omega_radps * self.omega_radps;
        Vector3::new(
            -self.radius_m * w2 * c,
            -self.radius_m * w2 * s,
            -self.height_m * self.nu_radps * self.nu_radps * (self.nu_radps * t).sin(),
        )
    }

    fn attitude(&self, t: f64) -> UnitQuaternion<f64> {
        let yaw = self.yaw_amplitude_rad * (self.lambda_radps * t).sin();
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), self.roll_rad)
    }

    fn body_rate(&self, t: f64) -> Vector3<f64> {
        let yaw_rate = self.yaw_amplitude_rad * self.lambda_radps * (self.lambda_radps * t).cos();
        Vector3::new(0.0, self.roll_rad.sin(), self.roll_rad.cos()) * yaw_rate
    }

    fn state(&self, t: f64) -> RigidBodyState {
        RigidBodyState {
            position_in_world_m: self.position(t),
            world_from_body: self.attitude(t),
            velocity_in_world_mps: self.velocity(t),
            angular_velocity_in_body_radps: self.body_rate(t),
        }
    }

    /// The true mean specific force and rate over (t − dt, t], by the midpoint rule (error
    /// O(dt³) per sample).
    fn imu(&self, t: f64, dt: f64) -> ImuSample {
        let tm = t - 0.5 * dt;
        let f = self.attitude(tm).inverse()
            * (self.acceleration(tm) + Vector3::new(0.0, 0.0, GRAVITY_MPS2));
        ImuSample {
            time_s: t,
            specific_force_in_body_mps2: f,
            angular_velocity_in_body_radps: self.body_rate(tm),
        }
    }
}

/// How a scenario stamps its pose measurements.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stamp {
    /// With their capture time (the estimator reaches back into its history).
    Capture,
    /// With their arrival time: latency ignored, as a naive filter would.
    Arrival,
}

#[derive(Debug, Clone, Copy)]
struct Scenario {
    trajectory: Circle,
    duration_s: f64,
    imu: ImuModel,
    accel_bias: Vector3<f64>,
    gyro_bias: Vector3<f64>,
    pose: PoseModel,
    stamp: Stamp,
    seed: u64,
    /// Errors are scored after this, s (bias convergence transient).
    score_after_s: f64,
}

const ACCEL_BIAS: Vector3<f64> = Vector3::new(0.08, -0.05, 0.12);
const GYRO_BIAS: Vector3<f64> = Vector3::new(0.004, -0.006, 0.003);

/// The circle for 40 s: a 200 Hz IMU with the default noise and the biases above, a 50 Hz
/// pose sensor with 2 mm / 0.005 rad noise and 20 ms latency.
fn circle_scenario() -> Scenario {
    Scenario {
        trajectory: CIRCLE,
        duration_s: 40.0,
        imu: ImuModel {
            rate_hz: 200.0,
            ..ImuModel::default()
        },
        accel_bias: ACCEL_BIAS,
        gyro_bias: GYRO_BIAS,
        pose: PoseModel {
            rate_hz: 50.0,
            position_std_m: 0.002,
            attitude_std_rad: 0.005,
            latency_s: 0.02,
        },
        stamp: Stamp::Capture,
        seed: 7,
        score_after_s: 10.0,
    }
}

#[derive(Debug)]
struct Outcome {
    estimator: Estimator,
    /// RMS of the 3-D position error after `score_after_s`, m.
    position_rms_m: f64,
    /// Largest 3-D position error after `score_after_s`, m.
    position_max_m: f64,
    /// RMS of the estimator's own 3-D position deviation √(tr P_pp) over the same ticks, m.
    predicted_rms_m: f64,
    /// RMS velocity error after `score_after_s`, m/s.
    velocity_rms_mps: f64,
    /// Largest attitude error after `score_after_s`, rad.
    attitude_max_rad: f64,
    /// Mean NIS of the fused poses after `score_after_s`.
    mean_nis: f64,
    /// The IMU's biases at the end.
    true_biases: (Vector3<f64>, Vector3<f64>),
}

fn run(s: &Scenario) -> Outcome {
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    let mut imu = ImuSensor::with_biases(s.imu, s.accel_bias, s.gyro_bias).unwrap();
    let mut pose = PoseSensor::new(s.pose).unwrap();
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    est.initialize(0.0, &s.trajectory.state(0.0)).unwrap();
    let dt = 1.0 / s.imu.rate_hz;
    let ticks = (s.duration_s * s.imu.rate_hz).round() as u64;
    let (mut n, mut sum_p, mut max_p, mut sum_pred, mut sum_v, mut max_att) =
        (0u64, 0.0, 0.0_f64, 0.0, 0.0, 0.0_f64);
    let (mut nis_sum, mut nis_n) = (0.0, 0u64);
    for k in 1..=ticks {
        let t = k as f64 * dt;
        let truth = s.trajectory.imu(t, dt);
        let sample = imu.measure(&truth, &mut rng);
        assert!(matches!(
            est.predict(&sample),
            Ok(Accepted::Propagated { .. })
        ));
        let tr = &s.trajectory;
        for mut m in pose.step(t, &tr.position(t), &tr.attitude(t), &mut rng) {
            if s.stamp == Stamp::Arrival {
                m.time_s = t;
            }
            match est.correct(&Measurement::Pose(m)).unwrap() {
                Accepted::Fused(innovation) if t >= s.score_after_s => {
                    nis_sum += innovation.nis;
                    nis_n += 1;
                }
                _ => {}
            }
        }
        if t >= s.score_after_s {
            let e = est.state().unwrap();
            let ep = (e.position_in_world_m - tr.position(t)).norm();
            let sd = est.std_devs().unwrap().position_m;
            n += 1;
            sum_p += ep * ep;
            max_p = max_p.max(ep);
            sum_pred += sd.norm_squared();
            sum_v += (e.velocity_in_world_mps - tr.velocity(t)).norm_squared();
            max_att = max_att.max(e.world_from_body.angle_to(&tr.attitude(t)));
        }
    }
    let nf = n as f64;
    Outcome {
        true_biases: imu.biases(),
        estimator: est,
        position_rms_m: (sum_p / nf).sqrt(),
        position_max_m: max_p,
        predicted_rms_m: (sum_pred / nf).sqrt(),
        velocity_rms_mps: (sum_v / nf).sqrt(),
        attitude_max_rad: max_att,
        mean_nis: nis_sum / nis_n as f64,
    }
}

#[test]
fn trajectory_derivatives_are_consistent() {
    // The hand-derived velocity, acceleration and body rate against central differences of
    // position, velocity and attitude: the test fixture itself is right.
    let c = CIRCLE;
    let h = 1e-5;
    for t in [0.0, 1.3, 7.9, 21.4] {
        let dv = (c.position(t + h) - c.position(t - h)) / (2.0 * h);
        let da = (c.velocity(t + h) - c.velocity(t - h)) / (2.0 * h);
        let dq = c.attitude(t - h).inverse() * c.attitude(t + h);
        let w = dq.scaled_axis() / (2.0 * h);
        assert!((dv - c.velocity(t)).norm() < 1e-8, "v at {t}");
        assert!((da - c.acceleration(t)).norm() < 1e-8, "a at {t}");
        assert!((w - c.body_rate(t)).norm() < 1e-8, "ω at {t}");
    }
}

/// The circle (1.6 m/s, 1.28 m/s², yaw ±1 rad) with a noisy, biased 200 Hz IMU and a 50 Hz
/// pose sensor (σ = 2 mm, 0.005 rad; 20 ms latency), measurements stamped with their
/// capture time.
///
/// Bound: after the bias transient (10 s), the RMS 3-D position error stays below
/// σ_p = 2 mm, i.e. below the RMS error of a raw pose sample (√3·σ_p = 3.5 mm) — the IMU
/// must add information, not only pass the pose through — and the largest error below
/// 3·√3·σ_p ≈ 10 mm. The filter must also know how good it is: the RMS error lies within a
/// factor 2 of its own predicted deviation √(tr P_pp), and the mean NIS of the poses
/// (χ² with 6 degrees of freedom when consistent) lies in [3, 12].
#[test]
fn circle_with_noise_and_bias_tracks_within_the_pose_noise() {
    let o = run(&circle_scenario());
    eprintln!(
        "position RMS {:.3} mm, max {:.3} mm, predicted {:.3} mm, velocity RMS {:.2} mm/s, attitude max {:.2} mrad, mean NIS {:.2}",
        o.position_rms_m * 1e3,
        o.position_max_m * 1e3,
        o.predicted_rms_m * 1e3,
        o.velocity_rms_mps * 1e3,
        o.attitude_max_rad * 1e3,
        o.mean_nis
    );
    assert!(o.position_rms_m < 0.002, "RMS {} m", o.position_rms_m);
    assert!(o.position_max_m < 0.0104, "max {} m", o.position_max_m);
    assert!(
        o.position_rms_m < 2.0 * o.predicted_rms_m && o.predicted_rms_m < 2.0 * o.position_rms_m,
        "RMS {} m against predicted {} m",
        o.position_rms_m,
        o.predicted_rms_m
    );
    assert!((3.0..12.0).contains(&o.mean_nis), "mean NIS {}", o.mean_nis);
    assert!(
        o.velocity_rms_mps < 0.02,
        "velocity RMS {}",
        o.velocity_rms_mps
    );
    assert!(
        o.attitude_max_rad < 0.005,
        "attitude {}",
        o.attitude_max_rad
    );
}

/// The same flight: the biases converge to the injected ones (the IMU's at the end, after
/// their slow random walk). Tolerances: 0.01 m/s² (the injected ones are 0.05–0.12 m/s²)
/// and 0.5 mrad/s (injected 3–6 mrad/s), and within 4 of the filter's own deviations.
#[test]
fn circle_biases_converge_to_the_injected_values() {
    let o = run(&circle_scenario());
    let (ba, bg) = o.estimator.biases().unwrap();
    let sd = o.estimator.std_devs().unwrap();
    let (true_ba, true_bg) = o.true_biases;
    eprintln!(
        "accel bias {ba:?} (true {true_ba:?}, σ {:?}); gyro bias {bg:?} (true {true_bg:?}, σ {:?})",
        sd.accel_bias_mps2, sd.gyro_bias_radps
    );
    for i in 0..3 {
        let ea = (ba[i] - true_ba[i]).abs();
        let eg = (bg[i] - true_bg[i]).abs();
        assert!(ea < 0.01, "accel bias axis {i}: error {ea}");
        assert!(
            ea < 4.0 * sd.accel_bias_mps2[i],
            "accel bias axis {i}: error {ea}"
        );
        assert!(eg < 5e-4, "gyro bias axis {i}: error {eg}");
        assert!(
            eg < 4.0 * sd.gyro_bias_radps[i],
            "gyro bias axis {i}: error {eg}"
        );
    }
}

/// 20 ms latency at 1.6 m/s is 32 mm of travel. Fused at its capture time, a pose is worth
/// more than the same pose taken as current: the RMS position error must be at least three
/// times smaller.
#[test]
fn delayed_pose_fused_at_capture_time_beats_taking_it_as_current() {
    let proper = run(&circle_scenario());
    let naive = run(&Scenario {
        stamp: Stamp::Arrival,
        ..circle_scenario()
    });
    eprintln!(
        "position RMS: at capture time {:.3} mm, as current {:.3} mm",
        proper.position_rms_m * 1e3,
        naive.position_rms_m * 1e3
    );
    assert!(
        3.0 * proper.position_rms_m < naive.position_rms_m,
        "{} m vs {} m",
        proper.position_rms_m,
        naive.position_rms_m
    );
    assert!(proper.estimator.diagnostics().fused_delayed > 0);
    assert_eq!(naive.estimator.diagnostics().fused_delayed, 0);
}

/// A perfect IMU at rest, no measurement at all: the integration must cancel gravity exactly
/// (f = Rᵀ g e_z at any attitude), so the state does not move (1e-9 m after 10 s).
#[test]
fn ideal_imu_at_rest_does_not_drift() {
    for roll in [0.0, 0.3] {
        let still = Circle {
            roll_rad: roll,
            ..STILL
        };
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        est.initialize(0.0, &still.state(0.0)).unwrap();
        let dt = 0.005;
        for k in 1..=2000 {
            est.predict(&still.imu(f64::from(k) * dt, dt)).unwrap();
        }
        let s = est.state().unwrap();
        assert!((s.position_in_world_m - still.position(0.0)).norm() < 1e-9);
        assert!(s.velocity_in_world_mps.norm() < 1e-9);
        assert!(s.world_from_body.angle_to(&still.attitude(0.0)) < 1e-12);
        assert!(s.angular_velocity_in_body_radps.norm() < 1e-15);
    }
}

/// Standing still with the noisy, biased IMU and the pose sensor for 40 s: after the bias
/// transient the position error stays under σ_p = 2 mm RMS and the velocity under 5 mm/s
/// RMS — the noise, no drift.
#[test]
fn standing_still_the_estimate_stays_within_the_noise() {
    let o = run(&Scenario {
        trajectory: STILL,
        ..circle_scenario()
    });
    eprintln!(
        "still: position RMS {:.3} mm, velocity RMS {:.3} mm/s",
        o.position_rms_m * 1e3,
        o.velocity_rms_mps * 1e3
    );
    assert!(o.position_rms_m < 0.002, "{}", o.position_rms_m);
    assert!(o.velocity_rms_mps < 0.005, "{}", o.velocity_rms_mps);
    // Standing still, the accelerometer bias is the offset of the specific force from g.
    let (ba, _) = o.estimator.biases().unwrap();
    assert!((ba - o.true_biases.0).norm() < 0.01, "{ba:?}");
}

#[test]
fn same_seed_same_bits() {
    let a = run(&circle_scenario());
    let b = run(&circle_scenario());
    let (sa, sb) = (a.estimator.state().unwrap(), b.estimator.state().unwrap());
    for (x, y) in sa
        .position_in_world_m
        .iter()
        .chain(sa.velocity_in_world_mps.iter())
        .zip(
            sb.position_in_world_m
                .iter()
                .chain(sb.velocity_in_world_mps.iter()),
        )
    {
        assert_eq!(x.to_bits(), y.to_bits());
    }
    assert_eq!(a.position_rms_m.to_bits(), b.position_rms_m.to_bits());
}

fn pose_at(t: f64, p: Vector3<f64>) -> Measurement {
    Measurement::Pose(PoseMeasurement {
        time_s: t,
        position_in_world_m: p,
        world_from_body: UnitQuaternion::identity(),
        position_std_m: 0.01,
        attitude_std_rad: 0.01,
    })
}

fn level_imu(t: f64) -> ImuSample {
    ImuSample {
        time_s: t,
        specific_force_in_body_mps2: Vector3::new(0.0, 0.0, GRAVITY_MPS2),
        angular_velocity_in_body_radps: Vector3::zeros(),
    }
}

#[test]
fn rejected_inputs_say_why_and_change_nothing() {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    assert_eq!(
        est.predict(&level_imu(0.01)),
        Err(Rejection::NotInitialized)
    );
    assert_eq!(
        est.correct(&pose_at(0.0, Vector3::new(0.0, 0.0, 1.0))),
        Ok(Accepted::Initialized)
    );
    for k in 1..=100 {
        est.predict(&level_imu(f64::from(k) * 0.01)).unwrap();
    }
    let before = est.state().unwrap();

    let mut nan_imu = level_imu(1.01);
    nan_imu.specific_force_in_body_mps2.y = f64::NAN;
    assert_eq!(
        est.predict(&nan_imu),
        Err(Rejection::NonFinite {
            field: "imu.specific_force_in_body_mps2"
        })
    );
    assert!(matches!(
        est.predict(&level_imu(0.5)),
        Err(Rejection::OutOfOrder { .. })
    ));
    assert!(matches!(
        est.predict(&level_imu(1.0)),
        Err(Rejection::OutOfOrder { .. })
    ));
    assert_eq!(
        est.correct(&pose_at(0.9, Vector3::new(f64::INFINITY, 0.0, 1.0))),
        Err(Rejection::NonFinite {
            field: "pose.position_in_world_m"
        })
    );
    let Measurement::Pose(mut zero_std) = pose_at(0.9, Vector3::new(0.0, 0.0, 1.0)) else {
        unreachable!()
    };
    zero_std.position_std_m = 0.0;
    assert_eq!(
        est.correct(&Measurement::Pose(zero_std)),
        Err(Rejection::NonFinite {
            field: "pose.position_std_m"
        })
    );
    // The default history is 0.5 s: a pose from 0.2 s is too old at t = 1 s.
    assert_eq!(
        est.correct(&pose_at(0.2, Vector3::new(0.0, 0.0, 1.0))),
        Err(Rejection::TooOld {
            time_s: 0.2,
            oldest_s: 0.5
        })
    );
    assert_eq!(est.state().unwrap(), before);
    assert_eq!(
        est.diagnostics().rejected,
        7,
        "the six above and the IMU before initialisation"
    );

    // A pose at 0.9 s is fused; one at 0.8 s is then out of order.
    assert!(matches!(
        est.correct(&pose_at(0.9, Vector3::new(0.0, 0.0, 1.0))),
        Ok(Accepted::Fused(_))
    ));
    assert_eq!(
        est.correct(&pose_at(0.8, Vector3::new(0.0, 0.0, 1.0))),
        Err(Rejection::OutOfOrder {
            time_s: 0.8,
            latest_s: 0.9
        })
    );
    let r = est.diagnostics().last_rejection.unwrap();
    assert_eq!(
        r.to_string(),
        "out of order: t = 0.8 s is before t = 0.9 s, already used"
    );
}

#[test]
fn gate_rejects_an_outlier() {
    let mut est = Estimator::new(EstimatorConfig {
        innovation_gate_nis: Some(22.5),
        ..EstimatorConfig::default()
    })
    .unwrap();
    est.correct(&pose_at(0.0, Vector3::new(0.0, 0.0, 1.0)))
        .unwrap();
    for k in 1..=100 {
        let t = f64::from(k) * 0.01;
        est.predict(&level_imu(t)).unwrap();
        est.correct(&pose_at(t, Vector3::new(0.0, 0.0, 1.0)))
            .unwrap();
    }
    // 1 m off with σ = 1 cm: NIS ~ 10⁴.
    assert!(matches!(
        est.correct(&pose_at(1.0, Vector3::new(1.0, 0.0, 1.0))),
        Err(Rejection::Gated { nis, .. }) if nis > 1e3
    ));
}

/// A pose captured after the newest IMU sample waits, and is fused when the IMU passes it.
#[test]
fn pose_ahead_of_the_imu_waits_for_it() {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    est.correct(&pose_at(0.0, Vector3::new(0.0, 0.0, 1.0)))
        .unwrap();
    est.predict(&level_imu(0.01)).unwrap();
    assert_eq!(
        est.correct(&pose_at(0.015, Vector3::new(0.01, 0.0, 1.0))),
        Ok(Accepted::Deferred)
    );
    assert_eq!(est.pending(), 1);
    assert_eq!(
        est.predict(&level_imu(0.02)),
        Ok(Accepted::Propagated {
            fused: 1,
            rejected: 0
        })
    );
    assert_eq!(est.pending(), 0);
    let innovation = est.diagnostics().last_innovation.unwrap();
    assert_eq!(innovation.time_s, 0.015);
    assert!((innovation.delay_s - 0.005).abs() < 1e-12);
    // Pulled towards +x by the measurement.
    assert!(est.state().unwrap().position_in_world_m.x > 0.0);
    let full = EstimatorConfig {
        max_pending: 1,
        ..EstimatorConfig::default()
    };
    let mut est = Estimator::new(full).unwrap();
    est.correct(&pose_at(0.0, Vector3::new(0.0, 0.0, 1.0)))
        .unwrap();
    est.correct(&pose_at(0.01, Vector3::new(0.0, 0.0, 1.0)))
        .unwrap();
    assert_eq!(
        est.correct(&pose_at(0.02, Vector3::new(0.0, 0.0, 1.0))),
        Err(Rejection::QueueFull { pending: 1 })
    );
}

/// A delayed measurement, fused into the history, gives the same estimate as the same
/// measurement fed in time (to rounding): the re-integration replays the same samples.
#[test]
fn late_fusion_equals_timely_fusion() {
    let run = |late: bool| {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        est.initialize(0.0, &CIRCLE.state(0.0)).unwrap();
        let dt = 0.005;
        let m = Measurement::Odometry(OdometryMeasurement {
            pose: PoseMeasurement {
                time_s: 0.05,
                position_in_world_m: CIRCLE.position(0.05) + Vector3::new(0.01, 0.0, 0.0),
                world_from_body: CIRCLE.attitude(0.05),
                position_std_m: 0.005,
                attitude_std_rad: 0.01,
            },
            velocity_in_world_mps: CIRCLE.velocity(0.05),
            velocity_std_mps: 0.05,
        });
        for k in 1..=20 {
            let t = f64::from(k) * dt;
            est.predict(&CIRCLE.imu(t, dt)).unwrap();
            if k == 10 && !late {
                est.correct(&m).unwrap();
            }
        }
        if late {
            assert!(
                matches!(est.correct(&m), Ok(Accepted::Fused(i)) if i.dof == 9 && (i.delay_s - 0.05).abs() < 1e-12)
            );
        }
        est.state().unwrap()
    };
    let (a, b) = (run(false), run(true));
    assert!((a.position_in_world_m - b.position_in_world_m).norm() < 1e-12);
    assert!((a.velocity_in_world_mps - b.velocity_in_world_mps).norm() < 1e-12);
    // And the measurement moved it (it was 1 cm off).
    assert!((a.position_in_world_m - CIRCLE.position(0.1)).x > 1e-4);
}

#[test]
fn bad_configurations_name_the_field() {
    let e = EstimatorConfig {
        history_s: 0.0,
        ..EstimatorConfig::default()
    }
    .validate()
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "estimator.history_s = 0: must be finite and positive"
    );
    assert!(
        Estimator::new(EstimatorConfig {
            gyro_noise_radps_per_sqrt_hz: f64::NAN,
            ..EstimatorConfig::default()
        })
        .is_err()
    );
    let e = PoseModel {
        latency_s: -0.01,
        ..PoseModel::default()
    }
    .validate()
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "pose.latency_s = -0.01: must be finite and not negative"
    );
    assert!(
        ImuModel {
            rate_hz: 0.0,
            ..ImuModel::default()
        }
        .validate()
        .is_err()
    );
    EstimatorConfig::default().validate().unwrap();
    ImuModel::default().validate().unwrap();
    PoseModel::default().validate().unwrap();
}

/// The sensor models' statistics: an IMU sample's noise has σ = density·√rate, the pose
/// sensor keeps its schedule and latency.
#[test]
fn sensor_models_have_their_stated_statistics() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let model = ImuModel {
        rate_hz: 400.0,
        accel_bias_walk_mps3_per_sqrt_hz: 0.0,
        gyro_bias_walk_radps2_per_sqrt_hz: 0.0,
        ..ImuModel::default()
    };
    let mut imu =
        ImuSensor::with_biases(model, Vector3::new(0.1, 0.0, 0.0), Vector3::zeros()).unwrap();
    let n = 20_000;
    let (mut sum, mut sum2) = (0.0, 0.0);
    for k in 0..n {
        let s = imu.measure(&level_imu(f64::from(k) / 400.0), &mut rng);
        let x = s.specific_force_in_body_mps2.x;
        sum += x;
        sum2 += x * x;
    }
    let mean = sum / f64::from(n);
    let std = (sum2 / f64::from(n) - mean * mean).sqrt();
    let expected = 0.002 * 400.0_f64.sqrt();
    assert!(
        (mean - 0.1).abs() < 4.0 * expected / f64::from(n).sqrt(),
        "mean {mean}"
    );
    assert!(
        (std / expected - 1.0).abs() < 0.03,
        "std {std} vs {expected}"
    );

    // 50 Hz capture, 20 ms latency, ticked at 200 Hz: a capture every 4th tick, arriving
    // 4 ticks later, stamped with its capture time.
    let mut pose = PoseSensor::new(PoseModel {
        rate_hz: 50.0,
        latency_s: 0.02,
        ..PoseModel::default()
    })
    .unwrap();
    let mut arrivals = Vec::new();
    for k in 0..40 {
        let t = f64::from(k) * 0.005;
        for m in pose.step(t, &Vector3::zeros(), &UnitQuaternion::identity(), &mut rng) {
            arrivals.push((t, m.time_s));
        }
    }
    assert_eq!(arrivals.len(), 9);
    for (i, (arrived, captured)) in arrivals.iter().enumerate() {
        assert!((captured - i as f64 * 0.02).abs() < 1e-12, "{captured}");
        assert!(
            (arrived - captured - 0.02).abs() < 1e-9,
            "{arrived} {captured}"
        );
    }
}

/// Started from a pose, the estimate knows position and attitude as well as the pose says
/// (σ = 1 cm, 0.01 rad here), velocity and biases as the configuration says; started from
/// odometry, velocity as the odometry says.
#[test]
fn the_first_measurement_sets_what_it_measures_and_its_uncertainty() {
    let config = EstimatorConfig::default();
    let mut est = Estimator::new(config).unwrap();
    assert_eq!(
        est.correct(&pose_at(2.0, Vector3::new(1.0, 2.0, 3.0))),
        Ok(Accepted::Initialized)
    );
    let sd = est.std_devs().unwrap();
    assert_eq!(sd.position_m, Vector3::repeat(0.01));
    assert_eq!(sd.attitude_rad, Vector3::repeat(0.01));
    assert_eq!(
        sd.velocity_mps,
        Vector3::repeat(config.initial_velocity_std_mps)
    );
    assert_eq!(
        sd.accel_bias_mps2,
        Vector3::repeat(config.initial_accel_bias_std_mps2)
    );
    assert_eq!(est.time_s(), Some(2.0));
    assert_eq!(
        est.state().unwrap().position_in_world_m,
        Vector3::new(1.0, 2.0, 3.0)
    );

    let Measurement::Pose(pose) = pose_at(0.0, Vector3::zeros()) else {
        unreachable!()
    };
    let mut est = Estimator::new(config).unwrap();
    est.correct(&Measurement::Odometry(OdometryMeasurement {
        pose,
        velocity_in_world_mps: Vector3::new(0.5, 0.0, 0.0),
        velocity_std_mps: 0.03,
    }))
    .unwrap();
    assert_eq!(est.std_devs().unwrap().velocity_mps, Vector3::repeat(0.03));
    assert_eq!(
        est.state().unwrap().velocity_in_world_mps,
        Vector3::new(0.5, 0.0, 0.0)
    );
}
