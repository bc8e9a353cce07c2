//! `amstack bench --shard I/N` and `amstack bench merge`: one benchmark run split into shards
//! that run anywhere (other machines, array jobs, Ray tasks), merged back into exactly the
//! result the unsharded run writes.
//!
//! A shard writes a *part*: `part.json` (the run's full configuration, its shard, and for
//! each of its rollouts the rollout's entry of the results and its metric summary) and the
//! logs of its rollouts under `rollouts/`, as the unsharded run lays them out. The merge
//! recomputes each task's aggregates from the rollouts with the runner's own functions, so
//! the merged `results.json` equals the unsharded one except for `timing`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Result;
use comfy_table::{Table, presets};
use policy_runtime::bench::{
    BenchConfig, BenchReport, SHARD_ASSIGNMENT, Shard, first_difference, rollout_log_path,
};
use policy_runtime::metrics::{RolloutSummary, format_or_na, summarize_run};
use serde_json::{Value, json};
use sim_twin::TaskId;

use crate::bench_results::{
    PolicyRollout, RESULTS_SCHEMA, check_out_dir, policy_block, policy_setup_json, rollout_json,
    task_json_of, timing_json,
};
use crate::cli_error::bad_input;
use crate::output::{check_writable, write_bytes, write_json};

/// Version of the part layout.
const PART_SCHEMA: u64 = 1;
/// What a part is a part of (its `part_of` field).
const PART_OF: &str = "amstack bench";
/// The part's file in its directory.
pub(crate) const PART_FILE: &str = "part.json";
/// Environment variables of array jobs that carry the shard index (Slurm job arrays,
/// Kubernetes Indexed Jobs), in the order they are read.
pub(crate) const SHARD_ENV: [&str; 2] = ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"];

/// `amstack bench <action>`.
#[derive(Debug, clap::Subcommand)]
pub enum BenchAction {
    /// Merge the parts written by `amstack bench --shard I/N` into the result of the whole
    /// run: results.json, config.json and the logs, as the unsharded run writes them.
    Merge(MergeArgs),
}

#[derive(Debug, clap::Args)]
#[command(after_help = "\
The parts must be of one run (same configuration and seed: the first field that differs is
named), of one split (same N), complete (each shard finished and holds exactly its rollouts)
and non-overlapping (each shard once). Either every part has its logs (--out DIR) or none.

Examples:
  amstack bench --task all --rollouts 30 --shard 0/3 --out part0   (and 1/3, 2/3)
  amstack bench merge part0 part1 part2 --out run
  amstack bench merge parts/*/ --out run --json run.json")]
pub struct MergeArgs {
    /// The parts: directories written by `amstack bench --shard I/N --out DIR` (their
    /// part.json and logs), or part files written with `--json FILE` (no logs).
    #[arg(required = true, value_name = "PART")]
    parts: Vec<PathBuf>,
    /// Output directory: results.json, config.json and one MCAP log per rollout.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Also write the results JSON here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

/// Runs `amstack bench <action>`.
pub fn run_action(action: &BenchAction) -> Result<()> {
    match action {
        BenchAction::Merge(args) => merge(args),
    }
}

/// The shard of `--shard SPEC`: `I/N`, or `env/N` with I from the first of [`SHARD_ENV`]
/// that `env` finds (two that disagree are refused).
pub(crate) fn parse_shard(spec: &str, env: &dyn Fn(&str) -> Option<String>) -> Result<Shard> {
    let usage = || {
        bad_input(format!(
            "--shard {spec}: expected I/N (shard I of N, 0-based) or env/N (I from {})",
            SHARD_ENV.join(" or ")
        ))
    };
    let (index, count) = spec.split_once('/').ok_or_else(usage)?;
    let count: usize = count.trim().parse().map_err(|_| usage())?;
    if index.trim() != "env" {
        let index: usize = index.trim().parse().map_err(|_| usage())?;
        return Shard::new(index, count).map_err(|e| bad_input(format!("--shard {spec}: {e}")));
    }
    let found: Vec<(&str, String)> = SHARD_ENV
        .iter()
        .filter_map(|var| env(var).map(|value| (*var, value)))
        .collect();
    let (var, value) = match found.as_slice() {
        [] => {
            return Err(bad_input(format!(
                "--shard {spec}: neither {} is set (an array job's index; or give --shard I/{count})",
                SHARD_ENV.join(" nor ")
            )));
        }
        [(a, x), (b, y), ..] if x.trim() != y.trim() => {
            return Err(bad_input(format!(
                "--shard {spec}: {a}={x} and {b}={y} disagree; unset one"
            )));
        }
        [first, ..] => first.clone(),
    };
    let index: usize = value.trim().parse().map_err(|_| {
        bad_input(format!(
            "--shard {spec}: {var}={value:?} is not a shard index (0, 1, ...)"
        ))
    })?;
    Shard::new(index, count).map_err(|e| {
        bad_input(format!(
            "--shard {spec}: {var}={value}: {e} (a Slurm array for N shards is --array=0-{})",
            count.saturating_sub(1)
        ))
    })
}

/// The part of `shard` of the run configured as `config_value` (the results' `config`).
pub(crate) fn part_json(
    config_value: &Value,
    config: &BenchConfig,
    shard: Shard,
    report: &BenchReport,
) -> Result<Value> {
    let rollouts = report
        .tasks
        .iter()
        .flat_map(|t| &t.rollouts)
        .map(|r| {
            let mut entry = json!({
                "task": r.task.name(),
                "index": r.index,
                "summary": serde_json::to_value(&r.summary)?,
                "result": rollout_json(r),
            });
            // A learned policy's every query time: the merge's run-level statistics.
            if let (Some(p), Some(object)) = (&r.policy, entry.as_object_mut()) {
                object.insert("latency_samples_ms".to_owned(), json!(p.latency_samples_ms));
            }
            Ok(entry)
        })
        .collect::<Result<Vec<Value>>>()?;
    let expected = shard.rollouts(&config.tasks, config.rollouts).len();
    let mut part = json!({
        "schema": PART_SCHEMA,
        "part_of": PART_OF,
        "status": if report.interrupted { "interrupted" } else { "completed" },
        "seed": config.seed,
        "config": config_value,
        "shard": {
            "index": shard.index,
            "count": shard.count,
            "assignment": SHARD_ASSIGNMENT,
            "rollouts": expected,
        },
        "logs": config.mcap_dir.is_some(),
        "rollouts": rollouts,
        "timing": timing_json(
            &config.link.name(),
            report.wall_time_s,
            &json!(config.jobs),
            report.env_steps,
            rollouts.len(),
        ),
    });
    // With a learned policy only (a scripted run's parts keep their layout).
    let policy = policy_setup_json(config);
    if let (false, Some(object)) = (policy.is_null(), part.as_object_mut()) {
        object.insert("policy".to_owned(), policy);
    }
    Ok(part)
}

/// Writes a part to `out/part.json` and/or `json`.
pub(crate) fn write_part(out: Option<&Path>, json: Option<&Path>, part: &Value) -> Result<()> {
    if let Some(dir) = out {
        write_json(&dir.join(PART_FILE), part)?;
        eprintln!(
            "wrote part {}/{} to {}",
            part["shard"]["index"],
            part["shard"]["count"],
            dir.display()
        );
    }
    if let Some(path) = json {
        write_json(path, part)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// One part read back.
#[derive(Debug)]
struct Part {
    /// Its part file.
    file: PathBuf,
    /// The folder its logs are under (`rollouts/`).
    dir: PathBuf,
    doc: Value,
    shard: Shard,
}

fn read_part(arg: &Path) -> Result<Part> {
    let file = if arg.is_dir() {
        arg.join(PART_FILE)
    } else {
        arg.to_path_buf()
    };
    let shown = file.display();
    let text = std::fs::read_to_string(&file).map_err(|e| {
        bad_input(format!(
            "{shown}: cannot read it: {e} (a part is the --out DIR or --json FILE of `amstack bench --shard I/N`)"
        ))
    })?;
    let doc: Value = serde_json::from_str(&text)
        .map_err(|e| bad_input(format!("{shown}: not a JSON part: {e}")))?;
    if doc["part_of"] != PART_OF {
        return Err(bad_input(format!(
            "{shown}: not a part of `amstack bench --shard I/N` (part_of is {}, not \"{PART_OF}\")",
            doc["part_of"]
        )));
    }
    if doc["schema"].as_u64() != Some(PART_SCHEMA) {
        return Err(bad_input(format!(
            "{shown}: schema {}, this amstack reads parts of schema {PART_SCHEMA}",
            doc["schema"]
        )));
    }
    let number = |field: &str| {
        doc["shard"][field]
            .as_u64()
            .and_then(|n| usize::try_from(n).ok())
            .ok_or_else(|| bad_input(format!("{shown}: shard.{field} is not a number")))
    };
    let shard = Shard::new(number("index")?, number("count")?)
        .map_err(|e| bad_input(format!("{shown}: shard: {e}")))?;
    let dir = match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok(Part {
        file,
        dir,
        doc,
        shard,
    })
}

/// One rollout of a part: its task position, index, and entry.
type Held<'a> = BTreeMap<(usize, usize), (&'a Part, &'a Value)>;

/// Checks that `parts` are the complete, non-overlapping split of one run; returns the
/// run's tasks, rollouts per task and every rollout by (task position, index).
fn check_parts(parts: &[Part]) -> Result<(Vec<TaskId>, Held<'_>)> {
    let Some(first) = parts.first() else {
        return Err(bad_input("bench merge: name at least one part"));
    };
    for p in &parts[1..] {
        for key in ["seed", "config", "policy"] {
            if let Some((field, a, b)) = first_difference(&first.doc[key], &p.doc[key], key) {
                return Err(bad_input(format!(
                    "parts of different runs: {} has {field} = {a}, {} has {b}",
                    first.file.display(),
                    p.file.display()
                )));
            }
        }
        if p.shard.count != first.shard.count {
            return Err(bad_input(format!(
                "parts of different splits: {} is shard {}, {} is shard {}",
                first.file.display(),
                first.shard,
                p.file.display(),
                p.shard
            )));
        }
        if p.doc["logs"] != first.doc["logs"] {
            let (with, without) = if first.doc["logs"] == true {
                (first, p)
            } else {
                (p, first)
            };
            return Err(bad_input(format!(
                "{} has logs, {} has none: merge parts that all ran with --out DIR, or none",
                with.file.display(),
                without.file.display()
            )));
        }
    }
    let count = first.shard.count;
    let mut by_index: Vec<Option<&Part>> = vec![None; count];
    for p in parts {
        if let Some(other) = by_index[p.shard.index] {
            return Err(bad_input(format!(
                "shard {} given twice: {} and {}",
                p.shard,
                other.file.display(),
                p.file.display()
            )));
        }
        by_index[p.shard.index] = Some(p);
    }
    let missing: Vec<String> = (0..count)
        .filter(|i| by_index[*i].is_none())
        .map(|i| format!("{i}/{count}"))
        .collect();
    if !missing.is_empty() {
        return Err(bad_input(format!(
            "shard {} missing (have {} of {count} parts): run it with `amstack bench ... --shard {}` and merge again",
            missing.join(", "),
            parts.len(),
            missing[0]
        )));
    }
    let config = &first.doc["config"];
    let shown = first.file.display();
    let tasks: Vec<TaskId> = config["tasks"]
        .as_array()
        .ok_or_else(|| bad_input(format!("{shown}: config.tasks is not a list")))?
        .iter()
        .map(|t| {
            TaskId::parse(t.as_str().unwrap_or_default())
                .map_err(|e| bad_input(format!("{shown}: config.tasks: {e}")))
        })
        .collect::<Result<_>>()?;
    let per_task = config["rollouts"]
        .as_u64()
        .and_then(|n| usize::try_from(n).ok())
        .ok_or_else(|| bad_input(format!("{shown}: config.rollouts is not a number")))?;
    let mut held: Held<'_> = BTreeMap::new();
    for p in parts {
        let shown = p.file.display();
        if p.doc["status"] != "completed" {
            return Err(bad_input(format!(
                "{shown}: shard {} is incomplete (status {}): run it again",
                p.shard, p.doc["status"]
            )));
        }
        let expected = p.shard.rollouts(&tasks, per_task);
        let rollouts = p.doc["rollouts"]
            .as_array()
            .ok_or_else(|| bad_input(format!("{shown}: rollouts is not a list")))?;
        let mut got = Vec::with_capacity(rollouts.len());
        for r in rollouts {
            let task = TaskId::parse(r["task"].as_str().unwrap_or_default())
                .map_err(|e| bad_input(format!("{shown}: rollouts: {e}")))?;
            let index = r["index"]
                .as_u64()
                .and_then(|n| usize::try_from(n).ok())
                .ok_or_else(|| bad_input(format!("{shown}: a rollout without an index")))?;
            got.push((task, index));
            let position = tasks.iter().position(|t| *t == task).unwrap_or(usize::MAX);
            held.insert((position, index), (p, r));
        }
        if let Some((t, i)) = expected.iter().find(|job| !got.contains(job)) {
            return Err(bad_input(format!(
                "{shown}: shard {} is incomplete: {} #{i} missing ({} of its {} rollouts)",
                p.shard,
                t.name(),
                got.len(),
                expected.len()
            )));
        }
        if let Some((t, i)) = got.iter().find(|job| !expected.contains(job)) {
            return Err(bad_input(format!(
                "{shown}: shard {} holds {} #{i}, which is not its rollout (or twice)",
                p.shard,
                t.name()
            )));
        }
        if got.len() != expected.len() {
            return Err(bad_input(format!(
                "{shown}: shard {} holds {} rollouts, its share is {}",
                p.shard,
                got.len(),
                expected.len()
            )));
        }
    }
    Ok((tasks, held))
}

fn merge(args: &MergeArgs) -> Result<()> {
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    let parts: Vec<Part> = args
        .parts
        .iter()
        .map(|p| read_part(p))
        .collect::<Result<_>>()?;
    let (tasks, held) = check_parts(&parts)?;
    let Some(first) = parts.first() else {
        return Err(bad_input("bench merge: name at least one part"));
    };
    let logs = first.doc["logs"] == true;
    // Everything is read and checked before anything is written.
    let mut sources = Vec::new();
    if logs {
        for (&(position, index), (part, _)) in &held {
            let task = tasks[position];
            let source = rollout_log_path(&part.dir.join("rollouts"), task, index);
            if !source.is_file() {
                return Err(bad_input(format!(
                    "{}: the log of {} #{index} is missing ({})",
                    part.file.display(),
                    task.name(),
                    source.display()
                )));
            }
            sources.push((task, index, source));
        }
    }
    let out_logs = args.out.join("rollouts");
    let mut tasks_json = serde_json::Map::new();
    for (position, task) in tasks.iter().enumerate() {
        let mut summaries = Vec::new();
        let mut per_rollout = Vec::new();
        for ((_, index), (part, r)) in held.range((position, 0)..(position + 1, 0)) {
            let summary: RolloutSummary =
                serde_json::from_value(r["summary"].clone()).map_err(|e| {
                    bad_input(format!(
                        "{}: {} #{index}: summary: {e}",
                        part.file.display(),
                        task.name()
                    ))
                })?;
            summaries.push(summary);
            let mut result = r["result"].clone();
            if logs {
                result["mcap"] = json!(rollout_log_path(&out_logs, *task, *index));
            }
            per_rollout.push(result);
        }
        let criteria: Vec<String> = task
            .criteria_names()
            .iter()
            .map(|n| (*n).to_owned())
            .collect();
        tasks_json.insert(
            task.name().to_owned(),
            task_json_of(&summarize_run(&summaries), &criteria, &per_rollout),
        );
    }
    let wall_time_s: f64 = parts
        .iter()
        .filter_map(|p| p.doc["timing"]["wall_time_s"].as_f64())
        .sum();
    let env_steps: u64 = parts
        .iter()
        .filter_map(|p| p.doc["timing"]["env_steps"].as_u64())
        .sum();
    let mut timing = timing_json(
        first.doc["timing"]["link"].as_str().unwrap_or("twin"),
        wall_time_s,
        &Value::Null,
        env_steps,
        held.len(),
    );
    timing["merged_from_shards"] = parts
        .iter()
        .map(|p| {
            json!({
                "shard": p.shard.to_string(),
                "part": p.file,
                "wall_time_s": p.doc["timing"]["wall_time_s"],
                "jobs": p.doc["timing"]["jobs"],
            })
        })
        .collect();
    let mut results = json!({
        "schema": RESULTS_SCHEMA,
        "status": "completed",
        "seed": first.doc["seed"],
        "config": first.doc["config"],
        "tasks": tasks_json,
        "timing": timing,
    });
    // A learned policy's run-level block, rebuilt from the rollouts as `bench` builds it.
    if first.doc["policy"].is_object() {
        let mut samples: Vec<Vec<f64>> = Vec::with_capacity(held.len());
        for ((position, index), (part, r)) in &held {
            let s: Vec<f64> =
                serde_json::from_value(r["latency_samples_ms"].clone()).map_err(|e| {
                    bad_input(format!(
                        "{}: {} #{index}: latency_samples_ms: {e}",
                        part.file.display(),
                        tasks[*position].name()
                    ))
                })?;
            samples.push(s);
        }
        let rollouts = held
            .iter()
            .zip(&samples)
            .map(|(((position, index), (_, r)), s)| PolicyRollout {
                task: tasks[*position].name(),
                index: *index,
                queries: r["result"]["policy"]["queries"].as_u64().unwrap_or(0),
                latency_samples_ms: s,
                failure: r["result"]["policy"]["failure"].as_str(),
            });
        let block = policy_block(&first.doc["policy"], rollouts);
        if let Some(object) = results.as_object_mut() {
            object.insert("policy".to_owned(), block);
        }
    }
    check_out_dir(&args.out)?;
    for (task, index, source) in &sources {
        let target = rollout_log_path(&out_logs, *task, *index);
        if let Some(dir) = target.parent() {
            std::fs::create_dir_all(dir)
                .map_err(|e| bad_input(format!("--out: cannot create {}: {e}", dir.display())))?;
        }
        let bytes = std::fs::read(source)
            .map_err(|e| bad_input(format!("cannot read {}: {e}", source.display())))?;
        write_bytes(&target, &bytes)?;
    }
    write_json(&args.out.join("results.json"), &results)?;
    write_json(&args.out.join("config.json"), &results["config"])?;
    println!("{}", summary_table(&results));
    eprintln!(
        "merged {} shard(s), {} rollouts{} into {}",
        parts.len(),
        held.len(),
        if logs { " and their logs" } else { "" },
        args.out.display()
    );
    if let Some(path) = &args.json {
        write_json(path, &results)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// Per task: rollouts, success rate and subtask completion of a results document.
pub(crate) fn summary_table(results: &Value) -> Table {
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "task",
        "rollouts",
        "SR (%)",
        "subtasks (%)",
    ]);
    if let Some(tasks) = results["tasks"].as_object() {
        for (name, t) in tasks {
            table.add_row([
                name.clone(),
                t["rollouts"].to_string(),
                format_or_na(t["success_rate"].as_f64().map(|r| 100.0 * r), 2),
                format_or_na(t["subtask_completion"].as_f64().map(|c| 100.0 * c), 1),
            ]);
        }
    }
    table
}
