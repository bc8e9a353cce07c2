//! `amstack track`: fly a reference in the twin, print and save its scores.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Result;
use comfy_table::{Table, presets};
use controllers::{ControllerConfig, ControllerKind, profile};
use policy_runtime::LinkError;
use policy_runtime::bench::{
    BenchConfig, BenchError, BenchLink, EpisodeLength, Termination, run_rollout_logged,
};
use policy_runtime::live::LiveServer;
use policy_runtime::{
    EstimatorSettings, Interface, StateSource, TrackConfig, TrackResult, Trajectory, run_track,
};

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};
use crate::twin_flags::{SceneFlag, TwinFlags};
use crate::vehicles::find_vehicle;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Trajectories (all start hovering at (0, 0, 1) m):
  hover         hold 1 m
  step          a 1 m step along world x at t = 1 s
  sines-low     base z = 1 m + four 1 cm sines over 0.18-0.71 Hz
  sines-high    the same over 0.25-1.50 Hz
  ground-sweep  end-effector z = 0.8 + 0.2 cos(2 pi t / 30) m (the paper's ground-effect run)
  arm-sweep     hover while every arm joint sweeps its range
  scripted      the --task's scripted policy: one benchmark rollout at --seed (its result
                is bench's for that seed); --duration caps the episode

Errors are scored after the settling time; the maximum rotor thrust covers the whole flight.
The paper's actuator experiment, for example:
  amstack track --platform fa-hexa --trajectory sines-high --disturbances saturation --motor-tau 0.0475
  amstack track --platform fa-hexa --trajectory ground-sweep --interface ee --disturbances ground --mcap sweep.mcap")]
pub struct Args {
    /// Vehicle id (ua-quad, ua-hexa, fa-hexa, omni-hexa, ee-only, or one added with --vehicle).
    #[arg(long, default_value = "fa-hexa")]
    platform: String,
    /// Controller: pid (PID6, or PID4 on under-actuated vehicles), l1, or mpc (the FA-Hexa's
    /// whole-body MPC; it flies the end-effector interface, --interface ee).
    #[arg(long, default_value = "pid", value_parser = ["pid", "l1", "mpc"])]
    controller: String,
    /// Reference to fly.
    #[arg(long, default_value = "hover")]
    trajectory: String,
    /// Action interface: base-joint (base pose + arm joints to the controller) or ee (the
    /// end-effector pose through whole-body IK, as the paper's ground-effect run).
    #[arg(long, default_value = "base-joint", value_parser = ["base-joint", "ee"])]
    interface: String,
    /// Flight length, s [default: hover, step 10; sines 30; ground-sweep 60; arm-sweep 16].
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    /// Start transient excluded from the error metrics, s.
    #[arg(long, value_name = "S", default_value_t = 2.0)]
    settle: f64,
    /// Wrench-space limit of the PID controller: largest norm of its force, N (gravity
    /// compensation included; default none, as the reference).
    #[arg(long, value_name = "N")]
    max_force: Option<f64>,
    /// Wrench-space limit of the PID controller: largest norm of its torque, N·m.
    #[arg(long, value_name = "NM")]
    max_torque: Option<f64>,
    #[command(flatten)]
    twin: TwinFlags,
    #[command(flatten)]
    scene: SceneFlag,
    #[command(flatten)]
    state: StateFlags,
    #[command(flatten)]
    pub(crate) policy: crate::policy_flags::PolicyFlags,
    #[command(flatten)]
    cameras: crate::camera_flags::CameraFlags,
    /// Write an MP4 of the flight: the scene camera (with the EE camera beside it when
    /// --cameras names ee), 30 fps from every 4th step. Needs the ffmpeg program (apt-get
    /// install ffmpeg, or AMSTACK_FFMPEG=PATH).
    #[arg(long, value_name = "FILE.mp4")]
    video: Option<PathBuf>,
    /// Write the scores as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write the flight log as MCAP.
    #[arg(long, value_name = "FILE")]
    mcap: Option<PathBuf>,
    /// Stream the flight log's channels live (the 3D scene, transforms, every amstack
    /// channel) over the Foxglove WebSocket protocol: open Foxglove, "Open connection",
    /// ws://ADDR. ADDR is IP:PORT [default: 127.0.0.1:8765]. The flight never waits for a
    /// viewer: a full queue drops messages and counts them (printed at the end).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = policy_runtime::live::DEFAULT_LIVE_ADDR)]
    live: Option<String>,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
}

/// Where the controllers' base state comes from, and the simulated sensors of the estimator.
#[derive(Debug, Clone, clap::Args)]
#[command(next_help_heading = "State source")]
pub struct StateFlags {
    /// `truth`: the controllers fly on the twin's measurement; `estimator`: on the EKF fed by
    /// a simulated IMU (at the control rate) and pose sensor (motion capture).
    #[arg(long, value_name = "SOURCE", default_value = "truth", value_parser = ["truth", "estimator"])]
    state_source: String,
    /// The sensors and the filter from a TOML file with `[imu]`, `[pose]`, `[estimator]`
    /// sections (any subset of fields; the flags below override it).
    #[arg(long, value_name = "FILE.toml")]
    sensors: Option<PathBuf>,
    /// Pose sensor rate, Hz [default: 60].
    #[arg(long, value_name = "HZ")]
    pose_rate: Option<f64>,
    /// Pose sensor latency (capture → arrival), s [default: 0.02].
    #[arg(long, value_name = "S")]
    pose_latency: Option<f64>,
    /// Pose position noise, standard deviation per axis, m [default: 0.002].
    #[arg(long, value_name = "M")]
    pose_position_std: Option<f64>,
    /// Pose attitude noise, standard deviation per axis, rad [default: 0.005].
    #[arg(long, value_name = "RAD")]
    pose_attitude_std: Option<f64>,
    /// Accelerometer white-noise density, m/s²/√Hz [default: 0.002].
    #[arg(long, value_name = "D")]
    imu_accel_noise: Option<f64>,
    /// Gyroscope white-noise density, rad/s/√Hz [default: 0.0005].
    #[arg(long, value_name = "D")]
    imu_gyro_noise: Option<f64>,
    /// Accelerometer turn-on bias, standard deviation per axis, m/s² [default: 0.05].
    #[arg(long, value_name = "B")]
    imu_accel_bias_std: Option<f64>,
    /// Gyroscope turn-on bias, standard deviation per axis, rad/s [default: 0.005].
    #[arg(long, value_name = "B")]
    imu_gyro_bias_std: Option<f64>,
}

impl StateFlags {
    /// The state source; a bad file or value is bad input naming it.
    pub fn state_source(&self) -> Result<StateSource> {
        let sensor_flags = [
            ("--sensors", self.sensors.is_some()),
            ("--pose-rate", self.pose_rate.is_some()),
            ("--pose-latency", self.pose_latency.is_some()),
            ("--pose-position-std", self.pose_position_std.is_some()),
            ("--pose-attitude-std", self.pose_attitude_std.is_some()),
            ("--imu-accel-noise", self.imu_accel_noise.is_some()),
            ("--imu-gyro-noise", self.imu_gyro_noise.is_some()),
            ("--imu-accel-bias-std", self.imu_accel_bias_std.is_some()),
            ("--imu-gyro-bias-std", self.imu_gyro_bias_std.is_some()),
        ];
        if self.state_source == "truth" {
            if let Some((flag, _)) = sensor_flags.iter().find(|(_, set)| *set) {
                return Err(bad_input(format!(
                    "{flag}: the simulated sensors need --state-source estimator"
                )));
            }
            return Ok(StateSource::Truth);
        }
        let mut settings = match &self.sensors {
            None => EstimatorSettings::default(),
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .map_err(|e| bad_input(format!("--sensors {}: {e}", path.display())))?;
                toml::from_str(&text).map_err(|e| {
                    bad_input(format!(
                        "{}: {}",
                        path.display(),
                        e.to_string().lines().collect::<Vec<_>>().join(" ")
                    ))
                })?
            }
        };
        let set = |target: &mut f64, value: Option<f64>| {
            if let Some(v) = value {
                *target = v;
            }
        };
        set(&mut settings.pose.rate_hz, self.pose_rate);
        set(&mut settings.pose.latency_s, self.pose_latency);
        set(&mut settings.pose.position_std_m, self.pose_position_std);
        set(&mut settings.pose.attitude_std_rad, self.pose_attitude_std);
        set(
            &mut settings.imu.accel_noise_mps2_per_sqrt_hz,
            self.imu_accel_noise,
        );
        set(
            &mut settings.imu.gyro_noise_radps_per_sqrt_hz,
            self.imu_gyro_noise,
        );
        set(
            &mut settings.imu.accel_bias_std_mps2,
            self.imu_accel_bias_std,
        );
        set(
            &mut settings.imu.gyro_bias_std_radps,
            self.imu_gyro_bias_std,
        );
        settings.validate().map_err(|e| {
            let source = self
                .sensors
                .as_ref()
                .map_or_else(|| "sensors".to_owned(), |p| p.display().to_string());
            bad_input(format!("{source}: {e}"))
        })?;
        Ok(StateSource::Estimator(settings))
    }
}

impl Args {
    /// The `--controller` flag.
    pub(crate) fn controller_name(&self) -> &str {
        &self.controller
    }
}

/// The controller of `--controller`, with `--max-force`/`--max-torque`.
fn controller_config(args: &Args, vehicle: &platform::Vehicle) -> Result<ControllerConfig> {
    let kind = match args.controller.as_str() {
        "l1" => ControllerKind::L1,
        "mpc" => ControllerKind::Mpc,
        _ => ControllerKind::Pid,
    };
    let mut controller = profile(vehicle, kind)
        .map_err(|e| bad_input(format!("--controller {}: {e}", args.controller)))?;
    if args.max_force.is_some() || args.max_torque.is_some() {
        let (force, torque) = match &mut controller {
            ControllerConfig::Pid6(g) => (&mut g.max_force_n, &mut g.max_torque_nm),
            ControllerConfig::Pid4(g) => (&mut g.max_force_n, &mut g.max_torque_nm),
            _ => {
                return Err(bad_input(format!(
                    "--max-force/--max-torque: wrench limits are the PID controller's, not {}'s",
                    args.controller
                )));
            }
        };
        *force = args.max_force.or(*force);
        *torque = args.max_torque.or(*torque);
        controller
            .validate()
            .map_err(|e| bad_input(format!("--max-force/--max-torque: {e}")))?;
    }
    if kind == ControllerKind::Mpc && args.interface != "ee" {
        return Err(bad_input(
            "--controller mpc: the whole-body MPC tracks end-effector targets; add --interface ee",
        ));
    }
    Ok(controller)
}

fn config(args: &Args) -> Result<TrackConfig> {
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let trajectory: Trajectory = args
        .trajectory
        .parse()
        .map_err(|e| bad_input(format!("--trajectory: {e}")))?;
    let controller = controller_config(args, &vehicle)?;
    let mut twin = args.twin.twin_config()?;
    args.scene.apply(&mut twin)?;
    let duration_s = args
        .duration
        .unwrap_or_else(|| trajectory.default_duration_s());
    if !(duration_s.is_finite() && duration_s > 0.0) {
        return Err(bad_input(format!(
            "--duration {duration_s}: must be a positive number of seconds"
        )));
    }
    if !(args.settle.is_finite() && args.settle >= 0.0 && args.settle < duration_s) {
        return Err(bad_input(format!(
            "--settle {}: must be within [0, {duration_s}) s",
            args.settle
        )));
    }
    let state_source = args.state.state_source()?;
    let interface = if args.interface == "ee" {
        Interface::Ee
    } else {
        Interface::BaseJoint
    };
    if let Some(p) = &args.video {
        check_writable("--video", p)?;
    }
    let cameras = args.cameras.config(&vehicle, args.video.as_deref())?;
    let live = start_live(args.live.as_deref())?;
    Ok(TrackConfig {
        live,
        cameras,
        vehicle,
        controller,
        trajectory,
        interface,
        duration_s,
        settle_s: args.settle,
        twin,
        mcap: args.mcap.clone(),
        state_source,
        // In the twin the MPC's solves are not timed: results never depend on the wall clock.
        clock: None,
    })
}

/// Starts `--live ADDR`'s server (bad address: bad input), saying where it serves.
pub(crate) fn start_live(addr: Option<&str>) -> Result<Option<Arc<LiveServer>>> {
    let Some(text) = addr else {
        return Ok(None);
    };
    let addr = policy_runtime::live::parse_addr(text).map_err(|e| bad_input(e.to_string()))?;
    let server = LiveServer::start(addr)?;
    eprintln!(
        "live view: ws://{} (Foxglove: Open connection)",
        server.addr()
    );
    Ok(Some(Arc::new(server)))
}

/// Publishes what is queued, stops the live view and prints what it published and dropped.
pub(crate) fn finish_live(live: Option<&LiveServer>) {
    if let Some(live) = live {
        let stats = live.finish();
        eprintln!(
            "live view: {} messages published, {} dropped (queue full)",
            stats.published, stats.dropped
        );
    }
}

fn cell(x: Option<f64>, scale: f64, decimals: usize) -> String {
    x.filter(|v| v.is_finite())
        .map_or_else(|| "N/A".to_owned(), |v| format!("{:.decimals$}", v * scale))
}

pub fn run(args: &Args) -> Result<()> {
    if is_scripted(args) {
        return run_scripted(args, BenchLink::InProcess);
    }
    let config = prepare(args)?;
    run_with(args, &config, |config, progress| {
        Ok(run_track(config, progress)?)
    })
}

/// Checks that the result files can be written and builds the flight's configuration: the
/// bad-input errors, before anything is flown or printed.
pub(crate) fn prepare(args: &Args) -> Result<TrackConfig> {
    for (flag, path) in [("--json", &args.json), ("--mcap", &args.mcap)] {
        if let Some(p) = path {
            check_writable(flag, p)?;
        }
    }
    config(args)
}

/// One flight of `config` (from [`prepare`]) flown by `flight` — the in-process twin for
/// `amstack track`, any link for `amstack fly` — with everything around it: the banner,
/// Ctrl-C, the table and the JSON.
pub(crate) fn run_with(
    args: &Args,
    config: &TrackConfig,
    flight: impl FnOnce(&TrackConfig, &mut dyn FnMut(f64) -> ControlFlow<()>) -> Result<TrackResult>,
) -> Result<()> {
    eprintln!(
        "flying {} on {} ({}, {} interface) for {} s, disturbances: {}, state: {}",
        config.trajectory.name(),
        config.vehicle.id,
        config.controller.name(),
        config.interface.name(),
        config.duration_s,
        args.twin.disturbances,
        config.state_source.name()
    );
    let duration = config.duration_s;
    // Ctrl-C stops the flight at the next simulated second and closes the log properly.
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    // A second handler cannot be installed (only in tests calling run twice): keep going.
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let result = flight(config, &mut |t| {
        if t >= 5.0 && (t.round() as u64).is_multiple_of(5) {
            eprintln!("  t = {t:.0} / {duration} s");
        }
        if stop.load(Ordering::SeqCst) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    finish_live(config.live.as_deref());
    let result = result?;
    let mut table = Table::new();
    table
        .load_style(presets::ASCII_MARKDOWN)
        .set_header(["metric", "value"]);
    let r = &result;
    for (name, value) in [
        (
            "EE position RMSE (cm)",
            cell(Some(r.ee_pos_rmse_m), 100.0, 3),
        ),
        (
            "base position RMSE (cm)",
            cell(Some(r.base_pos_rmse_m), 100.0, 3),
        ),
        ("base z RMSE (cm)", cell(Some(r.base_z_rmse_m), 100.0, 3)),
        (
            "tilt use (deg)",
            cell(Some(r.tilt_use_rad), 180.0 / std::f64::consts::PI, 3),
        ),
        ("saturation rate (%)", cell(r.saturation_rate, 100.0, 2)),
        ("max rotor thrust (N)", cell(r.max_rotor_thrust_n, 1.0, 2)),
        ("scored after (s)", cell(Some(r.settle_s), 1.0, 1)),
        ("ticks per second", cell(Some(r.ticks_per_second), 1.0, 0)),
    ] {
        table.add_row([name.to_owned(), value]);
    }
    if let Some(e) = &r.estimator {
        for (name, value) in [
            ("estimator fed by (sensors)", e.sensors.to_owned()),
            (
                "estimate position RMSE (mm)",
                cell(Some(e.position_rmse_m), 1000.0, 3),
            ),
            (
                "estimate max position error (mm)",
                cell(Some(e.position_max_error_m), 1000.0, 3),
            ),
            (
                "estimator mean NIS (6 = consistent)",
                cell(Some(e.mean_nis), 1.0, 2),
            ),
            (
                "poses fused / inputs refused",
                format!("{} / {}", e.fused, e.rejected),
            ),
        ] {
            table.add_row([name.to_owned(), value]);
        }
    }
    println!("{table}");
    if let Some(path) = &args.json {
        write_json(path, &serde_json::to_value(&result)?)?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &result.mcap {
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &args.video {
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

impl Args {
    /// Whether the flight renders cameras (`--cameras`).
    pub(crate) fn wants_cameras(&self) -> bool {
        self.cameras.any() || self.video.is_some()
    }

    /// Whether the flight writes an MCAP log (`--mcap`).
    pub(crate) fn logs_mcap(&self) -> bool {
        self.mcap.is_some()
    }
}

/// Whether `--trajectory` asks for the task's scripted policy.
pub(crate) fn is_scripted(args: &Args) -> bool {
    args.trajectory == SCRIPTED || args.policy.policy.is_some()
}

/// `--trajectory scripted`.
const SCRIPTED: &str = "scripted";

/// `--trajectory scripted --task T`: one benchmark rollout of the task's scripted policy (seed
/// `--seed`, as `amstack bench --rollouts 1 --seed S` runs it) flown over `link`, with the
/// rollout's table and JSON. The interface and controller are track's (`--interface
/// base-joint` is the benchmark's `ik-` controllers).
pub(crate) fn run_scripted(args: &Args, link: BenchLink) -> Result<()> {
    for (flag, path) in [("--json", &args.json), ("--mcap", &args.mcap)] {
        if let Some(p) = path {
            check_writable(flag, p)?;
        }
    }
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let controller = controller_config(args, &vehicle)?;
    let mut twin = args.twin.twin_config()?;
    args.scene.apply(&mut twin)?;
    let Some(task) = twin.task else {
        return Err(bad_input(
            "--trajectory scripted and --policy: name the task to fly with --task (the names of \
             `amstack bench --help`)",
        ));
    };
    let state_source = args.state.state_source()?;
    let interface = if args.interface == "ee" {
        Interface::Ee
    } else {
        Interface::BaseJoint
    };
    if interface == Interface::BaseJoint && vehicle.ee_link == vehicle.base_link {
        return Err(bad_input(format!(
            "--interface base-joint: {} has no arm joints (use --interface ee)",
            vehicle.id
        )));
    }
    let episode = match args.duration {
        None => EpisodeLength::Script,
        Some(s) if s.is_finite() && s > 0.0 => EpisodeLength::Seconds(s),
        Some(s) => {
            return Err(bad_input(format!(
                "--duration {s}: must be a positive number of seconds"
            )));
        }
    };
    let controller_name = format!(
        "{}{}",
        if interface == Interface::BaseJoint {
            "ik-"
        } else {
            ""
        },
        args.controller
    );
    let link_name = link.name();
    let policy = args.policy.resolve(
        &vehicle,
        interface,
        twin.control_rate_hz,
        &args.cameras.names(),
    )?;
    if (args.cameras.any() || args.video.is_some()) && !matches!(link, BenchLink::InProcess) {
        return Err(bad_input(format!(
            "--cameras over {link_name}: the cameras are rendered from the twin in this process; fly with --link twin"
        )));
    }
    if let Some(p) = &args.video {
        check_writable("--video", p)?;
    }
    let cameras = args.cameras.config(&vehicle, args.video.as_deref())?;
    let config = BenchConfig {
        live: start_live(args.live.as_deref())?,
        cameras,
        vehicle,
        controller,
        controller_name,
        interface,
        tasks: vec![task],
        rollouts: 1,
        seed: twin.seed,
        twin,
        jobs: 1,
        episode,
        mcap_dir: None,
        link,
        state_source,
        policy,
    };
    eprintln!(
        "flying {}'s {} (seed {}) on {} ({}, {} interface) over {link_name}, \
         disturbances: {}",
        task.name(),
        config.policy.as_ref().map_or_else(
            || "scripted policy".to_owned(),
            |p| format!("policy {}", p.endpoint.describe())
        ),
        config.seed,
        config.vehicle.id,
        config.controller_name,
        config.interface.name(),
        args.twin.disturbances,
    );
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let r = run_rollout_logged(&config, task, 0, &stop, args.mcap.as_deref());
    finish_live(config.live.as_deref());
    let r = r.map_err(|e| {
        // A link that refuses this flight's configuration is bad input, one line (exit 2).
        match e {
            BenchError::Link(LinkError::Refused(_)) => bad_input(e.to_string()),
            e => anyhow::Error::new(e),
        }
    })?;
    let s = &r.summary;
    let mut table = Table::new();
    table
        .load_style(presets::ASCII_MARKDOWN)
        .set_header(["metric", "value"]);
    let success = if r.task_observed {
        if r.success { "yes" } else { "no" }.to_owned()
    } else {
        "not observed (the vehicle sends no task state; the twin's autopilot does with --task)"
            .to_owned()
    };
    let criteria = r
        .criteria
        .iter()
        .map(|(n, v)| format!("{n} {}", if *v { "yes" } else { "no" }))
        .collect::<Vec<_>>()
        .join(", ");
    for (name, value) in [
        ("success", success),
        ("termination", format!("{:?}", r.termination).to_lowercase()),
        ("env steps", r.executed_steps.to_string()),
        (
            "criteria reached",
            if r.task_observed && !criteria.is_empty() {
                criteria
            } else {
                "N/A".to_owned()
            },
        ),
        ("EE position error (cm)", cell(s.ee_pos_error_m, 100.0, 3)),
        (
            "base position error (cm)",
            cell(s.base_pos_error_m, 100.0, 3),
        ),
        ("saturation rate (%)", cell(s.saturation_rate, 100.0, 2)),
        (
            "tilt use (deg)",
            cell(s.tilt_use_rad, 180.0 / std::f64::consts::PI, 3),
        ),
        ("wall time (s)", cell(Some(r.wall_time_s), 1.0, 2)),
    ] {
        table.add_row([name.to_owned(), value]);
    }
    println!("{table}");
    if let Some(path) = &args.json {
        let mut value = serde_json::to_value(&r)?;
        if let Some(object) = value.as_object_mut() {
            object.insert("link".to_owned(), link_name.into());
            object.insert("platform".to_owned(), config.vehicle.id.clone().into());
            object.insert(
                "controller".to_owned(),
                config.controller_name.clone().into(),
            );
        }
        write_json(path, &value)?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &r.mcap {
        eprintln!("wrote {}", path.display());
    }
    if r.termination == Termination::Interrupted {
        eprintln!("interrupted: the rollout is partial");
    }
    Ok(())
}
