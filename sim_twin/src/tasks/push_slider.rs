//! Push Slider (AMBENCH_SPEC §4.9): a knob on a rail along a randomised wall, pushed from
//! q = −0.5 m to 0.45 m.
//!
//! [U] choices (the reference keeps the slider only as a USD asset): the rail is a fixed bar
//! 1.1 m long, 0.02 m deep and 0.04 m high on the wall face; the knob ("Slider" body, mass
//! 0.2 kg, its origin 0.10 m off the wall face) is a box 0.03 m along the rail and 0.08 m
//! high that reaches from the rail to 0.31 m off the wall face; the joint is limited to
//! [−0.5, 0.5] m. The root is the wall frame turned 180° about z, so the joint's positive
//! direction is −w_y (the scripted push direction).
//!
//! Why the knob reaches 0.31 m: the script sends every vehicle's EE link to 0.23 m in front
//! of the knob's origin (0.33 m off the face), and the tool tips sit 0.18 m (FA-Hexa, UA-Hexa),
//! 0.075 m (UA-Quad) and 0.0445 m (Omni-Hexa) ahead of it, so they stop 0.15, 0.255 and
//! 0.29 m off the face. The paper's embodiment table reports Push Slider on all four vehicles,
//! so its knob reached all four tool tips; a knob ending at 0.18 m left the UA-Quad and the
//! Omni-Hexa at 0 %. The FA-Hexa's gripper body then presses on the knob's end (its rotor
//! saturation on this task, 44 %, is then near the paper's 39.5 %).

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::{Dof, JointSpec, ReducedJoint, Wall, attach, fixed_body, symmetric};
use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::error::TwinError;

/// Slider position at which it counts as pushed, m.
pub(crate) const PUSHED_M: f64 = 0.45;
/// Slider position at reset, m.
pub(crate) const INITIAL_M: f64 = -0.5;
/// Engagement: 5 % of the way from the start to the goal.
pub(crate) const ENGAGED_M: f64 = 0.05 * (PUSHED_M - INITIAL_M);

const RAIL_DEPTH_M: f64 = 0.02;
/// Half extents of the knob's box if it were centred on the body's origin: its origin sits
/// `RAIL_DEPTH_M + KNOB_HALF.x` = 0.10 m off the wall face (what the script aims at).
const KNOB_HALF: Vector3<f64> = Vector3::new(0.08, 0.015, 0.04);
/// How far the knob reaches out from the wall face, m (see the module's note).
pub(crate) const KNOB_REACH_M: f64 = 0.31;
/// Half length of the knob's box out of the wall: from the rail's face to `KNOB_REACH_M`.
const KNOB_LONG_HALF_X: f64 = (KNOB_REACH_M - RAIL_DEPTH_M) / 2.0;

const SPEC: JointSpec = JointSpec {
    dof: Dof::Prismatic,
    limits: Some((-0.5, 0.5)),
    stiffness: 0.0,
    damping: 5.0,
    target: 0.0,
    effort: 1000.0,
    friction: 4.0,
    initial: INITIAL_M,
};

#[derive(Debug, Default)]
pub(crate) struct PushSlider {
    wall: Option<Wall>,
    slider: Option<ReducedJoint>,
}

impl Scene for PushSlider {
    fn task(&self) -> TaskId {
        TaskId::PushSlider
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &["slider_engaged", keys::SLIDER_PUSHED]
    }

    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError> {
        let wall = Wall::randomized(b.rng, 0.2, 0.2, 0.0);
        wall.insert(b.world);
        let y = symmetric(b.rng, 0.3);
        let z = symmetric(b.rng, 0.3);
        let turned = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
        // Root frame: x out of the wall toward the robot, y = −w_y (the push direction).
        let root = fixed_body(
            b.world,
            &wall.frame(Vector3::new(-Wall::HALF.x, y, z), turned),
        );
        attach(
            b.world,
            root,
            ColliderBuilder::cuboid(RAIL_DEPTH_M / 2.0, 0.55, 0.02),
            &Isometry3::translation(RAIL_DEPTH_M / 2.0, 0.0, 0.0),
        );
        // Joint frame: its x along the root's y.
        let root_from_joint = Isometry3::rotation(Vector3::z() * std::f64::consts::FRAC_PI_2);
        // Knob centre in the joint frame at q = 0: out of the wall along the root's x, which
        // is the joint frame's −y.
        let out = RAIL_DEPTH_M + KNOB_HALF.x;
        let joint_from_link0 = Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, -out, 0.0),
            root_from_joint.rotation.inverse(),
        );
        let Some((slider, _)) = ReducedJoint::insert(
            b.world,
            root,
            root_from_joint,
            joint_from_link0,
            vec![(
                ColliderBuilder::cuboid(KNOB_LONG_HALF_X, KNOB_HALF.y, KNOB_HALF.z),
                // Toward the robot from the body's origin, which stays where it was.
                Isometry3::translation(KNOB_LONG_HALF_X - KNOB_HALF.x, 0.0, 0.0),
            )],
            0.2,
            &SPEC,
        ) else {
            return Err(TwinError::Config(
                "push-slider: the slider joint closes a loop".to_owned(),
            ));
        };
        // The fingers close around the knob and carry it (their drives alone would yield
        // to the rail's friction).
        b.graspable.push(slider.link);
        self.wall = Some(wall);
        self.slider = Some(slider);
        Ok(())
    }

    fn after_step(&mut self, world: &mut PhysicsWorld, _view: &View) -> TaskStatus {
        let q = self.position(world);
        let pushed = q >= PUSHED_M;
        TaskStatus {
            success: pushed,
            criteria: vec![q - INITIAL_M >= ENGAGED_M, pushed],
        }
    }

    fn observation(&self, world: &PhysicsWorld) -> TaskObservation {
        let mut o = TaskObservation::default();
        let q = self.position(world);
        o.push(keys::SLIDER_POS, [q]);
        o.push(keys::SLIDER_PUSHED, [f64::from(u8::from(q >= PUSHED_M))]);
        if let Some(s) = &self.slider {
            o.push_vec3(
                keys::SLIDER_BODY_POS,
                &s.link_pose(world).translation.vector,
            );
        }
        o
    }

    fn wall(&self) -> Option<Isometry3<f64>> {
        self.wall.map(|w| w.pose)
    }

    fn obstacle_face_x(&self, _world: &PhysicsWorld) -> Option<f64> {
        self.wall.map(|w| w.face_x())
    }
}

impl PushSlider {
    /// Whether the point `p` (world) lies inside the knob's collider (tests).
    #[cfg(test)]
    pub(crate) fn knob_contains(&self, world: &PhysicsWorld, p: &Vector3<f64>) -> bool {
        let Some(s) = &self.slider else { return false };
        world.bodies.get(s.link).is_some_and(|rb| {
            rb.colliders().iter().any(|h| {
                world.colliders.get(*h).is_some_and(|c| {
                    // From the body's pose (a collider's own pose is synced on a step).
                    let pose = c
                        .position_wrt_parent()
                        .map_or(*rb.position(), |local| *rb.position() * *local);
                    c.shape()
                        .contains_point(&pose, crate::convert::vector_to_rapier(p))
                })
            })
        })
    }

    /// Puts the knob at `q` (tests).
    #[cfg(test)]
    pub(crate) fn set_slider(&self, world: &mut PhysicsWorld, q: f64) {
        if let Some(s) = &self.slider {
            s.set_position(world, q);
        }
    }

    fn position(&self, world: &PhysicsWorld) -> f64 {
        self.slider
            .as_ref()
            .map_or(INITIAL_M, |s| s.position(world))
    }
}
