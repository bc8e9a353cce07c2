//! `amstack fly`: the flight stack of `amstack track` against a chosen link — the twin in this
//! process, the twin in another process over iceoryx2, or a PX4-style autopilot over MAVLink
//! (the twin's, `amstack twin serve --mavlink ...`, or a real vehicle).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use firmware_bridge::{Address, BridgeConfig, Signing, SigningKey};
use policy_runtime::bench::BenchLink;
use policy_runtime::ipc_link::TickTiming;
use policy_runtime::{
    IpcLink, IpcLinkConfig, Level, LinkError, MavlinkLink, MavlinkLinkConfig, TrackError,
    TrackResult, run_track_with_link,
};
use serde::Serialize;

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};
use crate::track;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Links:
  twin                   the twin in this process (as amstack track)
  ipc:<service>          the twin in another process: amstack twin serve --ipc <service> ...
  mavlink:udp:HOST:PORT  a PX4-style autopilot; we send to its UDP port (the twin's:
                         amstack twin serve --mavlink udp:HOST:PORT ...)
  mavlink:udpin:HOST:PORT  listen on HOST:PORT for the autopilot (PX4 companion style)
  mavlink:tcp:HOST:PORT  connect to the autopilot's TCP server
  mavlink:serial:DEVICE:BAUD  a serial port (mavlink:serial:/dev/ttyACM0:921600)

Over MAVLink (docs/mavlink.md) the bridge is system 1, component 191. It waits for the
autopilot's first ODOMETRY, streams the first setpoint, switches to OFFBOARD, arms, and then
sends one setpoint per control tick and waits for the ODOMETRY that closes it. --level
actuator sends rotor thrusts (SET_ACTUATOR_CONTROL_TARGET through the vehicle's thrust
curve, our allocation flies); --level attitude sends the controller's desired attitude and
body force (SET_ATTITUDE_TARGET, the autopilot's attitude loop and allocation fly). Arm and
gripper go in group 2 at both levels. A refused or unanswered command (arming, offboard)
stops the flight with the autopilot's answer, exit 1. At the end the bridge stops sending;
it never disarms (the autopilot's offboard-loss failsafe holds, then lands).
With --signing-key every frame is signed and unsigned or badly signed frames are refused.
With --mcap the log also holds /autopilot/state (mode, arming, status, the link's counters,
once per tick) and /mavlink/raw (every frame in and out, bytes as on the wire), see
docs/mcap-format.md.

A task flight (`--task T --trajectory scripted`) flies one benchmark rollout of the task's
scripted policy at --seed over any link; its result (success, steps, criteria, errors) is
bench's for that seed. Over MAVLink the twin's autopilot must serve the same task and seed
(`twin serve --mavlink ... --task T --seed S`): it sends the scene's state each step
(DEBUG_FLOAT_ARRAY \"task\", docs/mavlink.md), checked against the scene built here; a vehicle
that sends none (a real one) flies the script from that scene, success not observed.

Over ipc the twin must serve the same vehicle and settings (disturbances, motor model, seed):
the handshake refuses a mismatch naming both values (exit 2). If the twin stops answering
within --link-timeout-ms, the flight stops, its MCAP log is closed and amstack exits 1.

Example (lockstep SITL, the results equal the in-process run's):
  amstack twin serve --ipc sitl --platform fa-hexa --seed 3 &
  amstack fly --link ipc:sitl --platform fa-hexa --seed 3 --trajectory step --json r.json

Example (the twin's autopilot over MAVLink, lockstep; the actuator level is the twin's SITL
extension, which current PX4 does not accept):
  amstack twin serve --mavlink udp:127.0.0.1:14540 --lockstep --platform fa-hexa \\
      --allow-actuator-setpoints &
  amstack fly --link mavlink:udp:127.0.0.1:14540 --platform fa-hexa --level actuator --timing

Example (a task over MAVLink; the same rollout as in process within f32 rounding):
  amstack twin serve --mavlink udp:127.0.0.1:14540 --lockstep --task push-slider --seed 3 \\
      --disturbances saturation --allow-actuator-setpoints &
  amstack fly --link mavlink:udp:127.0.0.1:14540 --task push-slider --trajectory scripted \\
      --seed 3 --disturbances saturation --json task.json")]
pub struct FlyArgs {
    /// Where the vehicle is: `twin` (in this process), `ipc:<service>` or
    /// `mavlink:<udp:HOST:PORT|udpin:HOST:PORT|tcp:HOST:PORT|serial:DEVICE:BAUD>`.
    #[arg(long, value_name = "LINK", default_value = "twin")]
    link: String,
    /// How long each tick's answer may take before the flight stops, ms [default: 50 over
    /// ipc, 500 over mavlink].
    #[arg(long, value_name = "MS")]
    link_timeout_ms: Option<u64>,
    /// How long to wait for the twin's handshake (ipc) or the autopilot's first ODOMETRY
    /// (mavlink), ms.
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    connect_timeout_ms: u64,
    /// MAVLink setpoint level: actuator (rotor thrusts, our allocation) or attitude
    /// (attitude + body force, the autopilot's allocation).
    #[arg(long, default_value = "actuator", value_parser = ["actuator", "attitude"])]
    level: String,
    /// MAVLink 2 signing key file: 32 raw bytes or 64 hex digits. Frames out are signed;
    /// unsigned or badly signed frames in are refused (and counted).
    #[arg(long, value_name = "FILE")]
    signing_key: Option<PathBuf>,
    /// Signing link id written into our signatures (0-255).
    #[arg(long, value_name = "ID", default_value_t = 0)]
    signing_link_id: u8,
    /// With --signing-key: also accept unsigned frames (signed ones are still checked).
    #[arg(long)]
    signing_optional: bool,
    /// Print the per-tick round trip over the link (median, p99, p99.9) at the end (ipc,
    /// mavlink).
    #[arg(long)]
    timing: bool,
    /// Write the per-tick timing figures as JSON (implies --timing).
    #[arg(long, value_name = "FILE")]
    timing_json: Option<PathBuf>,
    #[command(flatten)]
    track: track::Args,
}

/// Median, p99 and p99.9 of a sample, µs.
#[derive(Debug, Clone, Copy, Serialize)]
struct Percentiles {
    median_us: f64,
    p99_us: f64,
    p99_9_us: f64,
    max_us: f64,
}

#[derive(Debug, Serialize)]
struct Timing {
    link: String,
    ticks: usize,
    /// Publishing the command → holding the answer.
    round_trip: Percentiles,
    /// The twin's stepping and encoding, as it reports.
    twin_busy: Percentiles,
    /// Round trip minus the twin's busy time: the transport and scheduling alone.
    transport: Percentiles,
    ticks_per_second: f64,
}

fn percentiles(mut ns: Vec<u64>) -> Percentiles {
    ns.sort_unstable();
    let at = |p: f64| {
        if ns.is_empty() {
            return f64::NAN;
        }
        let i = ((p * ns.len() as f64).ceil() as usize).clamp(1, ns.len()) - 1;
        ns[i] as f64 / 1e3
    };
    Percentiles {
        median_us: at(0.5),
        p99_us: at(0.99),
        p99_9_us: at(0.999),
        max_us: at(1.0),
    }
}

fn timing(link: String, ticks: &[TickTiming], result: &TrackResult) -> Timing {
    Timing {
        link,
        ticks: ticks.len(),
        round_trip: percentiles(ticks.iter().map(|t| t.round_trip_ns).collect()),
        twin_busy: percentiles(ticks.iter().map(|t| t.twin_busy_ns).collect()),
        transport: percentiles(
            ticks
                .iter()
                .map(|t| t.round_trip_ns.saturating_sub(t.twin_busy_ns))
                .collect(),
        ),
        ticks_per_second: result.ticks_per_second,
    }
}

pub(crate) enum LinkChoice {
    Twin,
    Ipc(String),
    Mavlink(Address),
}

pub(crate) fn link_choice(link: &str) -> Result<LinkChoice> {
    match link.split_once(':') {
        None if link == "twin" => Ok(LinkChoice::Twin),
        Some(("ipc", service)) if !service.is_empty() && !service.contains(char::is_whitespace) => {
            Ok(LinkChoice::Ipc(service.to_owned()))
        }
        Some(("mavlink", address)) => Address::parse(address)
            .map(LinkChoice::Mavlink)
            .map_err(|e| bad_input(format!("--link {link}: {e}"))),
        _ => Err(bad_input(format!(
            "--link {link}: expected `twin`, `ipc:<service>` or `mavlink:<address>`"
        ))),
    }
}

pub fn run(args: &FlyArgs) -> Result<()> {
    let choice = link_choice(&args.link)?;
    if args.level == "attitude" && args.track.controller_name() == "mpc" {
        return Err(bad_input(
            "--controller mpc --level attitude: the whole-body MPC commands a body wrench and \
             arm joints, not an attitude (it has no attitude loop to hand the autopilot); fly \
             it with --level actuator",
        ));
    }
    if let Some(p) = &args.timing_json {
        check_writable("--timing-json", p)?;
    }
    if args.track.wants_cameras() && !matches!(choice, LinkChoice::Twin) {
        return Err(bad_input(format!(
            "--cameras with --link {}: the cameras are rendered from the twin in this process; \
             fly with --link twin (or run `amstack track`)",
            args.link
        )));
    }
    if track::is_scripted(&args.track) {
        let link = match choice {
            LinkChoice::Twin => BenchLink::InProcess,
            LinkChoice::Ipc(service) => BenchLink::Ipc(ipc_link_config(args, service)),
            LinkChoice::Mavlink(address) => {
                BenchLink::Mavlink(mavlink_link_config(args, &address)?)
            }
        };
        return track::run_scripted(&args.track, link);
    }
    let service = match choice {
        LinkChoice::Twin => return track::run(&args.track),
        LinkChoice::Ipc(service) => service,
        LinkChoice::Mavlink(address) => return run_mavlink(args, &address),
    };
    let config = track::prepare(&args.track)?;
    let link_config = ipc_link_config(args, service);
    // Connect before anything is printed: a refusal is bad input, one line.
    let mut link = IpcLink::connect(&config.vehicle, &config.twin, link_config)
        .map_err(|e| link_error(e.into()))?;
    eprintln!(
        "connected to the twin (process {}) on '{}': {} session {:x}",
        link.twin_pid(),
        args.link,
        link.mode().name(),
        link.session()
    );
    let mut figures = None;
    track::run_with(&args.track, &config, |config, progress| {
        let result = match run_track_with_link(config, &mut link, progress) {
            Ok(r) => r,
            Err(e) => {
                if let (TrackError::Link(_), Some(path)) = (&e, &config.mcap) {
                    eprintln!("closed the flight log {}", path.display());
                }
                return Err(e.into());
            }
        };
        figures = Some(timing(args.link.clone(), link.timings(), &result));
        Ok(result)
    })?;
    if let Some(t) = figures.filter(|_| args.timing || args.timing_json.is_some()) {
        report_timing(&t, args.timing_json.as_deref())?;
    }
    Ok(())
}

fn report_timing(t: &Timing, json: Option<&std::path::Path>) -> Result<()> {
    let line = |name: &str, p: &Percentiles| {
        if p.median_us.is_nan() {
            return; // not known over this link
        }
        eprintln!(
            "  {name:<34} median {:>8.1} µs   p99 {:>8.1} µs   p99.9 {:>8.1} µs   max {:>8.1} µs",
            p.median_us, p.p99_us, p.p99_9_us, p.max_us
        );
    };
    eprintln!("per-tick timing over {} ({} ticks):", t.link, t.ticks);
    line("round trip (command → measurement)", &t.round_trip);
    line("twin stepping (reported)", &t.twin_busy);
    line("transport (round trip − stepping)", &t.transport);
    eprintln!("  ticks per second: {:.0}", t.ticks_per_second);
    if let Some(path) = json {
        write_json(path, &serde_json::to_value(t)?)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn ipc_link_config(args: &FlyArgs, service: String) -> IpcLinkConfig {
    IpcLinkConfig {
        answer_timeout: Duration::from_millis(args.link_timeout_ms.unwrap_or(50).max(1)),
        connect_timeout: Duration::from_millis(args.connect_timeout_ms),
        record_timing: args.timing || args.timing_json.is_some(),
        ..IpcLinkConfig::new(service)
    }
}

/// The MAVLink link of the flags; a bad signing key is bad input.
fn mavlink_link_config(args: &FlyArgs, address: &Address) -> Result<MavlinkLinkConfig> {
    let signing = match &args.signing_key {
        None => None,
        Some(path) => Some(Signing {
            key: SigningKey::from_file(path, args.signing_link_id)
                .map_err(|e| bad_input(format!("--signing-key: {e}")))?,
            require: !args.signing_optional,
        }),
    };
    let level = if args.level == "attitude" {
        Level::Attitude
    } else {
        Level::Actuator
    };
    Ok(MavlinkLinkConfig {
        connect_timeout: Duration::from_millis(args.connect_timeout_ms),
        tick_timeout: Duration::from_millis(args.link_timeout_ms.unwrap_or(500).max(1)),
        record_timing: args.timing || args.timing_json.is_some(),
        ..MavlinkLinkConfig::new(
            BridgeConfig {
                signing,
                // Every frame in and out on the log's /mavlink/raw.
                capture_raw: args.track.logs_mcap(),
                ..BridgeConfig::new(address.clone())
            },
            level,
        )
    })
}

/// A link's error for the user: a refusal (a configuration, scene or layout the other side
/// does not take; an address that cannot be opened) is bad input, the rest a failure.
pub(crate) fn link_error(e: LinkError) -> anyhow::Error {
    match e {
        LinkError::Refused(_) => bad_input(e.to_string()),
        e => anyhow::Error::new(e),
    }
}

/// `amstack fly --link mavlink:...`.
fn run_mavlink(args: &FlyArgs, address: &Address) -> Result<()> {
    let config = track::prepare(&args.track)?;
    let link_config = mavlink_link_config(args, address)?;
    let (level, record_timing) = (link_config.level, link_config.record_timing);
    let mut link = MavlinkLink::connect(&config.vehicle, link_config).map_err(link_error)?;
    let autopilot = link.bridge().autopilot();
    eprintln!(
        "connected to the autopilot on {address}: {}, {}, {} level",
        autopilot.mode_name(),
        if autopilot.armed { "armed" } else { "disarmed" },
        level.name()
    );
    let mut figures = None;
    track::run_with(&args.track, &config, |config, progress| {
        let result = run_track_with_link(config, &mut link, progress)?;
        figures = Some(mavlink_timing(
            args.link.clone(),
            link.round_trips_ns(),
            &result,
        ));
        Ok(result)
    })?;
    let c = link.counters();
    eprintln!(
        "link counters: {} frames in, {} out; refused {} unsigned, {} bad signature; {} bad CRC, {} unknown id, {} truncated, {} garbage bytes",
        c.frames_ok,
        c.frames_sent,
        c.refused_unsigned,
        c.refused_bad_signature,
        c.bad_crc,
        c.unknown_id,
        c.truncated,
        c.garbage_bytes
    );
    if let Some(t) = figures.filter(|_| record_timing) {
        report_timing(&t, args.timing_json.as_deref())?;
    }
    Ok(())
}

/// Timing over MAVLink: the bridge knows the round trip (setpoint queued → its ODOMETRY
/// decoded), not the autopilot's busy time.
fn mavlink_timing(link: String, round_trips_ns: &[u64], result: &TrackResult) -> Timing {
    let nan = Percentiles {
        median_us: f64::NAN,
        p99_us: f64::NAN,
        p99_9_us: f64::NAN,
        max_us: f64::NAN,
    };
    Timing {
        link,
        ticks: round_trips_ns.len(),
        round_trip: percentiles(round_trips_ns.to_vec()),
        twin_busy: nan,
        transport: nan,
        ticks_per_second: result.ticks_per_second,
    }
}
