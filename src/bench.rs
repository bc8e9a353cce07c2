//! `amstack bench`: the benchmark — tasks × rollouts of the scripted policies on one
//! platform and controller, scored as the paper's tables.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Result;
use comfy_table::{Table, presets};
use controllers::{ControllerKind, profile};
use indicatif::{ProgressBar, ProgressStyle};
use policy_runtime::Interface;
use policy_runtime::bench::Termination;
use policy_runtime::bench::{
    BenchConfig, BenchError, BenchLink, BenchReport, EpisodeLength, RolloutResult, TaskResult,
    run_bench,
};
use policy_runtime::metrics::{Spread, Stats, format_or_na};
use policy_runtime::{IpcLinkConfig, LinkError};
use serde_json::{Value, json};
use sim_twin::TaskId;

use crate::cli_error::bad_input;
use crate::fly::{LinkChoice, link_choice};
use crate::output::{check_writable, write_json};
use crate::policy_flags::PolicyFlags;
use crate::twin_flags::TwinFlags;
use crate::vehicles::find_vehicle;

/// Version of the results JSON layout.
const RESULTS_SCHEMA: u32 = 1;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Tasks: press-button, peg-in-hole, frame-assembly, cabinet-pick-place, lemon-harvesting,
toss-ball, rotate-valve, push-slider, pull-lever, open-door, wipe-window, ndt (or all).

Controllers per platform:
  ee-only                        pid, l1          (end-effector interface only)
  fa-hexa                        ik-pid, ik-l1, mpc (mpc: end-effector interface only)
  ua-hexa, ua-quad, omni-hexa    ik-pid, ik-l1

Each rollout's seed is --seed + its index; same flags, same results, whatever --jobs.
The table shows, per task, the success rate (SR), subtask completion, the errors normalised
by the arm reach and the tilt use as mean +- std over the successful rollouts, and the rotor
saturation rate; N/A where a figure is undefined (no subtasks, no arm reach, no rotors).

Links: by default every rollout runs in a twin of its own in this process (--jobs threads).
With --link ipc:<service> each rollout is a lockstep session of a twin in another process,
one rollout at a time, with the same results bit for bit:
  amstack twin serve --ipc bench --platform ee-only --flight-chooses-episode &
  amstack bench --link ipc:bench --task press-button --rollouts 5

Examples:
  amstack bench --task press-button --rollouts 5
  amstack bench --platform fa-hexa --controller ik-pid --rollouts 30 --out runs/fa-ikpid
  amstack bench --platform fa-hexa --interface joint --task push-slider --json slider.json")]
pub struct Args {
    /// Task name, or `all`.
    #[arg(long, default_value = "all")]
    task: String,
    /// Vehicle id (ee-only, fa-hexa, ua-hexa, ua-quad, omni-hexa, or one added with --vehicle).
    #[arg(long, default_value = "ee-only")]
    platform: String,
    /// Controller [default: pid on ee-only, ik-pid otherwise].
    #[arg(long)]
    controller: Option<String>,
    /// Action interface: ee (end-effector target) or joint (base pose + arm joints, from the
    /// scripted end-effector targets through the whole-body IK).
    #[arg(long, default_value = "ee", value_parser = ["ee", "joint"])]
    interface: String,
    /// Rollouts per task.
    #[arg(long, default_value_t = 10)]
    rollouts: usize,
    /// Episode length: `spec` (the task's), `script` (the task's, or longer where its scripted
    /// policy needs it, as the reference's demonstration recorder runs it: only Wipe Window),
    /// or seconds.
    #[arg(long, value_name = "spec|script|S", default_value = "script")]
    episode_length: String,
    /// Worker threads [default: all cores; 1 over ipc].
    #[arg(long)]
    jobs: Option<usize>,
    /// Where the rollouts run: `twin` (this process) or `ipc:<service>` (the twin of
    /// `amstack twin serve --ipc <service> --flight-chooses-episode`, in lockstep).
    #[arg(long, value_name = "LINK", default_value = "twin")]
    link: String,
    /// How long each answer of the twin may take before the run stops, ms (ipc).
    #[arg(long, value_name = "MS", default_value_t = 50)]
    link_timeout_ms: u64,
    /// How long to wait for the twin to answer each rollout's handshake, ms (ipc).
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    connect_timeout_ms: u64,
    #[command(flatten)]
    twin: TwinFlags,
    #[command(flatten)]
    state: crate::track::StateFlags,
    #[command(flatten)]
    policy: PolicyFlags,
    #[command(flatten)]
    cameras: crate::camera_flags::CameraFlags,
    /// Output directory: results.json, config.json and one MCAP log per rollout.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Write the results JSON here (also written to --out).
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
}

/// Controllers valid on a vehicle, and whether each takes the joint interface.
fn controllers_for(vehicle: &platform::Vehicle) -> Vec<&'static str> {
    if vehicle.ee_link == vehicle.base_link {
        vec!["pid", "l1"]
    } else if vehicle.id == "fa-hexa" {
        vec!["ik-pid", "ik-l1", "mpc"]
    } else {
        vec!["ik-pid", "ik-l1"]
    }
}

fn tasks(name: &str) -> Result<Vec<TaskId>> {
    if name == "all" {
        return Ok(TaskId::ALL.to_vec());
    }
    name.split(',')
        .map(|n| TaskId::parse(n.trim()).map_err(|e| bad_input(format!("--task: {e}, or all"))))
        .collect()
}

pub(crate) fn config(args: &Args) -> Result<BenchConfig> {
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let tasks = tasks(&args.task)?;
    let valid = controllers_for(&vehicle);
    let name = args
        .controller
        .clone()
        .unwrap_or_else(|| valid[0].to_owned());
    if !valid.contains(&name.as_str()) {
        return Err(bad_input(format!(
            "--controller {name}: not available on {} (valid: {})",
            vehicle.id,
            valid.join(", ")
        )));
    }
    let kind = match name.as_str() {
        "l1" | "ik-l1" => ControllerKind::L1,
        "mpc" => ControllerKind::Mpc,
        _ => ControllerKind::Pid,
    };
    let interface = if args.interface == "joint" {
        Interface::BaseJoint
    } else {
        Interface::Ee
    };
    if interface == Interface::BaseJoint && vehicle.ee_link == vehicle.base_link {
        return Err(bad_input(format!(
            "--interface joint: {} has no arm joints (valid: ee)",
            vehicle.id
        )));
    }
    if interface == Interface::BaseJoint && kind == ControllerKind::Mpc {
        return Err(bad_input(
            "--interface joint: the whole-body MPC takes end-effector targets (valid: ee)",
        ));
    }
    let controller =
        profile(&vehicle, kind).map_err(|e| bad_input(format!("--controller {name}: {e}")))?;
    if args.rollouts == 0 {
        return Err(bad_input("--rollouts 0: run at least one rollout"));
    }
    let jobs = match args.jobs {
        Some(0) => return Err(bad_input("--jobs 0: use at least one thread")),
        Some(j) => j,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let episode = match args.episode_length.as_str() {
        "spec" => EpisodeLength::Spec,
        "script" => EpisodeLength::Script,
        s => match s.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => EpisodeLength::Seconds(x),
            _ => {
                return Err(bad_input(format!(
                    "--episode-length {s}: not spec, script or a positive number of seconds"
                )));
            }
        },
    };
    let twin = args.twin.twin_config()?;
    let policy = args.policy.resolve(
        &vehicle,
        interface,
        twin.control_rate_hz,
        &args.cameras.names(),
    )?;
    let link = match link_choice(&args.link)? {
        LinkChoice::Twin => BenchLink::InProcess,
        LinkChoice::Ipc(service) => BenchLink::Ipc(IpcLinkConfig {
            answer_timeout: Duration::from_millis(args.link_timeout_ms.max(1)),
            connect_timeout: Duration::from_millis(args.connect_timeout_ms),
            ..IpcLinkConfig::new(service)
        }),
        LinkChoice::Mavlink(_) => {
            return Err(bad_input(format!(
                "--link {}: the benchmark runs its rollouts in the twin (`twin` or \
                 `ipc:<service>`); an autopilot serves one flight per start: fly one rollout \
                 over MAVLink with `amstack fly --link {} --task T --trajectory scripted \
                 --seed S`",
                args.link, args.link
            )));
        }
    };
    let jobs = match (&link, args.jobs) {
        (BenchLink::Ipc(_), Some(j)) if j > 1 => {
            return Err(bad_input(format!(
                "--jobs {j}: over --link {} rollouts run one at a time (the twin serves one \
                 flight process at a time); start one twin per job and one bench per twin",
                args.link
            )));
        }
        (BenchLink::Ipc(_), _) => 1,
        _ => jobs,
    };
    if args.cameras.any() && !matches!(link, BenchLink::InProcess) {
        return Err(bad_input(format!(
            "--cameras with --link {}: the cameras are rendered from the twin in this process;              run with --link twin",
            args.link
        )));
    }
    let cameras = args.cameras.config(&vehicle)?;
    Ok(BenchConfig {
        cameras,
        link,
        episode,
        vehicle,
        controller,
        controller_name: name,
        interface,
        tasks,
        rollouts: args.rollouts,
        seed: args.twin.seed,
        twin,
        jobs,
        mcap_dir: args.out.as_ref().map(|d| d.join("rollouts")),
        state_source: args.state.state_source()?,
        policy,
    })
}

/// The run's configuration as recorded in the results (everything that decides them).
fn config_json(args: &Args, config: &BenchConfig) -> Result<Value> {
    Ok(json!({
        "platform": config.vehicle.id,
        "controller": config.controller_name,
        "controller_gains": serde_json::to_value(config.controller)?,
        "interface": match config.interface {
            Interface::Ee => "ee",
            Interface::BaseJoint => "joint",
        },
        "tasks": config.tasks.iter().map(|t| t.name()).collect::<Vec<_>>(),
        "rollouts": config.rollouts,
        "episode_length": config.episode,
        "seed": config.seed,
        "disturbances": args.twin.disturbances,
        "twin": serde_json::to_value(&config.twin)?,
    }))
}

fn spread_json(s: &Spread) -> Value {
    json!({ "mean": s.mean, "std": s.std, "stderr": s.stderr, "count": s.count })
}

fn rollout_json(r: &RolloutResult) -> Value {
    let s = &r.summary;
    let mut value = json!({
        "index": r.index,
        "seed": r.seed,
        "success": r.success,
        "termination": r.termination,
        "executed_steps": r.executed_steps,
        "subtask_completion": s.subtask_completion,
        "criteria": r.criteria.iter().map(|(n, v)| (n.clone(), Value::Bool(*v))).collect::<serde_json::Map<_, _>>(),
        "ee_pos_error_m": s.ee_pos_error_m,
        "base_pos_error_m": s.base_pos_error_m,
        "norm_ee_error": s.norm_ee_error,
        "norm_base_error": s.norm_base_error,
        "tilt_use_rad": s.tilt_use_rad,
        "saturation_rate": s.saturation_rate,
        "mcap": r.mcap,
    });
    if let (Some(e), Some(object)) = (&r.estimator, value.as_object_mut()) {
        object.insert("estimator".to_owned(), json!(e));
    }
    if let (Some(p), Some(object)) = (&r.policy, value.as_object_mut()) {
        object.insert("policy".to_owned(), json!(p));
    }
    value
}

/// The learned policy's figures over `rollouts`: queries, latency statistics (ms), failed
/// rollouts and their reasons.
fn policy_json<'a>(rollouts: impl Iterator<Item = &'a RolloutResult>) -> Value {
    let mut queries = 0;
    let mut samples = Vec::new();
    let mut failures = Vec::new();
    for r in rollouts {
        if let Some(p) = &r.policy {
            queries += p.queries;
            samples.extend_from_slice(&p.latency_samples_ms);
            if let Some(why) = &p.failure {
                failures.push(json!({ "task": r.task.name(), "index": r.index, "reason": why }));
            }
        }
    }
    json!({
        "queries": queries,
        "latency_ms": Stats::of(samples),
        "policy_failed": failures.len(),
        "failures": failures,
    })
}

fn task_json(t: &TaskResult) -> Value {
    let s = &t.summary;
    let criteria: serde_json::Map<String, Value> = t
        .criteria
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let reached = t.rollouts.iter().filter(|r| r.criteria[i].1).count();
            let rate = (!t.rollouts.is_empty()).then(|| reached as f64 / t.rollouts.len() as f64);
            (name.clone(), json!(rate))
        })
        .collect();
    json!({
        "rollouts": s.rollouts,
        "successes": s.successes,
        "success_rate": s.success_rate,
        "subtask_completion": s.subtask_completion,
        "criteria_rates": criteria,
        "norm_ee_error": s.norm_ee_error.mean,
        "norm_base_error": s.norm_base_error.mean,
        "tilt_use_rad": s.tilt_use_rad.mean,
        "saturation_rate": s.saturation_rate.mean,
        "spread_over_successes": {
            "norm_ee_error": spread_json(&s.norm_ee_error),
            "norm_base_error": spread_json(&s.norm_base_error),
            "tilt_use_rad": spread_json(&s.tilt_use_rad),
            "saturation_rate": spread_json(&s.saturation_rate),
        },
        "policy_failed": t.rollouts.iter().filter(|r| r.termination == Termination::PolicyFailed).count(),
        "per_rollout": t.rollouts.iter().map(rollout_json).collect::<Vec<_>>(),
    })
}

/// The results document (README "Results JSON").
pub(crate) fn results_json(
    args: &Args,
    config: &BenchConfig,
    report: &BenchReport,
) -> Result<Value> {
    let tasks: serde_json::Map<String, Value> = report
        .tasks
        .iter()
        .map(|t| (t.task.name().to_owned(), task_json(t)))
        .collect();
    let rollouts: usize = report.tasks.iter().map(|t| t.rollouts.len()).sum();
    let seconds_per_rollout = report.wall_time_s / rollouts.max(1) as f64;
    let policy = config.policy.as_ref().map(|p| {
        let mut value = policy_json(report.tasks.iter().flat_map(|t| &t.rollouts));
        if let Some(object) = value.as_object_mut() {
            object.insert("policy".to_owned(), p.endpoint.describe().into());
            object.insert("policy_hz".to_owned(), p.policy_hz.into());
            object.insert("action_steps".to_owned(), p.action_steps.into());
            object.insert("latency_mode".to_owned(), json!(p.latency));
        }
        value
    });
    Ok(json!({
        "schema": RESULTS_SCHEMA,
        "status": if report.interrupted { "interrupted" } else { "completed" },
        "seed": config.seed,
        "config": config_json(args, config)?,
        "tasks": tasks,
        "timing": {
            "link": config.link.name(),
            "wall_time_s": report.wall_time_s,
            "jobs": config.jobs,
            "env_steps": report.env_steps,
            "env_steps_per_second": report.steps_per_second(),
            "seconds_per_rollout": seconds_per_rollout,
            "rollouts_per_minute": 60.0 / seconds_per_rollout.max(1e-9),
        },
        "policy": policy,
    }))
}

fn pm(s: &Spread, scale: f64, decimals: usize) -> String {
    match (s.mean, s.std) {
        (Some(m), Some(d)) => format!("{:.decimals$} ± {:.decimals$}", m * scale, d * scale),
        (Some(m), None) => format!("{:.decimals$}", m * scale),
        _ => "N/A".to_owned(),
    }
}

/// The paper-shaped table.
pub(crate) fn table(report: &BenchReport) -> Table {
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "task",
        "SR (%)",
        "subtasks (%)",
        "norm. EE error",
        "norm. base error",
        "tilt use (deg)",
        "saturation (%)",
    ]);
    for t in &report.tasks {
        let s = &t.summary;
        table.add_row([
            t.task.title().to_owned(),
            format!("{:.2}", 100.0 * s.success_rate),
            format_or_na(s.subtask_completion.map(|c| 100.0 * c), 1),
            pm(&s.norm_ee_error, 1.0, 4),
            pm(&s.norm_base_error, 1.0, 4),
            pm(&s.tilt_use_rad, 180.0 / std::f64::consts::PI, 2),
            pm(&s.saturation_rate, 100.0, 2),
        ]);
    }
    table
}

fn check_out_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| bad_input(format!("--out {}: cannot create it: {e}", dir.display())))?;
    check_writable("--out", &dir.join("results.json"))
}

pub fn run(args: &Args) -> Result<()> {
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    let config = config(args)?;
    if let Some(dir) = &args.out {
        check_out_dir(dir)?;
    }
    let total = config.tasks.len() * config.rollouts;
    eprintln!(
        "bench: {} task(s) x {} rollouts on {} ({}, {} interface), seed {}, {} thread(s), disturbances: {}, link: {}",
        config.tasks.len(),
        config.rollouts,
        config.vehicle.id,
        config.controller_name,
        args.interface,
        config.seed,
        config.jobs,
        args.twin.disturbances,
        config.link.name()
    );
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} rollouts ({eta} left) {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let on_done = |r: &RolloutResult| {
        bar.set_message(format!(
            "{} #{}: {}",
            r.task.name(),
            r.index,
            if r.success {
                "success"
            } else if r.termination == Termination::PolicyFailed {
                "policy_failed"
            } else {
                "fail"
            }
        ));
        bar.inc(1);
    };
    let report = run_bench(&config, &on_done, &stop).map_err(|e| match e {
        BenchError::Link(LinkError::Refused(_)) => bad_input(e.to_string()),
        e => anyhow::Error::new(e),
    })?;
    bar.finish_and_clear();
    println!("{}", table(&report));
    let estimates: Vec<_> = report
        .tasks
        .iter()
        .flat_map(|t| &t.rollouts)
        .filter_map(|r| r.estimator)
        .collect();
    if !estimates.is_empty() {
        let n = estimates.len() as f64;
        eprintln!(
            "estimator vs truth: position RMSE {:.2} mm (mean over {} rollouts), largest error {:.2} mm; {} fixes fused, {} refused",
            estimates.iter().map(|e| e.position_rmse_m).sum::<f64>() / n * 1e3,
            estimates.len(),
            estimates
                .iter()
                .map(|e| e.position_max_error_m)
                .fold(0.0, f64::max)
                * 1e3,
            estimates.iter().map(|e| e.fused).sum::<u64>(),
            estimates.iter().map(|e| e.rejected).sum::<u64>(),
        );
    }
    if config.policy.is_some() {
        let p = policy_json(report.tasks.iter().flat_map(|t| &t.rollouts));
        let ms = |q: &str| {
            p["latency_ms"][q]
                .as_f64()
                .map_or("N/A".to_owned(), |x| format!("{x:.2} ms"))
        };
        eprintln!(
            "policy: {} queries, latency median {}, p99 {}; {} rollout(s) policy_failed",
            p["queries"],
            ms("p50"),
            ms("p99"),
            p["policy_failed"]
        );
        for f in p["failures"].as_array().into_iter().flatten() {
            eprintln!(
                "  {} #{}: {}",
                f["task"].as_str().unwrap_or(""),
                f["index"],
                f["reason"].as_str().unwrap_or("")
            );
        }
    }
    eprintln!(
        "{} env steps in {:.1} s ({:.0} steps/s, {} thread(s))",
        report.env_steps,
        report.wall_time_s,
        report.steps_per_second(),
        config.jobs
    );
    let results = results_json(args, &config, &report)?;
    if let Some(dir) = &args.out {
        write_json(&dir.join("results.json"), &results)?;
        write_json(&dir.join("config.json"), &results["config"])?;
        eprintln!("wrote {}", dir.display());
    }
    if let Some(path) = &args.json {
        write_json(path, &results)?;
        eprintln!("wrote {}", path.display());
    }
    if report.interrupted {
        return Err(anyhow::Error::new(Interrupted));
    }
    Ok(())
}

/// The run was stopped with Ctrl-C (partial results were written).
#[derive(Debug, thiserror::Error)]
#[error("interrupted; partial results written")]
pub struct Interrupted;
