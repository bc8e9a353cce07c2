//! The thrust bounds of an allocation variable vector x: one thrust per fixed rotor
//! (T_min ≤ T_i ≤ T_max), or one (c, s) pair per tilting rotor (T_min ≤ ‖(c, s)‖ ≤ T_max).

use crate::variable_tilt::{bound_thrust_vector, within_magnitude_bounds};

/// Per-rotor thrust bounds and the shape of the variable vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ThrustBounds {
    /// T_min, N.
    pub min_n: f64,
    /// T_max, N.
    pub max_n: f64,
    /// Variables are (c, s) pairs of tilting rotors.
    pub tilting: bool,
}

impl ThrustBounds {
    /// Variables per rotor: 1 (thrust) or 2 (c, s).
    pub fn variables_per_rotor(self) -> usize {
        if self.tilting { 2 } else { 1 }
    }

    /// Thrust magnitude of rotor `rotor` in `x`.
    pub fn magnitude(self, x: &[f64], rotor: usize) -> f64 {
        if self.tilting {
            x[2 * rotor].hypot(x[2 * rotor + 1])
        } else {
            x[rotor]
        }
    }

    /// True when every rotor of `x` is within its bounds (no tolerance).
    pub fn contains(self, x: &[f64]) -> bool {
        if self.tilting {
            x.chunks_exact(2)
                .all(|p| within_magnitude_bounds(p[0], p[1], self.min_n, self.max_n))
        } else {
            x.iter().all(|&t| t >= self.min_n && t <= self.max_n)
        }
    }

    /// The clip-after-pseudo-inverse rule: clamp each thrust (fixed rotors) or scale each
    /// (c, s) magnitude (tilting rotors, see [`crate::variable_tilt`]) into the bounds.
    /// `measured_tilt_rad` (empty or one per rotor) orients a tilting rotor with no thrust
    /// vector. Returns true when anything changed.
    pub fn clip(self, x: &mut [f64], measured_tilt_rad: &[f64]) -> bool {
        let mut changed = false;
        if self.tilting {
            for (rotor, pair) in x.chunks_exact_mut(2).enumerate() {
                let measured = measured_tilt_rad.get(rotor).copied().unwrap_or(0.0);
                let ((c, s), moved) =
                    bound_thrust_vector(pair[0], pair[1], self.min_n, self.max_n, measured);
                pair[0] = c;
                pair[1] = s;
                changed |= moved;
            }
        } else {
            for t in x.iter_mut() {
                changed |= *t < self.min_n || *t > self.max_n;
                *t = t.clamp(self.min_n, self.max_n);
            }
        }
        changed
    }

    /// Projection onto the convex set the QP works in: the box for fixed rotors, the disc
    /// ‖(c, s)‖ ≤ T_max for tilting ones (T_min > 0 is not convex for a tilting rotor; it is
    /// applied afterwards by [`ThrustBounds::clip`]).
    pub fn project_onto_convex_set(self, x: &mut [f64]) {
        if self.tilting {
            for pair in x.chunks_exact_mut(2) {
                let magnitude = pair[0].hypot(pair[1]);
                if magnitude > self.max_n {
                    let scale = self.max_n / magnitude;
                    pair[0] *= scale;
                    pair[1] *= scale;
                }
            }
        } else {
            for t in x.iter_mut() {
                *t = t.clamp(self.min_n, self.max_n);
            }
        }
    }

    /// True when rotor `rotor` of `x` is within `tolerance_n` of a bound of the convex set (its
    /// variables are then held by the polish step).
    pub fn at_convex_bound(self, x: &[f64], rotor: usize, tolerance_n: f64) -> bool {
        let magnitude = self.magnitude(x, rotor);
        if self.tilting {
            magnitude >= self.max_n - tolerance_n
        } else {
            magnitude <= self.min_n + tolerance_n || magnitude >= self.max_n - tolerance_n
        }
    }

    /// Largest t ∈ [0, ∞) for which rotor `rotor` of x + t·step stays in the convex set
    /// (∞ when the step does not move it towards a bound).
    pub fn max_step(self, x: &[f64], step: &[f64], rotor: usize) -> f64 {
        if self.tilting {
            // |p + t d|² = R²:  a t² + 2 b t + c = 0, positive root.
            let (p, d) = (
                [x[2 * rotor], x[2 * rotor + 1]],
                [step[2 * rotor], step[2 * rotor + 1]],
            );
            let a = d[0] * d[0] + d[1] * d[1];
            if a == 0.0 {
                return f64::INFINITY;
            }
            let b = p[0] * d[0] + p[1] * d[1];
            let c = (p[0] * p[0] + p[1] * p[1] - self.max_n * self.max_n).min(0.0);
            ((-b + (b * b - a * c).sqrt()) / a).max(0.0)
        } else {
            let (t, d) = (x[rotor], step[rotor]);
            if d > 0.0 {
                ((self.max_n - t) / d).max(0.0)
            } else if d < 0.0 {
                ((self.min_n - t) / d).max(0.0)
            } else {
                f64::INFINITY
            }
        }
    }

    /// Puts rotor `rotor` of `x` exactly on the nearer bound of the convex set.
    pub fn snap_to_nearest_bound(self, x: &mut [f64], rotor: usize) {
        if self.tilting {
            let magnitude = x[2 * rotor].hypot(x[2 * rotor + 1]);
            if magnitude > 0.0 {
                let scale = self.max_n / magnitude;
                x[2 * rotor] *= scale;
                x[2 * rotor + 1] *= scale;
            }
        } else if x[rotor] - self.min_n < self.max_n - x[rotor] {
            x[rotor] = self.min_n;
        } else {
            x[rotor] = self.max_n;
        }
    }

    /// Puts rotor `rotor` of `x` exactly on the bound that `step` was heading for.
    pub fn snap_to_bound(self, x: &mut [f64], step: &[f64], rotor: usize) {
        if self.tilting {
            let magnitude = x[2 * rotor].hypot(x[2 * rotor + 1]);
            if magnitude > 0.0 {
                let scale = self.max_n / magnitude;
                x[2 * rotor] *= scale;
                x[2 * rotor + 1] *= scale;
            }
        } else if step[rotor] > 0.0 {
            x[rotor] = self.max_n;
        } else if step[rotor] < 0.0 {
            x[rotor] = self.min_n;
        }
    }
}

#[cfg(test)]
#[expect(
    clippy::float_cmp,
    reason = "exact values are the contract: clamps, zeros, replays"
)]
mod tests {
    use super::*;

    const FIXED: ThrustBounds = ThrustBounds {
        min_n: 0.0,
        max_n: 23.0,
        tilting: false,
    };
    const TILTING: ThrustBounds = ThrustBounds {
        min_n: 0.0,
        max_n: 23.0,
        tilting: true,
    };

    #[test]
    fn clip_clamps_fixed_rotors() {
        let mut x = [-1.0, 5.0, 30.0];
        assert!(!FIXED.contains(&x));
        assert!(FIXED.clip(&mut x, &[]));
        assert_eq!(x, [0.0, 5.0, 23.0]);
        assert!(FIXED.contains(&x));
        assert!(!FIXED.clip(&mut x, &[]));
    }

    #[test]
    fn clip_scales_tilting_rotor_magnitudes() {
        let mut x = [30.0, 40.0, 3.0, 4.0];
        assert!(TILTING.clip(&mut x, &[]));
        assert!((TILTING.magnitude(&x, 0) - 23.0).abs() < 1e-12);
        assert_eq!(&x[2..], &[3.0, 4.0]);
    }

    #[test]
    fn max_step_stops_at_the_first_bound() {
        let x = [10.0, 20.0];
        let step = [-20.0, 6.0];
        assert_eq!(FIXED.max_step(&x, &step, 0), 0.5);
        assert_eq!(FIXED.max_step(&x, &step, 1), 0.5);
        assert_eq!(FIXED.max_step(&x, &[0.0, 0.0], 0), f64::INFINITY);
        // Disc of radius 23 from (3, 4) along +x: 3 + t·10 = √(23² − 16).
        let t = TILTING.max_step(&[3.0, 4.0], &[10.0, 0.0], 0);
        assert!((t - ((23.0f64 * 23.0 - 16.0).sqrt() - 3.0) / 10.0).abs() < 1e-12);
        let mut y = [3.0 + 10.0 * t, 4.0];
        TILTING.snap_to_bound(&mut y, &[10.0, 0.0], 0);
        assert!((TILTING.magnitude(&y, 0) - 23.0).abs() < 1e-12);
    }

    #[test]
    fn convex_set_of_a_tilting_rotor_ignores_the_minimum() {
        let bounds = ThrustBounds {
            min_n: 2.0,
            ..TILTING
        };
        let mut x = [0.3, 0.4];
        bounds.project_onto_convex_set(&mut x);
        assert_eq!(x, [0.3, 0.4]);
        assert!(!bounds.contains(&x), "but the final bounds do include it");
    }
}
