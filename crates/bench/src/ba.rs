//! `colslam bench ba`: colslam-optim's bundle adjuster against Ceres (pycolmap
//! 4.2's `bundle_adjustment`, through `scripts/peers/bench_ba.py`) on
//! identical problems.
//!
//! Each problem is written once as a binary COLMAP model to a temporary
//! folder; both sides read that folder (ours with `colslam_scene::read_model`)
//! and solve the same thing: every registered image and every point vary,
//! intrinsics are constant, the gauge is COLMAP's TWO_CAMS_FROM_WORLD (the
//! first registered image by id constant, and of the second the translation
//! coordinate along which the two differ most; `Problem::fix_gauge` is the
//! same rule), the same robust loss, Ceres' default tolerances on both sides,
//! at most [`MAX_ITERATIONS`] LM iterations, the same thread count.
//!
//! Problems:
//! * `a`: synthetic, 100 poses / 20,000 points / ~250 k observations, 2 %
//!   outliers, perturbed; Cauchy(1) loss.
//! * `b`: local-BA size, 7 poses / 3,000 points, 2 % outliers, perturbed;
//!   soft-L1(1) (the loss of COLMAP's local BA).
//! * `c`: a real reconstruction: pycolmap (SIFT, sequential matching,
//!   incremental mapping, `scripts/peers/make_tum_model.py`) on the first
//!   `--frames` frames of `tum_fr1_rpy_sub`, cached under
//!   `$XDG_CACHE_HOME/colslam/bench-ba/`; poses and points are perturbed
//!   with a seed (scaled by the scene's median depth) so both solvers have
//!   work to do; trivial loss (that of COLMAP's global BA).
//!
//! Timed on both sides: the solve only (ours `BundleAdjuster::solve`, theirs
//! `adjuster.solve()`), not reading the model or building the problem. Wall
//! time is the minimum over `--repeats`; CPU time is process CPU (all
//! threads) of that run.

use crate::features::{machine, peer_script};
use crate::stdout::outln;
use anyhow::{Context, Result, anyhow, bail};
use colslam_geometry::stats::upper_median_in_place;
use colslam_geometry::{Quat, Rigid3, SplitMix64, Vec3};
use colslam_optim::synthetic::{SyntheticOptions, perturb, synthetic_scene};
use colslam_optim::{BaOptions, BaPose, BaReport, BundleAdjuster, IntrinsicsRefinement, LossFunction, Problem};
use colslam_scene::{
    CameraId, Image, ImageId, ModelFormat, Point3D, Point3DId, Reconstruction, TrackElement, UNKNOWN_ERROR, read_model,
    write_model,
};
use colslam_testutil::{find_data_dir, find_peer_python};
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// LM iteration cap on both sides (COLMAP's default for BA).
const MAX_ITERATIONS: usize = 100;
/// The goal: our final cost within this relative distance of Ceres'.
const COST_TOLERANCE: f64 = 1e-3;
/// Seed of the synthetic scenes.
const SCENE_SEED: u64 = 1;
/// Seed of the perturbation of every problem.
const PERTURB_SEED: u64 = 2;
/// Synthetic perturbation: rotation (rad), translation and point sigmas
/// (scene units; points lie 4-8 units deep).
const SYNTH_PERTURB: (f64, f64, f64) = (0.002, 0.01, 0.05);
/// Real-model perturbation: rotation sigma (rad).
const REAL_ROTATION_SIGMA: f64 = 0.001;
/// Real-model perturbation: translation and point sigma as a fraction of the
/// median observation depth.
const REAL_OFFSET_SIGMA: f64 = 0.002;
/// Points of the real model observed at a depth below this fraction of the
/// median observation depth are removed (degenerate triangulations).
const REAL_MIN_DEPTH_FRACTION: f64 = 0.01;
/// Pixel noise of the synthetic observations.
const SYNTH_PIXEL_NOISE: f64 = 0.5;
/// Share of synthetic observations replaced by random pixels.
const SYNTH_OUTLIERS: f64 = 0.02;
/// Dataset of problem `c`.
const REAL_DATASET: &str = "tum_fr1_rpy_sub";

/// Which problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Which {
    /// Synthetic, 100 poses / 20,000 points / ~250 k observations.
    A,
    /// Local-BA size, 7 poses / 3,000 points.
    B,
    /// Real reconstruction of tum_fr1_rpy_sub by pycolmap.
    C,
}

/// Arguments of `bench ba`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Run one problem only.
    #[arg(long, value_enum)]
    pub only: Option<Which>,
    /// Solves per side and thread count; the minimum wall time is reported.
    #[arg(long, default_value_t = 1)]
    pub repeats: usize,
    /// Frames of tum_fr1_rpy_sub reconstructed for problem `c`.
    #[arg(long, default_value_t = 120)]
    pub frames: usize,
    /// Skip the extra 1-thread runs (CPU-time comparison).
    #[arg(long)]
    pub no_single_thread: bool,
    /// Keep the problem models in this folder instead of a removed temp folder.
    #[arg(long)]
    pub keep: Option<PathBuf>,
}

/// One benchmark problem, written as a model.
struct Spec {
    name: &'static str,
    description: String,
    loss: LossFunction,
    /// Loss name and scale as `bench_ba.py` takes them.
    peer_loss: (&'static str, f64),
}

/// Removes the temporary folder when dropped (also on error).
struct TempDir(Option<PathBuf>);

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Some(d) = &self.0 {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// One side's run at one thread count.
#[derive(Debug, Clone)]
struct Run {
    wall_s: f64,
    cpu_s: f64,
    initial_cost: f64,
    final_cost: f64,
    iterations: usize,
    linear_solver: String,
    termination: String,
}

/// Process CPU time (user + system, all threads), seconds.
fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec for the duration of the call.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    if r != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
}

/// Writes a synthetic [`Problem`] as a [`Reconstruction`]: camera `i + 1`,
/// image `i + 1` (registered, named `<i>.png`), point `j + 1`. Points seen
/// fewer than twice are left out (a single ray does not constrain a point;
/// COLMAP's models never hold one).
fn problem_to_reconstruction(problem: &Problem) -> Result<Reconstruction> {
    let mut rec = Reconstruction::new();
    let id32 = |i: usize| u32::try_from(i + 1).map_err(|_| anyhow!("too many items for a COLMAP id"));
    for (i, c) in problem.cameras.iter().enumerate() {
        rec.add_camera_with_id(CameraId(id32(i)?), c.camera.clone())?;
    }
    let mut count = vec![0usize; problem.points.len()];
    for o in &problem.observations {
        if let Some(c) = count.get_mut(o.point) {
            *c += 1;
        }
    }
    let kept = |point: usize| count.get(point).is_some_and(|&c| c >= 2);
    let mut per_image: Vec<Vec<usize>> = vec![Vec::new(); problem.poses.len()];
    let mut tracks: Vec<Vec<TrackElement>> = vec![Vec::new(); problem.points.len()];
    for (k, o) in problem.observations.iter().enumerate() {
        if !kept(o.point) {
            continue;
        }
        let list = per_image.get_mut(o.pose).ok_or_else(|| anyhow!("observation {k}: pose {} out of range", o.pose))?;
        let idx = u32::try_from(list.len())?;
        list.push(k);
        if let Some(t) = tracks.get_mut(o.point) {
            t.push(TrackElement::new(ImageId(id32(o.pose)?), idx));
        }
    }
    for (i, (pose, obs)) in problem.poses.iter().zip(&per_image).enumerate() {
        let camera = obs.first().and_then(|&k| problem.observations.get(k)).map_or(0, |o| o.camera);
        let pixels = obs.iter().filter_map(|&k| problem.observations.get(k)).map(|o| o.pixel).collect();
        let mut image = Image::new(ImageId(id32(i)?), format!("{i}.png"), CameraId(id32(camera)?), pixels);
        image.cam_from_world = pose.cam_from_world;
        image.registered = true;
        rec.add_image(image)?;
    }
    for (j, (p, track)) in problem.points.iter().zip(tracks).enumerate() {
        if track.len() < 2 {
            continue;
        }
        let id = Point3DId(u64::try_from(j + 1)?);
        rec.add_point3d_with_id(id, Point3D { xyz: p.xyz, color: [128; 3], error: UNKNOWN_ERROR, track })?;
    }
    Ok(rec)
}

/// The problem pycolmap's BA builds from `rec` (see the module docs): poses
/// of the registered images in id order, constant intrinsics, all points
/// variable, gauge on the first two images.
fn reconstruction_to_problem(rec: &Reconstruction) -> Result<Problem> {
    let mut problem = Problem::default();
    let mut cams: BTreeMap<CameraId, usize> = BTreeMap::new();
    for c in rec.cameras() {
        cams.insert(c.id, problem.add_camera(c.camera.clone(), IntrinsicsRefinement::Fixed));
    }
    // Like COLMAP's adjuster, only images with at least one observation take
    // part (and so can be picked for the gauge).
    let observing: std::collections::BTreeSet<ImageId> =
        rec.points3d().flat_map(|(_, p)| p.track.iter().map(|el| el.image_id)).collect();
    let mut poses: BTreeMap<ImageId, (usize, usize)> = BTreeMap::new();
    for img in rec.images().filter(|i| i.registered && observing.contains(&i.id)) {
        let cam = *cams
            .get(&img.camera_id)
            .ok_or_else(|| anyhow!("image {} has unknown camera {}", img.id, img.camera_id))?;
        poses.insert(img.id, (problem.add_pose(BaPose::variable(img.cam_from_world)), cam));
    }
    for (pid, p) in rec.points3d() {
        let pi = problem.add_point(p.xyz, false);
        for el in &p.track {
            let (Some(&(pose, cam)), Some(img)) = (poses.get(&el.image_id), rec.image(el.image_id)) else { continue };
            let kp = img
                .points2d
                .get(el.point2d_idx as usize)
                .ok_or_else(|| anyhow!("point {pid}: image {} has no keypoint {}", el.image_id, el.point2d_idx))?;
            problem.add_observation(pose, cam, pi, kp.xy);
        }
    }
    // `images()` iterates by increasing id, so poses 0 and 1 are the two
    // smallest observing image ids: the pair COLMAP's
    // FixGaugeWithTwoCamsFromWorld takes (it walks a std::set of image ids
    // and takes the second with a non-zero baseline). Its fixed coordinate is
    // the largest of cam1_from_cam2's translation, fix_gauge's that of
    // cam2_from_cam1: the same for the small relative rotations here.
    problem.fix_gauge(0, 1);
    Ok(problem)
}

/// A synthetic problem (perturbed) as a reconstruction.
fn synthetic(num_poses: usize, num_points: usize, step: f64) -> Result<Reconstruction> {
    let scene = synthetic_scene(&SyntheticOptions {
        num_poses,
        num_points,
        step,
        pixel_noise: SYNTH_PIXEL_NOISE,
        outlier_ratio: SYNTH_OUTLIERS,
        seed: SCENE_SEED,
        ..Default::default()
    })?;
    let mut problem = scene.problem;
    let (r, t, p) = SYNTH_PERTURB;
    perturb(&mut problem, r, t, p, PERTURB_SEED);
    problem_to_reconstruction(&problem)
}

/// The cache folder of the real model.
fn cache_dir(frames: usize) -> PathBuf {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(std::env::temp_dir);
    base.join("colslam").join("bench-ba").join(format!("{REAL_DATASET}-{frames}"))
}

/// The pycolmap reconstruction of the first `frames` frames, built once.
fn real_model(frames: usize, threads: usize, quiet: bool) -> Result<Reconstruction> {
    let dir = cache_dir(frames);
    let sparse = dir.join("sparse");
    if !sparse.join("points3D.bin").is_file() {
        let dataset = find_data_dir()?.join(REAL_DATASET);
        if !dataset.is_dir() {
            bail!("dataset {} not found", dataset.display());
        }
        if !quiet {
            eprintln!(
                "bench ba: reconstructing {frames} frames of {REAL_DATASET} with pycolmap into {} (once)",
                dir.display()
            );
        }
        let py = find_peer_python()?;
        let script = peer_script("make_tum_model.py")?;
        let out = Command::new(&py)
            .arg(&script)
            .arg(&dataset)
            .arg(&dir)
            .args(["--num-frames", &frames.to_string(), "--threads", &threads.to_string()])
            .output()
            .with_context(|| format!("cannot start {}", py.display()))?;
        if !out.status.success() {
            bail!("{} failed:\n{}", script.display(), String::from_utf8_lossy(&out.stderr));
        }
        if !quiet {
            eprintln!("bench ba: {}", String::from_utf8_lossy(&out.stdout).trim());
        }
    }
    read_model(&sparse).with_context(|| format!("cannot read the cached model {}", sparse.display()))
}

/// Upper median of the depths of every observation of a model (one of the
/// depths); an error when the model has no observation.
fn median_observation_depth(rec: &Reconstruction) -> Result<f64> {
    let mut depths: Vec<f64> = Vec::new();
    for (_, p) in rec.points3d() {
        for el in &p.track {
            if let Some(img) = rec.image(el.image_id) {
                depths.push(img.cam_from_world.transform_point(&p.xyz).z);
            }
        }
    }
    upper_median_in_place(&mut depths).ok_or_else(|| anyhow!("the real model has no observations"))
}

/// Removes points seen at a depth below [`REAL_MIN_DEPTH_FRACTION`] of the
/// median; returns how many.
fn remove_near_points(rec: &mut Reconstruction) -> Result<usize> {
    let min_depth = REAL_MIN_DEPTH_FRACTION * median_observation_depth(rec)?;
    let near: Vec<Point3DId> = rec
        .points3d()
        .filter(|(_, p)| {
            p.track.iter().any(|el| {
                rec.image(el.image_id).is_some_and(|img| img.cam_from_world.transform_point(&p.xyz).z < min_depth)
            })
        })
        .map(|(id, _)| id)
        .collect();
    for id in &near {
        rec.delete_point3d(*id)?;
    }
    Ok(near.len())
}

/// Perturbs the registered poses (by id) and points (by id) of a real model,
/// seeded; offsets scale with the median observation depth.
fn perturb_reconstruction(rec: &mut Reconstruction, seed: u64) -> Result<()> {
    let sigma = REAL_OFFSET_SIGMA * median_observation_depth(rec)?.abs();
    let mut rng = SplitMix64::new(seed);
    let mut n3 = |s: f64| Vec3::new(rng.normal(), rng.normal(), rng.normal()) * s;
    let ids: Vec<ImageId> = rec.images().filter(|i| i.registered).map(|i| i.id).collect();
    for id in ids {
        let (w, t) = (n3(REAL_ROTATION_SIGMA), n3(sigma));
        if let Some(pose) = rec.cam_from_world_mut(id) {
            *pose = Rigid3::new(Quat::from_scaled_axis(w) * pose.rotation, pose.translation + t);
        }
    }
    for pid in rec.point3d_ids() {
        let d = n3(sigma);
        if let Some(xyz) = rec.point3d_xyz_mut(pid) {
            *xyz += d;
        }
    }
    Ok(())
}

/// Our solve of the model in `dir`, `repeats` times (fresh read each time).
fn run_ours(dir: &Path, loss: LossFunction, threads: usize, repeats: usize) -> Result<(Run, (BaReport, usize))> {
    let options = BaOptions { loss, num_threads: threads, max_iterations: MAX_ITERATIONS, ..Default::default() };
    let mut best: Option<(Run, (BaReport, usize))> = None;
    for _ in 0..repeats.max(1) {
        let rec = read_model(dir).with_context(|| format!("cannot read {}", dir.display()))?;
        let mut problem = reconstruction_to_problem(&rec)?;
        let (t0, c0) = (Instant::now(), cpu_seconds());
        let report = BundleAdjuster::solve(&mut problem, &options)?;
        let (wall_s, cpu_s) = (t0.elapsed().as_secs_f64(), cpu_seconds() - c0);
        let run = Run {
            wall_s,
            cpu_s,
            initial_cost: report.initial_cost,
            final_cost: report.final_cost,
            iterations: report.iterations,
            linear_solver: format!("{:?}", report.linear_solver),
            termination: format!("{:?}", report.termination),
        };
        if best.as_ref().is_none_or(|(b, _)| run.wall_s < b.wall_s) {
            best = Some((run, (report, problem.poses.len())));
        }
    }
    best.ok_or_else(|| anyhow!("no run"))
}

/// Ceres' solve through `bench_ba.py`.
fn run_ceres(dir: &Path, peer_loss: (&str, f64), threads: usize, repeats: usize) -> Result<(Run, Value)> {
    let py = find_peer_python()?;
    let script = peer_script("bench_ba.py")?;
    let out = Command::new(&py)
        .arg(&script)
        .arg(dir)
        .args(["--loss", peer_loss.0, "--scale", &peer_loss.1.to_string()])
        .args(["--threads", &threads.to_string(), "--repeats", &repeats.max(1).to_string()])
        .args(["--max-iterations", &MAX_ITERATIONS.to_string()])
        .output()
        .with_context(|| format!("cannot start {} (run scripts/setup-peers.sh)", py.display()))?;
    if !out.status.success() {
        bail!("{} failed on {}:\n{}", script.display(), dir.display(), String::from_utf8_lossy(&out.stderr));
    }
    let v: Value =
        serde_json::from_slice(&out.stdout).with_context(|| format!("{} printed no valid JSON", script.display()))?;
    let num =
        |k: &str| v.get(k).and_then(Value::as_f64).ok_or_else(|| anyhow!("{} output lacks `{k}`", script.display()));
    let text = |k: &str| v.get(k).and_then(Value::as_str).unwrap_or("?").to_string();
    let run = Run {
        wall_s: num("wall_s")?,
        cpu_s: num("cpu_s")?,
        initial_cost: num("initial_cost")?,
        final_cost: num("final_cost")?,
        iterations: num("iterations")? as usize,
        linear_solver: text("linear_solver").trim_start_matches("LinearSolverType.").to_string(),
        termination: text("termination").trim_start_matches("TerminationType.").to_string(),
    };
    Ok((run, v))
}

/// Runs `bench ba` with `threads` on both sides (the global `--threads`;
/// `None`: the number of cores).
pub fn run(args: &Args, quiet: bool, threads: Option<usize>) -> Result<()> {
    let nproc = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let threads = threads.unwrap_or(nproc);
    if args.repeats == 0 {
        bail!("--repeats must be >= 1");
    }
    if args.frames < 2 {
        bail!("--frames must be >= 2");
    }
    let (root, _guard) = match &args.keep {
        Some(d) => (d.clone(), TempDir(None)),
        None => {
            let d = std::env::temp_dir().join(format!("colslam-bench-ba-{}", std::process::id()));
            (d.clone(), TempDir(Some(d)))
        }
    };
    let wanted = |w: Which| args.only.is_none_or(|o| o == w);
    let mut problems: Vec<(Spec, PathBuf)> = Vec::new();
    let mut add = |spec: Spec, rec: Reconstruction| -> Result<()> {
        let dir = root.join(spec.name);
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        write_model(&rec, &dir, ModelFormat::Binary).with_context(|| format!("cannot write {}", dir.display()))?;
        problems.push((spec, dir));
        Ok(())
    };
    if wanted(Which::A) {
        let spec = Spec {
            name: "a_synthetic_100x20000",
            description: "synthetic, 100 poses / 20,000 points, 2 % outliers, perturbed".into(),
            loss: LossFunction::Cauchy(1.0),
            peer_loss: ("cauchy", 1.0),
        };
        add(spec, synthetic(100, 20_000, 0.6)?)?;
    }
    if wanted(Which::B) {
        let spec = Spec {
            name: "b_local_7x3000",
            description: "local-BA size, 7 poses / 3,000 points, 2 % outliers, perturbed".into(),
            loss: LossFunction::SoftL1(1.0),
            peer_loss: ("soft_l1", 1.0),
        };
        add(spec, synthetic(7, 3_000, 0.3)?)?;
    }
    if wanted(Which::C) {
        let mut rec = real_model(args.frames, threads, quiet)?;
        // pycolmap's model can hold a point (almost) at a camera centre (depth
        // ~1e-8 with a small reprojection error): any perturbation gives it
        // an enormous error that dominates a trivial-loss cost. Such points
        // are removed before the benchmark.
        let removed = remove_near_points(&mut rec)?;
        if !quiet {
            eprintln!(
                "bench ba: real model: {removed} point(s) nearer than {REAL_MIN_DEPTH_FRACTION} x median depth removed"
            );
        }
        perturb_reconstruction(&mut rec, PERTURB_SEED)?;
        let spec = Spec {
            name: "c_real_tum_fr1_rpy",
            description: format!(
                "pycolmap reconstruction of {} frames of {REAL_DATASET} (FULL_OPENCV, SIFT, sequential), perturbed",
                args.frames
            ),
            loss: LossFunction::Trivial,
            peer_loss: ("trivial", 1.0),
        };
        add(spec, rec)?;
    }

    let mut thread_counts = vec![threads];
    if threads != 1 && !args.no_single_thread {
        thread_counts.push(1);
    }
    let mut rows = Vec::new();
    let mut pycolmap_version = Value::Null;
    for (spec, dir) in &problems {
        let mut per_threads = Vec::new();
        let mut report = None;
        for &t in &thread_counts {
            if !quiet {
                eprintln!("bench ba: {} with {t} thread(s)", spec.name);
            }
            let (ours, rep) = run_ours(dir, spec.loss, t, args.repeats)?;
            let (ceres, peer) = run_ceres(dir, spec.peer_loss, t, args.repeats)?;
            pycolmap_version = peer.get("pycolmap_version").cloned().unwrap_or(Value::Null);
            report.get_or_insert(rep);
            per_threads.push((t, ours, ceres));
        }
        let Some((report, num_images)) = report else { continue };
        let Some((_, ours, ceres)) = per_threads.first() else { continue };
        let rel = (ours.final_cost - ceres.final_cost) / ceres.final_cost.abs().max(f64::MIN_POSITIVE);
        let mut row = json!({
            "name": spec.name,
            "description": spec.description,
            "loss": format!("{:?}", spec.loss),
            "num_images": num_images,
            "num_points": report.num_variable_points,
            "num_observations": report.num_observations,
            "threads": threads,
            "ours_initial_cost": ours.initial_cost,
            "ceres_initial_cost": ceres.initial_cost,
            "ours_final_cost": ours.final_cost,
            "ceres_final_cost": ceres.final_cost,
            "final_cost_rel_diff": rel,
            "final_cost_within_0.1pct": rel <= COST_TOLERANCE,
            "ours_iterations": ours.iterations,
            "ceres_iterations": ceres.iterations,
            "ours_s": ours.wall_s,
            "ceres_s": ceres.wall_s,
            "ratio": ours.wall_s / ceres.wall_s,
            "ours_cpu_s": ours.cpu_s,
            "ceres_cpu_s": ceres.cpu_s,
            "ours_linear_solver": ours.linear_solver,
            "ceres_linear_solver": ceres.linear_solver,
            "ours_termination": ours.termination,
            "ceres_termination": ceres.termination,
        });
        if let (Some((_, o1, c1)), Some(obj)) = (per_threads.get(1), row.as_object_mut()) {
            obj.insert("ours_1t_s".into(), json!(o1.wall_s));
            obj.insert("ceres_1t_s".into(), json!(c1.wall_s));
            obj.insert("ours_1t_cpu_s".into(), json!(o1.cpu_s));
            obj.insert("ceres_1t_cpu_s".into(), json!(c1.cpu_s));
            obj.insert("ratio_1t_cpu".into(), json!(o1.cpu_s / c1.cpu_s));
            obj.insert("ours_1t_final_cost".into(), json!(o1.final_cost));
            obj.insert("ceres_1t_final_cost".into(), json!(c1.final_cost));
        }
        rows.push(row);
    }
    let out = json!({
        "benchmark": "ba",
        "machine": machine(),
        "threads": threads,
        "repeats": args.repeats,
        "max_iterations": MAX_ITERATIONS,
        "pycolmap_version": pycolmap_version,
        "problems": rows,
    });
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    print_table(&out);
    Ok(())
}

/// Human-readable table of the JSON result.
fn print_table(out: &Value) {
    let m = &out["machine"];
    outln!(
        "bundle adjustment, colslam-optim vs Ceres (pycolmap {}), {} thread(s); {} cores ({}), load {}",
        out["pycolmap_version"].as_str().unwrap_or("?"),
        out["threads"],
        m["nproc"],
        m["cpu_model"].as_str().unwrap_or("?"),
        m["loadavg"].as_str().unwrap_or("?"),
    );
    let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    for p in out["problems"].as_array().into_iter().flatten() {
        outln!(
            "\n{} ({}; {} images, {} points, {} observations, loss {})",
            p["name"].as_str().unwrap_or("?"),
            p["description"].as_str().unwrap_or("?"),
            p["num_images"],
            p["num_points"],
            p["num_observations"],
            p["loss"].as_str().unwrap_or("?"),
        );
        outln!("  {:<22} {:>16} {:>16} {:>10}", "", "colslam", "ceres", "ours/ceres");
        outln!("  {:<22} {:>16.6} {:>16.6}", "initial cost", f(&p["ours_initial_cost"]), f(&p["ceres_initial_cost"]));
        outln!(
            "  {:<22} {:>16.6} {:>16.6} {:>+9.5}%",
            "final cost",
            f(&p["ours_final_cost"]),
            f(&p["ceres_final_cost"]),
            100.0 * f(&p["final_cost_rel_diff"])
        );
        outln!(
            "  {:<22} {:>16} {:>16}",
            "iterations",
            p["ours_iterations"].to_string(),
            p["ceres_iterations"].to_string()
        );
        outln!("  {:<22} {:>16.3} {:>16.3} {:>10.2}", "wall s", f(&p["ours_s"]), f(&p["ceres_s"]), f(&p["ratio"]));
        outln!(
            "  {:<22} {:>16.3} {:>16.3} {:>10.2}",
            "CPU s",
            f(&p["ours_cpu_s"]),
            f(&p["ceres_cpu_s"]),
            f(&p["ours_cpu_s"]) / f(&p["ceres_cpu_s"])
        );
        if p.get("ours_1t_cpu_s").is_some() {
            outln!(
                "  {:<22} {:>16.3} {:>16.3} {:>10.2}",
                "1-thread CPU s",
                f(&p["ours_1t_cpu_s"]),
                f(&p["ceres_1t_cpu_s"]),
                f(&p["ratio_1t_cpu"])
            );
        }
        outln!(
            "  {:<22} {:>16} {:>16}",
            "linear solver",
            p["ours_linear_solver"].as_str().unwrap_or("?"),
            p["ceres_linear_solver"].as_str().unwrap_or("?")
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic problem written as a binary model and read back gives
    /// the same problem (costs equal), with the gauge on the same poses.
    #[test]
    fn model_round_trip_keeps_the_problem() {
        let scene = synthetic_scene(&SyntheticOptions {
            num_poses: 5,
            num_points: 200,
            pixel_noise: 0.5,
            outlier_ratio: 0.05,
            seed: 3,
            ..Default::default()
        })
        .unwrap();
        let mut original = scene.problem;
        perturb(&mut original, 0.002, 0.01, 0.05, 4);
        let rec = problem_to_reconstruction(&original).unwrap();
        let dir = tempfile::tempdir().unwrap();
        write_model(&rec, dir.path(), ModelFormat::Binary).unwrap();
        let mut back = reconstruction_to_problem(&read_model(dir.path()).unwrap()).unwrap();
        assert_eq!(back.poses.len(), 5);
        assert!(back.poses[0].fixed && back.poses[1].fixed_translation.iter().any(|f| *f));
        assert!(back.cameras.iter().all(|c| c.refine == IntrinsicsRefinement::Fixed));
        for c in &mut original.cameras {
            c.refine = IntrinsicsRefinement::Fixed;
        }
        original.fix_gauge(0, 1);
        let options = BaOptions { loss: LossFunction::Cauchy(1.0), max_iterations: 3, ..Default::default() };
        let a = BundleAdjuster::solve(&mut original, &options).unwrap();
        let b = BundleAdjuster::solve(&mut back, &options).unwrap();
        assert_eq!(a.num_observations, b.num_observations);
        assert!(
            (a.initial_cost - b.initial_cost).abs() <= 1e-9 * a.initial_cost,
            "{} vs {}",
            a.initial_cost,
            b.initial_cost
        );
        assert!((a.final_cost - b.final_cost).abs() <= 1e-9 * a.final_cost, "{} vs {}", a.final_cost, b.final_cost);
        assert!(b.final_cost < b.initial_cost);
    }

    #[test]
    fn near_points_are_removed_from_a_model() {
        let scene = synthetic_scene(&SyntheticOptions { num_poses: 4, num_points: 100, seed: 5, ..Default::default() })
            .unwrap();
        let mut rec = problem_to_reconstruction(&scene.problem).unwrap();
        let n = rec.num_points3d();
        // Move one point onto the centre of an image that observes it.
        let id = rec.point3d_ids()[0];
        let observer = rec.point3d(id).unwrap().track[0].image_id;
        let centre = rec.image(observer).unwrap().projection_center();
        *rec.point3d_xyz_mut(id).unwrap() = centre;
        assert_eq!(remove_near_points(&mut rec).unwrap(), 1);
        assert_eq!(rec.num_points3d(), n - 1);
        assert!(rec.point3d(id).is_none());
    }
}
