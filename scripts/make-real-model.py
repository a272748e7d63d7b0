#!/usr/bin/env python3
"""Reconstructs a small real dataset with pycolmap into a COLMAP sparse model.

Usage: make-real-model.py IMAGE_DIR OUTPUT_DIR [--max-image-size N] [--threads N]

Pipeline (pycolmap 4.2.x, CPU only): SIFT extraction (images downscaled to
--max-image-size, one shared camera), exhaustive matching, incremental mapping.
The largest model is written in binary to OUTPUT_DIR/sparse (cameras.bin,
images.bin, points3D.bin, rigs.bin, frames.bin) and in text to
OUTPUT_DIR/sparse-text; the database is OUTPUT_DIR/database.db. A summary line
with the timing is printed. Used by crates/scene tests as a real-model fixture
(e.g. on datasets/strecha_fountain_P11/rgb).
"""
import argparse
import shutil
import sys
import time
from pathlib import Path

import pycolmap


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("image_dir", type=Path)
    ap.add_argument("output_dir", type=Path)
    ap.add_argument("--max-image-size", type=int, default=800)
    ap.add_argument("--max-num-features", type=int, default=4096)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    t0 = time.time()
    out: Path = args.output_dir
    out.mkdir(parents=True, exist_ok=True)
    db = out / "database.db"
    if db.exists():
        db.unlink()

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = args.max_image_size
    extraction.num_threads = args.threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = args.max_num_features
    reader = pycolmap.ImageReaderOptions()
    pycolmap.extract_features(
        db,
        args.image_dir,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    t1 = time.time()

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = args.threads
    matching.use_gpu = False
    pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
    t2 = time.time()

    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = args.threads
    work = out / "mapper"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()
    models = pycolmap.incremental_mapping(db, args.image_dir, work, options=mapper)
    t3 = time.time()
    if not models:
        print("no model reconstructed", file=sys.stderr)
        return 1
    best = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    for sub, text in (("sparse", False), ("sparse-text", True)):
        d = out / sub
        if d.exists():
            shutil.rmtree(d)
        d.mkdir()
        if text:
            best.write_text(d)
        else:
            best.write_binary(d)
    shutil.rmtree(work)
    print(
        f"models={len(models)} reg_images={best.num_reg_images()} "
        f"points3D={best.num_points3D()} "
        f"mean_reproj={best.compute_mean_reprojection_error():.3f}px "
        f"extract={t1 - t0:.1f}s match={t2 - t1:.1f}s map={t3 - t2:.1f}s total={t3 - t0:.1f}s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
