"""Judging a stage's output beyond the contract `call_stage` checks (the pipeline's: types, shapes, ranges, finite
values): the dtypes `i2pbench.types` documents, descriptors a stage declares it provides, and equality.

A wrong dtype rarely breaks a run, but it silently costs memory or precision downstream, so dtypes are the kit's
addition rather than the pipeline's.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import torch

from ..errors import StageError
from ..stages.components import FEATURES2D, FEATURES3D, Component
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
    (Matches, "frustum"): np.float32,
    (PoseEstimate, "T"): np.float64,
    (PoseEstimate, "inliers"): np.int64,
}


def check_extras(component: Component, out: Any, inputs: StageInputs) -> None:
    """Raise StageError naming the first way a contract-checked `out` falls short of what the kit also asks."""
    label, kind = component.label, component.kind
    if kind in ("encoder2d", "encoder3d"):
        _check_descriptors(component, out)
    elif kind == "exchanger":
        _check_descriptors(component, out.desc2d, FEATURES2D)
        _check_descriptors(component, out.desc3d, FEATURES3D)
    elif kind == "solver" and out.ok and len(out.inliers):
        if out.inliers.min() < 0 or out.inliers.max() >= len(inputs.matches):
            raise StageError(label, f"inliers index out of range for {len(inputs.matches)} matches")
    check_dtypes(out, label)


def _check_descriptors(component: Component, desc: Any, value: str | None = None) -> None:
    value = value or (FEATURES2D if component.kind == "encoder2d" else FEATURES3D)
    if desc is None and value in component.provides:
        raise StageError(component.label, f"returned no descriptors although it declares it provides {value}")
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
