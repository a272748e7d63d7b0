"""The Python API on the synthetic default: each test fails when the
feature it names is broken."""

import inspect
import json
import os
import re
import signal
import threading

import numpy as np
import pytest

import colslam
from conftest import cli


def read_tum(path):
    rows = [l.split() for l in open(path) if l.strip() and not l.startswith("#")]
    return np.array(rows, dtype=np.float64).reshape(-1, 8)


def quat_xyzw_to_matrix(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_poses_equal_the_written_trajectory(demo_run):
    result, _ = demo_run
    tum = read_tum(result.output / "trajectory.tum")
    assert len(tum) > 100, "the synthetic default localises most of its 150 frames"
    poses = result.poses
    assert poses.shape == (len(tum), 4, 4) and poses.dtype == np.float64
    np.testing.assert_array_equal(result.timestamps, tum[:, 0])
    # world_from_cam: the translation is the camera centre TUM stores.
    np.testing.assert_allclose(poses[:, :3, 3], tum[:, 1:4], rtol=0, atol=1e-12)
    for pose, row in zip(poses, tum):
        np.testing.assert_allclose(pose[:3, :3], quat_xyzw_to_matrix(row[4:8]), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])
    assert len(result) == len(tum) == len(result.frame_names)
    kf = read_tum(result.output / "keyframes.tum")
    np.testing.assert_array_equal(result.timestamps[result.keyframe_mask], kf[:, 0])


def test_result_model_matches_pycolmap_reading_the_output(demo_run):
    pycolmap = pytest.importorskip("pycolmap")
    result, _ = demo_run
    mine = result.to_pycolmap()
    disk = pycolmap.Reconstruction(str(result.output))
    assert mine.num_reg_images() == disk.num_reg_images() == int(result.keyframe_mask.sum())
    assert sorted(mine.images) == sorted(disk.images)
    for image_id, a in mine.images.items():
        b = disk.images[image_id]
        assert a.name == b.name
        np.testing.assert_array_equal(a.cam_from_world().matrix(), b.cam_from_world().matrix())
        np.testing.assert_array_equal([p.xy for p in a.points2D], [p.xy for p in b.points2D])
        np.testing.assert_array_equal(
            [p.point3D_id for p in a.points2D], [p.point3D_id for p in b.points2D]
        )
    assert sorted(mine.points3D) == sorted(disk.points3D) == sorted(result.point_ids.tolist())
    for (pid, a), xyz, rgb, err in zip(
        sorted(disk.points3D.items()), result.points, result.colors, result.point_errors
    ):
        np.testing.assert_array_equal(a.xyz, xyz)
        np.testing.assert_array_equal(a.color, rgb)
        assert a.error == err
        b = mine.points3D[pid]
        assert [(e.image_id, e.point2D_idx) for e in a.track.elements] == [
            (e.image_id, e.point2D_idx) for e in b.track.elements
        ]
    # The keyframes' names and poses in the result are the model's.
    by_name = {im.name: im for im in disk.images.values()}
    for name, pose in zip(np.array(result.frame_names)[result.keyframe_mask], result.poses[result.keyframe_mask]):
        cam_from_world = by_name[name].cam_from_world().matrix()
        np.testing.assert_allclose(np.linalg.inv(pose)[:3], cam_from_world, atol=1e-9)
    cam = disk.cameras[1]
    assert result.camera.model == cam.model.name
    np.testing.assert_array_equal(result.camera.params, cam.params)
    np.testing.assert_allclose(result.camera.K, cam.calibration_matrix())
    assert (result.camera.width, result.camera.height) == (cam.width, cam.height)


def test_report_is_report_json(demo_run):
    result, _ = demo_run
    assert result.report == json.load(open(result.output / "report.json"))
    assert result.report["localized"] == len(result)


def test_writers_write_what_the_run_wrote(demo_run, tmp_path):
    result, _ = demo_run
    result.write_tum(tmp_path / "t.tum")
    assert (tmp_path / "t.tum").read_bytes() == (result.output / "trajectory.tum").read_bytes()
    result.write_ply(tmp_path / "p.ply")
    assert (tmp_path / "p.ply").read_bytes() == (result.output / "points.ply").read_bytes()
    result.write_colmap(tmp_path / "model")
    for name in ["cameras.bin", "images.bin", "points3D.bin"]:
        assert (tmp_path / "model" / name).read_bytes() == (result.output / name).read_bytes()
    result.write_colmap(tmp_path / "text", text=True)
    assert (tmp_path / "text" / "images.txt").is_file()


def test_read_model_gives_the_run_result(demo_run, tmp_path):
    result, _ = demo_run
    back = colslam.read_model(result.output)
    np.testing.assert_array_equal(back.timestamps, result.timestamps)
    np.testing.assert_allclose(back.poses, result.poses, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.keyframe_mask, result.keyframe_mask)
    # Keyframes are named (from the model); other frames are not known there.
    assert [n for n, k in zip(back.frame_names, back.keyframe_mask) if k] == [
        n for n, k in zip(result.frame_names, result.keyframe_mask) if k
    ]
    np.testing.assert_array_equal(back.points, result.points)
    assert back.report == result.report
    # A bare COLMAP model: its images.
    result.write_colmap(tmp_path / "model")
    model = colslam.read_model(tmp_path / "model")
    assert len(model) == int(result.keyframe_mask.sum()) and model.keyframe_mask.all()
    with pytest.raises(colslam.InputError, match="not a folder"):
        colslam.read_model(tmp_path / "missing")


def test_progress_is_called_for_every_frame(demo_run):
    result, calls = demo_run
    frames = result.report["frames"]
    assert [c[0] for c in calls] == list(range(1, frames + 1))
    assert all(total == frames for _, total in calls)


def test_progress_exception_stops_the_run_and_is_raised(demo_seq, tmp_path):
    seen = []

    def progress(done, total):
        seen.append(done)
        if done == 3:
            raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        colslam.run(demo_seq, tmp_path / "out", progress=progress)
    assert seen == [1, 2, 3]


def test_ctrl_c_cancels_the_run(demo_seq, tmp_path):
    # SIGINT from elsewhere while the main thread is inside the run (no
    # Python code of ours runs there to see it): the run checks for it
    # after each frame, stops, writes what it has and raises.
    assert threading.current_thread() is threading.main_thread()
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            colslam.run(demo_seq, tmp_path / "out")
    finally:
        timer.cancel()
    report = json.load(open(tmp_path / "out" / "report.json"))
    assert report["stopped_after"] is not None and report["stopped_after"] < 150, report["stopped_after"]


def test_gil_is_released_while_running(demo_seq, tmp_path):
    ticks = []
    done = threading.Event()

    def ticker():
        while not done.is_set():
            ticks.append(1)
            done.wait(0.01)

    t = threading.Thread(target=ticker)
    t.start()
    try:
        colslam.run(demo_seq, tmp_path / "out", max_frames=30)
    finally:
        done.set()
        t.join()
    assert len(ticks) > 5, "another thread ran while colslam.run worked"


def test_temporary_output_lives_with_the_result(demo_seq):
    import gc

    result = colslam.run(demo_seq, max_frames=30)
    out = result.output
    assert (out / "trajectory.tum").is_file()
    del result
    gc.collect()
    assert not out.exists() and not out.parent.exists()


def test_missing_input_raises_input_error(tmp_path):
    with pytest.raises(colslam.InputError, match="nope"):
        colslam.run(tmp_path / "nope", tmp_path / "out")


def test_bad_option_value_raises_options_error(demo_seq, tmp_path):
    with pytest.raises(colslam.OptionsError, match=r"invalid value 'many' for 'num_features"):
        colslam.run(demo_seq, tmp_path / "out", num_features="many")
    # Range checks of the options tree, named as on the command line.
    with pytest.raises(ValueError, match="skip = 0: must be at least 1"):
        colslam.run(demo_seq, tmp_path / "out", skip=0)
    with pytest.raises(colslam.OptionsError, match="possible values"):
        colslam.run(demo_seq, tmp_path / "out", preset="nikon")
    assert not (tmp_path / "out").exists(), "refused before anything is written"


def test_unknown_option_raises_type_error_with_suggestion(demo_seq, tmp_path):
    with pytest.raises(TypeError, match=r"num_feature.*\n.*num_features") as e:
        colslam.run(demo_seq, tmp_path / "out", num_feature=500)
    assert isinstance(e.value, colslam.UnknownOptionError)
    assert isinstance(e.value, colslam.ColslamError)
    with pytest.raises(TypeError):
        colslam.run(demo_seq, tmp_path / "out", help=True)


def test_output_that_is_a_file_raises_output_error(demo_seq, tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(colslam.OutputError, match="not a folder"):
        colslam.run(demo_seq, f)


def test_options_reach_the_run(demo_seq, tmp_path):
    result = colslam.run(
        demo_seq, tmp_path / "out", max_frames=40, skip=2, num_features=600, allow_pure_rotation=True,
        localize_all_frames=False, text=True,
    )
    assert result.report["frames"] == 40
    opts = result.report["options"]
    assert opts["frontend"]["num_features"] == 600
    assert opts["keyframes"]["allow_pure_rotation"] is True
    assert opts["refine"]["localize_all_frames"] is False
    assert (tmp_path / "out" / "images.txt").is_file()
    assert result.keyframe_mask.all(), "without localisation only keyframes have poses"


def test_help_lists_every_cli_option(colslam_bin):
    # The run's own flags; the live viewer's (--view, --port, ...: no use
    # from Python) and the binary's global ones (-q, -v, --threads) follow them.
    text = cli(colslam_bin, "run", "--help").split("\nViewer:")[0]
    flags = set(re.findall(r"--([a-z][a-z0-9-]+)", text)) - {"help", "version", "output"}
    assert len(flags) > 30
    doc = colslam.run.__doc__
    assert doc == inspect.getdoc(colslam.run) or inspect.cleandoc(doc) == inspect.getdoc(colslam.run)
    for flag in flags:
        assert re.search(rf"^{flag.replace('-', '_')} : ", doc, re.M), f"{flag} missing from help(colslam.run)"
    assert sorted(colslam.option_names()) == sorted(f.replace("-", "_") for f in flags)
    # The defaults are clap's: --max-hamming's default as the CLI prints it.
    default = re.search(r"--max-hamming <BITS>\n.*?\[default: (\d+)\]", text, re.S).group(1)
    assert re.search(rf"^max_hamming : BITS = {default}$", doc, re.M)


def test_evaluate_equals_colslam_eval(demo_run, demo_seq, colslam_bin, tmp_path):
    result, _ = demo_run
    gt = demo_seq / "groundtruth.txt"
    est = result.output / "trajectory.tum"
    for kwargs, flags in [({}, []), ({"align": "se3", "delta": 5}, ["--align", "se3", "--delta", "5"])]:
        mine = colslam.evaluate(gt, est, **kwargs)
        theirs = json.loads(cli(colslam_bin, "-q", "eval", "--gt", gt, "--est", est, "--json", "--no-plot", *flags))
        assert mine == theirs
    # Sim(3) by default, as `colslam eval`: the monocular scale is aligned.
    default = colslam.evaluate(gt, est)
    assert default["align"] == "sim3" and 0 < default["ate_rmse"] < mine["ate_rmse"]
    with pytest.raises(colslam.OptionsError):
        colslam.evaluate(gt, est, align="affine")
    with pytest.raises(colslam.InputError):
        colslam.evaluate(tmp_path / "none.txt", est)


def test_exports_are_the_cli_exports(demo_run, colslam_bin, tmp_path):
    result, _ = demo_run
    summary = result.export_nerfstudio(tmp_path / "ns", keyframes_only=True)
    assert summary["frames"] == summary["keyframes"] == int(result.keyframe_mask.sum())
    cli(colslam_bin, "-q", "export", result.output, "-o", tmp_path / "ns-cli", "-f", "nerfstudio", "--frames", "keyframes")
    assert (tmp_path / "ns" / "transforms.json").read_bytes() == (tmp_path / "ns-cli" / "transforms.json").read_bytes()
    summary = result.export_3dgs(tmp_path / "gs")
    assert summary["frames"] == len(result) and summary["camera_model"] == "PINHOLE"
    pycolmap = pytest.importorskip("pycolmap")
    assert pycolmap.Reconstruction(str(tmp_path / "gs" / "sparse" / "0")).num_reg_images() == len(result)
    result.write_colmap(tmp_path / "model")
    with pytest.raises(colslam.InputError, match="not a colslam run folder"):
        colslam.read_model(tmp_path / "model").export_3dgs(tmp_path / "gs2")
