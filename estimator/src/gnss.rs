//! GNSS receiver model, and the geodetic position of amstack's world frame.
//!
//! **The world on the globe.** The world frame (x east, y north, z up) is a local tangent
//! plane at a home origin (latitude φ₀, longitude λ₀, altitude h₀ above mean sea level) on
//! the WGS-84 ellipsoid (a = 6 378 137 m, f = 1/298.257223563, e² = f(2 − f)). A world point
//! (x, y, z) is, to first order in its distance from home,
//!
//! ```text
//! M = a (1 − e²) / (1 − e² sin²φ₀)^{3/2}      (meridian radius of curvature)
//! N = a / (1 − e² sin²φ₀)^{1/2}               (prime-vertical radius of curvature)
//! φ = φ₀ + y / M,   λ = λ₀ + x / (N cos φ₀),   h = h₀ + z
//! ```
//!
//! The neglected terms are of order d²/R: under 0.1 m at 1 km from home, far beyond any task
//! scene. (PX4 projects with a sphere of radius 6 371 000 m; at 47° N its north scale differs
//! from M by 0.01 %, 1 mm per 10 m.)
//!
//! **The receiver** reports at `rate_hz` the position with white noise N(0, σ_h²) on each
//! horizontal axis and N(0, σ_v²) vertically, the velocity with N(0, σ_vel²) per axis, a 3D
//! fix, its accuracy (eph = σ_h, epv = σ_v) and a satellite count.

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::config::ConfigError;
use crate::schedule::Schedule;
use crate::sensors::check;

/// WGS-84 semi-major axis, m.
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// A point on the globe.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Geodetic {
    /// Latitude, degrees north.
    pub latitude_deg: f64,
    /// Longitude, degrees east.
    pub longitude_deg: f64,
    /// Altitude above mean sea level, m.
    pub altitude_amsl_m: f64,
}

/// Where the world frame's origin is on the globe. Default: PX4's default SITL home
/// (`PX4_HOME_LAT/LON/ALT`: 47.397742° N, 8.545594° E, 488 m, Zürich).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GeodeticOrigin {
    /// Latitude of the world origin, degrees north (−89..89).
    pub latitude_deg: f64,
    /// Longitude of the world origin, degrees east.
    pub longitude_deg: f64,
    /// Altitude of the world origin (the ground under the vehicle's start), m above mean sea
    /// level.
    pub altitude_amsl_m: f64,
}

impl Default for GeodeticOrigin {
    fn default() -> Self {
        Self {
            latitude_deg: 47.397742,
            longitude_deg: 8.545594,
            altitude_amsl_m: 488.0,
        }
    }
}

impl GeodeticOrigin {
    /// Checks the fields: finite, latitude within [−89, 89] (the tangent plane degenerates
    /// at the poles), longitude within [−180, 180].
    pub fn validate(&self) -> Result<(), ConfigError> {
        let within = |field: &'static str, value: f64, limit: f64, requirement: &'static str| {
            if value.is_finite() && value.abs() <= limit {
                Ok(())
            } else {
                Err(ConfigError {
                    section: "origin",
                    field,
                    value,
                    requirement,
                })
            }
        };
        within(
            "latitude_deg",
            self.latitude_deg,
            89.0,
            "must be within [-89, 89]",
        )?;
        within(
            "longitude_deg",
            self.longitude_deg,
            180.0,
            "must be within [-180, 180]",
        )?;
        within(
            "altitude_amsl_m",
            self.altitude_amsl_m,
            10_000.0,
            "must be within [-10000, 10000] (the ISA troposphere)",
        )
    }

    /// The radii of curvature (meridian M, prime vertical N) at the origin, m.
    pub fn radii_m(&self) -> (f64, f64) {
        let e2 = WGS84_F * (2.0 - WGS84_F);
        let s = self.latitude_deg.to_radians().sin();
        let w = 1.0 - e2 * s * s;
        (
            WGS84_A_M * (1.0 - e2) / (w * w.sqrt()),
            WGS84_A_M / w.sqrt(),
        )
    }

    /// The geodetic position of a world point (x east, y north, z up, m).
    pub fn geodetic(&self, position_in_world_m: &Vector3<f64>) -> Geodetic {
        let (m, n) = self.radii_m();
        let lat0 = self.latitude_deg.to_radians();
        Geodetic {
            latitude_deg: self.latitude_deg + (position_in_world_m.y / m).to_degrees(),
            longitude_deg: self.longitude_deg
                + (position_in_world_m.x / (n * lat0.cos())).to_degrees(),
            altitude_amsl_m: self.altitude_amsl_m + position_in_world_m.z,
        }
    }

    /// The world point of a geodetic position (the inverse of [`GeodeticOrigin::geodetic`]).
    pub fn world(&self, point: &Geodetic) -> Vector3<f64> {
        let (m, n) = self.radii_m();
        let lat0 = self.latitude_deg.to_radians();
        Vector3::new(
            (point.longitude_deg - self.longitude_deg).to_radians() * n * lat0.cos(),
            (point.latitude_deg - self.latitude_deg).to_radians() * m,
            point.altitude_amsl_m - self.altitude_amsl_m,
        )
    }
}

/// GNSS fix type, as MAVLink's GPS_FIX_TYPE numbers it.
pub const GNSS_FIX_3D: u8 = 3;

/// A GNSS receiver's model. Defaults: a single-frequency receiver (u-blox M8/M9 class) at
/// 10 Hz, 0.5 m horizontal and 0.8 m vertical noise, 0.05 m/s velocity noise, 12 satellites.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GnssModel {
    /// Fix rate, Hz. Default 10.
    pub rate_hz: f64,
    /// Standard deviation of each horizontal position component, m; reported as eph.
    /// Default 0.5.
    pub horizontal_std_m: f64,
    /// Standard deviation of the altitude, m; reported as epv. Default 0.8.
    pub vertical_std_m: f64,
    /// Standard deviation of each velocity component, m/s. Default 0.05.
    pub velocity_std_mps: f64,
    /// Satellites reported visible. Default 12.
    pub satellites: u8,
}

impl Default for GnssModel {
    fn default() -> Self {
        Self {
            rate_hz: 10.0,
            horizontal_std_m: 0.5,
            vertical_std_m: 0.8,
            velocity_std_mps: 0.05,
            satellites: 12,
        }
    }
}

impl GnssModel {
    /// Checks every field: the rate finite and positive, deviations finite and not negative.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check("gnss", &[("rate_hz", self.rate_hz)], true)?;
        check(
            "gnss",
            &[
                ("horizontal_std_m", self.horizontal_std_m),
                ("vertical_std_m", self.vertical_std_m),
                ("velocity_std_mps", self.velocity_std_mps),
            ],
            false,
        )
    }
}

/// One GNSS fix.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GnssFix {
    /// When it was taken, s.
    pub time_s: f64,
    /// Position on the globe.
    pub position: Geodetic,
    /// Velocity in the world frame (x east, y north, z up), m/s.
    pub velocity_in_world_mps: Vector3<f64>,
    /// Fix type (MAVLink GPS_FIX_TYPE: 3 = 3D fix).
    pub fix_type: u8,
    /// Horizontal accuracy (1σ), m.
    pub eph_m: f64,
    /// Vertical accuracy (1σ), m.
    pub epv_m: f64,
    /// Satellites visible.
    pub satellites: u8,
}

/// A simulated GNSS receiver: the model and its schedule.
#[derive(Debug, Clone, PartialEq)]
pub struct GnssSensor {
    model: GnssModel,
    schedule: Schedule,
}

fn normal(rng: &mut impl Rng, std: f64) -> f64 {
    rng.sample::<f64, _>(StandardNormal) * std
}

impl GnssSensor {
    /// A receiver with `model`; its first fix is at its first [`GnssSensor::step`].
    pub fn new(model: GnssModel) -> Result<Self, ConfigError> {
        model.validate()?;
        Ok(Self {
            model,
            schedule: Schedule::default(),
        })
    }

    /// The model.
    pub fn model(&self) -> &GnssModel {
        &self.model
    }

    /// One fix of the world position and velocity now (outside the schedule).
    pub fn measure(
        &self,
        time_s: f64,
        origin: &GeodeticOrigin,
        position_in_world_m: &Vector3<f64>,
        velocity_in_world_mps: &Vector3<f64>,
        rng: &mut impl Rng,
    ) -> GnssFix {
        let m = &self.model;
        let error = Vector3::new(
            normal(rng, m.horizontal_std_m),
            normal(rng, m.horizontal_std_m),
            normal(rng, m.vertical_std_m),
        );
        let velocity_error = Vector3::new(
            normal(rng, m.velocity_std_mps),
            normal(rng, m.velocity_std_mps),
            normal(rng, m.velocity_std_mps),
        );
        GnssFix {
            time_s,
            position: origin.geodetic(&(position_in_world_m + error)),
            velocity_in_world_mps: velocity_in_world_mps + velocity_error,
            fix_type: GNSS_FIX_3D,
            eph_m: m.horizontal_std_m,
            epv_m: m.vertical_std_m,
            satellites: m.satellites,
        }
    }

    /// A fix at `time_s` if one is due on the receiver's schedule.
    pub fn step(
        &mut self,
        time_s: f64,
        origin: &GeodeticOrigin,
        position_in_world_m: &Vector3<f64>,
        velocity_in_world_mps: &Vector3<f64>,
        rng: &mut impl Rng,
    ) -> Option<GnssFix> {
        if self.schedule.due(time_s, 1.0 / self.model.rate_hz) {
            Some(self.measure(
                time_s,
                origin,
                position_in_world_m,
                velocity_in_world_mps,
                rng,
            ))
        } else {
            None
        }
    }
}
