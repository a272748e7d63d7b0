"""Independent checks of `colslam export -f 3dgs|nerfstudio` (issue 18), run by
crates/cli/tests/export_scene.rs through the peer venv (COLSLAM_PYTHON).

    check_export.py 3dgs OUT RUN
    check_export.py nerfstudio OUT RUN

Prints one JSON object with what was measured; the Rust test asserts on it.
Everything here is computed from the written files with pycolmap, numpy and
OpenCV, never with colslam's code:

* 3dgs: pycolmap reads OUT/sparse/0; the camera model, the image names
  against OUT/images (the same set: gsplat pairs them sorted), each image's
  size; the reprojection of the points in the exported PINHOLE camera onto
  the (undistorted) keypoints; and, for a distorted run camera, each exported
  image against OpenCV's own undistortion of the source image (the run's
  camera as the distorted one, the exported PINHOLE K as the new one), in
  grey levels over the pixels OpenCV fills.
* nerfstudio: transforms.json's keys; the points of sparse_pc.ply against the
  run's points rotated by applied_transform; each keyframe's points
  projected with its transform_matrix (OpenGL camera: y up, looking down -z)
  and the intrinsics and OPENCV distortion terms as nerfstudio applies them
  (nerfstudio/cameras/camera_utils.py: 1 + k1 r2 + k2 r4 + k3 r6 + k4 r8 with
  p1, p2), against the keypoints the run observed and against pycolmap's own
  projection with the run's camera.
"""

import json
import os
import sys

import cv2
import numpy as np
import pycolmap


def run_points(run):
    rec = pycolmap.Reconstruction(run)
    ids = sorted(rec.points3D.keys())
    xyz = np.array([rec.points3D[i].xyz for i in ids]).reshape(-1, 3)
    return rec, ids, xyz


def stats(errors):
    e = np.asarray(errors, dtype=float)
    if e.size == 0:
        return {"n": 0, "mean": None, "median": None, "max": None}
    return {"n": int(e.size), "mean": float(e.mean()), "median": float(np.median(e)), "max": float(e.max())}


def read_ply(path):
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    n = int([l for l in header.splitlines() if l.startswith("element vertex")][0].split()[-1])
    assert "binary_little_endian" in header, header
    rows = np.frombuffer(data[end:], dtype=np.dtype([("xyz", "<f4", 3), ("rgb", "u1", 3)]), count=n)
    return rows["xyz"].astype(float), rows["rgb"]


def opencv_camera(cam):
    """K (OpenCV pixel convention: pixel centres at integers) and distortion
    coefficients of a pycolmap camera."""
    p = np.asarray(cam.params, dtype=float)
    name = cam.model.name
    if name == "SIMPLE_PINHOLE":
        f, cx, cy, d = p[0], p[1], p[2], []
        fx = fy = f
    elif name == "PINHOLE":
        fx, fy, cx, cy, d = p[0], p[1], p[2], p[3], []
    elif name == "SIMPLE_RADIAL":
        fx = fy = p[0]
        cx, cy, d = p[1], p[2], [p[3], 0, 0, 0]
    elif name == "RADIAL":
        fx = fy = p[0]
        cx, cy, d = p[1], p[2], [p[3], p[4], 0, 0]
    elif name == "OPENCV":
        fx, fy, cx, cy, d = p[0], p[1], p[2], p[3], list(p[4:8])
    elif name == "FULL_OPENCV":
        fx, fy, cx, cy, d = p[0], p[1], p[2], p[3], list(p[4:12])
    else:
        raise SystemExit(f"no OpenCV check for {name}")
    # COLMAP puts the centre of the top-left pixel at (0.5, 0.5), OpenCV at (0, 0).
    K = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]], dtype=float)
    return K, np.array(d, dtype=float)


def source_images(run):
    """Exported name -> source file, for an image-sequence input."""
    with open(os.path.join(run, "report.json")) as f:
        inp = json.load(f)["input"]
    rgb = os.path.join(inp, "rgb.txt")
    files = {}
    if os.path.isfile(rgb):
        for line in open(rgb):
            if line.startswith("#") or not line.strip():
                continue
            path = os.path.join(inp, line.split()[1])
            files[os.path.basename(path)] = path
    return files


def check_3dgs(out, run):
    rec = pycolmap.Reconstruction(os.path.join(out, "sparse", "0"))
    cams = list(rec.cameras.values())
    res = {"cameras": len(cams), "camera_model": cams[0].model.name, "images": rec.num_images(),
           "points": rec.num_points3D()}
    cam = cams[0]
    res["width"], res["height"] = cam.width, cam.height
    names = sorted(img.name for img in rec.images.values())
    files = sorted(os.listdir(os.path.join(out, "images")))
    res["names_equal_files"] = names == files
    bad_size = []
    for n in names:
        im = cv2.imread(os.path.join(out, "images", n), cv2.IMREAD_UNCHANGED)
        if im is None or im.shape[1] != cam.width or im.shape[0] != cam.height:
            bad_size.append(n)
    res["bad_size"] = bad_size[:5]
    errors = []
    keyframes = 0
    for img in rec.images.values():
        obs = [p for p in img.points2D if p.has_point3D()]
        keyframes += bool(obs)
        for p in obs:
            xy = cam.img_from_cam(img.cam_from_world() * rec.points3D[p.point3D_id].xyz)
            errors.append(float(np.linalg.norm(xy - p.xy)))
    res["images_with_observations"] = keyframes
    res["reprojection"] = stats(errors)
    # Undistortion against OpenCV.
    run_rec = pycolmap.Reconstruction(run)
    run_cam = list(run_rec.cameras.values())[0]
    res["run_camera_model"] = run_cam.model.name
    if run_cam.model.name not in ("SIMPLE_PINHOLE", "PINHOLE"):
        K_dist, dist = opencv_camera(run_cam)
        K_new, _ = opencv_camera(cam)
        size = (cam.width, cam.height)
        mx, my = cv2.initUndistortRectifyMap(K_dist, dist, None, K_new, size, cv2.CV_32FC1)
        w, h = run_cam.width, run_cam.height
        # Pixels whose bilinear footprint lies inside the source image.
        valid = (mx >= 0) & (my >= 0) & (mx <= w - 1) & (my <= h - 1)
        sources = source_images(run)
        diffs = []
        for n in names[:: max(1, len(names) // 20)]:
            src = cv2.imread(sources[n], cv2.IMREAD_UNCHANGED)
            ref = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            got = cv2.imread(os.path.join(out, "images", n), cv2.IMREAD_UNCHANGED)
            if got is None or got.shape != ref.shape:
                continue  # reported in bad_size
            d = np.abs(ref.astype(float) - got.astype(float))
            diffs.append(float(d[valid].mean()))
        res["opencv_undistort_mean_abs"] = stats(diffs)
        res["opencv_valid_fraction"] = float(valid.mean())
    return res


def ns_project(meta, c2w, xyz):
    """Pixels of world points `xyz` (nerfstudio's world) in a frame, as
    nerfstudio's camera model sees them."""
    w2c = np.linalg.inv(np.asarray(c2w, dtype=float))
    pc = (w2c[:3, :3] @ xyz.T).T + w2c[:3, 3]
    # OpenGL camera: visible points have z < 0; the image y axis points down.
    x, y = pc[:, 0] / -pc[:, 2], -pc[:, 1] / -pc[:, 2]
    k = [meta.get(n, 0.0) for n in ("k1", "k2", "k3", "k4")]
    p1, p2 = meta.get("p1", 0.0), meta.get("p2", 0.0)
    r = x * x + y * y
    d = 1 + r * (k[0] + r * (k[1] + r * (k[2] + r * k[3])))
    xd = d * x + 2 * p1 * x * y + p2 * (r + 2 * x * x)
    yd = d * y + 2 * p2 * x * y + p1 * (r + 2 * y * y)
    return np.stack([meta["fl_x"] * xd + meta["cx"], meta["fl_y"] * yd + meta["cy"]], 1), pc[:, 2]


def check_nerfstudio(out, run):
    with open(os.path.join(out, "transforms.json")) as f:
        meta = json.load(f)
    res = {"camera_model": meta["camera_model"], "frames": len(meta["frames"])}
    res["missing_keys"] = [k for k in ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "frames",
                                       "applied_transform", "ply_file_path") if k not in meta]
    missing, bad_size = [], []
    for fr in meta["frames"]:
        path = os.path.join(out, fr["file_path"])
        im = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if im is None:
            missing.append(fr["file_path"])
        elif im.shape[1] != meta["w"] or im.shape[0] != meta["h"]:
            bad_size.append(fr["file_path"])
    res["missing_files"], res["bad_size"] = missing[:5], bad_size[:5]
    rec, ids, xyz = run_points(run)
    A = np.asarray(meta["applied_transform"], dtype=float)
    expected = (A[:3, :3] @ xyz.T).T + A[:3, 3]
    ply, _ = read_ply(os.path.join(out, meta["ply_file_path"]))
    res["ply_points"] = len(ply)
    res["ply_max_diff"] = float(np.abs(ply - expected).max()) if len(ply) == len(expected) else None
    index = {pid: k for k, pid in enumerate(ids)}
    to_keypoint, to_pycolmap = [], []
    behind = 0
    for fr in meta["frames"]:
        if "colmap_im_id" not in fr:
            continue
        img = rec.images[fr["colmap_im_id"]]
        cam = rec.cameras[img.camera_id]
        obs = [p for p in img.points2D if p.has_point3D()]
        if not obs:
            continue
        pts = np.array([expected[index[p.point3D_id]] for p in obs])
        uv, z = ns_project(meta, fr["transform_matrix"], pts)
        behind += int((z >= 0).sum())
        for p, q in zip(obs, uv):
            to_keypoint.append(float(np.linalg.norm(q - p.xy)))
            ref = cam.img_from_cam(img.cam_from_world() * rec.points3D[p.point3D_id].xyz)
            to_pycolmap.append(float(np.linalg.norm(q - ref)))
    res["behind_camera"] = behind
    res["to_keypoints"] = stats(to_keypoint)
    res["to_pycolmap"] = stats(to_pycolmap)
    errs = [p.error for p in rec.points3D.values()]
    res["run_mean_reprojection_error"] = float(np.mean(errs)) if errs else None
    return res


def main():
    kind, out, run = sys.argv[1:4]
    res = check_3dgs(out, run) if kind == "3dgs" else check_nerfstudio(out, run)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
