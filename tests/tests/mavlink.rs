//! The twin's PX4-style autopilot (`amstack twin serve --mavlink udp:…`) against a MAVLink
//! implementation that is not ours: pymavlink (scripts/mavlink_gcs.py, in the venv of
//! scripts/setup-python.sh) as a ground station, an offboard sender and a source of garbage.
//!
//! The `amstack` binary is the one cargo builds for the root package's CLI test
//! (`cargo test --workspace`); alone, run `cargo build --bin amstack` first. The first run
//! installs pymavlink from PyPI into the shared venv.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::{Mutex, MutexGuard};

use platform::{GRAVITY_MPS2, Vehicle};
use serde_json::Value;
use tests::process::{Proc, amstack};

/// One test at a time (each runs a twin and a Python peer on a small machine).
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `amstack twin serve --mavlink udp:127.0.0.1:0 …`: the process, and the port and resting
/// height it announced.
struct Autopilot {
    proc: Proc,
    port: u16,
    rest_z_m: f64,
}

impl Autopilot {
    fn start(args: &[&str]) -> Self {
        // The actuator-level peer flies SET_ACTUATOR_CONTROL_TARGET: a SITL extension of the
        // twin (current PX4 has no actuator offboard), off unless asked for.
        let mut all = vec![
            "twin",
            "serve",
            "--mavlink",
            "udp:127.0.0.1:0",
            "--allow-actuator-setpoints",
        ];
        all.extend_from_slice(args);
        let mut proc = Proc::start("twin serve --mavlink", &all);
        // "… on udp:127.0.0.1:PORT (lockstep, …); resting height 0.025 m"
        let ready = proc.wait_for("serving");
        let port = ready
            .split("udp:127.0.0.1:")
            .nth(1)
            .and_then(|s| s.split(' ').next())
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("no port in {ready:?}"));
        let rest_z_m = ready
            .split("resting height ")
            .nth(1)
            .and_then(|s| s.trim_end_matches(" m").parse().ok())
            .unwrap_or_else(|| panic!("no resting height in {ready:?}"));
        Self {
            proc,
            port,
            rest_z_m,
        }
    }

    fn stderr(&self) -> String {
        self.proc.stderr()
    }

    fn wait_for(&mut self, needle: &str) -> String {
        self.proc.wait_for(needle)
    }

    /// Runs the pymavlink peer in `mode`; its JSON.
    fn peer(&self, mode: &str, args: &[&str]) -> Value {
        let connect = format!("udpout:127.0.0.1:{}", self.port);
        let out = Command::new(tests::python())
            .arg(tests::scripts_dir().join("mavlink_gcs.py"))
            .args([mode, "--connect", &connect])
            .args(args)
            .stderr(Stdio::inherit())
            .output()
            .unwrap_or_else(|e| panic!("mavlink_gcs.py: {e}"));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "mavlink_gcs.py {mode} failed: {text}");
        serde_json::from_str(text.trim())
            .unwrap_or_else(|e| panic!("{e}: {text}\nautopilot:\n{}", self.stderr()))
    }

    /// Ctrl-C, then the exit line with the link's counters.
    fn stop(&mut self) -> String {
        self.proc.interrupt();
        self.wait_for("stopped after")
    }
}

/// A counter's value in the exit line ("…, bad crc 50, …").
fn counter(line: &str, name: &str) -> u64 {
    line.split(&format!("{name} "))
        .nth(1)
        .and_then(|s| s.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no counter {name:?} in {line:?}"))
}

fn rate(report: &Value, message: &str) -> f64 {
    report["rates_hz"][message]
        .as_f64()
        .unwrap_or_else(|| panic!("no rate for {message}: {report}"))
}

#[test]
fn a_pymavlink_ground_station_sees_the_vehicle_at_its_rates_and_arms_it() {
    let _one = serial();
    let ap = Autopilot::start(&["--platform", "fa-hexa"]);
    let r = ap.peer("rates", &["--seconds", "4"]);
    // HEARTBEAT: MAV_TYPE_HEXAROTOR (13), MAV_AUTOPILOT_PX4 (12), custom mode enabled,
    // disarmed, POSCTL (3 << 16), STANDBY (3), MAVLink 2.
    let hb = &r["heartbeat"];
    assert_eq!(hb["type"], 13, "{r}");
    assert_eq!(hb["autopilot"], 12, "{r}");
    assert_eq!(hb["base_mode"], 1, "{r}");
    assert_eq!(hb["custom_mode"], 3 << 16, "{r}");
    assert_eq!(hb["system_status"], 3, "{r}");
    assert_eq!(hb["mavlink_version"], true, "{r}");
    // The configured rates, within 10 % (the twin stands still: per-step messages at 10 Hz).
    for (message, hz) in [
        ("HEARTBEAT", 1.0),
        ("SYS_STATUS", 1.0),
        ("EXTENDED_SYS_STATE", 1.0),
        ("ATTITUDE", 50.0),
        ("GLOBAL_POSITION_INT", 10.0),
        ("ODOMETRY", 10.0),
        ("HIGHRES_IMU", 10.0),
        ("ACTUATOR_OUTPUT_STATUS", 10.0),
        ("DEBUG_FLOAT_ARRAY", 10.0),
        ("ATTITUDE_QUATERNION", 10.0),
        ("LOCAL_POSITION_NED", 10.0),
    ] {
        let got = rate(&r, message);
        assert!(
            (got - hz).abs() <= 0.1 * hz,
            "{message}: {got:.2} Hz, configured {hz} Hz\n{r}"
        );
    }
    assert_eq!(r["request_autopilot_version"], "ACCEPTED", "{r}");
    assert_eq!(r["autopilot_version_received"], true, "{r}");
    // Started with --allow-actuator-setpoints: the capabilities declare the extension (bit
    // 1024, MAVLink's former SET_ACTUATOR_TARGET), besides COMMAND_INT (8), PARAM_ENCODE_
    // BYTEWISE (16), MISSION_INT (4), SET_ATTITUDE_TARGET (64), SET_POSITION_TARGET_LOCAL_NED
    // (128) and MAVLINK2 (8192): 4 + 8 + 16 + 64 + 128 + 1024 + 8192 = 9436.
    assert_eq!(r["capabilities"], 9436, "{r}");
    assert_eq!(r["request_home_position"], "ACCEPTED", "{r}");
    assert_eq!(r["home"]["lat"], 473_977_420, "{r}");
    assert_eq!(r["home"]["lon"], 85_455_940, "{r}");
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    assert_eq!(r["armed_flag_after_arm"], true, "{r}");
    // Armed in POSCTL the autopilot holds the vehicle 1 m up: a plain disarm is refused with
    // the reason (PX4), a forced one (param2 21196) is accepted.
    assert_eq!(r["disarm"], "DENIED", "{r}");
    assert!(r["disarm_texts"].to_string().contains("in the air"), "{r}");
    assert_eq!(r["force_disarm"], "ACCEPTED", "{r}");
    assert_eq!(r["unsupported_command"], "UNSUPPORTED", "{r}");
}

#[test]
fn offboard_loss_holds_then_lands_then_disarms_without_a_crash() {
    let _one = serial();
    // With the paper's disturbances (drag, wind, ground and wall effects, rotor limits).
    let mut ap = Autopilot::start(&[
        "--platform",
        "fa-hexa",
        "--failsafe-hold-s",
        "2",
        "--disturbances",
        "reference",
    ]);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
    let mass = vehicle
        .mass_properties(&vehicle.initial_configuration())
        .mass_kg;
    let hover = mass * GRAVITY_MPS2 / (vehicle.rotors.len() as f64 * vehicle.rotors.thrust_max_n);
    let r = ap.peer(
        "failsafe",
        &[
            "--hover-thrust",
            &hover.to_string(),
            "--hover-s",
            "1.5",
            "--climb-mps",
            "0.3",
            "--watch-s",
            "20",
        ],
    );
    assert_eq!(r["heartbeat_interval"], "ACCEPTED", "{r}");
    // Offboard needs a setpoint stream; arming in offboard too, refused with the reason.
    assert_eq!(
        r["offboard_without_setpoints"], "TEMPORARILY_REJECTED",
        "{r}"
    );
    assert_eq!(r["offboard_with_setpoints"], "ACCEPTED", "{r}");
    assert_eq!(r["arm_without_setpoints"], "DENIED", "{r}");
    assert!(
        r["arm_refusal_texts"].to_string().contains("no setpoints"),
        "{r}"
    );
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    // Lockstep: 1.5 s of setpoints is 180 ticks, 1.5 s of twin time; the vehicle was
    // climbing (NED vz < 0) when they stopped.
    assert!(
        (r["stopped_at"]["t_s"].as_f64().unwrap_or(0.0) - 1.5).abs() < 1e-6,
        "{r}"
    );
    assert!(r["stopped_at"]["vz"].as_f64().unwrap_or(0.0) < -0.2, "{r}");
    // OFFBOARD armed → AUTO.LOITER (CRITICAL) → AUTO.LAND (CRITICAL) → disarmed.
    let modes: Vec<(u64, u64, bool)> = r["modes"]
        .as_array()
        .unwrap_or_else(|| panic!("{r}"))
        .iter()
        .map(|m| {
            (
                m["main"].as_u64().unwrap_or(0),
                m["sub"].as_u64().unwrap_or(0),
                m["armed"].as_bool().unwrap_or(true),
            )
        })
        .collect();
    assert_eq!(
        modes,
        vec![(6, 0, true), (4, 3, true), (4, 6, true), (3, 0, false)],
        "{r}"
    );
    // The hold stops the climb within 3 cm of where the setpoints stopped; nothing tilts
    // more than 5°; the vehicle ends at its resting height, still.
    let hold = r["hold_max_deviation_m"].as_f64().unwrap_or(f64::NAN);
    assert!(hold < 0.03, "hold deviation {hold} m\n{r}");
    let tilt = r["max_tilt_deg"].as_f64().unwrap_or(f64::NAN);
    assert!(tilt < 5.0, "tilt {tilt}°\n{r}");
    let z = -r["final"]["z_ned"].as_f64().unwrap_or(f64::NAN);
    assert!(
        (z - ap.rest_z_m).abs() < 0.02,
        "final z {z} m, rest {} m\n{r}",
        ap.rest_z_m
    );
    assert!(
        r["final"]["speed"].as_f64().unwrap_or(f64::NAN) < 0.05,
        "{r}"
    );
    // The hold lasts 2 s of twin time, then a ≈ 1.2 m descent at 0.5 m/s (≈ 2.4 s) and the
    // landed detection (0.5 s): the disarm comes 4–6.5 s after the setpoints stopped.
    let stopped = r["stopped_at"]["t_s"].as_f64().unwrap_or(f64::NAN);
    let disarmed = r["disarmed_at_s"].as_f64().unwrap_or(f64::NAN);
    assert!(
        (4.0..6.5).contains(&(disarmed - stopped)),
        "disarmed {disarmed} s after stopping at {stopped} s\n{r}"
    );
    // Each transition is logged with the twin time.
    for needle in [
        "mode AUTO.LOITER (failsafe: offboard setpoints lost, holding)",
        "mode AUTO.LAND (failsafe: hold over, landing)",
        "disarmed (landed)",
    ] {
        let line = ap.wait_for(needle);
        assert!(line.contains("t = "), "{line}");
    }
    ap.stop();
}

#[test]
fn garbage_is_counted_and_the_link_keeps_working() {
    let _one = serial();
    let mut ap = Autopilot::start(&["--platform", "ua-quad"]);
    let r = ap.peer("robust", &["--rounds", "50", "--seed", "7"]);
    // After 50 rounds of random bytes, truncated frames, bad CRCs and unknown ids the ground
    // station still gets its ACKs.
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    assert_eq!(r["force_disarm"], "ACCEPTED", "{r}");
    let s = &r["sys_status"];
    let at_least = |field: &str, n: u64| {
        let v = s[field].as_u64().unwrap_or(0);
        assert!(v >= n, "{field} = {v} < {n}\n{r}");
    };
    // errors_count1–3: bad CRC, unknown id, truncated (random bytes may add to each).
    at_least("errors_count1", 50);
    at_least("errors_count2", 50);
    at_least("errors_count3", 50);
    at_least("errors_comm", 150);
    at_least("drop_rate_comm", 1);
    let exit = ap.stop();
    assert!(counter(&exit, "bad crc") >= 50, "{exit}");
    assert!(counter(&exit, "unknown id") >= 50, "{exit}");
    assert!(counter(&exit, "truncated") >= 50, "{exit}");
    assert!(counter(&exit, "junk bytes") > 0, "{exit}");
    // Arm, force disarm, heartbeats and SYS_STATUS polls decoded fine.
    assert!(counter(&exit, "frames ok") >= 3, "{exit}");
    assert!(!ap.stderr().contains("panicked"), "{}", ap.stderr());
}

#[test]
fn with_signing_required_unsigned_and_forged_frames_are_refused() {
    let _one = serial();
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let key_hex = "0123456789abcdef".repeat(4);
    let key = dir.path().join("key.hex");
    std::fs::write(&key, format!("{key_hex}\n")).unwrap_or_else(|e| panic!("{e}"));
    let key_arg = key.display().to_string();
    let mut ap = Autopilot::start(&[
        "--platform",
        "fa-hexa",
        "--signing-key",
        &key_arg,
        "--require-signing",
    ]);
    let r = ap.peer("signing", &["--key-hex", &key_hex]);
    // No ACK for the unsigned or forged command; the signed one is accepted, and what the
    // autopilot sends is signed.
    assert_eq!(r["unsigned"], Value::Null, "{r}");
    assert_eq!(r["unsigned_heard_heartbeat"], false, "{r}");
    assert_eq!(r["forged"], Value::Null, "{r}");
    assert_eq!(r["signed"], "ACCEPTED", "{r}");
    assert_eq!(r["heartbeat_signed"], true, "{r}");
    let exit = ap.stop();
    assert!(counter(&exit, "unsigned refused") >= 2, "{exit}");
    assert!(counter(&exit, "bad signature") >= 2, "{exit}");
}

#[test]
fn the_serial_path_carries_the_link_over_a_pseudo_terminal() {
    let _one = serial();
    // pymavlink's parser on the pty's master end; the autopilot opens the slave's path.
    let mut peer = Command::new(tests::python())
        .arg(tests::scripts_dir().join("mavlink_gcs.py"))
        .args(["serial", "--seconds", "2", "--watch-s", "30"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("mavlink_gcs.py serial: {e}"));
    let stderr = peer.stderr.take().unwrap_or_else(|| panic!("no stderr"));
    let mut lines = BufReader::new(stderr).lines();
    let path = lines
        .by_ref()
        .map_while(Result::ok)
        .find_map(|l| l.strip_prefix("pty ").map(str::to_owned))
        .unwrap_or_else(|| panic!("the peer printed no pty path"));
    let device = format!("serial:{path}:115200");
    let mut child = Command::new(amstack())
        .args([
            "twin",
            "serve",
            "--mavlink",
            &device,
            "--platform",
            "fa-hexa",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start the autopilot: {e}"));
    let out = peer
        .wait_with_output()
        .unwrap_or_else(|e| panic!("mavlink_gcs.py serial: {e}"));
    let _ = child.kill();
    let _ = child.wait();
    let text = String::from_utf8_lossy(&out.stdout);
    let r: Value = serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"));
    assert_eq!(r["heartbeat"]["type"], 13, "{r}");
    assert_eq!(r["heartbeat"]["autopilot"], 12, "{r}");
    // 2 s of the standing twin's per-step telemetry at 10 Hz.
    let odometry = r["counts"]["ODOMETRY"].as_u64().unwrap_or(0);
    assert!((18..=22).contains(&odometry), "{r}");
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    assert_eq!(r["force_disarm"], "ACCEPTED", "{r}");
}

#[test]
fn lockstep_actuator_setpoints_step_the_twin_once_per_tick() {
    let _one = serial();
    let mut ap = Autopilot::start(&["--platform", "fa-hexa"]);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
    let u = 0.55;
    let arm_joints = vehicle.arm_joints.len().to_string();
    let r = ap.peer(
        "actuator",
        &[
            "--rotors",
            "6",
            "--arm-joints",
            &arm_joints,
            "--motor-u",
            &u.to_string(),
            "--joint-control",
            "0.5",
            "--ticks",
            "60",
        ],
    );
    // Disarmed, setpoints only refresh the stream: the twin stands still at t = 0.
    assert_eq!(r["disarmed_time_usec"], serde_json::json!([0, 0]), "{r}");
    assert_eq!(r["offboard"], "ACCEPTED", "{r}");
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    // Tick k (group 2 then group 0) answers with ODOMETRY at exactly k control periods.
    let times: Vec<u64> = r["times_usec"]
        .as_array()
        .unwrap_or_else(|| panic!("{r}"))
        .iter()
        .filter_map(Value::as_u64)
        .collect();
    let expected: Vec<u64> = (1..=60u64)
        .map(|k| (k as f64 * 1e6 / 120.0).round() as u64)
        .collect();
    assert_eq!(times, expected, "{r}");
    // Every rotor realises the thrust curve's thrust for u (ideal rotors: no dynamics).
    let thrust = vehicle.rotors.thrust_curve.thrust_n(u);
    let thrusts = r["thrusts_n"].as_array().unwrap_or_else(|| panic!("{r}"));
    assert_eq!(thrusts.len(), 6, "{r}");
    for t in thrusts {
        let t = t.as_f64().unwrap_or(f64::NAN);
        assert!(
            (t - thrust).abs() < 1e-4 * thrust,
            "{t} N vs {thrust} N\n{r}"
        );
    }
    // Group 2: arm joint 0 at control 0.5 → 3/4 of its range; the gripper open.
    let joints = r["joints"].as_array().unwrap_or_else(|| panic!("{r}"));
    let j0 = &vehicle.model.joints[vehicle.arm_joints[0]];
    let limits = j0
        .limits
        .unwrap_or_else(|| panic!("arm joint 0 has limits"));
    let target = limits.lower + 0.75 * (limits.upper - limits.lower);
    let dof = j0.dof.unwrap_or_else(|| panic!("movable"));
    let q0 = joints[dof].as_f64().unwrap_or(f64::NAN);
    assert!(
        (q0 - target).abs() < 0.1,
        "joint 0 at {q0} rad, target {target} rad\n{r}"
    );
    let gripper = vehicle
        .gripper
        .as_ref()
        .unwrap_or_else(|| panic!("a gripper"));
    for (k, &j) in gripper.joints.iter().enumerate() {
        let d = vehicle.model.joints[j]
            .dof
            .unwrap_or_else(|| panic!("movable"));
        let q = joints[d].as_f64().unwrap_or(f64::NAN);
        assert!((q - gripper.open[k]).abs() < 0.01, "finger {k} at {q}\n{r}");
    }
    assert_eq!(r["force_disarm"], "ACCEPTED", "{r}");
    ap.stop();
}

/// The flight stack's side: `amstack fly --link mavlink:udp:...` (the flight stack through
/// `firmware_bridge`) against `amstack twin serve --mavlink udp:... --lockstep`, both real
/// processes over UDP loopback, started and stopped by the tests.
mod bridge {
    use std::io::{BufRead, BufReader};
    use std::path::Path;
    use std::process::{Command, ExitStatus, Stdio};

    use super::{Proc, serial};

    fn read_json(path: &Path) -> serde_json::Value {
        let text = std::fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    }

    fn number(v: &serde_json::Value, key: &str) -> f64 {
        v[key]
            .as_f64()
            .unwrap_or_else(|| panic!("no number {key} in {v}"))
    }

    /// `amstack fly --link <link>` with `flags`; the exit status, the JSON result and
    /// stderr.
    fn fly_over(
        link: &str,
        flags: &[&str],
        json: &Path,
    ) -> (ExitStatus, Option<serde_json::Value>, String) {
        let json_arg = json.to_string_lossy().into_owned();
        let mut args = vec![
            "fly",
            "--link",
            link,
            "--connect-timeout-ms",
            "30000",
            "--json",
            &json_arg,
        ];
        args.extend_from_slice(flags);
        let mut p = Proc::start("fly", &args);
        let status = p.wait();
        let result = json.is_file().then(|| read_json(json));
        (status, result, p.stderr())
    }

    /// A flight that must succeed: `fly --link <link>` with [`FLIGHT`] and `flags`; its JSON
    /// result (written to `dir/<name>.json`) and stderr.
    fn flown(link: &str, flags: &[&str], dir: &Path, name: &str) -> (serde_json::Value, String) {
        let mut all = FLIGHT.to_vec();
        all.extend_from_slice(flags);
        let (status, result, stderr) = fly_over(link, &all, &dir.join(format!("{name}.json")));
        assert!(status.success(), "fly {name} over {link} failed:\n{stderr}");
        let result = result.unwrap_or_else(|| panic!("fly {name} wrote no result:\n{stderr}"));
        (result, stderr)
    }

    /// The flight in this process (`fly --link twin`, as `amstack track`): the reference.
    fn in_process(flags: &[&str], dir: &Path) -> serde_json::Value {
        flown("twin", flags, dir, "in-process").0
    }

    /// A flight against the twin's autopilot, started here (`mode`: `--lockstep` or
    /// `--realtime`) with [`FLIGHT`] and `twin_flags`, over UDP; stopped after the flight.
    fn against_autopilot(
        mode: &str,
        twin_flags: &[&str],
        flags: &[&str],
        dir: &Path,
        name: &str,
    ) -> (serde_json::Value, String) {
        let port = std::net::UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .map(|a| a.port())
            .unwrap_or_else(|e| panic!("no free port: {e}"));
        let address = format!("udp:127.0.0.1:{port}");
        let mut args = vec!["twin", "serve", "--mavlink", &address, mode];
        // Only the actuator level needs the twin's SITL extension (SET_ACTUATOR_CONTROL_TARGET);
        // the attitude level (the default) and the position level fly what a PX4 accepts.
        if flags.windows(2).any(|w| w == ["--level", "actuator"]) {
            args.push("--allow-actuator-setpoints");
        }
        args.extend_from_slice(FLIGHT);
        args.extend_from_slice(twin_flags);
        let _autopilot = Proc::start("twin serve --mavlink", &args);
        flown(&format!("mavlink:{address}"), flags, dir, name)
    }

    const FLIGHT: &[&str] = &[
        "--platform",
        "fa-hexa",
        "--disturbances",
        "saturation",
        "--seed",
        "3",
    ];

    #[test]
    fn a_step_at_actuator_level_over_udp_matches_the_in_process_flight() {
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let step = ["--trajectory", "step", "--duration", "4"];
        let mut flags = step.to_vec();
        flags.extend_from_slice(&["--level", "actuator"]);
        let (scores, _) = against_autopilot("--lockstep", &[], &flags, dir.path(), "mavlink");
        let reference = in_process(&step, dir.path());
        // Lockstep from the same reset state, f32 on the wire: the same flight within 0.1 mm of
        // RMS error (the fixture of policy_runtime's MavlinkLink tests measured 6e-9 m).
        for key in ["ee_pos_rmse_m", "base_pos_rmse_m", "base_z_rmse_m"] {
            let (a, b) = (number(&scores, key), number(&reference, key));
            assert!(
                (a - b).abs() < 1e-4,
                "{key}: {a} over MAVLink vs {b} in process"
            );
        }
        assert_eq!(scores["ticks"], reference["ticks"]);
    }

    /// Lower-case hex → bytes.
    fn from_hex(text: &str) -> Vec<u8> {
        (0..text.len())
            .step_by(2)
            .map(|i| {
                u8::from_str_radix(&text[i..i + 2], 16)
                    .unwrap_or_else(|e| panic!("bad hex {text:?}: {e}"))
            })
            .collect()
    }

    /// A message of the log: topic, log time (ns), JSON payload.
    type Logged = (String, u64, serde_json::Value);

    /// Every message of `path`'s JSON channels (not the 3D scene's protobuf ones), read with
    /// the `mcap` crate (not amstack's reader); the schema names of the MAVLink channels are
    /// checked on the way.
    fn read_mcap(path: &Path) -> Vec<Logged> {
        let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let stream = mcap::MessageStream::new(&bytes).unwrap_or_else(|e| panic!("{e}"));
        stream
            .map(|m| m.unwrap_or_else(|e| panic!("{}: {e}", path.display())))
            .filter(|m| m.channel.message_encoding == "json")
            .map(|m| {
                let topic = m.channel.topic.clone();
                let schema = m.channel.schema.as_ref().map(|s| s.name.clone());
                match topic.as_str() {
                    "/autopilot/state" => {
                        assert_eq!(schema.as_deref(), Some("amstack.AutopilotState"));
                    }
                    "/mavlink/raw" => assert_eq!(schema.as_deref(), Some("amstack.MavlinkRaw")),
                    _ => {}
                }
                let value = serde_json::from_slice(&m.data)
                    .unwrap_or_else(|e| panic!("{topic} is not JSON: {e}"));
                (topic, m.log_time, value)
            })
            .collect()
    }

    /// What a bridge flight of `ticks` ticks logs of the autopilot and the wire.
    fn check_the_mavlink_channels(log: &Path, ticks: u64) {
        use mavlink::dialects::common::MavMessage;
        let messages = read_mcap(log);
        let on = |topic: &str| -> Vec<&Logged> {
            messages.iter().filter(|(t, _, _)| t == topic).collect()
        };
        // /autopilot/state: one per measurement (the start, then each tick), at its time.
        let states = on("/autopilot/state");
        assert_eq!(states.len() as u64, ticks + 1);
        let (_, t0, first) = states[0];
        assert_eq!(
            (*t0, &first["armed"]),
            (0, &serde_json::json!(false)),
            "{first}"
        );
        // Armed in OFFBOARD over the whole flight (the start sequence runs before tick 0's
        // setpoint: every later measurement sees it).
        for (_, t, s) in &states[1..] {
            assert!(*t > 0, "{s}");
            assert_eq!(s["armed"], true, "at {t} ns: {s}");
            assert_eq!(s["mode"], "OFFBOARD", "at {t} ns: {s}");
            assert_eq!(s["main_mode"], 6, "at {t} ns: {s}");
            assert_eq!(s["system_status"], "MAV_STATE_ACTIVE", "at {t} ns: {s}");
        }
        let (_, _, last) = states[states.len() - 1];
        let link = &last["link"];
        for clean in [
            "bad_crc",
            "unknown_id",
            "truncated",
            "undecodable",
            "raw_frames_dropped",
        ] {
            assert_eq!(link[clean], 0, "{clean}: {last}");
        }
        assert!(last["heartbeats"].as_u64().unwrap_or(0) >= 1, "{last}");

        // /mavlink/raw: every frame, decoded by the mavlink crate's parser.
        let raw = on("/mavlink/raw");
        let captured = link["raw_frames_captured"].as_u64().unwrap_or(0);
        assert!(raw.len() as u64 >= captured && captured > 0, "{last}");
        let base_states: std::collections::BTreeMap<u64, &serde_json::Value> = on("/base/state")
            .into_iter()
            .map(|(_, t, v)| (*t, v))
            .collect();
        let mut odometry_in = 0u64;
        let mut odometry_times = std::collections::BTreeSet::new();
        let mut checked = 0u64;
        let (mut group0_out, mut group2_out) = (0u64, 0u64);
        for (_, t, r) in &raw {
            let frame = from_hex(r["bytes_hex"].as_str().unwrap_or_default());
            let (header, message) = mavlink::MavlinkReader::new(&frame[..])
                .read_message::<MavMessage>(mavlink::MavlinkVersion::V2)
                .unwrap_or_else(|e| panic!("{r}: the mavlink crate cannot parse it: {e:?}"));
            assert_eq!(
                r["message_id"],
                mavlink::Message::message_id(&message),
                "{r}"
            );
            assert_eq!(r["sequence"], header.sequence, "{r}");
            let flight_time = r["flight_time_s"].as_f64().unwrap_or(f64::NAN);
            assert_eq!(*t, (flight_time * 1e9).round() as u64, "{r}");
            match (r["direction"].as_str(), &message) {
                (Some("in"), MavMessage::ODOMETRY(o)) => {
                    assert_eq!((header.system_id, header.component_id), (1, 1), "{r}");
                    odometry_in += 1;
                    if o.time_usec > 0 {
                        odometry_times.insert(o.time_usec);
                    }
                    // The measurement logged at the frame's time is the frame's: NED → world
                    // of its f32 position, exactly.
                    if let Some(state) = base_states.get(t) {
                        let logged = &state["position_m"];
                        let expected = [f64::from(o.y), f64::from(o.x), -f64::from(o.z)];
                        for (i, e) in expected.iter().enumerate() {
                            assert_eq!(logged[i].as_f64(), Some(*e), "at {t} ns: {r}");
                        }
                        checked += 1;
                    }
                }
                (Some("out"), MavMessage::SET_ACTUATOR_CONTROL_TARGET(s)) => {
                    assert_eq!((header.system_id, header.component_id), (1, 191), "{r}");
                    match s.group_mlx {
                        0 => group0_out += 1,
                        2 => group2_out += 1,
                        _ => {}
                    }
                }
                _ => {}
            }
        }
        // Lockstep: one ODOMETRY per step (k/120 s, k = 1 … ticks) besides the standing
        // twin's at 10 Hz; one setpoint per tick (group 2 then 0, FA-Hexa) after the start's
        // stream of 6.
        assert_eq!(
            odometry_times.len() as u64,
            ticks,
            "distinct ODOMETRY times"
        );
        assert!(odometry_in >= ticks, "{odometry_in} ODOMETRY frames in");
        assert!(checked >= ticks, "{checked} ODOMETRY frames checked");
        assert_eq!(group0_out, ticks + 6, "group 0 setpoints out");
        assert_eq!(group2_out, ticks + 6, "group 2 setpoints out");
        eprintln!(
            "{} frames on /mavlink/raw over {ticks} ticks ({odometry_in} ODOMETRY in)",
            raw.len()
        );
    }

    #[test]
    fn a_log_flown_through_the_bridge_replays_in_the_twin() {
        // The flight's MCAP (written by `fly --link mavlink:`) re-flown in the twin from its
        // references: the same plant, so only the wire's f32 separates the two (measured:
        // 1.2e-7 m RMS in x); bound 1e-5 m. The log also holds the autopilot's state and every
        // frame on the wire (checked with the mcap and mavlink crates and the Python mcap
        // reader); replay ignores them, compare reads them like any channel.
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let (log, replayed, compared) = (
            dir.path().join("bridge.mcap"),
            dir.path().join("replay.mcap"),
            dir.path().join("compare.json"),
        );
        let log_arg = log.to_string_lossy().into_owned();
        let flags = [
            "--trajectory",
            "step",
            "--duration",
            "3",
            "--mcap",
            &log_arg,
            "--level",
            "actuator",
        ];
        let (scores, _) = against_autopilot("--lockstep", &[], &flags, dir.path(), "fly");
        let ticks = scores["ticks"]
            .as_u64()
            .unwrap_or_else(|| panic!("no ticks: {scores}"));
        assert_eq!(ticks, 360);
        check_the_mavlink_channels(&log, ticks);
        let expect = format!("/autopilot/state={}", ticks + 1);
        let (code, report) = tests::mcap_check(&log, &["--require-complete", "--expect", &expect]);
        assert_eq!(code, 0, "mcap_check.py: {report}");
        // compare's signal paths reach the autopilot's numbers.
        let self_compared = dir.path().join("self.json");
        let self_arg = self_compared.to_string_lossy().into_owned();
        let mut compare = Proc::start(
            "compare",
            &[
                "compare",
                &log_arg,
                &log_arg,
                "--signal",
                "/autopilot/state.link.frames_ok",
                "--json",
                &self_arg,
            ],
        );
        assert!(
            compare.wait().success(),
            "compare failed:\n{}",
            compare.stderr()
        );
        let report = read_json(&self_compared);
        assert_eq!(
            report["signals"][0]["signal"], "/autopilot/state.link.frames_ok",
            "{report}"
        );
        assert_eq!(
            number(&report["signals"][0]["whole"], "rmse"),
            0.0,
            "{report}"
        );
        let (replayed_arg, compared_arg) = (
            replayed.to_string_lossy().into_owned(),
            compared.to_string_lossy().into_owned(),
        );
        let mut replay = Proc::start("replay", &["replay", &log_arg, "--out", &replayed_arg]);
        assert!(
            replay.wait().success(),
            "replay failed:\n{}",
            replay.stderr()
        );
        let mut compare = Proc::start(
            "compare",
            &[
                "compare",
                &log_arg,
                &replayed_arg,
                "--signal",
                "/base/state.position_m",
                "--json",
                &compared_arg,
            ],
        );
        assert!(
            compare.wait().success(),
            "compare failed:\n{}",
            compare.stderr()
        );
        let report = read_json(&compared);
        let signals = report["signals"].as_array().cloned().unwrap_or_default();
        assert_eq!(signals.len(), 3, "{report}");
        for s in &signals {
            let rmse = number(&s["whole"], "rmse");
            assert!(rmse < 1e-5, "{}: RMSE {rmse} m", s["signal"]);
            assert!(number(&s["whole"], "samples") > 200.0, "{s}");
        }
    }

    #[test]
    fn hover_at_attitude_level_holds_altitude() {
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let flags = [
            "--trajectory",
            "hover",
            "--duration",
            "4",
            "--level",
            "attitude",
        ];
        let (scores, stderr) = against_autopilot("--lockstep", &[], &flags, dir.path(), "attitude");
        // The autopilot's own attitude loop and allocation hold the hover at 1 m: within 5 cm
        // RMS after the 2 s settling, and the base barely tilts.
        let z = number(&scores, "base_z_rmse_m");
        assert!(z < 0.05, "base z RMSE {z} m\n{stderr}");
        let tilt = number(&scores, "tilt_use_rad");
        assert!(tilt < 0.2, "tilt {tilt} rad\n{stderr}");
    }

    /// The ramp PX4's position controller makes of a 1 m step (the twin's MPC_ACC_HOR = 1
    /// m/s², well under MPC_XY_VEL_MAX = 2 m/s): 1 s accelerating, 1 s braking. Its error
    /// to the step, e = 1 − t²/2 then (2 − t)²/2, has ∫e² dt = (1 − 1/3 + 1/20) + 1/20 =
    /// 0.7667 m²·s.
    const RAMP_SQUARED_ERROR_M2S: f64 = 1.0 - 1.0 / 3.0 + 1.0 / 20.0 + 1.0 / 20.0;

    #[test]
    fn a_step_at_the_position_level_is_flown_by_the_autopilots_position_controller() {
        // `--level position`: the stack sends its base target (SET_POSITION_TARGET_LOCAL_NED),
        // the autopilot (the twin's, no actuator extension) flies it as PX4 does, the target
        // moving within its MPC_* limits. Over the whole flight (8 s, the step at 1 s) the
        // tracking error to the step is that of the ramp (measured: 30.82 cm against
        // √(0.7667/8) = 30.96 cm; the stack's own PID on the raw step in process: 25.7 cm);
        // once there (scored after 4 s) the base holds the point (measured: 0.025 cm).
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let step = [
            "--trajectory",
            "step",
            "--duration",
            "8",
            "--level",
            "position",
        ];
        let mut whole = step.to_vec();
        whole.extend_from_slice(&["--settle", "0"]);
        let (scores, stderr) = against_autopilot("--lockstep", &[], &whole, dir.path(), "whole");
        assert!(stderr.contains("position level"), "{stderr}");
        let ramp = (RAMP_SQUARED_ERROR_M2S / 8.0).sqrt();
        let rmse = number(&scores, "base_pos_rmse_m");
        assert!(
            (rmse - ramp).abs() < 0.01,
            "base RMSE {rmse} m, the ramp's {ramp} m\n{stderr}"
        );
        assert!(number(&scores, "base_z_rmse_m") < 0.005, "{scores}");
        let mut held = step.to_vec();
        held.extend_from_slice(&["--settle", "4"]);
        let (scores, stderr) = against_autopilot("--lockstep", &[], &held, dir.path(), "held");
        let rmse = number(&scores, "base_pos_rmse_m");
        assert!(rmse < 0.005, "base RMSE after 4 s {rmse} m\n{stderr}");
        assert!(number(&scores, "tilt_use_rad") < 0.01, "{scores}");
    }

    #[test]
    fn the_actuator_level_is_refused_without_the_extension_and_flown_with_it() {
        // Without --allow-actuator-setpoints the twin's autopilot declares what current PX4
        // declares (no SET_ACTUATOR_TARGET): the bridge refuses before streaming or arming,
        // one line, exit 2, no result written; the autopilot never left its start state.
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let hover = [
            "--platform",
            "fa-hexa",
            "--trajectory",
            "hover",
            "--duration",
            "1",
            "--settle",
            "0",
            "--level",
            "actuator",
        ];
        for extension in [false, true] {
            let port = std::net::UdpSocket::bind("127.0.0.1:0")
                .and_then(|s| s.local_addr())
                .map(|a| a.port())
                .unwrap_or_else(|e| panic!("no free port: {e}"));
            let address = format!("udp:127.0.0.1:{port}");
            let mut args = vec![
                "twin",
                "serve",
                "--mavlink",
                &address,
                "--lockstep",
                "--platform",
                "fa-hexa",
            ];
            if extension {
                args.push("--allow-actuator-setpoints");
            }
            let mut autopilot = Proc::start("twin serve --mavlink", &args);
            autopilot.wait_for("autopilot: serving");
            let json = dir.path().join(format!("actuator-{extension}.json"));
            let (status, result, stderr) = fly_over(&format!("mavlink:{address}"), &hover, &json);
            autopilot.interrupt();
            autopilot.wait_for("stopped after");
            let served = autopilot.stderr();
            if extension {
                assert!(status.success(), "{stderr}");
                assert!(result.is_some(), "{stderr}");
                assert!(served.contains("armed"), "{served}");
            } else {
                assert_eq!(status.code(), Some(2), "{stderr}");
                assert!(result.is_none(), "{stderr}");
                let lines: Vec<&str> = stderr.lines().collect();
                assert_eq!(lines.len(), 1, "{stderr}");
                assert!(
                    lines[0].starts_with(
                        "amstack: the actuator level needs an autopilot that declares \
                         MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET in its AUTOPILOT_VERSION; \
                         this one does not"
                    ),
                    "{stderr}"
                );
                assert!(!served.contains("OFFBOARD"), "{served}");
                assert!(!served.contains("armed"), "{served}");
                assert!(served.contains("stopped after 0 steps"), "{served}");
            }
        }
    }

    #[test]
    fn a_step_at_the_rate_level_is_flown_by_the_autopilots_rate_loop() {
        // `--level rates`: the controller's attitude setpoint through amstack's attitude law
        // (PX4's attitude P gains) as body rates, the autopilot's rate loop and allocation
        // flying them (ATTITUDE_IGNORE). The same 1 m step as at the attitude level: the
        // stack's position loop still flies it, so the base RMSE (scored after 2 s) is near
        // the attitude level's; it holds z and barely tilts.
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let step = ["--trajectory", "step", "--duration", "4"];
        let mut flags = step.to_vec();
        flags.extend_from_slice(&["--level", "rates"]);
        let (rates, stderr) = against_autopilot("--lockstep", &[], &flags, dir.path(), "rates");
        assert!(stderr.contains("rates level"), "{stderr}");
        let mut flags = step.to_vec();
        flags.extend_from_slice(&["--level", "attitude"]);
        let (attitude, _) = against_autopilot("--lockstep", &[], &flags, dir.path(), "attitude");
        let (a, b) = (
            number(&rates, "base_pos_rmse_m"),
            number(&attitude, "base_pos_rmse_m"),
        );
        assert!(
            (a - b).abs() < 0.02,
            "base RMSE {a} m at rates, {b} m at attitude"
        );
        assert!(number(&rates, "base_z_rmse_m") < 0.05, "{rates}");
        assert!(number(&rates, "tilt_use_rad") < 0.2, "{rates}");
    }

    #[test]
    fn the_estimator_flies_on_the_autopilots_imu_and_odometry() {
        // `--state-source estimator` over MAVLink: the EKF fuses the autopilot's HIGHRES_IMU
        // and ODOMETRY (not simulated sensors) and the controllers fly on its estimate. The
        // twin's autopilot reports its truth to f32, so the estimate stays on the odometry
        // (measured: 0.044 mm RMS) and the flight is the truth-fed one (9.155 vs 9.150 cm
        // base RMSE on a 1 m step).
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let step = ["--trajectory", "step", "--duration", "4"];
        let mut flags = step.to_vec();
        flags.extend_from_slice(&["--state-source", "estimator", "--level", "actuator"]);
        let (scores, _) = against_autopilot("--lockstep", &[], &flags, dir.path(), "estimator");
        let e = &scores["estimator"];
        assert_eq!(e["sensors"], "vehicle", "{scores}");
        let ticks = number(&scores, "ticks");
        assert!(number(e, "fused") >= ticks - 1.0, "{e}");
        assert_eq!(number(e, "rejected"), 0.0, "{e}");
        assert!(number(e, "position_rmse_m") < 1e-3, "{e}");
        // The same flight in process on the truth.
        let truth = in_process(&step, dir.path());
        let (a, b) = (
            number(&scores, "base_pos_rmse_m"),
            number(&truth, "base_pos_rmse_m"),
        );
        assert!(
            (a - b).abs() < 1e-3,
            "base RMSE {a} on the estimate, {b} on the truth"
        );
    }

    #[test]
    fn a_realtime_autopilot_is_flown_on_its_clock() {
        // `--realtime`: the twin steps on the wall clock at 120 Hz with the latest setpoint,
        // as a vehicle does; the bridge answers each ODOMETRY with a setpoint. The flight
        // cannot tick faster than the twin's clock (lockstep runs at thousands of ticks per
        // second), and the hover holds.
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let flags = [
            "--trajectory",
            "hover",
            "--duration",
            "3",
            "--level",
            "actuator",
        ];
        let (scores, stderr) = against_autopilot("--realtime", &[], &flags, dir.path(), "realtime");
        let rate = number(&scores, "ticks_per_second");
        assert!(
            rate <= 120.0 * 1.05,
            "{rate} ticks/s against a 120 Hz clock"
        );
        let z = number(&scores, "base_z_rmse_m");
        assert!(z < 0.02, "base z RMSE {z} m\n{stderr}");
    }

    #[test]
    fn a_flight_without_an_autopilot_stops_with_a_clear_error() {
        // Nobody on the port: the bridge waits for the first ODOMETRY, then says so (exit 1).
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let port = std::net::UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .map(|a| a.port())
            .unwrap_or_else(|e| panic!("no free port: {e}"));
        let link = format!("mavlink:udp:127.0.0.1:{port}");
        let json = dir.path().join("none.json");
        let json_arg = json.to_string_lossy().into_owned();
        let mut p = Proc::start(
            "fly",
            &[
                "fly",
                "--link",
                &link,
                "--connect-timeout-ms",
                "300",
                "--json",
                &json_arg,
            ],
        );
        let status = p.wait();
        assert_eq!(status.code(), Some(1), "{}", p.stderr());
        assert!(
            p.stderr().contains(
                "no ODOMETRY (the vehicle's state at start) from the autopilot within 300 ms"
            ),
            "{}",
            p.stderr()
        );
        assert!(!json.exists());
    }

    /// The task flight of the must-show: Push Slider's scripted policy, seed 3, FA-Hexa.
    const TASK: &[&str] = &["--task", "push-slider", "--trajectory", "scripted"];

    /// The task scene the twin's autopilot serves for [`TASK`].
    const TASK_SCENE: &[&str] = &["--task", "push-slider"];

    /// The actuator-level task flight is the in-process rollout: the same outcome, step for
    /// step, and errors within 1e-5 m. The flights are lockstep from the same reset; only the
    /// wire's f32 separates them, amplified by the pushes' contact (measured on the mean EE
    /// and base errors: 1e-8 m with rapier's solver in 4 steps per substep; 1.5e-7 and
    /// 1.0e-6 m with its 2-step default since 2026-11-29, the bound then 1e-6).
    fn assert_same_rollout(over: &serde_json::Value, reference: &serde_json::Value) {
        assert_eq!(over["task_observed"], true, "{over}");
        assert_eq!(reference["success"], true, "{reference}");
        for key in ["success", "termination", "executed_steps", "criteria"] {
            assert_eq!(over[key], reference[key], "{key}: {over} vs {reference}");
        }
        for key in [
            "ee_pos_error_m",
            "base_pos_error_m",
            "norm_ee_error",
            "tilt_use_rad",
        ] {
            let (a, b) = (
                number(&over["summary"], key),
                number(&reference["summary"], key),
            );
            assert!(
                (a - b).abs() < 1e-5,
                "{key}: {a} over MAVLink, {b} in process"
            );
        }
    }

    #[test]
    fn push_slider_flies_over_udp_at_both_levels_as_in_process() {
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let reference = in_process(TASK, dir.path());
        // Actuator level: our allocation flies, the same rollout.
        let log = dir.path().join("task.mcap");
        let log_arg = log.to_string_lossy().into_owned();
        let mut flags = TASK.to_vec();
        flags.extend_from_slice(&["--level", "actuator", "--mcap", &log_arg]);
        let (actuator, _) =
            against_autopilot("--lockstep", TASK_SCENE, &flags, dir.path(), "actuator");
        assert_same_rollout(&actuator, &reference);
        // Its log, read by an independent reader: the task's state at every step, the
        // autopilot's at the start and every step.
        let steps = number(&actuator, "executed_steps") as u64;
        let (task_states, autopilot_states) = (
            format!("/task/state={steps}"),
            format!("/autopilot/state={}", steps + 1),
        );
        let (code, report) = tests::mcap_check(
            &log,
            &[
                "--require-complete",
                "--expect",
                &task_states,
                "--expect",
                &autopilot_states,
            ],
        );
        assert_eq!(code, 0, "{report}");
        // Attitude level, the default (no --level), against the autopilot with the actuator
        // extension off (what a PX4 accepts): its attitude loop and allocation fly the base,
        // so the flight differs, but the task succeeds with the EE on the script within 2 cm
        // on average (measured: 1329 steps against 1328, 0.99 cm).
        let (attitude, _) =
            against_autopilot("--lockstep", TASK_SCENE, TASK, dir.path(), "attitude");
        assert_eq!(attitude["success"], true, "{attitude}");
        assert_eq!(attitude["criteria"], reference["criteria"], "{attitude}");
        let (a, b) = (
            number(&attitude, "executed_steps"),
            number(&reference, "executed_steps"),
        );
        assert!((a - b).abs() <= 0.05 * b, "{a} steps against {b}");
        let ee = number(&attitude["summary"], "ee_pos_error_m");
        assert!(ee < 0.02, "mean EE error {ee} m");
    }

    #[test]
    fn the_whole_body_mpc_flies_push_slider_over_udp_as_in_process() {
        // The MPC models the task: the slider's joint once the hand holds it, and the knob's
        // end the palm presses (docs/mpc-contact.md). Both reach it over MAVLink in the task
        // array; without them the same flight timed out (3119 steps, the slider not pushed)
        // where the in-process rollout succeeds at 1379.
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let mut flags = TASK.to_vec();
        flags.extend_from_slice(&["--controller", "mpc", "--interface", "ee"]);
        let reference = in_process(&flags, dir.path());
        flags.extend_from_slice(&["--level", "actuator"]);
        let (over, _) = against_autopilot("--lockstep", TASK_SCENE, &flags, dir.path(), "mpc");
        assert_same_rollout(&over, &reference);
    }

    #[test]
    fn the_same_task_flight_over_a_serial_pseudo_terminal_pair() {
        // Two pseudo-terminals joined by scripts/pty_pair.py (a null-modem cable): the twin's
        // autopilot opens one as its serial port, the bridge the other.
        let _one = serial();
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let reference = in_process(TASK, dir.path());
        let mut cable = Command::new(tests::python())
            .arg(tests::scripts_dir().join("pty_pair.py"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("pty_pair.py: {e}"));
        let stdout = cable.stdout.take().unwrap_or_else(|| panic!("no stdout"));
        let mut line = String::new();
        BufReader::new(stdout)
            .read_line(&mut line)
            .unwrap_or_else(|e| panic!("pty_pair.py: {e}"));
        let ends: Vec<&str> = line.split_whitespace().skip(1).collect();
        let [twin_end, bridge_end] = ends[..] else {
            panic!("pty_pair.py printed {line:?}");
        };
        let device = format!("serial:{twin_end}:921600");
        // Actuator level: the twin's SITL extension.
        let mut args = vec![
            "twin",
            "serve",
            "--mavlink",
            &device,
            "--lockstep",
            "--allow-actuator-setpoints",
        ];
        args.extend_from_slice(FLIGHT);
        args.extend_from_slice(TASK_SCENE);
        let twin = Proc::start("twin serve --mavlink serial", &args);
        let mut flags = TASK.to_vec();
        flags.extend_from_slice(&["--level", "actuator"]);
        let (serial, _) = flown(
            &format!("mavlink:serial:{bridge_end}:921600"),
            &flags,
            dir.path(),
            "serial",
        );
        drop(twin);
        drop(cable.stdin.take());
        let out = cable
            .wait_with_output()
            .unwrap_or_else(|e| panic!("pty_pair.py: {e}"));
        assert_same_rollout(&serial, &reference);
        // The cable carried the flight: at least a setpoint (≥ 40 bytes) per step one way and
        // the step's telemetry (≥ 300 bytes) the other.
        let report = String::from_utf8_lossy(&out.stderr);
        let copied: Vec<u64> = report
            .split(|c: char| !c.is_ascii_digit())
            .filter_map(|w| w.parse().ok())
            .collect();
        let steps = number(&serial, "executed_steps") as u64;
        assert!(
            copied.len() == 2
                && copied.iter().min() >= Some(&(40 * steps))
                && copied.iter().max() >= Some(&(300 * steps)),
            "{report}"
        );
    }
}
