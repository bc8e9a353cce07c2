//! The benchmark's results document (README "Results JSON"): the parts of it that
//! `amstack bench` and `amstack bench merge` build alike.

use std::path::Path;

use anyhow::Result;
use policy_runtime::bench::RolloutResult;
use policy_runtime::metrics::{RunSummary, Spread};
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
        "mcap": r.mcap,
    });
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
