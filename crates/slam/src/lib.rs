//! The offline SLAM pipeline of the paper (*Build an Offline Python SLAM
//! using COLMAP*, Bozic et al., sections 3.1-3.6), on colslam's native
//! COLMAP parts, as a library:
//!
//! - [`run::run`] drives a source end to end (reader thread, cancellation,
//!   events, outputs, report), as `colslam run` and the viewer do;
//! - [`Slam`] is the controller (tracking policy) fed frame by frame;
//! - [`mapper::Mapper`] offers the steps (initialise, register, triangulate,
//!   refine, filter, deregister, merge, localise) on one map;
//! - [`options::SlamOptions`] is the one options tree.
//!
//! ```no_run
//! use colslam_slam::{EventSink, RunConfig, RunHooks};
//! # fn main() -> Result<(), colslam_slam::SlamError> {
//! let mut config = RunConfig::new("video.mp4", "out");
//! config.options.slam.keyframes.flow_threshold = 0.04; // the options tree of `colslam run --help`
//! let out = colslam_slam::run::run(&config, EventSink::none(), RunHooks::default())?;
//! println!("{} of {} frames localised", out.report.localized, out.report.frames);
//! # Ok(())
//! # }
//! ```
//!
//! Beyond the paper: a pure-rotation guard, forced keyframes before
//! tracking is lost, backward tracking from a late map, localisation of
//! every frame, new maps after a loss and their merging, rolling-shutter
//! compensation.

pub mod calibrate;
pub mod error;
pub mod events;
pub mod export;
pub mod frame;
pub mod frontend;
pub mod keyframe;
pub mod mapper;
pub mod options;
pub mod output;
pub mod patch;
pub mod pipeline;
pub mod records;
pub mod run;
pub mod timing;

pub use error::{SlamError, error_chain};
pub use events::{EventPoint, EventSink, SlamEvent};
pub use export::{
    ExportError, ExportProgress, ExportSummary, FrameSelection, SceneExport, SceneFormat, export_scene,
    export_scene_with,
};
pub use frame::{FrameData, FrameId, FramePose, FrameRecord};
pub use mapper::observations::{FrameImages, ObservationRefinement, TrackTemplates};
pub use mapper::rolling_shutter;
pub use options::{FeatureKind, LocalMapSearch, MatcherKind, RollingShutter, SlamOptions};
pub use output::{
    IntrinsicsSummary, OutputFormat, RUN_OUTPUT_NAMES, RunReport, begin_run_output, write_outputs, write_report,
};
pub use pipeline::{MapResult, RunStats, Slam, SlamResult};
pub use run::{CameraOptions, CameraSource, InputOptions, RunConfig, RunHooks, RunOptions, RunOutput, RunStart};
pub use timing::{Stage, StageTimings};
