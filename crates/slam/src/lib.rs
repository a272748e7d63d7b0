//! The offline SLAM pipeline of the paper (*Build an Offline Python SLAM
//! using COLMAP*, Bozic et al., sections 3.1-3.6), on colslam's native
//! COLMAP parts: ORB features and Hamming matching, the optical-flow
//! keyframe test, initialisation from the first N frames, registration and
//! triangulation with the point-count check, local and global bundle
//! adjustment with normalisation, track merge/complete and filtering; plus
//! what the paper lacks: a pure-rotation guard, forced keyframes before
//! tracking is lost, localisation of every frame, and new maps after a loss.

pub mod error;
pub mod events;
pub mod frontend;
pub mod map;
pub mod merge;
pub mod options;
pub mod output;
pub mod pipeline;
pub mod rolling_shutter;
pub mod timing;

pub use error::SlamError;
pub use events::{EventPoint, EventSink, SlamEvent};
pub use options::SlamOptions;
pub use output::{OutputFormat, RunReport, write_outputs, write_report};
pub use pipeline::{FrameInfo, MapResult, Slam, SlamResult};
pub use timing::{Stage, StageTimings};
