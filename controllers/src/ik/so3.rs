//! The few SO(3) maps the IK needs: exp, log and the inverse left Jacobian.
//!
//! Rotations are unit quaternions. `exp(φ)` is the rotation by |φ| about φ/|φ|; `log` is its
//! inverse with |log(R)| ∈ [0, π]. For a left (world-frame) perturbation,
//! `log(exp(a)·exp(φ)) ≈ φ + J_l⁻¹(φ)·a`, with
//!
//! ```text
//! J_l⁻¹(φ) = I − ½ φ^ + (1/θ²)(1 − (θ/2)·cot(θ/2)) φ^²,   θ = |φ|,
//! ```
//!
//! which is finite on the whole range θ ∈ [0, π] that `log` returns.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// Below this |imaginary part| of a quaternion (≈ half the angle, rad) `log` uses its series.
const LOG_SERIES_BELOW: f64 = 1e-6;
/// Below this angle (rad) `exp` and `left_jacobian_inverse` use their series.
const SERIES_BELOW_RAD: f64 = 1e-4;

/// The skew-symmetric matrix of `v`: `hat(v)·u = v × u`.
pub(crate) fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The rotation by the rotation vector `phi` (rad).
pub(crate) fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    // q = (cos(θ/2), sin(θ/2)/θ · φ)
    let (w, k) = if theta < SERIES_BELOW_RAD {
        (1.0 - theta2 / 8.0, 0.5 - theta2 / 48.0)
    } else {
        let half = 0.5 * theta;
        (half.cos(), half.sin() / theta)
    };
    UnitQuaternion::new_normalize(Quaternion::new(w, k * phi.x, k * phi.y, k * phi.z))
}

/// The rotation vector of `q` (rad), angle in [0, π].
pub(crate) fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = q.quaternion();
    // q and −q are the same rotation: take the one with w ≥ 0 so the angle is ≤ π.
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let s = v.norm();
    if s < LOG_SERIES_BELOW {
        // 2·atan(s/w)/s = (2/w)(1 − s²/(3w²) + …); w ≈ 1 here.
        v * ((2.0 / w) * (1.0 - s * s / (3.0 * w * w)))
    } else {
        v * (2.0 * s.atan2(w) / s)
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Round-off allowed on exp/log round trips, rad.
    const ROUND_TRIP_TOLERANCE: f64 = 1e-12;

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
    fn exp_matches_nalgebra() {
        let phi = Vector3::new(0.4, -1.2, 0.7);
        let ours = exp(&phi);
        let theirs = UnitQuaternion::from_scaled_axis(phi);
        assert!(ours.angle_to(&theirs) < ROUND_TRIP_TOLERANCE);
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
