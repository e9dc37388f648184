"""The official size's stages: the authors' pixels and points (their KITTI loader's preparation), their network as one
matcher stage with their inference rule (coarse and fine argmax), their grid-classification + PnP solver
(evaluation/registration_pnp.py), and by name their frustum registration (evaluation/registration_lsq.py).

Why one learned stage: the authors' network attends from point nodes over whole image maps (strides 16 and 32), not
per-keypoint descriptors, so it has no cut at i2pbench's encoder/exchanger boundaries; the official size runs no
encoder or exchanger, and the matcher holds the network (network.py) under `net.`, its keys the authors'.

Pixels (`deepi2p-official-grid`): the authors' image is the frame's, top 50 rows cut, halved (OpenCV linear) and
centre-cropped to 160 x 512 (kitti/options.py, data/kitti_pc_img_pose_loader.py); the network classifies each point
into one of its 32 px cells, which their PnP reads as the cell's integer (column, row) with K at 1/32 of the crop's.
That is full-resolution pixel (64 c + 2 dx, 64 r + 2 dy + 50) under the frame's K (dx, dy: the crop's offsets in the
half-size image), exactly: so EPnP on these pixels with the frame's K and 38.4 px is theirs on cells with K/32 and
0.6. The crop is a conf of the grid and of the matcher, their defaults the authors'; a frame too small for it gets no
pixel (the conformance kit scales it to its frame).

Points (`deepi2p-official-points`): the scan voxelised at 0.1 m with open3d normals (radius 0.6 m, 30 neighbours,
oriented to +z) and the intensity of the nearest return, voxelised again at 0.3 m when it holds over twice the 20,480
points (normals and intensity averaged, as the loader's colour trick), then a seeded random 20,480. Kept differences:
the loader's accumulation of 3 scans by odometry poses is not done (a benchmark frame is one scan); a cloud of fewer
points is taken whole rather than drawn with repeats; each point's `index` is its nearest return's row; the network
sees the cloud in camera axes (x right, y down, z forward: a fixed permutation of the LiDAR's), in which the
protocol's yaw is the rotation about y that the authors train under.

Under the `deepi2p` card the frame already is the loader's inputs: the fine cells are the 160 x 512 image's own (the
PnP threshold 19.2 px there, 0.6 cell as theirs), the points the frame's 20,480 drawn 0.1 m voxels in their order, in
camera axes already (no permutation), normals estimated on them (peer_inputs); the loader's 0.3 m step applies to the
card's cloud by its own rule (over twice the point count), i.e. not at the card's 20,480.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

import cv2
import numpy as np
import torch

from i2pbench.api import (
    FRUSTUM_SCORES,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
    BatchedStage,
    Device,
    Features,
    Frame,
    Keypoints2D,
    Keypoints3D,
    Matcher,
    Matches,
    PoseEstimate,
    PoseSolver,
    StageError,
    transform_points,
)
from i2pbench.layers import peer_inputs
from i2pbench.layers.peer_inputs import (
    LIDAR_TO_CAMERA_AXES,
    CropCells,
    DrawnCloud,
    cell_corners,
    crop_offsets,
    empty_cloud,
    finite_returns,
    frame_cloud,
    frame_crop,
    image_input,
    network_axes,
    node_inputs,
    point_inputs,
    voxels_with_normals,
)
from i2pbench.layers.pointnet2 import frame_seed

from .network import DeepI2PNetwork
from .solvers import (
    PNP_ITERATIONS,
    PNP_MAX_TRANSLATION,
    PNP_THRESHOLD,
    RESTARTS,
    initial_guess,
    restarts,
    solve_frustum,
)

CELL_PX = 32  # kitti/options.py img_fine_resolution_scale: the fine cells, in pixels of the crop
NUM_POINTS, NODES = 20480, 128  # options.py input_pt_num, node_a_num = node_b_num
# the authors' image preparation (options.py crop_original_top_rows, img_scale, img_W x img_H): a conf of the grid
# and of the matcher, which must agree (the official size pins both to these)
CROP: dict[str, Any] = {"top_rows": 50, "scale": 0.5, "crop": (512, 160)}
LOADER_CARDS = frozenset({"deepi2p"})  # the card whose frames are the authors' loader's inputs


def cell_pixels(width: int, height: int, crop: Mapping[str, Any] = CROP) -> np.ndarray:
    """the full-resolution pixel of each fine cell's corner, raster order -> [cells x 2] (peer_inputs)."""
    return cell_corners(width, height, crop, CELL_PX)


def pixel_cells(uv: np.ndarray, width: int, height: int, crop: Mapping[str, Any] = CROP) -> np.ndarray:
    """the fine cell each pixel uv [M x 2] falls in, raster order -> [M] int64; -1 outside the crop."""
    return peer_inputs.pixel_cells(uv, width, height, crop, CELL_PX)


def network_cloud(
    frame: Frame, count: int, axes: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """the scan as the authors' loader makes it before its random draw: points [V x 3], normals [V x 3], intensity
    [V] and each point's nearest raw row [V] (module docstring); with `axes` (a `deepi2p` card's frame, network_axes)
    the card's drawn voxels, voxelised at 0.3 m only by the loader's rule."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    finite, raw = finite_returns(frame)
    if len(raw) == 0:
        return empty_cloud()
    tree = cKDTree(raw[:, :3])
    if axes is None:
        cloud = voxels_with_normals(raw[:, :3])
        intensity = raw[tree.query(np.asarray(cloud.points), k=1)[1], 3].astype(np.float64)
    else:
        xyz, normals, reflectance, rows = frame_cloud(frame, axes)
        if len(xyz) <= 2 * count:
            return xyz, normals, reflectance, rows
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz.astype(np.float64)))
        cloud.normals = o3d.utility.Vector3dVector(normals.astype(np.float64))
        intensity = reflectance.astype(np.float64)
    if len(cloud.points) > 2 * count:
        top = max(float(intensity.max()), 1e-12)
        cloud.colors = o3d.utility.Vector3dVector(np.c_[intensity / top, np.zeros((len(intensity), 2))])
        cloud = cloud.voxel_down_sample(voxel_size=0.3)
        intensity = np.asarray(cloud.colors)[:, 0] * top
    xyz = np.asarray(cloud.points, np.float32)
    rows = finite[tree.query(xyz, k=1)[1]]
    return xyz, np.asarray(cloud.normals, np.float32), intensity.astype(np.float32), rows


class OfficialCells(CropCells):
    """Every fine cell of the authors' crop, as the frame's pixel their PnP puts it at (module docstring)."""

    name = "deepi2p-official-grid"
    default_conf: ClassVar[dict[str, Any]] = dict(CROP)
    cell_px = CELL_PX
    loader_cards = LOADER_CARDS


class OfficialPoints(DrawnCloud):
    """A seeded 20,480 of the scan as the authors' loader prepares it (module docstring)."""

    name = "deepi2p-official-points"
    default_conf: ClassVar[dict[str, Any]] = {"max_keypoints": NUM_POINTS, "seed": 0}

    loader_cards = LOADER_CARDS

    def cloud(self, frame: Frame, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return network_cloud(frame, count)

    def card_cloud(
        self, frame: Frame, count: int, axes: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return network_cloud(frame, count, axes)


class OfficialDeepI2P(BatchedStage, Matcher):
    """The authors' network and inference: a point whose coarse argmax is 'inside' is paired with the pixel of its
    fine argmax cell; every point's softmax 'inside' probability is its frustum score (the frustum solvers' input).

    A pair is true when its point projects within one cell diagonal of the cell's corner pixel (64 px cells at full
    size: 90.5 px), which holds the whole cell the classifier names."""

    name = "deepi2p-official"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D})
    provides = frozenset({MATCHES, FRUSTUM_SCORES})
    default_conf: ClassVar[dict[str, Any]] = {
        "nodes": NODES,  # node_a and node_b each (options.py)
        "node_pool": 8,  # FPS over a random 8 x nodes points (kitti_pc_img_pose_loader.py)
        "normals_points": NUM_POINTS,  # the cloud size whose preparation gives each point its normal
        **CROP,
    }

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        super().__init__(conf)
        crop_w, crop_h = self.conf["crop"]
        self.net = DeepI2PNetwork((crop_h, crop_w), CELL_PX)

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """the network's inputs: image [3 x 160 x 512] (0-255), cloud and normals [3 x N] in camera axes, intensity
        [1 x N], nodes [3 x 128] each."""
        axes = network_axes(frame, LOADER_CARDS, self.label)
        points = point_inputs(kp3d, *network_cloud(frame, int(self.conf["normals_points"]), axes)[:2], axes)
        nodes = node_inputs(frame, points["pc"], int(self.conf["nodes"]), int(self.conf["node_pool"]))
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        inputs = {"image": image_input(frame.image, crop, divide_by=1.0), **points, **nodes}
        return {k: v.contiguous().to(device) for k, v in inputs.items()}

    def forward(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """`prepare`d frames -> coarse [B x 2 x N] and fine [B x cells x N] scores (network.py)."""
        return self.net(inputs["pc"], inputs["intensity"], inputs["sn"], inputs["node_a"], inputs["node_b"],
                        inputs["image"])  # fmt: skip

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if len(kp3d) == 0:  # an empty scan: nothing to classify
            return dataclasses.replace(Matches.empty(), frustum=np.zeros(0, np.float32))
        width, height = frame.image_size
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        if crop_offsets(width, height, crop) is None:
            raise StageError(self.label, f"the {width} x {height} image cannot hold the authors' crop {self.conf}")
        cells = pixel_cells(np.asarray(kp2d.uv, np.float32).reshape(-1, 2), width, height, crop)
        out = self.batched(self.one(frame, kp2d, kp3d))
        return classified_matches(out["coarse_scores"][0], out["fine_scores"][0], cells, cell_diagonal_px(crop))


def cell_diagonal_px(crop: Mapping[str, Any]) -> float:
    """a fine cell's diagonal in the frame's pixels."""
    return float(np.hypot(CELL_PX, CELL_PX) / crop["scale"])


def classified_matches(coarse: torch.Tensor, fine: torch.Tensor, cells: np.ndarray, radius_px: float) -> Matches:
    """coarse [2 x N], fine [C x N] scores and the cell of each 2D keypoint [M] (-1: none) -> each point classified
    inside paired with the first keypoint in its predicted cell (score: that cell's softmax probability); frustum:
    every point's softmax probability of 'inside'."""
    frustum = torch.softmax(coarse.float(), dim=0)[1].cpu().numpy().astype(np.float32)
    fine_prob, fine_cell = torch.softmax(fine.float(), dim=0).max(dim=0)
    keypoint_of = np.full(fine.shape[0], -1, np.int64)
    for row in range(len(cells) - 1, -1, -1):  # backwards, so the first keypoint of a cell is the one kept
        if cells[row] >= 0:
            keypoint_of[cells[row]] = row
    inside = (coarse.argmax(dim=0) == 1).cpu().numpy()
    pixel = keypoint_of[fine_cell.cpu().numpy()]
    points = np.flatnonzero(inside & (pixel >= 0))
    return Matches(
        pixel[points], points.astype(np.int64), fine_prob.cpu().numpy()[points].astype(np.float32), frustum,
        radius_px=radius_px,
    )  # fmt: skip


class OfficialPnP(PoseSolver):
    """registration_pnp.py's solve_PnP on the official grid's pixels: EPnP in RANSAC, 500 iterations, 0.6 cell
    (38.4 px at full size), from no initial guess; a pose whose translation is 14.14 m or longer is refused (the
    authors replace it with the identity, a pose; here it is a failed solve, which the metrics count as such)."""

    name = "deepi2p-official-pnp"
    default_conf: ClassVar[dict[str, Any]] = {
        "iterations": PNP_ITERATIONS,
        "reprojection_error_px": PNP_THRESHOLD * CELL_PX / CROP["scale"],
        "max_translation_m": PNP_MAX_TRANSLATION,
    }

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        if len(matches) < 4:
            return PoseEstimate.failed(f"{self.label}: {len(matches)} points classified inside, EPnP needs 4")
        points = np.asarray(kp3d.xyz, np.float64)[matches.index3d]
        pixels = np.asarray(kp2d.uv, np.float64)[matches.index2d]
        crop = frame_crop(frame, CROP, LOADER_CARDS, self.label)  # a loader card's pixels are the crop's
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            points, pixels, np.asarray(frame.K, np.float64), None, useExtrinsicGuess=False,
            iterationsCount=int(self.conf["iterations"]),
            reprojectionError=float(self.conf["reprojection_error_px"]) * CROP["scale"] / crop["scale"],
            flags=cv2.SOLVEPNP_EPNP,
        )  # fmt: skip
        if not ok or inliers is None:
            return PoseEstimate.failed(f"{self.label}: EPnP-RANSAC found no pose")
        if np.linalg.norm(tvec) >= float(self.conf["max_translation_m"]):
            return PoseEstimate.failed(
                f"{self.label}: translation {np.linalg.norm(tvec):.2f} m >= {self.conf['max_translation_m']} m, "
                "refused as the authors' solve_PnP does"
            )
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec[:, 0]
        return PoseEstimate(T, inliers[:, 0].astype(np.int64))


def crop_K(K: np.ndarray, width: int, height: int, crop: Mapping[str, Any]) -> np.ndarray:
    """the frame's K moved onto the authors' crop (top rows cut, scaled, shifted by the crop offsets), as their
    loader moves it."""
    dx, dy = crop_offsets(width, height, crop)
    moved = np.asarray(K, np.float64).copy()
    moved[1, 2] -= crop["top_rows"]
    moved[:2] *= crop["scale"]
    moved[0, 2] -= dx
    moved[1, 2] -= dy
    return moved


class OfficialFrustum(PoseSolver):
    """registration_lsq.py's frustum registration (official/solvers.py `solve_frustum`) on the official matcher's
    frustum scores: a point is 'inside' when its softmax probability is over 0.5 (the coarse argmax), the cloud in
    camera axes and the crop's K and size as the authors pass them; `variant` "2d" (yaw + translation) or "3d" (6 DoF),
    `restarts` perturbed starts (theirs: 60) drawn from a generator seeded by the frame. Inliers: the matches whose
    point projects inside the crop under the solved pose."""

    name = "deepi2p-official-frustum"
    consumes = frozenset({KEYPOINTS3D, MATCHES, FRUSTUM_SCORES})
    default_conf: ClassVar[dict[str, Any]] = {"variant": "2d", "restarts": RESTARTS, **CROP}

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        super().__init__(conf)
        if self.conf["variant"] not in ("2d", "3d"):
            raise ValueError(f"{self.label}: variant must be '2d' or '3d', got {self.conf['variant']!r}")

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        if matches.frustum is None:
            return PoseEstimate.failed(f"{self.label}: the matches carry no frustum scores ({FRUSTUM_SCORES})")
        width, height = frame.image_size
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        axes = network_axes(frame, LOADER_CARDS, self.label)
        if crop_offsets(width, height, crop) is None:
            return PoseEstimate.failed(f"{self.label}: the {width} x {height} image cannot hold the crop")
        coarse = (np.asarray(matches.frustum) > 0.5).astype(np.int64)
        if not coarse.any():
            return PoseEstimate.failed(f"{self.label}: no point classified inside the frustum")
        if axes is None:  # the dataset's frame: the fixed LiDAR -> camera permutation
            axes = np.eye(4)
            axes[:3, :3] = LIDAR_TO_CAMERA_AXES
            pc = (np.asarray(kp3d.xyz, np.float64) @ LIDAR_TO_CAMERA_AXES.T).T
        else:
            pc = transform_points(axes, np.asarray(kp3d.xyz, np.float64)).T
        K = crop_K(frame.K, width, height, crop)
        hw = (self.conf["crop"][1], self.conf["crop"][0])
        yaw, _ = initial_guess(pc, coarse)
        starts = restarts(yaw, np.random.default_rng(frame_seed(frame)), int(self.conf["restarts"]))
        pose, _ = solve_frustum(pc, coarse, K, hw, starts, is_2d=self.conf["variant"] == "2d")
        T = pose @ axes
        return PoseEstimate(T, np.flatnonzero(projects_inside(kp3d.xyz[matches.index3d], T, K, hw)).astype(np.int64))


def projects_inside(xyz: np.ndarray, T: np.ndarray, K: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """[M x 3] points under T and K: in front (0.1 m, the authors' label) and within the H x W image -> [M] bool."""
    camera = np.asarray(xyz, np.float64) @ T[:3, :3].T + T[:3, 3]
    depth = np.maximum(camera[:, 2], 1e-9)
    u, v = K[0, 0] * camera[:, 0] / depth + K[0, 2], K[1, 1] * camera[:, 1] / depth + K[1, 2]
    return (camera[:, 2] > 0.1) & (u >= 0) & (u <= hw[1] - 1) & (v >= 0) & (v <= hw[0] - 1)
