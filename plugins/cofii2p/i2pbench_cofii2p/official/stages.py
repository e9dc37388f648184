"""The official size's stages: the loader's pixels and points (prepare.py), the authors' network with eval_all.py's
fine matching as one matcher stage, and their solvePnPRansac (solver.py).

Why one learned stage: the network exchanges whole feature maps and a coarse transformer's tokens between its
branches and picks its own coarse matches inside its test mode (model/network.py:145-161), so it has no cut at
i2pbench's encoder/exchanger boundaries; the official size runs no encoder or exchanger (as CorrI2P's official size).

Pixels (`cofii2p-official-grid`): every cell of the network's fine map (stride 2 in the 160 x 512 crop: 80 x 256),
as the frame's pixel the authors' PnP puts it at: (4x + 2 dx, 4y + 2 dy) on a full-size KITTI image. Points
(`cofii2p-official-points`): the loader's 20,480 (prepare.py).
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
    Extractor2D,
    Extractor3D,
    Features,
    Frame,
    Keypoints2D,
    Keypoints3D,
    LearnedComponent,
    Matcher,
    Matches,
)
from i2pbench.layers.peer_inputs import cell_corners, pixel_cells
from i2pbench.layers.point_pyramid import PointPyramid

from .matching import cell_rows, fine_pixels, node_rows
from .network import CoFiI2PNetwork
from .prepare import CELL_PX, CROP, NUM_POINTS, loader_cloud, loader_crop, network_inputs


def grid_pixels(width: int, height: int, crop: Mapping[str, Any] = CROP) -> np.ndarray:
    """the full-size pixel of each fine-map cell of the crop, raster order -> [cells x 2]."""
    return cell_corners(width, height, loader_crop(width, height, crop), CELL_PX)


def fine_cells(uv: np.ndarray, width: int, height: int, crop: Mapping[str, Any] = CROP) -> np.ndarray:
    """the fine-map cell each pixel uv [M x 2] falls in, raster order -> [M] int64; -1 outside the crop."""
    return pixel_cells(np.asarray(uv, np.float32), width, height, loader_crop(width, height, crop), CELL_PX)


class OfficialGrid(Extractor2D):
    """Every fine-map cell of the loader's crop, as the frame's pixel (module docstring)."""

    name = "cofii2p-official-grid"
    default_conf: ClassVar[dict[str, Any]] = dict(CROP)

    def __call__(self, frame: Frame) -> Keypoints2D:
        return Keypoints2D(uv=grid_pixels(*frame.image_size, self.conf))


class OfficialPoints(Extractor3D):
    """The loader's 20,480 points (prepare.loader_cloud)."""

    name = "cofii2p-official-points"
    default_conf: ClassVar[dict[str, Any]] = {"max_keypoints": NUM_POINTS, "seed": 0}

    def __call__(self, frame: Frame) -> Keypoints3D:
        return loader_cloud(frame, int(self.conf["max_keypoints"]), int(self.conf["seed"]))


class OfficialCoFiI2P(LearnedComponent, Matcher):
    """The authors' network in its test mode and eval_all.py's fine matching: each coarse point the network keeps,
    paired with the fine-map cell of its patch whose feature is nearest in cosine similarity (matching.py). Fewer
    than 2,048 points are repeated up to it (prepare.network_inputs)."""

    name = "cofii2p-official"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D})
    provides = frozenset({MATCHES})
    runtime_keys = frozenset({"swap_patch_axes"})
    default_conf: ClassVar[dict[str, Any]] = {
        "seed": 0,  # the pyramid's random halvings, with the frame's seed
        "features": "normals",  # point features beside intensity: "normals" (KITTI) or "xyz" (nuScenes)
        "intensity_scale": 1.0,  # the frame's reflectance times this: 255 for their nuScenes files' 0-255
        "swap_patch_axes": True,  # eval_all.py:104-105 (matching.py)
        "radius_px": 4.0,  # a pair's tolerance: one fine-map cell of a full-size KITTI image
        **CROP,
    }

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        super().__init__(conf)
        self.net = CoFiI2PNetwork()

    def forward(self, data: dict[str, Any], image: torch.Tensor) -> tuple:
        """the network's test mode (model/network.py:145-164): its eight outputs."""
        return self.net(data, image, None, None, None, "test")

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        width, height = frame.image_size
        cells = fine_cells(kp2d.uv, width, height, self.conf)
        if len(kp3d) == 0 or not (cells >= 0).any():  # an empty scan, or a frame too small for the crop
            return Matches.empty()
        data, image, pyramid = network_inputs(frame, kp3d, self.conf)
        try:
            out = self.batched(on_device(data, self.device), image.to(self.device))
        except ValueError:  # under 4 pairs at any threshold (their loop never ends) or a patch off the map (theirs
            # asserts): the network refuses the frame, and it gets no match
            return Matches.empty()
        return self.pairs([t.cpu() for t in out[4:8]], cells, pyramid)

    def pairs(self, test_outputs: list[torch.Tensor], cells: np.ndarray, pyramid: PointPyramid) -> Matches:
        """the 'test' outputs (patches, point features, patch centres, chosen points) -> matches between the
        extractors' rows: each chosen point's fine pixel (matching.fine_pixels), read by the keypoint in its cell."""
        patches, point_features, centres, chosen = test_outputs
        xy, score = fine_pixels(patches.reshape(len(chosen), patches.shape[-2], -1), point_features.reshape(
            len(chosen), -1), centres.float(), bool(self.conf["swap_patch_axes"]))  # fmt: skip
        map_width, map_height = (side // CELL_PX for side in self.conf["crop"])
        x, y = xy.long().numpy()
        on_map = (x >= 0) & (x < map_width) & (y >= 0) & (y < map_height)
        rows2d = np.where(on_map, cell_rows(cells, map_width * map_height)[np.where(on_map, y * map_width + x, 0)], -1)
        rows3d = pyramid.picks[-1][node_rows(pyramid.points[-1], chosen).numpy()]
        keep = rows2d >= 0
        return Matches(rows2d[keep], rows3d[keep], score.numpy()[keep].astype(np.float32),
                       radius_px=float(self.conf["radius_px"]))  # fmt: skip


def on_device(data: dict[str, Any], device: torch.device) -> dict[str, Any]:
    """the `pc_data_dict`'s tensors on `device` (its `lengths` stay integers)."""
    moved = {k: [t.to(device) for t in v] for k, v in data.items() if k not in ("lengths", "feats")}
    return {**data, **moved, "feats": data["feats"].to(device)}
