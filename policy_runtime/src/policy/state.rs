//! The observation state a policy sees (AMBENCH_SPEC §5.1, §7.1): named keys, each a fixed
//! number of values read from the measurement, resolved to joint indices once per flight.

use platform::{Measurement, Vehicle};

/// One key of the observation state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StateKey {
    /// End-effector link origin, world, m (3).
    EePos,
    /// End-effector link orientation, world, wxyz (4) — the link, not the command frame.
    EeQuat,
    /// Sum of the gripper joint positions, m (1).
    GripperWidth,
    /// Arm joint positions in command order, rad (n).
    ArmJointPos,
    /// Base link origin, world, m (3).
    BasePos,
    /// Base link orientation, world, wxyz (4).
    BaseQuat,
}

impl StateKey {
    /// Every key, in the order `--help` lists them.
    pub const ALL: [Self; 6] = [
        Self::EePos,
        Self::EeQuat,
        Self::GripperWidth,
        Self::ArmJointPos,
        Self::BasePos,
        Self::BaseQuat,
    ];

    /// The key's name (`ee_pos`, …).
    pub fn name(self) -> &'static str {
        match self {
            Self::EePos => "ee_pos",
            Self::EeQuat => "ee_quat",
            Self::GripperWidth => "gripper_width",
            Self::ArmJointPos => "arm_joint_pos",
            Self::BasePos => "base_pos",
            Self::BaseQuat => "base_quat",
        }
    }

    /// The key named `name`.
    pub fn parse(name: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| {
                format!(
                    "unknown state key {name:?} (valid: {})",
                    Self::ALL.map(Self::name).join(", ")
                )
            })
    }

    /// A comma-separated list of keys.
    pub fn parse_list(list: &str) -> Result<Vec<Self>, String> {
        let keys = list
            .split(',')
            .map(|k| Self::parse(k.trim()))
            .collect::<Result<Vec<_>, _>>()?;
        if keys.is_empty() {
            return Err("no state keys".to_owned());
        }
        Ok(keys)
    }

    /// The default state of the end-effector interface: [ee_pos, ee_quat, gripper_width].
    pub const EE_DEFAULT: [Self; 3] = [Self::EePos, Self::EeQuat, Self::GripperWidth];
    /// The default state of the base + joint interface:
    /// [base_pos, base_quat, arm_joint_pos, gripper_width].
    pub const BASE_JOINT_DEFAULT: [Self; 4] = [
        Self::BasePos,
        Self::BaseQuat,
        Self::ArmJointPos,
        Self::GripperWidth,
    ];
}

/// Reads the state keys of one vehicle from its measurements (joint indices resolved once).
#[derive(Debug, Clone)]
pub struct StateReader {
    arm_dofs: Vec<usize>,
    gripper_dofs: Vec<usize>,
}

impl StateReader {
    /// The reader for `vehicle`.
    pub fn new(vehicle: &Vehicle) -> Self {
        let gripper_dofs = vehicle
            .gripper
            .as_ref()
            .map(|g| {
                g.joints
                    .iter()
                    .filter_map(|&j| vehicle.model.joints.get(j).and_then(|j| j.dof))
                    .collect()
            })
            .unwrap_or_default();
        Self {
            arm_dofs: vehicle.arm_dofs(),
            gripper_dofs,
        }
    }

    /// Values of `key`.
    pub fn len(&self, key: StateKey) -> usize {
        match key {
            StateKey::EePos | StateKey::BasePos => 3,
            StateKey::EeQuat | StateKey::BaseQuat => 4,
            StateKey::GripperWidth => 1,
            StateKey::ArmJointPos => self.arm_dofs.len(),
        }
    }

    /// Appends the values of `key` in `m` to `out`.
    pub fn read(&self, key: StateKey, m: &Measurement, out: &mut Vec<f64>) {
        let joint = |d: &usize| m.joint_positions.get(*d).copied().unwrap_or(0.0);
        match key {
            StateKey::EePos => out.extend(m.world_from_ee.translation.vector.iter()),
            StateKey::EeQuat => out.extend(wxyz(&m.world_from_ee.rotation)),
            StateKey::BasePos => out.extend(m.base.position_in_world_m.iter()),
            StateKey::BaseQuat => out.extend(wxyz(&m.base.world_from_body)),
            StateKey::GripperWidth => out.push(self.gripper_dofs.iter().map(joint).sum()),
            StateKey::ArmJointPos => out.extend(self.arm_dofs.iter().map(joint)),
        }
    }

    /// The values of every key of `keys`, concatenated.
    pub fn vector(&self, keys: &[StateKey], m: &Measurement) -> Vec<f64> {
        let mut out = Vec::new();
        for &k in keys {
            self.read(k, m, &mut out);
        }
        out
    }

    /// The measured arm joint positions, command order.
    pub fn arm_joints(&self, m: &Measurement) -> Vec<f64> {
        let mut out = Vec::new();
        self.read(StateKey::ArmJointPos, m, &mut out);
        out
    }
}

/// A unit quaternion as w, x, y, z.
pub fn wxyz(q: &nalgebra::UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}
