//! Where the internal controller flies: the position target of the autopilot's own modes
//! (hold, takeoff, land, RTL, reposition, missions) and of offboard position, velocity and
//! acceleration setpoints. A pure state machine: the measured state and `dt` arrive as
//! arguments; the output is a pose target for amstack's PID (`controllers`, through
//! [`crate::control::Control::hold`]).
//!
//! The target moves toward its goal as PX4's position setpoints do, within speed limits
//! (MPC_XY_*, MPC_Z_VEL_MAX_*) and acceleration limits (MPC_ACC_*), braking so that it stops
//! at the goal: per axis group (horizontal, vertical) the speed is
//! `min(v_max, √(2 a d))` along the remaining distance d, changed by at most `a dt` a step.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};

/// Speed and acceleration limits of the moving target (SI, positive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Horizontal speed, m/s.
    pub xy_speed_mps: f64,
    /// Climb rate, m/s.
    pub up_speed_mps: f64,
    /// Descent rate, m/s.
    pub down_speed_mps: f64,
    /// Horizontal acceleration, m/s².
    pub xy_acc_mps2: f64,
    /// Upward acceleration, m/s².
    pub up_acc_mps2: f64,
    /// Downward acceleration, m/s².
    pub down_acc_mps2: f64,
}

/// A position target that moves toward a goal within [`Limits`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Carrot {
    /// Target position, world, m.
    pub position_m: Vector3<f64>,
    /// Target velocity, world, m/s.
    pub velocity_mps: Vector3<f64>,
    /// Target heading (amstack yaw, rad).
    pub yaw_rad: f64,
}

/// Speed of a braking approach: at most `v_max`, at most √(2 a d).
fn approach_speed(distance: f64, v_max: f64, acc: f64) -> f64 {
    v_max.min((2.0 * acc * distance).sqrt())
}

impl Carrot {
    /// At `position_m`, still, heading `yaw_rad`.
    pub fn at(position_m: Vector3<f64>, yaw_rad: f64) -> Self {
        Self {
            position_m,
            velocity_mps: Vector3::zeros(),
            yaw_rad,
        }
    }

    /// The pose target (level, at the heading).
    pub fn pose(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.position_m),
            UnitQuaternion::from_euler_angles(0.0, 0.0, self.yaw_rad),
        )
    }

    /// One step of `dt` toward `goal` within `limits`; true once the target is at the goal
    /// (and then stays there, still).
    pub fn toward(&mut self, goal: &Vector3<f64>, limits: &Limits, dt: f64) -> bool {
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 0.1)
        } else {
            0.0
        };
        // Horizontal.
        let d_xy = Vector2::new(goal.x - self.position_m.x, goal.y - self.position_m.y);
        let v_xy = Vector2::new(self.velocity_mps.x, self.velocity_mps.y);
        let dist_xy = d_xy.norm();
        let want_xy = if dist_xy > 1e-9 {
            d_xy / dist_xy * approach_speed(dist_xy, limits.xy_speed_mps, limits.xy_acc_mps2)
        } else {
            Vector2::zeros()
        };
        let dv = want_xy - v_xy;
        let max_dv = limits.xy_acc_mps2 * dt;
        let v_xy = v_xy
            + if dv.norm() > max_dv {
                dv * (max_dv / dv.norm())
            } else {
                dv
            };
        // Vertical.
        let d_z = goal.z - self.position_m.z;
        let (v_max, acc) = if d_z >= 0.0 {
            (limits.up_speed_mps, limits.up_acc_mps2)
        } else {
            (limits.down_speed_mps, limits.down_acc_mps2)
        };
        let want_z = d_z.signum() * approach_speed(d_z.abs(), v_max, acc);
        let max_dvz = acc.max(limits.down_acc_mps2) * dt;
        let v_z = self.velocity_mps.z + (want_z - self.velocity_mps.z).clamp(-max_dvz, max_dvz);
        let mut next = self.position_m + Vector3::new(v_xy.x, v_xy.y, v_z) * dt;
        // Never step past the goal (per group).
        let step_xy = Vector2::new(next.x - self.position_m.x, next.y - self.position_m.y);
        if step_xy.norm() >= dist_xy {
            next.x = goal.x;
            next.y = goal.y;
        }
        if (next.z - self.position_m.z).abs() >= d_z.abs() {
            next.z = goal.z;
        }
        self.velocity_mps = if dt > 0.0 {
            (next - self.position_m) / dt
        } else {
            Vector3::zeros()
        };
        self.position_m = next;
        let arrived = (self.position_m - goal).norm() < 1e-6;
        if arrived {
            self.position_m = *goal;
            self.velocity_mps = Vector3::zeros();
        }
        arrived
    }

    /// One step of `dt` at the velocity `velocity_mps` (world), clamped to `limits`' speeds.
    pub fn with_velocity(&mut self, velocity_mps: &Vector3<f64>, limits: &Limits, dt: f64) {
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 0.1)
        } else {
            0.0
        };
        let v = clamp_velocity(velocity_mps, limits);
        self.velocity_mps = v;
        self.position_m += v * dt;
    }
}

/// `v` with its horizontal speed at most `xy_speed_mps` and its vertical speed within the
/// climb and descent limits.
pub fn clamp_velocity(v: &Vector3<f64>, limits: &Limits) -> Vector3<f64> {
    let xy = Vector2::new(v.x, v.y);
    let n = xy.norm();
    let xy = if n > limits.xy_speed_mps && n > 0.0 {
        xy * (limits.xy_speed_mps / n)
    } else {
        xy
    };
    Vector3::new(
        xy.x,
        xy.y,
        v.z.clamp(-limits.down_speed_mps, limits.up_speed_mps),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        Limits {
            xy_speed_mps: 2.0,
            up_speed_mps: 1.0,
            down_speed_mps: 0.5,
            xy_acc_mps2: 3.0,
            up_acc_mps2: 4.0,
            down_acc_mps2: 3.0,
        }
    }

    #[test]
    fn the_target_reaches_the_goal_within_its_limits_and_stops() {
        let mut c = Carrot::at(Vector3::new(0.0, 0.0, 1.0), 0.0);
        let goal = Vector3::new(3.0, 4.0, 2.0);
        let dt = 1.0 / 120.0;
        let mut steps = 0;
        let mut max_xy: f64 = 0.0;
        let mut max_z: f64 = 0.0;
        while !c.toward(&goal, &limits(), dt) {
            max_xy = max_xy.max(Vector2::new(c.velocity_mps.x, c.velocity_mps.y).norm());
            max_z = max_z.max(c.velocity_mps.z);
            steps += 1;
            assert!(steps < 120 * 60, "never arrived: {c:?}");
        }
        assert_eq!(c.position_m, goal);
        assert!(max_xy <= 2.0 + 1e-9 && max_xy > 1.9, "{max_xy}");
        assert!(max_z <= 1.0 + 1e-9, "{max_z}");
        // 5 m at 2 m/s with 3 m/s² ramps: a little more than 2.5 s.
        let t = f64::from(steps) * dt;
        assert!((2.5..3.5).contains(&t), "{t}");
        assert!(c.toward(&goal, &limits(), dt), "stays");
    }

    #[test]
    fn velocities_are_clamped_to_the_speed_limits() {
        let v = clamp_velocity(&Vector3::new(30.0, 40.0, -10.0), &limits());
        assert!((Vector2::new(v.x, v.y).norm() - 2.0).abs() < 1e-12);
        assert_eq!(v.z, -0.5);
        let mut c = Carrot::at(Vector3::zeros(), 0.0);
        // 5 m/s up is clamped to 1 m/s: 0.1 m in 0.1 s.
        c.with_velocity(&Vector3::new(0.0, 0.0, 5.0), &limits(), 0.1);
        assert!((c.position_m.z - 0.1).abs() < 1e-12);
    }
}
