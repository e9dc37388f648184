"""What a stage receives besides the frame, made from ground truth.

Keypoints are true correspondences (3D points in view and their projections, plus a few unmatched pixels), so a
matcher or solver sees a solvable problem; descriptors are seeded random unit vectors. The kit hands them to a stage
through `i2pbench.stages.calling.call_stage`, the pipeline's own call, so values a component does not declare in
`consumes` are withheld exactly as in a run: T_gt is hidden, and a matcher that does not declare features gets
`Features(None, None)`.
"""

from __future__ import annotations

import numpy as np
import torch

from ..geometry.transforms import in_image, project
from ..stages.calling import StageInputs
from ..stages.components import Component
from ..types import Features, Frame, Keypoints2D, Keypoints3D, Matches

DEFAULT_DIM = 32  # descriptor width when the component's conf has no `descriptor_dim`


def descriptor_dim(component: Component) -> int:
    dim = component.conf.get("descriptor_dim") if isinstance(component.conf, dict) else None
    return int(dim) if isinstance(dim, int) and dim > 0 else DEFAULT_DIM


def random_descriptors(count: int, dim: int, seed: int) -> torch.Tensor:
    """[count x dim] float32 unit vectors from a seeded generator."""
    desc = torch.randn(count, dim, generator=torch.Generator().manual_seed(seed))
    return torch.nn.functional.normalize(desc, dim=1)


def visible_points(frame: Frame, limit: int) -> np.ndarray:
    """Up to `limit` rows of frame.points that project into the image, evenly spread over those that do."""
    finite = np.isfinite(frame.points[:, :3]).all(axis=1)
    uv, front = project(frame.K, frame.T_gt, np.nan_to_num(frame.points[:, :3]).astype(np.float64))
    rows = np.flatnonzero(in_image(uv, front, frame.image_size) & finite)
    return rows[np.linspace(0, len(rows) - 1, min(limit, len(rows))).astype(np.int64)] if len(rows) else rows


def ground_truth_inputs(frame: Frame, dim: int, limit: int = 64, extra_pixels: int = 8) -> StageInputs:
    """True 2D-3D pairs of one frame (match i pairs 2D keypoint i with 3D keypoint i) and random descriptors."""
    rows = visible_points(frame, limit)
    kp3d = Keypoints3D.from_index(frame, rows)
    uv, _ = project(frame.K, frame.T_gt, kp3d.xyz.astype(np.float64))
    width, height = frame.image_size
    extras = np.random.default_rng(0).uniform((0, 0), (width - 1, height - 1), size=(extra_pixels, 2))
    kp2d = Keypoints2D(np.concatenate([uv, extras]).astype(np.float32))
    pairs = np.arange(len(kp3d), dtype=np.int64)
    matches = Matches(pairs, pairs.copy(), np.ones(len(pairs), np.float32))
    features = Features(random_descriptors(len(kp2d), dim, 1), random_descriptors(len(kp3d), dim, 2))
    return StageInputs(kp2d, kp3d, features, matches)


def empty_inputs(dim: int) -> StageInputs:
    """Zero keypoints on both sides, [0 x D] descriptors, no matches."""
    kp3d = Keypoints3D(np.zeros(0, np.int64), np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
    features = Features(torch.zeros(0, dim), torch.zeros(0, dim))
    return StageInputs(Keypoints2D(np.zeros((0, 2), np.float32)), kp3d, features, Matches.empty())


def without_2d(inputs: StageInputs) -> StageInputs:
    """Zero 2D keypoints, 3D side kept (no matches then)."""
    desc2d = inputs.features.desc2d
    features = Features(None if desc2d is None else desc2d[:0], inputs.features.desc3d)
    return StageInputs(Keypoints2D(inputs.kp2d.uv[:0]), inputs.kp3d, features, Matches.empty())
