//! Scripted policies: end-effector waypoints in time, as the reference's scripted
//! demonstrations (AMBENCH_SPEC §4.0). Times are control ticks at 120 Hz.
//!
//! Between waypoints (t₀, p₀, q₀, g₀) and (t₁, p₁, q₁, g₁), with τ = clamp((t − t₀)/(t₁ − t₀), 0, 1):
//! position p₀ + s(τ)(p₁ − p₀) with the smootherstep s = τ³(τ(6τ − 15) + 10) (zero velocity and
//! acceleration at both ends); orientation slerp(q₀, q₁, τ); gripper g₀ + τ(g₁ − g₀). Before
//! the first waypoint the first holds, after the last the last. Output quaternions have w ≥ 0.
//! Positions are end-effector link targets in the command frame.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// One waypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Waypoint {
    /// Control tick at which the waypoint is reached.
    pub tick: u64,
    /// End-effector position (world), m.
    pub position: Vector3<f64>,
    /// End-effector orientation in the command frame.
    pub orientation: UnitQuaternion<f64>,
    /// Gripper action in [−1, 1] (−1 closed, +1 open).
    pub gripper: f64,
}

/// A waypoint script.
#[derive(Debug, Clone, PartialEq)]
pub struct WaypointPolicy {
    waypoints: Vec<Waypoint>,
}

/// The smootherstep s(τ) = τ³(τ(6τ − 15) + 10) on [0, 1].
pub fn smootherstep(tau: f64) -> f64 {
    let t = tau.clamp(0.0, 1.0);
    t * t * t * (t * (6.0 * t - 15.0) + 10.0)
}

impl WaypointPolicy {
    /// A script from waypoints in time order (equal ticks allowed: a jump). Refuses an empty
    /// script, ticks going back, and non-finite values.
    pub fn new(waypoints: Vec<Waypoint>) -> Result<Self, String> {
        if waypoints.is_empty() {
            return Err("a script needs at least one waypoint".to_owned());
        }
        for (i, w) in waypoints.iter().enumerate() {
            let finite = w.position.iter().all(|x| x.is_finite())
                && w.orientation.coords.iter().all(|x| x.is_finite())
                && w.gripper.is_finite();
            if !finite {
                return Err(format!(
                    "waypoint {i} (tick {}) has a non-finite value",
                    w.tick
                ));
            }
            if i > 0 && w.tick < waypoints[i - 1].tick {
                return Err(format!(
                    "waypoint {i} at tick {} comes before tick {}",
                    w.tick,
                    waypoints[i - 1].tick
                ));
            }
        }
        Ok(Self { waypoints })
    }

    /// The waypoints.
    pub fn waypoints(&self) -> &[Waypoint] {
        &self.waypoints
    }

    /// The tick of the last waypoint (the script is over after it).
    pub fn end_tick(&self) -> u64 {
        self.waypoints.last().map_or(0, |w| w.tick)
    }

    /// The end-effector target (command frame) and gripper action at `tick`.
    pub fn action(&self, tick: u64) -> (Isometry3<f64>, f64) {
        let ws = &self.waypoints;
        let next = ws.partition_point(|w| w.tick <= tick);
        let (position, orientation, gripper) = match next {
            0 => (ws[0].position, ws[0].orientation, ws[0].gripper),
            n if n == ws.len() => {
                let w = ws[n - 1];
                (w.position, w.orientation, w.gripper)
            }
            n => {
                let (a, b) = (ws[n - 1], ws[n]);
                let tau = ((tick - a.tick) as f64 / (b.tick - a.tick) as f64).clamp(0.0, 1.0);
                let s = smootherstep(tau);
                (
                    a.position + (b.position - a.position) * s,
                    a.orientation.slerp(&b.orientation, tau),
                    a.gripper + tau * (b.gripper - a.gripper),
                )
            }
        };
        let orientation = if orientation.w < 0.0 {
            UnitQuaternion::new_unchecked(-orientation.into_inner())
        } else {
            orientation
        };
        (
            Isometry3::from_parts(Translation3::from(position), orientation),
            gripper,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXACT: f64 = 1e-12;

    fn wp(tick: u64, x: f64, yaw: f64, gripper: f64) -> Waypoint {
        Waypoint {
            tick,
            position: Vector3::new(x, 0.0, 1.0),
            orientation: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            gripper,
        }
    }

    #[test]
    fn smootherstep_has_the_reference_values() {
        assert!(smootherstep(0.0).abs() < EXACT && (smootherstep(1.0) - 1.0).abs() < EXACT);
        assert!((smootherstep(0.5) - 0.5).abs() < EXACT);
        // 0.25³ (0.25 (1.5 − 15) + 10) = 0.103515625.
        assert!((smootherstep(0.25) - 0.103_515_625).abs() < EXACT);
        assert!((smootherstep(-1.0)).abs() < EXACT && (smootherstep(2.0) - 1.0).abs() < EXACT);
    }

    #[test]
    fn a_segment_interpolates_position_orientation_and_gripper() {
        let p = WaypointPolicy::new(vec![
            wp(0, 0.0, 0.0, 1.0),
            wp(100, 1.0, std::f64::consts::FRAC_PI_2, -1.0),
        ])
        .unwrap_or_else(|e| panic!("{e}"));
        let (pose, g) = p.action(25);
        assert!(
            (pose.translation.x - 0.103_515_625).abs() < EXACT,
            "smootherstep position"
        );
        assert!(
            (pose.rotation.euler_angles().2 - 0.25 * std::f64::consts::FRAC_PI_2).abs() < 1e-12,
            "slerp is linear in τ"
        );
        assert!((g - 0.5).abs() < EXACT, "gripper linear in τ");
        let (end, g_end) = p.action(100);
        assert!((end.translation.x - 1.0).abs() < EXACT && (g_end + 1.0).abs() < EXACT);
    }

    #[test]
    fn the_script_holds_its_last_waypoint_and_jumps_at_equal_ticks() {
        let p = WaypointPolicy::new(vec![
            wp(0, 0.0, 0.0, 1.0),
            wp(400, 2.0, 0.0, 1.0),
            wp(400, 2.0, 0.0, -1.0),
            wp(500, 2.0, 0.0, -1.0),
        ])
        .unwrap_or_else(|e| panic!("{e}"));
        assert!((p.action(10_000).0.translation.x - 2.0).abs() < EXACT);
        assert!(
            (p.action(400).1 + 1.0).abs() < EXACT,
            "at tick 400 the second of the two waypoints applies"
        );
        assert_eq!(p.end_tick(), 500);
    }

    #[test]
    fn output_quaternions_have_non_negative_w() {
        // Yaw from 170° to 190°: the slerp path passes 180° where w changes sign.
        let p = WaypointPolicy::new(vec![
            wp(0, 0.0, 170f64.to_radians(), 0.0),
            wp(10, 0.0, 190f64.to_radians(), 0.0),
        ])
        .unwrap_or_else(|e| panic!("{e}"));
        for t in 0..=10 {
            assert!(p.action(t).0.rotation.w >= 0.0, "tick {t}");
        }
    }

    #[test]
    fn bad_scripts_are_refused() {
        assert!(WaypointPolicy::new(vec![]).is_err());
        assert!(
            WaypointPolicy::new(vec![wp(10, 0.0, 0.0, 0.0), wp(5, 0.0, 0.0, 0.0)])
                .is_err_and(|e| e.contains("comes before"))
        );
        assert!(
            WaypointPolicy::new(vec![wp(0, f64::NAN, 0.0, 0.0)])
                .is_err_and(|e| e.contains("non-finite"))
        );
    }
}
