"""What plugin authors import: `from i2pbench.api import hookimpl, Extractor2D, ..., Method`; and what a Python
caller uses: `run`, `evaluate`, `compare`, `score` (the commands as calls, also `i2pbench.run` etc.) and the typed
results they return (docs/python.md).

Each name is imported from its module on first use: a plugin module that takes only `hookimpl` (its components
registered by path) then imports none of the stage contracts, so `i2pbench plugins` stays light, and
`LearnedComponent` (it subclasses torch.nn.Module) is imported by the stages that use it, never by a plugin of
classic stages.

Each name is listed once, in `_MODULES` beside the module it is defined in; `__all__` is read from there.
"""

from __future__ import annotations

import importlib
from typing import Any

_MODULES = {  # where each public name is defined (in i2pbench)
    "commands.calls": ("OptionError", "compare", "evaluate", "run", "score"),
    "commands.results": ("CompareResult", "EvaluateResult", "RunResult", "ScoreResult"),
    "corruptions.base": ("Corruption",),
    "data.base": ("Dataset",),
    "errors": ("DataError", "PluginError", "StageError", "WeightsError"),
    "geometry.correspondence": ("ground_truth_matches",),
    "geometry.transforms": ("cell_half_diagonal", "in_image", "make_transform", "project", "rot_z", "transform_points"),
    "registry.hookspecs": ("Register", "hookimpl"),
    "registry.methods": ("Method", "MethodPreset", "Row", "Size"),
    "scoring.metrics": ("Metric", "Scored"),
    "stages.components": (
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
    "stages.config": ("ConfigError",),
    "stages.learned": ("BatchedStage", "Device", "LearnedComponent", "width_mismatch"),
    "types": ("Features", "Frame", "Keypoints2D", "Keypoints3D", "Matches", "PoseEstimate", "SensorFrame"),
    "weights.checkpoints": ("ImportedWeights",),
}
_HOME = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(_HOME)  # read from _MODULES, so each name is written once


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"i2pbench.{_HOME[name]}"), name)
    globals()[name] = value  # found directly from now on
    return value


def __dir__() -> list[str]:
    return __all__
