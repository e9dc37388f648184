"""ResNet's residual blocks with GroupNorm, and the mask of a padded batch's coarse cells: CorrI2P's image branch
brought them, DeepI2P's is built from them too.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def norm(channels: int, groups: int) -> nn.GroupNorm:
    return nn.GroupNorm(min(groups, channels), channels)


class BasicBlock(nn.Module):
    """ResNet's two 3x3 convolutions with an identity (or strided 1x1) shortcut."""

    def __init__(self, cin: int, cout: int, stride: int, groups: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.norm1, self.norm2 = norm(cout, groups), norm(cout, groups)
        self.shortcut = (
            nn.Identity()
            if stride == 1 and cin == cout
            else nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), norm(cout, groups))
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.relu(self.norm1(self.conv1(x)))
        return F.relu(self.norm2(self.conv2(out)) + self.shortcut(x))


def stage(cin: int, cout: int, blocks: int, stride: int, groups: int) -> nn.Sequential:
    layers = [BasicBlock(cin, cout, stride, groups)]
    layers += [BasicBlock(cout, cout, 1, groups) for _ in range(blocks - 1)]
    return nn.Sequential(*layers)


def coarse_mask(size: torch.Tensor, shape: tuple[int, int], stride: int) -> torch.Tensor:
    """[B x 1 x h x w] float: the cells of a stride-`stride` map that cover each frame's own size [B x 2] (H, W).

    Every stride-2 layer here maps n pixels to ceil(n / 2), so a frame of height H covers ceil(H / stride) rows.
    """
    cells = torch.div(size + stride - 1, stride, rounding_mode="floor")
    rows = torch.arange(shape[0], device=size.device)[None, :, None] < cells[:, :1, None]
    cols = torch.arange(shape[1], device=size.device)[None, None, :] < cells[:, 1:, None]
    return (rows & cols)[:, None].float()
