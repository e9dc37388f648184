"""CorrI2P's whole network as the authors' `CorrI2P` computes it (network.py:11-230): the two encoders, the
exchange, the heads. The node counts are the network's `Options` (options.py: 128 + 128): the published loader
samples 256 + 256 nodes (kitti_pc_img_dataloader.py:107-108), which no layer built from options.py accepts, so the
nodes follow options.py (the authors' training log folder is named `log_xy_40960_128`)."""

from __future__ import annotations

import torch
from torch import nn

from .exchange import Exchange
from .heads import Heads
from .image import ResNet34
from .points import PointEncoder

NODES = 128  # options.py node_a_num, node_b_num
IMAGE_SIZE = (160, 512)  # options.py img_H, img_W: the stride-32 map is 5 x 16 = 80 cells, a layer width
NUM_POINTS = 40960  # options.py input_pt_num


class CorrI2PNet(nn.Module):
    """(cloud, intensity, normals, image, node_a, node_b) -> descriptors and overlap scores of points and pixels."""

    def __init__(self, nodes: int = NODES, image_size: tuple[int, int] = IMAGE_SIZE) -> None:
        super().__init__()
        cells32 = (image_size[0] // 32) * (image_size[1] // 32)
        self.encoder3d = PointEncoder()
        self.encoder2d = ResNet34()
        self.exchange = Exchange(nodes, nodes, cells32)
        self.heads = Heads()

    def forward(
        self, pc: torch.Tensor, intensity: torch.Tensor, normals: torch.Tensor, image: torch.Tensor,
        node_a: torch.Tensor, node_b: torch.Tensor, trace: dict | None = None,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        """pc, normals [B x 3 x N], intensity [B x 1 x N], image [B x 3 x H x W] (RGB / 255), nodes [B x 3 x M]
        -> `img_feature` [B x 64 x H/4 x W/4], `pc_feature` [B x 64 x N], `img_score`, `pc_score`; `trace`, when
        given, receives every intermediate tensor by name."""
        trace = {} if trace is None else trace
        points = self.encoder3d(pc, intensity, normals, node_a, node_b)
        maps = self.encoder2d(image)
        trace.update({f"pc_{k}": v for k, v in points.items()})
        trace.update(zip(("img_s4", "img_s8", "img_s16", "img_s32", "img_global"), maps[1:], strict=True))
        pixels = self.exchange.image(maps, points, trace)
        per_point = self.exchange.points(maps, points, pc, node_a, node_b, trace)
        return self.heads(per_point, pixels)
