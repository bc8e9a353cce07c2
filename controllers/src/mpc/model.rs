//! The prediction model of the NMPC: the paper's dynamics, an RK4 integrator with its exact
//! sensitivities, and the whole-body forward kinematics of the end effector with analytic
//! Jacobians.
//!
//! State `x = [p(3), v(3), η(3), ω(3), q(4)]`, input `u = [F_w(3), τ_w(3), q_ref(4)]`:
//!
//! ```text
//! ṗ = v,  v̇ = F_w/m,  η̇ = ω,  ω̇_i = τ_i/J_ii,  q̇ = k_a (q_ref − q)
//! ```
//!
//! (F_w excludes gravity; m and J are the vehicle's total mass and the diagonal of its composite
//! inertia at the initial configuration, from the `platform` description.)
//!
//! The end effector is the vehicle's `ee_link` frame: `p_ee = p + R_b(η) p_be(q)`,
//! `R_ee = R_b(η) R_be(q)`, `R_b = Rz(yaw) Ry(pitch) Rx(roll)`, with `(R_be, p_be)` the arm's
//! forward kinematics flattened from the URDF chain (`ik::chain`), not a copy of its lengths.
//! Jacobians: an Euler rate `η̇_i` turns the base about the world axis `e_i`
//! (`e_roll = Rz Ry x̂`, `e_pitch = Rz ŷ`, `e_yaw = ẑ`), a joint rate about `R_b a_j`; positions
//! move by `e × (p_ee − origin)`, and the EE roll–pitch–yaw by `E(rpy_ee)⁻¹ ω` with
//! `E = [Rz Ry x̂, Rz ŷ, ẑ]` the map from ZYX Euler rates to world angular velocity.

use nalgebra::{Matrix3, Rotation3, SMatrix, Vector3};
use platform::Vehicle;

use crate::controller::BodyParams;
use crate::ik::chain::{Chain, ChainPoses, Motion};
use crate::mpc::qp::{InputVector, NU, NX, StateInputMatrix, StateMatrix, StateVector};

/// Arm joints of the MPC's model.
pub const NQ: usize = 4;

/// Index of p in x.
pub const IX_P: usize = 0;
/// Index of v in x.
pub const IX_V: usize = 3;
/// Index of the Euler angles (roll, pitch, yaw) in x.
pub const IX_ETA: usize = 6;
/// Index of ω in x.
pub const IX_OMEGA: usize = 9;
/// Index of the arm joints in x.
pub const IX_Q: usize = 12;
/// Index of the world force in u.
pub const IU_F: usize = 0;
/// Index of the world torque in u.
pub const IU_TAU: usize = 3;
/// Index of the arm references in u.
pub const IU_QREF: usize = 6;

/// Why a vehicle cannot be modelled.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ModelError {
    /// The OCP is written for a fully actuated base with a 4-joint arm.
    #[error(
        "the whole-body MPC needs a fully actuated vehicle with a 4-joint revolute arm (FA-Hexa); {0}"
    )]
    Unsupported(String),
}

/// The end effector and its derivatives at one state.
#[derive(Debug, Clone, PartialEq)]
pub struct EeKinematics {
    /// `ee_link` origin in the world, m.
    pub position: Vector3<f64>,
    /// `ee_link` rotation in the world.
    pub rotation: Rotation3<f64>,
    /// Roll, pitch, yaw of `rotation` (ZYX), rad.
    pub rpy: Vector3<f64>,
    /// ∂position/∂x (non-zero in the p, η and q columns).
    pub position_jacobian: SMatrix<f64, 3, NX>,
    /// ∂rpy/∂x.
    pub rpy_jacobian: SMatrix<f64, 3, NX>,
}

/// [`MpcModel::ee`]'s forward kinematics before the Jacobians.
struct EeFrame {
    /// The base's rotation.
    r_b: Rotation3<f64>,
    /// Base origin to EE, world frame, m.
    lever: Vector3<f64>,
    position: Vector3<f64>,
    rotation: Rotation3<f64>,
    rpy: Vector3<f64>,
}

/// The prediction model (see the module documentation).
#[derive(Debug, Clone)]
pub struct MpcModel {
    /// Total mass, kg.
    pub mass_kg: f64,
    /// Diagonal of the composite inertia about the centre of mass, kg·m².
    pub inertia_diag_kgm2: Vector3<f64>,
    /// Arm servo gain, 1/s.
    pub arm_gain_per_s: f64,
    /// Lowest arm joint positions (URDF), rad.
    pub arm_lower_rad: [f64; NQ],
    /// Highest arm joint positions (URDF), rad.
    pub arm_upper_rad: [f64; NQ],
    chain: Chain,
    poses: ChainPoses,
}

impl MpcModel {
    /// The model of `vehicle` with arm gain `arm_gain_per_s`.
    pub fn new(vehicle: &Vehicle, arm_gain_per_s: f64) -> Result<Self, ModelError> {
        if vehicle.actuation != platform::Actuation::FullyActuated {
            return Err(ModelError::Unsupported(format!(
                "{} is {:?}",
                vehicle.id, vehicle.actuation
            )));
        }
        let arm_dofs = vehicle.arm_dofs();
        if arm_dofs.len() != NQ {
            return Err(ModelError::Unsupported(format!(
                "{} has {} arm joints",
                vehicle.id,
                arm_dofs.len()
            )));
        }
        let held = vehicle.initial_configuration();
        let chain = Chain::new(vehicle, &held, &arm_dofs);
        if chain.joints.len() != NQ || chain.joints.iter().any(|j| j.motion != Motion::Rotation) {
            return Err(ModelError::Unsupported(format!(
                "{}: the arm joints are not all revolute joints between the base and the end effector",
                vehicle.id
            )));
        }
        let mut arm_lower_rad = [f64::NEG_INFINITY; NQ];
        let mut arm_upper_rad = [f64::INFINITY; NQ];
        for (k, &d) in arm_dofs.iter().enumerate() {
            if let Some(l) = vehicle.model.dof_joint(d).limits {
                arm_lower_rad[k] = l.lower;
                arm_upper_rad[k] = l.upper;
            }
        }
        let body = BodyParams::from_vehicle(vehicle);
        let poses = chain.poses_buffer();
        Ok(Self {
            mass_kg: body.mass_kg,
            inertia_diag_kgm2: body.inertia_kgm2.diagonal(),
            arm_gain_per_s,
            arm_lower_rad,
            arm_upper_rad,
            chain,
            poses,
        })
    }

    /// ẋ = f(x, u).
    pub fn derivative(&self, x: &StateVector, u: &InputVector) -> StateVector {
        let mut dx = StateVector::zeros();
        for i in 0..3 {
            dx[IX_P + i] = x[IX_V + i];
            dx[IX_V + i] = u[IU_F + i] / self.mass_kg;
            dx[IX_ETA + i] = x[IX_OMEGA + i];
            dx[IX_OMEGA + i] = u[IU_TAU + i] / self.inertia_diag_kgm2[i];
        }
        for j in 0..NQ {
            dx[IX_Q + j] = self.arm_gain_per_s * (u[IU_QREF + j] - x[IX_Q + j]);
        }
        dx
    }

    /// ∂f/∂x and ∂f/∂u at (x, u) (constant for this model).
    pub fn derivative_jacobians(
        &self,
        _x: &StateVector,
        _u: &InputVector,
    ) -> (StateMatrix, StateInputMatrix) {
        let mut fx = StateMatrix::zeros();
        let mut fu = StateInputMatrix::zeros();
        for i in 0..3 {
            fx[(IX_P + i, IX_V + i)] = 1.0;
            fu[(IX_V + i, IU_F + i)] = 1.0 / self.mass_kg;
            fx[(IX_ETA + i, IX_OMEGA + i)] = 1.0;
            fu[(IX_OMEGA + i, IU_TAU + i)] = 1.0 / self.inertia_diag_kgm2[i];
        }
        for j in 0..NQ {
            fx[(IX_Q + j, IX_Q + j)] = -self.arm_gain_per_s;
            fu[(IX_Q + j, IU_QREF + j)] = self.arm_gain_per_s;
        }
        (fx, fu)
    }

    /// One RK4 step of `h` seconds and its exact sensitivities ∂x⁺/∂x, ∂x⁺/∂u (the
    /// variational equations of each stage, propagated with the stages).
    pub fn rk4(
        &self,
        x: &StateVector,
        u: &InputVector,
        h: f64,
    ) -> (StateVector, StateMatrix, StateInputMatrix) {
        let id = StateMatrix::identity();
        let k1 = self.derivative(x, u);
        let (fx, fu) = self.derivative_jacobians(x, u);
        let k1x = fx;
        let k1u = fu;
        let x2 = x + k1 * (h / 2.0);
        let (fx, fu) = self.derivative_jacobians(&x2, u);
        let k2 = self.derivative(&x2, u);
        let k2x = fx * (id + k1x * (h / 2.0));
        let k2u = fx * k1u * (h / 2.0) + fu;
        let x3 = x + k2 * (h / 2.0);
        let (fx, fu) = self.derivative_jacobians(&x3, u);
        let k3 = self.derivative(&x3, u);
        let k3x = fx * (id + k2x * (h / 2.0));
        let k3u = fx * k2u * (h / 2.0) + fu;
        let x4 = x + k3 * h;
        let (fx, fu) = self.derivative_jacobians(&x4, u);
        let k4 = self.derivative(&x4, u);
        let k4x = fx * (id + k3x * h);
        let k4u = fx * k3u * h + fu;
        let next = x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
        let a = id + (k1x + k2x * 2.0 + k3x * 2.0 + k4x) * (h / 6.0);
        let b = (k1u + k2u * 2.0 + k3u * 2.0 + k4u) * (h / 6.0);
        (next, a, b)
    }

    /// The end effector's position and roll, pitch, yaw at state x: [`Self::ee`]'s, without
    /// the Jacobians (the same arithmetic, so the same bits).
    pub fn ee_pose(&mut self, x: &StateVector) -> (Vector3<f64>, Vector3<f64>) {
        let frame = self.ee_frame(x);
        (frame.position, frame.rpy)
    }

    /// Forward kinematics at x: the base rotation, the lever (world frame), the EE position,
    /// rotation and roll, pitch, yaw.
    fn ee_frame(&mut self, x: &StateVector) -> EeFrame {
        let arm = [x[IX_Q], x[IX_Q + 1], x[IX_Q + 2], x[IX_Q + 3]];
        self.chain.evaluate(&arm, &mut self.poses);
        let (roll, pitch, yaw) = (x[IX_ETA], x[IX_ETA + 1], x[IX_ETA + 2]);
        let r_b = Rotation3::from_euler_angles(roll, pitch, yaw);
        let p_be = self.poses.base_from_ee.translation.vector;
        let lever = r_b * p_be;
        let position = Vector3::new(x[IX_P], x[IX_P + 1], x[IX_P + 2]) + lever;
        let rotation = r_b * self.poses.base_from_ee.rotation.to_rotation_matrix();
        let (er, ep, ey) = rotation.euler_angles();
        EeFrame {
            r_b,
            lever,
            position,
            rotation,
            rpy: Vector3::new(er, ep, ey),
        }
    }

    /// The end effector at state x, with Jacobians.
    pub fn ee(&mut self, x: &StateVector) -> EeKinematics {
        let EeFrame {
            r_b,
            lever,
            position,
            rotation,
            rpy,
        } = self.ee_frame(x);
        let (pitch, yaw) = (x[IX_ETA + 1], x[IX_ETA + 2]);
        let (ep, ey) = (rpy[1], rpy[2]);
        let p_be = self.poses.base_from_ee.translation.vector;
        let (sp, cp) = pitch.sin_cos();
        let (sy, cy) = yaw.sin_cos();
        let axes = [
            Vector3::new(cp * cy, cp * sy, -sp),
            Vector3::new(-sy, cy, 0.0),
            Vector3::z(),
        ];
        let e_inv = euler_rate_map(ep, ey)
            .try_inverse()
            .unwrap_or_else(Matrix3::zeros);
        let mut position_jacobian = SMatrix::<f64, 3, NX>::zeros();
        let mut rpy_jacobian = SMatrix::<f64, 3, NX>::zeros();
        for i in 0..3 {
            position_jacobian[(i, IX_P + i)] = 1.0;
        }
        for (i, axis) in axes.iter().enumerate() {
            position_jacobian
                .column_mut(IX_ETA + i)
                .copy_from(&axis.cross(&lever));
            rpy_jacobian
                .column_mut(IX_ETA + i)
                .copy_from(&(e_inv * axis));
        }
        for (joint, (axis_b, origin_b)) in self
            .chain
            .joints
            .iter()
            .zip(self.poses.axes.iter().zip(&self.poses.origins))
        {
            let axis_w = r_b * axis_b;
            let column = IX_Q + joint.arm_index;
            position_jacobian
                .column_mut(column)
                .copy_from(&(r_b * axis_b.cross(&(p_be - origin_b))));
            rpy_jacobian.column_mut(column).copy_from(&(e_inv * axis_w));
        }
        EeKinematics {
            position,
            rotation,
            rpy,
            position_jacobian,
            rpy_jacobian,
        }
    }
}

/// The rotors' thrust envelope around hover, for bounding the MPC's force and torque.
///
/// With A the effectiveness matrix (columns `[d_i; r_i × d_i + s_i k_f d_i]`, base frame) at
/// the initial configuration and `T_h = A⁺ w_hover` the hover thrusts (weight and the gravity
/// moment of the centre of mass), a body wrench change δw is allocated as
/// `T = T_h + A⁺ δw`. Bounding the change the force alone asks of each rotor to a share φ of
/// its margin, `−φ(T_h,i − T_min) ≤ (A⁺_F R_bᵀ F_w)_i ≤ φ(T_max − T_h,i)`, leaves 1 − φ of every
/// margin to the torque: six linear rows on the MPC's input.
#[derive(Debug, Clone, PartialEq)]
pub struct RotorEnvelope {
    /// Rows of A⁺ (one per rotor): force part then torque part, base frame.
    pub allocation_rows: Vec<[f64; 6]>,
    /// Hover thrust of each rotor, N.
    pub hover_thrust_n: Vec<f64>,
    /// Lowest rotor thrust, N.
    pub thrust_min_n: f64,
    /// Highest rotor thrust, N.
    pub thrust_max_n: f64,
    /// Weight, N.
    pub weight_n: f64,
    /// Centre of mass in the base frame, m (its gravity moment is compensated with the weight).
    pub com_in_body_m: Vector3<f64>,
}

impl RotorEnvelope {
    /// The envelope of `vehicle` (None without rotors, if the rotors cannot produce every
    /// wrench, or if hover leaves a rotor without margin).
    pub fn of(vehicle: &Vehicle) -> Option<Self> {
        let rotors = &vehicle.rotors;
        let n = rotors.len();
        if n == 0 {
            return None;
        }
        let mut a = nalgebra::DMatrix::<f64>::zeros(6, n);
        for (j, r) in rotors.rotors.iter().enumerate() {
            let d = r.axis_in_base.into_inner();
            let tau =
                r.position_in_base.cross(&d) + d * (r.spin.sign() * rotors.reaction_torque_ratio_m);
            for i in 0..3 {
                a[(i, j)] = d[i];
                a[(3 + i, j)] = tau[i];
            }
        }
        let svd = a.svd(true, true);
        if svd.rank(1e-9) < 6 {
            return None;
        }
        let a_pinv = svd.pseudo_inverse(1e-12).ok()?;
        let body = BodyParams::from_vehicle(vehicle);
        let weight = Vector3::new(0.0, 0.0, body.mass_kg * platform::GRAVITY_MPS2);
        let moment = body.com_in_body_m.cross(&weight);
        let hover = nalgebra::DVector::from_column_slice(&[
            0.0, 0.0, weight.z, moment.x, moment.y, moment.z,
        ]);
        let thrust = &a_pinv * hover;
        if thrust
            .iter()
            .any(|t| *t <= rotors.thrust_min_n || *t >= rotors.thrust_max_n)
        {
            return None;
        }
        Some(Self {
            allocation_rows: (0..n)
                .map(|j| std::array::from_fn(|i| a_pinv[(j, i)]))
                .collect(),
            hover_thrust_n: thrust.iter().copied().collect(),
            thrust_min_n: rotors.thrust_min_n,
            thrust_max_n: rotors.thrust_max_n,
            weight_n: weight.z,
            com_in_body_m: body.com_in_body_m,
        })
    }

    /// The input rows `e_i` (over the force part of u) and bounds of each rotor for base
    /// attitude `world_from_base` and margin share `fraction`: `lower_i ≤ e_iᵀu ≤ upper_i`
    /// bounds the thrust change the force alone asks of rotor i.
    pub fn input_rows<'s>(
        &'s self,
        world_from_base: &Rotation3<f64>,
        fraction: f64,
    ) -> impl Iterator<Item = (InputVector, f64, f64)> + use<'s> {
        let r = *world_from_base;
        self.allocation_rows
            .iter()
            .zip(&self.hover_thrust_n)
            .map(move |(row, hover)| {
                // The force's part of (A⁺ δw)_i: row_F·R_bᵀF = (R_b row_F)·F.
                let f = r * Vector3::new(row[0], row[1], row[2]);
                let mut e = InputVector::zeros();
                for k in 0..3 {
                    e[k] = f[k];
                }
                (
                    e,
                    -fraction * (hover - self.thrust_min_n),
                    fraction * (self.thrust_max_n - hover),
                )
            })
    }

    /// The input rows `e_i` (over the force and torque parts of u, both world frame) and
    /// bounds of each rotor at base attitude `world_from_base` (roll and pitch included) for
    /// margin share `fraction`: `lower_i ≤ e_iᵀu ≤ upper_i` keeps the thrust the whole
    /// commanded wrench allocates to rotor i,
    /// `T_i = A⁺_i [R_bᵀ(F + W ẑ); R_bᵀτ + c × R_bᵀW ẑ]` (the weight W and its moment about the
    /// base origin compensated as the controller does), within `fraction` of its margin
    /// around `T_0,i`, the thrust that compensation alone takes at this attitude.
    pub fn wrench_rows<'s>(
        &'s self,
        world_from_base: &Rotation3<f64>,
        fraction: f64,
    ) -> impl Iterator<Item = (InputVector, f64, f64)> + use<'s> {
        let r = *world_from_base;
        let lift = r.inverse() * Vector3::new(0.0, 0.0, self.weight_n);
        let moment = self.com_in_body_m.cross(&lift);
        let (t_min, t_max) = (self.thrust_min_n, self.thrust_max_n);
        self.allocation_rows.iter().map(move |row| {
            let f = r * Vector3::new(row[0], row[1], row[2]);
            let t = r * Vector3::new(row[3], row[4], row[5]);
            let t0 = (0..3)
                .map(|k| row[k] * lift[k] + row[3 + k] * moment[k])
                .sum::<f64>();
            let mut e = InputVector::zeros();
            for k in 0..3 {
                e[IU_F + k] = f[k];
                e[IU_TAU + k] = t[k];
            }
            // T_0 outside [T_min, T_max] (an attitude no hover holds): the rows keep the
            // wrench from asking more of that rotor in the wrong direction.
            (
                e,
                (fraction * (t_min - t0)).min(0.0),
                (fraction * (t_max - t0)).max(0.0),
            )
        })
    }
}

/// E(pitch, yaw): ZYX Euler rates (roll, pitch, yaw) → world angular velocity.
fn euler_rate_map(pitch: f64, yaw: f64) -> Matrix3<f64> {
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    Matrix3::new(
        cp * cy,
        -sy,
        0.0, //
        cp * sy,
        cy,
        0.0, //
        -sp,
        0.0,
        1.0,
    )
}

/// Compile-time check of the state and input layout.
const _: () = assert!(IX_Q + NQ == NX && IU_QREF + NQ == NU);
