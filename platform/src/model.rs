//! The kinematic tree of a vehicle, loaded from URDF and validated.
//!
//! Links are rigid bodies; joints connect a parent link to a child link. A joint's frame is
//! `parent_from_joint` (the URDF `<origin>`); its motion — a rotation about `axis` by q for a
//! revolute or continuous joint, a translation along `axis` by q for a prismatic one — is
//! applied in that frame, so `parent_from_child = parent_from_joint · motion(q)`.
//!
//! Every movable joint owns one entry of the configuration vector `q`, in the order the joints
//! appear in the URDF. The root link (the base) is the one link that is nobody's child.

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::error::{DescriptionError, Problem, one_line};

/// Index of a link in [`KinematicModel::links`].
pub type LinkId = usize;
/// Index of a joint in [`KinematicModel::joints`].
pub type JointId = usize;

/// Tolerance on the norm of a unit axis.
pub const UNIT_AXIS_TOLERANCE: f64 = 1e-6;

/// How a joint moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum JointKind {
    /// Rigid.
    Fixed,
    /// Rotation about the axis within limits, rad.
    Revolute,
    /// Rotation about the axis without limits, rad.
    Continuous,
    /// Translation along the axis within limits, m.
    Prismatic,
}

/// Position, effort and velocity limits of a joint (rad or m; N·m or N; rad/s or m/s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct JointLimits {
    /// Lowest position.
    pub lower: f64,
    /// Highest position.
    pub upper: f64,
    /// Largest effort.
    pub effort: f64,
    /// Largest speed.
    pub velocity: f64,
}

/// A joint of the tree.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Joint {
    /// URDF name.
    pub name: String,
    /// How it moves.
    pub kind: JointKind,
    /// Parent link.
    pub parent: LinkId,
    /// Child link.
    pub child: LinkId,
    /// The joint frame in the parent link frame (URDF `<origin>`).
    pub parent_from_joint: Isometry3<f64>,
    /// Unit axis of motion in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Limits (None for fixed and continuous joints).
    pub limits: Option<JointLimits>,
    /// Index into the configuration vector (None for a fixed joint).
    pub dof: Option<usize>,
}

/// Mass properties of one link.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Inertial {
    /// Mass, kg.
    pub mass_kg: f64,
    /// Centre of mass and principal frame of the inertia in the link frame.
    pub link_from_inertial: Isometry3<f64>,
    /// Inertia tensor about the centre of mass, in the inertial frame, kg·m².
    pub inertia_kgm2: Matrix3<f64>,
}

/// A primitive shape. Cylinders and capsules lie along their frame's z axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    /// Full side lengths, m.
    Box {
        /// Side lengths along x, y, z, m.
        size_m: Vector3<f64>,
    },
    /// Cylinder along z.
    Cylinder {
        /// Radius, m.
        radius_m: f64,
        /// Length, m.
        length_m: f64,
    },
    /// Capsule along z (length of the cylindrical part).
    Capsule {
        /// Radius, m.
        radius_m: f64,
        /// Length, m.
        length_m: f64,
    },
    /// Sphere.
    Sphere {
        /// Radius, m.
        radius_m: f64,
    },
}

/// A shape placed in a link frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Geometry {
    /// Shape frame in the link frame.
    pub link_from_shape: Isometry3<f64>,
    /// The shape.
    pub shape: Shape,
    /// Colour, linear RGBA in [0, 1], of a visual with a URDF `<material>` (its inline
    /// `<color>`, or the robot-level material it names); None otherwise and for collisions.
    pub rgba: Option<[f64; 4]>,
}

/// A link of the tree.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Link {
    /// URDF name.
    pub name: String,
    /// Mass properties (None for a massless frame such as a rotor marker).
    pub inertial: Option<Inertial>,
    /// Shapes drawn.
    pub visuals: Vec<Geometry>,
    /// Shapes that collide.
    pub collisions: Vec<Geometry>,
    /// The joint whose child this link is (None for the root).
    pub parent_joint: Option<JointId>,
}

/// A validated kinematic tree.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct KinematicModel {
    /// URDF robot name.
    pub name: String,
    /// Links, in URDF order.
    pub links: Vec<Link>,
    /// Joints, in URDF order.
    pub joints: Vec<Joint>,
    /// The root link.
    pub root: LinkId,
    /// Joints ordered so every joint comes after the joint of its parent link.
    pub(crate) topological: Vec<JointId>,
    /// The movable joints, by configuration index.
    pub(crate) dofs: Vec<JointId>,
}

fn vec3(v: &urdf_rs::Vec3) -> Vector3<f64> {
    Vector3::new(v[0], v[1], v[2])
}

fn pose(p: &urdf_rs::Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(vec3(&p.xyz)),
        // URDF rpy: R = Rz(yaw)·Ry(pitch)·Rx(roll), which is nalgebra's from_euler_angles.
        UnitQuaternion::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]),
    )
}

fn all_finite(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

struct Checker<'a> {
    file: &'a str,
}

impl Checker<'_> {
    fn err(&self, field: impl Into<String>, problem: Problem) -> DescriptionError {
        DescriptionError::new(self.file, field, problem)
    }

    fn invalid(&self, field: impl Into<String>, message: String) -> DescriptionError {
        self.err(field, Problem::Invalid(message))
    }

    fn pose(&self, field: &str, p: &urdf_rs::Pose) -> Result<Isometry3<f64>, DescriptionError> {
        if !all_finite(&p.xyz.0) || !all_finite(&p.rpy.0) {
            return Err(self.invalid(
                format!("{field} origin"),
                format!("xyz {:?} rpy {:?} is not finite", p.xyz.0, p.rpy.0),
            ));
        }
        Ok(pose(p))
    }

    fn geometry(
        &self,
        field: &str,
        origin: &urdf_rs::Pose,
        g: &urdf_rs::Geometry,
    ) -> Result<Geometry, DescriptionError> {
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(self.invalid(
                    field.to_owned(),
                    format!("{what} {v} must be finite and positive"),
                ))
            }
        };
        let shape = match g {
            urdf_rs::Geometry::Box { size } => {
                for s in size.0 {
                    positive("box size", s)?;
                }
                Shape::Box { size_m: vec3(size) }
            }
            urdf_rs::Geometry::Cylinder { radius, length } => Shape::Cylinder {
                radius_m: positive("cylinder radius", *radius)?,
                length_m: positive("cylinder length", *length)?,
            },
            urdf_rs::Geometry::Capsule { radius, length } => Shape::Capsule {
                radius_m: positive("capsule radius", *radius)?,
                length_m: positive("capsule length", *length)?,
            },
            urdf_rs::Geometry::Sphere { radius } => Shape::Sphere {
                radius_m: positive("sphere radius", *radius)?,
            },
            urdf_rs::Geometry::Mesh { filename, .. } => {
                return Err(self.invalid(
                    field.to_owned(),
                    format!(
                        "mesh '{filename}' is not supported: use box, cylinder, capsule or sphere"
                    ),
                ));
            }
        };
        Ok(Geometry {
            link_from_shape: self.pose(field, origin)?,
            shape,
            rgba: None,
        })
    }

    /// The colour of a visual's `<material>`: its own `<color>`, else the colour of the
    /// robot-level material of that name; None without either.
    fn material_rgba(
        &self,
        field: &str,
        material: Option<&urdf_rs::Material>,
        robot_materials: &[urdf_rs::Material],
    ) -> Result<Option<[f64; 4]>, DescriptionError> {
        let Some(m) = material else {
            return Ok(None);
        };
        let color = m.color.as_ref().or_else(|| {
            robot_materials
                .iter()
                .find(|r| r.name == m.name)
                .and_then(|r| r.color.as_ref())
        });
        let Some(c) = color else {
            return Ok(None);
        };
        let rgba = c.rgba.0;
        if rgba
            .iter()
            .all(|v| v.is_finite() && (0.0..=1.0).contains(v))
        {
            Ok(Some(rgba))
        } else {
            Err(self.invalid(
                format!("{field} material '{}'", m.name),
                format!("rgba {rgba:?} must lie in [0, 1]"),
            ))
        }
    }

    /// urdf-rs reads a missing `<inertial>` as zero mass and zero inertia: such a link is a
    /// massless frame (a rotor marker), not a body of its own.
    fn inertial(&self, link: &urdf_rs::Link) -> Result<Option<Inertial>, DescriptionError> {
        let field = format!("link '{}' inertial", link.name);
        let i = &link.inertial;
        let m = i.mass.value;
        if !m.is_finite() {
            return Err(self.invalid(field, format!("mass {m} is not finite")));
        }
        if m < 0.0 {
            return Err(self.err(field, Problem::NegativeMass(m)));
        }
        let t = &i.inertia;
        let values = [t.ixx, t.ixy, t.ixz, t.iyy, t.iyz, t.izz];
        if !all_finite(&values) {
            return Err(self.invalid(field, format!("inertia {values:?} is not finite")));
        }
        if m == 0.0 {
            if values.iter().any(|v| *v != 0.0) {
                return Err(self.invalid(
                    field,
                    format!("mass 0 kg with a non-zero inertia {values:?}"),
                ));
            }
            return Ok(None);
        }
        let inertia = Matrix3::new(
            t.ixx, t.ixy, t.ixz, //
            t.ixy, t.iyy, t.iyz, //
            t.ixz, t.iyz, t.izz,
        );
        // A physical inertia tensor is positive semi-definite and its principal moments obey
        // the triangle inequality; a negative moment is the usual typo.
        let eig = inertia.symmetric_eigenvalues();
        let scale = eig.amax().max(f64::MIN_POSITIVE);
        if eig.iter().any(|e| *e < -1e-9 * scale) {
            return Err(self.invalid(
                field,
                format!(
                    "inertia (ixx {}, iyy {}, izz {}, ixy {}, ixz {}, iyz {}) is not positive semi-definite",
                    t.ixx, t.iyy, t.izz, t.ixy, t.ixz, t.iyz
                ),
            ));
        }
        Ok(Some(Inertial {
            mass_kg: m,
            link_from_inertial: self.pose(&field, &i.origin)?,
            inertia_kgm2: inertia,
        }))
    }
}

impl KinematicModel {
    /// Physically impossible but loadable data, one line each: a link inertia whose principal
    /// moments break the triangle inequality (I_a ≤ I_b + I_c holds for every rigid body;
    /// MuJoCo refuses such a model). The reference's FA-Hexa and UA-Hexa base,
    /// diag(0.198, 0.198, 0.460), is one: the built-in vehicles keep its numbers, and the
    /// loader's caller says so.
    pub fn physical_warnings(&self) -> Vec<String> {
        let mut warnings = Vec::new();
        for link in &self.links {
            let Some(inertial) = &link.inertial else {
                continue;
            };
            let e = inertial.inertia_kgm2.symmetric_eigenvalues();
            let (a, b, c) = (e[0], e[1], e[2]);
            let tol = 1e-9 * e.amax();
            for (big, x, y) in [(a, b, c), (b, a, c), (c, a, b)] {
                if big > x + y + tol {
                    warnings.push(format!(
                        "link '{}' inertia: principal moment {big:.4} > {x:.4} + {y:.4} \
                         breaks the triangle inequality (no rigid body has it)",
                        link.name
                    ));
                    break;
                }
            }
        }
        warnings
    }
}

impl KinematicModel {
    /// Parses and validates a URDF document. `file` names it in errors.
    ///
    /// Rejected: XML that is not URDF, duplicate link or joint names, joints naming unknown
    /// links, a link with two parents, no single root, cycles, non-unit or zero axes on movable
    /// joints, negative or non-finite masses, inertias that are not positive semi-definite,
    /// limits with lower > upper (or lower = upper, a missing `<limit>`), negative effort or
    /// velocity limits, non-finite origins, meshes and degenerate shapes.
    pub fn from_urdf(file: &str, text: &str) -> Result<Self, DescriptionError> {
        let check = Checker { file };
        let robot = urdf_rs::read_from_string(text)
            .map_err(|e| check.err("", Problem::Syntax(one_line(&e.to_string()))))?;

        let mut link_ids: HashMap<&str, LinkId> = HashMap::new();
        let mut links = Vec::with_capacity(robot.links.len());
        for (id, l) in robot.links.iter().enumerate() {
            if link_ids.insert(l.name.as_str(), id).is_some() {
                return Err(check.err("link", Problem::DuplicateLink(l.name.clone())));
            }
            let visuals = l
                .visual
                .iter()
                .map(|v| {
                    let field = format!("link '{}' visual", l.name);
                    let mut g = check.geometry(&field, &v.origin, &v.geometry)?;
                    g.rgba = check.material_rgba(&field, v.material.as_ref(), &robot.materials)?;
                    Ok::<Geometry, DescriptionError>(g)
                })
                .collect::<Result<Vec<_>, _>>()?;
            let collisions = l
                .collision
                .iter()
                .map(|c| {
                    check.geometry(
                        &format!("link '{}' collision", l.name),
                        &c.origin,
                        &c.geometry,
                    )
                })
                .collect::<Result<Vec<_>, _>>()?;
            links.push(Link {
                name: l.name.clone(),
                inertial: check.inertial(l)?,
                visuals,
                collisions,
                parent_joint: None,
            });
        }
        if links.is_empty() {
            return Err(check.invalid("robot", "has no links".to_owned()));
        }

        let mut joint_names: HashMap<&str, JointId> = HashMap::new();
        let mut joints = Vec::with_capacity(robot.joints.len());
        let mut dofs = Vec::new();
        for (id, j) in robot.joints.iter().enumerate() {
            let field = format!("joint '{}'", j.name);
            if joint_names.insert(j.name.as_str(), id).is_some() {
                return Err(check.err("joint", Problem::DuplicateJoint(j.name.clone())));
            }
            let link = |name: &str, role: &str| {
                link_ids.get(name).copied().ok_or_else(|| {
                    check.err(
                        format!("{field} {role}"),
                        Problem::UnknownLink(name.to_owned()),
                    )
                })
            };
            let parent = link(&j.parent.link, "parent")?;
            let child = link(&j.child.link, "child")?;
            if parent == child {
                return Err(check.invalid(
                    field,
                    format!("parent and child are both '{}'", j.parent.link),
                ));
            }
            let kind = match j.joint_type {
                urdf_rs::JointType::Fixed => JointKind::Fixed,
                urdf_rs::JointType::Revolute => JointKind::Revolute,
                urdf_rs::JointType::Continuous => JointKind::Continuous,
                urdf_rs::JointType::Prismatic => JointKind::Prismatic,
                ref other => {
                    return Err(check.invalid(
                        format!("{field} type"),
                        format!("{other:?} joints are not supported (fixed, revolute, continuous, prismatic)"),
                    ));
                }
            };
            let a = vec3(&j.axis.xyz);
            let axis = if kind == JointKind::Fixed {
                Unit::new_normalize(if a.norm() > 0.0 { a } else { Vector3::x() })
            } else {
                let norm = a.norm();
                if !norm.is_finite() || (norm - 1.0).abs() > UNIT_AXIS_TOLERANCE {
                    return Err(check.err(
                        format!("{field} axis"),
                        Problem::NonUnitAxis {
                            x: a.x,
                            y: a.y,
                            z: a.z,
                            norm,
                        },
                    ));
                }
                Unit::new_normalize(a)
            };
            let limits =
                match kind {
                    JointKind::Revolute | JointKind::Prismatic => {
                        let l = &j.limit;
                        let f = format!("{field} limit");
                        if !all_finite(&[l.lower, l.upper, l.effort, l.velocity]) {
                            return Err(check.invalid(
                                f,
                                format!(
                                    "lower {} upper {} effort {} velocity {} must be finite",
                                    l.lower, l.upper, l.effort, l.velocity
                                ),
                            ));
                        }
                        if l.lower >= l.upper {
                            return Err(check.invalid(f, format!(
                            "lower {} must be below upper {} (is the <limit> element missing?)",
                            l.lower, l.upper
                        )));
                        }
                        if l.effort < 0.0 || l.velocity < 0.0 {
                            return Err(check.invalid(
                                f,
                                format!(
                                    "effort {} and velocity {} must not be negative",
                                    l.effort, l.velocity
                                ),
                            ));
                        }
                        Some(JointLimits {
                            lower: l.lower,
                            upper: l.upper,
                            effort: l.effort,
                            velocity: l.velocity,
                        })
                    }
                    JointKind::Fixed | JointKind::Continuous => None,
                };
            let dof = (kind != JointKind::Fixed).then(|| {
                dofs.push(id);
                dofs.len() - 1
            });
            if let Some(other) = links[child].parent_joint {
                return Err(check.invalid(
                    field,
                    format!(
                        "link '{}' already has parent joint '{}'",
                        j.child.link, robot.joints[other].name
                    ),
                ));
            }
            links[child].parent_joint = Some(id);
            joints.push(Joint {
                name: j.name.clone(),
                kind,
                parent,
                child,
                parent_from_joint: check.pose(&field, &j.origin)?,
                axis,
                limits,
                dof,
            });
        }

        let roots: Vec<LinkId> = (0..links.len())
            .filter(|&l| links[l].parent_joint.is_none())
            .collect();
        let root = match roots.as_slice() {
            [r] => *r,
            [] => {
                return Err(check.invalid(
                    "robot",
                    "has no root link (the joints form a cycle)".to_owned(),
                ));
            }
            many => {
                let names: Vec<&str> = many.iter().map(|&l| links[l].name.as_str()).collect();
                return Err(check.invalid(
                    "robot",
                    format!(
                        "has {} root links ({}): every link but one must be a joint's child",
                        many.len(),
                        names.join(", ")
                    ),
                ));
            }
        };

        // Breadth-first from the root: orders joints parent-first and finds unreachable cycles.
        let mut children: Vec<Vec<JointId>> = vec![Vec::new(); links.len()];
        for (id, j) in joints.iter().enumerate() {
            children[j.parent].push(id);
        }
        let mut topological = Vec::with_capacity(joints.len());
        let mut frontier = vec![root];
        while let Some(l) = frontier.pop() {
            for &j in &children[l] {
                topological.push(j);
                frontier.push(joints[j].child);
            }
        }
        if topological.len() != joints.len() {
            return Err(check.invalid(
                "robot",
                "some links are not connected to the root (a cycle)".to_owned(),
            ));
        }

        Ok(Self {
            name: robot.name,
            links,
            joints,
            root,
            topological,
            dofs,
        })
    }

    /// Number of movable joints (the length of a configuration vector).
    pub fn dof(&self) -> usize {
        self.dofs.len()
    }

    /// Every joint, ordered so that a joint comes after the joint of its parent link.
    pub fn topological_joints(&self) -> &[JointId] {
        &self.topological
    }

    /// The movable joint at configuration index `dof`.
    pub fn dof_joint(&self, dof: usize) -> &Joint {
        &self.joints[self.dofs[dof]]
    }

    /// A link's id by name.
    pub fn link_id(&self, name: &str) -> Option<LinkId> {
        self.links.iter().position(|l| l.name == name)
    }

    /// A joint's id by name.
    pub fn joint_id(&self, name: &str) -> Option<JointId> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// The joints from the root down to `link`, root first.
    pub fn chain(&self, link: LinkId) -> Vec<JointId> {
        let mut chain = Vec::new();
        let mut l = link;
        while let Some(j) = self.links[l].parent_joint {
            chain.push(j);
            l = self.joints[j].parent;
        }
        chain.reverse();
        chain
    }

    /// The all-zero configuration.
    pub fn zero_configuration(&self) -> Vec<f64> {
        vec![0.0; self.dof()]
    }

    /// Total mass of all links, kg.
    pub fn total_mass_kg(&self) -> f64 {
        self.links
            .iter()
            .filter_map(|l| l.inertial)
            .map(|i| i.mass_kg)
            .sum()
    }
}
