//! Wipe Window (AMBENCH_SPEC §4.12): from a stand-off pose low in front of the robot, visit
//! the visible stains in (z, y) order; for each, come in from 0.40 m in front, close to
//! 0.25 m, press the sponge on (end effector 0.215 m in front of the stain, 1 cm to its
//! left), hold, wipe 4 cm to the right, hold, and back off. Identity orientations; the
//! gripper stays closed (the runner forces −0.6). The script is 200 + 860 steps per stain:
//! within the 20 s episode it reaches the third stain; stains within the sponge's reach of
//! a visited one go with it.

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, identity, wp};
use crate::scripted::{Waypoint, WaypointPolicy};
use sim_twin::tasks::keys;

/// The first stand-off pose (world).
const START: Vector3<f64> = Vector3::new(0.0, 0.0, 0.7);
/// Time of the first stand-off pose (env steps).
const T_START: u64 = 100;
/// Segment durations per stain: aim, forward, contact, pause, sweep, pause, retreat.
const AIM: u64 = 100;
const FORWARD: u64 = 300;
const CONTACT: u64 = 100;
const PAUSE: u64 = 40;
const SWEEP: u64 = 180;
const RETREAT: u64 = 100;
/// Stand-off of the far pose in front of a stain, m.
const HOVER_M: f64 = 0.40;

pub(crate) fn policy(ctx: &PolicyContext, _rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let positions = ctx.task.get(keys::STAIN_POS)?;
    let visible = ctx.task.get(keys::STAIN_VISIBLE)?;
    let mut stains: Vec<Vector3<f64>> = visible
        .iter()
        .enumerate()
        .filter(|(_, v)| **v > 0.5)
        .map(|(i, _)| ctx.task.vec3(keys::STAIN_POS, i))
        .collect::<Result<_, _>>()?;
    if positions.len() < 3 * visible.len() {
        return Err("stain_pos has fewer positions than stain_visible".to_owned());
    }
    let mut waypoints: Vec<Waypoint> = vec![wp(0, ctx.init, identity(), -1.0)];
    if stains.is_empty() {
        return WaypointPolicy::new(waypoints);
    }
    stains.sort_by(|a, b| a.z.total_cmp(&b.z).then(a.y.total_cmp(&b.y)));
    waypoints.push(wp(T_START, START, identity(), -1.0));
    let mut t = T_START;
    for d in &stains {
        let far = Vector3::new(d.x - HOVER_M, d.y, d.z - 0.1);
        let close = Vector3::new(d.x - 0.25, d.y + 0.01, d.z);
        let contact = Vector3::new(d.x - 0.215, close.y, close.z);
        let sweep = contact - Vector3::new(0.0, 0.04, 0.0);
        for (dt, p) in [
            (AIM, far),
            (FORWARD, close),
            (CONTACT, contact),
            (PAUSE, contact),
            (SWEEP, sweep),
            (PAUSE, sweep),
            (RETREAT, far),
        ] {
            t += dt;
            waypoints.push(wp(t, p, identity(), -1.0));
        }
    }
    WaypointPolicy::new(waypoints)
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use sim_twin::TaskObservation;

    use super::*;

    fn context(visible: [f64; 4]) -> PolicyContext {
        let mut task = TaskObservation::default();
        let stains = [
            Vector3::new(2.015, 0.05, 1.08),
            Vector3::new(2.015, -0.02, 0.95),
            Vector3::new(2.015, 0.08, 0.95),
            Vector3::new(2.015, 0.0, 1.01),
        ];
        task.push("stain_pos", stains.iter().flat_map(|s| s.iter().copied()));
        task.push("stain_visible", visible);
        PolicyContext {
            init: Vector3::new(0.0, 0.0, 1.0),
            task,
            wall: None,
        }
    }

    #[test]
    fn visible_stains_are_visited_by_height_then_across() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let p = policy(&context([1.0, 1.0, 1.0, 0.0]), &mut rng).unwrap_or_else(|e| panic!("{e}"));
        let w = p.waypoints();
        // Start, stand-off, then seven waypoints per visible stain.
        assert_eq!(w.len(), 2 + 3 * 7);
        assert_eq!(p.end_tick(), T_START + 3 * 860);
        // Contact poses (third of each stain's seven): z ascending, then y ascending.
        let contacts: Vec<Vector3<f64>> = (0..3).map(|k| w[2 + 7 * k + 2].position).collect();
        assert!((contacts[0] - Vector3::new(2.015 - 0.215, -0.01, 0.95)).norm() < 1e-12);
        assert!((contacts[1] - Vector3::new(2.015 - 0.215, 0.09, 0.95)).norm() < 1e-12);
        assert!((contacts[2] - Vector3::new(2.015 - 0.215, 0.06, 1.08)).norm() < 1e-12);
        // The wipe: 4 cm toward −y, then back to the far pose 0.40 m off and 0.1 m lower.
        assert!((w[2 + 4].position - contacts[0] + Vector3::new(0.0, 0.04, 0.0)).norm() < 1e-12);
        assert!((w[2 + 6].position - Vector3::new(2.015 - 0.40, -0.02, 0.85)).norm() < 1e-12);
        assert!(w.iter().all(|w| w.gripper == -1.0));
    }

    #[test]
    fn with_nothing_to_wipe_the_script_holds_still() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let p = policy(&context([0.0; 4]), &mut rng).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(p.waypoints().len(), 1);
    }
}
