//! Signals of a flight log: a numeric field of a channel's JSON messages over time.
//!
//! # Signal paths
//!
//! `<topic><field>...`, where `<topic>` is a channel's topic as written in the log (`/base/state`,
//! `/rotors`) and each `<field>` is `.name` (an object member) or `[i]` (an array element,
//! from 0):
//!
//! - `/base/state.position_m[2]`: the base's z, m;
//! - `/rotors.realised_n[3]`: rotor 3's realised thrust, N;
//! - `/ee/pose.pose.position.z`: the end effector's z (Foxglove pose), m;
//! - `/rotors.saturated`: a boolean, read as 0 or 1.
//!
//! The topic is the longest topic of the log the path starts with. A path naming an array of
//! numbers without an index (`/rotors.realised_n`) stands for each of its elements. Values are
//! the messages' numbers; a `null` (a non-finite number as JSON writes it) is NaN. Times are
//! the messages' log times, s.

use std::collections::BTreeSet;
use std::fmt;

use serde_json::Value;

use crate::record::Recording;

/// One step of a path inside a message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Field {
    /// An object member.
    Key(String),
    /// An array element.
    Index(usize),
}

/// A parsed signal path: a topic and the fields inside its messages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SignalPath {
    /// The channel's topic.
    pub topic: String,
    /// Fields from the message root to the value.
    pub fields: Vec<Field>,
}

impl fmt::Display for SignalPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.topic)?;
        for field in &self.fields {
            match field {
                Field::Key(k) => write!(f, ".{k}")?,
                Field::Index(i) => write!(f, "[{i}]")?,
            }
        }
        Ok(())
    }
}

/// A signal path that cannot be used with a log.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SignalError {
    /// The text is not a path.
    #[error("signal '{path}': {reason}")]
    Syntax {
        /// The text given.
        path: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The log has no such channel or field.
    #[error("signal '{path}' is not in {file}: {reason}; available: {available}")]
    Missing {
        /// The path asked for.
        path: String,
        /// The log (file name).
        file: String,
        /// What is missing.
        reason: String,
        /// The signals the log has (compact listing).
        available: String,
    },
}

/// A signal's samples, times non-decreasing.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series {
    /// Sample times, s.
    pub times_s: Vec<f64>,
    /// Values (NaN where the message held `null`).
    pub values: Vec<f64>,
}

/// Splits `text` into the topic (the longest of `topics` it starts with, followed by `.`,
/// `[` or nothing) and its fields.
pub fn parse_signal_path<'a>(
    text: &str,
    topics: impl IntoIterator<Item = &'a str>,
) -> Result<SignalPath, SignalError> {
    let syntax = |reason: &str| SignalError::Syntax {
        path: text.to_owned(),
        reason: reason.to_owned(),
    };
    if !text.starts_with('/') {
        return Err(syntax(
            "a signal starts with its channel's topic, e.g. /base/state.position_m[2]",
        ));
    }
    let topic = topics
        .into_iter()
        .filter(|t| {
            text.strip_prefix(*t)
                .is_some_and(|rest| rest.is_empty() || rest.starts_with(['.', '[']))
        })
        .max_by_key(|t| t.len())
        .map(str::to_owned);
    // Without a matching topic, split at the first `.` or `[` so the error names a topic.
    let topic = topic.unwrap_or_else(|| {
        text.find(['.', '['])
            .map_or(text, |i| &text[..i])
            .to_owned()
    });
    let mut rest = &text[topic.len()..];
    let mut fields = Vec::new();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix('.') {
            let end = r.find(['.', '[']).unwrap_or(r.len());
            let key = &r[..end];
            if key.is_empty() {
                return Err(syntax("empty field name after '.'"));
            }
            fields.push(Field::Key(key.to_owned()));
            rest = &r[end..];
        } else if let Some(r) = rest.strip_prefix('[') {
            let end = r.find(']').ok_or_else(|| syntax("'[' without ']'"))?;
            let index = r[..end]
                .trim()
                .parse::<usize>()
                .map_err(|_| syntax(&format!("'[{}]' is not an index (0, 1, ...)", &r[..end])))?;
            fields.push(Field::Index(index));
            rest = &r[end + 1..];
        } else {
            return Err(syntax(&format!(
                "unexpected '{rest}' (fields are .name or [i])"
            )));
        }
    }
    Ok(SignalPath { topic, fields })
}

fn walk<'v>(value: &'v Value, fields: &[Field]) -> Result<&'v Value, String> {
    let mut v = value;
    for (depth, field) in fields.iter().enumerate() {
        v = match (field, v) {
            (Field::Key(k), Value::Object(map)) => map.get(k).ok_or_else(|| {
                let keys: Vec<&str> = map.keys().map(String::as_str).collect();
                format!("no field '{k}' (fields here: {})", keys.join(", "))
            })?,
            (Field::Index(i), Value::Array(items)) => items.get(*i).ok_or_else(|| {
                format!(
                    "index {i} is out of range (the array has {} elements)",
                    items.len()
                )
            })?,
            (Field::Key(k), _) => {
                return Err(format!(
                    "field '{k}' asked of a value that is not an object (after {depth} fields)"
                ));
            }
            (Field::Index(i), _) => {
                return Err(format!(
                    "[{i}] asked of a value that is not an array (after {depth} fields)"
                ));
            }
        };
    }
    Ok(v)
}

fn number(value: &Value) -> Option<f64> {
    match value {
        Value::Number(n) => n.as_f64(),
        Value::Bool(b) => Some(f64::from(u8::from(*b))),
        Value::Null => Some(f64::NAN),
        _ => None,
    }
}

/// The file name of a log, for messages.
fn file_name(file: &str) -> String {
    std::path::Path::new(file)
        .file_name()
        .map_or_else(|| file.to_owned(), |n| n.to_string_lossy().into_owned())
}

/// Topics of a recording, sorted.
pub fn topics(recording: &Recording) -> BTreeSet<&str> {
    recording
        .messages
        .iter()
        .map(|m| m.topic.as_str())
        .collect()
}

/// Parses `text` against `recording` and expands an array path to its elements; an
/// unknown topic or field is [`SignalError::Missing`], naming the signal and listing the
/// available ones. `file` names the log in errors.
pub fn resolve(
    recording: &Recording,
    file: &str,
    text: &str,
) -> Result<Vec<SignalPath>, SignalError> {
    let path = parse_signal_path(text, topics(recording))?;
    let missing = |reason: String| SignalError::Missing {
        path: text.to_owned(),
        file: file_name(file),
        reason,
        available: available_signals(recording).join(", "),
    };
    let Some(first) = recording.messages.iter().find(|m| m.topic == path.topic) else {
        return Err(missing(format!("no channel {}", path.topic)));
    };
    let value: Value = serde_json::from_slice(&first.data)
        .map_err(|e| missing(format!("its first message is not JSON: {e}")))?;
    let leaf = walk(&value, &path.fields).map_err(missing)?;
    match leaf {
        Value::Array(items) if !items.is_empty() && items.iter().all(|v| number(v).is_some()) => {
            Ok((0..items.len())
                .map(|i| {
                    let mut p = path.clone();
                    p.fields.push(Field::Index(i));
                    p
                })
                .collect())
        }
        v if number(v).is_some() => Ok(vec![path]),
        _ => Err(missing(
            "it is not a number, a boolean or an array of numbers".to_owned(),
        )),
    }
}

/// The samples of `path` in `recording`. Messages where the path does not lead to a number
/// are an error naming the message's time.
pub fn extract(
    recording: &Recording,
    file: &str,
    path: &SignalPath,
) -> Result<Series, SignalError> {
    let mut series = Series::default();
    for m in recording.messages.iter().filter(|m| m.topic == path.topic) {
        let t = m.log_time_ns as f64 / 1e9;
        let bad = |reason: String| SignalError::Missing {
            path: path.to_string(),
            file: file_name(file),
            reason: format!("message at t = {t:.6} s: {reason}"),
            available: available_signals(recording).join(", "),
        };
        let value: Value =
            serde_json::from_slice(&m.data).map_err(|e| bad(format!("not JSON: {e}")))?;
        let leaf = walk(&value, &path.fields).map_err(bad)?;
        let x = number(leaf).ok_or_else(|| bad("not a number".to_owned()))?;
        series.times_s.push(t);
        series.values.push(x);
    }
    // amstack writes each channel in time order; a foreign writer may not: sort (stable, so
    // samples at equal times keep their file order and the later one wins interpolation).
    if !series.times_s.is_sorted() {
        let mut order: Vec<usize> = (0..series.times_s.len()).collect();
        order.sort_by(|&i, &j| series.times_s[i].total_cmp(&series.times_s[j]));
        series = Series {
            times_s: order.iter().map(|&i| series.times_s[i]).collect(),
            values: order.iter().map(|&i| series.values[i]).collect(),
        };
    }
    Ok(series)
}

/// Every numeric signal of a recording (from the first message of each channel): arrays of
/// numbers as `path[a..b]` (each index from a to b − 1), arrays of objects element by element.
pub fn available_signals(recording: &Recording) -> Vec<String> {
    let mut out = Vec::new();
    for topic in topics(recording) {
        let Some(first) = recording.messages.iter().find(|m| m.topic == topic) else {
            continue;
        };
        if let Ok(value) = serde_json::from_slice::<Value>(&first.data) {
            leaves(&value, topic.to_owned(), &mut out);
        }
    }
    out
}

fn leaves(value: &Value, prefix: String, out: &mut Vec<String>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                leaves(v, format!("{prefix}.{k}"), out);
            }
        }
        Value::Array(items) if !items.is_empty() && items.iter().all(|v| number(v).is_some()) => {
            out.push(format!("{prefix}[0..{}]", items.len()));
        }
        Value::Array(items) => {
            for (i, v) in items.iter().enumerate() {
                leaves(v, format!("{prefix}[{i}]"), out);
            }
        }
        Value::Number(_) | Value::Bool(_) | Value::Null => out.push(prefix),
        Value::String(_) => {}
    }
}

/// The unit of a signal, from the naming convention of its last field name: `_m` m, `_mps`
/// m/s, `_mps2` m/s², `_rad` rad, `_radps` rad/s, `_n` N, `_nm` N·m, `_ms` ms, `_s` s, `_v`
/// V; `x`/`y`/`z` of a
/// Foxglove position or translation m; booleans and quaternion parts have none (`""`).
pub fn unit_of(path: &SignalPath) -> &'static str {
    let keys: Vec<&str> = path
        .fields
        .iter()
        .filter_map(|f| match f {
            Field::Key(k) => Some(k.as_str()),
            Field::Index(_) => None,
        })
        .collect();
    let Some(last) = keys.last() else {
        return "";
    };
    for (suffix, unit) in [
        ("_radps", "rad/s"),
        ("_mps2", "m/s²"),
        ("_mps", "m/s"),
        ("_nm", "N·m"),
        ("_ms", "ms"),
        ("_rad", "rad"),
        ("_m", "m"),
        ("_n", "N"),
        ("_s", "s"),
        ("_v", "V"),
    ] {
        if last.ends_with(suffix) {
            return unit;
        }
    }
    let parent = keys.len().checked_sub(2).map(|i| keys[i]);
    if matches!(*last, "x" | "y" | "z") && matches!(parent, Some("position" | "translation")) {
        return "m";
    }
    if path.topic == "/joints" && matches!(*last, "target" | "position") {
        return "rad";
    }
    ""
}
