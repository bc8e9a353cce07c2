//! Reduced-order rotor actuator: thrust limits, a first-order lag and a symmetric rate limit,
//! acting on the normalised rotor speed q = ω/ω_max (T = T_max·q²). The flight stack and the
//! twin's motor model run this same code.
//!
//! Per rotor and tick (paper § "Rotor Saturation and Reduced-Order Actuator Dynamics"):
//!
//! ```text
//!     T_c = clip(T, T_min, T_max),     q_c = √(T_c / T_max)
//!     q̃   = q + (1 − e^{−Δt/τ}) (q_c − q)                     exact first-order lag
//!     q'  = clip(q̃, q − q̇_max Δt, q + q̇_max Δt)              symmetric rate limit
//!     q   ← clip(q', √(T_min/T_max), 1),   T = T_max q²
//! ```
//!
//! The lag (τ) and the rate limit (q̇_max) are each optional. With both disabled the actuator
//! is instantaneous and returns T = T_c, as the paper states. (The reference refuses to build
//! an actuator without at least one of them; that is a quirk of its configuration, not of the
//! model, and is not copied.) The first command after construction or a reset initialises
//! q = q_c, with zero acceleration.
//!
//! A non-finite thrust command is treated as T_min (the rotor idles, PX4's meaning of a NaN
//! motor setpoint) and flagged `saturated`; it never reaches the state.

use serde::{Deserialize, Serialize};

use crate::ActuatorError;

/// Configuration of a [`RotorActuator`]. Plain data; check with [`RotorActuatorConfig::validate`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RotorActuatorConfig {
    /// T_min, N (≥ 0). Default 0 (AM-Bench).
    pub thrust_min_n: f64,
    /// T_max, N (> T_min). Default 23 (AM-Bench).
    pub thrust_max_n: f64,
    /// Time constant τ of the first-order lag of q, s; `None` disables the lag. Default `None`
    /// (every shipped AM-Bench robot).
    pub time_constant_s: Option<f64>,
    /// Rate limit q̇_max of the normalised speed, 1/s; `None` disables it. Default `None`.
    pub speed_rate_limit_per_s: Option<f64>,
}

impl Default for RotorActuatorConfig {
    fn default() -> Self {
        Self {
            thrust_min_n: 0.0,
            thrust_max_n: 23.0,
            time_constant_s: None,
            speed_rate_limit_per_s: None,
        }
    }
}

impl RotorActuatorConfig {
    /// Instantaneous actuator with the thrust limits of `layout`.
    pub fn from_layout(layout: &platform::RotorLayout) -> Self {
        Self {
            thrust_min_n: layout.thrust_min_n,
            thrust_max_n: layout.thrust_max_n,
            ..Self::default()
        }
    }

    /// Checks every field: τ and q̇_max finite and positive when set, T_max finite > T_min ≥ 0.
    ///
    /// # Errors
    /// [`ActuatorError::InvalidConfig`] naming the field.
    pub fn validate(&self) -> Result<(), ActuatorError> {
        let (t_min, t_max) = (self.thrust_min_n, self.thrust_max_n);
        if !(t_min.is_finite() && t_max.is_finite()) {
            return Err(ActuatorError::InvalidConfig(format!(
                "thrust limits must be finite, got ({t_min}, {t_max}) N"
            )));
        }
        if !(t_min >= 0.0 && t_max > t_min) {
            return Err(ActuatorError::InvalidConfig(format!(
                "thrust limits need 0 ≤ min < max, got ({t_min}, {t_max}) N"
            )));
        }
        let finite_positive = |name: &str, value: Option<f64>| match value {
            Some(v) if !(v.is_finite() && v > 0.0) => Err(ActuatorError::InvalidConfig(format!(
                "{name} must be finite and positive when set, got {v}"
            ))),
            _ => Ok(()),
        };
        finite_positive("time_constant_s", self.time_constant_s)?;
        finite_positive("speed_rate_limit_per_s", self.speed_rate_limit_per_s)
    }
}

/// What one rotor did in one [`RotorActuator::step`].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RotorTelemetry {
    /// T_c: the command clamped into `[T_min, T_max]`, N.
    pub commanded_thrust_n: f64,
    /// q_c = √(T_c/T_max).
    pub speed_command: f64,
    /// q after the step.
    pub speed: f64,
    /// (q − q_prev)/Δt, 1/s (0 on the first command).
    pub speed_rate_per_s: f64,
    /// The rate limit cut the lagged speed this step.
    pub rate_limited: bool,
    /// The command was outside `[T_min, T_max]` (or not finite) and was clamped.
    pub saturated: bool,
    /// Realised thrust T = T_max q², N.
    pub thrust_n: f64,
}

/// The actuator model of all rotors of one vehicle.
#[derive(Debug, Clone)]
pub struct RotorActuator {
    config: RotorActuatorConfig,
    /// Lowest speed √(T_min/T_max).
    speed_min: f64,
    /// q per rotor.
    speed: Vec<f64>,
    /// False until the first command after construction or reset.
    initialised: Vec<bool>,
    telemetry: Vec<RotorTelemetry>,
}

impl RotorActuator {
    /// An actuator for `rotor_count` rotors, all at rest and uninitialised.
    ///
    /// # Errors
    /// [`ActuatorError::InvalidConfig`] if `config` does not validate.
    pub fn new(config: RotorActuatorConfig, rotor_count: usize) -> Result<Self, ActuatorError> {
        config.validate()?;
        Ok(Self {
            config,
            speed_min: (config.thrust_min_n / config.thrust_max_n).sqrt(),
            speed: vec![0.0; rotor_count],
            initialised: vec![false; rotor_count],
            telemetry: vec![RotorTelemetry::default(); rotor_count],
        })
    }

    /// The configuration.
    pub fn config(&self) -> &RotorActuatorConfig {
        &self.config
    }

    /// Number of rotors.
    pub fn rotor_count(&self) -> usize {
        self.speed.len()
    }

    /// Advances every rotor by `dt` seconds towards `thrust_commands_n` (N, one per rotor) and
    /// returns the per-rotor telemetry (realised thrust in [`RotorTelemetry::thrust_n`]).
    ///
    /// # Errors
    /// [`ActuatorError::InvalidTimeStep`] if `dt` is not finite and positive;
    /// [`ActuatorError::CommandLength`] if the command does not have one entry per rotor.
    /// The state is untouched on error.
    pub fn step(
        &mut self,
        thrust_commands_n: &[f64],
        dt: f64,
    ) -> Result<&[RotorTelemetry], ActuatorError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(ActuatorError::InvalidTimeStep(dt));
        }
        if thrust_commands_n.len() != self.speed.len() {
            return Err(ActuatorError::CommandLength {
                expected: self.speed.len(),
                got: thrust_commands_n.len(),
            });
        }
        let RotorActuatorConfig {
            thrust_min_n: t_min,
            thrust_max_n: t_max,
            time_constant_s,
            speed_rate_limit_per_s,
        } = self.config;
        let lag_gain = time_constant_s.map(|tau| 1.0 - (-dt / tau).exp());
        let max_speed_step = speed_rate_limit_per_s.map(|rate| rate * dt);
        let instantaneous = lag_gain.is_none() && max_speed_step.is_none();

        for (rotor, &raw) in thrust_commands_n.iter().enumerate() {
            let commanded = if raw.is_finite() {
                raw.clamp(t_min, t_max)
            } else {
                t_min
            };
            // Outside the limits, or NaN (which fails both comparisons).
            let saturated = !(raw >= t_min && raw <= t_max);
            let speed_command = (commanded / t_max).sqrt();
            let previous = if self.initialised[rotor] {
                self.speed[rotor]
            } else {
                speed_command
            };
            let lagged = match lag_gain {
                Some(gain) => previous + gain * (speed_command - previous),
                None => speed_command,
            };
            let (limited, rate_limited) = match max_speed_step {
                Some(step) => {
                    let (low, high) = (previous - step, previous + step);
                    (lagged.clamp(low, high), lagged < low || lagged > high)
                }
                None => (lagged, false),
            };
            let speed = limited.clamp(self.speed_min, 1.0);
            self.speed[rotor] = speed;
            self.initialised[rotor] = true;
            self.telemetry[rotor] = RotorTelemetry {
                commanded_thrust_n: commanded,
                speed_command,
                speed,
                speed_rate_per_s: (speed - previous) / dt,
                rate_limited,
                saturated,
                // Without dynamics the realised thrust is the clamped command itself (the
                // speed round trip would only add round-off).
                thrust_n: if instantaneous {
                    commanded
                } else {
                    t_max * speed * speed
                },
            };
        }
        Ok(&self.telemetry)
    }

    /// Telemetry of the last step (zeros before the first, and for a rotor just reset).
    pub fn telemetry(&self) -> &[RotorTelemetry] {
        &self.telemetry
    }

    /// Resets every rotor: speed 0, telemetry zeroed; the next command initialises q = q_c.
    pub fn reset(&mut self) {
        self.speed.fill(0.0);
        self.initialised.fill(false);
        self.telemetry.fill(RotorTelemetry::default());
    }

    /// Resets one rotor, as [`RotorActuator::reset`].
    ///
    /// # Errors
    /// [`ActuatorError::RotorIndex`] if `rotor` is outside `0..rotor_count`.
    pub fn reset_rotor(&mut self, rotor: usize) -> Result<(), ActuatorError> {
        let count = self.speed.len();
        if rotor >= count {
            return Err(ActuatorError::RotorIndex {
                index: rotor,
                count,
            });
        }
        self.speed[rotor] = 0.0;
        self.initialised[rotor] = false;
        self.telemetry[rotor] = RotorTelemetry::default();
        Ok(())
    }
}

#[cfg(test)]
#[expect(
    clippy::unwrap_used,
    clippy::float_cmp,
    reason = "a test fails loudly; exact values are the contract: clamps, zeros, replays"
)]
mod tests {
    //! The cases of the reference's `robots/test_rotor_actuator.py` (AMBENCH_SPEC §8), with its
    //! numbers: thrust limits (0, 100), τ 0.1, dt 0.01 unless a case says otherwise.
    use super::*;
    use crate::fixtures::{assert_all_close, assert_close};

    /// Round-off of a few exp/sqrt operations.
    const TOLERANCE: f64 = 1e-12;
    const DT: f64 = 0.01;

    fn config(tau: Option<f64>, rate: Option<f64>) -> RotorActuatorConfig {
        RotorActuatorConfig {
            thrust_min_n: 0.0,
            thrust_max_n: 100.0,
            time_constant_s: tau,
            speed_rate_limit_per_s: rate,
        }
    }

    fn actuator(tau: Option<f64>, rate: Option<f64>, rotors: usize) -> RotorActuator {
        RotorActuator::new(config(tau, rate), rotors).unwrap()
    }

    #[test]
    fn zero_command_gives_zeros_and_no_flags() {
        // Spec: 2 envs × 3 rotors → one actuator of 6 rotors.
        let mut a = actuator(Some(0.1), None, 6);
        let out = a.step(&[0.0; 6], DT).unwrap();
        for t in out {
            assert_eq!(*t, RotorTelemetry::default());
        }
    }

    #[test]
    fn first_command_initialises_speed() {
        let mut a = actuator(Some(0.1), None, 1);
        let t = a.step(&[36.0], DT).unwrap()[0];
        assert_close(t.speed_command, 0.6, TOLERANCE, "q_c");
        assert_close(t.speed, 0.6, TOLERANCE, "q");
        assert_eq!(t.speed_rate_per_s, 0.0);
        assert_close(t.thrust_n, 36.0, TOLERANCE, "thrust");
    }

    #[test]
    fn first_order_lag_is_integrated_exactly() {
        let mut a = actuator(Some(0.2), None, 1);
        a.step(&[0.0], 0.05).unwrap();
        let t = a.step(&[100.0], 0.05).unwrap()[0];
        let q = 1.0 - (-0.25f64).exp();
        assert_close(t.speed, q, TOLERANCE, "q");
        assert_close(q, 0.221199, 1e-6, "spec digits");
        assert_close(t.speed_rate_per_s, q / 0.05, TOLERANCE, "accel");
        assert_close(t.thrust_n, 100.0 * q * q, TOLERANCE, "thrust");
        assert!(!t.rate_limited);
    }

    #[test]
    fn rate_limit_alone_caps_the_speed_step() {
        let mut a = actuator(None, Some(2.5), 1);
        a.step(&[0.0], DT).unwrap();
        let t = a.step(&[100.0], DT).unwrap()[0];
        assert_close(t.speed, 0.025, TOLERANCE, "q");
        assert_close(t.speed_rate_per_s, 2.5, TOLERANCE, "accel");
        assert_close(t.thrust_n, 0.0625, TOLERANCE, "thrust");
        assert!(t.rate_limited);
    }

    #[test]
    fn rate_limit_applies_after_the_lag() {
        let mut a = actuator(Some(0.1), Some(0.5), 1);
        a.step(&[0.0], 0.1).unwrap();
        let t = a.step(&[100.0], 0.1).unwrap()[0];
        assert_close(t.speed, 0.05, TOLERANCE, "q");
        assert_close(t.speed_rate_per_s, 0.5, TOLERANCE, "accel");
        assert!(t.rate_limited);
    }

    #[test]
    fn rate_limit_is_symmetric_when_braking() {
        let mut a = actuator(Some(0.1), Some(2.5), 1);
        a.step(&[100.0], 0.1).unwrap();
        let t = a.step(&[0.0], 0.1).unwrap()[0];
        assert_close(t.speed, 0.75, TOLERANCE, "q");
        assert_close(t.speed_rate_per_s, -2.5, TOLERANCE, "accel");
        assert_close(t.thrust_n, 56.25, TOLERANCE, "thrust");
        assert!(t.rate_limited);
    }

    #[test]
    fn commands_outside_limits_are_clamped_and_flagged() {
        let mut a = actuator(Some(0.1), None, 2);
        let out = a.step(&[-1.0, 400.0], DT).unwrap();
        assert_all_close(
            out.iter().map(|t| &t.commanded_thrust_n),
            [0.0, 100.0].iter(),
            TOLERANCE,
            "commanded",
        );
        assert_all_close(
            out.iter().map(|t| &t.speed_command),
            [0.0, 1.0].iter(),
            TOLERANCE,
            "q_c",
        );
        assert_all_close(
            out.iter().map(|t| &t.thrust_n),
            [0.0, 100.0].iter(),
            TOLERANCE,
            "T",
        );
        assert!(out.iter().all(|t| t.saturated));
    }

    #[test]
    fn minimum_thrust_sets_the_speed_floor() {
        let mut a = RotorActuator::new(
            RotorActuatorConfig {
                thrust_min_n: 25.0,
                ..config(Some(0.1), Some(1.0))
            },
            1,
        )
        .unwrap();
        let t = a.step(&[0.0], DT).unwrap()[0];
        assert_close(t.commanded_thrust_n, 25.0, TOLERANCE, "commanded");
        assert_close(t.speed, 0.5, TOLERANCE, "q");
        assert_close(t.thrust_n, 25.0, TOLERANCE, "thrust");
        assert!(t.saturated);
    }

    #[test]
    fn reset_reinitialises_only_the_reset_rotor() {
        // Spec: 2 envs, a_max 1.0, dt 0.1: steps (0, 100), (100, 0), reset env 0, step (25, 0).
        // Done with one actuator per env, and again with one actuator and a per-rotor reset.
        let mut envs = [
            actuator(Some(0.1), Some(1.0), 1),
            actuator(Some(0.1), Some(1.0), 1),
        ];
        for (env, commands) in envs.iter_mut().zip([[0.0, 100.0], [100.0, 0.0]]) {
            for c in commands {
                env.step(&[c], 0.1).unwrap();
            }
        }
        envs[0].reset();
        assert_eq!(envs[0].telemetry()[0], RotorTelemetry::default());
        let t0 = envs[0].step(&[25.0], 0.1).unwrap()[0];
        let t1 = envs[1].step(&[0.0], 0.1).unwrap()[0];
        assert_close(t0.speed, 0.5, TOLERANCE, "env 0 q");
        assert_eq!(t0.speed_rate_per_s, 0.0);
        assert_close(t1.speed, 0.8, TOLERANCE, "env 1 q");
        assert_close(t1.speed_rate_per_s, -1.0, TOLERANCE, "env 1 accel");

        let mut both = actuator(Some(0.1), Some(1.0), 2);
        both.step(&[0.0, 100.0], 0.1).unwrap();
        both.step(&[100.0, 0.0], 0.1).unwrap();
        both.reset_rotor(0).unwrap();
        assert_eq!(both.telemetry()[0].speed, 0.0);
        assert!(both.telemetry()[1].speed > 0.0);
        let out = both.step(&[25.0, 0.0], 0.1).unwrap();
        assert_eq!((out[0], out[1]), (t0, t1));
    }

    #[test]
    fn invalid_config_and_steps_are_rejected_with_the_reference_words() {
        let message = |e: ActuatorError| e.to_string();
        let tau_zero = RotorActuator::new(config(Some(0.0), None), 1).unwrap_err();
        assert!(message(tau_zero).contains("positive"));
        let rate_nan = RotorActuator::new(config(None, Some(f64::NAN)), 1).unwrap_err();
        assert!(message(rate_nan).contains("finite"));
        let rate_inf = RotorActuator::new(config(None, Some(f64::INFINITY)), 1).unwrap_err();
        assert!(message(rate_inf).contains("finite"));
        let rate_negative = RotorActuator::new(config(None, Some(-1.0)), 1).unwrap_err();
        assert!(message(rate_negative).contains("positive"));
        let tau_nan = RotorActuator::new(config(Some(f64::NAN), None), 1).unwrap_err();
        assert!(message(tau_nan).contains("finite"));
        let max_nan = RotorActuatorConfig {
            thrust_max_n: f64::NAN,
            ..config(None, None)
        };
        assert!(message(max_nan.validate().unwrap_err()).contains("finite"));

        let mut a = actuator(Some(0.1), None, 2);
        let dt_nan = a.step(&[1.0, 1.0], f64::NAN).unwrap_err();
        assert!(message(dt_nan).contains("finite and positive"));
        let dt_zero = a.step(&[1.0, 1.0], 0.0).unwrap_err();
        assert!(message(dt_zero).contains("finite and positive"));
        let shape = a.step(&[1.0], DT).unwrap_err();
        assert_eq!(
            shape,
            ActuatorError::CommandLength {
                expected: 2,
                got: 1
            }
        );
        assert!(message(shape).contains("shape"));
        let outside = a.reset_rotor(2).unwrap_err();
        assert!(message(outside).contains("outside"));
        assert_eq!(
            a.telemetry(),
            &[RotorTelemetry::default(); 2],
            "errors leave the state"
        );
    }

    #[test]
    fn without_dynamics_the_thrust_is_the_clamped_command() {
        // The paper: disabling both gives T_dyn = T_c. The reference would refuse this config.
        let mut a = actuator(None, None, 3);
        for commands in [[5.0, 36.0, 99.9], [0.1, 150.0, -4.0]] {
            let out = a.step(&commands, DT).unwrap();
            for (t, c) in out.iter().zip(commands) {
                assert_eq!(t.thrust_n, c.clamp(0.0, 100.0));
                assert!(!t.rate_limited);
            }
        }
    }

    #[test]
    fn non_finite_command_idles_without_poisoning_the_state() {
        let mut a = actuator(Some(0.1), Some(2.5), 2);
        a.step(&[50.0, 50.0], DT).unwrap();
        let out = a.step(&[f64::NAN, f64::INFINITY], DT).unwrap();
        for t in out {
            assert!(t.saturated);
            assert_eq!(t.commanded_thrust_n, 0.0);
            assert!(t.speed.is_finite() && t.thrust_n.is_finite());
        }
        let out = a.step(&[50.0, 50.0], DT).unwrap();
        assert!(out.iter().all(|t| t.speed.is_finite() && !t.saturated));
    }

    #[test]
    fn steady_command_converges_to_the_commanded_thrust() {
        let mut a = actuator(Some(0.05), Some(5.0), 1);
        a.step(&[0.0], DT).unwrap();
        for _ in 0..500 {
            a.step(&[64.0], DT).unwrap();
        }
        assert_close(a.telemetry()[0].thrust_n, 64.0, 1e-9, "steady thrust");
    }

    #[test]
    fn identical_runs_are_bit_identical() {
        let run = || {
            let mut a = actuator(Some(0.07), Some(3.0), 2);
            let mut bits = Vec::new();
            for k in 0..50 {
                let c = [f64::from(k) * 2.1, 100.0 - f64::from(k)];
                for t in a.step(&c, 1.0 / 120.0).unwrap() {
                    bits.push(t.thrust_n.to_bits());
                }
            }
            bits
        };
        assert_eq!(run(), run());
    }
}
