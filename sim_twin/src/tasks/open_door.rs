//! Open Door (AMBENCH_SPEC §4.6): a hinged door standing on the ground, pushed open 20° by
//! the closed gripper.
//!
//! The door is a fixed root on the ground at (1, 0, 0) moved by U(±0.3) in x and y and turned
//! by U(±15°) in yaw (Isaac Lab's `reset_root_state_uniform`, drawn x, y, yaw), and a leaf on
//! a vertical revolute hinge ("Hinge": stiffness 0, damping 5.0 N·m·s/rad scaled by
//! U(0.5, 2.0) at every reset, Coulomb friction 0.2 N·m, effort 20 N·m). The hinge opens away
//! from the robot: q > 0 when the leaf's free edge moves along the root's +x. It is a
//! multibody (reduced-coordinate) joint, as the reference's PhysX articulation
//! ([`ReducedJoint`]).
//!
//! [U] choices (the reference keeps the door only as a USD asset):
//! - Leaf ("door body"): a box 0.05 m thick (the thickness the reference's IK assumes), 0.8 m
//!   wide and 1.98 m high, its bottom 0.02 m above the ground (no ground friction), mass
//!   1.0 kg (the spec's `mass_props`, all of it on the leaf: the root is fixed). Its origin is
//!   its centre, at root-local (0, 0, 1.01) when closed, so the IK's obstacle face (leaf
//!   origin x − 0.025, per step) is the closed leaf's front face and follows the leaf as it
//!   swings open.
//! - Hinge: the vertical line through the leaf's +y edge on its mid-plane, root-local
//!   (0, 0.4, ·); limits [0, 100°] (0 closed against the frame's stop).
//! - Frame: only a hinge post on the root, a box 0.05 × 0.05 × 2.0 m just past the hinge
//!   edge (root-local y 0.425); no lintel or far jamb, so nothing but the leaf stands in the
//!   scripted path through the doorway.
//!
//! The scripted contact point (door_pos + (−0.15 + 0.18, −0.25, 1.2), the fingertips) lies
//! 0.65 m from the hinge on the leaf's front face: pushing it 0.4 m along x opens the door
//! well past 20°.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::{
    Dof, DriveType, JointSpec, ReducedJoint, attach, euler_xyz, fixed_body, symmetric, uniform,
};
use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::error::TwinError;

/// Hinge angle above which the door counts as opened, rad (20°).
pub(crate) const OPENED_RAD: f64 = 20.0 * std::f64::consts::PI / 180.0;
/// Engagement: 5 % of the opening angle, rad.
pub(crate) const ENGAGED_RAD: f64 = 0.05 * OPENED_RAD;
/// Default root position.
const ROOT: Vector3<f64> = Vector3::new(1.0, 0.0, 0.0);
/// Leaf thickness, m (the IK's 0.05).
pub(crate) const THICKNESS_M: f64 = 0.05;
/// Leaf width and height, m.
const WIDTH_M: f64 = 0.8;
const HEIGHT_M: f64 = 1.98;
/// Leaf bottom above the ground, m.
const CLEARANCE_M: f64 = 0.02;
/// Leaf mass, kg.
const MASS_KG: f64 = 1.0;
/// Nominal hinge damping, N·m·s/rad.
const DAMPING: f64 = 5.0;

#[derive(Debug, Default)]
pub(crate) struct OpenDoor {
    root: Option<RigidBodyHandle>,
    hinge: Option<ReducedJoint>,
    /// The hinge damping of this rollout (nominal × U(0.5, 2.0)).
    damping: f64,
}

impl OpenDoor {
    /// The leaf's centre relative to the root when closed.
    fn root_from_leaf() -> Isometry3<f64> {
        Isometry3::translation(0.0, 0.0, CLEARANCE_M + HEIGHT_M / 2.0)
    }

    /// The hinge frame on the root: x up (the revolute axis), on the leaf's +y edge.
    fn root_from_hinge() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.0, WIDTH_M / 2.0, CLEARANCE_M + HEIGHT_M / 2.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -std::f64::consts::FRAC_PI_2),
        )
    }

    fn spec(damping: f64) -> JointSpec {
        JointSpec {
            dof: Dof::Revolute,
            limits: Some((0.0, 100f64.to_radians())),
            stiffness: 0.0,
            damping,
            target: 0.0,
            effort: 20.0,
            friction: 0.2,
            initial: 0.0,
            drive: DriveType::Force,
        }
    }

    /// Hinge angle, rad (signed, + opening away from the robot).
    fn angle(&self, world: &PhysicsWorld) -> f64 {
        self.hinge.as_ref().map_or(0.0, |h| h.position(world))
    }

    /// World position of the door body (the leaf's origin).
    fn leaf_position(&self, world: &PhysicsWorld) -> Option<Vector3<f64>> {
        self.hinge
            .as_ref()
            .map(|h| h.link_pose(world).translation.vector)
    }
}

impl Scene for OpenDoor {
    fn task(&self) -> TaskId {
        TaskId::OpenDoor
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &["door_engaged", "door_opened"]
    }

    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError> {
        let x = symmetric(b.rng, 0.3);
        let y = symmetric(b.rng, 0.3);
        let yaw = symmetric(b.rng, std::f64::consts::PI / 12.0);
        self.damping = DAMPING * uniform(b.rng, 0.5, 2.0);
        let pose = Isometry3::from_parts(
            Translation3::from(ROOT + Vector3::new(x, y, 0.0)),
            euler_xyz(0.0, 0.0, yaw),
        );
        let root = fixed_body(b.world, &pose);
        // The hinge post, just past the leaf's hinge edge.
        attach(
            b.world,
            root,
            ColliderBuilder::cuboid(0.025, 0.025, 1.0),
            &Isometry3::translation(0.0, WIDTH_M / 2.0 + 0.025 + 0.001, 1.0),
        );
        let root_from_hinge = Self::root_from_hinge();
        let hinge_from_leaf = root_from_hinge.inverse() * Self::root_from_leaf();
        let (hinge, _) = ReducedJoint::insert(
            b.world,
            root,
            root_from_hinge,
            hinge_from_leaf,
            vec![(
                ColliderBuilder::cuboid(THICKNESS_M / 2.0, WIDTH_M / 2.0, HEIGHT_M / 2.0),
                Isometry3::identity(),
            )],
            MASS_KG,
            &Self::spec(self.damping),
        )
        .ok_or_else(|| TwinError::Config("open door: the hinge cannot join its root".to_owned()))?;
        self.root = Some(root);
        self.hinge = Some(hinge);
        Ok(())
    }

    fn after_step(&mut self, world: &mut PhysicsWorld, _view: &View) -> TaskStatus {
        let q = self.angle(world);
        let opened = q > OPENED_RAD;
        TaskStatus {
            success: opened,
            criteria: vec![q >= ENGAGED_RAD, opened],
        }
    }

    fn observation(&self, world: &PhysicsWorld) -> TaskObservation {
        let mut o = TaskObservation::default();
        o.push(keys::DOOR_JOINT_POS, [self.angle(world)]);
        if let Some(root) = self.root {
            o.push_vec3(keys::DOOR_POS, &super::objects::position_of(world, root));
        }
        o
    }

    fn obstacle_face_x(&self, world: &PhysicsWorld) -> Option<f64> {
        self.leaf_position(world).map(|p| p.x - THICKNESS_M / 2.0)
    }
}

#[cfg(test)]
mod tests {

    use super::*;
    use crate::convert::vector_to_rapier;
    use crate::tasks::objects::pose_of;

    fn built(seed: u64) -> (PhysicsWorld, OpenDoor) {
        let mut w = crate::tasks::tests::world_with(false);
        let mut scene = OpenDoor::default();
        crate::tasks::tests::build_into(&mut w, &mut scene, seed);
        (w, scene)
    }

    fn view() -> View {
        crate::tasks::tests::view_of(1, Vector3::zeros(), Vector3::zeros(), 0.0)
    }

    fn hinge(scene: &OpenDoor) -> ReducedJoint {
        scene.hinge.clone().unwrap_or_else(|| panic!("no hinge"))
    }

    #[test]
    fn the_door_pose_and_hinge_damping_are_drawn_in_the_spec_ranges() {
        let mut dampings = Vec::new();
        for seed in 0..30 {
            let (w, scene) = built(seed);
            let obs = scene.observation(&w);
            let p = obs.vec3("door_pos", 0).unwrap_or_else(|e| panic!("{e}"));
            assert!((p.x - 1.0).abs() <= 0.3 && p.y.abs() <= 0.3 && p.z.abs() < 1e-12);
            let root = pose_of(&w, scene.root.unwrap_or_else(|| panic!("no root")));
            let (roll, pitch, yaw) = root.rotation.euler_angles();
            assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12);
            assert!(yaw.abs() <= std::f64::consts::PI / 12.0);
            assert!(
                (2.5..10.0).contains(&scene.damping),
                "damping {}",
                scene.damping
            );
            assert_eq!(obs.scalar("door_joint_pos"), Ok(0.0));
            // Closed, the obstacle face is the leaf's front face at the root's x.
            let face = scene.obstacle_face_x(&w).unwrap_or(f64::NAN);
            assert!((face - (p.x - 0.025)).abs() < 1e-9, "face {face}, root {p}");
            dampings.push(scene.damping);
        }
        let spread = dampings.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - dampings.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(spread > 4.0, "the damping is randomised: spread {spread}");
    }

    #[test]
    fn the_criteria_flip_at_20_degrees_and_at_5_percent_of_it() {
        let (mut w, mut scene) = built(4);
        let h = hinge(&scene);
        let cases = [
            (0.0, false, false),
            (0.017453 - 1e-4, false, false),
            (0.017453 + 1e-4, true, false),
            (0.34907 - 1e-4, true, false),
            (0.34907 + 1e-4, true, true),
        ];
        for (q, engaged, opened) in cases {
            h.set_position(&mut w, q);
            let s = scene.after_step(&mut w, &view());
            assert_eq!(s.criteria, vec![engaged, opened], "q = {q}");
            assert_eq!(s.success, opened, "q = {q}");
        }
    }

    #[test]
    fn pushing_the_leaf_away_opens_it_against_the_hinge_damping_and_the_face_follows() {
        let (mut w, scene) = built(6);
        let h = hinge(&scene);
        let root = pose_of(&w, scene.root.unwrap_or_else(|| panic!("no root")));
        let closed_face = scene.obstacle_face_x(&w).unwrap_or(f64::NAN);
        // 5 N along the leaf's normal at its centre, 0.4 m from the hinge: 2 N·m less 0.2 N·m
        // of friction against the rollout's damping c: 1.8/c rad/s once the leaf's
        // 0.21 kg·m² has spun up (I/c < 0.1 s).
        let c = scene.damping;
        for _ in 0..240 {
            let normal = h.link_pose(&w).rotation * Vector3::x();
            if let Some(rb) = w.bodies.get_mut(h.link) {
                rb.reset_forces(false);
                rb.add_force(vector_to_rapier(&(normal * 5.0)), true);
            }
            w.step();
        }
        let q = h.position(&w);
        let expected = 1.8 / c * 0.5;
        assert!(q > 0.0, "the door opens away from the robot");
        assert!(
            (q - expected).abs() < 0.15 * expected,
            "q = {q}, expected {expected} (c = {c})"
        );
        // The face moves with the leaf (its centre is 0.4 m from the hinge).
        let face = scene.obstacle_face_x(&w).unwrap_or(f64::NAN);
        let centre = h.link_pose(&w).translation.vector;
        assert!((face - (centre.x - 0.025)).abs() < 1e-12);
        assert!(
            face > closed_face,
            "face {face} vs closed {closed_face} (root {root:?})"
        );
    }
}
