#!/usr/bin/env python3
"""Trains an ORB vocabulary for ORB-SLAM3 (DBoW2 text format) from images
that are not the evaluation sequence.

    train_orbvoc.py [--data DIR] [--exclude NAME ...] [--k 10] [--levels 5]
                    [--seed 7] [--out FILE]

ORB-SLAM3 needs a bag-of-words vocabulary (ORBvoc.txt, 139 MB, trained by
its authors on the Bovisa dataset). The `pyorbslam3` wheel does not ship it
and downloads it from GitHub, which the project's peer runs never do. This
script builds an equivalent, smaller one:

* ORB descriptors (OpenCV: 8 levels, scale 1.2, FAST threshold 20, the
  same rBRIEF pattern as ORB-SLAM's extractor) of the training images: every
  `strecha_*/rgb` image and the frames of `twitchslam_kitti984/*.mp4` under
  the datasets folder, skipping the folders named by --exclude;
* a hierarchical k-medians tree (branching k, depth L) on Hamming distance,
  seeded with k-means++ (as DBoW2's HKmeansStep / initiateClustersKMpp, see
  DBoW2 by D. Galvez-Lopez, Thirdparty/DBoW2 in ORB-SLAM3): the centre of a
  cluster is its bitwise majority vote; a node with at most k descriptors
  gets one child per descriptor;
* TF-IDF word weights: idf = ln(N / n_i), N training images, n_i images
  with at least one descriptor quantised to word i;
* the text format read by ORB-SLAM3's
  `TemplatedVocabulary::loadFromTextFile`: a header line "k L scoring
  weighting" (scoring 0 = L1 norm, weighting 0 = TF-IDF), then one line per
  node in id order (breadth first, root excluded): "parent isLeaf d0 .. d31
  weight" with the 32 descriptor bytes as decimal integers. The file has no
  trailing newline (the reader's `while (!eof)` loop would otherwise add an
  empty node).

Deterministic for a given seed and training set. `vocabulary(...)` caches the
result under the peer venv (`<venv>/share/colslam/orbvoc/`), keyed by a hash
of the parameters and the training files' names and sizes.
"""

import argparse
import glob
import hashlib
import os
import sys
import tempfile
import time

import numpy as np

DESC_BYTES = 32
SCORING_L1 = 0
WEIGHTING_TF_IDF = 0
DEFAULT_K = 10
DEFAULT_LEVELS = 5
DEFAULT_SEED = 7
MAX_ITERATIONS = 15
# Features per image: Strecha images are 1536x1024, the KITTI frames 1242x375.
STRECHA_FEATURES = 2000
VIDEO_FEATURES = 1000
# Training version: bump when the algorithm changes so caches are rebuilt.
TRAINER_VERSION = 1


def default_data_dir():
    env = os.environ.get("COLSLAM_DATA")
    if env:
        return env
    here = os.path.dirname(os.path.abspath(__file__))
    for cand in (os.path.join(here, "..", "..", "datasets"), os.path.join(here, "..", "..", "..", "shared", "datasets")):
        if os.path.isdir(cand):
            return os.path.normpath(cand)
    return "datasets"


def training_sources(data, exclude):
    """(kind, path) of every training input: image files and videos."""
    excl = {os.path.basename(os.path.normpath(e)) for e in exclude}
    out = []
    for d in sorted(glob.glob(os.path.join(data, "strecha_*"))):
        if os.path.basename(d) in excl:
            continue
        for p in sorted(glob.glob(os.path.join(d, "rgb", "*"))):
            if p.lower().endswith((".jpg", ".jpeg", ".png")):
                out.append(("image", p))
    for d in sorted(glob.glob(os.path.join(data, "twitchslam_kitti*"))):
        if os.path.basename(d) in excl:
            continue
        for p in sorted(glob.glob(os.path.join(d, "*.mp4"))):
            out.append(("video", p))
    return out


def extract(sources, log):
    """ORB descriptors per training image: a list of (n_i, 32) uint8 arrays."""
    import cv2

    cv2.setNumThreads(1)
    per_image = []
    for kind, path in sources:
        if kind == "image":
            img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            if img is None:
                log(f"skipping unreadable {path}")
                continue
            frames = [img]
            n = STRECHA_FEATURES
        else:
            cap = cv2.VideoCapture(path)
            frames = []
            while True:
                ok, f = cap.read()
                if not ok:
                    break
                frames.append(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY))
            cap.release()
            n = VIDEO_FEATURES
        orb = cv2.ORB_create(nfeatures=n, scaleFactor=1.2, nlevels=8, edgeThreshold=19, fastThreshold=20)
        for img in frames:
            _, d = orb.detectAndCompute(img, None)
            if d is not None and len(d):
                per_image.append(np.ascontiguousarray(d, dtype=np.uint8))
        log(f"{path}: {len(frames)} image(s)")
    return per_image


def hamming(words, centres):
    """(n, k) Hamming distances between (n, 4) and (k, 4) uint64 rows."""
    return np.bitwise_count(words[:, None, :] ^ centres[None, :, :]).sum(axis=2, dtype=np.int32)


def majority(bits):
    """Bitwise majority (ties set the bit, as DBoW2's FORB::meanValue) of (m, 256) bits, packed to 32 bytes."""
    m = bits.shape[0]
    need = m // 2 + m % 2
    return np.packbits(bits.sum(axis=0, dtype=np.int32) >= need)


def kmedians(words, bits, k, rng):
    """Cluster labels (n,) of one k-medians step; k-means++ seeding on Hamming distance."""
    n = words.shape[0]
    first = int(rng.integers(n))
    idx = [first]
    dmin = hamming(words, words[first : first + 1])[:, 0].astype(np.float64)
    while len(idx) < k:
        w = dmin * dmin
        total = w.sum()
        if total <= 0:
            break  # all remaining descriptors equal a centre
        nxt = int(rng.choice(n, p=w / total))
        idx.append(nxt)
        dmin = np.minimum(dmin, hamming(words, words[nxt : nxt + 1])[:, 0])
    centres = words[idx]
    labels = None
    for _ in range(MAX_ITERATIONS):
        new = np.argmin(hamming(words, centres), axis=1)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        packed = []
        for c in range(len(centres)):
            members = labels == c
            if members.any():
                packed.append(majority(bits[members]))
            else:
                packed.append(np.frombuffer(centres[c].tobytes(), dtype=np.uint8))
        centres = np.ascontiguousarray(np.stack(packed)).view(np.uint64)
    # Drop empty clusters (possible when seeds coincide).
    used = sorted(set(labels.tolist()))
    remap = {c: i for i, c in enumerate(used)}
    return np.array([remap[c] for c in labels.tolist()], dtype=np.int64), centres[used]


def build_tree(desc, k, levels, rng, log):
    """Nodes as (parent, descriptor bytes, member indices); node 0 is the root."""
    words = np.ascontiguousarray(desc).view(np.uint64)  # (n, 4)
    bits = np.unpackbits(desc, axis=1)  # (n, 256)
    parents = [-1]
    descs = [np.zeros(DESC_BYTES, dtype=np.uint8)]
    children = [[]]
    queue = [(0, np.arange(desc.shape[0]), 0)]  # (node, members, level)
    head = 0
    while head < len(queue):
        node, members, level = queue[head]
        head += 1
        if level >= levels or len(members) == 0:
            continue
        if len(members) <= k:
            groups = [(members[i : i + 1], desc[members[i]]) for i in range(len(members))]
        else:
            labels, centres = kmedians(words[members], bits[members], k, rng)
            cbytes = centres.view(np.uint8).reshape(-1, DESC_BYTES)
            groups = [(members[labels == c], cbytes[c]) for c in range(len(cbytes))]
        for m, d in groups:
            nid = len(parents)
            parents.append(node)
            descs.append(np.array(d, dtype=np.uint8))
            children.append([])
            children[node].append(nid)
            queue.append((nid, m, level + 1))
        if head % 2000 == 0:
            log(f"  {head} nodes expanded, {len(parents)} nodes")
    return parents, descs, children


def quantise(desc, descs, children):
    """Leaf node id of every descriptor, descending the tree greedily (as DBoW2's transform)."""
    words = np.ascontiguousarray(desc).view(np.uint64)
    node = np.zeros(desc.shape[0], dtype=np.int64)
    table = np.ascontiguousarray(np.stack(descs)).view(np.uint64)  # (nodes, 4)
    inner = np.array([len(c) > 0 for c in children])
    active = inner[node]
    while active.any():
        idx = np.where(active)[0]
        order = idx[np.argsort(node[idx], kind="stable")]
        parents, starts = np.unique(node[order], return_index=True)
        bounds = list(starts) + [len(order)]
        for i, parent in enumerate(parents):
            sel = order[bounds[i] : bounds[i + 1]]
            ch = np.array(children[parent])
            node[sel] = ch[np.argmin(hamming(words[sel], table[ch]), axis=1)]
        active = inner[node]
    return node


def train(per_image, k, levels, seed, log):
    """The vocabulary as text (no trailing newline)."""
    rng = np.random.default_rng(seed)
    desc = np.concatenate(per_image)
    log(f"training on {desc.shape[0]} descriptors of {len(per_image)} images, k={k} L={levels}")
    parents, descs, children = build_tree(desc, k, levels, rng, log)
    leaf = [len(c) == 0 for c in children]
    # Document frequency of every leaf.
    image_of = np.concatenate([np.full(len(d), i, dtype=np.int64) for i, d in enumerate(per_image)])
    leaf_of = quantise(desc, descs, children)
    pairs = np.unique(image_of * len(parents) + leaf_of)
    df = np.bincount(pairs % len(parents), minlength=len(parents))
    n_img = len(per_image)
    lines = [f"{k} {levels} {SCORING_L1} {WEIGHTING_TF_IDF}"]
    n_words = 0
    for nid in range(1, len(parents)):
        if leaf[nid]:
            n_words += 1
            weight = float(np.log(n_img / df[nid])) if df[nid] > 0 else float(np.log(n_img))
        else:
            weight = 0.0
        d = " ".join(str(int(b)) for b in descs[nid])
        lines.append(f"{parents[nid]} {1 if leaf[nid] else 0} {d} {weight:.6g}")
    log(f"{len(parents) - 1} nodes, {n_words} words")
    return "\n".join(lines)


def cache_dir():
    return os.path.join(sys.prefix, "share", "colslam", "orbvoc")


def cache_key(sources, k, levels, seed):
    h = hashlib.sha1()
    h.update(f"v{TRAINER_VERSION} k{k} L{levels} s{seed} {STRECHA_FEATURES} {VIDEO_FEATURES}\n".encode())
    for kind, p in sources:
        h.update(f"{kind} {os.path.basename(os.path.dirname(p))}/{os.path.basename(p)} {os.path.getsize(p)}\n".encode())
    return h.hexdigest()[:16]


def write_atomic(path, text):
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".orbvoc-", dir=d)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def vocabulary(data=None, exclude=(), k=DEFAULT_K, levels=DEFAULT_LEVELS, seed=DEFAULT_SEED, out=None, log=None):
    """Path of a trained vocabulary (cached); trains it when missing. Returns (path, trained_now)."""
    log = log or (lambda s: print(s, file=sys.stderr))
    data = data or default_data_dir()
    sources = training_sources(data, exclude)
    if not sources:
        raise FileNotFoundError(f"no training images (strecha_*/rgb, twitchslam_kitti*/*.mp4) under {data}")
    path = out or os.path.join(cache_dir(), f"ORBvoc-colslam-{cache_key(sources, k, levels, seed)}.txt")
    if os.path.isfile(path) and out is None:
        return path, False
    t0 = time.time()
    text = train(extract(sources, log), k, levels, seed, log)
    write_atomic(path, text)
    log(f"vocabulary written to {path} in {time.time() - t0:.1f} s")
    return path, True


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="datasets folder (default $COLSLAM_DATA, else ../shared/datasets)")
    ap.add_argument("--exclude", action="append", default=[], help="dataset folder name not to train on")
    ap.add_argument("--k", type=int, default=DEFAULT_K)
    ap.add_argument("--levels", type=int, default=DEFAULT_LEVELS)
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--out", help="output file (default: the cache under the venv)")
    a = ap.parse_args()
    if not 2 <= a.k <= 20 or not 1 <= a.levels <= 10:
        sys.exit("ORB-SLAM3 reads 2 <= k <= 20 and 1 <= L <= 10 only")
    path, _ = vocabulary(a.data, a.exclude, a.k, a.levels, a.seed, a.out)
    print(path)


if __name__ == "__main__":
    main()
