//! Toss Ball (AMBENCH_SPEC §4.11): tilt the held ball down, line up with the container in y,
//! move forward, pitch down to load the throw, turn the hand level, then swing forward and up
//! while the gripper opens, and follow through back and low.
//!
//! **Departure from the reference (aimed throw).** The reference script lines up with the
//! container in y only: its throw lands at the same x wherever the container stands, so with
//! the container's x randomised by ±0.5 m and the container 0.4 m long, most throws miss
//! (30 % of 30 rollouts with the EE-only oracle here). Scripted demonstrations are the
//! benchmark's training data and must succeed, so the whole throw (from the alignment on) is
//! shifted in x so that it lands on the container, as it is lined up in y. The geometry of
//! the throw relative to the container, and with it the "base at least 0.7 m behind the
//! container" criterion, is then the same in every rollout.
//!
//! **Departure from the reference (a swing the vehicles follow).** The reference's swing runs
//! 0.64–0.84 m in 17–22 ticks with a stop at the pre-release pose (its smootherstep peaks near
//! 9 m/s) and lets the ball go at 0.89 of the second segment, where the target has nearly
//! stopped: the throw was then set by how far each configuration lagged behind, and their
//! landings spread over 2.1 m (README "Toss Ball"). Here:
//! - the hand turns level at the load pose before the swing ([`TURN_STRETCH`] times the drawn
//!   pre-release increment), so the swing is a pure translation;
//! - the swing is one smootherstep from the load pose to the swing's end, which lies
//!   [`SWING_FORWARD_M`] further forward and [`SWING_RISE_M`] higher than the reference's
//!   release pose, and lasts so long that its peak speed, 15/8 · distance / duration, is
//!   [`SWING_PEAK_SPEED_MPS`] (the drawn release increment moves it by −1…+1 tick): the
//!   target's largest acceleration, 10/√3 · distance / duration², is then 6.6–8.0 m/s²
//!   against ~300 m/s² in the reference's;
//! - the gripper starts opening at the turn and its drives' target passes the ball's 0.08 m
//!   grasp width at [`RELEASE_FRACTION`] of the swing (the FA-Hexa's and EE-only's finger
//!   range, AMBENCH_SPEC §1.2);
//! - the follow-through comes back [`FOLLOW_BACK_M`] behind the swing's end, low, within
//!   [`FOLLOW_TICKS`] (the reference drifts to below the release pose until tick 800), so the
//!   vehicle is, or comes back, behind the 0.7 m line while the ball lies in the container.
//!
//! The configurations still lag behind this swing (the PID's feed-forward velocity is clamped
//! to 1 m/s per axis, AMBENCH_SPEC §2.2; a swing followed exactly throws the ball less than the
//! 0.7 m the base must stay behind the container), but they lag alike: the EE-only oracle, and
//! the FA-Hexa with IK-PID (with and without the reference's disturbances) and IK-L1 release
//! the ball at (1.13–1.60, 0.72–1.01) m/s forward and up and land it within −0.13…+0.15 m of
//! the container's centre ([`UNSHIFTED_LANDING_X_M`]); the MPC does not (README "Toss Ball").
//! The random draws are unchanged (same order, same ranges); the pre-release pose is now the
//! load pose (the reference's lies at 0.42 of the swing), and the follow-through's time is
//! [`FOLLOW_TICKS`] after the swing (the reference's: tick 800).
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

/// Where the throw's ball lands in x, starting at x = 0, m: the centre of the landing spread
/// of the configurations that follow the swing. Measured (seed 0; the ball's x where it first
/// comes down through the container's rim height, minus the container's x, from the logs'
/// `/task/state` of `amstack bench --platform P [--controller C] [--disturbances D] --task
/// toss-ball --out DIR`): EE-only −0.12…+0.12 m (30 rollouts), FA-Hexa IK-PID −0.13…+0.15
/// (30; with the reference's disturbances −0.12…+0.15), IK-L1 −0.12…+0.08 (10). The EE-only
/// oracle over seeds 0–39 (`cargo test --release -p policy_runtime --lib bench::tests::
/// toss_ball_landing -- --ignored --nocapture`): −0.13…+0.12, but seed 31 −0.24 (39 of 40).
const UNSHIFTED_LANDING_X_M: f64 = 2.30;
/// The swing's end lies this much further forward than the reference's release pose, m.
const SWING_FORWARD_M: f64 = 0.4;
/// The swing's end lies this much higher than the reference's release pose, m.
const SWING_RISE_M: f64 = 0.6;
/// The swing target's peak speed, m/s.
const SWING_PEAK_SPEED_MPS: f64 = 2.5;
/// The drawn pre-release increment (8–11 ticks) stretched by this, for the hand's turn from
/// the load pitch to level (π/3 in 32–44 ticks, ≤ 4 rad/s: under the wrist's 5 rad/s).
const TURN_STRETCH: u64 = 4;
/// Where in the swing (its time fraction) the gripper lets the ball go.
const RELEASE_FRACTION: f64 = 0.8;
/// The gripper action at which the FA-Hexa's (and EE-only's) finger drives' target width,
/// 0.002 + 0.5 (a + 1) · 0.088 m (AMBENCH_SPEC §1.2), passes the ball's 0.08 m grasp width:
/// 2 · 0.078 / 0.088 − 1 = 0.77273, rounded down so that the width at exactly
/// [`RELEASE_FRACTION`] is just short of it (no tie): the ball goes at the first tick after.
const RELEASE_ACTION: f64 = 0.7727;
/// The follow-through pose lies this far behind the swing's end, m.
const FOLLOW_BACK_M: f64 = 0.4;
/// The follow-through takes this long after the swing's end, ticks.
const FOLLOW_TICKS: u64 = 60;
/// Control rate, Hz.
const RATE_HZ: f64 = 120.0;

/// The swing's duration in ticks: the peak speed's, 15/8 · distance / speed, plus the jitter.
fn swing_ticks(distance_m: f64, jitter: i64) -> u64 {
    // Rounded ticks of a ~1 s swing: small positive numbers.
    let ticks = (15.0 / 8.0 * distance_m / SWING_PEAK_SPEED_MPS * RATE_HZ).round() as i64;
    (ticks + jitter).max(1) as u64
}

/// The gripper action at the turn's end such that the linear ramp to +1 over the swing passes
/// [`RELEASE_ACTION`] at [`RELEASE_FRACTION`].
fn pre_release_action() -> f64 {
    (RELEASE_ACTION - RELEASE_FRACTION) / (1.0 - RELEASE_FRACTION)
}

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
    // The reference's release pose, moved on: the swing's end.
    let swing_end = Vector3::new(
        release_x + SWING_FORWARD_M,
        align.y,
        release_z + SWING_RISE_M,
    );
    let follow = Vector3::new(
        swing_end.x - FOLLOW_BACK_M,
        align.y,
        init.z + uniform(rng, -0.14, -0.06),
    );

    let t_tilt = tick(rng, 100.0, 140.0);
    let t_align = tick(rng, 230.0, 290.0);
    let t_forward = tick(rng, 400.0, 410.0);
    let t_load = tick(rng, 420.0, 440.0);
    let t_hold = t_load + tick(rng, 80.0, 120.0);
    let t_turned = t_hold + TURN_STRETCH * tick(rng, 8.0, 12.0);
    // The drawn release increment (9–11) as a −1…+1 tick jitter of the swing.
    let jitter = tick(rng, 9.0, 12.0) as i64 - 10;
    let t_swing_end = t_turned + swing_ticks((swing_end - hold).norm(), jitter);

    WaypointPolicy::new(vec![
        wp(0, init, identity(), -1.0),
        wp(t_tilt, tilt, q_move, -1.0),
        wp(t_align, align, q_move, -1.0),
        wp(t_forward, forward, q_move, -1.0),
        wp(t_load, load, q_load, -1.0),
        wp(t_hold, hold, q_load, -1.0),
        wp(t_turned, hold, q_release, pre_release_action()),
        wp(t_swing_end, swing_end, q_release, 1.0),
        wp(t_swing_end + FOLLOW_TICKS, follow, q_load, 1.0),
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
            // The hold (80–119 ticks), the turn (4 × 8–11), the follow-through (60 ticks).
            assert!((80..120).contains(&(t[5] - t[4])), "{t:?}");
            assert!([32, 36, 40, 44].contains(&(t[6] - t[5])), "{t:?}");
            assert_eq!(t[8] - t[7], 60);
            // Lined up with the container in y from the alignment on, within ±0.06.
            for w in &w[2..] {
                assert!((w.position.y + 0.3).abs() <= 0.06);
            }
            // Closed until the hold, opening from the turn on, open at the swing's end.
            assert!(w[..6].iter().all(|w| w.gripper == -1.0));
            assert!(
                w[6].gripper > -1.0 && w[6].gripper < 0.0,
                "{}",
                w[6].gripper
            );
            assert!(w[7..].iter().all(|w| w.gripper == 1.0));
            // The turn happens in place; the swing goes forward 1.04–1.24 m (the reference's
            // 0.64–0.84 plus 0.4) and ends 0.68–0.78 m above the start; the follow-through
            // comes back 0.4 m, below the start.
            assert_eq!(w[6].position, w[5].position);
            let swing = w[7].position.x - w[6].position.x;
            assert!((1.04..1.24).contains(&swing), "{swing}");
            assert!((1.68..1.78).contains(&w[7].position.z));
            assert!((w[7].position.x - w[8].position.x - 0.4).abs() < 1e-12);
            assert!((0.86..0.94).contains(&w[8].position.z));
            // Pitched down π/3 ± 0.05 to load, level ± 0.04 for the whole swing.
            let load = w[4].orientation.euler_angles().1;
            assert!((load - std::f64::consts::FRAC_PI_3).abs() <= 0.05, "{load}");
            assert_eq!(w[6].orientation, w[7].orientation);
            assert!(w[7].orientation.euler_angles().1.abs() <= 0.04);
        }
    }

    /// The swing's target, sampled tick by tick: its peak speed is the smootherstep's, 15/8 ·
    /// distance / duration = 2.5 m/s (within the tick jitter and rounding), not the
    /// reference's ~9 m/s; the gripper's drives pass the ball's 0.08 m width at the first tick
    /// past 0.8 of the swing, where the target moves at s'(0.8) = 30 · 0.8² · 0.2² = 0.768 of
    /// distance / duration.
    #[test]
    fn the_swing_peaks_at_a_followable_speed_and_lets_go_at_four_fifths() {
        // The FA-Hexa's gripper as its vehicle description maps an action to finger targets.
        let vehicle = platform::Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
        let gripper = vehicle
            .gripper
            .unwrap_or_else(|| panic!("the FA-Hexa has a gripper"));
        let width = |action: f64| gripper.targets(action).iter().sum::<f64>();
        for seed in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let p = policy(&context(), &mut rng).unwrap_or_else(|e| panic!("{e}"));
            let (start, end) = (p.waypoints()[6], p.waypoints()[7]);
            let distance = (end.position - start.position).norm();
            let duration_s = (end.tick - start.tick) as f64 / RATE_HZ;
            // Hand-derived: ~1.43 m in ~1.07 s.
            assert!((1.2..1.6).contains(&distance), "{distance}");
            let peak = 15.0 / 8.0 * distance / duration_s;
            assert!((2.45..2.56).contains(&peak), "seed {seed}: {peak} m/s");
            let mut fastest = 0.0_f64;
            let mut release = None;
            for k in start.tick..end.tick {
                let (a, g_a) = p.action(k);
                let (b, g_b) = p.action(k + 1);
                let speed = (b.translation.vector - a.translation.vector).norm() * RATE_HZ;
                fastest = fastest.max(speed);
                if release.is_none() && width(g_a) <= 0.08 && width(g_b) > 0.08 {
                    release = Some((k + 1, speed));
                }
            }
            // The finite difference of the smootherstep over a tick stays within 1 % of its
            // peak derivative here (~128 ticks per swing).
            assert!(
                (fastest / peak - 1.0).abs() < 0.01,
                "{fastest} against {peak}"
            );
            assert!(fastest < 2.6, "{fastest} m/s");
            let (k, speed) = release.unwrap_or_else(|| panic!("seed {seed}: never let go"));
            let tau = (k - start.tick) as f64 / (end.tick - start.tick) as f64;
            let first_past = (0.8 * (end.tick - start.tick) as f64).floor() as u64 + 1;
            assert_eq!(k - start.tick, first_past, "seed {seed}: tau {tau}");
            let expected = 0.768 * distance / duration_s;
            assert!(
                (speed / expected - 1.0).abs() < 0.05,
                "{speed} against {expected}"
            );
        }
    }
}
