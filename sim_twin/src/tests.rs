//! Twin tests: physics invariants, the disturbance models measured in the world, joint
//! drives against the platform's kinematics, determinism, bad commands.

use allocation::{AllocationMethod, Allocator};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use platform::{ActuatorCommand, GRAVITY_MPS2, Vehicle, Wrench};

use crate::{Disturbances, Twin, TwinConfig, TwinError};

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"))
}

fn twin(id: &str, config: TwinConfig) -> Twin {
    Twin::new(vehicle(id), config).unwrap_or_else(|e| panic!("{e}"))
}

fn step(twin: &mut Twin, command: &ActuatorCommand) {
    if let Err(e) = twin.step(command) {
        panic!("{e}");
    }
}

/// Rotors idle, joints held at their initial positions.
fn idle(v: &Vehicle) -> ActuatorCommand {
    ActuatorCommand {
        rotor_thrusts_n: vec![0.0; v.rotors.len()],
        joint_targets: v.initial_configuration(),
        direct_wrench_in_body: None,
    }
}

/// Open-loop hover: the allocator's answer to the weight and its centre-of-mass moment.
fn hover(v: &Vehicle) -> ActuatorCommand {
    let q0 = v.initial_configuration();
    let mp = v.mass_properties(&q0);
    let weight = Vector3::new(0.0, 0.0, mp.mass_kg * GRAVITY_MPS2);
    let wrench = Wrench::new(weight, mp.com_in_root_m.cross(&weight));
    let mut a = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
        .unwrap_or_else(|e| panic!("{e}"));
    let tilt = vec![
        0.0;
        if v.rotors.is_variable_tilt() {
            v.rotors.len()
        } else {
            0
        }
    ];
    let thrusts = a
        .allocate(&wrench, &tilt)
        .map(|al| al.thrusts_n)
        .unwrap_or_else(|e| panic!("{e}"));
    ActuatorCommand {
        rotor_thrusts_n: thrusts,
        joint_targets: q0,
        direct_wrench_in_body: None,
    }
}

/// One closed-loop tick: the PID's wrench toward `target`, allocated to the rotors, flown.
fn pid_tick(
    t: &mut Twin,
    pid: &mut controllers::Pid6,
    allocator: &mut Allocator,
    cmd: &mut ActuatorCommand,
    target: &Isometry3<f64>,
) {
    use controllers::BaseController;
    let dt = t.config().control_dt_s();
    let wrench = pid.update(&t.truth().base, target, dt);
    cmd.rotor_thrusts_n = allocator
        .allocate(&wrench, &[])
        .map(|a| a.thrusts_n)
        .unwrap_or_else(|e| panic!("{e}"));
    step(t, cmd);
}

#[test]
fn an_idle_vehicle_falls_at_g() {
    let v = vehicle("fa-hexa");
    let mut t = twin("fa-hexa", TwinConfig::default());
    let dt = t.config().control_dt_s();
    // rapier's first step after a world is built integrates gravity over one internal
    // sub-iteration less (Δv = 15/16 g·dt with 4 substeps × 4 iterations); from then on
    // every tick adds exactly −g·dt.
    step(&mut t, &idle(&v));
    let mut previous = t.truth().base.velocity_in_world_mps.z;
    assert!(
        (previous + GRAVITY_MPS2 * dt).abs() < 0.1 * GRAVITY_MPS2 * dt,
        "first tick {previous}"
    );
    for _ in 0..11 {
        step(&mut t, &idle(&v));
        let vz = t.truth().base.velocity_in_world_mps.z;
        assert!(
            (vz - previous + GRAVITY_MPS2 * dt).abs() < 1e-9,
            "Δv {}",
            vz - previous
        );
        previous = vz;
    }
    let time = t.time_s();
    let z = t.truth().base.position_in_world_m.z;
    assert!(
        (z - (1.0 - 0.5 * GRAVITY_MPS2 * time * time)).abs() < 2e-3,
        "z {z} after {time} s"
    );
    // Falling straight: no drift, no spin.
    assert!(t.truth().base.position_in_world_m.xy().norm() < 1e-9);
    assert!(t.truth().base.angular_velocity_in_body_radps.norm() < 1e-9);
}

#[test]
fn the_twin_end_effector_is_where_platform_kinematics_puts_it() {
    for id in platform::BUILTIN_IDS {
        let v = vehicle(id);
        let mut t = twin(id, TwinConfig::default());
        // Move every driven joint toward a pose away from the initial one.
        let mut cmd = idle(&v);
        for (q, d) in cmd.joint_targets.iter_mut().zip(0..) {
            let joint = v.model.dof_joint(d);
            let (lo, hi) = joint.limits.map_or((-1.0, 1.0), |l| (l.lower, l.upper));
            *q = lo + 0.37 * (hi - lo).min(2.0);
        }
        for _ in 0..30 {
            step(&mut t, &cmd);
        }
        let m = t.truth();
        let fk = m.base.pose() * v.model.root_from_link(&m.joint_positions, v.ee_link);
        let err = (fk.translation.vector - m.world_from_ee.translation.vector).norm();
        assert!(err < 1e-9, "{id}: twin vs FK {err} m");
        assert!(
            fk.rotation.angle_to(&m.world_from_ee.rotation) < 1e-9,
            "{id}"
        );
    }
}

#[test]
fn joint_drives_reach_their_targets_at_the_velocity_limit() {
    let v = vehicle("fa-hexa");
    let mut t = twin("fa-hexa", TwinConfig::default());
    let mut cmd = hover(&v);
    let shoulder = v.arm_dofs()[0];
    cmd.joint_targets[shoulder] = 1.0;
    // After 0.1 s a 5 rad/s limit allows at most 0.5 rad.
    for _ in 0..12 {
        step(&mut t, &cmd);
    }
    let q = t.truth().joint_positions[shoulder];
    assert!(q > 0.2 && q <= 0.5 + 1e-3, "q {q} after 0.1 s");
    for _ in 0..108 {
        step(&mut t, &cmd);
    }
    let q = t.truth().joint_positions[shoulder];
    assert!((q - 1.0).abs() < 2e-3, "q {q} after 1 s");
    // Targets outside the limits are clamped to them (joint 1: [0, 2.268928]).
    cmd.joint_targets[shoulder] = 9.0;
    for _ in 0..120 {
        step(&mut t, &cmd);
    }
    let q = t.truth().joint_positions[shoulder];
    assert!(q < 2.268928 + 5e-3, "q {q} beyond its upper limit");
}

/// A UA-Hexa (vertical rotors, r_p = 0.152 m) with its lowest rotors at `rotor_height_m`.
fn ground_gain_at(rotor_height_m: f64) -> f64 {
    let v = vehicle("ua-hexa");
    let rotor_z = v.rotors.rotors[0].position_in_base.z;
    let config = TwinConfig {
        disturbances: Disturbances {
            ground_effect: true,
            ..Disturbances::default()
        },
        initial_base_pose: Isometry3::translation(0.0, 0.0, rotor_height_m - rotor_z),
        ..TwinConfig::default()
    };
    let mut t = twin("ua-hexa", config);
    let m = t.step(&hover(&v)).unwrap_or_else(|e| panic!("{e}"));
    let r = &m.rotors[0];
    assert!(
        (r.ground_distance_m - rotor_height_m).abs() < 1e-9,
        "distance {}",
        r.ground_distance_m
    );
    assert!((r.applied_n / r.realised_n - r.ground_effect_gain).abs() < 1e-12);
    r.ground_effect_gain
}

#[test]
fn ground_effect_gain_in_the_twin_matches_the_model_table() {
    // AMBENCH_SPEC §3.2 with R = 0.152 m, b = 1, k = 0.171.
    assert!((ground_gain_at(0.03) - 1.2063).abs() < 5e-5, "z ≤ R/4");
    assert!((ground_gain_at(0.1) - 1.0253).abs() < 5e-5);
    assert!((ground_gain_at(0.2) - 1.0062).abs() < 5e-5);
}

#[test]
fn a_wall_pulls_a_rotor_toward_it_and_lifts_it() {
    let v = vehicle("ua-hexa");
    let config = TwinConfig {
        disturbances: Disturbances {
            near_wall: true,
            ..Disturbances::default()
        },
        ..TwinConfig::default()
    };
    let mut t = twin("ua-hexa", config);
    // Rotor 1 sits at (0, 0.375) in the base, radial direction +y; a wall face r_p beyond
    // it. The fan's rays lie at ±5°, ±15°, …, ±45° from the radial direction, so the
    // nearest hit is at r_p / cos 5°.
    let radius = v.rotors.propeller_radius_m;
    let face = 0.375 + radius;
    t.add_fixed_box(
        &Isometry3::translation(0.0, face + 0.5, 1.0),
        &Vector3::new(3.0, 0.5, 3.0),
    );
    let m = t.step(&hover(&v)).unwrap_or_else(|e| panic!("{e}"));
    let r = &m.rotors[1];
    let h = radius / 5f64.to_radians().cos();
    assert!(
        (r.wall_distance_m - h).abs() < 1e-9,
        "h {} vs {h}",
        r.wall_distance_m
    );
    // Vertical rotor: |T'| = T·√(γ_h² + γ_v²), γ at d̄ = (h − r_p)/r_p.
    let aero = crate::aero::AeroConfig::default();
    let d = (h - radius) / radius;
    let expected = r.realised_n * aero.wall_gamma_h(d).hypot(aero.wall_gamma_v(d));
    assert!(
        (r.applied_n - expected).abs() < 1e-9,
        "{} vs {expected}",
        r.applied_n
    );
    // The rotor on the far side (y = −0.375) sees nothing within reach of its own fan.
    assert!(m.rotors[4].wall_distance_m > 0.7);
    // The net extra force points toward the wall (+y) and up.
    let extra = m.disturbances.near_wall_n;
    assert!(extra.y > 0.0 && extra.z > 0.0, "{extra:?}");
}

#[test]
fn drag_is_minus_c_times_body_velocity() {
    let v = vehicle("fa-hexa");
    let yawed = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 1.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7),
    );
    let config = TwinConfig {
        disturbances: Disturbances {
            drag: true,
            ..Disturbances::default()
        },
        initial_base_pose: yawed,
        ..TwinConfig::default()
    };
    let mut t = twin("fa-hexa", config);
    t.set_base_velocity(&Vector3::new(2.0, -1.0, 0.5));
    let before = t.truth().base;
    let m = t.step(&hover(&v)).unwrap_or_else(|e| panic!("{e}"));
    let v_body = before.world_from_body.inverse() * before.velocity_in_world_mps;
    assert!(
        (m.disturbances.drag_n + v_body * 0.1).norm() < 1e-12,
        "{:?} vs {:?}",
        m.disturbances.drag_n,
        -v_body * 0.1
    );
    assert!(m.disturbances.wind_n.norm() < 1e-15, "wind is off");
}

#[test]
fn same_seed_same_commands_bit_identical() {
    let run = |seed: u64| {
        let v = vehicle("omni-hexa");
        let config = TwinConfig {
            disturbances: Disturbances::all(),
            seed,
            ..TwinConfig::default()
        };
        let mut t = twin("omni-hexa", config);
        t.add_fixed_box(
            &Isometry3::translation(0.6, 0.0, 1.0),
            &Vector3::new(0.05, 2.0, 2.0),
        );
        let cmd = hover(&v);
        let mut trace = Vec::new();
        for _ in 0..60 {
            let m = t.step(&cmd).unwrap_or_else(|e| panic!("{e}"));
            trace.extend(m.base.position_in_world_m.iter().map(|x| x.to_bits()));
            trace.extend(m.joint_positions.iter().map(|x| x.to_bits()));
            trace.extend(m.rotors.iter().map(|r| r.applied_n.to_bits()));
        }
        trace
    };
    assert_eq!(run(7), run(7));
    assert_ne!(run(7), run(8), "the seed drives the noise");
}

#[test]
fn reset_is_a_fresh_twin() {
    let v = vehicle("ua-quad");
    let mut a = twin("ua-quad", TwinConfig::default());
    for _ in 0..30 {
        step(&mut a, &idle(&v));
    }
    a.reset(0).unwrap_or_else(|e| panic!("{e}"));
    let b = twin("ua-quad", TwinConfig::default());
    assert_eq!(a.truth(), b.truth());
    assert!(a.time_s().abs() < 1e-15);
}

#[test]
fn commands_of_the_wrong_size_or_not_finite_are_refused() {
    let v = vehicle("fa-hexa");
    let mut t = twin("fa-hexa", TwinConfig::default());
    let mut cmd = idle(&v);
    cmd.rotor_thrusts_n.pop();
    assert!(
        matches!(t.step(&cmd), Err(TwinError::Command(m)) if m.contains("5 rotor thrusts for 6"))
    );
    let mut cmd = idle(&v);
    cmd.joint_targets[0] = f64::NAN;
    assert!(matches!(t.step(&cmd), Err(TwinError::Command(m)) if m.contains("not finite")));
    assert!(
        t.time_s().abs() < 1e-15,
        "a refused command does not advance time"
    );
}

#[test]
fn a_state_past_the_physical_bounds_ends_the_flight_saying_what_and_when() {
    // A vehicle thrown at 300 m/s (past the 200 m/s no flight reaches): the twin stops with
    // the body and the speed named, at the step's time, and refuses further steps.
    let v = vehicle("fa-hexa");
    let mut t = twin("fa-hexa", TwinConfig::default());
    for _ in 0..3 {
        step(&mut t, &hover(&v));
    }
    t.set_base_velocity(&Vector3::new(300.0, 0.0, 0.0));
    let first = t.step(&hover(&v));
    let Err(TwinError::Diverged(why)) = first else {
        panic!("{first:?}");
    };
    assert!(why.contains("at t = 0.025 s"), "{why}");
    assert!(
        why.contains("the vehicle's base moves at 300 m/s")
            || why.contains("a vehicle link moves at 300 m/s"),
        "{why}"
    );
    let again = t.step(&hover(&v));
    assert!(matches!(again, Err(TwinError::Diverged(_))), "{again:?}");
}

#[test]
fn invalid_configs_are_refused() {
    let motor_without_limits = TwinConfig {
        motor: crate::MotorConfig {
            time_constant_s: Some(0.0475),
            rate_limit_per_s: None,
        },
        ..TwinConfig::default()
    };
    assert!(
        matches!(Twin::new(vehicle("fa-hexa"), motor_without_limits), Err(TwinError::Config(m)) if m.contains("saturation"))
    );
    let zero_rate = TwinConfig {
        control_rate_hz: 0.0,
        ..TwinConfig::default()
    };
    assert!(Twin::new(vehicle("fa-hexa"), zero_rate).is_err());
    assert_eq!(
        Disturbances::parse_list("drag, ground,wall"),
        Ok(Disturbances {
            drag: true,
            ground_effect: true,
            near_wall: true,
            ..Disturbances::default()
        })
    );
    assert!(Disturbances::parse_list("drag,gravity").is_err_and(|m| m.contains("'gravity'")));
}

/// An ideal rotor (no limits) commanded a negative thrust pushes backwards, and the report's
/// applied thrust keeps the sign (it was the vector's norm, always positive).
#[test]
fn a_reversed_ideal_rotor_reports_a_negative_applied_thrust() {
    let v = Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
    let mut t = Twin::new(v.clone(), TwinConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let mut cmd = hover(&v);
    cmd.rotor_thrusts_n[0] = -1.5;
    let m = t.step(&cmd).unwrap_or_else(|e| panic!("{e}"));
    // No ground or near-wall effect by default: applied = realised = commanded.
    assert_eq!(m.rotors[0].realised_n, -1.5);
    assert_eq!(m.rotors[0].applied_n, -1.5);
    assert!(m.rotors[1].applied_n > 0.0);
}

/// Gravity's force on the vehicle and its torque about the world origin at the current poses.
fn gravity_wrench(t: &Twin) -> (Vector3<f64>, Vector3<f64>) {
    use crate::convert::{pose_from_rapier, vector_from_rapier};
    let g = Vector3::new(0.0, 0.0, -GRAVITY_MPS2);
    let mut f = Vector3::zeros();
    let mut tau = Vector3::zeros();
    for h in &t.body.bodies {
        let rb = &t.world().bodies[*h];
        // The centre of mass from the pose (a kinematic body's world copy is not kept).
        let local = vector_from_rapier(rb.mass_properties().local_mprops.local_com);
        let c = (pose_from_rapier(rb.position()) * nalgebra::Point3::from(local)).coords;
        f += rb.mass() * g;
        tau += c.cross(&(rb.mass() * g));
    }
    (f, tau)
}

/// Momentum balance over a 10 s arm sweep in closed-loop hover (PID6 + pseudo-inverse
/// allocation, no disturbances, no contact): the change of the vehicle's linear and angular
/// momentum equals the impulse of gravity and of the rotor forces. The impulse is summed by
/// the trapezoidal rule over the poses at the start and end of each tick (the twin re-applies
/// the rotor forces at the current poses each substep), so the residual is that quadrature's
/// error plus the integrator's. The tolerance is 1e-4 of the gross impulse (the summed
/// magnitudes of the gravity and rotor impulses, ≈ 2 m g T ≈ 1300 N s): 0.13 N s and
/// 0.13 N m s, where the residuals measured are 0.042 N s and 0.051 N m s on rapier's
/// multibody (4 substeps) and 0.0058 and 0.0059 on the vehicle's own dynamics (16 steps per
/// tick; 0.131 and 0.151 when a substep's steps shared one mass matrix); a rotor's force
/// lost for two ticks (≈ 0.18 N s) or a joint motor pushing on the world over the sweep
/// exceeds it. Both engines, each momentum read from the engine holding the vehicle.
#[test]
fn momentum_change_equals_the_impulse_of_gravity_and_rotors_over_an_arm_sweep() {
    momentum_balance_over_an_arm_sweep(crate::VehicleDynamics::Rapier, None);
    momentum_balance_over_an_arm_sweep(crate::VehicleDynamics::Articulated, None);
    // One step of the vehicle's own dynamics per substep (its fastest setting).
    momentum_balance_over_an_arm_sweep(crate::VehicleDynamics::Articulated, Some(1));
}

fn momentum_balance_over_an_arm_sweep(
    vehicle_dynamics: crate::VehicleDynamics,
    own_dynamics_steps: Option<u32>,
) {
    use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
    let v = vehicle("fa-hexa");
    let mut t = twin(
        "fa-hexa",
        TwinConfig {
            vehicle_dynamics,
            own_dynamics_steps,
            ..TwinConfig::default()
        },
    );
    // The rotor forces of a tick are only known once it ran: start from a tick at rest.
    let mut cmd = hover(&v);
    step(&mut t, &cmd);
    let mut allocator = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&v));
    pid.reset(&t.truth().base);
    let target = Isometry3::translation(0.0, 0.0, 1.0);
    let dt = t.config().control_dt_s();
    let q0 = v.initial_configuration();
    let arm = v.arm_dofs();
    let (p_start, l_start) = t.vehicle_momentum();
    let (mut impulse, mut angular_impulse) = (Vector3::zeros(), Vector3::zeros());
    let mut gross = 0.0;
    let ticks = (10.0 / dt).round() as usize;
    for k in 0..ticks {
        let time = k as f64 * dt;
        for (n, &d) in arm.iter().enumerate() {
            let phase = 2.0 * std::f64::consts::PI * (time / 2.5 + n as f64 / 4.0);
            cmd.joint_targets[d] = q0[d] + 0.6 * phase.sin();
        }
        let wrench = pid.update(&t.truth().base, &target, dt);
        cmd.rotor_thrusts_n = allocator
            .allocate(&wrench, &[])
            .map(|a| a.thrusts_n)
            .unwrap_or_else(|e| panic!("{e}"));
        // Gravity at the poses before the tick; the rotors' forces are those the tick fixed,
        // at the poses before and after it.
        let (gravity_start, gravity_torque_start) = gravity_wrench(&t);
        let rotors_at_start = rotor_poses(&t);
        step(&mut t, &cmd);
        let (rotor_f_start, rotor_tau_start) = rotor_wrench_at(&t, &rotors_at_start);
        let (rotor_f_end, rotor_tau_end) = rotor_wrench_at(&t, &rotor_poses(&t));
        let (gravity_end, gravity_torque_end) = gravity_wrench(&t);
        let f_start = gravity_start + rotor_f_start;
        let tau_start = gravity_torque_start + rotor_tau_start;
        let f_end = gravity_end + rotor_f_end;
        let tau_end = gravity_torque_end + rotor_tau_end;
        impulse += 0.5 * dt * (f_start + f_end);
        angular_impulse += 0.5 * dt * (tau_start + tau_end);
        gross += dt * (gravity_start.norm() + rotor_f_start.norm());
    }
    // The vehicle hovered and the arm swept: the test exercised what it claims.
    let m = t.truth();
    assert!((m.base.position_in_world_m - Vector3::new(0.0, 0.0, 1.0)).norm() < 0.2);
    let swept = arm
        .iter()
        .map(|&d| (m.joint_positions[d] - q0[d]).abs())
        .fold(0.0, f64::max);
    assert!(gross > 1.5 * 9.0 * 10.0, "gross impulse {gross} N s");
    let (p_end, l_end) = t.vehicle_momentum();
    let linear_residual = (p_end - p_start - impulse).norm();
    let angular_residual = (l_end - l_start - angular_impulse).norm();
    let tolerance = 1e-4 * gross;
    println!(
        "{vehicle_dynamics:?} ({own_dynamics_steps:?} steps): arm swept up to {swept:.3} rad; gross impulse {gross:.1} N s; Δp {:.4} vs impulse {:.4} \
         (residual {linear_residual:.2e} N s); ΔL {:.4} vs angular impulse {:.4} (residual \
         {angular_residual:.2e} N m s); tolerance {tolerance:.2e}",
        (p_end - p_start).norm(),
        impulse.norm(),
        (l_end - l_start).norm(),
        angular_impulse.norm()
    );
    assert!(swept > 0.3, "the arm barely moved: {swept} rad");
    assert!(
        linear_residual < tolerance,
        "linear momentum residual {linear_residual} N s"
    );
    assert!(
        angular_residual < tolerance,
        "angular momentum residual {angular_residual} N m s"
    );
}

/// Each rotor's world pose now.
fn rotor_poses(t: &Twin) -> Vec<Isometry3<f64>> {
    use crate::convert::pose_from_rapier;
    t.rotors
        .iter()
        .map(|r| pose_from_rapier(t.world().bodies[r.body].position()) * r.body_from_rotor)
        .collect()
}

/// The rotors' force (the last tick's, fixed in each rotor frame) and torque about the world
/// origin with the rotors at `world_from_rotor`.
fn rotor_wrench_at(t: &Twin, world_from_rotor: &[Isometry3<f64>]) -> (Vector3<f64>, Vector3<f64>) {
    let k_f = t.vehicle().rotors.reaction_torque_ratio_m;
    let mut f = Vector3::zeros();
    let mut tau = Vector3::zeros();
    for (r, pose) in t.rotors.iter().zip(world_from_rotor) {
        let force = pose.rotation * r.force_in_rotor;
        f += force;
        tau += pose.translation.vector.cross(&force) + force * (r.reaction_sign * k_f);
    }
    (f, tau)
}

/// The twin's vehicle state as ours: (world from base, q, ν).
fn tree_state_of(m: &platform::Measurement) -> platform::TreeState {
    let base = &m.base;
    let r = base.world_from_body;
    let mut nu = nalgebra::DVector::zeros(6 + m.joint_positions.len());
    nu.fixed_rows_mut::<3>(0)
        .copy_from(&(r.inverse() * base.velocity_in_world_mps));
    nu.fixed_rows_mut::<3>(3)
        .copy_from(&base.angular_velocity_in_body_radps);
    for (d, qd) in m.joint_velocities.iter().enumerate() {
        nu[6 + d] = *qd;
    }
    platform::TreeState {
        world_from_base: Isometry3::from_parts(Translation3::from(base.position_in_world_m), r),
        q: m.joint_positions.clone(),
        nu,
    }
}

/// One closed-loop arm-sweep flight of the FA-Hexa (PID6 + pseudo-inverse allocation, the arm's
/// four joints swept ±0.6 rad at 0.4 Hz, 5 s), its vehicle dynamics either the twin's (rapier's
/// multibody at `config`'s substeps and solver iterations) or ours (`platform::ArticulatedBody`
/// with implicit drives, `substeps` steps per tick): base positions and joint positions per tick.
fn arm_sweep_flight(
    config: Option<&TwinConfig>,
    substeps: u32,
) -> Vec<(Vector3<f64>, UnitQuaternion<f64>, Vec<f64>)> {
    use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
    use platform::{ArticulatedBody, Drive, RigidBodyState};
    let v = vehicle("fa-hexa");
    let mut t = twin("fa-hexa", config.cloned().unwrap_or_default());
    let mut allocator = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&v));
    pid.reset(&t.truth().base);
    let target = Isometry3::translation(0.0, 0.0, 1.0);
    let dt = t.config().control_dt_s();
    let q0 = v.initial_configuration();
    let arm = v.arm_dofs();
    let mut cmd = hover(&v);
    // Ours starts where the twin starts.
    let tree = ArticulatedBody::new(&v.model);
    let mut ws = tree.workspace();
    let mut ours = tree_state_of(t.truth());
    let mut setpoints: Vec<f64> = ours.q.clone();
    let k_f = v.rotors.reaction_torque_ratio_m;
    let mut out = Vec::new();
    for k in 0..600u32 {
        let time = f64::from(k) * dt;
        for (n, &d) in arm.iter().enumerate() {
            let phase = 2.0 * std::f64::consts::PI * (time / 2.5 + n as f64 / 4.0);
            cmd.joint_targets[d] = q0[d] + 0.6 * phase.sin();
        }
        let state = if config.is_some() {
            t.truth().base
        } else {
            let r = ours.world_from_base.rotation;
            RigidBodyState {
                position_in_world_m: ours.world_from_base.translation.vector,
                world_from_body: r,
                velocity_in_world_mps: r * Vector3::new(ours.nu[0], ours.nu[1], ours.nu[2]),
                angular_velocity_in_body_radps: Vector3::new(ours.nu[3], ours.nu[4], ours.nu[5]),
            }
        };
        let wrench = pid.update(&state, &target, dt);
        cmd.rotor_thrusts_n = allocator
            .allocate(&wrench, &[])
            .map(|a| a.thrusts_n)
            .unwrap_or_else(|e| panic!("{e}"));
        if config.is_some() {
            step(&mut t, &cmd);
            let m = t.truth();
            out.push((
                m.base.position_in_world_m,
                m.base.world_from_body,
                m.joint_positions.clone(),
            ));
            continue;
        }
        // The rotors' wrench on the base, fixed in base axes over the tick (ideal rotors).
        let mut tau = nalgebra::DVector::zeros(tree.nv());
        for (rotor, thrust) in v.rotors.rotors.iter().zip(&cmd.rotor_thrusts_n) {
            let force = rotor.axis_in_base.into_inner() * *thrust;
            let torque = rotor.position_in_base.cross(&force) + force * (rotor.spin.sign() * k_f);
            for i in 0..3 {
                tau[i] += force[i];
                tau[3 + i] += torque[i];
            }
        }
        let h = dt / f64::from(substeps);
        for _ in 0..substeps {
            // The twin's drives: setpoints slewed at the velocity limit, then PD.
            let drives: Vec<Drive> = v
                .drives
                .iter()
                .filter_map(|d| {
                    let joint = &v.model.joints[d.joint];
                    let dof = joint.dof?;
                    // As the twin: the target within the joint's limits, the setpoint slewed.
                    let goal = joint.limits.map_or(cmd.joint_targets[dof], |l| {
                        cmd.joint_targets[dof].clamp(l.lower, l.upper)
                    });
                    let step = d.velocity_limit * h;
                    setpoints[dof] += (goal - setpoints[dof]).clamp(-step, step);
                    Some(Drive {
                        dof,
                        stiffness: d.stiffness,
                        damping: d.damping,
                        target: setpoints[dof],
                        effort_limit: d.effort_limit,
                    })
                })
                .collect();
            assert!(
                tree.step(&mut ours, &tau, &[], &drives, h, &mut ws),
                "our step failed"
            );
        }
        out.push((
            ours.world_from_base.translation.vector,
            ours.world_from_base.rotation,
            ours.q.clone(),
        ));
    }
    out
}

/// RMS over the flight of the base position (mm), attitude (mrad) and arm joints (mrad)
/// between two flights.
fn flight_gap(
    a: &[(Vector3<f64>, UnitQuaternion<f64>, Vec<f64>)],
    b: &[(Vector3<f64>, UnitQuaternion<f64>, Vec<f64>)],
    arm: &[usize],
) -> (f64, f64, f64) {
    let n = a.len() as f64;
    let (mut p, mut r, mut q) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        p += (x.0 - y.0).norm_squared();
        r += x.1.angle_to(&y.1).powi(2);
        q += arm.iter().map(|&d| (x.2[d] - y.2[d]).powi(2)).sum::<f64>() / arm.len() as f64;
    }
    (
        1e3 * (p / n).sqrt(),
        1e3 * (r / n).sqrt(),
        1e3 * (q / n).sqrt(),
    )
}

/// The twin's rapier multibody against the vehicle's own rigid-body dynamics
/// (`platform::ArticulatedBody`, checked against Pinocchio by scripts/pinocchio-peer.sh) on the
/// same closed-loop arm sweep, both against ours at 64 steps per tick (converged: its error
/// falls with the step). Measured (RMS base mm / attitude mrad / arm joints mrad): ours at 1
/// and 4 steps per tick 2.21 / 21.07 / 2.63 and 0.27 / 2.63 / 0.33; the rapier twin at its
/// default 4 substeps × 4 solver iterations 0.11 / 1.21 / 0.54, at 2 × 2 1.92 / 21.43 / 0.57,
/// at 1 × 1 2.14 / 21.57 / 3.02, at 8 × 8 0.14 / 1.01 / 0.35. The bounds on rapier's 4 × 4
/// keep it within ~2.5× of that (2 × 2 breaks the attitude's). The twin on its own dynamics
/// (the default, 4 steps per substep) 0.39 / 2.49 / 0.53, at 2 and 1 steps per substep
/// (`own_dynamics_steps`) 0.22 / 1.23 / 0.31 and 0.27 / 2.63 / 0.33 — the last is ours at 4
/// steps per tick to round-off. rapier's default split since `rapier_steps` (2 solver steps
/// of 2 passes per substep, the multibody's mass matrix rebuilt twice instead of 4 times)
/// 0.57 / 5.62 / 0.31 in this free flight, which the twin flies on its own dynamics.
/// `cargo test -p sim_twin --lib rapier_multibody_against -- --nocapture` prints the table.
#[test]
fn rapier_multibody_against_our_articulated_dynamics_on_an_arm_sweep() {
    let v = vehicle("fa-hexa");
    let arm = v.arm_dofs();
    let reference = arm_sweep_flight(None, 64);
    let twin = |p: u32, i: u32| {
        arm_sweep_flight(
            Some(&TwinConfig {
                physics_substeps: p,
                solver_iterations: i,
                vehicle_dynamics: crate::VehicleDynamics::Rapier,
                // i solver steps of one pass each (rapier's split before `rapier_steps`).
                rapier_steps: None,
                ..TwinConfig::default()
            }),
            0,
        )
    };
    let rows = [
        ("ours, 1 step per tick", arm_sweep_flight(None, 1)),
        ("ours, 4 steps per tick", arm_sweep_flight(None, 4)),
        ("twin 4 x 4 (rapier)", twin(4, 4)),
        ("twin 2 x 2", twin(2, 2)),
        ("twin 1 x 1", twin(1, 1)),
        ("twin 8 x 8", twin(8, 8)),
        (
            "twin articulated, 4",
            arm_sweep_flight(
                Some(&TwinConfig {
                    vehicle_dynamics: crate::VehicleDynamics::Articulated,
                    own_dynamics_steps: Some(4),
                    ..TwinConfig::default()
                }),
                0,
            ),
        ),
        (
            "twin articulated, 2",
            arm_sweep_flight(
                Some(&TwinConfig {
                    vehicle_dynamics: crate::VehicleDynamics::Articulated,
                    own_dynamics_steps: Some(2),
                    ..TwinConfig::default()
                }),
                0,
            ),
        ),
        (
            "twin articulated, 1",
            arm_sweep_flight(
                Some(&TwinConfig {
                    vehicle_dynamics: crate::VehicleDynamics::Articulated,
                    own_dynamics_steps: Some(1),
                    ..TwinConfig::default()
                }),
                0,
            ),
        ),
        (
            "twin 4 x (2 steps, 2 passes)",
            arm_sweep_flight(
                Some(&TwinConfig {
                    vehicle_dynamics: crate::VehicleDynamics::Rapier,
                    ..TwinConfig::default()
                }),
                0,
            ),
        ),
    ];
    println!("RMS from ours at 64 steps per tick: base mm, attitude mrad, arm joints mrad");
    let gaps: Vec<(f64, f64, f64)> = rows
        .iter()
        .map(|(name, flight)| {
            let (p, r, q) = flight_gap(flight, &reference, &arm);
            println!("{name:24} {p:9.4} {r:9.4} {q:9.4}");
            (p, r, q)
        })
        .collect();
    // At one step per substep the twin is the stand-alone dynamics at 4 steps per tick: the
    // same forces, drives and steps through the twin's rapier bodies and hand-over code
    // (measured 5.7e-14 mm, 1.3e-14 mrad, 7e-18 mrad).
    let (p, r, q) = flight_gap(&rows[8].1, &rows[1].1, &arm);
    println!("twin articulated, 1 against ours at 4 steps per tick: {p:.2e} {r:.2e} {q:.2e}");
    assert!(
        p < 1e-9 && r < 1e-9 && q < 1e-9,
        "the twin's own dynamics are not the platform's: {p} mm, {r} mrad, {q} mrad"
    );
    // The arm swept: the comparison is of a moving tree.
    let swept = reference
        .iter()
        .map(|s| (s.2[arm[0]] - v.initial_configuration()[arm[0]]).abs())
        .fold(0.0, f64::max);
    assert!(swept > 0.3, "the arm barely moved: {swept} rad");
    // Ours converges as its step shrinks (semi-implicit Euler: at least first order).
    let (one, four) = (gaps[0], gaps[1]);
    assert!(
        four.0 < one.0 / 4.0 && four.1 < one.1 / 4.0 && four.2 < one.2 / 4.0,
        "ours does not converge: 1 step {one:?}, 4 steps {four:?}"
    );
    let (p, r, q) = gaps[2];
    assert!(
        p < 0.3 && r < 3.0 && q < 1.5,
        "the rapier twin at 4 x 4 left our dynamics: {p} mm, {r} mrad, {q} mrad"
    );
    // The twin flying our dynamics (the default; 4 substeps × 4 steps, the mass matrix kept
    // through a substep, the setpoints slewed per substep): measured 0.39 / 2.47 / 0.53.
    let (p, r, q) = gaps[6];
    assert!(
        p < 1.0 && r < 5.0 && q < 1.5,
        "the twin's articulated dynamics left the converged flight: {p} mm, {r} mrad, {q} mrad"
    );
}

/// The twin flying its own articulated dynamics is bit-for-bit reproducible, and its bodies
/// in rapier are where the dynamics put them (the EE pose of the measurement is read from
/// rapier's kinematic body; the platform's FK at the measured joints must agree).
#[test]
fn the_articulated_twin_is_deterministic_and_its_bodies_follow_the_dynamics() {
    let v = vehicle("fa-hexa");
    let config = TwinConfig {
        vehicle_dynamics: crate::VehicleDynamics::Articulated,
        disturbances: Disturbances::all(),
        ..TwinConfig::default()
    };
    let fly = || {
        let mut t = twin("fa-hexa", config.clone());
        let mut cmd = hover(&v);
        let arm = v.arm_dofs();
        for k in 0..240u32 {
            // Within the first joint's limits (its lower one is 0).
            cmd.joint_targets[arm[0]] = 0.3 * (f64::from(k) / 120.0).min(1.0);
            step(&mut t, &cmd);
        }
        t
    };
    let (a, b) = (fly(), fly());
    assert_eq!(a.truth(), b.truth(), "two flights from one seed differ");
    let m = a.truth();
    let fk = m.base.pose() * v.model.root_from_link(&m.joint_positions, v.ee_link);
    let gap = (fk.translation.vector - m.world_from_ee.translation.vector).norm();
    assert!(
        gap < 1e-9,
        "EE body {gap:e} m from the FK at the measured joints"
    );
    assert!(
        (m.joint_positions[v.arm_dofs()[0]]).abs() > 0.1,
        "the arm did not move: {:?}",
        m.joint_positions
    );
}

/// Drag and wind act on the articulated twin where they act on rapier's bodies (at the base's
/// centre of mass): the same closed-loop 1 m step with both on tilts the base alike. A
/// first version applied them at the centre of mass rotated but not translated, a spurious
/// torque: 1.92 against rapier's 1.19 mrad of tilt on `track --trajectory step`.
#[test]
fn the_articulated_twin_feels_drag_and_wind_where_rapier_does() {
    use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
    let v = vehicle("fa-hexa");
    let fly = |vehicle_dynamics| {
        let config = TwinConfig {
            vehicle_dynamics,
            disturbances: Disturbances {
                drag: true,
                wind: true,
                ..Disturbances::default()
            },
            ..TwinConfig::default()
        };
        let mut t = twin("fa-hexa", config);
        let mut allocator = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&v));
        pid.reset(&t.truth().base);
        let target = Isometry3::translation(1.0, 0.0, 1.0);
        let mut cmd = hover(&v);
        let mut max_tilt: f64 = 0.0;
        for _ in 0..360 {
            pid_tick(&mut t, &mut pid, &mut allocator, &mut cmd, &target);
            let (roll, pitch, _) = t.truth().base.world_from_body.euler_angles();
            max_tilt = max_tilt.max(roll.hypot(pitch));
        }
        (max_tilt, t.truth().base.position_in_world_m)
    };
    let (tilt_rapier, end_rapier) = fly(crate::VehicleDynamics::Rapier);
    let (tilt_ours, end_ours) = fly(crate::VehicleDynamics::Articulated);
    assert!(end_rapier.x > 0.5, "the step was not flown: {end_rapier:?}");
    assert!(
        (tilt_ours - tilt_rapier).abs() < 0.2 * tilt_rapier,
        "max tilt {tilt_ours} rad (articulated) against {tilt_rapier} rad (rapier)"
    );
    assert!(
        (end_ours - end_rapier).norm() < 0.01,
        "end {end_ours:?} against {end_rapier:?}"
    );
}

/// The articulated twin hands the vehicle to rapier's multibody and back without changing
/// its state: mid-flight (base translating and turning, arm joints moving), the measurement
/// read from the multibody right after the hand-over equals the one of the vehicle's own
/// dynamics, and taking it back gives the same state again (to rounding).
#[test]
fn handing_the_vehicle_between_engines_keeps_its_state() {
    let v = vehicle("fa-hexa");
    let config = TwinConfig {
        vehicle_dynamics: crate::VehicleDynamics::Articulated,
        ..TwinConfig::default()
    };
    let mut t = twin("fa-hexa", config);
    let mut cmd = hover(&v);
    // Uneven thrusts turn and push the base; the arm swings.
    cmd.rotor_thrusts_n[0] *= 1.2;
    cmd.rotor_thrusts_n[3] *= 0.9;
    let arm = v.arm_dofs();
    t.set_base_velocity(&Vector3::new(0.4, -0.2, 0.1));
    for k in 0..30u32 {
        cmd.joint_targets[arm[0]] = 0.02 * f64::from(k);
        cmd.joint_targets[arm[1]] = -0.01 * f64::from(k);
        step(&mut t, &cmd);
    }
    assert!(
        t.on_own_dynamics(),
        "free flight runs on the vehicle's dynamics"
    );
    let ours = t.measure(&[], platform::DisturbanceReport::default());
    assert!(
        ours.base.angular_velocity_in_body_radps.norm() > 0.05
            && ours.joint_velocities[arm[0]].abs() > 0.1,
        "not a moving state: {:?}",
        ours
    );
    let close = |a: &platform::Measurement, b: &platform::Measurement, what: &str| {
        let gaps = [
            (a.base.position_in_world_m - b.base.position_in_world_m).norm(),
            a.base.world_from_body.angle_to(&b.base.world_from_body),
            (a.base.velocity_in_world_mps - b.base.velocity_in_world_mps).norm(),
            (a.base.angular_velocity_in_body_radps - b.base.angular_velocity_in_body_radps).norm(),
            (a.world_from_ee.translation.vector - b.world_from_ee.translation.vector).norm(),
        ];
        let joints = a
            .joint_positions
            .iter()
            .zip(&b.joint_positions)
            .chain(a.joint_velocities.iter().zip(&b.joint_velocities))
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(
            gaps.iter().all(|g| *g < 1e-12) && joints < 1e-12,
            "{what}: base position, attitude, velocity, angular velocity, EE {gaps:?}, joints {joints:e}"
        );
    };
    t.hand_to_rapier().unwrap_or_else(|e| panic!("{e}"));
    assert!(!t.on_own_dynamics());
    close(
        &ours,
        &t.measure(&[], platform::DisturbanceReport::default()),
        "rapier's multibody",
    );
    t.take_from_rapier();
    close(
        &ours,
        &t.measure(&[], platform::DisturbanceReport::default()),
        "back on the vehicle's dynamics",
    );
}

/// Flying into a wall, the articulated twin's vehicle is stopped by it as rapier's is: rapier's
/// multibody takes the vehicle over within `CONTACT_MARGIN_M` (the vehicle's own dynamics
/// feels no contact: before the hand-over existed its rotor arms passed through the wall),
/// the two closed-loop flights (pressing 3 cm into the wall, then back to the start) agree
/// as closely as rapier's own flight at 8 substeps does, and the vehicle's own dynamics takes
/// over again once it has backed away.
#[test]
fn the_articulated_twin_is_stopped_by_a_wall_as_rapier_is() {
    use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
    let v = vehicle("fa-hexa");
    // The wall's face at x = 0.8 m; the rotor arms reach to x ≈ 0.49 m at the start.
    let face_x = 0.8;
    let fly = |vehicle_dynamics, physics_substeps, rapier_steps| {
        let mut t = twin(
            "fa-hexa",
            TwinConfig {
                vehicle_dynamics,
                physics_substeps,
                rapier_steps,
                ..TwinConfig::default()
            },
        );
        t.add_fixed_box(
            &Isometry3::translation(face_x + 0.1, 0.0, 1.0),
            &Vector3::new(0.1, 1.0, 1.0),
        );
        let mut allocator = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&v));
        pid.reset(&t.truth().base);
        let mut cmd = hover(&v);
        let (mut own, mut path) = (Vec::new(), Vec::new());
        for k in 0..480 {
            let target = Isometry3::translation(if k < 240 { 0.33 } else { 0.0 }, 0.0, 1.0);
            pid_tick(&mut t, &mut pid, &mut allocator, &mut cmd, &target);
            own.push(t.on_own_dynamics());
            path.push(t.truth().base.position_in_world_m);
        }
        (own, path)
    };
    let (_, path_rapier) = fly(crate::VehicleDynamics::Rapier, 4, Some(2));
    let (own, path_ours) = fly(crate::VehicleDynamics::Articulated, 4, Some(2));
    let (_, path_fine) = fly(crate::VehicleDynamics::Rapier, 8, Some(2));
    // rapier's solver split into 4 steps of one pass (its mass matrix rebuilt at each, the
    // split before `rapier_steps`) instead of the default 2 steps of 2 passes.
    let (_, path_split) = fly(crate::VehicleDynamics::Rapier, 4, None);
    let gap8 = path_rapier
        .iter()
        .zip(&path_fine)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    // Unstopped, the base would fly to x = 1 m.
    let reach = |path: &[Vector3<f64>]| path.iter().map(|p| p.x).fold(f64::MIN, f64::max);
    let (reach_rapier, reach_ours) = (reach(&path_rapier), reach(&path_ours));
    assert!(
        (0.25..0.4).contains(&reach_rapier) && (0.25..0.4).contains(&reach_ours),
        "the base went to x = {reach_rapier} m (rapier), {reach_ours} m (articulated)"
    );
    let gap = path_rapier
        .iter()
        .zip(&path_ours)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    // Measured: 0.8 mm against 25 mm with rapier's 2-step split (3.3 against 4.5 mm with its
    // 4 steps of one pass; the contact slides the vehicle ~10 cm down the wall, and where
    // the slide stops moves the largest gap).
    assert!(
        gap < gap8,
        "the articulated twin parts from rapier's by {gap} m, rapier at 8 substeps by {gap8} m"
    );
    // How far the contact slides the vehicle down the wall: the default split (2 solver
    // steps of 2 passes per substep) as rapier converged at 16 substeps of 4 steps, where one
    // step of 4 passes slides it further. Measured lowest base z: 0.8904 m (default), 0.8917
    // (16 substeps), 0.8914 (4 steps of one pass, the split before `rapier_steps`), 0.8594
    // (one step of 4 passes).
    let lowest = |path: &[Vector3<f64>]| path.iter().map(|p| p.z).fold(f64::MAX, f64::min);
    let (_, path_converged) = fly(crate::VehicleDynamics::Rapier, 16, None);
    let (_, path_one_step) = fly(crate::VehicleDynamics::Rapier, 4, Some(1));
    let (z, z_converged, z_split, z_one) = (
        lowest(&path_rapier),
        lowest(&path_converged),
        lowest(&path_split),
        lowest(&path_one_step),
    );
    println!(
        "gaps: articulated {gap:.4} m, rapier at 8 substeps {gap8:.4} m; lowest base z: default {z:.4}, 16 substeps {z_converged:.4}, 4 steps {z_split:.4}, one step {z_one:.4}"
    );
    assert!(
        z_converged < 0.95
            && (z - z_converged).abs() < 0.003
            && (z_split - z_converged).abs() < 0.003,
        "the contact slid the base to z = {z} m (default), {z_converged} (16 substeps), {z_split} (4 steps)"
    );
    assert!(
        z_one < z_converged - 0.01,
        "one solver step slides as far as the converged flight: {z_one} m against {z_converged} m"
    );
    // Own dynamics in free flight, rapier's near the wall, own again after backing away.
    let first_rapier = own.iter().position(|o| !o);
    let back = own.iter().rposition(|o| !o);
    assert!(own[0], "the flight started on rapier's multibody");
    assert!(
        first_rapier.is_some_and(|k| k > 5) && back.is_some_and(|k| k < 470) && own[479],
        "engines along the flight: {own:?}"
    );
}

/// The FA-Hexa flown 6 cm forward with a fixed block 2 cm ahead of its palm: the twin reports
/// no hand contact in free flight and, once the palm presses the block, a contact whose
/// normal points out of the block's face (−x) — what the whole-body MPC keeps its target on
/// the near side of (`MpcConfig::contact_reference`).
#[test]
fn the_hand_pressing_a_fixed_block_reports_the_blocks_face_normal() {
    use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
    let v = vehicle("fa-hexa");
    let mut t = twin("fa-hexa", TwinConfig::default());
    let ee = t.truth().world_from_ee;
    // The palm (ee_link's box) reaches 0.08 m ahead of the EE link along its x.
    let palm_front = ee * nalgebra::Point3::new(0.08, 0.0, 0.0);
    let half = Vector3::new(0.05, 0.03, 0.03);
    t.add_fixed_box(
        &Isometry3::translation(palm_front.x + 0.02 + half.x, palm_front.y, palm_front.z),
        &half,
    );
    assert_eq!(t.hand_contact(), None, "touching before the flight");
    let mut allocator = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&v));
    pid.reset(&t.truth().base);
    let start = t.truth().base.position_in_world_m;
    let target = Isometry3::translation(start.x + 0.06, start.y, start.z);
    let mut cmd = hover(&v);
    let mut contacts = Vec::new();
    for _ in 0..240 {
        pid_tick(&mut t, &mut pid, &mut allocator, &mut cmd, &target);
        contacts.push(t.hand_contact());
    }
    let first = contacts.iter().position(Option::is_some);
    assert!(
        first.is_some_and(|k| k > 10),
        "the first contact at tick {first:?}"
    );
    let Some(Some(normal)) = contacts.last() else {
        panic!("no contact at the end of the press: {contacts:?}");
    };
    assert!(
        (normal + Vector3::x()).norm() < 0.05,
        "the contact's normal {normal}"
    );
    // Stopped by the block: the base 2 cm on, not 6.
    let moved = t.truth().base.position_in_world_m.x - start.x;
    assert!((0.01..0.04).contains(&moved), "the base moved {moved} m");
}

/// What a touched object gives way to: a fixed body nothing; Push Slider's knob (a rail
/// along y) a push along the rail but not one at its end (its axis, x); a valve's handle
/// (turning about z through the origin, touched at (0.2, 0, 0)) a push along the circle's
/// tangent (y) but not one toward the axis.
#[test]
fn a_contact_is_blocked_where_the_touched_object_does_not_move() {
    use crate::tasks::HeldJoint;
    use crate::twin::blocked_part;
    let rail = HeldJoint::Prismatic {
        axis: Vector3::new(0.0, 2.0, 0.0),
    };
    let shaft = HeldJoint::Revolute {
        axis: Vector3::z(),
        point: Vector3::zeros(),
    };
    let at = Vector3::new(0.2, 0.0, 0.0);
    let n = |v: Vector3<f64>| blocked_part(&v, None, &at);
    assert_eq!(n(-Vector3::x()), -Vector3::x());
    let end = blocked_part(&-Vector3::x(), Some(&rail), &at);
    assert!((end + Vector3::x()).norm() < 1e-12, "{end}");
    let side = blocked_part(&Vector3::y(), Some(&rail), &at);
    assert!(side.norm() < 1e-12, "{side}");
    let tangential = blocked_part(&-Vector3::y(), Some(&shaft), &at);
    assert!(tangential.norm() < 1e-12, "{tangential}");
    let radial = blocked_part(&Vector3::x(), Some(&shaft), &at);
    assert!((radial - Vector3::x()).norm() < 1e-12, "{radial}");
}

/// A held ball (Toss Ball's, welded in the grasp) rides on the vehicle's own dynamics as a
/// payload in free flight — the vehicle carries it at 0.3 m/s, then opens the gripper — and
/// the ball's path, its reported velocity while held and its flight after the release match
/// rapier's multibody carrying it on the grasp's joint.
#[test]
fn a_held_ball_rides_on_the_vehicles_own_dynamics_and_leaves_the_hand_as_on_rapier() {
    use crate::tasks::{TaskId, keys};
    use controllers::{BaseController, BodyParams, Pid6, Pid6Gains};
    let v = vehicle("fa-hexa");
    let Some(gripper) = v.gripper.clone() else {
        panic!("the FA-Hexa has a gripper");
    };
    let fly = |vehicle_dynamics| {
        let mut t = twin(
            "fa-hexa",
            TwinConfig {
                vehicle_dynamics,
                task: Some(TaskId::TossBall),
                ..TwinConfig::default()
            },
        );
        let mut allocator = Allocator::new(&v.rotors, v.actuation, AllocationMethod::PseudoInverse)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut pid = Pid6::new(Pid6Gains::am_bench(), BodyParams::from_vehicle(&v));
        pid.reset(&t.truth().base);
        let mut cmd = hover(&v);
        let start = t.truth().base.position_in_world_m;
        let mut flight = Vec::new();
        for k in 0..300u32 {
            // Held 1 s, carried 0.3 m along x over 1 s, let go at 2 s.
            let x = start.x + 0.3 * (f64::from(k.saturating_sub(120)) / 120.0).min(1.0);
            if k == 240 {
                for (j, open) in gripper.joints.iter().zip(&gripper.open) {
                    if let Some(d) = v.model.joints[*j].dof {
                        cmd.joint_targets[d] = *open;
                    }
                }
            }
            let target = Isometry3::translation(x, start.y, start.z);
            pid_tick(&mut t, &mut pid, &mut allocator, &mut cmd, &target);
            let obs = t.task_observation().unwrap_or_default();
            let ball = obs
                .vec3(keys::BALL_POS, 0)
                .unwrap_or_else(|e| panic!("{e}"));
            let speed = obs
                .vec3(keys::BALL_LIN_VEL, 0)
                .unwrap_or_else(|e| panic!("{e}"));
            let holding = t.task_snapshot().is_some_and(|s| s.holding);
            flight.push((ball, speed, holding, t.on_own_dynamics()));
        }
        flight
    };
    let rapier = fly(crate::VehicleDynamics::Rapier);
    let ours = fly(crate::VehicleDynamics::Articulated);
    let carried = ours.iter().filter(|s| s.2 && s.3).count();
    assert!(
        carried > 200,
        "the held ball kept the vehicle on rapier: {carried} ticks carried"
    );
    assert!(
        rapier.iter().take(240).all(|s| s.2),
        "rapier dropped the ball"
    );
    let released = ours.iter().position(|s| !s.2).unwrap_or(ours.len());
    assert!(
        (240..250).contains(&released),
        "released at tick {released}"
    );
    // Where the ball is, and how fast rapier says it moves, held and thrown.
    let (mut path, mut speed) = (0.0_f64, 0.0_f64);
    for (a, b) in rapier.iter().zip(&ours) {
        path = path.max((a.0 - b.0).norm());
        speed = speed.max((a.1 - b.1).norm());
    }
    let carried_speed = ours.iter().map(|s| s.1.x).fold(0.0, f64::max);
    let fallen = ours[239].0.z - ours[299].0.z;
    println!(
        "ball: path gap {path:.2e} m, speed gap {speed:.2e} m/s, fastest {carried_speed:.3} m/s, \
         fell {fallen:.3} m in 0.5 s; {carried} ticks carried"
    );
    assert!(
        carried_speed > 0.25,
        "the ball was not carried: {carried_speed} m/s"
    );
    assert!(fallen > 0.5, "the released ball did not fall: {fallen} m");
    assert!(
        path < 5e-4 && speed < 1e-2,
        "the carried ball left rapier's: {path} m, {speed} m/s"
    );
}
