//! The bundle-adjustment problem: cameras, poses, points and observations.
//!
//! Independent of the scene crate: the mapper converts its reconstruction into
//! a [`Problem`], solves it and copies the refined values back.

use crate::BaError;
use colslam_camera::Camera;
use colslam_geometry::{Rigid3, Vec2, Vec3};

/// Which intrinsic parameters of one camera are refined.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum IntrinsicsRefinement {
    /// Use the option flags (`refine_focal_length`, `refine_principal_point`,
    /// `refine_extra_params` of [`crate::BaOptions`]).
    #[default]
    FromOptions,
    /// All intrinsics constant.
    Fixed,
    /// Exactly these parameter indices (COLMAP order) are refined.
    Params(Vec<usize>),
}

/// A camera (intrinsics) of the problem.
#[derive(Debug, Clone, PartialEq)]
pub struct BaCamera {
    /// The camera model and parameters; refined in place.
    pub camera: Camera,
    /// Which parameters are refined.
    pub refine: IntrinsicsRefinement,
}

/// A pose (`cam_from_world`) of the problem.
#[derive(Debug, Clone, PartialEq)]
pub struct BaPose {
    /// The pose; refined in place.
    pub cam_from_world: Rigid3,
    /// Whole pose constant.
    pub fixed: bool,
    /// Translation coordinates held constant while the rest varies (COLMAP
    /// fixes one coordinate of a second pose to remove the scale gauge).
    pub fixed_translation: [bool; 3],
}

impl BaPose {
    /// A variable pose.
    pub fn variable(cam_from_world: Rigid3) -> Self {
        Self { cam_from_world, fixed: false, fixed_translation: [false; 3] }
    }

    /// A constant pose.
    pub fn fixed(cam_from_world: Rigid3) -> Self {
        Self { cam_from_world, fixed: true, fixed_translation: [false; 3] }
    }

    /// A variable pose whose translation coordinate `coord` (0..3) is constant.
    pub fn with_fixed_translation_coord(cam_from_world: Rigid3, coord: usize) -> Self {
        let mut fixed_translation = [false; 3];
        if let Some(f) = fixed_translation.get_mut(coord) {
            *f = true;
        }
        Self { cam_from_world, fixed: false, fixed_translation }
    }

    /// Which of the 6 tangent dimensions `(w, dt)` vary.
    pub(crate) fn free_dims(&self) -> Vec<usize> {
        if self.fixed {
            return Vec::new();
        }
        let mut dims = vec![0, 1, 2];
        dims.extend((0..3).filter(|&k| !self.fixed_translation[k]).map(|k| k + 3));
        dims
    }
}

/// A 3D point of the problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaPoint {
    /// World position; refined in place.
    pub xyz: Vec3,
    /// Constant point.
    pub fixed: bool,
}

/// One observation: pose `pose` with camera `camera` sees point `point` at `pixel`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Index into [`Problem::poses`].
    pub pose: usize,
    /// Index into [`Problem::cameras`].
    pub camera: usize,
    /// Index into [`Problem::points`].
    pub point: usize,
    /// Observed pixel (COLMAP convention: the centre of the top-left pixel is
    /// (0.5, 0.5)).
    pub pixel: Vec2,
    /// Inverse standard deviation of the measurement in pixels (1 for a
    /// 1-pixel measurement); the residual and its Jacobians are multiplied by
    /// it, as ORB-SLAM weights keypoints by their pyramid level.
    pub weight: f64,
}

/// A bundle-adjustment problem.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Problem {
    /// Cameras (intrinsics).
    pub cameras: Vec<BaCamera>,
    /// Poses.
    pub poses: Vec<BaPose>,
    /// 3D points.
    pub points: Vec<BaPoint>,
    /// Observations.
    pub observations: Vec<Observation>,
}

impl Problem {
    /// Adds a camera; returns its index.
    pub fn add_camera(&mut self, camera: Camera, refine: IntrinsicsRefinement) -> usize {
        self.cameras.push(BaCamera { camera, refine });
        self.cameras.len() - 1
    }

    /// Adds a pose; returns its index.
    pub fn add_pose(&mut self, pose: BaPose) -> usize {
        self.poses.push(pose);
        self.poses.len() - 1
    }

    /// Adds a point; returns its index.
    pub fn add_point(&mut self, xyz: Vec3, fixed: bool) -> usize {
        self.points.push(BaPoint { xyz, fixed });
        self.points.len() - 1
    }

    /// Adds an observation of unit weight.
    pub fn add_observation(&mut self, pose: usize, camera: usize, point: usize, pixel: Vec2) {
        self.add_weighted_observation(pose, camera, point, pixel, 1.0);
    }

    /// Adds an observation whose residual is scaled by `weight` (the inverse
    /// standard deviation of the measurement in pixels).
    pub fn add_weighted_observation(&mut self, pose: usize, camera: usize, point: usize, pixel: Vec2, weight: f64) {
        self.observations.push(Observation { pose, camera, point, pixel, weight });
    }

    /// Checks indices, parameter counts and finiteness.
    pub fn validate(&self) -> Result<(), BaError> {
        for (i, c) in self.cameras.iter().enumerate() {
            let n = c.camera.model.num_params();
            if c.camera.params.len() != n {
                return Err(BaError::InvalidCamera {
                    index: i,
                    reason: format!("model {} takes {n} parameters, got {}", c.camera.model, c.camera.params.len()),
                });
            }
            if let Some(v) = c.camera.params.iter().find(|v| !v.is_finite()) {
                return Err(BaError::InvalidCamera { index: i, reason: format!("parameter value {v} is not finite") });
            }
            if let IntrinsicsRefinement::Params(idx) = &c.refine
                && let Some(&k) = idx.iter().find(|&&k| k >= n)
            {
                return Err(BaError::InvalidCamera {
                    index: i,
                    reason: format!("refined parameter index {k} out of range for {} ({n} parameters)", c.camera.model),
                });
            }
        }
        for (i, p) in self.poses.iter().enumerate() {
            let q = p.cam_from_world.rotation.quaternion();
            let finite = q.coords.iter().chain(p.cam_from_world.translation.iter()).all(|v| v.is_finite());
            if !finite {
                return Err(BaError::NonFinite { what: "pose", index: i });
            }
        }
        for (i, p) in self.points.iter().enumerate() {
            if !p.xyz.iter().all(|v| v.is_finite()) {
                return Err(BaError::NonFinite { what: "point", index: i });
            }
        }
        for (i, o) in self.observations.iter().enumerate() {
            let check = |what: &'static str, idx: usize, len: usize| {
                if idx >= len {
                    Err(BaError::IndexOutOfRange { observation: i, what, index: idx, len })
                } else {
                    Ok(())
                }
            };
            check("pose", o.pose, self.poses.len())?;
            check("camera", o.camera, self.cameras.len())?;
            check("point", o.point, self.points.len())?;
            if !o.pixel.iter().all(|v| v.is_finite()) {
                return Err(BaError::NonFinite { what: "observation pixel", index: i });
            }
            if !(o.weight.is_finite() && o.weight > 0.0) {
                return Err(BaError::NonFinite { what: "observation weight", index: i });
            }
        }
        Ok(())
    }
}

impl Problem {
    /// Removes the 7-degree-of-freedom similarity gauge as COLMAP does: pose
    /// `first` becomes constant, and of pose `second` the translation
    /// coordinate along which the two poses differ most becomes constant
    /// (that coordinate scales with the reconstruction, so fixing it fixes
    /// the scale). Out-of-range indices are ignored.
    pub fn fix_gauge(&mut self, first: usize, second: usize) {
        let (Some(a), Some(b)) = (self.poses.get(first), self.poses.get(second)) else { return };
        // second_from_first translation: how pose `second` moves when the
        // world is scaled about camera `first`.
        let rel = b.cam_from_world * a.cam_from_world.inverse();
        let t = rel.translation.abs();
        let coord = if t.x >= t.y && t.x >= t.z {
            0
        } else if t.y >= t.z {
            1
        } else {
            2
        };
        if let Some(p) = self.poses.get_mut(first) {
            p.fixed = true;
        }
        if first != second
            && let Some(p) = self.poses.get_mut(second)
        {
            p.fixed_translation[coord] = true;
        }
    }
}
