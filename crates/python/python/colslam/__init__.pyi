import os
from typing import Any, Callable, Optional, Union

from ._colslam import Camera as Camera
from ._colslam import Result as Result
from ._colslam import __version__ as __version__
from ._colslam import evaluate as evaluate
from ._colslam import option_names as option_names
from ._colslam import read_model as read_model
from .errors import CameraError as CameraError
from .errors import ColslamError as ColslamError
from .errors import InputError as InputError
from .errors import OptionsError as OptionsError
from .errors import OutputError as OutputError
from .errors import UnknownOptionError as UnknownOptionError

_Path = Union[str, os.PathLike]

def run(
    input: _Path,
    output: Optional[_Path] = None,
    camera: Optional[_Path] = None,
    *,
    progress: Optional[Callable[[int, Optional[int]], None]] = None,
    threads: int = 0,
    **options: Any,
) -> Result:
    """Runs the SLAM pipeline on a video or an image sequence, as `colslam run`
    (options: the flags of `colslam run`, snake_case; see help(colslam.run))."""
