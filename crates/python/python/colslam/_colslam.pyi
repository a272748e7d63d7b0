"""The native module of colslam (PyO3). Use it through `colslam`."""

import os
from typing import Any, Callable, Dict, List, Mapping, Optional, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, os.PathLike]

__version__: str

class Camera:
    """A camera in COLMAP's model, parameter order and pixel convention
    (the centre of the top-left pixel is (0.5, 0.5))."""

    @property
    def model(self) -> str: ...
    @property
    def params(self) -> npt.NDArray[np.float64]: ...
    @property
    def readout(self) -> float: ...
    @property
    def K(self) -> npt.NDArray[np.float64]: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...

class Result:
    """A run's result: the trajectory of every localised frame and the model
    (keyframes, points) of the largest map. Poses are world_from_cam 4x4
    matrices (camera to world; x right, y down, z forward, as COLMAP and
    OpenCV)."""

    @property
    def poses(self) -> npt.NDArray[np.float64]: ...
    @property
    def timestamps(self) -> npt.NDArray[np.float64]: ...
    @property
    def frame_names(self) -> List[Optional[str]]: ...
    @property
    def keyframe_mask(self) -> npt.NDArray[np.bool_]: ...
    @property
    def camera(self) -> Optional[Camera]: ...
    @property
    def points(self) -> npt.NDArray[np.float64]: ...
    @property
    def colors(self) -> npt.NDArray[np.uint8]: ...
    @property
    def point_errors(self) -> npt.NDArray[np.float64]: ...
    @property
    def point_ids(self) -> npt.NDArray[np.uint64]: ...
    @property
    def report(self) -> Optional[Dict[str, Any]]: ...
    @property
    def output(self) -> os.PathLike: ...
    def write_colmap(self, path: _Path, text: bool = False) -> None: ...
    def write_tum(self, path: _Path) -> None: ...
    def write_ply(self, path: _Path) -> None: ...
    def to_pycolmap(self) -> Any:  # pycolmap.Reconstruction
        ...
    def export_nerfstudio(
        self,
        path: _Path,
        keyframes_only: bool = False,
        images: Optional[_Path] = None,
        map: int = 0,
    ) -> Dict[str, Any]: ...
    def export_3dgs(
        self,
        path: _Path,
        keyframes_only: bool = False,
        images: Optional[_Path] = None,
        map: int = 0,
    ) -> Dict[str, Any]: ...
    def __len__(self) -> int: ...

def run(
    input: _Path,
    output: Optional[_Path] = None,
    camera: Optional[_Path] = None,
    *,
    progress: Optional[Callable[[int, Optional[int]], None]] = None,
    threads: int = 0,
    options: Optional[Mapping[str, Any]] = None,
) -> Result: ...
def read_model(path: _Path) -> Result:
    """A run's output folder or a COLMAP model folder as a Result."""

def evaluate(
    gt: _Path,
    est: _Path,
    *,
    max_diff: Optional[float] = None,
    offset: Optional[float] = None,
    align: Optional[str] = None,
    delta: Optional[int] = None,
) -> Dict[str, Any]:
    """`colslam eval --gt GT --est EST --json`'s numbers as a dict."""

def options_help() -> str: ...
def option_names() -> List[str]: ...
