#!/usr/bin/env bash
# Builds the Python package colslam (crates/python) in the dev profile into
# the venv VENV and runs its tests (crates/python/tests). Part of the README's
# test command (scripts/test.sh calls it with the peer venv, which has numpy
# and pycolmap). The wheel's Rust build shares CARGO_TARGET_DIR with the
# workspace's, so after `cargo test` only the extension module is compiled.
# Usage: scripts/test-python.sh VENV [PYTEST_ARGS...]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${1:?usage: scripts/test-python.sh VENV [PYTEST_ARGS...]}"
shift
cd "$root"
"$venv/bin/python" -m pip install --quiet -r scripts/python-requirements.txt
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$root/target}"
# The binary the tests compare with (`colslam run --help`, `colslam eval`).
cargo build --locked --quiet -p colslam
(
  cd crates/python
  VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH" maturin develop --locked --profile dev --quiet
)
COLSLAM_BIN="$CARGO_TARGET_DIR/debug/colslam" "$venv/bin/python" -m pytest -q crates/python/tests "$@"
