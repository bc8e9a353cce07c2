//! Lemon Harvesting (AMBENCH_SPEC §4.4, the default script of the -v0 IDs): fly to a point
//! in front of the lemon, come in just above its centre, close, pull it off the wall and
//! away, tilt the gripper 0.3 rad nose down, carry the lemon over the container and let go.

use nalgebra::{UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, identity, uniform, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Pitch of the carrying orientation, rad.
const TILT_RAD: f64 = 0.30;

pub(crate) fn policy(ctx: &PolicyContext, rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let l = ctx.task.vec3(keys::LEMON_POS, 0)?;
    let k = ctx.task.vec3(keys::CONTAINER_POS, 0)?;
    let fly = l + Vector3::new(
        -uniform(rng, 0.25, 0.35),
        uniform(rng, -0.05, 0.05),
        uniform(rng, -0.05, 0.05),
    );
    let hover_rand = l + Vector3::new(
        -0.17 + uniform(rng, 0.0, 0.01),
        uniform(rng, -0.01, 0.01),
        uniform(rng, 0.025, 0.045),
    );
    let hover = l + Vector3::new(-0.17, uniform(rng, -0.005, 0.005), uniform(rng, 0.03, 0.04));
    let pull = hover - Vector3::new(0.50, 0.0, 0.0);
    let pull_far = Vector3::new(
        pull.x - uniform(rng, 0.40, 0.50),
        uniform(rng, 0.0, 0.30),
        uniform(rng, 0.70, 0.80) * pull.z,
    );
    let tilt = UnitQuaternion::from_euler_angles(0.0, TILT_RAD, 0.0);
    let align = Vector3::new(
        pull_far.x + uniform(rng, 0.30, 0.60) * (k.x - pull_far.x),
        k.y,
        k.z + uniform(rng, 0.30, 0.33),
    );
    let above = Vector3::new(k.x - 0.20, k.y, align.z);
    let i = identity();
    WaypointPolicy::new(vec![
        wp(0, ctx.init, i, 1.0),
        wp(400, fly, i, 1.0),
        wp(550, hover_rand, i, 1.0),
        wp(600, hover, i, 1.0),
        wp(650, hover, i, -1.0),
        wp(1200, pull_far, i, -1.0),
        wp(1250, pull_far, tilt, -1.0),
        wp(1470, align, tilt, -1.0),
        wp(1570, above, tilt, -1.0),
        wp(1620, above, tilt, 1.0),
        wp(1660, above, tilt, 1.0),
    ])
}
