"""Checks that a stage's output honours its contract; a violation becomes a failed row naming the component."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import StageError
from ..types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate
from .components import FRUSTUM_SCORES, STAGES

if TYPE_CHECKING:
    import torch


class ContractError(StageError):
    """A stage returned an output that breaks its kind's contract (rather than raising itself)."""


def _require(ok: bool, component: str, message: str) -> None:
    if not ok:
        raise ContractError(component, message)


def _shape(array: object) -> str:
    return str(tuple(getattr(array, "shape", ()))) if hasattr(array, "shape") else type(array).__name__


def check_keypoints2d(kp: object, frame: Frame, component: str) -> Keypoints2D:
    _require(isinstance(kp, Keypoints2D), component, f"returned {type(kp).__name__}, expected Keypoints2D")
    uv = kp.uv
    _require(
        isinstance(uv, np.ndarray) and uv.ndim == 2 and uv.shape[1] == 2,
        component,
        f"keypoints uv must be [M x 2], got {_shape(uv)}",
    )
    _require(bool(np.all(np.isfinite(uv))), component, "keypoints contain NaN or inf")
    w, h = frame.image_size
    inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
    _require(bool(np.all(inside)), component, f"{int((~inside).sum())} keypoints lie outside the {w}x{h} image")
    return kp


def check_keypoints3d(kp: object, frame: Frame, component: str) -> Keypoints3D:
    _require(isinstance(kp, Keypoints3D), component, f"returned {type(kp).__name__}, expected Keypoints3D")
    m = kp.index.shape[0] if isinstance(kp.index, np.ndarray) and kp.index.ndim == 1 else -1
    _require(m >= 0, component, f"index must be [M], got {_shape(kp.index)}")
    _require(kp.xyz.shape == (m, 3), component, f"xyz must be [{m} x 3], got {_shape(kp.xyz)}")
    _require(kp.reflectance.shape == (m,), component, f"reflectance must be [{m}], got {_shape(kp.reflectance)}")
    n = frame.points.shape[0]
    _require(m == 0 or (kp.index.min() >= 0 and kp.index.max() < n), component, f"index out of range for {n} points")
    _require(bool(np.all(np.isfinite(kp.xyz))), component, "xyz contains NaN or inf")
    return kp


def check_descriptors(desc: object, count: int, component: str) -> torch.Tensor | None:
    if desc is None:
        return None
    torch = sys.modules.get("torch")  # loaded if desc is a tensor: a classic run, which never imports it, makes none
    _require(
        torch is not None and isinstance(desc, torch.Tensor) and desc.ndim == 2 and desc.shape[0] == count,
        component,
        f"descriptors must be a [{count} x D] tensor, got {_shape(desc)}",
    )
    _require(bool(torch.isfinite(desc).all()), component, "descriptors contain NaN or inf")
    return desc


def check_features(features: object, n2d: int, n3d: int, component: str) -> Features:
    _require(isinstance(features, Features), component, f"returned {type(features).__name__}, expected Features")
    check_descriptors(features.desc2d, n2d, component)
    check_descriptors(features.desc3d, n3d, component)
    return features


def check_matches(matches: object, n2d: int, n3d: int, component: str, frustum_required: bool = False) -> Matches:
    """`matches` checked against n2d and n3d keypoints; `frustum_required`: the matcher declares FRUSTUM_SCORES."""
    _require(isinstance(matches, Matches), component, f"returned {type(matches).__name__}, expected Matches")
    k = len(matches.index2d)
    _require(
        matches.index3d.shape == (k,) and matches.score.shape == (k,),
        component,
        f"index2d, index3d and score must all be [K]; got {_shape(matches.index2d)}, "
        f"{_shape(matches.index3d)}, {_shape(matches.score)}",
    )
    _require(
        k == 0 or (0 <= matches.index2d.min() and matches.index2d.max() < n2d),
        component,
        f"index2d out of range for {n2d} 2D keypoints",
    )
    _require(
        k == 0 or (0 <= matches.index3d.min() and matches.index3d.max() < n3d),
        component,
        f"index3d out of range for {n3d} 3D keypoints",
    )
    _require(
        matches.frustum is not None or not frustum_required,
        component,
        f"declares it provides {FRUSTUM_SCORES} but returned Matches.frustum None",
    )
    if matches.frustum is not None:
        check_frustum(matches.frustum, n3d, component)
    _require(
        matches.radius_px is None or (math.isfinite(matches.radius_px) and matches.radius_px > 0),
        component,
        f"radius_px must be None or a positive number of pixels; got {matches.radius_px!r}",
    )
    return matches


def check_frustum(frustum: object, n3d: int, component: str) -> None:
    """Frustum scores: one probability per 3D keypoint, [M3], finite, in [0, 1]."""
    _require(
        isinstance(frustum, np.ndarray) and frustum.shape == (n3d,),
        component,
        f"frustum scores must be [{n3d}] (one per 3D keypoint), got {_shape(frustum)}",
    )
    _require(bool(np.all(np.isfinite(frustum))), component, "frustum scores contain NaN or inf")
    _require(n3d == 0 or (frustum.min() >= 0 and frustum.max() <= 1), component, "frustum scores must lie in [0, 1]")


def check_estimate(estimate: object, component: str) -> PoseEstimate:
    _require(
        isinstance(estimate, PoseEstimate), component, f"returned {type(estimate).__name__}, expected PoseEstimate"
    )
    if estimate.T is not None:
        T = estimate.T
        _require(isinstance(T, np.ndarray) and T.shape == (4, 4), component, f"T must be 4x4, got {_shape(T)}")
        _require(bool(np.all(np.isfinite(T))), component, "T contains NaN or inf")
        R = T[:3, :3]
        _require(
            np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0,
            component,
            "T's rotation block is not a rotation matrix",
        )
    return estimate


@dataclass(frozen=True)
class Handed:
    """What a stage was handed, as the check of its output needs it."""

    frame: Frame
    n2d: int  # 2D keypoints it was given (0 before the extractors ran)
    n3d: int  # 3D keypoints
    component: str  # its label, which a violation names
    provides: frozenset[str] = frozenset()  # what it declares beyond its kind's output (a matcher's FRUSTUM_SCORES)


# Each kind's contract, named by its `components.StageKind.contract`: (output, what the stage was handed) -> output.
def keypoints2d(out: object, h: Handed) -> Keypoints2D:
    return check_keypoints2d(out, h.frame, h.component)


def keypoints3d(out: object, h: Handed) -> Keypoints3D:
    return check_keypoints3d(out, h.frame, h.component)


def descriptors2d(out: object, h: Handed) -> torch.Tensor | None:
    return check_descriptors(out, h.n2d, h.component)


def descriptors3d(out: object, h: Handed) -> torch.Tensor | None:
    return check_descriptors(out, h.n3d, h.component)


def features(out: object, h: Handed) -> Features:
    return check_features(out, h.n2d, h.n3d, h.component)


def matches(out: object, h: Handed) -> Matches:
    return check_matches(out, h.n2d, h.n3d, h.component, FRUSTUM_SCORES in h.provides)


def estimate(out: object, h: Handed) -> PoseEstimate:
    return check_estimate(out, h.component)


def check_output(kind: str, out: object, handed: Handed) -> Any:
    """`out` checked as the output of a stage of `kind` by that kind's contract."""
    return globals()[STAGES[kind].contract](out, handed)
