//! What a served twin shows of itself (`amstack twin serve --live`): the twin process's own
//! truth on the flight log's channels, written through a recorder — file-less with the live
//! view's tap, so Foxglove watches the twin while another process (`amstack fly --link ipc:…`,
//! a MAVLink ground station or offboard program) flies it.
//!
//! After each reset, at the start time t_0: `/scene/static` (the vehicle, floor, walls and
//! fixed parts) and `/scene/tf`. After each step, at the new time t_{k+1}: `/scene/tf`,
//! `/scene/dynamic` (moving objects, rotor thrust arrows), `/scene/static` again every
//! simulated second, and amstack's JSON channels `/tf`, `/base/pose`, `/ee/pose`,
//! `/base/state`, `/joints` (the period's joint targets and the measured positions),
//! `/rotors`, `/disturbances` of the period, and `/task/state` with a task scene. Every
//! channel is registered (advertised to viewers) when the view is made. The schemas
//! and units are the flight log's (`docs/mcap-format.md`); the twin knows no reference, so
//! there is no `/scene/targets` and no controller channel. Each session restarts the twin's
//! time from 0.

use nalgebra::Isometry3;
use platform::{ActuatorCommand, Measurement, Vehicle};
use sim_twin::{Twin, TwinObserver};

use crate::flight_log::{BaseState, Disturbances, Joints, Rotors, TaskState, frame_transforms};
use crate::metrics::CriteriaLatch;
use crate::record::foxglove::{FrameTransforms, PoseInFrame};
use crate::record::{Channel, McapRecorder, RecordError};
use crate::scene3d::{SCENE_DYNAMIC_TOPIC, SCENE_STATIC_TOPIC, SCENE_TF_TOPIC, Scene3d};

/// A served twin's channels on one recorder: a [`TwinObserver`] for the twin's servers.
#[derive(Debug)]
pub struct TwinView {
    recorder: McapRecorder,
    scene: Scene3d,
    scene_tf: Channel<foxglove::schemas::FrameTransforms>,
    scene_static: Channel<foxglove::schemas::SceneUpdate>,
    scene_dynamic: Channel<foxglove::schemas::SceneUpdate>,
    tf: Channel<FrameTransforms>,
    base_pose: Channel<PoseInFrame>,
    ee_pose: Channel<PoseInFrame>,
    base_state: Channel<BaseState>,
    joints: Channel<Joints>,
    rotors: Channel<Rotors>,
    disturbances: Channel<Disturbances>,
    /// Advertised from the start (a twin serving `--flight-chooses-episode` learns its task
    /// with each session), written while the twin holds a task.
    task: Channel<TaskState>,
    latch: CriteriaLatch,
    /// The scene objects' poses (scratch).
    poses: Vec<Isometry3<f64>>,
    joint_names: Vec<String>,
    /// The rotor limits `/rotors.saturated` is judged against (None: ideal rotors).
    limits: Option<(f64, f64)>,
    /// The first error; nothing more is written after it.
    error: Option<RecordError>,
}

fn nanos(time_s: f64) -> u64 {
    // Simulated time is non-negative and far below u64's range.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let ns = (time_s * 1e9).round().max(0.0) as u64;
    ns
}

impl TwinView {
    /// Opens the channels on `recorder` for the twin of `vehicle`; `limits_enforced`: the
    /// twin's rotors are limited (its `saturation` disturbance).
    pub fn new(
        mut recorder: McapRecorder,
        vehicle: &Vehicle,
        limits_enforced: bool,
    ) -> Result<Self, RecordError> {
        Ok(Self {
            scene: Scene3d::new(vehicle),
            scene_tf: recorder.encoded_channel(SCENE_TF_TOPIC)?,
            scene_static: recorder.encoded_channel(SCENE_STATIC_TOPIC)?,
            scene_dynamic: recorder.encoded_channel(SCENE_DYNAMIC_TOPIC)?,
            tf: recorder.channel("/tf")?,
            base_pose: recorder.channel("/base/pose")?,
            ee_pose: recorder.channel("/ee/pose")?,
            base_state: recorder.channel("/base/state")?,
            joints: recorder.channel("/joints")?,
            rotors: recorder.channel("/rotors")?,
            disturbances: recorder.channel("/disturbances")?,
            task: recorder.channel("/task/state")?,
            latch: CriteriaLatch::new(0),
            poses: Vec::new(),
            joint_names: (0..vehicle.model.dof())
                .map(|d| vehicle.model.dof_joint(d).name.clone())
                .collect(),
            limits: limits_enforced
                .then_some((vehicle.rotors.thrust_min_n, vehicle.rotors.thrust_max_n)),
            error: None,
            recorder,
        })
    }

    /// The first error met (the view stopped writing there).
    pub fn error(&self) -> Option<&RecordError> {
        self.error.as_ref()
    }

    /// Finishes the recorder (a file-less one: what it logged).
    pub fn finish(self) -> Result<crate::record::RecordSummary, RecordError> {
        match self.error {
            Some(e) => Err(e),
            None => self.recorder.finish(),
        }
    }

    /// `/scene/tf` at `m`, the static scene when due.
    fn frames(&mut self, t: u64, m: &Measurement) -> Result<(), RecordError> {
        if self.scene.static_due(t) {
            let fixed = self.scene.static_scene(t);
            self.recorder.log_encoded(&self.scene_static, t, &fixed)?;
        }
        let tf = self.scene.transforms(t, m);
        self.recorder.log_encoded(&self.scene_tf, t, &tf)
    }

    fn write_reset(&mut self, twin: &Twin) -> Result<(), RecordError> {
        self.scene.set_scene(twin.scene_visuals());
        self.latch = CriteriaLatch::new(twin.task_status().map_or(0, |s| s.criteria.len()));
        let m = twin.truth();
        self.frames(nanos(m.time_s), m)
    }

    fn write_step(&mut self, twin: &Twin, command: &ActuatorCommand) -> Result<(), RecordError> {
        let m = twin.truth();
        let t = nanos(m.time_s);
        self.frames(t, m)?;
        twin.scene_visual_poses_into(&mut self.poses);
        let dynamic = self.scene.dynamic_scene(t, m, &self.poses);
        if !dynamic.entities.is_empty() {
            self.recorder
                .log_encoded(&self.scene_dynamic, t, &dynamic)?;
        }
        let r = &mut self.recorder;
        r.log(&self.tf, t, &frame_transforms(t, m))?;
        r.log(
            &self.base_pose,
            t,
            &PoseInFrame::new(t, "world", &m.base.pose()),
        )?;
        r.log(
            &self.ee_pose,
            t,
            &PoseInFrame::new(t, "world", &m.world_from_ee),
        )?;
        r.log(&self.base_state, t, &BaseState::of(m))?;
        r.log(
            &self.joints,
            t,
            &Joints {
                names: self.joint_names.clone(),
                target: command.joint_targets.clone(),
                position: m.joint_positions.clone(),
            },
        )?;
        if !m.rotors.is_empty() {
            r.log(&self.rotors, t, &Rotors::of(m, self.limits))?;
        }
        r.log(&self.disturbances, t, &Disturbances::of(m))?;
        if let Some(snapshot) = twin.task_snapshot() {
            self.latch.observe(&snapshot.status.criteria);
            let state = TaskState::from_snapshot(&snapshot, self.latch.reached());
            self.recorder.log(&self.task, t, &state)?;
        }
        Ok(())
    }
}

impl TwinObserver for TwinView {
    fn reset(&mut self, twin: &Twin) {
        if self.error.is_none()
            && let Err(e) = self.write_reset(twin)
        {
            self.error = Some(e);
        }
    }

    fn stepped(&mut self, twin: &Twin, command: &ActuatorCommand) {
        if self.error.is_none()
            && let Err(e) = self.write_step(twin, command)
        {
            self.error = Some(e);
        }
    }
}
