#!/usr/bin/env python3
"""Are a model's points too far or too near for its cameras' baselines (issue 20)? For
each 3D point of a run's model with observers a (its first frame) and b (its last), the
point's depth in a over the baseline |c_a - c_b| in the model, against the same ratio for
the point re-triangulated from its own track (DLT) with the ground-truth poses:
log(ratio model / ratio ground truth). The ratio is gauge-free (no alignment), and local
(the drift between a and b only): a point placed farther than its observations and the
true poses say gives a positive value, and a turn registered on such points takes a step
longer than the truth. Printed as medians by the frame of the point's first observer
(segments) and by the model's triangulation angle of a and b.

    kitti-depth-bias.py RUN_FOLDER GROUNDTRUTH.txt [FROM-TO ...]   (pycolmap, numpy)

Caveat: the ground truth's own local rotation error (KITTI: about 0.1 deg) moves the
low-angle points' values as much as a model would; compare runs with each other, not
with zero. Ground truth rows are taken in frame order (row i = frame i)."""
import pycolmap, numpy as np, sys, os
out, gtp = sys.argv[1], sys.argv[2]
ranges = [tuple(map(int, r.split('-'))) for r in sys.argv[3:]] or [(0, 85), (85, 100), (100, 130), (130, 170), (170, 200), (200, 230), (230, 300)]
gt = np.loadtxt(gtp, comments='#')
def quat_to_R(q):  # x y z w
    x, y, z, w = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-z*w), 2*(x*z+y*w)], [2*(x*y+z*w), 1-2*(x*x+z*z), 2*(y*z-x*w)], [2*(x*z-y*w), 2*(y*z+x*w), 1-2*(x*x+y*y)]])
def frame(img): return int(os.path.splitext(img.name)[0])
rec = pycolmap.Reconstruction(out)
K = next(iter(rec.cameras.values())).calibration_matrix()
proj, centre, rot = {}, {}, {}
for i, img in rec.images.items():
    f = frame(img); Rwc = quat_to_R(gt[f, 4:8]); c = gt[f, 1:4]
    proj[i] = K @ np.hstack([Rwc.T, (-Rwc.T @ c)[:, None]]); centre[i] = c; rot[i] = Rwc
rows = []
for p in rec.points3D.values():
    els = p.track.elements
    ids = sorted({e.image_id for e in els}, key=lambda i: frame(rec.images[i]))
    if len(ids) < 2:
        continue
    a, b = ids[0], ids[-1]
    A = []
    for el in els:
        u, v = rec.images[el.image_id].points2D[el.point2D_idx].xy; M = proj[el.image_id]
        A += [u * M[2] - M[0], v * M[2] - M[1]]
    X = np.linalg.svd(np.array(A))[2][-1]
    if abs(X[3]) < 1e-12:
        continue
    xg = X[:3] / X[3]
    ia, ib = rec.images[a], rec.images[b]
    ca, cb = ia.projection_center(), ib.projection_center()
    dm, bm = (ia.cam_from_world() * p.xyz)[2], np.linalg.norm(ca - cb)
    dg, bg = (rot[a].T @ (xg - centre[a]))[2], np.linalg.norm(centre[a] - centre[b])
    if min(dm, dg, bm, bg) <= 0:
        continue
    ra, rb = p.xyz - ca, p.xyz - cb
    angle = np.degrees(np.arccos(np.clip(ra @ rb / np.linalg.norm(ra) / np.linalg.norm(rb), -1, 1)))
    rows.append((frame(ia), angle, np.log((dm / bm) / (dg / bg))))
R = np.array(rows)
print(f'{out}: {len(R)} points; median log((depth/baseline) model / ground truth) by first frame and angle')
for lo, hi in ranges:
    seg = (R[:, 0] >= lo) & (R[:, 0] < hi)
    cells = []
    for alo, ahi in [(0, 1), (1, 2), (2, 4), (4, 180)]:
        sel = seg & (R[:, 1] >= alo) & (R[:, 1] < ahi)
        cells.append(f'{alo}-{ahi} deg {np.median(R[sel, 2]):+.3f} ({sel.sum()})' if sel.any() else f'{alo}-{ahi} deg -')
    print(f'frames {lo}-{hi}: ' + ' | '.join(cells))
