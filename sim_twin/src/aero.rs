//! Aerodynamic disturbance models (AMBENCH_SPEC §3.2; the paper's "Disturbances, Actuator
//! Dynamics, and Saturation" appendix). Pure functions of distances and velocities; the twin
//! finds the distances with ray casts.
//!
//! - **Ground effect**, per rotor, d = distance to the nearest surface along −thrust axis:
//!   ratio = b − k (r_p / 4d)², d ≥ r_p/4, ratio ∈ [ε, 1];  T ← T / ratio.
//! - **Near-wall effect**, per rotor, d̄ = max(h − r_p, 0)/r_p with h the nearest horizontal
//!   hit in a ±45° fan around the rotor's radial direction and u its unit direction:
//!   T_v = (0, 0, T_z), T_h = T − T_v (world),
//!   T' = T_h + γ_h(d̄)·|T_v|·u + γ_v(d̄)·T_v,  γ_h = a1·b1^d̄,  γ_v = 1 + a2·b2^d̄.
//! - **Drag**: F = −c ∘ v_body.   **Wind**: a constant world-frame force.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Smallest ground-effect ratio (keeps the gain finite for any b and k).
pub const GROUND_EFFECT_MIN_RATIO: f64 = 1e-6;

/// Constants of the aerodynamic models; defaults are the reference's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AeroConfig {
    /// Longest ray cast, m; a miss reads as this distance. Default 5.0.
    pub max_raycast_distance_m: f64,
    /// Ground-effect b (ratio far from the ground). Default 1.0.
    pub ground_effect_b: f64,
    /// Ground-effect k (intensity). Default 0.171.
    pub ground_effect_k: f64,
    /// Near-wall a1 (horizontal suction at contact). Default 0.05.
    pub wall_a1: f64,
    /// Near-wall b1 (decay of the horizontal term per propeller radius). Default 0.34.
    pub wall_b1: f64,
    /// Near-wall a2 (vertical gain at contact). Default 0.02.
    pub wall_a2: f64,
    /// Near-wall b2 (decay of the vertical term). Default 0.25.
    pub wall_b2: f64,
    /// Linear drag per body axis, N·s/m. Default (0.1, 0.1, 0.1).
    pub drag_coefficients_nspm: [f64; 3],
    /// Constant wind force in the world frame, N. Default (0, 0, 0), the reference code's
    /// value (its documentation quotes a (6, 6, 6) N preset, AMBENCH_SPEC §9 item 2).
    pub wind_force_in_world_n: [f64; 3],
}

impl Default for AeroConfig {
    fn default() -> Self {
        Self {
            max_raycast_distance_m: 5.0,
            ground_effect_b: 1.0,
            ground_effect_k: 0.171,
            wall_a1: 0.05,
            wall_b1: 0.34,
            wall_a2: 0.02,
            wall_b2: 0.25,
            drag_coefficients_nspm: [0.1; 3],
            wind_force_in_world_n: [0.0; 3],
        }
    }
}

impl AeroConfig {
    /// Checks every constant (the reference refuses b ≤ 0, NaN, k < 0, infinite k).
    pub fn validate(&self) -> Result<(), String> {
        let finite = |name: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(format!("{name} = {v} must be finite"))
            }
        };
        finite("max_raycast_distance_m", self.max_raycast_distance_m)?;
        if self.max_raycast_distance_m <= 0.0 {
            return Err(format!(
                "max_raycast_distance_m = {} must be positive",
                self.max_raycast_distance_m
            ));
        }
        finite("ground_effect_b", self.ground_effect_b)?;
        if self.ground_effect_b <= 0.0 {
            return Err(format!(
                "ground_effect_b = {} must be positive",
                self.ground_effect_b
            ));
        }
        finite("ground_effect_k", self.ground_effect_k)?;
        if self.ground_effect_k < 0.0 {
            return Err(format!(
                "ground_effect_k = {} must not be negative",
                self.ground_effect_k
            ));
        }
        for (name, v) in [
            ("wall_a1", self.wall_a1),
            ("wall_b1", self.wall_b1),
            ("wall_a2", self.wall_a2),
            ("wall_b2", self.wall_b2),
        ] {
            finite(name, v)?;
            if v < 0.0 {
                return Err(format!("{name} = {v} must not be negative"));
            }
        }
        for v in self
            .drag_coefficients_nspm
            .iter()
            .chain(&self.wind_force_in_world_n)
        {
            finite("drag/wind", *v)?;
        }
        Ok(())
    }

    /// Ground-effect ratio at distance `distance_m` for a propeller of radius `radius_m`.
    pub fn ground_effect_ratio(&self, distance_m: f64, radius_m: f64) -> f64 {
        ground_effect_ratio(
            distance_m,
            radius_m,
            self.ground_effect_b,
            self.ground_effect_k,
        )
    }

    /// γ_h(d̄) = a1·b1^d̄.
    pub fn wall_gamma_h(&self, normalised_distance: f64) -> f64 {
        self.wall_a1 * self.wall_b1.powf(normalised_distance)
    }

    /// γ_v(d̄) = 1 + a2·b2^d̄.
    pub fn wall_gamma_v(&self, normalised_distance: f64) -> f64 {
        1.0 + self.wall_a2 * self.wall_b2.powf(normalised_distance)
    }
}

/// ratio = b − k (R / 4d)² with d ≥ R/4, clamped to [ε, 1]. A NaN distance reads as far away.
pub fn ground_effect_ratio(distance_m: f64, radius_m: f64, b: f64, k: f64) -> f64 {
    let d = if distance_m.is_nan() {
        f64::INFINITY
    } else {
        distance_m.max(radius_m / 4.0)
    };
    let x = radius_m / (4.0 * d);
    (b - k * x * x).clamp(GROUND_EFFECT_MIN_RATIO, 1.0)
}

/// Thrust vector (world) after the near-wall effect, from the thrust before it, the
/// normalised wall distance and the unit horizontal direction toward the wall (zero on a
/// miss).
pub fn near_wall_thrust(
    config: &AeroConfig,
    thrust_in_world: &Vector3<f64>,
    normalised_distance: f64,
    toward_wall: &Vector3<f64>,
) -> Vector3<f64> {
    let vertical = Vector3::new(0.0, 0.0, thrust_in_world.z);
    let horizontal = thrust_in_world - vertical;
    horizontal
        + toward_wall * (config.wall_gamma_h(normalised_distance) * vertical.norm())
        + vertical * config.wall_gamma_v(normalised_distance)
}

/// Linear drag in the body frame: −c ∘ v_body.
pub fn drag_force_in_body(config: &AeroConfig, velocity_in_body: &Vector3<f64>) -> Vector3<f64> {
    -Vector3::from(config.drag_coefficients_nspm).component_mul(velocity_in_body)
}

/// The horizontal ray directions of the near-wall fan: 10 rays from −45° to +45° in 10°
/// steps around `base_angle_rad` (the rotor's radial direction).
pub fn wall_fan_directions(base_angle_rad: f64) -> [Vector3<f64>; 10] {
    std::array::from_fn(|i| {
        let a = base_angle_rad + (-45.0 + 10.0 * i as f64).to_radians();
        Vector3::new(a.cos(), a.sin(), 0.0)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The spec's tables carry four or five significant digits.
    const TABLE: f64 = 5e-5;

    #[test]
    fn ground_effect_gain_matches_the_model_table() {
        let c = AeroConfig::default();
        let r = 0.152;
        let gain = |z: f64| 1.0 / c.ground_effect_ratio(z, r);
        assert!((gain(r / 4.0) - 1.2063).abs() < TABLE, "{}", gain(r / 4.0));
        assert!((gain(0.01) - 1.2063).abs() < TABLE, "clamped below R/4");
        assert!((gain(0.1) - 1.0253).abs() < TABLE, "{}", gain(0.1));
        assert!((gain(0.2) - 1.0062).abs() < TABLE, "{}", gain(0.2));
        assert!((gain(5.0) - 1.0).abs() < 1e-4);
        assert!((gain(f64::NAN) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn ground_effect_reference_test_case() {
        // AMBENCH_SPEC §8 test_aerodynamic.py: R 0.2, b 1.0, k 0.2, d = R/4 → ratio 0.8.
        assert!((ground_effect_ratio(0.05, 0.2, 1.0, 0.2) - 0.8).abs() < 1e-12);
        assert!((ground_effect_ratio(0.01, 0.2, 1.0, 0.2) - 0.8).abs() < 1e-12);
        assert!((8.0 / ground_effect_ratio(0.05, 0.2, 1.0, 0.2) - 10.0).abs() < 1e-12);
        let far = 16.0 / ground_effect_ratio(5.0, 0.2, 1.0, 0.2);
        assert!(far >= 16.0 && (far - 16.0).abs() < 4e-4);
    }

    #[test]
    fn invalid_ground_effect_constants_are_refused() {
        for (b, k) in [
            (0.0, 0.171),
            (f64::NAN, 0.171),
            (1.0, -0.1),
            (1.0, f64::INFINITY),
        ] {
            let c = AeroConfig {
                ground_effect_b: b,
                ground_effect_k: k,
                ..AeroConfig::default()
            };
            assert!(c.validate().is_err(), "b {b} k {k}");
        }
        assert_eq!(AeroConfig::default().validate(), Ok(()));
    }

    #[test]
    fn near_wall_gammas_match_the_model_table() {
        let c = AeroConfig::default();
        assert!((c.wall_gamma_h(0.0) - 0.05).abs() < 1e-12);
        assert!((c.wall_gamma_v(0.0) - 1.02).abs() < 1e-12);
        assert!((c.wall_gamma_h(1.0) - 0.0170).abs() < 1e-12);
        assert!((c.wall_gamma_v(1.0) - 1.005).abs() < 1e-12);
    }

    #[test]
    fn near_wall_thrust_pulls_toward_the_wall_and_lifts() {
        let c = AeroConfig::default();
        let t = Vector3::new(1.0, 0.0, 10.0);
        let toward = Vector3::new(0.0, 1.0, 0.0);
        let out = near_wall_thrust(&c, &t, 0.0, &toward);
        assert!(
            (out - Vector3::new(1.0, 0.05 * 10.0, 10.2)).norm() < 1e-12,
            "{out:?}"
        );
        // A miss (no direction, far away) leaves the thrust as it was, up to b2^d̄.
        let miss = near_wall_thrust(&c, &t, (5.0 - 0.152) / 0.152, &Vector3::zeros());
        assert!((miss - t).norm() < 1e-12, "{miss:?}");
    }

    #[test]
    fn drag_opposes_body_velocity() {
        let c = AeroConfig {
            drag_coefficients_nspm: [0.1, 0.2, 0.3],
            ..AeroConfig::default()
        };
        let f = drag_force_in_body(&c, &Vector3::new(1.0, -2.0, 3.0));
        assert!((f - Vector3::new(-0.1, 0.4, -0.9)).norm() < 1e-15);
    }

    #[test]
    fn wall_fan_spans_plus_minus_45_degrees() {
        let fan = wall_fan_directions(0.0);
        assert!((fan[0].y.atan2(fan[0].x).to_degrees() + 45.0).abs() < 1e-12);
        assert!((fan[9].y.atan2(fan[9].x).to_degrees() - 45.0).abs() < 1e-12);
        assert!(
            fan.iter()
                .all(|d| (d.norm() - 1.0).abs() < 1e-15 && d.z == 0.0)
        );
    }
}
