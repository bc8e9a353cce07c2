//! What PX4 must be told about an amstack vehicle: its control-allocation geometry
//! (`CA_*`), the thrust curve, the hover thrust and the output functions of the HIL channels,
//! as an airframe-file snippet (`amstack px4-airframe --platform <id>`).
//!
//! From the vehicle file, per rotor i (PX4 numbers rotors from 0, outputs from 1):
//!
//! ```text
//! CA_ROTORi_PX/PY/PZ = FRD(r_i − c)       rotor centre about the centre of mass c at the
//!                                         initial joint configuration, body FRD, m
//! CA_ROTORi_AX/AY/AZ = FRD(d_i)           thrust direction (tilt 0), body FRD
//! CA_ROTORi_KM       = −s_i k_f           PX4: moment = CT p × a − CT KM a, so a reaction
//!                                         torque s_i k_f T d_i is KM = −s_i k_f (KM > 0: CCW)
//! CA_ROTORi_CT       = T_max − T_min      thrust of a full output, N (PX4 scales with it)
//! THR_MDL_FAC        = k                  the vehicle's thrust curve factor
//! MPC_THR_HOVER      = (m g / Σ d_z − T_min) / (T_max − T_min)   (linear in thrust)
//! PWM_MAIN_FUNC(n+1) = 101 + i            channel n = px4_hil.motors[i]: Motor i+1
//!                    = 201 + i            channel n = px4_hil.tilt_servos[i]: Servo i+1
//!                    = 301 + j            channel n = arm joint j, then the gripper:
//!                                         Offboard Actuator Set j+1 (MAV_CMD_DO_SET_ACTUATOR)
//! ```
//!
//! FRD(v) = (v_x, −v_y, −v_z) for amstack's FLU body. `CA_AIRFRAME` is 0 (Multirotor) for
//! the fixed-rotor vehicles (PX4's multirotor allocation takes any rotor axis; its position
//! controller commands thrust along −z only, so a fully actuated vehicle flies as a
//! multirotor); stock PX4's "Multirotor with Tilt" (8) handles at most 4 tilt servos, so the
//! Omni-Hexa's six hinges are listed as servos with a note, its rotors at tilt 0.

use std::fmt::Write as _;

use firmware_bridge::frames;
use nalgebra::Vector3;
use platform::Vehicle;

/// First PX4 output function of the motors (Motor 1).
pub const FUNCTION_MOTOR1: u32 = 101;
/// First PX4 output function of the servos (Servo 1).
pub const FUNCTION_SERVO1: u32 = 201;
/// First PX4 output function of the offboard actuator set (Offboard Actuator Set 1).
pub const FUNCTION_OFFBOARD1: u32 = 301;
/// PX4's motor, servo and offboard-actuator counts.
const MAX_MOTORS: usize = 8;
const MAX_SERVOS: usize = 8;
const MAX_OFFBOARD: usize = 6;
const MAX_TILTS: usize = 4;

/// One rotor as PX4's control allocation reads it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Px4Rotor {
    /// CA_ROTORi_PX/PY/PZ: position about the centre of mass, body FRD, m.
    pub position_frd_m: Vector3<f64>,
    /// CA_ROTORi_AX/AY/AZ: thrust direction, body FRD (unit).
    pub axis_frd: Vector3<f64>,
    /// CA_ROTORi_KM: moment ratio, m (> 0: CCW seen from above).
    pub km: f64,
    /// CA_ROTORi_CT: thrust of a full output, N.
    pub ct: f64,
}

/// A vehicle's PX4 airframe parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Px4Airframe {
    /// CA_AIRFRAME.
    pub ca_airframe: u32,
    /// The rotors, in rotor order.
    pub rotors: Vec<Px4Rotor>,
    /// THR_MDL_FAC.
    pub thrust_model_factor: f64,
    /// MPC_THR_HOVER (None when the rotors cannot hover the vehicle).
    pub hover_thrust: Option<f64>,
    /// (PWM_MAIN_FUNC index from 1, function, what it drives).
    pub outputs: Vec<(usize, u32, String)>,
    /// What stock PX4 cannot express for this vehicle.
    pub notes: Vec<String>,
}

/// The vehicle cannot be described to PX4.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct AirframeError(pub String);

impl Px4Airframe {
    /// The parameters of `vehicle`.
    pub fn of(vehicle: &Vehicle) -> Result<Self, AirframeError> {
        let layout = &vehicle.rotors;
        if layout.is_empty() {
            return Err(AirframeError(format!(
                "vehicle '{}' has no rotors: PX4 cannot fly it",
                vehicle.id
            )));
        }
        let mut notes = Vec::new();
        if layout.len() > MAX_MOTORS {
            return Err(AirframeError(format!(
                "vehicle '{}' has {} rotors; PX4's multirotor allocation takes at most {MAX_MOTORS}",
                vehicle.id,
                layout.len()
            )));
        }
        let com = vehicle
            .mass_properties(&vehicle.initial_configuration())
            .com_in_root_m;
        let span = layout.thrust_max_n - layout.thrust_min_n;
        let rotors = layout
            .rotors
            .iter()
            .map(|r| Px4Rotor {
                position_frd_m: frames::frd_from_flu(&(r.position_in_base - com)),
                axis_frd: frames::frd_from_flu(&r.axis_in_base.into_inner()),
                km: -r.spin.sign() * layout.reaction_torque_ratio_m,
                ct: span,
            })
            .collect();
        let tilts = vehicle.tilt_dofs().len();
        if tilts > 0 {
            notes.push(format!(
                "{tilts} tilt hinges: PX4's 'Multirotor with Tilt' (CA_AIRFRAME 8) takes at most {MAX_TILTS} tilt servos; the rotors are given at tilt 0 and the hinges as plain servos"
            ));
        }
        // PX4's thrust setpoint is linear in thrust (THR_MDL_FAC undoes the curve).
        let hover_thrust = vehicle
            .hover_thrust_per_rotor_n()
            .and_then(|t| (t <= layout.thrust_max_n).then(|| (t - layout.thrust_min_n) / span));
        let mut outputs = Vec::new();
        if let Some(map) = &vehicle.px4_hil {
            for (i, &ch) in map.motors.iter().enumerate() {
                outputs.push((
                    ch + 1,
                    FUNCTION_MOTOR1 + index(i),
                    format!("rotor {i} ({})", layout.rotors[i].link),
                ));
            }
            for (i, &ch) in map.tilt_servos.iter().enumerate() {
                if i < MAX_SERVOS {
                    outputs.push((
                        ch + 1,
                        FUNCTION_SERVO1 + index(i),
                        format!("tilt hinge of rotor {i}"),
                    ));
                }
            }
            let arm_names = vehicle
                .arm_joints
                .iter()
                .map(|&j| format!("arm joint {}", vehicle.model.joints[j].name));
            let actuators: Vec<(usize, String)> = map
                .arm_joints
                .iter()
                .copied()
                .zip(arm_names)
                .chain(map.gripper.map(|g| (g, "gripper".to_owned())))
                .collect();
            for (j, (ch, what)) in actuators.into_iter().enumerate() {
                if j < MAX_OFFBOARD {
                    outputs.push((ch + 1, FUNCTION_OFFBOARD1 + index(j), what));
                } else {
                    notes.push(format!(
                        "{what} (channel {ch}): PX4 has {MAX_OFFBOARD} offboard actuator functions; assign it by hand"
                    ));
                }
            }
            outputs.sort_by_key(|o| o.0);
        } else {
            notes.push("no [px4_hil] channel map: outputs not assigned".to_owned());
        }
        Ok(Self {
            ca_airframe: 0,
            rotors,
            thrust_model_factor: layout.thrust_curve.model_factor,
            hover_thrust,
            outputs,
            notes,
        })
    }

    /// As a PX4 airframe-file snippet (`param set-default` lines).
    pub fn snippet(&self, vehicle: &Vehicle) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# amstack {} ({}): PX4 airframe parameters",
            vehicle.name, vehicle.id
        );
        let _ = writeln!(
            s,
            "# from the vehicle file (amstack px4-airframe --platform {}); body frame FRD, rotor",
            vehicle.id
        );
        let _ = writeln!(
            s,
            "# positions about the centre of mass at the initial joint configuration, m; CT in N."
        );
        for n in &self.notes {
            let _ = writeln!(s, "# note: {n}");
        }
        let _ = writeln!(s, "param set-default CA_AIRFRAME {}", self.ca_airframe);
        let _ = writeln!(s, "param set-default CA_ROTOR_COUNT {}", self.rotors.len());
        for (i, r) in self.rotors.iter().enumerate() {
            for (name, v) in [
                ("PX", r.position_frd_m.x),
                ("PY", r.position_frd_m.y),
                ("PZ", r.position_frd_m.z),
                ("AX", r.axis_frd.x),
                ("AY", r.axis_frd.y),
                ("AZ", r.axis_frd.z),
                ("KM", r.km),
                ("CT", r.ct),
            ] {
                let _ = writeln!(s, "param set-default CA_ROTOR{i}_{name} {}", fmt4(v));
            }
        }
        let _ = writeln!(
            s,
            "param set-default THR_MDL_FAC {}",
            fmt4(self.thrust_model_factor)
        );
        if let Some(h) = self.hover_thrust {
            let _ = writeln!(s, "param set-default MPC_THR_HOVER {}", fmt4(h));
        }
        for (n, function, what) in &self.outputs {
            let _ = writeln!(s, "param set-default PWM_MAIN_FUNC{n} {function}  # {what}");
        }
        s
    }
}

/// A count onto a PX4 function offset (counts are at most 16).
fn index(i: usize) -> u32 {
    u32::try_from(i).unwrap_or(u32::MAX)
}

/// Four decimals, no negative zero.
fn fmt4(v: f64) -> String {
    let s = format!("{v:.4}");
    if s == "-0.0000" {
        "0.0000".to_owned()
    } else {
        s
    }
}
