//! Sharding a benchmark run: which rollouts shard `i` of `n` runs.
//!
//! A run's rollouts are numbered in the order the runner lists them, task-major:
//! `k = t · R + r` for the `t`-th configured task and rollout index `r` of `R` per task.
//! Shard `i` of `n` (0-based) holds the rollouts with `k mod n = i` — round robin, so every
//! shard gets a share of every task and of the long and short ones alike. Each rollout is a
//! pure function of its seed (run seed + `r`), so a rollout flown in a shard is the rollout
//! the unsharded run flies: merging the shards gives the unsharded result.

use std::fmt;

use sim_twin::TaskId;

/// Shard `index` of `count` (0-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// This shard, `0..count`.
    pub index: usize,
    /// How many shards the run is split into (at least 1).
    pub count: usize,
}

/// The assignment rule, as recorded in every partial result.
pub const ASSIGNMENT: &str = "rollout k = task_position * rollouts + index (task-major, tasks in \
                              the configured order); shard i of n holds the rollouts with k mod n = i";

/// A shard specification that is not `I/N` with `0 <= I < N`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ShardError(String);

impl Shard {
    /// The whole run as one shard.
    pub const WHOLE: Self = Self { index: 0, count: 1 };

    /// Shard `index` of `count`, checked.
    pub fn new(index: usize, count: usize) -> Result<Self, ShardError> {
        if count == 0 {
            return Err(ShardError(format!(
                "{index}/{count}: a run splits into at least 1 shard"
            )));
        }
        if index >= count {
            return Err(ShardError(format!(
                "{index}/{count}: shards are numbered 0 to {} (0-based)",
                count - 1
            )));
        }
        Ok(Self { index, count })
    }

    /// Whether this shard holds the run's rollout number `k`.
    pub fn holds(&self, k: usize) -> bool {
        k % self.count == self.index
    }

    /// The rollouts of this shard, as (task, rollout index), in run order.
    pub fn rollouts(&self, tasks: &[TaskId], rollouts_per_task: usize) -> Vec<(TaskId, usize)> {
        tasks
            .iter()
            .flat_map(|t| (0..rollouts_per_task).map(move |r| (*t, r)))
            .enumerate()
            .filter(|(k, _)| self.holds(*k))
            .map(|(_, job)| job)
            .collect()
    }
}

/// The first field (a dotted path from `path`) where `a` and `b` differ, with both values:
/// what names the difference between two parts that should be of one run.
pub fn first_difference(
    a: &serde_json::Value,
    b: &serde_json::Value,
    path: &str,
) -> Option<(String, serde_json::Value, serde_json::Value)> {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            keys.into_iter().find_map(|k| {
                first_difference(
                    x.get(k).unwrap_or(&Value::Null),
                    y.get(k).unwrap_or(&Value::Null),
                    &format!("{path}.{k}"),
                )
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (p, q))| first_difference(p, q, &format!("{path}[{i}]"))),
        _ if a == b => None,
        _ => Some((path.to_owned(), a.clone(), b.clone())),
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TASKS: [TaskId; 2] = [TaskId::PressButton, TaskId::PushSlider];

    #[test]
    fn the_shards_partition_the_run_round_robin() {
        let all = Shard::WHOLE.rollouts(&TASKS, 4);
        assert_eq!(all.len(), 8);
        let shards: Vec<_> = (0..3)
            .map(|i| Shard::new(i, 3).map(|s| s.rollouts(&TASKS, 4)))
            .collect::<Result<_, _>>()
            .unwrap_or_default();
        // k = 0..8; shard 1 holds k = 1, 4, 7: press-button #1, push-slider #0 and #3.
        assert_eq!(
            shards[1],
            vec![
                (TaskId::PressButton, 1),
                (TaskId::PushSlider, 0),
                (TaskId::PushSlider, 3)
            ]
        );
        let mut union: Vec<_> = shards.concat();
        union.sort();
        let mut expected = all;
        expected.sort();
        assert_eq!(union, expected, "every rollout exactly once");
    }

    #[test]
    fn more_shards_than_rollouts_leaves_some_empty() {
        let s = Shard::new(4, 5).map(|s| s.rollouts(&TASKS[..1], 2));
        assert_eq!(s, Ok(vec![]));
    }

    #[test]
    fn a_shard_outside_its_run_is_refused() {
        assert!(Shard::new(3, 3).is_err_and(|e| e.to_string().contains("0 to 2")));
        assert!(Shard::new(0, 0).is_err());
        assert_eq!(
            Shard::new(2, 3).map(|s| s.to_string()),
            Ok("2/3".to_owned())
        );
    }
}
