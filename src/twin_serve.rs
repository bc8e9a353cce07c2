//! `amstack twin serve`: the twin alone in its process, offered over iceoryx2 shared memory
//! (`--ipc`) or as a PX4-style autopilot over MAVLink 2 (`--mavlink`).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Result;
use platform::{ActuatorCommand, Vehicle};
use policy_runtime::live::LiveServer;
use policy_runtime::record::McapRecorder;
use policy_runtime::twin_view::TwinView;
use sim_twin::ipc::{Mode, ServeConfig, ServeError, TwinServer};
use sim_twin::{Twin, TwinConfig, TwinObserver};
use twin_autopilot::{
    Autopilot, AutopilotConfig, AutopilotError, Endpoint, RealtimePolicy, Signing,
};

use crate::cli_error::bad_input;
use crate::track::{finish_live, start_live};
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
    /// process at a time (`--ipc`, for `amstack fly --link ipc:<service>`), or as a PX4-style
    /// autopilot over MAVLink 2 (`--mavlink`, for `amstack fly --link mavlink:…`, a ground
    /// station, or any offboard program), or as PX4's simulator (`--px4-hil`, for PX4 SITL).
    Serve(Box<ServeArgs>),
}

#[derive(Debug, clap::Args)]
#[command(after_help = "\
IPC (--ipc). Lockstep (the default, PX4's SITL contract): the twin advances exactly one control period
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
  amstack fly --link ipc:sitl --platform fa-hexa --trajectory step --json r.json

MAVLINK (--mavlink): the twin is a PX4 vehicle, MAVLink 2 system 1 component 1 (MAVLink 1 to
a peer until it speaks MAVLink 2): HEARTBEAT (PX4 custom modes), SYS_STATUS (health),
EXTENDED_SYS_STATE, ATTITUDE, GLOBAL_POSITION_INT, GPS_RAW_INT, ALTITUDE, HOME_POSITION,
MISSION_CURRENT, and at every twin step DEBUG_FLOAT_ARRAY 'joints', ACTUATOR_OUTPUT_STATUS
(newtons), HIGHRES_IMU, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, ODOMETRY. Parameters
(PARAM_*: COM_OF_LOSS_T, COM_OBL_RC_ACT, MPC_*, MIS_TAKEOFF_ALT, NAV_ACC_RAD, RTL_RETURN_ALT,
MC_*RATE_MAX), missions (MISSION_INT; AUTO.MISSION flies takeoff, waypoints, land, RTL),
COMMAND_LONG and COMMAND_INT (arm, modes, NAV_TAKEOFF, DO_REPOSITION, NAV_RETURN_TO_LAUNCH,
NAV_LAND, MISSION_START...). OFFBOARD (only while setpoints stream) flies what PX4 accepts:
SET_POSITION_TARGET_LOCAL_NED (position, velocity, acceleration; its own PID) and
SET_ATTITUDE_TARGET (attitude or body rates, thrust or thrust_body; its own attitude loop).
SET_ACTUATOR_CONTROL_TARGET (groups 0 motors, 1 tilts, 2 arm + gripper), which current PX4
does not have, only with --allow-actuator-setpoints. Every command gets a COMMAND_ACK,
refusals a STATUSTEXT with the reason. It starts disarmed in POSCTL,
level, 1 m up (the benchmark's reset); POSCTL and AUTO modes hold/land with its own PID.
With --lockstep (what SITL tests use) the twin steps once per setpoint tick while armed in
OFFBOARD; with --realtime it runs on the wall clock from the first arming.
Failsafe: armed in OFFBOARD and no setpoint for --offboard-timeout-ms -> AUTO.LOITER (hold
the position) for --failsafe-hold-s -> AUTO.LAND at 0.5 m/s -> disarm on the ground; each
step is logged on stderr with the twin time. Bad input (CRC, unknown ids, truncated frames,
unsigned frames when signing is required) is counted: SYS_STATUS errors_comm and
drop_rate_comm, and a line on stderr at exit. The contract: docs/mavlink.md.

Example with pymavlink as the ground station (QGroundControl: add a UDP link to server
127.0.0.1:14540 and it shows the vehicle):
  amstack twin serve --mavlink udp:127.0.0.1:14540 --platform fa-hexa --realtime &
  PY=$(bash scripts/setup-python.sh)    # a venv with pymavlink
  $PY scripts/mavlink_gcs.py rates --connect udpout:127.0.0.1:14540 --seconds 3
  (it measures the message rates, requests AUTOPILOT_VERSION, arms and disarms: JSON)

PX4 HIL (--px4-hil): the twin is PX4's simulator. PX4 SITL's simulator_mavlink connects over
TCP; the twin sends HIL_SENSOR, HIL_GPS, HIL_STATE_QUATERNION and applies HIL_ACTUATOR_CONTROLS
through the vehicle file's [px4_hil] channel map, in lockstep (one reply per HIL_SENSOR) or
--realtime. The vehicle is held at its start until PX4 arms. `amstack px4-airframe` prints
the vehicle's PX4 parameters. The contract: docs/px4-hil.md.
  amstack twin serve --px4-hil tcp:0.0.0.0:4560 --platform fa-hexa --task wipe-window --mcap hil.mcap")]
#[command(group(clap::ArgGroup::new("link").required(true).args(["ipc", "mavlink", "px4_hil"])))]
pub struct ServeArgs {
    /// iceoryx2 service name the flight process connects to (`--link ipc:<NAME>`).
    #[arg(long, value_name = "NAME")]
    ipc: Option<String>,
    /// Serve as a PX4-style autopilot over MAVLink 2: bind a UDP port (telemetry goes to
    /// every peer heard from) or open a serial device.
    #[arg(long, value_name = "udp:HOST:PORT|serial:DEVICE:BAUD")]
    mavlink: Option<String>,
    /// Serve as PX4's simulator (PX4 SITL's simulator_mavlink connects here over TCP; HIL
    /// messages, lockstep): docs/px4-hil.md.
    #[arg(long, value_name = "tcp:HOST:PORT")]
    px4_hil: Option<String>,
    /// --px4-hil lockstep: before PX4's first reply, how long each HIL_SENSOR waits for one
    /// (default one control period: PX4 boots in real time), ms.
    #[arg(long, value_name = "MS", requires = "px4_hil")]
    first_reply_ms: Option<u64>,
    /// --px4-hil: the MCAP log of the sessions (FILE, then FILE-2.mcap, ...).
    #[arg(long, value_name = "FILE", requires = "px4_hil")]
    mcap: Option<PathBuf>,
    /// Vehicle id (ua-quad, ua-hexa, fa-hexa, omni-hexa, ee-only, or one added with --vehicle).
    #[arg(long, default_value = "fa-hexa")]
    platform: String,
    /// Advance one control period per command (the default).
    #[arg(long, conflicts_with = "realtime")]
    lockstep: bool,
    /// Run on the wall clock at the control rate, applying the latest command.
    #[arg(long)]
    realtime: bool,
    /// --ipc: how long a lost flight process's last command is held before the failsafe, ms.
    #[arg(long, value_name = "MS", default_value_t = 500)]
    hold_ms: u64,
    /// --ipc, --px4-hil lockstep: a peer alive but silent this long counts as lost, ms.
    #[arg(long, value_name = "MS", default_value_t = 5000)]
    stall_ms: u64,
    /// --ipc: let each flight process choose its session's episode, the task scene and the
    /// seed (`amstack bench --link ipc:<NAME>` runs every rollout as a session); everything
    /// else must still match. Without it, sessions run --task and --seed.
    #[arg(long)]
    flight_chooses_episode: bool,
    /// --ipc, --px4-hil: exit after serving this many sessions (default: until Ctrl-C).
    #[arg(long, value_name = "N")]
    sessions: Option<u64>,
    /// --mavlink: armed in OFFBOARD, no setpoint for this long starts the failsafe (and
    /// OFFBOARD or arming in it are refused), ms.
    #[arg(long, value_name = "MS", default_value_t = 500)]
    offboard_timeout_ms: u64,
    /// --mavlink: how long the failsafe holds position before it lands, s.
    #[arg(long, value_name = "S", default_value_t = 5.0)]
    failsafe_hold_s: f64,
    /// --mavlink: MAVLink 2 signing key file: 32 raw bytes or 64 hexadecimal digits. Outgoing
    /// frames are signed; incoming signed frames are checked.
    #[arg(long, value_name = "FILE")]
    signing_key: Option<PathBuf>,
    /// --mavlink: refuse unsigned frames (needs --signing-key).
    #[arg(long, requires = "signing_key")]
    require_signing: bool,
    /// --mavlink: link id written into outgoing signatures.
    #[arg(long, value_name = "ID", default_value_t = 0)]
    signing_link_id: u8,
    /// --mavlink: accept SET_ACTUATOR_CONTROL_TARGET (motors, tilts, arm), a SITL extension:
    /// current PX4 has no actuator offboard over MAVLink. Off: refused with a STATUSTEXT.
    #[arg(long)]
    allow_actuator_setpoints: bool,
    /// --mavlink --realtime: when the twin cannot keep up with the wall clock (its real-time
    /// factor, printed once per second, below 0.98): warn (keep running at the slower pace)
    /// or fail (exit 1).
    #[arg(long, value_name = "warn|fail", default_value = "warn")]
    realtime_policy: String,
    /// --ipc, --mavlink, --px4-hil: stream the twin's own truth live over the Foxglove WebSocket protocol
    /// (the 3D scene, /tf, poses, base state, joints, rotors, disturbances, task state):
    /// open Foxglove, "Open connection", ws://ADDR. ADDR is IP:PORT [default: 127.0.0.1:8765].
    /// The twin never waits for a viewer: a full queue drops messages and counts them.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = policy_runtime::live::DEFAULT_LIVE_ADDR)]
    live: Option<String>,
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
    if let Some(link) = &args.mavlink {
        return run_mavlink(args, link);
    }
    if let Some(endpoint) = &args.px4_hil {
        let mut twin = args.twin.twin_config()?;
        args.scene.apply(&mut twin)?;
        let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
        let live = start_live(args.live.as_deref())?;
        let view = twin_view(live.as_deref(), &vehicle, &twin)?;
        let served = crate::px4_hil::run_serve(crate::px4_hil::Serve {
            endpoint: endpoint.clone(),
            vehicle,
            twin,
            mode: if args.realtime {
                Mode::Realtime
            } else {
                Mode::Lockstep
            },
            stall_ms: args.stall_ms,
            first_reply_ms: args.first_reply_ms,
            sessions: args.sessions,
            mcap: args.mcap.clone(),
            live: view,
        });
        finish_live(live.as_deref());
        return served;
    }
    let ipc = args.ipc.clone().unwrap_or_default();
    if ipc.is_empty() || ipc.contains(char::is_whitespace) {
        return Err(bad_input(format!(
            "--ipc '{ipc}': a service name without spaces"
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
        ..ServeConfig::new(ipc, mode)
    };
    let live = start_live(args.live.as_deref())?;
    let view = twin_view(live.as_deref(), &vehicle, &twin)?;
    let mut server = TwinServer::new(vehicle, twin, config).map_err(|e| match e {
        ServeError::Taken(_) | ServeError::TooLarge(_) => bad_input(e.to_string()),
        e => anyhow::Error::new(e),
    })?;
    if let Some(view) = view {
        server.set_observer(view);
    }
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let summary = server.run(&stop, |event| eprintln!("twin: {event}"))?;
    eprintln!(
        "twin: stopped after {} session(s), {} refused",
        summary.sessions, summary.refused
    );
    finish_live(live.as_deref());
    Ok(())
}

fn run_mavlink(args: &ServeArgs, link: &str) -> Result<()> {
    let endpoint = Endpoint::parse(link).map_err(|e| bad_input(format!("--mavlink {e}")))?;
    if !(args.failsafe_hold_s.is_finite() && args.failsafe_hold_s >= 0.0) {
        return Err(bad_input(format!(
            "--failsafe-hold-s {}: a duration in seconds, not negative",
            args.failsafe_hold_s
        )));
    }
    if args.offboard_timeout_ms == 0 {
        return Err(bad_input(
            "--offboard-timeout-ms 0: must be positive".to_owned(),
        ));
    }
    let realtime_policy = RealtimePolicy::parse(&args.realtime_policy)
        .map_err(|e| bad_input(format!("--realtime-policy {e}")))?;
    let signing = match &args.signing_key {
        None => None,
        Some(path) => {
            let bytes = std::fs::read(path).map_err(|e| {
                bad_input(format!(
                    "--signing-key {}: cannot read: {e}",
                    path.display()
                ))
            })?;
            let key = Signing::key_from_file_bytes(&bytes)
                .map_err(|e| bad_input(format!("--signing-key {}: {e}", path.display())))?;
            Some(Signing {
                key,
                link_id: args.signing_link_id,
                require: args.require_signing,
            })
        }
    };
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let mut twin = args.twin.twin_config()?;
    args.scene.apply(&mut twin)?;
    let mode = if args.realtime {
        Mode::Realtime
    } else {
        Mode::Lockstep
    };
    let config = AutopilotConfig {
        offboard_timeout: Duration::from_millis(args.offboard_timeout_ms),
        failsafe_hold_s: args.failsafe_hold_s,
        signing,
        allow_actuator_setpoints: args.allow_actuator_setpoints,
        realtime_policy,
        ..AutopilotConfig::new(endpoint, mode)
    };
    let live = start_live(args.live.as_deref())?;
    let view = twin_view(live.as_deref(), &vehicle, &twin)?;
    let mut autopilot = Autopilot::new(vehicle, twin, config).map_err(|e| match e {
        AutopilotError::Vehicle(_) | AutopilotError::Link(_) => {
            bad_input(format!("--mavlink: {e}"))
        }
        e => anyhow::Error::new(e),
    })?;
    if let Some(view) = view {
        autopilot.set_observer(view);
    }
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let ran = autopilot.run(&stop, |event| eprintln!("autopilot: {event}"));
    finish_live(live.as_deref());
    ran?;
    Ok(())
}

/// The twin's live view on `live`'s server (None without `--live`).
fn twin_view(
    live: Option<&LiveServer>,
    vehicle: &Vehicle,
    twin: &TwinConfig,
) -> Result<Option<Box<dyn TwinObserver>>> {
    let Some(live) = live else {
        return Ok(None);
    };
    let recorder = McapRecorder::file_less(live.tap());
    let view = TwinView::new(recorder, vehicle, twin.disturbances.saturation)?;
    Ok(Some(Box::new(Reporting {
        view,
        reported: false,
    })))
}

/// The live view, saying once on stderr when it stops on an error (the twin serves on).
#[derive(Debug)]
struct Reporting {
    view: TwinView,
    reported: bool,
}

impl Reporting {
    fn report(&mut self) {
        if !self.reported
            && let Some(e) = self.view.error()
        {
            eprintln!("twin: live view stopped: {e}");
            self.reported = true;
        }
    }
}

impl TwinObserver for Reporting {
    fn reset(&mut self, twin: &Twin) {
        self.view.reset(twin);
        self.report();
    }

    fn stepped(&mut self, twin: &Twin, command: &ActuatorCommand) {
        self.view.stepped(twin, command);
        self.report();
    }
}
