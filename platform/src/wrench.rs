//! A force–torque pair acting on a body, expressed in one frame about one point.

use nalgebra::{Vector3, Vector6};
use serde::{Deserialize, Serialize};

/// A wrench: force (N) and torque (N·m), both expressed in the same frame and the torque
/// taken about that frame's origin. Which frame is the caller's to name (`wrench_in_body`).
///
/// As a 6-vector the order is `[F_x, F_y, F_z, τ_x, τ_y, τ_z]`, the row order of every
/// effectiveness matrix in `allocation`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Wrench {
    /// Force, N.
    pub force: Vector3<f64>,
    /// Torque about the frame origin, N·m.
    pub torque: Vector3<f64>,
}

impl Wrench {
    /// The zero wrench.
    pub const ZERO: Self = Self {
        force: Vector3::new(0.0, 0.0, 0.0),
        torque: Vector3::new(0.0, 0.0, 0.0),
    };

    /// A wrench from its force and torque.
    pub fn new(force: Vector3<f64>, torque: Vector3<f64>) -> Self {
        Self { force, torque }
    }

    /// From `[F_x, F_y, F_z, τ_x, τ_y, τ_z]`.
    pub fn from_vector(v: &Vector6<f64>) -> Self {
        Self {
            force: v.fixed_rows::<3>(0).into_owned(),
            torque: v.fixed_rows::<3>(3).into_owned(),
        }
    }

    /// As `[F_x, F_y, F_z, τ_x, τ_y, τ_z]`.
    pub fn to_vector(&self) -> Vector6<f64> {
        Vector6::new(
            self.force.x,
            self.force.y,
            self.force.z,
            self.torque.x,
            self.torque.y,
            self.torque.z,
        )
    }

    /// True when all six components are finite (no NaN, no infinity).
    pub fn is_finite(&self) -> bool {
        self.force
            .iter()
            .chain(self.torque.iter())
            .all(|x| x.is_finite())
    }
}

impl std::ops::Add for Wrench {
    type Output = Self;
    fn add(self, rhs: Self) -> Self {
        Self::new(self.force + rhs.force, self.torque + rhs.torque)
    }
}

impl std::ops::Sub for Wrench {
    type Output = Self;
    fn sub(self, rhs: Self) -> Self {
        Self::new(self.force - rhs.force, self.torque - rhs.torque)
    }
}
