//! What the `actuator`, `ground-effect` and `wrench-limit` experiments share: their flights
//! are `amstack track`, `replay` and `compare` command lines, parsed by the same flag
//! parsers and flown by the same library functions as those subcommands (never our binary
//! in a child process); independent flights run on `--jobs` threads, each result in its
//! place whatever the thread count; progress on stderr.

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use policy_runtime::validation::{CompareReport, ErrorStats, FlightLogFile, read_flight_log};
use policy_runtime::{TrackConfig, TrackResult, run_track};

use crate::cli_error::bad_input;
use crate::twin_flags::PhysicsFlags;

/// Strings from string slices (flag lists).
pub(super) fn strings(items: &[&str]) -> Vec<String> {
    items.iter().map(|s| (*s).to_owned()).collect()
}

/// The checks every experiment makes before it flies (`--jobs`, the physics counts, a
/// `--duration` past track's 2 s settling), then its `--out` folder made: the worker count.
pub(super) fn prepare(
    jobs_flag: Option<usize>,
    physics: &PhysicsFlags,
    duration: Option<f64>,
    out: &Path,
) -> Result<usize> {
    let jobs = jobs(jobs_flag)?;
    physics.check()?;
    if let Some(d) = duration
        && !(d.is_finite() && d > 2.0)
    {
        return Err(bad_input(format!(
            "--duration {d}: must be longer than track's 2 s settling time"
        )));
    }
    super::prepare_out(out)?;
    Ok(jobs)
}

/// An `amstack track FLAGS` flight, configured (every bad-input error raised here, before
/// anything flies).
pub(super) fn track_config(flags: &[String]) -> Result<TrackConfig> {
    let args: crate::track::Args = crate::flag_line::parse("track", flags)?;
    crate::track::prepare(&args)
}

/// The worker threads of `--jobs` (all cores by default); 0 is bad input.
pub(super) fn jobs(flag: Option<usize>) -> Result<usize> {
    match flag {
        Some(0) => Err(bad_input("--jobs: at least 1")),
        Some(n) => Ok(n),
        None => Ok(std::thread::available_parallelism().map_or(1, std::num::NonZero::get)),
    }
}

/// The experiments' progress bar on stderr, counting `total` units (simulated seconds).
pub(super) fn progress_bar(total: u64) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix} [{bar:30}] {pos}/{len} simulated s, {elapsed} (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// Runs `work(i)` for i in 0..n on up to `jobs` threads; the results come back in index
/// order, so what is computed never depends on `jobs`. The first error (in index order) is
/// returned.
pub(super) fn in_parallel<T: Send>(
    n: usize,
    jobs: usize,
    work: &(dyn Fn(usize) -> Result<T> + Sync),
) -> Result<Vec<T>> {
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<Result<T>>>> = (0..n).map(|_| Mutex::new(None)).collect();
    std::thread::scope(|scope| {
        for _ in 0..jobs.clamp(1, n.max(1)) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    if i >= n {
                        break;
                    }
                    let r = work(i);
                    if let Ok(mut slot) = slots[i].lock() {
                        *slot = Some(r);
                    }
                }
            });
        }
    });
    slots
        .into_iter()
        .enumerate()
        .map(|(i, slot)| {
            slot.into_inner()
                .ok()
                .flatten()
                .unwrap_or_else(|| Err(anyhow::anyhow!("run {i}: its worker thread died")))
        })
        .collect()
}

/// Flies `configs` (from [`track_config`]) on `jobs` threads, advancing `bar` by simulated
/// seconds and printing `labels[i]` on stderr when flight i is done; results in the order of
/// `configs`.
pub(super) fn fly_tracks(
    configs: &[TrackConfig],
    labels: &[String],
    jobs: usize,
    bar: &ProgressBar,
) -> Result<Vec<TrackResult>> {
    in_parallel(configs.len(), jobs, &|i| {
        let config = &configs[i];
        let label = labels.get(i).map_or("", String::as_str);
        let mut shown = 0.0_f64;
        let result = run_track(config, |t| {
            let whole = t.floor();
            if whole > shown {
                bar.inc((whole - shown) as u64);
                shown = whole;
            }
            ControlFlow::Continue(())
        })
        .with_context(|| {
            format!(
                "{} on {} ({})",
                config.trajectory.name(),
                config.vehicle.id,
                config.controller.name()
            )
        })?;
        bar.inc((config.duration_s.floor() - shown).max(0.0) as u64);
        bar.suspend(|| eprintln!("  flown: {label} ({} s)", config.duration_s));
        Ok(result)
    })
}

/// Simulated seconds of `configs`, for the progress bar.
pub(super) fn seconds(configs: &[TrackConfig]) -> u64 {
    configs.iter().map(|c| c.duration_s.floor() as u64).sum()
}

/// A flight log just written by this experiment.
pub(super) fn read_log(path: &Path) -> Result<FlightLogFile> {
    read_flight_log(path, false).map_err(|e| anyhow::anyhow!("{e}"))
}

/// `amstack compare A B --signal … --interval …` on two logs of this experiment.
pub(super) fn compare(
    a: &Path,
    b: &Path,
    signals: &[&str],
    intervals: &[&str],
) -> Result<CompareReport> {
    let (a, b) = (read_log(a)?, read_log(b)?);
    crate::compare::compare(&a, &b, &strings(signals), &strings(intervals), 0.0)
}

/// The statistics of `signal` over `interval` (None: whole overlap) in `report`.
pub(super) fn stats<'a>(
    report: &'a CompareReport,
    signal: &str,
    interval: Option<&str>,
) -> Option<&'a ErrorStats> {
    let s = report.signals.iter().find(|s| s.signal == signal)?;
    match interval {
        None => Some(&s.whole),
        Some(i) => s
            .intervals
            .iter()
            .find(|x| x.interval == i)
            .map(|x| &x.stats),
    }
}

/// Draws `report` with `compare --plot`'s drawing into `path`.
pub(super) fn plot(path: &Path, report: &CompareReport) -> Result<()> {
    crate::plot::draw(path, report).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// A claim of the paper checked on our figures.
#[derive(Debug, serde::Serialize)]
pub(super) struct Check {
    /// The paper's statement.
    pub claim: String,
    /// What we measured, in words and figures.
    pub ours: String,
    /// What the paper prints for it.
    pub paper: String,
    /// Whether it holds on our figures.
    pub holds: bool,
}

impl Check {
    pub(super) fn new(claim: &str, ours: String, paper: &str, holds: bool) -> Self {
        Self {
            claim: claim.to_owned(),
            ours,
            paper: paper.to_owned(),
            holds,
        }
    }
}

/// Prints the checks, one a line.
pub(super) fn print_checks(checks: &[Check]) {
    for c in checks {
        println!(
            "{} {} (ours: {}; paper: {})",
            if c.holds { "holds:  " } else { "differs:" },
            c.claim,
            c.ours,
            c.paper
        );
    }
}
