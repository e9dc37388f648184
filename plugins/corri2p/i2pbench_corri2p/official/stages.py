"""The official size's stages: the authors' pixels and points (their loader's preparation), their network as one
matcher stage with their inference rule (cal_error_all.py), and the geometry that lets the generic EPnP-RANSAC
solver run their PnP.

Why one learned stage: the authors' network exchanges whole feature maps (strides 2 to 32) and node sets between
its branches, not per-keypoint descriptors, so it has no cut at i2pbench's encoder/exchanger boundaries; the
official size runs no encoder or exchanger, and the matcher holds the network (network.py), its four parts under
`encoder3d.`, `encoder2d.`, `exchange.` and `heads.`.

Pixels (`corri2p-official-grid`): the authors' image is the frame's whole image, halved (OpenCV linear) and
centre-cropped to 160 x 512 (kitti_pc_img_dataloader.py:271-287 reads `img_P2`, the whole image in the corri2p-kitti
layout, and cuts no rows: options.py's `crop_original_top_rows` = 50 is read only by nuScenes_script/make_dataset.py);
the network scores every cell of its stride-4 map, whose (x, y) the authors' PnP reads with K at 1/4 of the crop's
(cal_error_all.py:44-48, 81-86). That cell is full-resolution pixel (8x + 2 dx, 8y + 2 dy) under the frame's K
(dx, dy: the crop's offsets in the half-size image), exactly: so EPnP on these pixels with the frame's K at 8 px is
their EPnP on (x, y) with K/4 at 1 px (the official solver, `solver.py`, scales their 1 px to the frame). The crop
(`top_rows`, scale, size) is a conf of the grid and of the matcher, their defaults the loader's (`top_rows` 0; 50
cuts as DeepI2P's loader does); a frame too small for it gets no pixel (the conformance kit scales it to its
frame).

Points (`corri2p-official-points`): the scan voxelised at 0.1 m with open3d normals (radius 0.6 m, 30 neighbours,
oriented to +z) and the intensity of the nearest return (kitti_script/kitti_pc_bin_to_npy_with_downsample_sn.py),
then a seeded random 40,960 of them (the loader's `downsample_np`). Kept differences: the loader's second 0.1 m
voxelisation in the camera frame is not repeated (it merges only points a shifted grid brings together); each
point's `index` is its nearest return's row (matches name frame points); the network sees the cloud in camera axes
(x right, y down, z forward: a fixed permutation of the LiDAR's, no extrinsic), in which the protocol's yaw is the
rotation about y that the authors train under.

Under the `corri2p` card (and `vp2p-match`, whose inputs are the same) the frame already is the authors' loader's
inputs: the grid's cells are the 160 x 512 image's own (their 1 px at K/4 is 4 px there), the points are
the frame's 40,960 in their order, in camera axes already (no permutation), normals estimated on them (peer_inputs).
"""

from __future__ import annotations

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
)
from i2pbench.layers import peer_inputs
from i2pbench.layers.peer_inputs import (
    CropCells,
    DrawnCloud,
    cell_corners,
    frame_cloud,
    frame_crop,
    image_input,
    network_axes,
    node_inputs,
    point_inputs,
    voxel_cloud,
)
from i2pbench.layers.peer_inputs import network_image as network_image  # the official crop, read by the tests

from .network import IMAGE_SIZE, NODES, NUM_POINTS, CorrI2PNet

STRIDE = 4  # the decoder's output stride
# the authors' loader's image preparation (no rows cut, kitti_pc_img_dataloader.py:271-287; options.py img_scale,
# img_W x img_H): a conf of the grid and of the matcher, which must agree (the official size pins both to these)
CROP: dict[str, Any] = {"top_rows": 0, "scale": 0.5, "crop": (IMAGE_SIZE[1], IMAGE_SIZE[0])}
LOADER_CARDS = frozenset({"corri2p", "vp2p-match"})  # the cards whose frames are the authors' loader's inputs


def grid_pixels(width: int, height: int, crop: Mapping[str, Any] = CROP) -> np.ndarray:
    """the full-resolution pixel of each stride-4 cell of the crop, raster order -> [cells x 2] (peer_inputs)."""
    return cell_corners(width, height, crop, STRIDE)


def pixel_cells(uv: np.ndarray, width: int, height: int, crop: Mapping[str, Any] = CROP) -> np.ndarray:
    """the stride-4 cell of the crop each pixel uv [M x 2] falls in, raster order -> [M] int64; -1 outside."""
    return peer_inputs.pixel_cells(uv, width, height, crop, STRIDE)


class OfficialGrid(CropCells):
    """Every stride-4 cell of the authors' crop, as the frame's pixel their PnP puts it at (module docstring)."""

    name = "corri2p-official-grid"
    default_conf: ClassVar[dict[str, Any]] = dict(CROP)
    cell_px = STRIDE
    loader_cards = LOADER_CARDS


class OfficialPoints(DrawnCloud):
    """A seeded 40,960 of the scan's 0.1 m voxel centroids (module docstring)."""

    name = "corri2p-official-points"
    default_conf: ClassVar[dict[str, Any]] = {"max_keypoints": NUM_POINTS, "seed": 0}
    loader_cards = LOADER_CARDS


class OfficialCorrI2P(BatchedStage, Matcher):
    """The authors' network and inference rule (cal_error_all.py:61-77): pixels and points whose overlap score
    exceeds 0.9, each such point paired with the selected pixel nearest in cosine distance. A pixel reads the cell it
    falls in (the official grid's pixels are every cell once, as theirs; other pixels work too)."""

    name = "corri2p-official"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D})
    provides = frozenset({MATCHES})
    runtime_keys = frozenset({"score_threshold"})
    default_conf: dict[str, Any] = {
        "score_threshold": 0.9,  # cal_error_all.py:61, 69 (both sides)
        "nodes": NODES,  # node_a and node_b each (options.py; network.py says why not the loader's 256)
        "node_pool": 8,  # FPS over a random 8 x nodes points (kitti_pc_img_dataloader.py:330-338)
        "radius_px": 8.0,  # a pair's tolerance: train.py's 1 px at stride 4 of the half-size image
        **CROP,
    }

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        super().__init__(conf)
        crop_w, crop_h = self.conf["crop"]
        self.net = CorrI2PNet(int(self.conf["nodes"]), (crop_h, crop_w))

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """the network's inputs: image [3 x 160 x 512], cloud and normals [3 x N] in camera axes, intensity
        [1 x N], nodes [3 x M] each."""
        axes = network_axes(frame, LOADER_CARDS, self.label)
        cloud = voxel_cloud(frame) if axes is None else frame_cloud(frame, axes)
        points = point_inputs(kp3d, *cloud[:2], axes)
        nodes = node_inputs(frame, points["pc"], int(self.conf["nodes"]), int(self.conf["node_pool"]))
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        inputs = {"image": image_input(frame.image, crop), **points, **nodes}
        return {k: v.contiguous().to(device) for k, v in inputs.items()}

    def forward(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """`prepare`d frames -> descriptors and scores of every point and stride-4 pixel (network.py)."""
        return self.net(inputs["pc"], inputs["intensity"], inputs["sn"], inputs["image"], inputs["node_a"],
                        inputs["node_b"])  # fmt: skip

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if len(kp2d) == 0 or len(kp3d) == 0:  # a frame too small for the crop, or an empty scan
            return Matches.empty()
        width, height = frame.image_size
        crop = frame_crop(frame, self.conf, LOADER_CARDS, self.label)
        cells = torch.from_numpy(pixel_cells(np.asarray(kp2d.uv, np.float32), width, height, crop))
        if (cells < 0).all():  # a frame too small for the crop, or no pixel inside it
            return Matches.empty()
        out = self.batched(self.one(frame, kp2d, kp3d))
        threshold = float(self.conf["score_threshold"])
        scores = out["img_score"][0, 0].flatten()
        pixels = torch.nonzero((cells >= 0) & (scores[cells.clamp(min=0)] > threshold))[:, 0]
        points = torch.nonzero(out["pc_score"][0, 0] > threshold)[:, 0]
        if len(pixels) == 0 or len(points) == 0:
            return Matches.empty()
        image_features = out["img_feature"][0].flatten(1)[:, cells[pixels]]
        similarity = out["pc_feature"][0][:, points].t() @ image_features
        best = similarity.argmax(1)  # the nearest pixel in cosine distance 1 - <f_pc, f_img>, first at a tie
        score = similarity.gather(1, best[:, None])[:, 0]
        return Matches(
            pixels[best].cpu().numpy(),
            points.cpu().numpy(),
            score.float().cpu().numpy(),
            radius_px=self.conf["radius_px"] * self.conf["scale"] / crop["scale"],  # 1 px at K/4 of the crop
        )
