//! Sim-to-real validation: re-flying a logged flight in the twin ([`replay`]) and comparing
//! two flight logs signal by signal ([`compare`], [`signals`]), and which rotors reached a
//! thrust limit in a log, when and for how long ([`saturation`]). Logs are read by
//! [`read_flight_log`], which checks the format version and reports damage naming the file.
//! The log format is described in `docs/mcap-format.md`.

pub mod compare;
mod log_file;
pub mod replay;
pub mod saturation;
pub mod signals;

use std::path::PathBuf;

use serde::Serialize;

pub use compare::{Aligned, ErrorStats, Interval, IntervalError, parse_interval};
pub use log_file::{FlightLogFile, LogFileError, OLDEST_READABLE_FORMAT_VERSION, read_flight_log};
pub use replay::{
    ReplayConfig, ReplayError, ReplayMode, ReplayResult, check_replay, replay_flight,
};
pub use saturation::{RotorLimitUse, SaturationSummary, rotor_saturation};
pub use signals::{SignalError, SignalPath, available_signals};

/// What stops a comparison. Every variant names the file, the signal or the interval.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    /// A signal path is wrong or missing from a log.
    #[error(transparent)]
    Signal(#[from] SignalError),
    /// An interval expression is wrong.
    #[error(transparent)]
    Interval(#[from] IntervalError),
    /// The two logs do not overlap in time for a signal.
    #[error("signal {signal}: {a} and {b} do not overlap in time ({a} {a_span}, {b} {b_span})")]
    NoOverlap {
        /// The signal.
        signal: String,
        /// Log A.
        a: String,
        /// Log B.
        b: String,
        /// A's time span.
        a_span: String,
        /// B's time span.
        b_span: String,
    },
}

/// The statistics of one signal over one interval.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IntervalStats {
    /// The interval expression.
    pub interval: String,
    /// Its statistics.
    #[serde(flatten)]
    pub stats: ErrorStats,
}

/// One signal compared.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SignalReport {
    /// The signal path.
    pub signal: String,
    /// Its unit (empty: none or unknown).
    pub unit: String,
    /// Over the whole overlap.
    pub whole: ErrorStats,
    /// Per interval, in the order given.
    pub intervals: Vec<IntervalStats>,
    /// The paired samples (for plots).
    #[serde(skip)]
    pub aligned: Aligned,
    /// Per interval, which paired samples it keeps (for plots).
    #[serde(skip)]
    pub masks: Vec<Vec<bool>>,
}

/// A comparison of two logs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompareReport {
    /// Log A (the reference: its times are the grid, its signals the intervals' conditions).
    pub a: PathBuf,
    /// Log B (interpolated onto A's times; errors are B − A).
    pub b: PathBuf,
    /// The interval expressions.
    pub intervals: Vec<String>,
    /// Added to B's times before aligning, s.
    pub b_shift_s: f64,
    /// Per signal (array paths expanded to their elements).
    pub signals: Vec<SignalReport>,
}

/// The shift that puts B's first message at A's first message time, s (for logs on clocks
/// with different origins, e.g. a flight's monotonic clock and its replay's simulated time).
pub fn start_shift_s(a: &FlightLogFile, b: &FlightLogFile) -> f64 {
    let first = |f: &FlightLogFile| {
        f.recording
            .messages
            .iter()
            .map(|m| m.log_time_ns)
            .min()
            .unwrap_or(0) as f64
            / 1e9
    };
    first(a) - first(b)
}

fn span(series: &signals::Series) -> String {
    match (series.times_s.first(), series.times_s.last()) {
        (Some(a), Some(b)) => format!("{a:.3}..{b:.3} s"),
        _ => "no samples".to_owned(),
    }
}

/// Compares `signals` (paths; arrays expand to their elements) of `b` against `a`, over the
/// whole overlap and over each of `intervals`. `b_shift_s` is added to B's times before
/// aligning (0 for logs on the same clock).
pub fn compare_logs(
    a: &FlightLogFile,
    b: &FlightLogFile,
    signal_paths: &[String],
    intervals: &[String],
    b_shift_s: f64,
) -> Result<CompareReport, CompareError> {
    let parsed: Vec<Interval> = intervals
        .iter()
        .map(|e| parse_interval(e))
        .collect::<Result<_, _>>()?;
    let a_name = a.path.display().to_string();
    let b_name = b.path.display().to_string();
    // Condition signals come from A; resolve them once (an unknown one is an error naming
    // the interval and listing A's signals).
    let mut conditions: std::collections::BTreeMap<String, signals::Series> =
        std::collections::BTreeMap::new();
    for interval in &parsed {
        for clause in &interval.clauses {
            if let compare::Clause::Threshold { signal, .. } = clause
                && signal != "t"
                && !conditions.contains_key(signal)
            {
                let paths =
                    signals::resolve(&a.recording, &a_name, signal).map_err(|e| IntervalError {
                        expr: interval.expr.clone(),
                        reason: e.to_string(),
                    })?;
                let [path] = paths.as_slice() else {
                    return Err(IntervalError {
                        expr: interval.expr.clone(),
                        reason: format!("{signal} is an array; name one element, [i]"),
                    }
                    .into());
                };
                let series = signals::extract(&a.recording, &a_name, path)?;
                conditions.insert(signal.clone(), series);
            }
        }
    }
    let mut reports = Vec::new();
    for text in signal_paths {
        let paths_a = signals::resolve(&a.recording, &a_name, text)?;
        // B must hold the same signal (and an array of the same length).
        let paths_b = signals::resolve(&b.recording, &b_name, text)?;
        if paths_a.len() != paths_b.len() {
            return Err(SignalError::Missing {
                path: text.clone(),
                file: b_name.clone(),
                reason: format!(
                    "it has {} elements here and {} in {a_name}",
                    paths_b.len(),
                    paths_a.len()
                ),
                available: String::new(),
            }
            .into());
        }
        for path in paths_a {
            let sa = signals::extract(&a.recording, &a_name, &path)?;
            let mut sb = signals::extract(&b.recording, &b_name, &path)?;
            for t in &mut sb.times_s {
                *t += b_shift_s;
            }
            let aligned = compare::align(&sa, &sb);
            if aligned.times_s.is_empty() {
                return Err(CompareError::NoOverlap {
                    signal: path.to_string(),
                    a: a_name.clone(),
                    b: b_name.clone(),
                    a_span: span(&sa),
                    b_span: span(&sb),
                });
            }
            let whole = compare::error_stats(&aligned, |_| true);
            let mut masks = Vec::new();
            let mut stats = Vec::new();
            for interval in &parsed {
                let mask = compare::interval_mask(interval, &aligned.times_s, &|s| {
                    conditions.get(s).cloned()
                })?;
                stats.push(IntervalStats {
                    interval: interval.expr.clone(),
                    stats: compare::error_stats(&aligned, |i| mask[i]),
                });
                masks.push(mask);
            }
            reports.push(SignalReport {
                signal: path.to_string(),
                unit: signals::unit_of(&path).to_owned(),
                whole,
                intervals: stats,
                aligned,
                masks,
            });
        }
    }
    Ok(CompareReport {
        a: a.path.clone(),
        b: b.path.clone(),
        intervals: intervals.to_vec(),
        b_shift_s,
        signals: reports,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests;
