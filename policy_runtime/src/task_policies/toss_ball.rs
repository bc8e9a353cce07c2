//! Toss Ball (AMBENCH_SPEC §4.11): tilt the held ball down, line up with the container in y,
//! move forward, pitch down to load the throw, then swing forward and up to level while
//! the gripper opens, and follow through low.
//!
//! **Departure from the reference (aimed throw).** The reference script lines up with the
//! container in y only: its throw lands at the same x wherever the container stands, so with
//! the container's x randomised by ±0.5 m and the container 0.4 m long, most throws miss
//! (30 % of 30 rollouts with the EE-only oracle here). Scripted demonstrations are the
//! benchmark's training data and must succeed, so the whole throw (from the alignment on) is
//! shifted in x so that it lands on the container, as it is lined up in y. The geometry of
//! the throw relative to the container, and with it the "base at least 0.7 m behind the
//! container" criterion, is then the same in every rollout. The random draws are unchanged
//! (same order, same ranges).
//!
//! Where the unshifted throw lands is a measured property of the twin and the controller, not
//! of the script: the waypoints ask for a swing far faster than the EE can follow (the
//! release segment's smootherstep peaks near 9 m/s), so the release speed (≈ 2.1–2.2 m/s here)
//! is set by the controller's limits. [`UNSHIFTED_LANDING_X_M`] is that landing point.
//!
//! Random offsets are drawn in the reference's order: the two pitch deltas (release, load),
//! the tilt offset (x, y, z), the alignment (y, then x, then z), the forward pose (x, z), the
//! load pose (x, z), the release pose (x, z), the follow-through z, then the times (tilt,
//! align, forward, load, and the hold, pre-release and release increments), each time the
//! integer part of its draw.

use nalgebra::{UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, identity, uniform, wp};
use crate::scripted::WaypointPolicy;
use sim_twin::tasks::keys;

/// Follow-through time (env steps).
const T_FOLLOW: u64 = 800;
/// Where the reference script's ball lands in x with the EE-only oracle and PID, starting at
/// x = 0, m: the centre of the measured landing spread. Throws vary by ±0.13 m with the
/// script's random offsets (the release timing sets the ball's vertical speed, 0.8–1.5 m/s),
/// and the container is 0.4 m long, so the throw is aimed at its centre. Measured (the ball's x
/// where it comes down through the container's rim height, minus the container's x, seeds
/// 0–39: −0.12 to +0.14 m with this value) by `cargo test --release -p policy_runtime --lib
/// bench::tests::toss_ball_landing -- --ignored --nocapture`.
const UNSHIFTED_LANDING_X_M: f64 = 1.84;
/// Where the pre-release pose lies between the hold and release poses.
const PRE_RELEASE_FRACTION: f64 = 0.42;

/// An integer time from U(lo, hi), truncated as the reference's `int(...)`.
fn tick(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> u64 {
    // Draws are small positive numbers: truncation is the reference's int().
    uniform(rng, lo, hi).floor() as u64
}

/// Pitch about y (the reference's `quat_from_euler_xyz(0, pitch, 0)`).
fn pitch(angle: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(0.0, angle, 0.0)
}

pub(crate) fn policy(ctx: &PolicyContext, rng: &mut ChaCha8Rng) -> Result<WaypointPolicy, String> {
    let target = ctx.task.vec3(keys::TARGET_POS, 0)?;
    let init = ctx.init;
    let release_delta = uniform(rng, -0.04, 0.04);
    let load_delta = uniform(rng, -0.05, 0.05);
    let q_move = pitch(std::f64::consts::PI / 5.0);
    let q_load = pitch(std::f64::consts::PI / 3.0 + load_delta);
    let q_release = pitch(release_delta);

    let tilt = init
        + Vector3::new(
            uniform(rng, -0.03, 0.03),
            uniform(rng, -0.03, 0.03),
            uniform(rng, -0.02, 0.02),
        );
    let align_y = target.y + uniform(rng, -0.06, 0.06);
    // The aimed throw: everything from the alignment on moves so the ball lands on the
    // container (relative to the start, as every other waypoint).
    let aim_x = target.x - (init.x + UNSHIFTED_LANDING_X_M);
    let align_x = init.x + aim_x + uniform(rng, -0.05, 0.10);
    let align_z = init.z + uniform(rng, -0.03, 0.03);
    let align = Vector3::new(align_x, align_y, align_z);
    let forward_x = init.x + aim_x + uniform(rng, 0.25, 0.45);
    let forward_z = align.z + uniform(rng, -0.03, 0.04);
    let forward = Vector3::new(forward_x, align.y, forward_z);
    let load_x = forward.x + uniform(rng, 0.05, 0.10);
    let load_z = init.z + uniform(rng, -0.16, -0.08);
    let load = Vector3::new(load_x, align.y, load_z);
    let hold = load;
    let release_x = load.x + uniform(rng, 0.64, 0.84);
    let release_z = init.z + uniform(rng, 0.08, 0.18);
    let release = Vector3::new(release_x, align.y, release_z);
    let pre = hold + PRE_RELEASE_FRACTION * (release - hold);
    let follow = Vector3::new(release.x, align.y, init.z + uniform(rng, -0.14, -0.06));

    let t_tilt = tick(rng, 100.0, 140.0);
    let t_align = tick(rng, 230.0, 290.0);
    let t_forward = tick(rng, 400.0, 410.0);
    let t_load = tick(rng, 420.0, 440.0);
    let t_hold = t_load + tick(rng, 80.0, 120.0);
    let t_pre = t_hold + tick(rng, 8.0, 12.0);
    let t_release = t_pre + tick(rng, 9.0, 12.0);

    WaypointPolicy::new(vec![
        wp(0, init, identity(), -1.0),
        wp(t_tilt, tilt, q_move, -1.0),
        wp(t_align, align, q_move, -1.0),
        wp(t_forward, forward, q_move, -1.0),
        wp(t_load, load, q_load, -1.0),
        wp(t_hold, hold, q_load, -1.0),
        wp(t_pre, pre, q_release, -1.0),
        wp(t_release, release, q_release, 1.0),
        wp(T_FOLLOW, follow, q_load, 1.0),
    ])
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;
    use rand::SeedableRng;
    use sim_twin::TaskObservation;

    use super::*;

    fn context() -> PolicyContext {
        let mut task = TaskObservation::default();
        task.push_vec3("target_pos", &Vector3::new(2.5, -0.3, 0.0));
        PolicyContext {
            init: Vector3::new(0.0, 0.0, 1.0),
            task,
            wall: None,
        }
    }

    #[test]
    fn the_throw_moves_with_the_container_in_x_from_the_alignment_on() {
        // The same draws, the container 0.3 m further: the start and the tilt stay, every later
        // waypoint moves 0.3 m in x and nothing else changes.
        let mut far = context();
        far.task = TaskObservation::default();
        far.task
            .push_vec3("target_pos", &Vector3::new(2.8, -0.3, 0.0));
        let near =
            policy(&context(), &mut ChaCha8Rng::seed_from_u64(7)).unwrap_or_else(|e| panic!("{e}"));
        let far = policy(&far, &mut ChaCha8Rng::seed_from_u64(7)).unwrap_or_else(|e| panic!("{e}"));
        for (i, (a, b)) in near.waypoints().iter().zip(far.waypoints()).enumerate() {
            let shift = if i < 2 { 0.0 } else { 0.3 };
            let d = b.position - a.position;
            assert!(
                (d - Vector3::new(shift, 0.0, 0.0)).norm() < 1e-12,
                "waypoint {i}: {d}"
            );
            assert_eq!((a.tick, a.gripper), (b.tick, b.gripper));
        }
    }

    #[test]
    fn the_throw_lines_up_with_the_container_and_opens_during_the_swing() {
        for seed in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let p = policy(&context(), &mut rng).unwrap_or_else(|e| panic!("{e}"));
            let w = p.waypoints();
            assert_eq!(w.len(), 9);
            let t: Vec<u64> = w.iter().map(|w| w.tick).collect();
            assert!(
                (100..140).contains(&t[1]) && (230..290).contains(&t[2]),
                "{t:?}"
            );
            assert!(
                (400..410).contains(&t[3]) && (420..440).contains(&t[4]),
                "{t:?}"
            );
            assert!((80..120).contains(&(t[5] - t[4])) && (8..12).contains(&(t[6] - t[5])));
            assert!((9..12).contains(&(t[7] - t[6])) && t[8] == T_FOLLOW);
            // Lined up with the container in y from the alignment on, within ±0.06.
            for w in &w[2..] {
                assert!((w.position.y + 0.3).abs() <= 0.06);
            }
            // Closed until the pre-release pose, open at the release.
            assert!(w[..7].iter().all(|w| w.gripper == -1.0));
            assert!(w[7..].iter().all(|w| w.gripper == 1.0));
            // The swing goes forward 0.64–0.84 m and up to 0.08–0.18 m above the start.
            let swing = w[7].position.x - w[5].position.x;
            assert!((0.64..0.84).contains(&swing), "{swing}");
            assert!((1.08..1.18).contains(&w[7].position.z));
            // Pitched down π/3 ± 0.05 to load, level ± 0.04 to release.
            let load = w[4].orientation.euler_angles().1;
            assert!((load - std::f64::consts::FRAC_PI_3).abs() <= 0.05, "{load}");
            assert!(w[7].orientation.euler_angles().1.abs() <= 0.04);
        }
    }
}
