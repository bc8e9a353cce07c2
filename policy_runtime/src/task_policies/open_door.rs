//! Open Door (AMBENCH_SPEC §4.6): with the gripper closed and an identity orientation, touch
//! the leaf 0.25 m left of the door root at 1.2 m, push it 0.4 m forward and 0.4 m toward the
//! hinge, fly through the opening, step aside from the leaf and leave diagonally.

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, identity, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

pub(crate) fn policy(ctx: &PolicyContext, _rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let door = ctx.task.vec3(keys::DOOR_POS, 0)?;
    let reference = door + Vector3::new(0.0, -0.25, 1.2);
    let contact = reference - Vector3::new(0.15, 0.0, 0.0);
    let push = reference + Vector3::new(0.4, 0.4, 0.0);
    let through = push + Vector3::new(0.2, 0.0, 0.0);
    let avoid = through - Vector3::new(0.0, 0.3, 0.0);
    let forward = avoid + Vector3::new(0.3, 0.0, 0.0);
    let diagonal = forward + Vector3::new(0.8, -0.8, 0.0);
    let last = diagonal + Vector3::new(1.3, 0.0, 0.0);
    let q = identity();
    let g = -1.0;
    WaypointPolicy::new(vec![
        wp(0, ctx.init, q, g),
        wp(300, contact, q, g),
        wp(500, push, q, g),
        wp(700, through, q, g),
        wp(850, avoid, q, g),
        wp(1000, forward, q, g),
        wp(1200, diagonal, q, g),
        wp(1250, last, q, g),
    ])
}
