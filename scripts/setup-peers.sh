#!/usr/bin/env bash
# Creates (or updates) the Python venv with the peers colslam is cross-checked
# against: pycolmap (COLMAP models, geometry), evo (trajectory metrics) and
# OpenCV (features). The main job never needs Python; only tests and
# benchmarks use this. Usage: scripts/setup-peers.sh [VENV_DIR] (default .venv)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${1:-$root/.venv}"
req="$root/scripts/peers-requirements.txt"
stamp="$venv/.colslam-peers-stamp"
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && cmp -s "$req" "$stamp"; then
  echo "peers venv up to date: $venv"
  exit 0
fi
python3 -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet -r "$req"
cp "$req" "$stamp"
"$venv/bin/python" -c "import pycolmap, evo, cv2; print('peers venv ready:', pycolmap.__version__, evo.__version__, cv2.__version__)"
