//! Update time of each base controller at 120 Hz on a moving target.
//! Run: `cargo bench -p controllers --bench controllers`.

use std::hint::black_box;
use std::time::Duration;

use controllers::{
    BaseController, BodyParams, L1Adaptive, L1Config, Pid4, Pid4Gains, Pid6, Pid6Gains,
};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use platform::{RigidBodyState, Vehicle, Wrench};

const DT: f64 = 1.0 / 120.0;

fn bench_controller(c: &mut Criterion, name: &str, mut controller: Box<dyn BaseController>) {
    let mut state = RigidBodyState::at_rest(Isometry3::translation(0.02, -0.01, 0.98));
    state.velocity_in_world_mps = Vector3::new(0.1, 0.0, -0.05);
    state.angular_velocity_in_body_radps = Vector3::new(0.01, -0.02, 0.1);
    let mut k = 0u64;
    c.bench_function(name, |b| {
        b.iter(|| {
            k += 1;
            let t = k as f64 * DT;
            let target = Isometry3::from_parts(
                Translation3::new(0.1 * t.sin(), 0.0, 1.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2 * t.sin()),
            );
            let w = controller.update(black_box(&state), black_box(&target), DT);
            controller.saturation_feedback(&Wrench::ZERO);
            w
        })
    });
}

fn controllers(c: &mut Criterion) {
    let (Ok(fa), Ok(quad)) = (Vehicle::builtin("fa-hexa"), Vehicle::builtin("ua-quad")) else {
        return;
    };
    let fa_body = BodyParams::from_vehicle(&fa);
    let quad_body = BodyParams::from_vehicle(&quad);
    bench_controller(
        c,
        "pid6_update/fa-hexa",
        Box::new(Pid6::new(Pid6Gains::am_bench(), fa_body)),
    );
    bench_controller(
        c,
        "pid4_update/ua-quad",
        Box::new(Pid4::new(Pid4Gains::ua_quad(), quad_body)),
    );
    bench_controller(
        c,
        "l1_update/fa-hexa",
        Box::new(L1Adaptive::new(L1Config::am_bench(), fa_body)),
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(2)).sample_size(30);
    targets = controllers
}
criterion_main!(benches);
