//! Wire round trips and the handshake's refusals (no second process).

use platform::Vehicle;

use super::*;
use crate::{Disturbances, TaskId, Twin, TwinConfig};

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn measurement_survives_the_wire_bit_for_bit() {
    let config = TwinConfig {
        disturbances: Disturbances::all(),
        seed: 3,
        ..TwinConfig::default()
    };
    let mut twin = Twin::new(vehicle("omni-hexa"), config).unwrap_or_else(|e| panic!("{e}"));
    let v = twin.vehicle().clone();
    let command = platform::ActuatorCommand {
        rotor_thrusts_n: vec![6.0; v.rotors.len()],
        joint_targets: v.initial_configuration(),
        direct_wrench_in_body: None,
    };
    let m = twin.step(&command).unwrap_or_else(|e| panic!("{e}"));
    let wire = MeasurementMsg::from_measurement(&m).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(wire.to_measurement(), m);
    let sent = CommandMsg::from_command(&command, 7, 9).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(sent.to_command(), command);
    assert_eq!((sent.session, sent.tick), (7, 9));
}

#[test]
fn direct_wrench_crosses_the_wire() {
    let command = platform::ActuatorCommand {
        rotor_thrusts_n: Vec::new(),
        joint_targets: Vec::new(),
        direct_wrench_in_body: Some(platform::Wrench::new(
            nalgebra::Vector3::new(1.0, 2.0, 3.0),
            nalgebra::Vector3::new(-1.0, -2.0, -3.5),
        )),
    };
    let wire = CommandMsg::from_command(&command, 1, 0).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(wire.to_command(), command);
}

#[test]
fn too_many_rotors_is_refused_naming_the_count() {
    let command = platform::ActuatorCommand {
        rotor_thrusts_n: vec![0.0; MAX_ROTORS + 1],
        ..platform::ActuatorCommand::default()
    };
    let e = CommandMsg::from_command(&command, 0, 0).err();
    assert_eq!(
        e.map(|e| e.to_string()),
        Some(format!(
            "rotor thrusts: {} does not fit the wire's {MAX_ROTORS}",
            MAX_ROTORS + 1
        ))
    );
}

fn offer(id: &str, config: &TwinConfig) -> Offer {
    Offer::new(&vehicle(id), config).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn matching_terms_are_accepted() {
    let c = TwinConfig::default();
    assert_eq!(
        check_hello(
            &offer("fa-hexa", &c).hello(1, [0, 0]),
            &offer("fa-hexa", &c),
            false
        ),
        Ok(())
    );
}

#[test]
fn a_mismatched_vehicle_is_refused_naming_both() {
    let c = TwinConfig::default();
    let refusal = check_hello(
        &offer("ua-quad", &c).hello(1, [0, 0]),
        &offer("fa-hexa", &c),
        false,
    );
    assert_eq!(
        refusal,
        Err(
            "vehicle mismatch: the flight process flies 'ua-quad', the twin serves 'fa-hexa'"
                .to_owned()
        )
    );
}

#[test]
fn a_mismatched_configuration_is_refused_naming_the_field_and_both_values() {
    let flight = TwinConfig {
        seed: 4,
        ..TwinConfig::default()
    };
    let twin = TwinConfig::default();
    let refusal = check_hello(
        &offer("fa-hexa", &flight).hello(1, [0, 0]),
        &offer("fa-hexa", &twin),
        false,
    )
    .err()
    .unwrap_or_default();
    assert!(refusal.contains("at seed: flight 4, twin 0"), "{refusal}");
    assert!(
        refusal.contains(&format!("{:016x}", config_hash(&flight))),
        "{refusal}"
    );
    assert!(
        refusal.contains(&format!("{:016x}", config_hash(&twin))),
        "{refusal}"
    );
}

#[test]
fn a_flight_that_chooses_the_episode_may_differ_in_task_and_seed_only() {
    let twin = TwinConfig::default();
    let episode = TwinConfig {
        seed: 4,
        task: Some(TaskId::TossBall),
        ..TwinConfig::default()
    };
    let served = offer("fa-hexa", &twin);
    let hello = offer("fa-hexa", &episode).hello(1, [0, 0]);
    assert_eq!(check_hello(&hello, &served, true), Ok(()));
    assert!(check_hello(&hello, &served, false).is_err());
    let other = TwinConfig {
        control_rate_hz: 240.0,
        solver_iterations: 8,
        ..episode
    };
    // The rate is refused first; with it equal, the first other field is named.
    let refusal = check_hello(&offer("fa-hexa", &other).hello(1, [0, 0]), &served, true);
    assert!(refusal.is_err_and(|r| r.contains("control rate")));
    let other = TwinConfig {
        control_rate_hz: twin.control_rate_hz,
        ..other
    };
    let refusal = check_hello(&offer("fa-hexa", &other).hello(1, [0, 0]), &served, true)
        .err()
        .unwrap_or_default();
    assert!(
        refusal.contains("at solver_iterations: flight 8, twin 4"),
        "{refusal}"
    );
}

#[test]
fn task_state_crosses_the_wire_bit_for_bit() {
    let mut twin = Twin::new(
        vehicle("ee-only"),
        TwinConfig {
            task: Some(TaskId::WipeWindow),
            seed: 9,
            ..TwinConfig::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let snapshot = twin.task_snapshot().unwrap_or_else(|| panic!("a task"));
    assert!(snapshot.wall.is_some() && snapshot.obstacle_face_x.is_some());
    let msg = TaskMsg::from_snapshot(Some(&snapshot)).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(msg.to_snapshot(), Some(snapshot.clone()));
    assert_eq!(
        TaskMsg::from_snapshot(None).map(|m| m.to_snapshot()),
        Ok(None)
    );
    // The held joint and the hand's contact, which the whole-body MPC reads from the scene,
    // cross it too (a flight over the wire flies what the in-process twin flies).
    for held in [
        None,
        Some(crate::HeldJoint::Prismatic {
            axis: nalgebra::Vector3::new(0.1, -0.99, 0.05),
        }),
        Some(crate::HeldJoint::Revolute {
            axis: nalgebra::Vector3::new(0.0, 0.6, 0.8),
            point: nalgebra::Vector3::new(1.9, -0.3, 1.2),
        }),
    ] {
        let mut s = snapshot.clone();
        s.held_joint = held;
        s.hand_contact = Some(nalgebra::Vector3::new(
            -0.98,
            0.1,
            std::f64::consts::FRAC_1_PI,
        ));
        let msg = TaskMsg::from_snapshot(Some(&s)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(msg.to_snapshot(), Some(s));
    }
    // Every task's state fits the message.
    for task in TaskId::ALL {
        twin.reset_episode(Some(task), 1)
            .unwrap_or_else(|e| panic!("{e}"));
        let snapshot = twin.task_snapshot().unwrap_or_else(|| panic!("a task"));
        let msg = TaskMsg::from_snapshot(Some(&snapshot)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(msg.to_snapshot(), Some(snapshot), "{task:?}");
    }
}

#[test]
fn a_mismatched_message_version_is_refused_naming_both() {
    let c = TwinConfig::default();
    let mut hello = offer("fa-hexa", &c).hello(1, [0, 0]);
    hello.version = MESSAGE_VERSION + 1;
    let refusal = check_hello(&hello, &offer("fa-hexa", &c), false)
        .err()
        .unwrap_or_default();
    assert!(
        refusal.contains(&format!("v{}", MESSAGE_VERSION + 1))
            && refusal.contains(&format!("v{MESSAGE_VERSION}")),
        "{refusal}"
    );
}

#[test]
fn node_ids_split_and_join() {
    let id = 0x0123_4567_89ab_cdef_fedc_ba98_7654_3210_u128;
    assert_eq!(join_id(split_id(id)), id);
}
