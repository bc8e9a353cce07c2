//! Whole-body MPC: one RTI step (preparation + QP + step) per QP path, on the standard scenario
//! (`controllers::mpc::scenario`, FA-Hexa EE step toward a wall), the loop closed on the model.
//! `amstack mpc-bench` reports the per-step distribution; this measures the mean under
//! criterion (`riccati_cold_start`: the Riccati path without its warm start).
//!
//! `mpc_infeasible_qp`: one Riccati solve of a QP whose hard rows are infeasible (the standard
//! scenario's first QP with the base at 2.5 m/s toward the wall 0.3 m ahead, what contact
//! poses), with the early infeasibility exit (`exit`) and run to convergence (`converged`).

use controllers::mpc::model::IX_V;
use controllers::mpc::scenario::WallStepScenario;
use controllers::mpc::{
    InfeasibilityExit, MpcConfig, QpPath, QpSolution, QpSolver, QpStatus, RiccatiIpm,
};
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

fn infeasible_qp(c: &mut Criterion) {
    let vehicle = match Vehicle::builtin("fa-hexa") {
        Ok(v) => v,
        Err(e) => panic!("fa-hexa: {e}"),
    };
    let config = MpcConfig::fa_hexa();
    let mut run = match WallStepScenario::new(&vehicle, config) {
        Ok(s) => s,
        Err(e) => panic!("mpc: {e}"),
    };
    run.prepare();
    let mut qp = run.rti().qp().clone();
    qp.x0[IX_V] = 2.5;
    let limit = config.state_row_slack_limit.unwrap_or(1e-3);
    let mut group = c.benchmark_group("mpc_infeasible_qp");
    for (name, exit) in [
        ("exit", Some(InfeasibilityExit::new(limit))),
        ("converged", None),
    ] {
        let mut solver = RiccatiIpm::new(config.qp);
        solver.set_infeasibility_exit(exit);
        let mut out = QpSolution::zeros(qp.intervals);
        // Both classify it alike: `infeasible` (exit) or a slack above the limit.
        let status = solver.solve(&qp, &mut out);
        let infeasible = status == QpStatus::Infeasible
            || (status == QpStatus::Solved && out.slack.iter().any(|t| *t > limit));
        assert!(infeasible, "{name}: {status:?}");
        group.bench_function(name, |b| b.iter(|| solver.solve(&qp, &mut out)));
    }
    group.finish();
}

criterion_group!(benches, rti_step, infeasible_qp);
criterion_main!(benches);
