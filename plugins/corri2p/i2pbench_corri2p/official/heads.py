"""The authors' four heads (network.py): 64-wide L2-normalised descriptors and sigmoid overlap scores for every
point (from the per-point features) and every stride-4 pixel (from the decoder's map)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .mlp import conv_bn_relu_1x1


class Heads(nn.Module):
    def __init__(self, point_width: int = 128, pixel_width: int = 64, dim: int = 64) -> None:
        super().__init__()
        self.point_descriptor = conv_bn_relu_1x1((point_width, 128, 128, dim), 1)
        self.point_score = conv_bn_relu_1x1((point_width, 128, 64, 1), 1)
        self.pixel_descriptor = conv_bn_relu_1x1((pixel_width, 64, 64, dim), 2)
        self.pixel_score = conv_bn_relu_1x1((pixel_width, 64, 64, 1), 2)

    def forward(self, per_point: torch.Tensor, pixels: torch.Tensor) -> dict[str, torch.Tensor]:
        """per_point [B x 128 x N], pixels [B x 64 x h x w] -> descriptors and scores, channels first."""
        return {
            "pc_feature": F.normalize(self.point_descriptor(per_point), dim=1),
            "pc_score": torch.sigmoid(self.point_score(per_point)),
            "img_feature": F.normalize(self.pixel_descriptor(pixels), dim=1),
            "img_score": torch.sigmoid(self.pixel_score(pixels)),
        }
