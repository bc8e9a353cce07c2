//! Push Slider (AMBENCH_SPEC §4.9): a knob on a rail along a randomised wall, pushed from
//! q = −0.5 m to 0.45 m.
//!
//! [U] choices (the reference keeps the slider only as a USD asset): the rail is a fixed bar
//! 1.1 m long, 0.02 m deep and 0.04 m high on the wall face; the knob ("Slider" body) is a
//! round bar 0.03 m across standing out from the rail along the wall's normal to 0.28 m off
//! the wall face, mass 0.2 kg, its body's origin on its axis 0.10 m off the wall face (the
//! point the script aims at: the EE link stops 0.23 m in front of it); the joint is limited
//! to [−0.5, 0.5] m. The root is the wall frame turned 180° about z, so the joint's positive
//! direction is −w_y (the scripted push direction).
//!
//! The knob reaches 0.28 m (it reached 0.18 m, a bar 0.16 m long centred on the origin):
//! the scripts aim every vehicle's EE link at the same point (AMBENCH_SPEC §4.0), and the
//! tools reach 0.18 m (FA-Hexa, UA-Hexa), 0.075 m (UA-Quad) and 0.0445 m (Omni-Hexa) ahead
//! of it, so the UA-Quad's and the Omni-Hexa's tips stopped 0.075 m and 0.105 m short of the
//! 0.18 m knob, where the paper's embodiment table has every vehicle push it. A knob they
//! reach puts the FA-Hexa's palm (0.08 m ahead of its EE link, 0.25 m off the wall face)
//! against its end, 0.03 m short of its target: the paper's FA-Hexa saturates its rotors on
//! 39.5 % of Push Slider's steps (embodiment table), which such a press explains (the twin's
//! FA-Hexa IK-PID: 0.3 % with the short knob, 42.9 % now); 0.28 m is the least that gives
//! the UA-Quad's pads (0.04 m long, to its tip at 0.255 m off the wall face) their whole
//! length on the knob. Measured (seed 0, `amstack bench --platform P [--controller C]
//! --task push-slider --rollouts N`; 10 rollouts for the other vehicles, 30 for the FA-Hexa
//! and the oracle): Omni-Hexa 0 → 100 % and UA-Quad, with its pads reaching down across its
//! EE link's axis (`ua-quad.urdf`), 0 → 100 %; the FA-Hexa's whole-body MPC 100 → 0 % (10
//! rollouts) until it kept its target off what the palm presses
//! (`MpcConfig::contact_reference`), then 100 %; the FA-Hexa IK-PID, IK-L1, the UA-Hexa and
//! the EE-only oracle 100 % before and after.
//!
//! The knob is round (a departure from this module's earlier box, 0.03 × 0.16 × 0.08 m; the
//! reference's shape is not known): the twin's grasp lets a round bar turn in the fingers
//! about its axis (`objects::Grasp`), so a hand holding the knob may roll about the wall's
//! normal — which an under-actuated vehicle must do to push along the rail (its thrust tilts
//! toward the push). Welded to a box knob, the UA-Hexa's roll fought the grasp and, under the
//! reference's rotor limits, it pushed the knob 0.16 m of the 0.95 m in 0 of 10 rollouts;
//! with the round knob 10 of 10 (tilt 9.9°, the paper's embodiment table 0.143 rad). The
//! knob keeps the box's 0.03 m along the rail, so the fingers close on the same width.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::{
    Dof, DriveType, JointSpec, ReducedJoint, Wall, attach, fixed_body, symmetric,
};
use super::{Build, HeldJoint, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::error::TwinError;

/// Slider position at which it counts as pushed, m.
pub(crate) const PUSHED_M: f64 = 0.45;
/// Slider position at reset, m.
pub(crate) const INITIAL_M: f64 = -0.5;
/// Engagement: 5 % of the way from the start to the goal.
pub(crate) const ENGAGED_M: f64 = 0.05 * (PUSHED_M - INITIAL_M);

const RAIL_DEPTH_M: f64 = 0.02;
/// The knob body's origin ("Slider", the point the script aims at) off the rail, m.
const KNOB_ORIGIN_OUT_M: f64 = 0.08;
/// How far the knob reaches off the wall face, m.
pub(crate) const KNOB_REACH_M: f64 = 0.28;
/// The knob's end beyond its body's origin, along its axis, m.
#[cfg(test)]
pub(crate) const KNOB_END_FROM_ORIGIN_M: f64 = KNOB_REACH_M - RAIL_DEPTH_M - KNOB_ORIGIN_OUT_M;
/// Half the knob's length out from the rail, m.
const KNOB_HALF_LENGTH_M: f64 = (KNOB_REACH_M - RAIL_DEPTH_M) / 2.0;
/// The knob's radius, m (0.03 m across, along the rail as across it).
pub(crate) const KNOB_RADIUS_M: f64 = 0.015;

const SPEC: JointSpec = JointSpec {
    dof: Dof::Prismatic,
    limits: Some((-0.5, 0.5)),
    stiffness: 0.0,
    damping: 5.0,
    target: 0.0,
    effort: 1000.0,
    friction: 4.0,
    initial: INITIAL_M,
    drive: DriveType::Force,
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
        let out = RAIL_DEPTH_M + KNOB_ORIGIN_OUT_M;
        let joint_from_link0 = Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, -out, 0.0),
            root_from_joint.rotation.inverse(),
        );
        let Some((slider, _)) = ReducedJoint::insert(
            b.world,
            root,
            root_from_joint,
            joint_from_link0,
            // rapier's cylinders stand along their local y; the knob's axis is the link's x
            // (out of the wall).
            vec![(
                ColliderBuilder::cylinder(KNOB_HALF_LENGTH_M, KNOB_RADIUS_M),
                Isometry3::from_parts(
                    nalgebra::Translation3::new(RAIL_DEPTH_M + KNOB_HALF_LENGTH_M - out, 0.0, 0.0),
                    UnitQuaternion::from_axis_angle(
                        &Vector3::z_axis(),
                        -std::f64::consts::FRAC_PI_2,
                    ),
                ),
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

    fn held_joint(&self, world: &PhysicsWorld, object: RigidBodyHandle) -> Option<HeldJoint> {
        let slider = self.slider.as_ref().filter(|s| s.link == object)?;
        Some(slider.motion(world))
    }
}

impl PushSlider {
    /// Puts the knob at `q` (tests).
    #[cfg(test)]
    pub(crate) fn set_slider(&self, world: &mut PhysicsWorld, q: f64) {
        if let Some(s) = &self.slider {
            s.set_position(world, q);
        }
    }

    /// The knob's body (tests).
    #[cfg(test)]
    pub(crate) fn knob(&self) -> Option<RigidBodyHandle> {
        self.slider.as_ref().map(|s| s.link)
    }

    fn position(&self, world: &PhysicsWorld) -> f64 {
        self.slider
            .as_ref()
            .map_or(INITIAL_M, |s| s.position(world))
    }
}
