//! Lemon Harvesting (AMBENCH_SPEC §4.4): a lemon hangs on the wall by a breakable fixed
//! joint among six fixed limes; the gripper takes it, pulls it off (the joint breaks at 10 N
//! or 10 N·m), carries it over a container on a table and lets it drop in.
//!
//! The breakable joint: after every control tick the joint's impulses give its force (linear
//! part) and torque (angular part); above 10 N or 10 N·m the joint is removed, as PhysX
//! breaks a joint. rapier's `ImpulseJoint::impulses` are those of the last *solver* step: it
//! runs `num_solver_iterations` (4 in the twin) solver steps per physics substep, so the
//! force is the impulse divided by substep / iterations (dividing by the physics substep
//! alone would read a quarter of the force and break the stem at 40 N); the angular impulses
//! are twice the angular impulse (rapier constrains the quaternion's vector part), so the
//! torque is half of theirs over that step. The unit tests check 9 N / 9.5 N·m hold and
//! 11 N / 10.5 N·m break.
//!
//! [U] choices (the reference keeps the fruit, the container and the table only as USD
//! assets):
//! - Lemon: a capsule along z, radius [`LEMON_RADIUS_M`] = 0.025 m and straight part 0.02 m
//!   (0.07 m tall, 0.05 m wide), mass 0.05 kg (spec), its origin (`lemon_pos`, the joint's
//!   anchor) at its bottom, so its centre is 0.035 m above the origin. The script closes the
//!   fingers 0.03–0.04 m above the origin, i.e. around the lemon's middle, which this origin
//!   is derived from. (With the origin at the centre the fingers reach only the lemon's
//!   top, and the lemon hangs 0.035 m lower under the gripper: the twin's light end
//!   effector pitches 0.5–0.6 rad nose down under the 50 g lemon held 0.17 m ahead (its PID
//!   torques scale with its small inertia), and the lemon then caught on the container's
//!   near wall on the way in, in 17 of 100 rollouts.) Its axis stands 0.03 m off the wall
//!   face (spec x = 1.92), clearing the wall by 5 mm.
//! - Limes: balls of radius 0.025 m, fixed (the reference's are kinematic).
//! - Container: an open box, 0.4 × 0.3 m outside, 0.17 m tall (nominal), walls and floor
//!   0.01 m thick, origin at the centre of its bottom (the goal region's box starts there).
//! - Table ("cline", scale (0.4, 0.2, 0.8)): a box 0.4 m (x) × 0.2 m (y) under the container,
//!   its top at the container's bottom, z 0–0.65 m.
//! - The joint's frame is the lemon's origin (its bottom); the lemon does not collide with
//!   the wall while the joint holds.

use nalgebra::{Isometry3, Translation3, Vector3};
use rapier3d_f64::prelude::*;

use super::keys;
use super::objects::{Wall, attach, fixed_body, fixed_box, position_of, uniform, world_groups};
use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::convert::pose_to_rapier;
use crate::error::TwinError;
use crate::vehicle_body::material;

/// Lemon mass, kg.
pub(crate) const LEMON_MASS_KG: f64 = 0.05;
/// Lemon capsule radius and half straight length, m [U].
pub(crate) const LEMON_RADIUS_M: f64 = 0.025;
pub(crate) const LEMON_HALF_LENGTH_M: f64 = 0.01;
/// Height of the lemon's centre above its origin (its bottom), m [U].
pub(crate) const LEMON_CENTRE_Z_M: f64 = LEMON_HALF_LENGTH_M + LEMON_RADIUS_M;
/// Lime radius, m [U].
pub(crate) const LIME_RADIUS_M: f64 = 0.025;
/// Number of limes.
pub(crate) const LIMES: usize = 6;
/// Fruit x: the wall centre minus 0.08 m.
pub(crate) const FRUIT_X: f64 = 2.0 - 0.08;
/// Fruit y and z ranges.
pub(crate) const FRUIT_Y: (f64, f64) = (-0.5, 0.5);
pub(crate) const FRUIT_Z: (f64, f64) = (1.1, 1.5);
/// Least YZ distance between fruits, m.
pub(crate) const FRUIT_SPACING_M: f64 = 0.15;
/// Least distance of a fruit from the wall's edges (wall-local), m.
pub(crate) const EDGE_MARGIN_M: f64 = 0.08;
/// Rejection-sampling tries per lime.
pub(crate) const MAX_TRIES: usize = 200;
/// The joint breaks above this force, N, or torque, N·m.
pub(crate) const BREAK_FORCE_N: f64 = 10.0;
pub(crate) const BREAK_TORQUE_NM: f64 = 10.0;
/// Container position (centre of its bottom) and table position.
pub(crate) const CONTAINER: Vector3<f64> = Vector3::new(1.72, 0.5, 0.65);
pub(crate) const TABLE: Vector3<f64> = Vector3::new(1.72, 0.5, 0.0);
/// Goal region relative to the container: lower and upper corners (inclusive).
pub(crate) const GOAL_LO: Vector3<f64> = Vector3::new(-0.2, -0.15, 0.0);
pub(crate) const GOAL_HI: Vector3<f64> = Vector3::new(0.2, 0.15, 0.17);
/// Container outer size and wall thickness, m [U].
const CONTAINER_SIZE: Vector3<f64> = Vector3::new(0.4, 0.3, 0.17);
const CONTAINER_WALL_M: f64 = 0.01;
/// Table half extents, m [U].
const TABLE_HALF: Vector3<f64> = Vector3::new(0.2, 0.1, 0.325);
/// Released: gripper width above this, m.
pub(crate) const RELEASED_WIDTH_M: f64 = 0.0898;
/// Grasp-and-detach: closed below this width, m; near within this distance, m.
pub(crate) const CLOSED_WIDTH_M: f64 = 0.05;
pub(crate) const NEAR_M: f64 = 0.12;
/// Grasp-and-detach: least displacement of lemon and tip, m, and least cosine between them.
pub(crate) const MOVED_M: f64 = 0.02;
pub(crate) const MIN_COS: f64 = 0.75;

/// The latched `lemon_grasped_and_detached` subtask (AMBENCH_SPEC §4.4).
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct DetachLatch {
    /// Lemon and tool-tip positions when closed & near first held.
    anchor: Option<(Vector3<f64>, Vector3<f64>)>,
    /// Latched result.
    pub done: bool,
}

impl DetachLatch {
    /// One tick: closed = width < 0.05; near = |lemon − tip| < 0.12; the anchor is taken when
    /// closed & near first holds and dropped when it stops holding; the latch sets when the
    /// anchor is active, closed & near, both moved ≥ 0.02 m and cos(Δlemon, Δtip) ≥ 0.75.
    pub fn update(&mut self, lemon: &Vector3<f64>, tip: &Vector3<f64>, width_m: f64) -> bool {
        let closed = width_m < CLOSED_WIDTH_M;
        let near = (lemon - tip).norm() < NEAR_M;
        if !(closed && near) {
            self.anchor = None;
            return self.done;
        }
        let Some((lemon0, tip0)) = self.anchor else {
            self.anchor = Some((*lemon, *tip));
            return self.done;
        };
        let dl = lemon - lemon0;
        let dt = tip - tip0;
        let (nl, nt) = (dl.norm(), dt.norm());
        if nl >= MOVED_M && nt >= MOVED_M && dl.dot(&dt) / (nl * nt) >= MIN_COS {
            self.done = true;
        }
        self.done
    }
}

#[derive(Debug, Default)]
pub(crate) struct LemonHarvesting {
    wall: Option<Wall>,
    lemon: Option<RigidBodyHandle>,
    stem: Option<ImpulseJointHandle>,
    limes: Vec<Vector3<f64>>,
    container: Vector3<f64>,
    latch: DetachLatch,
}

impl Scene for LemonHarvesting {
    fn task(&self) -> TaskId {
        TaskId::LemonHarvesting
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &["lemon_grasped_and_detached", "lemon_delivered_released"]
    }

    fn build(&mut self, b: &mut Build<'_>) -> Result<(), TwinError> {
        let wall = Wall::at_default();
        let (wall_body, _) = wall.insert(b.world);
        // Lemon (y, z), then each lime by rejection sampling.
        let lemon_yz = sample_yz(b.rng);
        let mut placed = vec![lemon_yz];
        for i in 0..LIMES {
            let lime = (0..MAX_TRIES)
                .map(|_| sample_yz(b.rng))
                .find(|p| valid_lime(&wall, p, &placed))
                .ok_or_else(|| {
                    TwinError::Config(format!(
                        "lemon harvesting: no valid position for lime {i} in {MAX_TRIES} tries"
                    ))
                })?;
            placed.push(lime);
        }
        let at = |(y, z): (f64, f64)| {
            Isometry3::from_parts(Translation3::new(FRUIT_X, y, z), wall.pose.rotation)
        };
        let lemon_pose = at(lemon_yz);
        let lemon = insert_lemon(b.world, &lemon_pose);
        let wall_from_lemon = wall.pose.inverse() * lemon_pose;
        let stem = FixedJointBuilder::new()
            .local_frame1(pose_to_rapier(&wall_from_lemon))
            .local_frame2(pose_to_rapier(&Isometry3::identity()))
            .contacts_enabled(false);
        let stem = b.world.insert_impulse_joint(wall_body, lemon, stem);
        self.limes = placed[1..]
            .iter()
            .map(|&p| {
                let pose = at(p);
                let body = fixed_body(b.world, &pose);
                attach(
                    b.world,
                    body,
                    ColliderBuilder::ball(LIME_RADIUS_M),
                    &Isometry3::identity(),
                );
                pose.translation.vector
            })
            .collect();
        fixed_box(
            b.world,
            &Isometry3::translation(TABLE.x, TABLE.y, TABLE.z + TABLE_HALF.z),
            TABLE_HALF,
        );
        insert_container(b.world, &CONTAINER);
        self.container = CONTAINER;
        self.wall = Some(wall);
        self.lemon = Some(lemon);
        self.stem = Some(stem);
        self.latch = DetachLatch::default();
        b.graspable.push(lemon);
        Ok(())
    }

    fn after_step(&mut self, world: &mut PhysicsWorld, view: &View) -> TaskStatus {
        self.break_stem_if_overloaded(world, view.substep_s);
        let lemon = self.lemon_position(world);
        let detached = self
            .latch
            .update(&lemon, &view.tool_tip, view.gripper_width_m);
        let delivered = self.in_goal(&lemon) && view.gripper_width_m > RELEASED_WIDTH_M;
        TaskStatus {
            success: delivered,
            criteria: vec![detached, delivered],
        }
    }

    fn observation(&self, world: &PhysicsWorld) -> TaskObservation {
        let mut o = TaskObservation::default();
        o.push_vec3(keys::LEMON_POS, &self.lemon_position(world));
        o.push_vec3(keys::CONTAINER_POS, &self.container);
        o
    }

    fn wall(&self) -> Option<Isometry3<f64>> {
        self.wall.map(|w| w.pose)
    }

    fn obstacle_face_x(&self, _world: &PhysicsWorld) -> Option<f64> {
        self.wall.map(|w| w.face_x())
    }
}

impl LemonHarvesting {
    fn lemon_position(&self, world: &PhysicsWorld) -> Vector3<f64> {
        self.lemon
            .map_or_else(Vector3::zeros, |l| position_of(world, l))
    }

    /// Whether `p` is in the goal region (container + [lo, hi], inclusive).
    fn in_goal(&self, p: &Vector3<f64>) -> bool {
        let d = p - self.container;
        (0..3).all(|i| d[i] >= GOAL_LO[i] && d[i] <= GOAL_HI[i])
    }

    /// Whether the lemon still hangs on the wall.
    #[cfg(test)]
    pub fn attached(&self) -> bool {
        self.stem.is_some()
    }

    /// Removes the stem joint when its last substep's force or torque is over the limit.
    fn break_stem_if_overloaded(&mut self, world: &mut PhysicsWorld, substep_s: f64) {
        let Some(stem) = self.stem else {
            return;
        };
        let Some(joint) = world.impulse_joints.get(stem) else {
            self.stem = None;
            return;
        };
        // rapier splits each physics substep into `num_solver_iterations` solver steps and
        // keeps the impulse of the last one.
        let solver_dt =
            substep_s / world.integration_parameters.num_solver_iterations.max(1) as f64;
        let i = joint.impulses;
        let force = Vector3::new(i[0], i[1], i[2]).norm() / solver_dt;
        // The locked angular axes constrain the rotation's quaternion vector part, whose rate
        // is half the angular velocity: their impulses are twice the angular impulse.
        let torque = Vector3::new(i[3], i[4], i[5]).norm() / (2.0 * solver_dt);
        if force > BREAK_FORCE_N || torque > BREAK_TORQUE_NM {
            world.remove_impulse_joint(stem);
            self.stem = None;
        }
    }
}

/// A fruit's (y, z): U(−0.5, 0.5) × U(1.1, 1.5).
fn sample_yz(rng: &mut rand_chacha::ChaCha8Rng) -> (f64, f64) {
    let y = uniform(rng, FRUIT_Y.0, FRUIT_Y.1);
    let z = uniform(rng, FRUIT_Z.0, FRUIT_Z.1);
    (y, z)
}

/// A lime position is valid 0.08 m inside the wall's edges (wall-local, half size 1.0) and
/// at least 0.15 m (YZ) from every fruit placed.
fn valid_lime(wall: &Wall, (y, z): &(f64, f64), placed: &[(f64, f64)]) -> bool {
    let local = wall.pose.inverse() * nalgebra::Point3::new(FRUIT_X, *y, *z);
    let inside = Wall::HALF.y - local.y.abs() > EDGE_MARGIN_M
        && Wall::HALF.z - local.z.abs() > EDGE_MARGIN_M;
    inside
        && placed
            .iter()
            .all(|(py, pz)| (y - py).hypot(z - pz) >= FRUIT_SPACING_M)
}

/// The lemon: a dynamic capsule along z, gravity on.
fn insert_lemon(world: &mut PhysicsWorld, pose: &Isometry3<f64>) -> RigidBodyHandle {
    let body = world.insert_body(
        RigidBodyBuilder::dynamic()
            .pose(pose_to_rapier(pose))
            .can_sleep(false)
            .build(),
    );
    let collider = material(ColliderBuilder::capsule_z(
        LEMON_HALF_LENGTH_M,
        LEMON_RADIUS_M,
    ))
    .mass(LEMON_MASS_KG)
    .collision_groups(world_groups())
    .position(pose_to_rapier(&Isometry3::translation(
        0.0,
        0.0,
        LEMON_CENTRE_Z_M,
    )));
    world.insert_collider(collider, Some(body));
    body
}

/// The container: a floor and four walls on one fixed body at the centre of its bottom.
fn insert_container(world: &mut PhysicsWorld, bottom: &Vector3<f64>) {
    let body = fixed_body(world, &Isometry3::translation(bottom.x, bottom.y, bottom.z));
    let h = CONTAINER_SIZE / 2.0;
    let t = CONTAINER_WALL_M / 2.0;
    let boxes = [
        (Vector3::new(h.x, h.y, t), Vector3::new(0.0, 0.0, t)),
        (Vector3::new(t, h.y, h.z), Vector3::new(h.x - t, 0.0, h.z)),
        (Vector3::new(t, h.y, h.z), Vector3::new(-h.x + t, 0.0, h.z)),
        (Vector3::new(h.x, t, h.z), Vector3::new(0.0, h.y - t, h.z)),
        (Vector3::new(h.x, t, h.z), Vector3::new(0.0, -h.y + t, h.z)),
    ];
    for (half, centre) in boxes {
        attach(
            world,
            body,
            ColliderBuilder::cuboid(half.x, half.y, half.z),
            &Isometry3::translation(centre.x, centre.y, centre.z),
        );
    }
}

#[cfg(test)]
mod tests {

    use super::*;
    use crate::tasks::objects::place;
    use crate::tasks::{Scene, View};

    fn world() -> PhysicsWorld {
        crate::tasks::tests::world_with(true)
    }

    fn scene(seed: u64) -> (PhysicsWorld, LemonHarvesting) {
        let mut w = world();
        let mut s = LemonHarvesting::default();
        let built = crate::tasks::tests::build_into(&mut w, &mut s, seed);
        assert_eq!(
            built.graspable,
            vec![s.lemon.unwrap_or_else(|| panic!("no lemon"))]
        );
        (w, s)
    }

    fn view(tip: Vector3<f64>, width: f64) -> View {
        crate::tasks::tests::view_of(1, tip, Vector3::new(0.0, 0.0, 1.0), width)
    }

    fn lemon(s: &LemonHarvesting) -> RigidBodyHandle {
        s.lemon.unwrap_or_else(|| panic!("no lemon"))
    }

    /// One control tick (4 substeps) with a constant force on the lemon.
    fn tick(w: &mut PhysicsWorld, s: &mut LemonHarvesting, force: Vector3<f64>) -> TaskStatus {
        for _ in 0..4 {
            if let Some(rb) = w.bodies.get_mut(lemon(s)) {
                rb.reset_forces(false);
                rb.add_force(Vector::new(force.x, force.y, force.z), true);
            }
            w.step();
        }
        s.after_step(w, &view(Vector3::zeros(), 0.09))
    }

    #[test]
    fn fruits_are_sampled_in_range_and_spaced() {
        for seed in 0..30 {
            let (w, s) = scene(seed);
            let l = s.lemon_position(&w);
            assert!((l.x - FRUIT_X).abs() < 1e-12);
            assert!(
                (-0.5..0.5).contains(&l.y) && (1.1..1.5).contains(&l.z),
                "lemon {l}"
            );
            assert_eq!(s.limes.len(), LIMES);
            let mut all = vec![l];
            all.extend(s.limes.iter().copied());
            for (i, a) in all.iter().enumerate() {
                assert!((a.x - FRUIT_X).abs() < 1e-12);
                assert!((-0.5..0.5).contains(&a.y) && (1.1..1.5).contains(&a.z));
                for b in &all[i + 1..] {
                    assert!((a.y - b.y).hypot(a.z - b.z) >= FRUIT_SPACING_M);
                }
            }
        }
    }

    #[test]
    fn lime_validity_follows_the_edge_and_spacing_rules() {
        let wall = Wall::at_default();
        let lemon = [(0.0, 1.3)];
        assert!(valid_lime(&wall, &(0.15, 1.3), &lemon));
        assert!(!valid_lime(&wall, &(0.149, 1.3), &lemon));
        // Closer than 0.08 m to the wall's edges (wall-local |y| or |z| > 0.92): not valid.
        assert!(!valid_lime(&wall, &(0.921, 1.3), &lemon));
        assert!(valid_lime(&wall, &(0.919, 1.3), &lemon));
        assert!(!valid_lime(&wall, &(0.5, 1.921), &lemon));
        assert!(valid_lime(&wall, &(0.5, 1.919), &lemon));
    }

    #[test]
    fn the_lemon_hangs_under_its_weight_and_breaks_off_above_10_n() {
        let (mut w, mut s) = scene(1);
        let start = s.lemon_position(&w);
        for _ in 0..60 {
            tick(&mut w, &mut s, Vector3::new(-9.0, 0.0, 0.0));
        }
        assert!(s.attached(), "9 N pull (plus its weight) holds");
        assert!((s.lemon_position(&w) - start).norm() < 1e-3);
        tick(&mut w, &mut s, Vector3::new(-11.0, 0.0, 0.0));
        assert!(!s.attached(), "11 N pull breaks the stem");
        for _ in 0..30 {
            tick(&mut w, &mut s, Vector3::zeros());
        }
        assert!(
            s.lemon_position(&w).z < start.z - 0.03,
            "the lemon falls once free"
        );
    }

    #[test]
    fn a_torque_above_10_nm_breaks_the_stem() {
        let (mut w, mut s) = scene(2);
        for _ in 0..4 {
            if let Some(rb) = w.bodies.get_mut(lemon(&s)) {
                rb.reset_torques(false);
                rb.add_torque(Vector::new(0.0, 9.5, 0.0), true);
            }
            w.step();
        }
        s.after_step(&mut w, &view(Vector3::zeros(), 0.09));
        assert!(s.attached());
        for _ in 0..4 {
            if let Some(rb) = w.bodies.get_mut(lemon(&s)) {
                rb.reset_torques(false);
                rb.add_torque(Vector::new(0.0, 10.5, 0.0), true);
            }
            w.step();
        }
        s.after_step(&mut w, &view(Vector3::zeros(), 0.09));
        assert!(!s.attached());
    }

    #[test]
    fn delivered_needs_the_lemon_in_the_box_and_the_gripper_open_past_0_0898() {
        let (mut w, mut s) = scene(3);
        if let Some(j) = s.stem.take() {
            w.remove_impulse_joint(j);
        }
        let c = CONTAINER;
        for (offset, width, delivered) in [
            (Vector3::new(0.0, 0.0, 0.05), 0.0899, true),
            (Vector3::new(0.0, 0.0, 0.05), 0.0898, false),
            (Vector3::new(0.1999, 0.1499, 0.1699), 0.09, true),
            (Vector3::new(-0.1999, -0.1499, 0.0001), 0.09, true),
            (Vector3::new(0.201, 0.0, 0.05), 0.09, false),
            (Vector3::new(0.0, -0.151, 0.05), 0.09, false),
            (Vector3::new(0.0, 0.0, 0.171), 0.09, false),
            (Vector3::new(0.0, 0.0, -0.001), 0.09, false),
        ] {
            let p = c + offset;
            place(&mut w, lemon(&s), &Isometry3::translation(p.x, p.y, p.z));
            let st = s.after_step(&mut w, &view(Vector3::zeros(), width));
            assert_eq!(st.success, delivered, "offset {offset}, width {width}");
            assert_eq!(st.criteria[1], delivered);
        }
    }

    #[test]
    fn the_detach_latch_needs_a_closed_grip_near_the_lemon_and_a_common_motion() {
        let l0 = Vector3::new(1.92, 0.0, 1.3);
        let t0 = Vector3::new(1.93, 0.0, 1.33);
        let back = Vector3::new(-1.0, 0.0, 0.0);
        // Both move 2.1 cm the same way while closed and near: latched.
        let mut latch = DetachLatch::default();
        assert!(!latch.update(&l0, &t0, 0.01));
        assert!(!latch.update(&(l0 + back * 0.019), &(t0 + back * 0.019), 0.01));
        assert!(latch.update(&(l0 + back * 0.021), &(t0 + back * 0.021), 0.01));
        // Stays latched whatever follows.
        assert!(latch.update(&l0, &(t0 + Vector3::new(0.0, 0.0, 1.0)), 0.09));
        // Open gripper (width ≥ 0.05): no anchor, no latch.
        let mut latch = DetachLatch::default();
        latch.update(&l0, &t0, 0.05);
        assert!(!latch.update(&(l0 + back * 0.05), &(t0 + back * 0.05), 0.05));
        // Too far (≥ 0.12 m) from the tip: no anchor.
        let mut latch = DetachLatch::default();
        let far = l0 + Vector3::new(0.0, 0.12, 0.0);
        latch.update(&far, &t0, 0.01);
        assert!(!latch.update(&(far + back * 0.05), &(t0 + back * 0.05), 0.01));
        // The tip moves but the lemon stays (it has not come off): no latch.
        let mut latch = DetachLatch::default();
        latch.update(&l0, &t0, 0.01);
        assert!(!latch.update(&l0, &(t0 + back * 0.05), 0.01));
        // Moving apart (cos < 0.75): no latch; cos(40°) ≈ 0.766 latches.
        let mut latch = DetachLatch::default();
        latch.update(&l0, &t0, 0.01);
        let askew = Vector3::new(-0.7, 0.7, 0.0) * 0.05;
        assert!(!latch.update(&(l0 + back * 0.05), &(t0 + askew), 0.01));
        let (s40, c40) = 40f64.to_radians().sin_cos();
        assert!(latch.update(
            &(l0 + back * 0.05),
            &(t0 + Vector3::new(-c40, s40, 0.0) * 0.05),
            0.01
        ));
        // The anchor resets when the grip opens: motion before the reset does not count.
        let mut latch = DetachLatch::default();
        latch.update(&l0, &t0, 0.01);
        latch.update(&(l0 + back * 0.01), &(t0 + back * 0.01), 0.06);
        latch.update(&(l0 + back * 0.01), &(t0 + back * 0.01), 0.01);
        assert!(!latch.update(&(l0 + back * 0.025), &(t0 + back * 0.025), 0.01));
        assert!(latch.update(&(l0 + back * 0.031), &(t0 + back * 0.031), 0.01));
    }

    #[test]
    fn a_released_lemon_lands_in_the_container() {
        let (mut w, mut s) = scene(4);
        if let Some(j) = s.stem.take() {
            w.remove_impulse_joint(j);
        }
        place(&mut w, lemon(&s), &Isometry3::translation(1.67, 0.5, 0.89));
        for _ in 0..120 {
            tick(&mut w, &mut s, Vector3::zeros());
        }
        let st = s.after_step(&mut w, &view(Vector3::zeros(), 0.09));
        assert!(st.success, "lemon at {}", s.lemon_position(&w));
    }
}
