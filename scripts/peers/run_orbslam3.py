#!/usr/bin/env python3
"""Peer run for `colslam bench --peers`: ORB-SLAM3 monocular through the PyPI
wheel `pyorbslam3` 0.1.1 (optional).

    run_orbslam3.py SEQ_DIR OUT_DIR

Exits with status 3 and one line "not run: <reason>" on stderr when the
wheel or its ORB vocabulary is missing. The wheel does not ship ORBvoc.txt
(139 MB); `pyorbslam3.vocabulary_path()` downloads it from GitHub, which this
script never does: point PYORBSLAM3_VOCAB at a local copy instead.

When both are present, the frames listed in rgb.txt are tracked one by one
and the pose of every tracked frame is written as OUT/trajectory.tum (TUM
format, world_from_cam), the keyframes as OUT/keyframes.tum, with
OUT/peer.json holding the counts. (This tracking path is untested here: no
vocabulary was available when it was written.)
"""

import json
import os
import sys
import time

NOT_RUN = 3


def not_run(reason):
    print(f"not run: {reason}", file=sys.stderr)
    sys.exit(NOT_RUN)


def quat_xyzw(r):
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    import numpy as np

    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s)
    else:
        i = int(np.argmax([r[0, 0], r[1, 1], r[2, 2]]))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (r[j, i] + r[i, j]) / s
        v[k] = (r[k, i] + r[i, k]) / s
        q = (v[0], v[1], v[2], (r[k, j] - r[j, k]) / s)
    n = float(np.sqrt(sum(c * c for c in q)))
    return tuple(float(c) / n for c in q)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    seq, out = sys.argv[1], sys.argv[2]
    try:
        import pyorbslam3  # noqa: F401
    except ImportError:
        not_run("pyorbslam3 is not installed in the peer venv (pip install pyorbslam3==0.1.1)")
    try:
        from pyorbslam3.vocab import vocabulary_path

        vocab = vocabulary_path(download=False)
    except Exception:  # noqa: BLE001 - any failure means no vocabulary
        not_run("no ORB vocabulary: set PYORBSLAM3_VOCAB to a local ORBvoc.txt (the wheel does not ship one)")
    try:
        import cv2
        import numpy as np
    except ImportError:
        not_run("opencv-python / numpy missing in the peer venv")

    cam = {}
    with open(os.path.join(seq, "camera.yaml")) as f:
        for line in f:
            line = line.split("#", 1)[0].strip()
            if ":" in line:
                k, v = (s.strip() for s in line.split(":", 1))
                cam[k] = v
    settings = os.path.join(out, "orbslam3.yaml")
    os.makedirs(out, exist_ok=True)
    with open(settings, "w") as f:
        f.write("%YAML:1.0\nFile.version: \"1.0\"\nCamera.type: \"PinHole\"\n")
        for src, dst in [("fx", "fx"), ("fy", "fy"), ("cx", "cx"), ("cy", "cy"),
                         ("k1", "k1"), ("k2", "k2"), ("p1", "p1"), ("p2", "p2"), ("k3", "k3")]:
            f.write(f"Camera1.{dst}: {float(cam.get(src, 0.0))}\n")
        f.write(f"Camera.width: {int(cam['width'])}\nCamera.height: {int(cam['height'])}\n")
        f.write("Camera.fps: 30\nCamera.RGB: 1\nORBextractor.nFeatures: 1000\n")
        f.write("ORBextractor.scaleFactor: 1.2\nORBextractor.nLevels: 8\n")
        f.write("ORBextractor.iniThFAST: 20\nORBextractor.minThFAST: 7\n")
        f.write("Viewer.KeyFrameSize: 0.05\nViewer.KeyFrameLineWidth: 1.0\nViewer.GraphLineWidth: 0.9\n")
        f.write("Viewer.PointSize: 2.0\nViewer.CameraSize: 0.08\nViewer.CameraLineWidth: 3.0\n")
        f.write("Viewer.ViewpointX: 0.0\nViewer.ViewpointY: -0.7\nViewer.ViewpointZ: -1.8\nViewer.ViewpointF: 500.0\n")

    frames = []
    with open(os.path.join(seq, "rgb.txt")) as f:
        for line in f:
            p = line.split()
            if len(p) >= 2 and not line.startswith("#"):
                frames.append((float(p[0]), p[1]))
    slam = pyorbslam3.Slam(vocab, settings, pyorbslam3.Sensor.MONOCULAR, use_viewer=False)
    rows = []
    t0 = time.time()
    for t, rel in frames:
        img = cv2.imread(os.path.join(seq, rel), cv2.IMREAD_COLOR)
        res = slam.track_monocular(img, t)
        if res.ok and res.pose_valid:
            m = np.asarray(res.pose_wc, dtype=float).reshape(4, 4)
            rows.append((t, *m[:3, 3], *quat_xyzw(m[:3, :3])))
    wall = time.time() - t0
    # ORB-SLAM3 refuses SaveTrajectoryTUM for monocular; the keyframes are
    # saved for reference and the per-frame poses come from the results.
    slam.save_keyframe_trajectory_tum(os.path.join(out, "keyframes.tum"))
    slam.shutdown()
    with open(os.path.join(out, "trajectory.tum"), "w") as f:
        for r in rows:
            f.write("%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n" % r)
    with open(os.path.join(out, "peer.json"), "w") as f:
        json.dump({"system": "ORB-SLAM3 (pyorbslam3 0.1.1)", "frames": len(frames),
                   "localized": len(rows), "timings_s": {"tracking": wall}}, f, indent=2)


if __name__ == "__main__":
    main()
