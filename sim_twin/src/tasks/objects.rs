//! Building blocks of the task scenes: random draws, fixed and dynamic bodies, the wall,
//! articulated objects, and the grasp constraint.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rapier3d_f64::prelude::*;

use crate::convert::{pose_from_rapier, pose_to_rapier, vector_from_rapier, vector_to_rapier};
use crate::vehicle_body::{ROBOT_GROUP, WORLD_GROUP, material};

/// U(lo, hi) (lo when the interval is empty).
pub(crate) fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

/// U(−half, half).
pub(crate) fn symmetric(rng: &mut ChaCha8Rng, half: f64) -> f64 {
    uniform(rng, -half, half)
}

/// Scene colliders: world members that collide with everything.
pub(crate) fn world_groups() -> InteractionGroups {
    InteractionGroups::new(WORLD_GROUP, Group::ALL, InteractionTestMode::And)
}

/// A held object's colliders: no contact with the robot while the grasp constraint holds it.
pub(crate) fn held_groups() -> InteractionGroups {
    InteractionGroups::new(
        WORLD_GROUP,
        Group::ALL.difference(ROBOT_GROUP),
        InteractionTestMode::And,
    )
}

/// A fixed body at `pose`.
pub(crate) fn fixed_body(world: &mut PhysicsWorld, pose: &Isometry3<f64>) -> RigidBodyHandle {
    world.insert_body(RigidBodyBuilder::fixed().pose(pose_to_rapier(pose)))
}

/// Attaches a collider (default material: μ 1, e 0, multiply) to `body` at `local`.
pub(crate) fn attach(
    world: &mut PhysicsWorld,
    body: RigidBodyHandle,
    shape: ColliderBuilder,
    local: &Isometry3<f64>,
) -> ColliderHandle {
    let collider = material(shape)
        .collision_groups(world_groups())
        .position(pose_to_rapier(local));
    world.insert_collider(collider, Some(body))
}

/// A fixed box of `half` extents centred at `pose`.
pub(crate) fn fixed_box(
    world: &mut PhysicsWorld,
    pose: &Isometry3<f64>,
    half: Vector3<f64>,
) -> (RigidBodyHandle, ColliderHandle) {
    let body = fixed_body(world, pose);
    let c = attach(
        world,
        body,
        ColliderBuilder::cuboid(half.x, half.y, half.z),
        &Isometry3::identity(),
    );
    (body, c)
}

/// A dynamic body at `pose` with one collider of mass `mass_kg` (inertia from the shape).
pub(crate) fn dynamic_body(
    world: &mut PhysicsWorld,
    pose: &Isometry3<f64>,
    shape: ColliderBuilder,
    mass_kg: f64,
    gravity: bool,
) -> (RigidBodyHandle, ColliderHandle) {
    let body = world.insert_body(
        RigidBodyBuilder::dynamic()
            .pose(pose_to_rapier(pose))
            .gravity_scale(if gravity { 1.0 } else { 0.0 })
            .can_sleep(false)
            .build(),
    );
    let collider = material(shape)
        .mass(mass_kg)
        .collision_groups(world_groups());
    let c = world.insert_collider(collider, Some(body));
    (body, c)
}

/// World pose of a body (identity if it is gone).
pub(crate) fn pose_of(world: &PhysicsWorld, body: RigidBodyHandle) -> Isometry3<f64> {
    world
        .bodies
        .get(body)
        .map_or_else(Isometry3::identity, |rb| pose_from_rapier(rb.position()))
}

/// World position of a body's origin.
pub(crate) fn position_of(world: &PhysicsWorld, body: RigidBodyHandle) -> Vector3<f64> {
    pose_of(world, body).translation.vector
}

/// World linear velocity of a body's centre of mass.
pub(crate) fn velocity_of(world: &PhysicsWorld, body: RigidBodyHandle) -> Vector3<f64> {
    world
        .bodies
        .get(body)
        .map_or_else(Vector3::zeros, |rb| vector_from_rapier(rb.linvel()))
}

/// Sets the collision groups of every collider of `body`.
pub(crate) fn set_groups(
    world: &mut PhysicsWorld,
    body: RigidBodyHandle,
    groups: InteractionGroups,
) {
    let colliders: Vec<ColliderHandle> = world
        .bodies
        .get(body)
        .map(|rb| rb.colliders().to_vec())
        .unwrap_or_default();
    for c in colliders {
        if let Some(col) = world.colliders.get_mut(c) {
            col.set_collision_groups(groups);
        }
    }
}

/// Total contact force between two colliders over the last physics substep, N.
pub(crate) fn contact_force_n(
    world: &PhysicsWorld,
    a: ColliderHandle,
    b: ColliderHandle,
    substep_s: f64,
) -> f64 {
    world
        .contact_pair(a, b)
        .map_or(0.0, |p| p.total_impulse_magnitude() / substep_s)
}

/// Quaternion from Euler x-y-z (roll, pitch, yaw) as Isaac Lab's `quat_from_euler_xyz`
/// (R = Rz·Ry·Rx).
pub(crate) fn euler_xyz(roll: f64, pitch: f64, yaw: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(roll, pitch, yaw)
}

/// The default wall of the suite (AMBENCH_SPEC §4.0): a box 0.1 × 2.0 × 2.0 m, μ 1, e 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Wall {
    /// Centre pose.
    pub pose: Isometry3<f64>,
}

impl Wall {
    /// Half extents, m.
    pub const HALF: Vector3<f64> = Vector3::new(0.05, 1.0, 1.0);
    /// Default centre.
    pub const CENTER: Vector3<f64> = Vector3::new(2.0, 0.0, 1.0);

    /// The wall at its default pose.
    pub fn at_default() -> Self {
        Self::at(Self::CENTER)
    }

    /// The wall centred at `center`, unrotated.
    pub fn at(center: Vector3<f64>) -> Self {
        Self {
            pose: Isometry3::from_parts(Translation3::from(center), UnitQuaternion::identity()),
        }
    }

    /// The default wall moved by U(±dx), U(±dy) and pitched by U(±pitch) (Isaac Lab's
    /// `reset_root_state_uniform`: orientation = default ⊗ euler(0, pitch, 0)).
    pub fn randomized(rng: &mut ChaCha8Rng, dx: f64, dy: f64, pitch: f64) -> Self {
        let x = symmetric(rng, dx);
        let y = symmetric(rng, dy);
        let p = symmetric(rng, pitch);
        Self {
            pose: Isometry3::from_parts(
                Translation3::from(Self::CENTER + Vector3::new(x, y, 0.0)),
                euler_xyz(0.0, p, 0.0),
            ),
        }
    }

    /// Adds it to the world.
    pub fn insert(&self, world: &mut PhysicsWorld) -> (RigidBodyHandle, ColliderHandle) {
        fixed_box(world, &self.pose, Self::HALF)
    }

    /// A point given in the wall's frame, in the world.
    pub fn point(&self, local: Vector3<f64>) -> Vector3<f64> {
        self.pose.translation.vector + self.pose.rotation * local
    }

    /// The pose of a frame at `local` in the wall, turned by `rotation` after the wall's.
    pub fn frame(&self, local: Vector3<f64>, rotation: UnitQuaternion<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.point(local)),
            self.pose.rotation * rotation,
        )
    }

    /// World x of the face toward the robot at the wall's centre (IK limits).
    pub fn face_x(&self) -> f64 {
        self.pose.translation.x - Self::HALF.x
    }
}

/// A one-degree-of-freedom joint's type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Dof {
    /// Slides along the joint frame's x.
    Prismatic,
    /// Turns about the joint frame's x.
    Revolute,
}

/// An articulated object's joint: the spec's limits, drive and friction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct JointSpec {
    /// Prismatic or revolute.
    pub dof: Dof,
    /// Lower and upper limit (m or rad).
    pub limits: Option<(f64, f64)>,
    /// Spring stiffness toward `target` (N/m or N·m/rad), 0 for none.
    pub stiffness: f64,
    /// Viscous damping (N·s/m or N·m·s/rad).
    pub damping: f64,
    /// Spring rest position.
    pub target: f64,
    /// Most drive force or torque.
    pub effort: f64,
    /// Coulomb friction force or torque (static = dynamic).
    pub friction: f64,
    /// Position at reset.
    pub initial: f64,
    /// How the drive's stiffness, damping and effort are read.
    pub drive: DriveType,
}

/// How an articulated object's joint drive acts: PhysX articulation drives, which the
/// reference's assets author, are either of the two ([U] per asset: the reference sets only the
/// gains, its USD files the type).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DriveType {
    /// Force (or torque) = stiffness · Δq + damping · Δq̇, capped at the effort (SI units).
    Force,
    /// Acceleration = stiffness · Δq + damping · Δq̇: the force is that times the joint's
    /// effective inertia (PhysX `eACCELERATION`, rapier's `MotorModel::AccelerationBased`),
    /// so a light object's drive resists little whatever its gains.
    Acceleration,
}

/// Velocity gain of the friction motor: far above any object's inertia/dt so the cap
/// (the friction force) decides.
const FRICTION_GAIN: f64 = 1.0e4;

/// How much wider than the object the fingers open before it slips out, m.
const RELEASE_MARGIN_M: f64 = 0.002;

/// The grasp constraint (see [`super::GraspMode`]).
#[derive(Debug, Clone, Default)]
pub(crate) struct Grasp {
    /// Bodies the fingers may grasp.
    pub graspable: Vec<RigidBodyHandle>,
    /// The object held and the constraint holding it.
    pub held: Option<(RigidBodyHandle, ImpulseJointHandle)>,
    /// Gripper width beyond which the opening fingers no longer hold the object, m: its
    /// width between the fingers (measured when they closed on it, or the spec's grasp
    /// width for a pre-grasped object).
    pub release_width_m: f64,
}

impl Grasp {
    /// Attaches `object` to `ee_body` where they are now; the fingers let it go once they
    /// open wider than `release_width_m`.
    pub fn attach(
        &mut self,
        world: &mut PhysicsWorld,
        ee_body: RigidBodyHandle,
        object: RigidBodyHandle,
        release_width_m: f64,
    ) {
        self.release_width_m = release_width_m;
        let ee_from_object = pose_of(world, ee_body).inverse() * pose_of(world, object);
        // The fingers hold the object where it is; a round bar spins in them (see
        // `free_axis_frame`): the finger drives (100 N/m toward closed, AMBENCH_SPEC §1.2)
        // squeeze a 3 cm bar with ~1.4 N each, nothing beside the loads a grasp carries.
        let joint = match free_axis_frame(world, object) {
            Some(object_from_axis) => GenericJointBuilder::new(JointAxesMask::LOCKED_REVOLUTE_AXES)
                .local_frame1(pose_to_rapier(&(ee_from_object * object_from_axis)))
                .local_frame2(pose_to_rapier(&object_from_axis))
                .contacts_enabled(false)
                .build(),
            None => FixedJointBuilder::new()
                .local_frame1(pose_to_rapier(&ee_from_object))
                .local_frame2(pose_to_rapier(&Isometry3::identity()))
                .contacts_enabled(false)
                .build()
                .into(),
        };
        let handle = world.insert_impulse_joint(ee_body, object, joint);
        set_groups(world, object, held_groups());
        self.held = Some((object, handle));
    }

    /// Releases the held object, if any.
    pub fn release(&mut self, world: &mut PhysicsWorld) {
        if let Some((object, joint)) = self.held.take() {
            world.remove_impulse_joint(joint);
            set_groups(world, object, world_groups());
        }
    }

    /// One tick of the assisted grasp: release once the gripper opens (action ≥ 0) and its
    /// drives no longer squeeze the held object — their targets wider than the object (a
    /// friction grip lets go when the squeeze is gone, before the fingers have moved); engage
    /// when it is closing and both fingers press a graspable object with their inner faces.
    /// `width_m` is the measured gripper width, `target_width_m` the width its drives are
    /// commanded to.
    pub fn update(
        &mut self,
        world: &mut PhysicsWorld,
        ee_body: RigidBodyHandle,
        fingers: &[Vec<ColliderHandle>; 2],
        (closing, width_m, target_width_m): (bool, f64, f64),
        assisted: bool,
    ) {
        if !closing {
            if target_width_m > self.release_width_m {
                self.release(world);
            }
            return;
        }
        if self.held.is_some() || !assisted {
            return;
        }
        // Each finger must press the object with its inner face: the contact normal (finger
        // to object) within 60° of the way the finger closes, toward the other finger. A
        // fingertip or an outer face touching (e.g. a door panel beside a jammed gripper) is
        // no grip.
        let (Some(a), Some(b)) = (
            finger_origin(world, &fingers[0]),
            finger_origin(world, &fingers[1]),
        ) else {
            return;
        };
        let Some(inward) = (b - a).try_normalize(1e-9) else {
            return;
        };
        let found = self.graspable.iter().copied().find(|o| {
            presses(world, &fingers[0], &inward, *o) && presses(world, &fingers[1], &-inward, *o)
        });
        if let Some(object) = found {
            // The fingers stopped on it: it slips out once they open past this width.
            self.attach(world, ee_body, object, width_m + RELEASE_MARGIN_M);
        }
    }
}

/// The axis a grasped object turns about in the fingers, as a frame in the object's frame
/// (x along the axis, origin on it); None for an object the fingers hold fixed. A round bar
/// (an object of one cylinder collider) spins about its own axis: only the grip's friction
/// resists, 2·μ·N·r = 2 · 1 · 1.4 N · 0.015 m = 0.04 N·m for the valve's handle.
///
/// Tried and not kept: a long square bar (the lever) tipping about the axis across the bar
/// and the closing direction, as the soft finger drives would let it, through a point d
/// ahead of the EE link (docs/pull-lever.md). FA-Hexa lever 18–25° (weld) → 24° at the
/// pads' centre (d = 0.13 m), 34° at the palm (0.08), 39.9° at 0.04, 40° only at d = 0 (a
/// pivot no finger makes): the script's pull target lies on the EE link's circle, off the
/// circle of any point ahead of it on a hand that keeps its orientation. The EE-only oracle,
/// whose PID pushes at its centre of mass on the EE link, swings about any pivot ahead of it
/// (d = 0.13: pitch 84°, lever 15°; 30 of 30 → 0).
fn free_axis_frame(world: &PhysicsWorld, object: RigidBodyHandle) -> Option<Isometry3<f64>> {
    let [collider] = world.bodies.get(object)?.colliders() else {
        return None;
    };
    let collider = world.colliders.get(*collider)?;
    collider.shape().as_cylinder()?;
    let object_from_shape = collider
        .position_wrt_parent()
        .map_or_else(Isometry3::identity, pose_from_rapier);
    // rapier's cylinders stand along their local y.
    let axis = object_from_shape.rotation * Vector3::y();
    let turn = UnitQuaternion::rotation_between(&Vector3::x(), &axis).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
    });
    Some(Isometry3::from_parts(object_from_shape.translation, turn))
}

/// Smallest cosine between a finger's contact normal and its closing direction for the
/// contact to count as a grip (60°).
const GRIP_NORMAL_COS: f64 = 0.5;

/// World position of the body a finger's first collider is attached to.
fn finger_origin(world: &PhysicsWorld, finger: &[ColliderHandle]) -> Option<Vector3<f64>> {
    let body = world.colliders.get(*finger.first()?)?.parent()?;
    Some(pose_of(world, body).translation.vector)
}

/// How near a finger's face must come to the object to count as pressing it, m. The twin's
/// contacts start at 5 mm (`PREDICTION_DISTANCE_M`); the grip's test keeps the 2 cm it had
/// while rapier's default contact distance set it: the script closes the fingers as it
/// starts to move (Rotate Valve: closed at the circle's first step), and the fingers, slow
/// on their 100 N/m drives, stand 0.0199 m open then; with a 5 mm reach the far finger met
/// the valve's handle only after the near one had dragged it aside, and 20 of 30 FA-Hexa
/// valve rollouts never engaged (measured).
const GRIP_REACH_M: f64 = 0.02;

/// Whether `finger` is within [`GRIP_REACH_M`] of `object`, its nearest points' normal
/// (finger → object) along `closing` (unit, world) within the grip cone.
fn presses(
    world: &PhysicsWorld,
    finger: &[ColliderHandle],
    closing: &Vector3<f64>,
    object: RigidBodyHandle,
) -> bool {
    let Some(rb) = world.bodies.get(object) else {
        return false;
    };
    finger
        .iter()
        .filter_map(|f| world.colliders.get(*f))
        .any(|f| {
            rb.colliders()
                .iter()
                .filter_map(|o| world.colliders.get(*o))
                .any(|o| {
                    rapier3d_f64::parry::query::contact(
                        f.position(),
                        f.shape(),
                        o.position(),
                        o.shape(),
                        GRIP_REACH_M,
                    )
                    .ok()
                    .flatten()
                    .is_some_and(|c| vector_from_rapier(c.normal1).dot(closing) > GRIP_NORMAL_COS)
                })
        })
}

/// Sets a dynamic body's linear velocity (throws, tests).
#[allow(dead_code)]
pub(crate) fn set_velocity(world: &mut PhysicsWorld, body: RigidBodyHandle, v: &Vector3<f64>) {
    if let Some(rb) = world.bodies.get_mut(body) {
        rb.set_linvel(vector_to_rapier(v), true);
    }
}

// ---------------------------------------------------------------------------------------
// Reduced-coordinate articulated objects (added for Rotate Valve, Pull Lever, Open Door).
//
// The reference's articulated objects are PhysX articulations: reduced coordinates, the joint
// itself exact, only the drive solved. An impulse joint would hold its link with
// velocity constraints solved by the same few PGS iterations as the heavily damped drive; a
// load that reaches the link through the anchor (gravity, a grasp at a lever arm) then leaks
// past the drive: a 0.2 kg arm on a 100 N·m·s/rad damper under 0.2 N·m of gravity turns
// ~44× faster than the damping allows at 4 iterations (12× at 16). On a multibody joint the
// drive holds exactly (see the tests of these scenes).

/// An articulated object's link on a multibody (reduced-coordinate) joint of one degree of
/// freedom about or along the joint frame's x, with the spec's limits, drive and friction.
#[derive(Debug, Clone)]
pub(crate) struct ReducedJoint {
    /// The moving link.
    pub link: RigidBodyHandle,
    /// The multibody joint.
    pub joint: MultibodyJointHandle,
    dof: Dof,
    /// The joint frame in the link's frame (x = the axis, origin on it).
    link_from_joint: Isometry3<f64>,
}

impl ReducedJoint {
    /// Adds a link to `parent` on a joint at `parent_from_joint` (axis = the joint frame's x).
    /// `joint_from_link0` places the link in the joint frame at position 0; the link starts
    /// at `spec.initial`. `shapes` are the link's colliders in its own frame, sharing
    /// `mass_kg`. Coulomb friction is a velocity motor capped at the friction value on a
    /// second (impulse) joint of no locked axis. None if the joint cannot join the
    /// multibody (a cycle).
    pub fn insert(
        world: &mut PhysicsWorld,
        parent: RigidBodyHandle,
        parent_from_joint: Isometry3<f64>,
        joint_from_link0: Isometry3<f64>,
        shapes: Vec<(ColliderBuilder, Isometry3<f64>)>,
        mass_kg: f64,
        spec: &JointSpec,
    ) -> Option<(Self, Vec<ColliderHandle>)> {
        let pose = pose_of(world, parent) * parent_from_joint * joint_from_link0;
        let link = world.insert_body(
            RigidBodyBuilder::dynamic()
                .pose(pose_to_rapier(&pose))
                .can_sleep(false)
                .build(),
        );
        let each = mass_kg / shapes.len().max(1) as f64;
        let colliders = shapes
            .into_iter()
            .map(|(shape, local)| {
                let c = material(shape)
                    .mass(each)
                    .collision_groups(world_groups())
                    .position(pose_to_rapier(&local));
                world.insert_collider(c, Some(link))
            })
            .collect();
        let (mask, axis) = match spec.dof {
            Dof::Prismatic => (JointAxesMask::LOCKED_PRISMATIC_AXES, JointAxis::LinX),
            Dof::Revolute => (JointAxesMask::LOCKED_REVOLUTE_AXES, JointAxis::AngX),
        };
        let frame1 = pose_to_rapier(&parent_from_joint);
        let frame2 = pose_to_rapier(&joint_from_link0.inverse());
        let mut main = GenericJointBuilder::new(mask)
            .local_frame1(frame1)
            .local_frame2(frame2)
            .contacts_enabled(false)
            .motor_model(
                axis,
                match spec.drive {
                    DriveType::Force => MotorModel::ForceBased,
                    DriveType::Acceleration => MotorModel::AccelerationBased,
                },
            )
            .motor_max_force(axis, spec.effort);
        if let Some((lo, hi)) = spec.limits {
            main = main.limits(axis, [lo, hi]);
        }
        main = if spec.stiffness > 0.0 {
            main.motor_position(axis, spec.target, spec.stiffness, spec.damping)
        } else {
            main.motor_velocity(axis, 0.0, spec.damping)
        };
        let joint = world.insert_multibody_joint(parent, link, main.build())?;
        if spec.friction > 0.0 {
            let friction = GenericJointBuilder::new(JointAxesMask::empty())
                .local_frame1(frame1)
                .local_frame2(frame2)
                .contacts_enabled(false)
                .motor_model(axis, MotorModel::ForceBased)
                .motor_velocity(axis, 0.0, FRICTION_GAIN)
                .motor_max_force(axis, spec.friction);
            world.insert_impulse_joint(parent, link, friction.build());
        }
        let this = Self {
            link,
            joint,
            dof: spec.dof,
            link_from_joint: joint_from_link0.inverse(),
        };
        if spec.initial != 0.0 {
            this.set_position(world, spec.initial);
        }
        Some((this, colliders))
    }

    /// Joint position (m or rad): the multibody coordinate (continuous across ±π).
    pub fn position(&self, world: &PhysicsWorld) -> f64 {
        world
            .multibody_joints
            .get(self.joint)
            .and_then(|(mb, id)| mb.link(id))
            .map_or(0.0, |l| {
                let c = l.joint.coords();
                match self.dof {
                    Dof::Prismatic => c[0],
                    Dof::Revolute => c[3],
                }
            })
    }

    /// Moves the joint to `value` (at rest) and the bodies with it.
    pub fn set_position(&self, world: &mut PhysicsWorld, value: f64) {
        let current = self.position(world);
        let Some(multibody) = world
            .multibody_joints
            .rigid_body_link(self.link)
            .map(|l| l.multibody)
        else {
            return;
        };
        if let Some((mb, id)) = world.multibody_joints.get_mut(self.joint) {
            if let Some(l) = mb.link_mut(id) {
                l.joint.apply_displacement(&[value - current]);
            }
            mb.generalized_velocity_mut().fill(0.0);
        }
        if let Some(mb) = world.multibody_joints.get_multibody_mut(multibody) {
            mb.forward_kinematics(&world.bodies, true);
            mb.update_rigid_bodies(&mut world.bodies, false);
        }
    }

    /// World pose of the link.
    pub fn link_pose(&self, world: &PhysicsWorld) -> Isometry3<f64> {
        pose_of(world, self.link)
    }

    /// The motion this joint allows its link now, in the world: the joint frame carried by
    /// the link (its x the axis; for a revolute joint its origin stays on the axis).
    pub fn motion(&self, world: &PhysicsWorld) -> super::HeldJoint {
        let frame = self.link_pose(world) * self.link_from_joint;
        let axis = frame.rotation * Vector3::x();
        match self.dof {
            Dof::Prismatic => super::HeldJoint::Prismatic { axis },
            Dof::Revolute => super::HeldJoint::Revolute {
                axis,
                point: frame.translation.vector,
            },
        }
    }
}

// Shared by the peg-in-hole, toss-ball and wipe-window scenes.

/// Makes every contact of `collider` exact at every step. rapier's contact recycling keeps a
/// touching pair's contact points and normal, frozen in world space, until the pair's relative
/// pose has drifted by `contact_recycle_distance` (5 cm by default): a held peg sliding a few
/// millimetres into a hole keeps a stale normal from its first touch and stops against a
/// contact that is no longer there. Pairs with active hooks are never recycled; the twin
/// steps with no hooks (`()`), so the solver-contact hook asked for here is a no-op and the
/// only effect is a full contact update of this collider's pairs every step.
pub(crate) fn exact_contacts(world: &mut PhysicsWorld, collider: ColliderHandle) {
    if let Some(c) = world.colliders.get_mut(collider) {
        c.set_active_hooks(ActiveHooks::MODIFY_SOLVER_CONTACTS);
    }
}

/// Moves a body (and zeroes its velocity): scene tests.
#[cfg(test)]
pub(crate) fn place(world: &mut PhysicsWorld, body: RigidBodyHandle, pose: &Isometry3<f64>) {
    if let Some(rb) = world.bodies.get_mut(body) {
        rb.set_position(pose_to_rapier(pose), true);
        rb.set_linvel(Vector::ZERO, true);
        rb.set_angvel(Vector::ZERO, true);
    }
}

/// A point `local` of a body in the world: scene tests.
#[cfg(test)]
pub(crate) fn point_of(
    world: &PhysicsWorld,
    body: RigidBodyHandle,
    local: &Vector3<f64>,
) -> Vector3<f64> {
    (pose_of(world, body) * nalgebra::Point3::from(*local)).coords
}
