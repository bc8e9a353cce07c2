//! Scene tests: joints behave as specified, criteria flip at their thresholds.

use nalgebra::{Isometry3, Vector3};
use rapier3d_f64::prelude::*;

use super::objects::{Articulation, Dof, JointSpec, fixed_body};
use crate::convert::vector_to_rapier;

fn world() -> PhysicsWorld {
    let mut w = PhysicsWorld::new();
    w.gravity = Vector::new(0.0, 0.0, -9.81);
    w.integration_parameters.dt = 1.0 / 480.0;
    w
}

fn push(world: &mut PhysicsWorld, body: RigidBodyHandle, force: Vector3<f64>, steps: usize) {
    for _ in 0..steps {
        if let Some(rb) = world.bodies.get_mut(body) {
            rb.reset_forces(false);
            rb.add_force(vector_to_rapier(&force), true);
        }
        world.step();
    }
}

fn slider(stiffness: f64, damping: f64, friction: f64) -> (PhysicsWorld, Articulation) {
    let mut w = world();
    let root = fixed_body(&mut w, &Isometry3::translation(1.0, 0.0, 1.0));
    let spec = JointSpec {
        dof: Dof::Prismatic,
        limits: Some((-0.5, 0.5)),
        stiffness,
        damping,
        target: 0.0,
        effort: 1000.0,
        friction,
        initial: 0.0,
    };
    let (a, _) = Articulation::insert(
        &mut w,
        root,
        Isometry3::identity(),
        Isometry3::translation(-0.1, 0.0, 0.0),
        vec![(ColliderBuilder::cuboid(0.02, 0.02, 0.02), Isometry3::identity())],
        0.2,
        &spec,
    );
    (w, a)
}

#[test]
fn a_spring_joint_settles_where_force_balances_stiffness() {
    // 4 N against 1000 N/m: 4 mm.
    let (mut w, a) = slider(1000.0, 80.0, 0.0);
    push(&mut w, a.link, Vector3::new(4.0, 0.0, 0.0), 960);
    let q = a.position(&w);
    assert!((q - 0.004).abs() < 2e-4, "q = {q}");
}

#[test]
fn coulomb_friction_holds_below_and_slides_above_its_force() {
    let (mut w, a) = slider(0.0, 5.0, 4.0);
    push(&mut w, a.link, Vector3::new(3.0, 0.0, 0.0), 480);
    assert!(a.position(&w).abs() < 1e-3, "3 N < 4 N friction: q = {}", a.position(&w));
    // 6 N: 2 N net against damping 5 N·s/m → 0.4 m/s terminal speed.
    push(&mut w, a.link, Vector3::new(6.0, 0.0, 0.0), 480);
    let q = a.position(&w);
    assert!(q > 0.25 && q < 0.45, "q = {q}");
}
