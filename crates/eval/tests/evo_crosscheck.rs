//! Cross-check against evo 1.38.1: `evo_ape tum GT EST -as` and
//! `evo_rpe tum GT EST -as` (plus `-r angle_deg`, `-a`, `-s`, `--t_offset`)
//! are run through evo's own command-line entry points on estimates written
//! by this test, and every statistic, the scale, the match count and the
//! per-pose error arrays must agree to 1e-6.

use colslam_eval::{Alignment, EvalOptions, EvalReport, Trajectory, evaluate_files};
use colslam_geometry::{Quat, Rigid3, Sim3, SplitMix64, Vec3};
use std::path::{Path, PathBuf};

const TOL: f64 = 1e-6;

/// Runs evo's CLI entry points in one Python process for every case and
/// prints one JSON object per case after a marker.
const EVO_DRIVER: &str = r#"
import io, json, os, sys, tempfile, zipfile
import numpy as np
from evo.cli.entry_points import ape, rpe

def run(entry, name, args, out_zip):
    sys.argv = [name] + args + ["--save_results", out_zip, "--no_warnings", "--silent"]
    try:
        entry()
    except SystemExit as e:
        if e.code not in (None, 0):
            raise RuntimeError(f"{name} {args} exited with {e.code}")
    with zipfile.ZipFile(out_zip) as z:
        stats = json.loads(z.read("stats.json"))
        arrays = {}
        for f in z.namelist():
            if f.endswith(".npy"):
                arrays[f[:-4]] = np.load(io.BytesIO(z.read(f)))
    os.remove(out_zip)
    out = {"stats": stats, "errors": arrays["error_array"].tolist()}
    if "alignment_transformation_sim3" in arrays:
        m = arrays["alignment_transformation_sim3"]
        out["scale"] = float(np.linalg.norm(m[:3, 0]))
    else:
        out["scale"] = 1.0
    return out

tmp = tempfile.mkdtemp()
cases = json.loads(sys.argv[1])
for i, c in enumerate(cases):
    base = ["tum", c["gt"], c["est"]] + c["flags"]
    z = os.path.join(tmp, f"r{i}.zip")
    res = {
        "ape": run(ape, "evo_ape", base, z),
        "ape_rot": run(ape, "evo_ape", base + ["-r", "angle_deg"], z),
        "rpe": run(rpe, "evo_rpe", base + c["rpe_flags"], z),
        "rpe_rot": run(rpe, "evo_rpe", base + c["rpe_flags"] + ["-r", "angle_deg"], z),
    }
    print("EVO_RESULT " + json.dumps(res), flush=True)
"#;

struct Case {
    name: &'static str,
    gt: PathBuf,
    est: PathBuf,
    opts: EvalOptions,
}

fn noisy(pose: &Rigid3, rng: &mut SplitMix64, sigma_t: f64, sigma_r: f64) -> Rigid3 {
    let dr = Quat::from_scaled_axis(Vec3::new(rng.normal(), rng.normal(), rng.normal()) * sigma_r);
    let dt = Vec3::new(rng.normal(), rng.normal(), rng.normal()) * sigma_t;
    Rigid3::new(pose.rotation * dr, pose.translation + dt)
}

fn build_cases(gt_path: &Path, dir: &Path) -> Vec<Case> {
    let gt = Trajectory::read_tum(gt_path).expect("read ground truth");
    assert!(gt.len() > 1000, "unexpected ground truth length {}", gt.len());
    let mut rng = SplitMix64::new(20_261_122);
    let mut cases = Vec::new();
    let mut add = |name: &'static str, traj: Trajectory, opts: EvalOptions, gt: Option<PathBuf>| {
        let est = dir.join(format!("{name}.txt"));
        traj.write_tum(&est).expect("write estimate");
        cases.push(Case { name, gt: gt.unwrap_or_else(|| gt_path.to_path_buf()), est, opts });
    };
    let with = |align: Alignment| EvalOptions { align, ..EvalOptions::default() };

    // (a) every pose perturbed: 1 cm, 0.5 degree.
    let a = Trajectory::new(
        gt.stamps.clone(),
        gt.poses.iter().map(|p| noisy(p, &mut rng, 0.01, 0.5f64.to_radians())).collect(),
    );
    add("a_noise_sim3", a.clone(), with(Alignment::Sim3), None);
    add("a_noise_se3", a, with(Alignment::Se3), None);

    // (b) every 2nd pose, scaled by 0.3, rotated and translated, light noise.
    let s =
        Sim3 { scale: 0.3, rotation: Quat::from_euler_angles(0.7, -0.4, 2.2), translation: Vec3::new(4.0, -1.5, 0.8) };
    let idx: Vec<usize> = (0..gt.len()).step_by(2).collect();
    let sub = gt.select(&idx);
    let b = Trajectory::new(
        sub.stamps.clone(),
        sub.poses.iter().map(|p| s.transform_world_from_cam(&noisy(p, &mut rng, 0.003, 0.2f64.to_radians()))).collect(),
    );
    add("b_sim3", b.clone(), with(Alignment::Sim3), None);
    add("b_scale_only", b, with(Alignment::Scale), None);

    // (c) ~15 Hz (every 7th pose of the 100 Hz ground truth) with stamp
    // jitter up to 8 ms: below max_diff, but past half the 10 ms spacing,
    // so some poses associate with a neighbouring ground-truth stamp.
    let idx: Vec<usize> = (0..gt.len()).step_by(7).collect();
    let sub = gt.select(&idx);
    let c = Trajectory::new(
        sub.stamps.iter().map(|t| t + rng.uniform(-0.008, 0.008)).collect(),
        sub.poses.iter().map(|p| noisy(p, &mut rng, 0.005, 0.3f64.to_radians())).collect(),
    );
    add("c_15hz_jitter", c.clone(), with(Alignment::Sim3), None);
    // The same with RPE over all pairs 3 frames apart.
    add("c_delta3_all_pairs", c, EvalOptions { rpe_delta: 3, rpe_all_pairs: true, ..EvalOptions::default() }, None);

    // (d) every 3rd pose, with 25 % of them (and a whole 2 s block) missing.
    let t0 = gt.stamps[0];
    let idx: Vec<usize> = (0..gt.len())
        .step_by(3)
        .filter(|&i| rng.next_f64() > 0.25 && !(gt.stamps[i] - t0 > 8.0 && gt.stamps[i] - t0 < 10.0))
        .collect();
    let sub = gt.select(&idx);
    let d = Trajectory::new(
        sub.stamps.clone(),
        sub.poses.iter().map(|p| noisy(p, &mut rng, 0.008, 0.4f64.to_radians())).collect(),
    );
    add("d_missing", d.clone(), with(Alignment::Sim3), None);
    // The same aligned on the first 100 pairs only, RPE 5 frames apart.
    add("d_n_to_align_100", d, EvalOptions { n_to_align: Some(100), rpe_delta: 5, ..EvalOptions::default() }, None);

    // (e) the estimate is longer than the reference (so the reference drives
    // the search) and its clock is 2 s behind: evaluated with offset +2 s.
    let ref_idx: Vec<usize> = (0..gt.len()).step_by(10).collect();
    let short_gt = dir.join("gt_every10.txt");
    gt.select(&ref_idx).write_tum(&short_gt).expect("write short gt");
    let e = Trajectory::new(
        gt.stamps.iter().map(|t| t - 2.0).collect(),
        gt.poses.iter().map(|p| noisy(p, &mut rng, 0.006, 0.3f64.to_radians())).collect(),
    );
    add("e_offset_ref_drives", e, EvalOptions { offset: 2.0, ..EvalOptions::default() }, Some(short_gt));
    cases
}

/// evo flags shared by evo_ape and evo_rpe.
fn flags(o: &EvalOptions) -> Vec<String> {
    let mut f: Vec<String> = match o.align {
        Alignment::Sim3 => vec!["-as".into()],
        Alignment::Se3 => vec!["-a".into()],
        Alignment::Scale => vec!["-s".into()],
        Alignment::None => vec![],
    };
    if o.offset != 0.0 {
        f.push(format!("--t_offset={}", o.offset));
    }
    if let Some(n) = o.n_to_align {
        f.push(format!("--n_to_align={n}"));
    }
    f
}

/// evo_rpe-only flags.
fn rpe_flags(o: &EvalOptions) -> Vec<String> {
    let mut f = vec![format!("--delta={}", o.rpe_delta), "--delta_unit=f".to_string()];
    if o.rpe_all_pairs {
        f.push("--all_pairs".into());
    }
    f
}

fn close(what: &str, case: &str, ours: f64, theirs: f64, rel: bool) {
    let tol = if rel { TOL * theirs.abs().max(1.0) } else { TOL };
    assert!((ours - theirs).abs() <= tol, "{case}: {what} ours {ours} evo {theirs} (diff {})", (ours - theirs).abs());
}

fn num(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_f64().unwrap_or_else(|| panic!("evo output lacks {path:?}: {v}"))
}

fn check_stats(case: &str, what: &str, evo: &serde_json::Value, ours: [f64; 7]) {
    let names = ["rmse", "mean", "median", "std", "min", "max", "sse"];
    for (name, o) in names.iter().zip(ours) {
        close(&format!("{what}.{name}"), case, o, num(evo, &["stats", name]), *name == "sse");
    }
}

fn check_errors(case: &str, what: &str, evo: &serde_json::Value, ours: &[f64]) {
    let theirs: Vec<f64> =
        evo["errors"].as_array().expect("errors").iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect();
    assert_eq!(ours.len(), theirs.len(), "{case}: {what} count");
    for (i, (a, b)) in ours.iter().zip(&theirs).enumerate() {
        assert!((a - b).abs() <= TOL, "{case}: {what}[{i}] ours {a} evo {b}");
    }
}

fn compare(case: &Case, r: &EvalReport, evo: &serde_json::Value) {
    let n = case.name;
    let ape = &evo["ape"];
    check_stats(n, "ate", ape, [r.ate_rmse, r.ate_mean, r.ate_median, r.ate_std, r.ate_min, r.ate_max, r.ate_sse]);
    check_errors(n, "ate", ape, &r.detail.ate_errors);
    assert_eq!(r.matched, ape["errors"].as_array().map(Vec::len).unwrap_or(0), "{n}: matched");
    close("scale", n, r.scale, num(ape, &["scale"]), true);
    let ape_rot = &evo["ape_rot"];
    close("ate_rot.rmse", n, r.ate_rot_rmse_deg, num(ape_rot, &["stats", "rmse"]), false);
    close("ate_rot.mean", n, r.ate_rot_mean_deg, num(ape_rot, &["stats", "mean"]), false);
    close("ate_rot.median", n, r.ate_rot_median_deg, num(ape_rot, &["stats", "median"]), false);
    close("ate_rot.max", n, r.ate_rot_max_deg, num(ape_rot, &["stats", "max"]), false);
    let rpe = &evo["rpe"];
    check_stats(
        n,
        "rpe_trans",
        rpe,
        [
            r.rpe_trans_rmse,
            r.rpe_trans_mean,
            r.rpe_trans_median,
            r.rpe_trans_std,
            r.rpe_trans_min,
            r.rpe_trans_max,
            r.rpe_trans_sse,
        ],
    );
    check_errors(n, "rpe_trans", rpe, &r.detail.rpe_trans_errors);
    let rot = &evo["rpe_rot"];
    check_stats(
        n,
        "rpe_rot",
        rot,
        [
            r.rpe_rot_rmse_deg,
            r.rpe_rot_mean_deg,
            r.rpe_rot_median_deg,
            r.rpe_rot_std_deg,
            r.rpe_rot_min_deg,
            r.rpe_rot_max_deg,
            r.rpe_rot_sse_deg,
        ],
    );
    check_errors(n, "rpe_rot", rot, &r.detail.rpe_rot_errors_deg);
}

#[test]
fn matches_evo_ape_and_rpe() {
    let Some(data) = colslam_testutil::dataset("tum_fr1_rpy_sub") else { return };
    let Some(py) = colslam_testutil::peer_python(&["evo", "numpy"]) else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let cases = build_cases(&data.join("groundtruth.txt"), dir.path());

    let spec: Vec<serde_json::Value> = cases
        .iter()
        .map(|c| {
            serde_json::json!({
                "gt": c.gt.to_string_lossy(),
                "est": c.est.to_string_lossy(),
                "flags": flags(&c.opts),
                "rpe_flags": rpe_flags(&c.opts),
            })
        })
        .collect();
    let spec = serde_json::to_string(&spec).expect("json");
    // Keep evo's settings and matplotlib away from the user's home and display.
    let home = dir.path().join("home");
    std::fs::create_dir_all(&home).expect("home");
    let out = std::process::Command::new(&py)
        .args(["-c", EVO_DRIVER, &spec])
        .env("MPLBACKEND", "Agg")
        .env("HOME", &home)
        .output()
        .expect("spawn python");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "evo driver failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let results: Vec<serde_json::Value> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("EVO_RESULT "))
        .map(|l| serde_json::from_str(l).expect("evo json"))
        .collect();
    assert_eq!(results.len(), cases.len(), "evo output:\n{stdout}");

    for (case, evo) in cases.iter().zip(&results) {
        let r = evaluate_files(&case.gt, &case.est, &case.opts).unwrap_or_else(|e| panic!("{}: {e}", case.name));
        compare(case, &r, evo);
        eprintln!(
            "{}: matched {} ate_rmse {:.6} scale {:.6} rpe_trans_rmse {:.6} rpe_rot_rmse_deg {:.6}",
            case.name, r.matched, r.ate_rmse, r.scale, r.rpe_trans_rmse, r.rpe_rot_rmse_deg
        );
    }
}
