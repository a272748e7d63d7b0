#!/usr/bin/env python3
"""Reconstructs the first frames of a TUM sequence with pycolmap (the real
problem of `colslam bench ba`).

Usage: make_tum_model.py DATASET_DIR OUTPUT_DIR [--num-frames 60] [--threads 2]

DATASET_DIR holds rgb/*.png (sorted by name = by time) and camera.yaml (the
TUM fr1 calibration). The first --num-frames images are linked into
OUTPUT_DIR/images; pycolmap 4.2 (CPU only) runs SIFT extraction with one
shared FULL_OPENCV camera set to the calibration (k1 k2 p1 p2 k3; principal
point shifted by +0.5 px to COLMAP's pixel-centre convention), sequential
matching, and incremental mapping with the intrinsics held constant. The fr1
camera has k3 = 1.1633, above COLMAP's default `max_extra_param` of 1, which
would reject every image's camera as degenerate, so that option is raised.
The largest model is written in binary to OUTPUT_DIR/sparse; a summary line is
printed. Nothing else is modified.
"""
import argparse
import re
import shutil
import sys
import time
from pathlib import Path

import pycolmap

# Bound on |distortion parameter| accepted by the mapper (COLMAP's default is
# 1.0; fr1's k3 is 1.1633).
MAX_EXTRA_PARAM = 10.0
# COLMAP puts the centre of the top-left pixel at (0.5, 0.5); OpenCV/TUM at 0.
PIXEL_CENTRE_SHIFT = 0.5


def read_calibration(path: Path) -> dict:
    vals = {}
    for line in path.read_text().splitlines():
        m = re.match(r"^\s*(\w+)\s*:\s*([-+0-9.eE]+)", line.split("#")[0])
        if m:
            vals[m.group(1)] = float(m.group(2))
    for key in ("width", "height", "fx", "fy", "cx", "cy"):
        if key not in vals:
            raise SystemExit(f"{path}: no '{key}:' entry")
    return vals


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset_dir", type=Path)
    ap.add_argument("output_dir", type=Path)
    ap.add_argument("--num-frames", type=int, default=60)
    ap.add_argument("--max-num-features", type=int, default=4096)
    ap.add_argument("--overlap", type=int, default=10, help="sequential matching overlap")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    t0 = time.time()
    cal = read_calibration(args.dataset_dir / "camera.yaml")
    frames = sorted((args.dataset_dir / "rgb").glob("*.png"))[: args.num_frames]
    if len(frames) < 2:
        print(f"{args.dataset_dir}/rgb: fewer than 2 PNG frames", file=sys.stderr)
        return 1
    out: Path = args.output_dir
    out.mkdir(parents=True, exist_ok=True)
    images = out / "images"
    if images.exists():
        shutil.rmtree(images)
    images.mkdir()
    for f in frames:
        (images / f.name).symlink_to(f.resolve())
    db = out / "database.db"
    if db.exists():
        db.unlink()

    params = [cal["fx"], cal["fy"], cal["cx"] + PIXEL_CENTRE_SHIFT, cal["cy"] + PIXEL_CENTRE_SHIFT,
              cal.get("k1", 0.0), cal.get("k2", 0.0), cal.get("p1", 0.0), cal.get("p2", 0.0),
              cal.get("k3", 0.0), 0.0, 0.0, 0.0]
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "FULL_OPENCV"
    reader.camera_params = ",".join(f"{v:.10g}" for v in params)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = args.threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = args.max_num_features
    pycolmap.extract_features(db, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    t1 = time.time()

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = args.threads
    matching.use_gpu = False
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = args.overlap
    pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    t2 = time.time()

    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = args.threads
    mapper.max_extra_param = MAX_EXTRA_PARAM
    mapper.mapper.max_extra_param = MAX_EXTRA_PARAM
    mapper.ba_refine_focal_length = False
    mapper.ba_refine_principal_point = False
    mapper.ba_refine_extra_params = False
    work = out / "mapper"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()
    models = pycolmap.incremental_mapping(db, images, work, options=mapper)
    t3 = time.time()
    if not models:
        print("no model reconstructed", file=sys.stderr)
        return 1
    best = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    sparse = out / "sparse"
    if sparse.exists():
        shutil.rmtree(sparse)
    sparse.mkdir()
    best.write_binary(sparse)
    shutil.rmtree(work)
    print(
        f"models={len(models)} reg_images={best.num_reg_images()}/{len(frames)} "
        f"points3D={best.num_points3D()} observations={sum(p.track.length() for p in best.points3D.values())} "
        f"mean_reproj={best.compute_mean_reprojection_error():.3f}px "
        f"extract={t1 - t0:.1f}s match={t2 - t1:.1f}s map={t3 - t2:.1f}s total={t3 - t0:.1f}s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
