"""Peer for tests/pycolmap_crosscheck.rs: runs pycolmap 4.2 estimators on
correspondences given in normalised coordinates and prints the results as
JSON. Usage: python pycolmap_peer.py INPUT.json

Input: {"focal": f, "cases": [{"kind": "relative"|"absolute"|"twoview",
"x1": [[x, y], ...], "x2": [...], "p3": [[X, Y, Z], ...], "seed": s}, ...]}
Output: one JSON list with, per case, the pose as a 3x4 [R|t] matrix (or
null) and the configuration name for two-view cases.
"""

import json
import sys

import numpy as np
import pycolmap

WIDTH, HEIGHT = 640, 480


def main():
    with open(sys.argv[1]) as f:
        data = json.load(f)
    focal = float(data["focal"])
    cx, cy = WIDTH / 2, HEIGHT / 2
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", focal, WIDTH, HEIGHT)
    cam.params = [focal, focal, cx, cy]

    def px(pts):
        a = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        return a * focal + np.array([cx, cy])

    def mat(rigid):
        return None if rigid is None else np.asarray(rigid.matrix()).tolist()

    out = []
    for case in data["cases"]:
        kind = case["kind"]
        if kind == "relative":
            opts = pycolmap.RANSACOptions()
            opts.max_error = 2.0
            opts.random_seed = case["seed"]
            r = pycolmap.estimate_essential_matrix(px(case["x1"]), px(case["x2"]), cam, cam, opts)
            out.append({"pose": mat(r["cam2_from_cam1"]) if r else None,
                        "num_inliers": int(r["num_inliers"]) if r else 0})
        elif kind == "absolute":
            est = pycolmap.AbsolutePoseEstimationOptions()
            est.ransac.max_error = 5.0
            est.ransac.random_seed = case["seed"]
            r = pycolmap.estimate_and_refine_absolute_pose(
                px(case["x1"]), np.asarray(case["p3"], dtype=np.float64), cam, est)
            out.append({"pose": mat(r["cam_from_world"]) if r else None,
                        "num_inliers": int(r["num_inliers"]) if r else 0})
        elif kind == "twoview":
            o = pycolmap.TwoViewGeometryOptions()
            o.compute_relative_pose = True
            o.ransac.random_seed = case["seed"]
            n = len(case["x1"])
            matches = np.stack([np.arange(n), np.arange(n)], 1).astype(np.uint32)
            g = pycolmap.estimate_calibrated_two_view_geometry(
                cam, px(case["x1"]), cam, px(case["x2"]), matches, o)
            config = pycolmap.TwoViewGeometryConfiguration(g.config).name
            out.append({"config": config, "pose": mat(g.cam2_from_cam1),
                        "num_inliers": int(g.inlier_matches.shape[0])})
        else:
            raise ValueError(f"unknown case kind {kind}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
