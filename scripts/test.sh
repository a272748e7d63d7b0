#!/usr/bin/env bash
# The project's test command (README, .ci/run): prepares the Python peer venv
# used by cross-check tests (pycolmap, evo, OpenCV), then runs every test of
# the workspace and the Python package's (scripts/test-python.sh). Environment:
#   COLSLAM_VENV  where the peer venv lives (default: .venv in the checkout)
#   COLSLAM_DATA  the datasets folder (default: ../shared/datasets)
#   CI=true       data and peer tests must run instead of skipping
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
venv="${COLSLAM_VENV:-$root/.venv}"
if ! "$root/scripts/setup-peers.sh" "$venv"; then
  if [ "${CI:-}" = "true" ]; then
    echo "error: could not set up the peer venv in $venv" >&2
    exit 1
  fi
  echo "warning: peer venv unavailable; cross-check tests will skip" >&2
fi
export COLSLAM_PYTHON="$venv/bin/python"
cargo test --workspace --locked "$@"
# The Python package (crates/python): built into the peer venv (dev profile,
# sharing the build above) and tested with pytest.
if [ -x "$venv/bin/python" ]; then
  "$root/scripts/test-python.sh" "$venv"
elif [ "${CI:-}" = "true" ]; then
  echo "error: no peer venv in $venv for the Python package's tests" >&2
  exit 1
else
  echo "warning: peer venv unavailable; the Python package's tests are skipped" >&2
fi
