#!/usr/bin/env python3
"""Plots a TUM trajectory without ground truth (for example the KITTI clip):
top view (x against z, the camera's forward axis at the start) and the
distance travelled along the trajectory's main axis over time, and prints how
straight and how monotonic the motion is.

    scripts/plot-trajectory.py OUT/trajectory.tum PLOT.png

Needs numpy and matplotlib (the peer venv of scripts/setup-peers.sh has both).
"""
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    src, dst = sys.argv[1], sys.argv[2]
    try:
        d = np.loadtxt(src, comments="#", ndmin=2)
    except (OSError, ValueError) as e:
        print(f"{src}: cannot read a TUM trajectory: {e}", file=sys.stderr)
        return 1
    if d.shape[0] < 2 or d.shape[1] != 8:
        print(f"{src}: need at least 2 poses of 8 columns, got shape {d.shape}", file=sys.stderr)
        return 1
    p = d[:, 1:4] - d[0, 1:4]
    _, s, vt = np.linalg.svd(p - p.mean(0), full_matrices=False)
    along = p @ vt[0]
    if along[-1] < along[0]:
        along = -along
    straight = s[0] / s.sum()
    monotonic = float(np.mean(np.diff(along) > 0))
    print(f"poses {len(p)}, straightness {straight:.3f} (1 = a line), monotonic share {monotonic:.3f}")
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot(p[:, 0], p[:, 2])
    ax[0].set_xlabel("x")
    ax[0].set_ylabel("z")
    ax[0].set_title("top view (map units)")
    ax[0].axis("equal")
    ax[1].plot(d[:, 0] - d[0, 0], along)
    ax[1].set_xlabel("time (s)")
    ax[1].set_ylabel("distance along the main axis")
    ax[1].set_title(f"straightness {straight:.3f}, monotonic {monotonic:.3f}")
    fig.tight_layout()
    tmp = dst + ".tmp.png"
    fig.savefig(tmp, dpi=80)
    import os

    os.replace(tmp, dst)
    return 0


if __name__ == "__main__":
    sys.exit(main())
