"""Prints a COLMAP model, as pycolmap loads it, as canonical JSON.

Usage: dump_model.py MODEL_DIR [auto|bin|txt]

Floats are given as their IEEE-754 bit patterns (u64) so comparisons are
exact. Layout (matched by crates/scene/tests/common/mod.rs):
  cameras: [[id, model, width, height, [param bits]]]            by id
  images:  [[id, name, camera_id, has_pose, [qw qx qy qz tx ty tz bits],
             [[x bits, y bits, point3D id or -1]]]]               by id
  points:  [[id, [x y z bits], [r, g, b], error bits, [[image_id, point2D_idx]]]]
  reg_images: registered image ids, sorted
"""
import json
import struct
import sys

import pycolmap

INVALID = 2**64 - 1


def bits(x):
    return struct.unpack("<Q", struct.pack("<d", float(x)))[0]


def main():
    path = sys.argv[1]
    mode = sys.argv[2] if len(sys.argv) > 2 else "auto"
    rec = pycolmap.Reconstruction()
    if mode == "bin":
        rec.read_binary(path)
    elif mode == "txt":
        rec.read_text(path)
    else:
        rec.read(path)
    cameras = []
    for cid in sorted(rec.cameras):
        c = rec.cameras[cid]
        cameras.append([cid, c.model.name, c.width, c.height, [bits(p) for p in c.params]])
    images = []
    for iid in sorted(rec.images):
        im = rec.images[iid]
        pose = []
        if im.has_pose:
            T = im.cam_from_world()
            x, y, z, w = T.rotation.quat
            pose = [bits(v) for v in (w, x, y, z, *T.translation)]
        pts = []
        for p in im.points2D:
            pid = p.point3D_id
            pts.append([bits(p.xy[0]), bits(p.xy[1]), -1 if pid == INVALID else pid])
        images.append([iid, im.name, im.camera_id, bool(im.has_pose), pose, pts])
    points = []
    for pid in sorted(rec.points3D):
        p = rec.points3D[pid]
        track = [[e.image_id, e.point2D_idx] for e in p.track.elements]
        points.append([pid, [bits(v) for v in p.xyz], [int(c) for c in p.color], bits(p.error), track])
    json.dump(
        {
            "cameras": cameras,
            "images": images,
            "points": points,
            "reg_images": sorted(rec.reg_image_ids()),
        },
        sys.stdout,
    )


if __name__ == "__main__":
    main()
