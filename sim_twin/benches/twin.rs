//! Twin throughput: control ticks per second of `Twin::step`, single thread, FA-Hexa
//! hovering at 1 m with every disturbance on (ground and near-wall ray casts against a wall
//! 0.8 m away), at each (physics substeps per 120 Hz tick, solver iterations per substep)
//! pair of the study of docs/speed.md: 4x4 (the default), then the cheaper ones. rapier
//! rebuilds the vehicle's mass matrix at every solver iteration of every substep, so the cost
//! follows the product; last, the vehicle stepped by amstack's own articulated dynamics
//! (`VehicleDynamics::Articulated`, 4 substeps). A PID6 and the allocator close the loop
//! outside the timed part.
//! Run: `cargo bench -p sim_twin --bench twin` (one pair: `... -- 2x2`).

use std::time::{Duration, Instant};

use allocation::{AllocationMethod, Allocator};
use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Vector3};
use platform::{ActuatorCommand, Vehicle};
use sim_twin::{Disturbances, Twin, TwinConfig, VehicleDynamics};

fn twin_step(c: &mut Criterion) {
    for (substeps, iterations) in [(4, 4), (1, 4), (4, 1), (2, 2), (2, 1), (1, 2), (1, 1)] {
        twin_step_at(c, substeps, iterations, VehicleDynamics::Rapier);
    }
    // The vehicle stepped by amstack's own articulated dynamics, 4 substeps of 4 steps (the
    // default), then 2 and 1 steps per substep (docs/speed.md: the fidelity each costs).
    for own_steps in [4, 2, 1] {
        twin_step_at(c, 4, own_steps, VehicleDynamics::Articulated);
    }
}

fn twin_step_at(
    c: &mut Criterion,
    physics_substeps: u32,
    solver_iterations: u32,
    vehicle_dynamics: VehicleDynamics,
) {
    let Ok(vehicle) = Vehicle::builtin("fa-hexa") else {
        return;
    };
    let articulated = vehicle_dynamics == VehicleDynamics::Articulated;
    // On the vehicle's own dynamics the second count is its steps per substep; rapier keeps
    // its default iterations there.
    let config = TwinConfig {
        disturbances: Disturbances::all(),
        physics_substeps,
        solver_iterations: if articulated { 4 } else { solver_iterations },
        own_dynamics_steps: articulated.then_some(solver_iterations),
        vehicle_dynamics,
        ..TwinConfig::default()
    };
    let make = || -> Option<Twin> {
        let mut t = Twin::new(vehicle.clone(), config.clone()).ok()?;
        t.add_fixed_box(
            &Isometry3::translation(0.8 + 0.05, 0.0, 1.0),
            &Vector3::new(0.05, 3.0, 3.0),
        );
        Some(t)
    };
    let Some(mut twin) = make() else { return };
    let Ok(mut allocator) = Allocator::new(
        &vehicle.rotors,
        vehicle.actuation,
        AllocationMethod::PseudoInverse,
    ) else {
        return;
    };
    let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&vehicle));
    let target = Isometry3::translation(0.0, 0.0, 1.0);
    let dt = config.control_dt_s();
    let joints = vehicle.initial_configuration();
    // The default keeps its historical name, so criterion compares it with earlier runs.
    let name = if articulated && solver_iterations == 4 {
        format!("twin_step/fa-hexa_hover_all_disturbances_articulated_{physics_substeps}")
    } else if articulated {
        format!(
            "twin_step/fa-hexa_hover_all_disturbances_articulated_{physics_substeps}x{solver_iterations}"
        )
    } else if (physics_substeps, solver_iterations) == (4, 4) {
        "twin_step/fa-hexa_hover_all_disturbances".to_owned()
    } else {
        format!("twin_step/fa-hexa_hover_all_disturbances_{physics_substeps}x{solver_iterations}")
    };
    c.bench_function(&name, |b| {
        b.iter_custom(|ticks| {
            let mut stepping = Duration::ZERO;
            for k in 0..ticks {
                // Start over every 10 s of flight so the run stays a hover.
                if k % 1200 == 1199
                    && let Some(fresh) = make()
                {
                    twin = fresh;
                    pid.reset(&twin.truth().base);
                }
                let wrench = pid.update(&twin.truth().base, &target, dt);
                let thrusts = allocator
                    .allocate(&wrench, &[])
                    .map(|a| a.thrusts_n)
                    .unwrap_or_default();
                let command = ActuatorCommand {
                    rotor_thrusts_n: thrusts,
                    joint_targets: joints.clone(),
                    direct_wrench_in_body: None,
                };
                let start = Instant::now();
                let _ = twin.step(&command);
                stepping += start.elapsed();
            }
            stepping
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4)).sample_size(20);
    targets = twin_step
}
criterion_main!(benches);
