#!/usr/bin/env python3
"""Which local BA changes the scale (issue 20): from the `scale snapshot before-lba-F` /
`after-lba-F` and `scale probe pnp` lines of a `colslam -v run` log
(crates/slam/src/mapper/probe.rs), for every local BA the change it makes to
l_k = log((|c_k - c_p| / |g_k - g_p|) / (|c_p - c_p2| / |g_p - g_p2|)) of each earlier
keyframe k (p, p2: the keyframes before it), summed per segment of the drive by the
offset (in keyframes) of the BA's keyframe after k, and by how many of k, p, p2 that BA
varied.

    kitti-lba-scale.py RUN.log GROUNDTRUTH.txt

Ground truth rows are taken in frame order (row i = frame i)."""
import numpy as np, re, sys, collections
log, gtp = sys.argv[1], sys.argv[2]
g = np.loadtxt(gtp, comments='#')[:, 1:4]
pat = re.compile(r'scale probe pnp frame (\d+): .* centres (.*)')
snap = re.compile(r'scale snapshot (before|after)-lba-(\d+): (.*)')
bund = re.compile(r'scale bundle (\d+): (.*)')
def cs(t): return {int(a.split(':')[0]): np.array(list(map(float, a.split(':')[1].split(',')))) for a in t.split()}
trip, order, before, deltas, bundles = {}, [], None, [], {}
for line in open(log):
    m = pat.search(line)
    if m:
        f = int(m.group(1)); fr = [int(a.split(':')[0]) for a in m.group(2).split()[:3]]
        if len(fr) == 3: trip[f] = fr
        order.append(f); continue
    m = bund.search(line)
    if m: bundles[int(m.group(1))] = list(map(int, m.group(2).split())); continue
    m = snap.search(line)
    if m:
        if m.group(1) == 'before': before = cs(m.group(3))
        else: deltas.append((int(m.group(2)), before, cs(m.group(3))))
def ell(pos, fr):
    if not all(x in pos for x in fr): return np.nan
    k, p, p2 = fr
    s = np.linalg.norm(pos[k] - pos[p]) / np.linalg.norm(g[k] - g[p]); r = np.linalg.norm(pos[p] - pos[p2]) / np.linalg.norm(g[p] - g[p2])
    return np.log(s / r)
segs = [(0, 40), (40, 100), (100, 130), (130, 200), (200, 230), (230, 299)]
def seg(f): return next(i for i, (a, b) in enumerate(segs) if a < f <= b or (i == 0 and f == 0))
tab = collections.defaultdict(float); cnt = collections.Counter()
var_tab = collections.defaultdict(float)
for F, b, a in deltas:
    pf = order.index(F)
    for k, fr in trip.items():
        if k not in a: continue
        d = ell(a, fr) - ell(b, fr)
        if np.isnan(d): continue
        off = pf - order.index(k)
        tab[(seg(k), min(off, 9))] += d
        # where is the step relative to the bundle: both ends variable, one, none
        B = set(bundles.get(F, []))
        var_tab[(seg(k), (fr[0] in B) + (fr[1] in B) + (fr[2] in B))] += d
print('sum of delta l of steps in segment (rows) by local BA of the keyframe `offset` keyframes later (cols; 9 = 9+)')
print('seg      ' + ' '.join(f'{o:7d}' for o in range(1, 10)))
for s in range(6):
    print(f'{segs[s][0]:3d}-{segs[s][1]:3d} ' + ' '.join(f'{tab[(s, o)]:+.4f}' for o in range(1, 10)))
print('by how many of (k, p, p2) were variable in that BA: 0 1 2 3')
for s in range(6):
    print(f'{segs[s][0]:3d}-{segs[s][1]:3d} ' + ' '.join(f'{var_tab[(s, o)]:+.4f}' for o in range(4)))
