//! Forward kinematics, tool-tip Jacobian and mass properties of each vehicle.
//! Run: `cargo bench -p platform --bench kinematics`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use platform::{BUILTIN_IDS, Vehicle};

fn kinematics(c: &mut Criterion) {
    let mut group = c.benchmark_group("kinematics");
    group
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2))
        .sample_size(30);
    for id in BUILTIN_IDS {
        let Ok(v) = Vehicle::builtin(id) else {
            continue;
        };
        // A configuration away from zero so no rotation is trivially the identity.
        let q: Vec<f64> = (0..v.model.dof()).map(|i| 0.1 + 0.05 * i as f64).collect();
        let mut poses = Vec::new();
        group.bench_function(format!("{id}/fk_all_links"), |b| {
            b.iter(|| v.model.forward_kinematics_into(black_box(&q), &mut poses))
        });
        group.bench_function(format!("{id}/fk_tool_tip"), |b| {
            b.iter(|| v.tool_tip_in_base(black_box(&q)))
        });
        group.bench_function(format!("{id}/fk_and_jacobian_tool_tip"), |b| {
            b.iter(|| {
                (
                    v.tool_tip_in_base(black_box(&q)),
                    v.tool_tip_jacobian(black_box(&q)),
                )
            })
        });
        group.bench_function(format!("{id}/mass_properties"), |b| {
            b.iter(|| v.mass_properties(black_box(&q)))
        });
    }
    group.finish();
}

criterion_group!(benches, kinematics);
criterion_main!(benches);
