#!/usr/bin/env python3
"""Which stage changes the scale (issue 20): reads the `scale probe` lines of a
`colslam -v run` log (crates/slam/src/mapper/probe.rs) and the run's keyframes.tum,
and for each keyframe k with previous keyframes p, p2 (in registration order)
prints l = log((|c_k - c_p| / |g_k - g_p|) / (|c_p - c_p2| / |g_p - g_p2|)), the
change of scale from the previous step to this one, as it stood after PnP, after
local BA and in the final model, with the probe's point statistics. Sums of l over
a range of keyframes telescope: in the final model they are the log scale change
over the range; the pnp column says how much of it registration made, lba-pnp how
much its local BA added, then the later local BAs (up to each global
refinement), the global refinements, and what changed after the last one.

    kitti-stage-scale.py RUN.log RUN_FOLDER GROUNDTRUTH.txt [FROM-TO ...]

Ground truth rows are taken in frame order (row i = frame i)."""
import numpy as np, re, sys, os
log, out, gtp = sys.argv[1:4]
ranges = [tuple(map(int, r.split('-'))) for r in sys.argv[4:]] or [(0, 40), (40, 100), (100, 130), (130, 200), (200, 230), (230, 299)]
g = np.loadtxt(gtp, comments='#')[:, 1:4]
kf = np.loadtxt(os.path.join(out, 'keyframes.tum'), comments='#')
gt_t = np.loadtxt(gtp, comments='#')[:, 0]
final = {int(np.argmin(abs(gt_t - r[0]))): r[1:4] for r in kf}
pat = re.compile(r'scale probe (\w+) frame (\d+): points (\d+) angle (\S+) depth/baseline (\S+) centres (.*)')
snap = re.compile(r'scale snapshot (before-global|after-global): (.*)')
def centres(text):
    return [(int(a.split(':')[0]), np.array(list(map(float, a.split(':')[1].split(','))))) for a in text.split()]
probes, events = {}, []  # events: (kind, data) in log order
for line in open(log):
    m = pat.search(line)
    if m:
        st, f = m.group(1), int(m.group(2))
        probes.setdefault(f, {})[st] = dict(n=int(m.group(3)), angle=float(m.group(4)), depth=float(m.group(5)), cs=centres(m.group(6)))
        if st == 'lba': events.append(('lba', f))
        continue
    m = snap.search(line)
    if m: events.append((m.group(1), dict(centres(m.group(2)))))
def ell(cs):
    if len(cs) < 3: return np.nan
    (k, ck), (p, cp), (p2, cp2) = cs[:3]
    s = np.linalg.norm(ck - cp) / max(np.linalg.norm(g[k] - g[p]), 1e-9)
    r = np.linalg.norm(cp - cp2) / max(np.linalg.norm(g[p] - g[p2]), 1e-9)
    return np.log(s / r)
def at(pos, frames):
    return ell([(x, pos[x]) for x in frames]) if all(x in pos for x in frames) else np.nan
rows = []
print('frame  prev  pnp    lba    l-later global  end    final | pnp-inl angle d/b | new angle d/b | lba-kept')
for i, (kind, f) in enumerate(events):
    if kind != 'lba': continue
    pr = probes[f]
    if 'pnp' not in pr: continue
    cs = pr['pnp']['cs']
    frames = [c[0] for c in cs[:3]]
    lp, ll = ell(cs), ell(pr['lba']['cs'])
    cur, later, glob = ll, 0.0, 0.0
    for kind2, pos in events[i + 1:]:
        if kind2 == 'lba': continue
        v = at(pos, frames)
        if np.isnan(v): continue
        if kind2 == 'before-global': later += v - cur
        else: glob += v - cur
        cur = v
    lf = at(final, frames)
    rows.append((f, lp, ll - lp, later, glob, lf - cur, lf))
    t, a = pr.get('tri', pr['pnp']), pr['lba']
    print(f"{f:5d} {frames[1] if len(frames) > 1 else -1:5d} {lp:+.3f} {ll - lp:+.3f} {later:+.3f} {glob:+.3f} {lf - cur:+.3f} {lf:+.3f} | {pr['pnp']['n']:4d} {pr['pnp']['angle']:5.2f} {pr['pnp']['depth']:6.1f} | {t['n']:4d} {t['angle']:5.2f} {t['depth']:6.1f} | {a['n']:4d}")
rows = np.array(rows)
print('\nrange: sums of l (log scale change) by stage: registration (PnP), its local BA, later local BAs, global BAs, after the last global BA; final; exp(final)')
for a, b in ranges:
    sel = (rows[:, 0] > a) & (rows[:, 0] <= b)
    s = np.nansum(rows[sel, 1:], axis=0)
    print(f'{a:3d}-{b:3d}: n {sel.sum():3d}  pnp {s[0]:+.3f}  lba {s[1]:+.3f}  later-lba {s[2]:+.3f}  global {s[3]:+.3f}  end {s[4]:+.3f}  final {s[5]:+.3f}  (x{np.exp(s[5]):.3f})')
