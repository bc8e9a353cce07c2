//! Rotate Valve (AMBENCH_SPEC §4.10): approach the handle along the wall normal, close the
//! gripper on it, carry it 324° round a circle of radius 0.12 m in the wall plane, move to
//! the top of the circle and let go. Identity orientations throughout.
//!
//! The circle segment (ticks 700 to 1300) is not a smootherstep: the position is the
//! (t − 700)-th of 600 points θ_k = linspace(0, 1.8π) on p(θ) = c + r·sinθ·w_y − r·cosθ·w_z,
//! c the midpoint of grasp and end (= grasp + 0.12·w_z), starting at the grasp point. The
//! orientation slerps and the gripper is linear between the segment's waypoints as elsewhere.

use nalgebra::{Isometry3, Translation3, Vector3};
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, TaskPolicy, WallFrame, identity, uniform, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Waypoint times of the default script (env steps): navigate, approach, grasp, arc start,
/// arc end, release.
const TIMES: [u64; 6] = [450, 600, 650, 700, 1300, 1400];
/// Stand-off of the grasp pose from the handle along the normal, m.
const GRASP_OFFSET_M: f64 = 0.18;
/// Distance from the grasp point to the end point along w_z (the circle's diameter), m.
const ARC_LENGTH_M: f64 = 0.24;
/// The circle's sweep, rad.
const SWEEP_RAD: f64 = 1.8 * std::f64::consts::PI;

/// The scripted valve policy: waypoints with one circle segment.
#[derive(Debug, Clone)]
pub(crate) struct RotateValvePolicy {
    waypoints: WaypointPolicy,
    /// Circle points, one per tick of the segment.
    circle: Vec<Vector3<f64>>,
    /// First and last tick of the circle segment (the segment's waypoints).
    start: u64,
    end: u64,
}

/// `n` points of the circle through `from` and `to` (its diameter), swept by `sweep` from
/// `from` in the plane of `w_y`, `w_z`.
fn circle(
    from: Vector3<f64>,
    to: Vector3<f64>,
    sweep: f64,
    n: usize,
    w_y: Vector3<f64>,
    w_z: Vector3<f64>,
) -> Vec<Vector3<f64>> {
    let centre = 0.5 * (from + to);
    let r = 0.5 * (to - from).norm();
    (0..n)
        .map(|k| {
            let theta = if n > 1 {
                sweep * k as f64 / (n - 1) as f64
            } else {
                0.0
            };
            centre + w_y * (r * theta.sin()) - w_z * (r * theta.cos())
        })
        .collect()
}

impl TaskPolicy for RotateValvePolicy {
    fn action(&mut self, step: u64) -> (Isometry3<f64>, f64) {
        let (mut pose, gripper) = self.waypoints.action(step);
        if (self.start..self.end).contains(&step) {
            let k = usize::try_from(step - self.start)
                .unwrap_or(usize::MAX)
                .min(self.circle.len().saturating_sub(1));
            if let Some(p) = self.circle.get(k) {
                pose.translation = Translation3::from(*p);
            }
        }
        (pose, gripper)
    }

    fn end_step(&self) -> u64 {
        self.waypoints.end_tick()
    }
}

pub(crate) fn policy(
    ctx: &PolicyContext,
    rng: &mut ChaCha8Rng,
) -> Result<Box<dyn TaskPolicy>, String> {
    let wall = WallFrame::of(ctx)?;
    let goal = ctx.task.vec3(keys::GOAL_POS, 0)?;
    let approach_offset = uniform(rng, 0.3, 0.5);
    let approach = goal - wall.n * approach_offset;
    let grasp = goal - wall.n * GRASP_OFFSET_M;
    let end = grasp + wall.rotation * Vector3::new(0.0, 0.0, ARC_LENGTH_M);
    let [t_navigate, t_approach, t_grasp, t_start, t_end, t_release] = TIMES;
    let n = usize::try_from(t_end - t_start).map_err(|e| e.to_string())?;
    let q = identity();
    let waypoints = WaypointPolicy::new(vec![
        wp(0, ctx.init, q, 1.0),
        wp(t_navigate, approach, q, 1.0),
        wp(t_approach, grasp, q, 1.0),
        wp(t_grasp, grasp, q, 1.0),
        wp(t_start, grasp, q, -1.0),
        wp(t_end, end, q, -1.0),
        wp(t_release, end, q, 1.0),
    ])?;
    Ok(Box::new(RotateValvePolicy {
        waypoints,
        circle: circle(grasp, end, SWEEP_RAD, n, wall.w_y, wall.w_z),
        start: t_start,
        end: t_end,
    }))
}

#[cfg(test)]
mod tests {
    use nalgebra::Isometry3;
    use sim_twin::TaskObservation;

    use super::*;

    fn context() -> PolicyContext {
        let mut task = TaskObservation::default();
        task.push_vec3("goal_pos", &Vector3::new(1.8, 0.1, 0.9));
        PolicyContext {
            init: Vector3::new(0.0, 0.0, 1.0),
            task,
            wall: Some(Isometry3::translation(2.0, 0.0, 1.0)),
        }
    }

    #[test]
    fn the_circle_starts_at_the_grasp_and_sweeps_324_degrees_about_the_axis() {
        use rand::SeedableRng;
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let mut p = policy(&context(), &mut rng).unwrap_or_else(|e| panic!("{e}"));
        let grasp = Vector3::new(1.8 - 0.18, 0.1, 0.9);
        let centre = grasp + Vector3::new(0.0, 0.0, 0.12);
        let (at_start, g) = p.action(700);
        assert!((at_start.translation.vector - grasp).norm() < 1e-12);
        assert!((g + 1.0).abs() < 1e-12, "closed on the circle");
        // A quarter of the way round (81°, tick 700 + 599/4): +w_y side, radius 0.12.
        let (quarter, _) = p.action(700 + 150);
        let r = quarter.translation.vector - centre;
        assert!((r.norm() - 0.12).abs() < 1e-12);
        let theta = r.y.atan2(-r.z);
        assert!((theta - 1.8 * std::f64::consts::PI * 150.0 / 599.0).abs() < 1e-9);
        // The last circle point is at 324°; at 1300 the end waypoint (top of the circle).
        let (last, _) = p.action(1299);
        let r = last.translation.vector - centre;
        assert!((r.y.atan2(-r.z) + 0.2 * std::f64::consts::PI).abs() < 1e-9);
        let (top, _) = p.action(1300);
        assert!((top.translation.vector - (centre + Vector3::new(0.0, 0.0, 0.12))).norm() < 1e-12);
        assert!((p.action(1400).1 - 1.0).abs() < 1e-12, "released");
    }
}
