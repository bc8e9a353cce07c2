//! `amstack`: the command line of the amstack flight stack.
//!
//! Thin by design: it parses flags, reads files, calls the crates and writes results.
//! Exit codes: 0 success, 2 bad input (one line on stderr naming what was wrong), 1 failure.

mod bench;
mod bench_results;
mod bench_shard;
mod camera_flags;
mod cli_error;
mod compare;
mod dataset_cmd;
mod experiment;
mod flag_line;
mod fly;
mod mpc_bench;
mod output;
mod platforms;
mod plot;
mod policy_flags;
mod px4_hil;
mod record;
mod render_frame;
mod replay;
mod sweep;
mod track;
mod twin_flags;
mod twin_serve;
mod vehicles;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use crate::cli_error::BadInput;

/// amstack — flight stack and simulator twin for multirotor aerial manipulators (AM-Bench).
///
/// The same allocation, saturation and control code flies the simulator twin or a PX4-style
/// autopilot. Every command exits 0 on success and 2 on bad input, with a one-line error.
#[derive(Debug, Parser)]
#[command(
    name = "amstack",
    version,
    propagate_version = true,
    max_term_width = 100
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The vehicles and their figures: mass, inertia, rotors, reach, thrust margins.
    Platforms(platforms::Args),
    /// The benchmark: tasks x rollouts of the scripted policies on a platform and
    /// controller -> success rate, subtasks, tracking and limit metrics (table, JSON, MCAP).
    Bench(Box<bench::Args>),
    /// Fly a reference trajectory in the twin and report tracking errors, tilt and
    /// saturation: the validation experiments of the paper.
    Track(Box<track::Args>),
    /// The flight stack of `track` against a chosen link: the twin in this process
    /// (`--link twin`), in another process over iceoryx2 (`--link ipc:<service>`), or a
    /// PX4-style autopilot over MAVLink (`--link mavlink:udp:HOST:PORT`, `serial:DEV:BAUD`...).
    Fly(Box<fly::FlyArgs>),
    /// The twin on its own: `amstack twin serve` offers it to a flight process over iceoryx2.
    Twin(twin_serve::TwinArgs),
    /// Solve time of the whole-body MPC per QP path on its standard scenario (FA-Hexa, EE step
    /// near a wall): median/p90/p99/max per RTI step, QP iterations, cost, violation.
    MpcBench(mpc_bench::Args),
    /// Re-fly a logged flight (MCAP) in the twin from its logged initial state: its actions
    /// through the whole flight stack, or its actuator commands open loop.
    Replay(Box<replay::Args>),
    /// One camera frame to a PNG: a vehicle's EE or base camera, or the scene camera, in a
    /// task scene at reset (seeded), with or without visual randomisation.
    Render(Box<render_frame::Args>),
    /// Compare two flight logs signal by signal: RMSE, max error and bias over the whole
    /// overlap and over intervals; table, JSON, PNG plot.
    Compare(Box<compare::Args>),
    /// PX4's control-allocation parameters of a vehicle (CA_ROTOR*, THR_MDL_FAC,
    /// MPC_THR_HOVER, output functions of its HIL channels) as an airframe-file snippet.
    Px4Airframe(px4_hil::AirframeArgs),
    /// A grid of benchmark runs from a sweep file (platforms x controllers x interfaces x
    /// disturbances x tasks x rollouts x seeds): locally on all cores or as shards on a Ray
    /// cluster; one results folder per cell and a summary table (terminal, JSON, CSV).
    Sweep(Box<sweep::Args>),
    /// The paper's experiments as one command each (`embodiment`, `actuator`,
    /// `ground-effect`, `wrench-limit`): tables (terminal, JSON) and PNG plots in an output
    /// folder.
    Experiment(Box<experiment::Args>),
    /// Record demonstrations of a task's scripted policy (the rollouts of `bench`) as a
    /// LeRobot v3.0 dataset: observation state, actions, task prompt (120 fps).
    Record(Box<record::Args>),
    /// LeRobot datasets: `info`, `validate`, `export-openpi` (v2.1, 20 Hz), `merge`.
    Dataset(dataset_cmd::Args),
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // --help and --version print to stdout and succeed.
        Err(e) if !e.use_stderr() => {
            let _ = e.print();
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            // clap's message is several lines (usage, hint); keep the first, the problem.
            let rendered = e.render().to_string();
            let mut lines = rendered.lines().filter(|l| !l.trim().is_empty());
            let first = lines.next().unwrap_or("invalid arguments");
            let first = first.strip_prefix("error: ").unwrap_or(first);
            // "the following required arguments were not provided:" names them on the next line.
            let more = match lines.next() {
                Some(next) if first.ends_with(':') => format!(" {}", next.trim()),
                _ => String::new(),
            };
            eprintln!("amstack: {first}{more} (see 'amstack --help')");
            return ExitCode::from(2);
        }
    };
    let result = match cli.command {
        Command::Platforms(args) => platforms::run(&args),
        Command::Bench(args) => bench::run(&args),
        Command::Track(args) => track::run(&args),
        Command::Fly(args) => fly::run(&args),
        Command::Twin(args) => twin_serve::run(&args),
        Command::MpcBench(args) => mpc_bench::run(&args),
        Command::Replay(args) => replay::run(&args),
        Command::Compare(args) => compare::run(&args),
        Command::Px4Airframe(args) => px4_hil::run_airframe(&args),
        Command::Render(args) => render_frame::run(&args),
        Command::Sweep(args) => sweep::run(&args),
        Command::Experiment(args) => experiment::run(&args),
        Command::Record(args) => record::run(&args),
        Command::Dataset(args) => dataset_cmd::run(&args),
    };
    match result {
        Ok(()) => {
            for warning in vehicles::take_warnings() {
                eprintln!("amstack: warning: {warning}");
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            let interrupted = matches!(
                e.downcast_ref::<policy_runtime::TrackError>(),
                Some(policy_runtime::TrackError::Interrupted { .. })
            ) || e.downcast_ref::<bench::Interrupted>().is_some();
            let code = if e.downcast_ref::<BadInput>().is_some() {
                2
            } else if interrupted {
                // The shell's convention for a run stopped by SIGINT.
                130
            } else {
                1
            };
            eprintln!("amstack: {}", cli_error::one_line(&e));
            ExitCode::from(code)
        }
    }
}
