//! The benchmark's metrics (AMBENCH_SPEC §6; the paper's "Evaluation Metric Definitions").
//!
//! Per control tick a [`TrackingRecord`] holds what was asked and what happened; a rollout's
//! records reduce to a [`RolloutSummary`] (the last record is dropped, as the reference
//! drops the record of the terminating step), rollouts to a [`RunSummary`]:
//!
//! - EE and base errors: ‖p_des − p_act‖ and the geodesic angle of q_des ⊗ q_act*;
//! - normalised errors: divided by the vehicle's arm reach (its `max_arm_reach_m`; for a
//!   vehicle without one, ‖p_ee − p_base‖ at construction — 0 for the EE-only oracle, which
//!   makes them undefined, as in the reference);
//! - tilt use: the largest √(roll² + pitch²) of the base;
//! - saturation rate: the share of ticks whose rotors were saturated, over the ticks that
//!   have rotors (undefined without rotors);
//! - success rate and subtask completion (criteria latched "ever true" over a rollout;
//!   undefined for a task without subtasks).
//!
//! Undefined values are `None` in Rust and `null` in JSON ("N/A" in tables), never NaN:
//! statistics skip non-finite samples and report a count, the reference's rules.

use nalgebra::{Isometry3, UnitQuaternion};
use serde::{Deserialize, Serialize};

/// What one control tick asked for and achieved.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackingRecord {
    /// Desired end-effector link pose (world).
    pub ee_desired: Isometry3<f64>,
    /// Measured end-effector link pose (world).
    pub ee_actual: Isometry3<f64>,
    /// Desired base pose (world): the IK's base target, or the EE target for the oracle.
    pub base_desired: Isometry3<f64>,
    /// Measured base pose (world).
    pub base_actual: Isometry3<f64>,
    /// Rotor saturation indicator of the tick; `None` for a vehicle without rotors.
    pub saturated: Option<bool>,
    /// Whether the whole-body MPC's IK-PID fallback flew the tick; `None` without the MPC.
    pub fallback: Option<bool>,
}

/// Geodesic angle between two orientations, rad, in [0, π].
pub fn rotation_error_rad(desired: &UnitQuaternion<f64>, actual: &UnitQuaternion<f64>) -> f64 {
    desired.angle_to(actual)
}

/// Largest-magnitude tilt of a base: √(roll² + pitch²) with R = Rz(yaw)·Ry(pitch)·Rx(roll).
pub fn tilt_rad(orientation: &UnitQuaternion<f64>) -> f64 {
    let (roll, pitch, _) = orientation.euler_angles();
    roll.hypot(pitch)
}

/// Order statistics of the finite samples of one metric (numpy's linear-interpolation
/// percentiles). `None` fields when there is no finite sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Stats {
    /// Mean.
    pub mean: Option<f64>,
    /// Minimum.
    pub min: Option<f64>,
    /// Median.
    pub p50: Option<f64>,
    /// 90th percentile.
    pub p90: Option<f64>,
    /// 95th percentile.
    pub p95: Option<f64>,
    /// 99th percentile.
    pub p99: Option<f64>,
    /// Maximum.
    pub max: Option<f64>,
    /// Number of finite samples.
    pub count: usize,
}

impl Stats {
    /// Statistics of the finite values in `samples`.
    pub fn of(samples: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = samples.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let percentile = |p: f64| {
            // numpy 'linear': rank = p·(n − 1), interpolated between neighbours.
            let rank = p / 100.0 * (v.len() - 1) as f64;
            let lo = rank.floor() as usize;
            let hi = rank.ceil() as usize;
            v[lo] + (rank - lo as f64) * (v[hi] - v[lo])
        };
        Self {
            mean: Some(v.iter().sum::<f64>() / v.len() as f64),
            min: v.first().copied(),
            p50: Some(percentile(50.0)),
            p90: Some(percentile(90.0)),
            p95: Some(percentile(95.0)),
            p99: Some(percentile(99.0)),
            max: v.last().copied(),
            count: v.len(),
        }
    }
}

/// One rollout's metrics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutSummary {
    /// The task's success criterion was met.
    pub success: bool,
    /// Share of the task's subtasks completed (latched); `None` for a task without subtasks.
    pub subtask_completion: Option<f64>,
    /// Mean EE position error, m.
    pub ee_pos_error_m: Option<f64>,
    /// Mean EE orientation error, rad.
    pub ee_rot_error_rad: Option<f64>,
    /// Mean base position error, m.
    pub base_pos_error_m: Option<f64>,
    /// Mean base orientation error, rad.
    pub base_rot_error_rad: Option<f64>,
    /// Mean EE position error over the arm reach.
    pub norm_ee_error: Option<f64>,
    /// Mean base position error over the arm reach.
    pub norm_base_error: Option<f64>,
    /// Largest base tilt, rad.
    pub tilt_use_rad: Option<f64>,
    /// Share of ticks with saturated rotors; `None` without rotors.
    pub saturation_rate: Option<f64>,
    /// Share of ticks the whole-body MPC's IK-PID fallback flew; `None` without the MPC.
    #[serde(default)]
    pub fallback_rate: Option<f64>,
    /// Ticks scored (records less the last).
    pub ticks: usize,
    /// Statistics of the EE position error, m.
    pub ee_pos_error_stats: Stats,
}

/// Latches a task's subtask criteria over a rollout ("ever true").
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CriteriaLatch {
    reached: Vec<bool>,
}

impl CriteriaLatch {
    /// A latch for `count` criteria.
    pub fn new(count: usize) -> Self {
        Self {
            reached: vec![false; count],
        }
    }

    /// Records this tick's criteria (a slice of the same length as the latch).
    pub fn observe(&mut self, criteria: &[bool]) {
        for (r, c) in self.reached.iter_mut().zip(criteria) {
            *r |= *c;
        }
    }

    /// Each criterion: reached at some tick.
    pub fn reached(&self) -> &[bool] {
        &self.reached
    }

    /// Completed / total; `None` for a task without subtasks.
    pub fn completion(&self) -> Option<f64> {
        (!self.reached.is_empty())
            .then(|| self.reached.iter().filter(|r| **r).count() as f64 / self.reached.len() as f64)
    }
}

fn mean_of(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values
        .into_iter()
        .filter(|x| x.is_finite())
        .fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// Reduces a rollout's records. `arm_reach_m` of zero or less (or non-finite) makes the
/// normalised errors undefined.
pub fn summarize_rollout(
    records: &[TrackingRecord],
    success: bool,
    subtask_completion: Option<f64>,
    arm_reach_m: f64,
) -> RolloutSummary {
    // The record of the terminating tick is dropped (AMBENCH_SPEC §6.2), unless it is the only one.
    let used = if records.len() > 1 {
        &records[..records.len() - 1]
    } else {
        records
    };
    let ee_pos: Vec<f64> = used
        .iter()
        .map(|r| (r.ee_desired.translation.vector - r.ee_actual.translation.vector).norm())
        .collect();
    let base_pos: Vec<f64> = used
        .iter()
        .map(|r| (r.base_desired.translation.vector - r.base_actual.translation.vector).norm())
        .collect();
    let reach = (arm_reach_m.is_finite() && arm_reach_m > 0.0).then_some(arm_reach_m);
    let saturation: Vec<bool> = used.iter().filter_map(|r| r.saturated).collect();
    let fallback: Vec<bool> = used.iter().filter_map(|r| r.fallback).collect();
    let share = |flags: &[bool]| {
        (!flags.is_empty())
            .then(|| flags.iter().filter(|s| **s).count() as f64 / flags.len() as f64)
    };
    RolloutSummary {
        success,
        subtask_completion,
        ee_pos_error_m: mean_of(ee_pos.iter().copied()),
        ee_rot_error_rad: mean_of(
            used.iter()
                .map(|r| rotation_error_rad(&r.ee_desired.rotation, &r.ee_actual.rotation)),
        ),
        base_pos_error_m: mean_of(base_pos.iter().copied()),
        base_rot_error_rad: mean_of(
            used.iter()
                .map(|r| rotation_error_rad(&r.base_desired.rotation, &r.base_actual.rotation)),
        ),
        norm_ee_error: reach.and_then(|l| mean_of(ee_pos.iter().map(|e| e / l))),
        norm_base_error: reach.and_then(|l| mean_of(base_pos.iter().map(|e| e / l))),
        tilt_use_rad: used
            .iter()
            .map(|r| tilt_rad(&r.base_actual.rotation))
            .filter(|x| x.is_finite())
            .reduce(f64::max),
        saturation_rate: share(&saturation),
        fallback_rate: share(&fallback),
        ticks: used.len(),
        ee_pos_error_stats: Stats::of(ee_pos),
    }
}

/// Mean and sample standard deviation of a metric across rollouts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct Spread {
    /// Mean over the rollouts where the metric is defined.
    pub mean: Option<f64>,
    /// Sample standard deviation (n − 1); `None` below two rollouts.
    pub std: Option<f64>,
    /// Standard error std/√n; `None` below two rollouts.
    pub stderr: Option<f64>,
    /// Rollouts where the metric is defined.
    pub count: usize,
}

impl Spread {
    /// Over the defined values.
    pub fn of(values: impl IntoIterator<Item = Option<f64>>) -> Self {
        let v: Vec<f64> = values
            .into_iter()
            .flatten()
            .filter(|x| x.is_finite())
            .collect();
        let n = v.len();
        let mean = mean_of(v.iter().copied());
        let std = match (mean, n) {
            (Some(m), n) if n >= 2 => {
                Some((v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt())
            }
            _ => None,
        };
        Self {
            mean,
            std,
            stderr: std.map(|s| s / (n as f64).sqrt()),
            count: n,
        }
    }
}

/// A run's metrics, in the shape of the paper's tables: success over all rollouts, the
/// tracking and limit metrics over the successful ones.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunSummary {
    /// Rollouts flown.
    pub rollouts: usize,
    /// Rollouts that met the success criterion.
    pub successes: usize,
    /// successes / rollouts (0 with no rollout).
    pub success_rate: f64,
    /// Mean subtask completion over the rollouts where it is defined; `None` for a task
    /// without subtasks.
    pub subtask_completion: Option<f64>,
    /// Normalised EE error over successful rollouts.
    pub norm_ee_error: Spread,
    /// Normalised base error over successful rollouts.
    pub norm_base_error: Spread,
    /// Tilt use over successful rollouts, rad.
    pub tilt_use_rad: Spread,
    /// Saturation rate over successful rollouts.
    pub saturation_rate: Spread,
    /// Share of ticks the MPC's IK-PID fallback flew, over every rollout (failed ones
    /// included: where the fallback flies is part of why a rollout fails); undefined without
    /// the MPC.
    pub fallback_rate: Spread,
}

/// Reduces rollouts to a run.
pub fn summarize_run(rollouts: &[RolloutSummary]) -> RunSummary {
    let successes = rollouts.iter().filter(|r| r.success).count();
    let ok: Vec<&RolloutSummary> = rollouts.iter().filter(|r| r.success).collect();
    RunSummary {
        rollouts: rollouts.len(),
        successes,
        success_rate: if rollouts.is_empty() {
            0.0
        } else {
            successes as f64 / rollouts.len() as f64
        },
        subtask_completion: mean_of(rollouts.iter().filter_map(|r| r.subtask_completion)),
        norm_ee_error: Spread::of(ok.iter().map(|r| r.norm_ee_error)),
        norm_base_error: Spread::of(ok.iter().map(|r| r.norm_base_error)),
        tilt_use_rad: Spread::of(ok.iter().map(|r| r.tilt_use_rad)),
        saturation_rate: Spread::of(ok.iter().map(|r| r.saturation_rate)),
        fallback_rate: Spread::of(rollouts.iter().map(|r| r.fallback_rate)),
    }
}

/// A metric for a table: "N/A" when undefined, as the reference prints it.
pub fn format_or_na(value: Option<f64>, decimals: usize) -> String {
    value
        .filter(|v| v.is_finite())
        .map_or_else(|| "N/A".to_owned(), |v| format!("{v:.decimals$}"))
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, Vector3};

    use super::*;

    const EXACT: f64 = 1e-12;

    fn pose(x: f64, z: f64, roll: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, 0.0, z),
            UnitQuaternion::from_euler_angles(roll, 0.0, 0.0),
        )
    }

    /// A record whose EE is `ee_err` m off along x, base `base_err` m, base rolled `roll`.
    fn record(ee_err: f64, base_err: f64, roll: f64, saturated: Option<bool>) -> TrackingRecord {
        TrackingRecord {
            ee_desired: pose(1.0, 1.0, 0.0),
            ee_actual: pose(1.0 + ee_err, 1.0, 0.0),
            base_desired: pose(0.0, 1.0, 0.0),
            base_actual: pose(base_err, 1.0, roll),
            saturated,
            fallback: None,
        }
    }

    #[test]
    fn the_last_record_is_dropped() {
        let records = [
            record(0.1, 0.0, 0.0, None),
            record(0.3, 0.0, 0.0, None),
            record(9.0, 0.0, 0.0, None),
        ];
        let s = summarize_rollout(&records, true, None, 1.0);
        assert_eq!(s.ticks, 2);
        assert!((s.ee_pos_error_m.unwrap_or(f64::NAN) - 0.2).abs() < EXACT);
        // A single record is kept.
        let one = summarize_rollout(&records[..1], true, None, 1.0);
        assert_eq!(one.ticks, 1);
    }

    #[test]
    fn errors_normalise_by_the_arm_reach() {
        let records = [
            record(0.124, 0.062, 0.0, Some(false)),
            record(0.124, 0.062, 0.0, Some(false)),
            record(0.0, 0.0, 0.0, None),
        ];
        let s = summarize_rollout(&records, true, Some(1.0), 1.24);
        assert!((s.norm_ee_error.unwrap_or(f64::NAN) - 0.1).abs() < EXACT);
        assert!((s.norm_base_error.unwrap_or(f64::NAN) - 0.05).abs() < EXACT);
    }

    #[test]
    fn normalised_errors_and_saturation_are_undefined_where_the_reference_says_so() {
        // EE-only oracle: no reach (0) and no rotors.
        let records = [record(0.1, 0.1, 0.0, None), record(0.1, 0.1, 0.0, None)];
        let s = summarize_rollout(&records, true, None, 0.0);
        assert_eq!(
            (s.norm_ee_error, s.norm_base_error, s.saturation_rate),
            (None, None, None)
        );
        assert!(s.ee_pos_error_m.is_some());
        assert_eq!(format_or_na(s.saturation_rate, 6), "N/A");
        let empty = summarize_rollout(&[], false, None, 1.0);
        assert_eq!(
            (empty.ee_pos_error_m, empty.tilt_use_rad, empty.ticks),
            (None, None, 0)
        );
        assert_eq!(empty.ee_pos_error_stats.count, 0);
    }

    #[test]
    fn saturation_rate_counts_ticks_with_rotors() {
        let records = [
            record(0.0, 0.0, 0.0, Some(true)),
            record(0.0, 0.0, 0.0, Some(false)),
            record(0.0, 0.0, 0.0, Some(false)),
            record(0.0, 0.0, 0.0, Some(true)),
            record(0.0, 0.0, 0.0, Some(true)), // dropped
        ];
        let s = summarize_rollout(&records, true, None, 1.0);
        assert!((s.saturation_rate.unwrap_or(f64::NAN) - 0.5).abs() < EXACT);
    }

    #[test]
    fn the_fallback_rate_counts_the_mpcs_ticks_and_the_run_takes_every_rollout() {
        let flown = |flags: &[Option<bool>]| {
            let records: Vec<TrackingRecord> = flags
                .iter()
                .map(|&fallback| TrackingRecord {
                    fallback,
                    ..record(0.0, 0.0, 0.0, None)
                })
                .collect();
            records
        };
        // 1 of 4 scored ticks on the fallback (the last record dropped).
        let mpc = flown(&[
            Some(false),
            Some(true),
            Some(false),
            Some(false),
            Some(true),
        ]);
        let s = summarize_rollout(&mpc, false, None, 1.0);
        assert_eq!(s.fallback_rate, Some(0.25));
        let all = flown(&[Some(true), Some(true), Some(true)]);
        let t = summarize_rollout(&all, true, None, 1.0);
        assert_eq!(t.fallback_rate, Some(1.0));
        // Without the MPC: undefined.
        let pid = summarize_rollout(&flown(&[None, None]), true, None, 1.0);
        assert_eq!(pid.fallback_rate, None);
        // Over every rollout, the failed one included (the saturation over successes only).
        let run = summarize_run(&[s, t]);
        assert_eq!(
            (run.fallback_rate.mean, run.fallback_rate.count),
            (Some(0.625), 2)
        );
        // A rollout summary written before the field reads it as undefined.
        let mut old = serde_json::to_value(&pid).unwrap_or_default();
        if let Some(o) = old.as_object_mut() {
            o.remove("fallback_rate");
        }
        let read: RolloutSummary = serde_json::from_value(old).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(read.fallback_rate, None);
    }

    #[test]
    fn tilt_use_is_the_largest_roll_pitch_magnitude() {
        let records = [
            record(0.0, 0.0, 0.1, None),
            record(0.0, 0.0, -0.3, None),
            record(0.0, 0.0, 0.2, None),
            record(0.0, 0.0, 0.0, None),
        ];
        let s = summarize_rollout(&records, true, None, 1.0);
        assert!((s.tilt_use_rad.unwrap_or(f64::NAN) - 0.3).abs() < 1e-12);
        let tilted = UnitQuaternion::from_euler_angles(0.3, 0.4, 1.0);
        assert!(
            (tilt_rad(&tilted) - 0.5).abs() < 1e-12,
            "yaw does not count"
        );
    }

    #[test]
    fn rotation_error_is_the_geodesic_angle() {
        let a = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.2);
        let b = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -0.5);
        assert!((rotation_error_rad(&a, &b) - 0.7).abs() < 1e-12);
        // q and −q are the same rotation: the error is 0, not 2π.
        let minus = UnitQuaternion::new_unchecked(-a.into_inner());
        assert!(rotation_error_rad(&a, &minus) < 1e-7);
    }

    #[test]
    fn stats_use_numpy_linear_percentiles_over_finite_samples() {
        let s = Stats::of([4.0, 1.0, f64::NAN, 3.0, 2.0, f64::INFINITY]);
        assert_eq!(s.count, 4);
        assert_eq!((s.min, s.max), (Some(1.0), Some(4.0)));
        assert!((s.mean.unwrap_or(f64::NAN) - 2.5).abs() < EXACT);
        // numpy.percentile([1,2,3,4], 50) = 2.5; 90 → 3.7; 99 → 3.97.
        assert!((s.p50.unwrap_or(f64::NAN) - 2.5).abs() < EXACT);
        assert!((s.p90.unwrap_or(f64::NAN) - 3.7).abs() < EXACT);
        assert!((s.p99.unwrap_or(f64::NAN) - 3.97).abs() < EXACT);
        assert_eq!(Stats::of([f64::NAN]), Stats::default());
    }

    #[test]
    fn subtasks_latch_and_tasks_without_them_are_undefined() {
        let mut latch = CriteriaLatch::new(3);
        latch.observe(&[true, false, false]);
        latch.observe(&[false, false, true]);
        latch.observe(&[false, false, false]);
        assert!((latch.completion().unwrap_or(f64::NAN) - 2.0 / 3.0).abs() < EXACT);
        assert_eq!(CriteriaLatch::new(0).completion(), None);
    }

    #[test]
    fn run_metrics_average_successful_rollouts_only() {
        let rollout = |success: bool, ee: f64, completion: Option<f64>| {
            let records = [
                record(ee, 0.0, 0.0, Some(false)),
                record(ee, 0.0, 0.0, Some(false)),
            ];
            summarize_rollout(&records, success, completion, 1.0)
        };
        let run = summarize_run(&[
            rollout(true, 0.1, Some(1.0)),
            rollout(true, 0.3, Some(1.0)),
            rollout(false, 5.0, Some(0.5)),
        ]);
        assert_eq!((run.rollouts, run.successes), (3, 2));
        assert!((run.success_rate - 2.0 / 3.0).abs() < EXACT);
        assert!(
            (run.subtask_completion.unwrap_or(f64::NAN) - 2.5 / 3.0).abs() < EXACT,
            "over every rollout"
        );
        assert!(
            (run.norm_ee_error.mean.unwrap_or(f64::NAN) - 0.2).abs() < EXACT,
            "the failed rollout is left out"
        );
        // Sample std (n − 1) of {0.1, 0.3}: √0.02.
        assert!((run.norm_ee_error.std.unwrap_or(f64::NAN) - 0.02f64.sqrt()).abs() < EXACT);
        assert!((run.norm_ee_error.stderr.unwrap_or(f64::NAN) - 0.1).abs() < EXACT);
        let single = summarize_run(&[rollout(true, 0.1, None)]);
        assert_eq!(
            (single.norm_ee_error.std, single.subtask_completion),
            (None, None)
        );
        let none = summarize_run(&[]);
        assert_eq!((none.success_rate, none.norm_ee_error.mean), (0.0, None));
    }
}
