//! `amstack record`: demonstrations of a task's scripted policy as a LeRobot v3.0 dataset.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use policy_runtime::Interface;
use policy_runtime::bench::first_difference;
use policy_runtime::dataset::{
    ActionSemantics, Attempt, DatasetSpec, DatasetWriter, RecordConfig, RecordError, ShardPart,
    StateKey, record,
};
use serde_json::{Value, json};

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Each attempt is one rollout of `amstack bench` (same platform, controller, interface,
disturbances and episode length; attempt i has seed --seed + i). Successful episodes are
written (failed ones too with --save-failed) until the dataset holds --episodes, or
--max-attempts attempts were made. A frame k holds the observation of tick k
(observation.state: the --state-keys, measured) and the action applied after it (action:
the 8-D absolute end-effector target, or with --interface joint the 12-D base + joint target
the whole-body IK made of it), at 120 fps; with --cameras ee[,base] also the images of
observation k (observation.images.ee_camera: 384x384 RGB, PNG in the Parquet file). Actions
are rounded to float32 before the stack flies them, so the recorded action is exactly the
applied one.

The output is a LeRobot v3.0 dataset (lerobot >= 0.4 loads it with
LeRobotDataset(repo_id, root=DIR)); `amstack dataset info|validate|export-openpi|merge` work
on it. Same flags, same seed: the same bytes, whatever --jobs. An episode is written whole or
not at all: a run that dies leaves a valid dataset, and --resume goes on after its last
episode with the same attempts an uninterrupted run would have made.

Shards: --shard I/N records only the attempts a with a mod N = I (0-based; --shard env/N
takes I from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX), in order, until the shard holds
its quota (--shard-episodes, default ceil(--episodes / N)) or its attempts below
--max-attempts are made. Every shard is given the same flags otherwise. `amstack dataset merge
PART... --out DIR` checks the parts are the shards of one recording, each once, and writes
exactly the dataset the unsharded recording writes (the same bytes). When a task fails often,
one shard may need more episodes than its quota: the merge names it, and `--resume
--shard-episodes K` on that shard runs it on.
  amstack record --platform fa-hexa --task press-button --episodes 80 --shard 0/4 --out part0
  amstack dataset merge part0 part1 part2 part3 --out data/press-button

State keys: ee_pos ee_quat gripper_width base_pos base_quat base_lin_vel base_ang_vel
arm_joint_pos arm_joint_vel.

Examples:
  amstack record --platform fa-hexa --task press-button --episodes 80 --cameras ee \\
      --out data/press-button
  amstack record --platform fa-hexa --task push-slider --interface joint \\
      --state-keys base_pos,base_quat,arm_joint_pos,gripper_width --out data/slider-joint
  amstack dataset validate data/press-button")]
pub struct Args {
    /// The task (one of `amstack bench --help`'s).
    #[arg(long)]
    task: String,
    /// Episodes the dataset holds at the end.
    #[arg(long, default_value_t = 80)]
    episodes: u64,
    /// Attempts at most [default: 4 x --episodes].
    #[arg(long)]
    max_attempts: Option<u64>,
    /// Write failed episodes too.
    #[arg(long)]
    save_failed: bool,
    /// The dataset folder (refused if it is not empty, unless --resume).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Append to the dataset in --out after its last complete episode.
    #[arg(long)]
    resume: bool,
    /// The observation state's keys, comma-separated, in order.
    #[arg(
        long,
        value_name = "KEYS",
        default_value = "ee_pos,ee_quat,gripper_width"
    )]
    state_keys: String,
    #[command(flatten)]
    cameras: crate::camera_flags::CameraFlags,
    /// Write the summary JSON here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Vehicle id (ee-only, fa-hexa, ua-hexa, ua-quad, omni-hexa, or one added with --vehicle).
    #[arg(long, default_value = "ee-only")]
    platform: String,
    /// Controller [default: pid on ee-only, ik-pid otherwise] (the choices of `amstack bench`).
    #[arg(long)]
    controller: Option<String>,
    /// Action interface: ee (8-D end-effector actions) or joint (12-D base pose + arm joints,
    /// from the scripted end-effector targets through the whole-body IK).
    #[arg(long, default_value = "ee", value_parser = ["ee", "joint"])]
    interface: String,
    /// Episode length: `spec`, `script` or seconds (as `amstack bench`).
    #[arg(long, value_name = "spec|script|S", default_value = "script")]
    episode_length: String,
    /// Worker threads [default: all cores]; the dataset does not depend on it.
    #[arg(long)]
    jobs: Option<usize>,
    #[command(flatten)]
    twin: crate::twin_flags::TwinFlags,
    #[command(flatten)]
    state: crate::track::StateFlags,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
    /// Record only shard I (0-based) of N of the attempts (attempt a belongs to shard a mod
    /// N); `env/N` reads I from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX. Merge the shards
    /// with `amstack dataset merge`.
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Store the cameras as MP4 video features (LeRobot's `video` dtype:
    /// videos/observation.images.<camera>/chunk-CCC/file-FFF.mp4, one file per episode,
    /// H.264) instead of PNG images in the data files. Needs --cameras and the ffmpeg program
    /// (apt-get install ffmpeg, or AMSTACK_FFMPEG=PATH).
    #[arg(long)]
    video: bool,
    /// Episodes this shard records [default: ceil(--episodes / N)].
    #[arg(long, value_name = "K", requires = "shard")]
    shard_episodes: Option<u64>,
}

impl Args {
    /// The rollouts' flags as `amstack bench` takes them: its setup builds them.
    fn bench_args(&self) -> crate::bench::Args {
        crate::bench::Args {
            live: None,
            task: self.task.clone(),
            platform: self.platform.clone(),
            controller: self.controller.clone(),
            mpc_config: None,
            interface: self.interface.clone(),
            rollouts: 1,
            episode_length: self.episode_length.clone(),
            jobs: self.jobs,
            link: "twin".to_owned(),
            link_timeout_ms: 50,
            connect_timeout_ms: 10_000,
            twin: self.twin.clone(),
            state: self.state.clone(),
            cameras: self.cameras.clone(),
            video: None,
            out: None,
            json: None,
            vehicles: self.vehicles.clone(),
            action: None,
            shard: None,
            // Demonstrations are the task's script: no learned policy.
            policy: crate::policy_flags::PolicyFlags::default(),
        }
    }
}

fn state_keys(text: &str) -> Result<Vec<StateKey>> {
    text.split([',', ' '])
        .filter(|s| !s.is_empty())
        .map(|k| StateKey::parse(k).map_err(|e| bad_input(format!("--state-keys: {e}"))))
        .collect::<Result<Vec<_>>>()
        .and_then(|keys| {
            if keys.is_empty() {
                Err(bad_input("--state-keys: name at least one key"))
            } else {
                Ok(keys)
            }
        })
}

pub fn run(args: &Args) -> Result<()> {
    if let Some(p) = &args.json {
        check_writable("--json", p)?;
    }
    if args.task.contains(',') || args.task == "all" {
        return Err(bad_input(format!(
            "--task {}: record one task per dataset (merge them with `amstack dataset merge`)",
            args.task
        )));
    }
    let bench = crate::bench::config(&args.bench_args())?;
    if args.episodes == 0 {
        return Err(bad_input("--episodes 0: record at least one episode"));
    }
    let max_attempts = args.max_attempts.unwrap_or(args.episodes.saturating_mul(4));
    if max_attempts == 0 {
        return Err(bad_input("--max-attempts 0: make at least one attempt"));
    }
    let keys = state_keys(&args.state_keys)?;
    let shard = match &args.shard {
        Some(spec) => Some(crate::bench_shard::parse_shard(spec, &|v| {
            std::env::var(v).ok()
        })?),
        None => None,
    };
    if args.shard_episodes == Some(0) {
        return Err(bad_input("--shard-episodes 0: record at least one episode"));
    }
    // What every shard of the run shares beyond the recording block.
    let shard_part = shard.map(|s| {
        ShardPart::new(
            s.index as u64,
            s.count as u64,
            json!({
                "episodes": args.episodes,
                "max_attempts": max_attempts,
                "save_failed": args.save_failed,
            }),
        )
    });
    let semantics = match bench.interface {
        Interface::Ee => ActionSemantics::EeAbsolute,
        Interface::BaseJoint => ActionSemantics::BaseJointAbsolute,
    };
    let rate = bench.twin.control_rate_hz;
    if rate.fract() != 0.0 || rate <= 0.0 {
        return Err(bad_input(format!(
            "the control rate {rate} Hz is not a whole number of frames per second"
        )));
    }
    let cameras: Vec<(String, usize, usize)> = bench
        .cameras
        .as_ref()
        .map(|c| {
            c.cameras
                .iter()
                .map(|s| {
                    let i = &s.intrinsics;
                    (s.name.clone(), i.height as usize, i.width as usize)
                })
                .collect()
        })
        .unwrap_or_default();
    let ffmpeg = if args.video {
        if cameras.is_empty() {
            return Err(bad_input(
                "--video: name the cameras to store as videos (--cameras ee[,base])",
            ));
        }
        Some(
            policy_runtime::video::ffmpeg_program()
                .map_err(|e| bad_input(format!("--video: {e}")))?,
        )
    } else {
        None
    };
    let spec = DatasetSpec::new(&bench.vehicle, &keys, semantics, rate as u32, &cameras)
        .with_video(args.video);
    let mut recording = json!({
        "task": bench.tasks[0].name(),
        "platform": bench.vehicle.id,
        "controller": bench.controller_name,
        "interface": args.interface,
        "seed": bench.seed,
        "episode_length": bench.episode,
        "disturbances": args.twin.disturbances,
        "cameras": cameras.iter().map(|c| &c.0).collect::<Vec<_>>(),
        "visual_dr": args.cameras.visual_dr == crate::camera_flags::OnOff::On,
        "state_source": serde_json::to_value(bench.state_source).unwrap_or(Value::Null),
        "twin": serde_json::to_value(&bench.twin)?,
        "actions": "float32, rounded before the stack flies them",
    });
    // Only with videos: the recordings made before --video keep their block (and resume).
    if let (true, Some(object)) = (args.video, recording.as_object_mut()) {
        object.insert(
            "video".to_owned(),
            json!({"codec": "h264", "encoder": "ffmpeg libx264"}),
        );
    }
    let non_empty = std::fs::read_dir(&args.out).is_ok_and(|mut d| d.next().is_some());
    let writer = if non_empty {
        if !args.resume {
            return Err(bad_input(format!(
                "--out {}: not empty (pass --resume to append to the dataset in it)",
                args.out.display()
            )));
        }
        let writer = DatasetWriter::resume(&args.out, spec)
            .map_err(|e| bad_input(format!("--resume {}: {e}", args.out.display())))?;
        let repaired = writer.repaired();
        if repaired.any() {
            eprintln!(
                "record: --resume {}: dropped what the last run left of an unfinished episode ({} data rows, {} episode rows, {} task(s){}{})",
                args.out.display(),
                repaired.data_rows,
                repaired.episode_rows,
                repaired.tasks,
                if repaired.files_removed.is_empty() {
                    String::new()
                } else {
                    format!("; removed {}", repaired.files_removed.join(", "))
                },
                if repaired.stats_suspect() {
                    "; statistics recomputed"
                } else {
                    ""
                },
            );
        }
        let info = std::fs::read_to_string(args.out.join("meta/info.json")).unwrap_or_default();
        let info: Value = serde_json::from_str(&info).unwrap_or(Value::Null);
        let stored = &info["ambench"]["recording"];
        if let Some((field, was, now)) = first_difference(stored, &recording, "recording") {
            return Err(bad_input(format!(
                "--resume {}: the dataset was recorded with {field} = {was}; these flags give {now}",
                args.out.display()
            )));
        }
        match (writer.shard(), &shard_part) {
            (None, None) => {}
            (Some(had), Some(now)) => {
                let differs = if (had.index, had.count) == (now.index, now.count) {
                    first_difference(&had.run, &now.run, "shard.run")
                } else {
                    Some((
                        "shard".to_owned(),
                        json!(format!("{}/{}", had.index, had.count)),
                        json!(format!("{}/{}", now.index, now.count)),
                    ))
                };
                if let Some((field, was, now)) = differs {
                    return Err(bad_input(format!(
                        "--resume {}: the shard was recorded with {field} = {was}; these flags give {now}",
                        args.out.display()
                    )));
                }
            }
            (Some(had), None) => {
                return Err(bad_input(format!(
                    "--resume {}: the dataset is shard {}/{} of a recording; resume it with --shard {}/{}",
                    args.out.display(),
                    had.index,
                    had.count,
                    had.index,
                    had.count
                )));
            }
            (None, Some(_)) => {
                return Err(bad_input(format!(
                    "--resume {}: the dataset is a whole recording, not a shard (drop --shard)",
                    args.out.display()
                )));
            }
        }
        writer
    } else {
        std::fs::create_dir_all(&args.out).map_err(|e| {
            bad_input(format!(
                "--out {}: cannot create it: {e}",
                args.out.display()
            ))
        })?;
        let writer = DatasetWriter::create(&args.out, spec, recording)?;
        match shard_part {
            Some(part) => writer.with_shard(part)?,
            None => writer,
        }
    };
    let mut writer = match ffmpeg {
        Some(program) => writer.with_ffmpeg(program),
        None => writer,
    };
    let first_attempt = writer.next_attempt();
    let already = writer.episodes();
    // A shard: its quota of episodes, and its attempts among the run's 0..max_attempts.
    let (target, attempt_step, attempt_end) = match shard {
        Some(s) => (
            args.shard_episodes
                .unwrap_or_else(|| args.episodes.div_ceil(s.count as u64)),
            s.count as u64,
            max_attempts,
        ),
        None => (args.episodes, 1, first_attempt.saturating_add(max_attempts)),
    };
    let config = RecordConfig {
        bench,
        episodes: target,
        save_failed: args.save_failed,
        state_keys: keys,
        first_attempt,
        attempt_step,
        attempt_end,
    };
    eprintln!(
        "record: {} on {} ({}, {} interface), seed {}, {} thread(s), disturbances: {}; {} episode(s) wanted{}, {} in {} already, attempts {}..{}{}",
        config.bench.tasks[0].name(),
        config.bench.vehicle.id,
        config.bench.controller_name,
        args.interface,
        config.bench.seed,
        config.bench.jobs,
        args.twin.disturbances,
        target,
        shard.map_or(String::new(), |s| format!(
            " (shard {s} of a recording of {})",
            args.episodes
        )),
        already,
        args.out.display(),
        first_attempt,
        attempt_end,
        if attempt_step > 1 {
            format!(" every {attempt_step}")
        } else {
            String::new()
        },
    );
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let bar = ProgressBar::new(target);
    bar.set_position(already.min(target));
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} episodes ({eta} left) {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let (mut attempts, mut successes) = (0u64, 0u64);
    let mut on_attempt = |a: &Attempt| {
        attempts += 1;
        successes += u64::from(a.success);
        bar.set_message(format!(
            "attempt {}: {} ({} frames{}); {successes}/{attempts} succeeded",
            a.index,
            if a.success { "success" } else { "fail" },
            a.frames,
            if a.saved { ", saved" } else { "" }
        ));
        if a.saved {
            bar.inc(1);
        }
    };
    let report = record(&config, &mut writer, &mut on_attempt, &stop).map_err(|e| match e {
        RecordError::Rollout(policy_runtime::bench::BenchError::Link(
            policy_runtime::LinkError::Refused(_),
        )) => bad_input(e.to_string()),
        e => anyhow::Error::new(e),
    })?;
    bar.finish_and_clear();
    let size = crate::output::dir_size(&args.out);
    let summary = json!({
        "dataset": args.out.display().to_string(),
        "task": config.bench.tasks[0].name(),
        "platform": config.bench.vehicle.id,
        "attempts": report.attempts,
        "successes": report.successes,
        "episodes_written": report.saved,
        "frames_written": report.frames,
        "dataset_episodes": writer.episodes(),
        "dataset_frames": writer.frames(),
        "dataset_bytes": size,
        "status": if report.interrupted { "interrupted" } else if writer.episodes() >= target { "completed" } else { "attempts exhausted" },
        "shard": shard.map(|s| s.to_string()),
        "timing": {
            "wall_time_s": report.wall_time_s,
            "jobs": config.bench.jobs,
            "env_steps": report.env_steps,
            "env_steps_per_second": report.env_steps as f64 / report.wall_time_s.max(1e-9),
            "frames_written_per_second": report.frames as f64 / report.wall_time_s.max(1e-9),
        },
    });
    println!(
        "{} attempts, {} successes; wrote {} episodes ({} frames) in {:.1} s ({:.0} frames/s written, {:.0} env steps/s, {} thread(s)); {} now holds {} episodes, {} frames, {:.1} MB",
        report.attempts,
        report.successes,
        report.saved,
        report.frames,
        report.wall_time_s,
        report.frames as f64 / report.wall_time_s.max(1e-9),
        report.env_steps as f64 / report.wall_time_s.max(1e-9),
        config.bench.jobs,
        args.out.display(),
        writer.episodes(),
        writer.frames(),
        size as f64 / 1e6,
    );
    if let Some(path) = &args.json {
        write_json(path, &summary)?;
        eprintln!("wrote {}", path.display());
    }
    if report.interrupted {
        return Err(anyhow::Error::new(crate::bench::Interrupted));
    }
    if writer.episodes() < target {
        anyhow::bail!(
            "{} of the {} episodes after {} attempts (raise --max-attempts, or --save-failed)",
            writer.episodes(),
            target,
            report.attempts
        );
    }
    Ok(())
}
