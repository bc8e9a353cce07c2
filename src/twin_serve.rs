//! `amstack twin serve`: the twin alone in its process, offered over iceoryx2 shared memory.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Result;
use sim_twin::ipc::{Mode, ServeConfig, ServeError, TwinServer};

use crate::cli_error::bad_input;
use crate::twin_flags::{SceneFlag, TwinFlags};
use crate::vehicles::find_vehicle;

#[derive(Debug, clap::Args)]
pub struct TwinArgs {
    #[command(subcommand)]
    command: TwinCommand,
}

#[derive(Debug, clap::Subcommand)]
enum TwinCommand {
    /// Run the twin in this process and serve it over iceoryx2 shared memory to one flight
    /// process at a time (`amstack fly --link ipc:<service>`).
    Serve(Box<ServeArgs>),
}

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Lockstep (the default, PX4's SITL contract): the twin advances exactly one control period
when the command for its current tick arrives, so a split-process flight is bit-identical
to the in-process one. Realtime: the twin steps on the wall clock at the control rate with
the latest command, as hardware would.

Every connection starts a session from the twin's reset state. The flight process must ask
for the same vehicle and twin settings (disturbances, motor model, seed...): a mismatch is
refused with both values named. If the flight process dies (or, in realtime, goes silent),
the twin holds its last command for --hold-ms, then applies the failsafe (disarm: rotors
0 N, joints held), runs 3 s more so the vehicle comes to rest, and waits for the next flight
process. Resources left under /dev/shm by crashed processes are removed at start.

Example:
  amstack twin serve --ipc sitl --platform fa-hexa &
  amstack fly --link ipc:sitl --platform fa-hexa --trajectory step --json r.json")]
pub struct ServeArgs {
    /// iceoryx2 service name the flight process connects to (`--link ipc:<NAME>`).
    #[arg(long, value_name = "NAME")]
    ipc: String,
    /// Vehicle id (ua-quad, ua-hexa, fa-hexa, omni-hexa, ee-only, or one added with --vehicle).
    #[arg(long, default_value = "fa-hexa")]
    platform: String,
    /// Advance one control period per command (the default).
    #[arg(long, conflicts_with = "realtime")]
    lockstep: bool,
    /// Run on the wall clock at the control rate, applying the latest command.
    #[arg(long)]
    realtime: bool,
    /// How long a lost flight process's last command is held before the failsafe, ms.
    #[arg(long, value_name = "MS", default_value_t = 500)]
    hold_ms: u64,
    /// Lockstep: a flight process alive but silent this long counts as lost, ms.
    #[arg(long, value_name = "MS", default_value_t = 5000)]
    stall_ms: u64,
    /// Let each flight process choose its session's episode, the task scene and the seed
    /// (`amstack bench --link ipc:<NAME>` runs every rollout as a session); everything else
    /// must still match. Without it, sessions run --task and --seed.
    #[arg(long)]
    flight_chooses_episode: bool,
    /// Exit after serving this many sessions (default: until Ctrl-C).
    #[arg(long, value_name = "N")]
    sessions: Option<u64>,
    /// The twin's settings, as in `amstack track`; every session starts from the seed.
    #[command(flatten)]
    twin: TwinFlags,
    #[command(flatten)]
    scene: SceneFlag,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
}

pub fn run(args: &TwinArgs) -> Result<()> {
    match &args.command {
        TwinCommand::Serve(serve) => run_serve(serve),
    }
}

fn run_serve(args: &ServeArgs) -> Result<()> {
    if args.ipc.is_empty() || args.ipc.contains(char::is_whitespace) {
        return Err(bad_input(format!(
            "--ipc '{}': a service name without spaces",
            args.ipc
        )));
    }
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let mut twin = args.twin.twin_config()?;
    args.scene.apply(&mut twin)?;
    let mode = if args.realtime {
        Mode::Realtime
    } else {
        Mode::Lockstep
    };
    let config = ServeConfig {
        hold: Duration::from_millis(args.hold_ms),
        stall_timeout: Duration::from_millis(args.stall_ms),
        max_sessions: args.sessions,
        flight_chooses_episode: args.flight_chooses_episode,
        ..ServeConfig::new(args.ipc.clone(), mode)
    };
    let mut server = TwinServer::new(vehicle, twin, config).map_err(|e| match e {
        ServeError::Taken(_) | ServeError::TooLarge(_) => bad_input(e.to_string()),
        e => anyhow::Error::new(e),
    })?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let summary = server.run(&stop, |event| eprintln!("twin: {event}"))?;
    eprintln!(
        "twin: stopped after {} session(s), {} refused",
        summary.sessions, summary.refused
    );
    Ok(())
}
