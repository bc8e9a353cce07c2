//! `amstack dataset validate`: every check of AMBENCH_SPEC §7.4 (state and action features,
//! positive totals and fps, Σ episode lengths = total frames = the data's rows, shapes of
//! the first and last frames) and the consistency of every index and statistic.

use std::collections::BTreeSet;
use std::path::Path;

use arrow::array::{FixedSizeListArray, Float32Array, Int64Array};

use super::layout::{Dtype, data_file, episodes_file, video_file};
use super::read::{
    DatasetReader, column, episode_stats_columns, fixed_values, image_bytes, read_parquet,
};
use super::stats::{FeatureStats, StatsKind};
use super::write::decode_png;

/// Relative tolerance of a recomputed mean or std against the stored one.
const STATS_RTOL: f64 = 1e-6;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= STATS_RTOL * (1.0 + a.abs().max(b.abs()))
}

/// The problems of the dataset in `root`, one line each (empty: valid).
pub fn validate(root: &Path) -> Vec<String> {
    let mut problems = Vec::new();
    let reader = match DatasetReader::open(root) {
        Ok(r) => r,
        Err(e) => return vec![e.to_string()],
    };
    let spec = reader.spec.clone();
    let features = spec.features();
    let fps = f64::from(spec.fps);
    if reader.total_episodes == 0 {
        problems.push("meta/info.json: total_episodes is 0".to_owned());
    }
    if reader.total_frames == 0 {
        problems.push("meta/info.json: total_frames is 0".to_owned());
    }
    let total_tasks = reader.info.get("total_tasks").and_then(|v| v.as_u64());
    if total_tasks != Some(reader.tasks.len() as u64) {
        problems.push(format!(
            "meta/info.json: total_tasks {total_tasks:?}, meta/tasks.parquet has {}",
            reader.tasks.len()
        ));
    }
    for f in &features {
        let stored = reader.info.get("features").and_then(|fs| fs.get(&f.key));
        match stored {
            None => problems.push(format!("meta/info.json: no feature {}", f.key)),
            Some(s) if s.get("dtype").and_then(|d| d.as_str()) != Some(f.dtype.name()) => {
                problems.push(format!(
                    "meta/info.json: features.{}.dtype is not {}",
                    f.key,
                    f.dtype.name()
                ));
            }
            Some(_) => {}
        }
    }
    // The episodes' rows.
    let rows = reader.episodes.clone();
    if rows.len() as u64 != reader.total_episodes {
        problems.push(format!(
            "meta/episodes: {} episodes, info.json says {}",
            rows.len(),
            reader.total_episodes
        ));
    }
    let mut to = 0;
    for (i, r) in rows.iter().enumerate() {
        let at = format!("meta/episodes: episode {}", r.index);
        if r.index != i as u64 {
            problems.push(format!("{at}: found at position {i}"));
        }
        if r.from != to {
            problems.push(format!(
                "{at}: dataset_from_index {} (expected {to})",
                r.from
            ));
        }
        if r.to != r.from + r.length {
            problems.push(format!(
                "{at}: dataset_to_index {} ≠ from {} + length {}",
                r.to, r.from, r.length
            ));
        }
        if r.length == 0 {
            problems.push(format!("{at}: length 0"));
        }
        if r.tasks.iter().any(|t| !reader.tasks.contains(t)) {
            problems.push(format!(
                "{at}: tasks {:?} not all in meta/tasks.parquet",
                r.tasks
            ));
        }
        to = r.to;
    }
    let sum: u64 = rows.iter().map(|r| r.length).sum();
    if sum != reader.total_frames {
        problems.push(format!(
            "meta/episodes: Σ length = {sum}, info.json total_frames = {}",
            reader.total_frames
        ));
    }
    // The data: every row against its episode, every value finite, images decodable.
    let files: BTreeSet<(u64, u64)> = rows.iter().map(|r| r.data).collect();
    let mut data_rows = 0u64;
    let mut values: Vec<Vec<f64>> = vec![Vec::new(); 2];
    let mut episode_values: Vec<(Vec<f64>, Vec<f64>)> = vec![(Vec::new(), Vec::new()); rows.len()];
    for at in files {
        let file = data_file(at.0, at.1);
        let batches = match read_parquet(&root.join(&file)) {
            Ok(b) => b,
            Err(e) => {
                problems.push(e.to_string());
                continue;
            }
        };
        for batch in &batches {
            let checked = (|| -> Result<(), super::DatasetError> {
                let index = column::<Int64Array>(batch, "index", &file)?;
                let episode = column::<Int64Array>(batch, "episode_index", &file)?;
                let frame = column::<Int64Array>(batch, "frame_index", &file)?;
                let task = column::<Int64Array>(batch, "task_index", &file)?;
                let ts = column::<Float32Array>(batch, "timestamp", &file)?;
                let widths = [spec.state_dim, spec.action_dim];
                let mut cols = Vec::new();
                for (key, dim) in ["observation.state", "action"].into_iter().zip(widths) {
                    let list = column::<FixedSizeListArray>(batch, key, &file)?;
                    if list.value_length() as usize != dim {
                        problems.push(format!(
                            "{file}: {key} has {} values per frame, info.json says {dim}",
                            list.value_length()
                        ));
                    }
                    cols.push(fixed_values(batch, key, &file)?);
                }
                // Videos are not in the data files (their checks are below).
                let images = spec
                    .images
                    .iter()
                    .filter(|_| !spec.video)
                    .map(|(k, h, w)| image_bytes(batch, k, &file).map(|c| (k, *h, *w, c)))
                    .collect::<Result<Vec<_>, _>>()?;
                for r in 0..batch.num_rows() {
                    data_rows += 1;
                    let i = index.value(r) as u64;
                    let e = episode.value(r) as u64;
                    let Some(row) = rows.get(e as usize) else {
                        problems.push(format!(
                            "{file}: row index {i}: episode {e} not in meta/episodes"
                        ));
                        continue;
                    };
                    if row.data != at {
                        problems.push(format!("{file}: row index {i}: episode {e} is in another file per meta/episodes"));
                    }
                    if !(row.from..row.to).contains(&i) {
                        problems.push(format!(
                            "{file}: row index {i} outside episode {e}'s [{}, {})",
                            row.from, row.to
                        ));
                        continue;
                    }
                    let k = frame.value(r) as u64;
                    if k != i - row.from {
                        problems.push(format!(
                            "{file}: row index {i}: frame_index {k}, expected {}",
                            i - row.from
                        ));
                    }
                    let t = ts.value(r);
                    if t != (k as f64 / fps) as f32 {
                        problems.push(format!(
                            "{file}: row index {i}: timestamp {t} ≠ frame_index / fps"
                        ));
                    }
                    let ti = task.value(r);
                    match reader.tasks.get(ti as usize) {
                        Some(name) if row.tasks.contains(name) => {}
                        _ => problems.push(format!("{file}: row index {i}: task_index {ti} is not one of episode {e}'s tasks")),
                    }
                    for (c, (col, dim)) in cols.iter().zip(widths).enumerate() {
                        let v = &col[r * dim..(r + 1) * dim];
                        if v.iter().any(|x| !x.is_finite()) {
                            problems.push(format!(
                                "{file}: row index {i}: non-finite value in {}",
                                ["observation.state", "action"][c]
                            ));
                        }
                        values[c].extend(v.iter().map(|x| f64::from(*x)));
                        let ev = &mut episode_values[e as usize];
                        if c == 0 {
                            ev.0.extend(v.iter().map(|x| f64::from(*x)));
                        } else {
                            ev.1.extend(v.iter().map(|x| f64::from(*x)));
                        }
                    }
                    if k == 0 || i + 1 == row.to {
                        for (key, h, w, col) in &images {
                            match decode_png(col.value(r)) {
                                Ok((ih, iw, _)) if (ih, iw) == (*h, *w) => {}
                                Ok((ih, iw, _)) => problems.push(format!("{file}: row index {i}: {key} is {ih}×{iw}, info.json says {h}×{w}")),
                                Err(e) => problems.push(format!("{file}: row index {i}: {key}: {e}")),
                            }
                        }
                    }
                }
                Ok(())
            })();
            if let Err(e) = checked {
                problems.push(e.to_string());
            }
        }
    }
    if data_rows != reader.total_frames {
        problems.push(format!(
            "data: {data_rows} rows, info.json total_frames = {}",
            reader.total_frames
        ));
    }
    // Statistics: the dataset's against the data, each episode's against its frames.
    let dims = [spec.state_dim, spec.action_dim];
    let stored = reader.stats_for(&features);
    match &stored {
        None => problems.push(
            "meta/stats.json: missing, or a feature's statistics are not shaped as lerobot's"
                .to_owned(),
        ),
        Some(stats) => {
            for (c, key) in ["observation.state", "action"].into_iter().enumerate() {
                let Some(s) = features
                    .iter()
                    .position(|f| f.key == key)
                    .map(|p| &stats[p])
                else {
                    continue;
                };
                let data = FeatureStats::of_rows(&values[c], dims[c], StatsKind::Float);
                compare(&mut problems, &format!("meta/stats.json: {key}"), s, &data);
            }
            for (f, s) in features.iter().zip(stats) {
                if matches!(f.dtype, Dtype::Image | Dtype::Video)
                    && (s.min.len() != 3
                        || s.min.iter().chain(&s.max).any(|x| !(0.0..=1.0).contains(x)))
                {
                    problems.push(format!(
                        "meta/stats.json: {}: not 3 channels in [0, 1]",
                        f.key
                    ));
                }
            }
        }
    }
    // Video features: every episode's file is there and its span is its frames.
    if spec.video {
        for r in &rows {
            for (key, _, _) in &spec.images {
                let Some(v) = r.videos.iter().find(|v| v.key == *key) else {
                    problems.push(format!(
                        "meta/episodes: episode {}: no videos/{key} columns",
                        r.index
                    ));
                    continue;
                };
                let file = video_file(key, v.file.0, v.file.1);
                if !root.join(&file).is_file() {
                    problems.push(format!(
                        "meta/episodes: episode {}: {file} is missing",
                        r.index
                    ));
                }
                let span = v.to_timestamp - v.from_timestamp;
                let expected = r.length as f64 / fps;
                if v.from_timestamp < 0.0 || (span - expected).abs() > 1e-9 * (1.0 + expected) {
                    problems.push(format!(
                        "meta/episodes: episode {}: videos/{key} spans {}..{} s, its {} frames take {expected} s",
                        r.index, v.from_timestamp, v.to_timestamp, r.length
                    ));
                }
            }
        }
    }
    let meta_files: BTreeSet<(u64, u64)> = rows.iter().map(|r| r.meta).collect();
    let mut columns: super::read::NamedRows = Vec::new();
    for (c, f) in meta_files {
        match episode_stats_columns(root, &episodes_file(c, f)) {
            Ok(cols) => {
                for (name, v) in cols {
                    match columns.iter_mut().find(|(n, _)| *n == name) {
                        Some((_, all)) => all.extend(v),
                        None => columns.push((name, v)),
                    }
                }
            }
            Err(e) => problems.push(e.to_string()),
        }
    }
    for f in &features {
        for stat in [
            "min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99",
        ] {
            let name = format!("stats/{}/{stat}", f.key);
            if !columns.iter().any(|(n, _)| *n == name) {
                problems.push(format!("meta/episodes: no column {name}"));
            }
        }
    }
    let get = |name: &str, e: usize| -> Option<Vec<f64>> {
        columns
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, v)| v.get(e).cloned())
    };
    for (e, (state, action)) in episode_values.iter().enumerate() {
        for (key, v, dim) in [
            ("observation.state", state, dims[0]),
            ("action", action, dims[1]),
        ] {
            if v.is_empty() {
                continue;
            }
            let data = FeatureStats::of_rows(v, dim, StatsKind::Float);
            let stored = (|| {
                Some(FeatureStats {
                    min: get(&format!("stats/{key}/min"), e)?,
                    max: get(&format!("stats/{key}/max"), e)?,
                    mean: get(&format!("stats/{key}/mean"), e)?,
                    std: get(&format!("stats/{key}/std"), e)?,
                    count: get(&format!("stats/{key}/count"), e)?
                        .first()
                        .map(|c| *c as u64)?,
                    quantiles: Vec::new(),
                    kind: StatsKind::Float,
                })
            })();
            match stored {
                Some(s) => compare(
                    &mut problems,
                    &format!("meta/episodes: episode {e}: stats of {key}"),
                    &s,
                    &data,
                ),
                None => problems.push(format!("meta/episodes: episode {e}: no stats of {key}")),
            }
        }
    }
    problems
}

fn compare(problems: &mut Vec<String>, at: &str, stored: &FeatureStats, data: &FeatureStats) {
    if stored.count != data.count {
        problems.push(format!(
            "{at}: count {} ≠ {} frames",
            stored.count, data.count
        ));
    }
    for (name, s, d) in [
        ("min", &stored.min, &data.min),
        ("max", &stored.max, &data.max),
        ("mean", &stored.mean, &data.mean),
        ("std", &stored.std, &data.std),
    ] {
        if s.len() != d.len() {
            problems.push(format!(
                "{at}: {name} has {} values, the feature {}",
                s.len(),
                d.len()
            ));
        } else if let Some(i) = (0..s.len()).find(|&i| !close(s[i], d[i])) {
            problems.push(format!(
                "{at}: {name}[{i}] = {} but the data give {}",
                s[i], d[i]
            ));
        }
    }
}
