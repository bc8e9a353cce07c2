//! Specifications of the whole-body IK.

use std::f64::consts::PI;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use platform::Vehicle;

use super::chain::{Chain, Motion};
use super::*;

/// Pose accuracy every recovered target must meet, m and rad.
const RECOVERED_POSITION_M: f64 = 1e-4;
const RECOVERED_ORIENTATION_RAD: f64 = 1e-3;
/// Agreement of two evaluations of the same kinematics (round-off only), m or rad.
const KINEMATICS_AGREEMENT: f64 = 1e-12;
/// Largest limit violation of a converged solution (the solver's `limit_tolerance`).
const LIMIT_TOLERANCE: f64 = 1e-6;
/// Targets per vehicle and start in the recovery tests.
const TARGETS: usize = 1000;
/// Rate of the flight loop, Hz.
const RATE_HZ: f64 = 120.0;

/// A tiny deterministic generator (xorshift64*), so every run sees the same targets.
struct XorShift(u64);

impl XorShift {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let bits = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11;
        lo + (hi - lo) * (bits as f64 / (1u64 << 53) as f64)
    }
}

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap_or_else(|e| panic!("built-in vehicle {id}: {e}"))
}

fn ik_with(v: &Vehicle, config: IkConfig) -> WholeBodyIk {
    WholeBodyIk::new(v, config).unwrap_or_else(|e| panic!("{}: {e}", v.id))
}

fn ik_for(v: &Vehicle) -> WholeBodyIk {
    let config = IkConfig::for_vehicle(v).unwrap_or_else(|e| panic!("{}: {e}", v.id));
    ik_with(v, config)
}

fn pose(position: Vector3<f64>, rotation: UnitQuaternion<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(position), rotation)
}

fn spawn() -> Isometry3<f64> {
    pose(Vector3::new(0.0, 0.0, 1.0), UnitQuaternion::identity())
}

/// The EE pose by the platform's own FK (independent of the IK's flattened chain).
fn platform_world_from_ee(
    v: &Vehicle,
    world_from_base: &Isometry3<f64>,
    q: &[f64],
) -> Isometry3<f64> {
    world_from_base * v.model.root_from_link(q, v.ee_link)
}

/// Position and orientation distance of two poses, m and rad.
fn pose_errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    (
        (a.translation.vector - b.translation.vector).norm(),
        a.rotation.angle_to(&b.rotation),
    )
}

/// The IK's solution, checked by the platform's FK against the target.
fn solution_errors(v: &Vehicle, s: &IkSolution, target: &Isometry3<f64>) -> (f64, f64) {
    pose_errors(
        &platform_world_from_ee(v, &s.world_from_base, &s.configuration),
        target,
    )
}

fn all_finite(s: &IkSolution) -> bool {
    s.configuration.iter().all(|x| x.is_finite())
        && s.arm_joints.iter().all(|x| x.is_finite())
        && s.world_from_base
            .translation
            .vector
            .iter()
            .all(|x| x.is_finite())
        && s.world_from_base
            .rotation
            .coords
            .iter()
            .all(|x| x.is_finite())
}

fn joint_limits(v: &Vehicle, dof: usize) -> (f64, f64) {
    v.model
        .dof_joint(dof)
        .limits
        .map_or((f64::NEG_INFINITY, f64::INFINITY), |l| (l.lower, l.upper))
}

/// Joint sampling range: the limits, with unbounded or multi-turn joints (±2π, ±10 rad)
/// sampled on ±π.
fn sampling_range(v: &Vehicle, dof: usize) -> (f64, f64) {
    let (lo, hi) = joint_limits(v, dof);
    (lo.max(-PI), hi.min(PI))
}

/// A base pose and full configuration that respect the vehicle's locks and limits: base in
/// a 3 × 3 × 2 m box; FA-Hexa level with no yaw, UA yaw only, Omni ±30° roll and pitch and
/// any yaw; arm joints uniform within their sampling range.
fn random_state(v: &Vehicle, rng: &mut XorShift) -> (Isometry3<f64>, Vec<f64>) {
    let position = Vector3::new(
        rng.uniform(-1.5, 1.5),
        rng.uniform(-1.5, 1.5),
        rng.uniform(0.5, 2.5),
    );
    let max_tilt = 30f64.to_radians();
    let rotation = match v.id.as_str() {
        "fa-hexa" => UnitQuaternion::identity(),
        "omni-hexa" => UnitQuaternion::from_euler_angles(
            rng.uniform(-max_tilt, max_tilt),
            rng.uniform(-max_tilt, max_tilt),
            rng.uniform(-PI, PI),
        ),
        _ => UnitQuaternion::from_euler_angles(0.0, 0.0, rng.uniform(-PI, PI)),
    };
    let mut q = v.initial_configuration();
    for d in v.arm_dofs() {
        let (lo, hi) = sampling_range(v, d);
        q[d] = rng.uniform(lo, hi);
    }
    (pose(position, rotation), q)
}

/// How a recovery test starts each solve.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Start {
    /// Near the sampled state: joints ±0.05 rad (kept within limits), base ±2 cm per axis,
    /// free rotation axes ±0.05 rad.
    Warm,
    /// The rest posture with the base at the spawn pose (0, 0, 1), level, yaw 0.
    Rest,
}

#[derive(Debug)]
struct Recovery {
    /// Iteration counts of the solves that met the pose, sorted.
    iterations: Vec<u32>,
    /// Solves that met the pose within `RECOVERED_*`.
    successes: usize,
    /// Solves that met the pose and reported `converged`.
    converged: usize,
    /// Largest limit violation over the successful solves, m or rad.
    worst_violation: f64,
    /// Every returned number was finite.
    all_finite: bool,
}

impl Recovery {
    fn success_fraction(&self) -> f64 {
        self.successes as f64 / TARGETS as f64
    }

    fn max_iterations(&self) -> u32 {
        self.iterations.last().copied().unwrap_or(0)
    }

    fn p99_iterations(&self) -> u32 {
        let i = (self.iterations.len() * 99).div_ceil(100).max(1) - 1;
        self.iterations.get(i).copied().unwrap_or(0)
    }
}

/// Solves `TARGETS` targets from FK of random states of vehicle `id`.
fn recover(id: &str, start: Start, seed: u64) -> Recovery {
    let v = vehicle(id);
    let mut ik = ik_for(&v);
    let mut rng = XorShift(seed);
    let locks = ik.config().fix_base_orientation;
    let rest = ik.rest_configuration();
    let mut out = Recovery {
        iterations: Vec::with_capacity(TARGETS),
        successes: 0,
        converged: 0,
        worst_violation: 0.0,
        all_finite: true,
    };
    for _ in 0..TARGETS {
        let (base, q) = random_state(&v, &mut rng);
        let target = platform_world_from_ee(&v, &base, &q);
        match start {
            Start::Warm => {
                let mut q0 = q.clone();
                for d in v.arm_dofs() {
                    let (lo, hi) = joint_limits(&v, d);
                    q0[d] = (q0[d] + rng.uniform(-0.05, 0.05)).clamp(lo, hi);
                }
                let offset = Vector3::from_fn(|_, _| rng.uniform(-0.02, 0.02));
                let turn = Vector3::from_fn(|axis, _| {
                    if locks[axis] {
                        0.0
                    } else {
                        rng.uniform(-0.05, 0.05)
                    }
                });
                let base0 = pose(
                    base.translation.vector + offset,
                    UnitQuaternion::from_scaled_axis(turn) * base.rotation,
                );
                ik.reset(&base0, &q0).unwrap_or_else(|e| panic!("{e}"));
            }
            Start::Rest => ik.reset(&spawn(), &rest).unwrap_or_else(|e| panic!("{e}")),
        }
        let solution = ik.solve(&target, &BaseLimits::above_ground());
        out.all_finite &= all_finite(&solution);
        let (dp, dr) = solution_errors(&v, &solution, &target);
        if dp <= RECOVERED_POSITION_M && dr <= RECOVERED_ORIENTATION_RAD {
            out.successes += 1;
            out.iterations.push(solution.status.iterations);
            out.converged += usize::from(solution.status.converged);
            out.worst_violation = out.worst_violation.max(solution.status.limit_violation);
        }
    }
    out.iterations.sort_unstable();
    out
}

/// Warm start (a): every target is recovered, reported converged, within the limits, in at
/// most `max_iterations` iterations.
fn assert_warm_recovery(id: &str, max_iterations: u32) {
    let r = recover(id, Start::Warm, 0x5EED_0001);
    assert!(r.all_finite, "{id}: non-finite output");
    assert_eq!(r.successes, TARGETS, "{id}: warm-start recoveries {r:?}");
    assert_eq!(r.converged, TARGETS, "{id}: converged statuses");
    assert!(
        r.worst_violation <= LIMIT_TOLERANCE,
        "{id}: limit violation {}",
        r.worst_violation
    );
    assert!(
        r.max_iterations() <= max_iterations,
        "{id}: {} iterations (p99 {})",
        r.max_iterations(),
        r.p99_iterations()
    );
}

/// Rest start (b): at least `min_fraction` of the targets recovered, 99 % of them in at most
/// `p99_iterations` iterations and all within the 100-iteration budget.
fn assert_rest_recovery(id: &str, min_fraction: f64, p99_iterations: u32) {
    let r = recover(id, Start::Rest, 0x5EED_0002);
    assert!(r.all_finite, "{id}: non-finite output");
    assert!(
        r.success_fraction() >= min_fraction,
        "{id}: recovered {} from rest",
        r.success_fraction()
    );
    assert!(
        r.worst_violation <= LIMIT_TOLERANCE,
        "{id}: limit violation {}",
        r.worst_violation
    );
    assert!(
        r.p99_iterations() <= p99_iterations,
        "{id}: p99 {} iterations (max {})",
        r.p99_iterations(),
        r.max_iterations()
    );
}

// Measured on this suite (seeds above): warm start, max iterations 5 (UA-Quad), 12 (UA-Hexa),
// 6 (FA-Hexa), 12 (Omni-Hexa), p99 4–7; from rest, success 100 % (UA-Quad, FA-Hexa,
// Omni-Hexa) and 99.2 % (UA-Hexa), p99 iterations 28, 34, 12, 31. The bounds below add a
// margin for platform-dependent round-off.

#[test]
fn ua_quad_recovers_every_reachable_target_from_a_warm_start() {
    assert_warm_recovery("ua-quad", 15);
}

#[test]
fn ua_hexa_recovers_every_reachable_target_from_a_warm_start() {
    assert_warm_recovery("ua-hexa", 20);
}

#[test]
fn fa_hexa_recovers_every_reachable_target_from_a_warm_start() {
    assert_warm_recovery("fa-hexa", 15);
}

#[test]
fn omni_hexa_recovers_every_reachable_target_from_a_warm_start() {
    assert_warm_recovery("omni-hexa", 20);
}

#[test]
fn ua_quad_recovers_reachable_targets_from_rest() {
    assert_rest_recovery("ua-quad", 0.99, 45);
}

#[test]
fn ua_hexa_recovers_most_reachable_targets_from_rest() {
    // 0.8 % of the random targets are not recovered from rest: the solver settles in a local
    // minimum where an arm joint rests on its limit and the remaining orientation error
    // (0.1–0.5 rad) cannot be removed without leaving it (ClosestPose), or crawls near the
    // gimbal configuration pitch = ±π/2, where base yaw and wrist roll align (IterationLimit).
    // Both are properties of the problem (the reference's weighted sum has the same minima).
    assert_rest_recovery("ua-hexa", 0.98, 50);
}

#[test]
fn fa_hexa_recovers_reachable_targets_from_rest() {
    assert_rest_recovery("fa-hexa", 0.99, 25);
}

#[test]
fn omni_hexa_recovers_reachable_targets_from_rest() {
    assert_rest_recovery("omni-hexa", 0.99, 50);
}

#[test]
fn chain_matches_the_platform_kinematics() {
    let mut rng = XorShift(0xC4A1);
    for id in ["ua-quad", "ua-hexa", "fa-hexa", "omni-hexa", "ee-only"] {
        let v = vehicle(id);
        let ik = ik_with(&v, IkConfig::default());
        let held = v.initial_configuration();
        let arm_dofs = v.arm_dofs();
        let chain = Chain::new(&v, &held, &arm_dofs);
        let mut poses = chain.poses_buffer();
        for _ in 0..20 {
            let (base, q) = random_state(&v, &mut rng);
            let (dp, dr) = pose_errors(
                &ik.world_from_ee(&base, &q),
                &platform_world_from_ee(&v, &base, &q),
            );
            assert!(
                dp < KINEMATICS_AGREEMENT && dr < KINEMATICS_AGREEMENT,
                "{id}"
            );
            let arm: Vec<f64> = arm_dofs.iter().map(|&d| q[d]).collect();
            chain.evaluate(&arm, &mut poses);
            let jacobian = v.model.jacobian(&q, v.ee_link, &Vector3::zeros());
            let p = poses.base_from_ee.translation.vector;
            for (k, joint) in chain.joints.iter().enumerate() {
                let (a, o) = (poses.axes[k], poses.origins[k]);
                let (linear, angular) = match joint.motion {
                    Motion::Rotation => (a.cross(&(p - o)), a),
                    Motion::Translation => (a, Vector3::zeros()),
                };
                let column = jacobian.column(arm_dofs[joint.arm_index]);
                let err = (column.fixed_rows::<3>(0) - linear).norm()
                    + (column.fixed_rows::<3>(3) - angular).norm();
                assert!(err < KINEMATICS_AGREEMENT, "{id} joint {k}: {err}");
            }
        }
    }
}

#[test]
fn analytic_jacobians_match_finite_differences() {
    // Central-difference step and the agreement expected from it (truncation ~ step²).
    const STEP: f64 = 1e-6;
    const FD_TOLERANCE: f64 = 1e-6;
    let mut rng = XorShift(0xFD);
    for id in ["ua-quad", "ua-hexa", "fa-hexa", "omni-hexa"] {
        let v = vehicle(id);
        let ik = ik_for(&v);
        let (base, q) = random_state(&v, &mut rng);
        let (target_base, target_q) = random_state(&v, &mut rng);
        let target = platform_world_from_ee(&v, &target_base, &target_q);
        let (anchor_base, anchor_q) = random_state(&v, &mut rng);
        for (task_cost_gradient, regularisation_gradient, numeric) in
            ik.gradients_at(&base, &q, &anchor_base, &anchor_q, &target, STEP)
        {
            // Cost = |r|², so ∂C/∂x = 2Jᵀr.
            assert!(
                (2.0 * task_cost_gradient - numeric.0).abs()
                    < FD_TOLERANCE * (1.0 + numeric.0.abs()),
                "{id}: task {task_cost_gradient} vs {}",
                numeric.0
            );
            assert!(
                (2.0 * regularisation_gradient - numeric.1).abs()
                    < FD_TOLERANCE * (1.0 + numeric.1.abs()),
                "{id}: regularisation {regularisation_gradient} vs {}",
                numeric.1
            );
        }
    }
}

#[test]
fn smoke_a_target_at_the_current_pose_needs_no_motion() {
    for id in ["ua-quad", "ua-hexa", "fa-hexa", "omni-hexa"] {
        let v = vehicle(id);
        let mut ik = ik_for(&v);
        let rest = ik.rest_configuration();
        ik.reset(&spawn(), &rest).unwrap_or_else(|e| panic!("{e}"));
        let target = platform_world_from_ee(&v, &spawn(), &rest);
        let s = ik.solve(&target, &BaseLimits::above_ground());
        assert!(s.status.converged, "{id}: {:?}", s.status);
        assert_eq!(s.status.reason, IkReason::PoseReached);
        assert_eq!(s.status.iterations, 1, "{id}");
        for (a, b) in s.configuration.iter().zip(&rest) {
            assert!(
                (a - b).abs() < KINEMATICS_AGREEMENT,
                "{id}: {:?}",
                s.configuration
            );
        }
        let (dp, dr) = pose_errors(&s.world_from_base, &spawn());
        assert!(
            dp < KINEMATICS_AGREEMENT && dr < KINEMATICS_AGREEMENT,
            "{id}"
        );
    }
}

#[test]
fn flight_loop_follows_a_moving_target_in_a_few_iterations() {
    // A 10 s lap at 120 Hz: base on a 0.25 m circle with a yaw wobble, arm joints swinging
    // ±0.3 rad, the target being the FK of that motion (reachable by construction).
    const MAX_FLIGHT_ITERATIONS: u32 = 5;
    const FLIGHT_POSITION_M: f64 = 1e-9;
    const FLIGHT_ORIENTATION_RAD: f64 = 1e-5;
    for id in ["ua-quad", "ua-hexa", "fa-hexa", "omni-hexa"] {
        let v = vehicle(id);
        let mut ik = ik_for(&v);
        let rest = ik.rest_configuration();
        let arm = v.arm_dofs();
        let omega = 2.0 * PI / 10.0;
        let yaw_allowed = !ik.config().fix_base_orientation[2];
        let state = |t: f64| {
            let yaw = if yaw_allowed {
                0.5 * (omega * t).sin()
            } else {
                0.0
            };
            let base = pose(
                Vector3::new(0.25 * (omega * t).cos(), 0.25 * (omega * t).sin(), 1.2),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            );
            let mut q = rest.clone();
            for (k, &d) in arm.iter().enumerate() {
                let (lo, hi) = sampling_range(&v, d);
                let mid = (0.5 * (lo + hi)).clamp(lo + 0.35, hi - 0.35);
                q[d] = mid + 0.3 * (omega * t + k as f64).sin();
            }
            (base, q)
        };
        let (base0, q0) = state(0.0);
        ik.reset(&base0, &q0).unwrap_or_else(|e| panic!("{e}"));
        for tick in 0..1200 {
            let (base, q) = state(f64::from(tick) / RATE_HZ);
            let target = platform_world_from_ee(&v, &base, &q);
            let s = ik.solve(&target, &BaseLimits::above_ground());
            let (dp, dr) = solution_errors(&v, &s, &target);
            assert!(s.status.converged, "{id} tick {tick}: {:?}", s.status);
            assert!(
                s.status.iterations <= MAX_FLIGHT_ITERATIONS,
                "{id} tick {tick}: {:?}",
                s.status
            );
            assert!(
                dp < FLIGHT_POSITION_M && dr < FLIGHT_ORIENTATION_RAD,
                "{id} tick {tick}: {dp} {dr}"
            );
        }
    }
}

#[test]
fn reachable_pose_is_met_exactly_however_heavy_the_regularisation() {
    // Task priority: the smoothness and rest terms choose among exact solutions; they never
    // trade pose accuracy (the reference's weighted sum would leave a bias growing with them).
    const EXACT_POSITION_M: f64 = 1e-9;
    const EXACT_ORIENTATION_RAD: f64 = 1e-8;
    let v = vehicle("ua-hexa");
    let mut config = IkConfig::ua_hexa();
    config.weights.smoothness_base_position = 100.0;
    config.weights.smoothness_joints = 10.0;
    config.weights.rest_arm = 10.0;
    let mut ik = ik_with(&v, config);
    let mut rng = XorShift(0x7A5C);
    for _ in 0..50 {
        let (base, q) = random_state(&v, &mut rng);
        ik.reset(&base, &q).unwrap_or_else(|e| panic!("{e}"));
        let moved = pose(
            base.translation.vector + Vector3::new(0.3, -0.2, 0.1),
            base.rotation,
        );
        let target = platform_world_from_ee(&v, &moved, &q);
        let s = ik.solve(&target, &BaseLimits::above_ground());
        let (dp, dr) = solution_errors(&v, &s, &target);
        assert!(
            dp < EXACT_POSITION_M && dr < EXACT_ORIENTATION_RAD,
            "{dp} {dr} {:?}",
            s.status
        );
    }
}

#[test]
fn unreachable_target_beyond_a_wall_gives_the_closest_pose_within_the_limits() {
    let v = vehicle("fa-hexa");
    let mut ik = ik_for(&v);
    let w = ik.config().weights;
    // Wall face at x = 2 m: the base stays at x ≤ 2 − 0.85 = 1.15 m. Target 10 m beyond.
    let limits = BaseLimits::in_front_of_face_x(2.0, ik.config().safety_margin_m);
    let max_x = 2.0 - 0.85;
    let target = pose(
        Vector3::new(max_x + 10.0, 0.0, 1.0),
        UnitQuaternion::identity(),
    );
    let s = ik.solve(&target, &limits);
    assert!(all_finite(&s));
    assert!(!s.status.converged, "{:?}", s.status);
    assert!(
        matches!(
            s.status.reason,
            IkReason::ClosestPose | IkReason::IterationLimit
        ),
        "{:?}",
        s.status
    );
    // The arm reaches out toward the target: the EE is ahead of the base.
    let ee = platform_world_from_ee(&v, &s.world_from_base, &s.configuration);
    let base_x = s.world_from_base.translation.x;
    assert!(ee.translation.x > base_x + 0.5, "EE {ee} base x {base_x}");
    // The soft limit gives by at most (w_pos/w_limit)² times the remaining distance (the
    // stationary point of w_pos²·e_x + w_limit²·violation = 0).
    let hinge_tolerance =
        (w.pose_position / w.base_position_limit).powi(2) * s.status.position_error_m * 1.01;
    assert!(
        base_x <= max_x + hinge_tolerance,
        "base x {base_x} past {max_x} + {hinge_tolerance}"
    );
    assert!(s.world_from_base.translation.z >= -hinge_tolerance);
}

#[test]
fn base_stays_behind_the_wall_when_the_arm_can_reach_the_target() {
    // A target the arm reaches only with the base pressed against its limit: the pose is met
    // and the base holds the limit (within the solver's limit tolerance).
    let v = vehicle("fa-hexa");
    let mut ik = ik_for(&v);
    let limits = BaseLimits::in_front_of_face_x(2.0, ik.config().safety_margin_m);
    let max_x = 2.0 - 0.85;
    // The most forward-reaching arm configuration of a deterministic sample.
    let mut rng = XorShift(0x0A11);
    let rest = ik.rest_configuration();
    let mut best = (f64::NEG_INFINITY, rest.clone());
    for _ in 0..2000 {
        let mut q = rest.clone();
        for d in v.arm_dofs() {
            let (lo, hi) = sampling_range(&v, d);
            q[d] = rng.uniform(lo, hi);
        }
        let reach = v.base_from_ee(&q).translation.x;
        if reach > best.0 {
            best = (reach, q);
        }
    }
    let (reach, q) = best;
    assert!(reach > 0.5, "forward reach {reach}");
    // Base 1 cm inside the limit in the configuration that defines the target.
    let base = pose(
        Vector3::new(max_x - 0.01, 0.3, 1.5),
        UnitQuaternion::identity(),
    );
    let target = platform_world_from_ee(&v, &base, &q);
    let s = ik.solve(&target, &limits);
    assert!(s.status.converged, "{:?}", s.status);
    let (dp, dr) = solution_errors(&v, &s, &target);
    assert!(dp < RECOVERED_POSITION_M && dr < RECOVERED_ORIENTATION_RAD);
    assert!(s.world_from_base.translation.x <= max_x + LIMIT_TOLERANCE);
    assert!(limits.violation_m(&s.world_from_base.translation.vector) <= LIMIT_TOLERANCE);
}

#[test]
fn non_finite_target_returns_the_previous_solution_unchanged() {
    let v = vehicle("omni-hexa");
    let mut ik = ik_for(&v);
    let mut rng = XorShift(0x0BAD);
    let (base, q) = random_state(&v, &mut rng);
    let target = platform_world_from_ee(&v, &base, &q);
    let good = ik.solve(&target, &BaseLimits::above_ground());
    let nan_position = pose(Vector3::new(f64::NAN, 0.0, 1.0), UnitQuaternion::identity());
    for bad in [
        nan_position,
        pose(Vector3::new(f64::INFINITY, 0.0, 1.0), target.rotation),
    ] {
        let s = ik.solve(&bad, &BaseLimits::above_ground());
        assert_eq!(s.status.reason, IkReason::NonFiniteTarget);
        assert!(!s.status.converged);
        assert!(all_finite(&s));
        assert_eq!(s.configuration, good.configuration);
        assert_eq!(s.world_from_base, good.world_from_base);
    }
    let nan_limits = BaseLimits::above_ground().with_max(AXIS_X, f64::NAN);
    let s = ik.solve(&target, &nan_limits);
    assert_eq!(s.status.reason, IkReason::NonFiniteLimits);
    assert_eq!(s.configuration, good.configuration);
    // And the IK carries on.
    let again = ik.solve(&target, &BaseLimits::above_ground());
    assert!(again.status.converged, "{:?}", again.status);
}

#[test]
fn fa_hexa_base_rotation_stays_exactly_at_the_warm_start() {
    let v = vehicle("fa-hexa");
    let mut ik = ik_for(&v);
    let tilted = UnitQuaternion::from_euler_angles(0.01, -0.02, 0.3);
    ik.reset(
        &pose(Vector3::new(0.0, 0.0, 1.0), tilted),
        &ik.rest_configuration(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mut rng = XorShift(0xFA);
    for _ in 0..50 {
        let (base, q) = random_state(&v, &mut rng);
        let target = platform_world_from_ee(&v, &pose(base.translation.vector, tilted), &q);
        let s = ik.solve(&target, &BaseLimits::above_ground());
        assert_eq!(s.world_from_base.rotation, tilted);
    }
}

#[test]
fn ua_base_stays_level_and_turns_about_world_z() {
    // Round-off allowed on the roll and pitch components of the base quaternion.
    const LEVEL: f64 = 1e-12;
    for id in ["ua-hexa", "ua-quad"] {
        let v = vehicle(id);
        let mut ik = ik_for(&v);
        let mut rng = XorShift(0x0A);
        let mut yawed = false;
        for _ in 0..50 {
            let (base, q) = random_state(&v, &mut rng);
            let target = platform_world_from_ee(&v, &base, &q);
            let s = ik.solve(&target, &BaseLimits::above_ground());
            let r = s.world_from_base.rotation;
            assert!(r.i.abs() < LEVEL && r.j.abs() < LEVEL, "{id}: {r:?}");
            yawed |= r.angle() > 0.1;
        }
        assert!(yawed, "{id}: the base never turned");
    }
}

#[test]
fn locked_axes_are_removed_from_the_variables() {
    let count = |id: &str| ik_for(&vehicle(id)).variable_count();
    assert_eq!(count("fa-hexa"), 3 + 4);
    assert_eq!(count("ua-hexa"), 3 + 1 + 4);
    assert_eq!(count("ua-quad"), 3 + 1 + 4);
    assert_eq!(count("omni-hexa"), 3 + 3 + 3);
}

#[test]
fn non_arm_joints_are_returned_at_their_held_values() {
    for id in ["fa-hexa", "omni-hexa"] {
        let v = vehicle(id);
        let mut ik = ik_for(&v);
        let mut rng = XorShift(0x11);
        let (base, q) = random_state(&v, &mut rng);
        let target = platform_world_from_ee(&v, &base, &q);
        // A seed with non-arm joints away from their held values: they are ignored.
        let mut seed = q.clone();
        for (i, x) in seed.iter_mut().enumerate() {
            if !v.arm_dofs().contains(&i) {
                *x += 0.1;
            }
        }
        ik.reset(&base, &seed).unwrap_or_else(|e| panic!("{e}"));
        let s = ik.solve(&target, &BaseLimits::above_ground());
        let held = v.initial_configuration();
        for (i, (&got, &want)) in s.configuration.iter().zip(&held).enumerate() {
            if !v.arm_dofs().contains(&i) {
                assert_eq!(got.to_bits(), want.to_bits(), "{id}: joint {i}");
            }
        }
        let arm: Vec<f64> = v.arm_dofs().iter().map(|&d| s.configuration[d]).collect();
        assert_eq!(arm, s.arm_joints);
    }
}

#[test]
fn omni_rest_posture_is_the_vehicle_initial_configuration() {
    let v = vehicle("omni-hexa");
    let ik = ik_for(&v);
    let rest = ik.rest_configuration();
    let arm: Vec<f64> = v.arm_dofs().iter().map(|&d| rest[d]).collect();
    let expected = [-PI / 4.0, 3.0 * PI / 4.0, 0.0];
    for (a, e) in arm.iter().zip(expected) {
        assert!((a - e).abs() < 1e-9, "{arm:?}");
    }
    let fa = ik_for(&vehicle("fa-hexa"));
    let fa_v = vehicle("fa-hexa");
    assert!(
        fa_v.arm_dofs()
            .iter()
            .all(|&d| fa.rest_configuration()[d].abs() < f64::EPSILON)
    );
}

/// A controller taking over mid-motion (the MPC's IK-PID fallback) holds the arm posture it
/// was handed: with the rest term moved to that posture, a held target at its EE pose is the
/// cost's exact minimum (every residual zero) and the solves stay there; with the configured
/// rest (zero) the redundant arm drifts toward it and the base moves to keep the EE, which
/// in flight swings the arm against the motion it was making.
#[test]
fn the_rest_term_can_hold_a_handed_over_posture_blend_it_and_go_back_to_the_configured_one() {
    let v = vehicle("fa-hexa");
    let mut ik = ik_for(&v);
    let mut handed = ik.rest_configuration();
    // An arm swung forward and down, as the MPC flies Toss Ball's release (rad).
    for (&d, q) in v.arm_dofs().iter().zip([0.9, 0.4, 0.3, PI / 2.0]) {
        handed[d] = q;
    }
    let target = platform_world_from_ee(&v, &spawn(), &handed);
    let drift = |ik: &mut WholeBodyIk| {
        ik.reset(&spawn(), &handed)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut arm = 0.0_f64;
        let mut base = 0.0_f64;
        for _ in 0..60 {
            let s = ik.solve(&target, &BaseLimits::above_ground());
            let (dp, _) = pose_errors(
                &platform_world_from_ee(&v, &s.world_from_base, &s.configuration),
                &target,
            );
            assert!(dp < RECOVERED_POSITION_M, "EE off its target by {dp} m");
            for &d in &v.arm_dofs() {
                arm = arm.max((s.configuration[d] - handed[d]).abs());
            }
            base = base
                .max((s.world_from_base.translation.vector - spawn().translation.vector).norm());
        }
        (arm, base)
    };
    let (arm, base) = drift(&mut ik);
    assert!(
        arm > 0.05 && base > 0.01,
        "configured rest: arm {arm} rad, base {base} m"
    );
    ik.blend_rest_configuration(&handed, 1.0)
        .unwrap_or_else(|e| panic!("{e}"));
    let (arm, base) = drift(&mut ik);
    assert!(
        arm < KINEMATICS_AGREEMENT && base < KINEMATICS_AGREEMENT,
        "held: arm {arm}, base {base}"
    );
    ik.restore_rest_configuration();
    assert_eq!(ik.rest_configuration(), ik_for(&v).rest_configuration());
    let (arm, _) = drift(&mut ik);
    assert!(arm > 0.05, "configured rest again: arm {arm} rad");
    // Half way: the configured rest is zero, so the rest posture is half the handed one.
    ik.blend_rest_configuration(&handed, 0.5)
        .unwrap_or_else(|e| panic!("{e}"));
    for &d in &v.arm_dofs() {
        assert_eq!(ik.rest_configuration()[d], 0.5 * handed[d]);
    }
    assert!(matches!(
        ik.blend_rest_configuration(&handed, 1.5),
        Err(IkError::RestShare(_))
    ));
    assert!(matches!(
        ik.blend_rest_configuration(&handed[1..], 1.0),
        Err(IkError::ConfigurationLength { .. })
    ));
    let mut nan = handed.clone();
    nan[v.arm_dofs()[0]] = f64::NAN;
    assert!(matches!(
        ik.blend_rest_configuration(&nan, 1.0),
        Err(IkError::NonFiniteSeed(_))
    ));
}

#[test]
fn identical_runs_are_bit_identical() {
    let run = || {
        let v = vehicle("omni-hexa");
        let mut ik = ik_for(&v);
        let mut rng = XorShift(0xD7);
        (0..30)
            .flat_map(|_| {
                let (base, q) = random_state(&v, &mut rng);
                let s = ik.solve(
                    &platform_world_from_ee(&v, &base, &q),
                    &BaseLimits::above_ground(),
                );
                let mut bits: Vec<u64> = s.configuration.iter().map(|x| x.to_bits()).collect();
                bits.extend(
                    s.world_from_base
                        .translation
                        .vector
                        .iter()
                        .map(|x| x.to_bits()),
                );
                bits.extend(
                    s.world_from_base
                        .rotation
                        .coords
                        .iter()
                        .map(|x| x.to_bits()),
                );
                bits
            })
            .collect::<Vec<u64>>()
    };
    assert_eq!(run(), run());
}

#[test]
fn reset_rejects_a_wrong_length_or_non_finite_seed() {
    let v = vehicle("fa-hexa");
    let mut ik = ik_for(&v);
    let q = ik.rest_configuration();
    assert!(matches!(
        ik.reset(&spawn(), &q[1..]),
        Err(IkError::ConfigurationLength { .. })
    ));
    let mut nan = q.clone();
    nan[v.arm_dofs()[0]] = f64::NAN;
    assert!(matches!(
        ik.reset(&spawn(), &nan),
        Err(IkError::NonFiniteSeed(_))
    ));
    assert!(ik.reset(&spawn(), &q).is_ok());
}

#[test]
fn config_defaults_and_presets_follow_the_reference() {
    let d = IkConfig::default();
    let w = d.weights;
    assert_eq!(
        [
            w.pose_position,
            w.pose_orientation,
            w.joint_limit,
            w.smoothness_joints
        ],
        [5.0, 1.0, 100.0, 0.1]
    );
    assert_eq!(
        [
            w.smoothness_base_position,
            w.smoothness_base_orientation,
            w.rest_arm,
            w.base_position_limit
        ],
        [1.0, 0.1, 0.1, 100.0]
    );
    assert_eq!(d.fix_base_position, [false; 3]);
    assert_eq!(d.fix_base_orientation, [true, true, false]);
    let s = d.solver;
    assert_eq!(s.max_iterations, 100);
    assert_eq!(
        [
            s.lambda_initial,
            s.lambda_factor,
            s.lambda_min,
            s.lambda_max
        ],
        [5e-4, 2.0, 1e-5, 1e10]
    );
    assert_eq!(
        [
            s.cost_tolerance,
            s.gradient_tolerance,
            s.parameter_tolerance
        ],
        [1e-5, 1e-4, 1e-6]
    );
    assert!(d.validate().is_ok());

    let fa = IkConfig::fa_hexa();
    assert_eq!(fa.fix_base_orientation, [true, true, true]);
    assert_eq!(
        (
            fa.safety_margin_m,
            fa.weights.smoothness_base_position,
            fa.weights.smoothness_base_orientation
        ),
        (0.85, 1.0, 0.1)
    );
    let ua = IkConfig::ua_hexa();
    assert_eq!(ua.fix_base_orientation, [true, true, false]);
    assert_eq!(
        (ua.safety_margin_m, ua.weights.smoothness_base_position),
        (0.8, 8.0)
    );
    let quad = IkConfig::ua_quad();
    assert_eq!(quad.fix_base_orientation, [true, true, false]);
    assert_eq!(
        (quad.safety_margin_m, quad.weights.smoothness_base_position),
        (0.15, 1.0)
    );
    let omni = IkConfig::omni_hexa();
    assert_eq!(omni.fix_base_orientation, [false; 3]);
    assert_eq!(
        (
            omni.safety_margin_m,
            omni.weights.smoothness_base_position,
            omni.weights.smoothness_base_orientation
        ),
        (0.3, 1.0, 1.0)
    );
    assert_eq!(omni.rest_posture, RestPosture::VehicleInitial);
    for c in [fa, ua, quad, omni] {
        assert_eq!(c.initial_base_position_m, [0.0, 0.0, 1.0]);
        assert!(c.validate().is_ok());
    }
    assert_eq!(IkConfig::preset("fa-hexa"), Some(IkConfig::fa_hexa()));
    assert_eq!(IkConfig::preset("omni-hexa"), Some(IkConfig::omni_hexa()));
    assert_eq!(IkConfig::preset("ee-only"), None);
    assert_eq!(IkConfig::preset("nope"), None);
}

#[test]
fn config_loads_from_toml_and_rejects_unknown_keys() {
    let text = r#"
        fix_base_orientation = [true, true, true]
        safety_margin_m = 0.85
        rest_posture = "vehicle_initial"
        [weights]
        pose_position = 15.0
        [solver]
        max_iterations = 20
    "#;
    let c = IkConfig::from_toml_str(text).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.weights.pose_position, 15.0);
    assert_eq!(c.weights.pose_orientation, 1.0);
    assert_eq!(c.solver.max_iterations, 20);
    assert_eq!(c.rest_posture, RestPosture::VehicleInitial);
    for bad in [
        "unknown = 1",
        "[weights]\nposition = 5.0",
        "[solver]\nlambda = 1.0",
        "fix_base_position = [true]",
    ] {
        assert!(
            matches!(IkConfig::from_toml_str(bad), Err(IkConfigError::Toml(_))),
            "{bad}"
        );
    }
    assert!(matches!(
        IkConfig::from_toml_str("[weights]\npose_position = -1.0"),
        Err(IkConfigError::Invalid {
            field: "weights.pose_position",
            ..
        })
    ));
}

#[test]
fn validate_rejects_out_of_range_settings() {
    type Breaker = fn(&mut IkConfig);
    let cases: [(&str, Breaker); 8] = [
        ("weights.pose_orientation", |c| {
            c.weights.pose_orientation = 0.0
        }),
        ("weights.rest_arm", |c| c.weights.rest_arm = f64::NAN),
        ("solver.max_iterations", |c| c.solver.max_iterations = 0),
        ("solver.lambda_factor", |c| c.solver.lambda_factor = 1.0),
        ("solver.lambda_initial", |c| c.solver.lambda_initial = 1e-9),
        ("solver.step_quality_min", |c| {
            c.solver.step_quality_min = 1.0
        }),
        ("solver.nullspace_singular_value_ratio", |c| {
            c.solver.nullspace_singular_value_ratio = 0.0;
        }),
        ("safety_margin_m", |c| c.safety_margin_m = -0.1),
    ];
    for (field, break_it) in cases {
        let mut c = IkConfig::default();
        break_it(&mut c);
        match c.validate() {
            Err(IkConfigError::Invalid { field: f, .. }) => assert_eq!(f, field),
            other => panic!("{field}: {other:?}"),
        }
        assert!(WholeBodyIk::new(&vehicle("fa-hexa"), c).is_err());
    }
}

#[test]
fn base_limit_helpers_build_the_task_bounds() {
    let wall = BaseLimits::in_front_of_face_x(2.0, 0.85);
    assert_eq!(wall.bounds(AXIS_X), (f64::NEG_INFINITY, 2.0 - 0.85));
    assert_eq!(wall.bounds(AXIS_Y), (f64::NEG_INFINITY, f64::INFINITY));
    assert_eq!(wall.bounds(AXIS_Z), (0.0, f64::INFINITY));
    assert_eq!(
        BaseLimits::NONE.violation_m(&Vector3::new(1e9, -1e9, -1e9)),
        0.0
    );
    let past = Vector3::new(2.0 - 0.85 + 0.25, 0.0, -0.1);
    assert!((wall.violation_m(&past) - 0.25).abs() < KINEMATICS_AGREEMENT);
    assert!(wall.is_finite());
    assert!(!wall.with_min(AXIS_Y, f64::INFINITY).is_finite());
}

#[test]
fn ee_only_vehicle_solves_with_the_base_alone() {
    // No arm: the base (position and yaw under the default locks) is the end effector's
    // carrier; a target with a yawed, level orientation is met exactly.
    let v = vehicle("ee-only");
    let mut ik = ik_with(&v, IkConfig::default());
    assert_eq!(ik.variable_count(), 4);
    let base = pose(
        Vector3::new(0.4, -0.2, 1.3),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7),
    );
    let target = platform_world_from_ee(&v, &base, &v.initial_configuration());
    let s = ik.solve(&target, &BaseLimits::above_ground());
    assert!(s.status.converged, "{:?}", s.status);
    let (dp, dr) = solution_errors(&v, &s, &target);
    assert!(dp < RECOVERED_POSITION_M && dr < RECOVERED_ORIENTATION_RAD);
}

#[test]
fn rate_limited_arm_joints_step_at_their_drives_speed_and_the_base_takes_the_rest() {
    // The FA-Hexa's arm drives move at most 5 rad/s (AMBENCH_SPEC §1.2 velocity_limit_sim):
    // at 120 Hz an arm joint moves at most 5/120 = 0.041667 rad per solve. Its three pitch
    // joints (axes +y, −y, +y) set the EE pitch q1 − q2 + q3 while the base rotation is locked,
    // so a 0.45 rad wrist flick (the toss's q_load → q_release is 60°) needs
    // ⌈0.45 / (3 · 0.041667)⌉ = ⌈3.6⌉ = 4 solves: after solve n < 4 the pitch error is
    // 0.45 − 0.125 n, every pitch joint at its step, while the base (free in position) keeps
    // the EE position met; the 4th solve meets the pose. Without the bound one solve does.
    const STEP_RAD: f64 = 5.0 / 120.0;
    // The step is a hinge at the task level (weight 100 against the orientation's 1): it
    // yields by about e · (1/100)² = 3e-5 rad at a 0.3 rad pitch error.
    const HINGE_SLACK_RAD: f64 = 1e-4;
    let v = vehicle("fa-hexa");
    let arm = v.arm_dofs();
    let mut start = v.initial_configuration();
    let mut end = start.clone();
    for (k, (q0, dq)) in [(0.6, -0.15), (0.3, 0.15), (0.2, -0.15), (0.0, 0.0)]
        .into_iter()
        .enumerate()
    {
        start[arm[k]] = q0;
        end[arm[k]] = q0 + dq;
    }
    let target = platform_world_from_ee(&v, &spawn(), &end);

    let mut free = ik_for(&v);
    free.reset(&spawn(), &start)
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(free.joint_steps().iter().all(|s| s.is_infinite()));
    let s = free.solve(&target, &BaseLimits::above_ground());
    assert!(s.status.converged, "{:?}", s.status);
    let jump = (0..3)
        .map(|k| (s.arm_joints[k] - start[arm[k]]).abs())
        .fold(0.0, f64::max);
    assert!(
        jump > 3.0 * STEP_RAD,
        "unbounded: largest joint step {jump}"
    );

    let mut ik = ik_for(&v);
    ik.limit_joint_rates(&v, 1.0 / RATE_HZ);
    for step in ik.joint_steps() {
        assert!((step - STEP_RAD).abs() < KINEMATICS_AGREEMENT, "{step}");
    }
    ik.reset(&spawn(), &start).unwrap_or_else(|e| panic!("{e}"));
    let mut previous: Vec<f64> = arm.iter().map(|&d| start[d]).collect();
    for n in 1..=4 {
        let s = ik.solve(&target, &BaseLimits::above_ground());
        for (k, (q, q_prev)) in s.arm_joints.iter().zip(&previous).enumerate() {
            assert!(
                (q - q_prev).abs() <= STEP_RAD + HINGE_SLACK_RAD,
                "solve {n} joint {k}: {q_prev} -> {q}"
            );
        }
        let (dp, dr) = solution_errors(&v, &s, &target);
        assert!(dp < RECOVERED_POSITION_M, "solve {n}: position error {dp}");
        if n < 4 {
            let expected = 0.45 - 3.0 * STEP_RAD * f64::from(n);
            assert!(!s.status.converged, "solve {n}: {:?}", s.status);
            assert!(
                (dr - expected).abs() < 3.0 * HINGE_SLACK_RAD,
                "solve {n}: pitch error {dr}, expected {expected}"
            );
        } else {
            assert!(s.status.converged, "solve {n}: {:?}", s.status);
            assert!(dr < RECOVERED_ORIENTATION_RAD, "solve {n}: {dr}");
        }
        previous.clone_from(&s.arm_joints);
    }
}

/// Roll–pitch tilt of a base rotation, rad (√(roll² + pitch²), as the benchmark's tilt use).
fn tilt_of(rotation: &UnitQuaternion<f64>) -> f64 {
    let (roll, pitch, _) = rotation.euler_angles();
    roll.hypot(pitch)
}

#[test]
fn the_omni_hexa_tilts_its_base_to_reach_past_its_wall_bound_and_flies_level_within_reach() {
    // The paper reads the Omni-Hexa's tilt use as its IK exploiting tilted hover near the task
    // surface. Its preset leaves the base orientation free: a target the level base reaches
    // from inside its wall bound is met level; one 0.15 m past that is reached further by
    // pitching the base toward the wall, its position held on the bound.
    let v = vehicle("omni-hexa");
    let mut ik = ik_for(&v);
    let rest = ik.rest_configuration();
    let max_x = 1.0;
    let limits = BaseLimits::above_ground().with_max(AXIS_X, max_x);
    let at_bound = pose(Vector3::new(max_x, 0.0, 1.0), UnitQuaternion::identity());
    let ee_at_bound = platform_world_from_ee(&v, &at_bound, &rest);
    // 25 s of a 120 Hz flight loop's solves: the base smoothness spreads a move over many,
    // and the rest posture pulls the arm home ~1 % per solve.
    let settle = |ik: &mut WholeBodyIk, target: &Isometry3<f64>| {
        let mut s = ik.solve(target, &limits);
        for _ in 0..3000 {
            s = ik.solve(target, &limits);
        }
        s
    };
    ik.reset(&spawn(), &rest).unwrap_or_else(|e| panic!("{e}"));
    let within = pose(
        ee_at_bound.translation.vector - Vector3::new(0.1, 0.0, 0.0),
        ee_at_bound.rotation,
    );
    let level = settle(&mut ik, &within);
    assert!(level.status.converged, "{:?}", level.status);
    let level_tilt = tilt_of(&level.world_from_base.rotation);
    assert!(level_tilt < 1e-3, "within reach: tilt {level_tilt} rad");
    let beyond = pose(
        ee_at_bound.translation.vector + Vector3::new(0.15, 0.0, 0.0),
        ee_at_bound.rotation,
    );
    let tilted = settle(&mut ik, &beyond);
    // Met exactly, with the base on its bound and pitched (measured: 0.749 rad; the twin's
    // Omni-Hexa on Open Door, its base on the door's bound, pitches 0.9 rad).
    assert!(tilted.status.converged, "{:?}", tilted.status);
    let (dp, dr) = solution_errors(&v, &tilted, &beyond);
    assert!(
        dp < RECOVERED_POSITION_M && dr < RECOVERED_ORIENTATION_RAD,
        "{dp} m, {dr} rad"
    );
    let x = tilted.world_from_base.translation.x;
    assert!((x - max_x).abs() <= LIMIT_TOLERANCE, "base x {x}");
    let tilt = tilt_of(&tilted.world_from_base.rotation);
    assert!(tilt > 0.5, "beyond reach: tilt {tilt} rad");
}
