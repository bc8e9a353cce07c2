//! Whole-body MPC: one RTI step (preparation + QP + step) per QP path, on the standard scenario
//! (`controllers::mpc::scenario`, FA-Hexa EE step toward a wall), the loop closed on the model.
//! `amstack mpc-bench` reports the per-step distribution; this measures the mean under
//! criterion (`riccati_cold_start`: the Riccati path without its warm start).

use controllers::mpc::scenario::WallStepScenario;
use controllers::mpc::{MpcConfig, QpPath};
use criterion::{Criterion, criterion_group, criterion_main};
use platform::Vehicle;

/// Ticks after which the scenario restarts (the step has settled by then).
const TICKS: usize = 360;

fn rti_step(c: &mut Criterion) {
    let vehicle = match Vehicle::builtin("fa-hexa") {
        Ok(v) => v,
        Err(e) => panic!("fa-hexa: {e}"),
    };
    let mut group = c.benchmark_group("mpc_rti_step");
    // Each path as the controller flies it, and the Riccati path with every QP started cold.
    let variants = QpPath::ALL
        .into_iter()
        .map(|p| (p, true, p.name().to_owned()))
        .chain([(QpPath::Riccati, false, "riccati_cold_start".to_owned())]);
    for (path, warm_start, name) in variants {
        let new = || match WallStepScenario::new(&vehicle, MpcConfig::fa_hexa()) {
            Ok(mut s) => {
                s.rti_mut().set_qp_warm_start(warm_start);
                s
            }
            Err(e) => panic!("mpc: {e}"),
        };
        let mut run = new();
        let mut ticks = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                if ticks == TICKS {
                    run = new();
                    ticks = 0;
                }
                run.prepare();
                let report = run.feedback(path);
                run.advance();
                ticks += 1;
                report
            });
        });
    }
    group.finish();
}

criterion_group!(benches, rti_step);
criterion_main!(benches);
