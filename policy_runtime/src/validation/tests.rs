//! Compare on hand-made logs with known offsets, delays and rate differences (figures derived
//! by hand in each test), damaged and too-new files, and replays of twin flights.

use std::path::{Path, PathBuf};

use controllers::{ControllerKind, profile};
use nalgebra::Isometry3;
use platform::Vehicle;
use schemars::JsonSchema;
use serde::Serialize;
use sim_twin::{Disturbances, TwinConfig};

use super::replay::LoggedFlight;
use super::*;
use crate::record::foxglove::PoseInFrame;
use crate::record::{McapRecorder, RunMetadata, SchemaName};
use crate::{Interface, TrackConfig, Trajectory, run_track};

#[derive(Debug, Clone, Serialize, JsonSchema)]
struct Sample {
    /// The test signal, m.
    value_m: f64,
}
impl SchemaName for Sample {
    const SCHEMA_NAME: &'static str = "amstack.test.Sample";
}

/// Writes a log with `/test.value_m` = `f(t)` at times `k / rate_hz`, k = k0..=k1, and
/// `/ee/reference` at the same times with z = `z_ref(t)`.
fn hand_log(
    dir: &Path,
    name: &str,
    rate_hz: f64,
    (k0, k1): (u64, u64),
    f: impl Fn(f64) -> f64,
    z_ref: impl Fn(f64) -> f64,
) -> FlightLogFile {
    let path = dir.join(name);
    let mut rec = McapRecorder::create(&path, &RunMetadata::new("fa-hexa", "pid6", 0)).unwrap();
    let ch = rec.channel::<Sample>("/test").unwrap();
    let ee = rec.channel::<PoseInFrame>("/ee/reference").unwrap();
    for k in k0..=k1 {
        let t = k as f64 / rate_hz;
        let ns = (k as f64 * 1e9 / rate_hz).round() as u64;
        rec.log(&ch, ns, &Sample { value_m: f(t) }).unwrap();
        let pose = Isometry3::translation(0.0, 0.0, z_ref(t));
        rec.log(&ee, ns, &PoseInFrame::new(ns, "world", &pose))
            .unwrap();
    }
    rec.finish().unwrap();
    read_flight_log(&path, false).unwrap()
}

fn one(a: &FlightLogFile, b: &FlightLogFile, intervals: &[&str]) -> SignalReport {
    let intervals: Vec<String> = intervals.iter().map(|s| (*s).to_owned()).collect();
    let mut report = compare_logs(a, b, &["/test.value_m".to_owned()], &intervals, 0.0).unwrap();
    assert_eq!(report.signals.len(), 1);
    report.signals.remove(0)
}

fn close(x: Option<f64>, expected: f64, tol: f64) -> bool {
    x.is_some_and(|x| (x - expected).abs() <= tol)
}

/// Exact up to the rounding of times to nanoseconds and of the arithmetic.
const EXACT: f64 = 1e-9;

#[test]
fn a_constant_offset_at_another_rate_is_its_bias_and_rmse() {
    // A = t at 100 Hz, B = t + 0.5 at 30 Hz, both over [0, 10] s: B interpolated linearly at
    // A's times is exactly t + 0.5 (a line), so e = 0.5 at all 1001 samples.
    let dir = tempfile::tempdir().unwrap();
    let a = hand_log(dir.path(), "a.mcap", 100.0, (0, 1000), |t| t, |_| 1.0);
    let b = hand_log(dir.path(), "b.mcap", 30.0, (0, 300), |t| t + 0.5, |_| 1.0);
    let s = one(&a, &b, &[]);
    assert_eq!(s.whole.samples, 1001);
    assert!(close(s.whole.bias, 0.5, EXACT), "{:?}", s.whole);
    assert!(close(s.whole.rmse, 0.5, EXACT), "{:?}", s.whole);
    assert!(close(s.whole.max_abs, 0.5, EXACT), "{:?}", s.whole);
    assert_eq!(s.unit, "m");
}

#[test]
fn a_delay_on_a_ramp_and_on_a_sine_gives_the_derived_error() {
    let dir = tempfile::tempdir().unwrap();
    // Ramp of slope 2 m/s delayed by 0.25 s: e = 2(t − 0.25) − 2t = −0.5 m everywhere.
    let a = hand_log(dir.path(), "a.mcap", 100.0, (0, 1000), |t| 2.0 * t, |_| 1.0);
    let b = hand_log(
        dir.path(),
        "b.mcap",
        100.0,
        (0, 1000),
        |t| 2.0 * (t - 0.25),
        |_| 1.0,
    );
    let s = one(&a, &b, &[]);
    assert!(close(s.whole.bias, -0.5, EXACT), "{:?}", s.whole);
    assert!(close(s.whole.rmse, 0.5, EXACT), "{:?}", s.whole);

    // sin(2πt) delayed by d: e = sin(2π(t − d)) − sin(2πt) = −2 cos(2π(t − d/2)) sin(πd),
    // whose RMS over whole periods is √2·|sin(πd)| and mean 0. d = 0.05 s: 0.221232 m.
    let d = 0.05;
    let w = 2.0 * std::f64::consts::PI;
    let a = hand_log(
        dir.path(),
        "sa.mcap",
        1000.0,
        (0, 10_000),
        |t| (w * t).sin(),
        |_| 1.0,
    );
    let b = hand_log(
        dir.path(),
        "sb.mcap",
        1000.0,
        (0, 10_000),
        |t| (w * (t - d)).sin(),
        |_| 1.0,
    );
    let s = one(&a, &b, &[]);
    let rms = 2f64.sqrt() * (std::f64::consts::PI * d).sin();
    assert!((rms - 0.221_232).abs() < 1e-6);
    // 10001 samples over 10 periods: the extra sample shifts the means by ~1e-4.
    assert!(close(s.whole.rmse, rms, 1e-4), "{:?} vs {rms}", s.whole);
    assert!(close(s.whole.bias, 0.0, 1e-4), "{:?}", s.whole);
    assert!(close(
        s.whole.max_abs,
        2.0 * (std::f64::consts::PI * d).sin(),
        1e-4
    ));
}

#[test]
fn a_shift_of_b_removes_a_known_delay_and_start_lines_up_clocks() {
    // B = 2(t − 0.25) sampled at t: shifted by −0.25 s, its sample at τ = t − 0.25 holds 2τ,
    // A's value there: zero error over the overlap [0, 9.75] s (976 samples of A).
    let dir = tempfile::tempdir().unwrap();
    let a = hand_log(dir.path(), "a.mcap", 100.0, (0, 1000), |t| 2.0 * t, |_| 1.0);
    let b = hand_log(
        dir.path(),
        "b.mcap",
        100.0,
        (0, 1000),
        |t| 2.0 * (t - 0.25),
        |_| 1.0,
    );
    let s = compare_logs(&a, &b, &["/test.value_m".to_owned()], &[], -0.25).unwrap();
    assert_eq!(s.signals[0].whole.samples, 976);
    assert!(
        close(s.signals[0].whole.max_abs, 0.0, EXACT),
        "{:?}",
        s.signals[0].whole
    );
    // A log starting at 3 s (a flight clock) against one starting at 0 s (its replay).
    let late = hand_log(
        dir.path(),
        "late.mcap",
        100.0,
        (300, 1300),
        |t| t - 3.0,
        |_| 1.0,
    );
    let early = hand_log(dir.path(), "early.mcap", 100.0, (0, 1000), |t| t, |_| 1.0);
    let shift = start_shift_s(&late, &early);
    assert!(close(Some(shift), 3.0, EXACT), "{shift}");
    let s = compare_logs(&late, &early, &["/test.value_m".to_owned()], &[], shift).unwrap();
    assert_eq!(s.signals[0].whole.samples, 1001);
    assert!(
        close(s.signals[0].whole.max_abs, 0.0, EXACT),
        "{:?}",
        s.signals[0].whole
    );
}

#[test]
fn interpolating_a_slower_log_of_a_parabola_errs_by_theta_one_minus_theta_h_squared() {
    // A = t² every 0.1 s over [0, 3] (31 samples); B = t² every h = 0.3 s. At A's times
    // between B's samples, θ = 1/3 or 2/3 of the way, the chord lies above the parabola by
    // θ(1 − θ)h² = (2/9)·0.09 = 0.02 m; at the 11 common times e = 0. So 20 samples err by
    // 0.02: bias = 20·0.02/31 = 0.0129032, RMSE = √(20·0.0004/31) = 0.0160644, max 0.02.
    let dir = tempfile::tempdir().unwrap();
    let a = hand_log(dir.path(), "a.mcap", 10.0, (0, 30), |t| t * t, |_| 1.0);
    let b = hand_log(
        dir.path(),
        "b.mcap",
        10.0 / 3.0,
        (0, 10),
        |t| t * t,
        |_| 1.0,
    );
    let s = one(&a, &b, &[]);
    assert_eq!(s.whole.samples, 31);
    assert!(close(s.whole.bias, 0.4 / 31.0, 1e-9), "{:?}", s.whole);
    assert!(
        close(s.whole.rmse, (0.008_f64 / 31.0).sqrt(), 1e-9),
        "{:?}",
        s.whole
    );
    assert!(close(s.whole.max_abs, 0.02, 1e-9), "{:?}", s.whole);
}

#[test]
fn only_the_overlap_is_compared() {
    // A over [0, 10] s, B over [2, 12] s at 100 Hz: A's samples at 2.00..10.00 s, 801 of them.
    let dir = tempfile::tempdir().unwrap();
    let a = hand_log(dir.path(), "a.mcap", 100.0, (0, 1000), |t| t, |_| 1.0);
    let b = hand_log(dir.path(), "b.mcap", 100.0, (200, 1200), |t| t, |_| 1.0);
    let s = one(&a, &b, &[]);
    assert_eq!(s.whole.samples, 801);
    assert_eq!(s.whole.span_s, Some([2.0, 10.0]));
    assert!(close(s.whole.rmse, 0.0, EXACT));
    // Logs that do not overlap at all are refused, naming both spans.
    let c = hand_log(dir.path(), "c.mcap", 100.0, (1100, 1200), |t| t, |_| 1.0);
    let err = compare_logs(&a, &c, &["/test.value_m".to_owned()], &[], 0.0).unwrap_err();
    assert!(err.to_string().contains("do not overlap"), "{err}");
    assert!(err.to_string().contains("11.000..12.000 s"), "{err}");
}

#[test]
fn intervals_select_by_reference_altitude_and_by_time() {
    // A = 0 at 100 Hz over [0, 10] s; B = +0.5 before t = 5 s and −0.5 from 5 s on (same
    // times, no interpolation). z_ref = t/10 m.
    let dir = tempfile::tempdir().unwrap();
    let z = |t: f64| t / 10.0;
    let a = hand_log(dir.path(), "a.mcap", 100.0, (0, 1000), |_| 0.0, z);
    let b = hand_log(
        dir.path(),
        "b.mcap",
        100.0,
        (0, 1000),
        |t| if t < 5.0 { 0.5 } else { -0.5 },
        z,
    );
    let s = one(&a, &b, &["z_ref<=0.3", "t=6..7", "z_ref>0.8&t=0..9", "t<5"]);
    // Whole: 500 samples at +0.5, 501 at −0.5.
    assert!(close(s.whole.bias, -0.5 / 1001.0, EXACT), "{:?}", s.whole);
    assert!(close(s.whole.rmse, 0.5, EXACT));
    let by = |i: usize| &s.intervals[i].stats;
    // z_ref ≤ 0.3 m ⇔ t ≤ 3 s: 301 samples, all +0.5.
    assert_eq!(by(0).samples, 301);
    assert!(close(by(0).bias, 0.5, EXACT));
    // t ∈ [6, 7]: 101 samples at −0.5.
    assert_eq!(by(1).samples, 101);
    assert!(close(by(1).bias, -0.5, EXACT));
    // z_ref > 0.8 and t ≤ 9: t ∈ (8, 9], 100 samples.
    assert_eq!(by(2).samples, 100);
    assert!(close(by(2).bias, -0.5, EXACT));
    assert_eq!(by(3).samples, 500);
    assert!(close(by(3).rmse, 0.5, EXACT));
}

#[test]
fn bad_intervals_are_refused_naming_the_expression() {
    for (expr, says) in [
        ("z_ref<=abc", "not a finite number"),
        ("t=5..2", "ends before it starts"),
        ("t=1-2", "t=A..B"),
        ("altitude>1", "is not t, x_ref"),
        ("z_ref", "expected t=A..B"),
        ("", "empty"),
    ] {
        let err = parse_interval(expr).unwrap_err().to_string();
        assert!(
            err.contains(&format!("'{expr}'")) && err.contains(says),
            "{expr}: {err}"
        );
    }
    assert_eq!(
        parse_interval("z_ref>=0.9").unwrap().clauses,
        vec![compare::Clause::Threshold {
            signal: "/ee/reference.pose.position.z".to_owned(),
            op: compare::Op::Ge,
            value: 0.9
        }]
    );
}

#[test]
fn a_missing_signal_is_named_with_the_available_ones() {
    let dir = tempfile::tempdir().unwrap();
    let a = hand_log(dir.path(), "a.mcap", 10.0, (0, 10), |t| t, |_| 1.0);
    for (path, says) in [
        ("/base/state.position_m[2]", "no channel /base/state"),
        ("/test.value", "no field 'value' (fields here: value_m)"),
        ("/test.value_m[0]", "not an array"),
        ("/ee/reference.pose.position.w", "no field 'w'"),
    ] {
        let err = compare_logs(&a, &a, &[path.to_owned()], &[], 0.0)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(path) && err.contains("a.mcap") && err.contains(says),
            "{err}"
        );
        assert!(
            err.contains("available: /ee/reference.pose.orientation.w"),
            "{err}"
        );
        assert!(err.contains("/test.value_m"), "{err}");
    }
    let err = compare_logs(&a, &a, &["base.z".to_owned()], &[], 0.0)
        .unwrap_err()
        .to_string();
    assert!(err.contains("starts with its channel's topic"), "{err}");
}

#[test]
fn corrupt_truncated_and_too_new_files_are_refused_naming_the_file_older_ones_read() {
    let dir = tempfile::tempdir().unwrap();
    let log = hand_log(dir.path(), "whole.mcap", 120.0, (0, 600), |t| t, |_| 1.0);
    let bytes = std::fs::read(&log.path).unwrap();

    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let err = read_flight_log(&cut, false).unwrap_err().to_string();
    assert!(
        err.contains("cut.mcap") && err.contains("truncated"),
        "{err}"
    );
    assert!(err.contains("--allow-truncated"), "{err}");
    // With the flag, the complete chunks are used.
    let part = read_flight_log(&cut, true).unwrap();
    assert!(!part.recording.messages.is_empty());
    assert!(part.recording.messages.len() < log.recording.messages.len());

    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(&garbage, b"this is not an mcap file at all").unwrap();
    let err = read_flight_log(&garbage, false).unwrap_err().to_string();
    assert!(
        err.contains("garbage.mcap") && err.contains("not a readable MCAP"),
        "{err}"
    );

    let missing = dir.path().join("missing.mcap");
    let err = read_flight_log(&missing, false).unwrap_err().to_string();
    assert!(
        err.contains("missing.mcap") && err.contains("cannot read"),
        "{err}"
    );

    // Version 1 (the camera channels in JSON) is still read: replay and compare do not read
    // the camera channels, the only ones version 2 changed.
    assert_eq!(crate::record::LOG_FORMAT_VERSION, 2);
    let older = dir.path().join("older.mcap");
    let mut run = RunMetadata::new("fa-hexa", "pid6", 0);
    run.log_format_version = 1;
    let mut r = McapRecorder::create(&older, &run).unwrap();
    let channel: crate::record::Channel<crate::flight_log::Disturbances> =
        r.channel("/disturbances").unwrap();
    let none = crate::flight_log::Disturbances {
        drag_n: [0.0; 3],
        wind_n: [0.0; 3],
        ground_effect_n: [0.0; 3],
        near_wall_n: [0.0; 3],
    };
    r.log(&channel, 0, &none).unwrap();
    r.finish().unwrap();
    let read = read_flight_log(&older, false).unwrap();
    assert_eq!(read.recording.messages.len(), 1);

    let newer = dir.path().join("newer.mcap");
    let mut run = RunMetadata::new("fa-hexa", "pid6", 0);
    run.log_format_version = crate::record::LOG_FORMAT_VERSION + 1;
    McapRecorder::create(&newer, &run)
        .unwrap()
        .finish()
        .unwrap();
    let err = read_flight_log(&newer, false).unwrap_err().to_string();
    let (found, current) = (
        crate::record::LOG_FORMAT_VERSION + 1,
        crate::record::LOG_FORMAT_VERSION,
    );
    assert!(
        err.contains("newer.mcap")
            && err.contains(&format!("version {found} is newer"))
            && err.contains(&format!("to {current})")),
        "{err}"
    );
}

// ---- replays of twin flights ----

fn twin_flight(dir: &Path, name: &str, disturbances: &str, interface: Interface) -> PathBuf {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let controller = profile(&vehicle, ControllerKind::Pid).unwrap();
    let path = dir.join(name);
    let config = TrackConfig {
        live: None,
        cameras: None,
        vehicle,
        controller,
        trajectory: Trajectory::Step,
        interface,
        duration_s: 2.0,
        settle_s: 0.0,
        twin: TwinConfig {
            disturbances: Disturbances::parse_list(disturbances).unwrap(),
            seed: 11,
            ..TwinConfig::default()
        },
        mcap: Some(path.clone()),
        state_source: crate::StateSource::Truth,
        clock: None,
    };
    run_track(&config, |_| std::ops::ControlFlow::Continue(())).unwrap();
    path
}

fn replay_of(log: &Path, out: &Path, mode: ReplayMode, twin: Option<TwinConfig>) -> ReplayResult {
    let file = read_flight_log(log, false).unwrap();
    let logged = LoggedFlight::from_log(&file).unwrap();
    let vehicle = Vehicle::builtin(&logged.run.vehicle_id).unwrap();
    let config = ReplayConfig {
        controller: logged.controller_config(&vehicle).unwrap(),
        twin: twin.unwrap_or_else(|| logged.twin_config().unwrap()),
        vehicle,
        mode,
        out: out.to_path_buf(),
    };
    replay_flight(&logged, &config).unwrap()
}

const STATE: [&str; 4] = [
    "/base/state.position_m",
    "/base/state.orientation_wxyz",
    "/base/state.velocity_world_mps",
    "/joints.position",
];

#[test]
fn a_reference_replay_of_a_twin_flight_reproduces_it_bit_for_bit() {
    // Every disturbance, measurement and action noise included, through the EE interface
    // (IK): the twin is seeded and the actions are logged, so the replay is the same flight.
    let dir = tempfile::tempdir().unwrap();
    let log = twin_flight(dir.path(), "flight.mcap", "all", Interface::Ee);
    let out = dir.path().join("replay.mcap");
    let result = replay_of(&log, &out, ReplayMode::Reference, None);
    assert_eq!(result.replayed_ticks, 240);
    assert!(result.actions_from_action_channel && !result.initial_state_from_log);
    let (a, b) = (
        read_flight_log(&log, false).unwrap(),
        read_flight_log(&out, false).unwrap(),
    );
    let mut signals: Vec<String> = STATE.iter().map(|s| (*s).to_owned()).collect();
    signals.push("/rotors.applied_n".to_owned());
    signals.push("/control/wrench.force_n".to_owned());
    let report = compare_logs(&a, &b, &signals, &[], 0.0).unwrap();
    for s in &report.signals {
        assert!(s.whole.samples >= 239, "{}: {:?}", s.signal, s.whole);
        assert_eq!(s.whole.max_abs, Some(0.0), "{}: {:?}", s.signal, s.whole);
    }
    // Every payload of the state channels is identical, not only the compared numbers.
    let payloads = |f: &FlightLogFile, topic: &str| -> Vec<Vec<u8>> {
        f.recording
            .messages
            .iter()
            .filter(|m| m.topic == topic)
            .map(|m| m.data.clone())
            .collect()
    };
    for topic in ["/base/state", "/rotors", "/joints", "/action"] {
        assert_eq!(payloads(&a, topic), payloads(&b, topic), "{topic}");
    }
}

#[test]
fn a_commands_replay_is_exact_on_the_same_plant_and_drifts_open_loop_on_another() {
    let dir = tempfile::tempdir().unwrap();
    let log = twin_flight(
        dir.path(),
        "flight.mcap",
        "drag,wind,saturation",
        Interface::BaseJoint,
    );
    let a = read_flight_log(&log, false).unwrap();
    let signals: Vec<String> = STATE.iter().map(|s| (*s).to_owned()).collect();

    // Same plant: the same commands give the same flight.
    let same = dir.path().join("same.mcap");
    assert_eq!(
        replay_of(&log, &same, ReplayMode::Commands, None).replayed_ticks,
        240
    );
    let report = compare_logs(
        &a,
        &read_flight_log(&same, false).unwrap(),
        &signals,
        &[],
        0.0,
    )
    .unwrap();
    for s in &report.signals {
        assert_eq!(s.whole.max_abs, Some(0.0), "{}: {:?}", s.signal, s.whole);
    }

    // Without wind and drag, nothing corrects the open-loop flight: the base drifts. The
    // stated bound: within 1 cm over the first 0.5 s; more than that over the 2 s.
    let mut calm = read_flight_log(&log, false)
        .map(|f| LoggedFlight::from_log(&f).unwrap().twin_config().unwrap())
        .unwrap();
    calm.disturbances = Disturbances::parse_list("saturation").unwrap();
    let drift = dir.path().join("drift.mcap");
    replay_of(&log, &drift, ReplayMode::Commands, Some(calm));
    let report = compare_logs(
        &a,
        &read_flight_log(&drift, false).unwrap(),
        &["/base/state.position_m".to_owned()],
        &["t=0..0.5".to_owned()],
        0.0,
    )
    .unwrap();
    let worst_early = report
        .signals
        .iter()
        .map(|s| s.intervals[0].stats.max_abs.unwrap())
        .fold(0.0, f64::max);
    let worst = report
        .signals
        .iter()
        .map(|s| s.whole.max_abs.unwrap())
        .fold(0.0, f64::max);
    assert!(worst_early < 0.01, "first 0.5 s: {worst_early} m");
    assert!(
        worst > worst_early,
        "whole {worst} m, first 0.5 s {worst_early} m"
    );
}

#[test]
fn a_log_without_the_action_channel_replays_from_its_references() {
    // Logs written before `/action` existed (or by a writer without it): the action is
    // rebuilt from /ee/reference (EE interface) or /base/reference + /joints.target, with the
    // gripper closed as the track references have it; the replay is still exact.
    for interface in [Interface::Ee, Interface::BaseJoint] {
        let dir = tempfile::tempdir().unwrap();
        let log = twin_flight(dir.path(), "flight.mcap", "reference", interface);
        let mut file = read_flight_log(&log, false).unwrap();
        file.recording.messages.retain(|m| m.topic != "/action");
        let logged = LoggedFlight::from_log(&file).unwrap();
        assert!(logged.actions.is_none());
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let out = dir.path().join("replay.mcap");
        let config = ReplayConfig {
            controller: logged.controller_config(&vehicle).unwrap(),
            twin: logged.twin_config().unwrap(),
            vehicle,
            mode: ReplayMode::Reference,
            out: out.clone(),
        };
        let result = replay_flight(&logged, &config).unwrap();
        assert!(!result.actions_from_action_channel);
        let report = compare_logs(
            &file,
            &read_flight_log(&out, false).unwrap(),
            &STATE.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>(),
            &[],
            0.0,
        )
        .unwrap();
        for s in &report.signals {
            assert_eq!(
                s.whole.max_abs,
                Some(0.0),
                "{interface:?} {}: {:?}",
                s.signal,
                s.whole
            );
        }
    }
}

#[test]
fn a_replay_starts_from_the_logged_initial_state() {
    // A log whose initial pose is not the twin's reset pose (as a real flight's): the twin is
    // moved there.
    let dir = tempfile::tempdir().unwrap();
    let log = twin_flight(dir.path(), "flight.mcap", "none", Interface::BaseJoint);
    let file = read_flight_log(&log, false).unwrap();
    let mut logged = LoggedFlight::from_log(&file).unwrap();
    logged.initial_pose = Isometry3::translation(0.3, -0.2, 1.4);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let out = dir.path().join("moved.mcap");
    let config = ReplayConfig {
        controller: logged.controller_config(&vehicle).unwrap(),
        twin: logged.twin_config().unwrap(),
        vehicle,
        mode: ReplayMode::Reference,
        out: out.clone(),
    };
    let result = replay_flight(&logged, &config).unwrap();
    assert!(result.initial_state_from_log);
    let b = read_flight_log(&out, false).unwrap();
    let z = signals::extract(
        &b.recording,
        "moved.mcap",
        &signals::parse_signal_path("/base/state.position_m[2]", ["/base/state"]).unwrap(),
    )
    .unwrap();
    assert!((z.values[0] - 1.4).abs() < 1e-9, "{}", z.values[0]);
}

#[test]
fn a_bench_rollout_replays_with_its_scene_and_the_same_task_outcome() {
    // A rollout of the benchmark (task scene, IK limits in front of obstacles, scripted
    // actions with noise): the replay re-flies it in the same scene and logs the task's
    // state, identical to the rollout's.
    let dir = tempfile::tempdir().unwrap();
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let config = crate::bench::BenchConfig {
        live: None,
        cameras: None,
        controller: profile(&vehicle, ControllerKind::Pid).unwrap(),
        controller_name: "ik-pid".to_owned(),
        vehicle,
        interface: Interface::Ee,
        tasks: vec![sim_twin::TaskId::parse("press-button").unwrap()],
        rollouts: 1,
        seed: 5,
        twin: TwinConfig {
            disturbances: Disturbances::parse_list("reference,noise").unwrap(),
            ..TwinConfig::default()
        },
        jobs: 1,
        episode: crate::bench::EpisodeLength::Script,
        mcap_dir: Some(dir.path().to_path_buf()),
        link: crate::bench::BenchLink::InProcess,
        state_source: crate::StateSource::Truth,
        policy: None,
    };
    let stop = std::sync::atomic::AtomicBool::new(false);
    crate::bench::run_bench(&config, &|_| {}, &stop).unwrap();
    let log = crate::bench::rollout_log_path(
        dir.path(),
        sim_twin::TaskId::parse("press-button").unwrap(),
        0,
    );
    let out = dir.path().join("replay.mcap");
    let result = replay_of(&log, &out, ReplayMode::Reference, None);
    assert_eq!(result.replayed_ticks, result.logged_ticks);
    let (a, b) = (
        read_flight_log(&log, false).unwrap(),
        read_flight_log(&out, false).unwrap(),
    );
    let payloads = |f: &FlightLogFile, topic: &str| -> Vec<Vec<u8>> {
        f.recording
            .messages
            .iter()
            .filter(|m| m.topic == topic)
            .map(|m| m.data.clone())
            .collect()
    };
    for topic in ["/task/state", "/base/state", "/joints", "/rotors"] {
        let logged = payloads(&a, topic);
        assert!(!logged.is_empty(), "{topic}");
        assert_eq!(logged, payloads(&b, topic), "{topic}");
    }
}

#[test]
fn samples_out_of_time_order_are_sorted_and_interpolation_keeps_the_later_of_equal_times() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shuffled.mcap");
    let mut rec = McapRecorder::create(&path, &RunMetadata::new("fa-hexa", "pid6", 0)).unwrap();
    let ch = rec.channel::<Sample>("/test").unwrap();
    for (t_s, v) in [(2.0, 20.0), (0.0, 0.0), (1.0, 5.0), (1.0, 10.0)] {
        rec.log(&ch, (t_s * 1e9) as u64, &Sample { value_m: v })
            .unwrap();
    }
    rec.finish().unwrap();
    let log = read_flight_log(&path, false).unwrap();
    let path = signals::parse_signal_path("/test.value_m", ["/test"]).unwrap();
    let s = signals::extract(&log.recording, "shuffled.mcap", &path).unwrap();
    assert_eq!(s.times_s, [0.0, 1.0, 1.0, 2.0]);
    assert_eq!(s.values, [0.0, 5.0, 10.0, 20.0]);
    // At t = 1 s: the later of the two samples; between 1 and 2 s: from it to 20.
    assert_eq!(compare::interpolate(&s, 1.0), Some(10.0));
    assert_eq!(compare::interpolate(&s, 1.5), Some(15.0));
    assert_eq!(compare::interpolate(&s, 0.5), Some(2.5));
    assert_eq!(compare::interpolate(&s, 2.0), Some(20.0));
    assert_eq!(compare::interpolate(&s, 2.0 + 1e-9), None);
    assert_eq!(compare::interpolate(&s, -1e-9), None);
}

#[test]
fn a_non_finite_logged_command_is_refused_in_commands_mode_only() {
    let dir = tempfile::tempdir().unwrap();
    let log = twin_flight(dir.path(), "flight.mcap", "none", Interface::BaseJoint);
    let mut file = read_flight_log(&log, false).unwrap();
    // The 4th /rotors message's first command becomes null (a NaN as JSON writes it).
    let m = file
        .recording
        .messages
        .iter_mut()
        .filter(|m| m.topic == "/rotors")
        .nth(3)
        .unwrap();
    let mut value: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
    value["commanded_n"][0] = serde_json::Value::Null;
    m.data = serde_json::to_vec(&value).unwrap();
    let logged = LoggedFlight::from_log(&file).unwrap();
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut config = ReplayConfig {
        controller: logged.controller_config(&vehicle).unwrap(),
        twin: logged.twin_config().unwrap(),
        vehicle,
        mode: ReplayMode::Reference,
        out: dir.path().join("out.mcap"),
    };
    assert!(check_replay(&logged, &config).is_ok());
    config.mode = ReplayMode::Commands;
    let err = check_replay(&logged, &config).unwrap_err().to_string();
    assert!(
        err.contains("flight.mcap")
            && err.contains("/rotors message 3")
            && err.contains("not a number"),
        "{err}"
    );
}

/// Writes a log at 100 Hz with `/rotors.realised_n` = `thrusts[k]` and `/control/wrench`
/// whose unallocated force x is `unallocated[k]`.
fn rotor_log(dir: &Path, thrusts: &[[f64; 2]], unallocated: &[f64]) -> FlightLogFile {
    use crate::flight_log::{BodyWrench, Rotors};
    let path = dir.join("rotors.mcap");
    let mut rec = McapRecorder::create(&path, &RunMetadata::new("fa-hexa", "pid6", 0)).unwrap();
    let rotors = rec.channel::<Rotors>("/rotors").unwrap();
    let wrench = rec.channel::<BodyWrench>("/control/wrench").unwrap();
    for (k, (t, u)) in thrusts.iter().zip(unallocated).enumerate() {
        let ns = k as u64 * 10_000_000;
        let m = Rotors {
            commanded_n: t.to_vec(),
            realised_n: t.to_vec(),
            applied_n: t.to_vec(),
            saturated: false,
        };
        rec.log(&rotors, ns, &m).unwrap();
        let w = BodyWrench {
            force_n: [0.0; 3],
            torque_nm: [0.0; 3],
            unallocated_force_n: [*u, 0.0, 0.0],
            unallocated_torque_nm: [0.0; 3],
        };
        rec.log(&wrench, ns, &w).unwrap();
    }
    rec.finish().unwrap();
    read_flight_log(&path, false).unwrap()
}

#[test]
fn rotor_saturation_names_the_rotor_the_limit_the_time_and_the_longest_stretch() {
    // Limits 0..23 N, ticks every 10 ms. Rotor 0: 23 N (within the 1e-5 N tolerance) at
    // ticks 3, 4, 5, idle (0 N) at tick 8, else 10 N → first at max 0.03 s, first at min
    // 0.08 s, 4 of 10 ticks at a limit, longest stretch ticks 3..5 = 3 ticks = 0.03 s.
    // Rotor 1: 12 N then 22.9 N, never at a limit. The allocator falls short from tick 4.
    let dir = tempfile::tempdir().unwrap();
    let mut thrusts = [[10.0, 12.0]; 10];
    for t in &mut thrusts[3..=5] {
        t[0] = 23.0 - 0.5e-5;
    }
    thrusts[8][0] = 0.0;
    thrusts[9][1] = 22.9;
    let unallocated = [0.0, 0.0, 0.0, 1e-12, 0.4, 0.2, 0.0, 0.0, 0.0, 0.0];
    let log = rotor_log(dir.path(), &thrusts, &unallocated);
    let s = rotor_saturation(&log, 0.0, 23.0).unwrap();
    assert_eq!(s.ticks, 10);
    assert_eq!(s.rotors.len(), 2);
    let r0 = &s.rotors[0];
    assert!(close(r0.first_at_max_s, 0.03, EXACT), "{r0:?}");
    assert!(close(r0.first_at_min_s, 0.08, EXACT), "{r0:?}");
    assert_eq!((r0.ticks_at_max, r0.ticks_at_min), (3, 1));
    assert!((r0.share_at_limit - 0.4).abs() < EXACT, "{r0:?}");
    assert!((r0.longest_at_limit_s - 0.03).abs() < EXACT, "{r0:?}");
    assert!((r0.max_thrust_n - (23.0 - 0.5e-5)).abs() < EXACT, "{r0:?}");
    let r1 = &s.rotors[1];
    assert_eq!((r1.first_at_max_s, r1.first_at_min_s), (None, None));
    assert_eq!(r1.share_at_limit, 0.0);
    assert!((r1.max_thrust_n - 22.9).abs() < EXACT, "{r1:?}");
    assert_eq!(s.saturated_rotors(), vec![0]);
    // 1e-12 N is round-off, not a shortfall.
    assert!(close(s.first_unallocated_s, 0.04, EXACT), "{s:?}");
}
