//! `amstack fly`: the flight stack of `amstack track` against a chosen link — the twin in this
//! process, or the twin in another process over iceoryx2.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use policy_runtime::ipc_link::TickTiming;
use policy_runtime::{
    IpcLink, IpcLinkConfig, IpcLinkError, LinkError, TrackError, TrackResult, run_track_with_link,
};
use serde::Serialize;

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};
use crate::track;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Links:
  twin            the twin in this process (as amstack track)
  ipc:<service>   the twin in another process: amstack twin serve --ipc <service> ...

Over ipc the twin must serve the same vehicle and settings (disturbances, motor model, seed):
the handshake refuses a mismatch naming both values (exit 2). If the twin stops answering
within --link-timeout-ms, the flight stops, its MCAP log is closed and amstack exits 1.

Example (lockstep SITL, the results equal the in-process run's):
  amstack twin serve --ipc sitl --platform fa-hexa --seed 3 &
  amstack fly --link ipc:sitl --platform fa-hexa --seed 3 --trajectory step --json r.json")]
pub struct FlyArgs {
    /// Where the vehicle is: `twin` (in this process) or `ipc:<service>`.
    #[arg(long, value_name = "LINK", default_value = "twin")]
    link: String,
    /// How long each answer of the twin may take before the flight stops, ms (ipc).
    #[arg(long, value_name = "MS", default_value_t = 50)]
    link_timeout_ms: u64,
    /// How long to wait for the twin to answer the handshake, ms (ipc).
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    connect_timeout_ms: u64,
    /// Print the per-tick round trip over the link (median, p99, p99.9) at the end (ipc).
    #[arg(long)]
    timing: bool,
    /// Write the per-tick timing figures as JSON (ipc; implies --timing).
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
}

pub(crate) fn link_choice(link: &str) -> Result<LinkChoice> {
    match link.split_once(':') {
        None if link == "twin" => Ok(LinkChoice::Twin),
        Some(("ipc", service)) if !service.is_empty() && !service.contains(char::is_whitespace) => {
            Ok(LinkChoice::Ipc(service.to_owned()))
        }
        _ => Err(bad_input(format!(
            "--link {link}: expected `twin` or `ipc:<service>`"
        ))),
    }
}

pub fn run(args: &FlyArgs) -> Result<()> {
    let choice = link_choice(&args.link)?;
    if let Some(p) = &args.timing_json {
        check_writable("--timing-json", p)?;
    }
    let service = match choice {
        LinkChoice::Twin => return track::run(&args.track),
        LinkChoice::Ipc(service) => service,
    };
    let config = track::prepare(&args.track)?;
    let link_config = IpcLinkConfig {
        answer_timeout: Duration::from_millis(args.link_timeout_ms.max(1)),
        connect_timeout: Duration::from_millis(args.connect_timeout_ms),
        record_timing: args.timing || args.timing_json.is_some(),
        ..IpcLinkConfig::new(service)
    };
    // Connect before anything is printed: a refusal is bad input, one line.
    let mut link =
        IpcLink::connect(&config.vehicle, &config.twin, link_config).map_err(|e| match e {
            IpcLinkError::Refused { .. } | IpcLinkError::TooLarge(_) => bad_input(e.to_string()),
            e => anyhow::Error::new(e),
        })?;
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
                if let (TrackError::Link(LinkError::Ipc(_)), Some(path)) = (&e, &config.mcap) {
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
