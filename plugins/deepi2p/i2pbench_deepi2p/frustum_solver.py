"""The pose from frustum scores (Li & Lee, CVPR 2021, Sec. 4.2): minimise inverse_projection's C(T) from many starts.

Search: from seeded starts spread over yaw (translation set from the predicted-inside points), a local least-squares
solve of the paper's cost (Cauchy, 1 px) on a subset of the points; the paper likewise runs its Gauss-Newton solver
from 60 random starts. Polish: the few best candidates are solved again on every point with the bounded
Geman-McClure loss, and the lowest of those wins. The second loss is there for wrong labels far from the frustum:
under the Cauchy loss such a point's cost keeps growing (as a log) with its distance, so a pose that brings many of
them angularly nearer, a camera looking at the whole scan from afar, can cost less than the true one; a bounded loss
counts them instead. Measured on the toy scan of tests/test_deepi2p_geometry.py ending at +8 deg elevation, below
the frustum's top as a KITTI scan does, with 20% of labels flipped: a Cauchy polish put the camera 23-31 m away on
3 of 6 seeds, the bounded one within 0.85 m and 2.2 deg on all of 12. Its gradient vanishes far from a solution,
which is why it only polishes what the Cauchy search found.
The "3D" variant then frees all six degrees of freedom from the best planar pose (poses.py has both families).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from i2pbench.api import PoseEstimate

from .inverse_projection import (
    LOSSES,
    Faces,
    Pose,
    frustum_faces,
    frustum_residuals,
    residual_weights,
    residuals_and_jacobian,
    robust_cost,
)
from .poses import full_from_planar, full_pose, planar_pose, wrap_angle


@dataclass(frozen=True)
class FrustumOptions:
    """How the solver searches: the config of solver.py's component."""

    starts: int = 48  # local searches, one per yaw sector of 360 / starts degrees (the paper runs 60)
    start_depth_m: tuple[float, float] = (3.0, 30.0)  # a start puts the predicted-inside centroid this far ahead
    seed: int = 0  # seeds the starts' yaw jitter and depths, and the search subset
    search_points: int = 1000  # the searches run on a seeded subset of at most this many points
    search_sigma_px: float = 1.0  # the searches' Cauchy scale, the paper code's
    polished: int = 4  # this many of the best search results are solved again on every point ...
    sigma_px: float = 20.0  # ... with a Geman-McClure loss of this scale (pixels)
    margin_px: float = 0.0  # shrink the image by this much on every side
    max_translation_m: float = 20.0  # bound on |x| and |y| of M's translation (the protocol draws up to 10 m per axis)
    max_height_m: float = 2.0  # bound on |z| of M's translation in the 3D variant
    max_evaluations: int = 100  # residual evaluations per local solve
    min_inside: float = 3.0  # fail when the scores sum to less: too few points predicted in the frustum


@dataclass(frozen=True)
class FrustumSolution:
    """A solve's answer: the pose, the parameters of M it came from (see poses.py) and its cost."""

    T: np.ndarray  # [4 x 4] camera <- moved LiDAR
    params: np.ndarray  # planar (yaw, x, y) or full (rotation vector, translation)
    cost: float


@dataclass(frozen=True)
class Problem:
    """What a local solve fits: LiDAR points, their frustum scores, the image's frustum."""

    xyz: np.ndarray  # [N x 3] float64 moved LiDAR points
    scores: np.ndarray  # [N] float64 probabilities of lying in the frustum
    faces: Faces

    def subset(self, rows: np.ndarray) -> Problem:
        return Problem(self.xyz[rows], self.scores[rows], self.faces)

    def cost(self, T: np.ndarray, loss: str, sigma: float) -> float:
        """C(T) under `loss` of scale `sigma`."""
        return robust_cost(frustum_residuals(T, self.xyz, self.faces), self.scores, loss, sigma)


def local_solve(
    pose: Pose,
    start: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    problem: Problem,
    loss: tuple[str, float],
    max_evaluations: int,
) -> FrustumSolution:
    """Minimise C(pose(params)) under loss (name, scale) from `start` within `bounds`: scipy's trust-region
    reflective least squares, on the residuals whose weight is not 0 (a hard label keeps one per point)."""
    weights = residual_weights(problem.scores).ravel()
    kept = weights > 0
    last: dict[str, np.ndarray] = {}

    def residuals(params: np.ndarray) -> np.ndarray:
        r, J = residuals_and_jacobian(pose, params, problem.xyz, problem.faces)
        last.update(params=params.copy(), jacobian=J.reshape(-1, len(params))[kept])
        return r.ravel()[kept]

    def jacobian(params: np.ndarray) -> np.ndarray:
        if not np.array_equal(last.get("params"), params):
            residuals(params)
        return last["jacobian"]

    result = least_squares(
        residuals,
        np.clip(start, bounds[0] + 1e-6, bounds[1] - 1e-6),
        jac=jacobian,
        bounds=bounds,
        loss=lambda z: LOSSES[loss[0]](z, weights[kept], loss[1]),
        x_scale="jac",
        max_nfev=max_evaluations,
    )
    return FrustumSolution(pose(result.x), result.x, 2.0 * float(result.cost))  # scipy's cost is half the sum


def planar_starts(xyz: np.ndarray, scores: np.ndarray, T_base: np.ndarray, options: FrustumOptions) -> np.ndarray:
    """[S x 3] planar starts (yaw, x, y): one yaw per sector of the circle (seeded jitter), each start's translation
    putting the score-weighted centroid of the points on the camera's horizontal viewing axis, at a seeded depth."""
    rng = np.random.default_rng(options.seed)
    count = options.starts
    yaw = -np.pi + 2 * np.pi * (np.arange(count) + rng.random(count)) / count
    depth = rng.uniform(*options.start_depth_m, size=count)
    R, t = T_base[:3, :3], T_base[:3, 3]
    axis = R[2, :2] / max(float(np.linalg.norm(R[2, :2])), 1e-9)  # the optical axis in the LiDAR x-y plane
    target = (-R.T @ t)[:2] + depth[:, None] * axis  # that far ahead of the camera centre
    c = (scores @ xyz)[:2] / scores.sum()
    rotated = np.column_stack([np.cos(yaw) * c[0] - np.sin(yaw) * c[1], np.sin(yaw) * c[0] + np.cos(yaw) * c[1]])
    return np.column_stack([yaw, target - rotated])


def search_subset(count: int, options: FrustumOptions) -> np.ndarray:
    """Sorted rows of a seeded subset of at most options.search_points of `count` points."""
    if count <= options.search_points:
        return np.arange(count)
    return np.sort(np.random.default_rng(options.seed).choice(count, options.search_points, replace=False))


def problem_of(
    xyz: np.ndarray, scores: np.ndarray, K: np.ndarray, size: tuple[int, int], options: FrustumOptions
) -> Problem:
    """The points and scores as float64, with the frustum of a camera K and a (width, height) image."""
    faces = frustum_faces(K, size, options.margin_px)
    return Problem(np.asarray(xyz, np.float64), np.asarray(scores, np.float64), faces)


def solve_planar(
    xyz: np.ndarray,
    scores: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    T_base: np.ndarray,
    options: FrustumOptions = FrustumOptions(),
) -> FrustumSolution:
    """The best planar pose T = T_base @ M(yaw, x, y) (the paper's 2D variant); its cost is the polish loss's."""
    problem = problem_of(xyz, scores, K, size, options)
    search = problem.subset(search_subset(len(problem.xyz), options))
    b = options.max_translation_m
    bounds = (np.array([-np.inf, -b, -b]), np.array([np.inf, b, b]))
    cauchy, bounded = ("cauchy", options.search_sigma_px), ("geman-mcclure", options.sigma_px)
    n = options.max_evaluations

    def pose(params: np.ndarray) -> np.ndarray:
        return planar_pose(params, T_base)

    with threadpool_limits(1, user_api="blas"):  # [N x 3] systems: more BLAS threads only add overhead
        starts = planar_starts(search.xyz, search.scores, T_base, options)
        found = [local_solve(pose, start, bounds, search, cauchy, n) for start in starts]
        found.sort(key=lambda s: problem.cost(s.T, *bounded))
        polished = [local_solve(pose, s.params, bounds, problem, bounded, n) for s in found[: options.polished]]
    winner = min(polished, key=lambda s: s.cost)
    return FrustumSolution(winner.T, np.array([wrap_angle(winner.params[0]), *winner.params[1:]]), winner.cost)


def refine_full(
    planar: FrustumSolution,
    xyz: np.ndarray,
    scores: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    T_base: np.ndarray,
    options: FrustumOptions = FrustumOptions(),
) -> FrustumSolution:
    """Six-degree-of-freedom refinement (rotation vector, translation of M) of a planar solution: the 3D variant."""
    problem = problem_of(xyz, scores, K, size, options)
    b, z = options.max_translation_m, options.max_height_m
    bounds = (np.array([-np.inf] * 3 + [-b, -b, -z]), np.array([np.inf] * 3 + [b, b, z]))

    def pose(params: np.ndarray) -> np.ndarray:
        return full_pose(params, T_base)

    with threadpool_limits(1, user_api="blas"):
        start = full_from_planar(planar.params)
        return local_solve(pose, start, bounds, problem, ("geman-mcclure", options.sigma_px), options.max_evaluations)


def unusable_inputs(xyz: np.ndarray, scores: np.ndarray, T_base: np.ndarray | None, options: FrustumOptions) -> str:
    """Why these inputs cannot give a pose, or ''."""
    if T_base is None:
        return "no calibration (Frame.T_init): the planar search needs the camera's mount on the LiDAR"
    if xyz.shape != (len(scores), 3) or not (np.isfinite(xyz).all() and np.isfinite(scores).all()):
        return f"points {xyz.shape} and scores {scores.shape} must be finite, [N x 3] and [N]"
    if scores.min(initial=0.0) < 0.0 or scores.max(initial=0.0) > 1.0:
        return "frustum scores must be probabilities in [0, 1]"
    if scores.sum() < options.min_inside:
        return f"frustum scores sum to {scores.sum():.1f} < {options.min_inside}: too few points predicted inside"
    return ""


def solve_frustum_pose(
    xyz: np.ndarray,
    scores: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    T_base: np.ndarray | None,
    variant: str = "2d",
    options: FrustumOptions = FrustumOptions(),
) -> PoseEstimate:
    """The body of solver.py's component: a PoseEstimate, failed (never raising) when no pose can be fitted."""
    if variant not in ("2d", "3d"):
        raise ValueError(f"variant must be '2d' or '3d', got {variant!r}")
    xyz, scores = np.asarray(xyz, dtype=np.float64), np.asarray(scores, dtype=np.float64)
    reason = unusable_inputs(xyz, scores, T_base, options)
    if reason:
        return PoseEstimate.failed(reason)
    solution = solve_planar(xyz, scores, K, size, T_base, options)
    if variant == "3d":
        solution = refine_full(solution, xyz, scores, K, size, T_base, options)
    if not np.all(np.isfinite(solution.T)):
        return PoseEstimate.failed("the frustum solver returned a non-finite pose")
    return PoseEstimate(T=solution.T, message=f"frustum cost {solution.cost:.3g}")
