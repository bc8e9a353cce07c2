//! The HIL messages, the channel map and the airframe parameters against hand-derived
//! values.

#![allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]

use estimator::{
    BarometerSample, Geodetic, GeodeticOrigin, GnssFix, ImuSample, MagnetometerSample,
};
use mavlink::dialects::common::HilSensorUpdatedFlags;
use nalgebra::{UnitQuaternion, Vector3};
use platform::{ActuatorCommand, Measurement, Vehicle};

use crate::airframe::Px4Airframe;
use crate::channels::ChannelMap;
use crate::messages::{self, HeldReadings};

fn at_rest(time_s: f64) -> ImuSample {
    ImuSample {
        time_s,
        specific_force_in_body_mps2: Vector3::new(0.0, 0.0, 9.81),
        angular_velocity_in_body_radps: Vector3::new(0.1, 0.2, 0.3),
    }
}

/// Level at rest the accelerometer reads (0, 0, −9.81) m/s² in FRD; FLU rates (0.1, 0.2,
/// 0.3) are (0.1, −0.2, −0.3) FRD; 95 586.8 Pa is 955.868 hPa; bits 0x3F alone without mag
/// and baro, 0x3F | 0x1C0 | 0x1A00 = 0x1BFF with both.
#[test]
fn hil_sensor_units_frames_and_fields_updated() {
    let mut held = HeldReadings::default();
    let only_imu = messages::hil_sensor(8333, &at_rest(0.0), None, None, &mut held);
    assert_eq!(only_imu.fields_updated.bits(), 0x3F);
    assert_eq!(
        (only_imu.xacc, only_imu.yacc, only_imu.zacc),
        (0.0, 0.0, -9.81)
    );
    assert_eq!(
        (only_imu.xgyro, only_imu.ygyro, only_imu.zgyro),
        (0.1, -0.2, -0.3)
    );
    assert_eq!(only_imu.id, 0);
    assert_eq!(only_imu.time_usec, 8333);
    let mag = MagnetometerSample {
        time_s: 0.0,
        field_in_body_gauss: Vector3::new(0.2, 0.01, -0.43),
    };
    let baro = BarometerSample {
        time_s: 0.0,
        pressure_pa: 95_586.8,
        temperature_c: 11.8215,
        pressure_altitude_m: 489.0,
    };
    let all = messages::hil_sensor(16667, &at_rest(0.0), Some(&mag), Some(&baro), &mut held);
    assert_eq!(all.fields_updated.bits(), 0x1BFF);
    assert!(
        !all.fields_updated
            .contains(HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_DIFF_PRESSURE)
    );
    assert_eq!((all.xmag, all.ymag, all.zmag), (0.2, -0.01, 0.43));
    assert!((all.abs_pressure - 955.868).abs() < 1e-3);
    assert_eq!(all.diff_pressure, 0.0);
    assert_eq!(all.pressure_alt, 489.0);
    assert!((all.temperature - 11.8215).abs() < 1e-4);
    // The next one without new readings repeats them with their bits unset.
    let next = messages::hil_sensor(25000, &at_rest(0.0), None, None, &mut held);
    assert_eq!(next.fields_updated.bits(), 0x3F);
    assert_eq!(next.abs_pressure, all.abs_pressure);
    assert_eq!(next.zmag, all.zmag);
}

/// 47.3977420° N → 473977420 degE7; 490.25 m → 490250 mm; eph 0.5 m → 50 cm; a world
/// velocity (east 1, north 2, up 0.5) m/s is NED (2, 1, −0.5) → vn 200, ve 100, vd −50 cm/s,
/// ground speed √5 = 2.236 m/s → 224 cm/s, course atan2(1, 2) = 26.565° → 2657 cdeg.
#[test]
fn hil_gps_units() {
    let fix = GnssFix {
        time_s: 0.1,
        position: Geodetic {
            latitude_deg: 47.397742,
            longitude_deg: 8.545594,
            altitude_amsl_m: 490.25,
        },
        velocity_in_world_mps: Vector3::new(1.0, 2.0, 0.5),
        fix_type: 3,
        eph_m: 0.5,
        epv_m: 0.8,
        satellites: 12,
    };
    let g = messages::hil_gps(100_000, &fix);
    assert_eq!((g.lat, g.lon, g.alt), (473_977_420, 85_455_940, 490_250));
    assert_eq!((g.eph, g.epv), (50, 80));
    assert_eq!((g.vn, g.ve, g.vd), (200, 100, -50));
    assert_eq!(g.vel, 224);
    assert_eq!(g.cog, 2657);
    assert_eq!((g.fix_type, g.satellites_visible), (3, 12));
    let still = GnssFix {
        velocity_in_world_mps: Vector3::zeros(),
        ..fix
    };
    assert_eq!(messages::hil_gps(0, &still).cog, messages::COG_UNKNOWN);
}

/// A vehicle facing east (amstack yaw 0) is PX4 yaw 90°: q_ned_from_frd = (cos 45°, 0, 0,
/// sin 45°). 1 m up at home is 489 m = 489000 mm; climbing 1 m/s is vz = −100 cm/s; at rest
/// the specific force 9.81 m/s² up is −1000.34 mG in FRD z.
#[test]
fn hil_state_quaternion_is_ned_frd_ground_truth() {
    let mut m = Measurement::default();
    m.base.position_in_world_m = Vector3::new(0.0, 0.0, 1.0);
    m.base.velocity_in_world_mps = Vector3::new(0.0, 0.0, 1.0);
    m.base.world_from_body = UnitQuaternion::identity();
    let s = messages::hil_state_quaternion(
        1,
        &m,
        &Vector3::new(0.0, 0.0, 9.81),
        &GeodeticOrigin::default(),
    );
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let q = s.attitude_quaternion;
    assert!((q[0] - h).abs() < 1e-6 && q[1].abs() < 1e-6 && q[2].abs() < 1e-6);
    assert!((q[3] - h).abs() < 1e-6);
    assert_eq!((s.lat, s.lon, s.alt), (473_977_420, 85_455_940, 489_000));
    assert_eq!((s.vx, s.vy, s.vz), (0, 0, -100));
    assert_eq!((s.xacc, s.yacc, s.zacc), (0, 0, -1000));
}

/// FA-Hexa: u = 1 on a motor is T_max = 23 N, u = 0.5 with THR_MDL_FAC 0.3 is
/// (0.3·0.25 + 0.7·0.5)·23 = 9.775 N; arm joint c = 0 is mid-range; the gripper −1 closes; a
/// NaN motor reads 0 N and a NaN joint keeps its target.
#[test]
fn controls_map_onto_rotors_joints_and_gripper() {
    let v = Vehicle::builtin("fa-hexa").unwrap();
    let map = ChannelMap::new(&v).unwrap();
    let q0 = v.initial_configuration();
    let previous = ActuatorCommand {
        rotor_thrusts_n: vec![0.0; 6],
        joint_targets: q0.clone(),
        direct_wrench_in_body: None,
    };
    let mut c = [0.0f32; 16];
    c[0] = 1.0;
    c[1] = 0.5;
    c[2] = f32::NAN;
    c[3] = 2.0;
    c[6] = 0.0;
    c[7] = f32::NAN;
    c[10] = -1.0;
    let (cmd, mapped) = map.command(&c, &previous);
    assert_eq!(mapped.non_finite, 2);
    assert_eq!(cmd.rotor_thrusts_n[0], 23.0);
    assert!((cmd.rotor_thrusts_n[1] - 9.775).abs() < 1e-12);
    assert_eq!(cmd.rotor_thrusts_n[2], 0.0);
    assert_eq!(cmd.rotor_thrusts_n[3], 23.0);
    let arm = v.arm_dofs();
    let j0 = v.model.dof_joint(arm[0]).limits.unwrap();
    assert!((cmd.joint_targets[arm[0]] - 0.5 * (j0.lower + j0.upper)).abs() < 1e-12);
    assert_eq!(cmd.joint_targets[arm[1]], q0[arm[1]]);
    let g = v.gripper.as_ref().unwrap();
    let finger = v.model.joints[g.joints[0]].dof.unwrap();
    assert_eq!(cmd.joint_targets[finger], g.closed[0]);
    assert!(
        cmd.rotor_thrusts_n
            .iter()
            .chain(&cmd.joint_targets)
            .all(|x| x.is_finite())
    );
    // The oracle has no map: refused with the vehicle file's section named.
    let err = ChannelMap::new(&Vehicle::builtin("ee-only").unwrap()).unwrap_err();
    assert!(
        err.to_string().contains("ee-only.toml): px4_hil: missing"),
        "{err}"
    );
}

/// FA-Hexa rotor 1, by hand from fa-hexa.urdf: origin (−0.0335, 0.375, −0.058) m, rpy
/// (0, 0.524, 0): its +z turns about y to (sin 0.524, 0, cos 0.524) = (0.50035, 0, 0.86582)
/// FLU = (0.50035, 0, −0.86582) FRD; spin −1 → KM = +0.02 (CCW); CT = 23 − 0 N. The position
/// is the origin about the centre of mass c, in FRD: (−0.0335 − c_x, −(0.375 − c_y),
/// −(−0.058 − c_z)).
#[test]
fn airframe_parameters_of_one_rotor_by_hand() {
    let v = Vehicle::builtin("fa-hexa").unwrap();
    let a = Px4Airframe::of(&v).unwrap();
    let r = a.rotors[1];
    assert!((r.axis_frd - Vector3::new(0.50035, 0.0, -0.86582)).norm() < 1e-4);
    assert_eq!(r.km, 0.02);
    assert_eq!(r.ct, 23.0);
    assert_eq!(a.rotors[0].km, -0.02);
    let c = v.mass_properties(&v.initial_configuration()).com_in_root_m;
    let want = Vector3::new(-0.0335 - c.x, -(0.375 - c.y), 0.058 + c.z);
    assert!((r.position_frd_m - want).norm() < 1e-9);
    assert_eq!(a.ca_airframe, 0);
    assert_eq!(a.thrust_model_factor, 0.3);
    let text = a.snippet(&v);
    assert!(text.contains("param set-default CA_ROTOR_COUNT 6\n"));
    assert!(
        text.contains("param set-default CA_ROTOR1_AX 0.5003\n"),
        "{text}"
    );
    assert!(text.contains("param set-default CA_ROTOR1_KM 0.0200\n"));
    assert!(text.contains("param set-default PWM_MAIN_FUNC1 101"));
    assert!(text.contains("param set-default PWM_MAIN_FUNC7 301"));
    assert!(text.contains("param set-default PWM_MAIN_FUNC11 305  # gripper"));
    // Hover: m g / Σ n_z per rotor over the 23 N span.
    let hover = v.hover_thrust_per_rotor_n().unwrap() / 23.0;
    assert!((a.hover_thrust.unwrap() - hover).abs() < 1e-12);
}
