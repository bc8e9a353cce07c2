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
    BenchConfig, BenchError, BenchLink, BenchReport, EpisodeLength, RolloutResult, Shard,
    TaskResult, run_bench_shard,
};
use policy_runtime::metrics::{Spread, format_or_na};
use policy_runtime::{IpcLinkConfig, LinkError};
use serde_json::{Value, json};
use sim_twin::TaskId;

use crate::bench_results::{
    PolicyRollout, RESULTS_SCHEMA, check_out_dir, policy_block, policy_setup_json, rollout_json,
    task_json_of, timing_json,
};
use crate::cli_error::bad_input;
use crate::fly::{LinkChoice, link_choice};
use crate::output::{check_writable, write_json};
use crate::policy_flags::PolicyFlags;
use crate::twin_flags::TwinFlags;
use crate::vehicles::find_vehicle;

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
  amstack twin serve --ipc bench --platform fa-hexa --flight-chooses-episode &
  amstack bench --link ipc:bench --task press-button --rollouts 5

Shards: --shard I/N runs only shard I (0-based) of N of the run's rollouts -- rollout number
k = task position x rollouts + index, shard I holds k mod N = I -- and writes a partial result
(part.json and its logs under --out); `amstack bench merge PART... --out DIR` checks the parts
are of one run, complete and non-overlapping and writes what the unsharded run writes.
--shard env/N takes I from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX (array jobs).
  amstack bench --task all --rollouts 30 --shard 0/3 --out part0   (and 1/3, 2/3)
  amstack bench merge part0 part1 part2 --out run

Examples:
  amstack bench --task press-button --rollouts 5       (FA-Hexa, IK-PID: the default)
  amstack bench --rollouts 30 --out runs/fa-ikpid --disturbances reference
  amstack bench --platform ee-only --rollouts 30       (the floating end-effector oracle)
  amstack bench --controller mpc --task push-slider
  amstack bench --platform fa-hexa --interface joint --task push-slider --json slider.json")]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    pub(crate) action: Option<crate::bench_shard::BenchAction>,
    /// Task name, or `all`.
    #[arg(long, default_value = "all")]
    pub(crate) task: String,
    /// Vehicle id (fa-hexa, ee-only, ua-hexa, ua-quad, omni-hexa, or one added with
    /// --vehicle). The default is the paper's main configuration: the FA-Hexa, EE interface,
    /// IK-PID.
    #[arg(long, default_value = "fa-hexa")]
    pub(crate) platform: String,
    /// Controller [default: pid on ee-only, ik-pid otherwise].
    #[arg(long)]
    pub(crate) controller: Option<String>,
    /// With --controller mpc: a TOML file of `MpcConfig` fields (horizon_s, arm_gain_per_s,
    /// rotor_margin_for_force, rotor_margin_for_wrench, target_extrapolation_s, [qp], [weights],
    /// …; the defaults fill the rest, unknown keys are refused), recorded in config.json's
    /// controller_gains. E.g. `rotor_margin_for_wrench = 0.95` (plan only wrenches the rotors
    /// deliver) or `[qp]` `tolerance = 1e-3` (the reference's QP tolerance).
    #[arg(long, value_name = "FILE.toml")]
    pub(crate) mpc_config: Option<PathBuf>,
    /// Action interface: ee (end-effector target) or joint (base pose + arm joints, from the
    /// scripted end-effector targets through the whole-body IK).
    #[arg(long, default_value = "ee", value_parser = ["ee", "joint"])]
    pub(crate) interface: String,
    /// Rollouts per task.
    #[arg(long, default_value_t = 10)]
    pub(crate) rollouts: usize,
    /// Episode length: `spec` (the task's), `script` (the task's, or longer where its scripted
    /// policy needs it, as the reference's demonstration recorder runs it: only Wipe Window),
    /// or seconds.
    #[arg(long, value_name = "spec|script|S", default_value = "script")]
    pub(crate) episode_length: String,
    /// Worker threads [default: all cores; 1 over ipc].
    #[arg(long)]
    pub(crate) jobs: Option<usize>,
    /// Where the rollouts run: `twin` (this process) or `ipc:<service>` (the twin of
    /// `amstack twin serve --ipc <service> --flight-chooses-episode`, in lockstep).
    #[arg(long, value_name = "LINK", default_value = "twin")]
    pub(crate) link: String,
    /// How long each answer of the twin may take before the run stops, ms (ipc).
    #[arg(long, value_name = "MS", default_value_t = 50)]
    pub(crate) link_timeout_ms: u64,
    /// How long to wait for the twin to answer each rollout's handshake, ms (ipc).
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    pub(crate) connect_timeout_ms: u64,
    #[command(flatten)]
    pub(crate) twin: TwinFlags,
    #[command(flatten)]
    pub(crate) state: crate::track::StateFlags,
    #[command(flatten)]
    pub(crate) policy: PolicyFlags,
    #[command(flatten)]
    pub(crate) cameras: crate::camera_flags::CameraFlags,
    /// Write one MP4 per rollout into DIR (`<task>/rollout-NNN.mp4`): the scene camera (with
    /// the EE camera beside it when --cameras names ee), 30 fps from every 4th step. Needs the
    /// ffmpeg program (apt-get install ffmpeg, or AMSTACK_FFMPEG=PATH).
    #[arg(long, value_name = "DIR")]
    pub(crate) video: Option<PathBuf>,
    /// Output directory: results.json, config.json and one MCAP log per rollout.
    #[arg(long, value_name = "DIR")]
    pub(crate) out: Option<PathBuf>,
    /// Write the results JSON here (also written to --out).
    #[arg(long, value_name = "FILE")]
    pub(crate) json: Option<PathBuf>,
    /// Stream each rollout in progress live (its log's channels: the 3D scene, transforms,
    /// every amstack channel) over the Foxglove WebSocket protocol: in Foxglove, "Open
    /// connection", ws://ADDR. ADDR is IP:PORT [default: 127.0.0.1:8765]. Rollouts never wait
    /// for a viewer (a full queue drops and counts; printed at the end).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = policy_runtime::live::DEFAULT_LIVE_ADDR)]
    pub(crate) live: Option<String>,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    pub(crate) vehicles: Vec<PathBuf>,
    /// Run only shard I (0-based) of N of the rollouts and write a partial result
    /// (--out DIR/part.json, or --json); `env/N` reads I from SLURM_ARRAY_TASK_ID or
    /// JOB_COMPLETION_INDEX. Merge the parts with `amstack bench merge`.
    #[arg(long, value_name = "I/N")]
    pub(crate) shard: Option<String>,
}

/// Controllers valid on a vehicle, and whether each takes the joint interface.
pub(crate) fn controllers_for(vehicle: &platform::Vehicle) -> Vec<&'static str> {
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

/// The MPC's settings of an `--mpc-config` file: its fields over the defaults; a missing
/// file, an unknown key or a bad value is bad input naming the file.
pub(crate) fn mpc_config(path: &Path) -> Result<controllers::mpc::MpcConfig> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| bad_input(format!("--mpc-config {}: {e}", path.display())))?;
    controllers::mpc::MpcConfig::from_toml_str(&text)
        .map_err(|e| bad_input(format!("--mpc-config {}: {e}", path.display())))
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
    let controller = match (&args.mpc_config, kind) {
        (Some(path), ControllerKind::Mpc) => controllers::ControllerConfig::Mpc(mpc_config(path)?),
        (Some(_), _) => {
            return Err(bad_input(format!(
                "--mpc-config: the {name} controller takes no MPC settings (use --controller mpc)"
            )));
        }
        (None, _) => {
            profile(&vehicle, kind).map_err(|e| bad_input(format!("--controller {name}: {e}")))?
        }
    };
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
    if (args.cameras.any() || args.video.is_some()) && !matches!(link, BenchLink::InProcess) {
        return Err(bad_input(format!(
            "--cameras/--video with --link {}: the cameras are rendered from the twin in this process; run with --link twin",
            args.link
        )));
    }
    let cameras = args.cameras.config(&vehicle, args.video.as_deref())?;
    Ok(BenchConfig {
        live: crate::track::start_live(args.live.as_deref())?,
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
pub(crate) fn config_json(args: &Args, config: &BenchConfig) -> Result<Value> {
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

fn task_json(t: &TaskResult) -> Value {
    let per_rollout: Vec<Value> = t.rollouts.iter().map(rollout_json).collect();
    task_json_of(&t.summary, &t.criteria, &per_rollout)
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
    let policy = config.policy.as_ref().map(|_| {
        policy_block(
            &policy_setup_json(config),
            report
                .tasks
                .iter()
                .flat_map(|t| &t.rollouts)
                .filter_map(PolicyRollout::of),
        )
    });
    let mut results = json!({
        "schema": RESULTS_SCHEMA,
        "status": if report.interrupted { "interrupted" } else { "completed" },
        "seed": config.seed,
        "config": config_json(args, config)?,
        "tasks": tasks,
        "timing": timing_json(&config.link.name(), report.wall_time_s, &json!(config.jobs), report.env_steps, rollouts),
    });
    // With a learned policy only: the results of a scripted run keep their layout.
    if let (Some(p), Some(object)) = (policy, results.as_object_mut()) {
        object.insert("policy".to_owned(), p);
    }
    Ok(results)
}

fn pm(s: &Spread, scale: f64, decimals: usize) -> String {
    match (s.mean, s.std) {
        (Some(m), Some(d)) => format!("{:.decimals$} ± {:.decimals$}", m * scale, d * scale),
        (Some(m), None) => format!("{:.decimals$}", m * scale),
        _ => "N/A".to_owned(),
    }
}

/// The paper-shaped table; with the whole-body MPC, one more column: the share of the ticks
/// its IK-PID fallback flew (over every rollout, failed ones included).
pub(crate) fn table(report: &BenchReport) -> Table {
    let mut table = Table::new();
    let mpc = report
        .tasks
        .iter()
        .any(|t| t.summary.fallback_rate.count > 0);
    let mut header = vec![
        "task",
        "SR (%)",
        "subtasks (%)",
        "norm. EE error",
        "norm. base error",
        "tilt use (deg)",
        "saturation (%)",
    ];
    if mpc {
        header.push("IK-PID fallback (%)");
    }
    table.load_style(presets::ASCII_MARKDOWN).set_header(header);
    for t in &report.tasks {
        let s = &t.summary;
        let mut row = vec![
            t.task.title().to_owned(),
            format!("{:.2}", 100.0 * s.success_rate),
            format_or_na(s.subtask_completion.map(|c| 100.0 * c), 1),
            pm(&s.norm_ee_error, 1.0, 4),
            pm(&s.norm_base_error, 1.0, 4),
            pm(&s.tilt_use_rad, 180.0 / std::f64::consts::PI, 2),
            pm(&s.saturation_rate, 100.0, 2),
        ];
        if mpc {
            row.push(pm(&s.fallback_rate, 100.0, 2));
        }
        table.add_row(row);
    }
    table
}

pub fn run(args: &Args) -> Result<()> {
    if let Some(action) = &args.action {
        return crate::bench_shard::run_action(action);
    }
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    let config = config(args)?;
    let shard = match &args.shard {
        Some(spec) => Some(crate::bench_shard::parse_shard(spec, &|v| {
            std::env::var(v).ok()
        })?),
        None => None,
    };
    if shard.is_some() && args.out.is_none() && args.json.is_none() {
        return Err(bad_input(
            "--shard: name where the partial result goes (--out DIR, or --json FILE)",
        ));
    }
    if let Some(dir) = &args.out {
        check_out_dir(dir)?;
    }
    let total = shard
        .unwrap_or(Shard::WHOLE)
        .rollouts(&config.tasks, config.rollouts)
        .len();
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
    let report = run_bench_shard(&config, shard.unwrap_or(Shard::WHOLE), &on_done, &stop);
    crate::track::finish_live(config.live.as_deref());
    let report = report.map_err(|e| match e {
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
        let p = policy_block(
            &Value::Null,
            report
                .tasks
                .iter()
                .flat_map(|t| &t.rollouts)
                .filter_map(PolicyRollout::of),
        );
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
    if let Some(shard) = shard {
        let part =
            crate::bench_shard::part_json(&config_json(args, &config)?, &config, shard, &report)?;
        crate::bench_shard::write_part(args.out.as_deref(), args.json.as_deref(), &part)?;
        if report.interrupted {
            return Err(anyhow::Error::new(Interrupted));
        }
        return Ok(());
    }
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
