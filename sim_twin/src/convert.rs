//! The one boundary between nalgebra (the whole stack) and rapier/parry's glam types.

use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::math::{Matrix, Pose, Rotation, Vector};

pub(crate) fn vector_to_rapier(v: &Vector3<f64>) -> Vector {
    Vector::new(v.x, v.y, v.z)
}

pub(crate) fn vector_from_rapier(v: Vector) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

pub(crate) fn rotation_to_rapier(q: &UnitQuaternion<f64>) -> Rotation {
    Rotation::from_xyzw(q.i, q.j, q.k, q.w)
}

pub(crate) fn rotation_from_rapier(q: Rotation) -> UnitQuaternion<f64> {
    UnitQuaternion::new_normalize(Quaternion::new(q.w, q.x, q.y, q.z))
}

pub(crate) fn pose_to_rapier(p: &Isometry3<f64>) -> Pose {
    Pose::from_parts(
        vector_to_rapier(&p.translation.vector),
        rotation_to_rapier(&p.rotation),
    )
}

pub(crate) fn pose_from_rapier(p: &Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(vector_from_rapier(p.translation)),
        rotation_from_rapier(p.rotation),
    )
}

pub(crate) fn matrix_to_rapier(m: &Matrix3<f64>) -> Matrix {
    Matrix::from_cols(
        Vector::new(m[(0, 0)], m[(1, 0)], m[(2, 0)]),
        Vector::new(m[(0, 1)], m[(1, 1)], m[(2, 1)]),
        Vector::new(m[(0, 2)], m[(1, 2)], m[(2, 2)]),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_round_trip_through_rapier() {
        let p = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 0.5),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
        );
        let back = pose_from_rapier(&pose_to_rapier(&p));
        assert!((back.translation.vector - p.translation.vector).norm() < 1e-15);
        assert!(back.rotation.angle_to(&p.rotation) < 1e-12);
        // Rotating a vector agrees on both sides.
        let v = Vector3::new(0.1, 0.2, 0.3);
        let r = vector_from_rapier(rotation_to_rapier(&p.rotation) * vector_to_rapier(&v));
        assert!((r - p.rotation * v).norm() < 1e-15);
        let m = Matrix3::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0);
        let mv = vector_from_rapier(matrix_to_rapier(&m) * vector_to_rapier(&v));
        assert!((mv - m * v).norm() < 1e-14);
    }
}
