//! The benchmark's results document (README "Results JSON"): the parts of it that
//! `amstack bench` and `amstack bench merge` build alike.

use std::path::Path;

use anyhow::Result;
use policy_runtime::bench::{BenchConfig, RolloutResult};
use policy_runtime::metrics::{RunSummary, Spread, Stats};
use serde_json::{Value, json};

use crate::cli_error::bad_input;
use crate::output::check_writable;

/// Version of the results JSON layout.
pub(crate) const RESULTS_SCHEMA: u32 = 1;

fn spread_json(s: &Spread) -> Value {
    json!({ "mean": s.mean, "std": s.std, "stderr": s.stderr, "count": s.count })
}

pub(crate) fn rollout_json(r: &RolloutResult) -> Value {
    let s = &r.summary;
    let mut value = json!({
        "index": r.index,
        "seed": r.seed,
        "success": r.success,
        "termination": r.termination,
        "executed_steps": r.executed_steps,
        "subtask_completion": s.subtask_completion,
        "criteria": r.criteria.iter().map(|(n, v)| (n.clone(), Value::Bool(*v))).collect::<serde_json::Map<_, _>>(),
        "ee_pos_error_m": s.ee_pos_error_m,
        "base_pos_error_m": s.base_pos_error_m,
        "norm_ee_error": s.norm_ee_error,
        "norm_base_error": s.norm_base_error,
        "tilt_use_rad": s.tilt_use_rad,
        "saturation_rate": s.saturation_rate,
        "fallback_rate": s.fallback_rate,
        "mcap": r.mcap,
    });
    if let (Some(why), Some(object)) = (&r.divergence, value.as_object_mut()) {
        object.insert("divergence".to_owned(), json!(why));
    }
    if let (Some(e), Some(object)) = (&r.estimator, value.as_object_mut()) {
        object.insert("estimator".to_owned(), json!(e));
    }
    if let (Some(v), Some(object)) = (&r.video, value.as_object_mut()) {
        object.insert("video".to_owned(), json!(v));
    }
    if let (Some(p), Some(object)) = (&r.policy, value.as_object_mut()) {
        object.insert("policy".to_owned(), json!(p));
    }
    value
}

/// The learned policy's setup as the results record it (Null: the task's script).
pub(crate) fn policy_setup_json(config: &BenchConfig) -> Value {
    config.policy.as_ref().map_or(Value::Null, |p| {
        json!({
            "policy": p.endpoint.describe(),
            "policy_hz": p.policy_hz,
            "action_steps": p.action_steps,
            "latency_mode": p.latency,
        })
    })
}

/// One rollout's learned-policy figures, for the run-level `policy` block.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PolicyRollout<'a> {
    pub task: &'a str,
    pub index: usize,
    pub queries: u64,
    pub latency_samples_ms: &'a [f64],
    pub failure: Option<&'a str>,
}

impl<'a> PolicyRollout<'a> {
    /// The figures of a rollout flown by a learned policy (None: a scripted one).
    pub(crate) fn of(r: &'a RolloutResult) -> Option<Self> {
        r.policy.as_ref().map(|p| Self {
            task: r.task.name(),
            index: r.index,
            queries: p.queries,
            latency_samples_ms: &p.latency_samples_ms,
            failure: p.failure.as_deref(),
        })
    }
}

/// The run-level `policy` block: `setup` (the endpoint, `policy_hz`, `action_steps`,
/// `latency_mode`; an object, or Null for none) and, over `rollouts` in run order, the
/// queries, the latency statistics of every query (ms), the failed rollouts and their
/// reasons. `amstack bench` and `amstack bench merge` build it alike.
pub(crate) fn policy_block<'a>(
    setup: &Value,
    rollouts: impl Iterator<Item = PolicyRollout<'a>>,
) -> Value {
    let mut queries = 0;
    let mut samples = Vec::new();
    let mut failures = Vec::new();
    for r in rollouts {
        queries += r.queries;
        samples.extend_from_slice(r.latency_samples_ms);
        if let Some(why) = r.failure {
            failures.push(json!({ "task": r.task, "index": r.index, "reason": why }));
        }
    }
    let mut value = json!({
        "queries": queries,
        "latency_ms": Stats::of(samples),
        "policy_failed": failures.len(),
        "failures": failures,
    });
    if let (Some(object), Some(setup)) = (value.as_object_mut(), setup.as_object()) {
        for (k, v) in setup {
            object.insert(k.clone(), v.clone());
        }
    }
    value
}

/// A task's results from its summary and its rollouts' JSON (`amstack bench merge` builds
/// them from the parts' rollouts this way too).
pub(crate) fn task_json_of(
    s: &RunSummary,
    criteria_names: &[String],
    per_rollout: &[Value],
) -> Value {
    let criteria: serde_json::Map<String, Value> = criteria_names
        .iter()
        .map(|name| {
            let reached = per_rollout
                .iter()
                .filter(|r| r["criteria"][name.as_str()] == Value::Bool(true))
                .count();
            let rate = (!per_rollout.is_empty()).then(|| reached as f64 / per_rollout.len() as f64);
            (name.clone(), json!(rate))
        })
        .collect();
    json!({
        "rollouts": s.rollouts,
        "successes": s.successes,
        "success_rate": s.success_rate,
        "subtask_completion": s.subtask_completion,
        "criteria_rates": criteria,
        "norm_ee_error": s.norm_ee_error.mean,
        "norm_base_error": s.norm_base_error.mean,
        "tilt_use_rad": s.tilt_use_rad.mean,
        "saturation_rate": s.saturation_rate.mean,
        "fallback_rate": s.fallback_rate.mean,
        "spread_over_successes": {
            "norm_ee_error": spread_json(&s.norm_ee_error),
            "norm_base_error": spread_json(&s.norm_base_error),
            "tilt_use_rad": spread_json(&s.tilt_use_rad),
            "saturation_rate": spread_json(&s.saturation_rate),
        },
        "policy_failed": per_rollout
            .iter()
            .filter(|r| r["termination"] == "policy_failed")
            .count(),
        "per_rollout": per_rollout,
    })
}

/// The `timing` block of a results document.
pub(crate) fn timing_json(
    link: &str,
    wall_time_s: f64,
    jobs: &Value,
    env_steps: u64,
    rollouts: usize,
) -> Value {
    let seconds_per_rollout = wall_time_s / rollouts.max(1) as f64;
    json!({
        "link": link,
        "wall_time_s": wall_time_s,
        "jobs": jobs,
        "env_steps": env_steps,
        "env_steps_per_second": env_steps as f64 / wall_time_s.max(1e-9),
        "seconds_per_rollout": seconds_per_rollout,
        "rollouts_per_minute": 60.0 / seconds_per_rollout.max(1e-9),
    })
}

pub(crate) fn check_out_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| bad_input(format!("--out {}: cannot create it: {e}", dir.display())))?;
    check_writable("--out", &dir.join("results.json"))
}
