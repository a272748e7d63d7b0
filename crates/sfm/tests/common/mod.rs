//! Small synthetic scenes with exact geometry for the sfm integration tests:
//! pinhole cameras with known poses looking at known 3D points, keypoint `k`
//! of every image being the exact projection of point `k`.
#![allow(dead_code)]

use colslam_camera::Camera;
use colslam_geometry::{Mat3, Rigid3, SplitMix64, Vec2, Vec3};
use colslam_scene::{Image, ImageId, Point3DId, Reconstruction, TrackElement};
use colslam_sfm::CorrespondenceGraph;

/// Focal length (px) of the test camera.
pub const FOCAL: f64 = 500.0;

/// The test camera: 640 x 480 pinhole, f = 500 px, centred principal point.
pub fn camera() -> Camera {
    Camera::pinhole(640, 480, FOCAL, FOCAL, 320.0, 240.0)
}

/// Shorthand for an image id.
pub fn img(i: u32) -> ImageId {
    ImageId(i)
}

/// `cam_from_world` of a camera at `center` looking at `target` (camera y
/// axis pointing down, world +y is down).
pub fn look_at(center: Vec3, target: Vec3) -> Rigid3 {
    let z = (target - center).normalize();
    let x = Vec3::new(0.0, 1.0, 0.0).cross(&z).normalize();
    let y = z.cross(&x);
    let r = Mat3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    Rigid3::from_rotation_matrix(&r, -(r * center))
}

/// `n` cameras on the x axis, `spacing` apart starting at the origin, all
/// looking at (1, 0, 6).
pub fn line_poses(n: usize, spacing: f64) -> Vec<Rigid3> {
    (0..n).map(|i| look_at(Vec3::new(spacing * i as f64, 0.0, 0.0), Vec3::new(1.0, 0.0, 6.0))).collect()
}

/// `n` deterministic points in the box x in [-1, 2], y in [-1, 1], z in [5, 7].
pub fn box_points(n: usize, seed: u64) -> Vec<Vec3> {
    let mut rng = SplitMix64::new(seed);
    (0..n).map(|_| Vec3::new(rng.uniform(-1.0, 2.0), rng.uniform(-1.0, 1.0), rng.uniform(5.0, 7.0))).collect()
}

/// Pixel of a world point in an image with pose `pose` (no depth check: a
/// point behind the camera gives its mirrored pixel).
pub fn pixel(pose: &Rigid3, xyz: &Vec3) -> Vec2 {
    let p = pose.transform_point(xyz);
    Vec2::new(FOCAL * p.x / p.z + 320.0, FOCAL * p.y / p.z + 240.0)
}

/// A reconstruction and a correspondence graph over exact synthetic data.
pub struct Scene {
    /// Images `1..=poses.len()`, all registered, no 3D points.
    pub rec: Reconstruction,
    /// Every image, with as many keypoints as `truth` has points; no
    /// correspondences until a `match_*` call.
    pub graph: CorrespondenceGraph,
    /// The true points; keypoint `k` of each image observes `truth[k]`.
    pub truth: Vec<Vec3>,
    /// The true poses; `poses[i]` is image `i + 1`'s.
    pub poses: Vec<Rigid3>,
}

impl Scene {
    /// Images `1..=poses.len()` at `poses`, registered, keypoints the exact
    /// projections of `truth`.
    pub fn new(poses: Vec<Rigid3>, truth: Vec<Vec3>) -> Self {
        let mut rec = Reconstruction::new();
        let cam_id = rec.add_camera(camera());
        let mut graph = CorrespondenceGraph::new();
        for (i, pose) in poses.iter().enumerate() {
            let id = img(i as u32 + 1);
            let kps = truth.iter().map(|x| pixel(pose, x)).collect();
            let mut image = Image::new(id, format!("{id}.png"), cam_id, kps);
            image.cam_from_world = *pose;
            rec.add_image(image).unwrap();
            rec.register_image(id).unwrap();
            graph.add_image(id, truth.len()).unwrap();
        }
        Self { rec, graph, truth, poses }
    }

    /// `n_images` cameras 0.5 apart on a line, `n_points` box points.
    pub fn line(n_images: usize, n_points: usize) -> Self {
        Self::new(line_poses(n_images, 0.5), box_points(n_points, 7))
    }

    /// Number of points (= keypoints per image).
    pub fn n(&self) -> u32 {
        self.truth.len() as u32
    }

    /// Matches keypoint `k` of image `a` with keypoint `k` of image `b`, for every `k`.
    pub fn match_pair(&mut self, a: u32, b: u32) {
        let m: Vec<(u32, u32)> = (0..self.n()).map(|k| (k, k)).collect();
        assert_eq!(self.graph.add_correspondences(img(a), img(b), &m).unwrap(), m.len());
    }

    /// Matches consecutive images (1-2, 2-3, ...).
    pub fn match_chain(&mut self) {
        for a in 1..self.poses.len() as u32 {
            self.match_pair(a, a + 1);
        }
    }

    /// Matches every pair of images.
    pub fn match_all(&mut self) {
        let m = self.poses.len() as u32;
        for a in 1..=m {
            for b in a + 1..=m {
                self.match_pair(a, b);
            }
        }
    }

    /// Deregisters an image (before any point exists: only the flag changes).
    pub fn unregister(&mut self, i: u32) {
        self.rec.deregister_image(img(i)).unwrap();
    }

    /// Adds point `truth[k]` observed by keypoint `k` of each of `images`.
    pub fn add_true_point(&mut self, k: u32, images: &[u32]) -> Point3DId {
        self.add_point_at(self.truth[k as usize], k, images)
    }

    /// Adds a point at `xyz` observed by keypoint `k` of each of `images`.
    pub fn add_point_at(&mut self, xyz: Vec3, k: u32, images: &[u32]) -> Point3DId {
        let track = images.iter().map(|&i| TrackElement::new(img(i), k)).collect();
        self.rec.add_point3d(xyz, [0, 0, 0], track).unwrap()
    }

    /// Moves keypoint `k` of image `i` by `(dx, dy)` pixels.
    pub fn shift_keypoint(&mut self, i: u32, k: u32, dx: f64, dy: f64) {
        let xy = self.rec.image(img(i)).unwrap().points2d[k as usize].xy + Vec2::new(dx, dy);
        self.rec.set_point2d_xy(img(i), k, xy).unwrap();
    }

    /// The 3D point keypoint `k` of image `i` observes, if any.
    pub fn point_of(&self, i: u32, k: u32) -> Option<Point3DId> {
        self.rec.image(img(i)).unwrap().points2d[k as usize].point3d_id
    }

    /// Distance of a point to the truth of the keypoints of its track (all
    /// elements must share one keypoint index, as built here).
    pub fn truth_error(&self, pid: Point3DId) -> f64 {
        let p = self.rec.point3d(pid).unwrap();
        let k = p.track[0].point2d_idx;
        assert!(p.track.iter().all(|e| e.point2d_idx == k), "track mixes keypoints: {:?}", p.track);
        (p.xyz - self.truth[k as usize]).norm()
    }

    /// The sorted image ids of a point's track.
    pub fn track_images(&self, pid: Point3DId) -> Vec<u32> {
        let mut v: Vec<u32> = self.rec.point3d(pid).unwrap().track.iter().map(|e| e.image_id.0).collect();
        v.sort_unstable();
        v
    }

    /// Largest reprojection error (px) over every observation of the model.
    pub fn max_reprojection_error(&self) -> f64 {
        let mut worst: f64 = 0.0;
        for (_, p) in self.rec.points3d() {
            for el in &p.track {
                let image = self.rec.image(el.image_id).unwrap();
                let cam = &self.rec.camera(image.camera_id).unwrap().camera;
                let px = cam.img_from_cam(&image.cam_from_world.transform_point(&p.xyz)).unwrap();
                worst = worst.max((px - image.points2d[el.point2d_idx as usize].xy).norm());
            }
        }
        worst
    }
}

/// `pose` moved by a small deterministic rigid motion: a rotation of
/// `angle_deg` about a fixed oblique axis and a translation of length `shift`.
pub fn perturb_pose(pose: &Rigid3, angle_deg: f64, shift: f64) -> Rigid3 {
    let axis = colslam_geometry::nalgebra::Unit::new_normalize(Vec3::new(0.3, -0.8, 0.5));
    let delta = colslam_geometry::Quat::from_axis_angle(&axis, angle_deg.to_radians());
    Rigid3::new(delta * pose.rotation, pose.translation + Vec3::new(0.6, 0.0, -0.8) * shift)
}

/// A deterministic offset of length about `scale` for the `k`-th point.
pub fn point_offset(k: usize, scale: f64) -> Vec3 {
    let a = k as f64 * 2.399_963; // golden angle: offsets spread evenly
    Vec3::new(a.cos(), a.sin(), ((k % 3) as f64 - 1.0) * 0.5).normalize() * scale
}
