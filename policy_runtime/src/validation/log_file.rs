//! Opening a flight log for replay or comparison: the file read whole, its format version
//! checked, damage reported naming the file.

use std::path::{Path, PathBuf};

use crate::record::{LOG_FORMAT_VERSION, Recording};

/// The oldest log format version this build reads (see `docs/mcap-format.md`, compatibility).
pub const OLDEST_READABLE_FORMAT_VERSION: u32 = 1;

/// A log that cannot be used. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum LogFileError {
    /// The file cannot be read at all.
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// Not an MCAP file, or its header is damaged.
    #[error("{}: not a readable MCAP file: {reason}", path.display())]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What the reader found.
        reason: String,
    },
    /// The file stops before its footer (a killed run, a copy cut short) or is damaged
    /// after its header.
    #[error(
        "{}: truncated or damaged MCAP file: {reason} ({messages} messages readable up to t = {last_s:.3} s; pass --allow-truncated to use them)",
        path.display()
    )]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Why reading stopped.
        reason: String,
        /// Messages readable before the damage.
        messages: usize,
        /// Log time of the last readable message, s.
        last_s: f64,
    },
    /// Written by a newer amstack whose layout this build does not know.
    #[error(
        "{}: log format version {found} is newer than this amstack reads (versions {oldest} to {current}); use a newer amstack",
        path.display()
    )]
    TooNew {
        /// The file.
        path: PathBuf,
        /// Its `log_format_version`.
        found: u32,
        /// Oldest version read.
        oldest: u32,
        /// This build's [`LOG_FORMAT_VERSION`].
        current: u32,
    },
    /// Older than any version this build reads.
    #[error(
        "{}: log format version {found} is older than this amstack reads (versions {oldest} to {current})",
        path.display()
    )]
    TooOld {
        /// The file.
        path: PathBuf,
        /// Its `log_format_version`.
        found: u32,
        /// Oldest version read.
        oldest: u32,
        /// This build's [`LOG_FORMAT_VERSION`].
        current: u32,
    },
    /// A file without messages.
    #[error("{}: the log holds no messages", path.display())]
    Empty {
        /// The file.
        path: PathBuf,
    },
}

/// A flight log read into memory.
#[derive(Debug, Clone)]
pub struct FlightLogFile {
    /// Where it was read from.
    pub path: PathBuf,
    /// Its metadata and messages.
    pub recording: Recording,
}

/// Reads `path`: refuses a file that is not MCAP, a format version outside
/// [[`OLDEST_READABLE_FORMAT_VERSION`], [`LOG_FORMAT_VERSION`]], an empty log, and — unless
/// `allow_truncated` — a file cut short or damaged after its header (then the messages of its
/// complete chunks are used).
pub fn read_flight_log(path: &Path, allow_truncated: bool) -> Result<FlightLogFile, LogFileError> {
    let bytes = std::fs::read(path).map_err(|source| LogFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let recording = Recording::from_bytes(&bytes).map_err(|e| LogFileError::NotMcap {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    if let Some(run) = &recording.run {
        let found = run.log_format_version;
        if found > LOG_FORMAT_VERSION {
            return Err(LogFileError::TooNew {
                path: path.to_path_buf(),
                found,
                oldest: OLDEST_READABLE_FORMAT_VERSION,
                current: LOG_FORMAT_VERSION,
            });
        }
        if found < OLDEST_READABLE_FORMAT_VERSION {
            return Err(LogFileError::TooOld {
                path: path.to_path_buf(),
                found,
                oldest: OLDEST_READABLE_FORMAT_VERSION,
                current: LOG_FORMAT_VERSION,
            });
        }
    }
    if !recording.complete && !allow_truncated {
        return Err(LogFileError::Truncated {
            path: path.to_path_buf(),
            reason: recording
                .stopped_by
                .clone()
                .unwrap_or_else(|| "the file ends before its footer".to_owned()),
            messages: recording.messages.len(),
            last_s: recording
                .messages
                .iter()
                .map(|m| m.log_time_ns)
                .max()
                .unwrap_or(0) as f64
                * 1e-9,
        });
    }
    if recording.messages.is_empty() {
        return Err(LogFileError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok(FlightLogFile {
        path: path.to_path_buf(),
        recording,
    })
}
