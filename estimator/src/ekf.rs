//! The error-state EKF's two steps on one (nominal state, covariance) pair: IMU propagation
//! and a measurement update. No history, no time bookkeeping: [`crate::Estimator`] does that.
//!
//! Nominal state x = (p, v, q, b_a, b_g); error state δx = (δp, δv, δθ, δb_a, δb_g) ∈ ℝ¹⁵
//! with the attitude error in the body frame, q_true = q ⊗ Exp(δθ).
//!
//! Propagation over dt with a sample (f_m, ω_m) averaged over the interval:
//! ω = ω_m − b_g, q_mid = q ⊗ Exp(ω dt/2), a = R(q_mid)(f_m − b_a) + g,
//! p ← p + v dt + ½ a dt², v ← v + a dt, q ← q ⊗ Exp(ω dt); biases constant.
//! Error dynamics (first order), R = R(q_mid), f = f_m − b_a:
//!
//! ```text
//! δp ← δp + δv dt − ½R[f]× dt² δθ − ½R dt² δb_a
//! δv ← δv − R[f]× dt δθ − R dt δb_a
//! δθ ← Exp(ω dt)ᵀ δθ − dt δb_g
//! ```
//!
//! with process noise Q = diag(0, σ_a² dt, σ_g² dt, σ_ba² dt, σ_bg² dt) (σ the densities of
//! the configuration). A measurement z with residual y = h⁻¹(z, x), Jacobian H and noise R
//! updates with S = HPHᵀ + R, K = PHᵀS⁻¹, δx = Ky, the Joseph form
//! P ← (I − KH)P(I − KH)ᵀ + KRKᵀ, injection of δx into x and the reset
//! P ← GPGᵀ, G = diag(I, I, I − ½[δθ]×, I, I).

use nalgebra::{Const, SMatrix, SVector, UnitQuaternion, Vector3};
use platform::GRAVITY_MPS2;

use crate::config::EstimatorConfig;
use crate::sample::{ImuSample, Measurement};

/// Error-state dimension.
pub(crate) const N: usize = 15;
/// The error-state covariance, order δp, δv, δθ, δb_a, δb_g (m, m/s, rad, m/s², rad/s).
pub type Covariance = SMatrix<f64, N, N>;

pub(crate) const P: usize = 0;
pub(crate) const V: usize = 3;
pub(crate) const TH: usize = 6;
pub(crate) const BA: usize = 9;
pub(crate) const BG: usize = 12;

/// The nominal state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Nominal {
    pub(crate) position: Vector3<f64>,
    pub(crate) velocity: Vector3<f64>,
    pub(crate) attitude: UnitQuaternion<f64>,
    pub(crate) accel_bias: Vector3<f64>,
    pub(crate) gyro_bias: Vector3<f64>,
}

fn skew(v: &Vector3<f64>) -> nalgebra::Matrix3<f64> {
    v.cross_matrix()
}

/// Propagates `x`, `cov` over `dt` with `imu` (its time is not read).
pub(crate) fn propagate(
    x: &mut Nominal,
    cov: &mut Covariance,
    imu: &ImuSample,
    dt: f64,
    config: &EstimatorConfig,
) {
    let f = imu.specific_force_in_body_mps2 - x.accel_bias;
    let w = imu.angular_velocity_in_body_radps - x.gyro_bias;
    let q_mid = x.attitude * UnitQuaternion::from_scaled_axis(w * (0.5 * dt));
    let r = q_mid.to_rotation_matrix().into_inner();
    let a = r * f + Vector3::new(0.0, 0.0, -GRAVITY_MPS2);
    let step = UnitQuaternion::from_scaled_axis(w * dt);

    x.position += x.velocity * dt + a * (0.5 * dt * dt);
    x.velocity += a * dt;
    x.attitude = UnitQuaternion::new_normalize((x.attitude * step).into_inner());

    let mut fm = Covariance::identity();
    let rf = r * skew(&f);
    fm.fixed_view_mut::<3, 3>(P, V)
        .copy_from(&(nalgebra::Matrix3::identity() * dt));
    fm.fixed_view_mut::<3, 3>(P, TH)
        .copy_from(&(-rf * (0.5 * dt * dt)));
    fm.fixed_view_mut::<3, 3>(P, BA)
        .copy_from(&(-r * (0.5 * dt * dt)));
    fm.fixed_view_mut::<3, 3>(V, TH).copy_from(&(-rf * dt));
    fm.fixed_view_mut::<3, 3>(V, BA).copy_from(&(-r * dt));
    fm.fixed_view_mut::<3, 3>(TH, TH)
        .copy_from(&step.to_rotation_matrix().into_inner().transpose());
    fm.fixed_view_mut::<3, 3>(TH, BG)
        .copy_from(&(nalgebra::Matrix3::identity() * -dt));

    let mut next = fm * *cov * fm.transpose();
    let densities = [
        (V, config.accel_noise_mps2_per_sqrt_hz),
        (TH, config.gyro_noise_radps_per_sqrt_hz),
        (BA, config.accel_bias_walk_mps3_per_sqrt_hz),
        (BG, config.gyro_bias_walk_radps2_per_sqrt_hz),
    ];
    for (block, density) in densities {
        for i in block..block + 3 {
            next[(i, i)] += density * density * dt;
        }
    }
    *cov = symmetric(&next);
}

fn symmetric(m: &Covariance) -> Covariance {
    (m + m.transpose()) * 0.5
}

/// The outcome of one update: the residual (position m, attitude rad, velocity m/s if
/// measured) and its normalised squared size yᵀS⁻¹y.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Residual {
    pub(crate) position_m: Vector3<f64>,
    pub(crate) attitude_rad: Vector3<f64>,
    pub(crate) velocity_mps: Option<Vector3<f64>>,
    pub(crate) nis: f64,
    pub(crate) dof: usize,
}

/// Why an update did not change the state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum UpdateFailure {
    /// S was not positive definite, or the correction not finite.
    Numerical,
    /// NIS over the gate.
    Gated { nis: f64 },
}

/// The residual of a measurement against `x`: position, attitude Log(q⁻¹ ⊗ q_m), velocity.
fn residual(x: &Nominal, m: &Measurement) -> (Vector3<f64>, Vector3<f64>, Option<Vector3<f64>>) {
    let pose = m.pose();
    let dp = pose.position_in_world_m - x.position;
    let dth = (x.attitude.inverse() * pose.world_from_body).scaled_axis();
    let dv = match m {
        Measurement::Pose(_) => None,
        Measurement::Odometry(o) => Some(o.velocity_in_world_mps - x.velocity),
    };
    (dp, dth, dv)
}

/// Updates `x`, `cov` with `m`; on failure nothing changes.
pub(crate) fn update(
    x: &mut Nominal,
    cov: &mut Covariance,
    m: &Measurement,
    gate: Option<f64>,
) -> Result<Residual, (UpdateFailure, Residual)> {
    let (dp, dth, dv) = residual(x, m);
    let pose = m.pose();
    let (sp, sa) = (pose.position_std_m, pose.attitude_std_rad);
    match (m, dv) {
        (Measurement::Odometry(o), Some(dv)) => {
            let mut y = SVector::<f64, 9>::zeros();
            y.fixed_rows_mut::<3>(0).copy_from(&dp);
            y.fixed_rows_mut::<3>(3).copy_from(&dth);
            y.fixed_rows_mut::<3>(6).copy_from(&dv);
            let mut h = SMatrix::<f64, 9, N>::zeros();
            h.fixed_view_mut::<3, 3>(0, P)
                .copy_from(&nalgebra::Matrix3::identity());
            h.fixed_view_mut::<3, 3>(3, TH)
                .copy_from(&nalgebra::Matrix3::identity());
            h.fixed_view_mut::<3, 3>(6, V)
                .copy_from(&nalgebra::Matrix3::identity());
            let sv = o.velocity_std_mps;
            let noise = SVector::<f64, 9>::from_column_slice(&[
                sp * sp,
                sp * sp,
                sp * sp,
                sa * sa,
                sa * sa,
                sa * sa,
                sv * sv,
                sv * sv,
                sv * sv,
            ]);
            let residual = |nis| Residual {
                position_m: dp,
                attitude_rad: dth,
                velocity_mps: Some(dv),
                nis,
                dof: 9,
            };
            correct::<9>(x, cov, &y, &h, &noise, gate)
                .map(residual)
                .map_err(|(f, nis)| (f, residual(nis)))
        }
        _ => {
            let mut y = SVector::<f64, 6>::zeros();
            y.fixed_rows_mut::<3>(0).copy_from(&dp);
            y.fixed_rows_mut::<3>(3).copy_from(&dth);
            let mut h = SMatrix::<f64, 6, N>::zeros();
            h.fixed_view_mut::<3, 3>(0, P)
                .copy_from(&nalgebra::Matrix3::identity());
            h.fixed_view_mut::<3, 3>(3, TH)
                .copy_from(&nalgebra::Matrix3::identity());
            let noise = SVector::<f64, 6>::from_column_slice(&[
                sp * sp,
                sp * sp,
                sp * sp,
                sa * sa,
                sa * sa,
                sa * sa,
            ]);
            let residual = |nis| Residual {
                position_m: dp,
                attitude_rad: dth,
                velocity_mps: None,
                nis,
                dof: 6,
            };
            correct::<6>(x, cov, &y, &h, &noise, gate)
                .map(residual)
                .map_err(|(f, nis)| (f, residual(nis)))
        }
    }
}

/// The EKF correction for an M-dimensional residual with diagonal noise `noise_var`.
/// Returns the NIS.
fn correct<const M: usize>(
    x: &mut Nominal,
    cov: &mut Covariance,
    y: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    noise_var: &SVector<f64, M>,
    gate: Option<f64>,
) -> Result<f64, (UpdateFailure, f64)> {
    let noise = SMatrix::<f64, M, M>::from_diagonal(noise_var);
    let pht = *cov * h.transpose();
    let s = h * pht + noise;
    let Some(chol) = nalgebra::Cholesky::<f64, Const<M>>::new(s) else {
        return Err((UpdateFailure::Numerical, f64::NAN));
    };
    let s_inv_y = chol.solve(y);
    let nis = y.dot(&s_inv_y);
    if !nis.is_finite() {
        return Err((UpdateFailure::Numerical, nis));
    }
    if let Some(g) = gate
        && nis > g
    {
        return Err((UpdateFailure::Gated { nis }, nis));
    }
    // K = P Hᵀ S⁻¹ = (S⁻¹ H P)ᵀ, S symmetric.
    let k: SMatrix<f64, N, M> = chol.solve(&pht.transpose()).transpose();
    let dx = k * y;
    if !dx.iter().all(|v| v.is_finite()) {
        return Err((UpdateFailure::Numerical, nis));
    }
    let i_kh = Covariance::identity() - k * h;
    let mut next = i_kh * *cov * i_kh.transpose() + k * noise * k.transpose();

    let dth = Vector3::new(dx[TH], dx[TH + 1], dx[TH + 2]);
    x.position += Vector3::new(dx[P], dx[P + 1], dx[P + 2]);
    x.velocity += Vector3::new(dx[V], dx[V + 1], dx[V + 2]);
    x.attitude = UnitQuaternion::new_normalize(
        (x.attitude * UnitQuaternion::from_scaled_axis(dth)).into_inner(),
    );
    x.accel_bias += Vector3::new(dx[BA], dx[BA + 1], dx[BA + 2]);
    x.gyro_bias += Vector3::new(dx[BG], dx[BG + 1], dx[BG + 2]);

    let mut g = Covariance::identity();
    g.fixed_view_mut::<3, 3>(TH, TH)
        .copy_from(&(nalgebra::Matrix3::identity() - skew(&dth) * 0.5));
    next = g * next * g.transpose();
    *cov = symmetric(&next);
    Ok(nis)
}
