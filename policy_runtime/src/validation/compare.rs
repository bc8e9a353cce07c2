//! Comparing a signal of two logs: alignment on time, error statistics, intervals.
//!
//! # Alignment
//!
//! Log A sets the time grid: each sample of A whose time lies inside B's time span (the
//! overlap) is paired with B linearly interpolated at that time (B's samples at equal times:
//! the later one). Samples of A outside B's span are dropped, so only the overlap counts.
//! The error is e = B − A at each paired time.
//!
//! # Statistics
//!
//! Over the paired samples where both values are finite: RMSE = √(mean e²), max |e|, bias =
//! mean e, and the count.
//!
//! # Intervals
//!
//! An interval expression selects paired samples:
//!
//! ```text
//! interval := clause ('&' clause)*
//! clause   := 't=' NUMBER '..' NUMBER          time window [a, b], s
//!           | NAME OP NUMBER                   a signal of log A against a threshold
//! OP       := '<=' | '>=' | '<' | '>'
//! NAME     := 't' | 'x_ref' | 'y_ref' | 'z_ref' | a signal path (/topic.field[i])
//! ```
//!
//! `x_ref`, `y_ref`, `z_ref` are the end-effector reference `/ee/reference.pose.position.*`,
//! m (the paper's z_ref). A signal in a condition is read from log A, interpolated at the
//! paired times. Examples: `z_ref<=0.7`, `z_ref>=0.9`, `t=2..5`,
//! `/base/state.position_m[2]>1.2&t=0..30`.

use serde::Serialize;

use super::signals::Series;

/// Errors of an interval expression; each names the expression.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("interval '{expr}': {reason}")]
pub struct IntervalError {
    /// The expression given.
    pub expr: String,
    /// What is wrong.
    pub reason: String,
}

/// A comparison operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op {
    /// ≤
    Le,
    /// ≥
    Ge,
    /// <
    Lt,
    /// >
    Gt,
}

impl Op {
    fn holds(self, x: f64, threshold: f64) -> bool {
        match self {
            Self::Le => x <= threshold,
            Self::Ge => x >= threshold,
            Self::Lt => x < threshold,
            Self::Gt => x > threshold,
        }
    }
}

/// One clause of an interval.
#[derive(Debug, Clone, PartialEq)]
pub enum Clause {
    /// Times within [from_s, to_s].
    Time {
        /// Start, s.
        from_s: f64,
        /// End, s.
        to_s: f64,
    },
    /// A signal of log A against a threshold (`signal` is a signal path or `t`).
    Threshold {
        /// The signal path (aliases expanded) or `t`.
        signal: String,
        /// The comparison.
        op: Op,
        /// The threshold, in the signal's unit.
        value: f64,
    },
}

/// A parsed interval expression.
#[derive(Debug, Clone, PartialEq)]
pub struct Interval {
    /// The expression as given (its name in reports).
    pub expr: String,
    /// All must hold.
    pub clauses: Vec<Clause>,
}

/// The signal an alias of an interval stands for.
pub fn alias(name: &str) -> Option<&'static str> {
    match name {
        "x_ref" => Some("/ee/reference.pose.position.x"),
        "y_ref" => Some("/ee/reference.pose.position.y"),
        "z_ref" => Some("/ee/reference.pose.position.z"),
        _ => None,
    }
}

/// Parses an interval expression (grammar in the [module documentation](self)).
pub fn parse_interval(expr: &str) -> Result<Interval, IntervalError> {
    let err = |reason: String| IntervalError {
        expr: expr.to_owned(),
        reason,
    };
    let number = |text: &str, what: &str| -> Result<f64, IntervalError> {
        let t = text.trim();
        t.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| err(format!("{what} '{t}' is not a finite number")))
    };
    if expr.trim().is_empty() {
        return Err(err("empty expression".to_owned()));
    }
    let mut clauses = Vec::new();
    for clause in expr.split('&') {
        let clause = clause.trim();
        if let Some(window) = clause.strip_prefix("t=") {
            let (a, b) = window
                .split_once("..")
                .ok_or_else(|| err(format!("'{clause}': a time window is t=A..B (seconds)")))?;
            let (from_s, to_s) = (number(a, "start")?, number(b, "end")?);
            if from_s > to_s {
                return Err(err(format!("'{clause}': the window ends before it starts")));
            }
            clauses.push(Clause::Time { from_s, to_s });
            continue;
        }
        let ops = [("<=", Op::Le), (">=", Op::Ge), ("<", Op::Lt), (">", Op::Gt)];
        let Some((at, len, op)) = ops
            .iter()
            .filter_map(|(s, op)| clause.find(s).map(|i| (i, s.len(), *op)))
            .min_by_key(|(i, len, _)| (*i, usize::MAX - len))
        else {
            return Err(err(format!(
                "'{clause}': expected t=A..B or NAME OP NUMBER with OP one of <= >= < > (NAME: t, x_ref, y_ref, z_ref or a signal path)"
            )));
        };
        let name = clause[..at].trim();
        let value = number(&clause[at + len..], "threshold")?;
        let signal = if name == "t" {
            "t".to_owned()
        } else if let Some(path) = alias(name) {
            path.to_owned()
        } else if name.starts_with('/') {
            name.to_owned()
        } else {
            return Err(err(format!(
                "'{name}' is not t, x_ref, y_ref, z_ref or a signal path (/topic.field)"
            )));
        };
        clauses.push(Clause::Threshold { signal, op, value });
    }
    Ok(Interval {
        expr: expr.to_owned(),
        clauses,
    })
}

/// Two signals on A's time grid.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Aligned {
    /// Paired times (A's, inside B's span), s.
    pub times_s: Vec<f64>,
    /// A's values.
    pub a: Vec<f64>,
    /// B interpolated at the times.
    pub b: Vec<f64>,
}

/// Linear interpolation of `series` at `t`, which must lie within its span; samples at equal
/// times: the later one. `None` outside the span or for an empty series.
pub fn interpolate(series: &Series, t: f64) -> Option<f64> {
    let ts = &series.times_s;
    let (&first, &last) = (ts.first()?, ts.last()?);
    if !(t >= first && t <= last) {
        return None;
    }
    // First index with time > t; the bracket is [i − 1, i].
    let i = ts.partition_point(|&x| x <= t);
    if i == ts.len() {
        return series.values.last().copied();
    }
    let (t0, t1) = (ts[i - 1], ts[i]);
    let (v0, v1) = (series.values[i - 1], series.values[i]);
    if t == t0 {
        return Some(v0);
    }
    let w = (t - t0) / (t1 - t0);
    Some(v0 + w * (v1 - v0))
}

/// Pairs A's samples inside B's span with B interpolated at their times.
pub fn align(a: &Series, b: &Series) -> Aligned {
    let mut out = Aligned::default();
    for (&t, &va) in a.times_s.iter().zip(&a.values) {
        if let Some(vb) = interpolate(b, t) {
            out.times_s.push(t);
            out.a.push(va);
            out.b.push(vb);
        }
    }
    out
}

/// Error statistics of B − A.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Paired samples with both values finite.
    pub samples: usize,
    /// √(mean (B − A)²), in the signal's unit (null without samples).
    pub rmse: Option<f64>,
    /// max |B − A| (null without samples).
    pub max_abs: Option<f64>,
    /// mean (B − A) (null without samples).
    pub bias: Option<f64>,
    /// First and last paired time, s (null without samples).
    pub span_s: Option<[f64; 2]>,
}

/// Statistics over the paired samples that `select` keeps.
pub fn error_stats(aligned: &Aligned, select: impl Fn(usize) -> bool) -> ErrorStats {
    let (mut n, mut sum, mut sum_sq, mut max_abs) = (0usize, 0.0, 0.0, 0.0f64);
    let mut span: Option<[f64; 2]> = None;
    for i in 0..aligned.times_s.len() {
        let e = aligned.b[i] - aligned.a[i];
        if !e.is_finite() || !select(i) {
            continue;
        }
        n += 1;
        sum += e;
        sum_sq += e * e;
        max_abs = max_abs.max(e.abs());
        let t = aligned.times_s[i];
        span = Some(span.map_or([t, t], |[a, _]| [a, t]));
    }
    let some = |x: f64| (n > 0).then_some(x);
    ErrorStats {
        samples: n,
        rmse: some((sum_sq / n.max(1) as f64).sqrt()),
        max_abs: some(max_abs),
        bias: some(sum / n.max(1) as f64),
        span_s: span,
    }
}

/// Which paired samples an interval keeps. `condition_signal(path)` gives a signal of log A
/// (the condition's); a threshold on a time where it cannot be interpolated keeps nothing.
pub fn interval_mask(
    interval: &Interval,
    times_s: &[f64],
    condition_signal: &dyn Fn(&str) -> Option<Series>,
) -> Result<Vec<bool>, IntervalError> {
    let mut mask = vec![true; times_s.len()];
    for clause in &interval.clauses {
        match clause {
            Clause::Time { from_s, to_s } => {
                for (keep, &t) in mask.iter_mut().zip(times_s) {
                    *keep &= t >= *from_s && t <= *to_s;
                }
            }
            Clause::Threshold { signal, op, value } if signal == "t" => {
                for (keep, &t) in mask.iter_mut().zip(times_s) {
                    *keep &= op.holds(t, *value);
                }
            }
            Clause::Threshold { signal, op, value } => {
                let series = condition_signal(signal).ok_or_else(|| IntervalError {
                    expr: interval.expr.clone(),
                    reason: format!("log A has no signal {signal}"),
                })?;
                for (keep, &t) in mask.iter_mut().zip(times_s) {
                    *keep &= interpolate(&series, t).is_some_and(|x| op.holds(x, *value));
                }
            }
        }
    }
    Ok(mask)
}
