//! NDT inspection (AMBENCH_SPEC §4.5): the Press Button script aimed at the inspection point
//! 7 m up: part of the way toward the approach pose, the approach pose 0.3–0.5 m in front of
//! the goal along the wall normal (x̂, the wall being moved out of the way), then the goal
//! 1 cm lower. Identity orientations; the gripper closes on the way to the approach.

use rand_chacha::ChaCha8Rng;

use super::PolicyContext;
use crate::scripted::WaypointPolicy;

/// The Press Button script (same times, offsets and waypoints) toward this task's `goal_pos`.
pub(crate) fn policy(ctx: &PolicyContext, rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    super::press_button::policy(ctx, rng)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Vector3};
    use rand::SeedableRng;
    use sim_twin::TaskObservation;

    use super::*;

    #[test]
    fn the_script_ends_one_centimetre_below_the_goal_after_an_approach_in_front() {
        let goal = Vector3::new(1.77, 0.0, 7.0);
        let mut task = TaskObservation::default();
        task.push_vec3("goal_pos", &goal);
        let ctx = PolicyContext {
            init: Vector3::new(0.0, 0.0, 1.0),
            task,
            wall: Some(Isometry3::translation(2.0, -10.0, 1.0)),
        };
        for seed in 0..10 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let p = policy(&ctx, &mut rng).unwrap_or_else(|e| panic!("{e}"));
            let w = p.waypoints();
            let back = goal.x - w[2].position.x;
            assert!((0.3..0.5).contains(&back) && w[2].position.z == 7.0);
            assert!((w[3].position - Vector3::new(1.77, 0.0, 6.99)).norm() < 1e-12);
            assert_eq!(
                (w[1].gripper, w[2].gripper, w[3].gripper),
                (1.0, -1.0, -1.0)
            );
        }
    }
}
