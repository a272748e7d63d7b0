#!/usr/bin/env python3
"""Peer run for `colslam bench --peers`: ORB-SLAM3 monocular through the PyPI
wheel `pyorbslam3` 0.1.1 (optional).

    run_orbslam3.py SEQ_DIR OUT_DIR [--vocabulary FILE] [--data DIR] [--features N]

Exits with status 3 and one line "not run: <reason>" on stderr when the
wheel is missing or no vocabulary can be had.

Vocabulary: the wheel does not ship ORBvoc.txt and would download it from
GitHub, which this script never does. It uses, in order: --vocabulary,
$COLSLAM_ORBVOC, $PYORBSLAM3_VOCAB (existing files), else a vocabulary
trained by train_orbvoc.py (next to this script) from the non-evaluation
images (Strecha, KITTI clip; the sequence's own folder is excluded) of the
datasets folder (--data, else $COLSLAM_DATA, else the sequence's parent
folder when it holds them, else ../shared/datasets), cached under the venv
after the first run (about 30 s).

The frames listed in rgb.txt are tracked one by one (grayscale, with the
sequence's intrinsics and radial-tangential distortion from camera.yaml).
ORB-SLAM3 refuses SaveTrajectoryTUM for monocular input, so the per-frame
poses come from the tracking results: a frame counts as tracked when the
tracker state is OK. When tracking is lost, ORB-SLAM3 starts a new map in
another frame and scale; the frames of each map form a segment, and
OUT/trajectory.tum holds the poses (world_from_cam, TUM format) of the
segment with the most tracked frames. OUT/keyframes_last_map.tum holds the
keyframes of the last active map (ORB-SLAM3's own file), copied to
OUT/keyframes.tum when that map is the evaluated one; OUT/peer.json the counts:
frames, localized (frames in trajectory.tum), tracked_total, the first frame
at which tracking was lost, and every segment.
"""

import argparse
import json
import os
import sys
import time

NOT_RUN = 3
# ORB extractor settings of ORB-SLAM3's TUM1.yaml.
DEFAULT_FEATURES = 1000


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


def read_camera(seq):
    cam = {}
    with open(os.path.join(seq, "camera.yaml")) as f:
        for line in f:
            line = line.split("#", 1)[0].strip()
            if ":" in line:
                k, v = (s.strip() for s in line.split(":", 1))
                cam[k] = v
    return cam


def read_frames(seq):
    frames = []
    with open(os.path.join(seq, "rgb.txt")) as f:
        for line in f:
            p = line.split()
            if len(p) >= 2 and not line.startswith("#"):
                frames.append((float(p[0]), p[1]))
    return frames


def write_settings(path, cam, fps, features):
    """ORB-SLAM3 settings (File.version 1.0 layout), ORB parameters of TUM1.yaml."""
    lines = ["%YAML:1.0", 'File.version: "1.0"', 'Camera.type: "PinHole"']
    for k in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
        lines.append(f"Camera1.{k}: {float(cam.get(k, 0.0))}")
    lines += [
        f"Camera.width: {int(cam['width'])}",
        f"Camera.height: {int(cam['height'])}",
        f"Camera.fps: {int(round(fps))}",
        "Camera.RGB: 0",
        f"ORBextractor.nFeatures: {features}",
        "ORBextractor.scaleFactor: 1.2",
        "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20",
        "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05",
        "Viewer.KeyFrameLineWidth: 1.0",
        "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0",
        "Viewer.CameraSize: 0.08",
        "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0",
        "Viewer.ViewpointY: -0.7",
        "Viewer.ViewpointZ: -1.8",
        "Viewer.ViewpointF: 500.0",
    ]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def find_vocabulary(arg, seq, data):
    """(path, source) of the vocabulary; trains one when none is given."""
    for src, p in (("--vocabulary", arg), ("COLSLAM_ORBVOC", os.environ.get("COLSLAM_ORBVOC")),
                   ("PYORBSLAM3_VOCAB", os.environ.get("PYORBSLAM3_VOCAB"))):
        if p:
            if os.path.isfile(p):
                return p, src
            if src != "PYORBSLAM3_VOCAB":
                not_run(f"{src} {p} is not a file")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    sys.dont_write_bytecode = True  # no __pycache__ in the source tree
    try:
        import train_orbvoc
    except ImportError as e:
        not_run(f"no ORB vocabulary given and train_orbvoc.py cannot be imported ({e})")
    if not data:
        parent = os.path.dirname(os.path.abspath(seq.rstrip("/")))
        data = os.environ.get("COLSLAM_DATA") or (parent if train_orbvoc.training_sources(parent, []) else None)
    try:
        path, trained = train_orbvoc.vocabulary(data=data, exclude=[os.path.basename(os.path.abspath(seq))])
    except Exception as e:  # noqa: BLE001 - any failure means no vocabulary
        not_run(f"no ORB vocabulary given and training one failed: {e}")
    return path, "trained now" if trained else "trained (cached)"


def main():
    ap = argparse.ArgumentParser(usage=__doc__.split("\n\n")[1].strip())
    ap.add_argument("seq")
    ap.add_argument("out")
    ap.add_argument("--vocabulary", help="ORBvoc.txt (DBoW2 text format)")
    ap.add_argument("--data", help="datasets folder holding the vocabulary's training images")
    ap.add_argument("--features", type=int, default=DEFAULT_FEATURES, help="ORB features per frame")
    a = ap.parse_args()
    try:
        import pyorbslam3
    except ImportError:
        not_run("pyorbslam3 is not installed in the peer venv (pip install pyorbslam3==0.1.1)")
    try:
        import cv2
        import numpy as np
    except ImportError:
        not_run("opencv-python / numpy missing in the peer venv")

    t_voc = time.time()
    vocab, vocab_source = find_vocabulary(a.vocabulary, a.seq, a.data)
    t_train = time.time() - t_voc
    print(f"vocabulary: {vocab} ({vocab_source})", file=sys.stderr)

    os.makedirs(a.out, exist_ok=True)
    frames = read_frames(a.seq)
    if len(frames) < 2:
        sys.exit(f"fewer than 2 frames in {a.seq}/rgb.txt")
    dts = sorted(t1[0] - t0[0] for t0, t1 in zip(frames, frames[1:]))
    fps = 1.0 / dts[len(dts) // 2] if dts[len(dts) // 2] > 0 else 30.0
    settings = os.path.join(a.out, "orbslam3.yaml")
    write_settings(settings, read_camera(a.seq), fps, a.features)

    t_load = time.time()
    slam = pyorbslam3.Slam(vocab, settings, pyorbslam3.Sensor.MONOCULAR, use_viewer=False)
    t_load = time.time() - t_load
    tracked_states = {pyorbslam3.TrackingState.OK, pyorbslam3.TrackingState.OK_KLT}
    restart_states = {pyorbslam3.TrackingState.LOST, pyorbslam3.TrackingState.NOT_INITIALIZED}
    segments = []  # one per map: {"first_frame", "last_frame", "tracked", "rows"}
    current = None
    first_lost = None
    states = {}
    t0 = time.time()
    for i, (t, rel) in enumerate(frames):
        img = cv2.imread(os.path.join(a.seq, rel), cv2.IMREAD_GRAYSCALE)
        if img is None:
            sys.exit(f"cannot read {rel}")
        res = slam.track_monocular(img, t)
        state = res.state
        states[state.name] = states.get(state.name, 0) + 1
        if state in tracked_states and res.pose_valid:
            if current is None:
                current = {"first_frame": i, "last_frame": i, "tracked": 0, "rows": []}
                segments.append(current)
            m = np.asarray(res.pose_wc, dtype=float).reshape(4, 4)
            current["rows"].append((t, *m[:3, 3], *quat_xyzw(m[:3, :3])))
            current["tracked"] += 1
            current["last_frame"] = i
        elif current is not None:
            if first_lost is None:
                first_lost = i
            if state in restart_states:
                current = None  # the next tracked frame belongs to a new map
    wall = time.time() - t0
    slam.shutdown()
    last_map_kf = os.path.join(a.out, "keyframes_last_map.tum")
    slam.save_keyframe_trajectory_tum(last_map_kf)

    best = max(segments, key=lambda s: s["tracked"], default=None)
    rows = best["rows"] if best else []
    with open(os.path.join(a.out, "trajectory.tum"), "w") as f:
        for r in rows:
            f.write("%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n" % r)
    keyframes = None
    if best is not None and best is segments[-1] and os.path.isfile(last_map_kf):
        # ORB-SLAM3 saves the keyframes of the active (last) map only; they
        # are the evaluated map's keyframes when that map is the largest.
        with open(last_map_kf) as f:
            text = f.read()
        with open(os.path.join(a.out, "keyframes.tum"), "w") as f:
            f.write(text)
        keyframes = sum(1 for line in text.splitlines() if line.strip())
    tracked_total = sum(s["tracked"] for s in segments)
    summary = {
        "system": "ORB-SLAM3 (pyorbslam3 0.1.1)",
        "vocabulary": vocab,
        "vocabulary_source": vocab_source,
        "frames": len(frames),
        "localized": len(rows),
        "tracked_total": tracked_total,
        "first_lost_frame": first_lost,
        "keyframes": keyframes,
        "states": states,
        "segments": [{k: s[k] for k in ("first_frame", "last_frame", "tracked")} for s in segments],
        "timings_s": {"vocabulary": t_train, "load": t_load, "tracking": wall},
    }
    with open(os.path.join(a.out, "peer.json"), "w") as f:
        json.dump(summary, f, indent=2)
    print(
        f"ORB-SLAM3: {len(frames)} frames, tracked {tracked_total} in {len(segments)} map(s), "
        f"largest {len(rows)}, first lost at frame {first_lost}, {wall:.1f} s",
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
