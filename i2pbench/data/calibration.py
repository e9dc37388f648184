"""Checks on calibration read from disk: a bad K or a non-rigid extrinsic must stop at the reader, named.

Without them a singular K surfaces as a LinAlgError deep in the protocol, and a non-rigid `Tr` or a NaN in `P2`
runs to the end and gives metrics that mean nothing.
"""

from __future__ import annotations

import numpy as np

from ..errors import DataError

ROTATION_TOL = 1e-3  # |R^T R - I| and |det R - 1|: calibration files carry 6+ digits, so 1e-3 is a broken one
SINGULAR_COND = 1e12  # condition number beyond which K cannot be inverted meaningfully


def check_finite(values: np.ndarray, where: str, what: str) -> None:
    """Refuse NaN or inf in `what`."""
    bad = ~np.isfinite(values)
    if bad.any():
        raise DataError(f"{where}: {what} holds {int(bad.sum())} NaN or inf value(s)")


def check_intrinsics(K: np.ndarray, where: str) -> None:
    """K [3 x 3] must be finite, have positive focal lengths and be invertible."""
    if K.shape != (3, 3):
        raise DataError(f"{where}: K has shape {K.shape}, expected (3, 3)")
    check_finite(K, where, "K")
    fx, fy = float(K[0, 0]), float(K[1, 1])
    if fx <= 0 or fy <= 0:
        raise DataError(f"{where}: K has focal lengths fx={fx:g}, fy={fy:g}; both must be positive")
    if np.linalg.cond(K) > SINGULAR_COND:
        raise DataError(f"{where}: K is singular (not invertible): {K.tolist()}")


def check_rotation(R: np.ndarray, where: str, what: str) -> None:
    """R [3 x 3] must be a rotation: orthonormal and det +1, within ROTATION_TOL."""
    check_finite(R, where, what)
    off = float(np.abs(R.T @ R - np.eye(3)).max())
    if off > ROTATION_TOL:
        raise DataError(f"{where}: {what} is not a rotation (|R^T R - I| = {off:.3g} > {ROTATION_TOL:g})")
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > ROTATION_TOL:
        raise DataError(f"{where}: {what} is not a rotation (det R = {det:.6g}, expected +1)")
