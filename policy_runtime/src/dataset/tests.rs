//! Dataset tests: hand-made episodes through the writer, reader and validator; recorded
//! rollouts of the twin replayed bit for bit.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use controllers::{ControllerKind, profile};
use platform::Vehicle;
use serde_json::{Value, json};
use sim_twin::{TaskId, TwinConfig};

use super::*;
use crate::bench::{
    BenchConfig, BenchLink, EpisodeLength, RolloutHooks, Termination, rollout_seed,
    run_rollout_with,
};
use crate::stack::Interface;
use crate::state_source::StateSource;

fn spec(cameras: &[(String, usize, usize)]) -> DatasetSpec {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    DatasetSpec::new(
        &vehicle,
        &StateKey::DEFAULT,
        ActionSemantics::EeAbsolute,
        120,
        cameras,
    )
}

/// An episode of `len` frames whose values encode (episode, frame, element).
fn episode(e: u64, len: usize, task: &str, cameras: usize) -> EpisodeFrames {
    let value = |k: usize, i: usize| (e * 1000 + k as u64) as f32 + i as f32 / 10.0;
    EpisodeFrames {
        task: task.to_owned(),
        state: (0..len)
            .flat_map(|k| (0..8).map(move |i| value(k, i)))
            .collect(),
        action: (0..len)
            .flat_map(|k| (0..8).map(move |i| -value(k, i)))
            .collect(),
        images: (0..cameras)
            .map(|c| {
                (0..len)
                    .map(|k| {
                        let rgb: Vec<u8> = (0..4 * 4)
                            .flat_map(|p| [k as u8, c as u8, p as u8])
                            .collect();
                        encode_png(4, 4, &rgb).unwrap()
                    })
                    .collect()
            })
            .collect(),
        sampled_rgb: Vec::new(),
        source: EpisodeSource {
            task_name: task.to_owned(),
            seed: Some(e),
            success: true,
            attempt: e,
        },
        videos: Vec::new(),
    }
}

fn files(root: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_owned()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(dir).unwrap() {
            let p = entry.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(root).unwrap().display().to_string();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn episodes_read_back_as_written_and_validate() {
    let dir = tempfile::tempdir().unwrap();
    let cams = vec![("ee_camera".to_owned(), 4, 4)];
    let mut w = DatasetWriter::create(dir.path(), spec(&cams), json!({"test": 1})).unwrap();
    let written = [
        episode(0, 7, "press the button", 1),
        episode(1, 5, "open the door", 1),
        episode(2, 3, "press the button", 1),
    ];
    for e in &written {
        w.write_episode(e.clone()).unwrap();
    }
    assert_eq!((w.episodes(), w.frames()), (3, 15));
    let problems = validate(dir.path());
    assert!(problems.is_empty(), "{problems:#?}");
    let mut r = DatasetReader::open(dir.path()).unwrap();
    assert_eq!(r.tasks, vec!["press the button", "open the door"]);
    assert_eq!(
        r.spec.images,
        vec![("observation.images.ee_camera".to_owned(), 4, 4)]
    );
    for (i, e) in written.iter().enumerate() {
        let back = r.episode(i as u64).unwrap();
        assert_eq!(
            (&back.task, &back.state, &back.action, &back.images),
            (&e.task, &e.state, &e.action, &e.images)
        );
    }
    let rows = &r.episodes;
    assert_eq!(
        rows.iter().map(|r| (r.from, r.to)).collect::<Vec<_>>(),
        vec![(0, 7), (7, 12), (12, 15)]
    );
    // The dataset's statistics are those of all frames (the aggregate of the episodes').
    let stats = r.stats_for(&r.spec.features()).unwrap();
    let all: Vec<f64> = written
        .iter()
        .flat_map(|e| e.state.iter().map(|x| f64::from(*x)))
        .collect();
    let direct = stats::FeatureStats::of_rows(&all, 8, stats::StatsKind::Float);
    assert_eq!(stats[0].count, 15);
    assert_eq!(
        (stats[0].min.clone(), stats[0].max.clone()),
        (direct.min.clone(), direct.max.clone())
    );
    for d in 0..8 {
        assert!((stats[0].mean[d] - direct.mean[d]).abs() < 1e-9);
        assert!((stats[0].std[d] - direct.std[d]).abs() < 1e-9);
    }
    // info.json as lerobot writes it.
    let info: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("meta/info.json")).unwrap()).unwrap();
    assert_eq!(info["codebase_version"], "v3.0");
    assert_eq!(info["splits"]["train"], "0:3");
    assert_eq!(
        info["features"]["observation.images.ee_camera"]["shape"],
        json!([4, 4, 3])
    );
    assert_eq!(info["ambench"]["action_semantics"], "ee_absolute");
    assert_eq!(
        info["ambench"]["state_keys"],
        json!(["ee_pos", "ee_quat", "gripper_width"])
    );
}

#[test]
fn data_files_roll_over_past_their_size_and_resume_opens_new_files() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = DatasetWriter::create(dir.path(), spec(&[]), Value::Null)
        .unwrap()
        .with_data_file_limit_bytes(1);
    w.write_episode(episode(0, 4, "a", 0)).unwrap();
    w.write_episode(episode(1, 4, "a", 0)).unwrap();
    drop(w);
    let mut w = DatasetWriter::resume(dir.path(), spec(&[])).unwrap();
    assert_eq!(w.next_attempt(), 2);
    w.write_episode(episode(2, 4, "b", 0)).unwrap();
    let r = DatasetReader::open(dir.path()).unwrap();
    assert_eq!(
        r.episodes.iter().map(|e| e.data).collect::<Vec<_>>(),
        vec![(0, 0), (0, 1), (0, 2)]
    );
    assert_eq!(
        r.episodes.iter().map(|e| e.meta).collect::<Vec<_>>(),
        vec![(0, 0), (0, 0), (0, 1)]
    );
    assert!(
        validate(dir.path()).is_empty(),
        "{:#?}",
        validate(dir.path())
    );
    // Another spec is refused.
    let other = DatasetSpec::new(
        &Vehicle::builtin("fa-hexa").unwrap(),
        &[StateKey::EePos],
        ActionSemantics::EeAbsolute,
        120,
        &[],
    );
    assert!(DatasetWriter::resume(dir.path(), other).is_err());
}

#[test]
fn a_failed_episode_leaves_the_dataset_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = DatasetWriter::create(dir.path(), spec(&[]), Value::Null).unwrap();
    w.write_episode(episode(0, 4, "a", 0)).unwrap();
    let before = files(dir.path());
    // Wrong widths, no frame: refused before any file is touched.
    let mut bad = episode(1, 4, "a", 0);
    bad.action.pop();
    assert!(w.write_episode(bad).is_err());
    assert!(w.write_episode(EpisodeFrames::default()).is_err());
    // A data file that cannot be replaced (its folder made read-only... as root that does not
    // hold: a folder where the temporary file should go).
    std::fs::create_dir(dir.path().join("data/chunk-000/.file-000.parquet.tmp")).unwrap();
    assert!(w.write_episode(episode(1, 4, "a", 0)).is_err());
    std::fs::remove_dir(dir.path().join("data/chunk-000/.file-000.parquet.tmp")).unwrap();
    assert_eq!(files(dir.path()), before);
    assert!(validate(dir.path()).is_empty());
    // And the writer goes on.
    w.write_episode(episode(1, 4, "a", 0)).unwrap();
    assert!(validate(dir.path()).is_empty());
}

#[test]
fn the_validator_names_each_inconsistency() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = DatasetWriter::create(dir.path(), spec(&[]), Value::Null).unwrap();
    w.write_episode(episode(0, 4, "a", 0)).unwrap();
    w.write_episode(episode(1, 4, "a", 0)).unwrap();
    let info_path = dir.path().join("meta/info.json");
    let info = std::fs::read_to_string(&info_path).unwrap();
    std::fs::write(
        &info_path,
        info.replace("\"total_frames\": 8", "\"total_frames\": 9"),
    )
    .unwrap();
    let problems = validate(dir.path());
    assert!(
        problems
            .iter()
            .any(|p| p.contains("Σ length = 8, info.json total_frames = 9")),
        "{problems:#?}"
    );
    assert!(
        problems.iter().any(|p| p.contains("data: 8 rows")),
        "{problems:#?}"
    );
    std::fs::write(&info_path, &info).unwrap();
    let stats_path = dir.path().join("meta/stats.json");
    let stats = std::fs::read_to_string(&stats_path).unwrap();
    let mut v: Value = serde_json::from_str(&stats).unwrap();
    v["action"]["max"][0] = json!(123.0);
    std::fs::write(&stats_path, v.to_string()).unwrap();
    let problems = validate(dir.path());
    assert_eq!(problems.len(), 1, "{problems:#?}");
    assert!(
        problems[0].starts_with("meta/stats.json: action: max[0] = 123"),
        "{problems:#?}"
    );
}

#[test]
fn openpi_export_takes_every_sixth_frame() {
    let dir = tempfile::tempdir().unwrap();
    let out = tempfile::tempdir().unwrap();
    let cams = vec![("ee_camera".to_owned(), 4, 4)];
    let mut w = DatasetWriter::create(dir.path(), spec(&cams), Value::Null).unwrap();
    w.write_episode(episode(0, 13, "a", 1)).unwrap();
    w.write_episode(episode(1, 5, "a", 1)).unwrap(); // under one logical frame: skipped
    w.write_episode(episode(2, 12, "b", 1)).unwrap();
    let export = export_openpi(&[dir.path().to_owned()], out.path(), 20, &mut |_| {}).unwrap();
    assert_eq!(
        (export.episodes, export.frames, export.stride, export.images),
        (2, 4, 6, true)
    );
    let batches =
        read::read_parquet(&out.path().join("data/chunk-000/episode_000001.parquet")).unwrap();
    let b = &batches[0];
    let pos = read::fixed_values(b, "ee_pos", "x").unwrap();
    // Logical frames 0 and 1 of source episode 2 = raw frames 0 and 6: ee_pos = state[0..3].
    let src = episode(2, 12, "b", 1);
    assert_eq!(
        pos,
        &[
            src.state[0],
            src.state[1],
            src.state[2],
            src.state[48],
            src.state[49],
            src.state[50]
        ]
    );
    let info: Value =
        serde_json::from_slice(&std::fs::read(out.path().join("meta/info.json")).unwrap()).unwrap();
    assert_eq!(
        (
            info["codebase_version"].as_str(),
            info["fps"].as_u64(),
            info["total_frames"].as_u64()
        ),
        (Some("v2.1"), Some(20), Some(4))
    );
    assert_eq!(info["features"]["ee_image"]["shape"], json!([3, 4, 4]));
    let tasks = std::fs::read_to_string(out.path().join("meta/tasks.jsonl")).unwrap();
    assert_eq!(
        tasks,
        "{\"task\":\"a\",\"task_index\":0}\n{\"task\":\"b\",\"task_index\":1}\n"
    );
}

#[test]
fn merging_reindexes_episodes_and_tasks() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let out = tempfile::tempdir().unwrap();
    let mut wa = DatasetWriter::create(a.path(), spec(&[]), Value::Null).unwrap();
    wa.write_episode(episode(0, 4, "press", 0)).unwrap();
    wa.write_episode(episode(1, 3, "press", 0)).unwrap();
    let mut wb = DatasetWriter::create(b.path(), spec(&[]), Value::Null).unwrap();
    wb.write_episode(episode(7, 5, "open", 0)).unwrap();
    let w = merge(
        &[a.path().to_owned(), b.path().to_owned()],
        out.path(),
        &mut |_| {},
    )
    .unwrap();
    assert_eq!((w.episodes(), w.frames()), (3, 12));
    assert!(
        validate(out.path()).is_empty(),
        "{:#?}",
        validate(out.path())
    );
    let mut r = DatasetReader::open(out.path()).unwrap();
    assert_eq!(r.tasks, vec!["press", "open"]);
    assert_eq!(r.episode(2).unwrap().state, episode(7, 5, "open", 0).state);
    assert_eq!(r.episodes[2].from, 7);
}

/// An episode of a video dataset read back from elsewhere: `episode(e, …)` without PNGs, its
/// camera's "MP4" a file of marker bytes (a merge copies it and never decodes it) with
/// statistics that are not those of any frame.
fn video_episode(e: u64, len: usize, task: &str, dir: &Path) -> EpisodeFrames {
    let path = dir.join(format!("source-{e}.mp4"));
    std::fs::write(&path, format!("episode {e}").as_bytes()).unwrap();
    let v = e as f64 / 100.0;
    let mut frames = episode(e, len, task, 1);
    frames.images = vec![Vec::new()];
    frames.videos = vec![EpisodeVideoFile {
        path,
        from_frame: 0,
        whole_file: true,
        stats: Some(stats::FeatureStats {
            min: vec![v; 3],
            max: vec![v + 0.5; 3],
            mean: vec![v + 0.25; 3],
            std: vec![0.1; 3],
            count: len as u64,
            quantiles: vec![vec![v + 0.2; 3]; stats::QUANTILES.len()],
            kind: stats::StatsKind::Image,
        }),
    }];
    frames
}

#[test]
fn merging_video_datasets_copies_each_mp4_and_keeps_its_recorded_statistics() {
    let cams = [("ee_camera".to_owned(), 4, 4)];
    let files = tempfile::tempdir().unwrap();
    let (a, b, out) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    // No ffmpeg anywhere: episodes given as files are copied, not encoded.
    let mut wa =
        DatasetWriter::create(a.path(), spec(&cams).with_video(true), Value::Null).unwrap();
    wa.write_episode(video_episode(0, 4, "press", files.path()))
        .unwrap();
    wa.write_episode(video_episode(1, 3, "press", files.path()))
        .unwrap();
    let mut wb =
        DatasetWriter::create(b.path(), spec(&cams).with_video(true), Value::Null).unwrap();
    wb.write_episode(video_episode(7, 5, "open", files.path()))
        .unwrap();
    let w = merge(
        &[b.path().to_owned(), a.path().to_owned()],
        out.path(),
        &mut |_| {},
    )
    .unwrap();
    assert_eq!((w.episodes(), w.frames()), (3, 12));
    assert!(
        validate(out.path()).is_empty(),
        "{:#?}",
        validate(out.path())
    );
    let key = image_key("ee_camera");
    let r = DatasetReader::open(out.path()).unwrap();
    assert_eq!(r.tasks, vec!["open", "press"]);
    for (e, source) in [7, 0, 1].into_iter().enumerate() {
        let mp4 = out.path().join(layout::video_file(&key, 0, e as u64));
        assert_eq!(
            std::fs::read_to_string(&mp4).unwrap_or_else(|e| panic!("{}: {e}", mp4.display())),
            format!("episode {source}"),
            "episode {e}'s file"
        );
        let row = &r.episodes[e];
        assert_eq!(row.videos[0].file, (0, e as u64));
        assert_eq!(row.videos[0].from_timestamp, 0.0);
        assert_eq!(row.videos[0].to_timestamp, row.length as f64 / 120.0);
        let files = files.path();
        assert_eq!(
            row.videos[0].stats,
            video_episode(source, row.length as usize, "", files).videos[0].stats,
            "episode {e}'s statistics"
        );
    }
    // The dataset's: the count-weighted aggregate of the episodes' (4, 3 and 5 frames).
    let all = r.stats_for(&r.spec.features()).unwrap();
    let (f, s) = r
        .spec
        .features()
        .iter()
        .zip(&all)
        .find(|(f, _)| f.key == key)
        .map(|(f, s)| (f.clone(), s.clone()))
        .unwrap();
    assert_eq!(f.dtype, Dtype::Video);
    let mean = (0.25 * 4.0 + 0.26 * 3.0 + 0.32 * 5.0) / 12.0;
    assert!((s.mean[0] - mean).abs() < 1e-12, "{:?} vs {mean}", s.mean);
    assert_eq!((s.min[0], s.max[0], s.count), (0.0, 7.0 / 100.0 + 0.5, 12));

    // A video dataset and an image one are not merged; nothing is written.
    let c = tempfile::tempdir().unwrap();
    let mut wc = DatasetWriter::create(c.path(), spec(&cams), Value::Null).unwrap();
    wc.write_episode(episode(2, 3, "press", 1)).unwrap();
    let never = tempfile::tempdir().unwrap();
    let never = never.path().join("never");
    let err = merge(
        &[a.path().to_owned(), c.path().to_owned()],
        &never,
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("merge datasets stored alike"), "{err}");
    assert!(!never.exists());
}

fn bench_config(vehicle: &str, interface: Interface) -> BenchConfig {
    let vehicle = Vehicle::builtin(vehicle).unwrap();
    BenchConfig {
        live: None,
        controller: profile(&vehicle, ControllerKind::Pid).unwrap(),
        controller_name: "test".to_owned(),
        vehicle,
        interface,
        tasks: vec![TaskId::PressButton],
        rollouts: 1,
        seed: 3,
        twin: TwinConfig::default(),
        jobs: 2,
        cameras: None,
        policy: None,
        episode: EpisodeLength::Script,
        mcap_dir: None,
        link: BenchLink::InProcess,
        state_source: StateSource::Truth,
    }
}

/// Records `episodes` of press-button into `dir`.
fn record_into(dir: &Path, config: &BenchConfig, keys: &[StateKey], episodes: u64) -> RecordReport {
    let semantics = match config.interface {
        Interface::Ee => ActionSemantics::EeAbsolute,
        Interface::BaseJoint => ActionSemantics::BaseJointAbsolute,
    };
    let spec = DatasetSpec::new(&config.vehicle, keys, semantics, 120, &[]);
    let mut w = if dir.join("meta/info.json").exists() {
        DatasetWriter::resume(dir, spec).unwrap()
    } else {
        DatasetWriter::create(dir, spec, json!({"seed": config.seed})).unwrap()
    };
    let rc = RecordConfig {
        bench: config.clone(),
        episodes,
        save_failed: false,
        state_keys: keys.to_vec(),
        first_attempt: w.next_attempt(),
        attempt_step: 1,
        attempt_end: w.next_attempt() + 10,
    };
    record(&rc, &mut w, &mut |_| {}, &AtomicBool::new(false)).unwrap()
}

#[test]
fn recorded_actions_replayed_reproduce_the_recorded_states_bit_for_bit() {
    for (vehicle, interface, keys) in [
        ("ee-only", Interface::Ee, StateKey::DEFAULT.to_vec()),
        (
            "fa-hexa",
            Interface::BaseJoint,
            vec![
                StateKey::BasePos,
                StateKey::BaseQuat,
                StateKey::ArmJointPos,
                StateKey::GripperWidth,
            ],
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let config = bench_config(vehicle, interface);
        let report = record_into(dir.path(), &config, &keys, 1);
        assert_eq!(report.saved, 1, "{vehicle}: {report:?}");
        let mut r = DatasetReader::open(dir.path()).unwrap();
        assert!(
            validate(dir.path()).is_empty(),
            "{:#?}",
            validate(dir.path())
        );
        let e = r.episode(0).unwrap();
        let n = e.len(r.spec.state_dim);
        assert_eq!(
            r.spec.action_dim,
            if interface == Interface::Ee { 8 } else { 12 }
        );
        // Fly the recorded actions again in the twin of the same seed.
        let attempt = e.source.attempt;
        assert_eq!(
            e.source.seed,
            Some(rollout_seed(config.seed, attempt as usize))
        );
        let mut source =
            RecordedActions::new(r.spec.action_semantics, r.spec.action_dim, e.action.clone());
        let mut replayed = Recorder::new(&config.vehicle, &keys, r.spec.action_dim, &[]);
        let result = run_rollout_with(
            &config,
            TaskId::PressButton,
            attempt as usize,
            &AtomicBool::new(false),
            None,
            RolloutHooks {
                source: Some(&mut source),
                observers: vec![&mut replayed],
            },
        )
        .unwrap();
        assert_eq!(result.termination, Termination::Success, "{vehicle}");
        assert_eq!(result.executed_steps as usize, n, "{vehicle}");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&replayed.frames().state),
            bits(&e.state),
            "{vehicle}: states"
        );
        assert_eq!(
            bits(&replayed.frames().action),
            bits(&e.action),
            "{vehicle}: actions"
        );
    }
}

#[test]
fn recording_is_the_same_bytes_whatever_the_threads_and_resumes() {
    let keys = StateKey::DEFAULT.to_vec();
    let one = tempfile::tempdir().unwrap();
    let mut config = bench_config("ee-only", Interface::Ee);
    config.jobs = 1;
    record_into(one.path(), &config, &keys, 3);
    let two = tempfile::tempdir().unwrap();
    config.jobs = 2;
    record_into(two.path(), &config, &keys, 1);
    record_into(two.path(), &config, &keys, 3);
    let a = files(one.path());
    let b = files(two.path());
    assert!(
        b.iter().any(|f| f.0 == "data/chunk-000/file-001.parquet")
            && b.iter()
                .any(|f| f.0 == "meta/episodes/chunk-000/file-001.parquet"),
        "{:?}",
        b.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    assert_eq!(
        a.iter().map(|f| &f.0).collect::<Vec<_>>(),
        vec![
            "data/chunk-000/file-000.parquet",
            "meta/episodes/chunk-000/file-000.parquet",
            "meta/info.json",
            "meta/stats.json",
            "meta/tasks.parquet",
        ]
    );
    // The resumed dataset has its second part in new files (as lerobot resumes); the
    // episodes, their frames and the statistics are the same.
    let mut ra = DatasetReader::open(one.path()).unwrap();
    let mut rb = DatasetReader::open(two.path()).unwrap();
    assert_eq!(ra.total_frames, rb.total_frames);
    for e in 0..3 {
        assert_eq!(ra.episode(e).unwrap(), rb.episode(e).unwrap());
    }
    let stats = |d: &Path| std::fs::read(d.join("meta/stats.json")).unwrap();
    assert_eq!(stats(one.path()), stats(two.path()));
    // Same flags, same bytes.
    let three = tempfile::tempdir().unwrap();
    config.jobs = 2;
    record_into(three.path(), &config, &keys, 3);
    assert_eq!(files(three.path()), a);
}

/// The episode attempt `a` makes in the shard tests: a few frames, one camera; it fails when
/// `fails(a)`.
fn attempt_episode(a: u64, fails: &dyn Fn(u64) -> bool) -> (bool, EpisodeFrames) {
    let mut e = episode(a, 2 + (a % 4) as usize, "press", 1);
    e.source.success = !fails(a);
    (e.source.success, e)
}

const SHARD_RUN_EPISODES: u64 = 6;
const SHARD_RUN_MAX_ATTEMPTS: u64 = 20;

fn shard_run() -> Value {
    json!({"episodes": SHARD_RUN_EPISODES, "max_attempts": SHARD_RUN_MAX_ATTEMPTS, "save_failed": false})
}

/// What `record` does unsharded: attempts in order until the run's episodes are saved.
fn record_whole(dir: &Path, fails: &dyn Fn(u64) -> bool) {
    let mut w =
        DatasetWriter::create(dir, spec(&[("ee".into(), 4, 4)]), json!({"seed": 3})).unwrap();
    let mut a = 0;
    while w.episodes() < SHARD_RUN_EPISODES && a < SHARD_RUN_MAX_ATTEMPTS {
        let (ok, e) = attempt_episode(a, fails);
        w.decide(a, ok, ok.then_some(e)).unwrap();
        a += 1;
    }
}

/// What `record --shard index/count` does: its attempts in order until its quota is saved
/// (resuming the shard in `dir` if there is one).
fn record_shard(dir: &Path, index: u64, count: u64, quota: u64, fails: &dyn Fn(u64) -> bool) {
    let spec = spec(&[("ee".into(), 4, 4)]);
    let mut w = if dir.join("meta/info.json").exists() {
        DatasetWriter::resume(dir, spec).unwrap()
    } else {
        DatasetWriter::create(dir, spec, json!({"seed": 3}))
            .unwrap()
            .with_shard(ShardPart::new(index, count, shard_run()))
            .unwrap()
    };
    let mut a = w.next_attempt();
    while w.episodes() < quota && a < SHARD_RUN_MAX_ATTEMPTS {
        let (ok, e) = attempt_episode(a, fails);
        w.decide(a, ok, ok.then_some(e)).unwrap();
        a += count;
    }
}

#[test]
fn merged_shards_are_the_unsharded_recording_byte_for_byte() {
    // Attempt 3 fails: the unsharded run keeps attempts 0 1 2 4 5 6; the shards of quota 2
    // decide 0 3 6 | 1 4 | 2 5.
    let fails = |a: u64| a == 3;
    let whole = tempfile::tempdir().unwrap();
    record_whole(whole.path(), &fails);
    let root = tempfile::tempdir().unwrap();
    let parts: Vec<_> = (0..3)
        .map(|i| root.path().join(format!("part{i}")))
        .collect();
    for (i, p) in parts.iter().enumerate() {
        record_shard(p, i as u64, 3, 2, &fails);
        assert!(validate(p).is_empty(), "{:#?}", validate(p));
    }
    let out = root.path().join("merged");
    // In any order.
    let merged = merge_shards(
        &[parts[2].clone(), parts[0].clone(), parts[1].clone()],
        &out,
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(
        (merged.writer.episodes(), merged.attempts, merged.extra),
        (6, 7, 0)
    );
    assert_eq!(
        files(&out),
        files(whole.path()),
        "the same files, the same bytes"
    );
    let r = DatasetReader::open(&out).unwrap();
    let attempts: Vec<u64> = r
        .sources
        .iter()
        .map(|s| s["attempt"].as_u64().unwrap())
        .collect();
    assert_eq!(attempts, [0, 1, 2, 4, 5, 6]);
}

#[test]
fn a_shard_short_of_the_runs_attempts_is_named_and_resumed() {
    // Attempts 0 and 3 fail: shard 0 (quota 2) decides 0 3 6 9, shard 1 only 1 4, but the
    // run's walk 0..=7 needs shard 1's attempt 7.
    let fails = |a: u64| a == 0 || a == 3;
    let whole = tempfile::tempdir().unwrap();
    record_whole(whole.path(), &fails);
    let root = tempfile::tempdir().unwrap();
    let parts: Vec<_> = (0..3)
        .map(|i| root.path().join(format!("part{i}")))
        .collect();
    for (i, p) in parts.iter().enumerate() {
        record_shard(p, i as u64, 3, 2, &fails);
    }
    let out = root.path().join("merged");
    let err = merge_shards(&parts, &out, &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("shard 1/3 decided its attempts up to 4")
            && err.contains("needs its attempt 7")
            && err.contains("--shard-episodes 3"),
        "{err}"
    );
    // Run shard 1 on with a larger quota: now the merge is the unsharded run, and shard 0's
    // attempt 9 (past the run's last) is left out.
    record_shard(&parts[1], 1, 3, 3, &fails);
    let _ = std::fs::remove_dir_all(&out);
    let merged = merge_shards(&parts, &out, &mut |_| {}).unwrap();
    assert_eq!((merged.attempts, merged.extra), (8, 1));
    assert_eq!(files(&out), files(whole.path()));
}

#[test]
fn shards_that_are_not_one_recordings_split_are_refused() {
    let fails = |_: u64| false;
    let root = tempfile::tempdir().unwrap();
    let part = |name: &str, index: u64, count: u64| {
        let p = root.path().join(name);
        record_shard(&p, index, count, 2, &fails);
        p
    };
    let (p0, p1, p2) = (part("p0", 0, 3), part("p1", 1, 3), part("p2", 2, 3));
    let other_split = part("q1", 1, 2);
    let out = root.path().join("out");
    let err = |parts: &[std::path::PathBuf]| {
        merge_shards(parts, &out, &mut |_| {})
            .unwrap_err()
            .to_string()
    };
    assert!(err(&[p0.clone(), p2.clone()]).contains("shard 1/3 missing"));
    assert!(
        err(&[p0.clone(), p1.clone(), p1.clone(), p2.clone()]).contains("shard 1/3 given twice")
    );
    assert!(err(&[p0.clone(), other_split, p2.clone()]).contains("shards of different splits"));
    // Another recording (another seed).
    let mut info: Value =
        serde_json::from_slice(&std::fs::read(p1.join("meta/info.json")).unwrap()).unwrap();
    info["ambench"]["recording"]["seed"] = json!(4);
    std::fs::write(p1.join("meta/info.json"), info.to_string()).unwrap();
    let e = err(&[p0.clone(), p1.clone(), p2.clone()]);
    assert!(
        e.contains("shards of different recordings") && e.contains("ambench.recording.seed"),
        "{e}"
    );
    // A whole dataset is not a shard.
    let whole = tempfile::tempdir().unwrap();
    record_whole(whole.path(), &fails);
    assert!(!is_shard(whole.path()) && is_shard(&p0));
    assert!(err(&[p0, whole.path().to_owned()]).contains("not a shard of a recording"));
}

/// Copies every file of `from` (a snapshot of the dataset's `meta/`) back over `to`.
fn restore(from: &[(String, Vec<u8>)], to: &Path, only: &dyn Fn(&str) -> bool) {
    for (rel, bytes) in from {
        if only(rel) {
            std::fs::write(to.join(rel), bytes).unwrap();
        }
    }
}

#[test]
fn resume_drops_what_a_crash_between_data_and_metadata_left() {
    // Crash points: right after the data file (the episode's rows only), and right before
    // info.json (its rows, its meta/episodes row, its task and its statistics written).
    let cams = [("ee".to_owned(), 4, 4)];
    let is_meta = |rel: &str| rel.starts_with("meta/");
    let is_info = |rel: &str| rel == "meta/info.json";
    for (name, committed_files) in [
        ("after the data file", &is_meta as &dyn Fn(&str) -> bool),
        ("before info.json", &is_info),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let mut w = DatasetWriter::create(dir.path(), spec(&cams), Value::Null).unwrap();
        w.write_episode(episode(0, 4, "press", 1)).unwrap();
        w.write_episode(episode(1, 3, "press", 1)).unwrap();
        let before = files(dir.path());
        // The third episode, of another task, then the crash: what was committed before it
        // is put back (the files written after the crash point never were).
        w.write_episode(episode(2, 5, "open", 1)).unwrap();
        drop(w);
        restore(&before, dir.path(), committed_files);
        let problems = validate(dir.path());
        assert!(!problems.is_empty(), "{name}: the crash is visible");
        let mut w = DatasetWriter::resume(dir.path(), spec(&cams)).unwrap();
        let repaired = w.repaired().clone();
        assert_eq!(repaired.data_rows, 5, "{name}: {repaired:?}");
        assert_eq!(
            (repaired.episode_rows, repaired.tasks),
            if committed_files("meta/episodes") {
                (0, 0)
            } else {
                (1, 1)
            },
            "{name}"
        );
        assert!(
            validate(dir.path()).is_empty(),
            "{name}: {:#?}",
            validate(dir.path())
        );
        assert_eq!((w.episodes(), w.frames()), (2, 7), "{name}");
        // The statistics are the two committed episodes' again.
        let stats = std::fs::read(dir.path().join("meta/stats.json")).unwrap();
        let committed = before.iter().find(|f| f.0 == "meta/stats.json").unwrap();
        assert!(stats == committed.1, "{name}: stats.json");
        // And the recording goes on, valid.
        w.write_episode(episode(2, 5, "open", 1)).unwrap();
        assert!(
            validate(dir.path()).is_empty(),
            "{name}: {:#?}",
            validate(dir.path())
        );
        let mut r = DatasetReader::open(dir.path()).unwrap();
        assert_eq!(r.episode(2).unwrap().state, episode(2, 5, "open", 1).state);
        assert_eq!(r.tasks, vec!["press", "open"]);
    }
}
