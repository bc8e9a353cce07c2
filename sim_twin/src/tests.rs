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
