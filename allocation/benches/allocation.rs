//! Speed of one allocation per method and vehicle, and of one rotor actuator step.
//!
//! `cargo bench -p allocation`. Each measurement is one `allocate_into` on a reused buffer
//! (the flight-loop path), so the figures are per control tick.

#![allow(
    clippy::unwrap_used,
    reason = "benchmark set-up: a failure is a bug to see at once"
)]

#[path = "../tests/fixtures/mod.rs"]
mod fixtures;

use std::hint::black_box;
use std::time::Duration;

use allocation::{
    AllocationMethod, AllocationStatus, Allocator, ConstrainedSettings, RotorActuator,
    RotorActuatorConfig,
};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use platform::{Actuation, RotorLayout, Wrench};

fn bench_allocation(
    c: &mut Criterion,
    name: &str,
    layout: &RotorLayout,
    actuation: Actuation,
    method: AllocationMethod,
    wrench: Wrench,
    expect_qp: bool,
) {
    let mut allocator = Allocator::new(layout, actuation, method).unwrap();
    let mut out = allocator.new_allocation();
    let measured = vec![0.0; layout.len()];
    allocator
        .allocate_into(&wrench, &measured, &mut out)
        .unwrap();
    // Guard that the case measures the path it is named after.
    let solved = matches!(out.status, AllocationStatus::Solved { .. });
    assert_eq!(solved, expect_qp, "{name}: {:?}", out.status);
    c.bench_function(name, |b| {
        b.iter(|| {
            allocator
                .allocate_into(black_box(&wrench), black_box(&measured), &mut out)
                .unwrap();
            black_box(&out);
        });
    });
}

fn wrench(force: [f64; 3], torque: [f64; 3]) -> Wrench {
    Wrench::new(Vector3::from(force), Vector3::from(torque))
}

fn allocation_methods(c: &mut Criterion) {
    let pinv = AllocationMethod::PseudoInverse;
    let qp = AllocationMethod::Constrained(ConstrainedSettings::default());
    let (fa, ua_hexa, quad, omni) = (
        fixtures::fa_hexa(),
        fixtures::ua_hexa(),
        fixtures::ua_quad(),
        fixtures::omni_hexa(),
    );
    let fa_hover = wrench([2.0, -1.0, 65.0], [0.3, -0.2, 0.1]);
    let fa_over = wrench([20.0, 0.0, 150.0], [3.0, 0.0, 0.0]);
    let quad_hover = wrench([0.0, 0.0, 43.2], [0.2, -0.1, 0.05]);
    let quad_yaw = wrench([0.0, 0.0, 43.2], [0.0, 0.0, 5.0]);
    let ua_hexa_hover = wrench([0.0, 0.0, 65.0], [0.5, 0.3, 0.1]);
    let omni_tilted = wrench([10.0, 5.0, 33.0], [0.2, 0.1, 0.05]);
    let omni_over = wrench([150.0, 0.0, 33.0], [1.0, -0.5, 0.0]);

    use Actuation::{FullyActuated, UnderActuated, VariableTilt};
    bench_allocation(c, "pinv/fa_hexa", &fa, FullyActuated, pinv, fa_hover, false);
    bench_allocation(
        c,
        "pinv/ua_quad_reduced",
        &quad,
        UnderActuated,
        pinv,
        quad_hover,
        false,
    );
    bench_allocation(
        c,
        "pinv/ua_hexa_reduced",
        &ua_hexa,
        UnderActuated,
        pinv,
        ua_hexa_hover,
        false,
    );
    bench_allocation(
        c,
        "pinv/omni_hexa_variable_tilt",
        &omni,
        VariableTilt,
        pinv,
        omni_tilted,
        false,
    );
    bench_allocation(
        c,
        "qp/fa_hexa_feasible",
        &fa,
        FullyActuated,
        qp,
        fa_hover,
        false,
    );
    bench_allocation(
        c,
        "qp/fa_hexa_infeasible",
        &fa,
        FullyActuated,
        qp,
        fa_over,
        true,
    );
    bench_allocation(
        c,
        "qp/ua_quad_yaw_saturated",
        &quad,
        UnderActuated,
        qp,
        quad_yaw,
        true,
    );
    let ua_hexa_over = wrench([0.0, 0.0, 200.0], [2.0, 0.0, 0.0]);
    bench_allocation(
        c,
        "qp/ua_hexa_thrust_saturated",
        &ua_hexa,
        UnderActuated,
        qp,
        ua_hexa_over,
        true,
    );
    bench_allocation(
        c,
        "qp/omni_hexa_infeasible",
        &omni,
        VariableTilt,
        qp,
        omni_over,
        true,
    );
}

fn rotor_actuator(c: &mut Criterion) {
    let config = RotorActuatorConfig {
        time_constant_s: Some(0.05),
        speed_rate_limit_per_s: Some(5.0),
        ..RotorActuatorConfig::default()
    };
    let mut actuator = RotorActuator::new(config, 6).unwrap();
    let mut k = 0u32;
    c.bench_function("rotor_actuator/step_6_rotors", |b| {
        b.iter(|| {
            k = k.wrapping_add(1);
            let level = f64::from(k % 23);
            let commands = [level, 23.0 - level, 11.0, 12.0, level, 5.0];
            black_box(actuator.step(black_box(&commands), 1.0 / 120.0).unwrap());
        });
    });
}

fn config() -> Criterion {
    Criterion::default()
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_secs(1))
        .sample_size(30)
}

criterion_group! {
    name = benches;
    config = config();
    targets = allocation_methods, rotor_actuator
}
criterion_main!(benches);
