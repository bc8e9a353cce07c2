//! `amstack compare`: two flight logs, signal by signal.

use std::path::PathBuf;

use anyhow::Result;
use comfy_table::{Table, presets};
use policy_runtime::validation::{
    CompareError, CompareReport, ErrorStats, FlightLogFile, available_signals, compare_logs,
    read_flight_log, start_shift_s,
};

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};
use crate::plot;
use crate::replay::log_error;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Signals: <topic><field>..., a field being .name or [i] (from 0):
  /base/state.position_m[2]     base z, m          /rotors.realised_n[3]  rotor 3 thrust, N
  /ee/pose.pose.position.z      end-effector z, m  /rotors.saturated      0 or 1
A path naming an array (/rotors.realised_n) stands for each element. `--signal list` prints
every signal of the logs.

Alignment: A's times are the grid; B is linearly interpolated at A's times inside B's span
(only the overlap counts), after --shift-b. Error = B - A: RMSE, max |error|, bias (mean
error).

Intervals (--interval, repeatable; clauses joined with &):
  t=A..B                      a time window, s
  NAME OP NUMBER              OP: <= >= < >; NAME: t, x_ref, y_ref, z_ref (the end-effector
                              reference /ee/reference.pose.position.*, m) or a signal path,
                              read from log A
  e.g. 'z_ref<=0.7'  'z_ref>=0.9'  't=2..5'  '/base/state.position_m[2]>1.2&t=0..30'")]
pub struct Args {
    /// Log A: the reference (its times are the grid, its signals the intervals' conditions).
    #[arg(value_name = "A.mcap")]
    a: PathBuf,
    /// Log B: compared against A (error = B - A).
    #[arg(value_name = "B.mcap")]
    b: PathBuf,
    /// A signal path (repeatable), or `list` to print the available signals.
    #[arg(long = "signal", value_name = "PATH", required = true)]
    signals: Vec<String>,
    /// An interval to score separately (repeatable).
    #[arg(long = "interval", value_name = "EXPR")]
    intervals: Vec<String>,
    /// Draw the signals, their difference and the intervals in a PNG.
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Write the figures as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Shift B's times by this many seconds before aligning, or `start` to put B's first
    /// message at A's first (logs on clocks with different origins, a known delay).
    #[arg(long, value_name = "S|start", allow_hyphen_values = true)]
    shift_b: Option<String>,
    /// Use the readable part of a truncated or damaged log.
    #[arg(long)]
    allow_truncated: bool,
}

fn cell(x: Option<f64>) -> String {
    x.filter(|v| v.is_finite())
        .map_or_else(|| "N/A".to_owned(), crate::output::significant)
}

fn row(table: &mut Table, signal: &str, unit: &str, interval: &str, s: &ErrorStats) {
    table.add_row([
        signal.to_owned(),
        interval.to_owned(),
        s.samples.to_string(),
        cell(s.rmse),
        cell(s.max_abs),
        cell(s.bias),
        if unit.is_empty() {
            "-".to_owned()
        } else {
            unit.to_owned()
        },
    ]);
}

/// [`compare_logs`], a wrong signal or interval or logs that do not overlap being bad input.
pub(crate) fn compare(
    a: &FlightLogFile,
    b: &FlightLogFile,
    signals: &[String],
    intervals: &[String],
    b_shift_s: f64,
) -> Result<CompareReport> {
    compare_logs(a, b, signals, intervals, b_shift_s).map_err(|e| match e {
        CompareError::Signal(_) | CompareError::Interval(_) | CompareError::NoOverlap { .. } => {
            bad_input(e.to_string())
        }
    })
}

pub fn run(args: &Args) -> Result<()> {
    for (flag, path) in [("--json", &args.json), ("--plot", &args.plot)] {
        if let Some(p) = path {
            check_writable(flag, p)?;
        }
    }
    let a = read_flight_log(&args.a, args.allow_truncated).map_err(|e| log_error(&e))?;
    let b = read_flight_log(&args.b, args.allow_truncated).map_err(|e| log_error(&e))?;
    if args.signals.iter().any(|s| s == "list") {
        let in_a = available_signals(&a.recording);
        let in_b = available_signals(&b.recording);
        println!(
            "signals of {} ([a..b]: each index from a to b - 1):",
            args.a.display()
        );
        for s in &in_a {
            let mark = if in_b.contains(s) {
                ""
            } else {
                "   (not in B)"
            };
            println!("  {s}{mark}");
        }
        for s in in_b.iter().filter(|s| !in_a.contains(s)) {
            println!("  {s}   (only in B)");
        }
        return Ok(());
    }
    let shift = match args.shift_b.as_deref() {
        None => 0.0,
        Some("start") => start_shift_s(&a, &b),
        Some(text) => text
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                bad_input(format!(
                    "--shift-b {text}: expected seconds (e.g. -0.25) or `start`"
                ))
            })?,
    };
    if shift != 0.0 {
        eprintln!("B's times shifted by {shift:+.6} s");
    }
    let report = compare(&a, &b, &args.signals, &args.intervals, shift)?;
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "signal",
        "interval",
        "samples",
        "RMSE",
        "max |error|",
        "bias",
        "unit",
    ]);
    for s in &report.signals {
        row(&mut table, &s.signal, &s.unit, "whole overlap", &s.whole);
        for i in &s.intervals {
            row(&mut table, &s.signal, &s.unit, &i.interval, &i.stats);
        }
    }
    println!(
        "A = {}, B = {}; error = B - A",
        args.a.display(),
        args.b.display()
    );
    println!("{table}");
    if let Some(path) = &args.json {
        write_json(path, &serde_json::to_value(&report)?)?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &args.plot {
        plot::draw(path, &report).map_err(|e| anyhow::anyhow!("--plot {}: {e}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
