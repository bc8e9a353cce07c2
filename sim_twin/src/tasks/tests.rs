//! Scene tests: joints behave as specified, criteria flip at their thresholds.

use nalgebra::{Isometry3, Vector3};
use rapier3d_f64::prelude::*;

use super::objects::{Dof, DriveType, JointSpec, ReducedJoint, fixed_body};
use crate::convert::vector_to_rapier;

/// A world as the twin's (gravity, 120 Hz in 4 substeps) without a vehicle; with `ground`,
/// the ground plane too.
pub(crate) fn world_with(ground: bool) -> PhysicsWorld {
    let mut w = PhysicsWorld::new();
    w.gravity = Vector::new(0.0, 0.0, -9.81);
    w.integration_parameters.dt = 1.0 / 480.0;
    w.integration_parameters.normalized_prediction_distance = crate::twin::PREDICTION_DISTANCE_M;
    if ground {
        let body = w.insert_body(RigidBodyBuilder::fixed());
        w.insert_collider(
            crate::vehicle_body::material(ColliderBuilder::halfspace(
                rapier3d_f64::na::Unit::new_unchecked(Vector::Z),
            )),
            Some(body),
        );
    }
    w
}

fn world() -> PhysicsWorld {
    world_with(false)
}

/// What a scene registered while it built itself.
#[derive(Debug)]
pub(crate) struct Built {
    /// Bodies the fingers may grasp.
    pub graspable: Vec<RigidBodyHandle>,
    /// The object attached at reset.
    pub pre_grasped: Option<RigidBodyHandle>,
}

/// `scene` built into `world` from `seed`, with the tool tip at (0.18, 0, 1) m and the
/// identity command frame (the vehicles' reset pose).
pub(crate) fn build_into(
    world: &mut PhysicsWorld,
    scene: &mut dyn super::Scene,
    seed: u64,
) -> Built {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut b = super::Build {
        world,
        rng: &mut rng,
        tool_tip: Isometry3::translation(0.18, 0.0, 1.0),
        graspable: Vec::new(),
        pre_grasped: None,
        pre_grasp_width_m: 0.0,
    };
    scene.build(&mut b).unwrap_or_else(|e| panic!("{e}"));
    Built {
        graspable: b.graspable,
        pre_grasped: b.pre_grasped,
    }
}

/// The view after env step `step` of a level end effector whose tool tip is at `tool_tip`
/// (its link 0.18 m behind), the base at `base`, the gripper `width_m` wide.
pub(crate) fn view_of(
    step: u64,
    tool_tip: Vector3<f64>,
    base: Vector3<f64>,
    width_m: f64,
) -> super::View {
    super::View {
        step,
        substep_s: 1.0 / 480.0,
        world_from_ee: Isometry3::translation(tool_tip.x - 0.18, tool_tip.y, tool_tip.z),
        tool_tip,
        base_position: base,
        gripper_width_m: width_m,
    }
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

fn slider(stiffness: f64, damping: f64, friction: f64) -> (PhysicsWorld, ReducedJoint) {
    slider_of(stiffness, damping, friction, 0.2, DriveType::Force, 1000.0)
}

/// A free prismatic link of `mass_kg` on a fixed root, driven as `drive` says.
fn slider_of(
    stiffness: f64,
    damping: f64,
    friction: f64,
    mass_kg: f64,
    drive: DriveType,
    effort: f64,
) -> (PhysicsWorld, ReducedJoint) {
    let mut w = world();
    let root = fixed_body(&mut w, &Isometry3::translation(1.0, 0.0, 1.0));
    let spec = JointSpec {
        dof: Dof::Prismatic,
        limits: Some((-0.5, 0.5)),
        stiffness,
        damping,
        target: 0.0,
        effort,
        friction,
        initial: 0.0,
        drive,
    };
    let Some((a, _)) = ReducedJoint::insert(
        &mut w,
        root,
        Isometry3::identity(),
        Isometry3::translation(-0.1, 0.0, 0.0),
        vec![(
            ColliderBuilder::cuboid(0.02, 0.02, 0.02),
            Isometry3::identity(),
        )],
        mass_kg,
        &spec,
    ) else {
        panic!("the joint joins its root")
    };
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
    assert!(
        a.position(&w).abs() < 1e-3,
        "3 N < 4 N friction: q = {}",
        a.position(&w)
    );
    // 6 N: 2 N net against damping 5 N·s/m → 0.4 m/s terminal speed.
    push(&mut w, a.link, Vector3::new(6.0, 0.0, 0.0), 480);
    let q = a.position(&w);
    assert!(q > 0.25 && q < 0.45, "q = {q}");
}

#[test]
fn an_acceleration_drive_resists_in_proportion_to_the_mass_it_moves() {
    // 0.2 N against damping 5 (no spring, no friction), after 1 s (five time constants of the
    // slowest case), speed over the next 0.5 s. A force drive: F = d·v, v = 0.04 m/s whatever
    // the mass. An acceleration drive (PhysX eACCELERATION): F = m·d·v, v = F/(m·d) = 0.2 m/s
    // for 0.2 kg and 0.1 m/s for 0.4 kg.
    let speed = |mass: f64, drive: DriveType| {
        let (mut w, a) = slider_of(0.0, 5.0, 0.0, mass, drive, 1000.0);
        push(&mut w, a.link, Vector3::new(0.2, 0.0, 0.0), 480);
        let q1 = a.position(&w);
        push(&mut w, a.link, Vector3::new(0.2, 0.0, 0.0), 240);
        (a.position(&w) - q1) / 0.5
    };
    for (mass, drive, expected) in [
        (0.2, DriveType::Force, 0.04),
        (0.4, DriveType::Force, 0.04),
        (0.2, DriveType::Acceleration, 0.2),
        (0.4, DriveType::Acceleration, 0.1),
    ] {
        let v = speed(mass, drive);
        assert!(
            (v - expected).abs() < 0.01 * expected,
            "{mass} kg, {drive:?}: {v} m/s, expected {expected}"
        );
    }
}

#[test]
fn a_force_drive_gives_at_most_its_effort() {
    // Damping 100 N·s/m capped at 5 N (a PhysX drive's maxForce), 0.2 kg. 4 N, under the cap:
    // the damper sets v = 0.04 m/s (time constant m/c = 2 ms), q(0.5 s) = 0.02 m. 8 N, over
    // it: the damper holds 5 N from v = 0.05 m/s and the other 3 N accelerate the slider at
    // 15 m/s²: q(0.1 s) ≈ 0.05·0.1 + ½·15·0.1² = 0.080 m; an uncapped damper would allow
    // 0.08 m/s, 0.008 m.
    let travel = |force: f64, steps: usize| {
        let (mut w, a) = slider_of(0.0, 100.0, 0.0, 0.2, DriveType::Force, 5.0);
        push(&mut w, a.link, Vector3::new(force, 0.0, 0.0), steps);
        a.position(&w)
    };
    let q = travel(4.0, 240);
    assert!((q - 0.02).abs() < 0.001, "4 N: q = {q}");
    let q = travel(8.0, 48);
    assert!((q - 0.080).abs() < 0.008, "8 N: q = {q}");
}

/// A scene built alone in a world (no vehicle, no ground), from `seed`.
pub(crate) fn built(scene: &mut dyn super::Scene, seed: u64) -> PhysicsWorld {
    let mut w = world();
    build_into(&mut w, scene, seed);
    w
}

/// A view of a vehicle at its reset pose.
pub(crate) fn view(step: u64) -> super::View {
    view_of(
        step,
        Vector3::new(0.18, 0.0, 1.0),
        Vector3::new(0.0, 0.0, 1.0),
        0.002,
    )
}

#[test]
fn the_button_counts_as_pressed_from_4_mm() {
    use super::Scene;
    let mut scene = super::press_button::PressButton::default();
    let mut w = built(&mut scene, 3);
    for (q, pressed) in [(0.0, false), (0.0039, false), (0.0041, true), (0.01, true)] {
        scene.set_plunger(&mut w, q);
        let status = scene.after_step(&mut w, &view(1));
        assert_eq!(status.success, pressed, "q = {q}");
        let o = scene.observation(&w);
        assert_eq!(
            o.scalar("button_pressed").unwrap_or(-1.0),
            f64::from(u8::from(pressed))
        );
    }
}

#[test]
fn the_slider_engages_at_5_percent_and_succeeds_at_045() {
    use super::Scene;
    let mut scene = super::push_slider::PushSlider::default();
    let mut w = built(&mut scene, 4);
    // q0 = −0.5; engaged when q − q0 ≥ 0.05·0.95 = 0.0475.
    for (q, engaged, pushed) in [
        (-0.5, false, false),
        (-0.453, false, false),
        (-0.452, true, false),
        (0.449, true, false),
        (0.451, true, true),
    ] {
        scene.set_slider(&mut w, q);
        let s = scene.after_step(&mut w, &view(1));
        assert_eq!(s.criteria, vec![engaged, pushed], "q = {q}");
        assert_eq!(s.success, pushed, "q = {q}");
    }
}

#[test]
fn the_slider_reports_its_rail_as_the_held_joint_and_the_knob_moves_along_it() {
    use super::Scene;
    let mut scene = super::push_slider::PushSlider::default();
    let mut w = built(&mut scene, 4);
    let knob = scene.knob().unwrap_or_else(|| panic!("a knob"));
    let wall = scene.wall().unwrap_or_else(|| panic!("a wall"));
    let Some(super::HeldJoint::Prismatic { axis }) = scene.held_joint(&w, knob) else {
        panic!("the knob slides on a prismatic joint");
    };
    // The push direction −w_y, along the wall face.
    assert!(
        (axis - wall.rotation * -Vector3::y()).norm() < 1e-9,
        "{axis}"
    );
    let at = |w: &PhysicsWorld| super::objects::pose_of(w, knob).translation.vector;
    let before = at(&w);
    scene.set_slider(&mut w, 0.2);
    let moved = at(&w) - before;
    // 0.7 m along the axis, nothing across it.
    assert!((moved - axis * 0.7).norm() < 1e-9, "{moved}");
    // Nothing else is a held joint of this scene.
    let wall_body = w.bodies.iter().find(|(h, _)| *h != knob).map(|(h, _)| h);
    if let Some(other) = wall_body {
        assert_eq!(scene.held_joint(&w, other), None);
    }
}

#[test]
fn wall_and_button_randomisation_stays_in_the_spec_ranges() {
    use super::Scene;
    for seed in 0..20 {
        let mut scene = super::press_button::PressButton::default();
        let w = built(&mut scene, seed);
        let wall = scene.wall().unwrap_or_else(|| panic!("a wall"));
        let (roll, pitch, yaw) = wall.rotation.euler_angles();
        assert!((wall.translation.x - 2.0).abs() <= 0.2 && wall.translation.y.abs() <= 0.2);
        assert!(roll.abs() < 1e-12 && yaw.abs() < 1e-12 && pitch.abs() <= 0.2);
        // The plunger sits on the wall face within ±0.3 m of its centre (wall-local y, z).
        let goal = scene
            .observation(&w)
            .vec3("goal_pos", 0)
            .unwrap_or_else(|e| panic!("{e}"));
        let local = wall.inverse() * nalgebra::Point3::from(goal);
        assert!(local.y.abs() <= 0.3 && local.z.abs() <= 0.3, "{local:?}");
        assert!(
            local.x < -0.05 && local.x > -0.1,
            "in front of the face: {local:?}"
        );
    }
}

/// Two fixed fingers 0.02 m either side of the x axis (their inner faces at y = ±`gap`/2), a
/// dynamic graspable box at `object_at` with half extents `half`, after one step: whether the
/// assisted grasp engages as the gripper closes.
fn grasp_engages(gap: f64, object_at: Vector3<f64>, half: Vector3<f64>) -> bool {
    use super::objects::Grasp;
    let mut w = world();
    w.gravity = Vector::ZERO;
    let ee = fixed_body(&mut w, &Isometry3::identity());
    let finger = |w: &mut PhysicsWorld, y: f64| {
        let body = fixed_body(w, &Isometry3::translation(0.0, y, 0.0));
        vec![w.insert_collider(ColliderBuilder::cuboid(0.05, 0.004, 0.01), Some(body))]
    };
    let fingers = [
        finger(&mut w, -(gap / 2.0 + 0.004)),
        finger(&mut w, gap / 2.0 + 0.004),
    ];
    let object =
        w.insert_body(RigidBodyBuilder::dynamic().translation(vector_to_rapier(&object_at)));
    w.insert_collider(
        ColliderBuilder::cuboid(half.x, half.y, half.z),
        Some(object),
    );
    w.step();
    let mut grasp = Grasp {
        graspable: vec![object],
        ..Grasp::default()
    };
    grasp.update(&mut w, ee, &fingers, (true, gap, 0.0), true);
    grasp.held.is_some()
}

#[test]
fn the_assisted_grasp_engages_on_the_inner_faces_only() {
    // Between the fingers, pressing both inner faces (0.5 mm deep): a grip.
    assert!(grasp_engages(
        0.04,
        Vector3::zeros(),
        Vector3::new(0.03, 0.0205, 0.03)
    ));
    // Against both fingertips (a panel across the gripper's front, 0.5 mm deep): no grip,
    // though both fingers touch it.
    assert!(!grasp_engages(
        0.04,
        Vector3::new(0.05 + 0.03 - 0.0005, 0.0, 0.0),
        Vector3::new(0.03, 0.06, 0.03)
    ));
}

/// `torque` (world, N·m) on `body` for 0.5 s (240 steps): the angle the body turned through
/// from identity, rad.
fn turned_under(w: &mut PhysicsWorld, body: RigidBodyHandle, torque: Vector3<f64>) -> f64 {
    for _ in 0..240 {
        if let Some(rb) = w.bodies.get_mut(body) {
            rb.reset_torques(false);
            rb.add_torque(vector_to_rapier(&torque), true);
        }
        w.step();
    }
    super::objects::pose_of(w, body).rotation.angle()
}

/// An object of one `shape` (placed by `shape_pose` in its frame) held by the assisted grasp
/// of a gripper fixed in the world, turned by `torque` (world, N·m) for 0.5 s: the angle it
/// turned through, rad.
fn turn_in_the_fingers(
    shape: ColliderBuilder,
    shape_pose: Isometry3<f64>,
    torque: Vector3<f64>,
) -> f64 {
    let mut w = world_with(false);
    w.gravity = Vector::ZERO;
    let ee = fixed_body(&mut w, &Isometry3::translation(0.0, 0.0, 1.0));
    let object = w.insert_body(
        RigidBodyBuilder::dynamic()
            .pose(crate::convert::pose_to_rapier(&Isometry3::translation(
                0.18, 0.0, 1.0,
            )))
            .build(),
    );
    w.insert_collider(
        shape
            .density(100.0)
            .position(crate::convert::pose_to_rapier(&shape_pose)),
        Some(object),
    );
    let mut grasp = super::objects::Grasp::default();
    grasp.attach(&mut w, ee, object, 0.04);
    turned_under(&mut w, object, torque)
}

#[test]
fn a_grasped_round_bar_spins_about_its_own_axis_and_nothing_else_turns() {
    // The valve's handle: a bar along x (rapier's cylinder stands along y).
    let along_x = Isometry3::rotation(Vector3::z() * std::f64::consts::FRAC_PI_2);
    let bar = || ColliderBuilder::cylinder(0.05, 0.015);
    // 1e-5 N·m about its axis for 0.5 s turns the free bar ½·(τ/I)·t² = 1.571 rad
    // (m = 100 kg/m³ · π · 0.015² · 0.1 m³ = 7.07 g, I = ½·m·r² = 7.95e-7 kg·m²): the grasp
    // holds no torque about it.
    let spun = turn_in_the_fingers(bar(), along_x, Vector3::new(1e-5, 0.0, 0.0));
    let free = 0.5 * 1e-5 / (0.5 * 100.0 * std::f64::consts::PI * 0.015f64.powi(4) * 0.1) * 0.25;
    assert!(
        (spun - free).abs() < 0.02 * free,
        "the bar turned {spun} rad about its axis, free {free}"
    );
    // 10 N·m across it: the fingers hold it (to the joint solver's slack).
    for torque in [Vector3::new(0.0, 10.0, 0.0), Vector3::new(0.0, 0.0, 10.0)] {
        let tipped = turn_in_the_fingers(bar(), along_x, torque);
        assert!(
            tipped < 1e-3,
            "the bar tipped {tipped} rad under {torque:?}"
        );
    }
    // A box is held about every axis.
    for torque in [Vector3::x(), Vector3::y(), Vector3::z()] {
        let turned = turn_in_the_fingers(
            ColliderBuilder::cuboid(0.05, 0.015, 0.015),
            Isometry3::identity(),
            torque * 10.0,
        );
        assert!(
            turned < 1e-3,
            "the box turned {turned} rad under {torque:?}"
        );
    }
}

/// Push Slider's knob held by a hand (a free ball of 0.03 m radius on the knob's axis, 0.05 m
/// beyond its end), no gravity, a torque on the hand for 0.5 s: the angle it turned, rad.
fn roll_the_hand_on_the_knob(torque_in_knob_frame: Vector3<f64>) -> f64 {
    let mut scene = super::push_slider::PushSlider::default();
    let mut w = built(&mut scene, 4);
    w.gravity = Vector::ZERO;
    let Some(knob) = scene.knob() else {
        panic!("the Push Slider scene has no knob");
    };
    let knob_pose = super::objects::pose_of(&w, knob);
    // The knob's axis is its link's x, out of the wall toward the vehicle.
    let hand_at = knob_pose
        * nalgebra::Point3::new(super::push_slider::KNOB_END_FROM_ORIGIN_M + 0.05, 0.0, 0.0);
    let hand = w.insert_body(
        RigidBodyBuilder::dynamic()
            .pose(crate::convert::pose_to_rapier(&Isometry3::translation(
                hand_at.x, hand_at.y, hand_at.z,
            )))
            .build(),
    );
    w.insert_collider(ColliderBuilder::ball(0.03).density(1000.0), Some(hand));
    let mut grasp = super::objects::Grasp::default();
    grasp.attach(&mut w, hand, knob, 2.0 * super::push_slider::KNOB_RADIUS_M);
    let torque = knob_pose.rotation * torque_in_knob_frame;
    turned_under(&mut w, hand, torque)
}

#[test]
fn a_hand_holding_the_slider_knob_rolls_about_the_wall_normal_and_nothing_else_turns() {
    // About the knob's axis the hand turns freely: ½·(τ/I)·t² with I = 0.4·m·r² of the ball
    // (m = 1000 kg/m³ · 4/3·π·0.03³ = 0.1131 kg, I = 4.07e-5 kg·m²): 1e-4 N·m for 0.5 s is
    // 0.307 rad. This is the roll an under-actuated vehicle pushing along the rail needs.
    let m = 1000.0 * 4.0 / 3.0 * std::f64::consts::PI * 0.03f64.powi(3);
    let free = 0.5 * 1e-4 / (0.4 * m * 0.03 * 0.03) * 0.25;
    let rolled = roll_the_hand_on_the_knob(Vector3::new(1e-4, 0.0, 0.0));
    assert!(
        (rolled - free).abs() < 0.02 * free,
        "the hand rolled {rolled} rad about the knob, free {free}"
    );
    // 1 N·m across the knob (about the rail and about the vertical): the grasp holds it.
    for torque in [Vector3::new(0.0, 1.0, 0.0), Vector3::new(0.0, 0.0, 1.0)] {
        let turned = roll_the_hand_on_the_knob(torque);
        assert!(
            turned < 1e-3,
            "the hand turned {turned} rad under {torque:?}"
        );
    }
}
