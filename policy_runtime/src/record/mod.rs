//! MCAP flight logs: one file per run, readable in Foxglove and by any MCAP reader.
//!
//! # What a file contains
//!
//! In file order:
//!
//! 1. **Header**: profile empty (no well-known profile fits JSON), library
//!    `amstack-<version>; mcap-rust/<version>`.
//! 2. **Metadata record `amstack.run`** ([`RunMetadata`]), written and flushed when the recorder
//!    is created, before any message: `vehicle_id`, `controller`, `interface` and `trajectory`
//!    (absent when not applicable), `config` (the run's whole configuration as one JSON
//!    document), `seed`, `amstack_version`, `log_format_version` ([`LOG_FORMAT_VERSION`]). All
//!    values are strings (MCAP metadata is string → string); integers are decimal.
//! 3. **Chunks** holding the schema, channel and message records. Every channel has message
//!    encoding `json` (one compact JSON object per message, serde_json with `float_roundtrip`)
//!    and a schema with encoding `jsonschema`: the draft 2020-12 JSON Schema of the Rust type,
//!    derived by schemars (nested types inlined, no `$ref`), titled with the schema name.
//!    Schema names are explicit ([`SchemaName`]): Foxglove's own names for the well-known
//!    types in [`foxglove`] (`foxglove.PoseInFrame`, `foxglove.FrameTransforms`, …) so
//!    Foxglove's panels recognise them, and `amstack.<Type>` for amstack's types. Topics are
//!    chosen by the flight loop (slash-separated, e.g. `/base/pose`, `/tf`).
//! 4. **Summary** written by [`McapRecorder::finish`] (or on drop): data-end record, then
//!    schemas, channels, statistics (message counts per channel), chunk and metadata indexes,
//!    footer. A file with a summary opens instantly and seeks; one without is read by
//!    streaming.
//!
//! # Time base
//!
//! Log time and publish time are nanoseconds given by the caller: the run's own clock (the
//! twin's simulated time, starting at 0 at the start of the run; on hardware the flight
//! loop's monotonic clock since the start of the run). The recorder never reads the wall
//! clock, so two runs with the same seed produce the same message payloads and times; with
//! the writer's settings fixed (compression single-threaded, chunk bounds in log time and
//! bytes) they produce byte-identical files. Timestamps inside Foxglove messages
//! ([`foxglove::Time`]) use the same clock, split into seconds and nanoseconds.
//!
//! Quaternions: Foxglove types carry them as named fields `{x, y, z, w}`; amstack types that
//! carry a quaternion as an array use `[w, x, y, z]` (the workspace convention).
//! Non-finite floats: JSON has none, so serde_json writes `NaN`/`±inf` as `null`; a schema
//! check (`scripts/mcap_check.py`) reports such a field as not a number.
//!
//! # Chunking and crashes
//!
//! A chunk is built in memory and written whole when it is closed: before a message whose log
//! time lies [`RecorderConfig::chunk_max_span_ns`] (default 0.5 s, i.e. 60–61 ticks at 120 Hz)
//! or more from the chunk's first message, so one tick's messages share a chunk; after the
//! message that brings it to [`RecorderConfig::chunk_max_bytes`] (default 256 KiB); and on
//! [`McapRecorder::flush`]. Closing a chunk flushes it to the operating system, so a
//! process killed at any moment (even by SIGKILL) leaves a file whose header, metadata and
//! complete chunks a streaming reader reads (Rust: [`Recording::from_bytes`] or
//! `mcap::MessageStream`; Python: `mcap`'s non-seeking `StreamReader`); the loss is the open
//! chunk, at most one chunk bound of data. Chunks are zstd-compressed by default
//! ([`Compression`]). The summary is written on [`McapRecorder::finish`], and on drop when
//! `finish` was not called (early return, unwinding panic), so those exits leave a complete
//! file. SIGINT/SIGTERM are the binary's to turn into a normal exit.
//!
//! `scripts/mcap_check.py FILE` reads a file with the Python `mcap` package (an independent
//! implementation), prints channels, schema names, counts and metadata, and checks payloads
//! against their schemas.

mod error;
pub mod foxglove;
mod metadata;
mod read;
mod recorder;
mod schema;

pub use error::RecordError;
pub use metadata::{AMSTACK_VERSION, LOG_FORMAT_VERSION, RUN_METADATA_NAME, RunMetadata};
pub use read::{RecordedMessage, Recording};
pub use recorder::{
    Channel, ChannelInfo, Compression, McapRecorder, RecordSummary, RecorderConfig, Tap,
};
pub use schema::{MESSAGE_ENCODING, SCHEMA_ENCODING, SchemaName, json_schema_of};

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests;
