//! LighterGlue: the small LightGlue (Lindenberger, Sarlin, Pollefeys:
//! "LightGlue: Local Feature Matching at Light Speed", ICCV 2023) that the
//! XFeat authors trained for XFeat descriptors (`xfeat-lighterglue.pt`: 6
//! layers, one head, 96-dimensional states). Inference as kornia's
//! `LightGlue` runs it on the CPU with the XFeat configuration: rotary
//! positional encoding from learned Fourier features, self- and
//! cross-attention layers with a GELU feed-forward, point pruning by
//! matchability after every layer but the last (width confidence 0.95; no
//! early stopping), and the dual-softmax + matchability assignment with a
//! mutual check and a score threshold.

use crate::XFeatError;
use crate::model::DESCRIPTOR_DIM;
use crate::nn::par_gemm_strided;
use crate::weights::StateDict;
use colslam_features::{Descriptors, FeatureError, Features, Match, Matcher};
use std::path::{Path, PathBuf};

/// Width of the transformer states.
const DIM: usize = 96;
/// Number of transformer layers.
const LAYERS: usize = 6;
/// Fourier frequencies of the positional encoding (half the head width).
const FREQS: usize = DIM / 2;
/// LayerNorm epsilon (PyTorch default).
const LN_EPS: f32 = 1e-5;

/// Options of [`LighterGlue`].
#[derive(Debug, Clone, PartialEq)]
pub struct LighterGlueOptions {
    /// Keep matches whose assignment probability exceeds this (default 0.1,
    /// the reference `min_conf`).
    pub min_conf: f32,
    /// Point pruning: after each layer but the last, drop points whose
    /// matchability is at most `1 - width_confidence` (default 0.95, the
    /// XFeat configuration). Values `<= 0` switch pruning off.
    pub width_confidence: f32,
    /// Image size `[width, height]` in pixels that keypoints are normalised
    /// by, used by the [`Matcher`] interface (which sees no image). Default
    /// `None`: `match_features` then fails; set it to the camera's size.
    pub image_size: Option<[usize; 2]>,
    /// The `xfeat-lighterglue.pt` file; `None` (default): beside the XFeat
    /// weights that [`crate::find_weights`] finds.
    pub weights: Option<PathBuf>,
}

impl Default for LighterGlueOptions {
    fn default() -> Self {
        Self { min_conf: 0.1, width_confidence: 0.95, image_size: None, weights: None }
    }
}

impl LighterGlueOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), XFeatError> {
        let bad = |reason: String| Err(XFeatError::InvalidOptions { what: "LighterGlue", reason });
        if !(self.min_conf.is_finite() && (0.0..1.0).contains(&self.min_conf)) {
            return bad(format!("min_conf {} must be in [0, 1)", self.min_conf));
        }
        if !self.width_confidence.is_finite() || self.width_confidence > 1.0 {
            return bad(format!("width_confidence {} must be finite and at most 1", self.width_confidence));
        }
        if let Some([w, h]) = self.image_size
            && (w == 0 || h == 0)
        {
            return bad(format!("image_size {w}x{h} must be positive"));
        }
        Ok(())
    }
}

/// `y = x W^T + b` for `x` of `n x inp` rows.
#[derive(Debug, Clone)]
struct Linear {
    out: usize,
    inp: usize,
    w: Vec<f32>,
    b: Vec<f32>,
}

impl Linear {
    fn load(sd: &StateDict, prefix: &str, inp: usize, out: usize) -> Result<Self, XFeatError> {
        let w = sd.get(&format!("{prefix}.weight"), &[out, inp])?.data.clone();
        let b = sd.get(&format!("{prefix}.bias"), &[out])?.data.clone();
        Ok(Self { out, inp, w, b })
    }

    fn forward(&self, x: &[f32]) -> Vec<f32> {
        let n = x.len() / self.inp;
        let mut y = vec![0.0f32; n * self.out];
        // W^T: element (i, j) = w[j * inp + i].
        par_gemm_strided(n, self.inp, self.out, x, &self.w, (1, self.inp), &mut y);
        for row in y.chunks_exact_mut(self.out) {
            row.iter_mut().zip(&self.b).for_each(|(v, b)| *v += b);
        }
        y
    }
}

/// `Linear(2D, 2D) -> LayerNorm -> GELU -> Linear(2D, D)`.
#[derive(Debug, Clone)]
struct Ffn {
    l0: Linear,
    ln_w: Vec<f32>,
    ln_b: Vec<f32>,
    l3: Linear,
}

impl Ffn {
    fn load(sd: &StateDict, prefix: &str) -> Result<Self, XFeatError> {
        Ok(Self {
            l0: Linear::load(sd, &format!("{prefix}.0"), 2 * DIM, 2 * DIM)?,
            ln_w: sd.get(&format!("{prefix}.1.weight"), &[2 * DIM])?.data.clone(),
            ln_b: sd.get(&format!("{prefix}.1.bias"), &[2 * DIM])?.data.clone(),
            l3: Linear::load(sd, &format!("{prefix}.3"), 2 * DIM, DIM)?,
        })
    }

    /// `x += ffn([x, message])`.
    fn residual(&self, x: &mut [f32], message: &[f32]) {
        let cat: Vec<f32> =
            x.chunks_exact(DIM).zip(message.chunks_exact(DIM)).flat_map(|(a, b)| a.iter().chain(b).copied()).collect();
        let mut h = self.l0.forward(&cat);
        for row in h.chunks_exact_mut(2 * DIM) {
            let n = row.len() as f32;
            let mean = row.iter().sum::<f32>() / n;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n;
            let inv = 1.0 / (var + LN_EPS).sqrt();
            for ((v, w), b) in row.iter_mut().zip(&self.ln_w).zip(&self.ln_b) {
                *v = gelu((*v - mean) * inv * w + b);
            }
        }
        let y = self.l3.forward(&h);
        x.iter_mut().zip(&y).for_each(|(a, b)| *a += b);
    }
}

/// The error function, Abramowitz & Stegun 7.1.26 (absolute error below
/// 1.5e-7, ample for float32 GELU; LighterGlue's scores are far more
/// sensitive to float32 rounding elsewhere).
fn erf(x: f64) -> f64 {
    const P: f64 = 0.327_591_1;
    const A: [f64; 5] = [0.254_829_592, -0.284_496_736, 1.421_413_741, -1.453_152_027, 1.061_405_429];
    let a = x.abs();
    let t = 1.0 / (1.0 + P * a);
    let poly = t * (A[0] + t * (A[1] + t * (A[2] + t * (A[3] + t * A[4]))));
    (1.0 - poly * (-a * a).exp()).copysign(x)
}

/// Exact (erf) GELU, PyTorch's default.
fn gelu(x: f32) -> f32 {
    let x = f64::from(x);
    (0.5 * x * (1.0 + erf(x / std::f64::consts::SQRT_2))) as f32
}

/// Row-wise softmax of an `rows x cols` matrix, in place.
///
/// Probabilities below the smallest normal `f32` are flushed to zero: they
/// change nothing measurable, but subnormal operands make the following
/// matrix product many times slower on x86.
fn softmax_rows(m: &mut [f32], cols: usize) {
    use rayon::prelude::*;
    m.par_chunks_mut(cols.max(1) * SOFTMAX_ROWS_PER_TASK).for_each(|rows| softmax_rows_seq(rows, cols));
}

/// Rows per rayon task in [`softmax_rows`].
const SOFTMAX_ROWS_PER_TASK: usize = 64;

fn softmax_rows_seq(m: &mut [f32], cols: usize) {
    for row in m.chunks_exact_mut(cols) {
        let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut sum = 0.0f32;
        row.iter_mut().for_each(|v| {
            *v = (*v - max).exp();
            sum += *v;
        });
        row.iter_mut().for_each(|v| {
            *v /= sum;
            if *v < f32::MIN_POSITIVE {
                *v = 0.0;
            }
        });
    }
}

/// `a (m x d) * b^T` for `b` of `n x d` rows: `m x n`.
fn a_bt(a: &[f32], b: &[f32], d: usize) -> Vec<f32> {
    let (m, n) = (a.len() / d, b.len() / d);
    let mut out = vec![0.0f32; m * n];
    par_gemm_strided(m, d, n, a, b, (1, d), &mut out);
    out
}

/// `p (m x n) * v (n x d)`: `m x d`.
fn a_b(p: &[f32], v: &[f32], n: usize, d: usize) -> Vec<f32> {
    let m = p.len() / n;
    let mut out = vec![0.0f32; m * d];
    par_gemm_strided(m, n, d, p, v, (d, 1), &mut out);
    out
}

fn transpose(m: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut t = vec![0.0f32; m.len()];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = m[r * cols + c];
        }
    }
    t
}

/// Rotary embedding: pairs `(t[2i], t[2i+1])` rotated by the angle of
/// frequency `i` (`cos`/`sin` hold one value per pair).
fn rotate(t: &mut [f32], cos: &[f32], sin: &[f32]) {
    for ((row, c), s) in t.chunks_exact_mut(DIM).zip(cos.chunks_exact(FREQS)).zip(sin.chunks_exact(FREQS)) {
        for i in 0..FREQS {
            let (a, b) = (row[2 * i], row[2 * i + 1]);
            row[2 * i] = a * c[i] - b * s[i];
            row[2 * i + 1] = b * c[i] + a * s[i];
        }
    }
}

#[derive(Debug, Clone)]
struct Layer {
    wqkv: Linear,
    out_proj: Linear,
    self_ffn: Ffn,
    to_qk: Linear,
    to_v: Linear,
    to_out: Linear,
    cross_ffn: Ffn,
    matchability: Linear,
    final_proj: Linear,
}

impl Layer {
    fn self_attn(&self, x: &mut [f32], cos: &[f32], sin: &[f32]) {
        let n = x.len() / DIM;
        let qkv = self.wqkv.forward(x);
        // The 3*DIM outputs are laid out (dim, {q, k, v}).
        let pick = |j: usize| -> Vec<f32> {
            qkv.chunks_exact(3 * DIM).flat_map(|r| (0..DIM).map(move |d| r[3 * d + j])).collect()
        };
        let (mut q, mut k, v) = (pick(0), pick(1), pick(2));
        rotate(&mut q, cos, sin);
        rotate(&mut k, cos, sin);
        let scale = 1.0 / (DIM as f32).sqrt();
        let mut s = a_bt(&q, &k, DIM);
        s.iter_mut().for_each(|v| *v *= scale);
        softmax_rows(&mut s, n);
        let ctx = a_b(&s, &v, n, DIM);
        let message = self.out_proj.forward(&ctx);
        self.self_ffn.residual(x, &message);
    }

    fn cross_attn(&self, x0: &mut [f32], x1: &mut [f32]) {
        let (m, n) = (x0.len() / DIM, x1.len() / DIM);
        let s = (DIM as f32).powf(-0.25);
        let mut qk0 = self.to_qk.forward(x0);
        let mut qk1 = self.to_qk.forward(x1);
        qk0.iter_mut().chain(qk1.iter_mut()).for_each(|v| *v *= s);
        let (v0, v1) = (self.to_v.forward(x0), self.to_v.forward(x1));
        let sim = a_bt(&qk0, &qk1, DIM);
        let mut sim_t = transpose(&sim, m, n);
        let mut sim = sim;
        softmax_rows(&mut sim, n);
        softmax_rows(&mut sim_t, m);
        let m0 = self.to_out.forward(&a_b(&sim, &v1, n, DIM));
        let m1 = self.to_out.forward(&a_b(&sim_t, &v0, m, DIM));
        self.cross_ffn.residual(x0, &m0);
        self.cross_ffn.residual(x1, &m1);
    }

    /// Matchability logits, one per row.
    fn matchability_logits(&self, x: &[f32]) -> Vec<f32> {
        self.matchability.forward(x)
    }
}

fn log_sigmoid(x: f32) -> f32 {
    x.min(0.0) - (-x.abs()).exp().ln_1p()
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// The LighterGlue matcher ("lighterglue").
#[derive(Debug, Clone)]
pub struct LighterGlue {
    input_proj: Linear,
    /// `FREQS x 2` Fourier projection of normalised positions.
    wr: Vec<f32>,
    layers: Vec<Layer>,
    opts: LighterGlueOptions,
}

/// One side of a LighterGlue problem.
#[derive(Debug, Clone, Copy)]
pub struct GlueInput<'a> {
    /// Keypoints `(x, y)` in pixels.
    pub keypoints: &'a [[f32; 2]],
    /// `keypoints.len() x 64` XFeat descriptors.
    pub descriptors: &'a [f32],
    /// Image `[width, height]`.
    pub image_size: [usize; 2],
}

impl LighterGlue {
    /// Checks the options and loads `xfeat-lighterglue.pt`.
    pub fn new(opts: LighterGlueOptions) -> Result<Self, XFeatError> {
        opts.validate()?;
        let path = match &opts.weights {
            Some(p) => p.clone(),
            None => crate::find_weights()?.with_file_name("xfeat-lighterglue.pt"),
        };
        Self::from_state_dict(&StateDict::read(&path)?, opts)
    }

    /// Builds the matcher from a LighterGlue state dict (keys `matcher.*`).
    pub fn from_state_dict(sd: &StateDict, opts: LighterGlueOptions) -> Result<Self, XFeatError> {
        opts.validate()?;
        let p = "matcher";
        let layers = (0..LAYERS)
            .map(|i| {
                let t = format!("{p}.transformers.{i}");
                let a = format!("{p}.log_assignment.{i}");
                Ok(Layer {
                    wqkv: Linear::load(sd, &format!("{t}.self_attn.Wqkv"), DIM, 3 * DIM)?,
                    out_proj: Linear::load(sd, &format!("{t}.self_attn.out_proj"), DIM, DIM)?,
                    self_ffn: Ffn::load(sd, &format!("{t}.self_attn.ffn"))?,
                    to_qk: Linear::load(sd, &format!("{t}.cross_attn.to_qk"), DIM, DIM)?,
                    to_v: Linear::load(sd, &format!("{t}.cross_attn.to_v"), DIM, DIM)?,
                    to_out: Linear::load(sd, &format!("{t}.cross_attn.to_out"), DIM, DIM)?,
                    cross_ffn: Ffn::load(sd, &format!("{t}.cross_attn.ffn"))?,
                    matchability: Linear::load(sd, &format!("{a}.matchability"), DIM, 1)?,
                    final_proj: Linear::load(sd, &format!("{a}.final_proj"), DIM, DIM)?,
                })
            })
            .collect::<Result<Vec<_>, XFeatError>>()?;
        Ok(Self {
            input_proj: Linear::load(sd, &format!("{p}.input_proj"), DESCRIPTOR_DIM, DIM)?,
            wr: sd.get(&format!("{p}.posenc.Wr.weight"), &[FREQS, 2])?.data.clone(),
            layers,
            opts,
        })
    }

    /// Reads the weights file and builds the matcher.
    pub fn load(path: &Path, opts: LighterGlueOptions) -> Result<Self, XFeatError> {
        Self::from_state_dict(&StateDict::read(path)?, opts)
    }

    /// The options.
    pub fn options(&self) -> &LighterGlueOptions {
        &self.opts
    }

    /// Cosine and sine of the positional angles, `n x FREQS` each.
    fn encoding(&self, kps: &[[f32; 2]], [w, h]: [usize; 2]) -> (Vec<f32>, Vec<f32>) {
        let (sx, sy) = (w as f32 / 2.0, h as f32 / 2.0);
        let scale = w.max(h) as f32 / 2.0;
        let mut cos = Vec::with_capacity(kps.len() * FREQS);
        let mut sin = Vec::with_capacity(kps.len() * FREQS);
        for p in kps {
            let (x, y) = ((p[0] - sx) / scale, (p[1] - sy) / scale);
            for f in self.wr.chunks_exact(2) {
                let a = f[0] * x + f[1] * y;
                cos.push(a.cos());
                sin.push(a.sin());
            }
        }
        (cos, sin)
    }

    /// Matches two XFeat feature sets. Returns `(index in a, index in b,
    /// assignment probability)` sorted by the index in `a`.
    pub fn match_pair(&self, a: GlueInput<'_>, b: GlueInput<'_>) -> Result<Vec<(u32, u32, f32)>, XFeatError> {
        for (side, g) in [("first", &a), ("second", &b)] {
            if g.descriptors.len() != g.keypoints.len() * DESCRIPTOR_DIM {
                return Err(XFeatError::InvalidOptions {
                    what: "LighterGlue input",
                    reason: format!(
                        "{side} set: {} keypoints but {} descriptor values (expected {} per keypoint)",
                        g.keypoints.len(),
                        g.descriptors.len(),
                        DESCRIPTOR_DIM
                    ),
                });
            }
            if g.image_size[0] == 0 || g.image_size[1] == 0 {
                return Err(XFeatError::InvalidOptions {
                    what: "LighterGlue input",
                    reason: format!("{side} image size is zero"),
                });
            }
            if g.keypoints.iter().any(|p| !(p[0].is_finite() && p[1].is_finite())) {
                return Err(XFeatError::InvalidOptions {
                    what: "LighterGlue input",
                    reason: format!("{side} set has non-finite keypoints"),
                });
            }
        }
        if a.keypoints.is_empty() || b.keypoints.is_empty() {
            return Ok(Vec::new());
        }
        let mut x0 = self.input_proj.forward(a.descriptors);
        let mut x1 = self.input_proj.forward(b.descriptors);
        let (mut c0, mut s0) = self.encoding(a.keypoints, a.image_size);
        let (mut c1, mut s1) = self.encoding(b.keypoints, b.image_size);
        let mut ind0: Vec<u32> = (0..a.keypoints.len() as u32).collect();
        let mut ind1: Vec<u32> = (0..b.keypoints.len() as u32).collect();
        let prune = self.opts.width_confidence > 0.0;
        let min_matchability = 1.0 - self.opts.width_confidence;
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            layer.self_attn(&mut x0, &c0, &s0);
            layer.self_attn(&mut x1, &c1, &s1);
            layer.cross_attn(&mut x0, &mut x1);
            if i == last || !prune {
                continue;
            }
            for (x, c, s, ind) in [(&mut x0, &mut c0, &mut s0, &mut ind0), (&mut x1, &mut c1, &mut s1, &mut ind1)] {
                let keep: Vec<bool> =
                    layer.matchability_logits(x).iter().map(|&z| sigmoid(z) > min_matchability).collect();
                let filt = |v: &mut Vec<f32>, w: usize| {
                    let mut k = keep.iter();
                    let mut out = Vec::with_capacity(v.len());
                    for row in v.chunks_exact(w) {
                        if k.next() == Some(&true) {
                            out.extend_from_slice(row);
                        }
                    }
                    *v = out;
                };
                filt(x, DIM);
                filt(c, FREQS);
                filt(s, FREQS);
                let mut k = keep.iter();
                ind.retain(|_| k.next() == Some(&true));
            }
            if ind0.is_empty() || ind1.is_empty() {
                return Ok(Vec::new());
            }
        }
        Ok(self.assign(&self.layers[last], &x0, &x1, &ind0, &ind1))
    }

    /// Dual-softmax + matchability assignment, mutual check and threshold.
    fn assign(&self, layer: &Layer, x0: &[f32], x1: &[f32], ind0: &[u32], ind1: &[u32]) -> Vec<(u32, u32, f32)> {
        let (m, n) = (ind0.len(), ind1.len());
        let scale = (DIM as f32).powf(-0.25);
        let mut md0 = layer.final_proj.forward(x0);
        let mut md1 = layer.final_proj.forward(x1);
        md0.iter_mut().chain(md1.iter_mut()).for_each(|v| *v *= scale);
        let sim = a_bt(&md0, &md1, DIM);
        let z0 = layer.matchability_logits(x0);
        let z1 = layer.matchability_logits(x1);
        // Log-softmax over rows and over columns.
        let row_lse: Vec<f32> = sim.chunks_exact(n).map(log_sum_exp).collect();
        let col_lse: Vec<f32> =
            (0..n).map(|j| log_sum_exp(&(0..m).map(|i| sim[i * n + j]).collect::<Vec<_>>())).collect();
        let ls0: Vec<f32> = z0.iter().map(|&z| log_sigmoid(z)).collect();
        let ls1: Vec<f32> = z1.iter().map(|&z| log_sigmoid(z)).collect();
        let score =
            |i: usize, j: usize| (sim[i * n + j] - row_lse[i]) + (sim[i * n + j] - col_lse[j]) + (ls0[i] + ls1[j]);
        let argmax = |it: &mut dyn Iterator<Item = (usize, f32)>| {
            it.fold((usize::MAX, f32::NEG_INFINITY), |b, (k, v)| if v > b.1 { (k, v) } else { b })
        };
        let best0: Vec<(usize, f32)> = (0..m).map(|i| argmax(&mut (0..n).map(|j| (j, score(i, j))))).collect();
        let best1: Vec<usize> = (0..n).map(|j| argmax(&mut (0..m).map(|i| (i, score(i, j)))).0).collect();
        let mut out = Vec::new();
        for (i, &(j, s)) in best0.iter().enumerate() {
            if best1.get(j) != Some(&i) {
                continue;
            }
            let p = s.exp();
            if p > self.opts.min_conf {
                out.push((ind0[i], ind1[j], p));
            }
        }
        out
    }
}

fn log_sum_exp(v: &[f32]) -> f32 {
    let max = v.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    max + v.iter().map(|x| (x - max).exp()).sum::<f32>().ln()
}

impl Matcher for LighterGlue {
    fn name(&self) -> &str {
        "lighterglue"
    }

    /// Needs [`LighterGlueOptions::image_size`]; `distance` is `1 - p` for
    /// assignment probability `p`.
    fn match_features(&self, a: &Features, b: &Features) -> Result<Vec<Match>, FeatureError> {
        a.validate()?;
        b.validate()?;
        if a.is_empty() || b.is_empty() {
            return Ok(Vec::new());
        }
        let size = self.opts.image_size.ok_or_else(|| FeatureError::InvalidOptions {
            what: "LighterGlue",
            reason: "image_size must be set to use it through the Matcher interface".into(),
        })?;
        let desc = |f: &Features| -> Result<Vec<f32>, FeatureError> {
            match &f.descriptors {
                Descriptors::Float { dim, data } if *dim == DESCRIPTOR_DIM => Ok(data.clone()),
                _ => Err(FeatureError::DescriptorMismatch(format!(
                    "LighterGlue needs {DESCRIPTOR_DIM}-dimensional float (XFeat) descriptors"
                ))),
            }
        };
        let (da, db) = (desc(a)?, desc(b)?);
        let ka: Vec<[f32; 2]> = a.keypoints.iter().map(|k| [k.x, k.y]).collect();
        let kb: Vec<[f32; 2]> = b.keypoints.iter().map(|k| [k.x, k.y]).collect();
        let m = self.match_pair(
            GlueInput { keypoints: &ka, descriptors: &da, image_size: size },
            GlueInput { keypoints: &kb, descriptors: &db, image_size: size },
        )?;
        Ok(m.into_iter().map(|(q, t, p)| Match { query: q, train: t, distance: 1.0 - p }).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn math_helpers() {
        // erf(0.5) = 0.520499877813047, erf(3.5) = 0.999999256901628,
        // gelu(1) = 0.8413447461.
        for (x, want) in [(0.5, 0.520_499_877_813_047), (-3.5, -0.999_999_256_901_628), (2.9, 0.999_958_902_121_900_2)]
        {
            assert!((erf(x) - want).abs() < 1.5e-7, "erf({x})");
        }
        assert!(erf(0.0).abs() < 1.5e-7);
        assert!((gelu(1.0) - 0.841_344_7).abs() < 1e-6);
        assert!((gelu(-3.0) - (-0.004_049_94)).abs() < 1e-6);
        assert!((log_sigmoid(0.0) + std::f32::consts::LN_2).abs() < 1e-7);
        assert!((log_sigmoid(-100.0) + 100.0).abs() < 1e-4);
        let mut m = vec![1.0, 2.0, 3.0, 0.0, 0.0, 0.0];
        softmax_rows(&mut m, 3);
        assert!((m[0] + m[1] + m[2] - 1.0).abs() < 1e-6 && (m[3] - 1.0 / 3.0).abs() < 1e-6);
        assert!((log_sum_exp(&[0.0, 0.0]) - std::f32::consts::LN_2).abs() < 1e-6);
    }

    #[test]
    fn options_validate() {
        assert!(LighterGlueOptions::default().validate().is_ok());
        assert!(LighterGlueOptions { min_conf: 1.0, ..Default::default() }.validate().is_err());
        assert!(LighterGlueOptions { width_confidence: f32::NAN, ..Default::default() }.validate().is_err());
        assert!(LighterGlueOptions { image_size: Some([0, 5]), ..Default::default() }.validate().is_err());
    }
}
