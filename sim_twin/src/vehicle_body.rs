//! A vehicle from its `platform` description, built as one rapier multibody: a floating base,
//! arm joints, gripper fingers, tilt hinges.
//!
//! Links joined by fixed joints share one rigid body (their inertials summed), so a body
//! exists per movable-joint segment. Each body's frame is the frame of its first link. A
//! joint's rapier frames are `local_frame1 = body_from_parent · parent_from_joint · A` and
//! `local_frame2 = A` in the child body, with A turning x̂ onto the joint axis: rapier's free
//! axis is x, so q about the URDF axis is rapier's coordinate about x.
//!
//! Mass comes from the URDF inertials only (colliders have zero density). Motors use
//! rapier's force-based model (the acceleration-based default barely moves 0.2 kg links).

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use platform::{JointDrive, JointKind, LinkId, Shape, Vehicle};
use rapier3d_f64::prelude::*;

use crate::convert::{matrix_to_rapier, pose_to_rapier, vector_to_rapier};
use crate::error::TwinError;

/// Collision group of every robot collider (ray casts of the aerodynamic models skip it).
pub const ROBOT_GROUP: Group = Group::GROUP_1;
/// Collision group of the world: ground, walls, task objects.
pub const WORLD_GROUP: Group = Group::GROUP_2;

/// Contact material of every collider (AMBENCH_SPEC §0): μ 1.0, restitution 0, multiply.
pub(crate) fn material(builder: ColliderBuilder) -> ColliderBuilder {
    builder
        .friction(1.0)
        .restitution(0.0)
        .friction_combine_rule(CoefficientCombineRule::Multiply)
        .restitution_combine_rule(CoefficientCombineRule::Multiply)
}

/// A movable joint of the vehicle in the multibody.
#[derive(Debug, Clone)]
pub(crate) struct DofJoint {
    pub handle: MultibodyJointHandle,
    /// The bodies it joins and the joint as built (to re-insert it, [`attach`]).
    pub parent: RigidBodyHandle,
    pub child: RigidBodyHandle,
    pub spec: GenericJoint,
    pub axis: JointAxis,
    pub limits: Option<(f64, f64)>,
    pub drive: Option<JointDrive>,
    /// The position the motor is currently pulled toward (moves toward the target at no
    /// more than the drive's velocity limit).
    pub setpoint: f64,
}

/// Handles and frames of a vehicle in a physics world.
#[derive(Debug, Clone)]
pub(crate) struct VehicleBody {
    /// Rigid body per link, and the link frame in that body.
    pub link_body: Vec<(RigidBodyHandle, Isometry3<f64>)>,
    /// The base body (its frame is the base link frame).
    pub base: RigidBodyHandle,
    /// The base body's centre of mass in its frame (rapier computes its own copy only in a
    /// step).
    pub base_com_in_body: Vector3<f64>,
    /// Every rigid body of the vehicle.
    pub bodies: Vec<RigidBodyHandle>,
    /// Colliders of each link (by link id).
    pub link_colliders: Vec<Vec<ColliderHandle>>,
    /// One entry per configuration index.
    pub dofs: Vec<DofJoint>,
}

impl VehicleBody {
    /// The body carrying `link` and the link frame in it.
    pub fn of_link(&self, link: LinkId) -> (RigidBodyHandle, Isometry3<f64>) {
        self.link_body[link]
    }
}

/// Rotation taking x̂ onto `axis`.
fn align_x_to(axis: &Unit<Vector3<f64>>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(&Vector3::x(), axis).unwrap_or_else(|| {
        // axis = −x̂: half a turn about z.
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
    })
}

fn collider_for(shape: &Shape) -> ColliderBuilder {
    match *shape {
        Shape::Box { size_m } => {
            ColliderBuilder::cuboid(size_m.x / 2.0, size_m.y / 2.0, size_m.z / 2.0)
        }
        // URDF cylinders lie along z; rapier's along y: the shape pose adds a quarter turn.
        Shape::Cylinder { radius_m, length_m } => {
            ColliderBuilder::cylinder(length_m / 2.0, radius_m)
        }
        Shape::Capsule { radius_m, length_m } => {
            ColliderBuilder::capsule_z(length_m / 2.0, radius_m)
        }
        Shape::Sphere { radius_m } => ColliderBuilder::ball(radius_m),
    }
}

fn shape_fixup(shape: &Shape) -> Isometry3<f64> {
    match shape {
        Shape::Cylinder { .. } => Isometry3::rotation(Vector3::x() * std::f64::consts::FRAC_PI_2),
        _ => Isometry3::identity(),
    }
}

/// Builds the vehicle into `world` with its base at `world_from_base` and its joints at
/// their initial (drive) positions, as one rapier multibody.
pub(crate) fn build(
    vehicle: &Vehicle,
    world: &mut PhysicsWorld,
    world_from_base: &Isometry3<f64>,
    q0: &[f64],
) -> Result<VehicleBody, TwinError> {
    let model = &vehicle.model;
    let root_from_link = model.forward_kinematics(q0);

    // Segments: which body each link belongs to and where it sits in it.
    let mut segment: Vec<(usize, Isometry3<f64>)> =
        vec![(0, Isometry3::identity()); model.links.len()];
    let mut segment_root: Vec<LinkId> = vec![model.root];
    for &j in model.topological_joints() {
        let joint = &model.joints[j];
        let (parent_segment, body_from_parent) = segment[joint.parent];
        segment[joint.child] = if joint.kind == JointKind::Fixed {
            (parent_segment, body_from_parent * joint.parent_from_joint)
        } else {
            segment_root.push(joint.child);
            (segment_root.len() - 1, Isometry3::identity())
        };
    }

    // One rigid body per segment, with the summed inertials of its links.
    let mut bodies = Vec::with_capacity(segment_root.len());
    let mut base_com_in_body = Vector3::zeros();
    for (s, &first_link) in segment_root.iter().enumerate() {
        let mut mass = MassProperties::default();
        for (link, (seg, body_from_link)) in segment.iter().enumerate() {
            if *seg != s {
                continue;
            }
            if let Some(i) = model.links[link].inertial {
                let body_from_inertial = body_from_link * i.link_from_inertial;
                let r = body_from_inertial
                    .rotation
                    .to_rotation_matrix()
                    .into_inner();
                mass += MassProperties::with_inertia_matrix(
                    vector_to_rapier(&body_from_inertial.translation.vector),
                    i.mass_kg,
                    matrix_to_rapier(&(r * i.inertia_kgm2 * r.transpose())),
                );
            }
        }
        if mass.mass() <= 0.0 {
            return Err(TwinError::Vehicle(format!(
                "link '{}' and the links fixed to it have no mass: a moving body needs one",
                model.links[first_link].name
            )));
        }
        if s == 0 {
            let c = mass.local_com;
            base_com_in_body = Vector3::new(c.x, c.y, c.z);
        }
        let pose = world_from_base * root_from_link[first_link];
        let body = RigidBodyBuilder::dynamic()
            .pose(pose_to_rapier(&pose))
            .additional_mass_properties(mass)
            .can_sleep(false)
            .build();
        bodies.push(world.insert_body(body));
    }

    // Colliders, in the robot's group.
    let groups = InteractionGroups::new(ROBOT_GROUP, Group::ALL, InteractionTestMode::And);
    let mut link_colliders = vec![Vec::new(); model.links.len()];
    for (link, (seg, body_from_link)) in segment.iter().enumerate() {
        for g in &model.links[link].collisions {
            let pose = body_from_link * g.link_from_shape * shape_fixup(&g.shape);
            let collider = material(collider_for(&g.shape))
                .density(0.0)
                .collision_groups(groups)
                .position(pose_to_rapier(&pose));
            link_colliders[link].push(world.insert_collider(collider, Some(bodies[*seg])));
        }
    }

    // Joints, in the order of the configuration vector.
    let mut dofs = Vec::with_capacity(model.dof());
    for (dof, &setpoint) in q0.iter().enumerate() {
        let joint = model.dof_joint(dof);
        let Some(j) = model.joint_id(&joint.name) else {
            continue;
        };
        let (parent_segment, body_from_parent) = segment[joint.parent];
        let (child_segment, _) = segment[joint.child];
        let align = Isometry3::from_parts(Translation3::identity(), align_x_to(&joint.axis));
        let frame1 = body_from_parent * joint.parent_from_joint * align;
        let (mask, axis) = match joint.kind {
            JointKind::Prismatic => (JointAxesMask::LOCKED_PRISMATIC_AXES, JointAxis::LinX),
            _ => (JointAxesMask::LOCKED_REVOLUTE_AXES, JointAxis::AngX),
        };
        let limits = joint.limits.map(|l| (l.lower, l.upper));
        let drive = vehicle.drives.iter().find(|d| d.joint == j).copied();
        let mut builder = GenericJointBuilder::new(mask)
            .local_frame1(pose_to_rapier(&frame1))
            .local_frame2(pose_to_rapier(&align));
        if let Some((lo, hi)) = limits
            && joint.kind != JointKind::Continuous
        {
            builder = builder.limits(axis, [lo, hi]);
        }
        if let Some(d) = drive {
            builder = builder
                .motor_model(axis, MotorModel::ForceBased)
                .motor_position(axis, setpoint, d.stiffness, d.damping)
                .motor_max_force(axis, d.effort_limit);
        }
        let spec = builder.build();
        let (parent, child) = (bodies[parent_segment], bodies[child_segment]);
        let Some(handle) = world.multibody_joints.insert(parent, child, spec, true) else {
            return Err(TwinError::Vehicle(format!(
                "joint '{}' closes a loop: a vehicle must be a tree",
                joint.name
            )));
        };
        dofs.push(DofJoint {
            handle,
            parent,
            child,
            spec,
            axis,
            limits,
            drive,
            setpoint,
        });
    }

    // The arm must not collide with the base it is mounted on; start at the initial joints.
    if let Some(link) = world.multibody_joints.rigid_body_link(bodies[0]).copied()
        && let Some(mb) = world.multibody_joints.get_multibody_mut(link.multibody)
    {
        mb.set_self_contacts_enabled(false);
    }
    set_joint_positions(world, &dofs, q0);

    let link_body = segment.iter().map(|(s, f)| (bodies[*s], *f)).collect();
    Ok(VehicleBody {
        link_body,
        base: bodies[0],
        base_com_in_body,
        bodies,
        link_colliders,
        dofs,
    })
}

/// Places every joint at `q` (configuration order) and updates the bodies' poses to match.
pub(crate) fn set_joint_positions(world: &mut PhysicsWorld, dofs: &[DofJoint], q: &[f64]) {
    let mut root = None;
    for (d, &value) in dofs.iter().zip(q) {
        if let Some((mb, link)) = world.multibody_joints.get_mut(d.handle)
            && let Some(l) = mb.link_mut(link)
        {
            let current = joint_coordinate(&l.joint, d.axis);
            l.joint.apply_displacement(&[value - current]);
            root = Some(l.rigid_body_handle());
        }
    }
    if let Some(h) = root
        && let Some(link) = world.multibody_joints.rigid_body_link(h).copied()
        && let Some(mb) = world.multibody_joints.get_multibody_mut(link.multibody)
    {
        mb.forward_kinematics(&world.bodies, true);
        mb.update_rigid_bodies(&mut world.bodies, false);
    }
}

/// The joint's coordinate along its free axis (rad or m).
pub(crate) fn joint_coordinate(joint: &MultibodyJoint, axis: JointAxis) -> f64 {
    let c = joint.coords();
    match axis {
        JointAxis::LinX => c[0],
        _ => c[3],
    }
}

/// Position and velocity of every joint, configuration order.
pub(crate) fn joint_states(
    world: &PhysicsWorld,
    dofs: &[DofJoint],
    positions: &mut Vec<f64>,
    velocities: &mut Vec<f64>,
) {
    positions.clear();
    velocities.clear();
    for d in dofs {
        let (q, qd) = world
            .multibody_joints
            .get(d.handle)
            .and_then(|(mb, link)| {
                let l = mb.link(link)?;
                let v = mb.generalized_velocity();
                Some((
                    joint_coordinate(&l.joint, d.axis),
                    v.get(l.assembly_id()).copied().unwrap_or(0.0),
                ))
            })
            .unwrap_or((f64::NAN, f64::NAN));
        positions.push(q);
        velocities.push(qd);
    }
}

/// Takes the vehicle out of rapier's dynamics (`VehicleDynamics::Articulated` in free
/// flight): no multibody, every body kinematic where it is, for the twin's own dynamics to
/// place. [`attach`] puts it back.
pub(crate) fn detach(world: &mut PhysicsWorld, body: &VehicleBody) {
    world
        .multibody_joints
        .remove_multibody_articulations(body.base, false);
    for h in &body.bodies {
        if let Some(rb) = world.bodies.get_mut(*h) {
            rb.set_body_type(RigidBodyType::KinematicPositionBased, true);
        }
    }
}

/// The state [`attach`] hands to rapier's multibody: each body's world pose (`bodies`
/// order), the joints, the base's centre-of-mass velocity and angular velocity in the world.
pub(crate) struct HandOver<'a> {
    pub poses: &'a [Isometry3<f64>],
    pub q: &'a [f64],
    pub qd: &'a [f64],
    pub base_com_velocity_in_world: Vector3<f64>,
    pub base_angular_velocity_in_world: Vector3<f64>,
}

/// Puts a [`detach`]ed vehicle back into rapier's dynamics as the multibody [`build`] made,
/// in the state `s`.
pub(crate) fn attach(
    world: &mut PhysicsWorld,
    body: &VehicleBody,
    s: &HandOver<'_>,
) -> Result<(), TwinError> {
    for (h, pose) in body.bodies.iter().zip(s.poses) {
        if let Some(rb) = world.bodies.get_mut(*h) {
            rb.set_body_type(RigidBodyType::Dynamic, true);
            rb.set_position(pose_to_rapier(pose), true);
        }
    }
    // The base's velocity as the measurement reads it until the next step (which sets every
    // body's from the multibody's generalized velocities).
    if let Some(rb) = world.bodies.get_mut(body.base) {
        rb.set_linvel(vector_to_rapier(&s.base_com_velocity_in_world), true);
        rb.set_angvel(vector_to_rapier(&s.base_angular_velocity_in_world), true);
    }
    for d in &body.dofs {
        let handle = world
            .multibody_joints
            .insert(d.parent, d.child, d.spec, true);
        if handle != Some(d.handle) {
            return Err(TwinError::Vehicle(
                "re-inserting the vehicle's joints into rapier gave a different multibody"
                    .to_owned(),
            ));
        }
    }
    let Some(link) = world.multibody_joints.rigid_body_link(body.base).copied() else {
        return Ok(());
    };
    if let Some(mb) = world.multibody_joints.get_multibody_mut(link.multibody) {
        mb.set_self_contacts_enabled(false);
    }
    set_joint_positions(world, &body.dofs, s.q);
    let links: Vec<Option<usize>> = body
        .dofs
        .iter()
        .map(|d| {
            world
                .multibody_joints
                .rigid_body_link(d.child)
                .map(|l| l.id)
        })
        .collect();
    let Some(mb) = world.multibody_joints.get_multibody_mut(link.multibody) else {
        return Ok(());
    };
    let mut v = vec![0.0; mb.ndofs()];
    v[..3].copy_from_slice(s.base_com_velocity_in_world.as_slice());
    v[3..6].copy_from_slice(s.base_angular_velocity_in_world.as_slice());
    for (id, &rate) in links.iter().zip(s.qd) {
        if let Some(l) = id.and_then(|id| mb.link(id)) {
            v[l.assembly_id()] = rate;
        }
    }
    mb.generalized_velocity_mut().copy_from_slice(&v);
    Ok(())
}

/// Sets every body's linear velocity to `v` (world), the multibody's base included.
pub(crate) fn set_linear_velocity(world: &mut PhysicsWorld, body: &VehicleBody, v: &Vector3<f64>) {
    for h in &body.bodies {
        if let Some(rb) = world.bodies.get_mut(*h) {
            rb.set_linvel(vector_to_rapier(v), true);
        }
    }
    if let Some(link) = world.multibody_joints.rigid_body_link(body.base).copied()
        && let Some(mb) = world.multibody_joints.get_multibody_mut(link.multibody)
        && mb.ndofs() >= 6
    {
        mb.generalized_velocity_mut()
            .rows_mut(0, 3)
            .copy_from_slice(v.as_slice());
    }
}
