//! NDT inspection (AMBENCH_SPEC §4.5): hold the end-effector link at an inspection point
//! 7 m up for 100 consecutive env steps.
//!
//! The reference's warehouse background and its marker are visual only and are left out
//! (nothing collides with them). The default wall stands moved out of the way at
//! (2.0, −10.0, 1.0), unrotated: it only gives the IK's obstacle limit and the scripted
//! normal (x̂). No domain randomisation. [U] none: the goal and tolerances are the spec's.
//!
//! Criteria: `inspection_target_held` (the success itself, as the reference reports it).

use nalgebra::{Isometry3, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::Wall;
use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::error::TwinError;

/// The inspection point (z = inspection height 7.0 m).
pub(crate) const GOAL: Vector3<f64> = Vector3::new(1.77, 0.0, 7.0);
/// Where the wall stands (out of the way).
pub(crate) const WALL_CENTER: Vector3<f64> = Vector3::new(2.0, -10.0, 1.0);
/// |ee.x − goal.x| must stay below this, m.
pub(crate) const X_TOLERANCE_M: f64 = 0.03;
/// ‖ee.yz − goal.yz‖ must stay below this, m.
pub(crate) const YZ_TOLERANCE_M: f64 = 0.08;
/// Consecutive steps inside the tolerance that make a success.
pub(crate) const HOLD_STEPS: u32 = 100;

#[derive(Debug, Default)]
pub(crate) struct Ndt {
    wall: Option<Wall>,
    /// Consecutive steps with the end effector at the inspection point.
    counter: u32,
}

impl Scene for Ndt {
    fn task(&self) -> TaskId {
        TaskId::Ndt
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &["inspection_target_held"]
    }

    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError> {
        let wall = Wall::at(WALL_CENTER);
        wall.insert(b.world);
        self.wall = Some(wall);
        self.counter = 0;
        Ok(())
    }

    fn after_step(&mut self, _world: &mut PhysicsWorld, view: &View) -> TaskStatus {
        let ee = view.world_from_ee.translation.vector;
        if at_goal(&ee) {
            self.counter += 1;
        } else {
            self.counter = 0;
        }
        let held = self.counter >= HOLD_STEPS;
        TaskStatus {
            success: held,
            criteria: vec![held],
        }
    }

    fn observation(&self, _world: &PhysicsWorld) -> TaskObservation {
        let mut o = TaskObservation::default();
        o.push_vec3(keys::GOAL_POS, &GOAL);
        o
    }

    fn wall(&self) -> Option<Isometry3<f64>> {
        self.wall.map(|w| w.pose)
    }

    fn obstacle_face_x(&self, _world: &PhysicsWorld) -> Option<f64> {
        self.wall.map(|w| w.face_x())
    }
}

/// The reference's instantaneous condition on the end-effector link origin.
fn at_goal(ee: &Vector3<f64>) -> bool {
    let yz = ((ee.y - GOAL.y).powi(2) + (ee.z - GOAL.z).powi(2)).sqrt();
    (ee.x - GOAL.x).abs() < X_TOLERANCE_M && yz < YZ_TOLERANCE_M
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(step: u64, ee: Vector3<f64>) -> View {
        crate::tasks::tests::view_of(step, ee + Vector3::new(0.18, 0.0, 0.0), ee, 0.002)
    }

    #[test]
    fn the_tolerances_are_strict_at_their_edges() {
        assert!(at_goal(&GOAL));
        assert!(at_goal(&(GOAL + Vector3::new(0.0299, 0.0, 0.0))));
        assert!(!at_goal(&(GOAL + Vector3::new(0.0301, 0.0, 0.0))));
        assert!(!at_goal(&(GOAL - Vector3::new(0.0301, 0.0, 0.0))));
        // The y–z tolerance is a disc: 0.06² + 0.05² > 0.08² although each is below.
        assert!(at_goal(&(GOAL + Vector3::new(0.0, 0.0799, 0.0))));
        assert!(!at_goal(&(GOAL + Vector3::new(0.0, 0.0, -0.0801))));
        assert!(!at_goal(&(GOAL + Vector3::new(0.0, 0.06, 0.055))));
    }

    #[test]
    fn success_needs_one_hundred_consecutive_steps_and_a_slip_restarts_the_count() {
        let mut scene = Ndt::default();
        let mut world = PhysicsWorld::new();
        let mut step = 0;
        let mut tick = |scene: &mut Ndt, ee: Vector3<f64>| {
            step += 1;
            scene.after_step(&mut world, &view(step, ee))
        };
        for _ in 0..99 {
            assert!(!tick(&mut scene, GOAL).success);
        }
        // One step away: the count restarts.
        assert!(!tick(&mut scene, GOAL + Vector3::new(0.05, 0.0, 0.0)).success);
        for _ in 0..99 {
            let s = tick(&mut scene, GOAL);
            assert!(!s.success);
            assert_eq!(s.criteria, vec![false]);
        }
        let s = tick(&mut scene, GOAL);
        assert!(s.success);
        assert_eq!(s.criteria, vec![true]);
    }

    #[test]
    fn the_scene_has_the_moved_wall_and_the_constant_goal() {
        let vehicle = platform::Vehicle::builtin("ee-only").unwrap_or_else(|e| panic!("{e}"));
        let twin = crate::Twin::new(
            vehicle,
            crate::TwinConfig {
                task: Some(TaskId::Ndt),
                seed: 3,
                ..Default::default()
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let wall = twin.task_wall().unwrap_or_else(|| panic!("no wall"));
        assert!((wall.translation.vector - WALL_CENTER).norm() < 1e-12);
        assert!((twin.obstacle_face_x().unwrap_or(0.0) - 1.95).abs() < 1e-12);
        let o = twin.task_observation().unwrap_or_default();
        let goal = o.vec3("goal_pos", 0).unwrap_or_else(|e| panic!("{e}"));
        assert!((goal - Vector3::new(1.77, 0.0, 7.0)).norm() < 1e-12);
    }
}
