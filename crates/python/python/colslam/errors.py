"""The exceptions of colslam, by kind. Their message is the one ``colslam``
prints for the same failure (the error and its causes)."""

__all__ = [
    "ColslamError",
    "InputError",
    "CameraError",
    "OptionsError",
    "UnknownOptionError",
    "OutputError",
]


class ColslamError(Exception):
    """Base of every colslam error (a failure inside the pipeline itself when
    raised as such)."""


class InputError(ColslamError):
    """The input (video, image folder, ground truth, model) cannot be read."""


class CameraError(ColslamError):
    """The camera (file, preset, calibration) is unusable for the input."""


class OptionsError(ColslamError, ValueError):
    """An option's value is refused (type, range, possible values, conflicts)."""


class UnknownOptionError(OptionsError, TypeError):
    """No option has this name (the message suggests the nearest one)."""


class OutputError(ColslamError):
    """The output (folder or file) cannot be written."""
