//! NED/FRD (PX4) ↔ world/body (amstack): the only frame conversion in the code base.
//!
//! amstack's world is ENU-like and Z-up (x east, y north, z up; AM-Bench's frame) and its
//! body frame is FLU (x forward, y left, z up). PX4 speaks a NED local frame (x north,
//! y east, z down) and an FRD body frame (x forward, y right, z down).
//!
//! Both changes of frame are rotations by π, so each is its own inverse:
//!
//! ```text
//! world ↔ NED:  (x, y, z) ↦ (y, x, −z)     R_ned_from_world = [[0,1,0],[1,0,0],[0,0,−1]]
//! FLU  ↔ FRD:  (x, y, z) ↦ (x, −y, −z)    R_frd_from_flu   = diag(1, −1, −1)
//! ```
//!
//! An attitude `world_from_body` becomes `ned_from_frd = R_ned_from_world · world_from_body ·
//! R_flu_from_frd`. Heading follows: yaw 0 in amstack looks east (+x), yaw 0 in PX4 looks north,
//! and amstack's yaw ψ (counter-clockwise from east) is PX4's ψ' = π/2 − ψ (clockwise from north).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// A vector in amstack's world frame (ENU-like) → the same vector in NED.
pub fn ned_from_world(v_world: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v_world.y, v_world.x, -v_world.z)
}

/// A vector in NED → the same vector in amstack's world frame.
pub fn world_from_ned(v_ned: &Vector3<f64>) -> Vector3<f64> {
    // The swap is its own inverse.
    ned_from_world(v_ned)
}

/// A vector in amstack's body frame (FLU) → the same vector in FRD.
pub fn frd_from_flu(v_flu: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v_flu.x, -v_flu.y, -v_flu.z)
}

/// A vector in FRD → the same vector in FLU.
pub fn flu_from_frd(v_frd: &Vector3<f64>) -> Vector3<f64> {
    frd_from_flu(v_frd)
}

/// `R_ned_from_world`: a rotation by π about the axis (1, 1, 0)/√2.
fn ned_from_world_rotation() -> UnitQuaternion<f64> {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, h, h, 0.0))
}

/// `R_frd_from_flu`: a rotation by π about x.
fn frd_from_flu_rotation() -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, 1.0, 0.0, 0.0))
}

/// amstack attitude (`world_from_body`, FLU body in the ENU world) → PX4 attitude
/// (`ned_from_frd`). Returned with a non-negative scalar part.
pub fn ned_from_frd_attitude(world_from_body: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    canonical(ned_from_world_rotation() * world_from_body * frd_from_flu_rotation())
}

/// PX4 attitude (`ned_from_frd`) → amstack attitude (`world_from_body`). Returned with a
/// non-negative scalar part.
pub fn world_from_body_attitude(ned_from_frd: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    // Both rotations are by π, so each is its own inverse.
    canonical(ned_from_world_rotation() * ned_from_frd * frd_from_flu_rotation())
}

/// A MAVLink quaternion `[w, x, y, z]` (f32, as in ATTITUDE_QUATERNION, ODOMETRY,
/// SET_ATTITUDE_TARGET) → a unit quaternion, or `None` if it is not finite or far from unit
/// length (> 1 % off), which a sender must not produce.
pub fn quaternion_from_mavlink(q: [f32; 4]) -> Option<UnitQuaternion<f64>> {
    let q = Quaternion::new(
        f64::from(q[0]),
        f64::from(q[1]),
        f64::from(q[2]),
        f64::from(q[3]),
    );
    let norm = q.norm();
    if !norm.is_finite() || (norm - 1.0).abs() > 0.01 {
        return None;
    }
    Some(UnitQuaternion::from_quaternion(q))
}

/// A unit quaternion → MAVLink's `[w, x, y, z]` (f32).
pub fn quaternion_to_mavlink(q: &UnitQuaternion<f64>) -> [f32; 4] {
    // MAVLink carries f32; the narrowing is the protocol's.
    #[allow(clippy::cast_possible_truncation)]
    [q.w as f32, q.i as f32, q.j as f32, q.k as f32]
}

/// amstack yaw (rad, counter-clockwise from +x east) → PX4 yaw (rad, clockwise from north),
/// wrapped to (−π, π].
pub fn ned_yaw_from_world_yaw(yaw_world_rad: f64) -> f64 {
    wrap_pi(std::f64::consts::FRAC_PI_2 - yaw_world_rad)
}

/// PX4 yaw → amstack yaw (the map is its own inverse), wrapped to (−π, π].
pub fn world_yaw_from_ned_yaw(yaw_ned_rad: f64) -> f64 {
    ned_yaw_from_world_yaw(yaw_ned_rad)
}

fn wrap_pi(angle: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let wrapped = angle - two_pi * ((angle + std::f64::consts::PI) / two_pi).floor();
    if wrapped <= -std::f64::consts::PI {
        wrapped + two_pi
    } else {
        wrapped
    }
}

fn canonical(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    if q.w < 0.0 {
        UnitQuaternion::new_unchecked(-q.into_inner())
    } else {
        q
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

    const EPS: f64 = 1e-12;

    fn close(a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
        (a - b).norm() < EPS
    }

    #[test]
    fn east_north_up_is_y_x_minus_z_in_ned() {
        // 1 m east, 2 m north, 3 m up = 2 m north, 1 m east, −3 m down.
        let ned = ned_from_world(&Vector3::new(1.0, 2.0, 3.0));
        assert!(close(&ned, &Vector3::new(2.0, 1.0, -3.0)));
        assert!(close(&world_from_ned(&ned), &Vector3::new(1.0, 2.0, 3.0)));
    }

    #[test]
    fn left_up_is_minus_right_minus_down() {
        let frd = frd_from_flu(&Vector3::new(1.0, 2.0, 3.0));
        assert!(close(&frd, &Vector3::new(1.0, -2.0, -3.0)));
        assert!(close(&flu_from_frd(&frd), &Vector3::new(1.0, 2.0, 3.0)));
    }

    #[test]
    fn level_facing_east_is_ned_yaw_90_degrees() {
        // amstack identity: body x (forward) points east. In PX4 that is yaw +90° (east of north),
        // level.
        let q = ned_from_frd_attitude(&UnitQuaternion::identity());
        let (roll, pitch, yaw) = q.euler_angles();
        assert!(roll.abs() < EPS && pitch.abs() < EPS, "{roll} {pitch}");
        assert!((yaw - FRAC_PI_2).abs() < EPS, "{yaw}");
    }

    #[test]
    fn level_facing_north_is_ned_identity() {
        let world_from_body = UnitQuaternion::from_euler_angles(0.0, 0.0, FRAC_PI_2);
        let q = ned_from_frd_attitude(&world_from_body);
        assert!(q.angle() < 1e-9, "{q:?}");
    }

    #[test]
    fn attitude_maps_body_vectors_consistently() {
        // For any attitude and body vector v: ned(world_from_body · v) = ned_from_frd · frd(v).
        for (r, p, y) in [
            (0.3, -0.2, 1.1),
            (-1.0, 0.5, -2.9),
            (PI - 0.1, 0.2, FRAC_PI_4),
        ] {
            let world_from_body = UnitQuaternion::from_euler_angles(r, p, y);
            let ned_from_frd = ned_from_frd_attitude(&world_from_body);
            let v = Vector3::new(0.7, -1.3, 2.1);
            let lhs = ned_from_world(&(world_from_body * v));
            let rhs = ned_from_frd * frd_from_flu(&v);
            assert!(close(&lhs, &rhs), "{lhs} vs {rhs}");
            let back = world_from_body_attitude(&ned_from_frd);
            assert!(back.angle_to(&world_from_body) < 1e-12);
        }
    }

    #[test]
    fn roll_right_in_px4_is_the_same_roll_about_flu_x_when_facing_north() {
        // PX4 roll +0.2 rad (right wing down) facing north. In amstack the body faces north
        // (yaw +90°) and rolls right wing down: +0.2 about FLU x too (y left goes up).
        let ned_from_frd = UnitQuaternion::from_euler_angles(0.2, 0.0, 0.0);
        let world_from_body = world_from_body_attitude(&ned_from_frd);
        let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, FRAC_PI_2)
            * UnitQuaternion::from_euler_angles(0.2, 0.0, 0.0);
        assert!(world_from_body.angle_to(&expected) < 1e-12);
    }

    #[test]
    fn yaw_maps_east_to_ninety_and_north_to_zero() {
        assert!((ned_yaw_from_world_yaw(0.0) - FRAC_PI_2).abs() < EPS);
        assert!(ned_yaw_from_world_yaw(FRAC_PI_2).abs() < EPS);
        assert!((ned_yaw_from_world_yaw(PI) + FRAC_PI_2).abs() < EPS);
        assert!((world_yaw_from_ned_yaw(ned_yaw_from_world_yaw(2.5)) - 2.5).abs() < EPS);
    }

    #[test]
    fn mavlink_quaternions_round_trip_and_reject_garbage() {
        let q = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3);
        let back = quaternion_from_mavlink(quaternion_to_mavlink(&q)).expect("unit");
        assert!(back.angle_to(&q) < 1e-6);
        assert!(quaternion_from_mavlink([f32::NAN, 0.0, 0.0, 0.0]).is_none());
        assert!(quaternion_from_mavlink([0.0, 0.0, 0.0, 0.0]).is_none());
        assert!(quaternion_from_mavlink([2.0, 0.0, 0.0, 0.0]).is_none());
    }
}
