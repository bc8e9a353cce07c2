//! Small SO(3) helpers shared by the controllers and the IK, for what nalgebra does not provide.
//!
//! The IK's exp and log are nalgebra's: `UnitQuaternion::from_scaled_axis(φ)` is the rotation
//! by |φ| about φ/|φ|, and `q.scaled_axis()` its inverse with |log(q)| ∈ [0, π]. For a left
//! (world-frame) perturbation `log(exp(a)·exp(φ)) ≈ φ + J_l⁻¹(φ)·a`, with
//!
//! ```text
//! J_l⁻¹(φ) = I − ½ φ^ + (1/θ²)(1 − (θ/2)·cot(θ/2)) φ^²,   θ = |φ|,
//! ```
//!
//! which is finite on the whole range θ ∈ [0, π] that the log returns.

use nalgebra::{Matrix3, Vector3};

/// Below this angle (rad) `left_jacobian_inverse` uses its series.
const SERIES_BELOW_RAD: f64 = 1e-4;

/// The skew-symmetric matrix v^ with v^·x = v × x.
pub(crate) fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    v.cross_matrix()
}

/// The inverse left Jacobian J_l⁻¹(φ) of SO(3) (see the module doc).
pub(crate) fn left_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    // (1/θ²)(1 − (θ/2)cot(θ/2)) = 1/12 + θ²/720 + O(θ⁴)
    let k = if theta < SERIES_BELOW_RAD {
        1.0 / 12.0 + theta2 / 720.0
    } else {
        let half = 0.5 * theta;
        (1.0 - half * half.cos() / half.sin()) / theta2
    };
    let h = hat(phi);
    Matrix3::identity() - 0.5 * h + k * h * h
}

/// Geometric attitude error e_R = ½ (R_dᵀR − RᵀR_d)^∨ (Lee, Leok & McClamroch). Zero at
/// R = R_d; equals sin(θ)·axis for a rotation error of θ about `axis` (body frame).
pub fn attitude_error(r: &Matrix3<f64>, r_d: &Matrix3<f64>) -> Vector3<f64> {
    // R_dᵀR − RᵀR_d is skew-symmetric; e_R is half its vee.
    let m = r_d.transpose() * r - r.transpose() * r_d;
    Vector3::new(m[(2, 1)], m[(0, 2)], m[(1, 0)]) * 0.5
}

/// Elementwise clamp of a vector to [−limit, limit].
pub fn clamp_elementwise(v: &Vector3<f64>, limit: f64) -> Vector3<f64> {
    v.map(|x| x.clamp(-limit, limit))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// Round-off allowed on exp/log round trips, rad.
    const ROUND_TRIP_TOLERANCE: f64 = 1e-12;

    fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(*phi)
    }

    fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
        q.scaled_axis()
    }

    /// What the IK relies on from nalgebra: its log inverts its exp to round-off over the
    /// whole range [0, π], small angles included.
    #[test]
    fn log_inverts_exp_from_zero_to_pi() {
        for (i, angle) in [0.0, 1e-9, 1e-5, 0.3, 1.0, 2.5, 3.1, std::f64::consts::PI]
            .into_iter()
            .enumerate()
        {
            let axis = Vector3::new(0.3, -0.5, 0.8 + 0.1 * i as f64).normalize();
            let phi = axis * angle;
            let back = log(&exp(&phi));
            // At exactly π both ±φ are the log; compare the rotations instead.
            let err = (exp(&back).inverse() * exp(&phi)).angle();
            assert!(err < ROUND_TRIP_TOLERANCE, "angle {angle}: error {err}");
            if angle < 3.0 {
                assert!((back - phi).norm() < ROUND_TRIP_TOLERANCE, "angle {angle}");
            }
        }
    }

    #[test]
    fn left_jacobian_inverse_matches_finite_differences() {
        // Finite-difference step and the agreement expected from it.
        const STEP: f64 = 1e-6;
        const FD_TOLERANCE: f64 = 1e-6;
        for phi in [
            Vector3::new(1e-7, 0.0, 0.0),
            Vector3::new(0.2, -0.1, 0.3),
            Vector3::new(1.0, 2.0, -0.5).normalize() * 3.0,
        ] {
            let jinv = left_jacobian_inverse(&phi);
            for k in 0..3 {
                let mut a = Vector3::zeros();
                a[k] = STEP;
                let plus = log(&(exp(&a) * exp(&phi)));
                let minus = log(&(exp(&(-a)) * exp(&phi)));
                let column = (plus - minus) / (2.0 * STEP);
                let err = (column - jinv.column(k)).norm();
                assert!(err < FD_TOLERANCE, "phi {phi:?} column {k}: error {err}");
            }
        }
    }
}
