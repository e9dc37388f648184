"""Rigid transforms and pinhole projection used by the protocol, ground-truth matching and metrics."""

from __future__ import annotations

import math

import numpy as np


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform, exact (no general matrix inversion)."""
    R, t = T[:3, :3], T[:3, 3]
    return make_transform(R.T, -R.T @ t)


def transform_points(T: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to [N x 3] points."""
    return xyz @ T[:3, :3].T + T[:3, 3]


def project(
    K: np.ndarray, T_cam_pts: np.ndarray, xyz: np.ndarray, min_depth: float = 0.1
) -> tuple[np.ndarray, np.ndarray]:
    """Project [N x 3] points with camera <- points transform; returns ([N x 2] pixels, [N] bool in front)."""
    cam = transform_points(T_cam_pts, xyz)
    depth = cam[:, 2]
    front = depth > min_depth
    safe = np.where(front, depth, 1.0)
    uv = (cam[:, :2] / safe[:, None]) @ K[:2, :2].T + K[:2, 2]
    return uv, front


def in_image(uv: np.ndarray, front: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Mask of projections that land inside an image of (width, height) pixels."""
    w, h = size
    return front & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)


def cell_half_diagonal(side_px: float) -> float:
    """px from a square cell's centre to its corners: within it, a point projecting anywhere in a cell of this side is
    as near its centre as the cell allows (11.31 px for 16 px cells, 45.25 for 64). A matcher whose pixels stand for
    cells (grid keypoints) sets it as `Matches.radius_px`, where eps_c (3 px) would credit only the centre."""
    return side_px / math.sqrt(2)
