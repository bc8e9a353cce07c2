//! Peg-in-Hole (AMBENCH_SPEC §4.1): a peg held from the start is pushed into a square hole
//! standing on a randomised, pitched wall.
//!
//! Scene:
//! - the default wall, moved by U(±0.2) in x and y and pitched by U(±π/6);
//! - the hole: a fixed square frame on the wall face, its root at wall-local (−0.07, y, z)
//!   with y, z ~ U(±0.3), oriented as the wall; 0.04 m thick along the wall normal, so it
//!   spans wall-local x ∈ [−0.09, −0.05] and its back rests on the wall face; its bore is
//!   0.06·s square with s ~ U(0.75, 1.5) (the reference's (1, s, s) scale, drawn once per
//!   environment at start-up there, per rollout here, after the position);
//! - the peg: a cylinder of radius 0.02 m and length 0.15 m along its own x, mass 0.01 kg,
//!   gravity on, its root at its centre, placed at reset at the tool tip with the
//!   command-frame orientation (peg axis = command +x) and held by the grasp constraint.
//!
//! [U] choices (the reference keeps the hole and the peg only as USD assets):
//! - the frame's four bars are 0.03·s wide (outer side 0.12·s), scaled with the opening as
//!   the reference's asset is;
//! - the bore's mouth is chamfered: over the front half of the thickness (0.02 m, up to the
//!   hole's mid-plane) each bar's inner face widens from the bore to 0.025·s more at the front
//!   face (51° from the axis at s = 1); the bore itself, 0.06·s, runs from the mid-plane to
//!   the wall, which is where the success test looks at the tip;
//! - the hole's surface friction is 0.3 (a smooth fixture; the peg keeps the default 1.0 and
//!   the combination multiplies);
//! - the peg's root is its centre (the spec's tip is root + R·(0.075, 0, 0)).
//!
//! Why the chamfer and the friction: the EE-only oracle carries the peg 0.18 m ahead of its
//! control point with an attitude loop much softer than the peg's weight torque
//! (J·kp_rot ≈ 0.05 N·m/rad against 0.018 N·m), so when the insertion starts the peg's pitch
//! still lags or overshoots the wall's by 0.02–0.17 rad and the tip arrives up to 40 mm off
//! the axis, more than the bore's clearance (2.5–25 mm). With a square-edged bore and μ = 1
//! the tip catches on the front face and jams in most rollouts (about half succeed); the
//! chamfer, with a friction low enough for the tip to slide on it, guides the tip in as a
//! real fixture's lead-in does, the soft attitude loop letting the peg turn into the bore.
//!
//! How contact is modelled: the peg's contacts are exact every step ([`exact_contacts`]);
//! with rapier's contact recycling a touching peg keeps a stale contact normal for up to
//! 5 cm of motion and stops against a bar it no longer touches.
//!
//! Success (no subtasks): tip = peg + R_peg·(0.075, 0, 0); local = R_holeᵀ(tip − hole);
//! local.x > 0 and |local.y|, |local.z| < side/2. The script aims the tip at the hole's
//! centre, exactly the depth threshold on an unpitched wall: there success depends on the
//! end effector passing its target by a fraction of a millimetre.
//!
//! Observation: `goal_pos` (hole root), and `peg_pos` (peg root), which the reference's
//! script reads from the scene for the grasp offset along the normal.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::{
    Wall, attach, dynamic_body, exact_contacts, fixed_body, pose_of, symmetric, uniform,
};
use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::convert::{pose_to_rapier, vector_to_rapier};
use crate::error::TwinError;

/// Nominal side of the square bore, m.
pub(crate) const HOLE_SIDE_M: f64 = 0.06;
/// Hole thickness along the wall normal, m.
pub const HOLE_THICKNESS_M: f64 = 0.04;
/// Nominal width of the frame's bars, m ([U]).
const BAR_WIDTH_M: f64 = 0.03;
/// Nominal widening of the bore at the front face by the chamfer, m ([U]).
const CHAMFER_WIDTH_M: f64 = 0.025;
/// Depth of the chamfer from the front face, m ([U]): the front half of the thickness.
const CHAMFER_DEPTH_M: f64 = 0.02;
/// Friction coefficient of the hole's surfaces ([U]).
const HOLE_FRICTION: f64 = 0.3;
/// Peg length, m.
pub const PEG_LENGTH_M: f64 = 0.15;
/// Peg radius, m.
pub(crate) const PEG_RADIUS_M: f64 = 0.02;
/// Peg mass, kg.
const PEG_MASS_KG: f64 = 0.01;
/// How far past the hole's mid-plane the tip must be, m.
pub const INSERTION_DEPTH_MIN_M: f64 = 0.0;

#[derive(Debug, Default)]
pub(crate) struct PegInHole {
    wall: Option<Wall>,
    /// The hole frame's root (fixed).
    hole: Option<RigidBodyHandle>,
    /// The bore's side, m (0.06·s).
    side_m: f64,
    peg: Option<RigidBodyHandle>,
}

impl Scene for PegInHole {
    fn task(&self) -> TaskId {
        TaskId::PegInHole
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &[]
    }

    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError> {
        let wall = Wall::randomized(b.rng, 0.2, 0.2, std::f64::consts::FRAC_PI_6);
        wall.insert(b.world);
        let y = symmetric(b.rng, 0.3);
        let z = symmetric(b.rng, 0.3);
        let scale = uniform(b.rng, 0.75, 1.5);
        let x = -0.5 * (2.0 * Wall::HALF.x + HOLE_THICKNESS_M);
        let hole = fixed_body(
            b.world,
            &wall.frame(Vector3::new(x, y, z), UnitQuaternion::identity()),
        );
        self.side_m = HOLE_SIDE_M * scale;
        let bar = bar_points(
            self.side_m / 2.0,
            BAR_WIDTH_M * scale,
            CHAMFER_WIDTH_M * scale,
        );
        let points: Vec<_> = bar.iter().map(vector_to_rapier).collect();
        for k in 0..4 {
            // The top bar, turned about the hole's axis onto each side of the square.
            let turn =
                Isometry3::rotation(Vector3::x() * f64::from(k) * std::f64::consts::FRAC_PI_2);
            let shape = ColliderBuilder::convex_hull(&points).ok_or_else(|| {
                TwinError::Config("peg-in-hole: the hole's bar is degenerate".to_owned())
            })?;
            let collider = attach(b.world, hole, shape, &turn);
            if let Some(c) = b.world.colliders.get_mut(collider) {
                c.set_friction(HOLE_FRICTION);
            }
        }
        // The cylinder's own axis is y: turn it onto x.
        let along_x = Isometry3::rotation(Vector3::z() * std::f64::consts::FRAC_PI_2);
        let shape = ColliderBuilder::cylinder(PEG_LENGTH_M / 2.0, PEG_RADIUS_M)
            .position(pose_to_rapier(&along_x));
        let (peg, peg_collider) = dynamic_body(b.world, &b.tool_tip, shape, PEG_MASS_KG, true);
        exact_contacts(b.world, peg_collider);
        b.graspable.push(peg);
        b.pre_grasped = Some(peg);
        // AMBENCH_SPEC §4.1: grasp width 0.04 m.
        b.pre_grasp_width_m = 0.04;
        self.wall = Some(wall);
        self.hole = Some(hole);
        self.peg = Some(peg);
        Ok(())
    }

    fn after_step(&mut self, world: &mut PhysicsWorld, _view: &View) -> TaskStatus {
        TaskStatus {
            success: self.inserted(world),
            criteria: Vec::new(),
        }
    }

    fn observation(&self, world: &PhysicsWorld) -> TaskObservation {
        let mut o = TaskObservation::default();
        if let Some(hole) = self.hole {
            o.push_vec3(keys::GOAL_POS, &pose_of(world, hole).translation.vector);
        }
        if let Some(peg) = self.peg {
            o.push_vec3(keys::PEG_POS, &pose_of(world, peg).translation.vector);
        }
        o
    }

    fn wall(&self) -> Option<Isometry3<f64>> {
        self.wall.map(|w| w.pose)
    }

    fn obstacle_face_x(&self, _world: &PhysicsWorld) -> Option<f64> {
        self.wall.map(|w| w.face_x())
    }
}

impl PegInHole {
    /// The peg tip in the hole's frame.
    fn tip_in_hole(&self, world: &PhysicsWorld) -> Option<Vector3<f64>> {
        let (hole, peg) = (self.hole?, self.peg?);
        let tip = pose_of(world, peg) * nalgebra::Point3::new(PEG_LENGTH_M / 2.0, 0.0, 0.0);
        Some(pose_of(world, hole).inverse_transform_point(&tip).coords)
    }

    fn inserted(&self, world: &PhysicsWorld) -> bool {
        self.tip_in_hole(world)
            .is_some_and(|local| tip_inside(&local, self.side_m))
    }
}

/// The spec's test on the peg tip in the hole's frame.
fn tip_inside(local: &Vector3<f64>, side_m: f64) -> bool {
    let half = side_m / 2.0;
    local.x > INSERTION_DEPTH_MIN_M && local.y.abs() < half && local.z.abs() < half
}

/// The corners of the frame's top bar (hole frame: x along the axis toward the wall, z up)
/// around a bore of half side `half_m`, the bar `bar_m` wide, its mouth chamfered
/// `chamfer_m` wide. In the x–z section the bar's inner face runs from (−t, half + chamfer)
/// at the front face to (−t + depth, half) and straight on to the back (t, half), t being
/// half the thickness; the bar spans the full outer width in y (the four bars overlap at
/// the corners).
fn bar_points(half_m: f64, bar_m: f64, chamfer_m: f64) -> Vec<Vector3<f64>> {
    let t = HOLE_THICKNESS_M / 2.0;
    let y = half_m + bar_m;
    let section = [
        (-t, half_m + chamfer_m),
        (-t, half_m + bar_m),
        (-t + CHAMFER_DEPTH_M, half_m),
        (t, half_m),
        (t, half_m + bar_m),
    ];
    section
        .iter()
        .flat_map(|&(x, z)| [Vector3::new(x, -y, z), Vector3::new(x, y, z)])
        .collect()
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;
    use crate::tasks::objects::{place, position_of};
    use crate::{Twin, TwinConfig};

    /// The scene alone in a world without gravity, the tool tip at (0.18, 0, 1).
    fn built(seed: u64) -> (PhysicsWorld, PegInHole) {
        let mut world = crate::tasks::tests::world_with(false);
        world.gravity = Vector::ZERO;
        let mut scene = PegInHole::default();
        crate::tasks::tests::build_into(&mut world, &mut scene, seed);
        (world, scene)
    }

    fn view() -> View {
        crate::tasks::tests::view_of(
            1,
            Vector3::new(0.18, 0.0, 1.0),
            Vector3::new(0.0, 0.0, 1.0),
            0.002,
        )
    }

    fn handles(scene: &PegInHole) -> (RigidBodyHandle, RigidBodyHandle) {
        match (scene.hole, scene.peg) {
            (Some(h), Some(p)) => (h, p),
            _ => panic!("scene not built"),
        }
    }

    /// Puts the peg along the hole's normal with its tip at `tip_local` in the hole frame.
    fn put_tip(world: &mut PhysicsWorld, scene: &PegInHole, tip_local: Vector3<f64>) {
        let (hole, peg) = handles(scene);
        let world_from_hole = pose_of(world, hole);
        let center = tip_local - Vector3::new(PEG_LENGTH_M / 2.0, 0.0, 0.0);
        place(
            world,
            peg,
            &(world_from_hole * Isometry3::translation(center.x, center.y, center.z)),
        );
    }

    #[test]
    fn the_tip_must_pass_the_mid_plane_inside_the_opening() {
        for seed in 0..4 {
            let (mut world, mut scene) = built(seed);
            let half = scene.side_m / 2.0;
            let mut success = |tip: Vector3<f64>| {
                put_tip(&mut world, &scene, tip);
                scene.after_step(&mut world, &view()).success
            };
            assert!(success(Vector3::new(1e-4, 0.0, 0.0)));
            assert!(!success(Vector3::new(-1e-4, 0.0, 0.0)));
            assert!(success(Vector3::new(0.01, half - 1e-4, -(half - 1e-4))));
            assert!(!success(Vector3::new(0.01, half + 1e-4, 0.0)));
            assert!(!success(Vector3::new(0.01, 0.0, -(half + 1e-4))));
        }
        assert!(
            !tip_inside(&Vector3::zeros(), HOLE_SIDE_M),
            "depth must exceed 0 strictly"
        );
    }

    #[test]
    fn the_randomisation_stays_in_the_spec_ranges() {
        let mut sides = Vec::new();
        for seed in 0..30 {
            let (world, scene) = built(seed);
            let wall = scene.wall.unwrap_or_else(|| panic!("no wall"));
            let c = wall.pose.translation.vector;
            assert!(
                (c.x - 2.0).abs() <= 0.2 && c.y.abs() <= 0.2 && c.z == 1.0,
                "{c:?}"
            );
            let (roll, pitch, yaw) = wall.pose.rotation.euler_angles();
            assert!(roll.abs() < 1e-12 && yaw.abs() < 1e-12);
            assert!(pitch.abs() <= std::f64::consts::FRAC_PI_6);
            // The hole sits on the wall face, within ±0.3 m of the wall centre, as the wall.
            let (hole, _) = handles(&scene);
            let hole_pose = pose_of(&world, hole);
            let local = wall
                .pose
                .inverse_transform_point(&hole_pose.translation.vector.into());
            assert!((local.x + 0.07).abs() < 1e-9, "{local:?}");
            assert!(local.y.abs() <= 0.3 && local.z.abs() <= 0.3);
            assert!(hole_pose.rotation.angle_to(&wall.pose.rotation) < 1e-12);
            assert!(scene.side_m >= 0.045 && scene.side_m <= 0.09);
            sides.push(scene.side_m);
        }
        let spread =
            sides.iter().copied().fold(0.0, f64::max) - sides.iter().copied().fold(1.0, f64::min);
        assert!(spread > 0.02, "the scale is drawn: {sides:?}");
    }

    #[test]
    fn the_opening_lets_the_peg_through_and_the_frame_stops_it() {
        // Smallest opening over a few seeds: the peg (Ø 0.04) still fits (≥ 0.045).
        let seed = (0..30)
            .min_by(|a, b| built(*a).1.side_m.total_cmp(&built(*b).1.side_m))
            .unwrap_or(0);
        let (mut world, scene) = built(seed);
        let (_, peg) = handles(&scene);
        put_tip(&mut world, &scene, Vector3::new(0.01, 0.0, 0.0));
        let before = position_of(&world, peg);
        for _ in 0..10 {
            world.step();
        }
        assert!(
            (position_of(&world, peg) - before).norm() < 1e-9,
            "centred: no contact"
        );
        // Off-centre by the opening's half side: the peg overlaps a bar and is pushed out.
        put_tip(
            &mut world,
            &scene,
            Vector3::new(0.01, scene.side_m / 2.0, 0.0),
        );
        let before = position_of(&world, peg);
        for _ in 0..10 {
            world.step();
        }
        assert!(
            (position_of(&world, peg) - before).norm() > 1e-4,
            "the bar pushes"
        );
    }

    /// Pushes the peg, free to translate but not to turn, along the hole's axis (0.02 N, 2 s
    /// at 480 Hz) from its tip at (−0.03, 0, `offset`) in the hole frame; returns the tip in
    /// the hole frame.
    fn push_in(seed: u64, offset: f64) -> (Vector3<f64>, f64) {
        let (mut world, mut scene) = built(seed);
        world.integration_parameters.dt = 1.0 / 480.0;
        let (hole, peg) = handles(&scene);
        put_tip(&mut world, &scene, Vector3::new(-0.03, 0.0, offset));
        if let Some(rb) = world.bodies.get_mut(peg) {
            rb.lock_rotations(true, true);
        }
        let axis = pose_of(&world, hole).rotation * Vector3::x();
        for _ in 0..960 {
            if let Some(rb) = world.bodies.get_mut(peg) {
                rb.reset_forces(false);
                rb.add_force(vector_to_rapier(&(axis * 0.02)), true);
            }
            world.step();
        }
        let tip = scene
            .tip_in_hole(&world)
            .unwrap_or_else(|| panic!("no tip"));
        let success = scene.after_step(&mut world, &view()).success;
        assert_eq!(success, tip_inside(&tip, scene.side_m));
        (tip, scene.side_m)
    }

    #[test]
    fn the_chamfer_guides_an_off_axis_peg_into_the_bore() {
        for seed in [0, 1, 2] {
            let side = built(seed).1.side_m;
            let scale = side / HOLE_SIDE_M;
            // Tip centre on the bore's edge: its rim lands on the chamfer and slides in.
            let (tip, _) = push_in(seed, side / 2.0);
            assert!(tip_inside(&tip, side), "seed {seed}: {tip:?}");
            // Rim beyond the chamfer's mouth: it lands on the front face and stays out.
            let out = side / 2.0 + CHAMFER_WIDTH_M * scale - PEG_RADIUS_M + 0.003;
            let (tip, _) = push_in(seed, out);
            assert!(tip.x < -0.019, "seed {seed}: {tip:?}");
        }
    }

    #[test]
    fn the_peg_is_held_at_the_tool_tip_along_the_command_x() {
        let vehicle = platform::Vehicle::builtin("ee-only").unwrap_or_else(|e| panic!("{e}"));
        let twin = Twin::new(
            vehicle,
            TwinConfig {
                task: Some(TaskId::PegInHole),
                seed: 5,
                ..Default::default()
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(twin.holding());
        let o = twin.task_observation().unwrap_or_default();
        let peg = o.vec3("peg_pos", 0).unwrap_or_else(|e| panic!("{e}"));
        let tip = twin.tool_tip();
        assert!((peg - tip.translation.vector).norm() < 1e-9);
        assert!(o.vec3("goal_pos", 0).is_ok());
        // The peg's tip is 0.075 m ahead of the tool tip along the command x.
        let ahead = tip * Point3::new(PEG_LENGTH_M / 2.0, 0.0, 0.0);
        assert!((ahead.coords - peg - Vector3::new(0.075, 0.0, 0.0)).norm() < 1e-9);
    }
}
