//! The bridge's tests: setpoints encoded by hand-derived numbers, telemetry converted on
//! hand-made messages, the wire decoder on garbage and signing, and the COMMAND_ACK protocol
//! against a real UDP peer (a test fixture standing in for a misbehaving autopilot, written
//! with the mavlink crate's own reader and writer).

use std::net::UdpSocket;
use std::time::Duration;

use mavlink::dialects::common::{
    ACTUATOR_OUTPUT_STATUS_DATA, AUTOPILOT_VERSION_DATA, AttitudeTargetTypemask, COMMAND_ACK_DATA,
    DEBUG_FLOAT_ARRAY_DATA, HEARTBEAT_DATA, MavAutopilot, MavCmd, MavFrame, MavMessage,
    MavModeFlag, MavProtocolCapability, MavResult, MavState, MavType, ODOMETRY_DATA,
    PositionTargetTypemask, SET_ACTUATOR_CONTROL_TARGET_DATA, SET_ATTITUDE_TARGET_DATA,
};
use mavlink::{MavHeader, MavlinkReader, MavlinkVersion, SigningConfig, SigningData};
use nalgebra::{UnitQuaternion, Vector3};
use platform::{ActuatorCommand, Vehicle};

use crate::address::Address;
use crate::bridge::{Bridge, BridgeConfig, BridgeError};
use crate::capture::{Direction, RawFrame};
use crate::setpoint::{ActuatorUpdate, AttitudeSetpoint, SetpointCodec, SetpointError};
use crate::telemetry::{
    CAPABILITY_SET_ACTUATOR_TARGET, TWIN_FLIGHT_CUSTOM_VERSION, Telemetry, px4_mode,
};
use crate::wire::{CounterSnapshot, Counters, Decoder, Encoder, Signing, SigningKey};

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap()
}

fn hover_command(v: &Vehicle, thrust_n: f64) -> ActuatorCommand {
    ActuatorCommand {
        rotor_thrusts_n: vec![thrust_n; v.rotors.len()],
        joint_targets: v.initial_configuration(),
        direct_wrench_in_body: None,
    }
}

/// A SET_ACTUATOR_CONTROL_TARGET of group `group` with `controls`, as received.
fn target(group: u8, controls: [f32; 8]) -> SET_ACTUATOR_CONTROL_TARGET_DATA {
    SET_ACTUATOR_CONTROL_TARGET_DATA {
        time_usec: 0,
        controls,
        group_mlx: group,
        target_system: 1,
        target_component: 1,
    }
}

fn groups(messages: &[MavMessage]) -> Vec<(u8, [f32; 8])> {
    messages
        .iter()
        .filter_map(|m| match m {
            MavMessage::SET_ACTUATOR_CONTROL_TARGET(d) => Some((d.group_mlx, d.controls)),
            _ => None,
        })
        .collect()
}

// ---------------------------------------------------------------- setpoints

#[test]
fn half_thrust_on_the_fa_hexa_curve_is_the_root_of_the_quadratic() {
    // FA-Hexa: T_max = 23 N, T_min = 0, k = 0.3. 11.5 N is t = 0.5:
    // 0.3 u² + 0.7 u = 0.5  →  u = (−0.7 + √(0.49 + 0.6)) / 0.6 = 0.573 384 ...
    let v = vehicle("fa-hexa");
    assert_eq!(v.rotors.thrust_max_n, 23.0);
    assert_eq!(v.rotors.thrust_curve.model_factor, 0.3);
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let msgs = codec
        .actuator_messages(1_000, &hover_command(&v, 11.5))
        .unwrap();
    let expected = (-0.7 + (0.49_f64 + 0.6).sqrt()) / 0.6;
    assert!((expected - 0.573_384_4).abs() < 1e-6);
    let g = groups(&msgs);
    // No tilt servos: group 2 then group 0, which completes the tick.
    assert_eq!(g.iter().map(|(n, _)| *n).collect::<Vec<_>>(), vec![2, 0]);
    let motors = g[1].1;
    for u in &motors[..6] {
        assert!((f64::from(*u) - expected).abs() < 1e-6, "{u}");
    }
    assert_eq!(&motors[6..], &[0.0, 0.0]);
    // And back: the receiver's thrusts are 11.5 N within f32 precision.
    let mut q = v.initial_configuration();
    let Ok(ActuatorUpdate::Motors(thrusts)) = codec.decode_actuator(&target(0, motors), &mut q)
    else {
        panic!("group 0 completes a tick");
    };
    assert_eq!(thrusts.len(), 6);
    for t in thrusts {
        assert!((t - 11.5).abs() < 1e-5, "{t}");
    }
    for m in &msgs {
        let MavMessage::SET_ACTUATOR_CONTROL_TARGET(d) = m else {
            panic!("{m:?}")
        };
        assert_eq!(
            (d.target_system, d.target_component, d.time_usec),
            (1, 1, 1_000)
        );
    }
}

#[test]
fn thrusts_outside_the_rotor_range_are_clamped_to_zero_and_one() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let mut c = hover_command(&v, 0.0);
    c.rotor_thrusts_n = vec![-3.0, 0.0, 23.0, 40.0, 5.75, 17.25];
    let motors = groups(&codec.actuator_messages(0, &c).unwrap())[1].1;
    // 5.75 N: t = 0.25 → 0.3u² + 0.7u = 0.25; 17.25 N: t = 0.75.
    let root = |t: f64| (-0.7 + (0.49 + 1.2 * t).sqrt()) / 0.6;
    let expected = [0.0, 0.0, 1.0, 1.0, root(0.25), root(0.75)];
    for (u, e) in motors.iter().zip(expected) {
        assert!((f64::from(*u) - e).abs() < 1e-6, "{u} vs {e}");
    }
}

#[test]
fn arm_joints_and_gripper_map_linearly_onto_minus_one_to_one() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let mut c = hover_command(&v, 10.0);
    let limits: Vec<(usize, f64, f64)> = v
        .arm_joints
        .iter()
        .map(|&j| {
            let joint = &v.model.joints[j];
            let l = joint.limits.unwrap();
            (joint.dof.unwrap(), l.lower, l.upper)
        })
        .collect();
    // Joint 0 at its lower limit, joint 1 at its upper, joint 2 at 3/4 of the range,
    // joint 3 at the middle; the gripper fully open.
    let fractions = [0.0, 1.0, 0.75, 0.5];
    for (&(dof, lo, hi), f) in limits.iter().zip(fractions) {
        c.joint_targets[dof] = lo + f * (hi - lo);
    }
    let g = v.gripper.as_ref().unwrap();
    for ((&j, &open), _) in g.joints.iter().zip(&g.open).zip(&g.closed) {
        c.joint_targets[v.model.joints[j].dof.unwrap()] = open;
    }
    let arm = groups(&codec.actuator_messages(0, &c).unwrap())[0];
    assert_eq!(arm.0, 2);
    let expected = [-1.0, 1.0, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0];
    for (got, e) in arm.1.iter().zip(expected) {
        assert!((f64::from(*got) - e).abs() < 1e-6, "{:?}", arm.1);
    }
    // Back to joint targets: the same positions.
    let mut back = vec![f64::NAN; c.joint_targets.len()];
    assert_eq!(
        codec.decode_actuator(&target(2, arm.1), &mut back),
        Ok(ActuatorUpdate::Joints)
    );
    for &(dof, ..) in &limits {
        assert!((back[dof] - c.joint_targets[dof]).abs() < 1e-6);
    }
    // The gripper closed is −1.
    for ((&j, &closed), _) in g.joints.iter().zip(&g.closed).zip(&g.open) {
        c.joint_targets[v.model.joints[j].dof.unwrap()] = closed;
    }
    let arm = groups(&codec.actuator_messages(0, &c).unwrap())[0];
    assert_eq!(arm.1[4], -1.0);
}

#[test]
fn a_tilting_vehicle_sends_group_one_between_the_arm_and_the_motors() {
    let v = vehicle("omni-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    assert!(codec.has_tilt());
    let mut c = hover_command(&v, 10.0);
    let tilts: Vec<(usize, (f64, f64))> = v
        .rotors
        .rotors
        .iter()
        .map(|r| {
            let t = r.tilt.as_ref().unwrap();
            let j = v.model.joint_id(&t.joint).unwrap();
            (v.model.joints[j].dof.unwrap(), t.limits_rad)
        })
        .collect();
    // Tilt 0 at its upper limit, tilt 1 at its lower limit, the rest in the middle.
    for (i, &(dof, (lo, hi))) in tilts.iter().enumerate() {
        c.joint_targets[dof] = match i {
            0 => hi,
            1 => lo,
            _ => 0.5 * (lo + hi),
        };
    }
    let g = groups(&codec.actuator_messages(0, &c).unwrap());
    assert_eq!(g.iter().map(|(n, _)| *n).collect::<Vec<_>>(), vec![2, 1, 0]);
    let tilt = g[1].1;
    assert_eq!(tilt[0], 1.0);
    assert_eq!(tilt[1], -1.0);
    for x in &tilt[2..6] {
        assert!(x.abs() < 1e-6);
    }
}

#[test]
fn non_finite_setpoints_are_refused_naming_the_value() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let mut c = hover_command(&v, 10.0);
    c.rotor_thrusts_n[2] = f64::NAN;
    let e = codec.actuator_messages(0, &c).unwrap_err();
    assert!(
        matches!(e, SetpointError::NonFinite { ref field, .. } if field == "rotor_thrusts_n[2]")
    );
    assert!(e.to_string().contains("non-finite"), "{e}");
    let mut c = hover_command(&v, 10.0);
    c.joint_targets[1] = f64::INFINITY;
    let e = codec.actuator_messages(0, &c).unwrap_err();
    assert!(e.to_string().contains("joint_targets[1] = inf"), "{e}");
    let c = hover_command(&v, 10.0);
    let sp = AttitudeSetpoint {
        world_from_body: UnitQuaternion::identity(),
        force_in_body_n: Vector3::new(0.0, f64::NAN, 30.0),
        body_rates_radps: None,
    };
    let e = codec.attitude_messages(0, &c, &sp).unwrap_err();
    assert!(e.to_string().contains("force_in_body_n.y"), "{e}");
    // Wrong shape: 5 thrusts for 6 rotors.
    let mut c = hover_command(&v, 10.0);
    c.rotor_thrusts_n.pop();
    assert!(matches!(
        codec.actuator_messages(0, &c),
        Err(SetpointError::Shape(_))
    ));
}

#[test]
fn attitude_setpoint_is_ned_frd_with_thrust_over_total_max() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let c = hover_command(&v, 0.0);
    // Level, facing east (amstack identity) = PX4 yaw +90°. 69 N up (FLU +z) = FRD −z;
    // scale 6 · 23 = 138 N → thrust_body z = −0.5. 13.8 N left (FLU +y) = FRD −y → −0.1.
    let sp = AttitudeSetpoint {
        world_from_body: UnitQuaternion::identity(),
        force_in_body_n: Vector3::new(0.0, 13.8, 69.0),
        body_rates_radps: Some(Vector3::new(0.1, 0.2, 0.3)),
    };
    let msgs = codec.attitude_messages(5_000_000, &c, &sp).unwrap();
    assert_eq!(msgs.len(), 2);
    assert!(matches!(&msgs[0], MavMessage::SET_ACTUATOR_CONTROL_TARGET(d) if d.group_mlx == 2));
    let MavMessage::SET_ATTITUDE_TARGET(a) = &msgs[1] else {
        panic!("{:?}", msgs[1])
    };
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let expected_q = [h, 0.0, 0.0, h]; // yaw +90° about NED down
    for (x, e) in a.q.iter().zip(expected_q) {
        assert!((x - e).abs() < 1e-6, "{:?}", a.q);
    }
    assert!((a.thrust_body[0]).abs() < 1e-7);
    assert!((a.thrust_body[1] + 0.1).abs() < 1e-6, "{:?}", a.thrust_body);
    assert!((a.thrust_body[2] + 0.5).abs() < 1e-6, "{:?}", a.thrust_body);
    assert!((a.thrust - 0.5).abs() < 1e-6);
    assert_eq!(
        (a.body_roll_rate, a.body_pitch_rate, a.body_yaw_rate),
        (0.1, -0.2, -0.3)
    );
    // Rates used, thrust_body flagged (PX4 reads it only with THRUST_BODY_SET).
    assert_eq!(
        a.type_mask,
        AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET
    );
    assert_eq!(a.time_boot_ms, 5_000);
    // A force beyond every rotor's maximum is clamped to −1.
    let sp = AttitudeSetpoint {
        force_in_body_n: Vector3::new(0.0, 0.0, 1000.0),
        body_rates_radps: None,
        ..sp
    };
    let msgs = codec.attitude_messages(0, &c, &sp).unwrap();
    let MavMessage::SET_ATTITUDE_TARGET(a) = &msgs[1] else {
        panic!()
    };
    assert_eq!(a.thrust_body[2], -1.0);
    assert!(!a.type_mask.is_empty());
}

#[test]
fn an_under_actuated_vehicle_sends_the_collective_thrust_alone() {
    // The UA-Quad cannot push sideways: no THRUST_BODY_SET, thrust_body zero, and the
    // collective thrust F_z / (4 · T_max); a fully actuated vehicle sends thrust_body.
    let v = vehicle("ua-quad");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    assert!(!codec.sends_thrust_body());
    assert!(
        SetpointCodec::new(&vehicle("fa-hexa"), 1, 1)
            .unwrap()
            .sends_thrust_body()
    );
    assert!(
        SetpointCodec::new(&vehicle("omni-hexa"), 1, 1)
            .unwrap()
            .sends_thrust_body()
    );
    let total = 4.0 * v.rotors.thrust_max_n;
    let sp = AttitudeSetpoint {
        world_from_body: UnitQuaternion::identity(),
        force_in_body_n: Vector3::new(0.0, 0.0, 0.3 * total),
        body_rates_radps: None,
    };
    let msgs = codec
        .attitude_messages(0, &hover_command(&v, 0.0), &sp)
        .unwrap();
    let Some(MavMessage::SET_ATTITUDE_TARGET(a)) = msgs.last() else {
        panic!("{msgs:?}")
    };
    assert!((a.thrust - 0.3).abs() < 1e-6, "{}", a.thrust);
    assert_eq!(a.thrust_body, [0.0; 3]);
    assert!(
        !a.type_mask
            .contains(AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET)
    );
    // Read back as PX4 reads it: the collective thrust along body up.
    let back = codec.decode_attitude(a).unwrap();
    assert!((back.force_in_body_n - sp.force_in_body_n).norm() < 1e-3);
}

#[test]
fn position_setpoint_is_local_ned_with_only_position_and_yaw_used() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let c = hover_command(&v, 0.0);
    // World (1, 2, 3) m, z up → NED (2, 1, −3); heading north (amstack yaw π/2) → PX4 yaw 0,
    // heading west (π) → −π/2.
    let sp = platform::PositionSetpoint {
        position_in_world_m: Vector3::new(1.0, 2.0, 3.0),
        yaw_rad: std::f64::consts::FRAC_PI_2,
    };
    let msgs = codec.position_messages(7_000_000, &c, &sp).unwrap();
    assert_eq!(msgs.len(), 2);
    assert!(matches!(&msgs[0], MavMessage::SET_ACTUATOR_CONTROL_TARGET(d) if d.group_mlx == 2));
    let MavMessage::SET_POSITION_TARGET_LOCAL_NED(p) = &msgs[1] else {
        panic!("{:?}", msgs[1])
    };
    assert_eq!((p.x, p.y, p.z), (2.0, 1.0, -3.0));
    assert!(p.yaw.abs() < 1e-7, "{}", p.yaw);
    assert_eq!(p.coordinate_frame, MavFrame::MAV_FRAME_LOCAL_NED);
    assert_eq!((p.target_system, p.target_component), (1, 1));
    assert_eq!(p.time_boot_ms, 7_000);
    // PX4's bits: 8/16/32 velocity, 64/128/256 acceleration, 2048 yaw rate ignored; position
    // (1/2/4), yaw (1024) and FORCE_SET (512) clear: 8+16+32+64+128+256+2048 = 2552.
    assert_eq!(p.type_mask.bits(), 2552);
    assert!(
        !p.type_mask
            .contains(PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE)
    );
    let west = platform::PositionSetpoint {
        yaw_rad: std::f64::consts::PI,
        ..sp
    };
    let msgs = codec.position_messages(0, &c, &west).unwrap();
    let MavMessage::SET_POSITION_TARGET_LOCAL_NED(p) = &msgs[1] else {
        panic!()
    };
    assert!((f64::from(p.yaw) + std::f64::consts::FRAC_PI_2).abs() < 1e-6);
    // Without the arm channel (a PX4), the position target alone.
    let px4 = codec.clone().with_arm_channel(false);
    let msgs = px4.position_messages(0, &c, &sp).unwrap();
    assert_eq!(msgs.len(), 1);
    assert!(matches!(
        msgs[0],
        MavMessage::SET_POSITION_TARGET_LOCAL_NED(_)
    ));
    let msgs = px4
        .attitude_messages(
            0,
            &c,
            &AttitudeSetpoint {
                world_from_body: UnitQuaternion::identity(),
                force_in_body_n: Vector3::z() * 60.0,
                body_rates_radps: None,
            },
        )
        .unwrap();
    assert_eq!(msgs.len(), 1);
    // A non-finite position is refused by name; nothing is sent.
    let nan = platform::PositionSetpoint {
        position_in_world_m: Vector3::new(0.0, f64::NAN, 1.0),
        ..sp
    };
    let e = codec.position_messages(0, &c, &nan).unwrap_err();
    assert_eq!(
        e.to_string(),
        "refusing to send a non-finite setpoint: position_in_world_m.y = NaN"
    );
    let e = codec
        .position_messages(
            0,
            &c,
            &platform::PositionSetpoint {
                yaw_rad: f64::INFINITY,
                ..sp
            },
        )
        .unwrap_err();
    assert!(e.to_string().contains("yaw_rad = inf"), "{e}");
}

#[test]
fn rate_setpoint_ignores_the_attitude_and_carries_frd_rates_and_the_thrust() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    // 69 N up (FLU +z) of 6 · 23 N → thrust_body z = −0.5 (FRD); rates FLU (0.1, 0.2, 0.3) →
    // FRD (0.1, −0.2, −0.3); type_mask ATTITUDE_IGNORE (128) | THRUST_BODY_SET (32) = 160.
    let sp = platform::RateSetpoint {
        body_rates_radps: Vector3::new(0.1, 0.2, 0.3),
        force_in_body_n: Vector3::new(0.0, 0.0, 69.0),
    };
    let msgs = codec
        .rate_messages(0, &hover_command(&v, 0.0), &sp)
        .unwrap();
    assert_eq!(msgs.len(), 2);
    let MavMessage::SET_ATTITUDE_TARGET(a) = &msgs[1] else {
        panic!("{:?}", msgs[1])
    };
    assert_eq!(a.type_mask.bits(), 160);
    assert_eq!(a.q, [1.0, 0.0, 0.0, 0.0]);
    assert_eq!(
        (a.body_roll_rate, a.body_pitch_rate, a.body_yaw_rate),
        (0.1, -0.2, -0.3)
    );
    assert!((a.thrust_body[2] + 0.5).abs() < 1e-6 && (a.thrust - 0.5).abs() < 1e-6);
    // The UA-Quad: collective thrust, ATTITUDE_IGNORE alone.
    let ua = vehicle("ua-quad");
    let msgs = SetpointCodec::new(&ua, 1, 1)
        .unwrap()
        .rate_messages(0, &hover_command(&ua, 0.0), &sp)
        .unwrap();
    let Some(MavMessage::SET_ATTITUDE_TARGET(a)) = msgs.last() else {
        panic!()
    };
    assert_eq!(a.type_mask.bits(), 128);
    // A non-finite rate is refused by name.
    let nan = platform::RateSetpoint {
        body_rates_radps: Vector3::new(0.0, f64::NAN, 0.0),
        ..sp
    };
    let e = codec
        .rate_messages(0, &hover_command(&v, 0.0), &nan)
        .unwrap_err();
    assert!(e.to_string().contains("body_rates_radps.y = NaN"), "{e}");
}

#[test]
fn a_pose_gives_its_position_and_heading() {
    // Heading is body x projected on the ground: a target pitched and rolled keeps its yaw.
    let pose = nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(0.5, -1.0, 2.0),
        UnitQuaternion::from_euler_angles(0.2, -0.3, 1.1),
    );
    let sp = platform::PositionSetpoint::of_pose(&pose);
    assert_eq!(sp.position_in_world_m, Vector3::new(0.5, -1.0, 2.0));
    assert!((sp.yaw_rad - 1.1).abs() < 1e-12, "{}", sp.yaw_rad);
}

#[test]
fn every_setpoint_survives_the_wire() {
    let v = vehicle("omni-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let c = hover_command(&v, 9.0);
    let sp = AttitudeSetpoint {
        world_from_body: UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        force_in_body_n: Vector3::new(1.0, -2.0, 40.0),
        body_rates_radps: Some(Vector3::new(0.0, 0.1, 0.0)),
    };
    let mut msgs = codec.actuator_messages(42, &c).unwrap();
    msgs.extend(codec.attitude_messages(42, &c, &sp).unwrap());
    let mut encoder = Encoder::new(1, 191, None);
    let mut decoder = Decoder::new(None);
    let counters = Counters::default();
    let mut frames = Vec::new();
    for m in &msgs {
        decoder.push_datagram(&encoder.encode(m), &counters, &mut frames);
    }
    assert_eq!(frames.len(), msgs.len());
    for (f, m) in frames.iter().zip(&msgs) {
        assert_eq!(&f.message, m);
        assert_eq!((f.header.system_id, f.header.component_id), (1, 191));
    }
    // The mavlink crate's own reader agrees.
    let bytes = encoder.encode(&msgs[0]);
    let (_, m) = MavlinkReader::new(&bytes[..])
        .read_message::<MavMessage>(MavlinkVersion::V2)
        .unwrap();
    assert_eq!(m, msgs[0]);
}

// ---------------------------------------------------------------- telemetry

fn odometry(time_usec: u64) -> ODOMETRY_DATA {
    ODOMETRY_DATA {
        time_usec,
        x: 1.0,
        y: 2.0,
        z: -3.0,
        q: [1.0, 0.0, 0.0, 0.0],
        vx: 0.5,
        vy: 0.0,
        vz: -1.0,
        rollspeed: 0.1,
        pitchspeed: 0.2,
        yawspeed: 0.3,
        frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
        child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
        ..ODOMETRY_DATA::default()
    }
}

fn joints_message(v: &Vehicle, q: &[f64]) -> MavMessage {
    let mut data = [0f32; 58];
    for (d, x) in data.iter_mut().zip(q) {
        *d = *x as f32;
    }
    for (i, _) in q.iter().enumerate() {
        data[q.len() + i] = 0.25; // every joint moving at 0.25 rad/s
    }
    assert!(2 * v.model.dof() <= 58);
    MavMessage::DEBUG_FLOAT_ARRAY(DEBUG_FLOAT_ARRAY_DATA {
        time_usec: 0,
        name: "joints".into(),
        array_id: 1,
        data,
    })
}

#[test]
fn ned_telemetry_becomes_a_measurement_in_our_frames() {
    let v = vehicle("fa-hexa");
    let mut t = Telemetry::new(&v);
    let mut q = v.initial_configuration();
    let arm0 = v.arm_dofs()[0];
    q[arm0] = 0.5;
    assert!(t.apply(&joints_message(&v, &q)).is_none());
    let mut actuator = [0f32; 32];
    actuator[..6].copy_from_slice(&[10.0, 11.0, 12.0, 13.0, 14.0, 15.0]);
    t.apply(&MavMessage::ACTUATOR_OUTPUT_STATUS(
        ACTUATOR_OUTPUT_STATUS_DATA {
            time_usec: 0,
            active: 6,
            actuator,
        },
    ));
    let m = t
        .apply(&MavMessage::ODOMETRY(odometry(2_500_000)))
        .expect("ODOMETRY closes the tick");
    assert_eq!(m.time_s, 2.5);
    // NED (1 north, 2 east, 3 up) = world (2 east, 1 north, 3 up).
    assert_eq!(m.base.position_in_world_m, Vector3::new(2.0, 1.0, 3.0));
    // NED velocity (0.5 north, 1 up) = world (0, 0.5, 1).
    assert_eq!(m.base.velocity_in_world_mps, Vector3::new(0.0, 0.5, 1.0));
    // PX4 identity faces north: amstack yaw +90°.
    let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    assert!(m.base.world_from_body.angle_to(&expected) < 1e-9);
    // FRD rates (0.1, 0.2, 0.3) = FLU (0.1, −0.2, −0.3).
    let w = m.base.angular_velocity_in_body_radps;
    assert!((w - Vector3::new(0.1, -0.2, -0.3)).norm() < 1e-6, "{w}");
    assert!((m.joint_positions[arm0] - 0.5).abs() < 1e-7);
    assert!(m.joint_velocities.iter().all(|&x| x == 0.25));
    let realised: Vec<f64> = m.rotors.iter().map(|r| r.realised_n).collect();
    assert_eq!(realised, vec![10.0, 11.0, 12.0, 13.0, 14.0, 15.0]);
    // The end effector by the vehicle's forward kinematics from the reported joints.
    let ee = m.base.pose() * v.base_from_ee(&m.joint_positions);
    assert!((ee.translation.vector - m.world_from_ee.translation.vector).norm() < 1e-12);
    assert!(
        (m.world_from_ee.translation.vector - m.base.position_in_world_m).norm() > 0.05,
        "the EE is not at the base"
    );
}

#[test]
fn heartbeat_gives_armed_and_mode_and_bad_values_are_ignored() {
    let v = vehicle("fa-hexa");
    let mut t = Telemetry::new(&v);
    t.apply(&MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: px4_mode::custom_mode(px4_mode::OFFBOARD, 0),
        mavtype: MavType::MAV_TYPE_HEXAROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    }));
    assert!(t.autopilot.armed);
    assert!(t.autopilot.in_offboard());
    assert_eq!(t.autopilot.mode_name(), "OFFBOARD");
    assert_eq!(px4_mode::custom_mode(4, 3), 0x0304_0000);
    assert_eq!(px4_mode::name(0x0304_0000), "AUTO.LOITER");
    let mut bad = odometry(1);
    bad.x = f32::NAN;
    assert!(t.apply(&MavMessage::ODOMETRY(bad)).is_none());
    let mut bad = odometry(1);
    bad.q = [0.5, 0.0, 0.0, 0.0];
    assert!(t.apply(&MavMessage::ODOMETRY(bad)).is_none());
    assert_eq!(t.rejected_values, 2);
    assert_eq!(t.current().base.position_in_world_m, Vector3::zeros());
}

// ---------------------------------------------------------------- wire

/// xorshift64*: deterministic noise without a dependency.
fn noise(seed: u64, n: usize) -> Vec<u8> {
    let mut x = seed.max(1);
    (0..n)
        .map(|_| {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            (x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 56) as u8
        })
        .collect()
}

fn heartbeat_frame(encoder: &mut Encoder) -> Vec<u8> {
    encoder.encode(&MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()))
}

#[test]
fn garbage_is_counted_and_the_stream_resynchronises() {
    let counters = Counters::default();
    let mut decoder = Decoder::new(None);
    let mut encoder = Encoder::new(1, 1, None);
    let mut frames = Vec::new();
    // 64 kB of noise as a stream, in odd-sized chunks: no panic.
    let junk = noise(7, 65_536);
    for chunk in junk.chunks(97) {
        decoder.push_stream(chunk, &counters, &mut frames);
    }
    // A good frame after the noise still decodes (the noise may have left a false start
    // in the buffer: a few good frames flush it).
    for _ in 0..3 {
        decoder.push_stream(&heartbeat_frame(&mut encoder), &counters, &mut frames);
    }
    let good = frames
        .iter()
        .filter(|f| {
            f.header
                == MavHeader {
                    system_id: 1,
                    component_id: 1,
                    sequence: f.header.sequence,
                }
        })
        .count();
    assert!(good >= 2, "{good}");
    let c = counters.snapshot();
    assert!(c.garbage_bytes > 60_000, "{c:?}");

    // Bad CRC: one payload byte flipped.
    let counters = Counters::default();
    let mut decoder = Decoder::new(None);
    let mut frames = Vec::new();
    let mut bad = heartbeat_frame(&mut encoder);
    bad[12] ^= 0x40;
    decoder.push_datagram(&bad, &counters, &mut frames);
    assert!(frames.is_empty());
    assert_eq!(counters.snapshot().bad_crc, 1);

    // Unknown id (0x00FFFF is not in common).
    let mut unknown = heartbeat_frame(&mut encoder);
    unknown[7] = 0xFF;
    unknown[8] = 0xFF;
    decoder.push_datagram(&unknown, &counters, &mut frames);
    assert_eq!(counters.snapshot().unknown_id, 1);

    // Truncated: half a frame in a datagram.
    let whole = heartbeat_frame(&mut encoder);
    decoder.push_datagram(&whole[..whole.len() / 2], &counters, &mut frames);
    assert_eq!(counters.snapshot().truncated, 1);

    // Two frames glued in one datagram both decode; the link keeps working.
    let mut two = heartbeat_frame(&mut encoder);
    two.extend(heartbeat_frame(&mut encoder));
    decoder.push_datagram(&two, &counters, &mut frames);
    assert_eq!(frames.len(), 2);
    assert_eq!(counters.snapshot().frames_ok, 2);
}

#[test]
fn random_datagrams_never_panic() {
    let counters = Counters::default();
    let mut decoder = Decoder::new(None);
    let mut frames = Vec::new();
    for seed in 1..2_000u64 {
        let len = (seed as usize * 37) % 300;
        let mut d = noise(seed, len);
        if let Some(b) = d.first_mut() {
            *b = 0xFD; // start like a frame, to reach the header and length paths
        }
        decoder.push_datagram(&d, &counters, &mut frames);
    }
    let c = counters.snapshot();
    assert!(
        c.truncated + c.bad_crc + c.unknown_id + c.garbage_bytes > 0,
        "{c:?}"
    );
}

fn key(byte: u8) -> SigningKey {
    SigningKey {
        secret: [byte; 32],
        link_id: 0,
    }
}

#[test]
fn with_signing_required_unsigned_and_forged_frames_are_refused() {
    let signing = Signing {
        key: key(7),
        require: true,
    };
    let counters = Counters::default();
    let mut decoder = Decoder::new(Some(&signing));
    let mut frames = Vec::new();
    // Unsigned.
    let mut plain = Encoder::new(1, 1, None);
    decoder.push_datagram(&heartbeat_frame(&mut plain), &counters, &mut frames);
    // Signed with another key (forged).
    let mut forger = Encoder::new(1, 1, Some(&key(8)));
    decoder.push_datagram(&heartbeat_frame(&mut forger), &counters, &mut frames);
    // Signed with the right key, then one signature byte altered.
    let mut honest = Encoder::new(1, 1, Some(&key(7)));
    let mut altered = heartbeat_frame(&mut honest);
    let last = altered.len() - 1;
    altered[last] ^= 1;
    decoder.push_datagram(&altered, &counters, &mut frames);
    assert!(frames.is_empty());
    // Honest frames pass, a replay of one does not.
    let good = heartbeat_frame(&mut honest);
    decoder.push_datagram(&good, &counters, &mut frames);
    decoder.push_datagram(&good, &counters, &mut frames);
    assert_eq!(frames.len(), 1);
    let c = counters.snapshot();
    assert_eq!(c.refused_unsigned, 1, "{c:?}");
    assert_eq!(c.refused_bad_signature, 3, "{c:?}"); // forged, altered, replayed
    // The mavlink crate's own signer produces frames we accept.
    let data = SigningData::from_config(SigningConfig::new([7; 32], 3, true, false));
    let mut bytes = Vec::new();
    mavlink::write_v2_msg_signed(
        &mut bytes,
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        },
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()),
        Some(&data),
    )
    .unwrap();
    decoder.push_datagram(&bytes, &counters, &mut frames);
    assert_eq!(frames.len(), 2);
}

#[test]
fn signing_keys_read_from_hex_or_raw_files() {
    let dir = tempfile::tempdir().unwrap();
    let hex = dir.path().join("key.hex");
    std::fs::write(&hex, format!("{}\n", "0a".repeat(32))).unwrap();
    assert_eq!(SigningKey::from_file(&hex, 0).unwrap().secret, [10; 32]);
    let raw = dir.path().join("key.bin");
    std::fs::write(&raw, [3u8; 32]).unwrap();
    assert_eq!(SigningKey::from_file(&raw, 0).unwrap().secret, [3; 32]);
    let short = dir.path().join("short");
    std::fs::write(&short, "abcd").unwrap();
    let e = SigningKey::from_file(&short, 0).unwrap_err();
    assert!(e.contains("short") && e.contains("found 4 bytes"), "{e}");
}

// ------------------------------------------- the wire, as the twin's autopilot uses it

/// A ground station's heartbeat (the autopilot's usual first frame).
fn gcs_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 393_216,
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

#[test]
fn a_good_frame_decodes_and_bad_ones_are_counted_by_kind() {
    let mut tx = Encoder::new(255, 190, None);
    let mut rx = Decoder::new(None);
    let counters = Counters::default();
    let good = tx.encode(&gcs_heartbeat());
    let mut out = Vec::new();
    rx.push_datagram(&good, &counters, &mut out);
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].message, gcs_heartbeat());
    assert_eq!(out[0].header.system_id, 255);

    let mut bad_crc = good.clone();
    let last = bad_crc.len() - 1;
    bad_crc[last] ^= 0x55;
    rx.push_datagram(&bad_crc, &counters, &mut out);
    assert_eq!(counters.snapshot().bad_crc, 1);

    rx.push_datagram(&good[..good.len() - 3], &counters, &mut out);
    assert_eq!(counters.snapshot().truncated, 1);

    let mut unknown = good.clone();
    unknown[7] = 0xEE;
    unknown[8] = 0xEE;
    rx.push_datagram(&unknown, &counters, &mut out);
    assert_eq!(counters.snapshot().unknown_id, 1);

    // (After a refused frame the parser resyncs byte by byte: those bytes count as junk.)
    let junk = counters.snapshot().garbage_bytes;
    rx.push_datagram(&[1, 2, 3], &counters, &mut out);
    assert_eq!(counters.snapshot().garbage_bytes, junk + 3);
    assert_eq!(out.len(), 1, "nothing bad got through");
    // A good frame after garbage in the same datagram still decodes.
    let mut mixed = vec![0u8, 0xFD, 7];
    mixed.extend_from_slice(&good);
    rx.push_datagram(&mixed, &counters, &mut out);
    let c = counters.snapshot();
    assert_eq!(out.len(), 2, "{c}");
    assert_eq!(c.frames_ok, 2);
    assert_eq!(c.bad_crc, 1);
    assert_eq!(c.unknown_id, 1);
}

#[test]
fn a_stream_waits_for_the_rest_of_a_frame() {
    let mut tx = Encoder::new(255, 190, None);
    let mut rx = Decoder::new(None);
    let counters = Counters::default();
    let good = tx.encode(&gcs_heartbeat());
    let mut out = Vec::new();
    let (a, b) = good.split_at(5);
    rx.push_stream(a, &counters, &mut out);
    assert!(out.is_empty());
    rx.push_stream(b, &counters, &mut out);
    assert_eq!(out.len(), 1);
    assert_eq!(counters.snapshot().truncated, 0);
}

#[test]
fn a_decoder_accepting_v1_checks_mavlink_1_frames_and_the_encoder_answers_in_kind() {
    let mut tx = Encoder::new(255, 190, None);
    let counters = Counters::default();
    let mut out = Vec::new();
    // A MAVLink 1 heartbeat (ours and the crate's agree), a corrupted copy, a MAVLink 2 one.
    let mut v1 = Vec::new();
    assert!(tx.encode_v1_into(&gcs_heartbeat(), &mut v1));
    assert_eq!(v1[0], 0xFE);
    let mut bad = v1.clone();
    bad[7] ^= 0x10;
    let mut bytes = v1.clone();
    bytes.extend(&bad);
    bytes.extend(tx.encode(&gcs_heartbeat()));
    let mut rx = Decoder::new(None).accepting_v1(true);
    rx.push_datagram(&bytes, &counters, &mut out);
    let c = counters.snapshot();
    assert_eq!(out.len(), 2, "{c}");
    assert_eq!(out[0].version, MavlinkVersion::V1);
    assert_eq!(out[1].version, MavlinkVersion::V2);
    assert_eq!(
        (out[0].header.system_id, out[0].header.component_id),
        (255, 190)
    );
    assert_eq!(c.bad_crc, 1, "{c}");
    // Cut short: truncated, never a panic.
    rx.push_datagram(&v1[..5], &counters, &mut out);
    assert_eq!(counters.snapshot().truncated, 1);
    // MAVLink 1 cannot carry ids above 255 nor be signed.
    let odometry = MavMessage::ODOMETRY(ODOMETRY_DATA::default());
    let mut none = Vec::new();
    assert!(!tx.encode_v1_into(&odometry, &mut none));
    assert!(none.is_empty());
    let signing = Signing {
        key: key(7),
        require: true,
    };
    let mut strict = Decoder::new(Some(&signing)).accepting_v1(true);
    let strict_counters = Counters::default();
    strict.push_datagram(&v1, &strict_counters, &mut out);
    assert_eq!(strict_counters.snapshot().refused_unsigned, 1);
}

#[test]
fn mavlink_1_and_unknown_incompatibility_flags_are_unsupported() {
    let mut tx = Encoder::new(255, 190, None);
    let mut rx = Decoder::new(None);
    let counters = Counters::default();
    let mut out = Vec::new();
    // A MAVLink 1 heartbeat, then a good MAVLink 2 one in the same datagram.
    let mut bytes = Vec::new();
    mavlink::write_v1_msg(
        &mut bytes,
        MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: 0,
        },
        &gcs_heartbeat(),
    )
    .unwrap();
    assert_eq!(bytes[0], 0xFE);
    let v1_len = bytes.len();
    bytes.extend(tx.encode(&gcs_heartbeat()));
    rx.push_datagram(&bytes, &counters, &mut out);
    let c = counters.snapshot();
    assert_eq!(out.len(), 1, "{c}");
    assert_eq!(c.unsupported, 1, "{c}");
    // The MAVLink 1 body is junk.
    assert_eq!(c.garbage_bytes, (v1_len - 1) as u64, "{c}");
    // An incompatibility flag we do not know (0x02), over a stream.
    let mut odd = tx.encode(&gcs_heartbeat());
    odd[2] |= 0x02;
    rx.push_stream(&odd, &counters, &mut out);
    rx.push_stream(&tx.encode(&gcs_heartbeat()), &counters, &mut out);
    let c = counters.snapshot();
    assert_eq!(c.unsupported, 2, "{c}");
    assert_eq!(out.len(), 2, "{c}");
    assert_eq!(c.bad_frames(), 2, "{c}");
    assert_eq!(c.drop_rate_centi_percent(), 5_000, "{c}");
}

#[test]
fn bad_frames_and_the_drop_rate_sum_every_refusal() {
    let c = CounterSnapshot {
        frames_ok: 3,
        garbage_bytes: 1_000,
        bad_crc: 1,
        unknown_id: 1,
        truncated: 1,
        unsupported: 1,
        refused_unsigned: 1,
        refused_bad_signature: 1,
        undecodable: 1,
        rejected_input: 5,
        frames_sent: 9,
    };
    assert_eq!(c.bad_frames(), 7);
    assert_eq!(c.drop_rate_centi_percent(), 7_000);
    assert_eq!(CounterSnapshot::default().drop_rate_centi_percent(), 0);
    assert_eq!(
        c.to_string(),
        "frames ok 3, bad crc 1, unknown id 1, truncated 1, bad payload 1, unsigned refused 1, \
         bad signature 1, unsupported 1, junk bytes 1000, rejected input 5"
    );
}

#[test]
fn required_signing_with_a_link_id_refuses_unsigned_and_forged_frames() {
    let signing = Signing {
        key: SigningKey {
            secret: [7u8; 32],
            link_id: 3,
        },
        require: true,
    };
    let mut rx = Decoder::new(Some(&signing));
    let counters = Counters::default();
    let mut out = Vec::new();
    let mut plain = Encoder::new(255, 190, None);
    rx.push_datagram(&plain.encode(&gcs_heartbeat()), &counters, &mut out);
    assert_eq!(counters.snapshot().refused_unsigned, 1);
    let forger = SigningKey {
        secret: [8u8; 32],
        ..signing.key.clone()
    };
    let mut forged = Encoder::new(255, 190, Some(&forger));
    rx.push_datagram(&forged.encode(&gcs_heartbeat()), &counters, &mut out);
    assert_eq!(counters.snapshot().refused_bad_signature, 1);
    assert!(out.is_empty());
    let mut honest = Encoder::new(255, 190, Some(&signing.key));
    rx.push_datagram(&honest.encode(&gcs_heartbeat()), &counters, &mut out);
    assert_eq!(out.len(), 1);
}

#[test]
fn never_panics_on_random_bytes() {
    // A fixed xorshift stream: every length, every byte value, some start bytes; the same
    // decoder fed as datagrams and as a stream.
    let mut rx = Decoder::new(None);
    let counters = Counters::default();
    let mut out = Vec::new();
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for n in 0..2000 {
        let mut buf = Vec::with_capacity(n % 300);
        for _ in 0..n % 300 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            buf.push(if x.is_multiple_of(17) {
                0xFD
            } else {
                (x >> 24) as u8
            });
        }
        rx.push_datagram(&buf, &counters, &mut out);
        rx.push_stream(&buf, &counters, &mut out);
    }
    assert!(counters.snapshot().garbage_bytes > 0);
}

#[test]
fn key_files_are_raw_or_hex() {
    let hex = "00".repeat(31) + "ff\n";
    let key = SigningKey::from_bytes(hex.as_bytes(), 0).unwrap();
    assert_eq!(key.secret[31], 0xFF);
    assert_eq!(
        SigningKey::from_bytes(&[9u8; 32], 2).unwrap().secret,
        [9u8; 32]
    );
    assert_eq!(SigningKey::from_bytes(&[9u8; 32], 2).unwrap().link_id, 2);
    assert!(SigningKey::from_bytes(b"short", 0).is_err());
}

// ---------------------------------------------------------------- the bridge over UDP

/// A UDP peer standing in for the autopilot, written with the mavlink crate.
struct Peer {
    socket: UdpSocket,
    bridge_addr: Option<std::net::SocketAddr>,
    sequence: u8,
    signing: Option<SigningData>,
}

impl Peer {
    fn new() -> Self {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(20)))
            .unwrap();
        Self {
            socket,
            bridge_addr: None,
            sequence: 0,
            signing: None,
        }
    }

    fn address(&self) -> Address {
        Address::Udp {
            host: "127.0.0.1".into(),
            port: self.socket.local_addr().unwrap().port(),
        }
    }

    /// The next message from the bridge, if one comes within `wait`.
    fn recv(&mut self, wait: Duration) -> Option<MavMessage> {
        let deadline = std::time::Instant::now() + wait;
        let mut buf = [0u8; 512];
        while std::time::Instant::now() < deadline {
            if let Ok((n, from)) = self.socket.recv_from(&mut buf) {
                self.bridge_addr = Some(from);
                if let Ok((_, m)) =
                    MavlinkReader::new(&buf[..n]).read_message::<MavMessage>(MavlinkVersion::V2)
                {
                    return Some(m);
                }
            }
        }
        None
    }

    /// Waits for the bridge's first datagram (its heartbeat) to learn its address.
    fn learn_bridge(&mut self) {
        while self.bridge_addr.is_none() {
            self.recv(Duration::from_millis(100));
        }
    }

    fn send_raw(&self, bytes: &[u8]) {
        self.socket
            .send_to(bytes, self.bridge_addr.unwrap())
            .unwrap();
    }

    fn send(&mut self, m: &MavMessage) {
        let mut bytes = Vec::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        mavlink::write_v2_msg_signed(&mut bytes, header, m, self.signing.as_ref()).unwrap();
        self.send_raw(&bytes);
    }

    fn ack(&mut self, command: MavCmd, result: MavResult) {
        self.send(&MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command,
            result,
            target_system: 1,
            target_component: 191,
            ..COMMAND_ACK_DATA::default()
        }));
    }
}

fn fast_config(address: Address) -> BridgeConfig {
    BridgeConfig {
        command_timeout: Duration::from_millis(60),
        command_retries: 3,
        heartbeat_period: Duration::from_millis(20),
        ..BridgeConfig::new(address)
    }
}

/// Runs `peer_script` on its own thread while the bridge works on this one.
fn with_peer<T: Send + 'static>(
    mut peer: Peer,
    script: impl FnOnce(&mut Peer) -> T + Send + 'static,
) -> std::thread::JoinHandle<T> {
    std::thread::spawn(move || script(&mut peer))
}

fn command_longs(peer: &mut Peer, n: usize, wait: Duration) -> Vec<(MavCmd, u8)> {
    let mut seen = Vec::new();
    let deadline = std::time::Instant::now() + wait;
    while seen.len() < n && std::time::Instant::now() < deadline {
        if let Some(MavMessage::COMMAND_LONG(c)) = peer.recv(Duration::from_millis(50)) {
            seen.push((c.command, c.confirmation));
        }
    }
    seen
}

#[test]
fn a_lost_command_is_retried_with_rising_confirmation_until_acked() {
    let v = vehicle("fa-hexa");
    let peer = Peer::new();
    let mut bridge = Bridge::connect(fast_config(peer.address()), &v).unwrap();
    let script = with_peer(peer, |peer| {
        // Ignore the first two attempts, answer the third.
        let seen = command_longs(peer, 3, Duration::from_secs(5));
        peer.ack(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            MavResult::MAV_RESULT_ACCEPTED,
        );
        seen
    });
    bridge.arm().unwrap();
    let seen = script.join().unwrap();
    assert_eq!(
        seen,
        vec![
            (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 0),
            (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1),
            (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 2),
        ]
    );
}

#[test]
fn an_unanswered_command_times_out_naming_it() {
    let v = vehicle("fa-hexa");
    let peer = Peer::new();
    let mut bridge = Bridge::connect(fast_config(peer.address()), &v).unwrap();
    let script = with_peer(peer, |peer| command_longs(peer, 4, Duration::from_secs(5)));
    let e = bridge.set_offboard().unwrap_err();
    assert_eq!(
        e,
        BridgeError::CommandTimeout {
            what: "switching to offboard".into(),
            command: "MAV_CMD_DO_SET_MODE".into(),
            attempts: 4,
            timeout_ms: 60,
        }
    );
    assert!(
        e.to_string()
            .contains("no COMMAND_ACK for MAV_CMD_DO_SET_MODE"),
        "{e}"
    );
    assert_eq!(script.join().unwrap().len(), 4);
}

#[test]
fn a_refused_arming_names_the_result() {
    let v = vehicle("fa-hexa");
    let peer = Peer::new();
    let mut bridge = Bridge::connect(fast_config(peer.address()), &v).unwrap();
    let script = with_peer(peer, |peer| {
        // An ack for another command first (ignored), then the refusal.
        let seen = command_longs(peer, 1, Duration::from_secs(5));
        peer.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED);
        peer.ack(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            MavResult::MAV_RESULT_DENIED,
        );
        seen
    });
    let e = bridge.arm().unwrap_err();
    assert_eq!(
        e.to_string(),
        "arming refused by the autopilot: MAV_RESULT_DENIED (MAV_CMD_COMPONENT_ARM_DISARM)"
    );
    assert_eq!(script.join().unwrap().len(), 1, "no retry after an answer");
}

fn autopilot_version(capabilities: MavProtocolCapability, custom: [u8; 8]) -> MavMessage {
    MavMessage::AUTOPILOT_VERSION(AUTOPILOT_VERSION_DATA {
        capabilities,
        flight_custom_version: custom,
        ..AUTOPILOT_VERSION_DATA::default()
    })
}

#[test]
fn the_autopilot_version_is_asked_for_and_read() {
    let v = vehicle("fa-hexa");
    // PX4 (current): attitude and position targets, no actuator target; a git hash.
    let px4 = MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
        | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED;
    for (capabilities, custom, actuator, twin) in [
        (px4, *b"\x12\x34\x56\x78\x9a\0\0\0", false, false),
        (
            px4 | CAPABILITY_SET_ACTUATOR_TARGET,
            TWIN_FLIGHT_CUSTOM_VERSION,
            true,
            true,
        ),
    ] {
        let peer = Peer::new();
        let mut bridge = Bridge::connect(fast_config(peer.address()), &v).unwrap();
        let script = with_peer(peer, move |peer| {
            // The request: MAV_CMD_REQUEST_MESSAGE for id 148; ACK, then the message.
            let deadline = std::time::Instant::now() + Duration::from_secs(5);
            while std::time::Instant::now() < deadline {
                if let Some(MavMessage::COMMAND_LONG(c)) = peer.recv(Duration::from_millis(50)) {
                    peer.ack(c.command, MavResult::MAV_RESULT_ACCEPTED);
                    peer.send(&autopilot_version(capabilities, custom));
                    return Some((c.command, c.param1));
                }
            }
            None
        });
        let got = bridge
            .request_autopilot_version(Duration::from_secs(2))
            .unwrap();
        assert_eq!(
            script.join().unwrap(),
            Some((MavCmd::MAV_CMD_REQUEST_MESSAGE, 148.0))
        );
        assert_eq!(got.capabilities, capabilities);
        assert_eq!(got.accepts_actuator_setpoints(), actuator);
        assert_eq!(got.is_amstack_twin(), twin);
        assert_eq!(bridge.autopilot().version, Some(got));
    }
    // An autopilot that acknowledges and never sends it: an error naming the message.
    let peer = Peer::new();
    let mut bridge = Bridge::connect(fast_config(peer.address()), &v).unwrap();
    let script = with_peer(peer, |peer| {
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        while std::time::Instant::now() < deadline {
            if let Some(MavMessage::COMMAND_LONG(c)) = peer.recv(Duration::from_millis(50)) {
                peer.ack(c.command, MavResult::MAV_RESULT_ACCEPTED);
                return;
            }
        }
    });
    let e = bridge
        .request_autopilot_version(Duration::from_millis(200))
        .unwrap_err();
    script.join().unwrap();
    assert_eq!(
        e.to_string(),
        "no AUTOPILOT_VERSION (asked for with MAV_CMD_REQUEST_MESSAGE) from the autopilot within 200 ms"
    );
}

#[test]
fn garbage_into_the_bridge_socket_is_counted_and_telemetry_still_flows() {
    let v = vehicle("fa-hexa");
    let mut peer = Peer::new();
    let bridge = Bridge::connect(fast_config(peer.address()), &v).unwrap();
    peer.learn_bridge();
    let mut frame = Vec::new();
    let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        base_mode: MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
        ..HEARTBEAT_DATA::default()
    });
    mavlink::write_v2_msg(
        &mut frame,
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 9,
        },
        &hb,
    )
    .unwrap();
    for seed in 1..50 {
        peer.send_raw(&noise(seed, 200));
    }
    peer.send_raw(&frame[..frame.len() - 3]); // truncated
    let mut bad = frame.clone();
    bad[11] ^= 0xFF; // bad CRC
    peer.send_raw(&bad);
    let mut unknown = frame.clone();
    unknown[9] = 0x7F; // message id 0x7F0000: not in common
    peer.send_raw(&unknown);
    // Then real telemetry: the link still works.
    peer.send(&hb);
    peer.send(&MavMessage::ODOMETRY(odometry(1_000_000)));
    let m = bridge
        .next_measurement(None, Duration::from_secs(2), "ODOMETRY")
        .unwrap();
    assert_eq!(m.time_s, 1.0);
    assert!(bridge.autopilot().armed);
    assert!(bridge.heartbeat_age().is_some());
    let c = bridge.counters();
    assert!(c.garbage_bytes > 0, "{c:?}");
    assert!(c.truncated >= 1, "{c:?}");
    assert!(c.bad_crc >= 1, "{c:?}");
    assert!(c.unknown_id >= 1, "{c:?}");
    assert!(c.frames_ok >= 2, "{c:?}");
}

#[test]
fn the_capture_hands_over_every_frame_in_and_out_as_it_was_on_the_wire() {
    let v = vehicle("fa-hexa");
    let mut peer = Peer::new();
    let config = BridgeConfig {
        capture_raw: true,
        ..fast_config(peer.address())
    };
    let bridge = Bridge::connect(config, &v).unwrap();
    peer.learn_bridge();
    let encode = |sequence: u8, m: &MavMessage| {
        let mut bytes = Vec::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence,
        };
        mavlink::write_v2_msg(&mut bytes, header, m).unwrap();
        bytes
    };
    let hb = encode(
        4,
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            base_mode: MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
            ..HEARTBEAT_DATA::default()
        }),
    );
    let odo = encode(5, &MavMessage::ODOMETRY(odometry(2_500_000)));
    let mut bad = odo.clone();
    bad[12] ^= 0x55; // bad CRC: refused, not captured
    // Garbage, a refused frame, then both frames glued in one datagram.
    peer.send_raw(&noise(3, 50));
    peer.send_raw(&bad);
    peer.send_raw(&[&[0x01, 0x02][..], &hb, &odo].concat());
    bridge
        .next_measurement(None, Duration::from_secs(2), "ODOMETRY")
        .unwrap();
    // Drained at once, the frames that made the measurement are there already.
    let mut raw = Vec::new();
    bridge.drain_raw(&mut raw);
    assert!(
        raw.iter().any(|f| f.bytes == odo),
        "the ODOMETRY is queued before its measurement is handed over: {raw:?}"
    );
    std::thread::sleep(Duration::from_millis(60)); // a few of our heartbeats
    bridge.drain_raw(&mut raw);
    let ins: Vec<&RawFrame> = raw
        .iter()
        .filter(|f| f.direction == Direction::In)
        .collect();
    assert_eq!(ins.len(), 2, "{raw:?}");
    assert_eq!(ins[0].bytes, hb);
    assert_eq!(ins[1].bytes, odo);
    assert_eq!(
        (ins[1].message_id, ins[1].message_name, ins[1].sequence),
        (331, "ODOMETRY", 5)
    );
    // The heartbeat came before the first ODOMETRY; the ODOMETRY carries its own time.
    assert_eq!((ins[0].flight_time_s, ins[1].flight_time_s), (0.0, 2.5));
    let outs: Vec<&RawFrame> = raw
        .iter()
        .filter(|f| f.direction == Direction::Out)
        .collect();
    assert!(outs.len() >= 2, "{raw:?}");
    for f in &outs {
        let (header, m) = MavlinkReader::new(&f.bytes[..])
            .read_message::<MavMessage>(MavlinkVersion::V2)
            .unwrap();
        assert!(matches!(m, MavMessage::HEARTBEAT(_)), "{m:?}");
        assert_eq!((header.system_id, header.component_id), (1, 191));
        assert_eq!((f.system_id, f.component_id), (1, 191));
    }
    let stats = bridge.capture_stats().unwrap();
    assert_eq!(stats.dropped, 0);
    assert_eq!(stats.captured, raw.len() as u64);
    assert_eq!(bridge.counters().bad_crc, 1);
    // Off by default.
    let plain = Bridge::connect(fast_config(Peer::new().address()), &v).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(plain.drain_raw(&mut raw), 0);
    assert_eq!(plain.capture_stats(), None);
}

#[test]
fn a_signing_bridge_refuses_unsigned_telemetry_and_takes_signed() {
    let v = vehicle("fa-hexa");
    let mut peer = Peer::new();
    let config = BridgeConfig {
        signing: Some(Signing {
            key: key(5),
            require: true,
        }),
        ..fast_config(peer.address())
    };
    let bridge = Bridge::connect(config, &v).unwrap();
    peer.learn_bridge();
    peer.send(&MavMessage::ODOMETRY(odometry(1_000_000)));
    let e = bridge
        .next_measurement(None, Duration::from_millis(200), "ODOMETRY")
        .unwrap_err();
    assert!(matches!(e, BridgeError::NoTelemetry { .. }), "{e}");
    assert_eq!(bridge.counters().refused_unsigned, 1);
    peer.signing = Some(SigningData::from_config(SigningConfig::new(
        [5; 32], 0, true, false,
    )));
    peer.send(&MavMessage::ODOMETRY(odometry(2_000_000)));
    let m = bridge
        .next_measurement(None, Duration::from_secs(2), "ODOMETRY")
        .unwrap();
    assert_eq!(m.time_s, 2.0);
    // The bridge's own frames are signed: the peer's mavlink reader sees the flag.
    let mut buf = [0u8; 512];
    let (n, _) = loop {
        if let Ok(x) = peer.socket.recv_from(&mut buf) {
            break x;
        }
    };
    assert_eq!(buf[2] & 0x01, 0x01, "signed flag");
    assert!(n > 13);
}

// ---------------------------------------------------------------- TCP and serial

/// An autopilot on a byte stream: once it hears the bridge's HEARTBEAT it sends one
/// ODOMETRY; it answers ARM with ACCEPTED and then returns what it heard.
async fn stream_peer<S>(mut stream: S) -> Vec<MavMessage>
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let counters = Counters::default();
    let mut decoder = Decoder::new(None);
    let mut heard = Vec::new();
    let mut buf = [0u8; 1024];
    let mut sent_odometry = false;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let n = match tokio::time::timeout_at(deadline, stream.read(&mut buf)).await {
            Ok(Ok(n)) if n > 0 => n,
            // A pseudo-terminal reads 0 bytes while its other end is between writes.
            Ok(Ok(_)) => {
                tokio::time::sleep(Duration::from_millis(1)).await;
                continue;
            }
            _ => return heard,
        };
        let mut frames = Vec::new();
        decoder.push_stream(&buf[..n], &counters, &mut frames);
        for f in frames {
            let reply = match &f.message {
                MavMessage::HEARTBEAT(_) if !sent_odometry => {
                    sent_odometry = true;
                    Some(MavMessage::ODOMETRY(odometry(3_000_000)))
                }
                MavMessage::COMMAND_LONG(c) => Some(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                    command: c.command,
                    result: MavResult::MAV_RESULT_ACCEPTED,
                    ..COMMAND_ACK_DATA::default()
                })),
                _ => None,
            };
            let done = matches!(f.message, MavMessage::COMMAND_LONG(_));
            heard.push(f.message);
            if let Some(m) = reply {
                let mut bytes = Vec::new();
                let header = MavHeader {
                    system_id: 1,
                    component_id: 1,
                    sequence: 0,
                };
                mavlink::write_v2_msg(&mut bytes, header, &m).unwrap();
                stream.write_all(&bytes).await.unwrap();
            }
            if done {
                // Keep the stream open a moment: a pseudo-terminal whose master closes
                // discards what its slave has not read yet (the ack).
                tokio::time::sleep(Duration::from_millis(300)).await;
                return heard;
            }
        }
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

fn fly_the_peer(config: BridgeConfig, peer: std::thread::JoinHandle<Vec<MavMessage>>) {
    let v = vehicle("fa-hexa");
    let mut bridge = Bridge::connect(config, &v).unwrap();
    let m = bridge
        .next_measurement(None, Duration::from_secs(5), "ODOMETRY")
        .unwrap();
    assert_eq!(m.time_s, 3.0);
    assert_eq!(m.base.position_in_world_m, Vector3::new(2.0, 1.0, 3.0));
    bridge.arm().unwrap();
    let heard = peer.join().unwrap();
    assert!(heard.iter().any(|m| matches!(m, MavMessage::HEARTBEAT(h)
        if h.mavtype == MavType::MAV_TYPE_ONBOARD_CONTROLLER)));
    assert!(heard.iter().any(|m| matches!(m, MavMessage::COMMAND_LONG(c)
        if c.command == MavCmd::MAV_CMD_COMPONENT_ARM_DISARM && c.param1 == 1.0)));
}

#[test]
fn the_bridge_works_over_tcp() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let peer = std::thread::spawn(move || {
        let (stream, _) = listener.accept().unwrap();
        stream.set_nonblocking(true).unwrap();
        runtime()
            .block_on(async { stream_peer(tokio::net::TcpStream::from_std(stream).unwrap()).await })
    });
    let address = Address::Tcp {
        host: "127.0.0.1".into(),
        port,
    };
    fly_the_peer(fast_config(address), peer);
}

#[test]
fn the_bridge_works_over_a_pseudo_terminal_pair() {
    use tokio_serial::SerialPort;
    let (name_tx, name_rx) = std::sync::mpsc::channel();
    let peer = std::thread::spawn(move || {
        runtime().block_on(async {
            let (master, slave) = tokio_serial::SerialStream::pair().unwrap();
            name_tx.send(slave.name().unwrap()).unwrap();
            let heard = stream_peer(master).await;
            drop(slave);
            heard
        })
    });
    let device = name_rx.recv().unwrap();
    let address = Address::parse(&format!("serial:{device}:921600")).unwrap();
    fly_the_peer(fast_config(address), peer);
}

// ---------------------------------------------------------------- setpoints received

#[test]
fn received_motor_commands_follow_the_thrust_curve_and_bad_ones_are_refused() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let curve = v.rotors.thrust_curve;
    let mut q = v.initial_configuration();
    let controls = [0.0, 0.25, 0.5, 0.75, 1.0, 0.5, 0.0, 0.0];
    let Ok(ActuatorUpdate::Motors(t)) = codec.decode_actuator(&target(0, controls), &mut q) else {
        panic!("group 0 completes a tick");
    };
    assert_eq!(t.len(), 6);
    assert!((t[0] - curve.thrust_min_n).abs() < 1e-12);
    assert!((t[4] - curve.thrust_max_n).abs() < 1e-12);
    // Round trip through the inverse curve.
    assert!((curve.command(t[2]) - 0.5).abs() < 1e-6);
    assert!(codec.decode_actuator(&target(0, [1.5; 8]), &mut q).is_err());
    assert!(
        codec
            .decode_actuator(&target(0, [f32::NAN; 8]), &mut q)
            .is_err()
    );
}

#[test]
fn received_arm_and_gripper_controls_are_linear_over_their_limits() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    let mut q = v.initial_configuration();
    // Arm joint 0 at −1 → its lower limit, joint 1 at +1 → its upper limit, the gripper
    // (after the arm's joints) at +1 → open.
    let n = v.arm_joints.len();
    let mut controls = [0.0f32; 8];
    controls[0] = -1.0;
    controls[1] = 1.0;
    controls[n] = 1.0;
    assert_eq!(
        codec.decode_actuator(&target(2, controls), &mut q),
        Ok(ActuatorUpdate::Joints)
    );
    let j0 = &v.model.joints[v.arm_joints[0]];
    let j1 = &v.model.joints[v.arm_joints[1]];
    assert!((q[j0.dof.unwrap()] - j0.limits.unwrap().lower).abs() < 1e-9);
    assert!((q[j1.dof.unwrap()] - j1.limits.unwrap().upper).abs() < 1e-9);
    let g = v.gripper.as_ref().unwrap();
    for (k, &j) in g.joints.iter().enumerate() {
        assert!((q[v.model.joints[j].dof.unwrap()] - g.open[k]).abs() < 1e-9);
    }
    // Out of range: refused whole, the targets untouched.
    let before = q.clone();
    controls[0] = 1.5;
    assert!(codec.decode_actuator(&target(2, controls), &mut q).is_err());
    assert_eq!(q, before);
    // The FA-Hexa has no tilt servos: group 1 is refused.
    assert!(codec.decode_actuator(&target(1, [0.0; 8]), &mut q).is_err());
}

#[test]
fn received_omni_hexa_tilts_use_group_1() {
    let v = vehicle("omni-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    assert!(codec.has_tilt());
    let mut q = v.initial_configuration();
    codec.decode_actuator(&target(1, [1.0; 8]), &mut q).unwrap();
    let t = v.rotors.rotors[0].tilt.as_ref().unwrap();
    let dof = v.model.joints[v.model.joint_id(&t.joint).unwrap()]
        .dof
        .unwrap();
    assert!((q[dof] - t.limits_rad.1).abs() < 1e-9);
}

#[test]
fn a_received_attitude_target_converts_frames() {
    let v = vehicle("fa-hexa");
    let codec = SetpointCodec::new(&v, 1, 1).unwrap();
    // PX4 level, facing north (identity NED←FRD) = amstack yaw +90°; thrust straight up
    // (FRD −z) at 0.5 of the vehicle's total → FLU +z.
    let data = SET_ATTITUDE_TARGET_DATA {
        time_boot_ms: 0,
        q: [1.0, 0.0, 0.0, 0.0],
        body_roll_rate: 0.1,
        body_pitch_rate: 0.0,
        body_yaw_rate: 0.0,
        thrust: 0.0,
        target_system: 1,
        target_component: 1,
        type_mask: AttitudeTargetTypemask::empty(),
        thrust_body: [0.0, 0.0, -0.5],
    };
    let sp = codec.decode_attitude(&data).unwrap();
    let north = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    assert!(sp.world_from_body.angle_to(&north) < 1e-6);
    let total = 6.0 * v.rotors.thrust_max_n;
    assert!((sp.force_in_body_n - Vector3::new(0.0, 0.0, 0.5 * total)).norm() < 1e-6);
    let rates = sp.body_rates_radps.unwrap();
    assert!((rates - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-6);
    let bad = SET_ATTITUDE_TARGET_DATA {
        q: [0.0; 4],
        ..data.clone()
    };
    assert!(codec.decode_attitude(&bad).is_err());
    // Without thrust_body, the collective thrust pushes along body up.
    let collective = SET_ATTITUDE_TARGET_DATA {
        thrust: 0.25,
        thrust_body: [0.0; 3],
        ..data.clone()
    };
    let sp = codec.decode_attitude(&collective).unwrap();
    assert!((sp.force_in_body_n - Vector3::new(0.0, 0.0, 0.25 * total)).norm() < 1e-6);
    // What the codec sends, it reads back.
    let sent = AttitudeSetpoint {
        world_from_body: UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        force_in_body_n: Vector3::new(1.0, -2.0, 60.0),
        body_rates_radps: Some(Vector3::new(0.3, 0.0, -0.1)),
    };
    let msgs = codec
        .attitude_messages(0, &hover_command(&v, 0.0), &sent)
        .unwrap();
    let Some(MavMessage::SET_ATTITUDE_TARGET(d)) = msgs.last() else {
        panic!("attitude target last");
    };
    let back = codec.decode_attitude(d).unwrap();
    assert!(back.world_from_body.angle_to(&sent.world_from_body) < 1e-6);
    assert!((back.force_in_body_n - sent.force_in_body_n).norm() < 1e-4);
    assert!((back.body_rates_radps.unwrap() - Vector3::new(0.3, 0.0, -0.1)).norm() < 1e-6);
}
