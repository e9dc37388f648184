"""What plugin authors import: `from i2pbench.api import hookimpl, Extractor2D, ...`."""

from .components import (
    FEATURES2D,
    FEATURES3D,
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
    LearnedComponent,
    Matcher,
    PoseSolver,
)
from .data.base import Dataset
from .errors import DataError, StageError
from .plugins import hookimpl
from .types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate, SensorFrame

__all__ = [
    "FEATURES2D",
    "FEATURES3D",
    "GROUND_TRUTH",
    "IMAGE",
    "KEYPOINTS2D",
    "KEYPOINTS3D",
    "MATCHES",
    "POINTS",
    "Component",
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
    "PoseEstimate",
    "PoseSolver",
    "SensorFrame",
    "StageError",
    "hookimpl",
]
