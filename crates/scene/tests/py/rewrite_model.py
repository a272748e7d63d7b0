"""Reads a model with pycolmap and writes it again: rewrite_model.py SRC DST bin|txt"""
import sys
from pathlib import Path

import pycolmap

rec = pycolmap.Reconstruction(sys.argv[1])
Path(sys.argv[2]).mkdir(parents=True, exist_ok=True)
if sys.argv[3] == "bin":
    rec.write_binary(sys.argv[2])
else:
    rec.write_text(sys.argv[2])
