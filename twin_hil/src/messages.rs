//! What the twin sends PX4: HIL_SENSOR, HIL_GPS and HIL_STATE_QUATERNION, built from the
//! simulated sensors' readings and the twin's truth. Pure functions; units and frames as the
//! MAVLink `common` definitions and PX4's `simulator_mavlink` read them:
//!
//! | message | field | unit, frame |
//! |---|---|---|
//! | HIL_SENSOR | xacc, yacc, zacc | m/s², body FRD (specific force: (0, 0, −9.81) level at rest) |
//! | | xgyro, ygyro, zgyro | rad/s, body FRD |
//! | | xmag, ymag, zmag | gauss, body FRD |
//! | | abs_pressure | hPa |
//! | | diff_pressure | hPa: 0, its bit never set (a multicopter has no pitot tube) |
//! | | pressure_alt | m, ISA altitude of abs_pressure |
//! | | temperature | °C (PX4 takes it with the barometer) |
//! | | fields_updated | accel and gyro bits (0x3F) always; mag bits (0x1C0) when the magnetometer sampled; abs_pressure, pressure_alt, temperature (0x1A00) when the barometer sampled |
//! | | id | 0 (the IMU PX4 takes its clock from) |
//! | HIL_GPS | lat, lon | degE7 (WGS-84) |
//! | | alt | mm above mean sea level |
//! | | eph, epv | cm: the 1σ accuracy (MAVLink calls eph "HDOP × 100"; PX4's simulator reads it as cm of accuracy) |
//! | | vel | cm/s, horizontal ground speed |
//! | | vn, ve, vd | cm/s, NED |
//! | | cog | cdeg in [0, 36000), 65535 below 0.05 m/s |
//! | HIL_STATE_QUATERNION | attitude_quaternion | w x y z, `ned_from_frd` |
//! | | rollspeed, pitchspeed, yawspeed | rad/s, body FRD |
//! | | lat, lon, alt | degE7, mm (ground truth) |
//! | | vx, vy, vz | cm/s, NED |
//! | | ind_airspeed, true_airspeed | cm/s (still air: the ground speed) |
//! | | xacc, yacc, zacc | mG (1 G = 9.80665 m/s²), body FRD specific force |

use estimator::{BarometerSample, GeodeticOrigin, GnssFix, ImuSample, MagnetometerSample};
use firmware_bridge::frames;
use mavlink::dialects::common::{
    HIL_GPS_DATA, HIL_SENSOR_DATA, HIL_STATE_QUATERNION_DATA, HilSensorUpdatedFlags,
};
use nalgebra::Vector3;
use platform::Measurement;

/// Standard gravity of the milli-G unit, m/s².
pub const STANDARD_GRAVITY_MPS2: f64 = 9.80665;
/// HIL_GPS `cog` when the course is unknown (too slow to tell).
pub const COG_UNKNOWN: u16 = u16::MAX;
/// Below this horizontal speed the course is unknown, m/s.
pub const COG_MIN_SPEED_MPS: f64 = 0.05;

/// fields_updated bits of the accelerometer and gyroscope (0x3F).
pub fn imu_bits() -> HilSensorUpdatedFlags {
    HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XACC
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YACC
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZACC
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XGYRO
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YGYRO
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZGYRO
}

/// fields_updated bits of the magnetometer (0x1C0).
pub fn mag_bits() -> HilSensorUpdatedFlags {
    HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XMAG
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YMAG
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZMAG
}

/// fields_updated bits of the barometer: abs_pressure, pressure_alt, temperature (0x1A00,
/// PX4's `SensorSource::BARO`).
pub fn baro_bits() -> HilSensorUpdatedFlags {
    HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ABS_PRESSURE
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_PRESSURE_ALT
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_TEMPERATURE
}

/// An f64 onto MAVLink's f32 (the protocol's narrowing).
#[allow(clippy::cast_possible_truncation)]
fn f32_of(x: f64) -> f32 {
    x as f32
}

/// Rounds and saturates onto an integer field (a NaN gives 0; never reached: inputs are
/// checked finite).
#[allow(clippy::cast_possible_truncation)]
fn i32_of(x: f64) -> i32 {
    x.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
}
#[allow(clippy::cast_possible_truncation)]
fn i16_of(x: f64) -> i16 {
    x.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}
#[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
fn u16_of(x: f64) -> u16 {
    x.round().clamp(0.0, f64::from(u16::MAX)) as u16
}

/// The last magnetometer and barometer readings, repeated in the HIL_SENSOR fields whose
/// bits are not set (PX4 ignores them; a reader sees the latest value, never a zero).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HeldReadings {
    /// Last magnetometer sample.
    pub magnetometer: Option<MagnetometerSample>,
    /// Last barometer sample.
    pub barometer: Option<BarometerSample>,
}

/// HIL_SENSOR at `time_usec` from an IMU sample and the magnetometer and barometer samples
/// taken now (None: not sampled this tick; the held values fill the fields, bits unset).
pub fn hil_sensor(
    time_usec: u64,
    imu: &ImuSample,
    magnetometer: Option<&MagnetometerSample>,
    barometer: Option<&BarometerSample>,
    held: &mut HeldReadings,
) -> HIL_SENSOR_DATA {
    let mut bits = imu_bits();
    if let Some(m) = magnetometer {
        held.magnetometer = Some(*m);
        bits |= mag_bits();
    }
    if let Some(b) = barometer {
        held.barometer = Some(*b);
        bits |= baro_bits();
    }
    let accel = frames::frd_from_flu(&imu.specific_force_in_body_mps2);
    let gyro = frames::frd_from_flu(&imu.angular_velocity_in_body_radps);
    let mag = held.magnetometer.map_or_else(Vector3::zeros, |m| {
        frames::frd_from_flu(&m.field_in_body_gauss)
    });
    let (pressure_hpa, pressure_alt_m, temperature_c) =
        held.barometer.map_or((0.0, 0.0, 0.0), |b| {
            (
                b.pressure_pa / 100.0,
                b.pressure_altitude_m,
                b.temperature_c,
            )
        });
    HIL_SENSOR_DATA {
        time_usec,
        xacc: f32_of(accel.x),
        yacc: f32_of(accel.y),
        zacc: f32_of(accel.z),
        xgyro: f32_of(gyro.x),
        ygyro: f32_of(gyro.y),
        zgyro: f32_of(gyro.z),
        xmag: f32_of(mag.x),
        ymag: f32_of(mag.y),
        zmag: f32_of(mag.z),
        abs_pressure: f32_of(pressure_hpa),
        diff_pressure: 0.0,
        pressure_alt: f32_of(pressure_alt_m),
        temperature: f32_of(temperature_c),
        fields_updated: bits,
        id: 0,
    }
}

/// Course over ground of a NED velocity, cdeg in [0, 36000), or [`COG_UNKNOWN`] when slower
/// than [`COG_MIN_SPEED_MPS`].
pub fn course_over_ground_cdeg(velocity_ned_mps: &Vector3<f64>) -> u16 {
    let speed = velocity_ned_mps.xy().norm();
    if speed < COG_MIN_SPEED_MPS {
        return COG_UNKNOWN;
    }
    let deg = velocity_ned_mps.y.atan2(velocity_ned_mps.x).to_degrees();
    let cdeg = (deg.rem_euclid(360.0) * 100.0).round();
    // 35999.6 rounds up to 36000, which is north again.
    u16_of(if cdeg >= 36000.0 { 0.0 } else { cdeg })
}

/// HIL_GPS at `time_usec` of a GNSS fix.
pub fn hil_gps(time_usec: u64, fix: &GnssFix) -> HIL_GPS_DATA {
    let v = frames::ned_from_world(&fix.velocity_in_world_mps);
    HIL_GPS_DATA {
        time_usec,
        lat: i32_of(fix.position.latitude_deg * 1e7),
        lon: i32_of(fix.position.longitude_deg * 1e7),
        alt: i32_of(fix.position.altitude_amsl_m * 1e3),
        eph: u16_of(fix.eph_m * 100.0),
        epv: u16_of(fix.epv_m * 100.0),
        vel: u16_of(v.xy().norm() * 100.0),
        vn: i16_of(v.x * 100.0),
        ve: i16_of(v.y * 100.0),
        vd: i16_of(v.z * 100.0),
        cog: course_over_ground_cdeg(&v),
        fix_type: fix.fix_type,
        satellites_visible: fix.satellites,
        id: 0,
        // 0: no yaw from this receiver.
        yaw: 0,
    }
}

/// HIL_STATE_QUATERNION at `time_usec`: the ground truth of `truth`, with the ideal specific
/// force `specific_force_in_body_mps2` (FLU) of the period.
pub fn hil_state_quaternion(
    time_usec: u64,
    truth: &Measurement,
    specific_force_in_body_mps2: &Vector3<f64>,
    origin: &GeodeticOrigin,
) -> HIL_STATE_QUATERNION_DATA {
    let base = &truth.base;
    let q = frames::quaternion_to_mavlink(&frames::ned_from_frd_attitude(&base.world_from_body));
    let rates = frames::frd_from_flu(&base.angular_velocity_in_body_radps);
    let at = origin.geodetic(&base.position_in_world_m);
    let v = frames::ned_from_world(&base.velocity_in_world_mps);
    let accel_mg = frames::frd_from_flu(specific_force_in_body_mps2) / STANDARD_GRAVITY_MPS2 * 1e3;
    let airspeed = u16_of(v.norm() * 100.0);
    HIL_STATE_QUATERNION_DATA {
        time_usec,
        attitude_quaternion: q,
        rollspeed: f32_of(rates.x),
        pitchspeed: f32_of(rates.y),
        yawspeed: f32_of(rates.z),
        lat: i32_of(at.latitude_deg * 1e7),
        lon: i32_of(at.longitude_deg * 1e7),
        alt: i32_of(at.altitude_amsl_m * 1e3),
        vx: i16_of(v.x * 100.0),
        vy: i16_of(v.y * 100.0),
        vz: i16_of(v.z * 100.0),
        ind_airspeed: airspeed,
        true_airspeed: airspeed,
        xacc: i16_of(accel_mg.x),
        yacc: i16_of(accel_mg.y),
        zacc: i16_of(accel_mg.z),
    }
}
