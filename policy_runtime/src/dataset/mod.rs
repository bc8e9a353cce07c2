//! Demonstration datasets in the LeRobot v3.0 layout (`lerobot` ≥ 0.4), written and read
//! with the Apache Arrow / Parquet crates (AMBENCH_SPEC §7).
//!
//! ```text
//! DIR/meta/info.json                                codebase v3.0, fps, features, totals, ambench block
//! DIR/meta/stats.json                               per feature: min max mean std count q01 q10 q50 q90 q99
//! DIR/meta/tasks.parquet                            task (the prompt, pandas index) → task_index
//! DIR/meta/episodes/chunk-000/file-000.parquet      per episode: tasks, length, data file, index range, stats
//! DIR/data/chunk-000/file-000.parquet               frames of many episodes; a new file past 100 MB
//! ```
//!
//! A frame k of an episode holds the observation of tick k (`observation.state`, the
//! images) and the action applied after it (`action`), `timestamp` = k / fps, and its
//! indices. An episode is written whole or not at all ([`DatasetWriter::write_episode`]:
//! every file goes to a temporary file, is synced and renamed over the old one; the data
//! before the metadata, `info.json` last), so a run that dies leaves a valid dataset.
//!
//! - [`layout`]: the features, state keys, action semantics, task prompts;
//! - [`stats`]: lerobot's statistics;
//! - [`DatasetWriter`], [`DatasetReader`]; [`validate`]; [`export_openpi`] (the v2.1 layout
//!   of openpi at 20 Hz); [`merge`];
//! - [`merge_shards`]: the shards of a recording (`record --shard I/N`, [`ShardPart`]) merged
//!   into the dataset the unsharded recording writes;
//! - [`Recorder`]: the flight observer that makes the frames, [`RecordedActions`] the source
//!   that flies them again.

mod error;
mod json;
pub mod layout;
mod openpi;
mod read;
mod recorder;
mod repair;
mod shard;
pub mod stats;
mod validate;
mod video;
mod write;

pub use self::error::DatasetError;
pub use self::layout::{
    ActionSemantics, DatasetSpec, Dtype, Feature, StateKey, action_of_vector, action_vector,
    image_key, state_vector, task_prompt,
};
pub use self::openpi::{OpenpiExport, export_openpi};
pub use self::read::{DatasetReader, EpisodeRow, EpisodeVideo};
pub use self::recorder::{
    Attempt, QuantizedActions, RecordConfig, RecordError, RecordReport, RecordedActions, Recorder,
    record,
};
pub use self::repair::Repair;
pub use self::shard::{
    DecidedAttempt, RECORD_SHARD_ASSIGNMENT, ShardMerge, ShardPart, is_shard, merge_shards,
};
pub use self::validate::validate;
pub use self::write::{
    DatasetWriter, EpisodeFrames, EpisodeSource, EpisodeVideoFile, decode_png, encode_png, merge,
};

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]
mod tests;
