//! Sharded benchmark runs through the real `amstack` binary: `bench --shard I/N` parts merged
//! with `bench merge` are the unsharded run, and parts that are not one run's complete split
//! are refused naming the problem.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A small, fast run: two tasks of the EE-only oracle, two rollouts each (4 rollouts, so
/// three shards hold 2, 1 and 1 of them).
const RUN: [&str; 8] = [
    "--platform",
    "ee-only",
    "--task",
    "press-button,push-slider",
    "--rollouts",
    "2",
    "--seed",
    "11",
];

fn amstack(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_amstack"));
    command
        .args(args)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX");
    for (k, v) in env {
        command.env(k, v);
    }
    match command.output() {
        Ok(out) => out,
        Err(e) => panic!("cannot start amstack: {e}"),
    }
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn ok(out: &Output) {
    assert!(out.status.success(), "amstack failed: {}", stderr(out));
}

/// Bad input: exit 2 and exactly one line on stderr, containing every `needle`.
fn assert_bad_input(out: &Output, needles: &[&str]) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(2), "exit code; stderr: {err}");
    assert_eq!(err.lines().count(), 1, "one line: {err:?}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in {err:?}");
    }
}

fn bench(extra: &[&str], env: &[(&str, &str)]) -> Output {
    let mut args = vec!["bench"];
    args.extend(RUN);
    args.extend(extra);
    amstack(&args, env)
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every file under `dir`, by relative path, with its bytes.
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut found = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if let Ok(rel) = path.strip_prefix(dir) {
                found.insert(rel.to_path_buf(), std::fs::read(&path).unwrap_or_default());
            }
        }
    }
    found
}

/// A results document without its timing, its log paths relative to `out`.
fn comparable(results: &serde_json::Value, out: &Path) -> String {
    let mut v = results.clone();
    if let Some(o) = v.as_object_mut() {
        o.remove("timing");
    }
    serde_json::to_string(&v)
        .unwrap_or_default()
        .replace(&s(out), "OUT")
}

#[test]
fn three_shards_merged_equal_the_unsharded_run() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let full = dir.path().join("full");
    ok(&bench(&["--jobs", "2", "--out", &s(&full)], &[]));
    // Shard 0 from the flag, 1 from a Slurm array index, 2 from a Kubernetes Indexed Job's.
    let parts: Vec<PathBuf> = (0..3)
        .map(|i| dir.path().join(format!("part{i}")))
        .collect();
    ok(&bench(
        &["--jobs", "1", "--shard", "0/3", "--out", &s(&parts[0])],
        &[],
    ));
    ok(&bench(
        &["--jobs", "1", "--shard", "env/3", "--out", &s(&parts[1])],
        &[("SLURM_ARRAY_TASK_ID", "1")],
    ));
    ok(&bench(
        &["--jobs", "1", "--shard", "env/3", "--out", &s(&parts[2])],
        &[("JOB_COMPLETION_INDEX", "2")],
    ));
    // Round robin over k = task position * 2 + index: shard 0 holds k = 0, 3.
    let part0 = read_json(&parts[0].join("part.json"));
    assert_eq!(part0["shard"]["index"], 0);
    assert_eq!(part0["shard"]["count"], 3);
    let held: Vec<(String, u64)> = part0["rollouts"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|r| {
            (
                r["task"].as_str().unwrap_or_default().to_owned(),
                r["index"].as_u64().unwrap_or(99),
            )
        })
        .collect();
    assert_eq!(
        held,
        [
            ("press-button".to_owned(), 0),
            ("push-slider".to_owned(), 1)
        ]
    );
    assert_eq!(part0["config"], read_json(&full.join("config.json")));

    let merged = dir.path().join("merged");
    // The parts in any order.
    ok(&amstack(
        &[
            "bench",
            "merge",
            &s(&parts[2]),
            &s(&parts[0]),
            &s(&parts[1]),
            "--out",
            &s(&merged),
        ],
        &[],
    ));
    let expected = read_json(&full.join("results.json"));
    let got = read_json(&merged.join("results.json"));
    assert_eq!(expected["tasks"]["push-slider"]["rollouts"], 2);
    assert_eq!(comparable(&got, &merged), comparable(&expected, &full));
    assert_eq!(got["timing"]["env_steps"], expected["timing"]["env_steps"]);
    // The same files, byte for byte: config.json and every rollout's MCAP log.
    let (mut a, mut b) = (files(&full), files(&merged));
    let results = PathBuf::from("results.json");
    a.remove(&results);
    b.remove(&results);
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the same files"
    );
    assert_eq!(a.len(), 5, "config.json and 4 logs: {:?}", a.keys());
    for (path, bytes) in &a {
        assert!(b[path] == *bytes, "{} differs", path.display());
    }
}

#[test]
fn parts_that_are_not_one_runs_complete_split_are_refused() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let part = |i: usize, extra: &[&str]| {
        let path = dir.path().join(format!("part{i}{}.json", extra.join("")));
        let shard = format!("{i}/3");
        let mut args = vec!["--shard", &shard, "--json"];
        let file = s(&path);
        args.push(&file);
        args.extend(extra);
        ok(&bench(&args, &[]));
        file
    };
    let (p0, p1, p2) = (part(0, &[]), part(1, &[]), part(2, &[]));
    let other = part(1, &["--disturbances", "drag"]);
    let out = s(&dir.path().join("merged"));
    let merge = |parts: &[&str]| {
        let mut args = vec!["bench", "merge"];
        args.extend(parts);
        args.extend(["--out", &out]);
        amstack(&args, &[])
    };
    assert_bad_input(
        &merge(&[&p0, &other, &p2]),
        &["parts of different runs", "config.disturbances", "drag"],
    );
    assert_bad_input(&merge(&[&p0, &p2]), &["shard 1/3 missing"]);
    assert_bad_input(&merge(&[&p0, &p1, &p1, &p2]), &["shard 1/3 given twice"]);
    // A part that lost a rollout.
    let mut cut = read_json(Path::new(&p0));
    if let Some(rollouts) = cut["rollouts"].as_array_mut() {
        rollouts.pop();
    }
    let cut_path = dir.path().join("cut.json");
    let written = std::fs::write(&cut_path, cut.to_string());
    assert!(written.is_ok(), "{written:?}");
    assert_bad_input(
        &merge(&[&s(&cut_path), &p1, &p2]),
        &["shard 0/3 is incomplete", "push-slider #1 missing"],
    );
    assert!(!dir.path().join("merged").exists(), "nothing written");
    // And the three of one run merge.
    ok(&merge(&[&p0, &p1, &p2]));
    assert_eq!(
        read_json(&dir.path().join("merged/results.json"))["tasks"]["press-button"]["rollouts"],
        2
    );
}

#[test]
fn bad_shard_specs_and_missing_array_indices_are_bad_input() {
    let out = |flag: &str, env: &[(&str, &str)]| bench(&["--shard", flag, "--json", "x.json"], env);
    assert_bad_input(&out("1-3", &[]), &["--shard 1-3", "expected I/N"]);
    assert_bad_input(&out("3/3", &[]), &["--shard 3/3", "0 to 2"]);
    assert_bad_input(
        &out("env/3", &[]),
        &["SLURM_ARRAY_TASK_ID nor JOB_COMPLETION_INDEX"],
    );
    assert_bad_input(
        &out("env/3", &[("SLURM_ARRAY_TASK_ID", "3")]),
        &["SLURM_ARRAY_TASK_ID=3", "--array=0-2"],
    );
    assert_bad_input(
        &out("env/2", &[("JOB_COMPLETION_INDEX", "one")]),
        &["JOB_COMPLETION_INDEX=\"one\"", "not a shard index"],
    );
    assert_bad_input(
        &bench(&["--shard", "0/2"], &[]),
        &["--shard", "--out DIR, or --json FILE"],
    );
    assert_bad_input(
        &amstack(&["bench", "merge", "nowhere", "--out", "x"], &[]),
        &["nowhere: cannot read it"],
    );
}

/// A sweep of 2 cells: the oracle under PID and L1 on one task.
const SWEEP: &str = r#"
[grid]
platforms = ["ee-only"]
controllers = ["pid", "l1"]
tasks = ["press-button"]
rollouts = 2
seeds = 5
"#;

#[test]
fn a_sweep_runs_each_cell_as_bench_would_and_resumes() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let file = dir.path().join("sweep.toml");
    let written = std::fs::write(&file, SWEEP);
    assert!(written.is_ok(), "{written:?}");
    let out = dir.path().join("out");
    let sweep = || amstack(&["sweep", &s(&file), "--out", &s(&out), "--jobs", "2"], &[]);
    let first = sweep();
    ok(&first);
    let cells = [
        "ee-only_pid_ee_none_press-button_r2_s5",
        "ee-only_l1_ee_none_press-button_r2_s5",
    ];
    // Each cell holds what `amstack bench` writes for the same flags.
    let direct = dir.path().join("direct");
    ok(&amstack(
        &[
            "bench",
            "--platform",
            "ee-only",
            "--controller",
            "l1",
            "--task",
            "press-button",
            "--rollouts",
            "2",
            "--seed",
            "5",
            "--out",
            &s(&direct),
        ],
        &[],
    ));
    let cell = out.join("cells").join(cells[1]);
    assert_eq!(
        comparable(&read_json(&cell.join("results.json")), &cell),
        comparable(&read_json(&direct.join("results.json")), &direct)
    );
    assert_eq!(files(&cell).len(), files(&direct).len());
    // The summary: one CSV row per cell and task, the JSON naming each cell's results.
    let csv = std::fs::read_to_string(out.join("summary.csv")).unwrap_or_default();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 3, "{csv}");
    assert!(lines[0].starts_with("cell,platform,controller,interface,disturbances,seed"));
    assert!(
        lines[2].starts_with(&format!(
            "{},ee-only,l1,ee,none,5,script,press-button,2,",
            cells[1]
        )),
        "{csv}"
    );
    let summary = read_json(&out.join("summary.json"));
    assert_eq!(summary["cells"][0]["name"], cells[0]);
    assert_eq!(summary["cells"][0]["status"], "completed");
    // Resuming: nothing to run, nothing rewritten.
    let before = files(&out.join("cells"));
    let again = sweep();
    ok(&again);
    assert!(
        stderr(&again).contains("2 cell(s), 0 to run (2 completed before)"),
        "{}",
        stderr(&again)
    );
    assert!(
        files(&out.join("cells")) == before,
        "a completed cell is not run again"
    );
    // A cell cut short runs again.
    let results = out.join("cells").join(cells[0]).join("results.json");
    let mut cut = read_json(&results);
    cut["status"] = serde_json::json!("interrupted");
    assert!(std::fs::write(&results, cut.to_string()).is_ok());
    let third = sweep();
    ok(&third);
    assert!(stderr(&third).contains("1 to run"), "{}", stderr(&third));
    assert_eq!(read_json(&results)["status"], "completed");
}

#[test]
fn a_bad_sweep_file_is_refused_on_one_line_naming_the_field() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let check = |text: &str, needles: &[&str]| {
        let file = dir.path().join("bad.toml");
        assert!(std::fs::write(&file, text).is_ok());
        let out = s(&dir.path().join("out"));
        assert_bad_input(&amstack(&["sweep", &s(&file), "--out", &out], &[]), needles);
        assert!(
            !dir.path().join("out").exists(),
            "nothing written for {text}"
        );
    };
    check(
        "[grid]\nplatfroms = [\"ee-only\"]\n",
        &["grid.platfroms: unknown field"],
    );
    check(
        "[grid]\nrollouts = [\"many\"]\n",
        &["grid.rollouts", "many"],
    );
    check(
        "[grid]\nplatforms = [\"fa-hexa\"]\ncontrollers = [\"pid\"]\n",
        &[
            "grid cell 1",
            "controller pid is not available on fa-hexa",
            "skip_unavailable",
        ],
    );
    check(
        "[[run]]\nplatform = \"ee-only\"\ndisturbances = \"gusts\"\n",
        &["run[0]", "--disturbances", "gusts"],
    );
    check(
        "[[run]]\ntask = \"press-button\"\n[[run]]\ntask = \"press-button\"\n",
        &["run[1]", "already in the sweep"],
    );
    check("[grid\n", &["bad.toml line 1"]);
    check("", &["no cells"]);
    // Unavailable grid cells may be left out on request.
    let file = dir.path().join("skip.toml");
    let text = "[grid]\nplatforms = [\"ee-only\", \"fa-hexa\"]\ncontrollers = [\"pid\"]\ntasks = [\"press-button\"]\nrollouts = 1\nskip_unavailable = true\n";
    assert!(std::fs::write(&file, text).is_ok());
    let out = amstack(&["sweep", &s(&file), "--out", "unused", "--dry-run"], &[]);
    ok(&out);
    let plan = String::from_utf8_lossy(&out.stdout).into_owned();
    assert_eq!(plan.lines().count(), 1, "{plan}");
    assert!(
        plan.contains("--platform ee-only --controller pid"),
        "{plan}"
    );
    assert!(
        stderr(&out).contains("skipped grid cell 2"),
        "{}",
        stderr(&out)
    );
}
