//! Sharded recordings (`amstack record --shard I/N`) and their merge into the dataset the
//! unsharded recording writes.
//!
//! A recording's attempts are numbered `0, 1, 2, …` (attempt `a` flies rollout seed
//! `seed + a`); the unsharded run decides them in order and keeps the successful ones (every
//! one with `--save-failed`) until it holds `episodes`, or `max_attempts` were made. Shard
//! `i` of `n` flies only the attempts `a` with `a mod n = i`, in order, and keeps its own
//! episodes until it holds its quota (by default ⌈episodes / n⌉). Its dataset is a valid
//! dataset of its own; `info.json` `ambench.shard` says which shard it is, of which run, and
//! what became of every attempt it decided (success, saved).
//!
//! The merge walks the run's attempts `0, 1, 2, …` in order, each from its shard, and takes
//! the saved ones until the run's `episodes` — exactly the episodes, in the order, the
//! unsharded run keeps — and writes them with the same writer: the same bytes. An attempt the
//! walk needs that its shard did not decide (a shard whose quota was too small because the
//! task fails often) is refused naming the shard to run on.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use super::DatasetError;
use super::read::DatasetReader;
use super::write::DatasetWriter;
use crate::bench::first_difference;

/// The assignment of a recording's attempts to shards, as every shard records it.
pub const RECORD_SHARD_ASSIGNMENT: &str = "attempt a (seed = run seed + a) belongs to shard \
                                           a mod n; each shard decides its attempts in order";

/// What became of one attempt a shard decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecidedAttempt {
    /// The attempt (its rollout seed is the run seed + it).
    pub attempt: u64,
    /// Whether the task succeeded.
    pub success: bool,
    /// Whether its episode is in the shard's dataset.
    pub saved: bool,
}

/// A shard of a recording (`info.json` `ambench.shard`).
#[derive(Debug, Clone, PartialEq)]
pub struct ShardPart {
    /// This shard, `0..count`.
    pub index: u64,
    /// Shards of the run.
    pub count: u64,
    /// What every shard of the run shares beyond `ambench.recording`: `episodes`,
    /// `max_attempts`, `save_failed`.
    pub run: Value,
    /// Every attempt decided, in order.
    pub attempts: Vec<DecidedAttempt>,
}

impl ShardPart {
    /// Shard `index` of `count` of the run `run`, nothing decided yet.
    pub fn new(index: u64, count: u64, run: Value) -> Self {
        Self {
            index,
            count,
            run,
            attempts: Vec::new(),
        }
    }

    /// Its `info.json` block.
    pub fn to_json(&self) -> Value {
        json!({
            "index": self.index,
            "count": self.count,
            "assignment": RECORD_SHARD_ASSIGNMENT,
            "run": self.run,
            "attempts": self.attempts.iter().map(|a| json!({
                "attempt": a.attempt, "success": a.success, "saved": a.saved,
            })).collect::<Vec<_>>(),
        })
    }

    /// Reads the block back (None: not a shard; Err: a block that is not one).
    pub fn from_info(info: &Value) -> Result<Option<Self>, DatasetError> {
        let Some(block) = info.get("ambench").and_then(|a| a.get("shard")) else {
            return Ok(None);
        };
        let bad =
            |what: &str| DatasetError::invalid("meta/info.json", format!("ambench.shard.{what}"));
        let number = |k: &str| {
            block
                .get(k)
                .and_then(Value::as_u64)
                .ok_or_else(|| bad(&format!("{k} is not a number")))
        };
        let (index, count) = (number("index")?, number("count")?);
        if count == 0 || index >= count {
            return Err(bad(&format!("index {index} of count {count}: not a shard")));
        }
        let attempts = block
            .get("attempts")
            .and_then(Value::as_array)
            .ok_or_else(|| bad("attempts is not a list"))?
            .iter()
            .map(|a| {
                Some(DecidedAttempt {
                    attempt: a.get("attempt")?.as_u64()?,
                    success: a.get("success")?.as_bool()?,
                    saved: a.get("saved")?.as_bool()?,
                })
            })
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| bad("attempts: an entry without attempt, success and saved"))?;
        Ok(Some(Self {
            index,
            count,
            run: block.get("run").cloned().unwrap_or(Value::Null),
            attempts,
        }))
    }

    /// The attempt this shard decides next (its first, or the one after its last decided).
    pub fn next_attempt(&self) -> u64 {
        self.attempts
            .last()
            .map_or(self.index, |a| a.attempt + self.count)
    }

    /// Episodes saved.
    pub fn saved(&self) -> u64 {
        self.attempts.iter().filter(|a| a.saved).count() as u64
    }
}

/// What a merge of shards wrote.
#[derive(Debug)]
pub struct ShardMerge {
    /// The merged dataset.
    pub writer: DatasetWriter,
    /// The run's episodes (from each part's `run.episodes`).
    pub wanted: u64,
    /// Attempts the unsharded run decided (walked by the merge).
    pub attempts: u64,
    /// Episodes the parts hold that the unsharded run does not keep (past its last one).
    pub extra: u64,
}

struct Part {
    dir: PathBuf,
    reader: DatasetReader,
    shard: ShardPart,
    /// Saved attempt → episode index in the part.
    episodes: BTreeMap<u64, u64>,
    /// Attempt → (success, saved).
    decided: BTreeMap<u64, (bool, bool)>,
}

fn shown(dir: &Path) -> String {
    dir.join("meta/info.json").display().to_string()
}

fn open_part(dir: &Path) -> Result<Part, DatasetError> {
    let reader = DatasetReader::open(dir)?;
    let shard = ShardPart::from_info(&reader.info)?.ok_or_else(|| {
        DatasetError::invalid(
            &shown(dir),
            "not a shard of a recording (no ambench.shard): merge the shards of one recording \
             first, then merge datasets",
        )
    })?;
    let mut decided = BTreeMap::new();
    let mut previous: Option<u64> = None;
    for a in &shard.attempts {
        if a.attempt % shard.count != shard.index {
            return Err(DatasetError::invalid(
                &shown(dir),
                format!(
                    "ambench.shard: attempt {} is not shard {}/{}'s",
                    a.attempt, shard.index, shard.count
                ),
            ));
        }
        if previous.is_some_and(|p| a.attempt != p + shard.count)
            || (previous.is_none() && a.attempt != shard.index)
        {
            return Err(DatasetError::invalid(
                &shown(dir),
                format!(
                    "ambench.shard: attempt {} decided out of order (after {previous:?})",
                    a.attempt
                ),
            ));
        }
        previous = Some(a.attempt);
        decided.insert(a.attempt, (a.success, a.saved));
    }
    let mut episodes = BTreeMap::new();
    for (e, source) in reader.sources.iter().enumerate() {
        let attempt = source.get("attempt").and_then(Value::as_u64);
        match attempt.and_then(|a| decided.get(&a).map(|d| (a, d))) {
            Some((a, (_, true))) => {
                episodes.insert(a, e as u64);
            }
            _ => {
                return Err(DatasetError::invalid(
                    &shown(dir),
                    format!(
                        "episode {e} (attempt {attempt:?}) is not a saved attempt of ambench.shard"
                    ),
                ));
            }
        }
    }
    if episodes.len() as u64 != shard.saved() || reader.total_episodes != shard.saved() {
        return Err(DatasetError::invalid(
            &shown(dir),
            format!(
                "{} episodes, ambench.shard says {} were saved",
                reader.total_episodes,
                shard.saved()
            ),
        ));
    }
    Ok(Part {
        dir: dir.to_owned(),
        reader,
        shard,
        episodes,
        decided,
    })
}

/// Whether the dataset in `dir` is a shard of a recording.
pub fn is_shard(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join("meta/info.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .is_some_and(|info| info.get("ambench").and_then(|a| a.get("shard")).is_some())
}

/// Merges the shards in `parts` (any order) into the dataset the unsharded recording
/// writes, at `out`; checks first that they are the shards of one run (same recording, run
/// and features; the first field that differs is named), of one split, each once, and that
/// together they decided every attempt the unsharded run decides. `progress` sees each
/// episode written.
pub fn merge_shards(
    parts: &[PathBuf],
    out: &Path,
    progress: &mut dyn FnMut(u64),
) -> Result<ShardMerge, DatasetError> {
    let mut parts: Vec<Part> = parts
        .iter()
        .map(|p| open_part(p))
        .collect::<Result<_, _>>()?;
    let Some(first) = parts.first() else {
        return Err(DatasetError::invalid("merge", "no shard to merge"));
    };
    let count = first.shard.count;
    for p in &parts[1..] {
        let differs = first_difference(
            &first.reader.recording,
            &p.reader.recording,
            "ambench.recording",
        )
        .or_else(|| first_difference(&first.shard.run, &p.shard.run, "ambench.shard.run"));
        if let Some((field, a, b)) = differs {
            return Err(DatasetError::invalid(
                &shown(&p.dir),
                format!(
                    "shards of different recordings: {} has {field} = {a}, this one {b}",
                    first.dir.display()
                ),
            ));
        }
        if p.reader.spec != first.reader.spec {
            return Err(DatasetError::invalid(
                &shown(&p.dir),
                format!("its features differ from {}'s", first.dir.display()),
            ));
        }
        if p.shard.count != count {
            return Err(DatasetError::invalid(
                &shown(&p.dir),
                format!(
                    "shards of different splits: this is shard {}/{}, {} is shard {}/{count}",
                    p.shard.index,
                    p.shard.count,
                    first.dir.display(),
                    first.shard.index
                ),
            ));
        }
    }
    let mut by_index: Vec<Option<usize>> = vec![None; count as usize];
    for (i, p) in parts.iter().enumerate() {
        if let Some(other) = by_index[p.shard.index as usize] {
            return Err(DatasetError::invalid(
                &shown(&p.dir),
                format!(
                    "shard {}/{count} given twice: {} and {}",
                    p.shard.index,
                    parts[other].dir.display(),
                    p.dir.display()
                ),
            ));
        }
        by_index[p.shard.index as usize] = Some(i);
    }
    let missing: Vec<String> = (0..count)
        .filter(|i| by_index[*i as usize].is_none())
        .map(|i| format!("{i}/{count}"))
        .collect();
    if !missing.is_empty() {
        return Err(DatasetError::invalid(
            "merge",
            format!(
                "shard {} missing (have {} of {count}): record it with `amstack record ... --shard {}` and merge again",
                missing.join(", "),
                parts.len(),
                missing[0]
            ),
        ));
    }
    let run = first.shard.run.clone();
    let number = |k: &str| {
        run.get(k).and_then(Value::as_u64).ok_or_else(|| {
            DatasetError::invalid(
                &shown(&first.dir),
                format!("ambench.shard.run.{k} is not a number"),
            )
        })
    };
    let (wanted, max_attempts) = (number("episodes")?, number("max_attempts")?);
    // The unsharded run's walk: attempts in order, each from its shard.
    let mut taken: Vec<(usize, u64)> = Vec::new();
    let mut attempt = 0;
    while (taken.len() as u64) < wanted && attempt < max_attempts {
        let i = by_index[(attempt % count) as usize].unwrap_or(0);
        let p = &parts[i];
        match p.decided.get(&attempt) {
            Some((_, true)) => taken.push((i, p.episodes[&attempt])),
            Some((_, false)) => {}
            None => {
                let have = p.shard.saved();
                let more = (wanted - taken.len() as u64).div_ceil(count).max(1);
                return Err(DatasetError::invalid(
                    &shown(&p.dir),
                    format!(
                        "shard {}/{count} decided its attempts up to {} ({have} episodes), the run's \
                         episode {} needs its attempt {attempt}: run it on with `amstack record ... \
                         --shard {}/{count} --resume --shard-episodes {}` and merge again",
                        p.shard.index,
                        p.shard
                            .attempts
                            .last()
                            .map_or("none".to_owned(), |a| a.attempt.to_string()),
                        taken.len(),
                        p.shard.index,
                        have + more
                    ),
                ));
            }
        }
        attempt += 1;
    }
    let held: u64 = parts.iter().map(|p| p.shard.saved()).sum();
    let recording = first.reader.recording.clone();
    let spec = first.reader.spec.clone();
    let mut writer = DatasetWriter::create(out, spec, recording)?;
    for (i, e) in &taken {
        let frames = parts[*i].reader.episode(*e)?;
        writer.write_episode(frames)?;
        progress(writer.episodes());
    }
    Ok(ShardMerge {
        writer,
        wanted,
        attempts: attempt,
        extra: held - taken.len() as u64,
    })
}
