//! Controller tests: closed loop against an ideal rigid body written here (not the twin),
//! anti-windup, non-finite inputs, and the numbers of the reference's profiles.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use platform::{GRAVITY_MPS2, RigidBodyState, Vehicle, Wrench};

use crate::controller::BodyParams;
use crate::{
    BaseController, ConfigError, ControllerConfig, ControllerKind, DesiredStateGenerator,
    InputHealth, L1Adaptive, L1Config, Pid4, Pid4Gains, Pid6, Pid6Gains, attitude_error, profile,
};

const DT: f64 = 1.0 / 120.0;

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"))
}

/// The vehicle's mass and inertia on a body whose centre of mass is the control frame.
fn centred_body(id: &str) -> BodyParams {
    let b = BodyParams::from_vehicle(&vehicle(id));
    BodyParams::centred(b.mass_kg, b.inertia_kgm2)
}

/// An ideal rigid body: m v̇ = R F_b − m g ẑ + d,  J Ω̇ = τ − Ω×JΩ,  Ṙ = R Ω^, integrated
/// semi-implicitly with substeps.
struct Plant {
    body: BodyParams,
    state: RigidBodyState,
    disturbance_force_in_world: Vector3<f64>,
}

impl Plant {
    fn new(body: BodyParams, pose: Isometry3<f64>) -> Self {
        Self {
            body,
            state: RigidBodyState::at_rest(pose),
            disturbance_force_in_world: Vector3::zeros(),
        }
    }

    fn step(&mut self, wrench_in_body: &Wrench, dt: f64) {
        const SUBSTEPS: usize = 8;
        let h = dt / SUBSTEPS as f64;
        let j = self.body.inertia_kgm2;
        let j_inv = j.try_inverse().unwrap_or_else(Matrix3::identity);
        for _ in 0..SUBSTEPS {
            let s = &mut self.state;
            let force = s.world_from_body * wrench_in_body.force + self.disturbance_force_in_world;
            let acc = force / self.body.mass_kg - Vector3::z() * GRAVITY_MPS2;
            s.velocity_in_world_mps += acc * h;
            s.position_in_world_m += s.velocity_in_world_mps * h;
            let w = s.angular_velocity_in_body_radps;
            s.angular_velocity_in_body_radps +=
                j_inv * (wrench_in_body.torque - w.cross(&(j * w))) * h;
            s.world_from_body *=
                UnitQuaternion::from_scaled_axis(s.angular_velocity_in_body_radps * h);
        }
    }

    /// Runs `controller` toward `target` for `seconds`, the allocator achieving everything.
    fn fly(&mut self, controller: &mut dyn BaseController, target: &Isometry3<f64>, seconds: f64) {
        let ticks = (seconds / DT).round() as usize;
        for _ in 0..ticks {
            let w = controller.update(&self.state, target, DT);
            assert!(w.is_finite(), "controller output {w:?}");
            self.step(&w, DT);
        }
    }

    fn position_error(&self, target: &Isometry3<f64>) -> f64 {
        (target.translation.vector - self.state.position_in_world_m).norm()
    }

    fn rotation_error(&self, target: &Isometry3<f64>) -> f64 {
        target.rotation.angle_to(&self.state.world_from_body)
    }
}

fn pose(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
    )
}

// ---- Closed loop ----

#[test]
fn pid6_settles_a_6635_kg_body_from_half_a_metre_and_20_degrees_of_yaw() {
    let body = centred_body("fa-hexa");
    assert!((body.mass_kg - 6.635).abs() < 1e-9);
    let target = pose(0.0, 0.0, 1.0, 0.0);
    let mut plant = Plant::new(body, pose(0.3, -0.4, 1.0, (-20.0f64).to_radians()));
    assert!((plant.position_error(&target) - 0.5).abs() < 1e-12);
    let mut pid = Pid6::new(Pid6Gains::am_bench(), body);
    plant.fly(&mut pid, &target, 20.0);
    let (ep, er) = (plant.position_error(&target), plant.rotation_error(&target));
    assert!(ep < 1e-3, "position error {ep} m");
    assert!(er < 1e-3, "attitude error {er} rad");
}

#[test]
fn pid4_tracks_a_one_metre_step_without_steady_state_error() {
    // UA-Quad mass and inertia; an unknown 1 N lateral push that only the integrator removes.
    let body = centred_body("ua-quad");
    let mut plant = Plant::new(body, pose(0.0, 0.0, 1.0, 0.3));
    plant.disturbance_force_in_world = Vector3::new(0.0, 1.0, 0.0);
    let target = pose(1.0, 0.0, 1.0, 0.3);
    let mut pid = Pid4::new(Pid4Gains::ua_quad(), body);
    plant.fly(&mut pid, &target, 30.0);
    let ep = plant.position_error(&target);
    let er = plant.rotation_error(&target);
    assert!(ep < 1e-3, "steady-state position error {ep} m");
    // The base must tilt to hold 1 N sideways: about atan(1 / (m g)).
    let lean = (1.0 / (body.mass_kg * GRAVITY_MPS2)).atan();
    assert!(
        (er - lean).abs() < 2e-3,
        "attitude {er} rad vs lean {lean} rad"
    );
    // The body force of a 4-DoF controller is along body z only.
    let w = pid.status().output;
    assert!(w.force.x.abs() < 1e-15 && w.force.y.abs() < 1e-15, "{w:?}");
}

/// Steady-state position error under a constant 5 N lateral force.
fn l1_steady_state_error(config: L1Config) -> f64 {
    let body = centred_body("fa-hexa");
    let target = pose(0.0, 0.0, 1.0, 0.0);
    let mut plant = Plant::new(body, target);
    plant.disturbance_force_in_world = Vector3::new(0.0, 5.0, 0.0);
    let mut l1 = L1Adaptive::new(config, body);
    plant.fly(&mut l1, &target, 25.0);
    plant.position_error(&target)
}

#[test]
fn l1_removes_nine_tenths_of_a_constant_5n_push_that_the_baseline_leaves() {
    // Without the reference profile's 2 N bound on the estimate (class default: none).
    let unbounded = L1Config {
        sigma_max_lin_n: None,
        ..L1Config::am_bench()
    };
    let baseline = l1_steady_state_error(L1Config {
        adaptive_mix_lin: 0.0,
        adaptive_mix_ang: 0.0,
        ..unbounded
    });
    let adaptive = l1_steady_state_error(unbounded);
    // The baseline is a PD: its offset is F/(m k_p) = 5 / (6.635 · 200).
    assert!(
        (baseline - 5.0 / (6.635 * 200.0)).abs() < 1e-5,
        "baseline {baseline}"
    );
    assert!(
        adaptive <= 0.1 * baseline,
        "L1 {adaptive} vs baseline {baseline}"
    );
}

#[test]
fn l1_profile_bound_caps_the_estimate_at_2n() {
    // The reference profile bounds the raw estimate to 2 N: 3 N of the 5 N push remain.
    let baseline = l1_steady_state_error(L1Config {
        adaptive_mix_lin: 0.0,
        ..L1Config::am_bench()
    });
    let bounded = l1_steady_state_error(L1Config::am_bench());
    let ratio = bounded / baseline;
    assert!((ratio - 0.6).abs() < 0.02, "bounded/baseline = {ratio}");
}

#[test]
fn l1_tracks_without_disturbance_like_its_baseline() {
    let body = centred_body("ee-only");
    let target = pose(0.2, -0.1, 1.1, 0.4);
    let mut plant = Plant::new(body, pose(0.0, 0.0, 1.0, 0.0));
    let mut l1 = L1Adaptive::new(L1Config::am_bench(), body);
    plant.fly(&mut l1, &target, 15.0);
    assert!(plant.position_error(&target) < 1e-3);
    assert!(plant.rotation_error(&target) < 1e-3);
}

// ---- Anti-windup ----

#[test]
fn saturated_force_direction_stops_the_position_integral() {
    let body = centred_body("fa-hexa");
    let state = RigidBodyState::at_rest(pose(0.0, 0.0, 1.0, 0.0));
    let target = pose(1.0, 1.0, 1.0, 0.0);
    let mut pid = Pid6::new(Pid6Gains::am_bench(), body);
    for _ in 0..240 {
        pid.update(&state, &target, DT);
        // The allocator could not deliver 5 N of the +x request.
        pid.saturation_feedback(&Wrench::new(Vector3::new(5.0, 0.0, 0.0), Vector3::zeros()));
    }
    let s = pid.status();
    // One tick before the first feedback integrates; nothing after.
    assert!(
        s.position_integral.x <= DT + 1e-12,
        "x integral {}",
        s.position_integral.x
    );
    assert!(
        (s.position_integral.y - 240.0 * DT).abs() < 1e-9,
        "y integral {}",
        s.position_integral.y
    );
    assert!(s.windup_blocked[0] && !s.windup_blocked[1]);
}

#[test]
fn saturated_torque_direction_stops_the_attitude_integral() {
    let body = centred_body("fa-hexa");
    let state = RigidBodyState::at_rest(pose(0.0, 0.0, 1.0, 0.0));
    // Target yawed +0.3 rad and rolled: the law asks for +τ_z and some τ_x.
    let target = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 1.0),
        UnitQuaternion::from_euler_angles(0.2, 0.0, 0.3),
    );
    let mut pid = Pid6::new(Pid6Gains::am_bench(), body);
    pid.update(&state, &target, DT);
    let first = pid.status().attitude_integral;
    for _ in 0..120 {
        pid.saturation_feedback(&Wrench::new(Vector3::zeros(), Vector3::new(0.0, 0.0, 1.0)));
        pid.update(&state, &target, DT);
    }
    let s = pid.status();
    assert!(
        (s.attitude_integral.z - first.z).abs() < 1e-15,
        "z integral grew: {:?}",
        s.attitude_integral
    );
    assert!(
        s.attitude_integral.x.abs() > 100.0 * first.x.abs(),
        "x integral must keep integrating"
    );
    assert!(s.windup_blocked[5]);
}

/// A fake allocator that can give at most 2 N of body +x force against a 5 N push toward −x:
/// the body drifts and the request saturates. Returns the adaptive +x force when saturation
/// first occurs and the largest one after.
fn capped_flight(report: bool) -> (f64, f64) {
    let body = centred_body("fa-hexa");
    let target = pose(0.0, 0.0, 1.0, 0.0);
    let mut plant = Plant::new(body, target);
    plant.disturbance_force_in_world = Vector3::new(-5.0, 0.0, 0.0);
    let mut l1 = L1Adaptive::new(
        L1Config {
            sigma_max_lin_n: None,
            ..L1Config::am_bench()
        },
        body,
    );
    let max_fx = 2.0;
    let mut at_onset = None;
    let mut largest = f64::NEG_INFINITY;
    for _ in 0..600 {
        let w = l1.update(&plant.state, &target, DT);
        let adaptive_x = l1.status().adaptive_force_n.map_or(f64::NAN, |f| f.x);
        if at_onset.is_some() {
            largest = largest.max(adaptive_x);
        }
        let achieved = Wrench::new(
            Vector3::new(w.force.x.min(max_fx), w.force.y, w.force.z),
            w.torque,
        );
        if at_onset.is_none() && w.force.x > max_fx {
            at_onset = Some(adaptive_x);
        }
        if report {
            l1.saturation_feedback(&(w - achieved));
        }
        plant.step(&achieved, DT);
    }
    (at_onset.unwrap_or(f64::NAN), largest)
}

#[test]
fn saturated_direction_stops_l1_adaptation() {
    let (_, unreported) = capped_flight(false);
    // Without feedback the estimate takes the unachieved request for a disturbance and grows
    // past the real 5 N push.
    assert!(
        unreported > 6.0,
        "without feedback the estimate winds up: {unreported} N"
    );
    let (onset, reported) = capped_flight(true);
    assert!(
        onset.is_finite() && onset < 1.0,
        "saturation starts early: {onset} N"
    );
    assert!(
        reported <= onset + 1e-12,
        "with feedback it must not grow: {onset} N at onset, {reported} N after"
    );
}

// ---- Non-finite inputs ----

fn controllers() -> Vec<Box<dyn BaseController>> {
    let body = centred_body("fa-hexa");
    vec![
        Box::new(Pid6::new(Pid6Gains::am_bench(), body)),
        Box::new(Pid4::new(Pid4Gains::ua_hexa(), body)),
        Box::new(L1Adaptive::new(L1Config::am_bench(), body)),
    ]
}

#[test]
fn non_finite_state_gives_hover_then_the_last_wrench() {
    for mut c in controllers() {
        let mut bad = RigidBodyState::at_rest(pose(0.0, 0.0, 1.0, 0.0));
        bad.velocity_in_world_mps.x = f64::NAN;
        let w = c.update(&bad, &pose(0.0, 0.0, 1.0, 0.0), DT);
        assert!(w.is_finite());
        let weight = 6.635 * GRAVITY_MPS2;
        assert!(
            (w.force - Vector3::new(0.0, 0.0, weight)).norm() < 1e-9,
            "{}: {w:?}",
            c.status().controller
        );
        assert_eq!(c.status().input, InputHealth::NonFiniteState);
        // After a good tick, a bad one repeats the last wrench.
        let good = RigidBodyState::at_rest(pose(0.1, 0.0, 1.0, 0.0));
        let last = c.update(&good, &pose(0.0, 0.0, 1.0, 0.0), DT);
        let again = c.update(&bad, &pose(0.0, 0.0, 1.0, 0.0), DT);
        assert_eq!(last, again);
        let held = c.update(&good, &pose(0.0, 0.0, 1.0, 0.0), f64::NAN);
        assert_eq!(held, last);
        assert_eq!(c.status().input, InputHealth::InvalidDt);
    }
}

#[test]
fn non_finite_target_holds_the_previous_target() {
    for mut c in controllers() {
        let state = RigidBodyState::at_rest(pose(0.0, 0.0, 1.0, 0.0));
        let target = pose(0.2, 0.0, 1.0, 0.0);
        c.update(&state, &target, DT);
        let mut bad = target;
        bad.translation.vector.y = f64::NAN;
        let w = c.update(&state, &bad, DT);
        assert!(w.is_finite(), "{}", c.status().controller);
        assert_eq!(c.status().input, InputHealth::NonFiniteTarget);
        assert!(
            (c.status().position_error_m.x - 0.2).abs() < 1e-12,
            "tracks the held target"
        );
    }
}

// ---- Laws and desired states against hand-derived values ----

#[test]
fn attitude_error_is_sine_of_the_angle_about_the_axis() {
    let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
    let theta = 0.7;
    let r = UnitQuaternion::from_scaled_axis(axis * theta)
        .to_rotation_matrix()
        .into_inner();
    let e = attitude_error(&r, &Matrix3::identity());
    assert!((e - axis * theta.sin()).norm() < 1e-14, "{e:?}");
    assert!(attitude_error(&r, &r).norm() < 1e-15);
}

#[test]
fn desired_rate_is_the_true_rate_not_the_doubled_reference_one() {
    // AMBENCH_SPEC §9 item 3: the reference doubles Ω_d. A target yawing at 0.5 rad/s.
    let mut g = DesiredStateGenerator::default();
    let fallback = Isometry3::identity();
    let first = g.update(&pose(0.0, 0.0, 1.0, 0.0), DT, &fallback);
    assert_eq!(
        first.angular_velocity_radps,
        Vector3::zeros(),
        "first step: zero"
    );
    let second = g.update(&pose(0.0, 0.0, 1.0, 0.5 * DT), DT, &fallback);
    assert!(
        (second.angular_velocity_radps - Vector3::new(0.0, 0.0, 0.5)).norm() < 1e-9,
        "{:?}",
        second.angular_velocity_radps
    );
    // Derivatives are clamped to ±1, as in the reference: 2 m/s reads as 1 m/s.
    let third = g.update(&pose(2.0 * DT, 0.0, 1.0, DT), DT, &fallback);
    assert!((third.velocity_mps.x - 1.0).abs() < 1e-12);
}

#[test]
fn hover_at_the_target_needs_weight_and_the_centre_of_mass_moment() {
    let fa = vehicle("fa-hexa");
    let body = BodyParams::from_vehicle(&fa);
    let c = body.com_in_body_m;
    assert!(
        c.norm() > 0.01,
        "the FA-Hexa's arm moves its centre of mass forward: {c:?}"
    );
    let mut pid = Pid6::new(Pid6Gains::am_bench(), body);
    let at = pose(0.0, 0.0, 1.0, 0.0);
    let w = pid.update(&RigidBodyState::at_rest(at), &at, DT);
    let weight = Vector3::new(0.0, 0.0, body.mass_kg * GRAVITY_MPS2);
    assert!((w.force - weight).norm() < 1e-9, "{w:?}");
    assert!((w.torque - c.cross(&weight)).norm() < 1e-9, "{w:?}");
}

#[test]
fn l1_discrete_constants_match_the_spec() {
    // AMBENCH_SPEC §2.4: e^{A dt} = 0.991701 (lin), 0.994598 (ang); filter 0.984415 at 0.3 Hz.
    assert!(((-DT).exp() - 0.991701).abs() < 1e-6);
    assert!(((-0.65 * DT).exp() - 0.994598).abs() < 1e-6);
    assert!(((-2.0 * std::f64::consts::PI * 0.3 * DT).exp() - 0.984415).abs() < 1e-6);
    // h = −a e^{a dt} / (e^{a dt} − 1) x̃: for a = −1 at 120 Hz, ≈ 119.5 per unit error.
    let gain = crate::l1::adaptation_gain(&Vector3::new(-1.0, -0.65, 0.0), DT);
    let e = (-DT).exp();
    assert!((gain.x - e / (e - 1.0)).abs() < 1e-9);
    assert_eq!(gain.z, 0.0, "A = 0 has no adaptation");
}

// ---- Profiles and configuration ----

#[test]
fn profiles_carry_the_reference_gains() {
    let g = Pid6Gains::am_bench();
    assert_eq!(
        [g.kp_pos, g.kd_pos, g.ki_pos, g.kp_rot, g.kd_rot, g.ki_rot],
        [200.0, 120.0, 80.0, 200.0, 120.0, 120.0]
    );
    let o = Pid6Gains::omni();
    assert_eq!([o.kp_rot, o.kd_rot, o.ki_rot], [240.0, 130.0, 130.0]);
    let q = Pid4Gains::ua_quad();
    assert_eq!(
        [q.kp_xy, q.kp_z, q.kd_xy, q.kd_z, q.ki_xy, q.ki_z],
        [10.0, 30.0, 8.0, 10.0, 6.0, 10.0]
    );
    assert_eq!([q.kp_rot, q.kd_rot, q.ki_rot], [150.0, 20.0, 20.0]);
    assert_eq!(q.outer_loop_decimation, 3);
    let l = L1Config::am_bench();
    assert_eq!(l.k_pos, Vector3::repeat(200.0));
    assert_eq!(l.k_ang_vel, Vector3::repeat(120.0));
    assert_eq!(
        (
            l.filter_bandwidth_lin_hz,
            l.sigma_max_lin_n,
            l.sigma_max_ang_nm
        ),
        (0.3, Some(2.0), Some(2.0))
    );
    let d = L1Config::default();
    assert_eq!(d.k_ang_vel, Vector3::new(10.0, 20.0, 5.0));

    let pick = |id: &str, kind| profile(&vehicle(id), kind);
    assert_eq!(
        pick("fa-hexa", ControllerKind::Pid),
        Ok(ControllerConfig::Pid6(Pid6Gains::am_bench()))
    );
    assert_eq!(
        pick("omni-hexa", ControllerKind::L1),
        Ok(ControllerConfig::L1(L1Config::omni()))
    );
    assert_eq!(
        pick("ua-quad", ControllerKind::Pid),
        Ok(ControllerConfig::Pid4(Pid4Gains::ua_quad()))
    );
    assert!(matches!(
        pick("ua-hexa", ControllerKind::L1),
        Err(ConfigError::Unsupported(_))
    ));
}

#[test]
fn controller_config_loads_from_toml_and_refuses_unknown_keys() {
    let c = ControllerConfig::from_toml_str("controller = \"pid6\"\nkp_pos = 250.0\n");
    assert_eq!(
        c,
        Ok(ControllerConfig::Pid6(Pid6Gains {
            kp_pos: 250.0,
            ..Pid6Gains::default()
        }))
    );
    let c = ControllerConfig::from_toml_str("controller = \"l1\"\nk_ang_vel = [1.0, 2.0, 3.0]\n");
    assert!(matches!(c, Ok(ControllerConfig::L1(l)) if l.k_ang_vel == Vector3::new(1.0, 2.0, 3.0)));
    let typo = ControllerConfig::from_toml_str("controller = \"pid6\"\nkp_poss = 250.0\n");
    assert!(
        matches!(&typo, Err(ConfigError::Parse(m)) if m.contains("kp_poss")),
        "{typo:?}"
    );
    let long =
        ControllerConfig::from_toml_str("controller = \"l1\"\nk_pos = [1.0, 2.0, 3.0, 4.0]\n");
    assert!(
        matches!(&long, Err(ConfigError::Parse(m)) if m.contains("needs 3")),
        "{long:?}"
    );
    let negative = ControllerConfig::from_toml_str("controller = \"pid4\"\nkd_z = -1.0\n");
    assert_eq!(
        negative,
        Err(ConfigError::Invalid {
            field: "kd_z",
            message: "-1 must be finite and not negative".into()
        })
    );
    let unstable =
        ControllerConfig::from_toml_str("controller = \"l1\"\na_lin = [-1.0, 0.5, -1.0]\n");
    assert!(matches!(
        unstable,
        Err(ConfigError::Invalid { field: "a_lin", .. })
    ));
    let zero =
        ControllerConfig::from_toml_str("controller = \"pid4\"\nouter_loop_decimation = 0\n");
    assert!(matches!(
        zero,
        Err(ConfigError::Invalid {
            field: "outer_loop_decimation",
            ..
        })
    ));
}

#[test]
fn pid4_damps_the_centre_of_mass_velocity_not_the_base_origins() {
    // The base turning about its centre of mass moves the base origin (v = −R (Ω × c)) but
    // not the centre of mass: the outer loop sees no velocity error, so the thrust is the
    // weight's and the desired attitude level. Fed back, that origin velocity closed a loop
    // of gain k_d,xy·|c|/(g·outer_dt) through the rate feed-forward: the UA-Hexa's arm-sweep
    // diverged once the arm carried the centre of mass ~3 cm from the base origin.
    let ua = vehicle("ua-hexa");
    let mut body = BodyParams::from_vehicle(&ua);
    body.com_in_body_m = Vector3::new(0.10, 0.0, -0.02); // the arm reaching forward
    let gains = Pid4Gains::ua_hexa();
    let at = pose(0.0, 0.0, 1.0, 0.0);
    let mut turning = RigidBodyState::at_rest(at);
    turning.angular_velocity_in_body_radps = Vector3::new(0.0, 0.5, 0.0);
    turning.velocity_in_world_mps = -(turning.world_from_body
        * turning
            .angular_velocity_in_body_radps
            .cross(&body.com_in_body_m));
    assert!(turning.velocity_in_world_mps.norm() > 0.04);
    let mut pid = Pid4::new(gains, body);
    let w = pid.update(&turning, &at, DT);
    let weight = body.mass_kg * GRAVITY_MPS2;
    assert!(
        (w.force - Vector3::new(0.0, 0.0, weight)).norm() < 1e-9,
        "{w:?}"
    );
    let status = pid.status();
    assert!(status.velocity_error_mps.norm() < 1e-12, "{status:?}");
    // The same origin velocity with the body not turning is a real velocity error.
    let mut sliding = RigidBodyState::at_rest(at);
    sliding.velocity_in_world_mps = turning.velocity_in_world_mps;
    let mut pid = Pid4::new(gains, body);
    pid.update(&sliding, &at, DT);
    assert!((pid.status().velocity_error_mps + sliding.velocity_in_world_mps).norm() < 1e-12);
}

#[test]
fn the_rate_level_turns_an_attitude_error_into_rates_back_toward_the_target() {
    // R = R_d · exp(0.3 x̂): e_R = sin 0.3 x̂ (body); with PX4's gains (6.5, 6.5, 2.8) 1/s and a
    // feed-forward of (0.1, 0.2, 0.3) rad/s the rate is (0.1 − 6.5 sin 0.3, 0.2, 0.3), the force
    // unchanged. Without feed-forward, the error term alone.
    let r_d = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
    let r = r_d * UnitQuaternion::from_scaled_axis(Vector3::x() * 0.3);
    let e_r = attitude_error(
        r.to_rotation_matrix().matrix(),
        r_d.to_rotation_matrix().matrix(),
    );
    assert!(
        (e_r - Vector3::new(0.3f64.sin(), 0.0, 0.0)).norm() < 1e-12,
        "{e_r}"
    );
    let attitude = platform::AttitudeSetpoint {
        world_from_body: r_d,
        force_in_body_n: Vector3::new(1.0, 2.0, 60.0),
        body_rates_radps: Some(Vector3::new(0.1, 0.2, 0.3)),
    };
    let rates = crate::rate_setpoint(&attitude, &e_r, crate::PX4_ATTITUDE_P_PER_S);
    let expected = Vector3::new(0.1 - 6.5 * 0.3f64.sin(), 0.2, 0.3);
    assert!(
        (rates.body_rates_radps - expected).norm() < 1e-12,
        "{rates:?}"
    );
    assert_eq!(rates.force_in_body_n, attitude.force_in_body_n);
    let no_ff = platform::AttitudeSetpoint {
        body_rates_radps: None,
        ..attitude
    };
    let yawed = Vector3::new(0.0, 0.0, -0.1);
    let rates = crate::rate_setpoint(&no_ff, &yawed, crate::PX4_ATTITUDE_P_PER_S);
    assert!((rates.body_rates_radps - Vector3::new(0.0, 0.0, 0.28)).norm() < 1e-12);
    // All zero: all zero.
    let level = platform::AttitudeSetpoint {
        force_in_body_n: Vector3::zeros(),
        ..no_ff
    };
    let rates = crate::rate_setpoint(&level, &Vector3::zeros(), crate::PX4_ATTITUDE_P_PER_S);
    assert_eq!(rates.body_rates_radps, Vector3::zeros());
}

#[test]
fn the_tilt_limit_keeps_the_vertical_thrust_and_scales_the_horizontal_demand() {
    use crate::pid4::limit_tilt;
    let limit = std::f64::consts::FRAC_PI_4;
    // Within the limit: unchanged.
    let within = Vector3::new(3.0, -4.0, 20.0);
    assert_eq!(limit_tilt(&within, limit, 1.0), within);
    // 10 N up and 30 N sideways (71.6° from the vertical): at 45° the horizontal part is
    // scaled to 10 N along the same direction, the vertical part kept.
    let out = limit_tilt(&Vector3::new(18.0, 24.0, 10.0), limit, 1.0);
    assert!((out - Vector3::new(6.0, 8.0, 10.0)).norm() < 1e-12, "{out}");
    let tilt = out.xy().norm().atan2(out.z);
    assert!((tilt - limit).abs() < 1e-12);
    // A demand to fall (A_z < 0, a direction past 90°) keeps the least vertical part.
    let out = limit_tilt(&Vector3::new(5.0, 0.0, -3.0), limit, 2.0);
    assert!((out - Vector3::new(2.0, 0.0, 2.0)).norm() < 1e-12, "{out}");
}

#[test]
fn pid4_under_a_far_sideways_target_asks_for_at_most_its_tilt_limit() {
    // A UA-Hexa body at hover with its target 20 m to the side: the reference's law asks for
    // a thrust direction ~87° from the vertical (k_p·e = 200 m/s² against g); the limited
    // law's desired attitude (its attitude target's body z) is 45° from it.
    let body = BodyParams {
        mass_kg: 6.635,
        inertia_kgm2: Matrix3::from_diagonal(&Vector3::new(0.198, 0.198, 0.46)),
        com_in_body_m: Vector3::zeros(),
    };
    let state = RigidBodyState {
        position_in_world_m: Vector3::new(0.0, 0.0, 1.0),
        ..RigidBodyState::default()
    };
    let target = Isometry3::translation(0.0, 20.0, 1.0);
    let tilt_asked = |gains: Pid4Gains| {
        let mut pid = Pid4::new(gains, body);
        pid.reset(&state);
        pid.update(&state, &target, 1.0 / 120.0);
        let r_d = pid
            .status()
            .attitude_target
            .unwrap_or_else(|| panic!("PID4 sets an attitude target"))
            .world_from_body;
        (r_d * Vector3::z()).angle(&Vector3::z())
    };
    let limited = tilt_asked(Pid4Gains::ua_hexa());
    let free = tilt_asked(Pid4Gains {
        max_tilt_rad: None,
        ..Pid4Gains::ua_hexa()
    });
    assert!(
        (limited - std::f64::consts::FRAC_PI_4).abs() < 1e-6,
        "{limited}"
    );
    assert!(free > 1.4, "{free}");
    // And π/2 or more is no limit.
    let wide = tilt_asked(Pid4Gains {
        max_tilt_rad: Some(1.6),
        ..Pid4Gains::ua_hexa()
    });
    assert_eq!(wide, free);
}
