"""OpenCV peer of `colslam bench features` (issue 3).

Usage: python bench_features.py INPUT.json

INPUT: {"images": [path, ...], "timing_features": [1000, 2000],
        "fast_thresholds": [7, 20], "quality_features": 1000, "repeats": r,
        "match_threads": 2, "descriptors": [path, ...]}
* Extraction: cv2.ORB_create(nfeatures=n, fastThreshold=t) per frame with
  cv2.setNumThreads(1); per frame the best of `repeats` runs, then the
  median over frames (ms), for every n and t; per-frame times too.
* Matching: cv2.BFMatcher(NORM_HAMMING, crossCheck=True) on the descriptor
  files given (raw N x 32 bytes each, the caller's own descriptors so that
  both libraries match identical sets), consecutive pairs, with
  cv2.setNumThreads(match_threads).
* Quality: keypoints ([x, y, octave]) and matches of every consecutive pair at
  `quality_features` keypoints (per threshold), for the caller to score with
  its Sampson check.
Prints one JSON object on stdout.
"""

import json
import statistics
import sys
import time

import cv2
import numpy as np


def best_of(repeats, fn):
    best, out = None, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        best = dt if best is None else min(best, dt)
    return best, out


def main():
    with open(sys.argv[1]) as f:
        cfg = json.load(f)
    grays = []
    for p in cfg["images"]:
        img = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise SystemExit(f"bench_features.py: cannot read image {p}")
        grays.append(img)
    repeats = max(1, int(cfg.get("repeats", 1)))
    q = int(cfg["quality_features"])

    cv2.setNumThreads(1)
    out = {"opencv_version": cv2.__version__, "extract_ms": {}, "extract_frame_ms": {}, "num_keypoints": {},
           "pairs": {}}
    bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    for th in cfg["fast_thresholds"]:
        th = int(th)
        out["extract_ms"][str(th)] = {}
        out["num_keypoints"][str(th)] = {}
        out["extract_frame_ms"][str(th)] = {}
        for n in cfg["timing_features"]:
            orb = cv2.ORB_create(nfeatures=int(n), fastThreshold=th)
            orb.detectAndCompute(grays[0], None)  # warm-up
            samples, counts, feats = [], [], []
            for g in grays:
                dt, (kps, desc) = best_of(repeats, lambda: orb.detectAndCompute(g, None))
                samples.append(dt)
                counts.append(len(kps))
                feats.append((kps, desc))
            out["extract_ms"][str(th)][str(n)] = statistics.median(samples) * 1e3
            out["extract_frame_ms"][str(th)][str(n)] = [t * 1e3 for t in samples]
            out["num_keypoints"][str(th)][str(n)] = statistics.mean(counts)
            if int(n) == q:
                pairs = []
                for (k1, d1), (k2, d2) in zip(feats, feats[1:]):
                    ms = bf.match(d1, d2) if d1 is not None and d2 is not None else []
                    pairs.append({
                        "kp1": [[k.pt[0], k.pt[1], k.octave] for k in k1],
                        "kp2": [[k.pt[0], k.pt[1], k.octave] for k in k2],
                        "matches": [[m.queryIdx, m.trainIdx] for m in ms],
                    })
                out["pairs"][str(th)] = pairs

    cv2.setNumThreads(int(cfg.get("match_threads", 2)))
    descs = [np.fromfile(p, dtype=np.uint8).reshape(-1, 32) for p in cfg.get("descriptors", [])]
    samples, counts = [], []
    for d1, d2 in zip(descs, descs[1:]):
        bf.match(d1, d2)  # warm-up
        dt, ms = best_of(repeats, lambda: bf.match(d1, d2))
        samples.append(dt)
        counts.append(len(ms))
    out["match_ms"] = statistics.median(samples) * 1e3 if samples else None
    out["match_pair_ms"] = [t * 1e3 for t in samples]
    out["match_counts"] = counts
    cv2.setNumThreads(1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
