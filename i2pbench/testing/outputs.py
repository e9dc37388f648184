"""Judging a stage's output: the pipeline's contract checks plus the dtypes `i2pbench.types` documents, and equality.

The pipeline itself checks shapes and finiteness only (a wrong dtype rarely breaks a run, but it silently costs
memory or precision downstream), so dtypes are the kit's addition.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import torch

from .. import contracts
from ..components import FEATURES2D, FEATURES3D, Component
from ..errors import StageError
from ..types import Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate
from .inputs import StageInputs

# (type, field) -> the dtype types.py documents
DTYPES: dict[tuple[type, str], Any] = {
    (Keypoints2D, "uv"): np.float32,
    (Keypoints3D, "index"): np.int64,
    (Keypoints3D, "xyz"): np.float32,
    (Keypoints3D, "reflectance"): np.float32,
    (Matches, "index2d"): np.int64,
    (Matches, "index3d"): np.int64,
    (Matches, "score"): np.float32,
    (PoseEstimate, "T"): np.float64,
    (PoseEstimate, "inliers"): np.int64,
}


def validate(component: Component, out: Any, frame: Frame, inputs: StageInputs) -> None:
    """Raise StageError naming the first way `out` breaks the contract of the component's kind."""
    label, kind = component.label, component.kind
    n2d, n3d = len(inputs.kp2d), len(inputs.kp3d)
    if kind == "extractor2d":
        contracts.check_keypoints2d(out, frame, label)
    elif kind == "extractor3d":
        contracts.check_keypoints3d(out, frame, label)
    elif kind in ("encoder2d", "encoder3d"):
        _check_descriptors(component, out, n2d if kind == "encoder2d" else n3d)
    elif kind == "exchanger":
        contracts.check_features(out, n2d, n3d, label)
        _check_descriptors(component, out.desc2d, n2d, FEATURES2D)
        _check_descriptors(component, out.desc3d, n3d, FEATURES3D)
    elif kind == "matcher":
        contracts.check_matches(out, n2d, n3d, label)
    elif kind == "solver":
        contracts.check_estimate(out, label)
        if out.ok and len(out.inliers) and (out.inliers.min() < 0 or out.inliers.max() >= len(inputs.matches)):
            raise StageError(label, f"inliers index out of range for {len(inputs.matches)} matches")
    check_dtypes(out, label)


def _check_descriptors(component: Component, desc: Any, count: int, value: str | None = None) -> None:
    value = value or (FEATURES2D if component.kind == "encoder2d" else FEATURES3D)
    if desc is None and value in component.provides:
        raise StageError(component.label, f"returned no descriptors although it declares it provides {value}")
    contracts.check_descriptors(desc, count, component.label)
    if desc is not None and desc.dtype != torch.float32:
        raise StageError(component.label, f"descriptors must be float32, got {desc.dtype}")


def check_dtypes(out: Any, label: str) -> None:
    for (cls, name), dtype in DTYPES.items():
        value = getattr(out, name, None) if isinstance(out, cls) else None
        if isinstance(value, np.ndarray) and value.dtype != dtype:
            raise StageError(label, f"{cls.__name__}.{name} must be {np.dtype(dtype)}, got {value.dtype}")


def difference(a: Any, b: Any, path: str = "output") -> str | None:
    """Where two outputs differ (e.g. "output.uv"), or None when they are identical, NaN equal to NaN."""
    if dataclasses.is_dataclass(a) and type(a) is type(b):
        for f in dataclasses.fields(a):
            where = difference(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
            if where:
                return where
        return None
    if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor):
        same = a.shape == b.shape and a.dtype == b.dtype and torch.equal(a.nan_to_num(), b.nan_to_num())
        return None if same else path
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        same = a.shape == b.shape and a.dtype == b.dtype
        return None if same and np.array_equal(a, b, equal_nan=a.dtype.kind in "fc") else path
    return None if type(a) is type(b) and a == b else path


def frame_arrays(frame: Frame) -> dict[str, np.ndarray]:
    """Copies of the frame's arrays, to catch a component that writes into its input."""
    return {f.name: v.copy() for f in dataclasses.fields(frame) if isinstance(v := getattr(frame, f.name), np.ndarray)}


def changed_arrays(before: dict[str, np.ndarray], frame: Frame) -> list[str]:
    return [name for name, old in before.items() if not np.array_equal(old, getattr(frame, name), equal_nan=True)]
