"""DeepI2P's two pose solvers as its authors run them, from per-point classifier outputs.

- Grid classification + PnP (evaluation/registration_pnp.py `solve_PnP`): the points classified inside the image,
  each paired with its predicted fine cell's integer (column, row) in cell units (the authors pass the cell index,
  i.e. its corner, not its centre) and K scaled by 1/32; EPnP in RANSAC, 500 iterations, 0.6 cell; a solution whose
  translation is 14.14 m or longer, or a failed one, becomes the identity.
- Frustum classification + optimisation (evaluation/registration_lsq.py with the Ceres problems of
  frustum_reg/src): a yaw initial guess turning the mean inside point to the optical axis, the points more than 10 m
  behind the nearest inside one dropped, then restarts from that yaw perturbed (sigma 10 deg) and a forward offset in
  [-10, 10] m, each a bounded robust least squares (Cauchy loss, scale 1, on each point's residual block) of the frustum
  residuals, the lowest final cost kept. Ceres's trust region is replaced by scipy's `least_squares` (trf, same
  bounds, the same cost): docs/methods.md.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

FINE_SCALE = 1 / 32.0
PNP_ITERATIONS, PNP_THRESHOLD, PNP_MAX_TRANSLATION = 500, 0.6, 14.14
RESTARTS, YAW_SIGMA, FORWARD_AMPLITUDE = 60, 10 * math.pi / 180, 10.0
T_BOUNDS = ((-5.0, -0.1, -10.0), (5.0, 0.1, 10.0))  # registration_lsq.py's __main__ (x, y, z in the camera frame)


def solve_pnp(
    pc: np.ndarray, coarse: np.ndarray, fine: np.ndarray, K: np.ndarray, hw: tuple[int, int]
) -> tuple[np.ndarray, float]:
    """[3 x N] points, coarse [N] (1 = inside), fine [N] cell index, K of the H x W input -> (4 x 4 camera <- points,
    outlier ratio; 1 and the identity on failure)."""
    inside = coarse == 1
    points, cells = pc[:, inside].astype(np.float64), fine[inside]
    width = hw[1] * FINE_SCALE
    rows = np.floor(cells / width)
    pixels = np.stack([cells - rows * width, rows]).astype(np.float64)
    K_fine = FINE_SCALE * K.astype(np.float64)
    K_fine[2, 2] = 1
    if points.shape[1] < 4:
        return np.eye(4), 1.0
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points.T, pixels.T, K_fine, None, useExtrinsicGuess=False, iterationsCount=PNP_ITERATIONS,
        reprojectionError=PNP_THRESHOLD, flags=cv2.SOLVEPNP_EPNP,
    )  # fmt: skip
    if not ok or np.linalg.norm(tvec) >= PNP_MAX_TRANSLATION:
        return np.eye(4), 1.0
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = cv2.Rodrigues(rvec)[0], tvec[:, 0]
    return pose, 1 - len(inliers) / len(cells)


def yaw_matrix(angle: float) -> np.ndarray:
    return np.array([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]])


def initial_guess(pc: np.ndarray, coarse: np.ndarray) -> tuple[float, np.ndarray]:
    """(yaw turning the inside points' mean onto the optical axis, mask of the points kept: not more than 10 m
    behind the nearest inside point once turned)."""
    mean = pc[:, coarse == 1].mean(axis=1)
    yaw = math.remainder(math.atan2(mean[2], mean[0]) - math.pi / 2, 2 * math.pi)
    turned = yaw_matrix(yaw) @ pc
    return yaw, turned[2] > turned[2, coarse == 1].min() - 10


def frustum_residuals(
    params: np.ndarray, pc: np.ndarray, coarse: np.ndarray, K: np.ndarray, hw: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """the Ceres problems' residuals (registration_2d/3d.hpp), H and W minus one as the authors pass them:
    inside points: distance outside the image in x, in y, and 100 x behind the camera; outside points: the summed
    distances to the image border when they project inside it and in front, else 0."""
    angle_axis = np.array([0, params[0], 0]) if len(params) == 4 else params[:3]
    p = Rotation.from_rotvec(angle_axis).as_matrix() @ pc + params[-3:, None]
    x, y = K[0, 0] * p[0] / p[2] + K[0, 2], K[1, 1] * p[1] / p[2] + K[1, 2]
    h, w = hw[0] - 1.0, hw[1] - 1.0
    inside = coarse == 1
    r_in = np.stack([np.maximum(-x, 0) + np.maximum(x - w, 0), np.maximum(-y, 0) + np.maximum(y - h, 0),
                     100 * np.maximum(-p[2], 0)])[:, inside]  # fmt: skip
    dx, dy = w / 2 - np.abs(x - w / 2), h / 2 - np.abs(y - h / 2)
    r_out = ((dx + dy) * (p[2] > 0) * (dx > 0) * (dy > 0))[coarse == 0]
    return r_in, r_out


def robust_residuals(params: np.ndarray, *problem) -> np.ndarray:
    """one residual per Ceres residual block, sqrt(rho(|f|^2)) with rho the Cauchy loss log(1 + s): its squares sum
    to twice Ceres's cost (the loss applies to each block's squared norm, an inside point's 3 residuals together)."""
    r_in, r_out = frustum_residuals(params, *problem)
    return np.sqrt(np.log1p(np.concatenate([(r_in**2).sum(axis=0), r_out**2])))


def solve_frustum_once(
    pc: np.ndarray, coarse: np.ndarray, K: np.ndarray, hw: tuple[int, int], yaw: float, t0: np.ndarray, is_2d: bool,
    max_iter: int = 500,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """one restart -> (4 x 4 pose, final cost: half the summed Cauchy-robustified squared residuals, as Ceres)."""
    x0 = np.r_[yaw, t0] if is_2d else np.r_[0.0, yaw, 0.0, t0]
    lower = np.r_[[-np.inf] * (len(x0) - 3), T_BOUNDS[0]]
    upper = np.r_[[np.inf] * (len(x0) - 3), T_BOUNDS[1]]
    fit = least_squares(
        robust_residuals, np.clip(x0, lower, upper), bounds=(lower, upper), method="trf", max_nfev=max_iter,
        args=(pc, coarse, K, hw),
    )  # fmt: skip
    angle_axis = np.array([0, fit.x[0], 0]) if is_2d else fit.x[:3]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = Rotation.from_rotvec(angle_axis).as_matrix(), fit.x[-3:]
    return pose, float(fit.cost)


def restarts(yaw: float, rng: np.random.Generator, count: int = RESTARTS) -> list[tuple[float, np.ndarray]]:
    """the perturbed starts of solve_P_random_perturb: yaw + N(0, 10 deg), translation (0, 0, U(-10, 10))."""
    return [(yaw + rng.normal(0, YAW_SIGMA), np.array([0, 0, rng.uniform(-FORWARD_AMPLITUDE, FORWARD_AMPLITUDE)]))
            for _ in range(count)]  # fmt: skip


def solve_frustum(
    pc: np.ndarray, coarse: np.ndarray, K: np.ndarray, hw: tuple[int, int],
    starts: list[tuple[float, np.ndarray]] | None = None, is_2d: bool = True, rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """the frustum registration: initial guess, restarts (drawn from `rng` unless given), lowest cost kept ->
    (4 x 4 pose, cost); the identity and cost 1e4 when no point is classified inside, as the authors."""
    if not (coarse == 1).any():
        return np.eye(4), 1e4
    yaw, front = initial_guess(pc, coarse)
    starts = starts if starts is not None else restarts(yaw, rng or np.random.default_rng(0))
    fits = [solve_frustum_once(pc[:, front], coarse[front], K, hw, y, t, is_2d) for y, t in starts]
    return min(fits, key=lambda fit: fit[1])
