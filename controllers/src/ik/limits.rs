//! Per-call bounds on the base position (AMBENCH_SPEC §2.6 "per-env base limits").
//!
//! The task decides them every tick from its obstacles: in front of a wall, door, cabinet or
//! window whose face is at world x = f, `max_x = f − safety_margin`; always `min_z = 0` (the
//! ground). The solver turns each bound into a hinge residual of the task level,
//! `w·max(0, x − max)` and `w·max(0, min − x)`.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Optional lower and upper bounds per world axis (x, y, z) on the base position, m.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseLimits {
    /// Lowest base position per world axis, m (None: unbounded).
    pub min_m: [Option<f64>; 3],
    /// Highest base position per world axis, m (None: unbounded).
    pub max_m: [Option<f64>; 3],
}

/// World axis indices, for [`BaseLimits::with_min`] and [`BaseLimits::with_max`].
pub const AXIS_X: usize = 0;
/// World y axis.
pub const AXIS_Y: usize = 1;
/// World z axis (up).
pub const AXIS_Z: usize = 2;

impl BaseLimits {
    /// No bound at all.
    pub const NONE: Self = Self {
        min_m: [None; 3],
        max_m: [None; 3],
    };

    /// Only the ground: `min_z = 0` (every task of the reference has at least this).
    pub fn above_ground() -> Self {
        Self::NONE.with_min(AXIS_Z, 0.0)
    }

    /// In front of an obstacle whose face is at world x = `face_x_m`, approached from −x:
    /// `max_x = face_x_m − safety_margin_m`, and `min_z = 0`.
    pub fn in_front_of_face_x(face_x_m: f64, safety_margin_m: f64) -> Self {
        Self::above_ground().with_max(AXIS_X, face_x_m - safety_margin_m)
    }

    /// These limits with a lower bound on world axis `axis` (0 x, 1 y, 2 z), m.
    ///
    /// # Panics
    /// If `axis > 2` (a caller bug).
    #[must_use]
    pub fn with_min(mut self, axis: usize, min_m: f64) -> Self {
        self.min_m[axis] = Some(min_m);
        self
    }

    /// These limits with an upper bound on world axis `axis` (0 x, 1 y, 2 z), m.
    ///
    /// # Panics
    /// If `axis > 2` (a caller bug).
    #[must_use]
    pub fn with_max(mut self, axis: usize, max_m: f64) -> Self {
        self.max_m[axis] = Some(max_m);
        self
    }

    /// True when every bound given is a finite number.
    pub fn is_finite(&self) -> bool {
        self.min_m
            .iter()
            .chain(&self.max_m)
            .all(|b| b.is_none_or(f64::is_finite))
    }

    /// (lower, upper) on `axis`, ±∞ where unbounded.
    pub fn bounds(&self, axis: usize) -> (f64, f64) {
        (
            self.min_m[axis].unwrap_or(f64::NEG_INFINITY),
            self.max_m[axis].unwrap_or(f64::INFINITY),
        )
    }

    /// The largest distance by which `position_m` lies outside the bounds, m (0 inside).
    pub fn violation_m(&self, position_m: &Vector3<f64>) -> f64 {
        (0..3)
            .map(|axis| {
                let (lo, hi) = self.bounds(axis);
                (position_m[axis] - hi).max(lo - position_m[axis]).max(0.0)
            })
            .fold(0.0, f64::max)
    }
}
