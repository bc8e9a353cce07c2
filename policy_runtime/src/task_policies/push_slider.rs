//! Push Slider (AMBENCH_SPEC §4.9): approach the knob along the wall normal with the gripper
//! open and wall-aligned, close on it, then carry it 1 m along −w_y.

use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, WallFrame, identity, uniform, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Stand-off of the start pose from the knob along the normal, m.
const OFFSET_M: f64 = 0.23;
/// Waypoint times of the default script (env steps).
const TIMES: [u64; 6] = [300, 600, 800, 820, 840, 1440];

pub(crate) fn policy(ctx: &PolicyContext, rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let wall = WallFrame::of(ctx)?;
    let slider = ctx.task.vec3(keys::SLIDER_BODY_POS, 0)?;
    let start = slider - wall.n * OFFSET_M;
    let approach = start - wall.n * uniform(rng, 0.3, 0.5);
    let wp1 = ctx.init + uniform(rng, 0.2, 0.5) * (approach - ctx.init);
    let end = start - wall.w_y * 1.0;
    let q = wall.aligned();
    let [t0, t1, t2, t3, t4, t5] = TIMES;
    WaypointPolicy::new(vec![
        wp(0, ctx.init, identity(), 1.0),
        wp(t0, wp1, identity(), 1.0),
        wp(t1, approach, q, 1.0),
        wp(t2, start, q, 1.0),
        wp(t3, start, q, 1.0),
        wp(t4, start, q, -1.0),
        wp(t5, end, q, -1.0),
    ])
}
