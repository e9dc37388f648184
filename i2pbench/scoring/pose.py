"""Registration metrics exactly as the peers compute them, plus the geodesic angle for cross-paper comparison.

P_diff = inv(T_pred) @ T_gt; RTE = ||P_diff[:3, 3]||; RRE = sum |extrinsic 'xzy' Euler angles of P_diff| in degrees
(scipy's convention, lowercase = extrinsic). A failed solve has infinite errors.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from ..geometry.transforms import invert
from .protocol import Protocol


@dataclass(frozen=True)
class PoseErrors:
    rte_m: float
    rre_deg: float
    geodesic_deg: float


FAILED = PoseErrors(math.inf, math.inf, math.inf)


def pose_errors(T_pred: np.ndarray | None, T_gt: np.ndarray) -> PoseErrors:
    if T_pred is None or not np.all(np.isfinite(T_pred)):
        return FAILED
    P_diff = invert(np.asarray(T_pred, dtype=np.float64)) @ np.asarray(T_gt, dtype=np.float64)
    R = P_diff[:3, :3]
    rre = float(np.abs(xzy_euler_deg(R)).sum())
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return PoseErrors(float(np.linalg.norm(P_diff[:3, 3])), rre, float(np.degrees(np.arccos(cos))))


def xzy_euler_deg(R: np.ndarray) -> np.ndarray:
    """scipy's extrinsic 'xzy' angles, as the peers' scripts compute them. At gimbal lock (the z angle at +-90 deg)
    the split between x and y is not unique; scipy then sets the y angle to 0 and puts the whole remaining rotation
    in x, with a warning. That is the peers' number too, so it is kept, and the warning (which says nothing the
    geodesic angle beside it does not) is silenced here rather than left to every caller's output."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected", category=UserWarning)
        return Rotation.from_matrix(R).as_euler("xzy", degrees=True)


def success(rte: pd.Series, rre: pd.Series, protocol: Protocol) -> pd.Series:
    return (rre < protocol.acc_rre_deg) & (rte < protocol.acc_rte_m)


def kept(rte: pd.Series, rre: pd.Series, protocol: Protocol) -> pd.Series:
    """The frames inside the protocol's filter, over which a board averages RTE and RRE (a failure never is)."""
    rte, rre = pd.Series(rte, dtype=float), pd.Series(rre, dtype=float)
    return (rre < protocol.filter_rre_deg) & (rte < protocol.filter_rte_m)
