//! Whole flight stacks in the twin: controller → allocation → rapier, scored as
//! `amstack track` scores them, and their MCAP logs read back by an independent reader.

use controllers::{ControllerKind, profile};
use platform::Vehicle;
use policy_runtime::record::Recording;
use policy_runtime::{
    EstimatorSettings, Interface, StateSource, TrackConfig, TrackResult, Trajectory, run_track,
};
use sim_twin::{Disturbances, MotorConfig, TwinConfig};

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"))
}

fn flight(
    id: &str,
    kind: ControllerKind,
    trajectory: Trajectory,
    duration_s: f64,
    twin: TwinConfig,
) -> TrackConfig {
    let v = vehicle(id);
    let controller = profile(&v, kind).unwrap_or_else(|e| panic!("{id}: {e}"));
    TrackConfig {
        live: None,
        cameras: None,
        vehicle: v,
        controller,
        trajectory,
        interface: Interface::BaseJoint,
        duration_s,
        settle_s: 2.0,
        twin,
        mcap: None,
        state_source: StateSource::Truth,
        clock: None,
    }
}

fn fly(config: &TrackConfig) -> TrackResult {
    run_track(config, |_| std::ops::ControlFlow::Continue(()))
        .unwrap_or_else(|e| panic!("{} {}: {e}", config.vehicle.id, config.trajectory.name()))
}

#[test]
fn every_vehicle_hovers_within_a_centimetre() {
    // AM-Bench's control pairs: PID everywhere, L1 where the vehicle is fully actuated.
    let pairs = [
        ("ua-quad", ControllerKind::Pid),
        ("ua-hexa", ControllerKind::Pid),
        ("fa-hexa", ControllerKind::Pid),
        ("fa-hexa", ControllerKind::L1),
        ("omni-hexa", ControllerKind::Pid),
        ("omni-hexa", ControllerKind::L1),
        ("ee-only", ControllerKind::Pid),
        ("ee-only", ControllerKind::L1),
    ];
    for (id, kind) in pairs {
        let r = fly(&flight(
            id,
            kind,
            Trajectory::Hover,
            10.0,
            TwinConfig::default(),
        ));
        assert!(
            r.ee_pos_rmse_m < 0.01,
            "{id} {kind:?}: EE RMS {} m",
            r.ee_pos_rmse_m
        );
        // The same hover asked for as an end-effector target, through whole-body IK.
        let mut ee = flight(id, kind, Trajectory::Hover, 4.0, TwinConfig::default());
        ee.interface = Interface::Ee;
        let through_ik = fly(&ee);
        assert!(
            through_ik.ee_pos_rmse_m < 0.01,
            "{id} {kind:?} through IK: EE RMS {} m",
            through_ik.ee_pos_rmse_m
        );
        assert!(
            r.tilt_use_rad < 0.01,
            "{id} {kind:?}: tilt {} rad",
            r.tilt_use_rad
        );
        // Hover needs no rotor near its 23 N limit (AMBENCH_SPEC §2.10: 5.5–12.5 N).
        if let Some(peak) = r.max_rotor_thrust_n {
            assert!(peak < 23.0, "{id}: {peak} N");
        }
    }
}

#[test]
fn fa_hexa_holds_its_attitude_while_the_arm_sweeps_its_range() {
    let r = fly(&flight(
        "fa-hexa",
        ControllerKind::Pid,
        Trajectory::ArmSweep,
        16.0,
        TwinConfig::default(),
    ));
    // The arm's 0.9 kg swings ±0.4 m: the base stays within a degree and its EE tracks to
    // a centimetre.
    assert!(
        r.tilt_use_rad < 1f64.to_radians(),
        "tilt {}°",
        r.tilt_use_rad.to_degrees()
    );
    assert!(r.ee_pos_rmse_m < 0.01, "EE RMS {} m", r.ee_pos_rmse_m);
    assert!(
        r.base_pos_rmse_m < 0.005,
        "base RMS {} m",
        r.base_pos_rmse_m
    );
}

#[test]
fn paper_actuator_experiment_has_the_papers_shape() {
    // FA-Hexa on the high-frequency vertical sines, four motor models (the paper's
    // "Actuator Dynamics Identification" table): the lag raises the error, the rate limit
    // barely changes it, no rotor reaches its 23 N limit.
    let run = |tau: Option<f64>, rate: Option<f64>| {
        let twin = TwinConfig {
            disturbances: Disturbances {
                saturation: true,
                ..Disturbances::default()
            },
            motor: MotorConfig {
                time_constant_s: tau,
                rate_limit_per_s: rate,
            },
            ..TwinConfig::default()
        };
        fly(&flight(
            "fa-hexa",
            ControllerKind::Pid,
            Trajectory::SinesHigh,
            20.0,
            twin,
        ))
    };
    let none = run(None, None);
    let lag = run(Some(0.0475), None);
    let rate = run(None, Some(0.75));
    let both = run(Some(0.0475), Some(0.75));
    assert!(
        lag.base_z_rmse_m > 1.1 * none.base_z_rmse_m,
        "lag {} vs none {}",
        lag.base_z_rmse_m,
        none.base_z_rmse_m
    );
    assert!(
        (rate.base_z_rmse_m / none.base_z_rmse_m - 1.0).abs() < 0.05,
        "rate {} vs none {}",
        rate.base_z_rmse_m,
        none.base_z_rmse_m
    );
    assert!(
        (both.base_z_rmse_m / lag.base_z_rmse_m - 1.0).abs() < 0.05,
        "both {} vs lag {}",
        both.base_z_rmse_m,
        lag.base_z_rmse_m
    );
    for r in [&none, &lag, &rate, &both] {
        assert!(
            r.max_rotor_thrust_n.is_some_and(|t| t < 23.0),
            "{:?}",
            r.max_rotor_thrust_n
        );
    }
}

/// A noisy FA-Hexa flight with every disturbance on, logged to `path`.
fn logged_flight(path: &std::path::Path) -> TrackResult {
    let twin = TwinConfig {
        disturbances: Disturbances::all(),
        seed: 42,
        ..TwinConfig::default()
    };
    let mut config = flight("fa-hexa", ControllerKind::L1, Trajectory::Step, 3.0, twin);
    config.mcap = Some(path.to_path_buf());
    fly(&config)
}

#[test]
fn same_seed_same_results_and_same_log_payloads() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let (a_path, b_path) = (dir.path().join("a.mcap"), dir.path().join("b.mcap"));
    let mut a = logged_flight(&a_path);
    let mut b = logged_flight(&b_path);
    for r in [&mut a, &mut b] {
        r.wall_time_s = 0.0;
        r.ticks_per_second = 0.0;
        r.mcap = None;
    }
    assert_eq!(a, b);
    let read = |p: &std::path::Path| {
        Recording::from_bytes(&std::fs::read(p).unwrap_or_default())
            .unwrap_or_else(|e| panic!("{e}"))
    };
    let (ra, rb) = (read(&a_path), read(&b_path));
    assert!(ra.complete && rb.complete);
    assert_eq!(ra.messages.len(), rb.messages.len());
    assert!(
        ra.messages.iter().zip(&rb.messages).all(|(x, y)| x == y),
        "message payloads differ"
    );
}

/// FA-Hexa, PID6, hover and the 1 m step, flown twice each: on the twin's measurement and on
/// the estimator fed by the default simulated sensors (a 120 Hz IMU with noise and turn-on
/// biases drawn from the seed; 60 Hz motion capture, σ = 2 mm / 0.005 rad, 20 ms latency).
///
/// Bound: the controllers track the estimate, so the true base error is the tracking error
/// of the estimate plus the estimate's own error. The estimate must stay below the pose
/// sensor's σ_p = 2 mm RMS (what the estimator tests show on an analytic trajectory), and the
/// base position RMSE of the estimator-fed flight within 3 mm (1.5 σ_p: the estimate's error
/// and the controller's response to it) of the truth-fed flight's. The filter must be
/// consistent (mean NIS of the poses within [4, 8]; 6 expected) and refuse nothing. Its log
/// carries one `/estimator/state` per measurement the controllers acted on.
#[test]
fn fa_hexa_flies_on_the_estimator_within_3_mm_of_the_truth_fed_flight() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    for trajectory in [Trajectory::Hover, Trajectory::Step] {
        let truth = fly(&flight(
            "fa-hexa",
            ControllerKind::Pid,
            trajectory,
            8.0,
            TwinConfig::default(),
        ));
        let mut config = flight(
            "fa-hexa",
            ControllerKind::Pid,
            trajectory,
            8.0,
            TwinConfig::default(),
        );
        config.state_source = StateSource::Estimator(EstimatorSettings::default());
        let path = dir.path().join(format!("{}.mcap", trajectory.name()));
        config.mcap = Some(path.clone());
        let est = fly(&config);
        if trajectory == Trajectory::Hover {
            // Same seed, same sensor draws, same flight.
            let mut again = config.clone();
            again.mcap = None;
            let strip = |mut r: TrackResult| {
                r.wall_time_s = 0.0;
                r.ticks_per_second = 0.0;
                r.mcap = None;
                r
            };
            assert_eq!(strip(fly(&again)), strip(est.clone()));
        }
        let summary = est
            .estimator
            .unwrap_or_else(|| panic!("no estimator summary"));
        eprintln!(
            "{}: base RMSE truth-fed {:.3} mm, estimator-fed {:.3} mm; estimate RMSE {:.3} mm, mean NIS {:.2}",
            trajectory.name(),
            truth.base_pos_rmse_m * 1e3,
            est.base_pos_rmse_m * 1e3,
            summary.position_rmse_m * 1e3,
            summary.mean_nis
        );
        assert!(truth.estimator.is_none() && truth.state_source == "truth");
        assert_eq!(est.state_source, "estimator");
        assert!(summary.position_rmse_m < 0.002, "{summary:?}");
        assert!(
            est.base_pos_rmse_m < truth.base_pos_rmse_m + 0.003,
            "{}: {} m on the estimator, {} m on the truth",
            trajectory.name(),
            est.base_pos_rmse_m,
            truth.base_pos_rmse_m
        );
        assert!((4.0..8.0).contains(&summary.mean_nis), "{summary:?}");
        assert_eq!(summary.rejected, 0);
        // 60 Hz over 8 s, less the captures still in flight at the end.
        assert!((470..=481).contains(&summary.fused), "{summary:?}");
        let log = Recording::from_bytes(&std::fs::read(&path).unwrap_or_default())
            .unwrap_or_else(|e| panic!("{e}"));
        let estimates: Vec<serde_json::Value> = log
            .messages
            .iter()
            .filter(|m| m.topic == "/estimator/state")
            .map(|m| serde_json::from_slice(&m.data).unwrap_or_else(|e| panic!("{e}")))
            .collect();
        assert_eq!(estimates.len() as u64, est.ticks + 1);
        assert_eq!(
            log.messages
                .iter()
                .find(|m| m.topic == "/estimator/state")
                .and_then(|m| m.schema_name.clone()),
            Some("amstack.EstimatorState".to_owned())
        );
        let fused: usize = estimates
            .iter()
            .map(|e| e["innovations"].as_array().map_or(0, Vec::len))
            .sum();
        assert_eq!(fused as u64, summary.fused);
    }
}

#[test]
fn flight_logs_read_back_by_the_python_mcap_reader() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let path = dir.path().join("flight.mcap");
    let r = logged_flight(&path);
    let ticks = r.ticks.to_string();
    let per_tick = [
        "/tf",
        "/base/pose",
        "/ee/pose",
        "/base/reference",
        "/ee/reference",
        "/base/state",
        "/control/wrench",
        "/joints",
        "/controller/status",
        "/rotors",
        "/disturbances",
    ];
    let expectations: Vec<String> = per_tick.iter().map(|t| format!("{t}={ticks}")).collect();
    let mut args: Vec<&str> = vec!["--require-complete"];
    for e in &expectations {
        args.extend(["--expect", e.as_str()]);
    }
    let (code, report) = tests::mcap_check(&path, &args);
    assert_eq!(code, 0, "{report:#}");
    let schema = |topic: &str| {
        report["channels"]
            .as_array()
            .and_then(|cs| cs.iter().find(|c| c["topic"] == topic))
            .map(|c| c["schema_name"].clone())
    };
    assert_eq!(schema("/base/pose"), Some("foxglove.PoseInFrame".into()));
    assert_eq!(schema("/tf"), Some("foxglove.FrameTransforms".into()));
    assert_eq!(schema("/rotors"), Some("amstack.Rotors".into()));
    let run = &report["metadata"][0];
    assert_eq!(run["name"], "amstack.run");
    assert_eq!(run["metadata"]["vehicle_id"], "fa-hexa");
    assert_eq!(run["metadata"]["seed"], "42");
}

fn bench(
    id: &str,
    kind: ControllerKind,
    tasks: Vec<sim_twin::TaskId>,
    rollouts: usize,
) -> policy_runtime::bench::BenchReport {
    let v = vehicle(id);
    let config = policy_runtime::bench::BenchConfig {
        live: None,
        cameras: None,
        controller: profile(&v, kind).unwrap_or_else(|e| panic!("{id}: {e}")),
        controller_name: "test".to_owned(),
        vehicle: v,
        interface: Interface::Ee,
        tasks,
        rollouts,
        seed: 0,
        twin: TwinConfig::default(),
        jobs: std::thread::available_parallelism().map_or(1, |n| n.get()),
        episode: policy_runtime::bench::EpisodeLength::Script,
        mcap_dir: None,
        link: policy_runtime::bench::BenchLink::InProcess,
        state_source: StateSource::Truth,
        policy: None,
    };
    let stop = std::sync::atomic::AtomicBool::new(false);
    policy_runtime::bench::run_bench(&config, &|_| {}, &stop).unwrap_or_else(|e| panic!("{e}"))
}

/// The scripted demonstrations are the benchmark's training data: with the EE-only oracle
/// every task's script succeeds (30 rollouts per task: `amstack bench --rollouts 30`; here
/// seeds 0–2 of each), Toss Ball with its aimed throw (a departure from the reference
/// script, whose throw ignores the container's x).
#[test]
fn the_oracle_completes_every_task_with_its_scripted_policy() {
    use sim_twin::TaskId;
    let report = bench("ee-only", ControllerKind::Pid, TaskId::ALL.to_vec(), 3);
    let failed: Vec<String> = report
        .tasks
        .iter()
        .flat_map(|t| t.rollouts.iter())
        .filter(|r| !r.success)
        .map(|r| format!("{} seed {} ({:?})", r.task, r.seed, r.termination))
        .collect();
    assert!(failed.is_empty(), "failed rollouts: {failed:?}");
    for t in &report.tasks {
        if let Some(c) = t.summary.subtask_completion {
            assert!(
                (c - 1.0).abs() < 1e-12,
                "{}: a success completes its subtasks ({c})",
                t.task
            );
        }
    }
}

/// The FA-Hexa with IK-PID flies the wall tasks through the whole stack (allocation,
/// ideal rotors) and its metrics are defined: normalised errors small against the reach.
#[test]
fn fa_hexa_presses_the_button_and_pushes_the_slider_through_ik_pid() {
    use sim_twin::TaskId;
    let report = bench(
        "fa-hexa",
        ControllerKind::Pid,
        vec![TaskId::PressButton, TaskId::PushSlider],
        2,
    );
    for t in &report.tasks {
        assert_eq!(t.summary.success_rate, 1.0, "{}", t.task);
        let e = t.summary.norm_ee_error.mean.unwrap_or(f64::NAN);
        assert!(e > 0.0 && e < 0.02, "{}: normalised EE error {e}", t.task);
        assert!(
            t.summary.saturation_rate.mean.is_some(),
            "{}: rotors, so a rate",
            t.task
        );
    }
}

/// A rollout with the EE and base cameras (visual DR on) logs them as PNG that the independent
/// Python reader decodes at the cameras' 384×384, every 50th observation; the same seed logs
/// the same bytes; the flight itself is the one flown without cameras.
#[test]
fn rollout_camera_images_decode_at_their_size_and_repeat_with_the_seed() {
    use policy_runtime::flight::{CameraConfig, CameraRig, select_cameras};
    use sim_twin::TaskId;
    let v = vehicle("fa-hexa");
    let cameras = select_cameras(&v, &["ee", "base"]).unwrap_or_else(|e| panic!("{e}"));
    match CameraRig::new(&v, &cameras, render::VisualDr::On) {
        Err(render::RenderError::NoAdapter(reason)) => {
            eprintln!("SKIPPED: no graphics adapter on this machine ({reason})");
            return;
        }
        Err(e) => panic!("{e}"),
        Ok(_) => {}
    }
    const EVERY: u64 = 50;
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let rollout = |name: &str, with_cameras: bool| {
        let config = policy_runtime::bench::BenchConfig {
            live: None,
            policy: None,
            cameras: with_cameras.then(|| CameraConfig {
                cameras: cameras.clone(),
                visual_dr: render::VisualDr::On,
                log_every: EVERY,
                video: None,
            }),
            controller: profile(&v, ControllerKind::Pid).unwrap_or_else(|e| panic!("{e}")),
            controller_name: "test".to_owned(),
            vehicle: v.clone(),
            interface: Interface::Ee,
            tasks: vec![TaskId::PressButton],
            rollouts: 1,
            seed: 5,
            twin: TwinConfig::default(),
            jobs: 1,
            episode: policy_runtime::bench::EpisodeLength::Script,
            mcap_dir: Some(dir.path().join(name)),
            link: policy_runtime::bench::BenchLink::InProcess,
            state_source: StateSource::Truth,
        };
        std::fs::create_dir_all(dir.path().join(name).join(TaskId::PressButton.name()))
            .unwrap_or_else(|e| panic!("{e}"));
        let stop = std::sync::atomic::AtomicBool::new(false);
        policy_runtime::bench::run_rollout(&config, TaskId::PressButton, 0, &stop)
            .unwrap_or_else(|e| panic!("{e}"))
    };
    let first = rollout("first", true);
    let second = rollout("second", true);
    let plain = rollout("plain", false);
    assert!(first.success, "{:?}", first.termination);
    assert_eq!(first.executed_steps, plain.executed_steps);
    let summary = |r: &policy_runtime::bench::RolloutResult| {
        serde_json::to_string(&r.summary).unwrap_or_default()
    };
    assert_eq!(summary(&first), summary(&plain), "cameras change no result");
    let images = (first.executed_steps - 1) / EVERY + 1;
    let mut digests = Vec::new();
    for r in [&first, &second] {
        let path = r.mcap.clone().unwrap_or_default();
        let (code, report) = tests::mcap_check(&path, &["--require-complete"]);
        assert_eq!(code, 0, "{report:#}");
        for topic in ["/camera/ee_camera/image", "/camera/base_camera/image"] {
            let entry = &report["images"][topic];
            assert_eq!(entry["count"], images, "{topic}: {entry}");
            assert_eq!(entry["format"], "png", "{topic}");
            assert_eq!(
                (entry["width"].clone(), entry["height"].clone()),
                (384.into(), 384.into())
            );
            digests.push(entry["sha256"].clone());
        }
        let count = |topic: &str| {
            report["channels"]
                .as_array()
                .and_then(|cs| cs.iter().find(|c| c["topic"] == topic))
                .map(|c| c["count"].clone())
        };
        assert_eq!(count("/camera/ee_camera/calibration"), Some(images.into()));
        assert_eq!(count("/camera/tf"), Some(images.into()));
        // The Foxglove SDK's protobuf types, decoded by the class built from each channel's
        // own schema record (the 3D scene's encoding, on the same timeline).
        for (topic, schema) in [
            ("/camera/ee_camera/image", "foxglove.CompressedImage"),
            (
                "/camera/ee_camera/calibration",
                "foxglove.CameraCalibration",
            ),
            ("/camera/tf", "foxglove.FrameTransforms"),
        ] {
            let c = report["channels"]
                .as_array()
                .and_then(|cs| cs.iter().find(|c| c["topic"] == topic))
                .cloned()
                .unwrap_or_default();
            assert_eq!(c["schema_name"], schema, "{c}");
            assert_eq!(c["schema_encoding"], "protobuf", "{c}");
            assert_eq!(c["message_encoding"], "protobuf", "{c}");
            assert_eq!(report["decoded"][topic]["count"], images, "{topic}");
        }
        let frames = report["decoded"]["/camera/tf"]["frames"].clone();
        assert_eq!(
            frames,
            serde_json::json!(["world->ee_camera", "world->base_camera"])
        );
        let version = report["metadata"]
            .as_array()
            .and_then(|m| m.iter().find(|m| m["name"] == "amstack.run"))
            .map(|m| m["metadata"]["log_format_version"].clone());
        assert_eq!(version, Some("2".into()), "camera channels changed in 2");
    }
    assert_eq!(
        digests[0], digests[2],
        "EE camera: same seed, same PNG bytes"
    );
    assert_eq!(
        digests[1], digests[3],
        "base camera: same seed, same PNG bytes"
    );
    assert_ne!(
        digests[0], digests[1],
        "the two cameras see different things"
    );
    let ee = digests[0].as_array().cloned().unwrap_or_default();
    assert!(
        ee.first() != ee.last(),
        "the EE camera's view changes over the flight"
    );
}
