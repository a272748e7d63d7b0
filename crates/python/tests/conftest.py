"""Fixtures of the Python API tests: the synthetic default sequence (made by
`colslam demo --generate-only`) and one run of colslam.run on it, shared by
the session. COLSLAM_BIN names the `colslam` binary of the same build
(scripts/test-python.sh sets it)."""

import os
import subprocess
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def colslam_bin():
    path = os.environ.get("COLSLAM_BIN")
    if not path or not Path(path).is_file():
        pytest.fail("COLSLAM_BIN must name the colslam binary (scripts/test-python.sh sets it)")
    return path


def cli(colslam_bin, *args):
    """Runs the colslam binary; returns its stdout, fails the test on error."""
    p = subprocess.run([colslam_bin, *map(str, args)], capture_output=True, text=True)
    assert p.returncode == 0, f"colslam {' '.join(map(str, args))} failed:\n{p.stderr}"
    return p.stdout


@pytest.fixture(scope="session")
def demo_seq(tmp_path_factory, colslam_bin):
    """The synthetic default sequence (TUM layout with groundtruth.txt)."""
    seq = tmp_path_factory.mktemp("demo") / "seq"
    cli(colslam_bin, "-q", "demo", "-o", seq, "--generate-only")
    return seq


@pytest.fixture(scope="session")
def demo_run(demo_seq, tmp_path_factory):
    """colslam.run on the synthetic default into a folder, with the progress
    calls it made."""
    import colslam

    out = tmp_path_factory.mktemp("run") / "out"
    calls = []
    result = colslam.run(demo_seq, out, progress=lambda done, total: calls.append((done, total)))
    return result, calls
