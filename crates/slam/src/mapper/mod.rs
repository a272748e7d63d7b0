//! The mapper: one map of a run, a COLMAP reconstruction and correspondence
//! graph grown keyframe by keyframe (paper 3.3-3.6), and the records of the
//! non-keyframes that are localised against it at the end.
//!
//! As COLMAP's `IncrementalMapper`, it offers the steps and keeps its state
//! private; the tracking policy that decides their order lives in
//! the pipeline (`pipeline.rs`). The steps, one file each:
//! - [`Mapper::initialize`] (`init.rs`): the initial pair search;
//! - [`Mapper::register_keyframe`] (`register.rs`): registration,
//!   triangulation, local refinement, local filtering and deregistration;
//! - [`Mapper::global_refine`] and [`Mapper::needs_global_refine`] (here): the
//!   global BA schedule;
//! - [`Mapper::localize_all`] and [`Mapper::refine_with_all_frames`]
//!   (`localize.rs`);
//! - keyframe culling after registration (`cull.rs`, `--cull-keyframes`);
//! - [`Mapper::merge`] (`merge.rs`): joining a second map;
//! - [`Mapper::match_overlapping_pairs`] (`overlap.rs`): matching the
//!   keyframe pairs whose views overlap but were never matched, at the end;
//! - [`Mapper::refine_observations`] (`observations.rs`,
//!   `--refine-observations`): the keyframes' observations moved by patch
//!   alignment to their track's reference, at the end;
//! - rolling-shutter compensation (`rolling_shutter.rs`);
//! - [`Mapper::close_loop`] (`loop_closure.rs`, `--loop-closure`): loop
//!   detection by appearance after a keyframe, Sim(3) verification and
//!   correction.

mod cull;
pub(crate) mod init;
mod local_map;
mod localize;
mod loop_closure;
mod merge;
pub mod observations;
mod overlap;
mod probe;
mod register;
pub mod rolling_shutter;
mod state;

pub use localize::{FrameInliers, Localization};
pub use loop_closure::LoopClosure;
pub use overlap::OverlapReport;
pub use register::{RegisterFailure, Registration};
pub use state::{Keyframe, Mapper, ORB_LEVEL_SCALE, keypoint_sigmas};

#[cfg(test)]
mod tests;
