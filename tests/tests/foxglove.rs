//! The flight seen from outside, through the Foxglove SDK's channels: the 3D scene in the log
//! decoded by independent readers (Google's `protobuf` package over the Python `mcap` reader;
//! Rerun's MCAP importer), and the live view (`--live`) watched by a WebSocket client written
//! against the Foxglove WebSocket protocol (Python `websockets`).

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use tests::process::{Proc, amstack};
use tests::{mcap_check, scripts_dir, wait_for_file, ws_client};

/// Runs amstack to completion; panics with its stderr on failure.
fn run(args: &[&str]) -> String {
    let out = Command::new(amstack()).args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "amstack {args:?}: {stderr}");
    stderr
}

/// An FA-Hexa Press Button rollout (the scripted policy) logged to `dir/press.mcap`.
fn press_button_log(dir: &Path) -> PathBuf {
    let mcap = dir.join("press.mcap");
    run(&[
        "track",
        "--platform",
        "fa-hexa",
        "--trajectory",
        "scripted",
        "--task",
        "press-button",
        "--seed",
        "3",
        "--mcap",
        mcap.to_str().unwrap(),
    ]);
    mcap
}

fn strings(v: &Value) -> Vec<&str> {
    v.as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default()
}

#[test]
fn the_log_holds_the_3d_scene_in_foxglove_protobuf_decoded_by_python() {
    let dir = tempfile::tempdir().unwrap();
    let mcap = press_button_log(dir.path());
    let (code, report) = mcap_check(&mcap, &["--require-complete"]);
    assert_eq!(code, 0, "{report}");
    let channels = report["channels"].as_array().unwrap();
    let channel = |topic: &str| {
        channels
            .iter()
            .find(|c| c["topic"] == topic)
            .unwrap_or_else(|| panic!("no {topic}: {report}"))
    };
    let ticks = channel("/base/state")["count"].as_u64().unwrap();
    assert!(ticks > 100, "a rollout of more than 100 ticks: {ticks}");
    for (topic, schema) in [
        ("/scene/tf", "foxglove.FrameTransforms"),
        ("/scene/static", "foxglove.SceneUpdate"),
        ("/scene/dynamic", "foxglove.SceneUpdate"),
        ("/scene/targets", "foxglove.SceneUpdate"),
    ] {
        let c = channel(topic);
        assert_eq!(c["schema_name"], schema, "{c}");
        assert_eq!(c["schema_encoding"], "protobuf", "{c}");
        assert_eq!(c["message_encoding"], "protobuf", "{c}");
        // Every message decoded by the class built from the file's own schema record.
        assert_eq!(report["decoded"][topic]["count"], c["count"], "{topic}");
    }
    // One transform set and one targets marker per tick, one rotor/objects update per step.
    assert_eq!(channel("/scene/tf")["count"].as_u64(), Some(ticks));
    assert_eq!(channel("/scene/targets")["count"].as_u64(), Some(ticks));
    assert_eq!(
        channel("/scene/dynamic")["count"],
        channel("/rotors")["count"]
    );
    // The static scene: at t = 0 and once every simulated second after.
    let seconds = ticks as f64 / 120.0;
    let statics = channel("/scene/static")["count"].as_u64().unwrap();
    assert_eq!(statics, seconds.ceil() as u64, "{ticks} ticks");

    let tf = &report["decoded"]["/scene/tf"];
    let frames = strings(&tf["frames"]);
    assert!(frames.contains(&"world->base_link"), "{frames:?}");
    for i in 0..6 {
        assert!(
            frames.contains(&format!("base_link->rotor_{i}").as_str()),
            "{frames:?}"
        );
    }
    let statics = &report["decoded"]["/scene/static"];
    let entities = strings(&statics["entities"]);
    assert!(entities.contains(&"vehicle/base_link"), "{entities:?}");
    assert!(
        entities.contains(&"scene/fixed"),
        "floor and wall: {entities:?}"
    );
    assert!(
        statics["primitives"]["cubes"].as_u64().unwrap() >= 2,
        "floor and wall are cubes: {statics}"
    );
    let dynamic = &report["decoded"]["/scene/dynamic"];
    let entities = strings(&dynamic["entities"]);
    assert!(
        entities.contains(&"scene/objects"),
        "the button's plunger: {entities:?}"
    );
    for i in 0..6 {
        assert!(
            entities.contains(&format!("rotor/{i}/thrust").as_str()),
            "{entities:?}"
        );
    }
    let targets = strings(&report["decoded"]["/scene/targets"]["entities"]);
    assert_eq!(targets, ["target/ee", "target/base"]);
}

#[test]
fn the_layout_plots_channels_a_press_button_log_has() {
    let layout: Value = serde_json::from_str(
        &std::fs::read_to_string(scripts_dir().join("../docs/foxglove-layout.json")).unwrap(),
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mcap = press_button_log(dir.path());
    let (_, report) = mcap_check(&mcap, &[]);
    let topics: Vec<&str> = report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|c| c["topic"].as_str())
        .collect();
    let mut named = 0;
    for (id, panel) in layout["configById"].as_object().unwrap() {
        for p in panel["paths"].as_array().into_iter().flatten() {
            let path = p["value"].as_str().unwrap();
            let topic = path.split('.').next().unwrap();
            assert!(
                topics.contains(&topic),
                "{id}: {path} names no channel of {topics:?}"
            );
            named += 1;
        }
        if let Some(scene_topics) = panel["topics"].as_object() {
            for topic in scene_topics.keys() {
                if topic != "/camera/tf" {
                    assert!(topics.contains(&topic.as_str()), "{id}: {topic}");
                }
            }
        }
    }
    assert!(
        named >= 10,
        "plots of errors, thrusts and saturation: {named} paths"
    );
    assert_eq!(
        layout["configById"]["Image!ee"]["imageMode"]["imageTopic"],
        "/camera/ee_camera/image"
    );
}

/// The opt-in Rerun venv (scripts/setup-rerun.sh): set up with AMSTACK_RERUN=1, used when
/// present, else None (the caller says it skips).
fn rerun_python() -> Option<PathBuf> {
    let script = scripts_dir().join("setup-rerun.sh");
    let venv = std::env::var_os("AMSTACK_RERUN_VENV")
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/amstack-rerun-venv"))
        })?;
    if !venv.join("bin/python").is_file() && std::env::var("AMSTACK_RERUN").as_deref() != Ok("1") {
        return None;
    }
    let out = Command::new("bash").arg(&script).output().unwrap();
    assert!(
        out.status.success(),
        "{}: {}",
        script.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    Some(PathBuf::from(
        stdout.lines().last().unwrap_or_default().trim(),
    ))
}

#[test]
fn rerun_converts_a_press_button_log_into_transforms_scene_entities_and_images() {
    let Some(rerun_python) = rerun_python() else {
        eprintln!(
            "SKIPPED rerun_converts_a_press_button_log_into_transforms_scene_entities_and_images: the \
             opt-in Rerun venv is absent (run scripts/setup-rerun.sh, ~790 MB, or set AMSTACK_RERUN=1)"
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // With the EE and base cameras' images (the SDK's CompressedImage, CameraCalibration).
    let mcap = dir.path().join("press.mcap");
    run(&[
        "track",
        "--platform",
        "fa-hexa",
        "--trajectory",
        "scripted",
        "--task",
        "press-button",
        "--seed",
        "3",
        "--cameras",
        "ee,base",
        "--camera-log-every",
        "60",
        "--mcap",
        mcap.to_str().unwrap(),
    ]);
    let out = Command::new(rerun_python)
        .arg(scripts_dir().join("rrd_check.py"))
        .arg(&mcap)
        .args(["--expect-transforms", "--expect-scene", "--expect-images"])
        .output()
        .unwrap();
    let report: Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "rrd_check.py: {e}: {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert!(out.status.success(), "{report}");
    let entities = report["entities"].as_object().unwrap();
    let tf = entities
        .iter()
        .find(|(path, _)| path.ends_with("/scene/tf"))
        .map(|(_, e)| e)
        .unwrap();
    assert!(strings(&tf["archetypes"]).contains(&"Transform3D"), "{tf}");
    // The camera image comes through as an image, its calibration as a pinhole.
    let entity = |topic: &str| {
        entities
            .iter()
            .find(|(path, _)| path.trim_end_matches('/').ends_with(topic))
            .map(|(_, e)| e)
            .unwrap_or_else(|| panic!("no {topic}: {report}"))
    };
    let image = entity("/camera/ee_camera/image");
    assert!(
        strings(&image["archetypes"]).contains(&"EncodedImage"),
        "{image}"
    );
    let calibration = entity("/camera/ee_camera/calibration");
    assert!(
        strings(&calibration["archetypes"]).contains(&"Pinhole"),
        "{calibration}"
    );
    // The hand-written JSON channels stay raw bytes to Rerun: the reason for the SDK's.
    let json_tf = entities
        .iter()
        .find(|(path, _)| {
            path.trim_end_matches('/').ends_with("/tf")
                && !path.contains("scene")
                && !path.contains("camera")
        })
        .map(|(_, e)| e);
    if let Some(json_tf) = json_tf {
        assert!(
            !strings(&json_tf["archetypes"]).contains(&"Transform3D"),
            "{json_tf}"
        );
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn results(path: &Path) -> Value {
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    // The wall clock's figures differ between any two runs; the flight's do not.
    let o = v.as_object_mut().unwrap();
    o.remove("wall_time_s");
    o.remove("ticks_per_second");
    o.remove("mcap");
    v
}

#[test]
fn a_live_viewer_receives_the_scene_at_the_tick_rate_and_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let flight = |json: &Path| -> Vec<String> {
        [
            "track",
            "--platform",
            "fa-hexa",
            "--trajectory",
            "step",
            // Long enough (~1 s of CPU) for both viewers to connect while it flies: the
            // flight never waits for them.
            "--duration",
            "100",
            "--seed",
            "5",
            "--json",
            json.to_str().unwrap(),
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect()
    };
    let alone = dir.path().join("alone.json");
    run(&flight(&alone)
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());

    // Watched by a viewer that reads, and by one that subscribes and stalls.
    let port = free_port();
    let addr = format!("127.0.0.1:{port}");
    let watched = dir.path().join("watched.json");
    let mut args = flight(&watched);
    args.extend(["--live".to_owned(), addr.clone()]);
    let mut proc = Proc::start(
        "track --live",
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
    );
    let line = proc.wait_for("live view: ws://");
    assert!(line.contains(&addr), "{line}");
    let url = format!("ws://{addr}");
    let slow = ws_client(&[&url, "--stall", "3", "--timeout", "30"])
        .spawn()
        .unwrap();
    let out = ws_client(&[
        &url,
        "--messages",
        "60",
        "--need",
        "/scene/static=1",
        "--timeout",
        "60",
    ])
    .output()
    .unwrap();
    let report: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("client: {e}: {}", String::from_utf8_lossy(&out.stderr)));
    assert!(out.status.success(), "{report}");
    let slow = slow.wait_with_output().unwrap();
    assert!(
        slow.status.success(),
        "slow viewer: {}",
        String::from_utf8_lossy(&slow.stdout)
    );
    assert!(proc.wait().success(), "{}", proc.stderr());

    // What the viewer was told and given.
    let adv = &report["advertised"];
    assert_eq!(adv["/scene/tf"]["schemaName"], "foxglove.FrameTransforms");
    assert_eq!(adv["/scene/tf"]["encoding"], "protobuf");
    assert_eq!(adv["/scene/static"]["schemaName"], "foxglove.SceneUpdate");
    assert_eq!(
        adv["/rotors"]["schemaName"], "amstack.Rotors",
        "every log channel streams"
    );
    assert_eq!(adv["/rotors"]["encoding"], "json");
    let tf = &report["received"]["/scene/tf"];
    assert!(tf["count"].as_u64().unwrap() >= 60, "{tf}");
    // Consecutive transforms one control tick apart (1/120 s, in the flight's own time):
    // the viewer got every tick, at the tick rate.
    let step = tf["median_step_ns"].as_f64().unwrap();
    assert!((step - 1e9 / 120.0).abs() <= 1.0, "median step {step} ns");
    assert!(strings(&tf["frames"]).contains(&"world->base_link"), "{tf}");
    let targets = strings(&report["received"]["/scene/targets"]["entities"]);
    assert_eq!(targets, ["target/ee", "target/base"]);

    // The end report counts what was published and dropped; the flight is the same flight.
    let stats = proc.wait_for("live view: ");
    let stats = proc
        .stderr()
        .lines()
        .find(|l| l.contains("messages published"))
        .map(str::to_owned)
        .unwrap_or(stats);
    assert!(stats.contains("dropped"), "{stats}");
    assert_eq!(results(&alone), results(&watched));
}

#[test]
fn a_served_twin_streams_its_truth_live_while_another_process_flies_it() {
    let dir = tempfile::tempdir().unwrap();
    let service = format!("test-{}-live", std::process::id());
    let port = free_port();
    let addr = format!("127.0.0.1:{port}");
    let common = ["--platform", "fa-hexa", "--seed", "3"];
    let mut twin_args = vec![
        "twin",
        "serve",
        "--ipc",
        &service,
        "--flight-chooses-episode",
        "--sessions",
        "1",
        "--live",
        &addr,
    ];
    twin_args.extend(common);
    let mut twin = Proc::start("twin serve --live", &twin_args);
    let line = twin.wait_for("live view: ws://");
    assert!(line.contains(&addr), "{line}");
    twin.wait_for("twin: serving");

    // The viewer connects while the twin waits for a flight, subscribes, then the flight.
    let ready = dir.path().join("subscribed");
    let topics =
        "/scene/tf,/scene/static,/scene/dynamic,/tf,/base/state,/joints,/rotors,/task/state";
    let mut viewer = ws_client(&[
        &format!("ws://{addr}"),
        "--topics",
        topics,
        "--messages",
        "100",
        "--need",
        "/scene/static=2",
        "--timeout",
        "120",
        "--ready-file",
        ready.to_str().unwrap(),
    ])
    .stdout(std::process::Stdio::piped())
    .spawn()
    .unwrap();
    wait_for_file(&ready, &mut viewer);
    let link = format!("ipc:{service}");
    let out = dir.path().join("bench");
    let mut bench = vec![
        "bench",
        "--task",
        "press-button",
        "--rollouts",
        "1",
        "--link",
        &link,
        "--link-timeout-ms",
        "10000",
        "--out",
        out.to_str().unwrap(),
    ];
    bench.extend(common);
    let mut flight = Proc::start("bench --link ipc", &bench);
    assert!(flight.wait().success(), "{}", flight.stderr());
    let viewed = viewer.wait_with_output().unwrap();
    let report: Value = serde_json::from_slice(&viewed.stdout)
        .unwrap_or_else(|e| panic!("client: {e}: {}", String::from_utf8_lossy(&viewed.stdout)));
    assert!(viewed.status.success(), "{report}");
    assert!(twin.wait().success(), "{}", twin.stderr());
    sim_twin::ipc::cleanup_dead_nodes_now();

    // Advertised with the flight log's schemas: the SDK's protobuf scene, amstack's JSON.
    let adv = &report["advertised"];
    for (topic, schema, encoding) in [
        ("/scene/tf", "foxglove.FrameTransforms", "protobuf"),
        ("/scene/static", "foxglove.SceneUpdate", "protobuf"),
        ("/scene/dynamic", "foxglove.SceneUpdate", "protobuf"),
        ("/tf", "foxglove.FrameTransforms", "json"),
        ("/base/state", "amstack.BaseState", "json"),
        ("/rotors", "amstack.Rotors", "json"),
        ("/task/state", "amstack.TaskState", "json"),
    ] {
        assert_eq!(adv[topic]["schemaName"], schema, "{topic}: {adv}");
        assert_eq!(adv[topic]["encoding"], encoding, "{topic}: {adv}");
    }
    let got = &report["received"];
    // Every step of the twin, one control period (1/120 s of its time) apart.
    let tf = &got["/scene/tf"];
    assert!(tf["count"].as_u64().unwrap() >= 100, "{tf}");
    let step = tf["median_step_ns"].as_f64().unwrap();
    assert!((step - 1e9 / 120.0).abs() <= 1.0, "median step {step} ns");
    assert!(strings(&tf["frames"]).contains(&"world->base_link"), "{tf}");
    for i in 0..6 {
        assert!(
            strings(&tf["frames"]).contains(&format!("base_link->rotor_{i}").as_str()),
            "{tf}"
        );
    }
    // The task scene the twin holds: floor and wall, the button's plunger, the rotors' thrust.
    let statics = strings(&got["/scene/static"]["entities"]);
    assert!(statics.contains(&"vehicle/base_link"), "{statics:?}");
    assert!(statics.contains(&"scene/fixed"), "{statics:?}");
    let dynamic = strings(&got["/scene/dynamic"]["entities"]);
    assert!(dynamic.contains(&"scene/objects"), "{dynamic:?}");
    assert!(dynamic.contains(&"rotor/5/thrust"), "{dynamic:?}");
    // The twin's truth in amstack's JSON: the task it runs, six rotors, every joint.
    assert_eq!(got["/task/state"]["last"]["task"], "press-button");
    let rotors = &got["/rotors"]["last"];
    assert_eq!(
        rotors["realised_n"].as_array().unwrap().len(),
        6,
        "{rotors}"
    );
    let joints = &got["/joints"]["last"];
    let names = joints["names"].as_array().unwrap().len();
    assert!(names > 0, "{joints}");
    assert_eq!(joints["position"].as_array().unwrap().len(), names);
    assert_eq!(joints["target"].as_array().unwrap().len(), names);
    let z = got["/base/state"]["last"]["position_m"][2]
        .as_f64()
        .unwrap();
    assert!(z > 0.2, "flying, not on the floor: z = {z} m");

    // The twin reports what it published and dropped.
    let stats = twin.wait_for("messages published");
    assert!(stats.contains("dropped"), "{stats}");
}

#[test]
fn the_twins_mavlink_autopilot_streams_its_steps_live() {
    let dir = tempfile::tempdir().unwrap();
    let udp = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .unwrap()
        .port();
    let mavlink = format!("udp:127.0.0.1:{udp}");
    let addr = format!("127.0.0.1:{}", free_port());
    let common = [
        "--platform",
        "fa-hexa",
        "--disturbances",
        "saturation",
        "--seed",
        "3",
    ];
    let mut args = vec![
        "twin",
        "serve",
        "--mavlink",
        &mavlink,
        "--lockstep",
        "--live",
        &addr,
    ];
    args.extend(common);
    let mut autopilot = Proc::start("twin serve --mavlink --live", &args);
    autopilot.wait_for("live view: ws://");
    let ready = dir.path().join("subscribed");
    let mut viewer = ws_client(&[
        &format!("ws://{addr}"),
        "--topics",
        "/scene/tf,/scene/static,/scene/dynamic,/base/state,/rotors",
        "--messages",
        "100",
        "--need",
        "/scene/static=2",
        "--timeout",
        "120",
        "--ready-file",
        ready.to_str().unwrap(),
    ])
    .stdout(std::process::Stdio::piped())
    .spawn()
    .unwrap();
    wait_for_file(&ready, &mut viewer);
    let link = format!("mavlink:{mavlink}");
    let mut fly = vec![
        "fly",
        "--link",
        &link,
        "--trajectory",
        "step",
        "--duration",
        "4",
    ];
    fly.extend(common);
    let mut flight = Proc::start("fly --link mavlink", &fly);
    assert!(flight.wait().success(), "{}", flight.stderr());
    let viewed = viewer.wait_with_output().unwrap();
    let report: Value = serde_json::from_slice(&viewed.stdout).unwrap();
    assert!(viewed.status.success(), "{report}");
    autopilot.interrupt();
    assert!(autopilot.wait().success(), "{}", autopilot.stderr());
    let got = &report["received"];
    // One message set per autopilot step, a control period of the twin's time apart.
    for topic in ["/scene/tf", "/scene/dynamic", "/base/state", "/rotors"] {
        let entry = &got[topic];
        assert!(entry["count"].as_u64().unwrap() >= 100, "{topic}: {entry}");
        let step = entry["median_step_ns"].as_f64().unwrap();
        assert!((step - 1e9 / 120.0).abs() <= 1.0, "{topic}: {step} ns");
    }
    let statics = strings(&got["/scene/static"]["entities"]);
    assert!(statics.contains(&"vehicle/base_link"), "{statics:?}");
    // Armed and flying: the base above its resting height.
    let z = got["/base/state"]["last"]["position_m"][2]
        .as_f64()
        .unwrap();
    assert!(z > 0.5, "z = {z} m");
    let stats = autopilot.wait_for("messages published");
    assert!(stats.contains("dropped"), "{stats}");
}
