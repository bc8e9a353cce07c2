//! The PX4 HIL channel map of a vehicle: which entry of HIL_ACTUATOR_CONTROLS.controls[]
//! (PX4's simulated actuator outputs, channel i = PX4's `PWM_MAIN_FUNC{i+1}` output) drives
//! which rotor, tilt servo, arm joint and the gripper (`[px4_hil]` in the vehicle file).
//!
//! The values mean, as PX4 outputs them:
//!
//! ```text
//! motor (rotor i):          u ∈ [0, 1]   →  T = T_min + (k u² + (1 − k) u)(T_max − T_min)
//!                                            (the vehicle's ThrustCurve, k = THR_MDL_FAC)
//! tilt servo, arm joint j:  c ∈ [−1, 1]  →  q = lower + ½(c + 1)(upper − lower)  (joint limits)
//! gripper:                  c ∈ [−1, 1]  →  q = closed + ½(c + 1)(open − closed) per finger
//! ```
//!
//! The map is checked against the vehicle when it is assembled: one channel per rotor, one
//! per tilt hinge (variable-tilt vehicles only), one per arm joint, one for the gripper if
//! there is one; channels below [`PX4_HIL_CONTROLS`] and used once.

use serde::{Deserialize, Serialize};

use crate::error::{DescriptionError, Problem};

/// Entries of HIL_ACTUATOR_CONTROLS.controls.
pub const PX4_HIL_CONTROLS: usize = 16;

/// `[px4_hil]` as written in the vehicle file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Px4HilFile {
    /// Channel of each rotor, rotor order.
    pub motors: Vec<usize>,
    /// Channel of each rotor's tilt servo, rotor order (variable-tilt vehicles only).
    #[serde(default)]
    pub tilt_servos: Vec<usize>,
    /// Channel of each arm joint, `arm_joints` order.
    #[serde(default)]
    pub arm_joints: Vec<usize>,
    /// Channel of the gripper (vehicles with one).
    #[serde(default)]
    pub gripper: Option<usize>,
}

/// A vehicle's PX4 HIL channel map, checked.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Px4HilMap {
    /// Channel of each rotor, rotor order.
    pub motors: Vec<usize>,
    /// Channel of each rotor's tilt servo, rotor order (empty for fixed rotors).
    pub tilt_servos: Vec<usize>,
    /// Channel of each arm joint, arm command order.
    pub arm_joints: Vec<usize>,
    /// Channel of the gripper.
    pub gripper: Option<usize>,
}

/// What a map must fit: the vehicle's counts.
pub(crate) struct Fit {
    pub rotors: usize,
    pub tilts: usize,
    pub arm_joints: usize,
    pub gripper: bool,
}

impl Px4HilMap {
    /// Checks `f` against the vehicle (`fit`); errors name `file` and the field.
    pub(crate) fn check(file: &str, f: &Px4HilFile, fit: &Fit) -> Result<Self, DescriptionError> {
        let invalid = |field: &str, message: String| {
            DescriptionError::new(file, format!("px4_hil.{field}"), Problem::Invalid(message))
        };
        for (field, list, want, what) in [
            ("motors", &f.motors, fit.rotors, "rotors"),
            ("tilt_servos", &f.tilt_servos, fit.tilts, "tilt hinges"),
            ("arm_joints", &f.arm_joints, fit.arm_joints, "arm joints"),
        ] {
            if list.len() != want {
                return Err(invalid(
                    field,
                    format!("{} channels for {want} {what}", list.len()),
                ));
            }
        }
        match (f.gripper, fit.gripper) {
            (Some(_), false) => {
                return Err(invalid(
                    "gripper",
                    "given, but the vehicle has no gripper".to_owned(),
                ));
            }
            (None, true) => {
                return Err(invalid(
                    "gripper",
                    "missing: the vehicle has a gripper".to_owned(),
                ));
            }
            _ => {}
        }
        let mut used = [None::<&str>; PX4_HIL_CONTROLS];
        let all = f
            .motors
            .iter()
            .map(|c| ("motors", *c))
            .chain(f.tilt_servos.iter().map(|c| ("tilt_servos", *c)))
            .chain(f.arm_joints.iter().map(|c| ("arm_joints", *c)))
            .chain(f.gripper.iter().map(|c| ("gripper", *c)));
        for (field, channel) in all {
            let Some(slot) = used.get_mut(channel) else {
                return Err(invalid(
                    field,
                    format!(
                        "channel {channel} is beyond HIL_ACTUATOR_CONTROLS (0..{})",
                        PX4_HIL_CONTROLS - 1
                    ),
                ));
            };
            if let Some(other) = slot {
                return Err(invalid(
                    field,
                    format!("channel {channel} is already used by px4_hil.{other}"),
                ));
            }
            *slot = Some(field);
        }
        Ok(Self {
            motors: f.motors.clone(),
            tilt_servos: f.tilt_servos.clone(),
            arm_joints: f.arm_joints.clone(),
            gripper: f.gripper,
        })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use crate::{Vehicle, VehicleFile};

    const FA_HEXA: &str = include_str!("../vehicles/fa-hexa.toml");
    const FA_HEXA_URDF: &str = include_str!("../vehicles/fa-hexa.urdf");

    fn assemble(text: &str) -> Result<Vehicle, String> {
        let file = VehicleFile::parse("fa-hexa.toml", text).map_err(|e| e.to_string())?;
        Vehicle::assemble("fa-hexa.toml", &file, "fa-hexa.urdf", FA_HEXA_URDF)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn every_rotor_vehicle_has_a_channel_map_and_the_oracle_none() {
        for v in Vehicle::builtins().unwrap() {
            assert_eq!(v.px4_hil.is_some(), !v.rotors.is_empty(), "{}", v.id);
        }
        let fa = Vehicle::builtin("fa-hexa").unwrap().px4_hil.unwrap();
        assert_eq!(fa.motors, vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(fa.arm_joints, vec![6, 7, 8, 9]);
        assert_eq!(fa.gripper, Some(10));
        let omni = Vehicle::builtin("omni-hexa").unwrap().px4_hil.unwrap();
        assert_eq!(omni.tilt_servos, vec![6, 7, 8, 9, 10, 11]);
    }

    #[test]
    fn an_inconsistent_channel_map_is_one_line_naming_file_and_field() {
        let cases = [
            (
                "motors = [0, 1, 2, 3, 4, 5]",
                "motors = [0, 1, 2, 3, 4]",
                "fa-hexa.toml: px4_hil.motors: 5 channels for 6 rotors",
            ),
            (
                "gripper = 10",
                "gripper = 5",
                "fa-hexa.toml: px4_hil.gripper: channel 5 is already used by px4_hil.motors",
            ),
            (
                "gripper = 10",
                "gripper = 16",
                "fa-hexa.toml: px4_hil.gripper: channel 16 is beyond HIL_ACTUATOR_CONTROLS (0..15)",
            ),
            (
                "gripper = 10\n",
                "\n",
                "fa-hexa.toml: px4_hil.gripper: missing: the vehicle has a gripper",
            ),
            (
                "arm_joints = [6, 7, 8, 9]",
                "arm_joints = [6, 7, 8, 9]\ntilt_servos = [11, 12, 13, 14, 15, 0]",
                "fa-hexa.toml: px4_hil.tilt_servos: 6 channels for 0 tilt hinges",
            ),
        ];
        for (from, to, want) in cases {
            assert!(FA_HEXA.contains(from), "{from}");
            let err = assemble(&FA_HEXA.replacen(from, to, 1)).unwrap_err();
            assert_eq!(err, want);
            assert!(!err.contains('\n'));
        }
        let unknown = assemble(&FA_HEXA.replacen("gripper = 10", "grip = 10", 1)).unwrap_err();
        assert!(unknown.starts_with("fa-hexa.toml: line"), "{unknown}");
    }
}
