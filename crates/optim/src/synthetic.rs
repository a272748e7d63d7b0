//! Seeded synthetic bundle-adjustment scenes: a camera moving sideways along
//! a line (like a SLAM trajectory) in front of a slab of points, so that each
//! point is seen by a window of consecutive poses and the reduced camera
//! matrix is banded, as in real sequences.

use crate::BaError;
use crate::problem::{BaPose, IntrinsicsRefinement, Problem};
use crate::residual::reprojection_residual;
use colslam_camera::{Camera, CameraModelId};
use colslam_geometry::{Quat, Rigid3, SplitMix64, Vec2, Vec3};
use std::fmt::Write as _;
use std::path::Path;

/// Attempts at drawing a point seen by at least two poses before giving up
/// on that point.
const MAX_POINT_DRAWS: usize = 100;

/// Options of [`synthetic_scene`].
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticOptions {
    /// Number of poses. Default 10.
    pub num_poses: usize,
    /// Number of points (each seen by >= 2 poses when possible). Default 500.
    pub num_points: usize,
    /// The camera shared by all poses. Default SIMPLE_RADIAL 640x480,
    /// f = 500, k = -0.02.
    pub camera: Camera,
    /// Distance between consecutive camera centres along x. Default 0.3.
    pub step: f64,
    /// Range of point depths (z) in front of the trajectory. Default (4, 8).
    pub depth_range: (f64, f64),
    /// Standard deviation of the random camera rotation (radians). Default 0.05.
    pub rotation_jitter: f64,
    /// Standard deviation of Gaussian pixel noise. Default 0.
    pub pixel_noise: f64,
    /// Share of observations replaced by a uniformly random pixel. Default 0.
    pub outlier_ratio: f64,
    /// Seed. Default 0.
    pub seed: u64,
}

impl Default for SyntheticOptions {
    fn default() -> Self {
        Self {
            num_poses: 10,
            num_points: 500,
            camera: Camera {
                model: CameraModelId::SimpleRadial,
                width: 640,
                height: 480,
                params: vec![500.0, 320.0, 240.0, -0.02],
            },
            step: 0.3,
            depth_range: (4.0, 8.0),
            rotation_jitter: 0.05,
            pixel_noise: 0.0,
            outlier_ratio: 0.0,
            seed: 0,
        }
    }
}

impl SyntheticOptions {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), BaError> {
        let bad = |m: &str| Err(BaError::InvalidOptions(format!("synthetic scene: {m}")));
        if self.num_poses < 2 {
            return bad("need at least 2 poses");
        }
        let (lo, hi) = self.depth_range;
        if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
            return bad("depth_range must satisfy 0 < lo <= hi < inf");
        }
        if !(self.step.is_finite() && self.step > 0.0) {
            return bad("step must be finite and > 0");
        }
        if !(0.0..=1.0).contains(&self.outlier_ratio) {
            return bad("outlier_ratio must be in [0, 1]");
        }
        if !(self.pixel_noise >= 0.0 && self.rotation_jitter >= 0.0) {
            return bad("pixel_noise and rotation_jitter must be >= 0");
        }
        if self.camera.params.len() != self.camera.model.num_params() || self.camera.params.is_empty() {
            return bad("camera parameter count does not match its model");
        }
        Ok(())
    }
}

/// A synthetic problem with its ground truth.
#[derive(Debug, Clone)]
pub struct SyntheticScene {
    /// The problem (at ground truth; all poses and points variable, the
    /// camera refined per options). Perturb it to test convergence.
    pub problem: Problem,
    /// True `cam_from_world` poses.
    pub true_poses: Vec<Rigid3>,
    /// True points.
    pub true_points: Vec<Vec3>,
    /// True camera.
    pub true_camera: Camera,
    /// Per observation: true when it is an injected outlier.
    pub outliers: Vec<bool>,
}

/// Builds a synthetic scene.
pub fn synthetic_scene(options: &SyntheticOptions) -> Result<SyntheticScene, BaError> {
    options.validate()?;
    let mut rng = SplitMix64::new(options.seed);
    let cam = options.camera.clone();
    let (w, h) = (cam.width as f64, cam.height as f64);
    let f = cam.params[0];
    let length = (options.num_poses - 1) as f64 * options.step;
    let mut true_poses = Vec::with_capacity(options.num_poses);
    for i in 0..options.num_poses {
        let centre = Vec3::new(i as f64 * options.step, 0.1 * rng.normal(), 0.1 * rng.normal());
        let j = options.rotation_jitter;
        let rot = Quat::from_euler_angles(j * rng.normal(), j * rng.normal(), j * rng.normal());
        true_poses.push(Rigid3::new(rot, centre).inverse());
    }
    let (zlo, zhi) = options.depth_range;
    let margin = 0.5 * zhi * w / f;
    let half_h = 0.5 * 0.5 * (zlo + zhi) * h / f;
    let mut problem = Problem::default();
    let cam_idx = problem.add_camera(cam.clone(), IntrinsicsRefinement::FromOptions);
    for p in &true_poses {
        problem.add_pose(BaPose::variable(*p));
    }
    let mut true_points = Vec::with_capacity(options.num_points);
    let mut outliers = Vec::new();
    let mut seen = Vec::new();
    for _ in 0..options.num_points {
        let mut x = Vec3::zeros();
        for _ in 0..MAX_POINT_DRAWS {
            x = Vec3::new(rng.uniform(-margin, length + margin), rng.uniform(-half_h, half_h), rng.uniform(zlo, zhi));
            seen.clear();
            for (i, p) in true_poses.iter().enumerate() {
                if let Some(px) = reprojection_residual(&cam, p, &x, &Vec2::zeros())
                    && (0.0..w).contains(&px.x)
                    && (0.0..h).contains(&px.y)
                {
                    seen.push((i, px));
                }
            }
            if seen.len() >= 2 {
                break;
            }
        }
        let pt = problem.add_point(x, false);
        true_points.push(x);
        for &(i, px) in &seen {
            let outlier = rng.next_f64() < options.outlier_ratio;
            let pixel = if outlier {
                Vec2::new(rng.uniform(0.0, w), rng.uniform(0.0, h))
            } else {
                px + options.pixel_noise * Vec2::new(rng.normal(), rng.normal())
            };
            problem.add_observation(i, cam_idx, pt, pixel);
            outliers.push(outlier);
        }
    }
    Ok(SyntheticScene { problem, true_poses, true_points, true_camera: cam, outliers })
}

/// Perturbs every pose (rotation by `rotation_sigma` radians, translation by
/// `translation_sigma`) and point (by `point_sigma`) of `problem`, seeded.
pub fn perturb(problem: &mut Problem, rotation_sigma: f64, translation_sigma: f64, point_sigma: f64, seed: u64) {
    let mut rng = SplitMix64::new(seed);
    let mut n3 = |s: f64| Vec3::new(rng.normal(), rng.normal(), rng.normal()) * s;
    for p in &mut problem.poses {
        let w = n3(rotation_sigma);
        let t = n3(translation_sigma);
        p.cam_from_world =
            Rigid3::new(Quat::from_scaled_axis(w) * p.cam_from_world.rotation, p.cam_from_world.translation + t);
    }
    for p in &mut problem.points {
        p.xyz += n3(point_sigma);
    }
}

/// Writes a problem as a COLMAP text model (`cameras.txt`, `images.txt`,
/// `points3D.txt` in `dir`), to run COLMAP's or pycolmap's bundle adjustment
/// on the same data. Ids are 1-based indices (camera `i + 1`, image `i + 1`
/// named `<i>.png`, point `j + 1`); each image's camera is that of its first
/// observation.
pub fn write_colmap_text(problem: &Problem, dir: &Path) -> Result<(), BaError> {
    let io = |path: &Path, e: std::io::Error| BaError::Io { path: path.to_path_buf(), message: e.to_string() };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let mut cams = String::from("# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    for (i, c) in problem.cameras.iter().enumerate() {
        let params: Vec<String> = c.camera.params.iter().map(|v| format!("{v:.17}")).collect();
        let _ = writeln!(
            cams,
            "{} {} {} {} {}",
            i + 1,
            c.camera.model.name(),
            c.camera.width,
            c.camera.height,
            params.join(" ")
        );
    }
    // Per image: its observations, in order (POINT2D_IDX = position).
    let mut per_image: Vec<Vec<usize>> = vec![Vec::new(); problem.poses.len()];
    let mut track: Vec<Vec<(usize, usize)>> = vec![Vec::new(); problem.points.len()];
    for (k, o) in problem.observations.iter().enumerate() {
        track[o.point].push((o.pose + 1, per_image[o.pose].len()));
        per_image[o.pose].push(k);
    }
    let mut images =
        String::from("# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n");
    for (i, p) in problem.poses.iter().enumerate() {
        let q = p.cam_from_world.quat_wxyz();
        let t = p.cam_from_world.translation;
        let cam = per_image[i].first().map(|&k| problem.observations[k].camera).unwrap_or(0);
        let _ = writeln!(
            images,
            "{} {:.17} {:.17} {:.17} {:.17} {:.17} {:.17} {:.17} {} {}.png",
            i + 1,
            q[0],
            q[1],
            q[2],
            q[3],
            t.x,
            t.y,
            t.z,
            cam + 1,
            i
        );
        let obs: Vec<String> = per_image[i]
            .iter()
            .map(|&k| {
                let o = &problem.observations[k];
                format!("{:.17} {:.17} {}", o.pixel.x, o.pixel.y, o.point + 1)
            })
            .collect();
        let _ = writeln!(images, "{}", obs.join(" "));
    }
    let mut pts = String::from("# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    for (j, p) in problem.points.iter().enumerate() {
        let tr: Vec<String> = track[j].iter().map(|(i, k)| format!("{i} {k}")).collect();
        let _ =
            writeln!(pts, "{} {:.17} {:.17} {:.17} 128 128 128 0 {}", j + 1, p.xyz.x, p.xyz.y, p.xyz.z, tr.join(" "));
    }
    for (name, text) in [("cameras.txt", cams), ("images.txt", images), ("points3D.txt", pts)] {
        // Temp-then-rename: a reader never sees a half-written file.
        let tmp = dir.join(format!(".{name}.tmp"));
        let path = dir.join(name);
        std::fs::write(&tmp, text).map_err(|e| io(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| io(&path, e))?;
    }
    Ok(())
}
