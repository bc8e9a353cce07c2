//! The contract of the allocation crate, through its public API only:
//! - a wrench the rotors can produce round-trips allocate → forward map, for every method and
//!   vehicle class (property tests on the hand-built AM-Bench layouts);
//! - for a wrench they cannot produce, the constrained method stays within bounds and its
//!   weighted wrench error (the objective it minimises) is never above clip-after-pseudo-inverse;
//! - axis priorities in saturation (scenarios);
//! - the allocation → rotor actuator cases of the reference's
//!   `robots/test_rotor_actuator_pipeline.py` (AMBENCH_SPEC §8), with its numbers.

#![allow(
    clippy::unwrap_used,
    clippy::float_cmp,
    reason = "contract tests: a failed set-up fails loudly; exact values are asserted on purpose"
)]

mod fixtures;

use allocation::{
    Allocation, AllocationMethod, AllocationStatus, Allocator, ConstrainedSettings, RotorActuator,
    RotorActuatorConfig, RotorSaturation, any_rotor_saturated, effectiveness_matrix,
    reduced_effectiveness_matrix, variable_tilt_effectiveness_matrix, wrench_from_thrusts,
};
use fixtures::{assert_all_close, assert_close};
use nalgebra::{DMatrix, DVector, Vector3, Vector6};
use platform::{Actuation, Rotor, RotorLayout, Spin, Wrench};
use proptest::prelude::*;

/// A producible wrench must come back to this, per component (N or N·m).
const ROUND_TRIP_TOLERANCE: f64 = 1e-9;
/// Relative slack on "constrained error ≤ clip error" for the solver's tolerance.
const OBJECTIVE_RELATIVE_SLACK: f64 = 1e-6;
/// Absolute floor of that comparison (round-off of an exactly achieved wrench).
const OBJECTIVE_ABSOLUTE_SLACK: f64 = 1e-12;
/// How closely a kept axis must be kept in a saturation scenario (N or N·m). Weights are soft
/// priorities: a kept axis bleeds about lever·w_low·e_low/w_high, ≈ 0.02 N·m of roll for the
/// UA-Hexa 67 N short of thrust below; 0.05 is < 0.5 % of any vehicle's roll authority.
const KEPT_AXIS_TOLERANCE: f64 = 5e-2;
/// Cases per property: enough to find a bad corner, few enough to keep the suite fast.
const PROPERTY_CASES: u32 = 96;

fn constrained() -> AllocationMethod {
    AllocationMethod::Constrained(ConstrainedSettings::default())
}

fn allocator(layout: &RotorLayout, actuation: Actuation, method: AllocationMethod) -> Allocator {
    Allocator::new(layout, actuation, method).unwrap()
}

fn wrench_of(v: &DVector<f64>) -> Wrench {
    Wrench::from_vector(&Vector6::from_iterator(v.iter().copied()))
}

#[track_caller]
fn assert_round_trip(allocation: &Allocation, requested: &Wrench, what: &str) {
    assert_all_close(
        allocation.achieved.to_vector().iter(),
        requested.to_vector().iter(),
        ROUND_TRIP_TOLERANCE,
        what,
    );
}

#[track_caller]
fn assert_within_bounds(allocation: &Allocation, layout: &RotorLayout) {
    for &t in &allocation.thrusts_n {
        assert!(
            t >= layout.thrust_min_n && t <= layout.thrust_max_n,
            "thrust {t} outside [{}, {}]: {:?}",
            layout.thrust_min_n,
            layout.thrust_max_n,
            allocation.thrusts_n
        );
    }
}

/// The thrusts (fixed rotors) scaled towards the hover point T_mid·1 until the minimum-norm
/// allocation of their wrench lies within bounds: the feasible wrenches the pseudo-inverse can
/// round-trip on a redundant layout. (1 is in the row space of every +z or FA matrix here, so
/// A⁺A(T_mid·1 + λδ) = T_mid·1 + λ·A⁺Aδ.)
fn shrink_into_pseudo_inverse_range(
    matrix: &DMatrix<f64>,
    thrusts: &[f64],
    t_max: f64,
) -> Vec<f64> {
    let mid = 0.5 * t_max;
    let delta = DVector::from_iterator(thrusts.len(), thrusts.iter().map(|t| t - mid));
    let pinv = matrix.clone().pseudo_inverse(1e-12).unwrap();
    let projected = &pinv * (matrix * &delta);
    let largest = projected.amax();
    let lambda = if largest > mid { mid / largest } else { 1.0 };
    delta.iter().map(|d| mid + lambda * d).collect()
}

/// Same for (c, s) pairs of tilting rotors, towards 0 (T_min = 0 for the Omni-Hexa).
fn shrink_tilt_into_pseudo_inverse_range(matrix: &DMatrix<f64>, x: &[f64], t_max: f64) -> Vec<f64> {
    let x = DVector::from_row_slice(x);
    let pinv = matrix.clone().pseudo_inverse(1e-12).unwrap();
    let projected = &pinv * (matrix * &x);
    let largest = projected
        .as_slice()
        .chunks_exact(2)
        .map(|p| p[0].hypot(p[1]))
        .fold(0.0, f64::max);
    let lambda = if largest > t_max {
        t_max / largest
    } else {
        1.0
    };
    x.iter().map(|v| lambda * v).collect()
}

fn fixed_vehicles() -> [(&'static str, RotorLayout, Actuation); 3] {
    [
        ("FA-Hexa", fixtures::fa_hexa(), Actuation::FullyActuated),
        ("UA-Hexa", fixtures::ua_hexa(), Actuation::UnderActuated),
        ("UA-Quad", fixtures::ua_quad(), Actuation::UnderActuated),
    ]
}

/// Thrusts in the box, two thirds of them near a bound: on redundant layouts their minimum-norm
/// allocation then often leaves the box, which is where the constrained method must still be
/// exact.
fn thrusts_in_box(rotors: usize) -> impl Strategy<Value = Vec<f64>> {
    let (lo, hi) = (fixtures::THRUST_MIN_N, fixtures::THRUST_MAX_N);
    let near = 0.1 * (hi - lo);
    prop::collection::vec(prop_oneof![lo..=hi, lo..=lo + near, hi - near..=hi], rotors)
}

fn omni_thrust_vectors() -> impl Strategy<Value = Vec<f64>> {
    let t_max = fixtures::THRUST_MAX_N;
    prop::collection::vec(
        (
            prop_oneof![0.0..=t_max, 0.8 * t_max..=t_max],
            -std::f64::consts::PI..std::f64::consts::PI,
        ),
        6,
    )
    .prop_map(|rotors| {
        rotors
            .into_iter()
            .flat_map(|(t, a)| [t * a.cos(), t * a.sin()])
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(PROPERTY_CASES))]

    #[test]
    fn producible_wrench_round_trips_on_fixed_rotor_vehicles(
        thrusts in thrusts_in_box(6),
    ) {
        for (name, layout, actuation) in fixed_vehicles() {
            let n = layout.len();
            let full = effectiveness_matrix(&layout);
            let commanded = match actuation {
                Actuation::UnderActuated => reduced_effectiveness_matrix(&layout),
                _ => full.clone(),
            };
            // Constrained: any thrusts in the box.
            let t = DVector::from_row_slice(&thrusts[..n]);
            let wrench = wrench_of(&(&full * &t));
            let a = allocator(&layout, actuation, constrained()).allocate(&wrench, &[]).unwrap();
            assert_round_trip(&a, &wrench, &format!("{name} constrained"));
            assert_within_bounds(&a, &layout);
            // Pseudo-inverse: the thrusts whose minimum-norm allocation is in the box.
            let shrunk = shrink_into_pseudo_inverse_range(&commanded, &thrusts[..n], layout.thrust_max_n);
            let wrench = wrench_of(&(&full * DVector::from_row_slice(&shrunk)));
            let a = allocator(&layout, actuation, AllocationMethod::PseudoInverse)
                .allocate(&wrench, &[])
                .unwrap();
            assert_round_trip(&a, &wrench, &format!("{name} pseudo-inverse"));
        }
    }

    #[test]
    fn producible_wrench_round_trips_on_the_omni_hexa(
        x in omni_thrust_vectors(),
        measured in prop::collection::vec(-3.0..3.0f64, 6),
    ) {
        let layout = fixtures::omni_hexa();
        let matrix = variable_tilt_effectiveness_matrix(&layout).unwrap();
        let wrench = wrench_of(&(&matrix * DVector::from_row_slice(&x)));
        let a = allocator(&layout, Actuation::VariableTilt, constrained())
            .allocate(&wrench, &measured)
            .unwrap();
        assert_round_trip(&a, &wrench, "Omni-Hexa constrained");
        assert_within_bounds(&a, &layout);
        // The returned angles and thrusts reproduce the wrench through the forward map too,
        // and every angle is within π of its measurement.
        let forward = wrench_from_thrusts(&layout, &a.thrusts_n, &a.tilt_rad).unwrap();
        assert_all_close(
            forward.to_vector().iter(),
            wrench.to_vector().iter(),
            ROUND_TRIP_TOLERANCE,
            "forward map",
        );
        for (angle, m) in a.tilt_rad.iter().zip(&measured) {
            prop_assert!((angle - m).abs() <= std::f64::consts::PI);
        }

        let shrunk = shrink_tilt_into_pseudo_inverse_range(&matrix, &x, layout.thrust_max_n);
        let wrench = wrench_of(&(&matrix * DVector::from_row_slice(&shrunk)));
        let a = allocator(&layout, Actuation::VariableTilt, AllocationMethod::PseudoInverse)
            .allocate(&wrench, &measured)
            .unwrap();
        assert_round_trip(&a, &wrench, "Omni-Hexa pseudo-inverse");
    }

    #[test]
    fn constrained_is_within_bounds_and_never_worse_than_clipping(
        thrusts in thrusts_in_box(6),
        scale in 1.5..12.0f64,
        offset in prop::array::uniform6(-1.0..1.0f64),
    ) {
        let vehicles = fixed_vehicles().map(|(name, layout, actuation)| (name, layout, actuation, false));
        let omni = ("Omni-Hexa", fixtures::omni_hexa(), Actuation::VariableTilt, true);
        for (name, layout, actuation, tilting) in vehicles.into_iter().chain([omni]) {
            let n = layout.len();
            // A producible wrench scaled far outside the set, plus an arbitrary push
            // (±20 N, ±2 N·m) off any direction the rotors favour.
            let base = if tilting {
                wrench_from_thrusts(&layout, &thrusts[..n], &thrusts[..n].iter().map(|t| t * 0.3).collect::<Vec<_>>()).unwrap()
            } else {
                wrench_from_thrusts(&layout, &thrusts[..n], &[]).unwrap()
            };
            let push = Wrench::new(
                Vector3::new(offset[0], offset[1], offset[2]) * 20.0,
                Vector3::new(offset[3], offset[4], offset[5]) * 2.0,
            );
            let wrench = Wrench::from_vector(&(base.to_vector() * scale)) + push;

            let mut qp = allocator(&layout, actuation, constrained());
            let a = qp.allocate(&wrench, &[]).unwrap();
            let b = allocator(&layout, actuation, AllocationMethod::PseudoInverse)
                .allocate(&wrench, &[])
                .unwrap();
            assert_within_bounds(&a, &layout);
            prop_assert!(
                matches!(a.status, AllocationStatus::Solved { .. } | AllocationStatus::WithinBounds),
                "{name}: {:?}", a.status
            );
            let e_qp = qp.weighted_error(&wrench, &a.achieved);
            let e_clip = qp.weighted_error(&wrench, &b.achieved);
            prop_assert!(
                e_qp <= e_clip * (1.0 + OBJECTIVE_RELATIVE_SLACK) + OBJECTIVE_ABSOLUTE_SLACK,
                "{name}: constrained error {e_qp} above clip error {e_clip} for {wrench:?}"
            );
        }
    }
}

fn hover_wrench(weight_n: f64, torque: Vector3<f64>) -> Wrench {
    Wrench::new(Vector3::new(0.0, 0.0, weight_n), torque)
}

#[test]
fn saturated_yaw_keeps_thrust() {
    // UA-Quad at hover (4.407 kg) asked for 5 N·m of yaw, ~5× what k_f = 0.02 allows.
    let layout = fixtures::ua_quad();
    let wrench = hover_wrench(4.407 * 9.81, Vector3::new(0.0, 0.0, 5.0));
    let mut qp = allocator(&layout, Actuation::UnderActuated, constrained());
    let a = qp.allocate(&wrench, &[]).unwrap();
    let clip = allocator(
        &layout,
        Actuation::UnderActuated,
        AllocationMethod::PseudoInverse,
    )
    .allocate(&wrench, &[])
    .unwrap();

    // Constrained: thrust, roll and pitch kept; yaw gives way.
    assert_close(
        a.achieved.force.z,
        wrench.force.z,
        KEPT_AXIS_TOLERANCE,
        "F_z kept",
    );
    assert_close(a.achieved.torque.x, 0.0, KEPT_AXIS_TOLERANCE, "τ_x kept");
    assert_close(a.achieved.torque.y, 0.0, KEPT_AXIS_TOLERANCE, "τ_y kept");
    assert!(
        a.unallocated.torque.z > 4.0,
        "yaw sacrificed: {:?}",
        a.unallocated
    );
    assert!(a.any_saturated());
    // Clip-after-pseudo-inverse loses thrust too (46 N instead of 43.2 N).
    assert!(
        (clip.achieved.force.z - wrench.force.z).abs() > 1.0,
        "clip F_z {}",
        clip.achieved.force.z
    );
    assert!(qp.weighted_error(&wrench, &a.achieved) < qp.weighted_error(&wrench, &clip.achieved));
}

#[test]
fn saturated_thrust_keeps_roll_torque() {
    // UA-Hexa asked for more than its 138 N of thrust and 2 N·m of roll.
    let layout = fixtures::ua_hexa();
    let wrench = hover_wrench(200.0, Vector3::new(2.0, 0.0, 0.0));
    let mut qp = allocator(&layout, Actuation::UnderActuated, constrained());
    let a = qp.allocate(&wrench, &[]).unwrap();
    let clip = allocator(
        &layout,
        Actuation::UnderActuated,
        AllocationMethod::PseudoInverse,
    )
    .allocate(&wrench, &[])
    .unwrap();
    assert_close(a.achieved.torque.x, 2.0, KEPT_AXIS_TOLERANCE, "τ_x kept");
    assert_close(a.achieved.torque.y, 0.0, KEPT_AXIS_TOLERANCE, "τ_y kept");
    assert!(
        a.achieved.force.z > 120.0,
        "as much thrust as roll allows: {}",
        a.achieved.force.z
    );
    // Clipping saturates every rotor at T_max and loses the roll torque.
    assert!(
        clip.achieved.torque.x.abs() < 0.5,
        "clip τ_x {}",
        clip.achieved.torque.x
    );
    assert!(clip.saturation.iter().all(|s| *s == RotorSaturation::Upper));
}

#[test]
fn saturated_lateral_force_keeps_attitude_on_the_omni_hexa() {
    // Omni-Hexa asked to hover with far more lateral force than its rotors can give.
    let layout = fixtures::omni_hexa();
    let wrench = Wrench::new(Vector3::new(150.0, 0.0, 33.0), Vector3::new(1.0, -0.5, 0.0));
    let measured = [0.0; 6];
    let mut qp = allocator(&layout, Actuation::VariableTilt, constrained());
    let a = qp.allocate(&wrench, &measured).unwrap();
    let clip = allocator(
        &layout,
        Actuation::VariableTilt,
        AllocationMethod::PseudoInverse,
    )
    .allocate(&wrench, &measured)
    .unwrap();
    assert_within_bounds(&a, &layout);
    assert_close(a.achieved.torque.x, 1.0, KEPT_AXIS_TOLERANCE, "τ_x kept");
    assert_close(a.achieved.torque.y, -0.5, KEPT_AXIS_TOLERANCE, "τ_y kept");
    assert!(qp.weighted_error(&wrench, &a.achieved) < qp.weighted_error(&wrench, &clip.achieved));
}

#[test]
fn feasible_request_takes_the_exact_fast_path() {
    let layout = fixtures::fa_hexa();
    let wrench = hover_wrench(6.635 * 9.81, Vector3::zeros());
    let a = allocator(&layout, Actuation::FullyActuated, constrained())
        .allocate(&wrench, &[])
        .unwrap();
    assert_eq!(a.status, AllocationStatus::WithinBounds);
    assert_eq!(a.thrusts_n, a.unconstrained_thrusts_n);
    assert_round_trip(&a, &wrench, "FA-Hexa hover");
    assert!(!a.any_saturated());
    // Hover needs ≈ 12.5 N per rotor (spec §1.3).
    for &t in &a.thrusts_n {
        assert_close(t, 12.5, 0.1, "hover thrust");
    }
}

#[test]
fn all_zero_request_is_quiet_for_every_method() {
    let vehicles = fixed_vehicles().into_iter().chain([(
        "Omni-Hexa",
        fixtures::omni_hexa(),
        Actuation::VariableTilt,
    )]);
    for (name, layout, actuation) in vehicles {
        for method in [AllocationMethod::PseudoInverse, constrained()] {
            let mut alloc = allocator(&layout, actuation, method);
            let mut out = alloc.new_allocation();
            alloc.allocate_into(&Wrench::ZERO, &[], &mut out).unwrap();
            assert_eq!(out.status, AllocationStatus::WithinBounds, "{name}");
            assert!(
                out.thrusts_n.iter().all(|&t| t == 0.0),
                "{name}: {:?}",
                out.thrusts_n
            );
            assert_eq!(out.unallocated, Wrench::ZERO, "{name}");
        }
    }
}

#[test]
fn allocation_is_deterministic_bit_for_bit() {
    let run = || {
        let layout = fixtures::omni_hexa();
        let mut alloc = allocator(&layout, Actuation::VariableTilt, constrained());
        let mut out = alloc.new_allocation();
        let mut bits = Vec::new();
        for k in 0..20 {
            let s = f64::from(k);
            let w = Wrench::new(
                Vector3::new(10.0 * s, -3.0, 30.0 + s),
                Vector3::new(0.1, 0.2 * s, -0.1),
            );
            alloc
                .allocate_into(&w, &out.tilt_rad.clone(), &mut out)
                .unwrap();
            bits.extend(
                out.thrusts_n
                    .iter()
                    .chain(&out.tilt_rad)
                    .map(|x| x.to_bits()),
            );
        }
        bits
    };
    assert_eq!(run(), run());
}

// ---- robots/test_rotor_actuator_pipeline.py (AMBENCH_SPEC §8) ----

/// Single rotor at the origin pushing +z, spin +1, k_f 0.1, limits (0, 100).
fn single_rotor() -> RotorLayout {
    let rotor = Rotor::fixed(Vector3::zeros(), Vector3::z(), Spin::Positive);
    fixtures::layout(vec![rotor], 0.0, 100.0, 0.1)
}

fn pipeline_actuator(tau: Option<f64>, rate: Option<f64>) -> RotorActuator {
    let config = RotorActuatorConfig {
        thrust_min_n: 0.0,
        thrust_max_n: 100.0,
        time_constant_s: tau,
        speed_rate_limit_per_s: rate,
    };
    RotorActuator::new(config, 1).unwrap()
}

/// Pipeline tolerance: a handful of floating-point operations.
const PIPELINE_TOLERANCE: f64 = 1e-12;

#[test]
fn pipeline_single_rotor_reproduces_the_wrench() {
    let layout = single_rotor();
    let wrench = Wrench::new(Vector3::new(0.0, 0.0, 5.0), Vector3::new(0.0, 0.0, 0.5));
    let a = allocator(
        &layout,
        Actuation::FullyActuated,
        AllocationMethod::PseudoInverse,
    )
    .allocate(&wrench, &[])
    .unwrap();
    assert_close(a.thrusts_n[0], 5.0, PIPELINE_TOLERANCE, "allocated");
    assert_round_trip(&a, &wrench, "single rotor");
    let mut actuator = pipeline_actuator(Some(0.1), None);
    let t = actuator.step(&a.unconstrained_thrusts_n, 0.01).unwrap()[0];
    assert_close(t.commanded_thrust_n, 5.0, PIPELINE_TOLERANCE, "commanded");
    assert_close(t.thrust_n, 5.0, PIPELINE_TOLERANCE, "realised");
}

#[test]
fn pipeline_rate_limited_rotor_realises_a_quarter_newton() {
    let layout = single_rotor();
    let mut alloc = allocator(
        &layout,
        Actuation::FullyActuated,
        AllocationMethod::PseudoInverse,
    );
    let mut actuator = pipeline_actuator(Some(0.1), Some(0.5));
    actuator.step(&[0.0], 0.1).unwrap();
    let wrench = Wrench::new(Vector3::new(0.0, 0.0, 100.0), Vector3::new(0.0, 0.0, 10.0));
    let a = alloc.allocate(&wrench, &[]).unwrap();
    let t = actuator.step(&a.unconstrained_thrusts_n, 0.1).unwrap()[0];
    assert_close(t.commanded_thrust_n, 100.0, PIPELINE_TOLERANCE, "commanded");
    assert_close(t.speed_command, 1.0, PIPELINE_TOLERANCE, "speed command");
    assert_close(t.speed, 0.05, PIPELINE_TOLERANCE, "speed");
    assert_close(t.speed_rate_per_s, 0.5, PIPELINE_TOLERANCE, "accel");
    assert!(t.rate_limited);
    assert_close(t.thrust_n, 0.25, PIPELINE_TOLERANCE, "realised");
    let applied = wrench_from_thrusts(&layout, &[t.thrust_n], &[]).unwrap();
    assert_all_close(
        applied.to_vector().iter(),
        [0.0, 0.0, 0.25, 0.0, 0.0, 0.025].iter(),
        PIPELINE_TOLERANCE,
        "final wrench",
    );
}

#[test]
fn pipeline_over_limit_request_saturates_the_actuator() {
    let layout = single_rotor();
    let wrench = Wrench::new(Vector3::new(0.0, 0.0, 200.0), Vector3::new(0.0, 0.0, 20.0));
    let a = allocator(
        &layout,
        Actuation::FullyActuated,
        AllocationMethod::PseudoInverse,
    )
    .allocate(&wrench, &[])
    .unwrap();
    assert!(
        a.unconstrained_thrusts_n[0] > 100.0,
        "allocated {:?}",
        a.unconstrained_thrusts_n
    );
    assert_eq!(a.thrusts_n, [100.0]);
    assert_eq!(a.saturation, [RotorSaturation::Upper]);
    let mut actuator = pipeline_actuator(Some(0.1), None);
    let t = actuator.step(&a.unconstrained_thrusts_n, 0.01).unwrap()[0];
    assert_close(t.commanded_thrust_n, 100.0, PIPELINE_TOLERANCE, "commanded");
    assert!(t.saturated);
    assert_close(t.thrust_n, 100.0, PIPELINE_TOLERANCE, "realised");
    assert!(
        any_rotor_saturated(&[t.thrust_n], 0.0, 100.0),
        "collector's motor_saturated"
    );
}

#[test]
fn pipeline_single_tilting_rotor_reconstructs_the_wrench() {
    let rotor =
        fixtures::tilting_rotor(Vector3::zeros(), Vector3::z(), Vector3::x(), Spin::Positive);
    let layout = fixtures::layout(vec![rotor], 0.0, 100.0, 0.1);
    let wrench = Wrench::new(Vector3::new(4.0, 0.0, 3.0), Vector3::new(0.4, 0.0, 0.3));
    for method in [AllocationMethod::PseudoInverse, constrained()] {
        let a = allocator(&layout, Actuation::VariableTilt, method)
            .allocate(&wrench, &[0.0])
            .unwrap();
        assert_close(a.thrusts_n[0], 5.0, PIPELINE_TOLERANCE, "magnitude");
        assert_close(a.tilt_rad[0], 4f64.atan2(3.0), PIPELINE_TOLERANCE, "angle");
        assert_close(a.tilt_rad[0], 0.9273, 1e-4, "angle, spec digits");
        assert_round_trip(&a, &wrench, "single tilting rotor");
        let mut actuator = pipeline_actuator(Some(0.1), None);
        let t = actuator.step(&a.thrusts_n, 0.01).unwrap()[0];
        assert_close(t.commanded_thrust_n, 5.0, PIPELINE_TOLERANCE, "commanded");
        assert_close(t.thrust_n, 5.0, PIPELINE_TOLERANCE, "realised");
        let applied = wrench_from_thrusts(&layout, &[t.thrust_n], &a.tilt_rad).unwrap();
        assert_all_close(
            applied.to_vector().iter(),
            wrench.to_vector().iter(),
            ROUND_TRIP_TOLERANCE,
            "final wrench",
        );
    }
}

#[test]
fn pipeline_two_rotor_actuators_reset_independently() {
    // RobotIO case: τ 0.0475, 2 envs × 2 rotors (±0.2 m in x, +z, spins ±1), dt 0.01.
    let rotors = vec![
        Rotor::fixed(Vector3::new(0.2, 0.0, 0.0), Vector3::z(), Spin::Positive),
        Rotor::fixed(Vector3::new(-0.2, 0.0, 0.0), Vector3::z(), Spin::Negative),
    ];
    let layout = fixtures::layout(rotors, 0.0, 100.0, 0.1);
    let config = RotorActuatorConfig {
        time_constant_s: Some(0.0475),
        ..RotorActuatorConfig::from_layout(&layout)
    };
    let mut envs = [
        RotorActuator::new(config, 2).unwrap(),
        RotorActuator::new(config, 2).unwrap(),
    ];
    for env in &mut envs {
        let out = env.step(&[5.0, 5.0], 0.01).unwrap();
        assert!(out.iter().all(|t| t.speed > 0.0));
    }
    envs[0].reset();
    assert!(envs[0].telemetry().iter().all(|t| t.speed == 0.0));
    assert!(envs[1].telemetry().iter().all(|t| t.speed > 0.0));
}

#[test]
fn redundant_layouts_stay_exact_where_the_pseudo_inverse_clips() {
    // Producible wrenches whose minimum-norm allocation leaves the box: the pseudo-inverse
    // method loses them, the constrained method finds another exact allocation.
    let ua_hexa = fixtures::ua_hexa();
    let omni = fixtures::omni_hexa();
    let omni_x: Vec<f64> = (0..6)
        .flat_map(|i| {
            let angle = 1.1 * f64::from(i);
            [23.0 * angle.cos(), 23.0 * angle.sin()]
        })
        .collect();
    let cases = [
        (
            &ua_hexa,
            Actuation::UnderActuated,
            wrench_from_thrusts(&ua_hexa, &[23.0, 0.0, 0.0, 23.0, 23.0, 0.0], &[]).unwrap(),
        ),
        (
            &omni,
            Actuation::VariableTilt,
            wrench_of(
                &(variable_tilt_effectiveness_matrix(&omni).unwrap() * DVector::from_vec(omni_x)),
            ),
        ),
    ];
    for (layout, actuation, wrench) in cases {
        let clip = allocator(layout, actuation, AllocationMethod::PseudoInverse)
            .allocate(&wrench, &[])
            .unwrap();
        assert_eq!(clip.status, AllocationStatus::Clipped, "{actuation:?}");
        let a = allocator(layout, actuation, constrained())
            .allocate(&wrench, &[])
            .unwrap();
        assert!(
            matches!(
                a.status,
                AllocationStatus::Solved {
                    reduced_accuracy: false,
                    ..
                }
            ),
            "{actuation:?}: {:?}",
            a.status
        );
        assert_round_trip(&a, &wrench, &format!("{actuation:?}"));
        assert_within_bounds(&a, layout);
    }
}

/// The built-in vehicle descriptions (the one source the twin, IK and MPC also read), not
/// hand-typed copies: each allocator builds with the rank its class needs and holds the
/// vehicle's weight at the zero configuration, centre-of-mass moment included.
#[test]
fn builtin_vehicles_allocate_their_hover_wrench() {
    for (id, rank) in [
        ("ua-quad", 4),
        ("ua-hexa", 4),
        ("fa-hexa", 6),
        ("omni-hexa", 6),
    ] {
        let vehicle = platform::Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"));
        let mp = vehicle.mass_properties(&vehicle.model.zero_configuration());
        let weight = Vector3::new(0.0, 0.0, mp.mass_kg * platform::GRAVITY_MPS2);
        // Gravity acts at the centre of mass: the rotors must also cancel its moment.
        let hover = Wrench::new(weight, mp.com_in_root_m.cross(&weight));
        for method in [AllocationMethod::PseudoInverse, constrained()] {
            let mut a = allocator(&vehicle.rotors, vehicle.actuation, method);
            assert_eq!(a.rank(), rank, "{id}");
            let tilt = vec![
                0.0;
                if vehicle.rotors.is_variable_tilt() {
                    vehicle.rotors.len()
                } else {
                    0
                }
            ];
            let result = a
                .allocate(&hover, &tilt)
                .unwrap_or_else(|e| panic!("{id}: {e}"));
            assert_round_trip(&result, &hover, id);
            assert_within_bounds(&result, &vehicle.rotors);
            let mean = result.thrusts_n.iter().sum::<f64>() / result.thrusts_n.len() as f64;
            let expected = vehicle.hover_thrust_per_rotor_n().unwrap_or(f64::NAN);
            // Equal shares only if the centre of mass sat on the thrust centre: within 10 %.
            assert!(
                (mean - expected).abs() < 0.1 * expected,
                "{id}: mean {mean} N vs {expected} N"
            );
        }
    }
}
