//! Cabinet Pick-and-Place (AMBENCH_SPEC §4.2): grasp the sliding door's handle and pull the
//! door 0.62 m to the side, let go and back off, reach in for the can, carry it out, up over
//! the cabinet and put it down on the top. Identity orientations; no random offsets.

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, identity, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

pub(crate) fn policy(ctx: &PolicyContext, _rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let d = ctx.task.vec3(keys::PULLING_DOOR_POS, 0)?;
    let c = ctx.task.vec3(keys::CAN_POS, 0)?;
    let door_approach = Vector3::new(d.x - 0.58, d.y + 0.5, d.z + 0.2);
    let pull_right = door_approach - Vector3::new(0.0, 0.62, 0.0);
    let retract = pull_right - Vector3::new(0.1, 0.0, 0.0);
    let align_y = Vector3::new(retract.x, c.y, retract.z);
    let can_approach = Vector3::new(c.x - 0.15, c.y, c.z);
    let can_pick = Vector3::new(c.x - 0.15, c.y, c.z - 0.02);
    let lift = can_pick + Vector3::new(0.0, 0.0, 0.01);
    let back = Vector3::new(retract.x, lift.y, lift.z);
    let up = back + Vector3::new(0.0, 0.0, 0.65);
    let place = Vector3::new(can_pick.x, can_pick.y, up.z);
    let last = place - Vector3::new(0.0, 0.0, 0.05);
    let q = identity();
    WaypointPolicy::new(vec![
        wp(0, ctx.init, q, 1.0),
        wp(400, door_approach, q, 1.0),
        wp(500, door_approach, q, -1.0),
        wp(1150, pull_right, q, -1.0),
        wp(1200, pull_right, q, 1.0),
        wp(1300, retract, q, 1.0),
        wp(1450, align_y, q, 1.0),
        wp(1600, can_approach, q, 1.0),
        wp(1850, can_pick, q, 1.0),
        wp(1900, can_pick, q, -1.0),
        wp(2000, lift, q, -1.0),
        wp(2200, back, q, -1.0),
        wp(2400, up, q, -1.0),
        wp(2600, place, q, -1.0),
        wp(2700, last, q, -1.0),
        wp(2800, last, q, 1.0),
        wp(3000, last, q, 1.0),
    ])
}
