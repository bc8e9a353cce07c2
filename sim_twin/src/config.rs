//! Configuration of the twin: rates, which disturbances are on, motor dynamics, noise.

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::aero::AeroConfig;

/// Which disturbances and limits act. All off by default, as in the reference
/// (`base_env_cfg.py`); the reference's `--disturbance` evaluation flag turns on
/// saturation, aerodynamics and wind together.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Disturbances {
    /// Body-frame linear drag.
    pub drag: bool,
    /// Constant world-frame wind force ([`AeroConfig::wind_force_in_world_n`]).
    pub wind: bool,
    /// Ground effect from a ray cast along each rotor's −thrust axis.
    pub ground_effect: bool,
    /// Near-wall effect from a 10-ray horizontal fan per rotor.
    pub near_wall: bool,
    /// Gaussian noise and per-reset bias on every measured value.
    pub observation_noise: bool,
    /// Gaussian noise on every command value.
    pub action_noise: bool,
    /// Rotor thrust limits [T_min, T_max] (and with them the motor model). Off, thrust
    /// commands act unclipped, as the reference does without `enable_saturation`.
    pub saturation: bool,
}

impl Disturbances {
    /// Everything on.
    pub fn all() -> Self {
        Self {
            drag: true,
            wind: true,
            ground_effect: true,
            near_wall: true,
            observation_noise: true,
            action_noise: true,
            saturation: true,
        }
    }

    /// The reference's evaluation setting (`--disturbance`): rotor limits, aerodynamics
    /// (drag, ground, near-wall) and wind, no noise.
    pub fn reference() -> Self {
        Self {
            drag: true,
            wind: true,
            ground_effect: true,
            near_wall: true,
            saturation: true,
            ..Self::default()
        }
    }

    /// Parses a comma-separated list of `drag, wind, ground, wall, noise, saturation`
    /// (`noise` = observation and action noise), or `none`, `all`, `reference` (the
    /// reference's evaluation set: everything but noise).
    pub fn parse_list(list: &str) -> Result<Self, String> {
        let mut d = Self::default();
        for word in list.split(',').map(str::trim).filter(|w| !w.is_empty()) {
            match word {
                "none" => {}
                "all" => d = Self::all(),
                "reference" => {
                    let r = Self::reference();
                    d = Self {
                        drag: r.drag,
                        wind: r.wind,
                        ground_effect: r.ground_effect,
                        near_wall: r.near_wall,
                        saturation: r.saturation,
                        ..d
                    };
                }
                "drag" => d.drag = true,
                "wind" => d.wind = true,
                "ground" => d.ground_effect = true,
                "wall" => d.near_wall = true,
                "noise" => {
                    d.observation_noise = true;
                    d.action_noise = true;
                }
                "saturation" => d.saturation = true,
                other => {
                    return Err(format!(
                        "unknown disturbance '{other}' (known: drag, wind, ground, wall, noise, saturation, reference, all, none)"
                    ));
                }
            }
        }
        Ok(d)
    }

    /// Names of the disturbances on, for logs.
    pub fn names(&self) -> Vec<&'static str> {
        [
            (self.drag, "drag"),
            (self.wind, "wind"),
            (self.ground_effect, "ground"),
            (self.near_wall, "wall"),
            (self.observation_noise, "observation_noise"),
            (self.action_noise, "action_noise"),
            (self.saturation, "saturation"),
        ]
        .into_iter()
        .filter_map(|(on, name)| on.then_some(name))
        .collect()
    }
}

/// How the flight stack flying this twin allocates a wrench its bounded rotors cannot all
/// produce (with `saturation` on; ideal rotors produce any wrench and both give A⁺w). Not the
/// twin's physics but the stack's, kept here beside [`TiltThrust`] so that every flight built
/// from the same flags (and both sides of a split flight) allocate alike, and so that a run's
/// config.json records it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SaturatedAllocation {
    /// The bounded weighted least-squares allocation (`allocation`'s constrained QP): the
    /// thrusts within the rotor limits closest to the request, roll and pitch torque kept
    /// first, then force, yaw giving way first (PX4's desaturation priorities). What a flight
    /// stack on the real vehicle does; a request the rotors can produce gets A⁺w exactly.
    #[default]
    Prioritized,
    /// A⁺w with each rotor clamped into its limits: the reference's allocation (AMBENCH_SPEC
    /// §1.6), which distorts the attitude torques whenever a rotor saturates.
    Clip,
}

impl SaturatedAllocation {
    /// Parses `prioritized` or `clip`.
    pub fn parse(name: &str) -> Result<Self, String> {
        match name {
            "prioritized" => Ok(Self::Prioritized),
            "clip" => Ok(Self::Clip),
            other => Err(format!("{other:?}: expected prioritized or clip")),
        }
    }
}

/// What steps the vehicle's own dynamics (its base, arm and gripper).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleDynamics {
    /// rapier's multibody throughout: contacts and grasps act on the vehicle as on
    /// everything else.
    Rapier,
    /// amstack's own articulated-body dynamics (`platform::ArticulatedBody`: CRBA, RNEA,
    /// implicit joint drives, `solver_iterations` steps per physics substep, as many as
    /// rapier's TGS takes) in free flight, the vehicle's bodies moved kinematically in
    /// rapier; rapier's multibody while anything the vehicle can touch is within 0.1 m of it
    /// or it holds an object it cannot carry (contacts and grasps act on it there; an object
    /// welded in the grasp, on no other joint and clear of everything, rides along as a
    /// payload of the own dynamics), the state handed over
    /// exactly each way. Several times cheaper per tick in free flight, the benchmark's
    /// success tables unchanged (docs/speed.md). The default.
    #[default]
    Articulated,
}

/// Along which direction a tilting rotor (Omni-Hexa) pushes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TiltThrust {
    /// Along the commanded tilt angle, from the rotor's α = 0 position, as if the hinge
    /// reached its target at once: the reference's model (AMBENCH_SPEC §1.6, §9 item 5),
    /// for which its Omni-Hexa gains are tuned. The hinge bodies still move physically.
    #[default]
    Commanded,
    /// Along the hinge's measured angle, from the rotor's current position: what hardware
    /// does. The hinges are slew-limited (5 rad/s) with a ~10 ms drive: with the reference's
    /// Omni-Hexa gains (position D 120 1/s) the lateral loop then limit-cycles at ~6 Hz once
    /// disturbed (e.g. by the arm moving) — a flight stack for the real vehicle needs a lower
    /// lateral bandwidth. The flight stack projects each rotor's thrust on its measured
    /// direction in this mode.
    Measured,
}

/// Rotor dynamics (AMBENCH_SPEC §2.8; identified on the real FA-Hexa: τ = 47.5 ms,
/// q̇_max = 0.75 s⁻¹). Both off by default (instantaneous rotors, as every reference robot).
/// They act only with `saturation` on: the model works in normalised speed √(T/T_max).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotorConfig {
    /// First-order time constant, s.
    pub time_constant_s: Option<f64>,
    /// Rate limit of the normalised speed, 1/s.
    pub rate_limit_per_s: Option<f64>,
}

/// Noise models (AMBENCH_SPEC §3.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseConfig {
    /// Standard deviation of the per-tick observation noise. Default 0.002.
    pub observation_std: f64,
    /// Standard deviation of the per-reset observation bias. Default 1e-4.
    pub observation_bias_std: f64,
    /// Standard deviation of the action noise. Default 1e-4.
    pub action_std: f64,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        Self {
            observation_std: 0.002,
            observation_bias_std: 1e-4,
            action_std: 1e-4,
        }
    }
}

/// Everything the twin needs besides the vehicle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwinConfig {
    /// Control rate, Hz: one `step` advances 1/rate seconds. Default 120 (the paper's).
    pub control_rate_hz: f64,
    /// Physics substeps per control tick (the rotor forces are re-applied along the current
    /// axes at each). Default 4: 480 Hz physics keeps the stiff arm drives (1e5 N·m/rad on
    /// 0.2 kg links) stable while costing little.
    pub physics_substeps: u32,
    /// Constraint solver iterations per substep: rapier's passes, shared among its
    /// `rapier_steps` steps. Default 4.
    pub solver_iterations: u32,
    /// What steps the vehicle's dynamics. Default: the vehicle's own in free flight,
    /// rapier's multibody near contact; a config written before this field existed (or
    /// left out of a file) was flown on rapier's multibody throughout, and reads as `rapier`.
    #[serde(default = "dynamics_before_the_field")]
    pub vehicle_dynamics: VehicleDynamics,
    /// Steps of the vehicle's own dynamics per physics substep while it flies on them
    /// (`VehicleDynamics::Articulated` in free flight). None: `solver_iterations` steps,
    /// as a config written before this field existed (or left out of a file) was flown.
    #[serde(default = "own_steps_before_the_field")]
    pub own_dynamics_steps: Option<u32>,
    /// Steps rapier's solver splits each physics substep into. Each step rebuilds the
    /// vehicle multibody's mass matrix (two dense JᵀMJ products and two LU factorisations,
    /// most of a contact tick's time) and integrates the positions; the `solver_iterations`
    /// constraint passes are shared among the steps (⌈solver_iterations / steps⌉ each).
    /// While the hand holds an object on a joint (a lever, valve, slider, door or drawer) the
    /// solver takes `solver_iterations` steps of one pass whatever this says: the loop the
    /// grasp closes through the object's joint converges over steps, not passes (the MPC's
    /// Pull Lever and Rotate Valve 27 and 26 of 30 with 2 steps there, 30 and 29 without).
    /// Default 2 (two passes on each of two mass matrices per substep): the benchmark's
    /// tables, the grasped objects (within 2.1 mm) and a vehicle sliding down a wall (within
    /// 1.3 mm of a converged flight) as with four steps of one pass, the contact ticks
    /// cheaper; one step slides the vehicle 3 cm further down the wall and the grasped
    /// objects up to 6.9 mm off (docs/speed.md, "rapier's solver steps"). None:
    /// `solver_iterations` steps of one pass each, as a config written before this field
    /// existed (or left out of a file) was flown.
    #[serde(default = "rapier_steps_before_the_field")]
    pub rapier_steps: Option<u32>,
    /// Which disturbances act.
    pub disturbances: Disturbances,
    /// Aerodynamic constants.
    pub aero: AeroConfig,
    /// Rotor dynamics.
    pub motor: MotorConfig,
    /// How tilting rotors push (Omni-Hexa only). Default: as commanded, like the reference.
    pub tilt_thrust: TiltThrust,
    /// How the flight stack allocates under rotor limits. Default: prioritized; a config
    /// (a log's, a run's config.json) written before this field existed was flown with the
    /// clamp, and reads as `clip`.
    #[serde(default = "allocation_before_the_field")]
    pub saturated_allocation: SaturatedAllocation,
    /// Noise levels.
    pub noise: NoiseConfig,
    /// Seed of every random draw of the twin.
    pub seed: u64,
    /// The task scene built around the vehicle at every reset (None: an empty world with
    /// the ground only).
    pub task: Option<crate::tasks::TaskId>,
    /// How grasps hold (contact only, or with the grasp constraint).
    pub grasp: crate::tasks::GraspMode,
    /// Base pose at reset (AMBENCH_SPEC §1.1: 1 m up, level).
    #[serde(skip, default = "default_initial_pose")]
    pub initial_base_pose: Isometry3<f64>,
}

fn dynamics_before_the_field() -> VehicleDynamics {
    VehicleDynamics::Rapier
}

fn own_steps_before_the_field() -> Option<u32> {
    None
}

fn rapier_steps_before_the_field() -> Option<u32> {
    None
}

fn allocation_before_the_field() -> SaturatedAllocation {
    SaturatedAllocation::Clip
}

fn default_initial_pose() -> Isometry3<f64> {
    Isometry3::translation(0.0, 0.0, 1.0)
}

impl Default for TwinConfig {
    fn default() -> Self {
        Self {
            control_rate_hz: 120.0,
            physics_substeps: 4,
            solver_iterations: 4,
            vehicle_dynamics: VehicleDynamics::default(),
            own_dynamics_steps: None,
            rapier_steps: Some(2),
            disturbances: Disturbances::default(),
            aero: AeroConfig::default(),
            motor: MotorConfig::default(),
            tilt_thrust: TiltThrust::default(),
            saturated_allocation: SaturatedAllocation::default(),
            noise: NoiseConfig::default(),
            seed: 0,
            task: None,
            grasp: crate::tasks::GraspMode::default(),
            initial_base_pose: default_initial_pose(),
        }
    }
}

impl TwinConfig {
    /// rapier's solver steps per physics substep and constraint passes per step
    /// (`IntegrationParameters::num_solver_iterations`, `num_internal_pgs_iterations`),
    /// with the hand holding an object on a joint or not (see `rapier_steps`).
    pub fn rapier_solver(&self, holding_on_a_joint: bool) -> (usize, usize) {
        match self.rapier_steps {
            Some(steps) if !holding_on_a_joint => (
                steps as usize,
                self.solver_iterations.div_ceil(steps.max(1)) as usize,
            ),
            _ => (self.solver_iterations as usize, 1),
        }
    }

    /// Control period, s.
    pub fn control_dt_s(&self) -> f64 {
        1.0 / self.control_rate_hz
    }

    /// Checks every field.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.control_rate_hz.is_finite() && self.control_rate_hz > 0.0) {
            return Err(format!(
                "control_rate_hz = {} must be finite and positive",
                self.control_rate_hz
            ));
        }
        if self.physics_substeps == 0 || self.solver_iterations == 0 {
            return Err("physics_substeps and solver_iterations must be at least 1".to_owned());
        }
        if self.own_dynamics_steps == Some(0) {
            return Err("own_dynamics_steps must be at least 1".to_owned());
        }
        if self.rapier_steps == Some(0) {
            return Err("rapier_steps must be at least 1".to_owned());
        }
        self.aero.validate()?;
        for (name, v) in [
            ("motor.time_constant_s", self.motor.time_constant_s),
            ("motor.rate_limit_per_s", self.motor.rate_limit_per_s),
        ] {
            if let Some(x) = v
                && !(x.is_finite() && x > 0.0)
            {
                return Err(format!("{name} = {x} must be finite and positive"));
            }
        }
        let motor_on =
            self.motor.time_constant_s.is_some() || self.motor.rate_limit_per_s.is_some();
        if motor_on && !self.disturbances.saturation {
            return Err(
                "motor dynamics need rotor limits: add 'saturation' to the disturbances".to_owned(),
            );
        }
        let n = self.noise;
        for (name, v) in [
            ("noise.observation_std", n.observation_std),
            ("noise.observation_bias_std", n.observation_bias_std),
            ("noise.action_std", n.action_std),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} = {v} must be finite and not negative"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A config written before a field existed replays as it was flown: no
    /// `vehicle_dynamics` reads as rapier's multibody, no `own_dynamics_steps` as
    /// `solver_iterations` steps (None), no `rapier_steps` as rapier's solver in
    /// `solver_iterations` steps of one pass; a config written now carries them and reads
    /// back equal.
    #[test]
    fn fields_missing_from_an_older_config_read_as_it_was_flown() {
        let now = TwinConfig {
            own_dynamics_steps: Some(2),
            ..TwinConfig::default()
        };
        let text = serde_json::to_string(&now).unwrap_or_else(|e| panic!("{e}"));
        let mut value: serde_json::Value =
            serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(value["vehicle_dynamics"], "articulated", "{value}");
        assert_eq!(value["own_dynamics_steps"], 2, "{value}");
        assert_eq!(value["rapier_steps"], 2, "{value}");
        assert_eq!(now.rapier_solver(false), (2, 2));
        assert_eq!(now.rapier_solver(true), (4, 1));
        let back: TwinConfig =
            serde_json::from_value(value.clone()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back, now);
        let Some(fields) = value.as_object_mut() else {
            panic!("not an object: {value}");
        };
        fields.remove("vehicle_dynamics");
        fields.remove("own_dynamics_steps");
        fields.remove("rapier_steps");
        let old: TwinConfig = serde_json::from_value(value).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(old.vehicle_dynamics, VehicleDynamics::Rapier);
        assert_eq!(old.own_dynamics_steps, None);
        assert_eq!(old.rapier_steps, None);
        assert_eq!(old.rapier_solver(false), (4, 1));
        // Passes shared among the steps, rounded up: 4 passes over 3 steps are 2 each.
        let three = TwinConfig {
            rapier_steps: Some(3),
            ..TwinConfig::default()
        };
        assert_eq!(three.rapier_solver(false), (3, 2));
        let zero = TwinConfig {
            own_dynamics_steps: Some(0),
            ..TwinConfig::default()
        };
        assert!(
            zero.validate()
                .is_err_and(|e| e.contains("own_dynamics_steps"))
        );
        let zero = TwinConfig {
            rapier_steps: Some(0),
            ..TwinConfig::default()
        };
        assert!(zero.validate().is_err_and(|e| e.contains("rapier_steps")));
    }
}
