//! What every base-tracking controller shares: the interface, the body parameters, the
//! time-step guard, anti-windup from the allocator's feedback, and the status.

use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use platform::{AttitudeSetpoint, GRAVITY_MPS2, RateSetpoint, RigidBodyState, Vehicle, Wrench};
use serde::Serialize;

use crate::desired::{DesiredStateGenerator, is_finite_pose};
use crate::so3::hat;

/// Shortest time step a controller accepts, s; shorter ones are raised to it.
pub const DT_MIN_S: f64 = 1e-4;
/// Longest time step a controller accepts, s; longer ones (a stalled loop) are cut to it.
pub const DT_MAX_S: f64 = 0.1;
/// Unallocated force or torque below this (N, N·m) is not saturation.
pub const SATURATION_TOLERANCE: f64 = 1e-6;

/// A base-tracking controller: from the measured state of the controlled body and a target
/// pose, the body-frame wrench to request from the allocator.
///
/// Call order per tick: [`update`](Self::update), allocate, then
/// [`saturation_feedback`](Self::saturation_feedback) with what the allocator could not
/// achieve; the next update keeps its integrators and adaptation from winding up in those
/// directions.
pub trait BaseController: std::fmt::Debug + Send {
    /// Clears integrators, adaptation and history; `state` seeds whatever needs it.
    fn reset(&mut self, state: &RigidBodyState);

    /// One control step of `dt` seconds toward `target` (`world_from_body`). Never returns a
    /// non-finite wrench: a non-finite state, target or dt yields the documented safe output
    /// (the last wrench, or hover thrust before any) and a status that says why.
    fn update(&mut self, state: &RigidBodyState, target: &Isometry3<f64>, dt: f64) -> Wrench;

    /// The allocator's unallocated wrench (requested − achieved, body frame) for the wrench
    /// returned by the last update.
    fn saturation_feedback(&mut self, unallocated_in_body: &Wrench);

    /// Replaces the mass properties (e.g. as the arm moves the centre of mass).
    fn set_body(&mut self, body: BodyParams);

    /// Errors, integrators, adaptive estimates and input health after the last update.
    fn status(&self) -> ControllerStatus;
}

/// Mass properties used by the model-based laws.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BodyParams {
    /// Aggregate mass, kg.
    pub mass_kg: f64,
    /// Aggregate inertia about the centre of mass, body axes, kg·m².
    pub inertia_kgm2: Matrix3<f64>,
    /// Centre of mass in the body (control) frame, m.
    pub com_in_body_m: Vector3<f64>,
}

impl BodyParams {
    /// The whole vehicle (base, arm, gripper) at its initial joint configuration.
    ///
    /// The reference sums principal inertias about the base origin without rotating them
    /// (AMBENCH_SPEC §2.1); this is the exact composite inertia about the centre of mass.
    pub fn from_vehicle(vehicle: &Vehicle) -> Self {
        Self::at_configuration(vehicle, &vehicle.initial_configuration())
    }

    /// The whole vehicle at joint configuration `q`.
    pub fn at_configuration(vehicle: &Vehicle, q: &[f64]) -> Self {
        let mp = vehicle.mass_properties(q);
        Self {
            mass_kg: mp.mass_kg,
            inertia_kgm2: mp.inertia_about_com_kgm2,
            com_in_body_m: mp.com_in_root_m,
        }
    }

    /// A body with its centre of mass at the control frame's origin.
    pub fn centred(mass_kg: f64, inertia_kgm2: Matrix3<f64>) -> Self {
        Self {
            mass_kg,
            inertia_kgm2,
            com_in_body_m: Vector3::zeros(),
        }
    }

    /// Inverse inertia (identity-scaled fallback if singular, which validation prevents).
    pub(crate) fn inertia_inverse(&self) -> Matrix3<f64> {
        self.inertia_kgm2
            .try_inverse()
            .unwrap_or_else(Matrix3::identity)
    }

    /// Body-frame torque that cancels gravity acting at an offset centre of mass:
    /// c × Rᵀ(m g ẑ). Zero when the centre of mass is at the control frame's origin. The
    /// reference has no such term and leaves the offset to its integrator.
    pub(crate) fn gravity_moment_compensation(
        &self,
        world_from_body: &UnitQuaternion<f64>,
    ) -> Vector3<f64> {
        let lift_in_body =
            world_from_body.inverse() * (Vector3::z() * (self.mass_kg * GRAVITY_MPS2));
        self.com_in_body_m.cross(&lift_in_body)
    }
}

/// Whether the last update could use its inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum InputHealth {
    /// All inputs finite.
    #[default]
    Ok,
    /// The state had a non-finite value: safe output, nothing integrated.
    NonFiniteState,
    /// The target had a non-finite value: the previous target was held.
    NonFiniteTarget,
    /// dt was not finite and positive: safe output, nothing integrated.
    InvalidDt,
}

/// Serialisable status of a base controller after its last update.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ControllerStatus {
    /// `pid6`, `pid4` or `l1`.
    pub controller: &'static str,
    /// e_p = p_d − p, world, m.
    pub position_error_m: Vector3<f64>,
    /// e_v = v_d − v, world, m/s.
    pub velocity_error_mps: Vector3<f64>,
    /// e_R, body (≈ rad for small errors).
    pub attitude_error: Vector3<f64>,
    /// e_Ω, body, rad/s.
    pub angular_velocity_error_radps: Vector3<f64>,
    /// ∫e_p dt, world, m·s.
    pub position_integral: Vector3<f64>,
    /// ∫e_R dt, body.
    pub attitude_integral: Vector3<f64>,
    /// L1 adaptive force (body, N), when the controller adapts.
    pub adaptive_force_n: Option<Vector3<f64>>,
    /// L1 adaptive torque (body, N·m), when the controller adapts.
    pub adaptive_torque_nm: Option<Vector3<f64>>,
    /// Axes whose integration/adaptation the last saturation feedback stopped:
    /// world force x, y, z, then body torque x, y, z.
    pub windup_blocked: [bool; 6],
    /// Whether the inputs were usable.
    pub input: InputHealth,
    /// True when dt was outside [DT_MIN_S, DT_MAX_S] and was clamped.
    pub dt_clamped: bool,
    /// The wrench returned by the last update.
    pub output: Wrench,
    /// The attitude the last update steered to (the attitude level of its cascade); None
    /// before an update that could use its inputs.
    pub attitude_target: Option<AttitudeTarget>,
}

/// The attitude level of a base controller's cascade: the desired attitude R_d it steered to
/// (PID6 and L1: the reference pose's; PID4: the one its thrust direction needs) and the
/// desired body rate RᵀR_dΩ_d, in the current body frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AttitudeTarget {
    /// R_d as `world_from_body`.
    pub world_from_body: UnitQuaternion<f64>,
    /// RᵀR_dΩ_d, body (FLU), rad/s.
    pub body_rates_radps: Vector3<f64>,
}

impl ControllerStatus {
    /// The attitude setpoint of the cascade with body force `force_in_body_n` (the force the
    /// allocation will produce); None when the controller has no attitude target.
    pub fn attitude_setpoint(&self, force_in_body_n: Vector3<f64>) -> Option<AttitudeSetpoint> {
        self.attitude_target.map(|t| AttitudeSetpoint {
            world_from_body: t.world_from_body,
            force_in_body_n,
            body_rates_radps: Some(t.body_rates_radps),
        })
    }

    pub(crate) fn new(controller: &'static str) -> Self {
        Self {
            controller,
            position_error_m: Vector3::zeros(),
            velocity_error_mps: Vector3::zeros(),
            attitude_error: Vector3::zeros(),
            angular_velocity_error_radps: Vector3::zeros(),
            position_integral: Vector3::zeros(),
            attitude_integral: Vector3::zeros(),
            adaptive_force_n: None,
            adaptive_torque_nm: None,
            windup_blocked: [false; 6],
            input: InputHealth::Ok,
            dt_clamped: false,
            output: Wrench::ZERO,
            attitude_target: None,
        }
    }
}

/// PX4's multicopter attitude P gains, body x, y, z (MC_ROLL_P, MC_PITCH_P, MC_YAW_P
/// defaults), 1/s: the outer attitude law of the rate level, so that the rates amstack sends
/// ask of PX4's rate loop what PX4's own attitude loop would.
pub const PX4_ATTITUDE_P_PER_S: [f64; 3] = [6.5, 6.5, 2.8];

/// The rate level of a cascade: the body rates that fly attitude setpoint `attitude` from an
/// attitude error `e_R` (body, [`crate::attitude_error`]), with the body force unchanged:
///
/// ```text
/// Ω_cmd = Ω_ff − K ⊙ e_R      (Ω_ff = RᵀR_dΩ_d, the setpoint's feed-forward; 0 without)
/// ```
///
/// For small errors e_R ≈ θ, the rotation from R_d to R, and θ̇ ≈ Ω − Ω_ff, so a rate loop
/// that tracks Ω_cmd gives θ̇ = −K ⊙ θ.
pub fn rate_setpoint(
    attitude: &AttitudeSetpoint,
    attitude_error: &Vector3<f64>,
    gains_per_s: [f64; 3],
) -> RateSetpoint {
    let feed_forward = attitude.body_rates_radps.unwrap_or_else(Vector3::zeros);
    RateSetpoint {
        body_rates_radps: feed_forward - Vector3::from(gains_per_s).component_mul(attitude_error),
        force_in_body_n: attitude.force_in_body_n,
    }
}

/// dt in the accepted band, whether it was clamped; None if not finite and positive.
pub(crate) fn guard_dt(dt: f64) -> Option<(f64, bool)> {
    if !(dt.is_finite() && dt > 0.0) {
        return None;
    }
    let clamped = dt.clamp(DT_MIN_S, DT_MAX_S);
    Some((clamped, (clamped - dt).abs() > 0.0))
}

/// The wrench a controller falls back to when it cannot use its inputs: the last wrench it
/// returned, or, before any, the force that holds the body's weight with no torque (body +z
/// if the attitude is unknown).
pub(crate) fn safe_output(
    last: Option<Wrench>,
    body: &BodyParams,
    state: &RigidBodyState,
) -> Wrench {
    if let Some(w) = last {
        return w;
    }
    let weight = body.mass_kg * GRAVITY_MPS2;
    let q = state.world_from_body;
    let force = if q.coords.iter().all(|x| x.is_finite()) {
        q.inverse() * Vector3::new(0.0, 0.0, weight)
    } else {
        Vector3::new(0.0, 0.0, weight)
    };
    Wrench::new(force, Vector3::zeros())
}

/// Anti-windup from the allocator: remembers the unallocated wrench of the last tick and
/// stops, per axis, any integration or adaptation that would push the request further into
/// that saturation (conditional integration).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct WindupGuard {
    unallocated_force_in_world: Vector3<f64>,
    unallocated_torque_in_body: Vector3<f64>,
}

impl WindupGuard {
    pub(crate) fn record(
        &mut self,
        unallocated_in_body: &Wrench,
        world_from_body: &UnitQuaternion<f64>,
    ) {
        if !unallocated_in_body.is_finite() {
            return;
        }
        self.unallocated_force_in_world = world_from_body * unallocated_in_body.force;
        self.unallocated_torque_in_body = unallocated_in_body.torque;
    }

    pub(crate) fn clear(&mut self) {
        *self = Self::default();
    }

    /// `force_change` is how the increment would change the requested world force (same
    /// axes); components that would grow a saturated request are zeroed in `increment`.
    pub(crate) fn gate_force(
        &self,
        increment: &mut Vector3<f64>,
        force_change: &Vector3<f64>,
        blocked: &mut [bool; 6],
    ) {
        for k in 0..3 {
            let u = self.unallocated_force_in_world[k];
            if u.abs() > SATURATION_TOLERANCE && force_change[k] * u > 0.0 {
                increment[k] = 0.0;
                blocked[k] = true;
            }
        }
    }

    /// As [`Self::gate_force`] for the body torque (axes 3..6 of `blocked`).
    pub(crate) fn gate_torque(
        &self,
        increment: &mut Vector3<f64>,
        torque_change: &Vector3<f64>,
        blocked: &mut [bool; 6],
    ) {
        for k in 0..3 {
            let u = self.unallocated_torque_in_body[k];
            if u.abs() > SATURATION_TOLERANCE && torque_change[k] * u > 0.0 {
                increment[k] = 0.0;
                blocked[3 + k] = true;
            }
        }
    }
}

/// Errors of the geometric attitude law (Lee et al.), body frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AttitudeErrors {
    /// e_R = ½(R_dᵀR − RᵀR_d)^∨.
    pub e_r: Vector3<f64>,
    /// e_Ω = Ω − RᵀR_d Ω_d.
    pub e_omega: Vector3<f64>,
    /// RᵀR_d Ω_d: the desired rate in the current body frame.
    pub omega_d_in_body: Vector3<f64>,
    /// RᵀR_d Ω̇_d.
    pub omega_dot_d_in_body: Vector3<f64>,
    /// R_d.
    pub r_d: Matrix3<f64>,
}

pub(crate) fn attitude_errors(
    state: &RigidBodyState,
    r_d: &Matrix3<f64>,
    omega_d: &Vector3<f64>,
    omega_dot_d: &Vector3<f64>,
) -> AttitudeErrors {
    let r = state.world_from_body.to_rotation_matrix().into_inner();
    let rt_rd = r.transpose() * r_d;
    let omega_d_in_body = rt_rd * omega_d;
    AttitudeErrors {
        e_r: crate::so3::attitude_error(&r, r_d),
        e_omega: state.angular_velocity_in_body_radps - omega_d_in_body,
        omega_d_in_body,
        omega_dot_d_in_body: rt_rd * omega_dot_d,
        r_d: *r_d,
    }
}

/// τ = J(−K_R e_R − K_Ω e_Ω − K_I ∫e_R) + Ω×JΩ − J(Ω^ RᵀR_dΩ_d − RᵀR_dΩ̇_d)
/// (+ the centre-of-mass gravity moment, see [`BodyParams`]).
pub(crate) fn geometric_torque(
    body: &BodyParams,
    state: &RigidBodyState,
    errors: &AttitudeErrors,
    kp: &Vector3<f64>,
    kd: &Vector3<f64>,
    ki_integral: &Vector3<f64>,
) -> Vector3<f64> {
    let j = &body.inertia_kgm2;
    let omega = state.angular_velocity_in_body_radps;
    let feedback = -kp.component_mul(&errors.e_r) - kd.component_mul(&errors.e_omega) - ki_integral;
    let feedforward = hat(&omega) * errors.omega_d_in_body - errors.omega_dot_d_in_body;
    j * feedback + omega.cross(&(j * omega)) - j * feedforward
        + body.gravity_moment_compensation(&state.world_from_body)
}

/// What every base controller keeps besides its own law: the body, the desired-state
/// generator, anti-windup, the last output and the status; and the bookkeeping around each
/// update (input checks, safe output, recording).
#[derive(Debug, Clone)]
pub(crate) struct ControllerCore {
    pub body: BodyParams,
    pub desired: DesiredStateGenerator,
    pub guard: WindupGuard,
    name: &'static str,
    last_output: Option<Wrench>,
    last_attitude: UnitQuaternion<f64>,
    status: ControllerStatus,
}

impl ControllerCore {
    pub fn new(name: &'static str, body: BodyParams) -> Self {
        Self {
            body,
            desired: DesiredStateGenerator::default(),
            guard: WindupGuard::default(),
            name,
            last_output: None,
            last_attitude: UnitQuaternion::identity(),
            status: ControllerStatus::new(name),
        }
    }

    pub fn reset(&mut self) {
        self.desired.reset();
        self.guard.clear();
        self.last_output = None;
        self.status = ControllerStatus::new(self.name);
    }

    /// Checks the inputs of an update. `Ok` carries the dt to use and a fresh status;
    /// `Err` carries the safe output to return at once (nothing may be integrated).
    pub fn begin(
        &mut self,
        state: &RigidBodyState,
        target: &Isometry3<f64>,
        dt: f64,
    ) -> Result<(f64, ControllerStatus), Wrench> {
        let refuse = |core: &mut Self, input| {
            let wrench = safe_output(core.last_output, &core.body, state);
            core.status.input = input;
            core.status.output = wrench;
            Err(wrench)
        };
        let Some((dt, dt_clamped)) = guard_dt(dt) else {
            return refuse(self, InputHealth::InvalidDt);
        };
        if !state.is_finite() {
            return refuse(self, InputHealth::NonFiniteState);
        }
        let mut status = ControllerStatus::new(self.name);
        if !is_finite_pose(target) {
            status.input = InputHealth::NonFiniteTarget;
        }
        status.dt_clamped = dt_clamped;
        Ok((dt, status))
    }

    /// Records the update's result; a non-finite wrench (a bug upstream) is replaced by the
    /// safe output so nothing non-finite leaves the controller.
    pub fn finish(
        &mut self,
        state: &RigidBodyState,
        wrench: Wrench,
        mut status: ControllerStatus,
    ) -> Wrench {
        let wrench = if wrench.is_finite() {
            wrench
        } else {
            safe_output(self.last_output, &self.body, state)
        };
        status.output = wrench;
        self.status = status;
        self.last_output = Some(wrench);
        self.last_attitude = state.world_from_body;
        wrench
    }

    /// The wrench returned by the last update.
    pub fn last_output(&self) -> Option<Wrench> {
        self.last_output
    }

    pub fn record_saturation(&mut self, unallocated_in_body: &Wrench) {
        self.guard.record(unallocated_in_body, &self.last_attitude);
    }

    pub fn set_body(&mut self, body: BodyParams) {
        self.body = body;
    }

    pub fn status(&self) -> ControllerStatus {
        self.status
    }
}

impl ControllerStatus {
    /// Fills the tracking errors of one update.
    pub(crate) fn with_errors(
        mut self,
        e_p: Vector3<f64>,
        e_v: Vector3<f64>,
        attitude: &AttitudeErrors,
    ) -> Self {
        self.position_error_m = e_p;
        self.velocity_error_mps = e_v;
        self.attitude_error = attitude.e_r;
        self.angular_velocity_error_radps = attitude.e_omega;
        self.attitude_target = Some(AttitudeTarget {
            world_from_body: UnitQuaternion::from_rotation_matrix(
                &nalgebra::Rotation3::from_matrix_unchecked(attitude.r_d),
            ),
            body_rates_radps: attitude.omega_d_in_body,
        });
        self
    }
}
