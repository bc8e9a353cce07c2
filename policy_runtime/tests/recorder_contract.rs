//! Contracts of the MCAP recorder that need another process: a run killed with SIGKILL leaves a
//! readable file, and an independent reader (the Python `mcap` package, through
//! `scripts/mcap_check.py`) reads our files with the counts we wrote.
//!
//! The Python tests call `scripts/setup-python.sh` first (idempotent; creates the venv with the
//! pinned `mcap` on a fresh machine, which needs PyPI).

#![allow(
    clippy::unwrap_used,
    reason = "contract tests: a failed set-up or child process fails loudly"
)]

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};

use nalgebra::{Isometry3, Vector3};
use policy_runtime::record::foxglove::{FrameTransform, FrameTransforms, PoseInFrame};
use policy_runtime::record::{McapRecorder, RecorderConfig, Recording, RunMetadata, SchemaName};
use schemars::JsonSchema;
use serde::Serialize;

/// 120 Hz control tick, ns.
const TICK_NS: u64 = 8_333_333;
/// Set in the environment of the child process that writes until it is killed.
const CRASH_WRITER_ENV: &str = "AMSTACK_TEST_MCAP_CRASH_WRITER";
/// Prefix of the child's progress lines.
const PROGRESS: &str = "crash-writer:";
/// Messages per tick: pose, transforms, tick.
const MESSAGES_PER_TICK: u64 = 3;

#[derive(Serialize, JsonSchema)]
struct Tick {
    tick: u64,
    /// Rotor thrusts, N.
    thrust_n: [f64; 6],
}
impl SchemaName for Tick {
    const SCHEMA_NAME: &'static str = "amstack.test.Tick";
}

fn run_metadata() -> RunMetadata {
    RunMetadata::new("fa-hexa", "pid", 7)
        .with_trajectory("hover")
        .with_config(&serde_json::json!({"rate_hz": 120}))
        .unwrap()
}

/// The writer of both tests: `ticks` control ticks (unbounded if `None`) on three channels,
/// calling `after_tick(recorder)` after each.
fn write_ticks(
    rec: &mut McapRecorder,
    ticks: Option<u64>,
    mut after_tick: impl FnMut(&McapRecorder),
) {
    let pose = rec.channel::<PoseInFrame>("/base/pose").unwrap();
    let tf = rec.channel::<FrameTransforms>("/tf").unwrap();
    let tick = rec.channel::<Tick>("/controller/tick").unwrap();
    let mut k = 0;
    while ticks.is_none_or(|n| k < n) {
        let t_ns = k * TICK_NS;
        let world_from_base = Isometry3::new(
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::z() * (k as f64 * 1e-3),
        );
        rec.log(
            &pose,
            t_ns,
            &PoseInFrame::new(t_ns, "world", &world_from_base),
        )
        .unwrap();
        let transforms = FrameTransforms {
            transforms: vec![FrameTransform::new(
                t_ns,
                "world",
                "base_link",
                &world_from_base,
            )],
        };
        rec.log(&tf, t_ns, &transforms).unwrap();
        rec.log(
            &tick,
            t_ns,
            &Tick {
                tick: k,
                thrust_n: [6.9; 6],
            },
        )
        .unwrap();
        after_tick(rec);
        k += 1;
    }
}

/// The independent reader (PyPI `mcap`), shared with the cross-crate tests.
use tests::mcap_check;

/// Messages per topic in a `mcap_check.py` report.
fn python_counts(report: &serde_json::Value) -> BTreeMap<String, u64> {
    report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["topic"].as_str().unwrap().to_owned(),
                c["count"].as_u64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn python_mcap_reads_a_finished_run_with_our_counts_schemas_and_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let mut rec = McapRecorder::create(&path, &run_metadata()).unwrap();
    write_ticks(&mut rec, Some(300), |_| {});
    let summary = rec.finish().unwrap();

    let expects: Vec<String> = summary
        .message_counts
        .iter()
        .map(|(t, n)| format!("--expect={t}={n}"))
        .collect();
    let mut args: Vec<&str> = expects.iter().map(String::as_str).collect();
    args.push("--require-complete");
    let (code, report) = mcap_check(&path, &args);
    assert_eq!(code, 0, "{report:#}");
    assert_eq!(report["complete"], true);
    assert_eq!(python_counts(&report), summary.message_counts);
    assert_eq!(report["summary_statistics"]["message_count"], 900);
    let schema_names: BTreeMap<&str, &str> = report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["topic"].as_str().unwrap(),
                c["schema_name"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(schema_names["/base/pose"], "foxglove.PoseInFrame");
    assert_eq!(schema_names["/tf"], "foxglove.FrameTransforms");
    assert_eq!(schema_names["/controller/tick"], "amstack.test.Tick");
    let metadata = &report["metadata"][0];
    assert_eq!(metadata["name"], "amstack.run");
    let map: BTreeMap<String, String> =
        serde_json::from_value(metadata["metadata"].clone()).unwrap();
    assert_eq!(RunMetadata::from_record_map(&map).unwrap(), run_metadata());

    // Cut in the middle (inside a chunk, as a kill during a chunk write would leave it): the
    // streaming reader keeps the chunks before the cut, like ours.
    let cut = dir.path().join("cut.mcap");
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let ours = Recording::from_bytes(&bytes[..bytes.len() / 2]).unwrap();
    assert!(!ours.messages.is_empty() && ours.messages.len() < 900);
    let (code, report) = mcap_check(&cut, &[]);
    assert_eq!(code, 0, "{report:#}");
    assert_eq!(report["complete"], false);
    assert_eq!(python_counts(&report), ours.message_counts(), "{report:#}");

    // A wrong expectation fails the check.
    let (code, report) = mcap_check(&path, &["--expect", "/tf=299"]);
    assert_eq!(code, 1, "{report:#}");
    assert!(
        report["errors"][0].as_str().unwrap().contains("/tf"),
        "{report:#}"
    );
}

/// Not a test on its own: the child process of
/// [`sigkilled_run_leaves_every_complete_chunk_readable`], selected by [`CRASH_WRITER_ENV`]. It
/// writes ticks with 0.1 s chunks and prints its progress until it is killed.
#[test]
fn crash_writer_child() {
    let Ok(path) = std::env::var(CRASH_WRITER_ENV) else {
        return;
    };
    let config = RecorderConfig {
        chunk_max_span_ns: 100_000_000,
        ..RecorderConfig::default()
    };
    let mut rec = McapRecorder::create_with_config(&path, &run_metadata(), &config).unwrap();
    // Bounded all the same (~100 s): a parent that never kills still ends.
    write_ticks(&mut rec, Some(1_000_000), |rec| {
        println!(
            "{PROGRESS} logged={} flushed={}",
            rec.messages_logged(),
            rec.messages_flushed()
        );
        std::thread::sleep(std::time::Duration::from_micros(100));
    });
}

#[test]
fn sigkilled_run_leaves_every_complete_chunk_readable() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.mcap");
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "crash_writer_child",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CRASH_WRITER_ENV, &path)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let progress = |line: &str| -> Option<(u64, u64)> {
        let rest = line.strip_prefix(PROGRESS)?;
        let mut it = rest
            .split_whitespace()
            .map(|kv| kv.split_once('=').unwrap().1.parse().unwrap());
        Some((it.next()?, it.next()?))
    };
    // Let it write 10 complete chunks (0.1 s = 13 ticks = 39 messages each: 13 ticks span
    // 12 × 8.333333 ms < 0.1 s), and 5 ticks more so the kill lands inside an open chunk.
    let mut last = (0, 0);
    let mut ticks_since = 0;
    for line in lines.by_ref() {
        let Some(p) = progress(&line.unwrap()) else {
            continue;
        };
        last = p;
        if last.1 >= 10 * 39 {
            ticks_since += 1;
            if ticks_since == 5 {
                break;
            }
        }
    }
    child.kill().unwrap(); // SIGKILL
    // Lines printed before the kill landed.
    for line in lines {
        if let Some(p) = progress(&line.unwrap()) {
            last = p;
        }
    }
    let status = child.wait().unwrap();
    assert_eq!(status.signal(), Some(9), "{status:?}");
    let (logged, flushed) = last;
    assert!(
        flushed >= 10 * 39,
        "the child wrote too little before dying: {last:?}"
    );

    let bytes = std::fs::read(&path).unwrap();
    // Our streaming reader.
    let recording = Recording::from_bytes(&bytes).unwrap();
    assert!(!recording.complete);
    assert_eq!(recording.run, Some(run_metadata()), "metadata survives");
    let survived = recording.messages.len() as u64;
    // Every message of the complete chunks, none of the open one: at least what the child had
    // seen flushed, at most what it had logged (it may die between a flush and its report).
    assert!(
        flushed <= survived && survived <= logged,
        "{survived} of {logged}, {flushed} flushed"
    );
    assert_eq!(survived % 39, 0, "whole chunks only: {survived}");
    let ticks: Vec<u32> = recording
        .messages
        .iter()
        .filter(|m| m.topic == "/controller/tick")
        .map(|m| m.sequence)
        .collect();
    assert_eq!(
        ticks,
        (0..(survived / MESSAGES_PER_TICK) as u32).collect::<Vec<_>>(),
        "a prefix"
    );

    // mcap's own MessageStream: the same messages, then an error at the cut.
    let mut stream_ok = 0u64;
    let mut stream_err = None;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        match m {
            Ok(_) => stream_ok += 1,
            Err(e) => {
                stream_err = Some(e);
                break;
            }
        }
    }
    assert_eq!(stream_ok, survived);
    assert!(stream_err.is_some(), "a killed file has no footer");

    // The Python reader, streaming.
    let (code, report) = mcap_check(&path, &[]);
    assert_eq!(code, 0, "{report:#}");
    assert_eq!(report["complete"], false);
    assert_eq!(python_counts(&report), recording.message_counts());
    let (code, _) = mcap_check(&path, &["--require-complete"]);
    assert_eq!(code, 1);

    eprintln!(
        "SIGKILL test: {survived} of {logged} logged messages survived ({flushed} reported \
         flushed); file {} bytes; reader stopped by: {:?}",
        bytes.len(),
        recording.stopped_by
    );
}
