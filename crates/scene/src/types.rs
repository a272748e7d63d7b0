//! The map entities in COLMAP's terms (src/colmap/scene/{camera,image,
//! point2d,point3d,track}.h): cameras, images with their 2D keypoints, 3D
//! points with their tracks.

use crate::ids::{CameraId, ImageId, Point3DId};
use colslam_geometry::{Rigid3, Vec2, Vec3};

/// A camera of the reconstruction: its id and the intrinsic model.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// The id.
    pub id: CameraId,
    /// Model, image size and parameters in COLMAP order.
    pub camera: colslam_camera::Camera,
}

/// A 2D keypoint of an image, optionally observing a 3D point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point2D {
    /// Pixel position (COLMAP convention: the centre of the upper-left pixel
    /// is (0.5, 0.5)).
    pub xy: Vec2,
    /// The 3D point it observes, if any.
    pub point3d_id: Option<Point3DId>,
}

impl Point2D {
    /// A keypoint that observes no 3D point.
    pub fn new(x: f64, y: f64) -> Self {
        Self { xy: Vec2::new(x, y), point3d_id: None }
    }
}

/// An image: its camera, its pose and its keypoints.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// The id.
    pub id: ImageId,
    /// File name relative to the image folder (COLMAP's `NAME`).
    pub name: String,
    /// The camera that took it.
    pub camera_id: CameraId,
    /// World-to-camera transform. Meaningful when `registered` (an
    /// unregistered image keeps its last pose only as a hint).
    pub cam_from_world: Rigid3,
    /// The keypoints; a track element's `point2d_idx` indexes this vector.
    pub points2d: Vec<Point2D>,
    /// Whether the image is part of the model (has a valid pose).
    pub registered: bool,
}

impl Image {
    /// An unregistered image with the given keypoints (no 3D links) and an
    /// identity pose.
    pub fn new(id: ImageId, name: impl Into<String>, camera_id: CameraId, points2d: Vec<Vec2>) -> Self {
        Self {
            id,
            name: name.into(),
            camera_id,
            cam_from_world: Rigid3::identity(),
            points2d: points2d.into_iter().map(|xy| Point2D { xy, point3d_id: None }).collect(),
            registered: false,
        }
    }

    /// Number of keypoints that observe a 3D point.
    pub fn num_points3d(&self) -> usize {
        self.points2d.iter().filter(|p| p.point3d_id.is_some()).count()
    }

    /// Camera centre in world coordinates.
    pub fn projection_center(&self) -> Vec3 {
        self.cam_from_world.center()
    }
}

/// One observation of a 3D point: an image and the index of a keypoint in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TrackElement {
    /// The observing image.
    pub image_id: ImageId,
    /// Index into that image's `points2d`.
    pub point2d_idx: u32,
}

impl TrackElement {
    /// Builds an element.
    pub fn new(image_id: ImageId, point2d_idx: u32) -> Self {
        Self { image_id, point2d_idx }
    }
}

/// The value of [`Point3D::error`] when no reprojection error was computed
/// (COLMAP stores -1).
pub const UNKNOWN_ERROR: f64 = -1.0;

/// A triangulated 3D point.
#[derive(Debug, Clone, PartialEq)]
pub struct Point3D {
    /// Position in world coordinates.
    pub xyz: Vec3,
    /// RGB colour.
    pub color: [u8; 3],
    /// Mean reprojection error in pixels over the track, or
    /// [`UNKNOWN_ERROR`] (-1) when not computed.
    pub error: f64,
    /// The observations, in insertion order (kept as read, so files round
    /// trip byte for byte).
    pub track: Vec<TrackElement>,
}

impl Point3D {
    /// True when `error` holds a computed value (COLMAP's `HasError`).
    pub fn has_error(&self) -> bool {
        self.error >= 0.0
    }
}
