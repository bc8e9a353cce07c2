//! The vehicle file: a TOML document beside the URDF that says what the flight stack needs on
//! top of the kinematic tree — which links are the base and the end effector, the rotors, the
//! gripper, the twin's joint drives and the cameras. Unknown fields are refused (a typo is an
//! error, never a silent default). See `platform/vehicles/*.toml` for the five vehicles.
//!
//! Fixed-size values (positions, quaternions) are read as lists and their length checked when
//! the vehicle is assembled: serde's fixed arrays would silently drop a fifth quaternion entry.

use serde::Deserialize;

use crate::actuation::Actuation;
use crate::error::{DescriptionError, Problem, one_line};

/// The schema version this amstack reads.
pub const VEHICLE_SCHEMA: u32 = 1;

/// A parsed (not yet cross-checked) vehicle file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleFile {
    /// Schema version; must be [`VEHICLE_SCHEMA`].
    pub schema: u32,
    /// Stable id used on the command line and in results (`fa-hexa`).
    pub id: String,
    /// Display name (`FA-Hexa`).
    pub name: String,
    /// Path of the URDF, relative to this file.
    pub urdf: String,
    /// Actuation class.
    pub actuation: Actuation,
    /// The base link; must be the URDF root. Wrenches of the base controller act here.
    pub base_link: String,
    /// The end-effector link.
    pub ee_link: String,
    /// Tool tip in the end-effector link frame, m.
    pub tool_tip_in_ee_m: Vec<f64>,
    /// Command-frame to link-frame rotation, w x y z: link_quat = offset ⊗ command_quat.
    pub command_to_link_wxyz: Vec<f64>,
    /// Arm joints in command order.
    pub arm_joints: Vec<String>,
    /// Normaliser of the tracking metrics, m (absent for a vehicle without an arm).
    #[serde(default)]
    pub max_arm_reach_m: Option<f64>,
    /// The gripper.
    #[serde(default)]
    pub gripper: Option<GripperFile>,
    /// The rotors (absent for the EE-only oracle).
    #[serde(default)]
    pub rotors: Option<RotorsFile>,
    /// Joint position drives of the twin.
    #[serde(default)]
    pub drive: Vec<DriveFile>,
    /// Cameras.
    #[serde(default)]
    pub camera: Vec<CameraFile>,
    /// `[colors]`: the renderer's colour of a link's visual shapes, linear RGB in [0, 1], by
    /// link name (`base_link = [0.2, 0.2, 0.25]`). A URDF `<material>` colour wins; links
    /// named nowhere get the renderer's default by role.
    #[serde(default)]
    pub colors: std::collections::BTreeMap<String, Vec<f64>>,
    /// The controller and IK presets (required: read as `Option` so that its absence is
    /// refused with one line naming the section, not a parser's message).
    #[serde(default)]
    pub control: Option<ControlFile>,
    /// The PX4 HIL channel map (`amstack twin serve --px4-hil`; absent: the vehicle cannot
    /// be served to PX4).
    #[serde(default)]
    pub px4_hil: Option<crate::px4_hil::Px4HilFile>,
}

/// `[control]`: which presets of the `controllers` crate fly this vehicle. Names, not numbers:
/// the gains live with the controllers (`controllers::profile`), the vehicle says which.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlFile {
    /// The base controller of `--controller pid` (`pid6-am-bench`, `pid6-omni`,
    /// `pid4-ua-hexa`, `pid4-ua-quad`).
    pub pid: String,
    /// The L1 preset of `--controller l1` (`l1-am-bench`, `l1-omni`); absent: L1 is not
    /// offered (an under-actuated vehicle).
    #[serde(default)]
    pub l1: Option<String>,
    /// The whole-body MPC preset of `--controller mpc` (`mpc-fa-hexa`); absent: no MPC.
    #[serde(default)]
    pub mpc: Option<String>,
    /// The whole-body IK preset of the end-effector interface (`fa-hexa`, `ua-hexa`,
    /// `ua-quad`, `omni-hexa`); absent for a vehicle whose end effector is its base.
    #[serde(default)]
    pub ik: Option<String>,
}

/// `[gripper]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GripperFile {
    /// Gripper joints (two prismatic fingers, or one revolute jaw).
    pub joints: Vec<String>,
    /// Closed position per joint; default: each joint's lower limit.
    #[serde(default)]
    pub closed: Option<Vec<f64>>,
    /// Open position per joint; default: each joint's upper limit.
    #[serde(default)]
    pub open: Option<Vec<f64>>,
}

/// `[rotors]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotorsFile {
    /// Number of rotors; checked against the entries of `rotor`.
    pub count: usize,
    /// N.
    pub thrust_min_n: f64,
    /// N.
    pub thrust_max_n: f64,
    /// k_f, m.
    pub reaction_torque_ratio_m: f64,
    /// m.
    pub propeller_radius_m: f64,
    /// PX4's `THR_MDL_FAC` k ∈ [0, 1]: the thrust curve of a normalised motor command u,
    /// t = k·u² + (1 − k)·u (default 0: linear).
    #[serde(default)]
    pub thrust_model_factor: f64,
    /// One entry per rotor, in actuator order.
    pub rotor: Vec<RotorFile>,
}

/// One entry of `rotors.rotor`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotorFile {
    /// URDF link marking the rotor: origin = rotor centre, +z = thrust axis (at tilt 0).
    pub link: String,
    /// +1 or −1: sense of the reaction torque along the thrust axis.
    pub spin: i64,
    /// Tilt hinge joint, for a variable-tilt rotor.
    #[serde(default)]
    pub tilt_joint: Option<String>,
}

/// `[[drive]]`: position drives (implicit PD) of a group of joints.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveFile {
    /// The joints driven.
    pub joints: Vec<String>,
    /// N·m/rad or N/m.
    pub stiffness: f64,
    /// N·m·s/rad or N·s/m.
    pub damping: f64,
    /// N·m or N.
    pub effort_limit: f64,
    /// rad/s or m/s.
    pub velocity_limit: f64,
    /// Initial position: one value for all joints, or one per joint.
    pub initial: Initial,
}

/// One value for all joints of a drive, or one per joint.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum Initial {
    /// Every joint at this position.
    All(f64),
    /// One position per joint.
    Each(Vec<f64>),
}

/// `[[camera]]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    /// Unique name (`ee_camera`).
    pub name: String,
    /// Parent link.
    pub link: String,
    /// Position in the parent link, m.
    pub position_m: Vec<f64>,
    /// Orientation in the parent link, w x y z, ROS optical convention (+z forward, +x right, +y down).
    pub orientation_wxyz: Vec<f64>,
    /// Default 384.
    #[serde(default = "default_resolution")]
    pub width_px: u32,
    /// Default 384.
    #[serde(default = "default_resolution")]
    pub height_px: u32,
    /// Default 19.6 (Isaac convention: same unit as the aperture).
    #[serde(default = "default_focal")]
    pub focal_length_mm: f64,
    /// Default 20.955.
    #[serde(default = "default_aperture")]
    pub horizontal_aperture_mm: f64,
    /// Near and far clipping distances, m; default [0.01, 1000].
    #[serde(default = "default_clip")]
    pub clip_m: Vec<f64>,
}

fn default_resolution() -> u32 {
    384
}
fn default_focal() -> f64 {
    19.6
}
fn default_aperture() -> f64 {
    20.955
}
fn default_clip() -> Vec<f64> {
    vec![0.01, 1000.0]
}

impl VehicleFile {
    /// Parses a vehicle file. `file` names it in errors.
    pub fn parse(file: &str, text: &str) -> Result<Self, DescriptionError> {
        let parsed: Self = toml::from_str(text).map_err(|e| {
            let field = match e.span() {
                Some(span) => {
                    let line = text[..span.start.min(text.len())].matches('\n').count() + 1;
                    format!("line {line}")
                }
                None => String::new(),
            };
            DescriptionError::new(file, field, Problem::Syntax(one_line(e.message())))
        })?;
        if parsed.schema != VEHICLE_SCHEMA {
            return Err(DescriptionError::new(
                file,
                "schema",
                Problem::Invalid(format!(
                    "version {} is not supported (this amstack reads version {VEHICLE_SCHEMA})",
                    parsed.schema
                )),
            ));
        }
        Ok(parsed)
    }
}
