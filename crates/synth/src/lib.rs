//! Synthetic image sequences with exact ground truth: a textured room with
//! furniture-like boxes, seen by a hand-held-like camera, ray cast in
//! parallel and written in the TUM RGB-D layout.
//!
//! * [`SynthOptions`] / [`SynthOptions::validate`]: every knob, documented defaults.
//! * [`SyntheticSequence`]: the scene, camera, ground-truth poses and the
//!   precomputed ray table; renders colour ([`SyntheticSequence::render`],
//!   [`render_frame`]) and depth in memory, for tests elsewhere.
//! * [`generate`]: writes `rgb/*.png`, `rgb.txt`, `groundtruth.txt`,
//!   `camera.yaml` and `scene.json` into a folder (idempotent).
//!
//! ```no_run
//! use colslam_synth::{generate, SynthOptions, SyntheticSequence};
//! # fn main() -> Result<(), colslam_synth::SynthError> {
//! // Files (TUM layout), as `colslam demo` does:
//! let report = generate(&SynthOptions::default(), std::path::Path::new("demo"), None)?;
//! println!("{report}");
//! // In memory, for tests: images, depth and exact poses.
//! let seq = SyntheticSequence::new(&SynthOptions { frames: 10, ..Default::default() })?;
//! let image = seq.render(3)?;
//! let depth = seq.render_depth(3)?;
//! let cam_from_world = seq.cam_from_world(3)?;
//! # let _ = (image, depth, cam_from_world);
//! # Ok(())
//! # }
//! ```
//!
//! The scene: a room (default 6 x 5 x 2.8 m, an inside-out box) with a table
//! carrying stacked boxes, a shelf with items, cabinets, a sideboard and
//! random clutter, ~40 axis-aligned boxes in all. Every face has its own
//! baked procedural texture ([`texture`]): multi-octave value noise through
//! a per-surface palette, blobs, rectangles, striped patches and glyph-like
//! strokes, sampled bilinearly. Shading is Lambert + ambient (two fixed
//! directional lights), so brightness does not depend on the viewpoint.
//!
//! Conventions: world z is up (floor at z = 0); the camera is x right, y
//! down, z forward (COLMAP/OpenCV); ground truth is `world_from_cam` (TUM).
//! Pixel coordinates follow OpenCV/TUM (pixel `(i, j)` centred at `(i, j)`),
//! like the TUM datasets' `camera.yaml`, so the pipeline treats synthetic and
//! real sequences alike.

pub mod options;
pub mod output;
pub mod path;
pub mod render;
pub mod scene;
pub mod texture;

pub use options::{Distortion, PathShape, SynthError, SynthOptions, SynthReport};
pub use output::generate;
pub use path::Trajectory;
pub use scene::{Aabb, Hit, Scene, SceneBox};

use colslam_camera::Camera;
use colslam_geometry::{Rigid3, Vec2, Vec3};
use colslam_image::Image;

use render::RayTable;

/// A synthetic sequence held in memory: scene (with baked textures), camera,
/// trajectory and ray table. Building it costs the texture bake and the ray
/// table; rendering a frame is then cheap.
#[derive(Clone)]
pub struct SyntheticSequence {
    opts: SynthOptions,
    camera: Camera,
    scene: Scene,
    trajectory: Trajectory,
    poses: Vec<Rigid3>,
    rays: RayTable,
}

impl std::fmt::Debug for SyntheticSequence {
    /// A summary (the textures and ray table are megabytes).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SyntheticSequence")
            .field("frames", &self.poses.len())
            .field("camera", &self.camera)
            .field("boxes", &self.scene.boxes().len())
            .field("texels", &self.scene.texels())
            .field("seed", &self.opts.seed)
            .finish_non_exhaustive()
    }
}

impl SyntheticSequence {
    /// Validates the options, builds the scene and the path, checks that the
    /// path keeps clear of furniture and walls, and precomputes the rays.
    pub fn new(opts: &SynthOptions) -> Result<Self, SynthError> {
        opts.validate()?;
        let camera = render::make_camera(opts)?;
        let scene = Scene::build(opts);
        let trajectory = Trajectory::new(opts);
        let poses: Vec<Rigid3> = (0..opts.frames).map(|i| trajectory.world_from_cam(i as f64 / opts.fps)).collect();
        check_path(&scene, &trajectory, opts)?;
        let rays = RayTable::new(&camera, opts.width, opts.height, opts.supersample)?;
        Ok(Self { opts: opts.clone(), camera, scene, trajectory, poses, rays })
    }

    /// The options.
    pub fn options(&self) -> &SynthOptions {
        &self.opts
    }
    /// The camera (PINHOLE or OPENCV; OpenCV pixel convention).
    pub fn camera(&self) -> &Camera {
        &self.camera
    }
    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The continuous trajectory.
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }
    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.poses.len()
    }
    /// Timestamp of frame `i` in seconds (`i / fps`).
    pub fn timestamp(&self, i: usize) -> f64 {
        i as f64 / self.opts.fps
    }
    /// Ground-truth `world_from_cam` poses of all frames (TUM convention).
    pub fn world_from_cam(&self) -> &[Rigid3] {
        &self.poses
    }
    /// Ground-truth `cam_from_world` pose of frame `i` (COLMAP convention).
    pub fn cam_from_world(&self, i: usize) -> Result<Rigid3, SynthError> {
        self.pose(i).map(|p| p.inverse())
    }

    fn pose(&self, i: usize) -> Result<&Rigid3, SynthError> {
        self.poses.get(i).ok_or(SynthError::FrameOutOfRange { index: i, frames: self.poses.len() })
    }

    /// Renders frame `i`: supersampled, motion blurred when `motion_blur > 0`,
    /// row by row from the poses of a rolling shutter when `readout > 0`,
    /// with the configured noise.
    pub fn render(&self, i: usize) -> Result<Image, SynthError> {
        let pose = *self.pose(i)?;
        let (w, h) = (self.opts.width, self.opts.height);
        let mut acc = vec![0f32; w * h * 3];
        let t0 = self.timestamp(i);
        let blurred = self.opts.motion_blur > 0.0 && self.opts.blur_samples > 1;
        let (k, span) =
            if blurred { (self.opts.blur_samples, self.opts.motion_blur / self.opts.fps) } else { (1, 0.0) };
        let weight = 1.0 / k as f32;
        for s in 0..k {
            let t = if blurred { t0 + span * ((s as f64 + 0.5) / k as f64 - 0.5) } else { t0 };
            if self.opts.readout > 0.0 {
                let pose_of_row = |j: usize| self.trajectory.world_from_cam(self.row_time(t, j));
                render::accumulate_rolling(&self.scene, &self.rays, &pose_of_row, weight, &mut acc);
            } else if blurred {
                render::accumulate(&self.scene, &self.rays, &self.trajectory.world_from_cam(t), weight, &mut acc);
            } else {
                render::accumulate(&self.scene, &self.rays, &pose, 1.0, &mut acc);
            }
        }
        Ok(render::quantise(&acc, w, h, self.opts.noise_sigma, self.noise_seed(i)))
    }

    /// When pixel row `row` of an exposure at time `t` is read: the middle
    /// row at `t` (COLMAP's row centres `row + 0.5` over `height` rows).
    pub fn row_time(&self, t: f64, row: usize) -> f64 {
        t + ((row as f64 + 0.5) / self.opts.height as f64 - 0.5) * self.opts.readout
    }

    /// Renders the view from any `world_from_cam` pose (sharp, no noise).
    pub fn render_pose(&self, world_from_cam: &Rigid3) -> Image {
        let (w, h) = (self.opts.width, self.opts.height);
        let mut acc = vec![0f32; w * h * 3];
        render::accumulate(&self.scene, &self.rays, world_from_cam, 1.0, &mut acc);
        render::quantise(&acc, w, h, 0.0, 0)
    }

    fn noise_seed(&self, i: usize) -> u64 {
        colslam_geometry::SplitMix64::new(self.opts.seed ^ 0x4E01_5E00_0000_0004 ^ (i as u64).rotate_left(32))
            .next_u64()
    }

    /// Depth (camera z, metres) at every pixel centre of frame `i`, row-major
    /// (`width * height`). The room encloses the camera, so every value is
    /// finite and positive.
    pub fn render_depth(&self, i: usize) -> Result<Vec<f64>, SynthError> {
        Ok(render::depth_map(&self.scene, &self.rays, self.pose(i)?))
    }

    /// Depth (camera z) at every pixel centre of the view from any
    /// `world_from_cam` pose inside the room, row-major.
    pub fn render_depth_pose(&self, world_from_cam: &Rigid3) -> Vec<f64> {
        render::depth_map(&self.scene, &self.rays, world_from_cam)
    }

    /// Casts the ray through pixel `px` (continuous, OpenCV convention) of
    /// the view from `world_from_cam`: the hit and its world point. `None`
    /// when the pixel cannot be unprojected.
    pub fn cast_pixel(&self, world_from_cam: &Rigid3, px: &Vec2) -> Option<(Hit, Vec3)> {
        let n = self.camera.cam_from_img(px)?;
        let d = world_from_cam.rotation * Vec3::new(n.x, n.y, 1.0);
        let hit = self.scene.cast(&world_from_cam.translation, &d);
        Some((hit, world_from_cam.translation + d * hit.t))
    }

    /// Depth (camera z) of the scene seen through pixel `px` of frame `i`.
    pub fn depth_at(&self, i: usize, px: &Vec2) -> Result<Option<f64>, SynthError> {
        Ok(self.cast_pixel(self.pose(i)?, px).map(|(h, _)| h.t))
    }

    /// Projects a world point into frame `i` (pixel, depth); `None` when it
    /// is behind the camera.
    pub fn project(&self, i: usize, world: &Vec3) -> Result<Option<(Vec2, f64)>, SynthError> {
        let pc = self.pose(i)?.inverse().transform_point(world);
        Ok(self.camera.img_from_cam(&pc).map(|px| (px, pc.z)))
    }

    /// `n` surface points seen in frame `i`, at pixels drawn uniformly over
    /// the image (seeded, so deterministic): exact world points and their
    /// exact pixels, for estimator and bundle-adjustment tests.
    pub fn visible_points(&self, i: usize, n: usize, seed: u64) -> Result<Vec<SurfacePoint>, SynthError> {
        let pose = *self.pose(i)?;
        let mut rng = colslam_geometry::SplitMix64::new(seed);
        let (w, h) = (self.opts.width as f64, self.opts.height as f64);
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            // Continuous pixel positions within the image (OpenCV convention).
            let px = Vec2::new(rng.uniform(-0.5, w - 0.5), rng.uniform(-0.5, h - 0.5));
            if let Some((hit, world)) = self.cast_pixel(&pose, &px) {
                out.push(SurfacePoint { world, pixel: px, depth: hit.t, surface: hit.surface });
            }
        }
        Ok(out)
    }

    /// Where frame `i` sees the world point `world`: its pixel, when it
    /// projects inside the image and nothing occludes it (the depth seen
    /// through that pixel equals the point's depth to a relative 1e-9).
    pub fn observe(&self, i: usize, world: &Vec3) -> Result<Option<Vec2>, SynthError> {
        let Some((px, depth)) = self.project(i, world)? else { return Ok(None) };
        let (w, h) = (self.opts.width as f64, self.opts.height as f64);
        if !(px.x >= -0.5 && px.y >= -0.5 && px.x <= w - 0.5 && px.y <= h - 0.5) {
            return Ok(None);
        }
        let Some(seen) = self.depth_at(i, &px)? else { return Ok(None) };
        Ok(((seen - depth).abs() <= VISIBILITY_TOLERANCE * depth).then_some(px))
    }

    /// Length of the ground-truth path through all frames, metres.
    pub fn path_length(&self) -> f64 {
        self.poses.windows(2).map(|w| (w[1].translation - w[0].translation).norm()).sum()
    }
}

/// Relative depth tolerance of [`SyntheticSequence::observe`]'s visibility test.
pub const VISIBILITY_TOLERANCE: f64 = 1e-9;

/// A point on a scene surface seen in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// World coordinates.
    pub world: Vec3,
    /// Pixel (continuous, OpenCV convention) where the frame sees it.
    pub pixel: Vec2,
    /// Its depth (camera z) in the frame.
    pub depth: f64,
    /// Surface id (see [`Hit::surface`]).
    pub surface: usize,
}

/// Renders frame `index` of a sequence (see [`SyntheticSequence::render`]).
pub fn render_frame(seq: &SyntheticSequence, index: usize) -> Result<Image, SynthError> {
    seq.render(index)
}

/// Rejects paths that pass closer than [`scene::CAMERA_CLEARANCE`] to a box
/// or a wall (checked at every frame and at the motion-blur sub-frames' span).
fn check_path(scene: &Scene, tr: &Trajectory, opts: &SynthOptions) -> Result<(), SynthError> {
    // Sample densely (4 per frame, and half an interval beyond each end for
    // motion blur) so nothing slips between frames.
    let steps = 4 * opts.frames + 4;
    let dt = 1.0 / (4.0 * opts.fps);
    for k in 0..=steps {
        let t = -0.5 / opts.fps + k as f64 * dt;
        let c = tr.center(t);
        let clearance = scene.clearance(&c);
        if clearance < scene::CAMERA_CLEARANCE {
            return Err(SynthError::BadPath(format!(
                "at t = {t:.3} s the camera centre ({:.3}, {:.3}, {:.3}) is {clearance:.3} m from the nearest surface (minimum {})",
                c.x,
                c.y,
                c.z,
                scene::CAMERA_CLEARANCE
            )));
        }
    }
    Ok(())
}
