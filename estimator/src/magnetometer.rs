//! Magnetometer model: the Earth's field, fixed in the world frame, read in the body frame
//! with a constant (hard-iron) bias and white noise.
//!
//! The field is given as a geomagnetic model gives it at the home position: total intensity
//! F, inclination I (dip, positive when the field points down, as in the northern
//! hemisphere) and declination D (east of true north). In NED and in amstack's world frame
//! (ENU-like: x east, y north, z up):
//!
//! ```text
//! B_ned   = F (cos I cos D, cos I sin D, sin I)
//! B_world = (B_e, B_n, −B_d) = F (cos I sin D, cos I cos D, −sin I)
//! ```
//!
//! A sample reads m = R_world_from_bodyᵀ B_world + b + n, b drawn once at turn-on
//! (N(0, σ_b²I)), n ~ N(0, σ_n²I) per sample; gauss (1 G = 100 µT), body frame FLU.

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::config::ConfigError;
use crate::schedule::Schedule;
use crate::sensors::{check, normal3};

/// A magnetometer's error model and the field it sits in. Defaults: the field at PX4's
/// default SITL home (Zürich, 47.397742° N, 8.545594° E; WMM 2025: 0.485 G, inclination
/// 63.5°, declination 3.3° E), a MEMS magnetometer at 100 Hz.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MagnetometerModel {
    /// Sample rate, Hz. Default 100.
    pub rate_hz: f64,
    /// Total intensity F of the Earth's field, gauss. Default 0.485.
    pub intensity_gauss: f64,
    /// Inclination I, degrees, positive down (−90..90). Default 63.5.
    pub inclination_deg: f64,
    /// Declination D, degrees east of true north. Default 3.3.
    pub declination_deg: f64,
    /// Standard deviation of the white noise of each axis per sample, gauss. Default 0.002.
    pub noise_std_gauss: f64,
    /// Standard deviation of each axis of the constant (hard-iron) bias, gauss. Default
    /// 0.005.
    pub bias_std_gauss: f64,
}

impl Default for MagnetometerModel {
    fn default() -> Self {
        Self {
            rate_hz: 100.0,
            intensity_gauss: 0.485,
            inclination_deg: 63.5,
            declination_deg: 3.3,
            noise_std_gauss: 0.002,
            bias_std_gauss: 0.005,
        }
    }
}

impl MagnetometerModel {
    /// Checks every field: rate and intensity finite and positive, inclination within
    /// [−90, 90], declination finite, deviations finite and not negative.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            "magnetometer",
            &[
                ("rate_hz", self.rate_hz),
                ("intensity_gauss", self.intensity_gauss),
            ],
            true,
        )?;
        check(
            "magnetometer",
            &[
                ("noise_std_gauss", self.noise_std_gauss),
                ("bias_std_gauss", self.bias_std_gauss),
                ("inclination_deg", self.inclination_deg.abs()),
                ("declination_deg", self.declination_deg.abs()),
            ],
            false,
        )?;
        if self.inclination_deg.abs() > 90.0 {
            return Err(ConfigError {
                section: "magnetometer",
                field: "inclination_deg",
                value: self.inclination_deg,
                requirement: "must be within [-90, 90]",
            });
        }
        Ok(())
    }

    /// The Earth's field in the world frame (x east, y north, z up), gauss.
    pub fn field_in_world_gauss(&self) -> Vector3<f64> {
        let (i, d) = (
            self.inclination_deg.to_radians(),
            self.declination_deg.to_radians(),
        );
        let f = self.intensity_gauss;
        Vector3::new(f * i.cos() * d.sin(), f * i.cos() * d.cos(), -f * i.sin())
    }
}

/// One magnetometer sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MagnetometerSample {
    /// When it was taken, s.
    pub time_s: f64,
    /// The field read, body frame (FLU), gauss.
    pub field_in_body_gauss: Vector3<f64>,
}

/// A simulated magnetometer: the model, its bias and its schedule.
#[derive(Debug, Clone, PartialEq)]
pub struct MagnetometerSensor {
    model: MagnetometerModel,
    bias_gauss: Vector3<f64>,
    schedule: Schedule,
}

impl MagnetometerSensor {
    /// A magnetometer whose bias is drawn from the model's deviation.
    pub fn new(model: MagnetometerModel, rng: &mut impl Rng) -> Result<Self, ConfigError> {
        model.validate()?;
        let bias_gauss = normal3(rng, model.bias_std_gauss);
        Ok(Self {
            model,
            bias_gauss,
            schedule: Schedule::default(),
        })
    }

    /// The model.
    pub fn model(&self) -> &MagnetometerModel {
        &self.model
    }

    /// The bias, body frame, gauss.
    pub fn bias_gauss(&self) -> Vector3<f64> {
        self.bias_gauss
    }

    /// What the magnetometer reads now, at attitude `world_from_body` (outside the schedule).
    pub fn measure(
        &self,
        time_s: f64,
        world_from_body: &UnitQuaternion<f64>,
        rng: &mut impl Rng,
    ) -> MagnetometerSample {
        let field = world_from_body.inverse() * self.model.field_in_world_gauss();
        MagnetometerSample {
            time_s,
            field_in_body_gauss: field + self.bias_gauss + normal3(rng, self.model.noise_std_gauss),
        }
    }

    /// A sample at `time_s` if one is due on the sensor's schedule.
    pub fn step(
        &mut self,
        time_s: f64,
        world_from_body: &UnitQuaternion<f64>,
        rng: &mut impl Rng,
    ) -> Option<MagnetometerSample> {
        self.schedule
            .due(time_s, 1.0 / self.model.rate_hz)
            .then(|| self.measure(time_s, world_from_body, rng))
    }
}
