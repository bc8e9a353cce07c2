//! Forward kinematics, tool-tip Jacobian and mass properties of each vehicle; its rigid-body
//! dynamics (CRBA mass matrix, RNEA bias forces, forward dynamics through a Cholesky).
//! Run: `cargo bench -p platform --bench kinematics`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{DMatrix, DVector, Isometry3, UnitQuaternion};
use platform::{ArticulatedBody, BUILTIN_IDS, Drive, TreeState, Vehicle};

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
        let tree = ArticulatedBody::new(&v.model);
        let mut ws = tree.workspace();
        let nu = DVector::from_fn(tree.nv(), |i, _| 0.3 - 0.05 * i as f64);
        let tau = DVector::from_fn(tree.nv(), |i, _| 1.0 + 0.1 * i as f64);
        let attitude = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3);
        let mut m = DMatrix::zeros(tree.nv(), tree.nv());
        let mut out = DVector::zeros(tree.nv());
        group.bench_function(format!("{id}/mass_matrix_crba"), |b| {
            b.iter(|| tree.mass_matrix(black_box(&q), &mut ws, &mut m))
        });
        group.bench_function(format!("{id}/bias_rnea"), |b| {
            b.iter(|| tree.bias(&attitude, black_box(&q), &nu, &mut ws, &mut out))
        });
        let drives: Vec<Drive> = v
            .drives
            .iter()
            .filter_map(|d| {
                Some(Drive {
                    dof: v.model.joints[d.joint].dof?,
                    stiffness: d.stiffness,
                    damping: d.damping,
                    target: 0.2,
                    effort_limit: d.effort_limit,
                })
            })
            .collect();
        let start = TreeState {
            world_from_base: Isometry3::translation(0.0, 0.0, 1.0),
            q: q.clone(),
            nu: nu.clone(),
        };
        let mut state = start.clone();
        let zero = DVector::zeros(tree.nv());
        group.bench_function(format!("{id}/step_implicit_drives"), |b| {
            b.iter(|| {
                state.clone_from(&start);
                tree.step(
                    &mut state,
                    &zero,
                    &[],
                    black_box(&drives),
                    1.0 / 480.0,
                    &mut ws,
                )
            })
        });
        group.bench_function(format!("{id}/forward_dynamics"), |b| {
            b.iter(|| {
                tree.forward_dynamics(&attitude, black_box(&q), &nu, &tau, &[], &mut ws, &mut out)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, kinematics);
criterion_main!(benches);
