#!/usr/bin/env python3
"""Does the focal length alone move KITTI's scale steps (issue 20)? Bundle adjusts a run's
model with the same observations to convergence (trivial loss, intrinsics held) once with
its own camera and once with each focal length given, and prints for each the final RMS
reprojection error, the keyframes' ATE after one Sim(3) and the scale of each segment
(aligned keyframe displacement over the true one between the segment's end frames).

    kitti-focal-ba.py RUN_FOLDER GROUNDTRUTH.txt [FX[,FY] ...]    (pycolmap, numpy)

Ground truth rows are taken in frame order (row i = frame i = image name)."""
import pycolmap, numpy as np, sys, os
out, gtp = sys.argv[1], sys.argv[2]
gt = np.loadtxt(gtp, comments='#')
segments = [(0, 40), (40, 100), (100, 130), (130, 200), (200, 230), (230, 299)]
def frame(img): return int(os.path.splitext(img.name)[0])
def adjust(rec):
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = False; opts.refine_principal_point = False; opts.refine_extra_params = False
    so = opts.ceres.solver_options; so.function_tolerance = 1e-10; so.max_num_iterations = 200
    so.minimizer_progress_to_stdout = False
    pycolmap.bundle_adjustment(rec, opts)
def rms(rec):
    """RMS reprojection error of the observations below 30 px (a few points end behind or
    at a camera after the focal length changed), and how many those are."""
    K = next(iter(rec.cameras.values())).calibration_matrix(); e = []
    for p in rec.points3D.values():
        for el in p.track.elements:
            img = rec.images[el.image_id]; uv = K @ (img.cam_from_world() * p.xyz)
            e.append(np.linalg.norm(uv[:2] / uv[2] - img.points2D[el.point2D_idx].xy) if uv[2] > 0 else np.inf)
    e = np.array(e); ok = e < 30
    return np.sqrt((e[ok] ** 2).mean()), ok.sum(), len(e)
def report(rec, label):
    ids = sorted(rec.images, key=lambda i: frame(rec.images[i]))
    F = np.array([frame(rec.images[i]) for i in ids])
    P = np.array([rec.images[i].projection_center() for i in ids]); G = gt[F, 1:4]
    mu_e, mu_g = P.mean(0), G.mean(0); E, Gc = P - mu_e, G - mu_g
    U, S, Vt = np.linalg.svd(Gc.T @ E / len(P)); D = np.eye(3); D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt; s = np.trace(np.diag(S) @ D) / (E ** 2).sum() * len(P)
    a = (s * (R @ P.T)).T + (mu_g - s * R @ mu_e)
    ate = np.sqrt(((a - G) ** 2).sum(1).mean())
    def scale(i, j):
        ki, kj = np.argmin(abs(F - i)), np.argmin(abs(F - j))
        return np.linalg.norm(a[kj] - a[ki]) / max(np.linalg.norm(G[kj] - G[ki]), 1e-9)
    segs = ' / '.join(f'{scale(i, j):.3f}' for i, j in segments)
    r, n, m = rms(rec)
    print(f'{label}: RMS {r:.4f} px ({n} of {m} observations below 30 px), keyframe ATE {ate:.3f} m, scale {segs}')
rec = pycolmap.Reconstruction(out)
cam = next(iter(rec.cameras.values()))
adjust(rec); report(rec, f'own camera {list(np.round(cam.params[:2], 2))}')
for arg in sys.argv[3:]:
    f = [float(x) for x in arg.split(',')]
    rec = pycolmap.Reconstruction(out)
    cam = next(iter(rec.cameras.values())); p = cam.params.copy(); p[0], p[1] = f[0], f[-1]; cam.params = p
    adjust(rec); report(rec, f'focal {f[0]}, {f[-1]}')
