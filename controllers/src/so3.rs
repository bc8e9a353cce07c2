//! Small SO(3) helpers shared by the controllers.

use nalgebra::{Matrix3, Vector3};

/// The skew-symmetric matrix v^ with v^·x = v × x.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    v.cross_matrix()
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
