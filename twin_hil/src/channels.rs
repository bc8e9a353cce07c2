//! HIL_ACTUATOR_CONTROLS → the twin's [`ActuatorCommand`], through the vehicle's channel map
//! (`[px4_hil]` of its vehicle file, [`platform::Px4HilMap`]):
//!
//! ```text
//! rotor i:        u = controls[motors[i]] ∈ [0, 1]   →  T_i = curve(u)   (ThrustCurve: T_min..T_max)
//! tilt hinge i:   c = controls[tilt_servos[i]]       →  α_i = lower + ½(c + 1)(upper − lower)
//! arm joint j:    c = controls[arm_joints[j]]        →  q_j = lower + ½(c + 1)(upper − lower)
//! gripper:        c = controls[gripper]              →  Gripper::targets(c) (−1 closed, +1 open)
//! ```
//!
//! Values are clamped to their ranges. A non-finite control (PX4 marks a disarmed output
//! NaN) is never applied: a motor reads 0 (minimum thrust), a servo or joint keeps its last
//! target; each one is counted. Disarmed (mode without MAV_MODE_FLAG_SAFETY_ARMED), PX4
//! sends zeros: rotors at minimum thrust, servos at mid-range, as its outputs would be.

use platform::{ActuatorCommand, Gripper, ThrustCurve, Vehicle};

/// A vehicle's channel map, compiled: configuration indices and ranges resolved once.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelMap {
    curve: ThrustCurve,
    motors: Vec<usize>,
    /// (channel, configuration index, lower, upper) of every tilt hinge and arm joint.
    servos: Vec<(usize, usize, f64, f64)>,
    /// (channel, the gripper, its configuration indices).
    gripper: Option<(usize, Gripper, Vec<usize>)>,
    dof: usize,
}

/// What mapping one HIL_ACTUATOR_CONTROLS did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Mapped {
    /// Mapped controls that were not finite (not applied).
    pub non_finite: u32,
}

/// The vehicle cannot be served to PX4 (its channel map is missing or does not fit).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct MapError(pub String);

fn joint_range(vehicle: &Vehicle, dof: usize, what: &str) -> Result<(f64, f64), MapError> {
    let joint = vehicle.model.dof_joint(dof);
    match joint.limits {
        Some(l) if l.lower.is_finite() && l.upper.is_finite() && l.upper > l.lower => {
            Ok((l.lower, l.upper))
        }
        _ => Err(MapError(format!(
            "vehicle '{}': px4_hil: {what} joint '{}' has no finite limits to map [-1, 1] onto",
            vehicle.id, joint.name
        ))),
    }
}

impl ChannelMap {
    /// The map of `vehicle`; an error naming the vehicle file's section when it has none.
    pub fn new(vehicle: &Vehicle) -> Result<Self, MapError> {
        let Some(map) = &vehicle.px4_hil else {
            return Err(MapError(format!(
                "vehicle '{}' ({}.toml): px4_hil: missing: PX4 HIL needs a [px4_hil] channel map (docs/px4-hil.md)",
                vehicle.id, vehicle.id
            )));
        };
        let tilt_dofs = vehicle.tilt_dofs();
        let arm_dofs = vehicle.arm_dofs();
        if tilt_dofs.len() != map.tilt_servos.len() || arm_dofs.len() != map.arm_joints.len() {
            return Err(MapError(format!(
                "vehicle '{}': px4_hil: the map does not fit the vehicle's joints",
                vehicle.id
            )));
        }
        let mut servos = Vec::new();
        for (&channel, &dof) in map.tilt_servos.iter().zip(&tilt_dofs) {
            let (lo, hi) = joint_range(vehicle, dof, "tilt")?;
            servos.push((channel, dof, lo, hi));
        }
        for (&channel, &dof) in map.arm_joints.iter().zip(&arm_dofs) {
            let (lo, hi) = joint_range(vehicle, dof, "arm")?;
            servos.push((channel, dof, lo, hi));
        }
        let gripper = match (map.gripper, &vehicle.gripper) {
            (Some(channel), Some(g)) => Some((
                channel,
                g.clone(),
                g.joints
                    .iter()
                    .filter_map(|&j| vehicle.model.joints[j].dof)
                    .collect(),
            )),
            _ => None,
        };
        Ok(Self {
            curve: vehicle.rotors.thrust_curve,
            motors: map.motors.clone(),
            servos,
            gripper,
            dof: vehicle.model.dof(),
        })
    }

    /// The command of `controls` on top of `previous` (its joint targets kept where a control
    /// is not finite). `previous` must have the vehicle's shape.
    pub fn command(
        &self,
        controls: &[f32; 16],
        previous: &ActuatorCommand,
    ) -> (ActuatorCommand, Mapped) {
        let mut mapped = Mapped::default();
        let mut control = |channel: usize| {
            let c = controls.get(channel).copied().map_or(f64::NAN, f64::from);
            if c.is_finite() {
                Some(c)
            } else {
                mapped.non_finite += 1;
                None
            }
        };
        let rotor_thrusts_n = self
            .motors
            .iter()
            .map(|&ch| self.curve.thrust_n(control(ch).unwrap_or(0.0)))
            .collect();
        let mut joint_targets = previous.joint_targets.clone();
        joint_targets.resize(self.dof, 0.0);
        for &(ch, dof, lo, hi) in &self.servos {
            if let (Some(c), Some(q)) = (control(ch), joint_targets.get_mut(dof)) {
                *q = lo + 0.5 * (c.clamp(-1.0, 1.0) + 1.0) * (hi - lo);
            }
        }
        if let Some((ch, gripper, dofs)) = &self.gripper
            && let Some(c) = control(*ch)
        {
            for (&dof, target) in dofs.iter().zip(gripper.targets(c)) {
                if let Some(q) = joint_targets.get_mut(dof) {
                    *q = target;
                }
            }
        }
        (
            ActuatorCommand {
                rotor_thrusts_n,
                joint_targets,
                direct_wrench_in_body: None,
            },
            mapped,
        )
    }

    /// The rotors' thrust curve.
    pub fn thrust_curve(&self) -> &ThrustCurve {
        &self.curve
    }
}
