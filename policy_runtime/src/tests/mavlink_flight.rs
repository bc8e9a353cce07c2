//! [`MavlinkLink`] flown end to end over real UDP against a test fixture: a minimal lockstep
//! autopilot wrapping the in-process twin, written with the mavlink crate. It keeps only
//! what the contract needs for the actuator level (OFFBOARD refused before setpoints stream,
//! ARM, group decoding, one twin step per group-0 setpoint while armed in offboard, the
//! per-step telemetry with ODOMETRY last, idle telemetry at 10 Hz). The twin's real
//! autopilot (`amstack twin serve --mavlink`) is tested in `tests/tests/mavlink.rs`.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use controllers::{ControllerKind, profile};
use firmware_bridge::{ActuatorUpdate, Address, BridgeConfig, SetpointCodec, frames};
use mavlink::dialects::common::{
    COMMAND_ACK_DATA, HEARTBEAT_DATA, MavCmd, MavMessage, MavModeFlag, MavResult,
};
use mavlink::{MavHeader, MavlinkReader, MavlinkVersion};
use nalgebra::{UnitQuaternion, Vector3};
use platform::{ActuatorCommand, Measurement, Vehicle};
use sim_twin::{Twin, TwinConfig};
use twin_autopilot::telemetry;

use crate::link::{Setpoint, SetpointLevel};
use crate::mavlink_link::{Level, MavlinkLink, MavlinkLinkConfig};
use crate::track::{Interface, TrackConfig, run_track, run_track_with_link};
use crate::trajectory::Trajectory;

struct Fixture {
    port: u16,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<u64>>,
}

impl Drop for Fixture {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

struct Autopilot {
    socket: UdpSocket,
    peer: Option<SocketAddr>,
    sequence: u8,
    twin: Twin,
    codec: SetpointCodec,
    command: ActuatorCommand,
    streaming: bool,
    offboard: bool,
    armed: bool,
    steps: u64,
    /// Disarm after this many steps (a failsafe, say), announcing it in a HEARTBEAT.
    disarm_after: Option<u64>,
    /// The base at the last telemetry (the IMU's period start).
    previous_base: platform::RigidBodyState,
    /// Whether AUTOPILOT_VERSION declares SET_ACTUATOR_TARGET.
    actuator_extension: bool,
}

impl Autopilot {
    fn send(&mut self, m: &MavMessage) {
        let Some(peer) = self.peer else { return };
        let mut bytes = Vec::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        mavlink::write_v2_msg(&mut bytes, header, m).unwrap();
        let _ = self.socket.send_to(&bytes, peer);
    }

    /// The contract's per-step telemetry of `m`, as the twin's autopilot sends it.
    fn telemetry(&mut self, m: &Measurement) {
        let dt_s = 1.0 / self.twin.config().control_rate_hz;
        let imu = telemetry::imu(&self.previous_base, m, dt_s);
        self.previous_base = m.base;
        for message in telemetry::per_step(m, &imu) {
            self.send(&message);
        }
    }

    fn heartbeat(&self) -> MavMessage {
        let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if self.armed {
            base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
        }
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: if self.offboard { 6 << 16 } else { 0 },
            base_mode,
            ..HEARTBEAT_DATA::default()
        })
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

    fn handle(&mut self, m: &MavMessage) {
        match m {
            MavMessage::COMMAND_LONG(c) => match c.command {
                MavCmd::MAV_CMD_DO_SET_MODE if c.param2 == 6.0 => {
                    if self.streaming {
                        self.offboard = true;
                        self.ack(c.command, MavResult::MAV_RESULT_ACCEPTED);
                        // The new mode goes out at once (the idle heartbeats stop once armed
                        // in offboard: a client arming within one 100 ms idle period would
                        // otherwise never hear it; seen on a loaded machine).
                        let hb = self.heartbeat();
                        self.send(&hb);
                    } else {
                        self.ack(c.command, MavResult::MAV_RESULT_TEMPORARILY_REJECTED);
                    }
                }
                MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => {
                    self.armed = c.param1 == 1.0;
                    self.ack(c.command, MavResult::MAV_RESULT_ACCEPTED);
                    let hb = self.heartbeat();
                    self.send(&hb);
                }
                // AUTOPILOT_VERSION, as the twin's autopilot answers it (with or without the
                // actuator extension).
                MavCmd::MAV_CMD_REQUEST_MESSAGE if c.param1 == 148.0 => {
                    self.ack(c.command, MavResult::MAV_RESULT_ACCEPTED);
                    let version = telemetry::autopilot_version(self.actuator_extension);
                    self.send(&version);
                }
                other => self.ack(other, MavResult::MAV_RESULT_UNSUPPORTED),
            },
            MavMessage::SET_ACTUATOR_CONTROL_TARGET(s) => {
                let update = self
                    .codec
                    .decode_actuator(s, &mut self.command.joint_targets);
                if let Ok(ActuatorUpdate::Motors(thrusts)) = update {
                    self.command.rotor_thrusts_n = thrusts;
                    self.streaming = true;
                    if self.armed && self.offboard {
                        let command = self.command.clone();
                        let m = self.twin.step(&command).unwrap();
                        self.steps += 1;
                        if self.disarm_after == Some(self.steps) {
                            self.armed = false;
                            let hb = self.heartbeat();
                            self.send(&hb);
                            return; // this tick is never answered
                        }
                        self.telemetry(&m);
                    }
                }
            }
            _ => {}
        }
    }
}

fn fixture(vehicle: &Vehicle, config: &TwinConfig, disarm_after: Option<u64>) -> Fixture {
    fixture_declaring(vehicle, config, disarm_after, true)
}

/// The fixture, its AUTOPILOT_VERSION declaring the actuator extension or not.
fn fixture_declaring(
    vehicle: &Vehicle,
    config: &TwinConfig,
    disarm_after: Option<u64>,
    actuator_extension: bool,
) -> Fixture {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let port = socket.local_addr().unwrap().port();
    let stop = Arc::new(AtomicBool::new(false));
    let mut ap = Autopilot {
        socket,
        peer: None,
        sequence: 0,
        twin: Twin::new(vehicle.clone(), config.clone()).unwrap(),
        codec: SetpointCodec::new(vehicle, 1, 1).unwrap(),
        command: ActuatorCommand {
            rotor_thrusts_n: vec![0.0; vehicle.rotors.len()],
            joint_targets: vehicle.initial_configuration(),
            direct_wrench_in_body: None,
        },
        streaming: false,
        offboard: false,
        armed: false,
        steps: 0,
        disarm_after,
        previous_base: platform::RigidBodyState::default(),
        actuator_extension,
    };
    let flag = stop.clone();
    let thread = std::thread::spawn(move || {
        let mut buf = [0u8; 2048];
        let mut idle = Instant::now();
        while !flag.load(Ordering::SeqCst) {
            if let Ok((n, from)) = ap.socket.recv_from(&mut buf) {
                ap.peer = Some(from);
                let mut reader = MavlinkReader::new(&buf[..n]);
                while let Ok((_, m)) = reader.read_message::<MavMessage>(MavlinkVersion::V2) {
                    ap.handle(&m);
                }
            }
            // Idle telemetry at 10 Hz while not stepping, with a heartbeat.
            if !(ap.armed && ap.offboard) && idle.elapsed() >= Duration::from_millis(100) {
                idle = Instant::now();
                let hb = ap.heartbeat();
                ap.send(&hb);
                let m = ap.twin.truth().clone();
                ap.telemetry(&m);
            }
        }
        ap.steps
    });
    Fixture {
        port,
        stop,
        thread: Some(thread),
    }
}

fn track_config(vehicle: &Vehicle, trajectory: Trajectory, duration_s: f64) -> TrackConfig {
    TrackConfig {
        live: None,
        cameras: None,
        vehicle: vehicle.clone(),
        controller: profile(vehicle, ControllerKind::Pid).unwrap(),
        trajectory,
        interface: Interface::BaseJoint,
        duration_s,
        settle_s: 0.5,
        // Rotor limits on: the wire's normalised command u ∈ [0, 1] cannot carry the ideal
        // rotors' negative or above-maximum thrusts.
        twin: TwinConfig {
            disturbances: sim_twin::Disturbances::parse_list("saturation").unwrap(),
            ..TwinConfig::default()
        },
        mcap: None,
        state_source: crate::StateSource::Truth,
        clock: None,
    }
}

#[test]
fn a_step_flown_over_mavlink_in_lockstep_matches_the_in_process_flight() {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let config = track_config(&vehicle, Trajectory::Step, 2.0);
    let fixture = fixture(&vehicle, &config.twin, None);
    let address = Address::Udp {
        host: "127.0.0.1".into(),
        port: fixture.port,
    };
    let mut link = MavlinkLink::connect(
        &vehicle,
        MavlinkLinkConfig {
            tick_timeout: Duration::from_secs(5),
            ..MavlinkLinkConfig::new(BridgeConfig::new(address), Level::Actuator)
        },
    )
    .unwrap();
    let over_link =
        run_track_with_link(&config, &mut link, |_| std::ops::ControlFlow::Continue(())).unwrap();
    let in_process = run_track(&config, |_| std::ops::ControlFlow::Continue(())).unwrap();
    let counters = link.counters();
    drop(link);
    drop(fixture);
    assert_eq!(over_link.ticks, in_process.ticks);
    // The wire carries f32 (states and commands): the flights agree to within 10 µm of RMS
    // error (measured: 6e-9 m) while the step itself is a metre.
    for (name, a, b) in [
        ("ee", over_link.ee_pos_rmse_m, in_process.ee_pos_rmse_m),
        (
            "base",
            over_link.base_pos_rmse_m,
            in_process.base_pos_rmse_m,
        ),
        ("base z", over_link.base_z_rmse_m, in_process.base_z_rmse_m),
    ] {
        assert!(
            (a - b).abs() < 1e-5,
            "{name}: {a} over MAVLink vs {b} in process"
        );
    }
    assert!(
        in_process.base_pos_rmse_m > 0.05,
        "the step moved the vehicle"
    );
    assert_eq!(
        counters.bad_crc + counters.unknown_id + counters.truncated,
        0
    );
}

/// Decodes lower-case hex.
fn from_hex(text: &str) -> Vec<u8> {
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).unwrap())
        .collect()
}

#[test]
fn a_logged_flight_holds_the_autopilot_state_and_every_frame_an_independent_reader_decodes() {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mavlink.mcap");
    let config = TrackConfig {
        live: None,
        cameras: None,
        mcap: Some(path.clone()),
        settle_s: 0.0,
        ..track_config(&vehicle, Trajectory::Step, 0.5)
    };
    let fixture = fixture(&vehicle, &config.twin, None);
    let address = Address::Udp {
        host: "127.0.0.1".into(),
        port: fixture.port,
    };
    let link_config = MavlinkLinkConfig {
        tick_timeout: Duration::from_secs(5),
        ..MavlinkLinkConfig::new(
            BridgeConfig {
                capture_raw: true,
                ..BridgeConfig::new(address)
            },
            Level::Actuator,
        )
    };
    let stream_count = u64::from(link_config.stream_count);
    let mut link = MavlinkLink::connect(&vehicle, link_config).unwrap();
    let result =
        run_track_with_link(&config, &mut link, |_| std::ops::ControlFlow::Continue(())).unwrap();
    drop(link);
    drop(fixture);
    let ticks = result.ticks;
    assert_eq!(ticks, 60);

    // Read back with the mcap crate and parse the frames with the mavlink crate.
    let bytes = std::fs::read(&path).unwrap();
    let mut states = Vec::new();
    let mut raw = Vec::new();
    let mut base_states = std::collections::BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.message_encoding == "protobuf" {
            // The 3D scene (Foxglove SDK types): not what this test reads.
            assert!(
                m.channel.topic.starts_with("/scene/"),
                "{}",
                m.channel.topic
            );
            continue;
        }
        let value: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        let schema = m.channel.schema.as_ref().map(|s| s.name.clone());
        match m.channel.topic.as_str() {
            "/autopilot/state" => {
                assert_eq!(schema.as_deref(), Some("amstack.AutopilotState"));
                states.push((m.log_time, value));
            }
            "/mavlink/raw" => {
                assert_eq!(schema.as_deref(), Some("amstack.MavlinkRaw"));
                assert_eq!(m.channel.message_encoding, "json");
                raw.push((m.log_time, value));
            }
            "/base/state" => {
                base_states.insert(m.log_time, value);
            }
            _ => {}
        }
    }
    // One state per measurement: the start, then one per tick, at the measurement times.
    assert_eq!(states.len() as u64, ticks + 1);
    let times: Vec<u64> = states.iter().map(|(t, _)| *t).collect();
    // (The autopilot's time_usec: whole microseconds.)
    let expected: Vec<u64> = (0..=ticks)
        .map(|k| (k as f64 / 120.0 * 1e6).round() as u64 * 1000)
        .collect();
    assert_eq!(times, expected);
    let (_, last) = states.last().unwrap();
    assert_eq!(last["mode"], "OFFBOARD", "{last}");
    assert_eq!(last["main_mode"], 6, "{last}");
    assert_eq!(last["link"]["bad_crc"], 0, "{last}");
    assert_eq!(last["link"]["raw_frames_dropped"], 0, "{last}");
    // Every captured frame is on /mavlink/raw by the end.
    assert_eq!(
        last["link"]["raw_frames_captured"].as_u64().unwrap(),
        raw.len() as u64
    );

    let mut odometry_in_flight = 0;
    let mut checked = 0;
    let mut group0_out = 0;
    for (log_time, r) in &raw {
        let frame = from_hex(r["bytes_hex"].as_str().unwrap());
        let (header, message) = MavlinkReader::new(&frame[..])
            .read_message::<MavMessage>(MavlinkVersion::V2)
            .unwrap();
        assert_eq!(r["message_id"], mavlink::Message::message_id(&message));
        assert_eq!(r["sequence"], header.sequence);
        assert_eq!(
            *log_time,
            (r["flight_time_s"].as_f64().unwrap() * 1e9).round() as u64
        );
        match (r["direction"].as_str().unwrap(), &message) {
            ("in", MavMessage::ODOMETRY(o)) => {
                assert_eq!((header.system_id, header.component_id), (1, 1));
                // Its flight time is its own; the measurement logged at that time came from it.
                let t = o.time_usec as f64 * 1e-6;
                assert_eq!(r["flight_time_s"].as_f64().unwrap(), t);
                if t > 0.0 {
                    odometry_in_flight += 1;
                }
                if let Some(state) = base_states.get(log_time) {
                    let p = frames::world_from_ned(&Vector3::new(
                        f64::from(o.x),
                        f64::from(o.y),
                        f64::from(o.z),
                    ));
                    let logged: Vec<f64> = state["position_m"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|x| x.as_f64().unwrap())
                        .collect();
                    assert_eq!(logged, [p.x, p.y, p.z], "at {log_time} ns");
                    checked += 1;
                }
            }
            ("out", MavMessage::SET_ACTUATOR_CONTROL_TARGET(s)) => {
                assert_eq!((header.system_id, header.component_id), (1, 191));
                if s.group_mlx == 0 {
                    group0_out += 1;
                }
            }
            _ => {}
        }
    }
    // Lockstep: one ODOMETRY per step; one group-0 setpoint per tick plus the start's stream.
    assert_eq!(odometry_in_flight, ticks);
    assert_eq!(group0_out, ticks + stream_count);
    assert!(checked as u64 > ticks, "{checked} ODOMETRY frames checked");

    // compare's signal paths reach the new channel's numbers.
    let recording = crate::record::Recording::from_bytes(&bytes).unwrap();
    let frames_ok = crate::validation::signals::resolve(
        &recording,
        "mavlink.mcap",
        "/autopilot/state.link.frames_ok",
    )
    .unwrap();
    let series =
        crate::validation::signals::extract(&recording, "mavlink.mcap", &frames_ok[0]).unwrap();
    assert_eq!(series.values.len() as u64, ticks + 1);
    assert!(series.values.windows(2).all(|w| w[0] <= w[1]));
    let imu = crate::validation::signals::resolve(
        &recording,
        "mavlink.mcap",
        "/autopilot/state.imu_accel_body_mps2",
    )
    .unwrap();
    assert_eq!(
        imu.len(),
        3,
        "null until a HIGHRES_IMU, still three signals"
    );
    assert_eq!(crate::validation::signals::unit_of(&imu[0]), "m/s²");
}

#[test]
fn an_autopilot_that_disarms_mid_flight_stops_it_naming_why() {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let config = track_config(&vehicle, Trajectory::Hover, 2.0);
    let fixture = fixture(&vehicle, &config.twin, Some(50));
    let address = Address::Udp {
        host: "127.0.0.1".into(),
        port: fixture.port,
    };
    let mut link = MavlinkLink::connect(
        &vehicle,
        MavlinkLinkConfig {
            tick_timeout: Duration::from_millis(300),
            ..MavlinkLinkConfig::new(BridgeConfig::new(address), Level::Actuator)
        },
    )
    .unwrap();
    let e = run_track_with_link(&config, &mut link, |_| std::ops::ControlFlow::Continue(()))
        .unwrap_err();
    let e = e.to_string();
    assert!(
        e.starts_with("the autopilot disarmed during the flight (tick 5")
            && e.ends_with("now OFFBOARD, disarmed; the flight stack stopped sending"),
        "{e}"
    );
}

#[test]
fn the_attitude_level_sends_the_controllers_own_cascade() {
    // The PID6 steers to the target's attitude: the attitude setpoint is that R_d itself (no
    // re-derivation from the attitude error), with the body force the allocation produces.
    let r_d = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
    let r = r_d * UnitQuaternion::from_scaled_axis(Vector3::x() * 0.3);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut stack = crate::stack::FlightStack::new(
        vehicle.clone(),
        &profile(&vehicle, ControllerKind::Pid).unwrap(),
        allocation::AllocationMethod::PseudoInverse,
        crate::stack::ThrustLimits::Enforced,
        0.004,
    )
    .unwrap();
    let m = Measurement {
        base: platform::RigidBodyState {
            world_from_body: r,
            angular_velocity_in_body_radps: Vector3::new(0.5, 0.0, 0.0),
            ..platform::RigidBodyState::default()
        },
        joint_positions: vehicle.initial_configuration(),
        joint_velocities: vec![0.0; vehicle.model.dof()],
        ..Measurement::default()
    };
    let mut record = stack.act(
        &m,
        &crate::stack::Action::BaseJoint(crate::stack::BaseJointTarget {
            world_from_base: nalgebra::Isometry3::from_parts(Default::default(), r_d),
            arm_joints: vec![0.0; vehicle.arm_dof()],
            gripper: 0.0,
        }),
    );
    let target = record.controller.attitude_target.unwrap();
    assert!(target.world_from_body.angle_to(&r_d) < 1e-9);
    let Setpoint::Attitude { attitude, command } =
        record.setpoint(SetpointLevel::Attitude).unwrap()
    else {
        panic!("an attitude setpoint");
    };
    assert_eq!(command, record.command);
    assert_eq!(attitude.world_from_body, target.world_from_body);
    assert_eq!(attitude.body_rates_radps, Some(target.body_rates_radps));
    assert_eq!(
        attitude.force_in_body_n,
        record.wrench.force - record.unallocated.force
    );
    // The position level: the base target handed to the controller, position and heading.
    let Setpoint::Position { position, command } =
        record.setpoint(SetpointLevel::Position).unwrap()
    else {
        panic!("a position setpoint");
    };
    assert_eq!(command, record.command);
    assert_eq!(
        position.position_in_world_m,
        record.base_target.translation.vector
    );
    assert!(
        (position.yaw_rad - 0.7).abs() < 1e-12,
        "{}",
        position.yaw_rad
    );
    // The rate level: the same cascade through the attitude law, Ω_ff − K ⊙ e_R, with
    // e_R = sin 0.3 x̂ (R = R_d · exp(0.3 x̂)).
    let Setpoint::Rates { rates, .. } = record.setpoint(SetpointLevel::Rates).unwrap() else {
        panic!("a rate setpoint");
    };
    let e_r = record.controller.attitude_error;
    assert!(
        (e_r - Vector3::new(0.3f64.sin(), 0.0, 0.0)).norm() < 1e-9,
        "{e_r}"
    );
    let expected = target.body_rates_radps
        - Vector3::from(controllers::PX4_ATTITUDE_P_PER_S).component_mul(&e_r);
    assert!((rates.body_rates_radps - expected).norm() < 1e-12);
    assert_eq!(rates.force_in_body_n, attitude.force_in_body_n);
    // A tick with no attitude loop behind it (the whole-body MPC's) is refused by name.
    record.attitude = None;
    record.controller.controller = "mpc";
    let e = record.setpoint(SetpointLevel::Attitude).unwrap_err();
    assert!(
        e.to_string()
            .contains("mpc controller has no attitude loop"),
        "{e}"
    );
    assert!(record.setpoint(SetpointLevel::Rates).is_err());
}

#[test]
fn the_actuator_level_needs_an_autopilot_that_declares_it() {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let config = track_config(&vehicle, Trajectory::Hover, 1.0);
    for declared in [false, true] {
        let fixture = fixture_declaring(&vehicle, &config.twin, None, declared);
        let address = Address::Udp {
            host: "127.0.0.1".into(),
            port: fixture.port,
        };
        let link = MavlinkLink::connect(
            &vehicle,
            MavlinkLinkConfig::new(BridgeConfig::new(address), Level::Actuator),
        );
        match (declared, link) {
            (true, Ok(link)) => {
                let version = link.autopilot_version().unwrap();
                assert!(version.accepts_actuator_setpoints());
                // The fixture answers as the twin's autopilot: the arm channel is on.
                assert!(version.is_amstack_twin());
                assert!(link.arm_channel());
            }
            (false, Err(crate::LinkError::Refused(e))) => assert!(
                e.starts_with(
                    "the actuator level needs an autopilot that declares \
                     MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET in its AUTOPILOT_VERSION; this \
                     one does not"
                ),
                "{e}"
            ),
            (d, other) => panic!("declared {d}: {other:?}"),
        }
        drop(fixture);
    }
}
