//! The frame panel of a loaded model: where the model's images are on disk
//! ([`ImageSource`], COLMAP's `image_path`), each camera's keypoints by state
//! ([`camera_detail`]) and the picture the page shows ([`load_picture`]).
//!
//! Only images the model names are ever read: the page asks by image id, the
//! server looks the name up in the model and resolves it under the images
//! folder (a name that leaves it, through `..`, an absolute path or a
//! symbolic link, is refused), in the listed frames of the run's input, or as
//! a frame index of the run's video.

use colslam_io::{ImageSequence, Layout, SourceOptions, VideoSource, detect_layout};
use colslam_scene::{ImageId, Reconstruction};
use serde_json::{Value, json};
use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

/// Keypoint states sent to the page (`state` array of [`camera_detail`]).
pub const KEYPOINT_UNMATCHED: u8 = 0;
/// A keypoint with a 3D point that reprojects within the threshold.
pub const KEYPOINT_TRIANGULATED: u8 = 1;
/// A keypoint with a 3D point that reprojects beyond the threshold (or not at all).
pub const KEYPOINT_OUTLIER: u8 = 2;

/// Folders below the model searched for a `report.json` naming the run's input:
/// the model itself (a run's output folder) and two levels up (`out/maps/1`).
const REPORT_SEARCH_LEVELS: usize = 3;

/// Where the images of a model are.
#[derive(Debug, Clone, PartialEq)]
pub enum ImageSource {
    /// Image names are relative to this folder (COLMAP's `image_path`).
    Folder(PathBuf),
    /// The frames of an image-sequence input (TUM, EuRoC, KITTI, a folder):
    /// file name to file, as the project's frame source lists them.
    Sequence {
        /// The input as the run's report names it.
        input: PathBuf,
        /// File name -> path of every listed frame.
        files: HashMap<String, PathBuf>,
        /// File name -> the frame's timestamp as the run saw it (from the
        /// layout's list), which an image name need not hold.
        stamps: HashMap<String, f64>,
    },
    /// The frames of a video input, decoded through the project's video
    /// source (`ffmpeg`) by the source index in the frame's name.
    Video(PathBuf),
    /// No images: the reason, shown in the panel.
    Missing(String),
}

/// Why a picture cannot be served.
#[derive(Debug, thiserror::Error)]
pub enum PictureError {
    /// The model has no image with this id.
    #[error("the model has no image {0}")]
    UnknownImage(u32),
    /// The model's name for the image leaves the images folder.
    #[error("image name {0:?} is not inside the images folder: refused")]
    Refused(String),
    /// No images are known, or this one is not among them.
    #[error("{0}")]
    Missing(String),
    /// Decoding the file failed.
    #[error("cannot read image {name:?}")]
    Decode {
        /// The model's name of the image.
        name: String,
        /// The cause.
        source: colslam_image::ImageError,
    },
    /// Decoding a video frame failed.
    #[error("cannot decode frame {name:?} of the video")]
    Video {
        /// The frame's name.
        name: String,
        /// The cause.
        source: colslam_io::SourceError,
    },
}

impl PictureError {
    /// The HTTP status the server answers with.
    pub fn status(&self) -> u16 {
        match self {
            Self::UnknownImage(_) | Self::Missing(_) => 404,
            Self::Refused(_) => 403,
            Self::Decode { .. } | Self::Video { .. } => 500,
        }
    }
}

/// Why an explicit images location cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct ImagesOptionError {
    /// The path given.
    pub path: PathBuf,
    /// What is wrong with it.
    pub reason: String,
}

impl ImageSource {
    /// The images location given by the user (`--images`): a folder, or a
    /// video file. It must exist.
    pub fn given(path: &Path) -> Result<ImageSource, ImagesOptionError> {
        if path.is_dir() {
            return Ok(ImageSource::Folder(path.to_path_buf()));
        }
        if path.is_file() {
            return match detect_layout(path) {
                Ok(Layout::Video { file }) => Ok(ImageSource::Video(file)),
                _ => Err(ImagesOptionError {
                    path: path.to_path_buf(),
                    reason: "is a file but not a video: give the folder of the images".into(),
                }),
            };
        }
        Err(ImagesOptionError { path: path.to_path_buf(), reason: "no such folder".into() })
    }

    /// Finds the images of the model read from `model_dir` when none were
    /// given: the input named by a colslam run's `report.json` (in the model
    /// folder or up to two above), else the first of `model/images`, the
    /// folder above the model, its `rgb/` and its `images/` that holds the
    /// first registered image.
    pub fn discover(model_dir: &Path, rec: &Reconstruction) -> ImageSource {
        let mut looked = Vec::new();
        for dir in model_dir.ancestors().take(REPORT_SEARCH_LEVELS) {
            let report = dir.join("report.json");
            if let Some(src) = from_report(&report) {
                tracing::debug!("images of {}: the input named by {}", model_dir.display(), report.display());
                return src;
            }
        }
        let Some(first) = rec.registered_image_ids().first().and_then(|id| rec.image(*id)) else {
            return ImageSource::Missing("the model has no registered image".into());
        };
        let parent = model_dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let candidates = [model_dir.join("images"), parent.to_path_buf(), parent.join("rgb"), parent.join("images")];
        for dir in candidates {
            if resolve_in_folder(&dir, &first.name).is_ok_and(|p| p.is_file()) {
                tracing::debug!("images of {}: {}", model_dir.display(), dir.display());
                return ImageSource::Folder(dir);
            }
            looked.push(dir.display().to_string());
        }
        ImageSource::Missing(format!(
            "no images found for this model (looked for {:?} in {}); start the viewer with --images DIR",
            first.name,
            looked.join(", ")
        ))
    }

    /// One line for the page: where the images come from, or why none.
    pub fn describe(&self) -> String {
        match self {
            ImageSource::Folder(d) => format!("images from {}", d.display()),
            ImageSource::Sequence { input, .. } => format!("frames of {}", input.display()),
            ImageSource::Video(f) => format!("frames decoded from the video {}", f.display()),
            ImageSource::Missing(why) => why.clone(),
        }
    }

    /// The timestamp of the model's image `name` when this source knows it
    /// (a run's listed input), for comparing the model with a ground truth.
    pub fn timestamp(&self, name: &str) -> Option<f64> {
        match self {
            ImageSource::Sequence { stamps, .. } => stamps.get(name).copied(),
            _ => None,
        }
    }

    /// Whether pictures can be asked for at all.
    pub fn available(&self) -> bool {
        !matches!(self, ImageSource::Missing(_))
    }
}

/// The input named by a run's `report.json`, when it still exists.
fn from_report(report: &Path) -> Option<ImageSource> {
    let text = std::fs::read(report).ok()?;
    let v: Value = serde_json::from_slice(&text).ok()?;
    let input = PathBuf::from(v.get("input")?.as_str()?);
    match detect_layout(&input).ok()? {
        Layout::Video { file } => Some(ImageSource::Video(file)),
        layout => {
            let seq = ImageSequence::open_layout(&input, layout, &SourceOptions::default()).ok()?;
            let (mut files, mut stamps) = (HashMap::new(), HashMap::new());
            for frame in seq.listed() {
                stamps.insert(frame.name.clone(), frame.timestamp);
                files.insert(frame.name, frame.path.to_path_buf());
            }
            Some(ImageSource::Sequence { input, files, stamps })
        }
    }
}

/// `dir/name` when `name` stays inside `dir`: relative, only plain
/// components, and (resolving symbolic links) still under `dir` when it exists.
fn resolve_in_folder(dir: &Path, name: &str) -> Result<PathBuf, PictureError> {
    let rel = Path::new(name);
    let plain = !name.is_empty() && rel.components().all(|c| matches!(c, Component::Normal(_)));
    if !plain {
        return Err(PictureError::Refused(name.to_string()));
    }
    let path = dir.join(rel);
    if let (Ok(real), Ok(root)) = (path.canonicalize(), dir.canonicalize())
        && !real.starts_with(&root)
    {
        return Err(PictureError::Refused(name.to_string()));
    }
    Ok(path)
}

/// The source index of a video frame's name (`frame_000123` -> 123), the
/// names the project's video source gives.
fn video_frame_index(name: &str) -> Option<usize> {
    let stem = Path::new(name).file_stem()?.to_str()?;
    stem.strip_prefix("frame_")?.parse().ok()
}

/// The picture of image `id` of `rec`, decoded from `source` (bounded by
/// the image crate's limits) and made at most `max_width` wide.
pub fn load_picture(
    rec: &Reconstruction,
    source: &ImageSource,
    id: u32,
    max_width: usize,
) -> Result<colslam_image::Image, PictureError> {
    let img = rec.image(ImageId(id)).ok_or(PictureError::UnknownImage(id))?;
    let name = &img.name;
    let image = match source {
        ImageSource::Missing(why) => return Err(PictureError::Missing(why.clone())),
        ImageSource::Folder(dir) => {
            let path = resolve_in_folder(dir, name)?;
            if !path.is_file() {
                return Err(PictureError::Missing(format!("{} does not exist", path.display())));
            }
            colslam_image::Image::read(&path).map_err(|source| PictureError::Decode { name: name.clone(), source })?
        }
        ImageSource::Sequence { input, files, .. } => {
            let path = files
                .get(name)
                .ok_or_else(|| PictureError::Missing(format!("{name:?} is not a frame of {}", input.display())))?;
            colslam_image::Image::read(path).map_err(|source| PictureError::Decode { name: name.clone(), source })?
        }
        ImageSource::Video(file) => {
            let index = video_frame_index(name).ok_or_else(|| {
                PictureError::Missing(format!("{name:?} is not a frame name of a video (frame_NNNNNN)"))
            })?;
            let opts = SourceOptions { start: index, max_frames: Some(1), ..SourceOptions::default() };
            let video = |source| PictureError::Video { name: name.clone(), source };
            let mut src = VideoSource::open(file, &opts).map_err(video)?;
            match src.next() {
                Some(frame) => frame.map_err(video)?.image,
                None => return Err(PictureError::Missing(format!("the video has no frame {index}"))),
            }
        }
    };
    Ok(crate::downscale_for_view(&image, max_width).0)
}

/// What the page shows of camera `id`: name, timestamp, keypoints (pixel
/// coordinates of the full image, COLMAP convention) with their state, the
/// counts per state, the observations and their mean reprojection error.
/// `max_error` (pixels) separates triangulated keypoints from outliers.
/// `None` when the model has no such image.
pub fn camera_detail(rec: &Reconstruction, id: u32, max_error: f64) -> Option<Value> {
    let img = rec.image(ImageId(id))?;
    let cam = rec.camera(img.camera_id).map(|c| &c.camera);
    let mut xy = Vec::with_capacity(2 * img.points2d.len());
    let mut state = Vec::with_capacity(img.points2d.len());
    let (mut triangulated, mut outliers, mut unmatched) = (0usize, 0usize, 0usize);
    let (mut err_sum, mut err_n) = (0.0, 0usize);
    for kp in &img.points2d {
        xy.push(kp.xy.x as f32);
        xy.push(kp.xy.y as f32);
        let point = kp.point3d_id.and_then(|p| rec.point3d(p));
        let s = match (point, cam) {
            (None, _) => {
                unmatched += 1;
                KEYPOINT_UNMATCHED
            }
            (Some(p), cam) => {
                let err = cam.and_then(|c| {
                    colslam_scene::projection::reprojection_error(c, &img.cam_from_world, &p.xyz, &kp.xy)
                });
                if let Some(e) = err {
                    err_sum += e;
                    err_n += 1;
                }
                if err.is_some_and(|e| e <= max_error) {
                    triangulated += 1;
                    KEYPOINT_TRIANGULATED
                } else {
                    outliers += 1;
                    KEYPOINT_OUTLIER
                }
            }
        };
        state.push(s);
    }
    let (w, h) = cam.map_or((0, 0), |c| (c.width, c.height));
    Some(json!({
        "id": id,
        "name": img.name,
        "timestamp": crate::export::name_timestamp(&img.name),
        "width": w, "height": h,
        "keypoints": { "xy": xy, "state": state },
        "counts": { "triangulated": triangulated, "outlier": outliers, "unmatched": unmatched },
        "observations": triangulated + outliers,
        "mean_reproj_error": if err_n > 0 { Some(err_sum / err_n as f64) } else { None },
        "max_error": max_error,
    }))
}
