//! A vehicle: its kinematic tree (URDF) plus what its vehicle file says, cross-checked.

use std::collections::HashSet;

use nalgebra::{
    Isometry3, Matrix6xX, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3,
};
use serde::Serialize;

use crate::MassProperties;
use crate::actuation::Actuation;
use crate::error::{DescriptionError, Problem};
use crate::model::{JointId, JointKind, KinematicModel, LinkId, UNIT_AXIS_TOLERANCE};
use crate::parts::{CameraMount, Gripper, JointDrive};
use crate::px4_hil::{Fit, Px4HilMap};
use crate::rotor::{Rotor, RotorLayout, Spin, ThrustCurve, Tilt};
use crate::vehicle_file::{Initial, VehicleFile};

/// Standard gravity used throughout the stack, m/s² (AMBENCH_SPEC §0).
pub const GRAVITY_MPS2: f64 = 9.81;

/// Tolerance on the norm of a unit quaternion in a vehicle file.
const UNIT_QUATERNION_TOLERANCE: f64 = 1e-6;

/// One vehicle, validated: the single description that the twin, the allocation, IK and MPC
/// all read.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Vehicle {
    /// Stable id (`fa-hexa`).
    pub id: String,
    /// Display name (`FA-Hexa`).
    pub name: String,
    /// Actuation class.
    pub actuation: Actuation,
    /// The kinematic tree; its root is the base link.
    pub model: KinematicModel,
    /// Base link (the URDF root).
    pub base_link: LinkId,
    /// End-effector link.
    pub ee_link: LinkId,
    /// Tool tip in the end-effector link, m.
    pub tool_tip_in_ee_m: Vector3<f64>,
    /// link_quat = command_to_link ⊗ command_quat (a world-frame, left multiplication).
    pub command_to_link: UnitQuaternion<f64>,
    /// Arm joints, in command order.
    pub arm_joints: Vec<JointId>,
    /// The gripper (None if the vehicle has none).
    pub gripper: Option<Gripper>,
    /// Rotors (empty for the EE-only oracle).
    pub rotors: RotorLayout,
    /// Position drives of the twin, one per driven joint.
    pub drives: Vec<JointDrive>,
    /// Cameras.
    pub cameras: Vec<CameraMount>,
    /// Normaliser of the tracking metrics, m.
    pub max_arm_reach_m: Option<f64>,
    /// Colour of each link's visual shapes from the vehicle file's `[colors]`, linear RGB,
    /// indexed by link id (None where the file names none).
    pub link_colors: Vec<Option<[f64; 3]>>,
    /// The controller and IK presets that fly it (`[control]`).
    pub control: ControlPresets,
    /// PX4 HIL channel map (None: the vehicle file has no `[px4_hil]`).
    pub px4_hil: Option<Px4HilMap>,
}

/// The presets of the `controllers` crate a vehicle is flown with (its `[control]` section):
/// names, resolved by `controllers::profile` and `controllers::ik::IkConfig::preset`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ControlPresets {
    /// Base controller of `--controller pid`.
    pub pid: String,
    /// L1 preset, if L1 is offered.
    pub l1: Option<String>,
    /// Whole-body MPC preset, if the MPC is offered.
    pub mpc: Option<String>,
    /// Whole-body IK preset (None: the end effector is the base).
    pub ik: Option<String>,
}

impl Vehicle {
    /// Cross-checks a parsed vehicle file against its URDF and builds the vehicle.
    /// `file_name` and `urdf_name` name the two files in errors.
    pub fn assemble(
        file_name: &str,
        file: &VehicleFile,
        urdf_name: &str,
        urdf_text: &str,
    ) -> Result<Self, DescriptionError> {
        let model = KinematicModel::from_urdf(urdf_name, urdf_text)?;
        Assembler {
            file: file_name,
            model: &model,
        }
        .vehicle(file, model.clone())
    }

    /// Number of arm joints.
    pub fn arm_dof(&self) -> usize {
        self.arm_joints.len()
    }

    /// The configuration with every driven joint at its initial position, others at zero.
    pub fn initial_configuration(&self) -> Vec<f64> {
        let mut q = self.model.zero_configuration();
        for d in &self.drives {
            if let Some(i) = self.model.joints[d.joint].dof {
                q[i] = d.initial;
            }
        }
        q
    }

    /// Configuration indices of the arm joints, in command order.
    pub fn arm_dofs(&self) -> Vec<usize> {
        self.arm_joints
            .iter()
            .filter_map(|&j| self.model.joints[j].dof)
            .collect()
    }

    /// Configuration indices of the tilt hinges, in rotor order (rotors without a tilt
    /// hinge skipped).
    pub fn tilt_dofs(&self) -> Vec<usize> {
        self.rotors
            .rotors
            .iter()
            .filter_map(|r| {
                r.tilt
                    .as_ref()
                    .and_then(|t| self.model.joint_id(&t.joint))
                    .and_then(|j| self.model.joints.get(j))
                    .and_then(|j| j.dof)
            })
            .collect()
    }

    /// The end-effector link frame in the base frame at configuration `q`.
    pub fn base_from_ee(&self, q: &[f64]) -> Isometry3<f64> {
        self.model.root_from_link(q, self.ee_link)
    }

    /// The tool-tip position in the base frame at configuration `q`, m.
    pub fn tool_tip_in_base(&self, q: &[f64]) -> Vector3<f64> {
        (self.base_from_ee(q) * Point3::from(self.tool_tip_in_ee_m)).coords
    }

    /// Geometric Jacobian (6 × dof, base frame) of the tool tip at configuration `q`.
    pub fn tool_tip_jacobian(&self, q: &[f64]) -> Matrix6xX<f64> {
        self.model.jacobian(q, self.ee_link, &self.tool_tip_in_ee_m)
    }

    /// Mass, centre of mass and inertia at configuration `q`.
    pub fn mass_properties(&self, q: &[f64]) -> MassProperties {
        self.model.mass_properties(q)
    }

    /// Sum of the rotors' vertical axis components at tilt 0 (how many "rotor-equivalents"
    /// of thrust push up).
    fn vertical_axis_sum(&self) -> f64 {
        self.rotors.rotors.iter().map(|r| r.axis_in_base.z).sum()
    }

    /// Thrust each rotor gives when all share the weight equally at the zero configuration,
    /// m·g / Σ n_z, N (None without rotors).
    pub fn hover_thrust_per_rotor_n(&self) -> Option<f64> {
        let up = self.vertical_axis_sum();
        (up > 0.0).then(|| self.model.total_mass_kg() * GRAVITY_MPS2 / up)
    }

    /// Largest vertical thrust over weight, Σ T_max n_z / (m·g) (None without rotors).
    pub fn thrust_to_weight(&self) -> Option<f64> {
        let up = self.vertical_axis_sum();
        (up > 0.0)
            .then(|| self.rotors.thrust_max_n * up / (self.model.total_mass_kg() * GRAVITY_MPS2))
    }
}

struct Assembler<'a> {
    file: &'a str,
    model: &'a KinematicModel,
}

impl Assembler<'_> {
    fn err(&self, field: impl Into<String>, problem: Problem) -> DescriptionError {
        DescriptionError::new(self.file, field, problem)
    }

    fn invalid(&self, field: impl Into<String>, message: String) -> DescriptionError {
        self.err(field, Problem::Invalid(message))
    }

    fn link(&self, field: &str, name: &str) -> Result<LinkId, DescriptionError> {
        self.model
            .link_id(name)
            .ok_or_else(|| self.err(field, Problem::UnknownLink(name.to_owned())))
    }

    /// A joint that moves (arm, gripper, drive, tilt).
    fn movable_joint(&self, field: &str, name: &str) -> Result<JointId, DescriptionError> {
        let id = self
            .model
            .joint_id(name)
            .ok_or_else(|| self.err(field, Problem::UnknownJoint(name.to_owned())))?;
        if self.model.joints[id].kind == JointKind::Fixed {
            return Err(self.invalid(field, format!("joint '{name}' is fixed")));
        }
        Ok(id)
    }

    /// A list of exactly N finite numbers.
    fn array<const N: usize>(
        &self,
        field: &str,
        values: &[f64],
    ) -> Result<[f64; N], DescriptionError> {
        let array: [f64; N] = values.try_into().map_err(|_| {
            self.invalid(
                field,
                format!("{values:?} has {} values, needs {N}", values.len()),
            )
        })?;
        self.finite(field, &array)?;
        Ok(array)
    }

    fn finite(&self, field: &str, values: &[f64]) -> Result<(), DescriptionError> {
        if values.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(self.invalid(field, format!("{values:?} is not finite")))
        }
    }

    fn unit_quaternion(
        &self,
        field: &str,
        wxyz: &[f64],
    ) -> Result<UnitQuaternion<f64>, DescriptionError> {
        let wxyz: [f64; 4] = self.array(field, wxyz)?;
        let q = Quaternion::new(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
        let norm = q.norm();
        if (norm - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
            return Err(self.invalid(
                field,
                format!("{wxyz:?} is not a unit quaternion (norm {norm})"),
            ));
        }
        Ok(Unit::new_normalize(q))
    }

    fn within_limits(
        &self,
        field: &str,
        joint: JointId,
        value: f64,
    ) -> Result<(), DescriptionError> {
        let j = &self.model.joints[joint];
        if let Some(l) = j.limits
            && !(l.lower..=l.upper).contains(&value)
        {
            return Err(self.invalid(
                field,
                format!(
                    "{value} is outside joint '{}' limits [{}, {}]",
                    j.name, l.lower, l.upper
                ),
            ));
        }
        Ok(())
    }

    fn vehicle(&self, f: &VehicleFile, model: KinematicModel) -> Result<Vehicle, DescriptionError> {
        if f.id.is_empty()
            || !f
                .id
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-')
        {
            return Err(self.invalid(
                "id",
                format!("'{}' must be lowercase letters, digits and '-'", f.id),
            ));
        }
        let base_link = self.link("base_link", &f.base_link)?;
        if base_link != model.root {
            return Err(self.invalid(
                "base_link",
                format!(
                    "'{}' is not the URDF root link '{}'",
                    f.base_link, model.links[model.root].name
                ),
            ));
        }
        let ee_link = self.link("ee_link", &f.ee_link)?;
        let tool_tip_in_ee_m: [f64; 3] = self.array("tool_tip_in_ee_m", &f.tool_tip_in_ee_m)?;
        let command_to_link =
            self.unit_quaternion("command_to_link_wxyz", &f.command_to_link_wxyz)?;

        let mut arm_joints = Vec::with_capacity(f.arm_joints.len());
        for (i, name) in f.arm_joints.iter().enumerate() {
            let field = format!("arm_joints[{i}]");
            let j = self.movable_joint(&field, name)?;
            if arm_joints.contains(&j) {
                return Err(self.err(field, Problem::DuplicateJoint(name.clone())));
            }
            if !model.chain(ee_link).contains(&j) {
                return Err(self.invalid(
                    field,
                    format!("joint '{name}' does not move ee_link '{}'", f.ee_link),
                ));
            }
            arm_joints.push(j);
        }
        if let Some(reach) = f.max_arm_reach_m
            && !(reach.is_finite() && reach > 0.0)
        {
            return Err(self.invalid(
                "max_arm_reach_m",
                format!("{reach} must be finite and positive"),
            ));
        }

        let gripper = f.gripper.as_ref().map(|g| self.gripper(g)).transpose()?;
        let rotors = self.rotors(f)?;
        let drives = self.drives(f)?;
        let cameras = self.cameras(f)?;
        let link_colors = self.colors(f)?;
        let Some(c) = &f.control else {
            return Err(self.invalid(
                "control",
                "missing section [control]: name the controller and IK presets that fly this \
                 vehicle (pid = \"…\", and ik = \"…\" for an arm), as \
                 platform/vehicles/fa-hexa.toml does"
                    .to_owned(),
            ));
        };
        if c.ik.is_none() && ee_link != base_link {
            return Err(self.invalid(
                "control.ik",
                "missing: a vehicle with an arm needs the IK preset of its end-effector interface"
                    .to_owned(),
            ));
        }
        let control = ControlPresets {
            pid: c.pid.clone(),
            l1: c.l1.clone(),
            mpc: c.mpc.clone(),
            ik: c.ik.clone(),
        };
        let px4_hil = f
            .px4_hil
            .as_ref()
            .map(|map| {
                let fit = Fit {
                    rotors: rotors.rotors.len(),
                    tilts: rotors.rotors.iter().filter(|r| r.tilt.is_some()).count(),
                    arm_joints: arm_joints.len(),
                    gripper: gripper.is_some(),
                };
                Px4HilMap::check(self.file, map, &fit)
            })
            .transpose()?;

        Ok(Vehicle {
            id: f.id.clone(),
            name: f.name.clone(),
            actuation: f.actuation,
            model,
            base_link,
            ee_link,
            tool_tip_in_ee_m: Vector3::from(tool_tip_in_ee_m),
            command_to_link,
            arm_joints,
            gripper,
            rotors,
            drives,
            cameras,
            max_arm_reach_m: f.max_arm_reach_m,
            link_colors,
            control,
            px4_hil,
        })
    }

    fn gripper(&self, g: &crate::vehicle_file::GripperFile) -> Result<Gripper, DescriptionError> {
        let mut joints = Vec::with_capacity(g.joints.len());
        for (i, name) in g.joints.iter().enumerate() {
            joints.push(self.movable_joint(&format!("gripper.joints[{i}]"), name)?);
        }
        let limit = |j: JointId, upper: bool| {
            self.model.joints[j]
                .limits
                .map(|l| if upper { l.upper } else { l.lower })
        };
        let side =
            |name: &str,
             given: &Option<Vec<f64>>,
             upper: bool|
             -> Result<Vec<f64>, DescriptionError> {
                let field = format!("gripper.{name}");
                let values =
                    match given {
                        Some(v) => v.clone(),
                        None => joints
                            .iter()
                            .map(|&j| {
                                limit(j, upper).ok_or_else(|| {
                                    self.invalid(field.clone(), format!(
                                "joint '{}' has no limits: give gripper.{name} explicitly",
                                self.model.joints[j].name
                            ))
                                })
                            })
                            .collect::<Result<_, _>>()?,
                    };
                if values.len() != joints.len() {
                    return Err(self.invalid(
                        field,
                        format!(
                            "has {} values for {} gripper joints",
                            values.len(),
                            joints.len()
                        ),
                    ));
                }
                for (v, &j) in values.iter().zip(&joints) {
                    self.finite(&field, &[*v])?;
                    self.within_limits(&field, j, *v)?;
                }
                Ok(values)
            };
        let closed = side("closed", &g.closed, false)?;
        let open = side("open", &g.open, true)?;
        Ok(Gripper {
            joints,
            closed,
            open,
        })
    }

    fn rotors(&self, f: &VehicleFile) -> Result<RotorLayout, DescriptionError> {
        let Some(r) = &f.rotors else {
            if f.actuation != Actuation::FloatingEndEffector {
                return Err(self.invalid(
                    "rotors",
                    format!(
                        "missing: a {} vehicle needs a [rotors] table",
                        f.actuation.as_str()
                    ),
                ));
            }
            return Ok(RotorLayout {
                rotors: Vec::new(),
                thrust_min_n: 0.0,
                thrust_max_n: 0.0,
                reaction_torque_ratio_m: 0.0,
                propeller_radius_m: 0.0,
                thrust_curve: ThrustCurve {
                    model_factor: 0.0,
                    thrust_min_n: 0.0,
                    thrust_max_n: 0.0,
                },
            });
        };
        if f.actuation == Actuation::FloatingEndEffector {
            return Err(self.invalid(
                "rotors",
                "a floating-end-effector vehicle has no rotors".to_owned(),
            ));
        }
        if r.count != r.rotor.len() {
            return Err(self.err(
                "rotors.count",
                Problem::RotorCountMismatch {
                    declared: r.count,
                    listed: r.rotor.len(),
                },
            ));
        }
        if r.count == 0 {
            return Err(self.invalid(
                "rotors.count",
                "0: a vehicle with a [rotors] table needs rotors".to_owned(),
            ));
        }
        if !(r.thrust_min_n.is_finite() && r.thrust_min_n >= 0.0) {
            return Err(self.invalid(
                "rotors.thrust_min_n",
                format!("{} must be finite and not negative", r.thrust_min_n),
            ));
        }
        if !(r.thrust_max_n.is_finite() && r.thrust_max_n > r.thrust_min_n) {
            return Err(self.invalid(
                "rotors.thrust_max_n",
                format!(
                    "{} must be finite and above thrust_min_n {}",
                    r.thrust_max_n, r.thrust_min_n
                ),
            ));
        }
        if !(r.thrust_model_factor.is_finite() && (0.0..=1.0).contains(&r.thrust_model_factor)) {
            return Err(self.invalid(
                "rotors.thrust_model_factor",
                format!("{} must be within [0, 1]", r.thrust_model_factor),
            ));
        }
        if !(r.reaction_torque_ratio_m.is_finite() && r.reaction_torque_ratio_m >= 0.0) {
            return Err(self.invalid(
                "rotors.reaction_torque_ratio_m",
                format!(
                    "{} must be finite and not negative",
                    r.reaction_torque_ratio_m
                ),
            ));
        }
        if !(r.propeller_radius_m.is_finite() && r.propeller_radius_m > 0.0) {
            return Err(self.invalid(
                "rotors.propeller_radius_m",
                format!("{} must be finite and positive", r.propeller_radius_m),
            ));
        }

        let q0 = self.model.zero_configuration();
        let mut rotors = Vec::with_capacity(r.rotor.len());
        let mut seen = HashSet::new();
        for (i, entry) in r.rotor.iter().enumerate() {
            let field = format!("rotors.rotor[{i}]");
            let link = self.link(&format!("{field}.link"), &entry.link)?;
            if !seen.insert(link) {
                return Err(self.invalid(
                    format!("{field}.link"),
                    format!("link '{}' is already a rotor", entry.link),
                ));
            }
            let spin = match entry.spin {
                1 => Spin::Positive,
                -1 => Spin::Negative,
                other => {
                    return Err(
                        self.invalid(format!("{field}.spin"), format!("{other} must be 1 or -1"))
                    );
                }
            };
            let tilt_joint = entry
                .tilt_joint
                .as_deref()
                .map(|name| self.movable_joint(&format!("{field}.tilt_joint"), name))
                .transpose()?;
            // A rotor frame may move only with its own tilt hinge.
            for j in self.model.chain(link) {
                let joint = &self.model.joints[j];
                if joint.kind != JointKind::Fixed && Some(j) != tilt_joint {
                    return Err(self.invalid(
                        format!("{field}.link"),
                        format!(
                            "link '{}' moves with joint '{}', which is not its tilt_joint",
                            entry.link, joint.name
                        ),
                    ));
                }
            }
            let base_from_rotor = self.model.root_from_link(&q0, link);
            let axis_in_base = Unit::new_normalize(base_from_rotor.rotation * Vector3::z());
            let tilt = match tilt_joint {
                None => None,
                Some(j) => {
                    let joint = &self.model.joints[j];
                    if !self.model.chain(link).contains(&j) {
                        return Err(self.invalid(
                            format!("{field}.tilt_joint"),
                            format!(
                                "joint '{}' does not carry link '{}'",
                                joint.name, entry.link
                            ),
                        ));
                    }
                    if joint.kind != JointKind::Revolute && joint.kind != JointKind::Continuous {
                        return Err(self.invalid(
                            format!("{field}.tilt_joint"),
                            format!("joint '{}' is not revolute", joint.name),
                        ));
                    }
                    let base_from_joint =
                        self.model.root_from_link(&q0, joint.parent) * joint.parent_from_joint;
                    let hinge = base_from_joint.rotation * joint.axis.into_inner();
                    let sin_axis = hinge.cross(&axis_in_base);
                    if sin_axis.norm() < UNIT_AXIS_TOLERANCE {
                        return Err(self.invalid(format!("{field}.tilt_joint"), format!(
                            "joint '{}' axis is parallel to the thrust axis: tilting would not turn it",
                            joint.name
                        )));
                    }
                    let limits_rad = joint
                        .limits
                        .map_or((f64::NEG_INFINITY, f64::INFINITY), |l| (l.lower, l.upper));
                    Some(Tilt {
                        joint: joint.name.clone(),
                        hinge_axis_in_base: Unit::new_normalize(hinge),
                        sin_axis_in_base: Unit::new_normalize(sin_axis),
                        limits_rad,
                    })
                }
            };
            let wants_tilt = f.actuation == Actuation::VariableTilt;
            if wants_tilt != tilt.is_some() {
                return Err(self.invalid(
                    format!("{field}.tilt_joint"),
                    if wants_tilt {
                        "missing: every rotor of a variable-tilt vehicle needs a tilt_joint"
                            .to_owned()
                    } else {
                        format!(
                            "given, but a {} vehicle has fixed rotors",
                            f.actuation.as_str()
                        )
                    },
                ));
            }
            if f.actuation == Actuation::UnderActuated
                && (axis_in_base.into_inner() - Vector3::z()).norm() > UNIT_AXIS_TOLERANCE
            {
                let a = axis_in_base;
                return Err(self.invalid(format!("{field}.link"), format!(
                    "thrust axis ({:.6}, {:.6}, {:.6}) is not body +z, which an under-actuated vehicle needs",
                    a.x, a.y, a.z
                )));
            }
            rotors.push(Rotor {
                link: entry.link.clone(),
                position_in_base: base_from_rotor.translation.vector,
                axis_in_base,
                spin,
                tilt,
            });
        }
        Ok(RotorLayout {
            rotors,
            thrust_min_n: r.thrust_min_n,
            thrust_max_n: r.thrust_max_n,
            reaction_torque_ratio_m: r.reaction_torque_ratio_m,
            propeller_radius_m: r.propeller_radius_m,
            thrust_curve: ThrustCurve {
                model_factor: r.thrust_model_factor,
                thrust_min_n: r.thrust_min_n,
                thrust_max_n: r.thrust_max_n,
            },
        })
    }

    fn drives(&self, f: &VehicleFile) -> Result<Vec<JointDrive>, DescriptionError> {
        let mut drives: Vec<JointDrive> = Vec::new();
        for (i, d) in f.drive.iter().enumerate() {
            let field = format!("drive[{i}]");
            for (name, v, strictly) in [
                ("stiffness", d.stiffness, false),
                ("damping", d.damping, false),
                ("effort_limit", d.effort_limit, true),
                ("velocity_limit", d.velocity_limit, true),
            ] {
                if !v.is_finite() || v < 0.0 || (strictly && v <= 0.0) {
                    let need = if strictly { "positive" } else { "not negative" };
                    return Err(self.invalid(
                        format!("{field}.{name}"),
                        format!("{v} must be finite and {need}"),
                    ));
                }
            }
            let initial: Vec<f64> = match &d.initial {
                Initial::All(v) => vec![*v; d.joints.len()],
                Initial::Each(v) => v.clone(),
            };
            if initial.len() != d.joints.len() {
                return Err(self.invalid(
                    format!("{field}.initial"),
                    format!("has {} values for {} joints", initial.len(), d.joints.len()),
                ));
            }
            for (k, (name, init)) in d.joints.iter().zip(&initial).enumerate() {
                let jf = format!("{field}.joints[{k}]");
                let joint = self.movable_joint(&jf, name)?;
                if drives.iter().any(|x| x.joint == joint) {
                    return Err(self.invalid(jf, format!("joint '{name}' is already driven")));
                }
                self.finite(&format!("{field}.initial"), &[*init])?;
                self.within_limits(&format!("{field}.initial"), joint, *init)?;
                drives.push(JointDrive {
                    joint,
                    stiffness: d.stiffness,
                    damping: d.damping,
                    effort_limit: d.effort_limit,
                    velocity_limit: d.velocity_limit,
                    initial: *init,
                });
            }
        }
        Ok(drives)
    }

    fn colors(&self, f: &VehicleFile) -> Result<Vec<Option<[f64; 3]>>, DescriptionError> {
        let mut colors = vec![None; self.model.links.len()];
        for (name, rgb) in &f.colors {
            let field = format!("colors.{name}");
            let link = self.link(&field, name)?;
            let rgb: [f64; 3] = self.array(&field, rgb)?;
            if !rgb.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)) {
                return Err(self.invalid(field, format!("{rgb:?} must lie in [0, 1]")));
            }
            colors[link] = Some(rgb);
        }
        Ok(colors)
    }

    fn cameras(&self, f: &VehicleFile) -> Result<Vec<CameraMount>, DescriptionError> {
        let mut cameras: Vec<CameraMount> = Vec::with_capacity(f.camera.len());
        for (i, c) in f.camera.iter().enumerate() {
            let field = format!("camera[{i}]");
            if cameras.iter().any(|x| x.name == c.name) {
                return Err(self.invalid(
                    format!("{field}.name"),
                    format!("'{}' is already a camera", c.name),
                ));
            }
            let link = self.link(&format!("{field}.link"), &c.link)?;
            let position: [f64; 3] = self.array(&format!("{field}.position_m"), &c.position_m)?;
            let rotation =
                self.unit_quaternion(&format!("{field}.orientation_wxyz"), &c.orientation_wxyz)?;
            if c.width_px == 0 || c.height_px == 0 {
                return Err(self.invalid(
                    field,
                    format!("image {}×{} px must not be empty", c.width_px, c.height_px),
                ));
            }
            for (name, v) in [
                ("focal_length_mm", c.focal_length_mm),
                ("horizontal_aperture_mm", c.horizontal_aperture_mm),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(self.invalid(
                        format!("{field}.{name}"),
                        format!("{v} must be finite and positive"),
                    ));
                }
            }
            let [near, far]: [f64; 2] = self.array(&format!("{field}.clip_m"), &c.clip_m)?;
            if !(near.is_finite() && far.is_finite() && 0.0 < near && near < far) {
                return Err(self.invalid(
                    format!("{field}.clip_m"),
                    format!("[{near}, {far}] must satisfy 0 < near < far"),
                ));
            }
            cameras.push(CameraMount {
                name: c.name.clone(),
                link,
                link_from_camera: Isometry3::from_parts(
                    Translation3::from(Vector3::from(position)),
                    rotation,
                ),
                width_px: c.width_px,
                height_px: c.height_px,
                focal_length_mm: c.focal_length_mm,
                horizontal_aperture_mm: c.horizontal_aperture_mm,
                clip_m: [near, far],
            });
        }
        Ok(cameras)
    }
}
