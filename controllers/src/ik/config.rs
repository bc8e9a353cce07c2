//! Settings of the whole-body IK: weights, locks, solver tolerances and the per-vehicle presets
//! of AM-Bench (AMBENCH_SPEC §2.6).
//!
//! Plain data: every field is public, documented with its unit and default, and checked by
//! [`IkConfig::validate`]. Loaded from TOML with unknown keys rejected; a table or key left out
//! takes its default.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A configuration value the IK cannot work with.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum IkConfigError {
    /// A field is out of its range.
    #[error("ik config: {field} = {value} {requirement}")]
    Invalid {
        /// Dotted field name (`weights.pose_position`).
        field: &'static str,
        /// The value, as written.
        value: String,
        /// What it must be.
        requirement: &'static str,
    },
    /// A vehicle names an IK preset that does not exist.
    #[error("{0}")]
    UnknownPreset(String),
    /// The TOML text does not parse into an [`IkConfig`] (syntax, type or unknown key).
    #[error("ik config: {0}")]
    Toml(String),
}

/// Residual weights. Each residual is multiplied by its weight and the solver minimises the sum
/// of squares, so a cost term scales with the weight squared (as in pyroki).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IkWeights {
    /// End-effector position error, 1/m. Default 5.0.
    pub pose_position: f64,
    /// End-effector orientation error (SO(3) log), 1/rad. Default 1.0.
    pub pose_orientation: f64,
    /// Arm joint-limit hinge, 1/rad (1/m for a prismatic joint). Default 100.0.
    pub joint_limit: f64,
    /// Arm joints' change from the previous solution, 1/rad. Default 0.1.
    pub smoothness_joints: f64,
    /// Base position change from the previous solution, 1/m. Default 1.0 (the reference's
    /// config default; its solver-level default 0.1 is always overridden).
    pub smoothness_base_position: f64,
    /// Base orientation change from the previous solution (SO(3) log), 1/rad. Default 0.1.
    pub smoothness_base_orientation: f64,
    /// Arm joints' distance from the rest posture, 1/rad. Default 0.1.
    pub rest_arm: f64,
    /// Base position limit hinge, 1/m. Default 100.0.
    pub base_position_limit: f64,
}

impl Default for IkWeights {
    fn default() -> Self {
        Self {
            pose_position: 5.0,
            pose_orientation: 1.0,
            joint_limit: 100.0,
            smoothness_joints: 0.1,
            smoothness_base_position: 1.0,
            smoothness_base_orientation: 0.1,
            rest_arm: 0.1,
            base_position_limit: 100.0,
        }
    }
}

/// Levenberg–Marquardt settings. The first group repeats the defaults of the reference's solver
/// (jaxls `TrustRegionConfig` / `TerminationConfig`); the second is specific to the task-priority
/// formulation of this crate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IkSolverSettings {
    /// Most step attempts (accepted or rejected) per solve. Default 100.
    pub max_iterations: u32,
    /// Damping λ at the start of each solve (added to the diagonal: `JᵀJ + λI`). Default 5e-4.
    /// The regularisation step's own damping μ starts, moves and is bounded like λ.
    pub lambda_initial: f64,
    /// λ is divided by this after an accepted step and multiplied after a rejected one.
    /// Default 2.0.
    pub lambda_factor: f64,
    /// Smallest λ. Default 1e-5.
    pub lambda_min: f64,
    /// Largest λ: a step rejected at this damping ends the solve (no progress is possible).
    /// Default 1e10.
    pub lambda_max: f64,
    /// Smallest ratio of actual to predicted task-cost decrease that accepts a step.
    /// Default 1e-3.
    pub step_quality_min: f64,
    /// Stop when an accepted step changes both the task cost and the regularisation cost by
    /// less than this fraction (the task level also counts as settled once its pose is met
    /// within the pose tolerances). Default 1e-5.
    pub cost_tolerance: f64,
    /// Stop when the largest task gradient entry |J₁ᵀr₁| and the largest regularisation gradient
    /// entry projected on the task nullspace are both below this. Default 1e-4.
    pub gradient_tolerance: f64,
    /// The gradient test applies from this iteration on (it is too loose for the first few
    /// steps of a cold start). Default 10.
    pub gradient_tolerance_start_iteration: u32,
    /// Stop when a step's norm is below `parameter_tolerance·(|x| + parameter_tolerance)`,
    /// |x| the norm of (base position, unit quaternion, arm joints). Default 1e-6.
    pub parameter_tolerance: f64,
    /// Task-Jacobian singular values below this fraction of the largest span the nullspace in
    /// which the regularisation acts. Default 1e-6.
    pub nullspace_singular_value_ratio: f64,
    /// Ridge added to the regularisation step's normal matrix, on top of λ. Default 1e-9.
    pub nullspace_ridge: f64,
    /// End-effector position error below which the pose counts as reached (status
    /// `converged`), m. Also bounds the pose error regularisation steps may leave before the
    /// final polish. Default 1e-5.
    pub pose_position_tolerance_m: f64,
    /// End-effector orientation error below which the pose counts as reached, rad (same roles).
    /// Default 1e-5.
    pub pose_orientation_tolerance_rad: f64,
    /// Joint- or base-limit violation below which the limits count as respected (m or rad).
    /// Default 1e-6.
    pub limit_tolerance: f64,
}

impl Default for IkSolverSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            lambda_initial: 5e-4,
            lambda_factor: 2.0,
            lambda_min: 1e-5,
            lambda_max: 1e10,
            step_quality_min: 1e-3,
            cost_tolerance: 1e-5,
            gradient_tolerance: 1e-4,
            gradient_tolerance_start_iteration: 10,
            parameter_tolerance: 1e-6,
            nullspace_singular_value_ratio: 1e-6,
            nullspace_ridge: 1e-9,
            pose_position_tolerance_m: 1e-5,
            pose_orientation_tolerance_rad: 1e-5,
            limit_tolerance: 1e-6,
        }
    }
}

/// The arm posture the rest term pulls toward (`q_rest`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RestPosture {
    /// Every arm joint at 0 (FA-Hexa, UA-Hexa, UA-Quad). Default.
    #[default]
    Zero,
    /// The vehicle's initial drive positions (`Vehicle::initial_configuration`; Omni-Hexa:
    /// servo1 −π/4, servo2 3π/4, servo3 0).
    VehicleInitial,
}

/// Whole-body IK settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IkConfig {
    /// Residual weights.
    pub weights: IkWeights,
    /// Base position axes (world x, y, z) held at the warm start. Default all false.
    pub fix_base_position: [bool; 3],
    /// Base rotation axes (roll, pitch, yaw = world x, y, z) held at the warm start.
    /// Default `[true, true, false]`: level base, free yaw.
    pub fix_base_orientation: [bool; 3],
    /// Distance callers keep the base from obstacles when they build [`crate::ik::BaseLimits`]
    /// (`max_x = wall_face_x − safety_margin_m`), m. The solver itself does not read it.
    /// Default 1.0.
    pub safety_margin_m: f64,
    /// Posture of the rest term. Default [`RestPosture::Zero`].
    pub rest_posture: RestPosture,
    /// Base position of the first warm start, before any `reset`, m (world). The orientation
    /// starts at identity. Default (0, 0, 0) as the reference's config class; every preset
    /// uses (0, 0, 1), the vehicles' spawn pose.
    pub initial_base_position_m: [f64; 3],
    /// Levenberg–Marquardt settings.
    pub solver: IkSolverSettings,
}

impl Default for IkConfig {
    fn default() -> Self {
        Self {
            weights: IkWeights::default(),
            fix_base_position: [false; 3],
            fix_base_orientation: [true, true, false],
            safety_margin_m: 1.0,
            rest_posture: RestPosture::Zero,
            initial_base_position_m: [0.0, 0.0, 0.0],
            solver: IkSolverSettings::default(),
        }
    }
}

/// Spawn height of every AM-Bench vehicle, m (AMBENCH_SPEC §1.1 "init root pose").
const SPAWN_HEIGHT_M: f64 = 1.0;

impl IkConfig {
    /// The reference's common profile: level base, spawn pose (0, 0, 1).
    fn preset_base() -> Self {
        Self {
            initial_base_position_m: [0.0, 0.0, SPAWN_HEIGHT_M],
            ..Self::default()
        }
    }

    /// FA-Hexa (`hexa_ik`): base orientation fully locked, margin 0.85 m, base smoothness
    /// 1.0 (position) and 0.1 (orientation), rest posture zero.
    pub fn fa_hexa() -> Self {
        let mut c = Self::preset_base();
        c.fix_base_orientation = [true, true, true];
        c.safety_margin_m = 0.85;
        c.weights.smoothness_base_position = 1.0;
        c.weights.smoothness_base_orientation = 0.1;
        c
    }

    /// UA-Hexa (`hexa_ik`): roll and pitch locked, yaw free, margin 0.8 m, base position
    /// smoothness 8.0.
    pub fn ua_hexa() -> Self {
        let mut c = Self::preset_base();
        c.fix_base_orientation = [true, true, false];
        c.safety_margin_m = 0.8;
        c.weights.smoothness_base_position = 8.0;
        c.weights.smoothness_base_orientation = 0.1;
        c
    }

    /// UA-Quad (`quad_ik`): roll and pitch locked, yaw free, margin 0.15 m, base position
    /// smoothness 1.0.
    pub fn ua_quad() -> Self {
        let mut c = Self::preset_base();
        c.fix_base_orientation = [true, true, false];
        c.safety_margin_m = 0.15;
        c.weights.smoothness_base_position = 1.0;
        c.weights.smoothness_base_orientation = 0.1;
        c
    }

    /// Omni-Hexa (`omni_ik`): no locks, margin 0.3 m, base smoothness 1.0 and 1.0, rest
    /// posture = the vehicle's initial joints.
    pub fn omni_hexa() -> Self {
        let mut c = Self::preset_base();
        c.fix_base_orientation = [false, false, false];
        c.safety_margin_m = 0.3;
        c.weights.smoothness_base_position = 1.0;
        c.weights.smoothness_base_orientation = 1.0;
        c.rest_posture = RestPosture::VehicleInitial;
        c
    }

    /// The preset named `name` (`fa-hexa`, `ua-hexa`, `ua-quad`, `omni-hexa`: the reference's
    /// profiles, AMBENCH_SPEC §2.6), as a vehicle file's `[control] ik` names it; None for
    /// an unknown name.
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "fa-hexa" => Some(Self::fa_hexa()),
            "ua-hexa" => Some(Self::ua_hexa()),
            "ua-quad" => Some(Self::ua_quad()),
            "omni-hexa" => Some(Self::omni_hexa()),
            _ => None,
        }
    }

    /// The reference's task-specific override of preset `preset` for task `task` (a task id
    /// as `amstack` spells it), if it has one (AMBENCH_SPEC §2.6): Lemon Harvesting with the
    /// PID profiles of the FA-Hexa (base smoothness 6.0, margin 1.0 m), the UA-Quad (base
    /// fully locked, smoothness 6.0 and 1.0, pose weights 15 and 4, margin 0) and the
    /// Omni-Hexa (margin 0.5 m).
    ///
    /// The reference's lemon profiles also leave `arm_joint_names` unset, so its rest cost
    /// falls on the first three actuated joints in pyroki's order and the non-arm joints are
    /// not reset after the solve; here the rest cost stays on the arm joints and the non-arm
    /// joints are held, as in every other profile.
    pub fn task_override(preset: &str, task: &str) -> Option<Self> {
        if task != "lemon-harvesting" {
            return None;
        }
        match preset {
            "fa-hexa" => {
                let mut c = Self::fa_hexa();
                c.weights.smoothness_base_position = 6.0;
                c.safety_margin_m = 1.0;
                Some(c)
            }
            "ua-quad" => {
                let mut c = Self::ua_quad();
                c.fix_base_orientation = [true, true, true];
                c.weights.smoothness_base_position = 6.0;
                c.weights.smoothness_base_orientation = 1.0;
                c.weights.pose_position = 15.0;
                c.weights.pose_orientation = 4.0;
                c.safety_margin_m = 0.0;
                Some(c)
            }
            "omni-hexa" => {
                let mut c = Self::omni_hexa();
                c.safety_margin_m = 0.5;
                Some(c)
            }
            _ => None,
        }
    }

    /// The IK preset of `vehicle` (its `[control] ik`): the default profile when it names
    /// none (its end effector is its base); an error naming an unknown preset.
    pub fn for_vehicle(vehicle: &platform::Vehicle) -> Result<Self, IkConfigError> {
        match vehicle.control.ik.as_deref() {
            None => Ok(Self::default()),
            Some(name) => Self::preset(name).ok_or_else(|| {
                IkConfigError::UnknownPreset(format!(
                    "{}: [control] ik = \"{name}\" is not a preset (known: fa-hexa, ua-hexa, ua-quad, omni-hexa)",
                    vehicle.id
                ))
            }),
        }
    }

    /// Parses a TOML document (unknown keys rejected, missing ones defaulted) and validates it.
    pub fn from_toml_str(text: &str) -> Result<Self, IkConfigError> {
        let config: Self =
            toml::from_str(text).map_err(|e| IkConfigError::Toml(one_line(&e.to_string())))?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), IkConfigError> {
        let w = &self.weights;
        positive("weights.pose_position", w.pose_position)?;
        positive("weights.pose_orientation", w.pose_orientation)?;
        positive("weights.joint_limit", w.joint_limit)?;
        positive("weights.base_position_limit", w.base_position_limit)?;
        not_negative("weights.smoothness_joints", w.smoothness_joints)?;
        not_negative(
            "weights.smoothness_base_position",
            w.smoothness_base_position,
        )?;
        not_negative(
            "weights.smoothness_base_orientation",
            w.smoothness_base_orientation,
        )?;
        not_negative("weights.rest_arm", w.rest_arm)?;
        not_negative("safety_margin_m", self.safety_margin_m)?;
        for v in self.initial_base_position_m {
            if !v.is_finite() {
                return Err(invalid("initial_base_position_m", v, "must be finite"));
            }
        }

        let s = &self.solver;
        if s.max_iterations == 0 {
            return Err(IkConfigError::Invalid {
                field: "solver.max_iterations",
                value: "0".to_owned(),
                requirement: "must be at least 1",
            });
        }
        positive("solver.lambda_min", s.lambda_min)?;
        if !(s.lambda_factor.is_finite() && s.lambda_factor > 1.0) {
            return Err(invalid(
                "solver.lambda_factor",
                s.lambda_factor,
                "must be finite and above 1",
            ));
        }
        if !(s.lambda_initial.is_finite()
            && s.lambda_min <= s.lambda_initial
            && s.lambda_initial <= s.lambda_max)
        {
            return Err(invalid(
                "solver.lambda_initial",
                s.lambda_initial,
                "must lie in [lambda_min, lambda_max]",
            ));
        }
        if !(s.lambda_max.is_finite()) {
            return Err(invalid("solver.lambda_max", s.lambda_max, "must be finite"));
        }
        if !(0.0..1.0).contains(&s.step_quality_min) {
            return Err(invalid(
                "solver.step_quality_min",
                s.step_quality_min,
                "must lie in [0, 1)",
            ));
        }
        not_negative("solver.cost_tolerance", s.cost_tolerance)?;
        not_negative("solver.gradient_tolerance", s.gradient_tolerance)?;
        not_negative("solver.parameter_tolerance", s.parameter_tolerance)?;
        if !(s.nullspace_singular_value_ratio > 0.0 && s.nullspace_singular_value_ratio < 1.0) {
            return Err(invalid(
                "solver.nullspace_singular_value_ratio",
                s.nullspace_singular_value_ratio,
                "must lie in (0, 1)",
            ));
        }
        not_negative("solver.nullspace_ridge", s.nullspace_ridge)?;
        positive(
            "solver.pose_position_tolerance_m",
            s.pose_position_tolerance_m,
        )?;
        positive(
            "solver.pose_orientation_tolerance_rad",
            s.pose_orientation_tolerance_rad,
        )?;
        positive("solver.limit_tolerance", s.limit_tolerance)?;
        Ok(())
    }
}

fn invalid(field: &'static str, value: f64, requirement: &'static str) -> IkConfigError {
    IkConfigError::Invalid {
        field,
        value: value.to_string(),
        requirement,
    }
}

fn positive(field: &'static str, value: f64) -> Result<(), IkConfigError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, value, "must be finite and positive"))
    }
}

fn not_negative(field: &'static str, value: f64) -> Result<(), IkConfigError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(invalid(field, value, "must be finite and not negative"))
    }
}

/// Error messages of the TOML parser span lines; ours are one line.
fn one_line(message: &str) -> String {
    message.split_whitespace().collect::<Vec<_>>().join(" ")
}
