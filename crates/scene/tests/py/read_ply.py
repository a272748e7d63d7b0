"""Loads a PLY with pycolmap.Reconstruction.import_PLY and prints JSON:
{"n": number of points, "xyz": [[x, y, z] ...], "rgb": [[r, g, b] ...]} by point id."""
import json
import sys

import pycolmap

rec = pycolmap.Reconstruction()
rec.import_PLY(sys.argv[1])
ids = sorted(rec.points3D)
json.dump(
    {
        "n": len(ids),
        "xyz": [[float(v) for v in rec.points3D[i].xyz] for i in ids],
        "rgb": [[int(v) for v in rec.points3D[i].color] for i in ids],
    },
    sys.stdout,
)
