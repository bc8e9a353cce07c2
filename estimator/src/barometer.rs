//! Barometer model: the static pressure of the International Standard Atmosphere at the
//! vehicle's altitude, with white noise, a turn-on bias and a random-walk drift, and the
//! air temperature.
//!
//! ISA troposphere (h < 11 km above mean sea level, geopotential altitude taken equal to the
//! geometric one):
//!
//! ```text
//! T(h) = T₀ − L h                       T₀ = 288.15 K, L = 0.0065 K/m
//! p(h) = p₀ (T(h) / T₀)^(g₀ M / (R L))   p₀ = 101 325 Pa, g₀ M / (R L) = 5.255877
//! h(p) = (T₀ / L) (1 − (p / p₀)^(1 / 5.255877))     (pressure altitude, the inverse)
//! ```
//!
//! A sample reads p = p(h) + b + d + n: b drawn once (N(0, σ_b²)), d a random walk
//! (d ← d + σ_d √T ξ per sample period T), n ~ N(0, σ_n²) per sample.

use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::config::ConfigError;
use crate::schedule::Schedule;
use crate::sensors::check;

/// ISA sea-level temperature T₀, K.
pub const ISA_SEA_LEVEL_TEMPERATURE_K: f64 = 288.15;
/// ISA sea-level pressure p₀, Pa.
pub const ISA_SEA_LEVEL_PRESSURE_PA: f64 = 101_325.0;
/// ISA temperature lapse rate L in the troposphere, K/m.
pub const ISA_LAPSE_RATE_K_PER_M: f64 = 0.0065;
/// The ISA exponent g₀ M / (R L) (g₀ = 9.80665 m/s², M = 0.0289644 kg/mol,
/// R = 8.31432 J/(mol K)).
pub const ISA_EXPONENT: f64 = 5.255877;
/// 0 °C in kelvin.
const ZERO_CELSIUS_K: f64 = 273.15;

/// ISA temperature at altitude `altitude_m` above mean sea level, K.
pub fn isa_temperature_k(altitude_m: f64) -> f64 {
    ISA_SEA_LEVEL_TEMPERATURE_K - ISA_LAPSE_RATE_K_PER_M * altitude_m
}

/// ISA static pressure at altitude `altitude_m` above mean sea level with sea-level pressure
/// `sea_level_pa`, Pa.
pub fn isa_pressure_pa(altitude_m: f64, sea_level_pa: f64) -> f64 {
    sea_level_pa * (isa_temperature_k(altitude_m) / ISA_SEA_LEVEL_TEMPERATURE_K).powf(ISA_EXPONENT)
}

/// The ISA altitude of static pressure `pressure_pa` with sea-level pressure `sea_level_pa`
/// (pressure altitude), m.
pub fn isa_altitude_m(pressure_pa: f64, sea_level_pa: f64) -> f64 {
    ISA_SEA_LEVEL_TEMPERATURE_K / ISA_LAPSE_RATE_K_PER_M
        * (1.0 - (pressure_pa / sea_level_pa).powf(1.0 / ISA_EXPONENT))
}

/// A barometer's error model. Defaults: a MEMS barometer (BMP388-class) at 50 Hz, 1 Pa noise
/// (≈ 8 cm), no turn-on bias, a slow drift, in the standard atmosphere.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BarometerModel {
    /// Sample rate, Hz. Default 50.
    pub rate_hz: f64,
    /// Sea-level pressure of the day (QNH), Pa. Default 101 325 (ISA).
    pub sea_level_pressure_pa: f64,
    /// Standard deviation of the white noise per sample, Pa. Default 1.0.
    pub noise_std_pa: f64,
    /// Standard deviation of the constant (turn-on) bias, Pa. Default 0.
    pub bias_std_pa: f64,
    /// Random-walk drift of the pressure error, Pa/√s. Default 0.1.
    pub drift_pa_per_sqrt_s: f64,
    /// Standard deviation of the temperature noise per sample, K. Default 0.01.
    pub temperature_noise_std_k: f64,
}

impl Default for BarometerModel {
    fn default() -> Self {
        Self {
            rate_hz: 50.0,
            sea_level_pressure_pa: ISA_SEA_LEVEL_PRESSURE_PA,
            noise_std_pa: 1.0,
            bias_std_pa: 0.0,
            drift_pa_per_sqrt_s: 0.1,
            temperature_noise_std_k: 0.01,
        }
    }
}

impl BarometerModel {
    /// Checks every field: rate and sea-level pressure finite and positive, deviations finite
    /// and not negative.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            "barometer",
            &[
                ("rate_hz", self.rate_hz),
                ("sea_level_pressure_pa", self.sea_level_pressure_pa),
            ],
            true,
        )?;
        check(
            "barometer",
            &[
                ("noise_std_pa", self.noise_std_pa),
                ("bias_std_pa", self.bias_std_pa),
                ("drift_pa_per_sqrt_s", self.drift_pa_per_sqrt_s),
                ("temperature_noise_std_k", self.temperature_noise_std_k),
            ],
            false,
        )
    }
}

/// One barometer sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BarometerSample {
    /// When it was taken, s.
    pub time_s: f64,
    /// Static pressure, Pa.
    pub pressure_pa: f64,
    /// Air temperature, °C.
    pub temperature_c: f64,
    /// The ISA altitude of the measured pressure with the model's sea-level pressure, m
    /// above mean sea level.
    pub pressure_altitude_m: f64,
}

/// A simulated barometer: the model, its bias and drift, its schedule.
#[derive(Debug, Clone, PartialEq)]
pub struct BarometerSensor {
    model: BarometerModel,
    bias_pa: f64,
    drift_pa: f64,
    schedule: Schedule,
}

fn normal(rng: &mut impl Rng, std: f64) -> f64 {
    rng.sample::<f64, _>(StandardNormal) * std
}

impl BarometerSensor {
    /// A barometer whose turn-on bias is drawn from the model's deviation.
    pub fn new(model: BarometerModel, rng: &mut impl Rng) -> Result<Self, ConfigError> {
        model.validate()?;
        let bias_pa = normal(rng, model.bias_std_pa);
        Ok(Self {
            model,
            bias_pa,
            drift_pa: 0.0,
            schedule: Schedule::default(),
        })
    }

    /// The model.
    pub fn model(&self) -> &BarometerModel {
        &self.model
    }

    /// The current pressure error without the white noise (bias + drift), Pa.
    pub fn offset_pa(&self) -> f64 {
        self.bias_pa + self.drift_pa
    }

    /// What the barometer reads at `altitude_amsl_m` (m above mean sea level) as one sample:
    /// the drift walks one sample period, then bias, drift and noise are added.
    pub fn measure(
        &mut self,
        time_s: f64,
        altitude_amsl_m: f64,
        rng: &mut impl Rng,
    ) -> BarometerSample {
        let m = self.model;
        self.drift_pa += normal(rng, m.drift_pa_per_sqrt_s * (1.0 / m.rate_hz).sqrt());
        let pressure_pa = isa_pressure_pa(altitude_amsl_m, m.sea_level_pressure_pa)
            + self.bias_pa
            + self.drift_pa
            + normal(rng, m.noise_std_pa);
        let temperature_c = isa_temperature_k(altitude_amsl_m) - ZERO_CELSIUS_K
            + normal(rng, m.temperature_noise_std_k);
        BarometerSample {
            time_s,
            pressure_pa,
            temperature_c,
            pressure_altitude_m: isa_altitude_m(pressure_pa, m.sea_level_pressure_pa),
        }
    }

    /// A sample at `time_s` if one is due on the sensor's schedule.
    pub fn step(
        &mut self,
        time_s: f64,
        altitude_amsl_m: f64,
        rng: &mut impl Rng,
    ) -> Option<BarometerSample> {
        if self.schedule.due(time_s, 1.0 / self.model.rate_hz) {
            Some(self.measure(time_s, altitude_amsl_m, rng))
        } else {
            None
        }
    }
}
