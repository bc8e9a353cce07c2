//! Offboard setpoints as PX4 reads them (`mavlink_receiver.cpp`): SET_POSITION_TARGET_LOCAL_NED
//! with its type mask, and SET_ATTITUDE_TARGET (attitude or body rates, with thrust), in
//! amstack's frames (NED/FRD converted here and in `firmware_bridge::frames` only).
//!
//! **SET_POSITION_TARGET_LOCAL_NED** (84). type_mask bits 1/2/4 ignore x/y/z, 8/16/32 vx/vy/vz,
//! 64/128/256 afx/afy/afz, 512 FORCE_SET (refused: PX4 has no force setpoint), 1024 yaw,
//! 2048 yaw_rate. A position axis given → position control on that axis (its velocity, if
//! given too, is ignored: the twin's target generator brakes on its own); else a velocity →
//! velocity control; else an acceleration → acceleration control. Frames: LOCAL_NED,
//! LOCAL_OFFSET_NED (position relative to the vehicle), BODY_NED (velocity and acceleration
//! rotated by the heading), BODY_OFFSET_NED (both). Every field used must be finite;
//! positions farther than [`MAX_POSITION_M`] from the origin are refused.
//!
//! **SET_ATTITUDE_TARGET** (82). type_mask bits 1/2/4 ignore a body rate, 32 THRUST_BODY_SET
//! (`thrust_body` instead of `thrust`), 64 THROTTLE_IGNORE (keep the last thrust), 128
//! ATTITUDE_IGNORE (body-rate control). Body rates are clamped to MC_ROLLRATE_MAX,
//! MC_PITCHRATE_MAX and MC_YAWRATE_MAX. The quaternion must be unit (within 1 %), every
//! used value finite, thrusts within [−1, 1] (f32 slack).

#![allow(
    deprecated,
    reason = "PX4 still serves the deprecated MISSION_ITEM, MISSION_REQUEST, MISSION_SET_CURRENT, frames and commands: so does the twin"
)]

use firmware_bridge::frames;
use mavlink::dialects::common::{
    AttitudeTargetTypemask, MavFrame, PositionTargetTypemask, SET_ATTITUDE_TARGET_DATA,
    SET_POSITION_TARGET_LOCAL_NED_DATA,
};
use nalgebra::{UnitQuaternion, Vector3};

/// Positions farther than this from the origin are refused, m.
pub const MAX_POSITION_M: f64 = 10_000.0;
/// Accelerations beyond this are clamped, m/s².
pub const MAX_ACCELERATION_MPS2: f64 = 20.0;
/// Slack on the [−1, 1] thrust range (f32 rounding at the limits).
const THRUST_SLACK: f64 = 1e-3;

/// A position-level setpoint in amstack's world frame; `None` = ignored by the type mask.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionTarget {
    /// Position per axis (x, y, z world), m.
    pub position_m: [Option<f64>; 3],
    /// Velocity (world), m/s, if every component is given.
    pub velocity_mps: Option<Vector3<f64>>,
    /// Acceleration (world), m/s², if every component is given.
    pub acceleration_mps2: Option<Vector3<f64>>,
    /// Heading (amstack yaw), rad.
    pub yaw_rad: Option<f64>,
    /// Heading rate (amstack: counter-clockwise, rad/s).
    pub yaw_rate_radps: Option<f64>,
}

impl PositionTarget {
    /// Whether any position axis is given.
    pub fn has_position(&self) -> bool {
        self.position_m.iter().any(Option::is_some)
    }
}

/// An attitude-level setpoint in amstack's frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AttitudeTarget {
    /// Attitude (+ body-rate feed-forward) with a body force.
    Attitude {
        /// Desired attitude `world_from_body`.
        world_from_body: UnitQuaternion<f64>,
        /// Body-rate feed-forward (FLU), rad/s, clamped.
        body_rates_radps: Vector3<f64>,
        /// Body force (FLU), N; `None`: thrust ignored (keep the last).
        force_in_body_n: Option<Vector3<f64>>,
    },
    /// Body rates only (attitude ignored) with a body force.
    Rates {
        /// Body rates (FLU), rad/s, clamped.
        body_rates_radps: Vector3<f64>,
        /// Body force (FLU), N; `None`: thrust ignored.
        force_in_body_n: Option<Vector3<f64>>,
    },
}

/// Rate limits (MC_*RATE_MAX), rad/s, roll/pitch/yaw (FRD axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLimits {
    /// Roll, rad/s.
    pub roll_radps: f64,
    /// Pitch, rad/s.
    pub pitch_radps: f64,
    /// Yaw, rad/s.
    pub yaw_radps: f64,
}

fn finite(v: f32, what: &str) -> Result<f64, String> {
    if v.is_finite() {
        Ok(f64::from(v))
    } else {
        Err(format!("{what} = {v} not finite"))
    }
}

/// SET_POSITION_TARGET_LOCAL_NED → a [`PositionTarget`], given the vehicle's position (world)
/// and heading (amstack yaw) for the offset and body frames.
pub fn position_target(
    s: &SET_POSITION_TARGET_LOCAL_NED_DATA,
    position_now_m: &Vector3<f64>,
    yaw_now_rad: f64,
) -> Result<PositionTarget, String> {
    let mask = s.type_mask;
    let ignored = |bit: PositionTargetTypemask| mask.contains(bit);
    if ignored(PositionTargetTypemask::POSITION_TARGET_TYPEMASK_FORCE_SET) {
        return Err("FORCE_SET: force setpoints are not supported (PX4 has none)".into());
    }
    let (offset, body) = match s.coordinate_frame {
        MavFrame::MAV_FRAME_LOCAL_NED => (false, false),
        MavFrame::MAV_FRAME_LOCAL_OFFSET_NED => (true, false),
        MavFrame::MAV_FRAME_BODY_NED => (false, true),
        MavFrame::MAV_FRAME_BODY_OFFSET_NED => (true, true),
        f => return Err(format!("frame {f:?} not supported")),
    };
    // NED heading of the body frames: velocity/acceleration (and body-offset positions) are
    // rotated by it.
    let psi_ned = frames::ned_yaw_from_world_yaw(yaw_now_rad);
    let rotate = |north: f64, east: f64| -> (f64, f64) {
        if body {
            let (s, c) = psi_ned.sin_cos();
            (c * north - s * east, s * north + c * east)
        } else {
            (north, east)
        }
    };
    use PositionTargetTypemask as M;
    let axis = |v: f32, bit: M, name: &str| -> Result<Option<f64>, String> {
        if ignored(bit) {
            Ok(None)
        } else {
            finite(v, name).map(Some)
        }
    };
    let (px, py, pz) = (
        axis(s.x, M::POSITION_TARGET_TYPEMASK_X_IGNORE, "x")?,
        axis(s.y, M::POSITION_TARGET_TYPEMASK_Y_IGNORE, "y")?,
        axis(s.z, M::POSITION_TARGET_TYPEMASK_Z_IGNORE, "z")?,
    );
    let mut position_m = [None; 3];
    if px.is_some() || py.is_some() || pz.is_some() {
        let now_ned = frames::ned_from_world(position_now_m);
        let (n, e) = rotate(px.unwrap_or(0.0), py.unwrap_or(0.0));
        let d = pz.unwrap_or(0.0);
        let base = if offset { now_ned } else { Vector3::zeros() };
        let ned = base + Vector3::new(n, e, d);
        let world = frames::world_from_ned(&ned);
        if !(world.iter().all(|x| x.is_finite()) && world.norm() <= MAX_POSITION_M) {
            return Err(format!("position {world:?} m beyond {MAX_POSITION_M} m"));
        }
        // NED x → world y, NED y → world x, NED z → world z; in a body frame x and y mix.
        position_m = [
            py.or(px.filter(|_| body)).map(|_| world.x),
            px.or(py.filter(|_| body)).map(|_| world.y),
            pz.map(|_| world.z),
        ];
    }
    let triple = |a: f32,
                  b: f32,
                  c: f32,
                  bits: [M; 3],
                  name: &str|
     -> Result<Option<Vector3<f64>>, String> {
        if bits.iter().all(|&bit| ignored(bit)) {
            return Ok(None);
        }
        let v = [a, b, c];
        let mut out = [0.0; 3];
        for (i, bit) in bits.iter().enumerate() {
            if !ignored(*bit) {
                out[i] = finite(v[i], name)?;
            }
        }
        let (n, e) = rotate(out[0], out[1]);
        Ok(Some(frames::world_from_ned(&Vector3::new(n, e, out[2]))))
    };
    let velocity_mps = triple(
        s.vx,
        s.vy,
        s.vz,
        [
            M::POSITION_TARGET_TYPEMASK_VX_IGNORE,
            M::POSITION_TARGET_TYPEMASK_VY_IGNORE,
            M::POSITION_TARGET_TYPEMASK_VZ_IGNORE,
        ],
        "velocity",
    )?;
    let acceleration_mps2 = triple(
        s.afx,
        s.afy,
        s.afz,
        [
            M::POSITION_TARGET_TYPEMASK_AX_IGNORE,
            M::POSITION_TARGET_TYPEMASK_AY_IGNORE,
            M::POSITION_TARGET_TYPEMASK_AZ_IGNORE,
        ],
        "acceleration",
    )?
    .map(|a| {
        let n = a.norm();
        if n > MAX_ACCELERATION_MPS2 {
            a * (MAX_ACCELERATION_MPS2 / n)
        } else {
            a
        }
    });
    let yaw_rad = if ignored(M::POSITION_TARGET_TYPEMASK_YAW_IGNORE) {
        None
    } else {
        Some(frames::world_yaw_from_ned_yaw(finite(s.yaw, "yaw")?))
    };
    let yaw_rate_radps = if ignored(M::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE) {
        None
    } else {
        // NED yaw rate is clockwise seen from above: amstack's is its negative.
        Some(-finite(s.yaw_rate, "yaw_rate")?)
    };
    let target = PositionTarget {
        position_m,
        velocity_mps,
        acceleration_mps2,
        yaw_rad,
        yaw_rate_radps,
    };
    if !target.has_position() && velocity_mps.is_none() && acceleration_mps2.is_none() {
        return Err("type_mask ignores position, velocity and acceleration".into());
    }
    Ok(target)
}

/// SET_ATTITUDE_TARGET → an [`AttitudeTarget`]; `force_scale_n` maps a unit thrust to newtons
/// (rotor count × T_max).
pub fn attitude_target(
    s: &SET_ATTITUDE_TARGET_DATA,
    limits: &RateLimits,
    force_scale_n: f64,
) -> Result<AttitudeTarget, String> {
    use AttitudeTargetTypemask as M;
    let mask = s.type_mask;
    let rate = |v: f32, bit: M, name: &str| -> Result<f64, String> {
        if mask.contains(bit) {
            Ok(0.0)
        } else {
            finite(v, name)
        }
    };
    let rates_frd = Vector3::new(
        rate(
            s.body_roll_rate,
            M::ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE,
            "body_roll_rate",
        )?
        .clamp(-limits.roll_radps, limits.roll_radps),
        rate(
            s.body_pitch_rate,
            M::ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE,
            "body_pitch_rate",
        )?
        .clamp(-limits.pitch_radps, limits.pitch_radps),
        rate(
            s.body_yaw_rate,
            M::ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
            "body_yaw_rate",
        )?
        .clamp(-limits.yaw_radps, limits.yaw_radps),
    );
    let force_in_body_n = if mask.contains(M::ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE) {
        None
    } else {
        let thrust_frd = if mask.contains(M::ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET) {
            Vector3::new(
                finite(s.thrust_body[0], "thrust_body[0]")?,
                finite(s.thrust_body[1], "thrust_body[1]")?,
                finite(s.thrust_body[2], "thrust_body[2]")?,
            )
        } else {
            Vector3::new(0.0, 0.0, -finite(s.thrust, "thrust")?)
        };
        if thrust_frd.iter().any(|t| t.abs() > 1.0 + THRUST_SLACK) {
            return Err(format!("thrust {thrust_frd:?} outside [-1, 1]"));
        }
        Some(frames::flu_from_frd(&thrust_frd.map(|t| t.clamp(-1.0, 1.0))) * force_scale_n)
    };
    let body_rates_radps = frames::flu_from_frd(&rates_frd);
    if mask.contains(M::ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE) {
        return Ok(AttitudeTarget::Rates {
            body_rates_radps,
            force_in_body_n,
        });
    }
    let Some(ned_from_frd) = frames::quaternion_from_mavlink(s.q) else {
        return Err(format!("q {:?} is not a unit quaternion", s.q));
    };
    Ok(AttitudeTarget::Attitude {
        world_from_body: frames::world_from_body_attitude(&ned_from_frd),
        body_rates_radps,
        force_in_body_n,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    fn limits() -> RateLimits {
        let r = 220f64.to_radians();
        RateLimits {
            roll_radps: r,
            pitch_radps: r,
            yaw_radps: 200f64.to_radians(),
        }
    }

    fn hover_q() -> [f32; 4] {
        // Level, facing north: NED←FRD identity.
        [1.0, 0.0, 0.0, 0.0]
    }

    #[test]
    fn body_rates_beyond_the_limits_are_clamped_and_non_finite_refused() {
        let s = SET_ATTITUDE_TARGET_DATA {
            q: hover_q(),
            body_roll_rate: 50.0,
            body_pitch_rate: -1e30,
            body_yaw_rate: 0.5,
            thrust: 0.5,
            type_mask: AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE,
            ..SET_ATTITUDE_TARGET_DATA::default()
        };
        let AttitudeTarget::Rates {
            body_rates_radps,
            force_in_body_n,
        } = attitude_target(&s, &limits(), 100.0).unwrap()
        else {
            panic!()
        };
        // FRD (50, −1e30, 0.5) → clamped → FLU (x, −y, −z).
        assert!((body_rates_radps.x - 220f64.to_radians()).abs() < 1e-12);
        assert!((body_rates_radps.y - 220f64.to_radians()).abs() < 1e-12);
        assert!((body_rates_radps.z + 0.5).abs() < 1e-7);
        assert_eq!(force_in_body_n, Some(Vector3::new(0.0, 0.0, 50.0)));
        let bad = SET_ATTITUDE_TARGET_DATA {
            body_yaw_rate: f32::NAN,
            ..s.clone()
        };
        assert!(attitude_target(&bad, &limits(), 100.0).is_err());
        // An ignored rate may be anything.
        let ignored = SET_ATTITUDE_TARGET_DATA {
            type_mask: s.type_mask
                | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
            ..bad
        };
        assert!(attitude_target(&ignored, &limits(), 100.0).is_ok());
    }

    #[test]
    fn thrust_body_needs_its_bit_and_the_ignore_bit_keeps_the_last_thrust() {
        let s = SET_ATTITUDE_TARGET_DATA {
            q: hover_q(),
            thrust: 0.4,
            thrust_body: [0.1, 0.0, -0.5],
            type_mask: AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET,
            ..SET_ATTITUDE_TARGET_DATA::default()
        };
        let AttitudeTarget::Attitude {
            force_in_body_n, ..
        } = attitude_target(&s, &limits(), 10.0).unwrap()
        else {
            panic!()
        };
        let f = force_in_body_n.unwrap();
        assert!((f - Vector3::new(1.0, 0.0, 5.0)).norm() < 1e-6, "{f}");
        let collective = SET_ATTITUDE_TARGET_DATA {
            type_mask: AttitudeTargetTypemask::empty(),
            ..s.clone()
        };
        let AttitudeTarget::Attitude {
            force_in_body_n, ..
        } = attitude_target(&collective, &limits(), 10.0).unwrap()
        else {
            panic!()
        };
        assert!((force_in_body_n.unwrap() - Vector3::new(0.0, 0.0, 4.0)).norm() < 1e-6);
        let keep = SET_ATTITUDE_TARGET_DATA {
            thrust: f32::NAN,
            type_mask: AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE,
            ..s
        };
        let AttitudeTarget::Attitude {
            force_in_body_n, ..
        } = attitude_target(&keep, &limits(), 10.0).unwrap()
        else {
            panic!()
        };
        assert_eq!(force_in_body_n, None);
    }

    #[test]
    fn position_targets_follow_the_type_mask_and_frames() {
        use PositionTargetTypemask as M;
        let velocity_ignored = M::POSITION_TARGET_TYPEMASK_VX_IGNORE
            | M::POSITION_TARGET_TYPEMASK_VY_IGNORE
            | M::POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | M::POSITION_TARGET_TYPEMASK_AX_IGNORE
            | M::POSITION_TARGET_TYPEMASK_AY_IGNORE
            | M::POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | M::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE;
        let s = SET_POSITION_TARGET_LOCAL_NED_DATA {
            x: 1.0,
            y: 2.0,
            z: -3.0,
            vx: f32::NAN,
            yaw: 0.0,
            type_mask: velocity_ignored,
            coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
            ..SET_POSITION_TARGET_LOCAL_NED_DATA::default()
        };
        let t = position_target(&s, &Vector3::zeros(), 0.0).unwrap();
        // NED (1, 2, −3) → world (2, 1, 3); yaw 0 (north) → amstack π/2.
        assert_eq!(t.position_m, [Some(2.0), Some(1.0), Some(3.0)]);
        assert!((t.yaw_rad.unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(t.velocity_mps, None);
        // Velocity only, body frame, facing east (amstack yaw 0): body forward = east.
        let v = SET_POSITION_TARGET_LOCAL_NED_DATA {
            vx: 1.0,
            type_mask: M::POSITION_TARGET_TYPEMASK_X_IGNORE
                | M::POSITION_TARGET_TYPEMASK_Y_IGNORE
                | M::POSITION_TARGET_TYPEMASK_Z_IGNORE
                | M::POSITION_TARGET_TYPEMASK_AX_IGNORE
                | M::POSITION_TARGET_TYPEMASK_AY_IGNORE
                | M::POSITION_TARGET_TYPEMASK_AZ_IGNORE
                | M::POSITION_TARGET_TYPEMASK_YAW_IGNORE
                | M::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE,
            coordinate_frame: MavFrame::MAV_FRAME_BODY_NED,
            ..SET_POSITION_TARGET_LOCAL_NED_DATA::default()
        };
        let t = position_target(&v, &Vector3::zeros(), 0.0).unwrap();
        let vel = t.velocity_mps.unwrap();
        assert!((vel - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12, "{vel}");
        // A used non-finite field, a huge position, FORCE_SET: refused.
        let nan = SET_POSITION_TARGET_LOCAL_NED_DATA {
            x: f32::NAN,
            ..s.clone()
        };
        assert!(position_target(&nan, &Vector3::zeros(), 0.0).is_err());
        let huge = SET_POSITION_TARGET_LOCAL_NED_DATA {
            x: 1e30,
            ..s.clone()
        };
        assert!(position_target(&huge, &Vector3::zeros(), 0.0).is_err());
        let force = SET_POSITION_TARGET_LOCAL_NED_DATA {
            type_mask: s.type_mask | M::POSITION_TARGET_TYPEMASK_FORCE_SET,
            ..s
        };
        assert!(position_target(&force, &Vector3::zeros(), 0.0).is_err());
    }

    #[test]
    fn the_bridges_position_setpoint_reads_back_as_sent() {
        // What the flight stack's bridge sends at the position level is read here as the same
        // world position and heading, and nothing else.
        let vehicle = platform::Vehicle::builtin("fa-hexa").unwrap();
        let codec = firmware_bridge::SetpointCodec::new(&vehicle, 1, 1).unwrap();
        let sent = platform::PositionSetpoint {
            position_in_world_m: Vector3::new(0.4, -0.7, 1.3),
            yaw_rad: -2.0,
        };
        let command = platform::ActuatorCommand {
            rotor_thrusts_n: Vec::new(),
            joint_targets: vehicle.initial_configuration(),
            direct_wrench_in_body: None,
        };
        let messages = codec.position_messages(0, &command, &sent).unwrap();
        let Some(mavlink::dialects::common::MavMessage::SET_POSITION_TARGET_LOCAL_NED(s)) =
            messages.last()
        else {
            panic!("{messages:?}");
        };
        let t = position_target(s, &Vector3::new(5.0, 5.0, 5.0), 1.0).unwrap();
        for (got, want) in t.position_m.iter().zip(sent.position_in_world_m.iter()) {
            assert!((got.unwrap() - want).abs() < 1e-6, "{:?}", t.position_m);
        }
        assert!((t.yaw_rad.unwrap() - sent.yaw_rad).abs() < 1e-6);
        assert_eq!(t.velocity_mps, None);
        assert_eq!(t.acceleration_mps2, None);
        assert_eq!(t.yaw_rate_radps, None);
    }
}
