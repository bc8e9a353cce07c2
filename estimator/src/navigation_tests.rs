//! The navigation sensor models against hand-derived values.

#![allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]

use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::barometer::{isa_altitude_m, isa_pressure_pa, isa_temperature_k};
use crate::{
    BarometerModel, BarometerSensor, Geodetic, GeodeticOrigin, GnssModel, GnssSensor,
    MagnetometerModel, MagnetometerSensor,
};

/// ISA sea level: 101 325 Pa, 288.15 K. At 1000 m: T = 288.15 − 6.5 = 281.65 K and
/// p = 101 325 · (281.65 / 288.15)^5.255877 = 101 325 · 0.977442^5.255877 = 89 874.57 Pa
/// (ICAO tables: 898.7 hPa).
#[test]
fn isa_pressure_at_sea_level_and_at_one_kilometre() {
    assert_eq!(isa_pressure_pa(0.0, 101_325.0), 101_325.0);
    assert_eq!(isa_temperature_k(0.0), 288.15);
    assert!((isa_temperature_k(1000.0) - 281.65).abs() < 1e-9);
    let p = isa_pressure_pa(1000.0, 101_325.0);
    assert!((p - 89_874.57).abs() < 0.05, "p(1000 m) = {p}");
    // The pressure altitude inverts it.
    assert!((isa_altitude_m(p, 101_325.0) - 1000.0).abs() < 1e-6);
    // Near the ground one metre is ≈ ρ g = 1.225 · 9.80665 ≈ 12.01 Pa.
    let per_metre = isa_pressure_pa(0.0, 101_325.0) - isa_pressure_pa(1.0, 101_325.0);
    assert!((per_metre - 12.01).abs() < 0.01, "{per_metre} Pa/m");
}

#[test]
fn ideal_barometer_reads_the_isa_pressure_and_temperature() {
    let model = BarometerModel {
        noise_std_pa: 0.0,
        drift_pa_per_sqrt_s: 0.0,
        temperature_noise_std_k: 0.0,
        ..BarometerModel::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut baro = BarometerSensor::new(model, &mut rng).unwrap();
    let s = baro.measure(0.5, 1000.0, &mut rng);
    assert!((s.pressure_pa - 89_874.57).abs() < 0.05);
    assert!((s.temperature_c - 8.5).abs() < 1e-9);
    assert!((s.pressure_altitude_m - 1000.0).abs() < 1e-6);
    assert_eq!(s.time_s, 0.5);
}

#[test]
fn barometer_noise_has_the_model_deviation_and_drift_walks() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let model = BarometerModel {
        drift_pa_per_sqrt_s: 0.0,
        ..BarometerModel::default()
    };
    let mut baro = BarometerSensor::new(model, &mut rng).unwrap();
    let p0 = isa_pressure_pa(488.0, 101_325.0);
    let n = 4000;
    let errors: Vec<f64> = (0..n)
        .map(|k| {
            baro.measure(f64::from(k) * 0.02, 488.0, &mut rng)
                .pressure_pa
                - p0
        })
        .collect();
    let mean = errors.iter().sum::<f64>() / f64::from(n);
    let std = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / f64::from(n)).sqrt();
    assert!(mean.abs() < 0.06, "mean {mean}");
    assert!((std - 1.0).abs() < 0.05, "std {std}");
    // With drift: after 100 s of 50 Hz samples the walk's deviation is 0.1·√100 = 1 Pa;
    // over 200 seeds the spread of the offset is within 20 % of it.
    let offsets: Vec<f64> = (0..200)
        .map(|seed| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut b = BarometerSensor::new(BarometerModel::default(), &mut rng).unwrap();
            for k in 0..5000 {
                b.measure(f64::from(k) * 0.02, 0.0, &mut rng);
            }
            b.offset_pa()
        })
        .collect();
    let rms = (offsets.iter().map(|o| o * o).sum::<f64>() / 200.0).sqrt();
    assert!((rms - 1.0).abs() < 0.2, "drift rms {rms}");
}

/// At the equator M = a(1 − e²) = 6 378 137 · (1 − 0.00669438) = 6 335 439.33 m and
/// N = a: 100 m north is 100 / 6 335 439.33 rad = 9.043695e-4°, 100 m east is
/// 100 / 6 378 137 rad = 8.983153e-4°. At PX4's home (47.397742° N), M = 6 370 064.34 m:
/// 100 m north is 8.994537e-4°.
#[test]
fn geodetic_position_of_a_hundred_metres_north_and_east() {
    let equator = GeodeticOrigin {
        latitude_deg: 0.0,
        longitude_deg: 0.0,
        altitude_amsl_m: 0.0,
    };
    let north = equator.geodetic(&Vector3::new(0.0, 100.0, 0.0));
    assert!((north.latitude_deg - 9.043695e-4).abs() < 1e-10);
    assert_eq!(north.longitude_deg, 0.0);
    let east = equator.geodetic(&Vector3::new(100.0, 0.0, 5.0));
    assert!((east.longitude_deg - 8.983153e-4).abs() < 1e-10);
    assert_eq!(east.latitude_deg, 0.0);
    assert_eq!(east.altitude_amsl_m, 5.0);

    let home = GeodeticOrigin::default();
    let (m, _) = home.radii_m();
    assert!((m - 6_370_064.34).abs() < 0.01, "M = {m}");
    let north = home.geodetic(&Vector3::new(0.0, 100.0, 2.0));
    assert!((north.latitude_deg - (47.397742 + 8.994537e-4)).abs() < 1e-10);
    assert!((north.longitude_deg - 8.545594).abs() < 1e-12);
    assert_eq!(north.altitude_amsl_m, 490.0);
    // And back.
    let p = Vector3::new(-3.25, 12.5, 1.75);
    assert!((home.world(&home.geodetic(&p)) - p).norm() < 1e-9);
    assert!(home.validate().is_ok());
    let bad = GeodeticOrigin {
        latitude_deg: 91.0,
        ..home
    };
    assert_eq!(bad.validate().unwrap_err().field, "latitude_deg");
}

#[test]
fn ideal_gnss_fixes_at_its_rate_with_the_geodetic_position() {
    let model = GnssModel {
        horizontal_std_m: 0.0,
        vertical_std_m: 0.0,
        velocity_std_mps: 0.0,
        ..GnssModel::default()
    };
    let origin = GeodeticOrigin::default();
    let mut gnss = GnssSensor::new(model).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let p = Vector3::new(1.0, 100.0, 1.0);
    let v = Vector3::new(0.5, -0.25, 0.125);
    // 120 calls over one second at 120 Hz: 10 fixes, at 0, 0.1, ... 0.9 s.
    let fixes: Vec<_> = (0..120)
        .filter_map(|k| gnss.step(f64::from(k) / 120.0, &origin, &p, &v, &mut rng))
        .collect();
    assert_eq!(fixes.len(), 10);
    assert!((fixes[3].time_s - 0.3).abs() < 1e-9);
    let f = fixes[0];
    assert_eq!(f.position, origin.geodetic(&p));
    assert!((f.position.latitude_deg - (47.397742 + 8.994537e-4)).abs() < 1e-10);
    assert_eq!(f.velocity_in_world_mps, v);
    assert_eq!((f.fix_type, f.satellites), (3, 12));
    let _: Geodetic = f.position;
}

/// F = 0.5 G, I = 60°, D = 0: B_ned = (0.25, 0, 0.4330), world (ENU) = (0, 0.25, −0.4330).
/// A vehicle facing north (amstack yaw 90°) reads, in FLU, (0.25, 0, −0.4330).
#[test]
fn magnetometer_reads_the_field_in_the_body_frame() {
    let model = MagnetometerModel {
        intensity_gauss: 0.5,
        inclination_deg: 60.0,
        declination_deg: 0.0,
        noise_std_gauss: 0.0,
        bias_std_gauss: 0.0,
        ..MagnetometerModel::default()
    };
    let b = model.field_in_world_gauss();
    assert!((b - Vector3::new(0.0, 0.25, -0.5 * 3f64.sqrt() / 2.0)).norm() < 1e-12);
    assert!((b.norm() - 0.5).abs() < 1e-12);
    let inclination = (-b.z).atan2(b.xy().norm()).to_degrees();
    assert!((inclination - 60.0).abs() < 1e-9);

    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mag = MagnetometerSensor::new(model, &mut rng).unwrap();
    let facing_north = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    let s = mag.measure(0.0, &facing_north, &mut rng);
    assert!((s.field_in_body_gauss - Vector3::new(0.25, 0.0, -0.4330127)).norm() < 1e-6);

    // The default field (Zürich): 0.485 G, dip 63.5°, 3.3° east of north.
    let d = MagnetometerModel::default().field_in_world_gauss();
    assert!((d.norm() - 0.485).abs() < 1e-12);
    assert!((d.x.atan2(d.y).to_degrees() - 3.3).abs() < 1e-9);
    let bad = MagnetometerModel {
        inclination_deg: 95.0,
        ..MagnetometerModel::default()
    };
    assert_eq!(bad.validate().unwrap_err().field, "inclination_deg");
}

#[test]
fn magnetometer_bias_and_noise_follow_the_model_and_the_seed() {
    let model = MagnetometerModel::default();
    let draw = |seed| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut mag = MagnetometerSensor::new(model, &mut rng).unwrap();
        let q = UnitQuaternion::identity();
        (0..100)
            .filter_map(|k| mag.step(f64::from(k) / 120.0, &q, &mut rng))
            .map(|s| s.field_in_body_gauss)
            .collect::<Vec<_>>()
    };
    let a = draw(5);
    // 100 calls at 120 Hz span 0.825 s: samples at 0, 0.01 ... every call that reaches the
    // next 10 ms slot (ticks are 8.3 ms apart): 83 samples.
    assert_eq!(a.len(), 83);
    let b = draw(5);
    assert!(a.iter().zip(&b).all(|(x, y)| {
        x.iter()
            .zip(y.iter())
            .all(|(p, q)| p.to_bits() == q.to_bits())
    }));
    assert_ne!(a, draw(6));
}
