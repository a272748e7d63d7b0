//! The map state in COLMAP's terms and COLMAP model I/O.
//!
//! * [`Reconstruction`]: cameras, images, 3D points and tracks with typed ids
//!   ([`CameraId`], [`ImageId`], [`Point3DId`]), deterministic (`BTreeMap`)
//!   iteration, and the operations an incremental mapper needs, each keeping
//!   the 2D<->3D links consistent (after COLMAP's
//!   `src/colmap/scene/reconstruction.h`).
//! * [`read_model`] / [`write_model`]: COLMAP sparse model folders in binary
//!   (`cameras.bin`, `images.bin`, `points3D.bin`, plus COLMAP 4's `rigs.bin`
//!   and `frames.bin`) and text (`.txt`), byte-compatible with COLMAP 4 /
//!   pycolmap 4.2.
//! * [`write_ply`]: coloured point clouds.

pub mod error;
pub mod ids;
pub mod io;
pub mod ply;
pub mod projection;
pub mod reconstruction;
pub mod types;

pub use error::SceneError;
pub use ids::{CameraId, ImageId, Point3DId};
pub use io::{
    MODEL_FILE_NAMES, ModelFormat, begin_model_output, read_model, read_model_format, write_model, write_model_files,
};
pub use ply::{PlyFormat, write_ply, write_ply_with};
pub use reconstruction::{
    DeregisterReport, FilterReport, NormalizeOptions, ObservationRemoval, Reconstruction, triangulation_angle,
};
pub use types::{Camera, Image, Point2D, Point3D, TrackElement, UNKNOWN_ERROR};
