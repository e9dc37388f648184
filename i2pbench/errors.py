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
