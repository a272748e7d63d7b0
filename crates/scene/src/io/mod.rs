//! COLMAP sparse model folders: binary (`*.bin`) and text (`*.txt`).
//!
//! File formats follow COLMAP 4 (`src/colmap/scene/reconstruction_io_binary.cc`
//! and `reconstruction_io_text.cc`; independent implementation):
//! * `cameras`, `images`, `points3D` as in every COLMAP version;
//! * `rigs` and `frames` (COLMAP 4 / pycolmap 4.x). They are read when
//!   present and validated against the images (every image must belong to a
//!   frame of a rig holding its camera, and its pose must agree with the
//!   frame's). This crate models one camera per image, so rig structure is not
//!   kept: on writing, each camera becomes a single-sensor rig
//!   (`rig_id = camera_id`) and each registered image its own frame
//!   (`frame_id = image_id`), which is what pycolmap itself writes for
//!   single-camera models.
//!
//! As in COLMAP 4, only registered images are written (`images.bin` holds
//! `NumRegImages()` records, in registration order), so unregistered images do
//! not survive a write; every image read from a model is registered, and the
//! registration order is the file order.
//!
//! [`write_model`] writes a model folder as a whole (see
//! [`colslam_image::OutputDir`]): into a staging folder beside it, swapped in
//! when complete, so a reader finds the previous model or the new one, never
//! a mix, and no file of another format or an earlier model survives.
//! [`write_model_files`] writes the files into a folder of a larger output
//! that is itself written as a whole (a run's outputs).

mod binary;
mod fmt;
mod text;

pub use fmt::format_g17;

use crate::error::SceneError;
use crate::ids::{CameraId, ImageId, Point3DId};
use crate::reconstruction::Reconstruction;
use crate::types::{Camera, Image, Point2D, Point3D, TrackElement};
use colslam_geometry::{Quat, Rigid3, Vec2, Vec3};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// The on-disk format of a model folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelFormat {
    /// `cameras.bin`, `images.bin`, `points3D.bin`, `rigs.bin`, `frames.bin`.
    Binary,
    /// The same with `.txt`.
    Text,
}

impl ModelFormat {
    /// File extension without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            Self::Binary => "bin",
            Self::Text => "txt",
        }
    }
}

/// Base names of the model files.
const CAMERAS: &str = "cameras";
const IMAGES: &str = "images";
const POINTS3D: &str = "points3D";
const RIGS: &str = "rigs";
const FRAMES: &str = "frames";

/// Largest accepted deviation of a stored quaternion's norm from 1. Stored
/// quaternions are kept bit-exact (not re-normalised) so files round trip.
const QUAT_NORM_TOLERANCE: f64 = 1e-6;

/// Tolerance (relative to the translation's magnitude, plus an absolute
/// floor) when checking that an image pose agrees with its frame's.
const POSE_AGREEMENT_TOLERANCE: f64 = 1e-9;

/// COLMAP's `SensorType` values.
pub(crate) const SENSOR_CAMERA: i32 = 0;

fn file(dir: &Path, base: &str, format: ModelFormat) -> PathBuf {
    dir.join(format!("{base}.{}", format.extension()))
}

/// Reads a model folder, choosing binary when `cameras.bin`, `images.bin`
/// and `points3D.bin` all exist, else text (COLMAP's `Reconstruction::Read`).
pub fn read_model(dir: &Path) -> Result<Reconstruction, SceneError> {
    let has = |f: ModelFormat| [CAMERAS, IMAGES, POINTS3D].iter().all(|b| file(dir, b, f).is_file());
    if has(ModelFormat::Binary) {
        read_model_format(dir, ModelFormat::Binary)
    } else if has(ModelFormat::Text) {
        read_model_format(dir, ModelFormat::Text)
    } else {
        let missing: Vec<String> = [ModelFormat::Binary, ModelFormat::Text]
            .iter()
            .flat_map(|f| [CAMERAS, IMAGES, POINTS3D].map(|b| (b, *f)))
            .filter(|(b, f)| !file(dir, b, *f).is_file())
            .map(|(b, f)| format!("{b}.{}", f.extension()))
            .collect();
        Err(SceneError::MissingFiles { dir: dir.to_path_buf(), missing: missing.join(", ") })
    }
}

/// Reads a model folder in the given format. `rigs` and `frames` files are
/// optional; the other three are required.
pub fn read_model_format(dir: &Path, format: ModelFormat) -> Result<Reconstruction, SceneError> {
    let paths = ModelPaths::new(dir, format);
    for p in [&paths.cameras, &paths.images, &paths.points3d] {
        if !p.is_file() {
            return Err(SceneError::MissingFiles {
                dir: dir.to_path_buf(),
                missing: p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            });
        }
    }
    let read = |p: &Path| std::fs::read(p).map_err(|e| SceneError::io(p, e));
    let optional = |p: &Path| if p.is_file() { read(p).map(Some) } else { Ok(None) };
    let raw = match format {
        ModelFormat::Binary => RawModel {
            cameras: binary::parse_cameras(&paths.cameras, &read(&paths.cameras)?)?,
            rigs: optional(&paths.rigs)?.map(|b| binary::parse_rigs(&paths.rigs, &b)).transpose()?,
            frames: optional(&paths.frames)?.map(|b| binary::parse_frames(&paths.frames, &b)).transpose()?,
            images: binary::parse_images(&paths.images, &read(&paths.images)?)?,
            points: binary::parse_points(&paths.points3d, &read(&paths.points3d)?)?,
        },
        ModelFormat::Text => {
            let text = |p: &Path| {
                let bytes = read(p)?;
                String::from_utf8(bytes).map_err(|e| SceneError::Corrupt {
                    path: p.to_path_buf(),
                    offset: e.utf8_error().valid_up_to(),
                    what: "not UTF-8 text".into(),
                })
            };
            let opt_text = |p: &Path| if p.is_file() { text(p).map(Some) } else { Ok(None) };
            RawModel {
                cameras: text::parse_cameras(&paths.cameras, &text(&paths.cameras)?)?,
                rigs: opt_text(&paths.rigs)?.map(|t| text::parse_rigs(&paths.rigs, &t)).transpose()?,
                frames: opt_text(&paths.frames)?.map(|t| text::parse_frames(&paths.frames, &t)).transpose()?,
                images: text::parse_images(&paths.images, &text(&paths.images)?)?,
                points: text::parse_points(&paths.points3d, &text(&paths.points3d)?)?,
            }
        }
    };
    assemble(raw, &paths)
}

/// The names a model folder holds: the five files in either format.
pub const MODEL_FILE_NAMES: [&str; 10] = [
    "cameras.bin",
    "images.bin",
    "points3D.bin",
    "rigs.bin",
    "frames.bin",
    "cameras.txt",
    "images.txt",
    "points3D.txt",
    "rigs.txt",
    "frames.txt",
];

/// Starts writing the model folder `dir` as a whole (see
/// [`colslam_image::OutputDir::begin`]): checks the location, takes its lock
/// and creates the staging folder. `dir` may be missing, empty or a model
/// folder ([`MODEL_FILE_NAMES`]); a folder holding anything else is refused.
/// Write with [`write_model_files`] into its [`path`](colslam_image::OutputDir::path),
/// then [`commit`](colslam_image::OutputDir::commit).
pub fn begin_model_output(dir: &Path) -> Result<colslam_image::OutputDir, SceneError> {
    Ok(colslam_image::OutputDir::begin(dir, &MODEL_FILE_NAMES)?)
}

/// Writes a model folder in the given format as a whole: the folder then
/// holds this model's five files (rigs, cameras, frames, images, points3D)
/// and nothing else, or, should the write fail or be interrupted, what it
/// held before. Only registered images are written (see the module docs).
pub fn write_model(rec: &Reconstruction, dir: &Path, format: ModelFormat) -> Result<(), SceneError> {
    let out = begin_model_output(dir)?;
    write_model_files(rec, out.path(), format)?;
    Ok(out.commit()?)
}

/// Writes the five files of a model in the given format into the existing
/// folder `dir`, each atomically, leaving other files alone: the building
/// block of outputs written as a whole ([`write_model`], a run's outputs).
pub fn write_model_files(rec: &Reconstruction, dir: &Path, format: ModelFormat) -> Result<(), SceneError> {
    let paths = ModelPaths::new(dir, format);
    let files: [(&PathBuf, Vec<u8>); 5] = match format {
        ModelFormat::Binary => [
            (&paths.rigs, binary::write_rigs(rec)),
            (&paths.cameras, binary::write_cameras(rec)),
            (&paths.frames, binary::write_frames(rec)),
            (&paths.images, binary::write_images(rec, &paths.images)?),
            (&paths.points3d, binary::write_points(rec)),
        ],
        ModelFormat::Text => [
            (&paths.rigs, text::write_rigs(rec).into_bytes()),
            (&paths.cameras, text::write_cameras(rec).into_bytes()),
            (&paths.frames, text::write_frames(rec).into_bytes()),
            (&paths.images, text::write_images(rec, &paths.images)?.into_bytes()),
            (&paths.points3d, text::write_points(rec).into_bytes()),
        ],
    };
    for (path, bytes) in files {
        colslam_image::write_atomic(path, &bytes).map_err(|e| SceneError::io(path, e))?;
    }
    Ok(())
}

/// The five file paths of a model folder in one format.
pub(crate) struct ModelPaths {
    pub cameras: PathBuf,
    pub images: PathBuf,
    pub points3d: PathBuf,
    pub rigs: PathBuf,
    pub frames: PathBuf,
}

impl ModelPaths {
    fn new(dir: &Path, format: ModelFormat) -> Self {
        Self {
            cameras: file(dir, CAMERAS, format),
            images: file(dir, IMAGES, format),
            points3d: file(dir, POINTS3D, format),
            rigs: file(dir, RIGS, format),
            frames: file(dir, FRAMES, format),
        }
    }
}

/// Where a record came from, for error messages.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Loc {
    /// Byte offset of the record in a binary file.
    Byte(usize),
    /// 1-based line in a text file.
    Line(usize),
}

impl std::fmt::Display for Loc {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Loc::Byte(b) => write!(f, "record at byte {b}"),
            Loc::Line(l) => write!(f, "line {l}"),
        }
    }
}

pub(crate) struct RawSensor {
    pub kind: i32,
    pub id: u32,
    /// `sensor_from_rig`; `None` for the reference sensor and for unknown
    /// poses.
    pub pose: Option<Rigid3>,
}

pub(crate) struct RawRig {
    pub loc: Loc,
    pub id: u32,
    /// The reference sensor first.
    pub sensors: Vec<RawSensor>,
}

pub(crate) struct RawData {
    pub kind: i32,
    pub sensor_id: u32,
    pub data_id: u64,
}

pub(crate) struct RawFrame {
    pub loc: Loc,
    pub id: u32,
    pub rig_id: u32,
    pub rig_from_world: Rigid3,
    pub data: Vec<RawData>,
}

pub(crate) struct RawImage {
    pub loc: Loc,
    pub id: u32,
    pub cam_from_world: Rigid3,
    pub camera_id: u32,
    pub name: String,
    pub points2d: Vec<(Vec2, Option<u64>)>,
}

pub(crate) struct RawPoint {
    pub loc: Loc,
    pub id: u64,
    pub xyz: Vec3,
    pub color: [u8; 3],
    pub error: f64,
    pub track: Vec<(u32, u32)>,
}

pub(crate) struct RawCamera {
    pub loc: Loc,
    pub id: u32,
    pub camera: colslam_camera::Camera,
}

struct RawModel {
    cameras: Vec<RawCamera>,
    rigs: Option<Vec<RawRig>>,
    frames: Option<Vec<RawFrame>>,
    images: Vec<RawImage>,
    points: Vec<RawPoint>,
}

/// Builds a pose from stored (w, x, y, z) and translation without
/// re-normalising, after checking the quaternion is a finite unit one.
pub(crate) fn pose_from_parts(q: [f64; 4], t: [f64; 3]) -> Result<Rigid3, String> {
    if !q.iter().chain(t.iter()).all(|v| v.is_finite()) {
        return Err("pose has a non-finite value".into());
    }
    let quat = colslam_geometry::nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]);
    let norm = quat.norm();
    if (norm - 1.0).abs() > QUAT_NORM_TOLERANCE {
        return Err(format!("rotation quaternion has norm {norm}, not 1"));
    }
    Ok(Rigid3 { rotation: Quat::new_unchecked(quat), translation: Vec3::new(t[0], t[1], t[2]) })
}

/// Makes a camera from file values, mapping model errors to file errors.
/// The camera is checked with [`colslam_camera::Camera::validate`], the
/// check every camera reader applies (camera files too), so a NaN or
/// negative focal length is refused where it is read, with its location,
/// instead of being carried into a run or written back.
pub(crate) fn make_camera(
    path: &Path,
    loc: Loc,
    id: u32,
    model: colslam_camera::CameraModelId,
    width: u64,
    height: u64,
    params: Vec<f64>,
) -> Result<colslam_camera::Camera, SceneError> {
    let got = params.len();
    let camera = colslam_camera::Camera::new(model, width, height, params).map_err(|_| SceneError::ParamCount {
        path: path.to_path_buf(),
        camera: id,
        model: model.name(),
        expected: model.num_params(),
        got,
    })?;
    camera.validate().map_err(|source| SceneError::InvalidCamera {
        path: path.to_path_buf(),
        location: loc.to_string(),
        camera: id,
        source: Box::new(source),
    })?;
    Ok(camera)
}

fn inconsistent(path: &Path, loc: Loc, what: String) -> SceneError {
    SceneError::Inconsistent { path: path.to_path_buf(), what: format!("{loc}: {what}") }
}

fn poses_agree(a: &Rigid3, b: &Rigid3) -> bool {
    let dq = (a.rotation.inverse() * b.rotation).angle();
    let dt = (a.translation - b.translation).norm();
    let scale = 1.0 + a.translation.norm().max(b.translation.norm());
    dq <= POSE_AGREEMENT_TOLERANCE && dt <= POSE_AGREEMENT_TOLERANCE * scale
}

/// Checks every cross-file reference and builds the reconstruction.
fn assemble(raw: RawModel, paths: &ModelPaths) -> Result<Reconstruction, SceneError> {
    let mut cameras = BTreeMap::new();
    for c in raw.cameras {
        let id = CameraId(c.id);
        if cameras.insert(id, Camera { id, camera: c.camera }).is_some() {
            return Err(inconsistent(&paths.cameras, c.loc, format!("duplicate camera id {id}")));
        }
    }

    // Rigs and frames: image id -> (frame loc, expected cam_from_world if known, camera sensor id).
    let mut image_frames: HashMap<u32, (Loc, Option<Rigid3>, u32)> = HashMap::new();
    let have_frames = raw.frames.is_some();
    let mut rigs: HashMap<u32, RawRig> = HashMap::new();
    for r in raw.rigs.unwrap_or_default() {
        for s in &r.sensors {
            if s.kind == SENSOR_CAMERA && !cameras.contains_key(&CameraId(s.id)) {
                return Err(inconsistent(&paths.rigs, r.loc, format!("rig {} holds missing camera {}", r.id, s.id)));
            }
        }
        let (loc, id) = (r.loc, r.id);
        if rigs.insert(r.id, r).is_some() {
            return Err(inconsistent(&paths.rigs, loc, format!("duplicate rig id {id}")));
        }
    }
    let mut frame_ids = BTreeSet::new();
    for f in raw.frames.unwrap_or_default() {
        if !frame_ids.insert(f.id) {
            return Err(inconsistent(&paths.frames, f.loc, format!("duplicate frame id {}", f.id)));
        }
        let rig = rigs.get(&f.rig_id).ok_or_else(|| {
            inconsistent(&paths.frames, f.loc, format!("frame {} uses missing rig {}", f.id, f.rig_id))
        })?;
        for d in f.data.iter().filter(|d| d.kind == SENSOR_CAMERA) {
            let pos =
                rig.sensors.iter().position(|s| s.kind == SENSOR_CAMERA && s.id == d.sensor_id).ok_or_else(|| {
                    inconsistent(
                        &paths.frames,
                        f.loc,
                        format!("frame {} names camera {} that rig {} lacks", f.id, d.sensor_id, f.rig_id),
                    )
                })?;
            // The reference sensor (first) has the rig's frame; others need
            // their sensor_from_rig to predict the image pose.
            let expected = match (pos, rig.sensors.get(pos).and_then(|s| s.pose)) {
                (0, _) => Some(f.rig_from_world),
                (_, Some(sensor_from_rig)) => Some(sensor_from_rig * f.rig_from_world),
                _ => None,
            };
            let image_id = u32::try_from(d.data_id).map_err(|_| {
                inconsistent(&paths.frames, f.loc, format!("frame {} image id {} exceeds 32 bits", f.id, d.data_id))
            })?;
            if image_frames.insert(image_id, (f.loc, expected, d.sensor_id)).is_some() {
                return Err(inconsistent(&paths.frames, f.loc, format!("image {image_id} belongs to two frames")));
            }
        }
    }

    let mut images = BTreeMap::new();
    let mut order = Vec::with_capacity(raw.images.len());
    // Keypoint links as read, verified against the tracks below.
    let mut num_links = 0usize;
    for im in raw.images {
        let id = ImageId(im.id);
        let camera_id = CameraId(im.camera_id);
        if !cameras.contains_key(&camera_id) {
            return Err(inconsistent(&paths.images, im.loc, format!("image {id} uses missing camera {camera_id}")));
        }
        if have_frames {
            let Some((floc, expected, sensor)) = image_frames.get(&im.id) else {
                return Err(inconsistent(
                    &paths.images,
                    im.loc,
                    format!("image {id} belongs to no frame in {}", paths.frames.display()),
                ));
            };
            if *sensor != im.camera_id {
                return Err(inconsistent(
                    &paths.frames,
                    *floc,
                    format!("frame lists image {id} with camera {sensor}, but the image uses camera {camera_id}"),
                ));
            }
            if let Some(expected) = expected
                && !poses_agree(expected, &im.cam_from_world)
            {
                return Err(inconsistent(
                    &paths.images,
                    im.loc,
                    format!("image {id} pose disagrees with its frame in {}", paths.frames.display()),
                ));
            }
        }
        let points2d: Vec<Point2D> =
            im.points2d.iter().map(|(xy, p)| Point2D { xy: *xy, point3d_id: p.map(Point3DId) }).collect();
        num_links += points2d.iter().filter(|p| p.point3d_id.is_some()).count();
        let image =
            Image { id, name: im.name, camera_id, cam_from_world: im.cam_from_world, points2d, registered: true };
        if images.insert(id, image).is_some() {
            return Err(inconsistent(&paths.images, im.loc, format!("duplicate image id {id}")));
        }
        order.push(id);
    }

    let mut points3d = BTreeMap::new();
    let mut num_track_elements = 0usize;
    for p in raw.points {
        let pid = Point3DId(p.id);
        let mut seen = BTreeSet::new();
        let mut track = Vec::with_capacity(p.track.len());
        for &(image_id, idx) in &p.track {
            let img = images.get(&ImageId(image_id)).ok_or_else(|| {
                inconsistent(&paths.points3d, p.loc, format!("point {pid} track references missing image {image_id}"))
            })?;
            let kp = img.points2d.get(idx as usize).ok_or_else(|| {
                inconsistent(
                    &paths.points3d,
                    p.loc,
                    format!(
                        "point {pid} track references point2D {idx} of image {image_id}, which has {} points2D",
                        img.points2d.len()
                    ),
                )
            })?;
            if kp.point3d_id != Some(pid) {
                return Err(inconsistent(
                    &paths.points3d,
                    p.loc,
                    format!(
                        "point {pid} track names image {image_id} point2D {idx}, which links to {} in {}",
                        kp.point3d_id.map_or("no point".to_string(), |o| format!("point {o}")),
                        paths.images.display()
                    ),
                ));
            }
            if !seen.insert((image_id, idx)) {
                return Err(inconsistent(
                    &paths.points3d,
                    p.loc,
                    format!("point {pid} track holds image {image_id} point2D {idx} twice"),
                ));
            }
            track.push(TrackElement { image_id: ImageId(image_id), point2d_idx: idx });
        }
        num_track_elements += track.len();
        let point = Point3D { xyz: p.xyz, color: p.color, error: p.error, track };
        if points3d.insert(pid, point).is_some() {
            return Err(inconsistent(&paths.points3d, p.loc, format!("duplicate point id {pid}")));
        }
    }
    // Every track element links back (checked above) and tracks hold no
    // duplicates, so equal counts mean every keypoint link is in a track.
    if num_links != num_track_elements {
        for img in images.values() {
            for (idx, kp) in img.points2d.iter().enumerate() {
                let Some(pid) = kp.point3d_id else { continue };
                let el = TrackElement { image_id: img.id, point2d_idx: u32::try_from(idx).unwrap_or(u32::MAX) };
                let ok = points3d.get(&pid).is_some_and(|p: &Point3D| p.track.contains(&el));
                if !ok {
                    return Err(SceneError::Inconsistent {
                        path: paths.images.clone(),
                        what: format!(
                            "image {} point2D {idx} links to point {pid}, which is missing from {} or whose track lacks it",
                            img.id,
                            paths.points3d.display()
                        ),
                    });
                }
            }
        }
    }
    Ok(Reconstruction::from_parts(cameras, images, points3d, order))
}
