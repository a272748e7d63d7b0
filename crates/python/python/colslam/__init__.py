"""colslam: offline monocular SLAM (COLMAP's incremental SfM parts in Rust).

    import colslam
    result = colslam.run("colslam-demo")        # a video or an image folder
    print(result.poses.shape, result.camera.K)  # (N, 4, 4) world_from_cam
    result.write_colmap("model")

See docs/python.md for the whole API, its conventions and its exceptions.
"""

from . import _colslam
from ._colslam import Camera, Result, __version__, evaluate, option_names, read_model
from . import errors
from .errors import (
    CameraError,
    ColslamError,
    InputError,
    OptionsError,
    OutputError,
    UnknownOptionError,
)

__all__ = [
    "run",
    "read_model",
    "evaluate",
    "option_names",
    "Result",
    "Camera",
    "__version__",
] + errors.__all__


def run(input, output=None, camera=None, *, progress=None, threads=0, **options):
    return _colslam.run(
        input, output, camera, progress=progress, threads=threads, options=options
    )


run.__doc__ = """Runs the SLAM pipeline on a video or an image sequence, as `colslam run`.

Parameters
----------
input : str or os.PathLike
    Video file or image sequence folder (TUM, EuRoC, KITTI layouts or plain images).
output : str or os.PathLike, optional
    Output folder, written as `colslam run -o` writes it (a previous run's
    output there is replaced as a whole). None: a temporary folder that lives
    as long as the returned Result (removed when it is garbage collected);
    pass a folder, or use Result.write_colmap/write_tum/write_ply, to keep it.
camera : str or os.PathLike, optional
    Camera file (`--camera`). Default: camera.yaml beside the input, else a
    preset (`preset=`), a focal length (`focal=`) or a guess refined by bundle
    adjustment.
progress : callable, optional
    Called as progress(done, total) after every frame: frames processed so
    far and the frames the source will give (None when unknown).
threads : int
    Worker threads (0: all cores); the first run of a process sets it.
**options
    Every flag of `colslam run` as a keyword, snake_case (`--num-features N`
    is num_features=N): same defaults and checks. True/False for flags,
    a list for a flag taking several values. Listed below.

Returns
-------
Result
    poses (N, 4, 4) world_from_cam (COLMAP/OpenCV camera: x right, y down,
    z forward), timestamps, frame_names, keyframe_mask, camera, points,
    colors, point_errors, report, output.

Raises
------
UnknownOptionError (a TypeError) for an unknown keyword, OptionsError (a
ValueError) for a refused value, InputError, CameraError, OutputError, or
ColslamError, with `colslam run`'s message. KeyboardInterrupt (Ctrl-C) stops
the run after the current frame. The GIL is released while it runs.
""" + _colslam.options_help()
