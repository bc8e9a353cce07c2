//! The one error type of the recorder: every variant names the file or topic it is about.

use std::path::PathBuf;

/// What went wrong while writing (or reading back) a run's MCAP file.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be created (missing folder, no permission, …).
    #[error("cannot create MCAP file {}: {source}", path.display())]
    Create {
        /// The path that was asked for.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// The MCAP writer failed (usually an I/O error underneath: disk full, file removed).
    #[error("writing MCAP file {}: {source}", path.display())]
    Write {
        /// The file being written.
        path: PathBuf,
        /// The writer's error.
        source: mcap::McapError,
    },
    /// Flushing or syncing the finished file failed.
    #[error("closing MCAP file {}: {source}", path.display())]
    Close {
        /// The file being closed.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A message could not be serialised to JSON.
    #[error("serialising a message on topic {topic}: {source}")]
    Serialize {
        /// The channel's topic.
        topic: String,
        /// serde_json's reason.
        source: serde_json::Error,
    },
    /// The same topic was registered twice with different schemas.
    #[error("topic {topic} is already registered with schema {existing}, not {requested}")]
    TopicConflict {
        /// The topic.
        topic: String,
        /// The schema name it already has.
        existing: String,
        /// The schema name (or content) asked for now.
        requested: String,
    },
    /// A [`Channel`](super::Channel) handle was used with a recorder that did not create it.
    #[error("channel {topic} belongs to another recorder")]
    ForeignChannel {
        /// The handle's topic.
        topic: String,
    },
    /// The [`RecorderConfig`](super::RecorderConfig) is invalid.
    #[error("recorder config: {0}")]
    Config(String),
    /// The run metadata is unusable (`config_json` not JSON, a field missing on read-back, …).
    #[error("run metadata: {0}")]
    Metadata(String),
    /// A Foxglove SDK message could not be encoded.
    #[error("encoding a message of topic {topic}: {message}")]
    Encode {
        /// The channel's topic.
        topic: String,
        /// The encoder's message.
        message: String,
    },
    /// A camera image could not be encoded.
    #[error("encoding the image of topic {topic}: {message}")]
    Image {
        /// The channel's topic.
        topic: String,
        /// The encoder's reason.
        message: String,
    },
    /// Reading a file back failed before anything could be returned.
    #[error("reading MCAP data: {0}")]
    Read(#[from] mcap::McapError),
}
