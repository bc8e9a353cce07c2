//! Press Button (AMBENCH_SPEC §4.7): approach the button along the wall normal, close the
//! gripper, press 1 cm below the plunger centre. Identity orientations (not wall-aligned).

use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, WallFrame, identity, uniform, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Waypoint times of the default script (env steps).
const TIMES: (u64, u64, u64) = (200, 800, 1200);

pub(crate) fn policy(ctx: &PolicyContext, rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let wall = WallFrame::of(ctx)?;
    let goal = ctx.task.vec3(keys::GOAL_POS, 0)?;
    let approach = goal - wall.n * uniform(rng, 0.3, 0.5);
    let press = goal + nalgebra::Vector3::new(0.0, 0.0, -0.01);
    let wp1 = ctx.init + uniform(rng, 0.2, 0.5) * (approach - ctx.init);
    let (t0, t1, t2) = TIMES;
    WaypointPolicy::new(vec![
        wp(0, ctx.init, identity(), 1.0),
        wp(t0, wp1, identity(), 1.0),
        wp(t1, approach, identity(), -1.0),
        wp(t2, press, identity(), -1.0),
    ])
}
