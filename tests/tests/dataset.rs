//! `amstack record` and `amstack dataset` as a user runs them, the dataset read back by an
//! independent reader (pyarrow and numpy, scripts/dataset_check.py in the venv of
//! scripts/setup-python.sh): every file agrees with the data, the openpi export's frames are
//! every 6th source frame, bad input is one line and exit 2.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: fail loudly"
)]

use std::path::Path;
use std::process::{Command, Output};

use tests::process::amstack;
use tests::{python, scripts_dir};

fn run(args: &[&str]) -> Output {
    Command::new(amstack())
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("amstack {args:?}: {e}"))
}

fn ok(args: &[&str]) -> String {
    let out = run(args);
    assert!(
        out.status.success(),
        "amstack {args:?}: {:?}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn check(dir: &Path, openpi: Option<&Path>) -> serde_json::Value {
    let mut cmd = Command::new(python());
    cmd.arg(scripts_dir().join("dataset_check.py"))
        .arg(dir)
        .arg("--json");
    if let Some(o) = openpi {
        cmd.arg("--openpi").arg(o);
    }
    let out = cmd.output().unwrap();
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "dataset_check.py printed no JSON ({e}): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert!(out.status.success(), "dataset_check.py: {report}");
    report
}

const RECORD: &[&str] = &[
    "record",
    "--platform",
    "fa-hexa",
    "--task",
    "press-button",
    "--episodes",
    "2",
    "--seed",
    "5",
    "--jobs",
    "2",
    "--cameras",
    "ee",
];

#[test]
fn a_recorded_dataset_is_read_back_by_pyarrow_and_exported_at_20_hz() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("press");
    let summary = tmp.path().join("summary.json");
    let mut args = RECORD.to_vec();
    let d = dir.to_str().unwrap();
    let s = summary.to_str().unwrap();
    args.extend(["--out", d, "--json", s]);
    ok(&args);
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&summary).unwrap()).unwrap();
    assert_eq!(summary["dataset_episodes"], 2);
    assert!(summary["frames_written"].as_u64().unwrap() > 100);
    let validated = ok(&["dataset", "validate", d]);
    assert!(validated.contains("valid (2 episodes"), "{validated}");
    let info = ok(&["dataset", "info", d]);
    assert!(info.contains("press the button"), "{info}");
    // The independent reader: every file, every index and statistic.
    let report = check(&dir, None);
    assert_eq!(report["episodes"], 2);
    assert!(
        info.lines()
            .any(|l| l.contains("observation.images.ee_camera")
                && l.contains("image")
                && l.contains("[384, 384, 3]")),
        "{info}"
    );
    assert_eq!(report["frames"], summary["dataset_frames"]);
    // export-openpi: 20 Hz frames equal every 6th source frame.
    let out = tmp.path().join("openpi");
    ok(&[
        "dataset",
        "export-openpi",
        d,
        "--out",
        out.to_str().unwrap(),
    ]);
    let report = check(&dir, Some(&out));
    let frames = report["frames"].as_u64().unwrap();
    let openpi = report["openpi_frames"].as_u64().unwrap();
    assert!(openpi <= frames / 6 && openpi + 2 >= frames / 6, "{report}");
    // Its images are the source's PNGs at every 6th frame.
    assert_eq!(report["openpi_images"], report["openpi_frames"], "{report}");
    // merge: the same dataset twice is one of 4 episodes with one task.
    let merged = tmp.path().join("merged");
    ok(&["dataset", "merge", d, d, "--out", merged.to_str().unwrap()]);
    let report = check(&merged, None);
    assert_eq!(report["episodes"], 4);
    assert_eq!(report["frames"].as_u64().unwrap(), 2 * frames);
}

#[test]
fn bad_input_is_one_line_and_exit_2() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().to_str().unwrap().to_owned();
    std::fs::write(tmp.path().join("something"), "x").unwrap();
    for (args, needle) in [
        (
            vec!["record", "--task", "press-button", "--out", d.as_str()],
            "not empty (pass --resume",
        ),
        (
            vec![
                "record",
                "--task",
                "fly-to-the-moon",
                "--out",
                "/tmp/x-never",
            ],
            "unknown task",
        ),
        (
            vec![
                "record",
                "--task",
                "press-button",
                "--state-keys",
                "ee_pos,elbow",
                "--out",
                "/tmp/x-never",
            ],
            "unknown state key \"elbow\"",
        ),
        (vec!["dataset", "validate", d.as_str()], "not a dataset"),
    ] {
        let out = run(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
    }
}

/// Every file under `dir`, by relative path, with its bytes.
fn files(dir: &Path) -> std::collections::BTreeMap<std::path::PathBuf, Vec<u8>> {
    let mut found = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let rel = path.strip_prefix(dir).unwrap().to_path_buf();
                found.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    found
}

#[test]
fn three_recorded_shards_merged_are_the_unsharded_dataset_file_by_file() {
    let tmp = tempfile::tempdir().unwrap();
    let record = [
        "record",
        "--task",
        "press-button",
        "--episodes",
        "4",
        "--seed",
        "9",
        "--cameras",
        "ee",
        "--jobs",
        "1",
    ];
    let whole = tmp.path().join("whole");
    let mut args = record.to_vec();
    let w = whole.to_str().unwrap();
    args.extend(["--out", w]);
    ok(&args);
    // Shard 0 from the flag, 1 from a Slurm array index, 2 from a Kubernetes Indexed Job's.
    let parts: Vec<String> = (0..3)
        .map(|i| tmp.path().join(format!("part{i}")).display().to_string())
        .collect();
    for (i, (spec, env)) in [
        ("0/3", None),
        ("env/3", Some(("SLURM_ARRAY_TASK_ID", "1"))),
        ("env/3", Some(("JOB_COMPLETION_INDEX", "2"))),
    ]
    .into_iter()
    .enumerate()
    {
        let mut args = record.to_vec();
        args.extend(["--shard", spec, "--out", &parts[i]]);
        let mut cmd = Command::new(amstack());
        cmd.args(&args)
            .env_remove("SLURM_ARRAY_TASK_ID")
            .env_remove("JOB_COMPLETION_INDEX");
        if let Some((k, v)) = env {
            cmd.env(k, v);
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // Each shard is a valid dataset of its quota (ceil(4 / 3) = 2 episodes).
        let validated = ok(&["dataset", "validate", &parts[i]]);
        assert!(validated.contains("valid (2 episodes"), "{validated}");
    }
    let info: serde_json::Value = serde_json::from_slice(
        &std::fs::read(Path::new(&parts[1]).join("meta/info.json")).unwrap(),
    )
    .unwrap();
    let attempts: Vec<u64> = info["ambench"]["shard"]["attempts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["attempt"].as_u64().unwrap())
        .collect();
    assert_eq!(attempts, [1, 4], "shard 1/3 holds attempts a mod 3 = 1");
    let merged = tmp.path().join("merged");
    let m = merged.to_str().unwrap();
    let said = ok(&[
        "dataset", "merge", &parts[2], &parts[0], &parts[1], "--out", m,
    ]);
    assert!(
        said.contains("4 episodes") && said.contains("2 episodes of the shards past"),
        "{said}"
    );
    let (a, b) = (files(&whole), files(&merged));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (path, bytes) in &a {
        assert!(b[path] == *bytes, "{} differs", path.display());
    }
    // A missing shard and a whole dataset among shards are refused on one line, exit 2.
    for (args, needle) in [
        (
            vec![
                "dataset",
                "merge",
                &parts[0],
                &parts[2],
                "--out",
                "/tmp/x-never",
            ],
            "shard 1/3 missing",
        ),
        (
            vec!["dataset", "merge", &parts[0], w, "--out", "/tmp/x-never"],
            "is not: merge the shards",
        ),
    ] {
        let out = run(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
    }
    assert!(!Path::new("/tmp/x-never").exists());
}

#[test]
fn a_video_dataset_decodes_to_its_frames_merges_without_re_encoding_and_exports_at_20_hz() {
    // The encoder: the static ffmpeg of the venv's imageio-ffmpeg (no Debian ffmpeg needed).
    let exe = Command::new(python())
        .args([
            "-c",
            "import imageio_ffmpeg; print(imageio_ffmpeg.get_ffmpeg_exe())",
        ])
        .output()
        .unwrap();
    let ffmpeg = String::from_utf8_lossy(&exe.stdout).trim().to_owned();
    assert!(
        exe.status.success() && !ffmpeg.is_empty(),
        "no imageio-ffmpeg"
    );
    let tmp = tempfile::tempdir().unwrap();
    let amstack_ff = |args: &[&str]| {
        let out = Command::new(amstack())
            .args(args)
            .env("AMSTACK_FFMPEG", &ffmpeg)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let record = |dir: &Path, extra: &[&str]| {
        let mut args = vec![
            "record",
            "--task",
            "press-button",
            "--episodes",
            "2",
            "--seed",
            "3",
            "--cameras",
            "ee",
            "--jobs",
            "2",
        ];
        args.extend(extra);
        args.extend(["--out", dir.to_str().unwrap()]);
        amstack_ff(&args);
    };
    let dir = tmp.path().join("video");
    record(&dir, &["--video"]);
    let d = dir.to_str().unwrap();
    let validated = ok(&["dataset", "validate", d]);
    assert!(validated.contains("valid (2 episodes"), "{validated}");
    let info = ok(&["dataset", "info", d]);
    assert!(
        info.lines()
            .any(|l| l.contains("observation.images.ee_camera") && l.contains("video")),
        "{info}"
    );
    let mp4 = |root: &Path, f: u32| {
        root.join(format!(
            "videos/observation.images.ee_camera/chunk-000/file-{f:03}.mp4"
        ))
    };
    for f in 0..2 {
        assert!(mp4(&dir, f).is_file(), "{}", mp4(&dir, f).display());
    }
    // pyarrow reads the files, imageio-ffmpeg decodes every MP4: its frames are the
    // episode's, and the row's timestamps span them.
    let report = check(&dir, None);
    assert_eq!(report["episodes"], 2);
    assert_eq!(report["video_frames"], report["frames"], "{report}");
    // Same flags, same bytes (the encoder runs single-threaded, bit-exact).
    let again = tmp.path().join("again");
    record(&again, &["--video"]);
    assert!(files(&dir) == files(&again), "a second recording differs");

    // Video shards merged are the unsharded recording, file for file (MP4s copied as they are).
    let parts: Vec<String> = (0..2)
        .map(|i| tmp.path().join(format!("part{i}")).display().to_string())
        .collect();
    for (i, part) in parts.iter().enumerate() {
        let shard = format!("{i}/2");
        record(Path::new(part), &["--video", "--shard", &shard]);
    }
    let merged = tmp.path().join("merged");
    amstack_ff(&[
        "dataset",
        "merge",
        &parts[1],
        &parts[0],
        "--out",
        merged.to_str().unwrap(),
    ]);
    let (a, b) = (files(&dir), files(&merged));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (path, bytes) in &a {
        assert!(b[path] == *bytes, "{} differs", path.display());
    }

    // A dataset merged alone (no ffmpeg given: nothing is re-encoded): every file but
    // info.json (its `merged_from`) is the source's, so the videos' statistics (of the frames
    // before encoding) are carried, not recomputed from the lossy MP4.
    let alone = tmp.path().join("alone");
    ok(&["dataset", "merge", d, "--out", alone.to_str().unwrap()]);
    let c = files(&alone);
    assert_eq!(a.keys().collect::<Vec<_>>(), c.keys().collect::<Vec<_>>());
    for (path, bytes) in &a {
        if path != Path::new("meta/info.json") {
            assert!(c[path] == *bytes, "{} differs", path.display());
        }
    }

    // Two video datasets (another seed) merged: 3 episodes, the second's MP4 copied as
    // file-002, every file read back (frame counts and timestamps against the metadata).
    let other = tmp.path().join("other");
    amstack_ff(&[
        "record",
        "--task",
        "press-button",
        "--episodes",
        "1",
        "--seed",
        "11",
        "--cameras",
        "ee",
        "--video",
        "--out",
        other.to_str().unwrap(),
    ]);
    let both = tmp.path().join("both");
    let said = ok(&[
        "dataset",
        "merge",
        d,
        other.to_str().unwrap(),
        "--out",
        both.to_str().unwrap(),
    ]);
    assert!(said.contains("3 episodes"), "{said}");
    assert!(std::fs::read(mp4(&both, 2)).unwrap() == std::fs::read(mp4(&other, 0)).unwrap());
    assert!(std::fs::read(mp4(&both, 0)).unwrap() == std::fs::read(mp4(&dir, 0)).unwrap());
    let validated = ok(&["dataset", "validate", both.to_str().unwrap()]);
    assert!(validated.contains("valid (3 episodes"), "{validated}");

    // export-openpi decodes every 6th frame: the images equal what imageio-ffmpeg decodes
    // from the source MP4 at those timestamps (and the state/action every 6th source row).
    let openpi = tmp.path().join("openpi");
    let said = amstack_ff(&[
        "dataset",
        "export-openpi",
        both.to_str().unwrap(),
        "--out",
        openpi.to_str().unwrap(),
    ]);
    assert!(said.contains("exported 3 episodes"), "{said}");
    let report = check(&both, Some(&openpi));
    assert_eq!(report["episodes"], 3);
    assert_eq!(report["video_frames"], report["frames"], "{report}");
    let frames = report["frames"].as_u64().unwrap();
    let exported = report["openpi_frames"].as_u64().unwrap();
    assert!(
        exported <= frames / 6 && exported + 3 >= frames / 6,
        "{report}"
    );
    assert_eq!(report["openpi_images"], report["openpi_frames"], "{report}");

    // A merge mixing a video and an image dataset is one line, exit 2, and writes nothing.
    let images = tmp.path().join("images");
    amstack_ff(&[
        "record",
        "--task",
        "press-button",
        "--episodes",
        "1",
        "--seed",
        "3",
        "--cameras",
        "ee",
        "--out",
        images.to_str().unwrap(),
    ]);
    let never = tmp.path().join("never");
    let out = run(&[
        "dataset",
        "merge",
        d,
        images.to_str().unwrap(),
        "--out",
        never.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("videos (record --video)")
            && stderr.contains("merge datasets stored alike"),
        "{stderr}"
    );
    assert!(!never.exists(), "a refused merge left {}", never.display());

    // lerobot's packed layout (both episodes in file-000, the second from its first episode's
    // end, rewritten with pyarrow) cannot be merged without re-encoding: one line, exit 2.
    let packed = tmp.path().join("packed");
    let mut cp = Command::new("cp");
    assert!(
        cp.arg("-r")
            .arg(&dir)
            .arg(&packed)
            .status()
            .unwrap()
            .success()
    );
    let script = r#"
import glob, sys, pyarrow as pa, pyarrow.parquet as pq
key = "observation.images.ee_camera"
f = glob.glob(sys.argv[1] + "/meta/episodes/*/*.parquet")[0]
t = pq.read_table(f)
n = t.column("length").to_pylist()
start = [sum(n[:i]) / 120 for i in range(len(n))]
for name, v in ((f"videos/{key}/file_index", [0] * len(n)),
                (f"videos/{key}/from_timestamp", start),
                (f"videos/{key}/to_timestamp", [s + l / 120 for s, l in zip(start, n)])):
    i = t.schema.get_field_index(name)
    t = t.set_column(i, t.schema.field(i), pa.array(v, type=t.schema.field(i).type))
pq.write_table(t, f)
"#;
    let status = Command::new(python())
        .args(["-c", script])
        .arg(&packed)
        .status()
        .unwrap();
    assert!(status.success());
    let out = run(&[
        "dataset",
        "merge",
        packed.to_str().unwrap(),
        "--out",
        never.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("episode 0:") && stderr.contains("lerobot's packed layout"),
        "{stderr}"
    );
    assert!(!never.exists(), "a refused merge left {}", never.display());
}
