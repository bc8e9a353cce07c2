//! What a dataset holds: its features (LeRobot's `info.json` `features`), the observation
//! state's keys, the action's semantics, the task prompts, and the paths of LeRobot v3.0.

use platform::{Measurement, Vehicle};
use serde_json::{Value, json};
use sim_twin::TaskId;

use super::DatasetError;
use crate::stack::{Action, BaseJointTarget, EeTarget};

/// The layout version `lerobot` ≥ 0.4 writes and reads.
pub const CODEBASE_VERSION: &str = "v3.0";
/// Files per chunk folder (lerobot's default).
pub const CHUNKS_SIZE: u64 = 1000;
/// A data file is closed once it would grow past this many MB (lerobot's default).
pub const DATA_FILES_SIZE_IN_MB: u64 = 100;
/// lerobot's default for video files (written to `info.json`; amstack writes one video file
/// per episode and camera).
pub const VIDEO_FILES_SIZE_IN_MB: u64 = 200;
/// Path template of the video files (`record --video`).
pub const VIDEO_PATH: &str = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4";
/// The video codec `record --video` encodes (ffmpeg's libx264, yuv420p).
pub const VIDEO_CODEC: &str = "h264";

/// `videos/KEY/chunk-CCC/file-FFF.mp4`.
pub fn video_file(key: &str, chunk: u64, file: u64) -> String {
    format!("videos/{key}/chunk-{chunk:03}/file-{file:03}.mp4")
}
/// Path template of the data files.
pub const DATA_PATH: &str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet";

/// `data/chunk-CCC/file-FFF.parquet`.
pub fn data_file(chunk: u64, file: u64) -> String {
    format!("data/chunk-{chunk:03}/file-{file:03}.parquet")
}

/// `meta/episodes/chunk-CCC/file-FFF.parquet`.
pub fn episodes_file(chunk: u64, file: u64) -> String {
    format!("meta/episodes/chunk-{chunk:03}/file-{file:03}.parquet")
}

/// The next (chunk, file) after `(chunk, file)` (lerobot's `update_chunk_file_indices`).
pub fn next_file(chunk: u64, file: u64) -> (u64, u64) {
    if file + 1 >= CHUNKS_SIZE {
        (chunk + 1, 0)
    } else {
        (chunk, file + 1)
    }
}

/// A feature's element type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    /// 32-bit float.
    Float32,
    /// 64-bit integer.
    Int64,
    /// An image: PNG bytes in the Parquet file (`datasets.Image`), uint8 HWC when decoded.
    Image,
    /// A camera stream stored as MP4 video files (`videos/…`), uint8 HWC frames when decoded.
    Video,
}

impl Dtype {
    /// lerobot's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Float32 => "float32",
            Self::Int64 => "int64",
            Self::Image => "image",
            Self::Video => "video",
        }
    }
}

/// One feature of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Feature {
    /// Its key (`observation.state`).
    pub key: String,
    /// Element type.
    pub dtype: Dtype,
    /// Shape (images: height, width, channels).
    pub shape: Vec<usize>,
    /// Names of the elements (None: unnamed).
    pub names: Option<Vec<String>>,
}

impl Feature {
    fn scalar(key: &str, dtype: Dtype) -> Self {
        Self {
            key: key.to_owned(),
            dtype,
            shape: vec![1],
            names: None,
        }
    }

    /// Elements per frame (images: bytes of the decoded image).
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    /// Whether it has no element.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Its `info.json` entry (lerobot's `info` block for a video at `fps`).
    pub fn info(&self, fps: u32) -> Value {
        let mut v = json!({ "dtype": self.dtype.name(), "shape": self.shape, "names": self.names });
        if self.dtype == Dtype::Video {
            v["info"] = json!({
                "video.height": self.shape.first(),
                "video.width": self.shape.get(1),
                "video.codec": VIDEO_CODEC,
                "video.pix_fmt": "yuv420p",
                "video.is_depth_map": false,
                "video.fps": fps,
                "video.channels": 3,
                "has_audio": false,
            });
        }
        v
    }
}

/// A key of the observation state (AMBENCH_SPEC §5.1), in the world frame with the env at
/// the origin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StateKey {
    /// End-effector link origin, m (3).
    EePos,
    /// End-effector link orientation, w x y z (4).
    EeQuat,
    /// Sum of the gripper joint positions (1).
    GripperWidth,
    /// Base link origin, m (3).
    BasePos,
    /// Base orientation, w x y z (4).
    BaseQuat,
    /// Base linear velocity, world frame, m/s (3).
    BaseLinVel,
    /// Base angular velocity, world frame, rad/s (3).
    BaseAngVel,
    /// Arm joint positions, command order, rad (n).
    ArmJointPos,
    /// Arm joint velocities, rad/s (n).
    ArmJointVel,
}

impl StateKey {
    /// Every key, by name.
    pub const ALL: [(&'static str, Self); 9] = [
        ("ee_pos", Self::EePos),
        ("ee_quat", Self::EeQuat),
        ("gripper_width", Self::GripperWidth),
        ("base_pos", Self::BasePos),
        ("base_quat", Self::BaseQuat),
        ("base_lin_vel", Self::BaseLinVel),
        ("base_ang_vel", Self::BaseAngVel),
        ("arm_joint_pos", Self::ArmJointPos),
        ("arm_joint_vel", Self::ArmJointVel),
    ];

    /// The default state of the EE datasets: `ee_pos ee_quat gripper_width` (D = 8).
    pub const DEFAULT: [Self; 3] = [Self::EePos, Self::EeQuat, Self::GripperWidth];

    /// The key named `name`.
    pub fn parse(name: &str) -> Result<Self, String> {
        Self::ALL
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, k)| *k)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|(n, _)| *n).collect();
                format!("unknown state key {name:?} (valid: {})", names.join(", "))
            })
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(_, k)| *k == self)
            .map_or("?", |(n, _)| *n)
    }

    /// Its width on `vehicle`.
    pub fn dim(self, vehicle: &Vehicle) -> usize {
        match self {
            Self::EePos | Self::BasePos | Self::BaseLinVel | Self::BaseAngVel => 3,
            Self::EeQuat | Self::BaseQuat => 4,
            Self::GripperWidth => 1,
            Self::ArmJointPos | Self::ArmJointVel => vehicle.arm_dof(),
        }
    }
}

/// What the action vector means (`info.json` `ambench.action_semantics`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActionSemantics {
    /// `[x, y, z, qw, qx, qy, qz, gripper]`: the absolute end-effector target in the
    /// command frame (8).
    EeAbsolute,
    /// `[base x, y, z, base qw, qx, qy, qz, arm q1..qn, gripper]` (8 + n).
    BaseJointAbsolute,
}

impl ActionSemantics {
    /// Its name in `info.json`.
    pub fn name(self) -> &'static str {
        match self {
            Self::EeAbsolute => "ee_absolute",
            Self::BaseJointAbsolute => "base_joint_absolute",
        }
    }

    /// The semantics named `name`.
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "ee_absolute" => Some(Self::EeAbsolute),
            "base_joint_absolute" => Some(Self::BaseJointAbsolute),
            _ => None,
        }
    }
}

/// The language prompt of a task (AMBENCH_SPEC §7.1; the reference has none for NDT: its
/// title is used).
pub fn task_prompt(task: TaskId) -> &'static str {
    match task {
        TaskId::CabinetPickPlace => {
            "open the cabinet sliding door, pick up the red can, and place it on top of the cabinet"
        }
        TaskId::FrameAssembly => "pick up the frame and install it on the four posts",
        TaskId::LemonHarvesting => "pick the yellow lemon and place it in the bin",
        TaskId::OpenDoor => "open the door",
        TaskId::PegInHole => "insert the peg into the hole",
        TaskId::PressButton => "press the button",
        TaskId::PullLever => "pull the lever upwards",
        TaskId::PushSlider => "push the slider to the right",
        TaskId::RotateValve => "rotate the valve clockwise",
        TaskId::TossBall => "toss the ball into the bin",
        TaskId::WipeWindow => "clear the red stain on the window",
        TaskId::Ndt => task.title(),
    }
}

/// The feature key of a camera's images: `observation.images.<full name>` (`ee` →
/// `observation.images.ee_camera`), the reference's names, which its training and export
/// scripts look for.
pub fn image_key(camera: &str) -> String {
    format!(
        "observation.images.{}",
        crate::flight::full_camera_name(camera)
    )
}

/// What one dataset records: its features and what they mean.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetSpec {
    /// Frames per second.
    pub fps: u32,
    /// `robot_type` (the vehicle id).
    pub robot_type: String,
    /// The observation state's keys, in order.
    pub state_keys: Vec<String>,
    /// Width of the state.
    pub state_dim: usize,
    /// What the action means.
    pub action_semantics: ActionSemantics,
    /// Width of the action.
    pub action_dim: usize,
    /// Cameras recorded: (feature key, height, width).
    pub images: Vec<(String, usize, usize)>,
    /// The cameras are stored as MP4 videos (dtype `video`), not as images in the data files.
    pub video: bool,
}

impl DatasetSpec {
    /// The spec of a recording on `vehicle` with `state_keys` and `semantics`, at `fps`, with
    /// the cameras (name, height, width).
    pub fn new(
        vehicle: &Vehicle,
        state_keys: &[StateKey],
        semantics: ActionSemantics,
        fps: u32,
        cameras: &[(String, usize, usize)],
    ) -> Self {
        Self {
            fps,
            robot_type: vehicle.id.clone(),
            state_keys: state_keys.iter().map(|k| k.name().to_owned()).collect(),
            state_dim: state_keys.iter().map(|k| k.dim(vehicle)).sum(),
            action_semantics: semantics,
            action_dim: match semantics {
                ActionSemantics::EeAbsolute => 8,
                ActionSemantics::BaseJointAbsolute => 8 + vehicle.arm_dof(),
            },
            images: cameras
                .iter()
                .map(|(name, h, w)| (image_key(name), *h, *w))
                .collect(),
            video: false,
        }
    }

    /// The same spec with the cameras stored as MP4 videos.
    #[must_use]
    pub fn with_video(mut self, video: bool) -> Self {
        self.video = video;
        self
    }

    /// Every feature, in lerobot's order: the recorded ones, then timestamp, frame_index,
    /// episode_index, index, task_index.
    pub fn features(&self) -> Vec<Feature> {
        let mut features = vec![
            Feature {
                key: "observation.state".to_owned(),
                dtype: Dtype::Float32,
                shape: vec![self.state_dim],
                names: Some((0..self.state_dim).map(|i| format!("state_{i}")).collect()),
            },
            Feature {
                key: "action".to_owned(),
                dtype: Dtype::Float32,
                shape: vec![self.action_dim],
                names: Some(
                    (0..self.action_dim)
                        .map(|i| format!("action_{i}"))
                        .collect(),
                ),
            },
        ];
        for (key, h, w) in &self.images {
            features.push(Feature {
                key: key.clone(),
                dtype: if self.video {
                    Dtype::Video
                } else {
                    Dtype::Image
                },
                shape: vec![*h, *w, 3],
                names: Some(vec!["height".into(), "width".into(), "channels".into()]),
            });
        }
        features.push(Feature::scalar("timestamp", Dtype::Float32));
        for key in ["frame_index", "episode_index", "index", "task_index"] {
            features.push(Feature::scalar(key, Dtype::Int64));
        }
        features
    }

    /// The `ambench` block of `info.json`.
    pub fn ambench_block(&self) -> Value {
        json!({
            "action_semantics": self.action_semantics.name(),
            "state_keys": self.state_keys,
        })
    }

    /// Reads the spec back from an `info.json`.
    pub fn from_info(info: &Value, file: &str) -> Result<Self, DatasetError> {
        let bad = |what: String| DatasetError::Invalid {
            path: file.to_owned(),
            what,
        };
        let features = info
            .get("features")
            .and_then(Value::as_object)
            .ok_or_else(|| bad("no `features` object".into()))?;
        let dim = |key: &str| -> Result<usize, DatasetError> {
            features
                .get(key)
                .and_then(|f| f.get("shape"))
                .and_then(|s| s.get(0))
                .and_then(Value::as_u64)
                .map(|d| d as usize)
                .ok_or_else(|| bad(format!("features.{key}: no shape")))
        };
        let ambench = info
            .get("ambench")
            .or_else(|| info.get("am_isaac"))
            .ok_or_else(|| bad("no `ambench` block".into()))?;
        let semantics = ambench
            .get("action_semantics")
            .and_then(Value::as_str)
            .and_then(ActionSemantics::parse)
            .ok_or_else(|| bad("ambench.action_semantics: missing or unknown".into()))?;
        let state_keys = ambench
            .get("state_keys")
            .and_then(Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(Value::as_str)
                    .map(str::to_owned)
                    .collect()
            })
            .unwrap_or_default();
        let mut images = Vec::new();
        let mut videos = 0;
        for (key, f) in features {
            let dtype = f.get("dtype").and_then(Value::as_str);
            videos += usize::from(dtype == Some("video"));
            if dtype == Some("image") || dtype == Some("video") {
                let shape: Vec<usize> = f
                    .get("shape")
                    .and_then(Value::as_array)
                    .map(|s| {
                        s.iter()
                            .filter_map(Value::as_u64)
                            .map(|d| d as usize)
                            .collect()
                    })
                    .unwrap_or_default();
                let [h, w, 3] = shape[..] else {
                    return Err(bad(format!(
                        "features.{key}: shape {shape:?} is not [height, width, 3]"
                    )));
                };
                images.push((key.clone(), h, w));
            }
        }
        if videos != 0 && videos != images.len() {
            return Err(bad(format!(
                "features: {videos} video and {} image cameras (amstack reads one kind)",
                images.len() - videos
            )));
        }
        Ok(Self {
            fps: info
                .get("fps")
                .and_then(Value::as_u64)
                .and_then(|f| u32::try_from(f).ok())
                .filter(|f| *f > 0)
                .ok_or_else(|| bad("fps: missing or not a positive integer".into()))?,
            robot_type: info
                .get("robot_type")
                .and_then(Value::as_str)
                .unwrap_or_default()
                .to_owned(),
            state_keys,
            state_dim: dim("observation.state")?,
            action_semantics: semantics,
            action_dim: dim("action")?,
            images,
            video: videos > 0,
        })
    }
}

/// The observation state of `m` on `vehicle`: the keys' values, concatenated.
pub fn state_vector(vehicle: &Vehicle, keys: &[StateKey], m: &Measurement, out: &mut Vec<f32>) {
    let push3 = |out: &mut Vec<f32>, v: &nalgebra::Vector3<f64>| {
        out.extend(v.iter().map(|x| *x as f32));
    };
    let push_quat = |out: &mut Vec<f32>, q: &nalgebra::UnitQuaternion<f64>| {
        out.extend([q.w, q.i, q.j, q.k].iter().map(|x| *x as f32));
    };
    for key in keys {
        match key {
            StateKey::EePos => push3(out, &m.world_from_ee.translation.vector),
            StateKey::EeQuat => push_quat(out, &m.world_from_ee.rotation),
            StateKey::GripperWidth => {
                let width: f64 = vehicle
                    .gripper
                    .as_ref()
                    .map(|g| {
                        g.joints
                            .iter()
                            .filter_map(|&j| vehicle.model.joints[j].dof)
                            .filter_map(|d| m.joint_positions.get(d))
                            .sum()
                    })
                    .unwrap_or(0.0);
                out.push(width as f32);
            }
            StateKey::BasePos => push3(out, &m.base.position_in_world_m),
            StateKey::BaseQuat => push_quat(out, &m.base.world_from_body),
            StateKey::BaseLinVel => push3(out, &m.base.velocity_in_world_mps),
            StateKey::BaseAngVel => push3(
                out,
                &(m.base.world_from_body * m.base.angular_velocity_in_body_radps),
            ),
            StateKey::ArmJointPos => out.extend(
                vehicle
                    .arm_dofs()
                    .iter()
                    .map(|&d| m.joint_positions.get(d).copied().unwrap_or(f64::NAN) as f32),
            ),
            StateKey::ArmJointVel => out.extend(
                vehicle
                    .arm_dofs()
                    .iter()
                    .map(|&d| m.joint_velocities.get(d).copied().unwrap_or(f64::NAN) as f32),
            ),
        }
    }
}

/// The action vector of `action` (AMBENCH_SPEC §5.2), as float32.
pub fn action_vector(action: &Action) -> Vec<f32> {
    let (pose, tail, gripper): (&nalgebra::Isometry3<f64>, &[f64], f64) = match action {
        Action::Ee(ee) => (&ee.world_from_ee_command, &[], ee.gripper),
        Action::BaseJoint(t) => (&t.world_from_base, &t.arm_joints, t.gripper),
    };
    let p = pose.translation.vector;
    let q = pose.rotation;
    let mut v: Vec<f32> = [p.x, p.y, p.z, q.w, q.i, q.j, q.k]
        .iter()
        .map(|x| *x as f32)
        .collect();
    v.extend(tail.iter().map(|x| *x as f32));
    v.push(gripper as f32);
    v
}

/// The action of an action vector, exactly: the quaternion is taken as its four float32
/// values (not renormalised), so that `action_vector(action_of_vector(v)) == v` bit for bit
/// and a replay of recorded actions flies what the recording flew.
pub fn action_of_vector(semantics: ActionSemantics, v: &[f32]) -> Option<Action> {
    if v.len() < 8 {
        return None;
    }
    let f = |i: usize| f64::from(v[i]);
    let pose = nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(f(0), f(1), f(2)),
        nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(f(3), f(4), f(5), f(6))),
    );
    let gripper = f(v.len() - 1);
    Some(match semantics {
        ActionSemantics::EeAbsolute if v.len() == 8 => Action::Ee(EeTarget {
            world_from_ee_command: pose,
            gripper,
        }),
        ActionSemantics::BaseJointAbsolute => Action::BaseJoint(BaseJointTarget {
            world_from_base: pose,
            arm_joints: v[7..v.len() - 1].iter().map(|x| f64::from(*x)).collect(),
            gripper,
        }),
        ActionSemantics::EeAbsolute => return None,
    })
}
