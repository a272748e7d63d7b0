#!/usr/bin/env python3
"""Peer run for `colslam bench --peers`: pycolmap 4.2 on a TUM-layout sequence.

SIFT extraction with the sequence's own intrinsics (one shared, fixed camera;
keypoints of a distorted camera are undistorted to its pinhole image before
matching, see `undistort_keypoints_in_database`), sequential matching, then COLMAP's incremental mapper or the global mapper
(GLOMAP, `pycolmap.global_mapping`). Writes the largest model under
OUT/model/ and its camera trajectory (world_from_cam, image name -> timestamp
through rgb.txt) as OUT/trajectory.tum, plus OUT/peer.json with counts.

    run_pycolmap.py SEQ_DIR OUT_DIR --mapper incremental|global [--threads N] [--uncalibrated]

With --uncalibrated, camera.yaml is not read: COLMAP's own self-calibration
(one SIMPLE_RADIAL camera from its prior focal length, 1.2 x the larger image
side, focal length and k refined by every bundle adjustment, the principal
point held at the centre), the peer of `colslam run` without a camera file.

SEQ_DIR holds rgb.txt ("timestamp rgb/NAME"), the images and camera.yaml
(flat "key: value" lines: model, width, height, fx, fy, cx, cy and optional
k1 k2 p1 p2 k3).
"""

import argparse
import json
import os
import shutil
import sqlite3
import sys
import time

import numpy as np
import pycolmap


def read_camera_yaml(path):
    cam = {}
    with open(path) as f:
        for line in f:
            line = line.split("#", 1)[0].strip()
            if ":" not in line:
                continue
            k, v = (s.strip() for s in line.split(":", 1))
            cam[k] = v
    w, h = int(cam["width"]), int(cam["height"])
    fx, fy, cx, cy = (float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
    dist = [float(cam.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")]
    if dist[4] != 0.0:
        # FULL_OPENCV: fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6
        return w, h, "FULL_OPENCV", [fx, fy, cx, cy] + dist + [0.0, 0.0, 0.0]
    if any(dist[:4]):
        return w, h, "OPENCV", [fx, fy, cx, cy] + dist[:4]
    return w, h, "PINHOLE", [fx, fy, cx, cy]


def undistort_keypoints_in_database(db_path, model, params):
    """Rewrites every keypoint in the database to the ideal pinhole image of
    the same camera and turns the camera into a PINHOLE one.

    pycolmap 4.2.1's incremental mapper triangulates its initial pair with a
    default-constructed triangulator whose bogus-camera bound on the extra
    parameters is 1.0, so a camera with k3 = 1.1633 (TUM fr1) can never
    initialise, whatever the options say. Features stay those SIFT found on
    the original images; only their coordinates move, as COLMAP's
    undistortion would move them. Returns the number of keypoints rewritten.
    """
    camera = pycolmap.Camera(model=model, width=1, height=1, params=params)
    fx, fy, cx, cy = params[:4]
    con = sqlite3.connect(db_path)
    try:
        rows = con.execute("SELECT image_id, rows, cols, data FROM keypoints").fetchall()
        total = 0
        for image_id, n, cols, blob in rows:
            if n == 0:
                continue
            kp = np.frombuffer(blob, dtype=np.float32).reshape(n, cols).copy()
            # COLMAP's keypoints put the centre of the top-left pixel at
            # (0.5, 0.5); cam_from_img and the pinhole below share it.
            xy = camera.cam_from_img(kp[:, :2].astype(np.float64))
            kp[:, 0] = (fx * xy[:, 0] + cx).astype(np.float32)
            kp[:, 1] = (fy * xy[:, 1] + cy).astype(np.float32)
            con.execute("UPDATE keypoints SET data = ? WHERE image_id = ?", (kp.tobytes(), image_id))
            total += n
        pinhole = np.array([fx, fy, cx, cy], dtype=np.float64)
        con.execute(
            "UPDATE cameras SET model = ?, params = ?",
            (int(pycolmap.CameraModelId.PINHOLE), pinhole.tobytes()),
        )
        con.commit()
    finally:
        con.close()
    return total


def read_rgb_list(path):
    """(timestamp, relative path) per line of rgb.txt."""
    out = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split()
            if len(parts) >= 2:
                out.append((float(parts[0]), parts[1]))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("seq")
    ap.add_argument("out")
    ap.add_argument("--mapper", choices=["incremental", "global"], default="incremental")
    ap.add_argument("--threads", type=int, default=-1)
    ap.add_argument("--skip", type=int, default=1)
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--uncalibrated", action="store_true", help="ignore camera.yaml: COLMAP's self-calibration")
    a = ap.parse_args()

    entries = read_rgb_list(os.path.join(a.seq, "rgb.txt"))[:: max(1, a.skip)]
    if a.max_frames > 0:
        entries = entries[: a.max_frames]
    if not entries:
        sys.exit(f"{a.seq}/rgb.txt lists no images")
    if a.uncalibrated:
        model, params = "SIMPLE_RADIAL", None
    else:
        _, _, model, params = read_camera_yaml(os.path.join(a.seq, "camera.yaml"))
    # A known camera's intrinsics stay fixed, as colslam keeps them.
    fixed = params is not None

    os.makedirs(a.out, exist_ok=True)
    db = os.path.join(a.out, "database.db")
    if os.path.exists(db):
        os.remove(db)
    names = [p for _, p in entries]
    stamp_of = {p: t for t, p in entries}

    t0 = time.time()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = model
    if fixed:
        reader.camera_params = ",".join(repr(p) for p in params)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = a.threads
    pycolmap.extract_features(
        db, a.seq, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    if fixed and model != "PINHOLE":
        undistort_keypoints_in_database(db, model, params)
    t1 = time.time()
    pycolmap.match_sequential(db, device=pycolmap.Device.cpu)
    t2 = time.time()
    sparse = os.path.join(a.out, "sparse")
    shutil.rmtree(sparse, ignore_errors=True)
    os.makedirs(sparse)
    if a.mapper == "incremental":
        opts = pycolmap.IncrementalPipelineOptions()
        opts.num_threads = a.threads
        opts.ba_refine_focal_length = not fixed
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = not fixed
        recs = pycolmap.incremental_mapping(db, a.seq, sparse, opts)
    else:
        opts = pycolmap.GlobalPipelineOptions()
        opts.num_threads = a.threads
        ba = opts.mapper.bundle_adjustment
        ba.refine_focal_length = not fixed
        ba.refine_principal_point = False
        ba.refine_extra_params = not fixed
        recs = pycolmap.global_mapping(db, a.seq, sparse, opts)
    t3 = time.time()
    if not recs:
        sys.exit("pycolmap produced no model")
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    model_dir = os.path.join(a.out, "model")
    os.makedirs(model_dir, exist_ok=True)
    rec.write(model_dir)

    rows = []
    for img in rec.images.values():
        if not img.has_pose:
            continue
        t = stamp_of.get(img.name)
        if t is None:
            continue
        world_from_cam = img.cam_from_world().inverse()
        tx, ty, tz = (float(v) for v in world_from_cam.translation)
        qx, qy, qz, qw = (float(v) for v in world_from_cam.rotation.quat)
        rows.append((t, tx, ty, tz, qx, qy, qz, qw))
    rows.sort()
    tmp = os.path.join(a.out, "trajectory.tum.tmp")
    with open(tmp, "w") as f:
        for r in rows:
            f.write("%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n" % r)
    os.replace(tmp, os.path.join(a.out, "trajectory.tum"))

    points = rec.num_points3D()
    regs = rec.num_reg_images()
    obs = sum(len(p.track.elements) for p in rec.points3D.values())
    camera = rec.cameras[next(iter(rec.images.values())).camera_id]
    report = {
        "system": f"pycolmap {pycolmap.__version__} {a.mapper}",
        "frames": len(entries),
        "localized": len(rows),
        "keyframes": regs,
        "points": points,
        "mean_track_length": obs / points if points else 0.0,
        "mean_reprojection_error": rec.compute_mean_reprojection_error(),
        "points_per_image": obs / regs if regs else 0.0,
        "models": len(recs),
        "timings_s": {"extraction": t1 - t0, "matching": t2 - t1, "mapping": t3 - t2},
        "camera": {"model": camera.model.name, "params": [float(p) for p in camera.params]},
    }
    with open(os.path.join(a.out, "peer.json.tmp"), "w") as f:
        json.dump(report, f, indent=2)
    os.replace(os.path.join(a.out, "peer.json.tmp"), os.path.join(a.out, "peer.json"))


if __name__ == "__main__":
    main()
