//! The XFeat network (Potje et al., "XFeat: Accelerated Features for
//! Lightweight Image Matching", CVPR 2024; architecture as in the authors'
//! `XFeatModel`): a small CNN with a 1/8-resolution 64-channel descriptor
//! map, a 65-channel keypoint logit map computed from 8x8 pixel-unshuffled
//! input, and a reliability heatmap. Inference only; every
//! Conv-BatchNorm-ReLU block is folded into one biased convolution at load
//! time (`w' = w / sqrt(var + eps)`, `b' = -mean / sqrt(var + eps)`; the
//! BatchNorms have no affine parameters).

use crate::XFeatError;
use crate::nn::{Conv, Map, NORM_EPS, add_into, avg_pool, instance_norm, pixel_unshuffle, resize_bilinear};
use crate::weights::StateDict;
use std::path::Path;

/// The network's input size must be a multiple of this (five stride-2 steps).
pub const SIZE_MULTIPLE: usize = 32;
/// Descriptor / heatmap resolution relative to the input.
pub const CELL: usize = 8;
/// Descriptor length.
pub const DESCRIPTOR_DIM: usize = 64;
/// Keypoint logit channels: 64 cell positions plus a "no keypoint" dustbin.
pub const KEYPOINT_CHANNELS: usize = CELL * CELL + 1;
/// Side of the average pooling on the skip path.
const SKIP_POOL: usize = 4;

/// Outputs of one forward pass at 1/8 of the input resolution.
#[derive(Debug, Clone)]
pub struct DenseOutput {
    /// Raw (not normalised) descriptor map, `64 x H/8 x W/8` (`feats`).
    pub descriptors: Map,
    /// Keypoint logits, `65 x H/8 x W/8` (`keypoints`).
    pub keypoint_logits: Map,
    /// Reliability heatmap after the sigmoid, `1 x H/8 x W/8` (`heatmap`).
    pub reliability: Map,
}

/// The XFeat CNN with folded weights.
#[derive(Debug, Clone)]
pub struct XFeatModel {
    skip1: Conv,
    block1: Vec<Conv>,
    block2: Vec<Conv>,
    block3: Vec<Conv>,
    block4: Vec<Conv>,
    block5: Vec<Conv>,
    fusion: Vec<Conv>,
    heatmap_head: Vec<Conv>,
    keypoint_head: Vec<Conv>,
}

/// `(cin, cout, kernel, stride)` of a block's BasicLayers (padding is 1 for
/// 3x3 kernels and 0 for 1x1).
type LayerSpec = (usize, usize, usize, usize);

const BLOCK1: &[LayerSpec] = &[(1, 4, 3, 1), (4, 8, 3, 2), (8, 8, 3, 1), (8, 24, 3, 2)];
const BLOCK2: &[LayerSpec] = &[(24, 24, 3, 1), (24, 24, 3, 1)];
const BLOCK3: &[LayerSpec] = &[(24, 64, 3, 2), (64, 64, 3, 1), (64, 64, 1, 1)];
const BLOCK4: &[LayerSpec] = &[(64, 64, 3, 2), (64, 64, 3, 1), (64, 64, 3, 1)];
const BLOCK5: &[LayerSpec] = &[(64, 128, 3, 2), (128, 128, 3, 1), (128, 128, 3, 1), (128, 64, 1, 1)];
const FUSION: &[LayerSpec] = &[(64, 64, 3, 1), (64, 64, 3, 1)];
const HEATMAP: &[LayerSpec] = &[(64, 64, 1, 1), (64, 64, 1, 1)];
const KEYPOINT: &[LayerSpec] = &[(64, 64, 1, 1), (64, 64, 1, 1), (64, 64, 1, 1)];

/// One Conv(bias=False) -> BatchNorm(affine=False) -> ReLU, folded.
fn basic_layer(sd: &StateDict, prefix: &str, (cin, cout, k, stride): LayerSpec) -> Result<Conv, XFeatError> {
    let w = sd.get(&format!("{prefix}.layer.0.weight"), &[cout, cin, k, k])?;
    let mean = sd.get(&format!("{prefix}.layer.1.running_mean"), &[cout])?;
    let var = sd.get(&format!("{prefix}.layer.1.running_var"), &[cout])?;
    let per_out = cin * k * k;
    let mut weight = w.data.clone();
    let mut bias = vec![0.0f32; cout];
    for o in 0..cout {
        let inv = 1.0 / (f64::from(var.data[o]) + NORM_EPS).sqrt();
        for v in &mut weight[o * per_out..(o + 1) * per_out] {
            *v = (f64::from(*v) * inv) as f32;
        }
        bias[o] = (-f64::from(mean.data[o]) * inv) as f32;
    }
    Ok(Conv { cout, cin, k, stride, pad: k / 2, weight, bias, relu: true })
}

/// A plain biased 1x1 convolution.
fn plain_conv(sd: &StateDict, prefix: &str, cin: usize, cout: usize) -> Result<Conv, XFeatError> {
    let w = sd.get(&format!("{prefix}.weight"), &[cout, cin, 1, 1])?;
    let b = sd.get(&format!("{prefix}.bias"), &[cout])?;
    Ok(Conv { cout, cin, k: 1, stride: 1, pad: 0, weight: w.data.clone(), bias: b.data.clone(), relu: false })
}

fn block(sd: &StateDict, name: &str, specs: &[LayerSpec]) -> Result<Vec<Conv>, XFeatError> {
    specs.iter().enumerate().map(|(i, &s)| basic_layer(sd, &format!("{name}.{i}"), s)).collect()
}

fn run(layers: &[Conv], x: Map) -> Map {
    layers.iter().fold(x, |acc, l| l.forward(&acc))
}

impl XFeatModel {
    /// Builds the network from an XFeat state dict (`xfeat.pt`).
    pub fn from_state_dict(sd: &StateDict) -> Result<Self, XFeatError> {
        let mut fusion = block(sd, "block_fusion", FUSION)?;
        fusion.push(plain_conv(sd, "block_fusion.2", 64, 64)?);
        let mut heatmap_head = block(sd, "heatmap_head", HEATMAP)?;
        heatmap_head.push(plain_conv(sd, "heatmap_head.2", 64, 1)?);
        let mut keypoint_head = block(sd, "keypoint_head", KEYPOINT)?;
        keypoint_head.push(plain_conv(sd, "keypoint_head.3", 64, KEYPOINT_CHANNELS)?);
        Ok(Self {
            skip1: plain_conv(sd, "skip1.1", 1, 24)?,
            block1: block(sd, "block1", BLOCK1)?,
            block2: block(sd, "block2", BLOCK2)?,
            block3: block(sd, "block3", BLOCK3)?,
            block4: block(sd, "block4", BLOCK4)?,
            block5: block(sd, "block5", BLOCK5)?,
            fusion,
            heatmap_head,
            keypoint_head,
        })
    }

    /// Reads `xfeat.pt` and builds the network.
    pub fn load(path: &Path) -> Result<Self, XFeatError> {
        Self::from_state_dict(&StateDict::read(path)?)
    }

    /// Runs the network on a one-channel image whose height and width are
    /// positive multiples of [`SIZE_MULTIPLE`] (values in any range: the
    /// input is instance-normalised first, as the reference does).
    pub fn forward(&self, gray: &Map) -> Result<DenseOutput, XFeatError> {
        if gray.c != 1
            || gray.h == 0
            || gray.w == 0
            || !gray.h.is_multiple_of(SIZE_MULTIPLE)
            || !gray.w.is_multiple_of(SIZE_MULTIPLE)
        {
            return Err(XFeatError::InvalidOptions {
                what: "XFeat network input",
                reason: format!(
                    "expected 1 x H x W with H, W positive multiples of {SIZE_MULTIPLE}, got {} x {} x {}",
                    gray.c, gray.h, gray.w
                ),
            });
        }
        let mut x = gray.clone();
        instance_norm(&mut x);
        let x1 = run(&self.block1, x.clone());
        let mut skip = self.skip1.forward(&avg_pool(&x, SKIP_POOL));
        add_into(&mut skip, &x1);
        let x2 = run(&self.block2, skip);
        let x3 = run(&self.block3, x2);
        let x4 = run(&self.block4, x3.clone());
        let x5 = run(&self.block5, x4.clone());
        // Pyramid fusion at 1/8 resolution.
        let (h3, w3) = (x3.h, x3.w);
        let mut fused = x3;
        add_into(&mut fused, &resize_bilinear(&x4, h3, w3));
        add_into(&mut fused, &resize_bilinear(&x5, h3, w3));
        let feats = run(&self.fusion, fused);
        let mut heat = run(&self.heatmap_head, feats.clone());
        for v in &mut heat.data {
            *v = 1.0 / (1.0 + (-*v).exp());
        }
        let logits = run(&self.keypoint_head, pixel_unshuffle(&x, CELL));
        Ok(DenseOutput { descriptors: feats, keypoint_logits: logits, reliability: heat })
    }
}
