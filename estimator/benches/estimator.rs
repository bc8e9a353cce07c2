//! Time of one IMU prediction and one pose update of the estimator (with the default
//! 0.5 s history at 200 Hz, the update re-integrating the 4 samples of a 20 ms delay).
//! Run: `cargo bench -p estimator --bench estimator`.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use estimator::{Estimator, EstimatorConfig, ImuSample, Measurement, PoseMeasurement};
use nalgebra::{UnitQuaternion, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState};

const DT: f64 = 0.005;

fn imu(t: f64) -> ImuSample {
    ImuSample {
        time_s: t,
        specific_force_in_body_mps2: Vector3::new(0.1 * t.sin(), 0.05, GRAVITY_MPS2),
        angular_velocity_in_body_radps: Vector3::new(0.01, -0.02, 0.1 * t.cos()),
    }
}

fn warmed_up() -> Option<(Estimator, f64)> {
    let mut est = Estimator::new(EstimatorConfig::default()).ok()?;
    est.initialize(0.0, &RigidBodyState::default()).ok()?;
    let mut t = 0.0;
    for _ in 0..200 {
        t += DT;
        est.predict(&imu(t)).ok()?;
    }
    Some((est, t))
}

fn pose(t: f64) -> Measurement {
    Measurement::Pose(PoseMeasurement {
        time_s: t,
        position_in_world_m: Vector3::new(0.001, -0.002, 0.0),
        world_from_body: UnitQuaternion::from_euler_angles(0.001, 0.0, 0.002),
        position_std_m: 0.002,
        attitude_std_rad: 0.005,
    })
}

fn estimator(c: &mut Criterion) {
    let Some((mut est, mut t)) = warmed_up() else {
        return;
    };
    c.bench_function("predict (one IMU sample)", |b| {
        b.iter(|| {
            t += DT;
            est.predict(black_box(&imu(t)))
        })
    });
    let Some((est, t)) = warmed_up() else {
        return;
    };
    c.bench_function("pose update, current", |b| {
        b.iter_batched_ref(
            || est.clone(),
            |e| e.correct(black_box(&pose(t))),
            criterion::BatchSize::SmallInput,
        )
    });
    c.bench_function("pose update, 20 ms late (4 samples re-integrated)", |b| {
        b.iter_batched_ref(
            || est.clone(),
            |e| e.correct(black_box(&pose(t - 0.02))),
            criterion::BatchSize::SmallInput,
        )
    });
}

criterion_group!(benches, estimator);
criterion_main!(benches);
