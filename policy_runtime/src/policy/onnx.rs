//! ONNX policies, run in-process with tract (pure Rust): a model file plus its sidecar
//! `<model>.json` (docs/policies.md) naming
//!
//! - the state input: the ONNX input's name, the state keys concatenated in order (float32
//!   `[1, D]`), and optional normalisation statistics, x' = (x − mean) / std;
//! - optional image inputs: ONNX input name, observation key (`ee_image`, `base_image`),
//!   size, per-channel mean/std of the pixels scaled to [0, 1] (float32 `[1, 3, H, W]`);
//! - the output: its name, chunk length H, action dim D (`[1, H, D]`, `[H, D]` or
//!   `[1, H·D]`), semantics (`absolute` or `relative`, AMBENCH_SPEC §5.4) and optional
//!   statistics to undo, a = a'·std + mean;
//! - optional rates: `policy_hz`, `action_steps` (the flags' defaults for this model).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Deserialize;
use tract_onnx::prelude::*;

use super::chunk::{ActionChunk, ActionSemantics};
use super::state::StateKey;
use super::{Policy, PolicyError, PolicyObservation};

/// The state input of a model.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateInput {
    /// The ONNX input's name.
    pub input: String,
    /// State keys, concatenated in this order.
    pub keys: Vec<StateKey>,
    /// Per-value mean subtracted before the model (default: none).
    #[serde(default)]
    pub mean: Option<Vec<f64>>,
    /// Per-value standard deviation divided by (default: none).
    #[serde(default)]
    pub std: Option<Vec<f64>>,
}

/// An image input of a model.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageInput {
    /// The ONNX input's name.
    pub input: String,
    /// The observation's image (`ee_image`, `base_image`).
    pub key: String,
    /// Rows the model takes.
    pub height: usize,
    /// Columns the model takes.
    pub width: usize,
    /// Per-channel mean of pixels scaled to [0, 1] (default 0).
    #[serde(default = "zeros3")]
    pub mean: [f64; 3],
    /// Per-channel standard deviation (default 1).
    #[serde(default = "ones3")]
    pub std: [f64; 3],
}

fn zeros3() -> [f64; 3] {
    [0.0; 3]
}

fn ones3() -> [f64; 3] {
    [1.0; 3]
}

/// The action output of a model.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionOutput {
    /// The ONNX output's name.
    pub output: String,
    /// Actions per chunk (H).
    pub chunk: usize,
    /// Values per action (8, or 8 + arm joints).
    pub dim: usize,
    /// Absolute targets, or relative to the pose at the chunk's start.
    pub semantics: ActionSemantics,
    /// Per-value mean added back (default: none).
    #[serde(default)]
    pub mean: Option<Vec<f64>>,
    /// Per-value standard deviation multiplied back (default: none).
    #[serde(default)]
    pub std: Option<Vec<f64>>,
}

/// The rates a model was trained for.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rates {
    /// Policy rate, Hz.
    pub policy_hz: f64,
    /// Actions executed per query.
    pub action_steps: usize,
}

/// What a model takes and gives (the sidecar file).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sidecar {
    /// The state input.
    pub state: StateInput,
    /// Image inputs (none: a state-only policy).
    #[serde(default)]
    pub images: Vec<ImageInput>,
    /// The action output.
    pub output: ActionOutput,
    /// Rates; None: the flags' defaults.
    #[serde(default)]
    pub rates: Option<Rates>,
}

/// A model or sidecar that cannot be used: the file and why.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct OnnxError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub reason: String,
}

type Plan = Arc<TypedRunnableModel>;

/// A loaded model and its sidecar (shared by every rollout: running it does not change it).
#[derive(Debug)]
pub struct OnnxPolicy {
    path: PathBuf,
    sidecar: Sidecar,
    plan: Plan,
    /// Index of the model input fed by the state, and by each image of the sidecar.
    state_slot: usize,
    image_slots: Vec<usize>,
    state_dim: usize,
}

/// Where the sidecar of `model` is: `<model>.json`.
pub fn sidecar_path(model: &Path) -> PathBuf {
    let mut name = model.as_os_str().to_owned();
    name.push(".json");
    PathBuf::from(name)
}

fn check_stats(
    what: &str,
    stats: Option<&Vec<f64>>,
    len: usize,
    positive: bool,
) -> Result<(), String> {
    let Some(v) = stats else {
        return Ok(());
    };
    if v.len() != len {
        return Err(format!("{what}: {} values, expected {len}", v.len()));
    }
    if let Some(x) = v
        .iter()
        .find(|x| !x.is_finite() || (positive && **x <= 0.0))
    {
        return Err(format!(
            "{what}: {x} is not a finite{} number",
            if positive { " positive" } else { "" }
        ));
    }
    Ok(())
}

impl OnnxPolicy {
    /// Loads `model` and its sidecar; `key_len` gives each state key's length on the
    /// vehicle flown (the arm's joints).
    pub fn load(model: &Path, key_len: &dyn Fn(StateKey) -> usize) -> Result<Self, OnnxError> {
        let side_path = sidecar_path(model);
        let side_err = |reason: String| OnnxError {
            path: side_path.clone(),
            reason,
        };
        let text = std::fs::read_to_string(&side_path)
            .map_err(|e| side_err(format!("cannot read the model's sidecar: {e}")))?;
        let sidecar: Sidecar = serde_json::from_str(&text).map_err(|e| side_err(e.to_string()))?;
        let state_dim: usize = sidecar.state.keys.iter().map(|k| key_len(*k)).sum();
        if sidecar.state.keys.is_empty() || state_dim == 0 {
            return Err(side_err("state.keys: no state values".to_owned()));
        }
        check_stats("state.mean", sidecar.state.mean.as_ref(), state_dim, false)
            .map_err(side_err)?;
        check_stats("state.std", sidecar.state.std.as_ref(), state_dim, true).map_err(side_err)?;
        let out = &sidecar.output;
        if out.chunk == 0 || out.dim < 8 {
            return Err(side_err(format!(
                "output: chunk {} x dim {}: needs at least 1 action of 8 values",
                out.chunk, out.dim
            )));
        }
        check_stats("output.mean", out.mean.as_ref(), out.dim, false).map_err(side_err)?;
        check_stats("output.std", out.std.as_ref(), out.dim, true).map_err(side_err)?;
        for (i, image) in sidecar.images.iter().enumerate() {
            if image.height == 0 || image.width == 0 || image.std.iter().any(|s| *s <= 0.0) {
                return Err(side_err(format!(
                    "images[{i}]: size {}x{} and std must be positive",
                    image.height, image.width
                )));
            }
        }
        if let Some(r) = sidecar.rates
            && (!(r.policy_hz.is_finite() && r.policy_hz > 0.0) || r.action_steps == 0)
        {
            return Err(side_err(format!(
                "rates: policy_hz {} and action_steps {} must be positive",
                r.policy_hz, r.action_steps
            )));
        }
        let model_err = |reason: String| OnnxError {
            path: model.to_owned(),
            reason,
        };
        let mut graph = onnx()
            .model_for_path(model)
            .map_err(|e| model_err(format!("not a readable ONNX model: {e}")))?;
        let names: Vec<String> = graph
            .input_outlets()
            .map_err(|e| model_err(e.to_string()))?
            .iter()
            .map(|o| graph.node(o.node).name.clone())
            .collect();
        let slot = |name: &str| {
            names.iter().position(|n| n == name).ok_or_else(|| {
                model_err(format!(
                    "the sidecar names input {name:?}; the model's inputs are {names:?}"
                ))
            })
        };
        let state_slot = slot(&sidecar.state.input)?;
        let image_slots = sidecar
            .images
            .iter()
            .map(|i| slot(&i.input))
            .collect::<Result<Vec<_>, _>>()?;
        if names.len() != 1 + image_slots.len() {
            return Err(model_err(format!(
                "the model has inputs {names:?}; the sidecar feeds {}",
                1 + image_slots.len()
            )));
        }
        let fact_err = |e: TractError| model_err(format!("input shapes: {e}"));
        graph
            .set_input_fact(
                state_slot,
                InferenceFact::dt_shape(f32::datum_type(), [1, state_dim]),
            )
            .map_err(fact_err)?;
        for (image, &s) in sidecar.images.iter().zip(&image_slots) {
            graph
                .set_input_fact(
                    s,
                    InferenceFact::dt_shape(f32::datum_type(), [1, 3, image.height, image.width]),
                )
                .map_err(fact_err)?;
        }
        let output_names: Vec<String> = graph
            .output_outlets()
            .map_err(|e| model_err(e.to_string()))?
            .iter()
            .map(|o| graph.node(o.node).name.clone())
            .collect();
        let output_slot = output_names
            .iter()
            .position(|n| *n == sidecar.output.output)
            .ok_or_else(|| {
                model_err(format!(
                    "the sidecar names output {:?}; the model's outputs are {output_names:?}",
                    sidecar.output.output
                ))
            })?;
        let output = graph
            .output_outlets()
            .map_err(|e| model_err(e.to_string()))?[output_slot];
        graph
            .select_output_outlets(&[output])
            .map_err(|e| model_err(e.to_string()))?;
        let plan = graph
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .map_err(|e| model_err(format!("cannot prepare the model: {e}")))?;
        Ok(Self {
            path: model.to_owned(),
            sidecar,
            plan,
            state_slot,
            image_slots,
            state_dim,
        })
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Its sidecar.
    pub fn sidecar(&self) -> &Sidecar {
        &self.sidecar
    }

    /// The model's raw output (before the output statistics) on `state` (already
    /// normalised, as the model takes it) and images (as the model takes them): for
    /// checking against another runtime.
    pub fn run_raw(&self, state: &[f32], images: &[Vec<f32>]) -> Result<Vec<f32>, String> {
        if state.len() != self.state_dim || images.len() != self.image_slots.len() {
            return Err(format!(
                "inputs: {} state values and {} images, the model takes {} and {}",
                state.len(),
                images.len(),
                self.state_dim,
                self.image_slots.len()
            ));
        }
        let mut inputs: Vec<Option<TValue>> = vec![None; 1 + images.len()];
        let tensor = Tensor::from_shape(&[1, state.len()], state).map_err(|e| e.to_string())?;
        inputs[self.state_slot] = Some(tensor.into());
        for ((image, spec), &slot) in images
            .iter()
            .zip(&self.sidecar.images)
            .zip(&self.image_slots)
        {
            let tensor = Tensor::from_shape(&[1, 3, spec.height, spec.width], image)
                .map_err(|e| e.to_string())?;
            inputs[slot] = Some(tensor.into());
        }
        let inputs: TVec<TValue> = inputs.into_iter().flatten().collect();
        let outputs = self
            .plan
            .run(inputs)
            .map_err(|e| format!("inference: {e}"))?;
        let first = outputs.first().ok_or("inference gave no output")?;
        let view = first
            .to_plain_array_view::<f32>()
            .map_err(|e| format!("output: {e}"))?;
        Ok(view.iter().copied().collect())
    }
}

/// One flight's use of a shared model.
#[derive(Debug)]
pub struct OnnxSession {
    model: Arc<OnnxPolicy>,
}

impl OnnxSession {
    /// A session of `model`.
    pub fn new(model: Arc<OnnxPolicy>) -> Self {
        Self { model }
    }
}

/// Bilinear resampling of an RGB image to `height` × `width`, channels first, pixels scaled to
/// [0, 1] and normalised per channel.
fn image_tensor(rgb: &[u8], h: usize, w: usize, spec: &ImageInput) -> Vec<f32> {
    let (th, tw) = (spec.height, spec.width);
    let mut out = vec![0.0f32; 3 * th * tw];
    let sample = |y: usize, x: usize, c: usize| f64::from(rgb[(y * w + x) * 3 + c]) / 255.0;
    for ty in 0..th {
        // Pixel centres aligned (as OpenCV's INTER_LINEAR).
        let sy = ((ty as f64 + 0.5) * h as f64 / th as f64 - 0.5).clamp(0.0, (h - 1) as f64);
        let (y0, fy) = (sy.floor() as usize, sy - sy.floor());
        let y1 = (y0 + 1).min(h - 1);
        for tx in 0..tw {
            let sx = ((tx as f64 + 0.5) * w as f64 / tw as f64 - 0.5).clamp(0.0, (w - 1) as f64);
            let (x0, fx) = (sx.floor() as usize, sx - sx.floor());
            let x1 = (x0 + 1).min(w - 1);
            for c in 0..3 {
                let v = (1.0 - fy) * ((1.0 - fx) * sample(y0, x0, c) + fx * sample(y0, x1, c))
                    + fy * ((1.0 - fx) * sample(y1, x0, c) + fx * sample(y1, x1, c));
                #[allow(clippy::cast_possible_truncation, reason = "the model takes float32")]
                let normalised = ((v - spec.mean[c]) / spec.std[c]) as f32;
                out[(c * th + ty) * tw + tx] = normalised;
            }
        }
    }
    out
}

impl Policy for OnnxSession {
    fn query(&mut self, observation: &PolicyObservation<'_>) -> Result<ActionChunk, PolicyError> {
        let model = &self.model;
        let side = &model.sidecar;
        let fail = |what: String| PolicyError(format!("{}: {what}", model.path.display()));
        let mut state = Vec::with_capacity(model.state_dim);
        for key in &side.state.keys {
            let (_, values) = observation
                .state
                .iter()
                .find(|(k, _)| k == key)
                .ok_or_else(|| fail(format!("the observation has no {}", key.name())))?;
            state.extend_from_slice(values);
        }
        if let (Some(mean), Some(std)) = (&side.state.mean, &side.state.std) {
            for ((x, m), s) in state.iter_mut().zip(mean).zip(std) {
                *x = (*x - m) / s;
            }
        } else if let Some(mean) = &side.state.mean {
            for (x, m) in state.iter_mut().zip(mean) {
                *x -= m;
            }
        } else if let Some(std) = &side.state.std {
            for (x, s) in state.iter_mut().zip(std) {
                *x /= s;
            }
        }
        #[allow(clippy::cast_possible_truncation, reason = "the model takes float32")]
        let state: Vec<f32> = state.iter().map(|x| *x as f32).collect();
        let images = side
            .images
            .iter()
            .map(|spec| {
                let image = observation
                    .images
                    .iter()
                    .find(|i| i.key == spec.key)
                    .ok_or_else(|| {
                        fail(format!(
                            "the model takes the image {}; the flight has none (--cameras)",
                            spec.key
                        ))
                    })?;
                if image.height == 0
                    || image.width == 0
                    || image.rgb.len() != image.height * image.width * 3
                {
                    return Err(fail(format!(
                        "image {}: {} bytes for {}x{} RGB",
                        spec.key,
                        image.rgb.len(),
                        image.width,
                        image.height
                    )));
                }
                Ok(image_tensor(&image.rgb, image.height, image.width, spec))
            })
            .collect::<Result<Vec<_>, PolicyError>>()?;
        let raw = model.run_raw(&state, &images).map_err(fail)?;
        let out = &side.output;
        if raw.len() != out.chunk * out.dim {
            return Err(fail(format!(
                "wrong shape: {} output values, the sidecar says {} x {}",
                raw.len(),
                out.chunk,
                out.dim
            )));
        }
        let values = raw
            .iter()
            .enumerate()
            .map(|(i, y)| {
                let j = i % out.dim;
                let s = out.std.as_ref().map_or(1.0, |s| s[j]);
                let m = out.mean.as_ref().map_or(0.0, |m| m[j]);
                f64::from(*y) * s + m
            })
            .collect();
        Ok(ActionChunk {
            rows: out.chunk,
            dim: out.dim,
            values,
        })
    }
}
