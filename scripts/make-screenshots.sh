#!/usr/bin/env bash
# Makes the README's pictures of real runs with the viewer's screenshot mode
# (`colslam view MODEL --screenshot`): a run on Strecha fountain-P11 and on
# the TUM fr1_rpy subset, each shown as the reconstruction with its
# frustums and path and the frame panel with the latest camera's keypoints.
# Deterministic: the runs are seeded and the screenshot mode draws once on
# virtual time, so the same binary gives the same pictures.
#
#   scripts/make-screenshots.sh            # writes docs/screenshots/run-*.png
# Environment: COLSLAM (binary; default target/release/colslam), COLSLAM_DATA
# (datasets; default ../shared/datasets beside the checkout), COLSLAM_CHROMIUM (Chromium),
# SIZE (default 1400x900).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="${COLSLAM:-$root/target/release/colslam}"
data="${COLSLAM_DATA:-$root/../shared/datasets}"
size="${SIZE:-1400x900}"
out="$root/docs/screenshots"
[ -x "$bin" ] || { echo "no colslam binary at $bin (cargo build --release -p colslam, or set COLSLAM)" >&2; exit 1; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkdir -p "$out"

shoot() { # name input extra-run-args... ; view args come from $view_args
  local name="$1" input="$2"; shift 2
  [ -e "$input" ] || { echo "missing dataset $input" >&2; exit 1; }
  "$bin" -q run "$input" -o "$work/$name" "$@"
  # The run folder holds the model and report.json, which names the input
  # frames, so the frame panel finds the images itself.
  "$bin" -q view "$work/$name" --screenshot "$out/run-$name.png" --size "$size" ${view_args:-}
  echo "wrote $out/run-$name.png"
}

view_args="" shoot fountain "$data/strecha_fountain_P11"
view_args="--gt $data/tum_fr1_rpy_sub/groundtruth.txt" shoot tum-rpy "$data/tum_fr1_rpy_sub"
