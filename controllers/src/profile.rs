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

/// The reference profile's controller and gains for `vehicle`:
///
/// | vehicle | `pid` | `l1` |
/// |---|---|---|
/// | EE-only, FA-Hexa | PID6 `_PID6_GAINS` | L1 from those |
/// | Omni-Hexa | PID6 `_OMNI_PID6_GAINS` | L1 from those |
/// | UA-Hexa | PID4 `_PID4_GAINS` | — |
/// | UA-Quad | PID4 `_QUAD_PID4_GAINS` | — |
///
/// `mpc` is the reference's FA-Hexa profile (`_MPC_PARAMS`) and is refused for any other
/// vehicle.
pub fn profile(vehicle: &Vehicle, kind: ControllerKind) -> Result<ControllerConfig, ConfigError> {
    let omni = vehicle.id == "omni-hexa";
    match (vehicle.actuation, kind) {
        (_, ControllerKind::Mpc) if vehicle.id == "fa-hexa" => {
            Ok(ControllerConfig::Mpc(crate::mpc::MpcConfig::fa_hexa()))
        }
        (_, ControllerKind::Mpc) => Err(ConfigError::Unsupported(format!(
            "{}: the whole-body MPC is the FA-Hexa's (a fully actuated base with a 4-joint arm); use pid or l1",
            vehicle.id
        ))),
        (Actuation::UnderActuated, ControllerKind::Pid) => {
            Ok(ControllerConfig::Pid4(if vehicle.id == "ua-quad" {
                Pid4Gains::ua_quad()
            } else {
                Pid4Gains::ua_hexa()
            }))
        }
        (Actuation::UnderActuated, ControllerKind::L1) => Err(ConfigError::Unsupported(format!(
            "{}: L1 needs a fully actuated vehicle (it adapts a 6-DoF wrench); use pid",
            vehicle.id
        ))),
        (_, ControllerKind::Pid) => Ok(ControllerConfig::Pid6(if omni {
            Pid6Gains::omni()
        } else {
            Pid6Gains::am_bench()
        })),
        (_, ControllerKind::L1) => Ok(ControllerConfig::L1(if omni {
            L1Config::omni()
        } else {
            L1Config::am_bench()
        })),
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
