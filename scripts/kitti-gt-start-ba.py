#!/usr/bin/env python3
"""Is the drifted scale the minimum of the map's own observations (issue 20)? Loads a
run's model, bundle adjusts it to convergence as it is (trivial loss, fixed intrinsics,
Ceres to 1e-10), then again from its keyframe poses replaced by the ground truth
(Sim(3)-aligned into the model's frame) with every point re-triangulated from its track
(DLT), and prints the keyframes' ATE and the final cost of both, and how the squared
reprojection error difference splits by track length and by the track's first frame.

    kitti-gt-start-ba.py RUN_FOLDER GROUNDTRUTH.txt     (pycolmap, numpy)

Ground truth rows are taken in frame order (row i = frame i = image name)."""
import pycolmap, numpy as np, sys, os, collections
out, gtp = sys.argv[1], sys.argv[2]
gt = np.loadtxt(gtp, comments='#')
def quat_to_R(q):  # x y z w
    x, y, z, w = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-z*w), 2*(x*z+y*w)], [2*(x*y+z*w), 1-2*(x*x+z*z), 2*(y*z-x*w)], [2*(x*z-y*w), 2*(y*z+x*w), 1-2*(x*x+y*y)]])
def frame(img): return int(os.path.splitext(img.name)[0])
def ate(rec):
    ids = list(rec.images); P = np.array([rec.images[i].projection_center() for i in ids])
    G = np.array([gt[frame(rec.images[i]), 1:4] for i in ids])
    mu_e, mu_g = P.mean(0), G.mean(0); E, Gc = P - mu_e, G - mu_g
    U, S, Vt = np.linalg.svd(Gc.T @ E / len(P)); D = np.eye(3); D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt; s = np.trace(np.diag(S) @ D) / (E ** 2).sum() * len(P)
    a = (s * (R @ P.T)).T + (mu_g - s * R @ mu_e)
    return np.sqrt(((a - G) ** 2).sum(1).mean()), (s, R, mu_g - s * R @ mu_e)
def adjust(rec):
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = False; opts.refine_principal_point = False; opts.refine_extra_params = False
    so = opts.ceres.solver_options; so.function_tolerance = 1e-10; so.gradient_tolerance = 1e-12
    so.parameter_tolerance = 1e-12; so.max_num_iterations = 200
    return pycolmap.bundle_adjustment(rec, opts)
drift = pycolmap.Reconstruction(out)
K = next(iter(drift.cameras.values())).calibration_matrix()
print('model: keyframes', drift.num_reg_images(), 'ATE %.3f m' % ate(drift)[0])
adjust(drift); print('model after BA to convergence: ATE %.3f m' % ate(drift)[0])
rec = pycolmap.Reconstruction(out)
_, (s, R, t) = ate(rec)
for img in rec.images.values():
    f = frame(img); Rwc = R.T @ quat_to_R(gt[f, 4:8]); c = R.T @ (gt[f, 1:4] - t) / s
    rec.frames[img.frame_id].rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(Rwc.T), -Rwc.T @ c)
for p in rec.points3D.values():
    A = []
    for el in p.track.elements:
        img = rec.images[el.image_id]; M = K @ img.cam_from_world().matrix(); u, v = img.points2D[el.point2D_idx].xy
        A += [u * M[2] - M[0], v * M[2] - M[1]]
    X = np.linalg.svd(np.array(A))[2][-1]
    if abs(X[3]) > 1e-12: p.xyz = X[:3] / X[3]
adjust(rec); print('from the ground truth, after BA to convergence: ATE %.3f m' % ate(rec)[0])
def errors(r):
    d = {}
    for pid, p in r.points3D.items():
        e = []
        for el in p.track.elements:
            img = r.images[el.image_id]; uv = K @ (img.cam_from_world() * p.xyz)
            e.append(np.linalg.norm(uv[:2] / uv[2] - img.points2D[el.point2D_idx].xy))
        d[pid] = np.array(e)
    return d
eg, ed = errors(rec), errors(drift)
keep = [p for p in eg if p in ed and len(eg[p]) == len(ed[p]) and eg[p].max() < 30 and ed[p].max() < 30]
n_obs = sum(len(ed[p]) for p in keep)
sg = sum((eg[p] ** 2).sum() for p in keep); sd = sum((ed[p] ** 2).sum() for p in keep)
print(f'{len(keep)} points ({n_obs} observations) below 30 px in both: RMS error drifted {np.sqrt(sd / n_obs):.4f} px, from the ground truth {np.sqrt(sg / n_obs):.4f} px')
by_len, by_first = collections.defaultdict(float), collections.defaultdict(float)
for p in keep:
    fs = sorted(frame(drift.images[e.image_id]) for e in drift.points3D[p].track.elements)
    d = (eg[p] ** 2).sum() - (ed[p] ** 2).sum()
    by_len[min(len(fs), 8)] += d; by_first[fs[0] // 25 * 25] += d
print('squared error, from-ground-truth minus drifted, by track length (8 = 8+):', {k: round(v) for k, v in sorted(by_len.items())})
print('... by the first frame of the track (25-frame bins):', {k: round(v) for k, v in sorted(by_first.items())})
