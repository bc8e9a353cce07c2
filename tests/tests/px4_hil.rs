//! The twin as PX4's simulator (`amstack twin serve --px4-hil tcp:…`) against a PX4-protocol
//! stand-in written here with the `mavlink` crate: it connects as PX4's `simulator_mavlink`
//! does (TCP, a HEARTBEAT first), reads HIL_SENSOR and HIL_GPS, estimates its state from them
//! (a complementary attitude filter on gyro, accelerometer and magnetometer; position from
//! the accelerometer, barometer and GNSS — never the ground truth), flies a position and
//! attitude loop through the FA-Hexa's rotors and answers every HIL_SENSOR with one
//! HIL_ACTUATOR_CONTROLS (lockstep flag, armed). HIL_STATE_QUATERNION (ground truth) is read
//! only to judge the flight.
//!
//! The `amstack` binary is the one cargo builds for the root package's CLI test
//! (`cargo test --workspace`); alone, run `cargo build --bin amstack` first.

#![allow(clippy::unwrap_used, clippy::expect_used, reason = "tests")]

use std::io::{ErrorKind, Read};
use std::net::TcpStream;
use std::path::Path;
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use mavlink::dialects::common::{
    HEARTBEAT_DATA, HIL_ACTUATOR_CONTROLS_DATA, HIL_GPS_DATA, HIL_SENSOR_DATA,
    HIL_STATE_QUATERNION_DATA, HilActuatorControlsFlags, MavAutopilot, MavMessage, MavModeFlag,
    MavState, MavType,
};
use mavlink::{MavHeader, MavlinkReader, MavlinkVersion};
use nalgebra::{DMatrix, DVector, Matrix3, UnitQuaternion, Vector3};
use platform::{GRAVITY_MPS2, Vehicle};
use tests::process::Proc;

/// One test at a time (each runs a twin process and a stand-in on a small machine).
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Control (and HIL_SENSOR) rate of the twin, Hz.
const RATE_HZ: f64 = 120.0;
/// PX4's default SITL home, the twin's world origin.
const HOME_LAT_DEG: f64 = 47.397742;
const HOME_LON_DEG: f64 = 8.545594;
const HOME_ALT_M: f64 = 488.0;

/// `amstack twin serve --px4-hil tcp:127.0.0.1:0 …`, and the port it announced.
fn start_twin(extra: &[&str]) -> (Proc, u16) {
    let mut args = vec![
        "twin",
        "serve",
        "--px4-hil",
        "tcp:127.0.0.1:0",
        "--platform",
        "fa-hexa",
        // The stand-in answers the first HIL_SENSOR: wait for it (a loaded machine must not
        // move the start of lockstep).
        "--first-reply-ms",
        "60000",
    ];
    args.extend_from_slice(extra);
    let mut proc = Proc::start("twin serve --px4-hil", &args);
    let line = proc.wait_for("listening on tcp:");
    let port = line
        .split("tcp:127.0.0.1:")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no port in {line:?}"));
    (proc, port)
}

/// FLU ↔ FRD.
fn flip(v: Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v.x, -v.y, -v.z)
}

fn v3(x: f32, y: f32, z: f32) -> Vector3<f64> {
    Vector3::new(f64::from(x), f64::from(y), f64::from(z))
}

/// What the stand-in saw and did.
#[derive(Debug, Default)]
struct Record {
    sensors: Vec<HIL_SENSOR_DATA>,
    gps: Vec<HIL_GPS_DATA>,
    truth: Vec<HIL_STATE_QUATERNION_DATA>,
    replies: u64,
    /// A HIL_SENSOR arrived while the stand-in held back its reply (lockstep broken).
    early_sensors: u64,
}

/// A position reference: world (x east, y north, z up about home), m, from a tick on.
#[derive(Debug, Clone, Copy)]
struct Leg {
    from_tick: usize,
    target_m: Vector3<f64>,
}

/// The PX4 stand-in.
struct StandIn {
    stream: TcpStream,
    buffer: Vec<u8>,
    pending: Vec<u8>,
    sequence: u8,
    // Vehicle figures.
    mass_kg: f64,
    inertia: Matrix3<f64>,
    allocation: DMatrix<f64>,
    curve: platform::ThrustCurve,
    thrust_max_n: f64,
    // Estimate.
    attitude: Option<UnitQuaternion<f64>>,
    position: Vector3<f64>,
    velocity: Vector3<f64>,
    gps_seen: bool,
    baro_seen: bool,
    mag_reference: Option<Vector3<f64>>,
    last_rate: Vector3<f64>,
    /// (channel, control) holding each arm joint at its initial position:
    /// c = 2 (q0 − lower) / (upper − lower) − 1.
    arm_controls: Vec<(usize, f32)>,
    record: Record,
}

impl StandIn {
    fn connect(port: u16, vehicle: &Vehicle) -> Self {
        let stream = TcpStream::connect(("127.0.0.1", port)).expect("connect");
        stream.set_nodelay(true).expect("nodelay");
        let q0 = vehicle.initial_configuration();
        let mp = vehicle.mass_properties(&q0);
        // 6 × N effectiveness about the centre of mass, body FLU: [d_i; (r_i − c) × d_i +
        // s_i k_f d_i]; the stand-in allocates a body wrench by its pseudo-inverse.
        let n = vehicle.rotors.len();
        let mut b = DMatrix::zeros(6, n);
        for (i, r) in vehicle.rotors.rotors.iter().enumerate() {
            let d = r.axis_in_base.into_inner();
            let torque = (r.position_in_base - mp.com_in_root_m).cross(&d)
                + d * (r.spin.sign() * vehicle.rotors.reaction_torque_ratio_m);
            for k in 0..3 {
                b[(k, i)] = d[k];
                b[(k + 3, i)] = torque[k];
            }
        }
        let allocation = b.pseudo_inverse(1e-9).expect("pseudo-inverse");
        let map = vehicle.px4_hil.as_ref().expect("channel map");
        let arm_controls = map
            .arm_joints
            .iter()
            .zip(vehicle.arm_dofs())
            .map(|(&channel, dof)| {
                let l = vehicle.model.dof_joint(dof).limits.expect("limits");
                #[allow(clippy::cast_possible_truncation)]
                let c = (2.0 * (q0[dof] - l.lower) / (l.upper - l.lower) - 1.0) as f32;
                (channel, c)
            })
            .collect();
        let mut s = Self {
            stream,
            buffer: vec![0; 4096],
            pending: Vec::new(),
            sequence: 0,
            mass_kg: mp.mass_kg,
            inertia: mp.inertia_about_com_kgm2,
            allocation,
            curve: vehicle.rotors.thrust_curve,
            thrust_max_n: vehicle.rotors.thrust_max_n,
            attitude: None,
            position: Vector3::zeros(),
            velocity: Vector3::zeros(),
            gps_seen: false,
            baro_seen: false,
            mag_reference: None,
            last_rate: Vector3::zeros(),
            arm_controls,
            record: Record::default(),
        };
        // PX4's simulator_mavlink says hello first.
        s.send(&MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_GENERIC,
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_STANDBY,
            mavlink_version: 3,
        }));
        s
    }

    fn send(&mut self, m: &MavMessage) {
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        mavlink::write_v2_msg(&mut self.stream, header, m).expect("send");
    }

    /// The next frame (blocking); None when the twin closed the connection.
    fn next(&mut self) -> Option<MavMessage> {
        loop {
            if let Some((m, used)) = parse(&self.pending) {
                self.pending.drain(..used);
                if let Some(m) = m {
                    return Some(m);
                }
                continue;
            }
            let n = self.stream.read(&mut self.buffer).ok()?;
            if n == 0 {
                return None;
            }
            self.pending.extend_from_slice(&self.buffer[..n]);
        }
    }

    /// Whether anything is waiting on the socket (without blocking).
    fn anything_waiting(&mut self) -> bool {
        if !self.pending.is_empty() {
            return true;
        }
        self.stream.set_nonblocking(true).expect("nonblocking");
        let mut byte = [0u8; 1];
        let waiting = match self.stream.peek(&mut byte) {
            Ok(n) => n > 0,
            Err(e) if e.kind() == ErrorKind::WouldBlock => false,
            Err(_) => false,
        };
        self.stream.set_nonblocking(false).expect("blocking");
        waiting
    }

    /// Attitude: gyro integration corrected toward gravity (accelerometer) and the
    /// magnetometer's horizontal direction at the start (a complementary filter).
    fn update_attitude(&mut self, s: &HIL_SENSOR_DATA, dt: f64) {
        let gyro = flip(v3(s.xgyro, s.ygyro, s.zgyro));
        let accel = flip(v3(s.xacc, s.yacc, s.zacc));
        let mag = flip(v3(s.xmag, s.ymag, s.zmag));
        let Some(q) = self.attitude else {
            // Level start; heading from the magnetometer taken as the reference.
            self.attitude = Some(UnitQuaternion::identity());
            self.mag_reference = Some(mag);
            return;
        };
        // Hovering, the specific force points up (Mahony's assumption).
        let up_measured = accel.normalize();
        let up_predicted = q.inverse() * Vector3::z();
        let mut correction = up_measured.cross(&up_predicted) * 0.3;
        if let Some(reference) = self.mag_reference {
            let horizontal = |v: Vector3<f64>| Vector3::new(v.x, v.y, 0.0).normalize();
            let m_world = horizontal(q * mag);
            let r_world = horizontal(reference);
            let yaw_error = m_world.cross(&r_world).z;
            correction += q.inverse() * Vector3::new(0.0, 0.0, 0.5 * yaw_error);
        }
        let rate = gyro + correction;
        self.attitude = Some(q * UnitQuaternion::from_scaled_axis(rate * dt));
    }

    /// Position: accelerometer prediction, corrected by the barometer (height) and GNSS.
    fn predict(&mut self, s: &HIL_SENSOR_DATA, dt: f64) {
        let q = self.attitude.unwrap_or_else(UnitQuaternion::identity);
        let accel = q * flip(v3(s.xacc, s.yacc, s.zacc)) - Vector3::new(0.0, 0.0, GRAVITY_MPS2);
        self.position += self.velocity * dt + accel * (0.5 * dt * dt);
        self.velocity += accel * dt;
        // Barometer (bits 0x1A00): height above home, ISA with the standard QNH.
        if s.fields_updated.bits() & 0x1A00 == 0x1A00 {
            let z = f64::from(s.pressure_alt) - HOME_ALT_M;
            if !self.baro_seen {
                self.baro_seen = true;
                self.position.z = z;
            }
            let error = z - self.position.z;
            self.position.z += 0.05 * error;
            self.velocity.z += 0.2 * error;
        }
    }

    /// GNSS: east/north about PX4's default home (what PX4 SITL is told with
    /// `PX4_HOME_LAT/LON`), a sphere (plenty for a few metres).
    fn gps(&mut self, g: &HIL_GPS_DATA) {
        const EARTH_M: f64 = 6_371_000.0;
        let north = (f64::from(g.lat) * 1e-7 - HOME_LAT_DEG).to_radians() * EARTH_M;
        let east = (f64::from(g.lon) * 1e-7 - HOME_LON_DEG).to_radians()
            * EARTH_M
            * HOME_LAT_DEG.to_radians().cos();
        if !self.gps_seen {
            self.gps_seen = true;
            self.position.x = east;
            self.position.y = north;
        }
        let v = Vector3::new(f64::from(g.ve), f64::from(g.vn), -f64::from(g.vd)) / 100.0;
        let error = Vector3::new(east - self.position.x, north - self.position.y, 0.0);
        self.position += error * 0.1;
        let v_error = Vector3::new(v.x - self.velocity.x, v.y - self.velocity.y, 0.0);
        self.velocity += v_error * 0.6 + error * 0.1;
    }

    /// The controls of one tick: a PD position loop → desired thrust vector → attitude PD →
    /// body wrench → rotor thrusts (pseudo-inverse) → normalised commands.
    fn control(&mut self, target: Vector3<f64>) -> [f32; 16] {
        let q = self.attitude.unwrap_or_else(UnitQuaternion::identity);
        let accel = (target - self.position) * 4.0 - self.velocity * 3.5;
        let accel = accel.map(|a| a.clamp(-3.0, 3.0));
        let force_world = (accel + Vector3::new(0.0, 0.0, GRAVITY_MPS2)) * self.mass_kg;
        let z_desired = force_world.normalize();
        // Yaw held at zero (facing east).
        let x_c = Vector3::x();
        let y_desired = z_desired.cross(&x_c).normalize();
        let x_desired = y_desired.cross(&z_desired);
        let r_desired = Matrix3::from_columns(&[x_desired, y_desired, z_desired]);
        let r = q.to_rotation_matrix().into_inner();
        let e = (r_desired.transpose() * r - r.transpose() * r_desired) * 0.5;
        let e_r = Vector3::new(e[(2, 1)], e[(0, 2)], e[(1, 0)]);
        let omega = self.last_rate;
        let torque = -self.inertia * (e_r * 150.0 + omega * 20.0);
        let thrust = force_world.dot(&(r * Vector3::z()));
        let mut wrench = DVector::zeros(6);
        wrench[2] = thrust;
        for k in 0..3 {
            wrench[k + 3] = torque[k];
        }
        let thrusts = &self.allocation * wrench;
        let mut controls = [0.0f32; 16];
        for (i, t) in thrusts.iter().enumerate() {
            #[allow(clippy::cast_possible_truncation)]
            let u = self.curve.command(t.clamp(0.0, self.thrust_max_n)) as f32;
            controls[i] = u;
        }
        // The arm held at its initial configuration, the gripper closed (−1: it holds the
        // task's tool).
        for (channel, c) in &self.arm_controls {
            controls[*channel] = *c;
        }
        controls[10] = -1.0;
        controls
    }
}

/// One frame off the front of `bytes`: (message or None for a frame to skip, bytes used);
/// None when more bytes are needed.
fn parse(bytes: &[u8]) -> Option<(Option<MavMessage>, usize)> {
    let start = bytes.iter().position(|&b| b == 0xFD)?;
    if start > 0 {
        return Some((None, start));
    }
    if bytes.len() < 10 {
        return None;
    }
    let signed = bytes[2] & 1 != 0;
    let n = 10 + usize::from(bytes[1]) + 2 + if signed { 13 } else { 0 };
    if bytes.len() < n {
        return None;
    }
    let m = MavlinkReader::new(&bytes[..n])
        .read_message::<MavMessage>(MavlinkVersion::V2)
        .ok()
        .map(|(_, m)| m);
    Some((m, n))
}

impl StandIn {
    /// Flies `legs` for `ticks` ticks (holding back its reply for 30 ms every 97th tick, to
    /// catch a twin that does not wait), then disconnects.
    fn fly(&mut self, legs: &[Leg], ticks: usize) {
        let dt = 1.0 / RATE_HZ;
        let mut tick = 0;
        while tick < ticks {
            let Some(m) = self.next() else { break };
            match m {
                MavMessage::HIL_GPS(g) => {
                    self.gps(&g);
                    self.record.gps.push(g);
                }
                MavMessage::HIL_STATE_QUATERNION(s) => self.record.truth.push(s),
                MavMessage::HIL_SENSOR(s) => {
                    self.last_rate = flip(v3(s.xgyro, s.ygyro, s.zgyro));
                    self.update_attitude(&s, dt);
                    self.predict(&s, dt);
                    let target = legs
                        .iter()
                        .rev()
                        .find(|l| l.from_tick <= tick)
                        .map_or_else(|| Vector3::new(0.0, 0.0, 1.0), |l| l.target_m);
                    // This tick's HIL_GPS and HIL_STATE_QUATERNION follow its HIL_SENSOR: the
                    // GNSS fix is fused on the next tick.
                    let controls = self.control(target);
                    let time_usec = s.time_usec;
                    self.record.sensors.push(s);
                    if tick % 97 == 50 {
                        std::thread::sleep(Duration::from_millis(30));
                        // Drain this tick's HIL_GPS/HIL_STATE_QUATERNION: anything after
                        // them would be a HIL_SENSOR sent without waiting for the reply.
                        while self.anything_waiting() {
                            match self.next() {
                                Some(MavMessage::HIL_SENSOR(s)) => {
                                    // Sent without waiting for the reply (realtime only).
                                    self.record.early_sensors += 1;
                                    self.record.sensors.push(s);
                                }
                                Some(MavMessage::HIL_STATE_QUATERNION(t)) => {
                                    self.record.truth.push(t)
                                }
                                Some(MavMessage::HIL_GPS(g)) => {
                                    self.gps(&g);
                                    self.record.gps.push(g);
                                }
                                _ => {}
                            }
                        }
                    }
                    self.send(&MavMessage::HIL_ACTUATOR_CONTROLS(
                        HIL_ACTUATOR_CONTROLS_DATA {
                            time_usec,
                            flags: HilActuatorControlsFlags::HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP,
                            controls,
                            mode: MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED
                                | MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                        },
                    ));
                    self.record.replies += 1;
                    tick += 1;
                }
                _ => {}
            }
        }
        // Read to the end of the next tick's messages (the twin sends its HIL_SENSOR only
        // after the last reply), then hang up.
        let mut next_sensor = false;
        while let Some(m) = self.next() {
            match m {
                MavMessage::HIL_SENSOR(s) => {
                    self.record.sensors.push(s);
                    next_sensor = true;
                }
                MavMessage::HIL_GPS(g) => self.record.gps.push(g),
                MavMessage::HIL_STATE_QUATERNION(t) => {
                    self.record.truth.push(t);
                    if next_sensor {
                        break;
                    }
                }
                _ => {}
            }
        }
        let _ = self.stream.shutdown(std::net::Shutdown::Both);
    }
}

/// Ground truth of a HIL_STATE_QUATERNION: height above the home altitude (488 m), m.
fn height_m(s: &HIL_STATE_QUATERNION_DATA) -> f64 {
    f64::from(s.alt) / 1000.0 - 488.0
}

/// Hover 5 s at the start (1 m up), then a 1 m step up, 10 s: the stand-in flies on the HIL
/// sensors alone. Lockstep: exactly one HIL_SENSOR per reply, none sent while a reply is held
/// back, time stamps one period apart; the contents against hand-derived truth.
#[test]
fn a_px4_stand_in_hovers_and_steps_on_the_hil_sensors_in_lockstep() {
    let _serial = serial();
    let (mut twin, port) = start_twin(&["--sessions", "1"]);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut px4 = StandIn::connect(port, &vehicle);
    let hover = 600;
    let ticks = 1800;
    px4.fly(
        &[
            Leg {
                from_tick: 0,
                target_m: Vector3::new(0.0, 0.0, 1.0),
            },
            Leg {
                from_tick: hover,
                target_m: Vector3::new(0.0, 0.0, 2.0),
            },
        ],
        ticks,
    );
    let ended = twin.wait_for("session 1 ended");
    assert!(ended.contains("PX4 disconnected"), "{ended}");
    twin.wait();
    let r = &px4.record;

    // Lockstep: one HIL_SENSOR per reply (the twin sends the next one only after the reply:
    // ticks + 1 in all), none while a reply was held back.
    assert_eq!(r.replies, ticks as u64);
    assert_eq!(r.sensors.len(), ticks + 1, "{}", twin.stderr());
    assert_eq!(r.early_sensors, 0);
    assert!(
        ended.contains(&format!("HIL_ACTUATOR_CONTROLS {ticks} (stale 0)")),
        "{ended}"
    );
    // PX4's clock: the first HIL_SENSOR at one period, then one period (8333 or 8334 µs,
    // round(n·10⁶/120)) per tick.
    for (n, s) in r.sensors.iter().enumerate() {
        let want = ((n as f64 + 1.0) * 1e6 / RATE_HZ).round() as u64;
        assert_eq!(s.time_usec, want, "tick {n}");
    }
    // HIL_GPS at 10 Hz: every 12th tick from the first.
    assert_eq!(r.gps.len(), r.sensors.len().div_ceil(12));
    assert_eq!(r.gps[1].time_usec, r.sensors[12].time_usec);
    assert_eq!(r.truth.len(), r.sensors.len());

    // Contents at rest, tick 1: level, 1 m above home (488 m): accel (0, 0, −9.81) m/s² FRD
    // within the turn-on bias (σ 0.05 m/s²) and noise; no rotation; pressure ISA(489 m) =
    // 955.868 hPa within 5 Pa; magnetometer: the default field (0.485 G, dip 63.5°, 3.3° E)
    // seen facing east: FRD (B_east, −B_north·… ) — its norm and dip; every bit set.
    let s0 = &r.sensors[0];
    assert_eq!(s0.fields_updated.bits(), 0x1BFF);
    assert_eq!(s0.id, 0);
    assert!((v3(s0.xacc, s0.yacc, s0.zacc) - Vector3::new(0.0, 0.0, -9.81)).norm() < 0.3);
    assert!(v3(s0.xgyro, s0.ygyro, s0.zgyro).norm() < 0.03);
    assert!(
        (f64::from(s0.abs_pressure) - 955.868).abs() < 0.05,
        "{}",
        s0.abs_pressure
    );
    assert!((f64::from(s0.pressure_alt) - 489.0).abs() < 0.5);
    let mag = v3(s0.xmag, s0.ymag, s0.zmag);
    assert!((mag.norm() - 0.485).abs() < 0.03, "{mag}");
    // FRD z is down: the dip shows as a positive z of 0.485·sin 63.5° = 0.434 G.
    assert!((mag.z - 0.434).abs() < 0.03, "{mag}");
    // Facing east, body x (forward) is east: B_east = 0.485·cos 63.5°·sin 3.3° = 0.0125 G,
    // body y (right) is south: −B_north = −0.485·cos 63.5°·cos 3.3° = −0.216 G.
    assert!((mag.y + 0.216).abs() < 0.03, "{mag}");
    let g0 = &r.gps[0];
    assert_eq!(
        (g0.fix_type, g0.satellites_visible, g0.eph, g0.epv),
        (3, 12, 50, 80)
    );
    assert!(
        (f64::from(g0.alt) - 489_000.0).abs() < 4_000.0,
        "{}",
        g0.alt
    );
    // 1e-7° of latitude is 1.1 cm: the 0.5 m noise stays within ±300.
    assert!((g0.lat - 473_977_420).abs() < 300, "{}", g0.lat);
    assert!((g0.lon - 85_455_940).abs() < 450, "{}", g0.lon);
    let t0 = &r.truth[0];
    assert_eq!(t0.alt, 489_000);
    assert_eq!(t0.zacc, -1000);
    assert_eq!(t0.time_usec, s0.time_usec);

    // The flight (ground truth): hover within 0.15 m of 1 m over its last 2 s, then 2 m
    // within 0.15 m over the last 3 s.
    let err = |from: usize, to: usize, want: f64| {
        r.truth[from..to]
            .iter()
            .map(|s| (height_m(s) - want).abs())
            .fold(0.0, f64::max)
    };
    let hover_error = err(hover - 240, hover, 1.0);
    let step_error = err(ticks - 360, ticks, 2.0);
    eprintln!("hover |z error| max {hover_error:.4} m, after the step {step_error:.4} m");
    assert!(hover_error < 0.15, "hover error {hover_error}");
    assert!(step_error < 0.15, "step error {step_error}");
    let horizontal = r.truth[ticks - 360..ticks]
        .iter()
        .map(|s| {
            let dn = f64::from(s.lat - t0.lat) * 1e-7_f64.to_radians() * 6_371_000.0;
            let de = f64::from(s.lon - t0.lon) * 1e-7_f64.to_radians() * 6_371_000.0 * 0.677;
            dn.hypot(de)
        })
        .fold(0.0, f64::max);
    eprintln!("horizontal drift max {horizontal:.4} m");
    assert!(horizontal < 0.5, "horizontal drift {horizontal}");
}

/// Two sessions of the same seed, flown by the same stand-in, are the same bit for bit: every
/// HIL_SENSOR, HIL_GPS and HIL_STATE_QUATERNION equal.
#[test]
fn lockstep_sessions_are_bit_identical_from_the_seed() {
    let _serial = serial();
    let (mut twin, port) = start_twin(&["--sessions", "2", "--seed", "7"]);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let legs = [Leg {
        from_tick: 0,
        target_m: Vector3::new(0.0, 0.0, 1.3),
    }];
    let mut runs = Vec::new();
    for session in 1..=2 {
        let mut px4 = StandIn::connect(port, &vehicle);
        px4.fly(&legs, 240);
        twin.wait_for(&format!("session {session} ended"));
        runs.push(px4.record);
    }
    twin.wait();
    let (a, b) = (&runs[0], &runs[1]);
    assert_eq!(a.sensors.len(), 241);
    assert_eq!(a.sensors, b.sensors);
    assert_eq!(a.gps, b.gps);
    assert_eq!(a.truth, b.truth);
    // And the vehicle moved (the comparison is not of a vehicle at rest).
    assert!(height_m(&a.truth[240]) > 1.1);
}

/// Wipe Window with the near-wall effect: the stand-in flies from the start to 0.85 m in
/// front of the window (its front rotors ≈ 0.5 m from the glass) and holds there. The MCAP
/// log shows the flight, the scene and the wall's pull: /disturbances.near_wall_n grows from
/// nothing at the start to a force toward the wall (+x), /task/state names the task, and
/// /mavlink/raw holds one HIL_ACTUATOR_CONTROLS per HIL_SENSOR.
#[test]
fn a_stand_in_hovers_beside_the_wipe_window_wall_and_the_log_shows_it() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("hil.mcap");
    let log_arg = log.to_string_lossy().into_owned();
    // Where the window is at this seed: the scene built by the twin the server will build.
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let config = sim_twin::TwinConfig {
        task: Some(sim_twin::TaskId::parse("wipe-window").unwrap()),
        seed: 3,
        ..sim_twin::TwinConfig::default()
    };
    let scene = sim_twin::Twin::new(vehicle.clone(), config).unwrap();
    let wall = scene.task_wall().unwrap().translation.vector;
    let start = scene.truth().base.position_in_world_m;
    let (mut twin, port) = start_twin(&[
        "--sessions",
        "1",
        "--task",
        "wipe-window",
        "--seed",
        "3",
        "--disturbances",
        "wall",
        "--mcap",
        &log_arg,
    ]);
    let mut px4 = StandIn::connect(port, &vehicle);
    let want_x = wall.x - 0.025 - 0.85;
    let ticks = 1200;
    px4.fly(
        &[
            Leg {
                from_tick: 0,
                target_m: start,
            },
            Leg {
                from_tick: 120,
                target_m: Vector3::new(want_x, start.y, start.z),
            },
        ],
        ticks,
    );
    twin.wait_for("session 1 ended");
    twin.wait();

    let messages = read_mcap(&log);
    let on = |topic: &str| -> Vec<&(String, u64, serde_json::Value)> {
        messages.iter().filter(|(t, _, _)| t == topic).collect()
    };
    // /base/state at each tick; the last 2 s hold the target.
    let states = on("/base/state");
    assert_eq!(states.len(), ticks);
    let x_at = |m: &serde_json::Value| m["position_m"][0].as_f64().unwrap();
    let worst = states[ticks - 240..]
        .iter()
        .map(|(_, _, m)| (x_at(m) - want_x).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "hold beside the wall: |x error| max {worst:.4} m (wall face at x = {:.3} m)",
        wall.x - 0.025
    );
    assert!(worst < 0.3, "x error {worst}");
    // The near-wall force: none at the start, toward the wall (+x, the base facing it) at the
    // hold.
    let disturbances = on("/disturbances");
    let near = |m: &serde_json::Value| -> Vector3<f64> {
        let a = &m["near_wall_n"];
        Vector3::new(
            a[0].as_f64().unwrap(),
            a[1].as_f64().unwrap(),
            a[2].as_f64().unwrap(),
        )
    };
    let at_start = near(&disturbances[10].2).norm();
    let at_wall: Vec<Vector3<f64>> = disturbances[disturbances.len() - 240..]
        .iter()
        .map(|(_, _, m)| near(m))
        .collect();
    let mean_x = at_wall.iter().map(|f| f.x).sum::<f64>() / at_wall.len() as f64;
    eprintln!("near-wall force: start {at_start:.5} N, at the wall mean x {mean_x:.4} N");
    assert!(mean_x > 0.02, "{mean_x}");
    assert!(mean_x > 10.0 * at_start, "{mean_x} vs {at_start}");
    // /disturbances at t_k + dt: one period after the state of the same tick.
    let (_, t_state, _) = states[0];
    let (_, t_dist, _) = disturbances[0];
    assert_eq!((*t_state, *t_dist), (8_333_333, 16_666_667));
    // The task scene is in the log.
    let tasks = on("/task/state");
    assert_eq!(tasks.len(), ticks);
    assert_eq!(tasks[0].2["task"], "wipe-window");
    // The wire: every HIL_SENSOR answered once.
    let raw = on("/mavlink/raw");
    let count = |name: &str, dir: &str| {
        raw.iter()
            .filter(|(_, _, m)| m["message_name"] == name && m["direction"] == dir)
            .count()
    };
    // The last HIL_SENSOR, never answered, ends the session unlogged.
    assert_eq!(count("HIL_SENSOR", "out"), ticks);
    assert_eq!(count("HIL_ACTUATOR_CONTROLS", "in"), ticks);
    assert_eq!(count("HEARTBEAT", "in"), 1);
    // Bytes as on the wire: the first HIL_SENSOR decodes to what the stand-in received.
    let first = raw
        .iter()
        .find(|(_, _, m)| m["message_name"] == "HIL_SENSOR")
        .unwrap();
    let hex = first.2["bytes_hex"].as_str().unwrap();
    let bytes: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect();
    let (m, _) = parse(&bytes).unwrap();
    assert_eq!(
        m,
        Some(MavMessage::HIL_SENSOR(px4.record.sensors[0].clone()))
    );
}

/// Every message of `path`, read with the `mcap` crate: topic, log time (ns), JSON payload.
fn read_mcap(path: &Path) -> Vec<(String, u64, serde_json::Value)> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            let value = serde_json::from_slice(&m.data).unwrap();
            (m.channel.topic.clone(), m.log_time, value)
        })
        .collect()
}

/// A vehicle without a channel map, or a bad address, is refused in one line (exit 2).
#[test]
fn the_oracle_and_a_bad_address_are_refused_in_one_line() {
    let _serial = serial();
    let mut p = Proc::start(
        "twin serve --px4-hil (ee-only)",
        &[
            "twin",
            "serve",
            "--px4-hil",
            "tcp:127.0.0.1:0",
            "--platform",
            "ee-only",
        ],
    );
    assert_eq!(p.wait().code(), Some(2));
    let err = p.stderr();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("ee-only.toml): px4_hil: missing"), "{err}");
    let mut p = Proc::start(
        "twin serve --px4-hil (bad address)",
        &["twin", "serve", "--px4-hil", "udp:localhost:4560"],
    );
    assert_eq!(p.wait().code(), Some(2));
    assert!(p.stderr().contains("--px4-hil"), "{}", p.stderr());
}

/// `amstack px4-airframe --platform fa-hexa` prints rotor 1 as derived by hand in twin_hil's
/// unit test: thrust axis (0.5003, 0, −0.8658) FRD, KM +0.02, CT 23 N.
#[test]
fn px4_airframe_prints_the_allocation_parameters() {
    let out = std::process::Command::new(tests::process::amstack())
        .args(["px4-airframe", "--platform", "fa-hexa"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for line in [
        "param set-default CA_AIRFRAME 0",
        "param set-default CA_ROTOR_COUNT 6",
        "param set-default CA_ROTOR1_AX 0.5003",
        "param set-default CA_ROTOR1_AY 0.0000",
        "param set-default CA_ROTOR1_AZ -0.8658",
        "param set-default CA_ROTOR1_KM 0.0200",
        "param set-default CA_ROTOR1_CT 23.0000",
        "param set-default THR_MDL_FAC 0.3000",
    ] {
        assert!(text.lines().any(|l| l == line), "{line} missing:\n{text}");
    }
}

/// A PX4 that stops answering in lockstep is reported and the twin waits for the next one,
/// which gets a fresh session from the reset state.
#[test]
fn a_silent_px4_is_reported_and_the_next_connection_is_served() {
    let _serial = serial();
    let (mut twin, port) = start_twin(&["--sessions", "2", "--stall-ms", "300"]);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut silent = StandIn::connect(port, &vehicle);
    // Answer 10 HIL_SENSOR, then keep the connection open and say nothing.
    let mut answered = 0;
    while answered < 10 {
        if let Some(MavMessage::HIL_SENSOR(s)) = silent.next() {
            silent.send(&MavMessage::HIL_ACTUATOR_CONTROLS(
                HIL_ACTUATOR_CONTROLS_DATA {
                    time_usec: s.time_usec,
                    flags: HilActuatorControlsFlags::HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP,
                    controls: [0.0; 16],
                    mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                },
            ));
            answered += 1;
        }
    }
    let ended = twin.wait_for("session 1 ended");
    assert!(
        ended.contains("PX4 stopped answering in lockstep"),
        "{ended}"
    );
    assert!(ended.contains("waiting for the next connection"), "{ended}");
    // Never armed: the vehicle was held at its start.
    assert!(!twin.stderr().contains("PX4 armed"), "{}", twin.stderr());
    drop(silent);
    let mut px4 = StandIn::connect(port, &vehicle);
    px4.fly(&[], 24);
    twin.wait_for("session 2 ended");
    assert_eq!(twin.wait().code(), Some(0));
    // The new session starts again at PX4's first tick, from the reset state.
    assert_eq!(px4.record.sensors[0].time_usec, 8333);
    assert_eq!(px4.record.truth[0].alt, 489_000);
}

/// `--realtime`: the twin ticks on the wall clock; PX4's clock still advances one period per
/// HIL_SENSOR and the replies fly the vehicle.
#[test]
fn realtime_ticks_one_period_per_hil_sensor() {
    let _serial = serial();
    let (mut twin, port) = start_twin(&["--sessions", "1", "--realtime"]);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut px4 = StandIn::connect(port, &vehicle);
    px4.fly(&[], 120);
    let ended = twin.wait_for("session 1 ended");
    assert!(ended.contains("PX4 disconnected"), "{ended}");
    assert!(twin.stderr().contains("PX4 armed"), "{}", twin.stderr());
    assert!(
        !twin.stderr().contains("lockstep with PX4"),
        "{}",
        twin.stderr()
    );
    let r = &px4.record;
    assert!(r.sensors.len() > 120);
    for (n, s) in r.sensors.iter().enumerate() {
        let want = ((n as f64 + 1.0) * 1e6 / RATE_HZ).round() as u64;
        assert_eq!(s.time_usec, want, "tick {n}");
    }
}

#[test]
fn a_px4_hil_twin_streams_its_steps_live() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let addr = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .unwrap()
        .to_string();
    let (mut twin, port) = start_twin(&["--sessions", "1", "--live", &addr]);
    twin.wait_for("live view: ws://");
    let ready = dir.path().join("subscribed");
    let mut viewer = tests::ws_client(&[
        &format!("ws://{addr}"),
        "--topics",
        "/scene/tf,/scene/static,/base/state",
        "--messages",
        "100",
        "--need",
        "/scene/static=1",
        "--timeout",
        "120",
        "--ready-file",
        ready.to_str().unwrap(),
    ])
    .stdout(std::process::Stdio::piped())
    .spawn()
    .unwrap();
    tests::wait_for_file(&ready, &mut viewer);
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut px4 = StandIn::connect(port, &vehicle);
    px4.fly(
        &[Leg {
            from_tick: 0,
            target_m: Vector3::new(0.0, 0.0, 1.0),
        }],
        300,
    );
    twin.wait_for("session 1 ended");
    let viewed = viewer.wait_with_output().unwrap();
    let report: serde_json::Value = serde_json::from_slice(&viewed.stdout).unwrap();
    assert!(viewed.status.success(), "{report}");
    assert!(twin.wait().success(), "{}", twin.stderr());
    let got = &report["received"];
    // One message set per HIL tick, a control period of the twin's time apart.
    for topic in ["/scene/tf", "/base/state"] {
        let entry = &got[topic];
        assert!(entry["count"].as_u64().unwrap() >= 100, "{topic}: {entry}");
        let step = entry["median_step_ns"].as_f64().unwrap();
        assert!((step - 1e9 / RATE_HZ).abs() <= 1.0, "{topic}: {step} ns");
    }
}
