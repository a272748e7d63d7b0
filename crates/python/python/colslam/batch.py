"""Batch runs on Ray: many videos or image sequences, one Ray task each.

``run_many(inputs, out_root, ...)`` runs :func:`colslam.run` on every input as
one Ray task (a local cluster when no address is given), writes each run into
``out_root/<name>`` (the run stages its folder and swaps it in whole), skips
inputs whose output is already complete (resumable), and returns and writes a
table of the outcomes (``out_root/batch.csv``, ``out_root/batch.json``). One
failing input never stops the others: its row says ``failed`` with the
message.

The same from a shell::

    python -m colslam.batch INPUT... -o OUT_ROOT [--cpus-per-task N] [--set key=value ...]

See docs/batch.md.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import itertools
import json
import logging
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

__all__ = ["run_many", "format_table", "main", "COLUMNS", "GT_BESIDE"]

log = logging.getLogger("colslam.batch")

#: The table's columns, in order (``batch.csv``'s header, ``batch.json``'s row keys).
COLUMNS = (
    "input",
    "output",
    "status",
    "frames",
    "localized",
    "keyframes",
    "ate_m",
    "wall_s",
    "peak_rss_mb",
    "error",
)

#: ``gt`` value meaning: ground truth is ``groundtruth.txt`` in the sequence's
#: folder (the input folder, or the folder holding the video), when it exists.
GT_BESIDE = "beside"

#: The file ``GT_BESIDE`` looks for.
GT_FILE = "groundtruth.txt"

#: Files of the batch itself in ``out_root``; an input's name never takes one.
TABLE_CSV = "batch.csv"
TABLE_JSON = "batch.json"

#: Hidden folder in ``out_root`` holding, per output, what the batch asked
#: for (the request a finished output answered): the resumability check
#: compares it, because report.json does not record every option (frame
#: skip and limit, the text model, the camera file).
STATE_DIR = ".colslam-batch"

#: Keywords of ``colslam.run`` that the batch sets itself.
_RESERVED = ("output", "threads", "progress")

InputSpec = Union[str, "os.PathLike[str]", Tuple[Union[str, "os.PathLike[str]"], Mapping[str, Any]]]


@dataclass
class _Job:
    """One input of the batch, resolved."""

    input: str  # absolute path, as given to colslam.run and recorded in report.json
    name: str  # folder name under out_root
    output: str  # absolute output folder
    options: Dict[str, Any]  # colslam.run keywords (camera included, threads excluded)
    gt: Optional[str]  # ground-truth file when one is used
    state: str  # the request file in STATE_DIR
    request: Dict[str, Any] = field(default_factory=dict)


def run_many(
    inputs: Iterable[InputSpec],
    out_root: Union[str, "os.PathLike[str]"],
    *,
    address: Optional[str] = None,
    cpus_per_task: int = 2,
    memory: Union[int, str, None] = None,
    num_cpus: Optional[int] = None,
    gt: Union[str, "os.PathLike[str]", None] = GT_BESIDE,
    **options: Any,
) -> List[Dict[str, Any]]:
    """Runs :func:`colslam.run` on every input as one Ray task; returns the table.

    Args:
        inputs: videos or image-sequence folders; an item may be a pair
            ``(input, {option: value})`` whose options (``camera``, ``gt`` and any
            :func:`colslam.run` option, e.g. ``preset="kitti-984"``) override
            the shared ones for that input.
        out_root: folder of the outputs: ``out_root/<name>`` per input, where
            ``<name>`` is the folder's name or the video's stem; inputs sharing
            a name get ``<name>-<8 hex digits of a hash of the absolute input
            path>`` instead, so a name depends neither on the order nor on the
            options (other options rerun into the same folder). With
            a Ray cluster of several machines it must be a shared file system
            at the same path on every node.
        address: ``None`` starts a local Ray cluster for the call and stops it
            after (unless ``RAY_ADDRESS`` is set, as in a Ray job: then that
            cluster); ``"auto"`` joins the cluster this machine belongs to
            (``ray start`` ran here); ``"ray://HOST:10001"`` connects through
            Ray Client. When Ray is already initialised in this process, that
            connection is used.
        cpus_per_task: CPUs one task reserves; the run uses as many threads.
        memory: memory one task reserves in Ray's scheduler, bytes or a string
            such as ``"2G"`` (Ray does not cap the process; it only packs fewer
            tasks on a node). Default: none reserved.
        num_cpus: CPUs of the local cluster (``address=None``); default: every
            core of this machine.
        gt: ``"beside"`` (the default) evaluates against ``groundtruth.txt``
            in the sequence's folder when there is one; a path evaluates every
            input against that file; ``None`` evaluates nothing. The ATE is
            :func:`colslam.evaluate`'s ``ate_rmse`` (the numbers of
            ``colslam eval``) on the output's ``trajectory.tum``.
        **options: :func:`colslam.run`'s options (``camera``, ``num_features``,
            ``max_frames``, ...), the same names, checked by it.

    Returns:
        One dict per input, in input order, keys :data:`COLUMNS`: ``status`` is
        ``"done"`` (run now), ``"skipped"`` (a complete output of the same
        input and options was there) or ``"failed"`` (``error`` says why);
        ``frames``, ``localized``, ``keyframes`` from report.json; ``ate_m``
        when ground truth was found; ``wall_s`` the run's time (a skipped
        row: the earlier run's, from its report); ``peak_rss_mb`` the task's
        peak resident memory (runs of this call only). The same table is
        written to ``out_root/batch.csv`` and ``out_root/batch.json``
        (each atomically) and printed aligned on stdout.

    Raises:
        colslam.UnknownOptionError: an option colslam.run does not have (a
            TypeError and a ValueError), before anything runs.
        ValueError: an option the batch sets itself (``output``, ``threads``),
            two identical inputs, ``cpus_per_task`` below 1 or above what a node
            of the cluster has, a bad ``memory``.
    """
    started = time.monotonic()
    if cpus_per_task < 1:
        raise ValueError(f"cpus_per_task must be at least 1, got {cpus_per_task}")
    memory_bytes = _parse_memory(memory)
    out_root = os.path.abspath(os.fspath(out_root))
    jobs = _resolve(inputs, out_root, gt, options)
    _check_option_names(jobs)
    os.makedirs(os.path.join(out_root, STATE_DIR), exist_ok=True)

    rows: Dict[int, Dict[str, Any]] = {}
    pending: List[int] = []
    for i, job in enumerate(jobs):
        if not os.path.exists(job.input):
            # Checked here so that a batch whose other inputs are all complete
            # does not start Ray for an input that cannot run.
            rows[i] = _failed(job, f"{job.input}: no such file or folder")
            continue
        report = _complete_report(job)
        if report is not None:
            rows[i] = _skipped(job, report)
        else:
            pending.append(i)
    for i in sorted(rows):
        if rows[i]["status"] == "failed":
            log.warning("%s failed: %s", jobs[i].name, rows[i]["error"])
        else:
            log.info("%s: complete, skipped", jobs[i].name)
    if pending:
        log.info(
            "%d of %d inputs to run on Ray (%d CPUs each)", len(pending), len(jobs), cpus_per_task
        )
        for i, row in _run_on_ray(
            [jobs[i] for i in pending], pending, address, cpus_per_task, memory_bytes, num_cpus
        ):
            rows[i] = row
    table = [rows[i] for i in range(len(jobs))]
    _write_table(table, out_root, time.monotonic() - started)
    print(format_table(table), flush=True)
    return table


def _resolve(
    inputs: Iterable[InputSpec], out_root: str, gt: Any, shared: Mapping[str, Any]
) -> List[_Job]:
    """Turns the inputs into jobs: absolute paths, merged options, unique names."""
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    for key in _RESERVED:
        if key in shared:
            raise ValueError(f"run_many sets {key!r} itself ({_reserved_reason(key)})")
    specs: List[Tuple[str, Dict[str, Any], Any]] = []
    for item in inputs:
        if isinstance(item, tuple):
            if len(item) != 2 or not isinstance(item[1], Mapping):
                raise ValueError(f"an input pair is (path, {{option: value}}), got {item!r}")
            path, own = item
        else:
            path, own = item, {}
        for key in _RESERVED:
            if key in own:
                raise ValueError(f"run_many sets {key!r} itself ({_reserved_reason(key)})")
        merged = {**shared, **own}
        input_gt = merged.pop("gt", gt)
        specs.append((os.path.abspath(os.fspath(path)), merged, input_gt))

    bases = [_base_name(path) for path, _, _ in specs]
    taken: Dict[str, int] = {}
    for base in bases:
        taken[base] = taken.get(base, 0) + 1
    jobs = []
    seen: Dict[str, str] = {}
    for (path, merged, input_gt), base in zip(specs, bases):
        name = base
        if taken[base] > 1 or base in (TABLE_CSV, TABLE_JSON):
            name = f"{base}-{hashlib.sha1(path.encode()).hexdigest()[:8]}"
        if name in seen:
            raise ValueError(
                f"input given twice: {path} (one output folder per input; use another out_root)"
            )
        seen[name] = path
        output = os.path.join(out_root, name)
        options = {
            k: (os.path.abspath(os.fspath(v)) if k == "camera" and v is not None else v)
            for k, v in merged.items()
        }
        job = _Job(
            path,
            name,
            output,
            options,
            _ground_truth(path, input_gt),
            os.path.join(out_root, STATE_DIR, name + ".json"),
        )
        job.request = {"input": path, "options": _jsonable(options)}
        jobs.append(job)
    return jobs


def _check_option_names(jobs: Sequence[_Job]) -> None:
    """Refuses an option colslam.run does not have before any task starts
    (its values are checked by colslam.run, in the task: every input fails
    with its message)."""
    import colslam

    known = set(colslam.option_names()) | {"camera"}
    for job in jobs:
        for key in job.options:
            if key not in known:
                raise colslam.UnknownOptionError(
                    f"colslam.run has no option {key!r}; colslam.option_names() lists them"
                )


def _reserved_reason(key: str) -> str:
    return {
        "output": "out_root/<name> per input",
        "threads": "from cpus_per_task",
        "progress": "tasks run in other processes",
    }[key]


def _base_name(path: str) -> str:
    """The folder's name, or a file's name without its extension; only
    characters safe in a folder name, never hidden."""
    name = os.path.basename(path.rstrip(os.sep)) or "input"
    if not os.path.isdir(path):
        stem, _ = os.path.splitext(name)
        name = stem or name
    name = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return name or "input"


def _ground_truth(path: str, gt: Any) -> Optional[str]:
    if gt is None or gt is False:
        return None
    if gt == GT_BESIDE:
        folder = path if os.path.isdir(path) else os.path.dirname(path)
        candidate = os.path.join(folder, GT_FILE)
        return candidate if os.path.isfile(candidate) else None
    return os.path.abspath(os.fspath(gt))


def _jsonable(value: Any) -> Any:
    """Options as JSON stores them (paths as strings, tuples as lists), so a
    request read back compares equal to a fresh one."""
    return json.loads(json.dumps(value, sort_keys=True, default=os.fspath))


def _parse_memory(memory: Union[int, str, None]) -> Optional[int]:
    if memory is None:
        return None
    if isinstance(memory, int) and memory > 0:
        return memory
    if isinstance(memory, str):
        m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]?)i?B?\s*", memory, re.IGNORECASE)
        if m:
            unit = m.group(2).upper()
            scale = 1024 ** ("KMGT".index(unit) + 1) if unit else 1
            value = int(float(m.group(1)) * scale)
            if value > 0:
                return value
    raise ValueError(f"memory is a positive number of bytes or a size such as '2G', got {memory!r}")


# Resumability -------------------------------------------------------------


def _complete_report(job: _Job) -> Optional[Dict[str, Any]]:
    """The output's report when the output is complete and answers this job's
    request: report.json parses, names the same input and agrees with every
    option it records, and the batch's request file says the output was made
    with the same options (and belongs to this very report). None otherwise."""
    report = _read_json(os.path.join(job.output, "report.json"))
    state = _read_json(job.state)
    if not isinstance(report, dict) or not isinstance(state, dict):
        return None
    if state.get("request") != job.request:
        return None
    if os.path.abspath(str(report.get("input", ""))) != job.input:
        return None
    # The request file is written after the run it describes; the report it
    # saw must be the one in the folder (not a later run by other means).
    if state.get("report_wall_time_s") != report.get("wall_time_s"):
        return None
    recorded = _flatten(report.get("options"))
    for key, value in job.request["options"].items():
        if key in recorded and recorded[key] != value:
            return None
    if report.get("stopped_after") is not None:
        return None
    return report


def _flatten(options: Any) -> Dict[str, Any]:
    """report.json's options tree ({group: {name: value}}) as {name: value},
    the names colslam.run takes."""
    flat: Dict[str, Any] = {}
    if isinstance(options, dict):
        for key, value in options.items():
            if isinstance(value, dict):
                flat.update(_flatten(value))
            else:
                flat[key] = value
    return flat


def _read_json(path: str) -> Any:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


_TEMP_COUNTER = itertools.count()


def _write_atomic(path: str, text: str) -> None:
    """Writes a whole file or nothing: a temporary file beside it (named by
    pid and a counter, so no two writers share one; created with the umask's
    mode like any other file), synced, renamed over it."""
    folder, base = os.path.split(path)
    tmp = os.path.join(folder, f".{base}.tmp-{os.getpid()}-{next(_TEMP_COUNTER)}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


# Rows ---------------------------------------------------------------------


def _row(job: _Job, status: str, **values: Any) -> Dict[str, Any]:
    row: Dict[str, Any] = {column: None for column in COLUMNS}
    row.update(input=job.input, output=job.output, status=status)
    row.update(values)
    return row


def _failed(job: _Job, error: str, **values: Any) -> Dict[str, Any]:
    return _row(job, "failed", error=error, **values)


def _report_values(report: Mapping[str, Any]) -> Dict[str, Any]:
    return {
        "frames": report.get("frames"),
        "localized": report.get("localized"),
        "keyframes": report.get("keyframes"),
    }


def _skipped(job: _Job, report: Mapping[str, Any]) -> Dict[str, Any]:
    row = _row(job, "skipped", wall_s=report.get("wall_time_s"), **_report_values(report))
    _add_ate(row, job)
    return row


def _add_ate(row: Dict[str, Any], job: _Job) -> None:
    """The ATE against the job's ground truth, into the row; an evaluation
    that fails leaves the run done and says why in the error column."""
    if job.gt is None:
        return
    import colslam

    try:
        ev = colslam.evaluate(job.gt, os.path.join(job.output, "trajectory.tum"))
        row["ate_m"] = float(ev["ate_rmse"] if isinstance(ev, Mapping) else ev.ate_rmse)
    except Exception as e:  # the row reports it; other inputs go on
        row["error"] = f"evaluation against {job.gt}: {e}"


# The Ray task -------------------------------------------------------------


def _run_task(job: _Job, threads: int) -> Dict[str, Any]:
    """One input on a Ray worker: the run, the request file, the ATE. Returns
    the row; an error of the run is a failed row, never an exception."""
    import resource

    import colslam

    started = time.monotonic()
    try:
        result = colslam.run(job.input, job.output, threads=threads, **job.options)
        report = dict(result.report or {})
        del result
    except Exception as e:  # any error of this input fails this input only
        return _failed(
            job, _message(e), wall_s=time.monotonic() - started, peak_rss_mb=_peak_rss_mb(resource)
        )
    wall = time.monotonic() - started
    state = {"request": job.request, "report_wall_time_s": report.get("wall_time_s")}
    _write_atomic(job.state, json.dumps(state, indent=1, sort_keys=True) + "\n")
    row = _row(
        job, "done", wall_s=wall, peak_rss_mb=_peak_rss_mb(resource), **_report_values(report)
    )
    _add_ate(row, job)
    return row


def _peak_rss_mb(resource: Any) -> float:
    """Peak resident memory of this worker process and its largest child
    (ffmpeg for a video), MiB. Each task gets a fresh worker (max_calls=1),
    so this is the task's own peak."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return (own + child) / 1024.0  # Linux reports KiB


def _message(e: BaseException) -> str:
    import colslam

    text = str(e) or type(e).__name__
    if isinstance(e, getattr(colslam, "ColslamError", ())):
        return text
    return f"{type(e).__name__}: {text}"


def _run_on_ray(
    jobs: Sequence[_Job],
    indices: Sequence[int],
    address: Optional[str],
    cpus_per_task: int,
    memory: Optional[int],
    num_cpus: Optional[int],
) -> Iterable[Tuple[int, Dict[str, Any]]]:
    """Runs the jobs as Ray tasks, yielding (index, row) as each finishes."""
    import ray

    started_here = _connect(ray, address, num_cpus, cpus_per_task)
    try:
        for job in jobs:
            # A run that starts no longer answers the old request, whatever
            # happens to it: drop the request file before the folder may change.
            try:
                os.unlink(job.state)
            except FileNotFoundError:
                pass
        task_options: Dict[str, Any] = {
            "num_cpus": cpus_per_task,
            # A fresh worker per task: a crash or a leak stays with its input
            # and the peak memory measured is the task's own.
            "max_calls": 1,
            # A crashed worker is a failed row; running it again is the next
            # call's choice (the batch is resumable).
            "max_retries": 0,
        }
        if memory is not None:
            task_options["memory"] = memory
        task = ray.remote(**task_options)(_run_task)
        refs = {task.remote(job, cpus_per_task): (i, job) for i, job in zip(indices, jobs)}
        done = 0
        try:
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1)
                for ref in ready:
                    i, job = refs.pop(ref)
                    try:
                        row = ray.get(ref)
                    except ray.exceptions.RayError as e:  # worker crash, lost node
                        row = _failed(job, f"Ray task failed: {_first_line(e)}")
                    done += 1
                    if row["status"] == "failed":
                        log.warning(
                            "[%d/%d] %s failed: %s", done, len(jobs), job.name, row["error"]
                        )
                    else:
                        log.info(
                            "[%d/%d] %s done in %.1f s", done, len(jobs), job.name, row["wall_s"]
                        )
                    yield i, row
        except BaseException:
            for ref in refs:
                ray.cancel(ref, force=True)
            raise
    finally:
        if started_here:
            ray.shutdown()


def _first_line(e: BaseException) -> str:
    # Ray colours the task's name in its messages.
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(e)).strip()
    return text.splitlines()[0] if text else type(e).__name__


def _connect(ray: Any, address: Optional[str], num_cpus: Optional[int], cpus_per_task: int) -> bool:
    """Connects to Ray; returns whether this call started it (and stops it)."""
    if ray.is_initialized():
        started = False
    else:
        quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
        # A driver submitted as a Ray job (KubeRay's RayJob, `ray job submit`)
        # is told its cluster by RAY_ADDRESS: use it rather than start one.
        address = address or os.environ.get("RAY_ADDRESS") or None
        if address is None:
            cpus = num_cpus if num_cpus is not None else (os.cpu_count() or 1)
            if cpus < cpus_per_task:
                raise ValueError(
                    f"a local cluster of {cpus} CPUs cannot run tasks of {cpus_per_task} CPUs"
                )
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            # "local": a cluster of its own even where `ray start` ran on this
            # machine (Ray would join that one, refusing num_cpus).
            ray.init(address="local", num_cpus=cpus, include_dashboard=False, **quiet)
        else:
            ray.init(address=address, **quiet)
        started = True
    largest = max(
        (node.get("Resources", {}).get("CPU", 0) for node in ray.nodes() if node.get("Alive")),
        default=0,
    )
    if largest < cpus_per_task:
        if started:
            ray.shutdown()
        raise ValueError(
            f"no node of the Ray cluster has {cpus_per_task} CPUs (the largest has {largest:g})"
        )
    return started


# The table ------------------------------------------------------------------


def _cell(column: str, value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if column == "ate_m":
            return f"{value:.6f}"
        return f"{value:.1f}"
    return str(value)


def format_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The table as aligned text: one line per row, the input's name instead
    of its full path, numbers right-aligned."""
    columns = ("name",) + COLUMNS[2:]
    cells = [list(columns)]
    for row in rows:
        name = os.path.basename(str(row.get("output") or row.get("input")))
        cells.append([name] + [_cell(c, row.get(c)) for c in COLUMNS[2:]])
    widths = [max(len(line[k]) for line in cells) for k in range(len(columns) - 1)]
    numeric = {"frames", "localized", "keyframes", "ate_m", "wall_s", "peak_rss_mb"}
    lines = []
    for line in cells:
        parts = [
            line[k].rjust(widths[k]) if columns[k] in numeric else line[k].ljust(widths[k])
            for k in range(len(columns) - 1)
        ]
        lines.append("  ".join(parts + [line[-1]]).rstrip())
    return "\n".join(lines)


def _write_table(rows: Sequence[Mapping[str, Any]], out_root: str, wall: float) -> None:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow(["" if row.get(c) is None else row.get(c) for c in COLUMNS])
    _write_atomic(os.path.join(out_root, TABLE_CSV), buf.getvalue())
    counts = {
        status: sum(1 for r in rows if r["status"] == status)
        for status in ("done", "skipped", "failed")
    }
    doc = {"columns": list(COLUMNS), "rows": list(rows), "counts": counts, "wall_s": wall}
    _write_atomic(os.path.join(out_root, TABLE_JSON), json.dumps(doc, indent=1) + "\n")


# Command line ---------------------------------------------------------------


def _parse_value(text: str) -> Any:
    """A --set value: a JSON literal (2000, 0.5, true, null, "x") when it is
    one, else the text itself (a preset name, a path)."""
    try:
        return json.loads(text)
    except ValueError:
        return text


def _parse_sets(items: Sequence[str], what: str) -> Dict[str, Any]:
    options: Dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{what} takes key=value, got {item!r}")
        options[key.strip().replace("-", "_")] = _parse_value(value)
    return options


def _parse_input(text: str) -> InputSpec:
    """``PATH`` or ``PATH::key=value,key=value`` (that input's own options)."""
    path, sep, rest = text.partition("::")
    if not sep:
        return path
    return (path, _parse_sets([s for s in rest.split(",") if s], f"input {path!r}"))


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m colslam.batch``: exit status 0 when no input failed, 1
    when one did, 2 for bad arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m colslam.batch",
        description="Run colslam on many videos or image sequences, one Ray task each; "
        "skips inputs whose output is complete; writes OUT_ROOT/batch.csv and batch.json.",
        epilog="Option names are colslam.run's (the CLI's flags in snake_case): "
        "--set num_features=2000 --set preset=kitti-984. An input's own options follow it "
        "after '::', e.g. clip.mp4::preset=kitti-984,max_frames=100.",
    )
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="video file or image sequence folder [::key=value,...]",
    )
    parser.add_argument(
        "-o", "--out-root", required=True, help="folder of the outputs, one folder per input"
    )
    parser.add_argument(
        "--address",
        default=None,
        help="Ray cluster: 'auto' or 'ray://HOST:10001' (default: a local cluster)",
    )
    parser.add_argument(
        "--cpus-per-task",
        type=int,
        default=2,
        metavar="N",
        help="CPUs (and run threads) per task (default: 2)",
    )
    parser.add_argument(
        "--num-cpus",
        type=int,
        default=None,
        metavar="N",
        help="CPUs of the local cluster (default: all)",
    )
    parser.add_argument(
        "--memory", default=None, help="memory one task reserves in Ray, e.g. 2G (default: none)"
    )
    parser.add_argument(
        "--gt",
        default=GT_BESIDE,
        help="ground truth: 'beside' (groundtruth.txt in the sequence folder; the default), "
        "a file, or 'none'",
    )
    parser.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an option of colslam.run for every input (repeatable)",
    )
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="no progress on stderr, only the table on stdout"
    )
    args = parser.parse_intermixed_args(argv)

    logging.basicConfig(
        level=logging.WARNING if args.quiet else logging.INFO,
        format="%(message)s",
        stream=sys.stderr,
    )
    try:
        options = _parse_sets(args.sets, "--set")
        inputs = [_parse_input(text) for text in args.inputs]
    except ValueError as e:
        parser.error(str(e))
    gt = None if args.gt.lower() == "none" else args.gt
    memory: Union[int, str, None] = args.memory
    try:
        rows = run_many(
            inputs,
            args.out_root,
            address=args.address,
            cpus_per_task=args.cpus_per_task,
            memory=memory,
            num_cpus=args.num_cpus,
            gt=gt,
            **options,
        )
    except ValueError as e:  # an option name, the cluster's size, a duplicate input
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 1 if any(row["status"] == "failed" for row in rows) else 0


if __name__ == "__main__":
    # Through the importable module, so that Ray pickles the task and its rows
    # by reference to colslam.batch rather than by value from __main__.
    from colslam import batch

    sys.exit(batch.main())
