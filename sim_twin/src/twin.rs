//! The twin: a vehicle in a rapier world, advanced one control period per command.
//!
//! One control tick (AMBENCH_SPEC §3.3, with per-rotor forces instead of one reconstructed
//! wrench):
//! 1. rotor thrust commands → motor model (limits, lag, rate limit; `allocation`'s
//!    [`RotorActuator`]) → realised thrust T_i along the rotor's current axis;
//! 2. ground effect (ray along −axis) → near-wall effect (10-ray horizontal fan), from the
//!    poses at the start of the tick;
//! 3. drag and wind on the base;
//! 4. `physics_substeps` rapier steps; before each, every rotor force is re-applied at the
//!    rotor's current position along its current axis, with its reaction torque s_i k_f T_i,
//!    and the joint drives' setpoints move toward their targets at no more than the drive's
//!    velocity limit.
//!
//! The Omni-Hexa's thrust follows the commanded tilt by default, as in the reference, or the
//! measured hinge angle ([`TiltThrust`]). Observation noise, when on, is added to the
//! measurement handed out; [`Twin::truth`] keeps the exact one.

use allocation::{RotorActuator, RotorActuatorConfig};
use nalgebra::{DVector, Isometry3, Point3, UnitQuaternion, Vector3, Vector6};
use platform::{
    ActuatorCommand, ArticulatedBody, DisturbanceReport, Drive, DynamicsWorkspace, Measurement,
    RandomStream, RigidBodyState, RotorReport, TreeState, Vehicle, Wrench,
};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rapier3d_f64::prelude::*;

use crate::aero::{drag_force_in_body, near_wall_thrust, wall_fan_directions};
use crate::config::{TiltThrust, TwinConfig, VehicleDynamics};
use crate::convert::{
    pose_from_rapier, pose_to_rapier, rotation_from_rapier, vector_from_rapier, vector_to_rapier,
};
use crate::error::TwinError;
use crate::tasks::objects::Grasp;
use crate::tasks::{
    Build, GraspMode, HeldJoint, Scene, TaskId, TaskObservation, TaskSnapshot, TaskStatus, View,
};
use crate::vehicle_body::{self, ROBOT_GROUP, VehicleBody, WORLD_GROUP, material};

/// Standard gravity of the world, m/s² (AMBENCH_SPEC §0).
const GRAVITY_MPS2: f64 = platform::GRAVITY_MPS2;

/// How far apart two colliders get contacts (rapier's speculative contacts), m: the
/// reference's PhysX contact offset (0.005 m on its task objects, AMBENCH_SPEC §4.10, §4.12).
/// rapier 0.36's default, 0.02 m, let the FA-Hexa's open fingers push the lemon from 18 mm
/// away (the stem broke at 23 N before the fingers closed: 4 of 30 Lemon Harvesting rollouts
/// failed so, on the FA-Hexa and on the EE-only oracle alike; none at 0.005 m).
pub(crate) const PREDICTION_DISTANCE_M: f64 = 0.005;

/// How near a point of the hand must come to count as touching for
/// [`Twin::hand_contact`], m: any contact point rapier keeps (they start at
/// [`PREDICTION_DISTANCE_M`]; the FA-Hexa's palm pressed on Push Slider's knob rests with
/// its points 3.2–3.9 mm off, as the manifold reports them between full updates).
const HAND_CONTACT_M: f64 = PREDICTION_DISTANCE_M;
/// The part of a contact's unit normal off the touched object's joint motion that blocks the
/// hand for [`Twin::hand_contact`]: sin 60°, the normal at least 60° off that motion.
const HAND_CONTACT_BLOCKED: f64 = 0.866;

/// The part of a contact's unit `normal` (world) that the touched object does not give way
/// along, at the contact point `at`: all of it for a fixed body (`motion` None); without
/// its part along the rail of a prismatic joint, or along the circle's tangent through `at`
/// of a revolute one.
pub(crate) fn blocked_part(
    normal: &Vector3<f64>,
    motion: Option<&HeldJoint>,
    at: &Vector3<f64>,
) -> Vector3<f64> {
    let along = |d: &Vector3<f64>| normal - d * d.dot(normal);
    match motion {
        None => *normal,
        Some(HeldJoint::Prismatic { axis }) => along(&axis.normalize()),
        Some(HeldJoint::Revolute { axis, point }) => {
            match axis.cross(&(at - point)).try_normalize(1e-9) {
                Some(tangent) => along(&tangent),
                None => *normal,
            }
        }
    }
}

/// A rotor's force for the current tick, in its own frame (so it turns with the rotor
/// during substeps), and where it is mounted.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RotorForce {
    /// The body the force acts on and the rotor frame in it: the rotor's own link, or, for a
    /// tilting rotor pushing as commanded, the base with the rotor at its α = 0 position
    /// turned to the commanded angle.
    pub(crate) body: RigidBodyHandle,
    pub(crate) body_from_rotor: Isometry3<f64>,
    /// The physical mount (its own link), for the measured-tilt model.
    mount: (RigidBodyHandle, Isometry3<f64>),
    pub(crate) force_in_rotor: Vector3<f64>,
    pub(crate) reaction_sign: f64,
    /// Configuration index of a tilting rotor's hinge (resolved from its name once).
    tilt_dof: Option<usize>,
}

/// The simulator twin of one vehicle.
pub struct Twin {
    vehicle: Vehicle,
    config: TwinConfig,
    world: PhysicsWorld,
    pub(crate) body: VehicleBody,
    pub(crate) rotors: Vec<RotorForce>,
    actuator: Option<RotorActuator>,
    rng: ChaCha8Rng,
    observation_bias: Vec<f64>,
    joint_targets: Vec<f64>,
    base_force_in_body: Vector3<f64>,
    direct_wrench: Option<Wrench>,
    time_s: f64,
    truth: Measurement,
    /// The realised rotor thrusts of the tick (kept: a step allocates nothing of its own
    /// besides the measurement it returns).
    realised_n: Vec<f64>,
    diverged_at: Option<f64>,
    task: TaskState,
    /// The vehicle's own dynamics (`VehicleDynamics::Articulated`); None: rapier's multibody.
    articulated: Option<Box<Articulated>>,
}

/// How close anything the vehicle can touch may come before rapier's multibody takes the
/// vehicle over from its own dynamics (`VehicleDynamics::Articulated`), m: a tick's travel at
/// 12 m/s of closing speed.
const CONTACT_MARGIN_M: f64 = 0.1;

/// Ticks clear of everything (and holding nothing) before the vehicle's own dynamics takes
/// it back from rapier's multibody.
const CLEAR_TICKS: u32 = 12;

/// The vehicle stepped by `platform::ArticulatedBody` (`VehicleDynamics::Articulated`): its
/// bodies, in the tree's order, are `VehicleBody::bodies` (both segment the links alike).
/// It holds the vehicle while `engaged`; rapier's multibody does otherwise (near anything
/// it can touch, or holding an object), and `state` is stale then.
struct Articulated {
    engaged: bool,
    /// Ticks in a row with nothing within [`CONTACT_MARGIN_M`] and nothing held.
    clear_ticks: u32,
    tree: ArticulatedBody,
    ws: DynamicsWorkspace,
    state: TreeState,
    /// The drives, one per driven joint (their targets follow the setpoints each substep).
    drives: Vec<Drive>,
    /// The base body's centre of mass in its frame (drag and wind act there, as rapier's
    /// `add_force` applies them).
    base_com_in_body: Vector3<f64>,
    /// Buffers of a substep: no joint efforts, the forces on each body, the bodies' world
    /// poses.
    tau: DVector<f64>,
    external: Vec<Vector6<f64>>,
    poses: Vec<Isometry3<f64>>,
    /// An object carried in the grasp, welded to a body of the tree.
    payload: Option<Payload>,
}

/// A held object the vehicle's own dynamics carries (kinematic in rapier meanwhile).
#[derive(Debug, Clone, Copy)]
struct Payload {
    object: RigidBodyHandle,
    /// The tree's body holding it and the object's frame in that body's frame.
    body: usize,
    body_from_object: Isometry3<f64>,
    com_in_body: Vector3<f64>,
    /// Upward force that leaves the object rapier's gravity (its gravity scale), N.
    lift_n: f64,
}

/// The task scene and what the twin keeps for it.
#[derive(Debug, Default)]
struct TaskState {
    scene: Option<Box<dyn Scene>>,
    grasp: Grasp,
    /// Colliders of the two gripping sides.
    fingers: [Vec<ColliderHandle>; 2],
    /// Colliders of the hand: the EE link and every link it carries (fingers, palm, tool).
    hand: Vec<ColliderHandle>,
    /// Configuration indices of the gripper joints.
    gripper_dofs: Vec<usize>,
    /// Env steps since reset.
    steps: u64,
    status: TaskStatus,
}

impl std::fmt::Debug for Twin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Twin")
            .field("vehicle", &self.vehicle.id)
            .field("config", &self.config)
            .field("time_s", &self.time_s)
            .finish_non_exhaustive()
    }
}

impl Twin {
    /// A twin of `vehicle` at its reset pose.
    pub fn new(vehicle: Vehicle, config: TwinConfig) -> Result<Self, TwinError> {
        config.validate().map_err(TwinError::Config)?;
        let actuator = if config.disturbances.saturation && !vehicle.rotors.is_empty() {
            let actuator_config = RotorActuatorConfig {
                time_constant_s: config.motor.time_constant_s,
                speed_rate_limit_per_s: config.motor.rate_limit_per_s,
                ..RotorActuatorConfig::from_layout(&vehicle.rotors)
            };
            Some(
                RotorActuator::new(actuator_config, vehicle.rotors.len())
                    .map_err(|e| TwinError::Config(e.to_string()))?,
            )
        } else {
            None
        };
        let scene = config.task.map(TaskId::scene);
        let overrides = scene
            .as_ref()
            .map(|s| s.initial_overrides(&vehicle))
            .unwrap_or_default();
        let mut q0 = vehicle.initial_configuration();
        for (name, value) in &overrides.joints {
            if let Some(d) = vehicle
                .model
                .joint_id(name)
                .and_then(|j| vehicle.model.joints[j].dof)
            {
                q0[d] = *value;
            }
        }
        let mut world_from_base = config.initial_base_pose;
        if let Some(r) = overrides.base_rotation {
            world_from_base.rotation *= r;
        }
        let (world, body) = Self::build_world(&vehicle, &config, &world_from_base, &q0)?;
        let rotors = Self::rotor_mounts(&vehicle, &body)?;
        let articulated = if config.vehicle_dynamics == VehicleDynamics::Articulated {
            let tree = ArticulatedBody::new(&vehicle.model);
            if tree.body_count() != body.bodies.len() {
                return Err(TwinError::Vehicle(format!(
                    "the articulated dynamics has {} bodies, the world {}",
                    tree.body_count(),
                    body.bodies.len()
                )));
            }
            let drives = body
                .dofs
                .iter()
                .enumerate()
                .filter_map(|(dof, joint)| {
                    joint.drive.map(|d| Drive {
                        dof,
                        stiffness: d.stiffness,
                        damping: d.damping,
                        target: joint.setpoint,
                        effort_limit: d.effort_limit,
                    })
                })
                .collect();
            Some(Box::new(Articulated {
                engaged: false,
                clear_ticks: CLEAR_TICKS,
                ws: tree.workspace(),
                state: TreeState {
                    world_from_base,
                    q: q0.clone(),
                    nu: DVector::zeros(tree.nv()),
                },
                drives,
                base_com_in_body: body.base_com_in_body,
                tau: DVector::zeros(tree.nv()),
                external: vec![Vector6::zeros(); tree.body_count()],
                poses: Vec::new(),
                payload: None,
                tree,
            }))
        } else {
            None
        };
        let task = TaskState::new(&vehicle, &body, scene);
        let mut twin = Self {
            joint_targets: q0,
            vehicle,
            rng: RandomStream::TwinNoise.rng(config.seed),
            config,
            world,
            body,
            rotors,
            actuator,
            observation_bias: Vec::new(),
            base_force_in_body: Vector3::zeros(),
            direct_wrench: None,
            time_s: 0.0,
            truth: Measurement::default(),
            realised_n: Vec::new(),
            diverged_at: None,
            task,
            articulated,
        };
        twin.sample_observation_bias();
        twin.truth = twin.measure(&[], DisturbanceReport::default());
        twin.build_scene()?;
        // Ray casts read the broad phase, which only a step or a collision pass fills. One
        // pass, after every body is in: bodies added after a collision pass would miss the
        // physics pipeline's island registration.
        twin.world.detect_collisions(&(), &());
        // The collision pass consumed the new bodies' change flags without registering them
        // with the islands of the physics pipeline: flag the free bodies again so the first
        // step does (rapier keeps a free body out of an island otherwise, and never moves it).
        let handles: Vec<RigidBodyHandle> = twin.world.bodies.iter().map(|(h, _)| h).collect();
        for h in handles {
            if let Some(rb) = twin.world.bodies.get_mut(h)
                && rb.is_dynamic()
            {
                rb.wake_up(true);
            }
        }
        Ok(twin)
    }

    fn build_world(
        vehicle: &Vehicle,
        config: &TwinConfig,
        world_from_base: &Isometry3<f64>,
        q0: &[f64],
    ) -> Result<(PhysicsWorld, VehicleBody), TwinError> {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -GRAVITY_MPS2);
        world.integration_parameters.dt =
            config.control_dt_s() / f64::from(config.physics_substeps);
        let (steps, passes) = config.rapier_solver(false);
        world.integration_parameters.num_solver_iterations = steps;
        world.integration_parameters.num_internal_pgs_iterations = passes;
        world.integration_parameters.normalized_prediction_distance = PREDICTION_DISTANCE_M;
        // The ground: a half-space at z = 0.
        let ground = world.insert_body(RigidBodyBuilder::fixed());
        let groups = InteractionGroups::new(WORLD_GROUP, Group::ALL, InteractionTestMode::And);
        world.insert_collider(
            material(ColliderBuilder::halfspace(
                rapier3d_f64::na::Unit::new_unchecked(Vector::Z),
            ))
            .collision_groups(groups),
            Some(ground),
        );
        let body = vehicle_body::build(vehicle, &mut world, world_from_base, q0)?;
        Ok((world, body))
    }

    fn rotor_mounts(vehicle: &Vehicle, body: &VehicleBody) -> Result<Vec<RotorForce>, TwinError> {
        vehicle
            .rotors
            .rotors
            .iter()
            .map(|r| {
                let link = vehicle.model.link_id(&r.link).ok_or_else(|| {
                    TwinError::Vehicle(format!("rotor link '{}' is not in the model", r.link))
                })?;
                let (body, body_from_rotor) = body.of_link(link);
                let tilt_dof = r
                    .tilt
                    .as_ref()
                    .and_then(|t| vehicle.model.joint_id(&t.joint))
                    .and_then(|j| vehicle.model.joints[j].dof);
                Ok(RotorForce {
                    body,
                    body_from_rotor,
                    mount: (body, body_from_rotor),
                    force_in_rotor: Vector3::zeros(),
                    reaction_sign: r.spin.sign(),
                    tilt_dof,
                })
            })
            .collect()
    }

    /// Back to the reset pose and joints, time zero, motor state and noise bias re-drawn
    /// from `seed`. Bit-identical to a new twin with that seed.
    pub fn reset(&mut self, seed: u64) -> Result<(), TwinError> {
        self.config.seed = seed;
        let fresh = Self::new(self.vehicle.clone(), self.config.clone())?;
        *self = fresh;
        Ok(())
    }

    /// A new episode: the task scene `task` (None: the empty world) at `seed`, as a new twin
    /// with that configuration.
    pub fn reset_episode(&mut self, task: Option<TaskId>, seed: u64) -> Result<(), TwinError> {
        self.config.task = task;
        self.reset(seed)
    }

    /// The vehicle simulated.
    pub fn vehicle(&self) -> &Vehicle {
        &self.vehicle
    }

    /// The configuration in use.
    pub fn config(&self) -> &TwinConfig {
        &self.config
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// The exact measurement at the current time (no observation noise).
    pub fn truth(&self) -> &Measurement {
        &self.truth
    }

    /// The vehicle's linear momentum (kg·m/s) and its angular momentum about the world origin
    /// (kg·m²/s), from the engine that holds it: p = Σ m v_c and L = Σ (c × m v_c + R I_c Rᵀ ω)
    /// over rapier's bodies, or the first six rows of M ν of the vehicle's own dynamics
    /// (which count an object it carries as a payload; rapier's count the vehicle alone).
    pub fn vehicle_momentum(&self) -> (Vector3<f64>, Vector3<f64>) {
        if let Some(a) = self.articulated.as_deref().filter(|a| a.engaged) {
            let mut ws = a.tree.workspace();
            let h = a.tree.momentum(&a.state.q, &a.state.nu, &mut ws);
            let r = a.state.world_from_base.rotation;
            let p = r * Vector3::new(h[0], h[1], h[2]);
            let l_origin = r * Vector3::new(h[3], h[4], h[5]);
            let o = a.state.world_from_base.translation.vector;
            return (p, l_origin + o.cross(&p));
        }
        let mut p = Vector3::zeros();
        let mut l = Vector3::zeros();
        for rb in self
            .body
            .bodies
            .iter()
            .filter_map(|h| self.world.bodies.get(*h))
        {
            let m = rb.mass();
            let c = vector_from_rapier(rb.center_of_mass());
            let v = vector_from_rapier(rb.linvel());
            let w = vector_from_rapier(rb.angvel());
            let r = rotation_from_rapier(rb.position().rotation).to_rotation_matrix();
            let i = rb
                .mass_properties()
                .local_mprops
                .reconstruct_inertia_matrix();
            let i_local = nalgebra::Matrix3::from_fn(|row, col| i.col(col)[row]);
            p += m * v;
            l += c.cross(&(m * v)) + r * i_local * r.transpose() * w;
        }
        (p, l)
    }

    /// True if the vehicle's own dynamics stepped it on the last tick
    /// (`VehicleDynamics::Articulated` in free flight); false when rapier's multibody did.
    pub fn on_own_dynamics(&self) -> bool {
        self.articulated.as_ref().is_some_and(|a| a.engaged)
    }

    /// The physics world, read-only (the renderer's view of the scene, [`crate::visuals`]).
    pub(crate) fn world(&self) -> &PhysicsWorld {
        &self.world
    }

    /// The physics world, for scenes that add bodies (they belong to [`WORLD_GROUP`]).
    pub fn world_mut(&mut self) -> &mut PhysicsWorld {
        &mut self.world
    }

    /// Adds a fixed box (a wall, a table) to the world: `pose` of its centre, half extents m.
    pub fn add_fixed_box(
        &mut self,
        pose: &Isometry3<f64>,
        half_extents_m: &Vector3<f64>,
    ) -> ColliderHandle {
        let body = self
            .world
            .insert_body(RigidBodyBuilder::fixed().pose(pose_to_rapier(pose)));
        let groups = InteractionGroups::new(WORLD_GROUP, Group::ALL, InteractionTestMode::And);
        let collider = material(ColliderBuilder::cuboid(
            half_extents_m.x,
            half_extents_m.y,
            half_extents_m.z,
        ))
        .collision_groups(groups);
        let handle = self.world.insert_collider(collider, Some(body));
        // Ray casts read the broad phase, which a step updates; keep queries right at once.
        self.world.detect_collisions(&(), &());
        handle
    }

    /// Sets the base's world velocity (initial conditions, tests).
    pub fn set_base_velocity(&mut self, velocity_in_world_mps: &Vector3<f64>) {
        if let Some(a) = self.articulated.as_deref_mut().filter(|a| a.engaged) {
            let v = a.state.world_from_base.rotation.inverse() * velocity_in_world_mps;
            for i in 0..3 {
                a.state.nu[i] = v[i];
            }
        } else {
            vehicle_body::set_linear_velocity(&mut self.world, &self.body, velocity_in_world_mps);
        }
        self.truth = self.measure(&[], DisturbanceReport::default());
    }

    fn check(&self, command: &ActuatorCommand) -> Result<(), TwinError> {
        let rotors = self.vehicle.rotors.len();
        if command.rotor_thrusts_n.len() != rotors {
            return Err(TwinError::Command(format!(
                "{} rotor thrusts for {rotors} rotors",
                command.rotor_thrusts_n.len()
            )));
        }
        let dof = self.vehicle.model.dof();
        if command.joint_targets.len() != dof {
            return Err(TwinError::Command(format!(
                "{} joint targets for {dof} joints",
                command.joint_targets.len()
            )));
        }
        let finite_wrench = command.direct_wrench_in_body.is_none_or(|w| w.is_finite());
        if !finite_wrench
            || !command
                .rotor_thrusts_n
                .iter()
                .chain(&command.joint_targets)
                .all(|x| x.is_finite())
        {
            return Err(TwinError::Command("a value is not finite".to_owned()));
        }
        Ok(())
    }

    /// Applies `command` for one control period and returns the measurement at its end
    /// (with observation noise if that is on).
    ///
    /// A diverged simulation is an error, never a panic: rapier panics on some non-finite
    /// states, and that panic is caught here and reported as [`TwinError::Diverged`] (the
    /// twin must then be reset). A non-finite or ill-shaped command is
    /// [`TwinError::Command`] and leaves the twin as it was.
    pub fn step(&mut self, command: &ActuatorCommand) -> Result<Measurement, TwinError> {
        self.check(command)?;
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.step_checked(command)))
            .unwrap_or_else(|_| {
                Err(TwinError::Diverged(
                    "the physics engine panicked (non-finite state)".to_owned(),
                ))
            })
    }

    fn step_checked(&mut self, command: &ActuatorCommand) -> Result<Measurement, TwinError> {
        let dt = self.config.control_dt_s();
        let mut realised = std::mem::take(&mut self.realised_n);
        self.realise_thrusts(&command.rotor_thrusts_n, dt, &mut realised)?;
        self.place_tilting_rotors(&command.joint_targets);
        // The last tick's rotor reports make room for this tick's (no allocation).
        let mut reports = std::mem::take(&mut self.truth.rotors);
        let mut disturbances = self.rotor_forces(&command.rotor_thrusts_n, &realised, &mut reports);
        self.realised_n = realised;
        self.base_forces(&mut disturbances);
        self.direct_wrench = command.direct_wrench_in_body;
        for (target, (q, dof)) in self
            .joint_targets
            .iter_mut()
            .zip(command.joint_targets.iter().zip(&self.body.dofs))
        {
            *target = dof.limits.map_or(*q, |(lo, hi)| q.clamp(lo, hi));
        }
        if let Some(when) = self.diverged_at {
            self.truth.rotors = reports;
            return Err(TwinError::Diverged(format!(
                "the simulation diverged at t = {when:.3} s; reset the twin"
            )));
        }
        if let Err(e) = self.choose_vehicle_engine() {
            self.truth.rotors = reports;
            return Err(e);
        }
        let (steps, passes) = self.config.rapier_solver(self.held_joint().is_some());
        self.world.integration_parameters.num_solver_iterations = steps;
        self.world
            .integration_parameters
            .num_internal_pgs_iterations = passes;
        let substep = dt / f64::from(self.config.physics_substeps);
        for k in 1..=self.config.physics_substeps {
            if self.articulated.as_ref().is_some_and(|a| a.engaged) {
                self.advance_drives(substep);
                if !self.articulated_substep(substep, k == self.config.physics_substeps) {
                    self.diverged_at = Some(self.time_s);
                    self.truth.rotors = reports;
                    return Err(TwinError::Diverged(format!(
                        "the vehicle's dynamics diverged at t = {:.3} s; reset the twin",
                        self.time_s
                    )));
                }
            } else {
                self.apply_forces();
                self.advance_drives(substep);
            }
            // On the vehicle's own dynamics with nothing else awake in the world, rapier has
            // nothing to simulate until the vehicle's bodies move (the tick's last substep).
            let idle_world = k < self.config.physics_substeps
                && self.on_own_dynamics()
                && !self
                    .world
                    .active_bodies()
                    .any(|(h, _)| !self.body.bodies.contains(&h));
            if !idle_world {
                self.world.step();
            }
            // A non-finite body state would make rapier panic on the next step: stop here.
            if let Some(why) = self.unphysical_body() {
                self.diverged_at = Some(self.time_s);
                self.truth.rotors = reports;
                return Err(TwinError::Diverged(format!(
                    "the simulation diverged at t = {:.3} s ({why}); reset the twin",
                    self.time_s
                )));
            }
        }
        self.time_s += dt;
        let mut truth = std::mem::take(&mut self.truth);
        self.measure_into(reports, disturbances, &mut truth);
        self.truth = truth;
        self.update_task();
        Ok(self.observe())
    }

    /// The first free body (vehicle or scene) whose state is not finite or past physical
    /// bounds (position 1e4 m, speed 200 m/s, angular speed 2e3 rad/s), said in words; None
    /// when every body is within them. A jammed multibody blows up over a few steps before
    /// its state turns NaN (and rapier panics on NaN), so speeds and positions no flight
    /// reaches count as divergence too.
    fn unphysical_body(&self) -> Option<String> {
        const MAX_POSITION_M: f64 = 1.0e4;
        const MAX_SPEED_MPS: f64 = 200.0;
        const MAX_ANGULAR_SPEED_RADPS: f64 = 2.0e3;
        // The bound a body's state passes, if any (said after the body's name, which is
        // looked up only then: this runs every substep).
        let passed = |position: f64, speed: f64, spin: f64, finite: bool| {
            if !finite {
                Some("has a state that is not finite".to_owned())
            } else if position >= MAX_POSITION_M {
                Some(format!("is {position:.0} m from the origin"))
            } else if speed >= MAX_SPEED_MPS {
                Some(format!("moves at {speed:.0} m/s"))
            } else if spin >= MAX_ANGULAR_SPEED_RADPS {
                Some(format!("spins at {spin:.0} rad/s"))
            } else {
                None
            }
        };
        if let Some(a) = self.articulated.as_deref().filter(|a| a.engaged) {
            let s = &a.state;
            let finite = s
                .world_from_base
                .translation
                .vector
                .iter()
                .all(|x| x.is_finite())
                && s.q.iter().all(|x| x.is_finite())
                && s.nu.iter().all(|x| x.is_finite());
            let v = Vector3::new(s.nu[0], s.nu[1], s.nu[2]);
            let w = Vector3::new(s.nu[3], s.nu[4], s.nu[5]);
            let position = s.world_from_base.translation.vector.norm();
            if let Some(why) = passed(position, v.norm(), w.norm(), finite) {
                return Some(format!("the vehicle's base {why}"));
            }
        }
        self.world.bodies.iter().find_map(|(handle, rb)| {
            if !rb.is_dynamic() {
                return None;
            }
            let p = rb.position();
            let finite = |v: Vector| v.x.is_finite() && v.y.is_finite() && v.z.is_finite();
            let why = passed(
                p.translation.length(),
                rb.linvel().length(),
                rb.angvel().length(),
                finite(p.translation)
                    && p.rotation.is_finite()
                    && finite(rb.linvel())
                    && finite(rb.angvel()),
            )?;
            let what = if self.body.bodies.contains(&handle) {
                "a vehicle link"
            } else {
                "a scene object"
            };
            Some(format!("{what} {why}"))
        })
    }

    /// Motor model: the rotor actuator with limits on, the raw command otherwise.
    fn realise_thrusts(
        &mut self,
        commanded: &[f64],
        dt: f64,
        realised: &mut Vec<f64>,
    ) -> Result<(), TwinError> {
        realised.clear();
        match &mut self.actuator {
            Some(a) => realised.extend(
                a.step(commanded, dt)
                    .map_err(|e| TwinError::Command(e.to_string()))?
                    .iter()
                    .map(|t| t.thrust_n),
            ),
            None => realised.extend_from_slice(commanded),
        }
        Ok(())
    }

    fn world_from(&self, body: RigidBodyHandle) -> Isometry3<f64> {
        self.world
            .bodies
            .get(body)
            .map_or_else(Isometry3::identity, |rb| pose_from_rapier(rb.position()))
    }

    /// Where each tilting rotor pushes from this tick: its own link (measured tilt), or the
    /// base with the rotor at its α = 0 position turned to the commanded angle.
    fn place_tilting_rotors(&mut self, joint_targets: &[f64]) {
        let base = self.body.base;
        for (force, rotor) in self.rotors.iter_mut().zip(&self.vehicle.rotors.rotors) {
            let Some(tilt) = &rotor.tilt else { continue };
            (force.body, force.body_from_rotor) = match self.config.tilt_thrust {
                TiltThrust::Measured => force.mount,
                TiltThrust::Commanded => {
                    let commanded = force
                        .tilt_dof
                        .and_then(|d| joint_targets.get(d).copied())
                        .unwrap_or(0.0)
                        .clamp(tilt.limits_rad.0, tilt.limits_rad.1);
                    let axis = nalgebra::Unit::new_normalize(rotor.axis_at_tilt(commanded));
                    let rotation = UnitQuaternion::rotation_between_axis(&Vector3::z_axis(), &axis)
                        .unwrap_or_else(UnitQuaternion::identity);
                    (
                        base,
                        Isometry3::from_parts(
                            nalgebra::Translation3::from(rotor.position_in_base),
                            rotation,
                        ),
                    )
                }
            };
        }
    }

    /// What the aerodynamic rays see: everything but the robot.
    fn ray_filter() -> QueryFilter<'static> {
        QueryFilter::default().groups(InteractionGroups::new(
            Group::ALL,
            Group::ALL.difference(ROBOT_GROUP),
            InteractionTestMode::And,
        ))
    }

    /// Casts a ray that ignores the robot; the distance to the first hit or the maximum.
    fn cast(&self, origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<f64> {
        let ray = Ray::new(vector_to_rapier(origin), vector_to_rapier(direction));
        self.world
            .cast_ray(
                &ray,
                self.config.aero.max_raycast_distance_m,
                true,
                Self::ray_filter(),
            )
            .map(|(_, toi)| toi)
    }

    /// Whether a ray inside `region` may hit anything: a ray cast walks the broad phase's
    /// boxes and reaches a collider only through its box, so with no box of what the rays
    /// see meeting `region` (a half-space by its plane) every ray inside it misses. Exact:
    /// the same boxes, the same filter.
    fn rays_may_hit_within(&self, region: &Aabb) -> bool {
        self.world
            .intersect_aabb_conservative(*region, Self::ray_filter())
            .any(|(_, other)| match boundary_plane(other) {
                Some((normal, point)) => box_height_over_plane(region, &normal, &point) <= 0.0,
                None => true,
            })
    }

    /// Per-rotor thrust vectors after the proximity effects, fixed in each rotor's frame for
    /// this tick, and what each effect added (`reports`: one per rotor, replaced).
    fn rotor_forces(
        &mut self,
        commanded: &[f64],
        realised: &[f64],
        reports: &mut Vec<RotorReport>,
    ) -> DisturbanceReport {
        let d = self.config.disturbances;
        let aero = self.config.aero;
        let radius = self.vehicle.rotors.propeller_radius_m;
        let max = aero.max_raycast_distance_m;
        let world_from_base = self.world_from(self.body.base);
        let base_rotation = world_from_base.rotation;
        let mut disturbances = DisturbanceReport::default();
        reports.clear();
        // The near-wall fans are horizontal rays of length `max` from the rotors: in free
        // flight nothing is within their box and none of the 10 rays per rotor is cast.
        let wall_rays_may_hit = d.near_wall && {
            let mut lo = Vector3::repeat(f64::INFINITY);
            let mut hi = Vector3::repeat(f64::NEG_INFINITY);
            for r in &self.rotors {
                let p = (self.world_from(r.body) * r.body_from_rotor)
                    .translation
                    .vector;
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
            let reach = Vector3::new(max, max, 0.0);
            self.rays_may_hit_within(&Aabb::new(
                vector_to_rapier(&(lo - reach)),
                vector_to_rapier(&(hi + reach)),
            ))
        };
        for i in 0..self.rotors.len() {
            let mount = self.rotors[i];
            let world_from_rotor = self.world_from(mount.body) * mount.body_from_rotor;
            let position = world_from_rotor.translation.vector;
            let axis = world_from_rotor.rotation * Vector3::z();
            let thrust = axis * realised[i];
            let mut report = RotorReport {
                commanded_n: commanded[i],
                realised_n: realised[i],
                saturated: self
                    .actuator
                    .as_ref()
                    .is_some_and(|a| a.telemetry().get(i).is_some_and(|t| t.saturated)),
                ground_effect_gain: 1.0,
                ground_distance_m: max,
                wall_distance_m: max,
                ..RotorReport::default()
            };
            let mut after_ground = thrust;
            if d.ground_effect {
                let distance = self.cast(&position, &(-axis)).unwrap_or(max);
                let ratio = aero.ground_effect_ratio(distance, radius);
                report.ground_distance_m = distance;
                report.ground_effect_gain = 1.0 / ratio;
                after_ground = thrust / ratio;
            }
            let mut after_wall = after_ground;
            if d.near_wall {
                let radial = position - world_from_base.translation.vector;
                let base_angle = if radial.xy().norm() > 1e-6 {
                    radial.y.atan2(radial.x)
                } else {
                    0.0
                };
                let nearest = wall_fan_directions(base_angle)
                    .into_iter()
                    .filter(|_| wall_rays_may_hit)
                    .filter_map(|dir| self.cast(&position, &dir).map(|h| (h, dir)))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let (h, toward) = nearest.unwrap_or((max, Vector3::zeros()));
                report.wall_distance_m = h;
                let normalised = (h - radius).max(0.0) / radius;
                after_wall = near_wall_thrust(&aero, &after_ground, normalised, &toward);
            }
            disturbances.ground_effect_n += base_rotation.inverse() * (after_ground - thrust);
            disturbances.near_wall_n += base_rotation.inverse() * (after_wall - after_ground);
            // Signed along the rotor's axis: an ideal rotor may push backwards (a negative
            // thrust), and the report keeps that sign.
            report.applied_n = after_wall.norm().copysign(after_wall.dot(&axis));
            self.rotors[i].force_in_rotor = world_from_rotor.rotation.inverse() * after_wall;
            reports.push(report);
        }
        disturbances
    }

    /// Drag and wind on the base, body frame, held over the tick.
    fn base_forces(&mut self, disturbances: &mut DisturbanceReport) {
        let d = self.config.disturbances;
        let base = &self.truth.base;
        let to_body = base.world_from_body.inverse();
        if d.drag {
            disturbances.drag_n =
                drag_force_in_body(&self.config.aero, &(to_body * base.velocity_in_world_mps));
        }
        if d.wind {
            disturbances.wind_n = to_body * Vector3::from(self.config.aero.wind_force_in_world_n);
        }
        self.base_force_in_body = disturbances.drag_n + disturbances.wind_n;
    }

    /// One physics substep of the vehicle's own dynamics (`VehicleDynamics::Articulated`):
    /// the forces of the tick at the bodies' current poses (as [`Self::apply_forces`] applies
    /// them to rapier's bodies), the drives at their setpoints, `solver_iterations`
    /// implicit-drive steps, and, on the tick's `last` substep, the kinematic bodies sent to
    /// the new poses for rapier's step (nothing can touch the vehicle within a tick of free
    /// flight — `CONTACT_MARGIN_M` — so its colliders move once per tick: rapier refits a
    /// moved collider's bounding box at every step it moves, a tenth of the tick's time when
    /// they moved every substep). False if a step failed.
    fn articulated_substep(&mut self, h: f64, last: bool) -> bool {
        let Some(a) = self.articulated.as_deref_mut() else {
            return true;
        };
        a.tree
            .body_poses(&a.state.world_from_base, &a.state.q, &mut a.poses);
        for f in &mut a.external {
            *f = Vector6::zeros();
        }
        let bodies = &self.body.bodies;
        let index = |h: RigidBodyHandle| bodies.iter().position(|b| *b == h);
        // A world force through a world point on body i, plus a world torque.
        let mut push =
            |i: usize, force: &Vector3<f64>, point: &Vector3<f64>, torque: &Vector3<f64>| {
                let pose = &a.poses[i];
                let to_body = pose.rotation.inverse();
                let f = to_body * force;
                let n = to_body * ((point - pose.translation.vector).cross(force) + torque);
                a.external[i] += Vector6::new(f.x, f.y, f.z, n.x, n.y, n.z);
            };
        let k_f = self.vehicle.rotors.reaction_torque_ratio_m;
        for r in &self.rotors {
            let Some(i) = index(r.body) else { continue };
            let world_from_rotor = a.poses[i] * r.body_from_rotor;
            let force = world_from_rotor.rotation * r.force_in_rotor;
            push(
                i,
                &force,
                &world_from_rotor.translation.vector,
                &(force * (r.reaction_sign * k_f)),
            );
        }
        let base = a.poses[0];
        push(
            0,
            &(base.rotation * self.base_force_in_body),
            &(base * Point3::from(a.base_com_in_body)).coords,
            &Vector3::zeros(),
        );
        if let Some(w) = self.direct_wrench {
            push(
                0,
                &(base.rotation * w.force),
                &base.translation.vector,
                &(base.rotation * w.torque),
            );
        }
        if let Some(p) = &a.payload
            && p.lift_n != 0.0
        {
            let pose = a.poses[p.body];
            push(
                p.body,
                &Vector3::new(0.0, 0.0, p.lift_n),
                &(pose * Point3::from(p.com_in_body)).coords,
                &Vector3::zeros(),
            );
        }
        for d in &mut a.drives {
            d.target = self.body.dofs[d.dof].setpoint;
        }
        // `solver_iterations` steps of the dynamics per substep (rapier's TGS likewise splits
        // each substep into its iterations), the forces held in the bodies' axes, the mass
        // matrix of each step its own: kept through a substep's steps (as rapier keeps its),
        // the momentum balance over a 10 s arm sweep missed by 0.13 N s, against 0.006 N s
        // with it fresh and rapier's 0.042 (test `momentum_change_equals_…`).
        let steps = self
            .config
            .own_dynamics_steps
            .unwrap_or(self.config.solver_iterations);
        let dt = h / f64::from(steps);
        for _ in 0..steps {
            if !a
                .tree
                .step(&mut a.state, &a.tau, &a.external, &a.drives, dt, &mut a.ws)
            {
                return false;
            }
        }
        if last || a.payload.is_some() {
            a.tree
                .body_poses(&a.state.world_from_base, &a.state.q, &mut a.poses);
        }
        if last {
            for (h, pose) in bodies.iter().zip(&a.poses) {
                if let Some(rb) = self.world.bodies.get_mut(*h) {
                    rb.set_next_kinematic_position(pose_to_rapier(pose));
                }
            }
        }
        // A carried object moves every substep, so rapier's velocity of it (its motion
        // over the substep) is the object's.
        if let Some(p) = &a.payload
            && let Some(rb) = self.world.bodies.get_mut(p.object)
        {
            rb.set_next_kinematic_position(pose_to_rapier(&(a.poses[p.body] * p.body_from_object)));
        }
        true
    }

    /// Re-applies every force of the tick at the bodies' current poses.
    fn apply_forces(&mut self) {
        for h in &self.body.bodies {
            if let Some(rb) = self.world.bodies.get_mut(*h) {
                rb.reset_forces(false);
                rb.reset_torques(false);
            }
        }
        let k_f = self.vehicle.rotors.reaction_torque_ratio_m;
        for r in &self.rotors {
            let Some(rb) = self.world.bodies.get_mut(r.body) else {
                continue;
            };
            let world_from_rotor = pose_from_rapier(rb.position()) * r.body_from_rotor;
            let force = world_from_rotor.rotation * r.force_in_rotor;
            rb.add_force_at_point(
                vector_to_rapier(&force),
                vector_to_rapier(&world_from_rotor.translation.vector),
                true,
            );
            rb.add_torque(vector_to_rapier(&(force * (r.reaction_sign * k_f))), true);
        }
        if let Some(rb) = self.world.bodies.get_mut(self.body.base) {
            let world_from_base = pose_from_rapier(rb.position());
            let r = world_from_base.rotation;
            rb.add_force(vector_to_rapier(&(r * self.base_force_in_body)), true);
            if let Some(w) = self.direct_wrench {
                rb.add_force_at_point(
                    vector_to_rapier(&(r * w.force)),
                    vector_to_rapier(&world_from_base.translation.vector),
                    true,
                );
                rb.add_torque(vector_to_rapier(&(r * w.torque)), true);
            }
        }
    }

    /// Moves each drive's setpoint toward its target at no more than its velocity limit.
    fn advance_drives(&mut self, dt: f64) {
        for (dof, target) in self.body.dofs.iter_mut().zip(&self.joint_targets) {
            let Some(drive) = dof.drive else { continue };
            let step = drive.velocity_limit * dt;
            dof.setpoint += (target - dof.setpoint).clamp(-step, step);
            if let Some((mb, link)) = self.world.multibody_joints.get_mut(dof.handle)
                && let Some(l) = mb.link_mut(link)
            {
                l.joint.data.set_motor_position(
                    dof.axis,
                    dof.setpoint,
                    drive.stiffness,
                    drive.damping,
                );
            }
        }
    }

    /// The exact state now.
    pub(crate) fn measure(
        &self,
        rotors: &[RotorReport],
        disturbances: DisturbanceReport,
    ) -> Measurement {
        let mut m = Measurement::default();
        self.measure_into(rotors.to_vec(), disturbances, &mut m);
        m
    }

    /// [`Self::measure`] into `m`, reusing its joint vectors (no allocation).
    fn measure_into(
        &self,
        rotors: Vec<RotorReport>,
        disturbances: DisturbanceReport,
        m: &mut Measurement,
    ) {
        let base = if let Some(a) = self.articulated.as_deref().filter(|a| a.engaged) {
            // The vehicle's own dynamics hold the state (rapier's bodies are kinematic).
            let s = &a.state;
            let r = s.world_from_base.rotation;
            m.joint_positions.clear();
            m.joint_positions.extend_from_slice(&s.q);
            m.joint_velocities.clear();
            m.joint_velocities.extend(s.nu.iter().skip(6).copied());
            RigidBodyState {
                position_in_world_m: s.world_from_base.translation.vector,
                world_from_body: r,
                velocity_in_world_mps: r * Vector3::new(s.nu[0], s.nu[1], s.nu[2]),
                angular_velocity_in_body_radps: Vector3::new(s.nu[3], s.nu[4], s.nu[5]),
            }
        } else {
            vehicle_body::joint_states(
                &self.world,
                &self.body.dofs,
                &mut m.joint_positions,
                &mut m.joint_velocities,
            );
            self.rapier_base_state()
        };
        let (ee_body, body_from_ee) = self.body.of_link(self.vehicle.ee_link);
        m.time_s = self.time_s;
        m.base = base;
        m.world_from_ee = self.world_from(ee_body) * body_from_ee;
        m.rotors = rotors;
        m.disturbances = disturbances;
    }

    /// The base's state as rapier's multibody holds it.
    fn rapier_base_state(&self) -> RigidBodyState {
        self.world
            .bodies
            .get(self.body.base)
            .map(|rb| {
                let pose = pose_from_rapier(rb.position());
                let omega_world = vector_from_rapier(rb.angvel());
                // The centre of mass from the pose (rapier updates its world copy, and
                // computes its local one, only in steps).
                let com = (pose * Point3::from(self.body.base_com_in_body)).coords;
                let origin = pose.translation.vector;
                RigidBodyState {
                    position_in_world_m: origin,
                    world_from_body: rotation_from_rapier(rb.position().rotation),
                    velocity_in_world_mps: vector_from_rapier(rb.linvel())
                        + omega_world.cross(&(origin - com)),
                    angular_velocity_in_body_radps: pose.rotation.inverse() * omega_world,
                }
            })
            .unwrap_or_default()
    }

    /// Which engine steps the vehicle this tick (`VehicleDynamics::Articulated`): rapier's
    /// multibody while anything the vehicle can touch is within [`CONTACT_MARGIN_M`] of one
    /// of its colliders or it holds an object it cannot carry (contacts and the grasp act on it
    /// there; [`Self::carried_object`] says which it can), its
    /// own dynamics once it has been clear for [`CLEAR_TICKS`] ticks. The state is handed
    /// over exactly (poses, joints, velocities).
    fn choose_vehicle_engine(&mut self) -> Result<(), TwinError> {
        let Some(engaged) = self.articulated.as_ref().map(|a| a.engaged) else {
            return Ok(());
        };
        // An object held by a weld, free of any other joint and itself clear of everything,
        // rides along as a payload of the vehicle's own dynamics; any other grasp keeps the
        // vehicle on rapier's multibody.
        let carried = self.carried_object();
        let held = self.task.grasp.held.is_some();
        let near = (held && carried.is_none()) || self.near_anything();
        let payload = self
            .articulated
            .as_ref()
            .and_then(|a| a.payload.as_ref().map(|p| p.object));
        if engaged && !near && payload.is_some() && payload != carried.map(|c| c.0) {
            // Released (or out of reach of the weld): the object is rapier's again.
            self.release_payload();
        }
        let Some(a) = self.articulated.as_deref_mut() else {
            return Ok(());
        };
        if near {
            a.clear_ticks = 0;
            if engaged {
                self.hand_to_rapier()?;
            }
        } else if !engaged {
            a.clear_ticks = a.clear_ticks.saturating_add(1);
            if a.clear_ticks >= CLEAR_TICKS {
                self.take_from_rapier();
                if let Some((object, body)) = carried {
                    self.carry(object, body);
                }
            }
        } else if let Some((object, body)) = carried
            && a.payload.is_none()
        {
            self.carry(object, body);
        }
        Ok(())
    }

    /// The object the grasp holds, with the vehicle body (index) holding it, if the
    /// vehicle's own dynamics can carry it as a payload: held by a weld (an object that
    /// spins in the fingers is not), on no other joint, not driven by anything but gravity
    /// (no damping, no applied force), and nothing it can touch within [`CONTACT_MARGIN_M`].
    fn carried_object(&self) -> Option<(RigidBodyHandle, usize)> {
        let (object, joint) = self.task.grasp.held?;
        let joint = self.world.impulse_joints.get(joint)?;
        if joint.data.locked_axes != JointAxesMask::LOCKED_FIXED_AXES || joint.body2() != object {
            return None;
        }
        let body = self.body.bodies.iter().position(|b| *b == joint.body1())?;
        let rb = self.world.bodies.get(object)?;
        let payload = self
            .articulated
            .as_ref()
            .and_then(|a| a.payload.as_ref())
            .map(|p| p.object);
        let free = (rb.is_dynamic() || payload == Some(object))
            && self.world.impulse_joints.attached_joints(object).count() == 1
            && self
                .world
                .multibody_joints
                .rigid_body_link(object)
                .is_none()
            && rb.linear_damping() == 0.0
            && rb.angular_damping() == 0.0
            && rb.user_force() == Vector::ZERO
            && rb.user_torque() == AngVector::ZERO;
        if !free {
            return None;
        }
        let groups = rb
            .colliders()
            .first()
            .and_then(|c| self.world.colliders.get(*c))?
            .collision_groups();
        let filter = QueryFilter::default()
            .exclude_sensors()
            .exclude_rigid_body(object)
            .groups(groups);
        let colliders = || {
            rb.colliders()
                .iter()
                .filter_map(|h| self.world.colliders.get(*h))
        };
        (!self.within_margin(colliders, filter)).then_some((object, body))
    }

    /// Welds `object` to the vehicle's body `body` in its own dynamics (engaged): its mass
    /// joins the body's where it is now, and rapier moves it kinematically with the body.
    fn carry(&mut self, object: RigidBodyHandle, body: usize) {
        let Some(a) = self.articulated.as_deref_mut() else {
            return;
        };
        let Some(rb) = self.world.bodies.get_mut(object) else {
            return;
        };
        a.tree
            .body_poses(&a.state.world_from_base, &a.state.q, &mut a.poses);
        let Some(world_from_body) = a.poses.get(body).copied() else {
            return;
        };
        let body_from_object = world_from_body.inverse() * pose_from_rapier(rb.position());
        let mprops = rb.mass_properties().local_mprops;
        let com_in_body = body_from_object * Point3::from(vector_from_rapier(mprops.local_com));
        let i = mprops.reconstruct_inertia_matrix();
        let i_object = nalgebra::Matrix3::from_fn(|row, col| i.col(col)[row]);
        let r = body_from_object.rotation.to_rotation_matrix().into_inner();
        a.tree.add_payload(
            body,
            mprops.mass(),
            &com_in_body.coords,
            &(r * i_object * r.transpose()),
        );
        // The tree pulls the payload down with g; rapier with its gravity scale.
        let lift_n = (1.0 - rb.gravity_scale()) * mprops.mass() * platform::GRAVITY_MPS2;
        rb.set_body_type(RigidBodyType::KinematicPositionBased, true);
        a.payload = Some(Payload {
            object,
            body,
            body_from_object,
            com_in_body: com_in_body.coords,
            lift_n,
        });
    }

    /// Hands a carried object back to rapier: dynamic again, moving as the body carrying it
    /// moves (its centre of mass's velocity and the body's angular velocity).
    fn release_payload(&mut self) {
        let Some(a) = self.articulated.as_deref_mut() else {
            return;
        };
        let Some(p) = a.payload.take() else {
            return;
        };
        let twist = a.tree.body_velocity(&a.state, p.body, &mut a.ws);
        a.tree.clear_payloads();
        a.tree
            .body_poses(&a.state.world_from_base, &a.state.q, &mut a.poses);
        let r = a.poses[p.body].rotation;
        let v = Vector3::new(twist[0], twist[1], twist[2]);
        let w = Vector3::new(twist[3], twist[4], twist[5]);
        if let Some(rb) = self.world.bodies.get_mut(p.object) {
            rb.set_body_type(RigidBodyType::Dynamic, true);
            rb.set_linvel(vector_to_rapier(&(r * (v + w.cross(&p.com_in_body)))), true);
            rb.set_angvel(vector_to_rapier(&(r * w)), true);
        }
    }

    /// True if a collider the vehicle can touch (not a sensor, not an object it holds) is
    /// within [`CONTACT_MARGIN_M`] of one of the vehicle's colliders: the candidates by
    /// bounding boxes (the whole vehicle's, then each collider's), then the exact distance
    /// (a pair parry cannot measure counts as near).
    fn near_anything(&self) -> bool {
        let filter = QueryFilter::default()
            .exclude_sensors()
            .groups(InteractionGroups::new(
                ROBOT_GROUP,
                Group::ALL.difference(ROBOT_GROUP),
                InteractionTestMode::And,
            ));
        let vehicle = || {
            self.body
                .link_colliders
                .iter()
                .flatten()
                .filter_map(|h| self.world.colliders.get(*h))
        };
        self.within_margin(vehicle, filter)
    }

    /// True if a collider `filter` passes is within [`CONTACT_MARGIN_M`] of one of
    /// `colliders` (see [`Self::near_anything`]).
    fn within_margin<'a, I: Iterator<Item = &'a Collider>>(
        &'a self,
        colliders: impl Fn() -> I,
        filter: QueryFilter<'a>,
    ) -> bool {
        // Whether box `b` comes within the margin of another collider, by its box or, for a
        // half-space (the ground, whose box is unbounded), its boundary plane.
        type Plane = Option<(Vector3<f64>, Vector3<f64>)>;
        let may_touch = |b: &Aabb, plane: &Plane, other_box: &Aabb| match plane {
            Some((n, p)) => box_height_over_plane(b, n, p) < CONTACT_MARGIN_M,
            None => b.loosened(CONTACT_MARGIN_M).intersects(other_box),
        };
        // First the box around the colliders' bounding spheres: it holds their exact boxes
        // (which take a cylinder six support points each), so with nothing near it the
        // exact test below finds nothing either — the same answer, most ticks of free
        // flight without the exact boxes.
        let Some(loose) = colliders()
            .map(|c| {
                let s = c.shape().compute_bounding_sphere(c.position());
                Aabb::from_half_extents(s.center, Vector::splat(s.radius))
            })
            .reduce(|a, b| a.merged(&b))
        else {
            return false;
        };
        let mut near_loose = self
            .world
            .intersect_aabb_conservative(loose.loosened(CONTACT_MARGIN_M), filter)
            .filter(|(_, other)| may_touch(&loose, &boundary_plane(other), &other.compute_aabb()));
        if near_loose.next().is_none() {
            return false;
        }
        let Some(whole) = colliders()
            .map(|c| c.compute_aabb())
            .reduce(|a, b| a.merged(&b))
        else {
            return false;
        };
        self.world
            .intersect_aabb_conservative(whole.loosened(CONTACT_MARGIN_M), filter)
            .any(|(_, other)| {
                let (plane, other_box) = (boundary_plane(other), other.compute_aabb());
                let may_touch = |b: &Aabb| may_touch(b, &plane, &other_box);
                may_touch(&whole)
                    && colliders().any(|c| {
                        may_touch(&c.compute_aabb())
                            && rapier3d_f64::parry::query::distance(
                                c.position(),
                                c.shape(),
                                other.position(),
                                other.shape(),
                            )
                            .map_or(true, |d| d.distance < CONTACT_MARGIN_M)
                    })
            })
    }

    /// rapier's multibody → the vehicle's own dynamics, in the multibody's state.
    pub(crate) fn take_from_rapier(&mut self) {
        let base = self.rapier_base_state();
        let Some(a) = self.articulated.as_deref_mut() else {
            return;
        };
        let mut qd = Vec::with_capacity(a.state.q.len());
        vehicle_body::joint_states(&self.world, &self.body.dofs, &mut a.state.q, &mut qd);
        let r = base.world_from_body;
        a.state.world_from_base = Isometry3::from_parts(base.position_in_world_m.into(), r);
        let v = r.inverse() * base.velocity_in_world_mps;
        let w = base.angular_velocity_in_body_radps;
        for i in 0..3 {
            a.state.nu[i] = v[i];
            a.state.nu[3 + i] = w[i];
        }
        for (n, rate) in a.state.nu.iter_mut().skip(6).zip(qd) {
            *n = rate;
        }
        vehicle_body::detach(&mut self.world, &self.body);
        a.engaged = true;
    }

    /// The vehicle's own dynamics → rapier's multibody, in the dynamics' state.
    pub(crate) fn hand_to_rapier(&mut self) -> Result<(), TwinError> {
        // A carried object first: it rides on the grasp's joint again.
        self.release_payload();
        let Some(a) = self.articulated.as_deref_mut() else {
            return Ok(());
        };
        let s = &a.state;
        a.tree.body_poses(&s.world_from_base, &s.q, &mut a.poses);
        let r = s.world_from_base.rotation;
        let v = Vector3::new(s.nu[0], s.nu[1], s.nu[2]);
        let w = Vector3::new(s.nu[3], s.nu[4], s.nu[5]);
        let qd: Vec<f64> = s.nu.iter().skip(6).copied().collect();
        let hand_over = vehicle_body::HandOver {
            poses: &a.poses,
            q: &s.q,
            qd: &qd,
            base_com_velocity_in_world: r * (v + w.cross(&a.base_com_in_body)),
            base_angular_velocity_in_world: r * w,
        };
        vehicle_body::attach(&mut self.world, &self.body, &hand_over)?;
        a.engaged = false;
        Ok(())
    }

    fn sample_observation_bias(&mut self) {
        let n = 13 + 2 * self.vehicle.model.dof();
        self.observation_bias = if self.config.disturbances.observation_noise {
            gaussian(&mut self.rng, self.config.noise.observation_bias_std, n)
        } else {
            vec![0.0; n]
        };
    }

    /// The measurement handed to the flight stack: the truth, plus bias and noise if on.
    fn observe(&mut self) -> Measurement {
        let mut m = self.truth.clone();
        if !self.config.disturbances.observation_noise {
            return m;
        }
        let noise = gaussian(
            &mut self.rng,
            self.config.noise.observation_std,
            self.observation_bias.len(),
        );
        let mut e = noise.iter().zip(&self.observation_bias).map(|(a, b)| a + b);
        let mut next = || e.next().unwrap_or(0.0);
        let b = &mut m.base;
        for x in b.position_in_world_m.iter_mut() {
            *x += next();
        }
        let q = b.world_from_body.into_inner().coords.map(|c| c + next());
        b.world_from_body = UnitQuaternion::new_normalize(nalgebra::Quaternion::from(q));
        for x in b
            .velocity_in_world_mps
            .iter_mut()
            .chain(b.angular_velocity_in_body_radps.iter_mut())
        {
            *x += next();
        }
        for x in m
            .joint_positions
            .iter_mut()
            .chain(m.joint_velocities.iter_mut())
        {
            *x += next();
        }
        m
    }

    /// World position of a point fixed in a link (e.g. the tool tip in the EE link).
    pub fn point_in_world(
        &self,
        link: platform::LinkId,
        point_in_link: &Vector3<f64>,
    ) -> Vector3<f64> {
        let (body, body_from_link) = self.body.of_link(link);
        (self.world_from(body) * body_from_link * Point3::from(*point_in_link)).coords
    }
}

/// A half-space collider's boundary plane in the world (outward normal, a point on it);
/// None for any other shape.
fn boundary_plane(c: &Collider) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let hs = c.shape().as_halfspace()?;
    let pose = pose_from_rapier(c.position());
    Some((
        pose.rotation * vector_from_rapier(hs.normal),
        pose.translation.vector,
    ))
}

/// How far the box `b` lies above the plane through `p` with normal `n` (its corner deepest
/// along −n; negative once it crosses).
fn box_height_over_plane(b: &Aabb, n: &Vector3<f64>, p: &Vector3<f64>) -> f64 {
    let (lo, hi) = (vector_from_rapier(b.mins), vector_from_rapier(b.maxs));
    (0..3)
        .map(|i| (n[i] * lo[i]).min(n[i] * hi[i]))
        .sum::<f64>()
        - n.dot(p)
}

fn gaussian(rng: &mut ChaCha8Rng, std: f64, n: usize) -> Vec<f64> {
    match Normal::new(0.0, std) {
        Ok(dist) => (0..n).map(|_| dist.sample(rng)).collect(),
        Err(_) => vec![0.0; n],
    }
}

impl TaskState {
    fn new(vehicle: &Vehicle, body: &VehicleBody, scene: Option<Box<dyn Scene>>) -> Self {
        let model = &vehicle.model;
        let joints = vehicle.gripper.as_ref().map_or(&[][..], |g| &g.joints[..]);
        let child = |j: usize| body.link_colliders[model.joints[j].child].clone();
        let fingers = match *joints {
            [a, b, ..] => [child(a), child(b)],
            // One moving jaw: it closes against the link that carries it.
            [a] => [
                child(a),
                body.link_colliders[model.joints[a].parent].clone(),
            ],
            [] => [Vec::new(), Vec::new()],
        };
        // The EE link and the links below it (joints list parents before children in
        // URDF order, but not necessarily: repeat until nothing is added).
        let mut in_hand = vec![false; model.links.len()];
        if let Some(ee) = in_hand.get_mut(vehicle.ee_link) {
            *ee = true;
        }
        loop {
            let mut added = false;
            for j in &model.joints {
                if in_hand[j.parent] && !in_hand[j.child] {
                    in_hand[j.child] = true;
                    added = true;
                }
            }
            if !added {
                break;
            }
        }
        let hand = in_hand
            .iter()
            .enumerate()
            .filter(|(_, h)| **h)
            .flat_map(|(link, _)| body.link_colliders[link].iter().copied())
            .collect();
        let status = TaskStatus {
            success: false,
            criteria: vec![false; scene.as_ref().map_or(0, |s| s.criteria_names().len())],
        };
        Self {
            scene,
            grasp: Grasp::default(),
            fingers,
            hand,
            gripper_dofs: joints.iter().filter_map(|&j| model.joints[j].dof).collect(),
            steps: 0,
            status,
        }
    }
}

/// A task scene's view of the twin.
impl Twin {
    /// The task of the scene around the vehicle, if any.
    pub fn task(&self) -> Option<TaskId> {
        self.task.scene.as_ref().map(|s| s.task())
    }

    /// The task's verdict after the last step (criteria not latched); None without a task.
    pub fn task_status(&self) -> Option<&TaskStatus> {
        self.task.scene.as_ref().map(|_| &self.task.status)
    }

    /// The task's observation keys now (AMBENCH_SPEC §5.1); None without a task.
    pub fn task_observation(&self) -> Option<TaskObservation> {
        self.task.scene.as_ref().map(|s| s.observation(&self.world))
    }

    /// The pose of the task's wall (or wall-like object), for wall normals.
    pub fn task_wall(&self) -> Option<Isometry3<f64>> {
        self.task.scene.as_ref().and_then(|s| s.wall())
    }

    /// World x of the obstacle face the base must stay in front of (IK limits), if any.
    pub fn obstacle_face_x(&self) -> Option<f64> {
        self.task
            .scene
            .as_ref()
            .and_then(|s| s.obstacle_face_x(&self.world))
    }

    /// Whether the grasp constraint holds an object.
    pub fn holding(&self) -> bool {
        self.task.grasp.held.is_some()
    }

    /// The joint the held object moves on, now (None: nothing held, or a free object).
    pub fn held_joint(&self) -> Option<HeldJoint> {
        let (object, _) = self.task.grasp.held?;
        self.task.scene.as_ref()?.held_joint(&self.world, object)
    }

    /// The hand's blocking contact: the unit normal (world, pointing out of what it
    /// touches) of the hand's contacts — points within the contact distance of its EE link,
    /// fingers or tool — with what does not give way along them: a fixed body, or an
    /// articulated object whose joint (as the scene describes it, `Scene::held_joint`)
    /// does not move that way; the part of the normal along the motion the joint allows is
    /// dropped, and a contact at least 60° off that motion counts. None: no such contact.
    /// The held object and free objects give way. A controller with no contact in its model
    /// (the whole-body MPC) keeps its target on the hand's side of it.
    pub fn hand_contact(&self) -> Option<Vector3<f64>> {
        let scene = self.task.scene.as_ref();
        let held = self.task.grasp.held.map(|(object, _)| object);
        let mut sum = Vector3::zeros();
        for &c in &self.task.hand {
            for pair in self.world.contact_pairs_with(c) {
                let PairContacts::Rigid(contacts) = &pair.contacts else {
                    continue;
                };
                let (other, sign) = if pair.collider1 == c {
                    (pair.collider2, -1.0)
                } else {
                    (pair.collider1, 1.0)
                };
                let Some(body) = self.world.colliders.get(other).and_then(|o| o.parent()) else {
                    continue;
                };
                if Some(body) == held || self.body.bodies.contains(&body) {
                    continue;
                }
                let Some(rb) = self.world.bodies.get(body) else {
                    continue;
                };
                // A fixed body does not move; an articulated object moves as its joint lets
                // it; a free object (or a joint the scene does not describe) gives way.
                let motion = if rb.is_fixed() {
                    None
                } else {
                    match scene.and_then(|s| s.held_joint(&self.world, body)) {
                        Some(joint) => Some(joint),
                        None => continue,
                    }
                };
                let Some(c1) = self.world.colliders.get(pair.collider1) else {
                    continue;
                };
                for m in &contacts.manifolds {
                    let Some(point) = m.points.iter().find(|p| p.dist <= HAND_CONTACT_M) else {
                        continue;
                    };
                    // Out of the other collider, into the hand.
                    let normal = vector_from_rapier(m.data.normal) * sign;
                    let at = pose_from_rapier(c1.position())
                        * Point3::from(vector_from_rapier(point.local_p1));
                    let blocked = blocked_part(&normal, motion.as_ref(), &at.coords);
                    if blocked.norm() >= HAND_CONTACT_BLOCKED {
                        sum += blocked;
                    }
                }
            }
        }
        // No blocking contact leaves the sum zero: None.
        sum.try_normalize(1e-9)
    }

    /// Env steps since reset.
    pub fn steps(&self) -> u64 {
        self.task.steps
    }

    /// The task scene's state now, all in one (None without a task).
    pub fn task_snapshot(&self) -> Option<TaskSnapshot> {
        let scene = self.task.scene.as_ref()?;
        Some(TaskSnapshot {
            task: scene.task(),
            status: self.task.status.clone(),
            observation: scene.observation(&self.world),
            wall: scene.wall(),
            obstacle_face_x: scene.obstacle_face_x(&self.world),
            holding: self.holding(),
            held_joint: self.held_joint(),
            hand_contact: self.hand_contact(),
            steps: self.task.steps,
        })
    }

    /// The tool tip now: ee + R_ee·tool_tip offset, oriented as the command frame.
    pub fn tool_tip(&self) -> Isometry3<f64> {
        let ee = self.truth.world_from_ee;
        Isometry3::from_parts(
            nalgebra::Translation3::from(ee * Point3::from(self.vehicle.tool_tip_in_ee_m)),
            self.vehicle.command_to_link.inverse() * ee.rotation,
        )
    }

    fn gripper_width_m(&self) -> f64 {
        self.task
            .gripper_dofs
            .iter()
            .filter_map(|&d| self.truth.joint_positions.get(d))
            .sum()
    }

    /// The gripper is closing when its first joint's target is nearer the closed position
    /// than the open one (action < 0).
    fn gripper_closing(&self) -> bool {
        let Some(g) = &self.vehicle.gripper else {
            return false;
        };
        let (Some(&d), Some(&closed), Some(&open)) = (
            self.task.gripper_dofs.first(),
            g.closed.first(),
            g.open.first(),
        ) else {
            return false;
        };
        let target = self.joint_targets.get(d).copied().unwrap_or(closed);
        (target - closed).abs() < (target - open).abs()
    }

    fn build_scene(&mut self) -> Result<(), TwinError> {
        let Some(mut scene) = self.task.scene.take() else {
            return Ok(());
        };
        // Its own stream: noise draws never shift the scene's randomisation.
        let mut rng = RandomStream::Scene.rng(self.config.seed);
        let tool_tip = self.tool_tip();
        let mut b = Build {
            world: &mut self.world,
            rng: &mut rng,
            tool_tip,
            graspable: Vec::new(),
            pre_grasped: None,
            pre_grasp_width_m: 0.0,
        };
        let built = scene.build(&mut b);
        let (graspable, pre_grasped, width) = (b.graspable, b.pre_grasped, b.pre_grasp_width_m);
        self.task.scene = Some(scene);
        built?;
        self.task.grasp.graspable = graspable;
        if let Some(object) = pre_grasped {
            let (ee_body, _) = self.body.of_link(self.vehicle.ee_link);
            self.task
                .grasp
                .attach(&mut self.world, ee_body, object, width);
        }
        Ok(())
    }

    fn update_task(&mut self) {
        let Some(mut scene) = self.task.scene.take() else {
            return;
        };
        self.task.steps += 1;
        let closing = self.gripper_closing();
        let width = self.gripper_width_m();
        let target_width: f64 = self
            .task
            .gripper_dofs
            .iter()
            .filter_map(|&d| self.joint_targets.get(d))
            .sum();
        let (ee_body, _) = self.body.of_link(self.vehicle.ee_link);
        self.task.grasp.update(
            &mut self.world,
            ee_body,
            &self.task.fingers,
            (closing, width, target_width),
            self.config.grasp == GraspMode::Assisted,
        );
        let dt = self.config.control_dt_s();
        let view = View {
            step: self.task.steps,
            substep_s: dt / f64::from(self.config.physics_substeps),
            world_from_ee: self.truth.world_from_ee,
            tool_tip: self.tool_tip().translation.vector,
            base_position: self.truth.base.position_in_world_m,
            gripper_width_m: self.gripper_width_m(),
        };
        self.task.status = scene.after_step(&mut self.world, &view);
        self.task.scene = Some(scene);
    }
}
