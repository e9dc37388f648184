"""CoFiI2P's pose solver (evaluation/eval_all.py:107-113): OpenCV's solvePnPRansac called as the authors call it,
on the coordinates they call it with.

Their call passes the fine-map pixels (x, y on the 1/2-scale map of the 160 x 512 crop) with K_2, K of that map
(data/kitti.py:306-325: K of the whole image, x 0.5, the crop's offsets, x 0.5 again; rows cut first if `top_rows`),
the chosen coarse points in the network's axes, `iterationsCount=10000`, `distCoeffs=None`, and OpenCV's defaults
for the rest: SOLVEPNP_ITERATIVE, 8.0 px (on that map: 32 px of a full-size KITTI image), confidence 0.99. This
stage maps each matched pixel back to its fine-map cell and each point into network axes (prepare.py), makes the
same call (in float32, as their tensors are), and returns the pose of the frame's points: the network-axes pose
composed with `network_axes(frame)`. OpenCV's RANSAC generator is seeded before each call (`seed`), where theirs
runs on in one process.
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np

from i2pbench.api import Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate, PoseSolver, make_transform
from i2pbench.layers.peer_inputs import crop_offsets

from .prepare import CELL_PX, CROP, loader_crop, network_axes, to_network

MIN_MATCHES = 4  # fewer and OpenCV raises; the authors' network keeps lowering its threshold until it has 4


def fine_camera(K: np.ndarray, width: int, height: int, crop: dict[str, Any]) -> np.ndarray | None:
    """K_2 of data/kitti.py:306-325 for a frame of this size and K (rows cut, scale, crop offsets, x 0.5) -> [3 x 3]
    float32;
    None for a frame too small for the crop."""
    crop = loader_crop(width, height, crop)
    offsets = crop_offsets(width, height, crop)
    if offsets is None:
        return None
    fine = np.asarray(K, np.float32).copy()
    fine[1, 2] -= crop.get("top_rows", 0)  # rows cut first, if any
    fine = fine * np.float32(crop["scale"])
    fine[2, 2] = 1
    fine[0, 2] -= offsets[0]
    fine[1, 2] -= offsets[1]
    fine = fine * np.float32(1 / CELL_PX)
    fine[2, 2] = 1
    return fine


def fine_coordinates(uv: np.ndarray, width: int, height: int, crop: dict[str, Any]) -> np.ndarray:
    """full-size pixels [M x 2] -> their (x, y) on the fine map (the inverse of the grid's cell corners), float32."""
    crop = loader_crop(width, height, crop)
    dx, dy = crop_offsets(width, height, crop)
    scale = crop["scale"]
    shifted = np.asarray(uv, np.float64) - [0, crop.get("top_rows", 0)]
    return ((shifted * scale - [dx, dy]) / CELL_PX).astype(np.float32)


class OfficialPnP(PoseSolver):
    """eval_all.py's solvePnPRansac on the fine map (module docstring)."""

    name = "cofii2p-official-pnp"
    default_conf: ClassVar[dict[str, Any]] = {
        "iterations": 10000,  # eval_all.py:107 iterationsCount
        "reprojection_error_px": 8.0,  # OpenCV's default, in pixels of the fine map
        "confidence": 0.99,  # OpenCV's default
        "seed": 0,  # cv2.setRNGSeed before each solve
        **CROP,
    }

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        if len(matches) < MIN_MATCHES:
            return PoseEstimate.failed(f"{len(matches)} matches; PnP needs at least {MIN_MATCHES}")
        width, height = frame.image_size
        K = fine_camera(frame.K, width, height, self.conf)
        if K is None:
            return PoseEstimate.failed(f"a {width} x {height} image cannot hold the crop {self.conf['crop']}")
        pixels = fine_coordinates(kp2d.uv[matches.index2d], width, height, self.conf)
        points = to_network(frame, kp3d.xyz[matches.index3d])
        cv2.setRNGSeed(int(self.conf["seed"]))
        try:
            ok, rvec, tvec, inliers = cv2.solvePnPRansac(
                objectPoints=points,
                imagePoints=pixels,
                cameraMatrix=K,
                distCoeffs=None,
                iterationsCount=int(self.conf["iterations"]),
                reprojectionError=float(self.conf["reprojection_error_px"]),
                confidence=float(self.conf["confidence"]),
            )
        except cv2.error as exc:
            return PoseEstimate.failed(f"cv2.solvePnPRansac: {str(exc).strip().splitlines()[-1]}")
        if not ok or inliers is None:
            return PoseEstimate.failed("RANSAC found no pose with enough inliers")
        T = make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel()) @ network_axes(frame)
        if not np.all(np.isfinite(T)):
            return PoseEstimate.failed(f"{self.name} returned a non-finite pose")
        return PoseEstimate(T=T, inliers=inliers.ravel().astype(np.int64))
