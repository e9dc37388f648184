"""PnP solvers: EPnP inside OpenCV's RANSAC (the paper's and its reference code's choice) and PoseLib's LO-RANSAC.

Both return T (camera <- moved LiDAR) and the inlier rows of the matches. Too few matches, a degenerate point set or
a solver that gives up yields PoseEstimate.failed(reason), never an exception, so one bad frame cannot end a run.
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np
import poselib

from i2pbench.api import Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate, PoseSolver, make_transform

MIN_MATCHES = 4


def matched_points(kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> tuple[np.ndarray, np.ndarray]:
    """([K x 2] pixels, [K x 3] points) of the matched pairs, float64."""
    return kp2d.uv[matches.index2d].astype(np.float64), kp3d.xyz[matches.index3d].astype(np.float64)


def degeneracy(uv: np.ndarray, xyz: np.ndarray) -> str | None:
    """Why these correspondences cannot determine a pose, or None: too few, or points that span a line at most."""
    if len(uv) < MIN_MATCHES:
        return f"{len(uv)} matches; PnP needs at least {MIN_MATCHES}"
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(xyz))):
        return "non-finite keypoint coordinates"
    for name, pts in (("3D", xyz), ("2D", uv)):
        s = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if s[0] <= 1e-9 or s[1] <= 1e-6 * s[0]:
            return f"degenerate configuration: the {name} points are collinear or coincide"
    return None


def finite_pose(T: np.ndarray, inliers: np.ndarray, solver: str) -> PoseEstimate:
    if not np.all(np.isfinite(T)):
        return PoseEstimate.failed(f"{solver} returned a non-finite pose")
    return PoseEstimate(T=T, inliers=inliers.astype(np.int64))


class EPnPRansacSolver(PoseSolver):
    """cv2.solvePnPRansac with flags=SOLVEPNP_EPNP and no distortion, as EdgeRegNet's reference code.

    5000 iterations, 6.5 px threshold; confidence 0.99 is OpenCV's default, which the reference code leaves as is.
    OpenCV fits EPnP on minimal samples and refits EPnP on all inliers of the best one.
    """

    name = "epnp-ransac"
    default_conf: ClassVar[dict[str, Any]] = {
        "iterations": 5000,  # RANSAC iterationsCount
        "reprojection_error_px": 6.5,  # inlier threshold
        "confidence": 0.99,  # OpenCV's default (stops early once reached)
        "seed": 0,  # cv2.setRNGSeed before each solve, so repeated runs agree
    }

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        uv, xyz = matched_points(kp2d, kp3d, matches)
        reason = degeneracy(uv, xyz)
        if reason:
            return PoseEstimate.failed(reason)
        cv2.setRNGSeed(int(self.conf["seed"]))
        try:
            ok, rvec, tvec, inliers = cv2.solvePnPRansac(
                xyz,
                uv,
                frame.K.astype(np.float64),
                None,
                iterationsCount=int(self.conf["iterations"]),
                reprojectionError=float(self.conf["reprojection_error_px"]),
                confidence=float(self.conf["confidence"]),
                flags=cv2.SOLVEPNP_EPNP,
            )
        except cv2.error as exc:
            return PoseEstimate.failed(f"cv2.solvePnPRansac: {str(exc).strip().splitlines()[-1]}")
        if not ok or inliers is None:
            return PoseEstimate.failed("RANSAC found no pose with enough inliers")
        T = make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel())
        return finite_pose(T, inliers.ravel(), self.name)


class PoseLibSolver(PoseSolver):
    """PoseLib's LO-RANSAC (P3P on minimal samples, local optimisation) with non-linear refinement of the result.

    The camera is PINHOLE (fx, fy, cx, cy) from K; K's skew, if any, is ignored (KITTI and nuScenes have none).
    """

    name = "poselib"
    default_conf: ClassVar[dict[str, Any]] = {
        "max_reproj_error": 6.5,  # inlier threshold in pixels, as epnp-ransac
        "max_iterations": 100000,  # PoseLib's defaults: it stops once success_prob is reached
        "min_iterations": 1000,
        "success_prob": 0.9999,
        "seed": 0,  # PoseLib's RANSAC seed
    }

    def camera(self, frame: Frame) -> dict[str, Any]:
        width, height = frame.image_size
        K = frame.K
        return {"model": "PINHOLE", "width": width, "height": height, "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        uv, xyz = matched_points(kp2d, kp3d, matches)
        reason = degeneracy(uv, xyz)
        if reason:
            return PoseEstimate.failed(reason)
        ransac = {key: self.conf[key] for key in self.default_conf}
        try:
            pose, info = poselib.estimate_absolute_pose(uv, xyz, self.camera(frame), ransac, {})
        except (RuntimeError, ValueError) as exc:
            return PoseEstimate.failed(f"poselib: {exc}")
        inliers = np.flatnonzero(np.asarray(info["inliers"], dtype=bool))
        if inliers.size < MIN_MATCHES:
            return PoseEstimate.failed(f"poselib kept {inliers.size} inliers; at least {MIN_MATCHES} are needed")
        return finite_pose(make_transform(np.asarray(pose.R), np.asarray(pose.t)), inliers, self.name)
