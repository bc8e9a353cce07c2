//! Reading a dataset back: its metadata, and an episode's frames.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow::array::{
    Array, AsArray, BinaryArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array,
    ListArray, StringArray, StructArray,
};
use arrow::datatypes::{Float32Type, Int64Type};
use arrow::record_batch::RecordBatch;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde_json::Value;

use super::DatasetError;
use super::layout::{DatasetSpec, Dtype, Feature, data_file, video_file};
use super::stats::{FeatureStats, StatsKind};
use super::write::{EpisodeFrames, EpisodeSource, EpisodeVideoFile};

/// One row of `meta/episodes`.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeRow {
    /// `episode_index`.
    pub index: u64,
    /// `tasks`.
    pub tasks: Vec<String>,
    /// `length`.
    pub length: u64,
    /// `data/chunk_index`, `data/file_index`.
    pub data: (u64, u64),
    /// `dataset_from_index`.
    pub from: u64,
    /// `dataset_to_index`.
    pub to: u64,
    /// `meta/episodes/chunk_index`, `meta/episodes/file_index`.
    pub meta: (u64, u64),
    /// Per video feature: (key, `videos/KEY/chunk_index`, `file_index`, `from_timestamp`,
    /// `to_timestamp`); empty without videos.
    pub videos: Vec<EpisodeVideo>,
}

/// Where an episode's frames of one video feature are.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeVideo {
    /// The feature (`observation.images.ee_camera`).
    pub key: String,
    /// Chunk and file of its MP4 (`videos/KEY/chunk-CCC/file-FFF.mp4`).
    pub file: (u64, u64),
    /// The episode's first frame's timestamp in the file, s.
    pub from_timestamp: f64,
    /// One frame past its last, s.
    pub to_timestamp: f64,
    /// The episode's `stats/KEY/…` (of the frames before encoding), if its row has them.
    pub stats: Option<FeatureStats>,
}

/// A dataset opened for reading.
#[derive(Debug)]
pub struct DatasetReader {
    /// The root folder.
    pub root: PathBuf,
    /// `meta/info.json`.
    pub info: Value,
    /// What it records.
    pub spec: DatasetSpec,
    /// `total_episodes`.
    pub total_episodes: u64,
    /// `total_frames`.
    pub total_frames: u64,
    /// Tasks by index.
    pub tasks: Vec<String>,
    /// Rows of `meta/episodes`, in episode order.
    pub episodes: Vec<EpisodeRow>,
    /// `ambench.episodes`: where each episode came from.
    pub sources: Vec<Value>,
    /// `ambench.recording`.
    pub recording: Value,
    cache: Option<((u64, u64), Vec<RecordBatch>)>,
}

pub(crate) fn read_parquet(path: &Path) -> Result<Vec<RecordBatch>, DatasetError> {
    let file = std::fs::File::open(path).map_err(DatasetError::io(path))?;
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .and_then(|b| b.build())
        .map_err(DatasetError::parquet(path))?;
    reader
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| DatasetError::invalid(&path.display().to_string(), e.to_string()))
}

pub(crate) fn column<'a, T: 'static>(
    batch: &'a RecordBatch,
    name: &str,
    file: &str,
) -> Result<&'a T, DatasetError> {
    batch
        .column_by_name(name)
        .ok_or_else(|| DatasetError::invalid(file, format!("no column {name:?}")))?
        .as_any()
        .downcast_ref::<T>()
        .ok_or_else(|| DatasetError::invalid(file, format!("column {name:?} has another type")))
}

fn ints(batch: &RecordBatch, name: &str, file: &str) -> Result<Vec<u64>, DatasetError> {
    Ok(column::<Int64Array>(batch, name, file)?
        .values()
        .iter()
        .map(|v| *v as u64)
        .collect())
}

impl DatasetReader {
    /// Opens the dataset in `root`: `info.json`, the tasks, the episodes' rows.
    pub fn open(root: &Path) -> Result<Self, DatasetError> {
        let info_path = root.join("meta/info.json");
        let text = std::fs::read_to_string(&info_path).map_err(DatasetError::io(&info_path))?;
        let info: Value = serde_json::from_str(&text)
            .map_err(|e| DatasetError::invalid("meta/info.json", e.to_string()))?;
        let version = info.get("codebase_version").and_then(Value::as_str);
        if version != Some(super::layout::CODEBASE_VERSION) {
            return Err(DatasetError::invalid(
                "meta/info.json",
                format!("codebase_version {version:?}: amstack reads v3.0"),
            ));
        }
        let spec = DatasetSpec::from_info(&info, "meta/info.json")?;
        let total = |k: &str| info.get(k).and_then(Value::as_u64).unwrap_or(0);
        let ambench = info.get("ambench").cloned().unwrap_or(Value::Null);
        let mut reader = Self {
            root: root.to_owned(),
            spec,
            total_episodes: total("total_episodes"),
            total_frames: total("total_frames"),
            tasks: Vec::new(),
            episodes: Vec::new(),
            sources: ambench
                .get("episodes")
                .and_then(Value::as_array)
                .cloned()
                .unwrap_or_default(),
            recording: ambench.get("recording").cloned().unwrap_or(Value::Null),
            info,
            cache: None,
        };
        if reader.total_episodes == 0 {
            return Ok(reader);
        }
        reader.tasks = read_tasks(root)?;
        reader.episodes = read_episodes(root)?;
        if reader.spec.video {
            let keys: Vec<String> = reader.spec.images.iter().map(|i| i.0.clone()).collect();
            read_episode_videos(root, &keys, &mut reader.episodes)?;
        }
        Ok(reader)
    }

    /// The statistics of `stats.json` for `features` (None if missing or misshapen).
    pub fn stats_for(&self, features: &[Feature]) -> Option<Vec<FeatureStats>> {
        let text = std::fs::read_to_string(self.root.join("meta/stats.json")).ok()?;
        let all: Value = serde_json::from_str(&text).ok()?;
        features
            .iter()
            .map(|f| {
                let kind = match f.dtype {
                    Dtype::Image | Dtype::Video => StatsKind::Image,
                    Dtype::Int64 => StatsKind::Int,
                    Dtype::Float32 => StatsKind::Float,
                };
                FeatureStats::from_json(all.get(&f.key)?, kind)
            })
            .collect()
    }

    /// The batches of a data file (the last one read is kept).
    pub fn data_batches(&mut self, at: (u64, u64)) -> Result<&[RecordBatch], DatasetError> {
        if self.cache.as_ref().map(|c| c.0) != Some(at) {
            let batches = read_parquet(&self.root.join(data_file(at.0, at.1)))?;
            self.cache = Some((at, batches));
        }
        Ok(self.cache.as_ref().map_or(&[][..], |c| c.1.as_slice()))
    }

    /// Episode `e`'s frames (the rows of its data file with its `episode_index`, in order).
    pub fn episode(&mut self, e: u64) -> Result<EpisodeFrames, DatasetError> {
        let row = self
            .episodes
            .iter()
            .find(|r| r.index == e)
            .cloned()
            .ok_or_else(|| DatasetError::invalid("meta/episodes", format!("no episode {e}")))?;
        let file = data_file(row.data.0, row.data.1);
        let spec = self.spec.clone();
        let tasks = self.tasks.clone();
        let source = self.sources.get(e as usize).cloned().unwrap_or(Value::Null);
        let videos = self.episode_video_files(&row);
        let batches = self.data_batches(row.data)?;
        let mut out = EpisodeFrames {
            videos,
            images: vec![Vec::new(); spec.images.len()],
            source: EpisodeSource {
                task_name: source
                    .get("task")
                    .and_then(Value::as_str)
                    .unwrap_or_default()
                    .to_owned(),
                seed: source.get("seed").and_then(Value::as_u64),
                success: source
                    .get("success")
                    .and_then(Value::as_bool)
                    .unwrap_or(false),
                attempt: source.get("attempt").and_then(Value::as_u64).unwrap_or(e),
            },
            ..EpisodeFrames::default()
        };
        for batch in batches {
            let episode = column::<Int64Array>(batch, "episode_index", &file)?;
            let task = column::<Int64Array>(batch, "task_index", &file)?;
            let state = fixed_values(batch, "observation.state", &file)?;
            let action = fixed_values(batch, "action", &file)?;
            // A video dataset's frames are in its MP4 files, not here.
            let images = spec
                .images
                .iter()
                .filter(|_| !spec.video)
                .map(|(key, _, _)| image_bytes(batch, key, &file))
                .collect::<Result<Vec<_>, _>>()?;
            for r in 0..batch.num_rows() {
                if episode.value(r) as u64 != e {
                    continue;
                }
                if out.task.is_empty() {
                    out.task = tasks
                        .get(task.value(r) as usize)
                        .cloned()
                        .unwrap_or_default();
                }
                let sd = spec.state_dim;
                let ad = spec.action_dim;
                out.state.extend_from_slice(&state[r * sd..(r + 1) * sd]);
                out.action.extend_from_slice(&action[r * ad..(r + 1) * ad]);
                for (c, col) in images.iter().enumerate() {
                    out.images[c].push(col.value(r).to_vec());
                }
            }
        }
        if out.len(spec.state_dim) as u64 != row.length {
            return Err(DatasetError::invalid(
                &file,
                format!(
                    "episode {e}: {} frames, meta/episodes says {}",
                    out.len(spec.state_dim),
                    row.length
                ),
            ));
        }
        Ok(out)
    }
}

impl DatasetReader {
    /// A video dataset's episode: per camera of the spec, its MP4, where the episode starts in
    /// it, whether the file is the episode's alone (amstack writes one per episode; lerobot
    /// packs several), and its recorded statistics. Empty without videos.
    fn episode_video_files(&self, row: &EpisodeRow) -> Vec<EpisodeVideoFile> {
        if !self.spec.video {
            return Vec::new();
        }
        let fps = f64::from(self.spec.fps);
        self.spec
            .images
            .iter()
            .filter_map(|(key, _, _)| {
                let v = row.videos.iter().find(|v| v.key == *key)?;
                let shared = self.episodes.iter().any(|r| {
                    r.index != row.index
                        && r.videos.iter().any(|o| o.key == *key && o.file == v.file)
                });
                Some(EpisodeVideoFile {
                    path: self.root.join(video_file(key, v.file.0, v.file.1)),
                    from_frame: (v.from_timestamp * fps).round().max(0.0) as u64,
                    whole_file: !shared && v.from_timestamp == 0.0,
                    stats: v.stats.clone(),
                })
            })
            .collect()
    }
}

/// The float32 values of a fixed-size-list column, flat.
pub(crate) fn fixed_values<'a>(
    batch: &'a RecordBatch,
    name: &str,
    file: &str,
) -> Result<&'a [f32], DatasetError> {
    let list = column::<FixedSizeListArray>(batch, name, file)?;
    let values = list
        .values()
        .as_any()
        .downcast_ref::<Float32Array>()
        .ok_or_else(|| DatasetError::invalid(file, format!("{name}: not float32")))?;
    let offset = list.offset() * list.value_length() as usize;
    Ok(&values.values()[offset..offset + list.len() * list.value_length() as usize])
}

/// The `bytes` of an image column.
pub(crate) fn image_bytes<'a>(
    batch: &'a RecordBatch,
    name: &str,
    file: &str,
) -> Result<&'a BinaryArray, DatasetError> {
    let s = column::<StructArray>(batch, name, file)?;
    s.column_by_name("bytes")
        .and_then(|c| c.as_any().downcast_ref::<BinaryArray>())
        .ok_or_else(|| DatasetError::invalid(file, format!("{name}: no binary `bytes` field")))
}

fn read_tasks(root: &Path) -> Result<Vec<String>, DatasetError> {
    let rel = "meta/tasks.parquet";
    let mut by_index = BTreeMap::new();
    for batch in read_parquet(&root.join(rel))? {
        let index = column::<Int64Array>(&batch, "task_index", rel)?;
        let name = if batch.column_by_name("__index_level_0__").is_some() {
            "__index_level_0__"
        } else {
            "task"
        };
        let text = column::<StringArray>(&batch, name, rel)?;
        for r in 0..batch.num_rows() {
            by_index.insert(index.value(r), text.value(r).to_owned());
        }
    }
    let tasks: Vec<String> = by_index.values().cloned().collect();
    if by_index.keys().copied().ne(0..tasks.len() as i64) {
        return Err(DatasetError::invalid(
            rel,
            format!(
                "task_index values {:?} are not 0..{}",
                by_index.keys().collect::<Vec<_>>(),
                tasks.len()
            ),
        ));
    }
    Ok(tasks)
}

/// The parquet files in the chunk folders of `root/dir` (`chunk-CCC/file-FFF.parquet`), sorted.
pub(crate) fn parquet_files(root: &Path, dir: &str) -> Result<Vec<PathBuf>, DatasetError> {
    let mut files = Vec::new();
    let dir = root.join(dir);
    for chunk in std::fs::read_dir(&dir).map_err(DatasetError::io(&dir))? {
        let chunk = chunk.map_err(DatasetError::io(&dir))?.path();
        if chunk.is_dir() {
            for f in std::fs::read_dir(&chunk).map_err(DatasetError::io(&chunk))? {
                let f = f.map_err(DatasetError::io(&chunk))?.path();
                if f.extension().is_some_and(|e| e == "parquet") {
                    files.push(f);
                }
            }
        }
    }
    files.sort();
    Ok(files)
}

/// `path` relative to the dataset's `root`, for messages.
pub(crate) fn rel(root: &Path, path: &Path) -> String {
    path.strip_prefix(root)
        .unwrap_or(path)
        .display()
        .to_string()
}

fn read_episodes(root: &Path) -> Result<Vec<EpisodeRow>, DatasetError> {
    let files = parquet_files(root, "meta/episodes")?;
    let mut rows = Vec::new();
    for path in files {
        let rel = rel(root, &path);
        for batch in read_parquet(&path)? {
            let tasks = column::<ListArray>(&batch, "tasks", &rel)?;
            let index = ints(&batch, "episode_index", &rel)?;
            let length = ints(&batch, "length", &rel)?;
            let dc = ints(&batch, "data/chunk_index", &rel)?;
            let df = ints(&batch, "data/file_index", &rel)?;
            let from = ints(&batch, "dataset_from_index", &rel)?;
            let to = ints(&batch, "dataset_to_index", &rel)?;
            let mc = ints(&batch, "meta/episodes/chunk_index", &rel)?;
            let mf = ints(&batch, "meta/episodes/file_index", &rel)?;
            for r in 0..batch.num_rows() {
                let t = tasks.value(r);
                let t = t.as_string::<i32>();
                rows.push(EpisodeRow {
                    index: index[r],
                    tasks: (0..t.len()).map(|i| t.value(i).to_owned()).collect(),
                    length: length[r],
                    data: (dc[r], df[r]),
                    from: from[r],
                    to: to[r],
                    meta: (mc[r], mf[r]),
                    videos: Vec::new(),
                });
            }
        }
    }
    rows.sort_by_key(|r| r.index);
    Ok(rows)
}

/// The `videos/KEY/…` columns of the episodes files, into `rows` (sorted by index).
fn read_episode_videos(
    root: &Path,
    keys: &[String],
    rows: &mut [EpisodeRow],
) -> Result<(), DatasetError> {
    let files = parquet_files(root, "meta/episodes")?;
    for path in files {
        let rel = rel(root, &path);
        for batch in read_parquet(&path)? {
            let index = ints(&batch, "episode_index", &rel)?;
            for key in keys {
                let chunk = ints(&batch, &format!("videos/{key}/chunk_index"), &rel)?;
                let file = ints(&batch, &format!("videos/{key}/file_index"), &rel)?;
                let from =
                    column::<Float64Array>(&batch, &format!("videos/{key}/from_timestamp"), &rel)?;
                let to =
                    column::<Float64Array>(&batch, &format!("videos/{key}/to_timestamp"), &rel)?;
                let stats = video_stats(&batch, key);
                for r in 0..batch.num_rows() {
                    if let Some(row) = rows.iter_mut().find(|x| x.index == index[r]) {
                        row.videos.push(EpisodeVideo {
                            key: key.clone(),
                            file: (chunk[r], file[r]),
                            from_timestamp: from.value(r),
                            to_timestamp: to.value(r),
                            stats: stats.as_ref().map(|s| s[r].clone()),
                        });
                    }
                }
            }
        }
    }
    Ok(())
}

/// The `stats/KEY/…` columns of a batch of episode rows, per row (None if one is missing).
fn video_stats(batch: &RecordBatch, key: &str) -> Option<Vec<FeatureStats>> {
    let rows = |name: &str| -> Option<Vec<Vec<f64>>> {
        let list = batch
            .column_by_name(&format!("stats/{key}/{name}"))?
            .as_any()
            .downcast_ref::<ListArray>()?;
        Some(
            (0..list.len())
                .map(|r| {
                    let mut v = Vec::new();
                    flatten_array(list.value(r).as_ref(), &mut v);
                    v
                })
                .collect(),
        )
    };
    let (min, max, mean, std) = (rows("min")?, rows("max")?, rows("mean")?, rows("std")?);
    let count = rows("count")?;
    let quantiles = super::stats::QUANTILES
        .iter()
        .map(|(_, q)| rows(q))
        .collect::<Option<Vec<_>>>()?;
    (0..batch.num_rows())
        .map(|r| {
            Some(FeatureStats {
                min: min.get(r)?.clone(),
                max: max.get(r)?.clone(),
                mean: mean.get(r)?.clone(),
                std: std.get(r)?.clone(),
                count: *count.get(r)?.first()? as u64,
                quantiles: quantiles
                    .iter()
                    .map(|q| q.get(r).cloned())
                    .collect::<Option<Vec<_>>>()?,
                kind: StatsKind::Image,
            })
        })
        .collect()
}

/// Columns by name, each a list of rows of values.
pub(crate) type NamedRows = Vec<(String, Vec<Vec<f64>>)>;

/// The `stats/<feature>/<stat>` values of episode rows of an episodes file, flattened, by
/// column name (for the validator).
pub(crate) fn episode_stats_columns(root: &Path, rel: &str) -> Result<NamedRows, DatasetError> {
    let mut out: NamedRows = Vec::new();
    for batch in read_parquet(&root.join(rel))? {
        for (field, col) in batch.schema().fields().iter().zip(batch.columns()) {
            if !field.name().starts_with("stats/") {
                continue;
            }
            let mut rows = Vec::new();
            if let Some(list) = col.as_any().downcast_ref::<ListArray>() {
                for r in 0..list.len() {
                    let mut v = Vec::new();
                    flatten_array(list.value(r).as_ref(), &mut v);
                    rows.push(v);
                }
            }
            match out.iter_mut().find(|(n, _)| n == field.name()) {
                Some((_, all)) => all.extend(rows),
                None => out.push((field.name().clone(), rows)),
            }
        }
    }
    Ok(out)
}

fn flatten_array(a: &dyn Array, out: &mut Vec<f64>) {
    if let Some(l) = a.as_any().downcast_ref::<ListArray>() {
        for i in 0..l.len() {
            flatten_array(l.value(i).as_ref(), out);
        }
    } else if let Some(f) = a.as_primitive_opt::<arrow::datatypes::Float64Type>() {
        out.extend(f.values().iter());
    } else if let Some(i) = a.as_primitive_opt::<Int64Type>() {
        out.extend(i.values().iter().map(|x| *x as f64));
    } else if let Some(f) = a.as_primitive_opt::<Float32Type>() {
        out.extend(f.values().iter().map(|x| f64::from(*x)));
    }
}
