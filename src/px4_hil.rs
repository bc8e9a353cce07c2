//! `amstack twin serve --px4-hil tcp:HOST:PORT` (the twin as PX4's simulator, `twin_hil`)
//! and `amstack px4-airframe` (PX4's control-allocation parameters of a vehicle).
//!
//! The simulator's MCAP log is written here, at the CLI layer (`twin_hil` does not depend on
//! `policy_runtime`): one file per session (`FILE`, then `FILE-2.mcap`, …), with the flight
//! log's channels (docs/mcap-format.md) at PX4's clock: at each tick's time t_n `/tf`,
//! `/base/pose`, `/ee/pose`, `/base/state`, `/joints` (the state the HIL_SENSOR reported,
//! the targets of PX4's reply), `/task/state` with a task scene; at t_n + dt `/rotors` and
//! `/disturbances` of the period; `/mavlink/raw` every HIL frame in and out at t_n.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Result;
use firmware_bridge::RawFrame;
use platform::{Measurement, Vehicle};
use policy_runtime::flight_log::{
    BaseState, Disturbances, Joints, MAVLINK_RAW_TOPIC, MavlinkRawFrame, Rotors, TaskState,
    frame_transforms,
};
use policy_runtime::metrics::CriteriaLatch;
use policy_runtime::record::foxglove::{FrameTransforms, PoseInFrame};
use policy_runtime::record::{Channel, McapRecorder, RunMetadata};
use sim_twin::ipc::Mode;
use sim_twin::{Twin, TwinConfig, TwinObserver};
use twin_hil::{HilConfig, HilError, HilObserver, HilServer, HilTick, Px4Airframe, SessionStats};

use crate::cli_error::bad_input;
use crate::vehicles::find_vehicle;

/// What `twin serve --px4-hil` was asked for.
#[derive(Debug)]
pub struct Serve {
    /// `tcp:HOST:PORT`.
    pub endpoint: String,
    /// The vehicle.
    pub vehicle: Vehicle,
    /// The twin's settings (task scene, seed).
    pub twin: TwinConfig,
    /// Lockstep or realtime.
    pub mode: Mode,
    /// Lockstep stall timeout, ms.
    pub stall_ms: u64,
    /// Lockstep: how long each HIL_SENSOR waits for PX4's first reply, ms.
    pub first_reply_ms: Option<u64>,
    /// Exit after this many sessions.
    pub sessions: Option<u64>,
    /// MCAP log of the sessions.
    pub mcap: Option<PathBuf>,
    /// The live view (`--live`), told of every session start and tick.
    pub live: Option<Box<dyn TwinObserver>>,
}

pub fn run_serve(serve: Serve) -> Result<()> {
    let listen = twin_hil::parse_endpoint(&serve.endpoint)
        .map_err(|e| bad_input(format!("--px4-hil {e}")))?;
    if serve.stall_ms == 0 {
        return Err(bad_input("--stall-ms 0: must be positive".to_owned()));
    }
    let config = HilConfig {
        stall_timeout: Duration::from_millis(serve.stall_ms),
        first_reply: serve.first_reply_ms.map(Duration::from_millis),
        max_sessions: serve.sessions,
        ..HilConfig::new(listen, serve.mode)
    };
    let mut server =
        HilServer::new(serve.vehicle.clone(), serve.twin.clone(), config).map_err(|e| match e {
            HilError::Map(_) | HilError::Listen { .. } => bad_input(format!("--px4-hil: {e}")),
            e => anyhow::Error::new(e),
        })?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    let mut live = serve.live;
    if let Some(view) = &mut live {
        // Shown at once, as the other servers do when a view attaches: a viewer subscribes
        // before PX4 connects (every session starts from this state).
        view.reset(&Twin::new(serve.vehicle.clone(), serve.twin.clone())?);
    }
    let mut watch = Watch {
        log: SessionLog::new(serve.mcap.clone(), &serve.vehicle, &serve.twin),
        live,
    };
    let sessions = server.run(&stop, &mut watch, |event| eprintln!("px4-hil: {event}"))?;
    let mut log = watch.log;
    log.close();
    if let Some(e) = log.error.take() {
        return Err(anyhow::anyhow!("MCAP log: {e}"));
    }
    eprintln!("px4-hil: stopped after {sessions} session(s)");
    Ok(())
}

/// The session log and the live view, each told of every session and tick.
struct Watch {
    log: SessionLog,
    live: Option<Box<dyn TwinObserver>>,
}

impl HilObserver for Watch {
    fn session_started(&mut self, session: u64, twin: &Twin) {
        self.log.session_started(session, twin);
        if let Some(live) = &mut self.live {
            live.reset(twin);
        }
    }

    fn tick(&mut self, tick: &HilTick<'_>) {
        self.log.tick(tick);
        if let Some(live) = &mut self.live {
            live.stepped(tick.twin, tick.command);
        }
    }

    fn session_ended(&mut self, session: u64, stats: &SessionStats) {
        self.log.session_ended(session, stats);
    }
}

/// The MCAP file of session `n` (1: `path` itself).
fn session_path(path: &Path, n: u64) -> PathBuf {
    if n <= 1 {
        return path.to_path_buf();
    }
    let stem = path
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    path.with_file_name(format!("{stem}-{n}.mcap"))
}

fn nanos(time_s: f64) -> u64 {
    // Simulated time is non-negative and far below u64's range.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let ns = (time_s * 1e9).round().max(0.0) as u64;
    ns
}

struct Channels {
    tf: Channel<FrameTransforms>,
    base_pose: Channel<PoseInFrame>,
    ee_pose: Channel<PoseInFrame>,
    base_state: Channel<BaseState>,
    joints: Channel<Joints>,
    rotors: Channel<Rotors>,
    disturbances: Channel<Disturbances>,
    raw: Channel<MavlinkRawFrame>,
    task: Option<Channel<TaskState>>,
}

/// The observer writing each session's MCAP file.
struct SessionLog {
    path: Option<PathBuf>,
    vehicle_id: String,
    joint_names: Vec<String>,
    /// The rotor limits `/rotors.saturated` is judged against (None: the twin's rotors are
    /// ideal).
    limits: Option<(f64, f64)>,
    config_json: String,
    seed: u64,
    open: Option<(McapRecorder, Channels, Instant)>,
    latch: CriteriaLatch,
    error: Option<String>,
}

impl SessionLog {
    fn new(path: Option<PathBuf>, vehicle: &Vehicle, twin: &TwinConfig) -> Self {
        Self {
            path,
            vehicle_id: vehicle.id.clone(),
            joint_names: (0..vehicle.model.dof())
                .map(|d| vehicle.model.dof_joint(d).name.clone())
                .collect(),
            limits: twin
                .disturbances
                .saturation
                .then_some((vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n)),
            config_json: serde_json::to_string(twin).unwrap_or_else(|_| "{}".to_owned()),
            seed: twin.seed,
            open: None,
            latch: CriteriaLatch::new(0),
            error: None,
        }
    }

    fn open(&mut self, session: u64, twin: &Twin) -> Result<(), String> {
        let Some(path) = &self.path else {
            return Ok(());
        };
        let path = session_path(path, session);
        let mut run = RunMetadata::new(self.vehicle_id.clone(), "px4", self.seed);
        run.trajectory = Some(match twin.task() {
            Some(task) => format!("px4-hil:task:{}", task.name()),
            None => "px4-hil".to_owned(),
        });
        run.config_json = self.config_json.clone();
        let mut r = McapRecorder::create(&path, &run).map_err(|e| e.to_string())?;
        let e = |e: policy_runtime::record::RecordError| e.to_string();
        let channels = Channels {
            tf: r.channel("/tf").map_err(e)?,
            base_pose: r.channel("/base/pose").map_err(e)?,
            ee_pose: r.channel("/ee/pose").map_err(e)?,
            base_state: r.channel("/base/state").map_err(e)?,
            joints: r.channel("/joints").map_err(e)?,
            rotors: r.channel("/rotors").map_err(e)?,
            disturbances: r.channel("/disturbances").map_err(e)?,
            raw: r.channel(MAVLINK_RAW_TOPIC).map_err(e)?,
            task: match twin.task() {
                Some(_) => Some(r.channel("/task/state").map_err(e)?),
                None => None,
            },
        };
        self.latch = CriteriaLatch::new(twin.task_status().map_or(0, |s| s.criteria.len()));
        self.open = Some((r, channels, Instant::now()));
        Ok(())
    }

    fn write(&mut self, tick: &HilTick<'_>) -> Result<(), String> {
        let Some((r, c, opened)) = &mut self.open else {
            return Ok(());
        };
        let e = |e: policy_runtime::record::RecordError| e.to_string();
        let m: &Measurement = tick.state;
        let t = nanos(tick.time_s);
        let base = m.base.pose();
        r.log(&c.tf, t, &frame_transforms(t, m)).map_err(e)?;
        r.log(&c.base_pose, t, &PoseInFrame::new(t, "world", &base))
            .map_err(e)?;
        r.log(
            &c.ee_pose,
            t,
            &PoseInFrame::new(t, "world", &m.world_from_ee),
        )
        .map_err(e)?;
        r.log(&c.base_state, t, &BaseState::of(m)).map_err(e)?;
        r.log(
            &c.joints,
            t,
            &Joints {
                names: self.joint_names.clone(),
                target: tick.command.joint_targets.clone(),
                position: m.joint_positions.clone(),
            },
        )
        .map_err(e)?;
        for f in tick.frames {
            let raw = RawFrame {
                direction: f.direction,
                at: f.at,
                flight_time_s: tick.time_s,
                system_id: f.system_id,
                component_id: f.component_id,
                sequence: f.sequence,
                message_id: f.message_id,
                message_name: f.message_name,
                bytes: f.bytes.clone(),
            };
            r.log(&c.raw, t, &MavlinkRawFrame::new(&raw, *opened))
                .map_err(e)?;
        }
        if !tick.held {
            let a = tick.after;
            let t1 = nanos(a.time_s);
            if !a.rotors.is_empty() {
                r.log(&c.rotors, t1, &Rotors::of(a, self.limits))
                    .map_err(e)?;
            }
            r.log(&c.disturbances, t1, &Disturbances::of(a))
                .map_err(e)?;
            if let (Some(channel), Some(snapshot)) = (&c.task, tick.twin.task_snapshot()) {
                self.latch.observe(&snapshot.status.criteria);
                r.log(
                    channel,
                    t1,
                    &TaskState::from_snapshot(&snapshot, self.latch.reached()),
                )
                .map_err(e)?;
            }
        }
        Ok(())
    }

    fn close(&mut self) {
        if let Some((r, _, _)) = self.open.take()
            && let Err(e) = r.finish()
        {
            self.error.get_or_insert(e.to_string());
        }
    }
}

impl HilObserver for SessionLog {
    fn session_started(&mut self, session: u64, twin: &Twin) {
        self.close();
        if let Err(e) = self.open(session, twin) {
            eprintln!("px4-hil: MCAP log: {e}; this session is not logged");
            self.error.get_or_insert(e);
        }
    }

    fn tick(&mut self, tick: &HilTick<'_>) {
        if let Err(e) = self.write(tick) {
            // Report once, stop logging the session.
            eprintln!("px4-hil: MCAP log: {e}; logging stopped");
            self.error.get_or_insert(e);
            self.open = None;
        }
    }

    fn session_ended(&mut self, _session: u64, _stats: &SessionStats) {
        self.close();
    }
}

/// `amstack px4-airframe`.
#[derive(Debug, clap::Args)]
pub struct AirframeArgs {
    /// Vehicle id (ua-quad, ua-hexa, fa-hexa, omni-hexa, or one added with --vehicle).
    #[arg(long, default_value = "fa-hexa")]
    platform: String,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
}

pub fn run_airframe(args: &AirframeArgs) -> Result<()> {
    let vehicle = find_vehicle(&args.vehicles, &args.platform)?;
    let airframe = Px4Airframe::of(&vehicle).map_err(|e| bad_input(e.to_string()))?;
    print!("{}", airframe.snippet(&vehicle));
    Ok(())
}
