//! Dropping what a crash left uncommitted, before a recording resumes.
//!
//! An episode is written in order: its rows into the data file, then its row of
//! `meta/episodes`, `meta/tasks.parquet`, `meta/stats.json`, and `meta/info.json` last — the
//! commit (its `total_episodes`). A run killed in between leaves rows of an episode that
//! `info.json` does not count: in a data file (a file of its own, or after the committed
//! episodes' rows), in `meta/episodes`, a task, and its statistics folded into `stats.json`.
//! [`drop_uncommitted`] removes those rows and files, so the dataset is the committed one
//! again (`validate` is clean) and a resumed recording goes on from it; it says whether
//! `stats.json` must be recomputed (the episode's row had reached `meta/episodes`, so its
//! statistics may have reached `stats.json`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{BooleanArray, Int64Array};
use arrow::compute::{concat_batches, filter_record_batch};
use arrow::datatypes::Schema;
use arrow::record_batch::RecordBatch;
use serde_json::Value;

use super::DatasetError;
use super::layout::DatasetSpec;
use super::read::{column, parquet_files, read_parquet, rel};
use super::write::{data_schema, tasks_parquet, write_atomic, write_parquet};

/// What [`drop_uncommitted`] removed.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Repair {
    /// Data rows of uncommitted episodes.
    pub data_rows: u64,
    /// `meta/episodes` rows of uncommitted episodes.
    pub episode_rows: u64,
    /// Tasks past `info.json`'s `total_tasks`.
    pub tasks: u64,
    /// Files that held only uncommitted rows (relative paths).
    pub files_removed: Vec<String>,
}

impl Repair {
    /// Whether anything was dropped.
    pub fn any(&self) -> bool {
        self.data_rows + self.episode_rows + self.tasks > 0 || !self.files_removed.is_empty()
    }

    /// Whether `stats.json` may hold an uncommitted episode's statistics.
    pub fn stats_suspect(&self) -> bool {
        self.episode_rows > 0
    }
}

/// [`parquet_files`] of `root/dir`, none if a crash left no such folder.
fn existing_parquet_files(root: &Path, dir: &str) -> Result<Vec<PathBuf>, DatasetError> {
    if root.join(dir).is_dir() {
        parquet_files(root, dir)
    } else {
        Ok(Vec::new())
    }
}

/// The rows of `batches` (one table) whose `episode_index` is below `committed`, one batch
/// per episode in order of appearance (the writer's row groups), with `schema`; and how many
/// rows were dropped.
fn committed_rows(
    batches: &[RecordBatch],
    committed: u64,
    schema: &Arc<Schema>,
    file: &str,
    per_episode: bool,
) -> Result<(Vec<RecordBatch>, u64), DatasetError> {
    let Some(first) = batches.first() else {
        return Ok((Vec::new(), 0));
    };
    let all = concat_batches(&first.schema(), batches).map_err(DatasetError::arrow(file))?;
    let episodes: Vec<i64> = column::<Int64Array>(&all, "episode_index", file)?
        .values()
        .to_vec();
    let dropped = episodes.iter().filter(|e| **e as u64 >= committed).count() as u64;
    let mut order: Vec<i64> = Vec::new();
    for e in &episodes {
        if (*e as u64) < committed && order.last() != Some(e) && !order.contains(e) {
            order.push(*e);
        }
    }
    let groups: Vec<Vec<i64>> = if per_episode {
        order.iter().map(|e| vec![*e]).collect()
    } else if order.is_empty() {
        Vec::new()
    } else {
        vec![order]
    };
    let mut out = Vec::new();
    for group in groups {
        let mask = BooleanArray::from(
            episodes
                .iter()
                .map(|e| group.contains(e))
                .collect::<Vec<bool>>(),
        );
        let kept = filter_record_batch(&all, &mask).map_err(DatasetError::arrow(file))?;
        out.push(
            RecordBatch::try_new(schema.clone(), kept.columns().to_vec())
                .map_err(DatasetError::arrow(file))?,
        );
    }
    Ok((out, dropped))
}

/// Rewrites `path` with its committed rows (removes it if none is left); returns the rows
/// dropped.
fn keep_committed(
    root: &Path,
    path: &Path,
    committed: u64,
    schema: Option<&Arc<Schema>>,
    per_episode: bool,
    repair: &mut Repair,
) -> Result<u64, DatasetError> {
    let file = rel(root, path);
    let batches = read_parquet(path)?;
    let schema = schema
        .cloned()
        .or_else(|| batches.first().map(RecordBatch::schema));
    let Some(schema) = schema else {
        return Ok(0);
    };
    let (kept, dropped) = committed_rows(&batches, committed, &schema, &file, per_episode)?;
    if dropped == 0 {
        return Ok(0);
    }
    if kept.is_empty() {
        std::fs::remove_file(path).map_err(DatasetError::io(path))?;
        repair.files_removed.push(file);
    } else {
        write_parquet(root, &file, &schema, &kept)?;
    }
    Ok(dropped)
}

/// Drops every row, file and task of episodes `meta/info.json` does not count (see the
/// module). `stats.json` is left to the caller (see [`Repair::stats_suspect`]).
pub(crate) fn drop_uncommitted(root: &Path) -> Result<Repair, DatasetError> {
    let info_path = root.join("meta/info.json");
    let text = std::fs::read_to_string(&info_path).map_err(DatasetError::io(&info_path))?;
    let info: Value = serde_json::from_str(&text)
        .map_err(|e| DatasetError::invalid("meta/info.json", e.to_string()))?;
    let spec = DatasetSpec::from_info(&info, "meta/info.json")?;
    let committed = info
        .get("total_episodes")
        .and_then(Value::as_u64)
        .unwrap_or(0);
    let total_tasks = info.get("total_tasks").and_then(Value::as_u64).unwrap_or(0);
    let mut repair = Repair::default();
    for path in existing_parquet_files(root, "meta/episodes")? {
        repair.episode_rows += keep_committed(root, &path, committed, None, false, &mut repair)?;
    }
    let schema = data_schema(&spec.features());
    for path in existing_parquet_files(root, "data")? {
        repair.data_rows +=
            keep_committed(root, &path, committed, Some(&schema), true, &mut repair)?;
    }
    let tasks_path = root.join("meta/tasks.parquet");
    if tasks_path.is_file() {
        let rel_tasks = "meta/tasks.parquet";
        let mut tasks: Vec<(i64, String)> = Vec::new();
        for batch in read_parquet(&tasks_path)? {
            let index = column::<Int64Array>(&batch, "task_index", rel_tasks)?;
            let text = column::<arrow::array::StringArray>(&batch, "__index_level_0__", rel_tasks)?;
            for r in 0..batch.num_rows() {
                tasks.push((index.value(r), text.value(r).to_owned()));
            }
        }
        if tasks.len() as u64 > total_tasks {
            tasks.sort();
            repair.tasks = tasks.len() as u64 - total_tasks;
            tasks.truncate(total_tasks as usize);
            if tasks.is_empty() {
                std::fs::remove_file(&tasks_path).map_err(DatasetError::io(&tasks_path))?;
                repair.files_removed.push(rel_tasks.to_owned());
            } else {
                let names: Vec<String> = tasks.into_iter().map(|t| t.1).collect();
                write_atomic(root, rel_tasks, &tasks_parquet(&names)?)?;
            }
        }
    }
    Ok(repair)
}
