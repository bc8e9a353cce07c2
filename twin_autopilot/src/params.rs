//! The autopilot's parameters: a PX4-named, typed, range-checked set that changes what the
//! autopilot does, served over MAVLink's parameter protocol (PARAM_REQUEST_LIST,
//! PARAM_REQUEST_READ, PARAM_SET → PARAM_VALUE).
//!
//! Values travel as PX4 sends them: REAL32 as the float, INT32 *bytewise* (the integer's
//! four bytes in the float field, MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE). A set with
//! the wrong type, a non-finite or out-of-range value, or an enum value the twin does not
//! fly is refused: the reply is the parameter's current PARAM_VALUE and a STATUSTEXT saying
//! why. An unknown name gets PX4's answer: no PARAM_VALUE, a STATUSTEXT
//! `[pm] unknown param: NAME`.

use mavlink::dialects::common::{MavMessage, MavParamType, PARAM_VALUE_DATA};

/// One parameter of the set: its index in [`DEFS`] is its MAVLink `param_index`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Param {
    /// COM_OF_LOSS_T: offboard setpoints older than this are lost, s.
    ComOfLossT,
    /// COM_OBL_RC_ACT: what the offboard-loss failsafe does (0 Position, 3 Return, 4 Land,
    /// 5 Hold then land).
    ComOblRcAct,
    /// MPC_XY_VEL_MAX: horizontal speed limit of every position-controlled mode, m/s.
    MpcXyVelMax,
    /// MPC_XY_CRUISE: horizontal speed of missions, reposition and RTL, m/s.
    MpcXyCruise,
    /// MPC_Z_VEL_MAX_UP: climb rate limit, m/s.
    MpcZVelMaxUp,
    /// MPC_Z_VEL_MAX_DN: descent rate limit, m/s.
    MpcZVelMaxDn,
    /// MPC_TKO_SPEED: takeoff climb rate, m/s.
    MpcTkoSpeed,
    /// MPC_LAND_SPEED: landing descent rate, m/s.
    MpcLandSpeed,
    /// MPC_ACC_HOR: horizontal acceleration limit of the position target, m/s².
    MpcAccHor,
    /// MPC_ACC_UP_MAX: upward acceleration limit of the position target, m/s².
    MpcAccUpMax,
    /// MPC_ACC_DOWN_MAX: downward acceleration limit of the position target, m/s².
    MpcAccDownMax,
    /// MIS_TAKEOFF_ALT: takeoff altitude above home, m.
    MisTakeoffAlt,
    /// NAV_ACC_RAD: waypoint acceptance radius when a mission item gives none, m.
    NavAccRad,
    /// RTL_RETURN_ALT: RTL climbs to at least this altitude above home before returning, m.
    RtlReturnAlt,
    /// MC_ROLLRATE_MAX: roll rate limit of offboard rates, deg/s.
    McRollrateMax,
    /// MC_PITCHRATE_MAX: pitch rate limit, deg/s.
    McPitchrateMax,
    /// MC_YAWRATE_MAX: yaw rate limit, deg/s.
    McYawrateMax,
}

/// A parameter's MAVLink type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// MAV_PARAM_TYPE_REAL32.
    Real32,
    /// MAV_PARAM_TYPE_INT32 (bytewise).
    Int32,
}

/// A parameter's definition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Def {
    /// Which.
    pub param: Param,
    /// PX4's name (≤ 16 characters).
    pub name: &'static str,
    /// Type.
    pub kind: Kind,
    /// The twin's default.
    pub default: f64,
    /// PX4's default (where the twin's differs, `docs/mavlink.md` says why).
    pub px4_default: f64,
    /// Smallest value accepted.
    pub min: f64,
    /// Largest value accepted.
    pub max: f64,
    /// For an enum: the values the twin flies (others are refused).
    pub allowed: Option<&'static [i32]>,
}

const fn real(param: Param, name: &'static str, default: f64, px4: f64, min: f64, max: f64) -> Def {
    Def {
        param,
        name,
        kind: Kind::Real32,
        default,
        px4_default: px4,
        min,
        max,
        allowed: None,
    }
}

/// Every parameter, in `param_index` order. The twin's defaults depart from PX4's where its
/// vehicles need it (`docs/mavlink.md`): the speeds and accelerations of the position target
/// are gentler (PX4's multicopter defaults, 3 m/s² and 12 m/s, swing the FA-Hexa's arm until
/// its PID loses the attitude: measured, a 0.6 m offboard move at 3 m/s² diverges, at 1 m/s²
/// it settles level); NAV_ACC_RAD and RTL_RETURN_ALT fit scenes a few metres across;
/// COM_OF_LOSS_T is `--offboard-timeout-ms`; COM_OBL_RC_ACT keeps the twin's hold-then-land.
pub const DEFS: [Def; 17] = [
    real(Param::ComOfLossT, "COM_OF_LOSS_T", 0.5, 1.0, 0.01, 60.0),
    Def {
        param: Param::ComOblRcAct,
        name: "COM_OBL_RC_ACT",
        kind: Kind::Int32,
        default: 5.0,
        px4_default: 0.0,
        min: 0.0,
        max: 7.0,
        allowed: Some(&[0, 3, 4, 5]),
    },
    real(Param::MpcXyVelMax, "MPC_XY_VEL_MAX", 2.0, 12.0, 0.1, 20.0),
    real(Param::MpcXyCruise, "MPC_XY_CRUISE", 1.0, 5.0, 0.1, 20.0),
    real(Param::MpcZVelMaxUp, "MPC_Z_VEL_MAX_UP", 1.0, 3.0, 0.5, 8.0),
    real(Param::MpcZVelMaxDn, "MPC_Z_VEL_MAX_DN", 1.0, 1.5, 0.5, 4.0),
    real(Param::MpcTkoSpeed, "MPC_TKO_SPEED", 1.0, 1.5, 0.1, 5.0),
    real(Param::MpcLandSpeed, "MPC_LAND_SPEED", 0.5, 0.7, 0.1, 4.0),
    real(Param::MpcAccHor, "MPC_ACC_HOR", 1.0, 3.0, 0.5, 15.0),
    real(Param::MpcAccUpMax, "MPC_ACC_UP_MAX", 1.0, 4.0, 0.5, 15.0),
    real(
        Param::MpcAccDownMax,
        "MPC_ACC_DOWN_MAX",
        1.0,
        3.0,
        0.5,
        15.0,
    ),
    real(Param::MisTakeoffAlt, "MIS_TAKEOFF_ALT", 2.5, 2.5, 0.0, 80.0),
    real(Param::NavAccRad, "NAV_ACC_RAD", 0.2, 10.0, 0.05, 200.0),
    real(Param::RtlReturnAlt, "RTL_RETURN_ALT", 3.0, 60.0, 0.0, 150.0),
    real(
        Param::McRollrateMax,
        "MC_ROLLRATE_MAX",
        220.0,
        220.0,
        0.0,
        1800.0,
    ),
    real(
        Param::McPitchrateMax,
        "MC_PITCHRATE_MAX",
        220.0,
        220.0,
        0.0,
        1800.0,
    ),
    real(
        Param::McYawrateMax,
        "MC_YAWRATE_MAX",
        200.0,
        200.0,
        0.0,
        1800.0,
    ),
];

/// Why a PARAM_SET was refused (the STATUSTEXT, ≤ 50 characters where possible).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    /// No such parameter (PX4's wording).
    #[error("[pm] unknown param: {0}")]
    Unknown(String),
    /// Sent with another type than the parameter's.
    #[error("{name}: is {want}, sent as {got}")]
    WrongType {
        /// Parameter.
        name: &'static str,
        /// Its type.
        want: &'static str,
        /// The type sent.
        got: String,
    },
    /// NaN or infinite.
    #[error("{0}: value not finite")]
    NotFinite(&'static str),
    /// Outside the accepted range.
    #[error("{name}: {value} outside [{min}, {max}]")]
    OutOfRange {
        /// Parameter.
        name: &'static str,
        /// Value sent.
        value: String,
        /// Minimum.
        min: f64,
        /// Maximum.
        max: f64,
    },
    /// An enum value the twin does not fly.
    #[error("{name}: {value} not supported (use {allowed})")]
    NotSupported {
        /// Parameter.
        name: &'static str,
        /// Value sent.
        value: i32,
        /// The supported values.
        allowed: String,
    },
}

/// The current values.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    values: [f64; DEFS.len()],
}

impl Default for Params {
    fn default() -> Self {
        Self {
            values: DEFS.map(|d| d.default),
        }
    }
}

fn kind_name(kind: Kind) -> &'static str {
    match kind {
        Kind::Real32 => "REAL32",
        Kind::Int32 => "INT32",
    }
}

/// A NUL-padded 16-byte name.
fn id_bytes(name: &str) -> [u8; 16] {
    let mut out = [0u8; 16];
    for (o, b) in out.iter_mut().zip(name.bytes()) {
        *o = b;
    }
    out
}

/// The name in a PARAM_* `param_id` (up to the first NUL, 16 bytes at most).
pub fn name_of(id: &[u8]) -> String {
    let end = id.iter().position(|&b| b == 0).unwrap_or(id.len());
    String::from_utf8_lossy(id.get(..end).unwrap_or(&[])).into_owned()
}

impl Params {
    /// The value of `param` (an INT32 as its integer value).
    pub fn get(&self, param: Param) -> f64 {
        self.values[param as usize]
    }

    /// Sets `param` from code (a command-line flag), range-checked.
    pub fn set(&mut self, param: Param, value: f64) -> Result<(), ParamError> {
        let index = param as usize;
        Self::check(&DEFS[index], value)?;
        self.values[index] = value;
        Ok(())
    }

    /// The number of parameters.
    pub fn count(&self) -> usize {
        DEFS.len()
    }

    /// The index of the parameter named `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        DEFS.iter().position(|d| d.name == name)
    }

    fn check(def: &Def, value: f64) -> Result<(), ParamError> {
        if !value.is_finite() {
            return Err(ParamError::NotFinite(def.name));
        }
        if !(def.min..=def.max).contains(&value) {
            return Err(ParamError::OutOfRange {
                name: def.name,
                value: format!("{value}"),
                min: def.min,
                max: def.max,
            });
        }
        if let Some(allowed) = def.allowed {
            // An INT32 value: integral by construction (decoded from its bytes).
            #[allow(clippy::cast_possible_truncation)]
            let v = value as i32;
            if !allowed.contains(&v) {
                return Err(ParamError::NotSupported {
                    name: def.name,
                    value: v,
                    allowed: allowed
                        .iter()
                        .map(ToString::to_string)
                        .collect::<Vec<_>>()
                        .join(", "),
                });
            }
        }
        Ok(())
    }

    /// PARAM_SET: `name`, the float field as sent, and its type. On success the parameter's
    /// index; a refusal names why (the caller answers with the current value, or for an
    /// unknown name with nothing but the STATUSTEXT).
    pub fn set_from_mavlink(
        &mut self,
        name: &str,
        value: f32,
        kind: MavParamType,
    ) -> Result<usize, (Option<usize>, ParamError)> {
        let Some(index) = self.index_of(name) else {
            return Err((None, ParamError::Unknown(name.to_owned())));
        };
        let def = &DEFS[index];
        let decoded = match (def.kind, kind) {
            (Kind::Real32, MavParamType::MAV_PARAM_TYPE_REAL32) => f64::from(value),
            (Kind::Int32, MavParamType::MAV_PARAM_TYPE_INT32) => {
                f64::from(i32::from_le_bytes(value.to_le_bytes()))
            }
            (want, got) => {
                return Err((
                    Some(index),
                    ParamError::WrongType {
                        name: def.name,
                        want: kind_name(want),
                        got: format!("{got:?}").replace("MAV_PARAM_TYPE_", ""),
                    },
                ));
            }
        };
        Self::check(def, decoded).map_err(|e| (Some(index), e))?;
        self.values[index] = decoded;
        Ok(index)
    }

    /// PARAM_VALUE of the parameter at `index` (None beyond the set).
    pub fn value_message(&self, index: usize) -> Option<MavMessage> {
        let def = DEFS.get(index)?;
        let value = self.values[index];
        // MAVLink carries f32 (or an i32's bytes); the narrowing is the protocol's.
        #[allow(clippy::cast_possible_truncation)]
        let (param_value, param_type) = match def.kind {
            Kind::Real32 => (value as f32, MavParamType::MAV_PARAM_TYPE_REAL32),
            Kind::Int32 => (
                f32::from_le_bytes((value as i32).to_le_bytes()),
                MavParamType::MAV_PARAM_TYPE_INT32,
            ),
        };
        Some(MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value,
            param_count: u16::try_from(DEFS.len()).unwrap_or(u16::MAX),
            param_index: u16::try_from(index).unwrap_or(u16::MAX),
            param_id: id_bytes(def.name).into(),
            param_type,
        }))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    #[test]
    fn indices_match_the_enum_and_names_fit() {
        for (i, d) in DEFS.iter().enumerate() {
            assert_eq!(d.param as usize, i, "{}", d.name);
            assert!(d.name.len() <= 16, "{}", d.name);
            assert!((d.min..=d.max).contains(&d.default), "{}", d.name);
        }
    }

    #[test]
    fn sets_are_typed_and_range_checked() {
        let mut p = Params::default();
        let i = p
            .set_from_mavlink("COM_OF_LOSS_T", 2.0, MavParamType::MAV_PARAM_TYPE_REAL32)
            .unwrap();
        assert_eq!(p.get(Param::ComOfLossT), 2.0);
        let MavMessage::PARAM_VALUE(v) = p.value_message(i).unwrap() else {
            panic!()
        };
        assert_eq!(v.param_value, 2.0);
        assert_eq!(name_of(&v.param_id.to_vec()), "COM_OF_LOSS_T");
        // INT32 bytewise.
        let four = f32::from_le_bytes(4i32.to_le_bytes());
        p.set_from_mavlink("COM_OBL_RC_ACT", four, MavParamType::MAV_PARAM_TYPE_INT32)
            .unwrap();
        assert_eq!(p.get(Param::ComOblRcAct), 4.0);
        let refused = |r: Result<usize, (Option<usize>, ParamError)>| r.unwrap_err().1;
        assert!(matches!(
            refused(p.set_from_mavlink("COM_OBL_RC_ACT", 4.0, MavParamType::MAV_PARAM_TYPE_REAL32)),
            ParamError::WrongType { .. }
        ));
        let one = f32::from_le_bytes(1i32.to_le_bytes());
        assert!(matches!(
            refused(p.set_from_mavlink("COM_OBL_RC_ACT", one, MavParamType::MAV_PARAM_TYPE_INT32)),
            ParamError::NotSupported { .. }
        ));
        assert!(matches!(
            refused(p.set_from_mavlink(
                "MPC_XY_VEL_MAX",
                1e30,
                MavParamType::MAV_PARAM_TYPE_REAL32
            )),
            ParamError::OutOfRange { .. }
        ));
        assert!(matches!(
            refused(p.set_from_mavlink(
                "MPC_XY_VEL_MAX",
                f32::NAN,
                MavParamType::MAV_PARAM_TYPE_REAL32
            )),
            ParamError::NotFinite(_)
        ));
        let (index, e) = p
            .set_from_mavlink("NO_SUCH", 1.0, MavParamType::MAV_PARAM_TYPE_REAL32)
            .unwrap_err();
        assert_eq!(
            (index, e.to_string()),
            (None, "[pm] unknown param: NO_SUCH".to_owned())
        );
        assert_eq!(p.get(Param::MpcXyVelMax), 2.0, "unchanged by refusals");
    }
}
