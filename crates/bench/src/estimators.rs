//! `colslam bench estimators`: our LO-RANSAC estimators against pycolmap 4.2
//! (COLMAP's) on identical synthetic data (issue 4).
//!
//! * Essential matrix / relative pose: 2000 correspondences, 50 % outliers,
//!   ours `estimate_relative_pose` vs `pycolmap.estimate_essential_matrix`.
//! * Absolute pose: 500 correspondences, 30 % outliers, ours
//!   `estimate_absolute_pose` vs `pycolmap.estimate_and_refine_absolute_pose`.
//!
//! The scenes come from `colslam_estimators::synthetic` with fixed seeds and
//! are handed to `scripts/peers/bench_estimators.py` in pixels of a PINHOLE
//! camera. Both sides use the same pixel thresholds and the same RANSAC
//! confidence and trial bounds; each call is repeated `--repeats` times with
//! seeds 0.. and the median time is reported (best of `--rounds` rounds
//! that alternate the two sides). Both run single-threaded (our
//! estimators have no threads; pycolmap's RANSAC `num_threads` is 1, its
//! default).

use crate::stdout::outln;
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use colslam_estimators::synthetic::{absolute_scene, relative_scene, rotation_error_deg, translation_dir_error_deg};
use colslam_estimators::{
    AbsolutePoseOptions, RansacOptions, RelativePoseOptions, estimate_absolute_pose, estimate_relative_pose,
};
use colslam_geometry::{Mat3, Rigid3, Vec2, Vec3};
use serde_json::{Value, json};

use crate::features::{machine, median, run_peer};

/// Focal length (px) of the synthetic camera.
const FOCAL: f64 = 500.0;
/// Image size handed to pycolmap (the principal point is its centre).
const WIDTH: u32 = 640;
/// Image size handed to pycolmap.
const HEIGHT: u32 = 480;
/// Gaussian noise on the observations, px.
const NOISE_PX: f64 = 0.5;
/// Essential problem size and outlier share.
const ESSENTIAL_N: usize = 2000;
const ESSENTIAL_OUTLIERS: f64 = 0.5;
/// Absolute-pose problem size and outlier share.
const ABSOLUTE_N: usize = 500;
const ABSOLUTE_OUTLIERS: f64 = 0.3;
/// Inlier thresholds, px (same on both sides).
const ESSENTIAL_MAX_ERROR_PX: f64 = 2.0;
const ABSOLUTE_MAX_ERROR_PX: f64 = 4.0;
/// RANSAC bounds shared by both sides (COLMAP's absolute-pose defaults).
const CONFIDENCE: f64 = 0.9999;
const MIN_TRIALS: usize = 100;
const MAX_TRIALS: usize = 10_000;
const DYN_TRIALS_MULTIPLIER: f64 = 3.0;
const MIN_INLIER_RATIO: f64 = 0.1;
/// Scene seeds.
const ESSENTIAL_SEED: u64 = 4242;
const ABSOLUTE_SEED: u64 = 4343;

/// Arguments of `bench estimators`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Calls per estimator (seeds 0..N); the median time is reported.
    #[arg(long, default_value_t = 20)]
    pub repeats: usize,
    /// Rounds alternating ours and pycolmap; each side keeps its best.
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
}

fn ransac(max_error_px: f64, seed: u64) -> RansacOptions {
    RansacOptions {
        max_error: max_error_px / FOCAL,
        confidence: CONFIDENCE,
        min_trials: MIN_TRIALS,
        max_trials: MAX_TRIALS,
        dyn_trials_multiplier: DYN_TRIALS_MULTIPLIER,
        min_inlier_ratio: MIN_INLIER_RATIO,
        seed,
        ..RansacOptions::default()
    }
}

fn px(p: &Vec2) -> [f64; 2] {
    [p.x * FOCAL + f64::from(WIDTH) / 2.0, p.y * FOCAL + f64::from(HEIGHT) / 2.0]
}

fn pose_of(v: &Value) -> Option<Rigid3> {
    let rows = v.as_array()?;
    let m = |r: usize, c: usize| rows.get(r)?.as_array()?.get(c)?.as_f64();
    let mut rot = Mat3::zeros();
    for r in 0..3 {
        for c in 0..3 {
            rot[(r, c)] = m(r, c)?;
        }
    }
    Some(Rigid3::from_rotation_matrix(&rot, Vec3::new(m(0, 3)?, m(1, 3)?, m(2, 3)?)))
}

fn num(v: &Value, key: &str) -> Result<f64> {
    v.get(key).and_then(Value::as_f64).ok_or_else(|| anyhow!("peer output lacks `{key}`"))
}

/// Runs `bench estimators`.
pub fn run(args: &Args, quiet: bool) -> Result<()> {
    if args.repeats == 0 || args.rounds == 0 {
        bail!("--repeats and --rounds must be at least 1");
    }
    let noise = NOISE_PX / FOCAL;
    let rel = relative_scene(ESSENTIAL_SEED, ESSENTIAL_N, noise, ESSENTIAL_OUTLIERS);
    let abs = absolute_scene(ABSOLUTE_SEED, ABSOLUTE_N, noise, ABSOLUTE_OUTLIERS);
    if !quiet && !args.json {
        eprintln!("bench estimators: {} repeats per estimator", args.repeats);
    }

    let input = json!({
        "focal": FOCAL, "width": WIDTH, "height": HEIGHT, "repeats": args.repeats,
        "ransac": {
            "confidence": CONFIDENCE, "min_trials": MIN_TRIALS, "max_trials": MAX_TRIALS,
            "dyn_trials_multiplier": DYN_TRIALS_MULTIPLIER, "min_inlier_ratio": MIN_INLIER_RATIO,
        },
        "essential": {
            "max_error_px": ESSENTIAL_MAX_ERROR_PX,
            "x1": rel.x1.iter().map(px).collect::<Vec<_>>(),
            "x2": rel.x2.iter().map(px).collect::<Vec<_>>(),
        },
        "absolute": {
            "max_error_px": ABSOLUTE_MAX_ERROR_PX,
            "x": abs.points2d.iter().map(px).collect::<Vec<_>>(),
            "p3": abs.points3d.iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>(),
        },
    });
    // Rounds alternate ours and pycolmap (same data, same seeds); each side
    // keeps its best round's median, so that bursts of load from other
    // processes do not land on one side only.
    let mut best = [f64::INFINITY; 4];
    let (mut ess_last, mut abs_last, mut peer) = (None, None, Value::Null);
    // Accuracy per seed (the data and seeds are the same every round).
    let (mut ess_err, mut abs_err) = (Vec::new(), Vec::new());
    for _ in 0..args.rounds {
        let mut ess_times = Vec::new();
        ess_err.clear();
        abs_err.clear();
        for seed in 0..args.repeats as u64 {
            let opts =
                RelativePoseOptions { ransac: ransac(ESSENTIAL_MAX_ERROR_PX, seed), ..RelativePoseOptions::default() };
            let t0 = Instant::now();
            let r = estimate_relative_pose(&rel.x1, &rel.x2, &opts).context("our relative pose failed")?;
            ess_times.push(t0.elapsed().as_secs_f64() * 1e3);
            let p = &r.cam2_from_cam1;
            ess_err.push((
                rotation_error_deg(p, &rel.cam2_from_cam1),
                translation_dir_error_deg(&p.translation, &rel.cam2_from_cam1.translation),
            ));
            ess_last = Some(r);
        }
        let mut abs_times = Vec::new();
        for seed in 0..args.repeats as u64 {
            let opts =
                AbsolutePoseOptions { ransac: ransac(ABSOLUTE_MAX_ERROR_PX, seed), ..AbsolutePoseOptions::default() };
            let t0 = Instant::now();
            let r = estimate_absolute_pose(&abs.points2d, &abs.points3d, &opts).context("our absolute pose failed")?;
            abs_times.push(t0.elapsed().as_secs_f64() * 1e3);
            let p = &r.cam_from_world;
            abs_err
                .push((rotation_error_deg(p, &abs.cam_from_world), (p.center() - abs.cam_from_world.center()).norm()));
            abs_last = Some(r);
        }
        peer = run_peer("bench_estimators.py", &input)?;
        let now =
            [median(&ess_times), num(&peer, "essential_ms")?, median(&abs_times), num(&peer, "absolute_pose_ms")?];
        for (b, n) in best.iter_mut().zip(now) {
            *b = b.min(n);
        }
    }
    let [essential_ms, pycolmap_essential_ms, absolute_pose_ms, pycolmap_absolute_pose_ms] = best;
    let ess = ess_last.ok_or_else(|| anyhow!("no relative pose run"))?;
    let ab = abs_last.ok_or_else(|| anyhow!("no absolute pose run"))?;
    let poses = |key: &str| -> Result<Vec<Rigid3>> {
        peer[key]
            .as_array()
            .ok_or_else(|| anyhow!("peer output lacks `{key}`"))?
            .iter()
            .map(|v| pose_of(v).ok_or_else(|| anyhow!("pycolmap failed on a run ({key})")))
            .collect()
    };
    let their_rel = poses("essential_poses")?;
    let their_abs = poses("absolute_poses")?;
    let gt_rel = rel.cam2_from_cam1;
    let gt_abs = abs.cam_from_world;
    let med = |v: Vec<f64>| median(&v);
    let ours_rel_rot = med(ess_err.iter().map(|e| e.0).collect());
    let ours_rel_dir = med(ess_err.iter().map(|e| e.1).collect());
    let ours_abs_rot = med(abs_err.iter().map(|e| e.0).collect());
    let ours_abs_pos = med(abs_err.iter().map(|e| e.1).collect());
    let their_rel_rot = med(their_rel.iter().map(|p| rotation_error_deg(p, &gt_rel)).collect());
    let their_rel_dir =
        med(their_rel.iter().map(|p| translation_dir_error_deg(&p.translation, &gt_rel.translation)).collect());
    let their_abs_rot = med(their_abs.iter().map(|p| rotation_error_deg(p, &gt_abs)).collect());
    let their_abs_pos = med(their_abs.iter().map(|p| (p.center() - gt_abs.center()).norm()).collect());

    let true_inliers = |m: &[bool], truth: &[bool]| m.iter().zip(truth).filter(|(a, b)| **a && **b).count();
    let result = json!({
        "essential_ms": essential_ms,
        "pycolmap_essential_ms": pycolmap_essential_ms,
        "absolute_pose_ms": absolute_pose_ms,
        "pycolmap_absolute_pose_ms": pycolmap_absolute_pose_ms,
        "essential": {
            "n": ESSENTIAL_N, "outlier_ratio": ESSENTIAL_OUTLIERS, "max_error_px": ESSENTIAL_MAX_ERROR_PX,
            "rotation_error_deg": ours_rel_rot,
            "pycolmap_rotation_error_deg": their_rel_rot,
            "translation_dir_error_deg": ours_rel_dir,
            "pycolmap_translation_dir_error_deg": their_rel_dir,
            "inliers": ess.num_inliers,
            "true_inliers_found": true_inliers(&ess.inlier_mask, &rel.is_inlier),
            "pycolmap_inliers": peer["essential_inliers"],
            "trials": ess.num_trials,
        },
        "absolute_pose": {
            "n": ABSOLUTE_N, "outlier_ratio": ABSOLUTE_OUTLIERS, "max_error_px": ABSOLUTE_MAX_ERROR_PX,
            "rotation_error_deg": ours_abs_rot,
            "pycolmap_rotation_error_deg": their_abs_rot,
            "position_error": ours_abs_pos,
            "pycolmap_position_error": their_abs_pos,
            "inliers": ab.num_inliers,
            "true_inliers_found": true_inliers(&ab.inlier_mask, &abs.is_inlier),
            "pycolmap_inliers": peer["absolute_inliers"],
            "trials": ab.num_trials,
        },
        "accuracy": "median over the seeds 0..repeats; inliers and trials from the last seed",
        "noise_px": NOISE_PX,
        "focal_px": FOCAL,
        "confidence": CONFIDENCE,
        "min_trials": MIN_TRIALS,
        "max_trials": MAX_TRIALS,
        "repeats": args.repeats,
        "rounds": args.rounds,
        "threads": 1,
        "pycolmap_num_threads": 1,
        "pycolmap_version": peer["pycolmap_version"],
        "machine": machine(),
    });
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&result)?);
        return Ok(());
    }
    let m = &result["machine"];
    outln!(
        "bench estimators: {} repeats, {} cores, {}, load {}",
        args.repeats,
        m["nproc"],
        m["cpu_model"].as_str().unwrap_or("?"),
        m["loadavg"].as_str().unwrap_or("?")
    );
    outln!("{:<44} {:>10} {:>10} {:>10}", "measure", "colslam", "pycolmap", "ours/peer");
    let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    let (e, a) = (&result["essential"], &result["absolute_pose"]);
    let rows = [
        ("essential 2000 corr. 50% outl., ms/call", f(&result["essential_ms"]), f(&result["pycolmap_essential_ms"])),
        ("  rotation error, deg", f(&e["rotation_error_deg"]), f(&e["pycolmap_rotation_error_deg"])),
        (
            "  translation direction error, deg",
            f(&e["translation_dir_error_deg"]),
            f(&e["pycolmap_translation_dir_error_deg"]),
        ),
        ("  inliers", f(&e["inliers"]), f(&e["pycolmap_inliers"])),
        (
            "absolute pose 500 corr. 30% outl., ms/call",
            f(&result["absolute_pose_ms"]),
            f(&result["pycolmap_absolute_pose_ms"]),
        ),
        ("  rotation error, deg", f(&a["rotation_error_deg"]), f(&a["pycolmap_rotation_error_deg"])),
        ("  position error (scene units)", f(&a["position_error"]), f(&a["pycolmap_position_error"])),
        ("  inliers", f(&a["inliers"]), f(&a["pycolmap_inliers"])),
    ];
    for (name, x, y) in rows {
        let ratio = if y > 0.0 { format!("{:.2}", x / y) } else { "-".into() };
        outln!("{name:<44} {x:>10.4} {y:>10.4} {ratio:>10}");
    }
    Ok(())
}
