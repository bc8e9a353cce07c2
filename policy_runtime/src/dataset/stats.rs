//! Feature statistics as `lerobot` (≥ 0.4, `compute_stats.py`) computes them: per element
//! min, max, mean, std (population), count and the quantiles q01 q10 q50 q90 q99 estimated
//! from a 5000-bin histogram spanning [min, max]; images per channel over a sample of their
//! frames (every pixel, halved in size once past 300 px), scaled to [0, 1]. Datasets and
//! episodes aggregate by count-weighted means (the parallel variance formula; quantiles
//! count-weighted as lerobot does).
//!
//! One difference: lerobot squares uint8 pixels in uint8 (they wrap) when it computes the
//! images' standard deviation; amstack computes it in f64.

use serde_json::{Value, json};

use super::json::J;

/// The quantiles lerobot writes, with their keys.
pub const QUANTILES: [(f64, &str); 5] = [
    (0.01, "q01"),
    (0.10, "q10"),
    (0.50, "q50"),
    (0.90, "q90"),
    (0.99, "q99"),
];
const HISTOGRAM_BINS: usize = 5000;

/// The statistics of one feature.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureStats {
    /// Per element.
    pub min: Vec<f64>,
    /// Per element.
    pub max: Vec<f64>,
    /// Per element.
    pub mean: Vec<f64>,
    /// Per element (population).
    pub std: Vec<f64>,
    /// Samples (frames; sampled images for an image).
    pub count: u64,
    /// Per quantile of [`QUANTILES`], per element.
    pub quantiles: Vec<Vec<f64>>,
    /// How it is written: integers (min/max of an int64 feature), or an image (3, 1, 1).
    pub kind: StatsKind,
}

/// How a feature's statistics are shaped in JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatsKind {
    /// float vectors: `[d]`.
    Float,
    /// int64 scalars: min and max integers.
    Int,
    /// images: `[[[c0]], [[c1]], [[c2]]]`.
    Image,
}

impl FeatureStats {
    /// Statistics of `n` samples of `dim` elements (`values` row-major).
    pub fn of_rows(values: &[f64], dim: usize, kind: StatsKind) -> Self {
        let n = values.len().checked_div(dim).unwrap_or(0);
        let column = |d: usize| values.iter().skip(d).step_by(dim.max(1)).copied();
        let mut s = Self {
            min: Vec::with_capacity(dim),
            max: Vec::with_capacity(dim),
            mean: Vec::with_capacity(dim),
            std: Vec::with_capacity(dim),
            count: n as u64,
            quantiles: vec![Vec::with_capacity(dim); QUANTILES.len()],
            kind,
        };
        for d in 0..dim {
            let (lo, hi, sum, sum_sq) = column(d).fold(
                (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0),
                |(lo, hi, s, s2), x| (lo.min(x), hi.max(x), s + x, s2 + x * x),
            );
            let mean = sum / n.max(1) as f64;
            let std = if n < 2 {
                let var = column(d).map(|x| (x - mean) * (x - mean)).sum::<f64>() / n.max(1) as f64;
                var.sqrt()
            } else {
                (sum_sq / n as f64 - mean * mean).max(0.0).sqrt()
            };
            s.min.push(lo);
            s.max.push(hi);
            s.mean.push(mean);
            s.std.push(std);
            if n < 2 {
                for q in &mut s.quantiles {
                    q.push(mean);
                }
            } else {
                let qs = histogram_quantiles(column(d), lo, hi, n);
                for (q, v) in s.quantiles.iter_mut().zip(qs) {
                    q.push(v);
                }
            }
        }
        s
    }

    /// Statistics of images (RGB8, `height`×`width`, row-major HWC) as lerobot computes them
    /// for one episode: a sample of the frames ([`sample_indices`], chosen by the caller),
    /// halved by an integer factor once past 300 px, per channel, scaled to [0, 1]; the count
    /// is the number of frames sampled.
    pub fn of_images(frames: &[Vec<u8>], height: usize, width: usize) -> Self {
        let factor = if height.max(width) < 300 {
            1
        } else if width > height {
            width / 150
        } else {
            height / 150
        }
        .max(1);
        let mut values: Vec<f64> = Vec::new();
        for frame in frames {
            for y in (0..height).step_by(factor) {
                for x in (0..width).step_by(factor) {
                    let i = (y * width + x) * 3;
                    if let Some(px) = frame.get(i..i + 3) {
                        values.extend(px.iter().map(|v| f64::from(*v)));
                    }
                }
            }
        }
        let mut s = Self::of_rows(&values, 3, StatsKind::Image);
        s.count = frames.len() as u64;
        let scale = |v: &mut Vec<f64>| v.iter_mut().for_each(|x| *x /= 255.0);
        scale(&mut s.min);
        scale(&mut s.max);
        scale(&mut s.mean);
        scale(&mut s.std);
        s.quantiles.iter_mut().for_each(scale);
        s
    }

    /// The aggregate of several (lerobot's `aggregate_feature_stats`).
    pub fn aggregate(parts: &[&Self]) -> Option<Self> {
        let first = parts.first()?;
        let dim = first.mean.len();
        let total: u64 = parts.iter().map(|p| p.count).sum();
        let n = total.max(1) as f64;
        let mut out = Self {
            min: vec![f64::INFINITY; dim],
            max: vec![f64::NEG_INFINITY; dim],
            mean: vec![0.0; dim],
            std: vec![0.0; dim],
            count: total,
            quantiles: vec![vec![0.0; dim]; QUANTILES.len()],
            kind: first.kind,
        };
        for p in parts {
            let w = p.count as f64;
            for d in 0..dim.min(p.mean.len()) {
                out.min[d] = out.min[d].min(p.min[d]);
                out.max[d] = out.max[d].max(p.max[d]);
                out.mean[d] += p.mean[d] * w;
                for (q, pq) in out.quantiles.iter_mut().zip(&p.quantiles) {
                    q[d] += pq[d] * w;
                }
            }
        }
        out.mean.iter_mut().for_each(|m| *m /= n);
        out.quantiles
            .iter_mut()
            .for_each(|q| q.iter_mut().for_each(|x| *x /= n));
        for p in parts {
            let w = p.count as f64;
            for d in 0..dim.min(p.mean.len()) {
                let delta = p.mean[d] - out.mean[d];
                out.std[d] += (p.std[d] * p.std[d] + delta * delta) * w;
            }
        }
        out.std.iter_mut().for_each(|v| *v = (*v / n).sqrt());
        Some(out)
    }

    fn values(&self, v: &[f64], integer: bool) -> J {
        match self.kind {
            StatsKind::Image => J::V(Value::Array(v.iter().map(|x| json!([[x]])).collect())),
            StatsKind::Int if integer => {
                J::V(Value::Array(v.iter().map(|x| json!(*x as i64)).collect()))
            }
            _ => J::V(json!(v)),
        }
    }

    /// Its JSON object, in lerobot's key order.
    pub fn to_json(&self) -> J {
        let mut fields = vec![
            ("min".to_owned(), self.values(&self.min, true)),
            ("max".to_owned(), self.values(&self.max, true)),
            ("mean".to_owned(), self.values(&self.mean, false)),
            ("std".to_owned(), self.values(&self.std, false)),
            ("count".to_owned(), J::V(json!([self.count]))),
        ];
        for ((_, key), q) in QUANTILES.iter().zip(&self.quantiles) {
            fields.push(((*key).to_owned(), self.values(q, false)));
        }
        J::Obj(fields)
    }

    /// Reads one back from JSON (`stats.json`); None if it is not shaped as written.
    pub fn from_json(value: &Value, kind: StatsKind) -> Option<Self> {
        let flat = |key: &str| -> Option<Vec<f64>> {
            let mut out = Vec::new();
            flatten(value.get(key)?, &mut out);
            Some(out)
        };
        Some(Self {
            min: flat("min")?,
            max: flat("max")?,
            mean: flat("mean")?,
            std: flat("std")?,
            count: value.get("count")?.get(0)?.as_u64()?,
            quantiles: QUANTILES
                .iter()
                .map(|(_, k)| flat(k))
                .collect::<Option<Vec<_>>>()?,
            kind,
        })
    }
}

fn flatten(v: &Value, out: &mut Vec<f64>) {
    match v {
        Value::Array(a) => a.iter().for_each(|x| flatten(x, out)),
        Value::Number(n) => out.push(n.as_f64().unwrap_or(f64::NAN)),
        _ => out.push(f64::NAN),
    }
}

/// The quantiles of `values` (n of them, within [lo, hi]) from a histogram of 5000 bins over
/// [lo − 1e-10, hi + 1e-10], interpolated within the bin (lerobot's `RunningQuantileStats`).
fn histogram_quantiles(values: impl Iterator<Item = f64>, lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let first = lo - 1e-10;
    let last = hi + 1e-10;
    let width = (last - first) / HISTOGRAM_BINS as f64;
    let edge = |i: usize| {
        if i == HISTOGRAM_BINS {
            last
        } else {
            first + i as f64 * width
        }
    };
    let mut hist = vec![0u64; HISTOGRAM_BINS];
    for x in values {
        let b = (((x - first) / width).floor().max(0.0) as usize).min(HISTOGRAM_BINS - 1);
        hist[b] += 1;
    }
    let mut cumsum = Vec::with_capacity(HISTOGRAM_BINS);
    let mut acc = 0u64;
    for h in &hist {
        acc += h;
        cumsum.push(acc as f64);
    }
    QUANTILES
        .iter()
        .map(|(q, _)| {
            let target = q * n as f64;
            let idx = cumsum.partition_point(|c| *c < target);
            if idx == 0 {
                return edge(0);
            }
            if idx >= cumsum.len() {
                return edge(HISTOGRAM_BINS);
            }
            let before = cumsum[idx - 1];
            let in_bin = cumsum[idx] - before;
            if in_bin == 0.0 {
                return edge(idx);
            }
            edge(idx) + (target - before) / in_bin * (edge(idx + 1) - edge(idx))
        })
        .collect()
}

/// The frames of an episode of `len` whose images lerobot samples for its statistics:
/// max(min(len, 100), min(⌊len^0.75⌋, 10000)) indices spread evenly over [0, len − 1],
/// rounded half to even.
pub fn sample_indices(len: usize) -> Vec<usize> {
    if len == 0 {
        return Vec::new();
    }
    let floor = len.min(100);
    let num = floor.max(((len as f64).powf(0.75) as usize).min(10_000));
    if num == 1 {
        return vec![0];
    }
    let stop = (len - 1) as f64;
    let step = stop / (num - 1) as f64;
    (0..num)
        .map(|i| {
            let x = if i == num - 1 { stop } else { i as f64 * step };
            x.round_ties_even() as usize
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::expect_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    #[test]
    fn vector_stats_of_a_hand_made_column() {
        // 1, 2, 3, 4: mean 2.5, population std √1.25.
        let s = FeatureStats::of_rows(
            &[1.0, 10.0, 2.0, 10.0, 3.0, 10.0, 4.0, 10.0],
            2,
            StatsKind::Float,
        );
        assert_eq!(s.count, 4);
        assert_eq!((s.min[0], s.max[0], s.mean[0]), (1.0, 4.0, 2.5));
        assert!((s.std[0] - 1.25f64.sqrt()).abs() < 1e-12);
        // A constant column: std 0, every quantile at the value (within the ±1e-10 span).
        assert_eq!(s.std[1], 0.0);
        assert!(s.quantiles.iter().all(|q| (q[1] - 10.0).abs() < 1e-9));
        // The median of 1..4 from the histogram: 2 samples below → within [2, 3].
        assert!(
            (2.0..=3.0).contains(&s.quantiles[2][0]),
            "{:?}",
            s.quantiles[2]
        );
    }

    #[test]
    fn aggregate_equals_stats_of_the_concatenation() {
        let a = [1.0, 2.0, 3.0];
        let b = [10.0, 20.0];
        let all: Vec<f64> = a.iter().chain(&b).copied().collect();
        let sa = FeatureStats::of_rows(&a, 1, StatsKind::Float);
        let sb = FeatureStats::of_rows(&b, 1, StatsKind::Float);
        let sall = FeatureStats::of_rows(&all, 1, StatsKind::Float);
        let agg = FeatureStats::aggregate(&[&sa, &sb]).expect("two parts");
        assert_eq!(agg.count, 5);
        assert_eq!((agg.min[0], agg.max[0]), (1.0, 20.0));
        assert!((agg.mean[0] - sall.mean[0]).abs() < 1e-12);
        assert!((agg.std[0] - sall.std[0]).abs() < 1e-12);
    }

    #[test]
    fn sampled_frames_follow_lerobot() {
        // Under 100 frames: every frame.
        assert_eq!(sample_indices(5), vec![0, 1, 2, 3, 4]);
        // 1000 frames: ⌊1000^0.75⌋ = 177 samples, first 0, last 999.
        let s = sample_indices(1000);
        assert_eq!(s.len(), 177);
        assert_eq!((s[0], s[176]), (0, 999));
        // 200 frames: 100 samples of linspace(0, 199, 100) = 0, 2.0101.., rounded.
        let s = sample_indices(200);
        assert_eq!(s.len(), 100);
        assert_eq!(&s[..3], &[0, 2, 4]);
    }

    #[test]
    fn image_stats_are_per_channel_in_unit_range() {
        // Two 2×2 frames: red channel 255, green 0, blue 0 and 255.
        let f1 = [255u8, 0, 0].repeat(4);
        let f2 = [255u8, 0, 255].repeat(4);
        let s = FeatureStats::of_images(&[f1, f2], 2, 2);
        assert_eq!(s.count, 2);
        assert_eq!(s.mean, vec![1.0, 0.0, 0.5]);
        assert_eq!(s.std[2], 0.5);
        assert_eq!(s.max, vec![1.0, 0.0, 1.0]);
    }
}
