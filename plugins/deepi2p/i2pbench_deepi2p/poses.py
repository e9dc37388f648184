"""The two pose families the inverse-projection solver searches, both relative to the known calibration T_base.

Planar ("2D", the family docs/protocol.md draws from): the protocol moves the scan by T_rand, a yaw about LiDAR z and
a translation in the LiDAR x-y plane, so T_gt = T_base @ inv(T_rand) with T_base = T_cam_lidar; inv(T_rand) is again
a yaw plus a planar translation, M(yaw, x, y) = [Rz(yaw) | (x, y, 0)], which maps the moved scan back to the sensor's
LiDAR frame. Full ("3D"): M = [R(rotation vector r) | t], six parameters (the paper's 3D variant, Sec. 4.2).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from i2pbench.api import make_transform, rot_z


def planar_pose(params: np.ndarray, T_base: np.ndarray) -> np.ndarray:
    """[4 x 4] camera <- moved LiDAR for params (yaw rad, x m, y m): T_base @ [Rz(yaw) | (x, y, 0)]."""
    yaw, x, y = params
    return T_base @ make_transform(rot_z(yaw), np.array([x, y, 0.0]))


def planar_params(M: np.ndarray) -> np.ndarray:
    """(yaw, x, y) of a planar transform M (the inverse of planar_pose's M; M's tilt and z are ignored)."""
    return np.array([np.arctan2(M[1, 0], M[0, 0]), M[0, 3], M[1, 3]])


def full_pose(params: np.ndarray, T_base: np.ndarray) -> np.ndarray:
    """[4 x 4] camera <- moved LiDAR for params (rotation vector [3] rad, translation [3] m) of M."""
    return T_base @ make_transform(Rotation.from_rotvec(params[:3]).as_matrix(), np.asarray(params[3:]))


def full_from_planar(params: np.ndarray) -> np.ndarray:
    """The 6 full-family params of the same pose as planar params (yaw, x, y)."""
    yaw, x, y = params
    return np.array([0.0, 0.0, yaw, x, y, 0.0])


def wrap_angle(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)
