"""DeepI2P's inverse camera projection as a pose solver (Li & Lee, CVPR 2021, Sec. 4.2): the pose whose frustum best
agrees with the matcher's per-point frustum scores (`Matches.frustum`), found by frustum_solver.solve_frustum_pose.

It reads no match pairs, only the frustum scores the matches carry and the 3D keypoints they belong to, so it needs
a matcher that provides FRUSTUM_SCORES (the pipeline refuses it after any other). The pose is searched around the
camera's mount on the LiDAR, `Frame.T_init` (the dataset's calibration, which the protocol's random transform moves
the scan away from): the planar variant ("2d", the protocol's family) or the planar one refined in 6 DoF ("3d").
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from i2pbench.api import (
    FRUSTUM_SCORES,
    KEYPOINTS3D,
    MATCHES,
    Frame,
    Keypoints2D,
    Keypoints3D,
    Matches,
    PoseEstimate,
    PoseSolver,
)

from .frustum_solver import FrustumOptions, solve_frustum_pose
from .labels import frustum_labels

OPTIONS = {f.name: f.default for f in dataclasses.fields(FrustumOptions)}


class FrustumSolver(PoseSolver):
    """The camera <- LiDAR pose from frustum scores by inverse camera projection; inliers: the matches whose point
    lies in the solved frustum."""

    name = "deepi2p-frustum"
    consumes = frozenset({KEYPOINTS3D, MATCHES, FRUSTUM_SCORES})
    default_conf: dict[str, Any] = {
        "variant": "2d",  # "2d": yaw + planar translation about the calibration (the protocol's family); "3d": + 6 DoF
        **OPTIONS,  # the search: frustum_solver.FrustumOptions, whose comments say what each does
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        if self.conf["variant"] not in ("2d", "3d"):
            raise ValueError(f"{self.label}: variant must be '2d' or '3d', got {self.conf['variant']!r}")

    def options(self) -> FrustumOptions:
        conf = {k: v for k, v in self.conf.items() if k in OPTIONS}
        conf["start_depth_m"] = tuple(conf["start_depth_m"])
        return FrustumOptions(**conf)

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        if matches.frustum is None:
            return PoseEstimate.failed(f"{self.label}: the matches carry no frustum scores ({FRUSTUM_SCORES})")
        size = frame.image_size
        estimate = solve_frustum_pose(
            kp3d.xyz, matches.frustum, frame.K, size, frame.T_init, self.conf["variant"], self.options()
        )
        if not estimate.ok or len(matches) == 0:
            return estimate
        inside = frustum_labels(kp3d.xyz[matches.index3d], frame.K, estimate.T, size)
        return dataclasses.replace(estimate, inliers=np.flatnonzero(inside).astype(np.int64))
