#!/usr/bin/env python3
"""Issue 20's per-segment scale plot: for each run, the local scale along the drive (the
Sim(3)-aligned estimate's displacement over the ground truth's in windows of 10 frames; 1.0 =
the drive's average) and the top view of the aligned path against the ground truth.

    kitti-scale-plot.py GROUNDTRUTH.txt OUT.png LABEL=RUN_FOLDER [LABEL=RUN_FOLDER ...]

numpy and matplotlib (the peer venv)."""
import sys
import numpy as np
import matplotlib
matplotlib.use('Agg')
import matplotlib.pyplot as plt


def load(p):
    d = np.loadtxt(p, comments='#')
    return d[:, 0], d[:, 1:4]


def aligned(run, tg, pg):
    te, pe = load(run + '/trajectory.tum')
    g = pg[[np.argmin(abs(tg - t)) for t in te]]
    mu_e, mu_g = pe.mean(0), g.mean(0)
    E, G = pe - mu_e, g - mu_g
    U, S, Vt = np.linalg.svd(G.T @ E / len(pe))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (E ** 2).sum() * len(pe)
    return (s * (R @ pe.T)).T + (mu_g - s * R @ mu_e), g


def main():
    gt, png, runs = sys.argv[1], sys.argv[2], [a.split('=', 1) for a in sys.argv[3:]]
    tg, pg = load(gt)
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.5))
    for label, run in runs:
        a, g = aligned(run, tg, pg)
        cum = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(g, axis=0), axis=1))])
        w = 10
        x = [cum[i + w // 2] for i in range(0, len(a) - w)]
        y = [np.linalg.norm(a[i + w] - a[i]) / max(np.linalg.norm(g[i + w] - g[i]), 1e-9) for i in range(0, len(a) - w)]
        ate = np.sqrt(((a - g) ** 2).sum(1).mean())
        left.plot(x, y, label=f'{label} (ATE {ate:.2f} m)')
        right.plot(a[:, 0], a[:, 2], label=label)
    right.plot(pg[:, 0], pg[:, 2], 'k--', lw=1, label='ground truth')
    left.axhline(1.0, color='k', lw=0.5)
    left.set_xlabel('path length (m)')
    left.set_ylabel('local scale (10 frames)')
    left.legend()
    right.set_aspect('equal')
    right.set_xlabel('x (m)')
    right.set_ylabel('z (m)')
    right.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=80)


if __name__ == '__main__':
    main()
