"""What plugin authors import: `from i2pbench.api import hookimpl, Extractor2D, ..., Method`; and what a Python
caller uses: `run`, `evaluate`, `compare`, `score` (the commands as calls, also `i2pbench.run` etc.) and the typed
results they return (docs/python.md).

Each name is imported from its module on first use: a plugin module that takes only `hookimpl` (its components
registered by path) then imports none of the stage contracts, so `i2pbench plugins` stays light, and
`LearnedComponent` (it subclasses torch.nn.Module) is imported by the stages that use it, never by a plugin of
classic stages.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .calls import OptionError, compare, evaluate, run, score
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
    from .correspondence import ground_truth_matches
    from .corruptions import Corruption
    from .data.base import Dataset
    from .errors import DataError, PluginError, StageError, WeightsError
    from .geometry import cell_half_diagonal, in_image, make_transform, project, rot_z, transform_points
    from .learned import BatchedStage, Device, LearnedComponent, width_mismatch
    from .registry.hookspecs import Register, hookimpl
    from .registry.methods import Method, MethodPreset, Row, Size
    from .results import CompareResult, EvaluateResult, RunResult, ScoreResult
    from .scoring.metrics import Metric, Scored
    from .stages.config import ConfigError
    from .types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate, SensorFrame
    from .weights import ImportedWeights

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
    "BatchedStage",
    "CompareResult",
    "Component",
    "ConfigError",
    "Corruption",
    "DataError",
    "Dataset",
    "Device",
    "Encoder2D",
    "EvaluateResult",
    "Encoder3D",
    "Exchanger",
    "Extractor2D",
    "Extractor3D",
    "Features",
    "Frame",
    "ImportedWeights",
    "Keypoints2D",
    "Keypoints3D",
    "LearnedComponent",
    "Matcher",
    "Matches",
    "Method",
    "MethodPreset",
    "Metric",
    "OptionError",
    "PluginError",
    "PoseEstimate",
    "PoseSolver",
    "Register",
    "Row",
    "RunResult",
    "ScoreResult",
    "Scored",
    "SensorFrame",
    "Size",
    "StageError",
    "WeightsError",
    "cell_half_diagonal",
    "compare",
    "evaluate",
    "ground_truth_matches",
    "hookimpl",
    "in_image",
    "make_transform",
    "project",
    "rot_z",
    "run",
    "score",
    "transform_points",
    "width_mismatch",
]


# where each name is defined (in i2pbench)
_MODULES = {
    "calls": ("OptionError", "compare", "evaluate", "run", "score"),
    "components": (
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
        "Encoder2D",
        "Encoder3D",
        "Exchanger",
        "Extractor2D",
        "Extractor3D",
        "Matcher",
        "PoseSolver",
    ),
    "correspondence": ("ground_truth_matches",),
    "corruptions": ("Corruption",),
    "data.base": ("Dataset",),
    "stages.config": ("ConfigError",),
    "errors": ("DataError", "PluginError", "StageError", "WeightsError"),
    "geometry": ("cell_half_diagonal", "in_image", "make_transform", "project", "rot_z", "transform_points"),
    "registry.hookspecs": ("Register", "hookimpl"),
    "learned": ("BatchedStage", "Device", "LearnedComponent", "width_mismatch"),
    "registry.methods": ("Method", "MethodPreset", "Row", "Size"),
    "scoring.metrics": ("Metric", "Scored"),
    "results": ("CompareResult", "EvaluateResult", "RunResult", "ScoreResult"),
    "types": ("Features", "Frame", "Keypoints2D", "Keypoints3D", "Matches", "PoseEstimate", "SensorFrame"),
    "weights": ("ImportedWeights",),
}
_HOME = {name: module for module, names in _MODULES.items() for name in names}


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"i2pbench.{_HOME[name]}"), name)
    globals()[name] = value  # found directly from now on
    return value
