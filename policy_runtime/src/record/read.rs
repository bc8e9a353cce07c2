//! Reading a run back: a streaming pass over the file that keeps what it can read, so a file
//! cut short by a crash yields every message of its complete chunks.

use std::collections::BTreeMap;

use mcap::read::{ChunkFlattener, Options};
use mcap::records::Record;

use super::{RUN_METADATA_NAME, RecordError, RunMetadata};

/// One message as stored.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedMessage {
    /// Channel topic.
    pub topic: String,
    /// Schema name of the channel (`None` for a schemaless channel, which amstack never writes).
    pub schema_name: Option<String>,
    /// Per-channel sequence number.
    pub sequence: u32,
    /// Log time, ns.
    pub log_time_ns: u64,
    /// Publish time, ns.
    pub publish_time_ns: u64,
    /// The JSON payload.
    pub data: Vec<u8>,
}

/// What a streaming read of a file found.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The `amstack.run` metadata, if the file has it.
    pub run: Option<RunMetadata>,
    /// Every readable message, in file order.
    pub messages: Vec<RecordedMessage>,
    /// Whether the file ended with its footer and magic: `false` for a run that was killed.
    pub complete: bool,
    /// Why reading stopped before the footer (the truncation or damage), if it did.
    pub stopped_by: Option<String>,
}

impl Recording {
    /// Reads a whole file from memory, front to back (chunk CRCs checked). Fails only when the
    /// first record (magic and header) cannot be read; after it, everything is kept up to the
    /// first unreadable record (a cut-short chunk is dropped whole).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, RecordError> {
        let mut records =
            ChunkFlattener::new_with_options(bytes, Options::ValidateChunkCrcs.into())?;
        let mut schema_names: BTreeMap<u16, String> = BTreeMap::new();
        let mut channels: BTreeMap<u16, (String, u16)> = BTreeMap::new();
        let mut recording = Recording {
            run: None,
            messages: Vec::new(),
            complete: false,
            stopped_by: None,
        };
        let mut first = true;
        for record in records.by_ref() {
            let record = match record {
                Ok(record) => record,
                Err(e) if first => return Err(RecordError::Read(e)),
                Err(e) => {
                    recording.stopped_by = Some(e.to_string());
                    break;
                }
            };
            first = false;
            match record {
                Record::Schema { header, .. } => {
                    schema_names.insert(header.id, header.name);
                }
                Record::Channel(c) => {
                    channels.insert(c.id, (c.topic, c.schema_id));
                }
                Record::Metadata(m) if m.name == RUN_METADATA_NAME => {
                    recording.run = Some(RunMetadata::from_record_map(&m.metadata)?);
                }
                Record::Message { header, data } => {
                    let Some((topic, schema_id)) = channels.get(&header.channel_id) else {
                        recording.stopped_by =
                            Some(format!("message on unknown channel {}", header.channel_id));
                        break;
                    };
                    recording.messages.push(RecordedMessage {
                        topic: topic.clone(),
                        schema_name: schema_names.get(schema_id).cloned(),
                        sequence: header.sequence,
                        log_time_ns: header.log_time,
                        publish_time_ns: header.publish_time,
                        data: data.into_owned(),
                    });
                }
                Record::Footer(_) => recording.complete = true,
                _ => {}
            }
        }
        // A footer followed by garbage is not a complete file.
        if recording.stopped_by.is_some() {
            recording.complete = false;
        }
        Ok(recording)
    }

    /// Messages per topic.
    pub fn message_counts(&self) -> BTreeMap<String, u64> {
        let mut counts = BTreeMap::new();
        for m in &self.messages {
            *counts.entry(m.topic.clone()).or_insert(0) += 1;
        }
        counts
    }
}
