//! Reference trajectories of `amstack track`: the validation experiments of the paper.
//!
//! All start from hover at (0, 0, 1) m, level, heading +x, with the arm at its initial
//! posture and the gripper closed:
//!
//! | name | reference |
//! |---|---|
//! | `hover` | hold (0, 0, 1) m |
//! | `step` | hold, then at t = 1 s a 1 m step along world x |
//! | `sines-low` | base z = 1 + Σ 0.01 sin(2π f_k t + φ_k), f_k = 0.18, 0.357, 0.533, 0.71 Hz |
//! | `sines-high` | the same with f_k = 0.25, 0.667, 1.083, 1.50 Hz |
//!
//! (both faded in over their first 2 s)
//! | `ground-sweep` | end-effector z = 0.8 + 0.2 cos(2πt/30) m, lateral position held |
//! | `arm-sweep` | hover while every arm joint sweeps its range (8 s period) |
//!
//! The paper gives the sum-of-sines bands (0.18–0.71 Hz and 0.25–1.50 Hz) but not the
//! components: amstack uses four equal 1 cm components spread evenly over each band with
//! Schroeder phases φ_k = −πk(k−1)/4 (a low peak-to-RMS ratio), so the two references have
//! the same amplitude and differ only in frequency content. 1 cm keeps the high band inside
//! the identified actuator envelope, as the paper's runs were: it reports no rotor near
//! 23 N and the 0.75 s⁻¹ normalised-speed rate cap barely mattering. Measured here on the
//! FA-Hexa: with 2 cm components the high band asks the rotors for more speed rate than the
//! cap allows, and tracking collapses into a bang-bang cycle (base z RMSE ~94 cm; nothing
//! reports rate saturation to the controller); with 5 cm the peak thrust nears 23 N. The ground sweep is the paper's
//! EE reference; with the base + joint interface the arm holds its posture and the base
//! carries the EE along it.

use std::f64::consts::PI;
use std::str::FromStr;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use platform::Vehicle;
use serde::Serialize;

use crate::stack::BaseJointTarget;

/// A reference of `amstack track`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Trajectory {
    /// Hold 1 m.
    Hover,
    /// 1 m step along x at t = 1 s.
    Step,
    /// Vertical sum of sines, 0.18–0.71 Hz.
    SinesLow,
    /// Vertical sum of sines, 0.25–1.50 Hz.
    SinesHigh,
    /// The paper's ground-effect sweep of the end effector.
    GroundSweep,
    /// Hover while the arm sweeps its range.
    ArmSweep,
}

impl Trajectory {
    /// All trajectories, as named on the command line.
    pub const ALL: [Trajectory; 6] = [
        Self::Hover,
        Self::Step,
        Self::SinesLow,
        Self::SinesHigh,
        Self::GroundSweep,
        Self::ArmSweep,
    ];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Hover => "hover",
            Self::Step => "step",
            Self::SinesLow => "sines-low",
            Self::SinesHigh => "sines-high",
            Self::GroundSweep => "ground-sweep",
            Self::ArmSweep => "arm-sweep",
        }
    }

    /// A sensible flight length, s.
    pub fn default_duration_s(self) -> f64 {
        match self {
            Self::Hover | Self::Step => 10.0,
            Self::SinesLow | Self::SinesHigh => 30.0,
            Self::GroundSweep => 60.0,
            Self::ArmSweep => 16.0,
        }
    }

    /// The target at time `t_s` for `vehicle`.
    pub fn target(self, vehicle: &Vehicle, t_s: f64) -> BaseJointTarget {
        let q0 = vehicle.initial_configuration();
        let mut arm: Vec<f64> = vehicle.arm_dofs().iter().map(|&d| q0[d]).collect();
        let (x, z) = match self {
            Self::Hover | Self::ArmSweep => (0.0, 1.0),
            Self::Step => (if t_s >= 1.0 { 1.0 } else { 0.0 }, 1.0),
            Self::SinesLow => (0.0, 1.0 + fade_in(t_s) * sum_of_sines(t_s, 0.18, 0.71)),
            Self::SinesHigh => (0.0, 1.0 + fade_in(t_s) * sum_of_sines(t_s, 0.25, 1.50)),
            Self::GroundSweep => {
                // The EE link's height above the base at the held arm posture.
                let ee_above_base = vehicle.base_from_ee(&q0).translation.vector.z;
                (
                    0.0,
                    0.8 + 0.2 * (2.0 * PI * t_s / 30.0).cos() - ee_above_base,
                )
            }
        };
        if self == Self::ArmSweep {
            let phase = 0.5 - 0.5 * (2.0 * PI * t_s / 8.0).cos();
            for (q, &dof) in arm.iter_mut().zip(&vehicle.arm_dofs()) {
                let (lo, hi) = vehicle
                    .model
                    .dof_joint(dof)
                    .limits
                    .map_or((-1.0, 1.0), |l| {
                        (l.lower.max(-PI / 2.0), l.upper.min(PI / 2.0))
                    });
                // From the initial posture out to 90 % of the way to the far limit and back.
                let start = q0[dof].clamp(lo, hi);
                let far = if hi - start > start - lo { hi } else { lo };
                *q = start + 0.9 * phase * (far - start);
            }
        }
        BaseJointTarget {
            world_from_base: Isometry3::from_parts(
                Translation3::new(x, 0.0, z),
                UnitQuaternion::identity(),
            ),
            arm_joints: arm,
            gripper: -1.0,
        }
    }
}

/// The sums of sines fade in over this long, s (inside the default 2 s settling time).
pub const SINES_FADE_IN_S: f64 = 2.0;

/// Smoothstep from 0 to 1 over [`SINES_FADE_IN_S`]: the reference starts at rest. A sum of
/// sines switched on at full amplitude starts moving at once, and the PID's velocity term
/// (120 1/s) turns that velocity step into a near free-fall thrust command on the first tick.
fn fade_in(t: f64) -> f64 {
    let x = (t / SINES_FADE_IN_S).clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Amplitude of each sum-of-sines component, m.
pub const SINE_COMPONENT_AMPLITUDE_M: f64 = 0.01;

/// Σ_{k=1..4} a sin(2π f_k t + φ_k), f_k evenly over [f_lo, f_hi], Schroeder phases.
fn sum_of_sines(t: f64, f_lo: f64, f_hi: f64) -> f64 {
    (0..4u8)
        .map(|k| {
            let k = f64::from(k);
            let f = f_lo + (f_hi - f_lo) * k / 3.0;
            // φ_k = −πk(k−1)/4 for k = 1..4, here indexed from 0.
            let phi = -PI * (k * (k + 1.0)) / 4.0;
            SINE_COMPONENT_AMPLITUDE_M * (2.0 * PI * f * t + phi).sin()
        })
        .sum()
}

impl FromStr for Trajectory {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|t| t.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|t| t.name()).collect();
                format!("unknown trajectory '{s}' (known: {})", names.join(", "))
            })
    }
}
