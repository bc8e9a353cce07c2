//! The allocator of one vehicle (see [`Allocator`]).

use nalgebra::{DMatrix, DVector, Vector6};
use platform::{Actuation, RotorLayout, Wrench};
use serde::{Deserialize, Serialize};

use crate::bounds::ThrustBounds;
use crate::constrained::ConstrainedQp;
use crate::effectiveness::{
    FULL_WRENCH_ROWS, REDUCED_WRENCH_ROWS, effectiveness_matrix, select_rows, validate_layout,
    variable_tilt_effectiveness_matrix,
};
use crate::pseudo_inverse::pseudo_inverse;
use crate::variable_tilt::{held_angle, magnitude_and_angle};
use crate::{Allocation, AllocationError, AllocationStatus, ConstrainedSettings, RotorSaturation};

/// How thrusts are computed from the requested wrench.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum AllocationMethod {
    /// x = A⁺w, then clipped into the thrust bounds (the AM-Bench reference).
    PseudoInverse,
    /// The weighted, bounded least-squares QP (clarabel), falling back on the pseudo-inverse
    /// clip if the solver does not converge.
    Constrained(ConstrainedSettings),
}

/// Allocates a body wrench to the rotors of one vehicle. Built once from the rotor layout,
/// actuation class and method; then asked for rotor setpoints every tick, reusing its buffers
/// (the pseudo-inverse and the QP are set up at construction).
///
/// | actuation      | matrix | commanded rows                       | variables            |
/// |----------------|--------|--------------------------------------|----------------------|
/// | fully actuated | 6×N    | F_x F_y F_z τ_x τ_y τ_z               | T_i                  |
/// | under-actuated | 4×N    | F_z τ_x τ_y τ_z (F_x, F_y not commanded) | T_i              |
/// | variable tilt  | 6×2N   | F_x F_y F_z τ_x τ_y τ_z               | (c_i, s_i) per rotor |
///
/// Methods: [`AllocationMethod::PseudoInverse`] (x = A⁺w, then clip into the bounds: clamp for
/// fixed rotors, magnitude scaling for tilting ones) and [`AllocationMethod::Constrained`] (the
/// weighted QP described at [`ConstrainedSettings`]; its fast path returns A⁺w untouched when
/// it already lies within bounds, where it is exact and therefore optimal).
///
/// Fixed-rotor classes use every rotor's `axis_in_base` (a tilting rotor counts as fixed at
/// α = 0); tilt joint limits are not applied here (the joint targets are clamped downstream).
#[derive(Debug)]
pub struct Allocator {
    actuation: Actuation,
    method: AllocationMethod,
    rows: &'static [usize],
    bounds: ThrustBounds,
    rotor_count: usize,
    /// Numerical rank of A.
    rank: usize,
    /// A, m × n.
    matrix: DMatrix<f64>,
    /// A⁺, n × m.
    pinv: DMatrix<f64>,
    /// The full 6 × n map of the variables to the wrench (for the achieved wrench).
    forward: DMatrix<f64>,
    /// W of the commanded rows (the constrained weights, or their defaults).
    weights: DVector<f64>,
    qp: Option<ConstrainedQp>,
    // Per-tick buffers.
    request: DVector<f64>,
    unconstrained: DVector<f64>,
    x: DVector<f64>,
    x_final: DVector<f64>,
}

impl Allocator {
    /// Builds the allocator: the allocation matrix, its pseudo-inverse and, for the
    /// constrained method, the QP.
    ///
    /// # Errors
    /// - [`AllocationError::NoRotors`], [`AllocationError::InvalidLayout`]: unusable layout;
    /// - [`AllocationError::UnsupportedActuation`]: the floating end-effector has no rotors;
    /// - [`AllocationError::MissingTilt`]: variable tilt asked of a fixed rotor;
    /// - [`AllocationError::InvalidSettings`]: constrained settings out of range.
    pub fn new(
        layout: &RotorLayout,
        actuation: Actuation,
        method: AllocationMethod,
    ) -> Result<Self, AllocationError> {
        validate_layout(layout)?;
        let full = effectiveness_matrix(layout);
        let (rows, matrix, forward, tilting): (&'static [usize], _, _, _) = match actuation {
            Actuation::FullyActuated => (&FULL_WRENCH_ROWS, full.clone(), full, false),
            Actuation::UnderActuated => (
                &REDUCED_WRENCH_ROWS,
                select_rows(&full, &REDUCED_WRENCH_ROWS),
                full,
                false,
            ),
            Actuation::VariableTilt => {
                let tilt = variable_tilt_effectiveness_matrix(layout)?;
                (&FULL_WRENCH_ROWS, tilt.clone(), tilt, true)
            }
            Actuation::FloatingEndEffector => {
                return Err(AllocationError::UnsupportedActuation(actuation));
            }
        };
        // A rank below the commanded rows is accepted, as in the reference and PX4: A⁺ then
        // gives the least-squares thrusts and the unreachable directions show up in the
        // unallocated wrench. `rank()` lets a vehicle check refuse it.
        let (pinv, rank) = pseudo_inverse(&matrix);
        let bounds = ThrustBounds {
            min_n: layout.thrust_min_n,
            max_n: layout.thrust_max_n,
            tilting,
        };
        let settings = match &method {
            AllocationMethod::PseudoInverse => ConstrainedSettings::default(),
            AllocationMethod::Constrained(settings) => *settings,
        };
        settings.validate()?;
        let qp = match &method {
            AllocationMethod::PseudoInverse => None,
            AllocationMethod::Constrained(settings) => {
                Some(ConstrainedQp::new(&matrix, rows, bounds, settings)?)
            }
        };
        let (m, n) = matrix.shape();
        Ok(Self {
            actuation,
            method,
            rows,
            bounds,
            rotor_count: layout.len(),
            rank,
            weights: DVector::from_iterator(
                m,
                rows.iter().map(|&r| settings.wrench_error_weights[r]),
            ),
            matrix,
            pinv,
            forward,
            qp,
            request: DVector::zeros(m),
            unconstrained: DVector::zeros(n),
            x: DVector::zeros(n),
            x_final: DVector::zeros(n),
        })
    }

    /// Number of rotors.
    pub fn rotor_count(&self) -> usize {
        self.rotor_count
    }

    /// Numerical rank of the allocation matrix ([`crate::RANK_TOLERANCE`]). Below the number
    /// of commanded rows, some wrench directions can never be achieved.
    pub fn rank(&self) -> usize {
        self.rank
    }

    /// The actuation class allocated for.
    pub fn actuation(&self) -> Actuation {
        self.actuation
    }

    /// The method.
    pub fn method(&self) -> &AllocationMethod {
        &self.method
    }

    /// Rows of `[F_x, F_y, F_z, τ_x, τ_y, τ_z]` the allocation commands.
    pub fn commanded_rows(&self) -> &'static [usize] {
        self.rows
    }

    /// The allocation matrix A (6×N, 4×N or 6×2N).
    pub fn matrix(&self) -> &DMatrix<f64> {
        &self.matrix
    }

    /// Its pseudo-inverse A⁺.
    pub fn pseudo_inverse(&self) -> &DMatrix<f64> {
        &self.pinv
    }

    /// `(T_min, T_max)`, N.
    pub fn thrust_limits_n(&self) -> (f64, f64) {
        (self.bounds.min_n, self.bounds.max_n)
    }

    /// An empty result buffer sized for this vehicle, for [`Allocator::allocate_into`].
    pub fn new_allocation(&self) -> Allocation {
        let tilt = if self.bounds.tilting {
            self.rotor_count
        } else {
            0
        };
        Allocation {
            thrusts_n: Vec::with_capacity(self.rotor_count),
            tilt_rad: Vec::with_capacity(tilt),
            unconstrained_thrusts_n: Vec::with_capacity(self.rotor_count),
            saturation: Vec::with_capacity(self.rotor_count),
            ..Allocation::default()
        }
    }

    /// The weighted wrench error ½ eᵀWe, e = requested − achieved over the commanded rows: the
    /// objective the constrained method minimises (with the pseudo-inverse method, the default
    /// weights).
    pub fn weighted_error(&self, requested: &Wrench, achieved: &Wrench) -> f64 {
        let (r, a) = (requested.to_vector(), achieved.to_vector());
        0.5 * self
            .rows
            .iter()
            .zip(self.weights.iter())
            .map(|(&row, w)| w * (r[row] - a[row]).powi(2))
            .sum::<f64>()
    }

    /// Allocates `wrench` (body frame, about the base origin) into `out`, reusing its buffers.
    ///
    /// `measured_tilt_rad` is read by variable-tilt allocation only: empty (every hinge taken
    /// at 0) or one measured angle per rotor; the returned angles are unwrapped against it.
    /// A non-finite request commands every rotor to T_min (see
    /// [`AllocationStatus::NonFiniteRequest`]).
    ///
    /// # Errors
    /// [`AllocationError::LengthMismatch`] if `measured_tilt_rad` is neither empty nor one per
    /// rotor (variable tilt only).
    pub fn allocate_into(
        &mut self,
        wrench: &Wrench,
        measured_tilt_rad: &[f64],
        out: &mut Allocation,
    ) -> Result<(), AllocationError> {
        let measured: &[f64] = if self.bounds.tilting {
            measured_tilt_rad
        } else {
            &[]
        };
        if !measured.is_empty() && measured.len() != self.rotor_count {
            return Err(AllocationError::LengthMismatch {
                what: "measured tilt angles",
                expected: self.rotor_count,
                got: measured.len(),
            });
        }
        let status = if wrench.is_finite() {
            self.solve(wrench, measured)
        } else {
            self.idle(measured);
            AllocationStatus::NonFiniteRequest
        };
        self.finish(wrench, measured, status, out);
        Ok(())
    }

    /// [`Allocator::allocate_into`] into a new [`Allocation`].
    ///
    /// # Errors
    /// As [`Allocator::allocate_into`].
    pub fn allocate(
        &mut self,
        wrench: &Wrench,
        measured_tilt_rad: &[f64],
    ) -> Result<Allocation, AllocationError> {
        let mut out = self.new_allocation();
        self.allocate_into(wrench, measured_tilt_rad, &mut out)?;
        Ok(out)
    }

    /// Fills `self.x` for a finite request and returns how.
    fn solve(&mut self, wrench: &Wrench, measured: &[f64]) -> AllocationStatus {
        let v = wrench.to_vector();
        for (k, &row) in self.rows.iter().enumerate() {
            self.request[k] = v[row];
        }
        self.unconstrained.gemv(1.0, &self.pinv, &self.request, 0.0);
        self.x.copy_from(&self.unconstrained);
        let status = if self.bounds.contains(self.x.as_slice()) {
            AllocationStatus::WithinBounds
        } else if let Some(qp) = &mut self.qp {
            match qp.solve(&self.request, &mut self.x) {
                failed @ AllocationStatus::SolverFailed { .. } => {
                    self.x.copy_from(&self.unconstrained);
                    failed
                }
                solved => solved,
            }
        } else {
            AllocationStatus::Clipped
        };
        // The pseudo-inverse clip; after a QP solve only the post-scaling of a tilting rotor to
        // T_min (non-convex, so outside the QP) can still act.
        self.bounds.clip(self.x.as_mut_slice(), measured);
        status
    }

    /// Every rotor at T_min; tilting rotors at their measured angle.
    fn idle(&mut self, measured: &[f64]) {
        let t_min = self.bounds.min_n;
        self.unconstrained.fill(t_min);
        if self.bounds.tilting {
            for rotor in 0..self.rotor_count {
                let angle = held_angle(measured.get(rotor).copied().unwrap_or(0.0));
                self.x[2 * rotor] = t_min * angle.cos();
                self.x[2 * rotor + 1] = t_min * angle.sin();
                self.unconstrained[2 * rotor] = self.x[2 * rotor];
                self.unconstrained[2 * rotor + 1] = self.x[2 * rotor + 1];
            }
        } else {
            self.x.fill(t_min);
        }
    }

    /// Writes thrusts, angles, achieved and unallocated wrench and saturation from `self.x`.
    fn finish(
        &mut self,
        requested: &Wrench,
        measured: &[f64],
        status: AllocationStatus,
        out: &mut Allocation,
    ) {
        let (t_min, t_max) = (self.bounds.min_n, self.bounds.max_n);
        out.thrusts_n.clear();
        out.tilt_rad.clear();
        out.unconstrained_thrusts_n.clear();
        out.saturation.clear();
        if self.bounds.tilting {
            for rotor in 0..self.rotor_count {
                let (c, s) = (self.x[2 * rotor], self.x[2 * rotor + 1]);
                let measured_angle = measured.get(rotor).copied().unwrap_or(0.0);
                let (thrust, angle) = magnitude_and_angle(c, s, measured_angle);
                // hypot of a pair scaled onto a bound can land an ulp outside it.
                let thrust = thrust.clamp(t_min, t_max);
                out.thrusts_n.push(thrust);
                out.tilt_rad.push(angle);
                // The wrench is that of the returned magnitude and angle, exactly.
                self.x_final[2 * rotor] = thrust * angle.cos();
                self.x_final[2 * rotor + 1] = thrust * angle.sin();
                let (uc, us) = (
                    self.unconstrained[2 * rotor],
                    self.unconstrained[2 * rotor + 1],
                );
                out.unconstrained_thrusts_n.push(uc.hypot(us));
            }
        } else {
            out.thrusts_n.extend(self.x.iter());
            out.unconstrained_thrusts_n
                .extend(self.unconstrained.iter());
            self.x_final.copy_from(&self.x);
        }
        let mut achieved = Vector6::zeros();
        for (j, &xj) in self.x_final.iter().enumerate() {
            for (i, a) in achieved.iter_mut().enumerate() {
                *a += self.forward[(i, j)] * xj;
            }
        }
        out.requested = *requested;
        out.achieved = Wrench::from_vector(&achieved);
        out.unallocated = if requested.is_finite() {
            *requested - out.achieved
        } else {
            // A NaN must not reach the controllers' anti-windup; the status carries the fault.
            Wrench::ZERO
        };
        out.saturation.extend(
            out.thrusts_n
                .iter()
                .map(|&t| RotorSaturation::of(t, t_min, t_max)),
        );
        out.status = status;
    }
}

#[cfg(test)]
#[expect(
    clippy::unwrap_used,
    clippy::float_cmp,
    reason = "a test fails loudly; exact values are the contract: clamps, zeros, replays"
)]
mod tests {
    use super::*;
    use crate::fixtures::{self, assert_all_close, assert_close};
    use nalgebra::Vector3;

    /// Round-off of an allocation and its forward map, N or N·m.
    const WRENCH_TOLERANCE: f64 = 1e-9;

    fn methods() -> [AllocationMethod; 2] {
        [
            AllocationMethod::PseudoInverse,
            AllocationMethod::Constrained(ConstrainedSettings::default()),
        ]
    }

    fn vehicles() -> [(RotorLayout, Actuation); 4] {
        [
            (fixtures::fa_hexa(), Actuation::FullyActuated),
            (fixtures::ua_hexa(), Actuation::UnderActuated),
            (fixtures::ua_quad(), Actuation::UnderActuated),
            (fixtures::omni_hexa(), Actuation::VariableTilt),
        ]
    }

    #[test]
    fn zero_wrench_gives_zero_thrusts_for_every_method() {
        for (layout, actuation) in vehicles() {
            for method in methods() {
                let mut allocator = Allocator::new(&layout, actuation, method).unwrap();
                let a = allocator.allocate(&Wrench::ZERO, &[]).unwrap();
                assert_eq!(
                    a.status,
                    AllocationStatus::WithinBounds,
                    "{actuation:?} {method:?}"
                );
                assert!(a.thrusts_n.iter().all(|&t| t.abs() <= WRENCH_TOLERANCE));
                assert_eq!(a.thrusts_n.len(), layout.len());
                let expected_tilts = if actuation == Actuation::VariableTilt {
                    6
                } else {
                    0
                };
                assert_eq!(a.tilt_rad.len(), expected_tilts);
                assert!(a.tilt_rad.iter().all(|&t| t == 0.0));
                assert_eq!(a.achieved, Wrench::ZERO);
                assert_eq!(a.unallocated, Wrench::ZERO);
                // T_min = 0: idle rotors sit at the lower bound.
                assert!(a.saturation.iter().all(|s| *s == RotorSaturation::Lower));
            }
        }
    }

    #[test]
    fn non_finite_request_idles_every_rotor() {
        for (layout, actuation) in vehicles() {
            for method in methods() {
                let mut allocator = Allocator::new(&layout, actuation, method).unwrap();
                let wrench = Wrench::new(Vector3::new(0.0, f64::NAN, 50.0), Vector3::zeros());
                let measured = vec![0.3; layout.len()];
                let a = allocator.allocate(&wrench, &measured).unwrap();
                assert_eq!(a.status, AllocationStatus::NonFiniteRequest);
                assert!(a.thrusts_n.iter().all(|&t| t == layout.thrust_min_n));
                assert!(a.unconstrained_thrusts_n.iter().all(|t| t.is_finite()));
                assert_eq!(a.unallocated, Wrench::ZERO);
                assert!(a.achieved.is_finite());
                assert!(a.tilt_rad.iter().all(|&t| t == 0.3), "hinges hold");
            }
        }
    }

    #[test]
    fn allocate_into_reuses_buffers_across_vehicles() {
        let mut quad = Allocator::new(
            &fixtures::ua_quad(),
            Actuation::UnderActuated,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        let mut omni = Allocator::new(
            &fixtures::omni_hexa(),
            Actuation::VariableTilt,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        let mut out = omni.new_allocation();
        let hover = Wrench::new(Vector3::new(0.0, 0.0, 40.0), Vector3::zeros());
        omni.allocate_into(&hover, &[], &mut out).unwrap();
        assert_eq!((out.thrusts_n.len(), out.tilt_rad.len()), (6, 6));
        quad.allocate_into(&hover, &[], &mut out).unwrap();
        assert_eq!((out.thrusts_n.len(), out.tilt_rad.len()), (4, 0));
        assert_all_close(
            out.thrusts_n.iter(),
            [10.0; 4].iter(),
            WRENCH_TOLERANCE,
            "hover",
        );
    }

    #[test]
    fn measured_tilt_of_wrong_length_is_rejected() {
        let mut omni = Allocator::new(
            &fixtures::omni_hexa(),
            Actuation::VariableTilt,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        assert!(matches!(
            omni.allocate(&Wrench::ZERO, &[0.0; 5]),
            Err(AllocationError::LengthMismatch {
                expected: 6,
                got: 5,
                ..
            })
        ));
        // A fixed-rotor allocator ignores it.
        let mut quad = Allocator::new(
            &fixtures::ua_quad(),
            Actuation::UnderActuated,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        assert!(quad.allocate(&Wrench::ZERO, &[0.0; 5]).is_ok());
    }

    #[test]
    fn wrong_actuation_class_is_rejected_or_reported() {
        let method = AllocationMethod::PseudoInverse;
        let parallel = Allocator::new(&fixtures::ua_hexa(), Actuation::FullyActuated, method);
        assert_eq!(
            parallel.unwrap().rank(),
            4,
            "parallel axes: no body F_x, F_y"
        );
        assert_eq!(
            Allocator::new(&fixtures::ua_quad(), Actuation::VariableTilt, method).unwrap_err(),
            AllocationError::MissingTilt { rotor: 0 }
        );
        assert!(matches!(
            Allocator::new(&fixtures::ua_quad(), Actuation::FloatingEndEffector, method),
            Err(AllocationError::UnsupportedActuation(_))
        ));
        let bad = AllocationMethod::Constrained(ConstrainedSettings {
            max_iterations: 0,
            ..ConstrainedSettings::default()
        });
        assert!(matches!(
            Allocator::new(&fixtures::ua_quad(), Actuation::UnderActuated, bad),
            Err(AllocationError::InvalidSettings(_))
        ));
    }

    #[test]
    fn under_actuated_allocation_ignores_lateral_force() {
        let mut quad = Allocator::new(
            &fixtures::ua_quad(),
            Actuation::UnderActuated,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        let wrench = Wrench::new(Vector3::new(3.0, -2.0, 40.0), Vector3::zeros());
        let a = quad.allocate(&wrench, &[]).unwrap();
        assert_all_close(
            a.thrusts_n.iter(),
            [10.0; 4].iter(),
            WRENCH_TOLERANCE,
            "hover",
        );
        // F_x, F_y are reported as not achieved.
        assert_close(
            a.unallocated.force.x,
            3.0,
            WRENCH_TOLERANCE,
            "unallocated F_x",
        );
        assert_close(
            a.unallocated.force.y,
            -2.0,
            WRENCH_TOLERANCE,
            "unallocated F_y",
        );
        assert!(quad.weighted_error(&wrench, &a.achieved) < 1e-18);
    }

    #[test]
    fn constrained_beats_clip_on_a_saturating_fa_hexa_request() {
        let layout = fixtures::fa_hexa();
        let constrained = AllocationMethod::Constrained(ConstrainedSettings::default());
        let mut qp = Allocator::new(&layout, Actuation::FullyActuated, constrained).unwrap();
        let mut clip = Allocator::new(
            &layout,
            Actuation::FullyActuated,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        let wrench = Wrench::new(Vector3::new(20.0, 0.0, 150.0), Vector3::new(3.0, 0.0, 0.0));
        let a = qp.allocate(&wrench, &[]).unwrap();
        let b = clip.allocate(&wrench, &[]).unwrap();
        assert!(
            matches!(a.status, AllocationStatus::Solved { .. }),
            "{:?}",
            a.status
        );
        assert_eq!(b.status, AllocationStatus::Clipped);
        let (e_qp, e_clip) = (
            qp.weighted_error(&wrench, &a.achieved),
            qp.weighted_error(&wrench, &b.achieved),
        );
        assert!(e_qp < e_clip, "QP {e_qp} vs clip {e_clip}");
        assert!(a.thrusts_n.iter().all(|&t| (0.0..=23.0).contains(&t)));
    }

    #[test]
    fn solver_failure_falls_back_to_clipping() {
        let layout = fixtures::ua_quad();
        let starved = AllocationMethod::Constrained(ConstrainedSettings {
            max_iterations: 1,
            ..ConstrainedSettings::default()
        });
        let mut qp = Allocator::new(&layout, Actuation::UnderActuated, starved).unwrap();
        let mut clip = Allocator::new(
            &layout,
            Actuation::UnderActuated,
            AllocationMethod::PseudoInverse,
        )
        .unwrap();
        let yaw = Wrench::new(Vector3::new(0.0, 0.0, 43.0), Vector3::new(0.0, 0.0, 5.0));
        let a = qp.allocate(&yaw, &[]).unwrap();
        assert_eq!(
            a.status,
            AllocationStatus::SolverFailed {
                reason: crate::SolverFailure::MaxIterations
            }
        );
        assert!(a.status.is_fallback());
        assert_eq!(a.thrusts_n, clip.allocate(&yaw, &[]).unwrap().thrusts_n);
    }

    #[test]
    fn tilting_rotor_minimum_is_applied_after_the_qp() {
        // T_min > 0 makes a tilting rotor's set an annulus (not convex): the QP works on the
        // disc and the magnitudes below T_min are scaled up afterwards.
        let mut layout = fixtures::omni_hexa();
        layout.thrust_min_n = 2.0;
        let method = AllocationMethod::Constrained(ConstrainedSettings::default());
        let mut qp = Allocator::new(&layout, Actuation::VariableTilt, method).unwrap();
        let wrench = Wrench::new(Vector3::new(150.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.5));
        let a = qp.allocate(&wrench, &[0.0; 6]).unwrap();
        assert!(
            matches!(a.status, AllocationStatus::Solved { .. }),
            "{:?}",
            a.status
        );
        assert!(
            a.thrusts_n.iter().all(|&t| (2.0..=23.0).contains(&t)),
            "{:?}",
            a.thrusts_n
        );
        let idle = qp.allocate(&Wrench::ZERO, &[0.4; 6]).unwrap();
        assert!(idle.thrusts_n.iter().all(|&t| (t - 2.0).abs() < 1e-12));
        assert!(
            idle.tilt_rad.iter().all(|&t| (t - 0.4).abs() < 1e-12),
            "hinges hold"
        );
    }
}
