//! The map: cameras, images and 3D points with consistent 2D<->3D links
//! (after COLMAP's `src/colmap/scene/reconstruction.h`).
//!
//! Invariants kept by every mutating operation (and checked by
//! [`Reconstruction::check_consistency`]):
//! * a keypoint links to a 3D point iff that point's track holds the
//!   `(image, keypoint)` element, and no track holds an element twice;
//! * only registered images observe 3D points;
//! * `registered_image_ids()` lists exactly the images whose `registered`
//!   flag is set, each once, in registration order (COLMAP writes
//!   `images.bin` in this order, so keeping it makes files round trip);
//! * map keys equal the ids stored in the values.

use crate::error::SceneError;
use crate::ids::{CameraId, ImageId, Point3DId};
use crate::projection;
use crate::types::{Camera, Image, Point3D, TrackElement, UNKNOWN_ERROR};
use colslam_geometry::{Quat, Rigid3, Sim3, Vec2, Vec3};
use std::collections::{BTreeMap, BTreeSet};

/// The reprojection error COLMAP records for an observation whose point lies
/// behind its camera (`sqrt(DBL_MAX)`, from `CalculateSquaredReprojectionError`
/// returning `DBL_MAX`).
pub const NON_PROJECTING_ERROR: f64 = 1.340_780_792_994_259_6e154;

/// Options of [`Reconstruction::normalize`] (COLMAP `Reconstruction::Normalize`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalizeOptions {
    /// Target diagonal of the robust bounding box. Default 10.
    pub extent: f64,
    /// Lower percentile (0..1) of the coordinates kept for the box and
    /// centroid. Default 0.1.
    pub min_percentile: f64,
    /// Upper percentile (0..1). Default 0.9.
    pub max_percentile: f64,
    /// Use registered camera centres (true, default) or 3D points (false).
    pub use_images: bool,
    /// Only translate, keep the scale. Default false.
    pub fixed_scale: bool,
}

impl Default for NormalizeOptions {
    fn default() -> Self {
        Self { extent: 10.0, min_percentile: 0.1, max_percentile: 0.9, use_images: true, fixed_scale: false }
    }
}

impl NormalizeOptions {
    /// Checks the ranges: `extent > 0`, `0 <= min <= max <= 1`.
    pub fn validate(&self) -> Result<(), SceneError> {
        if !(self.extent > 0.0 && self.extent.is_finite()) {
            return Err(SceneError::InvalidOptions(format!("normalize extent must be > 0, got {}", self.extent)));
        }
        let (a, b) = (self.min_percentile, self.max_percentile);
        if !((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b) && a <= b) {
            return Err(SceneError::InvalidOptions(format!(
                "normalize percentiles must satisfy 0 <= min <= max <= 1, got {a} and {b}"
            )));
        }
        Ok(())
    }
}

/// What a removal of one observation did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObservationRemoval {
    /// The point that lost the observation.
    pub point3d_id: Point3DId,
    /// True when the point was deleted because fewer than two observations
    /// would have remained.
    pub point_deleted: bool,
}

/// What [`Reconstruction::deregister_image`] removed.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DeregisterReport {
    /// Observations of the image that were removed from tracks (including
    /// those of deleted points).
    pub observations_removed: usize,
    /// Points deleted because they were left with fewer than 2 observations.
    pub points_deleted: Vec<Point3DId>,
}

/// What a filter removed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FilterReport {
    /// Observations removed (those of deleted points included).
    pub observations_removed: usize,
    /// Points deleted.
    pub points_deleted: usize,
}

/// Cameras, images and 3D points in COLMAP's data model.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Reconstruction {
    cameras: BTreeMap<CameraId, Camera>,
    images: BTreeMap<ImageId, Image>,
    points3d: BTreeMap<Point3DId, Point3D>,
    /// Registered images in registration order (see module docs).
    reg_image_ids: Vec<ImageId>,
    /// Largest point id ever handed out or read; new points get the next one
    /// (ids are not reused, as in COLMAP).
    max_point3d_id: u64,
}

impl Reconstruction {
    /// An empty reconstruction.
    pub fn new() -> Self {
        Self::default()
    }

    // ----- cameras -------------------------------------------------------

    /// Adds a camera under the next free id (one above the largest).
    pub fn add_camera(&mut self, camera: colslam_camera::Camera) -> CameraId {
        let id = CameraId(self.cameras.keys().next_back().map_or(1, |c| c.0.saturating_add(1)));
        self.cameras.insert(id, Camera { id, camera });
        id
    }

    /// Adds a camera under a given id.
    pub fn add_camera_with_id(&mut self, id: CameraId, camera: colslam_camera::Camera) -> Result<(), SceneError> {
        if self.cameras.contains_key(&id) {
            return Err(SceneError::DuplicateId(format!("camera {id}")));
        }
        self.cameras.insert(id, Camera { id, camera });
        Ok(())
    }

    /// The camera with this id.
    pub fn camera(&self, id: CameraId) -> Option<&Camera> {
        self.cameras.get(&id)
    }

    /// Mutable intrinsics of a camera (the id cannot change).
    pub fn camera_mut(&mut self, id: CameraId) -> Option<&mut colslam_camera::Camera> {
        self.cameras.get_mut(&id).map(|c| &mut c.camera)
    }

    /// All cameras by increasing id.
    pub fn cameras(&self) -> impl Iterator<Item = &Camera> {
        self.cameras.values()
    }

    /// Number of cameras.
    pub fn num_cameras(&self) -> usize {
        self.cameras.len()
    }

    // ----- images --------------------------------------------------------

    /// One above the largest image id (1 for an empty model).
    pub fn next_image_id(&self) -> ImageId {
        ImageId(self.images.keys().next_back().map_or(1, |c| c.0.saturating_add(1)))
    }

    /// Adds an image. Its camera must exist, its id be free and its keypoints
    /// carry no 3D links (add points afterwards). A `registered` image is
    /// appended to the registration order.
    pub fn add_image(&mut self, image: Image) -> Result<(), SceneError> {
        if self.images.contains_key(&image.id) {
            return Err(SceneError::DuplicateId(format!("image {}", image.id)));
        }
        if !self.cameras.contains_key(&image.camera_id) {
            return Err(SceneError::UnknownCamera(image.camera_id));
        }
        if let Some(i) = image.points2d.iter().position(|p| p.point3d_id.is_some()) {
            return Err(SceneError::BadObservation {
                image: image.id,
                point2d_idx: u32::try_from(i).unwrap_or(u32::MAX),
                what: "a new image must not link to 3D points; add them with add_point3d".into(),
            });
        }
        if image.points2d.len() > u32::MAX as usize {
            return Err(SceneError::Registration { image: image.id, what: "more than 2^32 keypoints".into() });
        }
        if image.registered {
            self.reg_image_ids.push(image.id);
        }
        self.images.insert(image.id, image);
        Ok(())
    }

    /// The image with this id.
    pub fn image(&self, id: ImageId) -> Option<&Image> {
        self.images.get(&id)
    }

    /// All images by increasing id.
    pub fn images(&self) -> impl Iterator<Item = &Image> {
        self.images.values()
    }

    /// Number of images (registered or not).
    pub fn num_images(&self) -> usize {
        self.images.len()
    }

    /// Finds an image by name.
    pub fn find_image_by_name(&self, name: &str) -> Option<&Image> {
        self.images.values().find(|i| i.name == name)
    }

    /// Mutable pose of an image.
    pub fn cam_from_world_mut(&mut self, id: ImageId) -> Option<&mut Rigid3> {
        self.images.get_mut(&id).map(|i| &mut i.cam_from_world)
    }

    /// Moves keypoint `point2d_idx` of an image to `xy` (a measurement
    /// correction such as rolling-shutter compensation); its 3D point link
    /// stays.
    pub fn set_point2d_xy(&mut self, id: ImageId, point2d_idx: u32, xy: Vec2) -> Result<(), SceneError> {
        let img = self.images.get_mut(&id).ok_or(SceneError::UnknownImage(id))?;
        let p = img.points2d.get_mut(point2d_idx as usize).ok_or_else(|| SceneError::BadObservation {
            image: id,
            point2d_idx,
            what: "no such keypoint".into(),
        })?;
        p.xy = xy;
        Ok(())
    }

    /// Sets the pose of an image.
    pub fn set_cam_from_world(&mut self, id: ImageId, cam_from_world: Rigid3) -> Result<(), SceneError> {
        let img = self.images.get_mut(&id).ok_or(SceneError::UnknownImage(id))?;
        img.cam_from_world = cam_from_world;
        Ok(())
    }

    /// Appends an unlinked keypoint to an image; returns its index.
    pub fn push_point2d(&mut self, id: ImageId, xy: colslam_geometry::Vec2) -> Result<u32, SceneError> {
        let img = self.images.get_mut(&id).ok_or(SceneError::UnknownImage(id))?;
        let idx = u32::try_from(img.points2d.len())
            .map_err(|_| SceneError::Registration { image: id, what: "more than 2^32 keypoints".into() })?;
        img.points2d.push(crate::types::Point2D { xy, point3d_id: None });
        Ok(idx)
    }

    /// Marks an image registered (its current pose becomes valid). A no-op
    /// for an already registered image.
    pub fn register_image(&mut self, id: ImageId) -> Result<(), SceneError> {
        let img = self.images.get_mut(&id).ok_or(SceneError::UnknownImage(id))?;
        if !img.registered {
            img.registered = true;
            self.reg_image_ids.push(id);
        }
        Ok(())
    }

    /// Deregisters an image: every observation it makes is removed from its
    /// point's track, and points left with fewer than 2 observations are
    /// deleted (COLMAP's `DeRegisterImage` + `DeleteObservation`). A no-op for
    /// an unregistered image.
    pub fn deregister_image(&mut self, id: ImageId) -> Result<DeregisterReport, SceneError> {
        let img = self.images.get(&id).ok_or(SceneError::UnknownImage(id))?;
        let mut report = DeregisterReport::default();
        if !img.registered {
            return Ok(report);
        }
        let linked: Vec<u32> = img
            .points2d
            .iter()
            .enumerate()
            .filter(|(_, p)| p.point3d_id.is_some())
            .filter_map(|(i, _)| u32::try_from(i).ok())
            .collect();
        for idx in linked {
            // A point deleted earlier in this loop (both its observations in
            // this image) has already cleared this link: skip it.
            let still_linked = self.point2d_link(id, idx).is_some();
            if !still_linked {
                continue;
            }
            let removal = self.delete_observation(id, idx)?;
            report.observations_removed += 1;
            if removal.point_deleted {
                report.points_deleted.push(removal.point3d_id);
            }
        }
        if let Some(img) = self.images.get_mut(&id) {
            img.registered = false;
        }
        self.reg_image_ids.retain(|&i| i != id);
        Ok(report)
    }

    /// Deletes an image: deregisters it as [`Self::deregister_image`] does
    /// (its observations leave their tracks; points left with fewer than 2
    /// observations are deleted), then removes it from the model (COLMAP's
    /// `DeRegisterImage` followed by dropping the image, as keyframe culling
    /// needs). Returns what the deregistration removed. Ids are not reused
    /// while a larger one exists ([`Self::next_image_id`] is one above the
    /// largest).
    pub fn delete_image(&mut self, id: ImageId) -> Result<DeregisterReport, SceneError> {
        let report = self.deregister_image(id)?;
        self.images.remove(&id);
        Ok(report)
    }

    /// Registered image ids in registration order.
    pub fn registered_image_ids(&self) -> &[ImageId] {
        &self.reg_image_ids
    }

    /// Number of registered images.
    pub fn num_registered_images(&self) -> usize {
        self.reg_image_ids.len()
    }

    fn point2d_link(&self, image: ImageId, idx: u32) -> Option<Point3DId> {
        self.images.get(&image)?.points2d.get(idx as usize)?.point3d_id
    }

    // ----- 3D points -----------------------------------------------------

    /// The 3D point with this id.
    pub fn point3d(&self, id: Point3DId) -> Option<&Point3D> {
        self.points3d.get(&id)
    }

    /// All 3D points by increasing id.
    pub fn points3d(&self) -> impl Iterator<Item = (Point3DId, &Point3D)> {
        self.points3d.iter().map(|(k, v)| (*k, v))
    }

    /// All 3D point ids, increasing.
    pub fn point3d_ids(&self) -> Vec<Point3DId> {
        self.points3d.keys().copied().collect()
    }

    /// Number of 3D points.
    pub fn num_points3d(&self) -> usize {
        self.points3d.len()
    }

    /// Mutable position of a point.
    pub fn point3d_xyz_mut(&mut self, id: Point3DId) -> Option<&mut Vec3> {
        self.points3d.get_mut(&id).map(|p| &mut p.xyz)
    }

    /// Sets the colour of a point.
    pub fn set_point3d_color(&mut self, id: Point3DId, color: [u8; 3]) -> Result<(), SceneError> {
        self.points3d.get_mut(&id).ok_or(SceneError::UnknownPoint3D(id))?.color = color;
        Ok(())
    }

    /// Sets the stored reprojection error of a point.
    pub fn set_point3d_error(&mut self, id: Point3DId, error: f64) -> Result<(), SceneError> {
        self.points3d.get_mut(&id).ok_or(SceneError::UnknownPoint3D(id))?.error = error;
        Ok(())
    }

    /// Checks that an observation can be linked: registered image, keypoint
    /// in range and not yet linked.
    fn check_free_observation(&self, el: &TrackElement) -> Result<(), SceneError> {
        let img = self.images.get(&el.image_id).ok_or(SceneError::UnknownImage(el.image_id))?;
        let bad = |what: &str| SceneError::BadObservation {
            image: el.image_id,
            point2d_idx: el.point2d_idx,
            what: what.to_string(),
        };
        if !img.registered {
            return Err(bad("image is not registered"));
        }
        let p = img.points2d.get(el.point2d_idx as usize).ok_or_else(|| bad("keypoint index out of range"))?;
        if let Some(other) = p.point3d_id {
            return Err(bad(&format!("keypoint already observes 3D point {other}")));
        }
        Ok(())
    }

    fn set_link(&mut self, el: &TrackElement, link: Option<Point3DId>) {
        if let Some(p) = self.images.get_mut(&el.image_id).and_then(|i| i.points2d.get_mut(el.point2d_idx as usize)) {
            p.point3d_id = link;
        }
    }

    /// Adds a 3D point observed by `track` under the next id. Every element
    /// must name a registered image's keypoint that observes no other point,
    /// each at most once. The error is set to unknown (-1).
    pub fn add_point3d(
        &mut self,
        xyz: Vec3,
        color: [u8; 3],
        track: Vec<TrackElement>,
    ) -> Result<Point3DId, SceneError> {
        let id = Point3DId(
            self.max_point3d_id
                .checked_add(1)
                .ok_or_else(|| SceneError::DuplicateId("3D point ids are exhausted (u64::MAX reached)".into()))?,
        );
        self.insert_point3d(id, Point3D { xyz, color, error: UNKNOWN_ERROR, track })?;
        Ok(id)
    }

    /// Adds a point under a given id (readers and tests); same checks as
    /// [`Self::add_point3d`]. Keeps `error` as given.
    pub fn add_point3d_with_id(&mut self, id: Point3DId, point: Point3D) -> Result<(), SceneError> {
        if self.points3d.contains_key(&id) {
            return Err(SceneError::DuplicateId(format!("3D point {id}")));
        }
        self.insert_point3d(id, point)
    }

    fn insert_point3d(&mut self, id: Point3DId, point: Point3D) -> Result<(), SceneError> {
        if id.0 == crate::ids::INVALID_POINT3D_ID {
            return Err(SceneError::DuplicateId(format!("3D point id {id} is COLMAP's invalid id")));
        }
        let mut seen = BTreeSet::new();
        for el in &point.track {
            self.check_free_observation(el)?;
            if !seen.insert(*el) {
                return Err(SceneError::BadObservation {
                    image: el.image_id,
                    point2d_idx: el.point2d_idx,
                    what: "appears twice in the track".into(),
                });
            }
        }
        for el in &point.track {
            self.set_link(el, Some(id));
        }
        self.max_point3d_id = self.max_point3d_id.max(id.0);
        self.points3d.insert(id, point);
        Ok(())
    }

    /// Adds one observation to a point's track.
    pub fn add_observation(&mut self, point: Point3DId, el: TrackElement) -> Result<(), SceneError> {
        if !self.points3d.contains_key(&point) {
            return Err(SceneError::UnknownPoint3D(point));
        }
        self.check_free_observation(&el)?;
        self.set_link(&el, Some(point));
        if let Some(p) = self.points3d.get_mut(&point) {
            p.track.push(el);
        }
        Ok(())
    }

    /// Removes the observation made by keypoint `point2d_idx` of `image`. If
    /// its point would keep fewer than 2 observations, the whole point is
    /// deleted (COLMAP's `DeleteObservation`).
    pub fn delete_observation(&mut self, image: ImageId, point2d_idx: u32) -> Result<ObservationRemoval, SceneError> {
        if !self.images.contains_key(&image) {
            return Err(SceneError::UnknownImage(image));
        }
        let point3d_id = self.point2d_link(image, point2d_idx).ok_or_else(|| SceneError::BadObservation {
            image,
            point2d_idx,
            what: "keypoint observes no 3D point".into(),
        })?;
        let track_len = self.points3d.get(&point3d_id).map_or(0, |p| p.track.len());
        if track_len <= 2 {
            self.delete_point3d(point3d_id)?;
            return Ok(ObservationRemoval { point3d_id, point_deleted: true });
        }
        let el = TrackElement { image_id: image, point2d_idx };
        if let Some(p) = self.points3d.get_mut(&point3d_id) {
            p.track.retain(|e| *e != el);
        }
        self.set_link(&el, None);
        Ok(ObservationRemoval { point3d_id, point_deleted: false })
    }

    /// Deletes a point and clears the keypoint links to it; returns it.
    pub fn delete_point3d(&mut self, id: Point3DId) -> Result<Point3D, SceneError> {
        let point = self.points3d.remove(&id).ok_or(SceneError::UnknownPoint3D(id))?;
        for el in &point.track {
            self.set_link(el, None);
        }
        Ok(point)
    }

    /// Merges two points into a new one (next id): the track is the union,
    /// the position and colour the track-length-weighted means, the error
    /// unknown; both old points are deleted and their keypoints relinked
    /// (COLMAP's `MergePoints3D`). Merging a point with itself is an error.
    pub fn merge_points3d(&mut self, a: Point3DId, b: Point3DId) -> Result<Point3DId, SceneError> {
        if a == b {
            return Err(SceneError::DuplicateId(format!("cannot merge 3D point {a} with itself")));
        }
        let pa = self.points3d.get(&a).ok_or(SceneError::UnknownPoint3D(a))?;
        let pb = self.points3d.get(&b).ok_or(SceneError::UnknownPoint3D(b))?;
        let (wa, wb) = (pa.track.len() as f64, pb.track.len() as f64);
        let wsum = wa + wb;
        let (xyz, color) = if wsum > 0.0 {
            let mut color = [0u8; 3];
            for (c, (ca, cb)) in color.iter_mut().zip(pa.color.iter().zip(pb.color.iter())) {
                // A weighted mean of two u8 values lies in 0..=255.
                *c = ((wa * f64::from(*ca) + wb * f64::from(*cb)) / wsum).round().clamp(0.0, 255.0) as u8;
            }
            ((pa.xyz * wa + pb.xyz * wb) / wsum, color)
        } else {
            ((pa.xyz + pb.xyz) * 0.5, pa.color)
        };
        let old_a = self.delete_point3d(a)?;
        let old_b = self.delete_point3d(b)?;
        let mut track = old_a.track;
        track.extend(old_b.track);
        self.add_point3d(xyz, color, track)
    }

    // ----- statistics ----------------------------------------------------

    /// Number of observations (keypoints of registered images linked to a
    /// point; equals the summed track lengths).
    pub fn num_observations(&self) -> usize {
        self.reg_image_ids.iter().filter_map(|id| self.images.get(id)).map(Image::num_points3d).sum()
    }

    /// Mean track length (0 without points), as COLMAP computes it.
    pub fn mean_track_length(&self) -> f64 {
        if self.points3d.is_empty() { 0.0 } else { self.num_observations() as f64 / self.points3d.len() as f64 }
    }

    /// Mean observations per registered image (0 without registered images).
    pub fn mean_observations_per_registered_image(&self) -> f64 {
        if self.reg_image_ids.is_empty() {
            0.0
        } else {
            self.num_observations() as f64 / self.reg_image_ids.len() as f64
        }
    }

    /// Mean reprojection error of a point over its track, in pixels, with
    /// each observation's camera model (0 for an empty track; an observation
    /// behind its camera counts as [`NON_PROJECTING_ERROR`], as in COLMAP).
    pub fn compute_point_error(&self, id: Point3DId) -> Result<f64, SceneError> {
        let p = self.points3d.get(&id).ok_or(SceneError::UnknownPoint3D(id))?;
        if p.track.is_empty() {
            return Ok(0.0);
        }
        let mut sum = 0.0;
        for el in &p.track {
            let img = self.images.get(&el.image_id).ok_or(SceneError::UnknownImage(el.image_id))?;
            let cam = self.cameras.get(&img.camera_id).ok_or(SceneError::UnknownCamera(img.camera_id))?;
            let kp = img.points2d.get(el.point2d_idx as usize).ok_or_else(|| SceneError::BadObservation {
                image: el.image_id,
                point2d_idx: el.point2d_idx,
                what: "keypoint index out of range".into(),
            })?;
            sum += projection::reprojection_error(&cam.camera, &img.cam_from_world, &p.xyz, &kp.xy)
                .unwrap_or(NON_PROJECTING_ERROR);
        }
        Ok(sum / p.track.len() as f64)
    }

    /// Recomputes and stores the error of every point
    /// (COLMAP's `UpdatePoint3DErrors`).
    pub fn update_point_errors(&mut self) -> Result<(), SceneError> {
        for id in self.point3d_ids() {
            let e = self.compute_point_error(id)?;
            self.set_point3d_error(id, e)?;
        }
        Ok(())
    }

    /// Mean of the stored point errors over points that have one (0 if none).
    pub fn mean_reprojection_error(&self) -> f64 {
        let (sum, n) =
            self.points3d.values().filter(|p| p.has_error()).fold((0.0, 0usize), |(s, n), p| (s + p.error, n + 1));
        if n == 0 { 0.0 } else { sum / n as f64 }
    }

    // ----- similarity transforms -----------------------------------------

    /// Applies `new_from_old` to the whole model: points move, camera poses
    /// follow so that every projection is unchanged (COLMAP's `Transform`).
    /// Unregistered images' stored poses are transformed too.
    pub fn transform(&mut self, new_from_old: &Sim3) {
        for img in self.images.values_mut() {
            img.cam_from_world = transform_cam_from_world(new_from_old, &img.cam_from_world);
        }
        for p in self.points3d.values_mut() {
            p.xyz = new_from_old.transform_point(&p.xyz);
        }
    }

    /// Translates and scales the model so that the robust bounding box of the
    /// registered camera centres (or of the points) has diagonal
    /// `options.extent` and its robust centroid is the origin (COLMAP's
    /// `Normalize`). Returns the similarity applied (identity when fewer than
    /// 2 elements exist).
    pub fn normalize(&mut self, options: &NormalizeOptions) -> Result<Sim3, SceneError> {
        options.validate()?;
        let coords: Vec<Vec3> = if options.use_images {
            self.reg_image_ids.iter().filter_map(|id| self.images.get(id)).map(Image::projection_center).collect()
        } else {
            self.points3d.values().map(|p| p.xyz).collect()
        };
        if coords.len() < 2 {
            return Ok(Sim3::identity());
        }
        let (bbox_min, bbox_max, centroid) = robust_box(&coords, options.min_percentile, options.max_percentile);
        let mut scale = 1.0;
        if !options.fixed_scale {
            let old_extent = (bbox_max - bbox_min).norm();
            if old_extent >= f64::EPSILON {
                scale = options.extent / old_extent;
            }
        }
        let tform = Sim3 { scale, rotation: Quat::identity(), translation: -scale * centroid };
        self.transform(&tform);
        Ok(tform)
    }

    // ----- filters ---------------------------------------------------------

    fn selected_points(&self, points: Option<&[Point3DId]>) -> Vec<Point3DId> {
        match points {
            Some(ids) => ids.iter().copied().filter(|id| self.points3d.contains_key(id)).collect(),
            None => self.point3d_ids(),
        }
    }

    /// Removes observations whose reprojection error exceeds `max_error_px`
    /// (points left with fewer than 2 observations are deleted) and updates
    /// the error of the surviving points (COLMAP's
    /// `FilterPoints3DWithLargeReprojectionError`). `points = None` filters
    /// all points.
    pub fn filter_by_reprojection_error(
        &mut self,
        max_error_px: f64,
        points: Option<&[Point3DId]>,
    ) -> Result<FilterReport, SceneError> {
        let mut report = FilterReport::default();
        for id in self.selected_points(points) {
            let Some(p) = self.points3d.get(&id) else { continue };
            let mut bad = Vec::new();
            let mut good_sum = 0.0;
            for el in &p.track {
                let err = self.observation_error(p, el)?;
                if err > max_error_px {
                    bad.push(*el);
                } else {
                    good_sum += err;
                }
            }
            let len = p.track.len();
            if bad.is_empty() {
                if len > 0 {
                    self.set_point3d_error(id, good_sum / len as f64)?;
                }
                continue;
            }
            if len - bad.len() < 2 {
                self.delete_point3d(id)?;
                report.observations_removed += len;
                report.points_deleted += 1;
            } else {
                for el in &bad {
                    self.delete_observation(el.image_id, el.point2d_idx)?;
                    report.observations_removed += 1;
                }
                self.set_point3d_error(id, good_sum / (len - bad.len()) as f64)?;
            }
        }
        Ok(report)
    }

    fn observation_error(&self, p: &Point3D, el: &TrackElement) -> Result<f64, SceneError> {
        let img = self.images.get(&el.image_id).ok_or(SceneError::UnknownImage(el.image_id))?;
        let cam = self.cameras.get(&img.camera_id).ok_or(SceneError::UnknownCamera(img.camera_id))?;
        let kp = img.points2d.get(el.point2d_idx as usize).ok_or_else(|| SceneError::BadObservation {
            image: el.image_id,
            point2d_idx: el.point2d_idx,
            what: "keypoint index out of range".into(),
        })?;
        Ok(projection::reprojection_error(&cam.camera, &img.cam_from_world, &p.xyz, &kp.xy).unwrap_or(f64::INFINITY))
    }

    /// Deletes points whose largest triangulation angle over all pairs of
    /// observing camera centres is below `min_angle_deg` (COLMAP's
    /// `FilterPoints3DWithSmallTriangulationAngle`).
    pub fn filter_by_triangulation_angle(
        &mut self,
        min_angle_deg: f64,
        points: Option<&[Point3DId]>,
    ) -> Result<FilterReport, SceneError> {
        let min_angle = min_angle_deg.to_radians();
        let mut report = FilterReport::default();
        for id in self.selected_points(points) {
            let Some(p) = self.points3d.get(&id) else { continue };
            let centers: Vec<Vec3> =
                p.track.iter().filter_map(|el| self.images.get(&el.image_id)).map(Image::projection_center).collect();
            let mut keep = false;
            'pairs: for (i, c1) in centers.iter().enumerate() {
                for c2 in centers.iter().skip(i + 1) {
                    if triangulation_angle(c1, c2, &p.xyz) >= min_angle {
                        keep = true;
                        break 'pairs;
                    }
                }
            }
            if !keep {
                let len = p.track.len();
                self.delete_point3d(id)?;
                report.points_deleted += 1;
                report.observations_removed += len;
            }
        }
        Ok(report)
    }

    /// Removes observations of points that lie behind (or on) the observing
    /// camera's plane; points left with fewer than 2 observations are deleted
    /// (COLMAP's `FilterObservationsWithNegativeDepth`).
    pub fn filter_negative_depth(&mut self, points: Option<&[Point3DId]>) -> Result<FilterReport, SceneError> {
        let mut report = FilterReport::default();
        for id in self.selected_points(points) {
            let Some(p) = self.points3d.get(&id) else { continue };
            let bad: Vec<TrackElement> = p
                .track
                .iter()
                .filter(|el| {
                    self.images
                        .get(&el.image_id)
                        .is_some_and(|img| projection::depth(&img.cam_from_world, &p.xyz) < projection::MIN_DEPTH)
                })
                .copied()
                .collect();
            for el in bad {
                // The point may already be gone when an earlier removal left
                // it with fewer than 2 observations.
                if self.point2d_link(el.image_id, el.point2d_idx) != Some(id) {
                    continue;
                }
                let track_len = self.points3d.get(&id).map_or(0, |p| p.track.len());
                let r = self.delete_observation(el.image_id, el.point2d_idx)?;
                if r.point_deleted {
                    report.points_deleted += 1;
                    report.observations_removed += track_len;
                } else {
                    report.observations_removed += 1;
                }
            }
        }
        Ok(report)
    }

    // ----- checks ----------------------------------------------------------

    /// Verifies every invariant listed in the module docs; the error names
    /// the first violation found.
    pub fn check_consistency(&self) -> Result<(), SceneError> {
        let fail = |s: String| Err(SceneError::Invariant(s));
        for (id, cam) in &self.cameras {
            if cam.id != *id {
                return fail(format!("camera stored under {id} has id {}", cam.id));
            }
            if cam.camera.params.len() != cam.camera.model.num_params() {
                return fail(format!("camera {id} has {} parameters", cam.camera.params.len()));
            }
        }
        let mut seen_reg = BTreeSet::new();
        for id in &self.reg_image_ids {
            if !seen_reg.insert(*id) {
                return fail(format!("image {id} registered twice"));
            }
            if !self.images.get(id).is_some_and(|i| i.registered) {
                return fail(format!("image {id} in the registration list but not registered"));
            }
        }
        for (id, img) in &self.images {
            if img.id != *id {
                return fail(format!("image stored under {id} has id {}", img.id));
            }
            if !self.cameras.contains_key(&img.camera_id) {
                return fail(format!("image {id} uses missing camera {}", img.camera_id));
            }
            if img.registered != seen_reg.contains(id) {
                return fail(format!("image {id} registered flag disagrees with the registration list"));
            }
            for (idx, kp) in img.points2d.iter().enumerate() {
                let Some(pid) = kp.point3d_id else { continue };
                if !img.registered {
                    return fail(format!("unregistered image {id} keypoint {idx} observes point {pid}"));
                }
                let el = TrackElement { image_id: *id, point2d_idx: u32::try_from(idx).unwrap_or(u32::MAX) };
                match self.points3d.get(&pid) {
                    None => return fail(format!("image {id} keypoint {idx} links to missing point {pid}")),
                    Some(p) if !p.track.contains(&el) => {
                        return fail(format!("image {id} keypoint {idx} links to point {pid} whose track lacks it"));
                    }
                    Some(_) => {}
                }
            }
        }
        for (id, p) in &self.points3d {
            if id.0 > self.max_point3d_id {
                return fail(format!("point {id} above the id counter {}", self.max_point3d_id));
            }
            let mut seen = BTreeSet::new();
            for el in &p.track {
                if !seen.insert(*el) {
                    return fail(format!("point {id} track holds {el:?} twice"));
                }
                if self.point2d_link(el.image_id, el.point2d_idx) != Some(*id) {
                    return fail(format!(
                        "point {id} track element (image {}, keypoint {}) does not link back",
                        el.image_id, el.point2d_idx
                    ));
                }
            }
        }
        Ok(())
    }

    /// Assembles a model from parts that a reader has already validated
    /// (links in both directions, registration order = registered images).
    pub(crate) fn from_parts(
        cameras: BTreeMap<CameraId, Camera>,
        images: BTreeMap<ImageId, Image>,
        points3d: BTreeMap<Point3DId, Point3D>,
        reg_image_ids: Vec<ImageId>,
    ) -> Self {
        let max_point3d_id = points3d.keys().next_back().map_or(0, |p| p.0);
        Self { cameras, images, points3d, reg_image_ids, max_point3d_id }
    }
}

/// `cam_from_new_world` for a camera when the world moves by `new_from_old`:
/// the centre is mapped, the rotation composed with the inverse rotation.
pub fn transform_cam_from_world(new_from_old: &Sim3, cam_from_world: &Rigid3) -> Rigid3 {
    let rotation = cam_from_world.rotation * new_from_old.rotation.inverse();
    let center = new_from_old.transform_point(&cam_from_world.center());
    Rigid3 { rotation, translation: -(rotation * center) }
}

/// The smaller angle between the rays from two centres to a point, in
/// radians (COLMAP's `CalculateTriangulationAngle`).
pub fn triangulation_angle(c1: &Vec3, c2: &Vec3, xyz: &Vec3) -> f64 {
    let baseline2 = (c1 - c2).norm_squared();
    let r1 = (xyz - c1).norm();
    let r2 = (xyz - c2).norm();
    let denom = 2.0 * r1 * r2;
    if denom == 0.0 {
        return 0.0;
    }
    let cos = ((r1 * r1 + r2 * r2 - baseline2) / denom).clamp(-1.0, 1.0);
    let angle = cos.acos().abs();
    angle.min(std::f64::consts::PI - angle)
}

/// Robust bounding box and centroid per axis: the coordinates at sorted
/// positions `floor(min_p * (n-1))` and `ceil(max_p * (n-1))`, and the mean
/// of the coordinates between them (COLMAP's `ComputeBoundingBoxAndCentroid`).
/// `coords` must be non-empty.
fn robust_box(coords: &[Vec3], min_p: f64, max_p: f64) -> (Vec3, Vec3, Vec3) {
    let end = coords.len().saturating_sub(1);
    let lo = ((min_p * end as f64).floor() as usize).min(end);
    let hi = ((max_p * end as f64).ceil() as usize).min(end).max(lo);
    let mut bmin = Vec3::zeros();
    let mut bmax = Vec3::zeros();
    let mut centroid = Vec3::zeros();
    for axis in 0..3 {
        let mut v: Vec<f64> = coords.iter().map(|c| c[axis]).collect();
        v.sort_by(f64::total_cmp);
        let kept = v.get(lo..=hi).unwrap_or(&[]);
        bmin[axis] = kept.first().copied().unwrap_or(0.0);
        bmax[axis] = kept.last().copied().unwrap_or(0.0);
        let norm = 1.0 / kept.len().max(1) as f64;
        centroid[axis] = kept.iter().map(|x| norm * x).sum();
    }
    (bmin, bmax, centroid)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> Vec3 {
        Vec3::new(x, y, z)
    }

    #[test]
    fn robust_box_percentiles() {
        let (lo, hi, c) = robust_box(&[v(1.0, 2.0, 3.0)], 0.0, 1.0);
        assert_eq!((lo, hi, c), (v(1.0, 2.0, 3.0), v(1.0, 2.0, 3.0), v(1.0, 2.0, 3.0)));
        let (lo, hi, c) = robust_box(&[v(2.0, 3.0, 4.0), v(-1.0, -2.0, -3.0)], 0.0, 1.0);
        assert_eq!((lo, hi, c), (v(-1.0, -2.0, -3.0), v(2.0, 3.0, 4.0), v(0.5, 0.5, 0.5)));
        // Five values 0..4 with percentiles 0.25/0.75: positions 1..3.
        let pts: Vec<Vec3> = [4.0, 0.0, 3.0, 1.0, 2.0].iter().map(|&x| v(x, -x, 10.0 * x)).collect();
        let (lo, hi, c) = robust_box(&pts, 0.25, 0.75);
        assert_eq!(lo, v(1.0, -3.0, 10.0));
        assert_eq!(hi, v(3.0, -1.0, 30.0));
        assert!((c - v(2.0, -2.0, 20.0)).norm() < 1e-12);
    }

    #[test]
    fn triangulation_angle_is_symmetric_and_acute() {
        let a = triangulation_angle(&v(-1.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), &v(0.0, 0.0, 1.0));
        assert!((a - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let b = triangulation_angle(&v(-1.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), &v(0.0, 0.0, 1e6));
        assert!(b < 1e-5);
        assert_eq!(triangulation_angle(&v(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), &v(0.0, 0.0, 0.0)), 0.0);
    }

    #[test]
    fn point_ids_continue_after_the_largest() {
        let mut rec = Reconstruction::new();
        let cam = rec.add_camera(
            colslam_camera::Camera::new(colslam_camera::CameraModelId::SimplePinhole, 10, 10, vec![1.0, 5.0, 5.0])
                .unwrap_or_else(|e| panic!("{e}")),
        );
        let mut img = Image::new(ImageId(3), "a", cam, vec![colslam_geometry::Vec2::zeros(); 3]);
        img.registered = true;
        rec.add_image(img).unwrap_or_else(|e| panic!("{e}"));
        let p =
            Point3D { xyz: Vec3::zeros(), color: [0; 3], error: 0.5, track: vec![TrackElement::new(ImageId(3), 0)] };
        rec.add_point3d_with_id(Point3DId(41), p.clone()).unwrap_or_else(|e| panic!("{e}"));
        assert!(rec.add_point3d_with_id(Point3DId(41), p).is_err());
        let next = rec.add_point3d(Vec3::zeros(), [0; 3], vec![TrackElement::new(ImageId(3), 1)]);
        assert_eq!(next.ok(), Some(Point3DId(42)));
        assert_eq!(rec.next_image_id(), ImageId(4));
        assert!(rec.check_consistency().is_ok());
    }
}
