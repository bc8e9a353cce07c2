//! Gain profiles of the base controllers: typed, documented, with the reference's presets,
//! loadable from TOML with unknown keys refused (AMBENCH_SPEC §2.2–§2.4).
//!
//! Position and attitude gains multiply the mass and the inertia, so they are in 1/s²
//! (proportional), 1/s (derivative) and 1/s³ (integral).

use nalgebra::Vector3;
use serde::{Deserialize, Deserializer, Serialize};

/// A configuration that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// Not valid TOML, an unknown key, or a value of the wrong type.
    #[error("cannot parse controller config: {0}")]
    Parse(String),
    /// A value out of range.
    #[error("{field}: {message}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// What is wrong, with the value.
        message: String,
    },
    /// A controller the vehicle cannot use.
    #[error("{0}")]
    Unsupported(String),
}

fn invalid(field: &'static str, message: String) -> ConfigError {
    ConfigError::Invalid { field, message }
}

fn check_gain(field: &'static str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!("{v} must be finite and not negative"),
        ))
    }
}

fn check_limit(field: &'static str, v: Option<f64>) -> Result<(), ConfigError> {
    match v {
        Some(x) if !(x.is_finite() && x > 0.0) => Err(invalid(
            field,
            format!("{x} must be finite and positive (omit it for no limit)"),
        )),
        _ => Ok(()),
    }
}

/// Reads a 3-vector from a list of exactly three numbers (serde's fixed arrays would accept
/// and truncate a longer list).
fn vector3<'de, D: Deserializer<'de>>(d: D) -> Result<Vector3<f64>, D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    match v.as_slice() {
        [x, y, z] => Ok(Vector3::new(*x, *y, *z)),
        _ => Err(serde::de::Error::custom(format!(
            "{v:?} has {} values, needs 3",
            v.len()
        ))),
    }
}

/// Scales `v` onto the ball of radius `limit` (no-op without a limit).
pub(crate) fn limit_norm(v: Vector3<f64>, limit: Option<f64>) -> Vector3<f64> {
    match limit {
        Some(l) => v * (l / v.norm().max(1e-8)).min(1.0),
        None => v,
    }
}

/// Gains of the 6-DoF geometric PID.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Pid6Gains {
    /// Position P, 1/s². Default 100.
    pub kp_pos: f64,
    /// Position D, 1/s. Default 80.
    pub kd_pos: f64,
    /// Position I, 1/s³. Default 50.
    pub ki_pos: f64,
    /// Attitude P, 1/s². Default 300.
    pub kp_rot: f64,
    /// Attitude D, 1/s. Default 100.
    pub kd_rot: f64,
    /// Attitude I, 1/s³. Default 120.
    pub ki_rot: f64,
    /// Norm limit of the force, N. Default none.
    pub max_force_n: Option<f64>,
    /// Norm limit of the torque, N·m. Default none.
    pub max_torque_nm: Option<f64>,
    /// Norm limit of each integral state. Default none.
    pub integral_limit: Option<f64>,
}

impl Default for Pid6Gains {
    /// The reference class defaults (100, 80, 50, 300, 100, 120).
    fn default() -> Self {
        Self {
            kp_pos: 100.0,
            kd_pos: 80.0,
            ki_pos: 50.0,
            kp_rot: 300.0,
            kd_rot: 100.0,
            ki_rot: 120.0,
            max_force_n: None,
            max_torque_nm: None,
            integral_limit: None,
        }
    }
}

impl Pid6Gains {
    /// `_PID6_GAINS`: the EE-only oracle and the FA-Hexa (200, 120, 80, 200, 120, 120).
    pub fn am_bench() -> Self {
        Self {
            kp_pos: 200.0,
            kd_pos: 120.0,
            ki_pos: 80.0,
            kp_rot: 200.0,
            kd_rot: 120.0,
            ki_rot: 120.0,
            ..Self::default()
        }
    }

    /// `_OMNI_PID6_GAINS`: the Omni-Hexa (200, 120, 80, 240, 130, 130).
    pub fn omni() -> Self {
        Self {
            kp_rot: 240.0,
            kd_rot: 130.0,
            ki_rot: 130.0,
            ..Self::am_bench()
        }
    }

    /// Checks every gain and limit.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check_gain("kp_pos", self.kp_pos)?;
        check_gain("kd_pos", self.kd_pos)?;
        check_gain("ki_pos", self.ki_pos)?;
        check_gain("kp_rot", self.kp_rot)?;
        check_gain("kd_rot", self.kd_rot)?;
        check_gain("ki_rot", self.ki_rot)?;
        check_limit("max_force_n", self.max_force_n)?;
        check_limit("max_torque_nm", self.max_torque_nm)?;
        check_limit("integral_limit", self.integral_limit)
    }
}

/// Gains of the nested 4-DoF geometric PID (under-actuated vehicles).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Pid4Gains {
    /// Horizontal position P, 1/s². Default 10.
    pub kp_xy: f64,
    /// Vertical position P, 1/s². Default 30.
    pub kp_z: f64,
    /// Horizontal position D, 1/s. Default 8.
    pub kd_xy: f64,
    /// Vertical position D, 1/s. Default 10.
    pub kd_z: f64,
    /// Horizontal position I, 1/s³. Default 6.
    pub ki_xy: f64,
    /// Vertical position I, 1/s³. Default 10.
    pub ki_z: f64,
    /// Attitude P, 1/s². Default 200.
    pub kp_rot: f64,
    /// Attitude D, 1/s. Default 120.
    pub kd_rot: f64,
    /// Attitude I, 1/s³. Default 120.
    pub ki_rot: f64,
    /// The position loop runs every this many ticks (≥ 1). Default 3 (40 Hz at 120 Hz).
    pub outer_loop_decimation: u32,
    /// Limit of the thrust magnitude, N. Default none.
    pub max_force_n: Option<f64>,
    /// Norm limit of the torque, N·m. Default none.
    pub max_torque_nm: Option<f64>,
    /// Norm limit of each integral state. Default none.
    pub integral_limit: Option<f64>,
    /// Largest angle of the desired thrust direction from the vertical, rad: the position
    /// loop's horizontal demand is scaled down to it, its vertical part kept (PX4's
    /// MPC_TILTMAX_AIR, whose default this is). Default π/4 (45°). `None`, or any value of
    /// π/2 or more (`max_tilt_rad = 1.6` in a TOML gain table), for no limit, as the
    /// reference — whose UA-Hexa turned over in 24 of 60 rollouts of Lemon Harvesting and
    /// Wipe Window (README, departures).
    pub max_tilt_rad: Option<f64>,
}

impl Default for Pid4Gains {
    /// The reference class defaults, which are also `_PID4_GAINS` (UA-Hexa).
    fn default() -> Self {
        Self {
            kp_xy: 10.0,
            kp_z: 30.0,
            kd_xy: 8.0,
            kd_z: 10.0,
            ki_xy: 6.0,
            ki_z: 10.0,
            kp_rot: 200.0,
            kd_rot: 120.0,
            ki_rot: 120.0,
            outer_loop_decimation: 3,
            max_force_n: None,
            max_torque_nm: None,
            integral_limit: None,
            max_tilt_rad: Some(std::f64::consts::FRAC_PI_4),
        }
    }
}

impl Pid4Gains {
    /// `_PID4_GAINS`: the UA-Hexa.
    pub fn ua_hexa() -> Self {
        Self::default()
    }

    /// `_QUAD_PID4_GAINS`: the UA-Quad (attitude 150, 20, 20).
    pub fn ua_quad() -> Self {
        Self {
            kp_rot: 150.0,
            kd_rot: 20.0,
            ki_rot: 20.0,
            ..Self::default()
        }
    }

    /// Checks every gain and limit.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (field, v) in [
            ("kp_xy", self.kp_xy),
            ("kp_z", self.kp_z),
            ("kd_xy", self.kd_xy),
            ("kd_z", self.kd_z),
            ("ki_xy", self.ki_xy),
            ("ki_z", self.ki_z),
            ("kp_rot", self.kp_rot),
            ("kd_rot", self.kd_rot),
            ("ki_rot", self.ki_rot),
        ] {
            check_gain(field, v)?;
        }
        if self.outer_loop_decimation == 0 {
            return Err(invalid(
                "outer_loop_decimation",
                "0 must be at least 1".to_owned(),
            ));
        }
        check_limit("max_force_n", self.max_force_n)?;
        check_limit("max_torque_nm", self.max_torque_nm)?;
        check_limit("integral_limit", self.integral_limit)?;
        match self.max_tilt_rad {
            Some(t) if !(t.is_finite() && t > 0.0) => Err(invalid(
                "max_tilt_rad",
                format!("{t} must be finite and positive (π/2 or more for no limit)"),
            )),
            _ => Ok(()),
        }
    }
}

/// Configuration of the L1 adaptive controller.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct L1Config {
    /// Position P per world axis, 1/s². Default (8, 8, 8).
    #[serde(deserialize_with = "vector3")]
    pub k_pos: Vector3<f64>,
    /// Velocity D per world axis, 1/s. Default (5, 5, 5).
    #[serde(deserialize_with = "vector3")]
    pub k_vel: Vector3<f64>,
    /// Attitude P per body axis, 1/s². Default (10, 10, 10).
    #[serde(deserialize_with = "vector3")]
    pub k_ori: Vector3<f64>,
    /// Angular-rate D per body axis, 1/s. Default (10, 20, 5).
    #[serde(deserialize_with = "vector3")]
    pub k_ang_vel: Vector3<f64>,
    /// Diagonal of the (Hurwitz) linear predictor matrix A_v, 1/s. Default (−1, −1, −1).
    #[serde(deserialize_with = "vector3")]
    pub a_lin: Vector3<f64>,
    /// Diagonal of the angular predictor matrix A_ω, 1/s. Default (−0.65, −0.65, −0.65).
    #[serde(deserialize_with = "vector3")]
    pub a_ang: Vector3<f64>,
    /// Cut-off of the force estimate's low-pass filter, Hz. Default 0.75.
    pub filter_bandwidth_lin_hz: f64,
    /// Cut-off of the torque estimate's low-pass filter, Hz. Default 0.75.
    pub filter_bandwidth_ang_hz: f64,
    /// Norm bound of the raw force estimate, N. Default none.
    pub sigma_max_lin_n: Option<f64>,
    /// Norm bound of the raw torque estimate, N·m. Default none.
    pub sigma_max_ang_nm: Option<f64>,
    /// Share of the adaptive force added to the command (0 = baseline only). Default 1.
    pub adaptive_mix_lin: f64,
    /// Share of the adaptive torque added to the command. Default 1.
    pub adaptive_mix_ang: f64,
}

impl Default for L1Config {
    /// The reference class defaults (`L1AdaptiveGains`).
    fn default() -> Self {
        Self {
            k_pos: Vector3::repeat(8.0),
            k_vel: Vector3::repeat(5.0),
            k_ori: Vector3::repeat(10.0),
            k_ang_vel: Vector3::new(10.0, 20.0, 5.0),
            a_lin: Vector3::repeat(-1.0),
            a_ang: Vector3::repeat(-0.65),
            filter_bandwidth_lin_hz: 0.75,
            filter_bandwidth_ang_hz: 0.75,
            sigma_max_lin_n: None,
            sigma_max_ang_nm: None,
            adaptive_mix_lin: 1.0,
            adaptive_mix_ang: 1.0,
        }
    }
}

impl L1Config {
    /// L1 on a PID6 baseline as the reference profiles build it: P and D gains from the PID,
    /// integral gains dropped, predictor matrices at their defaults, then `_L1_PARAMS`:
    /// 0.3 Hz filters, 2 N and 2 N·m estimate bounds, full adaptive mix.
    pub fn from_pid6(pid: &Pid6Gains) -> Self {
        Self {
            k_pos: Vector3::repeat(pid.kp_pos),
            k_vel: Vector3::repeat(pid.kd_pos),
            k_ori: Vector3::repeat(pid.kp_rot),
            k_ang_vel: Vector3::repeat(pid.kd_rot),
            filter_bandwidth_lin_hz: 0.3,
            filter_bandwidth_ang_hz: 0.3,
            sigma_max_lin_n: Some(2.0),
            sigma_max_ang_nm: Some(2.0),
            adaptive_mix_lin: 1.0,
            adaptive_mix_ang: 1.0,
            ..Self::default()
        }
    }

    /// EE-only and FA-Hexa profile (`EE_ABS_L1`, `FA_HEXA_ABS_L1`).
    pub fn am_bench() -> Self {
        Self::from_pid6(&Pid6Gains::am_bench())
    }

    /// Omni-Hexa profile (`OMNI_HEXA_ABS_L1`).
    pub fn omni() -> Self {
        Self::from_pid6(&Pid6Gains::omni())
    }

    /// Checks gains, predictor stability, filters and bounds.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (field, v) in [
            ("k_pos", self.k_pos),
            ("k_vel", self.k_vel),
            ("k_ori", self.k_ori),
            ("k_ang_vel", self.k_ang_vel),
        ] {
            if !v.iter().all(|x| x.is_finite() && *x >= 0.0) {
                return Err(invalid(
                    field,
                    format!("{:?} must be finite and not negative", v.as_slice()),
                ));
            }
        }
        for (field, v) in [("a_lin", self.a_lin), ("a_ang", self.a_ang)] {
            if !v.iter().all(|x| x.is_finite() && *x < 0.0) {
                return Err(invalid(
                    field,
                    format!("{:?} must be negative (a stable predictor)", v.as_slice()),
                ));
            }
        }
        for (field, v) in [
            ("filter_bandwidth_lin_hz", self.filter_bandwidth_lin_hz),
            ("filter_bandwidth_ang_hz", self.filter_bandwidth_ang_hz),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(field, format!("{v} must be finite and positive")));
            }
        }
        check_limit("sigma_max_lin_n", self.sigma_max_lin_n)?;
        check_limit("sigma_max_ang_nm", self.sigma_max_ang_nm)?;
        for (field, v) in [
            ("adaptive_mix_lin", self.adaptive_mix_lin),
            ("adaptive_mix_ang", self.adaptive_mix_ang),
        ] {
            if !v.is_finite() {
                return Err(invalid(field, format!("{v} must be finite")));
            }
        }
        Ok(())
    }
}

/// A base controller and its gains, as written in a TOML file:
///
/// ```toml
/// controller = "pid6"   # or "pid4", "l1"
/// kp_pos = 200.0        # any field of that controller's gains; the rest keep their defaults
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "controller", rename_all = "lowercase")]
// Built once per flight and kept Copy: the MPC's settings make it a few hundred bytes.
#[allow(clippy::large_enum_variant)]
pub enum ControllerConfig {
    /// 6-DoF geometric PID.
    Pid6(Pid6Gains),
    /// Nested 4-DoF geometric PID.
    Pid4(Pid4Gains),
    /// L1 adaptive on the PID baseline.
    L1(L1Config),
    /// Whole-body NMPC (FA-Hexa, end-effector interface): not a base controller, the flight
    /// stack builds it as the EE interface ([`crate::mpc::WholeBodyMpc`]).
    Mpc(crate::mpc::MpcConfig),
}

impl ControllerConfig {
    /// Parses and validates a TOML controller config; unknown keys are refused.
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let config: Self =
            toml::from_str(text).map_err(|e| ConfigError::Parse(e.message().to_owned()))?;
        config.validate()?;
        Ok(config)
    }

    /// Checks the gains.
    pub fn validate(&self) -> Result<(), ConfigError> {
        match self {
            Self::Pid6(g) => g.validate(),
            Self::Pid4(g) => g.validate(),
            Self::L1(c) => c.validate(),
            Self::Mpc(c) => c
                .validate()
                .map_err(|e| ConfigError::Unsupported(e.to_string())),
        }
    }

    /// `pid6`, `pid4`, `l1` or `mpc`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Pid6(_) => "pid6",
            Self::Pid4(_) => "pid4",
            Self::L1(_) => "l1",
            Self::Mpc(_) => "mpc",
        }
    }
}
