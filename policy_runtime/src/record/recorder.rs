//! [`McapRecorder`]: one run, one MCAP file, written chunk by chunk.

use std::collections::BTreeMap;
use std::fmt;
use std::fs::File;
use std::io::BufWriter;
use std::marker::PhantomData;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use mcap::records::MessageHeader;
use mcap::write::NoSeek;
use schemars::JsonSchema;
use serde::Serialize;

use super::{
    AMSTACK_VERSION, MESSAGE_ENCODING, RecordError, RunMetadata, SCHEMA_ENCODING, SchemaName,
    json_schema_of,
};

type McapWriter = mcap::Writer<NoSeek<BufWriter<File>>>;

/// Size of a message record outside its payload: opcode 1 + length 8 + channel 2 +
/// sequence 4 + log time 8 + publish time 8 bytes.
const MESSAGE_RECORD_OVERHEAD_BYTES: u64 = 31;

/// Hands out recorder identities, so a [`Channel`] cannot be used with the wrong recorder.
static NEXT_RECORDER_ID: AtomicU64 = AtomicU64::new(1);

/// Compression of the chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Compression {
    /// Zstandard (default level 3, single-threaded so the output does not depend on the
    /// machine's core count). JSON telemetry shrinks ~5–10×.
    #[default]
    Zstd,
    /// LZ4 (faster, larger).
    Lz4,
    /// None (for debugging a file with a hex viewer).
    None,
}

/// How the recorder cuts the data into chunks. A chunk reaches the operating system only when
/// it is complete, so these two bounds are also what a killed process can lose: at most one
/// chunk, i.e. under `chunk_max_span_ns` of log time or about `chunk_max_bytes` of messages,
/// whichever is less. Both count the logged data only (never the wall clock), so where chunks
/// are cut is part of the deterministic output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecorderConfig {
    /// A message whose log time is this far (ns) from the open chunk's earliest (or latest)
    /// message starts a new chunk: a chunk covers less than this span, and the messages of one
    /// tick (one log time) share a chunk. Default 0.5 s (60–61 control ticks at 120 Hz).
    pub chunk_max_span_ns: u64,
    /// The chunk is closed after the message that brings its uncompressed messages to this
    /// size, bytes. Default 256 KiB (about 0.5 s of a 120 Hz run logging ~15 channels of
    /// ~300 B), so the time bound usually cuts first.
    pub chunk_max_bytes: u64,
    /// Chunk compression. Default [`Compression::Zstd`].
    pub compression: Compression,
}

impl RecorderConfig {
    /// Default chunk span: 0.5 s of log time.
    pub const DEFAULT_CHUNK_MAX_SPAN_NS: u64 = 500_000_000;
    /// Default chunk size bound: 256 KiB.
    pub const DEFAULT_CHUNK_MAX_BYTES: u64 = 256 * 1024;

    /// Rejects bounds of zero (a chunk per message would be meant as 1, not 0).
    pub fn validate(&self) -> Result<(), String> {
        if self.chunk_max_span_ns == 0 {
            return Err("chunk_max_span_ns must be positive".to_owned());
        }
        if self.chunk_max_bytes == 0 {
            return Err("chunk_max_bytes must be positive".to_owned());
        }
        Ok(())
    }
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            chunk_max_span_ns: Self::DEFAULT_CHUNK_MAX_SPAN_NS,
            chunk_max_bytes: Self::DEFAULT_CHUNK_MAX_BYTES,
            compression: Compression::default(),
        }
    }
}

/// A registered channel: the handle [`McapRecorder::log`] takes for messages of type `T`.
pub struct Channel<T: ?Sized> {
    id: u16,
    recorder_id: u64,
    topic: String,
    _message: PhantomData<fn(&T)>,
}

impl<T: ?Sized> Channel<T> {
    /// The channel's topic.
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

impl<T: ?Sized> Clone for Channel<T> {
    fn clone(&self) -> Self {
        Self {
            id: self.id,
            recorder_id: self.recorder_id,
            topic: self.topic.clone(),
            _message: PhantomData,
        }
    }
}

impl<T: ?Sized> PartialEq for Channel<T> {
    fn eq(&self, other: &Self) -> bool {
        (self.id, self.recorder_id) == (other.id, other.recorder_id)
    }
}
impl<T: ?Sized> Eq for Channel<T> {}

impl<T: ?Sized> fmt::Debug for Channel<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Channel")
            .field("topic", &self.topic)
            .field("id", &self.id)
            .field("type", &std::any::type_name::<T>())
            .finish()
    }
}

/// What a finished file holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordSummary {
    /// The file.
    pub path: PathBuf,
    /// Messages per topic (every registered topic, zero included).
    pub message_counts: BTreeMap<String, u64>,
    /// All messages.
    pub message_count: u64,
    /// Chunks in the file.
    pub chunk_count: u32,
    /// Earliest and latest message log time, ns (`None` without messages).
    pub log_time_range_ns: Option<(u64, u64)>,
}

/// Per-topic bookkeeping.
struct Registered {
    id: u16,
    schema_name: String,
    schema: Vec<u8>,
    next_sequence: u32,
}

/// A channel as a live view needs it to advertise the topic (everything but the messages).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// The recorder's channel id (what [`Tap::message`] names).
    pub id: u16,
    /// Topic.
    pub topic: String,
    /// Schema name (`foxglove.SceneUpdate`, `amstack.Rotors`, …).
    pub schema_name: String,
    /// Schema encoding (`jsonschema`, `protobuf`).
    pub schema_encoding: String,
    /// The schema record's bytes.
    pub schema: Vec<u8>,
    /// Message encoding (`json`, `protobuf`).
    pub message_encoding: String,
}

/// Something that sees every channel and message the recorder writes, as written (the live
/// view, [`crate::live`]). Called on the flight loop's thread: an implementation must not
/// block.
pub trait Tap: Send {
    /// A channel was registered (before its first message).
    fn channel(&mut self, channel: &ChannelInfo);
    /// A message was logged on channel `id` at `log_time_ns`, payload as in the file.
    fn message(&mut self, id: u16, log_time_ns: u64, payload: &[u8]);
}

/// The chunk being filled.
#[derive(Clone, Copy)]
struct OpenChunk {
    min_log_ns: u64,
    max_log_ns: u64,
    bytes: u64,
    messages: u64,
}

/// Writes one run to one MCAP file. See the [module documentation](super) for the layout.
///
/// Dropping a recorder without [`finish`](Self::finish) (an early `?` return, a panic that
/// unwinds) still finishes the file, ignoring errors; call `finish` to see them.
pub struct McapRecorder {
    path: PathBuf,
    /// `None` only after [`Self::finish`] took it.
    writer: Option<McapWriter>,
    config: RecorderConfig,
    id: u64,
    topics: BTreeMap<String, Registered>,
    /// Scratch buffer for serialising messages.
    payload: Vec<u8>,
    chunk: Option<OpenChunk>,
    messages_logged: u64,
    messages_flushed: u64,
    /// Without a file ([`Self::file_less`]): messages go to the tap only.
    file_less: bool,
    tap: Option<Box<dyn Tap>>,
}

impl fmt::Debug for McapRecorder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("McapRecorder")
            .field("path", &self.path)
            .field("config", &self.config)
            .field("topics", &self.topics.keys().collect::<Vec<_>>())
            .field("messages_logged", &self.messages_logged)
            .field("messages_flushed", &self.messages_flushed)
            .field("file_less", &self.file_less)
            .field("tap", &self.tap.is_some())
            .finish_non_exhaustive()
    }
}

impl McapRecorder {
    /// Creates (or truncates) the file at `path` with the default [`RecorderConfig`] and writes
    /// the header and the `amstack.run` metadata record through to the operating system.
    pub fn create(path: impl AsRef<Path>, run: &RunMetadata) -> Result<Self, RecordError> {
        Self::create_with_config(path, run, &RecorderConfig::default())
    }

    /// [`Self::create`] with explicit chunking and compression.
    pub fn create_with_config(
        path: impl AsRef<Path>,
        run: &RunMetadata,
        config: &RecorderConfig,
    ) -> Result<Self, RecordError> {
        let path = path.as_ref().to_path_buf();
        config.validate().map_err(RecordError::Config)?;
        run.validate()?;
        let file = File::create(&path).map_err(|source| RecordError::Create {
            path: path.clone(),
            source,
        })?;
        let compression = match config.compression {
            Compression::Zstd => Some(mcap::Compression::Zstd),
            Compression::Lz4 => Some(mcap::Compression::Lz4),
            Compression::None => None,
        };
        let options = mcap::WriteOptions::new()
            .library(format!(
                "amstack-{AMSTACK_VERSION}; {}",
                mcap::LIBRARY_IDENTIFIER
            ))
            .compression(compression)
            // Chunks are cut by `log_at` (deterministic bounds, flushed when cut), never by
            // the mcap writer on its own.
            .chunk_size(None)
            // Build each chunk in memory and write it whole once complete: a killed process
            // then leaves complete chunks, never a chunk header still waiting for its length.
            .disable_seeking(true)
            // Single-threaded zstd: the compressed bytes must not depend on the core count.
            .compression_threads(0);
        let wrap = |source| RecordError::Write {
            path: path.clone(),
            source,
        };
        let mut writer = options
            .create(NoSeek::new(BufWriter::new(file)))
            .map_err(wrap)?;
        writer.write_metadata(&run.to_record()).map_err(wrap)?;
        writer.flush().map_err(wrap)?;
        Ok(Self {
            path,
            writer: Some(writer),
            config: config.clone(),
            id: NEXT_RECORDER_ID.fetch_add(1, Ordering::Relaxed),
            topics: BTreeMap::new(),
            payload: Vec::new(),
            chunk: None,
            messages_logged: 0,
            messages_flushed: 0,
            file_less: false,
            tap: None,
        })
    }

    /// The recorder of one flight: the log file at `path` (its metadata from `run`, asked only
    /// then), also shown to `tap` (the live view) when there is one; `tap` alone without a
    /// path; none without either.
    pub fn for_flight(
        path: Option<&Path>,
        tap: Option<Box<dyn Tap>>,
        run: impl FnOnce() -> Result<RunMetadata, RecordError>,
    ) -> Result<Option<Self>, RecordError> {
        Ok(match (path, tap) {
            (None, None) => None,
            (None, Some(tap)) => Some(Self::file_less(tap)),
            (Some(path), tap) => {
                let recorder = Self::create(path, &run()?)?;
                Some(match tap {
                    Some(tap) => recorder.with_tap(tap),
                    None => recorder,
                })
            }
        })
    }

    /// A recorder that writes no file: every channel and message goes to `tap` only (a live
    /// view of a flight that is not logged). [`Self::finish`] reports what was logged, with
    /// an empty path and no chunk.
    pub fn file_less(tap: Box<dyn Tap>) -> Self {
        Self {
            path: PathBuf::new(),
            writer: None,
            config: RecorderConfig::default(),
            id: NEXT_RECORDER_ID.fetch_add(1, Ordering::Relaxed),
            topics: BTreeMap::new(),
            payload: Vec::new(),
            chunk: None,
            messages_logged: 0,
            messages_flushed: 0,
            file_less: true,
            tap: Some(tap),
        }
    }

    /// Shows every channel (those already registered first) and message from here on to
    /// `tap` as well (the live view).
    pub fn with_tap(mut self, mut tap: Box<dyn Tap>) -> Self {
        for (topic, r) in &self.topics {
            tap.channel(&ChannelInfo {
                id: r.id,
                topic: topic.clone(),
                schema_name: r.schema_name.clone(),
                schema_encoding: SCHEMA_ENCODING.to_owned(),
                schema: r.schema.clone(),
                message_encoding: MESSAGE_ENCODING.to_owned(),
            });
        }
        self.tap = Some(tap);
        self
    }

    /// Registers `topic` for messages of type `T`, with the JSON Schema of `T` under the name
    /// [`T::SCHEMA_NAME`](SchemaName::SCHEMA_NAME). Registering a topic again with the same
    /// schema returns an equal handle; with another schema it is an error.
    pub fn channel<T: JsonSchema + SchemaName + ?Sized>(
        &mut self,
        topic: &str,
    ) -> Result<Channel<T>, RecordError> {
        let schema = json_schema_of::<T>().map_err(|source| RecordError::Serialize {
            topic: topic.to_owned(),
            source,
        })?;
        self.register(
            topic,
            T::SCHEMA_NAME,
            SCHEMA_ENCODING,
            schema,
            MESSAGE_ENCODING,
        )
    }

    /// Registers `topic` for a Foxglove SDK message type `T` (`foxglove::schemas::SceneUpdate`,
    /// `FrameTransforms`, …): its schema record is the SDK's (name `foxglove.<Type>`, encoding
    /// `protobuf`, the FileDescriptorSet), its messages the SDK's encoding of them. Log with
    /// [`Self::log_encoded`].
    pub fn encoded_channel<T: foxglove::Encode>(
        &mut self,
        topic: &str,
    ) -> Result<Channel<T>, RecordError> {
        let schema = T::get_schema().ok_or_else(|| {
            RecordError::Config(format!(
                "{topic}: the message type {} has no schema",
                std::any::type_name::<T>()
            ))
        })?;
        self.register(
            topic,
            &schema.name,
            &schema.encoding,
            schema.data.into_owned(),
            &T::get_message_encoding(),
        )
    }

    fn register<T: ?Sized>(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema: Vec<u8>,
        message_encoding: &str,
    ) -> Result<Channel<T>, RecordError> {
        if let Some(existing) = self.topics.get(topic) {
            if existing.schema_name != schema_name || existing.schema != schema {
                return Err(RecordError::TopicConflict {
                    topic: topic.to_owned(),
                    existing: existing.schema_name.clone(),
                    requested: if existing.schema_name == schema_name {
                        format!("{schema_name} with a different schema")
                    } else {
                        schema_name.to_owned()
                    },
                });
            }
            return Ok(self.handle(existing.id, topic));
        }
        let id = if self.file_less {
            u16::try_from(self.topics.len() + 1)
                .map_err(|_| RecordError::Config(format!("{topic}: more than 65535 channels")))?
        } else {
            let path = &self.path;
            let writer = Self::writer_of(&mut self.writer, path)?;
            let wrap = |source| RecordError::Write {
                path: path.clone(),
                source,
            };
            let schema_id = writer
                .add_schema(schema_name, schema_encoding, &schema)
                .map_err(wrap)?;
            writer
                .add_channel(schema_id, topic, message_encoding, &BTreeMap::new())
                .map_err(wrap)?
        };
        if let Some(tap) = &mut self.tap {
            tap.channel(&ChannelInfo {
                id,
                topic: topic.to_owned(),
                schema_name: schema_name.to_owned(),
                schema_encoding: schema_encoding.to_owned(),
                schema: schema.clone(),
                message_encoding: message_encoding.to_owned(),
            });
        }
        self.topics.insert(
            topic.to_owned(),
            Registered {
                id,
                schema_name: schema_name.to_owned(),
                schema,
                next_sequence: 0,
            },
        );
        Ok(self.handle(id, topic))
    }

    fn handle<T: ?Sized>(&self, id: u16, topic: &str) -> Channel<T> {
        Channel {
            id,
            recorder_id: self.id,
            topic: topic.to_owned(),
            _message: PhantomData,
        }
    }

    /// Logs `msg` on `channel` with log time = publish time = `time_ns`: the run's own time in
    /// nanoseconds (simulated time in the twin), never the wall clock.
    pub fn log<T: Serialize + ?Sized>(
        &mut self,
        channel: &Channel<T>,
        time_ns: u64,
        msg: &T,
    ) -> Result<(), RecordError> {
        self.log_at(channel, time_ns, time_ns, msg)
    }

    /// Logs `msg` with distinct times: `log_time_ns` when the flight stack received or produced
    /// it, `publish_time_ns` when its source stamped it (e.g. autopilot telemetry).
    pub fn log_at<T: Serialize + ?Sized>(
        &mut self,
        channel: &Channel<T>,
        log_time_ns: u64,
        publish_time_ns: u64,
        msg: &T,
    ) -> Result<(), RecordError> {
        self.check_own(channel)?;
        self.payload.clear();
        serde_json::to_writer(&mut self.payload, msg).map_err(|source| RecordError::Serialize {
            topic: channel.topic.clone(),
            source,
        })?;
        self.write_payload(channel, log_time_ns, publish_time_ns)
    }

    /// Logs a Foxglove SDK message on a channel of [`Self::encoded_channel`] at `time_ns`
    /// (log time = publish time), in the SDK's encoding.
    pub fn log_encoded<T: foxglove::Encode>(
        &mut self,
        channel: &Channel<T>,
        time_ns: u64,
        msg: &T,
    ) -> Result<(), RecordError> {
        self.check_own(channel)?;
        self.payload.clear();
        msg.encode(&mut self.payload)
            .map_err(|e| RecordError::Encode {
                topic: channel.topic.clone(),
                message: e.to_string(),
            })?;
        self.write_payload(channel, time_ns, time_ns)
    }

    fn check_own<T: ?Sized>(&self, channel: &Channel<T>) -> Result<(), RecordError> {
        if channel.recorder_id == self.id {
            Ok(())
        } else {
            Err(RecordError::ForeignChannel {
                topic: channel.topic.clone(),
            })
        }
    }

    /// Writes `self.payload` on `channel`.
    fn write_payload<T: ?Sized>(
        &mut self,
        channel: &Channel<T>,
        log_time_ns: u64,
        publish_time_ns: u64,
    ) -> Result<(), RecordError> {
        let registered =
            self.topics
                .get_mut(&channel.topic)
                .ok_or_else(|| RecordError::ForeignChannel {
                    topic: channel.topic.clone(),
                })?;
        let sequence = registered.next_sequence;
        registered.next_sequence = sequence.wrapping_add(1);
        if let Some(tap) = &mut self.tap {
            tap.message(channel.id, log_time_ns, &self.payload);
        }
        if self.file_less {
            self.messages_logged += 1;
            return Ok(());
        }
        let header = MessageHeader {
            channel_id: channel.id,
            sequence,
            log_time: log_time_ns,
            publish_time: publish_time_ns,
        };
        // Time bound, checked before writing: a chunk covers less than `chunk_max_span_ns` of
        // log time, and messages sharing a time (one control tick) stay in one chunk.
        if let Some(c) = self.chunk
            && c.max_log_ns.max(log_time_ns) - c.min_log_ns.min(log_time_ns)
                >= self.config.chunk_max_span_ns
        {
            self.flush()?;
        }
        let path = &self.path;
        Self::writer_of(&mut self.writer, path)?
            .write_to_known_channel(&header, &self.payload)
            .map_err(|source| RecordError::Write {
                path: path.clone(),
                source,
            })?;
        self.messages_logged += 1;

        let bytes = MESSAGE_RECORD_OVERHEAD_BYTES + self.payload.len() as u64;
        let chunk = match self.chunk {
            None => OpenChunk {
                min_log_ns: log_time_ns,
                max_log_ns: log_time_ns,
                bytes,
                messages: 1,
            },
            Some(c) => OpenChunk {
                min_log_ns: c.min_log_ns.min(log_time_ns),
                max_log_ns: c.max_log_ns.max(log_time_ns),
                bytes: c.bytes + bytes,
                messages: c.messages + 1,
            },
        };
        self.chunk = Some(chunk);
        // Size bound, checked after writing.
        if chunk.bytes >= self.config.chunk_max_bytes {
            self.flush()?;
        }
        Ok(())
    }

    /// Closes the open chunk (if any) and hands everything written so far to the operating
    /// system: from here on a killed process loses none of it. (Not an fsync: a power cut can.)
    pub fn flush(&mut self) -> Result<(), RecordError> {
        if self.file_less {
            return Ok(());
        }
        let path = &self.path;
        Self::writer_of(&mut self.writer, path)?
            .flush()
            .map_err(|source| RecordError::Write {
                path: path.clone(),
                source,
            })?;
        if let Some(chunk) = self.chunk.take() {
            self.messages_flushed += chunk.messages;
        }
        Ok(())
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Messages logged so far.
    pub fn messages_logged(&self) -> u64 {
        self.messages_logged
    }

    /// Messages in complete chunks already handed to the operating system: what a reader of the
    /// file finds if the process is killed now.
    pub fn messages_flushed(&self) -> u64 {
        self.messages_flushed
    }

    /// Writes the last chunk and the summary section (statistics, chunk and metadata indexes),
    /// flushes and syncs the file, and reports what it holds.
    pub fn finish(mut self) -> Result<RecordSummary, RecordError> {
        if self.file_less {
            return Ok(RecordSummary {
                path: PathBuf::new(),
                message_counts: self
                    .topics
                    .iter()
                    .map(|(t, r)| (t.clone(), u64::from(r.next_sequence)))
                    .collect(),
                message_count: self.messages_logged,
                chunk_count: 0,
                log_time_range_ns: None,
            });
        }
        let writer = Self::writer_of(&mut self.writer, &self.path)?;
        let summary = writer.finish().map_err(|source| RecordError::Write {
            path: self.path.clone(),
            source,
        })?;
        // Close the file (Drop would do it too, without reporting errors).
        if let Some(writer) = self.writer.take() {
            close(&self.path, writer)?;
        }
        let names: BTreeMap<u16, &String> =
            self.topics.iter().map(|(topic, r)| (r.id, topic)).collect();
        let mut message_counts: BTreeMap<String, u64> =
            self.topics.keys().map(|t| (t.clone(), 0)).collect();
        let stats = summary.stats.unwrap_or_default();
        for (id, count) in &stats.channel_message_counts {
            if let Some(topic) = names.get(id) {
                message_counts.insert((*topic).clone(), *count);
            }
        }
        Ok(RecordSummary {
            path: self.path.clone(),
            message_counts,
            message_count: stats.message_count,
            chunk_count: stats.chunk_count,
            log_time_range_ns: (stats.message_count > 0)
                .then_some((stats.message_start_time, stats.message_end_time)),
        })
    }

    fn writer_of<'w>(
        writer: &'w mut Option<McapWriter>,
        path: &Path,
    ) -> Result<&'w mut McapWriter, RecordError> {
        // Unreachable through the public API (`finish` consumes the recorder); an error rather
        // than a panic all the same.
        writer.as_mut().ok_or_else(|| RecordError::Write {
            path: path.to_path_buf(),
            source: mcap::McapError::AttemptedWriteAfterFailure,
        })
    }
}

/// Flushes the buffered tail of a finished writer and syncs the file to disk.
fn close(path: &Path, writer: McapWriter) -> Result<(), RecordError> {
    let wrap = |source| RecordError::Close {
        path: path.to_path_buf(),
        source,
    };
    let file = writer
        .into_inner()
        .into_inner()
        .into_inner()
        .map_err(|e| wrap(e.into_error()))?;
    file.sync_all().map_err(wrap)
}

impl Drop for McapRecorder {
    fn drop(&mut self) {
        if let Some(mut writer) = self.writer.take() {
            // Best effort: finish the summary so the file is complete; errors have nowhere to
            // go from a destructor (and the chunks already flushed stay readable regardless).
            if writer.finish().is_ok() {
                let _ = close(&self.path, writer);
            }
        }
    }
}
