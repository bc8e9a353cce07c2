//! `amstack replay`: re-fly a logged flight in the twin.

use std::path::PathBuf;

use anyhow::Result;
use policy_runtime::validation::replay::{LoggedFlight, check_replay, controller_profile};
use policy_runtime::validation::{
    LogFileError, ReplayConfig, ReplayError, ReplayMode, ReplayResult, read_flight_log,
    replay_flight,
};
use sim_twin::Disturbances;

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};
use crate::vehicles::find_vehicle;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
The configuration of the logged run comes from its amstack.run metadata record (vehicle,
controller and gains, twin configuration: disturbances, motor model, seed, scene); the flags
override it, and each override is printed. The twin starts from the logged initial state.

Modes:
  reference  the logged actions (/action; or the EE/base references) through the whole
             flight stack: IK, base controller, allocation (closed loop)
  commands   the logged actuator commands (/rotors commanded thrusts, /joints targets)
             applied open loop: isolates the plant model

Examples:
  amstack track --platform fa-hexa --trajectory ground-sweep --interface ee \\
      --disturbances ground --ground-effect-k 3.4 --mcap real.mcap
  amstack replay real.mcap --disturbances none --out sim.mcap
  amstack compare real.mcap sim.mcap --signal /ee/pose.pose.position.z \\
      --interval 'z_ref<=0.7' --interval 'z_ref>=0.9'")]
pub struct Args {
    /// The flight log to replay (MCAP).
    #[arg(value_name = "LOG.mcap")]
    log: PathBuf,
    /// What to feed the twin.
    #[arg(long, default_value = "reference", value_parser = ["reference", "commands"])]
    mode: String,
    /// Fly another vehicle than the logged one.
    #[arg(long)]
    platform: Option<String>,
    /// Fly another controller (pid, l1, mpc: the reference gains) than the logged one.
    #[arg(long, value_parser = ["pid", "l1", "mpc"])]
    controller: Option<String>,
    /// Replace the logged disturbances (the names of `amstack track --help`).
    #[arg(long, value_name = "LIST")]
    disturbances: Option<String>,
    /// Replace the logged ground-effect intensity k (the paper's rho).
    #[arg(long, value_name = "K")]
    ground_effect_k: Option<f64>,
    /// Replace the logged seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Use the readable part of a truncated or damaged log.
    #[arg(long)]
    allow_truncated: bool,
    /// The replay's flight log (MCAP, same format).
    #[arg(long, value_name = "SIM.mcap")]
    out: PathBuf,
    /// Write what the replay did as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
}

/// An unusable log is bad input (exit 2), its message naming the file.
pub(crate) fn log_error(e: &LogFileError) -> anyhow::Error {
    bad_input(e.to_string())
}

/// A replay ready to fly: the logged flight, the replay's configuration (the log's, with the
/// flags' overrides), and the overrides in words.
#[derive(Debug)]
pub(crate) struct Prepared {
    pub logged: LoggedFlight,
    pub config: ReplayConfig,
    pub overrides: Vec<String>,
}

/// Reads the log and builds the replay of `args`: every bad-input error (an unreadable log,
/// an unknown vehicle, a bad override), before anything is flown.
pub(crate) fn prepare(args: &Args) -> Result<Prepared> {
    check_writable("--out", &args.out)?;
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    if std::fs::canonicalize(&args.out).ok() == std::fs::canonicalize(&args.log).ok()
        && args.out.exists()
    {
        return Err(bad_input(format!(
            "--out {}: is the log being replayed; choose another file",
            args.out.display()
        )));
    }
    let file = read_flight_log(&args.log, args.allow_truncated).map_err(|e| log_error(&e))?;
    let logged = LoggedFlight::from_log(&file).map_err(|e| bad_input(e.to_string()))?;
    let name = args.log.display();
    let run = &logged.run;
    let mut overrides = Vec::new();
    let vehicle_id = match &args.platform {
        Some(p) if *p != run.vehicle_id => {
            overrides.push(format!("platform {} -> {p}", run.vehicle_id));
            p.clone()
        }
        _ => run.vehicle_id.clone(),
    };
    let vehicle = find_vehicle(&args.vehicles, &vehicle_id)?;
    let mut twin = logged
        .twin_config()
        .map_err(|e| bad_input(format!("{name}: {e}")))?;
    let controller = match &args.controller {
        Some(c) => {
            overrides.push(format!("controller {} -> {c}", run.controller));
            controller_profile(&vehicle, c).map_err(|e| bad_input(format!("--controller: {e}")))?
        }
        // Another vehicle flies its own reference gains for the logged controller.
        None if vehicle.id != run.vehicle_id => controller_profile(&vehicle, &run.controller)
            .map_err(|e| bad_input(format!("--platform {}: {e}", vehicle.id)))?,
        None => logged
            .controller_config(&vehicle)
            .map_err(|e| bad_input(format!("{name}: {e}")))?,
    };
    if let Some(list) = &args.disturbances {
        let d = Disturbances::parse_list(list)
            .map_err(|e| bad_input(format!("--disturbances: {e}")))?;
        overrides.push(format!(
            "disturbances {} -> {}",
            names(&twin.disturbances),
            names(&d)
        ));
        twin.disturbances = d;
    }
    if let Some(k) = args.ground_effect_k {
        overrides.push(format!(
            "ground-effect k {} -> {k}",
            twin.aero.ground_effect_k
        ));
        twin.aero.ground_effect_k = k;
    }
    if let Some(seed) = args.seed {
        overrides.push(format!("seed {} -> {seed}", twin.seed));
        twin.seed = seed;
    }
    twin.validate()
        .map_err(|e| bad_input(format!("twin configuration after overrides: {e}")))?;
    let mode = if args.mode == "commands" {
        ReplayMode::Commands
    } else {
        ReplayMode::Reference
    };
    let config = ReplayConfig {
        vehicle,
        controller,
        twin,
        mode,
        out: args.out.clone(),
    };
    check_replay(&logged, &config).map_err(|e| bad_input(e.to_string()))?;
    Ok(Prepared {
        logged,
        config,
        overrides,
    })
}

/// Flies a prepared replay; a log the stack cannot replay is bad input.
pub(crate) fn fly(p: &Prepared) -> Result<ReplayResult> {
    replay_flight(&p.logged, &p.config).map_err(|e| match e {
        ReplayError::Log { .. } | ReplayError::Stack(_) => bad_input(e.to_string()),
        other => anyhow::Error::new(other),
    })
}

pub fn run(args: &Args) -> Result<()> {
    let prepared = prepare(args)?;
    let Prepared {
        logged,
        config,
        overrides,
    } = &prepared;
    let (run, mode, name) = (&logged.run, config.mode, args.log.display());
    eprintln!(
        "replaying {} ({} ticks, {} on {}, {} interface) in {} mode, disturbances: {}",
        name,
        logged.ticks(),
        run.controller,
        run.vehicle_id,
        run.interface.as_deref().unwrap_or("unknown"),
        mode.name(),
        names(&config.twin.disturbances)
    );
    for o in overrides {
        eprintln!("  override: {o}");
    }
    let result = fly(&prepared)?;
    if !result.actions_from_action_channel && mode == ReplayMode::Reference {
        eprintln!(
            "  note: the log has no /action channel; actions rebuilt from the references (gripper closed)"
        );
    }
    if result.initial_state_from_log {
        eprintln!("  the twin starts from the logged initial state");
    }
    if let Some(m) = result.initial_joint_mismatch.filter(|m| *m > 1e-6) {
        eprintln!(
            "  note: the twin's initial joints differ from the logged ones by up to {m:.4} rad or m"
        );
    }
    if let Some(why) = &result.stopped_early {
        eprintln!(
            "  stopped after {} of {} ticks: {why}",
            result.replayed_ticks, result.logged_ticks
        );
    }
    eprintln!(
        "replayed {} ticks; wrote {}",
        result.replayed_ticks,
        result.out.display()
    );
    if let Some(path) = &args.json {
        write_json(path, &serde_json::to_value(&result)?)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn names(d: &Disturbances) -> String {
    let n = d.names();
    if n.is_empty() {
        "none".to_owned()
    } else {
        n.join(",")
    }
}
