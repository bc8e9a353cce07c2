//! `amstack mpc-bench`: the solve time of the whole-body MPC on its standard scenario, per QP
//! path.
//!
//! Each path flies the scenario of `controllers::mpc::scenario` (the FA-Hexa tracking a 0.3 m
//! EE step toward a wall, the loop closed on the prediction model) for `--iterations` control
//! ticks. Every RTI step is timed as a whole (preparation: shift, roll-out, linearisation and
//! QP assembly; feedback: the QP solve and the step) and by part.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use comfy_table::{Table, presets};
use controllers::mpc::scenario::{self, WallStepScenario};
use controllers::mpc::{MpcConfig, QpPath, QpStatus};
use platform::Vehicle;
use serde::Serialize;

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};

#[derive(Debug, clap::Args)]
#[command(after_help = "\
The scenario: FA-Hexa hovering at (0, 0, 1) m steps its end effector 0.3 m along x toward a
wall at x = 1.15 m (the base may not pass x = 0.3 m); 32 intervals over 0.8 s, 120 Hz, the
loop closed on the MPC's own model. Both QP paths fly it: riccati (the structure-exploiting
interior point of this crate) and clarabel (the sparse multiple-shooting QP).
Build with --release for meaningful times.")]
pub struct Args {
    /// Control ticks (RTI steps) per path.
    #[arg(long, default_value_t = 600)]
    iterations: usize,
    /// Write the figures as JSON (`paths.<name>.solve_ms_median`, ...).
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

/// The figures of one path.
#[derive(Debug, Clone, Serialize)]
struct PathFigures {
    solve_ms_median: f64,
    solve_ms_p90: f64,
    solve_ms_p99: f64,
    solve_ms_max: f64,
    prepare_ms_median: f64,
    qp_ms_median: f64,
    qp_iterations_median: f64,
    qp_iterations_max: u32,
    failed_solves: usize,
    cost_first: f64,
    cost_last: f64,
    max_constraint_violation: f64,
    final_ee_error_m: f64,
    final_base_x_m: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    scenario: Scenario,
    iterations: usize,
    build: &'static str,
    paths: std::collections::BTreeMap<&'static str, PathFigures>,
}

#[derive(Debug, Serialize)]
struct Scenario {
    vehicle: &'static str,
    ee_step_m: f64,
    wall_face_x_m: f64,
    base_max_x_m: f64,
    horizon_s: f64,
    intervals: usize,
    rate_hz: f64,
}

/// The `q`-quantile of sorted `v` (nearest rank).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

fn fly(vehicle: &Vehicle, path: QpPath, iterations: usize) -> Result<PathFigures> {
    let mut run = WallStepScenario::new(vehicle, MpcConfig::fa_hexa())?;
    let mut total = Vec::with_capacity(iterations);
    let mut prepare = Vec::with_capacity(iterations);
    let mut qp = Vec::with_capacity(iterations);
    let mut qp_iterations = Vec::with_capacity(iterations);
    let mut failed = 0;
    let mut violation: f64 = 0.0;
    let mut cost_first = f64::NAN;
    let mut cost_last = f64::NAN;
    for tick in 0..iterations {
        let t0 = Instant::now();
        run.prepare();
        let t1 = Instant::now();
        let report = run.feedback(path);
        let t2 = Instant::now();
        prepare.push((t1 - t0).as_secs_f64() * 1e3);
        qp.push((t2 - t1).as_secs_f64() * 1e3);
        total.push((t2 - t0).as_secs_f64() * 1e3);
        qp_iterations.push(f64::from(report.qp_iterations));
        failed += usize::from(report.status != QpStatus::Solved);
        violation = violation.max(report.max_constraint_violation);
        if tick == 0 {
            cost_first = report.cost;
        }
        cost_last = report.cost;
        run.advance();
    }
    for v in [&mut total, &mut prepare, &mut qp, &mut qp_iterations] {
        v.sort_by(f64::total_cmp);
    }
    Ok(PathFigures {
        solve_ms_median: quantile(&total, 0.5),
        solve_ms_p90: quantile(&total, 0.9),
        solve_ms_p99: quantile(&total, 0.99),
        solve_ms_max: total.last().copied().unwrap_or(f64::NAN),
        prepare_ms_median: quantile(&prepare, 0.5),
        qp_ms_median: quantile(&qp, 0.5),
        qp_iterations_median: quantile(&qp_iterations, 0.5),
        qp_iterations_max: qp_iterations.last().map_or(0, |v| *v as u32),
        failed_solves: failed,
        cost_first,
        cost_last,
        max_constraint_violation: violation,
        final_ee_error_m: run.ee_error_m(),
        final_base_x_m: run.state()[0],
    })
}

pub fn run(args: &Args) -> Result<()> {
    if args.iterations == 0 {
        return Err(bad_input("--iterations 0: must be at least 1"));
    }
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    let vehicle = Vehicle::builtin("fa-hexa").map_err(|e| anyhow::anyhow!("{e}"))?;
    let config = MpcConfig::fa_hexa();
    eprintln!(
        "mpc-bench: {} RTI steps per path (FA-Hexa, 0.3 m EE step toward a wall)",
        args.iterations
    );
    let mut paths = std::collections::BTreeMap::new();
    for path in QpPath::ALL {
        paths.insert(path.name(), fly(&vehicle, path, args.iterations)?);
    }
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "path",
        "median ms",
        "p90 ms",
        "p99 ms",
        "max ms",
        "prepare ms",
        "QP ms",
        "QP iters (med/max)",
        "failed",
        "max violation",
        "final EE error (mm)",
    ]);
    for (name, f) in &paths {
        table.add_row([
            (*name).to_owned(),
            format!("{:.3}", f.solve_ms_median),
            format!("{:.3}", f.solve_ms_p90),
            format!("{:.3}", f.solve_ms_p99),
            format!("{:.3}", f.solve_ms_max),
            format!("{:.3}", f.prepare_ms_median),
            format!("{:.3}", f.qp_ms_median),
            format!("{:.0} / {}", f.qp_iterations_median, f.qp_iterations_max),
            f.failed_solves.to_string(),
            format!("{:.2e}", f.max_constraint_violation),
            format!("{:.2}", f.final_ee_error_m * 1e3),
        ]);
    }
    println!("{table}");
    if let Some(path) = &args.json {
        let report = Report {
            scenario: Scenario {
                vehicle: "fa-hexa",
                ee_step_m: scenario::STEP_M,
                wall_face_x_m: scenario::WALL_FACE_X_M,
                base_max_x_m: scenario::WALL_FACE_X_M - scenario::WALL_MARGIN_M,
                horizon_s: config.horizon_s,
                intervals: config.intervals,
                rate_hz: scenario::RATE_HZ,
            },
            iterations: args.iterations,
            build: if cfg!(debug_assertions) {
                "debug"
            } else {
                "release"
            },
            paths,
        };
        write_json(path, &serde_json::to_value(&report)?)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
