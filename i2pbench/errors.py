"""Errors users see: each names the file or component at fault and what is wrong."""


class I2PBenchError(Exception):
    """Base class of every error i2pbench raises on purpose."""


class DataError(I2PBenchError):
    """A dataset file is missing, malformed or inconsistent; the message names the file."""


class PluginError(I2PBenchError):
    """A plugin or component name is unknown, clashes, or a combination is incompatible."""


class StageError(I2PBenchError):
    """A component broke its contract (raised, or returned the wrong shape) on one frame."""

    def __init__(self, component: str, message: str) -> None:
        super().__init__(f"{component}: {message}")
        self.component = component


class WeightsError(I2PBenchError):
    """A checkpoint is unreadable or does not fit the requested combination."""


class IsolationError(Exception):
    """An isolated pipeline's child process could not run the frame: it died, or could not receive the pipeline."""


def os_problem(exc: OSError) -> str:
    """An OSError as one line naming the path at fault: `PATH: reason`, where a path that is a file but must be a
    folder says so (mkdir's bare 'File exists' reads as if the target itself were there), and a path inside the
    i2pbench cache folder says how to move that folder."""
    import errno
    import os
    from pathlib import Path

    from .paths import cache_home

    path = exc.filename
    if path is None:
        return str(exc.strerror or exc)
    reason = exc.strerror or str(exc)
    if exc.errno == errno.EEXIST and os.path.isfile(path):
        reason = "a file is there where a folder is needed"
    text = f"{os.fsdecode(path)}: {reason}"
    cache = cache_home()
    if Path(os.fsdecode(path)) == cache or cache in Path(os.fsdecode(path)).parents:
        text += f" (in the i2pbench cache folder {cache}: make it writable, or set XDG_CACHE_HOME to a writable folder)"
    return text
