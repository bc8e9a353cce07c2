//! Learned policies in the flight loop, against peers that are not amstack's code:
//!
//! - a policy server built on PyPI `openpi-client`'s encoding (`scripts/openpi_server.py`),
//!   started as a process on 127.0.0.1, checks every key, dtype and shape `amstack bench
//!   --policy remote:…` sends and answers chunks that the rollout flies;
//! - the same server, deliberately broken (refusing, dying, silent, answering a wrong shape,
//!   a NaN, an unnormalised quaternion, an error), ends each rollout `policy_failed` with the
//!   reason while the run goes on;
//! - a server replaying a scripted demonstration's own actions chunk by chunk succeeds on the
//!   demonstration's seed (the chunked interface loses nothing);
//! - an ONNX model made with the `onnx` helper API gives, in amstack (tract), what PyPI
//!   `onnxruntime` gives to 1e-5.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};

use serde_json::Value;
use tests::process::amstack;
use tests::{python, scripts_dir};

/// ONNX inference agreement with onnxruntime (float32 kernels may differ in summation order).
const ONNX_TOLERANCE: f64 = 1e-5;

/// Control steps per macro action (120 Hz / 20 Hz) times the default 8 actions per query.
const TICKS_PER_QUERY: u64 = 6 * 8;

/// A policy server process, killed on drop.
struct Server {
    child: Child,
    url: String,
}

impl Server {
    fn start(args: &[&str]) -> Self {
        let mut child = Command::new(python())
            .arg(scripts_dir().join("openpi_server.py"))
            .args(["--port", "0"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start openpi_server.py: {e}"));
        let stdout = child.stdout.take().unwrap_or_else(|| panic!("no stdout"));
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let url = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("openpi_server.py said {line:?}"))
            .to_owned();
        Self { child, url }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `amstack bench ARGS… --json FILE` on the EE-only oracle's Press Button; its results.
fn bench(dir: &Path, name: &str, args: &[&str]) -> Value {
    let json = dir.join(format!("{name}.json"));
    let out = Command::new(amstack())
        .args([
            "bench",
            "--platform",
            "ee-only",
            "--task",
            "press-button",
            "--jobs",
            "1",
            "--json",
        ])
        .arg(&json)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run amstack: {e}"));
    assert!(
        out.status.success(),
        "amstack bench {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&json).unwrap_or_else(|e| panic!("{e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}"))
}

/// Writes a small ONNX test model (and its sidecar) with `scripts/onnx_model.py make ARGS`.
fn make_model(model: &Path, args: &[&str]) {
    let made = Command::new(python())
        .arg(scripts_dir().join("onnx_model.py"))
        .arg("make")
        .args(args)
        .arg("--out")
        .arg(model)
        .output()
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
}

fn rollouts(results: &Value) -> &Vec<Value> {
    results["tasks"]["press-button"]["per_rollout"]
        .as_array()
        .unwrap_or_else(|| panic!("no rollouts in {results}"))
}

#[test]
fn a_remote_policy_flies_through_openpi_s_protocol() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let log = dir.path().join("requests.jsonl");
    let server = Server::start(&[
        "--mode",
        "goto",
        "--offset",
        "0.1,0,0.1",
        "--prompt",
        "press the button",
        "--log",
        log.to_str().unwrap_or_default(),
    ]);
    let url = format!("remote:{}", server.url);
    // 4 s: ⌈4·120⌉ − 1 = 479 ticks, a query every 48: 10 queries.
    let results = bench(
        dir.path(),
        "goto",
        &["--rollouts", "1", "--episode-length", "4", "--policy", &url],
    );
    let r = &rollouts(&results)[0];
    assert_eq!(r["termination"], "timeout", "{r}");
    assert_eq!(r["executed_steps"], 479);
    assert_eq!(r["policy"]["queries"], 10);
    assert_eq!(results["policy"]["policy_failed"], 0);
    assert!(results["policy"]["latency_ms"]["p50"].as_f64().is_some());
    let requests: Vec<Value> = std::fs::read_to_string(&log)
        .unwrap_or_else(|e| panic!("{e}"))
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}")))
        .collect();
    assert_eq!(requests.len(), 10);
    let mut keys: Vec<&String> = requests[0]["keys"]
        .as_object()
        .unwrap_or_else(|| panic!("keys"))
        .keys()
        .collect();
    keys.sort();
    assert_eq!(
        keys,
        [
            "am_bench/ee_pos",
            "am_bench/ee_quat",
            "am_bench/gripper_width",
            "prompt"
        ]
    );
    assert_eq!(
        requests[0]["keys"]["am_bench/ee_pos"],
        serde_json::json!(["float32", [3]])
    );
    assert_eq!(
        requests[0]["keys"]["am_bench/ee_quat"],
        serde_json::json!(["float32", [4]])
    );
    // The chunks were flown: the end-effector went to the goal, 10 cm ahead and 10 cm up
    // of where it started (observed by the server at the last query, tick 432).
    let position = |q: &Value| -> Vec<f64> {
        q["state"]["am_bench/ee_pos"]
            .as_array()
            .unwrap_or_else(|| panic!("ee_pos"))
            .iter()
            .filter_map(Value::as_f64)
            .collect()
    };
    let first = position(&requests[0]);
    let last = position(&requests[9]);
    let moved: Vec<f64> = last.iter().zip(&first).map(|(l, f)| l - f).collect();
    let error = ((moved[0] - 0.1).powi(2) + moved[1].powi(2) + (moved[2] - 0.1).powi(2)).sqrt();
    assert!(error < 0.02, "moved {moved:?}, expected (0.1, 0, 0.1)");
}

/// A broken server ends each rollout `policy_failed` with `reason`; the run goes on (two
/// rollouts, both reported).
fn broken(fault: &str, reason: &str) {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let server = Server::start(&["--fault", fault, "--fault-after", "1"]);
    let url = format!("remote:{}", server.url);
    let results = bench(
        dir.path(),
        fault,
        &[
            "--rollouts",
            "2",
            "--episode-length",
            "2",
            "--policy",
            &url,
            "--policy-timeout-ms",
            "1500",
        ],
    );
    let all = rollouts(&results);
    assert_eq!(all.len(), 2);
    for r in all {
        assert_eq!(r["termination"], "policy_failed", "{fault}: {r}");
        let why = r["policy"]["failure"].as_str().unwrap_or_default();
        assert!(why.contains(reason), "{fault}: {why:?} lacks {reason:?}");
    }
    // The first chunk was flown whole; the faulty one never reached the stack.
    assert_eq!(all[0]["executed_steps"], TICKS_PER_QUERY, "{fault}");
    assert_eq!(results["tasks"]["press-button"]["policy_failed"], 2);
    assert_eq!(results["policy"]["policy_failed"], 2);
}

#[test]
fn a_server_that_dies_fails_the_rollout_and_the_run_goes_on() {
    // The second rollout finds no server at all (refused).
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let server = Server::start(&["--fault", "die", "--fault-after", "1"]);
    let url = format!("remote:{}", server.url);
    let results = bench(
        dir.path(),
        "die",
        &["--rollouts", "2", "--episode-length", "2", "--policy", &url],
    );
    let all = rollouts(&results);
    assert_eq!(all[0]["termination"], "policy_failed");
    let died = all[0]["policy"]["failure"].as_str().unwrap_or_default();
    assert!(
        died.contains("closed the connection") || died.contains("connection lost"),
        "{died}"
    );
    assert_eq!(all[0]["executed_steps"], TICKS_PER_QUERY);
    let refused = all[1]["policy"]["failure"].as_str().unwrap_or_default();
    assert!(refused.contains("cannot connect"), "{refused}");
    assert_eq!(all[1]["executed_steps"], 0);
    assert_eq!(results["policy"]["policy_failed"], 2);
}

#[test]
fn a_silent_server_times_out() {
    broken("timeout", "no answer in 1500 ms");
}

#[test]
fn a_wrong_shape_is_refused() {
    broken(
        "wrong-shape",
        "wrong shape: actions (10, 7), expected (>= 8, 8)",
    );
}

#[test]
fn a_non_finite_action_is_refused() {
    broken("nan", "non-finite value NaN at actions[1, 0]");
}

#[test]
fn an_unnormalised_quaternion_is_refused() {
    broken(
        "unnormalised",
        "unnormalised quaternion at actions[0, 3..7]: norm 2.000000",
    );
}

#[test]
fn a_server_error_frame_is_the_reason() {
    broken(
        "error",
        "server error: RuntimeError: deliberate policy failure (--fault error)",
    );
}

#[test]
fn replaying_a_demonstration_through_the_remote_path_succeeds() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("scripted");
    let scripted = bench(
        dir.path(),
        "scripted",
        &[
            "--rollouts",
            "1",
            "--seed",
            "5",
            "--out",
            out.to_str().unwrap_or_default(),
        ],
    );
    assert_eq!(rollouts(&scripted)[0]["success"], true, "{scripted}");
    let demo = out.join("rollouts/press-button/rollout-000.mcap");
    let server = Server::start(&[
        "--mode",
        "replay",
        "--demo",
        demo.to_str().unwrap_or_default(),
        "--horizon",
        "16",
    ]);
    let url = format!("remote:{}", server.url);
    let replayed = bench(
        dir.path(),
        "replayed",
        &["--rollouts", "1", "--seed", "5", "--policy", &url],
    );
    let r = &rollouts(&replayed)[0];
    assert_eq!(r["success"], true, "{r}");
    // Within a chunk of the demonstration's own length.
    let demo_steps = rollouts(&scripted)[0]["executed_steps"]
        .as_u64()
        .unwrap_or(0);
    let steps = r["executed_steps"].as_u64().unwrap_or(0);
    assert!(
        steps.abs_diff(demo_steps) <= TICKS_PER_QUERY,
        "{steps} vs {demo_steps}"
    );
}

#[test]
fn onnx_inference_matches_onnxruntime() {
    use policy_runtime::policy::{OnnxPolicy, StateKey};
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let model = dir.path().join("mlp.onnx");
    make_model(&model, &["--horizon", "4", "--seed", "3"]);
    let len = |k: StateKey| match k {
        StateKey::EePos | StateKey::BasePos => 3,
        StateKey::EeQuat | StateKey::BaseQuat => 4,
        StateKey::GripperWidth => 1,
        StateKey::ArmJointPos => 4,
    };
    let policy = OnnxPolicy::load(&model, &len).unwrap_or_else(|e| panic!("{e}"));
    // Five inputs: zeros, a hover pose, and three spread ones.
    let inputs: Vec<Vec<f32>> = (0..5)
        .map(|i| {
            (0..8)
                .map(|j| {
                    if i == 0 {
                        0.0
                    } else {
                        ((i * 8 + j) as f32 * 0.37).sin() * i as f32
                    }
                })
                .collect()
        })
        .collect();
    let file = dir.path().join("inputs.json");
    std::fs::write(&file, serde_json::to_string(&inputs).unwrap_or_default())
        .unwrap_or_else(|e| panic!("{e}"));
    let run = Command::new(python())
        .arg(scripts_dir().join("onnx_model.py"))
        .args(["run", "--model"])
        .arg(&model)
        .arg("--inputs")
        .arg(&file)
        .output()
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let reference: Value = serde_json::from_slice(&run.stdout).unwrap_or_else(|e| panic!("{e}"));
    for (input, expected) in inputs
        .iter()
        .zip(reference["outputs"].as_array().into_iter().flatten())
    {
        let ours = policy.run_raw(input, &[]).unwrap_or_else(|e| panic!("{e}"));
        let theirs: Vec<f64> = expected
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(Value::as_f64)
            .collect();
        assert_eq!(ours.len(), 4 * 8);
        assert_eq!(theirs.len(), ours.len());
        for (a, b) in ours.iter().zip(&theirs) {
            assert!(
                (f64::from(*a) - b).abs() <= ONNX_TOLERANCE,
                "tract {a} vs onnxruntime {b} on {input:?}"
            );
        }
    }
}

#[test]
fn an_onnx_policy_flies_a_rollout_from_the_cli() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let model = dir.path().join("relative.onnx");
    make_model(&model, &["--horizon", "8", "--semantics", "relative"]);
    let policy = format!("onnx:{}", model.display());
    // 1 s: 119 ticks, a query every 48: 3 queries.
    let results = bench(
        dir.path(),
        "onnx",
        &[
            "--rollouts",
            "1",
            "--episode-length",
            "1",
            "--policy",
            &policy,
        ],
    );
    let r = &rollouts(&results)[0];
    assert_eq!(r["policy"]["queries"], 3, "{r}");
    assert_eq!(r["policy"]["failure"], Value::Null, "{r}");
}

#[test]
fn a_remote_policy_sees_the_cameras_images_on_query_ticks() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let log = dir.path().join("requests.jsonl");
    let server = Server::start(&["--log", log.to_str().unwrap_or_default()]);
    let url = format!("remote:{}", server.url);
    // 1 s: 119 ticks, 3 queries, each with the EE camera's image of its observation.
    let results = bench(
        dir.path(),
        "cameras",
        &[
            "--rollouts",
            "1",
            "--episode-length",
            "1",
            "--cameras",
            "ee",
            "--policy",
            &url,
        ],
    );
    let r = &rollouts(&results)[0];
    assert_eq!(r["policy"]["queries"], 3, "{r}");
    let requests: Vec<Value> = std::fs::read_to_string(&log)
        .unwrap_or_else(|e| panic!("{e}"))
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}")))
        .collect();
    assert_eq!(requests.len(), 3);
    for q in &requests {
        let image = &q["keys"]["am_bench/ee_image"];
        assert_eq!(image[0], "uint8", "{q}");
        assert_eq!(image[1][2], 3, "{q}");
        assert!(image[1][0].as_u64().unwrap_or(0) > 0);
        assert_eq!(q["keys"].get("am_bench/base_image"), None);
    }
}

/// `v` without its `timing` and without every `latency_ms` (wall-clock figures).
fn without_wall_clock(v: &Value) -> Value {
    match v {
        Value::Object(m) => Value::Object(
            m.iter()
                .filter(|(k, _)| *k != "timing" && *k != "latency_ms")
                .map(|(k, x)| (k.clone(), without_wall_clock(x)))
                .collect(),
        ),
        Value::Array(a) => Value::Array(a.iter().map(without_wall_clock).collect()),
        x => x.clone(),
    }
}

#[test]
fn a_sharded_run_of_a_learned_policy_merges_to_the_unsharded_results() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let model = dir.path().join("relative.onnx");
    make_model(&model, &["--horizon", "8", "--semantics", "relative"]);
    let policy = format!("onnx:{}", model.display());
    let run = [
        "--rollouts",
        "3",
        "--episode-length",
        "1",
        "--policy",
        &policy,
    ];
    let whole = bench(dir.path(), "whole", &run);
    let mut parts = Vec::new();
    for i in 0..2 {
        let shard = format!("{i}/2");
        let mut args = run.to_vec();
        args.extend(["--shard", &shard]);
        let part = bench(dir.path(), &format!("part{i}"), &args);
        assert_eq!(part["policy"]["policy_hz"].as_f64(), Some(20.0), "{part}");
        parts.push(dir.path().join(format!("part{i}.json")));
    }
    let merged_dir = dir.path().join("merged");
    let out = Command::new(amstack())
        .args(["bench", "merge"])
        .args(&parts)
        .arg("--out")
        .arg(&merged_dir)
        .output()
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let merged: Value =
        serde_json::from_slice(&std::fs::read(merged_dir.join("results.json")).unwrap_or_default())
            .unwrap_or_else(|e| panic!("{e}"));
    // 1 s: 3 queries per rollout.
    assert_eq!(merged["policy"]["queries"], 9, "{merged}");
    assert_eq!(merged["policy"]["latency_ms"]["count"], 9, "{merged}");
    assert_eq!(merged["policy"]["policy"], whole["policy"]["policy"]);
    assert_eq!(without_wall_clock(&merged), without_wall_clock(&whole));
}

/// The train-here pipeline, tiny: `scripts/pipeline.sh` records 2 NDT demonstrations on the
/// FA-Hexa, trains the behaviour-cloning MLP (scikit-learn), exports ONNX, and flies it in
/// process (tract) and served over openpi's protocol (onnxruntime). The chain works — the
/// model loads, rollouts run and query it, the results parse — whatever the success rate of a
/// policy of 2 demonstrations.
#[test]
fn the_record_train_evaluate_pipeline_runs_end_to_end() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("pipeline");
    let run = Command::new("bash")
        .arg(scripts_dir().join("pipeline.sh"))
        .args(["--episodes", "2", "--rollouts", "2", "--jobs", "2", "--out"])
        .arg(&out)
        .env("AMSTACK", amstack())
        .output()
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        run.status.success(),
        "pipeline.sh failed:\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let read = |name: &str| -> Value {
        let text =
            std::fs::read_to_string(out.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"))
    };
    let train = read("train.json");
    assert_eq!(train["episodes"], 2, "{train}");
    assert!(
        train["onnx_vs_sklearn_max_abs"]
            .as_f64()
            .is_some_and(|e| e < 1e-4),
        "{train}"
    );
    let sidecar = read("policy.onnx.json");
    assert_eq!(sidecar["output"]["dim"], 8);
    for path in ["onnx", "remote"] {
        let results = read(&format!("bench-{path}.json"));
        let task = &results["tasks"]["ndt"];
        assert_eq!(task["rollouts"], 2, "{path}: {results}");
        assert_eq!(task["policy_failed"], 0, "{path}: {results}");
        for r in task["per_rollout"].as_array().into_iter().flatten() {
            // At least the first query, then one every 48 ticks flown.
            let steps = r["executed_steps"].as_u64().unwrap_or(0);
            let queries = r["policy"]["queries"].as_u64().unwrap_or(0);
            assert!(
                steps > 0 && queries >= 1 && queries >= steps / TICKS_PER_QUERY,
                "{path}: {r}"
            );
        }
        assert!(
            results["policy"]["latency_ms"]["p50"].as_f64().is_some(),
            "{path}"
        );
    }
    let summary = read("summary.json");
    assert!(
        summary["remote"]["success_rate"].as_f64().is_some(),
        "{summary}"
    );
}
