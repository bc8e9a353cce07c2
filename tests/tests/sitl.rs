//! Split-process SITL: `amstack twin serve` and `amstack fly --link ipc:…` as two real
//! processes over iceoryx2 shared memory, started, killed and cleaned up by the tests.
//!
//! The `amstack` binary is the one cargo builds for the root package's CLI test
//! (`cargo test --workspace`); alone, run `cargo build --bin amstack` first. The tests run one
//! at a time (each busy-polls two processes on a small machine) and every process and
//! shared-memory resource they start is removed when a test ends, passed or failed.

use std::path::Path;
use std::process::Command;
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use policy_runtime::record::Recording;
use tests::process::{Proc, amstack};

/// One test at a time.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A service name no other test run uses.
fn service(test: &str) -> String {
    format!("test-{}-{test}", std::process::id())
}

/// The processes of one test; on drop they are stopped and whatever a killed one left in
/// shared memory is removed.
struct Sitl {
    procs: Vec<Proc>,
    _serial: MutexGuard<'static, ()>,
}

impl Sitl {
    fn new() -> Self {
        Self {
            procs: Vec::new(),
            _serial: serial(),
        }
    }

    fn start(&mut self, name: &str, args: &[&str]) -> usize {
        self.procs.push(Proc::start(name, args));
        self.procs.len() - 1
    }

    fn twin(&mut self, service: &str, extra: &[&str]) -> usize {
        let mut args = vec!["twin", "serve", "--ipc", service];
        args.extend_from_slice(extra);
        let i = self.start("twin", &args);
        self.procs[i].wait_for("twin: serving");
        i
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        self.procs.clear();
        sim_twin::ipc::cleanup_dead_nodes_now();
    }
}

fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}: {text}", path.display()))
}

/// A results JSON without what differs between any two runs (wall clock, the log's path).
fn scores(path: &Path) -> serde_json::Value {
    let mut v = read_json(path);
    if let Some(o) = v.as_object_mut() {
        for k in ["wall_time_s", "ticks_per_second", "mcap"] {
            o.remove(k);
        }
    }
    v
}

fn recording(path: &Path) -> Recording {
    Recording::from_bytes(&std::fs::read(path).unwrap_or_default())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The 3D scene's channels drawn from what only the twin in this process can show (the floor,
/// walls and task objects: `Link::camera_scene`/`camera_state`): a link to another process
/// logs the vehicle, rotors and targets there, not the scene's bodies.
const LINK_DRAWN_SCENE: [&str; 2] = ["/scene/static", "/scene/dynamic"];

/// A log's messages without [`LINK_DRAWN_SCENE`] (the static scene, always written:
/// checked; the dynamic one holds nothing for a vehicle without rotors and a scene without
/// moving bodies).
fn flight_messages(r: &Recording) -> Vec<&policy_runtime::record::RecordedMessage> {
    assert!(
        r.messages.iter().any(|m| m.topic == LINK_DRAWN_SCENE[0]),
        "no {}",
        LINK_DRAWN_SCENE[0]
    );
    r.messages
        .iter()
        .filter(|m| !LINK_DRAWN_SCENE.contains(&m.topic.as_str()))
        .collect()
}

#[test]
fn lockstep_split_flight_equals_the_in_process_one() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    // Every disturbance and both noises on (the seed's streams must line up across the
    // wire), the L1 controller on the FA-Hexa; the EE-only oracle's direct wrench.
    let scenarios: [&[&str]; 2] = [
        &[
            "--platform",
            "fa-hexa",
            "--controller",
            "l1",
            "--trajectory",
            "step",
            "--duration",
            "3",
            "--disturbances",
            "all",
            "--seed",
            "7",
        ],
        &[
            "--platform",
            "ee-only",
            "--trajectory",
            "step",
            "--duration",
            "2",
            "--settle",
            "1",
        ],
    ];
    for (k, flags) in scenarios.iter().enumerate() {
        let path = |name: &str| dir.path().join(format!("{k}-{name}"));
        let mut sitl = Sitl::new();
        let svc = service(&format!("equal{k}"));
        // The twin takes the flags that describe it; the flight all of them.
        let twin_flags: Vec<&str> = flags
            .chunks(2)
            .filter(|p| ["--platform", "--disturbances", "--seed"].contains(&p[0]))
            .flatten()
            .copied()
            .collect();
        let mut twin_args = vec!["--sessions", "1"];
        twin_args.extend(&twin_flags);
        let twin = sitl.twin(&svc, &twin_args);

        let (json_a, mcap_a) = (path("in.json"), path("in.mcap"));
        let (json_b, mcap_b) = (path("ipc.json"), path("ipc.mcap"));
        let mut track = vec!["track", "--json", json_a.to_str().unwrap_or_default()];
        track.extend(["--mcap", mcap_a.to_str().unwrap_or_default()]);
        track.extend(flags.iter());
        let link = format!("ipc:{svc}");
        let mut fly = vec!["fly", "--link", &link, "--link-timeout-ms", "10000"];
        fly.extend(["--json", json_b.to_str().unwrap_or_default()]);
        fly.extend(["--mcap", mcap_b.to_str().unwrap_or_default()]);
        fly.extend(flags.iter());

        let in_process = sitl.start("track", &track);
        let split = sitl.start("fly", &fly);
        for i in [in_process, split] {
            let status = sitl.procs[i].wait();
            assert!(status.success(), "{}", sitl.procs[i].stderr());
        }
        sitl.procs[split].wait_for("lockstep session");
        assert!(
            sitl.procs[twin].wait().success(),
            "{}",
            sitl.procs[twin].stderr()
        );

        assert_eq!(scores(&json_a), scores(&json_b), "scenario {k}");
        let (a, b) = (recording(&mcap_a), recording(&mcap_b));
        assert!(a.complete && b.complete);
        let (a, b) = (flight_messages(&a), flight_messages(&b));
        assert_eq!(a.len(), b.len(), "scenario {k}");
        assert!(
            a.iter().zip(&b).all(|(x, y)| x == y),
            "scenario {k}: log payloads differ"
        );
    }
}

/// A bench results JSON without what differs between two runs of the same flags (the
/// `timing` section, the logs' paths).
fn bench_scores(path: &Path) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(o) => {
                o.remove("timing");
                o.remove("mcap");
                o.values_mut().for_each(strip);
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let mut v = read_json(path);
    strip(&mut v);
    v
}

#[test]
fn bench_over_ipc_equals_the_in_process_bench() {
    // Every rollout a session of one twin process that lets the flight choose the episode;
    // every disturbance and noise on, a held object thrown (Toss Ball) and a wall task.
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let mut sitl = Sitl::new();
    let svc = service("bench");
    let common = [
        "--platform",
        "fa-hexa",
        "--disturbances",
        "all",
        "--seed",
        "3",
    ];
    let mut twin_args = vec!["--flight-chooses-episode", "--sessions", "4"];
    twin_args.extend(common);
    let twin = sitl.twin(&svc, &twin_args);
    let out = |name: &str| dir.path().join(name);
    let bench = |out_dir: &Path, link: &str| -> Vec<String> {
        let mut args: Vec<String> = [
            "bench",
            "--task",
            "press-button,toss-ball",
            "--rollouts",
            "2",
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect();
        args.extend(common.iter().map(|s| (*s).to_owned()));
        args.extend(["--link".to_owned(), link.to_owned()]);
        args.extend(["--link-timeout-ms".to_owned(), "10000".to_owned()]);
        args.extend(["--out".to_owned(), out_dir.display().to_string()]);
        args
    };
    let in_args = bench(&out("in"), "twin");
    let ipc_args = bench(&out("ipc"), &format!("ipc:{svc}"));
    let in_args: Vec<&str> = in_args.iter().map(String::as_str).collect();
    let ipc_args: Vec<&str> = ipc_args.iter().map(String::as_str).collect();
    let in_process = sitl.start("bench-in", &in_args);
    let split = sitl.start("bench-ipc", &ipc_args);
    for i in [in_process, split] {
        let status = sitl.procs[i].wait();
        assert!(status.success(), "{}", sitl.procs[i].stderr());
    }
    assert!(
        sitl.procs[twin].wait().success(),
        "{}",
        sitl.procs[twin].stderr()
    );
    let (a, b) = (out("in/results.json"), out("ipc/results.json"));
    assert_eq!(read_json(&b)["timing"]["link"], format!("ipc:{svc}"));
    assert_eq!(bench_scores(&a), bench_scores(&b));
    // The logs agree message for message, the task's state included.
    for log in [
        "press-button/rollout-000.mcap",
        "toss-ball/rollout-001.mcap",
    ] {
        let (x, y) = (
            recording(&out("in/rollouts").join(log)),
            recording(&out("ipc/rollouts").join(log)),
        );
        assert!(x.complete && y.complete);
        assert!(
            x.message_counts()
                .get("/task/state")
                .is_some_and(|n| *n > 0)
        );
        assert_eq!(flight_messages(&x), flight_messages(&y), "{log}");
    }
}

#[test]
fn the_mpc_over_ipc_pushes_the_slider_as_in_process() {
    // The whole-body MPC reads the held joint and the hand's blocking contact from the task
    // scene (Push Slider: the palm on the knob's end, then the rail): both cross the wire, so
    // the split flight pushes the knob as the in-process one does. (Without them on the wire,
    // 0 of 3 over the link against 3 of 3 in-process: the plan stretched the arm into the
    // knob's end and pushed its own base back.)
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let mut sitl = Sitl::new();
    let svc = service("mpc");
    let twin = sitl.twin(
        &svc,
        &[
            "--flight-chooses-episode",
            "--sessions",
            "1",
            "--platform",
            "fa-hexa",
        ],
    );
    let json = |name: &str| dir.path().join(name);
    let bench = |file: &Path, link: &str| -> Vec<String> {
        [
            "bench",
            "--platform",
            "fa-hexa",
            "--controller",
            "mpc",
            "--task",
            "push-slider",
            "--rollouts",
            "1",
            "--link-timeout-ms",
            "10000",
            "--link",
            link,
            "--json",
            &file.display().to_string(),
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect()
    };
    let in_args = bench(&json("in.json"), "twin");
    let ipc_args = bench(&json("ipc.json"), &format!("ipc:{svc}"));
    let in_args: Vec<&str> = in_args.iter().map(String::as_str).collect();
    let ipc_args: Vec<&str> = ipc_args.iter().map(String::as_str).collect();
    let in_process = sitl.start("mpc-in", &in_args);
    let split = sitl.start("mpc-ipc", &ipc_args);
    for i in [in_process, split, twin] {
        let status = sitl.procs[i].wait();
        assert!(status.success(), "{}", sitl.procs[i].stderr());
    }
    let (a, b) = (json("in.json"), json("ipc.json"));
    assert_eq!(read_json(&b)["tasks"]["push-slider"]["success_rate"], 1.0);
    assert_eq!(bench_scores(&a), bench_scores(&b));
}

#[test]
fn killing_the_twin_stops_the_flight_with_a_finished_log() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let mcap = dir.path().join("cut.mcap");
    let mut sitl = Sitl::new();
    let svc = service("kill-twin");
    let twin = sitl.twin(&svc, &[]);
    let link = format!("ipc:{svc}");
    let fly = sitl.start(
        "fly",
        &[
            "fly",
            "--link",
            &link,
            "--trajectory",
            "hover",
            "--duration",
            "600",
            "--mcap",
            mcap.to_str().unwrap_or_default(),
        ],
    );
    sitl.procs[fly].wait_for("connected to the twin");
    std::thread::sleep(Duration::from_millis(300));
    sitl.procs[twin].kill();

    let status = sitl.procs[fly].wait();
    let stderr = sitl.procs[fly].stderr();
    assert_eq!(status.code(), Some(1), "{stderr}");
    // The default deadline is 50 ms; the dead node is noticed before it.
    let noticed = sitl.procs[fly].wait_for("stopped answering");
    assert!(
        noticed.contains("its process is gone") && noticed.contains("deadline 50 ms"),
        "{noticed}"
    );
    eprintln!("{noticed}");
    sitl.procs[fly].wait_for("closed the flight log");

    let log = recording(&mcap);
    assert!(log.complete, "the log was finished");
    assert!(!log.messages.is_empty());
    let (code, report) = tests::mcap_check(&mcap, &["--require-complete"]);
    assert_eq!(code, 0, "{report:#}");

    // The flight process cleaned up after the twin as it exited. A twin killed with nobody
    // attached leaves its resources; the next twin on the name removes them and serves.
    let crashed = sitl.twin(&svc, &[]);
    sitl.procs[crashed].kill();
    let again = sitl.twin(&svc, &["--sessions", "1"]);
    let started = sitl.procs[again].wait_for("twin: serving");
    assert!(started.contains("resources of 1 dead"), "{started}");
    let fly = sitl.start(
        "fly",
        &["fly", "--link", &link, "--duration", "1", "--settle", "0"],
    );
    assert!(
        sitl.procs[fly].wait().success(),
        "{}",
        sitl.procs[fly].stderr()
    );
    assert!(sitl.procs[again].wait().success());
}

#[test]
fn a_killed_flight_gets_the_failsafe_and_a_new_flight_reconnects() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let json = dir.path().join("second.json");
    let mut sitl = Sitl::new();
    let svc = service("kill-flight");
    let twin = sitl.twin(&svc, &["--hold-ms", "200", "--sessions", "2"]);
    let link = format!("ipc:{svc}");
    let first = sitl.start(
        "first flight",
        &[
            "fly",
            "--link",
            &link,
            "--link-timeout-ms",
            "10000",
            "--duration",
            "600",
        ],
    );
    sitl.procs[first].wait_for("connected to the twin");
    std::thread::sleep(Duration::from_millis(300));
    sitl.procs[first].kill();

    let t = &mut sitl.procs[twin];
    let lost = t.wait_for("lost at");
    assert!(
        lost.contains("its process is gone")
            && lost.contains("holding its last command for 200 ms"),
        "{lost}"
    );
    t.wait_for("failsafe disarm");
    // Disarmed, the FA-Hexa falls from its 1 m hover and rests on the ground.
    let settled = t.wait_for("after the failsafe");
    let z: f64 = settled
        .split("base z = ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no height in {settled:?}"));
    assert!(z < 0.3, "{settled}");

    let second = sitl.start(
        "second flight",
        &[
            "fly",
            "--link",
            &link,
            "--link-timeout-ms",
            "10000",
            "--duration",
            "3",
            "--json",
            json.to_str().unwrap_or_default(),
        ],
    );
    let status = sitl.procs[second].wait();
    assert!(status.success(), "{}", sitl.procs[second].stderr());
    // It flew from the twin's reset state: a hover within a centimetre.
    let r = read_json(&json);
    assert!(
        r["ee_pos_rmse_m"].as_f64().is_some_and(|e| e < 0.01),
        "{r:#}"
    );
    let t = &mut sitl.procs[twin];
    t.wait_for("ended by the flight process");
    assert!(t.wait().success(), "{}", t.stderr());
}

#[test]
fn a_mismatched_vehicle_is_refused_naming_both() {
    let mut sitl = Sitl::new();
    let svc = service("mismatch");
    let twin = sitl.twin(&svc, &["--platform", "fa-hexa"]);
    let link = format!("ipc:{svc}");
    let fly = sitl.start("fly", &["fly", "--link", &link, "--platform", "ua-quad"]);
    let status = sitl.procs[fly].wait();
    let stderr = sitl.procs[fly].stderr();
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "one line: {stderr}");
    assert!(
        stderr.contains("flies 'ua-quad'") && stderr.contains("serves 'fa-hexa'"),
        "{stderr}"
    );
    let refused = sitl.procs[twin].wait_for("refused flight process");
    assert!(
        refused.contains("'ua-quad'") && refused.contains("'fa-hexa'"),
        "{refused}"
    );
}

#[test]
fn realtime_twin_flies_on_the_wall_clock() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let json = dir.path().join("rt.json");
    let mut sitl = Sitl::new();
    let svc = service("realtime");
    let twin = sitl.twin(&svc, &["--realtime", "--sessions", "1"]);
    let link = format!("ipc:{svc}");
    let fly = sitl.start(
        "fly",
        &[
            "fly",
            "--link",
            &link,
            "--link-timeout-ms",
            "10000",
            "--duration",
            "1.5",
            "--settle",
            "0.5",
            "--json",
            json.to_str().unwrap_or_default(),
        ],
    );
    let status = sitl.procs[fly].wait();
    assert!(status.success(), "{}", sitl.procs[fly].stderr());
    sitl.procs[fly].wait_for("realtime session");
    let r = read_json(&json);
    // 120 Hz on the wall clock: about 120 ticks per second, and a hover that holds.
    let rate = r["ticks_per_second"].as_f64().unwrap_or_default();
    assert!(rate < 200.0, "{r:#}");
    assert!(
        r["ee_pos_rmse_m"].as_f64().is_some_and(|e| e < 0.02),
        "{r:#}"
    );
    assert!(sitl.procs[twin].wait().success());
}

#[test]
fn bad_link_and_serve_flags_are_bad_input() {
    for args in [
        &["fly", "--link", "udp:1234"][..],
        &["fly", "--link", "ipc:"][..],
        &["twin", "serve", "--ipc", "x", "--platform", "no-such"][..],
        &["twin", "serve", "--ipc", "x", "--lockstep", "--realtime"][..],
    ] {
        let out = Command::new(amstack())
            .args(args)
            .output()
            .unwrap_or_else(|e| panic!("{e}"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
    }
}

#[test]
fn a_command_the_twin_refuses_ends_the_session_and_the_twin_serves_on() {
    use policy_runtime::{IpcLink, IpcLinkConfig, Link, LinkError, Setpoint};
    let mut sitl = Sitl::new();
    let svc = service("refused-command");
    let twin = sitl.twin(&svc, &["--sessions", "2"]);
    let vehicle = platform::Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
    let config = sim_twin::TwinConfig::default();
    let connect = || {
        let link = IpcLinkConfig {
            answer_timeout: Duration::from_secs(10),
            ..IpcLinkConfig::new(svc.clone())
        };
        IpcLink::connect(&vehicle, &config, link).unwrap_or_else(|e| panic!("{e}"))
    };
    let mut link = connect();
    let start = link.receive().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(start.time_s, 0.0);
    // A non-finite thrust: the twin refuses to step, says so and ends the session.
    let bad = platform::ActuatorCommand {
        rotor_thrusts_n: vec![f64::NAN; vehicle.rotors.len()],
        joint_targets: vehicle.initial_configuration(),
        direct_wrench_in_body: None,
    };
    link.send(&Setpoint::Actuators(bad.clone()))
        .unwrap_or_else(|e| panic!("{e}"));
    let refused = link.receive();
    assert!(
        matches!(
            refused,
            // The twin process failed to step (IpcLinkError::TwinFailed): categorised as a
            // simulation that diverged.
            Err(LinkError::Diverged(ref why)) if why.contains("failed at t =")
        ),
        "{refused:?}"
    );
    sitl.procs[twin].wait_for("the twin failed");
    drop(link);
    // The twin serves on: a new session steps from the reset state.
    let mut link = connect();
    let idle = platform::ActuatorCommand {
        rotor_thrusts_n: vec![0.0; vehicle.rotors.len()],
        ..bad
    };
    link.send(&Setpoint::Actuators(idle))
        .unwrap_or_else(|e| panic!("{e}"));
    let after = link.receive().unwrap_or_else(|e| panic!("{e}"));
    assert!(
        (after.time_s - config.control_dt_s()).abs() < 1e-12,
        "{}",
        after.time_s
    );
    drop(link);
    assert!(
        sitl.procs[twin].wait().success(),
        "{}",
        sitl.procs[twin].stderr()
    );
}
