//! Under rotor limits the flight stack keeps the attitude torques (prioritized allocation), where
//! the reference's clamp trades them for the force it cannot give.

use controllers::{ControllerKind, profile};
use nalgebra::{Isometry3, Vector3};
use platform::{Measurement, RigidBodyState, Vehicle};
use sim_twin::{Disturbances, SaturatedAllocation, TwinConfig};

use crate::stack::{BaseJointTarget, FlightStack, TickRecord};

/// One tick of the FA-Hexa's IK-PID stack at rest in hover, asked for a base target 0.1 m ahead
/// (at the PID's position gain 200 /s², ~130 N forward besides its weight: beyond its 23 N rotors).
fn tick(how: SaturatedAllocation) -> TickRecord {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
    let config = profile(&vehicle, ControllerKind::Pid).unwrap_or_else(|e| panic!("{e}"));
    let twin = TwinConfig {
        disturbances: Disturbances::parse_list("saturation").unwrap_or_else(|e| panic!("{e}")),
        saturated_allocation: how,
        ..TwinConfig::default()
    };
    let arm = vehicle.arm_dof();
    let q0 = vehicle.initial_configuration();
    let mut stack =
        FlightStack::for_twin(vehicle, &config, &twin).unwrap_or_else(|e| panic!("{e}"));
    let m = Measurement {
        base: RigidBodyState::at_rest(Isometry3::translation(0.0, 0.0, 1.0)),
        joint_velocities: vec![0.0; q0.len()],
        joint_positions: q0,
        ..Measurement::default()
    };
    let target = BaseJointTarget {
        world_from_base: Isometry3::translation(0.1, 0.0, 1.0),
        arm_joints: vec![0.0; arm],
        gripper: 1.0,
    };
    stack.tick(&m, &target)
}

#[test]
fn under_rotor_limits_the_prioritized_allocation_keeps_roll_and_pitch() {
    let prioritized = tick(SaturatedAllocation::Prioritized);
    let clip = tick(SaturatedAllocation::Clip);
    // The same request, beyond the rotors: both leave force unallocated.
    assert_eq!(prioritized.wrench, clip.wrench);
    assert!(
        prioritized.unallocated.force.norm() > 1.0,
        "{prioritized:?}"
    );
    assert!(clip.unallocated.force.norm() > 1.0, "{clip:?}");
    let roll_pitch =
        |r: &TickRecord| Vector3::new(r.unallocated.torque.x, r.unallocated.torque.y, 0.0).norm();
    // Prioritized (measured: 0.0028 N·m; the clamp 0.72): the force gives way; roll and
    // pitch keep all but what the weights trade (1 N·m of roll or pitch weighs as 100 N of
    // force): ~110 N of force left out costs under 0.01 N·m.
    assert!(
        roll_pitch(&prioritized) < 0.01,
        "{:?}",
        prioritized.unallocated
    );
    // The clamp: a rotor-by-rotor cut shows up as a roll/pitch torque error.
    assert!(roll_pitch(&clip) > 0.1, "{:?}", clip.unallocated);
}
