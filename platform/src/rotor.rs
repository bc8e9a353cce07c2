//! Rotor layout: where each rotor sits on the base, where it pushes, how it spins, and the
//! limits every rotor shares.
//!
//! Everything is expressed in the base-link frame (FLU), at the zero configuration. For a
//! variable-tilt rotor (Omni-Hexa), `axis_in_base` is the thrust direction at tilt angle 0
//! (the "cos axis" c_i) and [`Tilt::sin_axis_in_base`] the direction it turns towards
//! (s_i = normalise(a_i × c_i), with a_i the tilt hinge axis), so that at tilt α the thrust
//! direction is cos α·c_i + sin α·s_i. Rotor positions are held at their α = 0 reference.

use nalgebra::{Unit, Vector3};
use serde::Serialize;

/// Sense of a rotor's drag reaction torque, the s_i of the effectiveness column
/// `[d_i ; r_i × d_i + s_i·k_f·d_i]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Spin {
    /// s_i = +1: the reaction torque on the base points along the thrust axis
    /// (a propeller turning clockwise seen from the side it pushes towards).
    Positive,
    /// s_i = −1: the reaction torque points against the thrust axis.
    Negative,
}

impl Spin {
    /// s_i as a number, +1 or −1.
    pub fn sign(self) -> f64 {
        match self {
            Spin::Positive => 1.0,
            Spin::Negative => -1.0,
        }
    }
}

/// The hinge of a variable-tilt rotor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Tilt {
    /// The URDF joint that tilts the rotor (its position is the tilt angle α).
    pub joint: String,
    /// Hinge axis a_i in the base frame.
    pub hinge_axis_in_base: Unit<Vector3<f64>>,
    /// s_i: the thrust direction at α = +90°, in the base frame; orthogonal to `axis_in_base`.
    pub sin_axis_in_base: Unit<Vector3<f64>>,
    /// Tilt angle limits (lower, upper), rad, from the joint.
    pub limits_rad: (f64, f64),
}

/// One rotor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Rotor {
    /// The URDF link that marks the rotor (its origin is the rotor centre, its +z the thrust axis).
    pub link: String,
    /// Rotor centre r_i in the base frame, m.
    pub position_in_base: Vector3<f64>,
    /// Unit thrust direction d_i in the base frame (c_i for a tilting rotor at α = 0).
    pub axis_in_base: Unit<Vector3<f64>>,
    /// Sense of the reaction torque.
    pub spin: Spin,
    /// Present for a variable-tilt rotor.
    pub tilt: Option<Tilt>,
}

impl Rotor {
    /// A fixed rotor from its geometry, for tests and hand-built layouts.
    pub fn fixed(position_in_base: Vector3<f64>, axis_in_base: Vector3<f64>, spin: Spin) -> Self {
        Self {
            link: String::new(),
            position_in_base,
            axis_in_base: Unit::new_normalize(axis_in_base),
            spin,
            tilt: None,
        }
    }

    /// Thrust direction in the base frame at tilt angle `tilt_rad` (ignored for a fixed rotor).
    pub fn axis_at_tilt(&self, tilt_rad: f64) -> Vector3<f64> {
        match &self.tilt {
            None => self.axis_in_base.into_inner(),
            Some(t) => {
                tilt_rad.cos() * self.axis_in_base.into_inner()
                    + tilt_rad.sin() * t.sin_axis_in_base.into_inner()
            }
        }
    }
}

/// All rotors of a vehicle and the figures they share.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RotorLayout {
    /// The rotors, in actuator order (the order of every thrust vector in the stack).
    pub rotors: Vec<Rotor>,
    /// Lowest thrust a rotor can produce, N (≥ 0).
    pub thrust_min_n: f64,
    /// Highest thrust a rotor can produce, N.
    pub thrust_max_n: f64,
    /// Reaction-torque-to-thrust ratio k_f, m.
    pub reaction_torque_ratio_m: f64,
    /// Propeller radius r_p, m (ground and near-wall effect models).
    pub propeller_radius_m: f64,
    /// Normalised command ↔ thrust of the motors (what an autopilot's outputs mean).
    pub thrust_curve: ThrustCurve,
}

/// The motor thrust curve of PX4's `THR_MDL_FAC`: a normalised motor command u ∈ [0, 1]
/// produces the relative thrust
///
/// ```text
/// t = k·u² + (1 − k)·u,      T = T_min + t·(T_max − T_min)
/// ```
///
/// k = 0 is linear in thrust, k = 1 is thrust ∝ u² (u proportional to rotor speed).
/// The inverse is `u = (−(1 − k) + √((1 − k)² + 4·k·t)) / (2k)` for k > 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ThrustCurve {
    /// k ∈ [0, 1] (PX4's `THR_MDL_FAC`).
    pub model_factor: f64,
    /// T at u = 0, N.
    pub thrust_min_n: f64,
    /// T at u = 1, N.
    pub thrust_max_n: f64,
}

impl ThrustCurve {
    /// Thrust, N, of a normalised command (clamped to [0, 1]; a non-finite command gives
    /// `thrust_min_n`).
    pub fn thrust_n(&self, command: f64) -> f64 {
        let u = if command.is_finite() {
            command.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let k = self.model_factor;
        let t = k * u * u + (1.0 - k) * u;
        self.thrust_min_n + t * (self.thrust_max_n - self.thrust_min_n)
    }

    /// Normalised command in [0, 1] that produces `thrust_n` (clamped to the thrust range; a
    /// non-finite thrust gives 0).
    pub fn command(&self, thrust_n: f64) -> f64 {
        let span = self.thrust_max_n - self.thrust_min_n;
        if !thrust_n.is_finite() || span <= 0.0 {
            return 0.0;
        }
        let t = ((thrust_n - self.thrust_min_n) / span).clamp(0.0, 1.0);
        let k = self.model_factor;
        if k <= f64::EPSILON {
            return t;
        }
        let linear = 1.0 - k;
        let u = (-linear + (linear * linear + 4.0 * k * t).sqrt()) / (2.0 * k);
        u.clamp(0.0, 1.0)
    }
}

impl RotorLayout {
    /// Number of rotors.
    pub fn len(&self) -> usize {
        self.rotors.len()
    }

    /// True for a vehicle without rotors (the EE-only oracle).
    pub fn is_empty(&self) -> bool {
        self.rotors.is_empty()
    }

    /// True when every rotor can tilt.
    pub fn is_variable_tilt(&self) -> bool {
        !self.rotors.is_empty() && self.rotors.iter().all(|r| r.tilt.is_some())
    }
}
