//! The flags that set up the twin, shared by `amstack track`, `amstack fly` and
//! `amstack twin serve`: both sides of a split flight must build the same `TwinConfig` from
//! the same flags, or the handshake refuses them.

use anyhow::Result;
use sim_twin::{
    Disturbances, MotorConfig, SaturatedAllocation, TaskId, TwinConfig, VehicleDynamics,
};

use crate::cli_error::bad_input;

#[derive(Debug, Clone, clap::Args)]
pub struct TwinFlags {
    /// Comma-separated: drag, wind, ground, wall, noise, saturation; or `reference` (the
    /// paper's evaluation set: all but noise), `all`, `none`. Without `saturation` the
    /// rotors are ideal and unbounded, as in the reference's default.
    #[arg(long, value_name = "LIST", default_value = "none")]
    pub disturbances: String,
    /// Motor time constant, s (needs `saturation`); the paper identified 0.0475.
    #[arg(long, value_name = "S")]
    pub motor_tau: Option<f64>,
    /// Motor normalised-speed rate limit, 1/s (needs `saturation`); the paper uses 0.75.
    #[arg(long, value_name = "R")]
    pub motor_rate_limit: Option<f64>,
    /// Ground-effect intensity k (the paper's rho); default 0.171, its real-flight fit 3.4.
    #[arg(long, value_name = "K")]
    pub ground_effect_k: Option<f64>,
    /// Seed of every random draw (noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// How the flight stack allocates a wrench the rotors cannot produce (with
    /// `saturation`): `prioritized` (default: the bounded least-squares thrusts, roll and
    /// pitch kept first, yaw giving way first) or `clip` (the reference's: the pseudo-inverse
    /// clamped rotor by rotor, which loses attitude when a rotor saturates).
    #[arg(long, value_name = "HOW", default_value = "prioritized")]
    pub saturated_allocation: String,
    #[command(flatten)]
    pub physics: PhysicsFlags,
}

/// How finely the twin's physics runs: `--physics-substeps` and `--solver-iterations`
/// (`track`, `fly`, `twin serve`, `bench`, the experiments). rapier rebuilds the vehicle's
/// mass matrix at every solver iteration of every substep: the product is the physics cost.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct PhysicsFlags {
    /// Physics steps per 120 Hz control tick (rotor forces re-applied at the current poses
    /// before each). Default 4; fewer run faster, at the fidelity measured in docs/speed.md.
    #[arg(long, value_name = "N")]
    pub physics_substeps: Option<u32>,
    /// Constraint-solver iterations per physics step: rapier's passes, shared among its
    /// `--rapier-steps` steps (each step a rebuild of the vehicle's mass matrix), and the
    /// default steps of the vehicle's own dynamics. Default 4; see docs/speed.md.
    #[arg(long, value_name = "N")]
    pub solver_iterations: Option<u32>,
    /// What steps the vehicle's dynamics: `articulated` (default): amstack's own rigid-body
    /// dynamics (CRBA, RNEA, implicit joint drives, `--solver-iterations` steps per physics
    /// substep) in free flight, handing the vehicle to rapier's multibody while anything it
    /// can touch is within 0.1 m or it holds an object it cannot carry (a welded object clear of
    /// everything rides along as a payload) — several times faster per tick in
    /// free flight; or `rapier`: rapier's multibody throughout (docs/speed.md).
    #[arg(long, value_name = "ENGINE")]
    pub vehicle_dynamics: Option<DynamicsEngine>,
    /// Steps of the vehicle's own dynamics per physics substep while it flies on them
    /// (`--vehicle-dynamics articulated`, in free flight). Default: `--solver-iterations`.
    #[arg(long, value_name = "N")]
    pub own_dynamics_steps: Option<u32>,
    /// Steps rapier's solver splits each physics substep into, each rebuilding the
    /// vehicle's multibody mass matrix; the `--solver-iterations` constraint passes are
    /// shared among them. Default 2 (two passes on each of two mass matrices: the
    /// benchmark's tables and the grasped objects as with 4 steps, the contact ticks
    /// cheaper; docs/speed.md); 4 with `--solver-iterations 4` is the earlier default.
    #[arg(long, value_name = "N")]
    pub rapier_steps: Option<u32>,
}

/// `--vehicle-dynamics`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DynamicsEngine {
    /// rapier's multibody throughout.
    Rapier,
    /// amstack's own articulated-body dynamics in free flight, rapier's near contact.
    Articulated,
}

impl PhysicsFlags {
    /// Refuses a 0 before anything is written.
    pub fn check(&self) -> Result<()> {
        if self.physics_substeps == Some(0) {
            return Err(bad_input("--physics-substeps: 0; at least 1 step per tick"));
        }
        if self.solver_iterations == Some(0) {
            return Err(bad_input(
                "--solver-iterations: 0; at least 1 iteration per physics step",
            ));
        }
        if self.own_dynamics_steps == Some(0) {
            return Err(bad_input(
                "--own-dynamics-steps: 0; at least 1 step per physics substep",
            ));
        }
        if self.rapier_steps == Some(0) {
            return Err(bad_input(
                "--rapier-steps: 0; at least 1 solver step per physics substep",
            ));
        }
        Ok(())
    }

    /// Sets the given counts on `twin` (after [`Self::check`]).
    pub fn apply(&self, twin: &mut TwinConfig) -> Result<()> {
        self.check()?;
        if let Some(n) = self.physics_substeps {
            twin.physics_substeps = n;
        }
        if let Some(n) = self.solver_iterations {
            twin.solver_iterations = n;
        }
        if let Some(n) = self.own_dynamics_steps {
            twin.own_dynamics_steps = Some(n);
        }
        if let Some(n) = self.rapier_steps {
            twin.rapier_steps = Some(n);
        }
        if let Some(e) = self.vehicle_dynamics {
            twin.vehicle_dynamics = match e {
                DynamicsEngine::Rapier => VehicleDynamics::Rapier,
                DynamicsEngine::Articulated => VehicleDynamics::Articulated,
            };
        }
        Ok(())
    }

    /// The same flags as a command line (`track`'s), the unset ones left out.
    pub fn flag_line(&self) -> Vec<String> {
        let mut f = Vec::new();
        if let Some(n) = self.physics_substeps {
            f.extend(["--physics-substeps".to_owned(), n.to_string()]);
        }
        if let Some(n) = self.solver_iterations {
            f.extend(["--solver-iterations".to_owned(), n.to_string()]);
        }
        if let Some(n) = self.own_dynamics_steps {
            f.extend(["--own-dynamics-steps".to_owned(), n.to_string()]);
        }
        if let Some(n) = self.rapier_steps {
            f.extend(["--rapier-steps".to_owned(), n.to_string()]);
        }
        if let Some(e) = self.vehicle_dynamics {
            let name = match e {
                DynamicsEngine::Rapier => "rapier",
                DynamicsEngine::Articulated => "articulated",
            };
            f.extend(["--vehicle-dynamics".to_owned(), name.to_owned()]);
        }
        f
    }
}

impl TwinFlags {
    /// The validated twin configuration; a bad value is bad input naming its flag.
    pub fn twin_config(&self) -> Result<TwinConfig> {
        let disturbances = Disturbances::parse_list(&self.disturbances)
            .map_err(|e| bad_input(format!("--disturbances: {e}")))?;
        let mut twin = TwinConfig {
            disturbances,
            motor: MotorConfig {
                time_constant_s: self.motor_tau,
                rate_limit_per_s: self.motor_rate_limit,
            },
            seed: self.seed,
            saturated_allocation: SaturatedAllocation::parse(&self.saturated_allocation)
                .map_err(|e| bad_input(format!("--saturated-allocation: {e}")))?,
            ..TwinConfig::default()
        };
        if let Some(k) = self.ground_effect_k {
            twin.aero.ground_effect_k = k;
        }
        self.physics.apply(&mut twin)?;
        twin.validate()
            .map_err(|e| bad_input(format!("twin: {e}")))?;
        Ok(twin)
    }
}

/// `--task`: a task's scene built around the vehicle (`track`, `fly`, `twin serve`; both
/// sides of a split flight must name the same one, or the handshake refuses them).
#[derive(Debug, clap::Args)]
pub struct SceneFlag {
    /// Build a task's scene around the vehicle (press-button, push-slider, ...: the names of
    /// `amstack bench --help`): its objects are in the world, for contact and for the ground
    /// and near-wall effects.
    #[arg(long, value_name = "NAME")]
    pub task: Option<String>,
}

impl SceneFlag {
    /// Puts the named task's scene into `twin`; an unknown name is bad input listing the
    /// valid ones.
    pub fn apply(&self, twin: &mut TwinConfig) -> Result<()> {
        twin.task = self
            .task
            .as_deref()
            .map(TaskId::parse)
            .transpose()
            .map_err(|e| bad_input(format!("--task: {e}")))?;
        Ok(())
    }
}
