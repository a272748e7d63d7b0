"""pycolmap peer of `colslam bench estimators` (issue 4).

Usage: python bench_estimators.py INPUT.json

INPUT (written by the Rust side, pixel coordinates of a PINHOLE camera):
  {"focal": f, "width": w, "height": h, "repeats": n,
   "ransac": {"confidence": c, "min_trials": a, "max_trials": b,
              "dyn_trials_multiplier": m, "min_inlier_ratio": r},
   "essential": {"max_error_px": e, "x1": [[u, v], ...], "x2": [...]},
   "absolute": {"max_error_px": e, "x": [[u, v], ...], "p3": [[X, Y, Z], ...]}}
Runs pycolmap.estimate_essential_matrix and
pycolmap.estimate_and_refine_absolute_pose `repeats` times each (seed = run
index, RANSAC num_threads = 1, pycolmap's default) and prints one JSON object
with the median times (ms), every run's pose as a 3x4 [R|t] matrix (null
when it failed) and the last run's inlier count.
"""

import json
import statistics
import sys
import time

import numpy as np
import pycolmap


def ransac_options(base, cfg, max_error, seed):
    base.max_error = float(max_error)
    base.confidence = float(cfg["confidence"])
    base.min_num_trials = int(cfg["min_trials"])
    base.max_num_trials = int(cfg["max_trials"])
    base.dyn_num_trials_multiplier = float(cfg["dyn_trials_multiplier"])
    base.min_inlier_ratio = float(cfg["min_inlier_ratio"])
    base.random_seed = int(seed)
    base.num_threads = 1
    return base


def mat(rigid):
    return None if rigid is None else np.asarray(rigid.matrix()).tolist()


def main():
    with open(sys.argv[1]) as f:
        data = json.load(f)
    focal = float(data["focal"])
    w, h = int(data["width"]), int(data["height"])
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", focal, w, h)
    cam.params = [focal, focal, w / 2, h / 2]
    reps = int(data["repeats"])
    rc = data["ransac"]

    e = data["essential"]
    x1 = np.asarray(e["x1"], dtype=np.float64).reshape(-1, 2)
    x2 = np.asarray(e["x2"], dtype=np.float64).reshape(-1, 2)
    times, res, poses = [], None, []
    for i in range(reps):
        opts = ransac_options(pycolmap.RANSACOptions(), rc, e["max_error_px"], i)
        t0 = time.perf_counter()
        res = pycolmap.estimate_essential_matrix(x1, x2, cam, cam, opts)
        times.append(time.perf_counter() - t0)
        poses.append(mat(res and res["cam2_from_cam1"]))
    out = {
        "pycolmap_version": pycolmap.__version__,
        "essential_ms": statistics.median(times) * 1e3,
        "essential_poses": poses,
        "essential_inliers": int(res["num_inliers"]) if res else 0,
    }

    a = data["absolute"]
    x = np.asarray(a["x"], dtype=np.float64).reshape(-1, 2)
    p3 = np.asarray(a["p3"], dtype=np.float64).reshape(-1, 3)
    times, res, poses = [], None, []
    for i in range(reps):
        est = pycolmap.AbsolutePoseEstimationOptions()
        ransac_options(est.ransac, rc, a["max_error_px"], i)
        ref = pycolmap.AbsolutePoseRefinementOptions()
        t0 = time.perf_counter()
        res = pycolmap.estimate_and_refine_absolute_pose(x, p3, cam, est, ref)
        times.append(time.perf_counter() - t0)
        poses.append(mat(res and res["cam_from_world"]))
    out["absolute_pose_ms"] = statistics.median(times) * 1e3
    out["absolute_poses"] = poses
    out["absolute_inliers"] = int(res["num_inliers"]) if res else 0
    print(json.dumps(out))


if __name__ == "__main__":
    main()
