//! The twin's autopilot toward a PX4 client (issue 20): pymavlink (scripts/px4_gcs.py, in the
//! venv of scripts/setup-python.sh) uses the parameter and mission protocols, COMMAND_INT,
//! takeoff / reposition / hold / RTL / land, position and attitude offboard, body-rate limits,
//! MAVLink 1, and fuzzes every new message. The twin serves lockstep (the offboard flights step
//! once per setpoint); the internal modes run on the wall clock. No assertion is on a duration.
//!
//! The `amstack` binary is the one cargo builds for the root package's CLI test
//! (`cargo test --workspace`); alone, run `cargo build --bin amstack` first.

use std::process::{Command, Stdio};
use std::sync::{Mutex, MutexGuard};

use platform::{GRAVITY_MPS2, Vehicle};
use serde_json::Value;
use tests::process::Proc;

/// One test at a time (each runs a twin and a Python peer on a small machine).
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `amstack twin serve --mavlink udp:127.0.0.1:0 --platform P`, its port, and the peer.
struct Autopilot {
    proc: Proc,
    port: u16,
}

impl Autopilot {
    fn start(platform: &str) -> Self {
        let mut proc = Proc::start(
            "twin serve --mavlink",
            &[
                "twin",
                "serve",
                "--mavlink",
                "udp:127.0.0.1:0",
                "--platform",
                platform,
            ],
        );
        let ready = proc.wait_for("serving");
        let port = ready
            .split("udp:127.0.0.1:")
            .nth(1)
            .and_then(|s| s.split(' ').next())
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("no port in {ready:?}"));
        Self { proc, port }
    }

    /// Runs scripts/px4_gcs.py in `mode`; its JSON.
    fn peer(&self, mode: &str, args: &[&str]) -> Value {
        let connect = format!("udpout:127.0.0.1:{}", self.port);
        let out = Command::new(tests::python())
            .arg(tests::scripts_dir().join("px4_gcs.py"))
            .args([mode, "--connect", &connect])
            .args(args)
            .stderr(Stdio::inherit())
            .output()
            .unwrap_or_else(|e| panic!("px4_gcs.py: {e}"));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "px4_gcs.py {mode} failed: {text}");
        serde_json::from_str(text.trim())
            .unwrap_or_else(|e| panic!("{e}: {text}\nautopilot:\n{}", self.proc.stderr()))
    }

    /// Ctrl-C, then the exit line with the link's counters.
    fn stop(&mut self) -> String {
        self.proc.interrupt();
        self.proc.wait_for("stopped after")
    }
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn ned(v: &Value) -> [f64; 3] {
    [f(&v[0]), f(&v[1]), f(&v[2])]
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The FA-Hexa's hover thrust as a fraction of all rotors' maximum.
fn hover_fraction(id: &str) -> f64 {
    let v = Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"));
    v.mass_properties(&v.initial_configuration()).mass_kg * GRAVITY_MPS2
        / (v.rotors.len() as f64 * v.rotors.thrust_max_n)
}

#[test]
fn parameters_are_listed_read_set_checked_and_change_behaviour() {
    let _one = serial();
    let ap = Autopilot::start("fa-hexa");
    let r = ap.peer("params", &["--takeoff-alt", "1.8"]);
    let list = &r["list"];
    assert_eq!(r["count"], 17, "{r}");
    assert_eq!(
        list["COM_OF_LOSS_T"]["value"], 0.5,
        "--offboard-timeout-ms default: {r}"
    );
    // INT32 bytewise, as PX4.
    assert_eq!(list["COM_OBL_RC_ACT"]["type"], 6, "{r}");
    assert_eq!(list["COM_OBL_RC_ACT"]["value"], 5, "{r}");
    assert_eq!(list["MC_ROLLRATE_MAX"]["value"], 220.0, "{r}");
    assert_eq!(r["read_by_name"][0], "MPC_XY_VEL_MAX", "{r}");
    assert_eq!(r["read_by_index_0"], "COM_OF_LOSS_T", "{r}");
    // Unknown names: PX4's answer, a STATUSTEXT and no PARAM_VALUE.
    assert_eq!(
        r["read_unknown"],
        serde_json::json!(["STATUSTEXT:[pm] unknown param: NO_SUCH_PARAM"]),
        "{r}"
    );
    assert!((f(&r["set_takeoff_alt"][0]) - 1.8).abs() < 1e-6, "{r}");
    // Refused sets answer the unchanged value and say why.
    assert_eq!(r["set_out_of_range"][0], 2.0, "{r}");
    assert!(
        r["set_out_of_range"][1].to_string().contains("outside"),
        "{r}"
    );
    assert_eq!(r["set_nan"][0], 2.0, "{r}");
    assert_eq!(r["set_int32"][0], 4, "{r}");
    assert!(
        r["set_int32_as_real"][1].to_string().contains("INT32"),
        "{r}"
    );
    assert!(r["set_unknown"][0].is_null(), "{r}");
    // COM_OF_LOSS_T: a setpoint 1.5 s old is too old at 0.5 s, fresh enough at 30 s.
    assert_eq!(
        r["offboard_1p5s_after_a_setpoint_with_loss_t_0.5"], "TEMPORARILY_REJECTED",
        "{r}"
    );
    assert_eq!(
        r["offboard_1p5s_after_a_setpoint_with_loss_t_30"], "ACCEPTED",
        "{r}"
    );
    // MIS_TAKEOFF_ALT: NAV_TAKEOFF without an altitude climbs there (within NAV_ACC_RAD).
    assert_eq!(r["takeoff"], "ACCEPTED", "{r}");
    assert_eq!(r["loiter_after_takeoff"], true, "{r}");
    assert!((f(&r["altitude_after_takeoff"]) - 1.8).abs() < 0.05, "{r}");
}

#[test]
fn a_mission_is_uploaded_downloaded_flown_landed_and_disarmed() {
    let _one = serial();
    let mut ap = Autopilot::start("fa-hexa");
    let r = ap.peer("mission", &["--alt", "1.5"]);
    assert_eq!(
        r["mode_mission_without_mission"], "TEMPORARILY_REJECTED",
        "{r}"
    );
    assert_eq!(
        r["upload_requested"],
        serde_json::json!([0, 1, 2, 3, 4]),
        "{r}"
    );
    assert_eq!(r["upload_ack"], 0, "MAV_MISSION_ACCEPTED: {r}");
    assert_eq!(r["download"], r["uploaded"], "{r}");
    assert_eq!(r["mode_mission"], "ACCEPTED", "{r}");
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    // Every item reached, in order, each where it is (waypoints: within their 0.1 m).
    assert_eq!(r["reached"], serde_json::json!([0, 1, 2, 3, 4]), "{r}");
    let at = &r["reached_at_ned"];
    for (seq, point) in [
        ("1", [1.0, 0.0, -1.5]),
        ("2", [1.0, 1.0, -1.5]),
        ("3", [0.0, 1.0, -1.5]),
    ] {
        assert!(dist(ned(&at[seq]), point) < 0.1 + 0.02, "item {seq}: {r}");
    }
    assert_eq!(r["current_seq"], serde_json::json!([0, 1, 2, 3, 4]), "{r}");
    // Landed where the last waypoint was, then disarmed.
    assert_eq!(r["disarmed"], true, "{r}");
    let last = ned(&r["final_ned"]);
    assert!(dist([last[0], last[1], 0.0], [0.0, 1.0, 0.0]) < 0.1, "{r}");
    assert!(last[2] > -0.1, "on the ground: {r}");
    assert!(
        r["landed_states"].to_string().contains('4'),
        "EXTENDED_SYS_STATE LANDING seen: {r}"
    );
    assert_eq!(r["clear_ack"], 0, "{r}");
    assert_eq!(r["count_after_clear"], 0, "{r}");
    let stderr = ap.stop();
    assert!(stderr.contains("stopped"), "{stderr}");
    assert!(
        ap.proc.stderr().contains("disarmed (landed)"),
        "{}",
        ap.proc.stderr()
    );
}

#[test]
fn takeoff_reposition_hold_rtl_and_land_as_px4_with_command_int() {
    let _one = serial();
    let ap = Autopilot::start("fa-hexa");
    let r = ap.peer(
        "auto",
        &[
            "--alt",
            "1.5",
            "--north",
            "1.0",
            "--east",
            "0.5",
            "--rtl-alt",
            "2.0",
        ],
    );
    assert_eq!(r["takeoff_disarmed"], "DENIED", "{r}");
    assert_eq!(r["takeoff"], "ACCEPTED", "{r}");
    assert_eq!(r["loiter_after_takeoff"], true, "{r}");
    assert!((-f(&r["after_takeoff_ned"][2]) - 1.5).abs() < 0.2, "{r}");
    // DO_REPOSITION as COMMAND_INT (lat/lon · 1e7, relative altitude).
    assert_eq!(r["reposition_int"], "ACCEPTED", "{r}");
    assert!(
        dist(ned(&r["after_reposition_ned"]), [1.0, 0.5, -1.5]) < 0.05,
        "{r}"
    );
    // Hold stays.
    assert_eq!(r["hold"], "ACCEPTED", "{r}");
    assert!(
        dist(ned(&r["after_hold_ned"]), [1.0, 0.5, -1.5]) < 0.05,
        "{r}"
    );
    assert_eq!(r["request_message_int"], "ACCEPTED", "{r}");
    assert!(r["home"].is_array(), "HOME_POSITION on request: {r}");
    // RTL climbs to RTL_RETURN_ALT, returns above home (where it armed), lands, disarms.
    assert_eq!(r["rtl"], "ACCEPTED", "{r}");
    assert_eq!(r["rtl_disarmed"], true, "{r}");
    assert!((f(&r["rtl_max_alt"]) - 2.0).abs() < 0.1, "{r}");
    let home = ned(&r["home"]
        .as_array()
        .map(|h| Value::from(h[3..6].to_vec()))
        .unwrap_or_default());
    let end = ned(&r["after_rtl_ned"]);
    assert!(
        dist([end[0], end[1], 0.0], [home[0], home[1], 0.0]) < 0.25,
        "{r}"
    );
    assert_eq!(r["land"], "ACCEPTED", "{r}");
    assert_eq!(r["land_disarmed"], true, "{r}");
    assert_eq!(
        r["unsupported_int"], "UNSUPPORTED",
        "COMMAND_INT answered: {r}"
    );
}

#[test]
fn position_offboard_reaches_its_setpoint_within_5_cm() {
    let _one = serial();
    let ap = Autopilot::start("fa-hexa");
    let r = ap.peer(
        "position",
        &["--target", "0.5", "-0.3", "-1.5", "--ticks", "720"],
    );
    assert_eq!(r["offboard"], "ACCEPTED", "{r}");
    assert_eq!(r["arm"], "ACCEPTED", "{r}");
    assert!(r["error"].is_null(), "{r}");
    assert!(f(&r["error_m"]) < 0.05, "{r}");
}

#[test]
fn attitude_offboard_with_thrust_body_pushes_the_fa_hexa_level() {
    let _one = serial();
    let ap = Autopilot::start("fa-hexa");
    let hover = hover_fraction("fa-hexa").to_string();
    // 240 ticks (2 s) of level attitude with 2 % of the rotors' thrust forward (FRD x).
    let r = ap.peer(
        "attitude",
        &[
            "--hover-thrust",
            &hover,
            "--forward",
            "0.02",
            "--ticks",
            "240",
        ],
    );
    assert!(r["error"].is_null(), "{r}");
    // Level: the forward force is body thrust, not tilt.
    assert!(f(&r["max_tilt_deg"]) < 1.0, "{r}");
    // Facing east: forward is NED +y; a = 0.02 · 6 · 23 N / 6.635 kg ≈ 0.42 m/s², 2 s → ≈ 0.83 m.
    let end = ned(&r["final_ned"]);
    assert!((end[1] - 0.83).abs() < 0.1, "{r}");
    assert!(end[0].abs() < 0.05, "{r}");
    assert!((end[2] + 1.0).abs() < 0.05, "altitude held: {r}");
}

#[test]
fn body_rates_beyond_the_limits_are_clamped_and_non_finite_ones_refused() {
    let _one = serial();
    let mut ap = Autopilot::start("fa-hexa");
    let hover = hover_fraction("fa-hexa").to_string();
    let r = ap.peer("rates", &["--hover-thrust", &hover, "--ticks", "8"]);
    let res = &r["results"];
    // 50 rad/s asked: at most MC_ROLLRATE_MAX = 220 °/s (+ 5 % loop overshoot).
    let limit = 220f64.to_radians();
    let roll = f(&res["50"]["max_roll_rate"]);
    assert!(roll <= limit * 1.05 && roll > 1.0, "{r}");
    // 1e30 rad/s asked with MC_ROLLRATE_MAX set to 90 °/s.
    let roll = f(&res["1e30"]["max_roll_rate"]);
    assert!(roll <= 90f64.to_radians() * 1.05 && roll > 0.5, "{r}");
    // NaN: refused with a reason, counted.
    assert!(
        res["nan"]["texts"].to_string().contains("NaN not finite"),
        "{r}"
    );
    let line = ap.stop();
    assert!(!line.contains("rejected input 0"), "{line}");
}

#[test]
fn actuator_setpoints_are_refused_with_a_reason_unless_allowed() {
    let _one = serial();
    let mut ap = Autopilot::start("fa-hexa");
    let r = ap.peer("actuator", &[]);
    // One STATUSTEXT a second at most, saying why; no setpoint stream, so no OFFBOARD.
    assert_eq!(
        r["texts"],
        serde_json::json!(["Actuator setpoints refused: not in PX4 (SITL flag)"]),
        "{r}"
    );
    assert_eq!(r["offboard"], "TEMPORARILY_REJECTED", "{r}");
    let line = ap.stop();
    assert!(line.contains("rejected input 5"), "{line}");
}

#[test]
fn a_mavlink_1_ground_station_is_answered_in_mavlink_1() {
    let _one = serial();
    let ap = Autopilot::start("fa-hexa");
    let r = ap.peer("v1", &[]);
    assert_eq!(r["heartbeat_v1"], true, "{r}");
    assert_eq!(r["ack"], "ACCEPTED", "{r}");
    assert_eq!(r["ack_v1"], true, "{r}");
    assert_eq!(r["v2_frames_seen"], serde_json::json!([]), "{r}");
    assert!(
        r["v1_types_seen"].to_string().contains("GPS_RAW_INT"),
        "{r}"
    );
}

#[test]
fn fuzzed_frames_are_counted_and_move_nothing() {
    let _one = serial();
    let mut ap = Autopilot::start("fa-hexa");
    let r = ap.peer("fuzz", &["--frames", "3000", "--seed", "7"]);
    // Still serving, still disarmed in POSCTL, not moved, parameters and mission untouched.
    assert_eq!(r["ack_after"], "ACCEPTED", "{r}");
    assert_eq!(r["armed_after"], false, "{r}");
    assert_eq!(r["mode_after"], serde_json::json!([3, 0]), "{r}");
    assert_eq!(r["after_ned"], r["before_ned"], "{r}");
    assert_eq!(r["mission_count_after"], 0, "{r}");
    let p = &r["params_after"];
    assert_eq!(p["COM_OF_LOSS_T"], 0.5, "{r}");
    assert_eq!(p["MPC_XY_VEL_MAX"], 2.0, "{r}");
    assert_eq!(p["MC_ROLLRATE_MAX"], 220.0, "{r}");
    assert_eq!(p["COM_OBL_RC_ACT"], 5, "{r}");
    assert!(f(&r["errors_comm"]) > 0.0, "{r}");
    // Counted by kind at exit.
    let line = ap.stop();
    for kind in ["bad crc", "unknown id", "truncated", "rejected input"] {
        assert!(!line.contains(&format!("{kind} 0,")), "{kind}: {line}");
    }
}
