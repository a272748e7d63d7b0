"""Builds a small synthetic model with pycolmap and writes it.

Usage: make_model.py BIN_DIR TXT_DIR

Several camera models, images added out of id order (so the registration
order differs from id order), one unregistered image (pycolmap does not
write it), points with tracks of length 2..4, computed reprojection errors.
Deterministic (numpy seed 3).
"""
import sys
from pathlib import Path

import numpy as np
import pycolmap


def main():
    rng = np.random.default_rng(3)
    rec = pycolmap.Reconstruction()
    cams = [
        (1, "SIMPLE_RADIAL", 640, 480, [520.3, 320.1, 239.7, -0.0123]),
        (2, "OPENCV", 800, 600, [610.5, 611.25, 401.1, 299.3, 0.021, -0.0042, 0.0011, -0.0007]),
        (4, "PINHOLE", 1024, 768, [700.0, 702.5, 512.0, 384.0]),
        (7, "FULL_OPENCV", 640, 480, [500.0, 501.0, 320.0, 240.0, 0.01, -0.002, 0.0005, 0.0004, 0.0001, 0.001, -0.0002, 0.00003]),
        (9, "OPENCV_FISHEYE", 640, 480, [300.0, 300.5, 320.0, 240.0, 0.01, -0.003, 0.0004, -0.00005]),
    ]
    for cid, model, w, h, params in cams:
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=w, height=h, params=params, camera_id=cid))
    order = [5, 2, 11, 3, 8, 6]
    cam_of = {5: 1, 2: 2, 11: 4, 3: 7, 8: 9, 6: 1}
    for k, iid in enumerate(order):
        pts = [pycolmap.Point2D(rng.uniform(0, 600, size=2)) for _ in range(30 + k)]
        im = pycolmap.Image(name=f"frames/img_{iid:03d}.png", points2D=pts, camera_id=cam_of[iid], image_id=iid)
        if iid == 6:
            rec.add_image_with_trivial_frame(im)  # unregistered
            continue
        # Near-identity rotations and small offsets: the points (around z = 5)
        # lie in front of every camera, so reprojection errors are finite.
        q = np.array([1.0, 0, 0, 0]) + 0.1 * rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = np.array([q[1], q[2], q[3], q[0]])  # pycolmap takes (x, y, z, w)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(q), 0.3 * rng.normal(size=3))
        rec.add_image_with_trivial_frame(im, pose)
    reg = [i for i in order if i != 6]
    used = {i: set() for i in reg}
    for n in range(25):
        length = 2 + n % 3
        imgs = rng.choice(reg, size=length, replace=False)
        elements = []
        for i in imgs:
            free = [j for j in range(rec.images[int(i)].num_points2D()) if j not in used[int(i)]]
            j = int(free[0])
            used[int(i)].add(j)
            elements.append(pycolmap.TrackElement(int(i), j))
        color = rng.integers(0, 256, size=3).astype(np.uint8)
        rec.add_point3D(rng.normal(size=3) + np.array([0, 0, 5.0]), pycolmap.Track(elements), color)
    rec.update_point_3d_errors()
    for d, text in ((sys.argv[1], False), (sys.argv[2], True)):
        Path(d).mkdir(parents=True, exist_ok=True)
        if text:
            rec.write_text(d)
        else:
            rec.write_binary(d)


if __name__ == "__main__":
    main()
