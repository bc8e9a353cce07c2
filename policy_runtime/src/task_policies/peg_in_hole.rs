//! Peg-in-Hole (AMBENCH_SPEC §4.1): carry the held peg part of the way toward an approach
//! pose 0.40–0.60 m in front of the hole along the wall normal, turn wall-aligned on the way
//! there, then push straight in until the peg tip reaches the hole's centre.
//!
//! The peg tip's lead over the end-effector link along the normal is the peg centre's
//! offset at reset, (peg − init)·n (clamped at 0), plus half the peg length: the end
//! effector stops that far in front of the hole (the reference reads the peg position from
//! the scene: the `peg_pos` observation here).

use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, WallFrame, identity, uniform, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Half the peg length, m (AMBENCH_SPEC §4.1: 0.15 m).
const PEG_HALF_LENGTH_M: f64 = 0.075;
/// Waypoint times (env steps).
const TIMES: (u64, u64, u64) = (200, 800, 1100);

pub(crate) fn policy(ctx: &PolicyContext, rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let wall = WallFrame::of(ctx)?;
    let goal = ctx.task.vec3(keys::GOAL_POS, 0)?;
    let peg = ctx.task.vec3(keys::PEG_POS, 0)?;
    let approach = goal - wall.n * uniform(rng, 0.40, 0.60);
    let wp1 = ctx.init + uniform(rng, 0.2, 0.4) * (approach - ctx.init);
    let tip_offset = (peg - ctx.init).dot(&wall.n).max(0.0) + PEG_HALF_LENGTH_M;
    let insert = goal - wall.n * tip_offset;
    let q = wall.aligned();
    let (t0, t1, t2) = TIMES;
    WaypointPolicy::new(vec![
        wp(0, ctx.init, identity(), -1.0),
        wp(t0, wp1, identity(), -1.0),
        wp(t1, approach, q, -1.0),
        wp(t2, insert, q, -1.0),
    ])
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, UnitQuaternion, Vector3};
    use rand::SeedableRng;
    use sim_twin::TaskObservation;

    use super::*;

    #[test]
    fn the_insert_pose_brings_the_peg_tip_to_the_hole_centre() {
        let goal = Vector3::new(1.93, 0.1, 1.2);
        let init = Vector3::new(0.0, 0.0, 1.0);
        for pitch in [-0.5, 0.0, 0.3] {
            let wall = UnitQuaternion::from_euler_angles(0.0, pitch, 0.0);
            let mut task = TaskObservation::default();
            task.push_vec3("goal_pos", &goal);
            task.push_vec3("peg_pos", &(init + Vector3::new(0.18, 0.0, 0.0)));
            let ctx = PolicyContext {
                init,
                task,
                wall: Some(Isometry3::from_parts(
                    Vector3::new(2.0, 0.0, 1.0).into(),
                    wall,
                )),
            };
            let mut rng = ChaCha8Rng::seed_from_u64(1);
            let p = policy(&ctx, &mut rng).unwrap_or_else(|e| panic!("{e}"));
            let w = p.waypoints();
            assert_eq!(
                w.iter().map(|w| w.tick).collect::<Vec<_>>(),
                vec![0, 200, 800, 1100]
            );
            let n = wall * Vector3::x();
            // Approach 0.40–0.60 m in front of the hole along the normal.
            let back = (goal - w[2].position).dot(&n);
            assert!(
                (0.40..0.60).contains(&back) && (goal - w[2].position - n * back).norm() < 1e-12
            );
            // At the last pose, wall-aligned, the tip (0.18 + 0.075 ahead of the link) sits
            // 0.18·(1 − cos pitch) past the hole centre along the normal.
            let tip = w[3].position + w[3].orientation * Vector3::new(0.255, 0.0, 0.0);
            let past = 0.18 * (1.0 - pitch.cos());
            assert!((tip - goal - n * past).norm() < 1e-12, "{tip:?}");
            assert!(w.iter().all(|w| w.gripper == -1.0));
        }
    }
}
