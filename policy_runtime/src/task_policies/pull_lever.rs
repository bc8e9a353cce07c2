//! Pull Lever (AMBENCH_SPEC §4.8): with the gripper rolled 90° (fingers closing vertically),
//! approach the lever's arm 0.25 m in front of its root, close on it, pull it up 0.25 m (and
//! 0.06 m toward the wall), let go and back away.

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, quat_wxyz, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

pub(crate) fn policy(ctx: &PolicyContext, _rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let lever = ctx.task.vec3(keys::LEVER_POS, 0)?;
    let handle = lever + Vector3::new(-0.25, 0.04, 0.0);
    let approach = handle - Vector3::new(0.50, 0.0, 0.0);
    let grasp = handle - Vector3::new(0.08, 0.0, 0.0);
    let pull = handle + Vector3::new(0.06, 0.0, 0.25);
    let retract = pull - Vector3::new(0.65, 0.0, 0.0);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let roll90 = quat_wxyz(h, h, 0.0, 0.0);
    WaypointPolicy::new(vec![
        wp(0, ctx.init, roll90, 1.0),
        wp(500, approach, roll90, 1.0),
        wp(750, grasp, roll90, 1.0),
        wp(780, grasp, roll90, -1.0),
        wp(800, grasp, roll90, -1.0),
        wp(1000, pull, roll90, -1.0),
        wp(1050, pull, roll90, -1.0),
        wp(1080, pull, roll90, 1.0),
        wp(1100, pull, roll90, 1.0),
        wp(1400, retract, roll90, 1.0),
    ])
}
