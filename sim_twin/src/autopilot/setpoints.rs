//! The setpoints of the contract, decoded into amstack's commands:
//!
//! - SET_ACTUATOR_CONTROL_TARGET group 0: rotor i's normalised command u ∈ [0, 1] → thrust
//!   through the vehicle's thrust curve; group 1: tilt servo i, [−1, 1] linear over its joint
//!   limits; group 2: arm joints (command order) then the gripper (−1 closed, +1 open).
//!   Group 0 completes a control tick.
//! - SET_ATTITUDE_TARGET: attitude (NED←FRD), body thrust (FRD, normalised by rotor count ×
//!   T_max), body rates (FRD) → [`AttitudeSetpoint`] in world/FLU, through
//!   `firmware_bridge::frames`.
//!
//! A setpoint with a non-finite or out-of-range value is refused whole (the caller counts it);
//! values within range are clamped to their limits.

use firmware_bridge::frames;
use mavlink::dialects::common::{
    AttitudeTargetTypemask, SET_ACTUATOR_CONTROL_TARGET_DATA, SET_ATTITUDE_TARGET_DATA,
};
use nalgebra::Vector3;
use platform::{Gripper, ThrustCurve, Vehicle};

use super::control::AttitudeSetpoint;

/// Slack on the [−1, 1] and [0, 1] ranges before a control counts as out of range (f32
/// rounding of a sender at the limits).
const RANGE_SLACK: f32 = 1e-3;

/// One joint commanded over [−1, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
struct ScaledJoint {
    dof: usize,
    lower: f64,
    upper: f64,
}

impl ScaledJoint {
    fn position(&self, control: f32) -> f64 {
        let c = f64::from(control).clamp(-1.0, 1.0);
        self.lower + 0.5 * (c + 1.0) * (self.upper - self.lower)
    }
}

/// What a decoded actuator-control message did.
#[derive(Debug, Clone, PartialEq)]
pub enum ActuatorUpdate {
    /// Group 0: the rotor thrusts, N; a control tick is complete.
    Motors(Vec<f64>),
    /// Group 1 or 2: joint targets updated.
    Joints,
}

/// Decodes the contract's setpoints for one vehicle.
#[derive(Debug, Clone)]
pub struct SetpointDecoder {
    rotor_count: usize,
    thrust_curve: ThrustCurve,
    thrust_max_n: f64,
    tilts: Vec<ScaledJoint>,
    arm: Vec<ScaledJoint>,
    gripper: Option<(Gripper, Vec<usize>)>,
}

impl SetpointDecoder {
    /// The layout of `vehicle`'s groups.
    pub fn new(vehicle: &Vehicle) -> Self {
        let model = &vehicle.model;
        let joint = |j: usize| model.joints.get(j);
        let limits = |j: usize| {
            joint(j)
                .and_then(|jt| jt.limits)
                .map_or((-std::f64::consts::PI, std::f64::consts::PI), |l| {
                    (l.lower, l.upper)
                })
        };
        let tilts = vehicle
            .rotors
            .rotors
            .iter()
            .filter_map(|r| {
                let t = r.tilt.as_ref()?;
                let dof = model.joint_id(&t.joint).and_then(joint)?.dof?;
                Some(ScaledJoint {
                    dof,
                    lower: t.limits_rad.0,
                    upper: t.limits_rad.1,
                })
            })
            .collect();
        let arm = vehicle
            .arm_joints
            .iter()
            .filter_map(|&j| {
                let (lower, upper) = limits(j);
                Some(ScaledJoint {
                    dof: joint(j)?.dof?,
                    lower,
                    upper,
                })
            })
            .collect();
        let gripper = vehicle.gripper.as_ref().map(|g| {
            let dofs = g
                .joints
                .iter()
                .filter_map(|&j| joint(j).and_then(|jt| jt.dof))
                .collect();
            (g.clone(), dofs)
        });
        Self {
            rotor_count: vehicle.rotors.len(),
            thrust_curve: vehicle.rotors.thrust_curve,
            thrust_max_n: vehicle.rotors.thrust_max_n,
            tilts,
            arm,
            gripper,
        }
    }

    /// Whether the vehicle has tilt servos (group 1).
    pub fn has_tilts(&self) -> bool {
        !self.tilts.is_empty()
    }

    /// Decodes one SET_ACTUATOR_CONTROL_TARGET into `joint_targets` (configuration order) or
    /// rotor thrusts.
    pub fn actuator(
        &self,
        data: &SET_ACTUATOR_CONTROL_TARGET_DATA,
        joint_targets: &mut [f64],
    ) -> Result<ActuatorUpdate, String> {
        if let Some(c) = data.controls.iter().find(|c| !c.is_finite()) {
            return Err(format!("group {}: control {c} not finite", data.group_mlx));
        }
        match data.group_mlx {
            0 => {
                let controls = data.controls.get(..self.rotor_count).unwrap_or(&[]);
                if controls.len() != self.rotor_count {
                    return Err(format!(
                        "group 0: {} rotors do not fit 8 controls",
                        self.rotor_count
                    ));
                }
                if let Some(u) = controls
                    .iter()
                    .find(|&&u| !(-RANGE_SLACK..=1.0 + RANGE_SLACK).contains(&u))
                {
                    return Err(format!("group 0: motor command {u} outside [0, 1]"));
                }
                Ok(ActuatorUpdate::Motors(
                    controls
                        .iter()
                        .map(|&u| self.thrust_curve.thrust_n(f64::from(u)))
                        .collect(),
                ))
            }
            1 if self.has_tilts() => {
                self.scaled(&self.tilts, &data.controls, joint_targets)?;
                Ok(ActuatorUpdate::Joints)
            }
            2 => {
                self.scaled(&self.arm, &data.controls, joint_targets)?;
                if let Some((g, dofs)) = &self.gripper {
                    let c = data.controls.get(self.arm.len()).copied().unwrap_or(-1.0);
                    check_unit(c, 2)?;
                    for (&dof, q) in dofs.iter().zip(g.targets(f64::from(c))) {
                        if let Some(t) = joint_targets.get_mut(dof) {
                            *t = q;
                        }
                    }
                }
                Ok(ActuatorUpdate::Joints)
            }
            g => Err(format!("group {g}: not used by this vehicle")),
        }
    }

    fn scaled(
        &self,
        joints: &[ScaledJoint],
        controls: &[f32; 8],
        joint_targets: &mut [f64],
    ) -> Result<(), String> {
        for (j, &c) in joints.iter().zip(controls) {
            check_unit(c, 1)?;
            if let Some(t) = joint_targets.get_mut(j.dof) {
                *t = j.position(c);
            }
        }
        Ok(())
    }

    /// Decodes one SET_ATTITUDE_TARGET.
    pub fn attitude(&self, data: &SET_ATTITUDE_TARGET_DATA) -> Result<AttitudeSetpoint, String> {
        if data
            .type_mask
            .contains(AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE)
        {
            return Err("attitude ignored by type_mask: the twin needs an attitude".to_owned());
        }
        let ned_from_frd = frames::quaternion_from_mavlink(data.q)
            .ok_or_else(|| format!("q {:?} is not a unit quaternion", data.q))?;
        let mut thrust: Vector3<f64> =
            Vector3::from_iterator(data.thrust_body.iter().map(|&t| f64::from(t)));
        // A sender without the thrust_body extension (e.g. pymavlink's common dialect) gives
        // the collective `thrust` along body up, as PX4 takes it for a multicopter.
        if thrust == Vector3::zeros() && data.thrust != 0.0 {
            thrust = Vector3::new(0.0, 0.0, -f64::from(data.thrust));
        }
        if thrust
            .iter()
            .any(|t| !t.is_finite() || t.abs() > 1.0 + f64::from(RANGE_SLACK))
        {
            return Err(format!(
                "thrust_body {:?} (thrust {}) outside [-1, 1]",
                data.thrust_body, data.thrust
            ));
        }
        let mask = data.type_mask;
        let rate = |v: f32, bit: AttitudeTargetTypemask| {
            if mask.contains(bit) {
                0.0
            } else {
                f64::from(v)
            }
        };
        let rates_frd = Vector3::new(
            rate(
                data.body_roll_rate,
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE,
            ),
            rate(
                data.body_pitch_rate,
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE,
            ),
            rate(
                data.body_yaw_rate,
                AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
            ),
        );
        if rates_frd.iter().any(|r| !r.is_finite()) {
            return Err(format!("body rates {rates_frd:?} not finite"));
        }
        let scale = self.rotor_count as f64 * self.thrust_max_n;
        Ok(AttitudeSetpoint {
            world_from_body: frames::world_from_body_attitude(&ned_from_frd),
            force_in_body_n: frames::flu_from_frd(&thrust.map(|t| t.clamp(-1.0, 1.0))) * scale,
            rates_in_body_radps: frames::flu_from_frd(&rates_frd),
        })
    }
}

fn check_unit(c: f32, group: u8) -> Result<(), String> {
    if (-1.0 - RANGE_SLACK..=1.0 + RANGE_SLACK).contains(&c) {
        Ok(())
    } else {
        Err(format!("group {group}: control {c} outside [-1, 1]"))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn vehicle(id: &str) -> Vehicle {
        Vehicle::builtin(id).unwrap()
    }

    fn target(group: u8, controls: [f32; 8]) -> SET_ACTUATOR_CONTROL_TARGET_DATA {
        SET_ACTUATOR_CONTROL_TARGET_DATA {
            time_usec: 0,
            controls,
            group_mlx: group,
            target_system: 1,
            target_component: 1,
        }
    }

    #[test]
    fn motors_follow_the_thrust_curve() {
        let v = vehicle("fa-hexa");
        let d = SetpointDecoder::new(&v);
        let curve = v.rotors.thrust_curve;
        let mut q = v.initial_configuration();
        let controls = [0.0, 0.25, 0.5, 0.75, 1.0, 0.5, 0.0, 0.0];
        let ActuatorUpdate::Motors(t) = d.actuator(&target(0, controls), &mut q).unwrap() else {
            panic!("group 0 completes a tick");
        };
        assert_eq!(t.len(), 6);
        assert!((t[0] - curve.thrust_min_n).abs() < 1e-12);
        assert!((t[4] - curve.thrust_max_n).abs() < 1e-12);
        // Round trip through the inverse curve.
        assert!((curve.command(t[2]) - 0.5).abs() < 1e-6);
        assert!(d.actuator(&target(0, [1.5; 8]), &mut q).is_err());
        assert!(d.actuator(&target(0, [f32::NAN; 8]), &mut q).is_err());
    }

    #[test]
    fn arm_and_gripper_are_linear_over_their_limits() {
        let v = vehicle("fa-hexa");
        let d = SetpointDecoder::new(&v);
        let mut q = v.initial_configuration();
        // Arm joint 0 at −1 → its lower limit, joint 1 at +1 → its upper limit, the gripper
        // (after the arm's joints) at +1 → open.
        let n = v.arm_joints.len();
        let mut controls = [0.0f32; 8];
        controls[0] = -1.0;
        controls[1] = 1.0;
        controls[n] = 1.0;
        assert_eq!(
            d.actuator(&target(2, controls), &mut q).unwrap(),
            ActuatorUpdate::Joints
        );
        let j0 = &v.model.joints[v.arm_joints[0]];
        let j1 = &v.model.joints[v.arm_joints[1]];
        assert!((q[j0.dof.unwrap()] - j0.limits.unwrap().lower).abs() < 1e-9);
        assert!((q[j1.dof.unwrap()] - j1.limits.unwrap().upper).abs() < 1e-9);
        let g = v.gripper.as_ref().unwrap();
        for (k, &j) in g.joints.iter().enumerate() {
            assert!((q[v.model.joints[j].dof.unwrap()] - g.open[k]).abs() < 1e-9);
        }
        // fa-hexa has no tilt servos: group 1 is refused.
        assert!(d.actuator(&target(1, [0.0; 8]), &mut q).is_err());
    }

    #[test]
    fn omni_hexa_tilts_use_group_1() {
        let v = vehicle("omni-hexa");
        let d = SetpointDecoder::new(&v);
        assert!(d.has_tilts());
        let mut q = v.initial_configuration();
        d.actuator(&target(1, [1.0; 8]), &mut q).unwrap();
        let t = v.rotors.rotors[0].tilt.as_ref().unwrap();
        let dof = v.model.joints[v.model.joint_id(&t.joint).unwrap()]
            .dof
            .unwrap();
        assert!((q[dof] - t.limits_rad.1).abs() < 1e-9);
    }

    #[test]
    fn attitude_setpoint_converts_frames() {
        let v = vehicle("fa-hexa");
        let d = SetpointDecoder::new(&v);
        // PX4 level, facing north (identity NED←FRD) = amstack yaw +90°; thrust straight up
        // (FRD −z) at 0.5 of the vehicle's total → FLU +z.
        let data = SET_ATTITUDE_TARGET_DATA {
            time_boot_ms: 0,
            q: [1.0, 0.0, 0.0, 0.0],
            body_roll_rate: 0.1,
            body_pitch_rate: 0.0,
            body_yaw_rate: 0.0,
            thrust: 0.0,
            target_system: 1,
            target_component: 1,
            type_mask: AttitudeTargetTypemask::empty(),
            thrust_body: [0.0, 0.0, -0.5],
        };
        let sp = d.attitude(&data).unwrap();
        let north = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        assert!(sp.world_from_body.angle_to(&north) < 1e-6);
        let total = 6.0 * v.rotors.thrust_max_n;
        assert!((sp.force_in_body_n - Vector3::new(0.0, 0.0, 0.5 * total)).norm() < 1e-6);
        assert!((sp.rates_in_body_radps - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-6);
        let bad = SET_ATTITUDE_TARGET_DATA {
            q: [0.0; 4],
            ..data.clone()
        };
        assert!(d.attitude(&bad).is_err());
        // Without thrust_body, the collective thrust pushes along body up.
        let collective = SET_ATTITUDE_TARGET_DATA {
            thrust: 0.25,
            thrust_body: [0.0; 3],
            ..data.clone()
        };
        let sp = d.attitude(&collective).unwrap();
        assert!((sp.force_in_body_n - Vector3::new(0.0, 0.0, 0.25 * total)).norm() < 1e-6);
    }
}
