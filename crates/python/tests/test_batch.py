"""colslam.batch: Ray batches of runs, resumability, the table, the CLI entry.

One local Ray cluster (2 CPUs, 1 per task) runs three inputs: two copies of
the synthetic default (conftest's demo_seq) in folders both named seq, each
with a frame limit of its own, and a corrupt video. The other tests reuse
that batch's outputs without Ray.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import colslam
from colslam import batch

if os.environ.get("CI") == "true":
    import ray  # in CI the batch test must run, never skip
else:
    ray = pytest.importorskip("ray")

#: Frames of the first input and the second input's own limit: a few
#: seconds of run each on the synthetic default.
LIMIT_A = 30
LIMIT_B = 20


def _copy_sequence(seq: Path, dest: Path) -> Path:
    """A sequence folder of its own (the listing, ground truth and camera
    copied, the images linked), so that two inputs share a folder name."""
    dest.mkdir(parents=True)
    for entry in seq.iterdir():
        if entry.is_dir():
            (dest / entry.name).symlink_to(entry, target_is_directory=True)
        else:
            shutil.copy(entry, dest / entry.name)
    return dest


@pytest.fixture(scope="module")
def first_batch(demo_seq, tmp_path_factory):
    """The batch on a local cluster: (inputs, out_root, rows, seconds). Two
    copies of the synthetic default named seq (frame limits of their own)
    and a corrupt video."""
    root = tmp_path_factory.mktemp("inputs")
    a = _copy_sequence(demo_seq, root / "a" / "seq")
    b = _copy_sequence(demo_seq, root / "b" / "seq")
    broken = root / "broken.mp4"
    broken.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    inputs = [(str(a), {"max_frames": LIMIT_A}), (str(b), {"max_frames": LIMIT_B}), str(broken)]
    out_root = tmp_path_factory.mktemp("batch") / "out"
    t = time.monotonic()
    rows = batch.run_many(inputs, out_root, num_cpus=2, cpus_per_task=1)
    seconds = time.monotonic() - t
    assert not ray.is_initialized(), "the local cluster the call started is stopped"
    return inputs, out_root, rows, seconds


def test_batch_rows(first_batch):
    inputs, out_root, rows, seconds = first_batch
    print(f"first batch: {seconds:.1f} s")
    assert [r["status"] for r in rows] == ["done", "done", "failed"], rows
    a, b, bad = rows
    assert a["input"] == inputs[0][0] and b["input"] == inputs[1][0] and bad["input"] == inputs[2]
    # Both folders are named seq: each gets its own output, neither is "seq".
    names = {Path(a["output"]).name, Path(b["output"]).name}
    assert len(names) == 2 and all(n.startswith("seq-") for n in names)
    assert (a["frames"], a["localized"]) == (LIMIT_A, LIMIT_A), "each input's own options are used"
    assert (b["frames"], b["localized"]) == (LIMIT_B, LIMIT_B)
    for row in (a, b):
        assert row["error"] is None
        assert row["keyframes"] >= 2
        assert row["wall_s"] > 0 and row["peak_rss_mb"] > 0
        # The ATE is colslam.evaluate's on the written trajectory, ground
        # truth found beside the input.
        gt = Path(row["input"]) / "groundtruth.txt"
        ev = colslam.evaluate(str(gt), str(Path(row["output"]) / "trajectory.tum"))
        assert row["ate_m"] == pytest.approx(ev["ate_rmse"], rel=1e-12)
        assert row["ate_m"] < 0.05
    # The bad input fails with the run's own message, and nothing else.
    assert "broken.mp4" in bad["error"], bad["error"]
    assert bad["frames"] is None and bad["ate_m"] is None


def test_batch_outputs(first_batch):
    _, out_root, rows, _ = first_batch
    for row in rows[:2]:
        out = Path(row["output"])
        assert out.parent == out_root
        report = json.loads((out / "report.json").read_text())
        assert report["input"] == row["input"] and report["frames"] == row["frames"]
        trajectory = [
            line
            for line in (out / "trajectory.tum").read_text().splitlines()
            if not line.startswith("#")
        ]
        assert len(trajectory) == row["localized"]
        assert (out / "cameras.bin").is_file() and (out / "points.ply").is_file()
    assert not Path(rows[2]["output"]).exists(), "a failed run leaves no output folder"
    # Only the outputs, the table and the batch's own state: no staging
    # folders, locks or temporary files left behind.
    entries = sorted(p.name for p in out_root.iterdir())
    expected = sorted(
        [Path(r["output"]).name for r in rows[:2]] + [batch.STATE_DIR, "batch.csv", "batch.json"]
    )
    assert entries == expected


def test_batch_table_files(first_batch):
    _, out_root, rows, _ = first_batch
    doc = json.loads((out_root / "batch.json").read_text())
    assert doc["columns"] == list(batch.COLUMNS)
    assert doc["rows"] == rows
    assert doc["counts"] == {"done": 2, "skipped": 0, "failed": 1}
    with open(out_root / "batch.csv", newline="") as f:
        table = list(csv.reader(f))
    assert table[0] == list(batch.COLUMNS)
    assert len(table) == 4
    for line, row in zip(table[1:], rows):
        for column, cell in zip(batch.COLUMNS, line):
            value = row[column]
            if value is None:
                assert cell == ""
            elif isinstance(value, float):
                assert float(cell) == value
            else:
                assert cell == str(value)
    text = batch.format_table(rows)
    lines = text.splitlines()
    assert len(lines) == 4 and lines[0].split()[:3] == ["name", "status", "frames"]
    # Aligned: the status column starts at the same place on every line.
    starts = {
        line.index(status) for line, status in zip(lines, ["status", "done", "done", "failed"])
    }
    assert len(starts) == 1


def test_second_call_skips_without_ray(first_batch):
    inputs, out_root, rows, _ = first_batch
    t = time.monotonic()
    again = batch.run_many(inputs[:2], out_root, num_cpus=2, cpus_per_task=1)
    seconds = time.monotonic() - t
    print(f"second call: {seconds:.2f} s")
    assert [r["status"] for r in again] == ["skipped", "skipped"]
    assert seconds < 10
    assert not ray.is_initialized()
    for old, new in zip(rows, again):
        for column in ("input", "output", "frames", "localized", "keyframes", "ate_m"):
            assert new[column] == old[column], column
    doc = json.loads((out_root / "batch.json").read_text())
    assert doc["counts"] == {"done": 0, "skipped": 2, "failed": 0}


def test_changed_request_is_not_complete(first_batch):
    """An output answers only the same input with the same options: another
    frame limit, another option, a request file that is gone or claims other
    options than report.json records, a report that does not parse each make
    it incomplete (and the input runs again, into the same folder)."""
    inputs, out_root, _, _ = first_batch
    (a, own_a), (b, own_b) = inputs[0], inputs[1]

    def job(b_options=own_b, **shared):
        return batch._resolve([(a, own_a), (b, b_options)], str(out_root), batch.GT_BESIDE, shared)

    assert [batch._complete_report(j) is not None for j in job()] == [True, True]
    changed = job({"max_frames": LIMIT_B + 1})
    assert changed[1].output == job()[1].output, "other options, the same folder"
    assert batch._complete_report(changed[1]) is None
    assert batch._complete_report(job({})[1]) is None
    assert batch._complete_report(job(num_features=500)[0]) is None
    assert batch._complete_report(job(seed=1)[0]) is None

    # A request file claiming options report.json contradicts is not trusted.
    state = Path(job()[0].state)
    saved = state.read_text()
    try:
        doc = json.loads(saved)
        claimed = job(min_tri_angle=3.0)[0]
        doc["request"] = claimed.request
        state.write_text(json.dumps(doc))
        assert batch._complete_report(claimed) is None
        state.unlink()
        assert batch._complete_report(job()[0]) is None
    finally:
        state.write_text(saved)
    report = Path(job()[0].output) / "report.json"
    saved = report.read_text()
    try:
        report.write_text(saved[: len(saved) // 2])
        assert batch._complete_report(job()[0]) is None
        # Another run of the same input and options into the folder (by
        # other means than this batch): the request file is not its own.
        other = json.loads(saved)
        other["wall_time_s"] += 1.0
        report.write_text(json.dumps(other))
        assert batch._complete_report(job()[0]) is None
    finally:
        report.write_text(saved)
    assert batch._complete_report(job()[0]) is not None


def test_cli(first_batch, tmp_path):
    inputs, out_root, _, _ = first_batch
    missing = tmp_path / "missing.mp4"
    (a, _), (b, _) = inputs[0], inputs[1]
    cmd = [
        sys.executable,
        "-m",
        "colslam.batch",
        f"{a}::max_frames={LIMIT_A}",
        f"{b}::max_frames={LIMIT_B}",
        "-o",
        str(out_root),
    ]
    ok = subprocess.run(cmd + ["--cpus-per-task", "1"], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    lines = ok.stdout.splitlines()
    assert (
        len(lines) == 3 and lines[1].split()[1] == "skipped" and lines[2].split()[1] == "skipped"
    ), ok.stdout
    bad = subprocess.run(cmd + [str(missing)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1, bad.stderr
    assert f"{missing}: no such file or folder" in bad.stdout
    usage = subprocess.run(cmd + ["--set", "threads=2"], capture_output=True, text=True, timeout=60)
    assert usage.returncode == 2 and "threads" in usage.stderr


def test_missing_input_fails_without_ray(tmp_path):
    missing = tmp_path / "nowhere" / "clip.mp4"
    rows = batch.run_many([str(missing)], tmp_path / "out")
    assert [r["status"] for r in rows] == ["failed"]
    assert rows[0]["error"] == f"{missing}: no such file or folder"
    assert not ray.is_initialized()
    assert json.loads((tmp_path / "out" / "batch.json").read_text())["rows"] == rows


def test_names_are_unique_and_stable(tmp_path):
    specs = [
        str(tmp_path / "x" / "seq"),
        str(tmp_path / "y" / "seq"),
        str(tmp_path / "clip.mp4"),
        str(tmp_path / "batch.json.mp4"),
    ]
    names = [j.name for j in batch._resolve(specs, str(tmp_path), None, {})]
    reversed_names = [j.name for j in batch._resolve(specs[::-1], str(tmp_path), None, {})][::-1]
    assert names == reversed_names, "a name does not depend on the order"
    assert len(set(names)) == 4
    assert names[2] == "clip" and names[0].startswith("seq-") and names[3].startswith("batch.json-")
    # The name does not depend on the options; one input twice is an error.
    with_options = batch._resolve(specs[:2] + [(specs[2], {"seed": 1})], str(tmp_path), None, {})
    assert [j.name for j in with_options] == names[:3]
    with pytest.raises(ValueError, match="twice"):
        batch._resolve([specs[2], (specs[2], {"seed": 2})], str(tmp_path), None, {})


def test_options_the_batch_sets_are_refused(tmp_path):
    for key in ("threads", "output"):
        with pytest.raises(ValueError, match=key):
            batch.run_many([str(tmp_path)], tmp_path / "out", **{key: 1})
    with pytest.raises(ValueError, match="cpus_per_task"):
        batch.run_many([str(tmp_path)], tmp_path / "out", cpus_per_task=0)
    with pytest.raises(ValueError, match="memory"):
        batch.run_many([str(tmp_path)], tmp_path / "out", memory="lots")
    # An unknown option is refused before anything runs or is written.
    with pytest.raises(colslam.UnknownOptionError, match="'num_feature'"):
        batch.run_many([str(tmp_path)], tmp_path / "out", num_feature=2000)
    with pytest.raises(colslam.UnknownOptionError, match="'max_frame'"):
        batch.run_many([(str(tmp_path), {"max_frame": 3})], tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert (
        batch._parse_memory("2G") == 2 * 1024**3 and batch._parse_memory("512MiB") == 512 * 1024**2
    )
