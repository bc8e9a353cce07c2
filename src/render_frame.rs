//! `amstack render`: one camera frame of a vehicle in a task scene, to a PNG — the quickest way
//! to see what a policy sees.

use std::path::PathBuf;

use anyhow::Result;
use controllers::{ControllerKind, profile};
use policy_runtime::flight::{
    ActionSource, EpisodeLength, FlightSpec, Observation, ScriptedTask, SourceError, Step,
    TrajectorySource,
};
use policy_runtime::stack::FlightStack;
use policy_runtime::{Interface, StateSource, Trajectory, TwinLink};
use render::{CameraSpec, RenderError, Renderer, Snapshot, VisualDr};
use sim_twin::{TaskId, Twin, TwinConfig};

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_bytes, write_json};
use crate::vehicles::find_vehicle;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum OnOff {
    On,
    Off,
}

#[derive(Debug, clap::Args)]
#[command(after_help = "\
The frame shows the twin at reset: the vehicle at its start pose and joints, the task's scene
drawn from --seed as a benchmark rollout of that seed would have it; with --time T, after the
task's scripted policy (PID, end-effector interface, as `bench`) flew T seconds from there
(without --task: a hover), through the same flight loop as bench. Cameras are the vehicle
file's [[camera]] sections (ee = ee_camera, base = base_camera) or the reference's scene camera
(1280x720 at (-2, -2.5, 1.6) m looking at (2, 0, 1) m). Intrinsics: fx = fy = width x focal /
aperture, principal point at the image centre (19.6 / 20.955 -> fx = 359.17 px at 384 px).
It needs a graphics adapter: a GPU, or Mesa's Vulkan software rasteriser (mesa-vulkan-drivers,
installed by scripts/setup.sh). Set WGPU_BACKEND=vulkan|gl to choose a backend.

Examples:
  amstack render --platform fa-hexa --task press-button --out ee.png
  amstack render --platform fa-hexa --task peg-in-hole --camera scene --out scene.png
  amstack render --platform ua-quad --task rotate-valve --seed 3 --visual-dr on --out dr.png
  amstack render --platform fa-hexa --task press-button --time 4 --camera ee --out ee-4s.png")]
pub struct Args {
    /// The vehicle: ee-only, fa-hexa, ua-hexa, ua-quad, omni-hexa, or the id of a --vehicle file.
    #[arg(long, value_name = "ID", default_value = "fa-hexa")]
    platform: String,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
    /// The task scene around the vehicle (press-button, peg-in-hole, ...: the names of
    /// `amstack bench --help`); without it the empty world (ground only).
    #[arg(long, value_name = "NAME")]
    task: Option<String>,
    /// Render after flying this many seconds from reset (the task's scripted policy, or a
    /// hover without --task); 0: at reset.
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    time: f64,
    /// Rollout seed: the scene's randomisation, and the look with --visual-dr on.
    #[arg(long, value_name = "S", default_value_t = 0)]
    seed: u64,
    /// The camera: ee, base (the vehicle's ee_camera, base_camera), scene, or any camera name
    /// of the vehicle file.
    #[arg(long, value_name = "NAME", default_value = "ee")]
    camera: String,
    /// Size of the scene camera's image, WIDTHxHEIGHT (same field of view as 1280x720).
    #[arg(long, value_name = "WxH", default_value = "1280x720")]
    scene_size: String,
    /// Visual domain randomisation: colours, textures and light drawn from the seed.
    #[arg(long, value_name = "on|off", default_value = "off")]
    visual_dr: OnOff,
    /// The PNG to write.
    #[arg(long, value_name = "FILE.png")]
    out: PathBuf,
    /// Also write the camera's intrinsics and world pose as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

fn scene_size(text: &str) -> Result<(u32, u32)> {
    let bad = || {
        bad_input(format!(
            "--scene-size {text}: expected WIDTHxHEIGHT, e.g. 640x360"
        ))
    };
    let (w, h) = text.split_once('x').ok_or_else(bad)?;
    let w: u32 = w.parse().map_err(|_| bad())?;
    let h: u32 = h.parse().map_err(|_| bad())?;
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        return Err(bad());
    }
    Ok((w, h))
}

/// The camera named on the command line.
fn camera(args: &Args, vehicle: &platform::Vehicle) -> Result<CameraSpec> {
    if args.camera == "scene" {
        let (w, h) = scene_size(&args.scene_size)?;
        return Ok(CameraSpec::scene_scaled(w, h));
    }
    let name = match args.camera.as_str() {
        "ee" => "ee_camera",
        "base" => "base_camera",
        other => other,
    };
    vehicle
        .cameras
        .iter()
        .find(|c| c.name == name)
        .map(CameraSpec::from_mount)
        .ok_or_else(|| {
            let mut known: Vec<String> = vehicle.cameras.iter().map(|c| c.name.clone()).collect();
            known.push("scene".to_owned());
            bad_input(format!(
                "--camera {}: vehicle '{}' has no such camera (known: {})",
                args.camera,
                vehicle.id,
                known.join(", ")
            ))
        })
}

pub fn run(args: &Args) -> Result<()> {
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let task = args
        .task
        .as_deref()
        .map(TaskId::parse)
        .transpose()
        .map_err(|e| bad_input(format!("--task: {e}")))?;
    let spec = camera(args, &vehicle)?;
    check_writable("--out", &args.out)?;
    if let Some(path) = &args.json {
        check_writable("--json", path)?;
    }
    let dr = match args.visual_dr {
        OnOff::On => VisualDr::On,
        OnOff::Off => VisualDr::Off,
    };
    let config = TwinConfig {
        task,
        seed: args.seed,
        ..TwinConfig::default()
    };
    if !(args.time.is_finite() && (0.0..=600.0).contains(&args.time)) {
        return Err(bad_input(format!(
            "--time {}: must be a number of seconds within [0, 600]",
            args.time
        )));
    }
    let twin = Twin::new(vehicle.clone(), config.clone())?;
    let twin = if args.time > 0.0 {
        fly_to(&vehicle, &config, twin, args.time)?
    } else {
        twin
    };
    let mut renderer = Renderer::new(&vehicle, std::slice::from_ref(&spec), dr).map_err(|e| {
        match e {
            // No adapter is the machine's setup, which the user fixes: bad input, exit 2.
            RenderError::NoAdapter(_) => bad_input(e.to_string()),
            other => anyhow::Error::new(other),
        }
    })?;
    renderer.reset_scene(&twin.scene_visuals(), args.seed)?;
    let snapshot = Snapshot::of_twin(&twin);
    let image = renderer.render(&snapshot, 0)?;
    write_bytes(&args.out, &image.to_png()?)?;
    let k = spec.intrinsics;
    if let Some(path) = &args.json {
        let pose = renderer.world_from_camera(&snapshot, 0)?;
        let q = pose.rotation;
        let t = pose.translation.vector;
        let value = serde_json::json!({
            "camera": spec.name,
            "platform": vehicle.id,
            "task": task.map(TaskId::name),
            "seed": args.seed,
            "visual_dr": matches!(dr, VisualDr::On),
            "time_s": twin.time_s(),
            "intrinsics": {
                "width": k.width, "height": k.height,
                "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
            },
            "clip_m": spec.clip_m,
            "world_from_camera": {
                "position_m": [t.x, t.y, t.z],
                "orientation_wxyz": [q.w, q.i, q.j, q.k],
                "convention": "ROS optical: +z forward, +x right, +y down",
            },
            "adapter": renderer.adapter().name,
        });
        write_json(path, &value)?;
    }
    let adapter = renderer.adapter();
    println!(
        "{}: {} of {} ({}, seed {}, visual DR {}) at t = {:.3} s, {}x{} px, fx {:.2} fy {:.2} cx {} cy {}; adapter {} ({:?})",
        args.out.display(),
        spec.name,
        vehicle.id,
        task.map_or("no task", TaskId::name),
        args.seed,
        if dr == VisualDr::On { "on" } else { "off" },
        twin.time_s(),
        k.width,
        k.height,
        k.fx,
        k.fy,
        k.cx,
        k.cy,
        adapter.name,
        adapter.backend,
    );
    Ok(())
}

/// A source flown for `ticks` ticks at most.
struct Capped {
    inner: Box<dyn ActionSource>,
    ticks: u64,
}

impl ActionSource for Capped {
    fn start(&mut self, first: &Observation<'_>) -> Result<(), SourceError> {
        self.inner.start(first)
    }

    fn tick_limit(&self) -> Option<u64> {
        Some(
            self.inner
                .tick_limit()
                .map_or(self.ticks, |n| n.min(self.ticks)),
        )
    }

    fn next(
        &mut self,
        k: u64,
        observation: &Observation<'_>,
        stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        self.inner.next(k, observation, stack)
    }
}

/// The twin after `time_s` seconds of the task's scripted policy (a hover without a task),
/// flown through the flight loop.
fn fly_to(
    vehicle: &platform::Vehicle,
    config: &TwinConfig,
    twin: Twin,
    time_s: f64,
) -> Result<Twin> {
    let rate_hz = config.control_rate_hz;
    // A small positive number of ticks (time ≤ 600 s): the cast is exact.
    let ticks = (time_s * rate_hz).round() as u64;
    let controller = profile(vehicle, ControllerKind::Pid)?;
    let mut stack = FlightStack::for_twin(vehicle.clone(), &controller, config)?;
    let mut link = TwinLink::new(twin);
    let (source, interface): (Box<dyn ActionSource>, Interface) = match config.task {
        Some(task) => (
            Box::new(ScriptedTask::new(
                task,
                config.seed,
                rate_hz,
                EpisodeLength::Script,
            )),
            Interface::Ee,
        ),
        None => (
            Box::new(TrajectorySource::new(Trajectory::Hover, vehicle.clone())),
            Interface::BaseJoint,
        ),
    };
    let mut capped = Capped {
        inner: source,
        ticks,
    };
    let end = policy_runtime::flight::run(
        &mut link,
        &mut stack,
        &mut capped,
        &mut [],
        FlightSpec {
            max_ticks: ticks,
            dt_s: config.control_dt_s(),
            control_rate_hz: rate_hz,
            seed: config.seed,
            state_source: StateSource::Truth,
            score_from_s: 0.0,
            interface: Some(interface),
            action_noise: None,
            stop: None,
            cameras: None,
        },
    )?;
    if end.ticks < ticks {
        eprintln!(
            "note: the flight ended at t = {:.3} s ({:?}), before --time {time_s}",
            end.last_time_s, end.end
        );
    }
    Ok(link.into_twin())
}
