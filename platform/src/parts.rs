//! What a vehicle carries besides its rotors: the gripper, the twin's joint drives, cameras.

use nalgebra::{Isometry3, Vector3};
use serde::Serialize;

use crate::model::{JointId, LinkId};

/// The gripper: joints and their open and closed positions.
///
/// Action mapping (AMBENCH_SPEC §1.2): a ∈ [−1, 1], −1 closed, +1 open;
/// target = closed + ½(a + 1)(open − closed), per joint.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Gripper {
    /// Gripper joints.
    pub joints: Vec<JointId>,
    /// Closed position per joint.
    pub closed: Vec<f64>,
    /// Open position per joint.
    pub open: Vec<f64>,
}

impl Gripper {
    /// Joint targets for a gripper action a (clamped to [−1, 1]; NaN counts as closed).
    pub fn targets(&self, action: f64) -> Vec<f64> {
        let a = if action.is_nan() {
            -1.0
        } else {
            action.clamp(-1.0, 1.0)
        };
        self.closed
            .iter()
            .zip(&self.open)
            .map(|(c, o)| c + 0.5 * (a + 1.0) * (o - c))
            .collect()
    }
}

/// A joint's position drive in the twin (implicit PD toward a target).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct JointDrive {
    /// The joint.
    pub joint: JointId,
    /// N·m/rad or N/m.
    pub stiffness: f64,
    /// N·m·s/rad or N·s/m.
    pub damping: f64,
    /// N·m or N.
    pub effort_limit: f64,
    /// rad/s or m/s.
    pub velocity_limit: f64,
    /// Position at reset, rad or m.
    pub initial: f64,
}

/// A pinhole camera mounted on a link (ROS optical frame: +z forward, +x right, +y down).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraMount {
    /// Unique name.
    pub name: String,
    /// Parent link.
    pub link: LinkId,
    /// Camera frame in the link frame.
    pub link_from_camera: Isometry3<f64>,
    /// Image width, px.
    pub width_px: u32,
    /// Image height, px.
    pub height_px: u32,
    /// Focal length (same unit as the aperture).
    pub focal_length_mm: f64,
    /// Horizontal aperture.
    pub horizontal_aperture_mm: f64,
    /// Near and far clipping distances, m.
    pub clip_m: [f64; 2],
}

impl CameraMount {
    /// Horizontal field of view, rad: 2·atan(aperture / (2·focal)).
    pub fn horizontal_fov_rad(&self) -> f64 {
        2.0 * (self.horizontal_aperture_mm / (2.0 * self.focal_length_mm)).atan()
    }

    /// The optical axis (+z of the camera frame) in the link frame.
    pub fn optical_axis_in_link(&self) -> Vector3<f64> {
        self.link_from_camera.rotation * Vector3::z()
    }
}
