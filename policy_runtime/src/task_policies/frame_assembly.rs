//! Frame Assembly (AMBENCH_SPEC §4.3): take the standing frame by its top, lift it, carry it
//! in front of the pegs and push it over them, then let go and back off. Identity
//! orientations throughout; no random offsets.

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, identity, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Half the frame's height, m.
const HALF_HEIGHT_M: f64 = 0.25;

pub(crate) fn policy(ctx: &PolicyContext, _rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let f = ctx.task.vec3(keys::FRAME_POS, 0)?;
    let p = ctx.task.vec3(keys::PEG_CENTER_POS, 0)?;
    let hover = f + Vector3::new(-0.60, 0.0, 0.22);
    let grasp_approach = f + Vector3::new(-0.25, 0.0, 0.22);
    let grasp = f + Vector3::new(-0.16, 0.0, 0.22);
    let lift = grasp + Vector3::new(0.0, 0.0, 0.20);
    let lift_far = Vector3::new(1.0, 0.0, 1.0);
    let aim_z = p.z + HALF_HEIGHT_M - 0.02;
    let approach_far = Vector3::new(p.x - 0.8, p.y, aim_z);
    let approach_wall = Vector3::new(p.x - 0.45, p.y, aim_z);
    let insert = Vector3::new(p.x - 0.22, p.y, aim_z);
    let retract = Vector3::new(p.x - 0.60, p.y, aim_z);
    let q = identity();
    WaypointPolicy::new(vec![
        wp(0, ctx.init, q, 1.0),
        wp(450, hover, q, 1.0),
        wp(750, grasp_approach, q, 1.0),
        wp(900, grasp, q, 1.0),
        wp(950, grasp, q, -1.0),
        wp(1000, grasp, q, -1.0),
        wp(1100, lift, q, -1.0),
        wp(1700, lift_far, q, -1.0),
        wp(2400, approach_far, q, -1.0),
        wp(2700, approach_wall, q, -1.0),
        wp(2750, approach_wall, q, -1.0),
        wp(3100, insert, q, -1.0),
        wp(3200, insert, q, 1.0),
        wp(3400, retract, q, 1.0),
    ])
}
