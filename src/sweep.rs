//! `amstack sweep SWEEP.toml --out DIR`: a grid of benchmark runs (platforms × controllers ×
//! interfaces × disturbance sets × tasks × rollouts × seeds, or explicit runs), run locally on
//! all cores or as shards on a Ray cluster, one results folder per cell plus a summary table
//! (terminal, JSON, CSV). A cell is exactly an `amstack bench` run: its flags are recorded in
//! the plan, and its folder holds what `amstack bench --out` writes.
//!
//! A sweep resumes: a cell whose folder already holds completed results of the same
//! configuration is not run again.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::Result;
use comfy_table::{Table, presets};
use indicatif::{ProgressBar, ProgressStyle};
use policy_runtime::bench::{RolloutResult, run_bench};
use policy_runtime::metrics::format_or_na;
use serde_json::{Value, json};

use crate::cli_error::bad_input;
use crate::output::{write_bytes, write_json};

/// The Ray driver, shipped inside the binary and written next to the sweep's plan.
const RAY_DRIVER: &str = include_str!("../scripts/ray_sweep.py");

#[derive(Debug, clap::Args)]
#[command(after_help = "\
A sweep file (TOML) names a grid, explicit runs, or both:

  vehicles = []                      # vehicle files to add (paths relative to this file)
  [grid]                             # every combination is a cell; a value or a list each
  platforms = [\"ee-only\", \"fa-hexa\"]
  controllers = [\"default\"]          # `default`: the platform's first (pid / ik-pid)
  interfaces = [\"ee\"]                # ee, joint
  disturbances = [\"none\", \"reference\"] # as bench --disturbances
  tasks = [\"press-button\"]           # as bench --task: a name, a comma list, or all
  rollouts = 3
  seeds = [0]
  episode_length = \"script\"          # spec, script or seconds
  skip_unavailable = false           # true: leave out cells whose controller/interface
                                     # the platform lacks (else they are an error)
  [[run]]                            # an explicit cell (same keys, one value each)
  name = \"mpc-slider\"                # optional folder name
  platform = \"fa-hexa\"
  controller = \"mpc\"
  task = \"push-slider\"
  rollouts = 2

Output: DIR/cells/<cell>/ (results.json, config.json, rollouts/ as `amstack bench --out`),
DIR/summary.json, DIR/summary.csv (one row per cell and task) and DIR/plan.json (each cell's
bench flags). Run again with the same --out to resume: completed cells are kept.

Engines:
  local (default)   every cell in turn, its rollouts on --jobs threads (all cores).
  ray[:ADDRESS]     every shard of every cell (--shards per cell) is a Ray task running
                    `amstack bench ... --shard I/N` on a worker; a dead worker's shard is
                    retried; the parts are merged with `amstack bench merge`. Without ADDRESS
                    Ray starts a local instance. Needs scripts/setup-ray.sh (or --ray-python).
  Slurm / Kubernetes: see deploy/ (array jobs running `amstack bench --shard env/N`).

Examples:
  amstack sweep examples/sweep.toml --out runs/sweep
  amstack sweep examples/sweep.toml --out runs/sweep --engine ray:127.0.0.1:6379 --shards 2")]
pub struct Args {
    /// The sweep file (TOML).
    #[arg(value_name = "SWEEP.toml")]
    file: PathBuf,
    /// Output directory (one folder per cell, summary.json, summary.csv).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// `local`, or `ray` / `ray:ADDRESS` (a Ray cluster, e.g. ray:127.0.0.1:6379).
    #[arg(long, value_name = "ENGINE", default_value = "local")]
    engine: String,
    /// Worker threads of the local engine [default: all cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Shards per cell on Ray (each a Ray task of one CPU).
    #[arg(long, value_name = "N", default_value_t = 2)]
    shards: usize,
    /// The Python that has Ray [default: $AMSTACK_RAY_PYTHON, else
    /// ~/.cache/amstack-ray-venv/bin/python as scripts/setup-ray.sh makes it].
    #[arg(long, value_name = "PYTHON")]
    ray_python: Option<PathBuf>,
    /// Test hook of the Ray engine: the first attempt of shard I of CELL kills its own worker
    /// process, so Ray must retry it (CELL:I).
    #[arg(long, value_name = "CELL:I", hide = true)]
    kill_once: Option<String>,
    /// Only validate the sweep file and print its cells.
    #[arg(long)]
    dry_run: bool,
}

/// One cell: one `amstack bench` run.
#[derive(Debug, Clone)]
struct Cell {
    name: String,
    platform: String,
    controller: String,
    interface: String,
    disturbances: String,
    task: String,
    rollouts: usize,
    seed: u64,
    episode_length: String,
    /// Where it came from, for errors: `grid cell 3` or `run 2`.
    origin: String,
}

impl Cell {
    /// The cell's `amstack bench` flags (without --out and --jobs).
    fn bench_flags(&self, vehicles: &[PathBuf]) -> Vec<String> {
        let mut flags: Vec<String> = [
            "--platform",
            &self.platform,
            "--controller",
            &self.controller,
            "--interface",
            &self.interface,
            "--disturbances",
            &self.disturbances,
            "--task",
            &self.task,
            "--rollouts",
            &self.rollouts.to_string(),
            "--seed",
            &self.seed.to_string(),
            "--episode-length",
            &self.episode_length,
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect();
        for v in vehicles {
            flags.push("--vehicle".to_owned());
            flags.push(v.to_string_lossy().into_owned());
        }
        flags
    }
}

/// `amstack bench FLAGS` parsed as the command line parses it.
pub(crate) fn bench_args(flags: &[String]) -> Result<crate::bench::Args> {
    crate::flag_line::parse("bench", flags)
}

// ---- the sweep file ----------------------------------------------------------------------

const GRID_KEYS: [&str; 9] = [
    "platforms",
    "controllers",
    "interfaces",
    "disturbances",
    "tasks",
    "rollouts",
    "seeds",
    "episode_length",
    "skip_unavailable",
];
const RUN_KEYS: [&str; 9] = [
    "name",
    "platform",
    "controller",
    "interface",
    "disturbances",
    "task",
    "rollouts",
    "seed",
    "episode_length",
];

/// Reads one field of a table as strings: a string, a number (episode lengths) or a list of
/// them; `list` allows a list.
fn strings(file: &str, field: &str, value: &toml::Value, list: bool) -> Result<Vec<String>> {
    let one = |v: &toml::Value, at: &str| match v {
        toml::Value::String(s) if !s.trim().is_empty() => Ok(s.trim().to_owned()),
        toml::Value::Integer(i) => Ok(i.to_string()),
        toml::Value::Float(x) => Ok(x.to_string()),
        other => Err(bad_input(format!(
            "{file}: {at}: {other} is not a name or a number"
        ))),
    };
    match value {
        toml::Value::Array(items) if list => {
            if items.is_empty() {
                return Err(bad_input(format!("{file}: {field}: an empty list")));
            }
            items
                .iter()
                .enumerate()
                .map(|(i, v)| one(v, &format!("{field}[{i}]")))
                .collect()
        }
        toml::Value::Array(_) => Err(bad_input(format!(
            "{file}: {field}: one value here, not a list"
        ))),
        v => Ok(vec![one(v, field)?]),
    }
}

fn unsigned(file: &str, field: &str, text: &str) -> Result<u64> {
    text.parse::<u64>().map_err(|_| {
        bad_input(format!(
            "{file}: {field}: {text} is not a non-negative integer"
        ))
    })
}

fn check_keys(file: &str, table: &toml::Table, prefix: &str, valid: &[&str]) -> Result<()> {
    match table.keys().find(|k| !valid.contains(&k.as_str())) {
        Some(k) => Err(bad_input(format!(
            "{file}: {prefix}{k}: unknown field (valid: {})",
            valid.join(", ")
        ))),
        None => Ok(()),
    }
}

/// A cell's folder name from its parameters: letters, digits and `.+-` only.
fn cell_name(c: &Cell) -> String {
    let mut name = format!(
        "{}_{}_{}_{}_{}_r{}_s{}",
        c.platform, c.controller, c.interface, c.disturbances, c.task, c.rollouts, c.seed
    );
    if c.episode_length != "script" {
        name.push_str(&format!("_e{}", c.episode_length));
    }
    name.chars()
        .map(|ch| match ch {
            ',' => '+',
            ch if ch.is_ascii_alphanumeric() || "._+-".contains(ch) => ch,
            _ => '-',
        })
        .collect()
}

/// The parsed sweep: its cells and the vehicle files they add.
#[derive(Debug)]
struct Sweep {
    cells: Vec<Cell>,
    vehicles: Vec<PathBuf>,
    skipped: Vec<String>,
}

fn read_sweep(path: &Path) -> Result<Sweep> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| bad_input(format!("{file}: cannot read it: {e}")))?;
    let doc: toml::Table = toml::from_str(&text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1));
        bad_input(format!(
            "{file}{}: {}",
            line.map(|l| format!(" line {l}")).unwrap_or_default(),
            e.message()
        ))
    })?;
    check_keys(&file, &doc, "", &["vehicles", "grid", "run"])?;
    let base = path.parent().unwrap_or(Path::new("."));
    let vehicles: Vec<PathBuf> = match doc.get("vehicles") {
        None => Vec::new(),
        Some(v) => strings(&file, "vehicles", v, true)?
            .into_iter()
            .map(|p| base.join(p))
            .collect(),
    };
    let mut cells = Vec::new();
    let mut skipped = Vec::new();
    if let Some(grid) = doc.get("grid") {
        let grid = grid
            .as_table()
            .ok_or_else(|| bad_input(format!("{file}: grid: a table ([grid])")))?;
        check_keys(&file, grid, "grid.", &GRID_KEYS)?;
        let axis = |key: &str, default: &str| -> Result<Vec<String>> {
            match grid.get(key) {
                Some(v) => strings(&file, &format!("grid.{key}"), v, true),
                None => Ok(vec![default.to_owned()]),
            }
        };
        let skip_unavailable = match grid.get("skip_unavailable") {
            None => false,
            Some(toml::Value::Boolean(b)) => *b,
            Some(v) => {
                return Err(bad_input(format!(
                    "{file}: grid.skip_unavailable: {v} is not true or false"
                )));
            }
        };
        let rollouts = axis("rollouts", "10")?
            .iter()
            .map(|r| unsigned(&file, "grid.rollouts", r))
            .collect::<Result<Vec<_>>>()?;
        let seeds = axis("seeds", "0")?
            .iter()
            .map(|s| unsigned(&file, "grid.seeds", s))
            .collect::<Result<Vec<_>>>()?;
        let (platforms, controllers, interfaces) = (
            axis("platforms", "ee-only")?,
            axis("controllers", "default")?,
            axis("interfaces", "ee")?,
        );
        let (disturbances, tasks, lengths) = (
            axis("disturbances", "none")?,
            axis("tasks", "all")?,
            axis("episode_length", "script")?,
        );
        let mut k = 0;
        for p in &platforms {
            for c in &controllers {
                for i in &interfaces {
                    for d in &disturbances {
                        for t in &tasks {
                            for r in &rollouts {
                                for s in &seeds {
                                    for e in &lengths {
                                        k += 1;
                                        let cell = Cell {
                                            name: String::new(),
                                            platform: p.clone(),
                                            controller: c.clone(),
                                            interface: i.clone(),
                                            disturbances: d.clone(),
                                            task: t.clone(),
                                            rollouts: usize::try_from(*r).unwrap_or(usize::MAX),
                                            seed: *s,
                                            episode_length: e.clone(),
                                            origin: format!("grid cell {k}"),
                                        };
                                        match resolve(&file, cell, &vehicles)? {
                                            Resolved::Cell(cell) => cells.push(cell),
                                            Resolved::Unavailable(why) if skip_unavailable => {
                                                skipped.push(why);
                                            }
                                            Resolved::Unavailable(why) => {
                                                return Err(bad_input(format!(
                                                    "{file}: {why} (list explicit [[run]]s, or set grid.skip_unavailable = true)"
                                                )));
                                            }
                                        }
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    if let Some(runs) = doc.get("run") {
        let runs = runs
            .as_array()
            .ok_or_else(|| bad_input(format!("{file}: run: a list of tables ([[run]])")))?;
        for (n, run) in runs.iter().enumerate() {
            let at = format!("run[{n}]");
            let run = run
                .as_table()
                .ok_or_else(|| bad_input(format!("{file}: {at}: a table")))?;
            check_keys(&file, run, &format!("{at}."), &RUN_KEYS)?;
            let field = |key: &str, default: &str| -> Result<String> {
                match run.get(key) {
                    Some(v) => Ok(strings(&file, &format!("{at}.{key}"), v, false)?.remove(0)),
                    None => Ok(default.to_owned()),
                }
            };
            let rollouts = unsigned(&file, &format!("{at}.rollouts"), &field("rollouts", "10")?)?;
            let cell = Cell {
                name: field("name", "")?,
                platform: field("platform", "ee-only")?,
                controller: field("controller", "default")?,
                interface: field("interface", "ee")?,
                disturbances: field("disturbances", "none")?,
                task: field("task", "all")?,
                rollouts: usize::try_from(rollouts).unwrap_or(usize::MAX),
                seed: unsigned(&file, &format!("{at}.seed"), &field("seed", "0")?)?,
                episode_length: field("episode_length", "script")?,
                origin: at.clone(),
            };
            if !cell.name.is_empty()
                && !cell
                    .name
                    .chars()
                    .all(|ch| ch.is_ascii_alphanumeric() || "._+-".contains(ch))
            {
                return Err(bad_input(format!(
                    "{file}: {at}.name: {:?} is not a folder name (letters, digits, . _ + -)",
                    cell.name
                )));
            }
            match resolve(&file, cell, &vehicles)? {
                Resolved::Cell(cell) => cells.push(cell),
                Resolved::Unavailable(why) => return Err(bad_input(format!("{file}: {why}"))),
            }
        }
    }
    if cells.is_empty() {
        return Err(bad_input(format!(
            "{file}: no cells: give a [grid] or [[run]]s{}",
            if skipped.is_empty() {
                ""
            } else {
                " (every grid cell is unavailable)"
            }
        )));
    }
    let mut seen = BTreeSet::new();
    for c in &cells {
        if !seen.insert(c.name.clone()) {
            return Err(bad_input(format!(
                "{file}: {}: cell {} is already in the sweep",
                c.origin, c.name
            )));
        }
    }
    Ok(Sweep {
        cells,
        vehicles,
        skipped,
    })
}

enum Resolved {
    Cell(Cell),
    /// The platform lacks the controller or interface (why).
    Unavailable(String),
}

/// Resolves `default`, names the cell, and validates it as `amstack bench` does.
fn resolve(file: &str, mut cell: Cell, vehicles: &[PathBuf]) -> Result<Resolved> {
    let at = |cell: &Cell, e: &anyhow::Error| {
        bad_input(format!(
            "{file}: {} ({} {} {} {} {}): {}",
            cell.origin,
            cell.platform,
            cell.controller,
            cell.interface,
            cell.disturbances,
            cell.task,
            crate::cli_error::one_line(e)
        ))
    };
    let vehicle =
        crate::vehicles::find_vehicle(vehicles, &cell.platform).map_err(|e| at(&cell, &e))?;
    let valid = crate::bench::controllers_for(&vehicle);
    if cell.controller == "default" {
        cell.controller = valid[0].to_owned();
    }
    let unavailable = if !valid.contains(&cell.controller.as_str()) {
        Some(format!(
            "controller {} is not available on {} (valid: {})",
            cell.controller,
            cell.platform,
            valid.join(", ")
        ))
    } else if cell.interface == "joint"
        && (vehicle.ee_link == vehicle.base_link || cell.controller == "mpc")
    {
        Some(format!(
            "the joint interface is not available with {} on {}",
            cell.controller, cell.platform
        ))
    } else {
        None
    };
    if let Some(why) = unavailable {
        return Ok(Resolved::Unavailable(format!("{}: {why}", cell.origin)));
    }
    if cell.name.is_empty() {
        cell.name = cell_name(&cell);
    }
    let args = bench_args(&cell.bench_flags(vehicles)).map_err(|e| at(&cell, &e))?;
    crate::bench::config(&args).map_err(|e| at(&cell, &e))?;
    Ok(Resolved::Cell(cell))
}

// ---- running ------------------------------------------------------------------------------

/// Whether `dir` holds the completed results of `config`; an error if it holds another
/// configuration's.
fn completed(dir: &Path, config: &Value, cell: &str) -> Result<bool> {
    let path = dir.join("results.json");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(false);
    };
    let Ok(results) = serde_json::from_str::<Value>(&text) else {
        return Ok(false);
    };
    if results["config"] != *config {
        return Err(bad_input(format!(
            "cell {cell}: {} holds a run of another configuration; use another --out or remove it",
            path.display()
        )));
    }
    Ok(results["status"] == "completed")
}

fn progress(total: u64) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} rollouts ({eta} left) {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar
}

/// The number of rollouts of a cell (tasks × rollouts).
fn cell_rollouts(cell: &Cell, vehicles: &[PathBuf]) -> Result<usize> {
    let args = bench_args(&cell.bench_flags(vehicles))?;
    let config = crate::bench::config(&args)?;
    Ok(config.tasks.len() * config.rollouts)
}

/// Runs the cells not yet completed here, each on `jobs` threads.
fn run_local(
    sweep: &Sweep,
    todo: &[&Cell],
    out: &Path,
    jobs: usize,
    stop: &AtomicBool,
) -> Result<()> {
    let mut total = 0;
    for c in todo {
        total += cell_rollouts(c, &sweep.vehicles)?;
    }
    let bar = progress(total as u64);
    for (n, cell) in todo.iter().enumerate() {
        let dir = out.join("cells").join(&cell.name);
        let mut flags = cell.bench_flags(&sweep.vehicles);
        flags.extend([
            "--out".to_owned(),
            dir.to_string_lossy().into_owned(),
            "--jobs".to_owned(),
            jobs.to_string(),
        ]);
        let args = bench_args(&flags)?;
        let config = crate::bench::config(&args)?;
        crate::bench_results::check_out_dir(&dir)?;
        bar.set_message(format!("cell {}/{}: {}", n + 1, todo.len(), cell.name));
        let on_done = |_: &RolloutResult| bar.inc(1);
        let report = run_bench(&config, &on_done, stop)?;
        let results = crate::bench::results_json(&args, &config, &report)?;
        write_json(&dir.join("config.json"), &results["config"])?;
        write_json(&dir.join("results.json"), &results)?;
        if report.interrupted {
            bar.abandon();
            return Err(anyhow::Error::new(crate::bench::Interrupted));
        }
    }
    bar.finish_and_clear();
    Ok(())
}

/// The Python with Ray.
fn ray_python(args: &Args) -> Result<PathBuf> {
    let python = args
        .ray_python
        .clone()
        .or_else(|| std::env::var_os("AMSTACK_RAY_PYTHON").map(PathBuf::from))
        .or_else(|| {
            std::env::var_os("HOME")
                .map(|h| PathBuf::from(h).join(".cache/amstack-ray-venv/bin/python"))
        })
        .unwrap_or_else(|| PathBuf::from("python3"));
    if !python.is_file() {
        return Err(bad_input(format!(
            "--engine {}: no Python with Ray at {} (run scripts/setup-ray.sh, or give --ray-python)",
            args.engine,
            python.display()
        )));
    }
    Ok(python)
}

/// Runs the cells not yet completed as shards on Ray, through the driver script.
fn run_ray(args: &Args, sweep: &Sweep, todo: &[&Cell], address: Option<&str>) -> Result<()> {
    let python = ray_python(args)?;
    let amstack = std::env::current_exe()?;
    // Paths as given (the driver runs in this directory), so the cells' results name their
    // logs as the local engine's do.
    let out = args.out.clone();
    let mut cells = Vec::new();
    for c in todo {
        cells.push(json!({
            "name": c.name,
            "dir": out.join("cells").join(&c.name),
            "bench": c.bench_flags(&sweep.vehicles),
            "rollouts": cell_rollouts(c, &sweep.vehicles)?,
        }));
    }
    let plan = json!({
        "amstack": amstack,
        "shards": args.shards,
        "parts": out.join("parts"),
        "kill_once": args.kill_once,
        "cells": cells,
    });
    let plan_path = out.join("ray-plan.json");
    write_json(&plan_path, &plan)?;
    let driver = out.join("ray_sweep.py");
    write_bytes(&driver, RAY_DRIVER.as_bytes())?;
    let mut command = std::process::Command::new(&python);
    command.arg(&driver).arg("--plan").arg(&plan_path);
    if let Some(a) = address {
        command.arg("--address").arg(a);
    }
    let status = command
        .status()
        .map_err(|e| anyhow::anyhow!("cannot start {}: {e}", python.display()))?;
    if !status.success() {
        anyhow::bail!(
            "the Ray driver failed ({status}); completed cells are kept: run the sweep again to resume"
        );
    }
    Ok(())
}

// ---- summary ------------------------------------------------------------------------------

const CSV_HEADER: [&str; 17] = [
    "cell",
    "platform",
    "controller",
    "interface",
    "disturbances",
    "seed",
    "episode_length",
    "task",
    "rollouts",
    "successes",
    "success_rate",
    "subtask_completion",
    "norm_ee_error",
    "norm_base_error",
    "tilt_use_rad",
    "saturation_rate",
    "results",
];

fn figure(v: &Value) -> String {
    match v {
        Value::Null => String::new(),
        Value::String(s) => s.clone(),
        v => v.to_string(),
    }
}

fn summarize(sweep: &Sweep, out: &Path, wall_time_s: f64, engine: &str) -> Result<()> {
    let mut rows = Vec::new();
    let mut cells_json = Vec::new();
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "cell",
        "task",
        "rollouts",
        "SR (%)",
        "subtasks (%)",
        "norm. EE error",
        "tilt use (deg)",
        "saturation (%)",
    ]);
    for c in &sweep.cells {
        let path = out.join("cells").join(&c.name).join("results.json");
        let text = std::fs::read_to_string(&path)
            .map_err(|e| anyhow::anyhow!("cell {}: cannot read {}: {e}", c.name, path.display()))?;
        let results: Value = serde_json::from_str(&text)?;
        let mut tasks = serde_json::Map::new();
        for (task, t) in results["tasks"].as_object().into_iter().flatten() {
            let pick = |k: &str| t[k].clone();
            let row = vec![
                c.name.clone(),
                c.platform.clone(),
                c.controller.clone(),
                c.interface.clone(),
                c.disturbances.clone(),
                c.seed.to_string(),
                c.episode_length.clone(),
                task.clone(),
                figure(&pick("rollouts")),
                figure(&pick("successes")),
                figure(&pick("success_rate")),
                figure(&pick("subtask_completion")),
                figure(&pick("norm_ee_error")),
                figure(&pick("norm_base_error")),
                figure(&pick("tilt_use_rad")),
                figure(&pick("saturation_rate")),
                format!("cells/{}/results.json", c.name),
            ];
            rows.push(row);
            table.add_row([
                c.name.clone(),
                task.clone(),
                figure(&pick("rollouts")),
                format_or_na(t["success_rate"].as_f64().map(|r| 100.0 * r), 2),
                format_or_na(t["subtask_completion"].as_f64().map(|r| 100.0 * r), 1),
                format_or_na(t["norm_ee_error"].as_f64(), 4),
                format_or_na(t["tilt_use_rad"].as_f64().map(f64::to_degrees), 2),
                format_or_na(t["saturation_rate"].as_f64().map(|r| 100.0 * r), 2),
            ]);
            tasks.insert(
                task.clone(),
                json!({
                    "rollouts": t["rollouts"],
                    "successes": t["successes"],
                    "success_rate": t["success_rate"],
                    "subtask_completion": t["subtask_completion"],
                    "norm_ee_error": t["norm_ee_error"],
                    "norm_base_error": t["norm_base_error"],
                    "tilt_use_rad": t["tilt_use_rad"],
                    "saturation_rate": t["saturation_rate"],
                }),
            );
        }
        cells_json.push(json!({
            "name": c.name,
            "platform": c.platform,
            "controller": c.controller,
            "interface": c.interface,
            "disturbances": c.disturbances,
            "task": c.task,
            "rollouts": c.rollouts,
            "seed": c.seed,
            "episode_length": c.episode_length,
            "status": results["status"],
            "results": format!("cells/{}/results.json", c.name),
            "tasks": tasks,
        }));
    }
    let mut csv = csv::Writer::from_writer(Vec::new());
    csv.write_record(CSV_HEADER)?;
    for row in &rows {
        csv.write_record(row)?;
    }
    let bytes = csv
        .into_inner()
        .map_err(|e| anyhow::anyhow!("summary.csv: {e}"))?;
    write_bytes(&out.join("summary.csv"), &bytes)?;
    write_json(
        &out.join("summary.json"),
        &json!({
            "engine": engine,
            "wall_time_s": wall_time_s,
            "skipped": sweep.skipped,
            "cells": cells_json,
        }),
    )?;
    println!("{table}");
    eprintln!(
        "{} cell(s) in {:.1} s ({engine}); wrote {}/summary.json and summary.csv",
        sweep.cells.len(),
        wall_time_s,
        out.display()
    );
    Ok(())
}

pub fn run(args: &Args) -> Result<()> {
    let started = Instant::now();
    let sweep = read_sweep(&args.file)?;
    let engine = match args.engine.as_str() {
        "local" => None,
        "ray" => Some(None),
        e => match e.strip_prefix("ray:") {
            Some(address) if !address.is_empty() => Some(Some(address.to_owned())),
            _ => {
                return Err(bad_input(format!(
                    "--engine {e}: not local, ray or ray:ADDRESS"
                )));
            }
        },
    };
    if args.shards == 0 {
        return Err(bad_input(
            "--shards 0: split each cell into at least 1 shard",
        ));
    }
    let jobs = match args.jobs {
        Some(0) => return Err(bad_input("--jobs 0: use at least one thread")),
        Some(j) => j,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    for s in &sweep.skipped {
        eprintln!("sweep: skipped {s}");
    }
    if args.dry_run {
        for c in &sweep.cells {
            println!(
                "{}\tamstack bench {}",
                c.name,
                c.bench_flags(&sweep.vehicles).join(" ")
            );
        }
        return Ok(());
    }
    std::fs::create_dir_all(args.out.join("cells")).map_err(|e| {
        bad_input(format!(
            "--out {}: cannot create it: {e}",
            args.out.display()
        ))
    })?;
    // The plan: every cell's bench flags, for people and for other engines.
    let plan: Vec<Value> = sweep
        .cells
        .iter()
        .map(|c| json!({ "name": c.name, "bench": c.bench_flags(&sweep.vehicles) }))
        .collect();
    write_json(
        &args.out.join("plan.json"),
        &json!({ "sweep": args.file, "cells": plan }),
    )?;
    let mut todo = Vec::new();
    for c in &sweep.cells {
        let dir = args.out.join("cells").join(&c.name);
        let bench = bench_args(&c.bench_flags(&sweep.vehicles))?;
        let config = crate::bench::config(&bench)?;
        let config = crate::bench::config_json(&bench, &config)?;
        if completed(&dir, &config, &c.name)? {
            continue;
        }
        todo.push(c);
    }
    eprintln!(
        "sweep: {} cell(s), {} to run ({} completed before), engine {}",
        sweep.cells.len(),
        todo.len(),
        sweep.cells.len() - todo.len(),
        args.engine
    );
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    if !todo.is_empty() {
        match &engine {
            None => run_local(&sweep, &todo, &args.out, jobs, &stop)?,
            Some(address) => run_ray(args, &sweep, &todo, address.as_deref())?,
        }
    }
    summarize(
        &sweep,
        &args.out,
        started.elapsed().as_secs_f64(),
        &args.engine,
    )
}
