//! Aggregate mass properties of a kinematic tree at a configuration.
//!
//! With link i of mass m_i, centre of mass c_i and inertia I_i (about c_i, in its inertial
//! frame rotated by R_i into the root frame):
//!
//! ```text
//! m = Σ m_i        c = Σ m_i c_i / m
//! J = Σ [ R_i I_i R_iᵀ + m_i (‖c_i − c‖² 1 − (c_i − c)(c_i − c)ᵀ) ]   (about c, root axes)
//! ```
//!
//! AM-Bench's controllers use a simpler sum (principal diagonals only, bodies taken at their
//! link origins, about the base origin; AMBENCH_SPEC §2.1). This is the exact composite
//! inertia; the controllers' issue decides which one they feed.

use nalgebra::{Matrix3, Point3, Vector3};
use serde::Serialize;

use crate::model::KinematicModel;

/// Mass, centre of mass and inertia of a whole tree.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MassProperties {
    /// Total mass, kg.
    pub mass_kg: f64,
    /// Centre of mass in the root frame, m.
    pub com_in_root_m: Vector3<f64>,
    /// Composite inertia about the centre of mass, root-frame axes, kg·m².
    pub inertia_about_com_kgm2: Matrix3<f64>,
}

impl KinematicModel {
    /// Mass properties at configuration `q`.
    ///
    /// # Panics
    /// If `q.len() != self.dof()`.
    pub fn mass_properties(&self, q: &[f64]) -> MassProperties {
        let poses = self.forward_kinematics(q);
        let bodies: Vec<_> = self
            .links
            .iter()
            .zip(&poses)
            .filter_map(|(link, root_from_link)| {
                link.inertial.map(|i| {
                    let root_from_inertial = root_from_link * i.link_from_inertial;
                    let rot = root_from_inertial.rotation.to_rotation_matrix();
                    let com = (root_from_inertial * Point3::origin()).coords;
                    (i.mass_kg, com, rot * i.inertia_kgm2 * rot.transpose())
                })
            })
            .collect();
        let mass_kg: f64 = bodies.iter().map(|b| b.0).sum();
        let com_in_root_m = if mass_kg > 0.0 {
            bodies.iter().map(|(m, c, _)| c * *m).sum::<Vector3<f64>>() / mass_kg
        } else {
            Vector3::zeros()
        };
        let inertia_about_com_kgm2 = bodies
            .iter()
            .map(|(m, c, inertia)| {
                let r = c - com_in_root_m;
                inertia + (Matrix3::identity() * r.norm_squared() - r * r.transpose()) * *m
            })
            .sum();
        MassProperties {
            mass_kg,
            com_in_root_m,
            inertia_about_com_kgm2,
        }
    }
}
