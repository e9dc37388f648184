"""Ground-truth 2D-3D correspondences: project 3D keypoints with T_gt, pair each with the nearest 2D keypoint.

Used by the oracle matcher, the edge-quality diagnostics, training losses and the inlier ratio of a run's matches,
so all of them agree on what a true match is: a 3D keypoint whose projection lies within eps_c pixels of a 2D
keypoint. The projection uses the camera that formed the image (`Frame.K_true`), not a corrupted calibration the
stages may be given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..types import Frame, Keypoints2D, Keypoints3D
from .transforms import in_image, project


@dataclass(frozen=True)
class GroundTruthMatches:
    index2d: np.ndarray  # [K] int64 rows of Keypoints2D
    index3d: np.ndarray  # [K] int64 rows of Keypoints3D (each 3D keypoint appears at most once)
    distance_px: np.ndarray  # [K] float64 reprojection distance of the pair
    in_fov3d: np.ndarray  # [M3] bool: projects in front of the camera and inside the image
    matchable2d: np.ndarray  # [M2] bool: has at least one true partner
    matchable3d: np.ndarray  # [M3] bool

    def __len__(self) -> int:
        return int(self.index2d.shape[0])


def ground_truth_matches(
    frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, radius_px: float | None = None
) -> GroundTruthMatches:
    if frame.T_gt is None:
        raise ValueError("ground_truth_matches needs a frame with T_gt")
    radius = frame.match_radius_px if radius_px is None else radius_px
    uv, front = project(frame.K_true, frame.T_gt, kp3d.xyz.astype(np.float64))
    in_fov = in_image(uv, front, frame.image_size)
    candidates = np.flatnonzero(in_fov)
    if len(kp2d) == 0 or candidates.size == 0:
        index2d, index3d, dist = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    else:
        dist, nearest = cKDTree(kp2d.uv.astype(np.float64)).query(uv[candidates], k=1)
        keep = dist < radius
        index2d, index3d, dist = nearest[keep].astype(np.int64), candidates[keep].astype(np.int64), dist[keep]
    matchable2d = np.zeros(len(kp2d), bool)
    matchable2d[index2d] = True
    matchable3d = np.zeros(len(kp3d), bool)
    matchable3d[index3d] = True
    return GroundTruthMatches(index2d, index3d, dist, in_fov, matchable2d, matchable3d)


def true_match_mask(frame: Frame, uv: np.ndarray, xyz: np.ndarray, radius_px: float | None = None) -> np.ndarray:
    """[K] bool: which matched pairs (pixel uv[k], LiDAR point xyz[k]) are true under T_gt, i.e. the point projects
    in front of the camera within eps_c pixels of its pixel."""
    if frame.T_gt is None:
        raise ValueError("true_match_mask needs a frame with T_gt")
    radius = frame.match_radius_px if radius_px is None else radius_px
    projected, front = project(frame.K_true, frame.T_gt, np.asarray(xyz, np.float64).reshape(-1, 3))
    distance = np.linalg.norm(projected - np.asarray(uv, np.float64).reshape(-1, 2), axis=1)
    return front & (distance < radius)
