#!/usr/bin/env python3
"""Scale consistency of a colslam run on a drive (issue 20): ATE after one Sim(3), the
local scale of each segment between the given end frames, the scale error over every 50 m
window of the path, and the track lengths of the model (pycolmap, when importable).

    kitti-scale.py RUN_FOLDER GROUNDTRUTH.txt

The segments are those of kitti_odom00_first300 (three straights, two turns)."""
import numpy as np, sys, os
out = sys.argv[1]; gtp = sys.argv[2]
def load(p):
    d = np.loadtxt(p, comments='#'); return d[:, 0], d[:, 1:4]
te, pe = load(os.path.join(out, 'trajectory.tum')); tg, pg = load(gtp)
idx = [np.argmin(abs(tg - t)) for t in te]; g = pg[idx]
mu_e, mu_g = pe.mean(0), g.mean(0); E = pe - mu_e; G = g - mu_g
U, S, Vt = np.linalg.svd(G.T @ E / len(pe)); D = np.eye(3); D[2, 2] = np.sign(np.linalg.det(U @ Vt))
R = U @ D @ Vt; s = np.trace(np.diag(S) @ D) / (E ** 2).sum() * len(pe)
a = (s * (R @ pe.T)).T + (mu_g - s * R @ mu_e)
ate = np.sqrt(((a - g) ** 2).sum(1).mean())
cum = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(g, axis=0), axis=1))])
def scale(i, j):
    return np.linalg.norm(a[j] - a[i]) / max(np.linalg.norm(g[j] - g[i]), 1e-9)
segs = [(0, 40), (40, 100), (100, 130), (130, 200), (200, 230), (230, 299)]
seg = ' '.join(f'{i}-{j}:{scale(i, j):.3f}' for i, j in segs if j < len(a))
# 50 m windows: aligned path length / gt path length
ea = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(a, axis=0), axis=1))])
errs = []
for i in range(len(a)):
    j = np.searchsorted(cum, cum[i] + 50.0)
    if j >= len(a): break
    errs.append((ea[j] - ea[i]) / (cum[j] - cum[i]) - 1)
errs = np.abs(errs) if errs else np.array([np.nan])
line = f'frames {len(te)} ATE {ate:.3f} m | seg scale {seg} | 50m-window scale err max {100*errs.max():.1f}% mean {100*errs.mean():.1f}%'
try:
    import pycolmap
    rec = pycolmap.Reconstruction(out)
    tl = np.array([p.track.length() for p in rec.points3D.values()])
    line += f' | kf {rec.num_reg_images()} pts {len(tl)} track mean {tl.mean():.2f} 2-obs {100*(tl==2).mean():.0f}% >=5 {100*(tl>=5).mean():.0f}%'
except Exception as e:
    line += f' | model: {e}'
print(line)
