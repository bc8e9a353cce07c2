//! `amstack mpc-bench`: the solve time of the whole-body MPC, per QP path, on its standard
//! scenario or on a recorded benchmark rollout in contact.
//!
//! - `--scenario standard`: each path flies the scenario of `controllers::mpc::scenario` (the
//!   FA-Hexa tracking a 0.3 m EE step toward a wall, the loop closed on the prediction model)
//!   for `--iterations` control ticks.
//! - `--scenario push-slider|wipe-window`: the command first flies one benchmark rollout of the
//!   task (FA-Hexa, `mpc` controller, in-process twin, default disturbances, `--seed`) and keeps
//!   what every tick's RTI step was given ([`controllers::mpc::MpcProblem`]: the measured
//!   state, the EE target, the last applied input, the base limits, the shift); then each path
//!   replays those problems in order through a fresh solver (open loop: the states are the
//!   rollout's). Regenerated on every run, so the scenario follows the code; deterministic
//!   from the seed.
//!
//! Every RTI step is timed as a whole (preparation: shift, roll-out, linearisation and QP
//! assembly; feedback: the QP solve and the step) and by part.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Result, anyhow};
use clap::Parser;
use comfy_table::{Table, presets};
use controllers::ControllerConfig;
use controllers::mpc::scenario::{self, WallStepScenario};
use controllers::mpc::{
    MpcConfig, MpcMode, MpcProblem, QpPath, QpSettings, QpSolution, QpSolver, QpStatus, RiccatiIpm,
    RowScreening, RtiReport, ScreeningReport, ShotOutcome, SqpRti, StructuredQp,
};
use platform::Vehicle;
use policy_runtime::bench::{RolloutHooks, run_rollout_with};
use policy_runtime::flight::{Decided, FlightError, Observer};
use serde::Serialize;
use sim_twin::TaskId;

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Scenarios:
  standard     FA-Hexa hovering at (0, 0, 1) m steps its end effector 0.3 m along x toward a
               wall at x = 1.15 m (the base may not pass x = 0.3 m); the loop closed on the
               MPC's own model, --iterations ticks.
  push-slider  one benchmark rollout of the task (FA-Hexa, mpc controller, in-process twin,
  wipe-window  default disturbances, --seed) is flown first and every tick's MPC problem kept
               (measured state, EE target, last input, base limits); each path then replays
               them in order (open loop), so the QPs are those of the vehicle in contact.
32 intervals over 0.8 s, 120 Hz. Both QP paths run: riccati (the structure-exploiting
interior point of this crate) and clarabel (the sparse multiple-shooting QP); --paths picks.
--warm-start off starts every QP of the riccati path cold (the replay of a rollout then
solves the same problems as the warm-started rollout did). --infeasibility-exit off runs every
QP to convergence (no early exit on a proven slack above the limit); check solves every QP
again without the exit and counts the ticks classified differently (exit_check in the JSON).
--row-screening off walks every state row at every iteration (on: the rows far from their
bounds are left out, exactly: see controllers::mpc::RowScreening); check also solves every QP
with and without the screening and compares them (screening_check in the JSON).
--state-rows hard removes the state rows' exact-penalty slacks (the QP may be infeasible in
contact) from the rollout and the replay; --replay-state-rows replays the same recorded
problems with the other setting.
Times: the wall time of each RTI step, and the thread's CPU time over it (not inflated by
other processes on a loaded machine). Build with --release for meaningful times.

Examples:
  amstack mpc-bench
  amstack mpc-bench --scenario push-slider --paths riccati --json slider.json
  amstack mpc-bench --scenario wipe-window --paths riccati --warm-start off
  amstack mpc-bench --scenario wipe-window --state-rows hard
  amstack mpc-bench --scenario push-slider --state-rows hard --replay-state-rows soft
  amstack mpc-bench --scenario push-slider --paths riccati --infeasibility-exit check
  amstack mpc-bench --scenario push-slider --paths riccati --row-screening check")]
pub struct Args {
    /// `standard`, `push-slider` or `wipe-window`.
    #[arg(long, default_value = "standard")]
    scenario: String,
    /// Control ticks (RTI steps) per path (standard scenario; a recorded one replays every
    /// tick of its rollout).
    #[arg(long, default_value_t = 600)]
    iterations: usize,
    /// Seed of the recorded rollout (its disturbances and noise), as `amstack bench --seed`.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Comma-separated QP paths: riccati, clarabel.
    #[arg(long, default_value = "riccati,clarabel")]
    paths: String,
    /// A TOML file of `MpcConfig` fields over the FA-Hexa's defaults (as `amstack bench
    /// --mpc-config`), for the scenario and its replay; `--state-rows`, `--penalty` apply
    /// on top of it. E.g. `arm_gain_per_s = 12.0`, the reference's arm servo model.
    #[arg(long, value_name = "FILE.toml")]
    mpc_config: Option<PathBuf>,
    /// `soft` (the config's exact-penalty slacks on the state rows) or `hard` (none).
    #[arg(long, default_value = "soft")]
    state_rows: String,
    /// Recorded scenarios: replay with these state rows (`soft` or `hard`) instead of the
    /// rollout's (`--state-rows`), so both solvers see the same problems.
    #[arg(long, value_name = "ROWS")]
    replay_state_rows: Option<String>,
    /// With soft state rows (rollout or replay): their penalty weight ρ in place of the
    /// config's (`state_row_penalty`).
    #[arg(long, value_name = "RHO")]
    penalty: Option<f64>,
    /// `on` (default, as the controller flies): the Riccati path's interior point starts
    /// from the previous tick's multipliers; `off`: every QP starts cold. Applies to the
    /// standard scenario and to the replay (a recorded rollout is flown as the controller
    /// flies, so `off` replays the same problems cold).
    #[arg(long, default_value = "on", value_name = "on|off")]
    warm_start: String,
    /// The Riccati path's early infeasibility exit (`controllers::mpc::InfeasibilityExit`):
    /// `on` (default, as the controller flies), `off` (every QP runs to convergence), or
    /// `check`: as `on`, and every replayed or flown QP is solved a second time (untimed)
    /// without the exit; the report counts the ticks whose status differs (`exit_check`).
    #[arg(long, default_value = "on", value_name = "on|off|check")]
    infeasibility_exit: String,
    /// The Riccati path's row screening (`controllers::mpc::RowScreening`): `on` (default,
    /// as the controller flies: margin 0.5 m or rad, pause 60), `off` (every state row walked
    /// at every iteration), `MARGIN[:PAUSE]`: the pairs of state rows whose slacks at a QP's
    /// start are both at least the margin are left out of the iteration, the solve is redone
    /// with every row if one of them is violated, and the next PAUSE solves walk every row
    /// (default 60) — or `check`: as `on`, and every QP is also
    /// solved (untimed, cold) by two fresh solvers, screened and unscreened, and compared
    /// (`screening_check`). Applies to the standard scenario and to the replay (a recorded
    /// rollout is flown as the controller flies).
    #[arg(long, default_value = "on", value_name = "on|off|check|MARGIN[:PAUSE]")]
    row_screening: String,
    /// Write the figures as JSON (`paths.<name>.solve_ms_median`, ...).
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

/// The figures of one path. `solve_ms_*`: wall time of an RTI step; `solve_cpu_ms_*`: the
/// thread's CPU time over it (what other processes of a loaded machine do not inflate).
#[derive(Debug, Clone, Serialize)]
struct PathFigures {
    ticks: usize,
    solve_cpu_ms_median: f64,
    solve_cpu_ms_p90: f64,
    solve_cpu_ms_p99: f64,
    solve_cpu_ms_max: f64,
    solve_ms_median: f64,
    solve_ms_p90: f64,
    solve_ms_p99: f64,
    solve_ms_max: f64,
    prepare_ms_median: f64,
    qp_ms_median: f64,
    qp_iterations_median: f64,
    qp_iterations_p90: f64,
    qp_iterations_p99: f64,
    qp_iterations_max: u32,
    qp_iterations_mean: f64,
    /// Ticks per QP status.
    statuses: BTreeMap<String, usize>,
    failed_solves: usize,
    cost_first: f64,
    cost_last: f64,
    max_constraint_violation: f64,
    /// Standard scenario only: EE distance from the goal after the last tick, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    final_ee_error_m: Option<f64>,
    /// Standard scenario only: the base's final x, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    final_base_x_m: Option<f64>,
    /// Recorded scenarios, the rollout's own path: ticks whose replayed status and iteration
    /// count equal the rollout's (the replay poses the same QPs).
    #[serde(skip_serializing_if = "Option::is_none")]
    replay_matches_rollout_ticks: Option<usize>,
    /// `--infeasibility-exit check`: the exit against the converged solves.
    #[serde(skip_serializing_if = "Option::is_none")]
    exit_check: Option<ExitCheck>,
    /// Riccati path: what the row screening did (`--row-screening`).
    #[serde(skip_serializing_if = "Option::is_none")]
    screening: Option<ScreeningFigures>,
    /// `--row-screening check`: screened against unscreened solves of the same QPs.
    #[serde(skip_serializing_if = "Option::is_none")]
    screening_check: Option<ScreeningCheck>,
    /// Riccati path: what the active-set shot did (`[qp] active_set_shot`).
    #[serde(skip_serializing_if = "Option::is_none")]
    active_set_shot: Option<ShotFigures>,
}

/// The Riccati path's active-set shot over a run.
#[derive(Debug, Clone, Default, Serialize)]
struct ShotFigures {
    /// QPs whose solve tried the last solution's active set first.
    tried: usize,
    /// QPs it solved (no interior-point iteration).
    accepted: usize,
}

/// The same QPs solved cold by a screened and an unscreened solver (`--row-screening check`).
#[derive(Debug, Clone, Default, Serialize)]
struct ScreeningCheck {
    /// QPs compared.
    qps: usize,
    /// QPs whose classification (solved, infeasible by the slack limit or the exit, failed)
    /// differs (must be 0).
    disagreements: usize,
    /// QPs both solve: the largest difference of the penalised objectives (absolute, and
    /// relative to max(1, |J|)), and of any entry of the points (x, u).
    solved: usize,
    max_objective_abs_diff: f64,
    max_objective_rel_diff: f64,
    max_point_diff: f64,
    /// The same QPs solved unscreened to a 1000× tighter tolerance (z*): the largest
    /// distance (any entry of x, u) of the screened and of the unscreened solution from it,
    /// and of the objectives, over the QPs all three solve. The screened solve is "equal to
    /// tolerance" when it is no farther from z* than the unscreened one.
    tight_solved: usize,
    screened_point_error: f64,
    unscreened_point_error: f64,
    screened_objective_error: f64,
    unscreened_objective_error: f64,
    /// QPs the screened solver solved again with every row.
    resolved: usize,
}

/// The solvers of `--row-screening check`.
struct ScreeningTwins {
    screened: RiccatiIpm,
    full: RiccatiIpm,
    tight: RiccatiIpm,
    limit: Option<f64>,
    check: ScreeningCheck,
}

impl ScreeningTwins {
    fn new(rti: &SqpRti) -> Self {
        let config = rti.config();
        let make = |screening| {
            let mut ipm = RiccatiIpm::new(config.qp);
            ipm.set_infeasibility_exit(rti.default_qp_infeasibility_exit());
            ipm.set_row_screening(screening);
            ipm
        };
        let mut tight = RiccatiIpm::new(QpSettings {
            tolerance: config.qp.tolerance * 1e-3,
            max_iterations: 100,
            ..config.qp
        });
        tight.set_infeasibility_exit(None);
        Self {
            // Every QP screened (no pause), so every one is compared.
            screened: make(Some(RowScreening {
                pause_after_resolve: 0,
                ..RowScreening::default()
            })),
            full: make(None),
            tight,
            limit: config.state_row_slack_limit,
            check: ScreeningCheck::default(),
        }
    }

    fn push(&mut self, qp: &StructuredQp) {
        let classify = |status: QpStatus, sol: &QpSolution, limit: Option<f64>| {
            if status == QpStatus::Solved
                && let Some(limit) = limit
                && sol.slack.iter().any(|t| *t > limit)
            {
                QpStatus::Infeasible
            } else {
                status
            }
        };
        let mut a = QpSolution::zeros(qp.intervals);
        let mut b = QpSolution::zeros(qp.intervals);
        let sa = classify(self.screened.solve(qp, &mut a), &a, self.limit);
        let sb = classify(self.full.solve(qp, &mut b), &b, self.limit);
        let c = &mut self.check;
        c.qps += 1;
        c.resolved += usize::from(self.screened.screening_report().resolved);
        c.disagreements += usize::from(sa != sb);
        if sa == QpStatus::Solved && sb == QpStatus::Solved {
            c.solved += 1;
            let rho = qp.soft_penalty.unwrap_or(0.0);
            let penalised =
                |s: &QpSolution| qp.objective(&s.x, &s.u) + rho * s.slack.iter().sum::<f64>();
            let (ja, jb) = (penalised(&a), penalised(&b));
            c.max_objective_abs_diff = c.max_objective_abs_diff.max((ja - jb).abs());
            c.max_objective_rel_diff = c
                .max_objective_rel_diff
                .max((ja - jb).abs() / jb.abs().max(1.0));
            let distance = |p: &QpSolution, q: &QpSolution| {
                let dx = p.x.iter().zip(&q.x).map(|(v, w)| (v - w).amax());
                let du = p.u.iter().zip(&q.u).map(|(v, w)| (v - w).amax());
                dx.chain(du).fold(0.0, f64::max)
            };
            c.max_point_diff = c.max_point_diff.max(distance(&a, &b));
            let mut z = QpSolution::zeros(qp.intervals);
            if self.tight.solve(qp, &mut z) == QpStatus::Solved {
                let jz = penalised(&z);
                c.tight_solved += 1;
                c.screened_point_error = c.screened_point_error.max(distance(&a, &z));
                c.unscreened_point_error = c.unscreened_point_error.max(distance(&b, &z));
                c.screened_objective_error = c.screened_objective_error.max((ja - jz).abs());
                c.unscreened_objective_error = c.unscreened_objective_error.max((jb - jz).abs());
            }
        }
    }
}

/// The Riccati path's row screening over a run.
#[derive(Debug, Clone, Default, Serialize)]
struct ScreeningFigures {
    /// One-sided rows of a QP (the largest seen).
    rows_per_qp: usize,
    /// Rows left out of the first solve, mean over the QPs the interior point solved.
    screened_rows_mean: f64,
    /// QPs solved again with every row (a screened row violated at the reduced solution,
    /// or the reduced solve ended without one).
    resolved_qps: usize,
}

/// The early infeasibility exit against the same QPs solved to convergence.
#[derive(Debug, Clone, Default, Serialize)]
struct ExitCheck {
    /// Ticks compared.
    ticks: usize,
    /// Ticks whose status with the exit differs from the converged solve's (must be 0).
    disagreements: usize,
    /// Ticks the exit stopped early (status `infeasible` before convergence).
    exited: usize,
    /// Ticks the converged solve classifies `infeasible`.
    infeasible: usize,
    /// QP iterations with the exit and without it, summed over the `infeasible` ticks.
    iterations_with_exit: u64,
    iterations_converged: u64,
    /// Feasible (`solved`) ticks whose cost or iterations differ between the two solves
    /// (must be 0).
    solved_cost_differences: usize,
    /// How far the QPs are from the slack limit: over the converged `infeasible` ticks the
    /// smallest largest slack, over the `solved` ones the largest (m or rad).
    infeasible_min_slack: Option<f64>,
    solved_max_slack: Option<f64>,
}

impl ExitCheck {
    /// One tick: the reports with and without the exit, and the converged solve's slacks.
    fn push(&mut self, with_exit: &RtiReport, converged: &RtiReport, slack: &[f64]) {
        self.ticks += 1;
        let largest = slack.iter().copied().fold(0.0, f64::max);
        match converged.status {
            QpStatus::Infeasible => {
                self.infeasible_min_slack = Some(
                    self.infeasible_min_slack
                        .map_or(largest, |v| v.min(largest)),
                );
            }
            QpStatus::Solved => {
                self.solved_max_slack =
                    Some(self.solved_max_slack.map_or(largest, |v| v.max(largest)));
            }
            _ => {}
        }
        self.disagreements += usize::from(with_exit.status != converged.status);
        if converged.status == QpStatus::Infeasible {
            self.infeasible += 1;
            self.iterations_with_exit += u64::from(with_exit.qp_iterations);
            self.iterations_converged += u64::from(converged.qp_iterations);
            self.exited += usize::from(
                with_exit.status == QpStatus::Infeasible
                    && with_exit.qp_iterations < converged.qp_iterations,
            );
        }
        if converged.status == QpStatus::Solved
            && (with_exit.cost.to_bits() != converged.cost.to_bits()
                || with_exit.qp_iterations != converged.qp_iterations)
        {
            self.solved_cost_differences += 1;
        }
    }
}

/// `--infeasibility-exit`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ExitMode {
    On,
    Off,
    Check,
}

impl ExitMode {
    fn parse(text: &str) -> Result<Self> {
        match text {
            "on" => Ok(Self::On),
            "off" => Ok(Self::Off),
            "check" => Ok(Self::Check),
            other => Err(bad_input(format!(
                "--infeasibility-exit {other}: not on, off or check"
            ))),
        }
    }

    /// Applies the mode to `rti` (the timed solver).
    fn apply(self, rti: &mut SqpRti) {
        let exit = match self {
            Self::Off => None,
            Self::On | Self::Check => rti.default_qp_infeasibility_exit(),
        };
        rti.set_qp_infeasibility_exit(exit);
    }
}

/// How the Riccati path's solver is set up (`--warm-start`, `--infeasibility-exit`,
/// `--row-screening`).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Modes {
    warm_start: bool,
    exit: ExitMode,
    screening: Option<RowScreening>,
    /// `--row-screening check`.
    screening_check: bool,
}

impl Modes {
    fn apply(self, rti: &mut SqpRti) {
        rti.set_qp_warm_start(self.warm_start);
        self.exit.apply(rti);
        rti.set_qp_row_screening(self.screening);
    }

    /// The untimed twin of `--infeasibility-exit check`: the same, without the exit.
    fn converged(self) -> Self {
        Self {
            exit: ExitMode::Off,
            ..self
        }
    }
}

/// `--row-screening`: `on`, `off`, `check` or a margin.
fn parse_screening(text: &str) -> Result<Option<RowScreening>> {
    match text {
        "on" | "check" => Ok(Some(RowScreening::default())),
        "off" => Ok(None),
        other => {
            let (margin, pause) = other.split_once(':').unwrap_or((other, ""));
            let margin = margin
                .parse::<f64>()
                .ok()
                .filter(|m| m.is_finite() && *m > 0.0);
            let pause = if pause.is_empty() {
                Some(RowScreening::DEFAULT_PAUSE)
            } else {
                pause.parse::<u32>().ok()
            };
            match (margin, pause) {
                (Some(margin), Some(pause_after_resolve)) => Ok(Some(RowScreening {
                    margin,
                    pause_after_resolve,
                })),
                _ => Err(bad_input(format!(
                    "--row-screening {other}: not on, off, check or MARGIN[:PAUSE] (a positive margin in m or rad, a count of solves)"
                ))),
            }
        }
    }
}

/// The recorded rollout a replay comes from.
#[derive(Debug, Clone, Serialize)]
struct RolloutFigures {
    task: &'static str,
    seed: u64,
    success: bool,
    ticks: usize,
    /// Ticks per mode (`mpc`, `hold`, `ik_pid`).
    modes: BTreeMap<String, usize>,
    /// Ticks per QP status in the rollout.
    statuses: BTreeMap<String, usize>,
    env_steps_per_s: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    scenario: String,
    state_rows: String,
    /// `on` or `off` (`--warm-start`).
    warm_start: String,
    /// `on`, `off` or `check` (`--infeasibility-exit`).
    infeasibility_exit: String,
    /// `on`, `off` or a margin (`--row-screening`).
    row_screening: String,
    /// The replay's state rows, when not the rollout's.
    #[serde(skip_serializing_if = "Option::is_none")]
    replay_state_rows: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    standard: Option<Scenario>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rollout: Option<RolloutFigures>,
    iterations: usize,
    build: &'static str,
    /// The version of the Riccati kernels this CPU runs (`avx2` or `baseline`): the same
    /// bits, not the same speed.
    kernels: &'static str,
    paths: BTreeMap<&'static str, PathFigures>,
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

fn name_of<T: Serialize>(v: &T) -> String {
    serde_json::to_value(v)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

/// This thread's CPU time, ms (NaN where the clock is not available).
fn thread_cpu_ms() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID).map_or(f64::NAN, |t| {
        t.tv_sec() as f64 * 1e3 + t.tv_nsec() as f64 * 1e-6
    })
}

/// When an RTI step started: wall clock and thread CPU time.
#[derive(Clone, Copy)]
struct Stamp {
    wall: Instant,
    cpu_ms: f64,
}

impl Stamp {
    fn now() -> Self {
        Self {
            wall: Instant::now(),
            cpu_ms: thread_cpu_ms(),
        }
    }
}

/// Timings and reports of one path over a run, reduced to [`PathFigures`].
#[derive(Default)]
struct Samples {
    cpu: Vec<f64>,
    total: Vec<f64>,
    prepare: Vec<f64>,
    qp: Vec<f64>,
    iterations: Vec<f64>,
    statuses: BTreeMap<String, usize>,
    failed: usize,
    violation: f64,
    cost_first: Option<f64>,
    cost_last: f64,
    /// Riccati path: the row screening's reports.
    screening: Vec<ScreeningReport>,
    /// Riccati path: the active-set shot's outcomes.
    shots: Vec<ShotOutcome>,
}

impl Samples {
    fn push(&mut self, start: Stamp, t1: Instant, end: Stamp, report: &RtiReport) {
        let (t0, t2) = (start.wall, end.wall);
        self.cpu.push(end.cpu_ms - start.cpu_ms);
        self.prepare.push((t1 - t0).as_secs_f64() * 1e3);
        self.qp.push((t2 - t1).as_secs_f64() * 1e3);
        self.total.push((t2 - t0).as_secs_f64() * 1e3);
        self.iterations.push(f64::from(report.qp_iterations));
        *self.statuses.entry(name_of(&report.status)).or_default() += 1;
        self.failed += usize::from(report.status != QpStatus::Solved);
        self.violation = self.violation.max(report.max_constraint_violation);
        self.cost_first.get_or_insert(report.cost);
        self.cost_last = report.cost;
    }

    fn figures(mut self) -> PathFigures {
        let mean = self.iterations.iter().sum::<f64>() / self.iterations.len().max(1) as f64;
        for v in [
            &mut self.cpu,
            &mut self.total,
            &mut self.prepare,
            &mut self.qp,
            &mut self.iterations,
        ] {
            v.sort_by(f64::total_cmp);
        }
        PathFigures {
            ticks: self.total.len(),
            solve_cpu_ms_median: quantile(&self.cpu, 0.5),
            solve_cpu_ms_p90: quantile(&self.cpu, 0.9),
            solve_cpu_ms_p99: quantile(&self.cpu, 0.99),
            solve_cpu_ms_max: self.cpu.last().copied().unwrap_or(f64::NAN),
            solve_ms_median: quantile(&self.total, 0.5),
            solve_ms_p90: quantile(&self.total, 0.9),
            solve_ms_p99: quantile(&self.total, 0.99),
            solve_ms_max: self.total.last().copied().unwrap_or(f64::NAN),
            prepare_ms_median: quantile(&self.prepare, 0.5),
            qp_ms_median: quantile(&self.qp, 0.5),
            qp_iterations_median: quantile(&self.iterations, 0.5),
            qp_iterations_p90: quantile(&self.iterations, 0.9),
            qp_iterations_p99: quantile(&self.iterations, 0.99),
            qp_iterations_max: self.iterations.last().map_or(0, |v| *v as u32),
            qp_iterations_mean: mean,
            statuses: self.statuses,
            failed_solves: self.failed,
            cost_first: self.cost_first.unwrap_or(f64::NAN),
            cost_last: self.cost_last,
            max_constraint_violation: self.violation,
            final_ee_error_m: None,
            final_base_x_m: None,
            replay_matches_rollout_ticks: None,
            exit_check: None,
            screening_check: None,
            screening: (!self.screening.is_empty()).then(|| ScreeningFigures {
                rows_per_qp: self.screening.iter().map(|r| r.rows).max().unwrap_or(0),
                screened_rows_mean: {
                    // Over the QPs the interior point solved (a QP the active-set shot
                    // solved is not screened).
                    let (sum, count) = self
                        .screening
                        .iter()
                        .zip(&self.shots)
                        .filter(|(_, o)| **o != ShotOutcome::Accepted)
                        .fold((0.0, 0usize), |(s, c), (r, _)| {
                            (s + r.screened as f64, c + 1)
                        });
                    sum / count.max(1) as f64
                },
                resolved_qps: self.screening.iter().filter(|r| r.resolved).count(),
            }),
            active_set_shot: (!self.shots.is_empty()).then(|| ShotFigures {
                tried: self
                    .shots
                    .iter()
                    .filter(|o| **o != ShotOutcome::NotTried)
                    .count(),
                accepted: self
                    .shots
                    .iter()
                    .filter(|o| **o == ShotOutcome::Accepted)
                    .count(),
            }),
        }
    }
}

fn fly(
    vehicle: &Vehicle,
    config: MpcConfig,
    path: QpPath,
    iterations: usize,
    modes: Modes,
) -> Result<PathFigures> {
    let mut run = WallStepScenario::new(vehicle, config)?;
    modes.apply(run.rti_mut());
    // `check`: the same scenario flown beside it without the exit (it flies the same ticks
    // as long as both classify alike).
    let mut twin = if modes.exit == ExitMode::Check {
        let mut twin = WallStepScenario::new(vehicle, config)?;
        modes.converged().apply(twin.rti_mut());
        Some(twin)
    } else {
        None
    };
    let mut check = ExitCheck::default();
    let mut twins =
        (modes.screening_check && path == QpPath::Riccati).then(|| ScreeningTwins::new(run.rti()));
    let mut samples = Samples::default();
    for _ in 0..iterations {
        let t0 = Stamp::now();
        run.prepare();
        let t1 = Instant::now();
        let report = run.feedback(path);
        let t2 = Stamp::now();
        samples.push(t0, t1, t2, &report);
        if path == QpPath::Riccati {
            samples.screening.push(run.rti().qp_screening_report());
            samples.shots.push(run.rti().qp_shot_outcome());
        }
        if let Some(twins) = &mut twins {
            twins.push(run.rti().qp());
        }
        run.advance();
        if let Some(twin) = &mut twin {
            twin.prepare();
            let converged = twin.feedback(path);
            check.push(&report, &converged, &twin.rti().last_qp_solution().slack);
            twin.advance();
        }
    }
    let mut figures = samples.figures();
    if twin.is_some() {
        figures.exit_check = Some(check);
    }
    figures.screening_check = twins.map(|t| t.check);
    figures.final_ee_error_m = Some(run.ee_error_m());
    figures.final_base_x_m = Some(run.state()[0]);
    Ok(figures)
}

/// One tick of a recorded rollout: what the MPC was given and what its step reported.
#[derive(Debug, Clone, Copy)]
struct RecordedTick {
    problem: MpcProblem,
    report: RtiReport,
    mode: MpcMode,
}

/// Keeps every tick's MPC problem of a rollout.
#[derive(Default)]
struct Recorder {
    ticks: Vec<RecordedTick>,
}

impl Observer for Recorder {
    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        if let Some(status) = &tick.record.mpc
            && let (Some(problem), Some(report)) = (status.problem, status.rti)
        {
            self.ticks.push(RecordedTick {
                problem,
                report,
                mode: status.mode,
            });
        }
        Ok(())
    }
}

/// Flies one benchmark rollout of `task` with the MPC and keeps its problems.
fn record(
    task: TaskId,
    seed: u64,
    config: MpcConfig,
) -> Result<(Vec<RecordedTick>, RolloutFigures)> {
    let argv = [
        "amstack",
        "bench",
        "--platform",
        "fa-hexa",
        "--controller",
        "mpc",
        "--task",
        task.name(),
        "--rollouts",
        "1",
        "--jobs",
        "1",
        "--seed",
        &seed.to_string(),
    ];
    let cli = crate::Cli::try_parse_from(argv).map_err(|e| anyhow!("mpc-bench: {e}"))?;
    let crate::Command::Bench(args) = cli.command else {
        return Err(anyhow!(
            "mpc-bench: the benchmark's arguments did not parse"
        ));
    };
    let mut bench = crate::bench::config(&args)?;
    bench.controller = ControllerConfig::Mpc(config);
    let mut recorder = Recorder::default();
    let stop = AtomicBool::new(false);
    let started = Instant::now();
    let result = run_rollout_with(
        &bench,
        task,
        0,
        &stop,
        None,
        RolloutHooks {
            source: None,
            observers: vec![&mut recorder],
        },
    )?;
    let wall = started.elapsed().as_secs_f64();
    let mut modes = BTreeMap::new();
    let mut statuses = BTreeMap::new();
    for t in &recorder.ticks {
        *modes.entry(name_of(&t.mode)).or_default() += 1;
        *statuses.entry(name_of(&t.report.status)).or_default() += 1;
    }
    let figures = RolloutFigures {
        task: task.name(),
        seed: result.seed,
        success: result.success,
        ticks: recorder.ticks.len(),
        modes,
        statuses,
        env_steps_per_s: result.executed_steps as f64 / wall.max(1e-9),
    };
    Ok((recorder.ticks, figures))
}

/// Replays recorded problems in order through a fresh solver on `path`; `as_recorded`: the
/// solver is the rollout's (its reports must be reproduced).
fn replay(
    vehicle: &Vehicle,
    config: MpcConfig,
    path: QpPath,
    ticks: &[RecordedTick],
    as_recorded: bool,
    modes: Modes,
) -> Result<PathFigures> {
    let mut rti = SqpRti::new(vehicle, config)?;
    modes.apply(&mut rti);
    let mut twin = if modes.exit == ExitMode::Check {
        let mut twin = SqpRti::new(vehicle, config)?;
        modes.converged().apply(&mut twin);
        Some(twin)
    } else {
        None
    };
    let mut check = ExitCheck::default();
    let mut twins =
        (modes.screening_check && path == QpPath::Riccati).then(|| ScreeningTwins::new(&rti));
    let mut samples = Samples::default();
    let mut matches = 0;
    for tick in ticks {
        let p = &tick.problem;
        if !p.warm {
            rti.reset();
        }
        rti.set_grasp(p.grasp);
        rti.set_contact(p.contact);
        rti.set_compensated_weight(p.compensated_weight.0, p.compensated_weight.1);
        let t0 = Stamp::now();
        rti.prepare(&p.x_hat, &p.reference, &p.limits, p.elapsed_s);
        let t1 = Instant::now();
        let report = rti.feedback(path);
        let t2 = Stamp::now();
        samples.push(t0, t1, t2, &report);
        if path == QpPath::Riccati {
            samples.screening.push(rti.qp_screening_report());
            samples.shots.push(rti.qp_shot_outcome());
        }
        if let Some(twins) = &mut twins {
            twins.push(rti.qp());
        }
        if let Some(twin) = &mut twin {
            if !p.warm {
                twin.reset();
            }
            twin.set_grasp(p.grasp);
            twin.set_contact(p.contact);
            twin.set_compensated_weight(p.compensated_weight.0, p.compensated_weight.1);
            twin.prepare(&p.x_hat, &p.reference, &p.limits, p.elapsed_s);
            let converged = twin.feedback(path);
            check.push(&report, &converged, &twin.last_qp_solution().slack);
        }
        matches += usize::from(
            report.status == tick.report.status
                && report.qp_iterations == tick.report.qp_iterations,
        );
    }
    let mut figures = samples.figures();
    if twin.is_some() {
        figures.exit_check = Some(check);
    }
    figures.screening_check = twins.map(|t| t.check);
    if as_recorded
        && modes.warm_start
        && modes.exit != ExitMode::Off
        && modes.screening == Some(RowScreening::default())
        && path == config.qp_path
    {
        figures.replay_matches_rollout_ticks = Some(matches);
    }
    Ok(figures)
}

fn parse_paths(text: &str) -> Result<Vec<QpPath>> {
    let mut paths = Vec::new();
    for name in text.split(',').map(str::trim) {
        let path = QpPath::ALL
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| {
                bad_input(format!(
                    "--paths {text}: {name:?} is not riccati or clarabel"
                ))
            })?;
        if !paths.contains(&path) {
            paths.push(path);
        }
    }
    Ok(paths)
}

pub fn run(args: &Args) -> Result<()> {
    if args.iterations == 0 {
        return Err(bad_input("--iterations 0: must be at least 1"));
    }
    let task = match args.scenario.as_str() {
        "standard" => None,
        "push-slider" => Some(TaskId::PushSlider),
        "wipe-window" => Some(TaskId::WipeWindow),
        other => {
            return Err(bad_input(format!(
                "--scenario {other}: not standard, push-slider or wipe-window"
            )));
        }
    };
    let base = match &args.mpc_config {
        None => MpcConfig::fa_hexa(),
        Some(path) => crate::bench::mpc_config(path)?,
    };
    let mut config = base;
    match args.state_rows.as_str() {
        "soft" => {
            if let Some(rho) = args.penalty {
                config.state_row_penalty = Some(rho);
            }
        }
        "hard" if args.penalty.is_some() && args.replay_state_rows.as_deref() != Some("soft") => {
            return Err(bad_input(
                "--penalty: needs --state-rows soft (or --replay-state-rows soft)",
            ));
        }
        "hard" => config.state_row_penalty = None,
        other => {
            return Err(bad_input(format!("--state-rows {other}: not soft or hard")));
        }
    }
    config
        .validate()
        .map_err(|e| bad_input(format!("--penalty: {e}")))?;
    let replay_config = match args.replay_state_rows.as_deref() {
        None => config,
        Some("soft") => MpcConfig {
            state_row_penalty: args
                .penalty
                .or(base.state_row_penalty)
                .or(MpcConfig::fa_hexa().state_row_penalty),
            ..config
        },
        Some("hard") => MpcConfig {
            state_row_penalty: None,
            ..config
        },
        Some(other) => {
            return Err(bad_input(format!(
                "--replay-state-rows {other}: not soft or hard"
            )));
        }
    };
    if args.replay_state_rows.is_some() && task.is_none() {
        return Err(bad_input(
            "--replay-state-rows: only with a recorded scenario (push-slider, wipe-window)",
        ));
    }
    let paths_wanted = parse_paths(&args.paths)?;
    let warm_start = match args.warm_start.as_str() {
        "on" => true,
        "off" => false,
        other => {
            return Err(bad_input(format!("--warm-start {other}: not on or off")));
        }
    };
    let exit = ExitMode::parse(&args.infeasibility_exit)?;
    let modes = Modes {
        warm_start,
        exit,
        screening: parse_screening(&args.row_screening)?,
        screening_check: args.row_screening == "check",
    };
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    let vehicle = Vehicle::builtin("fa-hexa").map_err(|e| anyhow!("{e}"))?;
    let mut paths = BTreeMap::new();
    let mut rollout = None;
    match task {
        None => {
            eprintln!(
                "mpc-bench: {} RTI steps per path (FA-Hexa, 0.3 m EE step toward a wall, {} state rows, warm start {})",
                args.iterations, args.state_rows, args.warm_start
            );
            for &path in &paths_wanted {
                paths.insert(
                    path.name(),
                    fly(&vehicle, config, path, args.iterations, modes)?,
                );
            }
        }
        Some(task) => {
            eprintln!(
                "mpc-bench: flying one {} rollout (FA-Hexa, mpc, seed {}, {} state rows) to record its MPC problems",
                task.name(),
                args.seed,
                args.state_rows
            );
            let (ticks, figures) = record(task, args.seed, config)?;
            eprintln!(
                "mpc-bench: {} ticks recorded (success: {}); replaying them per path",
                figures.ticks, figures.success
            );
            for &path in &paths_wanted {
                paths.insert(
                    path.name(),
                    replay(
                        &vehicle,
                        replay_config,
                        path,
                        &ticks,
                        replay_config == config,
                        modes,
                    )?,
                );
            }
            rollout = Some(figures);
        }
    }
    if let Some(r) = &rollout {
        let list = |m: &BTreeMap<String, usize>| {
            m.iter()
                .map(|(k, v)| format!("{k} {v}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        println!(
            "rollout: {} seed {}, {} ticks, success {}, modes: {}; QP statuses: {}",
            r.task,
            r.seed,
            r.ticks,
            r.success,
            list(&r.modes),
            list(&r.statuses)
        );
    }
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "path",
        "CPU ms (med/p90/p99/max)",
        "median ms",
        "p90 ms",
        "p99 ms",
        "max ms",
        "prepare ms",
        "QP ms",
        "QP iters (med/p90/p99/max)",
        "not solved",
        "max violation",
    ]);
    for (name, f) in &paths {
        table.add_row([
            (*name).to_owned(),
            format!(
                "{:.3} / {:.3} / {:.3} / {:.3}",
                f.solve_cpu_ms_median, f.solve_cpu_ms_p90, f.solve_cpu_ms_p99, f.solve_cpu_ms_max
            ),
            format!("{:.3}", f.solve_ms_median),
            format!("{:.3}", f.solve_ms_p90),
            format!("{:.3}", f.solve_ms_p99),
            format!("{:.3}", f.solve_ms_max),
            format!("{:.3}", f.prepare_ms_median),
            format!("{:.3}", f.qp_ms_median),
            format!(
                "{:.0} / {:.0} / {:.0} / {}",
                f.qp_iterations_median,
                f.qp_iterations_p90,
                f.qp_iterations_p99,
                f.qp_iterations_max
            ),
            format!("{} of {}", f.failed_solves, f.ticks),
            format!("{:.2e}", f.max_constraint_violation),
        ]);
    }
    println!("{table}");
    for (name, f) in &paths {
        if let (Some(e), Some(x)) = (f.final_ee_error_m, f.final_base_x_m) {
            println!("{name}: final EE error {:.2} mm, base x {x:.4} m", e * 1e3);
        }
        if let Some(c) = &f.exit_check {
            println!(
                "{name}: infeasibility exit against the converged solves: {} disagreements in {} ticks; {} of {} infeasible QPs stopped early ({} iterations against {}); {} solved QPs changed; converged largest slack: infeasible QPs >= {:.3e}, solved QPs <= {:.3e}",
                c.disagreements,
                c.ticks,
                c.exited,
                c.infeasible,
                c.iterations_with_exit,
                c.iterations_converged,
                c.solved_cost_differences,
                c.infeasible_min_slack.unwrap_or(f64::NAN),
                c.solved_max_slack.unwrap_or(f64::NAN)
            );
        }
        if let Some(r) = &f.screening {
            println!(
                "{name}: row screening {}: {:.0} of {} rows left out per interior-point QP (mean); {} of {} QPs solved again with every row",
                args.row_screening, r.screened_rows_mean, r.rows_per_qp, r.resolved_qps, f.ticks
            );
        }
        if let Some(r) = &f.active_set_shot {
            println!(
                "{name}: active-set shot: {} of {} QPs tried, {} solved by it (no interior-point iteration)",
                r.tried, f.ticks, r.accepted
            );
        }
        if *name == "riccati" {
            println!(
                "{name}: kernels: {} (this CPU's version of the interior point's kernels; the same bits on every version)",
                controllers::mpc::kernel_target()
            );
        }
        if let Some(c) = &f.screening_check {
            println!(
                "{name}: row screening against unscreened solves of the same QPs (cold): {} disagreements in {} QPs; {} solved by both: objectives within {:.1e} ({:.1e} relative), points within {:.1e}; {} solved again with every row; against the tight solve (tolerance x 1e-3, {} QPs): screened point within {:.1e}, objective {:.1e}; unscreened point within {:.1e}, objective {:.1e}",
                c.disagreements,
                c.qps,
                c.solved,
                c.max_objective_abs_diff,
                c.max_objective_rel_diff,
                c.max_point_diff,
                c.resolved,
                c.tight_solved,
                c.screened_point_error,
                c.screened_objective_error,
                c.unscreened_point_error,
                c.unscreened_objective_error
            );
        }
        if let Some(m) = f.replay_matches_rollout_ticks {
            println!(
                "{name}: the replay reproduced the rollout's QP status and iterations on {m} of {} ticks",
                f.ticks
            );
        }
    }
    if let Some(path) = &args.json {
        let report = Report {
            scenario: args.scenario.clone(),
            state_rows: args.state_rows.clone(),
            warm_start: args.warm_start.clone(),
            infeasibility_exit: args.infeasibility_exit.clone(),
            row_screening: args.row_screening.clone(),
            replay_state_rows: args.replay_state_rows.clone(),
            standard: task.is_none().then_some(Scenario {
                vehicle: "fa-hexa",
                ee_step_m: scenario::STEP_M,
                wall_face_x_m: scenario::WALL_FACE_X_M,
                base_max_x_m: scenario::WALL_FACE_X_M - scenario::WALL_MARGIN_M,
                horizon_s: config.horizon_s,
                intervals: config.intervals,
                rate_hz: scenario::RATE_HZ,
            }),
            rollout,
            iterations: args.iterations,
            build: if cfg!(debug_assertions) {
                "debug"
            } else {
                "release"
            },
            kernels: controllers::mpc::kernel_target(),
            paths,
        };
        write_json(path, &serde_json::to_value(&report)?)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
