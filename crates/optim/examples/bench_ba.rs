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

use colslam_optim::synthetic::{SyntheticOptions, perturb, synthetic_scene, write_colmap_text};
use colslam_optim::{BaOptions, BundleAdjuster, LinearSolverType, LossFunction};
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let export = args.iter().position(|a| a == "--export").and_then(|i| args.get(i + 1)).map(Path::new);
    let arg = |name: &str| {
        args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse::<usize>().ok())
    };
    let mut scenes =
        vec![("large_100x20000".to_string(), 100, 20_000, 0.6), ("small_7x3000".to_string(), 7, 3_000, 0.3)];
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
