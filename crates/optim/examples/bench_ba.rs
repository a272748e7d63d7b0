//! Bundle-adjustment timing on seeded synthetic scenes.
//!
//! `cargo run --release -p colslam-optim --example bench_ba [-- --export DIR]
//! [--poses N --points M] [--solver dense|sparse|iterative]`
//!
//! Scenes: 100 poses / 20,000 points / ~250,000 observations with 2 %
//! outliers and 7 poses / 3,000 points, Cauchy(1) loss, focal length and k
//! refined, gauge fixed on poses 0 and 1. With `--export DIR`, each perturbed
//! starting problem is also written as a COLMAP text model
//! (`DIR/<name>/{cameras,images,points3D}.txt`) for
//! `scripts/bench-ba-ceres.py`, which runs pycolmap's Ceres bundle adjustment
//! on the same data.

use colslam_optim::synthetic::{perturb, synthetic_scene, SyntheticOptions};
use colslam_optim::{BaOptions, BundleAdjuster, LinearSolverType, LossFunction, Problem};
use std::fmt::Write as _;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let export = args.iter().position(|a| a == "--export").and_then(|i| args.get(i + 1)).map(Path::new);
    let arg = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse::<usize>().ok());
    let mut scenes = vec![("large_100x20000".to_string(), 100, 20_000, 0.6), ("small_7x3000".to_string(), 7, 3_000, 0.3)];
    if let (Some(poses), Some(points)) = (arg("--poses"), arg("--points")) {
        // A custom scene instead (about 12 observations per point).
        scenes = vec![(format!("custom_{poses}x{points}"), poses, points, 0.6)];
    }
    let solver = match args.iter().position(|a| a == "--solver").and_then(|i| args.get(i + 1)).map(String::as_str) {
        Some("dense") => LinearSolverType::DenseSchur,
        Some("sparse") => LinearSolverType::SparseSchur,
        Some("iterative") => LinearSolverType::IterativeSchur,
        _ => LinearSolverType::Auto,
    };
    for (name, poses, points, step) in scenes {
        let name = name.as_str();
        let scene = synthetic_scene(&SyntheticOptions {
            num_poses: poses,
            num_points: points,
            step,
            pixel_noise: 0.5,
            outlier_ratio: 0.02,
            seed: 1,
            ..Default::default()
        })?;
        let mut problem = scene.problem;
        problem.fix_gauge(0, 1);
        perturb(&mut problem, 0.002, 0.01, 0.05, 2);
        if let Some(dir) = export {
            write_colmap_text(&problem, &dir.join(name))?;
        }
        let options = BaOptions { loss: LossFunction::Cauchy(1.0), linear_solver: solver, ..Default::default() };
        let cpu0 = process_cpu_seconds();
        let report = BundleAdjuster::solve(&mut problem, &options)?;
        let cpu = process_cpu_seconds() - cpu0;
        println!(
            "{name}: {} poses, {} points, {} observations | cost {:.2} -> {:.2} in {} iterations ({} accepted), \
             {:.3} s wall, {:.2} s CPU (linear {:.3} s), {:?}, {:?}, threads {}",
            poses,
            report.num_variable_points,
            report.num_observations,
            report.initial_cost,
            report.final_cost,
            report.iterations,
            report.successful_steps,
            report.time.as_secs_f64(),
            cpu,
            report.linear_solver_time.as_secs_f64(),
            report.termination,
            report.linear_solver,
            rayon::current_num_threads(),
        );
        println!("  {:?}", report.timings);
    }
    Ok(())
}

/// User + system CPU time of this process (Linux `/proc/self/stat`, clock
/// ticks of 1/100 s); NaN elsewhere. Wall time alone misleads on a shared
/// machine.
fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    // Fields after the parenthesised command name; utime and stime are the
    // 14th and 15th fields overall (12th and 13th after the name).
    let Some(rest) = stat.rfind(')').map(|i| &stat[i + 1..]) else { return f64::NAN };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(11) + ticks(12)) / 100.0
}

/// Writes the problem as a COLMAP text model (one camera, image ids and
/// point ids 1-based, image names `<index>.png`).
fn write_colmap_text(problem: &Problem, dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut cams = String::from("# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    for (i, c) in problem.cameras.iter().enumerate() {
        let params: Vec<String> = c.camera.params.iter().map(|v| format!("{v:.17}")).collect();
        let _ = writeln!(cams, "{} {} {} {} {}", i + 1, c.camera.model.name(), c.camera.width, c.camera.height, params.join(" "));
    }
    // Per image: its observations, in order (POINT2D_IDX = position).
    let mut per_image: Vec<Vec<usize>> = vec![Vec::new(); problem.poses.len()];
    let mut track: Vec<Vec<(usize, usize)>> = vec![Vec::new(); problem.points.len()];
    for (k, o) in problem.observations.iter().enumerate() {
        track[o.point].push((o.pose + 1, per_image[o.pose].len()));
        per_image[o.pose].push(k);
    }
    let mut images = String::from("# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n");
    for (i, p) in problem.poses.iter().enumerate() {
        let q = p.cam_from_world.quat_wxyz();
        let t = p.cam_from_world.translation;
        let cam = per_image[i].first().map(|&k| problem.observations[k].camera).unwrap_or(0);
        let _ = writeln!(
            images,
            "{} {:.17} {:.17} {:.17} {:.17} {:.17} {:.17} {:.17} {} {}.png",
            i + 1, q[0], q[1], q[2], q[3], t.x, t.y, t.z, cam + 1, i
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
        let _ = writeln!(pts, "{} {:.17} {:.17} {:.17} 128 128 128 0 {}", j + 1, p.xyz.x, p.xyz.y, p.xyz.z, tr.join(" "));
    }
    for (name, text) in [("cameras.txt", cams), ("images.txt", images), ("points3D.txt", pts)] {
        let tmp = dir.join(format!(".{name}.tmp"));
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, dir.join(name))?;
    }
    Ok(())
}
