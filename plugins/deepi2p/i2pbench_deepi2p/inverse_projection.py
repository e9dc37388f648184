"""DeepI2P's inverse camera projection objective (Li & Lee, CVPR 2021, Sec. 4.2): how badly a pose contradicts
each LiDAR point's predicted probability s_i of lying in the camera frustum.

The frustum of a W x H image is the cone bounded by four planes through the camera centre, the rays through
u = -0.5, u = W - 0.5, v = -0.5 and v = H - 0.5 (labels.py's image extent, moved inwards by a margin if one is set).
For a point p in camera coordinates, d_k = c_k (n_k . p) / |p| is its signed distance to face k, positive inside:
n_k . p / |p| is the sine of the angle between the point's ray and the face (n_k the unit inward normal), and
c_k = |a_k|^2 / f_k (a_k the unnormalised normal, f_k the focal length across that border) makes d_k the distance in
pixels to that border, to first order, at the border's midpoint. Per point, two residuals:
  in-residual   r_i = |(max(0, -d_ik))_k|    how far outside the faces it is (0 inside)
  out-residual  o_i = max(0, min_k d_ik)     how far inside the frustum: the distance to the nearest border
  C(T) = sum_i [ s_i rho(r_i^2) + (1 - s_i) rho(o_i^2) ]
with rho a robust loss of scale sigma (pixels): the paper code's Cauchy, sigma^2 log(1 + z / sigma^2), or the bounded
Geman-McClure, sigma^2 z / (sigma^2 + z). For hard labels and the Cauchy loss this is the paper's cost, one robust
term per point as in its code, with two changes: distances are angular, so they stay defined and continuous behind
the camera, where pixel coordinates flip (a point behind the camera is outside at least two faces, so the paper's
separate depth penalty is not needed); and an out-labelled point inside the image costs its distance to the nearest
border rather than the sum of its distances to the nearer u and v borders. The residuals are hinges, so C is
continuously differentiable, and exactly 0 at every pose consistent with all labels.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from i2pbench.api import transform_points

Pose = Callable[[np.ndarray], np.ndarray]  # params -> [4 x 4] camera <- moved LiDAR
Faces = tuple[np.ndarray, np.ndarray]  # ([4 x 3] unit inward normals, [4] pixel scales c_k): left, right, top, bottom
Loss = Callable[[np.ndarray, np.ndarray, float], np.ndarray]  # (z = r^2, weights, sigma) -> [3 x M]


def frustum_faces(K: np.ndarray, size: tuple[int, int], margin_px: float = 0.0) -> Faces:
    """Unit inward normals and pixel scales c_k of the frustum's faces, for a camera with intrinsics K."""
    w, h = size
    lo, hi_u, hi_v = -0.5 + margin_px, w - 0.5 - margin_px, h - 0.5 - margin_px
    # u >= lo  <=>  (K[0] - lo K[2]) . p >= 0 for p in front of the camera; likewise for the other three borders
    a = np.stack([K[0] - lo * K[2], hi_u * K[2] - K[0], K[1] - lo * K[2], hi_v * K[2] - K[1]])
    norm = np.linalg.norm(a, axis=1)
    focal = np.array([K[0, 0], K[0, 0], K[1, 1], K[1, 1]])
    return a / norm[:, None], norm**2 / focal


def unit_rays(p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """([N x 3] unit directions, [N x 1] distances) of camera-frame points (a point at the centre counts as 1e-9 m)."""
    radius = np.maximum(np.linalg.norm(p_cam, axis=1, keepdims=True), 1e-9)
    return p_cam / radius, radius


def face_distances(p_cam: np.ndarray, faces: Faces) -> np.ndarray:
    """[N x 4] signed pixel-equivalent distances d_k of camera-frame points [N x 3] to the faces, positive inside."""
    unit, _ = unit_rays(p_cam)
    return (unit @ faces[0].T) * faces[1]


def hinge_residuals(d: np.ndarray) -> np.ndarray:
    """[N x 2] in- and out-residuals (r_i, o_i) from face distances [N x 4]."""
    return np.column_stack([np.linalg.norm(np.maximum(-d, 0.0), axis=1), np.maximum(d.min(axis=1), 0.0)])


def hinge_jacobian(d: np.ndarray, dd: np.ndarray) -> np.ndarray:
    """[N x 2 x P] derivatives of hinge_residuals(d) given those of d, [N x 4 x P]; 0 where a residual is 0."""
    outside = np.maximum(-d, 0.0)
    r_in = np.linalg.norm(outside, axis=1)
    j_in = -(outside[:, :, None] * dd).sum(axis=1) / np.maximum(r_in, 1e-12)[:, None]  # d|h| = h . dh / |h|
    rows, nearest = np.arange(len(d)), d.argmin(axis=1)
    j_out = np.where((d[rows, nearest] > 0)[:, None], dd[rows, nearest], 0.0)
    return np.stack([j_in, j_out], axis=1)


def frustum_residuals(T: np.ndarray, xyz: np.ndarray, faces: Faces) -> np.ndarray:
    """[N x 2] in- and out-residuals of LiDAR points [N x 3] under pose T (camera <- LiDAR)."""
    return hinge_residuals(face_distances(transform_points(T, xyz), faces))


def pose_derivatives(pose: Pose, params: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """[P x 4 x 4] derivatives of the pose matrix in each parameter (central differences of 4 x 4 matrices)."""
    return np.stack([(pose(params + e) - pose(params - e)) / (2 * step) for e in np.eye(len(params)) * step])


def distance_derivative(dp: np.ndarray, unit: np.ndarray, radius: np.ndarray, faces: Faces) -> np.ndarray:
    """[N x 4] derivative of the face distances along a motion dp [N x 3] of the points: d_k = c_k n_k . p^ with
    p^ = p / |p|, and p^ moves by (dp - (p^ . dp) p^) / |p|."""
    normals, scales = faces
    along = (unit * dp).sum(axis=1, keepdims=True)
    return scales * (dp @ normals.T - along * (unit @ normals.T)) / radius


def residuals_and_jacobian(
    pose: Pose, params: np.ndarray, xyz: np.ndarray, faces: Faces
) -> tuple[np.ndarray, np.ndarray]:
    """([N x 2] residuals, [N x 2 x P] their derivatives in the params) of LiDAR points under pose(params)."""
    unit, radius = unit_rays(transform_points(pose(params), xyz))
    # a pose derivative dT moves the points by dR x + dt, which is what transform_points computes
    dd = [distance_derivative(transform_points(dT, xyz), unit, radius, faces) for dT in pose_derivatives(pose, params)]
    d = (unit @ faces[0].T) * faces[1]
    return hinge_residuals(d), hinge_jacobian(d, np.stack(dd, axis=-1))


def residual_weights(scores: np.ndarray) -> np.ndarray:
    """[N x 2]: s_i for the in-residual, 1 - s_i for the out-residual."""
    s = np.asarray(scores, dtype=np.float64)
    return np.column_stack([s, 1.0 - s])


def cauchy(z: np.ndarray, weights: np.ndarray, sigma: float) -> np.ndarray:
    """[3 x M]: w sigma^2 log(1 + z / sigma^2) and its first two derivatives in z = r^2 (scipy's loss form)."""
    t = 1.0 + z / sigma**2
    return np.stack([weights * sigma**2 * np.log(t), weights / t, -weights / (sigma**2 * t**2)])


def geman_mcclure(z: np.ndarray, weights: np.ndarray, sigma: float) -> np.ndarray:
    """[3 x M]: w sigma^2 z / (sigma^2 + z), at most w sigma^2, and its first two derivatives in z = r^2."""
    t = sigma**2 + z
    return np.stack([weights * sigma**2 * z / t, weights * sigma**4 / t**2, -2.0 * weights * sigma**4 / t**3])


LOSSES: dict[str, Loss] = {"cauchy": cauchy, "geman-mcclure": geman_mcclure}


def frustum_cost(
    T: np.ndarray,
    xyz: np.ndarray,
    scores: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    loss: str = "cauchy",
    sigma_px: float = 1.0,
    margin_px: float = 0.0,
) -> float:
    """C(T): how badly pose T (camera <- LiDAR) contradicts the frustum scores [N] of the points [N x 3]."""
    r = frustum_residuals(T, np.asarray(xyz, dtype=np.float64), frustum_faces(K, size, margin_px))
    return robust_cost(r, scores, loss, sigma_px)


def robust_cost(residuals: np.ndarray, scores: np.ndarray, loss: str, sigma: float) -> float:
    """C from the [N x 2] residuals and [N] scores: the weighted sum of the loss over every residual."""
    return float(LOSSES[loss](residuals.ravel() ** 2, residual_weights(scores).ravel(), sigma)[0].sum())
