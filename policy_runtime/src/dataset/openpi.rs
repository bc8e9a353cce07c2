//! `amstack dataset export-openpi`: the LeRobot v2.1 layout openpi trains on, at the policy's
//! rate (AMBENCH_SPEC §7.2): logical frame k of an episode is raw frame 6k (120 → 20 Hz;
//! ⌊len/6⌋ frames, no averaging); `ee_image` (and `base_image`), `actions`, the state split
//! into its fields; one Parquet file per episode, `meta/*.jsonl`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{ArrayRef, FixedSizeListArray, Float32Array, Int64Array};
use arrow::datatypes::{DataType, Field};
use arrow::record_batch::RecordBatch;
use serde_json::{Value, json};

use super::DatasetError;
use super::json::J;
use super::layout::{ActionSemantics, Dtype, Feature, image_key};
use super::read::DatasetReader;
use super::stats::{FeatureStats, StatsKind};
use super::video::decode_frames;
use super::write::{
    data_schema, decode_png, encode_png, image_column, write_atomic, write_parquet,
};

/// The v2.1 layout openpi pins.
const OPENPI_VERSION: &str = "v2.1";
const OPENPI_CHUNK_SIZE: u64 = 1000;
const OPENPI_DATA_PATH: &str = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet";

/// What an export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenpiExport {
    /// Episodes.
    pub episodes: u64,
    /// Frames (20 Hz).
    pub frames: u64,
    /// Raw frames read.
    pub raw_frames: u64,
    /// Raw frames per exported one.
    pub stride: u32,
    /// Whether `ee_image` is in it (the source recorded the EE camera).
    pub images: bool,
}

fn state_key_dim(key: &str, arm: usize) -> usize {
    match key {
        "ee_pos" | "base_pos" | "base_lin_vel" | "base_ang_vel" => 3,
        "ee_quat" | "base_quat" => 4,
        "gripper_width" => 1,
        _ => arm,
    }
}

/// Exports the datasets `sources` (same features) to `out` at `target_hz`; `progress` sees
/// each episode written.
pub fn export_openpi(
    sources: &[PathBuf],
    out: &Path,
    target_hz: u32,
    progress: &mut dyn FnMut(u64),
) -> Result<OpenpiExport, DatasetError> {
    let first = sources
        .first()
        .ok_or_else(|| DatasetError::invalid("export-openpi", "no dataset to export"))?;
    let spec = DatasetReader::open(first)?.spec;
    // A video dataset's frames are decoded by the ffmpeg program (found when first needed).
    let mut ffmpeg: Option<PathBuf> = None;
    if target_hz == 0 || spec.fps % target_hz != 0 {
        return Err(DatasetError::invalid(
            "export-openpi",
            format!(
                "--target-hz {target_hz}: the dataset's {} fps is not a multiple of it",
                spec.fps
            ),
        ));
    }
    let stride = spec.fps / target_hz;
    let required: &[&str] = match spec.action_semantics {
        ActionSemantics::EeAbsolute => &["ee_pos", "ee_quat", "gripper_width"],
        ActionSemantics::BaseJointAbsolute => {
            &["base_pos", "base_quat", "arm_joint_pos", "gripper_width"]
        }
    };
    let arm = spec.action_dim.saturating_sub(8).max(4);
    let mut offsets = Vec::new();
    let mut offset = 0;
    for key in &spec.state_keys {
        offsets.push((key.clone(), offset, state_key_dim(key, arm)));
        offset += state_key_dim(key, arm);
    }
    let parts: Vec<(String, usize, usize)> = required
        .iter()
        .map(|k| {
            offsets.iter().find(|(n, _, _)| n == k).cloned().ok_or_else(|| {
                DatasetError::invalid(
                    "meta/info.json",
                    format!(
                        "openpi's {} export needs state keys {required:?}; the dataset has {:?}",
                        spec.action_semantics.name(),
                        spec.state_keys
                    ),
                )
            })
        })
        .collect::<Result<_, _>>()?;
    let cams: Vec<(String, String, usize, usize)> =
        [("ee_camera", "ee_image"), ("base_camera", "base_image")]
            .iter()
            .filter_map(|(cam, name)| {
                let key = image_key(cam);
                spec.images
                    .iter()
                    .find(|i| i.0 == key)
                    .map(|(k, h, w)| (k.clone(), (*name).to_owned(), *h, *w))
            })
            .collect();
    // Features in frame order, then the indices.
    let mut features: Vec<Feature> = Vec::new();
    if let Some((_, name, h, w)) = cams.iter().find(|c| c.1 == "ee_image") {
        features.push(image_feature(name, *h, *w));
    }
    features.push(float_feature("actions", spec.action_dim));
    for (key, _, dim) in &parts {
        features.push(float_feature(key, *dim));
    }
    if let Some((_, name, h, w)) = cams.iter().find(|c| c.1 == "base_image") {
        features.push(image_feature(name, *h, *w));
    }
    features.push(Feature {
        key: "timestamp".into(),
        dtype: Dtype::Float32,
        shape: vec![1],
        names: None,
    });
    for k in ["frame_index", "episode_index", "index", "task_index"] {
        features.push(Feature {
            key: k.into(),
            dtype: Dtype::Int64,
            shape: vec![1],
            names: None,
        });
    }
    // The parquet schema as `datasets` makes it; image features are CHW in info.json only.
    let mut schema_features = features.clone();
    for f in &mut schema_features {
        if f.dtype == Dtype::Image {
            f.shape = vec![f.shape[1], f.shape[2], f.shape[0]];
        }
    }
    let schema = data_schema(&schema_features);
    std::fs::create_dir_all(out.join("meta")).map_err(DatasetError::io(out))?;
    let mut tasks: Vec<String> = Vec::new();
    let mut tasks_jsonl = String::new();
    let mut episodes_jsonl = String::new();
    let mut stats_jsonl = String::new();
    let mut reports = Vec::new();
    let mut episode_index = 0u64;
    let mut frames_total = 0u64;
    let mut raw_total = 0u64;
    for src in sources {
        let mut reader = DatasetReader::open(src)?;
        if reader.spec.fps != spec.fps
            || reader.spec.action_semantics != spec.action_semantics
            || reader.spec.state_keys != spec.state_keys
            || reader.spec.images != spec.images
        {
            return Err(DatasetError::invalid(
                &src.join("meta/info.json").display().to_string(),
                format!("its features differ from {}'s", first.display()),
            ));
        }
        let mut logical = 0u64;
        for e in 0..reader.total_episodes {
            let ep = reader.episode(e)?;
            let raw_len = ep.len(spec.state_dim);
            raw_total += raw_len as u64;
            let len = raw_len / stride as usize;
            if len == 0 {
                continue;
            }
            let picks: Vec<usize> = (0..len).map(|k| k * stride as usize).collect();
            let task_index = match tasks.iter().position(|t| *t == ep.task) {
                Some(i) => i,
                None => {
                    tasks.push(ep.task.clone());
                    tasks_jsonl.push_str(&format!(
                        "{}\n",
                        json!({"task_index": tasks.len() - 1, "task": ep.task})
                    ));
                    tasks.len() - 1
                }
            } as i64;
            let rows = |data: &[f32], dim: usize, off: usize, width: usize| -> Vec<f32> {
                picks
                    .iter()
                    .flat_map(|&k| data[k * dim + off..k * dim + off + width].iter().copied())
                    .collect()
            };
            let mut columns: Vec<ArrayRef> = Vec::new();
            let mut stats: Vec<(String, J)> = Vec::new();
            for f in &features {
                let (column, s): (ArrayRef, FeatureStats) = match f.key.as_str() {
                    "actions" => {
                        let v = rows(&ep.action, spec.action_dim, 0, spec.action_dim);
                        (fixed(&v, spec.action_dim), float_stats(&v, spec.action_dim))
                    }
                    "timestamp" => {
                        let v: Vec<f32> = (0..len)
                            .map(|k| (k as f64 / f64::from(target_hz)) as f32)
                            .collect();
                        (Arc::new(Float32Array::from(v.clone())), float_stats(&v, 1))
                    }
                    "frame_index" | "episode_index" | "index" | "task_index" => {
                        let v: Vec<i64> = (0..len as i64)
                            .map(|k| match f.key.as_str() {
                                "frame_index" => k,
                                "episode_index" => episode_index as i64,
                                "index" => frames_total as i64 + k,
                                _ => task_index,
                            })
                            .collect();
                        let s = FeatureStats::of_rows(
                            &v.iter().map(|x| *x as f64).collect::<Vec<_>>(),
                            1,
                            StatsKind::Int,
                        );
                        (Arc::new(Int64Array::from(v)), s)
                    }
                    _ if f.dtype == Dtype::Image => {
                        let (src_key, _, h, w) = cams
                            .iter()
                            .find(|c| c.1 == f.key)
                            .cloned()
                            .unwrap_or_default();
                        let c = spec.images.iter().position(|i| i.0 == src_key).unwrap_or(0);
                        let (pngs, rgb) = if let Some(video) = ep.videos.get(c) {
                            // The frames at the picks' timestamps, decoded from the MP4.
                            let program = match &ffmpeg {
                                Some(p) => p.clone(),
                                None => ffmpeg
                                    .insert(crate::video::ffmpeg_program().map_err(|e| {
                                        DatasetError::invalid(
                                            &video.path.display().to_string(),
                                            format!("a video dataset needs a decoder: {e}"),
                                        )
                                    })?)
                                    .clone(),
                            };
                            let at: Vec<usize> = picks
                                .iter()
                                .map(|&k| video.from_frame as usize + k)
                                .collect();
                            let rgb = decode_frames(&program, &video.path, w, h, &at)?;
                            let pngs = rgb
                                .iter()
                                .map(|f| encode_png(w as u32, h as u32, f))
                                .collect::<Result<Vec<_>, _>>()?;
                            (pngs, rgb)
                        } else {
                            let pngs: Vec<Vec<u8>> =
                                picks.iter().map(|&k| ep.images[c][k].clone()).collect();
                            let rgb = pngs
                                .iter()
                                .map(|p| decode_png(p).map(|d| d.2))
                                .collect::<Result<Vec<_>, _>>()?;
                            (pngs, rgb)
                        };
                        let s = all_pixel_stats(&rgb);
                        (image_column(&pngs), s)
                    }
                    key => {
                        let (_, off, width) = parts
                            .iter()
                            .find(|p| p.0 == key)
                            .cloned()
                            .unwrap_or_default();
                        let v = rows(&ep.state, spec.state_dim, off, width);
                        let column: ArrayRef = if width == 1 {
                            Arc::new(Float32Array::from(v.clone()))
                        } else {
                            fixed(&v, width)
                        };
                        (column, float_stats(&v, width))
                    }
                };
                columns.push(column);
                stats.push((f.key.clone(), v21_stats(&s)));
            }
            let rel = format!(
                "data/chunk-{:03}/episode_{episode_index:06}.parquet",
                episode_index / OPENPI_CHUNK_SIZE
            );
            let batch =
                RecordBatch::try_new(schema.clone(), columns).map_err(DatasetError::arrow(&rel))?;
            write_parquet(out, &rel, &schema, &[batch])?;
            episodes_jsonl.push_str(&format!(
                "{}\n",
                serde_json::to_string(&J::obj([
                    ("episode_index", J::V(json!(episode_index))),
                    ("tasks", J::V(json!([ep.task]))),
                    ("length", J::V(json!(len))),
                ]))
                .unwrap_or_default()
            ));
            stats_jsonl.push_str(&format!(
                "{}\n",
                serde_json::to_string(&J::obj([
                    ("episode_index", J::V(json!(episode_index))),
                    ("stats", J::Obj(stats)),
                ]))
                .unwrap_or_default()
            ));
            episode_index += 1;
            frames_total += len as u64;
            logical += len as u64;
            progress(episode_index);
        }
        reports.push(json!({
            "dataset_root": src.display().to_string(),
            "action_semantics": reader.spec.action_semantics.name(),
            "raw_fps": reader.spec.fps,
            "target_hz": target_hz,
            "stride": stride,
            "raw_frames": reader.total_frames,
            "logical_frames": logical,
        }));
    }
    let info = J::obj([
        ("codebase_version", J::V(json!(OPENPI_VERSION))),
        ("robot_type", J::V(json!("am_bench"))),
        ("total_episodes", J::V(json!(episode_index))),
        ("total_frames", J::V(json!(frames_total))),
        ("total_tasks", J::V(json!(tasks.len()))),
        ("total_videos", J::V(json!(0))),
        (
            "total_chunks",
            J::V(json!(episode_index.div_ceil(OPENPI_CHUNK_SIZE))),
        ),
        ("chunks_size", J::V(json!(OPENPI_CHUNK_SIZE))),
        ("fps", J::V(json!(target_hz))),
        (
            "splits",
            J::V(json!({"train": format!("0:{episode_index}")})),
        ),
        ("data_path", J::V(json!(OPENPI_DATA_PATH))),
        ("video_path", J::V(Value::Null)),
        (
            "features",
            J::obj(
                features
                    .iter()
                    .map(|f| (f.key.clone(), J::V(f.info(target_hz)))),
            ),
        ),
        (
            "ambench",
            J::obj([(
                "openpi_export",
                J::V(json!({
                    "source_dataset_roots": sources.iter().map(|s| s.display().to_string()).collect::<Vec<_>>(),
                    "source_action_semantics": spec.action_semantics.name(),
                    "target_hz": target_hz,
                    "schema": "openpi_am_bench",
                    "lerobot_version": OPENPI_VERSION,
                    "include_base_image": cams.iter().any(|c| c.1 == "base_image"),
                })),
            )]),
        ),
    ]);
    write_atomic(out, "meta/tasks.jsonl", tasks_jsonl.as_bytes())?;
    write_atomic(out, "meta/episodes.jsonl", episodes_jsonl.as_bytes())?;
    write_atomic(out, "meta/episodes_stats.jsonl", stats_jsonl.as_bytes())?;
    let mut text = info.pretty();
    text.push(b'\n');
    write_atomic(out, "meta/info.json", &text)?;
    let report = json!({
        "output_root": out.display().to_string(),
        "target_hz": target_hz,
        "include_base_image": cams.iter().any(|c| c.1 == "base_image"),
        "sources": reports,
    });
    write_atomic(
        out,
        "ambench_openpi_export_report.json",
        format!(
            "{}\n",
            serde_json::to_string_pretty(&report).unwrap_or_default()
        )
        .as_bytes(),
    )?;
    Ok(OpenpiExport {
        episodes: episode_index,
        frames: frames_total,
        raw_frames: raw_total,
        stride,
        images: cams.iter().any(|c| c.1 == "ee_image"),
    })
}

/// v2.1 image statistics: every pixel of every frame, per channel, in [0, 1].
fn all_pixel_stats(frames: &[Vec<u8>]) -> FeatureStats {
    let mut min = [f64::INFINITY; 3];
    let mut max = [f64::NEG_INFINITY; 3];
    let mut sum = [0.0; 3];
    let mut sum_sq = [0.0; 3];
    let mut n = 0.0;
    for f in frames {
        for px in f.chunks_exact(3) {
            for c in 0..3 {
                let v = f64::from(px[c]) / 255.0;
                min[c] = min[c].min(v);
                max[c] = max[c].max(v);
                sum[c] += v;
                sum_sq[c] += v * v;
            }
            n += 1.0;
        }
    }
    let mean: Vec<f64> = sum.iter().map(|s| s / f64::max(n, 1.0)).collect();
    FeatureStats {
        min: min.to_vec(),
        max: max.to_vec(),
        std: (0..3)
            .map(|c| {
                (sum_sq[c] / f64::max(n, 1.0) - mean[c] * mean[c])
                    .max(0.0)
                    .sqrt()
            })
            .collect(),
        mean,
        count: frames.len() as u64,
        quantiles: Vec::new(),
        kind: StatsKind::Image,
    }
}

fn image_feature(name: &str, h: usize, w: usize) -> Feature {
    Feature {
        key: name.to_owned(),
        dtype: Dtype::Image,
        shape: vec![3, h, w],
        names: Some(vec!["channel".into(), "height".into(), "width".into()]),
    }
}

fn float_feature(name: &str, dim: usize) -> Feature {
    Feature {
        key: name.to_owned(),
        dtype: Dtype::Float32,
        shape: vec![dim],
        names: Some((0..dim).map(|i| format!("{name}_{i}")).collect()),
    }
}

fn fixed(values: &[f32], dim: usize) -> ArrayRef {
    Arc::new(FixedSizeListArray::new(
        Arc::new(Field::new("item", DataType::Float32, true)),
        dim as i32,
        Arc::new(Float32Array::from(values.to_vec())),
        None,
    ))
}

fn float_stats(v: &[f32], dim: usize) -> FeatureStats {
    FeatureStats::of_rows(
        &v.iter().map(|x| f64::from(*x)).collect::<Vec<_>>(),
        dim,
        StatsKind::Float,
    )
}

/// v2.1 episode statistics: min, max, mean, std, count (no quantiles).
fn v21_stats(s: &FeatureStats) -> J {
    match s.to_json() {
        J::Obj(fields) => J::Obj(
            fields
                .into_iter()
                .filter(|(k, _)| matches!(k.as_str(), "min" | "max" | "mean" | "std" | "count"))
                .collect(),
        ),
        other => other,
    }
}
