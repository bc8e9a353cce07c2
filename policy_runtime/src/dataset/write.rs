//! The dataset writer: episodes appended whole, every file replaced atomically.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{
    Array, ArrayRef, BinaryArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array,
    ListArray, StringArray, StructArray,
};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::{DataType, Field, Fields, Schema};
use arrow::record_batch::RecordBatch;
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::WriterProperties;
use serde_json::{Value, json};

use super::DatasetError;
use super::json::J;
use super::layout::{
    CHUNKS_SIZE, CODEBASE_VERSION, DATA_FILES_SIZE_IN_MB, DATA_PATH, DatasetSpec, Dtype, Feature,
    VIDEO_FILES_SIZE_IN_MB, VIDEO_PATH, data_file, episodes_file, next_file, video_file,
};
use super::read::DatasetReader;
use super::repair::{Repair, drop_uncommitted};
use super::shard::{DecidedAttempt, ShardPart};
use super::stats::{FeatureStats, QUANTILES, StatsKind, sample_indices};
use super::video::{copy_video, encode_episode};

/// One episode's frames, as recorded.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodeFrames {
    /// The task's prompt.
    pub task: String,
    /// `observation.state` of every frame, row-major (frames × state_dim).
    pub state: Vec<f32>,
    /// `action` of every frame, row-major (frames × action_dim).
    pub action: Vec<f32>,
    /// Per camera of the spec, in its order: every frame's PNG.
    pub images: Vec<Vec<Vec<u8>>>,
    /// Per camera: the decoded RGB8 frames at [`sample_indices`] of the episode's length, for
    /// the statistics (filled by [`EpisodeFrames::finish_images`] if empty).
    pub sampled_rgb: Vec<Vec<Vec<u8>>>,
    /// Where the episode came from.
    pub source: EpisodeSource,
    /// An episode of a video dataset read back: per camera of the spec, its MP4 (`images`
    /// then stays empty; a merge copies the file, an export decodes it).
    pub videos: Vec<EpisodeVideoFile>,
}

/// Where an episode of a video dataset has one camera's frames.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeVideoFile {
    /// The MP4.
    pub path: PathBuf,
    /// The episode's first frame in it (`from_timestamp` · fps).
    pub from_frame: u64,
    /// Whether the file is this episode's alone, from its start (amstack writes one file per
    /// episode; lerobot's writer packs several into one).
    pub whole_file: bool,
    /// The camera's statistics for the episode as recorded (of its frames before encoding).
    pub stats: Option<FeatureStats>,
}

/// Where an episode came from (`info.json` `ambench.episodes`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodeSource {
    /// The task's name (`press-button`).
    pub task_name: String,
    /// The rollout seed.
    pub seed: Option<u64>,
    /// Whether the task's success criterion held.
    pub success: bool,
    /// The recording's attempt that made it (seed = run seed + attempt).
    pub attempt: u64,
}

impl EpisodeFrames {
    /// Frames, from the state's width.
    pub fn len(&self, state_dim: usize) -> usize {
        self.state.len().checked_div(state_dim).unwrap_or(0)
    }

    /// Decodes the sampled frames of every camera from its PNGs (when not given).
    pub fn finish_images(&mut self, state_dim: usize) -> Result<(), DatasetError> {
        if self.sampled_rgb.len() == self.images.len() || !self.videos.is_empty() {
            return Ok(());
        }
        let idx = sample_indices(self.len(state_dim));
        self.sampled_rgb = self
            .images
            .iter()
            .map(|frames| {
                idx.iter()
                    .map(|&i| decode_png(frames.get(i).map_or(&[][..], Vec::as_slice)).map(|d| d.2))
                    .collect::<Result<Vec<_>, _>>()
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(())
    }
}

/// Decodes a PNG to (height, width, RGB8 bytes).
pub fn decode_png(bytes: &[u8]) -> Result<(usize, usize, Vec<u8>), DatasetError> {
    let bad = |e: png::DecodingError| DatasetError::invalid("image", format!("PNG: {e}"));
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .map_err(bad)?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    if info.color_type != png::ColorType::Rgb || info.bit_depth != png::BitDepth::Eight {
        return Err(DatasetError::invalid(
            "image",
            format!(
                "PNG is {:?} {:?}, not RGB8",
                info.color_type, info.bit_depth
            ),
        ));
    }
    buf.truncate(info.buffer_size());
    Ok((info.height as usize, info.width as usize, buf))
}

/// Encodes RGB8 to PNG (fixed settings: the same pixels give the same bytes).
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, DatasetError> {
    let mut out = Vec::new();
    let bad = |e: png::EncodingError| DatasetError::invalid("image", format!("PNG: {e}"));
    {
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::Fast);
        let mut writer = encoder.write_header().map_err(bad)?;
        writer.write_image_data(rgb).map_err(bad)?;
    }
    Ok(out)
}

/// One row of `meta/episodes` being written.
#[derive(Debug, Clone)]
struct EpisodeMeta {
    index: u64,
    tasks: Vec<String>,
    length: u64,
    data: (u64, u64),
    from: u64,
    stats: Vec<FeatureStats>,
    meta: (u64, u64),
    /// Its video files' (chunk, file), with `record --video`.
    video: Option<(u64, u64)>,
}

/// The data file being filled.
#[derive(Debug)]
struct OpenData {
    chunk: u64,
    file: u64,
    batches: Vec<RecordBatch>,
    frames: u64,
    bytes: u64,
}

/// Writes a dataset, an episode at a time.
#[derive(Debug)]
pub struct DatasetWriter {
    root: PathBuf,
    spec: DatasetSpec,
    features: Vec<Feature>,
    schema: Arc<Schema>,
    total_episodes: u64,
    total_frames: u64,
    tasks: Vec<String>,
    stats: Option<Vec<FeatureStats>>,
    data: Option<OpenData>,
    next_data: (u64, u64),
    meta_rows: Vec<EpisodeMeta>,
    meta_file: (u64, u64),
    sources: Vec<Value>,
    recording: Value,
    data_file_limit_bytes: u64,
    shard: Option<ShardPart>,
    repaired: Repair,
    ffmpeg: Option<PathBuf>,
    next_video: (u64, u64),
}

impl DatasetWriter {
    /// A new dataset in `root` (created; it must not hold a dataset), described by `spec`;
    /// `recording` goes to `info.json` as `ambench.recording` (what made it). Writes the
    /// empty dataset's `info.json`.
    pub fn create(root: &Path, spec: DatasetSpec, recording: Value) -> Result<Self, DatasetError> {
        std::fs::create_dir_all(root.join("meta")).map_err(DatasetError::io(root))?;
        let features = spec.features();
        let writer = Self {
            root: root.to_owned(),
            schema: data_schema(&features),
            features,
            spec,
            total_episodes: 0,
            total_frames: 0,
            tasks: Vec::new(),
            stats: None,
            data: None,
            next_data: (0, 0),
            meta_rows: Vec::new(),
            meta_file: (0, 0),
            sources: Vec::new(),
            recording,
            data_file_limit_bytes: DATA_FILES_SIZE_IN_MB * 1024 * 1024,
            shard: None,
            repaired: Repair::default(),
            ffmpeg: None,
            next_video: (0, 0),
        };
        writer.write_info()?;
        Ok(writer)
    }

    /// Makes the new dataset a shard of a recording (`info.json` `ambench.shard`): every
    /// attempt [`DatasetWriter::decide`]s is noted in it, saved or not.
    pub fn with_shard(mut self, shard: ShardPart) -> Result<Self, DatasetError> {
        self.shard = Some(shard);
        self.write_info()?;
        Ok(self)
    }

    /// The shard this dataset is (None: a whole recording).
    pub fn shard(&self) -> Option<&ShardPart> {
        self.shard.as_ref()
    }

    /// Decides an attempt: writes its episode if `episode` is given (see
    /// [`DatasetWriter::write_episode`]); a shard also notes the attempt, saved or not.
    /// Returns whether the episode was written.
    pub fn decide(
        &mut self,
        attempt: u64,
        success: bool,
        episode: Option<EpisodeFrames>,
    ) -> Result<bool, DatasetError> {
        let saved = episode.is_some();
        if let Some(shard) = &mut self.shard {
            shard.attempts.push(DecidedAttempt {
                attempt,
                success,
                saved,
            });
        }
        let written = match episode {
            Some(e) => self.write_episode(e),
            None if self.shard.is_some() => self.write_info(),
            None => Ok(()),
        };
        if let (Err(_), Some(shard)) = (&written, &mut self.shard) {
            shard.attempts.pop();
        }
        written.map(|()| saved)
    }

    /// Opens the dataset in `root` to append after its last complete episode (lerobot's
    /// resume: new episodes go to a new data file and a new episodes file). `spec` must be
    /// the dataset's. What a run that died mid-episode left uncommitted (rows, files, a
    /// task, statistics: see [`DatasetWriter::repaired`]) is dropped first.
    pub fn resume(root: &Path, spec: DatasetSpec) -> Result<Self, DatasetError> {
        // Another recording's dataset is refused before anything in it is touched.
        if let Ok(reader) = DatasetReader::open(root)
            && reader.spec != spec
        {
            return Err(Self::other_spec(&reader.spec, &spec));
        }
        let repaired = drop_uncommitted(root)?;
        let reader = DatasetReader::open(root)?;
        if reader.spec != spec {
            return Err(Self::other_spec(&reader.spec, &spec));
        }
        let features = spec.features();
        let stats = reader.stats_for(&features);
        let shard = ShardPart::from_info(&reader.info)?;
        let last = reader.episodes.last();
        let next_data = last.map_or((0, 0), |e| next_file(e.data.0, e.data.1));
        let meta_file = last.map_or((0, 0), |e| next_file(e.meta.0, e.meta.1));
        let mut writer = Self {
            root: root.to_owned(),
            schema: data_schema(&features),
            features,
            spec,
            total_episodes: reader.total_episodes,
            total_frames: reader.total_frames,
            tasks: reader.tasks.clone(),
            stats,
            data: None,
            next_data,
            meta_rows: Vec::new(),
            meta_file,
            sources: reader.sources.clone(),
            recording: reader.recording.clone(),
            data_file_limit_bytes: DATA_FILES_SIZE_IN_MB * 1024 * 1024,
            shard,
            repaired,
            ffmpeg: None,
            next_video: last
                .and_then(|e| e.videos.first())
                .map_or((0, 0), |v| next_file(v.file.0, v.file.1)),
        };
        if writer.repaired.stats_suspect() {
            writer.recompute_stats(reader)?;
        }
        Ok(writer)
    }

    /// The ffmpeg program that encodes the videos of a video dataset (`record --video`).
    #[must_use]
    pub fn with_ffmpeg(mut self, program: PathBuf) -> Self {
        self.ffmpeg = Some(program);
        self
    }

    /// What [`DatasetWriter::resume`] dropped (nothing: the last run ended cleanly).
    pub fn repaired(&self) -> &Repair {
        &self.repaired
    }

    /// `stats.json` again from the committed episodes, folded in order as they were written.
    fn recompute_stats(&mut self, mut reader: DatasetReader) -> Result<(), DatasetError> {
        let mut all: Option<Vec<FeatureStats>> = None;
        let rows = reader.episodes.clone();
        for row in &rows {
            let mut frames = reader.episode(row.index)?;
            frames.finish_images(self.spec.state_dim)?;
            let len = frames.len(self.spec.state_dim);
            let task_index = self
                .tasks
                .iter()
                .position(|t| *t == frames.task)
                .unwrap_or(0) as i64;
            let stats = self.episode_stats(&frames, len, row.index, row.from, task_index);
            all = Some(with_episode_stats(all.as_deref(), stats));
        }
        if let Some(all) = &all {
            write_atomic(
                &self.root,
                "meta/stats.json",
                &self.stats_json(all).pretty(),
            )?;
        }
        self.stats = all;
        Ok(())
    }

    fn other_spec(had: &DatasetSpec, spec: &DatasetSpec) -> DatasetError {
        DatasetError::invalid(
            "meta/info.json",
            format!(
                "the dataset records {} (state {:?}, action {}, images {:?}); this recording \
                     would add {} (state {:?}, action {}, images {:?})",
                had.robot_type,
                had.state_keys,
                had.action_semantics.name(),
                had.images.iter().map(|i| &i.0).collect::<Vec<_>>(),
                spec.robot_type,
                spec.state_keys,
                spec.action_semantics.name(),
                spec.images.iter().map(|i| &i.0).collect::<Vec<_>>(),
            ),
        )
    }

    /// Sets the size past which a data file is closed (tests: small files).
    pub fn with_data_file_limit_bytes(mut self, bytes: u64) -> Self {
        self.data_file_limit_bytes = bytes.max(1);
        self
    }

    /// Episodes written.
    pub fn episodes(&self) -> u64 {
        self.total_episodes
    }

    /// Frames written.
    pub fn frames(&self) -> u64 {
        self.total_frames
    }

    /// One past the last attempt of the episodes written (where a resumed recording goes on);
    /// a shard: its attempt after the last it decided.
    pub fn next_attempt(&self) -> u64 {
        if let Some(shard) = &self.shard {
            return shard.next_attempt();
        }
        self.sources
            .iter()
            .filter_map(|s| s.get("attempt").and_then(Value::as_u64))
            .max()
            .map_or(0, |a| a + 1)
    }

    /// The spec.
    pub fn spec(&self) -> &DatasetSpec {
        &self.spec
    }

    /// Appends one episode, whole: its frames to the data file, then its row to
    /// `meta/episodes`, the tasks, the statistics and `info.json`, each file replaced
    /// atomically (temporary file, fsync, rename).
    pub fn write_episode(&mut self, mut episode: EpisodeFrames) -> Result<(), DatasetError> {
        let index = self.total_episodes;
        let bad = |what: String| DatasetError::Episode {
            episode: index,
            what,
        };
        let len = episode.len(self.spec.state_dim);
        if len == 0 {
            return Err(bad("no frame".into()));
        }
        if episode.state.len() != len * self.spec.state_dim
            || episode.action.len() != len * self.spec.action_dim
        {
            return Err(bad(format!(
                "{} state values and {} action values for {len} frames of {} and {}",
                episode.state.len(),
                episode.action.len(),
                self.spec.state_dim,
                self.spec.action_dim
            )));
        }
        let from_videos = !episode.videos.is_empty();
        if from_videos {
            if !self.spec.video || episode.videos.len() != self.spec.images.len() {
                return Err(bad(format!(
                    "videos of {} cameras for the dataset's {} {}",
                    episode.videos.len(),
                    self.spec.images.len(),
                    if self.spec.video { "videos" } else { "images" }
                )));
            }
            for v in &episode.videos {
                if !v.whole_file {
                    return Err(bad(format!(
                        "{} holds other episodes too (lerobot's packed layout): amstack copies \
                         one file per episode and does not re-encode",
                        v.path.display()
                    )));
                }
                if v.stats.is_none() {
                    return Err(bad(format!(
                        "{}: its episode row has no statistics of the video",
                        v.path.display()
                    )));
                }
            }
        } else if episode.images.len() != self.spec.images.len()
            || episode.images.iter().any(|c| c.len() != len)
        {
            return Err(bad(format!(
                "images of {} cameras for the dataset's {}, or not one per frame",
                episode.images.len(),
                self.spec.images.len()
            )));
        }
        episode.finish_images(self.spec.state_dim)?;
        let task_index = match self.tasks.iter().position(|t| *t == episode.task) {
            Some(i) => i,
            None => {
                self.tasks.push(episode.task.clone());
                self.tasks.len() - 1
            }
        } as i64;
        let from = self.total_frames;
        let batch = self.episode_batch(&episode, len, index, from, task_index)?;
        let stats = self.episode_stats(&episode, len, index, from, task_index);

        // A video dataset's camera streams first: one MP4 per camera (not counted until the
        // metadata says so).
        let video_at = if self.spec.video && !from_videos {
            let ffmpeg = self.ffmpeg.clone().ok_or_else(|| {
                bad("a video dataset needs the ffmpeg program to encode its cameras".into())
            })?;
            let at = self.next_video;
            for ((key, _, _), frames) in self.spec.images.iter().zip(&episode.images) {
                encode_episode(
                    &ffmpeg,
                    &self.root,
                    &video_file(key, at.0, at.1),
                    frames,
                    self.spec.fps,
                )?;
            }
            Some(at)
        } else if from_videos {
            // Another video dataset's episode (a merge): its files as they are.
            let at = self.next_video;
            for ((key, _, _), v) in self.spec.images.iter().zip(&episode.videos) {
                copy_video(&v.path, &self.root, &video_file(key, at.0, at.1))?;
            }
            Some(at)
        } else {
            None
        };

        // The data file: this episode joins the open one, or opens the next.
        let avg = self
            .data
            .as_ref()
            .map_or(0, |d| d.bytes.checked_div(d.frames).unwrap_or(0));
        let full = self
            .data
            .as_ref()
            .is_some_and(|d| d.bytes + avg * len as u64 >= self.data_file_limit_bytes);
        if full || self.data.is_none() {
            let (chunk, file) = match &self.data {
                Some(d) => next_file(d.chunk, d.file),
                None => self.next_data,
            };
            self.data = Some(OpenData {
                chunk,
                file,
                batches: Vec::new(),
                frames: 0,
                bytes: 0,
            });
        }
        let data = self
            .data
            .as_mut()
            .ok_or_else(|| DatasetError::invalid("data", "no open data file"))?;
        data.batches.push(batch);
        let rel = data_file(data.chunk, data.file);
        let bytes = write_parquet(&self.root, &rel, &self.schema, &data.batches);
        let bytes = match bytes {
            Ok(b) => b,
            Err(e) => {
                data.batches.pop();
                return Err(e);
            }
        };
        data.bytes = bytes;
        data.frames += len as u64;
        let data_at = (data.chunk, data.file);

        // Then its metadata.
        self.meta_rows.push(EpisodeMeta {
            index,
            tasks: vec![episode.task.clone()],
            length: len as u64,
            data: data_at,
            from,
            stats: stats.clone(),
            meta: self.meta_file,
            video: video_at,
        });
        let rel = episodes_file(self.meta_file.0, self.meta_file.1);
        if let Err(e) = self.write_episodes_meta(&rel) {
            self.meta_rows.pop();
            return Err(e);
        }
        write_atomic(
            &self.root,
            "meta/tasks.parquet",
            &tasks_parquet(&self.tasks)?,
        )?;
        let aggregated = with_episode_stats(self.stats.as_deref(), stats);
        write_atomic(
            &self.root,
            "meta/stats.json",
            &self.stats_json(&aggregated).pretty(),
        )?;
        self.stats = Some(aggregated);
        if let Some(at) = video_at {
            self.next_video = next_file(at.0, at.1);
        }
        self.total_episodes += 1;
        self.total_frames += len as u64;
        self.sources.push(json!({
            "task": episode.source.task_name,
            "seed": episode.source.seed,
            "success": episode.source.success,
            "attempt": episode.source.attempt,
        }));
        self.write_info()
    }

    fn episode_batch(
        &self,
        episode: &EpisodeFrames,
        len: usize,
        index: u64,
        from: u64,
        task_index: i64,
    ) -> Result<RecordBatch, DatasetError> {
        let fps = self.spec.fps;
        let mut columns: Vec<ArrayRef> = Vec::with_capacity(self.features.len());
        let mut camera = 0;
        for f in self.features.iter().filter(|f| f.dtype != Dtype::Video) {
            let column: ArrayRef = match f.key.as_str() {
                "observation.state" => fixed_f32(&episode.state, self.spec.state_dim),
                "action" => fixed_f32(&episode.action, self.spec.action_dim),
                "timestamp" => Arc::new(Float32Array::from_iter_values(
                    (0..len).map(|k| (k as f64 / f64::from(fps)) as f32),
                )),
                "frame_index" => Arc::new(Int64Array::from_iter_values(0..len as i64)),
                "episode_index" => Arc::new(Int64Array::from(vec![index as i64; len])),
                "index" => Arc::new(Int64Array::from_iter_values(
                    (0..len as i64).map(|k| from as i64 + k),
                )),
                "task_index" => Arc::new(Int64Array::from(vec![task_index; len])),
                _ if f.dtype == Dtype::Image => {
                    let frames = &episode.images[camera];
                    camera += 1;
                    image_column(frames)
                }
                other => {
                    return Err(DatasetError::invalid(
                        "data",
                        format!("unknown feature {other}"),
                    ));
                }
            };
            columns.push(column);
        }
        RecordBatch::try_new(self.schema.clone(), columns).map_err(DatasetError::arrow("data"))
    }

    pub(crate) fn episode_stats(
        &self,
        episode: &EpisodeFrames,
        len: usize,
        index: u64,
        from: u64,
        task_index: i64,
    ) -> Vec<FeatureStats> {
        let fps = f64::from(self.spec.fps);
        let ints = |v: Vec<f64>| FeatureStats::of_rows(&v, 1, StatsKind::Int);
        let mut camera = 0;
        self.features
            .iter()
            .map(|f| match f.key.as_str() {
                "observation.state" => FeatureStats::of_rows(
                    &episode
                        .state
                        .iter()
                        .map(|x| f64::from(*x))
                        .collect::<Vec<_>>(),
                    self.spec.state_dim,
                    StatsKind::Float,
                ),
                "action" => FeatureStats::of_rows(
                    &episode
                        .action
                        .iter()
                        .map(|x| f64::from(*x))
                        .collect::<Vec<_>>(),
                    self.spec.action_dim,
                    StatsKind::Float,
                ),
                "timestamp" => FeatureStats::of_rows(
                    &(0..len)
                        .map(|k| f64::from((k as f64 / fps) as f32))
                        .collect::<Vec<_>>(),
                    1,
                    StatsKind::Float,
                ),
                "frame_index" => ints((0..len).map(|k| k as f64).collect()),
                "episode_index" => ints(vec![index as f64; len]),
                "index" => ints((0..len).map(|k| (from + k as u64) as f64).collect()),
                "task_index" => ints(vec![task_index as f64; len]),
                _ => {
                    let (_, h, w) = &self.spec.images[camera];
                    let s = match episode.videos.get(camera).and_then(|v| v.stats.clone()) {
                        Some(recorded) => recorded,
                        None => FeatureStats::of_images(&episode.sampled_rgb[camera], *h, *w),
                    };
                    camera += 1;
                    s
                }
            })
            .collect()
    }

    fn stats_json(&self, stats: &[FeatureStats]) -> J {
        J::obj(
            self.features
                .iter()
                .zip(stats)
                .map(|(f, s)| (f.key.clone(), s.to_json())),
        )
    }

    fn write_episodes_meta(&self, rel: &str) -> Result<(), DatasetError> {
        let rows = &self.meta_rows;
        let ints = |f: &dyn Fn(&EpisodeMeta) -> u64| -> ArrayRef {
            Arc::new(Int64Array::from_iter_values(
                rows.iter().map(|r| f(r) as i64),
            ))
        };
        let mut fields: Vec<Field> = Vec::new();
        let mut columns: Vec<ArrayRef> = Vec::new();
        let mut push = |name: &str, column: ArrayRef| {
            fields.push(Field::new(name, column.data_type().clone(), true));
            columns.push(column);
        };
        push("episode_index", ints(&|r| r.index));
        let tasks: Vec<&str> = rows
            .iter()
            .flat_map(|r| r.tasks.iter().map(String::as_str))
            .collect();
        push(
            "tasks",
            Arc::new(ListArray::new(
                Arc::new(Field::new("item", DataType::Utf8, true)),
                OffsetBuffer::from_lengths(rows.iter().map(|r| r.tasks.len())),
                Arc::new(StringArray::from(tasks)),
                None,
            )),
        );
        push("length", ints(&|r| r.length));
        push("data/chunk_index", ints(&|r| r.data.0));
        push("data/file_index", ints(&|r| r.data.1));
        push("dataset_from_index", ints(&|r| r.from));
        push("dataset_to_index", ints(&|r| r.from + r.length));
        if self.spec.video {
            let fps = f64::from(self.spec.fps);
            for (key, _, _) in &self.spec.images {
                let at = |r: &EpisodeMeta| r.video.unwrap_or((0, 0));
                push(&format!("videos/{key}/chunk_index"), ints(&|r| at(r).0));
                push(&format!("videos/{key}/file_index"), ints(&|r| at(r).1));
                push(
                    &format!("videos/{key}/from_timestamp"),
                    Arc::new(Float64Array::from_iter_values(rows.iter().map(|_| 0.0))),
                );
                push(
                    &format!("videos/{key}/to_timestamp"),
                    Arc::new(Float64Array::from_iter_values(
                        rows.iter().map(|r| r.length as f64 / fps),
                    )),
                );
            }
        }
        for (i, f) in self.features.iter().enumerate() {
            let per: Vec<&FeatureStats> = rows.iter().map(|r| &r.stats[i]).collect();
            let kind = per.first().map_or(StatsKind::Float, |s| s.kind);
            let mut stat = |name: &str, get: &dyn Fn(&FeatureStats) -> &Vec<f64>, integer: bool| {
                push(
                    &format!("stats/{}/{name}", f.key),
                    stats_column(&per, get, kind, integer),
                );
            };
            stat("min", &|s| &s.min, true);
            stat("max", &|s| &s.max, true);
            stat("mean", &|s| &s.mean, false);
            stat("std", &|s| &s.std, false);
            push(
                &format!("stats/{}/count", f.key),
                Arc::new(ListArray::new(
                    Arc::new(Field::new("item", DataType::Int64, true)),
                    OffsetBuffer::from_lengths(per.iter().map(|_| 1)),
                    Arc::new(Int64Array::from_iter_values(
                        per.iter().map(|s| s.count as i64),
                    )),
                    None,
                )),
            );
            for (q, (_, key)) in QUANTILES.iter().enumerate() {
                push(
                    &format!("stats/{}/{key}", f.key),
                    stats_column(&per, &|s| &s.quantiles[q], kind, false),
                );
            }
        }
        push("meta/episodes/chunk_index", ints(&|r| r.meta.0));
        push("meta/episodes/file_index", ints(&|r| r.meta.1));
        let schema = Arc::new(Schema::new(fields));
        let batch =
            RecordBatch::try_new(schema.clone(), columns).map_err(DatasetError::arrow(rel))?;
        write_parquet(&self.root, rel, &schema, &[batch]).map(|_| ())
    }

    fn write_info(&self) -> Result<(), DatasetError> {
        let mut ambench = match self.spec.ambench_block() {
            Value::Object(m) => m.into_iter().map(|(k, v)| (k, J::V(v))).collect::<Vec<_>>(),
            _ => Vec::new(),
        };
        ambench.push(("recording".into(), J::V(self.recording.clone())));
        ambench.push(("episodes".into(), J::V(Value::Array(self.sources.clone()))));
        if let Some(shard) = &self.shard {
            ambench.push(("shard".into(), J::V(shard.to_json())));
        }
        let info = J::obj([
            ("codebase_version", J::V(json!(CODEBASE_VERSION))),
            ("robot_type", J::V(json!(self.spec.robot_type))),
            ("total_episodes", J::V(json!(self.total_episodes))),
            ("total_frames", J::V(json!(self.total_frames))),
            ("total_tasks", J::V(json!(self.tasks.len()))),
            ("chunks_size", J::V(json!(CHUNKS_SIZE))),
            ("data_files_size_in_mb", J::V(json!(DATA_FILES_SIZE_IN_MB))),
            (
                "video_files_size_in_mb",
                J::V(json!(VIDEO_FILES_SIZE_IN_MB)),
            ),
            ("fps", J::V(json!(self.spec.fps))),
            (
                "splits",
                J::V(if self.total_episodes > 0 {
                    json!({ "train": format!("0:{}", self.total_episodes) })
                } else {
                    json!({})
                }),
            ),
            ("data_path", J::V(json!(DATA_PATH))),
            (
                "video_path",
                J::V(if self.spec.video {
                    json!(VIDEO_PATH)
                } else {
                    Value::Null
                }),
            ),
            (
                "features",
                J::obj(
                    self.features
                        .iter()
                        .map(|f| (f.key.clone(), J::V(f.info(self.spec.fps)))),
                ),
            ),
            ("ambench", J::Obj(ambench)),
        ]);
        write_atomic(&self.root, "meta/info.json", &info.pretty())
    }
}

/// The Arrow schema of the data files: lerobot's (`datasets` features: fixed-size lists of
/// float32, `Image` structs, scalars), with the `huggingface` metadata `datasets` writes.
pub(crate) fn data_schema(features: &[Feature]) -> Arc<Schema> {
    let mut hf = Vec::new();
    // Videos live in their MP4 files, not in the data files.
    let fields: Vec<Field> = features
        .iter()
        .filter(|f| f.dtype != Dtype::Video)
        .map(|f| {
            let (dt, hf_feature) = match (f.dtype, f.shape.as_slice()) {
                (Dtype::Image | Dtype::Video, _) => (image_type(), json!({"_type": "Image"})),
                (Dtype::Float32, [1]) => (
                    DataType::Float32,
                    json!({"dtype": "float32", "_type": "Value"}),
                ),
                (Dtype::Int64, _) => (DataType::Int64, json!({"dtype": "int64", "_type": "Value"})),
                (Dtype::Float32, _) => (
                    DataType::FixedSizeList(
                        Arc::new(Field::new("item", DataType::Float32, true)),
                        f.len() as i32,
                    ),
                    json!({"feature": {"dtype": "float32", "_type": "Value"}, "length": f.len(), "_type": "Sequence"}),
                ),
            };
            hf.push((f.key.clone(), J::V(hf_feature)));
            Field::new(&f.key, dt, true)
        })
        .collect();
    let meta = J::obj([("info", J::obj([("features", J::Obj(hf))]))]);
    let text = serde_json::to_string(&meta).unwrap_or_default();
    Arc::new(
        Schema::new(fields).with_metadata(std::collections::HashMap::from([(
            "huggingface".to_owned(),
            text,
        )])),
    )
}

fn image_type() -> DataType {
    DataType::Struct(Fields::from(vec![
        Field::new("bytes", DataType::Binary, true),
        Field::new("path", DataType::Utf8, true),
    ]))
}

fn fixed_f32(values: &[f32], dim: usize) -> ArrayRef {
    Arc::new(FixedSizeListArray::new(
        Arc::new(Field::new("item", DataType::Float32, true)),
        dim as i32,
        Arc::new(Float32Array::from(values.to_vec())),
        None,
    ))
}

pub(crate) fn image_column(frames: &[Vec<u8>]) -> ArrayRef {
    let bytes = BinaryArray::from_iter_values(frames.iter());
    let paths = StringArray::from(vec![None::<&str>; frames.len()]);
    let DataType::Struct(fields) = image_type() else {
        unreachable!("image_type is a struct")
    };
    Arc::new(StructArray::new(
        fields,
        vec![Arc::new(bytes), Arc::new(paths)],
        None,
    ))
}

/// A column of one statistic per episode: `list<double>` (`list<int64>` for the min/max of
/// an int64 feature), `list<list<list<double>>>` for images (3, 1, 1).
fn stats_column(
    per: &[&FeatureStats],
    get: &dyn Fn(&FeatureStats) -> &Vec<f64>,
    kind: StatsKind,
    integer: bool,
) -> ArrayRef {
    let item = |dt: DataType| Arc::new(Field::new("item", dt, true));
    let lengths = per.iter().map(|s| get(s).len());
    let flat: Vec<f64> = per.iter().flat_map(|s| get(s).iter().copied()).collect();
    match kind {
        StatsKind::Int if integer => Arc::new(ListArray::new(
            item(DataType::Int64),
            OffsetBuffer::from_lengths(lengths),
            Arc::new(Int64Array::from_iter_values(flat.iter().map(|x| *x as i64))),
            None,
        )),
        StatsKind::Image => {
            // Each channel value v as [[v]]: two inner list levels of length 1.
            let n = flat.len();
            let inner = ListArray::new(
                item(DataType::Float64),
                OffsetBuffer::from_lengths(std::iter::repeat_n(1, n)),
                Arc::new(Float64Array::from(flat)),
                None,
            );
            let middle = ListArray::new(
                item(inner.data_type().clone()),
                OffsetBuffer::from_lengths(std::iter::repeat_n(1, n)),
                Arc::new(inner),
                None,
            );
            Arc::new(ListArray::new(
                item(middle.data_type().clone()),
                OffsetBuffer::from_lengths(lengths),
                Arc::new(middle),
                None,
            ))
        }
        _ => Arc::new(ListArray::new(
            item(DataType::Float64),
            OffsetBuffer::from_lengths(lengths),
            Arc::new(Float64Array::from(flat)),
            None,
        )),
    }
}

/// `meta/tasks.parquet` as pandas writes lerobot's tasks frame: the prompt as the frame's
/// index (`__index_level_0__`, with the `pandas` metadata that makes it the index again) and
/// `task_index`.
pub(crate) fn tasks_parquet(tasks: &[String]) -> Result<Vec<u8>, DatasetError> {
    let rel = "meta/tasks.parquet";
    let pandas = json!({
        "index_columns": ["__index_level_0__"],
        "column_indexes": [{"name": null, "field_name": null, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": null},
            {"name": null, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object", "metadata": null}
        ],
        "creator": {"library": "amstack", "version": env!("CARGO_PKG_VERSION")},
        "pandas_version": "2.2.3"
    });
    let schema = Arc::new(
        Schema::new(vec![
            Field::new("task_index", DataType::Int64, true),
            Field::new("__index_level_0__", DataType::Utf8, true),
        ])
        .with_metadata(std::collections::HashMap::from([(
            "pandas".to_owned(),
            pandas.to_string(),
        )])),
    );
    let batch = RecordBatch::try_new(
        schema.clone(),
        vec![
            Arc::new(Int64Array::from_iter_values(0..tasks.len() as i64)),
            Arc::new(StringArray::from_iter_values(tasks.iter())),
        ],
    )
    .map_err(DatasetError::arrow(rel))?;
    parquet_bytes(rel, &schema, &[batch])
}

fn parquet_bytes(
    rel: &str,
    schema: &Arc<Schema>,
    batches: &[RecordBatch],
) -> Result<Vec<u8>, DatasetError> {
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .build();
    let mut out = Vec::new();
    let mut writer = ArrowWriter::try_new(&mut out, schema.clone(), Some(props))
        .map_err(DatasetError::parquet(rel))?;
    for b in batches {
        writer.write(b).map_err(DatasetError::parquet(rel))?;
        // One row group per episode, as lerobot's appending writer makes them.
        writer.flush().map_err(DatasetError::parquet(rel))?;
    }
    writer.close().map_err(DatasetError::parquet(rel))?;
    Ok(out)
}

/// Writes `batches` to `root/rel` atomically; returns the file's size.
pub(crate) fn write_parquet(
    root: &Path,
    rel: &str,
    schema: &Arc<Schema>,
    batches: &[RecordBatch],
) -> Result<u64, DatasetError> {
    let bytes = parquet_bytes(rel, schema, batches)?;
    write_atomic(root, rel, &bytes)?;
    Ok(bytes.len() as u64)
}

/// The dataset's statistics `all` (none before the first episode) with one more episode's.
fn with_episode_stats(
    all: Option<&[FeatureStats]>,
    episode: Vec<FeatureStats>,
) -> Vec<FeatureStats> {
    match all {
        None => episode,
        Some(all) => all
            .iter()
            .zip(&episode)
            .filter_map(|(a, b)| FeatureStats::aggregate(&[a, b]))
            .collect(),
    }
}

/// A file replaced atomically: filled as a temporary file beside it, then synced, renamed over
/// it and the folder synced ([`AtomicFile::commit`]); a failure leaves the old file.
pub(crate) struct AtomicFile {
    pub(crate) path: PathBuf,
    dir: PathBuf,
    /// The temporary file to fill.
    pub(crate) tmp: PathBuf,
}

impl AtomicFile {
    /// `root/rel`, its folder created.
    pub(crate) fn new(root: &Path, rel: &str) -> Result<Self, DatasetError> {
        let path = root.join(rel);
        let dir = path.parent().unwrap_or(root).to_owned();
        std::fs::create_dir_all(&dir).map_err(DatasetError::io(&dir))?;
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = dir.join(format!(".{name}.tmp"));
        Ok(Self { path, dir, tmp })
    }

    /// Syncs the filled temporary file and renames it over the file, then syncs the folder.
    pub(crate) fn commit(&self) -> Result<(), DatasetError> {
        File::open(&self.tmp)
            .and_then(|f| f.sync_all())
            .and_then(|()| std::fs::rename(&self.tmp, &self.path))
            .and_then(|()| File::open(&self.dir)?.sync_all())
            .map_err(|e| {
                self.abandon();
                DatasetError::Io {
                    path: self.path.clone(),
                    source: e,
                }
            })
    }

    /// Removes the temporary file (after a failure).
    pub(crate) fn abandon(&self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}

/// Replaces `root/rel` with `bytes` atomically ([`AtomicFile`]). A failure (a full disk) leaves
/// the old file and removes the temporary one.
pub(crate) fn write_atomic(root: &Path, rel: &str, bytes: &[u8]) -> Result<(), DatasetError> {
    let file = AtomicFile::new(root, rel)?;
    if let Err(e) = std::fs::write(&file.tmp, bytes) {
        file.abandon();
        return Err(DatasetError::Io {
            path: file.path,
            source: e,
        });
    }
    file.commit()
}

/// Merges datasets of the same features (several tasks) into one at `out`: episodes in the
/// order given, re-indexed, tasks numbered in order of appearance, statistics recomputed
/// (their aggregate is lerobot's). Video datasets merge with video datasets: each episode's
/// MP4 is copied as it is (amstack's one file per episode; no re-encoding) and its recorded
/// statistics kept. Every source is checked before anything is written. `progress` sees each
/// episode copied.
pub fn merge(
    sources: &[PathBuf],
    out: &Path,
    progress: &mut dyn FnMut(u64),
) -> Result<DatasetWriter, DatasetError> {
    let first = sources
        .first()
        .ok_or_else(|| DatasetError::invalid("merge", "no dataset to merge"))?;
    let spec = DatasetReader::open(first)?.spec;
    let mut readers: Vec<DatasetReader> = Vec::with_capacity(sources.len());
    for src in sources {
        let reader = DatasetReader::open(src)?;
        check_mergeable(first, &spec, src, &reader)?;
        readers.push(reader);
    }
    let mut writer = DatasetWriter::create(out, spec, Value::Null)?;
    let mut recordings = Vec::new();
    // Each source's reader (and its cached data file) goes once its episodes are copied.
    for (src, mut reader) in sources.iter().zip(readers) {
        recordings
            .push(json!({ "source": src.display().to_string(), "recording": reader.recording }));
        writer.recording = json!({ "merged_from": recordings });
        for e in 0..reader.total_episodes {
            let frames = reader.episode(e)?;
            writer.write_episode(frames)?;
            progress(writer.total_episodes);
        }
    }
    writer.write_info()?;
    Ok(writer)
}

/// Whether `reader` (of `src`) can join a merge whose first dataset (`first`) has `spec`: the
/// same features, stored alike (videos or images), and, for videos, one file per episode.
fn check_mergeable(
    first: &Path,
    spec: &DatasetSpec,
    src: &Path,
    reader: &DatasetReader,
) -> Result<(), DatasetError> {
    let shown = src.join("meta/info.json").display().to_string();
    let other = &reader.spec;
    if other.state_dim != spec.state_dim
        || other.action_dim != spec.action_dim
        || other.action_semantics != spec.action_semantics
        || other.images != spec.images
        || other.fps != spec.fps
    {
        return Err(DatasetError::invalid(
            &shown,
            format!(
                "its features differ from {}'s (state {}, action {} {}, images {:?}, fps {})",
                first.display(),
                spec.state_dim,
                spec.action_semantics.name(),
                spec.action_dim,
                spec.images.iter().map(|i| &i.0).collect::<Vec<_>>(),
                spec.fps
            ),
        ));
    }
    if other.video != spec.video {
        let how = |video: bool| {
            if video {
                "videos (record --video)"
            } else {
                "PNG images in its data files"
            }
        };
        return Err(DatasetError::invalid(
            &shown,
            format!(
                "its cameras are stored as {}, {}'s as {}: merge datasets stored alike",
                how(other.video),
                first.display(),
                how(spec.video)
            ),
        ));
    }
    if other.video {
        for row in &reader.episodes {
            for v in &row.videos {
                let shared = reader.episodes.iter().any(|r| {
                    r.index != row.index
                        && r.videos.iter().any(|o| o.key == v.key && o.file == v.file)
                });
                if shared || v.from_timestamp != 0.0 {
                    return Err(DatasetError::invalid(
                        &shown,
                        format!(
                            "episode {}: its {} video shares file-{:03} of chunk-{:03} with other \
                             episodes (lerobot's packed layout): merge copies amstack's one file \
                             per episode and does not re-encode",
                            row.index, v.key, v.file.1, v.file.0
                        ),
                    ));
                }
                if v.stats.is_none() {
                    return Err(DatasetError::invalid(
                        &shown,
                        format!("episode {}: no stats/{} in its row", row.index, v.key),
                    ));
                }
            }
        }
    }
    Ok(())
}
