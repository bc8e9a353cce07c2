//! The reference's task-specific IK profiles (AMBENCH_SPEC §2.6) reach the flight stack.

use controllers::{ControllerKind, profile};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use platform::Vehicle;
use sim_twin::{TaskId, TwinConfig};

use crate::stack::{EeTarget, FlightStack};

/// The lemon's wall face (the default wall at x 2.0, 0.1 m thick), m.
const WALL_FACE_X_M: f64 = 1.95;

/// Base x the stack's IK gives for an EE target 0.5 m behind the wall face (out of reach of
/// every allowed base position), after a few solves from the spawn pose, for `task` under the
/// `kind` profile.
fn base_x(vehicle_id: &str, kind: ControllerKind, task: TaskId) -> f64 {
    let vehicle = Vehicle::builtin(vehicle_id).unwrap_or_else(|e| panic!("{e}"));
    let config = profile(&vehicle, kind).unwrap_or_else(|e| panic!("{e}"));
    let twin = TwinConfig {
        task: Some(task),
        ..TwinConfig::default()
    };
    let mut stack =
        FlightStack::for_twin(vehicle, &config, &twin).unwrap_or_else(|e| panic!("{e}"));
    stack.keep_in_front_of(Some(WALL_FACE_X_M));
    let ee = EeTarget {
        world_from_ee_command: Isometry3::from_parts(
            Translation3::new(WALL_FACE_X_M + 0.5, 0.0, 1.2),
            UnitQuaternion::identity(),
        ),
        gripper: 1.0,
    };
    let mut x = f64::NAN;
    for _ in 0..20 {
        x = stack
            .ee_to_base_joint_target(&ee)
            .world_from_base
            .translation
            .x;
    }
    x
}

#[test]
fn the_lemon_profile_keeps_the_fa_hexa_a_metre_from_the_wall_under_pid_only() {
    // The base sits on its limit, face − margin (a stiff hinge: within a few mm).
    let lemon_pid = base_x("fa-hexa", ControllerKind::Pid, TaskId::LemonHarvesting);
    assert!(
        (lemon_pid - (WALL_FACE_X_M - 1.0)).abs() < 5e-3,
        "{lemon_pid}"
    );
    // Other tasks, and the L1 profile on the lemon, keep the FA-Hexa's 0.85 m.
    let valve_pid = base_x("fa-hexa", ControllerKind::Pid, TaskId::RotateValve);
    assert!(
        (valve_pid - (WALL_FACE_X_M - 0.85)).abs() < 5e-3,
        "{valve_pid}"
    );
    let lemon_l1 = base_x("fa-hexa", ControllerKind::L1, TaskId::LemonHarvesting);
    assert!(
        (lemon_l1 - (WALL_FACE_X_M - 0.85)).abs() < 5e-3,
        "{lemon_l1}"
    );
    // The Omni-Hexa's lemon profile: 0.5 m instead of 0.3 m.
    let omni = base_x("omni-hexa", ControllerKind::Pid, TaskId::LemonHarvesting);
    assert!((omni - (WALL_FACE_X_M - 0.5)).abs() < 5e-3, "{omni}");
}
