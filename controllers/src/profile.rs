//! The reference's controller for each vehicle (AMBENCH_SPEC §2.1 profiles).

use platform::{Actuation, Vehicle};
use serde::{Deserialize, Serialize};

use crate::controller::{BaseController, BodyParams};
use crate::gains::{ConfigError, ControllerConfig, L1Config, Pid4Gains, Pid6Gains};
use crate::{L1Adaptive, Pid4, Pid6};

/// Which family of base controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ControllerKind {
    /// Geometric PID (6-DoF or nested 4-DoF by actuation).
    Pid,
    /// L1 adaptive on the PID baseline (fully actuated vehicles and the EE-only oracle).
    L1,
    /// Whole-body NMPC (FA-Hexa only, end-effector interface).
    Mpc,
}

/// The controller and gains of `kind` for `vehicle`, from the presets its vehicle file
/// names (`[control]`): the reference's profiles (AMBENCH_SPEC §2.1) are
///
/// | preset | controller |
/// |---|---|
/// | `pid6-am-bench` | PID6 `_PID6_GAINS` (EE-only, FA-Hexa) |
/// | `pid6-omni` | PID6 `_OMNI_PID6_GAINS` (Omni-Hexa) |
/// | `pid4-ua-hexa` | PID4 `_PID4_GAINS` (UA-Hexa) |
/// | `pid4-ua-quad` | PID4 `_QUAD_PID4_GAINS` (UA-Quad) |
/// | `l1-am-bench`, `l1-omni` | L1 from the PID6 gains above |
/// | `mpc-fa-hexa` | the FA-Hexa's whole-body MPC (`_MPC_PARAMS`) |
///
/// A kind the vehicle names no preset for is refused, saying why.
pub fn profile(vehicle: &Vehicle, kind: ControllerKind) -> Result<ControllerConfig, ConfigError> {
    let c = &vehicle.control;
    let unknown = |field: &str, name: &str| {
        ConfigError::Unsupported(format!(
            "{}: [control] {field} = \"{name}\" is not a preset (known: {})",
            vehicle.id,
            match field {
                "pid" => "pid6-am-bench, pid6-omni, pid4-ua-hexa, pid4-ua-quad",
                "l1" => "l1-am-bench, l1-omni",
                _ => "mpc-fa-hexa",
            }
        ))
    };
    match kind {
        ControllerKind::Pid => match c.pid.as_str() {
            "pid6-am-bench" => Ok(ControllerConfig::Pid6(Pid6Gains::am_bench())),
            "pid6-omni" => Ok(ControllerConfig::Pid6(Pid6Gains::omni())),
            "pid4-ua-hexa" => Ok(ControllerConfig::Pid4(Pid4Gains::ua_hexa())),
            "pid4-ua-quad" => Ok(ControllerConfig::Pid4(Pid4Gains::ua_quad())),
            other => Err(unknown("pid", other)),
        },
        ControllerKind::L1 => match c.l1.as_deref() {
            Some("l1-am-bench") => Ok(ControllerConfig::L1(L1Config::am_bench())),
            Some("l1-omni") => Ok(ControllerConfig::L1(L1Config::omni())),
            Some(other) => Err(unknown("l1", other)),
            None if vehicle.actuation == Actuation::UnderActuated => {
                Err(ConfigError::Unsupported(format!(
                    "{}: L1 needs a fully actuated vehicle (it adapts a 6-DoF wrench); use pid",
                    vehicle.id
                )))
            }
            None => Err(ConfigError::Unsupported(format!(
                "{}: its vehicle file's [control] names no l1 preset; use pid",
                vehicle.id
            ))),
        },
        ControllerKind::Mpc => match c.mpc.as_deref() {
            Some("mpc-fa-hexa") => Ok(ControllerConfig::Mpc(crate::mpc::MpcConfig::fa_hexa())),
            Some(other) => Err(unknown("mpc", other)),
            None => Err(ConfigError::Unsupported(format!(
                "{}: the whole-body MPC is the FA-Hexa's (a fully actuated base with a 4-joint arm); use pid or l1",
                vehicle.id
            ))),
        },
    }
}

/// A base controller from a validated config, for a body with `body` mass properties.
pub fn build(
    config: &ControllerConfig,
    body: BodyParams,
) -> Result<Box<dyn BaseController>, ConfigError> {
    config.validate()?;
    Ok(match config {
        ControllerConfig::Pid6(g) => Box::new(Pid6::new(*g, body)),
        ControllerConfig::Pid4(g) => Box::new(Pid4::new(*g, body)),
        ControllerConfig::L1(c) => Box::new(L1Adaptive::new(*c, body)),
        ControllerConfig::Mpc(_) => {
            return Err(ConfigError::Unsupported(
                "mpc is a whole-body interface, not a base controller: the flight stack builds it"
                    .to_owned(),
            ));
        }
    })
}
