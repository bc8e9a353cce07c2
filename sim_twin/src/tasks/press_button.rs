//! Press Button (AMBENCH_SPEC §4.7): a spring-loaded plunger on a randomised wall.
//!
//! [U] choices (the reference keeps the button only as a USD asset): the plunger is a
//! cylinder of radius 0.06·s (s ~ U(0.5, 1.0), the spec's (1, s, s) scale) and length 0.03 m,
//! mass 0.05 kg, on a prismatic joint along the wall's x (into the wall) from 0 (out) to
//! 0.01 m (fully pressed); at 0 its front face stands 0.04 m off the wall face. The joint
//! frame sits on the wall face at the button centre (wall-local x = −0.05). The scale is drawn
//! per rollout (the reference draws it once per environment at start-up).

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::{
    Dof, DriveType, JointSpec, ReducedJoint, Wall, fixed_body, symmetric, uniform,
};
use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::error::TwinError;

/// Plunger travel at which the button counts as pressed, m.
pub(crate) const PRESSED_M: f64 = 0.004;
/// Plunger length, m.
const PLUNGER_LENGTH_M: f64 = 0.03;
/// Nominal plunger radius, m.
const RADIUS_M: f64 = 0.06;

const SPEC: JointSpec = JointSpec {
    dof: Dof::Prismatic,
    limits: Some((0.0, 0.01)),
    stiffness: 1000.0,
    damping: 80.0,
    target: 0.0,
    effort: 20.0,
    friction: 0.0,
    initial: 0.0,
    drive: DriveType::Force,
};

#[derive(Debug, Default)]
pub(crate) struct PressButton {
    wall: Option<Wall>,
    plunger: Option<ReducedJoint>,
}

impl Scene for PressButton {
    fn task(&self) -> TaskId {
        TaskId::PressButton
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &[]
    }

    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError> {
        let wall = Wall::randomized(b.rng, 0.2, 0.2, 0.2);
        wall.insert(b.world);
        let y = symmetric(b.rng, 0.3);
        let z = symmetric(b.rng, 0.3);
        let scale = uniform(b.rng, 0.5, 1.0);
        let root = fixed_body(
            b.world,
            &wall.frame(
                Vector3::new(-Wall::HALF.x, y, z),
                UnitQuaternion::identity(),
            ),
        );
        // The cylinder's own axis is y: turn it onto x.
        let shape = ColliderBuilder::cylinder(PLUNGER_LENGTH_M / 2.0, RADIUS_M * scale);
        let along_x = Isometry3::rotation(Vector3::z() * std::f64::consts::FRAC_PI_2);
        let Some((plunger, _)) = ReducedJoint::insert(
            b.world,
            root,
            Isometry3::identity(),
            Isometry3::translation(-0.01 - PLUNGER_LENGTH_M / 2.0, 0.0, 0.0),
            vec![(shape, along_x)],
            0.05,
            &SPEC,
        ) else {
            return Err(TwinError::Config(
                "press-button: the plunger joint closes a loop".to_owned(),
            ));
        };
        self.wall = Some(wall);
        self.plunger = Some(plunger);
        Ok(())
    }

    fn after_step(&mut self, world: &mut PhysicsWorld, _view: &View) -> TaskStatus {
        TaskStatus {
            success: self.pressed(world),
            criteria: Vec::new(),
        }
    }

    fn observation(&self, world: &PhysicsWorld) -> TaskObservation {
        let mut o = TaskObservation::default();
        o.push(
            keys::BUTTON_PRESSED,
            [f64::from(u8::from(self.pressed(world)))],
        );
        if let Some(p) = &self.plunger {
            o.push_vec3(keys::GOAL_POS, &p.link_pose(world).translation.vector);
            o.push(keys::PLUNGER_POS, [p.position(world)]);
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

impl PressButton {
    /// Puts the plunger at `q` (tests).
    #[cfg(test)]
    pub(crate) fn set_plunger(&self, world: &mut PhysicsWorld, q: f64) {
        if let Some(p) = &self.plunger {
            p.set_position(world, q);
        }
    }

    fn pressed(&self, world: &PhysicsWorld) -> bool {
        self.plunger
            .as_ref()
            .is_some_and(|p| p.position(world) >= PRESSED_M)
    }
}
