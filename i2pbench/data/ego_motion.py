"""The LiDAR's ego motion from its poses: what `SensorFrame.ego_motion` holds, for corruptions that move a scan in time.

A dataset that knows where its LiDAR was (KITTI's ground-truth poses, nuScenes' ego poses) gives the sensor's velocity
at the scan's time as a finite difference of two poses around it: central when the scan lies between them, one-sided
at a sequence's ends. Linear and angular velocity are both expressed in the LiDAR's own frame at the scan.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def velocity(before: np.ndarray, t_before: float, after: np.ndarray, t_after: float, at: np.ndarray) -> np.ndarray:
    """[6] (vx, vy, vz in m/s, wx, wy, wz in rad/s) of a sensor with poses `before` and `after` (world <- sensor,
    [4 x 4]) at those times (s), in its own frame at pose `at` (the scan's: one of the two, or one between)."""
    dt = t_after - t_before
    if not dt > 0:
        raise ValueError(f"the two poses must be in time order, {t_before} s then {t_after} s")
    R_at = at[:3, :3]
    v = R_at.T @ (after[:3, 3] - before[:3, 3]) / dt
    turn = Rotation.from_matrix(before[:3, :3].T @ after[:3, :3]).as_rotvec() / dt  # in the frame `before`
    return np.concatenate([v, R_at.T @ before[:3, :3] @ turn])


def around(poses: np.ndarray, times: np.ndarray, i: int) -> np.ndarray | None:
    """The velocity at pose `i` of a sequence (poses [n x 4 x 4], times [n] s): central from its neighbours, one-sided
    at either end; None for a sequence of one pose, which says nothing about motion."""
    a, b = max(i - 1, 0), min(i + 1, len(poses) - 1)
    if a == b:
        return None
    return velocity(poses[a], float(times[a]), poses[b], float(times[b]), poses[i])
