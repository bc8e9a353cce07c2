//! Foxglove's well-known schemas used by amstack, as Rust types.
//!
//! Field names, nesting and schema names are Foxglove's (`foxglove.PoseInFrame`,
//! `foxglove.FrameTransforms`, …), so Foxglove's 3D and plot panels understand the channels.
//! Foxglove's quaternions are objects `{x, y, z, w}`: named fields, so the order question of
//! amstack's array convention (`[w, x, y, z]`) does not arise here.
//!
//! Only the required fields of each schema are modelled (Foxglove's optional `message_id` /
//! `lineage` are left out).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::SchemaName;

const NANOS_PER_SEC: u64 = 1_000_000_000;

/// `foxglove.Time`: a timestamp as seconds and nanoseconds since the run's epoch (in amstack,
/// the start of the run in simulated or flight time, see the [module doc](super)).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default, Serialize, Deserialize, JsonSchema,
)]
#[schemars(rename = "foxglove.Time", title = "foxglove.Time")]
pub struct Time {
    /// Whole seconds.
    pub sec: u32,
    /// Nanoseconds past `sec`, below 1e9.
    #[schemars(range(max = 999_999_999))]
    pub nsec: u32,
}

impl Time {
    /// Splits a time in nanoseconds. Seconds saturate at `u32::MAX` (year 2106 as a Unix time;
    /// 136 years of run time), where the nanoseconds are clamped to the last representable one.
    pub fn from_nanos(time_ns: u64) -> Self {
        let sec = time_ns / NANOS_PER_SEC;
        match u32::try_from(sec) {
            // The remainder is below 1e9 < u32::MAX.
            Ok(sec) => Self {
                sec,
                nsec: (time_ns % NANOS_PER_SEC) as u32,
            },
            Err(_) => Self {
                sec: u32::MAX,
                nsec: 999_999_999,
            },
        }
    }

    /// The time in nanoseconds.
    pub fn as_nanos(self) -> u64 {
        u64::from(self.sec) * NANOS_PER_SEC + u64::from(self.nsec)
    }
}

/// `foxglove.Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[schemars(rename = "foxglove.Vector3", title = "foxglove.Vector3")]
pub struct Vector3 {
    /// x coordinate.
    pub x: f64,
    /// y coordinate.
    pub y: f64,
    /// z coordinate.
    pub z: f64,
}

/// `foxglove.Quaternion` (unit quaternion; fields x, y, z, w).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[schemars(rename = "foxglove.Quaternion", title = "foxglove.Quaternion")]
pub struct Quaternion {
    /// x (vector part).
    pub x: f64,
    /// y (vector part).
    pub y: f64,
    /// z (vector part).
    pub z: f64,
    /// w (scalar part).
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity rotation.
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `foxglove.Pose`: position and orientation of a frame in its parent.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[schemars(rename = "foxglove.Pose", title = "foxglove.Pose")]
pub struct Pose {
    /// Position, m.
    pub position: Vector3,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `foxglove.PoseInFrame`: a timestamped pose in a named frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[schemars(rename = "foxglove.PoseInFrame", title = "foxglove.PoseInFrame")]
pub struct PoseInFrame {
    /// Time of the pose.
    pub timestamp: Time,
    /// Frame the pose is expressed in (e.g. `world`).
    pub frame_id: String,
    /// The pose.
    pub pose: Pose,
}

/// `foxglove.FrameTransform`: where `child_frame_id` is in `parent_frame_id` (the isometry
/// `parent_from_child`: `translation` is the child origin in the parent frame, `rotation` the
/// child's orientation in it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[schemars(rename = "foxglove.FrameTransform", title = "foxglove.FrameTransform")]
pub struct FrameTransform {
    /// Time of the transform.
    pub timestamp: Time,
    /// Parent frame.
    pub parent_frame_id: String,
    /// Child frame.
    pub child_frame_id: String,
    /// Child origin in the parent frame, m.
    pub translation: Vector3,
    /// Child orientation in the parent frame.
    pub rotation: Quaternion,
}

/// `foxglove.FrameTransforms`: several transforms in one message (e.g. the whole arm chain).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[schemars(
    rename = "foxglove.FrameTransforms",
    title = "foxglove.FrameTransforms"
)]
pub struct FrameTransforms {
    /// The transforms.
    pub transforms: Vec<FrameTransform>,
}

impl SchemaName for Time {
    const SCHEMA_NAME: &'static str = "foxglove.Time";
}
impl SchemaName for Vector3 {
    const SCHEMA_NAME: &'static str = "foxglove.Vector3";
}
impl SchemaName for Quaternion {
    const SCHEMA_NAME: &'static str = "foxglove.Quaternion";
}
impl SchemaName for Pose {
    const SCHEMA_NAME: &'static str = "foxglove.Pose";
}
impl SchemaName for PoseInFrame {
    const SCHEMA_NAME: &'static str = "foxglove.PoseInFrame";
}
impl SchemaName for FrameTransform {
    const SCHEMA_NAME: &'static str = "foxglove.FrameTransform";
}
impl SchemaName for FrameTransforms {
    const SCHEMA_NAME: &'static str = "foxglove.FrameTransforms";
}

impl From<&nalgebra::Vector3<f64>> for Vector3 {
    fn from(v: &nalgebra::Vector3<f64>) -> Self {
        Self {
            x: v.x,
            y: v.y,
            z: v.z,
        }
    }
}

impl From<&Translation3<f64>> for Vector3 {
    fn from(t: &Translation3<f64>) -> Self {
        Self::from(&t.vector)
    }
}

impl From<&UnitQuaternion<f64>> for Quaternion {
    fn from(q: &UnitQuaternion<f64>) -> Self {
        Self {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }
    }
}

impl From<&Isometry3<f64>> for Pose {
    /// The pose of the frame whose placement is `parent_from_frame`.
    fn from(parent_from_frame: &Isometry3<f64>) -> Self {
        Self {
            position: Vector3::from(&parent_from_frame.translation),
            orientation: Quaternion::from(&parent_from_frame.rotation),
        }
    }
}

impl PoseInFrame {
    /// The pose `frame_from_body` of a body, expressed in `frame_id`, at `time_ns`.
    pub fn new(
        time_ns: u64,
        frame_id: impl Into<String>,
        frame_from_body: &Isometry3<f64>,
    ) -> Self {
        Self {
            timestamp: Time::from_nanos(time_ns),
            frame_id: frame_id.into(),
            pose: Pose::from(frame_from_body),
        }
    }
}

impl FrameTransform {
    /// The transform placing `child` in `parent` (`parent_from_child`), at `time_ns`.
    pub fn new(
        time_ns: u64,
        parent: impl Into<String>,
        child: impl Into<String>,
        parent_from_child: &Isometry3<f64>,
    ) -> Self {
        Self {
            timestamp: Time::from_nanos(time_ns),
            parent_frame_id: parent.into(),
            child_frame_id: child.into(),
            translation: Vector3::from(&parent_from_child.translation),
            rotation: Quaternion::from(&parent_from_child.rotation),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use crate::record::json_schema_of;
    use nalgebra::Vector3 as NVector3;
    use std::f64::consts::FRAC_PI_2;

    fn schema<T: JsonSchema + SchemaName>() -> serde_json::Value {
        serde_json::from_slice(&json_schema_of::<T>().unwrap()).unwrap()
    }

    #[test]
    fn schema_names_are_foxglove_names() {
        fn check<T: JsonSchema + SchemaName>(expected: &str) {
            assert_eq!(T::SCHEMA_NAME, expected);
            assert_eq!(T::schema_name(), expected, "schemars name agrees");
            assert_eq!(schema::<T>()["title"], expected);
        }
        check::<Time>("foxglove.Time");
        check::<Vector3>("foxglove.Vector3");
        check::<Quaternion>("foxglove.Quaternion");
        check::<Pose>("foxglove.Pose");
        check::<PoseInFrame>("foxglove.PoseInFrame");
        check::<FrameTransform>("foxglove.FrameTransform");
        check::<FrameTransforms>("foxglove.FrameTransforms");
    }

    #[test]
    fn pose_in_frame_has_foxglove_layout() {
        let s = schema::<PoseInFrame>();
        let p = &s["properties"];
        assert_eq!(p["timestamp"]["properties"]["nsec"]["maximum"], 999_999_999);
        assert_eq!(p["timestamp"]["title"], "foxglove.Time");
        assert_eq!(p["frame_id"]["type"], "string");
        assert_eq!(p["pose"]["title"], "foxglove.Pose");
        assert_eq!(
            p["pose"]["properties"]["position"]["title"],
            "foxglove.Vector3"
        );
        assert_eq!(
            p["pose"]["properties"]["orientation"]["title"],
            "foxglove.Quaternion"
        );
        for axis in ["x", "y", "z", "w"] {
            assert_eq!(
                p["pose"]["properties"]["orientation"]["properties"][axis]["type"],
                "number"
            );
        }

        let msg = PoseInFrame::new(1_500_000_000, "world", &Isometry3::identity());
        let json: serde_json::Value = serde_json::to_value(&msg).unwrap();
        assert_eq!(
            json,
            serde_json::json!({
                "timestamp": {"sec": 1, "nsec": 500_000_000},
                "frame_id": "world",
                "pose": {
                    "position": {"x": 0.0, "y": 0.0, "z": 0.0},
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
                }
            })
        );
    }

    #[test]
    fn frame_transforms_has_foxglove_layout() {
        let s = schema::<FrameTransforms>();
        let item = &s["properties"]["transforms"]["items"];
        assert_eq!(item["title"], "foxglove.FrameTransform");
        for key in [
            "timestamp",
            "parent_frame_id",
            "child_frame_id",
            "translation",
            "rotation",
        ] {
            assert!(item["properties"].get(key).is_some(), "{key}");
            assert!(
                item["required"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|k| k == key),
                "{key}"
            );
        }
    }

    #[test]
    fn isometry_conversion_keeps_position_and_orientation() {
        // 90° about +z, then at (1, 2, 3): body x axis points along world y.
        let world_from_body =
            Isometry3::new(NVector3::new(1.0, 2.0, 3.0), NVector3::z() * FRAC_PI_2);
        let tf = FrameTransform::new(0, "world", "base_link", &world_from_body);
        assert_eq!(
            tf.translation,
            Vector3 {
                x: 1.0,
                y: 2.0,
                z: 3.0
            }
        );
        let half = FRAC_PI_2 / 2.0;
        let q = tf.rotation;
        let tol = 1e-15;
        assert!(q.x.abs() < tol && q.y.abs() < tol);
        assert!(
            (q.z - half.sin()).abs() < tol && (q.w - half.cos()).abs() < tol,
            "{q:?}"
        );
        let pose = Pose::from(&world_from_body);
        assert_eq!(
            (pose.position, pose.orientation),
            (tf.translation, tf.rotation)
        );
    }

    #[test]
    fn time_splits_nanoseconds_and_saturates() {
        assert_eq!(Time::from_nanos(0), Time { sec: 0, nsec: 0 });
        assert_eq!(
            Time::from_nanos(8_333_333),
            Time {
                sec: 0,
                nsec: 8_333_333
            }
        );
        let t = Time::from_nanos(12 * NANOS_PER_SEC + 999_999_999);
        assert_eq!(
            t,
            Time {
                sec: 12,
                nsec: 999_999_999
            }
        );
        assert_eq!(t.as_nanos(), 12_999_999_999);
        assert_eq!(
            Time::from_nanos(u64::MAX),
            Time {
                sec: u32::MAX,
                nsec: 999_999_999
            }
        );
    }
}
