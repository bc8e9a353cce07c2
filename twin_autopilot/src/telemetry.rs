//! The twin's state as the MAVLink messages of a PX4 autopilot, in NED/FRD through
//! `firmware_bridge::frames`.
//!
//! Timestamps (`time_usec`, `time_boot_ms`) are the twin's simulated time. Positions are in the
//! local NED frame whose origin is the twin's world origin, which is [`HOME`] on the globe.

use estimator::ImuSample;
use firmware_bridge::frames;
use firmware_bridge::task_array::TaskArray;
use mavlink::dialects::common::{
    ACTUATOR_OUTPUT_STATUS_DATA, ALTITUDE_DATA, ATTITUDE_DATA, ATTITUDE_QUATERNION_DATA,
    AUTOPILOT_VERSION_DATA, DEBUG_FLOAT_ARRAY_DATA, EXTENDED_SYS_STATE_DATA,
    GLOBAL_POSITION_INT_DATA, GPS_RAW_INT_DATA, GpsFixType, HEARTBEAT_DATA, HIGHRES_IMU_DATA,
    HOME_POSITION_DATA, HighresImuUpdatedFlags, LOCAL_POSITION_NED_DATA, MISSION_CURRENT_DATA,
    MavAutopilot, MavEstimatorType, MavFrame, MavLandedState, MavMessage, MavModeFlag,
    MavProtocolCapability, MavState, MavSysStatusSensor, MavSysStatusSensorExtended, MavType,
    MavVtolState, MissionState, ODOMETRY_DATA, SYS_STATUS_DATA,
};
use nalgebra::Vector3;
use platform::{GRAVITY_MPS2, Measurement, RigidBodyState};

use crate::modes::{Commander, Failsafe};
use crate::wire::LinkCounters;
use sim_twin::{TaskId, TaskSnapshot};

/// Where the twin's world origin is on the globe: PX4 SITL's default home (Zürich). The
/// ground under the origin is at `alt_m`; world z is the height above it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Home {
    /// Latitude, degrees.
    pub lat_deg: f64,
    /// Longitude, degrees.
    pub lon_deg: f64,
    /// Altitude above mean sea level, m.
    pub alt_m: f64,
}

/// The home of every twin: 47.397742° N, 8.545594° E, 488.0 m AMSL.
pub const HOME: Home = Home {
    lat_deg: 47.397_742,
    lon_deg: 8.545_594,
    alt_m: 488.0,
};

/// Earth radius for the local-to-global map, m (spherical, as PX4's map projection).
const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// DEBUG_FLOAT_ARRAY's array_id for the joints.
pub const JOINTS_ARRAY_ID: u16 = 1;

/// The task scene's state after a step as the contract's SITL extension, DEBUG_FLOAT_ARRAY
/// "task" (`firmware_bridge::task_array`), stamped with the step's time. `None` when it does
/// not fit the array (no scene of ours comes near: at most 9 observation values of 33).
pub fn task_array(m: &Measurement, snapshot: &TaskSnapshot) -> Option<MavMessage> {
    let number = TaskId::ALL
        .iter()
        .position(|t| *t == snapshot.task)
        .map_or(0, |i| i + 1);
    TaskArray {
        time_usec: time_us(m),
        task_number: u32::try_from(number).unwrap_or(0),
        steps: snapshot.steps,
        success: snapshot.status.success,
        holding: snapshot.holding,
        criteria: snapshot.status.criteria.clone(),
        obstacle_face_x_m: snapshot.obstacle_face_x,
        wall: snapshot.wall,
        values: snapshot
            .observation
            .entries
            .iter()
            .flat_map(|(_, v)| v.iter().copied())
            .collect(),
        held_joint: snapshot.held_joint,
        hand_contact: snapshot.hand_contact,
    }
    .encode()
    .ok()
}

/// The landed state for EXTENDED_SYS_STATE.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Landed {
    /// On the ground (or disarmed).
    OnGround,
    /// Flying.
    InAir,
    /// Landing (AUTO.LAND, RTL's or a mission's landing).
    Landing,
    /// Taking off (AUTO.TAKEOFF, a mission's takeoff).
    Takeoff,
}

fn f(x: f64) -> f32 {
    // MAVLink carries f32; the narrowing is the protocol's.
    #[allow(clippy::cast_possible_truncation)]
    let y = x as f32;
    y
}

fn time_us(m: &Measurement) -> u64 {
    (m.time_s.max(0.0) * 1e6).round() as u64
}

fn time_ms(m: &Measurement) -> u32 {
    u32::try_from((m.time_s.max(0.0) * 1e3).round() as u64).unwrap_or(u32::MAX)
}

/// The messages sent at every twin step, in the contract's order (ODOMETRY last: it closes
/// the tick). `imu` is the step's IMU sample ([`imu`]): HIGHRES_IMU's accelerometer and gyro.
pub fn per_step(m: &Measurement, imu: &ImuSample) -> [MavMessage; 6] {
    let t_us = time_us(m);
    let t_ms = time_ms(m);
    let base = &m.base;
    let q = frames::quaternion_to_mavlink(&frames::ned_from_frd_attitude(&base.world_from_body));
    let p = frames::ned_from_world(&base.position_in_world_m);
    let v = frames::ned_from_world(&base.velocity_in_world_mps);
    let w = frames::frd_from_flu(&base.angular_velocity_in_body_radps);
    let acc = frames::frd_from_flu(&imu.specific_force_in_body_mps2);
    let gyro = frames::frd_from_flu(&imu.angular_velocity_in_body_radps);

    let mut data = [0.0f32; 58];
    for (d, x) in data
        .iter_mut()
        .zip(m.joint_positions.iter().chain(&m.joint_velocities))
    {
        *d = f(*x);
    }
    let mut actuator = [0.0f32; 32];
    for (a, r) in actuator.iter_mut().zip(&m.rotors) {
        *a = f(r.realised_n);
    }
    let mut unknown = [0.0f32; 21];
    unknown[0] = f32::NAN;
    [
        MavMessage::DEBUG_FLOAT_ARRAY(DEBUG_FLOAT_ARRAY_DATA {
            time_usec: t_us,
            array_id: JOINTS_ARRAY_ID,
            name: "joints".into(),
            data,
        }),
        MavMessage::ACTUATOR_OUTPUT_STATUS(ACTUATOR_OUTPUT_STATUS_DATA {
            time_usec: t_us,
            active: u32::try_from(m.rotors.len().min(32)).unwrap_or(32),
            actuator,
        }),
        MavMessage::HIGHRES_IMU(HIGHRES_IMU_DATA {
            time_usec: t_us,
            xacc: f(acc.x),
            yacc: f(acc.y),
            zacc: f(acc.z),
            xgyro: f(gyro.x),
            ygyro: f(gyro.y),
            zgyro: f(gyro.z),
            fields_updated: HighresImuUpdatedFlags::HIGHRES_IMU_UPDATED_XACC
                | HighresImuUpdatedFlags::HIGHRES_IMU_UPDATED_YACC
                | HighresImuUpdatedFlags::HIGHRES_IMU_UPDATED_ZACC
                | HighresImuUpdatedFlags::HIGHRES_IMU_UPDATED_XGYRO
                | HighresImuUpdatedFlags::HIGHRES_IMU_UPDATED_YGYRO
                | HighresImuUpdatedFlags::HIGHRES_IMU_UPDATED_ZGYRO,
            ..Default::default()
        }),
        MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
            time_boot_ms: t_ms,
            q1: q[0],
            q2: q[1],
            q3: q[2],
            q4: q[3],
            rollspeed: f(w.x),
            pitchspeed: f(w.y),
            yawspeed: f(w.z),
            repr_offset_q: [0.0; 4],
        }),
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: t_ms,
            x: f(p.x),
            y: f(p.y),
            z: f(p.z),
            vx: f(v.x),
            vy: f(v.y),
            vz: f(v.z),
        }),
        MavMessage::ODOMETRY(ODOMETRY_DATA {
            time_usec: t_us,
            x: f(p.x),
            y: f(p.y),
            z: f(p.z),
            q,
            vx: f(v.x),
            vy: f(v.y),
            vz: f(v.z),
            rollspeed: f(w.x),
            pitchspeed: f(w.y),
            yawspeed: f(w.z),
            pose_covariance: unknown,
            velocity_covariance: unknown,
            frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
            child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
            reset_counter: 0,
            estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_AUTOPILOT,
            quality: 100,
        }),
    ]
}

/// The IMU the autopilot reports over the step from `previous` to `m` (`dt_s` apart): the
/// twin's one IMU model ([`sim_twin::sensors::ideal_imu`]: mean acceleration as specific force
/// at mid-period, mean body rate), the same the iceoryx2 server and the estimator's simulated
/// sensors read.
pub fn imu(previous: &RigidBodyState, m: &Measurement, dt_s: f64) -> ImuSample {
    if m.time_s > 0.0 && dt_s > 0.0 {
        sim_twin::sensors::ideal_imu(previous, &m.base, m.time_s, dt_s)
    } else {
        // Before the first step: at rest, the specific force of gravity at the current attitude.
        ImuSample {
            time_s: m.time_s,
            specific_force_in_body_mps2: m.base.world_from_body.inverse()
                * Vector3::new(0.0, 0.0, GRAVITY_MPS2),
            angular_velocity_in_body_radps: m.base.angular_velocity_in_body_radps,
        }
    }
}

/// HEARTBEAT of the autopilot.
pub fn heartbeat(mav_type: MavType, commander: &Commander) -> MavMessage {
    let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
    if commander.armed() {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    let system_status = if commander.failsafe() != Failsafe::None {
        MavState::MAV_STATE_CRITICAL
    } else if commander.armed() {
        MavState::MAV_STATE_ACTIVE
    } else {
        MavState::MAV_STATE_STANDBY
    };
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: commander.mode().custom_mode(),
        mavtype: mav_type,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode,
        system_status,
        mavlink_version: 3,
    })
}

/// SYS_STATUS: the sensors and control functions the twin's autopilot has (present, enabled,
/// healthy: it flies on the twin's truth, so they are healthy while it runs; the
/// pre-arm check is healthy when arming would be accepted now, as PX4 reports it), and the
/// comm error counters of the link (errors_comm: bad frames; drop_rate_comm: their share in
/// c%; errors_count1–4: bad CRC, unknown id, truncated, refused by signing).
pub fn sys_status(counters: &LinkCounters, armable: bool) -> MavMessage {
    let sat = |x: u64| u16::try_from(x).unwrap_or(u16::MAX);
    type S = MavSysStatusSensor;
    let sensors = S::MAV_SYS_STATUS_SENSOR_3D_GYRO
        | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL
        | S::MAV_SYS_STATUS_SENSOR_3D_MAG
        | S::MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        | S::MAV_SYS_STATUS_SENSOR_GPS
        | S::MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
        | S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
        | S::MAV_SYS_STATUS_SENSOR_YAW_POSITION
        | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
        | S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
        | S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        | S::MAV_SYS_STATUS_AHRS
        | S::MAV_SYS_STATUS_PREARM_CHECK;
    let health = if armable {
        sensors
    } else {
        sensors & !S::MAV_SYS_STATUS_PREARM_CHECK
    };
    MavMessage::SYS_STATUS(SYS_STATUS_DATA {
        onboard_control_sensors_present: sensors,
        onboard_control_sensors_enabled: sensors,
        onboard_control_sensors_health: health,
        load: 0,
        voltage_battery: u16::MAX,
        current_battery: -1,
        drop_rate_comm: counters.drop_rate_centi_percent(),
        errors_comm: sat(counters.bad_frames()),
        errors_count1: sat(counters.bad_crc),
        errors_count2: sat(counters.unknown_id),
        errors_count3: sat(counters.truncated),
        errors_count4: sat(counters.refused_unsigned + counters.refused_bad_signature),
        battery_remaining: -1,
        onboard_control_sensors_present_extended: MavSysStatusSensorExtended::empty(),
        onboard_control_sensors_enabled_extended: MavSysStatusSensorExtended::empty(),
        onboard_control_sensors_health_extended: MavSysStatusSensorExtended::empty(),
    })
}

/// EXTENDED_SYS_STATE.
pub fn extended_sys_state(landed: Landed) -> MavMessage {
    MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
        vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
        landed_state: match landed {
            Landed::OnGround => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            Landed::InAir => MavLandedState::MAV_LANDED_STATE_IN_AIR,
            Landed::Landing => MavLandedState::MAV_LANDED_STATE_LANDING,
            Landed::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
        },
    })
}

/// ATTITUDE (NED←FRD Euler angles, FRD rates).
pub fn attitude(m: &Measurement) -> MavMessage {
    let q = frames::ned_from_frd_attitude(&m.base.world_from_body);
    let (roll, pitch, yaw) = q.euler_angles();
    let w = frames::frd_from_flu(&m.base.angular_velocity_in_body_radps);
    MavMessage::ATTITUDE(ATTITUDE_DATA {
        time_boot_ms: time_ms(m),
        roll: f(roll),
        pitch: f(pitch),
        yaw: f(yaw),
        rollspeed: f(w.x),
        pitchspeed: f(w.y),
        yawspeed: f(w.z),
    })
}

/// World (x east, y north) in metres of a (lat, lon) in degrees: the inverse of
/// [`lat_lon_deg`].
pub fn world_xy_of(home: &Home, lat_deg: f64, lon_deg: f64) -> (f64, f64) {
    let north = (lat_deg - home.lat_deg).to_radians() * EARTH_RADIUS_M;
    let east =
        (lon_deg - home.lon_deg).to_radians() * EARTH_RADIUS_M * home.lat_deg.to_radians().cos();
    (east, north)
}

/// (lat, lon) in degrees of a local NED position.
pub fn lat_lon_deg(home: &Home, north_m: f64, east_m: f64) -> (f64, f64) {
    let lat = home.lat_deg + (north_m / EARTH_RADIUS_M).to_degrees();
    let lon =
        home.lon_deg + (east_m / (EARTH_RADIUS_M * home.lat_deg.to_radians().cos())).to_degrees();
    (lat, lon)
}

fn e7(deg: f64) -> i32 {
    // ±180° · 1e7 fits an i32.
    #[allow(clippy::cast_possible_truncation)]
    let x = (deg * 1e7).round() as i32;
    x
}

fn mm(m: f64) -> i32 {
    #[allow(clippy::cast_possible_truncation)]
    let x = (m * 1e3)
        .round()
        .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
    x
}

fn cm_s(v: f64) -> i16 {
    #[allow(clippy::cast_possible_truncation)]
    let x = (v * 100.0)
        .round()
        .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
    x
}

/// GLOBAL_POSITION_INT from the local position and [`HOME`].
pub fn global_position_int(m: &Measurement) -> MavMessage {
    let p = frames::ned_from_world(&m.base.position_in_world_m);
    let v = frames::ned_from_world(&m.base.velocity_in_world_mps);
    let (lat, lon) = lat_lon_deg(&HOME, p.x, p.y);
    let q = frames::ned_from_frd_attitude(&m.base.world_from_body);
    let (_, _, yaw) = q.euler_angles();
    let hdg = (yaw.to_degrees().rem_euclid(360.0) * 100.0).round() as u16 % 36_000;
    MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
        time_boot_ms: time_ms(m),
        lat: e7(lat),
        lon: e7(lon),
        alt: mm(HOME.alt_m - p.z),
        relative_alt: mm(-p.z),
        vx: cm_s(v.x),
        vy: cm_s(v.y),
        vz: cm_s(v.z),
        hdg,
    })
}

/// HOME_POSITION: `home_m` (world; the ground under the point where the vehicle armed).
pub fn home_position(m: &Measurement, home_m: &Vector3<f64>) -> MavMessage {
    let ned = frames::ned_from_world(home_m);
    let (lat, lon) = lat_lon_deg(&HOME, ned.x, ned.y);
    MavMessage::HOME_POSITION(HOME_POSITION_DATA {
        latitude: e7(lat),
        longitude: e7(lon),
        altitude: mm(HOME.alt_m + home_m.z),
        x: f(ned.x),
        y: f(ned.y),
        z: f(ned.z),
        q: [1.0, 0.0, 0.0, 0.0],
        approach_x: 0.0,
        approach_y: 0.0,
        approach_z: 0.0,
        time_usec: time_us(m),
    })
}

/// The protocols the twin's autopilot implements, exactly: MAVLink 2 (and MAVLink 1 peers),
/// COMMAND_INT, the parameter protocol with PX4's bytewise encoding, the mission protocol
/// with MISSION_INT (MISSION_ITEM is accepted on upload too, but downloads answer with
/// MISSION_ITEM_INT: MISSION_FLOAT is not claimed), SET_ATTITUDE_TARGET and
/// SET_POSITION_TARGET_LOCAL_NED; and SET_ACTUATOR_CONTROL_TARGET (motors, tilt servos) only
/// when `actuator_setpoints` (`--allow-actuator-setpoints`, the SITL extension: current PX4
/// no longer sets this bit). Not: SET_POSITION_TARGET_GLOBAL_INT, FTP, fences, rally points,
/// terrain, flight termination.
pub fn capabilities(actuator_setpoints: bool) -> MavProtocolCapability {
    let actuator = if actuator_setpoints {
        firmware_bridge::telemetry::CAPABILITY_SET_ACTUATOR_TARGET
    } else {
        MavProtocolCapability::empty()
    };
    actuator
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MISSION_INT
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
}

/// AUTOPILOT_VERSION: amstack's version as the flight software version
/// (major << 24 | minor << 16 | patch << 8 | 0xFF for a release, as PX4), the
/// [`capabilities`] (with the actuator extension when `actuator_setpoints`), and
/// `flight_custom_version` `firmware_bridge::telemetry::TWIN_FLIGHT_CUSTOM_VERSION` (how the
/// bridge knows it talks to the twin).
pub fn autopilot_version(actuator_setpoints: bool) -> MavMessage {
    let part = |s: &str| s.parse::<u32>().unwrap_or(0) & 0xFF;
    let mut parts = env!("CARGO_PKG_VERSION").split('.');
    let (major, minor, patch) = (
        parts.next().map_or(0, part),
        parts.next().map_or(0, part),
        parts.next().map_or(0, part),
    );
    MavMessage::AUTOPILOT_VERSION(AUTOPILOT_VERSION_DATA {
        capabilities: capabilities(actuator_setpoints),
        uid: 0x616D_7374_6163_6B00, // "amstack\0"
        flight_sw_version: (major << 24) | (minor << 16) | (patch << 8) | 0xFF,
        flight_custom_version: firmware_bridge::telemetry::TWIN_FLIGHT_CUSTOM_VERSION,
        ..Default::default()
    })
}

/// GPS_RAW_INT of a fix of the twin's simulated GNSS receiver (`sim_twin::sensors`: WGS-84
/// tangent plane about the world origin, noise, rate, eph/epv), stamped with the twin's time
/// `m`.
pub fn gps_raw_int(m: &Measurement, fix: &estimator::GnssFix) -> MavMessage {
    let v = frames::ned_from_world(&fix.velocity_in_world_mps);
    let ground = v.x.hypot(v.y);
    let cog = if ground > 0.1 {
        (v.y.atan2(v.x).to_degrees().rem_euclid(360.0) * 100.0).round()
    } else {
        f64::from(u16::MAX)
    };
    let mm_u32 = |x: f64| (x * 1e3).round().clamp(0.0, f64::from(u32::MAX)) as u32;
    // DOP-like eph/epv (unitless · 100) from the accuracies, a 1 m-accurate fix at 100.
    let dop = |x: f64| (x * 100.0).round().clamp(0.0, 65_534.0) as u16;
    let fix_type = match fix.fix_type {
        0 => GpsFixType::GPS_FIX_TYPE_NO_GPS,
        1 => GpsFixType::GPS_FIX_TYPE_NO_FIX,
        2 => GpsFixType::GPS_FIX_TYPE_2D_FIX,
        _ => GpsFixType::GPS_FIX_TYPE_3D_FIX,
    };
    MavMessage::GPS_RAW_INT(GPS_RAW_INT_DATA {
        time_usec: time_us(m),
        lat: e7(fix.position.latitude_deg),
        lon: e7(fix.position.longitude_deg),
        alt: mm(fix.position.altitude_amsl_m),
        eph: dop(fix.eph_m),
        epv: dop(fix.epv_m),
        vel: (ground * 100.0).round().clamp(0.0, 65_534.0) as u16,
        cog: cog.clamp(0.0, f64::from(u16::MAX)) as u16,
        fix_type,
        satellites_visible: fix.satellites,
        alt_ellipsoid: mm(fix.position.altitude_amsl_m),
        h_acc: mm_u32(fix.eph_m),
        v_acc: mm_u32(fix.epv_m),
        vel_acc: mm_u32(0.1),
        hdg_acc: 0,
        yaw: 0,
    })
}

/// ALTITUDE: AMSL, local (up), relative to `home_m`, and the clearance above the ground.
pub fn altitude(m: &Measurement, home_m: &Vector3<f64>) -> MavMessage {
    let z = m.base.position_in_world_m.z;
    MavMessage::ALTITUDE(ALTITUDE_DATA {
        time_usec: time_us(m),
        altitude_monotonic: f(HOME.alt_m + z),
        altitude_amsl: f(HOME.alt_m + z),
        altitude_local: f(z),
        altitude_relative: f(z - home_m.z),
        altitude_terrain: f(z),
        bottom_clearance: f(z),
    })
}

/// MISSION_CURRENT: the item flown (or next), the item count and the mission's state.
pub fn mission_current(seq: u16, total: u16, state: MissionState, mission_id: u32) -> MavMessage {
    MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA {
        seq,
        total,
        mission_state: state,
        mission_mode: 0,
        mission_id,
        fence_id: 0,
        rally_points_id: 0,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, UnitQuaternion};
    use platform::RigidBodyState;

    fn measurement() -> Measurement {
        let mut m = Measurement {
            time_s: 1.5,
            ..Measurement::default()
        };
        // 1 m east, 2 m north, 3 m up, facing north, moving up at 0.5 m/s.
        m.base = RigidBodyState {
            velocity_in_world_mps: Vector3::new(0.0, 0.0, 0.5),
            ..RigidBodyState::at_rest(Isometry3::from_parts(
                Vector3::new(1.0, 2.0, 3.0).into(),
                UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            ))
        };
        m.joint_positions = vec![0.1, 0.2];
        m.joint_velocities = vec![-0.1, -0.2];
        m
    }

    #[test]
    fn odometry_is_ned_frd_and_closes_the_tick() {
        let m = measurement();
        let msgs = per_step(
            &m,
            &ImuSample {
                time_s: m.time_s,
                specific_force_in_body_mps2: Vector3::new(0.0, 0.0, GRAVITY_MPS2),
                angular_velocity_in_body_radps: m.base.angular_velocity_in_body_radps,
            },
        );
        let MavMessage::ODOMETRY(o) = &msgs[5] else {
            panic!("ODOMETRY last");
        };
        assert_eq!(o.time_usec, 1_500_000);
        assert_eq!((o.x, o.y, o.z), (2.0, 1.0, -3.0));
        assert_eq!(o.vz, -0.5);
        // Facing north, level: NED←FRD identity.
        assert!((o.q[0].abs() - 1.0).abs() < 1e-6, "{:?}", o.q);
        let MavMessage::HIGHRES_IMU(imu) = &msgs[2] else {
            panic!("IMU third");
        };
        // At rest the accelerometer reads −g along FRD z (up is −z).
        assert!((imu.zacc + 9.81).abs() < 1e-3, "{}", imu.zacc);
        let MavMessage::DEBUG_FLOAT_ARRAY(d) = &msgs[0] else {
            panic!("joints first");
        };
        assert_eq!(&d.data[..4], &[0.1, 0.2, -0.1, -0.2]);
        assert_eq!(d.name.to_str().unwrap(), "joints");
    }

    #[test]
    fn global_position_is_home_plus_the_local_offset() {
        let m = measurement();
        let MavMessage::GLOBAL_POSITION_INT(g) = global_position_int(&m) else {
            panic!()
        };
        assert_eq!(g.relative_alt, 3000);
        assert_eq!(g.alt, 491_000);
        // 2 m north ≈ 1.8e-5 degrees of latitude.
        let dlat = f64::from(g.lat) / 1e7 - HOME.lat_deg;
        assert!(
            (dlat - (2.0 / EARTH_RADIUS_M).to_degrees()).abs() < 2e-7,
            "{dlat}"
        );
        assert_eq!(g.hdg, 0, "facing north");
        assert_eq!(g.vz, -50);
        // The inverse map.
        let (x, y) = world_xy_of(&HOME, f64::from(g.lat) / 1e7, f64::from(g.lon) / 1e7);
        assert!((x - 1.0).abs() < 0.02 && (y - 2.0).abs() < 0.02, "{x} {y}");
        let fix = estimator::GnssFix {
            time_s: m.time_s,
            position: estimator::GeodeticOrigin::default().geodetic(&m.base.position_in_world_m),
            velocity_in_world_mps: m.base.velocity_in_world_mps,
            fix_type: 3,
            eph_m: 0.5,
            epv_m: 0.8,
            satellites: 10,
        };
        let MavMessage::GPS_RAW_INT(r) = gps_raw_int(&m, &fix) else {
            panic!()
        };
        // A noiseless fix lands on GLOBAL_POSITION_INT's point (within the ellipsoid's
        // difference from the sphere over 2 m: well under a centimetre).
        assert!(
            (r.lat - g.lat).abs() <= 1 && (r.lon - g.lon).abs() <= 1,
            "{r:?} {g:?}"
        );
        assert_eq!(r.alt, g.alt);
        assert_eq!(r.fix_type, GpsFixType::GPS_FIX_TYPE_3D_FIX);
        assert_eq!((r.eph, r.h_acc, r.satellites_visible), (50, 500, 10));
    }
}
