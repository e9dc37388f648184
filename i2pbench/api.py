"""What plugin authors import: `from i2pbench.api import hookimpl, Extractor2D, ..., Method`.

`LearnedComponent` is imported on first use (it subclasses torch.nn.Module), so a plugin of classic stages imports
this module without importing torch.
"""

from typing import TYPE_CHECKING, Any

from .components import (
    FEATURES2D,
    FEATURES3D,
    FRUSTUM_SCORES,
    GROUND_TRUTH,
    IMAGE,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
    POINTS,
    Component,
    Encoder2D,
    Encoder3D,
    Exchanger,
    Extractor2D,
    Extractor3D,
    Matcher,
    PoseSolver,
)
from .corruptions import Corruption
from .data.base import Dataset
from .errors import DataError, StageError
from .hookspecs import hookimpl
from .methods import Method, MethodPreset, Row, Size
from .types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate, SensorFrame

if TYPE_CHECKING:
    from .learned import LearnedComponent

__all__ = [
    "FEATURES2D",
    "FEATURES3D",
    "FRUSTUM_SCORES",
    "GROUND_TRUTH",
    "IMAGE",
    "KEYPOINTS2D",
    "KEYPOINTS3D",
    "MATCHES",
    "POINTS",
    "Component",
    "Corruption",
    "DataError",
    "Dataset",
    "Encoder2D",
    "Encoder3D",
    "Exchanger",
    "Extractor2D",
    "Extractor3D",
    "Features",
    "Frame",
    "Keypoints2D",
    "Keypoints3D",
    "LearnedComponent",
    "Matcher",
    "Matches",
    "Method",
    "MethodPreset",
    "PoseEstimate",
    "PoseSolver",
    "Row",
    "SensorFrame",
    "Size",
    "StageError",
    "hookimpl",
]


def __getattr__(name: str) -> Any:
    if name == "LearnedComponent":
        from .learned import LearnedComponent

        return LearnedComponent
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
