//! Recorder contracts that need no second process (the SIGKILL test and the Python reader are
//! in `tests/recorder_contract.rs`).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Isometry3, Vector3};
use schemars::JsonSchema;
use serde::Serialize;

use super::foxglove::{FrameTransform, FrameTransforms, PoseInFrame};
use super::*;

/// 120 Hz control tick, ns.
const TICK_NS: u64 = 8_333_333;

#[derive(Debug, Clone, Serialize, JsonSchema)]
struct Tick {
    tick: u64,
    /// Rotor thrusts, N.
    thrust_n: [f64; 6],
    saturated: bool,
}
impl SchemaName for Tick {
    const SCHEMA_NAME: &'static str = "amstack.test.Tick";
}

#[derive(Debug, Clone, Serialize, JsonSchema)]
struct Other {
    value: f64,
}
impl SchemaName for Other {
    const SCHEMA_NAME: &'static str = "amstack.test.Other";
}

fn run_metadata() -> RunMetadata {
    RunMetadata::new("fa-hexa", "pid", 42)
        .with_trajectory("hover")
        .with_config(&serde_json::json!({"rate_hz": 120.0, "disturbances": ["drag", "wind"]}))
        .unwrap()
}

/// Logs `ticks` control ticks on three channels (pose, transforms, our own type); values are
/// a deterministic function of the tick.
fn log_ticks(rec: &mut McapRecorder, ticks: u64) {
    let pose = rec.channel::<PoseInFrame>("/base/pose").unwrap();
    let tf = rec.channel::<FrameTransforms>("/tf").unwrap();
    let tick_ch = rec.channel::<Tick>("/controller/tick").unwrap();
    for k in 0..ticks {
        let t_ns = k * TICK_NS;
        let t = t_ns as f64 * 1e-9;
        let world_from_base = Isometry3::new(
            Vector3::new(0.1 * t.sin(), 0.0, 1.0 + 0.01 * t),
            Vector3::z() * (0.3 * t),
        );
        rec.log(
            &pose,
            t_ns,
            &PoseInFrame::new(t_ns, "world", &world_from_base),
        )
        .unwrap();
        let transforms = FrameTransforms {
            transforms: vec![
                FrameTransform::new(t_ns, "world", "base_link", &world_from_base),
                FrameTransform::new(
                    t_ns,
                    "base_link",
                    "link1",
                    &Isometry3::translation(0.0, 0.0, -0.1),
                ),
            ],
        };
        rec.log(&tf, t_ns, &transforms).unwrap();
        let thrust = 9.81 * 4.2 / 6.0 + 1e-3 * (k as f64);
        let msg = Tick {
            tick: k,
            thrust_n: [thrust; 6],
            saturated: k % 50 == 0,
        };
        rec.log(&tick_ch, t_ns, &msg).unwrap();
    }
}

fn record(path: &Path, ticks: u64, config: &RecorderConfig) -> RecordSummary {
    let mut rec = McapRecorder::create_with_config(path, &run_metadata(), config).unwrap();
    log_ticks(&mut rec, ticks);
    rec.finish().unwrap()
}

#[test]
fn finished_file_holds_every_message_with_its_schema_and_the_run_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let summary = record(&path, 240, &RecorderConfig::default());
    let expected: BTreeMap<String, u64> =
        [("/base/pose", 240), ("/controller/tick", 240), ("/tf", 240)]
            .into_iter()
            .map(|(t, n)| (t.to_owned(), n))
            .collect();
    assert_eq!(summary.message_counts, expected);
    assert_eq!(summary.message_count, 720);
    assert_eq!(summary.log_time_range_ns, Some((0, 239 * TICK_NS)));
    // 2 s at 120 Hz with 0.5 s chunks.
    assert!((4..=5).contains(&summary.chunk_count), "{summary:?}");

    let bytes = std::fs::read(&path).unwrap();
    let recording = Recording::from_bytes(&bytes).unwrap();
    assert!(recording.complete, "{:?}", recording.stopped_by);
    assert_eq!(recording.message_counts(), expected);
    assert_eq!(
        recording.run,
        Some(run_metadata()),
        "metadata round-trips through the file"
    );
    let names: BTreeMap<&str, &str> = recording
        .messages
        .iter()
        .map(|m| (m.topic.as_str(), m.schema_name.as_deref().unwrap()))
        .collect();
    assert_eq!(names["/base/pose"], "foxglove.PoseInFrame");
    assert_eq!(names["/tf"], "foxglove.FrameTransforms");
    assert_eq!(names["/controller/tick"], "amstack.test.Tick");
    for m in &recording.messages {
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        assert!(v.is_object());
        assert_eq!(m.log_time_ns, m.publish_time_ns);
    }
    let ticks: Vec<u32> = recording
        .messages
        .iter()
        .filter(|m| m.topic == "/controller/tick")
        .map(|m| m.sequence)
        .collect();
    assert_eq!(
        ticks,
        (0..240).collect::<Vec<u32>>(),
        "per-channel sequence numbers"
    );

    // The summary section is there: a seeking reader finds statistics and the metadata index.
    let mcap_summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert_eq!(mcap_summary.stats.unwrap().message_count, 720);
    assert_eq!(mcap_summary.metadata_indexes.len(), 1);
    assert_eq!(mcap_summary.metadata_indexes[0].name, RUN_METADATA_NAME);
    let meta = mcap::read::metadata(&bytes, &mcap_summary.metadata_indexes[0]).unwrap();
    assert_eq!(
        RunMetadata::from_record_map(&meta.metadata).unwrap(),
        run_metadata()
    );
    // The schema records carry the JSON Schema under the schema name.
    let schema = mcap_summary
        .schemas
        .values()
        .find(|s| s.name == "foxglove.PoseInFrame")
        .unwrap();
    assert_eq!(schema.encoding, SCHEMA_ENCODING);
    assert_eq!(&*schema.data, &json_schema_of::<PoseInFrame>().unwrap()[..]);
    assert!(
        mcap_summary
            .channels
            .values()
            .all(|c| c.message_encoding == MESSAGE_ENCODING)
    );
}

#[test]
fn same_messages_and_times_give_identical_payloads_and_identical_files() {
    let dir = tempfile::tempdir().unwrap();
    for compression in [Compression::Zstd, Compression::Lz4, Compression::None] {
        let config = RecorderConfig {
            compression,
            ..RecorderConfig::default()
        };
        let a = dir.path().join("a.mcap");
        let b = dir.path().join("b.mcap");
        record(&a, 150, &config);
        record(&b, 150, &config);
        let (bytes_a, bytes_b) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        let (ra, rb) = (
            Recording::from_bytes(&bytes_a).unwrap(),
            Recording::from_bytes(&bytes_b).unwrap(),
        );
        assert_eq!(ra.messages.len(), 450);
        assert_eq!(
            ra.messages, rb.messages,
            "{compression:?}: payloads and times"
        );
        assert!(bytes_a == bytes_b, "{compression:?}: whole files differ");
    }
}

#[test]
fn file_on_disk_holds_exactly_the_flushed_chunks_while_the_run_goes_on() {
    // What a crash at any instant leaves: read the file while the recorder is still writing.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("live.mcap");
    let config = RecorderConfig {
        chunk_max_span_ns: 100_000_000,
        ..RecorderConfig::default()
    };
    let mut rec = McapRecorder::create_with_config(&path, &run_metadata(), &config).unwrap();
    // Before any message: header and metadata are already on disk.
    let early = Recording::from_bytes(&std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(early.run, Some(run_metadata()));
    assert!(early.messages.is_empty() && !early.complete);

    let ch = rec.channel::<Tick>("/controller/tick").unwrap();
    let mut flushes = 0;
    for k in 0..100u64 {
        let before = rec.messages_flushed();
        let msg = Tick {
            tick: k,
            thrust_n: [1.0; 6],
            saturated: false,
        };
        rec.log(&ch, k * TICK_NS, &msg).unwrap();
        if rec.messages_flushed() != before {
            flushes += 1;
        }
        let on_disk = Recording::from_bytes(&std::fs::read(&path).unwrap()).unwrap();
        assert!(!on_disk.complete);
        assert_eq!(
            on_disk.messages.len() as u64,
            rec.messages_flushed(),
            "tick {k}"
        );
    }
    // 0.1 s chunks at 120 Hz: 13 ticks span 12 × 8.333333 ms < 0.1 s, so the 14th message
    // starts a new chunk: a chunk is closed before messages 13, 26, …, 91.
    assert_eq!(flushes, 100 / 13);
    assert_eq!(rec.messages_logged(), 100);
    // Never more than one chunk bound behind.
    assert!(rec.messages_logged() - rec.messages_flushed() < 13);
}

#[test]
fn a_file_cut_at_any_byte_reads_as_its_whole_chunks() {
    // A kill during the write of a chunk leaves part of it: readers must drop that part only.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.mcap");
    let config = RecorderConfig {
        chunk_max_span_ns: 100_000_000,
        ..RecorderConfig::default()
    };
    let mut rec = McapRecorder::create_with_config(&path, &run_metadata(), &config).unwrap();
    let ch = rec.channel::<Tick>("/t").unwrap();
    let mut boundaries = vec![0];
    for k in 0..60u64 {
        rec.log(
            &ch,
            k * TICK_NS,
            &Tick {
                tick: k,
                thrust_n: [1.0; 6],
                saturated: false,
            },
        )
        .unwrap();
        if boundaries.last() != Some(&rec.messages_flushed()) {
            boundaries.push(rec.messages_flushed());
        }
    }
    boundaries.push(60);
    rec.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let mut previous = 0;
    let mut readable = false;
    for len in (0..bytes.len()).step_by(3) {
        // Only a cut inside the magic or the header record is not an MCAP file at all.
        let recording = match Recording::from_bytes(&bytes[..len]) {
            Ok(recording) => recording,
            Err(e) => {
                assert!(
                    !readable,
                    "cut at {len}: {e} after shorter cuts were readable"
                );
                continue;
            }
        };
        readable = true;
        let n = recording.messages.len() as u64;
        assert!(!recording.complete, "cut at {len}");
        assert!(
            boundaries.contains(&n),
            "cut at {len}: {n} messages, chunks end at {boundaries:?}"
        );
        assert!(n >= previous, "cut at {len}");
        previous = n;
    }
    assert_eq!(
        previous, 60,
        "the data section is complete before the summary"
    );
}

#[test]
fn byte_bound_cuts_chunks_too() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bytes.mcap");
    let config = RecorderConfig {
        chunk_max_bytes: 1024,
        ..RecorderConfig::default()
    };
    let mut rec = McapRecorder::create_with_config(&path, &run_metadata(), &config).unwrap();
    let ch = rec.channel::<Tick>("/t").unwrap();
    for k in 0..20u64 {
        // All at the same time: only the byte bound can cut.
        rec.log(
            &ch,
            0,
            &Tick {
                tick: k,
                thrust_n: [1.0; 6],
                saturated: false,
            },
        )
        .unwrap();
    }
    assert!(rec.messages_flushed() >= 10, "{rec:?}");
    let summary = rec.finish().unwrap();
    assert!(summary.chunk_count >= 2, "{summary:?}");
}

#[test]
fn dropping_without_finish_still_completes_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let dropped = dir.path().join("dropped.mcap");
    {
        let mut rec = McapRecorder::create(&dropped, &run_metadata()).unwrap();
        log_ticks(&mut rec, 10);
    }
    let recording = Recording::from_bytes(&std::fs::read(&dropped).unwrap()).unwrap();
    assert!(recording.complete);
    assert_eq!(recording.messages.len(), 30);

    // An unwinding panic mid-run is an exit path too.
    let panicked = dir.path().join("panicked.mcap");
    let result = std::panic::catch_unwind(|| {
        let mut rec = McapRecorder::create(&panicked, &run_metadata()).unwrap();
        log_ticks(&mut rec, 10);
        panic!("controller diverged");
    });
    assert!(result.is_err());
    let recording = Recording::from_bytes(&std::fs::read(&panicked).unwrap()).unwrap();
    assert!(recording.complete);
    assert_eq!(recording.messages.len(), 30);
}

#[test]
fn bad_path_is_an_error_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no/such/folder/run.mcap");
    let err = McapRecorder::create(&missing, &run_metadata()).unwrap_err();
    assert!(matches!(err, RecordError::Create { .. }), "{err:?}");
    assert!(err.to_string().contains("no/such/folder/run.mcap"), "{err}");
    // A folder is not a file either.
    let err = McapRecorder::create(dir.path(), &run_metadata()).unwrap_err();
    assert!(
        err.to_string().contains(&dir.path().display().to_string()),
        "{err}"
    );
}

#[test]
fn unusable_metadata_or_config_is_rejected_before_the_file_is_created() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("never.mcap");
    let mut bad = run_metadata();
    bad.config_json = "not json".to_owned();
    assert!(matches!(
        McapRecorder::create(&path, &bad),
        Err(RecordError::Metadata(_))
    ));
    let zero = RecorderConfig {
        chunk_max_span_ns: 0,
        ..RecorderConfig::default()
    };
    assert!(matches!(
        McapRecorder::create_with_config(&path, &run_metadata(), &zero),
        Err(RecordError::Config(_))
    ));
    assert!(!path.exists());
}

#[test]
fn a_topic_has_one_schema_and_a_channel_one_recorder() {
    let dir = tempfile::tempdir().unwrap();
    let mut rec = McapRecorder::create(dir.path().join("a.mcap"), &run_metadata()).unwrap();
    let first = rec.channel::<Tick>("/t").unwrap();
    let again = rec.channel::<Tick>("/t").unwrap();
    assert_eq!(first, again);
    let err = rec.channel::<Other>("/t").unwrap_err();
    assert!(matches!(err, RecordError::TopicConflict { .. }), "{err}");
    assert!(err.to_string().contains("amstack.test.Tick"), "{err}");

    let mut other = McapRecorder::create(dir.path().join("b.mcap"), &run_metadata()).unwrap();
    let err = other
        .log(
            &first,
            0,
            &Tick {
                tick: 0,
                thrust_n: [0.0; 6],
                saturated: false,
            },
        )
        .unwrap_err();
    assert!(matches!(err, RecordError::ForeignChannel { .. }), "{err}");
    rec.log(
        &again,
        5,
        &Tick {
            tick: 0,
            thrust_n: [0.0; 6],
            saturated: false,
        },
    )
    .unwrap();
    assert_eq!(rec.finish().unwrap().message_counts["/t"], 1);
}

#[test]
fn publish_time_may_differ_from_log_time() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("times.mcap");
    let mut rec = McapRecorder::create(&path, &run_metadata()).unwrap();
    let ch = rec.channel::<Other>("/telemetry").unwrap();
    rec.log_at(&ch, 2_000, 1_500, &Other { value: 0.1 })
        .unwrap();
    rec.finish().unwrap();
    let m = &Recording::from_bytes(&std::fs::read(&path).unwrap())
        .unwrap()
        .messages[0];
    assert_eq!((m.log_time_ns, m.publish_time_ns), (2_000, 1_500));
    assert_eq!(m.data, br#"{"value":0.1}"#);
}

#[test]
fn non_mcap_bytes_are_an_error_not_an_empty_recording() {
    assert!(Recording::from_bytes(b"definitely not an mcap file").is_err());
    assert!(Recording::from_bytes(b"").is_err());
}
