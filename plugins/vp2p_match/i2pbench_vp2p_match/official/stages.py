"""The official size's stages: the authors' pixels and points (their KITTI loader's preparation), their network as one
matcher stage with run_kitti.py's inference rule, and the geometry that lets the generic EPnP-RANSAC solver run their
PnP.

Why one learned stage: the network fuses whole feature maps and global features across its branches, not
per-keypoint descriptors, so it has no cut at i2pbench's encoder/exchanger boundaries (as CorrI2P's official size).

Pixels (`vp2p-match-official-grid`): the authors' image is the frame's halved (OpenCV linear, no rows cut) and
centre-cropped to 160 x 512 (models/kitti_dataset.py:306-319); the network scores every cell of its stride-4 map, whose
(x, y) their PnP reads with K at 1/4 of the crop's (run_kitti.py:53-91, kitti_dataset.py:322-323). That cell is the
full-resolution pixel (8x + 2 dx, 8y + 2 dy) under the frame's K, exactly, so EPnP on these pixels with the frame's K
and 8 px is theirs with K/4 and 1 px (prepare.py).

Points (`vp2p-match-official-points`): the scan voxelised at 0.1 m with normals and nearest-return intensity (the
preprocessed .npy files both papers' loaders read), then a seeded random 40,960 of them in the random order the
loader's `downsample_np` draws (run_kitti.py keeps the first 8,500 confident points in that order). Kept differences:
the loader's second 0.1 m voxelisation (in the camera frame) is not repeated; the network sees the cloud in camera
axes (a fixed permutation of the LiDAR's, no extrinsic).

Under the `vp2p-match` card (and `corri2p`, whose inputs are the same) the frame already is the loader's inputs: the
grid's cells are the 160 x 512 image's own, the points the frame's 40,960 in the card's order, in camera axes already
(no permutation), normals estimated on them (peer_inputs).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import torch

from i2pbench.api import (
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
    StageError,
)
from i2pbench.layers.peer_inputs import (
    LIDAR_TO_CAMERA_AXES,
    CropCells,
    DrawnCloud,
    frame_cloud,
    frame_crop,
    image_input,
    network_axes,
    point_inputs,
    voxel_cloud,
)

from .loss import LOSS_CONF, anchors, cell_camera, frame_loss, pose_vector
from .network import VP2PMatchNet
from .prepare import STRIDE, pixel_cells

SUP = "sup_"  # the prefix of a prepared frame's anchors (training) beside the network's inputs
NUM_POINTS = 40960  # utils/options.py input_pt_num
# the authors' image preparation (kitti_dataset.py:306-319; options.py img_W x img_H): a conf of the grid and of the
# matcher, which must agree (the official size pins both to these)
CROP: dict[str, Any] = {"scale": 0.5, "crop": (512, 160)}
LOADER_CARDS = frozenset({"vp2p-match", "corri2p"})  # the cards whose frames are the authors' loader's inputs


class OfficialGrid(CropCells):
    """Every stride-4 cell of the authors' crop, as the frame's pixel their PnP puts it at (module docstring)."""

    name = "vp2p-match-official-grid"
    default_conf: ClassVar[dict[str, Any]] = dict(CROP)
    cell_px = STRIDE
    loader_cards = LOADER_CARDS


class OfficialPoints(DrawnCloud):
    """A seeded 40,960 of the scan's 0.1 m voxel centroids, in the order drawn (module docstring)."""

    name = "vp2p-match-official-points"
    default_conf: ClassVar[dict[str, Any]] = {"max_keypoints": NUM_POINTS, "seed": 0}
    in_draw_order = True
    loader_cards = LOADER_CARDS


def confident_pairs(
    pixel_feat: torch.Tensor,
    pixel_score: torch.Tensor,
    point_feat: torch.Tensor,
    point_score: torch.Tensor,
    conf: Mapping[str, Any],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """run_kitti.py:62-87 on one frame: pixels [D x P] and points [D x N] whose scores exceed the thresholds, the first
    `max_pixels` and `max_points` of each in their order, every such pixel paired with the point nearest in cosine
    distance (first at a tie) -> (pixel rows, point rows, cosine similarity)."""
    pixels = torch.nonzero(pixel_score > float(conf["pixel_threshold"]))[:, 0][: int(conf["max_pixels"])]
    points = torch.nonzero(point_score > float(conf["point_threshold"]))[:, 0][: int(conf["max_points"])]
    if len(pixels) == 0 or len(points) == 0:
        return pixels[:0], points[:0], pixel_score[:0]
    similarity = pixel_feat[:, pixels].t() @ point_feat[:, points]
    best = similarity.argmax(1)
    return pixels, points[best], similarity.gather(1, best[:, None])[:, 0]


def sample_seed(frame: Frame) -> int:
    """a seed for one training sample: its frame and its transform (a fresh transform draws fresh anchors)."""
    identity = zlib.crc32(f"{frame.dataset}/{frame.frame_id}".encode())
    return zlib.crc32(np.ascontiguousarray(frame.T_gt, np.float64).tobytes(), identity)


def supervision(
    frame: Frame, pc: torch.Tensor, conf: Mapping[str, Any], axes: np.ndarray | None = None
) -> dict[str, torch.Tensor]:
    """one frame's anchors (official/loss.py) from its true pose, for the cloud pc [3 x N] in network axes (`axes`
    [4 x 4] from the frame's points, None: the fixed LiDAR -> camera permutation): the pose moving network-axes
    points into the camera is T_gt after the axes' inverse."""
    width, height = frame.image_size
    crop_w, crop_h = conf["crop"]
    K4 = cell_camera(frame.K_true, width, height, conf, STRIDE)
    to_axes = np.eye(4)
    to_axes[:3, :3] = LIDAR_TO_CAMERA_AXES
    pose = frame.T_gt @ np.linalg.inv(to_axes if axes is None else axes)
    R, t = pose[:3, :3], pose[:3, 3]
    seed = sample_seed(frame)
    sup = anchors(pc.numpy().astype(np.float64), K4, R, t, (crop_w // STRIDE, crop_h // STRIDE),
                  int(conf["num_kpt"]), float(conf["dist_thres"]), np.random.default_rng(seed))  # fmt: skip
    sup |= {"K4": K4, "pose": pose_vector(R, t), "seed": np.int64(seed)}
    sup |= {f"num_{k}": np.int64(len(sup[k])) for k in ("pc_kpt_idx", "pc_outline_idx", "img_outline_idx")}
    return {k: torch.from_numpy(np.asarray(v)) for k, v in sup.items()}


def unpadded(sup: Mapping[str, torch.Tensor], b: int) -> dict[str, torch.Tensor]:
    """frame b's anchors out of a collated batch (index lists cut to their counts)."""
    n_in, n_out, n_img = (int(sup[f"num_{k}"][b]) for k in ("pc_kpt_idx", "pc_outline_idx", "img_outline_idx"))
    return {
        "pc_kpt_idx": sup["pc_kpt_idx"][b, :n_in], "img_kpt_idx": sup["img_kpt_idx"][b, :n_in],
        "img_xy": sup["img_xy"][b, :n_in], "correspondence": sup["correspondence"][b, :n_in, :n_in],
        "pc_outline_idx": sup["pc_outline_idx"][b, :n_out], "img_outline_idx": sup["img_outline_idx"][b, :n_img],
        "K4": sup["K4"][b], "pose": sup["pose"][b], "seed": sup["seed"][b],
    }  # fmt: skip


class OfficialVP2PMatch(BatchedStage, Matcher):
    """The authors' network (VP2PMatchNet) and run_kitti.py's inference rule (confident_pairs). A pixel reads the
    stride-4 cell it falls in (the official grid's pixels are every cell once, in raster order, as theirs). It
    trains with official/loss.py (`batch_loss`); the loss's keys steer training only, so a checkpoint fits any."""

    name = "vp2p-match-official"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D})
    provides = frozenset({MATCHES})
    runtime_keys = frozenset({"pixel_threshold", "point_threshold", "max_pixels", "max_points", *LOSS_CONF})
    default_conf: ClassVar[dict[str, Any]] = {
        "pixel_threshold": 0.95,  # run_kitti.py --img_thres
        "point_threshold": 0.95,  # run_kitti.py --pc_thres
        "max_pixels": 2800,  # run_kitti.py:71-73
        "max_points": 8500,  # run_kitti.py:80-82
        "radius_px": 8.0,  # a pair's tolerance: --dist_thres 1 px at K/4 of the half-size crop
        **CROP,
        **LOSS_CONF,
    }

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        super().__init__(conf)
        self.net = VP2PMatchNet()

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """the network's inputs: image [3 x 160 x 512], cloud and normals [3 x N] in camera axes, intensity [1 x N];
        with the frame's true pose (training), its anchors, each key prefixed `sup_`."""
        axes = network_axes(frame, LOADER_CARDS, self.label)
        cloud = voxel_cloud(frame) if axes is None else frame_cloud(frame, axes)
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        inputs = {"img": image_input(frame.image, crop), **point_inputs(kp3d, *cloud[:2], axes)}
        if frame.T_gt is not None:
            inputs |= {SUP + k: v for k, v in supervision(frame, inputs["pc"], {**self.conf, **crop}, axes).items()}
        return {k: v.contiguous().to(device) for k, v in inputs.items()}

    def forward(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """`prepare`d frames -> descriptors and scores of every point and stride-4 pixel (official/network.py)."""
        return self.net.trace(inputs["pc"], inputs["intensity"], inputs["sn"], inputs["img"])

    def batch_loss(
        self, inputs: dict[str, Any], features: Features, mask2d: torch.Tensor, mask3d: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """official/loss.py's total, the mean over a batch of `prepare`d frames (each with its own anchors)."""
        sup = {k.removeprefix(SUP): v for k, v in inputs.items() if k.startswith(SUP)}
        if not sup:
            raise StageError(self.label, "trains on frames with their true pose (T_gt): prepare draws anchors from it")
        out = self.batched(inputs)
        terms = [
            frame_loss({k: v[b] for k, v in out.items()}, unpadded(sup, b), inputs["pc"][b], self.conf)
            for b in range(len(inputs["pc"]))
        ]
        mean = {k: torch.stack([t[k] for t in terms]).mean() for k in terms[0]}
        report = {k: float(v.detach()) for k, v in mean.items() if k != "loss"}
        report["anchors"] = float(sup["num_pc_kpt_idx"].float().mean())
        return mean["loss"], report

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if len(kp2d) == 0 or len(kp3d) == 0:  # a frame too small for the crop, or an empty scan
            return Matches.empty()
        width, height = frame.image_size
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        cells = torch.from_numpy(pixel_cells(np.asarray(kp2d.uv, np.float32), width, height, crop))
        inside = torch.nonzero(cells >= 0)[:, 0]
        if len(inside) == 0:
            return Matches.empty()
        out = self.batched(self.one(frame, kp2d, kp3d))
        pixel_feat = out["pixel_feat"][0].flatten(1)[:, cells[inside]]
        pixel_score = out["img_score"][0, 0].flatten()[cells[inside]]
        rows, points, score = confident_pairs(
            pixel_feat, pixel_score, out["point_feat"][0], out["pc_score"][0, 0], self.conf
        )
        if len(rows) == 0:
            return Matches.empty()
        return Matches(
            inside[rows].cpu().numpy(),
            points.cpu().numpy(),
            score.float().cpu().numpy(),
            radius_px=self.conf["radius_px"] * self.conf["scale"] / crop["scale"],  # 1 px at K/4 of the crop
        )
