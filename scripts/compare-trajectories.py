#!/usr/bin/env python3
"""Compares several estimated trajectories of one sequence with its ground truth
and with each other: is the remaining error a system's own, or shared?

    compare-trajectories.py GROUNDTRUTH NAME=TRAJECTORY NAME=TRAJECTORY [...]

Every trajectory is a TUM file. Each is aligned to the ground truth with a
Sim(3) Umeyama fit on the timestamps all of them share (ground truth
associated within --max-diff seconds, nearest stamp), as `evo_ape tum -as`
does. Prints each system's ATE RMSE and per-axis RMS, the RMS distance between
every two aligned trajectories, and the correlation of their error vectors
(1: the same error, 0: unrelated errors). Needs only numpy.
"""

import argparse
import sys

import numpy as np


def read_tum(path):
    rows = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            v = line.split()
            if len(v) < 4:
                sys.exit(f"{path}: expected 'timestamp tx ty tz ...', got {line!r}")
            rows.append([float(x) for x in v[:4]])
    if not rows:
        sys.exit(f"{path}: no poses")
    return np.array(rows)


def umeyama_sim3(src, dst):
    """s, R, t minimising |dst - (s R src + t)|^2 (Umeyama 1991)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    w = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        w[2, 2] = -1.0
    r = u @ w @ vt
    s = np.trace(np.diag(d) @ w) / ((xs ** 2).sum() / len(src))
    return s, r, mu_d - s * r @ mu_s


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("groundtruth")
    ap.add_argument("systems", nargs="+", help="NAME=TRAJECTORY.tum")
    ap.add_argument("--max-diff", type=float, default=0.01, help="association tolerance, seconds")
    a = ap.parse_args()
    gt = read_tum(a.groundtruth)
    ests = {}
    for item in a.systems:
        if "=" not in item:
            sys.exit(f"expected NAME=TRAJECTORY, got {item!r}")
        name, path = item.split("=", 1)
        ests[name] = {round(r[0], 6): r[1:4] for r in read_tum(path)}
    stamps = sorted(set.intersection(*(set(e) for e in ests.values())))
    gt_pos, kept = [], []
    for t in stamps:
        i = int(np.argmin(np.abs(gt[:, 0] - t)))
        if abs(gt[i, 0] - t) <= a.max_diff:
            gt_pos.append(gt[i, 1:4])
            kept.append(t)
    if len(kept) < 3:
        sys.exit(f"only {len(kept)} timestamps shared by every trajectory and the ground truth")
    g = np.array(gt_pos)
    aligned = {}
    print(f"{len(kept)} shared timestamps")
    for name, e in ests.items():
        x = np.array([e[t] for t in kept])
        s, r, t = umeyama_sim3(x, g)
        aligned[name] = (s * (r @ x.T)).T + t
        err = aligned[name] - g
        ate = np.sqrt((np.linalg.norm(err, axis=1) ** 2).mean())
        axes = np.sqrt((err ** 2).mean(0))
        print(f"{name}: ATE RMSE {ate:.4f} m, per axis {axes[0]:.4f} {axes[1]:.4f} {axes[2]:.4f} m")
    names = list(aligned)
    for i, a_name in enumerate(names):
        for b_name in names[i + 1:]:
            ea, eb = aligned[a_name] - g, aligned[b_name] - g
            dist = np.sqrt((np.linalg.norm(aligned[a_name] - aligned[b_name], axis=1) ** 2).mean())
            corr = float(np.sum(ea * eb) / np.sqrt(np.sum(ea * ea) * np.sum(eb * eb)))
            print(f"{a_name} vs {b_name}: RMS distance {dist:.4f} m, error correlation {corr:.2f}")


if __name__ == "__main__":
    main()
